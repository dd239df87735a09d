// tessera._tessera: the C++ delegate, renderer and builder as seen from Python.
// The USD scene delegate is a Python subclass of SceneDelegate; its arrays reach C++ without copies:
// a MeshSource borrows numpy buffers (views of USD's VtArrays) and keeps them alive.
#include "tessera/cache.h"
#include "tessera/delegate.h"
#include "tessera/image_io.h"
#include "tessera/parallel.h"

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/map.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/shared_ptr.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>
#include <nanobind/trampoline.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>

namespace nb = nanobind;
using namespace nb::literals;
using namespace tessera;
using namespace tessera::hd;

namespace {

template <typename T>
using Array1 = nb::ndarray<const T, nb::ndim<1>, nb::c_contig, nb::device::cpu>;

// Owns Python objects from C++; releasing them takes the GIL, wherever the last owner lets go.
std::shared_ptr<const void> keep_alive(nb::object object) {
    auto* held = new nb::object(std::move(object));
    return std::shared_ptr<const void>(held, [](const void* p) {
        nb::gil_scoped_acquire gil;
        delete static_cast<const nb::object*>(p);
    });
}

// Runs `call` in the delegate's turn (RenderDelegate::turn) with the GIL released. The scene delegate's calls take it
// back themselves (nanobind's trampolines), as do the Python objects C++ lets go of (keep_alive). The GIL goes first, so
// that a thread waiting for its turn never holds it while the thread in turn needs it. `call` returns C++ values: Python
// objects are made once the GIL is back.
template <class Call>
auto in_turn(RenderDelegate& delegate, Call&& call) {
    nb::gil_scoped_release release;
    const std::lock_guard<std::mutex> turn(delegate.turn());
    return call();
}

// The index's mesh of that id; a KeyError names an id it lacks.
const Mesh& rprim_of(const RenderIndex& index, const PrimId& id) {
    const Mesh* mesh = index.rprim(id);
    if (!mesh) throw nb::key_error(id.c_str());
    return *mesh;
}

template <typename T>
std::span<const T> span_of(const std::optional<Array1<T>>& array) {
    if (!array) return {};
    return {array->data(), array->shape(0)};
}

Interpolation interpolation_from(const std::string& name) {
    if (name == "constant") return Interpolation::Constant;
    if (name == "uniform") return Interpolation::Uniform;
    if (name == "vertex") return Interpolation::Vertex;
    if (name == "varying") return Interpolation::Varying;
    if (name == "faceVarying") return Interpolation::FaceVarying;
    return Interpolation::None;
}

// UsdGeomMesh's subdivision tag tokens; an unknown one is an error naming it and the choices.
template <typename Enum>
Enum token_from(const char* attribute, const std::string& token, std::initializer_list<std::pair<const char*, Enum>> choices) {
    std::string names;
    for (const auto& [name, value] : choices) {
        if (token == name) return value;
        names += (names.empty() ? "" : ", ") + std::string(name);
    }
    throw std::invalid_argument(std::string(attribute) + " '" + token + "' is not one of " + names);
}
// UsdGeomMesh's subdivisionScheme token; none, or any token outside the schema's, draws the cage as it is.
SubdivisionScheme subdivision_scheme_from(const std::string& token) {
    return token == "catmullClark" ? SubdivisionScheme::CatmullClark
         : token == "loop"         ? SubdivisionScheme::Loop
         : token == "bilinear"     ? SubdivisionScheme::Bilinear
                                   : SubdivisionScheme::None;
}
BoundaryInterpolation boundary_interpolation_from(const std::string& token) {
    return token_from<BoundaryInterpolation>("interpolateBoundary", token,
                                             {{"none", BoundaryInterpolation::None},
                                              {"edgeOnly", BoundaryInterpolation::EdgeOnly},
                                              {"edgeAndCorner", BoundaryInterpolation::EdgeAndCorner}});
}
FaceVaryingLinear face_varying_linear_from(const std::string& token) {
    return token_from<FaceVaryingLinear>("faceVaryingLinearInterpolation", token,
                                         {{"none", FaceVaryingLinear::None},
                                          {"cornersOnly", FaceVaryingLinear::CornersOnly},
                                          {"cornersPlus1", FaceVaryingLinear::CornersPlus1},
                                          {"cornersPlus2", FaceVaryingLinear::CornersPlus2},
                                          {"boundaries", FaceVaryingLinear::Boundaries},
                                          {"all", FaceVaryingLinear::All}});
}
TriangleSubdivision triangle_subdivision_from(const std::string& token) {
    return token_from<TriangleSubdivision>("triangleSubdivisionRule", token,
                                           {{"catmullClark", TriangleSubdivision::CatmullClark}, {"smooth", TriangleSubdivision::Smooth}});
}

Aov aov_from(const std::string& name) {
    static const std::map<std::string, Aov> names{{"color", Aov::Color},           {"depth", Aov::Depth},
                                                  {"normal", Aov::Normal},         {"primId", Aov::PrimId},
                                                  {"instanceId", Aov::InstanceId}, {"clusterId", Aov::ClusterId},
                                                  {"triangleId", Aov::TriangleId}};
    auto it = names.find(name);
    if (it == names.end()) throw std::invalid_argument("unknown AOV '" + name + "' (color, depth, normal, primId, instanceId, clusterId, triangleId)");
    return it->second;
}

struct PySceneDelegate : SceneDelegate {
    // One slot per method overridden below, at least: a scene that called all of them (cameras, lights, materials,
    // subsets, instances, extents) failed a lookup past the slots with "the trampoline ran out of slots".
    NB_TRAMPOLINE(SceneDelegate, 10);
    MeshSource get_mesh(const PrimId& id) override { NB_OVERRIDE_PURE(get_mesh, id); }
    Matrix4d get_transform(const PrimId& id) override { NB_OVERRIDE_PURE(get_transform, id); }
    bool get_visible(const PrimId& id) override { NB_OVERRIDE_PURE(get_visible, id); }
    PrimId get_material_id(const PrimId& id) override { NB_OVERRIDE_PURE(get_material_id, id); }
    InstanceSet get_instances(const PrimId& instancerId, const PrimId& prototypeId) override {
        NB_OVERRIDE_PURE(get_instances, instancerId, prototypeId);
    }
    MaterialDesc get_material(const PrimId& id) override { NB_OVERRIDE_PURE(get_material, id); }
    LightDesc get_light(const PrimId& id) override { NB_OVERRIDE_PURE(get_light, id); }
    CameraDesc get_camera(const PrimId& id) override { NB_OVERRIDE_PURE(get_camera, id); }
    std::vector<PrimId> get_subset_material_ids(const PrimId& id) override { NB_OVERRIDE(get_subset_material_ids, id); }
    std::optional<std::array<double, 6>> get_extent(const PrimId& id) override { NB_OVERRIDE(get_extent, id); }
};

Visualize visualize_from(const std::string& name) {
    for (int mode = 0; mode <= int(Visualize::Tessellation); ++mode)
        if (name == visualize_name(Visualize(mode))) return Visualize(mode);
    throw nb::value_error(("unknown visualization mode '" + name + "'").c_str());
}

PixelFilter pixel_filter_from(const std::string& name) {
    if (name == "box") return PixelFilter::Box;
    if (name == "gaussian") return PixelFilter::Gaussian;
    throw nb::value_error(("unknown pixel filter '" + name + "' (box or gaussian)").c_str());
}

nb::dict stats_dict(const FrameStats& s) {
    nb::dict d;
    d["instances"] = s.instances;
    d["pixel_samples"] = s.pixelSamples;
    d["instance_batches"] = s.instanceBatches;
    d["instance_bytes"] = s.instanceBytes;
    d["visible_instances"] = s.visibleInstances;
    d["clusters"] = s.clusters;
    d["candidate_clusters"] = s.candidateClusters;
    d["visible_clusters"] = s.visibleClusters;
    d["source_triangles"] = s.sourceTriangles;
    d["visible_triangles"] = s.visibleTriangles;
    d["sw_triangles"] = s.swTriangles;
    d["hw_triangles"] = s.hwTriangles;
    d["sw_clusters"] = s.swClusters;
    d["sw_large_clusters"] = s.swLargeClusters;
    d["sw_raster_vertices"] = s.swSharedVertices ? "shared" : "per-triangle";
    d["cull_group_size"] = s.cullGroupSize;
    d["sw_raster_group_size"] = s.swRasterGroupSize;
    d["shade_pixels_per_thread"] = s.shadePixelsPerThread;
    d["texel_views"] = s.texelViews;
    d["output_binding"] = s.outputBinding;
    d["aovs_imported"] = s.aovsImported;
    d["aov_imports_made"] = s.aovImportsMade;
    d["sample_sums_on_device"] = s.sampleSumsOnDevice;
    d["overflow_redraws"] = s.overflowRedraws;
    d["visible_cluster_capacity"] = s.visibleClusterCapacity;
    d["occlusion_tested"] = s.occlusionTested;
    d["occlusion_rested"] = s.occlusionRested;
    d["occluded_instances"] = s.occludedInstances;
    d["occluded_clusters"] = s.occludedClusters;
    d["post_pass_clusters"] = s.postPassClusters;
    d["hzb_builds"] = s.hzbBuilds;
    d["backface_clusters"] = s.backfaceClusters;
    d["shading_bins"] = s.shadingBins;
    d["covered_pixels"] = s.coveredPixels;
    d["resolve_pixels"] = s.resolvePixels;
    d["pixel_materials"] = s.pixelMaterials;
    d["textures"] = s.textures;
    d["geometry_bytes"] = s.geometryBytes;
    d["geometry_upload_bytes"] = s.geometryUploadBytes;
    d["upload_submissions"] = s.uploadSubmissions;
    d["displaced_meshes_prepared"] = s.displacedMeshesPrepared;
    d["host_mesh_bytes"] = s.hostMeshBytes;
    d["texture_bytes"] = s.textureBytes;
    d["tessellated_clusters"] = s.tessellatedClusters;
    d["tessellated_triangles"] = s.tessellatedTriangles;
    d["patches"] = s.patches;
    d["compute_patches"] = s.computePatches;
    d["deferred_patches"] = s.deferredPatches;
    d["occluded_patches"] = s.occludedPatches;
    d["kept_micro_pixels"] = s.keptMicroPixels;
    d["diced_micro_pixels"] = s.dicedMicroPixels;
    d["micro_triangles"] = s.microTriangles;
    d["tessellation_bytes"] = s.tessellationBytes;
    d["pixel_bytes"] = s.pixelBytes;
    nb::dict gpuMs;
    gpuMs["cull"] = s.cullMs;
    gpuMs["sw_raster"] = s.softwareRasterMs;
    gpuMs["hw_raster"] = s.rasterMs;
    gpuMs["tessellation"] = s.tessellationMs;
    gpuMs["hzb"] = s.hzbMs;
    gpuMs["classify"] = s.classifyMs;
    gpuMs["resolve"] = s.resolveMs;
    gpuMs["readback"] = s.readbackMs;
    d["gpu_ms"] = gpuMs;
    d["upload_ms"] = s.uploadMs;
    d["cpu_record_ms"] = s.cpuRecordMs;
    d["cpu_wait_ms"] = s.cpuWaitMs;
    d["cpu_frame_ms"] = s.cpuFrameMs;
    return d;
}

// Build settings by their Python names (snake case of BuildSettings' fields); position_precision None is automatic.
constexpr std::pair<const char*, const char*> kSettingNames[] = {
    {"position_precision", "positionPrecision"},         {"preserve_area", "preserveArea"},
    {"trim_relative_error", "trimRelativeError"},       {"keep_triangle_percent", "keepTrianglePercent"},
    {"fallback_relative_error", "fallbackRelativeError"}, {"fallback_triangle_percent", "fallbackTrianglePercent"},
    {"max_edge_length_factor", "maxEdgeLengthFactor"}};

// Validated settings from keyword arguments; errors name the Python keyword.
BuildSettings settings_from(const nb::kwargs& kwargs, BuildSettings s = {}) {
    for (auto [key, value] : kwargs) {
        const std::string name = nb::cast<std::string>(key);
        if (name == "position_precision") s.positionPrecision = value.is_none() ? BuildSettings::kAutoPrecision : nb::cast<int>(value);
        else if (name == "preserve_area") s.preserveArea = nb::cast<bool>(value);
        else if (name == "trim_relative_error") s.trimRelativeError = nb::cast<float>(value);
        else if (name == "keep_triangle_percent") s.keepTrianglePercent = nb::cast<float>(value);
        else if (name == "fallback_relative_error") s.fallbackRelativeError = nb::cast<float>(value);
        else if (name == "fallback_triangle_percent") s.fallbackTrianglePercent = nb::cast<float>(value);
        else if (name == "max_edge_length_factor") s.maxEdgeLengthFactor = nb::cast<float>(value);
        else throw nb::type_error(("unknown build setting '" + name + "'").c_str());
    }
    try {
        validate_settings(s);
    } catch (const std::invalid_argument& e) {
        std::string message = e.what();
        for (auto [python, cpp] : kSettingNames)
            if (size_t at = message.find(cpp); at != std::string::npos) message.replace(at, std::strlen(cpp), python);
        throw nb::value_error(message.c_str());
    }
    return s;
}

nb::dict settings_dict(const BuildSettings& s) {
    nb::dict d;
    d["position_precision"] = s.positionPrecision == BuildSettings::kAutoPrecision ? nb::none() : nb::cast(s.positionPrecision);
    d["preserve_area"] = s.preserveArea;
    d["trim_relative_error"] = s.trimRelativeError;
    d["keep_triangle_percent"] = s.keepTrianglePercent;
    d["fallback_relative_error"] = s.fallbackRelativeError;
    d["fallback_triangle_percent"] = s.fallbackTrianglePercent;
    d["max_edge_length_factor"] = s.maxEdgeLengthFactor;
    return d;
}

// (N, Columns) numpy array owning `values`.
template <size_t Columns, typename T>
nb::ndarray<T, nb::numpy, nb::shape<-1, Columns>> rows_of(std::vector<T> values) {
    auto* owned = new std::vector<T>(std::move(values));
    nb::capsule owner(owned, [](void* v) noexcept { delete static_cast<std::vector<T>*>(v); });
    return nb::ndarray<T, nb::numpy, nb::shape<-1, Columns>>(owned->data(), {owned->size() / Columns, Columns}, owner);
}
template <typename T>
nb::ndarray<T, nb::numpy, nb::shape<-1, 3>> rows_of_three(std::vector<T> values) {
    return rows_of<3>(std::move(values));
}

nb::dict fallback_dict(const BuiltMesh& built) {
    FallbackMesh f = fallback_mesh(built);  // extracted now: built meshes keep only its cut
    std::vector<float> positions(f.positions.size());  // object space, through double
    for (size_t i = 0; i < positions.size(); ++i) positions[i] = float(built.origin[i % 3] + double(f.positions[i]));
    nb::dict d;
    d["positions"] = rows_of_three(std::move(positions));
    const size_t triangles = f.indices.size() / 3;
    d["normals"] = rows_of_three(std::move(f.normals));
    d["indices"] = rows_of_three(std::move(f.indices));
    // None where the mesh has no such attribute.
    d["colors"] = f.colors.empty() ? nb::none() : nb::object(nb::cast(rows_of<4>(std::move(f.colors))));
    d["uvs"] = f.uvs.empty() ? nb::none() : nb::object(nb::cast(rows_of<2>(std::move(f.uvs))));
    d["material_slots"] = f.materialSlots.empty() ? nb::none() : nb::object(nb::cast(rows_of<1>(std::move(f.materialSlots))));
    d["triangles"] = triangles;
    d["error"] = f.error;
    d["relative_error"] = built.size > 0 ? f.error / built.size : 0.0f;
    return d;
}

}  // namespace

NB_MODULE(_tessera, m) {
    m.doc() = "Tessera's C++ core: Hydra-style delegate, renderer and builder";
    nb::exception<DeviceError>(m, "DeviceError");
    nb::exception<MeshError>(m, "MeshError", PyExc_ValueError);
    nb::exception<ImageIoError>(m, "ImageIoError", PyExc_IOError);
    nb::exception<TextureError>(m, "TextureError", PyExc_IOError);

    nb::class_<BuildSettings>(m, "BuildSettings")
        .def("__init__", [](BuildSettings* self, const nb::kwargs& kwargs) { new (self) BuildSettings(settings_from(kwargs)); })
        .def("replace", [](const BuildSettings& s, const nb::kwargs& kwargs) { return settings_from(kwargs, s); },
             "A copy with the given settings changed (validated).")
        .def("as_dict", &settings_dict)
        .def("__repr__", [](const BuildSettings& s) { return "BuildSettings(" + nb::cast<std::string>(nb::repr(settings_dict(s))) + ")"; })
        .doc() = "Per-mesh build settings after Nanite's, validated; keywords as tessera.build_mesh takes them.";

    nb::class_<MeshSource>(m, "MeshSource")
        .def_rw("settings", &MeshSource::settings, "The BuildSettings this mesh is built with.");
    m.def(
        "mesh_source",
        [](const std::string& name, Array1<float> points, Array1<int32_t> counts, Array1<int32_t> indices,
           std::optional<Array1<int32_t>> holes, bool leftHanded, bool doubleSided, std::optional<Array1<float>> normals,
           const std::string& normalsInterpolation, std::optional<Array1<int32_t>> normalsIndices, std::optional<Array1<float>> displayColor,
           const std::string& displayColorInterpolation, std::optional<Array1<int32_t>> displayColorIndices, std::optional<Array1<float>> uvs,
           const std::string& uvsInterpolation, std::optional<Array1<int32_t>> uvsIndices, std::optional<Array1<int32_t>> faceMaterials,
           const std::string& scheme, int refineLevel, const std::string& interpolateBoundary, const std::string& faceVaryingLinearInterpolation,
           const std::string& triangleSubdivisionRule, std::optional<Array1<int32_t>> creaseIndices, std::optional<Array1<int32_t>> creaseLengths,
           std::optional<Array1<float>> creaseSharpnesses, std::optional<Array1<int32_t>> cornerIndices, std::optional<Array1<float>> cornerSharpnesses, int displayColorComponents) {
            if (displayColorComponents != 3 && displayColorComponents != kChannelComponents)
                throw std::invalid_argument(name + ": display_color_components must be 3 or " + std::to_string(kChannelComponents));
            if (displayColor && displayColor->shape(0) % size_t(displayColorComponents) != 0)
                throw std::invalid_argument(name + ": display_color's length is not a multiple of display_color_components");
            MeshSource source;
            SubdivisionTags& tags = source.view.subdivisionTags;
            tags.interpolateBoundary = boundary_interpolation_from(interpolateBoundary);
            tags.faceVaryingLinearInterpolation = face_varying_linear_from(faceVaryingLinearInterpolation);
            tags.triangleSubdivisionRule = triangle_subdivision_from(triangleSubdivisionRule);
            tags.creaseIndices = span_of(creaseIndices);
            tags.creaseLengths = span_of(creaseLengths);
            tags.creaseSharpnesses = span_of(creaseSharpnesses);
            tags.cornerIndices = span_of(cornerIndices);
            tags.cornerSharpnesses = span_of(cornerSharpnesses);
            source.view.subdivisionScheme = subdivision_scheme_from(scheme);
            source.view.refineLevel = std::clamp(refineLevel, 0, 8);
            source.view.name = name;
            source.view.points = {points.data(), points.shape(0)};
            source.view.faceVertexCounts = {counts.data(), counts.shape(0)};
            source.view.faceVertexIndices = {indices.data(), indices.shape(0)};
            source.view.holeIndices = span_of(holes);
            source.view.leftHanded = leftHanded;
            source.doubleSided = doubleSided;
            if (normals) source.view.normals = {interpolation_from(normalsInterpolation), 3, span_of(normals), span_of(normalsIndices)};
            if (displayColor)
                source.view.displayColor = {interpolation_from(displayColorInterpolation), displayColorComponents, span_of(displayColor),
                                            span_of(displayColorIndices)};
            if (uvs) source.view.uvs = {interpolation_from(uvsInterpolation), 2, span_of(uvs), span_of(uvsIndices)};
            source.view.faceMaterials = span_of(faceMaterials);
            nb::list owners;
            for (nb::handle h : {nb::cast(points), nb::cast(counts), nb::cast(indices)}) owners.append(h);
            for (auto* o : {&holes, &normalsIndices, &displayColorIndices, &uvsIndices, &faceMaterials, &creaseIndices, &creaseLengths, &cornerIndices})
                if (*o) owners.append(nb::cast(**o));
            for (auto* o : {&normals, &displayColor, &uvs, &creaseSharpnesses, &cornerSharpnesses})
                if (*o) owners.append(nb::cast(**o));
            source.keepAlive = keep_alive(owners);
            return source;
        },
        "name"_a, "points"_a, "face_vertex_counts"_a, "face_vertex_indices"_a, "hole_indices"_a = nb::none(), "left_handed"_a = false,
        "double_sided"_a = false, "normals"_a = nb::none(), "normals_interpolation"_a = "vertex", "normals_indices"_a = nb::none(),
        "display_color"_a = nb::none(), "display_color_interpolation"_a = "constant", "display_color_indices"_a = nb::none(),
        "uvs"_a = nb::none(), "uvs_interpolation"_a = "faceVarying", "uvs_indices"_a = nb::none(), "face_materials"_a = nb::none(),
        "subdivision_scheme"_a = "none",
        "refine_level"_a = 0, "interpolate_boundary"_a = "edgeAndCorner", "face_varying_linear_interpolation"_a = "cornersPlus1",
        "triangle_subdivision_rule"_a = "catmullClark", "crease_indices"_a = nb::none(), "crease_lengths"_a = nb::none(),
        "crease_sharpnesses"_a = nb::none(), "corner_indices"_a = nb::none(), "corner_sharpnesses"_a = nb::none(),
        "display_color_components"_a = 3,
        "A mesh as authored, borrowing flat contiguous arrays (points: float32 xyz triples; colours: display_color_components "
        "floats per element, 3 (displayColor) or 4 (the vertex channel as the scene delegate packs it); uvs: float32 pairs). "
        "Subdivision tags take UsdGeomMesh's tokens and arrays (int32 indices and lengths, float32 sharpnesses); an unknown "
        "token is a ValueError.");

    // The common mesh (no primvars, normals, holes or tags: what the scene delegate's short path reads) in one lean call:
    // 100 k small prims paid for mesh_source's 29 arguments and for numpy copies of the arrays. USD's arrays are taken
    // as they come (any object with the buffer protocol: a Vt.Vec3fArray, a numpy array), without copies.
    m.def(
        "plain_mesh_source",
        [](const std::string& name, nb::object points, nb::object counts, nb::object indices, bool leftHanded, bool doubleSided,
           const std::string& scheme, int refineLevel) {
            using Floats = nb::ndarray<const float, nb::c_contig, nb::device::cpu>;
            using Ints = nb::ndarray<const int32_t, nb::c_contig, nb::device::cpu>;
            Floats p;
            Ints c, i;
            // No implicit conversion: a converted copy would not outlive this call, and the views would dangle.
            if (!nb::try_cast(points, p, false) || !nb::try_cast(counts, c, false) || !nb::try_cast(indices, i, false))
                throw std::invalid_argument(name + ": points must be contiguous float32 values, face vertex counts and indices int32");
            MeshSource source;
            source.view.subdivisionScheme = subdivision_scheme_from(scheme);
            source.view.refineLevel = std::clamp(refineLevel, 0, 8);
            source.view.name = name;
            source.view.points = {p.data(), p.size()};
            source.view.faceVertexCounts = {c.data(), c.size()};
            source.view.faceVertexIndices = {i.data(), i.size()};
            source.view.leftHanded = leftHanded;
            source.doubleSided = doubleSided;
            // The arrays' own objects are kept (their data stays where it is while they live), not the views.
            source.keepAlive = keep_alive(nb::make_tuple(points, counts, indices));
            return source;
        },
        "name"_a, "points"_a, "face_vertex_counts"_a, "face_vertex_indices"_a, "left_handed"_a = false, "double_sided"_a = false,
        "subdivision_scheme"_a = "none", "refine_level"_a = 0,
        "mesh_source for a mesh of points, face vertex counts and indices alone (subdivision tags at USD's fallbacks), "
        "borrowing any contiguous float32 / int32 arrays with the buffer protocol, USD's VtArrays included.");

    nb::class_<MatrixArray>(m, "MatrixArray").def_prop_ro("size", &MatrixArray::size);
    m.def(
        "matrix_array",
        [](nb::ndarray<const double, nb::shape<-1, 4, 4>, nb::c_contig, nb::device::cpu> matrices) {
            MatrixArray array;
            array.values = {matrices.data(), matrices.shape(0) * 16};
            array.keepAlive = keep_alive(nb::cast(matrices));
            return array;
        },
        "matrices"_a, "Row-major (N, 4, 4) float64 matrices acting on column vectors.");

    // A PointInstancer's arrays, borrowed (numpy views of USD's VtArrays): validated here, never copied.
    nb::class_<InstanceArrays>(m, "InstanceArrays").def_prop_ro("count", &InstanceArrays::count);
    nb::class_<InstanceSet>(m, "InstanceSet")
        .def_prop_ro("count", &InstanceSet::count)
        .def_prop_ro("instances_per_frame", [](const InstanceSet& set) { return set.arrays ? set.arrays->count() : 1; });
    m.def(
        "instance_arrays",
        [](nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> positions,
           std::optional<nb::ndarray<const float, nb::shape<-1, 4>, nb::c_contig, nb::device::cpu>> orientations,
           std::optional<nb::ndarray<const uint16_t, nb::shape<-1, 4>, nb::c_contig, nb::device::cpu>> orientationsHalf,
           std::optional<nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>> scales,
           std::optional<Array1<uint32_t>> selection, std::optional<Matrix4d> local) {
            auto arrays = std::make_shared<InstanceArrays>();
            nb::list owners;
            arrays->positions = {positions.data(), positions.shape(0) * 3};
            owners.append(nb::cast(positions));
            if (orientations) arrays->orientations = {orientations->data(), orientations->shape(0) * 4}, owners.append(nb::cast(*orientations));
            if (orientationsHalf) arrays->orientationsHalf = {orientationsHalf->data(), orientationsHalf->shape(0) * 4}, owners.append(nb::cast(*orientationsHalf));
            if (scales) arrays->scales = {scales->data(), scales->shape(0) * 3}, owners.append(nb::cast(*scales));
            if (selection) arrays->selection = span_of(selection), owners.append(nb::cast(*selection));
            if (local) arrays->local = *local;
            arrays->validate();
            arrays->keepAlive = keep_alive(owners);
            return arrays;
        },
        "positions"_a, "orientations"_a = nb::none(), "orientations_half"_a = nb::none(), "scales"_a = nb::none(), "selection"_a = nb::none(),
        "local"_a = nb::none(),
        "A PointInstancer's arrays for one prototype: positions (N, 3) float32; orientations (N, 4) float32 or orientations_half "
        "(N, 4) float16 bits as uint16 (i j k r); scales (N, 3) float32; selection: uint32 indices of the instances drawn "
        "(None: all); local: the mesh within the prototype (row-major, column vectors).");
    m.def(
        "instance_set",
        [](nb::ndarray<const double, nb::shape<-1, 4, 4>, nb::c_contig, nb::device::cpu> frames, std::shared_ptr<InstanceArrays> arrays) {
            InstanceSet set;
            set.frames.values = {frames.data(), frames.shape(0) * 16};
            set.frames.keepAlive = keep_alive(nb::cast(frames));
            set.arrays = std::move(arrays);
            return set;
        },
        "frames"_a, nb::arg("arrays").none() = nb::none(),
        "The copies of a prototype: one per frame (row-major (N, 4, 4) float64, column vectors), or every instance of "
        "`arrays` in each frame.");

    nb::enum_<ColorSpace>(m, "ColorSpace").value("auto", ColorSpace::Auto).value("sRGB", ColorSpace::Srgb).value("raw", ColorSpace::Raw);
    nb::enum_<TextureWrap>(m, "TextureWrap")
        .value("repeat", TextureWrap::Repeat)
        .value("mirror", TextureWrap::Mirror)
        .value("clamp", TextureWrap::Clamp)
        .value("black", TextureWrap::Black);
    nb::enum_<TextureChannel>(m, "TextureChannel")
        .value("r", TextureChannel::R)
        .value("g", TextureChannel::G)
        .value("b", TextureChannel::B)
        .value("a", TextureChannel::A)
        .value("rgb", TextureChannel::Rgb);
    nb::enum_<MaterialInput>(m, "MaterialInput")
        .value("diffuseColor", MaterialInput::DiffuseColor)
        .value("emissiveColor", MaterialInput::EmissiveColor)
        .value("specularColor", MaterialInput::SpecularColor)
        .value("metallic", MaterialInput::Metallic)
        .value("roughness", MaterialInput::Roughness)
        .value("opacity", MaterialInput::Opacity)
        .value("occlusion", MaterialInput::Occlusion)
        .value("normal", MaterialInput::Normal)
        .value("displacement", MaterialInput::Displacement);
    // A UsdUVTexture feeding one input (textures.h TextureSlot); the image is loaded when the material syncs.
    nb::class_<TextureSlot>(m, "TextureSlot")
        .def(nb::init<>())
        .def_rw("input", &TextureSlot::input)
        .def_rw("file", &TextureSlot::file)
        .def_rw("color_space", &TextureSlot::colorSpace)
        .def_rw("wrap_s", &TextureSlot::wrapS)
        .def_rw("wrap_t", &TextureSlot::wrapT)
        .def_rw("channel", &TextureSlot::channel)
        .def_rw("scale", &TextureSlot::scale)
        .def_rw("bias", &TextureSlot::bias)
        .def_rw("fallback", &TextureSlot::fallback)
        .def_rw("transform", &TextureSlot::transform)
        .def_prop_ro("loaded", [](const TextureSlot& slot) { return slot.image != nullptr; })
        .def("__repr__", [](const TextureSlot& slot) {
            return std::string("TextureSlot(") + material_input_name(slot.input) + ", '" + slot.file + "')";
        });
    m.def(
        "read_texture",
        [](const std::string& path, ColorSpace colorSpace) {
            const TextureImage t = read_texture(path, colorSpace);
            nb::dict d;
            d["width"] = t.width;
            d["height"] = t.height;
            d["levels"] = t.levels;
            d["channels"] = t.channels;
            d["format"] = texture_format_name(t.format);
            d["bytes"] = t.bytes();
            return d;
        },
        "path"_a, "color_space"_a = ColorSpace::Auto,
        "Reads an image file as the texture pool stores it (every mip level): its size, levels, format and bytes.");
    m.def(
        "latlong_irradiance",
        [](const std::string& path) {
            const auto c = latlong_irradiance(read_texture(path, ColorSpace::Auto));
            return std::vector<float>(c.begin(), c.end());
        },
        "path"_a,
        "A lat-long image's irradiance divided by pi as 9 spherical harmonics coefficients (rgb each), as a dome light uses it.");
    m.def("transform2d", &transform2d, "rotation"_a, "scale"_a, "translation"_a,
          "UsdTransform2d's 2x3 matrix (row-major): scale, then rotate counter-clockwise (degrees), then translate.");

    nb::class_<MaterialDesc>(m, "MaterialDesc")
        .def(nb::init<>())
        .def_rw("diffuse_color", &MaterialDesc::diffuseColor)
        .def_rw("emissive_color", &MaterialDesc::emissiveColor)
        .def_rw("opacity", &MaterialDesc::opacity)
        .def_rw("opacity_threshold", &MaterialDesc::opacityThreshold)
        .def_rw("metallic", &MaterialDesc::metallic)
        .def_rw("roughness", &MaterialDesc::roughness)
        .def_rw("use_specular_workflow", &MaterialDesc::useSpecularWorkflow)
        .def_rw("specular_color", &MaterialDesc::specularColor)
        .def_rw("ior", &MaterialDesc::ior)
        .def_rw("occlusion", &MaterialDesc::occlusion)
        .def_rw("vertex_inputs", &MaterialDesc::vertexInputs)
        // A list copied in and out: assign a whole list (appending to the copy `textures` returns changes nothing).
        .def_rw("displacement", &MaterialDesc::displacement)
        .def_rw("displacement_magnitude", &MaterialDesc::displacementMagnitude)
        .def_rw("displacement_center", &MaterialDesc::displacementCenter)
        .def_rw("displacement_fade_start", &MaterialDesc::displacementFadeStart)
        .def_rw("displacement_fade_end", &MaterialDesc::displacementFadeEnd)
        .def_rw("displacement_bake", &MaterialDesc::displacementBake)
        .def_rw("textures", &MaterialDesc::textures)
        .def_rw("uv_primvar", &MaterialDesc::uvPrimvar);

    nb::enum_<LightType>(m, "LightType")
        .value("distant", LightType::Distant)
        .value("dome", LightType::Dome)
        .value("rect", LightType::Rect)
        .value("sphere", LightType::Sphere);
    nb::class_<LightDesc>(m, "LightDesc")
        .def(nb::init<>())
        .def_rw("type", &LightDesc::type)
        .def_rw("direction", &LightDesc::direction)
        .def_rw("radiance", &LightDesc::radiance)
        .def_rw("position", &LightDesc::position)
        .def_rw("radius", &LightDesc::radius)
        .def_rw("axis_x", &LightDesc::axisX)
        .def_rw("axis_y", &LightDesc::axisY)
        .def_rw("texture_file", &LightDesc::textureFile);

    nb::class_<CameraDesc>(m, "CameraDesc")
        .def(nb::init<>())
        .def_rw("camera_to_world", &CameraDesc::cameraToWorld)
        .def_rw("orthographic", &CameraDesc::orthographic)
        .def_rw("focal_length", &CameraDesc::focalLength)
        .def_rw("horizontal_aperture", &CameraDesc::horizontalAperture)
        .def_rw("vertical_aperture", &CameraDesc::verticalAperture)
        .def_rw("horizontal_aperture_offset", &CameraDesc::horizontalApertureOffset)
        .def_rw("vertical_aperture_offset", &CameraDesc::verticalApertureOffset)
        .def_rw("near_clip", &CameraDesc::nearClip)
        .def_rw("far_clip", &CameraDesc::farClip);

    nb::class_<SceneDelegate, PySceneDelegate>(m, "SceneDelegate")
        .def(nb::init<>())
        .def("get_mesh", &SceneDelegate::get_mesh)
        .def("get_transform", &SceneDelegate::get_transform)
        .def("get_visible", &SceneDelegate::get_visible)
        .def("get_material_id", &SceneDelegate::get_material_id)
        .def("get_instances", &SceneDelegate::get_instances)
        .def("get_material", &SceneDelegate::get_material)
        .def("get_light", &SceneDelegate::get_light)
        .def("get_camera", &SceneDelegate::get_camera)
        .def("get_subset_material_ids", &SceneDelegate::get_subset_material_ids)
        .def("get_extent", &SceneDelegate::get_extent);

    nb::class_<Image>(m, "Image")
        .def_ro("width", &Image::width)
        .def_ro("height", &Image::height)
        .def_prop_ro("aov", [](const Image& i) { return std::string(aov_name(i.aov)); })
        .def_prop_ro(
            "pixels",
            [](const Image& i) {
                // A read-only float32 (height, width, 4) view; ids are in channel 0 as uint32 bits (see ids()).
                return nb::ndarray<const float, nb::numpy, nb::shape<-1, -1, 4>>(i.pixels.data(), {i.height, i.width, 4}, nb::handle());
            },
            nb::rv_policy::reference_internal)
        .def(
            "ids",
            [](const Image& i) {
                auto* ids = new std::vector<uint32_t>(size_t(i.width) * i.height);
                for (size_t p = 0; p < ids->size(); ++p) std::memcpy(&(*ids)[p], &i.pixels[4 * p], 4);
                nb::capsule owner(ids, [](void* v) noexcept { delete static_cast<std::vector<uint32_t>*>(v); });
                return nb::ndarray<uint32_t, nb::numpy, nb::shape<-1, -1>>(ids->data(), {i.height, i.width}, owner);
            },
            "The id AOV as uint32 (height, width); 0xffffffff where nothing was drawn.")
        .def(
            "write",
            [](const Image& i, const std::string& path, const std::string& ocioConfig, const std::string& display, const std::string& view) {
                write_image(path, i, ocioConfig, display, view);
            },
            "path"_a, "ocio_config"_a, "display"_a = "", "view"_a = "");

    m.def(
        "read_image",
        [](const std::string& path) {
            auto* image = new LoadedImage(read_image(path));
            nb::capsule owner(image, [](void* v) noexcept { delete static_cast<LoadedImage*>(v); });
            return nb::ndarray<float, nb::numpy, nb::shape<-1, -1, 4>>(image->pixels.data(), {image->height, image->width, 4}, owner);
        },
        "path"_a, "Reads an image as float32 RGBA (height, width, 4).");

    m.attr("MOST_PIXEL_SAMPLES") = kMostPixelSamples;
    m.attr("DEFAULT_SOFTWARE_RASTER_AREA") = RenderSettings{}.softwareRasterArea;
    m.def(
        "pixel_sample_offset", [](uint32_t index, const std::string& filter) { return pixel_sample_offset(index, pixel_filter_from(filter)); },
        "index"_a, "filter"_a = "box",
        "Where anti-aliasing sample `index` lies, (x right, y down) in pixels from the pixel's centre: evenly spread over "
        "[-0.5, 0.5) for the box filter, over (-1, 1) and denser towards the centre for the gaussian; sample 0 is the centre.");

    m.def("core_count", &core_count,
          "The cores this process may run on (its CPU affinity: a taskset or a cpuset limits it): the builder, the mesh "
          "table and the renderer's uploads start a thread per core.");

    m.def("release_shared_devices", &Device::release_shared_devices,
          "Lets go of the devices sessions share (each goes when its last session does); called at exit.");

    nb::class_<RenderDelegate>(m, "RenderDelegate")
        .def(
            "__init__",
            [](RenderDelegate* self, std::optional<std::string> device, std::optional<bool> validation) {
                DeviceOptions options = DeviceOptions::from_environment();
                if (device) options.select = *device;
                if (validation) options.validation = *validation;
                new (self) RenderDelegate(options);
            },
            "device"_a = nb::none(), "validation"_a = nb::none())
        .def_prop_ro("device_name", [](RenderDelegate& d) { return d.device().name(); })
        .def_prop_ro("software_device", [](RenderDelegate& d) { return d.device().is_software(); })
        .def_prop_ro("validation_enabled", [](RenderDelegate& d) { return d.device().validation_enabled(); })
        .def("take_validation_messages", [](RenderDelegate& d) { return d.device().take_validation_messages(); })
        .def_prop_ro("validation_error_count", [](RenderDelegate& d) { return d.device().validation_error_count(); })
        .def_prop_ro("cache_directory", [](RenderDelegate& d) { return d.cache().directory(); })
        .def("set_visible_cluster_capacity", [](RenderDelegate& d, uint32_t c) { in_turn(d, [&] { d.renderer().set_visible_cluster_capacity(c); }); })
        .def("set_patch_capacity", [](RenderDelegate& d, uint32_t c) { in_turn(d, [&] { d.renderer().set_patch_capacity(c); }); })
        .def("set_point_capacity", [](RenderDelegate& d, uint32_t c) { in_turn(d, [&] { d.renderer().set_point_capacity(c); }); })
        .def_static("supported_rprim_types", &RenderDelegate::supported_rprim_types)
        .def_static("supported_sprim_types", &RenderDelegate::supported_sprim_types)
        .def_static("supported_bprim_types", &RenderDelegate::supported_bprim_types);

    nb::class_<RenderIndex>(m, "RenderIndex")
        .def(nb::init<RenderDelegate&>(), "delegate"_a, nb::keep_alive<1, 2>())
        .def("insert_rprim", [](RenderIndex& index, const std::string& type, const PrimId& id, const PrimId& instancerId, uint32_t defaults) {
                 in_turn(index.delegate(), [&] { index.insert_rprim(type, id, instancerId, defaults); });
             }, "type"_a, "id"_a, "instancer_id"_a = "", "defaults"_a = 0,
             "defaults: dirty bits (VISIBILITY: visible, MATERIAL_ID: no material nor subset materials) the delegate knows "
             "to be in their default state, which the first sync then does not ask for")
        .def(
            "insert_rprims",
            [](RenderIndex& index, const std::string& type, const std::vector<PrimId>& ids, const std::optional<std::vector<uint32_t>>& defaults,
               std::optional<nb::ndarray<const double, nb::shape<-1, 16>, nb::c_contig, nb::device::cpu>> transforms) {
                if (defaults && defaults->size() != ids.size())
                    throw std::invalid_argument(std::to_string(defaults->size()) + " defaults for " + std::to_string(ids.size()) + " ids");
                if (transforms && transforms->shape(0) != ids.size())
                    throw std::invalid_argument(std::to_string(transforms->shape(0)) + " transforms for " + std::to_string(ids.size()) + " ids");
                in_turn(index.delegate(), [&] {
                    for (size_t i = 0; i < ids.size(); ++i) {
                        Matrix4d transform;
                        if (transforms)  // Gf's layout (row vectors): transposed into the C++ convention
                            for (size_t r = 0; r < 4; ++r)
                                for (size_t c = 0; c < 4; ++c) transform[r * 4 + c] = transforms->data()[i * 16 + c * 4 + r];
                        index.insert_rprim(type, ids[i], "", defaults ? (*defaults)[i] : 0u, transforms ? &transform : nullptr);
                    }
                });
            },
            "type"_a, "ids"_a, "defaults"_a = nb::none(), "transforms"_a = nb::none(),
            "insert_rprim for each id in turn (no instancer), with its defaults if given: one call for a whole walk's finds. "
            "`transforms`: (N, 16) world transforms in Gf's layout (row vectors), used where `defaults` has dirty.TRANSFORM.")
        .def("insert_sprim", [](RenderIndex& index, const std::string& type, const PrimId& id) { in_turn(index.delegate(), [&] { index.insert_sprim(type, id); }); },
             "type"_a, "id"_a)
        .def("remove_prim", [](RenderIndex& index, const PrimId& id) { in_turn(index.delegate(), [&] { index.remove_prim(id); }); }, "id"_a)
        .def("mark_dirty", [](RenderIndex& index, const PrimId& id, uint32_t bits) { in_turn(index.delegate(), [&] { index.mark_dirty(id, bits); }); },
             "id"_a, "bits"_a)
        .def("mark_all_dirty", [](RenderIndex& index, uint32_t bits) { in_turn(index.delegate(), [&] { index.mark_all_dirty(bits); }); }, "bits"_a)
        .def(
            "sync_all",
            [](RenderIndex& index, SceneDelegate& scene, const PrimId& camera, uint32_t width, uint32_t height) {
                in_turn(index.delegate(), [&] { index.sync_all(scene, camera, width, height); });
            },
            "scene_delegate"_a, "camera"_a = "", "width"_a = 0, "height"_a = 0,
            "Syncs what is dirty; with a camera sprim and a resolution, meshes that view does not see wait to be built. Runs "
            "without the GIL (the scene delegate's calls take it back), one thread at a time per delegate.")
        .def_prop_ro("meshes_out_of_view", [](RenderIndex& index) { return in_turn(index.delegate(), [&] { return index.meshes_out_of_view(); }); })
        .def(
            "execute",
            [](RenderIndex& index, const std::string& cameraId, const CameraDesc& camera, uint32_t width, uint32_t height,
               const std::vector<std::string>& aovs, std::array<float, 4> background, float pixelError, bool lod,
               const std::string& visualize, const std::string& raster, bool occlusion, float dicingRate, const std::string& rasterVertices,
               float softwareRasterArea, uint32_t pixelSamples, const std::string& pixelFilter, float occlusionMinimumCulled, bool lastFrame) {
                RenderPassSettings settings;
                settings.render.pixelSamples = pixelSamples;
                settings.render.pixelFilter = pixel_filter_from(pixelFilter);
                if (!(dicingRate > 0.0f)) throw nb::value_error("the dicing rate must be a number of pixels > 0");
                if (!(softwareRasterArea > 0.0f) || !std::isfinite(softwareRasterArea))
                    throw nb::value_error("the software raster area must be a number of pixels > 0");
                settings.render.softwareRasterArea = softwareRasterArea;
                settings.render.dicingRate = dicingRate;
                settings.render.pixelError = pixelError;
                settings.render.lod = lod;
                settings.render.occlusion = occlusion;
                settings.render.occlusionMinimumCulled = occlusionMinimumCulled;
                settings.render.lastFrame = lastFrame;
                settings.render.visualize = visualize_from(visualize);
                if (raster == "auto") settings.render.raster = RasterMode::Auto;
                else if (raster == "hardware") settings.render.raster = RasterMode::Hardware;
                else if (raster == "software") settings.render.raster = RasterMode::Software;
                else throw nb::value_error(("unknown raster mode '" + raster + "' (auto, hardware or software)").c_str());
                if (rasterVertices == "auto") settings.render.rasterVertices = RasterVertices::Auto;
                else if (rasterVertices == "shared") settings.render.rasterVertices = RasterVertices::Shared;
                else if (rasterVertices == "per-triangle") settings.render.rasterVertices = RasterVertices::PerTriangle;
                else throw nb::value_error(("unknown raster vertices '" + rasterVertices + "' (auto, shared or per-triangle)").c_str());
                settings.cameraId = cameraId;
                settings.camera = camera;
                settings.render.width = width;
                settings.render.height = height;
                settings.render.background = background;
                settings.aovs.clear();
                for (auto& a : aovs) settings.aovs.push_back(aov_from(a));
                FrameStats stats;
                std::vector<std::shared_ptr<const Image>> images =  // shared with the render buffers
                    in_turn(index.delegate(), [&] { return index.execute(settings, &stats); });
                return std::make_pair(std::move(images), stats_dict(stats));
            },
            "camera_id"_a, "camera"_a, "width"_a, "height"_a, "aovs"_a, "background"_a, "pixel_error"_a = 1.0f, "lod"_a = true,
            "visualize"_a = "none", "raster"_a = "auto", "occlusion"_a = true, "dicing_rate"_a = 1.0f, "raster_vertices"_a = "auto",
            "software_raster_area"_a = RenderSettings{}.softwareRasterArea, "pixel_samples"_a = 1u, "pixel_filter"_a = "box",
            "occlusion_minimum_culled"_a = RenderSettings{}.occlusionMinimumCulled, "last_frame"_a = false)
        .def("prim_path", [](RenderIndex& index, uint32_t primId) { return in_turn(index.delegate(), [&] { return index.prim_path(primId); }); }, "prim_id"_a)
        .def_prop_ro("sync_counts", [](RenderIndex& index) { return in_turn(index.delegate(), [&] { return index.sync_counts(); }); })
        .def_prop_ro(
            "last_synced", [](RenderIndex& index) {
                const auto synced = in_turn(index.delegate(), [&] { return index.last_synced(); });
                nb::dict d;  // prim id -> the dirty bits it was synced with
                for (const auto& [id, bits] : synced) d[nb::cast(id)] = bits;
                return d;
            },
            "The prims the last sync synced: {id: dirty bits} (tessera._tessera.dirty names the bits).")
        .def_prop_ro("rprim_count", [](RenderIndex& index) { return in_turn(index.delegate(), [&] { return index.rprim_count(); }); })
        .def(
            "rprim_transform", [](RenderIndex& index, const PrimId& id) { return in_turn(index.delegate(), [&] { return rprim_of(index, id).transform(); }); },
            "id"_a,
            "The mesh's world transform (row-major, column vectors): as synced, or as given at insertion.")
        .def(
            "rprim_defaults", [](RenderIndex& index, const PrimId& id) { return in_turn(index.delegate(), [&] { return rprim_of(index, id).defaults(); }); },
            "id"_a,
            "The dirty bits whose state the mesh was given at insertion and its next sync will not ask for.")
        .def("take_diagnostics", [](RenderIndex& index) {
            RenderParam p = in_turn(index.delegate(), [&] { return index.take_diagnostics(); });
            nb::dict d;
            d["warnings"] = p.warnings;
            d["errors"] = p.errors;
            d["meshes_built"] = p.meshesBuilt;
            d["meshes_cached"] = p.meshesFromCache;
            d["meshes_shared"] = p.meshesShared;
            return d;
        });

    nb::module_ dirty = m.def_submodule("dirty", "Dirty bits (Hydra's change-tracker bits Tessera reads)");
    dirty.attr("POINTS") = uint32_t(DirtyPoints);
    dirty.attr("TOPOLOGY") = uint32_t(DirtyTopology);
    dirty.attr("TRANSFORM") = uint32_t(DirtyTransform);
    dirty.attr("VISIBILITY") = uint32_t(DirtyVisibility);
    dirty.attr("PRIMVAR") = uint32_t(DirtyPrimvar);
    dirty.attr("MATERIAL_ID") = uint32_t(DirtyMaterialId);
    dirty.attr("INSTANCER") = uint32_t(DirtyInstancer);
    dirty.attr("DOUBLE_SIDED") = uint32_t(DirtyDoubleSided);
    dirty.attr("PARAMS") = uint32_t(DirtyParams);
    dirty.attr("ALL") = uint32_t(AllDirty);

    m.def(
        "cache_mesh",
        [](const MeshSource& source) {
            CachedBuild built;
            {
                nb::gil_scoped_release release;
                built = build_through_cache(source.view, source.settings, MeshCache::from_environment());
            }
            nb::dict d;
            d["cached"] = built.fromCache;
            d["source_triangles"] = built.mesh->sourceTriangles;
            d["warnings"] = built.warnings;
            return d;
        },
        "source"_a, "Builds a mesh into the cache ($TESSERA_CACHE) unless it is there already.");

    m.def(
        "build_mesh",
        [](Array1<float> points, Array1<int32_t> counts, Array1<int32_t> indices, const std::string& name, std::optional<Array1<float>> uvs,
           const std::string& uvInterpolation, const nb::kwargs& kwargs) {
            const BuildSettings settings = settings_from(kwargs);
            MeshView view;
            view.name = name;
            view.points = {points.data(), points.shape(0)};
            view.faceVertexCounts = {counts.data(), counts.shape(0)};
            view.faceVertexIndices = {indices.data(), indices.shape(0)};
            if (uvs) {
                view.uvs = {interpolation_from(uvInterpolation), 2, span_of(uvs), {}};
                if (view.uvs.interpolation == Interpolation::None)
                    throw nb::value_error(("uv_interpolation '" + uvInterpolation + "' is not constant, uniform, vertex, varying or faceVarying").c_str());
            }
            PreparedMesh prepared;
            BuiltMesh built;
            PageLayout layout;
            std::vector<uint8_t> pages;
            {
                nb::gil_scoped_release release;  // building is pure C++: let other Python threads run
                prepared = prepare_mesh(view);
                built = build_mesh(std::move(prepared), settings);  // empties its arrays; its warnings stay
                pages = encode_pages(built, &layout);
            }
            nb::dict d;
            d["source_triangles"] = built.sourceTriangles;
            d["clusters"] = built.clusters.size();
            d["leaf_clusters"] = built.leafClusters;
            d["groups"] = built.groups;
            d["size"] = built.size;
            nb::list levels;
            for (const LevelStats& level : built.levels) {
                nb::dict l;
                l["clusters"] = level.clusters;
                l["triangles"] = level.triangles;
                l["max_error"] = level.maxError;
                l["relative_error"] = built.size > 0 ? level.maxError / built.size : 0.0f;
                levels.append(l);
            }
            d["levels"] = levels;
            uint64_t roots = 0;
            for (const Cluster& c : built.clusters)
                if (std::isinf(c.parentError)) roots += c.triangleCount;
            d["root_triangles"] = roots;
            d["memory_bytes"] = built.positions.size() * 4 + built.normals.size() * 4 + built.colors.size() * 4 + built.triangles.size() * 4 +
                                built.clusters.size() * sizeof(Cluster);
            d["disk_bytes"] = layout.bytes;
            d["pages"] = layout.pages;
            d["root_pages"] = layout.rootPages;
            d["position_precision"] = built.positionPrecision;
            d["leaf_triangles"] = built.leafTriangles;
            d["leaf_error"] = built.leafError;
            d["fallback"] = fallback_dict(built);
            d["settings"] = settings_dict(settings);
            d["warnings"] = prepared.warnings;
            double decodeSeconds = 0;
            {
                nb::gil_scoped_release release;
                built = {};  // freed first: decoding is measured apart from the build's memory
                prepared = {};
                const auto start = std::chrono::steady_clock::now();  // what a cached mesh costs at every render
                decode_pages(pages, name);
                decodeSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            }
            d["decode_seconds"] = decodeSeconds;
            return d;
        },
        "points"_a, "face_vertex_counts"_a, "face_vertex_indices"_a, "name"_a = "mesh", "uvs"_a = nb::none(), "uv_interpolation"_a = "faceVarying",
        "kwargs"_a,
        "Prepares a mesh (with texture coordinates, 2 floats per element of their interpolation, where given) and builds its "
        "cluster DAG with the build settings given as keywords (see tessera.build_mesh); "
        "returns the DAG's statistics (levels, clusters, groups, triangles and error per level, in-memory bytes, page file "
        "bytes, and the seconds its page file takes to decode) and the fallback mesh.");
}
