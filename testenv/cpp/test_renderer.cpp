// Renderer on the real device (lavapipe here): coverage, ids, overflow redraw, camera-relative precision.
#include "tessera/delegate.h"

#include <gtest/gtest.h>

#include "device_fixture.h"
#include "test_meshes.h"
#include "shared.h"
#include "stream_arena.h"
#include "upload_batch.h"

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <map>
#include <set>
#include <memory>
#include <string>
#include <thread>

using namespace tessera;

namespace {
uint32_t id_at(const Image& image, uint32_t x, uint32_t y) {
    uint32_t bits;
    std::memcpy(&bits, &image.pixels[4 * (y * image.width + x)], 4);
    return bits;
}

// A renderer whose pipelines are made while the environment variable `variable` is `value`: the sizes and counts it
// forces ($TESSERA_CULL_GROUP_SIZE, ...) are chosen then.
std::unique_ptr<Renderer> renderer_with(Device& device, const char* variable, const std::string& value) {
    struct Forced {  // unset again however the renderer's construction ends (a refused value throws)
        const char* variable;
        ~Forced() { unsetenv(variable); }
    } forced{variable};
    setenv(variable, value.c_str(), 1);
    return std::make_unique<Renderer>(device);
}

// An n x n grid of quads over [-0.5, 0.5]^2 in the XY plane, facing +Z. `uvsAndColours`: with texture coordinates from
// -0.5 to 1.5 across (so that every wrap mode shows) and a displayColor per point (a red-green ramp).
std::shared_ptr<BuiltMesh> grid_mesh(int n, bool uvsAndColours = false) {
    std::vector<float> points, uvs, colors;
    std::vector<int32_t> counts, indices;
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) {
            const float u = float(x) / n, v = float(y) / n;
            points.insert(points.end(), {u - 0.5f, v - 0.5f, 0.0f});
            uvs.insert(uvs.end(), {2 * u - 0.5f, 2 * v - 0.5f});
            colors.insert(colors.end(), {u, v, 0.5f});
        }
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            counts.push_back(4);
            const int a = y * (n + 1) + x;
            indices.insert(indices.end(), {a, a + 1, a + n + 2, a + n + 1});
        }
    MeshView v = polygon_view(uvsAndColours ? "/UvGrid" : "/Grid", points, counts, indices);
    if (uvsAndColours) {
        v.uvs = {Interpolation::Vertex, 2, uvs, {}};
        v.displayColor = {Interpolation::Vertex, 3, colors, {}};
    }
    return std::make_shared<BuiltMesh>(build_mesh(prepare_mesh(v)));
}

// A closed, bumpy latitude-longitude sphere (radius about 1): its simplification always loses something, so each
// DAG level has a nonzero error and the cut has real choices to make.
std::shared_ptr<BuiltMesh> bumpy_sphere(int rings) {
    const double pi = 3.14159265358979323846;
    const int segments = 2 * rings;
    std::vector<float> points;
    auto radius = [](double theta, double phi) { return 1.0 + 0.04 * std::sin(9 * theta) * std::sin(7 * phi); };
    points.insert(points.end(), {0.0f, 0.0f, 1.0f});  // north pole
    for (int r = 1; r < rings; ++r)
        for (int s = 0; s < segments; ++s) {
            const double theta = pi * r / rings, phi = 2 * pi * s / segments, k = radius(theta, phi);
            points.insert(points.end(), {float(k * std::sin(theta) * std::cos(phi)), float(k * std::sin(theta) * std::sin(phi)), float(k * std::cos(theta))});
        }
    points.insert(points.end(), {0.0f, 0.0f, -1.0f});  // south pole
    const int south = 1 + (rings - 1) * segments;
    auto ring = [&](int r, int s) { return 1 + (r - 1) * segments + (s % segments); };
    std::vector<int32_t> counts, indices;
    for (int s = 0; s < segments; ++s) {
        counts.push_back(3);
        indices.insert(indices.end(), {0, ring(1, s), ring(1, s + 1)});
        counts.push_back(3);
        indices.insert(indices.end(), {south, ring(rings - 1, s + 1), ring(rings - 1, s)});
        for (int r = 1; r + 1 < rings; ++r) {
            counts.push_back(4);
            indices.insert(indices.end(), {ring(r, s), ring(r + 1, s), ring(r + 1, s + 1), ring(r, s + 1)});
        }
    }
    MeshView v = polygon_view("/BumpySphere", points, counts, indices);
    return std::make_shared<BuiltMesh>(build_mesh(prepare_mesh(v)));
}

// Background pixels that the image border cannot reach through other background pixels: holes in the surface.
size_t enclosed_background_pixels(const Image& ids) {
    const uint32_t w = ids.width, h = ids.height;
    std::vector<uint8_t> reached(size_t(w) * h, 0);
    std::vector<uint32_t> stack;
    auto push = [&](uint32_t x, uint32_t y) {
        const size_t i = size_t(y) * w + x;
        uint32_t bits;
        std::memcpy(&bits, &ids.pixels[4 * i], 4);
        if (!reached[i] && bits == 0xffffffffu) {
            reached[i] = 1;
            stack.push_back(uint32_t(i));
        }
    };
    for (uint32_t x = 0; x < w; ++x) push(x, 0), push(x, h - 1);
    for (uint32_t y = 0; y < h; ++y) push(0, y), push(w - 1, y);
    while (!stack.empty()) {
        const uint32_t i = stack.back(), x = i % w, y = i / w;
        stack.pop_back();
        if (x > 0) push(x - 1, y);
        if (x + 1 < w) push(x + 1, y);
        if (y > 0) push(x, y - 1);
        if (y + 1 < h) push(x, y + 1);
    }
    size_t enclosed = 0;
    for (size_t i = 0; i < reached.size(); ++i) {
        uint32_t bits;
        std::memcpy(&bits, &ids.pixels[4 * i], 4);
        enclosed += bits == 0xffffffffu && !reached[i];
    }
    return enclosed;
}

// A copy of a mesh where the mesh was modelled.
InstanceDesc identity_instance(uint32_t mesh) {
    InstanceDesc instance;
    instance.mesh = mesh;
    instance.transform = identity_matrix();
    return instance;
}

CameraDesc camera_at(double x, double y, double z) {
    CameraDesc c;
    c.cameraToWorld = identity_matrix();
    c.cameraToWorld[3] = x;
    c.cameraToWorld[7] = y;
    c.cameraToWorld[11] = z;
    c.focalLength = 50;
    c.horizontalAperture = c.verticalAperture = 50;  // 53 degrees
    c.nearClip = 0.01;
    return c;
}

class RendererTest : public DeviceTest {};
}  // namespace

TEST_F(RendererTest, GridCoversTheExpectedPixels) {
    Renderer renderer(*device);
    GpuScene scene;
    const uint32_t mesh = scene.add_mesh(grid_mesh(64));
    InstanceDesc instance = identity_instance(mesh);
    instance.primId = 42;
    scene.set_instances({instance});
    scene.set_lights({{LightType::Dome, {0, 0, -1}, {1, 1, 1}}});
    // 1 unit wide at distance 2 with a 53-degree view: the grid covers the middle half of the image.
    RenderSettings settings{128, 128, {0, 0, 0, 0}};
    settings.lod = false;  // every source triangle
    FrameStats stats;
    auto images = renderer.render(scene, camera_at(0, 0, 2), settings, {Aov::PrimId, Aov::Color}, &stats);
    EXPECT_EQ(id_at(images[0], 64, 64), 42u);
    EXPECT_EQ(id_at(images[0], 5, 5), 0xffffffffu);
    size_t covered = 0;
    for (uint32_t y = 0; y < 128; ++y)
        for (uint32_t x = 0; x < 128; ++x) covered += id_at(images[0], x, y) == 42u;
    EXPECT_NEAR(double(covered) / (128 * 128), 0.25, 0.02);
    EXPECT_GT(images[1].pixels[4 * (64 * 128 + 64)], 0.0f);
    EXPECT_EQ(stats.visibleInstances, 1u);
    EXPECT_EQ(stats.visibleTriangles, 64u * 64u * 2u);

    // A flat grid simplifies without error, so the cut draws its roots; they cover exactly the same pixels.
    settings.lod = true;
    FrameStats lodStats;
    auto lod = renderer.render(scene, camera_at(0, 0, 2), settings, {Aov::PrimId}, &lodStats);
    EXPECT_LT(lodStats.visibleTriangles, 64u * 64u * 2u / 8);
    size_t differ = 0;
    for (uint32_t y = 0; y < 128; ++y)
        for (uint32_t x = 0; x < 128; ++x) differ += id_at(images[0], x, y) != id_at(lod[0], x, y);
    EXPECT_LE(differ, 128u) << "the simplified grid must cover the grid's pixels (edge pixels may round differently)";
}

TEST_F(RendererTest, TheCutDrawsSourceTrianglesAtZeroErrorAndRootsAtInfiniteError) {
    Renderer renderer(*device);
    GpuScene scene;
    std::shared_ptr<BuiltMesh> sphere = bumpy_sphere(96);  // 36k triangles
    InstanceDesc instance = identity_instance(scene.add_mesh(sphere));
    scene.set_instances({instance});
    RenderSettings settings{128, 128, {0, 0, 0, 0}};
    settings.occlusion = false;  // the counts of the cut alone
    uint32_t roots = 0, rootTriangles = 0;
    for (const Cluster& c : sphere->clusters)
        if (c.parentGroup == kNoGroup) ++roots, rootTriangles += c.triangleCount;
    ASSERT_GT(sphere->levels.size(), 3u);

    FrameStats fine, coarse;
    settings.pixelError = 0;
    renderer.render(scene, camera_at(0, 0, 4), settings, {Aov::PrimId}, &fine);
    EXPECT_EQ(fine.visibleClusters, sphere->leafClusters);
    EXPECT_EQ(fine.visibleTriangles, sphere->leafTriangles);
    settings.pixelError = 1e30f;
    renderer.render(scene, camera_at(0, 0, 4), settings, {Aov::PrimId}, &coarse);
    EXPECT_EQ(coarse.visibleClusters, roots);
    EXPECT_EQ(coarse.visibleTriangles, rootTriangles);
    EXPECT_LT(coarse.candidateClusters, fine.candidateClusters) << "levels ruled out by distance are not tested";

    // A larger threshold never draws more triangles.
    uint64_t previous = fine.visibleTriangles;
    for (float pixels : {0.25f, 1.0f, 4.0f, 16.0f}) {
        FrameStats stats;
        settings.pixelError = pixels;
        renderer.render(scene, camera_at(0, 0, 4), settings, {Aov::PrimId}, &stats);
        EXPECT_LE(stats.visibleTriangles, previous) << pixels << " px";
        previous = stats.visibleTriangles;
    }
    EXPECT_LT(previous, fine.visibleTriangles / 4);
}

TEST_F(RendererTest, MixedCutsLeaveNoHoles) {
    // Close to a closed sphere and looking along it, the cut mixes fine clusters near the camera with coarse ones
    // far away; a crack between levels would show the background through the surface.
    Renderer renderer(*device);
    GpuScene scene;
    std::shared_ptr<BuiltMesh> sphere = bumpy_sphere(160);  // 102k triangles
    InstanceDesc instance = identity_instance(scene.add_mesh(sphere));
    scene.set_instances({instance});
    // The whole sphere in a 90-degree view from 0.6 above it: the rim is twice as far as the nearest point, so
    // each level boundary of the cut crosses the visible surface for some threshold of the sweep.
    CameraDesc camera = camera_at(0, 0, 1.6);
    camera.horizontalAperture = camera.verticalAperture = 100;
    RenderSettings settings{192, 192, {0, 0, 0, 0}};
    for (float pixels : {0.5f, 0.7f, 1.0f, 1.4f, 2.0f, 2.8f, 4.0f, 5.6f, 8.0f}) {
        settings.pixelError = pixels;
        FrameStats stats;
        auto images = renderer.render(scene, camera, settings, {Aov::PrimId, Aov::ClusterId}, &stats);
        EXPECT_EQ(enclosed_background_pixels(images[0]), 0u) << pixels << " px";
        std::set<uint32_t> levels;
        for (uint32_t i = 0; i < 192 * 192; ++i) {
            const uint32_t id = id_at(images[1], i % 192, i / 192);
            if (id != 0xffffffffu) levels.insert(sphere->clusters.at(id).level);
        }
        EXPECT_GE(levels.size(), 2u) << pixels << " px: the view must mix DAG levels for this test to mean anything";
    }
}

// The compute rasterizer snaps like hardware raster and follows its top-left rule, so the two cover the same
// pixels with the same triangles. Edges through pixel centres (a grid aligned to the pixels, then shifted by half a
// pixel) test the tie rule; a bumpy sphere at several distances tests everything else.
TEST_F(RendererTest, SoftwareAndHardwareRasterCoverTheSamePixels) {
    Renderer renderer(*device);
    GpuScene scene;
    InstanceDesc grid = identity_instance(scene.add_mesh(grid_mesh(16)));
    scene.set_instances({grid});
    RenderSettings settings{64, 64, {0, 0, 0, 0}};
    settings.lod = false;
    auto compare = [&](const CameraDesc& camera, double minimumShare, const char* what) {
        FrameStats hw, sw;
        settings.raster = RasterMode::Hardware;
        Image a = renderer.render(scene, camera, settings, {Aov::TriangleId}, &hw)[0];
        EXPECT_EQ(hw.swTriangles, 0u) << what;
        settings.raster = RasterMode::Software;
        for (RasterVertices vertices : {RasterVertices::Shared, RasterVertices::PerTriangle}) {  // both compute variants
            settings.rasterVertices = vertices;
            Image b = renderer.render(scene, camera, settings, {Aov::TriangleId}, &sw)[0];
            EXPECT_EQ(sw.hwTriangles, 0u) << what << ": every cluster must have gone to the compute rasterizer";
            size_t same = 0, covered = 0;
            for (uint32_t y = 0; y < a.height; ++y)
                for (uint32_t x = 0; x < a.width; ++x) {
                    same += id_at(a, x, y) == id_at(b, x, y);
                    covered += id_at(a, x, y) != 0xffffffffu;
                }
            EXPECT_GT(covered, 64u) << what;
            EXPECT_GE(double(same) / (a.width * a.height), minimumShare) << what << (sw.swSharedVertices ? ", shared vertices" : ", per triangle");
        }
        settings.rasterVertices = RasterVertices::Auto;
    };
    for (double shift : {0.0, 0.5}) {  // in pixels: diagonals, then horizontal and vertical edges through pixel centres
        CameraDesc ortho = camera_at(shift / 64, shift / 64, 2);
        ortho.orthographic = true;
        ortho.horizontalAperture = ortho.verticalAperture = 1.0;  // the grid fills the image: 4 pixels per cell
        compare(ortho, 1.0, shift == 0 ? "grid, diagonal edges through pixel centres" : "grid, axis edges through pixel centres");
    }
    InstanceDesc sphere = identity_instance(scene.add_mesh(bumpy_sphere(64)));
    scene.set_instances({sphere});
    settings.width = settings.height = 160;
    for (double distance : {3.0, 8.0, 30.0})  // depth ties between the two paths' interpolated depths are rare
        compare(camera_at(0.1, 0.2, distance), 0.999, "bumpy sphere");
}

// The compute rasterizer takes a cluster whose sphere projects to at most TS_SW_MAX_RADIUS_PIXELS, estimated at its
// nearest depth; far off the view axis of a wide lens the true projection is several times longer, and a triangle there
// can be far more than TS_SW_SMALL_TRIANGLE_SUBPIXELS across, past what 32-bit edge functions hold. The cull sends such
// a cluster to the compute rasterizer's variant with 64-bit ones (its exact screen bound of the sphere), which must
// cover the same pixels as hardware raster; the quads near the view axis take the 32-bit variant.
TEST_F(RendererTest, ComputeRasterOfTrianglesTooLargeForItsSmallVariantMatchesHardware) {
    Renderer renderer(*device);
    GpuScene scene;
    const uint32_t quad = scene.add_mesh(grid_mesh(1));  // two triangles, one cluster
    CameraDesc camera = camera_at(0, 0, 0);
    camera.focalLength = 10;
    camera.horizontalAperture = camera.verticalAperture = 120;  // 161 degrees
    RenderSettings settings{1024, 1024, {0, 0, 0, 0}};
    settings.lod = false;
    // Unit quads facing the camera, off the view axis by `angle` along the image diagonal, at `distance`.
    auto quad_at = [&](double angle, double distance, uint32_t primId) {
        const double pi = 3.14159265358979323846, a = angle * pi / 180;
        const double n[3] = {-std::sin(a) * std::sqrt(0.5), -std::sin(a) * std::sqrt(0.5), std::cos(a)};  // towards the camera
        double x[3] = {n[2], 0, -n[0]};  // (0, 1, 0) x n, normalized
        const double lx = std::sqrt(x[0] * x[0] + x[2] * x[2]);
        for (double& v : x) v /= lx;
        const double y[3] = {n[1] * x[2] - n[2] * x[1], n[2] * x[0] - n[0] * x[2], n[0] * x[1] - n[1] * x[0]};
        InstanceDesc instance = identity_instance(quad);
        for (int r = 0; r < 3; ++r) {
            instance.transform[4 * r + 0] = x[r];
            instance.transform[4 * r + 1] = y[r];
            instance.transform[4 * r + 2] = n[r];
            instance.transform[4 * r + 3] = -n[r] * distance;
        }
        instance.doubleSided = true;
        instance.primId = primId;
        return instance;
    };
    scene.set_instances({quad_at(78, 8.6, 1), quad_at(0, 40, 2), quad_at(30, 30, 3)});
    FrameStats hw, sw;
    settings.raster = RasterMode::Hardware;
    const Image a = renderer.render(scene, camera, settings, {Aov::PrimId}, &hw)[0];
    settings.raster = RasterMode::Software;
    for (RasterVertices vertices : {RasterVertices::Shared, RasterVertices::PerTriangle}) {
        settings.rasterVertices = vertices;
        const Image b = renderer.render(scene, camera, settings, {Aov::PrimId}, &sw)[0];
        EXPECT_EQ(sw.hwTriangles, 0u) << "every cluster must have gone to the compute rasterizer";
        EXPECT_EQ(sw.swClusters, 3u);
        EXPECT_EQ(sw.swLargeClusters, 1u) << "the quad off axis is large on screen, the others are not";
        size_t same = 0;
        std::set<uint32_t> seen;
        for (uint32_t y = 0; y < a.height; ++y)
            for (uint32_t x = 0; x < a.width; ++x) {
                same += id_at(a, x, y) == id_at(b, x, y);
                seen.insert(id_at(a, x, y));
            }
        EXPECT_EQ(seen, (std::set<uint32_t>{1, 2, 3, 0xffffffffu}));
        EXPECT_EQ(same, size_t(a.width) * a.height) << (sw.swSharedVertices ? "shared vertices" : "per triangle");
    }
}

// The compute rasterizer's two variants (vertices shared through workgroup memory, or each thread transforming its own
// triangle's corners) snap with the same arithmetic, so they draw the same visibility buffer bit for bit: triangle ids
// and depths, for plain, mirrored (winding flipped) and double-sided instances. The shared variant's workgroup is the
// device's (one subgroup on a CPU device) and a GPU's 128 threads, which stride differently over vertices and triangles.
TEST_F(RendererTest, ComputeRasterVariantsDrawTheSameVisibility) {
    Renderer renderer(*device);
    const std::unique_ptr<Renderer> gpuSized = renderer_with(*device, "TESSERA_SW_RASTER_GROUP_SIZE", "128");
    GpuScene scene;
    const uint32_t sphere = scene.add_mesh(bumpy_sphere(48)), grid = scene.add_mesh(grid_mesh(24));
    InstanceDesc plain = identity_instance(sphere), mirrored = identity_instance(sphere), sheet = identity_instance(grid);
    // The spheres cut into each other and the sheet cuts into both: which surface wins a pixel along those curves
    // follows the depths the rasterizer interpolated, so the ids test depth too.
    plain.transform[3] = -0.6;
    mirrored.transform[0] = -1;  // mirrored in x: the winding flips
    mirrored.transform[3] = 0.6;
    mirrored.primId = 1;
    sheet.transform[5] = -1;  // half a turn about x: its back faces the camera
    sheet.transform[10] = -1;
    sheet.transform[7] = 0.7;
    sheet.transform[11] = 0.4;
    sheet.doubleSided = true;
    sheet.primId = 2;
    scene.set_instances({plain, mirrored, sheet});
    RenderSettings settings{200, 120, {0, 0, 0, 0}};
    settings.raster = RasterMode::Software;
    settings.lod = false;  // every source triangle, to the compute rasterizer (but for clusters that are large on screen)
    for (double distance : {4.0, 12.0}) {
        std::vector<Image> images[3];
        FrameStats stats[3];
        for (int k = 0; k < 3; ++k) {  // shared (the device's workgroup), own corners, shared in 128-thread workgroups
            settings.rasterVertices = k == 1 ? RasterVertices::PerTriangle : RasterVertices::Shared;
            images[k] = (k == 2 ? *gpuSized : renderer).render(scene, camera_at(0, 0.2, distance), settings, {Aov::TriangleId, Aov::Depth, Aov::PrimId}, &stats[k]);
            EXPECT_EQ(stats[k].swSharedVertices, k != 1);
            EXPECT_GT(stats[k].swTriangles, 1000u) << "the compute rasterizer must draw the scene";
        }
        EXPECT_EQ(stats[0].swRasterGroupSize, device->is_software() ? device->subgroup_size() : uint32_t(TS_SW_RASTER_GROUP_SIZE));
        EXPECT_EQ(stats[1].swRasterGroupSize, uint32_t(TS_SW_RASTER_OWN_CORNERS_GROUP_SIZE));
        EXPECT_EQ(stats[2].swRasterGroupSize, 128u);
        std::set<uint32_t> prims;
        for (uint32_t y = 0; y < images[0][2].height; ++y)
            for (uint32_t x = 0; x < images[0][2].width; ++x) prims.insert(id_at(images[0][2], x, y));
        EXPECT_EQ(prims, (std::set<uint32_t>{0u, 1u, 2u, 0xffffffffu})) << "every instance and the background in view at " << distance;
        for (int k = 1; k < 3; ++k)
            for (size_t aov = 0; aov < 2; ++aov) {
                ASSERT_EQ(images[0][aov].pixels.size(), images[k][aov].pixels.size());
                size_t differing = 0;
                for (size_t i = 0; i < images[0][aov].pixels.size(); ++i)
                    differing += std::memcmp(&images[0][aov].pixels[i], &images[k][aov].pixels[i], 4) != 0;  // as bits
                EXPECT_EQ(differing, 0u) << (aov == 0 ? "triangle ids" : "depths") << " at distance " << distance
                                         << (k == 1 ? ", own corners" : ", 128-thread workgroups");
            }
    }
}

// Through either rasterizer, for copies mirrored or not, and with single- and double-sided copies in one frame (hardware
// raster draws them from the two ends of its list, with and without face culling).
TEST_F(RendererTest, SingleSidedBackFacesAreCulledDoubleSidedAreNot) {
    Renderer renderer(*device);
    GpuScene scene;
    const uint32_t mesh = scene.add_mesh(grid_mesh(4));  // in the XY plane, facing +Z
    RenderSettings settings{64, 32, {0, 0, 0, 0}};
    CameraDesc front = camera_at(0, 0, 1.5), behind = camera_at(0, 0, -1.5);
    front.horizontalAperture = behind.horizontalAperture = 100;  // 90 degrees: x = +-0.7 at columns 17 and 47 (mirrored from behind)
    behind.cameraToWorld[0] = -1;  // turn around (rotate 180 degrees about Y)
    behind.cameraToWorld[10] = -1;
    for (RasterMode mode : {RasterMode::Hardware, RasterMode::Software}) {
        settings.raster = mode;
        for (bool mirrored : {false, true}) {  // mirrored in Z: the copy faces -Z
            auto copy = [&](double x, bool doubleSided, uint32_t primId) {
                InstanceDesc instance = identity_instance(mesh);
                instance.transform[3] = x;
                if (mirrored) instance.transform[10] = -1;
                instance.doubleSided = doubleSided;
                instance.primId = primId;
                return instance;
            };
            scene.set_instances({copy(-0.7, false, 1), copy(0.7, true, 2)});  // left single-sided, right double-sided
            const std::string what = std::string(mode == RasterMode::Hardware ? "hardware" : "software") + (mirrored ? ", mirrored" : "");
            FrameStats stats;
            const Image seen = renderer.render(scene, mirrored ? behind : front, settings, {Aov::PrimId}, &stats)[0];
            const Image back = renderer.render(scene, mirrored ? front : behind, settings, {Aov::PrimId})[0];
            EXPECT_EQ(mode == RasterMode::Hardware ? stats.hwTriangles : stats.swTriangles, stats.visibleTriangles) << what;
            // Seen from the side they face, both show; from the other, only the double-sided one. The view from the other
            // side is mirrored, so the single-sided copy's column there is the double-sided one's from the front.
            const uint32_t single = mirrored ? 47 : 17, both = 64 - single;
            EXPECT_EQ(id_at(seen, single, 16), 1u) << what;
            EXPECT_EQ(id_at(seen, both, 16), 2u) << what;
            EXPECT_EQ(id_at(back, single, 16), 2u) << what;
            EXPECT_EQ(id_at(back, both, 16), 0xffffffffu) << what;
        }
    }
}

TEST_F(RendererTest, OverflowGrowsTheListAndRedrawsTheExactImage) {
    Renderer renderer(*device);
    GpuScene scene;
    InstanceDesc instance = identity_instance(scene.add_mesh(grid_mesh(64)));
    scene.set_instances({instance});
    RenderSettings settings{64, 64, {0, 0, 0, 0}};
    settings.lod = false;  // 32 clusters to overflow a list of 1
    FrameStats roomy, tight;
    auto reference = renderer.render(scene, camera_at(0, 0, 2), settings, {Aov::TriangleId}, &roomy);
    Renderer small(*device);
    small.set_visible_cluster_capacity(1);
    auto redrawn = small.render(scene, camera_at(0, 0, 2), settings, {Aov::TriangleId}, &tight);
    EXPECT_EQ(roomy.overflowRedraws, 0u);
    EXPECT_GE(tight.overflowRedraws, 1u);
    ASSERT_EQ(reference[0].pixels.size(), redrawn[0].pixels.size());
    EXPECT_EQ(std::memcmp(reference[0].pixels.data(), redrawn[0].pixels.data(), reference[0].pixels.size() * 4), 0);  // ids as bits
}

TEST_F(RendererTest, FarFromOriginRendersLikeTheOrigin) {
    Renderer renderer(*device);
    GpuScene scene;
    const uint32_t mesh = scene.add_mesh(grid_mesh(32));
    RenderSettings settings{96, 96, {0, 0, 0, 0}};
    auto render_at = [&](double offset) {
        InstanceDesc instance = identity_instance(mesh);
        instance.transform[3] = offset;
        instance.transform[7] = offset;
        scene.set_instances({instance});
        return renderer.render(scene, camera_at(offset + 0.1, offset, 1.5), settings, {Aov::TriangleId})[0];
    };
    Image origin = render_at(0.0), far = render_at(1.0e7);
    size_t differ = 0;
    for (uint32_t y = 0; y < 96; ++y)
        for (uint32_t x = 0; x < 96; ++x) differ += id_at(origin, x, y) != id_at(far, x, y);
    EXPECT_EQ(differ, 0u) << "1e7 units from the origin must render like the origin";
}

namespace {
// A wall (a 5x5 grid facing +Z at z = 0) with 9 spheres hidden behind it, one in front of it, one beside it
// mirrored, one beside it stretched (its transform does not keep angles, so its normal cones do not apply).
std::vector<InstanceDesc> wall_and_spheres(uint32_t wall, uint32_t sphere) {
    std::vector<InstanceDesc> instances;
    InstanceDesc w = identity_instance(wall);
    for (int i : {0, 5, 10}) w.transform[i] = 5;
    w.primId = 100;
    instances.push_back(w);
    auto place = [&](double x, double y, double z, double sx, double sy, double sz) {
        InstanceDesc s = identity_instance(sphere);
        s.transform[0] = sx, s.transform[5] = sy, s.transform[10] = sz;
        s.transform[3] = x, s.transform[7] = y, s.transform[11] = z;
        s.primId = uint32_t(instances.size());
        instances.push_back(s);
    };
    for (int y = -1; y <= 1; ++y)
        for (int x = -1; x <= 1; ++x) place(x, y, -2, 0.5, 0.5, 0.5);
    place(0.5, -0.5, 1, 0.6, 0.6, 0.6);
    place(3.4, 0, -1, 0.6, 0.6, -0.6);  // mirrored in Z: its normal cones must turn with it
    place(-3.4, 0.5, -1, 0.3, 0.9, 0.5);
    return instances;
}

// One copy of `mesh` with a constant displacement of 0.08 units (runtime tessellation draws it).
InstanceDesc displaced_instance(GpuScene& scene, uint32_t mesh) {
    MaterialDesc bumpy;
    bumpy.displacement = 1.0f;
    bumpy.displacementMagnitude = 0.08f;
    InstanceDesc instance = identity_instance(mesh);
    instance.material = scene.add_material(bumpy);
    return instance;
}

// A UsdUVTexture slot of an image made in memory.
TextureSlot memory_slot(MaterialInput input, std::shared_ptr<const TextureImage> image, TextureWrap s, TextureWrap t, TextureChannel channel) {
    TextureSlot slot;
    slot.input = input;
    slot.file = "memory";
    slot.image = std::move(image);
    slot.wrapS = s;
    slot.wrapT = t;
    slot.channel = channel;
    return slot;
}

// Both renders must agree on these AOVs: bit for bit, or within `tolerance` for values whose bits differ.
void expect_same_images(const std::vector<Image>& a, const std::vector<Image>& b, const char* what, float tolerance = 0) {
    ASSERT_EQ(a.size(), b.size());
    for (size_t i = 0; i < a.size(); ++i) {
        ASSERT_EQ(a[i].pixels.size(), b[i].pixels.size());
        size_t differ = 0, first = 0;
        float largest = 0;
        for (size_t k = 0; k < a[i].pixels.size(); ++k)
            if (std::memcmp(&a[i].pixels[k], &b[i].pixels[k], 4) != 0 && !(std::abs(a[i].pixels[k] - b[i].pixels[k]) <= tolerance)) {
                if (differ++ == 0) first = k;
                largest = std::max(largest, std::abs(a[i].pixels[k] - b[i].pixels[k]));
            }
        EXPECT_EQ(differ, 0u) << what << ", " << aov_name(a[i].aov) << ": " << differ << " values differ, by at most " << largest
                              << "; the first at pixel " << first / 4 << " channel " << first % 4 << ": " << a[i].pixels[first] << " against "
                              << b[i].pixels[first];
    }
}
}  // namespace

// The patch rasterizer (dice.comp.glsl) runs in workgroups of one subgroup on a CPU device and of TS_DICE_GROUP_SIZE on a
// GPU; its threads stride over a patch's points and micro-triangles by the workgroup's size, and every size draws the
// same micro-triangles to the same pixels.
TEST_F(RendererTest, PatchRasterWorkgroupSizesDrawTheSameFrames) {
    Renderer renderer(*device);
    const std::unique_ptr<Renderer> gpuSized = renderer_with(*device, "TESSERA_SW_RASTER_GROUP_SIZE", "64");
    GpuScene scene;
    scene.set_instances({displaced_instance(scene, scene.add_mesh(bumpy_sphere(24)))});
    RenderSettings settings{160, 96, {0, 0, 0, 0}};
    settings.dicingRate = 0.5f;  // patches of many micro-triangles: several per thread
    const std::vector<Aov> aovs = {Aov::TriangleId, Aov::Depth, Aov::Normal};
    FrameStats stats[2];
    const std::vector<Image> a = renderer.render(scene, camera_at(0.8, 0.3, 1.4), settings, aovs, &stats[0]);
    const std::vector<Image> b = gpuSized->render(scene, camera_at(0.8, 0.3, 1.4), settings, aovs, &stats[1]);
    EXPECT_GT(stats[0].computePatches, 100u) << "the compute patch rasterizer must draw the scene";
    EXPECT_GT(stats[0].microTriangles, 20u * stats[0].computePatches) << "patches of many micro-triangles";
    EXPECT_EQ(stats[0].microTriangles, stats[1].microTriangles);
    EXPECT_EQ(stats[0].computePatches, stats[1].computePatches);
    expect_same_images(a, b, "patch raster in workgroups of 64");
}

// The cut's blocks (GpuCutBlock) only spare tests: with and without them the same clusters are drawn, through the
// same rasterizers, to the same pixels, for views that mix levels, cut the mesh with the frustum, look from inside the
// LOD spheres, are orthographic, or sit far from the origin under a stretching transform.
TEST_F(RendererTest, CutBlocksChangeWhatIsTestedNotTheCut) {
    // A CPU device's cull group (one lavapipe subgroup) on every device: this sphere's cut passes the block path's
    // threshold (TS_CUT_BLOCKS_FROM clusters per thread) for groups of 8, not for a GPU's larger groups.
    const std::unique_ptr<Renderer> eightWide = renderer_with(*device, "TESSERA_CULL_GROUP_SIZE", "8");
    Renderer& renderer = *eightWide;
    GpuScene scene;
    std::shared_ptr<BuiltMesh> sphere = bumpy_sphere(160);  // 102k triangles
    const uint32_t mesh = scene.add_mesh(sphere);
    struct View {
        const char* name;
        CameraDesc camera;
        Matrix4d transform;
    };
    std::vector<View> views;
    CameraDesc wide = camera_at(0, 0, 1.6);  // the whole sphere from 0.6 above it, a 90-degree lens
    wide.horizontalAperture = wide.verticalAperture = 100;
    views.push_back({"close and wide", wide, identity_matrix()});
    views.push_back({"grazing", camera_at(0.8, 0.3, 1.05), identity_matrix()});
    CameraDesc telephoto = camera_at(0.3, 0.2, 3);  // a 4.6-degree lens: most of the sphere lies outside the frustum
    telephoto.horizontalAperture = telephoto.verticalAperture = 4;
    views.push_back({"telephoto", telephoto, identity_matrix()});
    CameraDesc ortho = camera_at(0.2, 0, 3);
    ortho.orthographic = true;
    ortho.horizontalAperture = ortho.verticalAperture = 12;  // tenths of a unit, as USD: 1.2 units across
    views.push_back({"orthographic", ortho, identity_matrix()});
    Matrix4d far = identity_matrix();
    far[0] = 3, far[5] = 0.5, far[10] = 2;  // stretched: its scale bounds the error by the largest axis
    far[3] = 1.0e6, far[7] = -2.0e6, far[11] = 5.0e5;
    views.push_back({"far from the origin, stretched", camera_at(1.0e6 + 0.5, -2.0e6, 5.0e5 + 2.6), far});
    Matrix4d huge = identity_matrix();
    huge[0] = huge[5] = huge[10] = 40;
    views.push_back({"a huge sphere from just above it", wide, huge});  // the frustum holds a sliver of it
    views.back().camera.cameraToWorld[11] = 41.0;

    RenderSettings settings{320, 240, {0, 0, 0, 0}};
    settings.occlusion = false;  // the counts of the cut alone
    uint64_t telephotoWith = 0, telephotoWithout = 0;
    for (const View& view : views) {
        InstanceDesc instance = identity_instance(mesh);
        instance.transform = view.transform;
        scene.set_instances({instance});
        for (float pixels : {0.5f, 1.0f, 4.0f}) {
            settings.pixelError = pixels;
            FrameStats with, without;
            settings.cutBlocks = true;
            auto a = renderer.render(scene, view.camera, settings, {Aov::ClusterId, Aov::TriangleId}, &with);
            settings.cutBlocks = false;
            auto b = renderer.render(scene, view.camera, settings, {Aov::ClusterId, Aov::TriangleId}, &without);
            const std::string what = std::string(view.name) + ", " + std::to_string(pixels) + " px";
            EXPECT_GT(with.visibleClusters, 0u) << what;
            EXPECT_EQ(with.visibleClusters, without.visibleClusters) << what;
            EXPECT_EQ(with.visibleTriangles, without.visibleTriangles) << what;
            EXPECT_EQ(with.swTriangles, without.swTriangles) << what;
            EXPECT_EQ(with.backfaceClusters, without.backfaceClusters) << what;
            EXPECT_LE(with.candidateClusters, without.candidateClusters) << what;
            expect_same_images(a, b, what.c_str());
            if (view.camera.horizontalAperture == telephoto.horizontalAperture)
                telephotoWith += with.candidateClusters, telephotoWithout += without.candidateClusters;
        }
    }
    // Through the telephoto lens most blocks lie outside the frustum (measured: 2 357 clusters tested against 4 186).
    EXPECT_LT(telephotoWith * 3, telephotoWithout * 2) << "blocks outside the frustum must not be tested cluster by cluster";

    // A displaced copy: the blocks' frustum spheres are widened by the instance's largest offset, as the clusters' are, so
    // a surface displaced into the frustum from clusters just outside it is drawn (and diced) either way. Close up, its
    // levels in the cut hold level 0's 800 clusters: more than the block path's threshold.
    scene.set_instances({displaced_instance(scene, mesh)});
    for (const CameraDesc& camera : {wide, camera_at(0.8, 0.3, 1.12), telephoto}) {
        settings.pixelError = 1.0f;
        FrameStats with, without;
        settings.cutBlocks = true;
        auto a = renderer.render(scene, camera, settings, {Aov::ClusterId, Aov::TriangleId, Aov::Depth}, &with);
        settings.cutBlocks = false;
        auto b = renderer.render(scene, camera, settings, {Aov::ClusterId, Aov::TriangleId, Aov::Depth}, &without);
        EXPECT_GT(with.tessellatedClusters, 0u) << "displaced, blocks";
        EXPECT_EQ(with.visibleClusters, without.visibleClusters) << "displaced";
        EXPECT_EQ(with.tessellatedClusters, without.tessellatedClusters) << "displaced";
        EXPECT_EQ(with.microTriangles, without.microTriangles) << "displaced";
        EXPECT_LE(with.candidateClusters, without.candidateClusters) << "displaced";
        expect_same_images(a, b, "displaced");
    }
}

// An instance's cut shared by several workgroups (RenderSettings::cutParts, cull.comp.glsl cut_parts) is the same cut:
// the same clusters drawn, tested and culled, the same pixels, whether one workgroup walks it or seven, with parts
// of one cluster each (every instance split as far as it goes) or of the device's size; through the block path and the
// per-cluster one, without LOD, and with two-pass occlusion (the post pass walks the deferred instances' parts).
TEST_F(RendererTest, CutPartsShareTheWorkNotTheCut) {
    GpuScene scene;
    const uint32_t sphere = scene.add_mesh(bumpy_sphere(160));  // 102k triangles
    const CameraDesc close = camera_at(0.3, 0.2, 1.7), grazing = camera_at(0.8, 0.3, 1.05);
    RenderSettings settings{200, 150, {0, 0, 0, 0}};
    const std::vector<Aov> aovs = {Aov::InstanceId, Aov::ClusterId, Aov::TriangleId, Aov::Depth};
    struct Case {
        const char* name;
        std::vector<InstanceDesc> instances;
        CameraDesc camera;
        bool lod, blocks, occlusion;
    };
    const std::vector<Case> cases = {
        {"one sphere, close", {identity_instance(sphere)}, close, true, true, false},
        {"one sphere, grazing, per cluster", {identity_instance(sphere)}, grazing, true, false, false},
        {"one sphere, no LOD", {identity_instance(sphere)}, close, false, true, false},
        {"a wall and spheres, occlusion", wall_and_spheres(scene.add_mesh(grid_mesh(16)), scene.add_mesh(bumpy_sphere(48))), camera_at(0, 0, 6), true,
         true, true},
    };
    Renderer whole(*device), sevenParts(*device), deviceParts(*device);
    Renderer* renderers[3] = {&whole, &sevenParts, &deviceParts};
    for (const Case& c : cases) {
        scene.set_instances(c.instances);
        settings.lod = c.lod;
        settings.cutBlocks = c.blocks;
        settings.occlusion = c.occlusion;
        std::vector<std::vector<Image>> images;
        std::vector<FrameStats> stats;
        const std::pair<uint32_t, uint32_t> partings[3] = {{1, 0}, {7, 1}, {0, 0}};
        for (int r = 0; r < 3; ++r) {
            const auto [parts, clusters] = partings[r];
            Renderer& renderer = *renderers[r];  // new instances: the occlusion case's first frame has no HZB, its second has
            settings.cutParts = parts;
            settings.cutPartClusters = clusters;
            for (int frame = 0; frame < 2; ++frame) {
                FrameStats frameStats;
                images.push_back(renderer.render(scene, c.camera, settings, aovs, &frameStats));
                stats.push_back(frameStats);
            }
        }
        for (size_t k = 2; k < images.size(); ++k) {
            const std::string what = std::string(c.name) + ", run " + std::to_string(k / 2) + " frame " + std::to_string(k % 2);
            const FrameStats& one = stats[k % 2];
            EXPECT_GT(stats[k].visibleClusters, 0u) << what;
            EXPECT_EQ(stats[k].visibleInstances, one.visibleInstances) << what;
            EXPECT_EQ(stats[k].visibleClusters, one.visibleClusters) << what;
            EXPECT_EQ(stats[k].candidateClusters, one.candidateClusters) << what;
            EXPECT_EQ(stats[k].swTriangles, one.swTriangles) << what;
            EXPECT_EQ(stats[k].hwTriangles, one.hwTriangles) << what;
            EXPECT_EQ(stats[k].backfaceClusters, one.backfaceClusters) << what;
            EXPECT_EQ(stats[k].occludedClusters, one.occludedClusters) << what;
            EXPECT_EQ(stats[k].occludedInstances, one.occludedInstances) << what;
            expect_same_images(images[k], images[k % 2], what.c_str());
        }
    }
}

TEST_F(RendererTest, OcclusionCullingChangesCountsNotTheImage) {
    GpuScene scene;
    scene.set_instances(wall_and_spheres(scene.add_mesh(grid_mesh(16)), scene.add_mesh(bumpy_sphere(48))));
    Renderer culling(*device), plain(*device);
    RenderSettings on{128, 128, {0, 0, 0, 0}};
    on.pixelError = 0;  // source clusters: small enough for their normal cones to cull
    RenderSettings off = on;
    off.occlusion = false;
    const std::vector<Aov> aovs = {Aov::PrimId, Aov::ClusterId, Aov::TriangleId, Aov::Depth};
    const CameraDesc front = camera_at(0, 0, 6);

    FrameStats first, second, reference;
    auto expected = plain.render(scene, front, off, aovs, &reference);
    expect_same_images(culling.render(scene, front, on, aovs, &first), expected, "first frame");
    EXPECT_FALSE(first.occlusionTested) << "a first frame has no previous HZB";
    EXPECT_GT(first.backfaceClusters, 0u) << "the spheres' far sides face away";
    EXPECT_EQ(first.occludedInstances, 9u) << "a first frame draws the wall first (large on screen), then tests the spheres against it";
    EXPECT_GT(first.postPassClusters, 0u) << "the spheres beside the wall";
    EXPECT_EQ(first.hzbBuilds, 2u) << "after the main pass (the wall), and again with what the post pass drew";
    EXPECT_EQ(reference.hzbBuilds, 0u) << "no occlusion culling, no HZB";

    expect_same_images(culling.render(scene, front, on, aovs, &second), expected, "second frame");
    EXPECT_TRUE(second.occlusionTested);
    EXPECT_EQ(second.occludedInstances, 9u) << "the spheres behind the wall";
    EXPECT_EQ(second.postPassClusters, 0u) << "what the first frame drew in its post pass is in the HZB it kept";
    EXPECT_EQ(second.hzbBuilds, 1u) << "the HZB of the main pass is the frame's: the post pass drew nothing";
    EXPECT_LT(second.visibleClusters, first.visibleClusters);
    EXPECT_LT(first.visibleClusters, reference.visibleClusters);
    EXPECT_EQ(reference.backfaceClusters + reference.occludedInstances + reference.occludedClusters, 0u);

    // The camera moves a little: the previous frame's HZB is reprojected, and still nothing visible is lost.
    const CameraDesc moved = camera_at(0.4, -0.3, 5.5);
    FrameStats movedStats;
    expect_same_images(culling.render(scene, moved, on, aovs, &movedStats), plain.render(scene, moved, off, aovs), "moved camera");
    EXPECT_TRUE(movedStats.occlusionTested);
}

// AOVs written straight into their images' memory (imported: VK_EXT_external_memory_host; on a CPU device the last AOV
// is resolved in place) are the AOVs that go through the readback buffer, bit for bit: several AOVs, a plain
// background of unequal words, a frame too small to import (under a megabyte per image), and an overflowing frame's
// redraw. An import that is refused (no such driver) leaves the frame on the readback path.
TEST_F(RendererTest, AovsWrittenIntoTheirImagesAreTheReadbackOnes) {
    GpuScene scene;
    scene.set_instances(wall_and_spheres(scene.add_mesh(grid_mesh(16)), scene.add_mesh(bumpy_sphere(48))));
    const std::unique_ptr<Renderer> imported = renderer_with(*device, "TESSERA_IMPORT_AOVS", "1");
    const std::unique_ptr<Renderer> readback = renderer_with(*device, "TESSERA_IMPORT_AOVS", "0");
    const std::vector<Aov> aovs = {Aov::Depth, Aov::Color, Aov::PrimId, Aov::Normal};
    const bool canImport = device->host_import_alignment() != 0;
    for (const auto& [width, height] : std::vector<std::pair<uint32_t, uint32_t>>{{512, 384}, {97, 67}, {1, 1}}) {
        RenderSettings settings{width, height, {0.1f, 0.2f, 0.3f, 1.0f}};
        const std::string what = std::to_string(width) + "x" + std::to_string(height);
        for (const auto& order : {aovs, std::vector<Aov>{Aov::Color}}) {
            FrameStats in, out;
            const std::vector<Image> a = imported->render(scene, camera_at(0, 0.5, 7), settings, order, &in);
            const std::vector<Image> b = readback->render(scene, camera_at(0, 0.5, 7), settings, order, &out);
            expect_same_images(a, b, what.c_str());
            EXPECT_EQ(in.aovsImported, canImport && width * height * 16 >= (1u << 20)) << what;
            EXPECT_FALSE(out.aovsImported) << what;
        }
    }
    // The visible-cluster list overflows and the frame is drawn again: into the same images.
    const RenderSettings settings{512, 384, {0, 0, 0, 0}};
    imported->set_visible_cluster_capacity(16);
    readback->set_visible_cluster_capacity(16);
    FrameStats in, out;
    expect_same_images(imported->render(scene, camera_at(0, 0.5, 7), settings, aovs, &in), readback->render(scene, camera_at(0, 0.5, 7), settings, aovs, &out),
                       "an overflowing frame");
    EXPECT_GT(in.overflowRedraws, 0u);
    EXPECT_EQ(in.aovsImported, canImport);
}

// A frame's AOV images are imported into the device once, and the imports kept while later frames reuse the images'
// memory (a GPU would otherwise pin and unpin 33 MB of pages a frame at 1080p). Frames made while the last frame's
// images are held import their own; once the frame before last is let go, its blocks serve the next frame and no
// import is made (a CPU device's resolve writes each AOV into its image through a binding of its own; a GPU copies each
// from its slice of the output). Every frame is the readback renderer's.
TEST_F(RendererTest, AovImportsAreKeptWhileFramesReuseTheirImages) {
    if (device->host_import_alignment() == 0) GTEST_SKIP() << "this device cannot import host memory";
    GpuScene scene;
    scene.set_instances(wall_and_spheres(scene.add_mesh(grid_mesh(16)), scene.add_mesh(bumpy_sphere(48))));
    const RenderSettings settings{512, 384, {0.1f, 0.2f, 0.3f, 1.0f}};
    for (const std::vector<Aov>& aovs : {std::vector<Aov>{Aov::Depth, Aov::Color, Aov::PrimId}, std::vector<Aov>{Aov::Color}}) {
        const std::unique_ptr<Renderer> imported = renderer_with(*device, "TESSERA_IMPORT_AOVS", "1");
        const std::unique_ptr<Renderer> readback = renderer_with(*device, "TESSERA_IMPORT_AOVS", "0");
        std::vector<Image> held;
        for (int f = 0; f < 6; ++f) {
            const std::string what = "frame " + std::to_string(f) + " of " + std::to_string(aovs.size()) + " AOVs";
            const CameraDesc camera = camera_at(0.1 * f, 0.5, 7);
            FrameStats stats;
            std::vector<Image> frame = imported->render(scene, camera, settings, aovs, &stats);
            expect_same_images(frame, readback->render(scene, camera, settings, aovs), what.c_str());
            ASSERT_TRUE(stats.aovsImported) << what;
            EXPECT_EQ(stats.aovImportsMade, f < 2 ? uint32_t(aovs.size()) : 0u) << what;
            held = std::move(frame);  // lets go of the frame before
        }
    }
}

// The cull's workgroup size is chosen per device (TS_CULL_GROUP_SIZE on a GPU, one subgroup on a CPU: 8 on lavapipe):
// every size culls, cuts and defers the same clusters, so the frames are the same bit for bit.
TEST_F(RendererTest, CullWorkgroupSizesDrawTheSameFrames) {
    GpuScene scene;
    const uint32_t sphere = scene.add_mesh(bumpy_sphere(48));
    std::vector<InstanceDesc> instances = wall_and_spheres(scene.add_mesh(grid_mesh(16)), sphere);
    for (int i = 0; i < 60; ++i) {  // beside the wall, more than a workgroup's threads: each thread strides over several
        InstanceDesc s = identity_instance(sphere);
        s.transform[0] = s.transform[5] = s.transform[10] = 0.15;
        s.transform[3] = -4.5 + 0.3 * (i % 10), s.transform[7] = 2.6 + 0.3 * (i / 10), s.transform[11] = -1.0 - 0.05 * i;
        s.primId = uint32_t(200 + i);
        instances.push_back(s);
    }
    scene.set_instances(instances);
    RenderSettings settings{160, 128, {0, 0, 0, 0}};
    settings.pixelError = 0;  // source clusters: a sphere's level holds more clusters than a workgroup has threads
    settings.occlusionMinimumCulled = 0;  // occlusion in both frames, however little it culls: its deferrals are compared
    const std::vector<Aov> aovs = {Aov::PrimId, Aov::ClusterId, Aov::TriangleId, Aov::Depth};
    std::vector<Image> frames[2][2];
    FrameStats stats[2][2];
    const uint32_t sizes[2] = {TS_CULL_GROUP_SIZE, 8};
    for (int k = 0; k < 2; ++k) {
        const std::unique_ptr<Renderer> renderer = renderer_with(*device, "TESSERA_CULL_GROUP_SIZE", std::to_string(sizes[k]));
        frames[k][0] = renderer->render(scene, camera_at(0, 0.5, 7), settings, aovs, &stats[k][0]);  // first frame: no HZB yet
        frames[k][1] = renderer->render(scene, camera_at(0.3, 0.4, 6.5), settings, aovs, &stats[k][1]);  // the HZB reprojected
        EXPECT_EQ(stats[k][0].cullGroupSize, sizes[k]);
    }
    for (int f = 0; f < 2; ++f) {
        expect_same_images(frames[0][f], frames[1][f], f ? "second frame" : "first frame");
        const FrameStats &a = stats[0][f], &b = stats[1][f];
        EXPECT_EQ(a.visibleClusters, b.visibleClusters) << "frame " << f;
        EXPECT_EQ(a.candidateClusters, b.candidateClusters) << "frame " << f;
        EXPECT_EQ(a.swTriangles, b.swTriangles) << "frame " << f;
        EXPECT_EQ(a.hwTriangles, b.hwTriangles) << "frame " << f;
        EXPECT_EQ(a.occludedInstances, b.occludedInstances) << "frame " << f;
        EXPECT_EQ(a.occludedClusters, b.occludedClusters) << "frame " << f;
        EXPECT_EQ(a.postPassClusters, b.postPassClusters) << "frame " << f;
        EXPECT_GT(a.visibleClusters, 60u) << "the small spheres are drawn";
    }
    EXPECT_GT(stats[0][0].occludedInstances, 0u) << "the first frame tests the spheres behind the wall against it";
    EXPECT_GT(stats[0][1].occludedClusters + stats[0][1].occludedInstances, 0u);
}

// The pixels each resolve thread shades are chosen per device (1 on a GPU, TS_CPU_SHADE_PIXELS_PER_THREAD on a CPU):
// any count shades the same pixels, so the frames are the same bit for bit, whatever the bins' pixel counts (a frame of
// 157x45 pixels; one stage has three material bins, the other one).
TEST_F(RendererTest, ShadePixelsPerThreadDrawTheSameFrames) {
    GpuScene bins;
    const uint32_t grid = bins.add_mesh(grid_mesh(8));
    std::vector<InstanceDesc> grids;
    for (int i = 0; i < 3; ++i) {
        MaterialDesc material;
        material.diffuseColor = {0.2f * i, 0.5f, 0.3f};
        material.emissiveColor = {0.1f, 0.05f * i, 0};
        InstanceDesc instance = identity_instance(grid);
        instance.material = bins.add_material(material);
        instance.transform[3] = 1.2 * (i - 1);
        instance.transform[7] = 0.3 * (i - 1);
        instance.primId = uint32_t(i);
        grids.push_back(instance);
    }
    bins.set_instances(grids);
    GpuScene oneBin;
    oneBin.set_instances(wall_and_spheres(oneBin.add_mesh(grid_mesh(16)), oneBin.add_mesh(bumpy_sphere(48))));
    const std::vector<Aov> aovs = {Aov::Color, Aov::PrimId, Aov::Depth, Aov::Normal};
    const RenderSettings settings{157, 45, {0.25f, 0.5f, 0.75f, 1}};
    std::vector<Image> frames[3][2];
    FrameStats stats[3][2];
    const uint32_t counts[3] = {1, TS_CPU_SHADE_PIXELS_PER_THREAD, 3};
    for (int k = 0; k < 3; ++k) {
        const std::unique_ptr<Renderer> renderer = renderer_with(*device, "TESSERA_SHADE_PIXELS_PER_THREAD", std::to_string(counts[k]));
        frames[k][0] = renderer->render(bins, camera_at(0, 0, 1.6), settings, aovs, &stats[k][0]);
        frames[k][1] = renderer->render(oneBin, camera_at(0, 0.5, 7), settings, aovs, &stats[k][1]);
        EXPECT_EQ(stats[k][0].shadePixelsPerThread, counts[k]);
    }
    EXPECT_EQ(stats[0][0].shadingBins, 3u);
    EXPECT_EQ(stats[0][1].shadingBins, 1u);
    for (int k = 1; k < 3; ++k) {
        expect_same_images(frames[0][0], frames[k][0], "three bins");
        expect_same_images(frames[0][1], frames[k][1], "one bin");
    }
    size_t background = 0, covered = 0;  // both kinds of pixel in both frames
    for (int f = 0; f < 2; ++f)
        for (uint32_t y = 0; y < settings.height; ++y)
            for (uint32_t x = 0; x < settings.width; ++x) (id_at(frames[0][f][1], x, y) == 0xffffffffu ? background : covered) += 1;
    EXPECT_GT(background, 1000u);
    EXPECT_GT(covered, 1000u);
}

// The passes read the scene's streams through texel views (shared.h TS_SPEC_TEXEL_VIEWS) or through their addresses:
// the same frames bit for bit, for every AOV, both rasterizers, several material bins, a mirrored instance, the
// occlusion passes of a second frame, the visualizations that read clusters and counts, and displaced surfaces (their
// dicing, patch raster and micro-triangle resolve read the same streams). A loader that read a struct's field from the
// wrong place in its texels changes one of them (the cut blocks' loader: CutBlocksChangeWhatIsTestedNotTheCut, whose
// block path must agree with the per-cluster one).
// A textured bin's resolve variant carries only the code of its material's texture formats, encodings and wrap modes
// (TS_SPEC_TEXTURE_KINDS): the same frame bit for bit as the variant that carries every kind, for materials whose two
// wrap modes, formats and encodings differ. Leaving a material's wrapT out of its kinds changes the frame.
TEST_F(RendererTest, TexturedBinsReadOnlyTheirTextureKindsAndDrawTheSameFrame) {
    GpuScene scene;
    const uint32_t grid = scene.add_mesh(grid_mesh(8, true));
    std::vector<uint8_t> rgba(6 * 5 * 4), gray(6 * 5);
    std::vector<float> halves(6 * 5 * 4);
    for (int i = 0; i < 30; ++i) {
        for (int c = 0; c < 4; ++c) rgba[4 * i + c] = uint8_t((53 * i + 91 * c) % 256), halves[4 * i + c] = 0.1f + 0.03f * float((7 * i + c) % 29);
        gray[i] = uint8_t((29 * i) % 256);
    }
    const auto srgb = std::make_shared<const TextureImage>(make_texture(6, 5, 4, rgba.data(), nullptr, ColorSpace::Auto));
    const auto linear = std::make_shared<const TextureImage>(make_texture(6, 5, 4, rgba.data(), nullptr, ColorSpace::Raw));
    const auto r8 = std::make_shared<const TextureImage>(make_texture(6, 5, 1, gray.data(), nullptr, ColorSpace::Raw));
    const auto half = std::make_shared<const TextureImage>(make_texture(6, 5, 4, nullptr, halves.data(), ColorSpace::Raw));
    ASSERT_EQ(srgb->format, uint32_t(TS_TEXTURE_RGBA8 | TS_TEXTURE_SRGB));
    ASSERT_EQ(r8->format, TS_TEXTURE_R8);
    ASSERT_EQ(half->format, TS_TEXTURE_RGBA16F);
    auto slot = [](MaterialInput input, std::shared_ptr<const TextureImage> image, TextureWrap s, TextureWrap t) {
        return memory_slot(input, std::move(image), s, t, input == MaterialInput::Roughness ? TextureChannel::R : TextureChannel::Rgb);
    };
    const std::vector<std::vector<TextureSlot>> materials = {
        {slot(MaterialInput::DiffuseColor, srgb, TextureWrap::Repeat, TextureWrap::Black)},
        {slot(MaterialInput::Roughness, r8, TextureWrap::Mirror, TextureWrap::Clamp), slot(MaterialInput::DiffuseColor, linear, TextureWrap::Clamp, TextureWrap::Repeat)},
        {slot(MaterialInput::EmissiveColor, half, TextureWrap::Black, TextureWrap::Mirror)},
        {slot(MaterialInput::DiffuseColor, linear, TextureWrap::Mirror, TextureWrap::Repeat), slot(MaterialInput::Normal, half, TextureWrap::Repeat, TextureWrap::Clamp)}};
    std::vector<InstanceDesc> instances;
    for (size_t i = 0; i < materials.size(); ++i) {
        MaterialDesc material;
        material.textures = materials[i];
        material.uvPrimvar = "st";
        InstanceDesc instance = identity_instance(grid);
        instance.transform[3] = (double(i % 2) - 0.5) * 1.05;
        instance.transform[7] = (double(i / 2) - 0.5) * 1.05;
        instance.material = scene.add_material(material);
        instances.push_back(instance);
    }
    scene.set_instances(instances);
    scene.set_lights({{LightType::Distant, {0.3, -0.5, -1}, {2, 2, 2}}, {LightType::Dome, {0, 0, -1}, {0.2f, 0.3f, 0.4f}}});
    RenderSettings settings{128, 128, {0.25f, 0.5f, 0.75f, 1}};
    FrameStats stats;
    const std::vector<Image> specialized =
        renderer_with(*device, "TESSERA_MATERIAL_BINS", "1")->render(scene, camera_at(0, 0, 2.6), settings, {Aov::Color}, &stats);
    EXPECT_EQ(stats.textures, 4u);
    EXPECT_EQ(stats.shadingBins, 4u);
    const std::vector<Image> everyKind = renderer_with(*device, "TESSERA_TEXTURE_KINDS", "all")->render(scene, camera_at(0, 0, 2.6), settings, {Aov::Color});
    // Each pixel reading its own material, through one variant for all four materials' textures (on a CPU device).
    FrameStats pixelStats;
    const std::vector<Image> pixelMaterials =
        renderer_with(*device, "TESSERA_MATERIAL_BINS", "0")->render(scene, camera_at(0, 0, 2.6), settings, {Aov::Color}, &pixelStats);
    if (device->is_software()) EXPECT_TRUE(pixelStats.pixelMaterials);
    // lavapipe compiles both variants' shared arithmetic alike; a GPU's compiler may round one operation differently in
    // the two (an H100: one value of 65 536 one ulp off, 1.9e-9). A wrong wrap mode or format moves values by 1e-3 or more.
    expect_same_images(specialized, everyKind, "textured bins", device->is_software() ? 0.0f : 1e-6f);
    expect_same_images(specialized, pixelMaterials, "textured pixel materials", device->is_software() ? 0.0f : 1e-6f);
    EXPECT_THROW(renderer_with(*device, "TESSERA_TEXTURE_KINDS", "some"), std::invalid_argument);
}

TEST_F(RendererTest, TexelViewsAndAddressesDrawTheSameFrames) {  // and the output's and visibility's bindings against addresses
    GpuScene spheres;
    const uint32_t wall = spheres.add_mesh(grid_mesh(16)), sphere = spheres.add_mesh(bumpy_sphere(48));
    std::vector<InstanceDesc> instances = wall_and_spheres(wall, sphere);
    for (size_t i = 0; i < instances.size(); ++i) {
        MaterialDesc material;
        material.diffuseColor = {0.3f + 0.1f * float(i % 3), 0.5f, 0.2f};
        material.roughness = 0.3f;
        instances[i].material = spheres.add_material(material);
    }
    spheres.set_instances(instances);
    spheres.set_lights({{LightType::Distant, {0.3, -0.5, -1}, {2, 2, 2}}, {LightType::Dome, {0, 0, -1}, {0.2f, 0.3f, 0.4f}}});

    GpuScene displaced;
    displaced.set_instances({displaced_instance(displaced, displaced.add_mesh(bumpy_sphere(24)))});
    displaced.set_lights({{LightType::Distant, {0.3, -0.5, -1}, {2, 2, 2}}});

    // Textures of every format and wrap mode (an sRGB 8-bit diffuse map, an 8-bit roughness map, a half-float normal map,
    // an 8-bit opacity mask cut by both rasterizers) and a diffuse colour from the vertex channel: slots, records,
    // texels, texture coordinates and vertex colours are all read through views or addresses.
    GpuScene textured;
    {
        const uint32_t grid = textured.add_mesh(grid_mesh(12, true));
        std::vector<uint8_t> rgba(8 * 8 * 4), gray(8 * 8);
        std::vector<float> normals(8 * 8 * 4);
        for (int i = 0; i < 64; ++i) {
            for (int c = 0; c < 4; ++c) rgba[4 * i + c] = uint8_t((37 * i + 71 * c) % 256);
            gray[i] = uint8_t((i % 8 + i / 8) % 2 ? 220 : 30);
            normals[4 * i] = 0.3f * std::sin(float(i)), normals[4 * i + 1] = 0.3f * std::cos(float(i)), normals[4 * i + 2] = 1, normals[4 * i + 3] = 1;
        }
        auto image = [](TextureImage t) { return std::make_shared<const TextureImage>(std::move(t)); };
        const auto color = image(make_texture(8, 8, 4, rgba.data(), nullptr, ColorSpace::Auto));
        const auto mask = image(make_texture(8, 8, 1, gray.data(), nullptr, ColorSpace::Raw));
        const auto normal = image(make_texture(8, 8, 4, nullptr, normals.data(), ColorSpace::Raw));
        MaterialDesc maps;
        maps.textures = {memory_slot(MaterialInput::DiffuseColor, color, TextureWrap::Repeat, TextureWrap::Mirror, TextureChannel::Rgb),
                         memory_slot(MaterialInput::Roughness, mask, TextureWrap::Mirror, TextureWrap::Clamp, TextureChannel::R),
                         memory_slot(MaterialInput::Normal, normal, TextureWrap::Clamp, TextureWrap::Black, TextureChannel::Rgb)};
        maps.uvPrimvar = "st";
        MaterialDesc cutOut;
        cutOut.vertexInputs = kDisplayColorInputs;
        cutOut.opacityThreshold = 0.5f;
        cutOut.textures = {memory_slot(MaterialInput::Opacity, mask, TextureWrap::Black, TextureWrap::Repeat, TextureChannel::R)};
        cutOut.uvPrimvar = "st";
        InstanceDesc left = identity_instance(grid), right = identity_instance(grid);
        left.transform[3] = -0.55;
        right.transform[3] = 0.55;
        left.material = textured.add_material(maps);
        right.material = textured.add_material(cutOut);
        textured.set_instances({left, right});
        textured.set_lights({{LightType::Distant, {0.3, -0.5, -1}, {2, 2, 2}}, {LightType::Dome, {0, 0, -1}, {0.2f, 0.3f, 0.4f}}});
    }

    const std::vector<Aov> aovs = {Aov::Color, Aov::Depth, Aov::Normal, Aov::PrimId, Aov::InstanceId, Aov::ClusterId, Aov::TriangleId};
    struct Case {
        const char* name;
        GpuScene* scene;
        CameraDesc camera;
        RasterMode raster;
        Visualize visualize;
        float pixelError = 1.0f;
    };
    const Case cases[] = {{"spheres", &spheres, camera_at(0, 0.5, 7), RasterMode::Auto, Visualize::None},
                          {"spheres, source clusters (normal cones cull)", &spheres, camera_at(0, 0, 6), RasterMode::Auto, Visualize::None, 0.0f},
                          {"spheres, hardware raster", &spheres, camera_at(0.3, 0.2, 4), RasterMode::Hardware, Visualize::None},
                          {"spheres, compute raster", &spheres, camera_at(0.3, 0.2, 4), RasterMode::Software, Visualize::None},
                          {"spheres, groups", &spheres, camera_at(0, 0.5, 7), RasterMode::Auto, Visualize::Groups},
                          {"spheres, overdraw", &spheres, camera_at(0, 0.5, 7), RasterMode::Auto, Visualize::Overdraw},
                          {"textured, masked", &textured, camera_at(0, 0, 1.6), RasterMode::Hardware, Visualize::None},
                          {"textured, masked, compute raster", &textured, camera_at(0, 0, 1.6), RasterMode::Software, Visualize::None},
                          {"displaced", &displaced, camera_at(0.8, 0.3, 1.4), RasterMode::Auto, Visualize::None},
                          {"displaced, tessellation", &displaced, camera_at(0.8, 0.3, 1.4), RasterMode::Auto, Visualize::Tessellation}};
    for (const Case& c : cases) {
        RenderSettings settings{160, 96, {0.25f, 0.5f, 0.75f, 1}};
        settings.raster = c.raster;
        settings.visualize = c.visualize;
        settings.pixelError = c.pixelError;
        settings.occlusionMinimumCulled = 0;  // occlusion in both frames, however little it culls: compared too
        // Three ways: addresses only, texel views with the AOVs stored (and the rasterizers' atomics made) through the
        // addresses, and views with the output's and the visibility buffer's bindings (the default).
        std::vector<Image> frames[3][2];
        FrameStats stats[3][2];
        for (int way = 0; way < 3; ++way) {
            Renderer renderer(*device);  // its own previous frame: the second render tests against the first's HZB
            settings.texelViews = way > 0;
            settings.outputBinding = way == 2;
            for (int frame = 0; frame < 2; ++frame) frames[way][frame] = renderer.render(*c.scene, c.camera, settings, aovs, &stats[way][frame]);
        }
        for (int frame = 0; frame < 2; ++frame) {
            EXPECT_FALSE(stats[0][frame].texelViews || stats[0][frame].outputBinding) << c.name;
            EXPECT_TRUE(stats[1][frame].texelViews && !stats[1][frame].outputBinding) << c.name;
            EXPECT_TRUE(stats[2][frame].texelViews && stats[2][frame].outputBinding) << c.name;
            EXPECT_GT(stats[2][frame].visibleClusters, 0u) << c.name;
            for (int way = 0; way < 2; ++way) {
                const std::string what = std::string(c.name) + (way ? ", output address" : ", addresses") + (frame ? ", second frame" : ", first frame");
                EXPECT_EQ(stats[way][frame].visibleClusters, stats[2][frame].visibleClusters) << what;
                EXPECT_EQ(stats[way][frame].swTriangles, stats[2][frame].swTriangles) << what;
                EXPECT_EQ(stats[way][frame].hwTriangles, stats[2][frame].hwTriangles) << what;
                EXPECT_EQ(stats[way][frame].microTriangles, stats[2][frame].microTriangles) << what;
                EXPECT_EQ(stats[way][frame].backfaceClusters, stats[2][frame].backfaceClusters) << what;
                EXPECT_EQ(stats[way][frame].occludedClusters, stats[2][frame].occludedClusters) << what;
                expect_same_images(frames[way][frame], frames[2][frame], what.c_str());
            }
        }
        EXPECT_TRUE(stats[2][1].occlusionTested) << c.name;
        if (c.pixelError == 0.0f) EXPECT_GT(stats[2][0].backfaceClusters, 0u) << c.name;
        if (c.scene == &displaced) EXPECT_GT(stats[2][0].microTriangles, 0u) << c.name;
        if (c.scene == &textured) EXPECT_EQ(stats[2][0].textures, 3u) << c.name;
    }
}

// A stream's ranges: first fit among the freed ones (aligned as asked, the padding kept free), freed neighbours merged,
// the end dropping back when the last range goes; fit() keeps the ranges in use, grows with room to spare, and gives
// an empty stream one zeroed element; write() fills the ranges it is given and nothing else. Through staging (a
// discrete GPU), the upload batch sends its writes in parts of at most its bound, and a grown stream's copy on the
// device before the writes into it, in the same submission.
TEST_F(RendererTest, StreamArenaReusesFreedRangesAndKeepsTheOnesInUse) {
    UploadBatch uploads(*device);
    StreamArena arena(sizeof(uint32_t));
    arena.fit(*device, uploads);
    uploads.submit();
    ASSERT_NE(arena.buffer().handle, VK_NULL_HANDLE);
    EXPECT_EQ(arena.buffer().size, 16u) << "one zeroed element (the smallest buffer)";
    EXPECT_EQ(arena.allocate(10), 0u);
    EXPECT_EQ(arena.allocate(5), 10u);
    EXPECT_EQ(arena.allocate(4, 2), 16u) << "aligned; the padding at 15 stays free";
    EXPECT_EQ(arena.end(), 20u);
    EXPECT_EQ(arena.free_elements(), 1u);
    arena.release({0, 10});
    arena.release({10, 5});
    EXPECT_EQ(arena.free_elements(), 16u) << "0-9, 10-14 and the padding merged";
    EXPECT_EQ(arena.allocate(12), 0u) << "first fit in the merged range";
    EXPECT_EQ(arena.allocate(8), 20u) << "too long for the 4 left: past the end";
    arena.release({20, 8});
    EXPECT_EQ(arena.end(), 20u) << "the last range went: the end drops back";
    arena.release({16, 4});
    EXPECT_EQ(arena.end(), 12u) << "and again, over the free range below it";
    EXPECT_EQ(arena.free_elements(), 0u);

    // Written, grown (the ranges in use copied over), written again: each range holds what it was given.
    arena.clear();
    std::vector<StreamArena::Range> ranges = {{arena.allocate(3), 3}, {arena.allocate(70000), 70000}};
    arena.fit(*device, uploads);
    auto fill = [](size_t range, size_t first, size_t end, void* to) {
        for (size_t i = first; i < end; ++i) static_cast<uint32_t*>(to)[i - first] = uint32_t(range * 1000000 + i);
    };
    EXPECT_EQ(arena.write(uploads, ranges, fill), 70003u * 4);
    uploads.submit();
    EXPECT_EQ(arena.buffer().size, 70003u * 4) << "an empty stream grows to exactly what it holds";
    ranges.push_back({arena.allocate(100), 100});
    arena.fit(*device, uploads);
    EXPECT_EQ(arena.buffer().size, (70003u + 70003u / 4) * 4) << "with a quarter to spare once it holds meshes";
    EXPECT_EQ(arena.write(uploads, std::span(ranges).subspan(2), [&](size_t, size_t first, size_t end, void* to) { fill(2, first, end, to); }), 400u);
    uploads.submit();
    if (arena.buffer().mapped) EXPECT_EQ(uploads.submissions(), 0u) << "the host wrote the device's memory itself";
    auto expect_written = [&](Device& on, const StreamArena& a, const char* what) {
        Buffer readback = on.create_buffer(a.buffer().size, MemoryUse::Readback);
        on.run([&](VkCommandBuffer cmd) {
            const VkBufferCopy whole{0, 0, a.buffer().size};
            vkCmdCopyBuffer(cmd, a.buffer().handle, readback.handle, 1, &whole);
        });
        const uint32_t* words = static_cast<const uint32_t*>(readback.mapped);
        for (size_t r = 0; r < ranges.size(); ++r)
            for (size_t i = 0; i < ranges[r].count; i += 997) ASSERT_EQ(words[ranges[r].offset + i], r * 1000000 + i) << what << " " << r << " " << i;
    };
    expect_written(*device, arena, "mapped");

    // The same through staging of at most 100 KB, as to a discrete GPU. Runs of 64 k words (256 KB): the 3 words go in a
    // part of their own, the first run in one of its size, the rest of the stream in a third part.
    DeviceOptions options = DeviceOptions::from_environment();
    options.stagedUploads = true;
    Device staged(options);
    UploadBatch throughStaging(staged, 100000);
    StreamArena stagedArena(sizeof(uint32_t));
    for (const StreamArena::Range& range : ranges) EXPECT_EQ(stagedArena.allocate(range.count), range.offset);
    stagedArena.fit(staged, throughStaging);
    ASSERT_EQ(stagedArena.buffer().mapped, nullptr);
    EXPECT_EQ(stagedArena.write(throughStaging, ranges, fill), 70103u * 4);
    throughStaging.submit();
    EXPECT_EQ(throughStaging.submissions(), 3u);
    expect_written(staged, stagedArena, "staged");
    // Grown in one submission: the ranges in use copied on the device, then a range written where a released one was
    // (inside what the copy wrote: the copy must come first) and one past the old end.
    stagedArena.release(ranges[0]);
    ranges[0] = {stagedArena.allocate(3), 3};
    ASSERT_EQ(ranges[0].offset, 0u) << "the released place";
    ranges.push_back({stagedArena.allocate(20000), 20000});
    stagedArena.fit(staged, throughStaging);
    const std::array<StreamArena::Range, 2> written = {ranges[0], ranges[3]};
    const size_t writtenIndex[2] = {0, 3};
    stagedArena.write(throughStaging, written, [&](size_t range, size_t first, size_t end, void* to) { fill(writtenIndex[range], first, end, to); });
    throughStaging.submit();
    EXPECT_EQ(throughStaging.submissions(), 4u) << "the copy and the writes together";
    expect_written(staged, stagedArena, "staged, grown");
    EXPECT_EQ(staged.validation_error_count(), 0u);
    for (auto& m : staged.take_validation_messages()) ADD_FAILURE() << m;
}

// Uploads through staging buffers (as into a discrete GPU's memory, which the host cannot map) draw what uploads written
// straight into mapped memory draw, and a frame sends all of its uploads in one submission. A scene that gains a mesh, and loses one, after its first frames draws what a fresh
// renderer draws: the meshes already up keep their places in the streams, so the geometry upload writes the added mesh
// alone, a removal writes nothing, and a later mesh that fits takes the freed place. Cluster and triangle ids number the
// streams, so a renderer that kept its meshes' places numbers them otherwise than a fresh one: the same pixels, one to one.
TEST_F(RendererTest, StagedUploadsAndKeptMeshPlacesDrawTheSameFrames) {
    DeviceOptions options = DeviceOptions::from_environment();
    options.stagedUploads = true;
    Device staged(options);
    ASSERT_TRUE(staged.staged_uploads());

    GpuScene scene;
    const uint32_t wall = scene.add_mesh(grid_mesh(16, true)), sphere = scene.add_mesh(bumpy_sphere(48));
    std::vector<InstanceDesc> instances = wall_and_spheres(wall, sphere);
    scene.set_instances(instances);
    scene.set_lights({{LightType::Distant, {0.3, -0.5, -1}, {2, 2, 2}}, {LightType::Dome, {0, 0, -1}, {0.2f, 0.3f, 0.4f}}});
    const std::vector<Aov> aovs = {Aov::Color, Aov::PrimId, Aov::ClusterId, Aov::TriangleId};
    const RenderSettings settings{160, 96, {0.25f, 0.5f, 0.75f, 1}};
    const CameraDesc camera = camera_at(0, 0.5, 7);
    auto same_bits = [](const Image& a, const Image& b) {  // ids are float bits, the background's a NaN
        return a.pixels.size() == b.pixels.size() && std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(float)) == 0;
    };
    auto same_partition = [](const Image& a, const Image& b) {  // each id of one image stands for one id of the other
        if (a.pixels.size() != b.pixels.size()) return false;
        std::map<uint32_t, uint32_t> forward, backward;
        for (size_t i = 0; i < a.pixels.size(); i += 4) {
            uint32_t x, y;
            std::memcpy(&x, &a.pixels[i], 4);
            std::memcpy(&y, &b.pixels[i], 4);
            if (forward.emplace(x, y).first->second != y || backward.emplace(y, x).first->second != x) return false;
        }
        return true;
    };
    auto expect_same = [&](const std::vector<Image>& a, const std::vector<Image>& b, const char* what, bool renumbered) {
        ASSERT_EQ(a.size(), b.size());
        for (size_t i = 0; i < a.size(); ++i) {
            const bool numbersStreams = aovs[i] == Aov::ClusterId || aovs[i] == Aov::TriangleId;
            if (renumbered && numbersStreams) EXPECT_TRUE(same_partition(a[i], b[i])) << what << ", AOV " << i;
            else EXPECT_TRUE(same_bits(a[i], b[i])) << what << ", AOV " << i;
        }
    };

    Renderer mapped(*device), throughStaging(staged);
    FrameStats stats, stagedStats;
    const std::vector<Image> first = mapped.render(scene, camera, settings, aovs, &stats);
    expect_same(throughStaging.render(scene, camera, settings, aovs, &stagedStats), first, "staged uploads", false);
    const uint64_t firstUpload = stats.geometryUploadBytes, firstBytes = stats.geometryBytes;
    EXPECT_GT(firstUpload, 0u);
    EXPECT_LE(firstUpload, firstBytes);
    EXPECT_EQ(stagedStats.geometryUploadBytes, firstUpload);
    EXPECT_EQ(stagedStats.uploadSubmissions, 1u) << "the first frame's uploads, all of them in one submission";
    mapped.render(scene, camera, settings, aovs, &stats);
    EXPECT_EQ(stats.geometryUploadBytes, 0u) << "nothing changed, nothing written";

    // A third mesh, then the first one gone, then a small one in its place.
    const uint32_t extra = scene.add_mesh(bumpy_sphere(20));
    InstanceDesc added = identity_instance(extra);
    added.transform[3] = 1.5;
    added.primId = 77;
    instances.push_back(added);
    scene.set_instances(instances);
    for (const int step : {0, 1, 2}) {
        if (step == 1) {
            std::erase_if(instances, [&](const InstanceDesc& i) { return i.mesh == wall; });
            scene.set_instances(instances);
            scene.remove_mesh(wall);
        }
        if (step == 2) {
            InstanceDesc patch = identity_instance(scene.add_mesh(grid_mesh(4, true)));
            patch.transform[3] = -1.5;
            patch.primId = 78;
            instances.push_back(patch);
            scene.set_instances(instances);
        }
        const char* what = step == 0 ? "a mesh added" : step == 1 ? "a mesh removed" : "a small mesh added after the removal";
        const uint64_t bytesBefore = stats.geometryBytes;
        const std::vector<Image> kept = mapped.render(scene, camera, settings, aovs, &stats);
        expect_same(kept, Renderer(*device).render(scene, camera, settings, aovs), what, true);
        expect_same(throughStaging.render(scene, camera, settings, aovs, &stagedStats), kept, what, false);
        EXPECT_EQ(stagedStats.geometryUploadBytes, stats.geometryUploadBytes) << what;
        EXPECT_EQ(stagedStats.uploadSubmissions, 1u) << what << ": streams grown on the device, written, instances: one submission";
        if (step == 0) EXPECT_GT(stats.geometryUploadBytes, 0u) << what;
        if (step == 0) EXPECT_LT(stats.geometryUploadBytes, firstUpload / 2) << what << ": the added sphere alone, not the 48-ring sphere too";
        if (step == 1) EXPECT_EQ(stats.geometryUploadBytes, 0u) << what;
        if (step == 2) EXPECT_GT(stats.geometryUploadBytes, 0u) << what;
        if (step == 2) EXPECT_EQ(stats.geometryBytes, bytesBefore) << what << ": it fits where the wall was";
    }
    throughStaging.render(scene, camera, settings, aovs, &stagedStats);
    EXPECT_EQ(stagedStats.uploadSubmissions, 0u) << "nothing changed, nothing sent";
    EXPECT_EQ(staged.validation_error_count(), 0u);
    for (auto& m : staged.take_validation_messages()) ADD_FAILURE() << m;
}

// Removals leave holes in the mesh streams: once a stream's holes outgrow what it holds (and 1 MiB), the next geometry
// upload puts every mesh up again, packed, into buffers of their size, and draws what a fresh renderer draws.
TEST_F(RendererTest, MeshStreamsArePackedAgainOnceRemovalsLeaveMoreHolesThanMeshes) {
    GpuScene scene;
    const uint32_t grid = scene.add_mesh(grid_mesh(300)), sphere = scene.add_mesh(bumpy_sphere(24));
    InstanceDesc flat = identity_instance(grid), round = identity_instance(sphere);
    flat.primId = 1;
    round.primId = 2;
    round.transform[3] = 0.6;
    scene.set_instances({flat, round});
    const std::vector<Aov> aovs = {Aov::Color, Aov::PrimId, Aov::ClusterId};
    const RenderSettings settings{96, 64};
    const CameraDesc camera = camera_at(0, 0, 5);
    Renderer renderer(*device);
    FrameStats both, alone;
    renderer.render(scene, camera, settings, aovs, &both);
    scene.set_instances({round});
    scene.remove_mesh(grid);
    const std::vector<Image> packed = renderer.render(scene, camera, settings, aovs, &alone);
    EXPECT_LT(alone.geometryBytes, both.geometryBytes / 4) << "the grid's 180 k triangles' place given back";
    EXPECT_GT(alone.geometryUploadBytes, 0u) << "the sphere went up again";
    const std::vector<Image> fresh = Renderer(*device).render(scene, camera, settings, aovs);
    ASSERT_EQ(packed.size(), fresh.size());
    for (size_t i = 0; i < packed.size(); ++i)  // the same places as a fresh renderer's: the same ids too
        EXPECT_EQ(std::memcmp(packed[i].pixels.data(), fresh[i].pixels.data(), packed[i].pixels.size() * sizeof(float)), 0) << "AOV " << i;
}

// A mesh added with a way to reload it: once a renderer holds its streams on the GPU, the scene keeps its description
// alone (a mesh added without one keeps them). The renderer that uploaded it never needs them again; a second renderer
// reloads them (and the scene lets them go again), drawing the same images.
TEST_F(RendererTest, TheSceneLetsAMeshsStreamsGoOnceTheGpuHoldsThem) {
    GpuScene scene;
    const std::shared_ptr<const BuiltMesh> source = bumpy_sphere(48);
    int reloads = 0;
    const uint32_t sphere = scene.add_mesh(source, [&] {
        ++reloads;
        return source;
    });
    const uint32_t wall = scene.add_mesh(grid_mesh(16, true));
    std::vector<InstanceDesc> instances = wall_and_spheres(wall, sphere);
    scene.set_instances(instances);
    const std::vector<Aov> aovs = {Aov::Color, Aov::PrimId, Aov::ClusterId};
    const RenderSettings settings{128, 80};
    const CameraDesc camera = camera_at(0, 0.5, 7);
    EXPECT_TRUE(scene.holds_streams(sphere));
    const uint64_t bothHeld = scene.held_stream_bytes();

    Renderer first(*device);
    FrameStats stats;
    const std::vector<Image> images = first.render(scene, camera, settings, aovs, &stats);
    EXPECT_FALSE(scene.holds_streams(sphere));
    EXPECT_TRUE(scene.holds_streams(wall)) << "no way to reload it: kept";
    EXPECT_TRUE(scene.mesh(sphere)->positions.empty() && scene.mesh(sphere)->clusters.empty());
    EXPECT_EQ(scene.mesh(sphere)->sourceTriangles, source->sourceTriangles);
    EXPECT_EQ(stats.hostMeshBytes, scene.held_stream_bytes());
    EXPECT_LT(stats.hostMeshBytes, bothHeld / 4);
    instances[1].transform[3] += 0.25;  // an instance moved, then a mesh added: the sphere's streams are not needed
    scene.set_instances(instances);
    first.render(scene, camera, settings, aovs);
    const uint32_t extra = scene.add_mesh(bumpy_sphere(12));
    first.render(scene, camera, settings, aovs);
    EXPECT_EQ(reloads, 0);
    scene.remove_mesh(extra);

    instances[1].transform[3] -= 0.25;
    scene.set_instances(instances);
    const std::vector<Image> again = first.render(scene, camera, settings, aovs);
    Renderer second(*device);
    const std::vector<Image> reloaded = second.render(scene, camera, settings, aovs);
    EXPECT_EQ(reloads, 1) << "the second renderer read the streams back";
    EXPECT_FALSE(scene.holds_streams(sphere)) << "and let them go again";
    ASSERT_EQ(images.size(), reloaded.size());
    for (size_t i = 0; i < images.size(); ++i) {
        EXPECT_EQ(std::memcmp(images[i].pixels.data(), again[i].pixels.data(), images[i].pixels.size() * sizeof(float)), 0) << "AOV " << i;
        EXPECT_EQ(std::memcmp(images[i].pixels.data(), reloaded[i].pixels.data(), images[i].pixels.size() * sizeof(float)), 0) << "AOV " << i;
    }
}

// A frame whose AOV output outgrows the device's storage buffer binding (lavapipe allows 128 MiB: 8.4 M pixels) stores it
// through its address and still reads the streams through texel views; on a device that allows more, the binding.
TEST_F(RendererTest, AnOutputLargerThanTheBindingAllowsIsStoredThroughItsAddress) {
    Renderer renderer(*device);
    GpuScene scene;
    InstanceDesc instance = identity_instance(scene.add_mesh(grid_mesh(8)));
    instance.primId = 7;
    scene.set_instances({instance});
    RenderSettings settings{4096, 2056, {0, 0, 0, 0}};  // 16 B a pixel: 134.7 MB, past 2^27
    FrameStats stats;
    // The grid fills the frame: the pixels past the first 2^27 bytes are written by resolve too.
    const std::vector<Image> ids = renderer.render(scene, camera_at(0, 0, 0.4), settings, {Aov::PrimId}, &stats);
    EXPECT_TRUE(stats.texelViews);
    EXPECT_EQ(stats.outputBinding, uint64_t(4096) * 2056 * 16 <= device->max_storage_buffer_range());
    for (uint32_t y : {0u, 1028u, 2055u})
        for (uint32_t x : {0u, 2048u, 4095u}) EXPECT_EQ(id_at(ids[0], x, y), 7u) << x << ", " << y;
}

TEST_F(RendererTest, ThePostPassDrawsWhatTheLastFrameHid) {
    GpuScene scene;
    scene.set_instances(wall_and_spheres(scene.add_mesh(grid_mesh(16)), scene.add_mesh(bumpy_sphere(48))));
    Renderer culling(*device), plain(*device);
    RenderSettings on{128, 128, {0, 0, 0, 0}}, off = on;
    on.occlusionMinimumCulled = 0;  // every frame: from behind the wall, occlusion culls nothing (it would rest after)
    off.occlusion = false;
    const std::vector<Aov> aovs = {Aov::PrimId, Aov::TriangleId};
    culling.render(scene, camera_at(0, 0, 6), on, aovs);  // the spheres hide behind the wall
    // From behind the (single-sided) wall everything the first frame hid is in plain view.
    CameraDesc behind = camera_at(0, 0, -8);
    behind.cameraToWorld[0] = -1;  // turn around (rotate 180 degrees about Y)
    behind.cameraToWorld[10] = -1;
    FrameStats stats;
    expect_same_images(culling.render(scene, behind, on, aovs, &stats), plain.render(scene, behind, off, aovs), "view from behind");
    EXPECT_TRUE(stats.occlusionTested);
    EXPECT_GT(stats.postPassClusters, 0u) << "the spheres hidden last frame come back in the post pass";
    EXPECT_EQ(stats.hzbBuilds, 2u) << "after the main pass, and again with what the post pass drew";
    // The same view again: the HZB kept holds what the post pass drew, so nothing visible is deferred, and the main pass
    // needs no HZB of its own (one build, the frame's).
    FrameStats again;
    expect_same_images(culling.render(scene, behind, on, aovs, &again), plain.render(scene, behind, off, aovs), "view from behind, again");
    EXPECT_EQ(again.postPassClusters, 0u) << "last frame's HZB held the spheres it drew in its post pass";
    EXPECT_EQ(again.hzbBuilds, 1u);
}

TEST_F(RendererTest, HugeTrianglesThroughTheNearPlaneAreClippedNotDroppedOrSmeared) {
    // A ground plane 2e5 units across, two triangles, seen from 1 unit above looking at the horizon: every triangle
    // crosses the near plane and reaches far past any guard band, and the camera is inside the cluster's bounds.
    // Below the horizon every pixel must be ground, above it none, whichever rasterizer is asked for (clusters
    // through the near plane go to hardware raster).
    std::vector<float> points = {-1e5f, 0, -1e5f, 1e5f, 0, -1e5f, 1e5f, 0, 1e5f, -1e5f, 0, 1e5f};
    std::vector<int32_t> counts = {4}, indices = {0, 3, 2, 1};  // faces +Y
    GpuScene scene;
    scene.set_instances({identity_instance(scene.add_mesh(std::make_shared<BuiltMesh>(build_mesh(prepare_mesh(polygon_view("/Ground", points, counts, indices))))))});
    CameraDesc eye = camera_at(0, 1, 0);
    eye.farClip = 1e7;
    Renderer renderer(*device);
    for (RasterMode mode : {RasterMode::Auto, RasterMode::Software, RasterMode::Hardware}) {
        RenderSettings settings{128, 96, {0, 0, 0, 0}};
        settings.raster = mode;
        const Image ids = renderer.render(scene, eye, settings, {Aov::PrimId})[0];
        size_t wrong = 0;
        for (uint32_t y = 0; y < 96; ++y)
            for (uint32_t x = 0; x < 128; ++x) {
                const bool ground = id_at(ids, x, y) == 0u;
                // Rows 0-47 lie above the horizon (the image centre is between rows 47 and 48); the farthest ground
                // a row-48 pixel centre sees is 1 / tan(0.5 px) ~ 100 units away, well inside the plane.
                wrong += ground != (y >= 48);
            }
        EXPECT_EQ(wrong, 0u) << "raster mode " << int(mode);
    }
}

// A pixel offset moves where each pixel samples the scene (a whole pixel shifts the image by one, in perspective and
// orthographic views); pixel samples average the colours of their offsets, so a silhouette's alpha is its coverage,
// and keep the centre sample's ids.
TEST_F(RendererTest, PixelSamplesAverageShiftedFramesAndKeepTheCentresIds) {
    EXPECT_EQ(pixel_sample_offset(0), (std::array<float, 2>{0, 0})) << "sample 0 is the pixel's centre";
    std::set<std::array<float, 2>> offsets;
    for (uint32_t k = 0; k < 256; ++k) {
        const std::array<float, 2> o = pixel_sample_offset(k);
        EXPECT_TRUE(o[0] >= -0.5f && o[0] < 0.5f && o[1] >= -0.5f && o[1] < 0.5f) << k;
        offsets.insert(o);
    }
    EXPECT_EQ(offsets.size(), 256u);

    GpuScene scene;
    scene.set_instances({identity_instance(scene.add_mesh(bumpy_sphere(24)))});
    Renderer renderer(*device);
    const RenderSettings centre{64, 48, {0, 0, 0, 0}};
    for (bool orthographic : {false, true}) {
        CameraDesc eye = camera_at(0, 0, 4);
        if (orthographic) {
            eye.orthographic = true;
            eye.horizontalAperture = eye.verticalAperture = 4;
        }
        const Image base = renderer.render(scene, eye, centre, {Aov::TriangleId})[0];
        RenderSettings shifted = centre;
        shifted.pixelOffset = {1, -2};  // pixel (x, y) samples where pixel (x + 1, y - 2) has its centre
        const Image moved = renderer.render(scene, eye, shifted, {Aov::TriangleId})[0];
        size_t same = 0, covered = 0, compared = 0;
        for (uint32_t y = 2; y < 48; ++y)
            for (uint32_t x = 0; x + 1 < 64; ++x, ++compared) {
                same += id_at(moved, x, y) == id_at(base, x + 1, y - 2);
                covered += id_at(base, x + 1, y - 2) != 0xffffffffu;
            }
        EXPECT_GT(covered, compared / 8) << "the sphere covers a seventh of the view";
        EXPECT_GE(double(same), 0.995 * double(compared)) << (orthographic ? "orthographic" : "perspective");
    }

    const CameraDesc eye = camera_at(0, 0, 4);
    RenderSettings antialiased = centre;
    antialiased.pixelSamples = 16;
    FrameStats stats;
    const std::vector<Image> images = renderer.render(scene, eye, antialiased, {Aov::Color, Aov::TriangleId}, &stats);
    EXPECT_EQ(stats.pixelSamples, 16u);
    const Image& color = images[0];
    // Ids: the centre's, exactly as a frame of one sample draws them.
    const Image single = renderer.render(scene, eye, centre, {Aov::TriangleId})[0];
    EXPECT_EQ(std::memcmp(images[1].pixels.data(), single.pixels.data(), single.pixels.size() * sizeof(float)), 0);
    // Colour: the mean of the frames drawn at each sample's offset.
    std::vector<double> sum(color.pixels.size(), 0.0);
    for (uint32_t k = 0; k < 16; ++k) {
        RenderSettings one = centre;
        one.pixelOffset = pixel_sample_offset(k);
        const Image frame = renderer.render(scene, eye, one, {Aov::Color})[0];
        for (size_t p = 0; p < sum.size(); ++p) sum[p] += frame.pixels[p];
    }
    float largest = 0;
    for (size_t p = 0; p < sum.size(); ++p) largest = std::max(largest, std::abs(color.pixels[p] - float(sum[p] / 16)));
    EXPECT_LE(largest, 2e-6f) << "float sums of 16 samples";
    // Alpha: the silhouette's coverage, in sixteenths, adding up to the area a frame of 4 x 4 times the pixels covers.
    double alpha = 0;
    size_t partial = 0;
    for (size_t p = 3; p < color.pixels.size(); p += 4) {
        alpha += color.pixels[p];
        partial += color.pixels[p] > 0 && color.pixels[p] < 1;
        EXPECT_NEAR(color.pixels[p] * 16, std::round(color.pixels[p] * 16), 1e-3) << p / 4;
    }
    EXPECT_GT(partial, 50u) << "the silhouette's pixels are partly covered";
    const Image fine = renderer.render(scene, eye, RenderSettings{256, 192, {0, 0, 0, 0}}, {Aov::TriangleId})[0];
    size_t fineCovered = 0;
    for (uint32_t y = 0; y < 192; ++y)
        for (uint32_t x = 0; x < 256; ++x) fineCovered += id_at(fine, x, y) != 0xffffffffu;
    EXPECT_NEAR(alpha, fineCovered / 16.0, 0.01 * alpha);
    // The Gaussian: samples over two pixels' width, denser towards the centre; the colour their mean, ids still the
    // centre's.
    EXPECT_EQ(pixel_sample_offset(0, PixelFilter::Gaussian), (std::array<float, 2>{0, 0}));
    size_t beyondThePixel = 0, nearTheCentre = 0;
    std::set<std::array<float, 2>> gaussianOffsets;
    for (uint32_t k = 0; k < 256; ++k) {
        const std::array<float, 2> o = pixel_sample_offset(k, PixelFilter::Gaussian);
        EXPECT_TRUE(o[0] > -1 && o[0] < 1 && o[1] > -1 && o[1] < 1) << k;
        gaussianOffsets.insert(o);
        beyondThePixel += std::max(std::abs(o[0]), std::abs(o[1])) > 0.5f;
        nearTheCentre += std::max(std::abs(o[0]), std::abs(o[1])) < 0.25f;
    }
    EXPECT_EQ(gaussianOffsets.size(), 256u);
    EXPECT_GT(beyondThePixel, 0u) << "the Gaussian reaches into the neighbouring pixels";
    // Evenly over the two-pixel square, a sixteenth of the samples would lie within a quarter pixel of the centre; the
    // Gaussian (sigma 0.4 px) puts about a quarter there.
    EXPECT_GT(nearTheCentre, 256u / 6) << "denser towards the centre";
    RenderSettings gaussian = antialiased;
    gaussian.pixelFilter = PixelFilter::Gaussian;
    const std::vector<Image> soft = renderer.render(scene, eye, gaussian, {Aov::Color, Aov::TriangleId});
    EXPECT_EQ(std::memcmp(soft[1].pixels.data(), single.pixels.data(), single.pixels.size() * sizeof(float)), 0);
    std::vector<double> softSum(color.pixels.size(), 0.0);
    for (uint32_t k = 0; k < 16; ++k) {
        RenderSettings one = centre;
        one.pixelOffset = pixel_sample_offset(k, PixelFilter::Gaussian);
        const Image frame = renderer.render(scene, eye, one, {Aov::Color})[0];
        for (size_t p = 0; p < softSum.size(); ++p) softSum[p] += frame.pixels[p];
    }
    largest = 0;
    double softAlpha = 0;
    size_t softPartial = 0;
    for (size_t p = 0; p < softSum.size(); ++p) largest = std::max(largest, std::abs(soft[0].pixels[p] - float(softSum[p] / 16)));
    for (size_t p = 3; p < softSum.size(); p += 4) {
        softAlpha += soft[0].pixels[p];
        softPartial += soft[0].pixels[p] > 0 && soft[0].pixels[p] < 1;
    }
    EXPECT_LE(largest, 2e-6f) << "float sums of 16 samples";
    EXPECT_GT(softPartial, partial) << "a wider filter softens a wider band of the silhouette";
    EXPECT_NEAR(softAlpha, fineCovered / 16.0, 0.03 * softAlpha) << "the same area, spread wider";

    // Without a colour AOV there is nothing to average: one frame, the centre's.
    FrameStats idsOnly;
    const Image ids = renderer.render(scene, eye, antialiased, {Aov::TriangleId}, &idsOnly)[0];
    EXPECT_EQ(idsOnly.pixelSamples, 1u);
    EXPECT_EQ(std::memcmp(ids.pixels.data(), single.pixels.data(), single.pixels.size() * sizeof(float)), 0);
}

// Pixel samples summed on the device (samples.comp.glsl: a GPU's way) or on the host (a CPU device's): either way the
// image's colour is the samples' mean, whichever way the frames hand it back (a large image's imported memory, or the
// readback of a small one), the other AOVs are the centre's, and a sample drawn again after an overflow counts once.
TEST_F(RendererTest, PixelSamplesSummedOnTheDeviceOrTheHostGiveTheirMean) {
    GpuScene scene;
    scene.set_instances(wall_and_spheres(scene.add_mesh(grid_mesh(16)), scene.add_mesh(bumpy_sphere(48))));
    const CameraDesc eye = camera_at(0, 0.5, 7);
    for (const std::string sums : {"device", "host"})
        for (const auto& [width, height] : std::vector<std::pair<uint32_t, uint32_t>>{{512, 384}, {96, 64}}) {
            const std::string what = sums + ", " + std::to_string(width) + "x" + std::to_string(height);
            const RenderSettings centre{width, height, {0.1f, 0.2f, 0.3f, 1.0f}};
            RenderSettings antialiased = centre;
            antialiased.pixelSamples = 5;
            const std::unique_ptr<Renderer> renderer = renderer_with(*device, "TESSERA_SAMPLE_SUMS", sums);
            FrameStats stats;
            const std::vector<Image> images = renderer->render(scene, eye, antialiased, {Aov::PrimId, Aov::Color}, &stats);
            EXPECT_EQ(stats.pixelSamples, 5u);
            EXPECT_EQ(stats.sampleSumsOnDevice, sums == "device") << what;
            const Image ids = renderer->render(scene, eye, centre, {Aov::PrimId})[0];
            EXPECT_EQ(std::memcmp(images[0].pixels.data(), ids.pixels.data(), ids.pixels.size() * sizeof(float)), 0) << what;
            std::vector<float> sum(images[1].pixels.size(), 0.0f);  // in float and in order, as both sum
            for (uint32_t k = 0; k < 5; ++k) {
                RenderSettings one = centre;
                one.pixelOffset = pixel_sample_offset(k);
                const Image frame = renderer->render(scene, eye, one, {Aov::Color})[0];
                for (size_t p = 0; p < sum.size(); ++p) sum[p] += frame.pixels[p];
            }
            float largest = 0;
            for (size_t p = 0; p < sum.size(); ++p) largest = std::max(largest, std::abs(images[1].pixels[p] - sum[p] * (1.0f / 5)));
            EXPECT_LE(largest, 1e-6f) << what;
            // The first sample overflows the visible-cluster list and is drawn again: the same image.
            const std::unique_ptr<Renderer> overflowing = renderer_with(*device, "TESSERA_SAMPLE_SUMS", sums);
            overflowing->set_visible_cluster_capacity(2);
            FrameStats redrawn;
            const std::vector<Image> again = overflowing->render(scene, eye, antialiased, {Aov::PrimId, Aov::Color}, &redrawn);
            EXPECT_GT(redrawn.overflowRedraws, 0u) << what;
            expect_same_images(again, images, what.c_str());
        }
}

TEST_F(RendererTest, MaterialBinsShadeEachMaterialsPixels) {
    // Three grids side by side, each with its own emissive material (no lights: colour is exactly the emission);
    // a fourth material is bound to nothing in view. Each visible material gets a bin of its own.
    GpuScene scene;
    const uint32_t grid = scene.add_mesh(grid_mesh(8));
    std::vector<InstanceDesc> instances;
    const std::array<std::array<float, 3>, 4> colors = {{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 0}}};
    for (int i = 0; i < 4; ++i) {
        MaterialDesc material;
        material.diffuseColor = {0, 0, 0};
        material.emissiveColor = colors[i];
        InstanceDesc instance = identity_instance(grid);
        instance.material = scene.add_material(material);
        instance.transform[3] = i < 3 ? 1.2 * (i - 1) : 100.0;  // the fourth far off to the side
        instance.primId = uint32_t(i);
        instances.push_back(instance);
    }
    scene.set_instances(instances);
    RenderSettings settings{96, 32, {0.25f, 0.25f, 0.25f, 1}};
    // Classified into bins (a GPU's way), and each pixel reading its own material (a CPU device's): the same frame.
    std::vector<Image> binned;
    for (const char* bins : {"1", "0"}) {
        FrameStats stats;
        const auto images = renderer_with(*device, "TESSERA_MATERIAL_BINS", bins)->render(scene, camera_at(0, 0, 1.3), settings, {Aov::Color, Aov::PrimId}, &stats);
        if (bins == std::string("1")) {
            EXPECT_EQ(stats.shadingBins, 3u);
            EXPECT_FALSE(stats.pixelMaterials);
            binned = images;
        } else {
            if (device->is_software()) EXPECT_TRUE(stats.pixelMaterials) << "a CPU device reads each pixel's material";
            expect_same_images(images, binned, "pixel materials against bins");
        }
        size_t checked = 0;
        for (uint32_t y = 0; y < 32; ++y)
            for (uint32_t x = 0; x < 96; ++x) {
                const uint32_t prim = id_at(images[1], x, y);
                const float* rgba = &images[0].pixels[4 * (y * 96 + x)];
                const std::array<float, 3> expected = prim == 0xffffffffu ? std::array<float, 3>{0.25f, 0.25f, 0.25f} : colors.at(prim);
                for (int c = 0; c < 3; ++c) ASSERT_EQ(rgba[c], expected[c]) << "pixel " << x << "," << y << " prim " << prim << " bins " << bins;
                checked += prim != 0xffffffffu;
            }
        EXPECT_GT(checked, 96u * 32u / 3u) << "the grids must fill a good part of the image";
    }
}

TEST_F(RendererTest, TexturesCostNothingUntilUsedAreSharedAndUnreadableOnesShowTheirFallback) {
    GpuScene scene;
    const uint32_t grid = scene.add_mesh(grid_mesh(4));
    MaterialDesc plain;
    plain.diffuseColor = {0, 0, 0};
    plain.emissiveColor = {0.5f, 0.5f, 0.5f};
    InstanceDesc instance = identity_instance(grid);
    instance.material = scene.add_material(plain);
    scene.set_instances({instance});
    Renderer renderer(*device);
    RenderSettings settings{32, 32, {0, 0, 0, 0}};
    FrameStats stats;
    renderer.render(scene, camera_at(0, 0, 1.3), settings, {Aov::Color}, &stats);
    EXPECT_EQ(stats.textures, 0u);
    EXPECT_EQ(stats.textureBytes, 0u) << "a scene without textures has no texture memory";

    // An emissive texture whose file is missing: a warning, and the slot's fallback (green) as the emission.
    MaterialDesc missing = plain;
    TextureSlot slot;
    slot.input = MaterialInput::EmissiveColor;
    slot.file = "/nonexistent/emission.png";
    slot.fallback = {0, 1, 0, 1};
    missing.textures = {slot};
    std::vector<std::string> warnings;
    scene.textures().load_slots(missing.textures, "/Looks/Missing", warnings);
    ASSERT_EQ(warnings.size(), 1u);
    // Two materials reading one image (loaded once) share it in the pool.
    const uint8_t texel[] = {10, 20, 30, 255};
    auto image = std::make_shared<const TextureImage>(make_texture(1, 1, 4, texel, nullptr, ColorSpace::Raw));
    MaterialDesc textured = plain;
    slot.file = "memory";
    slot.image = image;
    textured.textures = {slot};
    MaterialDesc roughness = plain;
    slot.input = MaterialInput::Roughness;
    roughness.textures = {slot};
    scene.clear_materials();
    instance.material = scene.add_material(missing);
    InstanceDesc other = identity_instance(grid);
    other.transform[3] = 100.0;  // out of view: only the counts matter
    other.material = scene.add_material(textured);
    InstanceDesc third = other;
    third.material = scene.add_material(roughness);
    scene.set_instances({instance, other, third});
    const Image color = renderer.render(scene, camera_at(0, 0, 1.3), settings, {Aov::Color}, &stats)[0];
    const float* centre = &color.pixels[4 * (16 * 32 + 16)];
    EXPECT_EQ(centre[0], 0.0f);
    EXPECT_EQ(centre[1], 1.0f) << "the fallback of the unreadable texture";
    EXPECT_EQ(stats.textures, 1u) << "one image, however many materials read it";
    EXPECT_EQ(stats.textureBytes, sizeof(gpu::GpuTexture) + image->bytes() + 2 * sizeof(gpu::GpuTextureSlot));
}

TEST_F(RendererTest, MoreThan65535WorkgroupsSpillIntoTheSecondDimension) {
    // 300 x 300 tiny quads: 90 000 clusters for the compute rasterizer, one workgroup each (X stops at 65535).
    GpuScene scene;
    const uint32_t quad = scene.add_mesh(grid_mesh(1));
    std::vector<InstanceDesc> instances;
    for (int y = 0; y < 300; ++y)
        for (int x = 0; x < 300; ++x) {
            InstanceDesc instance = identity_instance(quad);
            for (int i : {0, 5, 10}) instance.transform[i] = 0.01;
            instance.transform[3] = (x - 149.5) * 0.01;
            instance.transform[7] = (y - 149.5) * 0.01;
            instance.primId = uint32_t(y * 300 + x);
            instances.push_back(instance);
        }
    scene.set_instances(instances);
    Renderer renderer(*device);
    RenderSettings settings{300, 300, {0, 0, 0, 0}};
    settings.occlusion = false;
    const CameraDesc camera = camera_at(0, 0, 3.0);  // the 3x3 field fills the 53-degree view
    settings.raster = RasterMode::Software;
    FrameStats software;
    const Image a = renderer.render(scene, camera, settings, {Aov::PrimId}, &software)[0];
    settings.raster = RasterMode::Hardware;
    const Image b = renderer.render(scene, camera, settings, {Aov::PrimId})[0];
    EXPECT_EQ(software.swClusters, 90000u);
    size_t drawn = 0, differ = 0;
    for (uint32_t y = 0; y < 300; ++y)
        for (uint32_t x = 0; x < 300; ++x) drawn += id_at(a, x, y) != 0xffffffffu, differ += id_at(a, x, y) != id_at(b, x, y);
    EXPECT_GT(drawn, 300u * 300u * 9 / 10) << "every quad covers about one pixel";
    EXPECT_EQ(differ, 0u) << "the clusters past the first 65535 must be drawn like the others";

    // More than 65535 x 64 covered pixels in one material bin: its shading dispatch spills into Y as well, with a
    // pixel per thread (a GPU's count: a CPU device's threads shade 16 each, in 16 times fewer workgroups).
    const std::unique_ptr<Renderer> perPixelRenderer = renderer_with(*device, "TESSERA_SHADE_PIXELS_PER_THREAD", "1");
    Renderer& perPixel = *perPixelRenderer;
    RenderSettings large{2100, 2100, {0, 0, 0, 0}};
    large.occlusion = false;
    // A first frame from afar leaves "nothing here" in most of the output buffer: a pixel the second frame's bin
    // dispatch missed would keep it.
    perPixel.render(scene, camera_at(0, 0, 40.0), large, {Aov::PrimId});
    const Image ids = perPixel.render(scene, camera_at(0, 0, 1.0), large, {Aov::PrimId})[0];
    size_t unshaded = 0;
    for (uint32_t y = 0; y < 2100; ++y)
        for (uint32_t x = 0; x < 2100; ++x) unshaded += id_at(ids, x, y) == 0xffffffffu;
    EXPECT_EQ(unshaded, 0u) << "the field fills the frame: every pixel is covered and shaded";
}

// Renderers on one device share its compiled pipelines (renderer/pipelines.h) and nothing else: two of them drawing
// different scenes on two threads at once give, bit for bit, what each gives alone.
TEST_F(RendererTest, RenderersSharingADeviceDrawTheirOwnScenesOnSeparateThreads) {
    GpuScene grid, sphere;
    InstanceDesc flat = identity_instance(grid.add_mesh(grid_mesh(48)));
    flat.primId = 1;
    grid.set_instances({flat});
    InstanceDesc round = identity_instance(sphere.add_mesh(bumpy_sphere(40)));
    round.primId = 2;
    sphere.set_instances({round});
    RenderSettings settings{96, 96, {0, 0, 0, 0}};
    const std::vector<Aov> aovs{Aov::PrimId, Aov::TriangleId, Aov::Depth};
    auto draw = [&](Renderer& renderer, GpuScene& scene, double distance) { return renderer.render(scene, camera_at(0, 0, distance), settings, aovs); };
    std::vector<Image> gridAlone, sphereAlone;
    {
        Renderer first(*device);
        gridAlone = draw(first, grid, 2.0);
    }
    {
        Renderer second(*device);
        sphereAlone = draw(second, sphere, 4.0);
    }
    ASSERT_EQ(id_at(gridAlone[0], 48, 48), 1u);
    ASSERT_EQ(id_at(sphereAlone[0], 48, 48), 2u);

    Renderer gridRenderer(*device), sphereRenderer(*device);
    std::vector<std::vector<Image>> gridFrames(3), sphereFrames(3);
    std::thread other([&] {
        for (auto& frame : sphereFrames) frame = draw(sphereRenderer, sphere, 4.0);
    });
    for (auto& frame : gridFrames) frame = draw(gridRenderer, grid, 2.0);
    other.join();
    auto same_bits = [](const Image& a, const Image& b) {  // ids are bits (NaN as floats), compared as such
        return a.pixels.size() == b.pixels.size() && std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(float)) == 0;
    };
    for (size_t f = 0; f < 3; ++f)
        for (size_t a = 0; a < aovs.size(); ++a) {
            EXPECT_TRUE(same_bits(gridFrames[f][a], gridAlone[a])) << "grid frame " << f << " " << aov_name(aovs[a]);
            EXPECT_TRUE(same_bits(sphereFrames[f][a], sphereAlone[a])) << "sphere frame " << f << " " << aov_name(aovs[a]);
        }
}

// A renderer's pipelines are made in the background while its scene loads (pipelines.h): a frame drawn at once waits
// for them and draws what a renderer whose pipelines were made long before draws, and a device given back while they
// are still being made waits for them first (no pipeline made on a destroyed device, no validation message).
TEST_F(RendererTest, PipelinesMadeInTheBackgroundServeAFrameDrawnAtOnce) {
    GpuScene scene;
    scene.set_instances({identity_instance(scene.add_mesh(bumpy_sphere(24)))});
    const RenderSettings settings{96, 64, {0, 0, 0, 0}};
    const std::vector<Aov> aovs = {Aov::Color, Aov::PrimId, Aov::TriangleId, Aov::Depth};
    const std::vector<Image> expected = Renderer(*device).render(scene, camera_at(0, 0, 3), settings, aovs);
    for (const bool draw : {false, true}) {
        auto fresh = std::make_unique<Device>();  // pipelines of its own, made from scratch
        auto renderer = std::make_unique<Renderer>(*fresh);
        if (draw) expect_same_images(renderer->render(scene, camera_at(0, 0, 3), settings, aovs), expected, "a frame drawn at once");
        renderer.reset();
        EXPECT_EQ(fresh->validation_error_count(), 0u) << (draw ? "drawn at once" : "given back at once");
        for (auto& m : fresh->take_validation_messages()) ADD_FAILURE() << m;
        fresh.reset();  // waits for the pipelines still being made
    }
}

// The workgroup order of resolve and the compute rasterizer (shared.h spread_index, the very code the shaders run): a
// permutation of [0, n) for every n, neighbours kept within a band, and each of the runs that lavapipe's 2, 4 or 8
// threads take reaching into every eighth, quarter or half of the bands.
TEST(SpreadIndex, PermutesAndSpreadsEveryRunOfWorkgroups) {
    const uint32_t bands = TS_SPREAD_BANDS;
    for (uint32_t n = 0; n < 40 * bands; n += n < 4 * bands ? 1 : 7) {
        const uint32_t band = n / bands;  // a band's workgroups
        std::vector<bool> taken(n, false);
        for (uint32_t k = 0; k < n; ++k) {
            const uint32_t at = gpu::spread_index(k, n);
            ASSERT_LT(at, n) << k << " of " << n;
            ASSERT_FALSE(taken[at]) << k << " of " << n << " lands where another did";
            taken[at] = true;
            if (band > 0 && k % band != 0 && k < band * bands)
                ASSERT_EQ(at, gpu::spread_index(k - 1, n) + 1) << k << " of " << n << ": a band's neighbours stay neighbours";
        }
        if (n < 8 * bands) continue;
        for (const uint32_t runs : {2u, 4u, 8u}) {
            const uint32_t parts = bands / runs;
            for (uint32_t run = 0; run < runs; ++run) {
                const uint32_t first = run * n / runs, end = (run + 1) * n / runs;
                std::set<uint32_t> reached;
                for (uint32_t k = first; k < end; ++k)  // parts of the bands
                    reached.insert(std::min(gpu::spread_index(k, n), band * bands - 1) * parts / (band * bands));
                // Any `parts` consecutive bands land one in each part. A run whose edges are not the bands' (the indices
                // past the bands shift them) holds fewer whole bands: as many parts as it holds.
                const uint32_t firstWhole = (first + band - 1) / band, endWhole = std::min(end / band, bands);
                const uint32_t whole = endWhole > firstWhole ? endWhole - firstWhole : 0;
                if (n % bands == 0) ASSERT_EQ(whole, parts);
                EXPECT_GE(reached.size(), std::min(whole, parts)) << "run " << run << " of " << runs << ", " << n << " workgroups";
            }
        }
    }
}

// The process's devices (Device::shared): one per options, until released; a device that cannot be made is not kept.
TEST(SharedDevice, OnePerOptionsUntilReleased) {
    const DeviceOptions options = DeviceOptions::from_environment();
    const std::shared_ptr<Device> first = Device::shared(options), again = Device::shared(options);
    EXPECT_EQ(first.get(), again.get());
    DeviceOptions missing = options;
    missing.select = "no device is called this";
    EXPECT_THROW(Device::shared(missing), DeviceError);
    EXPECT_THROW(Device::shared(missing), DeviceError) << "a failure is not remembered as a device";
    Device::release_shared_devices();
    const std::shared_ptr<Device> after = Device::shared(options);
    EXPECT_NE(after.get(), first.get()) << "a released device is not handed out again";
    EXPECT_EQ(first->validation_error_count(), 0u);
    Device::release_shared_devices();
}

// The device's switches from the environment: 1 on, 0 or unset off, anything else an error naming the variable (as the
// renderer's own choices: TESSERA_KEEP_IMPORTS, ...), never a silent guess ("false" once meant on).
TEST(DeviceOptions, EnvironmentSwitchesAreOneOrZeroAndNameTheVariableOtherwise) {
    struct Restore {  // the suite runs with TESSERA_VALIDATION set: put both variables back however the test ends
        std::string validation, staged;
        bool hadValidation, hadStaged;
        ~Restore() {
            if (hadValidation) setenv("TESSERA_VALIDATION", validation.c_str(), 1);
            else unsetenv("TESSERA_VALIDATION");
            if (hadStaged) setenv("TESSERA_STAGED_UPLOADS", staged.c_str(), 1);
            else unsetenv("TESSERA_STAGED_UPLOADS");
        }
    };
    const char* v = std::getenv("TESSERA_VALIDATION");
    const char* s = std::getenv("TESSERA_STAGED_UPLOADS");
    const Restore restore{v ? v : "", s ? s : "", v != nullptr, s != nullptr};
    unsetenv("TESSERA_VALIDATION");
    unsetenv("TESSERA_STAGED_UPLOADS");
    EXPECT_FALSE(DeviceOptions::from_environment().validation);
    EXPECT_FALSE(DeviceOptions::from_environment().stagedUploads);
    setenv("TESSERA_VALIDATION", "1", 1);
    setenv("TESSERA_STAGED_UPLOADS", "1", 1);
    EXPECT_TRUE(DeviceOptions::from_environment().validation);
    EXPECT_TRUE(DeviceOptions::from_environment().stagedUploads);
    setenv("TESSERA_VALIDATION", "0", 1);
    EXPECT_FALSE(DeviceOptions::from_environment().validation);
    for (const char* variable : {"TESSERA_VALIDATION", "TESSERA_STAGED_UPLOADS"}) {
        setenv(variable, "false", 1);
        try {
            (void)DeviceOptions::from_environment();
            ADD_FAILURE() << variable << "=false was taken";
        } catch (const std::invalid_argument& error) {
            EXPECT_NE(std::string(error.what()).find(variable), std::string::npos) << error.what();
        }
        setenv(variable, "1", 1);
    }
}

// Image pixels (image_memory.cpp): a freed large block serves the next image of its size, so a frame's readback does
// not fault in fresh pages; at most two wait; small images are plain allocations.
TEST(ImageMemory, FreedLargeBlocksServeTheNextImageOfTheirSize) {
    const size_t frame = size_t(1920) * 1080 * 4;  // a 1080p RGBA float image
    PixelVector first(frame, 0.5f);
    const float* block = first.data();
    first = PixelVector();  // freed: kept
    PixelVector second(frame, 0.25f);
    EXPECT_EQ(second.data(), block) << "the freed block of that size";
    EXPECT_EQ(second[frame - 1], 0.25f);
    PixelVector other(frame / 2, 1.0f);  // another size: a block of its own
    EXPECT_NE(other.data(), block);
    // Three freed: the two newest wait, the oldest goes back to the system.
    PixelVector a(frame), b(frame), c(frame);
    const float* newest[2] = {b.data(), c.data()};
    a = PixelVector(), b = PixelVector(), c = PixelVector();
    PixelVector d(frame), e(frame);
    EXPECT_EQ(d.data(), newest[1]);
    EXPECT_EQ(e.data(), newest[0]);
    PixelVector small(64, 2.0f);  // under a megabyte
    EXPECT_EQ(small[63], 2.0f);
}

// A block a device has imported is pinned (the renderer keeps its AOV images' imports): freed, it waits among the spare
// blocks however many of its size are freed after it, and serves the next image of its size before a newer one. Pins
// are counted; unpinned, it is an ordinary spare block again and goes back to the system when its turn comes.
TEST(ImageMemory, PinnedBlocksAreNeverReturnedToTheSystem) {
    const size_t frame = size_t(1024) * 768 * 4;
    PixelVector imported(frame, 0.75f);
    float* const block = imported.data();
    pin_pixel_block(block);
    pin_pixel_block(block);  // imported twice
    {
        PixelVector a(frame), b(frame), c(frame);
        imported = PixelVector();  // spare, the oldest: three freed after it would push out an unpinned block
    }
    PixelVector next(frame);
    EXPECT_EQ(next.data(), block) << "the pinned block waited, and serves before the newer spare ones";
    EXPECT_EQ(next[frame - 1], 0.75f) << "its pixels never went back to the system";
    unpin_pixel_block(block);  // one import left
    {
        PixelVector a(frame), b(frame), c(frame);
        next = PixelVector();
    }
    PixelVector again(frame);
    EXPECT_EQ(again.data(), block) << "still pinned by its second import";
    unpin_pixel_block(block);
    {
        PixelVector a(frame), b(frame), c(frame);
        again = PixelVector();  // spare and unpinned: the oldest, pushed out by the three freed after it
    }
    PixelVector x(frame), y(frame);
    EXPECT_NE(x.data(), block);
    EXPECT_NE(y.data(), block);
}
