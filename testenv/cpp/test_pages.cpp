// The page file: exact round trip, page invariants, and clear errors for truncated, corrupt or foreign files.
#include "tessera/builder.h"

#include "cluster_codec.h"

#include <gtest/gtest.h>

#include "test_meshes.h"

#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <random>
#include <set>

using namespace tessera;

namespace {

BuiltMesh bumpy_grid(int n, bool colors, bool uvs = false) {
    std::vector<float> points, colorValues, uvValues;
    std::vector<int32_t> counts, indices;
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x)
            points.insert(points.end(), {float(x) / n, float(y) / n, 0.05f * std::sin(0.31f * x) * std::cos(0.27f * y)});
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            const int a = y * (n + 1) + x;
            counts.push_back(4);
            indices.insert(indices.end(), {a, a + 1, a + n + 2, a + n + 1});
            colorValues.insert(colorValues.end(), {float((x / 8 + y / 8) % 2), 0.3f, 0.7f});
            // UV islands of 8 x 8 quads, each placed in its own tile: seams on every island border.
            const float u0 = float(x % 8) / 8 + float(x / 8), v0 = float(y % 8) / 8 + float(y / 8);
            uvValues.insert(uvValues.end(), {u0, v0, u0 + 0.125f, v0, u0 + 0.125f, v0 + 0.125f, u0, v0 + 0.125f});
        }
    MeshView v = polygon_view("/Grid", points, counts, indices);
    if (colors) v.displayColor = {Interpolation::Uniform, 3, colorValues, {}};
    if (uvs) v.uvs = {Interpolation::FaceVarying, 2, uvValues, {}};
    return build_mesh(prepare_mesh(v));
}

float angle_degrees(const std::array<float, 3>& a, const std::array<float, 3>& b) {
    const double cx = double(a[1]) * b[2] - double(a[2]) * b[1], cy = double(a[2]) * b[0] - double(a[0]) * b[2], cz = double(a[0]) * b[1] - double(a[1]) * b[0];
    const double dot = double(a[0]) * b[0] + double(a[1]) * b[1] + double(a[2]) * b[2];
    return float(std::atan2(std::sqrt(cx * cx + cy * cy + cz * cz), dot) * 180.0 / 3.14159265358979);
}

std::array<float, 3> random_direction(std::mt19937& rng) {
    std::normal_distribution<float> d;
    std::array<float, 3> n{d(rng), d(rng), d(rng)};
    const float length = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (float& x : n) x /= length;
    return n;
}

// One root cluster of `vertexCount` random grid points and random normals, every vertex used, in page order; its
// normals' directions before quantization go to `directions`.
BuiltMesh single_cluster(uint32_t vertexCount, uint32_t triangleCount, std::vector<std::array<float, 3>>& directions) {
    std::mt19937 rng(vertexCount * 131 + triangleCount);
    std::vector<uint32_t> corners;
    for (uint32_t t = 0; t < triangleCount; ++t)
        for (uint32_t k = 0; k < 3; ++k) corners.push_back(3 * t + k < vertexCount ? 3 * t + k : rng() % vertexCount);
    const std::vector<uint32_t> newToOld = order_cluster_for_pages(corners, vertexCount);
    BuiltMesh mesh;
    mesh.positionPrecision = -10;
    mesh.positionStep = std::ldexp(1.0, -10);
    mesh.sourceTriangles = triangleCount;
    std::uniform_int_distribution<int32_t> grid(-(1 << 20), 1 << 20);
    std::vector<std::array<float, 3>> oldDirections(vertexCount);
    for (auto& n : oldDirections) n = random_direction(rng);
    for (uint32_t v = 0; v < vertexCount; ++v) {
        for (int k = 0; k < 3; ++k) mesh.positions.push_back(float(grid(rng) * mesh.positionStep));
        directions.push_back(oldDirections[newToOld[v]]);
        mesh.normals.push_back(encode_octahedral(directions[v][0], directions[v][1], directions[v][2]));
    }
    for (size_t i = 0; i < corners.size(); i += 3) mesh.triangles.push_back(corners[i] | (corners[i + 1] << 8) | (corners[i + 2] << 16));
    Cluster c{};
    c.sphere = c.lodSphere = c.parentSphere = {0, 0, 0, 2000};
    c.parentError = std::numeric_limits<float>::infinity();
    c.parentGroup = kNoGroup;
    c.vertexCount = vertexCount;
    c.triangleCount = triangleCount;
    append_cluster(mesh, c);
    mesh.groups = 0;
    return mesh;
}

// Rewrites the checksums of every page and of the table, so that a changed page reaches the decoder.
void fix_checksums(std::vector<uint8_t>& file) {
    uint32_t pages;
    std::memcpy(&pages, &file[12], 4);
    const size_t table = kPageHeaderBytes;
    for (uint32_t p = 0; p < pages; ++p) {
        uint64_t offset;
        uint32_t size;
        std::memcpy(&offset, &file[table + 24 * p], 8);
        std::memcpy(&size, &file[table + 24 * p + 8], 4);
        const uint32_t crc = crc32(std::span(file).subspan(offset, size));
        std::memcpy(&file[table + 24 * p + 20], &crc, 4);
    }
    const uint32_t crc = crc32(std::span(file).subspan(table, 24 * pages));
    std::memcpy(&file[table + 24 * pages], &crc, 4);
}

void expect_same(const BuiltMesh& a, const BuiltMesh& b) {
    EXPECT_EQ(a.origin, b.origin);
    EXPECT_EQ(a.positionPrecision, b.positionPrecision);
    EXPECT_EQ(a.positions, b.positions);
    EXPECT_EQ(a.normals, b.normals);
    EXPECT_EQ(a.colors, b.colors);
    EXPECT_EQ(a.uvs, b.uvs);
    EXPECT_EQ(a.uvPrecision, b.uvPrecision);
    EXPECT_EQ(a.triangles, b.triangles);
    ASSERT_EQ(a.clusters.size(), b.clusters.size());
    EXPECT_EQ(std::memcmp(a.clusters.data(), b.clusters.data(), a.clusters.size() * sizeof(Cluster)), 0);
    EXPECT_EQ(a.leafClusters, b.leafClusters);
    EXPECT_EQ(a.leafVertices, b.leafVertices);
    EXPECT_EQ(a.leafTriangles, b.leafTriangles);
    EXPECT_EQ(a.sphere, b.sphere);
    EXPECT_EQ(a.groups, b.groups);
    EXPECT_EQ(a.sourceTriangles, b.sourceTriangles);
    ASSERT_EQ(a.levels.size(), b.levels.size());
    for (size_t l = 0; l < a.levels.size(); ++l) EXPECT_EQ(a.levels[l].triangles, b.levels[l].triangles);
    EXPECT_EQ(a.leafError, b.leafError);
    // The fallback mesh is rebuilt from its cut, bit for bit.
    EXPECT_EQ(std::bit_cast<uint32_t>(a.fallbackThreshold), std::bit_cast<uint32_t>(b.fallbackThreshold)) << "NaN (none) too";
    EXPECT_EQ(a.fallbackError, b.fallbackError);
    const FallbackMesh fa = fallback_mesh(a), fb = fallback_mesh(b);
    EXPECT_EQ(fa.threshold, fb.threshold);
    EXPECT_EQ(fa.error, fb.error);
    EXPECT_EQ(fa.positions, fb.positions);
    EXPECT_EQ(fa.normals, fb.normals);
    EXPECT_EQ(fa.indices, fb.indices);
    EXPECT_EQ(fa.colors, fb.colors);
    EXPECT_EQ(fa.uvs, fb.uvs);
    EXPECT_EQ(fa.materialSlots, fb.materialSlots);
}

}  // namespace

// The fallback mesh carries what the source has: colours, texture coordinates (split at their seams) and material slots.
TEST(Fallback, CarriesColoursTextureCoordinatesAndMaterialSlots) {
    const int n = 48;
    std::vector<float> points, colorValues, uvValues;
    std::vector<int32_t> counts, indices, slots;
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) points.insert(points.end(), {float(x), float(y), 0.0f});
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            const int a = y * (n + 1) + x;
            counts.push_back(4);
            indices.insert(indices.end(), {a, a + 1, a + n + 2, a + n + 1});
            colorValues.insert(colorValues.end(), {float(y / 24), 0.25f, 0.75f});  // two bands, each across many UV tiles
            // A UV tile per 8 x 8 block of quads, tiles apart (seams on every block border): [2 bx, 2 bx + 1].
            const float u0 = float(2 * (x / 8)) + float(x % 8) / 8, v0 = float(2 * (y / 8)) + float(y % 8) / 8;
            uvValues.insert(uvValues.end(), {u0, v0, u0 + 0.125f, v0, u0 + 0.125f, v0 + 0.125f, u0, v0 + 0.125f});
            slots.push_back(x < n / 2 ? 0 : 2);
        }
    MeshView v = polygon_view("/Grid", points, counts, indices);
    v.displayColor = {Interpolation::Uniform, 3, colorValues, {}};
    v.uvs = {Interpolation::FaceVarying, 2, uvValues, {}};
    v.faceMaterials = slots;
    const BuiltMesh built = build_mesh(prepare_mesh(v));
    for (const float threshold : {-1.0f, built.fallbackThreshold}) {
        const FallbackMesh f = extract_fallback(built, threshold);
        const size_t vertices = f.positions.size() / 3, triangles = f.indices.size() / 3;
        ASSERT_GT(triangles, 0u);
        ASSERT_EQ(f.colors.size(), 4 * vertices);
        ASSERT_EQ(f.uvs.size(), 2 * vertices);
        ASSERT_EQ(f.materialSlots.size(), triangles);
        for (size_t t = 0; t < triangles; ++t) {
            float cx = 0, cy = 0;
            for (int k = 0; k < 3; ++k) cx += f.positions[3 * f.indices[3 * t + k]] / 3, cy += f.positions[3 * f.indices[3 * t + k] + 1] / 3;
            cx += built.origin[0], cy += built.origin[1];
            EXPECT_EQ(f.materialSlots[t], cx < n / 2 ? 0 : 2) << "triangle " << t << " at x " << cx;
            if (threshold >= 0) continue;  // simplified triangles may span blocks; source ones lie in one quad
            const int bx = int(cx) / 8, by = int(cy) / 8;
            for (int k = 0; k < 3; ++k) {
                const uint32_t i = f.indices[3 * t + k];
                EXPECT_EQ(f.colors[4 * i], float(int(cy) / 24)) << "triangle " << t;
                EXPECT_EQ(f.colors[4 * i + 3], 1.0f);
                EXPECT_TRUE(f.uvs[2 * i] >= 2 * bx && f.uvs[2 * i] <= 2 * bx + 1 && f.uvs[2 * i + 1] >= 2 * by && f.uvs[2 * i + 1] <= 2 * by + 1)
                    << "triangle " << t << ": its corners' coordinates lie in its block's tile";
            }
        }
    }
}

TEST(Pages, RoundTripIsExact) {
    for (bool colors : {false, true})
        for (bool uvs : {false, true}) {
            BuiltMesh built = bumpy_grid(150, colors, uvs);
            ASSERT_EQ(built.uvs.empty(), !uvs);
            ASSERT_FALSE(fallback_mesh(built).indices.empty());
            const std::vector<uint8_t> file = encode_pages(built);
            const BuiltMesh decoded = decode_pages(file, "grid.tsra");
            expect_same(built, decoded);
            EXPECT_EQ(file, encode_pages(built)) << "same mesh, same bytes";
            // The stored cones and mean areas are those of the decoded triangles: the renderer derives none.
            size_t culling = 0;
            for (const Cluster& c : decoded.clusters) {
                const NormalCone cone = cluster_normal_cone(decoded, c);
                EXPECT_EQ(c.cone.axis8, cone.axis8);
                EXPECT_EQ(c.cone.cutoff8, cone.cutoff8);
                const ClusterTriangleSizes sizes = cluster_triangle_sizes(decoded, c);
                EXPECT_EQ(c.meanTriangleArea, sizes.meanArea);
                EXPECT_GT(c.meanTriangleArea, 0.0f);
                EXPECT_EQ(c.longestEdge, sizes.longestEdge);
                EXPECT_GE(c.longestEdge * c.longestEdge, 4.0f / std::sqrt(3.0f) * c.meanTriangleArea);  // an equilateral's at least
                culling += c.cone.cutoff8 < 127;
            }
            EXPECT_GT(culling, decoded.clusters.size() / 2) << "a bumpy grid's clusters mostly have cones that cull";
        }
}

TEST(Pages, MaterialSlotsRoundTrip) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices, slots;
    const int n = 120;
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) points.insert(points.end(), {float(x) / n, float(y) / n, 0.03f * std::sin(0.4f * x)});
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            const int a = y * (n + 1) + x;
            counts.push_back(4);
            indices.insert(indices.end(), {a, a + 1, a + n + 2, a + n + 1});
            slots.push_back((x / 30 + 2 * (y / 40)) % 5);
        }
    MeshView v = polygon_view("/Grid", points, counts, indices);
    v.faceMaterials = slots;
    const BuiltMesh built = build_mesh(prepare_mesh(v));
    ASSERT_EQ(built.materialSlots, 5u);
    const std::vector<uint8_t> file = encode_pages(built);
    expect_same(built, decode_pages(file, "slots.tsra"));
    BuiltMesh wrong = built;
    wrong.materialSlots = 2;
    EXPECT_THROW(encode_pages(wrong), std::invalid_argument) << "slots must fit the mesh's count";
}

TEST(Pages, TextureCoordinatesCostLittle) {
    // Seams everywhere (islands of 8 x 8 quads): the UV stream is predicted like positions and stays small.
    const size_t plain = encode_pages(bumpy_grid(150, false)).size(), mapped = encode_pages(bumpy_grid(150, false, true)).size();
    const double extraPerTriangle = double(mapped - plain) / (150.0 * 150.0 * 2.0);
    EXPECT_LT(extraPerTriangle, 2.5) << plain << " bytes without UVs, " << mapped << " with";
}

TEST(Pages, OffGridTextureCoordinatesAreRefused) {
    BuiltMesh built = bumpy_grid(20, false, true);
    built.uvs[7] = std::nextafter(built.uvs[7], 10.0f);
    EXPECT_THROW(encode_pages(built), std::invalid_argument);
}

TEST(Pages, GroupsNeverStraddlePagesAndRootsHaveTheirOwn) {
    BuiltMesh built = bumpy_grid(300, true);
    PageLayout layout;
    const std::vector<uint8_t> file = encode_pages(built, &layout);
    ASSERT_GT(layout.pages, 2u) << "the test needs several pages";
    EXPECT_GE(layout.rootPages, 1u);
    std::map<uint32_t, uint32_t> pageOfGroup;
    std::set<uint32_t> all;
    for (uint32_t p = 0; p < layout.pages; ++p)
        for (uint32_t c : layout.pageClusters[p]) {
            all.insert(c);
            const Cluster& cluster = built.clusters[c];
            EXPECT_EQ(cluster.parentGroup == kNoGroup, p < layout.rootPages) << "roots, and only roots, fill the root pages";
            if (cluster.parentGroup == kNoGroup) continue;
            auto [it, first] = pageOfGroup.try_emplace(cluster.parentGroup, p);
            EXPECT_EQ(it->second, p) << "the children of group " << cluster.parentGroup << " straddle pages";
        }
    EXPECT_EQ(all.size(), built.clusters.size());
    // Every page fits the fixed page size.
    const double bytesPerTriangle = double(file.size()) / double(built.sourceTriangles);
    EXPECT_LT(bytesPerTriangle, 14.0);  // with colours, which are stored as they are
    RecordProperty("bytes_per_input_triangle", std::to_string(bytesPerTriangle));
}

// Every page unit of `mesh` (the children of one group, or one root) encodes within UnitBytesBound, its ranges taken
// from the mesh: the bound the builder splits groups by is an upper bound. Returns the largest unit's bytes.
size_t expect_units_within_their_bound(const BuiltMesh& mesh) {
    double farthest = 0, farthestUv = 0;
    for (float p : mesh.positions) farthest = std::max(farthest, double(std::fabs(p)));
    for (float u : mesh.uvs) farthestUv = std::max(farthestUv, double(std::fabs(u)));
    UnitBytesBound bound{UnitBytesBound::residual_bits(uint64_t(std::ceil(farthest / mesh.positionStep)) + 1), 0, !mesh.colors.empty(),
                         mesh.materialSlots > 1};
    if (!mesh.uvs.empty()) bound.uvBits = UnitBytesBound::residual_bits(uint64_t(std::ceil(farthestUv / std::ldexp(1.0, mesh.uvPrecision))) + 1);
    std::map<uint32_t, std::vector<uint32_t>> children;
    std::vector<std::vector<uint32_t>> units;
    for (uint32_t i = 0; i < mesh.clusters.size(); ++i)
        if (mesh.clusters[i].parentGroup == kNoGroup) units.push_back({i});
        else children[mesh.clusters[i].parentGroup].push_back(i);
    for (auto& [parent, list] : children) units.push_back(list);
    size_t largest = 0;
    for (const std::vector<uint32_t>& unit : units) {
        PageStreams streams;
        encode_unit(mesh, unit, streams);
        size_t bytes = 0, limit = UnitBytesBound::kUnitBytes;
        for (const auto& stream : streams) bytes += stream.size();
        for (uint32_t c : unit) limit += bound.cluster(mesh.clusters[c].vertexCount, mesh.clusters[c].triangleCount);
        EXPECT_LE(bytes, limit) << "a unit of " << unit.size() << " clusters";
        largest = std::max(largest, bytes);
    }
    return largest;
}

// A faceted, noisy mesh with a normal, a colour and texture coordinates per corner (a scan's raw export, say): every
// corner is its own vertex, so clusters hold 255 vertices for 85 triangles, and the residuals are wide. A group of such
// clusters encoded to more than a page (135 KiB in a fuzzed mesh): encode_pages threw, and a stage holding the mesh
// failed to render. The builder now splits such groups (UnitBytesBound): every group's children fit a page, and the
// file decodes.
TEST(Pages, GroupsOfFacetedMeshesWithEveryAttributeFitAPage) {
    const int n = 96;
    std::vector<float> points, normals, colors, uvs;
    std::vector<int32_t> counts, indices;
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> unit(0, 1);
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) points.insert(points.end(), {float(x) + 0.4f * unit(rng), float(y) + 0.4f * unit(rng), 30 * unit(rng)});
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            const int a = y * (n + 1) + x;
            counts.push_back(4);
            indices.insert(indices.end(), {a, a + 1, a + n + 2, a + n + 1});
            for (int k = 0; k < 4; ++k) {
                normals.insert(normals.end(), {unit(rng) - 0.5f, unit(rng) - 0.5f, 1.0f});
                colors.insert(colors.end(), {unit(rng), unit(rng), unit(rng)});
                uvs.insert(uvs.end(), {4096 * unit(rng), 4096 * unit(rng)});
            }
        }
    MeshView view = polygon_view("/Faceted", points, counts, indices);
    view.normals = {Interpolation::FaceVarying, 3, normals, {}};
    view.displayColor = {Interpolation::FaceVarying, 3, colors, {}};
    view.uvs = {Interpolation::FaceVarying, 2, uvs, {}};
    const BuiltMesh built = build_mesh(prepare_mesh(view));
    size_t fullClusters = 0;
    for (const Cluster& c : built.clusters) fullClusters += c.level == 0 && c.vertexCount >= 250;
    ASSERT_GT(fullClusters, 50u) << "clusters of a vertex per corner";
    PageLayout layout;
    std::vector<uint8_t> file;
    ASSERT_NO_THROW(file = encode_pages(built, &layout));
    std::map<uint32_t, uint32_t> pageOfGroup;
    std::map<uint32_t, size_t> unitSizes;
    for (uint32_t p = 0; p < layout.pages; ++p)
        for (uint32_t c : layout.pageClusters[p])
            if (const uint32_t parent = built.clusters[c].parentGroup; parent != kNoGroup) {
                auto [it, first] = pageOfGroup.try_emplace(parent, p);
                EXPECT_EQ(it->second, p) << "the children of group " << parent << " straddle pages";
                ++unitSizes[parent];
            }
    size_t largestUnit = 0;
    for (const auto& [parent, size] : unitSizes) largestUnit = std::max(largestUnit, size);
    EXPECT_GE(largestUnit, 6u) << "groups are split only as far as a page needs";
    const BuiltMesh decoded = decode_pages(file, "faceted");
    EXPECT_EQ(decoded.triangles, built.triangles);
    EXPECT_EQ(decoded.uvs, built.uvs);
    EXPECT_GT(expect_units_within_their_bound(built), size_t(kPageBytes / 2)) << "units that nearly fill a page";
    // And on meshes of other kinds.
    expect_units_within_their_bound(bumpy_grid(150, true, true));
    expect_units_within_their_bound(bumpy_grid(150, false));
}

TEST(Pages, EveryTruncationIsAClearError) {
    const std::vector<uint8_t> file = encode_pages(bumpy_grid(40, true));
    for (size_t length = 0; length < file.size(); length += 1 + length / 64) {
        try {
            decode_pages(std::span(file).first(length), "cut.tsra");
            FAIL() << "a file cut to " << length << " of " << file.size() << " bytes decoded";
        } catch (const PageFileError& e) {
            EXPECT_EQ(std::string(e.what()).rfind("cut.tsra: ", 0), 0u) << e.what();
        }
    }
}

TEST(Pages, CorruptBytesAreDetected) {
    const std::vector<uint8_t> file = encode_pages(bumpy_grid(40, true));
    std::mt19937 rng(11);
    for (int trial = 0; trial < 400; ++trial) {
        std::vector<uint8_t> broken = file;
        const size_t at = rng() % broken.size();
        broken[at] ^= uint8_t(1 + rng() % 255);
        EXPECT_THROW(decode_pages(broken, "flip.tsra"), PageFileError) << "a flipped byte at " << at << " went unnoticed";
    }
}

TEST(Pages, ForeignAndFutureFilesAreNamed) {
    std::vector<uint8_t> file = encode_pages(bumpy_grid(20, false));
    std::vector<uint8_t> foreign(file.size(), 0x42);
    try {
        decode_pages(foreign, "other.bin");
        FAIL();
    } catch (const PageFileError& e) {
        EXPECT_STREQ(e.what(), "other.bin: not a Tessera DAG file");
    }
    for (const uint32_t other : {kPageFormatVersion - 1, kPageFormatVersion + 1}) {  // an older file, a newer one
        std::memcpy(&file[4], &other, 4);
        try {
            decode_pages(file, "other.tsra");
            FAIL();
        } catch (const PageFileError& e) {
            EXPECT_NE(std::string(e.what()).find("format version " + std::to_string(other)), std::string::npos) << e.what();
        }
    }
}

TEST(Pages, Crc32IsTheStandardOne) {
    const std::string check = "123456789";
    EXPECT_EQ(crc32(std::span(reinterpret_cast<const uint8_t*>(check.data()), check.size())), 0xCBF43926u);
}

TEST(Pages, ClustersOfEverySizeRoundTrip) {
    // The largest clusters (255 vertices, the meshlet limit, and 256, the format's), the smallest (1 triangle).
    for (const auto [vertices, triangles] : {std::pair{255u, 128u}, std::pair{256u, 128u}, std::pair{3u, 1u}, std::pair{40u, 128u}}) {
        std::vector<std::array<float, 3>> directions;
        const BuiltMesh mesh = single_cluster(vertices, triangles, directions);
        const BuiltMesh back = decode_pages(encode_pages(mesh), "one.tsra");
        expect_same(mesh, back);
        for (uint32_t v = 0; v < vertices; ++v) EXPECT_LE(angle_degrees(directions[v], decode_octahedral(back.normals[v])), kNormalMaxErrorDegrees);
    }
}

TEST(Pages, MeshesOutOfPageOrderAreRefused) {
    std::vector<std::array<float, 3>> directions;
    BuiltMesh mesh = single_cluster(30, 20, directions);
    BuiltMesh rotated = mesh;  // one triangle turned (same winding): the decoder could not give it back
    const uint32_t t = rotated.triangles[3];
    rotated.triangles[3] = ((t >> 8) & 0xffff) | ((t & 0xff) << 16);
    EXPECT_THROW(encode_pages(rotated), std::invalid_argument);
    BuiltMesh renumbered = mesh;  // vertices not numbered by first use
    std::swap(renumbered.triangles[0], renumbered.triangles.back());
    EXPECT_THROW(encode_pages(renumbered), std::invalid_argument);
    BuiltMesh fineNormal = mesh;  // a normal finer than the stored bits
    fineNormal.normals[0] ^= 1;
    EXPECT_THROW(encode_pages(fineNormal), std::invalid_argument);
}

TEST(Pages, CorruptPagesWithValidChecksumsAreErrorsNotCrashes) {
    // Past the checksums (as if they had collided), a damaged page must still be an error or a mesh, never a
    // crash or a hang.
    const std::vector<uint8_t> file = encode_pages(bumpy_grid(40, true));
    uint64_t firstPage;
    std::memcpy(&firstPage, &file[kPageHeaderBytes], 8);
    std::mt19937 rng(17);
    int errors = 0;
    const int trials = 3000;
    for (int trial = 0; trial < trials; ++trial) {
        std::vector<uint8_t> broken = file;
        for (int flips = 1 + trial % 3; flips > 0; --flips) broken[firstPage + rng() % (broken.size() - firstPage)] ^= uint8_t(1 + rng() % 255);
        fix_checksums(broken);
        try {
            decode_pages(broken, "damaged.tsra");
        } catch (const PageFileError& e) {
            ++errors;
            EXPECT_EQ(std::string(e.what()).rfind("damaged.tsra: ", 0), 0u) << e.what();
        }
    }
    EXPECT_GT(errors, trials / 2) << "most damage is detected by the format itself";
}
