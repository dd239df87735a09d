// Internal to the builder: uniform subdivision of a validated polygon mesh (subdivide.cpp).
#pragma once

#include "tessera/builder.h"

namespace tessera {

struct RefinedMesh {
    std::vector<float> points;
    std::vector<int32_t> counts, indices;
    std::vector<float> colors;  // per point (Vertex) or per face (Uniform), kChannelComponents floats each
    Interpolation colorInterpolation = Interpolation::None;
    std::vector<float> uvs;          // refined texture coordinates, 2 floats each ...
    std::vector<int32_t> uvIndices;  // ... and one index into them per face corner (face-varying), or empty
    std::vector<int32_t> faceMaterials;  // per refined face, its material slot, when given
};

// Texture coordinates of the faces given to refine_subdivision, as one face-varying channel: `indices` has one entry
// per entry of the faces' indices, into `values` (2 floats each).
struct FaceVaryingUvs {
    std::span<const float> values;
    std::span<const int32_t> indices;
};

// Refines `mesh.refineLevel` times with `mesh.subdivisionScheme`, from the valid faces given (`counts`/`indices`,
// `holes` indexing them; `uniformColors` one vertex channel value (kChannelComponents floats) per given face, or null; `uvs` empty or one value index per
// corner; `faceMaterials` empty or one slot per given face), with `mesh.subdivisionTags` (texture coordinates by its
// faceVaryingLinearInterpolation). Tags that cannot be used are reported in `warnings` and ignored.
// False, with `problem` set, when OpenSubdiv cannot refine the topology.
bool refine_subdivision(const MeshView& mesh, std::span<const int32_t> counts, std::span<const int32_t> indices, std::span<const int32_t> holes,
                        const float* uniformColors, const FaceVaryingUvs& uvs, std::span<const int32_t> faceMaterials, RefinedMesh& out,
                        std::string& problem, std::vector<std::string>& warnings);

}  // namespace tessera
