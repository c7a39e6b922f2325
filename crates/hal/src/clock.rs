//! The time sources of ehactl, one trait for every user: the wall-clock pacer
//! (`ehactl_runtime::realtime::WallClockPacer`: absolute deadlines, thread CPU time), the
//! CANopen start-up and the CAN backend's I/O side (`ehactl_canopen::startup`,
//! `ehactl_canopen::hal`: timeouts, frame and heartbeat stamps, waits between polls).
//!
//! Who is given a [`Clock`] reads no clock of its own, as a ros2_control hardware interface
//! is given its time in `read(time, period)` and CANopenNode's process functions are given
//! the elapsed time. Three clocks:
//! - [`MonotonicClock`], CLOCK_MONOTONIC from its own origin, the clock of every real run,
//! - [`ManualClock`], which moves only when told (a wait advances it at once), so that a
//!   test decides a timeout at an exact simulated time,
//! - [`ScriptedClock`], a manual clock with a thread CPU time of its own, late wake-ups and
//!   preemption, so that a test counts the wall-clock pacer's decisions (overruns, skipped
//!   deadlines) independently of how loaded the machine is.
//!
//! The control cycle's own time is not read from a clock: it is `Timebase::time_of(k)`.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// A monotonic time source (ns since the clock's own origin).
pub trait Clock: Send + Sync {
    /// The present time (ns since the clock's own origin; never decreases).
    fn now_ns(&self) -> u64;

    /// Let `d` pass (a blocking wait between two polls of a device).
    fn sleep(&self, d: Duration);

    /// Sleep until the absolute time `t_ns` (ns, same clock as [`Clock::now_ns`]); returns
    /// at once if it has passed.
    fn sleep_until(&self, t_ns: u64) {
        let now = self.now_ns();
        if t_ns > now {
            self.sleep(Duration::from_nanos(t_ns - now));
        }
    }

    /// CPU time consumed by the calling thread so far (ns): it advances only while the
    /// thread runs, so a cycle's wall time minus its CPU time is the time it was preempted.
    /// A clock without threads of its own (the manual clock) reports its present time: its
    /// thread is never preempted.
    fn thread_cpu_ns(&self) -> u64 {
        self.now_ns()
    }
}

/// Current time of `clock` (ns): CLOCK_MONOTONIC or CLOCK_THREAD_CPUTIME_ID.
#[inline]
fn clock_ns(clock: libc::clockid_t) -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: ts is a valid, writable timespec; both clocks always exist on Linux.
    unsafe { libc::clock_gettime(clock, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// CLOCK_MONOTONIC (the clock `std::time::Instant` reads on Linux), counted from the
/// moment the clock was made; absolute waits with `clock_nanosleep(TIMER_ABSTIME)`.
#[derive(Debug, Clone, Copy)]
pub struct MonotonicClock {
    /// CLOCK_MONOTONIC at construction (ns).
    origin: u64,
}

impl MonotonicClock {
    /// A clock whose origin is now.
    pub fn new() -> MonotonicClock {
        MonotonicClock {
            origin: clock_ns(libc::CLOCK_MONOTONIC),
        }
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for MonotonicClock {
    #[inline]
    fn now_ns(&self) -> u64 {
        clock_ns(libc::CLOCK_MONOTONIC) - self.origin
    }

    fn sleep(&self, d: Duration) {
        std::thread::sleep(d);
    }

    /// Absolute sleep on CLOCK_MONOTONIC (retried on EINTR, so a signal handler that only
    /// sets a flag does not shorten the wait).
    #[inline]
    fn sleep_until(&self, t_ns: u64) {
        let t_ns = t_ns.saturating_add(self.origin);
        let ts = libc::timespec {
            tv_sec: (t_ns / 1_000_000_000) as libc::time_t,
            tv_nsec: (t_ns % 1_000_000_000) as libc::c_long,
        };
        loop {
            // SAFETY: ts is a valid timespec; the remainder pointer may be null with
            // TIMER_ABSTIME.
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

    #[inline]
    fn thread_cpu_ns(&self) -> u64 {
        clock_ns(libc::CLOCK_THREAD_CPUTIME_ID)
    }
}

/// A clock that moves only by [`ManualClock::advance`], [`ManualClock::set`] or a wait
/// ([`Clock::sleep`], [`Clock::sleep_until`], which advance it at once): simulated time for
/// tests.
#[derive(Debug, Default)]
pub struct ManualClock {
    ns: AtomicU64,
}

impl ManualClock {
    /// A clock at `ns` (ns).
    pub fn at(ns: u64) -> ManualClock {
        ManualClock {
            ns: AtomicU64::new(ns),
        }
    }

    /// Move the clock forward by `d`.
    pub fn advance(&self, d: Duration) {
        let d = d.as_nanos().min(u128::from(u64::MAX)) as u64;
        self.ns.fetch_add(d, Ordering::SeqCst);
    }

    /// Move the clock to `ns` (ns); a time before the present one is ignored (monotonic).
    pub fn set(&self, ns: u64) {
        self.ns.fetch_max(ns, Ordering::SeqCst);
    }
}

impl Clock for ManualClock {
    fn now_ns(&self) -> u64 {
        self.ns.load(Ordering::SeqCst)
    }
    fn sleep(&self, d: Duration) {
        self.advance(d);
    }
    fn sleep_until(&self, t_ns: u64) {
        self.set(t_ns);
    }
}

/// A manual clock with a thread CPU time of its own, for tests of a pacer: the test says
/// how long each cycle works ([`ScriptedClock::work`]: wall and CPU time), how long its
/// thread is preempted ([`ScriptedClock::preempted`]: wall time only) and how late every
/// wake-up is ([`ScriptedClock::set_late_by`]); it counts the waits.
#[derive(Debug, Default)]
pub struct ScriptedClock {
    now: AtomicU64,
    cpu: AtomicU64,
    sleeps: AtomicU64,
    late_by: AtomicU64,
}

impl ScriptedClock {
    /// A clock at `ns` (ns), its thread CPU time at 0.
    pub fn at(ns: u64) -> ScriptedClock {
        ScriptedClock {
            now: AtomicU64::new(ns),
            ..ScriptedClock::default()
        }
    }

    /// The cycle's work takes `ns` of wall and CPU time.
    pub fn work(&self, ns: u64) {
        self.now.fetch_add(ns, Ordering::SeqCst);
        self.cpu.fetch_add(ns, Ordering::SeqCst);
    }

    /// The thread is preempted for `ns` (wall time passes, CPU time does not).
    pub fn preempted(&self, ns: u64) {
        self.now.fetch_add(ns, Ordering::SeqCst);
    }

    /// The thread CPU clock jumps `ns` ahead of the wall clock (a migration to a core whose
    /// scheduler clock is ahead).
    pub fn cpu_clock_skew(&self, ns: u64) {
        self.cpu.fetch_add(ns, Ordering::SeqCst);
    }

    /// Every following wake-up comes `ns` after its deadline.
    pub fn set_late_by(&self, ns: u64) {
        self.late_by.store(ns, Ordering::SeqCst);
    }

    /// Waits so far ([`Clock::sleep`] and [`Clock::sleep_until`]).
    pub fn sleeps(&self) -> u64 {
        self.sleeps.load(Ordering::SeqCst)
    }
}

impl Clock for ScriptedClock {
    fn now_ns(&self) -> u64 {
        self.now.load(Ordering::SeqCst)
    }
    fn sleep(&self, d: Duration) {
        let d = d.as_nanos().min(u128::from(u64::MAX)) as u64;
        self.sleep_until(self.now_ns().saturating_add(d));
    }
    fn sleep_until(&self, t_ns: u64) {
        self.sleeps.fetch_add(1, Ordering::SeqCst);
        let late = self.late_by.load(Ordering::SeqCst);
        let now = self.now.load(Ordering::SeqCst);
        self.now.store(now.max(t_ns) + late, Ordering::SeqCst);
    }
    fn thread_cpu_ns(&self) -> u64 {
        self.cpu.load(Ordering::SeqCst)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_manual_clock_moves_only_forward_and_only_when_told() {
        let c = ManualClock::at(1_000);
        assert_eq!(c.now_ns(), 1_000);
        c.advance(Duration::from_micros(2));
        assert_eq!(c.now_ns(), 3_000);
        c.sleep(Duration::from_nanos(5));
        assert_eq!(c.now_ns(), 3_005);
        c.set(10);
        assert_eq!(c.now_ns(), 3_005);
        c.set(4_000);
        assert_eq!(c.now_ns(), 4_000);
        c.sleep_until(5_000);
        assert_eq!(c.now_ns(), 5_000);
        assert_eq!(c.thread_cpu_ns(), 5_000);
    }

    #[test]
    fn the_monotonic_clock_starts_near_zero_and_does_not_go_back() {
        let c = MonotonicClock::new();
        let a = c.now_ns();
        c.sleep(Duration::from_millis(2));
        let b = c.now_ns();
        assert!(a < 1_000_000_000 && b >= a + 2_000_000, "{a} {b}");
        c.sleep_until(b + 1_000_000);
        assert!(c.now_ns() >= b + 1_000_000);
    }

    #[test]
    fn the_scripted_clock_separates_work_preemption_and_late_wakeups() {
        let c = ScriptedClock::at(100);
        c.work(10);
        c.preempted(5);
        assert_eq!((c.now_ns(), c.thread_cpu_ns()), (115, 10));
        c.set_late_by(3);
        c.sleep_until(200);
        assert_eq!((c.now_ns(), c.sleeps()), (203, 1));
        c.sleep_until(0); // passed: only the lateness
        assert_eq!((c.now_ns(), c.sleeps()), (206, 2));
    }
}
