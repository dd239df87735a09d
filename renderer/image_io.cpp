#include "tessera/image_io.h"

#include "image_files.h"

#include <dlfcn.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <mutex>

namespace tessera {

const ImageFileFunctions& image_files() {
    static const ImageFileFunctions* functions = nullptr;
    static std::string failure;
    static std::once_flag once;
    std::call_once(once, [] {
        const char* name = "libtessera_image_files.so";
        std::string why;
        auto open = [&](const std::string& path) -> void* {
            void* library = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
            if (!library && why.empty()) why = dlerror();
            return library;
        };
        void* library = nullptr;
        Dl_info self{};
        if (dladdr(reinterpret_cast<void*>(&image_files), &self) && self.dli_fname) {
            const std::string binary = self.dli_fname;
            const size_t slash = binary.find_last_of('/');
            if (slash != std::string::npos) library = open(binary.substr(0, slash + 1) + name);
        }
        if (!library) library = open(name);  // the loader's search path: RUNPATH (the test binary), LD_LIBRARY_PATH
        if (library) {
            auto entry = reinterpret_cast<const ImageFileFunctions* (*)()>(dlsym(library, "tessera_image_files"));
            if (!entry) why = "it has no tessera_image_files";
            else if (entry()->abi != kImageFilesAbi) why = "it is from another build (interface " + std::to_string(entry()->abi) + ", not " +
                                                            std::to_string(kImageFilesAbi) + ")";
            else functions = entry();
        }
        if (!functions)
            failure = std::string("image files are read and written by ") + name + " (OpenImageIO, OpenColorIO), which cannot be loaded: " + why;
    });
    if (!functions) throw ImageIoError(failure);
    return *functions;
}

namespace {

std::string extension_of(const std::string& path) {
    const size_t dot = path.find_last_of('.');
    std::string ext = dot == std::string::npos ? "" : path.substr(dot + 1);
    std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
    return ext;
}

uint32_t id_bits(float f) {
    uint32_t bits;
    std::memcpy(&bits, &f, 4);
    return bits;
}

// A stable, well-spread colour per id (background stays black).
void id_color(uint32_t id, float rgb[3]) {
    if (id == 0xffffffffu) {
        rgb[0] = rgb[1] = rgb[2] = 0;
        return;
    }
    uint32_t h = id * 0x9E3779B1u;
    h ^= h >> 15;
    h *= 0x85EBCA77u;
    h ^= h >> 13;
    for (int k = 0; k < 3; ++k) rgb[k] = 0.25f + 0.75f * float((h >> (8 * k)) & 0xff) / 255.0f;
}

}  // namespace

void write_image(const std::string& path, const Image& image, const std::string& ocioConfig, const std::string& display,
                 const std::string& view) {
    const std::string ext = extension_of(path);
    const bool floatFormat = ext == "exr" || ext == "hdr" || ext == "tif" || ext == "tiff";
    const bool eightBit = ext == "png" || ext == "jpg" || ext == "jpeg";
    if (!floatFormat && !eightBit) throw ImageIoError(path + ": unsupported image format '." + ext + "' (use exr, tif, hdr, png or jpg)");
    const uint32_t n = image.width * image.height;

    const ImageFileFunctions& files = image_files();
    uint32_t channels = 0;
    PixelType stored = PixelType::Float;
    std::vector<std::string> channelNames;
    std::vector<float> floats;
    std::vector<uint32_t> ids;
    const void* data = nullptr;
    if (floatFormat) {
        if (aov_is_id(image.aov) && ext != "hdr") {
            channels = 1, stored = PixelType::UInt32;
            channelNames = {aov_name(image.aov)};
            ids.resize(n);
            for (uint32_t i = 0; i < n; ++i) ids[i] = id_bits(image.pixels[4 * i]);
            data = ids.data();
        } else if (image.aov == Aov::Depth) {
            channels = 1;
            channelNames = {"Z"};
            floats.resize(n);
            for (uint32_t i = 0; i < n; ++i) floats[i] = image.pixels[4 * i];
            data = floats.data();
        } else {
            channels = image.aov == Aov::Color && ext != "hdr" ? 4 : 3;
            if (image.aov == Aov::Normal) channelNames = {"N.x", "N.y", "N.z"};
            floats.resize(size_t(n) * channels);
            for (uint32_t i = 0; i < n; ++i)
                for (int c = 0; c < channels; ++c) floats[size_t(i) * channels + c] = image.pixels[4 * i + c];
            data = floats.data();
        }
    } else {
        // 8-bit: what a person should see.
        channels = ext == "png" ? 4 : 3;  // png keeps coverage as alpha
        stored = PixelType::UInt8;
        std::vector<float> rgba(image.pixels.begin(), image.pixels.end());
        if (image.aov == Aov::Color) {
            const std::string why = files.display_transform(rgba.data(), n, ocioConfig, display, view);
            if (!why.empty()) throw ImageIoError(path + ": " + why);
        } else if (image.aov == Aov::Normal) {
            for (uint32_t i = 0; i < n; ++i) {
                const bool covered = image.pixels[4 * i + 3] > 0;
                for (int c = 0; c < 3; ++c) rgba[4 * i + c] = covered ? 0.5f + 0.5f * image.pixels[4 * i + c] : 0.0f;
                rgba[4 * i + 3] = covered ? 1.0f : 0.0f;
            }
        } else if (image.aov == Aov::Depth) {
            float lo = INFINITY, hi = -INFINITY;
            for (uint32_t i = 0; i < n; ++i)
                if (std::isfinite(image.pixels[4 * i])) {
                    lo = std::min(lo, image.pixels[4 * i]);
                    hi = std::max(hi, image.pixels[4 * i]);
                }
            for (uint32_t i = 0; i < n; ++i) {
                const float z = image.pixels[4 * i];
                const bool covered = std::isfinite(z);
                const float g = covered ? (hi > lo ? 1.0f - 0.8f * (z - lo) / (hi - lo) : 1.0f) : 0.0f;  // near is bright
                rgba[4 * i] = rgba[4 * i + 1] = rgba[4 * i + 2] = g;
                rgba[4 * i + 3] = covered ? 1.0f : 0.0f;
            }
        } else {
            for (uint32_t i = 0; i < n; ++i) {
                const uint32_t id = id_bits(image.pixels[4 * i]);
                id_color(id, &rgba[4 * i]);
                rgba[4 * i + 3] = id == 0xffffffffu ? 0.0f : 1.0f;
            }
        }
        floats.resize(size_t(n) * channels);
        for (uint32_t i = 0; i < n; ++i)
            for (int c = 0; c < channels; ++c) floats[size_t(i) * channels + c] = std::clamp(rgba[4 * i + c], 0.0f, 1.0f);
        data = floats.data();
    }
    const PixelType given = ids.empty() ? PixelType::Float : PixelType::UInt32;
    const std::string why = files.write(path, image.width, image.height, channels, stored, given, channelNames, data);
    if (!why.empty()) throw ImageIoError(path + ": " + why);
}

LoadedImage read_image(const std::string& path) {
    ImageFile file;
    const std::string why = image_files().read(path, false, false, 0, file);
    if (!why.empty()) throw ImageIoError(path + ": " + why);
    LoadedImage image;
    image.width = file.width;
    image.height = file.height;
    const size_t pixels = size_t(file.width) * file.height;
    const uint32_t channels = file.channels;
    image.pixels.assign(pixels * 4, 1.0f);
    for (size_t i = 0; i < pixels; ++i) {
        for (uint32_t c = 0; c < channels; ++c) image.pixels[4 * i + c] = file.floats[i * channels + c];
        if (channels == 1) image.pixels[4 * i + 1] = image.pixels[4 * i + 2] = file.floats[i];
        if (channels == 2) image.pixels[4 * i + 2] = 0;
    }
    return image;
}

}  // namespace tessera
