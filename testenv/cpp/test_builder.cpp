// Builder: validation, triangulation, seams, clusters, encodings.
#include "tessera/builder.h"

#include <gtest/gtest.h>

#include "test_meshes.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <map>
#include <set>

using namespace tessera;

namespace {
struct Quad {  // a unit quad in the XY plane, facing +Z when wound counter-clockwise
    std::vector<float> points{0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
    std::vector<int32_t> counts{4};
    std::vector<int32_t> indices{0, 1, 2, 3};
    MeshView view(const char* name = "/Quad") {
        MeshView v = polygon_view(name, points, counts, indices);
        return v;
    }
};

std::array<float, 3> triangle_normal(const PreparedMesh& m, size_t t) {
    auto p = [&](size_t c) { const float* q = &m.positions[3 * m.indices[3 * t + c]]; return std::array<float, 3>{q[0], q[1], q[2]}; };
    auto a = p(0), b = p(1), c = p(2);
    float e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    return {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
}
}  // namespace

TEST(Prepare, FanTriangulatesPolygons) {
    Quad q;
    PreparedMesh m = prepare_mesh(q.view());
    ASSERT_EQ(m.indices.size(), 6u);
    EXPECT_EQ(m.sourceFaces, (std::vector<uint32_t>{0, 0}));
    for (size_t t = 0; t < 2; ++t) EXPECT_GT(triangle_normal(m, t)[2], 0.0f);
    EXPECT_TRUE(m.warnings.empty());
}

TEST(Prepare, LeftHandedReversesWinding) {
    Quad q;
    q.indices = {0, 3, 2, 1};  // the same quad listed clockwise
    MeshView v = q.view();
    v.leftHanded = true;
    PreparedMesh m = prepare_mesh(v);
    ASSERT_EQ(m.indices.size(), 6u);
    for (size_t t = 0; t < 2; ++t) EXPECT_GT(triangle_normal(m, t)[2], 0.0f) << "leftHanded faces must come out front-facing";
    EXPECT_GT(m.normals[2], 0.99f);
}

TEST(Prepare, HolesAreNotDrawn) {
    Quad q;
    q.points.insert(q.points.end(), {2, 0, 0, 2, 1, 0});
    q.counts = {4, 4};
    q.indices = {0, 1, 2, 3, 1, 4, 5, 2};
    std::vector<int32_t> holes{0};
    MeshView v = q.view();
    v.holeIndices = holes;
    PreparedMesh m = prepare_mesh(v);
    EXPECT_EQ(m.indices.size(), 6u);
    EXPECT_EQ(m.sourceFaces, (std::vector<uint32_t>{1, 1}));
}

TEST(Prepare, BadFacesAreDroppedWithAWarningNamingTheMesh) {
    Quad q;
    q.points.insert(q.points.end(), {NAN, 0, 0});
    q.counts = {4, 3, 2, 3};
    q.indices = {0, 1, 2, 3, 0, 1, 99, 0, 1, 0, 1, 4};
    PreparedMesh m = prepare_mesh(q.view("/World/Broken"));
    EXPECT_EQ(m.indices.size(), 6u);
    ASSERT_FALSE(m.warnings.empty());
    EXPECT_NE(m.warnings[0].find("/World/Broken"), std::string::npos);
    EXPECT_NE(m.warnings[0].find("dropped 3 invalid face"), std::string::npos) << m.warnings[0];
}

TEST(Prepare, UnusableMeshThrowsNamingTheProblem) {
    Quad q;
    q.indices = {0, 1, 2};  // counts say 4
    try {
        prepare_mesh(q.view("/World/Short"));
        FAIL() << "expected MeshError";
    } catch (const MeshError& e) {
        EXPECT_NE(std::string(e.what()).find("/World/Short"), std::string::npos);
        EXPECT_NE(std::string(e.what()).find("sum to 4"), std::string::npos);
    }
    Quad all;
    all.indices = {0, 1, 2, 7};
    EXPECT_THROW(prepare_mesh(all.view()), MeshError);
}

// The builder's float arithmetic holds meshes up to kMaxMeshExtent across. A larger one is refused, naming the mesh,
// rather than built into clusters of nothing: a flat 47 x 47 grid 2e21 units across crashed the build (its
// triangles' areas overflow, and the clusters made of them were none). Points no face uses do not count; a mesh
// too small for float areas is refused with the reason.
TEST(Prepare, MeshesBeyondTheFloatRangeAreRefusedNamingTheMesh) {
    auto grid = [](int n, double spacing, std::vector<float>& points, std::vector<int32_t>& counts, std::vector<int32_t>& indices) {
        quad_grid(n, [&](int x, int y) { return std::array<double, 3>{spacing * x, spacing * y, 0.0}; }, [](int, int, int, int) {}, points, counts, indices);
    };
    auto message = [](const MeshView& view) -> std::string {
        try {
            build_mesh(prepare_mesh(view));
        } catch (const MeshError& e) {
            return e.what();
        }
        return "";
    };
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    grid(47, 4.33e19, points, counts, indices);
    const std::string huge = message(polygon_view("/World/Galaxy", points, counts, indices));
    EXPECT_NE(huge.find("/World/Galaxy"), std::string::npos) << huge;
    EXPECT_NE(huge.find("spans 2.04e+21 units"), std::string::npos) << huge;
    EXPECT_NE(huge.find("2^31"), std::string::npos) << huge;

    // Just inside the limit, and with an unused point far outside it: built, its clusters cover the grid.
    points.clear(), counts.clear(), indices.clear();
    grid(16, kMaxMeshExtent / 16, points, counts, indices);
    points.insert(points.end(), {1e30f, 0, 0});
    EXPECT_EQ(message(polygon_view("/World/Planet", points, counts, indices)), "");
    const BuiltMesh planet = build_mesh(prepare_mesh(polygon_view("/World/Planet", points, counts, indices)));
    uint64_t leafTriangles = 0;
    for (const Cluster& c : planet.clusters) {
        EXPECT_TRUE(std::isfinite(c.sphere[3]) && std::isfinite(c.lodSphere[3]) && std::isfinite(c.lodError));
        if (c.level == 0) leafTriangles += c.triangleCount;
    }
    EXPECT_EQ(leafTriangles, 2u * 16 * 16);
    points.back() = 0;
    points[3 * (17 * 17 - 1)] *= 1.01f;  // a used point pushes it over
    EXPECT_NE(message(polygon_view("/World/Planet", points, counts, indices)).find("/World/Planet: spans"), std::string::npos);

    points.clear(), counts.clear(), indices.clear();
    grid(8, 1e-30, points, counts, indices);
    EXPECT_EQ(message(polygon_view("/World/Speck", points, counts, indices)), "/World/Speck: no drawable faces (every triangle has no area at float precision)");
}

// Texture coordinates are stored on one grid per mesh, as fine as their largest allows: one value far out of place
// (1e30 among coordinates in [0, 1], from a broken export) made the grid 2^78 wide, and every coordinate of the mesh 0,
// without a word. That is now a warning naming the mesh; coordinates of tiling textures (up to 1000 or so) are not.
TEST(Prepare, TextureCoordinatesFarOutOfPlaceAreNamed) {
    Quad q;
    std::vector<float> uvs = {0, 0, 1, 0, 1, 1, 0, 1};
    auto warnings_with = [&](float last) {
        uvs.back() = last;
        MeshView view = q.view("/World/Odd");
        view.uvs = {Interpolation::FaceVarying, 2, uvs, {}};
        std::string all;
        for (const std::string& w : prepare_mesh(view).warnings) all += w + "\n";
        return all;
    };
    EXPECT_EQ(warnings_with(1), "");
    EXPECT_EQ(warnings_with(1000), "") << "a tiling texture's coordinates";
    const std::string odd = warnings_with(1e30f);
    EXPECT_NE(odd.find("/World/Odd: texture coordinates reach 1e+30: they are stored on a grid of 2^78 texture widths"), std::string::npos) << odd;
    EXPECT_EQ(uv_grid_precision(1.0f), -16);
    EXPECT_EQ(uv_grid_precision(1e30f), 78);
}

TEST(Prepare, FaceVaryingSeamsSplitVertices) {
    Quad q;  // two quads sharing an edge, with a colour seam along it
    q.points = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 2, 0, 0, 2, 1, 0};
    q.counts = {4, 4};
    q.indices = {0, 1, 2, 3, 1, 4, 5, 2};
    std::vector<float> colors{1, 0, 0, 0, 0, 1};
    MeshView v = q.view();
    v.displayColor = {Interpolation::Uniform, 3, colors, {}};
    PreparedMesh m = prepare_mesh(v);
    EXPECT_EQ(m.positions.size() / 3, 8u) << "the two shared points are split by the colour seam";
    ASSERT_EQ(m.colors.size(), 32u);  // 4 per vertex: alpha 1
    // Vertex-interpolated colours need no split.
    std::vector<float> perPoint(18, 0.5f);
    v.displayColor = {Interpolation::Vertex, 3, perPoint, {}};
    EXPECT_EQ(prepare_mesh(v).positions.size() / 3, 6u);
    // A primvar too short for its interpolation is ignored with a warning, not a crash.
    std::vector<float> tooShort{1, 0, 0};
    v.displayColor = {Interpolation::FaceVarying, 3, tooShort, {}};
    PreparedMesh ignored = prepare_mesh(v);
    EXPECT_TRUE(ignored.colors.empty());
    EXPECT_FALSE(ignored.warnings.empty());
}

namespace {
// A grid of n x n quads with jittered heights.
struct Grid {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    explicit Grid(int n, double offset = 0.0) {
        std::mt19937 rng(7);
        std::uniform_real_distribution<float> jitter(-0.01f, 0.01f);
        for (int y = 0; y <= n; ++y)
            for (int x = 0; x <= n; ++x) points.insert(points.end(), {float(offset + x), float(y), jitter(rng)});
        for (int y = 0; y < n; ++y)
            for (int x = 0; x < n; ++x) {
                counts.push_back(4);
                const int a = y * (n + 1) + x;
                indices.insert(indices.end(), {a, a + 1, a + n + 2, a + n + 1});
            }
    }
    MeshView view() {
        MeshView v = polygon_view("/Grid", points, counts, indices);
        return v;
    }
};
}  // namespace

TEST(Clusters, RespectBudgetsAndCoverEveryTriangle) {
    Grid g(100);
    BuiltMesh b = build_mesh(prepare_mesh(g.view()));
    EXPECT_EQ(b.sourceTriangles, 20000u);
    size_t triangles = 0, leaves = 0;
    for (const Cluster& c : b.clusters) {
        EXPECT_LE(c.triangleCount, kClusterMaxTriangles);
        EXPECT_LE(c.vertexCount, kClusterMaxVertices);
        if (c.level == 0) {
            triangles += c.triangleCount;
            ++leaves;
        }
        // Every vertex of the cluster lies inside its sphere.
        for (uint32_t v = c.vertexOffset; v < c.vertexOffset + c.vertexCount; ++v) {
            float d2 = 0;
            for (int k = 0; k < 3; ++k) d2 += std::pow(b.positions[3 * v + k] - c.sphere[k], 2.0f);
            EXPECT_LE(std::sqrt(d2), c.sphere[3]);
        }
        for (uint32_t t = c.triangleOffset; t < c.triangleOffset + c.triangleCount; ++t)
            for (int k = 0; k < 3; ++k) EXPECT_LT((b.triangles[t] >> (8 * k)) & 0xff, c.vertexCount);
    }
    EXPECT_EQ(triangles, 20000u) << "level 0 holds every source triangle";
    EXPECT_EQ(leaves, b.leafClusters);
    EXPECT_GE(double(triangles) / leaves, 110.0) << "clusters of a regular grid should be nearly full";
}

TEST(Clusters, FarFromOriginKeepsPrecisionInTheOrigin) {
    Grid g(10, 1.0e6);
    BuiltMesh b = build_mesh(prepare_mesh(g.view()));
    EXPECT_NEAR(b.origin[0], 1.0e6 + 5.0, 1e-9);
    for (size_t i = 0; i < b.positions.size(); i += 3) EXPECT_LE(std::fabs(b.positions[i]), 5.0f + 1e-6f);
}

TEST(Clusters, DeterministicOutput) {
    Grid g(40);
    BuiltMesh a = build_mesh(prepare_mesh(g.view())), b = build_mesh(prepare_mesh(g.view()));
    EXPECT_EQ(a.positions, b.positions);
    EXPECT_EQ(a.triangles, b.triangles);
    EXPECT_EQ(a.normals, b.normals);
}

TEST(Encoding, OctahedralNormalsStayWithinTheStatedBound) {
    std::mt19937 rng(3);
    std::normal_distribution<float> d;
    const float minimumCosine = std::cos(kNormalMaxErrorDegrees * 3.14159265f / 180.0f);
    for (int i = 0; i < 200000; ++i) {
        float n[3] = {d(rng), d(rng), d(rng)};
        const float len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (float& x : n) x /= len;
        const uint32_t packed = encode_octahedral(n[0], n[1], n[2]);
        const auto r = decode_octahedral(packed);
        ASSERT_GT(double(r[0]) * n[0] + double(r[1]) * n[1] + double(r[2]) * n[2], minimumCosine);
        const auto bits = octahedral_to_bits(packed);  // what the page file stores gives the same normal back
        ASSERT_EQ(octahedral_from_bits(bits[0], bits[1]), packed);
    }
}

TEST(Encoding, HalfFloat) {
    EXPECT_EQ(float_to_half(1.0f), 0x3c00);
    EXPECT_EQ(float_to_half(0.5f), 0x3800);
    EXPECT_EQ(float_to_half(-2.0f), 0xc000);
    EXPECT_EQ(float_to_half(0.0f), 0x0000);
    EXPECT_EQ(float_to_half(1e6f), 0x7c00);
}

TEST(Prepare, DuplicatePositionsWeldUnlessTheirValuesDiffer) {
    // Two quads side by side, authored with separate points along the shared edge (as exporters often do).
    std::vector<float> points{0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 1, 0, 0, 2, 0, 0, 2, 1, 0, 1, 1, 0};
    std::vector<int32_t> counts{4, 4}, indices{0, 1, 2, 3, 4, 5, 6, 7};
    MeshView v = polygon_view("/Split", points, counts, indices);
    EXPECT_EQ(prepare_mesh(v).positions.size() / 3, 6u) << "exact duplicate positions weld";
    // Per-point normals that differ across the shared edge make it a hard edge: the weld must keep the seam.
    std::vector<float> normals{0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0};
    v.normals = {Interpolation::Vertex, 3, normals, {}};
    PreparedMesh seam = prepare_mesh(v);
    EXPECT_EQ(seam.positions.size() / 3, 8u) << "differing per-point normals keep the split";
    // Equal per-point values weld again.
    std::vector<float> flat(24);
    for (size_t i = 0; i < 8; ++i) flat[3 * i + 2] = 1;
    v.normals = {Interpolation::Vertex, 3, flat, {}};
    EXPECT_EQ(prepare_mesh(v).positions.size() / 3, 6u);
}

// A mesh of more than 2^16 vertices comes out of preparation with its vertices numbered along the surface (the build
// reads its per-vertex arrays in that order), whatever order its points and faces were authored in; every triangle
// keeps its face's corners, values included, and the faces' order.
TEST(Prepare, LargeMeshVerticesAreNumberedAlongTheSurface) {
    constexpr int n = 300;  // (n + 1)^2 = 90 601 points
    std::vector<int> pointAt((n + 1) * (n + 1));
    for (size_t i = 0; i < pointAt.size(); ++i) pointAt[i] = int(i);
    std::mt19937 random(3);
    std::shuffle(pointAt.begin(), pointAt.end(), random);  // grid point -> its number in the authored arrays
    std::vector<float> points(3 * pointAt.size()), colors(3 * pointAt.size()), uvs(2 * pointAt.size());
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) {
            const int p = pointAt[y * (n + 1) + x];
            const float u = float(x) / n, w = float(y) / n;
            std::copy_n(std::array<float, 3>{u, w, 0.1f * std::sin(9 * u) * std::cos(7 * w)}.data(), 3, &points[3 * p]);
            std::copy_n(std::array<float, 3>{u, w, 1 - u}.data(), 3, &colors[3 * p]);
            std::copy_n(std::array<float, 2>{u, w}.data(), 2, &uvs[2 * p]);
        }
    std::vector<int> faceOrder(n * n);
    for (size_t f = 0; f < faceOrder.size(); ++f) faceOrder[f] = int(f);
    std::shuffle(faceOrder.begin(), faceOrder.end(), random);
    std::vector<int32_t> counts(n * n, 4), indices;
    for (int f : faceOrder) {
        const int x = f % n, y = f / n;
        for (int corner : {y * (n + 1) + x, y * (n + 1) + x + 1, (y + 1) * (n + 1) + x + 1, (y + 1) * (n + 1) + x}) indices.push_back(pointAt[corner]);
    }
    MeshView v = polygon_view("/Scattered", points, counts, indices);
    v.displayColor = {Interpolation::Vertex, 3, colors, {}};
    v.uvs = {Interpolation::Vertex, 2, uvs, {}};
    const PreparedMesh m = prepare_mesh(v);
    ASSERT_EQ(m.positions.size() / 3, pointAt.size());
    ASSERT_EQ(m.indices.size(), size_t(6 * n * n));
    for (size_t t = 0; t < m.indices.size() / 3; ++t) {
        const uint32_t face = m.sourceFaces[t];
        ASSERT_EQ(face, t / 2) << "triangles keep the faces' order";
        const int fan[2][3] = {{0, 1, 2}, {0, 2, 3}};
        for (int k = 0; k < 3; ++k) {
            const uint32_t vertex = m.indices[3 * t + k];
            const int32_t point = indices[4 * face + fan[t % 2][k]];
            for (int c = 0; c < 3; ++c) ASSERT_EQ(m.positions[3 * vertex + c], points[3 * point + c]);
            for (int c = 0; c < 3; ++c) ASSERT_EQ(m.colors[4 * vertex + c], colors[3 * point + c]);
            for (int c = 0; c < 2; ++c) ASSERT_EQ(m.uvs[2 * vertex + c], uvs[2 * point + c]);
        }
    }
    // Consecutive vertices lie near each other: on average within a few grid steps (authored, they were a third of the
    // grid apart).
    auto mean_step = [](const float* p, size_t count) {
        double sum = 0;
        for (size_t i = 1; i < count; ++i) sum += std::hypot(p[3 * i] - p[3 * i - 3], p[3 * i + 1] - p[3 * i - 2]);
        return sum / double(count - 1);
    };
    EXPECT_GT(mean_step(points.data(), pointAt.size()), 0.3);
    EXPECT_LT(mean_step(m.positions.data(), pointAt.size()), 4.0 / n);
}

// A mesh whose primvars all vary per point (or not at all) makes a vertex of each point its triangles use; any other
// a vertex of each point and attribute values a corner has (a seam splits a point). Both then number their vertices
// by first use and, past 2^16, in spatial order. The same surface must give the same mesh either way, bit for bit,
// with the same warnings: here with its normals authored per point, and per corner (the same values). The mesh has
// what triangulation treats apart: holes, invalid faces (too few corners, an index out of range, a non-finite point),
// welded duplicate points, faces with collapsed corners, triangles and pentagons among its quads, unused points (far
// off: they must not widen the box the spatial order is taken in), normals too short to use (the smooth fallback),
// left-handed winding and faces in a scattered order. Also a mesh that uses few of its many points (numbered by first
// use only), and one with no drawable face (the same error).
TEST(Prepare, VerticesPerPointMatchVerticesPerCorner) {
    constexpr int n = 300;  // (n + 1)^2 = 90 601 grid points
    const int gridPoints = (n + 1) * (n + 1);
    std::mt19937 random(11);
    std::vector<float> points, normals, colors, uvs;
    auto add_point = [&](std::array<float, 3> p, std::array<float, 3> normal, float u, float w) {
        points.insert(points.end(), p.begin(), p.end());
        normals.insert(normals.end(), normal.begin(), normal.end());
        colors.insert(colors.end(), {u, w, 1 - u});
        uvs.insert(uvs.end(), {u, w});
    };
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) {
            const float u = float(x) / n, w = float(y) / n;
            const bool bad = (x * 7 + y * 13) % 29 == 0;  // zero length: the smooth normal instead
            add_point({u, w, 0.1f * std::sin(9 * u) * std::cos(7 * w)}, bad ? std::array<float, 3>{0, 0, 0} : std::array<float, 3>{0.1f * u, 0.2f, 1}, u, w);
        }
    std::vector<std::vector<int32_t>> faces;
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            const int a = y * (n + 1) + x;
            faces.push_back({a, a + 1, a + n + 2, a + n + 1});
        }
    // Duplicates of grid points (welded to them) used by some faces instead.
    for (int k = 0; k < 500; ++k) {
        const int original = int(random() % uint32_t(gridPoints)), copy = int(points.size() / 3);
        add_point({points[3 * original], points[3 * original + 1], points[3 * original + 2]},
                  {normals[3 * original], normals[3 * original + 1], normals[3 * original + 2]}, colors[3 * original], colors[3 * original + 1]);
        for (auto& face : faces)
            if (face[0] == original) face[0] = copy;
        faces.push_back({original, copy, (original + 1) % gridPoints});  // two corners weld to one point: dropped
    }
    for (int k = 0; k < 200; ++k) {  // triangles and pentagons over the grid
        const int a = int(random() % uint32_t(gridPoints - n - 3));
        faces.push_back({a, a + 1, a + n + 2});
        faces.push_back({a, a + 1, a + 2, a + n + 3, a + n + 1});
    }
    const int nanPoint = int(points.size() / 3);
    add_point({NAN, 0, 0}, {0, 0, 1}, 0, 0);
    faces.push_back({0, 1});                      // too few corners
    faces.push_back({0, 1, gridPoints * 10});     // an index out of range
    faces.push_back({0, 1, nanPoint});            // a non-finite point
    for (int k = 0; k < 1000; ++k) add_point({1000.0f + float(k), -500, 7}, {0, 1, 0}, 0, 0);  // used by no face
    std::shuffle(faces.begin(), faces.end(), random);
    std::vector<int32_t> counts, indices, holes;
    for (size_t f = 0; f < faces.size(); ++f) {
        counts.push_back(int32_t(faces[f].size()));
        indices.insert(indices.end(), faces[f].begin(), faces[f].end());
        if (f % 997 == 5) holes.push_back(int32_t(f));
    }
    std::vector<float> cornerNormals;
    for (int32_t p : indices)
        for (int k = 0; k < 3; ++k) cornerNormals.push_back(p >= 0 && size_t(p) < points.size() / 3 ? normals[3 * p + k] : 0.0f);

    auto both_paths = [&](const std::vector<int32_t>& faceCounts, const std::vector<int32_t>& faceIndices, const std::vector<float>& perCorner,
                          size_t expectVertices) {
        MeshView perPoint = polygon_view("/Big", points, faceCounts, faceIndices);
        perPoint.leftHanded = true;
        perPoint.holeIndices = holes;
        perPoint.displayColor = {Interpolation::Vertex, 3, colors, {}};
        perPoint.uvs = {Interpolation::Vertex, 2, uvs, {}};
        perPoint.normals = {Interpolation::Vertex, 3, normals, {}};
        MeshView general = perPoint;
        general.normals = {Interpolation::FaceVarying, 3, perCorner, {}};
        const PreparedMesh a = prepare_mesh(perPoint), b = prepare_mesh(general);
        EXPECT_EQ(a.positions.size() / 3, expectVertices);
        EXPECT_EQ(a.positions, b.positions);
        EXPECT_EQ(a.normals, b.normals);
        EXPECT_EQ(a.colors, b.colors);
        EXPECT_EQ(a.uvs, b.uvs);
        EXPECT_EQ(a.indices, b.indices);
        EXPECT_EQ(a.sourceFaces, b.sourceFaces);
        EXPECT_EQ(a.warnings, b.warnings);
        return a;
    };
    const PreparedMesh big = both_paths(counts, indices, cornerNormals, size_t(gridPoints));
    ASSERT_EQ(big.warnings.size(), 2u);
    EXPECT_NE(big.warnings[0].find("dropped 3 invalid face(s)"), std::string::npos) << big.warnings[0];
    EXPECT_NE(big.warnings[1].find("1 point(s) are NaN"), std::string::npos) << big.warnings[1];
    bool smoothUsed = false;  // some vertex took its smooth normal (not the authored 0.1u, 0.2, 1 direction)
    for (size_t v = 0; v < big.normals.size() / 3; ++v) smoothUsed |= std::abs(big.normals[3 * v + 1] * 5 - big.normals[3 * v + 2]) > 1e-3f;
    EXPECT_TRUE(smoothUsed);

    // The faces of one corner of the grid: a few thousand of its points used.
    std::vector<int32_t> fewCounts, fewIndices;
    std::vector<float> fewCorners;
    for (size_t f = 0, at = 0; f < counts.size(); at += size_t(counts[f]), ++f) {
        bool near = true;
        for (size_t c = at; c < at + size_t(counts[f]); ++c) near &= indices[c] >= 0 && indices[c] < gridPoints && indices[c] % (n + 1) < 40 && indices[c] / (n + 1) < 40;
        if (!near) continue;
        fewCounts.push_back(counts[f]);
        fewIndices.insert(fewIndices.end(), indices.begin() + at, indices.begin() + at + counts[f]);
        fewCorners.insert(fewCorners.end(), cornerNormals.begin() + 3 * at, cornerNormals.begin() + 3 * (at + counts[f]));
    }
    both_paths(fewCounts, fewIndices, fewCorners, 40 * 40);

    // No drawable face: the same error on both paths.
    const std::vector<int32_t> badCounts{3, 2}, badIndices{0, 1, gridPoints * 10, 4, 5};
    const std::vector<float> badCorners(3 * badIndices.size(), 1.0f);
    std::string errors[2];
    for (int path = 0; path < 2; ++path) {
        MeshView v = polygon_view("/Big", points, badCounts, badIndices);
        if (path) v.normals = {Interpolation::FaceVarying, 3, badCorners, {}};
        try {
            prepare_mesh(v);
        } catch (const MeshError& e) {
            errors[path] = e.what();
        }
    }
    EXPECT_NE(errors[0].find("no drawable faces (every face is invalid: "), std::string::npos) << errors[0];
    EXPECT_EQ(errors[0], errors[1]);
}

namespace {
// A cube cage from -1 to 1, refined `level` times with `scheme` (none: as authored).
MeshView cube_cage(std::vector<float>& points, std::vector<int32_t>& counts, std::vector<int32_t>& indices,
                   SubdivisionScheme scheme = SubdivisionScheme::None, int level = 0) {
    points = {-1, -1, 1, 1, -1, 1, -1, 1, 1, 1, 1, 1, -1, 1, -1, 1, 1, -1, -1, -1, -1, 1, -1, -1};
    counts = {4, 4, 4, 4, 4, 4};
    indices = {0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4};
    MeshView v = polygon_view("/Cage", points, counts, indices);
    v.subdivisionScheme = scheme;
    v.refineLevel = level;
    return v;
}
}  // namespace

// The vertex channel with 4 components (primvar readers packed by the scene delegate): carried per vertex through
// refinement (vertex and uniform interpolation alike) and through the DAG into rgba16f, the fourth component included.
TEST(Subdivision, AFourComponentVertexChannelIsRefinedWhole) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    MeshView v = cube_cage(points, counts, indices, SubdivisionScheme::CatmullClark, 1);
    std::vector<float> perPoint;
    for (int p = 0; p < 8; ++p) perPoint.insert(perPoint.end(), {1, 0, 0, float(p) / 7});  // fourth: 0 to 1 by point
    v.displayColor = {Interpolation::Vertex, 4, perPoint, {}};
    PreparedMesh m = prepare_mesh(v);
    ASSERT_EQ(m.colors.size(), 4 * (m.positions.size() / 3));
    float lo = 1, hi = 0;
    for (size_t i = 0; i < m.colors.size(); i += 4) {
        EXPECT_EQ(m.colors[i], 1.0f);
        lo = std::min(lo, m.colors[i + 3]);
        hi = std::max(hi, m.colors[i + 3]);
    }
    EXPECT_TRUE(lo >= 0 && hi <= 1 && hi - lo > 0.5f) << lo << " " << hi << ": the fourth component varies, within its range";
    std::vector<float> perFace;
    for (int f = 0; f < 6; ++f) perFace.insert(perFace.end(), {0, 1, 0, float(f) / 5});
    v.displayColor = {Interpolation::Uniform, 4, perFace, {}};
    PreparedMesh uniform = prepare_mesh(v);
    std::set<float> fourth;
    for (size_t i = 3; i < uniform.colors.size(); i += 4) fourth.insert(uniform.colors[i]);
    EXPECT_EQ(fourth.size(), 6u) << "each refined face keeps its cage face's value";
    BuiltMesh built = build_mesh(uniform, BuildSettings{});
    std::set<uint16_t> stored;
    for (size_t i = 1; i < built.colors.size(); i += 2) stored.insert(uint16_t(built.colors[i] >> 16));
    EXPECT_EQ(stored.size(), 6u) << "the fourth component reaches the rgba16f stream";
}

TEST(Subdivision, CatmullClarkRefinesTowardsTheLimitSurface) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    MeshView v = cube_cage(points, counts, indices, SubdivisionScheme::CatmullClark, 2);
    PreparedMesh m = prepare_mesh(v);
    EXPECT_EQ(m.indices.size() / 3, 6u * 16u * 2u) << "two refinements: 16 quads per face, 2 triangles each";
    float maxRadius = 0;
    for (size_t i = 0; i < m.positions.size(); i += 3) {
        for (int k = 0; k < 3; ++k) EXPECT_LE(std::fabs(m.positions[i + k]), 1.0f) << "refined points stay inside the cage";
        maxRadius = std::max(maxRadius, std::sqrt(m.positions[i] * m.positions[i] + m.positions[i + 1] * m.positions[i + 1] + m.positions[i + 2] * m.positions[i + 2]));
    }
    EXPECT_LT(maxRadius, 1.3f) << "the cage's corners (radius 1.73) are pulled in towards a rounded shape";
    EXPECT_TRUE(m.warnings.empty());
    // Holes stay holes.
    std::vector<int32_t> holes{0};
    v.holeIndices = holes;
    EXPECT_EQ(prepare_mesh(v).indices.size() / 3, 5u * 16u * 2u);
}

namespace {
std::vector<std::array<float, 3>> points_of(const PreparedMesh& m) {
    std::vector<std::array<float, 3>> out;
    for (size_t i = 0; i < m.positions.size(); i += 3) out.push_back({m.positions[i], m.positions[i + 1], m.positions[i + 2]});
    return out;
}
bool has_point(const PreparedMesh& m, std::array<float, 3> p, float tolerance = 1e-6f) {
    for (const auto& q : points_of(m))
        if (std::fabs(q[0] - p[0]) <= tolerance && std::fabs(q[1] - p[1]) <= tolerance && std::fabs(q[2] - p[2]) <= tolerance) return true;
    return false;
}
// An open grid of n x n unit quads in the XY plane, from (0, 0) to (n, n).
struct OpenGrid {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    explicit OpenGrid(int n) {
        for (int y = 0; y <= n; ++y)
            for (int x = 0; x <= n; ++x) points.insert(points.end(), {float(x), float(y), 0.0f});
        for (int y = 0; y < n; ++y)
            for (int x = 0; x < n; ++x) {
                const int a = y * (n + 1) + x;
                counts.push_back(4);
                indices.insert(indices.end(), {a, a + 1, a + n + 2, a + n + 1});
            }
    }
    MeshView view() {
        MeshView v = polygon_view("/Grid", points, counts, indices);
        v.subdivisionScheme = SubdivisionScheme::CatmullClark;
        v.refineLevel = 2;
        return v;
    }
};
}  // namespace

TEST(SubdivisionTags, InfinitelySharpCreaseKeepsTheCageEdge) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    MeshView v = cube_cage(points, counts, indices, SubdivisionScheme::CatmullClark, 2);
    auto on_edge = [](const PreparedMesh& m) {  // refined points on the cage's edge from (-1, -1, 1) to (1, -1, 1)
        std::set<float> xs;
        for (const auto& p : points_of(m))
            if (std::fabs(p[1] + 1.0f) < 1e-6f && std::fabs(p[2] - 1.0f) < 1e-6f) xs.insert(p[0]);
        return xs;
    };
    EXPECT_TRUE(on_edge(prepare_mesh(v)).empty()) << "smooth: the edge is rounded away";
    // The edge 0-1 creased infinitely (USD: 10) with its two ends as infinitely sharp corners: the refined edge is
    // the cage's edge, its points evenly spaced along it.
    std::vector<int32_t> crease{0, 1}, lengths{2}, corners{0, 1};
    std::vector<float> sharpness{10.0f}, cornerSharpness{10.0f, 10.0f};
    v.subdivisionTags.creaseIndices = crease;
    v.subdivisionTags.creaseLengths = lengths;
    v.subdivisionTags.creaseSharpnesses = sharpness;
    v.subdivisionTags.cornerIndices = corners;
    v.subdivisionTags.cornerSharpnesses = cornerSharpness;
    PreparedMesh m = prepare_mesh(v);
    EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];
    EXPECT_EQ(on_edge(m), (std::set<float>{-1.0f, -0.5f, 0.0f, 0.5f, 1.0f}));
    // A closed crease loop around the top face (one sharpness per edge), no corners: the loop is a crease curve,
    // smoothed along itself but kept in the top face's plane; without the crease the top is rounded below it.
    std::vector<int32_t> loop{0, 1, 3, 2, 0}, loopLength{5};
    std::vector<float> perEdge{10.0f, 10.0f, 10.0f, 10.0f};
    v.subdivisionTags = {};
    v.subdivisionTags.creaseIndices = loop;
    v.subdivisionTags.creaseLengths = loopLength;
    v.subdivisionTags.creaseSharpnesses = perEdge;
    auto at_top = [](const PreparedMesh& m) {
        size_t n = 0;
        for (const auto& p : points_of(m)) n += std::fabs(p[2] - 1.0f) < 1e-6f;
        return n;
    };
    m = prepare_mesh(v);
    EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];
    EXPECT_GE(at_top(m), 16u) << "the 16 refined crease edges' points lie in the plane z = 1";
    v.subdivisionTags = {};
    EXPECT_EQ(at_top(prepare_mesh(v)), 0u);
}

TEST(SubdivisionTags, SharpCornerKeepsTheCornerPoint) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    MeshView v = cube_cage(points, counts, indices, SubdivisionScheme::CatmullClark, 2);
    EXPECT_FALSE(has_point(prepare_mesh(v), {-1, -1, 1}));
    std::vector<int32_t> corner{0};
    std::vector<float> sharpness{10.0f};
    v.subdivisionTags.cornerIndices = corner;
    v.subdivisionTags.cornerSharpnesses = sharpness;
    PreparedMesh m = prepare_mesh(v);
    EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];
    EXPECT_TRUE(has_point(m, {-1, -1, 1}));
    EXPECT_FALSE(has_point(m, {1, -1, 1})) << "only the corner given is kept";
}

TEST(SubdivisionTags, InterpolateBoundaryShapesAnOpenGrid) {
    OpenGrid grid(3);
    MeshView v = grid.view();  // USD's default: edgeAndCorner
    PreparedMesh edgeAndCorner = prepare_mesh(v);
    EXPECT_TRUE(has_point(edgeAndCorner, {0, 0, 0})) << "the grid's corners are kept";
    EXPECT_TRUE(has_point(edgeAndCorner, {1.5f, 0, 0})) << "boundary edges are interpolated (straight here)";
    v.subdivisionTags.interpolateBoundary = BoundaryInterpolation::EdgeOnly;
    PreparedMesh edgeOnly = prepare_mesh(v);
    EXPECT_FALSE(has_point(edgeOnly, {0, 0, 0})) << "edgeOnly rounds the corners";
    EXPECT_TRUE(has_point(edgeOnly, {0, 1.5f, 0})) << "boundary edges are still interpolated";
    v.subdivisionTags.interpolateBoundary = BoundaryInterpolation::None;
    PreparedMesh none = prepare_mesh(v);
    EXPECT_LT(none.indices.size(), edgeAndCorner.indices.size()) << "boundary faces are holes, as OpenSubdiv and Storm draw them";
    float minX = 3;
    for (const auto& p : points_of(none)) minX = std::min(minX, p[0]);
    EXPECT_GT(minX, 0.5f) << "no surface reaches the boundary";
    EXPECT_EQ(edgeAndCorner.indices.size(), edgeOnly.indices.size());
}

TEST(SubdivisionTags, TriangleRuleAndFaceVaryingInterpolationAreApplied) {
    // A tetrahedron under Catmull-Clark: the smooth triangle rule moves the refined points.
    std::vector<float> points{1, 1, 1, -1, -1, 1, -1, 1, -1, 1, -1, -1};
    std::vector<int32_t> counts{3, 3, 3, 3}, indices{0, 1, 2, 0, 3, 1, 0, 2, 3, 1, 3, 2};
    MeshView v = polygon_view("/Tetra", points, counts, indices);
    v.subdivisionScheme = SubdivisionScheme::CatmullClark;
    v.refineLevel = 1;
    const PreparedMesh catmark = prepare_mesh(v);
    v.subdivisionTags.triangleSubdivisionRule = TriangleSubdivision::Smooth;
    const PreparedMesh smooth = prepare_mesh(v);
    ASSERT_EQ(catmark.positions.size(), smooth.positions.size());
    EXPECT_NE(catmark.positions, smooth.positions);
    // Texture coordinates of an open grid, u = x^2 / 9 (not reproduced by smooth subdivision): `all` interpolates
    // them linearly, so a control point keeps its UV; `none` smooths them in the interior.
    OpenGrid grid(3);
    std::vector<float> uvs;
    for (size_t i = 0; i < grid.points.size(); i += 3) uvs.insert(uvs.end(), {grid.points[i] * grid.points[i] / 9, grid.points[i + 1] / 3});
    MeshView g = grid.view();
    g.uvs = {Interpolation::Vertex, 2, uvs, {}};
    auto has_uv = [](const PreparedMesh& m, float u, float w) {
        for (size_t i = 0; i < m.uvs.size(); i += 2)
            if (std::fabs(m.uvs[i] - u) < 1e-6f && std::fabs(m.uvs[i + 1] - w) < 1e-6f) return true;
        return false;
    };
    g.subdivisionTags.faceVaryingLinearInterpolation = FaceVaryingLinear::All;
    EXPECT_TRUE(has_uv(prepare_mesh(g), 1.0f / 9, 1.0f / 3));
    g.subdivisionTags.faceVaryingLinearInterpolation = FaceVaryingLinear::None;
    EXPECT_FALSE(has_uv(prepare_mesh(g), 1.0f / 9, 1.0f / 3)) << "smooth: the interior control point's UV moves";
}

TEST(SubdivisionTags, BadTagsAreReportedAndIgnored) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    MeshView v = cube_cage(points, counts, indices, SubdivisionScheme::CatmullClark, 1);
    const PreparedMesh plain = prepare_mesh(v);
    auto expect_ignored = [&](const MeshView& bad, const char* message) {
        PreparedMesh m = prepare_mesh(bad);
        EXPECT_EQ(m.positions, plain.positions) << message;
        ASSERT_EQ(m.warnings.size(), 1u) << message;
        EXPECT_NE(m.warnings[0].find(message), std::string::npos) << m.warnings[0];
        EXPECT_EQ(m.warnings[0].rfind("/Cage: ", 0), 0u) << "names the prim: " << m.warnings[0];
    };
    std::vector<int32_t> crease{0, 1, 3}, two{2}, three{3}, outside{0, 99}, one{1}, corner{0}, badCorner{-1};
    std::vector<float> sharp{10.0f}, sharpTwo{10.0f, 10.0f}, sharpThree{1, 2, 3}, nan{std::nanf("")};
    MeshView bad = v;
    bad.subdivisionTags.creaseIndices = crease;
    bad.subdivisionTags.creaseLengths = two;
    bad.subdivisionTags.creaseSharpnesses = sharp;
    expect_ignored(bad, "creases ignored: creaseLengths sum to 2 but creaseIndices has 3 entries");
    bad.subdivisionTags.creaseLengths = three;
    bad.subdivisionTags.creaseSharpnesses = sharpThree;
    expect_ignored(bad, "creases ignored: 3 creaseSharpnesses for 1 crease(s) of 2 edge(s)");
    bad.subdivisionTags.creaseIndices = outside;
    bad.subdivisionTags.creaseLengths = two;
    bad.subdivisionTags.creaseSharpnesses = sharp;
    expect_ignored(bad, "creases ignored: creaseIndices has 99, outside the points 0..7");
    bad.subdivisionTags.creaseIndices = std::span<const int32_t>(crease).first(1);
    bad.subdivisionTags.creaseLengths = one;
    expect_ignored(bad, "creases ignored: a crease of 1 point(s)");
    bad.subdivisionTags.creaseIndices = crease;
    bad.subdivisionTags.creaseLengths = three;
    bad.subdivisionTags.creaseSharpnesses = nan;
    expect_ignored(bad, "creases ignored: a creaseSharpnesses value is not finite");
    std::vector<int32_t> diagonal{0, 3};  // across a face: not an edge
    bad.subdivisionTags.creaseIndices = diagonal;
    bad.subdivisionTags.creaseLengths = two;
    bad.subdivisionTags.creaseSharpnesses = sharp;
    expect_ignored(bad, "1 crease edge(s) are not edges of the mesh, first (0, 3)");
    bad = v;
    bad.subdivisionTags.cornerIndices = corner;
    bad.subdivisionTags.cornerSharpnesses = sharpTwo;
    expect_ignored(bad, "corners ignored: 1 cornerIndices but 2 cornerSharpnesses");
    bad.subdivisionTags.cornerIndices = badCorner;
    bad.subdivisionTags.cornerSharpnesses = sharp;
    expect_ignored(bad, "corners ignored: cornerIndices has -1, outside the points 0..7");
}

TEST(Subdivision, LoopNeedsTrianglesElseTheCageIsDrawnWithAWarning) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    MeshView v = cube_cage(points, counts, indices, SubdivisionScheme::Loop, 1);
    PreparedMesh m = prepare_mesh(v);
    EXPECT_EQ(m.indices.size() / 3, 12u);
    ASSERT_FALSE(m.warnings.empty());
    EXPECT_NE(m.warnings[0].find("/Cage: cannot subdivide (Loop subdivision needs triangles only)"), std::string::npos) << m.warnings[0];
}

TEST(Subdivision, BadFacesAreDroppedBeforeRefinement) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    cube_cage(points, counts, indices);
    counts.push_back(3);
    indices.insert(indices.end(), {0, 1, 42});
    MeshView v = polygon_view("/Cage", points, counts, indices);
    v.subdivisionScheme = SubdivisionScheme::CatmullClark;
    v.refineLevel = 1;
    PreparedMesh m = prepare_mesh(v);
    EXPECT_EQ(m.indices.size() / 3, 6u * 4u * 2u);
    ASSERT_FALSE(m.warnings.empty());
    EXPECT_NE(m.warnings[0].find("dropped 1 invalid face(s); first is face 6 with a vertex index out of range"), std::string::npos) << m.warnings[0];
}

TEST(Prepare, TextureCoordinateSeamsSplitVerticesAndAreKept) {
    Quad q;  // two quads sharing an edge; each its own UV island (a seam along the shared edge)
    q.points = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 2, 0, 0, 2, 1, 0};
    q.counts = {4, 4};
    q.indices = {0, 1, 2, 3, 1, 4, 5, 2};
    std::vector<float> islands{0, 0, 0.5f, 0, 0.5f, 1, 0, 1, 0.5f, 0, 1, 0, 1, 1, 0.5f, 1};
    std::vector<int32_t> islandIndices{0, 1, 2, 3, 4, 5, 6, 7};
    MeshView v = q.view();
    v.uvs = {Interpolation::FaceVarying, 2, islands, islandIndices};
    PreparedMesh m = prepare_mesh(v);
    EXPECT_EQ(m.positions.size() / 3, 6u) << "the islands meet at the same st: one vertex per point";
    ASSERT_EQ(m.uvs.size(), 2 * m.positions.size() / 3);
    std::vector<float> split = islands;
    split[8] = 0.55f;  // the second island's corner at point 1 moves away: a seam
    v.uvs = {Interpolation::FaceVarying, 2, split, islandIndices};
    m = prepare_mesh(v);
    EXPECT_EQ(m.positions.size() / 3, 7u) << "point 1 is split by the UV seam";
    // Every corner keeps its authored coordinate.
    for (size_t t = 0; t < m.indices.size(); ++t) {
        const float* p = &m.positions[3 * m.indices[t]];
        const float* uv = &m.uvs[2 * m.indices[t]];
        if (p[0] == 0) EXPECT_EQ(uv[0], 0.0f);
        if (p[0] == 2) EXPECT_EQ(uv[0], 1.0f);
        if (p[0] == 1) EXPECT_TRUE(uv[0] == 0.5f || uv[0] == 0.55f);
    }
    // Non-finite coordinates become 0 with a warning; a short array is ignored with one.
    split[0] = NAN;
    v.uvs = {Interpolation::FaceVarying, 2, split, islandIndices};
    m = prepare_mesh(v);
    EXPECT_FALSE(m.uvs.empty());
    EXPECT_NE(m.warnings.size(), 0u);
    std::vector<float> tooShort{0, 0, 1, 1};
    v.uvs = {Interpolation::Vertex, 2, tooShort, {}};
    m = prepare_mesh(v);
    EXPECT_TRUE(m.uvs.empty());
    ASSERT_EQ(m.warnings.size(), 1u);
    EXPECT_NE(m.warnings[0].find("texture coordinates"), std::string::npos) << m.warnings[0];
}

TEST(Subdivision, FaceVaryingTextureCoordinatesAreRefinedPerIsland) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    MeshView v = cube_cage(points, counts, indices, SubdivisionScheme::CatmullClark, 2);
    // Face f is the island (f, 0)-(f + 1, 1): seams on every cube edge.
    std::vector<float> islands;
    std::vector<int32_t> islandIndices;
    for (int f = 0; f < 6; ++f) {
        islands.insert(islands.end(), {float(f), 0, float(f + 1), 0, float(f + 1), 1, float(f), 1});
        islandIndices.insert(islandIndices.end(), {4 * f, 4 * f + 1, 4 * f + 2, 4 * f + 3});
    }
    v.uvs = {Interpolation::FaceVarying, 2, islands, islandIndices};
    PreparedMesh m = prepare_mesh(v);
    EXPECT_TRUE(m.warnings.empty());
    ASSERT_EQ(m.uvs.size(), 2 * m.positions.size() / 3);
    EXPECT_EQ(m.positions.size() / 3, 6u * 25u) << "5 x 5 refined vertices per face, split along every cube edge";
    std::set<std::pair<float, float>> corners;
    for (size_t i = 0; i < m.uvs.size(); i += 2) {
        EXPECT_GE(m.uvs[i], 0.0f);
        EXPECT_LE(m.uvs[i], 6.0f);
        EXPECT_GE(m.uvs[i + 1], 0.0f);
        EXPECT_LE(m.uvs[i + 1], 1.0f);
        corners.insert({m.uvs[i], m.uvs[i + 1]});
    }
    EXPECT_TRUE(corners.count({0.0f, 0.0f}) && corners.count({6.0f, 1.0f})) << "cornersPlus1 keeps island corners";
    EXPECT_TRUE(corners.count({0.5f, 0.5f})) << "each island's centre";
}

TEST(Prepare, MaterialSlotsSplitVerticesAndFollowTheirFaces) {
    Quad q;  // two quads sharing an edge, in two GeomSubsets
    q.points = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 2, 0, 0, 2, 1, 0};
    q.counts = {4, 4};
    q.indices = {0, 1, 2, 3, 1, 4, 5, 2};
    std::vector<int32_t> slots{0, 3};
    MeshView v = q.view();
    v.faceMaterials = slots;
    PreparedMesh m = prepare_mesh(v);
    EXPECT_EQ(m.positions.size() / 3, 8u) << "the shared edge is split between the two slots";
    EXPECT_EQ(m.triangleMaterials, (std::vector<uint8_t>{0, 0, 3, 3}));
    std::vector<int32_t> allZero{0, 0};
    v.faceMaterials = allZero;
    m = prepare_mesh(v);
    EXPECT_TRUE(m.triangleMaterials.empty()) << "one slot: nothing stored";
    EXPECT_EQ(m.positions.size() / 3, 6u);
    for (std::vector<int32_t> bad : {std::vector<int32_t>{1}, std::vector<int32_t>{0, 256}, std::vector<int32_t>{-1, 0}}) {
        v.faceMaterials = bad;
        m = prepare_mesh(v);
        EXPECT_TRUE(m.triangleMaterials.empty());
        ASSERT_EQ(m.warnings.size(), 1u);
        EXPECT_NE(m.warnings[0].find("/Quad: "), std::string::npos);
    }
}

TEST(Subdivision, MaterialSlotsFollowRefinedFaces) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    MeshView v = cube_cage(points, counts, indices, SubdivisionScheme::CatmullClark, 2);
    std::vector<int32_t> slots{0, 1, 2, 3, 4, 5};
    v.faceMaterials = slots;
    PreparedMesh m = prepare_mesh(v);
    ASSERT_EQ(m.triangleMaterials.size(), 6u * 32u);
    std::map<int, int> perSlot;
    for (uint8_t slot : m.triangleMaterials) ++perSlot[slot];
    for (int slot = 0; slot < 6; ++slot) EXPECT_EQ(perSlot[slot], 32) << "each face's 16 quads keep its slot";
}

// Random meshes (grids flat, bumpy and folded, soups of random indices and counts, fans of thousands of triangles
// on one edge, coincident and collinear points, duplicated and double-sided faces, spheres with non-finite points;
// sizes from 1e-8 to 1e8 units, some far from the origin; random holes, winding, primvars, material slots,
// subdivision and build settings) are built or refused with MeshError, never anything else, and what is built holds
// the DAG's invariants and decodes from its pages. (A scratch run of this generator over 900 seeds with ASan and
// UBSan found the overflow MeshesBeyondTheFloatRangeAreRefusedNamingTheMesh covers.)
TEST(Builder, RandomMeshesAreBuiltOrRefusedWithAMeshError) {
    size_t built = 0, refused = 0;
    for (int seed = 0; seed < 48; ++seed) {
        std::mt19937 rng(seed);
        auto uniform = [&](double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); };
        auto integer = [&](int a, int b) { return std::uniform_int_distribution<int>(a, b)(rng); };
        const int kind = integer(0, 7), n = integer(2, 40);
        const double scale = std::pow(10.0, uniform(-8, 8)), offset = integer(0, 3) == 0 ? std::pow(10.0, uniform(0, 6)) : 0.0;
        std::vector<float> points, uvs, normals, colors;
        std::vector<int32_t> counts, indices, holes, slots;
        auto quad = [&](int a, int b, int c, int d) { counts.push_back(4), indices.insert(indices.end(), {a, b, c, d}); };
        auto triangle = [&](int a, int b, int c) { counts.push_back(3), indices.insert(indices.end(), {a, b, c}); };
        if (kind <= 2) {  // a grid: bumpy, folded at random, flat
            for (int y = 0; y <= n; ++y)
                for (int x = 0; x <= n; ++x) {
                    const double z = kind == 0 ? 0.1 * std::sin(x * 0.7) * std::cos(y * 0.3) : kind == 1 ? uniform(-1, 1) : 0.0;
                    points.insert(points.end(), {float(offset + scale * x), float(offset + scale * y), float(offset + scale * z)});
                }
            for (int y = 0; y < n; ++y)
                for (int x = 0; x < n; ++x) quad(y * (n + 1) + x, y * (n + 1) + x + 1, (y + 1) * (n + 1) + x + 1, (y + 1) * (n + 1) + x);
        } else if (kind == 3) {  // a soup of random indices (some out of range) and counts (some below 3)
            const int pointCount = integer(1, 300);
            for (int i = 0; i < 3 * pointCount; ++i) points.push_back(float(offset + scale * uniform(-1, 1)));
            for (int f = integer(1, 1000); f > 0; --f) {
                counts.push_back(integer(0, 6));
                for (int k = 0; k < counts.back(); ++k) indices.push_back(integer(-2, pointCount + 2));
            }
        } else if (kind == 4) {  // a fan: thousands of triangles on one edge (non-manifold)
            points.insert(points.end(), {0, 0, 0, float(scale), 0, 0});
            for (int f = integer(3, 3000), i = 0; i < f; ++i) {
                const double a = uniform(0, 6.283);
                points.insert(points.end(), {float(scale * 0.5), float(scale * std::cos(a)), float(scale * std::sin(a))});
                triangle(0, 1, i + 2);
            }
        } else if (kind == 5) {  // coincident and collinear points
            const int pointCount = integer(3, 300);
            for (int i = 0; i < pointCount; ++i) points.insert(points.end(), {float(integer(0, 1) ? scale * i : scale), float(scale), float(scale)});
            for (int f = 0; f < pointCount; ++f) triangle(integer(0, pointCount - 1), integer(0, pointCount - 1), integer(0, pointCount - 1));
        } else if (kind == 6) {  // duplicated and double-sided triangles
            for (int y = 0; y <= n; ++y)
                for (int x = 0; x <= n; ++x) points.insert(points.end(), {float(scale * x), float(scale * y), 0.0f});
            for (int y = 0; y < n; ++y)
                for (int x = 0; x < n; ++x)
                    for (int copies = integer(1, 3), a = y * (n + 1) + x; copies > 0; --copies) triangle(a, a + 1, a + n + 2), triangle(a, a + n + 2, a + 1);
        } else {  // a sphere with non-finite points
            for (int i = 0; i <= n; ++i)
                for (int j = 0; j < 2 * n; ++j) {
                    const double theta = M_PI * i / n, phi = M_PI * j / n;
                    points.insert(points.end(), {float(scale * std::sin(theta) * std::cos(phi)), float(scale * std::sin(theta) * std::sin(phi)), float(scale * std::cos(theta))});
                }
            for (int i = 0; i < n; ++i)
                for (int j = 0; j < 2 * n; ++j) quad(i * 2 * n + j, (i + 1) * 2 * n + j, (i + 1) * 2 * n + (j + 1) % (2 * n), i * 2 * n + (j + 1) % (2 * n));
            for (int k = integer(0, 5); k > 0; --k) points[integer(0, int(points.size()) - 1)] = integer(0, 1) ? NAN : INFINITY;
        }
        const std::string name = "/Random" + std::to_string(seed);
        MeshView view = polygon_view(name, points, counts, indices);
        view.leftHanded = integer(0, 1);
        if (integer(0, 3) == 0) {
            for (int k = integer(1, 5); k > 0; --k) holes.push_back(integer(-1, int(counts.size())));
            view.holeIndices = holes;
        }
        if (integer(0, 2) == 0) {
            uvs.resize(2 * indices.size());
            for (float& u : uvs) u = integer(0, 50) ? float(uniform(-2, 2)) : integer(0, 1) ? NAN : 1e30f;
            view.uvs = {Interpolation::FaceVarying, 2, uvs, {}};
        }
        if (integer(0, 3) == 0) {
            normals.resize(3 * indices.size());
            for (float& x : normals) x = integer(0, 50) ? float(uniform(-1, 1)) : 0.0f;
            view.normals = {Interpolation::FaceVarying, 3, normals, {}};
        }
        if (integer(0, 3) == 0) {
            colors.resize(points.size());
            for (float& x : colors) x = float(uniform(0, 1));
            view.displayColor = {Interpolation::Vertex, 3, colors, {}};
        }
        if (integer(0, 3) == 0) {
            slots.resize(counts.size());
            for (int32_t& slot : slots) slot = integer(0, 3);
            view.faceMaterials = slots;
        }
        if (integer(0, 5) == 0) {
            view.subdivisionScheme = integer(0, 1) ? SubdivisionScheme::CatmullClark : SubdivisionScheme::Loop;
            view.refineLevel = integer(0, 2);
        }
        BuildSettings settings;
        settings.preserveArea = integer(0, 3) == 0;
        if (integer(0, 4) == 0) settings.maxEdgeLengthFactor = float(uniform(0, 3));
        if (integer(0, 4) == 0) settings.trimRelativeError = float(uniform(0, 2));
        if (integer(0, 4) == 0) settings.keepTrianglePercent = float(uniform(1, 100));
        SCOPED_TRACE(name + " kind " + std::to_string(kind) + " scale " + std::to_string(scale));
        BuiltMesh mesh;
        try {
            mesh = build_mesh(prepare_mesh(view), settings);
        } catch (const MeshError& e) {
            EXPECT_NE(std::string(e.what()).find(name + ": "), std::string::npos) << e.what();
            ++refused;
            continue;
        }
        ++built;
        ASSERT_FALSE(mesh.clusters.empty());
        for (const Cluster& c : mesh.clusters) {
            ASSERT_TRUE(std::isfinite(c.lodError) && !std::isnan(c.parentError));
            ASSERT_LE(c.lodError, c.parentError);
            for (int k = 0; k < 4; ++k) ASSERT_TRUE(std::isfinite(c.sphere[k]) && std::isfinite(c.lodSphere[k]));
            ASSERT_LE(c.triangleCount, kClusterMaxTriangles);
            ASSERT_GT(c.triangleCount, 0u);
        }
        const BuiltMesh decoded = decode_pages(encode_pages(mesh), name);
        ASSERT_EQ(decoded.clusters.size(), mesh.clusters.size());
        EXPECT_EQ(decoded.triangles, mesh.triangles);
    }
    EXPECT_GE(built, 24u) << "most of them are meshes to build";
    EXPECT_GE(refused, 2u) << "and some are not";
}

// A static displacement bake dices a mesh until it fits the bake's triangle budget. A mesh of more triangles than the
// budget cannot fit whatever the dicing: the coarsening looked for a fit for ever (a 5 M-triangle scan under a baked
// displacement material, at the 4 M default, hung its build; found by the scratch fuzzer). Such a mesh is not diced,
// and its corners still move; a mesh within the budget is diced as before.
TEST(Bake, AMeshOfMoreTrianglesThanTheBudgetIsDisplacedWithoutDicing) {
    const int n = 40;
    std::vector<float> points, uvs;
    std::vector<int32_t> counts, indices;
    quad_grid(n, [](int x, int y) { return std::array<float, 3>{float(x), float(y), 0.0f}; },
              [&](int, int, int x, int y) { uvs.insert(uvs.end(), {float(x) / n, float(y) / n}); }, points, counts, indices);
    MeshView view = polygon_view("/Baked", points, counts, indices);
    view.uvs = {Interpolation::FaceVarying, 2, uvs, {}};
    const PreparedMesh mesh = prepare_mesh(view);
    DisplacementBake bake;
    bake.height = [](float s, float t) { return std::sin(6.0f * s) * std::cos(5.0f * t); };
    bake.texels = 512;
    bake.magnitude = 0.5f;
    bake.maxTriangles = mesh.indices.size() / 3 / 2;  // half the mesh: no dicing fits
    const PreparedMesh flat = bake_displacement(mesh, bake);
    EXPECT_EQ(flat.indices.size(), mesh.indices.size()) << "not diced";
    float highest = 0;
    for (size_t v = 0; v < flat.positions.size() / 3; ++v) highest = std::max(highest, std::fabs(flat.positions[3 * v + 2]));
    EXPECT_GT(highest, 0.3f) << "its corners move along their normals";
    bake.maxTriangles = 20 * mesh.indices.size() / 3;
    const PreparedMesh diced = bake_displacement(mesh, bake);
    EXPECT_GT(diced.indices.size(), 4 * mesh.indices.size()) << "within the budget, diced";
    EXPECT_LE(diced.indices.size() / 3, bake.maxTriangles);
}
