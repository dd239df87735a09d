// Textures: mip chains built on the CPU (formats, orientation, box filter in linear light), files read with
// OpenImageIO and shared between users, and shaders/texture.h's sampling on the device against a CPU reference
// written here from the definitions (wrap modes, bilinear, trilinear level choice, sRGB decode, UsdTransform2d,
// scale and bias, output channels).
#include "tessera/textures.h"
#include "tessera/device.h"

#include <gtest/gtest.h>

#include <OpenImageIO/imageio.h>

#include "device_fixture.h"
#include "shared.h"
#include "spirv/texture_probe_comp.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <unistd.h>

using namespace tessera;

namespace {

using Rgba = std::array<double, 4>;

uint32_t byte_of(const TextureImage& t, size_t texel, int channel) { return (t.words[texel] >> (8 * channel)) & 0xffu; }

double srgb_decode(double c) { return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); }
double srgb_encode(double c) { return c <= 0.0031308 ? c * 12.92 : 1.055 * std::pow(c, 1 / 2.4) - 0.055; }

double half_value(uint32_t bits) {
    const int exponent = int((bits >> 10) & 31), mantissa = int(bits & 1023);
    const double magnitude = exponent == 0 ? std::ldexp(mantissa, -24) : std::ldexp(1024 + mantissa, exponent - 25);
    return (bits & 0x8000u) ? -magnitude : magnitude;
}

// ---- The CPU reference of texture.h, written from shared.h's definitions ----

struct Level {
    uint32_t width, height, offset;
};

std::vector<Level> levels_of(const TextureImage& t) {
    std::vector<Level> levels;
    uint32_t offset = 0;
    const uint32_t format = t.format & TS_TEXTURE_FORMAT_MASK;
    for (uint32_t l = 0; l < t.levels; ++l) {
        const uint32_t w = std::max(1u, t.width >> l), h = std::max(1u, t.height >> l);
        levels.push_back({w, h, offset});
        const uint32_t texels = w * h;
        offset += format == TS_TEXTURE_R8 ? (texels + 3) / 4 : format == TS_TEXTURE_RGBA16F ? 2 * texels : texels;
    }
    return levels;
}

Rgba reference_texel(const TextureImage& t, const Level& level, int x, int y) {
    if (x < 0 || y < 0) return {0, 0, 0, 0};
    const size_t i = size_t(y) * level.width + x;
    const uint32_t format = t.format & TS_TEXTURE_FORMAT_MASK;
    Rgba v;
    if (format == TS_TEXTURE_RGBA8) {
        for (int c = 0; c < 4; ++c) v[c] = ((t.words[level.offset + i] >> (8 * c)) & 0xffu) / 255.0;
    } else if (format == TS_TEXTURE_R8) {
        const double r = ((t.words[level.offset + i / 4] >> (8 * (i % 4))) & 0xffu) / 255.0;
        v = {r, r, r, 1};
    } else {
        for (int c = 0; c < 4; ++c) v[c] = half_value(t.words[level.offset + 2 * i + c / 2] >> (16 * (c % 2)) & 0xffffu);
    }
    if (t.format & TS_TEXTURE_SRGB)
        for (int c = 0; c < 3; ++c) v[c] = srgb_decode(v[c]);
    return v;
}

int reference_wrap(long i, long n, TextureWrap mode) {
    const auto floor_mod = [](long a, long m) { return ((a % m) + m) % m; };
    switch (mode) {
        case TextureWrap::Repeat: return int(floor_mod(i, n));
        case TextureWrap::Mirror: {
            const long m = floor_mod(i, 2 * n);
            return int(m < n ? m : 2 * n - 1 - m);
        }
        case TextureWrap::Clamp: return int(std::clamp(i, 0L, n - 1));
        case TextureWrap::Black: return i < 0 || i >= n ? -1 : int(i);
    }
    return 0;
}

Rgba reference_bilinear(const TextureImage& t, const Level& level, double u, double v, TextureWrap ws, TextureWrap wt) {
    const double px = u * level.width - 0.5, py = v * level.height - 0.5;
    const double bx = std::floor(px), by = std::floor(py), fx = px - bx, fy = py - by;
    const int x0 = reference_wrap(long(bx), level.width, ws), x1 = reference_wrap(long(bx) + 1, level.width, ws);
    const int y0 = reference_wrap(long(by), level.height, wt), y1 = reference_wrap(long(by) + 1, level.height, wt);
    const Rgba a = reference_texel(t, level, x0, y0), b = reference_texel(t, level, x1, y0);
    const Rgba c = reference_texel(t, level, x0, y1), d = reference_texel(t, level, x1, y1);
    Rgba out;
    for (int k = 0; k < 4; ++k) out[k] = (a[k] * (1 - fx) + b[k] * fx) * (1 - fy) + (c[k] * (1 - fx) + d[k] * fx) * fy;
    return out;
}

Rgba reference_sample(const TextureImage& t, double u, double v, const double dx[2], const double dy[2], TextureWrap ws, TextureWrap wt) {
    const auto levels = levels_of(t);
    const double lx = std::hypot(dx[0] * t.width, dx[1] * t.height), ly = std::hypot(dy[0] * t.width, dy[1] * t.height);
    const double footprint = std::max(lx, ly);
    const double lod = footprint > 1 ? std::min(std::log2(footprint), double(t.levels - 1)) : 0.0;
    const uint32_t level = uint32_t(lod);
    const double blend = lod - level;
    Rgba value = reference_bilinear(t, levels[level], u, v, ws, wt);
    if (blend > 0) {
        const Rgba next = reference_bilinear(t, levels[level + 1], u, v, ws, wt);
        for (int k = 0; k < 4; ++k) value[k] += (next[k] - value[k]) * blend;
    }
    return value;
}

// UsdUVTexture with its UsdTransform2d: the value at st, after scale and bias, in the output's channel(s).
Rgba reference_slot(const TextureImage& t, const TextureSlot& slot, const double st[2], const double dst_dx[2], const double dst_dy[2]) {
    const auto& m = slot.transform;
    const double u = m[0] * st[0] + m[1] * st[1] + m[2], v = m[3] * st[0] + m[4] * st[1] + m[5];
    const double dx[2] = {m[0] * dst_dx[0] + m[1] * dst_dx[1], m[3] * dst_dx[0] + m[4] * dst_dx[1]};
    const double dy[2] = {m[0] * dst_dy[0] + m[1] * dst_dy[1], m[3] * dst_dy[0] + m[4] * dst_dy[1]};
    Rgba value = reference_sample(t, u, v, dx, dy, slot.wrapS, slot.wrapT);
    for (int k = 0; k < 4; ++k) value[k] = value[k] * slot.scale[k] + slot.bias[k];
    if (slot.channel != TextureChannel::Rgb) value.fill(value[size_t(slot.channel)]);
    return value;
}

// ---- Running texture.h on the device ----

struct ProbePush {
    uint64_t pool, slots, probes, results;
    uint32_t count;
};

struct Probe {
    float st[2], dx[2], dy[2];
    uint32_t slot, pad;
};

class TextureSamplingTest : public DeviceTest {
protected:
    // texture_slot_value() of every probe, through shaders/texture.h on the device. The pool and the slots are laid
    // out as the renderer lays them out (records, then each image's words).
    static std::vector<std::array<float, 4>> sample_on_device(const std::vector<const TextureImage*>& images, const std::vector<TextureSlot>& slots,
                                                              const std::vector<uint32_t>& slotImages, const std::vector<Probe>& probes) {
        std::vector<uint32_t> pool;
        uint32_t offset = uint32_t(images.size() * 4);
        for (const TextureImage* t : images) {
            pool.insert(pool.end(), {t->width, t->height, offset, t->format | t->levels << 8});
            offset += uint32_t(t->words.size());
        }
        for (const TextureImage* t : images) pool.insert(pool.end(), t->words.begin(), t->words.end());
        std::vector<gpu::GpuTextureSlot> gpuSlots;
        for (size_t i = 0; i < slots.size(); ++i) {
            const TextureSlot& s = slots[i];
            gpu::GpuTextureSlot g{};
            g.scale = {s.scale[0], s.scale[1], s.scale[2], s.scale[3]};
            g.bias = {s.bias[0], s.bias[1], s.bias[2], s.bias[3]};
            g.transform = {s.transform[0], s.transform[1], s.transform[3], s.transform[4]};
            g.translationS = s.transform[2];
            g.translationT = s.transform[5];
            g.texture = slotImages[i];
            g.mode = uint32_t(s.wrapS) | uint32_t(s.wrapT) << 2 | uint32_t(s.channel) << 4;
            gpuSlots.push_back(g);
        }
        Buffer poolBuffer = device->create_buffer(pool.size() * 4, MemoryUse::Device);
        device->upload(poolBuffer, pool.data(), pool.size() * 4);
        Buffer slotBuffer = device->create_buffer(gpuSlots.size() * sizeof(gpu::GpuTextureSlot), MemoryUse::Device);
        device->upload(slotBuffer, gpuSlots.data(), gpuSlots.size() * sizeof(gpu::GpuTextureSlot));
        Buffer probeBuffer = device->create_buffer(probes.size() * sizeof(Probe), MemoryUse::Device);
        device->upload(probeBuffer, probes.data(), probes.size() * sizeof(Probe));
        Buffer results = device->create_buffer(probes.size() * 16, MemoryUse::Readback);

        VkDevice vk = device->handle();
        VkPushConstantRange range{VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(ProbePush)};
        VkPipelineLayoutCreateInfo layoutInfo{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
        layoutInfo.pushConstantRangeCount = 1;
        layoutInfo.pPushConstantRanges = &range;
        VkPipelineLayout layout;
        check_vk(vkCreatePipelineLayout(vk, &layoutInfo, nullptr, &layout), "vkCreatePipelineLayout");
        VkShaderModuleCreateInfo moduleInfo{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
        moduleInfo.codeSize = sizeof(texture_probe_comp);
        moduleInfo.pCode = texture_probe_comp;
        VkShaderModule module;
        check_vk(vkCreateShaderModule(vk, &moduleInfo, nullptr, &module), "vkCreateShaderModule");
        VkComputePipelineCreateInfo info{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
        info.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO, nullptr, 0, VK_SHADER_STAGE_COMPUTE_BIT, module, "main"};
        info.layout = layout;
        VkPipeline pipeline;
        check_vk(vkCreateComputePipelines(vk, VK_NULL_HANDLE, 1, &info, nullptr, &pipeline), "vkCreateComputePipelines");

        const ProbePush push{poolBuffer.address, slotBuffer.address, probeBuffer.address, results.address, uint32_t(probes.size())};
        device->run([&](VkCommandBuffer cmd) {
            vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline);
            vkCmdPushConstants(cmd, layout, VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(push), &push);
            vkCmdDispatch(cmd, uint32_t((probes.size() + 63) / 64), 1, 1);
            VkMemoryBarrier2 barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER_2};
            barrier.srcStageMask = VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT;
            barrier.srcAccessMask = VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT;
            barrier.dstStageMask = VK_PIPELINE_STAGE_2_HOST_BIT;
            barrier.dstAccessMask = VK_ACCESS_2_HOST_READ_BIT;
            VkDependencyInfo dependency{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
            dependency.memoryBarrierCount = 1;
            dependency.pMemoryBarriers = &barrier;
            vkCmdPipelineBarrier2(cmd, &dependency);
        });
        std::vector<std::array<float, 4>> out(probes.size());
        std::memcpy(out.data(), results.mapped, probes.size() * 16);
        vkDestroyPipeline(vk, pipeline, nullptr);
        vkDestroyShaderModule(vk, module, nullptr);
        vkDestroyPipelineLayout(vk, layout, nullptr);
        return out;
    }
};

TextureImage random_texture(std::mt19937& rng, uint32_t width, uint32_t height, uint32_t channels, bool eightBit, ColorSpace colorSpace) {
    std::vector<uint8_t> bytes(size_t(width) * height * channels);
    std::vector<float> floats(bytes.size());
    std::uniform_int_distribution<int> byte(0, 255);
    std::uniform_real_distribution<float> value(-0.5f, 4.0f);
    for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = uint8_t(byte(rng)), floats[i] = value(rng);
    return make_texture(width, height, channels, eightBit ? bytes.data() : nullptr, eightBit ? nullptr : floats.data(), colorSpace);
}

std::string temp_path(const std::string& name) {
    const auto dir = std::filesystem::temp_directory_path() / ("tessera-textures-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    return (dir / name).string();
}

void write_png(const std::string& path, uint32_t width, uint32_t height, int channels, const std::vector<uint8_t>& bytes) {
    auto out = OIIO::ImageOutput::create(path);
    ASSERT_TRUE(out) << OIIO::geterror();
    OIIO::ImageSpec spec(int(width), int(height), channels, OIIO::TypeDesc::UINT8);
    ASSERT_TRUE(out->open(path, spec)) << out->geterror();
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, bytes.data())) << out->geterror();
    ASSERT_TRUE(out->close());
}

}  // namespace

// ---- Mip chains ----

TEST(Textures, LevelsHalveDownTo1x1AndRowsAreStoredBottomFirst) {
    // 5x2 RGB, top row red, bottom row blue (8-bit, raw).
    std::vector<uint8_t> pixels;
    for (int y = 0; y < 2; ++y)
        for (int x = 0; x < 5; ++x) pixels.insert(pixels.end(), {uint8_t(y == 0 ? 255 : 0), 0, uint8_t(y == 0 ? 0 : 255)});
    const TextureImage t = make_texture(5, 2, 3, pixels.data(), nullptr, ColorSpace::Raw);
    EXPECT_EQ(t.levels, 3u);  // 5x2, 2x1, 1x1
    EXPECT_EQ(t.format, uint32_t(TS_TEXTURE_RGBA8));
    EXPECT_EQ(t.words.size(), 10u + 2u + 1u);
    EXPECT_EQ(byte_of(t, 0, 2), 255u) << "row 0 is the image's bottom row (st's origin is at the bottom left)";
    EXPECT_EQ(byte_of(t, 0, 0), 0u);
    EXPECT_EQ(byte_of(t, 5, 0), 255u);
    EXPECT_EQ(byte_of(t, 0, 3), 255u) << "three channels read with opaque alpha";
    // Level 1 (2x1) averages 2.5 columns by 2 rows: half red, half blue; the 1x1 level too.
    for (size_t texel : {10u, 11u, 12u}) {
        EXPECT_EQ(byte_of(t, texel, 0), 128u);
        EXPECT_EQ(byte_of(t, texel, 2), 128u);
    }
}

TEST(Textures, OddSizesAverageTheWholeFootprint) {
    // 3x1 single channel 0, 90, 255: the 1x1 level is their mean (a 2-texel box would drop one of them).
    const uint8_t pixels[] = {0, 90, 255};
    const TextureImage t = make_texture(3, 1, 1, pixels, nullptr, ColorSpace::Auto);
    EXPECT_EQ(t.format, uint32_t(TS_TEXTURE_R8)) << "8-bit single channel: one byte per texel, raw under auto";
    ASSERT_EQ(t.levels, 2u);
    EXPECT_EQ(t.words[0], 0u | 90u << 8 | 255u << 16);
    EXPECT_EQ(t.words[1], 115u);
}

TEST(Textures, SrgbLevelsAreFilteredInLinearLight) {
    // Black and white, 8-bit RGB under auto: sRGB. Their mean in linear light is 0.5, stored encoded (188), not the
    // encoded mean (128), which would darken every distant view of the texture.
    const uint8_t pixels[] = {0, 0, 0, 255, 255, 255};
    const TextureImage srgb = make_texture(2, 1, 3, pixels, nullptr, ColorSpace::Auto);
    EXPECT_EQ(srgb.format, uint32_t(TS_TEXTURE_RGBA8 | TS_TEXTURE_SRGB));
    EXPECT_EQ(byte_of(srgb, 2, 0), uint32_t(std::lround(srgb_encode(0.5) * 255)));
    EXPECT_EQ(byte_of(srgb, 2, 3), 255u) << "alpha is never sRGB";
    const TextureImage raw = make_texture(2, 1, 3, pixels, nullptr, ColorSpace::Raw);
    EXPECT_EQ(raw.format, uint32_t(TS_TEXTURE_RGBA8));
    EXPECT_EQ(byte_of(raw, 2, 0), 128u);
}

TEST(Textures, FloatImagesAreHalfAndDecodedAtLoadWhenSrgb) {
    const float pixels[] = {0.5f, 2.0f, 1e6f, NAN};  // two texels, grey + alpha
    const TextureImage t = make_texture(2, 1, 2, nullptr, pixels, ColorSpace::Raw);
    EXPECT_EQ(t.format, uint32_t(TS_TEXTURE_RGBA16F));
    auto channel = [&](size_t texel, int c) { return half_value(t.words[2 * texel + c / 2] >> (16 * (c % 2)) & 0xffffu); };
    EXPECT_EQ(channel(0, 0), 0.5);
    EXPECT_EQ(channel(0, 2), 0.5) << "two channels: grey in r, g and b";
    EXPECT_EQ(channel(0, 3), 2.0) << "and alpha in a";
    EXPECT_EQ(channel(1, 0), 65504.0) << "beyond the half range clamps";
    EXPECT_EQ(channel(1, 3), 0.0) << "NaN reads as 0";
    const float grey[] = {0.5f};
    const TextureImage decoded = make_texture(1, 1, 1, nullptr, grey, ColorSpace::Srgb);
    EXPECT_EQ(decoded.format, uint32_t(TS_TEXTURE_RGBA16F)) << "float data is decoded once, at load";
    EXPECT_NEAR(half_value(decoded.words[0] & 0xffffu), srgb_decode(0.5), 1e-3);
}

TEST(Textures, Transform2dScalesThenRotatesThenTranslates) {
    const auto m = transform2d(90.0f, {2.0f, 3.0f}, {0.25f, 0.5f});
    // (1, 0) -> scale (2, 0) -> rotate 90 degrees counter-clockwise (0, 2) -> translate (0.25, 2.5).
    EXPECT_NEAR(m[0] * 1 + m[1] * 0 + m[2], 0.25, 1e-6);
    EXPECT_NEAR(m[3] * 1 + m[4] * 0 + m[5], 2.5, 1e-6);
    // (0, 1) -> (0, 3) -> (-3, 0) -> (-2.75, 0.5).
    EXPECT_NEAR(m[0] * 0 + m[1] * 1 + m[2], -2.75, 1e-6);
    EXPECT_NEAR(m[3] * 0 + m[4] * 1 + m[5], 0.5, 1e-6);
}

// ---- Files ----

// slot_range must hold every value a bilinear level-0 read returns anywhere in the rectangle (whatever the wrap mode,
// transform, scale and bias), and stay within the texels around the rectangle where it can (clamp, no transform).
TEST(Textures, SlotRangeHoldsEveryReadOverTheRectangleAndLittleMore) {
    std::mt19937 random(7);
    std::uniform_real_distribution<float> unit(0.0f, 1.0f);
    for (const auto [width, height] : {std::array<uint32_t, 2>{37, 23}, std::array<uint32_t, 2>{1500, 700}}) {
        // Smooth structure plus noise, so that ranges differ from place to place.
        std::vector<uint8_t> pixels(size_t(width) * height * 3);
        for (uint32_t y = 0; y < height; ++y)
            for (uint32_t x = 0; x < width; ++x) {
                const double smooth = 0.5 + 0.4 * std::sin(6.0 * x / width) * std::cos(4.0 * y / height);
                for (int c = 0; c < 3; ++c)
                    pixels[(size_t(y) * width + x) * 3 + c] = uint8_t(std::clamp(smooth * 255 + (c ? 60.0 : 20.0) * (unit(random) - 0.5), 0.0, 255.0));
            }
        auto image = std::make_shared<TextureImage>(make_texture(width, height, 3, pixels.data(), nullptr, ColorSpace::Raw));
        for (uint32_t channel : {0u, 1u}) {
            const TextureRange range(*image, channel);
            for (int trial = 0; trial < 400; ++trial) {
                TextureSlot slot;
                slot.input = MaterialInput::Displacement;
                slot.image = image;
                slot.channel = channel ? TextureChannel::G : TextureChannel::R;
                const int mode = trial % 4;
                slot.wrapS = TextureWrap(mode);
                slot.wrapT = TextureWrap((trial / 4) % 4);
                const bool plain = trial % 3 == 0;  // no transform, scale or bias
                if (!plain) {
                    slot.transform = transform2d(360 * unit(random), {0.3f + 3 * unit(random), 0.3f + 3 * unit(random)}, {unit(random) - 0.5f, unit(random) - 0.5f});
                    slot.scale[channel] = 4 * unit(random) - 2;
                    slot.bias[channel] = unit(random) - 0.5f;
                }
                const float size = trial % 5 == 0 ? 1.5f * unit(random) : 0.1f * unit(random) * unit(random);
                const std::array<float, 2> lo{3 * unit(random) - 1, 3 * unit(random) - 1};
                const std::array<float, 2> hi{lo[0] + size * unit(random), lo[1] + size * unit(random)};
                const auto r = slot_range(slot, range, lo, hi);
                for (int k = 0; k < 64; ++k) {
                    const float s = k == 0 ? lo[0] : k == 1 ? hi[0] : lo[0] + (hi[0] - lo[0]) * unit(random);
                    const float t = k == 0 ? lo[1] : k == 1 ? hi[1] : lo[1] + (hi[1] - lo[1]) * unit(random);
                    const float value = sample_slot_level0(slot, s, t);
                    ASSERT_GE(value, r[0] - 1e-5f) << "trial " << trial << " at (" << s << ", " << t << ")";
                    ASSERT_LE(value, r[1] + 1e-5f) << "trial " << trial << " at (" << s << ", " << t << ")";
                }
                if (plain && slot.wrapS == TextureWrap::Clamp && slot.wrapT == TextureWrap::Clamp) {
                    // Tight: within the texels bilinear reads touch, widened by the margin (2 texels), a pyramid block
                    // and the pyramid's reach (its entries are square: under the rectangle's larger side, each way).
                    auto clamped = [](int i, uint32_t n) { return std::clamp(i, 0, int(n) - 1); };
                    const int x0 = clamped(int(std::floor(lo[0] * width - 0.5)) - 2, width), x1 = clamped(int(std::floor(hi[0] * width - 0.5)) + 3, width);
                    const int y0 = clamped(int(std::floor(lo[1] * height - 0.5)) - 2, height), y1 = clamped(int(std::floor(hi[1] * height - 0.5)) + 3, height);
                    const int reach = std::max(x1 - x0, y1 - y0) + 1 + int(range.block());
                    const std::array<int, 2> xs{clamped(x0 - reach, width), clamped(x1 + reach, width)};
                    const std::array<int, 2> ys{clamped(y0 - reach, height), clamped(y1 + reach, height)};
                    float low = INFINITY, high = -INFINITY;
                    for (int y = ys[0]; y <= ys[1]; ++y)
                        for (int x = xs[0]; x <= xs[1]; ++x) {
                            // Rows are stored bottom first: texel row y of the image is file row height - 1 - y.
                            const float v = pixels[(size_t(height - 1 - y) * width + x) * 3 + channel] / 255.0f;
                            low = std::min(low, v), high = std::max(high, v);
                        }
                    EXPECT_GE(r[0], low - 1e-6f) << "trial " << trial;
                    EXPECT_LE(r[1], high + 1e-6f) << "trial " << trial;
                }
            }
        }
    }
}

TEST(Textures, FilesAreReadSharedAndReadAgainWhenTheyChange) {
    const std::string path = temp_path("checker.png");
    std::vector<uint8_t> rgba = {255, 0, 0, 255, 0, 255, 0, 128, 0, 0, 255, 255, 255, 255, 255, 0};
    write_png(path, 2, 2, 4, rgba);
    TextureStore store;
    auto a = store.load(path, ColorSpace::Auto);
    EXPECT_EQ(a->width, 2u);
    EXPECT_EQ(a->channels, 4u);
    EXPECT_EQ(a->format, uint32_t(TS_TEXTURE_RGBA8 | TS_TEXTURE_SRGB));
    EXPECT_EQ(a->words[0], 0xffff0000u) << "bottom-left texel is the file's third pixel (blue)";
    EXPECT_EQ(a->words[1], 0x00ffffffu) << "straight alpha: a white texel with alpha 0 keeps its colour";
    auto b = store.load(path, ColorSpace::Auto);
    EXPECT_EQ(a.get(), b.get()) << "one file, one colour space: one image";
    EXPECT_EQ(store.files_read(), 1u);
    auto raw = store.load(path, ColorSpace::Raw);
    EXPECT_NE(raw.get(), a.get());
    EXPECT_EQ(raw->format, uint32_t(TS_TEXTURE_RGBA8));
    EXPECT_EQ(store.files_read(), 2u);

    std::filesystem::last_write_time(path, std::filesystem::last_write_time(path) - std::chrono::hours(1));
    write_png(path, 4, 4, 4, std::vector<uint8_t>(64, 7));
    auto changed = store.load(path, ColorSpace::Auto);
    EXPECT_EQ(changed->width, 4u) << "a file changed on disk is read again";

    a.reset(), b.reset(), changed.reset();
    store.load(path, ColorSpace::Auto);
    EXPECT_EQ(store.files_read(), 4u) << "an image nobody holds is not kept";
}

TEST(Textures, UnreadableFilesLeaveTheSlotEmptyWithAWarningNamingFileAndMaterial) {
    const std::string garbage = temp_path("garbage.png");
    std::ofstream(garbage) << "not an image";
    TextureStore store;
    std::vector<TextureSlot> slots(3);
    slots[0].file = temp_path("missing.png");
    slots[1].file = garbage;
    slots[1].input = MaterialInput::Roughness;
    slots[2].file = temp_path("ok.png");
    write_png(slots[2].file, 1, 1, 3, {1, 2, 3});
    std::vector<std::string> warnings;
    store.load_slots(slots, "/Looks/Wood", warnings);
    EXPECT_FALSE(slots[0].image);
    EXPECT_FALSE(slots[1].image);
    EXPECT_TRUE(slots[2].image);
    ASSERT_EQ(warnings.size(), 2u);
    EXPECT_NE(warnings[0].find("/Looks/Wood"), std::string::npos) << warnings[0];
    EXPECT_NE(warnings[0].find("missing.png"), std::string::npos) << warnings[0];
    EXPECT_NE(warnings[0].find("no such file"), std::string::npos) << warnings[0];
    EXPECT_NE(warnings[1].find("garbage.png"), std::string::npos) << warnings[1];
    EXPECT_NE(warnings[1].find("roughness"), std::string::npos) << warnings[1];
}

// ---- Sampling on the device ----

TEST_F(TextureSamplingTest, DeviceSamplingMatchesTheReference) {
    std::mt19937 rng(1234);
    // Every format, sRGB and raw, sizes that are not powers of two (odd levels on the way down).
    std::vector<TextureImage> textures;
    textures.push_back(random_texture(rng, 37, 23, 3, true, ColorSpace::Auto));  // RGBA8, sRGB
    textures.push_back(random_texture(rng, 16, 16, 4, true, ColorSpace::Raw));   // RGBA8, raw
    textures.push_back(random_texture(rng, 19, 40, 1, true, ColorSpace::Auto));  // R8
    textures.push_back(random_texture(rng, 8, 5, 4, false, ColorSpace::Raw));    // RGBA16F
    textures.push_back(random_texture(rng, 1, 1, 2, true, ColorSpace::Srgb));    // 1x1, grey + alpha, sRGB
    std::vector<const TextureImage*> images;
    for (const auto& t : textures) images.push_back(&t);

    std::vector<TextureSlot> slots;
    std::vector<uint32_t> slotImages;
    std::uniform_real_distribution<float> unit(0.0f, 1.0f);
    for (uint32_t image = 0; image < textures.size(); ++image)
        for (int wrap = 0; wrap < 16; ++wrap) {
            TextureSlot slot;
            slot.wrapS = TextureWrap(wrap & 3);
            slot.wrapT = TextureWrap(wrap >> 2);
            slot.channel = TextureChannel(wrap % 5);
            slot.scale = {0.5f + unit(rng), 2.0f * unit(rng), -1.0f, 1.0f};
            slot.bias = {unit(rng) - 0.5f, 0.0f, 1.0f, 0.25f};
            slot.transform = wrap < 4 ? std::array<float, 6>{1, 0, 0, 0, 1, 0}
                                      : transform2d(360.0f * unit(rng), {0.5f + 2 * unit(rng), 0.5f + 2 * unit(rng)}, {unit(rng), -unit(rng)});
            slots.push_back(slot);
            slotImages.push_back(image);
        }

    std::vector<Probe> probes;
    std::uniform_real_distribution<float> st(-2.5f, 2.5f), angle(0.0f, 6.2831853f), exponent(-4.5f, 0.5f);
    for (int i = 0; i < 8192; ++i) {
        Probe p{};
        p.st[0] = st(rng), p.st[1] = st(rng);
        const float lengthX = i % 17 == 0 ? 0.0f : std::pow(10.0f, exponent(rng)), lengthY = std::pow(10.0f, exponent(rng));
        const float a = angle(rng), b = angle(rng);
        p.dx[0] = lengthX * std::cos(a), p.dx[1] = lengthX * std::sin(a);
        p.dy[0] = lengthY * std::cos(b), p.dy[1] = lengthY * std::sin(b);
        p.slot = uint32_t(rng() % slots.size());
        probes.push_back(p);
    }
    const auto gpu = sample_on_device(images, slots, slotImages, probes);

    double worst = 0;
    size_t worstProbe = 0;
    for (size_t i = 0; i < probes.size(); ++i) {
        const Probe& p = probes[i];
        const double st2[2] = {p.st[0], p.st[1]}, dx[2] = {p.dx[0], p.dx[1]}, dy[2] = {p.dy[0], p.dy[1]};
        const Rgba expected = reference_slot(*images[slotImages[p.slot]], slots[p.slot], st2, dx, dy);
        for (int c = 0; c < 4; ++c) {
            const double error = std::abs(expected[c] - gpu[i][c]) / std::max(1.0, std::abs(expected[c]));
            if (error > worst) worst = error, worstProbe = i;
        }
    }
    const Probe& w = probes[worstProbe];
    EXPECT_LT(worst, 1e-4) << "probe " << worstProbe << " at st (" << w.st[0] << ", " << w.st[1] << "), slot " << w.slot;
}

TEST_F(TextureSamplingTest, WrapModesAndTexelCentresOnTheDevice) {
    // A 4x2 raw RGBA8 ramp: texel (x, y) stores red 40 * x + 100 * y (rows bottom first after the flip).
    std::vector<uint8_t> pixels;
    for (int fileRow = 0; fileRow < 2; ++fileRow)
        for (int x = 0; x < 4; ++x) pixels.insert(pixels.end(), {uint8_t(40 * x + 100 * (1 - fileRow)), 0, 0, 255});
    const TextureImage t = make_texture(4, 2, 4, pixels.data(), nullptr, ColorSpace::Raw);
    std::vector<TextureSlot> slots(4);
    for (int m = 0; m < 4; ++m) slots[m].wrapS = slots[m].wrapT = TextureWrap(m), slots[m].channel = TextureChannel::R;
    auto probe = [](float s, float t, uint32_t slot) {
        Probe p{};
        p.st[0] = s, p.st[1] = t, p.slot = slot;
        return p;
    };
    const float centre = 0.375f, top = 0.75f;  // texel x = 1, y = 1 centre
    const std::vector<Probe> probes = {
        probe(centre, top, 0),          // 0: exact texel (1, 1): 140
        probe(centre + 3, top - 2, 0),  // 1: repeat: the same
        probe(-centre, top, 1),         // 2: mirror at 0: texel (1, 1) again
        probe(2 - centre, top, 1),      // 3: mirror at 1: texel (2, 1) mirrored back to (1, 1)
        probe(7.0f, top, 2),            // 4: clamp: the right edge texel (3, 1): 220
        probe(7.0f, top, 3),            // 5: black outside
        probe(0.5f, top, 0),            // 6: halfway between texels 1 and 2: (140 + 180) / 2
        probe(0.0f, top, 0),            // 7: repeat across the left edge: (texel 3 + texel 0) / 2 = (220 + 100) / 2
    };
    const auto out = sample_on_device({&t}, slots, {0, 0, 0, 0}, probes);
    const double expected[] = {140, 140, 140, 140, 220, 0, 160, 160};
    for (size_t i = 0; i < probes.size(); ++i) EXPECT_NEAR(out[i][0] * 255.0, expected[i], 1e-3) << "probe " << i;
}
