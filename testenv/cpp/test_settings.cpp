// The builder's Nanite-style settings: validation, Preserve Area, trimming (Keep Triangle Percent, Trim Relative
// Error), the fallback mesh, and the edge length limit. Every DAG built with a setting is checked monotone and crack-free.
#include "dag_fixtures.h"

#include <algorithm>

using namespace tessera;
using namespace dagtest;

namespace {

// Uniform cuts in mesh units, as the builder chooses them: t < 0 is the stored leaf level, else every cluster with
// lodError <= t < parentError.
std::vector<uint32_t> cut_at(const BuiltMesh& m, double t) {
    std::vector<uint32_t> chosen;
    for (uint32_t i = 0; i < m.clusters.size(); ++i) {
        const Cluster& c = m.clusters[i];
        if (t < 0 ? c.level == 0 : c.lodError <= t && t < c.parentError) chosen.push_back(i);
    }
    return chosen;
}

struct CutMeasure {
    double threshold;  // -1: the leaves
    uint64_t triangles = 0;
    float error = 0;
};

// Every distinct uniform cut of an untrimmed DAG, fine to coarse.
std::vector<CutMeasure> all_cuts(const BuiltMesh& m) {
    std::vector<double> thresholds{-1};
    for (const Cluster& c : m.clusters) thresholds.push_back(c.lodError);
    std::sort(thresholds.begin(), thresholds.end());
    thresholds.erase(std::unique(thresholds.begin(), thresholds.end()), thresholds.end());
    std::vector<CutMeasure> cuts;
    for (double t : thresholds) {
        CutMeasure cut{t};
        for (uint32_t i : cut_at(m, t)) {
            cut.triangles += m.clusters[i].triangleCount;
            cut.error = std::max(cut.error, m.clusters[i].lodError);
        }
        cuts.push_back(cut);
    }
    return cuts;
}

// The first cut, fine to coarse, with error >= minError and triangles <= maxTriangles (the settings' rule).
CutMeasure first_cut(const std::vector<CutMeasure>& cuts, double minError, double maxTriangles) {
    for (const CutMeasure& c : cuts)
        if (c.error >= minError && double(c.triangles) <= maxTriangles) return c;
    return cuts.back();
}

uint64_t triangles_of(const BuiltMesh& m, const std::vector<uint32_t>& clusters) {
    uint64_t n = 0;
    for (uint32_t i : clusters) n += m.clusters[i].triangleCount;
    return n;
}

// Area seen along z (every quad of the test fields faces +z).
double projected_area(const BuiltMesh& m, const std::vector<uint32_t>& clusters) {
    double area = 0;
    for (uint32_t i : clusters) {
        const Cluster& c = m.clusters[i];
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            const uint32_t packed = m.triangles[c.triangleOffset + t];
            const float* p[3];
            for (int k = 0; k < 3; ++k) p[k] = &m.positions[3 * (c.vertexOffset + ((packed >> (8 * k)) & 0xff))];
            area += 0.5 * std::fabs(double(p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - double(p[1][1] - p[0][1]) * (p[2][0] - p[0][0]));
        }
    }
    return area;
}

// Foliage seen from above: disjoint square cards of cells x cells quads facing +z, at random places, heights and turns.
// Cards of several quads may straddle groups, so some of their border vertices are locked while others move.
Source card_field(int count, int cells) {
    Source s;
    s.name = "/Cards";
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(0, 1);
    const float half = 0.04f * std::sqrt(float(cells));
    for (int i = 0; i < count; ++i) {
        const float x = u(rng) * 10, y = u(rng) * 10, z = u(rng), a = u(rng) * 1.57f;
        const float ax = std::cos(a), ay = std::sin(a);  // the card's own axes: (ax, ay) and (-ay, ax)
        const int base = int(s.points.size() / 3);
        for (int j = 0; j <= cells; ++j)
            for (int k = 0; k <= cells; ++k) {
                const float p = half * (2.0f * k / cells - 1), q = half * (2.0f * j / cells - 1);
                s.points.insert(s.points.end(), {x + p * ax - q * ay, y + p * ay + q * ax, z});
            }
        for (int j = 0; j < cells; ++j)
            for (int k = 0; k < cells; ++k) {
                const int c = base + j * (cells + 1) + k;
                s.counts.push_back(4);
                s.indices.insert(s.indices.end(), {c, c + 1, c + cells + 2, c + cells + 1});
            }
    }
    return s;
}

// A gently bumpy round sheet with a hole in every 8 x 8 block of quads (a quarter of it missing): a square grid mapped
// onto a disc, so that its outline is a circle, which coarser levels cut into fewer, shorter chords (covering less:
// what Preserve Area restores; the bumps they flatten cover the same).
Source perforated_sheet(int n) {
    Source s;
    s.name = "/Sheet";
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) {
            const float u = 2.0f * x / n - 1.0f, v = 2.0f * y / n - 1.0f;
            s.points.insert(s.points.end(), {u * std::sqrt(1.0f - 0.5f * v * v), v * std::sqrt(1.0f - 0.5f * u * u),
                                             0.02f * std::sin(x * 0.3f) * std::cos(y * 0.2f)});
        }
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            if (x % 8 >= 2 && x % 8 < 6 && y % 8 >= 2 && y % 8 < 6) continue;
            const int a = y * (n + 1) + x;
            s.counts.push_back(4);
            s.indices.insert(s.indices.end(), {a, a + 1, a + n + 2, a + n + 1});
        }
    return s;
}

using PositionKey = std::array<uint32_t, 3>;

PositionKey key_of(const float* p) {
    PositionKey k;
    std::memcpy(k.data(), p, 12);
    return k;
}

double length(const PositionKey& a, const PositionKey& b) {
    float pa[3], pb[3];
    std::memcpy(pa, a.data(), 12);
    std::memcpy(pb, b.data(), 12);
    return std::sqrt(double(pa[0] - pb[0]) * (pa[0] - pb[0]) + double(pa[1] - pb[1]) * (pa[1] - pb[1]) + double(pa[2] - pb[2]) * (pa[2] - pb[2]));
}

// Edges (by position) of the given clusters, and the mean length of their triangles' edges.
std::set<std::pair<PositionKey, PositionKey>> edges_of(const BuiltMesh& m, const std::vector<uint32_t>& clusters, double* meanLength = nullptr) {
    std::set<std::pair<PositionKey, PositionKey>> edges;
    double sum = 0;
    size_t count = 0;
    for (uint32_t i : clusters) {
        const Cluster& c = m.clusters[i];
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            const uint32_t packed = m.triangles[c.triangleOffset + t];
            for (int k = 0; k < 3; ++k) {
                const PositionKey a = position_bits(m, c, (packed >> (8 * k)) & 0xff), b = position_bits(m, c, (packed >> (8 * ((k + 1) % 3))) & 0xff);
                edges.insert(std::minmax(a, b));
                sum += length(a, b);
                ++count;
            }
        }
    }
    if (meanLength) *meanLength = sum / double(std::max<size_t>(count, 1));
    return edges;
}

std::vector<uint32_t> leaves(const BuiltMesh& m) { return cut_at(m, -1); }

std::vector<uint32_t> above_leaves(const BuiltMesh& m) {
    std::vector<uint32_t> out;
    for (uint32_t i = m.leafClusters; i < m.clusters.size(); ++i) out.push_back(i);
    return out;
}

}  // namespace

TEST(Settings, DefaultsAreNanites) {
    const BuildSettings s;
    EXPECT_EQ(s.positionPrecision, BuildSettings::kAutoPrecision);
    EXPECT_FALSE(s.preserveArea);
    EXPECT_EQ(s.trimRelativeError, 0.0f);
    EXPECT_EQ(s.keepTrianglePercent, 100.0f);
    EXPECT_EQ(s.fallbackRelativeError, 1.0f);
    EXPECT_EQ(s.fallbackTrianglePercent, 100.0f);
    EXPECT_EQ(s.maxEdgeLengthFactor, 0.0f);
    EXPECT_NO_THROW(validate_settings(s));
}

TEST(Settings, BadValuesAreRejectedByName) {
    const Source s = grid(8);
    struct Case {
        const char* name;
        BuildSettings settings;
    };
    std::vector<Case> cases;
    auto add = [&](const char* name, auto change) {
        BuildSettings b;
        change(b);
        cases.push_back({name, b});
    };
    add("keepTrianglePercent", [](BuildSettings& b) { b.keepTrianglePercent = -1; });
    add("keepTrianglePercent", [](BuildSettings& b) { b.keepTrianglePercent = 100.5f; });
    add("keepTrianglePercent", [](BuildSettings& b) { b.keepTrianglePercent = NAN; });
    add("fallbackTrianglePercent", [](BuildSettings& b) { b.fallbackTrianglePercent = -0.1f; });
    add("trimRelativeError", [](BuildSettings& b) { b.trimRelativeError = -2; });
    add("trimRelativeError", [](BuildSettings& b) { b.trimRelativeError = INFINITY; });
    add("fallbackRelativeError", [](BuildSettings& b) { b.fallbackRelativeError = NAN; });
    add("maxEdgeLengthFactor", [](BuildSettings& b) { b.maxEdgeLengthFactor = -1; });
    add("positionPrecision", [](BuildSettings& b) { b.positionPrecision = 200; });
    for (const Case& c : cases) {
        try {
            s.build(c.settings);
            ADD_FAILURE() << c.name << ": a bad value was accepted";
        } catch (const std::invalid_argument& e) {
            EXPECT_NE(std::string(e.what()).find(c.name), std::string::npos) << e.what();
        }
    }
    BuildSettings edges;  // the ends of every range are fine
    edges.keepTrianglePercent = 0;
    edges.fallbackTrianglePercent = 100;
    edges.positionPrecision = -64;
    EXPECT_NO_THROW(validate_settings(edges));
}

TEST(Settings, BuildsStayDeterministic) {
    // Groups simplify in parallel; pins and moved vertices must not make the output depend on thread timing.
    BuildSettings s;
    s.preserveArea = true;
    s.maxEdgeLengthFactor = 6;
    s.keepTrianglePercent = 60;
    for (const Source& source : {card_field(400, 4), grid(80, true)}) {
        const BuiltMesh a = source.build(s), b = source.build(s);
        EXPECT_EQ(a.positions, b.positions);
        EXPECT_EQ(a.triangles, b.triangles);
        ASSERT_EQ(a.clusters.size(), b.clusters.size());
        EXPECT_EQ(std::memcmp(a.clusters.data(), b.clusters.data(), a.clusters.size() * sizeof(Cluster)), 0);
        EXPECT_EQ(fallback_mesh(a).indices, fallback_mesh(b).indices);
    }
}

TEST(PreserveArea, CardFieldKeepsItsAreaAtCoarseLevels) {
    // Single-quad cards (whole cards are dropped as levels coarsen) and 4 x 4-quad cards (also simplified inside).
    for (auto [count, cells] : {std::pair{6000, 1}, std::pair{800, 4}}) {
        const Source field = card_field(count, cells);
        BuildSettings on;
        on.preserveArea = true;
        const BuiltMesh with = field.build(on), without = field.build();
        const double source = projected_area(with, leaves(with));
        ASSERT_NEAR(source, projected_area(without, leaves(without)), 1e-3 * source);
        // Uniform cuts a third, two thirds and all of the way up the errors (the last is the roots): with the
        // setting the area stays within 2 %; without it the roots keep less than half.
        for (const BuiltMesh* m : {&with, &without}) {
            float top = 0;
            for (const Cluster& c : m->clusters) top = std::max(top, c.lodError);
            for (double t : {top / 3.0, 2 * top / 3.0, double(top)}) {
                const auto cut = cut_at(*m, t);
                ASSERT_LT(triangles_of(*m, cut), with.sourceTriangles / 3) << "a coarse cut";
                const double ratio = projected_area(*m, cut) / source;
                if (m == &with) EXPECT_NEAR(ratio, 1.0, 0.02) << cells << "-quad cards, cut at " << t;
                else if (t == top) EXPECT_LT(ratio, 0.5) << cells << "-quad cards lose area without the setting";
            }
        }
        expect_monotone(with);
        expect_crack_free_cuts(with, 20);
    }
}

TEST(PreserveArea, OpenSheetStaysCrackFreeWhereBordersMove) {
    const Source sheet = perforated_sheet(96);
    BuildSettings on;
    on.preserveArea = true;
    const BuiltMesh m = sheet.build(on);
    std::set<PositionKey> leafPositions;
    for (uint32_t i : leaves(m))
        for (uint32_t v = 0; v < m.clusters[i].vertexCount; ++v) leafPositions.insert(position_bits(m, m.clusters[i], v));
    size_t moved = 0;
    for (uint32_t i : above_leaves(m))
        for (uint32_t v = 0; v < m.clusters[i].vertexCount; ++v) moved += !leafPositions.count(position_bits(m, m.clusters[i], v));
    EXPECT_GT(moved, 0u) << "some groups lost area and moved their open borders (or the test proves nothing)";
    expect_monotone(m);
    expect_crack_free_cuts(m, 40);
}

TEST(PreserveArea, FlattenedBumpsAskForNoDilation) {
    // A bumpy square sheet: coarser levels flatten its bumps, which shrinks its surface but not what it covers (its
    // straight outline stays). Measured as surface area, Preserve Area pushed its borders out at every level, and the
    // moved borders raised the levels' errors up to the dilation's cap; measured as covered area, it keeps them.
    Source sheet;
    sheet.name = "/BumpySheet";
    const int n = 96;
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x)
            sheet.points.insert(sheet.points.end(), {float(x) / n, float(y) / n, 0.03f * std::sin(x * 0.5f) * std::cos(y * 0.4f)});
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            const int a = y * (n + 1) + x;
            sheet.counts.push_back(4);
            sheet.indices.insert(sheet.indices.end(), {a, a + 1, a + n + 2, a + n + 1});
        }
    BuildSettings on;
    on.preserveArea = true;
    const BuiltMesh with = sheet.build(on), without = sheet.build();
    ASSERT_EQ(with.levels.size(), without.levels.size());
    for (size_t level = 1; level < with.levels.size(); ++level)
        EXPECT_LE(with.levels[level].maxError, 1.1f * without.levels[level].maxError) << "level " << level;
}

TEST(PreserveArea, ClosedMeshesHaveNoBorderToMove) {
    BuildSettings on;
    on.preserveArea = true;
    const BuiltMesh a = icosphere(4).build(on), b = icosphere(4).build();
    EXPECT_EQ(a.positions, b.positions);
    EXPECT_EQ(a.triangles, b.triangles);
}

TEST(Trim, KeepTrianglePercentStoresTheFirstCutWithinBudget) {
    const Source sphere = icosphere(5);
    const BuiltMesh full = sphere.build();
    BuildSettings keep;
    keep.keepTrianglePercent = 25;
    const BuiltMesh trimmed = sphere.build(keep);
    const auto cuts = all_cuts(full);
    const CutMeasure expected = first_cut(cuts, 0, 0.25 * full.sourceTriangles);
    EXPECT_EQ(trimmed.sourceTriangles, full.sourceTriangles);
    EXPECT_EQ(trimmed.leafTriangles, expected.triangles);
    EXPECT_LE(trimmed.leafTriangles, 0.25 * full.sourceTriangles);
    EXPECT_GE(trimmed.leafTriangles, 0.15 * full.sourceTriangles) << "one group step coarser than the budget at most";
    EXPECT_EQ(trimmed.leafError, expected.error);
    EXPECT_EQ(trimmed.levels[0].maxError, 0.0f) << "stored leaves are drawn whenever the runtime wants full detail";
    expect_monotone(trimmed);
    expect_crack_free_cuts(trimmed, 200);  // few levels remain: enough cuts to land between them
}

TEST(Trim, TrimRelativeErrorDropsDetailBelowIt) {
    const Source sphere = icosphere(5);
    const BuiltMesh full = sphere.build();
    BuildSettings trim;
    trim.trimRelativeError = 0.5f;  // percent of the mesh size
    const BuiltMesh trimmed = sphere.build(trim);
    const double minError = 0.005 * full.size;
    const auto cuts = all_cuts(full);
    const CutMeasure expected = first_cut(cuts, minError, INFINITY);
    EXPECT_GE(trimmed.leafError, minError);
    EXPECT_EQ(trimmed.leafError, expected.error);
    EXPECT_EQ(trimmed.leafTriangles, expected.triangles);
    EXPECT_LT(trimmed.leafTriangles, full.leafTriangles);
    for (const Cluster& c : trimmed.clusters)
        if (c.level > 0) EXPECT_GT(c.lodError, trimmed.leafError) << "what is kept above the leaves is coarser than them";
    expect_monotone(trimmed);
    expect_crack_free_cuts(trimmed, 30);

    // Both at once: the more reduced of the two.
    trim.keepTrianglePercent = 10;
    const BuiltMesh both = sphere.build(trim);
    EXPECT_EQ(both.leafTriangles, first_cut(cuts, minError, 0.10 * full.sourceTriangles).triangles);
    EXPECT_LE(both.leafTriangles, std::min<uint64_t>(trimmed.leafTriangles, 0.10 * full.sourceTriangles));
}

TEST(Trim, TrimmedMeshesRoundTripThroughPages) {
    BuildSettings keep;
    keep.keepTrianglePercent = 30;
    const BuiltMesh m = grid(100, true).build(keep);
    const BuiltMesh back = decode_pages(encode_pages(m), "trimmed");
    EXPECT_EQ(back.leafTriangles, m.leafTriangles);
    EXPECT_EQ(back.positions, m.positions);
    EXPECT_EQ(back.groups, m.groups);
    expect_monotone(m);
    expect_crack_free_cuts(m, 25);
}

TEST(Fallback, DefaultIsTheFirstCutAtOnePercentOfTheSize) {
    const BuiltMesh m = icosphere(5).build();
    const FallbackMesh f = fallback_mesh(m);
    const CutMeasure expected = first_cut(all_cuts(m), 0.01 * m.size, INFINITY);
    ASSERT_EQ(f.indices.size() % 3, 0u);
    EXPECT_EQ(f.indices.size() / 3, expected.triangles);
    EXPECT_EQ(f.error, expected.error);
    EXPECT_GE(f.error, 0.01 * m.size);
    EXPECT_LT(f.indices.size() / 3, m.sourceTriangles);
    ASSERT_EQ(f.normals.size(), f.positions.size());
    for (size_t v = 0; v < f.normals.size(); v += 3)
        EXPECT_NEAR(std::sqrt(f.normals[v] * f.normals[v] + f.normals[v + 1] * f.normals[v + 1] + f.normals[v + 2] * f.normals[v + 2]), 1.0, 1e-3);
    // Crack-free: on a closed mesh every edge (by position) joins exactly two triangles.
    std::map<std::pair<PositionKey, PositionKey>, int> uses;
    for (size_t i = 0; i < f.indices.size(); i += 3)
        for (int k = 0; k < 3; ++k) {
            ASSERT_LT(f.indices[i + k], f.positions.size() / 3);
            ++uses[std::minmax(key_of(&f.positions[3 * f.indices[i + k]]), key_of(&f.positions[3 * f.indices[i + (k + 1) % 3]]))];
        }
    for (auto& [edge, n] : uses) ASSERT_GE(n, 2) << "an edge of the fallback mesh is open";
}

TEST(Fallback, FollowsTrianglePercentAndNeverExceedsTheStoredDetail) {
    const Source sphere = icosphere(5);
    BuildSettings s;
    s.fallbackRelativeError = 0;
    s.fallbackTrianglePercent = 10;
    const BuiltMesh tenth = sphere.build(s);
    EXPECT_LE(fallback_mesh(tenth).indices.size() / 3, 0.10 * tenth.sourceTriangles);
    EXPECT_EQ(fallback_mesh(tenth).indices.size() / 3, first_cut(all_cuts(tenth), 0, 0.10 * tenth.sourceTriangles).triangles);
    s.fallbackTrianglePercent = 100;
    const BuiltMesh whole = sphere.build(s);
    EXPECT_EQ(fallback_mesh(whole).indices.size() / 3, whole.sourceTriangles) << "0 % error and 100 % triangles: the source itself";
    EXPECT_EQ(fallback_mesh(whole).error, 0.0f);
    s.keepTrianglePercent = 25;
    const BuiltMesh trimmed = sphere.build(s);
    EXPECT_EQ(fallback_mesh(trimmed).indices.size() / 3, trimmed.leafTriangles) << "the fallback is never finer than what is stored";
    EXPECT_EQ(fallback_mesh(trimmed).error, trimmed.leafError);
}

TEST(Fallback, RestoredFromADecodedDagByItsThreshold) {
    BuildSettings trimmed;
    trimmed.keepTrianglePercent = 40;
    for (const BuildSettings& s : {BuildSettings{}, trimmed}) {
        const BuiltMesh m = icosphere(5).build(s);
        const FallbackMesh built = fallback_mesh(m), f = fallback_mesh(decode_pages(encode_pages(m), "sphere"));
        ASSERT_FALSE(built.indices.empty());
        EXPECT_EQ(f.positions, built.positions);
        EXPECT_EQ(f.normals, built.normals);
        EXPECT_EQ(f.indices, built.indices);
        EXPECT_EQ(f.error, built.error);
    }
}

TEST(MaxEdgeLength, SimplificationCreatesNoEdgeLongerThanTheLimit) {
    // A bumpy grid, and one whose last columns are stretched into long thin quads (source edges over the limit).
    Source stretched = grid(100);
    for (size_t i = 0; i < stretched.points.size(); i += 3)
        if (stretched.points[i] > 0.9f) stretched.points[i] = 0.9f + (stretched.points[i] - 0.9f) * 12;
    for (const Source& s : {grid(120), stretched}) {
        BuildSettings limited;
        limited.maxEdgeLengthFactor = 4;
        const BuiltMesh free = s.build(), m = s.build(limited);
        double mean = 0;
        const auto sourceEdges = edges_of(m, leaves(m), &mean);
        const double limit = 4 * mean;
        size_t longInFree = 0;
        for (auto& e : edges_of(free, above_leaves(free)))
            if (!sourceEdges.count(e) && length(e.first, e.second) > limit) ++longInFree;
        EXPECT_GT(longInFree, 0u) << "without the limit, coarse levels have longer edges (or the test proves nothing)";
        size_t checked = 0;
        for (auto& e : edges_of(m, above_leaves(m))) {
            if (sourceEdges.count(e)) continue;
            ++checked;
            ASSERT_LE(length(e.first, e.second), limit) << "a simplified edge is longer than " << limit;
        }
        EXPECT_GT(checked, 100u);
        EXPECT_GT(m.levels.size(), 2u);
        uint64_t roots = 0;
        for (const Cluster& c : m.clusters) roots += std::isinf(c.parentError) ? c.triangleCount : 0;
        EXPECT_LT(roots, m.sourceTriangles / 2) << "the DAG still reduces within the limit";
        expect_monotone(m);
        expect_crack_free_cuts(m, 25);
    }
}
