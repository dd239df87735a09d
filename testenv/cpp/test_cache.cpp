// The content-addressed mesh cache.
#include "tessera/cache.h"

#include <gtest/gtest.h>

#include "test_meshes.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <unistd.h>

using namespace tessera;
namespace fs = std::filesystem;

namespace {
struct Quads {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    explicit Quads(int n) {
        for (int y = 0; y <= n; ++y)
            for (int x = 0; x <= n; ++x) points.insert(points.end(), {float(x), float(y), float((x * y) % 3) * 0.1f});
        for (int y = 0; y < n; ++y)
            for (int x = 0; x < n; ++x) {
                const int a = y * (n + 1) + x;
                counts.push_back(4);
                indices.insert(indices.end(), {a, a + 1, a + n + 2, a + n + 1});
            }
    }
    MeshView view() const {
        MeshView v = polygon_view("/Quads", points, counts, indices);
        return v;
    }
};

fs::path fresh_directory(const char* name) {
    const fs::path dir = fs::temp_directory_path() / ("tessera-cache-test-" + std::string(name) + "-" + std::to_string(::getpid()));
    fs::remove_all(dir);
    return dir;
}
}  // namespace

TEST(Cache, KeyFollowsContentAndSettings) {
    Quads a(20), b(20);
    EXPECT_EQ(MeshCache::key(a.view(), {}), MeshCache::key(b.view(), {}));
    b.points[7] += 1e-6f;
    EXPECT_NE(MeshCache::key(a.view(), {}), MeshCache::key(b.view(), {}));
    BuildSettings fine;
    fine.positionPrecision = -20;
    EXPECT_NE(MeshCache::key(a.view(), {}), MeshCache::key(a.view(), fine));
    MeshView flipped = a.view();
    flipped.leftHanded = true;
    EXPECT_NE(MeshCache::key(a.view(), {}), MeshCache::key(flipped, {}));
    EXPECT_EQ(MeshCache::key(a.view(), {}).size(), 32u);
}

TEST(Cache, SubdivisionTagsChangeTheKeyOfARefinedMeshOnly) {
    Quads q(4);
    MeshView refined = q.view();
    refined.subdivisionScheme = SubdivisionScheme::CatmullClark;
    refined.refineLevel = 2;
    const std::string plain = MeshCache::key(refined, {});
    std::vector<int32_t> crease{0, 1, 2}, lengths{3};
    std::vector<float> sharp{10.0f}, softer{2.0f};
    MeshView creased = refined;
    creased.subdivisionTags.creaseIndices = crease;
    creased.subdivisionTags.creaseLengths = lengths;
    creased.subdivisionTags.creaseSharpnesses = sharp;
    const std::string creasedKey = MeshCache::key(creased, {});
    EXPECT_NE(creasedKey, plain);
    creased.subdivisionTags.creaseSharpnesses = softer;
    EXPECT_NE(MeshCache::key(creased, {}), creasedKey) << "an edit of a crease's sharpness rebuilds";
    std::vector<int32_t> corner{5};
    MeshView cornered = refined;
    cornered.subdivisionTags.cornerIndices = corner;
    cornered.subdivisionTags.cornerSharpnesses = sharp;
    EXPECT_NE(MeshCache::key(cornered, {}), plain);
    MeshView open = refined;
    open.subdivisionTags.interpolateBoundary = BoundaryInterpolation::EdgeOnly;
    EXPECT_NE(MeshCache::key(open, {}), plain);
    MeshView fvar = refined;
    fvar.subdivisionTags.faceVaryingLinearInterpolation = FaceVaryingLinear::All;
    EXPECT_NE(MeshCache::key(fvar, {}), plain);
    MeshView smooth = refined;
    smooth.subdivisionTags.triangleSubdivisionRule = TriangleSubdivision::Smooth;
    EXPECT_NE(MeshCache::key(smooth, {}), plain);
    // Unrefined (refine level 0), a subdivision surface builds the polygons as authored: one key with or without tags.
    creased.refineLevel = 0;
    MeshView polygons = q.view();
    EXPECT_EQ(MeshCache::key(creased, {}), MeshCache::key(polygons, {}));
}

TEST(Cache, EverySettingChangesTheKey) {
    Quads q(20);
    std::vector<BuildSettings> variants(7);
    variants[1].positionPrecision = -8;
    variants[2].preserveArea = true;
    variants[3].trimRelativeError = 0.5f;
    variants[4].keepTrianglePercent = 50;
    variants[5].fallbackRelativeError = 2;
    variants[6].maxEdgeLengthFactor = 10;
    variants.push_back({});
    variants.back().fallbackTrianglePercent = 20;
    std::set<std::string> keys;
    for (const BuildSettings& s : variants) keys.insert(MeshCache::key(q.view(), s));
    EXPECT_EQ(keys.size(), variants.size()) << "each setting changes the build, so each must change the key";
    BuildSettings negativeZero;
    negativeZero.trimRelativeError = -0.0f;
    EXPECT_EQ(MeshCache::key(q.view(), negativeZero), MeshCache::key(q.view(), {})) << "-0 builds what 0 builds";
}

TEST(Cache, BadSettingsFailBeforeTheLookup) {
    BuildSettings bad;
    bad.keepTrianglePercent = NAN;
    EXPECT_THROW(build_through_cache(Quads(4).view(), bad, MeshCache("")), std::invalid_argument);
}

TEST(Cache, SecondBuildComesFromTheCacheAndMatches) {
    const fs::path dir = fresh_directory("hit");
    MeshCache cache(dir.string());
    Quads q(60);
    CachedBuild first = build_through_cache(q.view(), {}, cache), second = build_through_cache(q.view(), {}, cache);
    EXPECT_FALSE(first.fromCache);
    EXPECT_TRUE(second.fromCache);
    EXPECT_EQ(first.mesh->positions, second.mesh->positions);
    EXPECT_EQ(first.mesh->triangles, second.mesh->triangles);
    EXPECT_EQ(first.mesh->clusters.size(), second.mesh->clusters.size());
    fs::remove_all(dir);
}

TEST(Cache, WarningsAreKeptAndCorruptEntriesRebuilt) {
    const fs::path dir = fresh_directory("corrupt");
    MeshCache cache(dir.string());
    Quads q(20);  // big enough to be cached (TinyMeshesAreBuiltNotCached)
    q.counts.push_back(3);
    q.indices.insert(q.indices.end(), {0, 1, 9999});  // a bad face: dropped with a warning
    CachedBuild first = build_through_cache(q.view(), {}, cache);
    ASSERT_EQ(first.warnings.size(), 1u);
    CachedBuild again = build_through_cache(q.view(), {}, cache);
    EXPECT_TRUE(again.fromCache);
    EXPECT_EQ(again.warnings, first.warnings) << "a cached bad mesh still reports its problems";

    const std::string key = MeshCache::key(q.view(), {});
    const fs::path file = dir / key.substr(0, 2) / (key + ".tsra");
    ASSERT_TRUE(fs::exists(file));
    fs::resize_file(file, fs::file_size(file) / 2);
    CachedBuild rebuilt = build_through_cache(q.view(), {}, cache);
    EXPECT_FALSE(rebuilt.fromCache);
    ASSERT_FALSE(rebuilt.warnings.empty());
    EXPECT_NE(rebuilt.warnings[0].find("cached build unreadable, rebuilding"), std::string::npos) << rebuilt.warnings[0];
    EXPECT_TRUE(build_through_cache(q.view(), {}, cache).fromCache) << "the rebuilt entry replaced the corrupt one";

    // A directory where the entry should be (a stream reads its size as 2^63): unreadable, rebuilt, never a crash.
    fs::remove(file);
    fs::create_directory(file);
    CachedBuild besideDirectory = build_through_cache(q.view(), {}, cache);
    EXPECT_FALSE(besideDirectory.fromCache);
    ASSERT_TRUE(besideDirectory.mesh && !besideDirectory.mesh->clusters.empty());
    ASSERT_FALSE(besideDirectory.warnings.empty());
    EXPECT_NE(besideDirectory.warnings[0].find("not a file"), std::string::npos) << besideDirectory.warnings[0];
    fs::remove_all(dir);
}

TEST(Cache, TinyMeshesAreBuiltNotCached) {
    // Building a mesh of a few hundred triangles costs less than reading its page file: such meshes never fill the cache.
    const fs::path dir = fresh_directory("tiny");
    MeshCache cache(dir.string());
    Quads tiny(16), big(17);  // 1024 and 1156 face-vertex indices
    EXPECT_FALSE(build_through_cache(tiny.view(), {}, cache).fromCache);
    EXPECT_FALSE(build_through_cache(tiny.view(), {}, cache).fromCache) << "built again";
    EXPECT_FALSE(build_through_cache(big.view(), {}, cache).fromCache);
    EXPECT_TRUE(build_through_cache(big.view(), {}, cache).fromCache);
    size_t files = 0;
    for (const auto& entry : fs::recursive_directory_iterator(dir)) files += entry.path().extension() == ".tsra";
    EXPECT_EQ(files, 1u);
    fs::remove_all(dir);
}

TEST(Cache, DisabledCacheBuildsEveryTime) {
    MeshCache off("");
    Quads q(8);
    EXPECT_FALSE(build_through_cache(q.view(), {}, off).fromCache);
    EXPECT_FALSE(build_through_cache(q.view(), {}, off).fromCache);
}
