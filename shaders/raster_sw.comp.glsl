// Software raster: one workgroup per cluster of the software list, one thread per triangle. Clusters here lie
// beyond the near plane and cover a small screen area (cull.comp.glsl), so no clipping is needed and edge
// functions stay small. Vertices are snapped to the hardware rasterizer's sub-pixel grid and
// coverage follows its top-left rule, so both paths cover the same pixels for the same triangle; depth and
// payload go into the visibility buffer with the same 64-bit atomic max.
#version 460
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_shader_atomic_int64 : require
#include "frame.h"
#include "surface.h"

layout(local_size_x = TS_SW_RASTER_GROUP_SIZE) in;

// The pipeline variant for frames with textured opacity masks (the others carry no mask code).
layout(constant_id = TS_SPEC_TEXTURES) const bool MASKS = false;

shared ivec2 screen[TS_CLUSTER_MAX_VERTICES];  // sub-pixel position
shared float depth[TS_CLUSTER_MAX_VERTICES];   // reversed-Z depth (z / w)

// Top-left rule for counter-clockwise triangles in y-down framebuffer space: left edges run downwards, top
// edges run exactly horizontally to the left. A sample exactly on an edge belongs to the triangle only then.
int edge_bias(ivec2 from, ivec2 to) {
    ivec2 d = to - from;
    return (d.y > 0 || (d.y == 0 && d.x < 0)) ? 0 : -1;
}

// Edge functions (the edge opposite each vertex), positive inside, stepped one pixel at a time from the first
// pixel centre of the box; a pixel is covered when all three pass the top-left rule. Depth is interpolated from the
// edge functions (z: the vertex depths, w: one over twice the area).
float depth_at(vec3 edges, vec4 z) { return (edges.x * z.x + edges.y * z.y + edges.z * z.z) * z.w; }

// `masked`: the instance's material cuts pixels by a textured opacity (TS_INSTANCE_MASKED; the same for a workgroup).
void write_pixel(GpuFrame frame, int x, int y, float depth, uint64_t payload, bool masked) {
    if (depth < 0.0 || depth > 1.0) return;  // beyond the far plane
    if (masked && masked_out(frame, uint(payload), uvec2(x, y))) return;
    uint pixel = uint(y) * frame.viewport.x + uint(x);
    atomicMax(VisibilityRef(frame.visibility).data[pixel], (uint64_t(floatBitsToUint(depth)) << 32) | payload);
    count_fragment(frame, pixel);
}

void scan_small(GpuFrame frame, ivec2 a, ivec2 b, ivec2 c, ivec2 lo, ivec2 hi, int step, int center, vec4 z, uint64_t payload, bool masked) {
    ivec2 p = lo * step + center;
    ivec3 row = ivec3((b.x - c.x) * (p.y - b.y) - (b.y - c.y) * (p.x - b.x),
                      (c.x - a.x) * (p.y - c.y) - (c.y - a.y) * (p.x - c.x),
                      (a.x - b.x) * (p.y - a.y) - (a.y - b.y) * (p.x - a.x));
    ivec3 stepX = -ivec3(b.y - c.y, c.y - a.y, a.y - b.y) * step;
    ivec3 stepY = ivec3(b.x - c.x, c.x - a.x, a.x - b.x) * step;
    ivec3 bias = ivec3(edge_bias(b, c), edge_bias(c, a), edge_bias(a, b));
    for (int y = lo.y; y <= hi.y; ++y, row += stepY) {
        ivec3 w = row;
        for (int x = lo.x; x <= hi.x; ++x, w += stepX)
            if (all(greaterThanEqual(w + bias, ivec3(0)))) write_pixel(frame, x, y, depth_at(vec3(w), z), payload, masked);
    }
}

void scan_large(GpuFrame frame, ivec2 a, ivec2 b, ivec2 c, ivec2 lo, ivec2 hi, int step, int center, vec4 z, uint64_t payload, bool masked) {
    ivec2 p = lo * step + center;
    i64vec3 row = i64vec3(int64_t(b.x - c.x) * int64_t(p.y - b.y) - int64_t(b.y - c.y) * int64_t(p.x - b.x),
                          int64_t(c.x - a.x) * int64_t(p.y - c.y) - int64_t(c.y - a.y) * int64_t(p.x - c.x),
                          int64_t(a.x - b.x) * int64_t(p.y - a.y) - int64_t(a.y - b.y) * int64_t(p.x - a.x));
    i64vec3 stepX = -i64vec3(b.y - c.y, c.y - a.y, a.y - b.y) * int64_t(step);
    i64vec3 stepY = i64vec3(b.x - c.x, c.x - a.x, a.x - b.x) * int64_t(step);
    i64vec3 bias = i64vec3(edge_bias(b, c), edge_bias(c, a), edge_bias(a, b));
    for (int y = lo.y; y <= hi.y; ++y, row += stepY) {
        i64vec3 w = row;
        for (int x = lo.x; x <= hi.x; ++x, w += stepX)
            if (all(greaterThanEqual(w + bias, i64vec3(0)))) write_pixel(frame, x, y, depth_at(vec3(w), z), payload, masked);
    }
}

void main() {
    GpuFrame frame = push.frame.f;
    DrawStateRef draw = DrawStateRef(frame.drawState);
    uint count = draw.state.swClusters;
    float steps = frame.raster.y;  // sub-pixel steps per pixel
    // One workgroup per cluster over a 2D grid, no loop: on lavapipe a loop around this code runs it masked.
    uint k = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
    if (k >= count) return;  // the whole workgroup: no barrier is skipped by some threads only
    uint slot = SlotListRef(frame.softwareList).data[k];
    uvec2 visible = VisibleClusterRef(frame.visibleClusters).data[slot];
    Instance instance = load_instance(frame, visible.x & ~TS_VISIBLE_SOFTWARE);
    GpuCluster cluster = ClusterRef(frame.clusters).data[visible.y];
    vec3 translation = camera_relative_translation(instance);

    // Vertices: clip space -> framebuffer sub-pixels (Vulkan viewport transform: (ndc * 0.5 + 0.5) * size).
    uint vertexCount = cluster.levelVertices & 0xffffu;
    for (uint v = gl_LocalInvocationIndex; v < vertexCount; v += TS_SW_RASTER_GROUP_SIZE) {
        vec4 clip = frame.viewProjection * vec4(to_camera_relative(instance, translation, vertex_position(frame, cluster.vertexOffset + v)), 1.0);
        vec3 ndc = clip.xyz / clip.w;
        vec2 pixel = (ndc.xy * 0.5 + 0.5) * vec2(frame.viewport.xy);
        screen[v] = ivec2(round(pixel * steps));
        depth[v] = ndc.z;
    }
    barrier();

    uint triangle = gl_LocalInvocationIndex;
    if (triangle < cluster.triangleCount) {
        bool flip = (instance.flags & TS_INSTANCE_FLIP_WINDING) != 0u;
        uint i0 = corner_vertex(frame, cluster, triangle, 0u, flip) - cluster.vertexOffset;
        uint i1 = corner_vertex(frame, cluster, triangle, 1u, flip) - cluster.vertexOffset;
        uint i2 = corner_vertex(frame, cluster, triangle, 2u, flip) - cluster.vertexOffset;
        ivec2 a = screen[i0], b = screen[i1], c = screen[i2];
        float za = depth[i0], zb = depth[i1], zc = depth[i2];
        // Edge functions stay within 2 E (E + step) for a triangle E sub-pixels across, so below 2^14 sub-pixels
        // 32-bit integers are exact, and much faster where 64-bit multiplies are emulated (lavapipe).
        ivec2 extent = max(a, max(b, c)) - min(a, min(b, c));
        bool small = max(extent.x, extent.y) < 16384;
        // Twice the signed area; negative is counter-clockwise on screen (y down), a front face.
        int64_t area = small ? int64_t((b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y))
                             : int64_t(b.x - a.x) * int64_t(c.y - a.y) - int64_t(c.x - a.x) * int64_t(b.y - a.y);
        bool front = area < 0l;
        bool doubleSided = (instance.flags & TS_INSTANCE_DOUBLE_SIDED) != 0u;
        if (area != 0l && (front || doubleSided)) {
            if (!front) {  // the back of a double-sided triangle, turned to the same orientation
                ivec2 s = b; b = c; c = s;
                float z = zb; zb = zc; zc = z;
                area = -area;
            }
            int step = int(steps), center = step / 2;
            ivec2 lo = max((min(a, min(b, c)) - center + step - 1) / step, ivec2(0));
            ivec2 hi = min((max(a, max(b, c)) - center) / step, ivec2(frame.viewport.xy) - 1);
            uint64_t payload = uint64_t((slot << TS_VIS_TRIANGLE_BITS) | triangle);
            vec4 z = vec4(za, zb, zc, 1.0 / float(-area));
            bool masked = MASKS && (instance.flags & TS_INSTANCE_MASKED) != 0u;
            if (small) scan_small(frame, a, b, c, lo, hi, step, center, z, payload, masked);
            else scan_large(frame, a, b, c, lo, hi, step, center, z, payload, masked);
        }
    }
}
