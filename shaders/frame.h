// GLSL side of shared.h: buffer references to the frame's data and helpers used by several passes.
// Include after `#extension GL_GOOGLE_include_directive : require`.
//
// Loops in the hot passes test at their end (do { } while), the first pass guarded where a lane may have nothing to do:
// lavapipe runs a loop as long as any lane is in it, testing at the end of the body, so a loop that tests at its start
// runs its whole body once more, every lane masked, after the last lane has left. That pass cost the 1e10 field's compute
// rasterizer 13 % of its time (docs/benchmarks.md, session 30); on a GPU both forms are the same loop.
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#include "shared.h"
#define TESSERA_FRAME_H  // texture.h reads the pool through the frame set's views when included after this

layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer InstanceRef { GpuInstance data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer InstanceBatchRef { GpuInstanceBatch data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer MeshRef { GpuMesh data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer ClusterRef { GpuCluster data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer VertexRef { GpuVertex data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer LevelRef { GpuLevel data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer CutBlockRef { GpuCutBlock data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer MaterialRef { GpuMaterial data[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer FloatRef { float data[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer UintRef { uint data[]; };
layout(buffer_reference, std430, buffer_reference_align = 8) buffer VisibleClusterRef { uvec2 data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) buffer VisibleRecordRef { GpuVisibleRecord data[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) buffer SlotListRef { uint data[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) buffer CounterRef { uint data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) buffer BinRef { GpuBin data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) buffer DrawStateRef { GpuDrawState state; };
layout(buffer_reference, std430, buffer_reference_align = 8) buffer VisibilityRef { uint64_t data[]; };

layout(buffer_reference, std430, buffer_reference_align = 4) buffer HzbRef { float data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) buffer PatchRef { GpuPatch data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) buffer PatchDrawRef { uvec4 data[]; };  // VkDrawIndirectCommand
layout(buffer_reference, std430, buffer_reference_align = 4) buffer PatchPointRef { float data[]; };

// The frame's constants (renderer.cpp: frameSet). A uniform block rather than a buffer reference: a CPU device
// (lavapipe) loads it once per SIMD batch, where it loads through an address lane by lane. Passes copy it into a local
// `frame`; arrays indexed by a variable (lights, frustum planes) are read from frameConstants itself (see lights in
// resolve.comp.glsl).
layout(set = 0, binding = 0, std140) uniform FrameBlock { GpuFrame frameConstants; };

// layout: renderer.cpp PushConstants (and ResolvePushConstants). `step`: the cull step (TS_CULL_*), the HZB level being
// built or resolve's material; `hzb`: the HZB that step tests against or builds; `material`: resolve's, GpuMaterial
// data[step] (only resolve's dispatches push it). samples.comp.glsl reads them as its own (see there).
layout(push_constant) uniform Push { uint aov; uint step; HzbRef hzb; GpuMaterial material; } push;

// Nearest and farthest view depth of a sphere (camera-relative world).
vec2 depth_range(GpuFrame frame, vec3 center, float radius) {
    float d = dot(center, frame.cameraForward.xyz);
    return vec2(d - radius, d + radius);
}

// An instance as the passes see it: its transform (camera-relative) with its batch's mesh, prim, material and flags.
struct Instance {
    vec4 rows[3];          // xyz: rows of the linear part of mesh -> world
    vec3 translation;      // relative to the camera
    uint meshIndex;
    uint primId;
    uint materialIndex;
    uint flags;            // TS_INSTANCE_*
    uint displacementBounds;  // GpuInstanceBatch.displacementBounds
};

// The streams read per pixel, per triangle or per vertex, through texel buffer views (shared.h TS_VIEW_*) in the
// variants with TEXEL_VIEWS, else through their addresses. Every loader below gives the same bits either way; the
// struct loaders follow shared.h's layouts, 16 bytes a texel (a fetch the caller's code leaves unused is dropped).
layout(constant_id = TS_SPEC_TEXEL_VIEWS) const bool TEXEL_VIEWS = false;
layout(set = 0, binding = TS_VIEW_INSTANCES) uniform usamplerBuffer instanceTexels;
layout(set = 0, binding = TS_VIEW_BATCHES) uniform usamplerBuffer batchTexels;
layout(set = 0, binding = TS_VIEW_INSTANCE_BATCHES) uniform usamplerBuffer instanceBatchTexels;
layout(set = 0, binding = TS_VIEW_CLUSTERS) uniform usamplerBuffer clusterTexels;
layout(set = 0, binding = TS_VIEW_MESHES) uniform usamplerBuffer meshTexels;
layout(set = 0, binding = TS_VIEW_VERTICES) uniform usamplerBuffer vertexTexels;
layout(set = 0, binding = TS_VIEW_TRIANGLES) uniform usamplerBuffer triangleTexels;
layout(set = 0, binding = TS_VIEW_VISIBLE_CLUSTERS) uniform usamplerBuffer visibleClusterTexels;
layout(set = 0, binding = TS_VIEW_VISIBILITY) uniform usamplerBuffer visibilityTexels;
layout(set = 0, binding = TS_VIEW_BIN_PIXELS) uniform usamplerBuffer binPixelTexels;
layout(set = 0, binding = TS_VIEW_LEVELS) uniform usamplerBuffer levelTexels;
layout(set = 0, binding = TS_VIEW_CUT_BLOCKS) uniform usamplerBuffer cutBlockTexels;
layout(set = 0, binding = TS_VIEW_BLOCK_CLUSTERS) uniform usamplerBuffer blockClusterTexels;
layout(set = 0, binding = TS_VIEW_HZB) uniform usamplerBuffer hzbTexels;
layout(set = 0, binding = TS_VIEW_TEXTURE_SLOTS) uniform usamplerBuffer textureSlotTexels;
layout(set = 0, binding = TS_VIEW_TEXTURE_WORDS) uniform usamplerBuffer textureWordTexels;
layout(set = 0, binding = TS_VIEW_UVS) uniform usamplerBuffer uvTexels;
layout(set = 0, binding = TS_VIEW_COLORS) uniform usamplerBuffer colorTexels;
layout(set = 0, binding = TS_VIEW_PATCHES) uniform usamplerBuffer patchTexels;
layout(set = 0, binding = TS_VIEW_PATCH_POINTS) uniform usamplerBuffer patchPointTexels;
layout(set = 0, binding = TS_VIEW_MATERIALS) uniform usamplerBuffer materialTexels;
layout(set = 0, binding = TS_VIEW_MATERIAL_TABLES) uniform usamplerBuffer materialTableTexels;
layout(set = 0, binding = TS_VIEW_VISIBLE_RECORDS) uniform usamplerBuffer visibleRecordTexels;

GpuCluster load_cluster(GpuFrame frame, uint index) {
    if (!TEXEL_VIEWS) return ClusterRef(frame.clusters).data[index];
    int at = int(6u * index);
    uvec4 t3 = texelFetch(clusterTexels, at + 3), t4 = texelFetch(clusterTexels, at + 4), t5 = texelFetch(clusterTexels, at + 5);
    GpuCluster c;
    c.sphere = uintBitsToFloat(texelFetch(clusterTexels, at));
    c.lodSphere = uintBitsToFloat(texelFetch(clusterTexels, at + 1));
    c.parentSphere = uintBitsToFloat(texelFetch(clusterTexels, at + 2));
    c.lodError = uintBitsToFloat(t3.x);
    c.parentError = uintBitsToFloat(t3.y);
    c.vertexOffset = t3.z;
    c.triangleOffset = t3.w;
    c.triangleCount = t4.x;
    c.meshIndex = t4.y;
    c.levelVertices = t4.z;
    c.group = t4.w;
    c.meanTriangleArea = uintBitsToFloat(t5.x);
    c.normalCone = t5.y;
    c.longestEdge = uintBitsToFloat(t5.z);
    c.pad1 = t5.w;
    return c;
}

GpuMesh load_mesh(GpuFrame frame, uint index) {
    if (!TEXEL_VIEWS) return MeshRef(frame.meshes).data[index];
    int at = int(4u * index);
    uvec4 t1 = texelFetch(meshTexels, at + 1), t2 = texelFetch(meshTexels, at + 2), t3 = texelFetch(meshTexels, at + 3);
    GpuMesh m;
    m.sphere = uintBitsToFloat(texelFetch(meshTexels, at));
    m.clusterOffset = t1.x;
    m.clusterCount = t1.y;
    m.colorOffset = t1.z;
    m.vertexOffset = t1.w;
    m.levelOffset = t2.x;
    m.levelCount = t2.y;
    m.leafClusterCount = t2.z;
    m.lodRadius = uintBitsToFloat(t2.w);
    m.uvOffset = t3.x;
    m.displacementNormalOffset = t3.y;
    m.seamVertexOffset = t3.z;
    m.seamTriangleOffset = t3.w;
    return m;
}

GpuLevel load_level(GpuFrame frame, uint index) {
    if (!TEXEL_VIEWS) return LevelRef(frame.levels).data[index];
    int at = int(3u * index);
    uvec2 t0 = texelFetch(levelTexels, at).xy, t1 = texelFetch(levelTexels, at + 1).xy, t2 = texelFetch(levelTexels, at + 2).xy;
    GpuLevel l;
    l.clusterOffset = t0.x;
    l.clusterCount = t0.y;
    l.minLodError = uintBitsToFloat(t1.x);
    l.maxParentError = uintBitsToFloat(t1.y);
    l.blockOffset = t2.x;
    l.blockCount = t2.y;
    return l;
}

GpuCutBlock load_cut_block(GpuFrame frame, uint index) {
    if (!TEXEL_VIEWS) return CutBlockRef(frame.cutBlocks).data[index];
    int at = int(4u * index);
    uvec4 t3 = texelFetch(cutBlockTexels, at + 3);
    GpuCutBlock b;
    b.sphere = uintBitsToFloat(texelFetch(cutBlockTexels, at));
    b.lodSphere = uintBitsToFloat(texelFetch(cutBlockTexels, at + 1));
    b.parentSphere = uintBitsToFloat(texelFetch(cutBlockTexels, at + 2));
    b.minLodError = uintBitsToFloat(t3.x);
    b.maxParentError = uintBitsToFloat(t3.y);
    b.firstCluster = t3.z;
    b.clusterCount = t3.w;
    return b;
}

// Material `index` of the frame's materials (resolve gets its bin's in push constants; the rasterizers' masks, the
// cull and tessellation read them here).
GpuMaterial load_material(GpuFrame frame, uint index) {
    if (!TEXEL_VIEWS) return MaterialRef(frame.materials).data[index];
    int at = int(7u * index);
    uvec4 t3 = texelFetch(materialTexels, at + 3), t6 = texelFetch(materialTexels, at + 6);
    GpuMaterial m;
    m.diffuseColor = uintBitsToFloat(texelFetch(materialTexels, at));
    m.emissiveColor = uintBitsToFloat(texelFetch(materialTexels, at + 1));
    m.specular = uintBitsToFloat(texelFetch(materialTexels, at + 2));
    m.metallic = uintBitsToFloat(t3.x);
    m.flags = t3.y;
    m.firstTextureSlot = t3.z;
    m.textureInputs = t3.w;
    m.displacement = uintBitsToFloat(texelFetch(materialTexels, at + 4));
    m.displacementFade = uintBitsToFloat(texelFetch(materialTexels, at + 5));
    m.vertexInputs = t6.x;
    m.unused0 = t6.y;
    m.unused1 = t6.z;
    m.unused2 = t6.w;
    return m;
}

// Entry i of frame.materialTables.
uint material_table_entry(GpuFrame frame, uint i) {
    return TEXEL_VIEWS ? texelFetch(materialTableTexels, int(i)).x : UintRef(frame.materialTables).data[i];
}

// A tessellation patch's record (written by the tessellation pass before the pass that reads it).
GpuPatch load_gpu_patch(GpuFrame frame, uint index) {
    if (!TEXEL_VIEWS) return PatchRef(frame.patches).data[index];
    uvec4 t0 = texelFetch(patchTexels, int(2u * index)), t1 = texelFetch(patchTexels, int(2u * index + 1u));
    return GpuPatch(t0.x, t0.y, t0.z, t0.w, t1.x, t1.y, t1.z, t1.w);
}

// Float i of the points the compute patch rasterizer kept (GpuPatch.points).
float patch_point_float(GpuFrame frame, uint i) {
    return TEXEL_VIEWS ? uintBitsToFloat(texelFetch(patchPointTexels, int(i)).x) : PatchPointRef(frame.patchPoints).data[i];
}

// Entry i of frame.blockClusters: a cluster of a cut block, counted from its mesh's first.
uint block_cluster(GpuFrame frame, uint i) {
    return TEXEL_VIEWS ? texelFetch(blockClusterTexels, int(i)).x : UintRef(frame.blockClusters).data[i];
}

GpuInstance load_gpu_instance(GpuFrame frame, uint index) {
    if (!TEXEL_VIEWS) return InstanceRef(frame.instances).data[index];
    GpuInstance g;
    for (int k = 0; k < 3; ++k) g.rows[k] = uintBitsToFloat(texelFetch(instanceTexels, int(3u * index) + k));
    return g;
}

uint instance_batch_word(GpuFrame frame, uint index) {
    return TEXEL_VIEWS ? texelFetch(instanceBatchTexels, int(index)).x : UintRef(frame.instanceBatches).data[index];
}

GpuInstanceBatch load_batch(GpuFrame frame, uint index) {
    if (!TEXEL_VIEWS) return InstanceBatchRef(frame.batches).data[index];
    int at = int(4u * index);
    uvec4 t2 = texelFetch(batchTexels, at + 2), t3 = texelFetch(batchTexels, at + 3);
    GpuInstanceBatch b;
    b.originHigh = uintBitsToFloat(texelFetch(batchTexels, at));
    b.originLow = uintBitsToFloat(texelFetch(batchTexels, at + 1));
    b.meshIndex = t2.x;
    b.primId = t2.y;
    b.materialIndex = t2.z;
    b.flags = t2.w;
    b.displacementBounds = t3.x;
    b.pad0 = t3.y;
    b.pad1 = t3.z;
    b.pad2 = t3.w;
    return b;
}

// A vertex's position bits and packed normal (GpuVertex): one texel, which a caller reading the position and the normal
// of one vertex fetches once.
uvec4 vertex_bits(GpuFrame frame, uint vertex) {
    return TEXEL_VIEWS ? texelFetch(vertexTexels, int(vertex)) : VertexRef(frame.vertices).data[vertex].bits;
}

// The packed normal of a vertex (decode_octahedral).
uint vertex_normal_bits(GpuFrame frame, uint vertex) { return vertex_bits(frame, vertex).w; }

// A pixel's visibility value (the rasterizers write it with atomics, through its address).
uint64_t visibility_value(GpuFrame frame, uint pixel) {
    return TEXEL_VIEWS ? packUint2x32(texelFetch(visibilityTexels, int(pixel)).xy) : VisibilityRef(frame.visibility).data[pixel];
}

// Texel i of the HZB the step tests against or builds (push.hzb: every level, level 0 first).
float hzb_texel(uint i) { return TEXEL_VIEWS ? uintBitsToFloat(texelFetch(hzbTexels, int(i)).x) : push.hzb.data[i]; }

// Entry i of frame.binPixels (pack_bin_pixel).
uint bin_pixel_entry(GpuFrame frame, uint i) {
    return TEXEL_VIEWS ? texelFetch(binPixelTexels, int(i)).x : CounterRef(frame.binPixels).data[i];
}

Instance load_instance(GpuFrame frame, uint index) {
    GpuInstance g = load_gpu_instance(frame, index);
    uint batchWord = instance_batch_word(frame, index);
    GpuInstanceBatch batch = load_batch(frame, batchWord & TS_INSTANCE_BATCH_MASK);
    Instance instance;
    instance.rows = g.rows;
    // The batch origin's high part plus the instance's offset first: an instance near the camera has an offset that
    // nearly cancels the high part (exactly, in float), and only then the low part, which (high + low) would round away
    // where the origin lies far from the camera (test_world_space_instances_far_from_their_instancer_...).
    precise vec3 nearCamera = batch.originHigh.xyz + vec3(g.rows[0].w, g.rows[1].w, g.rows[2].w);
    precise vec3 translation = nearCamera + batch.originLow.xyz;
    instance.translation = translation;
    instance.meshIndex = batch.meshIndex;
    instance.primId = batch.primId;
    instance.materialIndex = batch.materialIndex;
    instance.displacementBounds = batch.displacementBounds;
    instance.flags = batch.flags | ((batchWord & TS_INSTANCE_BATCH_FLIP) != 0u ? TS_INSTANCE_FLIP_WINDING : 0u) |
                     ((batchWord & TS_INSTANCE_BATCH_CONFORMAL) != 0u ? TS_INSTANCE_CONFORMAL : 0u);
    return instance;
}

// Instance translation relative to the camera (the batch origin subtracted in double on the CPU).
vec3 camera_relative_translation(Instance instance) { return instance.translation; }

// Mesh-space point -> camera-relative world.
vec3 to_camera_relative(Instance instance, vec3 translation, vec3 p) {
    return vec3(dot(instance.rows[0].xyz, p), dot(instance.rows[1].xyz, p), dot(instance.rows[2].xyz, p)) + translation;
}

vec3 vertex_position(GpuFrame frame, uint vertex) { return uintBitsToFloat(vertex_bits(frame, vertex).xyz); }

// A packed triangle of the scene's triangle stream: three 8-bit cluster-local corners, the material slot above.
uint triangle_word(GpuFrame frame, uint index) {
    return TEXEL_VIEWS ? texelFetch(triangleTexels, int(index)).x : UintRef(frame.triangles).data[index];
}

// The vertices of a triangle's three corners. The winding is reversed for flipped instances so that every triangle
// reaches the rasterizer counter-clockwise when seen from its front. All three from one load of the packed triangle,
// not one load per corner (on a CPU device every load of a per-pixel address is a loop over the lanes).
uvec3 triangle_vertices(GpuFrame frame, GpuCluster cluster, uint triangle, bool flip) {
    uint packed = triangle_word(frame, cluster.triangleOffset + triangle);
    uvec3 v = cluster.vertexOffset + (uvec3(packed, packed >> 8u, packed >> 16u) & 0xffu);
    return flip ? v.xzy : v;
}

// The vertex of one corner (the hardware rasterizer's vertex shader: one corner per invocation).
uint corner_vertex(GpuFrame frame, GpuCluster cluster, uint triangle, uint corner, bool flip) {
    return triangle_vertices(frame, cluster, triangle, flip)[corner];
}

// Largest factor by which the instance transform stretches a length: the square root of the largest eigenvalue of
// A^T A (A the linear part), in closed form (Smith's trigonometric solution for symmetric 3x3 matrices, as the CPU did).
float instance_scale(Instance instance) {
    mat3 a = transpose(mat3(instance.rows[0].xyz, instance.rows[1].xyz, instance.rows[2].xyz));  // columns = A's columns
    mat3 c = transpose(a) * a;
    float p1 = c[0][1] * c[0][1] + c[0][2] * c[0][2] + c[1][2] * c[1][2];
    float largest;
    if (p1 == 0.0) {
        largest = max(c[0][0], max(c[1][1], c[2][2]));
    } else {
        float q = (c[0][0] + c[1][1] + c[2][2]) / 3.0;
        float p2 = (c[0][0] - q) * (c[0][0] - q) + (c[1][1] - q) * (c[1][1] - q) + (c[2][2] - q) * (c[2][2] - q) + 2.0 * p1;
        float p = sqrt(p2 / 6.0);
        mat3 b = (c - q * mat3(1.0)) / p;
        float r = clamp(determinant(b) / 2.0, -1.0, 1.0);
        largest = q + 2.0 * p * cos(acos(r) / 3.0);
    }
    return sqrt(max(largest, 0.0)) * 1.000002;  // a hair above: float rounding must not shrink bounds
}

// The planes are read from the uniform block, not from the caller's copy `frame`: a copy's array indexed by a
// variable is copied whole into scratch memory for each invocation (on lavapipe, lane by lane).
bool sphere_in_frustum(GpuFrame frame, vec3 center, float radius) {
    for (int i = 0; i < 6; ++i)
        if (dot(frameConstants.frustumPlanes[i].xyz, center) + frameConstants.frustumPlanes[i].w < -radius) return false;
    return true;
}

// HZB levels: level l has a texel per 2^(l+1) x 2^(l+1) pixels (partial at the right and bottom edges), down to 1x1;
// the levels are stored one after another.
// Shifts, not divisions: a CPU device divides integers one lane at a time (x86 has no vector integer division).
uvec2 hzb_level_size(GpuFrame frame, uint level) {
    uint tile = 2u << level;
    return (frame.viewport.xy + tile - 1u) >> (level + 1u);
}

uint hzb_level_offset(GpuFrame frame, uint level) {
    uint offset = 0u;
    for (uint l = 0u; l < level; ++l) {
        uvec2 size = hzb_level_size(frame, l);
        offset += size.x * size.y;
    }
    return offset;
}

// frame.binPixels entries: a covered pixel's coordinates, x in the low 16 bits (resolutions are at most 16384 across).
// Coordinates rather than the pixel's index, which resolve would have to divide by the width.
uint pack_bin_pixel(uvec2 pixel) { return pixel.x | (pixel.y << 16u); }
uvec2 unpack_bin_pixel(uint packed) { return uvec2(packed & 0xffffu, packed >> 16u); }

// Pixel `index` of an AOV slice of the output, through its storage buffer binding (TS_BINDING_OUTPUT + slice) in the
// variants with it (TS_SPEC_OUTPUT_BINDING), else through its address: lavapipe stores through an address in a loop over
// the lanes for each component, a vec4 four loops, to a storage buffer in one loop for all four. On one core, 2 M pixels of a
// constant (with the 5 ms background fill): 55 ms through the address as a vec4, 20 ms as two 64-bit words, 15 ms
// through the binding. A GPU writes the same bytes either way.
layout(set = 0, binding = TS_BINDING_OUTPUT + 0, std430) buffer AovOutput0 { uvec4 aovPixels0[]; };
layout(set = 0, binding = TS_BINDING_OUTPUT + 1, std430) buffer AovOutput1 { uvec4 aovPixels1[]; };
layout(set = 0, binding = TS_BINDING_OUTPUT + 2, std430) buffer AovOutput2 { uvec4 aovPixels2[]; };
layout(set = 0, binding = TS_BINDING_OUTPUT + 3, std430) buffer AovOutput3 { uvec4 aovPixels3[]; };
layout(set = 0, binding = TS_BINDING_OUTPUT + 4, std430) buffer AovOutput4 { uvec4 aovPixels4[]; };
layout(set = 0, binding = TS_BINDING_OUTPUT + 5, std430) buffer AovOutput5 { uvec4 aovPixels5[]; };
layout(set = 0, binding = TS_BINDING_OUTPUT + 6, std430) buffer AovOutput6 { uvec4 aovPixels6[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) buffer OutputRef { uvec4 data[]; };
layout(constant_id = TS_SPEC_OUTPUT_BINDING) const bool OUTPUT_BINDING = false;
// Pixel `index` of AOV slice `slice` (a constant wherever it is called, so that one binding's code remains).
void write_output(GpuFrame frame, uint slice, uint index, uvec4 bits) {
    if (!OUTPUT_BINDING) OutputRef(frame.aovOutput).data[index + slice * frame.outputs.x] = bits;
    else if (slice == 0u) aovPixels0[index] = bits;
    else if (slice == 1u) aovPixels1[index] = bits;
    else if (slice == 2u) aovPixels2[index] = bits;
    else if (slice == 3u) aovPixels3[index] = bits;
    else if (slice == 4u) aovPixels4[index] = bits;
    else if (slice == 5u) aovPixels5[index] = bits;
    else aovPixels6[index] = bits;
}
void write_output(GpuFrame frame, uint slice, uint index, vec4 value) { write_output(frame, slice, index, floatBitsToUint(value)); }
// The visibility buffer through its binding (TS_BINDING_VISIBILITY), for the rasterizers' atomics (raster.h visibility_max).
layout(set = 0, binding = TS_BINDING_VISIBILITY, std430) buffer VisibilityWords { uint64_t visibilityWords[]; };
// Pixel `index` of the colour's slice (0), the one read back by a pass.
uvec4 read_colour_output(GpuFrame frame, uint index) {
    return OUTPUT_BINDING ? aovPixels0[index] : OutputRef(frame.aovOutput).data[index];
}
// classify.comp.glsl keeps each pixel's (bin, place in the bin) in its output's first two words between its count and
// scatter steps (resolve writes the AOVs only after): no memory of its own.
void write_bin_place(GpuFrame frame, uint index, uvec2 binPlace) {
    if (OUTPUT_BINDING) aovPixels0[index].xy = binPlace;
    else OutputRef(frame.aovOutput).data[index].xy = binPlace;
}
uvec2 bin_place_of(GpuFrame frame, uint index) {
    return OUTPUT_BINDING ? aovPixels0[index].xy : OutputRef(frame.aovOutput).data[index].xy;
}

// Both rasterizers record each fragment they write (the overdraw view), in their variants for it only.
layout(constant_id = TS_SPEC_COUNT_FRAGMENTS) const bool COUNT_FRAGMENTS = false;
void count_fragment(GpuFrame frame, uint pixel) {
    if (COUNT_FRAGMENTS) atomicAdd(CounterRef(frame.overdraw).data[pixel], 1u);
}

vec3 decode_octahedral(uint packed) {
    vec2 e = unpackSnorm2x16(packed);
    vec3 n = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    if (n.z < 0.0) n.xy = (1.0 - abs(n.yx)) * vec2(n.x >= 0.0 ? 1.0 : -1.0, n.y >= 0.0 ? 1.0 : -1.0);
    return normalize(n);
}

// What a visibility payload names: its visible-cluster slot and the triangle in that cluster, and for a micro-triangle
// (TS_VIS_TESSELLATED) its patch and its index in the patch (patchIndex 0xffffffff otherwise).
struct Payload {
    uint slot, triangle, patchIndex, micro;
};

// The instance flags some instance of the frame may carry (TS_SPEC_INSTANCE_FLAGS), and an instance's test of one of them:
// false at compile time for a flag no instance of the frame carries.
layout(constant_id = TS_SPEC_INSTANCE_FLAGS) const uint FRAME_INSTANCE_FLAGS = TS_SPECIALIZED_INSTANCE_FLAGS;
bool instance_flag(Instance instance, uint flag) { return (FRAME_INSTANCE_FLAGS & flag) != 0u && (instance.flags & flag) != 0u; }

Payload decode_payload(GpuFrame frame, uint payload) {
    Payload p;
    uint clusterTriangle = payload;
    p.patchIndex = 0xffffffffu;
    p.micro = 0u;
    if ((FRAME_INSTANCE_FLAGS & TS_INSTANCE_DISPLACED) != 0u && (payload & TS_VIS_TESSELLATED) != 0u) {  // only displaced instances dice
        p.patchIndex = (payload & ~TS_VIS_TESSELLATED) >> TS_VIS_MICRO_BITS;
        p.micro = payload & ((1u << TS_VIS_MICRO_BITS) - 1u);
        clusterTriangle = load_gpu_patch(frame, p.patchIndex).triangle;
    }
    p.slot = clusterTriangle >> TS_VIS_TRIANGLE_BITS;
    p.triangle = clusterTriangle & ((1u << TS_VIS_TRIANGLE_BITS) - 1u);
    return p;
}

// The instance and cluster behind a visible-cluster slot (TS_VISIBLE_SOFTWARE left in x).
uvec2 visible_cluster(GpuFrame frame, uint slot) {
    return TEXEL_VIEWS ? texelFetch(visibleClusterTexels, int(slot)).xy : VisibleClusterRef(frame.visibleClusters).data[slot];
}

// The cull's record of a visible cluster (shared.h GpuVisibleRecord), written beside its visible-cluster entry.
void store_visible_record(GpuFrame frame, uint slot, Instance instance, GpuCluster cluster) {
    GpuVisibleRecord record;
    for (int k = 0; k < 3; ++k) record.rows[k] = vec4(instance.rows[k].xyz, instance.translation[k]);
    record.vertexOffset = cluster.vertexOffset;
    record.triangleOffset = cluster.triangleOffset;
    record.flags = instance.flags;
    record.meshIndex = instance.meshIndex;
    VisibleRecordRef(frame.visibleRecords).data[slot] = record;
}

GpuVisibleRecord load_visible_record(GpuFrame frame, uint slot) {
    if (!TEXEL_VIEWS) return VisibleRecordRef(frame.visibleRecords).data[slot];
    int at = int(4u * slot);
    uvec4 t3 = texelFetch(visibleRecordTexels, at + 3);
    GpuVisibleRecord record;
    for (int k = 0; k < 3; ++k) record.rows[k] = uintBitsToFloat(texelFetch(visibleRecordTexels, at + k));
    record.vertexOffset = t3.x;
    record.triangleOffset = t3.y;
    record.flags = t3.z;
    record.meshIndex = t3.w;
    return record;
}

// The instance a record describes: its transform, flags and mesh (not its prim, material or displacement bounds,
// which the passes reading records load from the instance itself where they need them).
Instance record_instance(GpuVisibleRecord record) {
    Instance instance;
    instance.rows = record.rows;
    instance.translation = vec3(record.rows[0].w, record.rows[1].w, record.rows[2].w);
    instance.meshIndex = record.meshIndex;
    instance.primId = 0u;
    instance.materialIndex = 0u;
    instance.flags = record.flags;
    instance.displacementBounds = 0u;
    return instance;
}

// How far a displaced instance's surface may move from its mesh (mesh units: times instance_scale in the world); 0
// when nothing displaces it. An instance with a material table keeps the largest of its materials' in the word before
// its table.

float instance_displacement(GpuFrame frame, Instance instance) {
    if (!instance_flag(instance, TS_INSTANCE_DISPLACED)) return 0.0;
    if (instance_flag(instance, TS_INSTANCE_MATERIAL_SLOTS)) return uintBitsToFloat(material_table_entry(frame, instance.materialIndex - 1u));
    return load_material(frame, instance.materialIndex).displacement.w;
}

// How far displacement moves one cluster of a displaced instance (mesh units): its own bound, from the texture's range
// under it, where the CPU found it (GpuInstanceBatch.displacementBounds), else its materials'. `clusterInMesh` counts
// from the mesh's first cluster.
float cluster_displacement(GpuFrame frame, Instance instance, uint clusterInMesh) {
    if (!instance_flag(instance, TS_INSTANCE_DISPLACED)) return 0.0;
    if (instance.displacementBounds == TS_NO_STREAM) return instance_displacement(frame, instance);
    return FloatRef(frame.clusterDisplacement).data[instance.displacementBounds + clusterInMesh];
}

// The material of a visible triangle: the instance's own, or, for meshes whose triangles carry material slots
// (GeomSubsets), the slot's entry in the instance's material table.
uint pixel_material(GpuFrame frame, Instance instance, uint cluster, uint triangle) {
    if (!instance_flag(instance, TS_INSTANCE_MATERIAL_SLOTS)) return instance.materialIndex;
    uint slot = triangle_word(frame, load_cluster(frame, cluster).triangleOffset + triangle) >> 24;
    return material_table_entry(frame, instance.materialIndex + slot);
}
