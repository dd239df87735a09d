// The renderer: a GPU scene of built meshes and their instances, and the passes that draw a frame
// into the 64-bit visibility buffer and resolve it into an AOV. Knows nothing of USD.
#pragma once

#include "tessera/builder.h"
#include "tessera/device.h"
#include "tessera/textures.h"

#include <array>
#include <functional>
#include <memory>
#include <span>
#include <utility>
#include <string>
#include <vector>

namespace tessera {

// 4x4 matrices are row-major and act on column vectors (p' = M p); Python converts from Gf's row vectors.
using Matrix4d = std::array<double, 16>;
Matrix4d identity_matrix();
Matrix4d multiply(const Matrix4d& a, const Matrix4d& b);

// UsdPreviewSurface's inputs, with its defaults: constants, and the textures that drive some of them instead. A
// surface without a preview material (displayColor only) is diffuse: ior 1 reflects nothing at normal incidence.
// MaterialDesc::vertexInputs (GpuMaterial::vertexInputs, TS_VERTEX_INPUT_* in shaders/shared.h): 4 bits per input,
// diffuseColor to occlusion in MaterialInput order, saying which components of the mesh's vertex channel drive it.
constexpr uint32_t vertex_input(MaterialInput input, uint32_t firstComponent, bool rgb) {
    return (8u | (rgb ? 4u : 0u) | (firstComponent & 3u)) << (4u * uint32_t(input));
}
constexpr uint32_t kDisplayColorInputs = vertex_input(MaterialInput::DiffuseColor, 0, true);  // diffuse from displayColor

struct MaterialDesc {
    std::array<float, 3> diffuseColor{0.18f, 0.18f, 0.18f};
    std::array<float, 3> emissiveColor{0, 0, 0};
    float opacity = 1.0f;
    float opacityThreshold = 0.0f;  // > 0: masked; a constant opacity below it hides the surface
    float metallic = 0.0f, roughness = 0.5f;
    bool useSpecularWorkflow = false;  // specularColor instead of metallic
    std::array<float, 3> specularColor{0, 0, 0};
    float ior = 1.5f;
    float occlusion = 1.0f;          // scales what the dome light contributes
    // Inputs driven by the mesh's vertex channel (per vertex, interpolated over the surface), packed as
    // GpuMaterial::vertexInputs (TS_VERTEX_INPUT_*): 0 none; kDisplayColorInputs for diffuse from displayColor.
    uint32_t vertexInputs = 0;
    // Displacement along the (smoothed) vertex normal: offset = (displacement - center) * magnitude in mesh units, the
    // value from `displacement` or a texture slot for MaterialInput::Displacement. UsdPreviewSurface's displacement
    // input, with Tessera's tessera:displacement:* attributes for the rest. It fades out while its largest offset
    // projects to between fadeStart and fadeEnd pixels (none below fadeEnd): detail too small to see is not diced.
    float displacement = 0.0f;
    float displacementMagnitude = 1.0f, displacementCenter = 0.0f;
    float displacementFadeStart = 4.0f, displacementFadeEnd = 1.0f;
    // tessera:displacement:bake: the meshes bound to it are diced and displaced when they are built (bake_displacement)
    // and drawn as they are; nothing is displaced at render time.
    bool displacementBake = false;
    std::vector<TextureSlot> textures;  // at most one per input; a slot without an image uses its fallback
    std::string uvPrimvar;  // the primvar the texture readers read as st ("" without textures)
};

// Copies of a mesh laid out as a USD PointInstancer lays them out, borrowed from the instancer's own arrays (owned by
// `keepAlive`, never copied): instance i maps mesh space by T(positions[i]) R(orientations[i]) S(scales[i]) local, in
// the frame of the InstanceDesc that holds the arrays. Only `selection` (the instances of one prototype, when the
// instancer has several or hides some) is Tessera's own.
struct InstanceArrays {
    std::span<const float> positions;           // 3 per instance
    std::span<const float> orientations;        // 4 per instance (imaginary i j k, then real: GfQuatf), or empty
    std::span<const uint16_t> orientationsHalf; // the same as IEEE halves (GfQuath, USD's usual type), or empty
    std::span<const float> scales;              // 3 per instance, or empty (1, 1, 1)
    std::span<const uint32_t> selection;        // the instances drawn; empty: all of them
    Matrix4d local = identity_matrix();         // the mesh within the prototype (applied first)
    std::shared_ptr<const void> keepAlive;
    size_t count() const { return selection.empty() ? positions.size() / 3 : selection.size(); }
    // Throws std::invalid_argument when the arrays disagree in length or a selected index is out of range.
    void validate() const;
    // Mesh space -> the batch's frame for the n-th drawn instance.
    Matrix4d transform(size_t n) const;
};

// A batch of instances of one mesh: one (`arrays` null) at `transform`, or every instance of `arrays` in the frame
// `transform` (a PointInstancer's world transform). They share the prim, material and flags, and their GPU transforms
// are stored relative to the batch's origin.
struct InstanceDesc {
    uint32_t mesh = 0;        // a handle from GpuScene::add_mesh
    Matrix4d transform{};     // mesh space (or the arrays' frame) -> world, in double
    std::shared_ptr<const InstanceArrays> arrays;
    uint32_t primId = 0;      // reported by the primId AOV
    uint32_t material = 0;    // a handle from GpuScene::add_material; with materialTable, one from add_material_table
    bool materialTable = false;  // the mesh's triangles carry material slots (BuiltMesh::materialSlots > 1)
    bool doubleSided = false;
    size_t count() const { return arrays ? arrays->count() : 1; }
};

enum class LightType { Distant, Dome, Rect, Sphere };
// A light as the renderer shades it (shaders/lights.h says how). World space, double where it is a place.
// The most lights one frame is lit by (shaders/shared.h TS_MAX_LIGHTS): the render index keeps domes and distant lights
// first and says which others it leaves out.
constexpr size_t kMaxLights = 8;

struct LightDesc {
    LightType type = LightType::Distant;
    // Distant: the direction the light travels. Rect: the direction its front faces (it emits along its local -Z).
    std::array<double, 3> direction{0, 0, -1};
    // Distant: irradiance at normal incidence (UsdLux intensity times the sun disk's solid angle, unless
    // normalized). Dome: uniform radiance of the environment (times the texture's, with one). Rect and sphere: the
    // radiance their surface emits (divided by their area when normalized).
    std::array<float, 3> radiance{1, 1, 1};
    std::array<double, 3> position{0, 0, 0};  // rect and sphere: centre
    double radius = 0;                        // sphere
    // Rect: from its centre to the middle of its +X and +Y edges (width / 2 and height / 2 along its local axes, the
    // transform's scale included). Dome: its local X and Y axes (unit), which orient its texture (+Y is the pole).
    std::array<double, 3> axisX{1, 0, 0}, axisY{0, 1, 0};
    // Dome: a lat-long image (absolute path; "" for none), loaded by the light's sync with its irradiance as 9
    // spherical harmonics coefficients (rgb, in the dome's frame, divided by pi: see latlong_irradiance).
    std::string textureFile;
    std::shared_ptr<const TextureImage> texture;
    std::array<float, 27> environment{};
};

// A camera: where it is, and how it projects (USD's UsdGeomCamera model: apertures and focal length in the
// same units; orthographic apertures in scene units).
struct CameraDesc {
    Matrix4d cameraToWorld = identity_matrix();  // camera looks down -Z with +Y up
    bool orthographic = false;
    double focalLength = 50.0;
    double horizontalAperture = 36.0, verticalAperture = 24.0;
    double horizontalApertureOffset = 0.0, verticalApertureOffset = 0.0;
    double nearClip = 0.1, farClip = 1.0e6;  // farClip may be infinity
};

// What a camera sees at a resolution, as a frame draws it: six planes (a x + b y + c z + d >= 0 inside, (a, b, c) of
// unit length; an infinite far plane is 0 0 0 1) in world space relative to the camera's position.
struct ViewFrustum {
    std::array<double, 3> position{};
    std::array<std::array<double, 4>, 6> planes{};
    // False when the box [lo, hi] of mesh space, through `transform` (mesh -> world), lies wholly outside one plane.
    bool touches_box(const Matrix4d& transform, const std::array<double, 3>& lo, const std::array<double, 3>& hi) const;
};
ViewFrustum view_frustum(const CameraDesc& camera, uint32_t width, uint32_t height);

enum class Aov { Color, Depth, Normal, PrimId, InstanceId, ClusterId, TriangleId };
const char* aov_name(Aov aov);
bool aov_is_id(Aov aov);

// An AOV read back from the GPU: 4 floats per pixel, top row first. For id AOVs, channel 0 holds the
// id's bits (uint32; 0xffffffff where nothing was drawn). For depth, channel 0 is the distance along the
// view direction (infinity where nothing was drawn).
// Pixel storage (image_memory.cpp): blocks of a megabyte or more come as transparent huge pages, and the last two freed
// (at most 160 MB, besides pinned ones: below) are kept for the next image of their size, so a frame's readback does not
// fault in 33 MB of fresh 4 KB pages at 1080p.
void* allocate_pixel_bytes(size_t bytes);
void free_pixel_bytes(void* memory, size_t bytes);
// The block an allocation of `bytes` takes: for a large one, whole huge pages at a huge-page boundary (so a device can
// import it: Device::import_host_memory); 0 for a small one (a plain allocation).
size_t pixel_block_bytes(size_t bytes);
// While a device keeps an import of a block (the renderer keeps its AOV images' imports for the frames that reuse
// them), the block is pinned: freed, it waits among the spare blocks instead of going back to the system. Counted:
// each pin is undone by one unpin.
void pin_pixel_block(void* memory);
void unpin_pixel_block(void* memory);
template <class T>
struct PixelAllocator {
    using value_type = T;
    PixelAllocator() = default;
    template <class U>
    PixelAllocator(const PixelAllocator<U>&) {}
    T* allocate(size_t n) { return static_cast<T*>(allocate_pixel_bytes(n * sizeof(T))); }
    void deallocate(T* p, size_t n) { free_pixel_bytes(p, n * sizeof(T)); }
    // Sized without a value, pixels are left as they are (a frame's AOV is written whole by the device: no 33 MB of
    // zeros first); with one, they get it.
    template <class U>
    void construct(U* p) { ::new (static_cast<void*>(p)) U; }
    template <class U, class... Args>
    void construct(U* p, Args&&... args) { ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...); }
    template <class U>
    bool operator==(const PixelAllocator<U>&) const { return true; }
};
using PixelVector = std::vector<float, PixelAllocator<float>>;

struct Image {
    uint32_t width = 0, height = 0;
    Aov aov = Aov::Color;
    PixelVector pixels;  // 4 floats per pixel, top row first
};

// What the color AOV shows instead of shading (debug views in the manner of Nanite's visualization modes).
enum class Visualize { None, Triangles, Clusters, Groups, Lod, Instances, Primitives, ShadingBins, RasterBins, Overdraw, Uv, Tessellation };

// Which rasterizer draws a cluster. Auto: the compute rasterizer for clusters of small triangles, hardware raster
// for the rest. The forced modes exist for tests and measurements (Software still sends clusters that touch the
// near plane or cover a large area to hardware raster).
enum class RasterMode { Auto, Hardware, Software };

// The most pixel samples an image may take (RenderSettings::pixelSamples): their float sum stays within 2.4e-4 of its size.
constexpr uint32_t kMostPixelSamples = 4096;

// How pixel samples combine into a pixel. Box: the mean of samples over the pixel's own square (one pixel wide; alpha
// is the exact coverage). Gaussian: samples over a square two pixels wide, denser towards the centre as a Gaussian
// weighs (standard deviation 0.4 px, less its value at 1 px so that it falls to 0 there, separable): softer edges and
// less moire, the usual default of production renderers.
enum class PixelFilter { Box, Gaussian };
// How the compute rasterizer's workgroup gets its cluster's vertices on screen (both cover the same pixels, bit for bit).
// Shared: each vertex transformed once into shared memory, then a barrier, then one thread per triangle, in workgroups of
// 128 on a GPU and of one subgroup on a CPU device (lavapipe: a barrier in a larger workgroup switches between its
// subgroups as coroutines). PerTriangle: each thread transforms its own triangle's three corners, no shared memory, no
// barrier, 16 threads (8-16 % dearer on lavapipe; docs/benchmarks.md). Auto: Shared; $TESSERA_RASTER_VERTICES (shared,
// per-triangle) overrides Auto, for tests and measurements.
enum class RasterVertices { Auto, Shared, PerTriangle };
const char* visualize_name(Visualize mode);

struct RenderSettings {
    uint32_t width = 960, height = 540;
    std::array<float, 4> background{0, 0, 0, 0};  // linear RGBA where nothing is drawn
    // The DAG cut: a cluster is drawn when its simplification error projects to at most this many pixels (and its
    // parent's to more). 0 draws the source triangles wherever the builder's simplification lost anything.
    float pixelError = 1.0f;
    bool lod = true;  // false: every source triangle (level 0) is drawn, the DAG off (the full-detail reference);
                      // with RasterMode::Auto they all go through hardware raster (the r.Nanite 0 baseline)
    Visualize visualize = Visualize::None;
    RasterMode raster = RasterMode::Auto;
    RasterVertices rasterVertices = RasterVertices::Auto;
    // Auto mode: clusters whose triangles are estimated to cover less than this many pixels each go to the compute
    // rasterizer. Measured per device (`tessera bench raster --record`); this default is the largest size at which
    // neither measured device lost with it (docs/benchmarks.md, session 36: lavapipe on a 2-core AMD EPYC host won
    // with compute raster through 512 px, an H100 through 128 and tied at 256).
    float softwareRasterArea = 256.0f;
    // Occlusion culling, which changes counts and time, never the image. Clusters whose triangles all face away from
    // the camera are culled (normal cones; single-sided instances whose transform keeps angles). Two-pass HZB
    // culling: instances and clusters hidden behind what the previous frame drew are deferred, then tested against a
    // depth pyramid (HZB) of what this frame drew first; the first frame of a view (or after instances move) has no
    // previous frame to ask. Off with lod=false, which draws every source triangle.
    bool occlusion = true;
    // Occlusion where it pays. A frame whose occlusion culled less than this share of its work (1 minus the product of
    // the shares of instances, clusters and displaced patches it kept) lets the next kOcclusionRest frames of its renderer run
    // without it (no HZB, no post pass, no deferral; stats `occlusion_rested`), then tries again. 0: every frame.
    // Negative: the device's default, kCpuOcclusionMinimumCulled on a CPU device, where the HZB of a 1080p frame costs
    // about a quarter of a dense frame's culling and rasterization (lavapipe: 15.5 ms against 60-70), 0 on a GPU, where it
    // costs little.
    float occlusionMinimumCulled = -1.0f;
    // No frame follows on this renderer (a batch render's last): the frame builds no depth pyramid of what it drew for the
    // next frame's occlusion to test against (stats `hzb_builds`; a 1080p pyramid cost lavapipe 15-18 ms). Its own
    // two-pass occlusion is unchanged, and so is the image; a frame after it tests nothing, as a first frame.
    bool lastFrame = false;
    static constexpr float kCpuOcclusionMinimumCulled = 0.25f;
    static constexpr uint32_t kOcclusionRest = 15;
    // The cut skips whole blocks of clusters that cannot be drawn (GpuCutBlock, renderer/cut_blocks.cpp). Blocks change the clusters tested and
    // the time, never the cut: false tests each cluster of the levels not ruled out, to compare (tests, measurements).
    bool cutBlocks = true;
    // Up to `cutParts` workgroups (at most TS_CUT_MOST_PARTS) share one instance's cut, one per `cutPartClusters`
    // clusters of the levels its distance leaves in the cut; 0: the device's (renderer.cpp cut_parts_word). The same cut
    // either way: a large mesh seen from close by walks tens of thousands of clusters, which one workgroup (one GPU
    // multiprocessor, one lavapipe thread) walked alone. Set for tests and measurements.
    uint32_t cutParts = 0, cutPartClusters = 0;
    // The passes read the scene's streams (instances, clusters, vertices, triangles, the visibility buffer...) through
    // texel buffer views where every one fits the device's maxTexelBufferElements, else through their addresses. The
    // same image either way; on lavapipe views are much faster (shared.h TS_SPEC_TEXEL_VIEWS). False: addresses only,
    // to compare (tests, measurements).
    bool texelViews = true;
    // With texel views, the AOVs are stored through the output's storage buffer binding where it fits the device's
    // maxStorageBufferRange, else through its address (shared.h TS_SPEC_OUTPUT_BINDING). False: through the address, to
    // compare (tests).
    bool outputBinding = true;
    // Displaced surfaces are diced into micro-triangles whose edges project to about this many pixels.
    float dicingRate = 1.0f;
    // Anti-aliasing: each pixel's colour is the filtered mean of this many samples (`pixelFilter`), each a whole frame
    // drawn with the camera's window shifted by a sample offset (pixel_sample_offset). The first sample is the pixel's
    // centre, and the other AOVs (depth, normal, ids) are that sample's: ids stay exact, never blends of two.
    uint32_t pixelSamples = 1;  // 1 to kMostPixelSamples
    PixelFilter pixelFilter = PixelFilter::Box;
    // Where a frame's one sample lies in each pixel, in pixels from its centre (x right, y down); the samples'
    // offsets add to it. For tests and for callers that accumulate samples themselves.
    std::array<float, 2> pixelOffset{0.0f, 0.0f};
};

// The offset of sample `index` from the pixel's centre, in pixels, within the filter's support: sample 0 is the centre,
// the later ones the Halton sequence in bases 2 and 3 (shifted), spread as the filter weighs (evenly over the box's
// square; for the Gaussian, through its inverse cumulative distribution on each axis), so that any first n samples
// stand for the filter evenly and their plain mean is the filtered pixel.
std::array<float, 2> pixel_sample_offset(uint32_t index, PixelFilter filter = PixelFilter::Box);

struct FrameStats {
    uint64_t instances = 0;         // every drawn copy of every mesh (batches expanded)
    uint32_t visibleInstances = 0;
    uint32_t instanceBatches = 0;   // InstanceDescs: a plain mesh or native instance is one, a PointInstancer prototype one
    uint64_t instanceBytes = 0;     // GPU memory that grows with the instance count (transforms, batch words, lists)
    uint64_t clusters = 0;  // level 0 of every instance (the source)
    uint32_t visibleClusters = 0;
    uint64_t candidateClusters = 0;  // clusters the cut tested one by one (in the blocks that levels and block bounds did not rule out)
    uint64_t sourceTriangles = 0;   // every triangle of every instance
    uint64_t visibleTriangles = 0;  // triangles of the cut's visible clusters
    uint64_t swTriangles = 0, hwTriangles = 0;  // of those, drawn by the compute rasterizer and by hardware raster
    uint32_t swClusters = 0;
    uint32_t swLargeClusters = 0;   // of those, clusters not certainly small on screen: drawn by the variant with 64-bit edge functions
    bool swSharedVertices = false;  // the compute rasterizer's variant this frame: RasterVertices::Shared (else PerTriangle)
    uint32_t cullGroupSize = 0;     // the cull's workgroup size on this device (TS_CULL_GROUP_SIZE on a GPU, one subgroup on a CPU)
    uint32_t swRasterGroupSize = 0; // the compute rasterizer's workgroup size this frame (by device and variant)
    uint32_t shadePixelsPerThread = 0;   // pixels each resolve thread shades on this device (TS_SPEC_SHADE_PIXELS_PER_THREAD)
    bool texelViews = false;        // the passes read the streams through texel views (RenderSettings::texelViews)
    bool outputBinding = false;     // and store the AOVs through the output's binding (RenderSettings::outputBinding)
    bool aovsImported = false;      // the AOVs went straight into the images' memory, not through the readback buffer
    uint32_t aovImportsMade = 0;    // of their memory, blocks imported anew this frame (the renderer keeps its imports
                                    // while frames reuse the blocks; a CPU device's output is imported every frame)
    uint32_t pixelSamples = 1;      // frames drawn for this image (RenderSettings::pixelSamples; 1 without a colour AOV,
                                    // the only one averaged): the times below add them up
    bool sampleSumsOnDevice = false; // with several, the device summed their colours (a GPU), else the host
    uint32_t overflowRedraws = 0;   // times the visible-cluster list was too small and the frame was redrawn
    uint32_t visibleClusterCapacity = 0;
    bool occlusionTested = false;       // the frame had a previous frame's HZB to test against
    bool occlusionRested = false;       // occlusion was on but skipped: it culled too little a few frames before
                                        // (RenderSettings::occlusionMinimumCulled)
    uint32_t occludedInstances = 0, occludedClusters = 0;  // found hidden by the post pass
    uint32_t postPassClusters = 0;      // clusters drawn by the post pass (hidden last frame, visible now)
    uint32_t hzbBuilds = 0;             // HZB builds: after the main pass if it deferred anything, and at the end unless
                                        // the post pass drew nothing (the HZB after the main pass is then the frame's)
    uint32_t backfaceClusters = 0;      // clusters culled because all their triangles face away
    uint32_t shadingBins = 0;           // bins with visible pixels, each shaded by a dispatch of its own: one a material, or
                                        // up to three for a displaced one (its triangles, kept and diced micro-triangles);
                                        // 1 where one dispatch read every pixel (pixelMaterials or a one-bin frame)
    uint32_t coveredPixels = 0;         // pixels a surface covers (each shaded once for all the frame's AOVs)
    // Where resolve found its pixels: "listed" (classify's bins), or, in a one-bin frame, every pixel of the frame read,
    // "in place" (the frame before covered most pixels) or "packed" (each subgroup's covered pixels first, a CPU device).
    const char* resolvePixels = "listed";
    bool pixelMaterials = false;        // a frame of several materials whose pixels each read their own (a CPU device:
                                        // no classify, no bins; $TESSERA_MATERIAL_BINS=1 classifies them as a GPU does)
    uint32_t textures = 0;              // images in the texture pool
    uint64_t geometryBytes = 0;         // GPU memory of the meshes: clusters, levels, cut blocks, vertex streams, triangles
    uint64_t geometryUploadBytes = 0;   // of those, written by this frame's geometry upload: the meshes added since the last (0 without one)
    uint64_t hostMeshBytes = 0;         // the meshes' streams the host still holds (GpuScene::release_streams)
    uint32_t displacedMeshesPrepared = 0;  // meshes this frame made displacement normals, UV seams and UV boxes for: once
                                           // a mesh is drawn displaced, then kept (0 in a frame that uploads no geometry)
    uint32_t uploadSubmissions = 0;     // submissions this frame's uploads took: 1 where anything went through staging (a
                                        // discrete GPU), 0 where the host wrote the device's memory or nothing changed;
                                        // more for a stream grown on the device or staging past its bound (64 MiB)
    std::vector<std::string> errors;    // meshes this frame could not draw, and why (streams that could not be reloaded)
    uint64_t textureBytes = 0;          // GPU memory of the texture pool and texture slots (0 without textures)
    // Runtime tessellation (0 without displaced materials): clusters and triangles diced, patches, micro-triangles,
    // and the GPU memory of the patch lists and displacement normals.
    uint32_t tessellatedClusters = 0, patches = 0;
    uint32_t computePatches = 0;  // of the patches, those the compute rasterizer drew (the rest: hardware raster)
    uint32_t deferredPatches = 0; // patches the previous frame's HZB hid, left to the post pass
    uint32_t occludedPatches = 0; // patches the post pass found hidden (not drawn)
    uint32_t keptMicroPixels = 0;  // pixels of micro-triangles resolve read from the points the patch rasterizer kept
    uint32_t dicedMicroPixels = 0; // pixels of micro-triangles resolve diced again (hardware-rastered patch, vertex
                                   // colours, or a full point pool)
    uint64_t tessellatedTriangles = 0, microTriangles = 0;
    uint64_t tessellationBytes = 0;
    // GPU memory of the per-pixel buffers: the visibility buffer, the AOV output, the material bins' pixel list (only once
    // a frame lists its pixels), the HZB, the overdraw view's counts, pixel sample sums while a render samples.
    uint64_t pixelBytes = 0;
    // GPU time per pass, both occlusion passes added (rasterMs: hardware); hzbMs: building the depth pyramids; classifyMs:
    // the material bins (classify and bins); resolveMs: backgrounds and shading; readbackMs: copying the AOVs to host
    // memory (a GPU's; on a CPU device resolve writes each AOV into its image, or where it is read; past the eighth AOV
    // in resolveMs).
    double cullMs = 0, softwareRasterMs = 0, rasterMs = 0, tessellationMs = 0, hzbMs = 0, classifyMs = 0, resolveMs = 0, readbackMs = 0;
    double uploadMs = 0;  // CPU time spent uploading what changed in the scene (instances, geometry, materials) this frame
    // Wall time on the CPU: recording the frame's commands, from then until the GPU finished them (submission and wait),
    // and the whole render call (upload, recording, wait, readback). A redrawn frame counts both tries.
    double cpuRecordMs = 0, cpuWaitMs = 0, cpuFrameMs = 0;
};

// The GPU scene: meshes shared by any number of instances. Changes are uploaded by the next render.
class GpuScene {
public:
    // Gives a mesh's streams back (from the mesh cache, say); throws where it cannot.
    using MeshReload = std::function<std::shared_ptr<const BuiltMesh>()>;
    // `reload`: where the mesh can be had again, so that the scene may let its streams go once a renderer holds them
    // on the GPU (release_streams); without one the scene keeps them.
    uint32_t add_mesh(std::shared_ptr<const BuiltMesh> mesh, MeshReload reload = {});
    void remove_mesh(uint32_t handle);
    // Lets the mesh's streams go, keeping its description (without_streams), where it can be reloaded; mesh() then
    // returns the description and full_mesh() reloads the streams (and keeps them again).
    void release_streams(uint32_t handle);
    // The mesh with its streams: held, or reloaded now.
    const std::shared_ptr<const BuiltMesh>& full_mesh(uint32_t handle);
    bool holds_streams(uint32_t handle) const { return !released_.at(handle); }
    uint64_t held_stream_bytes() const { return heldBytes_; }  // of the meshes whose streams it holds
    // Changes whenever the handle's mesh does (a released or reloaded mesh is the same mesh).
    uint64_t mesh_serial(uint32_t handle) const { return serials_.at(handle); }
    uint32_t add_material(const MaterialDesc& material);
    // For meshes whose triangles carry material slots: slot s draws with material handle `materials[s]`. Instances of
    // one prim share a table.
    uint32_t add_material_table(std::span<const uint32_t> materials);
    void clear_materials();  // and the tables
    void set_instances(std::vector<InstanceDesc> instances);
    void set_instance_transform(size_t index, const Matrix4d& transform);  // one batch moved (a live edit)
    void set_lights(std::vector<LightDesc> lights);

    const std::vector<InstanceDesc>& instances() const { return instances_; }  // batches
    uint64_t instance_count() const;  // drawn copies, batches expanded
    const std::vector<LightDesc>& lights() const { return lights_; }
    const std::shared_ptr<const BuiltMesh>& mesh(uint32_t handle) const { return meshes_.at(handle); }
    size_t mesh_count() const { return meshes_.size(); }
    // Loads materials' textures (TextureStore::load_slots), sharing images between materials.
    TextureStore& textures() { return textures_; }

private:
    friend class Renderer;
    std::vector<std::shared_ptr<const BuiltMesh>> meshes_;  // null where removed; the description alone where released
    std::vector<MeshReload> reloads_;
    std::vector<char> released_;
    // Mesh serials and the scene's own number come from one count of the process: a renderer that drew another scene
    // (even one since destroyed, whose memory this scene took over) tells this one and its meshes from those.
    std::vector<uint64_t> serials_;
    uint64_t id_ = next_serial();
    static uint64_t next_serial();
    uint64_t heldBytes_ = 0;  // held_stream_bytes, kept as meshes come, go, are released and reloaded
    std::vector<uint32_t> freeMeshes_;
    std::vector<MaterialDesc> materials_;
    std::vector<uint32_t> materialTables_;  // each table: a header word (shaders/frame.h instance_displacement), then its entries
    std::vector<std::array<uint32_t, 2>> materialTableRanges_;  // first entry and size of each table
    std::vector<InstanceDesc> instances_;
    std::vector<LightDesc> lights_;
    TextureStore textures_;
    // Bumped on every change; each renderer uploads what moved past the versions it last saw.
    uint64_t geometryVersion_ = 1, instancesVersion_ = 1, materialsVersion_ = 1;
};

class Renderer {
public:
    explicit Renderer(Device& device);
    ~Renderer();
    Renderer(const Renderer&) = delete;
    Renderer& operator=(const Renderer&) = delete;

    // Draws the scene from the camera into the visibility buffer and resolves each requested AOV; with several pixel
    // samples, once per sample, the colour averaged.
    std::vector<Image> render(GpuScene& scene, const CameraDesc& camera, const RenderSettings& settings,
                              const std::vector<Aov>& aovs, FrameStats* stats = nullptr);

    // Pins the visible-cluster list's starting size (by default it follows the scene's cluster count, up to 4 M);
    // tests use tiny values to force the overflow path.
    void set_visible_cluster_capacity(uint32_t capacity);
    // The same for the patch list of runtime tessellation (by default 64 K patches to start).
    void set_patch_capacity(uint32_t capacity);
    // The kept-point pool's size for the next frame (by default 256 K points to start): patches beyond it are diced
    // again by resolve. Tests use tiny values to force that path.
    void set_point_capacity(uint32_t points);

    Device& device() { return device_; }

private:
    // One of an image's pixel samples, and how many it takes: the first starts the colours' sum on the device, the last
    // hands back their mean as its colour.
    struct SampleStep {
        uint32_t index, count;
    };
    std::vector<Image> render_sample(GpuScene& scene, const CameraDesc& camera, const RenderSettings& settings,
                                     const std::vector<Aov>& aovs, FrameStats* stats, const SampleStep* sample = nullptr);
    struct Impl;
    Device& device_;
    std::unique_ptr<Impl> impl_;
};

}  // namespace tessera
