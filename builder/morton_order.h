// Internal to the builder: things sorted along a Morton curve through their points, on every core (level 0's chunks of
// triangles, prepare_mesh's vertex order).
#pragma once

#include "tessera/morton.h"
#include "tessera/parallel.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace tessera {

// Items 0..count-1 as (Morton code of point(i, p), i), sorted: `point(i, p)` writes item i's xyz into p; `lo` and
// `extent` give the cube the codes span. Coded and sorted in blocks of `block` on every core, then merged: the order
// is total (item numbers differ), so it does not depend on the blocks.
template <typename PointOf>
std::vector<std::pair<uint32_t, uint32_t>> morton_sort(size_t count, PointOf point, const float lo[3], float extent, size_t block) {
    std::vector<std::pair<uint32_t, uint32_t>> order(count);
    parallel_blocks(count, block, [&](size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) {
            float p[3];
            point(i, p);
            order[i] = {morton_code(p, lo, extent), uint32_t(i)};
        }
        std::sort(order.begin() + begin, order.begin() + end);
    });
    for (size_t width = block; width < count; width *= 2)  // pairs of sorted runs, merged on every core
        parallel_for((count + 2 * width - 1) / (2 * width), [&](size_t pair) {
            const size_t begin = pair * 2 * width, middle = std::min(count, begin + width), end = std::min(count, begin + 2 * width);
            std::inplace_merge(order.begin() + begin, order.begin() + middle, order.begin() + end);
        });
    return order;
}

}  // namespace tessera
