// Types and constants shared by C++ (renderer/) and GLSL (shaders/): every GPU struct is defined here once.
// Layouts follow std430 with only 4-byte scalars and 16-byte vectors, so C++ and GLSL agree without padding
// rules; C++ checks each size with a static_assert.
#ifndef TESSERA_SHARED_H
#define TESSERA_SHARED_H

#ifdef __cplusplus
#include <cstdint>
namespace tessera::gpu {
using uint = uint32_t;
struct vec4 { float x, y, z, w; };
struct uvec4 { uint x, y, z, w; };
struct mat4 { vec4 columns[4]; };
using address = uint64_t;  // a VkDeviceAddress (buffer_reference in GLSL)
#define TS_CHECK_SIZE(type, bytes) static_assert(sizeof(type) == (bytes), #type " must match its GLSL layout")
#else
#define TS_CHECK_SIZE(type, bytes)
#define address uint64_t
#endif

// Clusters: the unit of culling and of the visibility buffer's id.
#define TS_CLUSTER_MAX_TRIANGLES 128
#define TS_CLUSTER_MAX_VERTICES 256

// Visibility buffer texel (64 bits): depth (32, reversed-Z float bits) | payload (32). Larger depth is nearer, so an
// atomic max keeps the nearest triangle; 0 means background. The payload is a cluster's triangle, visible cluster (24)
// | triangle (7), or, with its top bit set (TS_VIS_TESSELLATED), a micro-triangle of a displaced triangle's patch:
// patch (23) | micro-triangle (8).
#define TS_VIS_TRIANGLE_BITS 7
#define TS_VIS_CLUSTER_BITS 24
#define TS_VIS_MAX_VISIBLE_CLUSTERS (1u << TS_VIS_CLUSTER_BITS)
#define TS_VIS_TESSELLATED 0x80000000u
#define TS_VIS_MICRO_BITS 8
#define TS_VIS_MAX_PATCHES (1u << 23)

// Runtime tessellation (tessellation.h): a displaced triangle's edges are cut into segments of about `dicing rate`
// pixels, at most TS_TESS_MAX_FACTOR each; the triangle is split into split x split patches (split <= 16) so that no
// patch edge has more than TS_TESS_PATCH_FACTOR segments, and a patch into at most 16^2 = 256 micro-triangles.
#define TS_TESS_PATCH_FACTOR 16
#define TS_TESS_MAX_SPLIT 16
#define TS_TESS_MAX_FACTOR 256
#define TS_TESS_FACTOR_BITS 9   // a triangle's three edge factors in GpuPatch.factors, 1 to 256 each
// UV seams for displacement (frame.seams): a vertex's word is TS_NO_STREAM or the first word of the texture coordinates
// its position has (float bits, u then v, sorted) | their count << TS_SEAM_COUNT_SHIFT; a triangle's word is
// TS_NO_STREAM or the first of 12 words: per edge (corners 0-1, 1-2, 2-0 as stored), the other side's texture
// coordinates at its two corners, NaN where the edge is no seam.
#define TS_SEAM_COUNT_SHIFT 28

// Instance flags.
#define TS_INSTANCE_DOUBLE_SIDED 1u
#define TS_INSTANCE_FLIP_WINDING 2u  // the transform mirrors (negative determinant); leftHanded is fixed by the builder
#define TS_INSTANCE_CONFORMAL 4u     // the transform keeps angles (rotation, uniform scale, mirror): normal cones stay valid
#define TS_INSTANCE_MATERIAL_SLOTS 8u  // the mesh's triangles carry material slots: materialIndex starts its material table
#define TS_INSTANCE_MASKED 16u       // its material cuts pixels by a textured opacity (both rasterizers test each pixel)
#define TS_INSTANCE_DISPLACED 32u    // a material of it displaces: bounds widen, clusters near enough are tessellated

// Material flags.
#define TS_MATERIAL_VERTEX_CHANNEL 1u     // some input comes from the mesh's vertex channel (vertexInputs)
#define TS_MATERIAL_METALLIC 2u           // metallic workflow: reflectance blends towards the albedo with `metallic`
#define TS_MATERIAL_CUT_OUT 4u            // masked and below its opacity threshold everywhere: never drawn
#define TS_MATERIAL_DISPLACED 8u          // its displacement moves the surface (GpuMaterial.displacement.w > 0)

// Textures live in one storage buffer, the texture pool (GpuFrame.textures), and are sampled by hand in texture.h:
// lavapipe has no descriptor indexing, and the renderer reaches all data by buffer device address. Rows are stored
// bottom row first, so that texel row j covers t in [j, j + 1) / height (USD's st has its origin at the bottom left).
#define TS_TEXTURE_RGBA8 0u     // 8-bit images: unorm8x4, one word per texel
#define TS_TEXTURE_R8 1u        // 8-bit single-channel images: one byte per texel, four to a word; reads (r, r, r, 1)
#define TS_TEXTURE_RGBA16F 2u   // everything else (16-bit, half, float): float16x4, two words per texel
#define TS_TEXTURE_FORMAT_MASK 0xfu
#define TS_TEXTURE_SRGB 0x10u   // colour channels are sRGB-encoded: decoded per texel, before filtering

// UsdUVTexture wrapS / wrapT ('useMetadata' reads as repeat). Black: transparent black outside [0, 1].
#define TS_WRAP_REPEAT 0u
#define TS_WRAP_MIRROR 1u
#define TS_WRAP_CLAMP 2u
#define TS_WRAP_BLACK 3u

// What a set of textures needs from the sampling code (TS_SPEC_TEXTURE_KINDS): their formats, whether one is sRGB, their
// wrap modes.
#define TS_TEXTURE_KIND_FORMAT(format) (1u << (format))
#define TS_TEXTURE_KIND_SRGB (1u << 3)
#define TS_TEXTURE_KIND_WRAP(mode) (1u << (4u + (mode)))
#define TS_TEXTURE_KINDS_ALL 0xffu

// The UsdUVTexture output a slot uses.
#define TS_CHANNEL_R 0u
#define TS_CHANNEL_G 1u
#define TS_CHANNEL_B 2u
#define TS_CHANNEL_A 3u
#define TS_CHANNEL_RGB 4u

// UsdPreviewSurface inputs a texture can drive: bit i of GpuMaterial.textureInputs. A material's slots follow one
// another in this order from GpuMaterial.firstTextureSlot, one per set bit.
#define TS_INPUT_DIFFUSE_COLOR 0u
#define TS_INPUT_EMISSIVE_COLOR 1u
#define TS_INPUT_SPECULAR_COLOR 2u
#define TS_INPUT_METALLIC 3u
#define TS_INPUT_ROUGHNESS 4u
#define TS_INPUT_OPACITY 5u
#define TS_INPUT_OCCLUSION 6u
#define TS_INPUT_NORMAL 7u
#define TS_INPUT_DISPLACEMENT 8u  // read where the surface is diced (tessellation.h), not by resolve
#define TS_INPUT_COUNT 9u

// GpuMaterial.vertexInputs: which components of the mesh's vertex channel (its colour stream: 4 components per vertex,
// displayColor or the primvars the material's UsdPrimvarReaders read) drive an input, 4 bits per input TS_INPUT_DIFFUSE_COLOR
// to TS_INPUT_OCCLUSION at bit 4 * input: 0 none, else TS_VERTEX_INPUT_SET | the first component (bits 0-1), with
// TS_VERTEX_INPUT_RGB three components from there (else one: a colour input reads it as grey).
#define TS_VERTEX_INPUT_BITS 4u
#define TS_VERTEX_INPUT_RGB 4u
#define TS_VERTEX_INPUT_SET 8u
#define TS_VERTEX_INPUT_LAST TS_INPUT_OCCLUSION

// Mesh vertex streams.
#define TS_NO_STREAM 0xffffffffu

// The AOVs, as renderer.h numbers them (resolve writes those of its TS_SPEC_OUTPUT).
#define TS_AOV_COLOR 0u
#define TS_AOV_DEPTH 1u
#define TS_AOV_NORMAL 2u
#define TS_AOV_PRIM_ID 3u
#define TS_AOV_INSTANCE_ID 4u
#define TS_AOV_CLUSTER_ID 5u
#define TS_AOV_TRIANGLE_ID 6u

// Visualization modes: the color AOV shows one of these instead of shading (GpuFrame.counts.w).
#define TS_VIS_NONE 0u
#define TS_VIS_TRIANGLES 1u
#define TS_VIS_CLUSTERS 2u
#define TS_VIS_GROUPS 3u        // clusters coloured by the group they were simplified with (their parent group)
#define TS_VIS_LOD 4u           // DAG level: 0 (full detail) blue through red
#define TS_VIS_INSTANCES 5u
#define TS_VIS_PRIMITIVES 6u    // USD prims (primId)
#define TS_VIS_SHADING_BINS 7u  // materials
#define TS_VIS_RASTER_BINS 8u   // software (compute) raster blue, hardware raster orange
#define TS_VIS_OVERDRAW 9u      // fragments rasterized per pixel, both rasterizers: 1 blue through 9 or more red
#define TS_VIS_UV 10u           // texture coordinates: fract(u) red, fract(v) green; magenta where the mesh has none
#define TS_VIS_TESSELLATION 11u // dicing rate: a tessellated triangle's largest edge factor, 1 blue through 256 red, each
                                // micro-triangle shaded a little apart; grey where nothing is tessellated

// Frame flags (GpuFrame.counts.z).
#define TS_FRAME_NO_LOD 1u      // draw every source triangle (level 0), the DAG off: the full-detail reference
#define TS_FRAME_HARDWARE_ONLY 2u  // every cluster through hardware raster
#define TS_FRAME_SOFTWARE_FIRST 4u // every cluster the compute rasterizer can take goes there (tests, measurements)
#define TS_FRAME_PREVIOUS_HZB 8u   // two-pass occlusion: the main pass tests against the previous frame's HZB
#define TS_FRAME_OCCLUSION 16u     // two-pass HZB occlusion culling this frame (RenderSettings::occlusion, not resting)
#define TS_FRAME_MICRO_BINS 32u    // displaced materials drawn: the material bins come in TS_BIN_KINDS kinds
#define TS_FRAME_NO_CUT_BLOCKS 64u // every cut block is tested cluster by cluster (RenderSettings::cutBlocks)
#define TS_FRAME_BACKFACES 128u    // clusters facing away (normal cones) culled: RenderSettings::occlusion, even in the
                                   // frames whose HZB passes rest (they cost next to nothing)
#define TS_FRAME_DOME_BACKGROUND 256u  // a textured dome drew the colour's background (background.comp.glsl): resolve in place
                                       // leaves the colour of the pixels nothing covers as it is

// Cull steps (push constant `step`). Two-pass occlusion culling: the main pass draws what the previous frame's HZB
// does not hide and defers the rest; the post pass tests the deferred instances and clusters against an HZB of
// what the main pass drew, and draws those it does not hide.
// Each pass first tests instances, TS_CULL_INSTANCES_PER_GROUP per workgroup (steps *_INSTANCES: frustum and HZB),
// and lists the survivors; the cut steps then walk each listed instance's DAG, one workgroup each (on lavapipe a
// workgroup of the cull shader costs about 30 us even when it culls at once: a workgroup per instance of a
// 10 M-instance field would be 5 minutes of culling).
#define TS_CULL_MAIN 0u
#define TS_CULL_POST 1u
#define TS_CULL_MAIN_INSTANCES 2u
#define TS_CULL_POST_INSTANCES 3u
#define TS_TESS_DEFERRED_PATCHES 4u  // tessellate.comp.glsl, post pass: the patches the main pass deferred

// Material bins: covered pixels are counted per material, given each material a range, and scattered into it, so
// that each material's pixels are shaded by one indirect dispatch of their own (push constant `step`: the material);
// a pass of its own writes the background. A frame whose pixels can only fall in one bin lists its covered pixels at
// once (TS_CLASSIFY_ONE_BIN), or is not classified at all (TS_SPEC_PIXEL_SOURCE).
#define TS_CLASSIFY_COUNT 0u
#define TS_CLASSIFY_SCATTER 1u
#define TS_CLASSIFY_ONE_BIN 2u  // a frame whose pixels can only fall in one bin: listed at once, no count or scatter
#define TS_NO_BIN 0xffffffffu   // classify's mark for a pixel nothing covers
// What the AOVs hold where nothing covers a pixel, besides the frame's background colour and a zero normal: no id, and
// infinite depth (float bits). Written by the background fill (renderer.cpp background_words) or by resolve in place.
#define TS_BACKGROUND_ID 0xffffffffu
#define TS_BACKGROUND_DEPTH_BITS 0x7f800000u

// samples.comp.glsl's steps (push.step) in an image of several pixel samples: the first sample's colour starts the sum,
// each later one adds to it, and the last writes the mean into the frame's output.
#define TS_SAMPLES_FIRST 0u
#define TS_SAMPLES_ADD 1u
#define TS_SAMPLES_MEAN 2u

// Visible-cluster entries: (instance | raster bit, cluster). The bit records which rasterizer drew it.
#define TS_VISIBLE_SOFTWARE 0x80000000u
// The compute rasterizer takes clusters whose longest triangle edge projects to at most this many pixels (estimated at
// the cluster's nearest depth, GpuCluster.longestEdge) and that lie beyond the near plane. Their triangles' mean size
// decides the rest (frame.raster.x). The bound keeps one lane from scanning a box that spreads over much of the screen
// while the others wait. It bounded the clusters' radius before (128 px): clusters of small but spread-out triangles,
// along a silhouette, went to hardware raster (the 9.76 M sphere at 1 px: 214 clusters, 20 k triangles), which drew them
// dearer (docs/benchmarks.md, session 33).
#define TS_SW_MAX_EDGE_PIXELS 128.0
// A triangle less than this many sub-pixels across (E) is scanned with 32-bit edge functions (raster.h), far cheaper
// where 64-bit multiplies are emulated (lavapipe); a larger one needs 64-bit ones. Exact: the scan's edge functions
// stay within 2 E (E + step) (points at most one step past the triangle's box), below 2^31 for E < 2^15 - 2 * 256 and
// sub-pixel steps up to 256 (device.cpp caps subPixelPrecisionBits at 8). The cull lists a software cluster whose
// bounding sphere certainly projects within this (so every triangle of it does) at the front of the software list, the
// others at its back, each drawn by its own variant of the compute rasterizer.
#define TS_SW_SMALL_TRIANGLE_SUBPIXELS 32256
// The compute patch rasterizer takes patches up to this radius: their micro-triangles stay small (16 segments an edge),
// and sub-pixel coordinates this far off screen still fit 32 bits.
#define TS_DICE_MAX_RADIUS_PIXELS 256.0

#define TS_MAX_LIGHTS 8u
#define TS_LIGHT_DISTANT 0u
#define TS_LIGHT_DOME 1u
#define TS_LIGHT_RECT 2u
#define TS_LIGHT_SPHERE 3u
#define TS_NO_TEXTURE 0xffffffffu  // GpuLight::texture of a dome without a texture

// Specialization constant (constant_id) that compiles texture work into a pipeline variant: resolve's variant for
// materials with textures, the rasterizers' for frames with opacity masks. On lavapipe the texture code merely present
// in a shader, its branch never taken, made every pixel of every material 5x slower to resolve (docs/benchmarks.md).
// Most shaders now take it fixed per module instead (TS_MODULE_TEXTURED, TS_MODULE_MASKS: shaders/CMakeLists.txt), which
// also spares lavapipe compiling the code; resolve's module for micro-triangles diced again still reads it.
#define TS_SPEC_TEXTURES 0
// The same for micro-triangles: which kind of pixels (TS_BIN_*) a resolve variant takes. Each kind is a bin of its own
// with a variant of its own, since on lavapipe the code to dice a micro-triangle again, present beside the cheap read of
// its kept points, ran masked for every pixel and made displaced bins 2.5x as dear to resolve. Now a module per kind
// (TS_MODULE_PIXELS): no shader reads this id; Specialization::pixels picks the module.
#define TS_SPEC_DISPLACEMENT 1
#define TS_BIN_TRIANGLES 0u      // clusters' own triangles (every material)
#define TS_BIN_KEPT_MICRO 1u     // micro-triangles whose displaced points the compute patch rasterizer kept
#define TS_BIN_DICED_MICRO 2u    // micro-triangles resolve dices again (hardware-rastered patch, full point pool, or
                                 // vertex colours, which need the corners' weights)
#define TS_BIN_KINDS 3u          // bins: kind * material count + material (kinds 1 and 2 only in frames with displacement)
// Specialization constant of resolve's variant for frames with area lights (rect, sphere) or a textured dome: their
// shading code, present but not run, made the frames without them 3x slower to resolve on lavapipe.
#define TS_SPEC_AREA_LIGHTS 2
// Specialization constant of resolve: what its variant writes, all in one pass over the pixels (each pixel's triangle
// fetched once for every AOV of the frame): for each AOV (TS_AOV_*), bits TS_OUTPUT_BITS * aov hold its slice of the
// output plus one (0: not written; the colour's is slice 0); TS_OUTPUT_VISUALIZE: the colour is a debug view (--vis),
// not shaded. On lavapipe every branch of a shader runs, masked, for every pixel: only the code of the AOVs a variant
// writes is compiled in (the colour of shaded frames cost 25 % more with the other AOVs' and the debug views' code
// beside it).
#define TS_SPEC_OUTPUT 3
#define TS_OUTPUT_BITS 3u
#define TS_OUTPUT_VISUALIZE (1u << 24)
// An AOV's field of a TS_SPEC_OUTPUT value: its slice plus one, 0 where the variant does not write it.
#define TS_OUTPUT_FIELD(outputs, aov) (((outputs) >> (TS_OUTPUT_BITS * (aov))) & ((1u << TS_OUTPUT_BITS) - 1u))
#define TS_MOST_AOVS 7           // one of each TS_AOV_*: slices 0-6
// Specialization constants of the compute rasterizer (raster_sw.comp.glsl): its variant where each thread transforms its
// own triangles' corners, with no shared memory and no barrier, in workgroups of TS_SW_RASTER_OWN_CORNERS_GROUP_SIZE
// (RasterVertices::PerTriangle), and the workgroup size (local_size_x_id), which follows the variant and the device;
// the patch rasterizer's workgroup size too (dice.comp.glsl: one subgroup on a CPU device, TS_DICE_GROUP_SIZE on a GPU).
#define TS_SPEC_OWN_CORNERS 4
#define TS_SPEC_RASTER_GROUP_SIZE 5
// The cull's workgroup size (cull.comp.glsl, local_size_x_id): TS_CULL_GROUP_SIZE on a GPU, one subgroup on a CPU device
// (renderer/pipelines.cpp).
#define TS_SPEC_CULL_GROUP_SIZE 6
// The compute rasterizer's variant for the software clusters whose triangles may be large (boolean; the back of the
// software list, GpuDrawState.swLarge*). The other variant has no 64-bit scan at all: lavapipe runs both sides of a
// branch that differs between lanes, so a per-triangle choice cost every triangle both scans (12 % of its instructions).
#define TS_SPEC_LARGE_TRIANGLES 7
// The hardware raster's variant for double-sided instances (boolean): it draws the back of the hardware list with no face
// culling; the other culls back faces before any fragment (GpuDrawState.doubleSided*). lavapipe rasterizes and shades
// every fragment of a triangle it does not cull, so a back face rejected in the fragment shader cost as much as a front.
#define TS_SPEC_DOUBLE_SIDED 8
// Specialization constant of resolve (and of bins.comp.glsl, which sizes resolve's dispatches): how many of its bin's
// pixels each thread shades. 1 on a GPU (a thread per pixel, the most threads in flight); TS_CPU_SHADE_PIXELS_PER_THREAD
// on a CPU device, where lavapipe pays some 5 k instructions for each batch of 8 invocations of resolve whatever it
// shades: a third of a screen-filling frame's resolve (docs/benchmarks.md). Not for classify and background, whose
// per-pixel branches a loop made dearer than the batches it saved (measured).
#define TS_SPEC_SHADE_PIXELS_PER_THREAD 9
#define TS_CPU_SHADE_PIXELS_PER_THREAD 16
// Specialization constant of the passes whose steps are pipelines of their own: classify (TS_CLASSIFY_*) and the cull
// (TS_CULL_*). As a push constant, every step's code ran masked on lavapipe: classify's one-bin listing paid for
// decoding each pixel's bin, which it never uses (an empty 1080p frame cost 70-95 ms instead of 46-58), and each cull
// step ran the others' loops at least once, masked (docs/benchmarks.md).
#define TS_SPEC_STEP 10
// Specialization constant of resolve's variant for materials with inputs from the mesh's vertex channel
// (GpuMaterial.vertexInputs: displayColor, primvar readers). Its interpolation, present but not run, cost lavapipe 7-10 %
// of a screen-filling resolve with plain materials (docs/benchmarks.md).
#define TS_SPEC_VERTEX_INPUTS 11
// Specialization constant of the rasterizers' variants for the overdraw view (TS_VIS_OVERDRAW), which count every
// fragment: the count, present but not run, cost lavapipe 6 % of the compute raster (docs/benchmarks.md).
#define TS_SPEC_COUNT_FRAGMENTS 12
// Specialization constant: the passes read the streams below through texel buffer views (frame set bindings
// TS_VIEW_*) rather than through buffer addresses. lavapipe (Mesa 22.3) loads through an address lane by lane, in a loop
// with a branch per lane for each component; a texel fetch is one unrolled gather for all four components (a
// screen-filling resolve 190 -> ~70 ms, docs/benchmarks.md). The renderer picks it per frame: on where every view fits
// the device's maxTexelBufferElements (RenderSettings::texelViews).
#define TS_SPEC_TEXEL_VIEWS 13
// Specialization constant: the texture kinds a variant may read (TS_TEXTURE_KIND_* bits). Resolve's textured variants
// get the union over their material's textures, so that the code of every other format, encoding and wrap mode is left
// out: lavapipe runs every branch, masked, and the paths a texel could take cost a textured resolve 14-19 %
// (docs/benchmarks.md). Every other pass that samples keeps the default, all of them.
#define TS_SPEC_TEXTURE_KINDS 14
// Specialization constant of resolve's shading variants: the frame's lights, distant ones | all of them << 8 (at most
// TS_MAX_LIGHTS each), so that its two loops over them have constant trip counts and unroll: a loop whose count is
// read from the frame carries its sum through memory on lavapipe (11 % of a screen-filling resolve with a sun and a sky).
#define TS_SPEC_LIGHT_COUNTS 15
// Specialization constant: the passes store the AOV output through its storage buffer binding (TS_BINDING_OUTPUT)
// rather than its address; off in the sets for frames whose output outgrows the device's maxStorageBufferRange (128 MiB
// on lavapipe: above 8.4 M pixels).
#define TS_SPEC_OUTPUT_BINDING 16
// Specialization constant of the cull and classify: which of TS_SPECIALIZED_INSTANCE_FLAGS some instance of the frame
// carries (the other passes keep the default, all of them). The code for a flag no instance carries is left out:
// without TS_INSTANCE_DISPLACED, the bounds displacement adds to a cluster, whether it is diced, the tessellation list
// and the decoding of micro-triangle payloads; without TS_INSTANCE_MATERIAL_SLOTS, the material table lookup of each
// pixel's triangle. lavapipe ran them masked for every cluster and pixel of every scene: 13 % of the density fields'
// cull, 18 % of a frame's classify with 8 materials (docs/benchmarks.md).
#define TS_SPEC_INSTANCE_FLAGS 17
#define TS_SPECIALIZED_INSTANCE_FLAGS (TS_INSTANCE_DISPLACED | TS_INSTANCE_MATERIAL_SLOTS)
// Specialization constant of resolve: where it finds its pixels (TS_PIXELS_*). Its bin's list (classify's), or, in a
// one-bin frame (one material, no displacement), which then runs no classify and no bins pass, every pixel of the frame,
// tile by tile: shaded in place where the previous frame covered most pixels, else (on a CPU device) each subgroup's
// covered pixels packed first, so that its lanes shade full. On lavapipe, one core, 1080p: listing the covered pixels
// cost 15 ms; reading every pixel in place, each batch of 8 found partly uncovered is shaded masked (the density fields'
// resolve 28 ms dearer than the list); packing them costs the fields 3-4 ms over the list's resolve, the 1 px sphere
// (88 % covered) 5 ms over shading in place (docs/benchmarks.md).
#define TS_SPEC_PIXEL_SOURCE 18
#define TS_PIXELS_LISTED 0u        // the bin's pixels, listed by classify
#define TS_PIXELS_IN_PLACE 1u      // every pixel, each thread shading its own covered ones
#define TS_PIXELS_PACKED 2u        // every pixel, each subgroup's covered ones packed first (shared memory)
#define TS_PACKED_MOST_PIXELS_PER_THREAD 16u  // packing's shared memory: 8 bytes a pixel, 8 KiB a workgroup at most
// Specialization constant of resolve: each pixel reads its own material (its instance's, or its triangle's slot in the
// instance's material table) instead of its bin's from push constants. A CPU device's frames of several materials (no
// displacement) are not classified either: one dispatch reads every pixel, as a one-bin frame's does, through the
// variant for all their materials' features (textures, vertex inputs). On lavapipe (one core, 1080p, the 1 px sphere
// beside a second material) classify cost 49 ms and listed pixels 12 ms more resolve than in place; the pixel's
// material, a few texel fetches. A GPU keeps the bins: one material's code per dispatch, no divergence.
#define TS_SPEC_PIXEL_MATERIALS 19

// Frame set bindings: the frame's constants (a uniform block), then the texel buffer views (usamplerBuffer) of the
// streams read per pixel, per triangle or per vertex. The format of each: TS_VIEW_FORMAT_* (renderer.cpp).
#define TS_BINDING_FRAME 0
#define TS_VIEW_INSTANCES 1          // GpuInstance: 3 RGBA32UI texels each
#define TS_VIEW_BATCHES 2            // GpuInstanceBatch: 4 RGBA32UI texels each
#define TS_VIEW_INSTANCE_BATCHES 3   // uint per instance: R32UI
#define TS_VIEW_CLUSTERS 4           // GpuCluster: 6 RGBA32UI texels each
#define TS_VIEW_MESHES 5             // GpuMesh: 4 RGBA32UI texels each
#define TS_VIEW_VERTICES 6           // GpuVertex: one RGBA32UI texel each
#define TS_VIEW_TRIANGLES 7          // packed triangle: R32UI
#define TS_VIEW_VISIBLE_CLUSTERS 8   // uvec2 (instance, cluster): RG32UI
#define TS_VIEW_VISIBILITY 9         // 64-bit visibility value per pixel: RG32UI (low word first)
#define TS_VIEW_BIN_PIXELS 10        // packed pixel per binned pixel: R32UI
#define TS_VIEW_LEVELS 11            // GpuLevel: 3 RG32UI texels each
#define TS_VIEW_CUT_BLOCKS 12        // GpuCutBlock: 4 RGBA32UI texels each
#define TS_VIEW_BLOCK_CLUSTERS 13    // uint per block entry: R32UI
#define TS_VIEW_HZB 14               // the HZB's levels, float bits per texel: R32UI
#define TS_VIEW_TEXTURE_SLOTS 15     // GpuTextureSlot: 4 RGBA32UI texels each
#define TS_VIEW_TEXTURE_WORDS 16     // the texture pool (GpuTexture records, then the images' words): R32UI
#define TS_VIEW_UVS 17               // texture coordinates, a float pair per vertex: RG32UI
#define TS_VIEW_COLORS 18            // the vertex channel, 4 halves per vertex: RG32UI
#define TS_VIEW_PATCHES 19           // GpuPatch: 2 RGBA32UI texels each (tessellation; written by the pass before)
#define TS_VIEW_PATCH_POINTS 20      // the compute patch rasterizer's kept points, float bits: R32UI
#define TS_VIEW_MATERIALS 21         // GpuMaterial: 7 RGBA32UI texels each
#define TS_VIEW_MATERIAL_TABLES 22   // uint per entry (slot -> material, and each table's displacement bound): R32UI
#define TS_VIEW_VISIBLE_RECORDS 23   // GpuVisibleRecord per visible-cluster slot: 4 RGBA32UI texels each
#define TS_VIEW_COUNT 23
// The AOV output as storage buffers (std430, four words per pixel), one binding per slice (AOV of the frame): slice k
// at TS_BINDING_OUTPUT + k. Resolve stores each AOV's pixels into its own, the background and pixel samples the
// colour's (slice 0), and classify keeps its (bin, place) pairs in slice 0's. On a CPU device importing its images each
// binding is its AOV's image memory itself; otherwise a range of one output buffer. lavapipe loads and stores a vector
// of a storage buffer in one loop over the lanes, but through an address in one loop per component (a screen-filling
// resolve's stores 4x dearer). The variants with TS_SPEC_OUTPUT_BINDING use them; the others, for frames whose slice
// outgrows the device's maxStorageBufferRange, go through GpuFrame.aovOutput.
#define TS_BINDING_OUTPUT 24
// The visibility buffer as a storage buffer (one 64-bit word per pixel), for the rasterizers' atomic max in the same
// variants (TS_SPEC_OUTPUT_BINDING: a pixel's visibility word is half its output texel, so it fits wherever a slice
// does). lavapipe runs an atomic through an address with every operand taken apart lane by lane (the address of each
// lane among them), through a binding with the index alone: the 1 px sphere's compute raster 14 % cheaper on one core,
// its hardware raster 20 % (docs/benchmarks.md, session 33).
#define TS_BINDING_VISIBILITY (TS_BINDING_OUTPUT + TS_MOST_AOVS)
#define TS_BINDING_COUNT (TS_BINDING_VISIBILITY + 1)

// Workgroup sizes.
// On a CPU device the cull's workgroup is one subgroup: lavapipe runs a workgroup 8 invocations at a time, each batch
// loading the instance and its level table again; 16 threads striding over a level's clusters cost about a fifth of 64's
// cull time on the 1e6 field and a third on the 1e10 one, and 8 (one batch) a third less again (docs/benchmarks.md).
#define TS_CULL_GROUP_SIZE 64
#define TS_CULL_INSTANCES_PER_GROUP 2048  // the cull's instance steps: instances tested per workgroup
// A first frame (no previous HZB) draws in its main pass only the instances likely to hide others: those whose bounds
// project at least this fraction of the viewport's smaller side across (radius), or reach the camera plane. The post
// pass tests the rest against the HZB of those.
#define TS_OCCLUDER_FRACTION 0.125
#define TS_PIXEL_TILE 8        // classify, background: 8x8 pixels per workgroup
// resolve: threads per workgroup, each shading the bin's pixels TS_SHADE_GROUP_SIZE apart (TS_SPEC_SHADE_PIXELS_PER_THREAD
// of them): a workgroup shades TS_SHADE_GROUP_SIZE times that many pixels of its bin. The every-pixel variant's workgroup
// covers TS_SPEC_SHADE_PIXELS_PER_THREAD tiles side by side, a thread per pixel of each: one tile's pixels.
#define TS_SHADE_GROUP_SIZE 64
// The compute rasterizer's workgroup on a GPU: one per cluster, one thread per triangle (a CPU device's is one subgroup).
#define TS_SW_RASTER_GROUP_SIZE 128
// Its own-corners variant (RasterVertices::PerTriangle): one workgroup of 16 per cluster, each thread every 16th
// triangle. lavapipe runs a workgroup 8 invocations at a time and loads the cluster and instance again in each batch: 16
// triangles per thread cost 0.5x the 128-thread workgroup's raster time, 8 or 32 threads more (docs/benchmarks.md).
#define TS_SW_RASTER_OWN_CORNERS_GROUP_SIZE 16
#define TS_TESS_GROUP_SIZE 128       // tessellate: one workgroup per cluster, one thread per triangle
#define TS_DICE_GROUP_SIZE 64       // dice on a GPU: one workgroup per patch, its lattice points (<= 153), then its micro-triangles
                                     // (<= 256), 64 at a time
#define TS_DICE_MAX_POINTS 153       // (16 + 1)(16 + 2) / 2
#define TS_HZB_TILE 8
// Each HZB thread builds this many texels of a column: on lavapipe a workgroup costs about 16 k instructions before it
// does anything (an HZB whose threads returned at once still cost three quarters of the real one), so fewer, fuller
// workgroups (docs/benchmarks.md).
#define TS_HZB_ROWS_PER_THREAD 16
// hzb.comp.glsl's steps besides the levels it builds: write the dispatch arguments of the build after the main pass
// (needed iff the main pass deferred anything) or of the frame's final build (needed unless the post pass drew nothing).
#define TS_HZB_AFTER_MAIN 0x100u
#define TS_HZB_FINAL 0x101u

// One cluster of a built mesh's DAG: at most 128 triangles over at most 256 cluster-local vertices. The cut
// draws it iff its own LOD error, projected from its LOD sphere, is within the pixel threshold while its
// parent's is not (see builder.h: errors and spheres grow monotonically up the DAG, so the test is local).
struct GpuCluster {
    vec4 sphere;         // culling bounds of its triangles in mesh space (xyz centre, w radius)
    vec4 lodSphere;      // bounds of the simplification that made it (shared by the clusters it made)
    vec4 parentSphere;   // bounds of the simplification made from it (shared by its siblings)
    float lodError;      // mesh units; 0 at level 0
    float parentError;   // mesh units; TS_ROOT_ERROR for roots
    uint vertexOffset;   // first vertex in the scene's vertex streams
    uint triangleOffset; // first triangle in the scene's triangle stream (3 x 8-bit local indices per uint)
    uint triangleCount;
    uint meshIndex;
    uint levelVertices;  // DAG level (0 = source triangles) << 16 | cluster-local vertex count
    uint group;          // the group it was simplified with (its parent group), for visualization
    float meanTriangleArea;  // mesh units squared: picks the rasterizer (small triangles go to the compute one)
    uint normalCone;     // snorm8x4: xyz the axis of a cone holding every triangle normal, w its cutoff (builder.h NormalCone)
    float longestEdge;   // mesh units: the longest edge of its triangles (bounds the compute rasterizer's worst case)
    uint pad1;
};
TS_CHECK_SIZE(GpuCluster, 96);

#define TS_ROOT_ERROR 3.0e38  // a root's parent error: never fine enough, so roots are drawn when nothing finer is

// The clusters of one DAG level of a mesh, with bounds on their errors so that a whole level can be skipped
// for an instance whose distance rules it out (the cheap first step of a hierarchical cut).
struct GpuLevel {
    uint clusterOffset;
    uint clusterCount;
    float minLodError;      // smallest own error among the level's clusters
    float maxParentError;   // largest parent error (TS_ROOT_ERROR if the level holds a root)
    uint blockOffset;       // the level's GpuCutBlocks (frame.cutBlocks), which hold each of its clusters once
    uint blockCount;
};
TS_CHECK_SIZE(GpuLevel, 24);

// The cut's second step: up to TS_CUT_BLOCK_SIZE spatially close clusters of one level, with bounds that let the cut
// skip them all at once: when all are too coarse from where the instance is, when all parents are fine enough, or
// when none can touch the frustum (renderer/cut_blocks.cpp). The spheres enclose those of its clusters, in mesh space.
// 16 clusters: the 1 px sphere of tessera bench render (1080p) tests 8 761 clusters with 16 (8 713 on a per-axis grid), 10 073 with 32.
struct GpuCutBlock {
    vec4 sphere;            // encloses the clusters' culling spheres
    vec4 lodSphere;         // encloses their LOD spheres
    vec4 parentSphere;      // encloses the parent spheres of those that are not roots (radius 0 if all are)
    float minLodError;      // smallest own error among them
    float maxParentError;   // largest parent error (TS_ROOT_ERROR if one is a root)
    uint firstCluster;      // first entry of frame.blockClusters: the clusters, counted from the mesh's first
    uint clusterCount;      // 1 .. TS_CUT_BLOCK_SIZE
};
TS_CHECK_SIZE(GpuCutBlock, 64);
#define TS_CUT_BLOCK_SIZE 16u
// An instance goes block by block when the levels its distance allows hold more than this many clusters per thread of
// the cull's workgroup; below, cluster by cluster (most instances of a field of distant copies: their levels are small).
#define TS_CUT_BLOCKS_FROM 32u
#define TS_CUT_MOST_PARTS 64u  // workgroups that may share one instance's cut (cull.comp.glsl cut_parts)

struct GpuMesh {
    vec4 sphere;         // bounding sphere in mesh space
    uint clusterOffset;  // all levels, level 0 first
    uint clusterCount;
    uint colorOffset;    // first entry of the colour stream, or TS_NO_STREAM when the mesh has no vertex colours
    uint vertexOffset;   // first vertex (the colour stream is indexed by vertex - vertexOffset + colorOffset)
    uint levelOffset;    // first GpuLevel
    uint levelCount;
    uint leafClusterCount;  // level 0: the source triangles
    float lodRadius;     // about `sphere`'s centre, encloses every LOD and parent sphere of the mesh
    uint uvOffset;       // first entry of the texture coordinate stream (indexed like colours), or TS_NO_STREAM
    uint displacementNormalOffset;  // first entry of the displacement normal stream (indexed like colours), or TS_NO_STREAM
    // UV seams of a mesh drawn displaced (frame.seams, tessellation.h): seamVertexOffset is TS_NO_STREAM without seams,
    // else a vertex's word is seamVertexOffset + (vertex - vertexOffset), and a triangle's word seamTriangleOffset + its
    // scene triangle index (the offset already minus the mesh's first triangle, modulo 2^32).
    uint seamVertexOffset;
    uint seamTriangleOffset;
};
TS_CHECK_SIZE(GpuMesh, 64);

// Instances come in batches: the copies of one mesh that share its prim, material and flags and one origin (a plain
// mesh or a native instance: a batch of one; a PointInstancer prototype: a batch of all its instances). The batch
// origin is re-expressed relative to the camera in double on the CPU (a high and a low float) whenever the camera
// moves; each instance stores its transform relative to that origin in float, so geometry far from the origin renders
// like geometry at the origin and an instance costs 52 bytes: its GpuInstance and its word of frame.instanceBatches.
struct GpuInstanceBatch {
    vec4 originHigh;       // xyz: the batch origin relative to the camera, high float part; w: unused
    vec4 originLow;        // xyz: low part
    uint meshIndex;
    uint primId;
    uint materialIndex;    // its material; with TS_INSTANCE_MATERIAL_SLOTS the first entry of its table (frame.materialTables)
    uint flags;            // TS_INSTANCE_DOUBLE_SIDED, TS_INSTANCE_MATERIAL_SLOTS, TS_INSTANCE_MASKED
    // Displaced (TS_INSTANCE_DISPLACED): the first of its mesh's per-cluster displacement bounds under its materials
    // (frame.clusterDisplacement, indexed by the cluster's place in its mesh), or TS_NO_STREAM: its materials' bound.
    uint displacementBounds;
    uint pad0, pad1, pad2;
};
TS_CHECK_SIZE(GpuInstanceBatch, 64);

// What resolve needs of a visible cluster to rebuild one of its triangles at a pixel, written by the cull beside the
// visible-cluster entry from what it has loaded anyway: 4 texel fetches per pixel where the instance, its batch and the
// cluster took 9 (on lavapipe each fetch of a per-pixel index is a loop over the lanes: the 1 px sphere's resolve
// 0.9x, docs/benchmarks.md, session 36). What else a pass needs (ids, visualizations) it still loads the long way. Only
// clusters drawn as their own triangles have one: a diced cluster's pixels are micro-triangles, rebuilt from patches.
struct GpuVisibleRecord {
    vec4 rows[3];          // xyz: the instance's rows (Instance.rows); w: its translation relative to the camera
    uint vertexOffset;     // the cluster's
    uint triangleOffset;
    uint flags;            // the instance's (Instance.flags)
    uint meshIndex;
};
TS_CHECK_SIZE(GpuVisibleRecord, 64);

// A drawn copy of a mesh: rows of its 3x4 mesh->world matrix; w holds the translation relative to its batch's origin.
struct GpuInstance {
    vec4 rows[3];
};
TS_CHECK_SIZE(GpuInstance, 48);

// A mesh vertex: position and normal side by side, so that a pass reading both (resolve, tessellation) or the position
// alone (the rasterizers) reads one 16-byte texel: on lavapipe four single-word fetches per vertex, from two streams,
// cost a screen-filling resolve a sixth of its time (docs/benchmarks.md).
struct GpuVertex {
    uvec4 bits;  // x, y, z: the mesh-space position's float bits; w: the octahedral normal (snorm16x2)
};
TS_CHECK_SIZE(GpuVertex, 16);

// frame.instanceBatches[i]: the batch of instance i, with these flags of its transform in the top bits.
#define TS_INSTANCE_BATCH_MASK 0x3fffffffu
#define TS_INSTANCE_BATCH_FLIP (1u << 30)       // TS_INSTANCE_FLIP_WINDING
#define TS_INSTANCE_BATCH_CONFORMAL (1u << 31)  // TS_INSTANCE_CONFORMAL

// UsdPreviewSurface: a Lambert diffuse lobe and a GGX specular lobe with Schlick's Fresnel. The constants hold the
// inputs no texture drives; a material without textures (textureInputs 0) does no texture work at all.
struct GpuMaterial {
    vec4 diffuseColor;     // linear RGB; a: opacity, or with a textured opacity (masked) the opacityThreshold
    vec4 emissiveColor;    // rgb; a: occlusion (scales the dome light)
    vec4 specular;         // rgb: reflectance at normal incidence (specularColor, or from ior); a: roughness
    float metallic;
    uint flags;            // TS_MATERIAL_*
    uint firstTextureSlot; // GpuTextureSlot of the lowest set bit of textureInputs
    uint textureInputs;    // bit TS_INPUT_*: that input comes from a texture
    // Displacement along the vertex normal: offset = (value - center) * magnitude, value the displacement input (x, or
    // its texture), faded out as the bound projects to fewer pixels.
    vec4 displacement;     // x: constant value; y: magnitude; z: center; w: bound, the largest |offset| (mesh units)
    vec4 displacementFade; // x: full displacement while the bound projects to at least this many pixels; y: none
                           // below this many; z: the displacement texture's level-0 size in texels (for its footprint)
    uint vertexInputs;     // TS_VERTEX_INPUT_* per input: the inputs the mesh's vertex channel drives (0: none)
    uint unused0, unused1, unused2;
};
TS_CHECK_SIZE(GpuMaterial, 112);

// One image in the texture pool: its mip levels follow one another from `offset`, each starting on a word.
struct GpuTexture {
    uint width, height;    // level 0; level l is max(1, size >> l)
    uint offset;           // first word of level 0, counted from the start of the pool
    uint formatLevels;     // TS_TEXTURE_* | TS_TEXTURE_SRGB in bits 0-7, mip level count in bits 8-15
};
TS_CHECK_SIZE(GpuTexture, 16);

// A UsdUVTexture feeding one material input: which image, how it is read (wrap, output), the UsdTransform2d applied
// to st first, and the texture's scale and bias: value = texel * scale + bias, then the output's channel(s).
struct GpuTextureSlot {
    vec4 scale;
    vec4 bias;
    vec4 transform;        // rows of the 2x2 part: st' = (x y, z w) st + translation
    float translationS, translationT;
    uint texture;          // GpuTexture index in the pool
    uint mode;             // wrapS | wrapT << 2 | TS_CHANNEL_* << 4
};
TS_CHECK_SIZE(GpuTextureSlot, 64);

// A light (lights.h shades with it). Distant: `radiance` is the irradiance it delivers at normal incidence. Rect and
// sphere: `radiance` is what their surface emits, `position` their centre (camera-relative). Dome: uniform radiance, or
// with a texture that radiance times the lat-long image's, the image oriented by `axisX` and `axisY`.
struct GpuLight {
    vec4 directionType;    // xyz: the direction a distant light travels, or a rect's front normal (world); w: TS_LIGHT_* as float
    vec4 radiance;         // rgb: colour * intensity * 2^exposure (normalized by area where asked)
    vec4 position;         // xyz: rect and sphere centre, camera-relative; w: sphere radius
    vec4 axisX;            // rect: centre to the middle of its +X edge (world); dome: its local +X axis (world, unit)
    vec4 axisY;            // rect: centre to the middle of its +Y edge; dome: its local +Y axis (the lat-long's pole)
    uint texture;          // dome: its lat-long image in the texture pool, else TS_NO_TEXTURE
    uint pad0, pad1, pad2;
};
TS_CHECK_SIZE(GpuLight, 96);

// Indirect arguments of both rasterizers and of the post cull pass, plus the culling counters, written by the
// cull passes. The rasterizers' arguments are reset between the main and the post pass; the counters add up.
struct GpuDrawState {
    uint vertexCount;      // VkDrawIndirectCommand: TS_CLUSTER_MAX_TRIANGLES * 3 vertices per hardware cluster
    uint instanceCount;    // hardware clusters of single-sided instances stored (this pass) at the front of the hardware list
    uint firstVertex;
    uint firstInstance;
    uint swGroupsX;        // VkDispatchIndirectCommand: min(software clusters stored, 65535) workgroups
    uint swGroupsY;
    uint swGroupsZ;
    uint swClusters;       // software clusters stored (this pass) at the front of the software list: small triangles only
    uint swLargeGroupsX;   // VkDispatchIndirectCommand of the compute rasterizer's large-triangle variant
    uint swLargeGroupsY;
    uint swLargeGroupsZ;
    uint swLargeClusters;  // software clusters stored (this pass) at the back of the software list: triangles maybe large
    uint postGroupsX;      // VkDispatchIndirectCommand of the post cull pass: enough workgroups for the deferred work
    uint postGroupsY;
    uint postGroupsZ;
    uint deferredInstances; // instances the main pass deferred (hidden by the previous frame's HZB), may exceed capacity
    uint deferredClusters; // clusters the main pass deferred, may exceed capacity (overflow)
    uint visibleClusters;  // visible clusters found, may exceed capacity (overflow is detected on the CPU)
    uint visibleInstances;
    uint candidateClusters; // clusters the cut tested one by one (those of the blocks not ruled out)
    uint swTriangles;      // triangles sent to each rasterizer (32-bit: saturate past 4 G)
    uint hwTriangles;
    uint swClustersDrawn;  // software clusters, both passes
    uint swLargeClustersDrawn; // of those, the ones that may have large triangles (the large variant drew them)
    uint occludedInstances; // instances the post pass found hidden
    uint occludedClusters; // clusters the post pass found hidden
    uint postClusters;     // clusters drawn by the post pass (hidden last frame, visible now)
    uint backfaceClusters; // clusters all of whose triangles face away from the camera
    uint shadingBins;      // materials with at least one visible pixel
    uint cutGroupsX;       // VkDispatchIndirectCommand of the cut step: one workgroup per cut list entry, as X (at most
    uint cutGroupsY;       // 65535) times Y
    uint cutGroupsZ;
    uint cutInstances;     // cut list entries (instances' parts) for the cut step (this pass), may exceed the list's capacity
    uint postInstanceGroupsX; // VkDispatchIndirectCommand of the post pass's instance step: a thread per deferred instance
    uint postInstanceGroupsY;
    uint postInstanceGroupsZ;
    uint cutInstancesNeeded; // the most cut list entries either pass listed (overflow is detected on the CPU)
    uint tessGroupsX;      // VkDispatchIndirectCommand of the tessellate pass: one workgroup per tessellated cluster
    uint tessGroupsY;
    uint tessGroupsZ;
    uint tessClusters;     // clusters of displaced instances listed for tessellation (this pass)
    uint patches;          // patches made (both passes), may exceed capacity (overflow is detected on the CPU)
    uint tessTriangles;    // triangles tessellated
    uint microTriangles;   // micro-triangles of the patches stored (32-bit: saturates past 4 G)
    uint patchDraws;       // patches stored this pass: the count of the patch raster's indirect draws
    uint tessClustersDrawn; // clusters tessellated, both passes
    uint dicePatchGroupsX; // VkDispatchIndirectCommand of the patch rasterizer: one workgroup per patch of the compute list
    uint dicePatchGroupsY;
    uint dicePatchGroupsZ;
    uint dicePatches;      // patches listed for the compute patch rasterizer (this pass)
    uint dicePatchesDrawn; // patches the compute rasterizer drew, both passes (the rest went to hardware raster)
    uint patchPoints;      // points asked of the point pool (may exceed it: those patches keep none)
    uint deferredPatchGroupsX; // VkDispatchIndirectCommand of step TS_TESS_DEFERRED_PATCHES: a thread per deferred patch
    uint deferredPatchGroupsY;
    uint deferredPatchGroupsZ;
    uint deferredPatches;  // patches the main pass deferred (hidden by the previous frame's HZB)
    uint occludedPatches;  // patches the post pass found hidden
    uint keptMicroPixels;  // covered pixels resolve read from kept points (bin kind TS_BIN_KEPT_MICRO)
    uint dicedMicroPixels; // covered pixels whose micro-triangle resolve diced again (TS_BIN_DICED_MICRO)
    uint hzbBuilds;        // HZB builds the frame needed (hzb.comp.glsl: after the main pass, final)
    uint doubleSidedVertexCount;   // VkDrawIndirectCommand of the hardware clusters of double-sided instances, stored
    uint doubleSidedInstanceCount; // (this pass) at the back of the hardware list; the front's (above) cull back faces
    uint doubleSidedFirstVertex;
    uint doubleSidedFirstInstance;
    uint coveredPixels;    // pixels a surface covers: bins.comp.glsl's total; in a frame resolved over every pixel
                           // (TS_SPEC_PIXEL_SOURCE), the sum of its resolve dispatches' counts, one dispatch per AOV
};
TS_CHECK_SIZE(GpuDrawState, 260);

// One patch of a displaced triangle (tessellation.h). Each is drawn by an indirect draw of its own (GpuFrame.patchDraws:
// 3 vertices per micro-triangle, its index as the first instance), written per pass.
struct GpuPatch {
    uint triangle;         // visible cluster << 7 | triangle
    uint cell;             // split | cell << 8: which cell of the triangle's split x split lattice
    uint factors;          // the triangle's edge factors (corner 0-1, 1-2, 2-0), TS_TESS_FACTOR_BITS each
    uint patchFactors;     // this patch's edge factors (its corners 0-1, 1-2, 2-0), 5 bits each (0 to 16)
    // The compute patch rasterizer keeps its diced points for resolve: TS_PATCH_POINT_FLOATS floats each from float
    // points * TS_PATCH_POINT_FLOATS of frame.patchPoints (lattice order), or TS_NO_STREAM (hardware raster, vertex
    // colours, or the point pool was full: resolve dices again).
    uint points;
    uint pad0, pad1, pad2;
};
TS_CHECK_SIZE(GpuPatch, 32);
#define TS_PATCH_POINT_FLOATS 5   // camera-relative displaced position, texture coordinates

// One material's bin: its covered pixels' range in the bin pixel list, and the indirect dispatch that shades them.
struct GpuBin {
    uint groupsX;          // VkDispatchIndirectCommand: ceil(count / (TS_SHADE_GROUP_SIZE * pixels per thread))
    uint groupsY;          // workgroups, as X (at most 65535) times Y
    uint groupsZ;
    uint count;            // covered pixels of this material and kind (TS_BIN_*)
    uint offset;           // first entry in the bin pixel list
    uint pad0, pad1, pad2;
};
TS_CHECK_SIZE(GpuBin, 32);

// Per-frame constants, reached through the single pointer in the push constants.
struct GpuFrame {
    mat4 viewProjection;     // camera-relative world -> clip (reversed Z)
    // The ray through a point of the image (pixel units p, x right, y down), camera-relative: origin rayOrigin[0] + p.x
    // rayOrigin[1] + p.y rayOrigin[2], direction (unnormalized) rayDirection[0] + p.x rayDirection[1] + p.y
    // rayDirection[2]. Both are affine in p for perspective and orthographic cameras alike (w of the inverse projection
    // depends on depth only): the CPU takes them from the inverse view-projection in double (surface.h pixel_ray).
    vec4 rayOrigin[3];
    vec4 rayDirection[3];
    vec4 cameraForward;      // xyz: view direction (world)
    vec4 frustumPlanes[6];   // camera-relative world; dot(plane.xyz, p) + plane.w >= 0 inside
    vec4 background;         // linear RGBA of pixels no geometry covers
    vec4 lod;                // x: pixels per unit of error at unit view depth (or per unit, orthographic);
                             // y: error threshold in pixels; z: 1 when orthographic; w: near-plane distance
    vec4 raster;             // x: software raster below this estimated area per triangle (pixels); y: sub-pixel steps
    mat4 previousViewProjection; // the previous frame's camera, mapping this frame's camera-relative world to its clip
    uvec4 hzb;               // x: HZB levels (level l texel: the farthest depth of 2^(l+1) x 2^(l+1) pixels);
                             // y: capacity of the cut list; z: capacity of the deferred-instance list; w: the cut's parts
                             // (cull.comp.glsl cut_parts): at most w & 0xffff workgroups per instance (and at most
                             // TS_CUT_MOST_PARTS), one per w >> 16 clusters of its levels in the cut
    uvec4 viewport;          // x: width, y: height, z: material count, w: light count (distant lights first, then the
                             // others in the scene's order; resolve's counts: TS_SPEC_LIGHT_COUNTS)
    uvec4 counts;            // x: instances, y: visible-cluster capacity, z: TS_FRAME_* flags, w: TS_VIS_* mode
    uvec4 outputs;           // x: texels from a slice of the AOV output to the next (through GpuFrame.aovOutput)
    vec4 tessellation;       // x: dicing rate (pixels per micro-edge); y: patch capacity (exact: at most 2^23); z: point pool
                             // capacity (points)
    GpuLight lights[TS_MAX_LIGHTS];
    // The textured dome's irradiance (times 1/pi: an outgoing diffuse radiance per unit albedo) as 9 spherical
    // harmonics coefficients (rgb), in the dome's own frame; only read for a dome with a texture.
    vec4 environment[9];
    address instances;       // GpuInstance[]
    address instanceBatches; // uint[instances]: batch index | TS_INSTANCE_BATCH_* flags
    address batches;         // GpuInstanceBatch[]
    address meshes;          // GpuMesh[]
    address levels;          // GpuLevel[]
    address cutBlocks;       // GpuCutBlock[]
    address blockClusters;   // uint[clusters]: each block's clusters (GpuCutBlock.firstCluster), counted from the mesh's first
    address clusters;        // GpuCluster[]
    address vertices;        // GpuVertex[]
    address colors;          // uint[2 * colours], rgba16f
    address uvs;             // vec2[texture coordinates]
    address triangles;       // uint[triangles], 3 x 8-bit cluster-local indices
    address materials;       // GpuMaterial[]
    address materialTables;  // uint[]: per instance with material slots, slot -> material (pixel_material in frame.h)
    address visibleClusters; // uvec2[capacity]: (instance | TS_VISIBLE_SOFTWARE, cluster)
    address visibleRecords;  // GpuVisibleRecord[capacity]: beside each visible cluster, what resolve rebuilds it from
    address hardwareList;    // uint[capacity]: visible-cluster slots for hardware raster
    address softwareList;    // uint[capacity]: visible-cluster slots for the compute rasterizer (small-triangle clusters
                             // from the front, the others from the back)
    address drawState;       // GpuDrawState
    address visibility;      // uint64[width * height]
    address aovOutput;       // uvec4[width * height]: read and written through its binding where it fits (TS_BINDING_OUTPUT)
    address deferredInstances; // uint[hzb.z]: instances the main pass left to the post pass
    address cutList;         // uint[hzb.y]: instances the cut step of this pass walks, an instance once per part (consecutive)
    address deferredClusters;  // uvec2[capacity]: (instance, cluster) the main pass left to the post pass
    address overdraw;        // uint[width * height]: fragments per pixel, only with TS_VIS_OVERDRAW (else 0)
    address bins;            // GpuBin[materials]
    address binPixels;       // uint[width * height]: covered pixels (x | y << 16, frame.h pack_bin_pixel), grouped by material
    address textureSlots;    // GpuTextureSlot[], 0 when no material has a texture
    address textures;        // the texture pool: GpuTexture[] then texel words (uint); 0 when there are no textures
    // Displacement, 0 when no material displaces:
    address displacementNormals; // uint[]: octahedral snorm16x2, the mean normal at each vertex position (GpuMesh)
    address tessellationList;  // uint[capacity]: visible-cluster slots to tessellate
    address patches;         // GpuPatch[patch capacity]
    address patchDraws;      // VkDrawIndirectCommand[patch capacity]: this pass's patches
    address seams;           // uint[]: UV seams of meshes drawn displaced (GpuMesh.seamVertexOffset, tessellation.h)
    address dicePatches;     // uint[patch capacity]: this pass's patches for the compute patch rasterizer (dice.comp.glsl)
    address patchPoints;     // float[tessellation.z * TS_PATCH_POINT_FLOATS]: diced points kept for resolve (GpuPatch.points)
    address deferredPatchList; // uint[patch capacity]: patches the main pass deferred to the post pass
    address clusterDisplacement; // float[]: per cluster of a displaced batch's mesh, the largest offset its materials move
                                 // it by (mesh units; GpuInstanceBatch.displacementBounds)
    // Pixel samples (samples.comp.glsl), 0 in a frame of one: the colours of the samples before this one summed, and
    // where this sample's sum goes (two buffers, each sample writing the other).
    address samplesBefore;   // u64vec2[width * height]: a sum's float bits, rgba
    address samplesAfter;
};
TS_CHECK_SIZE(GpuFrame, 16 * 4 * 2 + 16 * 6 + 16 * 1 + 16 * 6 + 16 * 9 + 96 * TS_MAX_LIGHTS + 16 * 8 + 8 * 40);

// The order in which a dispatch's workgroups take its work. lavapipe (Mesa's compute thread pool) hands each of its
// threads one run of consecutive workgroups, the dispatch's count over its threads: where the work is uneven along that
// order (a frame's covered pixels from top to bottom, the software list in the cut's order), one thread idles while
// another finishes (two threads resolved the density fields in 0.8 of one thread's time, docs/benchmarks.md).
// spread_index(k, n) permutes [0, n) so that every such run takes work from all over it: the first 16 (n / 16) indices
// form 16 bands of consecutive ones, and band b takes the place of band b with its four bits reversed (the van der
// Corput order: any 2^j consecutive bands land one in each 2^j-th part of the bands); the indices past the bands stay.
// Within a band neighbours stay neighbours: finer bands (256) balanced the 1 px sphere's compute raster better but cost
// one thread 12 % more there (caches). A GPU starts workgroups as others finish: the order costs it nothing. Written in
// the subset C++ and GLSL share, so that the C++ tests check this very code.
#define TS_SPREAD_BITS 4u
#define TS_SPREAD_BANDS (1u << TS_SPREAD_BITS)
#ifdef __cplusplus
inline
#endif
uint spread_index(uint k, uint n) {
    uint size = n >> TS_SPREAD_BITS;
    if (k >= size << TS_SPREAD_BITS) return k;  // past the bands (all of [0, n) where n < 16)
    uint band = k / size, reversed = 0u;
    for (uint b = 0u; b < TS_SPREAD_BITS; ++b) reversed |= ((band >> b) & 1u) << (TS_SPREAD_BITS - 1u - b);
    return reversed * size + (k - band * size);
}

#ifdef __cplusplus
static_assert(TS_SHADE_GROUP_SIZE == TS_PIXEL_TILE * TS_PIXEL_TILE, "resolve's every-pixel workgroup is a thread per pixel of a tile");
}  // namespace tessera::gpu
#undef TS_CHECK_SIZE
#endif
#endif
