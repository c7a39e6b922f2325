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

impl Default for Measurements {
    fn default() -> Self {
        Self {
            t: 0.0,
            force: f64::NAN,
            position: f64::NAN,
            p_a: f64::NAN,
            p_b: f64::NAN,
            spool: f64::NAN,
        }
    }
}
