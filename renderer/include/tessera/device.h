// The Vulkan device: headless, a real GPU when present, else lavapipe (Mesa's CPU device).
#pragma once

#include <vulkan/vulkan.h>

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

namespace tessera {

// No usable device, or a required feature is missing: one line that says which.
struct DeviceError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

struct DeviceOptions {
    // "" picks the best device (discrete > integrated > virtual > cpu); "gpu", "cpu", an index, or a
    // substring of the device name forces one. Defaults to $TESSERA_DEVICE.
    std::string select;
    // Enables the Khronos validation layer (core + synchronization). Defaults to $TESSERA_VALIDATION=1 (0 or unset: off).
    bool validation = false;
    // Leaves the memory of device buffers unmapped even where the host could map it (a CPU device, integrated or
    // resizable-BAR GPUs), so that every upload goes through a staging buffer and every read back through a copy, as
    // with a discrete GPU's memory: those paths are then tested on lavapipe too. Defaults to $TESSERA_STAGED_UPLOADS=1.
    bool stagedUploads = false;
    // From the variables above; a switch set to anything but 1 or 0 throws std::invalid_argument naming it.
    static DeviceOptions from_environment();
};

// A choice of two that environment variable `name` may force: true for the value `on`, false for `off`, `fallback`
// when unset or empty; anything else throws std::invalid_argument naming the variable and both values.
bool environment_choice(const char* name, const char* on, const char* off, bool fallback);

enum class MemoryUse { Device, Upload, Readback };

// A buffer with its own memory, reachable from shaders by device address. Move-only.
class Buffer {
public:
    Buffer() = default;
    Buffer(Buffer&& other) noexcept { *this = std::move(other); }
    Buffer& operator=(Buffer&& other) noexcept;
    ~Buffer() { reset(); }
    void reset();

    VkBuffer handle = VK_NULL_HANDLE;
    VkDeviceAddress address = 0;
    VkDeviceSize size = 0;
    void* mapped = nullptr;  // host pointer for Upload / Readback memory (and Device memory that is host visible)

private:
    friend class Device;
    VkDevice device_ = VK_NULL_HANDLE;
    VkDeviceMemory memory_ = VK_NULL_HANDLE;
};

class Device {
public:
    explicit Device(const DeviceOptions& options = DeviceOptions::from_environment());
    ~Device();
    Device(const Device&) = delete;
    Device& operator=(const Device&) = delete;

    // The process's device for `options`: made by the first caller, then shared by every later one with the same
    // options, so that a process that opens many stages (a script, a test suite) creates the instance, the device and
    // the renderer's pipelines once. Held until release_shared_devices(); then each goes when its last user does.
    static std::shared_ptr<Device> shared(const DeviceOptions& options);
    static void release_shared_devices();

    // State made once per device and shared by its users (the renderer's compiled pipelines), by key: made by `make`
    // on the first call for the key; destroyed with the device, before it.
    std::shared_ptr<void> shared_state(const std::string& key, const std::function<std::shared_ptr<void>()>& make);

    VkDevice handle() const { return device_; }
    VkPhysicalDevice physical() const { return physical_; }
    const std::string& name() const { return name_; }
    bool is_software() const { return software_; }
    bool staged_uploads() const { return stagedUploads_; }
    float timestamp_period_ns() const { return timestampPeriod_; }
    // Sub-pixel bits of the hardware rasterizer's vertex snapping; the compute rasterizer snaps the same way.
    uint32_t sub_pixel_bits() const { return subPixelBits_; }
    // The most texels a texel buffer view may span (the renderer's views of its streams, shared.h TS_VIEW_*).
    uint32_t max_texel_buffer_elements() const { return maxTexelBufferElements_; }
    // The most bytes a storage buffer binding may span (the renderer's AOV output, shared.h TS_BINDING_OUTPUT).
    uint32_t max_storage_buffer_range() const { return maxStorageBufferRange_; }
    uint64_t min_storage_buffer_offset_alignment() const { return minStorageBufferOffsetAlignment_; }
    // Invocations per subgroup in compute shaders (on lavapipe, the lanes of its SIMD registers: 8 at 256 bits).
    uint32_t subgroup_size() const { return subgroupSize_; }

    Buffer create_buffer(VkDeviceSize size, MemoryUse use, VkBufferUsageFlags extraUsage = 0);
    // Host memory the device reads and writes in place (VK_EXT_external_memory_host): a buffer over the `bytes` at
    // `pointer`, both multiples of host_import_alignment() (else a DeviceError, as for memory the driver refuses). The
    // memory stays the caller's and must outlive the buffer (freeing the buffer leaves the memory as it is).
    // host_import_alignment() is 0 where the driver cannot import.
    uint64_t host_import_alignment() const { return hostImportAlignment_; }
    Buffer import_host_memory(void* pointer, VkDeviceSize bytes);
    // Copies `bytes` into a Device buffer (directly when mapped, else through a staging buffer).
    void upload(Buffer& buffer, const void* data, size_t bytes);
    // The same, with the bytes written by `write(destination)` straight where they go: the buffer's memory where the
    // host maps it, else a staging buffer (no copy of the data on the host besides).
    void upload(Buffer& buffer, size_t bytes, const std::function<void(void*)>& write);

    // Records commands into a one-time command buffer, submits it and waits. Callers on several threads take turns.
    void run(const std::function<void(VkCommandBuffer)>& record);
    // Waits until the device is idle, taking its turn with run() (the queue is the device's, not the caller's).
    void wait_idle();

    // Validation messages (errors and warnings) since the last call; empty when validation is off.
    std::vector<std::string> take_validation_messages();
    size_t validation_error_count() const { return validationErrors_; }
    bool validation_enabled() const { return messenger_ != VK_NULL_HANDLE; }

    // Called by the debug messenger.
    void record_validation_message(bool error, const char* message);

private:
    uint32_t find_memory_type(uint32_t typeBits, MemoryUse use) const;

    VkInstance instance_ = VK_NULL_HANDLE;
    VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
    VkPhysicalDevice physical_ = VK_NULL_HANDLE;
    VkDevice device_ = VK_NULL_HANDLE;
    VkQueue queue_ = VK_NULL_HANDLE;
    uint32_t queueFamily_ = 0;
    VkCommandPool commandPool_ = VK_NULL_HANDLE;
    VkFence fence_ = VK_NULL_HANDLE;
    VkPhysicalDeviceMemoryProperties memoryProperties_{};
    std::string name_;
    bool software_ = false;
    bool stagedUploads_ = false;
    float timestampPeriod_ = 1.0f;
    uint32_t subPixelBits_ = 8;
    uint32_t maxTexelBufferElements_ = 65536;
    uint32_t maxStorageBufferRange_ = 1u << 27;
    uint64_t minStorageBufferOffsetAlignment_ = 256;
    uint32_t subgroupSize_ = 1;
    uint64_t hostImportAlignment_ = 0;  // minImportedHostPointerAlignment, 0 without VK_EXT_external_memory_host
    PFN_vkGetMemoryHostPointerPropertiesEXT hostPointerProperties_ = nullptr;

    std::recursive_mutex runMutex_;  // the command pool and the queue are used by one thread at a time
    std::mutex sharedStateMutex_;
    std::map<std::string, std::shared_ptr<void>> sharedState_;
    std::mutex messagesMutex_;
    std::vector<std::string> messages_;
    size_t validationErrors_ = 0;
};

// Throws DeviceError naming the call when a Vulkan call fails.
void check_vk(VkResult result, const char* what);

}  // namespace tessera
