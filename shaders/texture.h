// Texture sampling by hand from the texture pool (shared.h: GpuTexture, GpuTextureSlot). Lavapipe has no descriptor
// indexing, so there are no samplers: texels are fetched from one buffer (through its texel view in the frame's passes,
// else by device address) and filtered here. Per axis wrap modes; bilinear filtering within a mip level, trilinear
// between the two levels that the UV derivatives pick (isotropic: the longer footprint axis decides, as most GPUs do
// without anisotropic filtering). sRGB texels are decoded before they are filtered, as hardware sRGB formats are.
// testenv/cpp/test_textures.cpp checks every path against a CPU reference of the same arithmetic.
// Include after shared.h and the buffer reference and int64 extensions.
#ifndef TESSERA_TEXTURE_H
#define TESSERA_TEXTURE_H

layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer TextureSlotRef { GpuTextureSlot data[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer TextureWordRef { uint data[]; };

// Word i of the pool (GpuTexture records, then the images' words). In the frame's passes (frame.h included first) through
// the pool's texel view where the pipeline reads through views (TEXEL_VIEWS): lavapipe loads through an address lane by
// lane, and the slot, record and texel loads of one textured input were three quarters of a textured resolve. Elsewhere
// (the probe test's shader) through the pool's address.
uint texture_word(uint64_t pool, uint i) {
#ifdef TESSERA_FRAME_H
    if (TEXEL_VIEWS) return texelFetch(textureWordTexels, int(i)).x;
#endif
    return TextureWordRef(pool).data[i];
}

// Texture `index`'s record, at the start of the pool (4 words each: TS_CHECK_SIZE(GpuTexture, 16)).
GpuTexture texture_record(uint64_t pool, uint index) {
    uint at = 4u * index;
    return GpuTexture(texture_word(pool, at), texture_word(pool, at + 1u), texture_word(pool, at + 2u), texture_word(pool, at + 3u));
}

// The texture kinds this variant reads (TS_SPEC_TEXTURE_KINDS): the code of the others is left out. Every kind where the
// frame's specialization constants are not declared (the probe test's shader).
#ifdef TESSERA_FRAME_H
layout(constant_id = TS_SPEC_TEXTURE_KINDS) const uint TEXTURE_KINDS = TS_TEXTURE_KINDS_ALL;
#else
const uint TEXTURE_KINDS = TS_TEXTURE_KINDS_ALL;
#endif
bool reads_kind(uint kind) { return (TEXTURE_KINDS & kind) != 0u; }

uvec2 texture_level_size(GpuTexture texture, uint level) {
    return max(uvec2(texture.width, texture.height) >> level, uvec2(1u));
}

uint texture_level_words(uint format, uvec2 size) {
    uint texels = size.x * size.y;
    return format == TS_TEXTURE_R8 ? (texels + 3u) / 4u : format == TS_TEXTURE_RGBA16F ? 2u * texels : texels;
}

// First word of a mip level: the levels before it, one after another from the texture's offset.
uint texture_level_offset(GpuTexture texture, uint level) {
    uint format = texture.formatLevels & TS_TEXTURE_FORMAT_MASK;
    uint offset = texture.offset;
    for (uint l = 0u; l < level; ++l) offset += texture_level_words(format, texture_level_size(texture, l));
    return offset;
}

// sRGB to linear: c / 12.92 up to 0.04045, above it ((c + 0.055) / 1.055)^2.4 as a degree-6 polynomial (a Chebyshev fit
// on [0.04045, 1]; within 1.5e-5 of the curve at every 8-bit value, a twentieth of the smallest 8-bit step). pow cost
// lavapipe a log2 and an exp2 per channel of every texel: a third of a resolve sampling one sRGB texture.
float srgb_to_linear(float c) {
    float curve = (((((-0.0489606597 * c + 0.207285017) * c - 0.409055501) * c + 0.700847626) * c + 0.516486168) * c + 0.0324432105) * c +
                  0.000945259526;
    return c <= 0.04045 ? c / 12.92 : curve;
}

// A coordinate brought into one period without changing what it samples: [0, 1] for repeat, [0, 2] for mirror,
// [-1, 2] otherwise. Texel indices then stay within a period of the image on either side, and wrap_texel needs no
// integer division (which lavapipe does lane by lane).
float wrap_coordinate(float u, uint mode) {
    if (reads_kind(TS_TEXTURE_KIND_WRAP(TS_WRAP_REPEAT)) && mode == TS_WRAP_REPEAT) return fract(u);
    if (reads_kind(TS_TEXTURE_KIND_WRAP(TS_WRAP_MIRROR)) && mode == TS_WRAP_MIRROR) return u - 2.0 * floor(0.5 * u);
    return clamp(u, -1.0, 2.0);
}

// The texel an integer coordinate reads after wrapping, or -1 outside the image with TS_WRAP_BLACK; `i` comes from a
// coordinate wrap_coordinate brought into range, so it lies in [-1, n] (repeat) or [-1, 2n] (mirror).
int wrap_texel(int i, int n, uint mode) {
    if (reads_kind(TS_TEXTURE_KIND_WRAP(TS_WRAP_CLAMP)) && mode == TS_WRAP_CLAMP) return clamp(i, 0, n - 1);
    if (reads_kind(TS_TEXTURE_KIND_WRAP(TS_WRAP_BLACK)) && mode == TS_WRAP_BLACK) return i < 0 || i >= n ? -1 : i;
    if (reads_kind(TS_TEXTURE_KIND_WRAP(TS_WRAP_MIRROR)) && mode == TS_WRAP_MIRROR) {
        int m = i < 0 ? i + 2 * n : (i >= 2 * n ? i - 2 * n : i);
        return m < n ? m : 2 * n - 1 - m;
    }
    return i < 0 ? i + n : (i >= n ? i - n : i);
}

// One texel as linear RGBA (transparent black for x or y < 0: outside a TS_WRAP_BLACK image).
vec4 texture_texel(uint64_t pool, uint format, bool srgb, uint levelOffset, uint levelWidth, int x, int y) {
    if (x < 0 || y < 0) return vec4(0.0);
    uint i = uint(y) * levelWidth + uint(x);
    // One load for the 8-bit formats, two for half.
    uint word = texture_word(pool, levelOffset + (format == TS_TEXTURE_RGBA8 ? i : format == TS_TEXTURE_R8 ? i >> 2u : 2u * i));
    vec4 v = unpackUnorm4x8(word);  // TS_TEXTURE_RGBA8
    if (reads_kind(TS_TEXTURE_KIND_FORMAT(TS_TEXTURE_R8)) && format == TS_TEXTURE_R8) v = vec4(vec3(float((word >> (8u * (i & 3u))) & 0xffu) / 255.0), 1.0);
    if (reads_kind(TS_TEXTURE_KIND_FORMAT(TS_TEXTURE_RGBA16F)) && format == TS_TEXTURE_RGBA16F)
        v = vec4(unpackHalf2x16(word), unpackHalf2x16(texture_word(pool, levelOffset + 2u * i + 1u)));
    if (reads_kind(TS_TEXTURE_KIND_SRGB) && srgb) v.rgb = vec3(srgb_to_linear(v.r), srgb_to_linear(v.g), srgb_to_linear(v.b));
    return v;
}

// Bilinear filtering of one mip level; texel centres sit at (i + 0.5) / size.
vec4 sample_texture_level(uint64_t pool, GpuTexture texture, uint level, vec2 uv, uint wrapS, uint wrapT) {
    uint format = texture.formatLevels & TS_TEXTURE_FORMAT_MASK;
    bool srgb = (texture.formatLevels & TS_TEXTURE_SRGB) != 0u;
    uvec2 size = texture_level_size(texture, level);
    uint offset = texture_level_offset(texture, level);
    vec2 p = vec2(wrap_coordinate(uv.x, wrapS), wrap_coordinate(uv.y, wrapT)) * vec2(size) - 0.5;
    vec2 base = floor(p);
    vec2 f = p - base;
    int x0 = wrap_texel(int(base.x), int(size.x), wrapS), x1 = wrap_texel(int(base.x) + 1, int(size.x), wrapS);
    int y0 = wrap_texel(int(base.y), int(size.y), wrapT), y1 = wrap_texel(int(base.y) + 1, int(size.y), wrapT);
    vec4 t00 = texture_texel(pool, format, srgb, offset, size.x, x0, y0);
    vec4 t10 = texture_texel(pool, format, srgb, offset, size.x, x1, y0);
    vec4 t01 = texture_texel(pool, format, srgb, offset, size.x, x0, y1);
    vec4 t11 = texture_texel(pool, format, srgb, offset, size.x, x1, y1);
    return mix(mix(t00, t10, f.x), mix(t01, t11, f.x), f.y);
}

// Trilinear sample of texture `index` at uv, its mip level from uv's derivatives along the two screen axes:
// lod = log2 of the longer footprint in level-0 texels, clamped to the chain; magnification samples level 0.
// `wrap`: wrapS | wrapT << 2.
vec4 sample_texture(uint64_t pool, uint index, uint wrap, vec2 uv, vec2 duvdx, vec2 duvdy) {
    GpuTexture texture = texture_record(pool, index);
    uint levels = (texture.formatLevels >> 8u) & 0xffu;
    vec2 size = vec2(texture.width, texture.height);
    vec2 fx = duvdx * size, fy = duvdy * size;
    float footprint2 = max(dot(fx, fx), dot(fy, fy));
    float lod = footprint2 > 1.0 ? min(0.5 * log2(footprint2), float(levels - 1u)) : 0.0;  // also 0 for NaN
    uint level = uint(lod);
    float blend = lod - float(level);
    vec4 value = sample_texture_level(pool, texture, level, uv, wrap & 3u, (wrap >> 2u) & 3u);
    if (blend > 0.0) value = mix(value, sample_texture_level(pool, texture, level + 1u, uv, wrap & 3u, (wrap >> 2u) & 3u), blend);
    return value;
}

// A UsdUVTexture's output at st (with st's derivatives along the screen axes): UsdTransform2d, then the sample
// times scale plus bias, then the output's channel (a single channel comes back in every component).
vec4 texture_slot_value(uint64_t pool, GpuTextureSlot slot, vec2 st, vec2 dstdx, vec2 dstdy) {
    mat2 linear = mat2(slot.transform.x, slot.transform.z, slot.transform.y, slot.transform.w);  // columns
    vec2 uv = linear * st + vec2(slot.translationS, slot.translationT);
    vec4 value = sample_texture(pool, slot.texture, slot.mode & 15u, uv, linear * dstdx, linear * dstdy) * slot.scale + slot.bias;
    uint channel = slot.mode >> 4u;
    return channel == TS_CHANNEL_RGB ? value : vec4(value[channel]);
}

#endif
