// Internal to the builder: one loop on every core (dag.cpp, pages.cpp).
#pragma once

#include <algorithm>
#include <atomic>
#include <exception>
#include <functional>
#include <thread>
#include <vector>

namespace tessera {

// The number of cores, asked once: std::thread::hardware_concurrency() reads /sys/devices/system/cpu/online on every
// call (an open, a read and a close), which cost more than building a small mesh's whole DAG.
inline size_t core_count() {
    static const size_t cores = std::max(1u, std::thread::hardware_concurrency());
    return cores;
}

// Runs body(0..count-1) on every core. body must not throw (an exception on a worker thread ends the process).
inline void parallel_for(size_t count, const std::function<void(size_t)>& body) {
    if (count <= 1) {  // nothing to share
        if (count == 1) body(0);
        return;
    }
    const size_t threads = std::min<size_t>(count, core_count());
    std::atomic<size_t> nextIndex{0};
    auto work = [&] {
        for (size_t i = nextIndex++; i < count; i = nextIndex++) body(i);
    };
    std::vector<std::thread> pool;
    for (size_t t = 1; t < threads; ++t) pool.emplace_back(work);
    work();
    for (auto& thread : pool) thread.join();
}

// Runs body(begin, end) over consecutive ranges of at most `block` of 0..count-1, on every core.
inline void parallel_blocks(size_t count, size_t block, const std::function<void(size_t, size_t)>& body) {
    parallel_for((count + block - 1) / block, [&](size_t b) { body(b * block, std::min(count, (b + 1) * block)); });
}

// parallel_for for a body that may throw: every index runs, then the exception of the lowest index that threw is
// rethrown (the same one whatever the threads' timing).
inline void parallel_for_rethrowing(size_t count, const std::function<void(size_t)>& body) {
    std::vector<std::exception_ptr> errors(count);
    parallel_for(count, [&](size_t i) {
        try {
            body(i);
        } catch (...) {
            errors[i] = std::current_exception();
        }
    });
    for (const std::exception_ptr& error : errors)
        if (error) std::rethrow_exception(error);
}

}  // namespace tessera
