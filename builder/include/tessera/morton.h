// Morton (Z-order) codes, for sorting things by where they are: the builder's level-0 chunks and the renderer's cut
// blocks. Header-only.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>

namespace tessera {

// The low 10 bits of v spread to every third bit of 30.
inline uint32_t morton_spread_bits(uint32_t v) {
    v &= 0x3ff;
    v = (v | (v << 16)) & 0x030000ff;
    v = (v | (v << 8)) & 0x0300f00f;
    v = (v | (v << 4)) & 0x030c30c3;
    v = (v | (v << 2)) & 0x09249249;
    return v;
}

// The cube codes of `count` points are taken in: its low corner into `lo`, and its side, returned (at least 1e-30, so that
// coincident points still give codes). `point(i, p)` writes point i's xyz into p.
template <typename PointOf>
float morton_cube(size_t count, PointOf point, float lo[3]) {
    float hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    lo[0] = lo[1] = lo[2] = INFINITY;
    for (size_t i = 0; i < count; ++i) {
        float p[3];
        point(i, p);
        for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], p[k]), hi[k] = std::max(hi[k], p[k]);
    }
    return std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-30f});
}

// The 30-bit code of point p in the cube of side `extent` (> 0) from corner `lo`, on a 1024^3 grid (cells by truncation).
inline uint32_t morton_code(const float p[3], const float lo[3], float extent) {
    uint32_t code = 0;
    for (int k = 0; k < 3; ++k) code |= morton_spread_bits(uint32_t(std::clamp((p[k] - lo[k]) / extent * 1023.0f, 0.0f, 1023.0f))) << k;
    return code;
}

}  // namespace tessera
