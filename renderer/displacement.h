// What the renderer prepares on the CPU for meshes drawn displaced (runtime tessellation, shaders/tessellation.h):
// the normals displacement moves along, the UV seams that keep it crack-free, and per-cluster bounds on how far it
// moves each cluster (from the displacement texture's range under the cluster). Private to the renderer.
#pragma once

#include "tessera/builder.h"
#include "tessera/renderer.h"
#include "tessera/textures.h"

#include "shared.h"

#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <utility>
#include <vector>

namespace tessera {

// Per vertex, the direction displacement moves it: the mean of the distinct normals that the source (level 0) has at
// its position, so that split vertices (hard edges, UV seams) move alike and a displaced hard edge does not tear.
std::vector<uint32_t> displacement_normals(const BuiltMesh& mesh);

// The UV seams of a mesh drawn displaced, appended to `words` in the layout of shaders/shared.h (TS_SEAM_COUNT_SHIFT).
// Returns {first vertex word, first triangle word}, or {TS_NO_STREAM, TS_NO_STREAM} for a mesh without seams.
std::array<uint32_t, 2> append_uv_seams(const BuiltMesh& mesh, std::vector<uint32_t>& words);

// The texture coordinates a displaced cluster reads its displacement at, as boxes (s0, t0, s1, t1): its vertices' own,
// and the other sides' its UV seams also read (empty, s0 > s1, without seams). A mesh without UVs reads st = (0, 0).
struct ClusterUvBoxes {
    std::array<float, 4> own, seams;
};
// `seamWords` and `seams` as append_uv_seams left and returned them.
std::vector<ClusterUvBoxes> cluster_uv_boxes(const BuiltMesh& mesh, const std::vector<uint32_t>& seamWords, std::array<uint32_t, 2> seams);

// What a mesh drawn displaced carries beside its streams, made once per mesh (hash tables over every vertex and edge of
// every level: a 1 M-triangle mesh takes about a second) and kept by the renderer while the mesh is drawn displaced, so
// that an edit elsewhere in the scene does not make it again.
struct DisplacementData {
    std::vector<uint32_t> normals;    // displacement_normals()
    std::vector<uint32_t> seamWords;  // append_uv_seams() into an empty list (word numbers from 0: see append_seam_words)
    std::array<uint32_t, 2> seams{TS_NO_STREAM, TS_NO_STREAM};
    uint32_t triangles = 0;           // the triangle words' count (the mesh's triangles)
    std::vector<ClusterUvBoxes> uvBoxes;
};
DisplacementData displacement_data(const BuiltMesh& mesh);
// Appends `data`'s seam words to `words`, the word numbers they hold moved to where they land; returns its seams
// {first vertex word, first triangle word} there, or {TS_NO_STREAM, TS_NO_STREAM} for a mesh without seams. Throws
// std::runtime_error where the words would outgrow the numbers a vertex word holds (2^TS_SEAM_COUNT_SHIFT).
std::array<uint32_t, 2> append_seam_words(const DisplacementData& data, std::vector<uint32_t>& words);
// Words [first, end) of `data`'s seam words into `to`, as placed at word `base` (append_seam_words, a part at a time).
void place_seam_words(const DisplacementData& data, uint32_t base, size_t first, size_t end, uint32_t* to);

// The largest offset (mesh units, any sign) a material moves a surface by, for displacement values in [low, high].
float displacement_bound(const MaterialDesc& material, float low, float high);
// The same over everything the material can read (its texture's level 0, or its constant); 0 when it does not
// displace at render time (no offset, or baked into the mesh).
float material_displacement_bound(const MaterialDesc& material);

// Per cluster, the largest offset its materials move it by: from the range of their displacement texture under the
// cluster's UV boxes (TextureRange pyramids, made once per image and channel and kept), at most the materials' own
// bounds. `materials` by material slot (one entry for a mesh with a single material; null: not displaced).
class ClusterDisplacementBounds {
public:
    std::vector<float> compute(const BuiltMesh& mesh, const std::vector<ClusterUvBoxes>& boxes, const std::vector<const MaterialDesc*>& materials);
    void clear() { ranges_.clear(); }  // drops the pyramids (the materials changed)

private:
    const TextureRange& range(const TextureSlot& slot);
    std::map<std::pair<const TextureImage*, uint32_t>, std::pair<std::shared_ptr<const TextureImage>, std::unique_ptr<TextureRange>>> ranges_;
};

}  // namespace tessera
