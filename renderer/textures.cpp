// Textures: image files to mip chains in the GPU pool's formats (shared.h TS_TEXTURE_*), shared between materials.
#include "tessera/textures.h"

#include "shared.h"
#include "tessera/builder.h"  // half_to_float

#include "image_files.h"
#include "tessera/image_io.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>

namespace tessera {

static_assert(int(MaterialInput::DiffuseColor) == TS_INPUT_DIFFUSE_COLOR && int(MaterialInput::EmissiveColor) == TS_INPUT_EMISSIVE_COLOR &&
                  int(MaterialInput::SpecularColor) == TS_INPUT_SPECULAR_COLOR && int(MaterialInput::Metallic) == TS_INPUT_METALLIC &&
                  int(MaterialInput::Roughness) == TS_INPUT_ROUGHNESS && int(MaterialInput::Opacity) == TS_INPUT_OPACITY &&
                  int(MaterialInput::Occlusion) == TS_INPUT_OCCLUSION && int(MaterialInput::Normal) == TS_INPUT_NORMAL &&
                  int(MaterialInput::Displacement) == TS_INPUT_DISPLACEMENT,
              "MaterialInput must follow the TS_INPUT_* bits");
static_assert(int(TextureWrap::Repeat) == TS_WRAP_REPEAT && int(TextureWrap::Mirror) == TS_WRAP_MIRROR &&
                  int(TextureWrap::Clamp) == TS_WRAP_CLAMP && int(TextureWrap::Black) == TS_WRAP_BLACK,
              "TextureWrap must follow TS_WRAP_*");
static_assert(int(TextureChannel::R) == TS_CHANNEL_R && int(TextureChannel::A) == TS_CHANNEL_A && int(TextureChannel::Rgb) == TS_CHANNEL_RGB,
              "TextureChannel must follow TS_CHANNEL_*");

const char* material_input_name(MaterialInput input) {
    switch (input) {
        case MaterialInput::DiffuseColor: return "diffuseColor";
        case MaterialInput::EmissiveColor: return "emissiveColor";
        case MaterialInput::SpecularColor: return "specularColor";
        case MaterialInput::Metallic: return "metallic";
        case MaterialInput::Roughness: return "roughness";
        case MaterialInput::Opacity: return "opacity";
        case MaterialInput::Occlusion: return "occlusion";
        case MaterialInput::Normal: return "normal";
        case MaterialInput::Displacement: return "displacement";
    }
    return "?";
}

const char* texture_format_name(uint32_t format) {
    const bool srgb = (format & TS_TEXTURE_SRGB) != 0;
    switch (format & TS_TEXTURE_FORMAT_MASK) {
        case TS_TEXTURE_RGBA8: return srgb ? "rgba8 srgb" : "rgba8";
        case TS_TEXTURE_R8: return srgb ? "r8 srgb" : "r8";
        default: return "rgba16f";
    }
}

std::array<float, 6> transform2d(float rotationDegrees, std::array<float, 2> scale, std::array<float, 2> translation) {
    const double radians = double(rotationDegrees) * 3.14159265358979323846 / 180.0;
    const double c = std::cos(radians), s = std::sin(radians);
    return {float(c * scale[0]), float(-s * scale[1]), translation[0], float(s * scale[0]), float(c * scale[1]), translation[1]};
}

namespace {

constexpr uint32_t kMaxTextureSize = 16384;

float srgb_to_linear(float c) { return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f); }
float linear_to_srgb(float c) { return c <= 0.0031308f ? c * 12.92f : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f; }

uint32_t to_byte(float v) { return uint32_t(std::lround(std::clamp(v, 0.0f, 1.0f) * 255.0f)); }

// IEEE half from float, rounding to nearest even; beyond the half range clamps to +-65504, NaN reads as 0 (a texture
// of NaNs would poison every filtered sample near it).
uint16_t float_to_half(float value) {
    if (std::isnan(value)) return 0;
    value = std::clamp(value, -65504.0f, 65504.0f);
    uint32_t bits;
    std::memcpy(&bits, &value, 4);
    const uint32_t sign = (bits >> 16) & 0x8000u;
    const uint32_t magnitude = bits & 0x7fffffffu;
    if (magnitude < 0x38800000u) {  // below the smallest normal half: a subnormal (or zero)
        if (magnitude < 0x33000000u) return uint16_t(sign);  // rounds to zero
        const uint32_t exponent = magnitude >> 23, mantissa = (magnitude & 0x7fffffu) | 0x800000u;
        const uint32_t shift = 126 - exponent;  // 14 - (exponent - 127) + 13 - 1 ... into 10 bits
        uint32_t half = mantissa >> shift;
        const uint32_t rest = mantissa & ((1u << shift) - 1), halfway = 1u << (shift - 1);
        if (rest > halfway || (rest == halfway && (half & 1u))) ++half;
        return uint16_t(sign | half);
    }
    uint32_t half = ((magnitude - 0x38000000u) >> 13);
    const uint32_t rest = magnitude & 0x1fffu;
    if (rest > 0x1000u || (rest == 0x1000u && (half & 1u))) ++half;
    return uint16_t(sign | half);
}


uint32_t level_words(uint32_t format, uint32_t width, uint32_t height) {
    const uint64_t texels = uint64_t(width) * height;
    return uint32_t(format == TS_TEXTURE_R8 ? (texels + 3) / 4 : format == TS_TEXTURE_RGBA16F ? 2 * texels : texels);
}

// Box filter weights from `source` texels down to `target` (= max(1, source / 2)): each target texel averages the
// source interval it covers, fractions of texels at its ends included (odd sizes).
std::vector<std::vector<std::pair<uint32_t, float>>> box_weights(uint32_t source, uint32_t target) {
    std::vector<std::vector<std::pair<uint32_t, float>>> weights(target);
    const double ratio = double(source) / target;
    for (uint32_t i = 0; i < target; ++i) {
        const double lo = i * ratio, hi = (i + 1) * ratio;
        for (uint32_t s = uint32_t(lo); s < source && s < hi; ++s) {
            const double covered = std::min(hi, double(s) + 1) - std::max(lo, double(s));
            if (covered > 1e-9) weights[i].push_back({s, float(covered / ratio)});
        }
    }
    return weights;
}

// Linear RGBA of one row of a stored level (decoding sRGB and the storage format).
void decode_row(const TextureImage& t, uint32_t offset, uint32_t width, uint32_t row, float* rgba) {
    const uint32_t format = t.format & TS_TEXTURE_FORMAT_MASK;
    const bool srgb = (t.format & TS_TEXTURE_SRGB) != 0;
    for (uint32_t x = 0; x < width; ++x) {
        const uint64_t i = uint64_t(row) * width + x;
        float* v = rgba + 4 * x;
        if (format == TS_TEXTURE_RGBA8) {
            const uint32_t w = t.words[offset + i];
            for (int c = 0; c < 4; ++c) v[c] = float((w >> (8 * c)) & 0xffu) / 255.0f;
        } else if (format == TS_TEXTURE_R8) {
            const uint32_t byte = (t.words[offset + i / 4] >> (8 * (i % 4))) & 0xffu;
            v[0] = v[1] = v[2] = float(byte) / 255.0f;
            v[3] = 1.0f;
        } else {
            const uint32_t a = t.words[offset + 2 * i], b = t.words[offset + 2 * i + 1];
            v[0] = half_to_float(uint16_t(a)), v[1] = half_to_float(uint16_t(a >> 16));
            v[2] = half_to_float(uint16_t(b)), v[3] = half_to_float(uint16_t(b >> 16));
        }
        if (srgb)
            for (int c = 0; c < 3; ++c) v[c] = srgb_to_linear(v[c]);
    }
}

// Stores linear RGBA texels (a whole level) in the texture's format at `offset`.
void encode_level(TextureImage& t, uint32_t offset, const std::vector<float>& rgba) {
    const uint32_t format = t.format & TS_TEXTURE_FORMAT_MASK;
    const bool srgb = (t.format & TS_TEXTURE_SRGB) != 0;
    const size_t texels = rgba.size() / 4;
    auto channel = [&](size_t i, int c) { return srgb && c < 3 ? linear_to_srgb(rgba[4 * i + c]) : rgba[4 * i + c]; };
    for (size_t i = 0; i < texels; ++i) {
        if (format == TS_TEXTURE_RGBA8) {
            t.words[offset + i] = to_byte(channel(i, 0)) | to_byte(channel(i, 1)) << 8 | to_byte(channel(i, 2)) << 16 | to_byte(channel(i, 3)) << 24;
        } else if (format == TS_TEXTURE_R8) {
            t.words[offset + i / 4] |= to_byte(channel(i, 0)) << (8 * (i % 4));
        } else {
            t.words[offset + 2 * i] = uint32_t(float_to_half(rgba[4 * i])) | uint32_t(float_to_half(rgba[4 * i + 1])) << 16;
            t.words[offset + 2 * i + 1] = uint32_t(float_to_half(rgba[4 * i + 2])) | uint32_t(float_to_half(rgba[4 * i + 3])) << 16;
        }
    }
}

// Level l + 1 from level l (linear RGBA rows from `row`), box-filtered in both directions.
std::vector<float> downsample(uint32_t width, uint32_t height, const std::function<void(uint32_t, float*)>& row) {
    const uint32_t w = std::max(1u, width / 2), h = std::max(1u, height / 2);
    const auto wx = box_weights(width, w), wy = box_weights(height, h);
    std::vector<float> out(size_t(w) * h * 4, 0.0f), source(size_t(width) * 4), filtered(size_t(w) * 4);
    for (uint32_t y = 0; y < h; ++y)
        for (const auto& [sy, weightY] : wy[y]) {
            row(sy, source.data());
            for (uint32_t x = 0; x < w; ++x) {
                float sum[4] = {0, 0, 0, 0};
                for (const auto& [sx, weightX] : wx[x])
                    for (int c = 0; c < 4; ++c) sum[c] += weightX * source[4 * sx + c];
                for (int c = 0; c < 4; ++c) out[(size_t(y) * w + x) * 4 + c] += weightY * sum[c];
            }
        }
    return out;
}

}  // namespace

TextureImage make_texture(uint32_t width, uint32_t height, uint32_t channels, const uint8_t* bytes, const float* floats,
                          ColorSpace colorSpace, std::string path) {
    if (width == 0 || height == 0 || width > kMaxTextureSize || height > kMaxTextureSize)
        throw TextureError(std::to_string(width) + "x" + std::to_string(height) + " pixels (textures are 1 to 16384 pixels on a side)");
    if (channels < 1 || channels > 4) throw TextureError(std::to_string(channels) + " channels (1 to 4 are read)");
    if (!bytes == !floats) throw std::invalid_argument("make_texture takes 8-bit or float pixels, not both");
    const bool eightBit = bytes != nullptr;
    const bool srgb = colorSpace == ColorSpace::Srgb || (colorSpace == ColorSpace::Auto && eightBit && channels >= 3);

    TextureImage t;
    t.path = std::move(path);
    t.width = width;
    t.height = height;
    t.channels = channels;
    t.levels = 1;
    while ((std::max(width, height) >> t.levels) > 0) ++t.levels;
    const uint32_t format = eightBit ? (channels == 1 ? TS_TEXTURE_R8 : TS_TEXTURE_RGBA8) : TS_TEXTURE_RGBA16F;
    // 8-bit sRGB stays encoded (8 bits of linear would band in the darks); float data is decoded here, once.
    t.format = format | (eightBit && srgb ? TS_TEXTURE_SRGB : 0u);
    std::vector<uint32_t> offsets;
    uint64_t total = 0;
    for (uint32_t l = 0; l < t.levels; ++l) {
        offsets.push_back(uint32_t(total));
        total += level_words(format, std::max(1u, width >> l), std::max(1u, height >> l));
    }
    t.words.assign(total, 0u);

    // Level 0: the file's channels as RGBA (one channel: r r r 1; two: l l l a; three: r g b 1), bottom row first.
    auto source = [&](uint32_t x, uint32_t fileRow, uint32_t c) {
        const size_t i = (size_t(fileRow) * width + x) * channels + c;
        return eightBit ? float(bytes[i]) : floats[i];
    };
    auto rgba = [&](uint32_t x, uint32_t fileRow, float v[4]) {
        for (uint32_t c = 0; c < 4; ++c) {
            const uint32_t from = channels == 1 ? (c < 3 ? 0 : 4) : channels == 2 ? (c < 3 ? 0 : 1) : (c < channels ? c : 4);
            v[c] = from < channels ? source(x, fileRow, from) : (eightBit ? 255.0f : 1.0f);
        }
    };
    // Level 0 as linear RGBA, row by row: the stored bytes decoded (8-bit), or the source floats (no full float copy
    // of a large image is ever made: at 4K that would be 256 MiB).
    auto level0_row = [&](uint32_t y, float* out) {
        if (eightBit) {
            decode_row(t, offsets[0], width, y, out);
            return;
        }
        for (uint32_t x = 0; x < width; ++x) {
            rgba(x, height - 1 - y, out + 4 * x);
            if (srgb)
                for (int c = 0; c < 3; ++c) out[4 * x + c] = srgb_to_linear(out[4 * x + c]);
        }
    };
    if (eightBit) {  // the file's bytes as they are
        for (uint32_t y = 0; y < height; ++y)
            for (uint32_t x = 0; x < width; ++x) {
                float v[4];
                rgba(x, height - 1 - y, v);
                const size_t i = size_t(y) * width + x;
                if (format == TS_TEXTURE_R8) t.words[i / 4] |= uint32_t(v[0]) << (8 * (i % 4));
                else t.words[i] = uint32_t(v[0]) | uint32_t(v[1]) << 8 | uint32_t(v[2]) << 16 | uint32_t(v[3]) << 24;
            }
    } else {
        std::vector<float> row(size_t(width) * 4);
        for (uint32_t y = 0; y < height; ++y) {
            level0_row(y, row.data());
            encode_level(t, uint32_t(2 * size_t(y) * width), row);  // RGBA16F: two words per texel
        }
    }

    // Level 0's range per channel, as the shader reads it (linear): bounds what a displacement texture can move.
    t.minValue = {INFINITY, INFINITY, INFINITY, INFINITY};
    t.maxValue = {-INFINITY, -INFINITY, -INFINITY, -INFINITY};
    {
        std::vector<float> row(size_t(width) * 4);
        for (uint32_t y = 0; y < height; ++y) {
            decode_row(t, offsets[0], width, y, row.data());
            for (uint32_t x = 0; x < width; ++x)
                for (int c = 0; c < 4; ++c) {
                    t.minValue[c] = std::min(t.minValue[c], row[4 * x + c]);
                    t.maxValue[c] = std::max(t.maxValue[c], row[4 * x + c]);
                }
        }
    }

    // Each level from the one above it, in linear light and unrounded (rounding once per level, not once per level
    // above it): level 1 from level 0's rows, the others from the float level above.
    std::vector<float> above;
    for (uint32_t l = 1; l < t.levels; ++l) {
        const uint32_t w = std::max(1u, width >> (l - 1)), h = std::max(1u, height >> (l - 1));
        std::vector<float> level = l == 1 ? downsample(w, h, level0_row)
                                          : downsample(w, h, [&](uint32_t y, float* out) { std::memcpy(out, &above[size_t(y) * w * 4], size_t(w) * 16); });
        encode_level(t, offsets[l], level);
        above = std::move(level);
    }
    return t;
}

namespace {

// One channel of a level-0 texel inside the image, linear, as shaders/texture.h decodes it.
float level0_texel(const TextureImage& image, size_t channel, uint32_t x, uint32_t y) {
    const uint32_t format = image.format & TS_TEXTURE_FORMAT_MASK;
    const uint64_t i = uint64_t(y) * image.width + uint64_t(x);
    float value;
    if (format == TS_TEXTURE_RGBA8) value = float((image.words[i] >> (8 * channel)) & 0xffu) / 255.0f;
    else if (format == TS_TEXTURE_R8) value = channel == 3 ? 1.0f : float((image.words[i / 4] >> (8 * (i % 4))) & 0xffu) / 255.0f;
    else value = half_to_float(uint16_t(image.words[2 * i + channel / 2] >> (16 * (channel % 2))));
    return (image.format & TS_TEXTURE_SRGB) != 0 && channel < 3 ? srgb_to_linear(value) : value;
}

// A texel coordinate through a wrap mode: inside [0, n), or -1 outside a black border.
int wrap_texel(int i, int n, TextureWrap mode) {
    if (mode == TextureWrap::Clamp) return std::clamp(i, 0, n - 1);
    if (mode == TextureWrap::Black) return i < 0 || i >= n ? -1 : i;
    if (mode == TextureWrap::Mirror) {
        const int m2 = ((i % (2 * n)) + 2 * n) % (2 * n);
        return m2 < n ? m2 : 2 * n - 1 - m2;
    }
    return ((i % n) + n) % n;
}

size_t slot_channel(const TextureSlot& slot) { return slot.channel == TextureChannel::Rgb ? 0 : size_t(slot.channel); }

}  // namespace

float sample_slot_level0(const TextureSlot& slot, float s, float t) {
    const size_t channel = slot_channel(slot);
    if (!slot.image) return slot.fallback[channel];
    const TextureImage& image = *slot.image;
    const auto& m = slot.transform;
    const float u = m[0] * s + m[1] * t + m[2], v = m[3] * s + m[4] * t + m[5];
    auto texel = [&](int x, int y) -> float {
        x = wrap_texel(x, int(image.width), slot.wrapS);
        y = wrap_texel(y, int(image.height), slot.wrapT);
        return x < 0 || y < 0 ? 0.0f : level0_texel(image, channel, uint32_t(x), uint32_t(y));
    };
    const double x = double(u) * image.width - 0.5, y = double(v) * image.height - 0.5;
    const int x0 = int(std::floor(x)), y0 = int(std::floor(y));
    const float fx = float(x - x0), fy = float(y - y0);
    const float a = texel(x0, y0), b = texel(x0 + 1, y0);
    const float c = texel(x0, y0 + 1), d = texel(x0 + 1, y0 + 1);
    const float value = (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy;
    return value * slot.scale[channel] + slot.bias[channel];
}

TextureRange::TextureRange(const TextureImage& image, uint32_t channel) {
    // Blocks small enough to follow a cluster's footprint, few enough that the pyramid stays small (at most 512^2
    // entries at its base, 2.8 MB for any image).
    while ((image.width + block_ - 1) / block_ > 512 || (image.height + block_ - 1) / block_ > 512) block_ *= 2;
    uint32_t w = std::max(1u, (image.width + block_ - 1) / block_), h = std::max(1u, (image.height + block_ - 1) / block_);
    std::vector<std::array<float, 2>> base(size_t(w) * h, {INFINITY, -INFINITY});
    for (uint32_t y = 0; y < image.height; ++y)
        for (uint32_t x = 0; x < image.width; ++x) {
            const float value = level0_texel(image, channel, x, y);
            auto& entry = base[size_t(y / block_) * w + x / block_];
            entry = {std::min(entry[0], value), std::max(entry[1], value)};
        }
    sizes_.push_back({w, h});
    levels_.push_back(std::move(base));
    while (w > 1 || h > 1) {
        const uint32_t pw = w, ph = h;
        w = (w + 1) / 2, h = (h + 1) / 2;
        const auto& below = levels_.back();
        std::vector<std::array<float, 2>> level(size_t(w) * h, {INFINITY, -INFINITY});
        for (uint32_t y = 0; y < ph; ++y)
            for (uint32_t x = 0; x < pw; ++x) {
                auto& entry = level[size_t(y / 2) * w + x / 2];
                const auto& from = below[size_t(y) * pw + x];
                entry = {std::min(entry[0], from[0]), std::max(entry[1], from[1])};
            }
        sizes_.push_back({w, h});
        levels_.push_back(std::move(level));
    }
}

std::array<float, 2> TextureRange::texels(uint32_t x0, uint32_t y0, uint32_t x1, uint32_t y1) const {
    uint32_t bx0 = x0 / block_, by0 = y0 / block_, bx1 = x1 / block_, by1 = y1 / block_;
    size_t l = 0;
    while (l + 1 < levels_.size() && (bx1 - bx0 > 7 || by1 - by0 > 7)) {  // the finest level with at most 8 x 8 entries
        bx0 /= 2, by0 /= 2, bx1 /= 2, by1 /= 2;
        ++l;
    }
    std::array<float, 2> out{INFINITY, -INFINITY};
    const uint32_t w = sizes_[l][0], h = sizes_[l][1];
    for (uint32_t y = by0; y <= std::min(by1, h - 1); ++y)
        for (uint32_t x = bx0; x <= std::min(bx1, w - 1); ++x) {
            const auto& entry = levels_[l][size_t(y) * w + x];
            out = {std::min(out[0], entry[0]), std::max(out[1], entry[1])};
        }
    return out;
}

namespace {

// The texels [a, b] of one axis (any integers: before wrapping), through its wrap mode, as at most three runs inside
// [0, n); `outside` when some fall on a black border.
void wrapped_runs(int64_t a, int64_t b, int64_t n, TextureWrap mode, std::vector<std::array<uint32_t, 2>>& runs, bool& outside) {
    runs.clear();
    auto whole = [&] { runs.push_back({0, uint32_t(n - 1)}); };
    switch (mode) {
        case TextureWrap::Clamp: runs.push_back({uint32_t(std::clamp<int64_t>(a, 0, n - 1)), uint32_t(std::clamp<int64_t>(b, 0, n - 1))}); return;
        case TextureWrap::Black:
            outside = outside || a < 0 || b >= n;
            if (b >= 0 && a < n) runs.push_back({uint32_t(std::max<int64_t>(a, 0)), uint32_t(std::min<int64_t>(b, n - 1))});
            return;
        case TextureWrap::Repeat: {
            if (b - a + 1 >= n) return whole();
            const int64_t start = ((a % n) + n) % n, end = start + (b - a);
            if (end < n) runs.push_back({uint32_t(start), uint32_t(end)});
            else runs.push_back({uint32_t(start), uint32_t(n - 1)}), runs.push_back({0, uint32_t(end - n)});
            return;
        }
        case TextureWrap::Mirror: {
            if (b - a + 1 >= 2 * n) return whole();
            // Tile k of width n is mirrored when k is odd: split [a, b] at tile borders and map each piece.
            for (int64_t i = a; i <= b;) {
                const int64_t tile = i >= 0 ? i / n : -((-i + n - 1) / n), tileEnd = std::min(b, (tile + 1) * n - 1);
                const int64_t p = i - tile * n, q = tileEnd - tile * n;
                if (tile % 2 == 0) runs.push_back({uint32_t(p), uint32_t(q)});
                else runs.push_back({uint32_t(n - 1 - q), uint32_t(n - 1 - p)});
                i = tileEnd + 1;
            }
            return;
        }
    }
}

}  // namespace

std::array<float, 2> slot_range(const TextureSlot& slot, const TextureRange& range, std::array<float, 2> lo, std::array<float, 2> hi) {
    const size_t channel = slot_channel(slot);
    auto output = [&](float a, float b) {  // a value range through scale and bias
        const float x = a * slot.scale[channel] + slot.bias[channel], y = b * slot.scale[channel] + slot.bias[channel];
        return std::array<float, 2>{std::min(x, y), std::max(x, y)};
    };
    if (!slot.image) return output(slot.fallback[channel], slot.fallback[channel]);
    const TextureImage& image = *slot.image;
    // The rectangle's corners through UsdTransform2d, then the texels bilinear reads touch, a texel wider each way.
    const auto& m = slot.transform;
    double u0 = INFINITY, u1 = -INFINITY, v0 = INFINITY, v1 = -INFINITY;
    for (float s : {lo[0], hi[0]})
        for (float t : {lo[1], hi[1]}) {
            const double u = double(m[0]) * s + double(m[1]) * t + m[2], v = double(m[3]) * s + double(m[4]) * t + m[5];
            u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
        }
    const double limit = 1e9;  // coordinates beyond any image: the whole range
    if (!(u0 > -limit && u1 < limit && v0 > -limit && v1 < limit)) {
        const auto all = range.texels(0, 0, image.width - 1, image.height - 1);
        auto out = output(all[0], all[1]);
        if (slot.wrapS == TextureWrap::Black || slot.wrapT == TextureWrap::Black) out = {std::min(out[0], output(0, 0)[0]), std::max(out[1], output(0, 0)[1])};
        return out;
    }
    const int64_t x0 = int64_t(std::floor(u0 * image.width - 0.5)) - 1, x1 = int64_t(std::floor(u1 * image.width - 0.5)) + 2;
    const int64_t y0 = int64_t(std::floor(v0 * image.height - 0.5)) - 1, y1 = int64_t(std::floor(v1 * image.height - 0.5)) + 2;
    std::vector<std::array<uint32_t, 2>> columns, rows;
    bool outside = false;
    wrapped_runs(x0, x1, image.width, slot.wrapS, columns, outside);
    wrapped_runs(y0, y1, image.height, slot.wrapT, rows, outside);
    float low = INFINITY, high = -INFINITY;
    for (const auto& r : rows)
        for (const auto& c : columns) {
            const auto part = range.texels(c[0], r[0], c[1], r[1]);
            low = std::min(low, part[0]), high = std::max(high, part[1]);
        }
    if (outside) low = std::min(low, 0.0f), high = std::max(high, 0.0f);
    return output(low, high);
}

TextureImage read_texture(const std::string& path, ColorSpace colorSpace) {
    ImageFile file;
    std::string why;
    try {
        why = image_files().read(path, true, true, kMaxTextureSize, file);  // colours as stored: UsdUVTexture reads straight alpha
    } catch (const ImageIoError& e) {
        throw TextureError(e.what());
    }
    if (!why.empty()) throw TextureError(std::filesystem::exists(path) ? why : "no such file");
    const bool eightBit = !file.bytes.empty();
    return make_texture(file.width, file.height, file.channels, eightBit ? file.bytes.data() : nullptr,
                        eightBit ? nullptr : file.floats.data(), colorSpace, path);
}

std::array<float, 27> latlong_irradiance(const TextureImage& image) {
    // The first level at most 128 texels wide: the irradiance is smooth (three bands), so its texels are plenty.
    const uint32_t format = image.format & TS_TEXTURE_FORMAT_MASK;
    uint32_t level = 0, offset = 0;
    while (level + 1 < image.levels && std::max(1u, image.width >> level) > 128) {
        offset += level_words(format, std::max(1u, image.width >> level), std::max(1u, image.height >> level));
        ++level;
    }
    const uint32_t w = std::max(1u, image.width >> level), h = std::max(1u, image.height >> level);
    constexpr double pi = 3.14159265358979323846;
    // Radiance projected on the real spherical harmonics of bands 0-2 (the usual constant factors), each texel
    // weighted by its solid angle.
    std::array<double, 27> sum{};
    std::vector<float> row(size_t(w) * 4);
    for (uint32_t y = 0; y < h; ++y) {
        decode_row(image, offset, w, y, row.data());  // rows bottom first: y = 0 is the lowest latitude
        const double latitude = ((y + 0.5) / h - 0.5) * pi;
        const double solidAngle = (2.0 * pi / w) * (pi / h) * std::cos(latitude);
        for (uint32_t x = 0; x < w; ++x) {
            const double longitude = (0.5 - (x + 0.5) / w) * 2.0 * pi;
            const double dx = std::cos(latitude) * std::sin(longitude), dy = std::sin(latitude), dz = std::cos(latitude) * std::cos(longitude);
            const double basis[9] = {0.282095, 0.488603 * dy, 0.488603 * dz, 0.488603 * dx, 1.092548 * dx * dy, 1.092548 * dy * dz,
                                     0.315392 * (3.0 * dz * dz - 1.0), 1.092548 * dx * dz, 0.546274 * (dx * dx - dy * dy)};
            for (int i = 0; i < 9; ++i)
                for (int c = 0; c < 3; ++c) sum[3 * i + c] += row[4 * x + c] * basis[i] * solidAngle;
        }
    }
    // Irradiance convolution per band (pi, 2 pi / 3, pi / 4), then / pi.
    const double band[9] = {1.0, 2.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0, 0.25, 0.25, 0.25, 0.25, 0.25};
    std::array<float, 27> coefficients{};
    for (int i = 0; i < 27; ++i) coefficients[i] = float(sum[i] * band[i / 3]);
    return coefficients;
}

std::shared_ptr<const TextureImage> TextureStore::load(const std::string& path, ColorSpace colorSpace) {
    std::error_code error;
    const auto time = std::filesystem::last_write_time(path, error);
    const int64_t fileTime = error ? 0 : int64_t(time.time_since_epoch().count());
    const uint64_t fileSize = error ? 0 : uint64_t(std::filesystem::file_size(path, error));
    const auto key = std::make_pair(path, colorSpace);
    {
        std::lock_guard lock(mutex_);
        auto it = images_.find(key);
        if (it != images_.end()) {
            auto image = it->second.lock();
            if (image && image->fileTime == fileTime && image->fileSize == fileSize) return image;
        }
    }
    auto image = std::make_shared<TextureImage>(read_texture(path, colorSpace));
    image->fileTime = fileTime;
    image->fileSize = fileSize;
    std::lock_guard lock(mutex_);
    ++filesRead_;
    images_[key] = image;
    for (auto it = images_.begin(); it != images_.end();)  // forget images nobody holds any more
        it = it->second.expired() ? images_.erase(it) : std::next(it);
    return image;
}

void TextureStore::load_slots(std::vector<TextureSlot>& slots, const std::string& materialName, std::vector<std::string>& warnings) {
    for (TextureSlot& slot : slots) {
        if (slot.image) continue;
        try {
            if (slot.file.empty()) throw TextureError("no file is given");
            slot.image = load(slot.file, slot.colorSpace);
        } catch (const TextureError& e) {
            const auto& f = slot.fallback;
            char fallback[96];
            std::snprintf(fallback, sizeof(fallback), "(%g, %g, %g, %g)", f[0], f[1], f[2], f[3]);
            warnings.push_back(materialName + ": texture '" + slot.file + "' for " + material_input_name(slot.input) + " cannot be read (" +
                               e.what() + "); its fallback " + fallback + " is used");
        }
    }
}

}  // namespace tessera
