// The CPU side of runtime displacement (displacement.h): displacement normals, UV seams, per-cluster bounds.
#include "displacement.h"

#include "shared.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>

namespace tessera {

namespace {

// Vertices that meet (split at seams and hard edges) share a position, by its bits: each vertex's position number, the
// positions numbered in order of first use (an open-addressing table of the first vertex at each).
struct Positions {
    std::vector<uint32_t> of;  // by vertex
    uint32_t count = 0;
};
Positions number_positions(const BuiltMesh& mesh) {
    const size_t vertices = mesh.positions.size() / 3;
    const uint32_t* bits = reinterpret_cast<const uint32_t*>(mesh.positions.data());
    size_t capacity = 64;
    while (capacity < 2 * vertices) capacity *= 2;
    std::vector<uint32_t> table(capacity, UINT32_MAX);  // a position's first vertex
    Positions p;
    p.of.resize(vertices);
    for (uint32_t v = 0; v < vertices; ++v) {
        const uint32_t* k = &bits[3 * size_t(v)];
        uint64_t h = (uint64_t(k[0]) * 0x9E3779B97F4A7C15ull) ^ (uint64_t(k[1]) * 0xC2B2AE3D27D4EB4Full) ^ (uint64_t(k[2]) * 0x165667B19E3779F9ull);
        size_t at = size_t(h ^ (h >> 29)) & (capacity - 1);
        for (;; at = (at + 1) & (capacity - 1)) {
            const uint32_t first = table[at];
            if (first == UINT32_MAX) {
                table[at] = v;
                p.of[v] = p.count++;
                break;
            }
            if (std::memcmp(&bits[3 * size_t(first)], k, 12) == 0) {
                p.of[v] = p.of[first];
                break;
            }
        }
    }
    return p;
}

// Calls visit(v) for each vertex of the level-0 clusters, in order (clusters come level by level, level 0 first).
template <class Visit>
void for_level_zero(const BuiltMesh& mesh, Visit visit) {
    for (const Cluster& c : mesh.clusters) {
        if (c.level != 0) break;
        for (uint32_t v = c.vertexOffset; v < c.vertexOffset + c.vertexCount; ++v) visit(v);
    }
}

std::array<uint32_t, 3> corners_of(const BuiltMesh& mesh, const Cluster& c, uint32_t t) {
    const uint32_t packed = mesh.triangles[c.triangleOffset + t];
    return {c.vertexOffset + (packed & 0xffu), c.vertexOffset + ((packed >> 8) & 0xffu), c.vertexOffset + ((packed >> 16) & 0xffu)};
}

// Per vertex, the direction displacement moves it (see displacement_normals).
std::vector<uint32_t> normals_by_position(const BuiltMesh& mesh, const Positions& positions) {
    // Each position's distinct level-0 normals, in the order of its vertices (the sum below adds them in that order).
    std::vector<uint32_t> start(positions.count + 1, 0), distinct(positions.count, 0);
    for_level_zero(mesh, [&](uint32_t v) { ++start[positions.of[v] + 1]; });
    for (uint32_t i = 0; i < positions.count; ++i) start[i + 1] += start[i];
    std::vector<uint32_t> normals(start.back());
    for_level_zero(mesh, [&](uint32_t v) {
        const uint32_t p = positions.of[v];
        uint32_t* list = &normals[start[p]];
        if (std::find(list, list + distinct[p], mesh.normals[v]) == list + distinct[p]) list[distinct[p]++] = mesh.normals[v];
    });
    std::vector<uint32_t> out(mesh.normals.size());
    for (size_t v = 0; v < out.size(); ++v) {
        const uint32_t p = positions.of[v], n = distinct[p];
        const uint32_t* list = &normals[start[p]];
        if (n <= 1) {
            out[v] = n == 0 ? mesh.normals[v] : list[0];
            continue;
        }
        double sum[3] = {0, 0, 0};
        for (uint32_t k = 0; k < n; ++k) {
            const auto d = decode_octahedral(list[k]);
            for (int c = 0; c < 3; ++c) sum[c] += d[c];
        }
        const double length = std::sqrt(sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]);
        out[v] = length > 1e-12 ? encode_octahedral(float(sum[0] / length), float(sum[1] / length), float(sum[2] / length)) : mesh.normals[v];
    }
    return out;
}

// The UV seams (see append_uv_seams).
std::array<uint32_t, 2> append_seams_by_position(const BuiltMesh& mesh, const Positions& positions, std::vector<uint32_t>& words) {
    if (mesh.uvs.empty()) return {TS_NO_STREAM, TS_NO_STREAM};
    using Uv = std::array<uint32_t, 2>;  // float bits
    auto uv = [&](uint32_t v) {
        Uv u;
        std::memcpy(u.data(), &mesh.uvs[2 * size_t(v)], 8);
        return u;
    };
    // Each position's distinct level-0 texture coordinates, sorted.
    std::vector<std::pair<uint32_t, Uv>> entries;
    for_level_zero(mesh, [&](uint32_t v) { entries.push_back({positions.of[v], uv(v)}); });
    std::sort(entries.begin(), entries.end());
    entries.erase(std::unique(entries.begin(), entries.end()), entries.end());
    std::vector<uint32_t> start(positions.count + 1, 0);
    for (const auto& e : entries) ++start[e.first + 1];
    for (uint32_t i = 0; i < positions.count; ++i) start[i + 1] += start[i];
    bool any = false;
    for (uint32_t p = 0; p < positions.count && !any; ++p) any = start[p + 1] - start[p] > 1;
    if (!any) return {TS_NO_STREAM, TS_NO_STREAM};
    // Positions whose vertices (of any level) carry more than one texture coordinate: only an edge with such an end
    // can have two sides that differ, which is a seam edge.
    std::vector<char> several(positions.count, 0);
    {
        std::vector<uint32_t> firstVertex(positions.count, UINT32_MAX);
        for (uint32_t v = 0; v < positions.of.size(); ++v) {
            uint32_t& first = firstVertex[positions.of[v]];
            if (first == UINT32_MAX) first = v;
            else if (uv(first) != uv(v)) several[positions.of[v]] = 1;
        }
    }
    // The edges with such an end, by their two positions (lower number first), with the distinct (uv at lower, uv at
    // upper) pairs of their triangles, from every level.
    struct EdgeSide {
        uint64_t edge;
        std::array<Uv, 2> pair;
        bool operator<(const EdgeSide& o) const { return edge != o.edge ? edge < o.edge : pair < o.pair; }
        bool operator==(const EdgeSide& o) const { return edge == o.edge && pair == o.pair; }
    };
    auto oriented = [&](uint32_t a, uint32_t b, EdgeSide& side) {  // true where b's position comes first
        const uint32_t pa = positions.of[a], pb = positions.of[b];
        const bool swap = pb < pa;
        side.edge = swap ? uint64_t(pb) << 32 | pa : uint64_t(pa) << 32 | pb;
        side.pair = swap ? std::array<Uv, 2>{uv(b), uv(a)} : std::array<Uv, 2>{uv(a), uv(b)};
        return swap;
    };
    std::vector<EdgeSide> sides;
    for (const Cluster& c : mesh.clusters)
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            const auto v = corners_of(mesh, c, t);
            for (int k = 0; k < 3; ++k) {
                if (!several[positions.of[v[k]]] && !several[positions.of[v[(k + 1) % 3]]]) continue;
                EdgeSide side;
                oriented(v[k], v[(k + 1) % 3], side);
                sides.push_back(side);
            }
        }
    std::sort(sides.begin(), sides.end());
    sides.erase(std::unique(sides.begin(), sides.end()), sides.end());

    const uint32_t vertexWords = uint32_t(words.size());
    words.resize(words.size() + mesh.normals.size(), TS_NO_STREAM);
    std::vector<uint32_t> storedAt(positions.count, TS_NO_STREAM);  // each position's list stored once
    for (uint32_t v = 0; v < mesh.normals.size(); ++v) {
        const uint32_t p = positions.of[v], count = start[p + 1] - start[p];
        if (count < 2) continue;
        if (storedAt[p] == TS_NO_STREAM) {
            storedAt[p] = uint32_t(words.size());
            for (uint32_t k = start[p]; k < start[p + 1]; ++k) words.insert(words.end(), entries[k].second.begin(), entries[k].second.end());
        }
        words[vertexWords + v] = storedAt[p] | std::min<uint32_t>(count, 15u) << TS_SEAM_COUNT_SHIFT;
    }
    const uint32_t triangleWords = uint32_t(words.size());
    words.resize(words.size() + mesh.triangles.size(), TS_NO_STREAM);
    const uint32_t nan = 0x7fc00000u;
    for (const Cluster& c : mesh.clusters)
        for (uint32_t t = 0; t < c.triangleCount; ++t) {
            const auto v = corners_of(mesh, c, t);
            std::array<uint32_t, 12> record;
            record.fill(nan);
            bool seam = false;
            for (int k = 0; k < 3; ++k) {
                if (!several[positions.of[v[k]]] && !several[positions.of[v[(k + 1) % 3]]]) continue;
                EdgeSide side;
                const bool swapped = oriented(v[k], v[(k + 1) % 3], side);
                const auto first = std::lower_bound(sides.begin(), sides.end(), EdgeSide{side.edge, {}});
                auto end = first;
                while (end != sides.end() && end->edge == side.edge) ++end;
                if (end - first != 2) continue;  // inside a UV island (or a non-manifold edge: no single other side)
                const auto& other = first->pair == side.pair ? (first + 1)->pair : first->pair;
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

}  // namespace

// Per vertex, the direction displacement moves it: the mean of the distinct normals that the source (level 0) has at its
// position. Split vertices (hard edges, UV seams) share a position, so they move alike and a displaced hard edge does not
// tear. Every vertex of every level is a source vertex (simplification only removes vertices), so every level finds its
// positions here.
std::vector<uint32_t> displacement_normals(const BuiltMesh& mesh) { return normals_by_position(mesh, number_positions(mesh)); }

// The UV seams of a mesh drawn displaced, appended to `words` in the layout of shaders/shared.h (TS_SEAM_COUNT_SHIFT):
// per vertex, the texture coordinates the source has at its position when there are several; per triangle with a seam
// edge, the other side's coordinates along each edge (found among the triangles of every level, keyed by the edge's two
// positions: every level's vertices are source vertices). Returns {first vertex word, first triangle word}, or
// {TS_NO_STREAM, TS_NO_STREAM} for a mesh without seams (no UVs, or one UV per position).
std::array<uint32_t, 2> append_uv_seams(const BuiltMesh& mesh, std::vector<uint32_t>& words) {
    return append_seams_by_position(mesh, number_positions(mesh), words);
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

DisplacementData displacement_data(const BuiltMesh& mesh) {
    DisplacementData data;
    const Positions positions = number_positions(mesh);
    data.normals = normals_by_position(mesh, positions);
    data.seams = append_seams_by_position(mesh, positions, data.seamWords);
    data.triangles = uint32_t(mesh.triangles.size());
    data.uvBoxes = cluster_uv_boxes(mesh, data.seamWords, data.seams);
    return data;
}

void place_seam_words(const DisplacementData& data, uint32_t base, size_t first, size_t end, uint32_t* to) {
    constexpr uint32_t kIndex = (1u << TS_SEAM_COUNT_SHIFT) - 1u;
    if (size_t(base) + data.seamWords.size() > kIndex)
        throw std::runtime_error("the UV seams of the meshes drawn displaced exceed 2^" + std::to_string(TS_SEAM_COUNT_SHIFT) + " words");
    // The vertex words hold a list's word number (below the count), the triangle words a record's; the lists and records
    // hold texture coordinates.
    const size_t vertexWords = data.seams[0], vertexEnd = vertexWords + data.normals.size();
    const size_t triangleWords = data.seams[1], triangleEnd = triangleWords + data.triangles;
    for (size_t i = first; i < end; ++i) {
        uint32_t word = data.seamWords[i];
        if (word != TS_NO_STREAM && i >= vertexWords && i < vertexEnd) word = ((word & kIndex) + base) | (word & ~kIndex);
        else if (word != TS_NO_STREAM && i >= triangleWords && i < triangleEnd) word += base;
        to[i - first] = word;
    }
}

std::array<uint32_t, 2> append_seam_words(const DisplacementData& data, std::vector<uint32_t>& words) {
    if (data.seams[0] == TS_NO_STREAM) return data.seams;
    const size_t base = words.size();
    words.resize(base + data.seamWords.size());
    place_seam_words(data, uint32_t(base), 0, data.seamWords.size(), words.data() + base);
    return {data.seams[0] + uint32_t(base), data.seams[1] + uint32_t(base)};
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
