//! Discrete PI force controller in the ideal form u = K_P·(e + I·∫e dt) (004 §6: K_P 0.57,
//! I 386.24 s⁻¹ on load-cell volts at 5 kHz; discrete K_i = K_P·T_s·I).
//!
//! Pure step function: no I/O, no clock, no allocation.

/// PI gains and limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PiGains {
    /// Proportional gain K_P (V per V of error).
    pub kp: f64,
    /// Integral rate I = 1/T_i (1/s).
    pub integral: f64,
    /// Error scale g (V per unit of the controlled variable, e.g. load-cell V/N).
    pub error_scale: f64,
    /// Lower output limit (V).
    pub u_min: f64,
    /// Upper output limit (V).
    pub u_max: f64,
    /// Back-calculation tracking gain (1/s); 0 = conditional integration (clamping).
    pub tracking: f64,
    /// Feed-forward gain on the setpoint (V per unit).
    pub feedforward: f64,
}

/// Per-cycle output with the terms for logging.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ControlTerms {
    /// Command after limits (V).
    pub u: f64,
    /// Command before limits (V).
    pub u_unsat: f64,
    /// Error in the controlled variable's unit (setpoint − feedback).
    pub error: f64,
    /// Proportional term (V).
    pub p: f64,
    /// Integral term (V).
    pub i: f64,
    /// Derivative term (V).
    pub d: f64,
    /// Feed-forward term (V).
    pub ff: f64,
}

/// PI controller state.
#[derive(Debug, Clone)]
pub struct Pi {
    /// Gains (may be swapped between cycles).
    pub gains: PiGains,
    integ: f64,
}

impl Pi {
    /// New controller with zero integrator.
    pub fn new(gains: PiGains) -> Self {
        Self { gains, integ: 0.0 }
    }

    /// Reset the integrator.
    pub fn reset(&mut self) {
        self.integ = 0.0;
    }

    /// One control step: `setpoint` and `feedback` in the controlled unit, `dt` in s.
    #[inline]
    pub fn step(&mut self, setpoint: f64, feedback: f64, dt: f64) -> ControlTerms {
        let g = &self.gains;
        let e = setpoint - feedback;
        let ev = g.error_scale * e;
        let p = g.kp * ev;
        let ff = g.feedforward * setpoint;
        // Backward-Euler integral: includes the current error.
        let di = g.kp * g.integral * dt * ev;
        let trial = self.integ + di;
        let u_trial = p + trial + ff;
        let u_sat = u_trial.clamp(g.u_min, g.u_max);
        if g.tracking > 0.0 {
            self.integ = trial + g.tracking * dt * (u_sat - u_trial);
        } else if u_trial == u_sat
            || (u_trial > g.u_max && di < 0.0)
            || (u_trial < g.u_min && di > 0.0)
        {
            self.integ = trial;
        }
        let u_unsat = p + self.integ + ff;
        ControlTerms {
            u: u_unsat.clamp(g.u_min, g.u_max),
            u_unsat,
            error: e,
            p,
            i: self.integ,
            d: 0.0,
            ff,
        }
    }
}
