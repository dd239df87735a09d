// Instance culling and the DAG cut: one workgroup per instance. A visible instance tests the clusters of
// the DAG levels its distance allows; a cluster is drawn iff its own error, projected to the screen, is
// within the threshold while its parent's is not, and its bounds touch the frustum. Survivors are appended
// to the visible-cluster list that the raster pass draws.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"

layout(local_size_x = TS_CULL_GROUP_SIZE) in;

const float NEVER_FINE_ENOUGH = 3.4e38;

// Screen-space size in pixels of an error of `error` mesh units anywhere in `sphere` (mesh space): measured at
// the sphere's nearest view depth, so the estimate is conservative. Every cluster that shares a sphere and
// an error gets the same answer, which keeps siblings and parents consistent (a cut without cracks).
float projected_error(GpuFrame frame, GpuInstance instance, vec3 translation, float scale, vec4 sphere, float error) {
    if (error >= TS_ROOT_ERROR) return NEVER_FINE_ENOUGH;
    float size = error * scale * frame.lod.x;
    if (frame.lod.z != 0.0) return size;  // orthographic: independent of distance
    vec3 center = to_camera_relative(instance, translation, sphere.xyz);
    float depth = dot(center, frame.cameraForward.xyz) - sphere.w * scale;
    return depth > 0.0 ? size / depth : NEVER_FINE_ENOUGH;
}

// Small triangles go to the compute rasterizer: the cluster must lie beyond the near plane (no clipping there),
// project to a bounded radius, and its triangles' mean area, projected at the cluster's nearest depth, must be
// below the measured crossover.
bool software_raster(GpuFrame frame, vec3 center, float radius, float scale, float meanTriangleArea) {
    if ((frame.counts.z & TS_FRAME_HARDWARE_ONLY) != 0u) return false;
    float nearest = depth_range(frame, center, radius).x;
    if (nearest <= frame.lod.w * 1.001) return false;  // touches the near plane: hardware clips
    float radiusPixels = radius * frame.lod.x / (frame.lod.z != 0.0 ? 1.0 : nearest);
    if (radiusPixels > TS_SW_MAX_RADIUS_PIXELS) return false;
    if ((frame.counts.z & TS_FRAME_SOFTWARE_FIRST) != 0u) return true;
    float pixelsPerUnit = scale * frame.lod.x / (frame.lod.z != 0.0 ? 1.0 : nearest);
    return meanTriangleArea * pixelsPerUnit * pixelsPerUnit < frame.raster.x;
}

void main() {
    GpuFrame frame = push.frame.f;
    uint instanceIndex = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (instanceIndex >= frame.counts.x) return;

    GpuInstance instance = InstanceRef(frame.instances).data[instanceIndex];
    GpuMesh mesh = MeshRef(frame.meshes).data[instance.meshIndex];
    vec3 translation = camera_relative_translation(instance);
    float scale = instance_scale(instance);
    vec3 meshCenter = to_camera_relative(instance, translation, mesh.sphere.xyz);
    float meshRadius = mesh.sphere.w * scale;
    if (!sphere_in_frustum(frame, meshCenter, meshRadius)) return;

    DrawStateRef draw = DrawStateRef(frame.drawState);
    if (gl_LocalInvocationIndex == 0) atomicAdd(draw.state.visibleInstances, 1u);
    bool lod = (frame.counts.z & TS_FRAME_NO_LOD) == 0u;
    float threshold = frame.lod.y;
    // Every LOD sphere of the mesh lies inside its LOD radius, so that sphere's depth range bounds each projected
    // error: a level all of whose clusters are too coarse, or all of whose parents are fine enough, is skipped
    // whole. The margins keep rounding from skipping a level that the per-cluster test would draw from.
    vec2 depths = depth_range(frame, meshCenter, mesh.lodRadius * scale);
    float nearScale = frame.lod.z != 0.0 ? frame.lod.x : (depths.x > 0.0 ? frame.lod.x / depths.x : NEVER_FINE_ENOUGH);
    float farScale = frame.lod.z != 0.0 ? frame.lod.x : (depths.y > 0.0 ? frame.lod.x / depths.y : NEVER_FINE_ENOUGH);
    uint capacity = frame.counts.y;
    uint levelCount = lod ? mesh.levelCount : 1u;
    for (uint l = 0u; l < levelCount; ++l) {
        GpuLevel level = LevelRef(frame.levels).data[mesh.levelOffset + l];
        if (lod) {
            if (level.minLodError * scale * farScale > threshold * 1.0001) continue;  // every cluster too coarse here
            if (level.maxParentError < TS_ROOT_ERROR && level.maxParentError * scale * nearScale < threshold * 0.9999) continue;  // every parent fine enough
        }
        if (gl_LocalInvocationIndex == 0) atomicAdd(draw.state.candidateClusters, level.clusterCount);
        for (uint c = gl_LocalInvocationIndex; c < level.clusterCount; c += TS_CULL_GROUP_SIZE) {
            uint clusterIndex = mesh.clusterOffset + level.clusterOffset + c;
            GpuCluster cluster = ClusterRef(frame.clusters).data[clusterIndex];
            if (lod) {
                if (projected_error(frame, instance, translation, scale, cluster.lodSphere, cluster.lodError) > threshold) continue;
                if (projected_error(frame, instance, translation, scale, cluster.parentSphere, cluster.parentError) <= threshold) continue;
            }
            vec3 center = to_camera_relative(instance, translation, cluster.sphere.xyz);
            float radius = cluster.sphere.w * scale;
            if (!sphere_in_frustum(frame, center, radius)) continue;
            // Count every visible cluster, store those that fit: the CPU sees the overflow, grows the list and redraws.
            uint slot = atomicAdd(draw.state.visibleClusters, 1u);
            bool software = software_raster(frame, center, radius, scale, cluster.meanTriangleArea);
            if (software) atomicAdd(draw.state.swTriangles, cluster.triangleCount);
            else atomicAdd(draw.state.hwTriangles, cluster.triangleCount);
            if (slot < capacity) {
                VisibleClusterRef(frame.visibleClusters).data[slot] = uvec2(instanceIndex | (software ? TS_VISIBLE_SOFTWARE : 0u), clusterIndex);
                if (software) {
                    uint k = atomicAdd(draw.state.swClusters, 1u);
                    SlotListRef(frame.softwareList).data[k] = slot;
                    atomicMax(draw.state.swGroupsX, min(k + 1u, 65535u));
                } else {
                    uint k = atomicAdd(draw.state.instanceCount, 1u);
                    SlotListRef(frame.hardwareList).data[k] = slot;
                }
            }
        }
    }
}
