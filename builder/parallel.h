// Internal to the builder: one loop on every core (dag.cpp, pages.cpp).
#pragma once

#include <algorithm>
#include <atomic>
#include <exception>
#include <functional>
#include <thread>
#include <vector>

namespace tessera {

// Runs body(0..count-1) on every core. body must not throw (an exception on a worker thread ends the process).
inline void parallel_for(size_t count, const std::function<void(size_t)>& body) {
    const size_t threads = std::min<size_t>(count, std::max(1u, std::thread::hardware_concurrency()));
    std::atomic<size_t> nextIndex{0};
    auto work = [&] {
        for (size_t i = nextIndex++; i < count; i = nextIndex++) body(i);
    };
    std::vector<std::thread> pool;
    for (size_t t = 1; t < threads; ++t) pool.emplace_back(work);
    work();
    for (auto& thread : pool) thread.join();
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
