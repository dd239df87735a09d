// Internal to the builder: the clusters of one page unit (the children of one group, or one root cluster) as
// streams that compress well (cluster_encoder.cpp, cluster_decoder.cpp); pages.cpp compresses each stream of a page
// on its own.
#pragma once

#include "byte_streams.h"
#include "cluster_prediction.h"

#include <array>
#include <bit>
#include <memory>

namespace tessera {

// Like data go together: each stream is compressed on its own.
enum PageStream : uint32_t {
    kRecordStream,         // unit and cluster records: bounds, LOD, counts, index stream sizes
    kIndexStream,          // meshoptimizer's index codec, one buffer per unit
    kVertexCodeStream,     // per vertex: new, or a copy of an earlier vertex of the unit
    kPositionWidthStream,  // bit width of each position residual
    kNormalWidthStream,    // bit width of each normal residual
    kColorStream,          // rgba16f of new vertices
    kUvWidthStream,        // bit width of each texture coordinate residual
    kMaterialStream,       // each triangle's material slot, when the mesh has several (runs: compresses to little)
    kResidualBitStream,    // the residuals' bits below their top one
    kPageStreamCount
};
using PageStreams = std::array<std::vector<uint8_t>, kPageStreamCount>;

// Appends the unit's clusters to the streams. Throws std::invalid_argument for a mesh build_mesh would not make
// (clusters not in page order, siblings with different parent records, off-grid positions).
void encode_unit(const BuiltMesh& mesh, std::span<const uint32_t> clusters, PageStreams& out);

// At most how many bytes encode_unit writes for a unit, from its clusters' vertex and triangle counts: every vertex
// new, every residual as wide as the values' range allows, the index codec's bound for up to 2^20 vertices. A page
// holds whole units, so the builder splits a group whose children could encode to more than a page (dag.cpp): a noisy
// faceted mesh with texture coordinates and colours per corner, every corner its own vertex, made units of 135 KiB.
struct UnitBytesBound {
    // The bits of one residual of values within [-largest, largest]: a width byte, and below the top bit of its zigzag
    // code (a parallelogram prediction lies within 3x the range, so the residual within 4x).
    static uint32_t residual_bits(uint64_t largest) { return 8 + uint32_t(std::bit_width(8 * largest)) - 1; }

    uint32_t positionBits = residual_bits(uint64_t(kGridLimit));  // per grid coordinate
    uint32_t uvBits = 0;                                          // per texture coordinate (0: none)
    bool colors = false, slots = false;                           // a colour per vertex, a material slot per triangle

    // The unit's record (count, parent group, sphere, error, index bytes) and the index codec's header and tail.
    static constexpr size_t kUnitBytes = 5 + 4 + 16 + 4 + 5 + 17;
    size_t cluster(uint32_t vertices, uint32_t triangles) const {
        constexpr size_t kRecordBytes = 4 + 16 + 16 + 4 + 3 + 4 + 4 + 4;  // encode_records, per cluster
        const size_t normalBits = residual_bits((1u << (kNormalBits - 1)) - 1);
        const size_t vertexBits = 8 + 3 * positionBits + 2 * normalBits + 2 * uvBits + (colors ? 64 : 0);
        const size_t triangleBytes = 2 + 3 * 3 + (slots ? 1 : 0);  // the index codec's worst (3 varint groups a corner), a slot
        return kRecordBytes + triangles * triangleBytes + (vertices * vertexBits + 7) / 8 + 1;
    }
};

struct DecodedCluster {
    uint32_t index = 0;  // its place in the mesh
    Cluster cluster{};
    std::vector<float> positions;
    std::vector<float> uvs;
    std::vector<uint32_t> normals, colors, triangles;
};

// What the page file's header says about every vertex and triangle of the mesh.
struct VertexFormat {
    double positionStep = 1.0;
    bool colors = false;
    bool uvs = false;
    double uvStep = 1.0;
    uint32_t materialSlots = 1;  // more than 1: each triangle stores its slot
};

// Reads units back, in order, from one page's decompressed streams; every malformed input is a PageFileError.
class UnitDecoder {
public:
    UnitDecoder(const PageStreams& streams, const VertexFormat& format, const std::string& where);
    ~UnitDecoder();
    void decode_unit(std::vector<DecodedCluster>& out);
    bool done() const;  // every stream consumed

private:
    struct State;
    std::unique_ptr<State> state_;
};

}  // namespace tessera
