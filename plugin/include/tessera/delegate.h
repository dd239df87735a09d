// Tessera's Hydra-style delegate API (see docs/overview.md for sync, commit and execute).
//
// A scene delegate (the USD stage reader, in Python) answers questions about prims by id. The render index
// holds the prims the render delegate created and a dirty mask per prim; sync_all() asks each dirty prim to
// pull only what its dirty bits name, then commit_resources() pushes the changes into the GPU scene, and
// execute() renders. The shapes follow Hydra's HdSceneDelegate / HdRenderIndex / HdRprim / HdSprim /
// HdBprim / HdRenderDelegate so that a real Hydra adapter can stay thin.
#pragma once

#include "tessera/builder.h"
#include "tessera/cache.h"
#include "tessera/renderer.h"

#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

namespace tessera::hd {

using PrimId = std::string;  // an SdfPath string

// What changed on a prim (Hydra's HdChangeTracker bits, reduced to what Tessera reads).
enum DirtyBits : uint32_t {
    Clean = 0,
    DirtyPoints = 1u << 0,
    DirtyTopology = 1u << 1,
    DirtyTransform = 1u << 2,
    DirtyVisibility = 1u << 3,
    DirtyPrimvar = 1u << 4,
    DirtyMaterialId = 1u << 5,
    DirtyInstancer = 1u << 6,
    DirtyDoubleSided = 1u << 7,
    DirtyParams = 1u << 8,  // sprim parameters (material, light, camera)
    AllDirty = 0xffffffffu,
};

// A mesh as authored. The views borrow arrays owned by `keepAlive` (numpy arrays over USD's buffers).
struct MeshSource {
    MeshView view;
    bool doubleSided = false;
    BuildSettings settings;  // the mesh's own, else the render-wide defaults
    std::shared_ptr<const void> keepAlive;
};

// Row-major 4x4 matrices (column vectors), 16 doubles each, owned by `keepAlive`.
struct MatrixArray {
    std::span<const double> values;
    std::shared_ptr<const void> keepAlive;
    size_t size() const { return values.size() / 16; }
};

// The copies of a prototype mesh an instancer draws: for each of `frames`, one copy there (`arrays` null), or every
// instance of a PointInstancer's `arrays` in that frame (the instancer's world transform; one frame per copy of the
// instancer itself when it is nested). Each frame becomes one batch of the GPU scene's instances.
struct InstanceSet {
    MatrixArray frames;
    std::shared_ptr<const InstanceArrays> arrays;
    uint64_t count() const { return frames.size() * (arrays ? arrays->count() : 1); }
};

class SceneDelegate {
public:
    virtual ~SceneDelegate() = default;
    virtual MeshSource get_mesh(const PrimId& id) = 0;
    virtual Matrix4d get_transform(const PrimId& id) = 0;  // mesh space -> world
    virtual bool get_visible(const PrimId& id) = 0;
    virtual PrimId get_material_id(const PrimId& id) = 0;  // "" when none is bound
    // For a mesh whose faces carry material slots (MeshView::faceMaterials): the material of slots 1, 2, ... (Hydra's
    // GeomSubsets); "" for a slot that takes the mesh's own. Slot 0 is get_material_id's.
    virtual std::vector<PrimId> get_subset_material_ids(const PrimId&) { return {}; }
    // Every copy of `prototypeId` drawn by `instancerId` (nesting already composed).
    virtual InstanceSet get_instances(const PrimId& instancerId, const PrimId& prototypeId) = 0;
    virtual MaterialDesc get_material(const PrimId& id) = 0;
    virtual LightDesc get_light(const PrimId& id) = 0;
    virtual CameraDesc get_camera(const PrimId& id) = 0;
    // A mesh's bounds in mesh space (UsdGeomBoundable's extent: lo xyz, hi xyz), or none when unknown: a mesh with
    // bounds is built only once a rendered view sees them.
    virtual std::optional<std::array<double, 6>> get_extent(const PrimId&) { return std::nullopt; }
};

class RenderDelegate;

// Where prims report what they could not use; messages name the prim.
struct RenderParam {
    // The synced material sprim of an id, or null (meshes read their material's static displacement when they build).
    std::function<const MaterialDesc*(const PrimId&)> material;
    std::vector<std::string> warnings;
    std::vector<std::string> errors;
    uint32_t meshesBuilt = 0, meshesFromCache = 0;
    uint32_t meshesShared = 0;  // meshes identical to one already in the GPU scene: that one is used
    // The view the rprims sync for (sync_all's camera): a mesh whose bounds it does not see waits to be built.
    std::optional<ViewFrustum> view;
};

// Built meshes shared by content: rprims whose meshes are identical (the mesh cache's key: points, topology,
// primvars, build settings) use one GPU scene mesh, built or loaded once, however many prims author it.
//
// Builds run on worker threads while the syncing thread goes on reading the stage (the scene delegate is Python: one
// thread): start() hands a mesh over, finish() waits for it on the syncing thread, in sync order (so the GPU scene,
// the counts and the messages come out as they would one by one), and adds it to the GPU scene.
class MeshTable {
public:
    MeshTable(GpuScene& scene, const MeshCache& cache) : scene_(scene), cache_(cache) {}
    ~MeshTable();
    MeshTable(const MeshTable&) = delete;
    MeshTable& operator=(const MeshTable&) = delete;

    struct Handle {
        uint32_t gpuMesh;
        MeshCache::Digest key;
        bool vertexColors = false;  // the mesh has a colour per vertex (the GPU scene may keep its description alone)
    };
    struct Build;  // one mesh on its way (mesh_table.cpp)
    struct Ticket {
        std::shared_ptr<Build> build;  // shared by the prims whose identical meshes were started before it finished
        std::string name;              // the prim's mesh name, which its messages use
        std::optional<Handle> held;    // an identical mesh was held already: shared at start (no build)
    };
    // Starts getting the GPU scene mesh of `source` (with `bake`, its material's static displacement, if any): one
    // held already is shared at once, one on its way is waited for, else it is loaded from the cache or built by a
    // worker thread. Bad settings throw MeshError at once.
    Ticket start(MeshSource source, std::optional<DisplacementBake> bake, RenderParam& param);
    static bool ready(const Ticket& ticket);
    // Waits for the mesh and adds it to the GPU scene; throws MeshError (naming the ticket's prim) as its build did.
    // On the syncing thread: the mesh's source arrays (Python's) are let go here.
    Handle finish(const Ticket& ticket, RenderParam& param);
    // Whether so much is on its way that the syncing thread should finish what it started before reading on (the
    // sources of started meshes stay in memory until they finish).
    bool saturated() const;
    void release(const Handle& handle);

private:
    void work();     // a worker thread's loop
    void publish();  // hands the started meshes over to the workers
    struct Shared;
    Handle share(Shared& shared, const MeshCache::Digest& key, const std::string& name, RenderParam& param);

    // Kept small (100 k distinct meshes are 100 k of these): the name only where there are warnings to rename.
    struct Shared {
        uint32_t gpuMesh = 0, users = 0;
        bool vertexColors = false;
        std::string name;  // of the prim it was built for, which its warnings name ("" without warnings)
        std::vector<std::string> warnings;
    };
    GpuScene& scene_;
    const MeshCache& cache_;
    std::unordered_map<MeshCache::Digest, Shared, MeshCache::DigestHash> byKey_;
    std::unordered_map<MeshCache::Digest, std::shared_ptr<Build>, MeshCache::DigestHash> started_;  // not finished yet
    size_t startedIndices_ = 0;  // face-vertex indices of the sources of started_ (saturated())
    std::vector<std::shared_ptr<Build>> unpublished_;  // started, not handed to the workers yet (publish())
    size_t unpublishedIndices_ = 0;
    // The workers, started at the first build (a render that builds nothing starts no thread).
    std::vector<std::thread> workers_;
    std::mutex mutex_;
    std::condition_variable queued_, done_;
    std::deque<std::shared_ptr<Build>> queue_;
    bool stopping_ = false;
};

// Base of every prim kind.
class Prim {
public:
    explicit Prim(PrimId id) : id_(std::move(id)) {}
    virtual ~Prim() = default;
    const PrimId& id() const { return id_; }
    virtual void sync(SceneDelegate& scene, RenderParam& param, uint32_t dirtyBits) = 0;

private:
    PrimId id_;
};

// The geometry prim (Hydra's Rprim "mesh"): holds its built mesh in the GPU scene.
class Mesh : public Prim {
public:
    Mesh(PrimId id, PrimId instancerId, uint32_t primId, GpuScene& scene, MeshTable& meshes)
        : Prim(std::move(id)), instancerId_(std::move(instancerId)), primId_(primId), scene_(scene), meshes_(meshes) {}
    ~Mesh() override;
    // A sync that rebuilds the mesh starts its build (MeshTable::start): the render index finishes it, in sync order.
    void sync(SceneDelegate& scene, RenderParam& param, uint32_t dirtyBits) override;
    bool building() const { return building_ != nullptr; }
    bool build_ready() const { return building_ && MeshTable::ready(*building_); }
    // Waits for the mesh its sync started; a mesh that cannot be built is reported and skipped.
    void finish_build(RenderParam& param);

    const PrimId& instancer_id() const { return instancerId_; }
    const PrimId& material_id() const { return materialId_; }
    const std::vector<PrimId>& subset_material_ids() const { return subsetMaterialIds_; }
    uint32_t prim_id() const { return primId_; }
    bool visible() const { return visible_; }
    bool double_sided() const { return doubleSided_; }
    std::optional<uint32_t> gpu_mesh() const { return mesh_ ? std::optional(mesh_->gpuMesh) : std::nullopt; }
    const Matrix4d& transform() const { return transform_; }
    const InstanceSet& instances() const { return instances_; }
    // The mesh's description (its streams may have gone to the GPU alone: GpuScene::release_streams).
    const BuiltMesh* built() const { return mesh_ ? scene_.mesh(mesh_->gpuMesh).get() : nullptr; }
    bool vertex_colors() const { return mesh_ && mesh_->vertexColors; }
    // Bits whose state the scene delegate gave when it inserted the mesh (DirtyVisibility: visible; DirtyMaterialId: no
    // material and no GeomSubset materials; DirtyTransform: `transform`, what the stage walk computed): the first sync
    // does not ask for them (100 k plain meshes made 400 k calls into Python for nothing). Marking such a bit dirty
    // forgets it.
    void assume_defaults(uint32_t bits, const Matrix4d* transform = nullptr) {
        defaults_ = bits & (DirtyVisibility | DirtyMaterialId | (transform ? DirtyTransform : 0u));
        if (defaults_ & DirtyTransform) transform_ = *transform;
    }
    void forget_defaults(uint32_t bits) { defaults_ &= ~bits; }
    uint32_t defaults() const { return defaults_; }  // those its next sync will not ask for
    // The build bits it holds back while no rendered view has seen its bounds (0: none; it is built or unbuildable).
    uint32_t awaiting_view() const { return awaitingBits_; }
    bool seen_by(const ViewFrustum& view) const { return view.touches_box(transform_, {box_[0], box_[1], box_[2]}, {box_[3], box_[4], box_[5]}); }

private:
    // Whether a material of it moves its surface (its bounds then say too little to skip it).
    bool displaced_by_materials(const RenderParam& param) const;

    uint32_t awaitingBits_ = 0;
    uint32_t defaults_ = 0;  // assume_defaults
    std::array<double, 6> box_{};  // its extent (mesh space) when it began to wait
    PrimId instancerId_, materialId_;
    std::string bakeKey_;  // the static displacement its mesh was built with (Material::bake_key), "" for none
    std::vector<PrimId> subsetMaterialIds_;
    uint32_t primId_;
    GpuScene& scene_;
    MeshTable& meshes_;
    std::optional<MeshTable::Handle> mesh_;
    std::unique_ptr<MeshTable::Ticket> building_;  // started by sync, not finished yet (a pointer: 100 k meshes hold one)
    Matrix4d transform_ = identity_matrix();
    InstanceSet instances_;
    bool visible_ = true, doubleSided_ = false;
};

// Sprims: state prims with parameters.
class Material : public Prim {
public:
    Material(PrimId id, TextureStore& textures) : Prim(std::move(id)), textures_(textures) {}
    // Pulls the material and loads its textures (a file that cannot be read is a warning naming it and the material).
    void sync(SceneDelegate& scene, RenderParam& param, uint32_t dirtyBits) override;
    const MaterialDesc& desc() const { return desc_; }
    // What its static displacement does to the meshes bound to it ("" without tessera:displacement:bake): when this
    // changes, those meshes are built again.
    const std::string& bake_key() const { return bakeKey_; }

private:
    TextureStore& textures_;
    MaterialDesc desc_;
    std::string bakeKey_;
};

// distantLight, domeLight, rectLight, sphereLight.
class Light : public Prim {
public:
    Light(PrimId id, TextureStore& textures) : Prim(std::move(id)), textures_(textures) {}
    // Pulls the light; a dome's texture is loaded (and its irradiance integrated) here. A texture that cannot be read
    // is a warning naming the file and the light, which then lights by its colour.
    void sync(SceneDelegate& scene, RenderParam& param, uint32_t dirtyBits) override;
    const LightDesc& desc() const { return desc_; }
    static bool is_light_type(const std::string& type);

private:
    TextureStore& textures_;
    LightDesc desc_;
};

class Camera : public Prim {
public:
    using Prim::Prim;
    void sync(SceneDelegate& scene, RenderParam& param, uint32_t dirtyBits) override;
    const CameraDesc& desc() const { return desc_; }

private:
    CameraDesc desc_;
};

// Bprim: an AOV's image, written by execute() (shared with what execute() returns: not a copy per frame).
class RenderBuffer : public Prim {
public:
    using Prim::Prim;
    void sync(SceneDelegate&, RenderParam&, uint32_t) override {}
    std::shared_ptr<const Image> image;
};

// Creates prims of the types it supports and owns the renderer and GPU scene they feed. The device (with the renderer's
// compiled pipelines) is the process's for these options (Device::shared): delegates after the first start at once.
class RenderDelegate {
public:
    explicit RenderDelegate(const DeviceOptions& options = DeviceOptions::from_environment());
    RenderDelegate(const RenderDelegate&) = delete;
    RenderDelegate& operator=(const RenderDelegate&) = delete;
    static const std::vector<std::string>& supported_rprim_types();  // {"mesh"}
    static const std::vector<std::string>& supported_sprim_types();  // material, camera, distantLight, domeLight, rectLight, sphereLight
    static const std::vector<std::string>& supported_bprim_types();  // {"renderBuffer"}

    std::unique_ptr<Mesh> create_rprim(const std::string& type, const PrimId& id, const PrimId& instancerId, uint32_t primId);
    std::unique_ptr<Prim> create_sprim(const std::string& type, const PrimId& id);
    std::unique_ptr<RenderBuffer> create_bprim(const std::string& type, const PrimId& id);

    Device& device() { return *device_; }
    Renderer& renderer() { return renderer_; }
    GpuScene& scene() { return scene_; }
    MeshTable& meshes() { return meshes_; }
    const MeshCache& cache() const { return cache_; }
    void set_cache(MeshCache cache) { cache_ = std::move(cache); }
    // One thread at a time uses a delegate and its index. Python's bindings take turns here, and run sync and execute
    // without the GIL (other Python threads, a viewer's UI among them, go on meanwhile).
    std::mutex& turn() { return turn_; }

private:
    std::mutex turn_;
    MeshCache cache_ = MeshCache::from_environment();
    std::shared_ptr<Device> device_;
    Renderer renderer_;
    GpuScene scene_;
    MeshTable meshes_{scene_, cache_};
};

// Settings of one render pass (Hydra's render pass state plus the render settings map).
struct RenderPassSettings {
    PrimId cameraId;                      // a camera sprim, or "" to use `camera`
    CameraDesc camera;
    RenderSettings render;
    std::vector<Aov> aovs{Aov::Color};
};

class RenderIndex {
public:
    explicit RenderIndex(RenderDelegate& delegate) : delegate_(delegate) {}
    RenderIndex(const RenderIndex&) = delete;
    RenderIndex& operator=(const RenderIndex&) = delete;

    // `defaults` (and `transform`): Mesh::assume_defaults, what the scene delegate already knows of the mesh.
    void insert_rprim(const std::string& type, const PrimId& id, const PrimId& instancerId = "", uint32_t defaults = 0,
                      const Matrix4d* transform = nullptr);
    void insert_sprim(const std::string& type, const PrimId& id);
    void insert_bprim(const std::string& type, const PrimId& id);
    void remove_prim(const PrimId& id);
    void mark_dirty(const PrimId& id, uint32_t bits);
    void mark_all_dirty(uint32_t bits);

    // Syncs every dirty prim (sprims first: rprims refer to materials), then commits to the GPU scene. Given a camera
    // sprim and the resolution it renders at, meshes whose bounds that view does not see are not built (yet): they
    // are, at the first sync_all whose view sees them.
    void sync_all(SceneDelegate& scene, const PrimId& cameraId = "", uint32_t width = 0, uint32_t height = 0);
    // Meshes waiting for a view to see them (not built).
    size_t meshes_out_of_view() const { return awaitingView_.size(); }
    // Renders the synced scene; the images also land in the render buffers named "aov:<name>".
    std::vector<std::shared_ptr<const Image>> execute(const RenderPassSettings& settings, FrameStats* stats = nullptr);

    // Path of the prim whose primId AOV value is `primId` ("" if none).
    PrimId prim_path(uint32_t primId) const;
    // Syncs performed per prim type since construction (tests use this to see that only dirty prims sync).
    const std::map<std::string, uint64_t>& sync_counts() const { return syncCounts_; }
    // The prims the last sync_all() synced, each with the dirty bits it was handed, in sync order.
    const std::vector<std::pair<PrimId, uint32_t>>& last_synced() const { return lastSynced_; }
    RenderParam take_diagnostics() { return std::exchange(param_, {}); }
    size_t rprim_count() const { return rprims_.size(); }
    const Mesh* rprim(const PrimId& id) const;  // null if there is none
    RenderDelegate& delegate() const { return delegate_; }

private:
    void commit_resources();
    void rebuild_bound_meshes(const PrimId& materialId);
    void prepare_view(const PrimId& cameraId, uint32_t width, uint32_t height);

    struct Entry {
        std::string type;
        std::unique_ptr<Prim> prim;
        uint32_t dirty = AllDirty;
        bool failed = false;  // its last sync threw; left out of the frame until it is dirtied again
        size_t firstInstance = 0, instanceCount = 0;  // a mesh's range of the committed instance list
    };
    RenderDelegate& delegate_;
    std::map<PrimId, Entry> rprims_, sprims_, bprims_;
    std::unordered_set<Entry*> dirtyRprims_, dirtySprims_;  // what sync_all visits: an edit costs what it dirtied
    std::unordered_set<Entry*> awaitingView_;  // meshes no view has seen yet (Mesh::awaiting_view), tested each sync
    std::vector<PrimId> primPaths_;  // primId -> path
    std::map<std::string, uint64_t> syncCounts_;
    std::vector<std::pair<PrimId, uint32_t>> lastSynced_;
    RenderParam param_;
    bool structureDirty_ = true;  // the instance and material lists must be rebuilt, not just patched
};

}  // namespace tessera::hd
