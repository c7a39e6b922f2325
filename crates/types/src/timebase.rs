//! The control period: [`Timebase`], built once from the config's `run.control_rate_hz`
//! (`RigConfig::timebase()`, crates/config/src/lib.rs) and read by the plant, the pacer, the
//! run loop and the backends. Here, below all of them, so that the config reaches it
//! without compiling the hardware contract or the logger.

/// The control period, owned in one place. Built once from the config's
/// `run.control_rate_hz` and handed to the plant (its discretisation step), the pacer (its
/// deadline grid) and the backends (SYNC period, staleness limits); the time of cycle `k` is
/// `k · period` everywhere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timebase {
    rate_hz: f64,
    period_ns: u64,
}

impl Timebase {
    /// A timebase at a rate the caller has validated (the config loader checks
    /// `run.control_rate_hz` ∈ [1, 1e6] Hz). An unusable rate gives a non-finite or zero
    /// period, which `Plant::configure` and the pacer reject; nothing here panics.
    pub fn at_rate_hz(rate_hz: f64) -> Timebase {
        let period_ns = 1e9 / rate_hz;
        Timebase {
            rate_hz,
            period_ns: if period_ns.is_finite() && period_ns >= 1.0 {
                period_ns.round() as u64
            } else {
                1
            },
        }
    }

    /// Control rate (Hz).
    #[inline]
    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    /// Control period (s), `1 / rate_hz`.
    #[inline]
    pub fn period(&self) -> f64 {
        1.0 / self.rate_hz
    }

    /// Control period rounded to whole nanoseconds (ns), the wall-clock pacer's grid.
    #[inline]
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// Time of cycle `k` (s) on the control grid.
    #[inline]
    pub fn time_of(&self, k: u64) -> f64 {
        k as f64 * self.period()
    }

    /// Number of whole cycles in `duration` (s), rounded to the nearest cycle.
    #[inline]
    pub fn cycles_in(&self, duration: f64) -> u64 {
        (duration * self.rate_hz).round().max(0.0) as u64
    }

    /// Whether a measured period (s) is off the nominal one by more than `tolerance`
    /// (relative, -): used by backends to count late or early cycles.
    #[inline]
    pub fn is_off(&self, measured: f64, tolerance: f64) -> bool {
        (measured - self.period()).abs() > tolerance * self.period()
    }
}
