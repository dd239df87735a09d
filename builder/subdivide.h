// Internal to the builder: uniform subdivision of a validated polygon mesh (subdivide.cpp).
#pragma once

#include "tessera/builder.h"

namespace tessera {

struct RefinedMesh {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    std::vector<float> colors;  // per point (Vertex) or per face (Uniform), 3 floats each
    Interpolation colorInterpolation = Interpolation::None;
};

// Refines `mesh.refineLevel` times with `mesh.subdivisionScheme`, from the valid faces given (`counts`/`indices`,
// `holes` indexing them; `uniformColors` one colour per given face, or null). False, with `problem` set, when
// OpenSubdiv cannot refine the topology.
bool refine_subdivision(const MeshView& mesh, std::span<const int32_t> counts, std::span<const int32_t> indices, std::span<const int32_t> holes,
                        const float* uniformColors, RefinedMesh& out, std::string& problem);

}  // namespace tessera
