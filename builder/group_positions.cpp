// A simplified group's positions in order of first use (group_positions.h).
#include "group_positions.h"

#include <algorithm>

namespace tessera {

size_t GroupPositions::place_of(uint32_t id) const {
    const size_t mask = table_.size() - 1;
    size_t at = (id * 2654435761u) & mask;
    while (table_[at].first != kNone && table_[at].first != id) at = (at + 1) & mask;
    return at;
}

void GroupPositions::insert(uint32_t id, uint32_t slot) {
    if (2 * (size_t(slot) + 1) > table_.size()) {  // grow: twice the capacity, every entry placed again
        std::vector<std::pair<uint32_t, uint32_t>> old(2 * table_.size(), {kNone, kNone});
        old.swap(table_);
        for (const auto& entry : old)
            if (entry.first != kNone) find(entry.first) = entry;
    }
    find(id) = {id, slot};
}

GroupPositions::GroupPositions(const std::vector<uint32_t>& input, const uint32_t* output, size_t outputCount,
                               const std::vector<uint32_t>& positionId) {
    // A closed mesh has about half as many positions as triangles; a soup, up to three per triangle (the table grows).
    size_t capacity = 16;
    while (capacity < input.size() / 3) capacity *= 2;
    table_.assign(capacity, {kNone, kNone});
    corners.resize(input.size());
    for (size_t i = 0; i < input.size(); ++i) {
        const uint32_t v = input[i];
        uint32_t slot = find(positionId[v]).second;  // kNone: a position not met yet
        if (slot == kNone) {
            slot = uint32_t(vertexOf.size());
            insert(positionId[v], slot);
            vertexOf.push_back(v);
            seam.push_back(0);
        } else if (vertexOf[slot] != v) {
            seam[slot] = 1;
        }
        corners[i] = slot;
    }
    neighbours.build(slots(), [&](auto add) {
        for (size_t i = 0; i < corners.size(); i += 3)
            for (int k = 0; k < 3; ++k) {
                add(corners[i + k], corners[i + (k + 1) % 3]);
                add(corners[i + (k + 1) % 3], corners[i + k]);
            }
    });
    outputCorners.resize(outputCount);
    for (size_t i = 0; i < outputCount; ++i) outputCorners[i] = find(positionId[output[i]]).second;
    outputInInput = std::find(outputCorners.begin(), outputCorners.end(), kNone) == outputCorners.end();
    if (!outputInInput) return;
    outputFan.build(slots(), [&](auto add) {
        for (size_t i = 0; i < outputCorners.size(); ++i) add(outputCorners[i], uint32_t(i / 3 * 3));
    });
    nearestKept.assign(slots(), kNone);
    std::vector<uint32_t> queue;
    for (uint32_t slot : outputCorners)
        if (nearestKept[slot] == kNone) {
            nearestKept[slot] = slot;
            queue.push_back(slot);
        }
    for (size_t head = 0; head < queue.size(); ++head)
        for (uint32_t k = neighbours.start[queue[head]]; k < neighbours.start[queue[head] + 1]; ++k)
            if (nearestKept[neighbours.items[k]] == kNone) {
                nearestKept[neighbours.items[k]] = nearestKept[queue[head]];
                queue.push_back(neighbours.items[k]);
            }
}

uint32_t GroupPositions::slot_of(uint32_t positionId) const { return table_[place_of(positionId)].second; }

}  // namespace tessera
