#include "tessera/device.h"
#include "shared.h"

#include <algorithm>
#include <bit>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <map>
#include <stdexcept>
#include <tuple>
#include <utility>

namespace tessera {

void check_vk(VkResult result, const char* what) {
    if (result != VK_SUCCESS) throw DeviceError(std::string("Vulkan call failed: ") + what + " (VkResult " + std::to_string(int(result)) + ")");
}

DeviceOptions DeviceOptions::from_environment() {
    DeviceOptions options;
    if (const char* select = std::getenv("TESSERA_DEVICE")) options.select = select;
    options.validation = environment_choice("TESSERA_VALIDATION", "1", "0", false);
    options.stagedUploads = environment_choice("TESSERA_STAGED_UPLOADS", "1", "0", false);
    return options;
}

bool environment_choice(const char* name, const char* on, const char* off, bool fallback) {
    const char* forced = std::getenv(name);
    if (!forced || !*forced) return fallback;
    if (std::strcmp(forced, on) == 0 || std::strcmp(forced, off) == 0) return std::strcmp(forced, on) == 0;
    throw std::invalid_argument(std::string(name) + "='" + forced + "': expected '" + on + "' or '" + off + "'");
}

Buffer& Buffer::operator=(Buffer&& other) noexcept {
    if (this != &other) {
        reset();
        std::swap(handle, other.handle);
        std::swap(address, other.address);
        std::swap(size, other.size);
        std::swap(mapped, other.mapped);
        std::swap(device_, other.device_);
        std::swap(memory_, other.memory_);
    }
    return *this;
}

void Buffer::reset() {
    if (device_) {
        vkDestroyBuffer(device_, handle, nullptr);
        vkFreeMemory(device_, memory_, nullptr);
    }
    handle = VK_NULL_HANDLE;
    memory_ = VK_NULL_HANDLE;
    device_ = VK_NULL_HANDLE;
    address = 0;
    size = 0;
    mapped = nullptr;
}

namespace {

VKAPI_ATTR VkBool32 VKAPI_CALL on_validation_message(VkDebugUtilsMessageSeverityFlagBitsEXT severity, VkDebugUtilsMessageTypeFlagsEXT,
                                                     const VkDebugUtilsMessengerCallbackDataEXT* data, void* user) {
    const bool error = severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
    static_cast<Device*>(user)->record_validation_message(error, data->pMessage);
    return VK_FALSE;
}

bool has_layer(const char* name) {
    uint32_t count = 0;
    vkEnumerateInstanceLayerProperties(&count, nullptr);
    std::vector<VkLayerProperties> layers(count);
    vkEnumerateInstanceLayerProperties(&count, layers.data());
    return std::any_of(layers.begin(), layers.end(), [&](const VkLayerProperties& l) { return std::strcmp(l.layerName, name) == 0; });
}

int type_rank(VkPhysicalDeviceType type) {
    switch (type) {
        case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: return 4;
        case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: return 3;
        case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: return 2;
        case VK_PHYSICAL_DEVICE_TYPE_CPU: return 1;
        default: return 0;
    }
}

// Every buffer's usage: any may be read through a texel buffer view (the renderer's views of its streams, shared.h
// TS_VIEW_*), bound as storage, reached by its address, and copied to and from.
constexpr VkBufferUsageFlags kBufferUsage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT |
                                            VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT |
                                            VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT;

VkDeviceAddress device_address(VkDevice device, VkBuffer buffer) {
    VkBufferDeviceAddressInfo info{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO};
    info.buffer = buffer;
    return vkGetBufferDeviceAddress(device, &info);
}

constexpr VkSubgroupFeatureFlags kSubgroupOperations = VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_VOTE_BIT | VK_SUBGROUP_FEATURE_BALLOT_BIT;

// The features Tessera needs; returns the names of those the device lacks.
std::vector<std::string> missing_features(VkPhysicalDevice device) {
    VkPhysicalDeviceVulkan13Features f13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
    VkPhysicalDeviceVulkan12Features f12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES, &f13};
    VkPhysicalDeviceFeatures2 f{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f12};
    vkGetPhysicalDeviceFeatures2(device, &f);
    std::vector<std::string> missing;
    auto need = [&](VkBool32 have, const std::string& name) { if (!have) missing.push_back(name); };
    need(f.features.shaderInt64, "shaderInt64");
    need(f.features.fragmentStoresAndAtomics, "fragmentStoresAndAtomics");
    need(f12.bufferDeviceAddress, "bufferDeviceAddress");
    need(f12.shaderBufferInt64Atomics, "shaderBufferInt64Atomics");
    need(f13.dynamicRendering, "dynamicRendering");
    need(f13.synchronization2, "synchronization2");
    // Runtime tessellation draws one indirect draw per patch, counted on the GPU.
    need(f.features.multiDrawIndirect, "multiDrawIndirect");
    need(f.features.drawIndirectFirstInstance, "drawIndirectFirstInstance");
    need(f12.drawIndirectCount, "drawIndirectCount");
    // Classify takes its pixels' places in a bin with one atomic per subgroup (frame.h bin_places).
    VkPhysicalDeviceSubgroupProperties subgroup{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES};
    VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &subgroup};
    vkGetPhysicalDeviceProperties2(device, &properties);
    need((subgroup.supportedStages & VK_SHADER_STAGE_COMPUTE_BIT) != 0 &&
             (subgroup.supportedOperations & kSubgroupOperations) == kSubgroupOperations,
         "subgroup basic, vote and ballot operations in compute shaders");
    // Resolve stores each AOV of a frame through a storage buffer binding of its own (shared.h TS_BINDING_OUTPUT), and the
    // rasterizers reach the visibility buffer through one more (TS_BINDING_VISIBILITY).
    const VkPhysicalDeviceLimits& limits = properties.properties.limits;
    constexpr uint32_t storageBuffers = TS_MOST_AOVS + 1;
    need(limits.maxPerStageDescriptorStorageBuffers >= storageBuffers && limits.maxDescriptorSetStorageBuffers >= storageBuffers,
         std::to_string(storageBuffers) + " storage buffers per shader stage");
    // Every pass sees the frame's streams through uniform texel buffer views (shared.h TS_VIEW_*), sampled-image
    // descriptors by the limits' count.
    need(limits.maxPerStageDescriptorSampledImages >= TS_VIEW_COUNT && limits.maxDescriptorSetSampledImages >= TS_VIEW_COUNT,
         std::to_string(TS_VIEW_COUNT) + " texel buffer views per shader stage");
    return missing;
}

}  // namespace

void Device::record_validation_message(bool error, const char* message) {
    std::lock_guard lock(messagesMutex_);
    if (error) ++validationErrors_;
    messages_.push_back(std::string(error ? "validation error: " : "validation warning: ") + message);
}

std::vector<std::string> Device::take_validation_messages() {
    std::lock_guard lock(messagesMutex_);
    return std::exchange(messages_, {});
}

Device::Device(const DeviceOptions& options) : stagedUploads_(options.stagedUploads) {
    uint32_t loaderVersion = 0;
    if (vkEnumerateInstanceVersion(&loaderVersion) != VK_SUCCESS || loaderVersion < VK_API_VERSION_1_3)
        throw DeviceError("the Vulkan loader is older than 1.3 (install libvulkan1 from Debian 12 or newer)");

    const char* validationLayer = "VK_LAYER_KHRONOS_validation";
    std::vector<const char*> layers, extensions;
    if (options.validation) {
        if (!has_layer(validationLayer))
            throw DeviceError("validation was requested but VK_LAYER_KHRONOS_validation is not installed (apt-get install vulkan-validationlayers)");
        layers.push_back(validationLayer);
        extensions.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
    }
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.pApplicationName = "tessera";
    app.apiVersion = VK_API_VERSION_1_3;
    VkValidationFeatureEnableEXT enables[] = {VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT};
    VkValidationFeaturesEXT validationFeatures{VK_STRUCTURE_TYPE_VALIDATION_FEATURES_EXT};
    validationFeatures.enabledValidationFeatureCount = 1;
    validationFeatures.pEnabledValidationFeatures = enables;
    VkInstanceCreateInfo instanceInfo{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    instanceInfo.pNext = options.validation ? &validationFeatures : nullptr;
    instanceInfo.pApplicationInfo = &app;
    instanceInfo.enabledLayerCount = uint32_t(layers.size());
    instanceInfo.ppEnabledLayerNames = layers.data();
    instanceInfo.enabledExtensionCount = uint32_t(extensions.size());
    instanceInfo.ppEnabledExtensionNames = extensions.data();
    if (vkCreateInstance(&instanceInfo, nullptr, &instance_) != VK_SUCCESS)
        throw DeviceError("no Vulkan driver could be loaded (install mesa-vulkan-drivers for the CPU device)");

    if (options.validation) {
        VkDebugUtilsMessengerCreateInfoEXT info{VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT};
        info.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
        info.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
        info.pfnUserCallback = on_validation_message;
        info.pUserData = this;
        auto create = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(vkGetInstanceProcAddr(instance_, "vkCreateDebugUtilsMessengerEXT"));
        check_vk(create(instance_, &info, nullptr, &messenger_), "vkCreateDebugUtilsMessengerEXT");
    }

    uint32_t count = 0;
    vkEnumeratePhysicalDevices(instance_, &count, nullptr);
    std::vector<VkPhysicalDevice> devices(count);
    vkEnumeratePhysicalDevices(instance_, &count, devices.data());
    if (devices.empty()) throw DeviceError("no Vulkan device found (install mesa-vulkan-drivers for the CPU device)");

    // Candidates that can run Tessera, best first.
    struct Candidate {
        VkPhysicalDevice device;
        VkPhysicalDeviceProperties properties;
        uint32_t index;
    };
    std::vector<Candidate> usable;
    std::string rejected;
    for (uint32_t i = 0; i < devices.size(); ++i) {
        VkPhysicalDeviceProperties properties;
        vkGetPhysicalDeviceProperties(devices[i], &properties);
        std::vector<std::string> missing;
        if (properties.apiVersion < VK_API_VERSION_1_3) missing.push_back("Vulkan 1.3");
        for (auto& m : missing_features(devices[i])) missing.push_back(m);
        if (missing.empty()) {
            usable.push_back({devices[i], properties, i});
        } else {
            std::string list;
            for (auto& m : missing) list += (list.empty() ? "" : ", ") + m;
            rejected += std::string(rejected.empty() ? "" : "; ") + properties.deviceName + " lacks " + list;
        }
    }
    std::stable_sort(usable.begin(), usable.end(), [](const Candidate& a, const Candidate& b) {
        return type_rank(a.properties.deviceType) > type_rank(b.properties.deviceType);
    });
    const std::string& select = options.select;
    auto chosen = usable.end();
    if (select.empty()) {
        chosen = usable.begin();
    } else {
        chosen = std::find_if(usable.begin(), usable.end(), [&](const Candidate& c) {
            const bool cpu = c.properties.deviceType == VK_PHYSICAL_DEVICE_TYPE_CPU;
            if (select == "cpu") return cpu;
            if (select == "gpu") return !cpu;
            if (!select.empty() && std::all_of(select.begin(), select.end(), ::isdigit)) return c.index == uint32_t(std::stoul(select));
            return std::string(c.properties.deviceName).find(select) != std::string::npos;
        });
    }
    if (chosen == usable.end()) {
        std::string why = usable.empty() ? "no Vulkan device has the features Tessera needs" : "no usable Vulkan device matches TESSERA_DEVICE=" + select;
        throw DeviceError(why + (rejected.empty() ? "" : " (" + rejected + ")"));
    }
    physical_ = chosen->device;
    name_ = chosen->properties.deviceName;
    software_ = chosen->properties.deviceType == VK_PHYSICAL_DEVICE_TYPE_CPU;
    timestampPeriod_ = chosen->properties.limits.timestampPeriod;
    subPixelBits_ = std::min<uint32_t>(chosen->properties.limits.subPixelPrecisionBits, 8);
    maxTexelBufferElements_ = chosen->properties.limits.maxTexelBufferElements;
    maxStorageBufferRange_ = chosen->properties.limits.maxStorageBufferRange;
    minStorageBufferOffsetAlignment_ = chosen->properties.limits.minStorageBufferOffsetAlignment;
    VkPhysicalDeviceSubgroupProperties subgroup{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES};
    VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &subgroup};
    vkGetPhysicalDeviceProperties2(physical_, &properties);
    subgroupSize_ = subgroup.subgroupSize;
    vkGetPhysicalDeviceMemoryProperties(physical_, &memoryProperties_);

    uint32_t familyCount = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(physical_, &familyCount, nullptr);
    std::vector<VkQueueFamilyProperties> families(familyCount);
    vkGetPhysicalDeviceQueueFamilyProperties(physical_, &familyCount, families.data());
    queueFamily_ = UINT32_MAX;
    for (uint32_t i = 0; i < familyCount && queueFamily_ == UINT32_MAX; ++i)
        if ((families[i].queueFlags & (VK_QUEUE_GRAPHICS_BIT | VK_QUEUE_COMPUTE_BIT)) == (VK_QUEUE_GRAPHICS_BIT | VK_QUEUE_COMPUTE_BIT)) queueFamily_ = i;
    if (queueFamily_ == UINT32_MAX) throw DeviceError(name_ + " has no graphics + compute queue");

    VkPhysicalDeviceVulkan13Features f13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
    f13.dynamicRendering = VK_TRUE;
    f13.synchronization2 = VK_TRUE;
    VkPhysicalDeviceVulkan12Features f12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES, &f13};
    f12.bufferDeviceAddress = VK_TRUE;
    f12.shaderBufferInt64Atomics = VK_TRUE;
    f12.drawIndirectCount = VK_TRUE;
    VkPhysicalDeviceFeatures2 features{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f12};
    features.features.shaderInt64 = VK_TRUE;
    features.features.fragmentStoresAndAtomics = VK_TRUE;
    features.features.multiDrawIndirect = VK_TRUE;
    features.features.drawIndirectFirstInstance = VK_TRUE;
    const float priority = 1.0f;
    VkDeviceQueueCreateInfo queueInfo{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    queueInfo.queueFamilyIndex = queueFamily_;
    queueInfo.queueCount = 1;
    queueInfo.pQueuePriorities = &priority;
    // Optional: host memory imported as device memory, so that AOVs land in their images' own memory (renderer.cpp).
    std::vector<const char*> deviceExtensions;
    uint32_t extensionCount = 0;
    vkEnumerateDeviceExtensionProperties(physical_, nullptr, &extensionCount, nullptr);
    std::vector<VkExtensionProperties> available(extensionCount);
    vkEnumerateDeviceExtensionProperties(physical_, nullptr, &extensionCount, available.data());
    const bool hostImport = std::any_of(available.begin(), available.end(), [](const VkExtensionProperties& e) {
        return std::strcmp(e.extensionName, VK_EXT_EXTERNAL_MEMORY_HOST_EXTENSION_NAME) == 0;
    });
    if (hostImport) deviceExtensions.push_back(VK_EXT_EXTERNAL_MEMORY_HOST_EXTENSION_NAME);
    VkDeviceCreateInfo deviceInfo{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO, &features};
    deviceInfo.queueCreateInfoCount = 1;
    deviceInfo.pQueueCreateInfos = &queueInfo;
    deviceInfo.enabledExtensionCount = uint32_t(deviceExtensions.size());
    deviceInfo.ppEnabledExtensionNames = deviceExtensions.data();
    check_vk(vkCreateDevice(physical_, &deviceInfo, nullptr, &device_), "vkCreateDevice");
    if (hostImport) {
        VkPhysicalDeviceExternalMemoryHostPropertiesEXT host{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_EXTERNAL_MEMORY_HOST_PROPERTIES_EXT};
        VkPhysicalDeviceProperties2 hostProperties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &host};
        vkGetPhysicalDeviceProperties2(physical_, &hostProperties);
        hostPointerProperties_ = reinterpret_cast<PFN_vkGetMemoryHostPointerPropertiesEXT>(vkGetDeviceProcAddr(device_, "vkGetMemoryHostPointerPropertiesEXT"));
        if (hostPointerProperties_) hostImportAlignment_ = std::max<uint64_t>(host.minImportedHostPointerAlignment, 1);
    }
    vkGetDeviceQueue(device_, queueFamily_, 0, &queue_);

    VkCommandPoolCreateInfo poolInfo{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    poolInfo.flags = VK_COMMAND_POOL_CREATE_TRANSIENT_BIT | VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
    poolInfo.queueFamilyIndex = queueFamily_;
    check_vk(vkCreateCommandPool(device_, &poolInfo, nullptr, &commandPool_), "vkCreateCommandPool");
    VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    check_vk(vkCreateFence(device_, &fenceInfo, nullptr, &fence_), "vkCreateFence");
}

namespace {
// Device::shared's devices, by options. Never destroyed by itself: a device must go before the Vulkan loader and driver,
// which static destruction at exit does not promise; release_shared_devices lets go of them in time.
std::mutex sharedDevicesMutex;
using SharedKey = std::tuple<std::string, bool, bool>;  // DeviceOptions: selection, validation, staged uploads
auto& sharedDevices = *new std::map<SharedKey, std::shared_ptr<Device>>;
}  // namespace

std::shared_ptr<Device> Device::shared(const DeviceOptions& options) {
    const std::lock_guard<std::mutex> lock(sharedDevicesMutex);
    const SharedKey key{options.select, options.validation, options.stagedUploads};
    std::shared_ptr<Device>& device = sharedDevices[key];
    if (!device) {
        try {
            device = std::make_shared<Device>(options);
        } catch (...) {
            sharedDevices.erase(key);
            throw;
        }
    }
    return device;
}

void Device::release_shared_devices() {
    std::map<SharedKey, std::shared_ptr<Device>> released;
    {
        const std::lock_guard<std::mutex> lock(sharedDevicesMutex);
        released.swap(sharedDevices);
    }
}

std::shared_ptr<void> Device::shared_state(const std::string& key, const std::function<std::shared_ptr<void>()>& make) {
    const std::lock_guard<std::mutex> lock(sharedStateMutex_);
    std::shared_ptr<void>& state = sharedState_[key];
    if (!state) {
        try {
            state = make();
        } catch (...) {
            sharedState_.erase(key);
            throw;
        }
    }
    return state;
}

Device::~Device() {
    sharedState_.clear();  // what it holds was made on this device
    if (device_) {
        vkDeviceWaitIdle(device_);
        vkDestroyFence(device_, fence_, nullptr);
        vkDestroyCommandPool(device_, commandPool_, nullptr);
        vkDestroyDevice(device_, nullptr);
    }
    if (messenger_) {
        auto destroy = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
        destroy(instance_, messenger_, nullptr);
    }
    if (instance_) vkDestroyInstance(instance_, nullptr);
}

uint32_t Device::find_memory_type(uint32_t typeBits, MemoryUse use) const {
    // Preferred properties first, then the minimum that works.
    std::vector<VkMemoryPropertyFlags> wanted;
    const VkMemoryPropertyFlags host = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    switch (use) {
        case MemoryUse::Device: wanted = {VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT, 0}; break;
        case MemoryUse::Upload: wanted = {host | VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT, host}; break;
        case MemoryUse::Readback: wanted = {host | VK_MEMORY_PROPERTY_HOST_CACHED_BIT, host}; break;
    }
    for (VkMemoryPropertyFlags flags : wanted)
        for (uint32_t i = 0; i < memoryProperties_.memoryTypeCount; ++i)
            if ((typeBits & (1u << i)) && (memoryProperties_.memoryTypes[i].propertyFlags & flags) == flags) return i;
    throw DeviceError("no suitable Vulkan memory type on " + name_);
}

Buffer Device::create_buffer(VkDeviceSize size, MemoryUse use, VkBufferUsageFlags extraUsage) {
    Buffer buffer;
    buffer.device_ = device_;
    buffer.size = std::max<VkDeviceSize>(size, 16);
    VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
    info.size = buffer.size;
    info.usage = kBufferUsage | extraUsage;
    check_vk(vkCreateBuffer(device_, &info, nullptr, &buffer.handle), "vkCreateBuffer");
    VkMemoryRequirements requirements;
    vkGetBufferMemoryRequirements(device_, buffer.handle, &requirements);
    VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO};
    flags.flags = VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT;
    VkMemoryAllocateInfo allocate{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags};
    allocate.allocationSize = requirements.size;
    allocate.memoryTypeIndex = find_memory_type(requirements.memoryTypeBits, use);
    if (vkAllocateMemory(device_, &allocate, nullptr, &buffer.memory_) != VK_SUCCESS)
        throw DeviceError("out of device memory allocating " + std::to_string(size >> 20) + " MiB on " + name_);
    check_vk(vkBindBufferMemory(device_, buffer.handle, buffer.memory_, 0), "vkBindBufferMemory");
    if ((memoryProperties_.memoryTypes[allocate.memoryTypeIndex].propertyFlags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT) &&
        !(use == MemoryUse::Device && stagedUploads_))
        check_vk(vkMapMemory(device_, buffer.memory_, 0, VK_WHOLE_SIZE, 0, &buffer.mapped), "vkMapMemory");
    buffer.address = device_address(device_, buffer.handle);
    return buffer;
}

Buffer Device::import_host_memory(void* pointer, VkDeviceSize bytes) {
    if (!hostImportAlignment_) throw DeviceError(name_ + " cannot import host memory");
    if (reinterpret_cast<uintptr_t>(pointer) % hostImportAlignment_ != 0 || bytes % hostImportAlignment_ != 0 || bytes == 0)
        throw DeviceError(name_ + " imports host memory at multiples of " + std::to_string(hostImportAlignment_) + " bytes only");
    constexpr VkExternalMemoryHandleTypeFlagBits kHost = VK_EXTERNAL_MEMORY_HANDLE_TYPE_HOST_ALLOCATION_BIT_EXT;
    VkMemoryHostPointerPropertiesEXT pointerProperties{VK_STRUCTURE_TYPE_MEMORY_HOST_POINTER_PROPERTIES_EXT};
    check_vk(hostPointerProperties_(device_, kHost, pointer, &pointerProperties), "vkGetMemoryHostPointerPropertiesEXT");
    Buffer buffer;
    buffer.device_ = device_;
    buffer.size = bytes;
    VkExternalMemoryBufferCreateInfo external{VK_STRUCTURE_TYPE_EXTERNAL_MEMORY_BUFFER_CREATE_INFO};
    external.handleTypes = kHost;
    VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO, &external};
    info.size = bytes;
    info.usage = kBufferUsage;
    check_vk(vkCreateBuffer(device_, &info, nullptr, &buffer.handle), "vkCreateBuffer");
    VkMemoryRequirements requirements;
    vkGetBufferMemoryRequirements(device_, buffer.handle, &requirements);
    const uint32_t types = requirements.memoryTypeBits & pointerProperties.memoryTypeBits;
    if (types == 0 || requirements.size > bytes) throw DeviceError(name_ + " cannot use imported host memory for a buffer");
    VkImportMemoryHostPointerInfoEXT import{VK_STRUCTURE_TYPE_IMPORT_MEMORY_HOST_POINTER_INFO_EXT};
    import.handleType = kHost;
    import.pHostPointer = pointer;
    VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO, &import};
    flags.flags = VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT;
    VkMemoryAllocateInfo allocate{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags};
    allocate.allocationSize = bytes;
    allocate.memoryTypeIndex = uint32_t(std::countr_zero(types));  // the lowest type the pointer allows
    check_vk(vkAllocateMemory(device_, &allocate, nullptr, &buffer.memory_), "vkAllocateMemory (imported host memory)");
    check_vk(vkBindBufferMemory(device_, buffer.handle, buffer.memory_, 0), "vkBindBufferMemory");
    buffer.mapped = pointer;
    buffer.address = device_address(device_, buffer.handle);
    return buffer;
}

void Device::upload(Buffer& buffer, const void* data, size_t bytes) {
    upload(buffer, bytes, [&](void* destination) { std::memcpy(destination, data, bytes); });
}

void Device::upload(Buffer& buffer, size_t bytes, const std::function<void(void*)>& write) {
    if (bytes == 0) return;
    if (buffer.mapped) {
        write(buffer.mapped);
        return;
    }
    Buffer staging = create_buffer(bytes, MemoryUse::Upload);
    write(staging.mapped);
    run([&](VkCommandBuffer cmd) {
        VkBufferCopy region{0, 0, bytes};
        vkCmdCopyBuffer(cmd, staging.handle, buffer.handle, 1, &region);
    });
}

void Device::wait_idle() {
    const std::lock_guard<std::recursive_mutex> lock(runMutex_);
    vkDeviceWaitIdle(device_);
}

void Device::run(const std::function<void(VkCommandBuffer)>& record) {
    const std::lock_guard<std::recursive_mutex> lock(runMutex_);
    VkCommandBufferAllocateInfo allocate{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    allocate.commandPool = commandPool_;
    allocate.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    allocate.commandBufferCount = 1;
    VkCommandBuffer cmd;
    check_vk(vkAllocateCommandBuffers(device_, &allocate, &cmd), "vkAllocateCommandBuffers");
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    check_vk(vkBeginCommandBuffer(cmd, &begin), "vkBeginCommandBuffer");
    record(cmd);
    check_vk(vkEndCommandBuffer(cmd), "vkEndCommandBuffer");
    VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cmd;
    check_vk(vkResetFences(device_, 1, &fence_), "vkResetFences");
    check_vk(vkQueueSubmit(queue_, 1, &submit, fence_), "vkQueueSubmit");
    // A bounded wait: a hung GPU becomes an error, never a hang.
    const VkResult waited = vkWaitForFences(device_, 1, &fence_, VK_TRUE, 120ull * 1000 * 1000 * 1000);
    vkFreeCommandBuffers(device_, commandPool_, 1, &cmd);
    if (waited == VK_TIMEOUT) throw DeviceError("the GPU did not finish a submission within 120 s on " + name_);
    check_vk(waited, "vkWaitForFences");
}

}  // namespace tessera
