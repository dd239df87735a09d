// Internal to the builder: exact welding of positions (prepare.cpp, dag.cpp).
#pragma once

#include <cstdint>
#include <cstring>
#include <unordered_map>
#include <vector>

namespace tessera {

// Ids of positions by exact bits (-0 equals +0): the first id added at a position stands for every later one there.
class PositionWelder {
public:
    void reserve(size_t count) { first_.reserve(count); }
    uint32_t add(const float* xyz, uint32_t id) {
        Bits b;
        std::memcpy(b.v, xyz, sizeof b.v);
        for (uint32_t& bits : b.v)
            if (bits == 0x80000000u) bits = 0;
        return first_.try_emplace(b, id).first->second;
    }

private:
    struct Bits {
        uint32_t v[3];
        bool operator==(const Bits&) const = default;
    };
    struct Hash {
        size_t operator()(const Bits& b) const { return (b.v[0] * 73856093u) ^ (b.v[1] * 19349663u) ^ (b.v[2] * 83492791u); }
    };
    std::unordered_map<Bits, uint32_t, Hash> first_;
};

// For each of `count` xyz triples, the index of the first triple with bit-identical coordinates.
inline std::vector<uint32_t> weld_equal_positions(const float* xyz, size_t count, PositionWelder* welder = nullptr) {
    PositionWelder local;
    PositionWelder& w = welder ? *welder : local;
    w.reserve(count);
    std::vector<uint32_t> weld(count);
    for (size_t i = 0; i < count; ++i) weld[i] = w.add(xyz + 3 * i, uint32_t(i));
    return weld;
}

}  // namespace tessera
