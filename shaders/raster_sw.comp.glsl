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
#include "raster.h"

layout(local_size_x = TS_SW_RASTER_GROUP_SIZE) in;

// The pipeline variant for frames with textured opacity masks (the others carry no mask code).
layout(constant_id = TS_SPEC_TEXTURES) const bool MASKS = false;

shared ivec2 screen[TS_CLUSTER_MAX_VERTICES];  // sub-pixel position
shared float depth[TS_CLUSTER_MAX_VERTICES];   // reversed-Z depth (z / w)

void main() {
    GpuFrame frame = frameConstants;
    DrawStateRef draw = DrawStateRef(frame.drawState);
    uint count = draw.state.swClusters;
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
    for (uint v = gl_LocalInvocationIndex; v < vertexCount; v += TS_SW_RASTER_GROUP_SIZE)
        snap_vertex(frame, frame.viewProjection * vec4(to_camera_relative(instance, translation, vertex_position(frame, cluster.vertexOffset + v)), 1.0),
                    screen[v], depth[v]);
    barrier();

    uint triangle = gl_LocalInvocationIndex;
    if (triangle < cluster.triangleCount) {
        bool flip = (instance.flags & TS_INSTANCE_FLIP_WINDING) != 0u;
        uint i0 = corner_vertex(frame, cluster, triangle, 0u, flip) - cluster.vertexOffset;
        uint i1 = corner_vertex(frame, cluster, triangle, 1u, flip) - cluster.vertexOffset;
        uint i2 = corner_vertex(frame, cluster, triangle, 2u, flip) - cluster.vertexOffset;
        uint64_t payload = uint64_t((slot << TS_VIS_TRIANGLE_BITS) | triangle);
        bool masked = MASKS && (instance.flags & TS_INSTANCE_MASKED) != 0u;
        rasterize_triangle(frame, screen[i0], screen[i1], screen[i2], depth[i0], depth[i1], depth[i2], payload,
                           (instance.flags & TS_INSTANCE_DOUBLE_SIDED) != 0u, masked);
    }
}
