//! The time source of the start-up and of the backend's I/O side, given by the caller.
//!
//! The CiA 301 services of this crate ([`crate::sdo`], [`crate::heartbeat`],
//! [`crate::sync`]) take the elapsed or present time as an argument (CANopenNode's process
//! functions that take the elapsed time); the start-up ([`crate::startup`]) and the backend
//! ([`crate::hal`]) read it from the [`Clock`] they are given, as a ros2_control hardware
//! interface is given its time in `read(time, period)`. Every timeout of the start-up (boot-up
//! wait and SDO probes, SDO transfers, NMT and valve state waits, priming), ehactl's own
//! heartbeat and the receive stamps the heartbeat consumers compare against the present time
//! come from this one clock. [`MonotonicClock`] is the clock of a real run; [`ManualClock`]
//! moves only when told, so that a test decides a timeout at an exact simulated time.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// A monotonic time source.
pub trait Clock: Send + Sync {
    /// The present time (ns since the clock's own origin; never decreases).
    fn now_ns(&self) -> u64;
    /// Let `d` pass (a blocking wait between two polls of a device).
    fn sleep(&self, d: Duration);
}

/// The operating system's monotonic clock (`std::time::Instant`).
#[derive(Debug, Clone, Copy)]
pub struct MonotonicClock {
    origin: Instant,
}

impl MonotonicClock {
    /// A clock whose origin is now.
    pub fn new() -> MonotonicClock {
        MonotonicClock {
            origin: Instant::now(),
        }
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for MonotonicClock {
    fn now_ns(&self) -> u64 {
        // u64 ns covers 584 years of uptime
        self.origin.elapsed().as_nanos().min(u128::from(u64::MAX)) as u64
    }
    fn sleep(&self, d: Duration) {
        std::thread::sleep(d);
    }
}

/// A clock that moves only by [`ManualClock::advance`], [`ManualClock::set`] or
/// [`Clock::sleep`] (which advances it at once): simulated time for tests.
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
    }

    #[test]
    fn the_monotonic_clock_starts_near_zero_and_does_not_go_back() {
        let c = MonotonicClock::new();
        let a = c.now_ns();
        c.sleep(Duration::from_millis(2));
        let b = c.now_ns();
        assert!(a < 1_000_000_000 && b >= a + 2_000_000, "{a} {b}");
    }
}
