// The builder's own cluster builder (builder/clusters.cpp) against meshoptimizer's meshlet builder, which it must
// reproduce exactly: the DAG, the page files and every measurement of them depend on the clusters.
#include "clusters.h"
#include "dag_fixtures.h"
#include "weld.h"

#include <meshoptimizer.h>

#include <gtest/gtest.h>

#include <array>
#include <filesystem>
#include <map>
#include <random>
#include <set>

using namespace tessera;
using namespace dagtest;

namespace {

// meshoptimizer's clusters, each as its corners in the order taken.
std::vector<std::vector<uint32_t>> meshoptimizer_clusters(const PreparedMesh& m, size_t maxVertices, size_t maxTriangles) {
    const size_t bound = meshopt_buildMeshletsBound(m.indices.size(), maxVertices, maxTriangles);
    std::vector<meshopt_Meshlet> meshlets(bound);
    std::vector<unsigned int> vertices(bound * maxVertices);
    std::vector<unsigned char> triangles(bound * maxTriangles * 3);
    const size_t count = meshopt_buildMeshlets(meshlets.data(), vertices.data(), triangles.data(), m.indices.data(), m.indices.size(), m.positions.data(),
                                               m.positions.size() / 3, 12, maxVertices, maxTriangles, 0.0f);
    std::vector<std::vector<uint32_t>> clusters(count);
    for (size_t c = 0; c < count; ++c)
        for (size_t i = 0; i < meshlets[c].triangle_count * 3; ++i)
            clusters[c].push_back(vertices[meshlets[c].vertex_offset + triangles[meshlets[c].triangle_offset + i]]);
    return clusters;
}

// Returns whether ours answered (false: it left the mesh to meshoptimizer); when it did, its clusters must be the same.
bool expect_same_clusters(const Source& source, size_t maxVertices = 255, size_t maxTriangles = 128) {
    const PreparedMesh m = prepare_mesh(polygon_view(source.name, source.points, source.counts, source.indices));
    std::vector<std::vector<uint32_t>> ours;
    std::vector<uint32_t> clusterOf;
    const bool answered =
        build_clusters(m.indices.data(), m.indices.size(), m.positions.data(), m.positions.size() / 3, maxVertices, maxTriangles, ours, &clusterOf);
    if (!answered) {
        EXPECT_TRUE(ours.empty()) << source.name;
        return false;
    }
    // Each triangle's cluster, as it says, holds that triangle (its corners in their order), and the clusters hold
    // each triangle once.
    EXPECT_EQ(clusterOf.size(), m.indices.size() / 3) << source.name;
    std::vector<std::multiset<std::array<uint32_t, 3>>> held(ours.size());
    for (size_t c = 0; c < ours.size(); ++c)
        for (size_t i = 0; i < ours[c].size(); i += 3) held[c].insert({ours[c][i], ours[c][i + 1], ours[c][i + 2]});
    size_t misplaced = 0;
    for (size_t t = 0; t < clusterOf.size(); ++t) {
        auto* in = clusterOf[t] < held.size() ? &held[clusterOf[t]] : nullptr;
        const auto it = in ? in->find({m.indices[3 * t], m.indices[3 * t + 1], m.indices[3 * t + 2]}) : held[0].end();
        if (!in || it == in->end()) ++misplaced;
        else in->erase(it);
    }
    EXPECT_EQ(misplaced, 0u) << source.name << ": triangles not in the cluster said to hold them";
    const auto theirs = meshoptimizer_clusters(m, maxVertices, maxTriangles);
    EXPECT_EQ(ours.size(), theirs.size()) << source.name;
    size_t first = 0;  // the first cluster that differs
    while (first < std::min(ours.size(), theirs.size()) && ours[first] == theirs[first]) ++first;
    EXPECT_EQ(first, std::min(ours.size(), theirs.size())) << source.name << ": cluster " << first << " of " << theirs.size() << " differs";
    return true;
}

// A grid of quads whose points are moved a little at random: no two distances are equal, so ours always answers.
Source jittered_grid(int n, bool apart) {
    Source s = apart ? quad_soup(n * n) : grid(n);
    std::mt19937 rng(n);
    std::uniform_real_distribution<float> u(-0.2f / float(n), 0.2f / float(n));
    for (float& p : s.points) p += u(rng);
    return s;
}

}  // namespace

TEST(ClusterBuilder, SameClustersAsMeshoptimizer) {
    const bool assets = std::filesystem::exists(shared_asset("meshes/stanford-bunny.obj")) && std::filesystem::exists(shared_asset("meshes/spot.obj"));
    if (assets) EXPECT_TRUE(expect_same_clusters(obj(shared_asset("meshes/stanford-bunny.obj"))));
    EXPECT_TRUE(expect_same_clusters(jittered_grid(90, false)));
    EXPECT_TRUE(expect_same_clusters(jittered_grid(40, true))) << "disjoint quads: every next quad is a nearest-triangle jump";
    EXPECT_TRUE(expect_same_clusters(quad_soup(3000)));
    // Equally near triangles, where meshoptimizer's k-d tree order decides: the first triangle (nearest to the
    // origin) of a mesh symmetric about it, and the jumps between the regular quads of a grid.
    if (assets) EXPECT_TRUE(expect_same_clusters(obj(shared_asset("meshes/spot.obj"))));
    EXPECT_TRUE(expect_same_clusters(icosphere(4)));
    EXPECT_TRUE(expect_same_clusters(grid(64)));
    Source spaced = grid(40);  // the grid's quads apart: every next quad is a jump
    spaced.points.clear();
    spaced.indices.clear();
    spaced.counts.clear();
    for (int y = 0; y < 40; ++y)
        for (int x = 0; x < 40; ++x) {
            const int base = int(spaced.points.size() / 3);
            spaced.points.insert(spaced.points.end(), {float(x), float(y), 0, x + 0.5f, float(y), 0, x + 0.5f, y + 0.5f, 0, float(x), y + 0.5f, 0});
            spaced.counts.push_back(4);
            spaced.indices.insert(spaced.indices.end(), {base, base + 1, base + 2, base + 3});
        }
    EXPECT_TRUE(expect_same_clusters(spaced));
    if (!assets) GTEST_SKIP() << "the bunny and spot cases need ../shared/assets (the generated meshes were tested)";
}

TEST(ClusterBuilder, SameClustersUnderOtherBudgets) {
    EXPECT_TRUE(expect_same_clusters(jittered_grid(30, true), 255, 16));
    const auto path = shared_asset("meshes/stanford-bunny.obj");
    if (!std::filesystem::exists(path)) GTEST_SKIP() << "shared asset " << path << " is not present (the generated mesh was tested)";
    const Source bunny = obj(path);
    EXPECT_TRUE(expect_same_clusters(bunny, 24, 128)) << "the vertex budget binds";
    EXPECT_TRUE(expect_same_clusters(bunny, 64, 32));
}

TEST(ClusterBuilder, LeavesMeshesOfNoAreaToMeshoptimizer) {
    // Collinear triangles: meshoptimizer's scores divide by a zero expected radius, which ours does not reproduce.
    const std::vector<float> positions = {0, 0, 0, 1, 0, 0, 2, 0, 0, 3, 0, 0};
    const std::vector<uint32_t> indices = {0, 1, 2, 1, 2, 3};
    std::vector<std::vector<uint32_t>> clusters = {{7}};
    EXPECT_FALSE(build_clusters(indices.data(), indices.size(), positions.data(), 4, 255, 128, clusters));
    EXPECT_TRUE(clusters.empty());
}

// The exact position weld (builder/weld.h) shards large inputs over the cores: every position must still map to the
// first index with its bits (-0 as +0), as the serial weld gives, whatever the shard a position falls in.
TEST(PositionWeld, ParallelWeldIsTheSerialOne) {
    std::mt19937 random(7);
    const size_t count = 700'000;  // above the size where the weld shards
    std::vector<float> xyz(3 * count);
    std::uniform_int_distribution<int> pick(0, 99'999);  // about 7 indices per position, in scattered order
    for (size_t i = 0; i < count; ++i) {
        const int p = pick(random);
        xyz[3 * i] = float(p % 100) * 0.25f;
        xyz[3 * i + 1] = float(p / 100 % 100) * 0.5f;
        xyz[3 * i + 2] = p % 7 == 0 ? ((i & 1) ? -0.0f : 0.0f) : float(p / 10'000);
    }
    std::map<std::array<float, 3>, uint32_t> first;  // the serial rule, by value (-0 == +0 as floats)
    std::vector<uint32_t> expected(count);
    for (size_t i = 0; i < count; ++i) expected[i] = first.try_emplace({xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]}, uint32_t(i)).first->second;
    ASSERT_GT(count / first.size(), 5u);
    EXPECT_EQ(weld_equal_positions(xyz.data(), count), expected);
    PositionWelder kept;  // the serial path, which keeps its welder for later additions
    EXPECT_EQ(weld_equal_positions(xyz.data(), count, &kept), expected);
}
