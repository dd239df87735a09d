// Pixel storage for images (renderer.h PixelAllocator). A 1080p RGBA float image is 33 MB: taking it from the system
// in 4 KB pages cost 15-20 ms a frame to page faults (both on lavapipe's host and beside an H100, which draws the frame
// in 3 ms), so large blocks are asked for as transparent huge pages and, once freed, a few are kept for the next
// image of the same size. A block a device has imported (the renderer keeps its AOV images' imports) is pinned: kept
// whatever the limits, and handed out first.
#include "tessera/renderer.h"

#include <sys/mman.h>

#include <cstdlib>
#include <mutex>
#include <new>

namespace tessera {
namespace {

constexpr size_t kLargeBlock = size_t(1) << 20;  // smaller blocks are plain allocations
constexpr size_t kHugePage = size_t(2) << 20;
constexpr size_t kSpareBlocks = 2;               // freed large blocks kept for reuse: a frame's and the one before
constexpr size_t kSpareBytes = size_t(160) << 20; // and at most this much memory held by them

struct Block {
    void* memory;
    size_t bytes;
};

// Freed large blocks, oldest first. Never destroyed: an image may be freed during the process's exit, after static
// destructors have run (Python lets go of its objects late).
struct Spare {
    std::mutex mutex;
    std::vector<Block> blocks;
    std::vector<std::pair<void*, int>> pins;  // blocks a device has imported, with how many imports each
};
Spare& spare_blocks() {
    static Spare* spare = new Spare;
    return *spare;
}

size_t huge_pages_for(size_t bytes) { return (bytes + kHugePage - 1) / kHugePage * kHugePage; }

bool pinned(const Spare& spare, const void* memory) {
    for (const auto& [block, count] : spare.pins)
        if (block == memory) return true;
    return false;
}

// Returns the oldest spare blocks to the system while more are kept than the limits allow; a pinned block stays (a
// device still maps it) and counts towards the limits, so the others go first.
void trim(Spare& spare) {
    size_t held = 0;
    for (const Block& b : spare.blocks) held += b.bytes;
    size_t count = spare.blocks.size();
    for (auto it = spare.blocks.begin(); it != spare.blocks.end() && (count > kSpareBlocks || held > kSpareBytes);) {
        if (pinned(spare, it->memory)) {
            ++it;
            continue;
        }
        held -= it->bytes;
        --count;
        std::free(it->memory);
        it = spare.blocks.erase(it);
    }
}

}  // namespace

void* allocate_pixel_bytes(size_t bytes) {
    if (bytes < kLargeBlock) {
        if (void* memory = std::malloc(bytes ? bytes : 1)) return memory;
        throw std::bad_alloc();
    }
    const size_t rounded = huge_pages_for(bytes);
    {
        Spare& spare = spare_blocks();
        const std::lock_guard lock(spare.mutex);
        // The newest spare block of this size, a pinned one first: a device has it imported already.
        auto chosen = spare.blocks.rend();
        for (auto it = spare.blocks.rbegin(); it != spare.blocks.rend(); ++it)
            if (it->bytes == rounded && (chosen == spare.blocks.rend() || (pinned(spare, it->memory) && !pinned(spare, chosen->memory))))
                chosen = it;
        if (chosen != spare.blocks.rend()) {
            void* memory = chosen->memory;
            spare.blocks.erase(std::next(chosen).base());
            return memory;
        }
    }
    void* memory = std::aligned_alloc(kHugePage, rounded);
    if (!memory) throw std::bad_alloc();
    madvise(memory, rounded, MADV_HUGEPAGE);  // a hint: without huge pages the block still works, in small pages
    return memory;
}

size_t pixel_block_bytes(size_t bytes) { return bytes < kLargeBlock ? 0 : huge_pages_for(bytes); }

void free_pixel_bytes(void* memory, size_t bytes) {
    if (!memory) return;
    if (bytes < kLargeBlock) {
        std::free(memory);
        return;
    }
    Spare& spare = spare_blocks();
    const std::lock_guard lock(spare.mutex);
    spare.blocks.push_back({memory, huge_pages_for(bytes)});
    trim(spare);
}

void pin_pixel_block(void* memory) {
    Spare& spare = spare_blocks();
    const std::lock_guard lock(spare.mutex);
    for (auto& [block, count] : spare.pins)
        if (block == memory) {
            ++count;
            return;
        }
    spare.pins.emplace_back(memory, 1);
}

void unpin_pixel_block(void* memory) {
    Spare& spare = spare_blocks();
    const std::lock_guard lock(spare.mutex);
    for (auto it = spare.pins.begin(); it != spare.pins.end(); ++it)
        if (it->first == memory) {
            if (--it->second == 0) spare.pins.erase(it);
            break;
        }
    trim(spare);  // a spare block held back by its import may go now
}

}  // namespace tessera
