// The renderer's pipelines on one device (pipelines.h): made once per device and choice of sizes, shared by renderers.
#include "pipelines.h"

#include "tessera/parallel.h"

#include "spirv/background_comp.h"
#include "spirv/bins_comp.h"
#include "spirv/classify_comp.h"
#include "spirv/cull_main_comp.h"
#include "spirv/cull_main_instances_comp.h"
#include "spirv/cull_post_comp.h"
#include "spirv/cull_post_instances_comp.h"
#include "spirv/dice_comp.h"
#include "spirv/dice_masked_comp.h"
#include "spirv/hzb_comp.h"
#include "spirv/patch_frag.h"
#include "spirv/patch_masked_frag.h"
#include "spirv/patch_vert.h"
#include "spirv/raster_frag.h"
#include "spirv/raster_masked_frag.h"
#include "spirv/raster_sw_comp.h"
#include "spirv/raster_sw_masked_comp.h"
#include "spirv/raster_vert.h"
#include "spirv/resolve_diced_micro_comp.h"
#include "spirv/resolve_kept_micro_comp.h"
#include "spirv/resolve_textured_kept_micro_comp.h"
#include "spirv/resolve_textured_triangles_comp.h"
#include "spirv/resolve_triangles_comp.h"
#include "spirv/samples_comp.h"
#include "spirv/tessellate_comp.h"

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <future>
#include <vector>
#include <span>
#include <stdexcept>
#include <string>

namespace tessera {

namespace {

// A workgroup size the environment variable `name` forces (8, 16, ... up to `largest`), for tests and measurements;
// 0 when it is not set.
uint32_t forced_group_size(const char* name, uint32_t largest) {
    const char* forced = std::getenv(name);
    if (!forced || !*forced) return 0;
    for (uint32_t size = 8; size <= largest; size *= 2)
        if (std::to_string(size) == forced) return size;
    throw std::invalid_argument(std::string(name) + "='" + forced + "': expected a power of two from 8 to " + std::to_string(largest));
}

// A CPU device's workgroup for the passes that load per-workgroup inputs (the cull, the compute rasterizers of clusters
// and of patches): one subgroup. lavapipe runs a workgroup as coroutines of one subgroup each (8 invocations at 256 bits), every one of which
// loads those inputs again and switches to the next at a barrier (docs/benchmarks.md).
uint32_t one_subgroup(const Device& device, uint32_t largest) { return std::clamp(device.subgroup_size(), 1u, largest); }

// The cull's workgroup size: one subgroup on a CPU device, TS_CULL_GROUP_SIZE on a GPU; $TESSERA_CULL_GROUP_SIZE
// overrides that.
uint32_t default_cull_group_size(const Device& device) {
    if (uint32_t forced = forced_group_size("TESSERA_CULL_GROUP_SIZE", 256)) return forced;
    return device.is_software() ? one_subgroup(device, TS_CULL_GROUP_SIZE) : TS_CULL_GROUP_SIZE;
}

// A compute rasterizer's workgroup size (the cluster rasterizer's shared-vertices variant: `gpuSize`
// TS_SW_RASTER_GROUP_SIZE; the patch rasterizer: TS_DICE_GROUP_SIZE): one subgroup on a CPU device, `gpuSize` on a GPU;
// $TESSERA_SW_RASTER_GROUP_SIZE forces one size for both.
uint32_t default_raster_group_size(const Device& device, uint32_t gpuSize) {
    if (uint32_t forced = forced_group_size("TESSERA_SW_RASTER_GROUP_SIZE", TS_SW_RASTER_GROUP_SIZE)) return forced;
    return device.is_software() ? one_subgroup(device, gpuSize) : gpuSize;
}

// Pixels each resolve thread shades: TS_CPU_SHADE_PIXELS_PER_THREAD on a CPU device, 1 on a GPU;
// $TESSERA_SHADE_PIXELS_PER_THREAD (1 to 64) overrides that, for tests and measurements.
uint32_t default_shade_pixels_per_thread(const Device& device) {
    if (const char* forced = std::getenv("TESSERA_SHADE_PIXELS_PER_THREAD"); forced && *forced) {
        for (uint32_t count = 1; count <= 64; ++count)
            if (std::to_string(count) == forced) return count;
        throw std::invalid_argument(std::string("TESSERA_SHADE_PIXELS_PER_THREAD='") + forced + "': expected a whole number from 1 to 64");
    }
    return device.is_software() ? TS_CPU_SHADE_PIXELS_PER_THREAD : 1u;
}

// A pass's module with or without the textured opacity masks' code (shaders/CMakeLists.txt builds both).
std::span<const uint32_t> with_masks(bool masks, std::span<const uint32_t> plain, std::span<const uint32_t> masked) { return masks ? masked : plain; }

VkShaderModule create_module(VkDevice device, std::span<const uint32_t> code) {
    VkShaderModuleCreateInfo info{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
    info.codeSize = code.size_bytes();
    info.pCode = code.data();
    VkShaderModule module;
    check_vk(vkCreateShaderModule(device, &info, nullptr, &module), "vkCreateShaderModule");
    return module;
}

// The index of a frame's instance flags (TS_SPEC_INSTANCE_FLAGS) among the cull's and classify's variants.
uint32_t instance_flags_variant(uint32_t flags) {
    return ((flags & TS_INSTANCE_DISPLACED) ? 1u : 0u) | ((flags & TS_INSTANCE_MATERIAL_SLOTS) ? 2u : 0u);
}

// A Specialization as Vulkan takes it, with what is the same for every pipeline of a set (the pixels each resolve thread
// shades, TS_SPEC_SHADE_PIXELS_PER_THREAD, reads through texel views, TS_SPEC_TEXEL_VIEWS, and stores the AOV output
// through its binding, TS_SPEC_OUTPUT_BINDING).
struct SpecializationInfo {
    uint32_t values[20];
    VkSpecializationMapEntry entries[20] = {{TS_SPEC_TEXTURES, 0, 4}, {TS_SPEC_DISPLACEMENT, 4, 4}, {TS_SPEC_AREA_LIGHTS, 8, 4}, {TS_SPEC_OUTPUT, 12, 4},
                                           {TS_SPEC_OWN_CORNERS, 16, 4}, {TS_SPEC_RASTER_GROUP_SIZE, 20, 4}, {TS_SPEC_CULL_GROUP_SIZE, 24, 4},
                                           {TS_SPEC_LARGE_TRIANGLES, 28, 4}, {TS_SPEC_DOUBLE_SIDED, 32, 4}, {TS_SPEC_SHADE_PIXELS_PER_THREAD, 36, 4},
                                           {TS_SPEC_STEP, 40, 4}, {TS_SPEC_VERTEX_INPUTS, 44, 4}, {TS_SPEC_COUNT_FRAGMENTS, 48, 4},
                                           {TS_SPEC_TEXEL_VIEWS, 52, 4}, {TS_SPEC_TEXTURE_KINDS, 56, 4}, {TS_SPEC_LIGHT_COUNTS, 60, 4}, {TS_SPEC_OUTPUT_BINDING, 64, 4},
                                           {TS_SPEC_INSTANCE_FLAGS, 68, 4}, {TS_SPEC_PIXEL_SOURCE, 72, 4}, {TS_SPEC_PIXEL_MATERIALS, 76, 4}};
    VkSpecializationInfo info{20, entries, sizeof(values), values};
    SpecializationInfo(const Specialization& s, uint32_t shadePixelsPerThread, bool texelViews, bool outputBinding)
        : values{VkBool32(s.textures), s.pixels, VkBool32(s.areaLights), s.outputs, VkBool32(s.ownCorners),
                 s.rasterGroupSize, s.cullGroupSize,
                 VkBool32(s.largeTriangles), VkBool32(s.doubleSided), shadePixelsPerThread, s.step, VkBool32(s.vertexInputs),
                 VkBool32(s.countFragments), VkBool32(texelViews), s.textureKinds, s.lightCounts, VkBool32(outputBinding),
                 s.instanceFlags, s.pixelSource, VkBool32(s.pixelMaterials)} {}
    SpecializationInfo(const SpecializationInfo&) = delete;
};

}  // namespace

std::shared_ptr<Pipelines> Pipelines::for_device(Device& device, bool texelViews, bool outputBinding) {
    const GroupSizes sizes{default_cull_group_size(device), default_raster_group_size(device, TS_SW_RASTER_GROUP_SIZE),
                           default_raster_group_size(device, TS_DICE_GROUP_SIZE)};
    const uint32_t shadePixelsPerThread = default_shade_pixels_per_thread(device);
    const std::string key = "tessera.pipelines cull " + std::to_string(sizes.cull) + " raster " + std::to_string(sizes.swRaster) + " dice " +
                            std::to_string(sizes.dice) + " shade " + std::to_string(shadePixelsPerThread) + (texelViews ? " views" : " addresses") +
                            (outputBinding ? " output binding" : " output address");
    return std::static_pointer_cast<Pipelines>(
        device.shared_state(key, [&] { return std::make_shared<Pipelines>(device, sizes, shadePixelsPerThread, texelViews, outputBinding); }));
}

Pipelines::Pipelines(Device& d, GroupSizes sizes, uint32_t shadePixels, bool views, bool outputBinding)
    : device(d), cullGroupSize(sizes.cull), swRasterGroupSize(sizes.swRaster), diceGroupSize(sizes.dice), shadePixelsPerThread(shadePixels),
      texelViews(views), outputBinding(outputBinding) {
    // The same layout in every set, so a renderer's frame set serves either (identically defined layouts are compatible).
    VkDescriptorSetLayoutBinding bindings[TS_BINDING_COUNT];
    bindings[0] = {TS_BINDING_FRAME, VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER, 1, VK_SHADER_STAGE_ALL, nullptr};
    for (uint32_t view = 1; view <= TS_VIEW_COUNT; ++view) bindings[view] = {view, VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, 1, VK_SHADER_STAGE_ALL, nullptr};
    for (uint32_t slice = 0; slice < TS_MOST_AOVS; ++slice)
        bindings[TS_BINDING_OUTPUT + slice] = {TS_BINDING_OUTPUT + slice, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1, VK_SHADER_STAGE_COMPUTE_BIT, nullptr};
    bindings[TS_BINDING_VISIBILITY] = {TS_BINDING_VISIBILITY, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1,
                                       VK_SHADER_STAGE_COMPUTE_BIT | VK_SHADER_STAGE_FRAGMENT_BIT, nullptr};  // both rasterizers
    static_assert(TS_BINDING_OUTPUT == 1 + TS_VIEW_COUNT, "the frame set's bindings are numbered without gaps");
    VkDescriptorSetLayoutCreateInfo setInfo{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    setInfo.bindingCount = TS_BINDING_COUNT;
    setInfo.pBindings = bindings;
    check_vk(vkCreateDescriptorSetLayout(device.handle(), &setInfo, nullptr, &frameSetLayout), "vkCreateDescriptorSetLayout");
    VkPushConstantRange range{VK_SHADER_STAGE_ALL, 0, sizeof(ResolvePushConstants)};
    VkPipelineLayoutCreateInfo layoutInfo{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    layoutInfo.setLayoutCount = 1;
    layoutInfo.pSetLayouts = &frameSetLayout;
    layoutInfo.pushConstantRangeCount = 1;
    layoutInfo.pPushConstantRanges = &range;
    check_vk(vkCreatePipelineLayout(device.handle(), &layoutInfo, nullptr, &layout), "vkCreatePipelineLayout");

    // What (nearly) every frame needs, made on as many threads as the host has (a driver compiles a pipeline on the
    // calling thread), in the background: the session reads its stage and loads its meshes meanwhile, and the first
    // frame waits for them (wait_for_startup). lavapipe compiles these in about 0.2 CPU s, with no pipeline cache
    // between processes. Resolve is not among them: its variant depends on the scene's lights and materials (the first frame
    // makes the ones it needs), and a guessed one cost a lit batch render 0.6-0.8 s for nothing.
    const bool ownCorners = default_own_corners();
    startup = std::async(std::launch::async, [this, ownCorners] {
        run_on_threads({[&] { cull_step(TS_CULL_MAIN_INSTANCES, 0); },
                        [&] { cull_step(TS_CULL_MAIN, 0); },
                        [&] { cull_step(TS_CULL_POST_INSTANCES, 0); },
                        [&] { cull_step(TS_CULL_POST, 0); },
                        [&] { hzb = compute_pipeline(hzb_comp); },
                        [&] { bins = compute_pipeline(bins_comp); },
                        [&] { classify_step(TS_CLASSIFY_ONE_BIN, 0); },
                        [&] { classify_step(TS_CLASSIFY_COUNT, 0); },
                        [&] { classify_step(TS_CLASSIFY_SCATTER, 0); },
                        [&] { software_raster(false, ownCorners, false, false); },
                        [&] { software_raster(false, ownCorners, true, false); },
                        [&] { hardware_raster(false, false, false); },
                        [&] { hardware_raster(false, true, false); }});
    });
}

void Pipelines::wait_for_startup() {
    if (!startup.valid()) return;
    std::future<void> made = std::move(startup);
    made.get();  // rethrows the first failure; what it left unmade is made on first use (or fails again there)
}

void Pipelines::run_on_threads(const std::vector<std::function<void()>>& tasks) {
    parallel_for_rethrowing(tasks.size(), [&](size_t t) { tasks[t](); });
}

Pipelines::~Pipelines() {
    if (startup.valid()) startup.wait();  // no pipeline destroyed while the background still makes it
    device.wait_idle();
    VkDevice vk = device.handle();
    for (VkPipeline step : std::span(&cull[0][0], sizeof(cull) / sizeof(VkPipeline))) vkDestroyPipeline(vk, step, nullptr);
    vkDestroyPipeline(vk, hzb, nullptr);
    for (VkPipeline step : std::span(&classify[0][0], sizeof(classify) / sizeof(VkPipeline))) vkDestroyPipeline(vk, step, nullptr);
    vkDestroyPipeline(vk, bins, nullptr);
    for (VkPipeline variant : std::span(&rasterSoftware[0][0][0][0], sizeof(rasterSoftware) / sizeof(VkPipeline))) vkDestroyPipeline(vk, variant, nullptr);
    for (VkPipeline variant : std::span(&rasterHardware[0][0][0], sizeof(rasterHardware) / sizeof(VkPipeline))) vkDestroyPipeline(vk, variant, nullptr);
    for (VkPipeline variant : std::span(&diceVariants[0][0], 4)) vkDestroyPipeline(vk, variant, nullptr);
    for (VkPipeline variant : std::span(&patchRasterVariants[0][0], 4)) vkDestroyPipeline(vk, variant, nullptr);
    vkDestroyPipeline(vk, tessellatePatches, nullptr);
    vkDestroyPipeline(vk, backgroundTextured, nullptr);
    vkDestroyPipeline(vk, pixelSamples, nullptr);
    for (const auto& [key, variant] : resolveVariants) vkDestroyPipeline(vk, variant, nullptr);
    vkDestroyPipelineLayout(vk, layout, nullptr);
    vkDestroyDescriptorSetLayout(vk, frameSetLayout, nullptr);
}

VkPipeline Pipelines::compute_pipeline(std::span<const uint32_t> code, const Specialization& specialization) {
    VkShaderModule module = create_module(device.handle(), code);
    const SpecializationInfo variant(specialization, shadePixelsPerThread, texelViews, outputBinding);
    const bool specialized = !(specialization == Specialization{}) || shadePixelsPerThread != 1 || texelViews || outputBinding;
    VkComputePipelineCreateInfo info{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
    info.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO, nullptr, 0, VK_SHADER_STAGE_COMPUTE_BIT, module, "main",
                  specialized ? &variant.info : nullptr};
    info.layout = layout;
    VkPipeline pipeline;
    const VkResult result = vkCreateComputePipelines(device.handle(), VK_NULL_HANDLE, 1, &info, nullptr, &pipeline);
    vkDestroyShaderModule(device.handle(), module, nullptr);
    check_vk(result, "vkCreateComputePipelines");
    return pipeline;
}

VkPipeline Pipelines::textured_background() {
    if (!backgroundTextured) backgroundTextured = compute_pipeline(background_comp);
    return backgroundTextured;
}

VkPipeline Pipelines::pixel_samples() {
    if (!pixelSamples) pixelSamples = compute_pipeline(samples_comp);
    return pixelSamples;
}

bool Pipelines::default_own_corners() const {
    if (const char* forced = std::getenv("TESSERA_RASTER_VERTICES"); forced && *forced) {
        if (std::strcmp(forced, "shared") == 0) return false;
        if (std::strcmp(forced, "per-triangle") == 0) return true;
        throw std::invalid_argument(std::string("TESSERA_RASTER_VERTICES='") + forced + "': expected shared or per-triangle");
    }
    return false;
}

uint32_t Pipelines::software_raster_group_size(bool ownCorners) const {
    return ownCorners ? uint32_t(TS_SW_RASTER_OWN_CORNERS_GROUP_SIZE) : swRasterGroupSize;
}

VkPipeline Pipelines::software_raster(bool masks, bool ownCorners, bool largeTriangles, bool countFragments) {
    VkPipeline& variant = rasterSoftware[masks][countFragments][ownCorners][largeTriangles];
    const std::span<const uint32_t> module = with_masks(masks, raster_sw_comp, raster_sw_masked_comp);
    if (!variant)
        variant = compute_pipeline(module,
                                   {.textures = masks,
                                    .ownCorners = ownCorners,
                                    .rasterGroupSize = software_raster_group_size(ownCorners),
                                    .largeTriangles = largeTriangles,
                                    .countFragments = countFragments});
    return variant;
}

VkPipeline Pipelines::hardware_raster(bool masks, bool doubleSided, bool countFragments) {
    VkPipeline& variant = rasterHardware[masks][countFragments][doubleSided];
    if (!variant) variant = graphics_pipeline(false, {.textures = masks, .doubleSided = doubleSided, .countFragments = countFragments});
    return variant;
}

VkPipeline Pipelines::tessellate() {
    if (!tessellatePatches) tessellatePatches = compute_pipeline(tessellate_comp);
    return tessellatePatches;
}

VkPipeline Pipelines::dice(bool masks, bool countFragments) {
    VkPipeline& variant = diceVariants[masks][countFragments];
    const std::span<const uint32_t> module = with_masks(masks, dice_comp, dice_masked_comp);
    if (!variant)
        variant = compute_pipeline(module, {.textures = masks, .rasterGroupSize = diceGroupSize, .countFragments = countFragments});
    return variant;
}

VkPipeline Pipelines::patch_raster(bool masks, bool countFragments) {
    // Patches come in one draw from instances of both kinds, which the fragment shader tells apart: no face culling.
    VkPipeline& variant = patchRasterVariants[masks][countFragments];
    if (!variant) variant = graphics_pipeline(true, {.textures = masks, .doubleSided = true, .countFragments = countFragments});
    return variant;
}

std::pair<uint64_t, Specialization> Pipelines::resolve_key(ResolveVariant v) {
    const bool shades = TS_OUTPUT_FIELD(v.outputs, TS_AOV_COLOR) != 0 && (v.outputs & TS_OUTPUT_VISUALIZE) == 0;  // the colour, shaded
    if (!shades) {
        v.textured = v.areaLights = v.vertexInputs = false;
        v.lightCounts = 0;
    }
    const bool idsAlone = TS_OUTPUT_FIELD(v.outputs, TS_AOV_COLOR) == 0 && TS_OUTPUT_FIELD(v.outputs, TS_AOV_DEPTH) == 0 &&
                          TS_OUTPUT_FIELD(v.outputs, TS_AOV_NORMAL) == 0;
    if (idsAlone) v.pixels = TS_BIN_TRIANGLES;  // ids alone need no micro-triangle
    if (!v.textured && v.pixels != TS_BIN_DICED_MICRO) v.textureKinds = 0;  // it reads no texture
    if (!v.pixelMaterials) v.instanceFlags = TS_SPECIALIZED_INSTANCE_FLAGS;  // read only by the per-pixel material lookup
    v.instanceFlags &= TS_SPECIALIZED_INSTANCE_FLAGS;
    static_assert(TS_OUTPUT_VISUALIZE < (1u << 25), "the outputs fit bits 34-58 of the key");
    return {v.textureKinds | uint64_t(v.textured) << 8 | uint64_t(v.pixels) << 9 | uint64_t(v.areaLights) << 11 | uint64_t(v.vertexInputs) << 12 |
                uint64_t(v.lightCounts) << 16 | uint64_t(v.pixelSource) << 32 | uint64_t(v.outputs) << 34 | uint64_t(v.pixelMaterials) << 59 |
                uint64_t(instance_flags_variant(v.instanceFlags)) << 60,
            {.textures = v.textured, .pixels = v.pixels, .areaLights = v.areaLights, .vertexInputs = v.vertexInputs, .outputs = v.outputs,
             .textureKinds = v.textureKinds, .lightCounts = v.lightCounts, .instanceFlags = v.instanceFlags, .pixelSource = v.pixelSource,
             .pixelMaterials = v.pixelMaterials}};
}

// Resolve's module for a variant's specialization: one per kind of pixels, and per texturing but for micro-triangles
// diced again (shaders/CMakeLists.txt).
std::span<const uint32_t> Pipelines::resolve_module(const Specialization& specialization) {
    const bool textured = specialization.textures;
    switch (specialization.pixels) {
    case TS_BIN_TRIANGLES: return textured ? std::span<const uint32_t>(resolve_textured_triangles_comp) : std::span<const uint32_t>(resolve_triangles_comp);
    case TS_BIN_KEPT_MICRO: return textured ? std::span<const uint32_t>(resolve_textured_kept_micro_comp) : std::span<const uint32_t>(resolve_kept_micro_comp);
    default: return resolve_diced_micro_comp;
    }
}

VkPipeline Pipelines::resolve_variant(const ResolveVariant& v) {
    const auto [key, specialization] = resolve_key(v);
    VkPipeline& variant = resolveVariants[key];
    if (!variant) variant = compute_pipeline(resolve_module(specialization), specialization);
    return variant;
}

void Pipelines::make_for_frame(const FrameNeeds& needs) {
    // A task per pipeline not made yet, each writing its own slot. The resolve variants first (their map entries
    // inserted here): the background set never touches them, so while it runs they are made meanwhile.
    std::vector<std::function<void()>> tasks;
    for (const ResolveVariant& v : needs.resolves) {
        const auto [key, specialization] = resolve_key(v);
        const auto [entry, inserted] = resolveVariants.try_emplace(key, VK_NULL_HANDLE);
        if (!inserted) continue;  // made, or already a task
        tasks.push_back([this, &slot = entry->second, specialization] { slot = compute_pipeline(resolve_module(specialization), specialization); });
    }
    if (startup.valid()) {
        run_on_threads(tasks);
        tasks.clear();
        wait_for_startup();
    }
    auto need = [&](VkPipeline made, std::function<void()> make) {
        if (!made) tasks.push_back(std::move(make));
    };
    const bool masks = needs.masks, corners = needs.ownCorners, counts = needs.countFragments;
    for (const bool large : {false, true})
        need(rasterSoftware[masks][counts][corners][large], [=, this] { software_raster(masks, corners, large, counts); });
    for (const bool doubleSided : {false, true})
        need(rasterHardware[masks][counts][doubleSided], [=, this] { hardware_raster(masks, doubleSided, counts); });
    const uint32_t flags = needs.instanceFlags, variant = instance_flags_variant(flags);
    for (uint32_t step = 0; step < 4; ++step) need(cull[step][variant], [=, this] { cull_step(step, flags); });
    static constexpr uint32_t kOneBin[] = {TS_CLASSIFY_ONE_BIN}, kSorted[] = {TS_CLASSIFY_COUNT, TS_CLASSIFY_SCATTER};
    for (uint32_t step : needs.oneBin ? std::span<const uint32_t>(kOneBin) : std::span<const uint32_t>(kSorted))
        need(classify[step][variant], [=, this] { classify_step(step, flags); });
    if (needs.displaced) {
        need(tessellatePatches, [this] { tessellate(); });
        need(diceVariants[masks][counts], [=, this] { dice(masks, counts); });
        need(patchRasterVariants[masks][counts], [=, this] { patch_raster(masks, counts); });
    }
    run_on_threads(tasks);  // an entry a failed task left empty is made on its first use (or fails again there)
}

VkPipeline Pipelines::cull_step(uint32_t step, uint32_t instanceFlags) {
    VkPipeline& pipeline = cull[step][instance_flags_variant(instanceFlags)];
    // A module per step (shaders/CMakeLists.txt).
    static constexpr std::span<const uint32_t> kModules[4] = {cull_main_comp, cull_post_comp, cull_main_instances_comp, cull_post_instances_comp};
    static_assert(TS_CULL_MAIN == 0 && TS_CULL_POST == 1 && TS_CULL_MAIN_INSTANCES == 2 && TS_CULL_POST_INSTANCES == 3);
    if (!pipeline)
        pipeline = compute_pipeline(kModules[step],
                                    {.cullGroupSize = cullGroupSize, .step = step, .instanceFlags = instanceFlags & TS_SPECIALIZED_INSTANCE_FLAGS});
    return pipeline;
}

VkPipeline Pipelines::classify_step(uint32_t step, uint32_t instanceFlags) {
    VkPipeline& pipeline = classify[step][instance_flags_variant(instanceFlags)];
    if (!pipeline)
        pipeline = compute_pipeline(classify_comp, {.step = step, .instanceFlags = instanceFlags & TS_SPECIALIZED_INSTANCE_FLAGS});
    return pipeline;
}

// Hardware raster: no attachments at all; the fragment shader writes the visibility buffer.
// Clusters (raster.vert.glsl, raster.frag.glsl) or patches (patch.vert.glsl, patch.frag.glsl). The cluster variant for
// single-sided instances culls back faces; patches come in one draw from instances of both kinds, which the fragment
// shader tells apart.
VkPipeline Pipelines::graphics_pipeline(bool patches, const Specialization& specialization) {
    VkShaderModule vert = create_module(device.handle(), patches ? std::span<const uint32_t>(patch_vert) : std::span<const uint32_t>(raster_vert));
    const bool masks = specialization.textures;
    VkShaderModule frag = create_module(device.handle(), patches ? with_masks(masks, patch_frag, patch_masked_frag) : with_masks(masks, raster_frag, raster_masked_frag));
    VkPipelineShaderStageCreateInfo stages[2] = {
        {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO, nullptr, 0, VK_SHADER_STAGE_VERTEX_BIT, vert, "main"},
        {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO, nullptr, 0, VK_SHADER_STAGE_FRAGMENT_BIT, frag, "main"}};
    const SpecializationInfo variant(specialization, 1, texelViews, outputBinding);
    stages[0].pSpecializationInfo = stages[1].pSpecializationInfo = &variant.info;
    VkPipelineVertexInputStateCreateInfo vertexInput{VK_STRUCTURE_TYPE_PIPELINE_VERTEX_INPUT_STATE_CREATE_INFO};
    VkPipelineInputAssemblyStateCreateInfo assembly{VK_STRUCTURE_TYPE_PIPELINE_INPUT_ASSEMBLY_STATE_CREATE_INFO};
    assembly.topology = VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST;
    VkPipelineViewportStateCreateInfo viewport{VK_STRUCTURE_TYPE_PIPELINE_VIEWPORT_STATE_CREATE_INFO};
    viewport.viewportCount = 1;
    viewport.scissorCount = 1;
    VkPipelineRasterizationStateCreateInfo rasterization{VK_STRUCTURE_TYPE_PIPELINE_RASTERIZATION_STATE_CREATE_INFO};
    rasterization.polygonMode = VK_POLYGON_MODE_FILL;
    rasterization.cullMode = specialization.doubleSided ? VK_CULL_MODE_NONE : VK_CULL_MODE_BACK_BIT;
    rasterization.frontFace = VK_FRONT_FACE_COUNTER_CLOCKWISE;
    rasterization.lineWidth = 1.0f;
    VkPipelineMultisampleStateCreateInfo multisample{VK_STRUCTURE_TYPE_PIPELINE_MULTISAMPLE_STATE_CREATE_INFO};
    multisample.rasterizationSamples = VK_SAMPLE_COUNT_1_BIT;
    VkPipelineColorBlendStateCreateInfo blend{VK_STRUCTURE_TYPE_PIPELINE_COLOR_BLEND_STATE_CREATE_INFO};
    VkPipelineDepthStencilStateCreateInfo depth{VK_STRUCTURE_TYPE_PIPELINE_DEPTH_STENCIL_STATE_CREATE_INFO};
    VkDynamicState dynamicStates[] = {VK_DYNAMIC_STATE_VIEWPORT, VK_DYNAMIC_STATE_SCISSOR};
    VkPipelineDynamicStateCreateInfo dynamic{VK_STRUCTURE_TYPE_PIPELINE_DYNAMIC_STATE_CREATE_INFO};
    dynamic.dynamicStateCount = 2;
    dynamic.pDynamicStates = dynamicStates;
    VkPipelineRenderingCreateInfo rendering{VK_STRUCTURE_TYPE_PIPELINE_RENDERING_CREATE_INFO};
    VkGraphicsPipelineCreateInfo info{VK_STRUCTURE_TYPE_GRAPHICS_PIPELINE_CREATE_INFO, &rendering};
    info.stageCount = 2;
    info.pStages = stages;
    info.pVertexInputState = &vertexInput;
    info.pInputAssemblyState = &assembly;
    info.pViewportState = &viewport;
    info.pRasterizationState = &rasterization;
    info.pMultisampleState = &multisample;
    info.pDepthStencilState = &depth;
    info.pColorBlendState = &blend;
    info.pDynamicState = &dynamic;
    info.layout = layout;
    VkPipeline pipeline;
    const VkResult result = vkCreateGraphicsPipelines(device.handle(), VK_NULL_HANDLE, 1, &info, nullptr, &pipeline);
    vkDestroyShaderModule(device.handle(), vert, nullptr);
    vkDestroyShaderModule(device.handle(), frag, nullptr);
    check_vk(result, "vkCreateGraphicsPipelines");
    return pipeline;
}

}  // namespace tessera
