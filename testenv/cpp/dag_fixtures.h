// Meshes and DAG checks shared by the DAG and build-settings suites: generators (icosphere, grid, quad soup, OBJ),
// the monotone-bounds check, and crack-free random cuts under the runtime rule.
#pragma once

#include "tessera/builder.h"

#include <gtest/gtest.h>

#include "test_meshes.h"

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <sstream>

namespace dagtest {

using namespace tessera;

struct Source {
    std::string name;
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    std::vector<float> colors;  // uniform (per face) when set
    std::vector<float> pointColors;  // vertex (per point) when set
    std::vector<float> normals; // uniform (per face) when set: flat shading
    std::vector<float> uvs;     // face-varying (per corner) when set
    std::vector<int32_t> faceMaterials;  // material slot per face when set
    BuiltMesh build(const BuildSettings& settings = {}) const {
        MeshView v = polygon_view(name, points, counts, indices);
        if (!colors.empty()) v.displayColor = {Interpolation::Uniform, 3, colors, {}};
        if (!pointColors.empty()) v.displayColor = {Interpolation::Vertex, 3, pointColors, {}};
        if (!normals.empty()) v.normals = {Interpolation::Uniform, 3, normals, {}};
        if (!uvs.empty()) v.uvs = {Interpolation::FaceVarying, 2, uvs, {}};
        v.faceMaterials = faceMaterials;
        return build_mesh(prepare_mesh(v), settings);
    }
};

inline Source icosphere(int level, double scale = 1.0, double offset = 0.0) {
    const double t = (1.0 + std::sqrt(5.0)) / 2.0;
    std::vector<std::array<double, 3>> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                                            {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    std::vector<std::array<int, 3>> f = {{0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                                         {11, 10, 2}, {10, 7, 6}, {7, 1, 8}, {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8},
                                         {3, 8, 9}, {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};
    for (int l = 0; l < level; ++l) {
        std::map<std::pair<int, int>, int> mid;
        auto midpoint = [&](int a, int b) {
            auto key = std::minmax(a, b);
            auto it = mid.find(key);
            if (it != mid.end()) return it->second;
            v.push_back({(v[a][0] + v[b][0]) / 2, (v[a][1] + v[b][1]) / 2, (v[a][2] + v[b][2]) / 2});
            return mid[key] = int(v.size() - 1);
        };
        std::vector<std::array<int, 3>> next;
        for (auto& tri : f) {
            int ab = midpoint(tri[0], tri[1]), bc = midpoint(tri[1], tri[2]), ca = midpoint(tri[2], tri[0]);
            next.insert(next.end(), {{tri[0], ab, ca}, {tri[1], bc, ab}, {tri[2], ca, bc}, {ab, bc, ca}});
        }
        f = next;
    }
    Source s;
    s.name = "/Icosphere";
    std::mt19937 rng(1);
    std::uniform_real_distribution<double> bump(0.97, 1.03);
    for (auto& p : v) {
        const double len = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) / bump(rng);
        for (int k = 0; k < 3; ++k) s.points.push_back(float(offset + scale * p[k] / len));
    }
    for (auto& tri : f) {
        s.counts.push_back(3);
        s.indices.insert(s.indices.end(), tri.begin(), tri.end());
    }
    return s;
}

// Flat shading: each face's own normal, authored per face. On a surface rougher than the grid weld's 30 degrees
// (an icosphere whose vertices are moved in and out by up to `roughness` of the radius) nearly every position is then
// a vertex of several wedges whose normals differ: hard edges everywhere.
inline Source flat_shaded(Source s, double roughness) {
    s.name += "FlatShaded";
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> bump(1.0 - roughness, 1.0 + roughness);
    for (size_t i = 0; i < s.points.size(); i += 3) {
        const double r = bump(rng);
        for (int k = 0; k < 3; ++k) s.points[i + k] = float(s.points[i + k] * r);
    }
    for (size_t f = 0; f < s.indices.size(); f += 3) {
        const float* a = &s.points[3 * s.indices[f]];
        const float* b = &s.points[3 * s.indices[f + 1]];
        const float* c = &s.points[3 * s.indices[f + 2]];
        const double e1[3] = {double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]};
        const double e2[3] = {double(c[0]) - a[0], double(c[1]) - a[1], double(c[2]) - a[2]};
        const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (int k = 0; k < 3; ++k) s.normals.push_back(float(n[k] / len));
    }
    return s;
}

// Spherical texture coordinates about the origin, per corner, with the seam where u wraps from 1 to 0.
inline Source with_spherical_uvs(Source s) {
    s.name += "WithUvs";
    s.uvs.clear();
    size_t corner = 0;
    for (int32_t count : s.counts) {
        std::vector<float> face;
        for (int32_t c = 0; c < count; ++c) {
            const float* p = &s.points[3 * s.indices[corner + c]];
            const double r = std::sqrt(double(p[0]) * p[0] + double(p[1]) * p[1] + double(p[2]) * p[2]);
            face.push_back(float(std::atan2(p[2], p[0]) / (2 * M_PI) + 0.5));
            face.push_back(float(std::acos(std::clamp(p[1] / r, -1.0, 1.0)) / M_PI));
        }
        float lo = 1, hi = 0;
        for (size_t i = 0; i < face.size(); i += 2) lo = std::min(lo, face[i]), hi = std::max(hi, face[i]);
        if (hi - lo > 0.5f)
            for (size_t i = 0; i < face.size(); i += 2)
                if (face[i] < 0.5f) face[i] += 1.0f;
        s.uvs.insert(s.uvs.end(), face.begin(), face.end());
        corner += size_t(count);
    }
    return s;
}

inline Source grid(int n, bool checkerColors = false, bool fins = false) {
    Source s;
    s.name = "/Grid";
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) s.points.insert(s.points.end(), {float(x) / n, float(y) / n, 0.02f * std::sin(x * 0.7f) * std::cos(y * 0.5f)});
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            const int a = y * (n + 1) + x;
            s.counts.push_back(4);
            s.indices.insert(s.indices.end(), {a, a + 1, a + n + 2, a + n + 1});
            if (checkerColors) s.colors.insert(s.colors.end(), {float((x / 4 + y / 4) % 2), 0.5f, 0.2f});
        }
    if (fins) {  // non-manifold: fins standing on interior grid edges (three faces share each edge)
        for (int x = 2; x < n - 2; x += 3) {
            const int y = n / 2, a = y * (n + 1) + x, b = a + 1;
            const int top = int(s.points.size() / 3);
            s.points.insert(s.points.end(), {float(x) / n, float(y) / n, 0.2f, float(x + 1) / n, float(y) / n, 0.2f});
            s.counts.push_back(4);
            s.indices.insert(s.indices.end(), {a, b, top + 1, top});
            if (checkerColors) s.colors.insert(s.colors.end(), {1, 1, 1});
        }
    }
    return s;
}

// A bumpy latitude-longitude sphere of n x 2n quads, mapped as modelling packages map one: texture coordinates per
// face corner, u along the azimuth and v along the polar angle, a seam where u wraps, and at a pole each face its own
// u. `weldedPoles`: each pole is one point; else a pole is 2n points whose radius follows the azimuth (as the bench's
// displaced sphere has them). `grid`: positions rounded to multiples of it (0: not), so that a libm's last bit cannot
// move them.
inline Source lat_long_sphere(int n, bool weldedPoles, double grid = 0) {
    Source s;
    s.name = "/LatLong";
    auto round = [&](double x) { return float(grid > 0 ? std::round(x / grid) * grid : x); };
    std::vector<int> pointAt((n + 1) * 2 * n);
    for (int i = 0; i <= n; ++i)
        for (int j = 0; j < 2 * n; ++j) {
            const bool pole = i == 0 || i == n;
            if (pole && weldedPoles && j > 0) {
                pointAt[i * 2 * n + j] = pointAt[i * 2 * n];
                continue;
            }
            const double theta = M_PI * i / n, phi = M_PI * j / n;
            const double r = 1.0 + 0.03 * std::sin(5 * theta) * std::cos(7 * phi) + (weldedPoles ? 0.0 : 0.004 * std::cos(3 * phi));
            pointAt[i * 2 * n + j] = int(s.points.size() / 3);
            s.points.insert(s.points.end(), {round(r * std::sin(theta) * std::cos(phi)), round(r * std::sin(theta) * std::sin(phi)), round(r * std::cos(theta))});
        }
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < 2 * n; ++j) {
            const int corners[4][2] = {{i, j}, {i + 1, j}, {i + 1, j + 1}, {i, j + 1}};
            s.counts.push_back(4);
            for (const auto& c : corners) {
                s.indices.push_back(pointAt[c[0] * 2 * n + c[1] % (2 * n)]);
                s.uvs.insert(s.uvs.end(), {float(c[1]) / float(2 * n), float(c[0]) / float(n)});
            }
        }
    return s;
}

inline Source quad_soup(int count) {  // foliage-like: disjoint small quads
    Source s;
    s.name = "/Soup";
    std::mt19937 rng(9);
    std::uniform_real_distribution<float> u(0, 1);
    for (int i = 0; i < count; ++i) {
        const float x = u(rng) * 10, y = u(rng) * 10, z = u(rng) * 10, a = u(rng) * 6.28f;
        const float dx = 0.05f * std::cos(a), dz = 0.05f * std::sin(a);
        const int base = int(s.points.size() / 3);
        s.points.insert(s.points.end(), {x - dx, y, z - dz, x + dx, y, z + dz, x + dx, y + 0.1f, z + dz, x - dx, y + 0.1f, z - dz});
        s.counts.push_back(4);
        s.indices.insert(s.indices.end(), {base, base + 1, base + 2, base + 3});
    }
    return s;
}

inline Source obj(const std::filesystem::path& path) {
    Source s;
    s.name = path.filename().string();
    std::ifstream in(path);
    std::string line;
    while (std::getline(in, line)) {
        std::istringstream ls(line);
        std::string tag;
        ls >> tag;
        if (tag == "v") {
            float x, y, z;
            ls >> x >> y >> z;
            s.points.insert(s.points.end(), {x, y, z});
        } else if (tag == "f") {
            std::string corner;
            int n = 0;
            while (ls >> corner) {
                s.indices.push_back(std::stoi(corner.substr(0, corner.find('/'))) - 1);
                ++n;
            }
            s.counts.push_back(n);
        }
    }
    return s;
}

inline std::filesystem::path shared_asset(const char* relative) {
    return std::filesystem::path(__FILE__).parent_path().parent_path().parent_path().parent_path() / "shared" / "assets" / relative;
}

inline double distance3(const std::array<float, 4>& a, const std::array<float, 4>& b) {
    return std::sqrt(double(a[0] - b[0]) * (a[0] - b[0]) + double(a[1] - b[1]) * (a[1] - b[1]) + double(a[2] - b[2]) * (a[2] - b[2]));
}

inline void expect_monotone(const BuiltMesh& m) {
    size_t roots = 0;
    for (const Cluster& c : m.clusters) {
        if (std::isinf(c.parentError)) {
            ++roots;
            continue;
        }
        EXPECT_GE(c.parentError, c.lodError) << "parent error below its child's";
        EXPECT_LE(distance3(c.parentSphere, c.lodSphere) + c.lodSphere[3], double(c.parentSphere[3]) * (1 + 1e-6))
            << "parent sphere does not contain its child's";
    }
    EXPECT_GE(roots, 1u);
}

// The DAG's roots (clusters without a parent): how many, and their triangles.
inline std::pair<size_t, size_t> root_clusters(const BuiltMesh& m) {
    size_t roots = 0, triangles = 0;
    for (const Cluster& c : m.clusters)
        if (std::isinf(c.parentError)) ++roots, triangles += c.triangleCount;
    return {roots, triangles};
}

// Position of a cluster-local vertex, as exact bits (vertices shared across clusters must match bit for bit).
inline std::array<uint32_t, 3> position_bits(const BuiltMesh& m, const Cluster& c, uint32_t local) {
    std::array<uint32_t, 3> bits;
    std::memcpy(bits.data(), &m.positions[3 * (c.vertexOffset + local)], 12);
    return bits;
}

using Edge = std::pair<std::array<uint32_t, 3>, std::array<uint32_t, 3>>;

inline std::map<Edge, int> edge_uses(const BuiltMesh& m, const std::vector<uint32_t>& clusters) {
    std::map<Edge, int> uses;
    for (uint32_t ci : clusters) {
        const Cluster& c = m.clusters[ci];
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            const uint32_t packed = m.triangles[c.triangleOffset + t];
            std::array<uint32_t, 3> corner;
            for (int k = 0; k < 3; ++k) corner[k] = (packed >> (8 * k)) & 0xff;
            for (int k = 0; k < 3; ++k) {
                auto a = position_bits(m, c, corner[k]), b = position_bits(m, c, corner[(k + 1) % 3]);
                if (a == b) continue;
                ++uses[std::minmax(a, b)];
            }
        }
    }
    return uses;
}

// The runtime rule: draw a cluster iff its projected LOD error fits the threshold and its parent's does not.
inline double projected(float error, const std::array<float, 4>& sphere, const std::array<double, 3>& eye) {
    const double d = std::sqrt((sphere[0] - eye[0]) * (sphere[0] - eye[0]) + (sphere[1] - eye[1]) * (sphere[1] - eye[1]) +
                               (sphere[2] - eye[2]) * (sphere[2] - eye[2])) - sphere[3];
    return std::isinf(error) ? INFINITY : error / std::max(d, 1e-12);
}

inline void expect_crack_free_cuts(const BuiltMesh& m, int cuts = 40) {
    ASSERT_GT(m.clusters.size(), m.leafClusters + 1) << "the DAG has levels above the source";
    std::vector<uint32_t> leaves;
    for (uint32_t i = 0; i < m.leafClusters; ++i) leaves.push_back(i);
    const auto sourceEdges = edge_uses(m, leaves);
    // Positions an open edge may join: those on the leaves' own open boundary, and those no leaf has (open borders that
    // Preserve Area moved outward). Without Preserve Area every position of every level is a leaf position.
    std::set<std::array<uint32_t, 3>> sourceBorder, leafPositions;
    for (auto& [edge, n] : sourceEdges) {
        leafPositions.insert(edge.first);
        leafPositions.insert(edge.second);
        if (n == 1) {
            sourceBorder.insert(edge.first);
            sourceBorder.insert(edge.second);
        }
    }
    for (const Cluster& c : m.clusters)
        for (uint32_t v = 0; v < c.vertexCount; ++v)
            if (!leafPositions.count(position_bits(m, c, v))) sourceBorder.insert(position_bits(m, c, v));
    std::mt19937 rng(4);
    std::uniform_real_distribution<double> u(0, 1);
    int mixed = 0;
    for (int cut = 0; cut < cuts; ++cut) {
        const double theta = u(rng) * 6.283, phi = std::acos(2 * u(rng) - 1), dist = m.size * (0.05 + 2 * u(rng));
        const std::array<double, 3> eye{dist * std::sin(phi) * std::cos(theta), dist * std::sin(phi) * std::sin(theta), dist * std::cos(phi)};
        // A threshold near some cluster's projected error from here, so the cut lands between levels.
        const Cluster& probe = m.clusters[m.leafClusters + size_t(u(rng) * (m.clusters.size() - m.leafClusters - 1))];
        const double threshold = projected(probe.lodError, probe.lodSphere, eye) * (0.5 + u(rng));
        std::vector<uint32_t> chosen;
        std::set<uint32_t> levels;
        for (uint32_t i = 0; i < m.clusters.size(); ++i) {
            const Cluster& c = m.clusters[i];
            if (projected(c.lodError, c.lodSphere, eye) <= threshold && projected(c.parentError, c.parentSphere, eye) > threshold) {
                chosen.push_back(i);
                levels.insert(c.level);
            }
        }
        ASSERT_FALSE(chosen.empty());
        mixed += levels.size() > 1;
        for (auto& [edge, n] : edge_uses(m, chosen)) {
            if (n != 1) continue;
            ASSERT_TRUE(sourceBorder.count(edge.first) && sourceBorder.count(edge.second))
                << "cut " << cut << " (threshold " << threshold << ", levels " << levels.size() << ") has an open edge inside the surface";
        }
    }
    EXPECT_GT(mixed, 0) << "some cuts should mix levels, or the test proves little";
}

// The point of triangle abc nearest to p, as barycentric weights (of a, b, c); returns the squared distance. By
// projecting onto the triangle's plane, else onto the nearest of its edges (the test's own, not the builder's code).
inline double nearest_on_triangle(const float* p, const float* a, const float* b, const float* c, double w[3]) {
    auto sub = [](const float* x, const float* y) { return std::array<double, 3>{double(x[0]) - y[0], double(x[1]) - y[1], double(x[2]) - y[2]}; };
    auto dot = [](const std::array<double, 3>& x, const std::array<double, 3>& y) { return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]; };
    const auto e0 = sub(b, a), e1 = sub(c, a), d = sub(p, a);
    const double a00 = dot(e0, e0), a01 = dot(e0, e1), a11 = dot(e1, e1), b0 = dot(e0, d), b1 = dot(e1, d);
    const double det = a00 * a11 - a01 * a01;
    double best = INFINITY;
    auto consider = [&](double u, double v) {  // weights of b and c
        std::array<double, 3> q;
        for (int k = 0; k < 3; ++k) q[k] = d[k] - u * e0[k] - v * e1[k];
        const double dist = dot(q, q);
        if (dist < best) {
            best = dist;
            w[0] = 1 - u - v;
            w[1] = u;
            w[2] = v;
        }
    };
    if (det > 0) {
        const double u = (a11 * b0 - a01 * b1) / det, v = (a00 * b1 - a01 * b0) / det;
        if (u >= 0 && v >= 0 && u + v <= 1) consider(u, v);
    }
    auto clamp01 = [](double x) { return std::min(1.0, std::max(0.0, x)); };
    if (a00 > 0) consider(clamp01(b0 / a00), 0);  // edge ab
    if (a11 > 0) consider(0, clamp01(b1 / a11));  // edge ac
    const auto e2 = sub(c, b), dp = sub(p, b);
    if (dot(e2, e2) > 0) {  // edge bc
        const double t = clamp01(dot(e2, dp) / dot(e2, e2));
        consider(1 - t, t);
    }
    consider(0, 0);
    return best;
}

}  // namespace dagtest
