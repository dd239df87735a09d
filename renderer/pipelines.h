// Internal to the renderer: its compiled pipelines on one device, shared by every Renderer on that device.
// Compiling is most of what starting a renderer costs (on lavapipe, which keeps no pipeline cache between processes,
// about 0.2 CPU s for the pipelines every frame uses, made in the background while the stage loads, and 25-35 ms for
// each resolve variant of clusters' untextured triangles a scene asks for, more for displaced ones), so a process that
// opens many stages, or a test suite, pays it once per device (Device::shared_state), not once per session. Pipelines
// are immutable once made; the variants a frame needs are made when it first needs them, under `mutex`, which a render
// holds throughout.
#pragma once

#include "shared.h"
#include "tessera/device.h"

#include <array>
#include <cstddef>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <span>
#include <vector>

namespace tessera {

struct PushConstants {  // matches `Push` in shaders/frame.h
    uint32_t aov;
    uint32_t step;       // cull step (TS_CULL_*) or HZB level
    gpu::address hzb;    // the HZB the step tests against or builds
};

// Resolve's: the same, then its bin's material (a constant for all the dispatch's pixels, which a CPU device would
// otherwise load pixel by pixel).
struct ResolvePushConstants {
    PushConstants pass;
    gpu::GpuMaterial material;
};
static_assert(offsetof(ResolvePushConstants, material) == 16 && sizeof(ResolvePushConstants) == 128, "layout of Push in shaders/frame.h");

// A pipeline variant's specialization constants (shared.h TS_SPEC_*), named: each at the value the shaders declare by
// default unless set. A shader ignores the ones it does not declare.
struct Specialization {
    bool textures = false;                 // TS_SPEC_TEXTURES: resolve's textured materials, the rasterizers' opacity masks
    uint32_t pixels = TS_BIN_TRIANGLES;    // TS_SPEC_DISPLACEMENT: resolve's kind of pixels (TS_BIN_*)
    bool areaLights = false;               // TS_SPEC_AREA_LIGHTS: resolve, frames with area lights or a textured dome
    bool vertexInputs = false;             // TS_SPEC_VERTEX_INPUTS: resolve, materials with inputs from the vertex channel
    uint32_t outputs = 1;                  // TS_SPEC_OUTPUT: the AOVs resolve writes, each into its slice (shared.h)
    bool ownCorners = false;               // TS_SPEC_OWN_CORNERS: the compute rasterizer's variant (RasterVertices)
    uint32_t rasterGroupSize = TS_SW_RASTER_GROUP_SIZE;  // TS_SPEC_RASTER_GROUP_SIZE: its workgroup, or the patch rasterizer's
    bool largeTriangles = false;           // TS_SPEC_LARGE_TRIANGLES: the compute rasterizer's back of the software list
    bool doubleSided = false;              // TS_SPEC_DOUBLE_SIDED: hardware raster without face culling
    uint32_t cullGroupSize = TS_CULL_GROUP_SIZE;  // TS_SPEC_CULL_GROUP_SIZE
    uint32_t step = 0;                     // TS_SPEC_STEP: classify's and the cull's step
    bool countFragments = false;           // TS_SPEC_COUNT_FRAGMENTS: the rasterizers' for the overdraw view
    uint32_t textureKinds = TS_TEXTURE_KINDS_ALL;  // TS_SPEC_TEXTURE_KINDS: what a textured resolve's textures need
    uint32_t lightCounts = 0;              // TS_SPEC_LIGHT_COUNTS: resolve's shading, the frame's lights
    uint32_t instanceFlags = TS_SPECIALIZED_INSTANCE_FLAGS;  // TS_SPEC_INSTANCE_FLAGS: the frame's, for the cull, classify and
                                                             // resolve with pixel materials
    uint32_t pixelSource = TS_PIXELS_LISTED;  // TS_SPEC_PIXEL_SOURCE: where resolve finds its pixels (TS_PIXELS_*)
    bool pixelMaterials = false;           // TS_SPEC_PIXEL_MATERIALS: resolve's pixels read their own materials
    bool operator==(const Specialization&) const = default;
};

struct Pipelines {
    // The set for `device` (made by the first renderer on it), with the choices the environment makes now
    // ($TESSERA_CULL_GROUP_SIZE, $TESSERA_SW_RASTER_GROUP_SIZE and $TESSERA_SHADE_PIXELS_PER_THREAD select different
    // sets), reading the scene's streams through texel views or through their addresses (TS_SPEC_TEXEL_VIEWS: a frame
    // whose streams outgrow the device's views takes the second).
    static std::shared_ptr<Pipelines> for_device(Device& device, bool texelViews, bool outputBinding);

    // Workgroup sizes chosen per device: the cull's, the cluster rasterizer's (shared vertices) and the patch rasterizer's.
    struct GroupSizes {
        uint32_t cull, swRaster, dice;
    };
    Pipelines(Device& device, GroupSizes sizes, uint32_t shadePixelsPerThread, bool texelViews, bool outputBinding);
    ~Pipelines();
    Pipelines(const Pipelines&) = delete;
    Pipelines& operator=(const Pipelines&) = delete;

    Device& device;
    std::mutex mutex;  // held by a render: it may make variants

    // Every pipeline's layout: set 0 holds the frame's constants (GpuFrame) as a uniform buffer and the texel views of
    // its streams (shared.h TS_BINDING_FRAME, TS_VIEW_*; each renderer has its own set), and ResolvePushConstants.
    VkDescriptorSetLayout frameSetLayout = VK_NULL_HANDLE;
    VkPipelineLayout layout = VK_NULL_HANDLE;
    const uint32_t cullGroupSize;         // the cull's workgroup size, chosen for the device (TS_SPEC_CULL_GROUP_SIZE)
    const uint32_t swRasterGroupSize;     // the compute rasterizer's, shared-vertices variant (TS_SPEC_RASTER_GROUP_SIZE)
    const uint32_t diceGroupSize;         // the patch rasterizer's (dice.comp.glsl, TS_SPEC_RASTER_GROUP_SIZE)
    const uint32_t shadePixelsPerThread;  // pixels each resolve thread shades (TS_SPEC_SHADE_PIXELS_PER_THREAD)
    const bool texelViews;                // every pipeline reads the streams through texel views (TS_SPEC_TEXEL_VIEWS)
    const bool outputBinding;             // and stores the AOV output through its binding (TS_SPEC_OUTPUT_BINDING)

    VkPipeline hzb = VK_NULL_HANDLE, bins = VK_NULL_HANDLE;

    // The cull's and classify's pipelines for one step (TS_CULL_*, TS_CLASSIFY_*), in the variant for the instance flags
    // of TS_SPECIALIZED_INSTANCE_FLAGS some instance of the frame carries (TS_SPEC_INSTANCE_FLAGS). The variant without
    // any of them is made with the set; the others for a frame that needs them (make_for_frame), or on first use.
    VkPipeline cull_step(uint32_t step, uint32_t instanceFlags);
    VkPipeline classify_step(uint32_t step, uint32_t instanceFlags);
    // The rasterizers' variants, made on first use (a few tens of ms each on lavapipe, cold): `masks` with texture code
    // (TS_SPEC_TEXTURES) for frames with opacity masks; `countFragments` (TS_SPEC_COUNT_FRAGMENTS) for the overdraw
    // view only, whose count per fragment, present but not run, cost lavapipe 6 % of the compute raster.
    // The compute rasterizer (RasterVertices: `ownCorners`; `largeTriangles`: the back of the software list).
    VkPipeline software_raster(bool masks, bool ownCorners, bool largeTriangles, bool countFragments);
    // Its workgroup size for a variant: TS_SW_RASTER_OWN_CORNERS_GROUP_SIZE with own corners, else swRasterGroupSize.
    uint32_t software_raster_group_size(bool ownCorners) const;
    // Hardware raster of clusters; single-sided instances' variant culls back faces (TS_SPEC_DOUBLE_SIDED).
    VkPipeline hardware_raster(bool masks, bool doubleSided, bool countFragments);
    // Runtime tessellation, made when a scene first displaces: the pass that makes the patches, and the patches diced
    // and scanned in compute or drawn by hardware raster.
    VkPipeline tessellate();
    VkPipeline dice(bool masks, bool countFragments);
    VkPipeline patch_raster(bool masks, bool countFragments);
    // Resolve's arguments for one bin. Textures, area lights and vertex inputs only matter to shading; `textureKinds`
    // (TS_TEXTURE_KIND_* bits) is what the textures it reads need (a displacement texture too, read where it dices
    // micro-triangles again); `lightCounts` the frame's lights (TS_SPEC_LIGHT_COUNTS).
    struct ResolveVariant {
        bool textured = false;
        uint32_t textureKinds = 0, pixels = TS_BIN_TRIANGLES;
        bool areaLights = false, vertexInputs = false;
        uint32_t outputs = 1, lightCounts = 0;  // TS_SPEC_OUTPUT: the frame's AOVs (default: the colour alone, shaded)
        uint32_t pixelSource = TS_PIXELS_LISTED;  // its bin's list, or every pixel of a one-bin frame (TS_SPEC_PIXEL_SOURCE)
        bool pixelMaterials = false;  // each pixel reads its material (TS_SPEC_PIXEL_MATERIALS), every material's features
        uint32_t instanceFlags = TS_SPECIALIZED_INSTANCE_FLAGS;  // the frame's (TS_SPEC_INSTANCE_FLAGS): pixel materials only
    };
    // Resolve's variant for a bin, made on first use.
    VkPipeline resolve_variant(const ResolveVariant& variant);
    // What a frame draws with: the rasterizers' variants for its masks and views, tessellation's passes where it
    // displaces, and the resolve variants of its bins.
    struct FrameNeeds {
        bool masks = false, ownCorners = false, countFragments = false, displaced = false;
        uint32_t instanceFlags = 0;  // of TS_SPECIALIZED_INSTANCE_FLAGS
        bool oneBin = true;          // classify's one-bin step, else its count and scatter steps
        std::vector<ResolveVariant> resolves;
    };
    // Makes those of `needs` not made yet, together on the host's threads, before the frame records: a first frame of
    // many materials, or with masks, made each in turn (on two cores 1.1 s of the textures test stage's 2.0 s first
    // frame). Nothing to make, no thread. While the constructor's background set is still being made, the frame's
    // resolve variants are made meanwhile, then the rest once that set is done.
    void make_for_frame(const FrameNeeds& needs);
    // The background of a textured dome light, made on first use.
    VkPipeline textured_background();
    // The sum of an image's pixel samples (samples.comp.glsl), made on first use.
    VkPipeline pixel_samples();

    // RasterVertices::Auto: shared vertices; $TESSERA_RASTER_VERTICES (shared, per-triangle) overrides that, for tests
    // and measurements.
    bool default_own_corners() const;

private:
    // A pipeline per step (TS_CULL_*, TS_CLASSIFY_*) and frame instance flags (instance_flags_variant).
    VkPipeline cull[4][4] = {};
    VkPipeline classify[3][4] = {};
    // The rasterizers' variants, by [masks][countFragments] and, for the compute rasterizer, [own corners][large
    // triangles]; for hardware raster, [double-sided].
    VkPipeline rasterSoftware[2][2][2][2] = {};
    VkPipeline rasterHardware[2][2][2] = {};
    VkPipeline backgroundTextured = VK_NULL_HANDLE, pixelSamples = VK_NULL_HANDLE, tessellatePatches = VK_NULL_HANDLE, diceVariants[2][2] = {}, patchRasterVariants[2][2] = {};
    // Resolve's variants by TS_SPEC_TEXTURE_KINDS | TS_SPEC_TEXTURES << 8 | TS_SPEC_DISPLACEMENT << 9 |
    // TS_SPEC_AREA_LIGHTS << 11 | TS_SPEC_VERTEX_INPUTS << 12 (what its textures need, textured materials, displaced
    // materials, frames with area lights or a textured dome, materials with vertex inputs), TS_SPEC_LIGHT_COUNTS << 16,
    // TS_SPEC_PIXEL_SOURCE << 32, TS_SPEC_OUTPUT (the AOVs it writes) << 34, TS_SPEC_PIXEL_MATERIALS << 59 and, with pixel
    // materials, the frame's instance flags (instance_flags_variant) << 60: on lavapipe each one's code, present but not
    // run, cost every pixel of the frames that do not need it.
    std::map<uint64_t, VkPipeline> resolveVariants;
    // The constructor's set, made in the background (wait_for_startup).
    std::future<void> startup;
    // Waits for that set and rethrows its first failure: make_for_frame calls it, and nothing reads a pipeline before a
    // frame's make_for_frame.
    void wait_for_startup();

    VkPipeline compute_pipeline(std::span<const uint32_t> code, const Specialization& specialization = {});
    // Resolve's variant's key in resolveVariants and its specialization (the arguments that do not matter to it cleared).
    static std::pair<uint64_t, Specialization> resolve_key(ResolveVariant variant);
    // Resolve's SPIR-V module for that specialization: one per kind of pixels and texturing (shaders/CMakeLists.txt).
    static std::span<const uint32_t> resolve_module(const Specialization& specialization);
    // Runs the tasks on every core (tessera/parallel.h: a driver compiles a pipeline on the calling thread); each task
    // writes a slot of its own. Rethrows the exception of the first task that threw.
    static void run_on_threads(const std::vector<std::function<void()>>& tasks);
    // Hardware raster of clusters or of tessellation's patches.
    VkPipeline graphics_pipeline(bool patches, const Specialization& specialization);
};

}  // namespace tessera
