// The blocks of the cull's hierarchical cut (shaders/cull.comp.glsl): each DAG level's clusters gathered into
// spatially compact blocks of at most TS_CUT_BLOCK_SIZE, with bounds that let the cut skip a whole block for an
// instance. Without them, an instance whose depth range spans many levels (a large mesh seen from close by) had every
// cluster of those levels tested. Private to the renderer.
#pragma once

#include "shared.h"

#include <cstdint>
#include <vector>

namespace tessera {

// Appends the blocks of one level: `clusters` are the level's `count` GPU clusters, the first of which is cluster
// `firstInMesh` of its mesh. `blockClusters` gets each block's clusters (counted from the mesh's first cluster), ordered
// along a Morton curve through their culling spheres' centres so that a block's clusters lie close together.
void append_cut_blocks(const gpu::GpuCluster* clusters, uint32_t count, uint32_t firstInMesh, std::vector<gpu::GpuCutBlock>& blocks,
                       std::vector<uint32_t>& blockClusters);

}  // namespace tessera
