// The builder's own cluster builder (builder/clusters.cpp), called directly: budgets, coverage, compactness.
#include "clusters.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>

using namespace tessera;

namespace {

struct Soup {
    std::vector<float> positions;
    std::vector<uint32_t> indices;
};

// A grid of n x n quads: joined (shared vertices), or apart (each quad its own four vertices, half a unit wide, one
// unit between neighbours), in a shuffled triangle order so that the input order says nothing about where they are.
Soup quad_grid(int n, bool apart) {
    Soup s;
    auto vertex = [&](float x, float y) {
        s.positions.insert(s.positions.end(), {x, y, 0.1f * std::sin(x) * std::cos(y)});
        return uint32_t(s.positions.size() / 3 - 1);
    };
    if (!apart)
        for (int y = 0; y <= n; ++y)
            for (int x = 0; x <= n; ++x) vertex(float(x), float(y));
    std::vector<std::array<uint32_t, 3>> triangles;
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            uint32_t a, b, c, d;
            if (apart) {
                a = vertex(x, y), b = vertex(x + 0.5f, y), c = vertex(x, y + 0.5f), d = vertex(x + 0.5f, y + 0.5f);
            } else {
                a = uint32_t(y * (n + 1) + x), b = a + 1, c = a + uint32_t(n + 1), d = c + 1;
            }
            triangles.push_back({a, b, d});
            triangles.push_back({a, d, c});
        }
    for (size_t i = 0; i < triangles.size(); ++i) std::swap(triangles[i], triangles[(i * 7919) % triangles.size()]);
    for (auto& t : triangles) s.indices.insert(s.indices.end(), t.begin(), t.end());
    return s;
}

// Checks that the clusters hold every triangle exactly once and keep to the budgets.
void expect_partition(const Soup& s, const std::vector<std::vector<uint32_t>>& clusters, size_t maxVertices, size_t maxTriangles) {
    std::vector<std::array<uint32_t, 3>> in, out;
    for (size_t i = 0; i < s.indices.size(); i += 3) in.push_back({s.indices[i], s.indices[i + 1], s.indices[i + 2]});
    for (const auto& cluster : clusters) {
        ASSERT_EQ(cluster.size() % 3, 0u);
        EXPECT_LE(cluster.size() / 3, maxTriangles);
        std::vector<uint32_t> vertices(cluster);
        std::sort(vertices.begin(), vertices.end());
        EXPECT_LE(size_t(std::unique(vertices.begin(), vertices.end()) - vertices.begin()), maxVertices);
        for (size_t i = 0; i < cluster.size(); i += 3) out.push_back({cluster[i], cluster[i + 1], cluster[i + 2]});
    }
    std::sort(in.begin(), in.end());
    std::sort(out.begin(), out.end());
    EXPECT_EQ(in, out) << "every triangle exactly once, corners as given";
}

double mean_cluster_diagonal(const Soup& s, const std::vector<std::vector<uint32_t>>& clusters) {
    double sum = 0;
    for (const auto& cluster : clusters) {
        float lo[3] = {1e30f, 1e30f, 1e30f}, hi[3] = {-1e30f, -1e30f, -1e30f};
        for (uint32_t v : cluster)
            for (int k = 0; k < 3; ++k) {
                lo[k] = std::min(lo[k], s.positions[3 * v + k]);
                hi[k] = std::max(hi[k], s.positions[3 * v + k]);
            }
        sum += std::sqrt(double(hi[0] - lo[0]) * (hi[0] - lo[0]) + double(hi[1] - lo[1]) * (hi[1] - lo[1]) + double(hi[2] - lo[2]) * (hi[2] - lo[2]));
    }
    return sum / double(clusters.size());
}

}  // namespace

TEST(ClusterBuilder, ConnectedGridMakesFullCompactClusters) {
    const Soup s = quad_grid(64, false);  // 8192 triangles
    const auto clusters = build_clusters(s.indices.data(), s.indices.size(), s.positions.data(), s.positions.size() / 3, 255, 128);
    expect_partition(s, clusters, 255, 128);
    EXPECT_LE(clusters.size(), 66u) << "64 clusters would be full";
    // A full cluster is 64 quads; a square of them is 8 units across (diagonal 11.3), a row of the grid 64 (measured:
    // 15.2, meshoptimizer 16.0; runs of 126 triangles in input order 88).
    EXPECT_LT(mean_cluster_diagonal(s, clusters), 20.0);
}

TEST(ClusterBuilder, TheVertexBudgetBindsToo) {
    const Soup s = quad_grid(32, false);
    const auto clusters = build_clusters(s.indices.data(), s.indices.size(), s.positions.data(), s.positions.size() / 3, 24, 128);
    expect_partition(s, clusters, 24, 128);
    for (size_t c = 0; c + 1 < clusters.size(); ++c) EXPECT_GE(clusters[c].size() / 3, 12u) << "24 vertices hold at least 12 triangles of a grid";
}

TEST(ClusterBuilder, DisjointPartsAreClusteredWithTheirNearestNeighbours) {
    // Foliage-like input: 1600 separate quads. Once a quad is taken the cluster has nothing around it, so every next
    // quad comes from the nearest-triangle search: a cluster of 63 quads should be a blob about 8 units across (measured:
    // 16.1, meshoptimizer 16.0; runs in input order 55).
    const Soup s = quad_grid(40, true);
    const auto clusters = build_clusters(s.indices.data(), s.indices.size(), s.positions.data(), s.positions.size() / 3, 255, 128);
    expect_partition(s, clusters, 255, 128);
    EXPECT_LE(clusters.size(), 27u);
    EXPECT_LT(mean_cluster_diagonal(s, clusters), 20.0);
}

TEST(ClusterBuilder, Deterministic) {
    const Soup s = quad_grid(50, true);
    EXPECT_EQ(build_clusters(s.indices.data(), s.indices.size(), s.positions.data(), s.positions.size() / 3, 255, 128),
              build_clusters(s.indices.data(), s.indices.size(), s.positions.data(), s.positions.size() / 3, 255, 128));
}
