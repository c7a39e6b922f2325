//! What a wall-clock pacer measures of each cycle ([`CycleTiming`]): produced by the pacer
//! (`ehactl_hal::pacer::Pacer::cycle_timing`), carried in the cycle record and written to
//! the `/timing` channel by the logger (crates/log/src/record.rs encodes it).

/// Wall-clock timing of one cycle, measured by a real-time pacer on CLOCK_MONOTONIC.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleTiming {
    /// Start of the cycle since the first deadline of the run (s, wall clock).
    pub wall_t: f64,
    /// Wake-up lateness: actual start − deadline (µs, ≥ 0).
    pub lateness_us: f64,
    /// Time since the previous cycle's start (µs); NaN for the first cycle.
    pub period_us: f64,
    /// Execution time of the previous cycle, from its start to the next wait (µs).
    pub exec_prev_us: f64,
    /// Deadlines skipped before this cycle by the overrun policy (-).
    pub skipped: u32,
    /// Whether the previous cycle overran (finished after this cycle's deadline).
    pub overrun: bool,
    /// Whether that overrun was the previous cycle's own doing: its execution
    /// (`exec_prev_us`) alone exceeded the period. False for an overrun of a cycle that fit
    /// in the period but started late (the thread was not running at its deadline).
    pub overrun_exec: bool,
}
