// Encodes a page unit's clusters into the page's streams (cluster_codec.h). Triangles go through meshoptimizer's
// index codec; vertices are walked in first-use order (cluster_prediction.h) and each new one leaves only residuals,
// stored as a bit width (a byte, which the page compressor entropy-codes) and the bits below the top one. Siblings
// share their borders, so a vertex equal to an earlier one of the unit is stored as a reference to it.
#include "cluster_codec.h"
#include "cluster_prediction.h"

#include <meshoptimizer.h>

#include <bit>
#include <cmath>

namespace tessera {
namespace {

// For each vertex of a unit, the first earlier one with the same position, normal and colour: open addressing over
// unit vertex numbers (no allocation per vertex).
class FirstSeen {
public:
    FirstSeen(const UnitVertices& vertices, size_t count) : vertices_(vertices), slots_(std::bit_ceil(2 * count + 2), -1) {}
    // The earlier vertex equal to `self`, or -1 (then `self` is recorded).
    int64_t find_or_add(int64_t self) {
        const size_t mask = slots_.size() - 1;
        for (size_t slot = hash(self) & mask;; slot = (slot + 1) & mask) {
            if (slots_[slot] < 0) {
                slots_[slot] = self;
                return -1;
            }
            if (equal(slots_[slot], self)) return slots_[slot];
        }
    }

private:
    size_t hash(int64_t v) const {
        // Independent products, not a chain: the lookup's result does not depend on the hash, only its speed.
        const int64_t* g = &vertices_.grid[3 * v];
        const int64_t* n = &vertices_.normal[2 * v];
        const uint64_t h = (uint64_t(g[0]) * 0x9E3779B97F4A7C15ull) ^ (uint64_t(g[1]) * 0xC2B2AE3D27D4EB4Full) ^
                           (uint64_t(g[2]) * 0x165667B19E3779F9ull) ^ (uint64_t(n[0]) * 0xff51afd7ed558ccdull) ^
                           (uint64_t(n[1]) * 0xc4ceb9fe1a85ec53ull);
        return size_t(h ^ (h >> 29));
    }
    bool equal(int64_t a, int64_t b) const {
        const bool colors = !vertices_.color.empty(), uvs = !vertices_.uv.empty();
        return std::equal(&vertices_.grid[3 * a], &vertices_.grid[3 * a + 3], &vertices_.grid[3 * b]) &&
               std::equal(&vertices_.normal[2 * a], &vertices_.normal[2 * a + 2], &vertices_.normal[2 * b]) &&
               (!colors || std::equal(&vertices_.color[2 * a], &vertices_.color[2 * a + 2], &vertices_.color[2 * b])) &&
               (!uvs || std::equal(&vertices_.uv[2 * a], &vertices_.uv[2 * a + 2], &vertices_.uv[2 * b]));
    }
    const UnitVertices& vertices_;
    std::vector<int64_t> slots_;
};

void put_residual(int64_t residual, std::vector<uint8_t>& widths, BitWriter& bits) {
    const uint64_t z = zigzag(residual);
    const uint32_t width = uint32_t(std::bit_width(z));
    widths.push_back(uint8_t(width));
    if (width > 1) bits.put(z, width - 1);  // the top bit is implied by the width
}

void put_sphere(ByteWriter& w, const std::array<float, 4>& s) {
    for (float f : s) w.put(f);
}

// Every cluster's corners (cluster-local numbers), cluster after cluster: unpacked once per unit.
std::vector<uint32_t> unit_corners(const BuiltMesh& mesh, std::span<const uint32_t> clusters) {
    size_t count = 0;
    for (uint32_t index : clusters) count += mesh.clusters[index].triangleCount;
    std::vector<uint32_t> corners(3 * count);
    uint32_t* out = corners.data();
    for (uint32_t index : clusters) {
        const Cluster& c = mesh.clusters[index];
        for (const uint32_t packed : std::span(mesh.triangles).subspan(c.triangleOffset, c.triangleCount)) {
            out[0] = packed & 0xff;
            out[1] = (packed >> 8) & 0xff;
            out[2] = (packed >> 16) & 0xff;
            out += 3;
        }
    }
    return corners;
}

void encode_records(const BuiltMesh& mesh, std::span<const uint32_t> clusters, size_t indexBytes, ByteWriter& records) {
    const Cluster& first = mesh.clusters[clusters[0]];
    records.put_varint(uint32_t(clusters.size()));
    records.put(first.parentGroup);  // siblings share their parent record: stored once
    put_sphere(records, first.parentSphere);
    records.put(first.parentError);
    records.put_varint(uint32_t(indexBytes));
    for (uint32_t index : clusters) {
        const Cluster& c = mesh.clusters[index];
        const bool sameParent = c.parentGroup == first.parentGroup && c.parentSphere == first.parentSphere &&
                                std::bit_cast<uint32_t>(c.parentError) == std::bit_cast<uint32_t>(first.parentError);
        if (!sameParent)
            throw std::invalid_argument("clusters of one parent group disagree on its bounds or error");
        if (c.level > 255 || c.vertexCount < 1 || c.vertexCount > kClusterMaxVertices || c.triangleCount < 1 || c.triangleCount > kClusterMaxTriangles)
            throw std::invalid_argument("a cluster's level or size is out of the page format's range");
        records.put(index);  // its place in the mesh (pages group clusters by parent instead)
        put_sphere(records, c.sphere);
        put_sphere(records, c.lodSphere);
        records.put(c.lodError);
        records.put(uint8_t(c.level));
        records.put(uint8_t(c.vertexCount - 1));  // 1..256 in a byte
        records.put(uint8_t(c.triangleCount - 1));
        for (int8_t k : c.cone.axis8) records.put(k);
        records.put(c.cone.cutoff8);
        records.put(c.meanTriangleArea);
        records.put(c.longestEdge);
    }
}

std::vector<uint8_t> encode_indices(const BuiltMesh& mesh, std::span<const uint32_t> clusters, std::span<const uint32_t> corners) {
    std::vector<uint32_t> unit(corners.size());
    uint32_t base = 0;
    size_t at = 0;
    for (uint32_t index : clusters) {
        const Cluster& c = mesh.clusters[index];
        for (const size_t end = at + 3 * size_t(c.triangleCount); at < end; ++at) unit[at] = base + corners[at];
        base += c.vertexCount;
    }
    std::vector<uint8_t> encoded(meshopt_encodeIndexBufferBound(unit.size(), base));
    encoded.resize(meshopt_encodeIndexBuffer(encoded.data(), encoded.size(), unit.data(), unit.size()));
    return encoded;
}

// A value's integer coordinate on a power-of-two grid. value / step is exact (powers of two), so the value is on the
// grid exactly when that quotient is an integer below kGridLimit (a truncation: llround, a library call, cost more).
int64_t grid_coordinate(float value, double step, const char* offGrid) {
    const double scaled = double(value) / step;
    if (!(std::fabs(scaled) < double(kGridLimit)) || double(int64_t(scaled)) != scaled) throw std::invalid_argument(offGrid);
    return int64_t(scaled);
}

// The unit's vertices as integers: grid coordinates and normal bits, both checked to give back the mesh's values.
UnitVertices unit_vertices(const BuiltMesh& mesh, std::span<const uint32_t> clusters) {
    const bool colors = !mesh.colors.empty(), uvs = !mesh.uvs.empty();
    const double uvStep = std::ldexp(1.0, mesh.uvPrecision);
    size_t count = 0;
    for (uint32_t index : clusters) count += mesh.clusters[index].vertexCount;
    UnitVertices vertices;
    vertices.resize(count, colors, uvs);
    size_t at = 0;
    for (uint32_t index : clusters) {
        const Cluster& c = mesh.clusters[index];
        for (size_t source = c.vertexOffset; source < c.vertexOffset + c.vertexCount; ++source, ++at) {
            for (int k = 0; k < 3; ++k) {
                vertices.grid[3 * at + k] = grid_coordinate(mesh.positions[3 * source + k], mesh.positionStep, "a position is off the mesh's grid");
            }
            const auto normal = octahedral_to_bits(mesh.normals[source]);
            if (octahedral_from_bits(normal[0], normal[1]) != mesh.normals[source])
                throw std::invalid_argument("a normal is not a " + std::to_string(kNormalBits) + "-bit octahedral one (encode_octahedral)");
            vertices.normal[2 * at] = normal[0];
            vertices.normal[2 * at + 1] = normal[1];
            if (colors) std::copy_n(&mesh.colors[2 * source], 2, &vertices.color[2 * at]);
            for (int k = 0; uvs && k < 2; ++k) {
                vertices.uv[2 * at + k] = grid_coordinate(mesh.uvs[2 * source + k], uvStep, "a texture coordinate is off the mesh's UV grid");
            }
        }
    }
    return vertices;
}

}  // namespace

void encode_unit(const BuiltMesh& mesh, std::span<const uint32_t> clusters, PageStreams& out) {
    const bool colors = !mesh.colors.empty();
    const std::vector<uint32_t> unitCorners = unit_corners(mesh, clusters);
    const std::vector<uint8_t> indices = encode_indices(mesh, clusters, unitCorners);
    ByteWriter records, codes;
    encode_records(mesh, clusters, indices.size(), records);
    const UnitVertices vertices = unit_vertices(mesh, clusters);
    FirstSeen firstSeen(vertices, vertices.normal.size() / 2);
    thread_local OppositeCorners opposite;  // 128 KiB: made once per thread, not per unit
    BitWriter bits;
    int64_t first = 0, nextReference = 0;
    size_t cornerAt = 0;
    for (uint32_t index : clusters) {
        const Cluster& c = mesh.clusters[index];
        const std::span<const uint32_t> triangles = std::span(unitCorners).subspan(cornerAt, 3 * size_t(c.triangleCount));
        cornerAt += triangles.size();
        for (size_t t = 0; t < triangles.size(); t += 3) {
            if ((mesh.triangles[c.triangleOffset + t / 3] >> 24) >= mesh.materialSlots)
                throw std::invalid_argument("a triangle's material slot is not below the mesh's materialSlots");
            if (triangles[t] < triangles[t + 1] && triangles[t] < triangles[t + 2]) continue;  // the usual case: in order
            uint32_t tri[3] = {triangles[t], triangles[t + 1], triangles[t + 2]};
            rotate_smallest_first(tri);
            if (!std::equal(tri, tri + 3, &triangles[t]))
                throw std::invalid_argument("a cluster's triangles are not in page order (order_cluster_for_pages)");
        }
        if (mesh.materialSlots > 1)
            for (uint32_t t = 0; t < c.triangleCount; ++t) out[kMaterialStream].push_back(uint8_t(mesh.triangles[c.triangleOffset + t] >> 24));
        const bool ordered = walk_first_use(triangles, c.vertexCount, opposite, [&](uint32_t v, const Neighbours& n) {
            const int64_t self = first + v;
            if (const int64_t seen = firstSeen.find_or_add(self); seen >= 0) {  // a copy: its source, relative to the last one's
                codes.put_varint(uint32_t(zigzag(seen - nextReference) + 1));
                nextReference = seen + 1;
                return;
            }
            codes.put_varint(0);
            const Predictor predict(n, first, self);
            for (int k = 0; k < 3; ++k) put_residual(vertices.grid[3 * self + k] - predict(vertices.grid, 3, k), out[kPositionWidthStream], bits);
            for (int k = 0; k < 2; ++k) put_residual(vertices.normal[2 * self + k] - predict(vertices.normal, 2, k), out[kNormalWidthStream], bits);
            if (colors)
                for (int k = 0; k < 2; ++k)
                    for (int byte = 0; byte < 4; ++byte) out[kColorStream].push_back(uint8_t(vertices.color[2 * self + k] >> (8 * byte)));
            if (!vertices.uv.empty())
                for (int k = 0; k < 2; ++k) put_residual(vertices.uv[2 * self + k] - predict(vertices.uv, 2, k), out[kUvWidthStream], bits);
        });
        if (!ordered) throw std::invalid_argument("a cluster's vertices are not numbered by first use (order_cluster_for_pages)");
        first += c.vertexCount;
    }
    bits.flush();
    auto append = [&](PageStream s, const std::vector<uint8_t>& bytes) { out[s].insert(out[s].end(), bytes.begin(), bytes.end()); };
    append(kRecordStream, records.bytes);
    append(kIndexStream, indices);
    append(kVertexCodeStream, codes.bytes);
    append(kResidualBitStream, bits.bytes);
}

}  // namespace tessera
