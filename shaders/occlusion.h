// The HZB occlusion test of the cull passes (cull.comp.glsl) and of tessellation patches (tessellate.comp.glsl).
#ifndef TESSERA_OCCLUSION_H
#define TESSERA_OCCLUSION_H

// True when the sphere is certainly hidden: its nearest depth lies behind the farthest depth the HZB holds over
// its whole screen footprint (the box of its bounding cube's corners, read at the finest HZB level where that box
// spans at most 4x4 texels: a coarser level would reach far past the box and find background). A sphere that
// reaches the camera plane is never hidden.
bool sphere_occluded(GpuFrame frame, mat4 viewProjection, vec3 center, float radius) {
    vec2 lo = vec2(3.4e38), hi = vec2(-3.4e38);
    float nearestDepth = 0.0;  // reversed Z: larger is nearer
    for (int i = 0; i < 8; ++i) {
        vec3 corner = center + radius * vec3((i & 1) != 0 ? 1.0 : -1.0, (i & 2) != 0 ? 1.0 : -1.0, (i & 4) != 0 ? 1.0 : -1.0);
        vec4 clip = viewProjection * vec4(corner, 1.0);
        if (clip.w <= 0.0) return false;
        vec3 ndc = clip.xyz / clip.w;
        lo = min(lo, ndc.xy);
        hi = max(hi, ndc.xy);
        nearestDepth = max(nearestDepth, ndc.z);
    }
    if (nearestDepth >= 1.0) return false;  // reaches the near plane
    vec2 size = vec2(frame.viewport.xy);
    vec2 pixelLo = clamp((lo * 0.5 + 0.5) * size, vec2(0.0), size - 1.0);
    vec2 pixelHi = clamp((hi * 0.5 + 0.5) * size, vec2(0.0), size - 1.0);
    float extent = max(pixelHi.x - pixelLo.x, pixelHi.y - pixelLo.y);
    // A texel of level l spans 2^(l+1) pixels; at least a third of the extent keeps the box within 4 texels.
    uint level = min(uint(max(ceil(log2(max(extent / 3.0, 1.0))) - 1.0, 0.0)), frame.hzb.x - 1u);
    uvec2 levelSize = hzb_level_size(frame, level);
    uint offset = hzb_level_offset(frame, level);
    uvec2 t0 = min(uvec2(pixelLo) >> (level + 1u), levelSize - 1u);
    uvec2 t1 = min(uvec2(pixelHi) >> (level + 1u), levelSize - 1u);
    float farthest = 3.4e38;
    uint y = t0.y;
    do {  // the tests at the end (frame.h): the box holds at least one texel (t0 <= t1)
        uint x = t0.x;
        do farthest = min(farthest, hzb_texel(offset + y * levelSize.x + x)); while (++x <= t1.x);
    } while (++y <= t1.y);
    // The margin covers rounding between this bound and the rasterizers' interpolated depths.
    return nearestDepth * 1.00001 < farthest;
}

// The test of this step: the main pass asks the previous frame's HZB (seen from the previous camera), the post
// pass this frame's. False when the main pass has no previous HZB.
bool hidden(GpuFrame frame, uint step, vec3 center, float radius) {
    if (step == TS_CULL_MAIN) {
        if ((frame.counts.z & TS_FRAME_PREVIOUS_HZB) == 0u) return false;
        return sphere_occluded(frame, frame.previousViewProjection, center, radius);
    }
    return sphere_occluded(frame, frame.viewProjection, center, radius);
}

#endif
