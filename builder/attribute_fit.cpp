// The least-squares normals and vertex channel of a simplified group (attribute_fit.h). Each input position with one
// vertex in the group is a sample: the values it is drawn with, weighed by the area around it, at its nearest point on
// the output. That point is searched among the output triangles around the kept position nearest the sample over the
// group's edges, and where it lies on the rim of those, around the rim's corners too. The unknowns are the values of
// the output's interior vertices; a few Gauss-Seidel sweeps minimise the weighted squared difference between each
// sample's values and the output's interpolated at its point.
#include "attribute_fit.h"

#include "area.h"
#include "rows.h"

#include <algorithm>
#include <cmath>

namespace tessera {
namespace {

constexpr int kSweeps = 2;  // converged: 4 gave the same images to 0.01 dB
constexpr float kUnchanged = 0.99999f;          // cosine above which a fitted normal is the one drawn already
constexpr float kChannelUnchanged = 1.0f / 4096;  // a channel value this close to the one drawn is that one
constexpr int kNormal = 3, kChannel = 4, kMaxValues = kNormal + kChannel;  // values per vertex: normal, then channel
constexpr uint32_t kNone = 0xffffffffu;

// A triangle set up for closest-point queries: a corner, the edges from it, and their dot products.
struct Triangle {
    float a[3], ab[3], ac[3], abab, abac, acac;
    Triangle(const float* pa, const float* pb, const float* pc) {
        for (int k = 0; k < 3; ++k) {
            a[k] = pa[k];
            ab[k] = pb[k] - pa[k];
            ac[k] = pc[k] - pa[k];
        }
        abab = ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2];
        abac = ab[0] * ac[0] + ab[1] * ac[1] + ab[2] * ac[2];
        acac = ac[0] * ac[0] + ac[1] * ac[1] + ac[2] * ac[2];
    }
    // The point nearest p on the edges ab, ac and bc, as the weights of b and c (p relative to a: ap).
    void nearest_on_edges(const float ap[3], float& u, float& v) const {
        const float bc[3] = {ac[0] - ab[0], ac[1] - ab[1], ac[2] - ab[2]}, bp[3] = {ap[0] - ab[0], ap[1] - ab[1], ap[2] - ab[2]};
        auto along = [](const float* from, const float* edge) {  // the parameter of the point of `edge` nearest (from: p - its start)
            const float length2 = edge[0] * edge[0] + edge[1] * edge[1] + edge[2] * edge[2];
            return length2 > 0 ? std::clamp((from[0] * edge[0] + from[1] * edge[1] + from[2] * edge[2]) / length2, 0.0f, 1.0f) : 0.0f;
        };
        auto off = [](const float* from, const float* edge, float t) {
            const float q[3] = {from[0] - t * edge[0], from[1] - t * edge[1], from[2] - t * edge[2]};
            return q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
        };
        const float tb = along(ap, ab), tc = along(ap, ac), tbc = along(bp, bc);
        const float db = off(ap, ab, tb), dc = off(ap, ac, tc), dbc = off(bp, bc, tbc);
        if (db <= dc && db <= dbc) u = tb, v = 0;
        else if (dc <= dbc) u = 0, v = tc;
        else u = 1 - tbc, v = tbc;
    }
    // The point nearest p, as barycentric weights (of a, b, c); returns the squared distance. In float: the weights
    // only place a sample's values, and positions are floats already. Ericson, Real-Time Collision Detection, 5.1.5,
    // with the dot products of b - p and c - p derived from those of a - p.
    float closest_point(const float* p, float weights[3]) const {
        const float ap[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]};
        const float d1 = ab[0] * ap[0] + ab[1] * ap[1] + ab[2] * ap[2], d2 = ac[0] * ap[0] + ac[1] * ap[1] + ac[2] * ap[2];
        const float d3 = d1 - abab, d4 = d2 - abac, d5 = d1 - abac, d6 = d2 - acac;
        const float va = d3 * d6 - d5 * d4, vb = d5 * d2 - d1 * d6, vc = d1 * d4 - d3 * d2;
        float u = 0, v = 0;  // weights of b and c
        if (d1 <= 0 && d2 <= 0) {
        } else if (d3 >= 0 && d4 <= d3) {
            u = 1;
        } else if (d6 >= 0 && d5 <= d6) {
            v = 1;
        } else if (vc <= 0 && d1 >= 0 && d3 <= 0 && d1 - d3 > 0) {
            u = d1 / (d1 - d3);
        } else if (vb <= 0 && d2 >= 0 && d6 <= 0 && d2 - d6 > 0) {
            v = d2 / (d2 - d6);
        } else if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0 && (d4 - d3) + (d5 - d6) > 0) {
            v = (d4 - d3) / ((d4 - d3) + (d5 - d6));
            u = 1 - v;
        } else if (const float denominator = va + vb + vc; denominator > 0) {
            u = vb / denominator;
            v = vc / denominator;
        } else {  // no area (two corners at one place, or three in a line): the nearest point of its edges
            nearest_on_edges(ap, u, v);
        }
        weights[0] = 1 - u - v;
        weights[1] = u;
        weights[2] = v;
        float d = 0;
        for (int k = 0; k < 3; ++k) {
            const float q = ap[k] - u * ab[k] - v * ac[k];
            d += q * q;
        }
        return d;
    }
};

// fit_attributes for `valueCount` values per vertex (the normal, and the channel where there is one): a constant, so
// that a mesh without a channel neither stores nor sweeps its four unused values.
template <int valueCount>
std::vector<FittedAttributes> fit(const std::vector<uint32_t>& input, const uint32_t* output, size_t outputCount, const GroupPositions& group,
                                  const std::vector<float>& positions, const std::vector<unsigned char>& lock, const VertexTable& normals,
                                  const VertexTable* channel) {
    std::vector<FittedAttributes> fitted;
    // The values vertex v is drawn with, into `to`.
    auto drawn = [&](uint32_t v, double* to) {
        const float* n = normals(v);
        for (int k = 0; k < kNormal; ++k) to[k] = n[k];
        if constexpr (valueCount > kNormal) {
            const float* c = (*channel)(v);
            for (int k = 0; k < kChannel; ++k) to[kNormal + k] = c[k];
        }
    };
    if (outputCount == 0 || input.empty() || !group.outputInInput) return fitted;  // (the simplifier only removes)
    // Per slot, its first vertex's position and drawn values are copied once: the mesh's arrays are read at random.
    const std::vector<uint32_t>& corners = group.corners;
    const std::vector<uint32_t>& outputCorners = group.outputCorners;
    const std::vector<uint32_t>& vertexOf = group.vertexOf;
    const std::vector<char>& seam = group.seam;
    const size_t slots = group.slots();
    std::vector<double> weight(slots, 0.0);  // slot -> area of its triangles
    std::vector<std::array<float, 3>> point(slots);
    std::vector<std::array<double, valueCount>> valueDrawn(slots);
    for (size_t slot = 0; slot < slots; ++slot) {
        const size_t v = vertexOf[slot];
        point[slot] = {positions[3 * v], positions[3 * v + 1], positions[3 * v + 2]};
        drawn(uint32_t(v), valueDrawn[slot].data());
    }
    for (size_t i = 0; i < input.size(); i += 3) {
        const double area = triangle_area(point[corners[i]].data(), point[corners[i + 1]].data(), point[corners[i + 2]].data());
        for (int k = 0; k < 3; ++k) weight[corners[i + k]] += area;
    }
    // Each position's nearest kept position over the input's edges, and the output triangles around it.
    const Rows& fan = group.outputFan;
    const std::vector<uint32_t>& nearestKept = group.nearestKept;

    // The unknowns: output vertices alone at their position and not locked.
    std::vector<uint32_t> unknownOf(slots, kNone), unknownVertex, unknownSlot;
    for (size_t i = 0; i < outputCount; ++i) {
        const uint32_t slot = outputCorners[i], v = output[i];
        if (seam[slot] || vertexOf[slot] != v || lock[v] != 0 || unknownOf[slot] != kNone) continue;
        unknownOf[slot] = uint32_t(unknownVertex.size());
        unknownVertex.push_back(v);
        unknownSlot.push_back(slot);
    }
    if (unknownVertex.empty()) return fitted;

    // Samples: weight, barycentric weights on their output triangle, and the residual (its normal minus the
    // interpolated one).
    struct Sample {
        uint32_t triangle;
        double weight, barycentric[3], residual[valueCount];
    };
    std::vector<Triangle> triangles;
    triangles.reserve(outputCount / 3);
    for (size_t i = 0; i < outputCount; i += 3)
        triangles.emplace_back(point[outputCorners[i]].data(), point[outputCorners[i + 1]].data(), point[outputCorners[i + 2]].data());
    std::vector<Sample> samples;
    samples.reserve(slots);
    for (uint32_t slot = 0; slot < slots; ++slot) {
        if (seam[slot] || nearestKept[slot] == kNone || !(weight[slot] > 0)) continue;
        const uint32_t kept = nearestKept[slot];
        Sample best{kNone, weight[slot], {}, {}};
        if (kept == slot) {  // a kept position is its own nearest point: a corner of any triangle around it
            if (fan.start[slot] == fan.start[slot + 1]) continue;
            best.triangle = fan.items[fan.start[slot]];
            for (int j = 0; j < 3; ++j) best.barycentric[j] = outputCorners[best.triangle + j] == slot ? 1.0 : 0.0;
        } else {
            // The output triangles around the kept position nearest over the edges; where the nearest point lies on
            // that fan's rim, also those around the rim's corners (the point may lie nearer a triangle beyond it).
            const float* p = point[slot].data();
            float bestDistance = INFINITY;
            auto search_fan = [&](uint32_t centre) {
                for (uint32_t k = fan.start[centre]; k < fan.start[centre + 1]; ++k) {
                    const uint32_t t = fan.items[k];
                    float b[3];
                    const float d = triangles[t / 3].closest_point(p, b);
                    if (d < bestDistance) {
                        bestDistance = d;
                        best.triangle = t;
                        std::copy_n(b, 3, best.barycentric);
                    }
                }
            };
            search_fan(kept);
            if (best.triangle == kNone) continue;
            const uint32_t first = best.triangle;
            int centre = 0;
            while (centre < 2 && outputCorners[first + centre] != kept) ++centre;
            if (bestDistance > 0 && best.barycentric[centre] == 0)
                for (int j = 0; j < 3; ++j)
                    if (j != centre) search_fan(outputCorners[first + j]);
        }
        if (best.triangle == kNone) continue;
        for (int k = 0; k < valueCount; ++k) best.residual[k] = valueDrawn[slot][k];
        for (int j = 0; j < 3; ++j) {
            const uint32_t corner = output[best.triangle + j], cornerSlot = outputCorners[best.triangle + j];
            double own[valueCount];
            const double* values = valueDrawn[cornerSlot].data();
            if (vertexOf[cornerSlot] != corner) {  // another wedge at the position: its own values
                drawn(corner, own);
                values = own;
            }
            for (int k = 0; k < valueCount; ++k) best.residual[k] -= best.barycentric[j] * values[k];
        }
        samples.push_back(best);
    }
    // Which samples each unknown's normal reaches, and with which corner.
    Rows reach;
    reach.build(unknownVertex.size(), [&](auto add) {
        for (uint32_t s = 0; s < samples.size(); ++s)
            for (int j = 0; j < 3; ++j) {
                const uint32_t unknown = unknownOf[outputCorners[samples[s].triangle + j]];
                if (unknown != kNone && output[samples[s].triangle + j] == unknownVertex[unknown]) add(unknown, s * 3 + uint32_t(j));
            }
    });
    std::vector<std::array<double, valueCount>> value(unknownVertex.size());
    for (size_t u = 0; u < unknownVertex.size(); ++u) value[u] = valueDrawn[unknownSlot[u]];
    for (int sweep = 0; sweep < kSweeps; ++sweep)
        for (size_t u = 0; u < unknownVertex.size(); ++u) {
            double step[valueCount] = {}, denominator = 0;
            for (uint32_t k = reach.start[u]; k < reach.start[u + 1]; ++k) {
                const Sample& s = samples[reach.items[k] / 3];
                const double b = s.barycentric[reach.items[k] % 3];
                for (int c = 0; c < valueCount; ++c) step[c] += s.weight * b * s.residual[c];
                denominator += s.weight * b * b;
            }
            if (!(denominator > 0)) continue;
            for (int c = 0; c < valueCount; ++c) {
                step[c] /= denominator;
                value[u][c] += step[c];
            }
            for (uint32_t k = reach.start[u]; k < reach.start[u + 1]; ++k) {
                Sample& s = samples[reach.items[k] / 3];
                const double b = s.barycentric[reach.items[k] % 3];
                for (int c = 0; c < valueCount; ++c) s.residual[c] -= b * step[c];
            }
        }
    // The channel stays within the range of the group's input (least squares may overshoot it: no negative colour).
    std::array<double, valueCount> lowest, highest;
    lowest.fill(INFINITY);
    highest.fill(-INFINITY);
    for (const auto& v : valueDrawn)
        for (int k = kNormal; k < valueCount; ++k) {
            lowest[k] = std::min(lowest[k], v[k]);
            highest[k] = std::max(highest[k], v[k]);
        }
    for (size_t u = 0; u < unknownVertex.size(); ++u) {
        const std::array<double, valueCount>& now = valueDrawn[unknownSlot[u]];
        FittedAttributes f{unknownVertex[u], {float(now[0]), float(now[1]), float(now[2])}, {}};
        bool changed = false;
        const double length = std::sqrt(value[u][0] * value[u][0] + value[u][1] * value[u][1] + value[u][2] * value[u][2]);
        if (length > 1e-6) {  // else the samples cancel out: keep the normal drawn
            for (int k = 0; k < kNormal; ++k) f.normal[k] = float(value[u][k] / length);
            changed = f.normal[0] * now[0] + f.normal[1] * now[1] + f.normal[2] * now[2] <= kUnchanged;
        }
        for (int k = 0; k < valueCount - kNormal; ++k) {
            f.channel[k] = float(std::clamp(value[u][kNormal + k], lowest[kNormal + k], highest[kNormal + k]));
            changed |= std::abs(f.channel[k] - now[kNormal + k]) > kChannelUnchanged;
        }
        if (changed) fitted.push_back(f);
    }
    return fitted;
}

}  // namespace

std::vector<FittedAttributes> fit_attributes(const std::vector<uint32_t>& input, const uint32_t* output, size_t outputCount,
                                             const GroupPositions& group, const std::vector<float>& positions,
                                             const std::vector<unsigned char>& lock, const VertexTable& normals, const VertexTable* channel) {
    return channel ? fit<kMaxValues>(input, output, outputCount, group, positions, lock, normals, channel)
                   : fit<kNormal>(input, output, outputCount, group, positions, lock, normals, channel);
}

}  // namespace tessera
