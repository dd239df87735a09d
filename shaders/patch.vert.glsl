// Patch raster, vertex stage: one indirect draw per patch (tessellate.comp.glsl), three vertices per micro-triangle.
// Each vertex dices and displaces its point of the patch (tessellation.h); raster.frag.glsl writes the visibility
// buffer as for clusters, with the micro-triangle's payload. Hardware clipping handles the near plane.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"
#include "surface.h"
#include "tessellation.h"

layout(location = 0) flat out uint outPayload;  // TS_VIS_TESSELLATED | patch << 8 | micro-triangle
layout(location = 1) flat out uint outFlags;

void main() {
    GpuFrame frame = frameConstants;
    uint patchIndex = uint(gl_InstanceIndex);
    uint micro = uint(gl_VertexIndex) / 3u;
    DicedPatch d = load_patch(frame, patchIndex);
    vec2 st;
    vec3 p = displaced_point(frame, d, micro_corner(d, micro, uint(gl_VertexIndex) % 3u), st);
    gl_Position = frame.viewProjection * vec4(p, 1.0);
    outPayload = TS_VIS_TESSELLATED | patchIndex << TS_VIS_MICRO_BITS | micro;
    outFlags = d.instance.flags;
}
