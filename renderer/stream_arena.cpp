// A scene stream whose meshes keep their ranges (stream_arena.h).
#include "stream_arena.h"

#include "tessera/parallel.h"

#include <array>
#include <cstring>
#include <vector>

namespace tessera {

size_t StreamArena::allocate(size_t count, size_t alignment) {
    auto aligned = [&](size_t offset) { return (offset + alignment - 1) & ~(alignment - 1); };
    for (auto it = free_.begin(); it != free_.end(); ++it) {
        const size_t start = aligned(it->first), rangeEnd = it->first + it->second;
        if (start + count > rangeEnd) continue;
        const size_t before = start - it->first, after = rangeEnd - start - count;
        if (before > 0) it->second = before;
        else free_.erase(it);
        if (after > 0) free_[start + count] = after;
        return start;
    }
    const size_t start = aligned(end_);
    if (start > end_) free_[end_] = start - end_;  // the padding: free, below the new end
    end_ = start + count;
    return start;
}

void StreamArena::release(Range range) {
    if (range.count == 0) return;
    auto [it, inserted] = free_.emplace(range.offset, range.count);
    if (!inserted) return;  // already free (never given out twice)
    auto next = std::next(it);
    if (next != free_.end() && it->first + it->second == next->first) {
        it->second += next->second;
        free_.erase(next);
    }
    if (it != free_.begin()) {
        auto previous = std::prev(it);
        if (previous->first + previous->second == it->first) {
            previous->second += it->second;
            free_.erase(it);
            it = previous;
        }
    }
    if (it->first + it->second == end_) {  // the last range in use went: the end drops back
        end_ = it->first;
        free_.erase(it);
    }
}

void StreamArena::clear() {
    free_.clear();
    end_ = 0;
    buffer_ = Buffer{};
}

size_t StreamArena::free_elements() const {
    size_t total = 0;
    for (const auto& [offset, count] : free_) total += count;
    return total;
}

void StreamArena::fit(Device& device) {
    const size_t capacity = buffer_.handle ? buffer_.size / elementBytes_ : 0;
    if (buffer_.handle && end_ <= capacity) return;
    const size_t elements = capacity == 0 ? std::max<size_t>(end_, 1) : std::max(end_, capacity + capacity / 4);
    Buffer grown = device.create_buffer(elements * elementBytes_, MemoryUse::Device);
    const size_t kept = std::min(end_, capacity) * elementBytes_;  // the ranges in use before this allocation
    if (kept > 0 && buffer_.mapped && grown.mapped) {
        std::memcpy(grown.mapped, buffer_.mapped, kept);
    } else if (kept > 0 || end_ == 0) {
        device.run([&](VkCommandBuffer cmd) {
            if (kept > 0) {
                const VkBufferCopy region{0, 0, kept};
                vkCmdCopyBuffer(cmd, buffer_.handle, grown.handle, 1, &region);
            } else {
                vkCmdFillBuffer(cmd, grown.handle, 0, VK_WHOLE_SIZE, 0);  // the empty stream's zeroed element
            }
        });
    }
    buffer_ = std::move(grown);
}

uint64_t StreamArena::write(Device& device, std::span<const Range> ranges,
                            const std::function<void(size_t range, size_t first, size_t end, void* to)>& write) {
    constexpr size_t kRun = 65536;  // elements a core writes at a time
    struct Run {
        size_t range, first, end;
    };
    std::vector<Run> runs;
    uint64_t total = 0;
    for (size_t r = 0; r < ranges.size(); ++r) {
        total += uint64_t(ranges[r].count) * elementBytes_;
        for (size_t first = 0; first < ranges[r].count; first += kRun) runs.push_back({r, first, std::min(ranges[r].count, first + kRun)});
    }
    if (buffer_.mapped) {
        parallel_for(runs.size(), [&](size_t k) {
            const Run& run = runs[k];
            write(run.range, run.first, run.end, static_cast<char*>(buffer_.mapped) + (ranges[run.range].offset + run.first) * elementBytes_);
        });
        return total;
    }
    // Not host-visible: through staging buffers of at most stagingBytes_ (a 10 M-triangle mesh's vertices are 100 MB),
    // each written on every core, then copied run by run.
    for (size_t begin = 0; begin < runs.size();) {
        size_t end = begin, bytes = 0;
        std::vector<size_t> at;  // each run's place in the staging buffer
        while (end < runs.size() && (end == begin || bytes + (runs[end].end - runs[end].first) * elementBytes_ <= stagingBytes_)) {
            at.push_back(bytes);
            bytes += (runs[end].end - runs[end].first) * elementBytes_;
            ++end;
        }
        Buffer staging = device.create_buffer(bytes, MemoryUse::Upload);
        parallel_for(end - begin, [&](size_t k) {
            const Run& run = runs[begin + k];
            write(run.range, run.first, run.end, static_cast<char*>(staging.mapped) + at[k]);
        });
        std::vector<VkBufferCopy> regions;
        for (size_t k = begin; k < end; ++k)
            regions.push_back({at[k - begin], (ranges[runs[k].range].offset + runs[k].first) * elementBytes_, (runs[k].end - runs[k].first) * elementBytes_});
        device.run([&](VkCommandBuffer cmd) { vkCmdCopyBuffer(cmd, staging.handle, buffer_.handle, uint32_t(regions.size()), regions.data()); });
        begin = end;
    }
    return total;
}

}  // namespace tessera
