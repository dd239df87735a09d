// Writing and reading images (OpenImageIO) with the display transform (OpenColorIO) for 8-bit outputs.
#pragma once

#include "tessera/renderer.h"

#include <string>

namespace tessera {

struct ImageIoError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// Writes an AOV to `path`; the format follows the extension (.exr, .tif/.tiff, .png, .jpg/.jpeg, .hdr).
// Float formats (exr, hdr, tif) hold linear colour and raw values (ids as uint32). 8-bit formats hold
// colour through the OCIO display/view (default: the config's default display and view), depth and
// normals remapped for viewing, and ids as distinct colours.
// `ocioConfig` is a config file path; $OCIO, when set, takes precedence.
void write_image(const std::string& path, const Image& image, const std::string& ocioConfig,
                 const std::string& display = "", const std::string& view = "");

// Reads any image OpenImageIO can read as float RGBA, top row first (used by tests).
struct LoadedImage {
    uint32_t width = 0, height = 0;
    std::vector<float> pixels;  // 4 per pixel
};
LoadedImage read_image(const std::string& path);

}  // namespace tessera
