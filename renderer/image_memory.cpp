// Pixel storage for images (renderer.h PixelAllocator). A 1080p RGBA float image is 33 MB: taking it from the system
// in 4 KB pages cost 15-20 ms a frame to page faults (both on lavapipe's host and beside an H100, which draws the frame
// in 3 ms), so large blocks are asked for as transparent huge pages and, once freed, a few are kept for the next
// image of the same size.
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
};
Spare& spare_blocks() {
    static Spare* spare = new Spare;
    return *spare;
}

size_t huge_pages_for(size_t bytes) { return (bytes + kHugePage - 1) / kHugePage * kHugePage; }

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
        for (auto it = spare.blocks.rbegin(); it != spare.blocks.rend(); ++it)
            if (it->bytes == rounded) {
                void* memory = it->memory;
                spare.blocks.erase(std::next(it).base());
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
    size_t held = 0;
    for (const Block& b : spare.blocks) held += b.bytes;
    while (!spare.blocks.empty() && (spare.blocks.size() > kSpareBlocks || held > kSpareBytes)) {
        held -= spare.blocks.front().bytes;
        std::free(spare.blocks.front().memory);
        spare.blocks.erase(spare.blocks.begin());
    }
}

}  // namespace tessera
