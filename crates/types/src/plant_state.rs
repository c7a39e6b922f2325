//! The simulated plant's complete state, as crates/plant/src/model.rs computes it and the
//! logger writes it (`/plant` channel).

/// Complete plant state (SI units), logged every cycle.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PlantState {
    /// Simulated time (s).
    pub t: f64,
    /// Command reaching the valve after any delay (V).
    pub command: f64,
    /// Spool position (fraction of full travel).
    pub spool: f64,
    /// Spool velocity (1/s).
    pub spool_velocity: f64,
    /// Chamber A pressure (Pa).
    pub p_a: f64,
    /// Chamber B pressure (Pa).
    pub p_b: f64,
    /// Supply pressure at the valve (Pa).
    pub p_s: f64,
    /// Piston position (m).
    pub x: f64,
    /// Piston velocity (m/s).
    pub v: f64,
    /// Load mass position (m) (equal to x without a flexible mount).
    pub x_load: f64,
    /// Load mass velocity (m/s).
    pub v_load: f64,
    /// Net valve flow into port A (m³/s).
    pub q_a: f64,
    /// Net valve flow into port B (m³/s).
    pub q_b: f64,
    /// Friction force on the piston (N), opposing motion.
    pub friction: f64,
    /// External excitation force (N).
    pub external: f64,
    /// Rod force seen by a load cell (N).
    pub rod_force: f64,
    /// Whether the piston is stuck by static friction.
    pub stuck: bool,
}
