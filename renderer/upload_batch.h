// Internal to the renderer: a frame's uploads gathered into one submission. Each write() says where its bytes go: the
// buffer's own memory where the host maps it, else room in a staging buffer that submit() copies from, every queued
// copy in one command buffer with one wait. A live edit writes a dozen small buffers (mesh streams, mesh records,
// instances, batch origins): beside an H100 each upload of its own cost about 0.3 ms (a staging allocation, a submission
// and a wait), together 3.4 ms of an edit's 8 ms frame.
#pragma once

#include "tessera/device.h"

#include <span>
#include <vector>

namespace tessera {

class UploadBatch {
public:
    struct Piece {
        const Buffer* buffer;
        VkDeviceSize offset, bytes;
    };

    // `stagingBytes`: the most one staging buffer holds (a 10 M-triangle mesh's vertices are 100 MB: they go up in
    // parts, the buffer used again, rather than doubling their memory on the host).
    explicit UploadBatch(Device& device, VkDeviceSize stagingBytes = VkDeviceSize(64) << 20);
    UploadBatch(const UploadBatch&) = delete;
    UploadBatch& operator=(const UploadBatch&) = delete;
    // Copies still queued are dropped: an upload that threw half way sends nothing more.
    ~UploadBatch() = default;

    // Where each piece's bytes are to be written (staged pieces 16-byte aligned). Write them before the next write() or
    // submit(): a write whose staged pieces do not fit beside the queued ones submits those first. Pieces larger
    // together than the bound get a staging buffer of their size. A buffer takes one write per submission (copies of one
    // submission are not ordered among themselves) and must outlive it.
    std::vector<void*> write(std::span<const Piece> pieces);
    void* write(const Buffer& buffer, VkDeviceSize offset, VkDeviceSize bytes);
    // A copy of `from`'s first `bytes` into `to` on the device, before every staged copy of the submission (a stream
    // grown: its ranges in use copied, then new ranges written). `from` is kept until then.
    void copy(Buffer from, const Buffer& to, VkDeviceSize bytes);
    // Sends what is queued (nothing: no submission) and waits for it.
    void submit();

    VkDeviceSize staging_bound() const { return stagingBytes_; }
    uint32_t submissions() const { return submissions_; }

private:
    struct Copy {
        VkBuffer from, to;
        VkBufferCopy region;
    };
    Device& device_;
    VkDeviceSize stagingBytes_;
    Buffer staging_;                 // grows up to the bound as pieces need; used again after each submission
    VkDeviceSize used_ = 0;          // of staging_
    std::vector<Copy> deviceCopies_, stagedCopies_;
    std::vector<Buffer> held_;       // until the submission: staging buffers replaced, sources of device copies
    uint32_t submissions_ = 0;
};

}  // namespace tessera
