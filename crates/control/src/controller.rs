//! [`Controller`]: the control law a config selects (PI on force, PD on position, or
//! open loop), one pure `step` per cycle — the loop kernel shared by `ehactl run`'s cycle
//! (`ehactl_runtime::runloop`, whose live hand-over writes new gains into it) and the
//! diagnosis's closed-loop replay (`ehactl_ident::replay`), so both step the same law.
//! The config builds it (`ehactl_config::RigConfig::controller`).

use crate::pd::Pd;
use crate::pi::{ControlTerms, Pi};
use crate::supervisor::FeedbackChannel;
use ehactl_types::Measurements;

/// The configured control law.
#[derive(Debug, Clone)]
pub enum Controller {
    /// PI on force (N), error scaled to load-cell volts.
    Force(Pi),
    /// PD on position (m).
    Position(Pd),
    /// Setpoint passed straight to the valve (V).
    OpenLoop,
}

impl Controller {
    /// Feedback channel the law closes on.
    pub fn feedback_channel(&self) -> FeedbackChannel {
        match self {
            Controller::Position(_) => FeedbackChannel::Position,
            _ => FeedbackChannel::Force,
        }
    }

    /// The measured value the law feeds back.
    #[inline]
    pub fn feedback(&self, m: &Measurements) -> f64 {
        match self {
            Controller::Position(_) => m.position,
            _ => m.force,
        }
    }

    /// One step. Pure: no I/O, no allocation.
    #[inline]
    pub fn step(&mut self, setpoint: f64, rate: f64, m: &Measurements, dt: f64) -> ControlTerms {
        match self {
            Controller::Force(pi) => pi.step(setpoint, m.force, dt),
            Controller::Position(pd) => pd.step(setpoint, rate, m.position, dt),
            Controller::OpenLoop => ControlTerms {
                u: setpoint,
                u_unsat: setpoint,
                error: f64::NAN,
                ff: setpoint,
                ..Default::default()
            },
        }
    }
}
