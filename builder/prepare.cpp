// Input preparation: validation, triangulation (holes, orientation), attribute seams, normals.
#include "phase_timer.h"
#include "tessera/builder.h"

#include "subdivide.h"
#include "tessera/morton.h"
#include "tessera/parallel.h"
#include "vertex_box.h"
#include "weld.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace tessera {
namespace {

struct Vec3 {
    float x, y, z;
};
Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
Vec3 cross(Vec3 a, Vec3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
float length(Vec3 a) { return std::sqrt(a.x * a.x + a.y * a.y + a.z * a.z); }

// Where a primvar's value for one corner comes from: the value index, or -1 when the primvar has none there.
class PrimvarLookup {
public:
    PrimvarLookup(const PrimvarView& view, const MeshView& mesh, const char* what, size_t pointCount,
                  std::vector<std::string>& warnings)
        : view_(view) {
        if (view.interpolation == Interpolation::None || view.values.empty()) {
            active_ = false;
            return;
        }
        const size_t valueCount = view.values.size() / size_t(view.components);
        size_t slots = 0;
        switch (view.interpolation) {
            case Interpolation::Constant: slots = 1; break;
            case Interpolation::Uniform: slots = mesh.faceVertexCounts.size(); break;
            case Interpolation::Vertex:
            case Interpolation::Varying: slots = pointCount; break;
            case Interpolation::FaceVarying: slots = mesh.faceVertexIndices.size(); break;
            case Interpolation::None: break;
        }
        const size_t available = view.indices.empty() ? valueCount : view.indices.size();
        if (available < slots) {
            warnings.push_back(mesh.name + ": " + what + " has " + std::to_string(available) +
                               " elements but its interpolation needs " + std::to_string(slots) + "; ignored");
            active_ = false;
            return;
        }
        for (int32_t index : view.indices) {
            if (index < 0 || size_t(index) >= valueCount) {
                warnings.push_back(mesh.name + ": " + what + " has an index out of range (" +
                                   std::to_string(index) + "); ignored");
                active_ = false;
                return;
            }
        }
        active_ = true;
    }

    bool active() const { return active_; }

    int64_t value_index(size_t face, size_t corner, size_t point) const {
        if (!active_) return -1;
        size_t slot = 0;
        switch (view_.interpolation) {
            case Interpolation::Constant: slot = 0; break;
            case Interpolation::Uniform: slot = face; break;
            case Interpolation::Vertex:
            case Interpolation::Varying: slot = point; break;
            case Interpolation::FaceVarying: slot = corner; break;
            case Interpolation::None: return -1;
        }
        return view_.indices.empty() ? int64_t(slot) : int64_t(view_.indices[slot]);
    }

    const float* value(int64_t index) const { return view_.values.data() + index * view_.components; }
    int components() const { return view_.components; }

private:
    const PrimvarView& view_;
    bool active_ = false;
};

// A vertex is a point with its attribute *values*: corners that agree share a vertex (a weld), corners that
// differ make a seam. Values are compared bit for bit.
struct CornerKey {
    uint32_t point;
    uint32_t normal[3];
    uint32_t color[kChannelComponents];
    uint32_t uv[2];
    uint32_t material;
    bool operator==(const CornerKey&) const = default;
};
template <size_t N>
void value_bits(const PrimvarLookup& primvar, int64_t index, uint32_t (&bits)[N]) {
    if (index < 0) {
        for (uint32_t& b : bits) b = 0xffffffffu;
        return;
    }
    std::memcpy(bits, primvar.value(index), N * sizeof(float));
}
// A vertex channel value as kChannelComponents floats: a 3-component displayColor gets alpha 1.
std::array<float, kChannelComponents> channel_value(const PrimvarLookup& primvar, int64_t index) {
    std::array<float, kChannelComponents> c{0, 0, 0, 1};
    std::copy_n(primvar.value(index), std::min(primvar.components(), kChannelComponents), c.begin());
    return c;
}
void channel_bits(const PrimvarLookup& primvar, int64_t index, uint32_t (&bits)[kChannelComponents]) {
    if (index < 0) {
        for (uint32_t& b : bits) b = 0xffffffffu;
        return;
    }
    const auto c = channel_value(primvar, index);
    std::memcpy(bits, c.data(), sizeof(bits));
}

constexpr size_t kBlock = 65536;      // loops over points, vertices and faces run on every core in blocks this size
constexpr size_t kSpatialOrderFrom = 65536;  // vertices: a mesh of more is numbered in spatial order (prepare_mesh)

// Throws MeshError where the vertices span more than kMaxMeshExtent along an axis: the builder's float arithmetic
// (squared lengths of edges' cross products) overflows beyond it, where it would make clusters of nothing.
void check_extent(const std::vector<float>& positions, const std::string& name) {
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    all_vertices_box(positions, kBlock, lo, hi);
    const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
    if (extent > kMaxMeshExtent) {
        char spans[32];
        std::snprintf(spans, sizeof spans, "%.3g", extent);
        throw MeshError(name + ": spans " + spans + " units; the builder takes meshes up to 2^31 (about 2.1e9) units across: scale it down or split it");
    }
}

// Why a face cannot be drawn, or null.
struct FaceCheck {
    const MeshView& mesh;
    const std::vector<uint8_t>& pointFinite;  // per point
    const char* operator()(size_t start, size_t count) const {
        if (count < 3) return "fewer than 3 vertices";
        for (size_t c = start; c < start + count; ++c) {
            const int32_t p = mesh.faceVertexIndices[c];
            if (p < 0 || size_t(p) >= pointFinite.size()) return "a vertex index out of range";
            if (!pointFinite[p]) return "a non-finite point";
        }
        return nullptr;
    }
};

Vec3 point_of(const MeshView& mesh, size_t p) { return {mesh.points[3 * p], mesh.points[3 * p + 1], mesh.points[3 * p + 2]}; }

// The fan triangles (as Hydra makes them) of the valid face whose corners start at `start`: emit(c0, c1, c2) with
// the corners (places in faceVertexIndices) of each, in order, but those two of whose corners weld to one point or
// that have no area (they draw nothing; dropping them is not worth a warning). Left-handed faces are flipped.
template <typename Emit>
void fan_triangles(const MeshView& mesh, const std::vector<uint32_t>& canonical, size_t start, size_t count, Emit emit) {
    for (size_t i = 1; i + 1 < count; ++i) {
        size_t c0 = start, c1 = start + i, c2 = start + i + 1;
        if (mesh.leftHanded) std::swap(c1, c2);
        const uint32_t p0 = canonical[mesh.faceVertexIndices[c0]], p1 = canonical[mesh.faceVertexIndices[c1]], p2 = canonical[mesh.faceVertexIndices[c2]];
        const Vec3 a = point_of(mesh, p0);
        if (p0 == p1 || p1 == p2 || p0 == p2 || length(cross(point_of(mesh, p1) - a, point_of(mesh, p2) - a)) == 0.0f) continue;
        emit(c0, c1, c2);
    }
}

// The spatial order of `count` points: cell by cell along a Morton curve (about four points a cell over their box), in
// a cell in their given order. `point(i, xyz)` writes point i's position. Returns the given numbers in that order.
template <typename PointOf>
std::vector<uint32_t> spatial_order(size_t count, PointOf point) {
    const int cellBits = std::min(30, int(std::bit_width(count / 4)));  // of the 30-bit code
    float lo[3];
    const float extent = morton_cube(count, point, lo);
    std::vector<uint32_t> cell(count);
    parallel_blocks(count, kBlock, [&](size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) {
            float xyz[3];
            point(i, xyz);
            cell[i] = morton_code(xyz, lo, extent) >> (30 - cellBits);
        }
    });
    std::vector<uint32_t> start((size_t(1) << cellBits) + 1, 0), order(count);
    for (uint32_t c : cell) ++start[c + 1];
    for (size_t c = 1; c < start.size(); ++c) start[c] += start[c - 1];
    for (size_t i = 0; i < count; ++i) order[start[cell[i]]++] = uint32_t(i);
    return order;
}

// Where each vertex takes its values from: `point`, its point (`ownPoints`: no two vertices share one); normal(v),
// colour(v) and uv(v), the value indices of its authored normal, colour and texture coordinates (-1: none).
template <typename NormalOf, typename ColorOf, typename UvOf>
struct VertexSources {
    const std::vector<uint32_t>& point;
    bool ownPoints;
    NormalOf normal;
    ColorOf color;
    UvOf uv;
};

// The vertex streams of `out` (its indices set) from the vertices' sources: positions, normals (authored, else smooth:
// area-weighted over the point's triangles, also the fallback for a bad authored one), colours and texture
// coordinates. The smooth normals are summed on every core, each over a range of points and in triangle order, so
// that they do not depend on the cores.
template <typename Sources>
void fill_vertex_streams(PreparedMesh& out, const MeshView& mesh, const Sources& source, const PrimvarLookup& normals, const PrimvarLookup* colors,
                         const PrimvarLookup& uvs) {
    const size_t vertexCount = source.point.size(), pointCount = mesh.points.size() / 3;
    out.positions.resize(3 * vertexCount);
    parallel_blocks(vertexCount, kBlock, [&](size_t begin, size_t end) {
        for (size_t v = begin; v < end; ++v) {
            const Vec3 p = point_of(mesh, source.point[v]);
            out.positions[3 * v] = p.x;
            out.positions[3 * v + 1] = p.y;
            out.positions[3 * v + 2] = p.z;
        }
    });
    // Summed per point (over the vertices of its seams), or per vertex where each is its own point (the same sums).
    const size_t sums = source.ownPoints ? vertexCount : pointCount;
    auto sum_of = [&](uint32_t v) { return source.ownPoints ? v : source.point[v]; };
    std::vector<float> smooth(3 * sums, 0.0f);
    const size_t ranges = std::min<size_t>(core_count(), 8), rangeSums = (sums + ranges - 1) / ranges;
    parallel_for(ranges, [&](size_t range) {
        const uint32_t first = uint32_t(range * rangeSums), last = uint32_t(std::min(sums, (range + 1) * rangeSums));
        for (size_t t = 0; t < out.indices.size(); t += 3) {
            const uint32_t* corner = &out.indices[t];
            const uint32_t sum[3] = {sum_of(corner[0]), sum_of(corner[1]), sum_of(corner[2])};
            if ((sum[0] < first || sum[0] >= last) && (sum[1] < first || sum[1] >= last) && (sum[2] < first || sum[2] >= last)) continue;
            const float* a = &out.positions[3 * size_t(corner[0])];
            const float* b = &out.positions[3 * size_t(corner[1])];
            const float* c = &out.positions[3 * size_t(corner[2])];
            const Vec3 n = cross(Vec3{b[0], b[1], b[2]} - Vec3{a[0], a[1], a[2]}, Vec3{c[0], c[1], c[2]} - Vec3{a[0], a[1], a[2]});
            for (uint32_t k : sum)
                if (k >= first && k < last) {
                    smooth[3 * size_t(k)] += n.x;
                    smooth[3 * size_t(k) + 1] += n.y;
                    smooth[3 * size_t(k) + 2] += n.z;
                }
        }
    });
    out.normals.resize(3 * vertexCount);
    parallel_blocks(vertexCount, kBlock, [&](size_t begin, size_t end) {
        for (size_t v = begin; v < end; ++v) {
            Vec3 n{0, 0, 0};
            if (const int64_t authored = source.normal(v); authored >= 0) {
                const float* value = normals.value(authored);
                n = {value[0], value[1], value[2]};
            }
            float len = length(n);
            if (!(len > 0.0f) || !std::isfinite(len)) {
                const float* accum = &smooth[3 * size_t(sum_of(uint32_t(v)))];
                n = {accum[0], accum[1], accum[2]};
                len = length(n);
            }
            if (!(len > 0.0f) || !std::isfinite(len)) {
                n = {0, 0, 1};
                len = 1;
            }
            out.normals[3 * v] = n.x / len;
            out.normals[3 * v + 1] = n.y / len;
            out.normals[3 * v + 2] = n.z / len;
        }
    });
    if (colors) {
        out.colors.resize(kChannelComponents * vertexCount);
        for (size_t v = 0; v < vertexCount; ++v) {
            const auto c = channel_value(*colors, source.color(v));
            std::copy(c.begin(), c.end(), &out.colors[kChannelComponents * v]);
        }
    }
    if (uvs.active()) {
        out.uvs.resize(2 * vertexCount);
        size_t nonFinite = 0;
        float largest = 0;
        for (size_t v = 0; v < vertexCount; ++v) {
            const float* uv = uvs.value(source.uv(v));
            for (int k = 0; k < 2; ++k) {
                const bool finite = std::isfinite(uv[k]);
                nonFinite += !finite;
                out.uvs[2 * v + k] = finite ? uv[k] : 0.0f;
                largest = std::max(largest, std::fabs(out.uvs[2 * v + k]));
            }
        }
        if (nonFinite) out.warnings.push_back(mesh.name + ": " + std::to_string(nonFinite) + " texture coordinate(s) are NaN or infinite; set to 0");
        // One value far out of place (1e30 among coordinates in [0, 1]) coarsens the grid every texture coordinate of
        // the mesh is stored on, and with it all of them: said where the steps pass 1/256 of a texture.
        if (const int precision = uv_grid_precision(largest); precision > -8) {
            char reach[32];
            std::snprintf(reach, sizeof reach, "%.3g", double(largest));
            out.warnings.push_back(mesh.name + ": texture coordinates reach " + reach + ": they are stored on a grid of 2^" + std::to_string(precision) +
                                   " texture widths, which blurs or collapses them (a value out of place?)");
        }
    }
}

// prepare_mesh.
PreparedMesh prepare_triangles(const MeshView& mesh) {
    PhaseTimer phases;
    PreparedMesh out;
    auto& warnings = out.warnings;
    const std::string& name = mesh.name;

    if (mesh.points.size() % 3 != 0) throw MeshError(name + ": points array length is not a multiple of 3");
    const size_t pointCount = mesh.points.size() / 3;
    if (pointCount == 0) throw MeshError(name + ": mesh has no points");
    size_t indexTotal = 0;
    for (int32_t count : mesh.faceVertexCounts) {
        if (count < 0) throw MeshError(name + ": faceVertexCounts has a negative count (" + std::to_string(count) + ")");
        indexTotal += size_t(count);
    }
    if (indexTotal != mesh.faceVertexIndices.size())
        throw MeshError(name + ": faceVertexCounts sum to " + std::to_string(indexTotal) + " but faceVertexIndices has " +
                        std::to_string(mesh.faceVertexIndices.size()) + " entries");

    auto point = [&](size_t i) { return point_of(mesh, i); };
    std::vector<uint8_t> pointFinite(pointCount);
    size_t nonFinitePoints = 0;
    for (size_t i = 0; i < pointCount; ++i) {
        Vec3 p = point(i);
        pointFinite[i] = std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z);
        nonFinitePoints += !pointFinite[i];
    }

    const FaceCheck face_problem{mesh, pointFinite};
    auto dropped_faces_warning = [&](size_t dropped, size_t first, const char* reason) {
        return name + ": dropped " + std::to_string(dropped) + " invalid face(s); first is face " + std::to_string(first) + " with " + reason;
    };

    // Material slots per face (GeomSubsets): all faces or none, each 0-255.
    std::span<const int32_t> faceMaterials = mesh.faceMaterials;
    if (!faceMaterials.empty() && faceMaterials.size() != mesh.faceVertexCounts.size()) {
        warnings.push_back(name + ": " + std::to_string(faceMaterials.size()) + " material slots for " +
                           std::to_string(mesh.faceVertexCounts.size()) + " faces; one material is used");
        faceMaterials = {};
    }
    for (int32_t slot : faceMaterials)
        if (slot < 0 || slot > 255) {
            warnings.push_back(name + ": material slot " + std::to_string(slot) + " is outside 0-255; one material is used");
            faceMaterials = {};
            break;
        }
    const bool materialSlots = std::any_of(faceMaterials.begin(), faceMaterials.end(), [](int32_t slot) { return slot != 0; });

    if (mesh.subdivisionScheme != SubdivisionScheme::None && mesh.refineLevel > 0) {
        // Refine the valid faces (OpenSubdiv must never see a bad index), then prepare the result as polygons.
        std::vector<int32_t> counts, indices, holes;
        std::vector<float> uniformColors;  // kChannelComponents per kept face
        std::vector<int32_t> newIndexOf(mesh.faceVertexCounts.size(), -1);
        const bool uniform = mesh.displayColor.interpolation == Interpolation::Uniform && !mesh.displayColor.values.empty();
        // Texture coordinates per point or per corner go through OpenSubdiv as one face-varying channel.
        std::vector<std::string> uvNotes;
        const PrimvarLookup uvSource(mesh.uvs, mesh, "texture coordinates", pointCount, uvNotes);
        const bool refineUvs = uvSource.active() && (mesh.uvs.interpolation == Interpolation::FaceVarying ||
                                                     mesh.uvs.interpolation == Interpolation::Vertex ||
                                                     mesh.uvs.interpolation == Interpolation::Varying);
        std::vector<int32_t> uvIndices, keptMaterials;
        size_t dropped = 0, firstBad = 0, start = 0;
        const char* firstReason = nullptr;
        for (size_t face = 0; face < mesh.faceVertexCounts.size(); ++face) {
            const size_t count = size_t(mesh.faceVertexCounts[face]);
            if (const char* problem = face_problem(start, count)) {
                if (dropped++ == 0) {
                    firstBad = face;
                    firstReason = problem;
                }
            } else {
                newIndexOf[face] = int32_t(counts.size());
                counts.push_back(int32_t(count));
                if (materialSlots) keptMaterials.push_back(faceMaterials[face]);
                indices.insert(indices.end(), mesh.faceVertexIndices.begin() + start, mesh.faceVertexIndices.begin() + start + count);
                if (refineUvs)
                    for (size_t c = start; c < start + count; ++c)
                        uvIndices.push_back(int32_t(uvSource.value_index(face, c, size_t(mesh.faceVertexIndices[c]))));
                if (uniform) {
                    const size_t slot = mesh.displayColor.indices.empty() ? face : size_t(mesh.displayColor.indices[face]);
                    const size_t width = size_t(mesh.displayColor.components);
                    std::array<float, kChannelComponents> c{0.5f, 0.5f, 0.5f, 1.0f};
                    if (width * slot + width - 1 < mesh.displayColor.values.size())
                        std::copy_n(&mesh.displayColor.values[width * slot], std::min<size_t>(width, kChannelComponents), c.begin());
                    uniformColors.insert(uniformColors.end(), c.begin(), c.end());
                }
            }
            start += count;
        }
        for (int32_t hole : mesh.holeIndices)
            if (hole >= 0 && size_t(hole) < newIndexOf.size() && newIndexOf[hole] >= 0) holes.push_back(newIndexOf[hole]);
        if (counts.empty()) throw MeshError(name + ": no drawable faces" + (firstReason ? std::string(" (every face is invalid: ") + firstReason + ")" : ""));
        RefinedMesh refined;
        std::string problem;
        const FaceVaryingUvs uvs{refineUvs ? mesh.uvs.values : std::span<const float>(), uvIndices};
        std::vector<std::string> tagNotes;
        if (refine_subdivision(mesh, counts, indices, holes, uniform ? uniformColors.data() : nullptr, uvs, keptMaterials, refined, problem,
                               tagNotes)) {
            MeshView view;
            view.name = name;
            view.points = refined.points;
            view.faceVertexCounts = refined.counts;
            view.faceVertexIndices = refined.indices;
            if (refined.colorInterpolation != Interpolation::None) view.displayColor = {refined.colorInterpolation, kChannelComponents, refined.colors, {}};
            else if (mesh.displayColor.interpolation == Interpolation::Constant) view.displayColor = mesh.displayColor;
            if (!refined.uvIndices.empty()) view.uvs = {Interpolation::FaceVarying, 2, refined.uvs, refined.uvIndices};
            else if (mesh.uvs.interpolation == Interpolation::Constant) view.uvs = mesh.uvs;
            view.faceMaterials = refined.faceMaterials;
            PreparedMesh result = prepare_triangles(view);
            std::vector<std::string> notes;
            if (dropped) notes.push_back(dropped_faces_warning(dropped, firstBad, firstReason));
            if (nonFinitePoints) notes.push_back(name + ": " + std::to_string(nonFinitePoints) + " point(s) are NaN or infinite");
            if (mesh.displayColor.interpolation == Interpolation::FaceVarying)
                notes.push_back(name + ": a face-varying vertex channel (displayColor or the primvars its materials read) is not refined "
                                       "yet; the subdivided mesh is drawn without it");
            notes.insert(notes.end(), uvNotes.begin(), uvNotes.end());
            notes.insert(notes.end(), tagNotes.begin(), tagNotes.end());
            if (mesh.uvs.interpolation == Interpolation::Uniform && uvSource.active())
                notes.push_back(name + ": uniform texture coordinates are not refined; the subdivided mesh is drawn without them");
            result.warnings.insert(result.warnings.begin(), notes.begin(), notes.end());
            return result;
        }
        warnings.push_back(name + ": cannot subdivide (" + problem + "); the control cage is drawn instead");
    }

    // Weld exact duplicate positions: every point maps to the first point with bit-identical coordinates, so that
    // split authoring (UV-sphere poles, per-face copies) joins up; attribute values still decide seams below.
    phases.mark("prepare: validate");
    const std::vector<uint32_t> canonical = weld_equal_positions(mesh.points.data(), pointCount);
    phases.mark("prepare: weld");

    std::vector<uint8_t> isHole(mesh.faceVertexCounts.size());
    for (int32_t hole : mesh.holeIndices) {
        if (hole < 0 || size_t(hole) >= isHole.size())
            warnings.push_back(name + ": holeIndices entry " + std::to_string(hole) + " is not a face; ignored");
        else
            isHole[hole] = 1;
    }

    PrimvarLookup normals(mesh.normals, mesh, "normals", pointCount, warnings);
    PrimvarLookup colors(mesh.displayColor, mesh, "primvars:displayColor", pointCount, warnings);
    if (colors.active() && mesh.displayColor.interpolation == Interpolation::Constant) {
        out.constantColor = channel_value(colors, colors.value_index(0, 0, 0));
        out.hasConstantColor = true;
    }
    const bool vertexColors = colors.active() && !out.hasConstantColor;
    PrimvarLookup uvs(mesh.uvs, mesh, "texture coordinates", pointCount, warnings);
    if (uvs.active() && uvs.components() != 2) throw MeshError(name + ": texture coordinates must have 2 components");

    // Triangulate (a fan per polygon, as Hydra does) and split vertices at attribute seams.
    std::vector<uint32_t> vertexPoint;
    std::vector<int64_t> vertexNormal, vertexColor, vertexUv;
    size_t droppedFaces = 0, firstBadFace = SIZE_MAX;
    std::string firstBadReason;
    // Fast path: when no primvar varies per face or per corner, a vertex is just its (welded) point.
    auto per_point = [](const PrimvarView& v, bool active) {
        return !active || v.interpolation == Interpolation::Constant || v.interpolation == Interpolation::Vertex ||
               v.interpolation == Interpolation::Varying;
    };
    // ...and only if welded points agree on their per-point values (else the weld would erase a seam).
    auto same_values = [&](const PrimvarLookup& lookup, bool active, uint32_t a, uint32_t b) {
        if (!active) return true;
        const int64_t ia = lookup.value_index(0, 0, a), ib = lookup.value_index(0, 0, b);
        return ia == ib || std::memcmp(lookup.value(ia), lookup.value(ib), lookup.components() * sizeof(float)) == 0;
    };
    bool pointVertices = per_point(mesh.normals, normals.active()) && per_point(mesh.displayColor, vertexColors) &&
                         per_point(mesh.uvs, uvs.active()) && !materialSlots;
    for (uint32_t p = 0; p < pointCount && pointVertices; ++p)
        if (canonical[p] != p)
            pointVertices = same_values(normals, normals.active(), p, canonical[p]) && same_values(colors, vertexColors, p, canonical[p]) &&
                            same_values(uvs, uvs.active(), p, canonical[p]);
    // Triangulated on every core: the faces in blocks, each keeping its triangles in order (their corners' welded
    // points and, where a vertex is more than its point, the corners themselves), counted, then numbered into
    // vertices by first use and written at their block's place. The numbering is the one loop on one core (a number
    // depends on every earlier triangle). All on one core, a 10 M-triangle mesh spent 0.25 s here, 2 s with its faces
    // in a scattered order, and 3.7 s with face-varying texture coordinates.
    if (mesh.faceVertexIndices.size() >= UINT32_MAX) throw MeshError(name + ": more than 2^32 face vertex indices");
    const size_t faces = mesh.faceVertexCounts.size(), blocks = (faces + kBlock - 1) / kBlock;
    std::vector<size_t> blockStart(blocks + 1, 0);  // the block's first corner
    parallel_for(blocks, [&](size_t b) {
        for (size_t face = b * kBlock; face < std::min(faces, (b + 1) * kBlock); ++face) blockStart[b + 1] += size_t(mesh.faceVertexCounts[face]);
    });
    for (size_t b = 0; b < blocks; ++b) blockStart[b + 1] += blockStart[b];
    struct Block {
        std::vector<uint32_t> points, corners, faces;  // per kept triangle: 3 welded points, 3 corners (unless pointVertices), its face
        size_t dropped = 0, firstBad = SIZE_MAX;
        const char* reason = nullptr;
    };
    std::vector<Block> block(blocks);
    parallel_for(blocks, [&](size_t b) {
        Block& mine = block[b];
        size_t start = blockStart[b];
        const size_t end = std::min(faces, (b + 1) * kBlock);
        // The points of the face kPrefetch faces on are fetched meanwhile: faces in a scattered order read them at
        // random, and waiting for each in turn took most of this loop's time.
        constexpr size_t kPrefetch = 16;
        size_t aheadFace = b * kBlock, aheadStart = start;
        auto fetch_ahead = [&] {
            if (aheadFace >= end) return;
            for (size_t c = aheadStart; c < aheadStart + size_t(mesh.faceVertexCounts[aheadFace]); ++c) {
                const size_t p = size_t(uint32_t(mesh.faceVertexIndices[c]));
                if (p >= pointCount) continue;
                __builtin_prefetch(&canonical[p]);
                __builtin_prefetch(&pointFinite[p]);
                __builtin_prefetch(&mesh.points[3 * p]);
            }
            aheadStart += size_t(mesh.faceVertexCounts[aheadFace++]);
        };
        for (size_t i = 0; i < kPrefetch; ++i) fetch_ahead();
        for (size_t face = b * kBlock; face < end; ++face) {
            fetch_ahead();
            const size_t count = size_t(mesh.faceVertexCounts[face]);
            const size_t first = start;
            start += count;
            if (isHole[face]) continue;
            if (const char* bad = face_problem(first, count)) {
                if (mine.dropped++ == 0) mine.firstBad = face, mine.reason = bad;
                continue;
            }
            fan_triangles(mesh, canonical, first, count, [&](size_t c0, size_t c1, size_t c2) {
                for (size_t c : {c0, c1, c2}) {
                    mine.points.push_back(canonical[mesh.faceVertexIndices[c]]);
                    if (!pointVertices) mine.corners.push_back(uint32_t(c));
                }
                mine.faces.push_back(uint32_t(face));
            });
        }
    });
    std::vector<size_t> blockTriangles(blocks + 1, 0);
    for (size_t b = 0; b < blocks; ++b) {
        blockTriangles[b + 1] = blockTriangles[b] + block[b].faces.size();
        if (block[b].dropped && droppedFaces == 0) firstBadFace = block[b].firstBad, firstBadReason = block[b].reason;
        droppedFaces += block[b].dropped;
    }
    out.indices.resize(3 * blockTriangles[blocks]);
    if (pointVertices) {  // a vertex per point
        std::vector<uint32_t> vertexOfPoint(pointCount, UINT32_MAX);
        vertexPoint.reserve(pointCount);
        for (size_t b = 0; b < blocks; ++b) {
            const std::vector<uint32_t>& points = block[b].points;
            uint32_t* written = out.indices.data() + 3 * blockTriangles[b];  // (no element to refer to when nothing is left)
            for (size_t i = 0; i < points.size(); ++i) {
                if (i + 32 < points.size()) __builtin_prefetch(&vertexOfPoint[points[i + 32]]);
                uint32_t& number = vertexOfPoint[points[i]];
                if (number == UINT32_MAX) {
                    number = uint32_t(vertexPoint.size());
                    vertexPoint.push_back(points[i]);
                }
                written[i] = number;
            }
        }
    } else {  // a vertex per point and attribute values (CornerKey): each point's vertices in a list, searched in turn
        std::vector<uint32_t> wedgeAt(pointCount, UINT32_MAX), nextWedge;  // per point, a vertex; per vertex, the next at its point
        std::vector<CornerKey> keyOf;                                      // per vertex
        for (auto* stream : {&vertexNormal, &vertexColor, &vertexUv}) stream->reserve(pointCount);
        for (size_t b = 0; b < blocks; ++b) {
            const Block& mine = block[b];
            uint32_t* written = out.indices.data() + 3 * blockTriangles[b];  // (no element to refer to when nothing is left)
            for (size_t i = 0; i < mine.points.size(); ++i) {
                const size_t face = mine.faces[i / 3], corner = mine.corners[i];
                const uint32_t point = mine.points[i], authored = uint32_t(mesh.faceVertexIndices[corner]);
                const int64_t normal = normals.value_index(face, corner, authored), color = vertexColors ? colors.value_index(face, corner, authored) : -1;
                const int64_t uv = uvs.value_index(face, corner, authored);
                CornerKey key{point, {}, {}, {}, materialSlots ? uint32_t(faceMaterials[face]) : 0u};
                value_bits(normals, normal, key.normal);
                channel_bits(colors, color, key.color);
                value_bits(uvs, uv, key.uv);
                uint32_t vertex = wedgeAt[point];
                while (vertex != UINT32_MAX && !(keyOf[vertex] == key)) vertex = nextWedge[vertex];
                if (vertex == UINT32_MAX) {
                    vertex = uint32_t(vertexPoint.size());
                    keyOf.push_back(key);
                    nextWedge.push_back(wedgeAt[point]);
                    wedgeAt[point] = vertex;
                    vertexPoint.push_back(point);
                    vertexNormal.push_back(normal);
                    vertexColor.push_back(color);
                    vertexUv.push_back(uv);
                }
                written[i] = vertex;
            }
        }
    }
    out.sourceFaces.resize(blockTriangles[blocks]);
    if (materialSlots) out.triangleMaterials.resize(blockTriangles[blocks]);
    parallel_for(blocks, [&](size_t b) {
        std::copy(block[b].faces.begin(), block[b].faces.end(), out.sourceFaces.begin() + blockTriangles[b]);
        if (materialSlots)
            for (size_t t = 0; t < block[b].faces.size(); ++t) out.triangleMaterials[blockTriangles[b] + t] = uint8_t(faceMaterials[block[b].faces[t]]);
        block[b] = {};
    });
    if (droppedFaces) warnings.push_back(dropped_faces_warning(droppedFaces, firstBadFace, firstBadReason.c_str()));
    if (nonFinitePoints)
        warnings.push_back(name + ": " + std::to_string(nonFinitePoints) + " point(s) are NaN or infinite");
    if (out.indices.empty())
        throw MeshError(name + ": no drawable faces" +
                        (droppedFaces ? " (every face is invalid: " + firstBadReason + ")" : " (every triangle has no area at float precision)"));
    phases.mark("prepare: triangulate");

    // A mesh of more than 2^16 vertices: renumbered in spatial order (spatial_order over the vertices' positions, in a
    // cell by first use), so that the builder, which walks the surface region by region, reads its per-vertex arrays
    // nearly in order whatever order the input came in (the 10 M-triangle bumpy sphere with its faces shuffled built
    // 1.4x slower than in its grid's order). A smaller mesh's arrays stay in the caches either way.
    if (vertexPoint.size() > kSpatialOrderFrom) {
        const std::vector<uint32_t> order = spatial_order(vertexPoint.size(), [&](size_t v, float* xyz) { std::copy_n(&mesh.points[3 * size_t(vertexPoint[v])], 3, xyz); });
        std::vector<uint32_t> newNumber(order.size());
        for (size_t i = 0; i < order.size(); ++i) newNumber[order[i]] = uint32_t(i);
        auto reorder = [&](auto& values) {
            if (values.empty()) return;
            std::remove_reference_t<decltype(values)> moved(values.size());
            for (size_t i = 0; i < order.size(); ++i) moved[i] = values[order[i]];
            values.swap(moved);
        };
        reorder(vertexPoint), reorder(vertexNormal), reorder(vertexColor), reorder(vertexUv);
        parallel_blocks(out.indices.size(), kBlock, [&](size_t begin, size_t end) {
            for (size_t i = begin; i < end; ++i) out.indices[i] = newNumber[out.indices[i]];
        });
        phases.mark("prepare: spatial order");
    }

    // Vertex streams. A vertex that is its point takes the point's values (a welded point's are the same bits as the
    // point's it was welded to, or the weld would not be taken), others those their corner key found.
    if (pointVertices) {
        auto at_point = [&](const PrimvarLookup& lookup, bool active) {
            return [&lookup, &vertexPoint, active](size_t v) { return active ? lookup.value_index(0, 0, vertexPoint[v]) : int64_t(-1); };
        };
        fill_vertex_streams(out, mesh, VertexSources{vertexPoint, true, at_point(normals, true), at_point(colors, vertexColors), at_point(uvs, true)}, normals,
                            vertexColors ? &colors : nullptr, uvs);
    } else {
        auto listed = [](const std::vector<int64_t>& values) { return [&values](size_t v) { return values[v]; }; };
        fill_vertex_streams(out, mesh, VertexSources{vertexPoint, false, listed(vertexNormal), listed(vertexColor), listed(vertexUv)}, normals,
                            vertexColors ? &colors : nullptr, uvs);
    }
    phases.mark("prepare: vertex streams");
    check_extent(out.positions, name);
    return out;
}

}  // namespace

PreparedMesh prepare_mesh(const MeshView& mesh) { return prepare_triangles(mesh); }

}  // namespace tessera
