// The builder's parallel loops (tessera/parallel.h): every index runs exactly once, whoever calls, however nested,
// and in a forked child too (whose pool has none of its parent's threads).
#include "tessera/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include <sys/wait.h>
#include <unistd.h>

using namespace tessera;

namespace {

bool each_once(const std::vector<std::atomic<int>>& visits) {
    for (const auto& v : visits)
        if (v.load() != 1) return false;
    return true;
}

// How many threads run a loop whose steps each wait (up to 10 s) for every core's thread to have taken one.
size_t threads_running_a_loop() {
    std::mutex mutex;
    std::set<std::thread::id> threads;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    parallel_for(64, [&](size_t) {
        {
            std::lock_guard<std::mutex> lock(mutex);
            threads.insert(std::this_thread::get_id());
        }
        for (;;) {
            {
                std::lock_guard<std::mutex> lock(mutex);
                if (threads.size() >= core_count() || std::chrono::steady_clock::now() > deadline) return;
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(1));
        }
    });
    return threads.size();
}

}  // namespace

TEST(Parallel, EveryIndexRunsExactlyOnce) {
    for (size_t count : {0, 1, 2, 3, 1000, 100000}) {
        std::vector<std::atomic<int>> visits(count);
        parallel_for(count, [&](size_t i) { ++visits[i]; });
        EXPECT_TRUE(each_once(visits)) << count;
    }
    EXPECT_EQ(threads_running_a_loop(), core_count());
}

TEST(Parallel, LoopsFromSeveralThreadsAndInsideLoopsAllFinish) {
    // Four callers at once (like the plugin's build threads), each loop's body running a loop of its own.
    constexpr size_t kCallers = 4, kOuter = 64, kInner = 32;
    std::vector<std::atomic<int>> visits(kCallers * kOuter * kInner);
    std::vector<std::thread> callers;
    for (size_t c = 0; c < kCallers; ++c)
        callers.emplace_back([&, c] {
            parallel_for(kOuter, [&](size_t o) { parallel_for(kInner, [&](size_t i) { ++visits[(c * kOuter + o) * kInner + i]; }); });
        });
    for (std::thread& t : callers) t.join();
    EXPECT_TRUE(each_once(visits));
}

TEST(Parallel, AForkedChildRunsLoops) {
    std::vector<std::atomic<int>> warm(100);
    parallel_for(warm.size(), [&](size_t i) { ++warm[i]; });  // the parent's pool is running
    const pid_t child = fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
        alarm(30);  // a hang ends the child with SIGALRM: a failure, not a stuck test
        std::vector<std::atomic<int>> visits(10000);
        parallel_for(visits.size(), [&](size_t i) { ++visits[i]; });
        if (!each_once(visits)) _exit(1);
        _exit(threads_running_a_loop() == core_count() ? 0 : 2);  // on every core, not on the caller alone
    }
    int status = 0;
    ASSERT_EQ(waitpid(child, &status, 0), child);
    ASSERT_TRUE(WIFEXITED(status)) << "the child did not exit normally (signal " << (WIFSIGNALED(status) ? WTERMSIG(status) : 0) << ")";
    EXPECT_EQ(WEXITSTATUS(status), 0);
}
