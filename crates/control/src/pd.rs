//! Discrete PD position controller, 003 eq. 32: u_k = K_P·[e_k + (T_D/T_p)·(e_k − e_{k−1})],
//! with a first-order derivative filter T_f = T_D/N (N → ∞ gives eq. 32 exactly) and an
//! optional velocity feed-forward. Pure step function: no I/O, no clock, no allocation.

use crate::pi::ControlTerms;

/// PD gains and limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PdGains {
    /// Proportional gain K_P (V/m).
    pub kp: f64,
    /// Derivative time T_D (s).
    pub td: f64,
    /// Derivative filter ratio N (-): T_f = T_D/N; 0 = no filter.
    pub filter_n: f64,
    /// Output limit (V), symmetric.
    pub u_max: f64,
    /// Velocity feed-forward (V per m/s of setpoint rate).
    pub feedforward_velocity: f64,
}

/// PD controller state.
#[derive(Debug, Clone)]
pub struct Pd {
    /// Gains (may be swapped between cycles).
    pub gains: PdGains,
    e_prev: Option<f64>,
    d: f64,
}

impl Pd {
    /// New controller.
    pub fn new(gains: PdGains) -> Self {
        Self {
            gains,
            e_prev: None,
            d: 0.0,
        }
    }

    /// One control step (setpoint and feedback in m, rate in m/s, dt in s).
    #[inline]
    pub fn step(
        &mut self,
        setpoint: f64,
        setpoint_rate: f64,
        feedback: f64,
        dt: f64,
    ) -> ControlTerms {
        let g = &self.gains;
        let e = setpoint - feedback;
        let de = e - self.e_prev.unwrap_or(e);
        self.e_prev = Some(e);
        let tf = if g.filter_n > 0.0 {
            g.td / g.filter_n
        } else {
            0.0
        };
        self.d = (tf * self.d + g.kp * g.td * de) / (tf + dt);
        let p = g.kp * e;
        let ff = g.feedforward_velocity * setpoint_rate;
        let u_unsat = p + self.d + ff;
        ControlTerms {
            u: u_unsat.clamp(-g.u_max, g.u_max),
            u_unsat,
            error: e,
            p,
            i: 0.0,
            d: self.d,
            ff,
        }
    }
}
