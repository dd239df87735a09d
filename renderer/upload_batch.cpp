// A frame's uploads in one submission (upload_batch.h).
#include "upload_batch.h"

#include <algorithm>

namespace tessera {
namespace {

constexpr VkDeviceSize kAlignment = 16;  // of staged pieces: the host writes structures there
constexpr VkDeviceSize kSmallestStaging = VkDeviceSize(64) << 10;

VkDeviceSize aligned(VkDeviceSize bytes) { return (bytes + kAlignment - 1) & ~(kAlignment - 1); }

}  // namespace

UploadBatch::UploadBatch(Device& device, VkDeviceSize stagingBytes) : device_(device), stagingBytes_(std::max<VkDeviceSize>(stagingBytes, kAlignment)) {}

std::vector<void*> UploadBatch::write(std::span<const Piece> pieces) {
    VkDeviceSize staged = 0;
    for (const Piece& piece : pieces)
        if (!piece.buffer->mapped && piece.bytes > 0) staged += aligned(piece.bytes);
    if (staged > 0) {
        if (used_ + staged > stagingBytes_ && !stagedCopies_.empty()) submit();
        if (used_ + staged > staging_.size) {  // a larger buffer: what is queued from this one keeps it until submitted
            if (used_ > 0) held_.push_back(std::move(staging_));
            const VkDeviceSize grown = std::clamp<VkDeviceSize>(2 * staging_.size, kSmallestStaging, stagingBytes_);
            staging_ = device_.create_buffer(std::max(staged, grown), MemoryUse::Upload);
            used_ = 0;
        }
    }
    std::vector<void*> places(pieces.size(), nullptr);
    for (size_t i = 0; i < pieces.size(); ++i) {
        const Piece& piece = pieces[i];
        if (piece.bytes == 0) continue;
        if (piece.buffer->mapped) {
            places[i] = static_cast<char*>(piece.buffer->mapped) + piece.offset;
            continue;
        }
        places[i] = static_cast<char*>(staging_.mapped) + used_;
        stagedCopies_.push_back({staging_.handle, piece.buffer->handle, {used_, piece.offset, piece.bytes}});
        used_ += aligned(piece.bytes);
    }
    return places;
}

void* UploadBatch::write(const Buffer& buffer, VkDeviceSize offset, VkDeviceSize bytes) {
    const Piece piece{&buffer, offset, bytes};
    return write(std::span(&piece, 1))[0];
}

void UploadBatch::copy(Buffer from, const Buffer& to, VkDeviceSize bytes) {
    if (bytes == 0) return;
    deviceCopies_.push_back({from.handle, to.handle, {0, 0, bytes}});
    held_.push_back(std::move(from));
}

void UploadBatch::submit() {
    if (deviceCopies_.empty() && stagedCopies_.empty()) {
        held_.clear();
        return;
    }
    device_.run([&](VkCommandBuffer cmd) {
        // Consecutive copies between the same two buffers go in one command.
        auto record = [&](const std::vector<Copy>& copies) {
            std::vector<VkBufferCopy> regions;
            for (size_t i = 0; i < copies.size(); ++i) {
                regions.push_back(copies[i].region);
                if (i + 1 < copies.size() && copies[i + 1].from == copies[i].from && copies[i + 1].to == copies[i].to) continue;
                vkCmdCopyBuffer(cmd, copies[i].from, copies[i].to, uint32_t(regions.size()), regions.data());
                regions.clear();
            }
        };
        record(deviceCopies_);
        if (!deviceCopies_.empty() && !stagedCopies_.empty()) {  // a grown stream's new ranges may lie in what was copied
            VkMemoryBarrier2 memory{VK_STRUCTURE_TYPE_MEMORY_BARRIER_2};
            memory.srcStageMask = memory.dstStageMask = VK_PIPELINE_STAGE_2_TRANSFER_BIT;
            memory.srcAccessMask = memory.dstAccessMask = VK_ACCESS_2_TRANSFER_WRITE_BIT;
            VkDependencyInfo dependency{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
            dependency.memoryBarrierCount = 1;
            dependency.pMemoryBarriers = &memory;
            vkCmdPipelineBarrier2(cmd, &dependency);
        }
        record(stagedCopies_);
    });
    ++submissions_;
    deviceCopies_.clear();
    stagedCopies_.clear();
    held_.clear();
    used_ = 0;
}

}  // namespace tessera
