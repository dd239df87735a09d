// Hardware raster, vertex stage: one draw instance per cluster of the hardware list, 128 triangles' worth of vertices
// each; vertices are pulled from the cluster's streams and unused triangle slots are sent off screen.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"

// The variant for double-sided instances, which draws the back of the hardware list (cull.comp.glsl).
layout(constant_id = TS_SPEC_DOUBLE_SIDED) const bool DOUBLE_SIDED = false;

layout(location = 0) flat out uint outPayload;  // visible cluster << 7 | triangle
layout(location = 1) flat out uint outFlags;

void main() {
    GpuFrame frame = frameConstants;
    uint slot = SlotListRef(frame.hardwareList).data[DOUBLE_SIDED ? frame.counts.y - 1u - gl_InstanceIndex : gl_InstanceIndex];
    uvec2 visible = visible_cluster(frame, slot);
    GpuCluster cluster = load_cluster(frame, visible.y);
    uint triangle = uint(gl_VertexIndex) / 3u;
    if (triangle >= cluster.triangleCount) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // outside the clip volume: the triangle is discarded
        outPayload = 0u;
        outFlags = 0u;
        return;
    }
    // The transform and flags from the cull's record of the cluster (shared.h GpuVisibleRecord): 4 fetches per vertex
    // where the instance and its batch took 7 (--no-lod's hardware raster 0.92x on lavapipe, session 36).
    GpuVisibleRecord record = load_visible_record(frame, slot);
    Instance instance = record_instance(record);
    bool flip = (instance.flags & TS_INSTANCE_FLIP_WINDING) != 0u;
    uint vertex = corner_vertex(frame, cluster, triangle, uint(gl_VertexIndex) % 3u, flip);
    vec3 p = to_camera_relative(instance, camera_relative_translation(instance), vertex_position(frame, vertex));
    gl_Position = frame.viewProjection * vec4(p, 1.0);
    outPayload = (slot << TS_VIS_TRIANGLE_BITS) | triangle;
    outFlags = instance.flags;
}
