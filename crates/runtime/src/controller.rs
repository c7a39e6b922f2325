//! [`Controller`]: the control law the config selects (PI on force, PD on position, or
//! open loop), one pure `step` per cycle. Used by the run loop ([`crate::runloop`]) and by
//! the live parameter hand-over ([`crate::live`]), which writes new gains into it.

use ehactl_config::{ControlMode, RigConfig};
use ehactl_control::pd::Pd;
use ehactl_control::pi::{ControlTerms, Pi};
use ehactl_control::supervisor::FeedbackChannel;
use ehactl_hal::Measurements;

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
    /// From a validated config.
    pub fn from_config(cfg: &RigConfig) -> Controller {
        match cfg.control.mode {
            ControlMode::Force => Controller::Force(Pi::new(cfg.pi_gains().expect("validated"))),
            ControlMode::Position => {
                Controller::Position(Pd::new(cfg.pd_gains().expect("validated")))
            }
            ControlMode::OpenLoop => Controller::OpenLoop,
        }
    }

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
