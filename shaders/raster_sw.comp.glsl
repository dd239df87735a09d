// Software raster: one workgroup per cluster of the software list, its threads over the triangles. Clusters here lie
// beyond the near plane and cover a small screen area (cull.comp.glsl), so no clipping is needed. Vertices are snapped
// to the hardware rasterizer's sub-pixel grid and coverage follows its top-left rule, so both paths cover the same
// pixels for the same triangle; depth and payload go into the visibility buffer with the same 64-bit atomic max.
#version 460
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_shader_atomic_int64 : require
#include "frame.h"
#include "surface.h"
#include "raster.h"

layout(local_size_x = TS_SW_RASTER_GROUP_SIZE, local_size_x_id = TS_SPEC_RASTER_GROUP_SIZE) in;

// The pipeline variant for frames with textured opacity masks (the others carry no mask code). Fixed per module
// (shaders/CMakeLists.txt: raster_sw and raster_sw_masked, TS_MODULE_MASKS): the mask's texture sampling is most of the
// module (162 KB of SPIR-V with it, 36-38 KB without), and lavapipe translates all of a module before specialization.
const bool MASKS = TS_MODULE_MASKS;

// Two variants (RasterVertices), the same pixels bit for bit. Shared (the default): the workgroup transforms each vertex
// once into shared memory, a barrier, then a thread per triangle; 128 threads on a GPU, one subgroup on a CPU device
// (local_size_x_id, Pipelines::software_raster_group_size): lavapipe runs a workgroup as coroutines of one subgroup each,
// loading the cluster and instance again in each and switching between them at a barrier, so one subgroup loads them once
// and its barrier switches nothing. Own corners (TS_SPEC_OWN_CORNERS, for measurements): 16 threads, each transforming
// the corners of every 16th triangle itself (about six transforms per vertex), with no shared memory and no barrier; on
// lavapipe 8-16 % dearer than one subgroup sharing its vertices (docs/benchmarks.md).
layout(constant_id = TS_SPEC_OWN_CORNERS) const bool OWN_CORNERS = false;

// Which end of the software list this variant draws: the front, clusters the cull found certainly small on screen (every
// triangle less than TS_SW_SMALL_TRIANGLE_SUBPIXELS across: 32-bit edge functions only, the 64-bit scan compiled out), or
// the back (LARGE_TRIANGLES: each triangle picks its scan). Both draw the same pixels for the same triangle.
layout(constant_id = TS_SPEC_LARGE_TRIANGLES) const bool LARGE_TRIANGLES = false;

// A vertex on screen: sub-pixel position and reversed-Z depth bits (z / w), read by a triangle's corner as one load (on
// lavapipe, two arrays cost a load each: 5 % of its compute raster). The back of the software list (LARGE_TRIANGLES)
// keeps them one word each. The front packs them into one 64-bit word: the position relative to the cluster's first
// vertex in 16 bits each way (the cull lists there only clusters whose sphere spans less than
// TS_SW_SMALL_TRIANGLE_SUBPIXELS < 2^15 sub-pixels on screen, so every difference fits), the depth bits above. lavapipe
// loads shared memory a lane at a time, per component: one word instead of three per corner made the densest field's
// compute raster 7-8 % cheaper (docs/benchmarks.md).
shared ivec4 corner[TS_CLUSTER_MAX_VERTICES];
shared uint64_t packedCorner[TS_CLUSTER_MAX_VERTICES];

uint64_t pack_corner(ivec2 screen, float depth, ivec2 origin) {
    ivec2 offset = screen - origin;
    return uint64_t((uint(offset.x) & 0xffffu) | (uint(offset.y) << 16)) | (uint64_t(floatBitsToUint(depth)) << 32);
}

void unpack_corner(uint64_t packed, ivec2 origin, out ivec2 screen, out float depth) {
    int offsets = int(uint(packed));
    screen = origin + ivec2(bitfieldExtract(offsets, 0, 16), offsets >> 16);  // both sign-extended
    depth = uintBitsToFloat(uint(packed >> 32));
}

// Vertex (index into the vertex streams) -> framebuffer sub-pixels and depth (Vulkan viewport transform:
// (ndc * 0.5 + 0.5) * size): the same arithmetic in both variants, so they cover the same pixels bit for bit.
void transform_vertex(GpuFrame frame, Instance instance, vec3 translation, uint vertex, out ivec2 screen, out float depth) {
    snap_vertex(frame, frame.viewProjection * vec4(to_camera_relative(instance, translation, vertex_position(frame, vertex)), 1.0),
                screen, depth);
}

// One triangle of the cluster, its corners from shared memory (or transformed here: OWN_CORNERS).
void draw_triangle(GpuFrame frame, Instance instance, GpuCluster cluster, vec3 translation, ivec2 origin, uint slot, uint triangle, bool flip) {
    uvec3 corners = triangle_vertices(frame, cluster, triangle, flip);
    uint i0 = corners.x, i1 = corners.y, i2 = corners.z;
    ivec2 a, b, c;
    float za, zb, zc;
    if (OWN_CORNERS) {
        transform_vertex(frame, instance, translation, i0, a, za);
        transform_vertex(frame, instance, translation, i1, b, zb);
        transform_vertex(frame, instance, translation, i2, c, zc);
    } else if (LARGE_TRIANGLES) {
        i0 -= cluster.vertexOffset;
        i1 -= cluster.vertexOffset;
        i2 -= cluster.vertexOffset;
        ivec4 ca = corner[i0], cb = corner[i1], cc = corner[i2];
        a = ca.xy;
        b = cb.xy;
        c = cc.xy;
        za = intBitsToFloat(ca.z);
        zb = intBitsToFloat(cb.z);
        zc = intBitsToFloat(cc.z);
    } else {
        unpack_corner(packedCorner[i0 - cluster.vertexOffset], origin, a, za);
        unpack_corner(packedCorner[i1 - cluster.vertexOffset], origin, b, zb);
        unpack_corner(packedCorner[i2 - cluster.vertexOffset], origin, c, zc);
    }
    uint64_t payload = uint64_t((slot << TS_VIS_TRIANGLE_BITS) | triangle);
    bool masked = MASKS && (instance.flags & TS_INSTANCE_MASKED) != 0u;
    rasterize_triangle(frame, a, b, c, za, zb, zc, payload, (instance.flags & TS_INSTANCE_DOUBLE_SIDED) != 0u, masked, LARGE_TRIANGLES);
}

void main() {
    GpuFrame frame = frameConstants;
    DrawStateRef draw = DrawStateRef(frame.drawState);
    uint count = LARGE_TRIANGLES ? draw.state.swLargeClusters : draw.state.swClusters;
    // One workgroup per cluster over a 2D grid, no loop: on lavapipe a loop around this code runs it masked.
    uint k = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
    if (k >= count) return;  // the whole workgroup: no barrier is skipped by some threads only
    k = spread_index(k, count);  // the list's clusters spread over lavapipe's threads (shared.h)
    uint slot = SlotListRef(frame.softwareList).data[LARGE_TRIANGLES ? frame.counts.y - 1u - k : k];
    // The transform and flags from the cull's record of the cluster (shared.h GpuVisibleRecord), the cluster's counts
    // from the cluster itself.
    GpuVisibleRecord record = load_visible_record(frame, slot);
    Instance instance = record_instance(record);
    GpuCluster cluster = load_cluster(frame, visible_cluster(frame, slot).y);
    vec3 translation = camera_relative_translation(instance);

    // The packed corners' origin: the cluster's first vertex, the same arithmetic in every thread.
    ivec2 origin = ivec2(0);
    if (!OWN_CORNERS && !LARGE_TRIANGLES) {
        float originDepth;
        transform_vertex(frame, instance, translation, cluster.vertexOffset, origin, originDepth);
    }
    if (!OWN_CORNERS) {
        // Each vertex once, into shared memory, for every triangle that uses it.
        uint vertexCount = cluster.levelVertices & 0xffffu;
        uint v = gl_LocalInvocationIndex;
        do {  // the test at the end (frame.h)
            if (v < vertexCount) {
                ivec2 sv;
                float dv;
                transform_vertex(frame, instance, translation, cluster.vertexOffset + v, sv, dv);
                if (LARGE_TRIANGLES) corner[v] = ivec4(sv, floatBitsToInt(dv), 0);
                else packedCorner[v] = pack_corner(sv, dv, origin);
            }
        } while ((v += gl_WorkGroupSize.x) < vertexCount);
        barrier();
    }

    bool flip = (instance.flags & TS_INSTANCE_FLIP_WINDING) != 0u;
    uint triangle = gl_LocalInvocationIndex;
    do {  // the test at the end (frame.h)
        if (triangle < cluster.triangleCount) draw_triangle(frame, instance, cluster, translation, origin, slot, triangle, flip);
    } while ((triangle += gl_WorkGroupSize.x) < cluster.triangleCount);
}
