// Vertex attribute encodings shared with the shaders' decoders (octahedral normals, half floats), and the
// bookkeeping shared by the DAG builder and the page codec (cluster statistics, the order clusters are stored in).
#include "tessera/builder.h"

#include <meshoptimizer.h>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace tessera {

void append_cluster(BuiltMesh& mesh, const Cluster& c) {
    if (c.level == 0) {
        ++mesh.leafClusters;
        mesh.leafVertices = c.vertexOffset + c.vertexCount;
        mesh.leafTriangles = c.triangleOffset + c.triangleCount;
    }
    if (mesh.levels.size() <= c.level) mesh.levels.resize(c.level + 1);
    LevelStats& level = mesh.levels[c.level];
    ++level.clusters;
    level.triangles += c.triangleCount;
    level.maxError = std::max(level.maxError, c.lodError);
    mesh.clusters.push_back(c);
}

namespace {

constexpr int32_t kNormalMax = (1 << (kNormalBits - 1)) - 1;  // octahedral coordinates are -kNormalMax..kNormalMax

// The octahedral square's point for a unit vector (folded below the equator).
std::array<float, 2> to_octahedral_square(float x, float y, float z) {
    const float l1 = std::fabs(x) + std::fabs(y) + std::fabs(z);
    float u = x / l1, v = y / l1;
    if (z < 0) {
        const float pu = (1 - std::fabs(v)) * (u >= 0 ? 1.0f : -1.0f);
        const float pv = (1 - std::fabs(u)) * (v >= 0 ? 1.0f : -1.0f);
        u = pu;
        v = pv;
    }
    return {u, v};
}

// q * to / from, rounded to nearest (no halves: `from` is odd).
int32_t rescale(int32_t q, int32_t to, int32_t from) {
    const int64_t magnitude = (2 * int64_t(std::abs(q)) * to + from) / (2 * int64_t(from));
    return int32_t(q < 0 ? -magnitude : magnitude);
}

uint32_t snorm16_of_bits(int32_t q) {
    static const auto table = [] {  // every normal the builder emits goes through here
        std::array<uint16_t, 2 * kNormalMax + 1> t{};
        for (int32_t b = -kNormalMax; b <= kNormalMax; ++b) t[b + kNormalMax] = uint16_t(int16_t(rescale(b, 32767, kNormalMax)));
        return t;
    }();
    return table[std::clamp(q, -kNormalMax, kNormalMax) + kNormalMax];
}

// The direction an snorm16x2 octahedral value stands for, not yet normalized (the shaders' decoder too).
std::array<float, 3> octahedral_direction(uint32_t packed) {
    auto unorm = [](uint32_t bits) { return std::max(float(int16_t(uint16_t(bits))) / 32767.0f, -1.0f); };
    float u = unorm(packed & 0xffff), v = unorm(packed >> 16);
    const float z = 1 - std::fabs(u) - std::fabs(v);
    if (z < 0) {
        const float pu = (1 - std::fabs(v)) * (u >= 0 ? 1.0f : -1.0f);
        const float pv = (1 - std::fabs(u)) * (v >= 0 ? 1.0f : -1.0f);
        u = pu;
        v = pv;
    }
    return {u, v, z};
}

}  // namespace

uint32_t encode_octahedral(float x, float y, float z) {
    // Of the four grid points around the exact one, the one whose decoded direction is nearest: a third less
    // error than rounding each coordinate.
    if (!(std::fabs(x) + std::fabs(y) + std::fabs(z) > 0)) return octahedral_from_bits(0, 0);  // no direction: +Z
    const auto [u, v] = to_octahedral_square(x, y, z);
    const float lu = std::floor(std::clamp(u, -1.0f, 1.0f) * kNormalMax), lv = std::floor(std::clamp(v, -1.0f, 1.0f) * kNormalMax);
    uint32_t best = 0;
    float bestScore = -INFINITY;
    for (int du = 0; du < 2; ++du)
        for (int dv = 0; dv < 2; ++dv) {
            const int32_t qu = std::min(int32_t(lu) + du, kNormalMax), qv = std::min(int32_t(lv) + dv, kNormalMax);
            const uint32_t packed = octahedral_from_bits(qu, qv);
            const auto d = octahedral_direction(packed);
            const float dot = d[0] * x + d[1] * y + d[2] * z;
            const float score = dot * std::fabs(dot) / (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);  // cos^2, signed: no sqrt
            if (score > bestScore) {
                bestScore = score;
                best = packed;
            }
        }
    return best;
}

uint32_t octahedral_from_bits(int32_t u, int32_t v) { return snorm16_of_bits(u) | (snorm16_of_bits(v) << 16); }

std::array<int32_t, 2> octahedral_to_bits(uint32_t packed) {
    auto bits = [](uint32_t snorm) { return rescale(int16_t(uint16_t(snorm)), kNormalMax, 32767); };
    return {bits(packed & 0xffff), bits(packed >> 16)};
}

std::array<float, 3> decode_octahedral(uint32_t packed) {
    const auto [u, v, z] = octahedral_direction(packed);
    const float len = std::sqrt(u * u + v * v + z * z);
    return {u / len, v / len, z / len};
}

namespace {

// A strip-like walk over a cluster's triangles: each next triangle shares an edge with the last one where it can
// (the index codec stores such a triangle in about a byte, and the vertex codec predicts its new corner across that
// edge), else with one of the last few (whose edges the codec still remembers), else the walk starts afresh on the
// unvisited region's border. Among candidates the one with the fewest unvisited neighbours goes first (walking along
// the border leaves no islands behind). Linear in the triangles: meshoptimizer's vertex cache optimizer, used before,
// cost a tenth of the build for clusters this small and gave 1.7 % more bytes. Clusters have at most 256 vertices
// and 128 triangles.
void order_triangles_as_strips(const uint32_t* corners, size_t triangleCount, uint32_t* out) {
    // The triangle on each directed edge (a 256 x 256 table, cleared through the cells set).
    thread_local std::vector<uint16_t> edgeTriangle(256 * 256, 0);
    constexpr uint32_t kNone = UINT32_MAX;
    std::vector<uint32_t> neighbours(3 * triangleCount, kNone);  // across edge k (corner k to k + 1)
    auto key = [&](size_t t, int k) { return corners[3 * t + k] << 8 | corners[3 * t + (k + 1) % 3]; };
    for (size_t t = 0; t < triangleCount; ++t)
        for (int k = 0; k < 3; ++k) edgeTriangle[key(t, k)] = uint16_t(t + 1);
    for (size_t t = 0; t < triangleCount; ++t)
        for (int k = 0; k < 3; ++k) {
            const uint32_t reverse = corners[3 * t + (k + 1) % 3] << 8 | corners[3 * t + k];
            if (edgeTriangle[reverse]) neighbours[3 * t + k] = edgeTriangle[reverse] - 1u;
        }
    for (size_t t = 0; t < triangleCount; ++t)
        for (int k = 0; k < 3; ++k) edgeTriangle[key(t, k)] = 0;
    std::vector<uint8_t> done(triangleCount, 0);
    std::vector<uint32_t> order(triangleCount);
    auto open_neighbours = [&](uint32_t t) {
        int count = 0;
        for (int k = 0; k < 3; ++k) count += neighbours[3 * t + k] != kNone && !done[neighbours[3 * t + k]];
        return count;
    };
    // The best unvisited neighbour of triangle t: the one with the fewest unvisited neighbours of its own.
    auto best_neighbour = [&](uint32_t t, uint32_t& next, int& nextScore) {
        for (int k = 0; k < 3; ++k) {
            const uint32_t candidate = neighbours[3 * t + k];
            if (candidate == kNone || done[candidate]) continue;
            const int score = open_neighbours(candidate);
            if (score < nextScore) next = candidate, nextScore = score;
        }
    };
    constexpr size_t kLookBack = 8;  // a restart first looks for a neighbour of the last few triangles (still in the codec's edge FIFO)
    size_t restartFrom = 0;
    for (size_t emitted = 0; emitted < triangleCount; ++emitted) {
        uint32_t next = kNone;
        int nextScore = 4;
        for (size_t back = 1; back <= std::min(emitted, kLookBack) && next == kNone; ++back)
            best_neighbour(order[emitted - back], next, nextScore);
        if (next == kNone) {  // a fresh start: the first unvisited triangle on the unvisited region's border
            while (done[restartFrom]) ++restartFrom;
            for (size_t t = restartFrom; t < triangleCount && nextScore > 1; ++t) {
                if (done[t]) continue;
                const int score = open_neighbours(uint32_t(t));
                if (score < nextScore) next = uint32_t(t), nextScore = score;
            }
        }
        done[next] = 1;
        order[emitted] = next;
        std::copy_n(&corners[3 * next], 3, &out[3 * emitted]);
    }
}

}  // namespace

std::vector<uint32_t> order_cluster_for_pages(std::vector<uint32_t>& corners, uint32_t vertexCount) {
    std::vector<uint32_t> ordered(corners.size()), oldToNew(vertexCount, UINT32_MAX), newToOld;
    if (vertexCount > kClusterMaxVertices || corners.size() > 3 * size_t(kClusterMaxTriangles))
        throw std::invalid_argument("a cluster has more vertices or triangles than the page format allows");
    order_triangles_as_strips(corners.data(), corners.size() / 3, ordered.data());
    newToOld.reserve(vertexCount);
    for (size_t i = 0; i < ordered.size(); ++i) {  // numbered by first use
        uint32_t& number = oldToNew[ordered[i]];
        if (number == UINT32_MAX) {
            number = uint32_t(newToOld.size());
            newToOld.push_back(ordered[i]);
        }
        corners[i] = number;
    }
    if (newToOld.size() != vertexCount) throw std::invalid_argument("a cluster has vertices that no triangle uses");
    for (size_t i = 0; i < corners.size(); i += 3) rotate_smallest_first(&corners[i]);
    return newToOld;
}

uint16_t float_to_half(float value) {
    uint32_t bits;
    std::memcpy(&bits, &value, 4);
    const uint32_t sign = (bits >> 16) & 0x8000;
    const int32_t exponent = int32_t((bits >> 23) & 0xff) - 127 + 15;
    uint32_t mantissa = bits & 0x7fffff;
    if (((bits >> 23) & 0xff) == 0xff) return uint16_t(sign | 0x7c00 | (mantissa ? 0x200 : 0));  // inf / nan
    if (exponent >= 31) return uint16_t(sign | 0x7c00);
    if (exponent <= 0) {
        if (exponent < -10) return uint16_t(sign);
        mantissa |= 0x800000;
        const uint32_t shift = uint32_t(14 - exponent);
        uint32_t half = mantissa >> shift;
        if ((mantissa >> (shift - 1)) & 1) ++half;  // round half up
        return uint16_t(sign | half);
    }
    uint32_t half = sign | (uint32_t(exponent) << 10) | (mantissa >> 13);
    if (mantissa & 0x1000) ++half;  // round half up (may carry into the exponent, which is correct)
    return uint16_t(half);
}

float half_to_float(uint16_t h) {
    const uint32_t sign = uint32_t(h & 0x8000u) << 16, exponent = (h >> 10) & 0x1fu, mantissa = h & 0x3ffu;
    float magnitude;
    if (exponent == 0) magnitude = std::ldexp(float(mantissa), -24);
    else if (exponent == 31) magnitude = mantissa ? NAN : INFINITY;
    else magnitude = std::ldexp(float(mantissa | 0x400u), int(exponent) - 25);
    uint32_t bits;
    std::memcpy(&bits, &magnitude, 4);
    bits |= sign;
    std::memcpy(&magnitude, &bits, 4);
    return magnitude;
}

}  // namespace tessera
