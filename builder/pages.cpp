// The page file: a BuiltMesh on disk.
//
//   header      (kHeaderBytes)  magic "TSRA", version, counts, origin, precision, size, colour mode, checksum
//   page table  (pages x 24)    per page: offset (u64), bytes, first cluster, cluster count, CRC32; then its CRC32
//   pages                       clusters, each: fixed record + bit-packed positions + normals [+ colours] + triangles
//
// All little-endian. Positions are grid offsets from the cluster's minimum with per-axis bit widths: the grid makes
// them exact, so decoding gives back the built positions bit for bit.
#include "tessera/builder.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <map>

static_assert(std::endian::native == std::endian::little, "the page format is little-endian; add byte swaps for big-endian hosts");

namespace tessera {
namespace {

constexpr char kMagic[4] = {'T', 'S', 'R', 'A'};
constexpr size_t kHeaderBytes = 112;
constexpr size_t kPageEntryBytes = 24;

class Writer {
public:
    template <typename T>
    void put(const T& value) {
        const size_t at = bytes.size();
        bytes.resize(at + sizeof(T));
        std::memcpy(&bytes[at], &value, sizeof(T));
    }
    void put_bits(uint32_t value, uint32_t bits) {  // LSB-first bit stream; flush() ends it on a byte
        for (uint32_t b = 0; b < bits; ++b) {
            if (bitCount_ % 8 == 0) bytes.push_back(0);
            bytes.back() |= uint8_t(((value >> b) & 1u) << (bitCount_ % 8));
            ++bitCount_;
        }
    }
    void flush_bits() { bitCount_ = 0; }
    std::vector<uint8_t> bytes;

private:
    size_t bitCount_ = 0;
};

class Reader {
public:
    Reader(std::span<const uint8_t> bytes, const std::string& where) : bytes_(bytes), where_(where) {}
    template <typename T>
    T get() {
        need(sizeof(T));
        T value;
        std::memcpy(&value, &bytes_[at_], sizeof(T));
        at_ += sizeof(T);
        return value;
    }
    uint32_t get_bits(uint32_t bits) {
        uint32_t value = 0;
        for (uint32_t b = 0; b < bits; ++b) {
            if (bit_ == 0) need(1);
            value |= uint32_t((bytes_[at_] >> bit_) & 1u) << b;
            if (++bit_ == 8) {
                bit_ = 0;
                ++at_;
            }
        }
        return value;
    }
    void end_bits() {
        if (bit_) {
            bit_ = 0;
            ++at_;
        }
    }
    size_t position() const { return at_; }
    bool done() const { return at_ == bytes_.size(); }

private:
    void need(size_t n) {
        if (at_ + n > bytes_.size()) throw PageFileError(where_ + ": data ends early");
    }
    std::span<const uint8_t> bytes_;
    std::string where_;
    size_t at_ = 0;
    uint32_t bit_ = 0;
};

uint32_t bits_for(uint32_t range) { return range ? uint32_t(std::bit_width(range)) : 0u; }

void put_sphere(Writer& w, const std::array<float, 4>& s) {
    for (float f : s) w.put(f);
}
std::array<float, 4> get_sphere(Reader& r) {
    std::array<float, 4> s;
    for (float& f : s) f = r.get<float>();
    return s;
}

// One cluster: its record, then its streams.
void encode_cluster(Writer& w, const BuiltMesh& mesh, uint32_t index, bool colors) {
    const Cluster& c = mesh.clusters[index];
    int32_t lo[3] = {INT32_MAX, INT32_MAX, INT32_MAX}, hi[3] = {INT32_MIN, INT32_MIN, INT32_MIN};
    std::vector<int32_t> grid(3 * c.vertexCount);
    for (uint32_t v = 0; v < c.vertexCount; ++v)
        for (int k = 0; k < 3; ++k) {
            const double q = double(mesh.positions[3 * (c.vertexOffset + v) + k]) / mesh.positionStep;  // exact: a grid point
            grid[3 * v + k] = int32_t(q);
            lo[k] = std::min(lo[k], grid[3 * v + k]);
            hi[k] = std::max(hi[k], grid[3 * v + k]);
        }
    uint8_t bits[3];
    for (int k = 0; k < 3; ++k) bits[k] = uint8_t(bits_for(uint32_t(int64_t(hi[k]) - lo[k])));
    w.put(index);  // its place in the mesh (file order groups clusters by parent instead)
    put_sphere(w, c.sphere);
    put_sphere(w, c.lodSphere);
    w.put(c.lodError);
    put_sphere(w, c.parentSphere);
    w.put(c.parentError);
    w.put(c.parentGroup);
    w.put(uint8_t(c.level));
    w.put(uint8_t(c.vertexCount - 1));  // 1..256 in a byte
    w.put(uint8_t(c.triangleCount - 1));
    for (int k = 0; k < 3; ++k) w.put(bits[k]);
    for (int k = 0; k < 3; ++k) w.put(lo[k]);
    for (uint32_t v = 0; v < c.vertexCount; ++v)
        for (int k = 0; k < 3; ++k) w.put_bits(uint32_t(int64_t(grid[3 * v + k]) - lo[k]), bits[k]);
    w.flush_bits();
    for (uint32_t v = 0; v < c.vertexCount; ++v) w.put(mesh.normals[c.vertexOffset + v]);
    if (colors)
        for (uint32_t v = 0; v < c.vertexCount; ++v) {
            w.put(mesh.colors[2 * (c.vertexOffset + v)]);
            w.put(mesh.colors[2 * (c.vertexOffset + v) + 1]);
        }
    for (uint32_t t = 0; t < c.triangleCount; ++t) {
        const uint32_t packed = mesh.triangles[c.triangleOffset + t];
        w.put(uint8_t(packed));
        w.put(uint8_t(packed >> 8));
        w.put(uint8_t(packed >> 16));
    }
}

struct DecodedCluster {
    Cluster cluster{};
    std::vector<float> positions;
    std::vector<uint32_t> normals, colors, triangles;
};

DecodedCluster decode_cluster(Reader& r, double step, bool colors, const std::string& where) {
    DecodedCluster d;
    Cluster& c = d.cluster;
    c.sphere = get_sphere(r);
    c.lodSphere = get_sphere(r);
    c.lodError = r.get<float>();
    c.parentSphere = get_sphere(r);
    c.parentError = r.get<float>();
    c.parentGroup = r.get<uint32_t>();
    c.level = r.get<uint8_t>();
    c.vertexCount = uint32_t(r.get<uint8_t>()) + 1;
    c.triangleCount = uint32_t(r.get<uint8_t>()) + 1;
    uint8_t bits[3];
    for (uint8_t& b : bits) {
        b = r.get<uint8_t>();
        if (b > 24) throw PageFileError(where + ": a cluster's position width is " + std::to_string(b) + " bits (at most 24)");
    }
    if (c.triangleCount > kClusterMaxTriangles) throw PageFileError(where + ": a cluster has more than 128 triangles");
    int32_t lo[3];
    for (int32_t& v : lo) v = r.get<int32_t>();
    for (uint32_t v = 0; v < c.vertexCount; ++v)
        for (int k = 0; k < 3; ++k) d.positions.push_back(float(double(int64_t(lo[k]) + r.get_bits(bits[k])) * step) + 0.0f);
    r.end_bits();
    for (uint32_t v = 0; v < c.vertexCount; ++v) d.normals.push_back(r.get<uint32_t>());
    if (colors)
        for (uint32_t v = 0; v < 2 * c.vertexCount; ++v) d.colors.push_back(r.get<uint32_t>());
    for (uint32_t t = 0; t < c.triangleCount; ++t) {
        uint32_t packed = 0;
        for (int k = 0; k < 3; ++k) {
            const uint32_t index = r.get<uint8_t>();
            if (index >= c.vertexCount) throw PageFileError(where + ": a triangle refers past its cluster's vertices");
            packed |= index << (8 * k);
        }
        d.triangles.push_back(packed);
    }
    return d;
}

}  // namespace

uint32_t crc32(std::span<const uint8_t> bytes) {
    static const auto table = [] {
        std::array<uint32_t, 256> t{};
        for (uint32_t i = 0; i < 256; ++i) {
            uint32_t c = i;
            for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
            t[i] = c;
        }
        return t;
    }();
    uint32_t crc = 0xffffffffu;
    for (uint8_t b : bytes) crc = table[(crc ^ b) & 0xff] ^ (crc >> 8);
    return crc ^ 0xffffffffu;
}

std::vector<uint8_t> encode_pages(const BuiltMesh& mesh, PageLayout* layout) {
    const bool colors = !mesh.colors.empty();
    // Page units: the children of one parent group together; roots on their own, in root pages first.
    std::map<uint32_t, std::vector<uint32_t>> byParent;  // ordered: deterministic bytes
    for (uint32_t i = 0; i < mesh.clusters.size(); ++i) byParent[mesh.clusters[i].parentGroup].push_back(i);
    std::vector<std::vector<uint32_t>> units;
    if (byParent.count(kNoGroup))
        for (uint32_t root : byParent[kNoGroup]) units.push_back({root});
    const size_t rootUnits = units.size();
    for (auto& [parent, members] : byParent)
        if (parent != kNoGroup) units.push_back(members);

    struct Page {
        std::vector<uint8_t> bytes;
        uint32_t firstCluster, clusters;
        std::vector<uint32_t> members;
    };
    std::vector<Page> pages;
    uint32_t rootPages = 0, written = 0;
    for (size_t u = 0; u < units.size(); ++u) {
        Writer unit;
        for (uint32_t c : units[u]) encode_cluster(unit, mesh, c, colors);
        if (unit.bytes.size() > kPageBytes) throw std::runtime_error("a cluster group does not fit in a page");
        const bool rootUnit = u < rootUnits;
        const bool startPage = pages.empty() || pages.back().bytes.size() + unit.bytes.size() > kPageBytes || (!rootUnit && u == rootUnits);
        if (startPage) {
            pages.push_back({{}, written, 0, {}});
            rootPages += rootUnit;
        }
        pages.back().bytes.insert(pages.back().bytes.end(), unit.bytes.begin(), unit.bytes.end());
        pages.back().clusters += uint32_t(units[u].size());
        pages.back().members.insert(pages.back().members.end(), units[u].begin(), units[u].end());
        written += uint32_t(units[u].size());
    }

    Writer header;
    for (char ch : kMagic) header.put(ch);
    header.put(kPageFormatVersion);
    header.put(kPageBytes);
    header.put(uint32_t(pages.size()));
    header.put(rootPages);
    header.put(uint32_t(mesh.clusters.size()));
    header.put(mesh.groups);
    header.put(uint32_t(colors));
    for (double o : mesh.origin) header.put(o);
    header.put(int32_t(mesh.positionPrecision));
    header.put(mesh.size);
    header.put(uint64_t(mesh.sourceTriangles));
    for (float c : mesh.constantColor) header.put(c);
    header.put(uint32_t(mesh.hasConstantColor));
    for (float f : mesh.sphere) header.put(f);
    header.bytes.resize(kHeaderBytes - 4, 0);
    header.put(crc32(header.bytes));

    Writer table;
    uint64_t offset = kHeaderBytes + pages.size() * kPageEntryBytes + 4;
    for (const Page& page : pages) {
        table.put(offset);
        table.put(uint32_t(page.bytes.size()));
        table.put(page.firstCluster);
        table.put(page.clusters);
        table.put(crc32(page.bytes));
        offset += page.bytes.size();
    }
    table.put(crc32(table.bytes));

    std::vector<uint8_t> file = std::move(header.bytes);
    file.insert(file.end(), table.bytes.begin(), table.bytes.end());
    for (const Page& page : pages) file.insert(file.end(), page.bytes.begin(), page.bytes.end());
    if (layout) {
        *layout = {uint32_t(pages.size()), rootPages, file.size(), {}};
        for (const Page& page : pages) layout->pageClusters.push_back(page.members);
    }
    return file;
}

BuiltMesh decode_pages(std::span<const uint8_t> bytes, const std::string& name) {
    if (bytes.size() < kHeaderBytes) throw PageFileError(name + ": truncated (" + std::to_string(bytes.size()) + " bytes, shorter than the header)");
    if (std::memcmp(bytes.data(), kMagic, 4) != 0) throw PageFileError(name + ": not a Tessera DAG file");
    Reader header(bytes.first(kHeaderBytes), name + ": header");
    header.get<uint32_t>();  // magic
    const uint32_t version = header.get<uint32_t>();
    if (version != kPageFormatVersion)
        throw PageFileError(name + ": format version " + std::to_string(version) + ", this build reads version " + std::to_string(kPageFormatVersion));
    uint32_t storedHeaderCrc;
    std::memcpy(&storedHeaderCrc, &bytes[kHeaderBytes - 4], 4);
    if (crc32(bytes.first(kHeaderBytes - 4)) != storedHeaderCrc) throw PageFileError(name + ": header checksum mismatch (corrupt file)");
    const uint32_t pageBytes = header.get<uint32_t>(), pageCount = header.get<uint32_t>(), rootPages = header.get<uint32_t>();
    const uint32_t clusterCount = header.get<uint32_t>();
    BuiltMesh mesh;
    mesh.groups = header.get<uint32_t>();
    const bool colors = header.get<uint32_t>() != 0;
    for (double& o : mesh.origin) o = header.get<double>();
    mesh.positionPrecision = header.get<int32_t>();
    if (mesh.positionPrecision < -1074 || mesh.positionPrecision > 1023) throw PageFileError(name + ": invalid position precision");
    mesh.positionStep = std::ldexp(1.0, mesh.positionPrecision);
    mesh.size = header.get<float>();
    mesh.sourceTriangles = header.get<uint64_t>();
    for (float& c : mesh.constantColor) c = header.get<float>();
    mesh.hasConstantColor = header.get<uint32_t>() != 0;
    for (float& f : mesh.sphere) f = header.get<float>();
    if (pageBytes != kPageBytes || rootPages > pageCount) throw PageFileError(name + ": inconsistent header");

    const size_t tableBytes = size_t(pageCount) * kPageEntryBytes + 4;
    if (bytes.size() < kHeaderBytes + tableBytes) throw PageFileError(name + ": truncated page table");
    const auto table = bytes.subspan(kHeaderBytes, tableBytes);
    uint32_t storedTableCrc;
    std::memcpy(&storedTableCrc, &table[tableBytes - 4], 4);
    if (crc32(table.first(tableBytes - 4)) != storedTableCrc) throw PageFileError(name + ": page table checksum mismatch (corrupt file)");
    Reader entries(table, name + ": page table");
    std::vector<DecodedCluster> decoded(clusterCount);
    std::vector<uint8_t> seen(clusterCount, 0);
    uint32_t expectedFirst = 0;
    for (uint32_t p = 0; p < pageCount; ++p) {
        const uint64_t offset = entries.get<uint64_t>();
        const uint32_t size = entries.get<uint32_t>(), first = entries.get<uint32_t>(), count = entries.get<uint32_t>(), crc = entries.get<uint32_t>();
        const std::string where = name + ": page " + std::to_string(p);
        if (size > kPageBytes || offset > bytes.size() || bytes.size() - offset < size) throw PageFileError(where + " is truncated or out of bounds");
        if (first != expectedFirst || count > clusterCount - first) throw PageFileError(where + " has an inconsistent cluster range");
        expectedFirst += count;
        const auto page = bytes.subspan(offset, size);
        if (crc32(page) != crc) throw PageFileError(where + ": checksum mismatch (corrupt file)");
        Reader reader(page, where);
        for (uint32_t c = 0; c < count; ++c) {
            const uint32_t index = reader.get<uint32_t>();
            if (index >= clusterCount || seen[index]) throw PageFileError(where + ": a cluster index is out of range or repeated");
            seen[index] = 1;
            decoded[index] = decode_cluster(reader, mesh.positionStep, colors, where);
        }
        if (!reader.done()) throw PageFileError(where + ": has trailing bytes");
    }
    if (expectedFirst != clusterCount) throw PageFileError(name + ": holds " + std::to_string(expectedFirst) + " clusters, the header says " + std::to_string(clusterCount));

    // Back into build order (level 0 first), with the streams laid out as the builder lays them out.
    for (DecodedCluster& d : decoded) {
        Cluster c = d.cluster;
        c.vertexOffset = uint32_t(mesh.positions.size() / 3);
        c.triangleOffset = uint32_t(mesh.triangles.size());
        mesh.positions.insert(mesh.positions.end(), d.positions.begin(), d.positions.end());
        mesh.normals.insert(mesh.normals.end(), d.normals.begin(), d.normals.end());
        mesh.colors.insert(mesh.colors.end(), d.colors.begin(), d.colors.end());
        mesh.triangles.insert(mesh.triangles.end(), d.triangles.begin(), d.triangles.end());
        append_cluster(mesh, c);
    }
    return mesh;
}

}  // namespace tessera
