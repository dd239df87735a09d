// Triangles into clusters: greedy growth over triangle adjacency (see clusters.h).
#include "clusters.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <memory>

namespace tessera {
namespace {

constexpr uint8_t kNotInCluster = 0xff;
constexpr uint32_t kNone = UINT32_MAX;

float distance2(const float* a, const float* b) { return (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]); }

// The triangle nearest to a point among those not yet clustered: a uniform grid over the centroids with cells about
// eight triangles of the surface wide, searched ring by ring outwards. Clustered triangles are dropped from their cell
// as searches meet them.
class NearestTriangle {
public:
    NearestTriangle(const std::vector<float>& centroids, const float* lo, const float* hi, double area) : centroids_(centroids) {
        const size_t triangles = centroids.size() / 3;
        const double extent = std::max({double(hi[0] - lo[0]), double(hi[1] - lo[1]), double(hi[2] - lo[2])});
        double cell = std::sqrt(8.0 * area / double(triangles));
        if (!(cell > 0)) cell = extent > 0 ? extent : 1.0;  // degenerate triangles only
        for (;;) {  // at most one cell per two triangles (a closed surface leaves most cells of its box empty)
            size_t cells = 1;
            for (int k = 0; k < 3; ++k) {
                size_[k] = std::min<size_t>(size_t(double(hi[k] - lo[k]) / cell) + 1, 1u << 20);
                cells *= size_[k];
            }
            if (cells <= triangles / 2 + 64) break;
            cell *= 1.5;
        }
        for (int k = 0; k < 3; ++k) lo_[k] = lo[k];
        cell_ = float(cell);
        std::vector<uint32_t> cellOf(triangles);
        first_.assign(size_[0] * size_[1] * size_[2] + 1, 0);
        for (size_t t = 0; t < triangles; ++t) {
            uint32_t c[3];
            for (int k = 0; k < 3; ++k) c[k] = coordinate(centroids[3 * t + k], k);
            cellOf[t] = uint32_t((c[2] * size_[1] + c[1]) * size_[0] + c[0]);
            ++first_[cellOf[t] + 1];
        }
        for (size_t c = 0; c + 1 < first_.size(); ++c) first_[c + 1] += first_[c];
        count_.resize(first_.size() - 1);
        entries_.resize(triangles);
        for (size_t t = 0; t < triangles; ++t) entries_[first_[cellOf[t]] + count_[cellOf[t]]++] = uint32_t(t);
    }
    uint32_t find(const float* point, const std::vector<uint8_t>& taken) {
        uint32_t home[3];
        float offset2 = 0;  // squared distance from the point to the grid's box
        for (int k = 0; k < 3; ++k) {
            home[k] = coordinate(point[k], k);
            const float inside = std::clamp(point[k], lo_[k], lo_[k] + cell_ * float(size_[k]));
            offset2 += (point[k] - inside) * (point[k] - inside);
        }
        const float offset = std::sqrt(offset2);
        const uint32_t rings = uint32_t(std::max({size_[0], size_[1], size_[2]}));
        uint32_t best = kNone;
        float bestDistance2 = FLT_MAX;
        for (uint32_t r = 0; r < rings; ++r) {
            // Triangles in farther rings are at least r cells away along some axis, less the point's distance to the box.
            const float bound = float(r) * cell_ - offset;
            if (best != kNone && bound > 0 && bound * bound >= bestDistance2) break;
            const int64_t from[3] = {int64_t(home[0]) - r, int64_t(home[1]) - r, int64_t(home[2]) - r};
            for (int64_t z = std::max<int64_t>(from[2], 0); z <= std::min<int64_t>(home[2] + r, size_[2] - 1); ++z)
                for (int64_t y = std::max<int64_t>(from[1], 0); y <= std::min<int64_t>(home[1] + r, size_[1] - 1); ++y) {
                    const bool face = z == from[2] || z == int64_t(home[2]) + r || y == from[1] || y == int64_t(home[1]) + r;
                    const int64_t step = face ? 1 : 2 * int64_t(r);  // inside the ring's faces only its two x ends
                    for (int64_t x = from[0]; x <= int64_t(home[0]) + r; x += std::max<int64_t>(step, 1)) {
                        if (x < 0 || x >= int64_t(size_[0])) continue;
                        const size_t c = size_t((z * int64_t(size_[1]) + y) * int64_t(size_[0]) + x);
                        uint32_t* entry = &entries_[first_[c]];
                        for (uint32_t i = 0; i < count_[c];) {
                            const uint32_t t = entry[i];
                            if (taken[t]) {
                                entry[i] = entry[--count_[c]];
                                continue;
                            }
                            ++i;
                            const float d = distance2(&centroids_[3 * t], point);
                            if (d < bestDistance2 || (d == bestDistance2 && t < best)) {
                                best = t;
                                bestDistance2 = d;
                            }
                        }
                    }
                }
        }
        return best;
    }

private:
    uint32_t coordinate(float value, int axis) const {
        const float c = std::floor((value - lo_[axis]) / cell_);
        return uint32_t(std::clamp(c, 0.0f, float(size_[axis] - 1)));
    }

    const std::vector<float>& centroids_;
    float lo_[3] = {0, 0, 0}, cell_ = 1;
    size_t size_[3] = {1, 1, 1};
    std::vector<uint32_t> first_, count_, entries_;  // per cell: its entries' start, how many are left; triangle numbers
};

}  // namespace

std::vector<std::vector<uint32_t>> build_clusters(const uint32_t* indices, size_t indexCount, const float* positions, size_t vertexCount,
                                                  size_t maxVertices, size_t maxTriangles) {
    std::vector<std::vector<uint32_t>> clusters;
    const size_t triangles = indexCount / 3;
    maxVertices = std::min<size_t>(maxVertices, kNotInCluster);  // a vertex's place in its cluster must fit below kNotInCluster
    if (triangles == 0) return clusters;

    // The triangles around each vertex; the first live[v] of vertex v's list are those not yet clustered.
    std::vector<uint32_t> first(vertexCount + 1, 0), live(vertexCount, 0), around(indexCount);
    for (size_t i = 0; i < indexCount; ++i) ++first[indices[i] + 1];
    for (size_t v = 0; v < vertexCount; ++v) first[v + 1] += first[v];
    for (size_t i = 0; i < indexCount; ++i) around[first[indices[i]] + live[indices[i]]++] = uint32_t(i / 3);

    std::vector<float> centroids(3 * triangles);
    float lo[3] = {FLT_MAX, FLT_MAX, FLT_MAX}, hi[3] = {-FLT_MAX, -FLT_MAX, -FLT_MAX};
    double area = 0;
    for (size_t t = 0; t < triangles; ++t) {
        const float *p0 = &positions[3 * indices[3 * t]], *p1 = &positions[3 * indices[3 * t + 1]], *p2 = &positions[3 * indices[3 * t + 2]];
        const float e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]}, e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        const float n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        area += 0.5 * std::sqrt(double(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]));
        for (int k = 0; k < 3; ++k) {
            const float c = (positions[3 * indices[3 * t] + k] + positions[3 * indices[3 * t + 1] + k] + positions[3 * indices[3 * t + 2] + k]) / 3;
            centroids[3 * t + k] = c;
            lo[k] = std::min(lo[k], c);
            hi[k] = std::max(hi[k], c);
        }
    }

    std::vector<uint8_t> taken(triangles, 0), slot(vertexCount, kNotInCluster);  // slot: the vertex's place in the open cluster
    // The triangles around the open cluster, with their priority and centroid side by side: scanning them is the hot
    // loop. A triangle's priority depends only on its corners, so it changes only when a triangle sharing a corner is
    // taken, and is updated then.
    struct Candidate {
        float centroid[3];
        uint32_t triangle;
        int priority;
    };
    std::vector<Candidate> candidates;
    std::vector<uint32_t> listed(triangles, kNone);  // a triangle's place in `candidates`
    std::vector<uint32_t> clusterVertices, corners, closed;  // closed: candidates whose corners are all in the cluster
    clusterVertices.reserve(maxVertices);
    corners.reserve(3 * maxTriangles);
    float sum[3] = {0, 0, 0}, center[3] = {0, 0, 0};
    std::unique_ptr<NearestTriangle> nearest;  // built on first need: connected surfaces seldom need it

    // meshoptimizer's priorities: a triangle that adds no vertex, then one that leaves a vertex with no other triangle
    // left, then (by how many vertices it adds) one that leaves two vertices with one, then the rest.
    auto priority_of = [&](uint32_t t) {
        const uint32_t a = indices[3 * size_t(t)], b = indices[3 * size_t(t) + 1], c = indices[3 * size_t(t) + 2];
        const int extra = (slot[a] == kNotInCluster) + (slot[b] == kNotInCluster) + (slot[c] == kNotInCluster);
        if (extra == 0) return 0;
        if (live[a] == 1 || live[b] == 1 || live[c] == 1) return 1;
        if ((live[a] == 2) + (live[b] == 2) + (live[c] == 2) >= 2) return 1 + extra;
        return 2 + extra;
    };
    auto unlist = [&](uint32_t t) {
        const uint32_t at = listed[t];
        if (at == kNone) return;
        candidates[at] = candidates.back();
        listed[candidates[at].triangle] = at;
        candidates.pop_back();
        listed[t] = kNone;
    };
    auto finish_cluster = [&] {
        for (uint32_t v : clusterVertices) slot[v] = kNotInCluster;
        clusterVertices.clear();
        clusters.push_back(corners);
        corners.clear();
        for (const Candidate& c : candidates) listed[c.triangle] = kNone;
        candidates.clear();
        closed.clear();
        sum[0] = sum[1] = sum[2] = 0;
    };
    // The best candidate: first by priority, then by distance to the cluster's centre (`spatial`) or by how few
    // triangles its vertices have left (for the first triangle of the next cluster).
    auto best_candidate = [&](bool spatial) {
        // One key per candidate, priority above the score's bits (a non-negative float's bits order as it does): the
        // scan is then a branch-free minimum.
        uint64_t bestKey = UINT64_MAX;
        uint32_t best = kNone;
        for (const Candidate& candidate : candidates) {
            float score;
            if (spatial) {
                score = distance2(candidate.centroid, center);
            } else {
                const uint32_t* c = &indices[3 * size_t(candidate.triangle)];
                score = float(live[c[0]] + live[c[1]] + live[c[2]]);
            }
            uint32_t bits;
            std::memcpy(&bits, &score, 4);
            const uint64_t key = uint64_t(candidate.priority) << 32 | bits;
            best = key < bestKey ? candidate.triangle : best;
            bestKey = std::min(key, bestKey);
        }
        return best;
    };
    auto fits = [&](uint32_t t) {
        const int extra = (slot[indices[3 * t]] == kNotInCluster) + (slot[indices[3 * t + 1]] == kNotInCluster) + (slot[indices[3 * t + 2]] == kNotInCluster);
        return corners.size() < 3 * maxTriangles && clusterVertices.size() + extra <= maxVertices;
    };

    // Seed at the end of the longest axis, so that clusters grow across the surface from one side.
    const int axis = hi[0] - lo[0] >= std::max(hi[1] - lo[1], hi[2] - lo[2]) ? 0 : hi[1] - lo[1] >= hi[2] - lo[2] ? 1 : 2;
    uint32_t next = 0;
    for (uint32_t t = 1; t < triangles; ++t)
        if (centroids[3 * t + axis] < centroids[3 * next + axis]) next = t;

    for (size_t done = 0;;) {
        if (!fits(next)) finish_cluster();
        const uint32_t* corner = &indices[3 * size_t(next)];
        size_t joined = clusterVertices.size();
        for (int k = 0; k < 3; ++k)
            if (slot[corner[k]] == kNotInCluster) {
                slot[corner[k]] = uint8_t(clusterVertices.size());
                clusterVertices.push_back(corner[k]);
            }
        corners.insert(corners.end(), corner, corner + 3);
        taken[next] = 1;
        unlist(next);
        for (int k = 0; k < 3; ++k) {  // no longer around its vertices
            const uint32_t v = corner[k];
            uint32_t* list = &around[first[v]];
            for (uint32_t i = 0; i < live[v]; ++i)
                if (list[i] == next) {
                    list[i] = list[--live[v]];
                    list[live[v]] = next;
                    break;
                }
        }
        // The triangles around vertices that just joined become candidates.
        for (; joined < clusterVertices.size(); ++joined) {
            const uint32_t v = clusterVertices[joined];
            for (uint32_t i = 0; i < live[v]; ++i) {
                const uint32_t t = around[first[v] + i];
                if (listed[t] == kNone) {
                    listed[t] = uint32_t(candidates.size());
                    candidates.push_back({{centroids[3 * size_t(t)], centroids[3 * size_t(t) + 1], centroids[3 * size_t(t) + 2]}, t, 0});
                }
            }
        }
        // Only the triangles sharing a corner with this one change priority.
        for (int k = 0; k < 3; ++k) {
            const uint32_t v = corner[k];
            for (uint32_t i = 0; i < live[v]; ++i) {
                const uint32_t t = around[first[v] + i];
                const int priority = priority_of(t);
                candidates[listed[t]].priority = priority;
                if (priority == 0) closed.push_back(t);
            }
        }
        for (int k = 0; k < 3; ++k) sum[k] += centroids[3 * size_t(next) + k];
        if (++done == triangles) break;

        const float inverse = 3.0f / float(corners.size());
        for (int k = 0; k < 3; ++k) center[k] = sum[k] * inverse;
        next = kNone;
        if (corners.size() < 3 * maxTriangles)
            while (!closed.empty() && next == kNone) {
                if (!taken[closed.back()]) next = closed.back();
                closed.pop_back();
            }
        if (next == kNone) {
            next = best_candidate(true);
            // The nearest does not fit: the next cluster starts where the fewest triangles are left around.
            if (next != kNone && !fits(next)) next = best_candidate(false);
        }
        if (next == kNone) {  // nothing around the cluster is left: the nearest triangle anywhere
            if (!nearest) nearest = std::make_unique<NearestTriangle>(centroids, lo, hi, area);
            next = nearest->find(center, taken);
        }
    }
    if (!corners.empty()) clusters.push_back(std::move(corners));
    return clusters;
}

}  // namespace tessera
