// Anti-aliasing on the device: an image of several pixel samples (Renderer::render) sums their colours here, in device
// memory, so that only their mean crosses to the host (summed on the host, each sample's 33 MB at 1080p crossed and was
// added there: beside an H100, more time than the sample's frame). Each sample's frame runs this after resolving its
// colour into the output: the first sample starts the sum, each later one adds to it, the last writes the mean into the
// output, which that frame then hands back as the image's colour. A sample reads the sum of those before it and writes
// its own into the other of two buffers (GpuFrame.samplesBefore / samplesAfter), so that a frame drawn again after an
// overflow adds its colour once. Push constants, read as this pass's own: `step` TS_SAMPLES_*, `aov` the samples in the
// image (the mean's divisor).
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"

layout(local_size_x = TS_PIXEL_TILE, local_size_y = TS_PIXEL_TILE) in;

// Two 64-bit words per pixel: lavapipe loads and stores through an address one lane and one word at a time, so that
// wider words cost it less (frame.h write_output).
layout(buffer_reference, std430, buffer_reference_align = 16) buffer SumRef { u64vec2 data[]; };

void main() {
    GpuFrame frame = frameConstants;
    uvec2 pixel = gl_GlobalInvocationID.xy;
    if (pixel.x >= frame.viewport.x || pixel.y >= frame.viewport.y) return;
    uint index = pixel.y * frame.viewport.x + pixel.x;
    precise vec4 sum = uintBitsToFloat(read_colour_output(frame, index));
    if (push.step != TS_SAMPLES_FIRST) {
        u64vec2 before = SumRef(frame.samplesBefore).data[index];
        sum += uintBitsToFloat(uvec4(unpack32(before.x), unpack32(before.y)));
    }
    if (push.step == TS_SAMPLES_MEAN) {
        precise vec4 mean = sum * (1.0 / float(push.aov));
        write_output(frame, 0u, index, mean);
    } else {
        uvec4 bits = floatBitsToUint(sum);
        SumRef(frame.samplesAfter).data[index] = u64vec2(pack64(bits.xy), pack64(bits.zw));
    }
}
