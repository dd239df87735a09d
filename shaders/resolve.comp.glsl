// Resolve, one dispatch per material bin (push.step: the material): one thread per covered pixel of the bin reads
// the visibility buffer, refetches its triangle, finds the barycentrics where the pixel's ray meets it, and writes
// the requested AOV. Every visible pixel is shaded exactly once, whatever the overdraw. background.comp.glsl writes
// the pixels nothing covers.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"
#include "surface.h"

layout(local_size_x = TS_SHADE_GROUP_SIZE) in;

// The pipeline variant for materials with textures (the renderer picks it per bin).
layout(constant_id = TS_SPEC_TEXTURES) const bool TEXTURED = false;

const float PI = 3.14159265358979;

vec3 decode_octahedral(uint packed) {
    vec2 e = unpackSnorm2x16(packed);
    vec3 n = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    if (n.z < 0.0) n.xy = (1.0 - abs(n.yx)) * vec2(n.x >= 0.0 ? 1.0 : -1.0, n.y >= 0.0 ? 1.0 : -1.0);
    return normalize(n);
}

vec3 vertex_color(GpuFrame frame, GpuMesh mesh, uint vertex) {
    uint i = vertex - mesh.vertexOffset + mesh.colorOffset;
    UintRef colors = UintRef(frame.colors);
    return vec3(unpackHalf2x16(colors.data[2u * i]), unpackHalf2x16(colors.data[2u * i + 1u]).x);
}

// A well-spread colour for an id (integer hash, then three 8-bit channels lifted away from black).
vec3 id_color(uint id) {
    id ^= id >> 16; id *= 0x7feb352du; id ^= id >> 15; id *= 0x846ca68bu; id ^= id >> 16;
    return vec3(uvec3(id, id >> 8, id >> 16) & 0xffu) / 255.0 * 0.8 + 0.2;
}

// DAG level as a heat colour: level 0 blue, then cyan, green, yellow, red from level 8 up.
vec3 level_color(uint level) {
    float t = min(float(level) / 8.0, 1.0);
    return clamp(vec3(2.0 * t - 0.5, 2.0 - abs(4.0 * t - 2.0), 1.5 - 2.0 * t), 0.0, 1.0);
}

vec3 visualize(uint mode, Instance instance, uvec2 visible, GpuCluster cluster, uint triangle, bool software, uint material) {
    if (mode == TS_VIS_RASTER_BINS) return software ? vec3(0.15, 0.45, 1.0) : vec3(1.0, 0.55, 0.1);
    if (mode == TS_VIS_TRIANGLES) return id_color(cluster.triangleOffset + triangle);
    if (mode == TS_VIS_CLUSTERS) return id_color(visible.y);
    if (mode == TS_VIS_GROUPS) return id_color(cluster.group == 0xffffffffu ? visible.y : cluster.group * 7919u + cluster.meshIndex);
    if (mode == TS_VIS_LOD) return level_color(cluster.levelVertices >> 16);
    if (mode == TS_VIS_INSTANCES) return id_color(visible.x);
    if (mode == TS_VIS_PRIMITIVES) return id_color(instance.primId);
    return id_color(material);  // TS_VIS_SHADING_BINS
}

// Light reflected towards `toEye` from a distant light arriving from `toLight` with unit radiance: Lambert diffuse
// plus a GGX microfacet lobe (alpha = roughness^2, Smith-Schlick shadowing, Schlick Fresnel), times the cosine.
vec3 direct_light(vec3 n, vec3 toEye, vec3 toLight, vec3 albedo, vec3 f0, float roughness) {
    float nl = dot(n, toLight);
    if (nl <= 0.0) return vec3(0.0);
    if (max(f0.r, max(f0.g, f0.b)) <= 0.0) return albedo / PI * nl;  // diffuse only (the same for a whole bin)
    float nv = max(dot(n, toEye), 1e-4);
    vec3 h = normalize(toLight + toEye);
    float nh = max(dot(n, h), 0.0), vh = max(dot(toEye, h), 0.0);
    float alpha = max(roughness * roughness, 1e-3);
    float a2 = alpha * alpha;
    float d = a2 / (PI * (nh * nh * (a2 - 1.0) + 1.0) * (nh * nh * (a2 - 1.0) + 1.0));
    float k = alpha / 2.0;
    float g = (nl / (nl * (1.0 - k) + k)) * (nv / (nv * (1.0 - k) + k));
    vec3 f = f0 + (1.0 - f0) * pow(1.0 - vh, 5.0);
    return (albedo / PI + d * g * f / (4.0 * nl * nv)) * nl;
}

// What fraction of a uniform environment the specular lobe reflects (directional albedo), by the analytic fit of
// the split-sum integral that Karis published for mobile (Unreal Engine 4, 2014).
vec3 environment_reflectance(vec3 f0, float roughness, float nv) {
    vec4 r = roughness * vec4(-1.0, -0.0275, -0.572, 0.022) + vec4(1.0, 0.0425, 1.04, -0.04);
    float a004 = min(r.x * r.x, exp2(-9.28 * nv)) * r.x + r.y;
    vec2 ab = vec2(-1.04, 1.04) * a004 + r.zw;
    return max(f0.r, max(f0.g, f0.b)) <= 0.0 ? vec3(0.0) : f0 * ab.x + ab.y;  // no reflectance, no lobe (diffuse only)
}

// One covered pixel (visibility buffer value `value`, non-zero).
void shade(GpuFrame frame, uint index, uint64_t value, uint aov) {
    uvec2 pixel = uvec2(index % frame.viewport.x, index / frame.viewport.x);
    bool idAov = aov >= TS_AOV_PRIM_ID;
    if (frame.counts.w == TS_VIS_OVERDRAW && aov == TS_AOV_COLOR) {
        uint fragments = CounterRef(frame.overdraw).data[index];
        OutputRef(frame.aovOutput).data[index] = vec4(level_color(max(fragments, 1u) - 1u), 1.0);
        return;
    }

    uint triangle = uint(value) & ((1u << TS_VIS_TRIANGLE_BITS) - 1u);
    uvec2 visible = visible_cluster(frame, value);
    bool software = (visible.x & TS_VISIBLE_SOFTWARE) != 0u;
    visible.x &= ~TS_VISIBLE_SOFTWARE;
    Instance instance = load_instance(frame, visible.x);
    GpuCluster cluster = ClusterRef(frame.clusters).data[visible.y];
    if (idAov) {
        uint id = aov == TS_AOV_PRIM_ID ? instance.primId
                : aov == TS_AOV_INSTANCE_ID ? visible.x
                : aov == TS_AOV_CLUSTER_ID ? visible.y
                : cluster.triangleOffset + triangle;
        OutputIdRef(frame.aovOutput).data[index] = uvec4(id, 0u, 0u, 0u);
        return;
    }

    GpuMesh mesh = MeshRef(frame.meshes).data[instance.meshIndex];
    // The pixel's ray and where it meets the triangle's plane (the rasterizers' masks use the same code).
    PixelTriangle hitTriangle = pixel_triangle(frame, instance, cluster, triangle, pixel);
    uint v0 = hitTriangle.v0, v1 = hitTriangle.v1, v2 = hitTriangle.v2;
    vec3 p0 = hitTriangle.p0, e1 = hitTriangle.e1, e2 = hitTriangle.e2;
    vec3 origin = hitTriangle.origin, direction = hitTriangle.direction, bary = hitTriangle.bary;
    float t = dot(p0 - origin, cross(e1, e2)) / dot(direction, cross(e1, e2));
    if (!(t > 0.0) || isinf(t)) t = 0.0;  // edge-on triangle: the plane test is meaningless
    vec3 hit = origin + t * direction;

    if (aov == TS_AOV_DEPTH) {
        OutputRef(frame.aovOutput).data[index] = vec4(dot(hit, frame.cameraForward.xyz));
        return;
    }

    mat3 toWorld = transpose(mat3(instance.rows[0].xyz, instance.rows[1].xyz, instance.rows[2].xyz));
    mat3 normalMatrix = transpose(inverse(toWorld));
    UintRef normals = UintRef(frame.normals);
    vec3 objectNormal = bary.x * decode_octahedral(normals.data[v0]) + bary.y * decode_octahedral(normals.data[v1]) +
                        bary.z * decode_octahedral(normals.data[v2]);
    vec3 n = normalize(normalMatrix * objectNormal);
    vec3 geometric = normalize(cross(e1, e2));
    if (dot(geometric, direction) > 0.0) {  // the back of a double-sided surface: shade its other side
        geometric = -geometric;
        n = -n;
    }
    if (dot(n, geometric) < 0.0) n = geometric;  // an interpolated normal facing away would shade black
    if (aov == TS_AOV_NORMAL) {
        OutputRef(frame.aovOutput).data[index] = vec4(n, 1.0);
        return;
    }

    if (frame.counts.w != TS_VIS_NONE) {  // flat id colours, lit from the eye so that shapes stay readable
        if (frame.counts.w == TS_VIS_UV) {  // data, not a picture: unlit
            vec3 uvColor = vec3(1.0, 0.0, 1.0);
            if (mesh.uvOffset != TS_NO_STREAM) {
                PixelUv uv = triangle_pixel_uv(frame, mesh, vec2(pixel), bary, p0, e1, e2, v0, v1, v2);
                uvColor = vec3(fract(uv.uv), 0.0);
            }
            OutputRef(frame.aovOutput).data[index] = vec4(uvColor, 1.0);
            return;
        }
        vec3 tint = visualize(frame.counts.w, instance, visible, cluster, triangle, software, push.step);
        OutputRef(frame.aovOutput).data[index] = vec4(tint * (0.3 + 0.7 * abs(dot(geometric, direction))), 1.0);
        return;
    }

    GpuMaterial material = MaterialRef(frame.materials).data[push.step];  // this dispatch's bin is one material
    vec3 albedo = material.diffuseColor.rgb;
    if ((material.flags & TS_MATERIAL_USE_DISPLAY_COLOR) != 0u && mesh.colorOffset != TS_NO_STREAM)
        albedo = bary.x * vertex_color(frame, mesh, v0) + bary.y * vertex_color(frame, mesh, v1) + bary.z * vertex_color(frame, mesh, v2);
    vec3 emission = material.emissiveColor.rgb, f0 = material.specular.rgb;
    float occlusion = material.emissiveColor.a, roughness = material.specular.a, metallic = material.metallic;

    // Textured inputs replace their constants (only in the textured variant: no texture code at all for the others).
    // Opacity is not among them here: masks are cut by the rasterizers.
    if (TEXTURED && material.textureInputs != 0u) {
        PixelUv uv = triangle_pixel_uv(frame, mesh, vec2(pixel), bary, p0, e1, e2, v0, v1, v2);
        // One sample per textured input, in a loop: the trip count is the bin's (uniform), where a branch per input
        // would run every input's sampling masked on lavapipe, textured or not.
        TextureSlotRef slots = TextureSlotRef(frame.textureSlots);
        uint slot = material.firstTextureSlot;
        vec3 tangentNormal = vec3(0.0);
        for (uint inputs = material.textureInputs; inputs != 0u; inputs &= inputs - 1u, ++slot) {
            uint textured = uint(findLSB(inputs));
            if (textured == TS_INPUT_OPACITY) continue;  // masks are cut by the rasterizers
            vec4 v = texture_slot_value(frame.textures, slots.data[slot], uv.uv, uv.dx, uv.dy);
            if (textured == TS_INPUT_DIFFUSE_COLOR) albedo = v.rgb;
            else if (textured == TS_INPUT_EMISSIVE_COLOR) emission = v.rgb;
            else if (textured == TS_INPUT_SPECULAR_COLOR) f0 = v.rgb;
            else if (textured == TS_INPUT_METALLIC) metallic = clamp(v.x, 0.0, 1.0);
            else if (textured == TS_INPUT_ROUGHNESS) roughness = clamp(v.x, 0.0, 1.0);
            else if (textured == TS_INPUT_OCCLUSION) occlusion = clamp(v.x, 0.0, 1.0);
            else tangentNormal = v.xyz;  // TS_INPUT_NORMAL
        }
        if ((material.textureInputs & (1u << TS_INPUT_NORMAL)) != 0u && mesh.uvOffset != TS_NO_STREAM) {
            n = apply_normal_map(n, tangentNormal, e1, e2, vertex_uv(frame, mesh, v0), vertex_uv(frame, mesh, v1), vertex_uv(frame, mesh, v2));
            if (dot(n, geometric) < 0.0) n = geometric;
        }
    }

    // UsdPreviewSurface: metallic blends the reflectance towards the albedo and takes the diffuse away.
    if ((material.flags & TS_MATERIAL_METALLIC) != 0u) {
        f0 = mix(f0, albedo, metallic);
        albedo *= 1.0 - metallic;
    }
    vec3 toEye = -direction;
    vec3 color = emission;
    for (uint i = 0u; i < frame.viewport.w; ++i) {
        GpuLight light = frame.lights[i];
        if (uint(light.directionType.w) == TS_LIGHT_DISTANT)
            color += light.radiance.rgb * direct_light(n, toEye, -light.directionType.xyz, albedo, f0, roughness);
        else  // a uniform dome, its light scaled by the occlusion input; no shadowing yet
            color += light.radiance.rgb * occlusion * (albedo + environment_reflectance(f0, roughness, max(dot(n, toEye), 0.0)));
    }
    OutputRef(frame.aovOutput).data[index] = vec4(color, 1.0);
}

void main() {
    GpuFrame frame = push.frame.f;
    uint aov = push.aov;
    // One thread per pixel of the bin, no loop: on lavapipe a loop around the shading code runs it masked.
    GpuBin bin = BinRef(frame.bins).data[push.step];
    uint i = (gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) * TS_SHADE_GROUP_SIZE + gl_LocalInvocationIndex;
    if (i >= bin.count) return;
    uint index = CounterRef(frame.binPixels).data[bin.offset + i];
    shade(frame, index, VisibilityRef(frame.visibility).data[index], aov);
}
