// The CPU side of runtime displacement (displacement.h): displacement normals, UV seams, per-cluster bounds.
#include "displacement.h"

#include "shared.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <unordered_map>

namespace tessera {

namespace {

// A built mesh vertex's position, by its bits: vertices that meet (split at seams and hard edges) have the same key.
using PositionKey = std::array<uint32_t, 3>;
struct PositionKeyHash {
    size_t operator()(const PositionKey& p) const { return (size_t(p[0]) * 73856093u) ^ (size_t(p[1]) * 19349663u) ^ (size_t(p[2]) * 83492791u); }
};
PositionKey position_key(const BuiltMesh& mesh, uint32_t vertex) {
    PositionKey k;
    std::memcpy(k.data(), &mesh.positions[3 * size_t(vertex)], 12);
    return k;
}

}  // namespace

// Per vertex, the direction displacement moves it: the mean of the distinct normals that the source (level 0) has at its
// position. Split vertices (hard edges, UV seams) share a position, so they move alike and a displaced hard edge does not
// tear. Every vertex of every level is a source vertex (simplification only removes vertices), so every level finds its
// positions here.
std::vector<uint32_t> displacement_normals(const BuiltMesh& mesh) {
    auto key = [&](uint32_t v) { return position_key(mesh, v); };
    std::unordered_map<PositionKey, std::vector<uint32_t>, PositionKeyHash> normalsAt;
    for (const Cluster& c : mesh.clusters) {
        if (c.level != 0) break;  // clusters come level by level, level 0 first
        for (uint32_t v = c.vertexOffset; v < c.vertexOffset + c.vertexCount; ++v) {
            auto& normals = normalsAt[key(v)];
            if (std::find(normals.begin(), normals.end(), mesh.normals[v]) == normals.end()) normals.push_back(mesh.normals[v]);
        }
    }
    std::vector<uint32_t> out(mesh.normals.size());
    for (size_t v = 0; v < out.size(); ++v) {
        const auto it = normalsAt.find(key(uint32_t(v)));
        if (it == normalsAt.end() || it->second.size() == 1) {
            out[v] = it == normalsAt.end() ? mesh.normals[v] : it->second[0];
            continue;
        }
        double sum[3] = {0, 0, 0};
        for (uint32_t packed : it->second) {
            const auto n = decode_octahedral(packed);
            for (int k = 0; k < 3; ++k) sum[k] += n[k];
        }
        const double length = std::sqrt(sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]);
        out[v] = length > 1e-12 ? encode_octahedral(float(sum[0] / length), float(sum[1] / length), float(sum[2] / length)) : mesh.normals[v];
    }
    return out;
}

// The UV seams of a mesh drawn displaced, appended to `words` in the layout of shaders/shared.h (TS_SEAM_COUNT_SHIFT):
// per vertex, the texture coordinates the source has at its position when there are several; per triangle with a seam
// edge, the other side's coordinates along each edge (found among the triangles of every level, keyed by the edge's two
// positions: every level's vertices are source vertices). Returns {first vertex word, first triangle word}, or
// {TS_NO_STREAM, TS_NO_STREAM} for a mesh without seams (no UVs, or one UV per position).
std::array<uint32_t, 2> append_uv_seams(const BuiltMesh& mesh, std::vector<uint32_t>& words) {
    if (mesh.uvs.empty()) return {TS_NO_STREAM, TS_NO_STREAM};
    using Key = PositionKey;
    using KeyHash = PositionKeyHash;
    using Uv = std::array<uint32_t, 2>;  // float bits
    auto key = [&](uint32_t v) { return position_key(mesh, v); };
    auto uv = [&](uint32_t v) {
        Uv u;
        std::memcpy(u.data(), &mesh.uvs[2 * size_t(v)], 8);
        return u;
    };
    std::unordered_map<Key, std::vector<Uv>, KeyHash> uvsAt;  // distinct, sorted
    for (const Cluster& c : mesh.clusters) {
        if (c.level != 0) break;
        for (uint32_t v = c.vertexOffset; v < c.vertexOffset + c.vertexCount; ++v) {
            auto& list = uvsAt[key(v)];
            const Uv u = uv(v);
            if (std::find(list.begin(), list.end(), u) == list.end()) list.insert(std::upper_bound(list.begin(), list.end(), u), u);
        }
    }
    // Edges by their two positions (lower first), with the distinct (uv at lower, uv at upper) pairs of their triangles.
    struct EdgeHash {
        size_t operator()(const std::array<Key, 2>& e) const { return KeyHash{}(e[0]) * 31 + KeyHash{}(e[1]); }
    };
    std::unordered_map<std::array<Key, 2>, std::vector<std::array<Uv, 2>>, EdgeHash> edges;
    auto corners = [&](const Cluster& c, uint32_t t) {
        const uint32_t packed = mesh.triangles[c.triangleOffset + t];
        return std::array<uint32_t, 3>{c.vertexOffset + (packed & 0xffu), c.vertexOffset + ((packed >> 8) & 0xffu), c.vertexOffset + ((packed >> 16) & 0xffu)};
    };
    auto oriented = [&](uint32_t a, uint32_t b, std::array<Key, 2>& edge, std::array<Uv, 2>& pair) {
        const Key ka = key(a), kb = key(b);
        const bool swap = kb < ka;
        edge = swap ? std::array<Key, 2>{kb, ka} : std::array<Key, 2>{ka, kb};
        pair = swap ? std::array<Uv, 2>{uv(b), uv(a)} : std::array<Uv, 2>{uv(a), uv(b)};
        return swap;
    };
    for (const Cluster& c : mesh.clusters)
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            const auto v = corners(c, t);
            for (int k = 0; k < 3; ++k) {
                std::array<Key, 2> edge;
                std::array<Uv, 2> pair;
                oriented(v[k], v[(k + 1) % 3], edge, pair);
                auto& pairs = edges[edge];
                if (std::find(pairs.begin(), pairs.end(), pair) == pairs.end()) pairs.push_back(pair);
            }
        }
    bool any = false;
    for (const auto& [k, list] : uvsAt) any |= list.size() > 1;
    if (!any) return {TS_NO_STREAM, TS_NO_STREAM};

    const uint32_t vertexWords = uint32_t(words.size());
    words.resize(words.size() + mesh.normals.size(), TS_NO_STREAM);
    std::unordered_map<Key, uint32_t, KeyHash> listAt;  // each position's list stored once
    for (uint32_t v = 0; v < mesh.normals.size(); ++v) {
        const auto it = uvsAt.find(key(v));
        if (it == uvsAt.end() || it->second.size() < 2) continue;
        auto [stored, fresh] = listAt.try_emplace(it->first, uint32_t(words.size()));
        if (fresh)
            for (const Uv& u : it->second) words.insert(words.end(), u.begin(), u.end());
        words[vertexWords + v] = stored->second | std::min<uint32_t>(uint32_t(it->second.size()), 15u) << TS_SEAM_COUNT_SHIFT;
    }
    const uint32_t triangleWords = uint32_t(words.size());
    words.resize(words.size() + mesh.triangles.size(), TS_NO_STREAM);
    const uint32_t nan = 0x7fc00000u;
    for (const Cluster& c : mesh.clusters)
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            const auto v = corners(c, t);
            std::array<uint32_t, 12> record;
            record.fill(nan);
            bool seam = false;
            for (int k = 0; k < 3; ++k) {
                std::array<Key, 2> edge;
                std::array<Uv, 2> pair;
                const bool swapped = oriented(v[k], v[(k + 1) % 3], edge, pair);
                const auto& pairs = edges[edge];
                if (pairs.size() != 2) continue;  // inside a UV island (or a non-manifold edge: no single other side)
                const auto& other = pairs[0] == pair ? pairs[1] : pairs[0];
                const Uv& atK = swapped ? other[1] : other[0];
                const Uv& atNext = swapped ? other[0] : other[1];
                record[4 * k] = atK[0], record[4 * k + 1] = atK[1], record[4 * k + 2] = atNext[0], record[4 * k + 3] = atNext[1];
                seam = true;
            }
            if (!seam) continue;
            words[triangleWords + c.triangleOffset + t] = uint32_t(words.size());
            words.insert(words.end(), record.begin(), record.end());
        }
    return {vertexWords, triangleWords};
}


std::vector<ClusterUvBoxes> cluster_uv_boxes(const BuiltMesh& mesh, const std::vector<uint32_t>& seamWords, std::array<uint32_t, 2> seams) {
    constexpr std::array<float, 4> empty{INFINITY, INFINITY, -INFINITY, -INFINITY};
    auto grow = [](std::array<float, 4>& box, float s, float t) {
        if (std::isnan(s) || std::isnan(t)) return;
        box = {std::min(box[0], s), std::min(box[1], t), std::max(box[2], s), std::max(box[3], t)};
    };
    auto word_float = [&](uint32_t i) {
        float f;
        std::memcpy(&f, &seamWords[i], 4);
        return f;
    };
    std::vector<ClusterUvBoxes> out(mesh.clusters.size(), ClusterUvBoxes{empty, empty});
    for (size_t i = 0; i < mesh.clusters.size(); ++i) {
        const Cluster& c = mesh.clusters[i];
        ClusterUvBoxes& b = out[i];
        if (mesh.uvs.empty()) {
            b.own = {0, 0, 0, 0};
            continue;
        }
        for (uint32_t v = c.vertexOffset; v < c.vertexOffset + c.vertexCount; ++v) {
            grow(b.own, mesh.uvs[2 * size_t(v)], mesh.uvs[2 * size_t(v) + 1]);
            if (seams[0] == TS_NO_STREAM) continue;
            const uint32_t word = seamWords[seams[0] + v];  // every texture coordinate at its position (the GPU averages them)
            if (word == TS_NO_STREAM) continue;
            const uint32_t first = word & ((1u << TS_SEAM_COUNT_SHIFT) - 1u), count = word >> TS_SEAM_COUNT_SHIFT;
            for (uint32_t k = 0; k < count; ++k) grow(b.seams, word_float(first + 2 * k), word_float(first + 2 * k + 1));
        }
        if (seams[0] == TS_NO_STREAM) continue;
        for (uint32_t t = 0; t < c.triangleCount; ++t) {  // the other sides of its seam edges
            const uint32_t record = seamWords[seams[1] + c.triangleOffset + t];
            if (record == TS_NO_STREAM) continue;
            for (uint32_t k = 0; k < 12; k += 2) grow(b.seams, word_float(record + k), word_float(record + k + 1));
        }
    }
    return out;
}

float displacement_bound(const MaterialDesc& material, float low, float high) {
    return std::max(std::abs(low - material.displacementCenter), std::abs(high - material.displacementCenter)) * std::abs(material.displacementMagnitude);
}

namespace {

// The material's displacement texture, or null when it reads a constant (`displacement`, or the fallback of a slot
// whose file could not be read).
const TextureSlot* displacement_texture(const MaterialDesc& material) {
    for (const TextureSlot& slot : material.textures)
        if (slot.input == MaterialInput::Displacement && slot.image) return &slot;
    return nullptr;
}

float displacement_constant(const MaterialDesc& material) {
    for (const TextureSlot& slot : material.textures)
        if (slot.input == MaterialInput::Displacement && !slot.image)
            return slot.fallback[slot.channel == TextureChannel::Rgb ? 0 : size_t(slot.channel)];
    return material.displacement;
}

}  // namespace

float material_displacement_bound(const MaterialDesc& material) {
    if (material.displacementBake) return 0;  // in the mesh already
    float low = displacement_constant(material), high = low;
    if (const TextureSlot* slot = displacement_texture(material)) {
        const size_t c = slot->channel == TextureChannel::Rgb ? 0 : size_t(slot->channel);
        const float a = slot->image->minValue[c] * slot->scale[c] + slot->bias[c], b = slot->image->maxValue[c] * slot->scale[c] + slot->bias[c];
        low = std::min(a, b);
        high = std::max(a, b);
    }
    const float bound = displacement_bound(material, low, high);
    return std::isfinite(bound) && bound > 0 ? bound : 0.0f;
}

const TextureRange& ClusterDisplacementBounds::range(const TextureSlot& slot) {
    const uint32_t channel = slot.channel == TextureChannel::Rgb ? 0 : uint32_t(slot.channel);
    auto& entry = ranges_[{slot.image.get(), channel}];
    if (!entry.second) entry = {slot.image, std::make_unique<TextureRange>(*slot.image, channel)};
    return *entry.second;
}

std::vector<float> ClusterDisplacementBounds::compute(const BuiltMesh& mesh, const std::vector<ClusterUvBoxes>& boxes,
                                                      const std::vector<const MaterialDesc*>& materials) {
    std::vector<float> out(mesh.clusters.size(), 0.0f);
    std::vector<bool> used(materials.size());
    for (size_t i = 0; i < mesh.clusters.size(); ++i) {
        const Cluster& c = mesh.clusters[i];
        // The material slots its triangles use (one material: slot 0).
        std::fill(used.begin(), used.end(), materials.size() == 1);
        if (materials.size() > 1)
            for (uint32_t t = 0; t < c.triangleCount; ++t) {
                const uint32_t slot = mesh.triangles[c.triangleOffset + t] >> 24;
                if (slot < used.size()) used[slot] = true;
            }
        for (size_t m = 0; m < materials.size(); ++m) {
            if (!used[m] || !materials[m]) continue;
            const MaterialDesc& material = *materials[m];
            const float whole = material_displacement_bound(material);
            float bound = whole;
            const TextureSlot* slot = whole > 0 ? displacement_texture(material) : nullptr;
            if (slot && i < boxes.size()) {
                const TextureRange& r = range(*slot);
                float low = INFINITY, high = -INFINITY;
                for (const auto& box : {boxes[i].own, boxes[i].seams}) {
                    if (!(box[0] <= box[2] && box[1] <= box[3])) continue;  // empty
                    const auto part = slot_range(*slot, r, {box[0], box[1]}, {box[2], box[3]});
                    low = std::min(low, part[0]), high = std::max(high, part[1]);
                }
                if (low <= high) bound = std::min(whole, displacement_bound(material, low, high));
            }
            out[i] = std::max(out[i], bound);
        }
    }
    return out;
}

}  // namespace tessera
