//! Grey-box extension when the catalogue is exhausted: a short force law on the rod, selected
//! term by term from a library of physical-state terms, fitted on the fitting part only and
//! scored once on the held-out part.
//!
//! Library: the terms of `[effects.polynomial_force]` ([`ehactl_plant::effects::PolynomialForce`],
//! a force on the rod): constant F₀, viscous c_v·v, Coulomb/yield F_c·sign(v), quadratic
//! c_q·|v|·v, stiffness k·(x − x₀), load-pressure A_p·(p_a − p_b) and pressure-dependent
//! friction A_c·sign(v)·|p_a − p_b|, and Dahl's pre-yield hysteresis F_d·z with
//! dz/dt = (v − |v|·z)/δ (Dahl 1968; for MR dampers Ikhouane & Dyke 2007); and of `[effects.polynomial_flow]`
//! ([`ehactl_plant::effects::PolynomialFlow`], a flow from port B to port A): null bias q₀,
//! flow-gain error q_s·x_v and direction asymmetry q_a·|x_v|. The damping coefficients (viscous,
//! quadratic) and the Dahl force are bounded at ≥ 0: a load-side damping dissipates energy.
//! Because every term is a field of
//! the plant config, the extended config stays runnable by `ehactl run` and the Python bindings.
//!
//! Selection: forward stepwise sparse regression in output error (the free-run simulation
//! error, not the one-step equation error of SINDy's sequentially thresholded least squares,
//! Brunton et al., PNAS 113(15):3932–3937, 2016: on a closed-loop rig with unmeasured
//! velocity and pressures the equation error cannot be formed without differentiating noisy
//! signals, and a free-run error is what the held-out score measures). Each round fits every
//! remaining term on top of the model so far (terms in parallel with rayon, the catalogue model
//! frozen, the earlier terms refit jointly), keeps the one that lowers the mean over channels
//! of ln J_c (J_c: fitting-part NRMSE² of channel c; the Gaussian log-likelihood with an unknown
//! variance per channel, so a small channel counts as much as a large one) most, if that
//! geometric mean falls by at least [`MIN_REL_GAIN`] and the overall J does not rise (the
//! threshold keeps the law sparse), and stops after [`MAX_TERMS`] terms. A coefficient that ends
//! on its bound gets the bound widened 4× (at most twice) and is refit. The held-out part never enters a choice: it is scored once at the end.
//! When the record has a force channel, each term starts from the least-squares coefficient of
//! the force residual on that term (the equation-error estimate), computed on the fitting part.

use crate::ctx::{Ctx, Errors, Hyp};
use crate::data::{ChannelKind, Record};
use crate::fit::{FreeParam, Scales};
use crate::replay::Replay;
use ehactl_plant::effects::{PolynomialFlow, PolynomialForce};
use ehactl_plant::spec::{self, ParamTree};
use ehactl_plant::PlantParams;
use rayon::prelude::*;
use serde::Serialize;
use std::sync::Arc;

/// At most this many library terms are selected (-).
pub const MAX_TERMS: usize = 4;
/// A term is selected only if it lowers the fitting-part cost J by at least this fraction (-).
pub const MIN_REL_GAIN: f64 = 0.05;

/// One selected term.
#[derive(Debug, Clone, Serialize)]
pub struct Term {
    /// Config path of the coefficient (`effects.polynomial_force.<field>`).
    pub path: String,
    /// Fitted coefficient (SI, see `unit`).
    pub value: f64,
    /// Unit of the coefficient.
    pub unit: String,
    /// What the term is (e.g. `load-side yield force`).
    pub name: String,
    /// The term in physical words.
    pub physics: String,
    /// Fitting-part overall NRMSE after this term was added (-).
    pub nrmse_train: f64,
    /// Overall NRMSE on the predicted segment of the fitting part (the transfer check) after
    /// this term was added, the terms fitted on the segment before it (-); `None` when the
    /// fitting part was too short to split.
    pub nrmse_transfer: Option<f64>,
    /// Held-out overall NRMSE after this term was added (-): reported, never used to choose.
    pub nrmse_validation: f64,
    /// Bound of the coefficient (±, SI) after any widening.
    pub bound: f64,
    /// Whether the final coefficient sits on its bound (a proxy, not a finding).
    pub at_bound: bool,
}

/// Fraction of the fitting part on which the terms are fitted for the transfer check; the
/// rest is predicted (-).
pub const TRANSFER_SPLIT: f64 = 0.6;

/// The transfer check of the grey-box law: fitted on one segment of the fitting part,
/// predicting the next.
#[derive(Debug, Clone, Serialize)]
pub struct Transfer {
    /// Samples the terms were fitted on (indices into the fitting record).
    pub fit_samples: std::ops::Range<usize>,
    /// Samples they had to predict.
    pub predicted_samples: std::ops::Range<usize>,
    /// Overall NRMSE on the predicted samples of the catalogue model alone (-).
    pub nrmse_before: f64,
    /// Overall NRMSE on the predicted samples with the chosen terms (-).
    pub nrmse_after: f64,
}

/// Result of the grey-box extension.
#[derive(Debug, Clone, Serialize)]
pub struct GreyBox {
    /// The force law in words (the selected terms).
    pub structure: String,
    /// Selected terms in order of selection.
    pub terms: Vec<Term>,
    /// Fitting-part overall NRMSE before the extension (catalogue model) (-).
    pub nrmse_train_before: f64,
    /// Fitting-part overall NRMSE with the selected terms (-).
    pub nrmse_train: f64,
    /// Held-out NRMSE of catalogue model + grey-box law (per channel and overall) (-).
    pub nrmse_validation: Errors,
    /// Held-out overall NRMSE / ARX baseline overall NRMSE (-).
    pub ratio_to_baseline: f64,
    /// Whether at least one term was selected (the extended config then carries
    /// `[effects.polynomial_force]`).
    pub accepted: bool,
    /// The transfer check the terms were chosen by (`None`: fitting part too short to split).
    pub transfer: Option<Transfer>,
    /// Fitted pre-yield velocity v_y of the yield term (m/s), when it was fitted.
    pub yield_velocity: Option<f64>,
    /// Fitted pre-yield travel δ of the Dahl term (m), when it was fitted.
    pub dahl_travel: Option<f64>,
    /// Yield force the law reaches in steady sliding (N): the sum of the selected yield
    /// terms, Dahl F_d, rate-only F_y and the pressure-dependent friction at the median load
    /// pressure while sliding ([`Self::median_load_pressure`]); `None` without one. Per
    /// record, so that records differing in one factor (an MR damper's current) show its
    /// trend whichever of the terms carries it.
    pub yield_force: Option<f64>,
    /// Median |p_a − p_b| (Pa) of the extended model on the fitting part while sliding
    /// (|v| above 10 % of the velocity scale), at which the pressure-dependent friction
    /// enters `yield_force`; `None` without that term.
    pub median_load_pressure: Option<f64>,
    /// Selection log: each round's best candidate and its fitting-part cost.
    pub selection: Vec<String>,
}

/// `v` with 4 significant digits (plain notation from 1e-3 to 1e6, else scientific).
fn sig4(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 || !(1e-3..1e6).contains(&a) {
        return format!("{v:.3e}");
    }
    let decimals = (3 - a.log10().floor() as i32).max(0) as usize;
    format!("{v:.decimals$}")
}

impl GreyBox {
    /// The cause in physical terms when the law carries the gain: its first term (the largest
    /// gain) with value and unit, and the further terms by name. When the first term is a
    /// yield term, the cause is the total yield force of the yield terms (Dahl and/or the
    /// rate-only yield) with each part, e.g. `load-side yield force 1273 N (Dahl 427.2 N over a
    /// pre-yield travel δ = 6.022e-4 m + 845.2 N ∝ tanh(v/v_y), v_y = … m/s)`.
    pub fn cause(&self) -> Option<String> {
        let first = self.terms.first()?;
        let is_yield = |t: &Term| {
            t.path.ends_with(".coulomb")
                || t.path.ends_with(".dahl")
                || t.path.ends_with(".pressure_coulomb")
        };
        let (mut c, rest): (String, Vec<&Term>) = if is_yield(first) {
            let parts: Vec<String> = self
                .terms
                .iter()
                .filter(|t| is_yield(t))
                .map(|t| {
                    if t.path.ends_with(".pressure_coulomb") {
                        match self.median_load_pressure {
                            Some(dp) => format!(
                                "{} N pressure-dependent at the median |p_a − p_b| = {} Pa",
                                sig4(t.value * dp),
                                sig4(dp)
                            ),
                            None => format!("pressure-dependent {} m²", sig4(t.value)),
                        }
                    } else if t.path.ends_with(".dahl") {
                        match self.dahl_travel {
                            Some(d) => format!(
                                "Dahl {} N over a pre-yield travel δ = {} m",
                                sig4(t.value),
                                sig4(d)
                            ),
                            None => format!("Dahl {} N", sig4(t.value)),
                        }
                    } else {
                        match self.yield_velocity {
                            Some(vy) => {
                                format!("{} N ∝ tanh(v/v_y), v_y = {} m/s", sig4(t.value), sig4(vy))
                            }
                            None => format!("{} N ∝ sign(v)", sig4(t.value)),
                        }
                    }
                })
                .collect();
            (
                format!(
                    "load-side yield force {} N ({})",
                    sig4(self.yield_force.unwrap_or(first.value)),
                    parts.join(" + ")
                ),
                self.terms.iter().filter(|t| !is_yield(t)).collect(),
            )
        } else {
            (
                format!("{} {} {}", first.name, sig4(first.value), first.unit),
                self.terms.iter().skip(1).collect(),
            )
        };
        if !rest.is_empty() {
            let more: Vec<&str> = rest.iter().map(|t| t.name.as_str()).collect();
            c = format!("{c}, with {}", more.join(", "));
        }
        Some(c)
    }
}

mod library;
mod select;
pub use library::VELOCITY_CORRELATION;
use library::*;
use select::*;

/// Run the grey-box extension on top of hypothesis `current` (whose fitting-part cost is
/// `cur_train`). Returns the extended hypothesis when a term was selected, and the report.
/// `baseline` is the ARX baseline's held-out overall NRMSE.
pub(crate) fn extend(
    ctx: &Ctx,
    current: &Hyp,
    cur_train: f64,
    scales: &Scales,
    baseline: f64,
    evals_per_param: usize,
) -> (Option<Hyp>, GreyBox) {
    // The catalogue model is frozen: the library terms are fitted on top of it.
    let frozen = ctx.frozen(current);
    let fit = GreyBoxFit::new(&frozen, scales, evals_per_param);
    let (mut st, transfer_before) = fit.start_selection(cur_train);
    for _round in 0..MAX_TERMS {
        if !fit.select_round(&mut st) {
            break;
        }
    }
    fit.fit_velocity_terms_together(&mut st);
    let transfer = fit.transfer(&st, transfer_before);
    fit.refit_on_fitting_part(&mut st);
    let h = st.h.clone();
    let report = fit.report(st, transfer, cur_train, baseline);
    if !report.accepted {
        return (None, report);
    }
    // Combine: the catalogue hypothesis plus the grey-box parameters.
    let mut out = current.clone();
    out.params.extend(h.params);
    out.values.extend(h.values);
    (Some(out), report)
}
