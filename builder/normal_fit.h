// Internal to the builder: the normals a simplified group's vertices are drawn with. meshoptimizer keeps each vertex's
// own normal; interpolated over the larger triangles of a coarser level, those normals miss the normals of the surface
// the triangles stand for (on a bumpy scan, a kept vertex on a bump's flank tilts a whole coarse triangle). Each kept
// interior vertex instead gets the normal that fits, in the least-squares sense, the normals of the group's input at
// their nearest points on the simplified surface. Positions, and so the DAG's geometry and errors, do not change.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace tessera {

// Per-vertex normals (xyz floats) through an index: vertex v's normal is `table + 3 * index[v]` where index[v] is
// below `tableCount`, else `extra + 3 * (index[v] - tableCount)`.
struct NormalTable {
    const float* table = nullptr;
    uint32_t tableCount = 0;
    const float* extra = nullptr;
    const uint32_t* index = nullptr;
    const float* operator()(uint32_t v) const {
        const uint32_t i = index[v];
        return i < tableCount ? table + 3 * size_t(i) : extra + 3 * size_t(i - tableCount);
    }
};

struct FittedNormal {
    uint32_t vertex;  // a vertex of the simplified group, interior to it
    std::array<float, 3> normal;
};

// `input`: the group's triangles before simplification, `output` after (vertex ids, a subset of the input's).
// `positionId`: vertices at one position share an id; a position with several vertices in the group (a seam) keeps its
// normals, as does a locked vertex (`lock` non-zero: shared with another group, whose clusters draw it too).
// `drawn`: the normal each vertex is drawn with: the input's are the targets (the finer level's normals, themselves
// fitted above the source), the output's the starting point. Returns the output's vertices whose fitted normal
// differs from the one drawn, with that normal (unit length).
std::vector<FittedNormal> fit_normals(const std::vector<uint32_t>& input, const uint32_t* output, size_t outputCount, const std::vector<float>& positions,
                                      const std::vector<uint32_t>& positionId, const std::vector<unsigned char>& lock, const NormalTable& drawn);

}  // namespace tessera
