// Subdivision surfaces: Catmull-Clark, Loop and bilinear meshes refined uniformly with OpenSubdiv before
// triangulation, so that the cluster DAG starts from the surface, not its control cage.
#include "subdivide.h"

#include <opensubdiv/far/primvarRefiner.h>
#include <opensubdiv/far/topologyDescriptor.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <unordered_set>

namespace tessera {
namespace {

using namespace OpenSubdiv;

template <int N>
struct Value {  // the value types OpenSubdiv's primvar refiner interpolates
    float v[N];
    void Clear() {
        for (float& x : v) x = 0.0f;
    }
    void AddWithWeight(const Value& src, float weight) {
        for (int k = 0; k < N; ++k) v[k] += weight * src.v[k];
    }
};
using Vec3 = Value<3>;
using Channel = Value<kChannelComponents>;  // the vertex channel (colours)
using Vec2 = Value<2>;
using Scalar = Value<1>;

Sdc::SchemeType scheme_type(SubdivisionScheme scheme) {
    switch (scheme) {
        case SubdivisionScheme::Loop: return Sdc::SCHEME_LOOP;
        case SubdivisionScheme::Bilinear: return Sdc::SCHEME_BILINEAR;
        default: return Sdc::SCHEME_CATMARK;
    }
}

Sdc::Options::VtxBoundaryInterpolation boundary_interpolation(BoundaryInterpolation b) {
    switch (b) {
        case BoundaryInterpolation::None: return Sdc::Options::VTX_BOUNDARY_NONE;
        case BoundaryInterpolation::EdgeOnly: return Sdc::Options::VTX_BOUNDARY_EDGE_ONLY;
        default: return Sdc::Options::VTX_BOUNDARY_EDGE_AND_CORNER;
    }
}

Sdc::Options::FVarLinearInterpolation fvar_interpolation(FaceVaryingLinear f) {
    switch (f) {
        case FaceVaryingLinear::None: return Sdc::Options::FVAR_LINEAR_NONE;
        case FaceVaryingLinear::CornersOnly: return Sdc::Options::FVAR_LINEAR_CORNERS_ONLY;
        case FaceVaryingLinear::CornersPlus2: return Sdc::Options::FVAR_LINEAR_CORNERS_PLUS2;
        case FaceVaryingLinear::Boundaries: return Sdc::Options::FVAR_LINEAR_BOUNDARIES;
        case FaceVaryingLinear::All: return Sdc::Options::FVAR_LINEAR_ALL;
        default: return Sdc::Options::FVAR_LINEAR_CORNERS_PLUS1;
    }
}

uint64_t edge_key(int32_t a, int32_t b) {
    return (uint64_t(uint32_t(std::min(a, b))) << 32) | uint32_t(std::max(a, b));
}

// USD's crease chains as OpenSubdiv's sharp edges (vertex pairs, one weight each). Tags that do not fit together
// (lengths that do not sum to the indices, a chain of fewer than 2 points, an index outside the points, a count of
// sharpnesses that is neither one per crease nor one per edge, a non-finite sharpness) are a warning and all creases
// are ignored; a pair of points that is not an edge of the mesh is a warning and that edge alone is ignored.
void crease_edges(const MeshView& mesh, std::span<const int32_t> counts, std::span<const int32_t> indices, int pointCount,
                  std::vector<int32_t>& pairs, std::vector<float>& weights, std::vector<std::string>& warnings) {
    const SubdivisionTags& tags = mesh.subdivisionTags;
    if (tags.creaseIndices.empty() && tags.creaseLengths.empty() && tags.creaseSharpnesses.empty()) return;
    auto ignore = [&](const std::string& why) { warnings.push_back(mesh.name + ": creases ignored: " + why); };
    size_t points = 0, edges = 0;
    for (int32_t length : tags.creaseLengths) {
        if (length < 2) return ignore("a crease of " + std::to_string(length) + " point(s) in creaseLengths (at least 2)");
        points += size_t(length);
        edges += size_t(length) - 1;
    }
    if (points != tags.creaseIndices.size())
        return ignore("creaseLengths sum to " + std::to_string(points) + " but creaseIndices has " + std::to_string(tags.creaseIndices.size()) +
                      " entries");
    const bool perCrease = tags.creaseSharpnesses.size() == tags.creaseLengths.size();
    if (!perCrease && tags.creaseSharpnesses.size() != edges)
        return ignore(std::to_string(tags.creaseSharpnesses.size()) + " creaseSharpnesses for " + std::to_string(tags.creaseLengths.size()) +
                      " crease(s) of " + std::to_string(edges) + " edge(s) (one per crease or one per edge)");
    for (int32_t p : tags.creaseIndices)
        if (p < 0 || p >= pointCount)
            return ignore("creaseIndices has " + std::to_string(p) + ", outside the points 0.." + std::to_string(pointCount - 1));
    for (float sharpness : tags.creaseSharpnesses)
        if (!std::isfinite(sharpness)) return ignore("a creaseSharpnesses value is not finite");

    std::unordered_set<uint64_t> meshEdges;
    for (size_t f = 0, start = 0; f < counts.size(); start += size_t(counts[f]), ++f)
        for (int32_t c = 0; c < counts[f]; ++c) meshEdges.insert(edge_key(indices[start + c], indices[start + (c + 1) % counts[f]]));
    size_t missing = 0, at = 0, edge = 0;
    std::string firstMissing;
    for (size_t crease = 0; crease < tags.creaseLengths.size(); at += size_t(tags.creaseLengths[crease]), ++crease)
        for (int32_t k = 0; k + 1 < tags.creaseLengths[crease]; ++k, ++edge) {
            const int32_t a = tags.creaseIndices[at + k], b = tags.creaseIndices[at + k + 1];
            if (!meshEdges.count(edge_key(a, b))) {
                if (missing++ == 0) firstMissing = "(" + std::to_string(a) + ", " + std::to_string(b) + ")";
                continue;
            }
            pairs.insert(pairs.end(), {a, b});
            weights.push_back(tags.creaseSharpnesses[perCrease ? crease : edge]);
        }
    if (missing)
        warnings.push_back(mesh.name + ": " + std::to_string(missing) + " crease edge(s) are not edges of the mesh, first " + firstMissing +
                           "; those are ignored");
}

// USD's corners, or none with a warning when the tags do not fit together.
bool corners_usable(const MeshView& mesh, int pointCount, std::vector<std::string>& warnings) {
    const SubdivisionTags& tags = mesh.subdivisionTags;
    auto ignore = [&](const std::string& why) {
        warnings.push_back(mesh.name + ": corners ignored: " + why);
        return false;
    };
    if (tags.cornerIndices.size() != tags.cornerSharpnesses.size())
        return ignore(std::to_string(tags.cornerIndices.size()) + " cornerIndices but " + std::to_string(tags.cornerSharpnesses.size()) +
                      " cornerSharpnesses");
    for (int32_t p : tags.cornerIndices)
        if (p < 0 || p >= pointCount)
            return ignore("cornerIndices has " + std::to_string(p) + ", outside the points 0.." + std::to_string(pointCount - 1));
    for (float sharpness : tags.cornerSharpnesses)
        if (!std::isfinite(sharpness)) return ignore("a cornerSharpnesses value is not finite");
    return !tags.cornerIndices.empty();
}

}  // namespace

bool refine_subdivision(const MeshView& mesh, std::span<const int32_t> counts, std::span<const int32_t> indices, std::span<const int32_t> holes,
                        const float* uniformColors, const FaceVaryingUvs& uvs, std::span<const int32_t> faceMaterials, RefinedMesh& out,
                        std::string& problem, std::vector<std::string>& warnings) {
    const int pointCount = int(mesh.points.size() / 3);
    if (mesh.subdivisionScheme == SubdivisionScheme::Loop)
        for (int32_t c : counts)
            if (c != 3) {
                problem = "Loop subdivision needs triangles only";
                return false;
            }
    Far::TopologyDescriptor descriptor;
    descriptor.numVertices = pointCount;
    descriptor.numFaces = int(counts.size());
    descriptor.numVertsPerFace = counts.data();
    descriptor.vertIndicesPerFace = indices.data();
    descriptor.numHoles = int(holes.size());
    descriptor.holeIndices = holes.data();
    descriptor.isLeftHanded = mesh.leftHanded;
    const bool hasUvs = !uvs.indices.empty();
    Far::TopologyDescriptor::FVarChannel uvChannel;
    if (hasUvs) {
        uvChannel.numValues = int(uvs.values.size() / 2);
        uvChannel.valueIndices = uvs.indices.data();
        descriptor.numFVarChannels = 1;
        descriptor.fvarChannels = &uvChannel;
    }
    // Subdivision tags (UsdGeomMesh's, USD's fallbacks by default), as Storm hands them to OpenSubdiv.
    const SubdivisionTags& tags = mesh.subdivisionTags;
    std::vector<int32_t> creasePairs;
    std::vector<float> creaseWeights;
    crease_edges(mesh, counts, indices, pointCount, creasePairs, creaseWeights, warnings);
    descriptor.numCreases = int(creaseWeights.size());
    descriptor.creaseVertexIndexPairs = creasePairs.data();
    descriptor.creaseWeights = creaseWeights.data();
    if (corners_usable(mesh, pointCount, warnings)) {
        descriptor.numCorners = int(tags.cornerIndices.size());
        descriptor.cornerVertexIndices = tags.cornerIndices.data();
        descriptor.cornerWeights = tags.cornerSharpnesses.data();
    }
    Sdc::Options options;
    options.SetVtxBoundaryInterpolation(boundary_interpolation(tags.interpolateBoundary));
    options.SetFVarLinearInterpolation(fvar_interpolation(tags.faceVaryingLinearInterpolation));
    options.SetTriangleSubdivision(tags.triangleSubdivisionRule == TriangleSubdivision::Smooth ? Sdc::Options::TRI_SUB_SMOOTH
                                                                                               : Sdc::Options::TRI_SUB_CATMARK);
    using Factory = Far::TopologyRefinerFactory<Far::TopologyDescriptor>;
    std::unique_ptr<Far::TopologyRefiner> refiner(Factory::Create(descriptor, Factory::Options(scheme_type(mesh.subdivisionScheme), options)));
    if (!refiner) {
        problem = "OpenSubdiv rejected the topology";
        return false;
    }
    const int levels = mesh.refineLevel;
    Far::TopologyRefiner::UniformOptions uniformOptions(levels);
    uniformOptions.fullTopologyInLastLevel = hasUvs;  // the last level's face-varying indices
    refiner->RefineUniform(uniformOptions);

    // Positions through the scheme; colours linearly (vertex / varying) or per face (uniform).
    Far::PrimvarRefiner primvars(*refiner);
    std::vector<Vec3> points(refiner->GetNumVerticesTotal());
    for (int p = 0; p < pointCount; ++p)
        for (int k = 0; k < 3; ++k) points[p].v[k] = mesh.points[3 * p + k];
    const bool vertexColors = mesh.displayColor.interpolation == Interpolation::Vertex || mesh.displayColor.interpolation == Interpolation::Varying;
    std::vector<Channel> colors(vertexColors ? points.size() : 0);
    const int width = std::min(mesh.displayColor.components, kChannelComponents);
    if (vertexColors)
        for (int p = 0; p < pointCount; ++p) {
            const int32_t index = mesh.displayColor.indices.empty() ? p : mesh.displayColor.indices[p];
            colors[p].v[kChannelComponents - 1] = 1.0f;  // a 3-component displayColor's alpha
            for (int k = 0; k < width; ++k) colors[p].v[k] = mesh.displayColor.values[size_t(mesh.displayColor.components) * index + k];
        }
    size_t faceTotal = 0;
    for (int l = 0; l <= levels; ++l) faceTotal += size_t(refiner->GetLevel(l).GetNumFaces());
    std::vector<Channel> faceColors(uniformColors ? faceTotal : 0);
    if (uniformColors)
        for (size_t f = 0; f < counts.size(); ++f)
            for (int k = 0; k < kChannelComponents; ++k) faceColors[f].v[k] = uniformColors[kChannelComponents * f + k];

    size_t uvTotal = 0;
    for (int l = 0; hasUvs && l <= levels; ++l) uvTotal += size_t(refiner->GetLevel(l).GetNumFVarValues(0));
    std::vector<Vec2> uvValues(uvTotal);
    for (size_t i = 0; i < uvs.values.size() / 2; ++i) uvValues[i] = {{uvs.values[2 * i], uvs.values[2 * i + 1]}};

    // Material slots are face-uniform values: each refined face takes its parent's (exact in float up to 2^24).
    std::vector<Scalar> slots(faceMaterials.empty() ? 0 : faceTotal);
    for (size_t f = 0; f < faceMaterials.size(); ++f) slots[f].v[0] = float(faceMaterials[f]);
    Scalar* srcSlot = slots.data();

    Vec2* srcUv = uvValues.data();
    Vec3* src = points.data();
    Channel* srcColor = colors.data();
    Channel* srcFace = faceColors.data();
    for (int l = 1; l <= levels; ++l) {
        Vec3* dst = src + refiner->GetLevel(l - 1).GetNumVertices();
        primvars.Interpolate(l, src, dst);
        if (vertexColors) {
            Channel* dstColor = srcColor + refiner->GetLevel(l - 1).GetNumVertices();
            primvars.InterpolateVarying(l, srcColor, dstColor);
            srcColor = dstColor;
        }
        if (uniformColors) {
            Channel* dstFace = srcFace + refiner->GetLevel(l - 1).GetNumFaces();
            primvars.InterpolateFaceUniform(l, srcFace, dstFace);
            srcFace = dstFace;
        }
        if (!slots.empty()) {
            Scalar* dstSlot = srcSlot + refiner->GetLevel(l - 1).GetNumFaces();
            primvars.InterpolateFaceUniform(l, srcSlot, dstSlot);
            srcSlot = dstSlot;
        }
        if (hasUvs) {
            Vec2* dstUv = srcUv + refiner->GetLevel(l - 1).GetNumFVarValues(0);
            primvars.InterpolateFaceVarying(l, srcUv, dstUv, 0);
            srcUv = dstUv;
        }
        src = dst;
    }

    const Far::TopologyLevel& last = refiner->GetLevel(levels);
    out = {};
    for (int v = 0; v < last.GetNumVertices(); ++v) out.points.insert(out.points.end(), src[v].v, src[v].v + 3);
    if (vertexColors)
        for (int v = 0; v < last.GetNumVertices(); ++v) out.colors.insert(out.colors.end(), srcColor[v].v, srcColor[v].v + kChannelComponents);
    for (int f = 0; f < last.GetNumFaces(); ++f) {
        if (last.IsFaceHole(f)) continue;
        const Far::ConstIndexArray face = last.GetFaceVertices(f);
        out.counts.push_back(face.size());
        for (int i = 0; i < face.size(); ++i) out.indices.push_back(face[i]);
        if (uniformColors) out.colors.insert(out.colors.end(), srcFace[f].v, srcFace[f].v + kChannelComponents);
        if (!slots.empty()) out.faceMaterials.push_back(int32_t(srcSlot[f].v[0]));
        if (hasUvs) {
            const Far::ConstIndexArray values = last.GetFaceFVarValues(f, 0);
            out.uvIndices.insert(out.uvIndices.end(), values.begin(), values.end());
        }
    }
    for (int i = 0; hasUvs && i < last.GetNumFVarValues(0); ++i) out.uvs.insert(out.uvs.end(), srcUv[i].v, srcUv[i].v + 2);
    out.colorInterpolation = vertexColors ? Interpolation::Vertex : uniformColors ? Interpolation::Uniform : Interpolation::None;
    return true;
}

}  // namespace tessera
