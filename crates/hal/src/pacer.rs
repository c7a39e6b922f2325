//! What starts each cycle, beside [`crate::Hal`] which the cycle talks to: the [`Pacer`]
//! trait (simulated time starts every cycle at once, the runtime's wall-clock executor sleeps
//! to absolute deadlines on the [`crate::Timebase`] grid) and the timing report a wall-clock
//! pacer hands back after the run (`--json` summary, MCAP `/summary`).

use ehactl_types::event::Event;
use ehactl_types::timing::CycleTiming;
use serde::Serialize;

/// Waits for the start of each cycle. The simulated loop does not wait; the wall-clock
/// executor (`ehactl_runtime::realtime::WallClockPacer`) sleeps to absolute deadlines.
pub trait Pacer {
    /// Block until cycle `k` may start; returns false if the loop should stop (a stop
    /// request, or a trip reported by [`Pacer::trip`]).
    fn wait_for_cycle(&mut self, k: u64) -> bool;

    /// Wall-clock timing of the cycle that just started (logged on `/timing`).
    fn cycle_timing(&self) -> Option<CycleTiming> {
        None
    }

    /// Next pending event of the pacer (set-up warnings, overruns); polled after each
    /// wait until None. Must not allocate.
    fn take_event(&mut self) -> Option<Event> {
        None
    }

    /// The trip that made `wait_for_cycle` return false, if it was one (e.g. too many
    /// consecutive overruns) rather than a stop request.
    fn trip(&self) -> Option<Event> {
        None
    }

    /// Timing statistics of the run (wall-clock pacers), read after the loop.
    fn timing_report(&self) -> Option<TimingReport> {
        None
    }
}

/// Simulated time: every cycle starts at once.
#[derive(Debug, Default, Clone, Copy)]
pub struct SimulatedTime;

impl Pacer for SimulatedTime {
    #[inline]
    fn wait_for_cycle(&mut self, _k: u64) -> bool {
        true
    }
}

/// Quantiles of one timing quantity (µs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Quantiles {
    /// Samples.
    pub count: u64,
    /// Minimum (µs).
    pub min: f64,
    /// Mean (µs).
    pub mean: f64,
    /// Median (µs).
    pub p50: f64,
    /// 99th percentile (µs).
    pub p99: f64,
    /// 99.9th percentile (µs).
    pub p999: f64,
    /// Maximum (µs).
    pub max: f64,
}

/// What real-time setting was applied at start-up.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct RtApplied {
    /// SCHED_FIFO priority in effect, if any.
    pub sched_fifo_priority: Option<i32>,
    /// CPU the loop thread is pinned to, if any.
    pub cpu: Option<usize>,
    /// Whether mlockall succeeded.
    pub memory_locked: bool,
    /// Settings that were requested but refused (one line each).
    pub warnings: Vec<String>,
}

/// Timing report of a wall-clock run (the `--json` summary and the MCAP `/summary`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TimingReport {
    /// Nominal period (µs).
    pub period_nominal_us: f64,
    /// Start lateness against the absolute deadline (µs).
    pub jitter: Quantiles,
    /// Start-to-start period (µs).
    pub period: Quantiles,
    /// Execution time per cycle, wall clock: cycle start → next wait (µs).
    pub exec: Quantiles,
    /// CPU time of the loop thread per cycle, cycle start → next wait (µs): the cycle's
    /// own work, without the time the thread was preempted.
    pub exec_cpu: Quantiles,
    /// Cycles whose CPU-time reading exceeded their wall execution time and was taken as
    /// the wall time (cycles; see `ehactl_runtime::realtime::TimingStats::exec_cpu_clamped`).
    pub exec_cpu_clamped: u64,
    /// Overruns (cycles).
    pub overruns: u64,
    /// Overruns whose cycle's own CPU time alone exceeded the period (cycles; see
    /// `ehactl_runtime::realtime::TimingStats::overruns_exec`).
    pub overruns_exec: u64,
    /// Overruns of cycles whose work fit in the period but whose thread was not running
    /// when needed: started late or preempted inside the cycle (cycles; see
    /// `ehactl_runtime::realtime::TimingStats::overruns_wakeup`).
    pub overruns_wakeup: u64,
    /// Longest streak of consecutive overruns (cycles).
    pub longest_overrun_streak: u64,
    /// Deadlines skipped by the overrun policy.
    pub skipped_deadlines: u64,
    /// Overrun policy ("continue", "skip", "trip after N").
    pub overrun_policy: String,
    /// Busy-wait tail (µs).
    pub spin_us: f64,
    /// Real-time settings in effect.
    pub rt: RtApplied,
}
