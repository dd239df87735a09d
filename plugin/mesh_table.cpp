// Built meshes shared by content, built on worker threads while the stage is read (delegate.h MeshTable).
#include "tessera/delegate.h"
#include "tessera/parallel.h"

#include <algorithm>
#include <atomic>
#include <utility>

namespace tessera::hd {

namespace {
// saturated(): at most this many meshes, or this many face-vertex indices of their sources, started and not finished.
// The sources are views of the stage's arrays, which stay alive until their meshes finish.
constexpr size_t kMaxStartedMeshes = 1024;
constexpr size_t kMaxStartedIndices = size_t(32) << 20;
// Started meshes go to the workers in batches of this many (or fewer with this many face-vertex indices): waking a
// worker per small mesh costs more than building it.
constexpr size_t kPublishMeshes = 64;
constexpr size_t kPublishIndices = size_t(1) << 16;

// A message about the prim `from` said of the prim `to` (an identical mesh has the same problems).
std::string renamed(const std::string& message, const std::string& from, const std::string& to) {
    return from != to && message.rfind(from + ": ", 0) == 0 ? to + message.substr(from.size()) : message;
}
}  // namespace

struct MeshTable::Build {
    MeshCache::Digest key;
    std::string name;  // of the prim it was started for, which the build's messages name
    MeshSource source;  // let go by finish(), on the syncing thread: its arrays are Python objects
    std::optional<DisplacementBake> bake;
    size_t indices = 0;  // the source's face-vertex indices
    std::atomic<bool> done = false;  // set by the worker, after `result` or `error`
    CachedBuild result;
    std::exception_ptr error;
    bool counted = false;  // its build or load counted in RenderParam (by the first finish)
};

MeshTable::~MeshTable() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    queued_.notify_all();
    for (std::thread& worker : workers_) worker.join();
}

MeshTable::Ticket MeshTable::start(MeshSource source, std::optional<DisplacementBake> bake, RenderParam& param) {
    validate_settings(source.settings);
    if (bake) source.view.bake = &*bake;
    const MeshCache::Digest key = MeshCache::digest(source.view, source.settings);
    Ticket ticket{nullptr, source.view.name, std::nullopt};
    if (auto found = byKey_.find(key); found != byKey_.end()) {  // held already: shared at once
        ticket.held = share(found->second, key, ticket.name, param);
        return ticket;
    }
    if (auto started = started_.find(key); started != started_.end()) {  // on its way for another prim
        ticket.build = started->second;
        return ticket;
    }
    auto build = std::make_shared<Build>();
    build->key = key;
    build->name = source.view.name;
    ticket.build = build;
    build->indices = source.view.faceVertexIndices.size();
    build->bake = std::move(bake);
    build->source = std::move(source);
    if (build->bake) build->source.view.bake = &*build->bake;  // the build's own copy
    started_.emplace(key, build);
    startedIndices_ += build->indices;
    unpublished_.push_back(build);
    unpublishedIndices_ += build->indices;
    if (unpublished_.size() >= kPublishMeshes || unpublishedIndices_ >= kPublishIndices) publish();
    return ticket;
}

void MeshTable::publish() {
    if (unpublished_.empty()) return;
    {
        std::lock_guard lock(mutex_);
        if (workers_.empty()) {
            // One per core: the syncing thread mostly reads the stage, or waits for these.
            for (size_t i = 0, cores = core_count(); i < cores; ++i)
                workers_.emplace_back(&MeshTable::work, this);
        }
        for (auto& build : unpublished_) queue_.push_back(std::move(build));
    }
    unpublished_.clear();
    unpublishedIndices_ = 0;
    queued_.notify_all();
}

void MeshTable::work() {
    std::unique_lock lock(mutex_);
    for (;;) {
        queued_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
        if (stopping_) return;
        std::shared_ptr<Build> build = std::move(queue_.front());
        queue_.pop_front();
        lock.unlock();
        CachedBuild result;
        std::exception_ptr error;
        try {
            result = build_through_cache(build->source.view, build->source.settings, cache_, &build->key);
        } catch (...) {
            error = std::current_exception();
        }
        build->result = std::move(result);
        build->error = error;
        lock.lock();
        build->done = true;
        // started_ holds the build until finish(): the last reference, which lets the source's Python arrays go (that
        // needs the interpreter's lock, held by the syncing thread), is never this thread's.
        build.reset();
        done_.notify_all();
    }
}

bool MeshTable::ready(const Ticket& ticket) {
    return !ticket.build || ticket.build->done;
}

bool MeshTable::saturated() const {
    return started_.size() >= kMaxStartedMeshes || startedIndices_ >= kMaxStartedIndices;
}

MeshTable::Handle MeshTable::share(Shared& shared, const MeshCache::Digest& key, const std::string& name, RenderParam& param) {
    ++shared.users;
    ++param.meshesShared;
    for (const std::string& warning : shared.warnings)  // this prim has the same problems: say so by its name
        param.warnings.push_back(renamed(warning, shared.name, name));
    return {shared.gpuMesh, key, shared.vertexColors};
}

MeshTable::Handle MeshTable::finish(const Ticket& ticket, RenderParam& param) {
    if (ticket.held) return *ticket.held;
    Build& build = *ticket.build;
    if (!build.done) {
        publish();  // it may be among them
        std::unique_lock lock(mutex_);
        done_.wait(lock, [&] { return build.done.load(); });
    }
    if (auto started = started_.find(build.key); started != started_.end() && started->second == ticket.build) {
        started_.erase(started);
        startedIndices_ -= build.indices;
        build.source = {};  // the arrays are let go here, on this thread
    }
    if (build.error) {
        try {
            std::rethrow_exception(build.error);
        } catch (const MeshError& e) {
            throw MeshError(renamed(e.what(), build.name, ticket.name));
        }
    }
    auto found = byKey_.find(build.key);
    if (found != byKey_.end()) return share(found->second, build.key, ticket.name, param);  // finished for an identical prim
    if (!build.counted) {
        ++(build.result.fromCache ? param.meshesFromCache : param.meshesBuilt);
        build.counted = true;
    } else {
        ++param.meshesShared;  // released by the prim it was built for, before this one finished
    }
    // A mesh the cache holds can be loaded again: the GPU scene may then let its streams go once they are on the GPU.
    GpuScene::MeshReload reload;
    if (build.result.inCache)
        reload = [cache = cache_, key = build.key.hex(), name = build.name] {
            std::string problem;
            std::optional<MeshCache::Entry> entry = cache.load(key, &problem);
            if (!entry)
                throw MeshError(name + ": the GPU needs its streams again and its page file " + key + " in the mesh cache " + cache.directory() +
                                " cannot be read (" + (problem.empty() ? "it is gone" : problem) + "); open the stage again to rebuild it");
            return entry->mesh;
        };
    const bool vertexColors = !build.result.mesh->colors.empty();
    Shared& shared = byKey_[build.key];
    shared = {scene_.add_mesh(build.result.mesh, std::move(reload)), 1, vertexColors, build.result.warnings.empty() ? std::string() : build.name,
              build.result.warnings};
    for (const std::string& warning : build.result.warnings) param.warnings.push_back(renamed(warning, build.name, ticket.name));
    return {shared.gpuMesh, build.key, vertexColors};
}

void MeshTable::release(const Handle& handle) {
    auto found = byKey_.find(handle.key);
    if (found == byKey_.end() || --found->second.users > 0) return;
    scene_.remove_mesh(found->second.gpuMesh);
    byKey_.erase(found);
}

}  // namespace tessera::hd
