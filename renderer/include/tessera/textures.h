// Textures for UsdPreviewSurface's UsdUVTexture: image files read with OpenImageIO, mip-mapped on the CPU (box filter,
// in linear light), packed as the GPU texture pool stores them (shaders/shared.h GpuTexture), shared by every
// material that reads the same file with the same colour space. Knows nothing of USD: paths arrive absolute.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace tessera {

// UsdUVTexture inputs:sourceColorSpace. Auto: sRGB for 8-bit images of three or four channels, raw otherwise.
enum class ColorSpace { Auto, Srgb, Raw };
// UsdUVTexture inputs:wrapS / wrapT ('useMetadata' reads as Repeat). Black: transparent black outside [0, 1].
enum class TextureWrap { Repeat, Mirror, Clamp, Black };
// The UsdUVTexture output a material input is connected to.
enum class TextureChannel { R, G, B, A, Rgb };
// UsdPreviewSurface inputs a texture can drive (the order of shared.h's TS_INPUT_*).
enum class MaterialInput { DiffuseColor, EmissiveColor, SpecularColor, Metallic, Roughness, Opacity, Occlusion, Normal, Displacement };
const char* material_input_name(MaterialInput input);

struct TextureError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// One image with its whole mip chain, in the pool's format: RGBA8 (8-bit images; sRGB ones stay encoded and are
// decoded per texel in the shader), R8 (8-bit single-channel images) or RGBA16F (everything else, sRGB decoded at
// load). Rows bottom first. Level l is max(1, size >> l) on each side, down to 1x1; levels start on a word.
struct TextureImage {
    std::string path;
    uint32_t width = 0, height = 0, levels = 0;
    uint32_t format = 0;           // TS_TEXTURE_* | TS_TEXTURE_SRGB
    uint32_t channels = 0;         // in the file
    std::vector<uint32_t> words;   // every level, level 0 first
    std::array<float, 4> minValue{}, maxValue{};  // level 0's range per channel, linear (bounds a displacement)
    int64_t fileTime = 0;          // the file's modification time and size when read: a changed file is read again
    uint64_t fileSize = 0;
    uint64_t bytes() const { return words.size() * 4; }
};

// "rgba8", "rgba8 srgb", "r8", "r8 srgb" or "rgba16f".
const char* texture_format_name(uint32_t format);

// Builds a texture from pixels in memory, top row first: `channels` values per pixel (1 to 4), 8-bit values as
// 0-255 in `bytes` or any other depth as floats in `floats` (exactly one of the two). Used by the file reader and tests.
TextureImage make_texture(uint32_t width, uint32_t height, uint32_t channels, const uint8_t* bytes, const float* floats,
                          ColorSpace colorSpace, std::string path = "");

// Reads an image file (first subimage, level 0) into a texture. Throws TextureError saying why it cannot.
TextureImage read_texture(const std::string& path, ColorSpace colorSpace);

// A lat-long environment image (UsdLuxDomeLight, OpenEXR's convention: +Y the pole, longitude 0 towards +Z, pi/2
// towards +X, longitude +pi at the left edge) as the irradiance it delivers, divided by pi: 9 spherical harmonics
// coefficients (rgb each, band by band) such that sum c_i Y_i(n) is the diffuse radiance a white Lambert surface
// facing n returns (Ramamoorthi and Hanrahan's convolution). Integrated over a mip level at most 128 texels wide.
std::array<float, 27> latlong_irradiance(const TextureImage& image);

// A UsdUVTexture driving one UsdPreviewSurface input: its file and how it is read, the UsdTransform2d on its st,
// and the image once loaded (null until then, and when the file cannot be read: the fallback is used).
struct TextureSlot {
    MaterialInput input = MaterialInput::DiffuseColor;
    std::string file;  // absolute path
    ColorSpace colorSpace = ColorSpace::Auto;
    TextureWrap wrapS = TextureWrap::Repeat, wrapT = TextureWrap::Repeat;
    TextureChannel channel = TextureChannel::Rgb;
    std::array<float, 4> scale{1, 1, 1, 1}, bias{0, 0, 0, 0};
    std::array<float, 4> fallback{0, 0, 0, 1};  // the output when the file cannot be read (no scale or bias applied)
    // UsdTransform2d as a 2x3 matrix, row-major: st' = (t0 t1; t3 t4) st + (t2, t5). A constant (unconnected) st is
    // (0 0 s; 0 0 t).
    std::array<float, 6> transform{1, 0, 0, 0, 1, 0};
    std::shared_ptr<const TextureImage> image;
};

// A texture slot's first output channel at st, read on the CPU as shaders/texture.h reads level 0 (UsdTransform2d, wrap,
// bilinear, scale and bias, the output): for what the CPU computes from a texture (static displacement). The fallback
// without an image.
float sample_slot_level0(const TextureSlot& slot, float s, float t);

// Minima and maxima of one channel of a texture's level 0 (linear, as sample_slot_level0 reads its texels) over blocks
// of texels, and over blocks of those blocks up to the whole image: any rectangle of texels has its range in at most
// 64 look-ups, at the price of the blocks around it (under a third of its larger side, and a block, on each side).
// Bounds what a displacement texture reads under a cluster.
class TextureRange {
public:
    TextureRange(const TextureImage& image, uint32_t channel);
    // Lowest and highest value of texels [x0, x1] x [y0, y1] (inclusive, inside the image), or of a little more.
    std::array<float, 2> texels(uint32_t x0, uint32_t y0, uint32_t x1, uint32_t y1) const;
    uint32_t block() const { return block_; }  // level 0 of the pyramid: one entry per block x block texels

private:
    uint32_t block_ = 1;
    std::vector<std::array<uint32_t, 2>> sizes_;             // entries per row and column, per level
    std::vector<std::vector<std::array<float, 2>>> levels_;  // (min, max) per entry, row by row
};

// The lowest and highest value a slot's reads (sample_slot_level0: UsdTransform2d, wrap, bilinear at level 0, scale and
// bias, its output channel) can return over the rectangle [lo, hi] of st, from the range of the slot's image and
// channel (a TextureRange of it). Conservative by a texel around the rectangle (the GPU's float coordinates).
std::array<float, 2> slot_range(const TextureSlot& slot, const TextureRange& range, std::array<float, 2> lo, std::array<float, 2> hi);

// Row-major 2x3 matrix of UsdTransform2d: scale, then rotate counter-clockwise by `rotationDegrees`, then translate.
std::array<float, 6> transform2d(float rotationDegrees, std::array<float, 2> scale, std::array<float, 2> translation);

// Loaded textures, shared while anyone holds them: two materials reading one file (with one colour space) share an
// image and its GPU memory. A file that changed on disk since it was read is read again.
class TextureStore {
public:
    std::shared_ptr<const TextureImage> load(const std::string& path, ColorSpace colorSpace);
    // Loads the image of every slot in `slots`; a slot whose file cannot be read keeps no image and adds a warning
    // naming the file and `materialName`.
    void load_slots(std::vector<TextureSlot>& slots, const std::string& materialName, std::vector<std::string>& warnings);
    uint64_t files_read() const { return filesRead_; }  // how many times a file was actually read (not shared)

private:
    std::mutex mutex_;
    std::map<std::pair<std::string, ColorSpace>, std::weak_ptr<const TextureImage>> images_;
    uint64_t filesRead_ = 0;
};

}  // namespace tessera
