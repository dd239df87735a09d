// Internal to the builder: exact welding of positions (prepare.cpp, dag.cpp).
#pragma once

#include <cstdint>
#include <cstring>
#include <unordered_map>
#include <vector>

namespace tessera {

// For each of `count` xyz triples, the index of the first triple with bit-identical coordinates (-0 equals +0).
inline std::vector<uint32_t> weld_equal_positions(const float* xyz, size_t count) {
    struct Bits {
        uint32_t v[3];
        bool operator==(const Bits&) const = default;
    };
    struct Hash {
        size_t operator()(const Bits& b) const { return (b.v[0] * 73856093u) ^ (b.v[1] * 19349663u) ^ (b.v[2] * 83492791u); }
    };
    std::unordered_map<Bits, uint32_t, Hash> first;
    first.reserve(count);
    std::vector<uint32_t> weld(count);
    for (size_t i = 0; i < count; ++i) {
        Bits b;
        std::memcpy(b.v, xyz + 3 * i, sizeof b.v);
        for (uint32_t& bits : b.v)
            if (bits == 0x80000000u) bits = 0;
        weld[i] = first.try_emplace(b, uint32_t(i)).first->second;
    }
    return weld;
}

}  // namespace tessera
