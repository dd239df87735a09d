// Per-cluster bounds the renderer culls with, derived from a built cluster's own triangles.
#include "tessera/builder.h"

#include <meshoptimizer.h>

namespace tessera {

NormalCone cluster_normal_cone(const BuiltMesh& mesh, const Cluster& cluster) {
    uint32_t indices[kClusterMaxTriangles * 3];
    for (uint32_t t = 0; t < cluster.triangleCount; ++t) {
        const uint32_t packed = mesh.triangles[cluster.triangleOffset + t];
        for (int k = 0; k < 3; ++k) indices[3 * t + k] = (packed >> (8 * k)) & 0xffu;
    }
    const meshopt_Bounds bounds = meshopt_computeClusterBounds(indices, cluster.triangleCount * 3, &mesh.positions[3 * size_t(cluster.vertexOffset)],
                                                               cluster.vertexCount, 3 * sizeof(float));
    // The 8-bit form is rounded so that it still holds every normal.
    NormalCone cone;
    cone.axis8 = {bounds.cone_axis_s8[0], bounds.cone_axis_s8[1], bounds.cone_axis_s8[2]};
    cone.cutoff8 = bounds.cone_cutoff_s8;
    return cone;
}

}  // namespace tessera
