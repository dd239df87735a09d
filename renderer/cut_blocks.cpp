#include "cut_blocks.h"

#include "tessera/morton.h"

#include <algorithm>
#include <array>
#include <cmath>

namespace tessera {
namespace {

using Sphere = std::array<double, 4>;

Sphere sphere_of(const gpu::vec4& s) { return {s.x, s.y, s.z, s.w}; }

// A sphere enclosing the given ones (the centre of their box, then the farthest reach), widened by a relative hair:
// the GPU transforms its centre in float, not the clusters' own, and a block must never leave out a cluster the
// per-cluster test would keep.
gpu::vec4 enclosing(const std::vector<Sphere>& spheres) {
    if (spheres.empty()) return {0, 0, 0, 0};
    std::array<double, 3> lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
    for (const Sphere& s : spheres)
        for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], s[k] - s[3]), hi[k] = std::max(hi[k], s[k] + s[3]);
    const std::array<double, 3> c{(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2};
    double radius = 0;
    for (const Sphere& s : spheres)
        radius = std::max(radius, std::sqrt((s[0] - c[0]) * (s[0] - c[0]) + (s[1] - c[1]) * (s[1] - c[1]) + (s[2] - c[2]) * (s[2] - c[2])) + s[3]);
    const double magnitude = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    return {float(c[0]), float(c[1]), float(c[2]), float(radius + 1e-5 * (radius + magnitude))};
}

}  // namespace

void append_cut_blocks(const gpu::GpuCluster* clusters, uint32_t count, uint32_t firstInMesh, std::vector<gpu::GpuCutBlock>& blocks,
                       std::vector<uint32_t>& blockClusters) {
    // Morton codes of the culling spheres' centres, on a 1024^3 grid over the cube around them.
    auto centre = [&](size_t i, float* p) {
        p[0] = clusters[i].sphere.x;
        p[1] = clusters[i].sphere.y;
        p[2] = clusters[i].sphere.z;
    };
    float lo[3];
    const float extent = morton_cube(count, centre, lo);
    std::vector<std::pair<uint32_t, uint32_t>> order(count);  // (code, cluster in level)
    for (uint32_t i = 0; i < count; ++i) {
        float p[3];
        centre(i, p);
        order[i] = {morton_code(p, lo, extent), i};
    }
    std::sort(order.begin(), order.end());  // ties by index: the same blocks every time

    std::vector<Sphere> spheres, lodSpheres, parentSpheres;
    for (uint32_t first = 0; first < count; first += TS_CUT_BLOCK_SIZE) {
        const uint32_t size = std::min<uint32_t>(TS_CUT_BLOCK_SIZE, count - first);
        gpu::GpuCutBlock block{};
        block.minLodError = INFINITY;
        block.maxParentError = 0;
        block.firstCluster = uint32_t(blockClusters.size());
        block.clusterCount = size;
        spheres.clear(), lodSpheres.clear(), parentSpheres.clear();
        for (uint32_t k = first; k < first + size; ++k) {
            const gpu::GpuCluster& c = clusters[order[k].second];
            blockClusters.push_back(firstInMesh + order[k].second);
            spheres.push_back(sphere_of(c.sphere));
            lodSpheres.push_back(sphere_of(c.lodSphere));
            block.minLodError = std::min(block.minLodError, c.lodError);
            block.maxParentError = std::max(block.maxParentError, c.parentError);
            if (c.parentError < TS_ROOT_ERROR) parentSpheres.push_back(sphere_of(c.parentSphere));
        }
        block.sphere = enclosing(spheres);
        block.lodSphere = enclosing(lodSpheres);
        block.parentSphere = enclosing(parentSpheres);
        blocks.push_back(block);
    }
}

}  // namespace tessera
