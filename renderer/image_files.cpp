// libtessera_image_files.so: image_files.h's functions on OpenImageIO and OpenColorIO.
#include "image_files.h"

#include <OpenColorIO/OpenColorIO.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cstdlib>
#include <strings.h>

namespace OCIO = OCIO_NAMESPACE;

namespace tessera {
namespace {

OIIO::TypeDesc oiio_type(PixelType type) {
    switch (type) {
        case PixelType::UInt8: return OIIO::TypeDesc::UINT8;
        case PixelType::UInt32: return OIIO::TypeDesc::UINT32;
        case PixelType::Float: break;
    }
    return OIIO::TypeDesc::FLOAT;
}

std::string write(const std::string& path, uint32_t width, uint32_t height, uint32_t channels, PixelType stored, PixelType given,
                  const std::vector<std::string>& channelNames, const void* pixels) {
    OIIO::ImageSpec spec(int(width), int(height), int(channels), oiio_type(stored));
    if (!channelNames.empty()) spec.channelnames = channelNames;
    if (path.size() > 4 && strcasecmp(path.c_str() + path.size() - 4, ".exr") == 0) spec.attribute("compression", "zip");
    spec.attribute("Software", "Tessera");
    auto out = OIIO::ImageOutput::create(path);
    if (!out) return OIIO::geterror();
    if (!out->open(path, spec)) return out->geterror();
    if (!out->write_image(oiio_type(given), pixels)) return out->geterror();
    if (!out->close()) return out->geterror();
    return "";
}

std::string read(const std::string& path, bool keepBytes, bool straightAlpha, uint32_t maxSide, ImageFile& image) {
    OIIO::ImageSpec config;
    if (straightAlpha) config.attribute("oiio:UnassociatedAlpha", 1);
    auto in = OIIO::ImageInput::open(path, &config);
    if (!in) {
        const std::string why = OIIO::geterror();
        return why.empty() ? "OpenImageIO cannot read it" : why;
    }
    const OIIO::ImageSpec& spec = in->spec();
    image.width = uint32_t(std::max(spec.width, 0));
    image.height = uint32_t(std::max(spec.height, 0));
    image.depth = uint32_t(std::max(spec.depth, 1));
    image.channels = uint32_t(std::clamp(spec.nchannels, 0, 4));
    if (image.width == 0 || image.height == 0 || image.channels == 0) return "an empty image";
    if (image.depth > 1) return "a volume image";
    if (maxSide && (image.width > maxSide || image.height > maxSide))
        return std::to_string(image.width) + "x" + std::to_string(image.height) + " pixels (at most " + std::to_string(maxSide) +
               " on a side)";
    const size_t values = size_t(image.width) * image.height * image.channels;
    bool ok;
    if (keepBytes && spec.format == OIIO::TypeDesc::UINT8) {
        image.bytes.resize(values);
        ok = in->read_image(0, 0, 0, int(image.channels), OIIO::TypeDesc::UINT8, image.bytes.data());
    } else {
        image.floats.resize(values);
        ok = in->read_image(0, 0, 0, int(image.channels), OIIO::TypeDesc::FLOAT, image.floats.data());
    }
    return ok ? "" : in->geterror();
}

std::string display_transform(float* rgba, size_t pixelCount, const std::string& configPath, const std::string& display,
                              const std::string& view) {
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
        OCIO::PackedImageDesc desc(rgba, long(pixelCount), 1, 4);
        cpu->apply(desc);
    } catch (const OCIO::Exception& e) {
        return std::string("OpenColorIO: ") + e.what();
    }
    return "";
}

const ImageFileFunctions kFunctions{kImageFilesAbi, write, read, display_transform};

}  // namespace
}  // namespace tessera

extern "C" __attribute__((visibility("default"))) const tessera::ImageFileFunctions* tessera_image_files() {
    return &tessera::kFunctions;
}
