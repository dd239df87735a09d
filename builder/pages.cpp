// The page file: a BuiltMesh on disk.
//
//   header      (kHeaderBytes)  magic "TSRA", version, counts, origin, precision, size, colour mode, UV grid, leaf error,
//                               fallback cut (threshold and error: the fallback mesh is extracted from the DAG on demand), checksum
//   page table  (pages x 24)    per page: offset (u64), bytes, first cluster, cluster count, CRC32; then its CRC32
//   pages                       per stream (cluster_codec.h): size before and after compression; then the streams,
//                               each zstd-compressed, or as is where that would not make it smaller
//
// All little-endian. A page holds whole units (the children of one parent group, or one root cluster) and at most
// kPageBytes of streams before compression, so it is also at most kPageBytes after, and decompresses into bounded
// memory. Positions are grid points, stored as predictions and residuals of their integer grid coordinates: the
// round trip is exact.
#include "tessera/builder.h"

#include "byte_streams.h"
#include "cluster_codec.h"
#include "tessera/parallel.h"
#include "phase_timer.h"

#include <zstd.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <memory>

static_assert(std::endian::native == std::endian::little, "the page format is little-endian; add byte swaps for big-endian hosts");

namespace tessera {
namespace {

constexpr char kMagic[4] = {'T', 'S', 'R', 'A'};
constexpr size_t kHeaderBytes = kPageHeaderBytes;
constexpr size_t kPageEntryBytes = 24;
constexpr size_t kStreamTableBytes = kPageStreamCount * 8;
constexpr size_t kMinClusterRecordBytes = 41;  // a cluster's record alone, before compression
constexpr int kCompressionLevel = 1;             // zstd: the smallest pages here, and the fastest (19: 3 % smaller, 7x slower)

size_t streams_bytes(const PageStreams& streams) {
    size_t total = 0;
    for (const auto& s : streams) total += s.size();
    return total;
}

std::vector<uint8_t> compress_page(const PageStreams& streams) {
    // One context per thread: making one per page (its tables) cost as much as compressing a small page.
    thread_local const std::unique_ptr<ZSTD_CCtx, size_t (*)(ZSTD_CCtx*)> context(ZSTD_createCCtx(), ZSTD_freeCCtx);
    std::vector<uint8_t> page(kStreamTableBytes);  // the stream table, then the streams
    for (size_t s = 0; s < streams.size(); ++s) {
        const std::vector<uint8_t>& raw = streams[s];
        const size_t at = page.size();
        page.resize(at + ZSTD_compressBound(raw.size()));
        size_t size = ZSTD_compressCCtx(context.get(), &page[at], page.size() - at, raw.data(), raw.size(), kCompressionLevel);
        if (ZSTD_isError(size) || size >= raw.size()) {  // stored as is
            size = raw.size();
            if (size) std::memcpy(&page[at], raw.data(), size);
        }
        page.resize(at + size);
        const uint32_t sizes[2] = {uint32_t(raw.size()), uint32_t(size)};
        std::memcpy(&page[8 * s], sizes, 8);
    }
    return page;
}

PageStreams decompress_page(std::span<const uint8_t> page, const std::string& where) {
    const std::unique_ptr<ZSTD_DCtx, size_t (*)(ZSTD_DCtx*)> context(ZSTD_createDCtx(), ZSTD_freeDCtx);
    ByteReader reader(page, where);
    uint32_t raw[kPageStreamCount], stored[kPageStreamCount];
    size_t total = 0;
    for (uint32_t s = 0; s < kPageStreamCount; ++s) {
        raw[s] = reader.get<uint32_t>();
        stored[s] = reader.get<uint32_t>();
        total += raw[s];
        if (stored[s] > raw[s] || total > kPageBytes) throw PageFileError(where + ": inconsistent stream sizes");
    }
    PageStreams streams;
    for (uint32_t s = 0; s < kPageStreamCount; ++s) {
        const std::span<const uint8_t> bytes = reader.take(stored[s]);
        if (stored[s] == raw[s]) {
            streams[s].assign(bytes.begin(), bytes.end());
            continue;
        }
        streams[s].resize(raw[s]);
        const size_t size = ZSTD_decompressDCtx(context.get(), streams[s].data(), raw[s], bytes.data(), bytes.size());
        if (ZSTD_isError(size) || size != raw[s]) throw PageFileError(where + ": a stream does not decompress");
    }
    if (!reader.done()) throw PageFileError(where + ": has trailing bytes");
    return streams;
}

}  // namespace

uint32_t crc32(std::span<const uint8_t> bytes) {
    // Slicing by 8 (eight bytes a step through eight tables): every cached mesh is checked at every load.
    static const auto tables = [] {
        std::array<std::array<uint32_t, 256>, 8> t{};
        for (uint32_t i = 0; i < 256; ++i) {
            uint32_t c = i;
            for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
            t[0][i] = c;
        }
        for (uint32_t i = 0; i < 256; ++i)
            for (int k = 1; k < 8; ++k) t[k][i] = (t[k - 1][i] >> 8) ^ t[0][t[k - 1][i] & 0xff];
        return t;
    }();
    uint32_t crc = 0xffffffffu;
    size_t i = 0;
    for (; i + 8 <= bytes.size(); i += 8) {
        uint32_t low, high;
        std::memcpy(&low, &bytes[i], 4);
        std::memcpy(&high, &bytes[i + 4], 4);
        low ^= crc;
        crc = tables[7][low & 0xff] ^ tables[6][(low >> 8) & 0xff] ^ tables[5][(low >> 16) & 0xff] ^ tables[4][low >> 24] ^
              tables[3][high & 0xff] ^ tables[2][(high >> 8) & 0xff] ^ tables[1][(high >> 16) & 0xff] ^ tables[0][high >> 24];
    }
    for (; i < bytes.size(); ++i) crc = tables[0][(crc ^ bytes[i]) & 0xff] ^ (crc >> 8);
    return crc ^ 0xffffffffu;
}

std::vector<uint8_t> encode_pages(const BuiltMesh& mesh, PageLayout* layout) {
    PhaseTimer phases;
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
        PageStreams streams;
        std::vector<uint8_t> bytes;
        uint32_t firstCluster, clusters;
        std::vector<uint32_t> members;
    };
    std::vector<PageStreams> unitStreams(units.size());  // units encode on every core, then fill pages in order
    parallel_for_rethrowing(units.size(), [&](size_t u) { encode_unit(mesh, units[u], unitStreams[u]); });
    phases.mark("pages: encode units");
    std::vector<Page> pages;
    uint32_t rootPages = 0, written = 0;
    for (size_t u = 0; u < units.size(); ++u) {
        PageStreams unit = std::move(unitStreams[u]);
        const size_t unitBytes = streams_bytes(unit);
        if (unitBytes + kStreamTableBytes > kPageBytes) throw std::runtime_error("a cluster group does not fit in a page");
        const bool rootUnit = u < rootUnits;
        const bool startPage = pages.empty() || streams_bytes(pages.back().streams) + unitBytes + kStreamTableBytes > kPageBytes ||
                               (!rootUnit && u == rootUnits);
        if (startPage) {
            pages.push_back({{}, {}, written, 0, {}});
            rootPages += rootUnit;
        }
        Page& page = pages.back();
        for (uint32_t s = 0; s < kPageStreamCount; ++s) page.streams[s].insert(page.streams[s].end(), unit[s].begin(), unit[s].end());
        page.clusters += uint32_t(units[u].size());
        page.members.insert(page.members.end(), units[u].begin(), units[u].end());
        written += uint32_t(units[u].size());
    }
    parallel_for_rethrowing(pages.size(), [&](size_t p) {
        pages[p].bytes = compress_page(pages[p].streams);
        pages[p].streams = {};
    });
    phases.mark("pages: compress");

    ByteWriter header;
    for (char ch : kMagic) header.put(ch);
    header.put(kPageFormatVersion);
    header.put(kPageBytes);
    header.put(uint32_t(pages.size()));
    header.put(rootPages);
    header.put(uint32_t(mesh.clusters.size()));
    header.put(mesh.groups);
    header.put(uint32_t(!mesh.colors.empty()));
    for (double o : mesh.origin) header.put(o);
    header.put(int32_t(mesh.positionPrecision));
    header.put(mesh.size);
    header.put(uint64_t(mesh.sourceTriangles));
    for (float c : mesh.constantColor) header.put(c);
    header.put(uint32_t(mesh.hasConstantColor));
    for (float f : mesh.sphere) header.put(f);
    header.put(uint32_t(!mesh.uvs.empty()));
    header.put(int32_t(mesh.uvPrecision));
    header.put(mesh.leafError);
    // A mesh without a fallback (one not made by build_mesh) stores NaN: the decoded mesh then has none.
    header.put(mesh.fallbackThreshold);
    header.put(mesh.fallbackError);
    header.put(mesh.materialSlots);
    if (header.bytes.size() > kHeaderBytes - 4) throw std::logic_error("the page file header outgrew kPageHeaderBytes");
    header.bytes.resize(kHeaderBytes - 4, 0);
    header.put(crc32(header.bytes));

    ByteWriter table;
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
    phases.mark("pages: file");
    return file;
}

BuiltMesh decode_pages(std::span<const uint8_t> bytes, const std::string& name) {
    if (bytes.size() < kHeaderBytes) throw PageFileError(name + ": truncated (" + std::to_string(bytes.size()) + " bytes, shorter than the header)");
    if (std::memcmp(bytes.data(), kMagic, 4) != 0) throw PageFileError(name + ": not a Tessera DAG file");
    ByteReader header(bytes.first(kHeaderBytes), name + ": header");
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
    const bool uvs = header.get<uint32_t>() != 0;
    mesh.uvPrecision = header.get<int32_t>();
    mesh.leafError = header.get<float>();
    mesh.fallbackThreshold = header.get<float>();
    mesh.fallbackError = header.get<float>();
    mesh.materialSlots = header.get<uint32_t>();
    if (pageBytes != kPageBytes || rootPages > pageCount) throw PageFileError(name + ": inconsistent header");
    if (mesh.uvPrecision < -1074 || mesh.uvPrecision > 1023) throw PageFileError(name + ": invalid texture coordinate precision");
    if (mesh.materialSlots < 1 || mesh.materialSlots > 256) throw PageFileError(name + ": invalid material slot count");
    const VertexFormat format{mesh.positionStep, colors, uvs, std::ldexp(1.0, mesh.uvPrecision), mesh.materialSlots};

    const size_t tableBytes = size_t(pageCount) * kPageEntryBytes + 4;
    if (bytes.size() < kHeaderBytes + tableBytes) throw PageFileError(name + ": truncated page table");
    const auto table = bytes.subspan(kHeaderBytes, tableBytes);
    uint32_t storedTableCrc;
    std::memcpy(&storedTableCrc, &table[tableBytes - 4], 4);
    if (crc32(table.first(tableBytes - 4)) != storedTableCrc) throw PageFileError(name + ": page table checksum mismatch (corrupt file)");
    if (clusterCount > uint64_t(pageCount) * (kPageBytes / kMinClusterRecordBytes)) throw PageFileError(name + ": inconsistent header");
    struct PageEntry {
        std::span<const uint8_t> bytes;
        uint32_t clusters, crc;
    };
    std::vector<PageEntry> entries(pageCount);
    ByteReader tableReader(table, name + ": page table");
    uint32_t expectedFirst = 0;
    for (uint32_t p = 0; p < pageCount; ++p) {
        const uint64_t offset = tableReader.get<uint64_t>();
        const uint32_t size = tableReader.get<uint32_t>(), first = tableReader.get<uint32_t>(), count = tableReader.get<uint32_t>();
        const std::string where = name + ": page " + std::to_string(p);
        if (size > kPageBytes || offset > bytes.size() || bytes.size() - offset < size) throw PageFileError(where + " is truncated or out of bounds");
        if (first != expectedFirst || count > clusterCount - first) throw PageFileError(where + " has an inconsistent cluster range");
        expectedFirst += count;
        entries[p] = {bytes.subspan(offset, size), count, tableReader.get<uint32_t>()};
    }
    if (expectedFirst != clusterCount) throw PageFileError(name + ": holds " + std::to_string(expectedFirst) + " clusters, the header says " + std::to_string(clusterCount));

    // Pages decode on their own, on every core; the first page in error is the one reported.
    PhaseTimer phases;
    std::vector<std::vector<DecodedCluster>> pageClusters(pageCount);
    parallel_for_rethrowing(pageCount, [&](size_t p) {
        const std::string where = name + ": page " + std::to_string(p);
        if (crc32(entries[p].bytes) != entries[p].crc) throw PageFileError(where + ": checksum mismatch (corrupt file)");
        const PageStreams streams = decompress_page(entries[p].bytes, where);
        UnitDecoder units(streams, format, where);
        while (pageClusters[p].size() < entries[p].clusters) units.decode_unit(pageClusters[p]);
        if (pageClusters[p].size() != entries[p].clusters || !units.done()) throw PageFileError(where + ": holds other clusters than its table entry says");
    });
    phases.mark("decode: pages");
    std::vector<DecodedCluster> decoded(clusterCount);
    std::vector<uint8_t> seen(clusterCount, 0);
    for (uint32_t p = 0; p < pageCount; ++p)
        for (DecodedCluster& d : pageClusters[p]) {
            if (d.index >= clusterCount || seen[d.index]) throw PageFileError(name + ": page " + std::to_string(p) + ": a cluster index is out of range or repeated");
            seen[d.index] = 1;
            decoded[d.index] = std::move(d);
        }

    // Back into build order (level 0 first), with the streams laid out as the builder lays them out: the offsets in
    // order, then each stream gathered on a core of its own (reserved: grown one cluster at a time, a 10 M-triangle
    // mesh's streams were copied over about twice).
    mesh.clusters.reserve(clusterCount);
    size_t vertices = 0, triangles = 0;
    for (const DecodedCluster& d : decoded) {
        Cluster c = d.cluster;
        c.vertexOffset = uint32_t(vertices);
        c.triangleOffset = uint32_t(triangles);
        vertices += d.normals.size();
        triangles += d.triangles.size();
        if (vertices > UINT32_MAX || triangles > UINT32_MAX) throw PageFileError(name + ": more vertices or triangles than 32-bit offsets reach");
        append_cluster(mesh, c);
    }
    auto gather = [&](auto& stream, auto member, size_t size) {
        stream.reserve(size);
        for (const DecodedCluster& d : decoded) stream.insert(stream.end(), (d.*member).begin(), (d.*member).end());
    };
    parallel_for_rethrowing(5, [&](size_t stream) {  // rethrowing: running out of memory is an error, not an abort
        if (stream == 0) gather(mesh.positions, &DecodedCluster::positions, 3 * vertices);
        if (stream == 1) gather(mesh.normals, &DecodedCluster::normals, vertices);
        if (stream == 2) gather(mesh.triangles, &DecodedCluster::triangles, triangles);
        if (stream == 3 && colors) gather(mesh.colors, &DecodedCluster::colors, 2 * vertices);
        if (stream == 4 && uvs) gather(mesh.uvs, &DecodedCluster::uvs, 2 * vertices);
    });
    phases.mark("decode: streams");
    return mesh;
}

}  // namespace tessera
