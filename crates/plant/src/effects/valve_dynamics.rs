//! `valve_dynamics`: spool dynamics, PT1 ż = (u − z)/T_z (003 eq. 1) or second order
//! ẍ = ω²(u − x) − 2ζω ẋ (004 eq. 1, 000): the config section [`ValveDynamics`]
//! (`[effects.valve_dynamics]`), its exact discretisation over a substep [`SpoolModel`] and
//! its component [`Spool`], the spool stage of the substep ([`SpoolStage`]).

use super::component::{Component, Setup, SpoolStage};
use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// `valve_dynamics`: spool dynamics, PT1 (003 eq. 1) or second order (004 eq. 1, 000).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveDynamics {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Order of the spool model: 1 (PT1) or 2.
    #[param(unit = "-", range = Within(1.0, 2.0), desc = "spool model order")]
    pub order: u8,
    /// PT1 time constant T_z (s) for order 1; 003: 0.01.
    #[serde(default)]
    #[param(unit = "s", range = NonNegative, desc = "PT1 time constant T_z (003)", uncertain(order = 13, to_range_end, role = loop_param, needs_order = 1))]
    pub time_constant: f64,
    /// Natural frequency ω_nv (rad/s) for order 2; 004: 1507.9.
    #[serde(default)]
    #[param(unit = "rad/s", range = Within(0.0, 1.0e6), desc = "spool ω_nv (004: 1507.9)", uncertain(order = 14, role = loop_param, needs_order = 2))]
    pub natural_frequency: f64,
    /// Damping ratio ζ (-) for order 2; 004: 0.59.
    #[serde(default)]
    #[param(unit = "-", range = NonNegative, desc = "spool damping ratio ζ (004: 0.59)")]
    pub damping_ratio: f64,
}

impl ValveDynamics {
    /// Check of the order and its bandwidth: order 1 with T_z ≥ 0 s (0: ideal spool), order 2 with
    /// ω_nv > 0 rad/s and ζ > 0.
    pub(crate) fn validate_order(&self) -> Result<(), ConfigError> {
        match self.order {
            // 0 is the ideal spool (the limit of the PT1 as T_z → 0, `SpoolModel::Ideal`): the
            // nominal value of a valve bandwidth the diagnosis refits from 0 up.
            1 if !(self.time_constant >= 0.0) => {
                return Err(ConfigError::new(
                    "effects.valve_dynamics.time_constant",
                    "must be ≥ 0 s for order = 1 (0: the spool follows the command at once)",
                ))
            }
            2 if self.natural_frequency <= 0.0 || self.damping_ratio <= 0.0 => {
                return Err(ConfigError::new(
                    "effects.valve_dynamics.natural_frequency",
                    "natural_frequency (rad/s) and damping_ratio (-) must be > 0 for order = 2",
                ))
            }
            1 | 2 => {}
            o => {
                return Err(ConfigError::new(
                    "effects.valve_dynamics.order",
                    format!("order {o} is not supported; expected 1 or 2"),
                ))
            }
        }
        Ok(())
    }
}

pub use discretisation::SpoolModel;

/// The exact discretisation of the spool, in a module of its own: the compiler then puts it
/// in a codegen unit apart from the rest of the effect, as it did when it was in
/// crates/plant/src/valve.rs; beside the component the `linear_exact` rigs' matrix
/// exponential came out 4 % slower per control cycle (BENCHMARKS.md, "An effect as a
/// component: `valve_dynamics`").
mod discretisation {
    use super::ValveDynamics;
    use crate::spec::ConfigError;
    use nalgebra::{Matrix2, Vector2};

    /// Spool dynamics discretised exactly for one substep (zero-order hold on the command).
    #[derive(Debug, Clone)]
    pub enum SpoolModel {
        /// Spool follows the command instantly.
        Ideal,
        /// PT1: ż = (u − z)/T_z (003 eq. 1).
        FirstOrder {
            /// e^(−h/T_z).
            decay: f64,
        },
        /// Second order: ẍ = ω²(u − x) − 2ζω ẋ (004 eq. 1); state transition over one substep.
        SecondOrder {
            /// Φ = e^(A h).
            phi: Matrix2<f64>,
            /// Γ = ∫₀ʰ e^(A τ) dτ · B.
            gamma: Vector2<f64>,
        },
    }

    impl SpoolModel {
        /// Build the discretisation of the section `s` (ideal when absent or switched off) for
        /// substep `h` (s). `Err` names the field when the second-order spool's ‖A·h‖₁ =
        /// h·max(ω², 1 + 2ζω) lies beyond [`crate::exact::EXPM_MAX_NORM`]
        /// ([`crate::exact::expm_checked`] refuses it).
        pub fn new(s: Option<&ValveDynamics>, h: f64) -> Result<Self, ConfigError> {
            let d = match s.filter(|d| d.enabled) {
                None => return Ok(SpoolModel::Ideal),
                Some(d) => d,
            };
            if d.order == 1 {
                return Ok(if d.time_constant <= 0.0 {
                    SpoolModel::Ideal
                } else {
                    SpoolModel::FirstOrder {
                        decay: (-h / d.time_constant).exp(),
                    }
                });
            }
            let (w, z) = (d.natural_frequency, d.damping_ratio);
            if w <= 0.0 {
                return Ok(SpoolModel::Ideal);
            }
            let a = Matrix2::new(0.0, 1.0, -w * w, -2.0 * z * w);
            let b = Vector2::new(0.0, w * w);
            // Augmented-matrix exponential gives Φ and Γ together (Van Loan).
            let mut m = nalgebra::Matrix3::<f64>::zeros();
            m.fixed_view_mut::<2, 2>(0, 0).copy_from(&(a * h));
            m.fixed_view_mut::<2, 1>(0, 2).copy_from(&(b * h));
            match crate::exact::expm_checked(&m) {
                Some(e) => Ok(SpoolModel::SecondOrder {
                    phi: e.fixed_view::<2, 2>(0, 0).into_owned(),
                    gamma: e.fixed_view::<2, 1>(0, 2).into_owned(),
                }),
                None => Err(ConfigError::new(
                    "effects.valve_dynamics.damping_ratio",
                    format!(
                        "spool ω = {w:e} rad/s with ζ = {z:e} gives ‖A·h‖₁ beyond {:e} at h = {h:e} s; expected a spool damping ratio of order 0.1–10 and ω below 10⁶ rad/s",
                        crate::exact::EXPM_MAX_NORM
                    ),
                )),
            }
        }

        /// Advance spool position `s` and velocity `sd` towards target `u` over one substep.
        #[inline]
        pub fn advance(&self, s: &mut f64, sd: &mut f64, u: f64) {
            match self {
                SpoolModel::Ideal => {
                    *s = u;
                    *sd = 0.0;
                }
                SpoolModel::FirstOrder { decay } => {
                    let s1 = u + (*s - u) * decay;
                    *sd = 0.0;
                    *s = s1;
                }
                SpoolModel::SecondOrder { phi, gamma } => {
                    let x = phi * Vector2::new(*s, *sd) + gamma * u;
                    *s = x[0];
                    *sd = x[1];
                }
            }
        }
    }
}

/// The component of `valve_dynamics`: the section (absent without the effect) and its
/// discretisation over the plant's substep h and over h/2. Its states, the spool position
/// and velocity, are the plant state's `spool` and `spool_velocity`.
#[derive(Debug, Clone)]
pub struct Spool {
    /// The section, `None` when it is absent or switched off.
    section: Option<ValveDynamics>,
    /// Over the substep h ([`SpoolStage::discretise`]; ideal before).
    full: SpoolModel,
    /// Over h/2, for the mid-step opening of `linear_exact`.
    half: SpoolModel,
}

impl Component for Spool {
    type Section = ValveDynamics;

    /// The order and its bandwidth: order 1 with T_z ≥ 0 s (0: ideal spool), order 2 with
    /// ω_nv > 0 rad/s and ζ > 0.
    fn validate(s: &ValveDynamics) -> Result<(), ConfigError> {
        s.validate_order()
    }

    /// The section only: the substep is not chosen yet (it depends on [`SpoolStage::bandwidth`]
    /// under `linear_exact`), so the spool is ideal until the plant calls
    /// [`SpoolStage::discretise`] in its configure phase.
    fn configure(s: Option<&ValveDynamics>, _setup: &Setup) -> Self {
        Spool {
            section: s.filter(|d| d.enabled).cloned(),
            full: SpoolModel::Ideal,
            half: SpoolModel::Ideal,
        }
    }

    /// No state of its own: the spool's position and velocity are set with the plant state.
    fn reset(&mut self) {}
}

impl SpoolStage for Spool {
    fn order(&self) -> u8 {
        self.section.as_ref().map_or(0, |d| d.order)
    }

    /// 1/T_z (order 1 with T_z > 0), ω_nv (order 2), 0 for an ideal spool (section absent or
    /// switched off, or T_z = 0).
    fn bandwidth(&self) -> f64 {
        match self.section.as_ref() {
            Some(d) if d.order == 1 && d.time_constant > 0.0 => 1.0 / d.time_constant,
            Some(d) if d.order == 2 => d.natural_frequency,
            _ => 0.0,
        }
    }

    /// [`SpoolModel::new`] over `h` and `h`/2; on `Err` both stay as they were.
    fn discretise(&mut self, h: f64) -> Result<(), ConfigError> {
        let full = SpoolModel::new(self.section.as_ref(), h)?;
        let half = SpoolModel::new(self.section.as_ref(), 0.5 * h)?;
        self.full = full;
        self.half = half;
        Ok(())
    }

    /// [`SpoolModel::advance`] over h.
    #[inline]
    fn advance(&self, spool: &mut f64, velocity: &mut f64, target: f64) {
        self.full.advance(spool, velocity, target);
    }

    /// [`SpoolModel::advance`] over h/2, from a copy of the state.
    #[inline]
    fn midstep(&self, spool: f64, velocity: f64, target: f64) -> f64 {
        let (mut s, mut sd) = (spool, velocity);
        self.half.advance(&mut s, &mut sd, target);
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SETUP: Setup = Setup::TEST;

    fn section(order: u8) -> ValveDynamics {
        ValveDynamics {
            enabled: true,
            order,
            time_constant: 0.01,
            natural_frequency: 1507.9,
            damping_ratio: 0.59,
        }
    }

    /// Without the effect (absent or switched off) the spool follows its target at once and
    /// is no state of the linearisation.
    #[test]
    fn without_the_effect_the_spool_is_ideal() {
        let mut off = section(2);
        off.enabled = false;
        for s in [None, Some(&off)] {
            let mut st = Spool::configure(s, &SETUP);
            st.discretise(1e-4).unwrap();
            assert_eq!((st.order(), st.bandwidth()), (0, 0.0));
            let (mut x, mut v) = (0.1, 3.0);
            st.advance(&mut x, &mut v, 0.4);
            assert_eq!((x, v), (0.4, 0.0));
            assert_eq!(st.midstep(0.1, 3.0, 0.4), 0.4);
        }
    }

    /// Order 1: z → u + (z − u)·e^(−h/T_z) over h, with e^(−h/(2T_z)) at mid-step;
    /// bandwidth 1/T_z; T_z = 0 is the ideal spool with order 1 kept for the linearisation.
    #[test]
    fn first_order_spool_is_the_pt1_over_h_and_h_half() {
        let s = section(1);
        let mut st = Spool::configure(Some(&s), &SETUP);
        let h = 1e-4;
        st.discretise(h).unwrap();
        assert_eq!((st.order(), st.bandwidth()), (1, 100.0));
        let (mut x, mut v) = (0.0, 0.0);
        st.advance(&mut x, &mut v, 0.5);
        assert!((x - 0.5 * (1.0 - (-h / 0.01f64).exp())).abs() < 1e-15);
        let m = st.midstep(0.0, 0.0, 0.5);
        assert!((m - 0.5 * (1.0 - (-0.5 * h / 0.01f64).exp())).abs() < 1e-15);
        let ideal = ValveDynamics {
            time_constant: 0.0,
            ..s
        };
        let mut st = Spool::configure(Some(&ideal), &SETUP);
        st.discretise(h).unwrap();
        assert_eq!((st.order(), st.bandwidth()), (1, 0.0));
        assert_eq!(st.midstep(0.0, 0.0, 0.5), 0.5);
    }

    /// Order 2 beyond the exponential's bound: `discretise` names the damping ratio and keeps
    /// the discretisation it had; `validate` refuses an order other than 1 or 2.
    #[test]
    fn second_order_out_of_bounds_keeps_the_previous_discretisation() {
        let s = section(2);
        let mut st = Spool::configure(Some(&s), &SETUP);
        st.discretise(1e-5).unwrap();
        assert_eq!((st.order(), st.bandwidth()), (2, 1507.9));
        let m = st.midstep(0.0, 0.0, 1.0);
        let huge = ValveDynamics {
            damping_ratio: 1e53,
            ..s.clone()
        };
        assert!(Spool::validate(&huge).is_ok());
        let mut bad = Spool::configure(Some(&huge), &SETUP);
        let e = bad.discretise(1e-5).unwrap_err();
        assert!(
            e.to_string()
                .contains("effects.valve_dynamics.damping_ratio"),
            "{e}"
        );
        assert_eq!(bad.midstep(0.0, 0.0, 1.0), 1.0, "still ideal");
        assert!(st.discretise(1e-5).is_ok() && st.midstep(0.0, 0.0, 1.0) == m);
        let e = Spool::validate(&section(3)).unwrap_err();
        assert!(
            e.to_string().contains("effects.valve_dynamics.order"),
            "{e}"
        );
    }
}
