//! What a backend reads once per cycle: one sample of every sensor (the simulated sensors
//! of crates/plant/src/sensors.rs or the CANopen devices).

/// One sample of every sensor, in SI units. A channel a backend lacks is NaN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurements {
    /// Sample time (s).
    pub t: f64,
    /// Rod / load-cell force (N).
    pub force: f64,
    /// Piston position (m).
    pub position: f64,
    /// Chamber A pressure (Pa).
    pub p_a: f64,
    /// Chamber B pressure (Pa).
    pub p_b: f64,
    /// Spool position (fraction of full travel).
    pub spool: f64,
}

impl Measurements {
    /// Nothing measured yet, the sample time included: every field NaN (a backend's held
    /// sample before its first reading, e.g. the CANopen backend before its priming SYNC).
    pub const UNMEASURED: Measurements = Measurements {
        t: f64::NAN,
        force: f64::NAN,
        position: f64::NAN,
        p_a: f64::NAN,
        p_b: f64::NAN,
        spool: f64::NAN,
    };
}

/// Every channel NaN ([`Measurements::UNMEASURED`]) at sample time 0 s.
impl Default for Measurements {
    fn default() -> Self {
        Self {
            t: 0.0,
            ..Self::UNMEASURED
        }
    }
}
