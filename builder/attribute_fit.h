// Internal to the builder: the normals and vertex channel (displayColor, primvar readers' inputs) a simplified group's
// vertices are drawn with. meshoptimizer keeps each vertex's own; interpolated over the larger triangles of a coarser
// level, those values miss the surface the triangles stand for (on a bumpy scan, a kept vertex on a bump's flank tilts
// a whole coarse triangle; on a scan coloured per vertex, a kept vertex's speck colours it). Each kept interior vertex
// instead gets the values that fit, in the least-squares sense, those of the group's input at their nearest points on
// the simplified surface. Positions, and so the DAG's geometry and errors, do not change.
#pragma once

#include "group_positions.h"

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace tessera {

// Per-vertex values (`width` floats each) through an index: vertex v's are at `table + width * index[v]` where
// index[v] is below `tableCount`, else at `extra + width * (index[v] - tableCount)`.
struct VertexTable {
    const float* table = nullptr;
    uint32_t tableCount = 0;
    const float* extra = nullptr;
    const uint32_t* index = nullptr;
    uint32_t width = 3;
    const float* operator()(uint32_t v) const {
        const uint32_t i = index[v];
        return i < tableCount ? table + size_t(width) * i : extra + size_t(width) * (i - tableCount);
    }
};

struct FittedAttributes {
    uint32_t vertex;  // a vertex of the simplified group, interior to it
    std::array<float, 3> normal;   // unit length
    std::array<float, 4> channel;  // within the range of the group's input values (unused without a channel)
};

// `input`: the group's triangles before simplification, `output` after (vertex ids, a subset of the input's), `group`
// their positions (vertices at one position share a slot); a position with several vertices in the group (a seam) keeps
// its values, as does a locked vertex (`lock` non-zero: shared with another group, whose clusters draw it too).
// `normals`, `channel` (4 wide; null where the mesh has none): the values each vertex is drawn with. The input's are
// the targets (the finer level's, themselves fitted above the source), the output's the starting point. Returns the
// output's vertices whose fitted values differ from those drawn.
std::vector<FittedAttributes> fit_attributes(const std::vector<uint32_t>& input, const uint32_t* output, size_t outputCount,
                                             const GroupPositions& group, const std::vector<float>& positions,
                                             const std::vector<unsigned char>& lock, const VertexTable& normals, const VertexTable* channel);

}  // namespace tessera
