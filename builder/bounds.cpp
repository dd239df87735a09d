// Per-cluster bounds the renderer culls with, derived from a built cluster's own triangles.
#include "tessera/builder.h"

#include <algorithm>
#include <array>
#include <cmath>

namespace tessera {

namespace {

// The positions of a cluster's triangle's three corners.
std::array<const float*, 3> triangle_corners(const BuiltMesh& mesh, const Cluster& cluster, uint32_t triangle) {
    const uint32_t packed = mesh.triangles[cluster.triangleOffset + triangle];
    std::array<const float*, 3> corners;
    for (int k = 0; k < 3; ++k) corners[k] = &mesh.positions[3 * size_t(cluster.vertexOffset + ((packed >> (8 * k)) & 0xffu))];
    return corners;
}

}  // namespace

// The cone's axis is the centre of a sphere around the triangles' unit normals (Ritter's: the widest of the three
// axis-extreme pairs as a first diameter, grown over every point), its cutoff the sine of the widest angle from it
// (the cone of view directions that see every triangle's back); in 8 bits rounded outwards, by the axis's rounding too,
// so that it still holds every normal. Only the cone: meshoptimizer's cluster bounds also fit a sphere around the
// corners and find a cone apex, which cost 2.5x more here and which the renderer does not use (it widens the test by the
// cluster's own sphere instead).
NormalCone cluster_normal_cone(const BuiltMesh& mesh, const Cluster& cluster) {
    float normals[kClusterMaxTriangles][3];
    size_t count = 0;
    for (uint32_t t = 0; t < cluster.triangleCount; ++t) {
        const std::array<const float*, 3> p = triangle_corners(mesh, cluster, t);
        const float e1[3] = {p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]};
        const float e2[3] = {p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]};
        const float n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        const float length = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (!(length > 0) || !std::isfinite(length)) continue;  // no area: never drawn, so no normal to hold
        for (int k = 0; k < 3; ++k) normals[count][k] = n[k] / length;
        ++count;
    }
    NormalCone cone;  // culls nothing
    if (count == 0) return cone;

    auto distance2 = [](const float* a, const float* b) {
        return (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]);
    };
    size_t lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    for (size_t i = 1; i < count; ++i)
        for (int k = 0; k < 3; ++k) {
            if (normals[i][k] < normals[lo[k]][k]) lo[k] = i;
            if (normals[i][k] > normals[hi[k]][k]) hi[k] = i;
        }
    int widest = 0;
    for (int k = 1; k < 3; ++k)
        if (distance2(normals[lo[k]], normals[hi[k]]) > distance2(normals[lo[widest]], normals[hi[widest]])) widest = k;
    const float* a = normals[lo[widest]];
    const float* b = normals[hi[widest]];
    float centre[3] = {(a[0] + b[0]) / 2, (a[1] + b[1]) / 2, (a[2] + b[2]) / 2};
    float radius = std::sqrt(distance2(a, b)) / 2;
    for (size_t i = 0; i < count; ++i) {
        const float d = std::sqrt(distance2(normals[i], centre));
        if (d <= radius) continue;
        const float keep = 0.5f + radius / d / 2;  // the new sphere touches the old one's far side and the point
        for (int k = 0; k < 3; ++k) centre[k] = centre[k] * keep + normals[i][k] * (1 - keep);
        radius = (radius + d) / 2;
    }
    const float length = std::sqrt(centre[0] * centre[0] + centre[1] * centre[1] + centre[2] * centre[2]);
    if (!(length > 0)) return cone;
    const float axis[3] = {centre[0] / length, centre[1] / length, centre[2] / length};
    float nearest = 1;  // cosine of the widest angle between a normal and the axis
    for (size_t i = 0; i < count; ++i) nearest = std::min(nearest, normals[i][0] * axis[0] + normals[i][1] * axis[1] + normals[i][2] * axis[2]);
    // Wider than about 168 degrees: a cone that culls next to nothing (and whose cutoff rounds badly near 1).
    if (nearest <= 0.1f) return cone;
    const float cutoff = std::sqrt(1 - nearest * nearest);
    float axisError = 0;
    for (int k = 0; k < 3; ++k) {
        cone.axis8[k] = int8_t(std::lround(axis[k] * 127));
        axisError += std::fabs(float(cone.axis8[k]) / 127 - axis[k]);
    }
    cone.cutoff8 = int8_t(std::min(127, int(127 * (cutoff + axisError)) + 1));  // rounded up
    return cone;
}

ClusterTriangleSizes cluster_triangle_sizes(const BuiltMesh& mesh, const Cluster& cluster) {
    double areaSum = 0, longest = 0;  // longest: squared
    // An edge's squared length, its difference taken in double (exact), so that the bound holds.
    auto squared = [](const float* a, const float* b) {
        const double dx = double(b[0]) - a[0], dy = double(b[1]) - a[1], dz = double(b[2]) - a[2];
        return dx * dx + dy * dy + dz * dz;
    };
    for (uint32_t t = 0; t < cluster.triangleCount; ++t) {
        const std::array<const float*, 3> p = triangle_corners(mesh, cluster, t);
        const double e1[3] = {p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]};
        const double e2[3] = {p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]};
        const double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2], cz = e1[0] * e2[1] - e1[1] * e2[0];
        areaSum += 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
        longest = std::max({longest, squared(p[0], p[1]), squared(p[1], p[2]), squared(p[2], p[0])});
    }
    return {float(areaSum / std::max(cluster.triangleCount, 1u)),
            std::nextafter(float(std::sqrt(longest)), INFINITY)};  // the edge never longer than its bound
}

}  // namespace tessera
