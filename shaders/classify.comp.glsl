// Material bins, one thread per pixel. Count step: each covered pixel adds one to its bin: its material's, and for
// a micro-triangle its kind's (TS_BIN_*: resolve has a variant per kind). Scatter step (after bins.comp.glsl gave each
// bin its range): each covered pixel writes its index into its bin's range.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"

layout(local_size_x = TS_PIXEL_TILE, local_size_y = TS_PIXEL_TILE) in;

void main() {
    GpuFrame frame = frameConstants;
    uvec2 pixel = gl_GlobalInvocationID.xy;
    if (pixel.x >= frame.viewport.x || pixel.y >= frame.viewport.y) return;
    uint index = pixel.y * frame.viewport.x + pixel.x;
    uint64_t value = VisibilityRef(frame.visibility).data[index];
    if (value == 0ul) return;
    Payload payload = decode_payload(frame, uint(value));
    uvec2 visible = visible_cluster(frame, payload.slot);
    Instance instance = load_instance(frame, visible.x & ~TS_VISIBLE_SOFTWARE);
    uint bin = pixel_material(frame, instance, visible.y, payload.triangle);
    if (payload.patchIndex != 0xffffffffu) {
        bool kept = PatchRef(frame.patches).data[payload.patchIndex].points != TS_NO_STREAM;
        bin += (kept ? TS_BIN_KEPT_MICRO : TS_BIN_DICED_MICRO) * frame.viewport.z;
    }
    BinRef bins = BinRef(frame.bins);
    if (push.step == TS_CLASSIFY_COUNT) {
        atomicAdd(bins.data[bin].count, 1u);
    } else {
        uint k = atomicAdd(bins.data[bin].cursor, 1u);
        CounterRef(frame.binPixels).data[bins.data[bin].offset + k] = index;
    }
}
