//! Imposed motion: the rod's position is prescribed (a displacement-controlled test of a damper
//! or a specimen, where the record holds the motion and the load-cell force but no valve
//! command), so the hydraulics drop out and the model's prediction is the rod force the load
//! cell sees at that motion: the load spring K_L·(x − x_c) of `[mechanics]` and the rod-force
//! law of `[effects.polynomial_force]` ([`PolynomialForce`]), the same terms and the same Dahl
//! state update as [`crate::Plant`] uses (one owner: [`PolynomialForce::rod_force`],
//! [`PolynomialForce::dahl_advance`]).
//!
//! Only a rigid rod is modelled: with `[effects.flexible_mount]` the load cell sees a mount
//! whose load-mass motion is not prescribed, and an `[excitation]` force is not in a record,
//! so both are refused with a clear error rather than left out silently.

use crate::effects::PolynomialForce;
use crate::PlantParams;

/// One term of the rod-force law, by its field in `[effects.polynomial_force]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum LawTerm {
    /// F₀ (N).
    Constant,
    /// c_v·v (N·s/m).
    Viscous,
    /// F_c·tanh(v/v_s) (N).
    Coulomb,
    /// c_q·|v|·v (N·s²/m²).
    Quadratic,
    /// k·(x − x₀) (N/m).
    Stiffness,
    /// A_p·(p_a − p_b) (m²).
    Pressure,
    /// A_c·tanh(v/v_s)·|p_a − p_b| (m²).
    PressureCoulomb,
    /// F_d·z, Dahl (N).
    Dahl,
}

impl LawTerm {
    /// Every term, in the order of the section's fields.
    pub const ALL: [LawTerm; 8] = [
        LawTerm::Constant,
        LawTerm::Viscous,
        LawTerm::Coulomb,
        LawTerm::Quadratic,
        LawTerm::Stiffness,
        LawTerm::Pressure,
        LawTerm::PressureCoulomb,
        LawTerm::Dahl,
    ];

    /// The field of `[effects.polynomial_force]` holding the coefficient.
    pub fn field(self) -> &'static str {
        match self {
            LawTerm::Constant => "constant",
            LawTerm::Viscous => "viscous",
            LawTerm::Coulomb => "coulomb",
            LawTerm::Quadratic => "quadratic",
            LawTerm::Stiffness => "stiffness",
            LawTerm::Pressure => "pressure",
            LawTerm::PressureCoulomb => "pressure_coulomb",
            LawTerm::Dahl => "dahl",
        }
    }

    /// Whether the term needs the chamber pressures.
    pub fn needs_pressure(self) -> bool {
        matches!(self, LawTerm::Pressure | LawTerm::PressureCoulomb)
    }

    /// The coefficient of this term in `law`.
    pub fn coefficient(self, law: &PolynomialForce) -> f64 {
        match self {
            LawTerm::Constant => law.constant,
            LawTerm::Viscous => law.viscous,
            LawTerm::Coulomb => law.coulomb,
            LawTerm::Quadratic => law.quadratic,
            LawTerm::Stiffness => law.stiffness,
            LawTerm::Pressure => law.pressure,
            LawTerm::PressureCoulomb => law.pressure_coulomb,
            LawTerm::Dahl => law.dahl,
        }
    }

    /// `law` with this term's coefficient set to `c`.
    pub fn with(self, mut law: PolynomialForce, c: f64) -> PolynomialForce {
        *match self {
            LawTerm::Constant => &mut law.constant,
            LawTerm::Viscous => &mut law.viscous,
            LawTerm::Coulomb => &mut law.coulomb,
            LawTerm::Quadratic => &mut law.quadratic,
            LawTerm::Stiffness => &mut law.stiffness,
            LawTerm::Pressure => &mut law.pressure,
            LawTerm::PressureCoulomb => &mut law.pressure_coulomb,
            LawTerm::Dahl => &mut law.dahl,
        } = c;
        law
    }
}

/// A prescribed motion of the rod: samples of position x (m), velocity v (m/s) and, where
/// measured, the load pressure p_a − p_b (Pa), at period `dt` (s).
#[derive(Debug, Clone, Copy)]
pub struct Motion<'a> {
    /// Sample period (s).
    pub dt: f64,
    /// Piston position (m).
    pub x: &'a [f64],
    /// Piston velocity (m/s), same length.
    pub v: &'a [f64],
    /// Load pressure p_a − p_b (Pa), if measured.
    pub dp: Option<&'a [f64]>,
}

/// Largest step of the Dahl state as a fraction of its pre-yield travel δ: the backward-Euler
/// update stays in [−1, 1] at any step, but is accurate only while (|v| + V)·h ≪ δ (V the
/// series-dashpot velocity), so a sample is split into substeps (velocity interpolated
/// linearly) until (|v| + V)·h ≤ 0.1·δ (at most 256).
const DAHL_STEP_FRACTION: f64 = 0.1;

/// Dahl state z (-) along the motion for the law's pre-yield travel, starting from z = 0
/// (the value at sample k is the state before the step to k + 1, as the plant logs it).
pub fn dahl_state(law: &PolynomialForce, m: &Motion<'_>) -> Vec<f64> {
    let unit = PolynomialForce { dahl: 1.0, ..*law };
    let delta = law.dahl_travel.max(1e-12);
    let mut z = 0.0;
    let mut out = Vec::with_capacity(m.v.len());
    for k in 0..m.v.len() {
        out.push(z);
        let Some(&v1) = m.v.get(k + 1) else { break };
        let v0 = m.v[k];
        let need = (m.dt * (v0.abs().max(v1.abs()) + law.dahl_velocity.max(0.0))
            / (DAHL_STEP_FRACTION * delta))
            .ceil();
        let n = need.clamp(1.0, 256.0) as usize;
        let h = m.dt / n as f64;
        for j in 0..n {
            let va = v0 + (v1 - v0) * j as f64 / n as f64;
            let vb = v0 + (v1 - v0) * (j + 1) as f64 / n as f64;
            z = unit.dahl_advance(z, va, vb, h);
        }
    }
    out
}

/// Force (N) of one law term per unit coefficient along the motion, with the law's shape
/// parameters (smoothing velocity, pre-yield travel, stiffness origin): the regressor of that
/// term in a least-squares fit. `None` when the term needs pressures the motion lacks.
pub fn term_series(term: LawTerm, law: &PolynomialForce, m: &Motion<'_>) -> Option<Vec<f64>> {
    if term.needs_pressure() && m.dp.is_none() {
        return None;
    }
    if term == LawTerm::Dahl {
        return Some(dahl_state(law, m));
    }
    let unit = term.with(
        PolynomialForce {
            constant: 0.0,
            viscous: 0.0,
            coulomb: 0.0,
            quadratic: 0.0,
            stiffness: 0.0,
            pressure: 0.0,
            pressure_coulomb: 0.0,
            dahl: 0.0,
            ..*law
        },
        1.0,
    );
    Some(
        (0..m.x.len())
            .map(|k| {
                let dp = m.dp.map_or(0.0, |d| d[k]);
                unit.rod_force(m.x[k], m.v[k], dp, 0.0, 0.0)
            })
            .collect(),
    )
}

/// The rod force of a rigid rod under prescribed motion.
#[derive(Debug, Clone)]
pub struct ImposedMotion {
    /// Load spring K_L (N/m) and its relaxed position x_c (m).
    k_load: f64,
    x_contact: f64,
    law: Option<PolynomialForce>,
}

impl ImposedMotion {
    /// From a plant config; refuses what a prescribed rod motion cannot predict.
    pub fn new(p: &PlantParams) -> Result<Self, String> {
        if p.effects.flexible_mount.as_ref().is_some_and(|m| m.enabled) {
            return Err("[effects.flexible_mount] is on: under imposed motion the load mass behind the mount moves on its own and is not in the record; predict the force of a rigid rod (switch the mount off) or replay the record closed loop".into());
        }
        if p.excitation.kind != crate::params::ExcitationKind::None {
            return Err("[excitation] applies an external force the record does not carry; an imposed-motion prediction of the load-cell force needs kind = \"none\"".into());
        }
        Ok(Self {
            k_load: p.mechanics.load_stiffness,
            x_contact: p.mechanics.load_contact_position,
            law: p.effects.polynomial_force.filter(|l| l.enabled),
        })
    }

    /// Load-cell force (N) along the motion.
    pub fn rod_forces(&self, m: &Motion<'_>) -> Result<Vec<f64>, String> {
        let mut f: Vec<f64> =
            m.x.iter()
                .map(|x| self.k_load * (x - self.x_contact))
                .collect();
        if let Some(law) = &self.law {
            for term in LawTerm::ALL {
                let c = term.coefficient(law);
                if c == 0.0 {
                    continue;
                }
                let s = term_series(term, law, m).ok_or_else(|| {
                    format!("the law's `{}` term needs the chamber pressures p_a and p_b, which the record does not carry", term.field())
                })?;
                for (fk, sk) in f.iter_mut().zip(s) {
                    *fk += c * sk;
                }
            }
        }
        Ok(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn law() -> PolynomialForce {
        PolynomialForce {
            constant: 12.0,
            viscous: 900.0,
            coulomb: 150.0,
            stiffness: 2.0e3,
            origin: 0.01,
            dahl: 300.0,
            dahl_travel: 2e-4,
            smoothing_velocity: 5e-3,
            ..PolynomialForce::zero()
        }
    }

    /// Σ coefficient × regressor equals the law's own rod force (stateless terms), so a linear
    /// fit on the regressors fits exactly what the plant evaluates.
    #[test]
    fn regressors_sum_to_the_law() {
        let dt = 1e-3;
        let x: Vec<f64> = (0..500).map(|k| 0.005 * (k as f64 * 0.02).sin()).collect();
        let v: Vec<f64> = (0..500).map(|k| 0.1 * (k as f64 * 0.02).cos()).collect();
        let m = Motion {
            dt,
            x: &x,
            v: &v,
            dp: None,
        };
        let l = law();
        let z = dahl_state(&l, &m);
        let sum: Vec<f64> = (0..x.len())
            .map(|k| {
                LawTerm::ALL
                    .iter()
                    .filter_map(|t| term_series(*t, &l, &m).map(|s| t.coefficient(&l) * s[k]))
                    .sum()
            })
            .collect();
        for k in 0..x.len() {
            let direct = l.rod_force(x[k], v[k], 0.0, 0.0, z[k]);
            assert!(
                (sum[k] - direct).abs() < 1e-9 * direct.abs().max(1.0),
                "{k}"
            );
        }
    }

    /// The Dahl state of a unit law of pre-yield travel `delta` (m) and Bouc–Wen exponent
    /// `exponent` along `n` samples of constant velocity `vel` (m/s) at period `dt` (s).
    fn state_at_constant_velocity(
        delta: f64,
        exponent: f64,
        vel: f64,
        dt: f64,
        n: usize,
    ) -> Vec<f64> {
        let x: Vec<f64> = (0..n).map(|k| vel * k as f64 * dt).collect();
        let v = vec![vel; n];
        let l = PolynomialForce {
            dahl: 1.0,
            dahl_travel: delta,
            dahl_exponent: exponent,
            ..PolynomialForce::zero()
        };
        dahl_state(
            &l,
            &Motion {
                dt,
                x: &x,
                v: &v,
                dp: None,
            },
        )
    }

    /// Dahl (1968) closed form: from z = 0 at constant velocity v > 0 the state follows
    /// z(s) = 1 − exp(−s/δ) over the travel s = v·t.
    #[test]
    fn dahl_state_follows_the_closed_form() {
        let (dt, delta, vel) = (1e-3, 1e-4, 0.02);
        let z = state_at_constant_velocity(delta, 1.0, vel, dt, 200);
        for (k, zk) in z.iter().enumerate().step_by(10) {
            let exact = 1.0 - (-(vel * k as f64 * dt) / delta).exp();
            assert!((zk - exact).abs() < 0.02, "k {k}: {zk} vs {exact}");
        }
    }

    /// With the series-dashpot velocity V the element is driven by r = v − V·z (Spencer et
    /// al. 1997's dashpot c₁ in series with the element): below V the state settles at
    /// z = a = v/V along dz/dt = (V/δ)·(a − z)·(1 − z), whose solution from z = 0 is
    /// z = a·(E − 1)/(E − a), E = exp((1 − a)·V·t/δ); above V it saturates at 1 as Dahl's
    /// law does.
    #[test]
    fn series_velocity_gives_the_bi_viscous_roll_off() {
        let (dt, delta, vd) = (1e-3, 1e-4, 0.02);
        let n = 400;
        for vel in [0.005, 0.05] {
            let x: Vec<f64> = (0..n).map(|k| vel * k as f64 * dt).collect();
            let v = vec![vel; n];
            let l = PolynomialForce {
                dahl: 1.0,
                dahl_travel: delta,
                dahl_velocity: vd,
                ..PolynomialForce::zero()
            };
            let m = Motion {
                dt,
                x: &x,
                v: &v,
                dp: None,
            };
            let z = dahl_state(&l, &m);
            let settled = if vel < vd { vel / vd } else { 1.0 };
            assert!((z[n - 1] - settled).abs() < 1e-3, "v {vel}: {}", z[n - 1]);
            if vel < vd {
                for (k, zk) in z.iter().enumerate().take(40) {
                    let e = ((1.0 - settled) * vd * k as f64 * dt / delta).exp();
                    let exact = settled * (e - 1.0) / (e - settled);
                    assert!((zk - exact).abs() < 0.01, "k {k}: {zk} vs {exact}");
                }
            }
        }
    }

    /// Bouc–Wen closed forms (Wen 1976) with A = β = 1, γ = 0: from z = 0 at constant v > 0,
    /// dz/ds = (1 − z^n)/δ gives z = tanh(s/δ) for n = 2; and the state saturates at 1 as
    /// Dahl's law does, later for the sharper knee (at s = δ: tanh 1 = 0.76 against
    /// 1 − e⁻¹ = 0.63 for n = 1).
    #[test]
    fn bouc_wen_exponent_two_follows_tanh() {
        let (dt, delta, vel, n) = (1e-3, 1e-4, 0.02, 200);
        let z = state_at_constant_velocity(delta, 2.0, vel, dt, n);
        let mut worst: f64 = 0.0;
        for (k, zk) in z.iter().enumerate() {
            let exact = (vel * k as f64 * dt / delta).tanh();
            worst = worst.max((zk - exact).abs());
        }
        assert!(worst < 0.02, "largest error {worst}");
        assert!((z[n - 1] - 1.0).abs() < 1e-3, "{}", z[n - 1]);
    }
}
