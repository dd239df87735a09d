#include "tessera/cache.h"

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

namespace tessera {
namespace {

// A 128-bit content hash: two 64-bit lanes of multiply-xorshift mixing over 8-byte words, with different seeds.
// Not cryptographic; collisions between meshes are negligible at 128 bits.
class Hasher {
public:
    void bytes(const void* data, size_t size) {
        const auto* p = static_cast<const uint8_t*>(data);
        word(size);
        for (; size >= 8; size -= 8, p += 8) {
            uint64_t w;
            std::memcpy(&w, p, 8);
            word(w);
        }
        uint64_t tail = 0;
        if (size > 0) std::memcpy(&tail, p, size);  // an empty span may have no data pointer at all
        word(tail ^ (uint64_t(size) << 56));
    }
    template <typename T>
    void span(std::span<const T> values) { bytes(values.data(), values.size_bytes()); }
    void word(uint64_t w) {
        a_ = mix(a_ ^ w) * 0x9E3779B97F4A7C15ull;
        b_ = mix(b_ + w * 0xC2B2AE3D27D4EB4Full) ^ (b_ >> 29);
    }
    MeshCache::Digest digest() const { return {mix(a_ ^ b_), mix(b_ + 0x165667B19E3779F9ull)}; }

private:
    static uint64_t mix(uint64_t x) {
        x ^= x >> 33;
        x *= 0xff51afd7ed558ccdull;
        x ^= x >> 33;
        x *= 0xc4ceb9fe1a85ec53ull;
        x ^= x >> 33;
        return x;
    }
    uint64_t a_ = 0x243F6A8885A308D3ull, b_ = 0x13198A2E03707344ull;
};

void hash_primvar(Hasher& h, const PrimvarView& p) {
    h.word(uint64_t(p.interpolation));
    h.word(uint64_t(p.components));
    h.span(p.values);
    h.span(p.indices);
}

// Every setting, as exact bits (+0 for -0, which builds the same).
void hash_settings(Hasher& h, const BuildSettings& s) {
    auto real = [&](float value) {
        uint32_t bits;
        value += 0.0f;
        std::memcpy(&bits, &value, 4);
        h.word(bits);
    };
    h.word(uint64_t(int64_t(s.positionPrecision)));
    h.word(s.preserveArea);
    real(s.trimRelativeError);
    real(s.keepTrianglePercent);
    real(s.fallbackRelativeError);
    real(s.fallbackTrianglePercent);
    real(s.maxEdgeLengthFactor);
}

}  // namespace

MeshCache::MeshCache(std::string directory) : directory_(std::move(directory)) {}

MeshCache MeshCache::from_environment() {
    if (const char* dir = std::getenv("TESSERA_CACHE")) {
        const std::string value = dir;
        if (value == "off" || value == "0" || value.empty()) return MeshCache("");
        return MeshCache(value);
    }
    if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg) return MeshCache(std::string(xdg) + "/tessera");
    if (const char* home = std::getenv("HOME"); home && *home) return MeshCache(std::string(home) + "/.cache/tessera");
    return MeshCache("");
}

std::string MeshCache::Digest::hex() const {
    char out[33];
    std::snprintf(out, sizeof out, "%016llx%016llx", (unsigned long long)hi, (unsigned long long)lo);
    return out;
}

MeshCache::Digest MeshCache::digest(const MeshView& mesh, const BuildSettings& settings) {
    Hasher h;
    h.word(kPageFormatVersion);
    h.word(kBuilderRevision);
    hash_settings(h, settings);
    h.span(mesh.points);
    h.span(mesh.faceVertexCounts);
    h.span(mesh.faceVertexIndices);
    h.span(mesh.holeIndices);
    h.word(mesh.leftHanded);
    // Refinement and its tags only where the mesh is refined: an unrefined subdivision surface builds (and shares)
    // as the same polygons without a scheme.
    if (mesh.subdivisionScheme != SubdivisionScheme::None && mesh.refineLevel > 0) {
        const SubdivisionTags& tags = mesh.subdivisionTags;
        h.word(uint64_t(mesh.subdivisionScheme));
        h.word(uint64_t(mesh.refineLevel));
        h.word(uint64_t(tags.interpolateBoundary));
        h.word(uint64_t(tags.faceVaryingLinearInterpolation));
        h.word(uint64_t(tags.triangleSubdivisionRule));
        h.span(tags.creaseIndices);
        h.span(tags.creaseLengths);
        h.span(tags.creaseSharpnesses);
        h.span(tags.cornerIndices);
        h.span(tags.cornerSharpnesses);
    }
    hash_primvar(h, mesh.normals);
    hash_primvar(h, mesh.displayColor);
    hash_primvar(h, mesh.uvs);
    h.span(mesh.faceMaterials);
    if (mesh.bake) {  // a static displacement: its height map and values (DisplacementBake::key)
        h.bytes(mesh.bake->key.data(), mesh.bake->key.size());
        h.word(mesh.bake->maxTriangles);
    }
    return h.digest();
}

std::string MeshCache::path_of(const std::string& key) const { return directory_ + "/" + key.substr(0, 2) + "/" + key + ".tsra"; }

std::optional<MeshCache::Entry> MeshCache::load(const std::string& key, std::string* problem) const {
    if (!enabled()) return std::nullopt;
    const std::string path = path_of(key);
    namespace fs = std::filesystem;
    std::error_code error;
    const fs::file_status status = fs::status(path, error);
    if (!fs::exists(status)) return std::nullopt;  // not cached
    // One read of the whole file, its size asked first (a byte at a time through a stream iterator took 0.3 s for a
    // 71 MB page file). Not a file (a directory reports a size of 2^63 to a stream) is unreadable, as is a short read.
    const bool file = fs::is_regular_file(status);
    std::vector<uint8_t> bytes;
    bool read = false;
    if (file) {
        const uintmax_t size = fs::file_size(path, error);
        std::ifstream in(path, std::ios::binary);
        if (!error && in) {
            bytes.resize(size_t(size));
            read = bool(in.read(reinterpret_cast<char*>(bytes.data()), std::streamsize(bytes.size())));
        }
    }
    if (!read) {
        if (problem) *problem = "cannot read " + path + (file ? "" : ": not a file");
        return std::nullopt;
    }
    try {
        Entry entry;
        entry.mesh = std::make_shared<BuiltMesh>(decode_pages(bytes, path));
        std::ifstream warnings(path_of(key) + ".warnings");
        for (std::string line; std::getline(warnings, line);)
            if (!line.empty()) entry.warnings.push_back(line);
        return entry;
    } catch (const PageFileError& e) {
        if (problem) *problem = e.what();
        return std::nullopt;
    }
}

bool MeshCache::store(const std::string& key, const BuiltMesh& mesh, const std::vector<std::string>& warnings, std::string* problem) const {
    if (!enabled()) return false;
    namespace fs = std::filesystem;
    const std::string path = path_of(key);
    try {
        fs::create_directories(fs::path(path).parent_path());
        // A unique temporary name, renamed into place: readers never see a partial file, writers never collide.
        std::random_device random;
        const std::string temporary = path + ".tmp" + std::to_string(random()) + std::to_string(random());
        {
            std::ofstream out(temporary + ".warnings");
            for (const std::string& w : warnings) out << w << '\n';
        }
        fs::rename(temporary + ".warnings", path + ".warnings");
        const std::vector<uint8_t> bytes = encode_pages(mesh);
        {
            std::ofstream out(temporary, std::ios::binary);
            out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
            if (!out) throw std::runtime_error("cannot write " + temporary);
        }
        fs::rename(temporary, path);
        return true;
    } catch (const std::exception& e) {
        if (problem) *problem = std::string("mesh cache: ") + e.what();
        return false;
    }
}

namespace {
// A mesh this small (face-vertex indices, before any refinement) builds in well under 0.1 ms, less than reading its
// page file back, let alone writing one: it is built every time and never cached (100 k tiny prims filled the cache
// with 100 k files for nothing).
constexpr size_t kUncachedFaceVertices = 1024;

bool worth_caching(const MeshView& mesh) {
    const bool refined = mesh.subdivisionScheme != SubdivisionScheme::None && mesh.refineLevel > 0;
    return refined || mesh.bake || mesh.faceVertexIndices.size() > kUncachedFaceVertices;  // baking is costly: cached
}
}  // namespace

CachedBuild build_through_cache(const MeshView& mesh, const BuildSettings& settings, const MeshCache& cache,
                                const MeshCache::Digest* digest) {
    validate_settings(settings);  // before the lookup: a bad setting fails whether or not the mesh is cached
    CachedBuild result;
    std::string key;
    const bool cached = cache.enabled() && worth_caching(mesh);
    if (cached) {
        key = (digest ? *digest : MeshCache::digest(mesh, settings)).hex();
        std::string problem;
        if (auto entry = cache.load(key, &problem)) {
            result.mesh = entry->mesh;
            result.warnings = std::move(entry->warnings);
            result.fromCache = result.inCache = true;
            return result;
        }
        if (!problem.empty()) result.warnings.push_back(mesh.name + ": cached build unreadable, rebuilding (" + problem + ")");
    }
    PreparedMesh prepared = prepare_mesh(mesh);
    if (mesh.bake) prepared = bake_displacement(prepared, *mesh.bake);
    auto built = std::make_shared<BuiltMesh>(build_mesh(std::move(prepared), settings));  // empties its arrays; its warnings stay
    if (cached) {
        std::string problem;
        result.inCache = cache.store(key, *built, prepared.warnings, &problem);
        if (!result.inCache) result.warnings.push_back(mesh.name + ": " + problem);
    }
    result.warnings.insert(result.warnings.end(), prepared.warnings.begin(), prepared.warnings.end());
    result.mesh = std::move(built);
    return result;
}

}  // namespace tessera
