// A group's measured distance from the source (builder/deviation.cpp) against brute force: every point's distance to
// every triangle, by the tests' own nearest-point code; both ways (source points to the simplified triangles, simplified
// edges' midpoints to the input).
#include "dag_fixtures.h"
#include "deviation.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>

using namespace tessera;

namespace {

// The distance from p to the triangle abc (the tests' own nearest point, dag_fixtures.h).
double triangle_distance(const float* p, const float* a, const float* b, const float* c) {
    double w[3];
    return std::sqrt(dagtest::nearest_on_triangle(p, a, b, c, w));
}

// A bumpy strip of triangles (nx by ny quads, 0.1 apart), two pieces split at its middle column.
struct Strip {
    std::vector<float> corners;
    std::vector<uint32_t> pieceOf;
};
Strip strip(int nx, int ny, std::mt19937& rng) {
    std::uniform_real_distribution<float> bump(-0.02f, 0.02f);
    std::vector<std::array<float, 3>> grid;
    for (int y = 0; y <= ny; ++y)
        for (int x = 0; x <= nx; ++x) grid.push_back({0.1f * x, 0.1f * y, bump(rng)});
    Strip s;
    for (int y = 0; y < ny; ++y)
        for (int x = 0; x < nx; ++x) {
            const int a = y * (nx + 1) + x, b = a + 1, c = a + nx + 1, d = c + 1;
            for (const std::array<int, 3>& t : {std::array<int, 3>{a, b, d}, {a, d, c}}) {
                for (int k : t) s.corners.insert(s.corners.end(), grid[k].begin(), grid[k].end());
                s.pieceOf.push_back(x < nx / 2 ? 0 : 1);
            }
        }
    return s;
}

}  // namespace

TEST(Deviation, NoLessThanTheTrueDistanceAndCloseToIt) {
    // Points near the surface, points far off (no cell near them lists a triangle), on a square patch and on a long
    // thin strip (a grid of one cell across).
    std::mt19937 rng(7);
    for (const auto& [nx, ny] : {std::pair{20, 20}, std::pair{400, 1}}) {
        SCOPED_TRACE(nx);
        const Strip simplified = strip(nx, ny, rng);
        std::uniform_real_distribution<float> across(0.0f, 0.1f * nx), along(0.0f, 0.1f * ny), height(-0.05f, 0.05f);
        std::vector<SourcePoint> points;
        for (int i = 0; i < 400; ++i) points.push_back({{across(rng), along(rng), height(rng)}, 0});
        for (int i = 0; i < 20; ++i) points.push_back({{across(rng), along(rng), 3.0f + height(rng)}, 0});  // far off
        const Deviation d = measure_deviation(simplified.corners, simplified.pieceOf, 2, points, 8);
        double largest = 0;
        for (const SourcePoint& p : points) {
            double nearest = INFINITY;
            for (size_t t = 0; t < simplified.pieceOf.size(); ++t)
                nearest = std::min(nearest, triangle_distance(p.position, &simplified.corners[9 * t], &simplified.corners[9 * t + 3],
                                                              &simplified.corners[9 * t + 6]));
            largest = std::max(largest, nearest);
        }
        EXPECT_GE(d.largest, largest * (1 - 1e-5));
        EXPECT_LE(d.largest, largest * 1.01) << "the farthest point measures its true distance";
        // Each piece keeps at most 8 points, the farthest it has first, none at distance 0.
        for (const auto& kept : d.kept) {
            EXPECT_LE(kept.size(), 8u);
            for (const SourcePoint& p : kept) EXPECT_GT(p.distance, 0.0f);
        }
        EXPECT_FALSE(d.kept[0].empty() || d.kept[1].empty());
    }
}

namespace {

// A bumpy sheet of (n + 1)^2 vertices 0.1 apart, `fold` of its rows bent up steeply at one end, and its simplification
// as the simplifier makes one: triangles over every `stride`-th vertex (a subset of the input's vertices).
struct Sheet {
    std::vector<float> positions;
    std::vector<uint32_t> input, output, positionId;
};
Sheet sheet(int n, int stride, std::mt19937& rng) {
    std::uniform_real_distribution<float> bump(-0.03f, 0.03f);
    Sheet s;
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) {
            const float lift = y > n - 3 ? 0.3f * float(y - (n - 3)) : 0.0f;  // the last rows rise steeply
            s.positions.insert(s.positions.end(), {0.1f * x, 0.1f * y, bump(rng) + lift});
            s.positionId.push_back(uint32_t(s.positionId.size()));
        }
    auto quads = [&](int step, std::vector<uint32_t>& to) {
        for (int y = 0; y + step <= n; y += step)
            for (int x = 0; x + step <= n; x += step) {
                const uint32_t a = y * (n + 1) + x, b = a + step, c = a + step * (n + 1), d = c + step;
                to.insert(to.end(), {a, b, d, a, d, c});
            }
    };
    quads(1, s.input);
    quads(stride, s.output);
    return s;
}

// Each simplified edge's midpoint to every input triangle: the largest of those distances.
double brute_stray(const Sheet& s) {
    double strayed = 0;
    for (size_t t = 0; t < s.output.size(); t += 3)
        for (int e = 0; e < 3; ++e) {
            const float* a = &s.positions[3 * s.output[t + e]];
            const float* b = &s.positions[3 * s.output[t + (e + 1) % 3]];
            const float m[3] = {0.5f * (a[0] + b[0]), 0.5f * (a[1] + b[1]), 0.5f * (a[2] + b[2])};
            double nearest = INFINITY;
            for (size_t u = 0; u < s.input.size(); u += 3)
                nearest = std::min(nearest, triangle_distance(m, &s.positions[3 * s.input[u]], &s.positions[3 * s.input[u + 1]],
                                                              &s.positions[3 * s.input[u + 2]]));
            strayed = std::max(strayed, nearest);
        }
    return strayed;
}

}  // namespace

TEST(Deviation, SimplifiedEdgesStrayAsFarAsBruteForceFinds) {
    // Simplified edges spanning 2, 3 and 5 input edges (their midpoints one ring or more from both ends), over bumps and
    // a steep rise: the walk over the input finds each midpoint's nearest input triangle.
    std::mt19937 rng(11);
    for (int stride : {2, 3, 5}) {
        SCOPED_TRACE(stride);
        const Sheet s = sheet(30, stride, rng);
        const GroupPositions group(s.input, s.output.data(), s.output.size(), s.positionId);
        const double expected = brute_stray(s);
        const float strayed = measure_stray(group, s.positions);
        EXPECT_GT(expected, 0.005);
        EXPECT_GE(strayed, expected * (1 - 1e-5));
        EXPECT_LE(strayed, expected * 1.001);
        // A known error above every midpoint's distance settles them all: the floor comes back; below, the distance.
        EXPECT_EQ(measure_stray(group, s.positions, float(2 * expected)), float(2 * expected));
        EXPECT_NEAR(measure_stray(group, s.positions, float(0.5 * expected)), strayed, 1e-6);
    }
}

TEST(Deviation, EdgesOfTheInputDoNotStray) {
    // The input itself as the simplified group: every edge is an input edge, every midpoint on the input.
    std::mt19937 rng(13);
    const Sheet s = sheet(12, 1, rng);
    const GroupPositions group(s.input, s.output.data(), s.output.size(), s.positionId);
    EXPECT_EQ(measure_stray(group, s.positions), 0.0f);
}

TEST(Deviation, PointsOnTheSurfaceMeasureNothing) {
    // The simplified triangles' own corners lie at distance 0 and are kept by no piece; an empty group measures 0.
    std::mt19937 rng(3);
    const Strip s = strip(10, 10, rng);
    std::vector<SourcePoint> points;
    for (size_t i = 0; i < s.corners.size(); i += 3) points.push_back({{s.corners[i], s.corners[i + 1], s.corners[i + 2]}, 0});
    const Deviation d = measure_deviation(s.corners, s.pieceOf, 2, points, 8);
    EXPECT_EQ(d.largest, 0.0f);
    EXPECT_TRUE(d.kept[0].empty() && d.kept[1].empty());
    const Deviation none = measure_deviation({}, {}, 0, points, 8);
    EXPECT_EQ(none.largest, 0.0f);
}

TEST(Deviation, PointsFarFromEveryTriangleFindTheNearest) {
    // Two patches at opposite corners of their box: points in the empty middle lie in cells that list no triangle, and
    // neither do the cells around them; they measure every triangle.
    std::mt19937 rng(5);
    Strip a = strip(6, 6, rng);
    const Strip b = strip(6, 6, rng);
    for (size_t i = 0; i < b.corners.size(); ++i) a.corners.push_back(b.corners[i] + 5.0f);
    a.pieceOf.insert(a.pieceOf.end(), b.pieceOf.size(), 1);
    std::fill(a.pieceOf.begin(), a.pieceOf.begin() + b.pieceOf.size(), 0);
    const std::vector<SourcePoint> points = {{{2.5f, 2.6f, 2.4f}, 0}, {{4.0f, 1.0f, 3.0f}, 0}};
    const Deviation d = measure_deviation(a.corners, a.pieceOf, 2, points, 8);
    double largest = 0;
    for (const SourcePoint& p : points) {
        double nearest = INFINITY;
        for (size_t t = 0; t < a.pieceOf.size(); ++t)
            nearest = std::min(nearest, triangle_distance(p.position, &a.corners[9 * t], &a.corners[9 * t + 3], &a.corners[9 * t + 6]));
        largest = std::max(largest, nearest);
    }
    EXPECT_NEAR(d.largest, largest, 1e-5 * largest);
}
