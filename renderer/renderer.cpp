// A frame: upload what changed, cull instances and clusters, raster visible clusters into the 64-bit
// visibility buffer, resolve each requested AOV, read back. The visible-cluster list is fixed-size: when the
// cull pass counts more clusters than fit, the list grows and the frame is drawn again.
// Two-pass occlusion culling: the main pass draws what the previous frame's HZB does not hide; an HZB of that is
// built; the post pass tests what the main pass deferred against it and draws the rest; the HZB of the whole frame is
// kept for the next frame (rebuilt only where the post pass drew something: the GPU decides, hzb.comp.glsl).
#include "tessera/renderer.h"
#include "tessera/parallel.h"

#include "cut_blocks.h"
#include "displacement.h"
#include "pipelines.h"
#include "shared.h"
#include "stream_arena.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <map>
#include <numeric>
#include <string>
#include <unordered_map>

namespace tessera {

static_assert(kClusterMaxTriangles == TS_CLUSTER_MAX_TRIANGLES && kClusterMaxVertices == TS_CLUSTER_MAX_VERTICES,
              "builder and shaders must agree on the cluster budget");
static_assert(kMaxLights == TS_MAX_LIGHTS, "the render index and the frame must agree on the light budget");
static_assert((1u << TS_VIS_TRIANGLE_BITS) == TS_CLUSTER_MAX_TRIANGLES, "the visibility buffer addresses every triangle of a cluster");

const char* aov_name(Aov aov) {
    switch (aov) {
        case Aov::Color: return "color";
        case Aov::Depth: return "depth";
        case Aov::Normal: return "normal";
        case Aov::PrimId: return "primId";
        case Aov::InstanceId: return "instanceId";
        case Aov::ClusterId: return "clusterId";
        case Aov::TriangleId: return "triangleId";
    }
    return "?";
}

const char* visualize_name(Visualize mode) {
    switch (mode) {
        case Visualize::None: return "none";
        case Visualize::Triangles: return "triangles";
        case Visualize::Clusters: return "clusters";
        case Visualize::Groups: return "groups";
        case Visualize::Lod: return "lod";
        case Visualize::Instances: return "instances";
        case Visualize::Primitives: return "primitives";
        case Visualize::ShadingBins: return "shading-bins";
        case Visualize::RasterBins: return "raster-bins";
        case Visualize::Overdraw: return "overdraw";
        case Visualize::Uv: return "uv";
        case Visualize::Tessellation: return "tessellation";
    }
    return "?";
}
static_assert(uint32_t(Visualize::Triangles) == TS_VIS_TRIANGLES && uint32_t(Visualize::Overdraw) == TS_VIS_OVERDRAW &&
                  uint32_t(Visualize::Uv) == TS_VIS_UV && uint32_t(Visualize::Tessellation) == TS_VIS_TESSELLATION,
              "Visualize must match the TS_VIS_* modes");

bool aov_is_id(Aov aov) { return aov == Aov::PrimId || aov == Aov::InstanceId || aov == Aov::ClusterId || aov == Aov::TriangleId; }

namespace {

static_assert(vertex_input(MaterialInput::Occlusion, 1, true) == (TS_VERTEX_INPUT_SET | TS_VERTEX_INPUT_RGB | 1u) << (TS_VERTEX_INPUT_BITS * TS_INPUT_OCCLUSION) &&
                  int(MaterialInput::Occlusion) == TS_VERTEX_INPUT_LAST,
              "MaterialDesc::vertexInputs is GpuMaterial::vertexInputs");

// HZB level sizes (shaders/frame.h hzb_level_size): level l has a texel per 2^(l+1) pixels, down to 1x1.
std::vector<std::array<uint32_t, 2>> hzb_levels(uint32_t width, uint32_t height) {
    std::vector<std::array<uint32_t, 2>> levels;
    for (uint32_t tile = 2;; tile *= 2) {
        levels.push_back({(width + tile - 1) / tile, (height + tile - 1) / tile});
        if (levels.back()[0] == 1 && levels.back()[1] == 1) break;
    }
    return levels;
}

Matrix4d translation_matrix(double x, double y, double z) {
    Matrix4d m = identity_matrix();
    m[3] = x;
    m[7] = y;
    m[11] = z;
    return m;
}

using Matrix3d = std::array<double, 9>;

// Largest singular value of a 3x3 matrix: the most it stretches any length (closed-form eigenvalue of MᵀM).
double max_stretch(const Matrix3d& m) {
    double a[3][3];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) a[i][j] = m[0 + i] * m[0 + j] + m[3 + i] * m[3 + j] + m[6 + i] * m[6 + j];
    const double p1 = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    double largest;
    if (p1 == 0) {
        largest = std::max({a[0][0], a[1][1], a[2][2]});
    } else {
        const double q = (a[0][0] + a[1][1] + a[2][2]) / 3;
        const double p2 = (a[0][0] - q) * (a[0][0] - q) + (a[1][1] - q) * (a[1][1] - q) + (a[2][2] - q) * (a[2][2] - q) + 2 * p1;
        const double p = std::sqrt(p2 / 6);
        double b[3][3];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) b[i][j] = (a[i][j] - (i == j ? q : 0)) / p;
        const double det = b[0][0] * (b[1][1] * b[2][2] - b[1][2] * b[2][1]) - b[0][1] * (b[1][0] * b[2][2] - b[1][2] * b[2][0]) +
                           b[0][2] * (b[1][0] * b[2][1] - b[1][1] * b[2][0]);
        const double phi = std::acos(std::clamp(det / 2, -1.0, 1.0)) / 3;
        largest = q + 2 * p * std::cos(phi);
    }
    return std::sqrt(std::max(largest, 0.0)) * (1 + 1e-6);
}

double determinant3(const Matrix3d& m) {
    return m[0] * (m[4] * m[8] - m[5] * m[7]) - m[1] * (m[3] * m[8] - m[5] * m[6]) + m[2] * (m[3] * m[7] - m[4] * m[6]);
}

bool invert(const Matrix4d& m, Matrix4d& out) {
    // Cofactor expansion, in double.
    Matrix4d inv;
    inv[0] = m[5] * m[10] * m[15] - m[5] * m[11] * m[14] - m[9] * m[6] * m[15] + m[9] * m[7] * m[14] + m[13] * m[6] * m[11] - m[13] * m[7] * m[10];
    inv[4] = -m[4] * m[10] * m[15] + m[4] * m[11] * m[14] + m[8] * m[6] * m[15] - m[8] * m[7] * m[14] - m[12] * m[6] * m[11] + m[12] * m[7] * m[10];
    inv[8] = m[4] * m[9] * m[15] - m[4] * m[11] * m[13] - m[8] * m[5] * m[15] + m[8] * m[7] * m[13] + m[12] * m[5] * m[11] - m[12] * m[7] * m[9];
    inv[12] = -m[4] * m[9] * m[14] + m[4] * m[10] * m[13] + m[8] * m[5] * m[14] - m[8] * m[6] * m[13] - m[12] * m[5] * m[10] + m[12] * m[6] * m[9];
    inv[1] = -m[1] * m[10] * m[15] + m[1] * m[11] * m[14] + m[9] * m[2] * m[15] - m[9] * m[3] * m[14] - m[13] * m[2] * m[11] + m[13] * m[3] * m[10];
    inv[5] = m[0] * m[10] * m[15] - m[0] * m[11] * m[14] - m[8] * m[2] * m[15] + m[8] * m[3] * m[14] + m[12] * m[2] * m[11] - m[12] * m[3] * m[10];
    inv[9] = -m[0] * m[9] * m[15] + m[0] * m[11] * m[13] + m[8] * m[1] * m[15] - m[8] * m[3] * m[13] - m[12] * m[1] * m[11] + m[12] * m[3] * m[9];
    inv[13] = m[0] * m[9] * m[14] - m[0] * m[10] * m[13] - m[8] * m[1] * m[14] + m[8] * m[2] * m[13] + m[12] * m[1] * m[10] - m[12] * m[2] * m[9];
    inv[2] = m[1] * m[6] * m[15] - m[1] * m[7] * m[14] - m[5] * m[2] * m[15] + m[5] * m[3] * m[14] + m[13] * m[2] * m[7] - m[13] * m[3] * m[6];
    inv[6] = -m[0] * m[6] * m[15] + m[0] * m[7] * m[14] + m[4] * m[2] * m[15] - m[4] * m[3] * m[14] - m[12] * m[2] * m[7] + m[12] * m[3] * m[6];
    inv[10] = m[0] * m[5] * m[15] - m[0] * m[7] * m[13] - m[4] * m[1] * m[15] + m[4] * m[3] * m[13] + m[12] * m[1] * m[7] - m[12] * m[3] * m[5];
    inv[14] = -m[0] * m[5] * m[14] + m[0] * m[6] * m[13] + m[4] * m[1] * m[14] - m[4] * m[2] * m[13] - m[12] * m[1] * m[6] + m[12] * m[2] * m[5];
    inv[3] = -m[1] * m[6] * m[11] + m[1] * m[7] * m[10] + m[5] * m[2] * m[11] - m[5] * m[3] * m[10] - m[9] * m[2] * m[7] + m[9] * m[3] * m[6];
    inv[7] = m[0] * m[6] * m[11] - m[0] * m[7] * m[10] - m[4] * m[2] * m[11] + m[4] * m[3] * m[10] + m[8] * m[2] * m[7] - m[8] * m[3] * m[6];
    inv[11] = -m[0] * m[5] * m[11] + m[0] * m[7] * m[9] + m[4] * m[1] * m[11] - m[4] * m[3] * m[9] - m[8] * m[1] * m[7] + m[8] * m[3] * m[5];
    inv[15] = m[0] * m[5] * m[10] - m[0] * m[6] * m[9] - m[4] * m[1] * m[10] + m[4] * m[2] * m[9] + m[8] * m[1] * m[6] - m[8] * m[2] * m[5];
    const double det = m[0] * inv[0] + m[1] * inv[4] + m[2] * inv[8] + m[3] * inv[12];
    if (det == 0 || !std::isfinite(det)) return false;
    for (int i = 0; i < 16; ++i) out[i] = inv[i] / det;
    return true;
}

gpu::mat4 to_gpu(const Matrix4d& m) {  // row-major double -> column-major float
    gpu::mat4 r;
    for (int c = 0; c < 4; ++c) r.columns[c] = {float(m[0 * 4 + c]), float(m[1 * 4 + c]), float(m[2 * 4 + c]), float(m[3 * 4 + c])};
    return r;
}

void split_double(double value, float& high, float& low) {
    high = float(value);
    low = float(value - double(high));
}

uint32_t pack_cone(const NormalCone& cone) {
    return uint32_t(uint8_t(cone.axis8[0])) | uint32_t(uint8_t(cone.axis8[1])) << 8 | uint32_t(uint8_t(cone.axis8[2])) << 16 |
           uint32_t(uint8_t(cone.cutoff8)) << 24;
}

// True when the matrix keeps angles (a rotation times a uniform scale, possibly mirrored): its columns are
// orthogonal and of equal length.
bool conformal(const Matrix3d& m) {
    double c[3][3];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) c[i][j] = m[0 + i] * m[0 + j] + m[3 + i] * m[3 + j] + m[6 + i] * m[6 + j];
    const double scale = (c[0][0] + c[1][1] + c[2][2]) / 3;
    const double tolerance = 1e-5 * scale;
    return scale > 0 && std::abs(c[0][1]) < tolerance && std::abs(c[0][2]) < tolerance && std::abs(c[1][2]) < tolerance &&
           std::abs(c[0][0] - scale) < tolerance && std::abs(c[1][1] - scale) < tolerance && std::abs(c[2][2] - scale) < tolerance;
}

struct CameraMatrices {
    double projectionScaleY;  // |P11|: clip-space y per unit of view-space height (at unit depth, perspective)
    Matrix4d viewProjection;  // camera-relative world -> clip
    Matrix4d inverseViewProjection;
    std::array<double, 3> position, forward;
};

// Reversed-Z projection (near -> 1, far -> 0), Vulkan clip space with +Y down, the window fit to the image. `pixelOffset`
// (pixels, x right, y down) moves where each pixel samples the scene: the image shifts the other way by as much.
CameraMatrices camera_matrices(const CameraDesc& camera, uint32_t width, uint32_t height, std::array<float, 2> pixelOffset = {0, 0}) {
    CameraMatrices out;
    const Matrix4d& c2w = camera.cameraToWorld;
    out.position = {c2w[3], c2w[7], c2w[11]};
    // World -> camera rotation: the transpose of the camera's orthonormalised axes.
    std::array<std::array<double, 3>, 3> axis;
    for (int a = 0; a < 3; ++a) {
        std::array<double, 3> v = {c2w[0 * 4 + a], c2w[1 * 4 + a], c2w[2 * 4 + a]};
        const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        for (double& x : v) x /= (len > 0 ? len : 1);
        axis[a] = v;
    }
    out.forward = {-axis[2][0], -axis[2][1], -axis[2][2]};
    Matrix4d view{};
    for (int r = 0; r < 3; ++r)
        for (int k = 0; k < 3; ++k) view[r * 4 + k] = axis[r][k];
    view[15] = 1;

    // Fit: widen whichever aperture is too small for the image's aspect ratio.
    double hAp = camera.horizontalAperture, vAp = camera.verticalAperture;
    const double imageAspect = double(width) / double(height);
    if (hAp / vAp < imageAspect) hAp = vAp * imageAspect;
    else vAp = hAp / imageAspect;
    const double n = camera.nearClip, f = camera.farClip;
    Matrix4d proj{};
    if (!camera.orthographic) {
        // Screen window at unit distance.
        const double x0 = (-0.5 * hAp + camera.horizontalApertureOffset) / camera.focalLength;
        const double x1 = (0.5 * hAp + camera.horizontalApertureOffset) / camera.focalLength;
        const double y0 = (-0.5 * vAp + camera.verticalApertureOffset) / camera.focalLength;
        const double y1 = (0.5 * vAp + camera.verticalApertureOffset) / camera.focalLength;
        proj[0] = 2 / (x1 - x0);
        proj[2] = 2 * x0 / (x1 - x0) + 1;
        proj[5] = -2 / (y1 - y0);
        proj[6] = -(2 * y0 / (y1 - y0) + 1);
        if (std::isinf(f)) {
            proj[10] = 0;
            proj[11] = n;
        } else {
            proj[10] = n / (f - n);
            proj[11] = n * f / (f - n);
        }
        proj[14] = -1;
    } else {
        const double x0 = -0.5 * hAp + camera.horizontalApertureOffset, x1 = 0.5 * hAp + camera.horizontalApertureOffset;
        const double y0 = -0.5 * vAp + camera.verticalApertureOffset, y1 = 0.5 * vAp + camera.verticalApertureOffset;
        const double far = std::isinf(f) ? 1e30 : f;
        proj[0] = 2 / (x1 - x0);
        proj[3] = -(x1 + x0) / (x1 - x0);
        proj[5] = -2 / (y1 - y0);
        proj[7] = (y1 + y0) / (y1 - y0);
        proj[10] = 1 / (far - n);
        proj[11] = far / (far - n);
        proj[15] = 1;
    }
    // Normalized device coordinates move by -2 offset / size; a perspective divide by w = -z (the terms of z), an
    // orthographic one by w = 1 (the constant terms).
    const double shiftX = -2.0 * pixelOffset[0] / width, shiftY = -2.0 * pixelOffset[1] / height;
    if (!camera.orthographic) {
        proj[2] -= shiftX;
        proj[6] -= shiftY;
    } else {
        proj[3] += shiftX;
        proj[7] += shiftY;
    }
    out.projectionScaleY = std::abs(proj[5]);
    out.viewProjection = multiply(proj, view);
    if (!invert(out.viewProjection, out.inverseViewProjection)) throw std::runtime_error("camera projection is singular");
    return out;
}

// The frame's pixel rays (GpuFrame.rayOrigin, rayDirection): the points of the near plane (NDC depth 1) and of NDC depth
// 0.5 through each point of the image, as an affine function of its pixel coordinates, in double. Exact where the
// inverse projection's w does not depend on the image position, as for every camera camera_matrices makes.
void set_pixel_rays(gpu::GpuFrame& f, const Matrix4d& inverseViewProjection, uint32_t width, uint32_t height) {
    auto unproject = [&](double px, double py, double depth) {
        const double ndc[4] = {px / width * 2 - 1, py / height * 2 - 1, depth, 1};
        std::array<double, 4> p{};
        for (int r = 0; r < 4; ++r)
            for (int k = 0; k < 4; ++k) p[r] += inverseViewProjection[r * 4 + k] * ndc[k];
        return std::array<double, 3>{p[0] / p[3], p[1] / p[3], p[2] / p[3]};
    };
    const std::array<double, 3> nearAt[3] = {unproject(0, 0, 1), unproject(1, 0, 1), unproject(0, 1, 1)};
    const std::array<double, 3> midAt[3] = {unproject(0, 0, 0.5), unproject(1, 0, 0.5), unproject(0, 1, 0.5)};
    for (int i = 0; i < 3; ++i) {
        std::array<double, 3> origin = nearAt[i], direction;
        for (int k = 0; k < 3; ++k) {
            direction[k] = midAt[i][k] - nearAt[i][k];
            if (i > 0) {  // the change per pixel
                origin[k] -= nearAt[0][k];
                direction[k] -= midAt[0][k] - nearAt[0][k];
            }
        }
        f.rayOrigin[i] = {float(origin[0]), float(origin[1]), float(origin[2]), 0};
        f.rayDirection[i] = {float(direction[0]), float(direction[1]), float(direction[2]), 0};
    }
}

// The frustum planes from the rows of the view-projection (Vulkan clip: -w <= x, y <= w, 0 <= z <= w), normalized.
ViewFrustum frustum_of(const CameraMatrices& cam) {
    const Matrix4d& vp = cam.viewProjection;
    auto row = [&](int r, int k) { return vp[r * 4 + k]; };
    const double planes[6][4] = {
        {row(3, 0) + row(0, 0), row(3, 1) + row(0, 1), row(3, 2) + row(0, 2), row(3, 3) + row(0, 3)},
        {row(3, 0) - row(0, 0), row(3, 1) - row(0, 1), row(3, 2) - row(0, 2), row(3, 3) - row(0, 3)},
        {row(3, 0) + row(1, 0), row(3, 1) + row(1, 1), row(3, 2) + row(1, 2), row(3, 3) + row(1, 3)},
        {row(3, 0) - row(1, 0), row(3, 1) - row(1, 1), row(3, 2) - row(1, 2), row(3, 3) - row(1, 3)},
        {row(2, 0), row(2, 1), row(2, 2), row(2, 3)},
        {row(3, 0) - row(2, 0), row(3, 1) - row(2, 1), row(3, 2) - row(2, 2), row(3, 3) - row(2, 3)}};
    ViewFrustum out;
    out.position = cam.position;
    for (int i = 0; i < 6; ++i) {
        const double len = std::sqrt(planes[i][0] * planes[i][0] + planes[i][1] * planes[i][1] + planes[i][2] * planes[i][2]);
        out.planes[i] = len > 1e-300 ? std::array<double, 4>{planes[i][0] / len, planes[i][1] / len, planes[i][2] / len, planes[i][3] / len}
                                     : std::array<double, 4>{0, 0, 0, 1};  // an infinite far plane culls nothing
    }
    return out;
}


// What an AOV holds where nothing covers a pixel, as the four words of its output texel: the background colour, infinite
// depth, a zero normal, no id (a textured dome's colour is drawn per pixel instead: background.comp.glsl).
std::array<uint32_t, 4> background_words(Aov aov, const std::array<float, 4>& color) {
    if (aov_is_id(aov)) return {TS_BACKGROUND_ID, TS_BACKGROUND_ID, TS_BACKGROUND_ID, TS_BACKGROUND_ID};
    if (aov == Aov::Depth) return {TS_BACKGROUND_DEPTH_BITS, TS_BACKGROUND_DEPTH_BITS, TS_BACKGROUND_DEPTH_BITS, TS_BACKGROUND_DEPTH_BITS};
    if (aov == Aov::Normal) return {0u, 0u, 0u, 0u};
    std::array<uint32_t, 4> words;
    std::memcpy(words.data(), color.data(), 16);
    return words;
}

// How many workgroups may share an instance's cut and the clusters each takes (GpuFrame.hzb.w, cull.comp.glsl
// cut_parts). A GPU: up to 64 parts of 1024 clusters (16 per thread of a 64-wide cull group), so that one mesh filling
// the view spreads over the multiprocessors. A CPU device: a part per core, of 16384 clusters, so that the instances of
// a field (a few hundred to a few thousand clusters each) stay whole: lavapipe pays about 30 us per workgroup.
uint32_t cut_parts_word(const Device& device, const RenderSettings& settings) {
    const uint32_t cores = uint32_t(std::clamp<size_t>(core_count(), 1, 64));
    const uint32_t parts = std::clamp(settings.cutParts ? settings.cutParts : device.is_software() ? cores : TS_CUT_MOST_PARTS, 1u, TS_CUT_MOST_PARTS);
    const uint32_t clusters = std::clamp(settings.cutPartClusters ? settings.cutPartClusters : device.is_software() ? 16384u : 1024u, 1u, 0xffffu);
    return parts | clusters << 16;
}

void barrier(VkCommandBuffer cmd, VkPipelineStageFlags2 srcStage, VkAccessFlags2 srcAccess, VkPipelineStageFlags2 dstStage, VkAccessFlags2 dstAccess) {
    // What a shader reads from storage it may read through a texel view of the same buffer (TS_VIEW_*): a sampled read.
    if (dstAccess & VK_ACCESS_2_SHADER_STORAGE_READ_BIT) dstAccess |= VK_ACCESS_2_SHADER_SAMPLED_READ_BIT;
    VkMemoryBarrier2 memory{VK_STRUCTURE_TYPE_MEMORY_BARRIER_2};
    memory.srcStageMask = srcStage;
    memory.srcAccessMask = srcAccess;
    memory.dstStageMask = dstStage;
    memory.dstAccessMask = dstAccess;
    VkDependencyInfo dependency{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
    dependency.memoryBarrierCount = 1;
    dependency.pMemoryBarriers = &memory;
    vkCmdPipelineBarrier2(cmd, &dependency);
}

// Copies `data` into `buffer` (made again where smaller) through the frame's upload batch.
template <typename T>
void upload_vector(Device& device, UploadBatch& uploads, Buffer& buffer, const std::vector<T>& data) {
    const size_t bytes = data.size() * sizeof(T);
    if (buffer.size < bytes || !buffer.handle) buffer = device.create_buffer(bytes, MemoryUse::Device);
    if (bytes > 0) std::memcpy(uploads.write(buffer, 0, bytes), data.data(), bytes);
}

}  // namespace

ViewFrustum view_frustum(const CameraDesc& camera, uint32_t width, uint32_t height) {
    return frustum_of(camera_matrices(camera, std::max(width, 1u), std::max(height, 1u)));
}

bool ViewFrustum::touches_box(const Matrix4d& transform, const std::array<double, 3>& lo, const std::array<double, 3>& hi) const {
    std::array<std::array<double, 3>, 8> corners;
    for (int c = 0; c < 8; ++c) {
        const double p[3] = {(c & 1) ? hi[0] : lo[0], (c & 2) ? hi[1] : lo[1], (c & 4) ? hi[2] : lo[2]};
        for (int r = 0; r < 3; ++r)
            corners[c][r] = transform[r * 4] * p[0] + transform[r * 4 + 1] * p[1] + transform[r * 4 + 2] * p[2] + transform[r * 4 + 3] - position[r];
    }
    for (const auto& plane : planes) {
        bool allOutside = true;
        for (const auto& q : corners) allOutside = allOutside && plane[0] * q[0] + plane[1] * q[1] + plane[2] * q[2] + plane[3] < 0;
        if (allOutside) return false;
    }
    return true;
}

struct Renderer::Impl {
    Device& device;
    // The compiled pipelines, shared with every renderer on this device (pipelines.h): the set reading the streams
    // through texel views and storing the AOVs through their binding, and (made when a frame first needs one) the set
    // storing them through their address (an output larger than the binding allows), and the set doing both through
    // addresses.
    std::shared_ptr<Pipelines> sharedPipelines;
    Pipelines& pipelines;
    std::shared_ptr<Pipelines> wideOutputPipelines, addressPipelines;
    // The frame's constants (GpuFrame) as a uniform buffer, set 0 binding 0 of every pipeline: a CPU device (lavapipe)
    // loads a uniform block once for all of a SIMD batch's invocations, where a load through a buffer device address
    // goes lane by lane; on a GPU it is the usual path for constants. Everything else is reached by address, and the
    // streams read per pixel, triangle or vertex also through the set's texel views.
    VkDescriptorPool framePool = VK_NULL_HANDLE;
    VkDescriptorSet frameSet = VK_NULL_HANDLE;
    VkQueryPool timestamps = VK_NULL_HANDLE;
    // The texel views of the frame set (shared.h TS_VIEW_*), made again for each frame over the buffers as they are then:
    // buffers are replaced as they grow, and a destroyed buffer's handle may be reused. The last frame has finished by
    // then (Device::run waits for it). `viewStandIn` is viewed where the scene lacks a stream: every binding needs a view.
    std::array<VkBufferView, TS_VIEW_COUNT> texelViews{};
    Buffer viewStandIn;

    // Scene streams.
    // start; main pass: cull, software raster, hardware raster, tessellation; HZB; post pass: cull, software, hardware
    // raster, tessellation; the frame's HZB; resolve. Then a pair around each AOV's copy to the readback (the first
    // kTimedCopies), which the readback span adds up and the resolve span leaves out.
    static constexpr uint32_t kFrameMarks = 13, kTimedCopies = 8;
    static constexpr uint32_t kTimestamps = kFrameMarks + 2 * kTimedCopies;
    Buffer hardwareList, softwareList;
    Buffer instances, meshes, materials, materialTables;
    // The meshes' streams: each mesh keeps its ranges while it is in the scene (upload_geometry).
    StreamArena levels{sizeof(gpu::GpuLevel)}, cutBlocks{sizeof(gpu::GpuCutBlock)}, blockClusters{sizeof(uint32_t)}, clusters{sizeof(gpu::GpuCluster)},
        vertices{sizeof(gpu::GpuVertex)}, colors{sizeof(uint32_t)}, uvs{sizeof(uint32_t)}, triangles{sizeof(uint32_t)};
    // Those of the meshes drawn displaced (empty without them): displacement normals and UV seam words (displacement.h).
    StreamArena displacementNormals{sizeof(uint32_t)}, seams{sizeof(uint32_t)};
    Buffer instanceBatches, batches;
    uint32_t instanceCount = 0;
    uint64_t clusterCount = 0, sourceTriangles = 0;
    uint64_t uploadedScene = 0;  // the id of the scene last uploaded (GpuScene::id_; 0: none)
    // Instance batches: their GPU records and world origins in double, re-expressed relative to the camera when it
    // moves. Per-instance data is written straight into the GPU buffers and kept nowhere else.
    std::vector<gpu::GpuInstanceBatch> gpuBatches;
    std::vector<std::array<double, 3>> origins;
    std::array<double, 3> relativeTo{NAN, NAN, NAN};  // camera position the uploaded origins are relative to
    uint64_t geometryVersion = 0, instancesVersion = 0, materialsVersion = 0;
    // Frame resources.
    Buffer frame, drawState, visibleClusters, visibleRecords, visibility, aovOutput, readback;
    // An image of several pixel samples: their colours summed on a GPU (samples.comp.glsl; made for the image), on the
    // host beside a CPU device; $TESSERA_SAMPLE_SUMS (device, host) chooses, for tests and measurements.
    Buffer sampleSums[2];
    const bool sampleSumsOnDevice = environment_choice("TESSERA_SAMPLE_SUMS", "device", "host", !device.is_software());
    // A frame of several materials is classified into bins, each shaded by a dispatch of its own, on a GPU; a CPU device's
    // resolve reads each pixel's material instead (TS_SPEC_PIXEL_MATERIALS; not where a displaced material needs its
    // micro-triangles' bins). $TESSERA_MATERIAL_BINS (1, 0) chooses, for tests and measurements.
    const bool materialBins = environment_choice("TESSERA_MATERIAL_BINS", "1", "0", !device.is_software());
    Buffer deferredInstances, deferredClusters;
    Buffer cutList;  // instances the cut step walks (those the instance step did not cull); grows on overflow
    uint32_t cutCapacity = 1u << 12;
    uint32_t deferredCapacity = 1u << 12;  // the deferred-instance list's (instances the previous HZB hid); grows on overflow
    Buffer overdraw;  // fragments per pixel, made only for the overdraw view
    Buffer shadingBins;  // material bins: one GpuBin per material
    Buffer binPixels;    // covered pixels grouped by material: made when a frame first lists them (classify)
    // The share of the pixels the previous frame covered (-1: none yet): a one-bin frame after one that covered at least
    // kEveryPixelCoverage shades every pixel in place, else packs them (a CPU device) or lists them (a GPU); why, with
    // lavapipe's figures: TS_SPEC_PIXEL_SOURCE in shared.h.
    static constexpr double kEveryPixelCoverage = 0.75;
    double coverage = -1;
    uint32_t materialCount = 1;
    std::vector<gpu::GpuMaterial> materialRecords;  // as uploaded: resolve pushes its bin's
    std::vector<gpu::GpuTextureSlot> materialSlotRecords;  // as uploaded (upload_materials compares them with the next)
    std::vector<uint32_t> materialTableRecords;             // the scene's tables as last uploaded, likewise
    std::vector<std::array<uint32_t, 2>> materialTableRangeRecords;
    // Textures: the slots of textured materials, and the pool of the images they read (both empty without textures).
    Buffer textureSlots, texturePool;
    std::vector<std::shared_ptr<const TextureImage>> poolImages;  // the materials' images, then the dome lights'
    std::vector<std::shared_ptr<const TextureImage>> materialImages;
    std::vector<bool> maskedMaterials;  // per material: a textured or per-vertex opacity under an opacityThreshold (TS_INSTANCE_MASKED)
    std::vector<bool> texturedMaterials;  // per material: resolve samples textures (its bin uses a textured variant)
    // Per material, what the textures resolve reads need (TS_TEXTURE_KIND_* bits): those it samples, and a displacement
    // texture, which it reads again where it dices a micro-triangle again.
    std::vector<uint32_t> materialTextureKinds;
    bool anyMasked = false;  // an instance is flagged TS_INSTANCE_MASKED: the rasterizers' mask variants draw the frame
    uint32_t instanceFlags = 0;  // TS_SPECIALIZED_INSTANCE_FLAGS some instance carries: the cull's and classify's variant
    // Displacement: per material, whether it displaces; per mesh, whether a displaced instance draws it (those get
    // displacement normals); the lists of runtime tessellation, made only for scenes that displace.
    std::vector<bool> displacedMaterials, displacedMeshes;
    bool anyDisplaced = false;
    Buffer tessellationList, patches, patchDraws, dicePatches, deferredPatchList;
    static constexpr uint32_t kFirstPatchCapacity = 1u << 16, kFirstPointCapacity = 1u << 18;
    uint32_t patchCapacity = kFirstPatchCapacity;
    // The compute patch rasterizer's diced points, kept for resolve: a pool that grows (for the next frame) to what the
    // last frame asked for, up to 2^24 points; patches it cannot hold are diced again by resolve.
    Buffer patchPoints;
    uint32_t pointCapacity = kFirstPointCapacity;
    // Two-pass occlusion: one HZB, of the last frame drawn (with the camera that drew it) until the main pass has
    // culled, then of what the main pass drew, then of the whole frame (each build only when the GPU finds it needed:
    // `hzbDispatch` holds both builds' per-level dispatch arguments, written by the GPU). The previous frame's is
    // forgotten when what it shows may have moved (instances, meshes, size).
    Buffer hzbLevels, hzbDispatch;
    bool previousValid = false;
    uint32_t occlusionRest = 0;  // frames left to draw without occlusion (RenderSettings::occlusionMinimumCulled)
    Matrix4d previousViewProjection{};
    std::array<double, 3> previousCamera{};
    uint32_t capacity = 1u << 16;
    bool capacityPinned = false;  // set explicitly (tests): never sized from the scene
    uint32_t width = 0, height = 0;

    // $TESSERA_TEXTURE_KINDS=all: every textured bin through the variant that reads every texture kind (for tests and
    // measurements; the default, `material`, compiles in only what the bin's textures need).
    const bool allTextureKinds = environment_choice("TESSERA_TEXTURE_KINDS", "all", "material", false);
    // Frames write AOVs straight into their images where the device can (imports_aovs), unless $TESSERA_IMPORT_AOVS=0 or
    // the driver refused an import.
    bool importAovs = environment_choice("TESSERA_IMPORT_AOVS", "1", "0", true);
    // A GPU's AOV images are imported once and kept while frames reuse their memory (image_memory.cpp hands a freed
    // image's block to the next image of its size): importing pins the block's pages in the driver and letting go
    // unpins them, which beside an H100 cost more CPU than the frame's GPU time. An import not used by this frame or the
    // three before goes: a caller holding its last result cycles through two blocks per AOV, and two sessions drawing
    // in turns through three, each session's frames taking the block the other just let go. While kept, a block is
    // pinned (pin_pixel_block) so that it is never returned to the system.
    struct KeptImport {
        void* pixels;
        VkDeviceSize bytes;
        Buffer buffer;
        uint64_t lastFrame;
        KeptImport(void* p, VkDeviceSize b, Buffer imported, uint64_t frame) : pixels(p), bytes(b), buffer(std::move(imported)), lastFrame(frame) {
            pin_pixel_block(pixels);
        }
        KeptImport(const KeptImport&) = delete;
        KeptImport& operator=(const KeptImport&) = delete;
        ~KeptImport() {
            buffer = Buffer{};  // the device lets go of the memory before the block may be freed
            unpin_pixel_block(pixels);
        }
    };
    std::vector<std::unique_ptr<KeptImport>> keptImports;
    static constexpr uint64_t kKeptImportFrames = 4;
    uint64_t framesRendered = 0;
    const bool keepImports = environment_choice("TESSERA_KEEP_IMPORTS", "1", "0", true);  // 0: an import every frame

    VkBuffer kept_import(void* pixels, VkDeviceSize bytes, uint32_t& made) {
        for (auto& kept : keptImports)
            if (kept->pixels == pixels && kept->bytes == bytes) {
                kept->lastFrame = framesRendered;
                return kept->buffer.handle;
            }
        keptImports.push_back(std::make_unique<KeptImport>(pixels, bytes, device.import_host_memory(pixels, bytes), framesRendered));
        ++made;
        return keptImports.back()->buffer.handle;
    }
    void forget_old_imports() {
        std::erase_if(keptImports, [&](const auto& kept) { return !keepImports || kept->lastFrame + kKeptImportFrames < framesRendered; });
    }

    Impl(Device& d, std::shared_ptr<Pipelines> shared) : device(d), sharedPipelines(std::move(shared)), pipelines(*sharedPipelines) {}

    ~Impl() {
        device.wait_idle();
        VkDevice vk = device.handle();
        for (VkBufferView view : texelViews) vkDestroyBufferView(vk, view, nullptr);
        vkDestroyDescriptorPool(vk, framePool, nullptr);
        vkDestroyQueryPool(vk, timestamps, nullptr);
    }

    // This renderer's own: the frame's uniform buffer and its descriptor set, and the timestamp queries.
    void create_frame_resources() {
        const VkDescriptorPoolSize poolSizes[] = {{VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER, 1}, {VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, TS_VIEW_COUNT},
                                                  {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, TS_MOST_AOVS + 1}};
        VkDescriptorPoolCreateInfo poolInfo{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
        poolInfo.maxSets = 1;
        poolInfo.poolSizeCount = 3;
        poolInfo.pPoolSizes = poolSizes;
        check_vk(vkCreateDescriptorPool(device.handle(), &poolInfo, nullptr, &framePool), "vkCreateDescriptorPool");
        VkDescriptorSetAllocateInfo allocateInfo{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
        allocateInfo.descriptorPool = framePool;
        allocateInfo.descriptorSetCount = 1;
        allocateInfo.pSetLayouts = &pipelines.frameSetLayout;
        check_vk(vkAllocateDescriptorSets(device.handle(), &allocateInfo, &frameSet), "vkAllocateDescriptorSets");
        frame = device.create_buffer(sizeof(gpu::GpuFrame), MemoryUse::Upload, VK_BUFFER_USAGE_UNIFORM_BUFFER_BIT);
        write_buffer_binding(TS_BINDING_FRAME, VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER, frame.handle, 0, sizeof(gpu::GpuFrame));

        VkQueryPoolCreateInfo queryInfo{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
        queryInfo.queryType = VK_QUERY_TYPE_TIMESTAMP;
        queryInfo.queryCount = kTimestamps;
        check_vk(vkCreateQueryPool(device.handle(), &queryInfo, nullptr, &timestamps), "vkCreateQueryPool");
    }

    // A stream of the frame set's texel views (shared.h TS_VIEW_*): its buffer, the view's format and the texels a frame
    // of `pixels` may read from it.
    struct ViewedStream {
        const Buffer& buffer;
        VkFormat format;
        uint64_t texelBytes;
        uint64_t texels;
    };
    std::array<ViewedStream, TS_VIEW_COUNT> viewed_streams(uint64_t pixels) const {
        auto whole = [](const Buffer& b, uint64_t texelBytes) { return b.handle ? b.size / texelBytes : 0; };
        // A mesh stream's texels up to its last range in use (its buffer keeps room to grow).
        auto streamed = [](const StreamArena& a, uint64_t texelBytes) { return std::max<uint64_t>(a.end(), 1) * a.element_bytes() / texelBytes; };
        return {{{instances, VK_FORMAT_R32G32B32A32_UINT, 16, whole(instances, 16)},
                 {batches, VK_FORMAT_R32G32B32A32_UINT, 16, whole(batches, 16)},
                 {instanceBatches, VK_FORMAT_R32_UINT, 4, whole(instanceBatches, 4)},
                 {clusters.buffer(), VK_FORMAT_R32G32B32A32_UINT, 16, streamed(clusters, 16)},
                 {meshes, VK_FORMAT_R32G32B32A32_UINT, 16, whole(meshes, 16)},
                 {vertices.buffer(), VK_FORMAT_R32G32B32A32_UINT, 16, streamed(vertices, 16)},
                 {triangles.buffer(), VK_FORMAT_R32_UINT, 4, streamed(triangles, 4)},
                 {visibleClusters, VK_FORMAT_R32G32_UINT, 8, TS_VIS_MAX_VISIBLE_CLUSTERS},  // the most a frame may grow it to
                 {visibility, VK_FORMAT_R32G32_UINT, 8, pixels},
                 {binPixels, VK_FORMAT_R32_UINT, 4, binPixels.handle ? pixels : 0},
                 {levels.buffer(), VK_FORMAT_R32G32_UINT, 8, streamed(levels, 8)},
                 {cutBlocks.buffer(), VK_FORMAT_R32G32B32A32_UINT, 16, streamed(cutBlocks, 16)},
                 {blockClusters.buffer(), VK_FORMAT_R32_UINT, 4, streamed(blockClusters, 4)},
                 {hzbLevels, VK_FORMAT_R32_UINT, 4, whole(hzbLevels, 4)},
                 {textureSlots, VK_FORMAT_R32G32B32A32_UINT, 16, whole(textureSlots, 16)},
                 {texturePool, VK_FORMAT_R32_UINT, 4, whole(texturePool, 4)},
                 {uvs.buffer(), VK_FORMAT_R32G32_UINT, 8, streamed(uvs, 8)},
                 {colors.buffer(), VK_FORMAT_R32G32_UINT, 8, streamed(colors, 8)},
                 {patches, VK_FORMAT_R32G32B32A32_UINT, 16, whole(patches, 16)},
                 {patchPoints, VK_FORMAT_R32_UINT, 4, whole(patchPoints, 4)},
                 {materials, VK_FORMAT_R32G32B32A32_UINT, 16, whole(materials, 16)},
                 {materialTables, VK_FORMAT_R32_UINT, 4, whole(materialTables, 4)},
                 {visibleRecords, VK_FORMAT_R32G32B32A32_UINT, 16, uint64_t(4) * TS_VIS_MAX_VISIBLE_CLUSTERS}}};  // as the visible list
    }

    // Whether a frame of `pixels` can read every stream through a view on this device.
    bool streams_fit_views(uint64_t pixels) const {
        for (const ViewedStream& stream : viewed_streams(pixels))
            if (stream.texels > device.max_texel_buffer_elements()) return false;
        return true;
    }

    // The views over the buffers as they are now, written into the frame set. A view spans at most what the device allows
    // (a frame whose streams are longer reads them through their addresses: streams_fit_views).
    void write_texel_views(uint64_t pixels) {
        if (!viewStandIn.handle) viewStandIn = device.create_buffer(16, MemoryUse::Device);
        const auto streams = viewed_streams(pixels);
        VkBufferView views[TS_VIEW_COUNT];
        VkWriteDescriptorSet writes[TS_VIEW_COUNT];
        for (uint32_t i = 0; i < TS_VIEW_COUNT; ++i) {
            const ViewedStream& stream = streams[i];
            const Buffer& buffer = stream.buffer.handle ? stream.buffer : viewStandIn;
            VkBufferViewCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO};
            info.buffer = buffer.handle;
            info.format = stream.format;
            info.range = std::max<uint64_t>(1, std::min<uint64_t>(buffer.size / stream.texelBytes, device.max_texel_buffer_elements())) * stream.texelBytes;
            check_vk(vkCreateBufferView(device.handle(), &info, nullptr, &views[i]), "vkCreateBufferView");
            writes[i] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
            writes[i].dstSet = frameSet;
            writes[i].dstBinding = TS_VIEW_INSTANCES + i;
            writes[i].descriptorCount = 1;
            writes[i].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
            writes[i].pTexelBufferView = &views[i];
        }
        vkUpdateDescriptorSets(device.handle(), TS_VIEW_COUNT, writes, 0, nullptr);
        for (uint32_t i = 0; i < TS_VIEW_COUNT; ++i) {
            vkDestroyBufferView(device.handle(), texelViews[i], nullptr);
            texelViews[i] = views[i];
        }
    }

    // The AOV slices' storage buffer bindings (TS_BINDING_OUTPUT + slice), after the output is made for the frame: slice
    // k of `slices` is `direct[k]` (an AOV's imported image) where given, else its range of the output; the bindings past
    // the frame's slices repeat slice 0. Then the visibility buffer's (TS_BINDING_VISIBILITY). Each at most what the device
    // allows (a frame whose slice is larger goes through the addresses: output_fits_binding).
    void write_output_bindings(uint64_t pixels, size_t slices, const std::vector<VkBuffer>& direct) {
        write_buffer_binding(TS_BINDING_VISIBILITY, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, visibility.handle, 0,
                             std::min<VkDeviceSize>(pixels * 8, device.max_storage_buffer_range()));
        const VkDeviceSize range = std::min<VkDeviceSize>(pixels * 16, device.max_storage_buffer_range());
        for (uint32_t k = 0; k < TS_MOST_AOVS; ++k) {
            const size_t slice = k < slices ? k : 0;
            if (slice < direct.size()) write_buffer_binding(TS_BINDING_OUTPUT + k, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, direct[slice], 0, range);
            else write_buffer_binding(TS_BINDING_OUTPUT + k, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, aovOutput.handle, slice * output_slice_stride(pixels), range);
        }
    }

    // From one AOV slice of the output buffer to the next: a slice rounded up to the device's storage buffer offset
    // alignment, so that each can be bound alone.
    uint64_t output_slice_stride(uint64_t pixels) const {
        const uint64_t align = std::max<uint64_t>(device.min_storage_buffer_offset_alignment(), 16);
        return (pixels * 16 + align - 1) / align * align;
    }

    // One buffer binding of the frame set: `range` bytes of `buffer` from `offset`.
    void write_buffer_binding(uint32_t binding, VkDescriptorType type, VkBuffer buffer, VkDeviceSize offset, VkDeviceSize range) {
        VkDescriptorBufferInfo info{buffer, offset, range};
        VkWriteDescriptorSet write{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
        write.dstSet = frameSet;
        write.dstBinding = binding;
        write.descriptorCount = 1;
        write.descriptorType = type;
        write.pBufferInfo = &info;
        vkUpdateDescriptorSets(device.handle(), 1, &write, 0, nullptr);
    }

    // Whether a frame of `pixels` can store its AOVs through the output's binding on this device (TS_BINDING_OUTPUT).
    bool output_fits_binding(uint64_t pixels) const { return pixels * 16 <= device.max_storage_buffer_range(); }

    // Whether a frame's AOVs go straight into their images' memory (Renderer::render): the device imports host memory
    // and each image is a large block (whole huge pages at a huge-page boundary: an alignment the driver refuses is a
    // refused import); not with $TESSERA_IMPORT_AOVS=0 (for tests and measurements).
    bool imports_aovs(uint64_t pixels) const { return importAovs && device.host_import_alignment() != 0 && pixel_block_bytes(pixels * 16) != 0; }

    // The other sets, made on first use (pipelines.h): texel views with the output stored through its address, and
    // addresses only.
    Pipelines& wide_output_pipelines() {
        if (!wideOutputPipelines) wideOutputPipelines = Pipelines::for_device(device, true, false);
        return *wideOutputPipelines;
    }
    Pipelines& address_pipelines() {
        if (!addressPipelines) addressPipelines = Pipelines::for_device(device, false, false);
        return *addressPipelines;
    }

    // Kinds of material bins (TS_BIN_*): micro-triangles have bins of their own only in scenes with displacement.
    uint32_t bin_kinds() const { return anyDisplaced ? TS_BIN_KINDS : 1u; }

    // What the renderer derives from a built mesh, once per mesh (built meshes never change): its clusters' GPU
    // records (with their cones and mean triangle areas), levels and cut blocks, their offsets counted from the mesh's
    // own first cluster, vertex, triangle and block; upload_geometry adds the scene's. Kept while the mesh is in the
    // scene, so that a geometry upload (a mesh added, removed or edited) derives only the new meshes'. Deriving a
    // 10 M-triangle mesh's 155 k clusters took 1.4 s on one core, most of it their normal cones (meshoptimizer's
    // cluster bounds then).
    struct MeshRecords {
        std::vector<gpu::GpuCluster> clusters;
        std::vector<gpu::GpuLevel> levels;
        std::vector<gpu::GpuCutBlock> blocks;
        std::vector<uint32_t> blockClusters;
        float lodRadius = 0;
    };
    // By scene mesh serial (GpuScene::mesh_serial: a released and reloaded mesh is the same mesh).
    std::unordered_map<uint64_t, std::shared_ptr<const MeshRecords>> meshRecords;

    static std::shared_ptr<const MeshRecords> derive_records(const BuiltMesh& mesh) {
        auto records = std::make_shared<MeshRecords>();
        const size_t count = mesh.clusters.size();
        for (size_t i = 1; i < count; ++i)
            if (mesh.clusters[i].level < mesh.clusters[i - 1].level) throw std::logic_error("built mesh clusters are not ordered by level");
        // Clusters on every core: each is its own.
        records->clusters.resize(count);
        parallel_blocks(count, 256, [&](size_t begin, size_t end) {
            for (size_t i = begin; i < end; ++i) {
                const Cluster& c = mesh.clusters[i];
                const bool root = c.parentGroup == kNoGroup || !(c.parentError < TS_ROOT_ERROR);
                records->clusters[i] = {{c.sphere[0], c.sphere[1], c.sphere[2], c.sphere[3]},
                                        {c.lodSphere[0], c.lodSphere[1], c.lodSphere[2], c.lodSphere[3]},
                                        {c.parentSphere[0], c.parentSphere[1], c.parentSphere[2], c.parentSphere[3]},
                                        c.lodError, root ? float(TS_ROOT_ERROR) : c.parentError,
                                        c.vertexOffset, c.triangleOffset, c.triangleCount, 0,
                                        c.level << 16 | c.vertexCount, c.parentGroup, c.meanTriangleArea, pack_cone(c.cone), c.longestEdge, 0};
            }
        });
        // Levels (clusters come level by level, level 0 first), how far the LOD spheres reach from the mesh's centre,
        // and each level's cut blocks.
        const std::array<float, 3> center = {mesh.sphere[0], mesh.sphere[1], mesh.sphere[2]};
        auto reach = [&](const std::array<float, 4>& sphere) {
            const double dx = sphere[0] - center[0], dy = sphere[1] - center[1], dz = sphere[2] - center[2];
            return std::sqrt(dx * dx + dy * dy + dz * dz) + sphere[3];
        };
        double lodRadius = mesh.sphere[3];
        for (uint32_t i = 0; i < count; ++i) {
            const Cluster& c = mesh.clusters[i];
            const gpu::GpuCluster& g = records->clusters[i];
            if (i == 0 || c.level != mesh.clusters[i - 1].level) records->levels.push_back({i, 0, c.lodError, 0.0f, 0, 0});
            gpu::GpuLevel& level = records->levels.back();
            ++level.clusterCount;
            level.minLodError = std::min(level.minLodError, c.lodError);
            level.maxParentError = std::max(level.maxParentError, g.parentError);
            lodRadius = std::max({lodRadius, reach(c.lodSphere), g.parentError < TS_ROOT_ERROR ? reach(c.parentSphere) : 0.0});
        }
        records->lodRadius = float(lodRadius * (1 + 1e-6));
        for (gpu::GpuLevel& level : records->levels) {
            level.blockOffset = uint32_t(records->blocks.size());
            append_cut_blocks(records->clusters.data() + level.clusterOffset, level.clusterCount, level.clusterOffset, records->blocks,
                              records->blockClusters);
            level.blockCount = uint32_t(records->blocks.size()) - level.blockOffset;
        }
        return records;
    }

    // The mesh streams, in the order of mesh_streams() and stream_counts().
    // The last two hold something only for a mesh drawn displaced (and count as tessellation memory, not geometry).
    enum Stream : size_t { kClusters, kLevels, kBlocks, kBlockClusters, kVertices, kTriangles, kColors, kUvs, kDisplacementNormals, kSeams, kStreams };
    // Where a scene mesh handle's streams lie in the arenas, and the mesh they hold: kept while the handle holds that
    // mesh, so that a geometry change writes only the meshes it added.
    struct ResidentMesh {
        uint64_t serial = 0;  // the scene mesh's (GpuScene::mesh_serial); 0: the handle holds nothing
        bool displaced = false;  // written with its displacement streams (a mesh that turns displaced, or plain, goes up again)
        std::array<StreamArena::Range, kStreams> ranges{};
        uint32_t at(Stream stream) const { return uint32_t(ranges[stream].offset); }  // the shaders index with 32 bits
    };
    std::vector<ResidentMesh> resident;  // by scene mesh handle
    uint64_t geometryUploadBytes = 0;    // the mesh streams the last geometry upload wrote
    uint32_t displacedMeshesPrepared = 0;  // the meshes whose displacement data it made
    std::vector<std::string> uploadErrors;  // the meshes it could not draw, for this frame's stats

    std::array<StreamArena*, kStreams> mesh_streams() {
        return {&clusters, &levels, &cutBlocks, &blockClusters, &vertices, &triangles, &colors, &uvs, &displacementNormals, &seams};
    }
    std::array<const StreamArena*, kStreams> mesh_streams() const {
        return {&clusters, &levels, &cutBlocks, &blockClusters, &vertices, &triangles, &colors, &uvs, &displacementNormals, &seams};
    }
    // `displacement`: the mesh's displacement data where it is drawn displaced, else null.
    static std::array<size_t, kStreams> stream_counts(const BuiltMesh& mesh, const MeshRecords& r, const DisplacementData* displacement) {
        return {r.clusters.size(), r.levels.size(), r.blocks.size(), r.blockClusters.size(), mesh.normals.size(), mesh.triangles.size(), mesh.colors.size(),
                mesh.uvs.size(), displacement ? displacement->normals.size() : 0, displacement ? displacement->seamWords.size() : 0};
    }
    bool drawn_displaced(size_t m) const { return m < displacedMeshes.size() && displacedMeshes[m]; }

    // `sameScene`: the scene these streams were uploaded for (else every range is let go first).
    void upload_geometry(GpuScene& scene, bool sameScene, UploadBatch& uploads) {
        if (!sameScene) {
            for (StreamArena* arena : mesh_streams()) arena->clear();
            resident.clear();
        }
        // Handles whose mesh changed give their ranges back; the meshes now at them are fresh.
        const auto arenas = mesh_streams();
        auto release = [&](ResidentMesh& r) {
            if (!r.serial) return;
            for (size_t k = 0; k < kStreams; ++k) arenas[k]->release(r.ranges[k]);
            r = {};
        };
        for (size_t m = scene.meshes_.size(); m < resident.size(); ++m) release(resident[m]);
        resident.resize(scene.meshes_.size());
        std::vector<size_t> fresh;  // handles
        for (size_t m = 0; m < scene.meshes_.size(); ++m) {
            if (resident[m].serial == scene.serials_[m] && resident[m].displaced == drawn_displaced(m)) continue;
            release(resident[m]);
            if (scene.meshes_[m]) fresh.push_back(m);
        }
        // The meshes written now, with their streams (held by the scene, or reloaded: full_mesh), by handle. A mesh
        // whose streams cannot be reloaded (its page file gone) is left out of this frame, named in its errors, and
        // tried again at the next upload.
        std::vector<std::shared_ptr<const BuiltMesh>> full(scene.meshes_.size());
        std::vector<char> lost(scene.meshes_.size(), 0);
        auto load = [&](size_t m) {
            if (full[m] || lost[m]) return !lost[m];
            try {
                full[m] = scene.full_mesh(uint32_t(m));
            } catch (const std::exception& e) {
                uploadErrors.push_back(e.what());
                lost[m] = 1;
            }
            return !lost[m];
        };
        auto full_of = [&](size_t m) -> const BuiltMesh& { return *full[m]; };  // after load(m)
        // Each mesh's records: kept, or derived now (the new meshes on every core, each also on every core: a stage of
        // many small meshes as much as one large); the meshes no longer in the scene are let go.
        decltype(meshRecords) kept;
        std::vector<size_t> derive;  // handles
        for (size_t m = 0; m < scene.meshes_.size(); ++m) {
            if (!scene.meshes_[m] || kept.count(scene.serials_[m])) continue;
            auto old = meshRecords.find(scene.serials_[m]);
            if (old != meshRecords.end()) kept.emplace(scene.serials_[m], old->second);
            else if (load(m)) kept.emplace(scene.serials_[m], nullptr), derive.push_back(m);  // loaded on this thread, not the workers'
        }
        std::erase_if(fresh, [&](size_t m) { return !load(m); });
        std::vector<std::shared_ptr<const MeshRecords>> derived(derive.size());
        parallel_for_rethrowing(derive.size(), [&](size_t i) { derived[i] = derive_records(*full[derive[i]]); });
        for (size_t i = 0; i < derive.size(); ++i) kept[scene.serials_[derive[i]]] = std::move(derived[i]);
        meshRecords = std::move(kept);
        auto records_of = [&](size_t m) -> const MeshRecords& { return *meshRecords.at(scene.serials_[m]); };

        // The displaced meshes' displacement normals, seams and UV boxes: kept, or made now (the new ones on every core).
        decltype(displacementData) keptData;
        std::vector<size_t> make;  // handles
        displacementOf.assign(scene.meshes_.size(), nullptr);
        for (size_t m = 0; m < scene.meshes_.size(); ++m) {
            if (!scene.meshes_[m] || !drawn_displaced(m) || !load(m)) continue;
            const auto old = displacementData.find(scene.serials_[m]);
            if (old != displacementData.end()) keptData.emplace(scene.serials_[m], old->second);
            else if (keptData.emplace(scene.serials_[m], nullptr).second) make.push_back(m);
        }
        std::vector<std::shared_ptr<const DisplacementData>> made(make.size());
        parallel_for_rethrowing(make.size(), [&](size_t i) { made[i] = std::make_shared<const DisplacementData>(displacement_data(*full[make[i]])); });
        for (size_t i = 0; i < make.size(); ++i) keptData[scene.serials_[make[i]]] = std::move(made[i]);
        displacedMeshesPrepared = uint32_t(make.size());
        displacementData = std::move(keptData);
        for (size_t m = 0; m < scene.meshes_.size(); ++m)
            if (scene.meshes_[m] && drawn_displaced(m) && !lost[m]) displacementOf[m] = displacementData.at(scene.serials_[m]);

        // Removals leave holes that later meshes may not fill: where a stream's holes outgrow what it will hold (the
        // meshes kept and the fresh ones) and 1 MiB, every mesh goes up again, packed, into buffers of their size.
        std::array<size_t, kStreams> freshCounts{};
        for (size_t m : fresh) {
            const auto counts = stream_counts(full_of(m), records_of(m), displacementOf[m].get());
            for (size_t k = 0; k < counts.size(); ++k) freshCounts[k] += counts[k];
        }
        bool compact = false;
        for (size_t k = 0; k < kStreams; ++k) {
            const size_t holes = arenas[k]->free_elements(), held = arenas[k]->end() - holes + freshCounts[k];
            compact |= holes * arenas[k]->element_bytes() > std::max<size_t>(size_t(1) << 20, held * arenas[k]->element_bytes());
        }
        if (compact) {
            for (StreamArena* arena : mesh_streams()) arena->clear();
            resident.assign(scene.meshes_.size(), {});
            fresh.clear();
            for (size_t m = 0; m < scene.meshes_.size(); ++m)
                if (scene.meshes_[m] && load(m)) fresh.push_back(m);
        }

        // The fresh meshes' ranges (colours and texture coordinates two words per vertex: an even offset, which the
        // shaders halve), then the arenas grown to hold them; the shaders index each stream with 32 bits.
        for (size_t m : fresh) {
            ResidentMesh& r = resident[m];
            const auto counts = stream_counts(full_of(m), records_of(m), displacementOf[m].get());
            for (size_t k = 0; k < kStreams; ++k) {
                r.ranges[k] = {arenas[k]->allocate(counts[k], k == kColors || k == kUvs ? 2 : 1), counts[k]};
                // A seam word holds a word number below its count (TS_SEAM_COUNT_SHIFT bits).
                const size_t limit = k == kSeams ? (size_t(1) << TS_SEAM_COUNT_SHIFT) - 1 : UINT32_MAX;
                if (r.ranges[k].offset + counts[k] > limit) {  // nothing kept: the next upload starts again from the host
                    for (StreamArena* arena : mesh_streams()) arena->clear();
                    resident.clear();
                    throw std::runtime_error(k == kSeams ? "the UV seams of the meshes drawn displaced exceed 2^28 words"
                                                         : "the scene's distinct meshes hold more than 2^32 vertices, triangles or clusters");
                }
            }
            r.serial = scene.serials_[m];
            r.displaced = drawn_displaced(m);
        }
        for (StreamArena* arena : mesh_streams()) arena->fit(device, uploads);

        // The fresh meshes' streams, written into their ranges (their scene offsets added to the records).
        geometryUploadBytes = 0;
        // `write(to, handle, mesh, records, resident, first, end)` fills elements [first, end) of the mesh's range of `stream`.
        auto write_stream = [&](Stream stream, auto write) {
            std::vector<StreamArena::Range> ranges;
            for (size_t m : fresh) ranges.push_back(resident[m].ranges[stream]);
            geometryUploadBytes += arenas[stream]->write(uploads, ranges, [&](size_t range, size_t first, size_t end, void* to) {
                const size_t m = fresh[range];
                write(to, m, *full[m], records_of(m), resident[m], first, end);  // full[m]: loaded above, on this thread
            });
        };
        write_stream(kClusters, [](void* to, size_t m, const BuiltMesh&, const MeshRecords& r, const ResidentMesh& placed, size_t first, size_t end) {
            for (size_t i = first; i < end; ++i) {
                gpu::GpuCluster& out = static_cast<gpu::GpuCluster*>(to)[i - first] = r.clusters[i];
                out.vertexOffset += placed.at(kVertices);
                out.triangleOffset += placed.at(kTriangles);
                out.meshIndex = uint32_t(m);
            }
        });
        write_stream(kLevels, [](void* to, size_t, const BuiltMesh&, const MeshRecords& r, const ResidentMesh& placed, size_t first, size_t end) {
            for (size_t l = first; l < end; ++l) {
                gpu::GpuLevel& out = static_cast<gpu::GpuLevel*>(to)[l - first] = r.levels[l];
                out.blockOffset += placed.at(kBlocks);
            }
        });
        write_stream(kBlocks, [](void* to, size_t, const BuiltMesh&, const MeshRecords& r, const ResidentMesh& placed, size_t first, size_t end) {
            for (size_t k = first; k < end; ++k) {
                gpu::GpuCutBlock& out = static_cast<gpu::GpuCutBlock*>(to)[k - first] = r.blocks[k];
                out.firstCluster += placed.at(kBlockClusters);
            }
        });
        write_stream(kBlockClusters, [](void* to, size_t, const BuiltMesh&, const MeshRecords& r, const ResidentMesh&, size_t first, size_t end) {
            std::copy(r.blockClusters.begin() + first, r.blockClusters.begin() + end, static_cast<uint32_t*>(to));
        });
        write_stream(kVertices, [](void* to, size_t, const BuiltMesh& mesh, const MeshRecords&, const ResidentMesh&, size_t first, size_t end) {
                         for (size_t v = first; v < end; ++v) {
                             gpu::GpuVertex& out = static_cast<gpu::GpuVertex*>(to)[v - first];
                             std::memcpy(&out.bits, &mesh.positions[3 * v], 12);
                             out.bits.w = mesh.normals[v];
                         }
                     });
        auto write_words = [&](Stream stream, auto words) {
            write_stream(stream, [words](void* to, size_t, const BuiltMesh& mesh, const MeshRecords&, const ResidentMesh&, size_t first, size_t end) {
                static_assert(sizeof((mesh.*words)[0]) == sizeof(uint32_t));
                std::memcpy(to, (mesh.*words).data() + first, (end - first) * sizeof(uint32_t));
            });
        };
        write_words(kTriangles, &BuiltMesh::triangles);
        write_words(kColors, &BuiltMesh::colors);
        write_words(kUvs, &BuiltMesh::uvs);
        write_stream(kDisplacementNormals, [&](void* to, size_t m, const BuiltMesh&, const MeshRecords&, const ResidentMesh&, size_t first, size_t end) {
            std::copy(displacementOf[m]->normals.begin() + first, displacementOf[m]->normals.begin() + end, static_cast<uint32_t*>(to));
        });
        write_stream(kSeams, [&](void* to, size_t m, const BuiltMesh&, const MeshRecords&, const ResidentMesh& placed, size_t first, size_t end) {
            place_seam_words(*displacementOf[m], placed.at(kSeams), first, end, static_cast<uint32_t*>(to));
        });

        // The mesh records (small: all of them again).
        std::vector<gpu::GpuMesh> gpuMeshes(std::max<size_t>(scene.meshes_.size(), 1));
        for (size_t m = 0; m < scene.meshes_.size(); ++m) {
            const BuiltMesh* mesh = scene.meshes_[m].get();
            gpu::GpuMesh& g = gpuMeshes[m];
            g = {};
            g.colorOffset = g.uvOffset = g.displacementNormalOffset = g.seamVertexOffset = g.seamTriangleOffset = TS_NO_STREAM;
            const ResidentMesh& r = resident[m];
            if (!mesh || !r.serial) continue;  // removed, or lost: nothing of it is drawn
            const MeshRecords& records = records_of(m);
            g.sphere = {mesh->sphere[0], mesh->sphere[1], mesh->sphere[2], mesh->sphere[3]};
            g.clusterOffset = r.at(kClusters);
            g.vertexOffset = r.at(kVertices);
            if (r.displaced && !displacementOf[m]) continue;  // its streams lost since (not drawn)
            if (r.displaced) {  // drawn displaced: its displacement normals and seams (kept by the scene while so, below)
                const DisplacementData& data = *displacementOf[m];
                g.displacementNormalOffset = r.at(kDisplacementNormals);
                if (data.seams[0] != TS_NO_STREAM) {
                    g.seamVertexOffset = data.seams[0] + r.at(kSeams);
                    g.seamTriangleOffset = data.seams[1] + r.at(kSeams) - r.at(kTriangles);  // indexed by scene triangle: the base folded in (mod 2^32)
                }
            }
            // The counts come from the ranges: a released mesh's description has no streams.
            if (r.ranges[kColors].count > 0) g.colorOffset = r.at(kColors) / 2;
            if (r.ranges[kUvs].count > 0) g.uvOffset = r.at(kUvs) / 2;
            // The whole DAG goes up; the cull pass picks the cut. Clusters come level by level, level 0 first.
            g.clusterCount = uint32_t(r.ranges[kClusters].count);
            g.leafClusterCount = mesh->leafClusters;
            g.levelOffset = r.at(kLevels);
            g.levelCount = uint32_t(records.levels.size());
            g.lodRadius = records.lodRadius;
        }
        upload_vector(device, uploads, meshes, gpuMeshes);
        // The GPU holds the streams now: the scene lets them go where it can reload them (not a mesh drawn displaced,
        // whose streams the displacement bounds read at every instance upload).
        for (size_t m = 0; m < scene.meshes_.size(); ++m)
            if (scene.meshes_[m] && !drawn_displaced(m)) scene.release_streams(uint32_t(m));
    }

    // The displacement data of the meshes drawn displaced, by mesh serial (made once a mesh is drawn displaced, let go
    // when it no longer is), and by scene mesh handle (null for the others): what each cluster reads its displacement at.
    std::unordered_map<uint64_t, std::shared_ptr<const DisplacementData>> displacementData;
    std::vector<std::shared_ptr<const DisplacementData>> displacementOf;
    // Per-cluster displacement bounds of the displaced batches (frame.clusterDisplacement), one run per mesh and
    // material (or table) that some batch draws, and what they are computed from.
    Buffer clusterDisplacement;
    ClusterDisplacementBounds displacementBounds;

    // The runs of frame.clusterDisplacement for the displaced batches, and each batch's first entry.
    void upload_displacement_bounds(GpuScene& scene, UploadBatch& uploads) {
        std::vector<float> bounds;
        std::map<std::pair<uint32_t, uint32_t>, uint32_t> runs;  // (mesh, material or table | 1 << 31) -> first entry
        decltype(boundsOf) kept;
        for (gpu::GpuInstanceBatch& g : gpuBatches) {
            g.displacementBounds = TS_NO_STREAM;
            if ((g.flags & TS_INSTANCE_DISPLACED) == 0 || g.meshIndex >= displacementOf.size() || !displacementOf[g.meshIndex]) continue;
            const bool table = (g.flags & TS_INSTANCE_MATERIAL_SLOTS) != 0;
            const auto [run, fresh] = runs.try_emplace({g.meshIndex, g.materialIndex | (table ? 1u << 31 : 0u)}, uint32_t(bounds.size()));
            g.displacementBounds = run->second;
            if (!fresh) continue;
            // The run's materials, by slot, clamped as upload_materials clamps table entries (none: UINT32_MAX).
            const BuiltMesh& description = *scene.meshes_[g.meshIndex];
            auto clamped = [&](uint32_t index) { return scene.materials_.empty() ? UINT32_MAX : std::min<uint32_t>(index, uint32_t(scene.materials_.size() - 1)); };
            std::pair<uint64_t, std::vector<uint32_t>> key{scene.serials_[g.meshIndex], {}};
            if (!table) key.second.push_back(clamped(g.materialIndex));
            else
                for (uint32_t k = 0; k < description.materialSlots; ++k) key.second.push_back(clamped(scene.materialTables_[g.materialIndex + k]));
            auto& runBounds = kept[key];
            if (const auto old = boundsOf.find(key); old != boundsOf.end()) runBounds = old->second;
            if (!runBounds) {
                std::vector<const MaterialDesc*> materials;
                for (uint32_t index : key.second) materials.push_back(index == UINT32_MAX ? nullptr : &scene.materials_[index]);
                const BuiltMesh& mesh = *scene.full_mesh(g.meshIndex);  // held: a mesh drawn displaced keeps its streams
                runBounds = std::make_shared<const std::vector<float>>(displacementBounds.compute(mesh, displacementOf[g.meshIndex]->uvBoxes, materials));
            }
            bounds.insert(bounds.end(), runBounds->begin(), runBounds->end());
        }
        boundsOf = std::move(kept);
        if (bounds.empty()) clusterDisplacement = Buffer{};
        else upload_vector(device, uploads, clusterDisplacement, bounds);
    }
    // Each run's per-cluster bounds by (mesh serial, its materials by slot): made once, while the materials stay
    // (an instance edit beside a displaced mesh computes none again; a material edit drops them all).
    std::map<std::pair<uint64_t, std::vector<uint32_t>>, std::shared_ptr<const std::vector<float>>> boundsOf;

    bool material_displaced(uint32_t material) const { return material < displacedMaterials.size() && displacedMaterials[material]; }

    // The largest displacement of a material table's materials (0: none displaces), by its first entry.
    std::unordered_map<uint32_t, float> tableDisplacement;

    bool instance_displaced(const GpuScene& scene, const InstanceDesc& desc) const {
        if (!desc.materialTable) return material_displaced(desc.material);
        const auto it = tableDisplacement.find(desc.material);
        return it != tableDisplacement.end() && it->second > 0;
    }

    // Which meshes displaced instances draw (their material, or a material of their table, displaces). True when
    // that changed: the geometry must go up again with (or without) their displacement normals.
    bool update_displaced_meshes(const GpuScene& scene) {
        std::vector<bool> displaced(scene.meshes_.size(), false);
        for (const InstanceDesc& desc : scene.instances_)
            if (desc.mesh < displaced.size() && !displaced[desc.mesh]) displaced[desc.mesh] = instance_displaced(scene, desc);
        anyDisplaced = std::find(displaced.begin(), displaced.end(), true) != displaced.end();
        if (displaced == displacedMeshes) return false;
        displacedMeshes = std::move(displaced);
        return true;
    }

    // `moved`: the instances may have moved (else only their material flags changed, and the last frame's depths hold).
    void upload_instances(GpuScene& scene, bool moved, UploadBatch& uploads) {
        gpuBatches.clear();
        origins.clear();
        clusterCount = 0;
        sourceTriangles = 0;
        anyMasked = false;
        instanceFlags = 0;
        std::vector<const InstanceDesc*> drawn;  // batch -> its desc
        std::vector<uint64_t> firstInstance;     // batch -> its first instance; one more entry at the end
        uint64_t count = 0;
        for (const InstanceDesc& desc : scene.instances_) {
            const BuiltMesh* mesh = desc.mesh < scene.meshes_.size() ? scene.meshes_[desc.mesh].get() : nullptr;
            const uint64_t copies = desc.count();
            if (!mesh || copies == 0) continue;
            gpu::GpuInstanceBatch g{};
            g.meshIndex = desc.mesh;
            g.primId = desc.primId;
            const bool table = desc.materialTable && mesh->materialSlots > 1 &&
                               uint64_t(desc.material) + mesh->materialSlots <= scene.materialTables_.size();
            g.materialIndex = table ? desc.material : std::min<uint32_t>(desc.material, uint32_t(std::max<size_t>(scene.materials_.size(), 1) - 1));
            if (desc.materialTable && !table) g.materialIndex = 0;  // a table too short for the mesh: the first material everywhere
            // Masked: its material, or any material of its table, cuts pixels by a textured opacity.
            bool masked = false;
            if (!table) masked = g.materialIndex < maskedMaterials.size() && maskedMaterials[g.materialIndex];
            else
                for (uint32_t k = 0; k < mesh->materialSlots; ++k) {
                    const uint32_t material = scene.materialTables_[g.materialIndex + k];
                    masked |= material < maskedMaterials.size() && maskedMaterials[material];
                }
            anyMasked |= masked;
            const auto tableBound = table ? tableDisplacement.find(g.materialIndex) : tableDisplacement.end();
            const bool displaced = table ? tableBound != tableDisplacement.end() && tableBound->second > 0 : material_displaced(g.materialIndex);
            g.flags = (desc.doubleSided ? TS_INSTANCE_DOUBLE_SIDED : 0u) | (table ? TS_INSTANCE_MATERIAL_SLOTS : 0u) | (masked ? TS_INSTANCE_MASKED : 0u) |
                      (displaced ? TS_INSTANCE_DISPLACED : 0u);
            instanceFlags |= g.flags & TS_SPECIALIZED_INSTANCE_FLAGS;
            // The origin: a single instance's translation with the mesh's origin folded in (its offset is then 0, as
            // when every instance carried its own double translation); an instancer's frame for an array.
            const Matrix4d& m = desc.transform;
            std::array<double, 3> origin;
            for (int r = 0; r < 3; ++r)
                origin[r] = desc.arrays ? m[r * 4 + 3]
                                        : m[r * 4 + 3] + m[r * 4 + 0] * mesh->origin[0] + m[r * 4 + 1] * mesh->origin[1] + m[r * 4 + 2] * mesh->origin[2];
            gpuBatches.push_back(g);
            origins.push_back(origin);
            drawn.push_back(&desc);
            firstInstance.push_back(count);
            count += copies;
            clusterCount += uint64_t(mesh->leafClusters) * copies;
            sourceTriangles += uint64_t(mesh->sourceTriangles) * copies;
        }
        firstInstance.push_back(count);
        upload_displacement_bounds(scene, uploads);
        if (count > 0xffffffffull) throw std::runtime_error("more than 2^32 - 1 instances: " + std::to_string(count));
        if (gpuBatches.size() > TS_INSTANCE_BATCH_MASK) throw std::runtime_error("more than 2^30 instance batches");
        instanceCount = uint32_t(count);
        write_instances(scene, drawn, firstInstance, uploads);
        relativeTo = {NAN, NAN, NAN};
        if (moved) previousValid = false;  // last frame's depths say nothing about instances that moved
        // Every cluster of every instance is an upper bound on the visible ones: start there (8 bytes each, within
        // reason) so that a frame rarely pays for an overflow redraw.
        if (!capacityPinned) capacity = uint32_t(std::clamp<uint64_t>(clusterCount, capacity, 1u << 22));
        // The cut list holds the instances that pass the instance tests: start with room for all of them, within
        // reason (4 bytes each), so that a frame rarely pays for an overflow redraw.
        cutCapacity = uint32_t(std::clamp<uint64_t>(instanceCount, cutCapacity, 1u << 16));
        deferredCapacity = uint32_t(std::clamp<uint64_t>(instanceCount, deferredCapacity, 1u << 16));
    }

    // Each instance's transform relative to its batch's origin, and its batch word, written straight into the GPU
    // buffers (into the frame's upload batch where those are not host-visible), on every core.
    void write_instances(const GpuScene& scene, const std::vector<const InstanceDesc*>& drawn, const std::vector<uint64_t>& firstInstance,
                         UploadBatch& uploads) {
        const uint64_t count = std::max<uint64_t>(instanceCount, 1);
        if (instances.size < count * sizeof(gpu::GpuInstance) || !instances.handle)
            instances = device.create_buffer(count * sizeof(gpu::GpuInstance), MemoryUse::Device);
        if (instanceBatches.size < count * 4 || !instanceBatches.handle) instanceBatches = device.create_buffer(count * 4, MemoryUse::Device);
        const UploadBatch::Piece pieces[2] = {{&instances, 0, uint64_t(instanceCount) * sizeof(gpu::GpuInstance)}, {&instanceBatches, 0, uint64_t(instanceCount) * 4}};
        const std::vector<void*> places = uploads.write(pieces);
        auto* records = static_cast<gpu::GpuInstance*>(places[0]);
        auto* words = static_cast<uint32_t*>(places[1]);

        auto write_range = [&](uint64_t begin, uint64_t end) {
            size_t b = std::upper_bound(firstInstance.begin(), firstInstance.end(), begin) - firstInstance.begin() - 1;
            for (uint64_t i = begin; i < end; ++i) {
                while (i >= firstInstance[b + 1]) ++b;
                const InstanceDesc& desc = *drawn[b];
                const BuiltMesh& mesh = *scene.meshes_[desc.mesh];
                const Matrix4d m = desc.arrays ? multiply(desc.transform, desc.arrays->transform(i - firstInstance[b])) : desc.transform;
                const Matrix3d linear = {m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]};
                gpu::GpuInstance& g = records[i];
                for (int r = 0; r < 3; ++r) {
                    const double t = m[r * 4 + 3] + m[r * 4 + 0] * mesh.origin[0] + m[r * 4 + 1] * mesh.origin[1] + m[r * 4 + 2] * mesh.origin[2];
                    g.rows[r] = {float(m[r * 4]), float(m[r * 4 + 1]), float(m[r * 4 + 2]), desc.arrays ? float(t - origins[b][r]) : 0.0f};
                }
                words[i] = uint32_t(b) | (determinant3(linear) < 0 ? TS_INSTANCE_BATCH_FLIP : 0u) | (conformal(linear) ? TS_INSTANCE_BATCH_CONFORMAL : 0u);
            }
        };
        parallel_blocks(instanceCount, size_t(1) << 16, write_range);
    }

    // Camera-relative rendering: batch origins minus the camera position, subtracted in double, so geometry far
    // from the origin renders like geometry at the origin. Re-uploaded only when the camera moves.
    void upload_relative_translations(const std::array<double, 3>& camera, UploadBatch& uploads) {
        if (camera == relativeTo) return;
        for (size_t i = 0; i < gpuBatches.size(); ++i) {
            float high[3], low[3];
            for (int r = 0; r < 3; ++r) split_double(origins[i][r] - camera[r], high[r], low[r]);
            gpuBatches[i].originHigh = {high[0], high[1], high[2], 0.0f};
            gpuBatches[i].originLow = {low[0], low[1], low[2], 0.0f};
        }
        upload_vector(device, uploads, batches, gpuBatches);
        relativeTo = camera;
    }

    // A material's inputs as the GPU reads them: the textured ones get slots (in TS_INPUT_* order), and the inputs of
    // slots whose file could not be read take the slot's fallback as their constant. `textureKinds`: what the textures
    // resolve reads need (TS_TEXTURE_KIND_* bits): all but opacity's (cut by the rasterizers), the displacement texture's
    // included (read again for the micro-triangles resolve dices again).
    gpu::GpuMaterial gpu_material(MaterialDesc m, std::vector<gpu::GpuTextureSlot>& slots, std::vector<std::shared_ptr<const TextureImage>>& images,
                                  uint32_t& textureKinds) {
        std::array<const TextureSlot*, TS_INPUT_COUNT> textured{};
        for (const TextureSlot& slot : m.textures) {
            // An input this material's workflow ignores costs nothing; nor does opacity without a threshold (no blending).
            if ((slot.input == MaterialInput::SpecularColor && !m.useSpecularWorkflow) || (slot.input == MaterialInput::Metallic && m.useSpecularWorkflow) ||
                (slot.input == MaterialInput::Opacity && !(m.opacityThreshold > 0)))
                continue;
            if (slot.image) {
                textured[size_t(slot.input)] = &slot;
                continue;
            }
            const auto& f = slot.fallback;
            const std::array<float, 3> rgb = slot.channel == TextureChannel::Rgb ? std::array<float, 3>{f[0], f[1], f[2]}
                                                                                   : std::array<float, 3>{f[size_t(slot.channel)], f[size_t(slot.channel)], f[size_t(slot.channel)]};
            switch (slot.input) {
                case MaterialInput::DiffuseColor: m.diffuseColor = rgb; break;
                case MaterialInput::EmissiveColor: m.emissiveColor = rgb; break;
                case MaterialInput::SpecularColor: m.specularColor = rgb; break;
                case MaterialInput::Metallic: m.metallic = rgb[0]; break;
                case MaterialInput::Roughness: m.roughness = rgb[0]; break;
                case MaterialInput::Opacity: m.opacity = rgb[0]; break;
                case MaterialInput::Occlusion: m.occlusion = rgb[0]; break;
                case MaterialInput::Normal: break;  // no normal map
                case MaterialInput::Displacement: m.displacement = rgb[0]; break;
            }
        }
        // An input that is textured or that this material's workflow ignores reads nothing from the vertex channel (a
        // texture slot and a primvar reader cannot both drive one input; a slot without an image keeps its fallback).
        for (const TextureSlot& slot : m.textures)
            if (size_t(slot.input) <= size_t(MaterialInput::Occlusion)) m.vertexInputs &= ~vertex_input(slot.input, 3, true);
        m.vertexInputs &= ~vertex_input(m.useSpecularWorkflow ? MaterialInput::Metallic : MaterialInput::SpecularColor, 3, true);
        if (!(m.opacityThreshold > 0)) m.vertexInputs &= ~vertex_input(MaterialInput::Opacity, 3, true);  // no blending
        const bool vertexOpacity = (m.vertexInputs & vertex_input(MaterialInput::Opacity, 3, true)) != 0;
        gpu::GpuMaterial g{};
        g.vertexInputs = m.vertexInputs;
        g.diffuseColor = {m.diffuseColor[0], m.diffuseColor[1], m.diffuseColor[2], m.opacity};
        g.emissiveColor = {m.emissiveColor[0], m.emissiveColor[1], m.emissiveColor[2], std::clamp(m.occlusion, 0.0f, 1.0f)};
        // UsdPreviewSurface: reflectance at normal incidence from the index of refraction, ((ior - 1) / (ior + 1))^2.
        const float fromIor = (m.ior - 1) / (m.ior + 1) * ((m.ior - 1) / (m.ior + 1));
        const std::array<float, 3> f0 = m.useSpecularWorkflow ? m.specularColor : std::array<float, 3>{fromIor, fromIor, fromIor};
        g.specular = {f0[0], f0[1], f0[2], std::clamp(m.roughness, 0.0f, 1.0f)};
        g.metallic = std::clamp(m.metallic, 0.0f, 1.0f);
        const bool texturedOpacity = textured[TS_INPUT_OPACITY] != nullptr;
        g.flags = (m.vertexInputs != 0 ? TS_MATERIAL_VERTEX_CHANNEL : 0u) | (m.useSpecularWorkflow ? 0u : TS_MATERIAL_METALLIC) |
                  (!texturedOpacity && !vertexOpacity && m.opacityThreshold > 0 && m.opacity < m.opacityThreshold ? TS_MATERIAL_CUT_OUT : 0u);
        // Masked per pixel (a textured or per-vertex opacity): the threshold takes opacity's place.
        if (texturedOpacity || vertexOpacity) g.diffuseColor.w = m.opacityThreshold;
        // Displacement: offset = (value - center) * magnitude; its bound from the value's range (the texture's level 0
        // through scale, bias and the output channel, or the constant). 0 for a baked one: it is in the mesh.
        const float bound = material_displacement_bound(m);
        const bool displaced = bound > 0;
        g.displacement = {m.displacement, m.displacementMagnitude, m.displacementCenter, displaced ? bound : 0.0f};
        g.displacementFade = {m.displacementFadeStart, m.displacementFadeEnd, 0, 0};
        if (displaced) g.flags |= TS_MATERIAL_DISPLACED;
        else textured[TS_INPUT_DISPLACEMENT] = nullptr;  // a displacement that moves nothing reads no texture
        g.firstTextureSlot = uint32_t(slots.size());
        textureKinds = 0;
        for (uint32_t input = 0; input < TS_INPUT_COUNT; ++input) {
            const TextureSlot* slot = textured[input];
            if (!slot) continue;
            auto image = std::find(images.begin(), images.end(), slot->image);
            if (image == images.end()) image = images.insert(images.end(), slot->image);
            const auto& t = slot->transform;
            gpu::GpuTextureSlot s{};
            s.scale = {slot->scale[0], slot->scale[1], slot->scale[2], slot->scale[3]};
            s.bias = {slot->bias[0], slot->bias[1], slot->bias[2], slot->bias[3]};
            s.transform = {t[0], t[1], t[3], t[4]};
            s.translationS = t[2];
            s.translationT = t[5];
            s.texture = uint32_t(image - images.begin());
            s.mode = uint32_t(slot->wrapS) | uint32_t(slot->wrapT) << 2 | uint32_t(slot->channel) << 4;
            slots.push_back(s);
            g.textureInputs |= 1u << input;
            if (input != TS_INPUT_OPACITY) {
                const uint32_t format = slot->image->format;
                textureKinds |= TS_TEXTURE_KIND_FORMAT(format & TS_TEXTURE_FORMAT_MASK) | (format & TS_TEXTURE_SRGB ? TS_TEXTURE_KIND_SRGB : 0u) |
                                TS_TEXTURE_KIND_WRAP(uint32_t(slot->wrapS)) | TS_TEXTURE_KIND_WRAP(uint32_t(slot->wrapT));
            }
        }
        return g;
    }

    // Returns whether they changed: the plugin hands every material over again after any sync, and where they read as
    // before (the same records, texture slots, images and tables) nothing is uploaded and what was computed from them
    // stays (an edit beside a displaced 1 M-triangle sphere otherwise made its displacement bounds again, 2.4 ms on
    // lavapipe, and wrote every instance again); else that goes (the images may have changed).
    bool upload_materials(GpuScene& scene, UploadBatch& uploads) {
        std::vector<gpu::GpuMaterial> gpuMaterials;
        std::vector<gpu::GpuTextureSlot> slots;
        std::vector<std::shared_ptr<const TextureImage>> images;
        maskedMaterials.clear();
        texturedMaterials.clear();
        materialTextureKinds.clear();
        displacedMaterials.clear();
        for (const MaterialDesc& m : scene.materials_) {
            uint32_t kinds = 0;
            gpuMaterials.push_back(gpu_material(m, slots, images, kinds));
            const gpu::GpuMaterial& g = gpuMaterials.back();
            maskedMaterials.push_back((g.textureInputs & (1u << TS_INPUT_OPACITY)) != 0 ||
                                      ((g.vertexInputs >> (TS_VERTEX_INPUT_BITS * TS_INPUT_OPACITY)) & TS_VERTEX_INPUT_SET) != 0);
            // Resolve samples every textured input but opacity (cut by the rasterizers) and displacement (diced).
            texturedMaterials.push_back((g.textureInputs & ~(1u << TS_INPUT_OPACITY | 1u << TS_INPUT_DISPLACEMENT)) != 0);
            materialTextureKinds.push_back(kinds && allTextureKinds ? TS_TEXTURE_KINDS_ALL : kinds);
            displacedMaterials.push_back((g.flags & TS_MATERIAL_DISPLACED) != 0);
        }
        if (gpuMaterials.empty()) {
            gpu::GpuMaterial fallback{};
            fallback.diffuseColor = {0.18f, 0.18f, 0.18f, 1};
            fallback.emissiveColor = {0, 0, 0, 1};
            fallback.specular = {0, 0, 0, 0.5f};
            fallback.flags = TS_MATERIAL_VERTEX_CHANNEL;
            fallback.vertexInputs = kDisplayColorInputs;
            gpuMaterials.push_back(fallback);
        }
        auto same_bytes = [](const auto& a, const auto& b) {
            return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(a[0])) == 0);
        };
        if (same_bytes(gpuMaterials, materialRecords) && same_bytes(slots, materialSlotRecords) && images == materialImages &&
            scene.materialTables_ == materialTableRecords && scene.materialTableRanges_ == materialTableRangeRecords)
            return false;
        displacementBounds.clear();
        boundsOf.clear();
        upload_vector(device, uploads, materials, gpuMaterials);
        materialCount = uint32_t(gpuMaterials.size());
        materialRecords = gpuMaterials;
        materialSlotRecords = slots;
        materialTableRecords = scene.materialTables_;
        materialTableRangeRecords = scene.materialTableRanges_;
        // Tables: entries clamped to the materials there are; each header holds the table's largest displacement.
        std::vector<uint32_t> tables = scene.materialTables_;
        tableDisplacement.clear();
        for (const auto& [first, size] : scene.materialTableRanges_) {
            float largest = 0;
            for (uint32_t k = first; k < first + size; ++k) {
                tables[k] = std::min(tables[k], materialCount - 1);
                largest = std::max(largest, gpuMaterials[tables[k]].displacement.w);
            }
            std::memcpy(&tables[first - 1], &largest, 4);
            tableDisplacement[first] = largest;
        }
        upload_vector(device, uploads, materialTables, tables);
        // Room for every kind of bin (TS_BIN_*), a few bytes a material, whether or not displacement comes later.
        if (shadingBins.size < uint64_t(materialCount) * TS_BIN_KINDS * sizeof(gpu::GpuBin))
            shadingBins = device.create_buffer(uint64_t(materialCount) * TS_BIN_KINDS * sizeof(gpu::GpuBin), MemoryUse::Device,
                                               VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT);
        // No textures, no texture memory.
        if (slots.empty()) textureSlots = Buffer{};
        else upload_vector(device, uploads, textureSlots, slots);
        materialImages = std::move(images);  // the pool follows at the next frame, with the dome lights' images
        return true;
    }

    // The texture pool: a GpuTexture record per image, then every image's words. Rebuilt when the set of images changes.
    void upload_texture_pool(std::vector<std::shared_ptr<const TextureImage>> images, UploadBatch& uploads) {
        poolImages = std::move(images);
        texturePool = Buffer{};
        if (poolImages.empty()) return;
        uint64_t words = poolImages.size() * 4;
        for (const auto& image : poolImages) words += image->words.size();
        if (words > 0xffffffffull) throw std::runtime_error("the texture pool would exceed 16 GiB");
        std::vector<uint32_t> pool;
        pool.reserve(words);
        uint32_t offset = uint32_t(poolImages.size() * 4);
        for (const auto& image : poolImages) {
            pool.insert(pool.end(), {image->width, image->height, offset, image->format | image->levels << 8});
            offset += uint32_t(image->words.size());
        }
        for (const auto& image : poolImages) pool.insert(pool.end(), image->words.begin(), image->words.end());
        upload_vector(device, uploads, texturePool, pool);
    }

    // The list of covered pixels by material, for frames that list them (TS_PIXELS_LISTED): a CPU device's one-bin frames
    // read every pixel instead and never make it (4 bytes a pixel). After ensure_frame_buffers (the frame's size).
    void ensure_bin_pixels() {
        if (!binPixels.handle) binPixels = device.create_buffer(uint64_t(width) * height * 4, MemoryUse::Device);
    }
    // `aovsImported`: this frame's AOVs go straight into their images' memory (Renderer::render), the readback buffer
    // then holds the draw state alone; `directSlices`: each AOV's slice is its imported image itself (a CPU device), with
    // no output buffer. Otherwise the output holds a slice per AOV (output_slice_stride apart), resolve writing them all
    // in one pass.
    void ensure_frame_buffers(uint32_t w, uint32_t h, size_t aovCount, bool aovsImported, bool directSlices) {
        if (!drawState.handle) drawState = device.create_buffer(sizeof(gpu::GpuDrawState), MemoryUse::Device, VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT);
        if (!visibleClusters.handle || visibleClusters.size < uint64_t(capacity) * 8) {
            visibleClusters = device.create_buffer(uint64_t(capacity) * 8, MemoryUse::Device);
            visibleRecords = device.create_buffer(uint64_t(capacity) * sizeof(gpu::GpuVisibleRecord), MemoryUse::Device);
            hardwareList = device.create_buffer(uint64_t(capacity) * 4, MemoryUse::Device);
            softwareList = device.create_buffer(uint64_t(capacity) * 4, MemoryUse::Device);
            deferredClusters = Buffer{};  // sized with the visible list, made on first use
        }
        if (cutList.size < uint64_t(cutCapacity) * 4) cutList = device.create_buffer(uint64_t(cutCapacity) * 4, MemoryUse::Device);
        const uint64_t pixels = uint64_t(w) * h;
        if (w != width || h != height || !visibility.handle) {
            visibility = device.create_buffer(pixels * 8, MemoryUse::Device);
            aovOutput = Buffer{};
            binPixels = Buffer{};  // made again when a frame lists its pixels (ensure_bin_pixels)
            hzbLevels = Buffer{};
            previousValid = false;
            width = w;
            height = h;
        }
        // On a CPU device the output is host memory that the AOVs are read from directly: no copy of them into the
        // readback buffer (33 MB each at 1080p; Renderer::render). A GPU writes device memory and copies. A frame of no
        // AOV keeps one slice: classify's places.
        const uint64_t outputBytes = directSlices && aovCount > 0 ? 0 : (std::max<uint64_t>(aovCount, 1) - 1) * output_slice_stride(pixels) + pixels * 16;
        if (outputBytes == 0) aovOutput = Buffer{};
        else if (!aovOutput.handle || aovOutput.size < outputBytes)
            aovOutput = device.create_buffer(outputBytes, device.is_software() ? MemoryUse::Readback : MemoryUse::Device);
        const uint64_t copiedAovs = aovsImported || aovOutput.mapped ? 0 : aovCount;  // else each read where resolve wrote it
        const uint64_t readbackBytes = sizeof(gpu::GpuDrawState) + copiedAovs * pixels * 16;
        if (readback.size < readbackBytes) readback = device.create_buffer(readbackBytes, MemoryUse::Readback);
    }

    // Runtime tessellation's lists, allocated only for scenes that displace: the clusters to dice (one slot per
    // visible cluster at most) and the patches with their draws.
    void ensure_tessellation_buffers() {
        if (tessellationList.size < uint64_t(capacity) * 4) tessellationList = device.create_buffer(uint64_t(capacity) * 4, MemoryUse::Device);
        // Sized to the capacities, which grow on demand and shrink when frames need far less (a view that moved away).
        if (patches.size != uint64_t(patchCapacity) * sizeof(gpu::GpuPatch)) {
            patches = device.create_buffer(uint64_t(patchCapacity) * sizeof(gpu::GpuPatch), MemoryUse::Device);
            patchDraws = device.create_buffer(uint64_t(patchCapacity) * sizeof(VkDrawIndirectCommand), MemoryUse::Device, VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT);
            dicePatches = device.create_buffer(uint64_t(patchCapacity) * 4, MemoryUse::Device);
            deferredPatchList = device.create_buffer(uint64_t(patchCapacity) * 4, MemoryUse::Device);
        }
        if (patchPoints.size != uint64_t(pointCapacity) * TS_PATCH_POINT_FLOATS * 4)
            patchPoints = device.create_buffer(uint64_t(pointCapacity) * TS_PATCH_POINT_FLOATS * 4, MemoryUse::Device);
    }

    // Occlusion culling's buffers, allocated only when a frame uses it.
    void ensure_occlusion_buffers() {
        if (!hzbLevels.handle) {
            uint64_t texels = 0;
            for (const auto& level : hzb_levels(width, height)) texels += uint64_t(level[0]) * level[1];
            hzbLevels = device.create_buffer(texels * 4, MemoryUse::Device);
        }
        if (!hzbDispatch.handle)  // two builds of at most 32 levels
            hzbDispatch = device.create_buffer(2 * 32 * sizeof(VkDispatchIndirectCommand), MemoryUse::Device, VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT);
        if (!deferredClusters.handle) deferredClusters = device.create_buffer(uint64_t(capacity) * 8, MemoryUse::Device);
        if (deferredInstances.size < uint64_t(deferredCapacity) * 4) deferredInstances = device.create_buffer(uint64_t(deferredCapacity) * 4, MemoryUse::Device);
    }

    // Builds every HZB level from the visibility buffer, one dispatch per level, if the GPU finds the build needed:
    // `when` (TS_HZB_AFTER_MAIN, TS_HZB_FINAL) names the build, whose dispatch arguments a first one-workgroup step writes
    // from the draw state (no workgroups for a build that would change nothing; hzb.comp.glsl).
    void build_hzb(VkCommandBuffer cmd, Pipelines& pipelines, uint32_t when) {
        vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipelines.hzb);
        PushConstants decide{0, when, hzbDispatch.address};
        vkCmdPushConstants(cmd, pipelines.layout, VK_SHADER_STAGE_ALL, 0, sizeof(decide), &decide);
        vkCmdDispatch(cmd, 1, 1, 1);
        barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT,
                VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
        const auto levels = hzb_levels(width, height);
        const uint64_t first = (when == TS_HZB_FINAL ? 32 : 0) * sizeof(VkDispatchIndirectCommand);
        for (uint32_t l = 0; l < levels.size(); ++l) {
            PushConstants push{0, l, hzbLevels.address};
            vkCmdPushConstants(cmd, pipelines.layout, VK_SHADER_STAGE_ALL, 0, sizeof(push), &push);
            vkCmdDispatchIndirect(cmd, hzbDispatch.handle, first + l * sizeof(VkDispatchIndirectCommand));
            barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                    VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
        }
    }
};

Renderer::Renderer(Device& device) : device_(device), impl_(std::make_unique<Impl>(device, Pipelines::for_device(device, true, true))) {
    impl_->create_frame_resources();
}
Renderer::~Renderer() = default;

void Renderer::set_visible_cluster_capacity(uint32_t capacity) {
    impl_->capacity = std::max(capacity, 1u);
    impl_->capacityPinned = true;
}

void Renderer::set_patch_capacity(uint32_t capacity) {
    impl_->patchCapacity = std::clamp<uint32_t>(capacity, 1u, TS_VIS_MAX_PATCHES);
}

void Renderer::set_point_capacity(uint32_t points) {
    impl_->pointCapacity = std::clamp<uint32_t>(points, 1u, 1u << 24);
}

namespace {

// The FrameStats fields that an image of several pixel samples adds up over its frames: times, redraws, imports and uploads.
template <class Visit>
void visit_frame_costs(FrameStats& a, const FrameStats& b, Visit visit) {
    visit(a.cullMs, b.cullMs), visit(a.softwareRasterMs, b.softwareRasterMs), visit(a.rasterMs, b.rasterMs);
    visit(a.tessellationMs, b.tessellationMs), visit(a.hzbMs, b.hzbMs), visit(a.classifyMs, b.classifyMs);
    visit(a.resolveMs, b.resolveMs), visit(a.readbackMs, b.readbackMs), visit(a.uploadMs, b.uploadMs);
    visit(a.cpuRecordMs, b.cpuRecordMs), visit(a.cpuWaitMs, b.cpuWaitMs), visit(a.cpuFrameMs, b.cpuFrameMs);
    visit(a.overflowRedraws, b.overflowRedraws), visit(a.aovImportsMade, b.aovImportsMade), visit(a.geometryUploadBytes, b.geometryUploadBytes),
        visit(a.uploadSubmissions, b.uploadSubmissions), visit(a.displacedMeshesPrepared, b.displacedMeshesPrepared);
}

// The Gaussian pixel filter along one axis: sigma 0.4 px, less its value at 1 px so that it falls to 0 there, over
// [-1, 1] px. Its inverse cumulative distribution: where a sample at quantile u in [0, 1] lies, from a table of 257
// quantiles made once by integrating the filter (u = 0.5 is the centre: the filter is symmetric).
float gaussian_quantile(float u) {
    static const std::array<float, 257> quantiles = [] {
        constexpr int kSteps = 1 << 14;
        const double sigma = 0.4, edge = std::exp(-1.0 / (2 * sigma * sigma));
        auto filter = [&](double x) { return std::max(std::exp(-x * x / (2 * sigma * sigma)) - edge, 0.0); };
        std::vector<double> cumulative(kSteps + 1, 0.0);
        for (int i = 0; i < kSteps; ++i) {
            const double x0 = -1 + 2.0 * i / kSteps, x1 = -1 + 2.0 * (i + 1) / kSteps;
            cumulative[i + 1] = cumulative[i] + (filter(x0) + filter(x1)) * (x1 - x0) / 2;
        }
        std::array<float, 257> table;
        int i = 0;
        for (int q = 0; q <= 256; ++q) {
            const double target = cumulative[kSteps] * q / 256;
            while (i < kSteps - 1 && cumulative[i + 1] < target) ++i;
            const double span = cumulative[i + 1] - cumulative[i], t = span > 0 ? std::clamp((target - cumulative[i]) / span, 0.0, 1.0) : 0.0;
            table[q] = float(-1 + 2.0 * (i + t) / kSteps);
        }
        table[128] = 0;  // the centre exactly
        return table;
    }();
    const float at = std::clamp(u, 0.0f, 1.0f) * 256;
    const int i = std::min(int(at), 255);
    return quantiles[i] + (at - float(i)) * (quantiles[i + 1] - quantiles[i]);
}

}  // namespace

std::array<float, 2> pixel_sample_offset(uint32_t index, PixelFilter filter) {
    auto radical_inverse = [](uint32_t i, uint32_t base) {
        double value = 0, digit = 1.0 / base;
        for (; i > 0; i /= base, digit /= base) value += digit * (i % base);
        return value;
    };
    if (index == 0) return {0.0f, 0.0f};  // the centre: the other AOVs' sample
    // The later samples: the Halton points shifted by irrational amounts (a shift keeps them as evenly spread, and the
    // edge of the square out of reach), then spread as the filter weighs: evenly over the box, denser towards the centre
    // for the Gaussian (its inverse cumulative distribution), so that every sample counts alike.
    auto shifted = [](double h, double shift) {
        const double u = h + shift;
        return float(u - std::floor(u));
    };
    const float ux = shifted(radical_inverse(index, 2), 0.5 * (std::sqrt(2.0) - 1.0));
    const float uy = shifted(radical_inverse(index, 3), 0.5 * (std::sqrt(3.0) - 1.0));
    if (filter == PixelFilter::Box) return {ux - 0.5f, uy - 0.5f};
    return {gaussian_quantile(ux), gaussian_quantile(uy)};
}

std::vector<Image> Renderer::render(GpuScene& scene, const CameraDesc& camera, const RenderSettings& settings, const std::vector<Aov>& aovs, FrameStats* stats) {
    if (settings.pixelSamples == 0 || settings.pixelSamples > kMostPixelSamples)
        throw std::invalid_argument("pixel samples must be between 1 and " + std::to_string(kMostPixelSamples));
    if (!std::isfinite(settings.pixelOffset[0]) || !std::isfinite(settings.pixelOffset[1]))
        throw std::invalid_argument("the pixel offset must be finite");
    // Only the colour is averaged: without it, one frame (the centre) is the whole image.
    const auto colour = std::find(aovs.begin(), aovs.end(), Aov::Color);
    if (settings.pixelSamples == 1 || colour == aovs.end()) {
        RenderSettings one = settings;
        one.pixelSamples = 1;
        return render_sample(scene, camera, one, aovs, stats);
    }
    // Sample 0 (the centre) gives every AOV; the later samples draw the colour alone (the samples are spread as the
    // filter weighs: each counts alike). A GPU sums their colours itself (samples.comp.glsl) and the last sample hands
    // back their mean; a CPU device hands back each sample's colour and the host adds it into sample 0's (lavapipe's
    // pass cost more than the host's loop: its loads and stores through an address go a lane at a time). In float, in
    // the same order either way: the sum of n samples is off by at most n float roundings of its size (2.4e-4 of it at
    // the kMostPixelSamples allowed; half an 8-bit step is 2e-3).
    const size_t colourIndex = size_t(colour - aovs.begin());
    const bool onDevice = impl_->sampleSumsOnDevice;
    std::vector<Image> images;
    FrameStats last, costs;
    RenderSettings sample = settings;
    sample.pixelSamples = 1;
    struct SampleSums {  // the device's two sum buffers: only while an image of several samples is drawn
        Impl& s;
        ~SampleSums() { s.sampleSums[0] = Buffer{}, s.sampleSums[1] = Buffer{}; }
    } sums{*impl_};
    for (uint32_t k = 0; k < settings.pixelSamples; ++k) {
        const std::array<float, 2> offset = pixel_sample_offset(k, settings.pixelFilter);
        sample.pixelOffset = {settings.pixelOffset[0] + offset[0], settings.pixelOffset[1] + offset[1]};
        const SampleStep step{k, settings.pixelSamples};
        FrameStats frame;
        std::vector<Image> drawn = render_sample(scene, camera, sample, k == 0 ? aovs : std::vector<Aov>{Aov::Color}, &frame, onDevice ? &step : nullptr);
        if (k == 0) {
            images = std::move(drawn);  // on the device, its colour went into the sum, not into its image
        } else if (onDevice) {
            if (k + 1 == settings.pixelSamples) images[colourIndex] = std::move(drawn[0]);
        } else {
            PixelVector& sum = images[colourIndex].pixels;
            const PixelVector& pixels = drawn[0].pixels;
            for (size_t p = 0; p < sum.size(); ++p) sum[p] += pixels[p];
        }
        visit_frame_costs(costs, frame, [](auto& total, const auto& value) { total += value; });
        costs.errors.insert(costs.errors.end(), frame.errors.begin(), frame.errors.end());
        last = frame;  // counts: the last sample's (every sample draws the same cut, the last with the best occlusion)
    }
    if (!onDevice) {
        const float scale = 1.0f / float(settings.pixelSamples);
        for (float& value : images[colourIndex].pixels) value *= scale;
    }
    last.sampleSumsOnDevice = onDevice;
    visit_frame_costs(last, costs, [](auto& field, const auto& total) { field = total; });
    last.errors = std::move(costs.errors);
    last.pixelSamples = settings.pixelSamples;
    if (stats) *stats = last;
    return images;
}

std::vector<Image> Renderer::render_sample(GpuScene& scene, const CameraDesc& camera, const RenderSettings& settings, const std::vector<Aov>& aovs,
                                           FrameStats* stats, const SampleStep* sample) {
    Impl& s = *impl_;
    const std::lock_guard<std::mutex> lock(s.pipelines.mutex);  // other renderers on the device share the pipelines
    if (settings.width == 0 || settings.height == 0 || settings.width > 16384 || settings.height > 16384)
        throw std::invalid_argument("resolution must be between 1x1 and 16384x16384");
    const auto uploadStarted = std::chrono::steady_clock::now();
    UploadBatch uploads(s.device);  // everything this frame changes, sent in one submission (submitted below)
    bool instancesMoved = s.uploadedScene != scene.id_ || s.instancesVersion != scene.instancesVersion_, materialsChanged = false;
    if (s.uploadedScene != scene.id_ || s.materialsVersion != scene.materialsVersion_) {
        materialsChanged = s.upload_materials(scene, uploads);  // instance flags say which materials mask pixels, displace and have slots
    }
    // Meshes drawn displaced carry displacement normals: which they are follows the instances and their materials.
    const bool displacedMeshesChanged = (instancesMoved || materialsChanged) && s.update_displaced_meshes(scene);
    uint64_t geometryUploadBytes = 0;
    uint32_t displacedMeshesPrepared = 0;
    if (s.uploadedScene != scene.id_ || s.geometryVersion != scene.geometryVersion_ || displacedMeshesChanged) {
        s.upload_geometry(scene, s.uploadedScene == scene.id_, uploads);
        geometryUploadBytes = s.geometryUploadBytes;
        displacedMeshesPrepared = s.displacedMeshesPrepared;
        instancesMoved = true;  // instance counts depend on the meshes
    }
    if (instancesMoved || materialsChanged) s.upload_instances(scene, instancesMoved, uploads);
    s.uploadedScene = scene.id_;
    s.geometryVersion = scene.geometryVersion_;
    s.instancesVersion = scene.instancesVersion_;
    s.materialsVersion = scene.materialsVersion_;

    // The pool: the materials' images, then the textured dome lights' (re-uploaded only when that set changes).
    std::vector<std::shared_ptr<const TextureImage>> poolImages = s.materialImages;
    bool texturedDome = false, areaLights = false;
    for (const LightDesc& light : scene.lights_) {
        areaLights = areaLights || light.type == LightType::Rect || light.type == LightType::Sphere;
        if (light.type == LightType::Dome && light.texture) {
            texturedDome = true;
            if (std::find(poolImages.begin(), poolImages.end(), light.texture) == poolImages.end()) poolImages.push_back(light.texture);
        }
    }
    areaLights = areaLights || texturedDome;
    if (poolImages != s.poolImages) s.upload_texture_pool(std::move(poolImages), uploads);
    // Every pass reads the streams through texel views where they fit, and stores the AOVs through the output's binding
    // where it fits, in the set that does both (whose lock is held); otherwise in the set for what does not fit (its lock
    // too).
    const uint64_t pixels = uint64_t(settings.width) * settings.height;
    const bool texelViews = settings.texelViews && s.streams_fit_views(pixels);
    const bool outputBinding = texelViews && settings.outputBinding && s.output_fits_binding(pixels);
    // Resolve writes every AOV of the frame in one pass, each into its slice (TS_BINDING_OUTPUT + slice): the AOVs in
    // their order but the colour first, in slice 0 (which the background and samples passes write).
    const uint64_t sliceBytes = pixels * 16, sliceStride = s.output_slice_stride(pixels);
    std::vector<size_t> sliceAov(aovs.size());  // slice -> the AOV's index
    std::iota(sliceAov.begin(), sliceAov.end(), size_t(0));
    std::stable_partition(sliceAov.begin(), sliceAov.end(), [&](size_t i) { return aovs[i] == Aov::Color; });
    Pipelines& pipelines = !texelViews ? s.address_pipelines() : outputBinding ? s.pipelines : s.wide_output_pipelines();
    std::unique_lock<std::mutex> otherSetLock;
    if (&pipelines != &s.pipelines) otherSetLock = std::unique_lock<std::mutex>(pipelines.mutex);
    const bool ownCorners = settings.rasterVertices == RasterVertices::Auto ? pipelines.default_own_corners()
                                                                              : settings.rasterVertices == RasterVertices::PerTriangle;
    const bool countFragments = settings.visualize == Visualize::Overdraw;  // the rasterizers' variants that count
    const CameraMatrices cam = camera_matrices(camera, settings.width, settings.height, settings.pixelOffset);
    s.upload_relative_translations(cam.position, uploads);
    uploads.submit();
    FrameStats frameStats;
    frameStats.swSharedVertices = !ownCorners;
    frameStats.cullGroupSize = pipelines.cullGroupSize;
    frameStats.swRasterGroupSize = pipelines.software_raster_group_size(ownCorners);
    frameStats.shadePixelsPerThread = pipelines.shadePixelsPerThread;
    frameStats.texelViews = texelViews;
    frameStats.outputBinding = outputBinding;
    frameStats.uploadMs = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - uploadStarted).count();
    frameStats.instances = s.instanceCount;
    frameStats.instanceBatches = uint32_t(s.gpuBatches.size());
    frameStats.clusters = s.clusterCount;
    frameStats.sourceTriangles = s.sourceTriangles;
    frameStats.textures = uint32_t(s.poolImages.size());
    frameStats.textureBytes = s.texturePool.size + s.textureSlots.size;
    frameStats.geometryUploadBytes = geometryUploadBytes;
    frameStats.uploadSubmissions = uploads.submissions();
    frameStats.displacedMeshesPrepared = displacedMeshesPrepared;
    frameStats.hostMeshBytes = scene.held_stream_bytes();
    frameStats.errors = std::move(s.uploadErrors);
    s.uploadErrors.clear();
    frameStats.geometryBytes = s.meshes.size;
    for (size_t k = 0; k < Impl::kDisplacementNormals; ++k) frameStats.geometryBytes += s.mesh_streams()[k]->buffer().size;

    // The AOVs' images are made first, and where the device can import their memory (VK_EXT_external_memory_host) it
    // writes them in place: on a CPU device each AOV's slice binding is its image (resolve writes there), a GPU copies
    // each AOV from its slice of the output into its image. Without an import (no such driver, images under a megabyte,
    // $TESSERA_IMPORT_AOVS=0), AOVs go through the readback buffer and the CPU copies them out of it: at 1080p 33 MB,
    // 9-10 ms of lavapipe's host and 4-5 ms beside an H100, a frame. The imports go when the frame is done; the images
    // keep their memory.
    std::vector<Image> images(aovs.size());
    for (size_t i = 0; i < aovs.size(); ++i) images[i].width = settings.width, images[i].height = settings.height, images[i].aov = aovs[i];
    bool importAovs = s.imports_aovs(pixels) && !aovs.empty();
    std::vector<VkBuffer> aovTargets;  // per AOV, its image's memory
    if (importAovs) {
        try {
            for (size_t i = 0; i < aovs.size(); ++i) {
                images[i].pixels.resize(pixels * 4);  // left as it is: written whole by the device
                aovTargets.push_back(s.kept_import(images[i].pixels.data(), pixel_block_bytes(pixels * 16), frameStats.aovImportsMade));
            }
        } catch (const DeviceError&) {  // the driver refused this memory: this renderer's frames take the readback path
            s.importAovs = false;
            importAovs = false;
            aovTargets.clear();
            s.keptImports.clear();
        }
    }
    // On a CPU device resolve stores each AOV straight into its image: the image is its slice's binding.
    const bool directSlices = importAovs && device_.is_software() && outputBinding;
    std::vector<VkBuffer> directTargets;  // slice -> its image's memory, where direct
    if (directSlices)
        for (size_t i : sliceAov) directTargets.push_back(aovTargets[i]);
    frameStats.aovsImported = importAovs;

    uint32_t lightCounts = 0;  // the frame's distant lights | all its lights << 8 (TS_SPEC_LIGHT_COUNTS)
    // Occlusion, unless --no-lod (every source triangle, the classic way) or resting after frames where it culled little.
    const bool occlusionWanted = settings.occlusion && settings.lod;
    const float minimumCulled = settings.occlusionMinimumCulled >= 0 ? settings.occlusionMinimumCulled
                                : device_.is_software()            ? RenderSettings::kCpuOcclusionMinimumCulled
                                                                   : 0.0f;
    const bool occlusion = occlusionWanted && (s.occlusionRest == 0 || minimumCulled <= 0);
    if (occlusionWanted && !occlusion) --s.occlusionRest;
    frameStats.occlusionRested = occlusionWanted && !occlusion;
    // The last frame of a rest builds its HZB all the same, so that the frame that tries occlusion again tests against
    // the frame before it, as occlusion does every frame (a first frame only finds what the instances large on screen hide).
    const bool hzbForNext = occlusion || (frameStats.occlusionRested && s.occlusionRest == 0);
    // ... unless no frame follows (the last sample of a renderer's last frame): then the post pass's HZB is the last.
    const bool finalHzb = hzbForNext && !(settings.lastFrame && (!sample || sample->index + 1 == sample->count));
    // A frame whose pixels can only fall in one bin (one material, no displacement) lists its covered pixels at once
    // (a GPU's frame after one that covered few pixels), or is not classified: its resolve reads every pixel.
    const bool oneBin = s.materialCount * s.bin_kinds() == 1;
    uint32_t pixelSource = s.coverage >= Impl::kEveryPixelCoverage ? TS_PIXELS_IN_PLACE
                         : pipelines.shadePixelsPerThread > 1 && pipelines.shadePixelsPerThread <= TS_PACKED_MOST_PIXELS_PER_THREAD
                             ? TS_PIXELS_PACKED
                             : TS_PIXELS_LISTED;
    // ... and so does a CPU device's frame of several materials, each pixel reading its own (Impl::materialBins).
    const bool pixelMaterials = !oneBin && !s.materialBins && s.bin_kinds() == 1 && pixelSource != TS_PIXELS_LISTED;
    if (!oneBin && !pixelMaterials) pixelSource = TS_PIXELS_LISTED;
    const bool everyPixel = pixelSource != TS_PIXELS_LISTED;
    for (;;) {
        s.ensure_frame_buffers(settings.width, settings.height, aovs.size(), importAovs, directSlices);
        if (s.anyDisplaced) s.ensure_tessellation_buffers();
        if (hzbForNext) s.ensure_occlusion_buffers();
        if (sample)
            for (Buffer& sum : s.sampleSums)
                if (sum.size < pixels * 16) sum = device_.create_buffer(pixels * 16, MemoryUse::Device);
        if (pixelSource == TS_PIXELS_LISTED) s.ensure_bin_pixels();
        s.write_texel_views(pixels);  // after every buffer a view covers is made (the HZB's too)
        s.write_output_bindings(pixels, aovs.size(), directTargets);

        gpu::GpuFrame f{};
        f.viewProjection = to_gpu(cam.viewProjection);
        set_pixel_rays(f, cam.inverseViewProjection, settings.width, settings.height);
        f.cameraForward = {float(cam.forward[0]), float(cam.forward[1]), float(cam.forward[2]), 0};
        const ViewFrustum frustum = frustum_of(cam);
        for (int i = 0; i < 6; ++i) {
            const auto& p = frustum.planes[i];
            f.frustumPlanes[i] = gpu::vec4{float(p[0]), float(p[1]), float(p[2]), float(p[3])};
        }
        f.background = {settings.background[0], settings.background[1], settings.background[2], settings.background[3]};
        // Distant lights first (resolve shades them in a loop of their own: TS_SPEC_LIGHT_COUNTS), then the others in the
        // scene's order.
        std::vector<const LightDesc*> lights;
        for (const LightDesc& l : scene.lights_) lights.push_back(&l);
        std::stable_partition(lights.begin(), lights.end(), [](const LightDesc* l) { return l->type == LightType::Distant; });
        const uint32_t lightCount = uint32_t(std::min<size_t>(lights.size(), TS_MAX_LIGHTS));
        f.viewport = {settings.width, settings.height, s.materialCount, lightCount};
        const auto distant = std::count_if(lights.begin(), lights.begin() + lightCount, [](const LightDesc* l) { return l->type == LightType::Distant; });
        lightCounts = uint32_t(distant) | lightCount << 8;  // resolve's shading variants (TS_SPEC_LIGHT_COUNTS)
        bool environmentSet = false;
        for (uint32_t i = 0; i < lightCount; ++i) {
            const LightDesc& l = *lights[i];
            double d[3] = {l.direction[0], l.direction[1], l.direction[2]};
            const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            for (double& x : d) x /= (len > 0 ? len : 1);
            const uint32_t type = l.type == LightType::Distant ? TS_LIGHT_DISTANT
                                : l.type == LightType::Dome    ? TS_LIGHT_DOME
                                : l.type == LightType::Rect    ? TS_LIGHT_RECT
                                                               : TS_LIGHT_SPHERE;
            gpu::GpuLight& g = f.lights[i];
            g.directionType = {float(d[0]), float(d[1]), float(d[2]), float(type)};
            g.radiance = {l.radiance[0], l.radiance[1], l.radiance[2], 0};
            // Places relative to the camera, in double (as instances are).
            g.position = {float(l.position[0] - cam.position[0]), float(l.position[1] - cam.position[1]), float(l.position[2] - cam.position[2]),
                          float(l.radius)};
            g.axisX = {float(l.axisX[0]), float(l.axisX[1]), float(l.axisX[2]), 0};
            g.axisY = {float(l.axisY[0]), float(l.axisY[1]), float(l.axisY[2]), 0};
            g.texture = TS_NO_TEXTURE;
            // One textured dome lights by its image (the first; the others by their colour).
            if (l.type == LightType::Dome && l.texture && !environmentSet) {
                g.texture = uint32_t(std::find(s.poolImages.begin(), s.poolImages.end(), l.texture) - s.poolImages.begin());
                for (int k = 0; k < 9; ++k) f.environment[k] = {l.environment[3 * k], l.environment[3 * k + 1], l.environment[3 * k + 2], 0};
                environmentSet = true;
            }
        }
        // LOD: an error of e units at view depth d covers e * lod.x / d pixels (|P11| maps unit height to NDC,
        // and NDC spans height / 2 pixels per unit).
        const double pixelsPerUnit = cam.projectionScaleY * 0.5 * settings.height;
        f.lod = {float(pixelsPerUnit), std::max(settings.pixelError, 0.0f), camera.orthographic ? 1.0f : 0.0f, float(camera.nearClip)};
        f.raster = {settings.softwareRasterArea, float(1u << device_.sub_pixel_bits()), 0, 0};
        f.tessellation = {std::max(settings.dicingRate, 1e-3f), float(s.patchCapacity), float(s.pointCapacity), 0};
        // With the DAG off and no rasterizer forced, draw the classic way: every source triangle through hardware raster.
        const bool hardwareOnly = settings.raster == RasterMode::Hardware || (settings.raster == RasterMode::Auto && !settings.lod);
        const uint32_t rasterFlags = hardwareOnly ? TS_FRAME_HARDWARE_ONLY : settings.raster == RasterMode::Software ? TS_FRAME_SOFTWARE_FIRST : 0u;
        // The main pass defers what the previous frame's HZB hides or, in a first frame, the instances too small on screen
        // to hide much (cull.comp.glsl likely_occluder); the post pass tests those against this frame's HZB.
        const bool postPass = occlusion, previous = occlusion && s.previousValid;
        f.counts = {s.instanceCount, s.capacity, (settings.lod ? 0u : TS_FRAME_NO_LOD) | rasterFlags | (previous ? TS_FRAME_PREVIOUS_HZB : 0u) |
                        (occlusion ? TS_FRAME_OCCLUSION : 0u) | (occlusionWanted ? TS_FRAME_BACKFACES : 0u) | (s.anyDisplaced ? TS_FRAME_MICRO_BINS : 0u) |
                        (settings.cutBlocks ? 0u : TS_FRAME_NO_CUT_BLOCKS) | (texturedDome ? TS_FRAME_DOME_BACKGROUND : 0u),
                    uint32_t(settings.visualize)};
        f.outputs = {uint32_t(sliceStride / 16), 0, 0, 0};  // slices of the output through its address
        if (previous) {
            // The previous camera saw positions relative to itself: shift this frame's camera-relative positions back.
            const Matrix4d shift = translation_matrix(cam.position[0] - s.previousCamera[0], cam.position[1] - s.previousCamera[1],
                                                      cam.position[2] - s.previousCamera[2]);
            f.previousViewProjection = to_gpu(multiply(s.previousViewProjection, shift));
        }
        f.hzb = {hzbForNext ? uint32_t(hzb_levels(settings.width, settings.height).size()) : 0u, s.cutCapacity, s.deferredCapacity,
                 cut_parts_word(device_, settings)};
        f.cutList = s.cutList.address;
        f.instances = s.instances.address;
        f.instanceBatches = s.instanceBatches.address;
        f.batches = s.batches.address;
        f.meshes = s.meshes.address;
        f.levels = s.levels.buffer().address;
        f.cutBlocks = s.cutBlocks.buffer().address;
        f.blockClusters = s.blockClusters.buffer().address;
        f.clusters = s.clusters.buffer().address;
        f.vertices = s.vertices.buffer().address;
        f.colors = s.colors.buffer().address;
        f.uvs = s.uvs.buffer().address;
        f.triangles = s.triangles.buffer().address;
        f.materials = s.materials.address;
        f.materialTables = s.materialTables.address;
        f.visibleClusters = s.visibleClusters.address;
        f.visibleRecords = s.visibleRecords.address;
        f.hardwareList = s.hardwareList.address;
        f.softwareList = s.softwareList.address;
        f.drawState = s.drawState.address;
        f.visibility = s.visibility.address;
        f.aovOutput = s.aovOutput.address;
        if (sample) {  // sample k writes sum k % 2, reading the other (that of the samples before it)
            f.samplesAfter = s.sampleSums[sample->index % 2].address;
            f.samplesBefore = s.sampleSums[(sample->index + 1) % 2].address;
        }
        f.deferredInstances = occlusion ? s.deferredInstances.address : 0;
        f.deferredClusters = occlusion ? s.deferredClusters.address : 0;
        if (countFragments && s.overdraw.size < pixels * 4) s.overdraw = device_.create_buffer(pixels * 4, MemoryUse::Device);
        f.overdraw = countFragments ? s.overdraw.address : 0;
        f.bins = s.shadingBins.address;
        f.binPixels = s.binPixels.address;
        f.textureSlots = s.textureSlots.address;
        f.textures = s.texturePool.address;
        f.displacementNormals = s.anyDisplaced ? s.displacementNormals.buffer().address : 0;
        f.tessellationList = s.anyDisplaced ? s.tessellationList.address : 0;
        f.patches = s.anyDisplaced ? s.patches.address : 0;
        f.patchDraws = s.anyDisplaced ? s.patchDraws.address : 0;
        f.seams = s.anyDisplaced ? s.seams.buffer().address : 0;
        f.dicePatches = s.anyDisplaced ? s.dicePatches.address : 0;
        f.deferredPatchList = s.anyDisplaced ? s.deferredPatchList.address : 0;
        f.patchPoints = s.anyDisplaced ? s.patchPoints.address : 0;
        f.clusterDisplacement = s.clusterDisplacement.address;
        std::memcpy(s.frame.mapped, &f, sizeof(f));

        // Resolve's variant for a bin: every AOV of the frame, each into its slice (TS_SPEC_OUTPUT); materials with
        // textures through the variant that samples them, which only the colour's shading reads.
        uint32_t outputs = 0;
        for (size_t k = 0; k < aovs.size(); ++k) {
            outputs |= uint32_t(k + 1) << (TS_OUTPUT_BITS * uint32_t(aovs[sliceAov[k]]));
            if (aovs[sliceAov[k]] == Aov::Color && settings.visualize != Visualize::None) outputs |= TS_OUTPUT_VISUALIZE;
        }
        auto resolve_variant_of = [&](uint32_t pixels, uint32_t m) {
            Pipelines::ResolveVariant v;
            v.pixelSource = pixelSource;
            v.outputs = outputs;
            v.textured = TS_OUTPUT_FIELD(outputs, TS_AOV_COLOR) != 0 && m < s.texturedMaterials.size() && s.texturedMaterials[m];
            v.textureKinds = m < s.materialTextureKinds.size() ? s.materialTextureKinds[m] : 0u;
            v.pixels = pixels;
            v.areaLights = areaLights;
            v.vertexInputs = s.materialRecords[m].vertexInputs != 0;
            v.lightCounts = lightCounts;
            return v;
        };
        // The one variant of a frame whose pixels read their own materials: every material's features, and the frame's
        // instance flags (the per-pixel material table lookup only where some instance has one).
        Pipelines::ResolveVariant pixelMaterialsVariant = resolve_variant_of(TS_BIN_TRIANGLES, 0);
        for (uint32_t m = 1; pixelMaterials && m < s.materialCount; ++m) {
            const Pipelines::ResolveVariant other = resolve_variant_of(TS_BIN_TRIANGLES, m);
            pixelMaterialsVariant.textured = pixelMaterialsVariant.textured || other.textured;
            pixelMaterialsVariant.textureKinds |= other.textureKinds;
            pixelMaterialsVariant.vertexInputs = pixelMaterialsVariant.vertexInputs || other.vertexInputs;
        }
        pixelMaterialsVariant.pixelMaterials = true;
        pixelMaterialsVariant.instanceFlags = s.instanceFlags;
        // What the frame draws with, made before it records, together on the host's threads (Pipelines::make_for_frame).
        Pipelines::FrameNeeds needs{s.anyMasked, ownCorners, countFragments, s.anyDisplaced, s.instanceFlags, oneBin || pixelMaterials, {}};
        if (pixelMaterials && !aovs.empty()) needs.resolves.push_back(pixelMaterialsVariant);
        else if (!aovs.empty())
            for (uint32_t pixels = 0; pixels < s.bin_kinds(); ++pixels)
                for (uint32_t m = 0; m < s.materialCount; ++m)
                    if (pixels == TS_BIN_TRIANGLES || s.material_displaced(m)) needs.resolves.push_back(resolve_variant_of(pixels, m));
        pipelines.make_for_frame(needs);
        const VkPipeline softwareRaster = pipelines.software_raster(s.anyMasked, ownCorners, false, countFragments);
        const VkPipeline softwareRasterLarge = pipelines.software_raster(s.anyMasked, ownCorners, true, countFragments);

        const auto submitted = std::chrono::steady_clock::now();
        uint32_t timedCopies = 0;  // AOV copies with timestamps around them (Impl::kTimedCopies at most)
        std::chrono::steady_clock::time_point recorded;
        device_.run([&](VkCommandBuffer cmd) {
            vkCmdResetQueryPool(cmd, s.timestamps, 0, Impl::kTimestamps);
            for (VkPipelineBindPoint point : {VK_PIPELINE_BIND_POINT_COMPUTE, VK_PIPELINE_BIND_POINT_GRAPHICS})
                vkCmdBindDescriptorSets(cmd, point, pipelines.layout, 0, 1, &s.frameSet, 0, nullptr);
            // Every mark waits for all the work before it. lavapipe writes a timestamp only when it next flushes, which a
            // barrier does: on a CPU device each mark is followed by an execution barrier, else a mark before a dispatch
            // with no barrier between them (classify's, the HZB's) took that dispatch's time into the span before it.
            uint32_t timestamp = 0;
            auto stamp = [&](uint32_t query) {
                vkCmdWriteTimestamp2(cmd, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, s.timestamps, query);
                if (device_.is_software()) barrier(cmd, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, 0, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, 0);
            };
            auto mark = [&]() { stamp(timestamp++); };
            mark();
            gpu::GpuDrawState initial{};
            initial.vertexCount = initial.doubleSidedVertexCount = TS_CLUSTER_MAX_TRIANGLES * 3;
            initial.swGroupsZ = 1;
            initial.swLargeGroupsZ = 1;
            initial.tessGroupsZ = 1;
            initial.dicePatchGroupsZ = 1;
            initial.deferredPatchGroupsY = initial.deferredPatchGroupsZ = 1;
            initial.postGroupsY = initial.postGroupsZ = 1;
            initial.cutGroupsY = initial.cutGroupsZ = 1;
            initial.postInstanceGroupsY = initial.postInstanceGroupsZ = 1;
            vkCmdUpdateBuffer(cmd, s.drawState.handle, 0, sizeof(initial), &initial);
            vkCmdFillBuffer(cmd, s.visibility.handle, 0, pixels * 8, 0);
            if (countFragments) vkCmdFillBuffer(cmd, s.overdraw.handle, 0, pixels * 4, 0);
            vkCmdFillBuffer(cmd, s.shadingBins.handle, 0, uint64_t(s.materialCount) * s.bin_kinds() * sizeof(gpu::GpuBin), 0);
            barrier(cmd, VK_PIPELINE_STAGE_2_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                    VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT,
                    VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);

            // Both rasterizers draw the clusters the cull step before them listed: small triangles through the compute
            // rasterizer (one workgroup per cluster, indirect), the rest through hardware raster (one draw instance each).
            auto rasterize = [&](bool post) {
                barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                        VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT | VK_PIPELINE_STAGE_2_VERTEX_SHADER_BIT | VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT |
                            VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                        VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
                // Two ends of the software list, each through its own variant: clusters of small triangles (32-bit
                // edge functions only), then the rest (no workgroups when there are none).
                vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, softwareRaster);
                vkCmdDispatchIndirect(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, swGroupsX));
                vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, softwareRasterLarge);
                vkCmdDispatchIndirect(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, swLargeGroupsX));
                mark();
                // Both rasterizers only do atomic max into the visibility buffer, which commutes; the barrier keeps the
                // synchronization validation layer (rightly strict about unordered writes) quiet and costs little.
                barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT,
                        VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
                VkRenderingInfo rendering{VK_STRUCTURE_TYPE_RENDERING_INFO};
                rendering.renderArea = {{0, 0}, {settings.width, settings.height}};
                rendering.layerCount = 1;
                vkCmdBeginRendering(cmd, &rendering);
                VkViewport viewport{0, 0, float(settings.width), float(settings.height), 0, 1};
                VkRect2D scissor{{0, 0}, {settings.width, settings.height}};
                vkCmdSetViewport(cmd, 0, 1, &viewport);
                vkCmdSetScissor(cmd, 0, 1, &scissor);
                for (bool doubleSided : {false, true}) {  // single-sided instances with back faces culled, then the others
                    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, pipelines.hardware_raster(s.anyMasked, doubleSided, countFragments));
                    vkCmdDrawIndirect(cmd, s.drawState.handle, doubleSided ? offsetof(gpu::GpuDrawState, doubleSidedVertexCount) : 0, 1,
                                      sizeof(VkDrawIndirectCommand));
                }
                vkCmdEndRendering(cmd);
                mark();
                // Displaced clusters: patches (one workgroup per cluster, indirect); the small ones diced and scanned in
                // compute (one workgroup per patch, indirect), the rest by one indirect draw per patch.
                if (s.anyDisplaced) {
                    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipelines.tessellate());
                    vkCmdDispatchIndirect(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, tessGroupsX));
                    if (post) {  // the patches the main pass deferred, against this frame's HZB
                        barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                                VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
                        PushConstants push{0, TS_TESS_DEFERRED_PATCHES, s.hzbLevels.address};
                        vkCmdPushConstants(cmd, pipelines.layout, VK_SHADER_STAGE_ALL, 0, sizeof(push), &push);
                        vkCmdDispatchIndirect(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, deferredPatchGroupsX));
                        push.step = TS_CULL_POST;
                        vkCmdPushConstants(cmd, pipelines.layout, VK_SHADER_STAGE_ALL, 0, sizeof(push), &push);
                    }
                    barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                            VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT | VK_PIPELINE_STAGE_2_VERTEX_SHADER_BIT | VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT |
                                VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                            VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
                    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipelines.dice(s.anyMasked, countFragments));
                    vkCmdDispatchIndirect(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, dicePatchGroupsX));
                    barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT,
                            VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
                    vkCmdBeginRendering(cmd, &rendering);
                    vkCmdSetViewport(cmd, 0, 1, &viewport);
                    vkCmdSetScissor(cmd, 0, 1, &scissor);
                    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, pipelines.patch_raster(s.anyMasked, countFragments));
                    vkCmdDrawIndirectCount(cmd, s.patchDraws.handle, 0, s.drawState.handle, offsetof(gpu::GpuDrawState, patchDraws), s.patchCapacity,
                                           sizeof(VkDrawIndirectCommand));
                    vkCmdEndRendering(cmd);
                }
                mark();
                barrier(cmd, VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT | VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT,
                        VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT | VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT,
                        VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_2_TRANSFER_BIT,
                        VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT | VK_ACCESS_2_TRANSFER_WRITE_BIT);
            };

            // Main pass: instances one per thread, then a workgroup per instance they listed.
            auto cull_step = [&](uint32_t step, const Buffer& hzb) {
                vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipelines.cull_step(step, s.instanceFlags));
                PushConstants push{0, step, hzb.address};
                vkCmdPushConstants(cmd, pipelines.layout, VK_SHADER_STAGE_ALL, 0, sizeof(push), &push);
            };
            auto compute_to_indirect = [&]() {
                barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                        VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT | VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                        VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
            };
            cull_step(TS_CULL_MAIN_INSTANCES, s.hzbLevels);
            if (s.instanceCount) {
                const uint32_t groups = (s.instanceCount + TS_CULL_INSTANCES_PER_GROUP - 1) / TS_CULL_INSTANCES_PER_GROUP;
                const uint32_t groupsX = std::min(groups, 65535u);
                vkCmdDispatch(cmd, groupsX, (groups + groupsX - 1) / groupsX, 1);
            }
            compute_to_indirect();
            cull_step(TS_CULL_MAIN, s.hzbLevels);
            vkCmdDispatchIndirect(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, cutGroupsX));
            mark();
            rasterize(false);

            // Post pass: an HZB of what the main pass drew, then what it deferred, tested against that.
            if (postPass) {
                // The rasterizers' arguments start again at zero (the visible list and the counters go on).
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, instanceCount), 4, 0);
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, doubleSidedInstanceCount), 4, 0);
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, swGroupsX), 8, 0);  // X and Y
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, swClusters), 4, 0);
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, swLargeGroupsX), 8, 0);  // X and Y
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, swLargeClusters), 4, 0);
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, cutInstances), 4, 0);
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, tessGroupsX), 8, 0);  // X and Y
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, tessClusters), 4, 0);
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, patchDraws), 4, 0);
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, dicePatchGroupsX), 8, 0);  // X and Y
                vkCmdFillBuffer(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, dicePatches), 4, 0);
                s.build_hzb(cmd, pipelines, TS_HZB_AFTER_MAIN);
                barrier(cmd, VK_PIPELINE_STAGE_2_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                        VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
                mark();
                compute_to_indirect();
                cull_step(TS_CULL_POST_INSTANCES, s.hzbLevels);
                vkCmdDispatchIndirect(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, postInstanceGroupsX));
                compute_to_indirect();
                cull_step(TS_CULL_POST, s.hzbLevels);
                vkCmdDispatchIndirect(cmd, s.drawState.handle, offsetof(gpu::GpuDrawState, postGroupsX));
                mark();
                rasterize(true);
            } else {
                for (int i = 0; i < 5; ++i) mark();
            }
            // The whole frame's HZB, for the next frame's main pass: unless the HZB of the main pass already is that (the
            // post pass drew nothing).
            if (finalHzb) s.build_hzb(cmd, pipelines, TS_HZB_FINAL);
            mark();

            // Material bins: count covered pixels per material, give each bin its range and dispatch arguments, scatter
            // (or, when only one bin is possible, list the covered pixels and give it its dispatch arguments).
            auto compute_barrier = [&]() {
                barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                        VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT,
                        VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT | VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
            };
            const uint32_t tilesX = (settings.width + TS_PIXEL_TILE - 1) / TS_PIXEL_TILE, tilesY = (settings.height + TS_PIXEL_TILE - 1) / TS_PIXEL_TILE;
            for (uint32_t step : {oneBin ? TS_CLASSIFY_ONE_BIN : TS_CLASSIFY_COUNT, TS_CLASSIFY_SCATTER}) {
                if (everyPixel || (oneBin && step == TS_CLASSIFY_SCATTER)) break;
                vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipelines.classify_step(step, s.instanceFlags));
                vkCmdDispatch(cmd, tilesX, tilesY, 1);
                compute_barrier();
                if (step != TS_CLASSIFY_SCATTER) {
                    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipelines.bins);
                    vkCmdDispatch(cmd, 1, 1, 1);
                    compute_barrier();
                }
            }
            // An every-pixel resolve: a workgroup per row of shadePixelsPerThread tiles (resolve.comp.glsl).
            const uint32_t everyPixelTile = TS_PIXEL_TILE * pipelines.shadePixelsPerThread;
            const uint32_t everyPixelGroupsX = (settings.width + everyPixelTile - 1) / everyPixelTile;

            mark();

            // A plain background into every pixel of the output, before resolve writes the covered ones: a fill where its
            // four words are equal, else the first row written and copied onto the rows below in blocks that double
            // (rows [0, k) onto [k, 2k)): 11 copies at 1080p. One copy of 1080 one-row regions cost an H100 2 ms (a copy
            // per region), and a shader storing the uncovered pixels cost lavapipe a loop over the lanes per word (about
            // 20 ms of a 1080p frame on one core).
            auto fill_background = [&](Aov aov, size_t slice) {
                const VkBuffer target = directSlices ? directTargets[slice] : s.aovOutput.handle;
                const VkDeviceSize base = directSlices ? 0 : slice * sliceStride;
                const std::array<uint32_t, 4> words = background_words(aov, settings.background);
                if (words[0] == words[1] && words[0] == words[2] && words[0] == words[3]) {
                    vkCmdFillBuffer(cmd, target, base, sliceBytes, words[0]);
                    return;
                }
                std::vector<std::array<uint32_t, 4>> row(settings.width, words);
                constexpr size_t kMostPerUpdate = 65536;  // vkCmdUpdateBuffer's limit
                const size_t rowBytes = size_t(settings.width) * 16;
                for (size_t at = 0; at < rowBytes; at += kMostPerUpdate)
                    vkCmdUpdateBuffer(cmd, target, base + at, std::min(kMostPerUpdate, rowBytes - at), reinterpret_cast<const char*>(row.data()) + at);
                for (uint32_t done = 1; done < settings.height; done *= 2) {
                    barrier(cmd, VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT,
                            VK_ACCESS_2_TRANSFER_READ_BIT | VK_ACCESS_2_TRANSFER_WRITE_BIT);
                    const VkBufferCopy block{base, base + done * rowBytes, std::min(done, settings.height - done) * rowBytes};
                    vkCmdCopyBuffer(cmd, target, target, 1, &block);
                }
            };

            // Each AOV's background into its slice, then one indirect dispatch per material over its bin's pixels, writing
            // every AOV (each pixel's triangle fetched once for all of them), then each AOV into its image. A resolve in
            // place stores every pixel, the background where nothing covers it (but a textured dome's): no fill before.
            if (!aovs.empty()) {
                // Classify (its count step keeps places in slice 0) is done with the output.
                barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                        VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT | VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                        VK_ACCESS_2_TRANSFER_WRITE_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
                const bool colour = aovs[sliceAov[0]] == Aov::Color;  // the colour comes first, in slice 0
                for (size_t k = 0; k < aovs.size() && pixelSource != TS_PIXELS_IN_PLACE; ++k)
                    if (!(texturedDome && aovs[sliceAov[k]] == Aov::Color)) fill_background(aovs[sliceAov[k]], k);
                barrier(cmd, VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                        VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
                if (texturedDome && colour) {  // the dome's image where nothing covers a pixel, before resolve's stores
                    PushConstants background{uint32_t(Aov::Color), 0, 0};
                    vkCmdPushConstants(cmd, pipelines.layout, VK_SHADER_STAGE_ALL, 0, sizeof(background), &background);
                    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipelines.textured_background());
                    vkCmdDispatch(cmd, tilesX, tilesY, 1);
                    barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                            VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
                }
                VkPipeline bound = VK_NULL_HANDLE;
                if (pixelMaterials) {  // one dispatch over every pixel, each reading its material
                    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipelines.resolve_variant(pixelMaterialsVariant));
                    const ResolvePushConstants shade{{0, 0, 0}, {}};
                    vkCmdPushConstants(cmd, pipelines.layout, VK_SHADER_STAGE_ALL, 0, sizeof(shade), &shade);
                    vkCmdDispatch(cmd, everyPixelGroupsX, tilesY, 1);
                }
                for (uint32_t pixels = 0; pixels < s.bin_kinds() && !pixelMaterials; ++pixels)
                    for (uint32_t m = 0; m < s.materialCount; ++m) {
                        if (pixels != TS_BIN_TRIANGLES && !s.material_displaced(m)) continue;  // micro-triangles: displaced only
                        const VkPipeline pipeline = pipelines.resolve_variant(resolve_variant_of(pixels, m));
                        if (pipeline != bound) vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, bound = pipeline);
                        const uint32_t bin = pixels * s.materialCount + m;
                        ResolvePushConstants shade{{0, bin, 0}, s.materialRecords[m]};
                        vkCmdPushConstants(cmd, pipelines.layout, VK_SHADER_STAGE_ALL, 0, sizeof(shade), &shade);
                        if (everyPixel) vkCmdDispatch(cmd, everyPixelGroupsX, tilesY, 1);
                        else vkCmdDispatchIndirect(cmd, s.shadingBins.handle, bin * sizeof(gpu::GpuBin));
                    }
                bool colourSummed = false;  // this sample's colour went into the samples' sum: nothing to hand back
                if (sample && colour) {  // the colour into the samples' sum; the last sample's, their mean
                    barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                            VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
                    const uint32_t step = sample->index == 0 ? TS_SAMPLES_FIRST : sample->index + 1 == sample->count ? TS_SAMPLES_MEAN : TS_SAMPLES_ADD;
                    const PushConstants samples{sample->count, step, 0};
                    vkCmdPushConstants(cmd, pipelines.layout, VK_SHADER_STAGE_ALL, 0, sizeof(samples), &samples);
                    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipelines.pixel_samples());
                    vkCmdDispatch(cmd, tilesX, tilesY, 1);
                    colourSummed = step != TS_SAMPLES_MEAN;
                }
                // Each AOV into its image (or the readback buffer, at its slice's place), unless read where resolve wrote
                // it: the image itself (direct slices) or host-visible output memory.
                if (!directSlices && (importAovs || !s.aovOutput.mapped)) {
                    barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, VK_PIPELINE_STAGE_2_COPY_BIT,
                            VK_ACCESS_2_TRANSFER_READ_BIT);
                    for (size_t k = 0; k < aovs.size(); ++k) {
                        if (colourSummed && aovs[sliceAov[k]] == Aov::Color) continue;
                        const VkBufferCopy region{k * sliceStride, importAovs ? 0 : sizeof(gpu::GpuDrawState) + k * sliceBytes, sliceBytes};
                        const bool timed = timedCopies < Impl::kTimedCopies;
                        if (timed) stamp(Impl::kFrameMarks + 2 * timedCopies);
                        vkCmdCopyBuffer(cmd, s.aovOutput.handle, importAovs ? aovTargets[sliceAov[k]] : s.readback.handle, 1, &region);
                        if (timed) stamp(Impl::kFrameMarks + 2 * timedCopies++ + 1);
                    }
                }
            }
            mark();
            barrier(cmd, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, VK_PIPELINE_STAGE_2_COPY_BIT,
                    VK_ACCESS_2_TRANSFER_READ_BIT);
            VkBufferCopy stateRegion{0, 0, sizeof(gpu::GpuDrawState)};
            vkCmdCopyBuffer(cmd, s.drawState.handle, s.readback.handle, 1, &stateRegion);
            barrier(cmd, VK_PIPELINE_STAGE_2_COPY_BIT | VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                    VK_PIPELINE_STAGE_2_HOST_BIT, VK_ACCESS_2_HOST_READ_BIT);
            recorded = std::chrono::steady_clock::now();
        });
        const auto finished = std::chrono::steady_clock::now();
        frameStats.cpuRecordMs += std::chrono::duration<double, std::milli>(recorded - submitted).count();
        frameStats.cpuWaitMs += std::chrono::duration<double, std::milli>(finished - recorded).count();
        // The HZB just built is of this camera (an overflowing frame's HZB lacks some geometry: farther, still safe).
        s.previousValid = finalHzb;
        s.previousViewProjection = cam.viewProjection;
        s.previousCamera = cam.position;

        gpu::GpuDrawState state;
        std::memcpy(&state, s.readback.mapped, sizeof(state));
        if (state.cutInstancesNeeded > s.cutCapacity || state.deferredInstances > s.deferredCapacity) {
            // More instances survived the instance step, or were hidden by the previous HZB, than the lists hold.
            ++frameStats.overflowRedraws;
            if (state.cutInstancesNeeded > s.cutCapacity)
                s.cutCapacity = std::max(s.cutCapacity * 2, state.cutInstancesNeeded + state.cutInstancesNeeded / 4);
            if (state.deferredInstances > s.deferredCapacity) {
                s.deferredCapacity = std::max(s.deferredCapacity * 2, state.deferredInstances + state.deferredInstances / 4);
                // Every deferred instance may come back in the post pass's cut list: room for them at once, not in a
                // second redraw.
                s.cutCapacity = std::max(s.cutCapacity, std::min(s.deferredCapacity, std::max(s.instanceCount, 1u)));
            }
            continue;
        }
        const uint32_t needed = std::max(state.visibleClusters, state.deferredClusters);
        const bool patchesOverflowed = s.anyDisplaced && state.patches > s.patchCapacity;
        if (needed > s.capacity || patchesOverflowed) {
            if (needed > TS_VIS_MAX_VISIBLE_CLUSTERS)
                throw std::runtime_error("more than 2^24 visible clusters in one frame: the visibility buffer cannot address them");
            if (state.patches > TS_VIS_MAX_PATCHES)
                throw std::runtime_error("more than 2^23 tessellation patches in one frame: the visibility buffer cannot address them "
                                         "(a larger dicing rate makes fewer)");
            ++frameStats.overflowRedraws;
            if (needed > s.capacity) s.capacity = std::min<uint32_t>(TS_VIS_MAX_VISIBLE_CLUSTERS, std::max(s.capacity * 2, needed + needed / 4));
            if (patchesOverflowed)
                s.patchCapacity = std::min<uint32_t>(TS_VIS_MAX_PATCHES, std::max(s.patchCapacity * 2, state.patches + state.patches / 4));
            continue;
        }
        frameStats.visibleInstances = state.visibleInstances;
        frameStats.visibleClusters = state.visibleClusters;
        frameStats.swTriangles = state.swTriangles;
        frameStats.hwTriangles = state.hwTriangles;
        frameStats.visibleTriangles = uint64_t(state.swTriangles) + state.hwTriangles;
        frameStats.swClusters = state.swClustersDrawn;
        frameStats.swLargeClusters = state.swLargeClustersDrawn;
        frameStats.candidateClusters = state.candidateClusters;
        frameStats.visibleClusterCapacity = s.capacity;
        frameStats.occlusionTested = previous;
        frameStats.occludedInstances = state.occludedInstances;
        frameStats.occludedClusters = state.occludedClusters;
        if (occlusion && minimumCulled > 0) {  // did it pay? If not, the next frames rest from it
            auto kept = [](double drawn, double culled) { return drawn + culled > 0 ? drawn / (drawn + culled) : 1.0; };
            const double share = kept(state.visibleInstances, state.occludedInstances) * kept(state.visibleClusters, state.occludedClusters) *
                                 kept(state.patches, state.occludedPatches);
            if (1.0 - share < minimumCulled) s.occlusionRest = RenderSettings::kOcclusionRest;
        }
        frameStats.postPassClusters = state.postClusters;
        frameStats.hzbBuilds = state.hzbBuilds;
        frameStats.backfaceClusters = state.backfaceClusters;
        // An every-pixel frame runs no bins pass: its resolve counted the covered pixels, and they are its one bin.
        frameStats.pixelMaterials = pixelMaterials;
        frameStats.resolvePixels = pixelSource == TS_PIXELS_IN_PLACE ? "in place" : pixelSource == TS_PIXELS_PACKED ? "packed" : "listed";
        frameStats.coveredPixels = state.coveredPixels;
        frameStats.shadingBins = everyPixel ? uint32_t(frameStats.coveredPixels > 0) : state.shadingBins;
        s.coverage = double(frameStats.coveredPixels) / double(pixels);
        frameStats.tessellatedClusters = state.tessClustersDrawn;
        frameStats.tessellatedTriangles = state.tessTriangles;
        frameStats.patches = state.patches;
        frameStats.microTriangles = state.microTriangles;
        frameStats.computePatches = state.dicePatchesDrawn;
        frameStats.deferredPatches = state.deferredPatches;
        frameStats.occludedPatches = state.occludedPatches;
        frameStats.keptMicroPixels = state.keptMicroPixels;
        frameStats.dicedMicroPixels = state.dicedMicroPixels;
        if (state.patchPoints > s.pointCapacity)  // the next frame keeps them all (no redraw: resolve dices the rest again)
            s.pointCapacity = std::min<uint32_t>(1u << 24, std::max(s.pointCapacity * 2, state.patchPoints + state.patchPoints / 4));
        // Memory follows the view down too: a pool or a patch list four times larger than this frame needed drops to
        // twice the need for the next frame (never below the first sizes; a list sized by hand, smaller, stays).
        if (state.patchPoints < s.pointCapacity / 4 && s.pointCapacity > Impl::kFirstPointCapacity)
            s.pointCapacity = std::max(Impl::kFirstPointCapacity, 2 * state.patchPoints);
        if (state.patches < s.patchCapacity / 4 && s.patchCapacity > Impl::kFirstPatchCapacity)
            s.patchCapacity = std::max(Impl::kFirstPatchCapacity, 2 * state.patches);
        frameStats.tessellationBytes =
            s.anyDisplaced ? s.displacementNormals.buffer().size + s.seams.buffer().size + s.clusterDisplacement.size + s.tessellationList.size + s.patches.size + s.patchDraws.size + s.dicePatches.size + s.deferredPatchList.size +
                                  s.patchPoints.size
                            : 0;
        uint64_t ticks[Impl::kTimestamps] = {};
        const uint32_t written = Impl::kFrameMarks + 2 * timedCopies;  // a query never written would fail the whole read
        if (vkGetQueryPoolResults(device_.handle(), s.timestamps, 0, written, sizeof(ticks), ticks, sizeof(uint64_t), VK_QUERY_RESULT_64_BIT) == VK_SUCCESS) {
            const double ms = device_.timestamp_period_ns() * 1e-6;
            auto span = [&](int from, int to) { return double(ticks[to] - ticks[from]) * ms; };
            frameStats.cullMs = span(0, 1) + span(5, 6);
            frameStats.softwareRasterMs = span(1, 2) + span(6, 7);
            frameStats.rasterMs = span(2, 3) + span(7, 8);
            frameStats.tessellationMs = span(3, 4) + span(8, 9);
            frameStats.hzbMs = span(4, 5) + span(9, 10);
            frameStats.classifyMs = span(10, 11);
            frameStats.readbackMs = 0;
            for (uint32_t c = 0; c < timedCopies; ++c) frameStats.readbackMs += span(Impl::kFrameMarks + 2 * c, Impl::kFrameMarks + 2 * c + 1);
            frameStats.resolveMs = span(11, 12) - frameStats.readbackMs;
        }
        break;
    }

    frameStats.instanceBytes = s.instances.size + s.instanceBatches.size + s.batches.size + s.deferredInstances.size + s.cutList.size;
    frameStats.pixelBytes = s.visibility.size + s.aovOutput.size + s.binPixels.size + s.hzbLevels.size + s.overdraw.size + s.sampleSums[0].size +
                            s.sampleSums[1].size;

    ++s.framesRendered;
    s.forget_old_imports();
    if (!importAovs) {
        for (size_t k = 0; k < aovs.size(); ++k) {
            // Copied straight from the mapped readback, or, on a CPU device, from its slice of the output itself.
            const char* bytes = s.aovOutput.mapped ? static_cast<const char*>(s.aovOutput.mapped) + k * sliceStride
                                                   : static_cast<const char*>(s.readback.mapped) + sizeof(gpu::GpuDrawState) + k * sliceBytes;
            const float* rgba = reinterpret_cast<const float*>(bytes);
            images[sliceAov[k]].pixels.assign(rgba, rgba + pixels * 4);
        }
    }
    frameStats.cpuFrameMs = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - uploadStarted).count();
    if (stats) *stats = frameStats;
    return images;
}

}  // namespace tessera
