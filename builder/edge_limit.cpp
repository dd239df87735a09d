// The edge length limit: finding the edges a simplification made too long, and the vertices that split them.
#include "edge_limit.h"

#include <algorithm>
#include <cmath>
#include <unordered_set>

namespace tessera {

double distance2(const float* a, const float* b) {
    return double(a[0] - b[0]) * (a[0] - b[0]) + double(a[1] - b[1]) * (a[1] - b[1]) + double(a[2] - b[2]) * (a[2] - b[2]);
}

namespace {

uint64_t edge_key(uint32_t a, uint32_t b) { return a < b ? uint64_t(a) << 32 | b : uint64_t(b) << 32 | a; }

}  // namespace

double mean_edge_length(const std::vector<uint32_t>& indices, const std::vector<float>& positions) {
    double sum = 0;
    for (size_t i = 0; i < indices.size(); i += 3)
        for (int e = 0; e < 3; ++e) sum += std::sqrt(distance2(&positions[3 * indices[i + e]], &positions[3 * indices[i + (e + 1) % 3]]));
    return indices.empty() ? 0.0 : sum / double(indices.size());
}

EdgeCheck check_edge_lengths(const std::vector<uint32_t>& original, const std::vector<uint32_t>& from, const uint32_t* output, size_t outputCount,
                             const std::vector<float>& positions, const std::vector<uint32_t>& positionId, const std::vector<unsigned char>& lock,
                             double maxLength) {
    EdgeCheck check;
    const double limit2 = maxLength * maxLength;
    std::unordered_set<uint64_t> originalEdges, kept, pinned;
    for (size_t i = 0; i < original.size(); i += 3)
        for (int e = 0; e < 3; ++e) originalEdges.insert(edge_key(positionId[original[i + e]], positionId[original[i + (e + 1) % 3]]));
    for (size_t i = 0; i < outputCount; ++i) kept.insert(positionId[output[i]]);
    // Candidates: positions the step removed and may still keep.
    std::vector<uint32_t> removed;
    std::unordered_set<uint32_t> seen;
    for (uint32_t v : from)
        if (!lock[v] && !kept.count(positionId[v]) && seen.insert(positionId[v]).second) removed.push_back(v);
    for (size_t i = 0; i < outputCount; i += 3)
        for (int e = 0; e < 3; ++e) {
            const uint32_t a = output[i + e], b = output[i + (e + 1) % 3];
            const float* pa = &positions[3 * a];
            const float* pb = &positions[3 * b];
            if (distance2(pa, pb) <= limit2 || originalEdges.count(edge_key(positionId[a], positionId[b]))) continue;
            check.tooLong = true;
            const float mid[3] = {(pa[0] + pb[0]) / 2, (pa[1] + pb[1]) / 2, (pa[2] + pb[2]) / 2};
            uint32_t best = UINT32_MAX;
            double bestDistance = INFINITY;
            for (uint32_t v : removed) {
                const double d = distance2(&positions[3 * v], mid);
                if (d < bestDistance && !pinned.count(v)) {
                    bestDistance = d;
                    best = v;
                }
            }
            if (best != UINT32_MAX) {
                pinned.insert(best);
                check.pins.push_back(best);
            }
        }
    return check;
}

}  // namespace tessera
