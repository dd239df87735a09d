// Internal to the builder: triangles into clusters (dag.cpp; level 0 and every simplified group's re-split).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tessera {

// Splits triangles over vertices 0..vertexCount-1 (xyz in `positions`) into clusters of at most `maxTriangles`
// triangles and `maxVertices` vertices (at most 255). Returns each cluster's corners (3 per triangle, the same vertex
// numbers). Deterministic: the same input gives the same clusters.
//
// Greedy growth over triangle adjacency, the scheme of meshoptimizer's meshlet builder (its topological priorities,
// then the distance of a triangle's centroid to the cluster's mean centroid), made cheaper: the triangles around the
// cluster are kept in a candidate list as vertices join (meshoptimizer rescans every cluster vertex's triangles at each
// step), triangles that add no vertex are taken without a scan, distances are compared squared, and the nearest-
// triangle search used when a cluster's surroundings run out builds its k-d tree only when first needed.
std::vector<std::vector<uint32_t>> build_clusters(const uint32_t* indices, size_t indexCount, const float* positions, size_t vertexCount,
                                                  size_t maxVertices, size_t maxTriangles);

}  // namespace tessera
