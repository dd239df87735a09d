// Resolve, one dispatch per bin (push.step: the bin, push.material: its material): each covered pixel of the bin (a
// thread per pixel on a GPU, several per thread on a CPU device): read the visibility buffer, refetch its triangle, find
// the barycentrics where the pixel's ray meets it, and write the requested AOV. Every visible pixel is shaded exactly
// once, whatever the overdraw. The pixels nothing covers keep the background the frame wrote first. A frame of one bin
// reads every pixel instead of a list (TS_SPEC_PIXEL_SOURCE); in place, it stores the background of those itself.
#version 460
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_EXT_control_flow_attributes : require
#include "frame.h"
#include "surface.h"
#include "tessellation.h"
#include "lights.h"

layout(local_size_x = TS_SHADE_GROUP_SIZE) in;
// Pixels per thread: one on a GPU, several on a CPU device (shared.h).
layout(constant_id = TS_SPEC_SHADE_PIXELS_PER_THREAD) const uint PIXELS_PER_THREAD = 1u;

// The pipeline variants for materials with textures and for each kind of pixels (TS_BIN_*: clusters' triangles,
// micro-triangles read from their kept points, micro-triangles diced again); the renderer picks them per bin. This source
// becomes a module per kind of pixels (TS_MODULE_PIXELS) and, but for micro-triangles diced again (whose displacement
// texture is read either way), per texturing (TS_MODULE_TEXTURED): shaders/CMakeLists.txt. lavapipe translates and
// optimizes all of a module's code before specialization drops what a variant does not run: one module for every kind
// took 0.45-0.6 s per variant, an untextured triangles' variant of its own module 24-35 ms.
const uint PIXELS = TS_MODULE_PIXELS;
#ifdef TS_MODULE_TEXTURED
const bool TEXTURED = TS_MODULE_TEXTURED;
#else
layout(constant_id = TS_SPEC_TEXTURES) const bool TEXTURED = false;
#endif
// The variant for frames with area lights or a textured dome (lights.h).
layout(constant_id = TS_SPEC_AREA_LIGHTS) const bool AREA_LIGHTS = false;
// The frame's lights (TS_SPEC_LIGHT_COUNTS): the distant ones first, then the others, in the frame's `lights`.
layout(constant_id = TS_SPEC_LIGHT_COUNTS) const uint LIGHT_COUNTS = 0u;
const uint DISTANT_LIGHTS = LIGHT_COUNTS & 0xffu, ALL_LIGHTS = LIGHT_COUNTS >> 8u;
// What this variant writes (TS_SPEC_OUTPUT): each AOV's slice of the output plus one, 0 where the frame has no such AOV;
// only the code of those it writes is compiled in.
layout(constant_id = TS_SPEC_OUTPUT) const uint OUTPUTS = 1u;  // the colour alone, shaded
const uint COLOR_OUT = TS_OUTPUT_FIELD(OUTPUTS, TS_AOV_COLOR), DEPTH_OUT = TS_OUTPUT_FIELD(OUTPUTS, TS_AOV_DEPTH),
           NORMAL_OUT = TS_OUTPUT_FIELD(OUTPUTS, TS_AOV_NORMAL), PRIM_ID_OUT = TS_OUTPUT_FIELD(OUTPUTS, TS_AOV_PRIM_ID),
           INSTANCE_ID_OUT = TS_OUTPUT_FIELD(OUTPUTS, TS_AOV_INSTANCE_ID), CLUSTER_ID_OUT = TS_OUTPUT_FIELD(OUTPUTS, TS_AOV_CLUSTER_ID),
           TRIANGLE_ID_OUT = TS_OUTPUT_FIELD(OUTPUTS, TS_AOV_TRIANGLE_ID);
const bool VISUALIZE = (OUTPUTS & TS_OUTPUT_VISUALIZE) != 0u;
// What the variant needs past the ids, the depth and the normal: the pixel's code stops at the last AOV it writes.
const bool PAST_IDS = COLOR_OUT != 0u || DEPTH_OUT != 0u || NORMAL_OUT != 0u;
const bool PAST_DEPTH = COLOR_OUT != 0u || NORMAL_OUT != 0u;
const bool COLOUR_ALONE = DEPTH_OUT == 0u && NORMAL_OUT == 0u && PRIM_ID_OUT == 0u && INSTANCE_ID_OUT == 0u && CLUSTER_ID_OUT == 0u &&
                          TRIANGLE_ID_OUT == 0u;
// The variant for materials with inputs from the vertex channel (GpuMaterial.vertexInputs != 0).
layout(constant_id = TS_SPEC_VERTEX_INPUTS) const bool VERTEX_INPUTS = false;
// Where this variant finds its pixels (TS_PIXELS_*): its bin's list, or every pixel of the frame, tile by tile (one bin,
// or every material with PIXEL_MATERIALS).
layout(constant_id = TS_SPEC_PIXEL_SOURCE) const uint PIXEL_SOURCE = TS_PIXELS_LISTED;
// Each pixel reads its own material (a CPU device's frames of several materials, shared.h), not binMaterial.
layout(constant_id = TS_SPEC_PIXEL_MATERIALS) const bool PIXEL_MATERIALS = false;

// The bin's material (push.material) and the frame's lights, copied by main() once, before its pixel loop: lavapipe loads
// push constants and the uniform block again for every batch of pixels where the loop reads them (the 1 px sphere's
// resolve 24.3 -> 19.4 ms, session 36). The lights are indexed by the light loops' counters, constant once the loops
// unroll (TS_SPEC_LIGHT_COUNTS): indexing the local copy of the whole frame by a variable made the compiler copy every
// light of it for each pixel (half of resolve's time, with two lights).
GpuMaterial binMaterial;
GpuLight frameLights[TS_MAX_LIGHTS];

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

// `patchIndex`: the micro-triangle's patch (0xffffffff for a cluster's own triangle); `largestFactor`: its triangle's.
vec3 visualize(GpuFrame frame, uint mode, Instance instance, uvec2 visible, GpuCluster cluster, uint triangle, bool software,
               uint material, uint patchIndex, uint micro, uint largestFactor) {
    bool diced = patchIndex != 0xffffffffu;
    // A micro-triangle's id from what it is (cluster, triangle, cell, index), not from its patch's list slot, which the
    // GPU hands out in no fixed order: the same frame shows the same colours.
    uint microId = diced ? ((visible.y * 128u + triangle) * 256u + (load_gpu_patch(frame, patchIndex).cell >> 8u)) * 256u + micro : 0u;
    if (mode == TS_VIS_RASTER_BINS) return diced ? vec3(0.25, 0.85, 0.3) : software ? vec3(0.15, 0.45, 1.0) : vec3(1.0, 0.55, 0.1);
    if (mode == TS_VIS_TESSELLATION) {
        if (!diced) return vec3(0.45);
        float shade = 0.8 + 0.2 * id_color(microId).x;  // neighbouring micro-triangles apart
        return level_color(uint(round(log2(float(largestFactor))))) * shade;  // 1 blue ... 256 red
    }
    if (mode == TS_VIS_TRIANGLES) return diced ? id_color(microId) : id_color(cluster.triangleOffset + triangle);
    if (mode == TS_VIS_CLUSTERS) return id_color(visible.y);
    if (mode == TS_VIS_GROUPS) return id_color(cluster.group == 0xffffffffu ? visible.y : cluster.group * 7919u + cluster.meshIndex);
    if (mode == TS_VIS_LOD) return level_color(cluster.levelVertices >> 16);
    if (mode == TS_VIS_INSTANCES) return id_color(visible.x);
    if (mode == TS_VIS_PRIMITIVES) return id_color(instance.primId);
    return id_color(material);  // TS_VIS_SHADING_BINS
}

// A pixel's texel of each AOV (those the variant does not write are left out by the compiler).
struct PixelOutputs {
    uvec4 color, depth, normal, primId, instanceId, clusterId, triangleId;
};

// What a pixel nothing covers holds (as renderer.cpp background_words): the background colour, infinite depth, a zero
// normal, no id.
PixelOutputs background_outputs(GpuFrame frame) {
    const uvec4 noId = uvec4(TS_BACKGROUND_ID), infinite = uvec4(TS_BACKGROUND_DEPTH_BITS);
    return PixelOutputs(floatBitsToUint(frame.background), infinite, uvec4(0u), noId, noId, noId, noId);
}

// Each AOV the variant writes into its slice of the output (`slice + 1` its OUTPUTS field), but the colour where `colour`
// is false.
void store_outputs(GpuFrame frame, uint index, PixelOutputs o, bool colour) {
    if (COLOR_OUT != 0u && colour) write_output(frame, COLOR_OUT - 1u, index, o.color);
    if (DEPTH_OUT != 0u) write_output(frame, DEPTH_OUT - 1u, index, o.depth);
    if (NORMAL_OUT != 0u) write_output(frame, NORMAL_OUT - 1u, index, o.normal);
    if (PRIM_ID_OUT != 0u) write_output(frame, PRIM_ID_OUT - 1u, index, o.primId);
    if (INSTANCE_ID_OUT != 0u) write_output(frame, INSTANCE_ID_OUT - 1u, index, o.instanceId);
    if (CLUSTER_ID_OUT != 0u) write_output(frame, CLUSTER_ID_OUT - 1u, index, o.clusterId);
    if (TRIANGLE_ID_OUT != 0u) write_output(frame, TRIANGLE_ID_OUT - 1u, index, o.triangleId);
}

// One covered pixel (`payloadBits`: the low word of its visibility value, which is not zero): every AOV the variant
// writes, into `o` (the caller stores them).
void shade(GpuFrame frame, uvec2 pixel, uint payloadBits, inout PixelOutputs o) {
    uint index = pixel.y * frame.viewport.x + pixel.x;
    bool overdraw = COLOR_OUT != 0u && VISUALIZE && frame.counts.w == TS_VIS_OVERDRAW;
    if (overdraw) {
        uint fragments = CounterRef(frame.overdraw).data[index];
        o.color = floatBitsToUint(vec4(level_color(max(fragments, 1u) - 1u), 1.0));
        if (COLOUR_ALONE) return;
    }

    // A bin of clusters' own triangles holds no micro-triangle: no patch to look up (a branch is not free on a CPU device).
    // A variant writing ids alone serves every kind of bin (pipelines.cpp: resolve_key), so it decodes micro-triangles too.
    Payload payload = PIXELS == TS_BIN_TRIANGLES && PAST_IDS ? Payload(payloadBits >> TS_VIS_TRIANGLE_BITS, payloadBits & ((1u << TS_VIS_TRIANGLE_BITS) - 1u), 0xffffffffu, 0u)
                                                 : decode_payload(frame, payloadBits);
    uint triangle = payload.triangle;
    uvec2 visible = visible_cluster(frame, payload.slot);
    bool software = (visible.x & TS_VISIBLE_SOFTWARE) != 0u;
    visible.x &= ~TS_VISIBLE_SOFTWARE;
    // The instance and cluster in full, for what the record leaves out (ids, visualizations, a pixel's own material);
    // a variant that writes none of those drops these loads (the compiler removes a fetch whose value goes unused).
    Instance instance = load_instance(frame, visible.x);
    GpuCluster cluster = load_cluster(frame, visible.y);
    // A cluster's own triangle is rebuilt from the cull's record of its cluster: the transform, flags and mesh, and the
    // cluster's vertex and triangle offsets, in 4 fetches (shared.h GpuVisibleRecord).
    Instance geometry = instance;
    if (PIXELS == TS_BIN_TRIANGLES) {
        GpuVisibleRecord record = load_visible_record(frame, payload.slot);
        geometry = record_instance(record);
        cluster.vertexOffset = record.vertexOffset;
        cluster.triangleOffset = record.triangleOffset;
    }
    o.primId = uvec4(instance.primId, 0u, 0u, 0u);
    o.instanceId = uvec4(visible.x, 0u, 0u, 0u);
    o.clusterId = uvec4(visible.y, 0u, 0u, 0u);
    o.triangleId = uvec4(cluster.triangleOffset + triangle, 0u, 0u, 0u);
    if (!PAST_IDS) return;

    GpuMesh mesh = load_mesh(frame, geometry.meshIndex);
    // The pixel's ray and where it meets the triangle's plane (the rasterizers' masks use the same code); for a
    // micro-triangle of a displaced surface, the micro-triangle rebuilt as the patch raster made it.
    PixelTriangle hitTriangle;
    vec3 sourceBary;     // barycentrics on the cluster's triangle: colours and normals are interpolated with them
    vec2 cornerUv[3];    // texture coordinates at the corners of the triangle hit (micro or not)
    const bool diced = PIXELS != TS_BIN_TRIANGLES;  // classify sent this bin micro-triangles only, or none
    uint largestFactor = 1u;
    if (diced) {
        // The points the compute patch rasterizer kept (it keeps none where vertex colours need the corners' weights),
        // else the micro-triangle diced again, as the patch rasterizer diced it.
        MicroTriangle m;
        if (PIXELS == TS_BIN_KEPT_MICRO) {
            kept_micro_triangle(frame, payload.patchIndex, payload.micro, pixel, m);
            m.t.v0 = m.t.v1 = m.t.v2 = 0u;  // not read: no vertex colours, and the normal is the micro-triangle's own
        } else {
            m = pixel_micro_triangle(frame, payload.patchIndex, payload.micro, pixel);
        }
        hitTriangle = m.t;
        largestFactor = m.largestFactor;
        cornerUv = m.uv;
        sourceBary = m.t.bary.x * m.w[0] + m.t.bary.y * m.w[1] + m.t.bary.z * m.w[2];
    } else {
        hitTriangle = pixel_triangle(frame, geometry, cluster, triangle, pixel);
        sourceBary = hitTriangle.bary;
        if (mesh.uvOffset != TS_NO_STREAM)
            cornerUv = vec2[3](vertex_uv(frame, mesh, hitTriangle.v0), vertex_uv(frame, mesh, hitTriangle.v1), vertex_uv(frame, mesh, hitTriangle.v2));
    }
    uint v0 = hitTriangle.v0, v1 = hitTriangle.v1, v2 = hitTriangle.v2;
    vec3 p0 = hitTriangle.p0, e1 = hitTriangle.e1, e2 = hitTriangle.e2;
    vec3 origin = hitTriangle.origin, direction = hitTriangle.direction, bary = hitTriangle.bary;
    float t = dot(p0 - origin, cross(e1, e2)) / dot(direction, cross(e1, e2));
    if (!(t > 0.0) || isinf(t)) t = 0.0;  // edge-on triangle: the plane test is meaningless
    vec3 hit = origin + t * direction;

    o.depth = floatBitsToUint(vec4(dot(hit, frame.cameraForward.xyz)));
    if (!PAST_DEPTH) return;

    vec3 geometric = normalize(cross(e1, e2));
    vec3 n = geometric;  // a micro-triangle's own normal is the displaced surface's
    if (!diced) {
        // The inverse transpose up to a positive scale (normalized below): the cofactor matrix, its sign the
        // determinant's. Three cross products instead of a general inverse per pixel.
        mat3 toWorld = transpose(mat3(geometry.rows[0].xyz, geometry.rows[1].xyz, geometry.rows[2].xyz));
        vec3 a = toWorld[0], b = toWorld[1], c = toWorld[2];
        mat3 normalMatrix = mat3(cross(b, c), cross(c, a), cross(a, b)) * (dot(a, cross(b, c)) < 0.0 ? -1.0 : 1.0);
        vec3 objectNormal = bary.x * decode_octahedral(vertex_normal_bits(frame, v0)) + bary.y * decode_octahedral(vertex_normal_bits(frame, v1)) +
                            bary.z * decode_octahedral(vertex_normal_bits(frame, v2));
        n = normalize(normalMatrix * objectNormal);
    }
    if (dot(geometric, direction) > 0.0) {  // the back of a double-sided surface: shade its other side
        geometric = -geometric;
        n = -n;
    }
    if (dot(n, geometric) < 0.0) n = geometric;  // an interpolated normal facing away would shade black
    o.normal = floatBitsToUint(vec4(n, 1.0));
    if (COLOR_OUT == 0u || overdraw) return;
    // This dispatch's bin (one material, or a displaced material's kind of pixels), else the pixel's own material.
    uint bin = PIXEL_MATERIALS ? pixel_material(frame, instance, visible.y, triangle) : push.step;

    if (VISUALIZE) {  // flat id colours, lit from the eye so that shapes stay readable
        if (frame.counts.w == TS_VIS_UV) {  // data, not a picture: unlit
            vec3 uvColor = vec3(1.0, 0.0, 1.0);
            if (mesh.uvOffset != TS_NO_STREAM) {
                PixelUv uv = pixel_uv(frame, vec2(pixel), bary, p0, e1, e2, cornerUv[0], cornerUv[1], cornerUv[2]);
                uvColor = vec3(fract(uv.uv), 0.0);
            }
            o.color = floatBitsToUint(vec4(uvColor, 1.0));
            return;
        }
        vec3 tint = visualize(frame, frame.counts.w, instance, visible, cluster, triangle, software, bin, payload.patchIndex, payload.micro,
                              largestFactor);
        o.color = floatBitsToUint(vec4(tint * (0.3 + 0.7 * abs(dot(geometric, direction))), 1.0));
        return;
    }

    GpuMaterial material = binMaterial;
    if (PIXEL_MATERIALS) material = load_material(frame, bin);
    vec3 albedo = material.diffuseColor.rgb;
    vec3 emission = material.emissiveColor.rgb, f0 = material.specular.rgb;
    float occlusion = material.emissiveColor.a, roughness = material.specular.a, metallic = material.metallic;
    // Inputs the mesh's vertex channel drives (displayColor, primvar readers), interpolated over the surface.
    if (VERTEX_INPUTS && PIXELS != TS_BIN_KEPT_MICRO && mesh.colorOffset != TS_NO_STREAM) {
        vec4 channel = interpolated_channel(frame, mesh, sourceBary, v0, v1, v2);
        uint inputs = material.vertexInputs;
        albedo = vertex_input(inputs, TS_INPUT_DIFFUSE_COLOR, channel, albedo);
        emission = vertex_input(inputs, TS_INPUT_EMISSIVE_COLOR, channel, emission);
        f0 = vertex_input(inputs, TS_INPUT_SPECULAR_COLOR, channel, f0);  // mapped in the specular workflow only
        metallic = clamp(vertex_input(inputs, TS_INPUT_METALLIC, channel, vec3(metallic)).x, 0.0, 1.0);
        roughness = clamp(vertex_input(inputs, TS_INPUT_ROUGHNESS, channel, vec3(roughness)).x, 0.0, 1.0);
        occlusion = clamp(vertex_input(inputs, TS_INPUT_OCCLUSION, channel, vec3(occlusion)).x, 0.0, 1.0);
    }

    // Textured inputs replace their constants (only in the textured variant: no texture code at all for the others).
    // Opacity is not among them here: masks are cut by the rasterizers.
    if (TEXTURED && material.textureInputs != 0u) {
        PixelUv uv = mesh.uvOffset == TS_NO_STREAM ? PixelUv(vec2(0.0), vec2(0.0), vec2(0.0))
                                                    : pixel_uv(frame, vec2(pixel), bary, p0, e1, e2, cornerUv[0], cornerUv[1], cornerUv[2]);
        // One sample per textured input, in a loop: the trip count is the bin's (uniform), where a branch per input
        // would run every input's sampling masked on lavapipe, textured or not.
        uint slot = material.firstTextureSlot;
        vec3 tangentNormal = vec3(0.0);
        for (uint inputs = material.textureInputs; inputs != 0u; inputs &= inputs - 1u, ++slot) {
            uint textured = uint(findLSB(inputs));
            if (textured == TS_INPUT_OPACITY || textured == TS_INPUT_DISPLACEMENT) continue;  // cut by the rasterizers, diced
            vec4 v = texture_slot_value(frame.textures, load_texture_slot(frame, slot), uv.uv, uv.dx, uv.dy);
            if (textured == TS_INPUT_DIFFUSE_COLOR) albedo = v.rgb;
            else if (textured == TS_INPUT_EMISSIVE_COLOR) emission = v.rgb;
            else if (textured == TS_INPUT_SPECULAR_COLOR) f0 = v.rgb;
            else if (textured == TS_INPUT_METALLIC) metallic = clamp(v.x, 0.0, 1.0);
            else if (textured == TS_INPUT_ROUGHNESS) roughness = clamp(v.x, 0.0, 1.0);
            else if (textured == TS_INPUT_OCCLUSION) occlusion = clamp(v.x, 0.0, 1.0);
            else tangentNormal = v.xyz;  // TS_INPUT_NORMAL
        }
        if ((material.textureInputs & (1u << TS_INPUT_NORMAL)) != 0u && mesh.uvOffset != TS_NO_STREAM) {
            n = apply_normal_map(n, tangentNormal, e1, e2, cornerUv[0], cornerUv[1], cornerUv[2]);
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
    // Each light from main()'s copy of the frame's (frameLights). Distant lights first, then the others, each loop with
    // only its kind's code (no shadowing yet). Unrolled, so that the copy is indexed by constants (a local array indexed
    // by a variable would live in scratch memory).
    [[unroll]] for (uint i = 0u; i < DISTANT_LIGHTS; ++i)
        color += distant_light_contribution(frameLights[i], n, toEye, albedo, f0, roughness);
    [[unroll]] for (uint i = DISTANT_LIGHTS; i < ALL_LIGHTS; ++i)
        color += other_light_contribution(frame, frameLights[i], hit, n, toEye, albedo, f0, roughness, occlusion, AREA_LIGHTS);
    o.color = floatBitsToUint(vec4(color, 1.0));
}

// TS_PIXELS_PACKED: each subgroup's covered pixels (the payload, the position), in its own part. Sized for at most
// TS_PACKED_MOST_PIXELS_PER_THREAD pixels per thread: the renderer packs no frame of more (renderer.cpp: pixelSource).
const uint PACKED_PIXELS = TS_SHADE_GROUP_SIZE * (PIXELS_PER_THREAD < TS_PACKED_MOST_PIXELS_PER_THREAD ? PIXELS_PER_THREAD : TS_PACKED_MOST_PIXELS_PER_THREAD);
shared uint packedPayload[PACKED_PIXELS];
shared uint packedPixel[PACKED_PIXELS];

void main() {
    GpuFrame frame = frameConstants;
    binMaterial = push.material;
    [[unroll]] for (uint i = 0u; i < ALL_LIGHTS; ++i) frameLights[i] = frameConstants.lights[i];
    if (PIXEL_SOURCE != TS_PIXELS_LISTED) {
        // A row of PIXELS_PER_THREAD tiles of TS_PIXEL_TILE x TS_PIXEL_TILE pixels per workgroup, each thread a pixel of
        // each tile (TS_SHADE_GROUP_SIZE is a tile's pixels), the rows spread over lavapipe's threads (shared.h). Shifts,
        // not a division per pixel: lavapipe divides lane by lane (a division per pixel cost a screen-filling frame as much
        // as classify saved; spread_index's two per thread cost nothing measurable). Each subgroup counts its covered
        // pixels: the frame's coverage, by which the renderer picks the next frame's pixel source.
        uvec2 group = uvec2(gl_WorkGroupID.x, spread_index(gl_WorkGroupID.y, gl_NumWorkGroups.y));
        uvec2 pixel = group * uvec2(TS_PIXEL_TILE * PIXELS_PER_THREAD, TS_PIXEL_TILE) +
                      uvec2(gl_LocalInvocationIndex % TS_PIXEL_TILE, gl_LocalInvocationIndex / TS_PIXEL_TILE);
        uint covered = 0u;  // the same in every lane: no lane leaves the loop before the others
        uint part = gl_SubgroupID * gl_SubgroupSize * PIXELS_PER_THREAD;
        uint k = 0u;
        [[dont_unroll]] do {  // the test at the end (frame.h)
            bool inside = all(lessThan(pixel, frame.viewport.xy));
            uint index = pixel.y * frame.viewport.x + pixel.x;
            uint64_t value = inside ? visibility_value(frame, index) : 0ul;
            uvec4 lanes = subgroupBallot(value != 0ul);
            if (PIXEL_SOURCE == TS_PIXELS_PACKED) {
                if (value != 0ul) {
                    uint at = part + covered + subgroupBallotExclusiveBitCount(lanes);
                    packedPayload[at] = uint(value);
                    packedPixel[at] = pixel.x | (pixel.y << 16u);
                }
            } else if (inside) {
                // Every pixel stored, the covered ones shaded and the others given the background: one store for both
                // (lavapipe runs a store as a loop over the lanes whichever of them store), in place of a fill before.
                PixelOutputs o = background_outputs(frame);
                if (value != 0ul) shade(frame, pixel, uint(value), o);
                store_outputs(frame, index, o, value != 0ul || (frame.counts.z & TS_FRAME_DOME_BACKGROUND) == 0u);
            }
            covered += subgroupBallotBitCount(lanes);
            pixel.x += TS_PIXEL_TILE;
        } while (++k < PIXELS_PER_THREAD);
        if (PIXEL_SOURCE == TS_PIXELS_PACKED) {
            subgroupBarrier();  // the subgroup's stores to its part, seen by all its lanes
            uint i = gl_SubgroupInvocationID;
            [[dont_unroll]] do {
                if (i < covered) {
                    uint xy = packedPixel[part + i];
                    uvec2 at = uvec2(xy & 0xffffu, xy >> 16u);
                    PixelOutputs o = background_outputs(frame);
                    shade(frame, at, packedPayload[part + i], o);
                    store_outputs(frame, at.y * frame.viewport.x + at.x, o, true);
                }
            } while ((i += gl_SubgroupSize) < covered);
        }
        if (subgroupElect() && covered != 0u) atomicAdd(DrawStateRef(frame.drawState).state.coveredPixels, covered);
        return;
    }
    // The bin's pixels TS_SHADE_GROUP_SIZE apart, PIXELS_PER_THREAD of them (the same trip count for every thread).
    GpuBin bin = BinRef(frame.bins).data[push.step];
    uint group = spread_index(gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x, gl_NumWorkGroups.x * gl_NumWorkGroups.y);
    uint first = group * TS_SHADE_GROUP_SIZE * PIXELS_PER_THREAD + gl_LocalInvocationIndex;
    uint k = 0u;
    [[dont_unroll]] do {  // the test at the end (frame.h)
        uint i = first + k * TS_SHADE_GROUP_SIZE;
        if (i >= bin.count) return;
        uvec2 pixel = unpack_bin_pixel(bin_pixel_entry(frame, bin.offset + i));
        uint index = pixel.y * frame.viewport.x + pixel.x;
        PixelOutputs o = background_outputs(frame);
        shade(frame, pixel, uint(visibility_value(frame, index)), o);
        store_outputs(frame, index, o, true);
    } while (++k < PIXELS_PER_THREAD);
}
