// The colour of the pixels nothing covers in a frame with a textured dome light: the dome's image seen through each
// pixel; resolve.comp.glsl shades the others, bin by bin. Every other background is a constant, which the renderer fills
// in before resolve (renderer.cpp fill_background). A shader of its own: on a CPU device (lavapipe) the shading code
// beside it would cost every pixel, covered or not.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"
#include "surface.h"
#include "lights.h"

layout(local_size_x = TS_PIXEL_TILE, local_size_y = TS_PIXEL_TILE) in;

// Lat-long coordinates (st, t up) of a direction in the dome's frame, in OpenEXR's convention: longitude
// atan2(x, z), +pi at the left edge; latitude asin(y), +pi/2 at the top.
vec2 latlong_st(vec3 d) {
    return vec2(0.5 - atan(d.x, d.z) / (2.0 * PI), 0.5 + asin(clamp(d.y, -1.0, 1.0)) / PI);
}

// What the camera sees of the textured dome through the pixel: its image times the light's radiance, filtered over
// the pixel's footprint (the coordinates' change to the next pixel right and down, across the seam the short way).
vec3 dome_background(GpuFrame frame, GpuLight light, vec2 pixel) {
    vec3 origin, direction, right, down;
    pixel_ray(frame, pixel + 0.5, origin, direction);
    pixel_ray(frame, pixel + vec2(1.5, 0.5), origin, right);
    pixel_ray(frame, pixel + vec2(0.5, 1.5), origin, down);
    vec2 st = latlong_st(normalize(dome_direction(light, direction)));
    vec2 dx = latlong_st(normalize(dome_direction(light, right))) - st, dy = latlong_st(normalize(dome_direction(light, down))) - st;
    dx.x -= round(dx.x);
    dy.x -= round(dy.x);
    return light.radiance.rgb * sample_texture(frame.textures, light.texture, TS_WRAP_REPEAT | TS_WRAP_CLAMP << 2, st, dx, dy).rgb;
}

void main() {
    GpuFrame frame = frameConstants;
    uvec2 pixel = gl_GlobalInvocationID.xy;
    if (pixel.x >= frame.viewport.x || pixel.y >= frame.viewport.y) return;
    uint index = pixel.y * frame.viewport.x + pixel.x;
    if (visibility_value(frame, index) != 0ul) return;
    for (uint i = 0u; i < frame.viewport.w; ++i)
        if (uint(frameConstants.lights[i].directionType.w) == TS_LIGHT_DOME && frameConstants.lights[i].texture != TS_NO_TEXTURE) {
            // frameConstants.lights[i], not frame.lights[i]: resolve.comp.glsl
            write_output(frame, 0u, index, vec4(dome_background(frame, frameConstants.lights[i], vec2(pixel)), 1.0));
            return;
        }
    write_output(frame, 0u, index, frame.background);  // no textured dome after all: the plain colour
}
