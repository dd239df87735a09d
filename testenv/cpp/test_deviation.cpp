// A group's measured distance from the source (builder/deviation.cpp) against brute force: every point's distance to
// every triangle, by the tests' own nearest-point code; both ways (source points to the simplified triangles, simplified
// edges' midpoints to the input), on simplified sheets: the input a bumpy grid, the output a grid over every few of its
// vertices, as the simplifier keeps a subset.
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

// A simplified sheet and its group's positions.
struct SheetGroup {
    Sheet s;
    GroupPositions group;
    SheetGroup(int n, int stride, std::mt19937& rng) : s(sheet(n, stride, rng)), group(s.input, s.output.data(), s.output.size(), s.positionId) {}
};

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


// The simplified triangles' corners (9 floats each), and each triangle's piece: the sheet's output split at x = 1.
struct Output {
    std::vector<float> corners;
    std::vector<uint32_t> pieceOf;
};
Output output_of(const Sheet& s) {
    Output o;
    for (size_t t = 0; t < s.output.size(); t += 3) {
        for (int k = 0; k < 3; ++k) o.corners.insert(o.corners.end(), &s.positions[3 * s.output[t + k]], &s.positions[3 * s.output[t + k]] + 3);
        o.pieceOf.push_back(o.corners[o.corners.size() - 9] < 1.0f ? 0 : 1);
    }
    return o;
}

// The distance from p to the nearest simplified triangle.
double brute_distance(const Output& o, const float* p) {
    double nearest = INFINITY;
    for (size_t t = 0; t < o.pieceOf.size(); ++t)
        nearest = std::min(nearest, triangle_distance(p, &o.corners[9 * t], &o.corners[9 * t + 3], &o.corners[9 * t + 6]));
    return nearest;
}

// The source points of a simplified sheet: the input vertices the output dropped (anchored at themselves), points above
// and below the input's triangles anchored at a corner of theirs (as the level below carries them), and points far off.
std::vector<SourcePoint> source_points(const Sheet& s, std::mt19937& rng) {
    std::vector<char> kept(s.positionId.size(), 0);
    for (uint32_t v : s.output) kept[v] = 1;
    std::vector<SourcePoint> points;
    for (uint32_t v = 0; v < kept.size(); ++v)
        if (!kept[v]) points.push_back({{s.positions[3 * v], s.positions[3 * v + 1], s.positions[3 * v + 2]}, 0, v});
    std::uniform_int_distribution<size_t> triangle(0, s.input.size() / 3 - 1);
    std::uniform_real_distribution<float> weight(0.0f, 1.0f), height(-0.05f, 0.05f);
    for (int i = 0; i < 300; ++i) {
        const size_t t = 3 * triangle(rng);
        float a = weight(rng), b = weight(rng) * (1 - a);
        const float w[3] = {a, b, 1 - a - b};
        SourcePoint p{{0, 0, 0}, 0, s.input[t + i % 3]};
        for (int k = 0; k < 3; ++k)
            for (int j = 0; j < 3; ++j) p.position[k] += w[j] * s.positions[3 * s.input[t + j] + k];
        p.position[2] += i < 280 ? height(rng) : 3.0f;  // the last ones far off
        points.push_back(p);
    }
    return points;
}

}  // namespace

TEST(Deviation, NoLessThanTheTrueDistanceAndCloseToIt) {
    // The source points of simplified sheets (edges over 2, 3 and 5 input edges, so most points lie a ring or more from
    // the nearest kept vertex; bumps and a steep rise) against brute force.
    std::mt19937 rng(7);
    for (int stride : {2, 3, 5}) {
        SCOPED_TRACE(stride);
        const auto& [s, group] = SheetGroup(30, stride, rng);
        const Output o = output_of(s);
        const std::vector<SourcePoint> points = source_points(s, rng);
        const Deviation d = measure_deviation(group, o.corners, s.output.data(), o.pieceOf, 2, points, s.positionId, 8);
        double largest = 0;
        for (const SourcePoint& p : points) largest = std::max(largest, brute_distance(o, p.position));
        EXPECT_GT(largest, 2.9);
        EXPECT_GE(d.largest, largest * (1 - 1e-5));
        EXPECT_LE(d.largest, largest * 1.001) << "the farthest point measures its true distance";
        // Without the far points, the farthest is one of those near the surface: found as well.
        const std::vector<SourcePoint> near(points.begin(), points.end() - 20);
        double nearLargest = 0;
        for (const SourcePoint& p : near) nearLargest = std::max(nearLargest, brute_distance(o, p.position));
        const Deviation dn = measure_deviation(group, o.corners, s.output.data(), o.pieceOf, 2, near, s.positionId, 8);
        EXPECT_GE(dn.largest, nearLargest * (1 - 1e-5));
        EXPECT_LE(dn.largest, nearLargest * 1.001);
        // Each piece keeps at most 8 points, none at distance 0, each no nearer than it truly is and anchored at one of
        // the output's vertices (where the next level's search starts).
        for (const auto& kept : d.kept) {
            EXPECT_EQ(kept.size(), 8u);
            for (const SourcePoint& p : kept) {
                EXPECT_GT(p.distance, 0.0f);
                EXPECT_GE(p.distance, brute_distance(o, p.position) * (1 - 1e-5));
                EXPECT_NE(std::find(s.output.begin(), s.output.end(), p.anchor), s.output.end());
            }
        }
    }
}

TEST(Deviation, PointsOnTheSurfaceMeasureNothing) {
    // The simplified triangles' own corners lie at distance 0 and are kept by no piece; an empty group measures 0.
    std::mt19937 rng(3);
    const auto& [s, group] = SheetGroup(10, 2, rng);
    const Output o = output_of(s);
    std::vector<SourcePoint> points;
    for (uint32_t v : s.output) points.push_back({{s.positions[3 * v], s.positions[3 * v + 1], s.positions[3 * v + 2]}, 0, v});
    const Deviation d = measure_deviation(group, o.corners, s.output.data(), o.pieceOf, 2, points, s.positionId, 8);
    EXPECT_EQ(d.largest, 0.0f);
    EXPECT_TRUE(d.kept[0].empty() && d.kept[1].empty());
    const Deviation none = measure_deviation(group, {}, nullptr, {}, 0, points, s.positionId, 8);
    EXPECT_EQ(none.largest, 0.0f);
}

TEST(Deviation, PointsAnchoredOffTheGroupMeasureEveryTriangle) {
    // An anchor the group does not hold (a vertex of another part of the mesh): the point is measured against every
    // triangle, and finds its nearest.
    std::mt19937 rng(5);
    const auto& [s, group] = SheetGroup(12, 3, rng);
    const Output o = output_of(s);
    std::vector<uint32_t> positionId = s.positionId;
    positionId.push_back(uint32_t(positionId.size()));  // a vertex no triangle of the group uses
    const std::vector<SourcePoint> points = {{{0.55f, 0.62f, 0.4f}, 0, uint32_t(positionId.size() - 1)}};
    const Deviation d = measure_deviation(group, o.corners, s.output.data(), o.pieceOf, 2, points, positionId, 8);
    EXPECT_NEAR(d.largest, brute_distance(o, points[0].position), 1e-6);
}

TEST(Deviation, SimplifiedEdgesStrayAsFarAsBruteForceFinds) {
    // Simplified edges spanning 2, 3 and 5 input edges (their midpoints one ring or more from both ends), over bumps and
    // a steep rise: the walk over the input finds each midpoint's nearest input triangle.
    std::mt19937 rng(11);
    for (int stride : {2, 3, 5}) {
        SCOPED_TRACE(stride);
        const auto& [s, group] = SheetGroup(30, stride, rng);
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
    const auto& [s, group] = SheetGroup(12, 1, rng);
    EXPECT_EQ(measure_stray(group, s.positions), 0.0f);
}


// A simplified triangle with two corners at one place (two wedges of a seam, say: simplifying along seams leaves such)
// is the segment between its places: a point beside it measures its distance to that segment. The nearest-point code
// divided 0 by 0 there, and a point whose only nearby triangles were such measured an infinite distance, which made
// its group's error and every error above it infinite (found by a scratch fuzzer on duplicated, double-sided faces).
TEST(Deviation, TrianglesWithTwoCornersAtOnePlaceMeasureAsTheSegmentTheyAre) {
    const std::vector<float> positions = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0, 0, 0, 0};  // vertex 4: a wedge of vertex 0
    const std::vector<uint32_t> positionId = {0, 1, 2, 3, 0};
    const std::vector<uint32_t> input = {0, 1, 2, 1, 3, 2, 4, 2, 1}, output = {0, 4, 3};
    const GroupPositions group(input, output.data(), output.size(), positionId);
    ASSERT_TRUE(group.outputInInput);
    std::vector<float> corners;
    for (uint32_t v : output) corners.insert(corners.end(), &positions[3 * v], &positions[3 * v] + 3);
    const std::vector<SourcePoint> points = {{{0.5f, 0.5f, 0.2f}, 0, 1}, {{0.25f, 0.25f, -0.1f}, 0, 2}};
    const Deviation d = measure_deviation(group, corners, output.data(), {0}, 1, points, positionId, 8);
    EXPECT_NEAR(d.largest, 0.2f, 1e-6f);
    ASSERT_EQ(d.kept[0].size(), 2u);
    for (const SourcePoint& p : d.kept[0]) EXPECT_TRUE(std::isfinite(p.distance));
}
