// Internal to the page codec (cluster_encoder.cpp, cluster_decoder.cpp): the order in which a unit's vertices are
// stored and what each new one is predicted from. The encoder and the decoder walk the same way, so they predict
// from the same, already known, vertices: the parallelogram across an edge seen before, else the edge's midpoint,
// else a known corner, else the unit's previous vertex.
#pragma once

#include "tessera/builder.h"

#include <algorithm>
#include <cstdint>
#include <span>
#include <vector>

namespace tessera {

constexpr uint32_t kNoVertex = UINT32_MAX;  // a corner not known yet
constexpr int64_t kGridLimit = int64_t(1) << 31;  // grid coordinates fit in int32: residuals stay below 2^34
constexpr uint32_t kMaxResidualBits = 40;
constexpr int32_t kNormalMax = (1 << (kNormalBits - 1)) - 1;

// The corner opposite each directed edge of the triangles seen so far in one cluster (local numbers < 256).
class OppositeCorners {
public:
    OppositeCorners() : cells_(256 * 256, 0) {}
    void clear() {
        for (uint32_t key : touched_) cells_[key] = 0;
        touched_.clear();
    }
    void add(uint32_t from, uint32_t to, uint32_t opposite) {
        const uint32_t key = from << 8 | to;
        if (!cells_[key]) touched_.push_back(key);
        cells_[key] = uint16_t(opposite + 1);
    }
    uint32_t find(uint32_t from, uint32_t to) const {
        const uint16_t cell = cells_[from << 8 | to];
        return cell ? cell - 1u : kNoVertex;
    }

private:
    std::vector<uint16_t> cells_;
    std::vector<uint32_t> touched_;
};

// The other corners of the triangle that first uses a vertex, where already known, and the corner across
// their edge in an earlier triangle (cluster-local numbers, or kNoVertex).
struct Neighbours {
    uint32_t a = kNoVertex, b = kNoVertex, across = kNoVertex;
};

// Visits a cluster's vertices in first-use order: visit(v, neighbours). False unless the triangles number
// 0..vertexCount-1 by first use.
template <typename Visit>
bool walk_first_use(std::span<const uint32_t> corners, uint32_t vertexCount, OppositeCorners& opposite, Visit&& visit) {
    opposite.clear();
    uint32_t next = 0;
    for (size_t t = 0; t < corners.size(); t += 3) {
        const uint32_t* tri = &corners[t];
        uint32_t fresh[3];
        int freshCount = 0;
        for (int j = 0; j < 3; ++j)
            if (tri[j] >= next) fresh[freshCount++] = tri[j];
        std::sort(fresh, fresh + freshCount);
        freshCount = int(std::unique(fresh, fresh + freshCount) - fresh);
        for (int i = 0; i < freshCount; ++i) {
            const uint32_t v = fresh[i];
            if (v != next || v >= vertexCount) return false;
            const int j = tri[0] == v ? 0 : tri[1] == v ? 1 : 2;
            const uint32_t a = tri[(j + 1) % 3], b = tri[(j + 2) % 3];
            Neighbours n;
            if (a < v) n.a = a;
            if (b < v) n.b = b;
            if (n.a != kNoVertex && n.b != kNoVertex) n.across = opposite.find(b, a);
            visit(v, n);
            ++next;
        }
        for (int j = 0; j < 3; ++j) opposite.add(tri[j], tri[(j + 1) % 3], tri[(j + 2) % 3]);
    }
    return next == vertexCount;
}

// A unit's vertices, in unit order (cluster after cluster): grid positions, normal bits, colours.
struct UnitVertices {
    std::vector<int64_t> grid, normal, uv;  // uv: texture coordinates on the mesh's UV grid, when it has them
    std::vector<uint32_t> color;
    void resize(size_t count, bool colors, bool uvs) {
        grid.resize(3 * count);
        normal.resize(2 * count);
        color.resize(colors ? 2 * count : 0);
        uv.resize(uvs ? 2 * count : 0);
    }
};

// Unit vertex numbers a new vertex is predicted from (-1: none).
struct Predictor {
    int64_t a = -1, b = -1, across = -1, previous = -1;
    Predictor(const Neighbours& n, int64_t first, int64_t self) : previous(self - 1) {
        if (n.a != kNoVertex) a = first + n.a;
        if (n.b != kNoVertex) b = first + n.b;
        if (n.across != kNoVertex) across = first + n.across;
    }
    int64_t operator()(const std::vector<int64_t>& values, int stride, int k) const {
        auto at = [&](int64_t vertex) { return values[size_t(vertex * stride + k)]; };
        if (across >= 0) return at(a) + at(b) - at(across);
        if (a >= 0 && b >= 0) return (at(a) + at(b)) >> 1;
        if (a >= 0) return at(a);
        if (b >= 0) return at(b);
        return previous >= 0 ? at(previous) : 0;
    }
};

}  // namespace tessera
