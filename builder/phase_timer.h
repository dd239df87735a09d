// Internal to the builder: with TESSERA_BUILD_PHASES=1, each phase of a build prints its wall and CPU seconds to
// stderr, an estimate of the CPU seconds that ran on the calling thread alone (the serial part, which more cores do
// not shorten), and the process's resident memory at its end and at its peak so far (Linux's VmRSS and VmHWM; what
// malloc keeps after a free stays resident). Off, a timer costs one getenv. The rounds' per-group work is also split into
// its steps (simplify, fit, split, ...): StepTotals sums each step's seconds over every group and thread, and prints the
// totals once, after the last round.
#pragma once

#include "tessera/parallel.h"

#include <array>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>

namespace tessera {

// Only "1" prints ("0" is off, as for the other switches; a build does not fail over a diagnostic's spelling).
inline bool build_phases_enabled() {
    const char* value = std::getenv("TESSERA_BUILD_PHASES");
    return value && value[0] == '1' && value[1] == '\0';
}

class PhaseTimer {
public:
    PhaseTimer() : enabled_(build_phases_enabled()) { now(wall_, cpu_, thread_); }
    // Prints the time since the last mark (or construction) under `name`.
    void mark(const char* name) {
        if (!enabled_) return;
        double wall, cpu, thread;
        now(wall, cpu, thread);
        // The calling thread does the serial part and its 1/n share of the parallel part: serial = (n t - c) / (n - 1).
        const double n = double(core_count()), own = thread - thread_, all = cpu - cpu_;
        const double serial = n > 1 ? std::max(0.0, (n * own - all) / (n - 1)) : all;
        long residentKiB = 0, peakKiB = 0;
        if (FILE* status = std::fopen("/proc/self/status", "r")) {
            char line[256];
            while (std::fgets(line, sizeof line, status)) std::sscanf(line, "VmRSS: %ld", &residentKiB), std::sscanf(line, "VmHWM: %ld", &peakKiB);
            std::fclose(status);
        }
        std::fprintf(stderr, "phase %-24s wall %7.3f s  cpu %7.3f s  serial ~%6.3f s  resident %6ld MiB  peak %6ld MiB\n", name, wall - wall_, all,
                     serial, residentKiB / 1024, peakKiB / 1024);
        wall_ = wall, cpu_ = cpu, thread_ = thread;
    }

private:
    void now(double& wall, double& cpu, double& thread) const {
        if (!enabled_) return;
        auto seconds = [](clockid_t clock) {
            timespec t;
            clock_gettime(clock, &t);
            return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
        };
        wall = std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
        cpu = seconds(CLOCK_PROCESS_CPUTIME_ID);
        thread = seconds(CLOCK_THREAD_CPUTIME_ID);
    }
    bool enabled_;
    double wall_ = 0, cpu_ = 0, thread_ = 0;
};

// Seconds per step of work that runs as many tasks on every core (a round's groups), summed over the tasks. A task
// times its steps with a Lap; the totals print once, with print(). Off, a lap reads no clock.
template <size_t kSteps>
class StepTotals {
    using Clock = std::chrono::steady_clock;

public:
    explicit StepTotals(std::array<const char*, kSteps> names) : names_(names), enabled_(build_phases_enabled()) {}

    // One task's clock: lap(step) counts the time since the last lap (or the start) to `step`.
    class Lap {
    public:
        explicit Lap(StepTotals& totals) : totals_(totals), last_(totals.enabled_ ? Clock::now() : Clock::time_point()) {}
        void lap(size_t step) {
            if (!totals_.enabled_) return;
            const Clock::time_point now = Clock::now();
            totals_.nanoseconds_[step].fetch_add(std::chrono::duration_cast<std::chrono::nanoseconds>(now - last_).count(), std::memory_order_relaxed);
            last_ = now;
        }

    private:
        StepTotals& totals_;
        Clock::time_point last_;
    };

    void print(const char* what) const {
        if (!enabled_) return;
        std::fprintf(stderr, "steps of %s (seconds summed over its tasks):", what);
        for (size_t k = 0; k < kSteps; ++k) std::fprintf(stderr, " %s %.3f", names_[k], 1e-9 * double(nanoseconds_[k].load()));
        std::fprintf(stderr, "\n");
    }

private:
    std::array<const char*, kSteps> names_;
    std::array<std::atomic<long long>, kSteps> nanoseconds_{};
    bool enabled_;
};

}  // namespace tessera
