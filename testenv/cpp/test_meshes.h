// Helpers shared by the C++ test suites.
#pragma once

#include "tessera/builder.h"

// A polygon mesh view over arrays the caller keeps alive.
inline tessera::MeshView polygon_view(std::string name, std::span<const float> points, std::span<const int32_t> counts,
                                      std::span<const int32_t> indices) {
    tessera::MeshView v;
    v.name = std::move(name);
    v.points = points;
    v.faceVertexCounts = counts;
    v.faceVertexIndices = indices;
    return v;
}
