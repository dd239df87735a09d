// Internal to the builder: the clusters of one page unit (the children of one group, or one root cluster) as
// streams that compress well (cluster_encoder.cpp, cluster_decoder.cpp); pages.cpp compresses each stream of a page
// on its own.
#pragma once

#include "byte_streams.h"

#include <array>
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
