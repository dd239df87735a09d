// The pixels nothing covers, for the AOV being resolved (push.aov); resolve.comp.glsl shades the others, bin by bin.
// A shader of its own: on a CPU device (lavapipe) the shading code beside it would cost every pixel, covered or not.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"

layout(local_size_x = TS_PIXEL_TILE, local_size_y = TS_PIXEL_TILE) in;

void main() {
    GpuFrame frame = push.frame.f;
    uvec2 pixel = gl_GlobalInvocationID.xy;
    if (pixel.x >= frame.viewport.x || pixel.y >= frame.viewport.y) return;
    uint index = pixel.y * frame.viewport.x + pixel.x;
    if (VisibilityRef(frame.visibility).data[index] != 0ul) return;
    uint aov = push.aov;
    if (aov >= TS_AOV_PRIM_ID) OutputIdRef(frame.aovOutput).data[index] = uvec4(0xffffffffu);
    else if (aov == TS_AOV_COLOR) OutputRef(frame.aovOutput).data[index] = frame.background;
    else if (aov == TS_AOV_DEPTH) OutputRef(frame.aovOutput).data[index] = vec4(uintBitsToFloat(0x7f800000u));
    else OutputRef(frame.aovOutput).data[index] = vec4(0.0);
}
