// Patch rasterizer in compute: one workgroup per patch of the compute list (tessellate.comp.glsl sends it the patches
// beyond the near plane that stay small on screen), its threads over its lattice points, then its micro-triangles. Each
// point is diced and displaced once (tessellation.h, the same code as the patch raster's vertex stage) and snapped to
// the hardware's sub-pixel grid in shared memory; the micro-triangles are scanned like the cluster rasterizer's
// (raster.h) into the visibility buffer with their payload, TS_VIS_TESSELLATED | patch << 8 | micro-triangle.
#version 460
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_shader_atomic_int64 : require
#include "frame.h"
#include "surface.h"
#include "tessellation.h"
#include "raster.h"

// 64 threads on a GPU (TS_DICE_GROUP_SIZE), one subgroup on a CPU device (local_size_x_id): lavapipe runs a workgroup as
// coroutines of one subgroup each and switches between them at the barrier; one subgroup cut its dicing time by a third.
layout(local_size_x = TS_DICE_GROUP_SIZE, local_size_x_id = TS_SPEC_RASTER_GROUP_SIZE) in;

// The pipeline variant for frames with textured opacity masks (the others carry no mask code): fixed per module
// (TS_MODULE_MASKS, shaders/CMakeLists.txt), since the mask's texture sampling is most of the code.
const bool MASKS = TS_MODULE_MASKS;

shared ivec4 corner[TS_DICE_MAX_POINTS];  // sub-pixel position, reversed-Z depth bits: one load per corner

// Lattice point v of the patch (row by row: the first row's n + 1 points, then n, ...): diced, displaced and snapped into
// shared memory, and kept for resolve where the patch has room for its points (`points`).
void place_point(GpuFrame frame, DicedPatch d, uint points, uint v) {
    uint n = d.n, b = 0u, first = 0u;
    if (first + n + 1u - b <= v) do {  // the test at the end (frame.h)
        first += n + 1u - b;
        ++b;
    } while (first + n + 1u - b <= v);
    vec2 st;
    vec3 p = displaced_point(frame, d, micro_point(d, uvec2(v - first, b)), st);
    ivec2 screen;
    float depth;
    snap_vertex(frame, frame.viewProjection * vec4(p, 1.0), screen, depth);
    corner[v] = ivec4(screen, floatBitsToInt(depth), 0);
    if (points != TS_NO_STREAM) {  // kept for resolve, which then need not dice again
        PatchPointRef pool = PatchPointRef(frame.patchPoints);
        uint at = (points + v) * TS_PATCH_POINT_FLOATS;
        pool.data[at] = p.x;
        pool.data[at + 1u] = p.y;
        pool.data[at + 2u] = p.z;
        pool.data[at + 3u] = st.x;
        pool.data[at + 4u] = st.y;
    }
}

// Micro-triangle `micro` of the patch, from its corners in shared memory.
void draw_micro_triangle(GpuFrame frame, DicedPatch d, uint index, uint micro) {
    uvec2 a, b, c;
    lattice_cell(micro, d.n, a, b, c);
    uint ia = lattice_index(a, d.n), ib = lattice_index(b, d.n), ic = lattice_index(c, d.n);
    uint64_t payload = uint64_t(TS_VIS_TESSELLATED | index << TS_VIS_MICRO_BITS | micro);
    ivec4 ca = corner[ia], cb = corner[ib], cc = corner[ic];
    rasterize_triangle(frame, ca.xy, cb.xy, cc.xy, intBitsToFloat(ca.z), intBitsToFloat(cb.z), intBitsToFloat(cc.z), payload,
                       (d.instance.flags & TS_INSTANCE_DOUBLE_SIDED) != 0u, MASKS && (d.instance.flags & TS_INSTANCE_MASKED) != 0u,
                       true);  // patches up to TS_DICE_MAX_RADIUS_PIXELS: micro-triangles may be large
}

void main() {
    GpuFrame frame = frameConstants;
    DrawStateRef draw = DrawStateRef(frame.drawState);
    // One workgroup per patch over a 2D grid, no loop (as the cluster rasterizer: lavapipe runs a loop around it masked).
    uint k = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
    if (k >= draw.state.dicePatches) return;  // the whole workgroup: no barrier is skipped by some threads only
    uint index = UintRef(frame.dicePatches).data[spread_index(k, draw.state.dicePatches)];  // spread (shared.h)
    DicedPatch d = load_patch(frame, index);
    uint n = d.n;

    // Each thread takes every workgroup-size-th point and then micro-triangle: a workgroup of 256 (one thread per
    // micro-triangle of the largest patch) cost lavapipe, which runs a workgroup 8 lanes at a time, masked or not, 4x as
    // much for the typical patch of far fewer. Both loops test at their end (frame.h).
    uint points = load_gpu_patch(frame, index).points, pointCount = (n + 1u) * (n + 2u) / 2u, v = gl_LocalInvocationIndex;
    do {
        if (v < pointCount) place_point(frame, d, points, v);
    } while ((v += gl_WorkGroupSize.x) < pointCount);
    barrier();

    uint micro = gl_LocalInvocationIndex;
    do {
        if (micro < n * n) draw_micro_triangle(frame, d, index, micro);
    } while ((micro += gl_WorkGroupSize.x) < n * n);
}
