// Tessera builder: turns an authored polygon mesh into clusters the renderer can draw.
// Knows only meshes: no USD, no Vulkan. The entry points are prepare_mesh() then build_mesh().
#pragma once

#include <algorithm>
#include <cmath>
#include <array>
#include <functional>
#include <limits>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace tessera {

// Cluster budget (the renderer checks these against shaders/shared.h). The DAG builder's clusters use at most
// 255 vertices (meshoptimizer's meshlet limit), within the 8-bit local index.
constexpr uint32_t kClusterMaxTriangles = 128;
constexpr uint32_t kClusterMaxVertices = 256;

// USD's subdivisionScheme.
enum class SubdivisionScheme { None, CatmullClark, Loop, Bilinear };

// USD's subdivision tags (UsdGeomMesh), as OpenSubdiv's Sdc options and tags take them. The defaults are USD's
// fallbacks. Creases and corners are borrowed, like the rest of a MeshView; bad ones are a warning and ignored.
enum class BoundaryInterpolation { None, EdgeOnly, EdgeAndCorner };  // interpolateBoundary
// faceVaryingLinearInterpolation: none (smooth everywhere), cornersOnly, cornersPlus1, cornersPlus2, boundaries, all.
enum class FaceVaryingLinear { None, CornersOnly, CornersPlus1, CornersPlus2, Boundaries, All };
enum class TriangleSubdivision { CatmullClark, Smooth };  // triangleSubdivisionRule
struct SubdivisionTags {
    BoundaryInterpolation interpolateBoundary = BoundaryInterpolation::EdgeAndCorner;
    FaceVaryingLinear faceVaryingLinearInterpolation = FaceVaryingLinear::CornersPlus1;
    TriangleSubdivision triangleSubdivisionRule = TriangleSubdivision::CatmullClark;
    // Creases: chains of points (creaseLengths points each, >= 2, their indices in creaseIndices), with one
    // sharpness per chain or one per edge of the chains. Corners: one sharpness per point. 10 or more is infinitely sharp.
    std::span<const int32_t> creaseIndices;
    std::span<const int32_t> creaseLengths;
    std::span<const float> creaseSharpnesses;
    std::span<const int32_t> cornerIndices;
    std::span<const float> cornerSharpnesses;
};

// Components per vertex of the vertex channel (the colour stream, rgba16f on the GPU and in page files).
constexpr int kChannelComponents = 4;

// How a primvar's values map onto the mesh (USD's interpolation names).
enum class Interpolation { None, Constant, Uniform, Vertex, Varying, FaceVarying };

// A primvar as authored: `values` holds `components` floats per element; `indices` (optional) maps
// each element slot to a value.
struct PrimvarView {
    Interpolation interpolation = Interpolation::None;
    int components = 3;
    std::span<const float> values;
    std::span<const int32_t> indices;
};

// A polygon mesh as authored; all views are borrowed for the duration of prepare_mesh().
struct DisplacementBake;

struct MeshView {
    std::string name;                          // used in every message (a prim path, say)
    std::span<const float> points;             // 3 floats per point
    std::span<const int32_t> faceVertexCounts;
    std::span<const int32_t> faceVertexIndices;
    std::span<const int32_t> holeIndices;      // faces not drawn
    bool leftHanded = false;                   // faces wind clockwise
    PrimvarView normals;                       // 3 components
    // The mesh's vertex channel: displayColor (3 components) or up to 4 primvars packed by the scene delegate (4
    // components: what its materials' primvar readers read, GpuMaterial::vertexInputs says which drives what).
    PrimvarView displayColor;
    PrimvarView uvs;                           // 2 components: the texture coordinates (USD's `st`), any interpolation
    // Per authored face, its material slot (0-255: USD's GeomSubsets of family materialBind, slot 0 the faces in no
    // subset), or empty: one material. Faces of different slots meet at split vertices, like a seam.
    std::span<const int32_t> faceMaterials;
    // Subdivision surfaces are refined uniformly this many times (OpenSubdiv) before triangulation, with the
    // mesh's subdivision tags. Authored normals do not describe the refined surface and are recomputed (the USD scene
    // delegate does not even read them for a scheme other than none, as UsdImaging does not); texture
    // coordinates are refined as a face-varying channel (faceVaryingLinearInterpolation), vertex colours linearly.
    SubdivisionScheme subdivisionScheme = SubdivisionScheme::None;
    int refineLevel = 0;
    SubdivisionTags subdivisionTags;  // read only when the mesh is refined
    // Static displacement: when set, the prepared mesh is diced and displaced before its DAG is built
    // (bake_displacement), and the bake's key joins the cache key.
    const DisplacementBake* bake = nullptr;
};

// The mesh cannot be used at all (no valid face left, or data that do not fit together).
struct MeshError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// Triangles over split vertices: a vertex is a unique (point, normal, colour) combination, so attribute
// seams survive as split vertices. Triangles wind counter-clockwise seen from their front.
struct PreparedMesh {
    std::vector<float> positions;      // 3 per vertex, as authored (float)
    std::vector<float> normals;        // 3 per vertex, unit length
    std::vector<float> colors;         // kChannelComponents per vertex when the vertex channel varies, else empty (a 3-component
                                       // displayColor gets alpha 1)
    std::vector<float> uvs;            // 2 per vertex when the mesh has texture coordinates, else empty
    std::array<float, 4> constantColor{0.5f, 0.5f, 0.5f, 1.0f};
    bool hasConstantColor = false;     // the vertex channel (displayColor) authored with constant interpolation
    std::vector<uint32_t> indices;     // 3 per triangle
    std::vector<uint8_t> triangleMaterials;  // per triangle, its material slot, when the mesh has more than one
    std::vector<uint32_t> sourceFaces; // per triangle, the authored face it came from
    std::vector<std::string> warnings; // dropped faces and the like, each naming the mesh
};

// The largest extent of a mesh along an axis, in its units: beyond it the builder's float arithmetic (squared lengths
// of edges' cross products) overflows. A planet in centimetres (1.3e9) fits.
constexpr double kMaxMeshExtent = 2147483648.0;  // 2^31
// The grid texture coordinates are stored on (BuiltMesh::uvPrecision), from the largest of them in magnitude: 2^-16, a
// quarter texel of a 16K texture, or coarser where they are so large that float holds no finer steps (22 bits below
// their top one).
inline int uv_grid_precision(float largest) { return std::max(-16, int(std::ceil(std::log2(double(std::max(largest, 1.0f))))) - 22); }
// Validates and triangulates. Bad faces (out-of-range indices, fewer than 3 vertices, non-finite points)
// are dropped with a warning; a mesh with nothing left to draw, whose arrays do not fit together, or that spans more
// than kMaxMeshExtent, throws MeshError naming the mesh and the problem. Triangles come in the faces' order; vertices are numbered by first
// use, or, in a mesh of more than 2^16 vertices, cell by cell along a Morton curve through their positions (the build
// then reads its per-vertex arrays nearly in order, whatever order the input came in).
PreparedMesh prepare_mesh(const MeshView& mesh);

// Static displacement (a material's tessera:displacement:bake, Nanite's build-time tessellation): the mesh is diced
// finely enough for its height map and displaced along its normals, so that the cluster DAG carries the detail and
// simplifies it by error like any other. Offset = (height - center) * magnitude, mesh units.
struct DisplacementBake {
    float magnitude = 1.0f, center = 0.0f;
    float constant = 0.0f;                     // the height where `height` is empty
    std::function<float(float, float)> height; // the height at texture coordinates (s, t): a height map, read on the CPU
    uint32_t texels = 0;                       // the height map's larger side: edges are cut about one texel long
    uint64_t maxTriangles = 4'000'000;         // the dicing coarsens until the result fits (a mesh of more is not diced)
    std::string key;                           // identifies the height map and the values above (joins the cache key)
};

// Every edge is cut into segments of about one texel of the height map (measured over the mesh: its area against its
// UV area), at most 64; triangles are diced on a lattice whose edge points follow each edge's own segments, so the
// edges' two triangles agree; each point's height is the mean of the samples every triangle around its position reads
// (UV seams do not tear) and moves it along the mean normal there (hard edges do not tear). Normals are recomputed from
// the displaced surface; texture coordinates, colours, slots and source faces carry over.
PreparedMesh bake_displacement(const PreparedMesh& mesh, const DisplacementBake& bake);

// A cone holding the normal of every triangle of a cluster, for backface culling: the cluster faces away from a
// viewer at direction v (unit, from the viewer) when dot(v, axis) >= cutoff, with axis and cutoff in 8-bit snorm
// (x / 127). A cutoff of 127 (1.0) culls nothing: the normals spread too wide.
struct NormalCone {
    std::array<int8_t, 3> axis8{0, 0, 0};
    int8_t cutoff8 = 127;
};

// One cluster of the DAG. Level 0 holds the source triangles; each higher level was made by simplifying a
// group of clusters below it. The runtime draws a cluster iff its LOD error, projected from its LOD sphere,
// is within the threshold while its parent's is not. Siblings share their LOD bounds, children share their
// parent bounds, and both grow monotonically up the DAG (parent error >= child error, parent sphere contains
// child sphere), so the test is local and every cut is crack-free.
struct Cluster {
    std::array<float, 4> sphere;        // culling bounds of its own triangles (mesh space, relative to origin)
    std::array<float, 4> lodSphere;     // bounds of the group simplification that made it
    float lodError;                     // that simplification's error in mesh units (0 at level 0)
    std::array<float, 4> parentSphere;  // bounds of the group simplification made from it
    float parentError;                  // its error; infinity for roots
    uint32_t parentGroup;               // the group simplification made from it (kNoGroup for roots): siblings share it
    uint32_t level;
    uint32_t vertexOffset;              // into BuiltMesh vertex streams
    uint32_t vertexCount;               // <= 255
    uint32_t triangleOffset;            // into BuiltMesh::triangles
    uint32_t triangleCount;             // <= 128
    // Derived from its triangles once the build has placed them (cluster_normal_cone, cluster_triangle_sizes) and kept
    // in the page file, so that loading a mesh derives nothing per cluster.
    NormalCone cone;                    // its triangles' normals, for backface culling
    float meanTriangleArea;             // mesh units squared: the raster split's estimate of its triangles' size
    float longestEdge;                  // mesh units: bounds each triangle's extent, for the raster split's worst case
};

constexpr uint32_t kNoGroup = 0xffffffffu;

struct LevelStats {
    uint32_t clusters = 0;
    uint64_t triangles = 0;
    float maxError = 0;  // largest LOD error of the level's clusters, mesh units
};

// A plain indexed triangle mesh: a crack-free DAG cut for whatever cannot draw the DAG.
struct FallbackMesh {
    std::vector<float> positions;   // 3 per vertex, relative to BuiltMesh::origin
    std::vector<float> normals;     // 3 per vertex, unit length
    std::vector<float> colors;      // 4 per vertex (linear RGBA) when the mesh has vertex colours, else empty
    std::vector<float> uvs;         // 2 per vertex when the mesh has texture coordinates, else empty
    std::vector<uint32_t> indices;  // 3 per triangle, counter-clockwise from the front
    std::vector<uint8_t> materialSlots;  // per triangle when the mesh has several (BuiltMesh::materialSlots > 1), else empty
    float error = 0;                // largest error of its clusters against the source, mesh units
    float threshold = -1;           // its cut: the clusters with lodError <= threshold < parentError; < 0: level 0
};

// A vertex or triangle stream of a built mesh: a vector whose resize leaves the new elements unset (the build then
// writes every one on every core). A zeroing resize wrote a 10 M-triangle mesh's streams on one core first, and its
// page faults with them: 0.8 s of a 12.6 s build, on 2 cores.
template <typename T>
struct UnsetAllocator : std::allocator<T> {
    template <typename U>
    struct rebind {
        using other = UnsetAllocator<U>;
    };
    UnsetAllocator() = default;
    template <typename U>
    UnsetAllocator(const UnsetAllocator<U>&) noexcept {}
    template <typename U>
    void construct(U* p) noexcept {
        ::new (static_cast<void*>(p)) U;  // default-initialised: an arithmetic value is left unset
    }
    template <typename U, typename... Args>
    void construct(U* p, Args&&... args) {
        ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
};
template <typename T>
using Stream = std::vector<T, UnsetAllocator<T>>;

// The cluster DAG over cluster-local vertex streams. Positions are relative to `origin` (computed in double), so a
// mesh authored far from the origin keeps its precision once its origin moves into the instance transform.
// Clusters are stored level 0 first: the first `leafClusters` clusters (and their vertices and triangles, which
// come first in the streams) are the full-detail mesh.
struct BuiltMesh {
    std::array<double, 3> origin{};
    Stream<float> positions;            // 3 per vertex, relative to origin
    Stream<uint32_t> normals;           // octahedral, snorm16x2 holding kNormalBits-bit values (encode_octahedral)
    Stream<uint32_t> colors;            // 2 per vertex (rgba16f) when the mesh has vertex colours
    Stream<float> uvs;                  // 2 per vertex when the mesh has texture coordinates: on the grid of 2^uvPrecision
    // Per triangle: 3 x 8-bit cluster-local indices, in page order (order_cluster_for_pages), and the triangle's material
    // slot in the top byte (0 unless the mesh has several: materialSlots).
    Stream<uint32_t> triangles;
    std::vector<Cluster> clusters;
    uint32_t leafClusters = 0, leafVertices = 0, leafTriangles = 0;
    std::vector<LevelStats> levels;
    uint32_t groups = 0;
    std::array<float, 4> sphere{};     // whole mesh, relative to origin
    float size = 0;                     // diagonal of the mesh's bounding box
    // Positions lie on a grid of this step (a power of two, 2^positionPrecision) in object space; the origin is on
    // the same grid, so meshes built with the same precision share vertices exactly.
    int positionPrecision = 0;
    double positionStep = 1.0;
    // Texture coordinates lie on a grid of this step (a power of two: 2^-16, a quarter texel of a 16K texture, or
    // coarser where the coordinates are so large that float holds no finer steps), so that clusters sharing a
    // vertex share its UV bit for bit and the page file stores integers.
    int uvPrecision = 0;
    std::array<float, 4> constantColor{0.5f, 0.5f, 0.5f, 1.0f};
    bool hasConstantColor = false;
    uint32_t materialSlots = 1;         // 1 + the largest material slot of its triangles
    size_t sourceTriangles = 0;         // as authored (after dropping collapsed triangles); the leaf level may hold fewer
    float leafError = 0;                // error of the stored leaf level against the source (0 unless trimmed), mesh units
    // The fallback mesh is kept as its cut alone (FallbackMesh::threshold; NaN: none, a mesh not made by build_mesh) and
    // its error, and extracted on demand (fallback_mesh): the renderer never draws it, and 100 k small meshes held it for
    // nothing. The page file stores the same two numbers.
    float fallbackThreshold = std::numeric_limits<float>::quiet_NaN();
    float fallbackError = 0;
};

// The mesh without its streams (positions, normals, colours, texture coordinates, triangles, clusters): its origin,
// bounds, counts, colour and levels' statistics, what a scene keeps of a mesh the GPU holds (GpuScene::release_streams).
// Every field but those vectors: keep it current with BuiltMesh.
inline BuiltMesh without_streams(const BuiltMesh& mesh) {
    BuiltMesh out;
    out.origin = mesh.origin;
    out.leafClusters = mesh.leafClusters;
    out.leafVertices = mesh.leafVertices;
    out.leafTriangles = mesh.leafTriangles;
    out.levels = mesh.levels;
    out.groups = mesh.groups;
    out.sphere = mesh.sphere;
    out.size = mesh.size;
    out.positionPrecision = mesh.positionPrecision;
    out.positionStep = mesh.positionStep;
    out.uvPrecision = mesh.uvPrecision;
    out.constantColor = mesh.constantColor;
    out.hasConstantColor = mesh.hasConstantColor;
    out.materialSlots = mesh.materialSlots;
    out.sourceTriangles = mesh.sourceTriangles;
    out.leafError = mesh.leafError;
    out.fallbackThreshold = mesh.fallbackThreshold;
    out.fallbackError = mesh.fallbackError;
    return out;
}

// Per-mesh build settings (the schema's tessera:* attributes; render-wide defaults), after Nanite's. Relative errors
// are in percent of the mesh size (the diagonal of its bounding box), as Nanite's are in percent of its size measure.
struct BuildSettings {
    static constexpr int kAutoPrecision = -1000;
    // log2 of the position grid step in object space (-10: 1/1024 units), or automatic: the largest power of two
    // at most min(mesh size / 2^16, shortest edge / 64). Coarsened if the mesh would span more than 2^23 steps.
    // Explicit values lie in [-64, 64].
    int positionPrecision = kAutoPrecision;
    // Foliage: open borders are dilated as groups simplify, so that the area a level loses (parts dropped, corners
    // cut) goes back into the parts that remain; cards and quad soups then do not thin out with distance.
    bool preserveArea = false;
    // Detail below these is not stored: the leaf level becomes the first DAG cut (fine to coarse) whose error is at
    // least trimRelativeError percent of the mesh size and whose triangles are at most keepTrianglePercent of the
    // source. The defaults (0 %, 100 %) keep everything; each works alone with the other at its default.
    float trimRelativeError = 0.0f;
    float keepTrianglePercent = 100.0f;
    // The fallback mesh (BuiltMesh::fallback): the first DAG cut whose error is at least fallbackRelativeError
    // percent of the mesh size and whose triangles are at most fallbackTrianglePercent of the source, never finer
    // than the stored leaf level. Nanite's defaults: 1 % and 100 %.
    float fallbackRelativeError = 1.0f;
    float fallbackTrianglePercent = 100.0f;
    // Simplification creates no edge longer than this factor times the mean edge length of the source (0: no
    // limit); edges the source already had are kept whatever their length.
    float maxEdgeLengthFactor = 0.0f;
};

// Settings that cannot be used: std::invalid_argument naming the setting and the value.
void validate_settings(const BuildSettings& settings);

// Builds the cluster DAG of a prepared mesh (meshoptimizer for clusters, partitioning and simplification).
// Positions are snapped to the precision grid first, so every level is built from grid points and vertices that
// neighbouring clusters share stay bit-identical once quantized.
BuiltMesh build_mesh(const PreparedMesh& mesh, const BuildSettings& settings = {});
// The same, emptying the mesh's arrays as the build is done with them (its warnings and constant colour stay), for a
// caller that has no more use for them: less memory at the build's peak (the 10 M sphere's 149 -> 127 B/tri).
BuiltMesh build_mesh(PreparedMesh&& mesh, const BuildSettings& settings = {});

// The on-disk form of a BuiltMesh (builder/pages.cpp): little-endian, versioned, compressed, every part checksummed.
// Clusters are stored in pages of at most kPageBytes (before compression too); the children of one group never
// straddle pages (a parent refines by loading one page), and root clusters (no parent) fill pages of their own that
// stay resident.
constexpr uint32_t kPageFormatVersion = 7;  // 4: the constant vertex channel has 4 components; 5: clusters keep their cone and mean
                                            // triangle area; 6: and their longest edge; 7: group errors measured (deviation.h)
// Bumped whenever the builder makes a different DAG from the same input and settings (simplifier weights, grouping,
// error measure, ...): the mesh cache keys on it, so that no stale build is ever served.
constexpr uint32_t kBuilderRevision = 15;  // 3: triangles within a cluster in strip order (encoding.cpp); 4: the seam retry (dag.cpp);
                                          // 5-7: fitted normals on coarse levels, then the vertex channel, then two sweeps (attribute_fit.cpp);
                                          // 8: fits with Preserve Area too; 9: edge midpoints measured over the input's surface (deviation.cpp);
                                          // 10: source points too; Preserve Area keeps the covered area (area.cpp);
                                          // 11: level 0 of a mesh of 32k-128k triangles in two Morton halves (dag.cpp);
                                          // 12: corners re-wedged toward their triangles, no-area triangles sample nothing (dag.cpp);
                                          // 13: a sliver sampling across a border counts a hundred times its width, not its length
                                          // 14: a group whose children could encode to more than a page is split (dag.cpp)
                                          // 15: triangles of no area measure and fit as their edges (deviation.cpp, attribute_fit.cpp)
constexpr uint32_t kPageBytes = 128 * 1024;
constexpr uint32_t kPageHeaderBytes = 160;  // the fixed-size header; the page table follows it

// A file that is not a Tessera DAG, or is truncated, corrupt or of another format version.
struct PageFileError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

struct PageLayout {
    uint32_t pages = 0, rootPages = 0;
    uint64_t bytes = 0;
    std::vector<std::vector<uint32_t>> pageClusters;  // the mesh's cluster indices in each page
};
std::vector<uint8_t> encode_pages(const BuiltMesh& mesh, PageLayout* layout = nullptr);
// `name` (a file path, say) begins every error message.
BuiltMesh decode_pages(std::span<const uint8_t> bytes, const std::string& name);
uint32_t crc32(std::span<const uint8_t> bytes);

// Appends a cluster whose streams are already in place, keeping the leaf ranges and level statistics current
// (clusters must come level 0 first).
void append_cluster(BuiltMesh& mesh, const Cluster& cluster);

NormalCone cluster_normal_cone(const BuiltMesh& mesh, const Cluster& cluster);
// The mean area of a cluster's triangles, in mesh units squared (summed in double), and their longest edge, in mesh
// units (rounded up to a float), in one walk over them.
struct ClusterTriangleSizes {
    float meanArea;
    float longestEdge;
};
ClusterTriangleSizes cluster_triangle_sizes(const BuiltMesh& mesh, const Cluster& cluster);

// The fallback mesh of the cut at `threshold` (FallbackMesh::threshold) of a built or decoded DAG: a decoded DAG gives the
// same mesh as the built one, bit for bit, so a page file needs to keep only the threshold and the error. `error` is
// left at 0.
FallbackMesh extract_fallback(const BuiltMesh& mesh, float threshold);
// The mesh's fallback mesh (BuiltMesh::fallbackThreshold, error included); empty when it has none.
FallbackMesh fallback_mesh(const BuiltMesh& mesh);

// Reorders one cluster for the page file, the DAG unchanged: triangles in strip order (an edge-adjacency walk), vertices
// numbered by first use, each triangle rotated to its smallest rotation. `corners` (3 cluster-local indices per
// triangle) is rewritten; returns, for each new vertex number, the old one.
std::vector<uint32_t> order_cluster_for_pages(std::vector<uint32_t>& corners, uint32_t vertexCount);
// Turns a triangle (3 indices, in place) to the smallest of its three rotations; the winding stays. Inline and without
// a branch on which corner is smallest (a coin toss per triangle): out of line with one, it took a tenth of decoding.
inline void rotate_smallest_first(uint32_t* triangle) {
    const uint32_t a = triangle[0], b = triangle[1], c = triangle[2];
    if (a == b || b == c || a == c) [[unlikely]] {  // repeated corners: compare whole rotations
        const uint32_t rotations[3][3] = {{a, b, c}, {b, c, a}, {c, a, b}};
        int best = 0;
        for (int r = 1; r < 3; ++r)
            if (std::lexicographical_compare(rotations[r], rotations[r] + 3, rotations[best], rotations[best] + 3)) best = r;
        std::copy(rotations[best], rotations[best] + 3, triangle);
        return;
    }
    const uint32_t corners[5] = {a, b, c, a, b};
    const int first = int(b < a && b < c) + 2 * int(c < a && c < b);  // the smallest corner's place
    triangle[0] = corners[first], triangle[1] = corners[first + 1], triangle[2] = corners[first + 2];
}

// Octahedral normals: kNormalBits-bit signed coordinates, held as snorm16x2 in a uint32 for the shaders' decoder; the
// page file stores just the bits (octahedral_to_bits). encode_octahedral picks the nearest of the four grid points
// around the direction: within kNormalMaxErrorDegrees of it (the worst of 30 M random directions was 0.1601), so N.L
// moves by at most 0.003, less than one step of 8-bit colour.
constexpr int kNormalBits = 10;
constexpr float kNormalMaxErrorDegrees = 0.17f;
uint32_t encode_octahedral(float x, float y, float z);
std::array<float, 3> decode_octahedral(uint32_t packed);
std::array<int32_t, 2> octahedral_to_bits(uint32_t packed);
uint32_t octahedral_from_bits(int32_t u, int32_t v);
uint16_t float_to_half(float value);
float half_to_float(uint16_t half);

}  // namespace tessera
