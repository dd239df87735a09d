// Internal to the builder: exact welding of positions (prepare.cpp, dag.cpp).
#pragma once

#include "tessera/parallel.h"

#include <array>
#include <bit>
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
        key_of(xyz, s.key);
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

    // A hint: the slot a later add of xyz starts at is fetched into the cache meanwhile (the table is far larger).
    void prefetch(const float* xyz) const {
        if (slots_.empty()) return;
        uint32_t key[3];
        key_of(xyz, key);
        __builtin_prefetch(&slots_[hash(key) & (slots_.size() - 1)]);
    }
    // The bits compared (-0 as +0), and their hash: equal positions have equal hashes.
    static void key_of(const float* xyz, uint32_t* key) {
        std::memcpy(key, xyz, 3 * sizeof(uint32_t));
        for (int k = 0; k < 3; ++k)
            if (key[k] == 0x80000000u) key[k] = 0;
    }
    static size_t hash(const uint32_t* k) {
        // Grid positions share low mantissa bits: mix all bits into the low ones the mask keeps.
        uint64_t h = (uint64_t(k[0]) * 0x9E3779B97F4A7C15ull) ^ (uint64_t(k[1]) * 0xC2B2AE3D27D4EB4Full) ^ (uint64_t(k[2]) * 0x165667B19E3779F9ull);
        return size_t(h ^ (h >> 32));
    }

private:
    static constexpr uint32_t kEmpty = UINT32_MAX;
    struct Slot {
        uint32_t key[3];
        uint32_t id = kEmpty;
    };
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

// For each of `count` xyz triples, the index of the first triple with bit-identical coordinates. Without a welder to
// keep, large inputs weld on every core: positions are dealt by hash into shards (equal positions share one), each
// shard welded on its own in index order, so the result is the serial one whatever the thread count.
inline std::vector<uint32_t> weld_equal_positions(const float* xyz, size_t count, PositionWelder* welder = nullptr) {
    std::vector<uint32_t> weld(count);
    constexpr size_t kMaxShards = 64, kBlock = 1 << 16, kAhead = 16;  // kAhead: positions prefetched ahead
    if (welder || count < 4 * kBlock || core_count() < 2) {
        PositionWelder local;
        PositionWelder& w = welder ? *welder : local;
        w.reserve(count);
        for (size_t i = 0; i < count; ++i) {
            if (i + kAhead < count) w.prefetch(xyz + 3 * (i + kAhead));
            weld[i] = w.add(xyz + 3 * i, uint32_t(i));
        }
        return weld;
    }
    // One shard per core (each reads every cache line of xyz: more shards cost more than they balance).
    const int shardBits = std::min(6, int(std::bit_width(core_count() - 1)));
    const size_t shards = size_t(1) << shardBits;
    auto shard_of = [&](size_t i) {
        uint32_t key[3];
        PositionWelder::key_of(xyz + 3 * i, key);
        return PositionWelder::hash(key) >> (64 - shardBits);  // the top bits: the tables' masks keep low ones
    };
    // Each shard's indices in order: counted per block, then written at their block's offset.
    const size_t blocks = (count + kBlock - 1) / kBlock;
    std::vector<std::array<uint32_t, kMaxShards>> blockCounts(blocks);
    parallel_blocks(count, kBlock, [&](size_t begin, size_t end) {
        std::array<uint32_t, kMaxShards> counts{};
        for (size_t i = begin; i < end; ++i) ++counts[shard_of(i)];
        blockCounts[begin / kBlock] = counts;
    });
    std::array<size_t, kMaxShards + 1> shardStart{};
    std::vector<std::array<size_t, kMaxShards>> blockOffset(blocks);
    size_t at = 0;
    for (size_t s = 0; s < shards; ++s) {
        shardStart[s] = at;
        for (size_t b = 0; b < blocks; ++b) {
            blockOffset[b][s] = at;
            at += blockCounts[b][s];
        }
    }
    shardStart[shards] = at;
    std::vector<uint32_t> byShard(count);
    parallel_blocks(count, kBlock, [&](size_t begin, size_t end) {
        std::array<size_t, kMaxShards> next = blockOffset[begin / kBlock];
        for (size_t i = begin; i < end; ++i) byShard[next[shard_of(i)]++] = uint32_t(i);
    });
    parallel_for(shards, [&](size_t s) {
        PositionWelder w;
        w.reserve(shardStart[s + 1] - shardStart[s]);
        for (size_t k = shardStart[s]; k < shardStart[s + 1]; ++k) {
            if (k + kAhead < shardStart[s + 1]) w.prefetch(xyz + 3 * size_t(byShard[k + kAhead]));
            weld[byShard[k]] = w.add(xyz + 3 * size_t(byShard[k]), byShard[k]);
        }
    });
    return weld;
}

}  // namespace tessera
