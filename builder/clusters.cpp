// Triangles into clusters: meshoptimizer's meshlet growth, reproduced exactly and cheaper (see clusters.h).
// The float expressions below are written as meshoptimizer 0.22 evaluates them (clusterizer.cpp), because equal scores
// and their tie order decide which triangle is taken: a different rounding would give different clusters. (Both are
// compiled for baseline x86-64, without fused multiply-adds; a build with -march allowing them could contract the two
// differently: the clusters would stay valid but differ from meshoptimizer's, which ClusterBuilder's tests would show.)
#include "clusters.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <memory>

namespace tessera {
namespace {

constexpr uint8_t kNotInCluster = 0xff;
constexpr uint32_t kNone = UINT32_MAX;

// meshoptimizer's distance between a centroid and a point (not squared: its scores compare the square roots).
inline float distance_between(const float* centroid, const float* point) {
    const float dx = centroid[0] - point[0], dy = centroid[1] - point[1], dz = centroid[2] - point[2];
    return std::sqrt(dx * dx + dy * dy + dz * dz);
}

// The nearest triangle offered so far, and whether another was exactly as near (meshoptimizer's order then decides).
struct Nearest {
    uint32_t triangle = kNone;
    float distance = FLT_MAX;
    bool tied = false;
    void offer(uint32_t t, float d) {
        if (d < distance) {
            triangle = t;
            distance = d;
            tied = false;
        } else if (d == distance) {
            tied = true;
        }
    }
};

// The triangle nearest to a point among those not yet clustered: a uniform grid over the centroids with cells about
// eight triangles of the surface wide, searched ring by ring outwards. Clustered triangles are dropped from their cell
// as searches meet them. `tied` tells that another triangle was exactly as near.
class NearestTriangle {
public:
    NearestTriangle(const std::vector<float>& centroids, const float* lo, const float* hi, double area) : centroids_(centroids) {
        const size_t triangles = centroids.size() / 3;
        const double extent = std::max({double(hi[0] - lo[0]), double(hi[1] - lo[1]), double(hi[2] - lo[2])});
        double cell = std::sqrt(8.0 * area / double(triangles));
        if (!(cell > 0)) cell = extent > 0 ? extent : 1.0;  // degenerate triangles only
        for (;;) {  // at most one cell per two triangles (a closed surface leaves most cells of its box empty)
            size_t cells = 1;
            for (int k = 0; k < 3; ++k) {
                size_[k] = std::min<size_t>(size_t(double(hi[k] - lo[k]) / cell) + 1, 1u << 20);
                cells *= size_[k];
            }
            if (cells <= triangles / 2 + 64) break;
            cell *= 1.5;
        }
        for (int k = 0; k < 3; ++k) lo_[k] = lo[k];
        cell_ = float(cell);
        std::vector<uint32_t> cellOf(triangles);
        first_.assign(size_[0] * size_[1] * size_[2] + 1, 0);
        for (size_t t = 0; t < triangles; ++t) {
            size_t c[3];
            for (int k = 0; k < 3; ++k) c[k] = coordinate(centroids[3 * t + k], k);
            cellOf[t] = uint32_t((c[2] * size_[1] + c[1]) * size_[0] + c[0]);
            ++first_[cellOf[t] + 1];
        }
        for (size_t c = 0; c + 1 < first_.size(); ++c) first_[c + 1] += first_[c];
        count_.assign(first_.size() - 1, 0);
        entries_.resize(triangles);
        for (size_t t = 0; t < triangles; ++t) entries_[first_[cellOf[t]] + count_[cellOf[t]]++] = uint32_t(t);
    }

    uint32_t find(const float* point, const std::vector<uint8_t>& taken, bool& tied) {
        size_t home[3];
        for (int k = 0; k < 3; ++k) home[k] = coordinate(point[k], k);
        const size_t rings = std::max({size_[0], size_[1], size_[2]});
        Nearest nearest;
        for (size_t r = 0; r <= rings; ++r) {
            // A centroid in ring r (or farther) lies at least r - 1 cells from the point along some axis (the point is
            // anywhere in its home cell, or beyond the grid's box where that cell was clamped); less a little for the
            // rounding of the cell numbers. Stop only when strictly farther, so that an equal distance is seen.
            const float bound = (float(r) - 1.01f) * cell_;
            if (nearest.triangle != kNone && bound > nearest.distance) break;
            const int64_t lo[3] = {int64_t(home[0]) - int64_t(r), int64_t(home[1]) - int64_t(r), int64_t(home[2]) - int64_t(r)};
            const int64_t hi[3] = {int64_t(home[0]) + int64_t(r), int64_t(home[1]) + int64_t(r), int64_t(home[2]) + int64_t(r)};
            for (int64_t z = std::max<int64_t>(lo[2], 0); z <= std::min<int64_t>(hi[2], int64_t(size_[2]) - 1); ++z)
                for (int64_t y = std::max<int64_t>(lo[1], 0); y <= std::min<int64_t>(hi[1], int64_t(size_[1]) - 1); ++y) {
                    const bool face = z == lo[2] || z == hi[2] || y == lo[1] || y == hi[1];
                    const int64_t step = face || r == 0 ? 1 : 2 * int64_t(r);  // inside the ring's faces only its two x ends
                    for (int64_t x = lo[0]; x <= hi[0]; x += step) {
                        if (x < 0 || x >= int64_t(size_[0])) continue;
                        const size_t c = size_t((z * int64_t(size_[1]) + y) * int64_t(size_[0]) + x);
                        uint32_t* entry = &entries_[first_[c]];
                        for (uint32_t i = 0; i < count_[c];) {
                            const uint32_t t = entry[i];
                            if (taken[t]) {
                                entry[i] = entry[--count_[c]];
                                continue;
                            }
                            ++i;
                            nearest.offer(t, distance_between(&centroids_[3 * size_t(t)], point));
                        }
                    }
                }
        }
        tied = nearest.tied;
        return nearest.triangle;
    }

private:
    size_t coordinate(float value, int axis) const {
        const float c = std::floor((value - lo_[axis]) / cell_);
        return size_t(std::clamp(c, 0.0f, float(size_[axis] - 1)));
    }

    const std::vector<float>& centroids_;
    float lo_[3] = {0, 0, 0}, cell_ = 1;
    size_t size_[3] = {1, 1, 1};
    std::vector<uint32_t> first_, count_, entries_;  // per cell: its entries' start, how many are left; triangle numbers
};

// meshoptimizer's k-d tree over the centroids, built the same way (split at the running mean of the axis of largest
// running variance, leaves of at most 8, points partitioned in the same order) so that its search meets equally near
// triangles in the same order. Built only when the grid finds two triangles equally near: then it says which one
// meshoptimizer takes.
class KdTree {
public:
    explicit KdTree(const std::vector<float>& centroids) : centroids_(centroids), order_(centroids.size() / 3) {
        for (size_t i = 0; i < order_.size(); ++i) order_[i] = uint32_t(i);
        nodes_.reserve(order_.size() / 2 + 1);
        build(0, order_.size());
    }

    uint32_t find(const float* point, const std::vector<uint8_t>& taken) const {
        uint32_t best = kNone;
        float bestDistance = FLT_MAX;
        search(0, point, taken, best, bestDistance);
        return best;
    }

private:
    static constexpr size_t kLeaf = 8;
    struct Node {
        uint32_t begin = 0, end = 0;  // a leaf's points in order_
        uint32_t left = 0, right = 0;  // a branch's children
        float split = 0;
        int axis = -1;  // -1: a leaf
    };

    uint32_t build(size_t begin, size_t end) {
        const uint32_t id = uint32_t(nodes_.size());
        nodes_.push_back({uint32_t(begin), uint32_t(end)});
        const size_t count = end - begin;
        if (count <= kLeaf) return id;
        float mean[3] = {0, 0, 0}, spread[3] = {0, 0, 0}, seen = 1, weight = 1;
        for (size_t i = begin; i < end; ++i, seen += 1.f, weight = 1.f / seen) {
            const float* p = &centroids_[3 * size_t(order_[i])];
            for (int k = 0; k < 3; ++k) {
                const float delta = p[k] - mean[k];
                mean[k] += delta * weight;
                spread[k] += delta * (p[k] - mean[k]);
            }
        }
        const int axis = spread[0] >= spread[1] && spread[0] >= spread[2] ? 0 : spread[1] >= spread[2] ? 1 : 2;
        const float split = mean[axis];
        size_t below = begin;  // order_[begin, below) lie below the split
        for (size_t i = begin; i < end; ++i) {
            const float value = centroids_[3 * size_t(order_[i]) + axis];
            std::swap(order_[below], order_[i]);
            below += value < split;
        }
        const size_t middle = below - begin;
        if (middle <= kLeaf / 2 || middle >= count - kLeaf / 2) return id;  // a lopsided split: one leaf
        const uint32_t left = build(begin, below), right = build(below, end);
        Node& node = nodes_[id];
        node.axis = axis;
        node.split = split;
        node.left = left;
        node.right = right;
        return id;
    }

    void search(uint32_t id, const float* point, const std::vector<uint8_t>& taken, uint32_t& best, float& bestDistance) const {
        const Node& node = nodes_[id];
        if (node.axis < 0) {
            for (uint32_t i = node.begin; i < node.end; ++i) {
                const uint32_t t = order_[i];
                if (taken[t]) continue;
                const float d = distance_between(&centroids_[3 * size_t(t)], point);
                if (d < bestDistance) {
                    best = t;
                    bestDistance = d;
                }
            }
            return;
        }
        const float delta = point[node.axis] - node.split;
        search(delta <= 0 ? node.left : node.right, point, taken, best, bestDistance);
        if (std::fabs(delta) <= bestDistance) search(delta <= 0 ? node.right : node.left, point, taken, best, bestDistance);
    }

    const std::vector<float>& centroids_;
    std::vector<uint32_t> order_;
    std::vector<Node> nodes_;
};

// Per vertex, side by side (the hot loops read all three): where its triangles are listed, how many of them are not
// yet clustered, and its place in the open cluster.
struct VertexState {
    uint32_t first = 0;
    uint32_t live : 24 = 0;
    uint32_t slot : 8 = kNotInCluster;
};

}  // namespace

bool build_clusters(const uint32_t* indices, size_t indexCount, const float* positions, size_t vertexCount, size_t maxVertices, size_t maxTriangles,
                    std::vector<std::vector<uint32_t>>& clusters, std::vector<uint32_t>* clusterOfTriangle) {
    clusters.clear();
    const size_t triangles = indexCount / 3;
    if (clusterOfTriangle) clusterOfTriangle->assign(triangles, 0);
    if (triangles == 0) return true;
    if (triangles >= (1u << 24) || indexCount >= UINT32_MAX) return false;  // counts must fit VertexState (clusters.h)
    maxVertices = std::min<size_t>(maxVertices, kNotInCluster);  // a vertex's place in its cluster must fit below kNotInCluster

    // The triangles around each vertex, listed in triangle order as meshoptimizer lists them; the first `live` of
    // vertex v's list are those not yet clustered (a taken triangle is swapped with the last live one, as there).
    std::vector<VertexState> vertex(vertexCount);
    std::vector<uint32_t> around(indexCount);
    for (size_t i = 0; i < indexCount; ++i) ++vertex[indices[i]].live;
    uint32_t offset = 0;
    for (size_t v = 0; v < vertexCount; ++v) {
        vertex[v].first = offset;
        offset += vertex[v].live;
    }
    {
        std::vector<uint32_t> fill(vertexCount);
        for (size_t v = 0; v < vertexCount; ++v) fill[v] = vertex[v].first;
        for (size_t t = 0; t < triangles; ++t)
            for (int k = 0; k < 3; ++k) around[fill[indices[3 * t + k]]++] = uint32_t(t);
    }

    // Centroids and the expected cluster radius, in meshoptimizer's float arithmetic.
    std::vector<float> centroids(3 * triangles);
    float lo[3] = {FLT_MAX, FLT_MAX, FLT_MAX}, hi[3] = {-FLT_MAX, -FLT_MAX, -FLT_MAX};
    float meshArea = 0;
    for (size_t t = 0; t < triangles; ++t) {
        const float *p0 = &positions[3 * size_t(indices[3 * t])], *p1 = &positions[3 * size_t(indices[3 * t + 1])], *p2 = &positions[3 * size_t(indices[3 * t + 2])];
        const float p10[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]}, p20[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        const float nx = p10[1] * p20[2] - p10[2] * p20[1], ny = p10[2] * p20[0] - p10[0] * p20[2], nz = p10[0] * p20[1] - p10[1] * p20[0];
        meshArea += std::sqrt(nx * nx + ny * ny + nz * nz);
        for (int k = 0; k < 3; ++k) {
            const float c = (p0[k] + p1[k] + p2[k]) / 3.f;
            centroids[3 * t + k] = c;
            lo[k] = std::min(lo[k], c);
            hi[k] = std::max(hi[k], c);
        }
    }
    const float triangleArea = meshArea / float(triangles) * 0.5f;
    const float expectedRadius = std::sqrt(triangleArea * float(maxTriangles)) * 0.5f;
    if (!(expectedRadius > 0) || !std::isfinite(expectedRadius) || !std::isfinite(meshArea)) return false;  // degenerate: meshoptimizer decides

    std::vector<uint8_t> taken(triangles, 0);
    std::vector<uint32_t> clusterVertices, corners;
    clusterVertices.reserve(maxVertices);
    corners.reserve(3 * maxTriangles);
    float sum[3] = {0, 0, 0};
    size_t clusterTriangles = 0;
    std::unique_ptr<NearestTriangle> nearest;  // built on first need: connected surfaces seldom need it
    std::unique_ptr<KdTree> tree;              // built on the first tie

    // meshoptimizer's priorities: a triangle that adds no vertex, then one that leaves a vertex with no other triangle
    // left, then (by how many vertices it adds) one that leaves two vertices with one, then the rest.
    auto priority_of = [&](uint32_t t) -> uint32_t {
        const uint32_t a = indices[3 * size_t(t)], b = indices[3 * size_t(t) + 1], c = indices[3 * size_t(t) + 2];
        const uint32_t extra = (vertex[a].slot == kNotInCluster) + (vertex[b].slot == kNotInCluster) + (vertex[c].slot == kNotInCluster);
        if (extra == 0) return 0;
        if (vertex[a].live == 1 || vertex[b].live == 1 || vertex[c].live == 1) return 1;
        if ((vertex[a].live == 2) + (vertex[b].live == 2) + (vertex[c].live == 2) >= 2) return 1 + extra;
        return 2 + extra;
    };
    auto extra_of = [&](uint32_t t) {
        return size_t(vertex[indices[3 * size_t(t)]].slot == kNotInCluster) + (vertex[indices[3 * size_t(t) + 1]].slot == kNotInCluster) +
               (vertex[indices[3 * size_t(t) + 2]].slot == kNotInCluster);
    };

    // The triangles around the open cluster (those meshoptimizer scans), kept by priority (a candidate shares a
    // vertex with the cluster, so it adds at most two: priorities 0-4), each with its centroid side by side: only the
    // best non-empty priority is scanned. A triangle's priority depends only on its corners, so it changes only when
    // a triangle sharing a corner is taken, and is moved then.
    // (Its arrays only grow, and `size` says how much of them is in use: one capacity check per candidate listed, where
    // four vectors' push_back made four.)
    struct Bucket {
        uint32_t size = 0;
        std::vector<uint32_t> triangle;
        std::vector<float> x, y, z;
        void push(uint32_t t, const float* centroid) {
            if (size == triangle.size()) {
                const size_t capacity = std::max<size_t>(64, 2 * triangle.size());
                triangle.resize(capacity);
                x.resize(capacity);
                y.resize(capacity);
                z.resize(capacity);
            }
            triangle[size] = t;
            x[size] = centroid[0];
            y[size] = centroid[1];
            z[size] = centroid[2];
            ++size;
        }
    };
    constexpr uint32_t kPriorities = 5;
    Bucket buckets[kPriorities];
    std::vector<uint32_t> listed(triangles, kNone);  // a candidate's place: index in its bucket * 8 + its priority
    std::vector<float> scores;
    size_t candidates = 0;
    auto list = [&](uint32_t t, uint32_t priority) {
        Bucket& b = buckets[priority];
        listed[t] = b.size << 3 | priority;
        b.push(t, &centroids[3 * size_t(t)]);
        ++candidates;
    };
    auto unlist = [&](uint32_t t) {
        const uint32_t at = listed[t] >> 3;
        Bucket& b = buckets[listed[t] & 7];
        const uint32_t last = --b.size, moved = b.triangle[last];
        b.triangle[at] = moved;
        b.x[at] = b.x[last];
        b.y[at] = b.y[last];
        b.z[at] = b.z[last];
        listed[moved] = at << 3 | (listed[t] & 7);
        listed[t] = kNone;
        --candidates;
    };
    auto best_bucket = [&]() -> const Bucket& {
        uint32_t p = 0;
        while (buckets[p].size == 0) ++p;
        return buckets[p];
    };
    // Where meshoptimizer's scan (the cluster's vertices in order, each one's live triangles in list order) first
    // meets triangle t: among equal scores the first met wins.
    auto scan_position = [&](uint32_t t) {
        uint64_t position = UINT64_MAX;
        for (int k = 0; k < 3; ++k) {
            const uint32_t v = indices[3 * size_t(t) + k];
            if (vertex[v].slot == kNotInCluster) continue;
            const uint32_t* list = &around[vertex[v].first];
            const uint32_t at = uint32_t(std::find(list, list + vertex[v].live, t) - list);
            position = std::min(position, uint64_t(vertex[v].slot) << 32 | at);
        }
        return position;
    };
    // The bucket's triangle with the smallest score, ties to the one meshoptimizer's scan meets first.
    auto smallest_score = [&](const Bucket& b) {
        float best = FLT_MAX;
        for (float score : scores) best = std::min(best, score);
        uint32_t winner = kNone;
        uint64_t winnerPosition = UINT64_MAX;
        size_t matches = 0;
        for (size_t i = 0; i < scores.size(); ++i) {
            if (scores[i] != best) continue;
            if (++matches == 1) {
                winner = b.triangle[i];
                continue;
            }
            if (matches == 2) winnerPosition = scan_position(winner);
            const uint64_t position = scan_position(b.triangle[i]);
            if (position < winnerPosition) {
                winner = b.triangle[i];
                winnerPosition = position;
            }
        }
        return winner;
    };
    // By distance to the cluster's mean centroid (meshoptimizer's score 1 + distance / expected radius).
    auto nearest_candidate = [&](const float* center) {
        const Bucket& b = best_bucket();
        scores.resize(b.size);
        for (size_t i = 0; i < scores.size(); ++i) {
            const float dx = b.x[i] - center[0], dy = b.y[i] - center[1], dz = b.z[i] - center[2];
            scores[i] = 1 + std::sqrt(dx * dx + dy * dy + dz * dz) / expectedRadius;
        }
        return smallest_score(b);
    };
    // By how many triangles its corners have left (for the first triangle of the next cluster).
    auto loneliest_candidate = [&]() {
        const Bucket& b = best_bucket();
        scores.resize(b.size);
        for (size_t i = 0; i < scores.size(); ++i) {
            const uint32_t* c = &indices[3 * size_t(b.triangle[i])];
            scores[i] = float(vertex[c[0]].live + vertex[c[1]].live + vertex[c[2]].live - 3);
        }
        return smallest_score(b);
    };

    for (size_t done = 0; done < triangles; ++done) {
        const float scale = clusterTriangles == 0 ? 0.f : 1.f / float(clusterTriangles);
        const float center[3] = {sum[0] * scale, sum[1] * scale, sum[2] * scale};
        uint32_t next = kNone;
        if (candidates > 0) {
            next = nearest_candidate(center);
            // The nearest does not fit: the next cluster starts where the fewest triangles are left around.
            if (clusterVertices.size() + extra_of(next) > maxVertices || clusterTriangles >= maxTriangles) next = loneliest_candidate();
        } else {
            // Nothing around the cluster is left: the nearest triangle anywhere (the first one: by a plain scan).
            bool tied = false;
            if (done == 0) {
                Nearest first;
                for (uint32_t t = 0; t < triangles; ++t) first.offer(t, distance_between(&centroids[3 * size_t(t)], center));
                next = first.triangle;
                tied = first.tied;
            } else {
                if (!nearest) nearest = std::make_unique<NearestTriangle>(centroids, lo, hi, double(meshArea) / 2);
                next = nearest->find(center, taken, tied);
            }
            if (tied) {  // equally near: meshoptimizer's search order decides
                if (!tree) tree = std::make_unique<KdTree>(centroids);
                next = tree->find(center, taken);
            }
        }

        // Take it, closing the cluster first if it does not fit.
        const uint32_t* corner = &indices[3 * size_t(next)];
        if (clusterVertices.size() + extra_of(next) > maxVertices || clusterTriangles >= maxTriangles) {
            for (uint32_t v : clusterVertices) vertex[v].slot = kNotInCluster;
            clusterVertices.clear();
            clusters.push_back(corners);
            corners.clear();
            for (Bucket& b : buckets) {
                for (uint32_t i = 0; i < b.size; ++i) listed[b.triangle[i]] = kNone;
                b.size = 0;
            }
            candidates = 0;
            sum[0] = sum[1] = sum[2] = 0;
            clusterTriangles = 0;
        }
        bool joinedNow[3] = {false, false, false};
        for (int k = 0; k < 3; ++k)
            if (vertex[corner[k]].slot == kNotInCluster) {
                joinedNow[k] = true;
                vertex[corner[k]].slot = uint32_t(clusterVertices.size());
                clusterVertices.push_back(corner[k]);
            }
        corners.insert(corners.end(), corner, corner + 3);
        if (clusterOfTriangle) (*clusterOfTriangle)[next] = uint32_t(clusters.size());  // the open cluster's number
        ++clusterTriangles;
        taken[next] = 1;
        if (listed[next] != kNone) unlist(next);
        for (int k = 0; k < 3; ++k) {  // no longer around its corners
            const uint32_t v = corner[k];
            uint32_t* list = &around[vertex[v].first];
            for (uint32_t i = 0; i < vertex[v].live; ++i)
                if (list[i] == next) {
                    list[i] = list[vertex[v].live - 1];
                    --vertex[v].live;
                    break;
                }
        }
        // The triangles around vertices that just joined become candidates, and only the triangles around this one's
        // corners can change priority, only where the corner just joined or is left with one or two triangles (the
        // priorities test for those counts). One pass over those corners does both: where a candidate is listed in a
        // bucket does not matter (ties go by meshoptimizer's scan order, scan_position).
        for (int k = 0; k < 3; ++k) {
            const uint32_t v = corner[k];
            if (vertex[v].live > 2 && !joinedNow[k]) continue;
            for (uint32_t i = 0; i < vertex[v].live; ++i) {
                const uint32_t t = around[vertex[v].first + i];
                const uint32_t priority = priority_of(t);
                if (listed[t] == kNone) {
                    list(t, priority);
                } else if ((listed[t] & 7) != priority) {
                    unlist(t);
                    list(t, priority);
                }
            }
        }
        for (int k = 0; k < 3; ++k) sum[k] += centroids[3 * size_t(next) + k];
    }
    if (!corners.empty()) clusters.push_back(std::move(corners));
    return true;
}

}  // namespace tessera
