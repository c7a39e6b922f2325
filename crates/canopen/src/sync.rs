//! SYNC producer (CiA 301 §7.2.5): an empty frame on 0x080 every communication cycle
//! period. Time is injected: [`SyncProducer::process`] takes the elapsed time, so the
//! producer is exact in simulated time and testable (CANopenNode style).

use crate::frame::CanFrame;

/// COB-ID of SYNC.
pub const SYNC_COB_ID: u16 = 0x080;

/// The SYNC frame (no data, CiA 301 without counter).
#[inline]
pub fn frame() -> CanFrame {
    CanFrame::std(SYNC_COB_ID, [])
}

/// SYNC with the counter of CiA 301 §7.2.5.2.1 when `overflow` (0x1019) is 2..240: the
/// `k`-th SYNC (k = 1, 2, ...) carries 1 + (k − 1) mod overflow; `overflow` 0: no data.
#[inline]
pub fn frame_with_counter(overflow: u8, k: u64) -> CanFrame {
    if overflow == 0 {
        frame()
    } else {
        CanFrame::std(
            SYNC_COB_ID,
            [(1 + (k.saturating_sub(1)) % u64::from(overflow)) as u8],
        )
    }
}

/// Decides when to send SYNC. Integer nanoseconds: no drift over long runs.
#[derive(Debug, Clone)]
pub struct SyncProducer {
    period_ns: u64,
    timer_ns: u64,
    count: u64,
    /// SYNC counter overflow value (0x1019; 0 = SYNC without counter).
    overflow: u8,
    /// SYNCs sent before this producer (the start-up's priming SYNC), for the counter.
    before: u64,
}

impl SyncProducer {
    /// Producer with communication cycle period `period_s` (s); the first SYNC is due at once.
    pub fn new(period_s: f64) -> SyncProducer {
        let period_ns = (period_s * 1e9).round().max(1.0) as u64;
        SyncProducer {
            period_ns,
            timer_ns: period_ns,
            count: 0,
            overflow: 0,
            before: 0,
        }
    }

    /// With the SYNC counter (`overflow` 2..240, 0 = none), `before` SYNCs already sent.
    pub fn with_counter(period_s: f64, overflow: u8, before: u64) -> SyncProducer {
        SyncProducer {
            overflow,
            before,
            ..SyncProducer::new(period_s)
        }
    }

    /// The frame of the SYNC just produced (with its counter, if configured).
    #[inline]
    pub fn frame(&self) -> CanFrame {
        frame_with_counter(self.overflow, self.before + self.count)
    }

    /// Advance by `elapsed_ns` (ns); true if a SYNC is due now. At most one SYNC per
    /// call: if the caller is late, the missed SYNCs are not sent in a burst.
    #[inline]
    pub fn process(&mut self, elapsed_ns: u64) -> bool {
        self.timer_ns = self.timer_ns.saturating_add(elapsed_ns);
        if self.timer_ns >= self.period_ns {
            self.timer_ns = (self.timer_ns - self.period_ns).min(self.period_ns - 1);
            self.count += 1;
            true
        } else {
            false
        }
    }

    /// SYNCs produced so far.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// Period (ns).
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_sync_every_fifth_cycle_at_5khz_over_1khz() {
        let mut s = SyncProducer::new(1e-3);
        let due: Vec<bool> = (0..20)
            .map(|k| s.process(if k == 0 { 0 } else { 200_000 }))
            .collect();
        let idx: Vec<usize> = due
            .iter()
            .enumerate()
            .filter(|(_, d)| **d)
            .map(|(i, _)| i)
            .collect();
        assert_eq!(idx, vec![0, 5, 10, 15]);
        assert_eq!(frame().payload().len(), 0);
        assert_eq!(frame().id, 0x080);
    }

    #[test]
    fn no_drift_with_non_divisor_rates_and_no_bursts_when_late() {
        // 3 kHz cycle, 1 kHz SYNC: 333_333 ns steps; over 3 s exactly 3000 (±1) SYNCs.
        let mut s = SyncProducer::new(1e-3);
        let mut n = 0;
        for _ in 0..9000 {
            n += s.process(333_333) as u32;
        }
        assert!((2999..=3000).contains(&n), "{n}");
        // A 10 ms stall yields one SYNC, not ten.
        let mut s = SyncProducer::new(1e-3);
        assert!(s.process(10_000_000));
        assert!(!s.process(0));
    }

    #[test]
    fn the_counter_runs_1_to_overflow() {
        // CiA 301 7.2.5.2.1: counter 1..0x1019, then 1 again; none when 0x1019 = 0.
        let mut s = SyncProducer::with_counter(1e-3, 3, 1); // the priming SYNC had 1
        let c: Vec<u8> = (0..5)
            .map(|_| {
                assert!(s.process(1_000_000));
                s.frame().data[0]
            })
            .collect();
        assert_eq!(c, vec![2, 3, 1, 2, 3]);
        assert_eq!(frame_with_counter(3, 1).payload(), &[1]);
        assert_eq!(frame_with_counter(0, 7).payload().len(), 0);
    }
}
