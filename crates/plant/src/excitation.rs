//! External force: constant, harmonic F₀ + F_A sin(2π f_e t) (003 eq. 2), impact train (003 eq. 17).

use crate::params::{Excitation, ExcitationKind};
use std::f64::consts::{PI, TAU};

/// External force source; the force opposes +x (a load pushing back on the rod).
#[derive(Debug, Clone)]
pub struct ExcitationModel {
    p: Excitation,
}

impl ExcitationModel {
    /// From the config section.
    pub fn new(p: &Excitation) -> Self {
        Self { p: p.clone() }
    }

    /// Force at time `t` (s), in N.
    #[inline]
    pub fn force(&self, t: f64) -> f64 {
        let p = &self.p;
        if matches!(p.kind, ExcitationKind::None) {
            return 0.0;
        }
        if t < p.start_time {
            return p.offset;
        }
        let tau = t - p.start_time;
        match p.kind {
            ExcitationKind::None => 0.0,
            ExcitationKind::Constant => p.offset,
            ExcitationKind::Harmonic => p.offset + p.amplitude * (TAU * p.frequency * tau).sin(),
            ExcitationKind::Impact => {
                let period = 60.0 / p.blows_per_minute.max(1e-9);
                let phase = tau % period;
                let width = p.pulse_duration.min(period);
                if width > 0.0 && phase < width {
                    p.offset + p.amplitude * (PI * phase / width).sin()
                } else {
                    p.offset
                }
            }
        }
    }
}
