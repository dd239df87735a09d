// The CPU side of runtime displacement (renderer/displacement.h): per-cluster bounds must hold every offset the GPU can
// compute for a point of the cluster (its own texture coordinates and the other sides' at its UV seams), and be tighter
// than the material's bound where the texture varies.
#include "displacement.h"

#include <gtest/gtest.h>

#include "shared.h"
#include "test_meshes.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <random>

using namespace tessera;

namespace {

// A bumpy n x n grid of quads whose texture coordinates jump across the middle column: two UV islands (a seam).
BuiltMesh grid_with_seam(int n, std::vector<float>& points, std::vector<int32_t>& counts, std::vector<int32_t>& indices, std::vector<float>& uvs) {
    quad_grid(
        n, [](int x, int y) { return std::array<float, 3>{float(x), float(y), 0.3f * std::sin(0.7f * x) * std::cos(0.5f * y)}; },
        [&](int x, int, int cx, int cy) {
            // Left island: u in [0, 0.4]; right island: u in [0.55, 0.95] (the middle column has both).
            const bool right = x >= n / 2;
            const float u = right ? 0.55f + 0.4f * float(cx - n / 2) / float(n - n / 2) : 0.4f * float(cx) / float(n / 2);
            uvs.insert(uvs.end(), {u, float(cy) / float(n)});
        },
        points, counts, indices);
    MeshView v = polygon_view("/SeamGrid", points, counts, indices);
    v.uvs.interpolation = Interpolation::FaceVarying;
    v.uvs.components = 2;
    v.uvs.values = uvs;
    return build_mesh(prepare_mesh(v));
}

float word_float(const std::vector<uint32_t>& words, uint32_t i) {
    float f;
    std::memcpy(&f, &words[i], 4);
    return f;
}

}  // namespace

TEST(Displacement, ClusterBoundsHoldEveryOffsetTheirPointsCanTake) {
    std::vector<float> points, uvs;
    std::vector<int32_t> counts, indices;
    const BuiltMesh mesh = grid_with_seam(48, points, counts, indices, uvs);
    ASSERT_GT(mesh.clusters.size(), 20u);

    // A height map that rises along u (so bounds differ from cluster to cluster), with noise.
    const uint32_t width = 96, height = 64;
    std::mt19937 random(3);
    std::uniform_real_distribution<float> unit(0.0f, 1.0f);
    std::vector<uint8_t> pixels(size_t(width) * height);
    for (uint32_t y = 0; y < height; ++y)
        for (uint32_t x = 0; x < width; ++x) pixels[size_t(y) * width + x] = uint8_t(std::clamp(255.0f * float(x) / width + 12.0f * (unit(random) - 0.5f), 0.0f, 255.0f));
    MaterialDesc material;
    material.displacementMagnitude = 0.5f;  // offsets from 0 to 0.5, growing with u
    TextureSlot slot;
    slot.input = MaterialInput::Displacement;
    slot.channel = TextureChannel::R;
    slot.wrapS = slot.wrapT = TextureWrap::Clamp;  // (repeat would blend u = 0 with the highest column)
    slot.image = std::make_shared<TextureImage>(make_texture(width, height, 1, pixels.data(), nullptr, ColorSpace::Raw));
    material.textures.push_back(slot);
    const float whole = material_displacement_bound(material);
    ASSERT_GT(whole, 0.45f);

    std::vector<uint32_t> seamWords;
    const auto seams = append_uv_seams(mesh, seamWords);
    ASSERT_NE(seams[0], uint32_t(TS_NO_STREAM)) << "the grid has a UV seam";
    const auto boxes = cluster_uv_boxes(mesh, seamWords, seams);
    ClusterDisplacementBounds bounds;
    const std::vector<float> bound = bounds.compute(mesh, boxes, {&material});
    ASSERT_EQ(bound.size(), mesh.clusters.size());

    auto offset = [&](float s, float t) { return std::abs((sample_slot_level0(slot, s, t) - material.displacementCenter) * material.displacementMagnitude); };
    size_t tight = 0, seamClusters = 0;
    for (size_t i = 0; i < mesh.clusters.size(); ++i) {
        const Cluster& c = mesh.clusters[i];
        EXPECT_LE(bound[i], whole) << "cluster " << i;
        tight += bound[i] < 0.5f * whole;
        bool seam = false;
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            const uint32_t packed = mesh.triangles[c.triangleOffset + t];
            const uint32_t v[3] = {c.vertexOffset + (packed & 0xffu), c.vertexOffset + ((packed >> 8) & 0xffu), c.vertexOffset + ((packed >> 16) & 0xffu)};
            // Points inside the triangle read its own coordinates.
            for (int k = 0; k < 16; ++k) {
                float a = unit(random), b = unit(random);
                if (a + b > 1) a = 1 - a, b = 1 - b;
                const float w[3] = {1 - a - b, a, b};
                float s = 0, tt = 0;
                for (int j = 0; j < 3; ++j) s += w[j] * mesh.uvs[2 * v[j]], tt += w[j] * mesh.uvs[2 * v[j] + 1];
                ASSERT_LE(offset(s, tt), bound[i] + 1e-6f) << "cluster " << i << " triangle " << t;
            }
            // Corners read every coordinate at their position, seam edges the other side's.
            for (int j = 0; j < 3; ++j) {
                const uint32_t word = seamWords[seams[0] + v[j]];
                if (word == TS_NO_STREAM) continue;
                seam = true;
                const uint32_t first = word & ((1u << TS_SEAM_COUNT_SHIFT) - 1u), count = word >> TS_SEAM_COUNT_SHIFT;
                for (uint32_t k = 0; k < count; ++k)
                    ASSERT_LE(offset(word_float(seamWords, first + 2 * k), word_float(seamWords, first + 2 * k + 1)), bound[i] + 1e-6f) << "cluster " << i;
            }
            const uint32_t record = seamWords[seams[1] + c.triangleOffset + t];
            if (record == TS_NO_STREAM) continue;
            for (int e = 0; e < 3; ++e) {
                const float s0 = word_float(seamWords, record + 4 * e), t0 = word_float(seamWords, record + 4 * e + 1);
                const float s1 = word_float(seamWords, record + 4 * e + 2), t1 = word_float(seamWords, record + 4 * e + 3);
                if (std::isnan(s0)) continue;
                for (int k = 0; k <= 8; ++k) {
                    const float f = k / 8.0f;
                    ASSERT_LE(offset(s0 + (s1 - s0) * f, t0 + (t1 - t0) * f), bound[i] + 1e-6f) << "cluster " << i << " seam edge " << e;
                }
            }
        }
        seamClusters += seam;
    }
    EXPECT_GT(seamClusters, 0u);
    // The heights climb along u: the left island's clusters (u up to 0.4) move less than half the whole range.
    EXPECT_GT(tight, mesh.clusters.size() / 4) << "per-cluster bounds should be tighter than the material's";
}

TEST(Displacement, ConstantAndBakedMaterialsBoundAlike) {
    MaterialDesc constant;
    constant.displacement = 0.8f;
    constant.displacementCenter = 0.5f;
    constant.displacementMagnitude = -2.0f;
    EXPECT_FLOAT_EQ(material_displacement_bound(constant), 0.6f);
    constant.displacementBake = true;
    EXPECT_EQ(material_displacement_bound(constant), 0.0f) << "a baked displacement is in the mesh already";
    MaterialDesc none;
    EXPECT_EQ(material_displacement_bound(none), 0.0f);
}

// A mesh's displacement data is made once and its seam words placed later, after other meshes' words: they must read
// as the words made in place would (every list and record number moved by where they land).
TEST(Displacement, SeamWordsPlacedAfterOthersMatchThoseMadeInPlace) {
    std::vector<float> points, uvs;
    std::vector<int32_t> counts, indices;
    const BuiltMesh mesh = grid_with_seam(24, points, counts, indices, uvs);
    const DisplacementData data = displacement_data(mesh);
    ASSERT_NE(data.seams[0], TS_NO_STREAM) << "the grid has a UV seam";
    EXPECT_EQ(data.normals, displacement_normals(mesh));
    std::vector<uint32_t> inPlace(777, 5u), placed(777, 5u);  // another mesh's words before
    const auto madeInPlace = append_uv_seams(mesh, inPlace);
    const auto moved = append_seam_words(data, placed);
    EXPECT_EQ(moved, madeInPlace);
    EXPECT_EQ(placed, inPlace);
    std::vector<uint32_t> fromZero;
    EXPECT_EQ(append_seam_words(data, fromZero), data.seams);
    EXPECT_EQ(fromZero, data.seamWords);
    // A mesh without texture coordinates has no seams, and appends nothing.
    const BuiltMesh plain = build_mesh(prepare_mesh(polygon_view("/Plain", points, counts, indices)));
    const DisplacementData none = displacement_data(plain);
    std::vector<uint32_t> untouched(3, 1u);
    EXPECT_EQ(append_seam_words(none, untouched)[0], TS_NO_STREAM);
    EXPECT_EQ(untouched.size(), 3u);
}
