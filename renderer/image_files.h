// Image files through OpenImageIO and OpenColorIO, kept in their own library (libtessera_image_files.so) that is
// loaded the first time a file is read or written. Those two libraries bring about 260 others with them: 0.3 s
// and 130 MB to every process that links them, which a render that reads no texture and writes no file never needs.
// image_io.cpp and textures.cpp hold what Tessera does with the pixels; this boundary only moves them.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace tessera {

// An image file's first subimage, level 0, top row first.
struct ImageFile {
    uint32_t width = 0, height = 0, depth = 1;
    uint32_t channels = 0;          // at most 4: the first channels of the file
    std::vector<uint8_t> bytes;     // 8-bit files when asked to keep them so, else empty
    std::vector<float> floats;      // every other file
};

enum class PixelType : uint32_t { UInt8, UInt32, Float };

// Raised when the library behind image_files() cannot be loaded: declared with ImageIoError in image_io.h.
// Each function returns "" on success, else why it failed (no exception crosses the library boundary).
struct ImageFileFunctions {
    uint32_t abi;  // kImageFilesAbi of the library's build: a library left from another build is refused
    // Writes `channels` values per pixel given as `given` (UInt8 are 0-255 bytes, the others 32-bit) into `stored`.
    std::string (*write)(const std::string& path, uint32_t width, uint32_t height, uint32_t channels, PixelType stored,
                         PixelType given, const std::vector<std::string>& channelNames, const void* pixels);
    // Reads up to 4 channels: 8-bit files into `bytes` when `keepBytes`, everything else into `floats`.
    // `straightAlpha` reads colours as stored (no premultiplication). Images wider or taller than `maxSide`
    // (0: no limit) are refused before their pixels are read.
    std::string (*read)(const std::string& path, bool keepBytes, bool straightAlpha, uint32_t maxSide, ImageFile& image);
    // Scene-linear RGBA in place through the display/view of `config` (a file; $OCIO, when set, wins); an empty
    // display or view is the config's default.
    std::string (*display_transform)(float* rgba, size_t pixelCount, const std::string& config, const std::string& display,
                                     const std::string& view);
};

constexpr uint32_t kImageFilesAbi = 1;

// The library's functions, loaded once: from beside the binary that holds this code (the Python extension's
// folder), else through the loader's search path. Throws ImageIoError naming the library and why it cannot load.
const ImageFileFunctions& image_files();

}  // namespace tessera

// The one symbol the library exports.
extern "C" const tessera::ImageFileFunctions* tessera_image_files();
