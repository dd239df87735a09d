// Runtime tessellation of displaced triangles, shared by the tessellate pass (which makes patches), the patch raster
// (which dices and displaces them) and resolve (which rebuilds the micro-triangle a pixel shows). Include after
// surface.h.
//
// Dicing. Each edge of a displaced triangle gets a factor, the number of segments it is cut into, from its own two
// endpoints alone (its projected length over the dicing rate), so the two triangles of an edge always agree. A
// triangle whose largest factor exceeds TS_TESS_PATCH_FACTOR is split into split x split patches, the cells of a
// uniform lattice over its corners; lattice points on the triangle's edges move to the nearest of that edge's own
// points (k / factor), so an edge's points are the same whichever triangle, and whichever split, made them. A patch is
// diced on a lattice of n = its largest edge factor, and the points on each patch edge move to that edge's own factor
// in the same way: a patch edge on the triangle's edge takes the edge's points between its ends, one inside the triangle
// gets a factor from its own projected length. What this makes is a zipper along each edge: it may hold zero-area
// micro-triangles (the rasterizers skip them) but no holes and no folds.
//
// Crack-freeness is exact, not approximate. Every point is a weighted sum of the triangle's three corners; a point on
// the triangle's edge has the weights (factor - k) / factor and k / factor, the third exactly 0, whichever end it is
// counted from; positions, displacement normals and texture coordinates are summed with `precise` (no fused
// multiply-add, whose rounding would depend on the order of the corners), so both triangles of an edge get the same
// bits. Displacement normals are one per position (the mean of every normal there: GpuMesh.displacementNormalOffset),
// so a hard edge, whose vertices are split, does not tear. At a UV seam the two sides read the texture at different
// coordinates, so a textured displacement is read seam-aware (frame.seams): a point on a seam edge takes the mean of
// its own sample and the one at the other side's coordinates, and a vertex where several UVs meet the mean over all of
// them (in one stored order): the same bits from every side.
#ifndef TESSERA_TESSELLATION_H
#define TESSERA_TESSELLATION_H

// A displaced triangle as tessellation reads it: its corners in the order the rasterizers see them (flipped instances
// reversed), mesh space.
struct DisplacedTriangle {
    uint v[3];     // vertices in the scene's streams
    vec3 p[3];     // positions
    vec3 n[3];     // displacement normals (unit)
    vec2 uv[3];    // texture coordinates; (0, 0) without a UV set
    uint seamVertex[3];  // the vertex's seam word (TS_SEAM_COUNT_SHIFT), TS_NO_STREAM where one UV meets its position
    vec4 twin[3];  // edge e (corners e, e + 1): the other side's texture coordinates at those corners; NaN: no seam
};

DisplacedTriangle displaced_triangle(GpuFrame frame, Instance instance, GpuCluster cluster, uint triangle) {
    DisplacedTriangle t;
    GpuMesh mesh = load_mesh(frame, instance.meshIndex);
    bool flip = (instance.flags & TS_INSTANCE_FLIP_WINDING) != 0u;
    uvec3 corners = triangle_vertices(frame, cluster, triangle, flip);
    for (uint k = 0u; k < 3u; ++k) {
        uint v = corners[k];
        t.v[k] = v;
        t.p[k] = vertex_position(frame, v);
        t.n[k] = decode_octahedral(mesh.displacementNormalOffset != TS_NO_STREAM
                                       ? UintRef(frame.displacementNormals).data[v - mesh.vertexOffset + mesh.displacementNormalOffset]
                                       : vertex_normal_bits(frame, v));
        t.uv[k] = mesh.uvOffset != TS_NO_STREAM ? vertex_uv(frame, mesh, v) : vec2(0.0);
        t.seamVertex[k] = mesh.seamVertexOffset != TS_NO_STREAM ? UintRef(frame.seams).data[mesh.seamVertexOffset + v - mesh.vertexOffset] : TS_NO_STREAM;
        t.twin[k] = vec4(uintBitsToFloat(0x7fc00000u));
    }
    uint record = mesh.seamVertexOffset != TS_NO_STREAM ? UintRef(frame.seams).data[mesh.seamTriangleOffset + cluster.triangleOffset + triangle]
                                                          : TS_NO_STREAM;
    if (record != TS_NO_STREAM) {
        UintRef seams = UintRef(frame.seams);
        for (uint e = 0u; e < 3u; ++e) {
            // Rasterizer corners e and e + 1 as stored corners (flipped instances swap 1 and 2), and the stored edge
            // (k, k + 1) they make.
            uint a = flip && e != 0u ? 3u - e : e, b = flip && e != 2u ? 3u - (e + 1u) % 3u : (e + 1u) % 3u;
            uint k = (a + 1u) % 3u == b ? a : b;
            vec4 stored = uintBitsToFloat(uvec4(seams.data[record + 4u * k], seams.data[record + 4u * k + 1u],
                                                seams.data[record + 4u * k + 2u], seams.data[record + 4u * k + 3u]));
            t.twin[e] = a == k ? stored : stored.zwxy;
        }
    }
    return t;
}

// How much of a material's displacement applies at a camera-relative point: all of it while its bound projects to at
// least fade-start pixels, none below fade-end, linearly between. A function of the point alone (crack-free).
float displacement_fade(GpuFrame frame, GpuMaterial material, float scale, vec3 point) {
    float size = material.displacement.w * scale * frame.lod.x;
    if (frame.lod.z == 0.0) {  // perspective
        float depth = dot(point, frame.cameraForward.xyz);
        if (depth <= frame.lod.w) return material.displacement.w > 0.0 ? 1.0 : 0.0;  // at the near plane: never too small
        size /= depth;
    }
    float start = material.displacementFade.x, end = material.displacementFade.y;
    if (!(start > end)) return size > end ? 1.0 : 0.0;
    return clamp((size - end) / (start - end), 0.0, 1.0);
}

// The displacement texture's value at texture coordinates st: its first output channel, read bilinearly from level 0
// (a mip level would have to be chosen alike on both sides of every edge).
float displacement_texel(GpuFrame frame, GpuMaterial material, vec2 st) {
    uint slot = material.firstTextureSlot + uint(bitCount(material.textureInputs & ((1u << TS_INPUT_DISPLACEMENT) - 1u)));
    return texture_slot_value(frame.textures, load_texture_slot(frame, slot), st, vec2(0.0), vec2(0.0)).x;
}

// The displacement input at a point of the triangle with corner weights w and texture coordinates st: the material's
// constant, or its texture read seam-aware. A point on an edge (one weight exactly 0) that is a UV seam takes the mean
// of its own sample and the other side's; a corner (two weights 0) where several UVs meet, the mean over all of them.
float displacement_value(GpuFrame frame, GpuMaterial material, DisplacedTriangle t, vec3 w, vec2 st) {
    if ((material.textureInputs & (1u << TS_INPUT_DISPLACEMENT)) == 0u) return material.displacement.x;
    uint zeros = uint(w.x == 0.0) + uint(w.y == 0.0) + uint(w.z == 0.0);
    if (zeros == 2u) {
        uint corner = w.x != 0.0 ? 0u : w.y != 0.0 ? 1u : 2u;
        uint word = t.seamVertex[corner];
        if (word == TS_NO_STREAM) return displacement_texel(frame, material, st);
        uint first = word & ((1u << TS_SEAM_COUNT_SHIFT) - 1u), count = word >> TS_SEAM_COUNT_SHIFT;
        float sum = 0.0;
        for (uint i = 0u; i < count; ++i)
            sum += displacement_texel(frame, material, uintBitsToFloat(uvec2(UintRef(frame.seams).data[first + 2u * i], UintRef(frame.seams).data[first + 2u * i + 1u])));
        return sum / float(count);
    }
    if (zeros == 1u) {
        uint e = (w.x == 0.0 ? 1u : w.y == 0.0 ? 2u : 0u);  // the edge opposite the corner whose weight is 0
        vec4 twin = t.twin[e];
        if (!isnan(twin.x)) {
            uint e1 = (e + 1u) % 3u;
            precise vec2 other = w[e] * twin.xy + w[e1] * twin.zw;
            return 0.5 * (displacement_texel(frame, material, st) + displacement_texel(frame, material, other));
        }
    }
    return displacement_texel(frame, material, st);
}

// round(a / b) for unsigned integers.
uint round_ratio(uint a, uint b) { return (2u * a + b) / (2u * b); }

// The point k / factor of the way along the triangle's edge from corner `from` to corner `to`, as corner weights. The
// triangle on the other side counts from the other end and gets the same two weights, bit for bit.
vec3 edge_point(uint from, uint to, uint k, uint factor) {
    vec3 w = vec3(0.0);
    if (k == 0u) {
        w[from] = 1.0;
    } else if (k >= factor) {
        w[to] = 1.0;
    } else {
        w[from] = float(factor - k) / float(factor);
        w[to] = float(k) / float(factor);
    }
    return w;
}

// A lattice point's index, row by row (row b holds n + 1 - b points).
uint lattice_index(uvec2 ab, uint n) { return ab.y * (n + 1u) - (ab.y * (ab.y - 1u)) / 2u + ab.x; }

// Cell `cell` of a triangular lattice of n segments a side (n^2 cells; row j holds n - j upward cells and n - j - 1
// downward ones, interleaved), as its three lattice points (i toward corner 1, j toward corner 2), counter-clockwise
// like the triangle's corners.
void lattice_cell(uint cell, uint n, out uvec2 a, out uvec2 b, out uvec2 c) {
    uint j = 0u, first = 0u;
    if (first + 2u * (n - j) - 1u <= cell) do {  // the test at the end (frame.h)
        first += 2u * (n - j) - 1u;
        ++j;
    } while (first + 2u * (n - j) - 1u <= cell);
    uint k = cell - first, i = k >> 1;
    if ((k & 1u) == 0u) {
        a = uvec2(i, j);
        b = uvec2(i + 1u, j);
        c = uvec2(i, j + 1u);
    } else {
        a = uvec2(i + 1u, j);
        b = uvec2(i + 1u, j + 1u);
        c = uvec2(i, j + 1u);
    }
}

// The triangle edge (0: corners 0-1, 1: 1-2, 2: 2-0) that the split lattice's points q and r both lie on, else 3.
uint split_edge(uvec2 q, uvec2 r, uint split) {
    if (q.y == 0u && r.y == 0u) return 0u;
    if (q.x + q.y == split && r.x + r.y == split) return 1u;
    if (q.x == 0u && r.x == 0u) return 2u;
    return 3u;
}

// Where a split lattice point on triangle edge `edge` moves: k of that edge's points (counted from corner 0, 1 and 0).
uint split_edge_index(uvec2 q, uint edge, uint split, uvec3 factors) {
    if (edge == 0u) return round_ratio(q.x * factors.x, split);
    if (edge == 1u) return round_ratio(q.y * factors.y, split);
    return round_ratio(q.y * factors.z, split);
}

vec3 triangle_edge_point(uint edge, uint k, uvec3 factors) {
    if (edge == 0u) return edge_point(0u, 1u, k, factors.x);
    if (edge == 1u) return edge_point(1u, 2u, k, factors.y);
    return edge_point(0u, 2u, k, factors.z);
}

// A point of the triangle's split x split lattice as corner weights; points on the triangle's edges move to the
// nearest of the edge's own points (the corners stay exact).
vec3 split_point(uvec2 q, uint split, uvec3 factors) {
    if (q.y == 0u) return triangle_edge_point(0u, split_edge_index(q, 0u, split, factors), factors);
    if (q.x == 0u) return triangle_edge_point(2u, split_edge_index(q, 2u, split, factors), factors);
    if (q.x + q.y == split) return triangle_edge_point(1u, split_edge_index(q, 1u, split, factors), factors);
    return vec3(float(split - q.x - q.y), float(q.x), float(q.y)) / float(split);
}

// The point m / g of the way along a patch edge from split point q (weights wq) to r (weights wr). On the triangle's
// edge it is that edge's own point; inside, a blend of the ends taken from the lower end, so that the patch on the
// other side (which sees the edge the other way round) computes the same bits.
vec3 patch_edge_point(uvec2 q, uvec2 r, vec3 wq, vec3 wr, uint m, uint g, uint split, uvec3 factors) {
    if (m == 0u || g == 0u) return wq;
    if (m >= g) return wr;
    uint edge = split_edge(q, r, split);
    if (edge < 3u) {
        uint kq = split_edge_index(q, edge, split, factors), kr = split_edge_index(r, edge, split, factors);
        return triangle_edge_point(edge, kr > kq ? kq + m : kq - m, factors);
    }
    if (q.y > r.y || (q.y == r.y && q.x > r.x)) {
        vec3 w = wq;
        wq = wr;
        wr = w;
        m = g - m;
    }
    precise vec3 blend = (float(g - m) * wq + float(m) * wr) / float(g);
    return blend;
}

// A patch record's triangle edge factors and its own (corners 0-1, 1-2, 2-0), and its lattice: n = its largest
// edge factor (at least 1).
uvec3 triangle_factors(GpuPatch record) {
    uint mask = (1u << TS_TESS_FACTOR_BITS) - 1u;
    return uvec3(record.factors & mask, (record.factors >> TS_TESS_FACTOR_BITS) & mask, (record.factors >> (2u * TS_TESS_FACTOR_BITS)) & mask);
}
uvec3 patch_factors(GpuPatch record) {
    return uvec3(record.patchFactors & 31u, (record.patchFactors >> 5u) & 31u, (record.patchFactors >> 10u) & 31u);
}
uint patch_lattice(uvec3 patchFactors) { return max(max(patchFactors.x, patchFactors.y), max(patchFactors.z, 1u)); }

// A patch ready to dice: its triangle, instance and material, where it lies in the triangle's split lattice, and its
// edge factors (corners 0-1, 1-2, 2-0).
struct DicedPatch {
    Instance instance;
    GpuMaterial material;
    DisplacedTriangle triangle;
    vec3 translation;
    float scale;
    uint split, n;
    uvec3 factors;
    uvec3 patchFactors;
    uvec2 q[3];
    vec3 w[3];
    uint slot, triangleIndex, clusterIndex;
};

DicedPatch load_patch(GpuFrame frame, uint index) {
    DicedPatch d;
    GpuPatch record = load_gpu_patch(frame, index);
    d.slot = record.triangle >> TS_VIS_TRIANGLE_BITS;
    d.triangleIndex = record.triangle & ((1u << TS_VIS_TRIANGLE_BITS) - 1u);
    uvec2 visible = visible_cluster(frame, d.slot);
    d.clusterIndex = visible.y;
    d.instance = load_instance(frame, visible.x & ~TS_VISIBLE_SOFTWARE);
    GpuCluster cluster = load_cluster(frame, visible.y);
    d.material = load_material(frame, pixel_material(frame, d.instance, visible.y, d.triangleIndex));
    d.triangle = displaced_triangle(frame, d.instance, cluster, d.triangleIndex);
    d.translation = camera_relative_translation(d.instance);
    d.scale = instance_scale(d.instance);
    d.split = record.cell & 0xffu;
    d.factors = triangle_factors(record);
    d.patchFactors = patch_factors(record);
    d.n = patch_lattice(d.patchFactors);
    lattice_cell(record.cell >> 8u, d.split, d.q[0], d.q[1], d.q[2]);
    for (uint k = 0u; k < 3u; ++k) d.w[k] = split_point(d.q[k], d.split, d.factors);
    return d;
}

// Corner weights of the micro-lattice point (a toward the patch's corner 1, b toward its corner 2).
vec3 micro_point(DicedPatch d, uvec2 ab) {
    uint a = ab.x, b = ab.y, n = d.n;
    if (b == 0u) return patch_edge_point(d.q[0], d.q[1], d.w[0], d.w[1], round_ratio(a * d.patchFactors.x, n), d.patchFactors.x, d.split, d.factors);
    if (a == 0u) return patch_edge_point(d.q[0], d.q[2], d.w[0], d.w[2], round_ratio(b * d.patchFactors.z, n), d.patchFactors.z, d.split, d.factors);
    if (a + b == n) return patch_edge_point(d.q[1], d.q[2], d.w[1], d.w[2], round_ratio(b * d.patchFactors.y, n), d.patchFactors.y, d.split, d.factors);
    precise vec3 inside = (float(n - a - b) * d.w[0] + float(a) * d.w[1] + float(b) * d.w[2]) / float(n);
    return inside;
}

// Corner weights of corner `corner` of micro-triangle `micro` of the patch.
vec3 micro_corner(DicedPatch d, uint micro, uint corner) {
    uvec2 a, b, c;
    lattice_cell(micro, d.n, a, b, c);
    return micro_point(d, corner == 0u ? a : corner == 1u ? b : c);
}

// The camera-relative displaced point with corner weights w, and its texture coordinates.
vec3 displaced_point(GpuFrame frame, DicedPatch d, vec3 w, out vec2 st) {
    DisplacedTriangle t = d.triangle;
    precise vec3 p = w.x * t.p[0] + w.y * t.p[1] + w.z * t.p[2];
    precise vec3 n = w.x * t.n[0] + w.y * t.n[1] + w.z * t.n[2];
    precise vec2 uv = w.x * t.uv[0] + w.y * t.uv[1] + w.z * t.uv[2];
    st = uv;
    vec3 base = to_camera_relative(d.instance, d.translation, p);
    float fade = displacement_fade(frame, d.material, d.scale, base);
    float length2 = dot(n, n);
    if (!(fade > 0.0) || !(length2 > 0.0)) return base;
    float offset = (displacement_value(frame, d.material, t, w, uv) - d.material.displacement.z) * d.material.displacement.y * fade;
    return to_camera_relative(d.instance, d.translation, p + n * (offset * inversesqrt(length2)));
}

// The micro-triangle a pixel shows, rebuilt with the code that drew it: its corners' weights on the cluster's triangle,
// their texture coordinates, and the pixel's ray and barycentrics on it (PixelTriangle: v0-v2 are the cluster
// triangle's vertices, p0, e1, e2 the micro-triangle's corners).
struct MicroTriangle {
    PixelTriangle t;
    vec3 w[3];
    vec2 uv[3];
    GpuMaterial material;
    uint largestFactor;  // the triangle's largest edge factor (--vis tessellation)
    uint meshIndex;      // set by pixel_micro_triangle
};

// A micro-triangle's camera-relative corners as the pixel sees them: its first corner and edges, the pixel's ray and the
// barycentrics where it meets the micro-triangle's plane.
void seen_through(GpuFrame frame, vec3 corner[3], uvec2 pixel, inout PixelTriangle t) {
    t.p0 = corner[0];
    t.e1 = corner[1] - corner[0];
    t.e2 = corner[2] - corner[0];
    pixel_ray(frame, vec2(pixel) + 0.5, t.origin, t.direction);
    t.bary = plane_barycentrics(t.origin, t.direction, t.p0, t.e1, t.e2);
}

MicroTriangle pixel_micro_triangle(GpuFrame frame, uint patchIndex, uint micro, uvec2 pixel) {
    MicroTriangle m;
    DicedPatch d = load_patch(frame, patchIndex);
    m.material = d.material;
    m.meshIndex = d.instance.meshIndex;
    m.largestFactor = max(d.factors.x, max(d.factors.y, d.factors.z));
    uvec2 lattice[3];
    lattice_cell(micro, d.n, lattice[0], lattice[1], lattice[2]);
    vec3 corner[3];
    for (uint k = 0u; k < 3u; ++k) {
        m.w[k] = micro_point(d, lattice[k]);
        corner[k] = displaced_point(frame, d, m.w[k], m.uv[k]);
    }
    m.t.v0 = d.triangle.v[0];
    m.t.v1 = d.triangle.v[1];
    m.t.v2 = d.triangle.v[2];
    seen_through(frame, corner, pixel, m.t);
    return m;
}

// The same from the points the compute patch rasterizer kept (GpuPatch.points), when it kept them: no dicing again.
// Without the corners' weights (m.w is left zero), which only vertex colours need. False when no points were kept.
bool kept_micro_triangle(GpuFrame frame, uint patchIndex, uint micro, uvec2 pixel, out MicroTriangle m) {
    GpuPatch record = load_gpu_patch(frame, patchIndex);
    if (record.points == TS_NO_STREAM) return false;
    uint n = patch_lattice(patch_factors(record));
    uvec3 factors = triangle_factors(record);
    m.largestFactor = max(factors.x, max(factors.y, factors.z));
    uvec2 lattice[3];
    lattice_cell(micro, n, lattice[0], lattice[1], lattice[2]);
    vec3 corner[3];
    for (uint k = 0u; k < 3u; ++k) {
        uint at = (record.points + lattice_index(lattice[k], n)) * TS_PATCH_POINT_FLOATS;
        corner[k] = vec3(patch_point_float(frame, at), patch_point_float(frame, at + 1u), patch_point_float(frame, at + 2u));
        m.uv[k] = vec2(patch_point_float(frame, at + 3u), patch_point_float(frame, at + 4u));
        m.w[k] = vec3(0.0);
    }
    seen_through(frame, corner, pixel, m.t);
    return true;
}

// masked_out (surface.h) for a micro-triangle's payload: the micro-triangle rebuilt as the patch rasterizers made it, its
// opacity read at the pixel. The patch rasterizers reach it through PIXEL_MASKED_OUT (raster.h).
bool micro_masked_out(GpuFrame frame, uint payload, uvec2 pixel) {
    Payload p = decode_payload(frame, payload);
    MicroTriangle m = pixel_micro_triangle(frame, p.patchIndex, p.micro, pixel);
    if ((m.material.textureInputs & (1u << TS_INPUT_OPACITY)) == 0u) {
        if (!vertex_opacity(m.material)) return false;
        GpuMesh mesh = load_mesh(frame, m.meshIndex);
        if (mesh.colorOffset == TS_NO_STREAM) return false;
        vec3 bary = m.t.bary.x * m.w[0] + m.t.bary.y * m.w[1] + m.t.bary.z * m.w[2];  // on the cluster's triangle
        vec4 channel = interpolated_channel(frame, mesh, bary, m.t.v0, m.t.v1, m.t.v2);
        return vertex_input(m.material.vertexInputs, TS_INPUT_OPACITY, channel, vec3(1.0)).x < m.material.diffuseColor.a;
    }
    PixelUv uv = pixel_uv(frame, vec2(pixel), m.t.bary, m.t.p0, m.t.e1, m.t.e2, m.uv[0], m.uv[1], m.uv[2]);
    return material_texture(frame, m.material, TS_INPUT_OPACITY, uv).x < m.material.diffuseColor.a;  // a: the threshold
}

#endif
