// Internal to the renderer: one geometry stream of the scene on the device (clusters, vertices, triangles, ...), in
// which each mesh keeps its range of elements while it stays in the scene. A geometry change then writes the ranges of
// the meshes it added and nothing else: an edit costs what the edited mesh holds, not what the scene holds. Ranges that
// removed meshes free are reused, first fit; the buffer grows by a copy on the device, never again from the host.
#pragma once

#include "tessera/device.h"
#include "upload_batch.h"

#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <span>

namespace tessera {

class StreamArena {
public:
    struct Range {
        size_t offset = 0, count = 0;  // in elements
    };

    explicit StreamArena(size_t elementBytes) : elementBytes_(elementBytes) {}

    // Takes `count` elements at an offset that is a multiple of `alignment` (a power of two): a free range where one
    // fits, else past the end. The buffer may be too small for it until fit().
    size_t allocate(size_t count, size_t alignment = 1);
    // Gives a range back (merged with free neighbours; the end drops back where the range was the last).
    void release(Range range);
    // Every range given back, and the buffer too.
    void clear();
    // Makes the buffer hold every range allocated: exactly that where it was empty, else with a quarter to spare, so
    // that a run of edits that add meshes copies it seldom; the ranges in use are copied on the device (in the batch, ahead
    // of its writes). An empty stream gets one zeroed element (a buffer to bind and address).
    void fit(Device& device, UploadBatch& batch);
    // Writes ranges that fit() placed: `write(range, first, end, to)` fills elements [first, end) of ranges[range] at
    // `to`. On every core, in runs of at most 64 k elements; straight into the buffer where it is host-visible, else
    // into the batch's staging, a bounded part at a time (a large mesh's upload does not double its memory on the host).
    // Returns the bytes written.
    uint64_t write(UploadBatch& batch, std::span<const Range> ranges, const std::function<void(size_t range, size_t first, size_t end, void* to)>& write);

    const Buffer& buffer() const { return buffer_; }
    size_t element_bytes() const { return elementBytes_; }
    size_t end() const { return end_; }  // elements up to the last range in use: what shaders may address
    size_t free_elements() const;        // in released ranges below the end

private:
    size_t elementBytes_;
    Buffer buffer_;
    size_t end_ = 0;
    std::map<size_t, size_t> free_;  // offset -> count of the released ranges below the end, none adjacent
};

}  // namespace tessera
