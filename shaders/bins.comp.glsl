// Material bins, one workgroup: each bin's range in the pixel list (an exclusive prefix sum of the counts, by one
// thread: there are as many bins as materials, three times as many with displacement, few next to pixels) and the
// indirect dispatch that shades it.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"

layout(local_size_x = 1) in;
// resolve.comp.glsl's pixels per thread (its workgroups shade TS_SHADE_GROUP_SIZE times as many pixels).
layout(constant_id = TS_SPEC_SHADE_PIXELS_PER_THREAD) const uint PIXELS_PER_THREAD = 1u;

void main() {
    GpuFrame frame = frameConstants;
    BinRef bins = BinRef(frame.bins);
    uint offset = 0u, used = 0u, micro[TS_BIN_KINDS] = uint[TS_BIN_KINDS](0u, 0u, 0u);
    uint binCount = frame.viewport.z * ((frame.counts.z & TS_FRAME_MICRO_BINS) != 0u ? TS_BIN_KINDS : 1u);
    for (uint m = 0u; m < binCount; ++m) {
        uint count = bins.data[m].count;
        bins.data[m].offset = offset;
        uint groups = (count + TS_SHADE_GROUP_SIZE * PIXELS_PER_THREAD - 1u) / (TS_SHADE_GROUP_SIZE * PIXELS_PER_THREAD);
        bins.data[m].groupsX = min(groups, 65535u);
        bins.data[m].groupsY = (groups + 65534u) / 65535u;
        bins.data[m].groupsZ = 1u;
        offset += count;
        used += count > 0u ? 1u : 0u;
        micro[m / frame.viewport.z] += count;
    }
    DrawStateRef draw = DrawStateRef(frame.drawState);
    draw.state.shadingBins = used;
    draw.state.coveredPixels = offset;
    draw.state.keptMicroPixels = micro[TS_BIN_KEPT_MICRO];
    draw.state.dicedMicroPixels = micro[TS_BIN_DICED_MICRO];
}
