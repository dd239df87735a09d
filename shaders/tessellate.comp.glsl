// Tessellate: one workgroup per cluster of the tessellation list (clusters of displaced instances near enough for
// their displacement to show), one thread per triangle. Each triangle gets its edge factors and is split into patches
// (tessellation.h); each patch is stored and listed for the compute patch rasterizer (dice.comp.glsl) when it lies
// beyond the near plane and is small on screen, else given an indirect draw of its own, 3 vertices per micro-triangle,
// for the patch raster's hardware path (patch.vert.glsl). Patches are counted past capacity: the CPU grows the list and redraws.
// Patches are culled by the frustum and by occlusion like clusters: in the main pass those the previous frame's HZB
// hides are deferred, and the post pass (step TS_TESS_DEFERRED_PATCHES) tests them against this frame's.
#version 460
#extension GL_GOOGLE_include_directive : require
#include "frame.h"
#include "occlusion.h"
#include "surface.h"
#include "tessellation.h"

layout(local_size_x = TS_TESS_GROUP_SIZE) in;

// Segments for an edge between camera-relative points a and b: its length on screen (in pixels; where an end lies at
// or before the near plane, its length at the near plane's distance) over the dicing rate; 1 where displacement has
// faded out at both ends. Symmetric in a and b: both triangles of an edge agree.
uint edge_factor(GpuFrame frame, vec3 a, vec3 b, float fadeA, float fadeB, uint most) {
    if (!(fadeA > 0.0) && !(fadeB > 0.0)) return 1u;
    float pixels;
    vec4 ca = frame.viewProjection * vec4(a, 1.0), cb = frame.viewProjection * vec4(b, 1.0);
    if (frame.lod.z == 0.0 && min(ca.w, cb.w) <= frame.lod.w) {
        pixels = length(a - b) * frame.lod.x / frame.lod.w;
    } else {
        vec2 halfSize = 0.5 * vec2(frame.viewport.xy);
        pixels = length((ca.xy / ca.w - cb.xy / cb.w) * halfSize);
    }
    return uint(clamp(ceil(pixels / frame.tessellation.x), 1.0, float(most)));
}

// Whether the compute patch rasterizer takes a patch (camera-relative corners p, its displacement reaching `reach`
// further): only beyond the near plane (it does not clip) and within TS_DICE_MAX_RADIUS_PIXELS on screen; the rest go to
// hardware raster.
bool dice_in_compute(GpuFrame frame, vec3 p[3], float reach) {
    if ((frame.counts.z & TS_FRAME_HARDWARE_ONLY) != 0u) return false;
    vec3 center = (p[0] + p[1] + p[2]) / 3.0;
    float radius = max(max(distance(center, p[0]), distance(center, p[1])), distance(center, p[2])) + reach;
    float nearest = depth_range(frame, center, radius).x;
    if (nearest <= frame.lod.w * 1.001) return false;
    return radius * frame.lod.x / (frame.lod.z != 0.0 ? 1.0 : nearest) <= TS_DICE_MAX_RADIUS_PIXELS;
}

// The bounding sphere of a triangle or patch (camera-relative corners p) and of all its displacement, `reach`, can move it.
vec4 displaced_sphere(vec3 p[3], float reach) {
    vec3 center = (p[0] + p[1] + p[2]) / 3.0;
    return vec4(center, max(max(distance(center, p[0]), distance(center, p[1])), distance(center, p[2])) + reach);
}

bool occlusion_culling(GpuFrame frame) { return (frame.counts.z & TS_FRAME_OCCLUSION) != 0u; }

// Sends a stored patch to a patch rasterizer: the compute one (with room in the point pool for its diced points, if
// any is left and resolve can use them) or an indirect draw of its own. Returns its micro-triangles.
uint route_patch(GpuFrame frame, uint index, vec3 p[3], float reach, uint n, Instance instance, GpuMaterial material) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    if (dice_in_compute(frame, p, reach)) {
        // The vertex channel (colours, primvar readers) is blended with the micro-triangle's corner weights, which the pool does not hold: resolve
        // dices such patches again (TS_BIN_DICED_MICRO), so their points are not kept.
        bool weights = (material.flags & TS_MATERIAL_VERTEX_CHANNEL) != 0u &&
                       load_mesh(frame, instance.meshIndex).colorOffset != TS_NO_STREAM;
        uint count = weights ? 0u : (n + 1u) * (n + 2u) / 2u;
        uint at = atomicAdd(draw.state.patchPoints, count);
        if (!weights && at + count <= uint(frame.tessellation.z)) PatchRef(frame.patches).data[index].points = at;
        uint k = atomicAdd(draw.state.dicePatches, 1u);
        atomicAdd(draw.state.dicePatchesDrawn, 1u);
        SlotListRef(frame.dicePatches).data[k] = index;
        atomicMax(draw.state.dicePatchGroupsX, min(k + 1u, 65535u));
        atomicMax(draw.state.dicePatchGroupsY, k / 65535u + 1u);
    } else {
        uint d = atomicAdd(draw.state.patchDraws, 1u);
        PatchDrawRef(frame.patchDraws).data[d] = uvec4(3u * n * n, 1u, 0u, index);
    }
    return n * n;
}

// How far displacement can move a triangle of a cluster: its material's bound, or its cluster's where that is tighter
// (mesh units times the instance's scale).
float displacement_reach(GpuFrame frame, Instance instance, GpuMaterial material, uint clusterIndex, float scale) {
    uint clusterInMesh = clusterIndex - load_mesh(frame, instance.meshIndex).clusterOffset;
    return min(material.displacement.w, cluster_displacement(frame, instance, clusterInMesh)) * scale;
}

// Step TS_TESS_DEFERRED_PATCHES (post pass, a thread per patch the main pass deferred): each is tested against this
// frame's HZB and, not hidden, sent to its rasterizer.
void route_deferred_patch(GpuFrame frame) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    uint k = (gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) * TS_TESS_GROUP_SIZE + gl_LocalInvocationIndex;
    if (k >= draw.state.deferredPatches) return;
    uint index = SlotListRef(frame.deferredPatchList).data[k];
    DicedPatch d = load_patch(frame, index);
    vec3 p[3];
    for (uint i = 0u; i < 3u; ++i) {
        precise vec3 meshPoint = d.w[i].x * d.triangle.p[0] + d.w[i].y * d.triangle.p[1] + d.w[i].z * d.triangle.p[2];
        p[i] = to_camera_relative(d.instance, d.translation, meshPoint);
    }
    float reach = displacement_reach(frame, d.instance, d.material, d.clusterIndex, d.scale);
    vec4 sphere = displaced_sphere(p, reach);
    if (hidden(frame, TS_CULL_POST, sphere.xyz, sphere.w)) {
        atomicAdd(draw.state.occludedPatches, 1u);
        return;
    }
    atomicAdd(draw.state.microTriangles, route_patch(frame, index, p, reach, d.n, d.instance, d.material));
}

// Steps TS_CULL_MAIN and TS_CULL_POST: a workgroup per listed cluster, a thread per triangle.
void tessellate_triangle(GpuFrame frame) {
    DrawStateRef draw = DrawStateRef(frame.drawState);
    uint k = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
    if (k >= draw.state.tessClusters) return;
    uint slot = SlotListRef(frame.tessellationList).data[spread_index(k, draw.state.tessClusters)];  // spread (shared.h)
    uvec2 visible = visible_cluster(frame, slot);
    GpuCluster cluster = load_cluster(frame, visible.y);
    uint triangle = gl_LocalInvocationIndex;
    if (triangle >= cluster.triangleCount) return;
    Instance instance = load_instance(frame, visible.x & ~TS_VISIBLE_SOFTWARE);
    GpuMaterial material = load_material(frame, pixel_material(frame, instance, visible.y, triangle));
    vec3 translation = camera_relative_translation(instance);
    float scale = instance_scale(instance);
    DisplacedTriangle t = displaced_triangle(frame, instance, cluster, triangle);
    float reach = displacement_reach(frame, instance, material, visible.y, scale);

    vec3 c[3];
    float fade[3];
    for (uint i = 0u; i < 3u; ++i) {
        c[i] = to_camera_relative(instance, translation, t.p[i]);
        fade[i] = displacement_fade(frame, material, scale, c[i]);
    }
    vec4 bounds = displaced_sphere(c, reach);
    if (!sphere_in_frustum(frame, bounds.xyz, bounds.w)) return;

    uvec3 factors = uvec3(edge_factor(frame, c[0], c[1], fade[0], fade[1], TS_TESS_MAX_FACTOR),
                          edge_factor(frame, c[1], c[2], fade[1], fade[2], TS_TESS_MAX_FACTOR),
                          edge_factor(frame, c[2], c[0], fade[2], fade[0], TS_TESS_MAX_FACTOR));
    uint largest = max(factors.x, max(factors.y, factors.z));
    uint split = min((largest + TS_TESS_PATCH_FACTOR - 1u) / TS_TESS_PATCH_FACTOR, TS_TESS_MAX_SPLIT);
    uint cells = split * split;
    uint first = atomicAdd(draw.state.patches, cells);
    atomicAdd(draw.state.tessTriangles, 1u);
    uint capacity = uint(frame.tessellation.y);
    uint packedFactors = factors.x | factors.y << TS_TESS_FACTOR_BITS | factors.z << (2u * TS_TESS_FACTOR_BITS);
    uint microTriangles = 0u;
    uint cell = 0u;
    if (first < capacity) do {  // the test at the end (frame.h); a triangle has at least one cell
        uvec2 q[3];
        lattice_cell(cell, split, q[0], q[1], q[2]);
        vec3 w[3];
        vec3 p[3];
        float f[3];
        for (uint i = 0u; i < 3u; ++i) {
            w[i] = split_point(q[i], split, factors);
            precise vec3 meshPoint = w[i].x * t.p[0] + w[i].y * t.p[1] + w[i].z * t.p[2];
            p[i] = to_camera_relative(instance, translation, meshPoint);
            f[i] = displacement_fade(frame, material, scale, p[i]);
        }
        // Culled patches leave their slot unused. In the main pass, one the previous frame's HZB hides is stored and
        // left to the post pass, which tests it against this frame's (like the clusters the cull defers).
        vec4 sphere = displaced_sphere(p, reach);
        if (split > 1u && !sphere_in_frustum(frame, sphere.xyz, sphere.w)) continue;
        bool deferred = false;
        if (occlusion_culling(frame)) {
            if (push.step == TS_CULL_POST && hidden(frame, TS_CULL_POST, sphere.xyz, sphere.w)) {
                atomicAdd(draw.state.occludedPatches, 1u);
                continue;
            }
            deferred = push.step == TS_CULL_MAIN && hidden(frame, TS_CULL_MAIN, sphere.xyz, sphere.w);
        }
        // A patch edge on the triangle's edge has that edge's points between its ends; one inside gets its own factor.
        uint g[3];
        for (uint e = 0u; e < 3u; ++e) {
            uint e1 = (e + 1u) % 3u;
            uint edge = split_edge(q[e], q[e1], split);
            if (edge < 3u) {
                uint a = split_edge_index(q[e], edge, split, factors), b = split_edge_index(q[e1], edge, split, factors);
                g[e] = a > b ? a - b : b - a;
            } else {
                g[e] = edge_factor(frame, p[e], p[e1], f[e], f[e1], TS_TESS_PATCH_FACTOR);
            }
        }
        uint n = max(max(g[0], g[1]), max(g[2], 1u));
        uint index = first + cell;
        PatchRef(frame.patches).data[index] = GpuPatch(slot << TS_VIS_TRIANGLE_BITS | triangle, split | cell << 8u, packedFactors,
                                                       g[0] | g[1] << 5u | g[2] << 10u, TS_NO_STREAM, 0u, 0u, 0u);
        if (deferred) {
            uint d = atomicAdd(draw.state.deferredPatches, 1u);
            SlotListRef(frame.deferredPatchList).data[d] = index;
            atomicMax(draw.state.deferredPatchGroupsX, min(d / TS_TESS_GROUP_SIZE + 1u, 65535u));
            atomicMax(draw.state.deferredPatchGroupsY, d / TS_TESS_GROUP_SIZE / 65535u + 1u);
            continue;
        }
        microTriangles += route_patch(frame, index, p, reach, n, instance, material);
    } while (++cell < cells && first + cell < capacity);
    atomicAdd(draw.state.microTriangles, microTriangles);
}

void main() {
    GpuFrame frame = frameConstants;
    if (push.step == TS_TESS_DEFERRED_PATCHES) route_deferred_patch(frame);
    else tessellate_triangle(frame);
}
