// Internal to the builder: Preserve Area (BuildSettings::preserveArea). Simplifying foliage drops whole leaves and cuts
// corners, so each coarser level covers less; the open borders of what remains are pushed outward, in each triangle's
// plane, until the group covers its children's area again ("scale each leaf up"). What counts is the area a part
// covers, not its surface: per connected part, the length of its vector area (the sum of its triangles' area-weighted
// normals), which for an open part depends only on its border loop. A flat card covers its whole area, a closed part
// nothing, and the bumps a simplification flattens, which shrink the surface but not what it covers, ask for no
// dilation (measured as surface area, they pushed a bumpy open sheet's borders out to the cap: session 35).
#pragma once

#include <cstdint>
#include <vector>

namespace tessera {

double triangle_area(const float* a, const float* b, const float* c);

// The area the triangles `indices` cover (see above); `positionId`: vertices at one position share an id.
double covered_area(const std::vector<uint32_t>& indices, const std::vector<float>& positions, const std::vector<uint32_t>& positionId);

struct Dilation {
    std::vector<float> positions;  // the moved vertices, new ids firstNewId, firstNewId + 1, ... (3 floats each)
    std::vector<uint32_t> sources; // per moved vertex, the vertex it replaces (its attributes carry over)
    float displacement = 0;        // the farthest any vertex moved: the error it adds
};

// Moves the vertices on the open border of `indices` that `lock` leaves free (group borders stay: crack-free) by a
// common distance, at most maxDisplacement, chosen so that the triangles' covered area reaches targetArea; rewrites
// `indices` to the moved vertices. New positions are snapped to the grid of `step`.
Dilation dilate_open_borders(std::vector<uint32_t>& indices, const std::vector<float>& positions, const std::vector<uint32_t>& positionId,
                             const std::vector<unsigned char>& lock, double targetArea, double maxDisplacement, double step, uint32_t firstNewId);

}  // namespace tessera
