// One loop on every core, shared by the builder (prepare.cpp, weld.h, dag.cpp, pages.cpp) and the renderer (its uploads).
#pragma once

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

#include <sched.h>
#include <unistd.h>

namespace tessera {

// The cores this process may run on, asked once. The affinity mask, not std::thread::hardware_concurrency(): a farm
// slot pinned to a few of a machine's cores (taskset, a container's or a scheduler's cpuset) would otherwise start a
// thread for every core of the machine (glibc 2.36 counts the cores online) and run them in turns on the few it has.
// (hardware_concurrency also reads /sys/devices/system/cpu/online on every call, which cost more than building a
// small mesh's whole DAG.)
inline size_t core_count() {
    static const size_t cores = [] {
        cpu_set_t allowed;
        if (sched_getaffinity(0, sizeof(allowed), &allowed) == 0 && CPU_COUNT(&allowed) > 0) return size_t(CPU_COUNT(&allowed));
        return size_t(std::max(1u, std::thread::hardware_concurrency()));  // more than CPU_SETSIZE cores: all of them
    }();
    return cores;
}

// Worker threads shared by every parallel_for of the process, started on first use: a build makes a hundred or
// more parallel loops, and starting threads for each one cost more than a small mesh's loops themselves. The calling
// thread always works on its own loop too, so a loop finishes even when every worker is busy elsewhere (several
// builds at once, say from the plugin's build threads, or a loop inside a loop's body).
class WorkerPool {
public:
    // The process's pool (made again in a forked child, which has none of its parent's threads). Never destroyed:
    // the workers wait for work until the process ends.
    static WorkerPool& instance() {
        static std::atomic<WorkerPool*> pool{nullptr};
        WorkerPool* current = pool.load(std::memory_order_acquire);
        if (!current || current->pid_ != getpid()) {
            static std::mutex creating;
            std::lock_guard<std::mutex> lock(creating);
            current = pool.load(std::memory_order_acquire);
            if (!current || current->pid_ != getpid()) {
                current = new WorkerPool(core_count() - 1);
                pool.store(current, std::memory_order_release);
            }
        }
        return *current;
    }

    void run(size_t count, const std::function<void(size_t)>& body) {
        Loop loop{&body, count};
        {
            std::lock_guard<std::mutex> lock(mutex_);
            loops_.push_back(&loop);
        }
        wake_.notify_all();
        loop.work();
        std::unique_lock<std::mutex> lock(mutex_);
        if (const auto it = std::find(loops_.begin(), loops_.end(), &loop); it != loops_.end()) loops_.erase(it);  // no one joins now
        finished_.wait(lock, [&] { return loop.helpers == 0; });
    }

private:
    struct Loop {
        const std::function<void(size_t)>* body;
        size_t count;
        std::atomic<size_t> next{0};
        size_t helpers = 0;  // workers inside work(), counted under the pool's mutex
        void work() {
            for (size_t i = next++; i < count; i = next++) (*body)(i);
        }
    };

    explicit WorkerPool(size_t workers) : pid_(getpid()) {
        for (size_t w = 0; w < workers; ++w) std::thread([this] { serve(); }).detach();
    }

    void serve() {
        std::unique_lock<std::mutex> lock(mutex_);
        for (;;) {
            wake_.wait(lock, [&] { return !loops_.empty(); });
            Loop* loop = loops_.front();
            if (loop->next.load() >= loop->count) {  // every index taken: its caller finishes it
                loops_.pop_front();
                continue;
            }
            ++loop->helpers;
            lock.unlock();
            loop->work();
            lock.lock();
            if (--loop->helpers == 0) finished_.notify_all();
        }
    }

    const pid_t pid_;
    std::mutex mutex_;
    std::condition_variable wake_, finished_;
    std::deque<Loop*> loops_;  // loops that may still have indices to hand out, oldest first
};

// Runs body(0..count-1) on every core. body must not throw (an exception on a worker thread ends the process).
inline void parallel_for(size_t count, const std::function<void(size_t)>& body) {
    if (count <= 1 || core_count() == 1) {  // nothing to share
        for (size_t i = 0; i < count; ++i) body(i);
        return;
    }
    WorkerPool::instance().run(count, body);
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
