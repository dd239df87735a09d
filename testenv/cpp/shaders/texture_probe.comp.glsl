// Test shader: evaluates shaders/texture.h's texture_slot_value() at probe points, so that test_textures.cpp can
// compare the GPU's filtering with its CPU reference.
#version 460
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#include "shared.h"
#include "texture.h"

layout(local_size_x = 64) in;

struct Probe {
    vec4 stDx;    // st, then d(st)/dx
    vec4 dySlot;  // d(st)/dy, then the slot index (as uint bits) and 0
};
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer ProbeRef { Probe data[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) writeonly buffer ResultRef { vec4 data[]; };

layout(push_constant) uniform Push { uint64_t pool; uint64_t slots; ProbeRef probes; ResultRef results; uint count; } push;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= push.count) return;
    Probe probe = push.probes.data[i];
    GpuTextureSlot slot = TextureSlotRef(push.slots).data[floatBitsToUint(probe.dySlot.z)];
    push.results.data[i] = texture_slot_value(push.pool, slot, probe.stDx.xy, probe.stDx.zw, probe.dySlot.xy);
}
