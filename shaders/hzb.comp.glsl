// HZB build, one level per dispatch (push.step): each texel keeps the farthest depth (the smallest reversed-Z
// value) of the 2x2 texels below it, or of its 2x2 pixels of the visibility buffer at level 0. Background pixels
// hold depth 0, the farthest there is, so they never hide anything. Texels past the image edge are left out.
// Before each build, a one-workgroup step decides from the draw state whether the build is needed at all and writes
// its levels' dispatch arguments (write_dispatches).
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"

layout(local_size_x = TS_HZB_TILE, local_size_y = TS_HZB_TILE) in;

// Steps TS_HZB_AFTER_MAIN and TS_HZB_FINAL (one workgroup): the dispatch arguments of that build's levels, 32 of them per
// build, at push.hzb. The HZB after the main pass serves only to test what it deferred; the final one is the HZB of
// the whole frame, which the HZB after the main pass already is when the post pass drew nothing (nothing it deferred
// showed). A build that is not needed gets no workgroups.
void write_dispatches(GpuFrame frame, uint when) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    bool deferred = draw.state.deferredInstances + draw.state.deferredClusters + draw.state.deferredPatches != 0u;
    bool postDrew = draw.state.postClusters != 0u || draw.state.deferredPatches > draw.state.occludedPatches;
    bool needed = when == TS_HZB_AFTER_MAIN ? deferred : !deferred || postDrew;
    uint level = gl_LocalInvocationIndex;
    if (level == 0u && needed) draw.state.hzbBuilds += 1u;  // the only writer
    if (level >= frame.hzb.x) return;
    uvec2 size = hzb_level_size(frame, level);
    uint first = (when == TS_HZB_FINAL ? 32u : 0u) + level;
    CounterRef arguments = CounterRef(push.hzb);
    arguments.data[3u * first] = needed ? (size.x + TS_HZB_TILE - 1u) / TS_HZB_TILE : 0u;
    arguments.data[3u * first + 1u] = (size.y + TS_HZB_TILE * TS_HZB_ROWS_PER_THREAD - 1u) / (TS_HZB_TILE * TS_HZB_ROWS_PER_THREAD);
    arguments.data[3u * first + 2u] = 1u;
}

void main() {
    GpuFrame frame = frameConstants;
    if (push.step >= TS_HZB_AFTER_MAIN) {
        write_dispatches(frame, push.step);
        return;
    }
    uint level = push.step;
    uvec2 size = hzb_level_size(frame, level);
    uvec2 below = level == 0u ? frame.viewport.xy : hzb_level_size(frame, level - 1u);
    uint belowOffset = level == 0u ? 0u : hzb_level_offset(frame, level - 1u), offset = hzb_level_offset(frame, level);
    // TS_HZB_ROWS_PER_THREAD texels of a column, TS_HZB_TILE rows apart (a workgroup's rows stay together).
    uint x = gl_GlobalInvocationID.x;
    uint firstRow = gl_WorkGroupID.y * TS_HZB_TILE * TS_HZB_ROWS_PER_THREAD + gl_LocalInvocationID.y;
    if (x >= size.x) return;
    uint r = 0u;
    do {  // the test at the end (frame.h)
        uvec2 texel = uvec2(x, firstRow + r * TS_HZB_TILE);
        if (texel.y >= size.y) return;
        // The 2x2 below, clamped at the last row and column (repeating a texel changes no minimum): no per-texel branch.
        uvec2 p0 = min(texel * 2u, below - 1u), p1 = min(texel * 2u + 1u, below - 1u);
        float farthest;
        if (level == 0u) {
            uint row0 = p0.y * below.x, row1 = p1.y * below.x;
            farthest = min(min(uintBitsToFloat(uint(visibility_value(frame, row0 + p0.x) >> 32)), uintBitsToFloat(uint(visibility_value(frame, row0 + p1.x) >> 32))),
                           min(uintBitsToFloat(uint(visibility_value(frame, row1 + p0.x) >> 32)), uintBitsToFloat(uint(visibility_value(frame, row1 + p1.x) >> 32))));
        } else {
            uint row0 = belowOffset + p0.y * below.x, row1 = row0 + (p1.y - p0.y) * below.x;
            farthest = min(min(hzb_texel(row0 + p0.x), hzb_texel(row0 + p1.x)), min(hzb_texel(row1 + p0.x), hzb_texel(row1 + p1.x)));
        }
        push.hzb.data[offset + texel.y * size.x + texel.x] = farthest;
    } while (++r < TS_HZB_ROWS_PER_THREAD);
}
