// The compute rasterizer's triangle setup and scan, shared by the cluster rasterizer (raster_sw.comp.glsl) and the patch
// rasterizer (dice.comp.glsl): vertices already snapped to the hardware rasterizer's sub-pixel grid, coverage by its
// top-left rule, so that both compute paths and hardware raster cover the same pixels for the same triangle. Include
// after surface.h, and after tessellation.h where micro-triangles are drawn (their masks); needs
// GL_EXT_shader_atomic_int64.
#ifndef TESSERA_RASTER_H
#define TESSERA_RASTER_H
#extension GL_EXT_control_flow_attributes : require

// The mask test: with tessellation.h included first (the patch rasterizer), micro-triangles' payloads too; the cluster
// rasterizer carries none of the tessellation code (on lavapipe it would lengthen every pipeline's compile).
#ifdef TESSERA_TESSELLATION_H
#define PIXEL_MASKED_OUT(frame, payload, pixel) \
    (((payload) & TS_VIS_TESSELLATED) != 0u ? micro_masked_out(frame, payload, pixel) : masked_out(frame, payload, pixel))
#else
#define PIXEL_MASKED_OUT(frame, payload, pixel) masked_out(frame, payload, pixel)
#endif

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

// The 64-bit atomic max of a fragment's (depth | payload) into its pixel's visibility word: through the buffer's binding
// where the variant has it (TS_SPEC_OUTPUT_BINDING), else through its address. The same word either way.
void visibility_max(GpuFrame frame, uint pixel, uint64_t value) {
    if (OUTPUT_BINDING) atomicMax(visibilityWords[pixel], value);
    else atomicMax(VisibilityRef(frame.visibility).data[pixel], value);
}

// `masked`: the instance's material cuts pixels by a textured opacity (TS_INSTANCE_MASKED; the same for a workgroup).
void write_pixel(GpuFrame frame, int x, int y, float depth, uint64_t payload, bool masked) {
    if (depth < 0.0 || depth > 1.0) return;  // beyond the far plane
    if (masked && PIXEL_MASKED_OUT(frame, uint(payload), uvec2(x, y))) return;
    uint pixel = uint(y) * frame.viewport.x + uint(x);
    visibility_max(frame, pixel, (uint64_t(floatBitsToUint(depth)) << 32) | payload);
    count_fragment(frame, pixel);
}

// The pixels of one block of at most 4 x 4 pixel centres of a triangle's box, from `corner` (the block's first pixel)
// with edge functions `w` there: its coverage first, as a 16-bit mask (straight-line code, no branch), then a loop over
// the covered pixels alone writes them. On a CPU device lanes run the loops in lockstep and each atomic max is a loop
// over the lanes, so the cost follows how often the write is reached: once per covered pixel of the lane with the most,
// where a scan row by row reached it once per box pixel of the lane with the largest box (lavapipe, one core: the densest
// field's compute raster 156 -> 123 ms, the 1 px sphere's 80 -> 47; docs/benchmarks.md). `inBox`: the block's pixels
// inside the box, 0-4 each way.
void scan_block(GpuFrame frame, ivec2 corner, ivec3 w, ivec3 stepX, ivec3 stepY, ivec3 bias, uvec2 inBox, vec4 z, uint64_t payload, bool masked) {
    // A sample lies outside when any of its biased edge functions is negative: the sign bit of their OR.
    uint outside = 0u;  // bit 4 dy + dx: the pixel corner + (dx, dy)
    ivec3 first = w + bias;
    [[unroll]] for (int dy = 0; dy < 4; ++dy, first += stepY) {
        ivec3 at = first;
        [[unroll]] for (int dx = 0; dx < 4; ++dx, at += stepX) outside |= (uint(at.x | at.y | at.z) >> 31u) << uint(dy * 4 + dx);
    }
    // Samples past the box are masked off here (their edge functions may exceed the bound that holds inside the box).
    uint covered = ~outside & (0x1111u * ((1u << inBox.x) - 1u)) & ((1u << (4u * inBox.y)) - 1u);
    if (covered != 0u) do {  // the test at the end (frame.h)
        int bit = findLSB(covered);
        covered &= covered - 1u;
        int dx = bit & 3, dy = bit >> 2;
        write_pixel(frame, corner.x + dx, corner.y + dy, depth_at(vec3(w + stepX * dx + stepY * dy), z), payload, masked);
    } while (covered != 0u);
}

// A triangle's box in blocks of 4 x 4 pixel centres (nearly every triangle of a dense cut fits one).
void scan_small(GpuFrame frame, ivec2 a, ivec2 b, ivec2 c, ivec2 lo, ivec2 hi, int step, int center, vec4 z, uint64_t payload, bool masked) {
    ivec2 p = lo * step + center;
    ivec3 row = ivec3((b.x - c.x) * (p.y - b.y) - (b.y - c.y) * (p.x - b.x),
                      (c.x - a.x) * (p.y - c.y) - (c.y - a.y) * (p.x - c.x),
                      (a.x - b.x) * (p.y - a.y) - (a.y - b.y) * (p.x - a.x));
    ivec3 stepX = -ivec3(b.y - c.y, c.y - a.y, a.y - b.y) * step;
    ivec3 stepY = ivec3(b.x - c.x, c.x - a.x, a.x - b.x) * step;
    ivec3 bias = ivec3(edge_bias(b, c), edge_bias(c, a), edge_bias(a, b));
    ivec2 size = hi - lo + 1;
    // One loop over the blocks, row by row (a nested loop runs its inner loop's mask logic once more per row), testing at
    // its end (frame.h): a box holding no pixel centre scans one block of none.
    int blocks = ((max(size.x, 0) + 3) >> 2) * ((max(size.y, 0) + 3) >> 2);
    ivec2 block = ivec2(0);
    ivec3 w = row;
    int k = 0;
    do {
        scan_block(frame, lo + block, w, stepX, stepY, bias, uvec2(clamp(size - block, 0, 4)), z, payload, masked);
        bool wrap = block.x + 4 >= size.x;
        row += wrap ? stepY * 4 : ivec3(0);
        w = wrap ? row : w + stepX * 4;
        block = wrap ? ivec2(0, block.y + 4) : ivec2(block.x + 4, block.y);
    } while (++k < blocks);
}

void scan_large(GpuFrame frame, ivec2 a, ivec2 b, ivec2 c, ivec2 lo, ivec2 hi, int step, int center, vec4 z, uint64_t payload, bool masked) {
    ivec2 p = lo * step + center;
    i64vec3 row = i64vec3(int64_t(b.x - c.x) * int64_t(p.y - b.y) - int64_t(b.y - c.y) * int64_t(p.x - b.x),
                          int64_t(c.x - a.x) * int64_t(p.y - c.y) - int64_t(c.y - a.y) * int64_t(p.x - c.x),
                          int64_t(a.x - b.x) * int64_t(p.y - a.y) - int64_t(a.y - b.y) * int64_t(p.x - a.x));
    i64vec3 stepX = -i64vec3(b.y - c.y, c.y - a.y, a.y - b.y) * int64_t(step);
    i64vec3 stepY = i64vec3(b.x - c.x, c.x - a.x, a.x - b.x) * int64_t(step);
    i64vec3 bias = i64vec3(edge_bias(b, c), edge_bias(c, a), edge_bias(a, b));
    if (lo.x > hi.x || lo.y > hi.y) return;  // no pixel centre in the box
    int y = lo.y;
    do {  // the tests at the end (frame.h)
        i64vec3 w = row;
        int x = lo.x;
        do {
            if (all(greaterThanEqual(w + bias, i64vec3(0)))) write_pixel(frame, x, y, depth_at(vec3(w), z), payload, masked);
            w += stepX;
        } while (++x <= hi.x);
        row += stepY;
    } while (++y <= hi.y);
}

// One triangle: sub-pixel corners a, b, c with reversed-Z depths; culled when it faces away (unless double-sided) or
// has no area; `payload` goes into the visibility buffer with the depth. Triangles less than
// TS_SW_SMALL_TRIANGLE_SUBPIXELS across use 32-bit edge functions (exact there; much faster where 64-bit multiplies are
// emulated, lavapipe), larger ones 64-bit. `mayBeLarge`: a constant of the caller; false where the caller knows every
// triangle is small (the cull's guarantee for the front of the software list), which compiles the 64-bit scan out
// (lavapipe runs both sides of a branch that differs between lanes). Such a caller's triangle that is not small after
// all is left out, never scanned with overflowing edge functions.
void rasterize_triangle(GpuFrame frame, ivec2 a, ivec2 b, ivec2 c, float za, float zb, float zc, uint64_t payload, bool doubleSided, bool masked,
                        bool mayBeLarge) {
    // Edge functions stay within 2 E (E + step) for a triangle E sub-pixels across (the bound: shared.h).
    ivec2 extent = max(a, max(b, c)) - min(a, min(b, c));
    bool small = max(extent.x, extent.y) < TS_SW_SMALL_TRIANGLE_SUBPIXELS;
    if (!mayBeLarge && !small) return;  // after this, a caller's constant `mayBeLarge` false leaves no 64-bit arithmetic
    // Twice the signed area; negative is counter-clockwise on screen (y down), a front face. In 32 bits where the
    // triangle is small (exact there), else in 64. The tests read the 32-bit value wherever it holds: lavapipe (Mesa
    // 22.3) compared a 32-bit value widened to 64 bits with zero wrongly (every triangle culled; docs/benchmarks.md).
    int area32 = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
    int64_t area = small ? int64_t(area32) : int64_t(b.x - a.x) * int64_t(c.y - a.y) - int64_t(c.x - a.x) * int64_t(b.y - a.y);
    bool front = small ? area32 < 0 : area < 0l;
    if ((small ? area32 == 0 : area == 0l) || !(front || doubleSided)) return;
    if (!front) {  // the back of a double-sided triangle, turned to the same orientation
        ivec2 s = b;
        b = c;
        c = s;
        float z = zb;
        zb = zc;
        zc = z;
        area = -area;
        area32 = -area32;
    }
    // The pixels whose centres the box may hold. The sub-pixel step is a power of two: shifts (rounding down), not
    // divisions, which a CPU device runs one lane at a time (no vector integer division on x86).
    int step = int(frame.raster.y), center = step >> 1, shift = findLSB(step);
    ivec2 lo = max((min(a, min(b, c)) - center + step - 1) >> shift, ivec2(0));
    ivec2 hi = min((max(a, max(b, c)) - center) >> shift, ivec2(frame.viewport.xy) - 1);
    vec4 z = vec4(za, zb, zc, 1.0 / (small ? float(-area32) : float(-area)));  // the same float either way where small
    if (small) scan_small(frame, a, b, c, lo, hi, step, center, z, payload, masked);
    else if (mayBeLarge) scan_large(frame, a, b, c, lo, hi, step, center, z, payload, masked);
}

// Clip-space position to the framebuffer's sub-pixel grid (the Vulkan viewport transform, then rounding to the
// hardware's sub-pixel steps) and reversed-Z depth.
void snap_vertex(GpuFrame frame, vec4 clip, out ivec2 screen, out float depth) {
    vec3 ndc = clip.xyz / clip.w;
    vec2 pixel = (ndc.xy * 0.5 + 0.5) * vec2(frame.viewport.xy);
    screen = ivec2(round(pixel * frame.raster.y));
    depth = ndc.z;
}

#endif
