// How far a simplified group strays from the source surface, measured at source points (deviation.h).
#include "deviation.h"

#include "rows.h"

#include <algorithm>
#include <cmath>

namespace tessera {
namespace {

float dot3(const float* a, const float* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

float distance2(const float* a, const float* b) {
    const float d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return dot3(d, d);
}

// Squared distance from p to the triangle abc: to the closest point, found by which of the triangle's Voronoi regions
// (a corner, an edge, the face) holds p (Ericson, "Real-Time Collision Detection", 5.1.5). A triangle with no area
// gives its nearest corner's distance, which is no less than the true one.
float distance2_to_triangle(const float* p, const float* a, const float* b, const float* c) {
    const float ab[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, ac[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    const float ap[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]}, bp[3] = {p[0] - b[0], p[1] - b[1], p[2] - b[2]};
    const float cp[3] = {p[0] - c[0], p[1] - c[1], p[2] - c[2]};
    const float d1 = dot3(ab, ap), d2 = dot3(ac, ap);
    if (d1 <= 0 && d2 <= 0) return dot3(ap, ap);
    const float d3 = dot3(ab, bp), d4 = dot3(ac, bp);
    if (d3 >= 0 && d4 <= d3) return dot3(bp, bp);
    const float d5 = dot3(ab, cp), d6 = dot3(ac, cp);
    if (d6 >= 0 && d5 <= d6) return dot3(cp, cp);
    auto at = [&](float s, float t) {  // |p - (a + s ab + t ac)|^2
        const float q[3] = {ap[0] - s * ab[0] - t * ac[0], ap[1] - s * ab[1] - t * ac[1], ap[2] - s * ab[2] - t * ac[2]};
        return dot3(q, q);
    };
    const float vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return at(d1 / (d1 - d3), 0);
    const float vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return at(0, d2 / (d2 - d6));
    const float va = d3 * d6 - d5 * d4;
    if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
        const float w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return at(1 - w, w);
    }
    const float sum = va + vb + vc;
    if (!(sum > 0)) return std::min({dot3(ap, ap), dot3(bp, bp), dot3(cp, cp)});
    return at(vb / sum, vc / sum);
}

// Triangles listed by the cells of a uniform grid, a cell about half a mean edge across (larger where the box would
// need more than 16 cells a triangle); each triangle in every cell its box, widened by half a cell, touches, so that a
// point within half a cell of a triangle finds it in its own cell.
class TriangleGrid {
public:
    explicit TriangleGrid(const std::vector<float>& corners) : corners_(corners), triangles_(corners.size() / 9), spheres_(4 * triangles_) {
        double edges = 0;
        for (size_t t = 0; t < triangles_; ++t) {
            const float* v = &corners[9 * t];
            for (int k = 0; k < 9; ++k) {
                lo_[k % 3] = std::min(lo_[k % 3], v[k]);
                hi_[k % 3] = std::max(hi_[k % 3], v[k]);
            }
            edges += std::sqrt(distance2(v, v + 3)) + std::sqrt(distance2(v + 3, v + 6)) + std::sqrt(distance2(v + 6, v));
            float* sphere = &spheres_[4 * t];
            for (int k = 0; k < 3; ++k) sphere[k] = (v[k] + v[3 + k] + v[6 + k]) / 3.0f;
            sphere[3] = std::sqrt(std::max({distance2(sphere, v), distance2(sphere, v + 3), distance2(sphere, v + 6)})) * 1.0001f;
        }
        const float extent = std::max({hi_[0] - lo_[0], hi_[1] - lo_[1], hi_[2] - lo_[2]});
        cell_ = std::max(0.5f * float(edges / (3.0 * double(std::max<size_t>(triangles_, 1)))), extent * 1e-6f);
        if (!(cell_ > 0)) cell_ = 1;  // every corner at one point
        for (;;) {  // at most about 16 cells per triangle
            size_t cells = 1;
            for (int k = 0; k < 3; ++k) {
                dims_[k] = std::max(1, int(std::ceil((hi_[k] - lo_[k]) / cell_)));
                cells *= size_t(dims_[k]);
            }
            if (cells <= 16 * triangles_ + 64) break;
            cell_ *= 1.5f;
        }
        inverseCell_ = 1.0f / cell_;
        const size_t cellCount = size_t(dims_[0]) * size_t(dims_[1]) * size_t(dims_[2]);
        // The triangles by cell: counted, then placed (a counting sort).
        start_.assign(cellCount + 1, 0);
        for (size_t t = 0; t < triangles_; ++t) for_cells(t, [&](size_t c) { ++start_[c + 1]; });
        for (size_t c = 0; c < cellCount; ++c) start_[c + 1] += start_[c];
        listed_.resize(start_[cellCount]);
        std::vector<uint32_t> next(start_.begin(), start_.end() - 1);
        for (size_t t = 0; t < triangles_; ++t) for_cells(t, [&](size_t c) { listed_[next[c]++] = uint32_t(t); });
    }

    // The squared distance from p to the nearest triangle its cell lists (of the two shells of cells around it where
    // its cell lists none, of every triangle where they list none either), and that triangle: never less than the
    // distance to the nearest triangle of all. `enough`: a squared distance within which any triangle will do (the
    // search stops at the first).
    std::pair<float, uint32_t> nearest(const float* p, float enough = -1) const {
        const int at[3] = {cell_of(p[0], 0), cell_of(p[1], 1), cell_of(p[2], 2)};
        // Triangle t's squared distance, or infinity where its sphere lies farther than `within` (skipped cheaply).
        auto within_reach = [&](uint32_t t, float within) {
            const float* sphere = &spheres_[4 * t];
            const float reach = within + sphere[3];
            if (distance2(p, sphere) > reach * reach) return INFINITY;
            const float* v = &corners_[9 * t];
            return distance2_to_triangle(p, v, v + 3, v + 6);
        };
        // First, where any triangle within `enough` will do, only those of the point's cell whose spheres reach that
        // near (most points find one: their full search is never made).
        if (enough > 0) {
            const size_t c = (size_t(at[2]) * dims_[1] + at[1]) * dims_[0] + at[0];
            for (uint32_t i = start_[c]; i < start_[c + 1]; ++i)
                if (const float d = within_reach(listed_[i], std::sqrt(enough)); d <= enough) return {d, listed_[i]};
        }
        std::pair<float, uint32_t> best{INFINITY, 0};
        float bestDistance = INFINITY;
        auto test = [&](uint32_t t) {
            if (const float d = within_reach(t, bestDistance); d < best.first) {
                best = {d, t};
                bestDistance = std::sqrt(d);
            }
        };
        for (int r = 0; r <= 2 && best.first == INFINITY; ++r)
            for (int z = std::max(at[2] - r, 0); z <= std::min(at[2] + r, dims_[2] - 1); ++z)
                for (int y = std::max(at[1] - r, 0); y <= std::min(at[1] + r, dims_[1] - 1); ++y)
                    for (int x = std::max(at[0] - r, 0); x <= std::min(at[0] + r, dims_[0] - 1); ++x) {
                        if (std::max({std::abs(x - at[0]), std::abs(y - at[1]), std::abs(z - at[2])}) != r) continue;
                        const size_t c = (size_t(z) * dims_[1] + y) * dims_[0] + x;
                        for (uint32_t i = start_[c]; i < start_[c + 1] && best.first > enough; ++i) test(listed_[i]);
                    }
        if (best.first == INFINITY)  // none listed near: every triangle
            for (uint32_t t = 0; t < triangles_; ++t) test(t);
        return best;
    }

private:
    int cell_of(float x, int k) const { return int(std::clamp(std::floor((x - lo_[k]) * inverseCell_), 0.0f, float(dims_[k] - 1))); }
    template <typename Visit>
    void for_cells(size_t t, Visit visit) const {
        const float* v = &corners_[9 * t];
        const float pad = 0.5f * cell_;
        int first[3], last[3];
        for (int k = 0; k < 3; ++k) {
            first[k] = cell_of(std::min({v[k], v[3 + k], v[6 + k]}) - pad, k);
            last[k] = cell_of(std::max({v[k], v[3 + k], v[6 + k]}) + pad, k);
        }
        for (int z = first[2]; z <= last[2]; ++z)
            for (int y = first[1]; y <= last[1]; ++y)
                for (int x = first[0]; x <= last[0]; ++x) visit((size_t(z) * dims_[1] + y) * dims_[0] + x);
    }

    const std::vector<float>& corners_;
    size_t triangles_;
    std::vector<float> spheres_;  // per triangle: centre and radius of a sphere holding it
    float lo_[3] = {INFINITY, INFINITY, INFINITY}, hi_[3] = {-INFINITY, -INFINITY, -INFINITY};
    float cell_ = 1, inverseCell_ = 1;
    int dims_[3] = {1, 1, 1};
    std::vector<uint32_t> start_, listed_;
};

}  // namespace

Deviation measure_deviation(const std::vector<float>& corners, const std::vector<uint32_t>& pieceOf, size_t pieces,
                            const std::vector<SourcePoint>& points, size_t keepPerPiece) {
    Deviation out;
    out.kept.resize(pieces);
    if (corners.empty()) return out;
    // The simplified surface from the source points: each point's distance to it, kept by the piece nearest.
    const TriangleGrid simplified(corners);
    std::vector<std::vector<SourcePoint>> near(pieces);
    for (const SourcePoint& point : points) {
        // A point within the largest distance so far does not change it: the first triangle that near will do (its
        // distance, an upper bound, ranks it among its piece's points).
        const auto [d2, nearest] = simplified.nearest(point.position, out.largest * out.largest);
        const float distance = std::sqrt(d2);
        out.largest = std::max(out.largest, distance);
        if (distance > 0) near[pieceOf[nearest]].push_back({{point.position[0], point.position[1], point.position[2]}, distance});
    }
    for (size_t piece = 0; piece < pieces; ++piece) {
        std::vector<SourcePoint>& list = near[piece];
        auto farther = [](const SourcePoint& a, const SourcePoint& b) { return a.distance > b.distance; };
        if (list.size() > keepPerPiece) {
            std::nth_element(list.begin(), list.begin() + keepPerPiece, list.end(), farther);
            list.resize(keepPerPiece);
        }
        out.kept[piece] = std::move(list);
    }
    return out;
}

float measure_stray(const GroupPositions& group, const std::vector<float>& positions, float floor) {
    if (!group.outputInInput) return 0;  // the simplifier only removes: not reached
    const std::vector<uint32_t>& input = group.corners;
    const std::vector<uint32_t>& output = group.outputCorners;
    auto point = [&](uint32_t slot) { return &positions[3 * size_t(group.vertexOf[slot])]; };
    Rows fan;  // per slot, the input triangles around it (their first corners)
    fan.build(group.slots(), [&](auto add) {
        for (size_t i = 0; i < input.size(); ++i) add(input[i], uint32_t(i / 3 * 3));
    });
    float strayed = floor;
    std::vector<uint32_t> slotStamp(group.slots(), 0), triangleStamp(input.size() / 3, 0), scratch;
    uint32_t stamp = 0;
    for (size_t t = 0; t < output.size(); t += 3)
        for (int e = 0; e < 3; ++e) {
            // Each edge once: from the triangle that runs it from its smaller slot (its twin runs it the other way; a
            // group border, run once, is locked and lies on the input anyway).
            const uint32_t a = output[t + e], b = output[t + (e + 1) % 3];
            if (!(a < b)) continue;
            const float* pa = point(a);
            const float* pb = point(b);
            const float midpoint[3] = {0.5f * (pa[0] + pb[0]), 0.5f * (pa[1] + pb[1]), 0.5f * (pa[2] + pb[2])};
            // Only a midpoint farther than the largest so far changes it: the first triangle within that will do, among
            // the input triangles around the edge's ends.
            const float enough = strayed * strayed;
            float best = INFINITY;
            auto test = [&](uint32_t u) {
                const float d = distance2_to_triangle(midpoint, point(input[u]), point(input[u + 1]), point(input[u + 2]));
                best = std::min(best, d);
                return d;
            };
            // An input edge: its midpoint lies on the input. Else the simplifier collapsed the input vertices between
            // the ends into them: a walk from one end over the input's vertices, each step to the neighbour nearest the
            // midpoint, reaches the one nearest it, and the input triangles around that one come first.
            const Rows& neighbours = group.neighbours;
            bool inputEdge = false;
            for (uint32_t k = neighbours.start[a]; k < neighbours.start[a + 1] && !inputEdge; ++k) inputEdge = neighbours.items[k] == b;
            if (inputEdge) continue;
            uint32_t nearest = a;
            for (float nearestDistance = distance2(point(a), midpoint);;) {
                const uint32_t from = nearest;
                for (uint32_t k = neighbours.start[from]; k < neighbours.start[from + 1]; ++k)
                    if (const float d = distance2(point(neighbours.items[k]), midpoint); d < nearestDistance) {
                        nearestDistance = d;
                        nearest = neighbours.items[k];
                    }
                if (nearest == from) break;
            }
            for (uint32_t k = fan.start[nearest]; k < fan.start[nearest + 1] && best > enough; ++k) test(fan.items[k]);
            if (best <= enough) continue;
            // Else the input between the ends: the edge's midpoint can lie a ring or two of input triangles from both.
            // Breadth first over the input from the ends, through the triangles within a ball around the midpoint
            // that holds both ends and every triangle nearer than those found so far.
            const float radius2 = std::max(best, distance2(midpoint, pa) * 1.0001f);
            ++stamp;
            std::vector<uint32_t>& queue = scratch;
            queue.assign({a, b});
            slotStamp[a] = slotStamp[b] = stamp;
            for (size_t head = 0; head < queue.size() && best > enough; ++head)
                for (uint32_t k = fan.start[queue[head]]; k < fan.start[queue[head] + 1] && best > enough; ++k) {
                    const uint32_t u = fan.items[k];
                    if (triangleStamp[u / 3] == stamp) continue;
                    triangleStamp[u / 3] = stamp;
                    if (test(u) > radius2) continue;
                    for (int j = 0; j < 3; ++j)
                        if (slotStamp[input[u + j]] != stamp) {
                            slotStamp[input[u + j]] = stamp;
                            queue.push_back(input[u + j]);
                        }
                }
            strayed = std::max(strayed, std::sqrt(best));
        }
    return strayed;
}

}  // namespace tessera
