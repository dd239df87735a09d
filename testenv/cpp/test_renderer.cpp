// Renderer on the real device (lavapipe here): coverage, ids, overflow redraw, camera-relative precision.
#include "tessera/delegate.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>

using namespace tessera;

namespace {
uint32_t id_at(const Image& image, uint32_t x, uint32_t y) {
    uint32_t bits;
    std::memcpy(&bits, &image.pixels[4 * (y * image.width + x)], 4);
    return bits;
}

std::shared_ptr<BuiltMesh> grid_mesh(int n) {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    for (int y = 0; y <= n; ++y)
        for (int x = 0; x <= n; ++x) points.insert(points.end(), {float(x) / n - 0.5f, float(y) / n - 0.5f, 0.0f});
    for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
            counts.push_back(4);
            const int a = y * (n + 1) + x;
            indices.insert(indices.end(), {a, a + 1, a + n + 2, a + n + 1});
        }
    MeshView v;
    v.name = "/Grid";
    v.points = points;
    v.faceVertexCounts = counts;
    v.faceVertexIndices = indices;
    return std::make_shared<BuiltMesh>(build_mesh(prepare_mesh(v)));
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

class RendererTest : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        device = new Device();
        const char* wanted = std::getenv("TESSERA_VALIDATION");
        if (wanted && std::string(wanted) == "1") EXPECT_TRUE(device->validation_enabled()) << "the validation layer must be active";
    }
    static void TearDownTestSuite() {
        EXPECT_EQ(device->validation_error_count(), 0u);
        for (auto& m : device->take_validation_messages()) ADD_FAILURE() << m;
        delete device;
    }
    static Device* device;
};
Device* RendererTest::device = nullptr;
}  // namespace

TEST_F(RendererTest, GridCoversTheExpectedPixels) {
    Renderer renderer(*device);
    GpuScene scene;
    const uint32_t mesh = scene.add_mesh(grid_mesh(64));
    InstanceDesc instance;
    instance.mesh = mesh;
    instance.transform = identity_matrix();
    instance.primId = 42;
    scene.set_instances({instance});
    scene.set_lights({{LightType::Dome, {0, 0, -1}, {1, 1, 1}}});
    // 1 unit wide at distance 2 with a 53-degree view: the grid covers the middle half of the image.
    RenderSettings settings{128, 128, {0, 0, 0, 0}};
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
}

TEST_F(RendererTest, SingleSidedBackFacesAreCulledDoubleSidedAreNot) {
    Renderer renderer(*device);
    GpuScene scene;
    InstanceDesc instance;
    instance.mesh = scene.add_mesh(grid_mesh(4));
    instance.transform = identity_matrix();
    scene.set_instances({instance});
    RenderSettings settings{32, 32, {0, 0, 0, 0}};
    CameraDesc behind = camera_at(0, 0, -2);
    behind.cameraToWorld[0] = -1;  // turn around (rotate 180 degrees about Y)
    behind.cameraToWorld[10] = -1;
    EXPECT_EQ(id_at(renderer.render(scene, behind, settings, {Aov::PrimId})[0], 16, 16), 0xffffffffu);
    instance.doubleSided = true;
    scene.set_instances({instance});
    EXPECT_EQ(id_at(renderer.render(scene, behind, settings, {Aov::PrimId})[0], 16, 16), 0u);
}

TEST_F(RendererTest, OverflowGrowsTheListAndRedrawsTheExactImage) {
    Renderer renderer(*device);
    GpuScene scene;
    InstanceDesc instance;
    instance.mesh = scene.add_mesh(grid_mesh(64));
    instance.transform = identity_matrix();
    scene.set_instances({instance});
    RenderSettings settings{64, 64, {0, 0, 0, 0}};
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
        InstanceDesc instance;
        instance.mesh = mesh;
        instance.transform = identity_matrix();
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
