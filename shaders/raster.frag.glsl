// Hardware raster, fragment stage: 64-bit atomic max of (depth | payload) into the visibility buffer.
// Reversed Z makes the nearest fragment the largest value.
#version 460
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_shader_atomic_int64 : require
#include "frame.h"
#include "surface.h"
#include "tessellation.h"

layout(location = 0) flat in uint inPayload;
layout(location = 1) flat in uint inFlags;

// The pipeline variant for frames with textured opacity masks (the others carry no mask code).
layout(constant_id = TS_SPEC_TEXTURES) const bool MASKS = false;

void main() {
    if (!gl_FrontFacing && (inFlags & TS_INSTANCE_DOUBLE_SIDED) == 0u) return;  // single-sided: back faces are culled
    GpuFrame frame = push.frame.f;
    // A textured opacity mask may cut the pixel away.
    if (MASKS && (inFlags & TS_INSTANCE_MASKED) != 0u && masked_out(frame, inPayload, uvec2(gl_FragCoord.xy))) return;
    uint pixel = uint(gl_FragCoord.y) * frame.viewport.x + uint(gl_FragCoord.x);
    uint64_t value = (uint64_t(floatBitsToUint(gl_FragCoord.z)) << 32) | uint64_t(inPayload);
    atomicMax(VisibilityRef(frame.visibility).data[pixel], value);
    count_fragment(frame, pixel);
}
