// The cluster DAG: clusters of the source triangles, then rounds of grouping and simplifying until a round
// makes no progress. Invariants (shared/DESIGN.md): group borders are locked while a group simplifies, so a
// parent shares its border vertices with its neighbours exactly (crack-free cuts); a group's error is its measured
// distance from the source (deviation.h), at least the largest of its children's, and its sphere encloses its
// children's (monotone).
#include "tessera/builder.h"
#include "tessera/morton.h"

#include "area.h"
#include "attribute_fit.h"
#include "cluster_codec.h"
#include "clusters.h"
#include "cut.h"
#include "deviation.h"
#include "edge_limit.h"
#include "tessera/parallel.h"
#include "phase_timer.h"
#include "rows.h"
#include "vertex_box.h"
#include "weld.h"

#include <meshoptimizer.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <mutex>
#include <tuple>
#include <unordered_map>

namespace tessera {
namespace {

constexpr size_t kClusterVertices = 255;  // meshoptimizer's meshlet limit (build_clusters keeps to it too)
constexpr size_t kGroupSize = 16;         // clusters per group (partitions come out between about 8 and 32)
constexpr double kStuckRatio = 0.85;      // a group that keeps more than this share of its triangles is stuck
constexpr double kSliverLength = 100;      // a triangle this many times longer than wide is a sliver (sampling_size)
constexpr size_t kCarriedPoints = 32;     // source points a cluster carries up to measure its parents by (deviation.h)
constexpr double kSeamRetryError = 0.25;  // a group whose simplification strays this share of its diameter retries without normal seams
constexpr int kPinRounds = 16;            // retries of one simplification step that made too long an edge
// Vertex locks: a group border (shared with another group: crack-free), or pinned to split an edge too long.
constexpr unsigned char kBorderLock = 1, kPinned = 2;

struct Sphere {
    double x = 0, y = 0, z = 0, r = 0;
};

double distance(const Sphere& a, const Sphere& b) { return std::sqrt((a.x - b.x) * (a.x - b.x) + (a.y - b.y) * (a.y - b.y) + (a.z - b.z) * (a.z - b.z)); }

// A sphere enclosing every sphere given (grown one sphere at a time; exact for two).
Sphere enclose(const std::vector<Sphere>& spheres) {
    Sphere s = *std::max_element(spheres.begin(), spheres.end(), [](const Sphere& a, const Sphere& b) { return a.r < b.r; });
    for (const Sphere& o : spheres) {
        const double d = distance(s, o);
        if (d + o.r <= s.r) continue;
        if (d + s.r <= o.r) {
            s = o;
            continue;
        }
        const double r = (d + s.r + o.r) / 2, t = (r - s.r) / d;
        s = {s.x + (o.x - s.x) * t, s.y + (o.y - s.y) * t, s.z + (o.z - s.z) * t, r};
    }
    for (const Sphere& o : spheres) s.r = std::max(s.r, distance(s, o) + o.r);  // rounding never leaves one out
    return s;
}

// The size of a triangle that samples texture across a border: its longest edge, or for a sliver a hundred times its
// width (twice its area over that edge), whichever is less. What it shows wrongly is a strip that wide: a sliver
// between points of a pole made of several points at one place (a sphere's, mapped per face) is no wider than their
// distance, and counted by its length it claimed 1.5 % of the sphere's size at its first level. A triangle with two
// corners at one position (simplifying along a seam leaves such) has no width: it samples nothing.
double sampling_size(const float* a, const float* b, const float* c) {
    const double ab[3] = {double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]};
    const double ac[3] = {double(c[0]) - a[0], double(c[1]) - a[1], double(c[2]) - a[2]};
    const double bc[3] = {ac[0] - ab[0], ac[1] - ab[1], ac[2] - ab[2]};
    const double cross[3] = {ab[1] * ac[2] - ab[2] * ac[1], ab[2] * ac[0] - ab[0] * ac[2], ab[0] * ac[1] - ab[1] * ac[0]};
    auto length = [](const double* v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); };
    const double longest = std::max({length(ab), length(ac), length(bc)});
    const double width = longest > 0 ? length(cross) / longest : 0.0;
    return std::min(longest, kSliverLength * width);
}

// Smallest sphere centred on the box centre that holds the vertices: the box (vertex_box.h), then the largest
// distance from its centre over the points point(i), i in [begin, end) (which does not depend on how a range is split).
template <class Point>
double farthest(Point point, size_t begin, size_t end, const Sphere& c) {
    double r = 0;
    for (size_t i = begin; i < end; ++i) {
        const float* p = point(i);
        r = std::max(r, std::sqrt((p[0] - c.x) * (p[0] - c.x) + (p[1] - c.y) * (p[1] - c.y) + (p[2] - c.z) * (p[2] - c.z)));
    }
    return r;
}

Sphere vertex_sphere(const std::vector<float>& positions, const uint32_t* vertices, size_t count) {
    auto point = [&](size_t i) { return &positions[3 * vertices[i]]; };
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    grow_box(point, 0, count, lo, hi);
    Sphere s{(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2, 0};
    s.r = farthest(point, 0, count, s);
    return s;
}

// vertex_sphere of every vertex, the same sphere, over blocks of `block` vertices on every core.
Sphere all_vertices_sphere(const std::vector<float>& positions, size_t block) {
    const size_t count = positions.size() / 3, blocks = (count + block - 1) / block;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    all_vertices_box(positions, block, lo, hi);
    Sphere s{(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2, 0};
    auto point = [&](size_t i) { return &positions[3 * i]; };
    std::vector<double> radii(blocks, 0.0);
    parallel_blocks(count, block, [&](size_t begin, size_t end) { radii[begin / block] = farthest(point, begin, end, s); });
    for (double r : radii) s.r = std::max(s.r, r);
    return s;
}

std::array<float, 4> to_float(const Sphere& s) {
    // Round the radius up so that the float sphere still contains what the double one did.
    const float r = float(s.r) * (1 + 4 * FLT_EPSILON) + float(std::fabs(s.x) + std::fabs(s.y) + std::fabs(s.z)) * 4 * FLT_EPSILON;
    return {float(s.x), float(s.y), float(s.z), r};
}

struct WorkCluster {
    std::vector<uint32_t> indices;  // 3 per triangle, into the mesh's vertices
    Sphere lodSphere;
    float lodError = 0;
    uint32_t level = 0;
    int32_t parentGroup = -1;
    int32_t madeBy = -1;  // the group whose simplification made it
    std::vector<SourcePoint> carried;  // source points nearest it that its level strays from most (deviation.h)
};

struct Group {
    Sphere sphere;
    float error;
};


// Foliage-like input (many small disconnected parts) cannot simplify by edge collapse. Parts of a group that
// touch no locked vertex are connected to nothing outside it, so dropping them whole opens no crack: drop the
// smallest such parts until the target is met, never the last one, and count the largest dropped part's extent
// as error. (meshoptimizer's own pruning may remove parts that touch locked borders, so it is not used.)
size_t drop_free_components(std::vector<uint32_t>& indices, size_t count, size_t target, const std::vector<float>& positions,
                            const std::vector<uint32_t>& positionId, const std::vector<unsigned char>& lock, float& error) {
    // Union-find over positions, through triangle edges.
    std::unordered_map<uint32_t, uint32_t> parent;
    auto find = [&](uint32_t p) {
        auto it = parent.try_emplace(p, p).first;
        uint32_t root = p;
        while (parent[root] != root) root = parent[root];
        while (it->second != root) {  // path compression
            const uint32_t next = it->second;
            it->second = root;
            it = parent.find(next);
        }
        return root;
    };
    for (size_t i = 0; i < count; i += 3) {
        const uint32_t a = find(positionId[indices[i]]);
        for (int k = 1; k < 3; ++k) {
            const uint32_t b = find(positionId[indices[i + k]]);
            if (a != b) parent[b] = a;
        }
    }
    struct Part {
        bool locked = false;
        size_t triangles = 0;
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        double extent() const { return std::sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) + (hi[2] - lo[2]) * (hi[2] - lo[2])); }
    };
    std::map<uint32_t, Part> parts;  // ordered: deterministic
    for (size_t i = 0; i < count; ++i) {
        Part& part = parts[find(positionId[indices[i]])];
        part.locked |= lock[indices[i]] == kBorderLock;
        if (i % 3 == 0) ++part.triangles;
        for (int k = 0; k < 3; ++k) {
            part.lo[k] = std::min(part.lo[k], double(positions[3 * indices[i] + k]));
            part.hi[k] = std::max(part.hi[k], double(positions[3 * indices[i] + k]));
        }
    }
    std::vector<std::pair<double, uint32_t>> free;
    for (auto& [root, part] : parts)
        if (!part.locked) free.push_back({part.extent(), root});
    std::sort(free.begin(), free.end());
    if (free.size() == parts.size() && !free.empty()) free.pop_back();  // keep at least the largest part
    std::unordered_map<uint32_t, bool> dropped;
    size_t remaining = count / 3;
    for (auto& [extent, root] : free) {
        if (3 * remaining <= target) break;
        dropped[root] = true;
        remaining -= parts[root].triangles;
        error = std::max(error, float(extent));
    }
    if (dropped.empty()) return count;
    size_t write = 0;
    for (size_t i = 0; i < count; i += 3)
        if (!dropped.count(find(positionId[indices[i]])))
            for (int k = 0; k < 3; ++k) indices[write++] = indices[i + k];
    return write;
}


// Frees a vector's memory (clear() keeps it).
template <class T>
void release(std::vector<T>& v) {
    std::vector<T>().swap(v);
}

// Per triangle of `indices` (3 vertices each), the piece `pieces` hold it in (each triangle's corners in their order):
// both lists of triangles sorted by their corners and matched. For meshoptimizer's clusters, which do not say.
std::vector<uint32_t> piece_of_triangles(const std::vector<uint32_t>& indices, const std::vector<std::vector<uint32_t>>& pieces) {
    using Keyed = std::pair<std::array<uint32_t, 3>, uint32_t>;  // (corners, triangle or piece)
    std::vector<Keyed> triangles, placed;
    for (uint32_t i = 0; i < indices.size(); i += 3) triangles.push_back({{indices[i], indices[i + 1], indices[i + 2]}, i / 3});
    for (uint32_t piece = 0; piece < pieces.size(); ++piece)
        for (size_t i = 0; i < pieces[piece].size(); i += 3) placed.push_back({{pieces[piece][i], pieces[piece][i + 1], pieces[piece][i + 2]}, piece});
    std::sort(triangles.begin(), triangles.end());
    std::sort(placed.begin(), placed.end());
    std::vector<uint32_t> pieceOf(triangles.size(), 0);
    for (size_t i = 0; i < triangles.size() && i < placed.size(); ++i) pieceOf[triangles[i].second] = placed[i].second;
    return pieceOf;
}

// Splits triangles into spatially compact clusters (at most 128 triangles and 255 vertices). The triangles'
// vertices are first compacted, so the cost follows the triangles given, not the whole mesh.
// `cornerCount` corners, 3 per triangle, read as `corner(i)` (level 0's chunks read the mesh's triangles in Morton
// order through it, rather than copies); `position(v)` gives vertex v's xyz; `pieceOf`, where given, receives each
// triangle's piece.
template <typename CornerOf, typename PositionOf>
std::vector<std::vector<uint32_t>> split_into_clusters(size_t cornerCount, CornerOf corner, PositionOf position, std::vector<uint32_t>* pieceOf = nullptr) {
    // Local numbers found through a table (sorting every index and searching for each cost a fifth of the build):
    // direct when the vertex numbers span little more than the indices (a small mesh in one piece), else open
    // addressing at most half full (Morton chunks and groups of large meshes).
    uint32_t first = UINT32_MAX, last = 0;
    for (size_t i = 0; i < cornerCount; ++i) {
        const uint32_t v = corner(i);
        first = std::min(first, v);
        last = std::max(last, v);
    }
    const bool direct = size_t(last - first) < 2 * cornerCount;
    size_t slots = 16;
    while (!direct && slots < 2 * cornerCount) slots *= 2;
    std::vector<std::pair<uint32_t, uint32_t>> table(direct ? size_t(last - first) + 1 : slots, {UINT32_MAX, 0});  // (vertex, local)
    auto entry = [&](uint32_t v) -> std::pair<uint32_t, uint32_t>& {
        if (direct) return table[v - first];
        size_t i = size_t((v * 0x9E3779B97F4A7C15ull) >> 32) & (slots - 1);
        while (table[i].first != v && table[i].first != UINT32_MAX) i = (i + 1) & (slots - 1);
        return table[i];
    };
    // Numbered by first use (neighbours in the triangle order are near in memory); the clusters do not depend on
    // the numbering, only on the triangle order.
    std::vector<uint32_t> vertices, localIndices(cornerCount);
    std::vector<float> compact;
    vertices.reserve(cornerCount / 2 + 3);
    compact.reserve(3 * (cornerCount / 2 + 3));
    for (size_t i = 0; i < cornerCount; ++i) {
        const uint32_t v = corner(i);
        auto& e = entry(v);
        if (e.first == UINT32_MAX) {
            e = {v, uint32_t(vertices.size())};
            vertices.push_back(v);
            compact.insert(compact.end(), position(v), position(v) + 3);
        }
        localIndices[i] = e.second;
    }
    release(table);  // freed before clustering: the build's memory peaks there (level 0)

    // Our builder gives meshoptimizer's clusters (the same, triangle for triangle) at half the cost; meshoptimizer
    // itself only for what ours leaves to it (a mesh of no area, clusters.h).
    std::vector<std::vector<uint32_t>> pieces;
    if (build_clusters(localIndices.data(), localIndices.size(), compact.data(), vertices.size(), kClusterVertices, kClusterMaxTriangles, pieces,
                       pieceOf)) {
        for (auto& piece : pieces)
            for (uint32_t& v : piece) v = vertices[v];
        return pieces;
    }
    const size_t maxClusters = meshopt_buildMeshletsBound(cornerCount, kClusterVertices, kClusterMaxTriangles);
    std::vector<meshopt_Meshlet> meshlets(maxClusters);
    std::vector<unsigned int> meshletVertices(maxClusters * kClusterVertices);
    std::vector<unsigned char> meshletTriangles(maxClusters * kClusterMaxTriangles * 3);
    const size_t count = meshopt_buildMeshlets(meshlets.data(), meshletVertices.data(), meshletTriangles.data(), localIndices.data(),
                                               localIndices.size(), compact.data(), vertices.size(), 12, kClusterVertices, kClusterMaxTriangles, 0.0f);
    pieces.resize(count);
    for (size_t m = 0; m < count; ++m) {
        const meshopt_Meshlet& meshlet = meshlets[m];
        pieces[m].resize(meshlet.triangle_count * 3);
        for (size_t i = 0; i < pieces[m].size(); ++i)
            pieces[m][i] = vertices[meshletVertices[meshlet.vertex_offset + meshletTriangles[meshlet.triangle_offset + i]]];
    }
    if (pieceOf) {
        std::vector<uint32_t> indices(cornerCount);
        for (size_t i = 0; i < cornerCount; ++i) indices[i] = corner(i);
        *pieceOf = piece_of_triangles(indices, pieces);
    }
    return pieces;
}

template <typename PositionOf>
std::vector<std::vector<uint32_t>> split_into_clusters(const std::vector<uint32_t>& indices, PositionOf position, std::vector<uint32_t>* pieceOf = nullptr) {
    return split_into_clusters(indices.size(), [&](size_t i) { return indices[i]; }, position, pieceOf);
}

// The cluster-local number by first use of each of `indices`, to `corner(number)`, and `fresh(v)` first for each vertex
// met first there (a small open-addressing table: clusters have at most 256 vertices). The table is the thread's own,
// and its slots are stamped with the call that filled them, so no call clears it.
template <typename Corner, typename Fresh>
void visit_first_uses(const std::vector<uint32_t>& indices, Corner corner, Fresh fresh) {
    constexpr uint32_t kSlots = 1024;
    struct Slot {
        uint32_t stamp, key, number;
    };
    thread_local std::array<Slot, kSlots> slots{};
    thread_local uint32_t stamp = 0;
    if (++stamp == 0) {  // wrapped: clear once every 4 billion calls
        slots.fill({});
        stamp = 1;
    }
    uint32_t numbered = 0;
    for (uint32_t v : indices) {
        uint32_t slot = (v * 0x9E3779B1u) >> 22;
        while (slots[slot].stamp == stamp && slots[slot].key != v) slot = (slot + 1) % kSlots;
        if (slots[slot].stamp != stamp) {
            slots[slot] = {stamp, v, numbered++};
            fresh(v);
        }
        corner(slots[slot].number);
    }
}

// Cluster-local vertex numbers by first use: returns the corners renumbered, and the mesh vertices in that order in
// `vertices`.
std::vector<uint32_t> number_by_first_use(const std::vector<uint32_t>& indices, std::vector<uint32_t>& vertices) {
    std::vector<uint32_t> corners;
    corners.reserve(indices.size());
    vertices.clear();
    visit_first_uses(indices, [&](uint32_t number) { corners.push_back(number); }, [&](uint32_t v) { vertices.push_back(v); });
    return corners;
}

// A group's children are stored together in one page (pages.cpp): a group whose children could encode to more than a
// page (UnitBytesBound: faceted meshes with texture coordinates and colours, every corner its own vertex) is split
// into runs of its members, in their order, each within a page. Ordinary groups (80 vertices a cluster) bound at
// under 100 KiB with every attribute and stay whole. `bytes[i]`: pending cluster i's bound taking it to have as many
// vertices as it may (cheap, and enough for most meshes), `exact_bytes(i)` its bound with its vertices counted (for the
// members of groups that the first bound does not clear). Returns the new group count.
template <typename ExactBytes>
size_t split_groups_beyond_a_page(std::vector<unsigned int>& partition, size_t groupCount, std::vector<size_t>& bytes, ExactBytes exact_bytes) {
    constexpr size_t kBudget = kPageBytes - kPageStreamCount * 8 - UnitBytesBound::kUnitBytes;  // less the page's stream table
    std::vector<size_t> groupBytes(groupCount, 0);
    for (size_t i = 0; i < partition.size(); ++i) groupBytes[partition[i]] += bytes[i];
    std::vector<size_t> doubtful;
    for (size_t i = 0; i < partition.size(); ++i)
        if (groupBytes[partition[i]] > kBudget) doubtful.push_back(i);
    if (doubtful.empty()) return groupCount;
    for (size_t i : doubtful) groupBytes[partition[i]] = 0;
    parallel_for(doubtful.size(), [&](size_t k) { bytes[doubtful[k]] = exact_bytes(doubtful[k]); });
    for (size_t i : doubtful) groupBytes[partition[i]] += bytes[i];
    std::vector<size_t> runBytes(groupCount, 0);  // the run a group's members fill now: its group (the first) or the newest
    std::vector<unsigned int> runOf(groupCount);
    for (size_t g = 0; g < groupCount; ++g) runOf[g] = unsigned(g);
    size_t groups = groupCount;
    for (size_t i = 0; i < partition.size(); ++i) {
        const unsigned int g = partition[i];
        if (groupBytes[g] <= kBudget) continue;
        // Runs of about equal bytes: a new one starts where this member would overfill the run or pass its share.
        const size_t runs = (groupBytes[g] + kBudget - 1) / kBudget, share = (groupBytes[g] + runs - 1) / runs;
        if (runBytes[g] > 0 && (runBytes[g] + bytes[i] > kBudget || runBytes[g] + bytes[i] / 2 > share)) {
            runOf[g] = unsigned(groups++);
            runBytes[g] = 0;
        }
        runBytes[g] += bytes[i];
        partition[i] = runOf[g];
    }
    return groups;
}

// Level 0: the source in spatially compact clusters. A mesh of more than 32k triangles is first cut into
// Morton-ordered chunks that are clustered in parallel (the meshlet builder is the build's slowest serial step): 64k
// triangles each, or two halves up to 128k (clustered whole, the 70k-triangle bunny spent an eighth of its build on
// one core). The chunks follow from the mesh alone, never the cores, so the clusters do not depend on the machine;
// only the last cluster of each chunk may be partly filled.
std::vector<std::vector<uint32_t>> split_level_zero(const std::vector<uint32_t>& indices, const std::vector<float>& positions) {
    const size_t triangles = indices.size() / 3;
    const size_t kChunkTriangles = triangles > 131072 ? 65536 : (triangles + 1) / 2;
    auto position = [&](uint32_t v) { return &positions[3 * v]; };
    if (triangles <= 32768) return split_into_clusters(indices, position);
    float lo[3];
    const float extent = morton_cube(positions.size() / 3, [&](size_t v, float* p) { std::copy_n(&positions[3 * v], 3, p); }, lo);
    // (Morton code of the centroid, triangle), coded and sorted in blocks on every core, then merged: the order is
    // total (triangle numbers differ), so it does not depend on the blocks.
    std::vector<std::pair<uint32_t, uint32_t>> order(triangles);
    const size_t chunks = (triangles + kChunkTriangles - 1) / kChunkTriangles;
    parallel_for(chunks, [&](size_t c) {
        const size_t end = std::min(triangles, (c + 1) * kChunkTriangles);
        for (size_t t = c * kChunkTriangles; t < end; ++t) {
            float centroid[3];
            for (int k = 0; k < 3; ++k)
                centroid[k] = (positions[3 * indices[3 * t] + k] + positions[3 * indices[3 * t + 1] + k] + positions[3 * indices[3 * t + 2] + k]) / 3;
            order[t] = {morton_code(centroid, lo, extent), uint32_t(t)};
        }
        std::sort(order.begin() + c * kChunkTriangles, order.begin() + end);
    });
    for (size_t width = kChunkTriangles; width < triangles; width *= 2)  // pairs of sorted runs, merged on every core
        parallel_for((triangles + 2 * width - 1) / (2 * width), [&](size_t pair) {
            const size_t begin = pair * 2 * width, middle = std::min(triangles, begin + width), end = std::min(triangles, begin + 2 * width);
            std::inplace_merge(order.begin() + begin, order.begin() + middle, order.begin() + end);
        });
    // The triangles in Morton order, without their codes (the build's memory peaks while level 0 clusters).
    std::vector<uint32_t> sorted(triangles);
    parallel_blocks(triangles, kChunkTriangles, [&](size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) sorted[i] = order[i].second;
    });
    release(order);
    std::vector<std::vector<std::vector<uint32_t>>> pieces(chunks);
    parallel_for(chunks, [&](size_t c) {
        const size_t begin = c * kChunkTriangles, end = std::min(triangles, (c + 1) * kChunkTriangles);
        pieces[c] = split_into_clusters(3 * (end - begin), [&](size_t i) { return indices[3 * sorted[begin + i / 3] + i % 3]; }, position);
    });
    std::vector<std::vector<uint32_t>> all;
    for (auto& chunk : pieces)
        for (auto& piece : chunk) all.push_back(std::move(piece));
    return all;
}

// build_mesh, which empties `spent`'s arrays (the same object as `mesh`, or null) as soon as it is done with them:
// positions, indices and the per-triangle arrays once the grid and the weld hold the mesh, normals and colours at the
// end. Both are at the peak of a build otherwise (encoding the pages comes after it, and the largest rounds before).
BuiltMesh build(const PreparedMesh& mesh, PreparedMesh* spent, const BuildSettings& settings) {
    validate_settings(settings);
    PhaseTimer phases;
    BuiltMesh out;
    const size_t vertexCount = mesh.positions.size() / 3;
    out.sourceTriangles = mesh.indices.size() / 3;
    out.constantColor = mesh.constantColor;
    out.hasConstantColor = mesh.hasConstantColor;

    // Recentre (in double, on the grid) so that large authored coordinates lose no more precision than they already have.
    // The loops over every vertex or triangle before the DAG run on every core in blocks; minima and maxima do not
    // depend on the blocks.
    constexpr size_t kBlock = 65536;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    all_vertices_box(mesh.positions, kBlock, lo, hi);
    out.size = float(std::sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) + (hi[2] - lo[2]) * (hi[2] - lo[2])));

    // The position grid: a power-of-two step in object space, anchored at the object's origin.
    int precision = settings.positionPrecision;
    if (precision == BuildSettings::kAutoPrecision) {
        // Fine against the shortest edge: snapping must not turn thin triangles into slivers or collapse them (the
        // simplifier's attribute metric punishes slivers badly, and a measured 1 M-triangle sphere's DAG stalled with
        // 32x coarser steps). The range cap below bounds the cost on meshes with near-degenerate edges.
        const size_t triangleCount = mesh.indices.size() / 3;
        std::vector<double> blockShortest((triangleCount + kBlock - 1) / kBlock, INFINITY);
        parallel_blocks(triangleCount, kBlock, [&](size_t begin, size_t end) {
            double shortest = INFINITY;
            for (size_t i = 3 * begin; i < 3 * end; i += 3)
                for (int e = 0; e < 3; ++e) {
                    const float* a = &mesh.positions[3 * mesh.indices[i + e]];
                    const float* b = &mesh.positions[3 * mesh.indices[i + (e + 1) % 3]];
                    const double length2 = double(a[0] - b[0]) * (a[0] - b[0]) + double(a[1] - b[1]) * (a[1] - b[1]) + double(a[2] - b[2]) * (a[2] - b[2]);
                    if (length2 > 0) shortest = std::min(shortest, length2);
                }
            blockShortest[begin / kBlock] = shortest;
        });
        const double shortest = *std::min_element(blockShortest.begin(), blockShortest.end());
        const double wanted = std::min(double(out.size) / 65536.0, std::sqrt(shortest) / 64.0);  // and 16 bits across the mesh
        precision = int(std::floor(std::log2(std::max(wanted, 1e-30))));
    }
    const double largestExtent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
    while (largestExtent / std::ldexp(1.0, precision) > double(1 << 23)) ++precision;  // keep grid coordinates exact in float
    out.positionPrecision = precision;
    out.positionStep = std::ldexp(1.0, precision);
    const double step = out.positionStep;
    double originGrid[3];
    for (int k = 0; k < 3; ++k) {
        originGrid[k] = std::round((lo[k] + hi[k]) * 0.5 / step);
        out.origin[k] = originGrid[k] * step;
    }
    std::vector<float> local(3 * vertexCount);
    parallel_blocks(vertexCount, kBlock, [&](size_t begin, size_t end) {
        for (size_t v = begin; v < end; ++v)
            for (int k = 0; k < 3; ++k)  // + 0.0f turns -0 into +0, so equal positions have equal bits
                local[3 * v + k] = float((std::round(double(mesh.positions[3 * v + k]) / step) - originGrid[k]) * step) + 0.0f;
    });

    // Vertices split at attribute seams share a position id: adjacency and border locks follow positions.
    // Preserve Area adds moved vertices later: the welder gives them ids too.
    PositionWelder welder;  // kept only for Preserve Area (without it, the weld runs on every core)
    std::vector<uint32_t> positionId = weld_equal_positions(local.data(), vertexCount, settings.preserveArea ? &welder : nullptr);
    phases.mark("bounds+grid+weld");

    // Texture coordinates on their grid (BuiltMesh::uvPrecision): at most 2^-16, and coarse enough that float holds
    // every grid point of the mesh's range exactly.
    const bool hasUvs = !mesh.uvs.empty();
    std::vector<float> uvs;
    uint64_t largestUv = 0;  // the largest texture coordinate on that grid, in steps
    if (hasUvs) {
        float largest = 1.0f;
        for (float u : mesh.uvs) largest = std::max(largest, std::fabs(u));
        out.uvPrecision = uv_grid_precision(largest);
        const double uvStep = std::ldexp(1.0, out.uvPrecision);
        largestUv = uint64_t(std::ceil(double(largest) / uvStep)) + 1;
        uvs.resize(mesh.uvs.size());
        for (size_t i = 0; i < uvs.size(); ++i) uvs[i] = float(std::round(double(mesh.uvs[i]) / uvStep) * uvStep) + 0.0f;
    }

    // Material slots are a property of vertices (prepare_mesh splits vertices where slots meet): the simplifier keeps
    // such splits as seams, so every triangle of every level has the slot of each of its vertices.
    std::vector<uint8_t> vertexMaterial(mesh.triangleMaterials.empty() ? 0 : vertexCount, 0);
    for (size_t t = 0; t < mesh.triangleMaterials.size(); ++t)
        for (int k = 0; k < 3; ++k) vertexMaterial[mesh.indices[3 * t + k]] = mesh.triangleMaterials[t];
    for (uint8_t slot : mesh.triangleMaterials) out.materialSlots = std::max(out.materialSlots, uint32_t(slot) + 1);
    auto material_of = [&](uint32_t v) { return vertexMaterial.empty() ? 0u : uint32_t(vertexMaterial[v]); };

    // Attributes weighed by the simplifier: normal, then colour and texture coordinates where the mesh has them.
    // meshoptimizer normalises positions to the group's extent before weighing, even when it reports absolute
    // errors, so the weights are relative and independent of scale.
    const bool hasColors = !mesh.colors.empty();
    const size_t colorAttribute = 3, uvAttribute = hasColors ? 3 + kChannelComponents : 3;
    const size_t attributeCount = uvAttribute + (hasUvs ? 2 : 0);
    std::vector<float> attributes(vertexCount * attributeCount);
    parallel_blocks(vertexCount, kBlock, [&](size_t begin, size_t end) {
        for (size_t v = begin; v < end; ++v) {
            for (int k = 0; k < 3; ++k) attributes[v * attributeCount + k] = mesh.normals[3 * v + k];
            if (hasColors)
                for (int k = 0; k < kChannelComponents; ++k)
                    attributes[v * attributeCount + colorAttribute + k] = mesh.colors[kChannelComponents * v + k];
            if (hasUvs)
                for (int k = 0; k < 2; ++k) attributes[v * attributeCount + uvAttribute + k] = uvs[2 * v + k];
        }
    });
    // Normals weigh little: the simplifier's error, which the cut projects to pixels, includes the attribute terms,
    // and at 0.5 they steered collapses into surfaces about 2.6x farther off at coarse levels (0.10 against 0.038
    // mesh units on a bumpy unit sphere at 3k triangles; docs/benchmarks.md). Texture coordinates are weighed per
    // group, like positions, relative to the group's own UV extent (set in the loop below): UV distortion of 10 % of
    // the group's texture span counts as a geometric error of 2.5 % of the group's extent.
    constexpr float kNormalWeight = 0.1f, kColorWeight = 1.0f, kUvWeight = 0.25f;
    constexpr int kMaxAttributes = 3 + kChannelComponents + 2;
    float weights[kMaxAttributes] = {kNormalWeight, kNormalWeight, kNormalWeight};
    for (size_t k = colorAttribute; hasColors && k < colorAttribute + kChannelComponents; ++k) weights[k] = kColorWeight;
    phases.mark("attributes");

    std::vector<WorkCluster> clusters;
    std::vector<Group> groups;
    auto add_clusters = [&](std::vector<std::vector<uint32_t>> pieces, const Sphere* groupSphere, float groupError, uint32_t level,
                            int32_t madeBy, std::vector<uint32_t>& created, std::vector<std::vector<SourcePoint>> carried = {}) {
        std::vector<Sphere> own(groupSphere ? 0 : pieces.size());  // level 0's, on every core
        parallel_for(own.size(), [&](size_t i) { own[i] = vertex_sphere(local, pieces[i].data(), pieces[i].size()); });
        for (size_t i = 0; i < pieces.size(); ++i) {
            WorkCluster c;
            c.indices = std::move(pieces[i]);
            c.lodSphere = groupSphere ? *groupSphere : own[i];
            c.lodError = groupError;
            c.level = level;
            c.madeBy = madeBy;
            if (i < carried.size()) c.carried = std::move(carried[i]);
            created.push_back(uint32_t(clusters.size()));
            clusters.push_back(std::move(c));
        }
    };

    // Weld again on the grid: vertices that snapped onto one grid point with the same colour and normals within
    // 30 degrees become one (otherwise they would look like attribute seams to the simplifier and lock it); a wider
    // angle is a real hard edge and stays split.
    std::vector<uint32_t> weld(vertexCount);
    {
        // A vertex first at its grid point (its position id is itself) is its own representative; only the others
        // (seams, snapped neighbours: few) look for one, among their grid point's representatives in vertex order.
        // Grid points are independent: their vertices are gathered by point (stable, so still in vertex order).
        std::vector<std::vector<std::pair<uint32_t, uint32_t>>> blockRepeats((vertexCount + kBlock - 1) / kBlock);  // (point, vertex)
        parallel_blocks(vertexCount, kBlock, [&](size_t begin, size_t end) {
            for (size_t v = begin; v < end; ++v) {
                weld[v] = uint32_t(v);
                if (positionId[v] != v) blockRepeats[begin / kBlock].push_back({positionId[v], uint32_t(v)});
            }
        });
        std::vector<std::pair<uint32_t, uint32_t>> repeats;
        for (const auto& block : blockRepeats) repeats.insert(repeats.end(), block.begin(), block.end());
        release(blockRepeats);
        std::stable_sort(repeats.begin(), repeats.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
        std::vector<uint32_t> reps;
        for (size_t i = 0; i < repeats.size();) {
            const uint32_t p = repeats[i].first;
            reps.assign(1, p);
            for (; i < repeats.size() && repeats[i].first == p; ++i) {
                const uint32_t v = repeats[i].second;
                bool welded = false;
                for (uint32_t r : reps) {
                    const float* n = &mesh.normals[3 * v];
                    const float* m = &mesh.normals[3 * r];
                    const bool sameColor = !hasColors || std::memcmp(&mesh.colors[kChannelComponents * v], &mesh.colors[kChannelComponents * r], 4 * kChannelComponents) == 0;
                    const bool sameUv = !hasUvs || std::memcmp(&uvs[2 * v], &uvs[2 * r], 8) == 0;
                    if (sameColor && sameUv && material_of(v) == material_of(r) && n[0] * m[0] + n[1] * m[1] + n[2] * m[2] > 0.866f) {
                        weld[v] = r;
                        welded = true;
                        break;
                    }
                }
                if (!welded) reps.push_back(v);
            }
        }
    }

    // Triangles that quantization collapsed (two corners on one grid point) cannot be seen: drop them. Slivers
    // would also make the simplifier's attribute gradients, which divide by area, explode.
    // Kept triangles are counted per block on every core, then written at their block's offset.
    const size_t inputTriangles = mesh.indices.size() / 3;
    std::vector<size_t> blockKept((inputTriangles + kBlock - 1) / kBlock + 1, 0);
    auto kept_triangle = [&](size_t t, uint32_t* out) {
        const uint32_t a = weld[mesh.indices[3 * t]], b = weld[mesh.indices[3 * t + 1]], c = weld[mesh.indices[3 * t + 2]];
        if (positionId[a] == positionId[b] || positionId[b] == positionId[c] || positionId[a] == positionId[c]) return false;
        if (out) out[0] = a, out[1] = b, out[2] = c;
        return true;
    };
    parallel_blocks(inputTriangles, kBlock, [&](size_t begin, size_t end) {
        size_t kept = 0;
        for (size_t t = begin; t < end; ++t) kept += kept_triangle(t, nullptr);
        blockKept[begin / kBlock + 1] = kept;
    });
    for (size_t b = 1; b < blockKept.size(); ++b) blockKept[b] += blockKept[b - 1];
    std::vector<uint32_t> sourceIndices(3 * blockKept.back());
    parallel_blocks(inputTriangles, kBlock, [&](size_t begin, size_t end) {
        uint32_t* out = sourceIndices.data() + 3 * blockKept[begin / kBlock];
        for (size_t t = begin; t < end; ++t) out += 3 * kept_triangle(t, out);
    });
    if (sourceIndices.empty())  // everything on one grid point: keep the mesh as it is
        for (uint32_t v : mesh.indices) sourceIndices.push_back(weld[v]);
    out.sourceTriangles = sourceIndices.size() / 3;

    // The edge length limit, from the source as welded on the grid.
    const double maxEdge = settings.maxEdgeLengthFactor > 0 ? settings.maxEdgeLengthFactor * mean_edge_length(sourceIndices, local) : 0.0;
    phases.mark("grid weld+drop");
    if (spent) release(spent->positions), release(spent->indices), release(spent->uvs), release(spent->triangleMaterials), release(spent->sourceFaces);
    // Where each vertex takes its normal and colour from (itself, or the vertex Preserve Area moved it from).
    std::vector<uint32_t> attributeOf(vertexCount);
    parallel_blocks(vertexCount, kBlock, [&](size_t begin, size_t end) {
        for (size_t v = begin; v < end; ++v) attributeOf[v] = uint32_t(v);
    });
    // Fitted normals and vertex channel (attribute_fit.h): fit k gave vertex fits[k].vertex the normal
    // fittedNormals[3k..3k+2] (and channel fittedChannels[4k..4k+3]) in the clusters of group fits[k].group and of every
    // later group that does not fit it again. drawnOf: the values each vertex is drawn with now, a source vertex's
    // (below vertexCount) or the latest fit's (vertexCount + k).
    struct Fit {
        uint32_t group, vertex;
    };
    std::vector<Fit> fits;
    std::vector<float> fittedNormals, fittedChannels;
    std::vector<uint32_t> drawnOf(attributeOf);
    // The source's UV islands, for the seam retry's last step (made by the first group that needs them: most builds
    // never do): triangles joined through shared vertices, and through wedges of one position with the same texture
    // coordinates (normal or colour seams inside an island). Each vertex's island is named by its smallest vertex.
    auto uv_distance2 = [](const float* a, const float* b) { return double(a[0] - b[0]) * (a[0] - b[0]) + double(a[1] - b[1]) * (a[1] - b[1]); };
    auto uv_of = [&](uint32_t v) { return &attributes[v * attributeCount + uvAttribute]; };
    std::vector<uint32_t> uvIsland;
    std::unordered_map<uint32_t, std::vector<uint32_t>> sourceWedges;  // position -> its source wedges, where it has several
    std::vector<float> uvStretch;  // per source vertex: the most UV length per unit of length along its source edges
    std::vector<uint8_t> severalWedges;  // per position (a source vertex's id): whether the source has several wedges there
    std::once_flag uvIslandsMade;
    auto make_uv_islands = [&] {
        uvIsland.resize(vertexCount);
        for (size_t v = 0; v < vertexCount; ++v) uvIsland[v] = uint32_t(v);
        auto find = [&](uint32_t v) {
            while (uvIsland[v] != v) v = uvIsland[v] = uvIsland[uvIsland[v]];  // path halving
            return v;
        };
        auto unite = [&](uint32_t a, uint32_t b) {
            a = find(a), b = find(b);
            if (a != b) uvIsland[std::max(a, b)] = std::min(a, b);
        };
        uvStretch.assign(vertexCount, 0.0f);
        for (size_t i = 0; i < sourceIndices.size(); i += 3) {
            unite(sourceIndices[i], sourceIndices[i + 1]), unite(sourceIndices[i], sourceIndices[i + 2]);
            for (int e = 0; e < 3; ++e) {
                const uint32_t a = sourceIndices[i + e], b = sourceIndices[i + (e + 1) % 3];
                const float stretch = float(std::sqrt(uv_distance2(&uvs[2 * a], &uvs[2 * b]) / std::max(distance2(&local[3 * a], &local[3 * b]), 1e-300)));
                uvStretch[a] = std::max(uvStretch[a], stretch), uvStretch[b] = std::max(uvStretch[b], stretch);
            }
        }
        // Wedges: the vertices that are not the first at their position (few), with the first and with each other.
        std::vector<uint32_t> wedges;
        severalWedges.assign(vertexCount, 0);
        for (size_t v = 0; v < vertexCount; ++v)
            if (positionId[v] != v) wedges.push_back(uint32_t(v)), severalWedges[positionId[v]] = 1;
        auto wedge_key = [&](uint32_t v) { return std::tuple(positionId[v], uvs[2 * v], uvs[2 * v + 1]); };
        for (uint32_t v : wedges)
            if (wedge_key(v) == wedge_key(positionId[v])) unite(v, positionId[v]);
        std::sort(wedges.begin(), wedges.end(), [&](uint32_t a, uint32_t b) { return std::pair(wedge_key(a), a) < std::pair(wedge_key(b), b); });
        for (size_t i = 1; i < wedges.size(); ++i)
            if (wedge_key(wedges[i]) == wedge_key(wedges[i - 1])) unite(wedges[i], wedges[i - 1]);
        for (size_t v = 0; v < vertexCount; ++v) uvIsland[v] = find(uint32_t(v));
        // The source's own wedges (vertices the grid weld kept) of each position that has several: a group's corner may
        // take one its group does not hold (the other side of a seam inside a chart).
        for (uint32_t v : wedges)
            if (weld[v] == v)
                for (uint32_t w : {positionId[v], v}) {
                    auto& list = sourceWedges[positionId[v]];
                    if (weld[w] == w && std::find(list.begin(), list.end(), w) == list.end()) list.push_back(w);
                }
    };

    std::vector<uint32_t> pending;
    add_clusters(split_level_zero(sourceIndices, local), nullptr, 0.0f, 0, -1, pending);
    phases.mark("level0 clusters");

    // `indices` with each vertex replaced by the first vertex in them of the same position and material, and of the
    // same colour unless `colours`, the same texture coordinates unless `texcoords`: wedges that differ only in those
    // attributes and their normals become one (see the seam retry below).
    auto weld_seams = [&](const std::vector<uint32_t>& indices, bool colours, bool texcoords) {
        // The attributes that must match: after the normal, none with `texcoords`, the UVs only with `colours`.
        const size_t compareFrom = texcoords ? attributeCount : colours ? uvAttribute : 3;
        std::unordered_map<uint32_t, std::vector<uint32_t>> firstAt;  // position -> its representatives, in order
        std::vector<uint32_t> welded(indices.size());
        for (size_t i = 0; i < indices.size(); ++i) {
            const uint32_t v = indices[i];
            std::vector<uint32_t>& reps = firstAt[positionId[v]];
            auto same = [&](uint32_t r) {
                return material_of(attributeOf[r]) == material_of(attributeOf[v]) &&
                       std::equal(attributes.begin() + r * attributeCount + compareFrom, attributes.begin() + (r + 1) * attributeCount,
                                  attributes.begin() + v * attributeCount + compareFrom);
            };
            const auto found = std::find_if(reps.begin(), reps.end(), same);
            welded[i] = found == reps.end() ? v : *found;
            if (found == reps.end()) reps.push_back(v);
        }
        return welded;
    };
    // The largest edge of a triangle of the `count` corners at `out` that samples across a UV border, whichever
    // simplification made it (meshoptimizer's, with seams kept, makes some too): its corners' wedges in different
    // islands of the source (uvIsland), or a corner on the far side of a seam inside the chart (a sphere's wrap: its
    // position has another wedge in the island, nearer in UV to the other corners by half). Such a triangle's size
    // (sampling_size) is the error it makes. `stretched`: also an edge whose UVs stretch more than twice what the
    // source's edges at its ends do (restore_uv_islands' test for the corners it picked; elsewhere a coarse level's edges
    // near a sphere's poles stretch that much without crossing anything).
    auto border_sampling_error = [&](const uint32_t* out, size_t count, bool stretched) {
        std::call_once(uvIslandsMade, make_uv_islands);
        auto far_side = [&](const uint32_t* corners, int k, uint32_t island) {
            const auto wedges = sourceWedges.find(positionId[corners[k]]);
            if (wedges == sourceWedges.end()) return false;
            const float* a = uv_of(corners[(k + 1) % 3]);
            const float* b = uv_of(corners[(k + 2) % 3]);
            const float middle[2] = {0.5f * (a[0] + b[0]), 0.5f * (a[1] + b[1])};
            const double own = uv_distance2(uv_of(corners[k]), middle);
            for (uint32_t w : wedges->second)
                if (uvIsland[attributeOf[w]] == island && 4.0 * uv_distance2(uv_of(w), middle) < own) return true;
            return false;
        };
        float worst = 0;
        for (size_t t = 0; t < count; t += 3) {
            const uint32_t island = uvIsland[attributeOf[out[t]]];
            bool consistent = uvIsland[attributeOf[out[t + 1]]] == island && uvIsland[attributeOf[out[t + 2]]] == island;
            for (int k = 0; k < 3 && consistent; ++k) {
                const uint32_t a = out[t + k], b = out[t + (k + 1) % 3];
                const double stretch = 2.0 * std::max(uvStretch[attributeOf[a]], uvStretch[attributeOf[b]]);
                consistent = stretched ? uv_distance2(uv_of(a), uv_of(b)) <= stretch * stretch * distance2(&local[3 * a], &local[3 * b]) + 1e-12
                                       : !far_side(&out[t], k, island);
            }
            if (!consistent) worst = std::max(worst, float(sampling_size(&local[3 * out[t]], &local[3 * out[t + 1]], &local[3 * out[t + 2]])));
        }
        return worst;
    };
    // After a simplification of `indices` with every wedge welded: gives each corner of the `count` corners at `out`
    // back a wedge of its position in one UV island of the source (uvIsland), the island that most of its triangle's
    // corners have a wedge in (ties: the first island). Where a position has several wedges in that island (a seam
    // inside a chart, such as a sphere's wrap), the corners take those nearest in UV to the triangle's first corner in
    // it. Returns the largest edge of a triangle whose corners found no common island, or whose UVs stretch more than
    // twice what the source's edges at its corners do (its corners on two sides of a seam inside a chart): such a
    // triangle samples across a border, and its size is the error that makes.
    auto restore_uv_islands = [&](const std::vector<uint32_t>& indices, uint32_t* out, size_t count) {
        std::call_once(uvIslandsMade, make_uv_islands);
        auto island_of = [&](uint32_t v) { return uvIsland[attributeOf[v]]; };
        // position -> its wedges (one per UV and material): the group's, then the source's others
        std::unordered_map<uint32_t, std::vector<uint32_t>> wedges;
        for (uint32_t v : weld_seams(indices, true, false)) {
            auto& list = wedges[positionId[v]];
            if (std::find(list.begin(), list.end(), v) != list.end()) continue;
            if (list.empty())
                if (auto source = sourceWedges.find(positionId[v]); source != sourceWedges.end()) list = source->second;
            if (std::find(list.begin(), list.end(), v) == list.end()) list.push_back(v);
        }
        // The wedge of `corner`'s position and material in `island` nearest in UV to `near` (the first where null), and
        // how many it had to choose from.
        auto wedge_in = [&](uint32_t corner, uint32_t island, const float* near, int* choices = nullptr) {
            uint32_t best = UINT32_MAX;
            double bestDistance = INFINITY;
            if (choices) *choices = 0;
            for (uint32_t v : wedges[positionId[corner]]) {
                if (island_of(v) != island || material_of(attributeOf[v]) != material_of(attributeOf[corner])) continue;
                if (choices) ++*choices;
                if (!near) {
                    if (best == UINT32_MAX) best = v;
                    continue;
                }
                const double d = uv_distance2(uv_of(v), near);
                if (d < bestDistance) best = v, bestDistance = d;
            }
            return best;
        };
        for (size_t t = 0; t < count; t += 3) {
            uint32_t island = UINT32_MAX;
            int most = 0;
            for (int k = 0; k < 3; ++k)
                for (uint32_t candidate : wedges[positionId[out[t + k]]]) {
                    int corners = 0;
                    for (int j = 0; j < 3; ++j) corners += wedge_in(out[t + j], island_of(candidate), nullptr) != UINT32_MAX;
                    if (corners > most || (corners == most && island_of(candidate) < island)) most = corners, island = island_of(candidate);
                }
            // The corners with one wedge in the island first: the first of them anchors the others' choices.
            int choices[3];
            uint32_t chosen[3];
            const float* anchor = nullptr;
            for (int k = 0; k < 3; ++k) {
                chosen[k] = wedge_in(out[t + k], island, nullptr, &choices[k]);
                if (!anchor && choices[k] == 1) anchor = uv_of(chosen[k]);
            }
            for (int k = 0; k < 3; ++k) {
                if (chosen[k] == UINT32_MAX) continue;
                if (choices[k] > 1 && anchor) chosen[k] = wedge_in(out[t + k], island, anchor);
                if (!anchor) anchor = uv_of(chosen[k]);
                out[t + k] = chosen[k];
            }
        }
        return border_sampling_error(out, count, true);
    };
    // After a simplification with texture-coordinate seams kept: each corner of the `count` corners at `out` at a
    // position where the group (`indices`) has several wedges in its UV island that differ only in texture coordinates
    // takes the one nearest in UV to its triangle's other corners. A pole where each face has its own u (as modelling
    // packages map spheres) keeps its triangles' corners as their faces had them, so a coarse triangle there took the
    // u of one of the many faces it replaced: its texture sheared, and border_sampling_error counted its size as error
    // (level 5 of a 90 k-triangle sphere claimed 3.1 % of its size; now 0.75 %, as without texture coordinates). The
    // same positions and the same islands: no crack, no new border; every corner stays a vertex of the group's input.
    auto rewedge_toward_triangles = [&](const std::vector<uint32_t>& indices, uint32_t* out, size_t count) {
        std::call_once(uvIslandsMade, make_uv_islands);
        auto same_but_uvs = [&](uint32_t a, uint32_t b) {
            return uvIsland[attributeOf[a]] == uvIsland[attributeOf[b]] && material_of(attributeOf[a]) == material_of(attributeOf[b]) &&
                   std::equal(attributes.begin() + a * attributeCount, attributes.begin() + a * attributeCount + uvAttribute,
                              attributes.begin() + b * attributeCount);
        };
        auto several = [&](uint32_t position) { return position < severalWedges.size() && severalWedges[position]; };
        std::unordered_map<uint32_t, std::vector<uint32_t>> wedges;  // position -> the group's vertices there (the source has several)
        for (uint32_t v : indices)
            if (several(positionId[v])) {
                std::vector<uint32_t>& list = wedges[positionId[v]];
                if (std::find(list.begin(), list.end(), v) == list.end()) list.push_back(v);
            }
        if (wedges.empty()) return;
        for (size_t t = 0; t < count; t += 3)
            for (int k = 0; k < 3; ++k) {
                const uint32_t position = positionId[out[t + k]];
                if (!several(position)) continue;
                const auto found = wedges.find(position);
                if (found == wedges.end() || found->second.size() < 2) continue;
                if (positionId[out[t + (k + 1) % 3]] == position || positionId[out[t + (k + 2) % 3]] == position) continue;  // no area
                const float* a = uv_of(out[t + (k + 1) % 3]);
                const float* b = uv_of(out[t + (k + 2) % 3]);
                const float middle[2] = {0.5f * (a[0] + b[0]), 0.5f * (a[1] + b[1])};
                uint32_t best = out[t + k];
                double nearest = uv_distance2(uv_of(best), middle);
                for (uint32_t w : found->second)
                    if (w != best && same_but_uvs(w, out[t + k]))
                        if (const double d = uv_distance2(uv_of(w), middle); d < nearest) best = w, nearest = d;
                out[t + k] = best;
            }
    };
    std::vector<unsigned char> lock(vertexCount, 0);
    std::vector<int32_t> firstGroup(vertexCount, -1);
    std::vector<unsigned char> shared(vertexCount, 0);
    std::vector<uint32_t> roundPosition;  // a position's number in the round's partition input
    std::vector<uint32_t> keptBy, measuredBy;  // per vertex, the last group (by stamp) that kept or measured it
    uint32_t stamps = 0;                       // groups numbered so far, over all rounds
    // The grid coordinates' range (Preserve Area moves open borders by at most a quarter of a group's size: twice it).
    double farthest = 0;
    for (int k = 0; k < 3; ++k) farthest = std::max({farthest, std::fabs(lo[k] - out.origin[k]), std::fabs(hi[k] - out.origin[k])});
    const uint64_t largestGrid = (uint64_t(std::ceil(farthest / step)) + 1) * (settings.preserveArea ? 2 : 1);
    const UnitBytesBound unitBound{UnitBytesBound::residual_bits(largestGrid), hasUvs ? UnitBytesBound::residual_bits(largestUv) : 0, hasColors,
                                   !vertexMaterial.empty()};
    // Where a round's time goes, group by group (TESSERA_BUILD_PHASES=1): gathering its triangles, simplifying (with
    // the seam retries), fitting attributes (with its positions' topology), Preserve Area and re-splitting, measuring
    // from the source and to it.
    enum GroupStep : size_t { kGatherStep, kSimplifyStep, kFitStep, kSplitStep, kDeviationStep, kStrayStep, kGroupSteps };
    StepTotals<kGroupSteps> groupSteps({"gather", "simplify", "fit", "split", "deviation", "stray"});
    while (pending.size() > 1) {
        // Group the pending clusters by shared positions.
        const size_t roundVertices = local.size() / 3;  // vertices added this round are numbered from here
        std::vector<unsigned int> partition(pending.size(), 0);
        size_t groupCount = 1;
        // Each cluster's distinct positions in order of first use (about a fifth of its corners): what the partition
        // and the border locks look at.
        std::vector<std::vector<uint32_t>> distinct(pending.size());
        std::vector<size_t> unitBytes(pending.size());  // each cluster's UnitBytesBound, first with as many vertices as it may have
        parallel_for(pending.size(), [&](size_t i) {
            const std::vector<uint32_t>& indices = clusters[pending[i]].indices;
            std::vector<uint32_t> cornerPositions(indices.size());
            for (size_t k = 0; k < cornerPositions.size(); ++k) cornerPositions[k] = positionId[indices[k]];
            number_by_first_use(cornerPositions, distinct[i]);
            unitBytes[i] = unitBound.cluster(uint32_t(std::min<size_t>(kClusterVertices, indices.size())), uint32_t(indices.size() / 3));
        });
        if (pending.size() > kGroupSize) {
            // The positions numbered for this round only: meshoptimizer's partitioner counts a position once per
            // cluster and only compares numbers, so the partition is the one every corner of the mesh's numbering
            // gives, while its tables (sized by the vertex count) and loops shrink to the round's own positions.
            std::vector<unsigned int> clusterIndices, counts(pending.size());
            uint32_t positions = 0;
            roundPosition.resize(roundVertices, UINT32_MAX);
            for (size_t i = 0; i < pending.size(); ++i) {
                for (uint32_t p : distinct[i]) {
                    if (roundPosition[p] == UINT32_MAX) roundPosition[p] = positions++;
                    clusterIndices.push_back(roundPosition[p]);
                }
                counts[i] = unsigned(distinct[i].size());
            }
            groupCount = meshopt_partitionClusters(partition.data(), clusterIndices.data(), clusterIndices.size(), counts.data(), pending.size(), positions, kGroupSize);
            for (const auto& list : distinct)
                for (uint32_t p : list) roundPosition[p] = UINT32_MAX;
        }
        groupCount = split_groups_beyond_a_page(partition, groupCount, unitBytes, [&](size_t i) {
            const std::vector<uint32_t>& indices = clusters[pending[i]].indices;
            uint32_t vertices = 0;
            visit_first_uses(indices, [](uint32_t) {}, [&](uint32_t) { ++vertices; });
            return unitBound.cluster(vertices, uint32_t(indices.size() / 3));
        });
        std::vector<std::vector<uint32_t>> members(groupCount);
        for (size_t i = 0; i < pending.size(); ++i) members[partition[i]].push_back(pending[i]);
        phases.mark("round: partition");

        // Positions used by more than one group are the group borders: locked while simplifying. The locks are set
        // for the whole round; while the groups simplify in parallel, each writes only its own interior vertices' locks
        // (pins), which no other group reads.
        // Whether a position is shared does not depend on the order the clusters are visited in. The locks are written
        // on every core (a vertex of two clusters gets the same value from both: relaxed atomic stores).
        for (size_t i = 0; i < pending.size(); ++i)
            for (uint32_t p : distinct[i]) {
                if (firstGroup[p] < 0) firstGroup[p] = int32_t(partition[i]);
                else if (firstGroup[p] != int32_t(partition[i])) shared[p] = 1;
            }
        parallel_for(pending.size(), [&](size_t i) {
            for (uint32_t v : clusters[pending[i]].indices)
                std::atomic_ref<unsigned char>(lock[v]).store(shared[positionId[v]] ? kBorderLock : 0, std::memory_order_relaxed);
        });

        struct Result {
            bool simplified = false;
            float error = 0;
            std::vector<std::vector<uint32_t>> pieces;
            Dilation dilation;  // its new vertices are numbered from roundVertices until recorded
            std::vector<FittedAttributes> fitted;  // its interior kept vertices' fitted normals and channel
            float measured = 0;  // its measured distance from the source (deviation.h)
            std::vector<std::vector<SourcePoint>> carried;  // per piece, the source points it carries up
        };
        std::vector<Result> results(groupCount);
        // Which group kept, and which measured, each interior vertex (deviation.h), by its number across rounds, so the
        // marks are never cleared: a group's interior vertices are its own, so the groups mark them in parallel without
        // a race (border vertices, locked, are kept and not marked).
        keptBy.resize(roundVertices, UINT32_MAX);
        measuredBy.resize(roundVertices, UINT32_MAX);
        const uint32_t firstStamp = stamps;
        stamps += uint32_t(groupCount);
        phases.mark("round: locks");
        // The values vertices are drawn with (fit_attributes' targets and starting point).
        const VertexTable drawnNormals{mesh.normals.data(), uint32_t(vertexCount), fittedNormals.data(), drawnOf.data(), 3};
        const VertexTable drawnChannels{mesh.colors.data(), uint32_t(vertexCount), fittedChannels.data(), drawnOf.data(), kChannelComponents};
        parallel_for(groupCount, [&](size_t g) {
            StepTotals<kGroupSteps>::Lap lap(groupSteps);
            std::vector<uint32_t> merged;
            for (uint32_t c : members[g]) merged.insert(merged.end(), clusters[c].indices.begin(), clusters[c].indices.end());
            std::vector<uint32_t> simplified(merged.size());
            float error = 0;
            const size_t target = (merged.size() / 3 / 2) * 3;
            float groupWeights[kMaxAttributes];
            std::copy_n(weights, kMaxAttributes, groupWeights);
            if (hasUvs) {
                float lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
                for (uint32_t v : merged)
                    for (int k = 0; k < 2; ++k) {
                        lo[k] = std::min(lo[k], attributes[v * attributeCount + uvAttribute + k]);
                        hi[k] = std::max(hi[k], attributes[v * attributeCount + uvAttribute + k]);
                    }
                const float span = std::max({hi[0] - lo[0], hi[1] - lo[1], float(std::ldexp(1.0, out.uvPrecision))});
                groupWeights[uvAttribute] = groupWeights[uvAttribute + 1] = kUvWeight / span;
            }
            auto simplify = [&](const std::vector<uint32_t>& from, size_t to, float& passError) {
                passError = 0;
                return meshopt_simplifyWithAttributes(simplified.data(), from.data(), from.size(), local.data(), roundVertices, 12, attributes.data(),
                                                      attributeCount * sizeof(float), groupWeights, attributeCount, lock.data(), to, FLT_MAX,
                                                      meshopt_SimplifySparse | meshopt_SimplifyErrorAbsolute, &passError);
            };
            double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
            grow_box([&](size_t i) { return &local[3 * size_t(merged[i])]; }, 0, merged.size(), lo, hi);
            const double diameter = std::sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) + (hi[2] - lo[2]) * (hi[2] - lo[2]));
            auto stuck = [&](size_t count) { return double(count) > kStuckRatio * double(merged.size()); };
            // One simplification of `input` (the group's triangles, or them with normal seams welded) into `simplified`:
            // returns the corners kept, and the error in `runError`.
            auto simplify_group = [&](const std::vector<uint32_t>& input, float& runError) -> size_t {
                runError = 0;
                if (maxEdge <= 0) return simplify(input, target, runError);
                // The edge length limit: simplify in steps of a fifth, so that each step makes few long edges; a step
                // that made one is redone with the vertices that split such edges pinned. The errors of the steps add up.
                std::vector<uint32_t> current = input, pinned;
                while (current.size() > target) {
                    const size_t stepTarget = std::max(target, (current.size() / 3 * 4 / 5) * 3);
                    size_t stepKept = 0;
                    float stepError = 0;
                    for (int attempt = 0; attempt <= kPinRounds; ++attempt) {
                        stepKept = simplify(current, stepTarget, stepError);
                        const EdgeCheck check = check_edge_lengths(input, current, simplified.data(), stepKept, local, positionId, lock, maxEdge);
                        if (!check.tooLong) break;
                        stepKept = current.size();  // rejected: retried with the splitting vertices pinned, if any
                        for (uint32_t v : check.pins) {
                            lock[v] = kPinned;
                            pinned.push_back(v);
                        }
                        if (check.pins.empty()) break;
                    }
                    if (stepKept >= current.size()) break;  // the limit allows no further step
                    current.assign(simplified.begin(), simplified.begin() + stepKept);
                    runError += stepError;
                }
                for (uint32_t v : pinned) lock[v] = 0;
                std::copy(current.begin(), current.end(), simplified.begin());
                return current.size();
            };
            lap.lap(kGatherStep);
            size_t kept = simplify_group(merged, error);
            // Normal and colour seams (wedges of one position that differ only in their normals, by more than the grid
            // weld's 30 degrees, or in their colours) let the simplifier collapse only along them. Where that left the
            // group stuck, or straying by a quarter of its size (flat shading or colour per face, the needle poles of a
            // latitude-longitude sphere), it simplifies again with its normal seams welded, then also its colour seams,
            // and keeps the better result: that level then has one normal (and colour) per position there, a hard edge
            // turned smooth, colours blended as distance blends them; no new crack (positions and locks are the wedges').
            // Simplifies `welded` instead, and keeps that where it is better (not stuck where the first was, or less
            // error); `restore(count)` fixes the welded result up first and returns the error that adds.
            auto retry_welded = [&](const std::vector<uint32_t>& welded, auto restore) {
                const std::vector<uint32_t> seamed(simplified.begin(), simplified.begin() + kept);
                float weldedError = 0;
                const size_t weldedKept = simplify_group(welded, weldedError);
                if (!stuck(weldedKept)) weldedError = std::max(weldedError, restore(weldedKept));
                const bool better = stuck(kept) ? !stuck(weldedKept) : !stuck(weldedKept) && weldedError < error;
                if (better) {
                    kept = weldedKept;
                    error = weldedError;
                } else {
                    std::copy(seamed.begin(), seamed.end(), simplified.begin());
                }
            };
            auto held_back = [&] { return stuck(kept) || double(error) > kSeamRetryError * diameter; };
            for (const bool colours : {false, true}) {
                if (!held_back() || (colours && !hasColors)) break;
                const std::vector<uint32_t> welded = weld_seams(merged, colours, false);
                if (welded != merged) retry_welded(welded, [](size_t) { return 0.0f; });
            }
            // Texture-coordinate seams last, only where the others left the group stuck or straying: it simplifies with
            // every wedge of a position welded (texture coordinates weighed 0), and each corner then takes back a wedge in
            // one UV island (restore_uv_islands). Where a triangle's corners share no island it samples across an island
            // border: its size counts as error, so that level is drawn only where such a triangle covers under a pixel.
            if (hasUvs && held_back()) {
                const std::vector<uint32_t> welded = weld_seams(merged, true, true);
                if (welded != merged) {
                    groupWeights[uvAttribute] = groupWeights[uvAttribute + 1] = 0;
                    retry_welded(welded, [&](size_t count) { return restore_uv_islands(merged, simplified.data(), count); });
                }
            }
            if (hasUvs) {
                rewedge_toward_triangles(merged, simplified.data(), kept);
                error = std::max(error, border_sampling_error(simplified.data(), kept, false));
            }
            // Dropping whole free parts makes no new edge.
            if (kept > target) kept = drop_free_components(simplified, kept, target, local, positionId, lock, error);
            lap.lap(kSimplifyStep);
            if (kept == 0 || stuck(kept)) return;  // stuck (vanishing too: keep a root)
            // The simplified surface is made of the group's own vertices, so it cannot stray further than the group's
            // extent; the simplifier's attribute terms can report more on slivers. Clamp to the group's diameter.
            error = std::min(error, float(diameter));
            simplified.resize(kept);
            Result& result = results[g];
            // Normals and vertex channel fitted to the group's input (attribute_fit.h), on the simplified surface before
            // Preserve Area moves its open borders (a moved copy is drawn with its source's values).
            const GroupPositions groupPositions(merged, simplified.data(), simplified.size(), positionId);
            result.fitted = fit_attributes(merged, simplified.data(), simplified.size(), groupPositions, local, lock, drawnNormals,
                                           hasColors ? &drawnChannels : nullptr);
            lap.lap(kFitStep);
            if (settings.preserveArea) {
                result.dilation = dilate_open_borders(simplified, local, positionId, lock, covered_area(merged, local, positionId), diameter / 4, step,
                                                      uint32_t(roundVertices));
                error += result.dilation.displacement;  // the moved border strays that much further from the children
            }
            const std::vector<float>& moved = result.dilation.positions;
            auto position = [&](uint32_t v) { return v < roundVertices ? &local[3 * v] : &moved[3 * (v - roundVertices)]; };
            result.simplified = true;
            result.error = error;
            std::vector<uint32_t> pieceOf;  // per triangle of `simplified`
            result.pieces = split_into_clusters(simplified, position, &pieceOf);
            lap.lap(kSplitStep);
            // The group's distance from the source (deviation.h): from its input vertices that simplification removed
            // and the points its children carried up to its triangles, and from its edges' midpoints to its input
            // triangles; each new cluster carries up the points nearest it that stray most.
            auto interior = [&](uint32_t v) { return v < roundVertices && lock[v] != kBorderLock; };
            const uint32_t stamp = firstStamp + uint32_t(g);
            std::vector<SourcePoint> points;
            auto measure_vertex = [&](uint32_t v) {
                if (interior(v) && keptBy[v] != stamp && measuredBy[v] != stamp) {
                    measuredBy[v] = stamp;
                    points.push_back({{local[3 * v], local[3 * v + 1], local[3 * v + 2]}, 0.0f, v});
                }
            };
            if (groupPositions.outputInInput && moved.empty()) {
                // Over the group's positions: one alone at its position is kept iff the output has triangles there, and
                // is met first where its position is (slots are numbered by first use), so the points come in the same
                // order; only the wedges of a seam need the marks by vertex.
                const std::vector<uint32_t>& slotOf = groupPositions.corners;
                const std::vector<char>& seam = groupPositions.seam;
                const Rows& fan = groupPositions.outputFan;
                for (size_t i = 0; i < simplified.size(); ++i)
                    if (seam[groupPositions.outputCorners[i]] && interior(simplified[i])) keptBy[simplified[i]] = stamp;
                uint32_t slotsMet = 0;
                for (size_t i = 0; i < merged.size(); ++i) {
                    const uint32_t slot = slotOf[i];
                    if (seam[slot]) {
                        slotsMet += slot == slotsMet;
                        measure_vertex(merged[i]);
                    } else if (slot == slotsMet) {
                        ++slotsMet;
                        const uint32_t v = merged[i];
                        if (fan.start[slot] == fan.start[slot + 1] && interior(v)) points.push_back({{local[3 * v], local[3 * v + 1], local[3 * v + 2]}, 0.0f, v});
                    }
                }
            } else {
                for (uint32_t v : simplified)
                    if (interior(v)) keptBy[v] = stamp;
                for (uint32_t v : merged) measure_vertex(v);
            }
            for (uint32_t c : members[g]) points.insert(points.end(), clusters[c].carried.begin(), clusters[c].carried.end());
            std::vector<float> triangleCorners;
            for (uint32_t v : simplified) triangleCorners.insert(triangleCorners.end(), position(v), position(v) + 3);
            Deviation deviation = measure_deviation(groupPositions, triangleCorners, simplified.data(), pieceOf, result.pieces.size(), points,
                                                    positionId, kCarriedPoints);
            // The simplified edges' midpoints from the input, where they stray further than the group's error so far
            // (its own, its children's, the first way's); before Preserve Area moved the open borders (its
            // displacement is in the error already).
            lap.lap(kDeviationStep);
            float known = std::max(error, deviation.largest);
            for (uint32_t c : members[g]) known = std::max(known, clusters[c].lodError);
            result.measured = measure_stray(groupPositions, local, known);
            result.carried = std::move(deviation.kept);
            lap.lap(kStrayStep);
        });

        phases.mark("round: simplify+split");
        // Record the groups in order, so the output does not depend on thread timing.
        std::vector<uint32_t> next;
        bool progress = false;
        for (size_t g = 0; g < groupCount; ++g) {
            if (!results[g].simplified) {
                next.insert(next.end(), members[g].begin(), members[g].end());  // retried with other neighbours next round
                continue;
            }
            progress = true;
            std::vector<Sphere> childSpheres;
            float childError = 0;
            uint32_t childLevel = 0;
            for (uint32_t c : members[g]) {
                childSpheres.push_back(clusters[c].lodSphere);
                childError = std::max(childError, clusters[c].lodError);
                childLevel = std::max(childLevel, clusters[c].level);
                clusters[c].parentGroup = int32_t(groups.size());
            }
            // Monotone by construction: the parent's error is at least the largest child's, and its sphere encloses
            // every child's. Its own: the distance measured from the source (deviation.h), or the simplifier's error
            // where that is larger (it weighs normals, colours and texture coordinates; the seam and Preserve Area
            // terms above are in it). Not their sum: summed level by level, errors claimed 1.5-2.3x the distance from
            // the source at coarse levels, and the cut drew twice the triangles a pixel of error needs
            // (docs/benchmarks.md, session 34).
            const Group group{enclose(childSpheres), std::max({childError, results[g].error, results[g].measured})};
            groups.push_back(group);
            const uint32_t groupIndex = uint32_t(groups.size() - 1);
            auto add_fit = [&](uint32_t vertex, const float* normal, const float* channel) {  // drawn so from this group's clusters on
                drawnOf[vertex] = uint32_t(vertexCount + fits.size());
                fits.push_back({groupIndex, vertex});
                fittedNormals.insert(fittedNormals.end(), normal, normal + 3);
                if (hasColors) fittedChannels.insert(fittedChannels.end(), channel, channel + kChannelComponents);
            };
            for (const FittedAttributes& fitted : results[g].fitted) add_fit(fitted.vertex, fitted.normal.data(), fitted.channel.data());
            // Vertices moved by Preserve Area join the mesh, numbered after those recorded so far, each drawn with its
            // source's values (this group's fit included).
            const Dilation& dilation = results[g].dilation;
            const uint32_t shift = uint32_t(local.size() / 3 - roundVertices);
            for (size_t i = 0; i < dilation.sources.size(); ++i) {
                const uint32_t id = uint32_t(local.size() / 3), source = dilation.sources[i];
                local.insert(local.end(), &dilation.positions[3 * i], &dilation.positions[3 * i] + 3);
                for (size_t k = 0; k < attributeCount; ++k) {
                    const float value = attributes[source * attributeCount + k];  // a copy: push_back may reallocate
                    attributes.push_back(value);
                }
                attributeOf.push_back(attributeOf[source]);
                drawnOf.push_back(drawnOf[source]);
                if (drawnOf[source] >= vertexCount) {  // a fit's values: copied, since the arrays may grow
                    const size_t fit = drawnOf[source] - vertexCount;
                    std::array<float, 3> normal;
                    std::array<float, kChannelComponents> channel{};
                    std::copy_n(&fittedNormals[3 * fit], 3, normal.data());
                    if (hasColors) std::copy_n(&fittedChannels[kChannelComponents * fit], kChannelComponents, channel.data());
                    add_fit(id, normal.data(), channel.data());
                }
                positionId.push_back(welder.add(&local[3 * id], id));
                lock.push_back(0);
                firstGroup.push_back(-1);
                shared.push_back(0);
            }
            if (shift) {
                for (auto& piece : results[g].pieces)
                    for (uint32_t& v : piece)
                        if (v >= roundVertices) v += shift;
                for (auto& carried : results[g].carried)
                    for (SourcePoint& point : carried)
                        if (point.anchor >= roundVertices) point.anchor += shift;
            }
            add_clusters(std::move(results[g].pieces), &group.sphere, group.error, childLevel + 1, int32_t(groups.size() - 1), next,
                         std::move(results[g].carried));
        }
        for (const auto& list : distinct)
            for (uint32_t p : list) {
                firstGroup[p] = -1;
                shared[p] = 0;
            }
        parallel_for(pending.size(), [&](size_t i) {
            for (uint32_t v : clusters[pending[i]].indices) std::atomic_ref<unsigned char>(lock[v]).store(0, std::memory_order_relaxed);
        });
        phases.mark("round: record");
        if (!progress) break;
        pending = std::move(next);
    }

    // Trimming and the fallback mesh: cuts of the whole DAG, by error (in percent of the mesh size) and triangles.
    std::vector<DagNode> nodes(clusters.size());
    for (size_t i = 0; i < clusters.size(); ++i) {
        const WorkCluster& w = clusters[i];
        nodes[i] = {w.lodError, w.parentGroup >= 0 ? groups[w.parentGroup].error : INFINITY, w.level, uint32_t(w.indices.size() / 3), w.madeBy,
                    w.parentGroup};
    }
    const double percentOfSize = out.size / 100.0, sourceTriangles = double(out.sourceTriangles);
    const DagCut leafCut = choose_cut(nodes, settings.trimRelativeError * percentOfSize, settings.keepTrianglePercent / 100.0 * sourceTriangles);
    const DagCut fallbackCut = coarser(leafCut, choose_cut(nodes, settings.fallbackRelativeError * percentOfSize,
                                                           settings.fallbackTrianglePercent / 100.0 * sourceTriangles));
    const TrimPlan plan = plan_trim(nodes, groups.size(), leafCut);
    out.groups = plan.groups;
    out.leafError = measure(nodes, leafCut).error;
    groupSteps.print("the rounds' groups");
    phases.mark("cuts");
    // What only the rounds needed goes before the emit, whose streams are the build's last large allocations: the
    // source points clusters carried, the source triangles, the simplifier's attributes, the welds, locks and marks,
    // the UV islands. (The 1 M-triangle sphere with face-varying texture coordinates peaked at 196 B/tri there.)
    parallel_for(clusters.size(), [&](size_t i) { release(clusters[i].carried); });
    release(sourceIndices), release(attributes), release(positionId), release(weld), release(drawnOf);
    release(lock), release(firstGroup), release(shared), release(roundPosition), release(keptBy), release(measuredBy);
    release(uvIsland), release(uvStretch), release(severalWedges);
    sourceWedges = {};
    welder = {};

    // Emit: cluster-local vertex streams and 8-bit triangles, level 0 first (clusters were created in level order
    // per round; a stable sort by level keeps that order within a level), each cluster in page order. Trimmed
    // clusters are left out. Clusters are ordered and their vertices encoded on every core; only the offsets are
    // counted in order.
    std::vector<uint32_t> order;
    for (uint32_t i = 0; i < clusters.size(); ++i)
        if (plan.level[i] >= 0) order.push_back(i);
    std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return plan.level[a] < plan.level[b]; });
    std::vector<std::vector<uint32_t>> clusterVertices(order.size()), clusterTriangles(order.size());  // mesh vertices; packed triangles
    std::vector<Cluster> emitted(order.size());
    parallel_for(order.size(), [&](size_t i) {
        const uint32_t id = order[i];
        const WorkCluster& w = clusters[id];
        std::vector<uint32_t>& vertices = clusterVertices[i];
        std::vector<uint32_t> corners = number_by_first_use(w.indices, vertices);
        std::vector<uint32_t> pageOrder = order_cluster_for_pages(corners, uint32_t(vertices.size()));
        for (uint32_t& v : pageOrder) v = vertices[v];  // cluster-local numbers to mesh vertices
        vertices.swap(pageOrder);
        clusterTriangles[i].resize(corners.size() / 3);
        for (size_t k = 0; k < corners.size(); k += 3)
            clusterTriangles[i][k / 3] = corners[k] | (corners[k + 1] << 8) | (corners[k + 2] << 16) |
                                         (vertexMaterial.empty() ? 0u : material_of(attributeOf[vertices[corners[k]]]) << 24);
        Cluster& c = emitted[i];
        c.vertexCount = uint32_t(vertices.size());
        c.triangleCount = uint32_t(w.indices.size() / 3);
        c.sphere = to_float(vertex_sphere(local, vertices.data(), vertices.size()));
        c.lodSphere = to_float(w.lodSphere);
        // The stored leaves are the best there is: always fine enough for the runtime cut.
        c.lodError = plan.level[id] == 0 ? 0.0f : w.lodError;
        c.level = uint32_t(plan.level[id]);
        if (w.parentGroup >= 0) {
            c.parentSphere = to_float(groups[w.parentGroup].sphere);
            c.parentError = groups[w.parentGroup].error;
            c.parentGroup = uint32_t(plan.group[w.parentGroup]);
        } else {
            c.parentSphere = c.lodSphere;
            c.parentError = std::numeric_limits<float>::infinity();
            c.parentGroup = kNoGroup;
        }
    });
    // Offsets in order, then the triangles copied into place on every core (one copy, no growth: at 10 M source
    // triangles the streams are hundreds of MB; a Stream's resize leaves them unset, so that their pages are first
    // touched there, on every core, too).
    uint32_t vertexTotal = 0, triangleTotal = 0;
    out.clusters.reserve(order.size());
    for (size_t i = 0; i < order.size(); ++i) {
        Cluster& c = emitted[i];
        c.vertexOffset = vertexTotal;
        c.triangleOffset = triangleTotal;
        vertexTotal += c.vertexCount;
        triangleTotal += c.triangleCount;
        append_cluster(out, c);
    }
    out.triangles.resize(triangleTotal);
    parallel_for(order.size(), [&](size_t i) {
        std::copy(clusterTriangles[i].begin(), clusterTriangles[i].end(), out.triangles.begin() + emitted[i].triangleOffset);
        release(clusterTriangles[i]);
    });
    phases.mark("emit: order clusters");
    out.positions.resize(3 * size_t(vertexTotal));
    out.normals.resize(vertexTotal);
    out.colors.resize(hasColors ? 2 * size_t(vertexTotal) : 0);
    out.uvs.resize(hasUvs ? 2 * size_t(vertexTotal) : 0);
    // Each normal encoded once (a vertex is stored about five times over the levels); vertices Preserve Area moved keep
    // their source's attributes, or its fit (a copy, recorded for the moved vertex when it joined the mesh).
    std::vector<uint32_t> packedNormals(vertexCount);
    parallel_blocks(vertexCount, kBlock, [&](size_t begin, size_t end) {
        for (size_t a = begin; a < end; ++a) packedNormals[a] = encode_octahedral(mesh.normals[3 * a], mesh.normals[3 * a + 1], mesh.normals[3 * a + 2]);
    });
    std::vector<uint32_t> packedFitted(fittedNormals.size() / 3);
    parallel_blocks(packedFitted.size(), kBlock, [&](size_t begin, size_t end) {
        for (size_t f = begin; f < end; ++f) packedFitted[f] = encode_octahedral(fittedNormals[3 * f], fittedNormals[3 * f + 1], fittedNormals[3 * f + 2]);
    });
    // Each vertex's fits in the order they were made (group order), and the fit whose values a cluster made by group
    // `madeBy` draws a vertex with: the latest by that group or an earlier one (kNoFit: the source's values).
    Rows fitsOf;
    fitsOf.build(local.size() / 3, [&](auto add) {
        for (uint32_t k = 0; k < fits.size(); ++k) add(fits[k].vertex, k);
    });
    constexpr uint32_t kNoFit = 0xffffffffu;
    auto fit_drawn = [&](uint32_t v, int32_t madeBy) {
        for (uint32_t k = fitsOf.start[v + 1]; k > fitsOf.start[v]; --k)
            if (int32_t(fits[fitsOf.items[k - 1]].group) <= madeBy) return fitsOf.items[k - 1];
        return kNoFit;
    };
    parallel_for(order.size(), [&](size_t i) {
        uint32_t at = emitted[i].vertexOffset;
        const int32_t madeBy = clusters[order[i]].madeBy;
        for (uint32_t v : clusterVertices[i]) {
            const uint32_t a = attributeOf[v];
            std::copy_n(&local[3 * v], 3, &out.positions[3 * size_t(at)]);
            const uint32_t fit = fit_drawn(v, madeBy);
            out.normals[at] = fit == kNoFit ? packedNormals[a] : packedFitted[fit];
            if (hasColors) {
                const float* col = fit == kNoFit ? &mesh.colors[kChannelComponents * a] : &fittedChannels[kChannelComponents * size_t(fit)];
                out.colors[2 * size_t(at)] = float_to_half(col[0]) | (uint32_t(float_to_half(col[1])) << 16);
                out.colors[2 * size_t(at) + 1] = float_to_half(col[2]) | (uint32_t(float_to_half(col[3])) << 16);
            }
            if (hasUvs) std::copy_n(&uvs[2 * a], 2, &out.uvs[2 * size_t(at)]);
            ++at;
        }
        release(clusterVertices[i]);
    });

    // Each cluster's normal cone, mean triangle area and longest edge, from its placed triangles (the page file keeps them).
    parallel_blocks(out.clusters.size(), 256, [&](size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) {
            Cluster& c = out.clusters[i];
            c.cone = cluster_normal_cone(out, c);
            const ClusterTriangleSizes sizes = cluster_triangle_sizes(out, c);
            c.meanTriangleArea = sizes.meanArea;
            c.longestEdge = sizes.longestEdge;
        }
    });
    out.sphere = to_float(all_vertices_sphere(local, kBlock));
    out.fallbackThreshold = fallbackCut.source ? -1.0f : fallbackCut.threshold;  // extracted on demand (fallback_mesh)
    out.fallbackError = measure(nodes, fallbackCut).error;
    phases.mark("emit: vertices");
    if (spent) release(spent->normals), release(spent->colors);
    return out;
}

}  // namespace

BuiltMesh build_mesh(const PreparedMesh& mesh, const BuildSettings& settings) { return build(mesh, nullptr, settings); }

BuiltMesh build_mesh(PreparedMesh&& mesh, const BuildSettings& settings) { return build(mesh, &mesh, settings); }

}  // namespace tessera
