// Tessera builder: turns an authored polygon mesh into clusters the renderer can draw.
// Knows only meshes: no USD, no Vulkan. The entry points are prepare_mesh() then build_clusters().
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace tessera {

// Cluster budget (the renderer checks these against shaders/shared.h).
constexpr uint32_t kClusterMaxTriangles = 128;
constexpr uint32_t kClusterMaxVertices = 256;

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
struct MeshView {
    std::string name;                          // used in every message (a prim path, say)
    std::span<const float> points;             // 3 floats per point
    std::span<const int32_t> faceVertexCounts;
    std::span<const int32_t> faceVertexIndices;
    std::span<const int32_t> holeIndices;      // faces not drawn
    bool leftHanded = false;                   // faces wind clockwise
    PrimvarView normals;                       // 3 components
    PrimvarView displayColor;                  // 3 components
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
    std::vector<float> colors;         // 3 per vertex when the mesh has varying displayColor, else empty
    std::array<float, 3> constantColor{0.5f, 0.5f, 0.5f};
    bool hasConstantColor = false;     // displayColor authored with constant interpolation
    std::vector<uint32_t> indices;     // 3 per triangle
    std::vector<uint32_t> sourceFaces; // per triangle, the authored face it came from
    std::vector<std::string> warnings; // dropped faces and the like, each naming the mesh
};

// Validates and triangulates. Bad faces (out-of-range indices, fewer than 3 vertices, non-finite points)
// are dropped with a warning; a mesh with nothing left to draw, or whose arrays do not fit together,
// throws MeshError naming the mesh and the problem.
PreparedMesh prepare_mesh(const MeshView& mesh);

struct Cluster {
    std::array<float, 4> sphere;  // centre (mesh space, relative to BuiltMesh::origin) and radius
    uint32_t vertexOffset;        // into BuiltMesh vertex streams
    uint32_t vertexCount;         // <= 256
    uint32_t triangleOffset;      // into BuiltMesh::triangles
    uint32_t triangleCount;       // <= 128
};

// Clusters over cluster-local vertex streams. Positions are relative to `origin` (computed in double), so a
// mesh authored far from the origin keeps its precision once its origin moves into the instance transform.
struct BuiltMesh {
    std::array<double, 3> origin{};
    std::vector<float> positions;       // 3 per vertex, relative to origin
    std::vector<uint32_t> normals;      // octahedral, snorm16x2
    std::vector<uint32_t> colors;       // 2 per vertex (rgba16f) when the mesh has vertex colours
    std::vector<uint32_t> triangles;    // 3 x 8-bit cluster-local indices per triangle
    std::vector<Cluster> clusters;
    std::array<float, 4> sphere{};     // whole mesh, relative to origin
    std::array<float, 3> constantColor{0.5f, 0.5f, 0.5f};
    bool hasConstantColor = false;
    size_t sourceTriangles = 0;
};

// Splits the prepared triangles into spatially compact clusters (Morton order of triangle centroids).
BuiltMesh build_clusters(const PreparedMesh& mesh);

// Octahedral normal encoding (snorm16x2 packed in a uint32), shared with the shaders' decoder.
uint32_t encode_octahedral(float x, float y, float z);
std::array<float, 3> decode_octahedral(uint32_t packed);
uint16_t float_to_half(float value);

}  // namespace tessera
