// What the rasterizers and resolve share about a point of a surface: the pixel's ray, barycentrics on the triangle's
// plane, texture coordinates with their analytic screen derivatives, and the UsdPreviewSurface inputs that textures
// drive (texture.h samples them). Include after frame.h.
#ifndef TESSERA_SURFACE_H
#define TESSERA_SURFACE_H

#include "texture.h"

vec2 vertex_uv(GpuFrame frame, GpuMesh mesh, uint vertex) {
    uint i = vertex - mesh.vertexOffset + mesh.uvOffset;
    if (TEXEL_VIEWS) return uintBitsToFloat(texelFetch(uvTexels, int(i)).xy);
    FloatRef uvs = FloatRef(frame.uvs);
    return vec2(uvs.data[2u * i], uvs.data[2u * i + 1u]);
}

// The ray through a point of the image (pixel units), from the frame's affine ray (perspective and orthographic):
// six multiply-adds where the inverse view-projection took two matrix products and two divisions per pixel.
void pixel_ray(GpuFrame frame, vec2 pixel, out vec3 origin, out vec3 direction) {
    origin = frame.rayOrigin[0].xyz + pixel.x * frame.rayOrigin[1].xyz + pixel.y * frame.rayOrigin[2].xyz;
    direction = normalize(frame.rayDirection[0].xyz + pixel.x * frame.rayDirection[1].xyz + pixel.y * frame.rayDirection[2].xyz);
}

// Barycentrics where a ray meets the plane of the triangle (p0, p0 + e1, p0 + e2), unclamped (Moller-Trumbore);
// the centroid for a ray along the plane.
vec3 plane_barycentrics(vec3 origin, vec3 direction, vec3 p0, vec3 e1, vec3 e2) {
    vec3 pv = cross(direction, e2);
    float det = dot(e1, pv);
    if (!(abs(det) > 0.0)) return vec3(1.0 / 3.0);
    vec3 tv = origin - p0;
    float u = dot(tv, pv) / det;
    float v = dot(direction, cross(tv, e1)) / det;
    return vec3(1.0 - u - v, u, v);
}

// A surface attribute at the pixel and its change to the next pixel right (dx) and down (dy): the analytic
// derivatives that pick a texture's mip level (a compute shader has no quads to difference).
struct PixelUv {
    vec2 uv, dx, dy;
};

PixelUv pixel_uv(GpuFrame frame, vec2 pixel, vec3 bary, vec3 p0, vec3 e1, vec3 e2, vec2 uv0, vec2 uv1, vec2 uv2) {
    vec3 origin, direction;
    PixelUv result;
    result.uv = bary.x * uv0 + bary.y * uv1 + bary.z * uv2;
    pixel_ray(frame, pixel + vec2(1.5, 0.5), origin, direction);
    vec3 bx = plane_barycentrics(origin, direction, p0, e1, e2) - bary;
    pixel_ray(frame, pixel + vec2(0.5, 1.5), origin, direction);
    vec3 by = plane_barycentrics(origin, direction, p0, e1, e2) - bary;
    result.dx = bx.x * uv0 + bx.y * uv1 + bx.z * uv2;
    result.dy = by.x * uv0 + by.y * uv1 + by.z * uv2;
    return result;
}

// The texture coordinates of a triangle's pixel (the pixel's top-left corner in image units), with derivatives.
// Without a UV set: (0, 0), as UsdPrimvarReader_float2's fallback, and no derivatives (level 0).
PixelUv triangle_pixel_uv(GpuFrame frame, GpuMesh mesh, vec2 pixel, vec3 bary, vec3 p0, vec3 e1, vec3 e2, uint v0, uint v1, uint v2) {
    if (mesh.uvOffset == TS_NO_STREAM) return PixelUv(vec2(0.0), vec2(0.0), vec2(0.0));
    return pixel_uv(frame, pixel, bary, p0, e1, e2, vertex_uv(frame, mesh, v0), vertex_uv(frame, mesh, v1), vertex_uv(frame, mesh, v2));
}

// Texture slot `index` of the frame's materials (the same bits through the view or the address).
GpuTextureSlot load_texture_slot(GpuFrame frame, uint index) {
    if (!TEXEL_VIEWS) return TextureSlotRef(frame.textureSlots).data[index];
    int at = int(4u * index);
    uvec4 t3 = texelFetch(textureSlotTexels, at + 3);
    GpuTextureSlot slot;
    slot.scale = uintBitsToFloat(texelFetch(textureSlotTexels, at));
    slot.bias = uintBitsToFloat(texelFetch(textureSlotTexels, at + 1));
    slot.transform = uintBitsToFloat(texelFetch(textureSlotTexels, at + 2));
    slot.translationS = uintBitsToFloat(t3.x);
    slot.translationT = uintBitsToFloat(t3.y);
    slot.texture = t3.z;
    slot.mode = t3.w;
    return slot;
}

// A textured input's value: the material's slot for `materialInput` (one of its textureInputs bits, TS_INPUT_*).
vec4 material_texture(GpuFrame frame, GpuMaterial material, uint materialInput, PixelUv uv) {
    uint slot = material.firstTextureSlot + uint(bitCount(material.textureInputs & ((1u << materialInput) - 1u)));
    return texture_slot_value(frame.textures, load_texture_slot(frame, slot), uv.uv, uv.dx, uv.dy);
}

// The mesh's vertex channel at a vertex: 4 components (rgba16f), displayColor or the primvars its materials read.
vec4 vertex_channel(GpuFrame frame, GpuMesh mesh, uint vertex) {
    uint i = vertex - mesh.vertexOffset + mesh.colorOffset;
    uvec2 halves = TEXEL_VIEWS ? texelFetch(colorTexels, int(i)).xy : uvec2(UintRef(frame.colors).data[2u * i], UintRef(frame.colors).data[2u * i + 1u]);
    return vec4(unpackHalf2x16(halves.x), unpackHalf2x16(halves.y));
}

// The channel interpolated with barycentrics over a triangle's vertices.
vec4 interpolated_channel(GpuFrame frame, GpuMesh mesh, vec3 bary, uint v0, uint v1, uint v2) {
    return bary.x * vertex_channel(frame, mesh, v0) + bary.y * vertex_channel(frame, mesh, v1) + bary.z * vertex_channel(frame, mesh, v2);
}

// A material input (TS_INPUT_*) from the vertex channel where the material's vertexInputs map it there, else `value`.
// A scalar input reads x.
vec3 vertex_input(uint vertexInputs, uint materialInput, vec4 channel, vec3 value) {
    uint code = (vertexInputs >> (TS_VERTEX_INPUT_BITS * materialInput)) & ((1u << TS_VERTEX_INPUT_BITS) - 1u);
    if ((code & TS_VERTEX_INPUT_SET) == 0u) return value;
    uint first = code & 3u;
    return (code & TS_VERTEX_INPUT_RGB) != 0u ? vec3(channel[first], channel[min(first + 1u, 3u)], channel[min(first + 2u, 3u)])
                                               : vec3(channel[first]);
}

bool vertex_opacity(GpuMaterial material) {
    return ((material.vertexInputs >> (TS_VERTEX_INPUT_BITS * TS_INPUT_OPACITY)) & TS_VERTEX_INPUT_SET) != 0u;
}

// A visible triangle seen through a pixel: its vertices, its first corner and edges relative to the camera, the
// pixel's ray and the unclamped barycentrics where that ray meets the triangle's plane.
struct PixelTriangle {
    uint v0, v1, v2;
    vec3 p0, e1, e2;
    vec3 origin, direction;
    vec3 bary;
};

PixelTriangle pixel_triangle(GpuFrame frame, Instance instance, GpuCluster cluster, uint triangle, uvec2 pixel) {
    PixelTriangle t;
    bool flip = (instance.flags & TS_INSTANCE_FLIP_WINDING) != 0u;
    vec3 translation = camera_relative_translation(instance);
    uvec3 v = triangle_vertices(frame, cluster, triangle, flip);
    t.v0 = v.x;
    t.v1 = v.y;
    t.v2 = v.z;
    t.p0 = to_camera_relative(instance, translation, vertex_position(frame, t.v0));
    t.e1 = to_camera_relative(instance, translation, vertex_position(frame, t.v1)) - t.p0;
    t.e2 = to_camera_relative(instance, translation, vertex_position(frame, t.v2)) - t.p0;
    pixel_ray(frame, vec2(pixel) + 0.5, t.origin, t.direction);
    t.bary = plane_barycentrics(t.origin, t.direction, t.p0, t.e1, t.e2);
    return t;
}

// UsdPreviewSurface opacityThreshold over a textured or per-vertex opacity (instances flagged TS_INSTANCE_MASKED): true where the
// opacity at this pixel is below the threshold, so that the rasterizer leaves the pixel to what lies behind. Both
// rasterizers call this same code for a pixel with the payload they write (visible cluster << 7 | triangle), so they
// cut the same pixels. Micro-triangles are masked by micro_masked_out (tessellation.h), which the patch rasterizers
// reach through PIXEL_MASKED_OUT (raster.h): the cluster rasterizers carry none of the tessellation code.
bool masked_out(GpuFrame frame, uint payload, uvec2 pixel) {
    uvec2 visible = visible_cluster(frame, payload >> TS_VIS_TRIANGLE_BITS);
    Instance instance = load_instance(frame, visible.x & ~TS_VISIBLE_SOFTWARE);
    GpuCluster cluster = load_cluster(frame, visible.y);
    uint triangle = payload & ((1u << TS_VIS_TRIANGLE_BITS) - 1u);
    GpuMaterial material = load_material(frame, pixel_material(frame, instance, visible.y, triangle));
    bool textured = (material.textureInputs & (1u << TS_INPUT_OPACITY)) != 0u;
    if (!textured && !vertex_opacity(material)) return false;  // another slot of the mesh's materials
    GpuMesh mesh = load_mesh(frame, instance.meshIndex);
    PixelTriangle t = pixel_triangle(frame, instance, cluster, triangle, pixel);
    if (!textured) {  // a primvar reader's opacity, per vertex
        if (mesh.colorOffset == TS_NO_STREAM) return false;
        vec4 channel = interpolated_channel(frame, mesh, t.bary, t.v0, t.v1, t.v2);
        return vertex_input(material.vertexInputs, TS_INPUT_OPACITY, channel, vec3(1.0)).x < material.diffuseColor.a;
    }
    PixelUv uv = triangle_pixel_uv(frame, mesh, vec2(pixel), t.bary, t.p0, t.e1, t.e2, t.v0, t.v1, t.v2);
    return material_texture(frame, material, TS_INPUT_OPACITY, uv).x < material.diffuseColor.a;  // a: the threshold
}

// A tangent-space normal (UsdPreviewSurface's normal input, after the texture's scale and bias) turned into the world
// frame of the triangle's UV parametrization around the shading normal n. A triangle whose UVs are degenerate keeps n.
vec3 apply_normal_map(vec3 n, vec3 tangentNormal, vec3 e1, vec3 e2, vec2 uv0, vec2 uv1, vec2 uv2) {
    vec2 d1 = uv1 - uv0, d2 = uv2 - uv0;
    float det = d1.x * d2.y - d2.x * d1.y;
    if (!(abs(det) > 0.0)) return n;
    vec3 dpdu = (e1 * d2.y - e2 * d1.y) / det, dpdv = (e2 * d1.x - e1 * d2.x) / det;
    vec3 t = dpdu - n * dot(n, dpdu);
    if (!(dot(t, t) > 0.0)) return n;
    t = normalize(t);
    vec3 b = cross(n, t) * (dot(cross(n, t), dpdv) < 0.0 ? -1.0 : 1.0);  // mirrored UVs flip the bitangent
    vec3 mapped = t * tangentNormal.x + b * tangentNormal.y + n * tangentNormal.z;
    return dot(mapped, mapped) > 0.0 ? normalize(mapped) : n;
}

#endif
