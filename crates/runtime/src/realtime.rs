//! Wall-clock executor: a [`Pacer`] that releases cycle k at an absolute deadline on
//! CLOCK_MONOTONIC (`clock_nanosleep(TIMER_ABSTIME)`, optionally followed by a short
//! busy-wait tail), applies SCHED_FIFO, `mlockall` and CPU affinity when the process is
//! permitted to (a warning, never a failure, when it is not), and keeps timing statistics
//! in constant memory (log-linear histograms, [`Histogram`]).
//!
//! Overrun = a cycle still running when the next deadline passes. What happens next is the
//! [`OverrunPolicy`]; no policy ever runs a burst of catch-up cycles:
//! - `Continue`: start the late cycle at once and shift the deadline grid to it (the period
//!   is kept, the phase is lost),
//! - `Skip`: keep the grid and wait for the next deadline still in the future (missed
//!   deadlines are counted as skipped),
//! - `Trip { after }`: like `Skip`, but N consecutive overruns trip the run (safe command).
//!
//! Everything in [`WallClockPacer::wait_for_cycle`] after the first call is allocation-free
//! and lock-free; the first call (start-up) applies the real-time settings, so that threads
//! spawned before it (the MCAP writer) keep the normal scheduler.

use crate::runloop::Pacer;
use ehactl_hal::record::{CycleTiming, Event, EventKind, Severity};
use ehactl_hal::Timebase;
use serde::Serialize;

/// What to do after a cycle overran its period.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OverrunPolicy {
    /// Run the late cycle at once and shift the deadline grid to it.
    Continue,
    /// Keep the grid phase; skip to the next deadline in the future.
    #[default]
    Skip,
    /// As `Skip`, and trip after this many consecutive overruns (≥ 1).
    Trip {
        /// Consecutive overruns that trip the run (cycles).
        after: u32,
    },
}

/// Real-time settings of a [`WallClockPacer`].
#[derive(Debug, Clone, Copy)]
pub struct RtOptions {
    /// SCHED_FIFO priority 1…99 for the loop thread; None = leave the scheduler alone.
    pub priority: Option<i32>,
    /// Pin the loop thread to this CPU (0-based); None = no affinity.
    pub cpu: Option<usize>,
    /// `mlockall(MCL_CURRENT | MCL_FUTURE)` so that no page fault hits the cycle.
    pub lock_memory: bool,
    /// Busy-wait tail before each deadline (s): sleep until `deadline − spin`, then spin.
    /// 0 = sleep only.
    pub spin: f64,
    /// Overrun policy.
    pub overrun: OverrunPolicy,
    /// Called once per real-time setting that could not be applied (start-up only).
    pub warn: Option<fn(&str)>,
}

impl RtOptions {
    /// Options of the wall-clock pacer from the config's `[realtime]` section.
    pub fn from_config(c: &ehactl_config::RealtimeConfig) -> RtOptions {
        use ehactl_config::OverrunPolicyConfig;
        RtOptions {
            priority: (c.priority > 0).then_some(c.priority as i32),
            cpu: (c.cpu >= 0).then_some(c.cpu as usize),
            lock_memory: c.lock_memory,
            spin: c.spin,
            overrun: match c.overrun_policy {
                OverrunPolicyConfig::Continue => OverrunPolicy::Continue,
                OverrunPolicyConfig::Skip => OverrunPolicy::Skip,
                OverrunPolicyConfig::Trip => OverrunPolicy::Trip {
                    after: c.trip_after,
                },
            },
            warn: None,
        }
    }
}

impl Default for RtOptions {
    fn default() -> Self {
        Self {
            priority: None,
            cpu: None,
            lock_memory: false,
            spin: 0.0,
            overrun: OverrunPolicy::Skip,
            warn: None,
        }
    }
}

const SUB_BITS: u32 = 8;
const SUB: u64 = 1 << SUB_BITS;
/// Largest value a histogram resolves (ns, ≈ 18 min); larger values land in the top bucket.
const MAX_VALUE: u64 = (1 << 40) - 1;
const BUCKETS: usize = (41 - SUB_BITS) as usize * SUB as usize;

/// Log-linear histogram of non-negative integer values (ns) in constant memory (8448
/// buckets, 66 KiB): exact below 512 ns, then 256 sub-buckets per power of two (relative
/// resolution ≤ 1/256 ≈ 0.4 %, i.e. ≤ 0.8 µs at a 200 µs period).
/// Quantiles report the upper edge of their bucket (never optimistic), capped at the
/// exact maximum.
#[derive(Clone)]
pub struct Histogram {
    counts: Box<[u64; BUCKETS]>,
    n: u64,
    min: u64,
    max: u64,
    sum: u128,
}

impl std::fmt::Debug for Histogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Histogram")
            .field("n", &self.n)
            .field("min", &self.min)
            .field("max", &self.max)
            .finish()
    }
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

impl Histogram {
    /// Empty histogram (allocates its fixed bucket array once).
    pub fn new() -> Self {
        Self {
            counts: Box::new([0; BUCKETS]),
            n: 0,
            min: u64::MAX,
            max: 0,
            sum: 0,
        }
    }

    #[inline]
    fn index(v: u64) -> usize {
        let v = v.min(MAX_VALUE);
        if v < 2 * SUB {
            return v as usize;
        }
        let msb = 63 - v.leading_zeros();
        let shift = msb - SUB_BITS;
        (shift as u64 * SUB + (v >> shift)) as usize
    }

    /// Largest value that falls in bucket `i`.
    fn upper(i: usize) -> u64 {
        let i = i as u64;
        if i < 2 * SUB {
            return i;
        }
        let shift = i / SUB - 1;
        let mant = i % SUB + SUB;
        ((mant + 1) << shift) - 1
    }

    /// Add one value (ns). Allocation-free, O(1).
    #[inline]
    pub fn record(&mut self, v: u64) {
        self.counts[Self::index(v)] += 1;
        self.n += 1;
        self.min = self.min.min(v);
        self.max = self.max.max(v);
        self.sum += v as u128;
    }

    /// Number of values.
    pub fn count(&self) -> u64 {
        self.n
    }

    /// Largest value (ns); 0 if empty.
    pub fn max(&self) -> u64 {
        self.max
    }

    /// Smallest value (ns); 0 if empty.
    pub fn min(&self) -> u64 {
        if self.n == 0 {
            0
        } else {
            self.min
        }
    }

    /// Mean (ns); NaN if empty.
    pub fn mean(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            self.sum as f64 / self.n as f64
        }
    }

    /// Value at quantile `q` ∈ [0, 1] (ns): the upper edge of the bucket holding the
    /// ⌈q·n⌉-th smallest value, capped at the maximum; None if empty.
    pub fn quantile(&self, q: f64) -> Option<u64> {
        if self.n == 0 {
            return None;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.n as f64).ceil() as u64).max(1);
        let mut seen = 0u64;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return Some(Self::upper(i).min(self.max).max(self.min));
            }
        }
        Some(self.max)
    }

    /// Quantile summary in µs.
    pub fn summary_us(&self) -> Quantiles {
        let us = |q: f64| self.quantile(q).map_or(f64::NAN, |v| v as f64 / 1e3);
        Quantiles {
            count: self.n,
            min: if self.n == 0 {
                f64::NAN
            } else {
                self.min as f64 / 1e3
            },
            mean: self.mean() / 1e3,
            p50: us(0.5),
            p99: us(0.99),
            p999: us(0.999),
            max: if self.n == 0 {
                f64::NAN
            } else {
                self.max as f64 / 1e3
            },
        }
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

/// Running timing statistics of a wall-clock run (constant memory).
#[derive(Debug, Clone, Default)]
pub struct TimingStats {
    /// Wake-up lateness: start − deadline (ns).
    pub jitter: Histogram,
    /// Start-to-start period (ns).
    pub period: Histogram,
    /// Execution time from cycle start to the next wait (ns).
    pub exec: Histogram,
    /// Cycles that finished after the next deadline.
    pub overruns: u64,
    /// Longest run of consecutive overruns (cycles).
    pub longest_overrun_streak: u64,
    /// Deadlines skipped by the `Skip` / `Trip` policies.
    pub skipped_deadlines: u64,
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
    /// Execution time per cycle (µs).
    pub exec: Quantiles,
    /// Overruns (cycles).
    pub overruns: u64,
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

/// Current CLOCK_MONOTONIC time (ns).
#[inline]
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: ts is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Sleep until the absolute CLOCK_MONOTONIC time `t_ns` (retries on EINTR, so a signal
/// handler that only sets a flag does not shorten the cycle).
#[inline]
fn sleep_until(t_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (t_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (t_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: ts is a valid timespec; the remainder pointer may be null with TIMER_ABSTIME.
        let rc = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if rc != libc::EINTR {
            break;
        }
    }
}

/// Minimum spacing of overrun warning events in the log (ns of wall time): the first
/// overrun of each second is logged (value = how late, s); all are counted in the stats
/// and flagged per cycle on `/timing`.
const OVERRUN_EVENT_SPACING_NS: u64 = 1_000_000_000;
const EVENT_SLOTS: usize = 8;

/// The wall-clock pacer (see the module docs).
pub struct WallClockPacer {
    period_ns: u64,
    spin_ns: u64,
    opts: RtOptions,
    started: bool,
    origin: u64,
    deadline: u64,
    last_start: u64,
    streak: u64,
    stats: TimingStats,
    timing: CycleTiming,
    applied: RtApplied,
    trip: Option<Event>,
    events: [Option<Event>; EVENT_SLOTS],
    n_events: usize,
    last_overrun_event: Option<u64>,
}

impl std::fmt::Debug for WallClockPacer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WallClockPacer")
            .field("period_ns", &self.period_ns)
            .field("opts", &self.opts)
            .field("stats", &self.stats)
            .finish()
    }
}

impl WallClockPacer {
    /// Pacer on the deadline grid of `timebase` (its period in whole ns). Nothing is
    /// applied until the first cycle.
    pub fn new(timebase: Timebase, opts: RtOptions) -> Self {
        let period_ns = timebase.period_ns();
        let spin_ns = (opts.spin.max(0.0) * 1e9).round() as u64;
        Self {
            period_ns,
            spin_ns: spin_ns.min(period_ns),
            opts,
            started: false,
            origin: 0,
            deadline: 0,
            last_start: 0,
            streak: 0,
            stats: TimingStats::default(),
            timing: CycleTiming::default(),
            applied: RtApplied::default(),
            trip: None,
            events: [None; EVENT_SLOTS],
            n_events: 0,
            last_overrun_event: None,
        }
    }

    /// Nominal period (ns).
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// Running statistics.
    pub fn stats(&self) -> &TimingStats {
        &self.stats
    }

    /// Real-time settings in effect (after the first cycle).
    pub fn applied(&self) -> &RtApplied {
        &self.applied
    }

    /// Timing report (µs) of the cycles so far.
    pub fn timing_report(&self) -> TimingReport {
        TimingReport {
            period_nominal_us: self.period_ns as f64 / 1e3,
            jitter: self.stats.jitter.summary_us(),
            period: self.stats.period.summary_us(),
            exec: self.stats.exec.summary_us(),
            overruns: self.stats.overruns,
            longest_overrun_streak: self.stats.longest_overrun_streak,
            skipped_deadlines: self.stats.skipped_deadlines,
            overrun_policy: match self.opts.overrun {
                OverrunPolicy::Continue => "continue".into(),
                OverrunPolicy::Skip => "skip".into(),
                OverrunPolicy::Trip { after } => format!("trip after {after}"),
            },
            spin_us: self.spin_ns as f64 / 1e3,
            rt: self.applied.clone(),
        }
    }

    fn push_event(&mut self, ev: Event) {
        if self.n_events < EVENT_SLOTS {
            self.events[self.n_events] = Some(ev);
            self.n_events += 1;
        }
    }

    fn warn(&mut self, channel: &'static str, errno: i32, text: String) {
        if let Some(w) = self.opts.warn {
            w(&text);
        }
        self.applied.warnings.push(text);
        self.push_event(Event {
            t: 0.0,
            cycle: 0,
            severity: Severity::Warning,
            kind: EventKind::RtSetup,
            channel,
            value: errno as f64,
            limit: f64::NAN,
            unit: "errno",
        });
    }

    /// Apply SCHED_FIFO, CPU affinity and mlockall to the calling thread / process.
    fn apply_rt(&mut self) {
        if let Some(cpu) = self.opts.cpu {
            // SAFETY: cpu_set_t is plain data; CPU_SET bounds are checked below.
            let rc = unsafe {
                let mut set: libc::cpu_set_t = std::mem::zeroed();
                if cpu < libc::CPU_SETSIZE as usize {
                    libc::CPU_SET(cpu, &mut set);
                    libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
                } else {
                    -1
                }
            };
            if rc == 0 {
                self.applied.cpu = Some(cpu);
            } else {
                let e = std::io::Error::last_os_error();
                self.warn(
                    "cpu_affinity",
                    e.raw_os_error().unwrap_or(0),
                    format!("cannot pin the control loop to CPU {cpu} ({e}); running unpinned"),
                );
            }
        }
        if self.opts.lock_memory {
            // SAFETY: plain syscall.
            let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
            if rc == 0 {
                self.applied.memory_locked = true;
            } else {
                let e = std::io::Error::last_os_error();
                self.warn(
                    "mlockall",
                    e.raw_os_error().unwrap_or(0),
                    format!("mlockall failed ({e}); memory not locked, page faults may delay cycles (raise RLIMIT_MEMLOCK or grant CAP_IPC_LOCK)"),
                );
            }
        }
        if let Some(prio) = self.opts.priority {
            let param = libc::sched_param {
                sched_priority: prio,
            };
            // SAFETY: valid sched_param; 0 = calling thread.
            let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
            if rc == 0 {
                self.applied.sched_fifo_priority = Some(prio);
            } else {
                let e = std::io::Error::last_os_error();
                self.warn(
                    "sched_fifo",
                    e.raw_os_error().unwrap_or(0),
                    format!("cannot set SCHED_FIFO priority {prio} ({e}); running under the normal scheduler (grant CAP_SYS_NICE or an rtprio limit)"),
                );
            }
        }
    }

    #[inline]
    fn sleep_to(&self, deadline: u64) -> u64 {
        if self.spin_ns > 0 {
            let wake = deadline - self.spin_ns.min(deadline);
            if monotonic_ns() < wake {
                sleep_until(wake);
            }
            loop {
                let now = monotonic_ns();
                if now >= deadline {
                    return now;
                }
                std::hint::spin_loop();
            }
        } else {
            sleep_until(deadline);
            monotonic_ns()
        }
    }
}

impl Pacer for WallClockPacer {
    fn wait_for_cycle(&mut self, k: u64) -> bool {
        if !self.started {
            self.started = true;
            self.apply_rt();
            // First deadline one period ahead, so start-up page faults settle first.
            let now = monotonic_ns();
            self.origin = now + self.period_ns;
            self.deadline = self.origin;
            let start = self.sleep_to(self.deadline);
            self.stats.jitter.record(start - self.deadline);
            self.last_start = start;
            self.timing = CycleTiming {
                wall_t: (start - self.origin) as f64 * 1e-9,
                lateness_us: (start - self.deadline) as f64 * 1e-3,
                period_us: f64::NAN,
                exec_prev_us: f64::NAN,
                skipped: 0,
                overrun: false,
            };
            return true;
        }
        let now = monotonic_ns();
        let exec = now - self.last_start;
        self.stats.exec.record(exec);
        let nominal = self.deadline + self.period_ns;
        let mut deadline = nominal;
        let mut skipped = 0u64;
        let overrun = now > deadline;
        if overrun {
            self.streak += 1;
            self.stats.overruns += 1;
            self.stats.longest_overrun_streak = self.stats.longest_overrun_streak.max(self.streak);
            let late = now - deadline;
            let spaced = match self.last_overrun_event {
                None => true,
                Some(t) => now - t >= OVERRUN_EVENT_SPACING_NS,
            };
            if spaced {
                self.last_overrun_event = Some(now);
                let ev = Event {
                    t: k as f64 * self.period_ns as f64 * 1e-9,
                    cycle: k,
                    severity: Severity::Warning,
                    kind: EventKind::Overrun,
                    channel: "cycle",
                    value: late as f64 * 1e-9,
                    limit: f64::NAN,
                    unit: "s",
                };
                self.push_event(ev);
            }
            match self.opts.overrun {
                OverrunPolicy::Continue => {
                    // Start now; the grid moves to this start (no catch-up burst).
                    deadline = now;
                }
                OverrunPolicy::Skip | OverrunPolicy::Trip { .. } => {
                    let missed = late / self.period_ns + 1;
                    skipped = missed;
                    deadline += missed * self.period_ns;
                    self.stats.skipped_deadlines += missed;
                }
            }
            if let OverrunPolicy::Trip { after } = self.opts.overrun {
                if self.streak >= after.max(1) as u64 {
                    self.trip = Some(Event {
                        t: k as f64 * self.period_ns as f64 * 1e-9,
                        cycle: k,
                        severity: Severity::Trip,
                        kind: EventKind::Overrun,
                        channel: "cycle",
                        value: self.streak as f64,
                        limit: after as f64,
                        unit: "cycles",
                    });
                    self.deadline = deadline;
                    return false;
                }
            }
        } else {
            self.streak = 0;
        }
        let start = if deadline > now {
            self.sleep_to(deadline)
        } else {
            now
        };
        // Lateness against the deadline the cycle runs for; with `Continue` that is the
        // original grid point it missed (honest: the late start counts as jitter).
        let late = match self.opts.overrun {
            OverrunPolicy::Continue => start.saturating_sub(nominal),
            _ => start.saturating_sub(deadline),
        };
        self.stats.jitter.record(late);
        let period = start - self.last_start;
        self.stats.period.record(period);
        self.timing = CycleTiming {
            wall_t: start.saturating_sub(self.origin) as f64 * 1e-9,
            lateness_us: late as f64 * 1e-3,
            period_us: period as f64 * 1e-3,
            exec_prev_us: exec as f64 * 1e-3,
            skipped: skipped.min(u32::MAX as u64) as u32,
            overrun,
        };
        self.deadline = deadline;
        self.last_start = start;
        true
    }

    fn cycle_timing(&self) -> Option<CycleTiming> {
        Some(self.timing)
    }

    fn take_event(&mut self) -> Option<Event> {
        if self.n_events == 0 {
            return None;
        }
        let ev = self.events[0].take();
        self.events.rotate_left(1);
        self.n_events -= 1;
        ev
    }

    fn trip(&self) -> Option<Event> {
        self.trip
    }

    fn timing_report(&self) -> Option<TimingReport> {
        Some(WallClockPacer::timing_report(self))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_buckets_are_contiguous_and_tight() {
        // Every value maps into a bucket whose upper edge is ≥ the value and within 1/256.
        let mut prev = 0usize;
        for v in (0..5000u64).chain((1..2000).map(|i| i * 9973)) {
            let i = Histogram::index(v);
            let up = Histogram::upper(i);
            assert!(up >= v, "v {v} bucket {i} upper {up}");
            assert!(
                (up - v) as f64 <= v as f64 / 256.0 + 1.0,
                "v {v} upper {up}"
            );
            if v < 5000 {
                assert!(i == prev || i == prev + 1, "gap at {v}");
                prev = i;
            }
        }
        assert!(Histogram::index(MAX_VALUE) < BUCKETS);
        assert_eq!(Histogram::index(u64::MAX), Histogram::index(MAX_VALUE));
    }

    #[test]
    fn histogram_quantiles_match_sorted_data() {
        // Deterministic pseudo-random data with a heavy tail; compare with exact order
        // statistics: the histogram answer must be ≥ exact and within 1/256 of it.
        let mut x = 0x1234_5678_9abc_def0u64;
        let mut data = Vec::new();
        let mut h = Histogram::new();
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let v = if x % 1000 == 0 {
                x % 5_000_000
            } else {
                1000 + x % 40_000
            };
            data.push(v);
            h.record(v);
        }
        data.sort_unstable();
        for q in [0.5, 0.9, 0.99, 0.999, 1.0] {
            let rank = ((q * data.len() as f64).ceil() as usize).max(1);
            let exact = data[rank - 1];
            let got = h.quantile(q).unwrap();
            assert!(got >= exact, "q {q}: {got} < exact {exact}");
            assert!(
                (got - exact) as f64 <= exact as f64 / 256.0 + 1.0,
                "q {q}: {got} vs {exact}"
            );
        }
        assert_eq!(h.max(), *data.last().unwrap());
        assert_eq!(h.min(), data[0]);
        assert_eq!(h.count(), 100_000);
    }

    #[test]
    fn paces_at_the_period_against_the_monotonic_clock() {
        // 500 cycles at 1 kHz must take ≥ 499 ms of monotonic time (deadlines are absolute:
        // the pacer can never run ahead), and every period sample is ≥ 0.
        let mut p = WallClockPacer::new(Timebase::at_rate_hz(1e3), RtOptions::default());
        let t0 = monotonic_ns();
        for k in 0..500 {
            assert!(p.wait_for_cycle(k));
        }
        let elapsed = monotonic_ns() - t0;
        assert!(elapsed >= 499_000_000, "elapsed {elapsed} ns");
        let s = p.stats();
        assert_eq!(s.jitter.count(), 500);
        assert_eq!(s.period.count(), 499);
        // Absolute deadlines do not drift: first-to-last start time equals the number of
        // grid periods elapsed (499 + skipped) to within the worst wake-up lateness.
        let first_to_last = s.period.mean() * 499.0;
        let grid = (499 + s.skipped_deadlines) as f64 * 1e6;
        assert!(
            (first_to_last - grid).abs() <= s.jitter.max() as f64 + 1.0,
            "first→last {first_to_last} ns vs grid {grid} ns (max lateness {} ns)",
            s.jitter.max()
        );
    }

    #[test]
    fn skip_policy_skips_missed_deadlines_without_a_burst() {
        // 10 ms period: wide margins against scheduling noise on a shared machine.
        let mut p = WallClockPacer::new(Timebase::at_rate_hz(100.0), RtOptions::default());
        assert!(p.wait_for_cycle(0));
        std::thread::sleep(std::time::Duration::from_millis(35));
        assert!(p.wait_for_cycle(1));
        // Overran by ≥ 2.5 periods: deadlines 1, 2, 3 (at least) are skipped and the
        // cycle starts on the grid, in the future.
        let s = p.stats();
        assert_eq!(s.overruns, 1);
        assert!(s.skipped_deadlines >= 3, "{}", s.skipped_deadlines);
        let tm = p.cycle_timing().unwrap();
        assert!(tm.overrun && tm.skipped >= 3);
        // The next cycle is one period later (no catch-up burst).
        let t1 = monotonic_ns();
        assert!(p.wait_for_cycle(2));
        let t2 = monotonic_ns();
        assert!(t2 - t1 >= 9_000_000, "next cycle came after {} ns", t2 - t1);
        assert_eq!(p.stats().overruns, 1);
        assert_eq!(p.stats().longest_overrun_streak, 1);
        let ev = p.take_event().expect("overrun event");
        assert_eq!(ev.kind, EventKind::Overrun);
        assert!(ev.value >= 25e-3, "{}", ev.value);
    }

    #[test]
    fn continue_policy_shifts_the_grid() {
        let opts = RtOptions {
            overrun: OverrunPolicy::Continue,
            ..Default::default()
        };
        let mut p = WallClockPacer::new(Timebase::at_rate_hz(100.0), opts);
        assert!(p.wait_for_cycle(0));
        std::thread::sleep(std::time::Duration::from_millis(25));
        let t_late = monotonic_ns();
        assert!(p.wait_for_cycle(1));
        // Started at once (no sleep to the next grid point, which is ≥ 5 ms away),
        // nothing skipped, and the late start counts as jitter (≥ 15 ms).
        assert!(monotonic_ns() - t_late < 4_000_000);
        assert_eq!(p.stats().skipped_deadlines, 0);
        assert_eq!(p.stats().overruns, 1);
        assert!(p.stats().jitter.max() >= 15_000_000);
        let t1 = monotonic_ns();
        assert!(p.wait_for_cycle(2));
        // One full period after the late start, not an immediate catch-up cycle.
        assert!(monotonic_ns() - t1 >= 9_000_000);
    }

    #[test]
    fn trip_policy_trips_after_n_consecutive_overruns() {
        let opts = RtOptions {
            overrun: OverrunPolicy::Trip { after: 3 },
            ..Default::default()
        };
        let mut p = WallClockPacer::new(Timebase::at_rate_hz(100.0), opts);
        assert!(p.wait_for_cycle(0));
        let mut k = 1;
        // Two overruns, then an on-time cycle resets the streak.
        for _ in 0..2 {
            std::thread::sleep(std::time::Duration::from_millis(15));
            assert!(p.wait_for_cycle(k));
            k += 1;
        }
        assert!(p.wait_for_cycle(k));
        k += 1;
        assert!(p.trip().is_none());
        assert_eq!(p.stats().longest_overrun_streak, 2);
        let mut ok = true;
        for _ in 0..3 {
            std::thread::sleep(std::time::Duration::from_millis(15));
            ok = p.wait_for_cycle(k);
            k += 1;
            if !ok {
                break;
            }
        }
        assert!(!ok, "third consecutive overrun must trip");
        let ev = p.trip().expect("trip event");
        assert_eq!(ev.kind, EventKind::Overrun);
        assert_eq!(ev.severity, Severity::Trip);
        assert_eq!(ev.value, 3.0);
        assert_eq!(p.stats().overruns, 5);
    }

    #[test]
    fn refused_settings_warn_instead_of_failing() {
        // CPU 100000 does not exist: affinity must be refused with a warning, and the
        // pacer still runs.
        let opts = RtOptions {
            cpu: Some(100_000),
            ..Default::default()
        };
        let mut p = WallClockPacer::new(Timebase::at_rate_hz(1e3), opts);
        assert!(p.wait_for_cycle(0));
        assert!(p.wait_for_cycle(1));
        assert_eq!(p.applied().cpu, None);
        assert_eq!(p.applied().warnings.len(), 1);
        let ev = p.take_event().unwrap();
        assert_eq!(ev.kind, EventKind::RtSetup);
        assert_eq!(ev.channel, "cpu_affinity");
        assert!(p.take_event().is_none());
    }
}
