// Clustering: spatially compact clusters of at most 128 triangles over at most 256 local vertices.
// This is level 0 of the cluster DAG; grouping and simplification build on it.
#include "tessera/builder.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>

namespace tessera {
namespace {

uint32_t spread_bits(uint32_t v) {  // 10 bits -> every third bit of 30
    v &= 0x3ff;
    v = (v | (v << 16)) & 0x030000ff;
    v = (v | (v << 8)) & 0x0300f00f;
    v = (v | (v << 4)) & 0x030c30c3;
    v = (v | (v << 2)) & 0x09249249;
    return v;
}

// Smallest sphere centred on the box centre that holds the points: simple, and tight for compact clusters.
std::array<float, 4> bounding_sphere(const float* positions, const std::vector<uint32_t>& vertices) {
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t v : vertices)
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], positions[3 * v + k]);
            hi[k] = std::max(hi[k], positions[3 * v + k]);
        }
    const float c[3] = {(lo[0] + hi[0]) * 0.5f, (lo[1] + hi[1]) * 0.5f, (lo[2] + hi[2]) * 0.5f};
    float r2 = 0;
    for (uint32_t v : vertices) {
        float d2 = 0;
        for (int k = 0; k < 3; ++k) d2 += (positions[3 * v + k] - c[k]) * (positions[3 * v + k] - c[k]);
        r2 = std::max(r2, d2);
    }
    // Widen by a few ulps so float rounding never leaves a vertex outside.
    const float r = std::sqrt(r2) * (1.0f + 1e-6f) + 1e-30f;
    return {c[0], c[1], c[2], r};
}

}  // namespace

uint32_t encode_octahedral(float x, float y, float z) {
    const float l1 = std::fabs(x) + std::fabs(y) + std::fabs(z);
    float u = x / l1, v = y / l1;
    if (z < 0) {
        const float pu = (1 - std::fabs(v)) * (u >= 0 ? 1.0f : -1.0f);
        const float pv = (1 - std::fabs(u)) * (v >= 0 ? 1.0f : -1.0f);
        u = pu;
        v = pv;
    }
    auto snorm = [](float f) { return uint32_t(uint16_t(int16_t(std::lround(std::clamp(f, -1.0f, 1.0f) * 32767.0f)))); };
    return snorm(u) | (snorm(v) << 16);
}

std::array<float, 3> decode_octahedral(uint32_t packed) {
    auto unorm = [](uint32_t bits) { return std::max(float(int16_t(uint16_t(bits))) / 32767.0f, -1.0f); };
    float u = unorm(packed & 0xffff), v = unorm(packed >> 16);
    const float z = 1 - std::fabs(u) - std::fabs(v);
    if (z < 0) {
        const float pu = (1 - std::fabs(v)) * (u >= 0 ? 1.0f : -1.0f);
        const float pv = (1 - std::fabs(u)) * (v >= 0 ? 1.0f : -1.0f);
        u = pu;
        v = pv;
    }
    const float len = std::sqrt(u * u + v * v + z * z);
    return {u / len, v / len, z / len};
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

BuiltMesh build_clusters(const PreparedMesh& mesh) {
    BuiltMesh out;
    const size_t vertexCount = mesh.positions.size() / 3;
    const size_t triangleCount = mesh.indices.size() / 3;
    out.sourceTriangles = triangleCount;
    out.constantColor = mesh.constantColor;
    out.hasConstantColor = mesh.hasConstantColor;

    // Recentre in double so that large authored coordinates lose no more precision than they already have.
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t v = 0; v < vertexCount; ++v)
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], double(mesh.positions[3 * v + k]));
            hi[k] = std::max(hi[k], double(mesh.positions[3 * v + k]));
        }
    for (int k = 0; k < 3; ++k) out.origin[k] = (lo[k] + hi[k]) * 0.5;
    std::vector<float> local(3 * vertexCount);
    for (size_t v = 0; v < vertexCount; ++v)
        for (int k = 0; k < 3; ++k) local[3 * v + k] = float(double(mesh.positions[3 * v + k]) - out.origin[k]);

    // Morton order of triangle centroids keeps consecutive triangles close together.
    const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-30});
    std::vector<uint32_t> code(triangleCount);
    for (size_t t = 0; t < triangleCount; ++t) {
        uint32_t cell[3];
        for (int k = 0; k < 3; ++k) {
            double c = 0;
            for (int j = 0; j < 3; ++j) c += mesh.positions[3 * mesh.indices[3 * t + j] + k];
            c = (c / 3.0 - lo[k]) / extent;
            cell[k] = uint32_t(std::clamp(c * 1023.0, 0.0, 1023.0));
        }
        code[t] = spread_bits(cell[0]) | (spread_bits(cell[1]) << 1) | (spread_bits(cell[2]) << 2);
    }
    std::vector<uint32_t> order(triangleCount);
    std::iota(order.begin(), order.end(), 0u);
    std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return code[a] < code[b]; });

    // Greedy fill: a cluster closes when the next triangle would exceed its triangle or vertex budget.
    std::vector<uint32_t> localIndex(vertexCount, 0), stamp(vertexCount, UINT32_MAX);
    std::vector<uint32_t> clusterVertices, clusterTriangles;
    auto flush = [&]() {
        if (clusterTriangles.empty()) return;
        Cluster cluster{};
        cluster.sphere = bounding_sphere(local.data(), clusterVertices);
        cluster.vertexOffset = uint32_t(out.positions.size() / 3);
        cluster.vertexCount = uint32_t(clusterVertices.size());
        cluster.triangleOffset = uint32_t(out.triangles.size());
        cluster.triangleCount = uint32_t(clusterTriangles.size() / 3);
        for (uint32_t v : clusterVertices) {
            out.positions.insert(out.positions.end(), &local[3 * v], &local[3 * v] + 3);
            out.normals.push_back(encode_octahedral(mesh.normals[3 * v], mesh.normals[3 * v + 1], mesh.normals[3 * v + 2]));
            if (!mesh.colors.empty()) {
                const float* c = &mesh.colors[3 * v];
                out.colors.push_back(float_to_half(c[0]) | (uint32_t(float_to_half(c[1])) << 16));
                out.colors.push_back(float_to_half(c[2]) | (uint32_t(float_to_half(1.0f)) << 16));
            }
        }
        for (size_t i = 0; i < clusterTriangles.size(); i += 3)
            out.triangles.push_back(clusterTriangles[i] | (clusterTriangles[i + 1] << 8) | (clusterTriangles[i + 2] << 16));
        out.clusters.push_back(cluster);
        clusterVertices.clear();
        clusterTriangles.clear();
    };
    for (uint32_t t : order) {
        const uint32_t clusterId = uint32_t(out.clusters.size());
        uint32_t fresh = 0;
        for (int j = 0; j < 3; ++j) fresh += stamp[mesh.indices[3 * t + j]] != clusterId;
        if (clusterTriangles.size() / 3 == kClusterMaxTriangles || clusterVertices.size() + fresh > kClusterMaxVertices) flush();
        const uint32_t id = uint32_t(out.clusters.size());
        for (int j = 0; j < 3; ++j) {
            const uint32_t v = mesh.indices[3 * t + j];
            if (stamp[v] != id) {
                stamp[v] = id;
                localIndex[v] = uint32_t(clusterVertices.size());
                clusterVertices.push_back(v);
            }
            clusterTriangles.push_back(localIndex[v]);
        }
    }
    flush();

    std::vector<uint32_t> all(vertexCount);
    std::iota(all.begin(), all.end(), 0u);
    out.sphere = bounding_sphere(local.data(), all);
    return out;
}

}  // namespace tessera
