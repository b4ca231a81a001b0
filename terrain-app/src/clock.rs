//! CPU clocks for timings on a shared machine: this thread's and this process's CPU seconds,
//! exact to the nanosecond (`clock_gettime` through rustix), where wall time includes waiting
//! for a core.
//!
//! The one implementation the benchmark, the progress lines and the examples read (the
//! `/proc` files they read before lag: `/proc/thread-self/schedstat` is updated at scheduler
//! ticks, `/proc/self/stat` counts 10 ms ticks).

/// CPU seconds this thread has used (`CLOCK_THREAD_CPUTIME_ID`); `NaN` where the platform has
/// no such clock.
pub fn thread_cpu_s() -> f64 {
    #[cfg(unix)]
    {
        seconds(rustix::time::clock_gettime(rustix::time::ClockId::ThreadCPUTime))
    }
    #[cfg(not(unix))]
    {
        f64::NAN
    }
}

/// CPU seconds (user + system, every thread) this process has used
/// (`CLOCK_PROCESS_CPUTIME_ID`); `NaN` where the platform has no such clock.
pub fn process_cpu_s() -> f64 {
    #[cfg(unix)]
    {
        seconds(rustix::time::clock_gettime(rustix::time::ClockId::ProcessCPUTime))
    }
    #[cfg(not(unix))]
    {
        f64::NAN
    }
}

#[cfg(unix)]
fn seconds(t: rustix::time::Timespec) -> f64 {
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both clocks advance with work done on this thread, by about the work's wall time (one
    /// busy thread), and the thread's never ahead of the process's.
    #[test]
    fn clocks_count_this_threads_work() {
        let (t0, p0) = (thread_cpu_s(), process_cpu_s());
        let start = std::time::Instant::now();
        let mut x = 0u64;
        while start.elapsed().as_millis() < 30 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let (t1, p1) = (thread_cpu_s(), process_cpu_s());
        let (dt, dp) = (t1 - t0, p1 - p0);
        assert!(dt > 0.0 && dt <= start.elapsed().as_secs_f64() + 1e-3, "thread {dt} s");
        assert!(dp >= dt - 1e-6, "process {dp} s against thread {dt} s");
        // Finer than the scheduler's tick (1-10 ms), which the `/proc` counters step by: the
        // first change seen while spinning is a small step.
        let a = thread_cpu_s();
        let mut b = a;
        while b == a {
            b = thread_cpu_s();
        }
        assert!(b - a < 2e-4, "the thread clock stepped {} s", b - a);
    }
}
