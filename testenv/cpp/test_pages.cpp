// The page file: exact round trip, page invariants, and clear errors for truncated, corrupt or foreign files.
#include "tessera/builder.h"

#include <gtest/gtest.h>

#include "test_meshes.h"

#include <cmath>
#include <cstring>
#include <random>
#include <map>
#include <set>

using namespace tessera;

namespace {

BuiltMesh bumpy_grid(int n, bool colors) {
    std::vector<float> points, colorValues;
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
        }
    MeshView v = polygon_view("/Grid", points, counts, indices);
    if (colors) v.displayColor = {Interpolation::Uniform, 3, colorValues, {}};
    return build_mesh(prepare_mesh(v));
}

void expect_same(const BuiltMesh& a, const BuiltMesh& b) {
    EXPECT_EQ(a.origin, b.origin);
    EXPECT_EQ(a.positionPrecision, b.positionPrecision);
    EXPECT_EQ(a.positions, b.positions);
    EXPECT_EQ(a.normals, b.normals);
    EXPECT_EQ(a.colors, b.colors);
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
}

}  // namespace

TEST(Pages, RoundTripIsExact) {
    for (bool colors : {false, true}) {
        BuiltMesh built = bumpy_grid(150, colors);
        const std::vector<uint8_t> file = encode_pages(built);
        expect_same(built, decode_pages(file, "grid.tsra"));
        EXPECT_EQ(file, encode_pages(built)) << "same mesh, same bytes";
    }
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
    EXPECT_LT(bytesPerTriangle, 40.0);
    RecordProperty("bytes_per_input_triangle", std::to_string(bytesPerTriangle));
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
    const uint32_t future = kPageFormatVersion + 1;
    std::memcpy(&file[4], &future, 4);
    try {
        decode_pages(file, "new.tsra");
        FAIL();
    } catch (const PageFileError& e) {
        EXPECT_NE(std::string(e.what()).find("format version " + std::to_string(future)), std::string::npos) << e.what();
    }
}
