// Internal to the builder: how far a simplified group strays from the source surface, measured at sample points.
//
// A group's error is its distance from the source surface, measured, not an estimate summed level by level (summed,
// the errors claimed 1.5-2.3x the distance at coarse levels; docs/benchmarks.md, session 34). Measured both ways:
// - from the source: the group's input vertices that simplification removed (source vertices: it only removes them)
//   and the source points its children carried up from finer levels, those that strayed most there (SourcePoint), to
//   the simplified triangles;
// - to the source: the simplified edges' midpoints to the group's input triangles (where a simplified edge stands
//   off the surface while every source point lies near some simplified triangle: a fold).
// Both search over the group's surface (group_positions.h), not space: the simplifier keeps a subset of the input's
// vertices, so a point's nearest triangles lie around the kept vertex nearest it over the input's edges (the first
// way), and an edge's midpoint's around the input vertex between its ends (the second). A walk from there towards
// nearer triangles settles a point, and where the point could raise the largest distance so far, every triangle within
// a ball around it is searched, breadth first from there: each distance is to a real triangle, never less than the true
// distance to those triangles, and the largest is the exact one where the surface in that ball is connected. (Uniform
// grids over the triangles, used before, cost a quarter of the build; session 35.) Sampled, it can fall short of the
// exact distance between the samples, and the second way measures against the level below, not the source: on the
// bumpy test sphere the claims came within 0.80-1.19x of the exact distance of the cut from the source (the sum:
// 0.51-2.29x).
#ifndef TESSERA_BUILDER_DEVIATION_H
#define TESSERA_BUILDER_DEVIATION_H

#include "group_positions.h"

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tessera {

// A source point carried up the DAG by the cluster it lies nearest to, with its distance to that cluster's level and
// the cluster's vertex nearest it (where the search over the next level's surface starts).
struct SourcePoint {
    float position[3];
    float distance;
    uint32_t anchor;  // a vertex of the mesh
};

struct Deviation {
    float largest = 0;                           // the largest distance of any point measured
    std::vector<std::vector<SourcePoint>> kept;  // per piece: the points nearest its triangles that strayed most
};

// From the source: `group`: the group's input and simplified triangles over their positions (a point's search starts
// at its anchor's position and walks over the simplified triangles); `corners`: 9 floats per simplified triangle, where
// it is drawn (Preserve Area may have moved its open borders), and `outputVertices` its corners' vertices (3 per
// triangle), both in the group's output order; `pieceOf`: the cluster (piece) each triangle went into, `pieces` of
// them; `points`: the source points to measure; `positionId`: vertices at one position share an id. Each piece keeps
// at most `keepPerPiece` of its points, the farthest first (those on its surface, distance 0, never), anchored at the
// corner of their nearest triangle nearest them.
Deviation measure_deviation(const GroupPositions& group, const std::vector<float>& corners, const uint32_t* outputVertices,
                            const std::vector<uint32_t>& pieceOf, size_t pieces, const std::vector<SourcePoint>& points,
                            const std::vector<uint32_t>& positionId, size_t keepPerPiece);

// To the source: the largest distance of a simplified edge's midpoint from the group's input triangles (`group`: the
// input and the simplified triangles over their positions; `positions`: 3 floats per vertex), or `floor` where none
// lies farther: an error known already (the first way's, say), which every midpoint within it cannot change, so those
// are settled by the first input triangle that near.
float measure_stray(const GroupPositions& group, const std::vector<float>& positions, float floor = 0);

}  // namespace tessera

#endif
