// Internal to the builder: the box of a set of points, on one core or over blocks on every core (the build's bounds,
// cluster spheres, prepare_mesh's extent check).
#pragma once

#include "tessera/parallel.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

namespace tessera {

// The box of the points point(i), i in [begin, end), grown into lo, hi. Minima and maxima do not depend on how a range
// is split. (In float, then widened once: the same bounds, as float to double is exact and keeps the order.)
template <class Point>
void grow_box(Point point, size_t begin, size_t end, double lo[3], double hi[3]) {
    float low[3] = {INFINITY, INFINITY, INFINITY}, high[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = begin; i < end; ++i) {
        const float* p = point(i);
        for (int k = 0; k < 3; ++k) {
            low[k] = std::min(low[k], p[k]);
            high[k] = std::max(high[k], p[k]);
        }
    }
    for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], double(low[k])), hi[k] = std::max(hi[k], double(high[k]));
}

// The box of every vertex of `positions` (3 floats each), grown into lo, hi, over blocks of `block` vertices on every core.
inline void all_vertices_box(const std::vector<float>& positions, size_t block, double lo[3], double hi[3]) {
    const size_t count = positions.size() / 3;
    std::vector<std::array<double, 6>> boxes((count + block - 1) / block, {INFINITY, INFINITY, INFINITY, -INFINITY, -INFINITY, -INFINITY});
    parallel_blocks(count, block, [&](size_t begin, size_t end) {
        grow_box([&](size_t i) { return &positions[3 * i]; }, begin, end, &boxes[begin / block][0], &boxes[begin / block][3]);
    });
    for (const auto& box : boxes)
        for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], box[k]), hi[k] = std::max(hi[k], box[3 + k]);
}

}  // namespace tessera
