#include "tessera/renderer.h"

#include <atomic>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>

namespace tessera {

uint64_t GpuScene::next_serial() {
    static std::atomic<uint64_t> next{1};
    return next.fetch_add(1, std::memory_order_relaxed);
}

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

namespace {
double half_to_double(uint16_t h) {
    const int exponent = (h >> 10) & 0x1f, mantissa = h & 0x3ff;
    const double sign = (h & 0x8000) ? -1.0 : 1.0;
    if (exponent == 0) return sign * std::ldexp(mantissa, -24);
    if (exponent == 31) return mantissa ? NAN : sign * INFINITY;
    return sign * std::ldexp(mantissa + 1024, exponent - 25);
}
}  // namespace

void InstanceArrays::validate() const {
    const size_t n = positions.size() / 3;
    if (positions.size() % 3) throw std::invalid_argument("positions must hold 3 floats per instance");
    if (!orientations.empty() && !orientationsHalf.empty()) throw std::invalid_argument("give orientations as floats or as halves, not both");
    if (!orientations.empty() && orientations.size() != 4 * n)
        throw std::invalid_argument(std::to_string(orientations.size() / 4) + " orientations for " + std::to_string(n) + " positions");
    if (!orientationsHalf.empty() && orientationsHalf.size() != 4 * n)
        throw std::invalid_argument(std::to_string(orientationsHalf.size() / 4) + " orientations for " + std::to_string(n) + " positions");
    if (!scales.empty() && scales.size() != 3 * n)
        throw std::invalid_argument(std::to_string(scales.size() / 3) + " scales for " + std::to_string(n) + " positions");
    for (uint32_t index : selection)
        if (index >= n) throw std::invalid_argument("instance " + std::to_string(index) + " selected of " + std::to_string(n));
}

// USD's PointInstancer order (UsdGeomPointInstancer::ComputeInstanceTransformsAtTime): scale, then rotate, then
// translate, in double, the quaternion normalized (a zero one is no rotation).
Matrix4d InstanceArrays::transform(size_t n) const {
    const size_t i = selection.empty() ? n : selection[n];
    double q[4] = {0, 0, 0, 1};
    if (!orientations.empty())
        for (int k = 0; k < 4; ++k) q[k] = orientations[4 * i + k];
    else if (!orientationsHalf.empty())
        for (int k = 0; k < 4; ++k) q[k] = half_to_double(orientationsHalf[4 * i + k]);
    const double length = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (length > 0 && std::isfinite(length))
        for (double& c : q) c /= length;
    else
        q[0] = q[1] = q[2] = 0, q[3] = 1;
    const double x = q[0], y = q[1], z = q[2], w = q[3];
    const double r[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                         2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                         2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)};
    const double s[3] = {scales.empty() ? 1.0 : scales[3 * i], scales.empty() ? 1.0 : scales[3 * i + 1], scales.empty() ? 1.0 : scales[3 * i + 2]};
    Matrix4d trs = identity_matrix();
    for (int row = 0; row < 3; ++row) {
        for (int col = 0; col < 3; ++col) trs[row * 4 + col] = r[row * 3 + col] * s[col];
        trs[row * 4 + 3] = positions[3 * i + row];
    }
    return multiply(trs, local);
}

uint64_t GpuScene::instance_count() const {
    uint64_t count = 0;
    for (const InstanceDesc& desc : instances_) count += desc.count();
    return count;
}

namespace {

// What a built mesh's streams take on the host.
uint64_t stream_bytes(const BuiltMesh* m) {
    if (!m) return 0;
    return m->positions.size() * sizeof(float) + (m->normals.size() + m->colors.size() + m->triangles.size()) * sizeof(uint32_t) +
           m->uvs.size() * sizeof(float) + m->clusters.size() * sizeof(Cluster);
}

}  // namespace

uint32_t GpuScene::add_mesh(std::shared_ptr<const BuiltMesh> mesh, MeshReload reload) {
    ++geometryVersion_;
    uint32_t handle;
    if (!freeMeshes_.empty()) {
        handle = freeMeshes_.back();
        freeMeshes_.pop_back();
    } else {
        handle = uint32_t(meshes_.size());
        meshes_.emplace_back();
        reloads_.emplace_back();
        released_.push_back(0);
        serials_.push_back(0);
    }
    heldBytes_ += stream_bytes(mesh.get());
    meshes_[handle] = std::move(mesh);
    reloads_[handle] = std::move(reload);
    released_[handle] = 0;
    serials_[handle] = next_serial();
    return handle;
}

void GpuScene::remove_mesh(uint32_t handle) {
    if (!released_.at(handle)) heldBytes_ -= stream_bytes(meshes_[handle].get());
    meshes_[handle].reset();
    reloads_[handle] = nullptr;
    released_[handle] = 0;
    serials_[handle] = 0;
    freeMeshes_.push_back(handle);
    ++geometryVersion_;
}

void GpuScene::release_streams(uint32_t handle) {
    if (!meshes_.at(handle) || !reloads_[handle] || released_[handle]) return;
    heldBytes_ -= stream_bytes(meshes_[handle].get());
    meshes_[handle] = std::make_shared<const BuiltMesh>(without_streams(*meshes_[handle]));
    released_[handle] = 1;
}

const std::shared_ptr<const BuiltMesh>& GpuScene::full_mesh(uint32_t handle) {
    if (meshes_.at(handle) && released_[handle]) {
        meshes_[handle] = reloads_[handle]();
        released_[handle] = 0;
        heldBytes_ += stream_bytes(meshes_[handle].get());
    }
    return meshes_[handle];
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
