// The fallback mesh: a cut of the built DAG as a plain indexed triangle mesh.
#include "fallback.h"

#include <cmath>
#include <cstring>
#include <unordered_map>

namespace tessera {

FallbackMesh extract_cut(const BuiltMesh& mesh, const DagCut& cut) {
    struct Key {
        uint32_t bits[8];  // position bits, the octahedral normal, the colour's halves, the texture coordinates' bits
        bool operator==(const Key&) const = default;
    };
    struct Hash {
        size_t operator()(const Key& k) const {
            size_t h = 0;
            for (uint32_t b : k.bits) h = h * 0x9e3779b1u + b;
            return h;
        }
    };
    const bool colors = !mesh.colors.empty(), uvs = !mesh.uvs.empty(), slots = mesh.materialSlots > 1;
    FallbackMesh out;
    out.threshold = cut.source ? -1.0f : cut.threshold;
    std::unordered_map<Key, uint32_t, Hash> vertexOf;
    for (const Cluster& c : mesh.clusters) {
        if (!cut.contains({c.lodError, c.parentError, c.level, c.triangleCount, -1, -1})) continue;
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            const uint32_t packed = mesh.triangles[c.triangleOffset + t];
            if (slots) out.materialSlots.push_back(uint8_t(packed >> 24));
            for (int k = 0; k < 3; ++k) {
                const uint32_t v = c.vertexOffset + ((packed >> (8 * k)) & 0xff);
                Key key{};
                std::memcpy(key.bits, &mesh.positions[3 * size_t(v)], 12);
                key.bits[3] = mesh.normals[v];
                if (colors) key.bits[4] = mesh.colors[2 * size_t(v)], key.bits[5] = mesh.colors[2 * size_t(v) + 1];
                if (uvs) std::memcpy(&key.bits[6], &mesh.uvs[2 * size_t(v)], 8);
                auto [it, added] = vertexOf.try_emplace(key, uint32_t(out.positions.size() / 3));
                if (added) {
                    out.positions.insert(out.positions.end(), &mesh.positions[3 * size_t(v)], &mesh.positions[3 * size_t(v)] + 3);
                    const auto n = decode_octahedral(mesh.normals[v]);
                    out.normals.insert(out.normals.end(), n.begin(), n.end());
                    if (colors)
                        for (int h = 0; h < 4; ++h) out.colors.push_back(half_to_float(uint16_t(mesh.colors[2 * size_t(v) + h / 2] >> (16 * (h % 2)))));
                    if (uvs) out.uvs.insert(out.uvs.end(), &mesh.uvs[2 * size_t(v)], &mesh.uvs[2 * size_t(v)] + 2);
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

FallbackMesh fallback_mesh(const BuiltMesh& mesh) {
    if (std::isnan(mesh.fallbackThreshold)) return {};
    FallbackMesh out = extract_fallback(mesh, mesh.fallbackThreshold);
    out.error = mesh.fallbackError;
    return out;
}

}  // namespace tessera
