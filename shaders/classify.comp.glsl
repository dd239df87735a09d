// Material bins, one thread per pixel. Count step: each covered pixel takes the next place in its bin (its material's,
// and for a micro-triangle its kind's, TS_BIN_*: resolve has a variant per kind) and notes bin and place. Scatter step
// (after bins.comp.glsl gave each bin its range): each covered pixel writes its coordinates at its place in its bin's range.
// A frame with a single possible bin (one material, no displacement) runs the one-bin step alone: the place is the
// pixel's entry, with nothing to decode and no second pass.
// Each step is a pipeline of its own (TS_SPEC_STEP), holding only that step's code.
#version 460
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_vote : require
#include "frame.h"

layout(local_size_x = TS_PIXEL_TILE, local_size_y = TS_PIXEL_TILE) in;
// This pipeline's step (TS_CLASSIFY_*): only its code is compiled in.
layout(constant_id = TS_SPEC_STEP) const uint STEP = TS_CLASSIFY_COUNT;

// The bin of a covered pixel's visibility value.
uint pixel_bin(GpuFrame frame, uint64_t value) {
    Payload payload = decode_payload(frame, uint(value));
    uvec2 visible = visible_cluster(frame, payload.slot);
    Instance instance = load_instance(frame, visible.x & ~TS_VISIBLE_SOFTWARE);
    uint bin = pixel_material(frame, instance, visible.y, payload.triangle);
    if (payload.patchIndex != 0xffffffffu) {
        bool kept = load_gpu_patch(frame, payload.patchIndex).points != TS_NO_STREAM;
        bin += (kept ? TS_BIN_KEPT_MICRO : TS_BIN_DICED_MICRO) * frame.viewport.z;
    }
    return bin;
}

// The next place in `bin` for each calling invocation. Lanes of a subgroup that share their bin (neighbouring pixels
// mostly do, and all of them in a one-bin frame) take theirs with one atomic: lavapipe runs an atomic lane by lane, and
// every covered pixel of a one-bin frame adding 1 to the same counter cost a screen-filling frame 35-40 ms.
uint bin_place(GpuFrame frame, uint bin) {
    if (STEP == TS_CLASSIFY_ONE_BIN || subgroupAllEqual(bin)) {
        uvec4 lanes = subgroupBallot(true);
        uint first = 0u;
        if (subgroupElect()) first = atomicAdd(BinRef(frame.bins).data[bin].count, subgroupBallotBitCount(lanes));
        return subgroupBroadcastFirst(first) + subgroupBallotExclusiveBitCount(lanes);
    }
    return atomicAdd(BinRef(frame.bins).data[bin].count, 1u);
}

void main() {
    GpuFrame frame = frameConstants;
    uvec2 pixel = gl_GlobalInvocationID.xy;
    if (pixel.x >= frame.viewport.x || pixel.y >= frame.viewport.y) return;
    uint index = pixel.y * frame.viewport.x + pixel.x;
    if (STEP == TS_CLASSIFY_SCATTER) {
        uvec2 place = bin_place_of(frame, index);
        if (place.x != TS_NO_BIN) CounterRef(frame.binPixels).data[BinRef(frame.bins).data[place.x].offset + place.y] = pack_bin_pixel(pixel);
        return;
    }
    uint64_t value = visibility_value(frame, index);
    if (value == 0ul) {
        if (STEP == TS_CLASSIFY_COUNT) write_bin_place(frame, index, uvec2(TS_NO_BIN, 0u));
        return;
    }
    uint bin = STEP == TS_CLASSIFY_ONE_BIN ? 0u : pixel_bin(frame, value);
    uint place = bin_place(frame, bin);
    if (STEP == TS_CLASSIFY_ONE_BIN) CounterRef(frame.binPixels).data[place] = pack_bin_pixel(pixel);  // the only bin starts at 0
    else write_bin_place(frame, index, uvec2(bin, place));
}
