// Sync of each prim kind: pull only what the dirty bits name.
#include "tessera/delegate.h"

#include <algorithm>
#include <utility>

namespace tessera::hd {

// What a material's static displacement does to a mesh (builder.h DisplacementBake), with a key naming everything that
// changes the result: the height map (file, size, time) and how it is read, and the material's values.
std::optional<DisplacementBake> displacement_bake(const MaterialDesc& m) {
    DisplacementBake bake;
    bake.magnitude = m.displacementMagnitude;
    bake.center = m.displacementCenter;
    bake.constant = m.displacement;
    std::string key = "bake " + std::to_string(bake.magnitude) + " " + std::to_string(bake.center) + " " + std::to_string(bake.constant);
    for (const TextureSlot& slot : m.textures) {
        if (slot.input != MaterialInput::Displacement) continue;
        if (!slot.image) {  // unreadable: its fallback is the height everywhere (already warned about)
            bake.constant = slot.fallback[slot.channel == TextureChannel::Rgb ? 0 : size_t(slot.channel)];
            key += " fallback " + std::to_string(bake.constant);
            break;
        }
        bake.height = [slot](float s, float t) { return sample_slot_level0(slot, s, t); };
        bake.texels = std::max(slot.image->width, slot.image->height);
        key += " " + slot.file + " " + std::to_string(slot.image->fileTime) + " " + std::to_string(slot.image->fileSize) + " " +
               std::to_string(int(slot.colorSpace)) + " " + std::to_string(int(slot.wrapS)) + " " + std::to_string(int(slot.wrapT)) + " " +
               std::to_string(int(slot.channel));
        for (float v : slot.scale) key += " " + std::to_string(v);
        for (float v : slot.bias) key += " " + std::to_string(v);
        for (float v : slot.transform) key += " " + std::to_string(v);
        break;
    }
    bake.key = std::move(key);
    return bake;
}

Mesh::~Mesh() {
    if (building_) {  // a sync that threw before the render index finished it: the build is waited for, then dropped
        RenderParam ignored;
        try {
            mesh_ = meshes_.finish(*building_, ignored);
        } catch (const std::exception&) {
        }
    }
    if (mesh_) meshes_.release(*mesh_);
}

void Mesh::finish_build(RenderParam& param) {
    const std::unique_ptr<MeshTable::Ticket> ticket = std::move(building_);
    try {
        mesh_ = meshes_.finish(*ticket, param);
    } catch (const MeshError& e) {
        param.errors.push_back(std::string(e.what()) + "; the mesh is skipped");
    }
}

void Mesh::sync(SceneDelegate& scene, RenderParam& param, uint32_t dirtyBits) {
    // A hidden mesh reads only its visibility: the rest (a build among it) waits until it shows, as in Hydra
    // (the render index keeps those bits dirty).
    const uint32_t asked = dirtyBits & ~std::exchange(defaults_, 0u);  // what the delegate said at insertion is not asked
    if (asked & DirtyVisibility) visible_ = scene.get_visible(id());
    if (!visible_) {
        awaitingBits_ = 0;  // its bits stay dirty with the render index, as a hidden mesh's do
        return;
    }
    // Only points, topology, primvars and sidedness rebuild the mesh; a transform, a material or new instance
    // transforms are read alone.
    if (asked & DirtyMaterialId) {
        materialId_ = scene.get_material_id(id());
        subsetMaterialIds_ = scene.get_subset_material_ids(id());
    }
    // A material that bakes its displacement: the mesh is diced and displaced as it is built, and built again when
    // its material's bake changes (or a binding moves it to or from one).
    std::optional<DisplacementBake> bake;
    bool rebuild = dirtyBits & (DirtyPoints | DirtyTopology | DirtyPrimvar | DirtyDoubleSided);
    if (rebuild || (dirtyBits & DirtyMaterialId)) {
        const MaterialDesc* material = param.material && !materialId_.empty() ? param.material(materialId_) : nullptr;
        if (material && material->displacementBake) bake = displacement_bake(*material);
        const std::string bakeKey = bake ? bake->key : "";
        rebuild = rebuild || bakeKey != bakeKey_;
        bakeKey_ = bakeKey;
    }
    if (asked & DirtyTransform) transform_ = scene.get_transform(id());
    awaitingBits_ = 0;
    if (rebuild) {
        if (building_) finish_build(param);  // the render index finishes each sync's builds: only defensive
        if (mesh_) {
            meshes_.release(*mesh_);
            mesh_.reset();
        }
        // Model only what the render needs: a plain mesh whose bounds the view does not see waits (its build held back
        // as DirtyPoints, with the material id to read again) until a view sees them. Instanced meshes (many places)
        // and displaced ones (bounds that grow) are built at once.
        if (param.view && instancerId_.empty() && !displaced_by_materials(param)) {
            if (const auto extent = scene.get_extent(id())) {
                box_ = *extent;
                if (!seen_by(*param.view)) {
                    awaitingBits_ = DirtyPoints | (dirtyBits & (DirtyTopology | DirtyPrimvar | DirtyDoubleSided | DirtyMaterialId));
                    return;
                }
            }
        }
        try {
            MeshSource source = scene.get_mesh(id());
            doubleSided_ = source.doubleSided;
            if (source.view.name.empty()) source.view.name = id();
            building_ = std::make_unique<MeshTable::Ticket>(meshes_.start(std::move(source), std::move(bake), param));
        } catch (const MeshError& e) {
            param.errors.push_back(std::string(e.what()) + "; the mesh is skipped");
        }
    }
    if ((dirtyBits & DirtyInstancer) && !instancerId_.empty()) instances_ = scene.get_instances(instancerId_, id());
}

bool Mesh::displaced_by_materials(const RenderParam& param) const {
    auto displaces = [&](const PrimId& id) {
        const MaterialDesc* m = param.material && !id.empty() ? param.material(id) : nullptr;
        if (!m) return false;
        for (const TextureSlot& slot : m->textures)
            if (slot.input == MaterialInput::Displacement) return true;
        return m->displacementBake || m->displacement != 0.0f;
    };
    return displaces(materialId_) || std::any_of(subsetMaterialIds_.begin(), subsetMaterialIds_.end(), displaces);
}

void Material::sync(SceneDelegate& scene, RenderParam& param, uint32_t dirtyBits) {
    if (!(dirtyBits & DirtyParams)) return;
    MaterialDesc desc = scene.get_material(id());
    textures_.load_slots(desc.textures, id(), param.warnings);  // while desc_ still holds the old images: shared, not re-read
    desc_ = std::move(desc);
    bakeKey_ = desc_.displacementBake ? displacement_bake(desc_)->key : "";
}

bool Light::is_light_type(const std::string& type) {
    return type == "distantLight" || type == "domeLight" || type == "rectLight" || type == "sphereLight";
}

void Light::sync(SceneDelegate& scene, RenderParam& param, uint32_t dirtyBits) {
    if (!(dirtyBits & (DirtyParams | DirtyTransform))) return;
    LightDesc desc = scene.get_light(id());
    if (!desc.textureFile.empty()) {
        try {
            desc.texture = textures_.load(desc.textureFile, ColorSpace::Auto);  // while desc_ holds the old image: shared
            desc.environment = desc.texture == desc_.texture ? desc_.environment : latlong_irradiance(*desc.texture);
        } catch (const TextureError& e) {
            param.warnings.push_back(id() + ": dome texture '" + desc.textureFile + "' cannot be read (" + e.what() +
                                     "); the dome lights by its colour alone");
        }
    }
    desc_ = std::move(desc);
}

void Camera::sync(SceneDelegate& scene, RenderParam&, uint32_t dirtyBits) {
    if (dirtyBits & (DirtyParams | DirtyTransform)) desc_ = scene.get_camera(id());
}

}  // namespace tessera::hd
