// How far a simplified group strays from the source surface, measured at source points (deviation.h).
#include "deviation.h"

#include "rows.h"

#include <algorithm>
#include <cmath>
#include <initializer_list>

namespace tessera {
namespace {

constexpr int kWalkSteps = 4;  // steps of a source point's walk over the simplified triangles (measure_deviation)

float dot3(const float* a, const float* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

float distance2(const float* a, const float* b) {
    const float d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return dot3(d, d);
}

// Squared distance from p to the segment ab (a point where a and b coincide).
float distance2_to_segment(const float* p, const float* a, const float* b) {
    const float ab[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, ap[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]};
    const float length2 = dot3(ab, ab);
    const float t = length2 > 0 ? std::clamp(dot3(ap, ab) / length2, 0.0f, 1.0f) : 0.0f;
    const float q[3] = {ap[0] - t * ab[0], ap[1] - t * ab[1], ap[2] - t * ab[2]};
    return dot3(q, q);
}

// Squared distance from p to the triangle abc: to the closest point, found by which of the triangle's Voronoi regions
// (a corner, an edge, the face) holds p (Ericson, "Real-Time Collision Detection", 5.1.5). A triangle of no area (two
// corners at one place, as simplifying along seams leaves, or three in a line) is the segments between its corners:
// the regions' divisions are 0 / 0 there (a NaN, which no comparison takes: a point with only such triangles near it
// measured an infinite distance).
float distance2_to_triangle(const float* p, const float* a, const float* b, const float* c) {
    const float ab[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, ac[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    const float ap[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]}, bp[3] = {p[0] - b[0], p[1] - b[1], p[2] - b[2]};
    const float cp[3] = {p[0] - c[0], p[1] - c[1], p[2] - c[2]};
    auto segments = [&] { return std::min({distance2_to_segment(p, a, b), distance2_to_segment(p, b, c), distance2_to_segment(p, c, a)}); };
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
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return d1 - d3 > 0 ? at(d1 / (d1 - d3), 0) : segments();
    const float vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return d2 - d6 > 0 ? at(0, d2 / (d2 - d6)) : segments();
    const float va = d3 * d6 - d5 * d4;
    if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
        if (!((d4 - d3) + (d5 - d6) > 0)) return segments();
        const float w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return at(1 - w, w);
    }
    const float sum = va + vb + vc;
    if (!(sum > 0)) return segments();
    return at(vb / sum, vc / sum);
}

// Breadth first over a group's triangles (`corners`: 3 slots per triangle; `fan`: per slot, the first corners of the
// triangles around it) from the slots `start`, through the triangles within a ball: `test(firstCorner)` measures a
// triangle (its squared distance from the ball's centre) and the search goes on past it where that is within
// `radius2`, until `settled()`. Each triangle and slot once per search (marked with a new stamp in `BallSearch`).
struct BallSearch {
    std::vector<uint32_t> slotStamp, triangleStamp, queue;
    uint32_t stamp = 0;
    BallSearch(size_t slots, size_t triangles) : slotStamp(slots, 0), triangleStamp(triangles, 0) {}

    template <typename Test, typename Settled>
    void run(const Rows& fan, const std::vector<uint32_t>& corners, std::initializer_list<uint32_t> start, float radius2, Test test,
             Settled settled) {
        ++stamp;
        queue.assign(start);
        for (uint32_t slot : start) slotStamp[slot] = stamp;
        for (size_t head = 0; head < queue.size() && !settled(); ++head)
            for (uint32_t k = fan.start[queue[head]]; k < fan.start[queue[head] + 1] && !settled(); ++k) {
                const uint32_t first = fan.items[k];
                if (triangleStamp[first / 3] == stamp) continue;
                triangleStamp[first / 3] = stamp;
                if (test(first) > radius2) continue;
                for (int j = 0; j < 3; ++j)
                    if (slotStamp[corners[first + j]] != stamp) {
                        slotStamp[corners[first + j]] = stamp;
                        queue.push_back(corners[first + j]);
                    }
            }
    }
};

}  // namespace

Deviation measure_deviation(const GroupPositions& group, const std::vector<float>& corners, const uint32_t* outputVertices,
                            const std::vector<uint32_t>& pieceOf, size_t pieces, const std::vector<SourcePoint>& points,
                            const std::vector<uint32_t>& positionId, size_t keepPerPiece) {
    Deviation out;
    out.kept.resize(pieces);
    const size_t triangles = corners.size() / 9;
    if (triangles == 0) return out;
    const Rows& fan = group.outputFan;
    BallSearch ball(group.slots(), triangles);
    std::vector<std::vector<SourcePoint>> near(pieces);
    // The walk meets a triangle once per corner it shares with the nearest so far: each is measured once per point.
    std::vector<uint32_t> walked(triangles, 0);
    uint32_t pointStamp = 0;
    for (const SourcePoint& point : points) {
        const float* p = point.position;
        ++pointStamp;
        // A point within the largest distance so far does not change it: the first triangle that near will do (its
        // distance, an upper bound, ranks it among its piece's points).
        const float enough = out.largest * out.largest;
        float best = INFINITY;
        uint32_t nearest = 0;
        auto test = [&](uint32_t t) {
            const float* v = &corners[9 * size_t(t)];
            const float d = distance2_to_triangle(p, v, v + 3, v + 6);
            if (d < best) {
                best = d;
                nearest = t;
            }
            return d;
        };
        auto walk_test = [&](uint32_t t) {
            if (walked[t] == pointStamp) return;
            walked[t] = pointStamp;
            test(t);
        };
        // The simplified triangles around the kept position nearest the point's anchor over the input's edges, then
        // a walk: the triangles around the nearest one's corners, while that finds a nearer one.
        const uint32_t anchor = group.outputInInput && point.anchor < positionId.size() ? group.slot_of(positionId[point.anchor]) : GroupPositions::kNone;
        const uint32_t kept = anchor == GroupPositions::kNone ? GroupPositions::kNone : group.nearestKept[anchor];
        if (kept == GroupPositions::kNone) {  // not on the group's surface: every triangle
            for (uint32_t t = 0; t < triangles && best > enough; ++t) test(t);
        } else {
            for (uint32_t k = fan.start[kept]; k < fan.start[kept + 1] && best > enough; ++k) walk_test(fan.items[k] / 3);
            for (int step = 0; step < kWalkSteps && best > enough; ++step) {
                const uint32_t from = nearest;
                for (int j = 0; j < 3; ++j) {
                    const uint32_t corner = group.outputCorners[3 * from + j];
                    for (uint32_t k = fan.start[corner]; k < fan.start[corner + 1] && best > enough; ++k) walk_test(fan.items[k] / 3);
                }
                if (nearest == from) break;
            }
            // Where it would raise the largest: the walk may have stopped at a triangle that is only nearest around it.
            // Breadth first over the simplified triangles from the kept position, through those within a ball around the
            // point as far again past that position as the nearest so far (so that the surface between them stays in
            // it where the point lies far off the surface, above a fold, say).
            if (best > enough && fan.start[kept] < fan.start[kept + 1]) {
                const uint32_t around = fan.items[fan.start[kept]];  // a triangle at the kept position: its corner there
                int at = 0;
                while (at < 2 && group.outputCorners[around + at] != kept) ++at;
                const float radius = std::sqrt(distance2(p, &corners[3 * (size_t(around) + at)])) + std::sqrt(best);
                ball.run(fan, group.outputCorners, {kept}, radius * radius * 1.0001f, [&](uint32_t first) { return test(first / 3); },
                         [&] { return best <= enough; });
            }
        }
        const float distance = std::sqrt(best);
        out.largest = std::max(out.largest, distance);
        if (!(distance > 0)) continue;
        // Carried up by the nearest triangle's piece, anchored at that triangle's corner nearest the point.
        const float* v = &corners[9 * size_t(nearest)];
        const int corner = distance2(p, v) <= std::min(distance2(p, v + 3), distance2(p, v + 6)) ? 0 : distance2(p, v + 3) <= distance2(p, v + 6) ? 1 : 2;
        near[pieceOf[nearest]].push_back({{p[0], p[1], p[2]}, distance, outputVertices[3 * size_t(nearest) + corner]});
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
    BallSearch ball(group.slots(), input.size() / 3);
    for (size_t t = 0; t < output.size(); t += 3)
        for (int e = 0; e < 3; ++e) {
            // Each edge once: from the triangle that runs it from its smaller slot (its twin runs it the other way; a
            // group border, run once, is locked and lies on the input anyway).
            const uint32_t a = output[t + e], b = output[t + (e + 1) % 3];
            if (!(a < b)) continue;
            const float* pa = point(a);
            const float* pb = point(b);
            const float midpoint[3] = {0.5f * (pa[0] + pb[0]), 0.5f * (pa[1] + pb[1]), 0.5f * (pa[2] + pb[2])};
            // Only a midpoint farther than the largest so far (at least the floor) changes it: the first triangle
            // within that will do.
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
            // An input vertex within the largest so far settles it as well: every triangle around it is as near.
            uint32_t nearest = a;
            float nearestDistance = distance2(point(a), midpoint);
            while (nearestDistance > enough) {
                const uint32_t from = nearest;
                for (uint32_t k = neighbours.start[from]; k < neighbours.start[from + 1]; ++k)
                    if (const float d = distance2(point(neighbours.items[k]), midpoint); d < nearestDistance) {
                        nearestDistance = d;
                        nearest = neighbours.items[k];
                    }
                if (nearest == from) break;
            }
            if (nearestDistance <= enough) continue;
            for (uint32_t k = fan.start[nearest]; k < fan.start[nearest + 1] && best > enough; ++k) test(fan.items[k]);
            if (best <= enough) continue;
            // Else the input between the ends: the edge's midpoint can lie a ring or two of input triangles from both.
            // Breadth first over the input from the ends, through the triangles within a ball around the midpoint
            // that holds both ends and every triangle nearer than those found so far.
            const float radius2 = std::max(best, distance2(midpoint, pa) * 1.0001f);
            ball.run(fan, input, {a, b}, radius2, test, [&] { return best <= enough; });
            strayed = std::max(strayed, std::sqrt(best));
        }
    return strayed;
}

}  // namespace tessera
