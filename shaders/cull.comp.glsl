// Instance culling and the DAG cut, in two passes, each of two steps (TS_CULL_*): a pipeline per step (TS_SPEC_STEP).
// Main pass: instances are tested one per thread (frustum, previous HZB), then one workgroup per listed instance
// tests the clusters of the DAG levels its distance allows; a cluster is drawn iff its own error, projected to the
// screen, is within the threshold while its parent's is not, and its bounds touch the frustum. With two-pass occlusion, instances and clusters that the
// previous frame's HZB hides are deferred instead of drawn. Survivors are appended to the visible-cluster list.
// Post pass: the deferred instances and clusters are tested against an HZB of what the main pass drew; those it
// does not hide are drawn. Nothing is lost: whatever the main pass leaves out, the post pass tests against
// geometry that really is in front of it this frame.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"
#include "occlusion.h"

layout(local_size_x = TS_CULL_GROUP_SIZE, local_size_x_id = TS_SPEC_CULL_GROUP_SIZE) in;  // the device's size
// This pipeline's step (TS_CULL_*): only its code is compiled in. Fixed per module (shaders/CMakeLists.txt builds one
// per step, TS_MODULE_STEP): lavapipe translates all of a module's code before specialization drops the other steps',
// which cost each step's pipeline 110-300 ms to compile.
const uint STEP = TS_MODULE_STEP;

const float NEVER_FINE_ENOUGH = 3.4e38;

// Screen-space size in pixels of an error of `error` mesh units anywhere in `sphere` (mesh space): measured at
// the sphere's nearest view depth, so the estimate is conservative. Every cluster that shares a sphere and
// an error gets the same answer, which keeps siblings and parents consistent (a cut without cracks).
float projected_error(GpuFrame frame, Instance instance, vec3 translation, float scale, vec4 sphere, float error) {
    if (error >= TS_ROOT_ERROR) return NEVER_FINE_ENOUGH;
    if (error <= 0.0) return 0.0;  // exact (source triangles): fine enough even from inside its sphere
    float size = error * scale * frame.lod.x;
    if (frame.lod.z != 0.0) return size;  // orthographic: independent of distance
    vec3 center = to_camera_relative(instance, translation, sphere.xyz);
    float depth = dot(center, frame.cameraForward.xyz) - sphere.w * scale;
    return depth > 0.0 ? size / depth : NEVER_FINE_ENOUGH;
}

// Small triangles go to the compute rasterizer: the cluster must lie beyond the near plane (no clipping there), its
// longest edge must project to a bounded length, and its triangles' mean area, both projected at the cluster's nearest
// depth, must be below the measured crossover.
bool software_raster(GpuFrame frame, vec3 center, float radius, float scale, GpuCluster cluster) {
    if ((frame.counts.z & TS_FRAME_HARDWARE_ONLY) != 0u) return false;
    float nearest = depth_range(frame, center, radius).x;
    if (nearest <= frame.lod.w * 1.001) return false;  // touches the near plane: hardware clips
    float pixelsPerUnit = scale * frame.lod.x / (frame.lod.z != 0.0 ? 1.0 : nearest);
    if (cluster.longestEdge * pixelsPerUnit > TS_SW_MAX_EDGE_PIXELS) return false;
    if ((frame.counts.z & TS_FRAME_SOFTWARE_FIRST) != 0u) return true;
    return cluster.meanTriangleArea * pixelsPerUnit * pixelsPerUnit < frame.raster.x;
}

// The exact range over the ball |p - center| <= radius (camera-relative world) of the projective coordinate
// dot(row, (p, 1)) / dot(rowW, (p, 1)), rows of the view-projection matrix: its extremes t are where the plane
// dot(row - t rowW, (p, 1)) = 0 touches the sphere, the roots of a quadratic (written so that no large terms cancel).
// Needs the whole ball on the positive side of rowW (beyond the camera plane); orthographic cameras included (rowW =
// (0, 0, 0, 1): the centre's coordinate plus or minus radius |row.xyz|). The 2D bound of a perspective-projected sphere
// (Mara and McGuire 2013), for any projection matrix.
vec2 sphere_ndc_range(vec4 row, vec4 rowW, vec3 center, float radius) {
    float a = dot(row.xyz, center) + row.w, w = dot(rowW.xyz, center) + rowW.w, r2 = radius * radius;
    vec3 tilt = w * row.xyz - a * rowW.xyz, axis = cross(row.xyz, rowW.xyz);
    float spread = radius * sqrt(max(dot(tilt, tilt) - r2 * dot(axis, axis), 0.0));
    float middle = a * w - r2 * dot(row.xyz, rowW.xyz);
    return vec2(middle - spread, middle + spread) / (w * w - r2 * dot(rowW.xyz, rowW.xyz));
}

// True when the sphere (camera-relative) certainly projects to less than TS_SW_SMALL_TRIANGLE_SUBPIXELS across in x and
// in y, and so does every triangle inside it as the compute rasterizer snaps it: its front-of-list variant scans with
// 32-bit edge functions only (raster.h). The margins (1 % and 8 sub-pixels) cover float rounding here and in the
// rasterizer's transform, and its rounding to the sub-pixel grid. False for a sphere that reaches the camera plane.
bool small_on_screen(GpuFrame frame, vec3 center, float radius) {
    mat4 m = frame.viewProjection;  // column-major: row i is (m[0][i], m[1][i], m[2][i], m[3][i])
    vec4 rowW = vec4(m[0][3], m[1][3], m[2][3], m[3][3]);
    if (!(dot(rowW.xyz, center) + rowW.w > radius * length(rowW.xyz) * 1.001)) return false;
    vec2 x = sphere_ndc_range(vec4(m[0][0], m[1][0], m[2][0], m[3][0]), rowW, center, radius);
    vec2 y = sphere_ndc_range(vec4(m[0][1], m[1][1], m[2][1], m[3][1]), rowW, center, radius);
    vec2 subpixels = vec2(x.y - x.x, y.y - y.x) * 0.5 * vec2(frame.viewport.xy) * frame.raster.y;
    return max(subpixels.x, subpixels.y) * 1.01 + 8.0 < float(TS_SW_SMALL_TRIANGLE_SUBPIXELS);  // false on NaN too
}

// True when every triangle of the cluster faces away from the camera (camera-relative centre and radius): the
// meshoptimizer cone test, widened by the bounding sphere so that it holds for a viewer anywhere near the cluster.
bool facing_away(GpuFrame frame, Instance instance, GpuCluster cluster, vec3 center, float radius) {
    if ((frame.counts.z & TS_FRAME_BACKFACES) == 0u || (frame.counts.z & TS_FRAME_NO_LOD) != 0u) return false;
    if ((instance.flags & (TS_INSTANCE_DOUBLE_SIDED | TS_INSTANCE_CONFORMAL | TS_INSTANCE_DISPLACED)) != TS_INSTANCE_CONFORMAL) return false;
    vec4 cone = unpackSnorm4x8(cluster.normalCone);
    if (cone.w >= 1.0) return false;  // the normals spread too wide
    vec3 axis = normalize(vec3(dot(instance.rows[0].xyz, cone.xyz), dot(instance.rows[1].xyz, cone.xyz), dot(instance.rows[2].xyz, cone.xyz)));
    if (frame.lod.z != 0.0) return dot(frame.cameraForward.xyz, axis) >= cone.w;  // orthographic: one view direction
    return dot(center, axis) >= cone.w * length(center) + radius;
}

// True when a displaced instance's cluster is diced: unless the displacement, seen from the cluster's nearest point,
// projects to no more than its material's fade-end size, where it has faded out entirely (tessellation.h). Clusters of
// instances with material tables are always diced (each triangle fades by its own material).
bool tessellated(GpuFrame frame, Instance instance, vec3 center, float radius, float scale) {
    if (!instance_flag(instance, TS_INSTANCE_DISPLACED)) return false;
    if (instance_flag(instance, TS_INSTANCE_MATERIAL_SLOTS)) return true;
    GpuMaterial material = load_material(frame, instance.materialIndex);
    float size = material.displacement.w * scale * frame.lod.x;
    if (frame.lod.z == 0.0) {
        float nearest = depth_range(frame, center, radius).x;
        if (nearest <= frame.lod.w) return true;
        size /= nearest;
    }
    return size > material.displacementFade.y * 0.999;  // the margin covers rounding against the per-point fade
}

// Appends a cluster to the visible list and to its rasterizer's list (or, diced, to the tessellation list). Every
// visible cluster is counted and those that fit are stored: the CPU sees an overflow, grows the list and redraws.
void draw_cluster(GpuFrame frame, uint step, uint instanceIndex, uint clusterIndex, GpuCluster cluster, vec3 center, float radius, float scale) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    uint slot = atomicAdd(draw.state.visibleClusters, 1u);
    if (step == TS_CULL_POST) atomicAdd(draw.state.postClusters, 1u);
    Instance instance = load_instance(frame, instanceIndex);
    if (tessellated(frame, instance, center, radius, scale)) {
        atomicAdd(draw.state.tessClustersDrawn, 1u);
        if (slot >= frame.counts.y) return;
        VisibleClusterRef(frame.visibleClusters).data[slot] = uvec2(instanceIndex, clusterIndex);  // no record: it is diced
        uint k = atomicAdd(draw.state.tessClusters, 1u);
        SlotListRef(frame.tessellationList).data[k] = slot;
        atomicMax(draw.state.tessGroupsX, min(k + 1u, 65535u));
        atomicMax(draw.state.tessGroupsY, k / 65535u + 1u);
        return;
    }
    bool software = software_raster(frame, center, radius, scale, cluster);
    if (software) atomicAdd(draw.state.swTriangles, cluster.triangleCount);
    else atomicAdd(draw.state.hwTriangles, cluster.triangleCount);
    if (slot >= frame.counts.y) return;
    VisibleClusterRef(frame.visibleClusters).data[slot] = uvec2(instanceIndex | (software ? TS_VISIBLE_SOFTWARE : 0u), clusterIndex);
    store_visible_record(frame, slot, instance, cluster);
    if (software) {
        // Clusters of certainly small triangles from the front of the software list, the others from its back: each end
        // has its own variant of the compute rasterizer. Both ends together hold at most the slots stored this pass, so
        // they cannot meet; past capacity, the visible list's overflow (grow, redraw) covers them.
        atomicAdd(draw.state.swClustersDrawn, 1u);
        if (small_on_screen(frame, center, radius)) {
            uint k = atomicAdd(draw.state.swClusters, 1u);
            SlotListRef(frame.softwareList).data[k] = slot;
            atomicMax(draw.state.swGroupsX, min(k + 1u, 65535u));
            atomicMax(draw.state.swGroupsY, k / 65535u + 1u);
        } else {
            atomicAdd(draw.state.swLargeClustersDrawn, 1u);
            uint k = atomicAdd(draw.state.swLargeClusters, 1u);
            SlotListRef(frame.softwareList).data[frame.counts.y - 1u - k] = slot;
            atomicMax(draw.state.swLargeGroupsX, min(k + 1u, 65535u));
            atomicMax(draw.state.swLargeGroupsY, k / 65535u + 1u);
        }
    } else if ((instance.flags & TS_INSTANCE_DOUBLE_SIDED) == 0u) {
        uint k = atomicAdd(draw.state.instanceCount, 1u);  // drawn with back faces culled
        SlotListRef(frame.hardwareList).data[k] = slot;
    } else {
        // Double-sided: from the back of the list, for the variant that culls nothing. Both ends together hold at most
        // the slots stored this pass, so they cannot meet.
        uint k = atomicAdd(draw.state.doubleSidedInstanceCount, 1u);
        SlotListRef(frame.hardwareList).data[frame.counts.y - 1u - k] = slot;
    }
}

// Leaves a cluster to the post pass (enough post workgroups are requested for its thread to exist).
void defer_cluster(GpuFrame frame, uint instanceIndex, uint clusterIndex) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    uint k = atomicAdd(draw.state.deferredClusters, 1u);
    if (k >= frame.counts.y) return;
    VisibleClusterRef(frame.deferredClusters).data[k] = uvec2(instanceIndex, clusterIndex);
    atomicMax(draw.state.postGroupsX, min(k / gl_WorkGroupSize.x + 1u, 65535u));
}

// False when no cluster of the block can be drawn for this instance: all too coarse from wherever they are, all with
// parents fine enough, or all outside the frustum (`extra`: how far displacement may move a cluster, mesh units). The
// tests mirror the per-cluster ones on spheres enclosing the clusters', with the level skip's margins against rounding.
bool block_may_draw(GpuFrame frame, Instance instance, vec3 translation, float scale, GpuCutBlock block, float extra) {
    float threshold = frame.lod.y;
    float far = dot(to_camera_relative(instance, translation, block.lodSphere.xyz), frame.cameraForward.xyz) + block.lodSphere.w * scale;
    float farScale = frame.lod.z != 0.0 ? frame.lod.x : (far > 0.0 ? frame.lod.x / far : NEVER_FINE_ENOUGH);
    if (block.minLodError * scale * farScale > threshold * 1.0001) return false;  // every cluster too coarse
    if (block.maxParentError < TS_ROOT_ERROR) {
        float near = dot(to_camera_relative(instance, translation, block.parentSphere.xyz), frame.cameraForward.xyz) - block.parentSphere.w * scale;
        float nearScale = frame.lod.z != 0.0 ? frame.lod.x : (near > 0.0 ? frame.lod.x / near : NEVER_FINE_ENOUGH);
        if (block.maxParentError * scale * nearScale < threshold * 0.9999) return false;  // every parent fine enough
    }
    return sphere_in_frustum(frame, to_camera_relative(instance, translation, block.sphere.xyz), (block.sphere.w + extra) * scale);
}

// One cluster of the instance's cut: drawn iff fine enough while its parent is not, in the frustum, facing the camera and
// not hidden (the main pass defers what the previous frame's HZB hides).
void test_cluster(GpuFrame frame, uint step, uint instanceIndex, Instance instance, GpuMesh mesh, vec3 translation, float scale, bool lod,
                  uint clusterInMesh) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    float threshold = frame.lod.y;
    uint clusterIndex = mesh.clusterOffset + clusterInMesh;
    GpuCluster cluster = load_cluster(frame, clusterIndex);
    if (lod) {
        if (projected_error(frame, instance, translation, scale, cluster.lodSphere, cluster.lodError) > threshold) return;
        if (projected_error(frame, instance, translation, scale, cluster.parentSphere, cluster.parentError) <= threshold) return;
    }
    vec3 center = to_camera_relative(instance, translation, cluster.sphere.xyz);
    float radius = (cluster.sphere.w + cluster_displacement(frame, instance, clusterInMesh)) * scale;  // widened by its displacement
    if (!sphere_in_frustum(frame, center, radius)) return;
    if (facing_away(frame, instance, cluster, center, radius)) {
        atomicAdd(draw.state.backfaceClusters, 1u);
        return;
    }
    if (hidden(frame, step, center, radius)) {
        if (step == TS_CULL_MAIN) defer_cluster(frame, instanceIndex, clusterIndex);
        else atomicAdd(draw.state.occludedClusters, 1u);
        return;
    }
    draw_cluster(frame, step, instanceIndex, clusterIndex, cluster, center, radius, scale);
}

// Pixels per unit of error at the nearest and at the farthest depth of the instance's LOD radius (orthographic: both
// the same): every projected error of its mesh lies between error times these.
struct LevelScales { float nearScale, farScale; };

// False when the instance's distance rules a whole level out: all its clusters too coarse, or all its parents fine
// enough. The margins keep rounding from skipping a level that the per-cluster test would draw from.
bool level_in_cut(GpuFrame frame, GpuLevel level, float scale, LevelScales s) {
    float threshold = frame.lod.y;
    if (level.minLodError * scale * s.farScale > threshold * 1.0001) return false;
    return !(level.maxParentError < TS_ROOT_ERROR && level.maxParentError * scale * s.nearScale < threshold * 0.9999);
}

// The instance's level scales: every LOD sphere of the mesh lies inside its LOD radius, so that sphere's depth range
// bounds each projected error.
LevelScales level_scales(GpuFrame frame, Instance instance, GpuMesh mesh, vec3 translation, float scale) {
    vec3 meshCenter = to_camera_relative(instance, translation, mesh.sphere.xyz);
    vec2 depths = depth_range(frame, meshCenter, mesh.lodRadius * scale);
    return LevelScales(frame.lod.z != 0.0 ? frame.lod.x : (depths.x > 0.0 ? frame.lod.x / depths.x : NEVER_FINE_ENOUGH),
                       frame.lod.z != 0.0 ? frame.lod.x : (depths.y > 0.0 ? frame.lod.x / depths.y : NEVER_FINE_ENOUGH));
}

// The levels the instance's distance leaves in the cut (level_in_cut), first to last, and the clusters they hold: what
// its cut walks at most. Without LOD, level 0. The cut's loops then walk those levels only: on lavapipe a level a loop
// skips (continue) still runs the loop's whole body, masked, and a 1e10 field's prototype has 18 levels, its far
// instances two or three in the cut (docs/benchmarks.md, session 30).
struct LevelsInCut { uint first, last, clusters; };

LevelsInCut levels_in_cut(GpuFrame frame, GpuMesh mesh, float scale, LevelScales s, bool lod) {
    LevelsInCut range = LevelsInCut(1u, 0u, 0u);  // none: a mesh left out (an error) has no level
    if (mesh.levelCount == 0u) return range;
    if (!lod) return LevelsInCut(0u, 0u, load_level(frame, mesh.levelOffset).clusterCount);
    range.first = mesh.levelCount;
    uint l = 0u;
    do {  // the test at the end (frame.h)
        GpuLevel level = load_level(frame, mesh.levelOffset + l);
        if (level_in_cut(frame, level, scale, s)) {
            range.first = min(range.first, l);
            range.last = l;
            range.clusters += level.clusterCount;
        }
    } while (++l < mesh.levelCount);
    return range;
}

// One of the workgroups that share an instance's cut (cut_parts): part `index`, whose threads take every `threads`-th
// block or cluster from `firstThread`.
struct CutPart { uint index, firstThread, threads; };

// The cut by clusters: each cluster of each level in the cut, spread over the threads.
void cut_by_clusters(GpuFrame frame, uint step, uint instanceIndex, CutPart part, Instance instance, GpuMesh mesh, vec3 translation,
                     float scale, bool lod, LevelScales s, LevelsInCut levels) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    uint l = levels.first;
    if (l <= levels.last) do {  // the tests at the end (frame.h)
        GpuLevel level = load_level(frame, mesh.levelOffset + l);
        if (lod && !level_in_cut(frame, level, scale, s)) continue;
        if (gl_LocalInvocationIndex == 0 && part.index == 0u) atomicAdd(draw.state.candidateClusters, level.clusterCount);
        uint c = part.firstThread;
        if (c < level.clusterCount) do {
            test_cluster(frame, step, instanceIndex, instance, mesh, translation, scale, lod, level.clusterOffset + c);
        } while ((c += part.threads) < level.clusterCount);
    } while (++l <= levels.last);
}

// The cut by blocks: each block of each level in the cut, spread over the threads; a thread tests the clusters of
// each of its blocks that may draw.
void cut_by_blocks(GpuFrame frame, uint step, uint instanceIndex, CutPart part, Instance instance, GpuMesh mesh, vec3 translation,
                   float scale, LevelScales s, LevelsInCut levels) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    float extra = instance_displacement(frame, instance);  // bounds every cluster's own (cluster_displacement)
    uint l = levels.first;
    if (l <= levels.last) do {  // the tests at the end (frame.h)
        GpuLevel level = load_level(frame, mesh.levelOffset + l);
        if (!level_in_cut(frame, level, scale, s)) continue;
        uint b = part.firstThread;
        if (b < level.blockCount) do {
            GpuCutBlock block = load_cut_block(frame, level.blockOffset + b);
            if (!block_may_draw(frame, instance, translation, scale, block, extra)) continue;
            atomicAdd(draw.state.candidateClusters, block.clusterCount);
            uint k = 0u;
            do {  // a block holds at least one cluster
                test_cluster(frame, step, instanceIndex, instance, mesh, translation, scale, true, block_cluster(frame, block.firstCluster + k));
            } while (++k < block.clusterCount);
        } while ((b += part.threads) < level.blockCount);
    } while (++l <= levels.last);
}

// The DAG cut of one instance whose sphere touches the frustum and is not hidden, by this workgroup (alone, or with the
// other parts of a cut list entry's instance: cut_parts, each thread of each part taking its share): a hierarchy of
// the levels the instance's distance allows, then (for an instance with many clusters in those levels) the blocks of
// those levels that may hold a cluster to draw (GpuCutBlock), then clusters. The choice is made per instance: lavapipe
// runs both sides of every branch, masked, so a per-level choice cost the field's instances, which test few
// clusters, a masked pass of the block code on every level (twice the cull of the 1e10 field).
void cut_instance(GpuFrame frame, uint step, uint entry, uint entries) {
    // An instance's parts are consecutive entries of the cut list, each holding the instance (list_for_cut); the list
    // names each instance once per pass, so the run of equal entries around this one is its instance's parts.
    UintRef list = UintRef(frame.cutList);
    uint instanceIndex = list.data[entry], first = entry, end = entry + 1u;
    while (first > 0u && entry - first < TS_CUT_MOST_PARTS && list.data[first - 1u] == instanceIndex) --first;
    while (end < entries && end - first < TS_CUT_MOST_PARTS && list.data[end] == instanceIndex) ++end;
    CutPart part = CutPart(entry - first, (entry - first) * gl_WorkGroupSize.x + gl_LocalInvocationIndex, (end - first) * gl_WorkGroupSize.x);
    Instance instance = load_instance(frame, instanceIndex);
    GpuMesh mesh = load_mesh(frame, instance.meshIndex);
    vec3 translation = camera_relative_translation(instance);
    float scale = instance_scale(instance);

    DrawStateRef draw = DrawStateRef(frame.drawState);
    if (gl_LocalInvocationIndex == 0 && part.index == 0u) atomicAdd(draw.state.visibleInstances, 1u);
    bool lod = (frame.counts.z & TS_FRAME_NO_LOD) == 0u;
    LevelScales s = level_scales(frame, instance, mesh, translation, scale);
    LevelsInCut levels = levels_in_cut(frame, mesh, scale, s, lod);
    bool blocks = lod && (frame.counts.z & TS_FRAME_NO_CUT_BLOCKS) == 0u && levels.clusters > TS_CUT_BLOCKS_FROM * gl_WorkGroupSize.x;
    if (blocks) cut_by_blocks(frame, step, instanceIndex, part, instance, mesh, translation, scale, s, levels);
    else cut_by_clusters(frame, step, instanceIndex, part, instance, mesh, translation, scale, lod, s, levels);
}

// How many workgroups share an instance's cut (its cut list entries): one per frame.hzb.w >> 16 clusters its levels in
// the cut hold, at most frame.hzb.w & 0xffff (and TS_CUT_MOST_PARTS). A single large mesh seen from close by walks tens
// of thousands of clusters, which one workgroup (one multiprocessor of a GPU, one thread of lavapipe) walked alone.
uint cut_parts(GpuFrame frame, Instance instance) {
    uint most = frame.hzb.w & 0xffffu, clustersPerPart = max(frame.hzb.w >> 16, 1u);
    GpuMesh mesh = load_mesh(frame, instance.meshIndex);
    if (most <= 1u || mesh.clusterCount < 2u * clustersPerPart) return 1u;
    vec3 translation = camera_relative_translation(instance);
    float scale = instance_scale(instance);
    bool lod = (frame.counts.z & TS_FRAME_NO_LOD) == 0u;
    uint inCut = levels_in_cut(frame, mesh, scale, level_scales(frame, instance, mesh, translation, scale), lod).clusters;
    return clamp(inCut / clustersPerPart, 1u, min(most, TS_CUT_MOST_PARTS));
}

vec4 instance_sphere(GpuFrame frame, Instance instance) {
    GpuMesh mesh = load_mesh(frame, instance.meshIndex);
    float scale = instance_scale(instance);
    return vec4(to_camera_relative(instance, camera_relative_translation(instance), mesh.sphere.xyz),
                mesh.sphere.w * scale + instance_displacement(frame, instance) * scale);
}

// Steps *_INSTANCES: one thread per instance (main) or per deferred instance (post). An instance that a material
// cuts out entirely, outside the frustum, or hidden, goes no further; the main pass defers those the previous
// frame's HZB hides; the rest are listed for the cut step.
void list_for_cut(GpuFrame frame, uint step, uint instanceIndex, Instance instance) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    uint parts = cut_parts(frame, instance);
    uint k = atomicAdd(draw.state.cutInstances, parts), end = k + parts;
    atomicMax(draw.state.cutInstancesNeeded, end);
    // Past the capacity: overflow, the CPU grows the list and redraws (the parts that fit are written all the same:
    // every entry the cut step reads holds an instance of this frame).
    for (uint p = k; p < min(end, frame.hzb.y); ++p) SlotListRef(frame.cutList).data[p] = instanceIndex;
    if (end > frame.hzb.y) return;
    if (step == TS_CULL_MAIN_INSTANCES) {
        atomicMax(draw.state.cutGroupsX, min(end, 65535u));
        atomicMax(draw.state.cutGroupsY, (end - 1u) / 65535u + 1u);
    } else {
        atomicMax(draw.state.postGroupsX, min(end, 65535u));  // the post cut step also strides over deferred clusters
    }
}

// Without a previous frame's HZB the main pass draws only the instances likely to hide others (TS_OCCLUDER_FRACTION):
// large on screen, or reaching the camera plane. The others wait for the post pass and its HZB of these.
bool likely_occluder(GpuFrame frame, vec4 sphere) {
    float least = TS_OCCLUDER_FRACTION * float(min(frame.viewport.x, frame.viewport.y));
    if (frame.lod.z != 0.0) return sphere.w * frame.lod.x >= least;
    float depth = dot(sphere.xyz, frame.cameraForward.xyz);
    return depth <= sphere.w || sphere.w * frame.lod.x >= least * depth;
}

void test_instance(GpuFrame frame, uint step, uint thread) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    if (step == TS_CULL_MAIN_INSTANCES) {
        if (thread >= frame.counts.x) return;
        Instance instance = load_instance(frame, thread);
        if ((instance.flags & TS_INSTANCE_MATERIAL_SLOTS) == 0u &&
            (load_material(frame, instance.materialIndex).flags & TS_MATERIAL_CUT_OUT) != 0u) return;  // masked away entirely
        vec4 sphere = instance_sphere(frame, instance);
        if (!sphere_in_frustum(frame, sphere.xyz, sphere.w)) return;
        bool previous = (frame.counts.z & TS_FRAME_PREVIOUS_HZB) != 0u;
        bool deferred = previous ? hidden(frame, TS_CULL_MAIN, sphere.xyz, sphere.w)
                                 : (frame.counts.z & TS_FRAME_OCCLUSION) != 0u && !likely_occluder(frame, sphere);
        if (deferred) {
            uint k = atomicAdd(draw.state.deferredInstances, 1u);
            if (k >= frame.hzb.z) return;  // overflow: the CPU grows the list and redraws
            SlotListRef(frame.deferredInstances).data[k] = thread;
            atomicMax(draw.state.postInstanceGroupsX, min(k / TS_CULL_INSTANCES_PER_GROUP + 1u, 65535u));
            atomicMax(draw.state.postInstanceGroupsY, k / TS_CULL_INSTANCES_PER_GROUP / 65535u + 1u);
            return;
        }
        list_for_cut(frame, step, thread, instance);
    } else {
        if (thread >= min(draw.state.deferredInstances, frame.hzb.z)) return;
        uint instanceIndex = UintRef(frame.deferredInstances).data[thread];
        Instance instance = load_instance(frame, instanceIndex);
        vec4 sphere = instance_sphere(frame, instance);
        if (hidden(frame, TS_CULL_POST, sphere.xyz, sphere.w)) {
            atomicAdd(draw.state.occludedInstances, 1u);
            return;
        }
        list_for_cut(frame, step, instanceIndex, instance);
    }
}

// A workgroup tests TS_CULL_INSTANCES_PER_GROUP consecutive instances, each thread every gl_WorkGroupSize.x-th: on
// lavapipe a workgroup of this shader costs about 30 us before it does anything, so each must do much.
void test_instances(GpuFrame frame, uint step) {
    uint first = (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * TS_CULL_INSTANCES_PER_GROUP;
    uint i = gl_LocalInvocationIndex;
    do test_instance(frame, step, first + i); while ((i += gl_WorkGroupSize.x) < TS_CULL_INSTANCES_PER_GROUP);
}

// Main pass: one workgroup per cut list entry (a part of an instance's cut).
void main_pass(GpuFrame frame) {
    uint entry = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (entry >= min(DrawStateRef(frame.drawState).state.cutInstances, frame.hzb.y)) return;
    cut_instance(frame, TS_CULL_MAIN, entry, min(DrawStateRef(frame.drawState).state.cutInstances, frame.hzb.y));
}

// Post pass: workgroups take the cut list's entries in turn; every thread takes deferred clusters in turn.
void post_pass(GpuFrame frame) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    uint instances = min(draw.state.cutInstances, frame.hzb.y);
    uint i = gl_WorkGroupID.x;
    if (i < instances) do {  // the tests at the end (frame.h)
        cut_instance(frame, TS_CULL_POST, i, instances);
    } while ((i += gl_NumWorkGroups.x) < instances);
    uint clusters = min(draw.state.deferredClusters, frame.counts.y);
    i = gl_GlobalInvocationID.x;
    if (i < clusters) do {
        uvec2 entry = VisibleClusterRef(frame.deferredClusters).data[i];
        Instance instance = load_instance(frame, entry.x);
        GpuCluster cluster = load_cluster(frame, entry.y);
        float scale = instance_scale(instance);
        vec3 center = to_camera_relative(instance, camera_relative_translation(instance), cluster.sphere.xyz);
        float displacement = (instance.flags & TS_INSTANCE_DISPLACED) != 0u
            ? cluster_displacement(frame, instance, entry.y - load_mesh(frame, instance.meshIndex).clusterOffset) : 0.0;
        float radius = (cluster.sphere.w + displacement) * scale;
        if (hidden(frame, TS_CULL_POST, center, radius)) atomicAdd(draw.state.occludedClusters, 1u);
        else draw_cluster(frame, TS_CULL_POST, entry.x, entry.y, cluster, center, radius, scale);
    } while ((i += gl_NumWorkGroups.x * gl_WorkGroupSize.x) < clusters);
}

void main() {
    GpuFrame frame = frameConstants;
    if (STEP == TS_CULL_MAIN) main_pass(frame);
    else if (STEP == TS_CULL_POST) post_pass(frame);
    else test_instances(frame, STEP);
}
