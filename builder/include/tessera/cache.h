// The content-addressed mesh cache: a built mesh is stored as a page file under a key computed from everything
// that determines it (the mesh as authored, the build settings, the page format version, the builder revision),
// so an unchanged mesh is never built twice, across renders, processes and stages.
#pragma once

#include "tessera/builder.h"

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace tessera {

class MeshCache {
public:
    // `directory` "" disables the cache.
    explicit MeshCache(std::string directory = "");
    // $TESSERA_CACHE ("off" or "0" disables it), else $XDG_CACHE_HOME/tessera, else ~/.cache/tessera.
    static MeshCache from_environment();

    bool enabled() const { return !directory_.empty(); }
    const std::string& directory() const { return directory_; }

    // A 128-bit hash of the mesh, the settings, the format version and the builder revision.
    struct Digest {
        uint64_t hi = 0, lo = 0;
        bool operator==(const Digest&) const = default;
        std::string hex() const;  // 32 hex digits
    };
    struct DigestHash {
        size_t operator()(const Digest& d) const { return size_t(d.lo); }  // already mixed
    };
    static Digest digest(const MeshView& mesh, const BuildSettings& settings);
    // The digest in hex: the page file's name.
    static std::string key(const MeshView& mesh, const BuildSettings& settings) { return digest(mesh, settings).hex(); }

    struct Entry {
        std::shared_ptr<const BuiltMesh> mesh;
        std::vector<std::string> warnings;  // the prepare warnings stored with the mesh
    };
    // A stored mesh, or nothing (no entry, or one that fails to decode: then `problem` says why).
    std::optional<Entry> load(const std::string& key, std::string* problem = nullptr) const;
    // Stores atomically (a temporary file renamed into place); a failure to write is reported, not thrown.
    bool store(const std::string& key, const BuiltMesh& mesh, const std::vector<std::string>& warnings, std::string* problem = nullptr) const;

private:
    std::string path_of(const std::string& key) const;
    std::string directory_;
};

struct CachedBuild {
    std::shared_ptr<const BuiltMesh> mesh;
    std::vector<std::string> warnings;
    bool fromCache = false;
    bool inCache = false;  // the cache holds it (loaded from it, or stored there): it can be loaded again by its key
};

// prepare_mesh + build_mesh through the cache (throws MeshError as prepare_mesh does; nothing is cached then).
// `digest`: MeshCache::digest of the mesh and settings where the caller has it already.
CachedBuild build_through_cache(const MeshView& mesh, const BuildSettings& settings, const MeshCache& cache,
                                const MeshCache::Digest* digest = nullptr);

}  // namespace tessera
