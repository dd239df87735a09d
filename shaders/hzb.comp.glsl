// HZB build, one level per dispatch (push.step): each texel keeps the farthest depth (the smallest reversed-Z
// value) of the 2x2 texels below it, or of its 2x2 pixels of the visibility buffer at level 0. Background pixels
// hold depth 0, the farthest there is, so they never hide anything. Texels past the image edge are left out.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"

layout(local_size_x = TS_HZB_TILE, local_size_y = TS_HZB_TILE) in;

void main() {
    GpuFrame frame = frameConstants;
    uint level = push.step;
    uvec2 size = hzb_level_size(frame, level);
    uvec2 texel = gl_GlobalInvocationID.xy;
    if (texel.x >= size.x || texel.y >= size.y) return;
    uvec2 below = level == 0u ? frame.viewport.xy : hzb_level_size(frame, level - 1u);
    uint belowOffset = level == 0u ? 0u : hzb_level_offset(frame, level - 1u);
    float farthest = 3.4e38;
    for (uint dy = 0u; dy < 2u; ++dy)
        for (uint dx = 0u; dx < 2u; ++dx) {
            uvec2 p = texel * 2u + uvec2(dx, dy);
            if (p.x >= below.x || p.y >= below.y) continue;
            float depth = level == 0u ? uintBitsToFloat(uint(VisibilityRef(frame.visibility).data[p.y * below.x + p.x] >> 32))
                                      : push.hzb.data[belowOffset + p.y * below.x + p.x];
            farthest = min(farthest, depth);
        }
    push.hzb.data[hzb_level_offset(frame, level) + texel.y * size.x + texel.x] = farthest;
}
