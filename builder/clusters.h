// Internal to the builder: triangles into clusters (dag.cpp: level 0 and every simplified group's re-split).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tessera {

// Splits triangles over vertices 0..vertexCount-1 (xyz in `positions`) into clusters of at most `maxTriangles`
// triangles and `maxVertices` vertices (at most 255): each cluster's corners, 3 per triangle, in the order taken.
//
// The result is exactly meshopt_buildMeshlets's (cone weight 0): the same greedy growth over shared vertices (its
// topological priorities, then the distance of a triangle's centroid to the cluster's mean centroid, in the same float
// arithmetic, ties broken in the order its scan meets them), the nearest triangle anywhere when the cluster's
// surroundings run out. It costs less: the triangles around the cluster are kept in a list with their priorities,
// updated only around the triangle taken (meshoptimizer rescans every cluster vertex's triangles at each step), and
// the nearest-triangle search is a uniform grid built on first need. Where two triangles are exactly as near (a mesh
// symmetric about its centre, a regular grid), meshoptimizer's k-d tree order decides: the same tree is then built
// to ask it. Returns false, leaving `clusters` empty, only for a mesh of no area (meshoptimizer's scores are not
// numbers there) or of 2^24 triangles or more (its counts are packed): the caller then uses meshoptimizer.
// `clusterOfTriangle`, where given, receives each triangle's cluster.
bool build_clusters(const uint32_t* indices, size_t indexCount, const float* positions, size_t vertexCount, size_t maxVertices, size_t maxTriangles,
                    std::vector<std::vector<uint32_t>>& clusters, std::vector<uint32_t>* clusterOfTriangle = nullptr);

}  // namespace tessera
