// Preserve Area: dilating the open borders of a simplified group back to its children's area.
#include "area.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

namespace tessera {
namespace {

struct V3 {
    double x = 0, y = 0, z = 0;
};
V3 operator-(V3 a, V3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
V3 operator+(V3 a, V3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
V3 operator*(V3 a, double s) { return {a.x * s, a.y * s, a.z * s}; }
double dot(V3 a, V3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
V3 cross(V3 a, V3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
V3 load(const float* p) { return {p[0], p[1], p[2]}; }

uint64_t edge_key(uint32_t a, uint32_t b) { return a < b ? uint64_t(a) << 32 | b : uint64_t(b) << 32 | a; }

// Per triangle, its connected part (triangles that share a position, transitively), numbered from 0 in order of first
// triangle; `parts` the count.
std::vector<uint32_t> connected_parts(const std::vector<uint32_t>& indices, const std::vector<uint32_t>& positionId, uint32_t& parts) {
    const size_t triangles = indices.size() / 3;
    std::vector<uint32_t> root(triangles);
    for (size_t t = 0; t < triangles; ++t) root[t] = uint32_t(t);
    auto find = [&](uint32_t t) {
        while (root[t] != t) t = root[t] = root[root[t]];
        return t;
    };
    std::unordered_map<uint32_t, uint32_t> firstAt;  // position id -> a triangle there
    for (size_t i = 0; i < indices.size(); ++i) {
        const auto [it, inserted] = firstAt.try_emplace(positionId[indices[i]], uint32_t(i / 3));
        if (inserted) continue;
        const uint32_t a = find(it->second), b = find(uint32_t(i / 3));
        if (a != b) root[std::max(a, b)] = std::min(a, b);
    }
    std::vector<uint32_t> part(triangles), number(triangles, UINT32_MAX);
    parts = 0;
    for (size_t t = 0; t < triangles; ++t) {
        uint32_t& n = number[find(uint32_t(t))];
        if (n == UINT32_MAX) n = parts++;
        part[t] = n;
    }
    return part;
}

// The covered area (area.h) of triangles whose corner i lies at corner(i), in parts `part` (per triangle).
template <typename Corner>
double covered_area_of(size_t triangles, const std::vector<uint32_t>& part, uint32_t parts, Corner corner) {
    std::vector<V3> vectorArea(parts);
    for (size_t t = 0; t < triangles; ++t) {
        const V3 p0 = corner(3 * t), n = cross(corner(3 * t + 1) - p0, corner(3 * t + 2) - p0);
        vectorArea[part[t]] = vectorArea[part[t]] + n * 0.5;
    }
    double sum = 0;
    for (const V3& a : vectorArea) sum += std::sqrt(dot(a, a));
    return sum;
}

}  // namespace

double triangle_area(const float* a, const float* b, const float* c) {
    const V3 n = cross(load(b) - load(a), load(c) - load(a));
    return 0.5 * std::sqrt(dot(n, n));
}

double covered_area(const std::vector<uint32_t>& indices, const std::vector<float>& positions, const std::vector<uint32_t>& positionId) {
    uint32_t parts = 0;
    const std::vector<uint32_t> part = connected_parts(indices, positionId, parts);
    return covered_area_of(indices.size() / 3, part, parts, [&](size_t i) { return load(&positions[3 * size_t(indices[i])]); });
}

Dilation dilate_open_borders(std::vector<uint32_t>& indices, const std::vector<float>& positions, const std::vector<uint32_t>& positionId,
                             const std::vector<unsigned char>& lock, double targetArea, double maxDisplacement, double step, uint32_t firstNewId) {
    Dilation out;
    std::unordered_map<uint64_t, uint32_t> edgeUses;  // by position, so that attribute seams are not borders
    for (size_t i = 0; i < indices.size(); ++i) {
        const size_t t = i - i % 3;
        ++edgeUses[edge_key(positionId[indices[i]], positionId[indices[t + (i + 1) % 3]])];
    }
    // Each free border position collects the outward directions (in the triangle's plane) of its border edges;
    // triangles are visited in order, so the sums do not depend on hashing.
    struct Outward {
        V3 sum;
        int count = 0;
    };
    std::unordered_map<uint32_t, Outward> outward;
    double movableLength = 0;
    for (size_t i = 0; i < indices.size(); ++i) {
        const size_t t = i - i % 3;
        const uint32_t a = indices[i], b = indices[t + (i + 1) % 3], c = indices[t + (i + 2) % 3];
        if (edgeUses[edge_key(positionId[a], positionId[b])] != 1 || (lock[a] && lock[b])) continue;
        const V3 pa = load(&positions[3 * a]), edge = load(&positions[3 * b]) - pa, normal = cross(edge, load(&positions[3 * c]) - pa);
        V3 u = cross(edge, normal);
        const double length = std::sqrt(dot(u, u));
        if (length == 0) continue;
        u = u * (1 / length);
        if (dot(u, load(&positions[3 * c]) - pa) > 0) u = u * -1.0;
        for (uint32_t v : {a, b})
            if (!lock[v]) {
                Outward& o = outward[positionId[v]];
                o.sum = o.sum + u;
                ++o.count;
            }
        movableLength += std::sqrt(dot(edge, edge)) * ((lock[a] ? 0 : 1) + (lock[b] ? 0 : 1)) / 2;
    }
    if (outward.empty()) return out;
    // The offset that moves every border edge at a vertex out by one unit: m / |m|^2 for m the mean of the edges'
    // normals (exact for two edges). Capped at 3 units, where a spike's edges nearly oppose each other.
    std::vector<V3> offset(indices.size());
    std::vector<bool> moves(indices.size(), false);
    for (size_t i = 0; i < indices.size(); ++i) {
        auto it = outward.find(positionId[indices[i]]);
        if (it == outward.end()) continue;
        const V3 m = it->second.sum * (1.0 / it->second.count);
        const double m2 = dot(m, m);
        if (m2 < 1e-12) continue;
        V3 o = m * (1 / m2);
        const double length = std::sqrt(dot(o, o));
        if (length > 3) o = o * (3 / length);
        offset[i] = o;
        moves[i] = true;
    }
    uint32_t parts = 0;
    const std::vector<uint32_t> part = connected_parts(indices, positionId, parts);
    auto area = [&](double d) {
        return covered_area_of(indices.size() / 3, part, parts, [&](size_t i) { return load(&positions[3 * size_t(indices[i])]) + offset[i] * d; });
    };
    const double start = area(0);
    if (start >= targetArea * (1 - 1e-3)) return out;
    // Secant steps from the first-order estimate (added area ~ distance x movable border length).
    double d0 = 0, f0 = start - targetArea;
    double d1 = std::min(maxDisplacement, (targetArea - start) / std::max(movableLength, 1e-30)), f1 = area(d1) - targetArea;
    for (int iteration = 0; iteration < 8 && std::fabs(f1) > 1e-4 * targetArea && f1 != f0; ++iteration) {
        const double d2 = std::clamp(d1 - f1 * (d1 - d0) / (f1 - f0), 0.0, maxDisplacement);
        d0 = d1;
        f0 = f1;
        d1 = d2;
        f1 = area(d1) - targetArea;
    }
    // Move: every vertex at a moving position gets a new vertex (seam wedges move together), on the grid.
    std::unordered_map<uint32_t, uint32_t> movedTo;
    for (size_t i = 0; i < indices.size(); ++i) {
        if (!moves[i]) continue;
        const uint32_t v = indices[i];
        if (auto it = movedTo.find(v); it != movedTo.end()) {
            indices[i] = it->second;
            continue;
        }
        const V3 target = load(&positions[3 * v]) + offset[i] * d1;
        const float p[3] = {float(std::round(target.x / step) * step) + 0.0f, float(std::round(target.y / step) * step) + 0.0f,
                            float(std::round(target.z / step) * step) + 0.0f};
        double moved2 = 0;
        for (int k = 0; k < 3; ++k) moved2 += double(p[k] - positions[3 * v + k]) * (p[k] - positions[3 * v + k]);
        if (moved2 == 0) {
            movedTo[v] = v;
            continue;
        }
        const uint32_t id = firstNewId + uint32_t(out.sources.size());
        out.positions.insert(out.positions.end(), p, p + 3);
        out.sources.push_back(v);
        out.displacement = std::max(out.displacement, float(std::sqrt(moved2)));
        movedTo[v] = id;
        indices[i] = id;
    }
    return out;
}

}  // namespace tessera
