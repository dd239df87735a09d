#include "tessera/image_io.h"

#include <OpenColorIO/OpenColorIO.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>

namespace OCIO = OCIO_NAMESPACE;

namespace tessera {
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

// Colour through the OCIO display transform from the scene-linear role.
void apply_display_transform(std::vector<float>& rgba, uint32_t pixelCount, const std::string& configPath,
                             const std::string& display, const std::string& view) {
    try {
        OCIO::ConstConfigRcPtr config;
        const char* env = std::getenv("OCIO");
        if (env && *env) config = OCIO::Config::CreateFromEnv();
        else config = OCIO::Config::CreateFromFile(configPath.c_str());
        const char* d = display.empty() ? config->getDefaultDisplay() : display.c_str();
        const char* v = view.empty() ? config->getDefaultView(d) : view.c_str();
        OCIO::DisplayViewTransformRcPtr transform = OCIO::DisplayViewTransform::Create();
        transform->setSrc(OCIO::ROLE_SCENE_LINEAR);
        transform->setDisplay(d);
        transform->setView(v);
        OCIO::ConstCPUProcessorRcPtr cpu = config->getProcessor(transform)->getDefaultCPUProcessor();
        OCIO::PackedImageDesc desc(rgba.data(), long(pixelCount), 1, 4);
        cpu->apply(desc);
    } catch (const OCIO::Exception& e) {
        throw ImageIoError(std::string("OpenColorIO: ") + e.what());
    }
}

}  // namespace

void write_image(const std::string& path, const Image& image, const std::string& ocioConfig, const std::string& display,
                 const std::string& view) {
    const std::string ext = extension_of(path);
    const bool floatFormat = ext == "exr" || ext == "hdr" || ext == "tif" || ext == "tiff";
    const bool eightBit = ext == "png" || ext == "jpg" || ext == "jpeg";
    if (!floatFormat && !eightBit) throw ImageIoError(path + ": unsupported image format '." + ext + "' (use exr, tif, hdr, png or jpg)");
    const uint32_t n = image.width * image.height;

    OIIO::ImageSpec spec;
    std::vector<float> floats;
    std::vector<uint32_t> ids;
    const void* data = nullptr;
    if (floatFormat) {
        if (aov_is_id(image.aov) && ext != "hdr") {
            spec = OIIO::ImageSpec(int(image.width), int(image.height), 1, OIIO::TypeDesc::UINT32);
            spec.channelnames = {aov_name(image.aov)};
            ids.resize(n);
            for (uint32_t i = 0; i < n; ++i) ids[i] = id_bits(image.pixels[4 * i]);
            data = ids.data();
        } else if (image.aov == Aov::Depth) {
            spec = OIIO::ImageSpec(int(image.width), int(image.height), 1, OIIO::TypeDesc::FLOAT);
            spec.channelnames = {"Z"};
            floats.resize(n);
            for (uint32_t i = 0; i < n; ++i) floats[i] = image.pixels[4 * i];
            data = floats.data();
        } else {
            const int channels = image.aov == Aov::Color && ext != "hdr" ? 4 : 3;
            spec = OIIO::ImageSpec(int(image.width), int(image.height), channels, OIIO::TypeDesc::FLOAT);
            if (image.aov == Aov::Normal) spec.channelnames = {"N.x", "N.y", "N.z"};
            floats.resize(size_t(n) * channels);
            for (uint32_t i = 0; i < n; ++i)
                for (int c = 0; c < channels; ++c) floats[size_t(i) * channels + c] = image.pixels[4 * i + c];
            data = floats.data();
        }
        if (ext == "exr") spec.attribute("compression", "zip");
    } else {
        // 8-bit: what a person should see.
        const bool alpha = ext == "png";
        const int channels = alpha ? 4 : 3;
        std::vector<float> rgba(image.pixels);
        if (image.aov == Aov::Color) {
            apply_display_transform(rgba, n, ocioConfig, display, view);
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
        spec = OIIO::ImageSpec(int(image.width), int(image.height), channels, OIIO::TypeDesc::UINT8);
        data = floats.data();
    }
    spec.attribute("Software", "Tessera");

    auto out = OIIO::ImageOutput::create(path);
    if (!out) throw ImageIoError(path + ": " + OIIO::geterror());
    if (!out->open(path, spec)) throw ImageIoError(path + ": " + out->geterror());
    const OIIO::TypeDesc sourceType = ids.empty() ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT32;
    if (!out->write_image(sourceType, data)) throw ImageIoError(path + ": " + out->geterror());
    if (!out->close()) throw ImageIoError(path + ": " + out->geterror());
}

LoadedImage read_image(const std::string& path) {
    auto in = OIIO::ImageInput::open(path);
    if (!in) throw ImageIoError(path + ": " + OIIO::geterror());
    const OIIO::ImageSpec& spec = in->spec();
    LoadedImage image;
    image.width = uint32_t(spec.width);
    image.height = uint32_t(spec.height);
    const int channels = spec.nchannels;
    std::vector<float> raw(size_t(spec.width) * spec.height * channels);
    if (!in->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, raw.data())) throw ImageIoError(path + ": " + in->geterror());
    image.pixels.assign(size_t(spec.width) * spec.height * 4, 1.0f);
    for (size_t i = 0; i < size_t(spec.width) * spec.height; ++i) {
        for (int c = 0; c < std::min(channels, 4); ++c) image.pixels[4 * i + c] = raw[i * channels + c];
        if (channels == 1) image.pixels[4 * i + 1] = image.pixels[4 * i + 2] = raw[i];
        if (channels == 2) image.pixels[4 * i + 2] = 0;
    }
    return image;
}

}  // namespace tessera
