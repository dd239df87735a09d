// Internal to the builder: compressed rows (a list of items per row, in one array), built by counting.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tessera {

// Row r's items are items[start[r] .. start[r + 1]), in the order they were added.
struct Rows {
    std::vector<uint32_t> start, items;
    // `for_each_pair(add)` calls add(row, item) for every pair; it is called twice (count, then fill), the same each time.
    template <class ForEachPair>
    void build(size_t rows, ForEachPair for_each_pair) {
        start.assign(rows + 1, 0);
        for_each_pair([&](uint32_t row, uint32_t) { ++start[row + 1]; });
        for (size_t r = 0; r < rows; ++r) start[r + 1] += start[r];
        items.resize(start[rows]);
        std::vector<uint32_t> fill(start.begin(), start.end() - 1);
        for_each_pair([&](uint32_t row, uint32_t item) { items[fill[row]++] = item; });
    }
};

}  // namespace tessera
