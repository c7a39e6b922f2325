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

use ehactl_hal::clock::{Clock, MonotonicClock};
use ehactl_hal::pacer::{Pacer, Quantiles, RtApplied, TimingReport};
use ehactl_hal::Timebase;
use ehactl_log::record::{CycleTiming, Event, EventKind, Severity};

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

/// Running timing statistics of a wall-clock run (constant memory).
#[derive(Debug, Clone, Default)]
pub struct TimingStats {
    /// Wake-up lateness: start − deadline (ns).
    pub jitter: Histogram,
    /// Start-to-start period (ns).
    pub period: Histogram,
    /// Execution time from cycle start to the next wait, wall clock (ns): includes any time
    /// the thread was preempted inside the cycle.
    pub exec: Histogram,
    /// CPU time of the loop thread from cycle start to the next wait (ns,
    /// `CLOCK_THREAD_CPUTIME_ID`): the cycle's own work, without the time it was not running.
    pub exec_cpu: Histogram,
    /// Cycles whose CPU-time reading exceeded their wall execution time. A thread cannot run
    /// longer than the wall time that passed, but Linux's per-thread CPU clock comes from the
    /// scheduler clock of the core the thread last ran on: on machines whose cores' scheduler
    /// clocks are not synchronised (VMs without a stable TSC; `sched_clock` in the kernel's
    /// `kernel/sched/clock.c`) it runs ahead of CLOCK_MONOTONIC across a migration. Such a
    /// cycle's CPU time is taken as its wall time (an upper bound); a count well above zero
    /// says the CPU/wall split of that run is uncertain by up to the skew.
    pub exec_cpu_clamped: u64,
    /// Cycles that finished after the next deadline.
    pub overruns: u64,
    /// Overruns caused by our own execution: the cycle's work (its thread CPU time, start to
    /// the next wait) alone took longer than the period, so it would have overrun even if it
    /// had started exactly on its deadline and run without preemption.
    pub overruns_exec: u64,
    /// Overruns of cycles whose work fit in the period but whose thread was not running
    /// when needed: it started late (woken after its deadline; with `Continue` also a spill
    /// of an earlier overrun) or was preempted inside the cycle (wall execution above the
    /// period, CPU time within it). `overruns_exec + overruns_wakeup = overruns`.
    pub overruns_wakeup: u64,
    /// Longest run of consecutive overruns (cycles).
    pub longest_overrun_streak: u64,
    /// Deadlines skipped by the `Skip` / `Trip` policies.
    pub skipped_deadlines: u64,
}

/// Minimum spacing of overrun warning events in the log (ns of wall time): the first
/// overrun of each second is logged (value = how late, s); all are counted in the stats
/// and flagged per cycle on `/timing`.
const OVERRUN_EVENT_SPACING_NS: u64 = 1_000_000_000;
const EVENT_SLOTS: usize = 8;

/// The wall-clock pacer (see the module docs), on CLOCK_MONOTONIC ([`MonotonicClock`])
/// unless a test gives it another [`Clock`] (`ehactl_hal::clock::ScriptedClock`: the
/// pacer's decisions checked by counting, whatever the machine's load).
pub struct WallClockPacer<C: Clock = MonotonicClock> {
    clock: C,
    period_ns: u64,
    spin_ns: u64,
    opts: RtOptions,
    started: bool,
    origin: u64,
    deadline: u64,
    last_start: u64,
    /// Thread CPU time at the start of the current cycle (ns).
    last_start_cpu: u64,
    streak: u64,
    stats: TimingStats,
    timing: CycleTiming,
    applied: RtApplied,
    trip: Option<Event>,
    events: [Option<Event>; EVENT_SLOTS],
    n_events: usize,
    last_overrun_event: Option<u64>,
}

impl<C: Clock> std::fmt::Debug for WallClockPacer<C> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WallClockPacer")
            .field("period_ns", &self.period_ns)
            .field("opts", &self.opts)
            .field("stats", &self.stats)
            .finish()
    }
}

impl WallClockPacer<MonotonicClock> {
    /// Pacer on the deadline grid of `timebase` (its period in whole ns). Nothing is
    /// applied until the first cycle.
    pub fn new(timebase: Timebase, opts: RtOptions) -> Self {
        WallClockPacer::with_clock(timebase, opts, MonotonicClock::new())
    }
}

impl<C: Clock> WallClockPacer<C> {
    /// [`WallClockPacer::new`] on another clock (tests).
    pub fn with_clock(timebase: Timebase, opts: RtOptions, clock: C) -> Self {
        let period_ns = timebase.period_ns();
        let spin_ns = (opts.spin.max(0.0) * 1e9).round() as u64;
        Self {
            clock,
            period_ns,
            spin_ns: spin_ns.min(period_ns),
            opts,
            started: false,
            origin: 0,
            deadline: 0,
            last_start: 0,
            last_start_cpu: 0,
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

    /// The clock.
    pub fn clock(&self) -> &C {
        &self.clock
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
            exec_cpu: self.stats.exec_cpu.summary_us(),
            exec_cpu_clamped: self.stats.exec_cpu_clamped,
            overruns: self.stats.overruns,
            overruns_exec: self.stats.overruns_exec,
            overruns_wakeup: self.stats.overruns_wakeup,
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
            if self.clock.now_ns() < wake {
                self.clock.sleep_until(wake);
            }
            loop {
                let now = self.clock.now_ns();
                if now >= deadline {
                    return now;
                }
                std::hint::spin_loop();
            }
        } else {
            self.clock.sleep_until(deadline);
            self.clock.now_ns()
        }
    }

    /// The first cycle: the real-time settings applied, the grid's origin one period ahead
    /// (so start-up page faults settle first) and the sleep to it.
    #[inline]
    fn start_grid(&mut self) {
        self.started = true;
        self.apply_rt();
        let now = self.clock.now_ns();
        self.origin = now + self.period_ns;
        self.deadline = self.origin;
        let start = self.sleep_to(self.deadline);
        self.stats.jitter.record(start - self.deadline);
        self.last_start = start;
        self.last_start_cpu = self.clock.thread_cpu_ns();
        self.timing = CycleTiming {
            wall_t: (start - self.origin) as f64 * 1e-9,
            lateness_us: (start - self.deadline) as f64 * 1e-3,
            period_us: f64::NAN,
            exec_prev_us: f64::NAN,
            skipped: 0,
            overrun: false,
            overrun_exec: false,
        };
    }

    /// The previous cycle's execution time up to `now` (ns), wall and thread CPU time, both
    /// recorded; (wall, CPU).
    #[inline]
    fn record_exec(&mut self, now: u64) -> (u64, u64) {
        let exec = now - self.last_start;
        self.stats.exec.record(exec);
        let exec_cpu_read = self
            .clock
            .thread_cpu_ns()
            .saturating_sub(self.last_start_cpu);
        // CPU time ≤ wall time; a reading above it is clock skew (`exec_cpu_clamped`).
        let exec_cpu = if exec_cpu_read > exec {
            self.stats.exec_cpu_clamped += 1;
            exec
        } else {
            exec_cpu_read
        };
        self.stats.exec_cpu.record(exec_cpu);
        (exec, exec_cpu)
    }

    /// Cycle `k` starts at `now` (ns), after its `deadline` (ns): counted (`overrun_exec`:
    /// the work's own CPU time exceeded the period), an overrun event at most every
    /// [`OVERRUN_EVENT_SPACING_NS`], then the policy. Returns the deadline the cycle runs for
    /// and the deadlines skipped, or `None` when the policy trips the run (the trip event
    /// set).
    #[inline]
    fn on_overrun(
        &mut self,
        k: u64,
        now: u64,
        deadline: u64,
        overrun_exec: bool,
    ) -> Option<(u64, u64)> {
        let mut deadline = deadline;
        let mut skipped = 0u64;
        self.streak += 1;
        self.stats.overruns += 1;
        if overrun_exec {
            self.stats.overruns_exec += 1;
        } else {
            self.stats.overruns_wakeup += 1;
        }
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
                return None;
            }
        }
        Some((deadline, skipped))
    }
}

impl<C: Clock> Pacer for WallClockPacer<C> {
    fn wait_for_cycle(&mut self, k: u64) -> bool {
        if !self.started {
            self.start_grid();
            return true;
        }
        let now = self.clock.now_ns();
        let (exec, exec_cpu) = self.record_exec(now);
        let nominal = self.deadline + self.period_ns;
        let mut deadline = nominal;
        let mut skipped = 0u64;
        let overrun = now > deadline;
        // Whose fault: the work alone (CPU time, preemptions inside the cycle excluded)
        // overran the period (ours), or it fit but the thread was not running when needed.
        let overrun_exec = overrun && exec_cpu > self.period_ns;
        if overrun {
            match self.on_overrun(k, now, nominal, overrun_exec) {
                Some(next) => (deadline, skipped) = next,
                None => return false,
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
            overrun_exec,
        };
        self.deadline = deadline;
        self.last_start = start;
        self.last_start_cpu = self.clock.thread_cpu_ns();
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
    use ehactl_hal::clock::ScriptedClock;

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
            let v = if x.is_multiple_of(1000) {
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
        let clock = MonotonicClock::new();
        let t0 = clock.now_ns();
        for k in 0..500 {
            assert!(p.wait_for_cycle(k));
        }
        let elapsed = clock.now_ns() - t0;
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

    const MS: u64 = 1_000_000;

    /// A pacer on a scripted clock (`ehactl_hal::clock::ScriptedClock`): time moves only
    /// when the test says so (`work`, the cycle's execution) or when the pacer sleeps (to
    /// the requested time + the lateness set), so every decision of the pacer is checked by
    /// counting, whatever the machine's load.
    fn scripted(opts: RtOptions) -> WallClockPacer<ScriptedClock> {
        // 10 ms period; the clock starts at 1 s.
        let clock = ScriptedClock::at(1_000 * MS);
        WallClockPacer::with_clock(Timebase::at_rate_hz(100.0), opts, clock)
    }

    #[test]
    fn skip_policy_skips_missed_deadlines_without_a_burst() {
        let mut p = scripted(RtOptions::default());
        assert!(p.wait_for_cycle(0));
        let d0 = 1_010 * MS; // first deadline: one period after the start-up call
        assert_eq!(p.clock().now_ns(), d0);
        // Cycle 0 works for 35 ms = 3.5 periods: it overran deadline 1 by 25 ms, so
        // deadlines 1, 2, 3 are missed and skipped; cycle 1 starts on deadline 4 (the
        // grid phase is kept) — not at once, which would begin a catch-up burst.
        p.clock().work(35 * MS);
        assert!(p.wait_for_cycle(1));
        assert_eq!(p.clock().now_ns(), d0 + 4 * 10 * MS);
        let s = p.stats();
        assert_eq!((s.overruns, s.skipped_deadlines), (1, 3));
        // Our own execution (35 ms > 10 ms) caused it.
        assert_eq!((s.overruns_exec, s.overruns_wakeup), (1, 0));
        let tm = p.cycle_timing().unwrap();
        assert!(tm.overrun && tm.overrun_exec);
        assert_eq!(tm.skipped, 3);
        assert_eq!(tm.exec_prev_us, 35_000.0);
        assert_eq!(tm.lateness_us, 0.0);
        let ev = p.take_event().expect("overrun event");
        assert_eq!(ev.kind, EventKind::Overrun);
        assert_eq!(ev.value, 25e-3);
        // The cycles after it come one period apart, each on its grid point: no burst.
        for k in 2..6u64 {
            p.clock().work(MS);
            assert!(p.wait_for_cycle(k));
            assert_eq!(p.clock().now_ns(), d0 + (k + 3) * 10 * MS, "cycle {k}");
            assert_eq!(p.cycle_timing().unwrap().period_us, 10_000.0);
        }
        let s = p.stats();
        assert_eq!(
            (s.overruns, s.skipped_deadlines, s.longest_overrun_streak),
            (1, 3, 1)
        );
        assert_eq!(s.period.count(), 5);
        assert!(p.take_event().is_none(), "one overrun, one event");
    }

    #[test]
    fn a_preemption_inside_the_cycle_is_not_our_overrun() {
        let mut p = scripted(RtOptions::default());
        assert!(p.wait_for_cycle(0));
        // Cycle 0 starts on time, works 3 ms, is preempted for 9 ms, works 1 ms more:
        // 13 ms of wall time > 10 ms, but only 4 ms of its own CPU time.
        p.clock().work(3 * MS);
        p.clock().preempted(9 * MS);
        p.clock().work(MS);
        assert!(p.wait_for_cycle(1));
        let s = p.stats();
        assert_eq!((s.overruns, s.overruns_exec, s.overruns_wakeup), (1, 0, 1));
        let tm = p.cycle_timing().unwrap();
        assert!(tm.overrun && !tm.overrun_exec);
        assert_eq!(tm.exec_prev_us, 13_000.0);
        assert_eq!(s.exec.summary_us().max, 13_000.0);
        // The CPU-time histogram holds the 4 ms (quantiles are bucket upper edges,
        // ≤ 1/256 above the value).
        let cpu = s.exec_cpu.summary_us().max;
        assert!(
            (4_000.0..=4_000.0 * (1.0 + 1.0 / 256.0)).contains(&cpu),
            "{cpu}"
        );
        // Cycle 1 (on its grid point after the skip) works 11 ms of CPU: ours.
        p.clock().work(11 * MS);
        assert!(p.wait_for_cycle(2));
        assert_eq!(p.stats().overruns_exec, 1);
        assert!(p.cycle_timing().unwrap().overrun_exec);
    }

    #[test]
    fn a_cpu_clock_ahead_of_the_wall_clock_is_clamped_and_counted() {
        let mut p = scripted(RtOptions::default());
        assert!(p.wait_for_cycle(0));
        // Cycle 0 works 2 ms and migrates to a core whose scheduler clock is 18 ms ahead:
        // its CPU time reads 20 ms for 2 ms of wall time.
        p.clock().work(2 * MS);
        p.clock().cpu_clock_skew(18 * MS);
        assert!(p.wait_for_cycle(1));
        let s = p.stats();
        assert_eq!(s.exec_cpu_clamped, 1);
        // Taken as its wall time, so it is neither an overrun nor ours.
        assert_eq!((s.overruns, s.overruns_exec), (0, 0));
        let (cpu, wall) = (s.exec_cpu.summary_us().max, s.exec.summary_us().max);
        assert_eq!(cpu, wall);
        assert!(
            (2_000.0..=2_000.0 * (1.0 + 1.0 / 256.0)).contains(&cpu),
            "{cpu}"
        );
        // A cycle whose CPU reading is within its wall time is not counted.
        p.clock().work(3 * MS);
        assert!(p.wait_for_cycle(2));
        assert_eq!(p.stats().exec_cpu_clamped, 1);
        assert_eq!(p.timing_report().exec_cpu_clamped, 1);
    }

    #[test]
    fn an_overrun_is_split_into_our_execution_and_a_late_start() {
        let mut p = scripted(RtOptions::default());
        assert!(p.wait_for_cycle(0));
        p.clock().work(4 * MS);
        // The thread is not running at deadline 1: its sleep returns 7 ms late. Cycle 1
        // then does 4 ms of work: 7 + 4 = 11 ms > 10 ms, an overrun of a cycle that fit.
        p.clock().set_late_by(7 * MS);
        assert!(p.wait_for_cycle(1));
        p.clock().set_late_by(0);
        assert_eq!(p.cycle_timing().unwrap().lateness_us, 7_000.0);
        p.clock().work(4 * MS);
        assert!(p.wait_for_cycle(2));
        let s = p.stats();
        assert_eq!((s.overruns, s.overruns_exec, s.overruns_wakeup), (1, 0, 1));
        let tm = p.cycle_timing().unwrap();
        assert!(tm.overrun && !tm.overrun_exec);
        assert_eq!(tm.exec_prev_us, 4_000.0);
        // Cycle 2 starts on time and works 12 ms: our own overrun.
        p.clock().work(12 * MS);
        assert!(p.wait_for_cycle(3));
        let tm = p.cycle_timing().unwrap();
        assert!(tm.overrun && tm.overrun_exec);
        let r = p.timing_report();
        assert_eq!((r.overruns, r.overruns_exec, r.overruns_wakeup), (2, 1, 1));
        // Execution is wall time from start to wait: a preemption inside the cycle counts
        // as execution (DEPLOY.md says so), e.g. 3 ms of work + 8 ms not running.
        p.clock().work(3 * MS);
        p.clock().work(8 * MS);
        assert!(p.wait_for_cycle(4));
        assert_eq!(p.stats().overruns_exec, 2);
    }

    #[test]
    fn continue_policy_shifts_the_grid() {
        let opts = RtOptions {
            overrun: OverrunPolicy::Continue,
            ..Default::default()
        };
        let mut p = scripted(opts);
        assert!(p.wait_for_cycle(0));
        let d0 = p.clock().now_ns();
        p.clock().work(25 * MS);
        let sleeps = p.clock().sleeps();
        assert!(p.wait_for_cycle(1));
        // Started at once (no sleep to the next grid point, 5 ms away), nothing skipped,
        // and the late start (15 ms after the deadline it missed) counts as jitter.
        assert_eq!(p.clock().sleeps(), sleeps);
        assert_eq!(p.clock().now_ns(), d0 + 25 * MS);
        assert_eq!(p.stats().skipped_deadlines, 0);
        assert_eq!(p.stats().overruns, 1);
        assert_eq!(p.stats().jitter.max(), 15 * MS);
        // The grid moved to that start: the next cycle one full period later, not at once.
        p.clock().work(MS);
        assert!(p.wait_for_cycle(2));
        assert_eq!(p.clock().now_ns(), d0 + 35 * MS);
        assert_eq!(p.stats().overruns, 1);
    }

    #[test]
    fn trip_policy_trips_after_n_consecutive_overruns() {
        let opts = RtOptions {
            overrun: OverrunPolicy::Trip { after: 3 },
            ..Default::default()
        };
        let mut p = scripted(opts);
        assert!(p.wait_for_cycle(0));
        let mut k = 1;
        // Two overruns, then an on-time cycle resets the streak.
        for _ in 0..2 {
            p.clock().work(15 * MS);
            assert!(p.wait_for_cycle(k));
            k += 1;
        }
        p.clock().work(MS);
        assert!(p.wait_for_cycle(k));
        k += 1;
        assert!(p.trip().is_none());
        assert_eq!(p.stats().longest_overrun_streak, 2);
        let mut trips_at = None;
        for i in 0..3 {
            p.clock().work(15 * MS);
            let ok = p.wait_for_cycle(k);
            k += 1;
            if !ok {
                trips_at = Some(i);
                break;
            }
        }
        assert_eq!(
            trips_at,
            Some(2),
            "the third consecutive overrun trips, not earlier"
        );
        let ev = p.trip().expect("trip event");
        assert_eq!(ev.kind, EventKind::Overrun);
        assert_eq!(ev.severity, Severity::Trip);
        assert_eq!(ev.value, 3.0);
        assert_eq!(p.stats().overruns, 5);
        assert_eq!(p.stats().overruns_exec, 5);
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
        // Only the one set-up warning; an overrun of cycle 1 on a loaded machine is a
        // different event and not what this test is about.
        while let Some(ev) = p.take_event() {
            assert_eq!(ev.kind, EventKind::Overrun, "unexpected event {ev:?}");
        }
    }
}
