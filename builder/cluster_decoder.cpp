// Decodes page units back into clusters (cluster_codec.h): the encoder's walk (cluster_prediction.h), reading where
// it writes. Every read is checked: a malformed stream is a PageFileError, never a read past the data.
#include "cluster_codec.h"
#include "cluster_prediction.h"

#include <meshoptimizer.h>

namespace tessera {

struct UnitDecoder::State {
    State(const PageStreams& s, const VertexFormat& format, const std::string& where)
        : records(s[kRecordStream], where + " records"),
          indices(s[kIndexStream], where + " indices"),
          codes(s[kVertexCodeStream], where + " vertices"),
          positionWidths(s[kPositionWidthStream], where + " positions"),
          normalWidths(s[kNormalWidthStream], where + " normals"),
          colorBytes(s[kColorStream], where + " colours"),
          uvWidths(s[kUvWidthStream], where + " texture coordinates"),
          materials(s[kMaterialStream], where + " material slots"),
          bits(s[kResidualBitStream], where + " residuals"),
          format(format),
          colors(format.colors),
          uvs(format.uvs),
          where(where) {}
    ByteReader records, indices, codes, positionWidths, normalWidths, colorBytes, uvWidths, materials;
    BitReader bits;
    VertexFormat format;
    bool colors, uvs;
    std::string where;
    OppositeCorners opposite;
    UnitVertices vertices;
    std::vector<uint32_t> corners;

    int64_t residual(ByteReader& widths) {
        const uint32_t width = widths.get<uint8_t>();
        if (width > kMaxResidualBits) throw PageFileError(where + ": a residual of " + std::to_string(width) + " bits");
        return width ? unzigzag((uint64_t(1) << (width - 1)) | bits.get(width - 1)) : 0;
    }
    std::array<float, 4> sphere() {
        std::array<float, 4> s;
        for (float& f : s) f = records.get<float>();
        return s;
    }

    // The unit's records appended to `out`; returns the size of its index stream.
    uint32_t read_records(std::vector<DecodedCluster>& out) {
        const uint32_t clusterCount = records.get_varint();
        if (clusterCount == 0) throw PageFileError(where + ": an empty cluster group");
        Cluster parent{};
        parent.parentGroup = records.get<uint32_t>();
        parent.parentSphere = sphere();
        parent.parentError = records.get<float>();
        const uint32_t indexBytes = records.get_varint();
        for (uint32_t i = 0; i < clusterCount; ++i) {
            DecodedCluster& d = out.emplace_back();
            Cluster& c = d.cluster;
            c = parent;
            d.index = records.get<uint32_t>();
            c.sphere = sphere();
            c.lodSphere = sphere();
            c.lodError = records.get<float>();
            c.level = records.get<uint8_t>();
            c.vertexCount = uint32_t(records.get<uint8_t>()) + 1;
            c.triangleCount = uint32_t(records.get<uint8_t>()) + 1;
            if (c.triangleCount > kClusterMaxTriangles)
                throw PageFileError(where + ": a cluster has more than " + std::to_string(kClusterMaxTriangles) + " triangles");
            for (int8_t& k : c.cone.axis8) k = records.get<int8_t>();
            c.cone.cutoff8 = records.get<int8_t>();
            c.meanTriangleArea = records.get<float>();
            c.longestEdge = records.get<float>();
        }
        return indexBytes;
    }

    // One vertex of the unit, where the walk reaches it: a copy of an earlier one, or a prediction and residuals.
    void read_vertex(int64_t self, const Predictor& predict, int64_t& nextReference) {
        if (const uint32_t code = codes.get_varint()) {
            const int64_t source = nextReference + unzigzag(code - 1);
            if (source < 0 || source >= self) throw PageFileError(where + ": a vertex copies one that does not come before it");
            std::copy_n(&vertices.grid[3 * source], 3, &vertices.grid[3 * self]);
            std::copy_n(&vertices.normal[2 * source], 2, &vertices.normal[2 * self]);
            if (colors) std::copy_n(&vertices.color[2 * source], 2, &vertices.color[2 * self]);
            if (uvs) std::copy_n(&vertices.uv[2 * source], 2, &vertices.uv[2 * self]);
            nextReference = source + 1;
            return;
        }
        for (int k = 0; k < 3; ++k) {
            const int64_t grid = predict(vertices.grid, 3, k) + residual(positionWidths);
            if (grid <= -kGridLimit || grid >= kGridLimit) throw PageFileError(where + ": a position is out of range");
            vertices.grid[3 * self + k] = grid;
        }
        for (int k = 0; k < 2; ++k) {
            const int64_t normal = predict(vertices.normal, 2, k) + residual(normalWidths);
            if (normal < -kNormalMax || normal > kNormalMax) throw PageFileError(where + ": a normal is out of range");
            vertices.normal[2 * self + k] = normal;
        }
        if (colors)
            for (int k = 0; k < 2; ++k) vertices.color[2 * self + k] = colorBytes.get<uint32_t>();
        for (int k = 0; uvs && k < 2; ++k) {
            const int64_t uv = predict(vertices.uv, 2, k) + residual(uvWidths);
            if (uv <= -kGridLimit || uv >= kGridLimit) throw PageFileError(where + ": a texture coordinate is out of range");
            vertices.uv[2 * self + k] = uv;
        }
    }

    // A decoded cluster's vertices as the builder lays them out.
    void write_vertices(DecodedCluster& d, int64_t first) const {
        const uint32_t count = d.cluster.vertexCount;
        d.positions.reserve(3 * count);
        d.normals.reserve(count);
        for (int64_t at = first; at < first + count; ++at) {
            for (int k = 0; k < 3; ++k) d.positions.push_back(float(double(vertices.grid[3 * at + k]) * format.positionStep) + 0.0f);
            for (int k = 0; uvs && k < 2; ++k) d.uvs.push_back(float(double(vertices.uv[2 * at + k]) * format.uvStep) + 0.0f);
            d.normals.push_back(octahedral_from_bits(int32_t(vertices.normal[2 * at]), int32_t(vertices.normal[2 * at + 1])));
            if (colors) d.colors.insert(d.colors.end(), &vertices.color[2 * at], &vertices.color[2 * at] + 2);
        }
    }
};

UnitDecoder::UnitDecoder(const PageStreams& streams, const VertexFormat& format, const std::string& where)
    : state_(std::make_unique<State>(streams, format, where)) {}
UnitDecoder::~UnitDecoder() = default;

bool UnitDecoder::done() const {
    State& s = *state_;
    return s.records.done() && s.indices.done() && s.codes.done() && s.positionWidths.done() && s.normalWidths.done() && s.colorBytes.done() &&
           s.uvWidths.done() && s.materials.done() &&
           s.bits.bytes_left() == 0;
}

void UnitDecoder::decode_unit(std::vector<DecodedCluster>& out) {
    State& s = *state_;
    const size_t firstOut = out.size();
    const uint32_t indexBytes = s.read_records(out);
    size_t triangles = 0, unitVertices = 0;
    for (size_t i = firstOut; i < out.size(); ++i) {
        triangles += out[i].cluster.triangleCount;
        unitVertices += out[i].cluster.vertexCount;
    }
    s.corners.resize(3 * triangles);
    const std::span<const uint8_t> encoded = s.indices.take(indexBytes);
    if (meshopt_decodeIndexBuffer(s.corners.data(), s.corners.size(), 4, encoded.data(), encoded.size()) != 0)
        throw PageFileError(s.where + ": a cluster group's triangles do not decode");

    s.vertices.resize(unitVertices, s.colors, s.uvs);
    int64_t first = 0, nextReference = 0;
    size_t corner = 0;
    for (size_t i = firstOut; i < out.size(); ++i) {
        DecodedCluster& d = out[i];
        const uint32_t vertexCount = d.cluster.vertexCount;
        const std::span<uint32_t> local(&s.corners[corner], 3 * d.cluster.triangleCount);
        corner += local.size();
        d.triangles.reserve(local.size() / 3);
        for (size_t t = 0; t < local.size(); t += 3) {
            for (uint32_t* index = &local[t]; index < &local[t + 3]; ++index)
                if ((*index -= uint32_t(first)) >= vertexCount) throw PageFileError(s.where + ": a triangle refers past its cluster's vertices");
            rotate_smallest_first(&local[t]);  // the codec may have rotated it; the smallest rotation is the stored one
            uint32_t slot = 0;
            if (s.format.materialSlots > 1 && (slot = s.materials.get<uint8_t>()) >= s.format.materialSlots)
                throw PageFileError(s.where + ": a triangle's material slot is out of range");
            d.triangles.push_back(local[t] | (local[t + 1] << 8) | (local[t + 2] << 16) | slot << 24);
        }
        const bool ordered = walk_first_use(local, vertexCount, s.opposite, [&](uint32_t v, const Neighbours& n) {
            s.read_vertex(first + v, Predictor(n, first, first + v), nextReference);
        });
        if (!ordered) throw PageFileError(s.where + ": a cluster's vertices are not in first-use order");
        s.write_vertices(d, first);
        first += vertexCount;
    }
    s.bits.skip_to_byte();  // each unit's residual bits end on a byte
}

}  // namespace tessera
