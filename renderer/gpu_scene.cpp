#include "tessera/renderer.h"

namespace tessera {

Matrix4d identity_matrix() { return {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1}; }

Matrix4d multiply(const Matrix4d& a, const Matrix4d& b) {
    Matrix4d r{};
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) {
            double sum = 0;
            for (int k = 0; k < 4; ++k) sum += a[i * 4 + k] * b[k * 4 + j];
            r[i * 4 + j] = sum;
        }
    return r;
}

uint32_t GpuScene::add_mesh(std::shared_ptr<const BuiltMesh> mesh) {
    ++geometryVersion_;
    if (!freeMeshes_.empty()) {
        const uint32_t handle = freeMeshes_.back();
        freeMeshes_.pop_back();
        meshes_[handle] = std::move(mesh);
        return handle;
    }
    meshes_.push_back(std::move(mesh));
    return uint32_t(meshes_.size() - 1);
}

void GpuScene::remove_mesh(uint32_t handle) {
    meshes_.at(handle).reset();
    freeMeshes_.push_back(handle);
    ++geometryVersion_;
}

uint32_t GpuScene::add_material(const MaterialDesc& material) {
    materials_.push_back(material);
    ++materialsVersion_;
    return uint32_t(materials_.size() - 1);
}

uint32_t GpuScene::add_material_table(std::span<const uint32_t> materials) {
    materialTables_.push_back(0);  // the header word: the renderer puts the table's largest displacement there
    materialTableRanges_.push_back({uint32_t(materialTables_.size()), uint32_t(materials.size())});
    materialTables_.insert(materialTables_.end(), materials.begin(), materials.end());
    ++materialsVersion_;
    return uint32_t(materialTables_.size() - materials.size());
}

void GpuScene::clear_materials() {
    materials_.clear();
    materialTables_.clear();
    materialTableRanges_.clear();
    ++materialsVersion_;
}

void GpuScene::set_instances(std::vector<InstanceDesc> instances) {
    instances_ = std::move(instances);
    ++instancesVersion_;
}

void GpuScene::set_instance_transform(size_t index, const Matrix4d& transform) {
    instances_.at(index).transform = transform;
    ++instancesVersion_;
}

void GpuScene::set_lights(std::vector<LightDesc> lights) { lights_ = std::move(lights); }

}  // namespace tessera
