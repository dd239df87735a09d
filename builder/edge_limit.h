// Internal to the builder: the edge length limit (BuildSettings::maxEdgeLengthFactor). meshoptimizer 0.22 has no such
// limit, so a group that simplified into too long an edge simplifies again with the vertices that would split it pinned.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tessera {

// Squared distance between two points (xyz floats), in double.
double distance2(const float* a, const float* b);

// Mean length of the triangles' edges (each triangle's three).
double mean_edge_length(const std::vector<uint32_t>& indices, const std::vector<float>& positions);

struct EdgeCheck {
    bool tooLong = false;        // the output has an edge longer than the limit that the original did not have
    std::vector<uint32_t> pins;  // for each such edge, the unlocked vertex of `from` removed nearest its midpoint
};
// `original` holds the edges that may stay whatever their length, `from` what this simplification step started with.
// `positionId` says which vertices share a position (edges are compared by position); `lock` marks vertices the
// simplifier could not remove (never pinned again).
EdgeCheck check_edge_lengths(const std::vector<uint32_t>& original, const std::vector<uint32_t>& from, const uint32_t* output, size_t outputCount,
                             const std::vector<float>& positions, const std::vector<uint32_t>& positionId, const std::vector<unsigned char>& lock,
                             double maxLength);

}  // namespace tessera
