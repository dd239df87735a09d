// The fallback mesh: a cut of the built DAG as a plain indexed triangle mesh.
#include "fallback.h"

#include <cstring>
#include <unordered_map>

namespace tessera {

FallbackMesh extract_cut(const BuiltMesh& mesh, const DagCut& cut) {
    struct Key {
        uint32_t bits[4];  // position bits and the octahedral normal
        bool operator==(const Key&) const = default;
    };
    struct Hash {
        size_t operator()(const Key& k) const { return (k.bits[0] * 73856093u) ^ (k.bits[1] * 19349663u) ^ (k.bits[2] * 83492791u) ^ k.bits[3]; }
    };
    FallbackMesh out;
    out.threshold = cut.source ? -1.0f : cut.threshold;
    std::unordered_map<Key, uint32_t, Hash> vertexOf;
    for (const Cluster& c : mesh.clusters) {
        if (!cut.contains({c.lodError, c.parentError, c.level, c.triangleCount, -1, -1})) continue;
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            const uint32_t packed = mesh.triangles[c.triangleOffset + t];
            for (int k = 0; k < 3; ++k) {
                const uint32_t v = c.vertexOffset + ((packed >> (8 * k)) & 0xff);
                Key key;
                std::memcpy(key.bits, &mesh.positions[3 * v], 12);
                key.bits[3] = mesh.normals[v];
                auto [it, added] = vertexOf.try_emplace(key, uint32_t(out.positions.size() / 3));
                if (added) {
                    out.positions.insert(out.positions.end(), &mesh.positions[3 * v], &mesh.positions[3 * v] + 3);
                    const auto n = decode_octahedral(mesh.normals[v]);
                    out.normals.insert(out.normals.end(), n.begin(), n.end());
                }
                out.indices.push_back(it->second);
            }
        }
    }
    return out;
}

FallbackMesh extract_fallback(const BuiltMesh& mesh, float threshold) {
    return extract_cut(mesh, threshold < 0 ? DagCut{} : DagCut{false, threshold});
}

}  // namespace tessera
