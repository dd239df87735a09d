// Instance and cluster culling: one workgroup per instance. A visible instance's clusters are tested
// against the frustum and the survivors appended to the visible-cluster list that the raster pass draws.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"

layout(local_size_x = TS_CULL_GROUP_SIZE) in;

void main() {
    GpuFrame frame = push.frame.f;
    uint instanceIndex = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (instanceIndex >= frame.counts.x) return;

    GpuInstance instance = InstanceRef(frame.instances).data[instanceIndex];
    GpuMesh mesh = MeshRef(frame.meshes).data[instance.meshIndex];
    vec3 translation = camera_relative_translation(instance);
    float scale = instance_scale(instance);
    if (!sphere_in_frustum(frame, to_camera_relative(instance, translation, mesh.sphere.xyz), mesh.sphere.w * scale)) return;

    DrawStateRef draw = DrawStateRef(frame.drawState);
    if (gl_LocalInvocationIndex == 0) atomicAdd(draw.state.visibleInstances, 1u);
    uint capacity = frame.counts.y;
    for (uint c = gl_LocalInvocationIndex; c < mesh.clusterCount; c += TS_CULL_GROUP_SIZE) {
        uint clusterIndex = mesh.clusterOffset + c;
        GpuCluster cluster = ClusterRef(frame.clusters).data[clusterIndex];
        if (!sphere_in_frustum(frame, to_camera_relative(instance, translation, cluster.sphere.xyz), cluster.sphere.w * scale)) continue;
        // Count every visible cluster, store those that fit: the CPU sees the overflow, grows the list and redraws.
        uint slot = atomicAdd(draw.state.visibleClusters, 1u);
        atomicAdd(draw.state.visibleTriangles, cluster.triangleCount);
        if (slot < capacity) {
            VisibleClusterRef(frame.visibleClusters).data[slot] = uvec2(instanceIndex, clusterIndex);
            atomicMax(draw.state.instanceCount, slot + 1u);
        }
    }
}
