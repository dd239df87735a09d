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

void StreamArena::fit(Device& device, UploadBatch& batch) {
    const size_t capacity = buffer_.handle ? buffer_.size / elementBytes_ : 0;
    if (buffer_.handle && end_ <= capacity) return;
    const size_t elements = capacity == 0 ? std::max<size_t>(end_, 1) : std::max(end_, capacity + capacity / 4);
    Buffer grown = device.create_buffer(elements * elementBytes_, MemoryUse::Device);
    const size_t kept = std::min(end_, capacity) * elementBytes_;  // the ranges in use before this allocation
    if (kept > 0 && buffer_.mapped && grown.mapped) std::memcpy(grown.mapped, buffer_.mapped, kept);
    else if (kept > 0) batch.copy(std::move(buffer_), grown, kept);
    else if (end_ == 0) std::memset(batch.write(grown, 0, grown.size), 0, grown.size);  // the empty stream's zeroed element
    buffer_ = std::move(grown);
}

uint64_t StreamArena::write(UploadBatch& batch, std::span<const Range> ranges,
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
    // In parts of at most the batch's staging bound (one run at least), each written on every core.
    for (size_t begin = 0; begin < runs.size();) {
        std::vector<UploadBatch::Piece> pieces;
        size_t bytes = 0;
        for (size_t end = begin; end < runs.size(); ++end) {
            const size_t runBytes = (runs[end].end - runs[end].first) * elementBytes_;
            if (!buffer_.mapped && !pieces.empty() && bytes + runBytes + 16 * (pieces.size() + 1) > batch.staging_bound()) break;
            pieces.push_back({&buffer_, (ranges[runs[end].range].offset + runs[end].first) * elementBytes_, runBytes});
            bytes += runBytes;
        }
        const std::vector<void*> places = batch.write(pieces);
        parallel_for(pieces.size(), [&](size_t k) {
            const Run& run = runs[begin + k];
            write(run.range, run.first, run.end, places[k]);
        });
        begin += pieces.size();
    }
    return total;
}

}  // namespace tessera
