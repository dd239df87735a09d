// Meshes shared by content, built on a worker thread while the stage is read (delegate.h MeshTable).
#include "tessera/delegate.h"

#include <cstring>

namespace tessera::hd {

namespace {
// Source bytes of the builds handed over and not done, above which acquire() waits for the worker: the scene delegate
// reads faster than large meshes build, and each source held costs its arrays.
constexpr size_t kPendingBytesBudget = size_t(64) << 20;
// Builds that wait before an idle worker is woken (or those left when finish() is called).
constexpr size_t kWakeBatch = 64;

size_t source_bytes(const MeshView& v) {
    auto primvar = [](const PrimvarView& p) { return p.values.size_bytes() + p.indices.size_bytes(); };
    return v.points.size_bytes() + v.faceVertexCounts.size_bytes() + v.faceVertexIndices.size_bytes() + v.holeIndices.size_bytes() +
           primvar(v.normals) + primvar(v.displayColor) + primvar(v.uvs) + v.faceMaterials.size_bytes();
}

// Sources up to this size are copied before they are handed to the worker: 100 k small meshes waiting with their
// Python arrays made the cyclic garbage collector scan them again and again (10 % of a first sync).
constexpr size_t kCopiedSourceBytes = size_t(64) << 10;

// The view's arrays copied into storage of its own, which replaces `keepAlive` (released here, on the caller's thread).
void own_arrays(MeshSource& source) {
    MeshView& v = source.view;
    SubdivisionTags& tags = v.subdivisionTags;
    auto storage = std::make_shared<std::vector<uint32_t>>();  // every array holds 4-byte elements
    storage->reserve((source_bytes(v) + tags.creaseIndices.size_bytes() + tags.creaseLengths.size_bytes() +
                      tags.creaseSharpnesses.size_bytes() + tags.cornerIndices.size_bytes() + tags.cornerSharpnesses.size_bytes()) / 4);
    auto move_in = [&]<typename T>(std::span<const T>& span) {
        static_assert(sizeof(T) == 4);
        if (span.empty()) return;
        const size_t at = storage->size();
        storage->resize(at + span.size());  // within the reservation: earlier spans stay valid
        std::memcpy(storage->data() + at, span.data(), span.size_bytes());
        span = {reinterpret_cast<const T*>(storage->data() + at), span.size()};
    };
    move_in(v.points), move_in(v.faceVertexCounts), move_in(v.faceVertexIndices), move_in(v.holeIndices), move_in(v.faceMaterials);
    for (PrimvarView* p : {&v.normals, &v.displayColor, &v.uvs}) move_in(p->values), move_in(p->indices);
    move_in(tags.creaseIndices), move_in(tags.creaseLengths), move_in(tags.creaseSharpnesses), move_in(tags.cornerIndices),
        move_in(tags.cornerSharpnesses);
    source.keepAlive = std::move(storage);
}

// A message of the prim `from` said of the prim `to` (identical meshes have the same problems).
std::string renamed(const std::string& message, const std::string& from, const std::string& to) {
    return message.rfind(from + ": ", 0) == 0 ? to + message.substr(from.size()) : message;
}
}  // namespace

MeshTable::~MeshTable() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    wake_.notify_all();
    if (worker_.joinable()) worker_.join();  // its builds are dropped with builds_
}

MeshTable::Shared* MeshTable::shared_of(const std::string& key) {
    auto found = byKey_.find(key);
    return found == byKey_.end() ? nullptr : &found->second;
}

MeshTable::Handle MeshTable::acquire(MeshSource source, RenderParam& param) {
    const MeshView& view = source.view;
    validate_settings(source.settings);
    std::string key = MeshCache::key(view, source.settings);
    if (Shared* shared = shared_of(key)) {
        if (!shared->error.empty()) throw MeshError(renamed(shared->error, shared->name, view.name));
        ++shared->users;
        ++param.meshesShared;
        if (shared->pending) {  // its warnings are known once it is built
            builds_[shared->build].sharers.push_back(view.name);  // appends happen on this thread alone
        } else {
            for (const std::string& warning : shared->warnings) param.warnings.push_back(renamed(warning, shared->name, view.name));
        }
        return {shared->gpuMesh, std::move(key)};
    }
    const uint32_t gpuMesh = scene_.add_mesh(nullptr);  // the handle now; the mesh at finish()
    byKey_[key] = {gpuMesh, 1, view.name, {}, "", false, 0};
    if (view.bake) {  // the bake (a height map read by a function) lives with the caller: built here
        Shared& shared = byKey_[key];
        try {
            CachedBuild built = build_through_cache(view, source.settings, cache_);
            ++(built.fromCache ? param.meshesFromCache : param.meshesBuilt);
            shared.warnings = built.warnings;
            for (auto& w : built.warnings) param.warnings.push_back(std::move(w));
            scene_.set_mesh(gpuMesh, std::move(built.mesh));
        } catch (...) {
            scene_.remove_mesh(gpuMesh);
            byKey_.erase(key);
            throw;
        }
        return {gpuMesh, std::move(key)};
    }
    Shared& shared = byKey_[key];
    shared.pending = true;
    shared.build = builds_.size();
    const size_t bytes = source_bytes(view);
    if (bytes <= kCopiedSourceBytes) own_arrays(source);
    {
        std::unique_lock lock(mutex_);
        if (pendingBytes_ > 0 && pendingBytes_ + bytes > kPendingBytesBudget) {
            wake_.notify_one();  // the worker (started with the first build) may be waiting for a whole batch
            ++waiting_;
            done_.wait(lock, [&] { return pendingBytes_ == 0 || pendingBytes_ + bytes <= kPendingBytesBudget; });
            --waiting_;
        }
        builds_.push_back({key, std::move(source), {}, {}, nullptr});
        ++submitted_;
        pendingBytes_ += bytes;
        if (!worker_.joinable()) worker_ = std::thread([this] { run_worker(); });
        // A busy worker takes the next build without being woken; an idle one is woken for a batch, as a wake-up costs
        // about what a small build does.
        if (!workerIdle_ || submitted_ - built_ < kWakeBatch) return {gpuMesh, std::move(key)};
    }
    wake_.notify_one();
    return {gpuMesh, std::move(key)};
}

void MeshTable::run_worker() {
    std::unique_lock lock(mutex_);
    for (;;) {
        workerIdle_ = true;
        wake_.wait(lock, [&] { return stopping_ || built_ < submitted_; });
        workerIdle_ = false;
        if (built_ == submitted_) return;  // stopping, nothing left
        // A deque's elements stay where they are as others are appended: the reference outlives the lock.
        Build& build = builds_[built_];
        lock.unlock();
        try {
            build.result = build_through_cache(build.source.view, build.source.settings, cache_);
        } catch (...) {
            build.error = std::current_exception();
        }
        const size_t bytes = source_bytes(build.source.view);
        lock.lock();
        ++built_;
        pendingBytes_ -= bytes;
        if (waiting_ > 0) done_.notify_all();  // a wake-up per build would cost more than a small build
    }
}

void MeshTable::finish(RenderParam& param) {
    // The worker builds what is left and ends: no thread outlives a sync (a process forked between syncs has none).
    if (worker_.joinable()) {
        {
            std::lock_guard lock(mutex_);
            stopping_ = true;
        }
        wake_.notify_one();
        worker_.join();
        stopping_ = false;
    }
    for (Build& build : builds_) {
        Shared& shared = byKey_.at(build.key);
        shared.pending = false;
        std::vector<std::string> names{shared.name};
        names.insert(names.end(), build.sharers.begin(), build.sharers.end());
        if (build.error) {
            try {
                std::rethrow_exception(build.error);
            } catch (const std::exception& e) {
                shared.error = e.what();
            } catch (...) {
                shared.error = shared.name + ": the build failed";
            }
            for (const std::string& name : names) param.errors.push_back(renamed(shared.error, shared.name, name) + "; the mesh is skipped");
        } else {
            ++(build.result.fromCache ? param.meshesFromCache : param.meshesBuilt);
            shared.warnings = std::move(build.result.warnings);
            for (const std::string& name : names)
                for (const std::string& warning : shared.warnings) param.warnings.push_back(renamed(warning, shared.name, name));
        }
        if (shared.users == 0) {  // every prim that wanted it went away meanwhile
            scene_.remove_mesh(shared.gpuMesh);
            byKey_.erase(build.key);
        } else if (!build.error) {
            scene_.set_mesh(shared.gpuMesh, std::move(build.result.mesh));
        }
    }
    std::lock_guard lock(mutex_);
    builds_.clear();  // the sources' arrays are released here, on the caller's thread
    submitted_ = built_ = 0;
}

void MeshTable::release(const Handle& handle) {
    Shared* shared = shared_of(handle.key);
    if (!shared || --shared->users > 0 || shared->pending) return;  // a pending one is dropped by finish()
    scene_.remove_mesh(shared->gpuMesh);
    byKey_.erase(handle.key);
}

}  // namespace tessera::hd
