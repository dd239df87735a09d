// Internal to the builder: exact welding of positions (prepare.cpp, dag.cpp).
#pragma once

#include <cstdint>
#include <cstring>
#include <vector>

namespace tessera {

// Ids of positions by exact bits (-0 equals +0): the first id added at a position stands for every later one there.
// Open addressing with linear probing: std::unordered_map's node per entry made welding a tenth of the build.
class PositionWelder {
public:
    void reserve(size_t count) {
        if (4 * count > 3 * slots_.size()) rehash(count * 4 / 3 + 1);
    }
    uint32_t add(const float* xyz, uint32_t id) {
        Slot s;
        std::memcpy(s.key, xyz, sizeof s.key);
        for (uint32_t& bits : s.key)
            if (bits == 0x80000000u) bits = 0;
        if (4 * (size_ + 1) > 3 * slots_.size()) rehash(2 * slots_.size());  // at most three quarters full
        const size_t mask = slots_.size() - 1;
        for (size_t i = hash(s.key) & mask;; i = (i + 1) & mask) {
            Slot& slot = slots_[i];
            if (slot.id == kEmpty) {
                s.id = id;
                slot = s;
                ++size_;
                return id;
            }
            if (slot.key[0] == s.key[0] && slot.key[1] == s.key[1] && slot.key[2] == s.key[2]) return slot.id;
        }
    }

private:
    static constexpr uint32_t kEmpty = UINT32_MAX;
    struct Slot {
        uint32_t key[3];
        uint32_t id = kEmpty;
    };
    static size_t hash(const uint32_t* k) {
        // Grid positions share low mantissa bits: mix all bits into the low ones the mask keeps.
        uint64_t h = (uint64_t(k[0]) * 0x9E3779B97F4A7C15ull) ^ (uint64_t(k[1]) * 0xC2B2AE3D27D4EB4Full) ^ (uint64_t(k[2]) * 0x165667B19E3779F9ull);
        return size_t(h ^ (h >> 32));
    }
    void rehash(size_t wanted) {
        size_t capacity = 16;
        while (capacity < wanted) capacity *= 2;
        std::vector<Slot> old(capacity);
        old.swap(slots_);
        const size_t mask = capacity - 1;
        for (const Slot& s : old)
            if (s.id != kEmpty) {
                size_t i = hash(s.key) & mask;
                while (slots_[i].id != kEmpty) i = (i + 1) & mask;
                slots_[i] = s;
            }
    }
    std::vector<Slot> slots_;
    size_t size_ = 0;
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
