// The hardware rasterizers' fragment stage, shared by clusters (raster.frag.glsl) and patches (patch.frag.glsl): 64-bit
// atomic max of (depth | payload) into the visibility buffer; reversed Z makes the nearest fragment the largest value.
// Include after raster.h.
#ifndef TESSERA_RASTER_FRAGMENT_H
#define TESSERA_RASTER_FRAGMENT_H

layout(location = 0) flat in uint inPayload;
layout(location = 1) flat in uint inFlags;

// The pipeline variant for frames with textured opacity masks (the others carry no mask code): fixed per module
// (TS_MODULE_MASKS, shaders/CMakeLists.txt), since the mask's texture sampling is most of the code.
const bool MASKS = TS_MODULE_MASKS;

void main() {
    if (!gl_FrontFacing && (inFlags & TS_INSTANCE_DOUBLE_SIDED) == 0u) return;  // single-sided: back faces are culled
    GpuFrame frame = frameConstants;
    // A textured opacity mask may cut the pixel away.
    if (MASKS && (inFlags & TS_INSTANCE_MASKED) != 0u && PIXEL_MASKED_OUT(frame, inPayload, uvec2(gl_FragCoord.xy))) return;
    uint pixel = uint(gl_FragCoord.y) * frame.viewport.x + uint(gl_FragCoord.x);
    uint64_t value = (uint64_t(floatBitsToUint(gl_FragCoord.z)) << 32) | uint64_t(inPayload);
    visibility_max(frame, pixel, value);
    count_fragment(frame, pixel);
}

#endif
