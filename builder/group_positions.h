// Internal to the builder: a simplified group's positions numbered in order of first use (slots), and the topology that
// fitting its attributes (attribute_fit.h) and measuring its distance from the source (deviation.h) walk. Vertices at
// one position (the wedges of a seam) share a slot, so that a seam does not cut the surface in two.
#pragma once

#include "rows.h"

#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace tessera {

struct GroupPositions {
    static constexpr uint32_t kNone = 0xffffffffu;

    // `input`: the group's triangles before simplification, `output` after (vertex ids); `positionId`: vertices at one
    // position share an id.
    GroupPositions(const std::vector<uint32_t>& input, const uint32_t* output, size_t outputCount, const std::vector<uint32_t>& positionId);

    std::vector<uint32_t> corners;        // per input corner, its slot
    std::vector<uint32_t> outputCorners;  // per output corner, its slot (kNone: a position the input lacks)
    std::vector<uint32_t> vertexOf;       // per slot, its first vertex in the input
    std::vector<char> seam;               // per slot: the input has several vertices there
    Rows neighbours;                      // per slot, the slots it shares an input edge with (each once per triangle)
    // The simplifier only removes: every output position is an input one. Where not, the two below are left empty.
    bool outputInInput = true;
    Rows outputFan;                       // per slot, the output triangles around it (their first corners in outputCorners)
    std::vector<uint32_t> nearestKept;    // per slot, its nearest output slot over the input's edges (breadth first; kNone
                                          // where none is connected to it)

    size_t slots() const { return vertexOf.size(); }
    // The slot of a position id, kNone where the input has none there.
    uint32_t slot_of(uint32_t positionId) const;

private:
    // Open addressing by position id, at most half full: (position id, slot).
    std::vector<std::pair<uint32_t, uint32_t>> table_;
    size_t place_of(uint32_t id) const;  // its entry, or the empty one where it would go
    std::pair<uint32_t, uint32_t>& find(uint32_t id) { return table_[place_of(id)]; }
    void insert(uint32_t id, uint32_t slot);
};

}  // namespace tessera
