//! Seal friction with a true stick phase (003 eq. 5, 004 eq. 28–34).
//!
//! Slip: F_f = (F_C + (F_s − F_C)·e^(−(|v|/v_s)²))·sign(v) (Stribeck; 003 eq. 5 writes the
//! decay as e^(−σ|v|), we use the Gaussian form of 004's static/Coulomb split), viscous
//! friction is handled with the mechanical damping. Stick is solved as a velocity
//! projection (Moreau time stepping): when the force needed to hold v = 0 over the substep
//! is at most F_s the piston stays exactly at rest, so there is no chatter and no drift.

use crate::params::Friction;

/// Friction law with stick state.
#[derive(Debug, Clone)]
pub struct FrictionModel {
    fs: f64,
    fc: f64,
    vs: f64,
    /// Variant `load_coulomb`: F = F_C·tanh(v/v_s), no stick.
    smooth: bool,
}

impl FrictionModel {
    /// From the config section.
    pub fn new(p: &Friction) -> Self {
        Self {
            fs: p.static_force.max(p.coulomb_force),
            fc: p.coulomb_force,
            vs: p.stribeck_velocity,
            smooth: p.variant == crate::params::FrictionVariant::LoadCoulomb,
        }
    }

    /// Slip friction magnitude at speed |v| (N).
    #[inline]
    pub fn slip_force(&self, speed: f64) -> f64 {
        let r = speed / self.vs;
        self.fc + (self.fs - self.fc) * (-r * r).exp()
    }

    /// Apply friction to the friction-free velocity `v_free` (m/s) reached from `v_old`.
    /// `m_eff` (kg) is the mass including the implicit damping term (m + h·c) and `h` the
    /// substep (s). Returns (new velocity, friction force on the body opposing motion, stuck).
    #[inline]
    pub fn project(&self, v_old: f64, v_free: f64, m_eff: f64, h: f64) -> (f64, f64, bool) {
        if self.smooth {
            // F = F_C·tanh(v/v_s), linearly implicit about v_old (stable for any slope).
            let th = (v_old / self.vs).tanh();
            let f0 = self.fc * th;
            let df = self.fc / self.vs * (1.0 - th * th);
            let v_new = (m_eff * v_free - h * (f0 - df * v_old)) / (m_eff + h * df);
            return (v_new, f0 + df * (v_new - v_old), false);
        }
        let crossing = v_old == 0.0 || v_free == 0.0 || (v_old > 0.0) != (v_free > 0.0);
        if crossing {
            let f_hold = m_eff * v_free / h;
            if f_hold.abs() <= self.fs {
                return (0.0, f_hold, true);
            }
            let f = self.fs.copysign(v_free);
            return (v_free - h * f / m_eff, f, false);
        }
        let f = self.slip_force(v_old.abs()).copysign(v_old);
        let v_new = v_free - h * f / m_eff;
        if (v_new > 0.0) != (v_old > 0.0) {
            // Friction would reverse the motion: it stops the body instead.
            (0.0, m_eff * v_free / h, true)
        } else {
            (v_new, f, false)
        }
    }
}
