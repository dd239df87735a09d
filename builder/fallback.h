// Internal to the builder: the fallback mesh, a DAG cut turned into one indexed triangle mesh.
#pragma once

#include "cut.h"
#include "tessera/builder.h"

namespace tessera {

// The triangles of the clusters in `cut` (with their material slots), with vertices that match in every attribute
// (position, normal, colour, texture coordinates; bit for bit) merged, so that cluster borders, whose vertices the DAG
// keeps identical, become shared vertices. `error` is left to the caller.
FallbackMesh extract_cut(const BuiltMesh& mesh, const DagCut& cut);

}  // namespace tessera
