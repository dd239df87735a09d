// The render delegate (prim factory) and the render index (prims, dirty bits, sync, commit, execute).
#include "tessera/delegate.h"

#include <algorithm>
#include <cmath>
#if defined(__GLIBC__)
#include <malloc.h>
#endif
#include <deque>
#include <optional>
#include <sstream>
#include <tuple>

namespace tessera::hd {

RenderDelegate::RenderDelegate(const DeviceOptions& options) : device_(Device::shared(options)), renderer_(*device_) {}

const std::vector<std::string>& RenderDelegate::supported_rprim_types() {
    static const std::vector<std::string> types{"mesh"};
    return types;
}
const std::vector<std::string>& RenderDelegate::supported_sprim_types() {
    static const std::vector<std::string> types{"material", "camera", "distantLight", "domeLight", "rectLight", "sphereLight"};
    return types;
}
const std::vector<std::string>& RenderDelegate::supported_bprim_types() {
    static const std::vector<std::string> types{"renderBuffer"};
    return types;
}

std::unique_ptr<Mesh> RenderDelegate::create_rprim(const std::string& type, const PrimId& id, const PrimId& instancerId, uint32_t primId) {
    if (type != "mesh") return nullptr;
    return std::make_unique<Mesh>(id, instancerId, primId, scene_, meshes_);
}

std::unique_ptr<Prim> RenderDelegate::create_sprim(const std::string& type, const PrimId& id) {
    if (type == "material") return std::make_unique<Material>(id, scene_.textures());
    if (type == "camera") return std::make_unique<Camera>(id);
    if (Light::is_light_type(type)) return std::make_unique<Light>(id, scene_.textures());
    return nullptr;
}

std::unique_ptr<RenderBuffer> RenderDelegate::create_bprim(const std::string& type, const PrimId& id) {
    if (type != "renderBuffer") return nullptr;
    return std::make_unique<RenderBuffer>(id);
}

void RenderIndex::insert_rprim(const std::string& type, const PrimId& id, const PrimId& instancerId, uint32_t defaults,
                               const Matrix4d* transform) {
    auto prim = delegate_.create_rprim(type, id, instancerId, uint32_t(primPaths_.size()));
    if (!prim) throw std::invalid_argument("unsupported rprim type '" + type + "' for " + id);
    prim->assume_defaults(defaults, transform);
    primPaths_.push_back(id);
    Entry& entry = rprims_[id];
    entry = {type, std::move(prim), AllDirty, false};
    dirtyRprims_.insert(&entry);
    structureDirty_ = true;
}

void RenderIndex::insert_sprim(const std::string& type, const PrimId& id) {
    auto prim = delegate_.create_sprim(type, id);
    if (!prim) throw std::invalid_argument("unsupported sprim type '" + type + "' for " + id);
    Entry& entry = sprims_[id];
    entry = {type, std::move(prim), AllDirty, false};
    dirtySprims_.insert(&entry);
    structureDirty_ = true;
}

void RenderIndex::insert_bprim(const std::string& type, const PrimId& id) {
    auto prim = delegate_.create_bprim(type, id);
    if (!prim) throw std::invalid_argument("unsupported bprim type '" + type + "' for " + id);
    bprims_[id] = {type, std::move(prim), AllDirty, false};
}

void RenderIndex::remove_prim(const PrimId& id) {
    for (auto [prims, dirty] : {std::pair{&rprims_, &dirtyRprims_}, std::pair{&sprims_, &dirtySprims_}}) {
        auto it = prims->find(id);
        if (it == prims->end()) continue;
        dirty->erase(&it->second);
        awaitingView_.erase(&it->second);
        prims->erase(it);
        structureDirty_ = true;
    }
    bprims_.erase(id);
}

void RenderIndex::mark_dirty(const PrimId& id, uint32_t bits) {
    for (auto [prims, dirty] : {std::pair{&rprims_, &dirtyRprims_}, std::pair{&sprims_, &dirtySprims_}}) {
        auto it = prims->find(id);
        if (it == prims->end()) continue;
        if (prims == &rprims_) static_cast<Mesh&>(*it->second.prim).forget_defaults(bits);  // changed: ask again
        it->second.dirty |= bits;
        it->second.failed = false;  // a changed prim gets another chance (sync_all decides what to commit)
        dirty->insert(&it->second);
    }
}

const Mesh* RenderIndex::rprim(const PrimId& id) const {
    auto it = rprims_.find(id);
    return it == rprims_.end() ? nullptr : static_cast<const Mesh*>(it->second.prim.get());
}

void RenderIndex::mark_all_dirty(uint32_t bits) {
    for (auto [prims, dirty] : {std::pair{&rprims_, &dirtyRprims_}, std::pair{&sprims_, &dirtySprims_}})
        for (auto& [id, entry] : *prims) {
            if (prims == &rprims_) static_cast<Mesh&>(*entry.prim).forget_defaults(bits);
            entry.dirty |= bits;
            dirty->insert(&entry);
        }
    structureDirty_ = true;
}

namespace {
// Scene delegate errors (USD's among them) can span lines; a diagnostic is one line that names the prim.
std::string one_line(const std::string& text) {
    std::istringstream in(text);
    std::string word, out;
    while (in >> word) out += (out.empty() ? "" : " ") + word;
    return out;
}

// A material whose inputs read a constant vertex channel `c`: those inputs take their values from `c`, as constants.
MaterialDesc fold_vertex_channel(MaterialDesc desc, const std::array<float, 4>& c) {
    auto component = [&](MaterialInput input, std::array<float, 3>* rgb, float* scalar) {
        const uint32_t code = (desc.vertexInputs >> (4u * uint32_t(input))) & 15u;
        if ((code & 8u) == 0) return;
        const uint32_t first = code & 3u;
        const bool three = (code & 4u) != 0;
        if (rgb) *rgb = three ? std::array<float, 3>{c[first], c[std::min(first + 1, 3u)], c[std::min(first + 2, 3u)]}
                              : std::array<float, 3>{c[first], c[first], c[first]};
        if (scalar) *scalar = c[first];
    };
    component(MaterialInput::DiffuseColor, &desc.diffuseColor, nullptr);
    component(MaterialInput::EmissiveColor, &desc.emissiveColor, nullptr);
    component(MaterialInput::SpecularColor, &desc.specularColor, nullptr);
    component(MaterialInput::Metallic, nullptr, &desc.metallic);
    component(MaterialInput::Roughness, nullptr, &desc.roughness);
    component(MaterialInput::Opacity, nullptr, &desc.opacity);
    component(MaterialInput::Occlusion, nullptr, &desc.occlusion);
    desc.vertexInputs = 0;
    return desc;
}

bool same_instances(const std::vector<InstanceDesc>& a, const std::vector<InstanceDesc>& b) {
    return std::equal(a.begin(), a.end(), b.begin(), b.end(), [](const InstanceDesc& x, const InstanceDesc& y) {
        return x.mesh == y.mesh && x.transform == y.transform && x.arrays == y.arrays && x.primId == y.primId && x.material == y.material &&
               x.materialTable == y.materialTable && x.doubleSided == y.doubleSided;
    });
}

// Hands the memory the allocator holds free back to the system (glibc's malloc_trim; elsewhere nothing).
void release_free_memory() {
#if defined(__GLIBC__)
    malloc_trim(0);
#endif
}

}  // namespace

void RenderIndex::sync_all(SceneDelegate& scene, const PrimId& cameraId, uint32_t width, uint32_t height) {
    lastSynced_.clear();
    const uint32_t meshesLoadedBefore = param_.meshesBuilt + param_.meshesFromCache;
    param_.material = [this](const PrimId& id) -> const MaterialDesc* {
        auto it = sprims_.find(id);
        return it != sprims_.end() && it->second.type == "material" ? &static_cast<const Material&>(*it->second.prim).desc() : nullptr;
    };
    std::vector<const Entry*> moved;  // plain meshes whose transform alone changed: patched into the instance list
    // Meshes whose builds their syncs started (MeshTable), finished in sync order: each as soon as it is ready, so that
    // the workers build while the next prims are read.
    std::deque<Entry*> building;
    auto finish_first = [&] {
        Entry& entry = *building.front();
        building.pop_front();
        try {
            static_cast<Mesh&>(*entry.prim).finish_build(param_);
        } catch (const std::exception& e) {
            param_.errors.push_back(entry.prim->id() + ": " + one_line(e.what()) + "; the prim is skipped");
            entry.failed = true;
        }
    };
    // Only the prims marked dirty are visited (sprims first: rprims refer to materials), in id order.
    for (auto* dirty : {&dirtySprims_, &dirtyRprims_}) {
        if (dirty == &dirtyRprims_) prepare_view(cameraId, width, height);
        std::vector<Entry*> entries;
        auto& all = dirty == &dirtyRprims_ ? rprims_ : sprims_;
        if (dirty->size() > all.size() / 8) {  // a first sync, say: the map is in id order already (sorting 100 k ids cost more)
            entries.reserve(dirty->size());
            for (auto& [id, entry] : all)
                if (dirty->count(&entry)) entries.push_back(&entry);
        } else {
            entries.assign(dirty->begin(), dirty->end());
            std::sort(entries.begin(), entries.end(), [](const Entry* a, const Entry* b) { return a->prim->id() < b->prim->id(); });
        }
        dirty->clear();
        for (Entry* entryPointer : entries) {
            Entry& entry = *entryPointer;
            const PrimId& id = entry.prim->id();
            if (entry.dirty == Clean) continue;
            const Mesh* mesh = dirty == &dirtyRprims_ ? static_cast<const Mesh*>(entry.prim.get()) : nullptr;
            // Hydra's rule: a hidden mesh syncs nothing until its visibility changes; its other bits stay dirty
            // (a hidden mesh is never built).
            if (mesh && !mesh->visible() && !(entry.dirty & DirtyVisibility)) {
                dirty->insert(&entry);
                continue;
            }
            const bool material = entry.type == "material";
            const std::string bakeBefore = material ? static_cast<const Material&>(*entry.prim).bake_key() : "";
            try {
                entry.prim->sync(scene, param_, entry.dirty);
                if (material && static_cast<const Material&>(*entry.prim).bake_key() != bakeBefore) rebuild_bound_meshes(id);
            } catch (const std::exception& e) {
                // One bad prim never stops the stage: report it and leave it out of the frame.
                param_.errors.push_back(id + ": " + one_line(e.what()) + "; the prim is skipped");
                entry.failed = true;
            }
            lastSynced_.emplace_back(id, entry.dirty);
            if (mesh && mesh->building()) {
                building.push_back(&entry);
                structureDirty_ = true;  // drawn with its new mesh, or no longer drawn if it cannot be built
            } else if (mesh) {
                const bool drawn = !entry.failed && mesh->visible() && mesh->gpu_mesh();
                if (entry.dirty == DirtyTransform && mesh->instancer_id().empty() && drawn && entry.instanceCount == 1)
                    moved.push_back(&entry);
                else if (drawn || entry.instanceCount > 0)
                    structureDirty_ = true;  // drawn differently, or no longer drawn
            } else if (entry.type == "material") {
                structureDirty_ = true;  // cameras and lights are read at execute()
            }
            entry.dirty = mesh && !mesh->visible() && !entry.failed ? entry.dirty & ~uint32_t(DirtyVisibility) : Clean;
            if (entry.dirty != Clean) dirty->insert(&entry);
            if (mesh && mesh->awaiting_view()) awaitingView_.insert(&entry);
            else if (mesh) awaitingView_.erase(&entry);
            ++syncCounts_[entry.type];
            while (!building.empty() && (static_cast<const Mesh&>(*building.front()->prim).build_ready() || delegate_.meshes().saturated()))
                finish_first();
        }
        while (!building.empty()) finish_first();
    }
    // Loading and building meshes frees far more than it keeps (pages decoded, clusters built, on the worker threads,
    // whose allocator arenas keep what they free): given back to the system before the frame allocates its uploads, it
    // is neither part of the peak nor held after (a 10 M-triangle mesh from the cache: 376 of 1330 MiB).
    if (param_.meshesBuilt + param_.meshesFromCache > meshesLoadedBefore) release_free_memory();
    if (structureDirty_) {
        commit_resources();
    } else if (!moved.empty()) {
        // A transform edit: the instance list is patched in place, not rebuilt.
        for (const Entry* entry : moved)
            delegate_.scene().set_instance_transform(entry->firstInstance, static_cast<const Mesh&>(*entry->prim).transform());
    }
    structureDirty_ = false;
}

// The view this sync builds for (RenderParam::view): the camera sprim's at the resolution, or none (build everything).
// Meshes waiting for a view come back to the dirty list, their held-back bits with them, when this one sees them (or
// when there is no view, or an edit dirtied them again).
void RenderIndex::prepare_view(const PrimId& cameraId, uint32_t width, uint32_t height) {
    param_.view.reset();
    auto camera = sprims_.find(cameraId);
    if (!cameraId.empty() && camera != sprims_.end() && camera->second.type == "camera" && width > 0 && height > 0)
        param_.view = view_frustum(static_cast<const Camera&>(*camera->second.prim).desc(), width, height);
    for (auto it = awaitingView_.begin(); it != awaitingView_.end();) {
        Entry& entry = **it;
        const Mesh& mesh = static_cast<const Mesh&>(*entry.prim);
        if (param_.view && !mesh.seen_by(*param_.view) && !dirtyRprims_.count(&entry)) {
            ++it;
            continue;
        }
        entry.dirty |= mesh.awaiting_view();
        dirtyRprims_.insert(&entry);
        it = awaitingView_.erase(it);
    }
}

// A material's static displacement changed: the meshes bound to it (directly or by a GeomSubset) look at their material
// again (Mesh::sync builds them again when the bake they were built with differs).
void RenderIndex::rebuild_bound_meshes(const PrimId& materialId) {
    for (auto& [id, entry] : rprims_) {
        const Mesh& mesh = static_cast<const Mesh&>(*entry.prim);
        const auto& subsets = mesh.subset_material_ids();
        if (mesh.material_id() != materialId && std::find(subsets.begin(), subsets.end(), materialId) == subsets.end()) continue;
        static_cast<Mesh&>(*entry.prim).forget_defaults(DirtyMaterialId);
        entry.dirty |= DirtyMaterialId;
        dirtyRprims_.insert(&entry);
    }
}

// Rebuilds the instance, material and light lists of the GPU scene from the synced prims.
void RenderIndex::commit_resources() {
    GpuScene& scene = delegate_.scene();
    scene.clear_materials();
    std::unordered_map<PrimId, uint32_t> materialHandles;
    std::unordered_map<PrimId, const MaterialDesc*> materialDescs;
    for (auto& [id, entry] : sprims_)
        if (entry.type == "material") {
            materialDescs[id] = &static_cast<Material&>(*entry.prim).desc();
            materialHandles[id] = scene.add_material(*materialDescs[id]);
        }
    // A material whose inputs come from the mesh's vertex channel (primvar readers), on a mesh whose channel is one
    // constant (constant primvars, or the readers' fallbacks): those values folded in, one material per pair.
    std::map<std::tuple<PrimId, float, float, float, float>, uint32_t> foldedHandles;
    // Meshes without a material share one fallback per colour: their displayColor (constant, or per vertex), else
    // Hydra's grey, diffuse only like Hydra's fallback surface.
    std::map<std::tuple<float, float, float, bool>, uint32_t> fallbackHandles;

    std::vector<InstanceDesc> instances;
    for (auto& [id, entry] : rprims_) {
        const Mesh& mesh = static_cast<Mesh&>(*entry.prim);
        entry.firstInstance = instances.size();
        entry.instanceCount = 0;
        if (entry.failed || !mesh.visible() || !mesh.gpu_mesh()) continue;
        InstanceDesc instance;
        instance.mesh = *mesh.gpu_mesh();
        instance.primId = mesh.prim_id();
        instance.doubleSided = mesh.double_sided();
        const BuiltMesh* built = mesh.built();
        auto handle_of = [&](const PrimId& materialId) {
            auto material = materialHandles.find(materialId);
            if (material != materialHandles.end()) {
                const MaterialDesc& desc = *materialDescs.at(materialId);
                if (desc.vertexInputs == 0 || !built->hasConstantColor) return material->second;
                const auto& c = built->constantColor;
                auto [it, added] = foldedHandles.try_emplace(std::make_tuple(materialId, c[0], c[1], c[2], c[3]), 0);
                if (added) it->second = scene.add_material(fold_vertex_channel(desc, c));
                return it->second;
            }
            // No bound material: the mesh's displayColor (constant, or per vertex), else Hydra's grey; one per colour.
            const auto color = built->hasConstantColor ? built->constantColor : std::array<float, 4>{0.5f, 0.5f, 0.5f, 1.0f};
            const auto key = std::make_tuple(color[0], color[1], color[2], mesh.vertex_colors());
            auto [it, added] = fallbackHandles.try_emplace(key, 0);
            if (added) {
                MaterialDesc fallback;
                fallback.diffuseColor = {color[0], color[1], color[2]};
                fallback.vertexInputs = std::get<3>(key) ? kDisplayColorInputs : 0u;
                fallback.ior = 1.0f;  // diffuse only, like Hydra's fallback surface
                it->second = scene.add_material(fallback);
            }
            return it->second;
        };
        instance.material = handle_of(mesh.material_id());
        if (built->materialSlots > 1) {  // GeomSubsets: one table per prim, shared by its instances
            std::vector<uint32_t> table{instance.material};
            const std::vector<PrimId>& subsets = mesh.subset_material_ids();
            for (uint32_t slot = 1; slot < built->materialSlots; ++slot)
                table.push_back(slot <= subsets.size() && !subsets[slot - 1].empty() ? handle_of(subsets[slot - 1]) : instance.material);
            instance.material = scene.add_material_table(table);
            instance.materialTable = true;
        }
        if (mesh.instancer_id().empty()) {
            instance.transform = mesh.transform();
            instances.push_back(instance);
        } else {
            // One batch per frame: the arrays (a PointInstancer's, borrowed) are shared, never expanded here.
            const InstanceSet& set = mesh.instances();
            instance.arrays = set.arrays;
            for (size_t i = 0; i < set.frames.size(); ++i) {
                std::copy_n(set.frames.values.data() + 16 * i, 16, instance.transform.begin());
                instances.push_back(instance);
            }
        }
        entry.instanceCount = instances.size() - entry.firstInstance;
    }
    // Unchanged instances (a material or light edit) keep the renderer's uploads and its previous-frame HZB.
    if (!same_instances(instances, scene.instances())) scene.set_instances(std::move(instances));
}

std::vector<std::shared_ptr<const Image>> RenderIndex::execute(const RenderPassSettings& settings, FrameStats* stats) {
    CameraDesc camera = settings.camera;
    if (!settings.cameraId.empty()) {
        auto it = sprims_.find(settings.cameraId);
        if (it == sprims_.end() || it->second.type != "camera") throw std::invalid_argument("no camera prim " + settings.cameraId);
        camera = static_cast<Camera&>(*it->second.prim).desc();
    }
    std::vector<LightDesc> lights;
    std::vector<const PrimId*> lightIds;
    for (auto& [id, entry] : sprims_)
        if (Light::is_light_type(entry.type)) {
            lights.push_back(static_cast<Light&>(*entry.prim).desc());
            lightIds.push_back(&id);
        }
    if (lights.size() > kMaxLights) {
        // Domes and distant lights first (they light everything), then the others in path order; say who is left out.
        std::vector<size_t> order(lights.size());
        for (size_t i = 0; i < order.size(); ++i) order[i] = i;
        std::stable_partition(order.begin(), order.end(), [&](size_t i) { return lights[i].type == LightType::Dome || lights[i].type == LightType::Distant; });
        std::string dropped;
        std::vector<LightDesc> kept;
        for (size_t k = 0; k < order.size(); ++k) {
            if (k < kMaxLights) kept.push_back(lights[order[k]]);
            else dropped += (dropped.empty() ? "" : ", ") + *lightIds[order[k]];
        }
        param_.warnings.push_back(std::to_string(lights.size()) + " lights, and a frame is lit by at most " + std::to_string(kMaxLights) +
                                  " (domes and distant lights first): left out " + dropped);
        lights = std::move(kept);
    }
    if (lights.empty()) {
        // The default rig when a stage has no lights: a key light over the camera's shoulder and a dim dome.
        const Matrix4d& c = camera.cameraToWorld;
        std::array<double, 3> direction;
        for (int k = 0; k < 3; ++k) direction[k] = -c[k * 4 + 2] - 0.35 * c[k * 4 + 1] + 0.2 * c[k * 4 + 0];
        lights.push_back({LightType::Distant, direction, {2.67f, 2.67f, 2.67f}});  // irradiance: 0.85 pi
        lights.push_back({LightType::Dome, {0, 0, -1}, {0.15f, 0.15f, 0.15f}});
    }
    RenderSettings render = settings.render;
    for (auto& [id, entry] : sprims_)
        if (entry.type == "domeLight") {  // the camera sees the dome where no geometry is (as usdview shows it)
            const auto& r = static_cast<Light&>(*entry.prim).desc().radiance;
            render.background = {r[0], r[1], r[2], 1.0f};
            break;
        }
    delegate_.scene().set_lights(std::move(lights));
    std::vector<std::shared_ptr<const Image>> images;
    FrameStats ownStats;
    if (!stats) stats = &ownStats;
    for (Image& image : delegate_.renderer().render(delegate_.scene(), camera, render, settings.aovs, stats)) {
        images.push_back(std::make_shared<const Image>(std::move(image)));
        const PrimId bufferId = std::string("aov:") + aov_name(images.back()->aov);
        if (!bprims_.count(bufferId)) insert_bprim("renderBuffer", bufferId);
        static_cast<RenderBuffer&>(*bprims_[bufferId].prim).image = images.back();
    }
    for (const std::string& error : stats->errors) param_.errors.push_back(error + "; the mesh is not drawn");
    // And once more after a frame that uploaded meshes: the streams the GPU scene let go (GpuScene::release_streams).
    if (param_.meshesBuilt + param_.meshesFromCache > 0) release_free_memory();
    return images;
}

PrimId RenderIndex::prim_path(uint32_t primId) const { return primId < primPaths_.size() ? primPaths_[primId] : PrimId(); }

}  // namespace tessera::hd
