// Static displacement: dice a prepared mesh to about one height-map texel per edge and displace it, crack-free, before
// its DAG is built (builder.h bake_displacement).
#include "tessera/builder.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <unordered_map>

namespace tessera {

namespace {

using Key = std::array<uint32_t, 3>;  // a position's bits

struct KeyHash {
    size_t operator()(const Key& k) const { return (size_t(k[0]) * 73856093u) ^ (size_t(k[1]) * 19349663u) ^ (size_t(k[2]) * 83492791u); }
};

Key key_of(const float* p) {
    Key k;
    std::memcpy(k.data(), p, 12);
    return k;
}

struct Vec3 {
    double x = 0, y = 0, z = 0;
};

double length(const float* a, const float* b) {
    const double dx = double(a[0]) - b[0], dy = double(a[1]) - b[1], dz = double(a[2]) - b[2];
    return std::sqrt(dx * dx + dy * dy + dz * dz);
}

// One point of an edge, computed from the edge's lower end (by position bits) so that both triangles of the edge get
// the same bits: the point k / factor of the way from `a` to `b`.
void edge_point(const float* a, const float* b, uint32_t k, uint32_t factor, float* out) {
    const bool swap = std::memcmp(b, a, 12) < 0;
    const float* from = swap ? b : a;
    const float* to = swap ? a : b;
    const uint32_t steps = swap ? factor - k : k;
    const float t = float(steps) / float(factor);
    for (int c = 0; c < 3; ++c) out[c] = steps == 0 ? from[c] : steps == factor ? to[c] : from[c] + (to[c] - from[c]) * t;
}

}  // namespace

PreparedMesh bake_displacement(const PreparedMesh& mesh, const DisplacementBake& bake) {
    const size_t triangles = mesh.indices.size() / 3;
    const bool hasUvs = !mesh.uvs.empty(), hasColors = !mesh.colors.empty();
    const float* P = mesh.positions.data();
    // The segment length: one texel of the height map, over the mesh (its area against its UV area); a constant height
    // needs no dicing at all (the corners move, the faces stay flat).
    double segment = 0;
    if (bake.height && hasUvs && bake.texels > 0) {
        double area = 0, uvArea = 0;
        for (size_t t = 0; t < triangles; ++t) {
            const uint32_t* v = &mesh.indices[3 * t];
            const float *a = P + 3 * v[0], *b = P + 3 * v[1], *c = P + 3 * v[2];
            const double e1[3] = {double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]};
            const double e2[3] = {double(c[0]) - a[0], double(c[1]) - a[1], double(c[2]) - a[2]};
            const double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2], cz = e1[0] * e2[1] - e1[1] * e2[0];
            area += 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
            const float *ua = &mesh.uvs[2 * v[0]], *ub = &mesh.uvs[2 * v[1]], *uc = &mesh.uvs[2 * v[2]];
            uvArea += 0.5 * std::abs((double(ub[0]) - ua[0]) * (double(uc[1]) - ua[1]) - (double(uc[0]) - ua[0]) * (double(ub[1]) - ua[1]));
        }
        if (uvArea > 0 && area > 0) segment = std::sqrt(area / uvArea) / bake.texels;
    }
    auto factor_of = [&](const float* a, const float* b, double seg) -> uint32_t {
        if (!(seg > 0)) return 1;
        return uint32_t(std::clamp(std::ceil(length(a, b) / seg), 1.0, 64.0));
    };
    // Coarser segments until the result fits the budget, or no triangle is diced any more (a mesh of more triangles than
    // the budget: its corners move, and it is not diced; coarsening on looked for a fit that cannot come, for ever).
    for (;;) {
        uint64_t total = 0;
        for (size_t t = 0; t < triangles && segment > 0; ++t) {
            const uint32_t* v = &mesh.indices[3 * t];
            const uint32_t n = std::max({factor_of(P + 3 * v[0], P + 3 * v[1], segment), factor_of(P + 3 * v[1], P + 3 * v[2], segment),
                                         factor_of(P + 3 * v[2], P + 3 * v[0], segment)});
            total += uint64_t(n) * n;
        }
        if (total <= bake.maxTriangles || total <= triangles || !(segment > 0)) break;
        segment *= 1.25;
    }

    PreparedMesh out;
    out.constantColor = mesh.constantColor;
    out.hasConstantColor = mesh.hasConstantColor;
    out.warnings = mesh.warnings;
    // Each triangle's lattice points (weights on its corners), positions on shared edges computed from the edge alone.
    for (size_t t = 0; t < triangles; ++t) {
        const uint32_t* v = &mesh.indices[3 * t];
        const float* corner[3] = {P + 3 * v[0], P + 3 * v[1], P + 3 * v[2]};
        const uint32_t f[3] = {factor_of(corner[0], corner[1], segment), factor_of(corner[1], corner[2], segment), factor_of(corner[2], corner[0], segment)};
        const uint32_t n = std::max({f[0], f[1], f[2]});
        const uint32_t base = uint32_t(out.positions.size() / 3);
        for (uint32_t j = 0; j <= n; ++j)
            for (uint32_t i = 0; i + j <= n; ++i) {
                // Barycentric lattice point (n - i - j, i, j) / n; points on an edge move to that edge's own points.
                double w[3] = {double(n - i - j) / n, double(i) / n, double(j) / n};
                float p[3];
                int edge = -1;
                uint32_t k = 0;
                if (j == 0) edge = 0, k = uint32_t(std::lround(double(i) * f[0] / n));            // corner 0 -> 1
                else if (i + j == n) edge = 1, k = uint32_t(std::lround(double(j) * f[1] / n));   // corner 1 -> 2
                else if (i == 0) edge = 2, k = uint32_t(std::lround(double(n - j) * f[2] / n));   // corner 2 -> 0
                if (edge >= 0) {
                    const int a = edge, b = (edge + 1) % 3;
                    edge_point(corner[a], corner[b], k, f[edge], p);
                    w[0] = w[1] = w[2] = 0;
                    w[a] = double(f[edge] - k) / f[edge];
                    w[b] = double(k) / f[edge];
                } else {
                    for (int c = 0; c < 3; ++c) p[c] = float(w[0] * corner[0][c] + w[1] * corner[1][c] + w[2] * corner[2][c]);
                }
                out.positions.insert(out.positions.end(), p, p + 3);
                for (int c = 0; c < 3; ++c)
                    out.normals.push_back(float(w[0] * mesh.normals[3 * v[0] + c] + w[1] * mesh.normals[3 * v[1] + c] + w[2] * mesh.normals[3 * v[2] + c]));
                if (hasUvs)
                    for (int c = 0; c < 2; ++c) out.uvs.push_back(float(w[0] * mesh.uvs[2 * v[0] + c] + w[1] * mesh.uvs[2 * v[1] + c] + w[2] * mesh.uvs[2 * v[2] + c]));
                if (hasColors)
                    for (int c = 0; c < kChannelComponents; ++c)
                        out.colors.push_back(float(w[0] * mesh.colors[kChannelComponents * v[0] + c] + w[1] * mesh.colors[kChannelComponents * v[1] + c] +
                                                   w[2] * mesh.colors[kChannelComponents * v[2] + c]));
            }
        auto index = [&](uint32_t i, uint32_t j) { return base + j * (n + 1) - j * (j - 1) / 2 + i; };
        for (uint32_t j = 0; j < n; ++j)
            for (uint32_t i = 0; i + j < n; ++i) {
                const uint32_t cells[2][3] = {{index(i, j), index(i + 1, j), index(i, j + 1)}, {index(i + 1, j), index(i + 1, j + 1), index(i, j + 1)}};
                for (int c = 0; c < (i + j + 1 < n ? 2 : 1); ++c) {
                    const float *a = &out.positions[3 * cells[c][0]], *b = &out.positions[3 * cells[c][1]], *d = &out.positions[3 * cells[c][2]];
                    if (!std::memcmp(a, b, 12) || !std::memcmp(b, d, 12) || !std::memcmp(a, d, 12)) continue;  // collapsed by the edge's points
                    out.indices.insert(out.indices.end(), cells[c], cells[c] + 3);
                    if (!mesh.triangleMaterials.empty()) out.triangleMaterials.push_back(mesh.triangleMaterials[t]);
                    if (!mesh.sourceFaces.empty()) out.sourceFaces.push_back(mesh.sourceFaces[t]);
                }
            }
    }

    // Heights: the mean of what every point at a position reads (one value per position: seams agree), along the mean
    // normal there.
    const size_t points = out.positions.size() / 3;
    std::unordered_map<Key, std::pair<double, uint32_t>, KeyHash> heightAt;
    std::unordered_map<Key, Vec3, KeyHash> pointNormal;
    for (size_t p = 0; p < points; ++p) {
        const Key k = key_of(&out.positions[3 * p]);
        const double h = bake.height && hasUvs ? double(bake.height(out.uvs[2 * p], out.uvs[2 * p + 1])) : double(bake.constant);
        auto& [sum, count] = heightAt[k];
        sum += h;
        ++count;
        Vec3& n = pointNormal[k];
        n.x += out.normals[3 * p], n.y += out.normals[3 * p + 1], n.z += out.normals[3 * p + 2];
    }
    for (size_t p = 0; p < points; ++p) {
        const Key k = key_of(&out.positions[3 * p]);
        const auto& [sum, count] = heightAt[k];
        const double offset = (sum / count - bake.center) * bake.magnitude;
        const Vec3& n = pointNormal[k];
        const double len = std::sqrt(n.x * n.x + n.y * n.y + n.z * n.z);
        if (!(len > 0) || !std::isfinite(offset)) continue;
        out.positions[3 * p] = float(out.positions[3 * p] + n.x / len * offset);
        out.positions[3 * p + 1] = float(out.positions[3 * p + 1] + n.y / len * offset);
        out.positions[3 * p + 2] = float(out.positions[3 * p + 2] + n.z / len * offset);
    }
    // Normals of the displaced surface: area-weighted face normals, summed per position (smooth across the dicing).
    std::unordered_map<Key, Vec3, KeyHash> faceNormalAt;
    for (size_t t = 0; t < out.indices.size() / 3; ++t) {
        const float *a = &out.positions[3 * out.indices[3 * t]], *b = &out.positions[3 * out.indices[3 * t + 1]],
                    *c = &out.positions[3 * out.indices[3 * t + 2]];
        const double e1[3] = {double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]};
        const double e2[3] = {double(c[0]) - a[0], double(c[1]) - a[1], double(c[2]) - a[2]};
        const Vec3 face{e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        for (int corner = 0; corner < 3; ++corner) {
            Vec3& n = faceNormalAt[key_of(&out.positions[3 * out.indices[3 * t + corner]])];
            n.x += face.x, n.y += face.y, n.z += face.z;
        }
    }
    for (size_t p = 0; p < points; ++p) {
        const Vec3& n = faceNormalAt[key_of(&out.positions[3 * p])];
        const double len = std::sqrt(n.x * n.x + n.y * n.y + n.z * n.z);
        if (len > 0) {
            out.normals[3 * p + 0] = float(n.x / len);
            out.normals[3 * p + 1] = float(n.y / len);
            out.normals[3 * p + 2] = float(n.z / len);
        }
    }
    return out;
}

}  // namespace tessera
