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

/// A library entry: section, field name, physics and coefficient bound (the unit is the
/// registry's, [`Lib::unit`]).
struct Lib {
    /// `polynomial_force` or `polynomial_flow`.
    section: &'static str,
    field: &'static str,
    /// What the term is, in words a user of the rig reads as a cause.
    name: &'static str,
    physics: &'static str,
    bound: f64,
    /// Regressor for the least-squares start (force records): f(x, v) or None.
    feature: Option<fn(f64, f64, &PolynomialForce) -> f64>,
}

impl Lib {
    /// Dotted registry path, e.g. `effects.polynomial_force.viscous`.
    fn path(&self) -> String {
        format!("effects.{}.{}", self.section, self.field)
    }

    /// SI unit from the parameter registry (the field's `#[param(unit)]`).
    fn unit(&self) -> &'static str {
        let path = self.path();
        spec::params()
            .iter()
            .find(|p| p.path == path)
            .map_or("-", |p| p.unit)
    }
}

/// Dahl state z (-) of velocity samples `v` (m/s) at period `dt` (s) and pre-yield travel
/// `delta` (m), from z = 0, exact for a velocity held over each sample:
/// z ← sign(v) + (z − sign(v))·exp(−|v|·dt/δ). The regressor of the Dahl term's start.
fn dahl_trace(v: &[f64], dt: f64, delta: f64) -> Vec<f64> {
    let mut z = 0.0_f64;
    v.iter()
        .map(|&v| {
            let out = z;
            let zi = if v > 0.0 {
                1.0
            } else if v < 0.0 {
                -1.0
            } else {
                z
            };
            z = zi + (z - zi) * (-v.abs() * dt / delta).exp();
            out
        })
        .collect()
}

/// |r| of the force residual with velocity above which the velocity terms are fitted together
/// when none was kept (velocity then explains at least a quarter of the residual's variance) (-).
pub const VELOCITY_CORRELATION: f64 = 0.5;

/// Robust scale of a trace: the 99th percentile of |v − c| (units of `v`).
fn robust_scale(v: &[f64], c: f64) -> f64 {
    let mut a: Vec<f64> = v
        .iter()
        .map(|x| (x - c).abs())
        .filter(|x| x.is_finite())
        .collect();
    if a.is_empty() {
        return 0.0;
    }
    a.sort_by(f64::total_cmp);
    a[((a.len() - 1) as f64 * 0.99) as usize]
}

/// Robust velocity scale of a trace: the 99th percentile of |v| (m/s).
fn v_scale(v: &[f64]) -> f64 {
    robust_scale(v, 0.0)
}

/// The term library: every candidate term with its bound, from the force scale `fs` (N), the
/// velocity scale `vr` (m/s), the cap area `area` (m²), the stroke (m) and the flow and
/// stiffness scales of `scales`.
fn term_library(scales: &Scales, fs: f64, vr: f64, area: f64, stroke: f64) -> [Lib; 11] {
    [
        Lib {
            section: "polynomial_force",
            field: "constant",
            name: "load-side constant force",
            physics: "constant force (preload)",
            bound: 0.2 * fs,
            feature: Some(|_, _, _| 1.0),
        },
        Lib {
            section: "polynomial_force",
            field: "viscous",
            name: "load-side viscous damping",
            physics: "viscous force ∝ v",
            bound: 0.3 * fs / vr,
            feature: Some(|_, v, _| v),
        },
        Lib {
            section: "polynomial_force",
            field: "coulomb",
            name: "load-side yield force",
            physics: "yield force F_y·tanh(v/v_y): Bingham with a fitted pre-yield velocity v_y, bounded at any speed",
            bound: 0.2 * fs,
            feature: Some(|_, v, f| (v / f.smoothing_velocity).tanh()),
        },
        Lib {
            section: "polynomial_force",
            field: "dahl",
            name: "load-side Dahl yield force",
            physics: "yield force F_d·z with pre-yield hysteresis, dz/dt = (v − |v|·z)/δ (Dahl): builds up over a fitted travel δ after each reversal, bounded at any speed",
            bound: 0.2 * fs,
            // Regressor from the state trace (`dahl_start` below), not per sample.
            feature: None,
        },
        Lib {
            section: "polynomial_force",
            field: "quadratic",
            name: "load-side quadratic damping",
            physics: "quadratic damping ∝ |v|·v",
            bound: 0.3 * fs / (vr * vr),
            feature: Some(|_, v, _| v.abs() * v),
        },
        Lib {
            section: "polynomial_force",
            field: "stiffness",
            name: "load-side stiffness",
            physics: "stiffness ∝ (x − x₀)",
            bound: 0.5 * scales.stiffness.max(fs / stroke),
            feature: Some(|x, _, f| x - f.origin),
        },
        Lib {
            section: "polynomial_force",
            field: "pressure",
            name: "load-pressure force",
            physics: "load-pressure force ∝ (p_a − p_b)",
            bound: 0.3 * area,
            feature: None,
        },
        Lib {
            section: "polynomial_force",
            field: "pressure_coulomb",
            name: "pressure-dependent friction",
            physics: "pressure-dependent friction ∝ sign(v)·|p_a − p_b|",
            bound: 0.3 * area,
            feature: None,
        },
        Lib {
            section: "polynomial_flow",
            field: "constant",
            name: "valve null-bias flow",
            physics: "valve null-bias flow (B→A)",
            bound: 0.2 * scales.flow,
            feature: None,
        },
        Lib {
            section: "polynomial_flow",
            field: "spool",
            name: "valve flow-gain error",
            physics: "flow-gain error ∝ x_v",
            bound: 0.5 * scales.flow,
            feature: None,
        },
        Lib {
            section: "polynomial_flow",
            field: "spool_abs",
            name: "valve flow-gain asymmetry",
            physics: "flow-gain direction asymmetry ∝ |x_v|",
            bound: 0.5 * scales.flow,
            feature: None,
        },
    ]
}

/// Checks that each term is a declared float parameter of its section: its unit and its
/// accessor (`get_path` / `set_path` in [`GreyBoxFit::make_param`]) come from the `#[param]`
/// declaration. Checked on every run, so a misspelt term fails loudly instead of being fitted
/// as nothing.
fn check_library(lib: &[Lib]) {
    for l in lib {
        let path = l.path();
        assert!(
            spec::params()
                .iter()
                .any(|p| p.path == path && p.kind == spec::Kind::Float),
            "grey-box term {path} is not a declared float parameter"
        );
    }
}

/// Force residual of the frozen model on the fitting part, with the states the equation-error
/// starts regress it on.
struct ForceResidual {
    /// Measured minus simulated force (N).
    resid: Vec<f64>,
    /// Simulated position (m), or the stiffness origin without a position channel.
    x: Vec<f64>,
    /// Simulated velocity (m/s).
    v: Vec<f64>,
}

/// The force residual of replay `s` on the first `n_fit` samples of `rec`, when the record has
/// a force channel; `origin` (m) stands in for a missing position channel.
fn force_residual_of(rec: &Record, s: &Replay, n_fit: usize, origin: f64) -> Option<ForceResidual> {
    let fc = rec
        .channels
        .iter()
        .position(|c| c.kind == ChannelKind::Force)?;
    let xs: Vec<f64> = match rec
        .channels
        .iter()
        .position(|c| c.kind == ChannelKind::Position)
    {
        Some(i) => s.y[i][..n_fit].to_vec(),
        None => vec![origin; n_fit],
    };
    let r: Vec<f64> = rec.channels[fc].values[..n_fit]
        .iter()
        .zip(&s.y[fc][..n_fit])
        .map(|(a, b)| a - b)
        .collect();
    Some(ForceResidual {
        resid: r,
        x: xs,
        v: s.v[..n_fit].to_vec(),
    })
}

/// Selection criterion: mean over channels of ln J_c (the negative log-likelihood of Gaussian
/// errors with an unknown variance per channel, up to constants), so a term that fixes a small
/// channel counts as much as one that fixes a large one (-).
fn log_cost(jc: &[f64]) -> f64 {
    jc.iter().map(|j| j.max(1e-300).ln()).sum::<f64>() / jc.len().max(1) as f64
}

/// Start of the Dahl term (force F_d in N, travel δ in m): least squares of the force residual
/// `resid` on the Dahl state of the velocity `v` (m/s, period `dt` s), over a log grid of δ from
/// 0.2 % to 50 % of the position scale `xr` (m) (the equation-error estimate of
/// scripts/mts_force_law_check.py).
fn dahl_start(v: &[f64], dt: f64, resid: &[f64], xr: f64) -> (f64, f64) {
    let mut best = (f64::INFINITY, 0.0, 0.05 * xr);
    for k in 0..16 {
        let delta = 0.002 * xr * (250.0_f64).powf(k as f64 / 15.0);
        let z = dahl_trace(v, dt, delta);
        let (num, den) = z
            .iter()
            .zip(resid)
            .fold((0.0, 0.0), |(n, d), (z, r)| (n + z * r, d + z * z));
        if den <= 0.0 {
            continue;
        }
        let c = (num / den).max(0.0);
        let sse: f64 = z
            .iter()
            .zip(resid)
            .map(|(z, r)| (r - c * z) * (r - c * z))
            .sum();
        if sse < best.0 {
            best = (sse, c, delta);
        }
    }
    (best.1, best.2)
}

/// Value of the free parameter named `name` in `h`, when `h` fits it.
fn param_value(h: &Hyp, name: &str) -> Option<f64> {
    h.params
        .iter()
        .position(|p| p.name == name)
        .map(|k| h.values[k])
}

/// Median |p_a − p_b| (Pa) of replay `s` over its first `n_fit` samples while sliding (|v| above
/// `v_min`, m/s); `None` when it never slides.
fn median_sliding_pressure(s: &Replay, n_fit: usize, v_min: f64) -> Option<f64> {
    let mut a: Vec<f64> = s.dp[..n_fit.min(s.dp.len())]
        .iter()
        .zip(&s.v)
        .filter(|(_, v)| v.abs() > v_min)
        .map(|(dp, _)| dp.abs())
        .filter(|x| x.is_finite())
        .collect();
    if a.is_empty() {
        return None;
    }
    a.sort_by(f64::total_cmp);
    Some(a[a.len() / 2])
}

/// Yield force (N) of the selected `terms` in steady sliding: the yield and Dahl forces plus
/// the pressure-dependent friction at the median load pressure `dp` (Pa); `None` without one.
fn yield_force_of(terms: &[Term], dp: Option<f64>) -> Option<f64> {
    let yield_terms: Vec<f64> = terms
        .iter()
        .filter_map(|t| {
            if t.path.ends_with(".coulomb") || t.path.ends_with(".dahl") {
                Some(t.value)
            } else if t.path.ends_with(".pressure_coulomb") {
                dp.map(|dp| t.value * dp)
            } else {
                None
            }
        })
        .collect();
    (!yield_terms.is_empty()).then(|| yield_terms.iter().sum())
}

/// The extended law in words: the force law and the flow law of `p` that selected `terms`
/// enter, or why nothing was accepted.
fn structure_of(p: Option<PlantParams>, terms: &[Term]) -> String {
    let Some(p) = p else {
        return "no library term lowered the fitting-part error (geometric mean over channels) by ≥ 5 %"
            .to_string();
    };
    let mut parts = Vec::new();
    if let Some(f) = p
        .effects
        .polynomial_force
        .filter(|_| terms.iter().any(|t| t.path.contains("force")))
    {
        parts.push(format!(
            "rod force law (opposing +x, seen by the load cell) = {}",
            f.describe().join(" + ")
        ));
    }
    if let Some(f) = p
        .effects
        .polynomial_flow
        .filter(|_| terms.iter().any(|t| t.path.contains("flow")))
    {
        parts.push(format!("B→A flow law = {}", f.describe().join(" + ")));
    }
    parts.join("; ")
}

/// A candidate law of one selection round: the hypothesis with its costs.
struct Candidate {
    h: Hyp,
    /// Cost J on the selection segment (-).
    cost: f64,
    /// Judged mean ln J_c ([`log_cost`]) (-).
    judged_log: f64,
    /// Judged overall NRMSE (-).
    judged: f64,
}

/// The state of the forward selection: the law so far, its costs and the log.
struct Selection {
    /// The grey-box parameters selected so far.
    h: Hyp,
    /// Cost J of `h` on the selection segment (-).
    j_cur: f64,
    /// Judged mean ln J_c of `h` (-).
    l_cur: f64,
    terms: Vec<Term>,
    /// Selection log (see [`GreyBox::selection`]).
    log: Vec<String>,
    /// Library terms selected (section, field).
    used: Vec<(&'static str, &'static str)>,
    /// Force residual (N) of `h` on the fitting part, for the next starts (empty without a
    /// force channel).
    resid: Vec<f64>,
}

/// The grey-box fit on top of a frozen catalogue model: its scales, the term library, the
/// force residual the terms start from and the transfer split that judges them.
struct GreyBoxFit<'a> {
    /// The catalogue model frozen into the base parameters.
    frozen: &'a Ctx<'a>,
    /// Transfer check, the measure of an extension's gain: terms are chosen on the first
    /// [`TRANSFER_SPLIT`] of the fitting part and judged by how they predict the rest, which a
    /// chirp or a sweep fills with other content (another band, other velocities). A term that
    /// only fits (a viscous coefficient fitted at low speed that extrapolates to forces the rig
    /// never saw, say) does not pass; the chosen law is then refit jointly on the whole fitting
    /// part. The held-out part still never enters a choice. `None`: too short to split.
    split: Option<Ctx<'a>>,
    /// Base parameters of the fitting part (the frozen model).
    base_fit: PlantParams,
    /// The base config's force law (zero without one).
    prior: PolynomialForce,
    /// The base config's flow law.
    prior_flow: Option<PolynomialFlow>,
    /// The force law a term's section is inserted with (smoothing velocity and origin set).
    start: PolynomialForce,
    /// Robust velocity scale (m/s).
    vr: f64,
    /// Force scale (N).
    fs: f64,
    /// Sign smoothing velocity (m/s).
    vs: f64,
    /// Position scale (m): the 99th percentile of |x − x₀| on the fitting part, for the Dahl
    /// term's pre-yield travel.
    xr: f64,
    lib: [Lib; 11],
    /// Force residual of the frozen model, when the record has a force channel.
    force_resid: Option<ForceResidual>,
    evals_per_param: usize,
}

impl<'a> GreyBoxFit<'a> {
    /// Scales, library, force residual and transfer split of the frozen model `frozen`.
    fn new(frozen: &'a Ctx<'a>, scales: &Scales, evals_per_param: usize) -> Self {
        let base_fit = frozen.fit_base_params().clone();
        let sim = frozen.fit_replay(&base_fit).ok();
        let vr = sim
            .as_ref()
            .map(|s| v_scale(&s.v[..frozen.n_fit().min(s.v.len())]))
            .unwrap_or(0.0);
        let vr = if vr > 0.0 { vr } else { 1e-2 };
        let fs = scales.force.max(1e-9);
        let area = base_fit.cylinder.area_a;
        let prior = base_fit
            .effects
            .polynomial_force
            .unwrap_or_else(PolynomialForce::zero);
        // Sign smoothing at 2 % of the velocity scale; stiffness origin at the data's mean
        // position.
        let vs = if base_fit.effects.polynomial_force.is_some() {
            prior.smoothing_velocity
        } else {
            0.02 * vr
        };
        let rec = frozen.fit_rec();
        let n_fit = frozen.n_fit();
        let origin = if base_fit.effects.polynomial_force.is_some() {
            prior.origin
        } else {
            rec.channel(ChannelKind::Position)
                .map(|x| x[..n_fit].iter().sum::<f64>() / n_fit as f64)
                .unwrap_or(base_fit.cylinder.initial_position)
        };
        let lib = term_library(scales, fs, vr, area, base_fit.cylinder.stroke);
        check_library(&lib);
        let mut start = prior;
        start.enabled = true;
        start.smoothing_velocity = vs;
        start.origin = origin;
        let force_resid = sim
            .as_ref()
            .and_then(|s| force_residual_of(rec, s, n_fit, origin));
        let xr = rec
            .channel(ChannelKind::Position)
            .map(|x| robust_scale(&x[..n_fit], origin))
            .filter(|a| *a > 0.0)
            .unwrap_or(0.01 * base_fit.cylinder.stroke);
        Self {
            frozen,
            split: frozen.transfer_split(TRANSFER_SPLIT),
            prior_flow: base_fit.effects.polynomial_flow,
            base_fit,
            prior,
            start,
            vr,
            fs,
            vs,
            xr,
            lib,
            force_resid,
            evals_per_param,
        }
    }

    /// The fitting record.
    fn rec(&self) -> &'a Record {
        self.frozen.fit_rec()
    }

    /// The context terms are chosen on: the transfer split's first segment, else the fitting
    /// part.
    fn sel(&self) -> &Ctx<'a> {
        self.split.as_ref().unwrap_or(self.frozen)
    }

    /// The free coefficient of library term `l`, started at the prior plus `init` (SI), its
    /// bound widened `widen` times (-).
    fn make_param(&self, l: &Lib, init: f64, widen: f64) -> FreeParam {
        // Every library field is a declared float of its section (tested), so the
        // accessor's `None` (0) is never taken.
        let p0 = if l.section == "polynomial_force" {
            self.prior.get_path(l.field)
        } else {
            self.prior_flow.and_then(|f| f.get_path(l.field))
        }
        .unwrap_or(0.0);
        let b = widen * l.bound.max(2.0 * p0.abs());
        // A rod force beyond what the actuator can push (supply pressure × cap area) is a
        // stand-in, not a load: force coefficients are never widened past it.
        let b = if l.unit() == "N" {
            b.min(self.fs.max(l.bound))
        } else {
            b
        };
        let field = l.field;
        let st = self.start;
        let set: crate::fit::Setter = if l.section == "polynomial_force" {
            Arc::new(move |p: &mut PlantParams, v| {
                // Inserted with the start's smoothing velocity and origin; an existing section
                // keeps its own (a pre-yield velocity fitted with the yield term must survive
                // the terms selected after it).
                let f = p.effects.polynomial_force.get_or_insert(st);
                f.enabled = true;
                // Declared float (checked above): the write cannot fail.
                let _ = f.set_path(field, v);
            })
        } else {
            Arc::new(move |p: &mut PlantParams, v| {
                let f = p
                    .effects
                    .polynomial_flow
                    .get_or_insert_with(PolynomialFlow::zero);
                f.enabled = true;
                // Declared float (checked above): the write cannot fail.
                let _ = f.set_path(field, v);
            })
        };
        // The Dahl force is a magnitude (F_d ≥ 0, the state carries the sign). A load-side
        // damping dissipates: its total coefficient is ≥ 0 (a negative quadratic damping fitted
        // at the speeds of one record injects energy at higher ones: the 0 A low-band law of
        // the MTS transfer check diverged on the high band with c_q < 0).
        let dissipative =
            l.section == "polynomial_force" && matches!(field, "viscous" | "quadratic");
        let lo = if field == "dahl" || dissipative {
            0.0
        } else {
            -b
        };
        FreeParam {
            name: format!("effects.{}.{field}", l.section),
            lo,
            hi: b,
            log: false,
            init: (p0 + init).clamp(lo, b),
            set,
        }
    }

    /// Per-channel cost (NRMSE² per channel, -) of parameters `p` on the samples of context
    /// `c`'s fit cost, normalised by its own stds.
    fn channel_costs_on(&self, c: &Ctx, p: &PlantParams) -> Vec<f64> {
        let rec = self.rec();
        let (n_fit, sd) = (c.n_fit(), c.sd_fit());
        match c.fit_replay(p) {
            Ok(s) if !s.failed => rec
                .channels
                .iter()
                .zip(&s.y)
                .zip(sd)
                .map(|((c, y), sd)| {
                    c.values[..n_fit]
                        .iter()
                        .zip(y)
                        .map(|(a, b)| (a - b) * (a - b))
                        .sum::<f64>()
                        / n_fit as f64
                        / (sd * sd)
                })
                .collect(),
            _ => vec![1e6; rec.channels.len()],
        }
    }

    /// Mean per-channel cost J (-) of parameters `p` on the selection segment.
    fn sel_cost(&self, p: &PlantParams) -> f64 {
        let jc = self.channel_costs_on(self.sel(), p);
        jc.iter().sum::<f64>() / jc.len().max(1) as f64
    }

    /// Judged cost of `hh`: mean ln NRMSE² over channels (-) and overall NRMSE (-) on the
    /// predicted segment (or, without a split, on the fitting part).
    fn judge(&self, hh: &Hyp) -> (f64, f64) {
        match &self.split {
            Some(t) => {
                let (e, _) = t.val_errors(hh);
                let jc: Vec<f64> = e.channels.values().map(|x| x * x).collect();
                (log_cost(&jc), e.overall)
            }
            None => {
                let jc = self.channel_costs_on(self.frozen, &hh.build(&self.base_fit));
                let j = jc.iter().sum::<f64>() / jc.len().max(1) as f64;
                (log_cost(&jc), j.sqrt())
            }
        }
    }

    /// Least-squares start (SI) of library term `l` on the force residual `resid` (N), the
    /// equation-error estimate; 0 without a regressor or a force channel.
    fn ls_start(&self, l: &Lib, resid: &[f64]) -> f64 {
        let (Some(feat), Some(fr)) = (l.feature, self.force_resid.as_ref()) else {
            return 0.0;
        };
        let (mut num, mut den) = (0.0, 0.0);
        for ((r, x), v) in resid.iter().zip(&fr.x).zip(&fr.v) {
            let phi = feat(*x, *v, &self.start);
            num += phi * r;
            den += phi * phi;
        }
        if den > 0.0 {
            num / den
        } else {
            0.0
        }
    }

    /// The yield term's pre-yield velocity v_y (m/s) started at `init`, fitted in log space
    /// with its force (from the base's smoothing velocity when the config has a force law: an
    /// assumption there). Written after its force term, which inserts the section.
    fn yield_velocity_param(&self, init: f64) -> FreeParam {
        FreeParam::at(
            "effects.polynomial_force.smoothing_velocity",
            (0.005 * self.vr, 0.5 * self.vr, true, init),
            &self.base_fit,
        )
    }

    /// The Dahl term's pre-yield travel δ (m) started at `init`, fitted in log space with its
    /// force (written after it, as the yield velocity).
    fn dahl_travel_param(&self, init: f64) -> FreeParam {
        FreeParam::at(
            "effects.polynomial_force.dahl_travel",
            (0.002 * self.xr, 0.5 * self.xr, true, init),
            &self.base_fit,
        )
    }

    /// Adds library term `l`'s coefficient (and the yield velocity or Dahl travel it carries)
    /// to `hh`, from its least-squares start on the force residual `resid` (N).
    fn push_term(&self, hh: &mut Hyp, l: &Lib, resid: &[f64]) {
        let (init, partner) = match l.field {
            "coulomb" if l.section == "polynomial_force" => (
                self.ls_start(l, resid),
                Some(self.yield_velocity_param(self.vs)),
            ),
            "dahl" => {
                // Without a force channel, F_d = 0 and δ at 5 % of the position scale.
                let (fd, delta) = match self.force_resid.as_ref() {
                    Some(fr) => dahl_start(&fr.v, self.rec().dt, resid, self.xr),
                    None => (0.0, 0.05 * self.xr),
                };
                (fd, Some(self.dahl_travel_param(delta)))
            }
            _ => (self.ls_start(l, resid), None),
        };
        let fp = self.make_param(l, init, 1.0);
        hh.values.push(fp.init);
        hh.params.push(fp);
        if let Some(fv) = partner {
            hh.values.push(fv.init);
            hh.params.push(fv);
        }
    }

    /// The report of a selected term `l` in hypothesis `h` (fitting cost `train`, judged
    /// overall NRMSE `judged`, -).
    fn term_of(&self, l: &Lib, h: &Hyp, train: f64, judged: f64) -> Term {
        let k = h.params.iter().rposition(|p| p.name == l.path());
        Term {
            path: l.path(),
            value: k.map_or(0.0, |k| h.values[k]),
            unit: l.unit().to_string(),
            name: l.name.to_string(),
            physics: l.physics.to_string(),
            nrmse_train: train.sqrt(),
            nrmse_transfer: self.split.as_ref().map(|_| judged),
            // Reported only: the held-out part never enters a choice.
            nrmse_validation: self.frozen.val_errors(h).0.overall,
            bound: k.map_or(0.0, |k| h.params[k].hi),
            at_bound: false,
        }
    }

    /// Force residual (N) of `h` on the fitting part, when the record has a force channel.
    fn force_residual(&self, h: &Hyp) -> Option<Vec<f64>> {
        self.force_resid.as_ref()?;
        let rec = self.rec();
        let n_fit = self.frozen.n_fit();
        let s = self.frozen.fit_replay(&h.build(&self.base_fit)).ok()?;
        let fc = rec
            .channels
            .iter()
            .position(|c| c.kind == ChannelKind::Force)?;
        Some(
            rec.channels[fc].values[..n_fit]
                .iter()
                .zip(&s.y[fc][..n_fit])
                .map(|(a, b)| a - b)
                .collect(),
        )
    }

    /// The empty law to select on, judged, and its judged overall NRMSE (-) (the transfer
    /// check's before); `cur_train` is the catalogue model's fitting-part cost (-).
    fn start_selection(&self, cur_train: f64) -> (Selection, f64) {
        let h = Hyp {
            effects: vec![],
            variants: vec![],
            params: vec![],
            values: vec![],
        };
        let j_cur = if self.split.is_some() {
            self.sel_cost(&self.base_fit)
        } else {
            cur_train
        };
        let (l_cur, transfer_before) = self.judge(&h);
        let mut log = Vec::new();
        if let Some(t) = &self.split {
            log.push(format!(
                "terms chosen on samples 0..{} of the fitting part and judged on how they predict samples {}..{} (transfer check); the chosen law refit on the whole fitting part",
                t.n_fit(),
                t.n_fit(),
                self.frozen.n_fit()
            ));
        }
        let resid = self
            .force_resid
            .as_ref()
            .map(|r| r.resid.clone())
            .unwrap_or_default();
        let st = Selection {
            h,
            j_cur,
            l_cur,
            terms: Vec::new(),
            log,
            used: Vec::new(),
            resid,
        };
        (st, transfer_before)
    }

    /// Every remaining term fitted on top of the law so far (in parallel), and the one with the
    /// lowest judged cost among those that do not raise the cost J; `None` when none is left.
    fn best_candidate(&self, st: &Selection) -> Option<(&Lib, Candidate)> {
        let cands: Vec<&Lib> = self
            .lib
            .iter()
            .filter(|l| !st.used.contains(&(l.section, l.field)))
            .collect();
        let results: Vec<(usize, Candidate)> = cands
            .par_iter()
            .enumerate()
            .map(|(i, l)| {
                let mut hh = st.h.clone();
                let first_new = hh.params.len();
                self.push_term(&mut hh, l, &st.resid);
                let (hh, c) = self.sel().fit(hh, first_new, self.evals_per_param);
                let (lc, e) = self.judge(&hh);
                let cand = Candidate {
                    h: hh,
                    cost: c,
                    judged_log: lc,
                    judged: e,
                };
                (i, cand)
            })
            .collect();
        let (i, best) = results
            .into_iter()
            .filter(|r| r.1.cost <= st.j_cur)
            .min_by(|a, b| a.1.judged_log.total_cmp(&b.1.judged_log))?;
        Some((cands[i], best))
    }

    /// A coefficient of term `l` that ends on its bound says the bound, not the data, stopped
    /// it: widen the bound (4×, at most twice) and refit `best`, on the fitting segment only.
    fn widen_on_bound(&self, l: &Lib, best: &mut Candidate, log: &mut Vec<String>) {
        let mut widen = 1.0;
        for _ in 0..2 {
            let path = l.path();
            let Some(k) = best.h.params.iter().rposition(|p| p.name == path) else {
                break;
            };
            let (fp, v) = (best.h.params[k].clone(), best.h.values[k]);
            if v.abs() < 0.98 * fp.hi {
                break;
            }
            widen *= 4.0;
            let wider = self.make_param(l, 0.0, widen);
            if wider.hi <= fp.hi * (1.0 + 1e-9) {
                log.push(format!(
                    "{}.{} ended on its bound ±{:.3e} {}: not widened (the actuator's force scale, supply pressure × cap area)",
                    l.section, l.field, fp.hi, l.unit()
                ));
                break;
            }
            let mut hw = best.h.clone();
            hw.params[k] = wider;
            hw.values[k] = v;
            let (hw, cw) = self.sel().fit(hw, k, self.evals_per_param);
            log.push(format!(
                "{}.{} ended on its bound ±{:.3e} {}: bound widened 4× and refit (fitting NRMSE {:.4} → {:.4})",
                l.section, l.field, fp.hi, l.unit(), best.cost.sqrt(), cw.sqrt()
            ));
            if cw < best.cost {
                (best.judged_log, best.judged) = self.judge(&hw);
                best.h = hw;
                best.cost = cw;
            }
        }
    }

    /// One round of the forward selection: the best remaining term, kept if it lowers the
    /// geometric mean of the judged per-channel J by [`MIN_REL_GAIN`]. Returns whether a term
    /// was kept (the selection goes on).
    fn select_round(&self, st: &mut Selection) -> bool {
        let Some((l, mut best)) = self.best_candidate(st) else {
            return false;
        };
        self.widen_on_bound(l, &mut best, &mut st.log);
        // Geometric-mean reduction of the per-channel cost on the judged segment (a replay
        // that failed or diverged scores the failure cost: said so, not as a huge number).
        let gain = 1.0 - (best.judged_log - st.l_cur).exp();
        let gain_text = if gain.is_finite() && gain > -10.0 {
            format!("{:+.1} %", -100.0 * gain)
        } else {
            "replay failed or diverged".to_string()
        };
        st.log.push(format!(
            "round {}: best {}.{} ({}): fitting NRMSE {:.4} → {:.4}, {} geometric mean of the per-channel J {}{}",
            st.terms.len() + 1,
            l.section,
            l.field,
            l.physics,
            st.j_cur.sqrt(),
            best.cost.sqrt(),
            if self.split.is_some() { "predicted segment:" } else { "fitting part:" },
            gain_text,
            if gain >= MIN_REL_GAIN { "" } else { " — not a 5 % fall, stop" }
        ));
        if gain < MIN_REL_GAIN {
            return false;
        }
        st.used.push((l.section, l.field));
        st.h = best.h;
        st.j_cur = best.cost;
        st.l_cur = best.judged_log;
        st.terms
            .push(self.term_of(l, &st.h, best.cost, best.judged));
        // Force residual after this term (for the next starts).
        if let Some(r) = self.force_residual(&st.h) {
            st.resid = r;
        }
        true
    }

    /// The force residual still tracks velocity but no velocity term was kept: alone, each may
    /// fail the transfer check when the load both yields and flows viscously (an MR damper: a
    /// yield force alone misses the high-speed slope, a viscous term alone the reversals), so
    /// the velocity terms are fitted together once, judged by the same rule.
    fn fit_velocity_terms_together(&self, st: &mut Selection) {
        let r_v = self
            .force_resid
            .as_ref()
            .map_or(0.0, |fr| crate::residual::corr(&st.resid, &fr.v));
        let velocity_terms = ["viscous", "coulomb", "dahl"];
        let kept_velocity = st
            .used
            .iter()
            .any(|(sec, f)| *sec == "polynomial_force" && velocity_terms.contains(f));
        if r_v.abs() < VELOCITY_CORRELATION || kept_velocity {
            return;
        }
        let group: Vec<&Lib> = self
            .lib
            .iter()
            .filter(|l| l.section == "polynomial_force" && velocity_terms.contains(&l.field))
            .collect();
        let mut hh = st.h.clone();
        let first_new = hh.params.len();
        for l in &group {
            self.push_term(&mut hh, l, &st.resid);
        }
        let (hh, c) = self.sel().fit(hh, first_new, self.evals_per_param);
        let (lc, e) = self.judge(&hh);
        let gain = 1.0 - (lc - st.l_cur).exp();
        let keep = c <= st.j_cur && gain >= MIN_REL_GAIN;
        st.log.push(format!(
            "the force residual tracks velocity (r = {r_v:+.2}) and no velocity term was kept: viscous, yield and Dahl terms fitted together: fitting NRMSE {:.4} → {:.4}, geometric mean of the per-channel J {:+.1} %{}",
            st.j_cur.sqrt(),
            c.sqrt(),
            -100.0 * gain,
            if keep { ", kept" } else { ", not kept" }
        ));
        if keep {
            st.h = hh;
            st.j_cur = c;
            for l in group {
                st.used.push((l.section, l.field));
                st.terms.push(self.term_of(l, &st.h, c, e));
            }
        }
    }

    /// The transfer check of the selected law, from the catalogue model's judged overall
    /// NRMSE `before` (-); `None` without a split.
    fn transfer(&self, st: &Selection, before: f64) -> Option<Transfer> {
        self.split.as_ref().map(|t| Transfer {
            fit_samples: 0..t.n_fit(),
            predicted_samples: t.n_fit()..self.frozen.n_fit(),
            nrmse_before: before,
            nrmse_after: st
                .terms
                .last()
                .and_then(|x| x.nrmse_transfer)
                .unwrap_or(before),
        })
    }

    /// The chosen law refit jointly on the whole fitting part (starts: the segment's values),
    /// then the final values of every selected term (the joint fit moved the earlier ones too).
    fn refit_on_fitting_part(&self, st: &mut Selection) {
        if self.split.is_some() && !st.h.params.is_empty() {
            let n = st.h.params.len();
            let (hf, cf) = self.frozen.fit(st.h.clone(), n, self.evals_per_param);
            if cf.is_finite() {
                st.h = hf;
                st.j_cur = cf;
            }
        }
        for t in st.terms.iter_mut() {
            if let Some(k) = st.h.params.iter().position(|p| p.name == t.path) {
                t.value = st.h.values[k];
                t.at_bound = t.value.abs() >= 0.98 * st.h.params[k].hi;
            }
        }
    }

    /// The report of the finished selection `st` (`cur_train`: the catalogue model's
    /// fitting-part cost, `baseline`: the ARX baseline's held-out overall NRMSE, -).
    fn report(
        &self,
        st: Selection,
        transfer: Option<Transfer>,
        cur_train: f64,
        baseline: f64,
    ) -> GreyBox {
        let h = &st.h;
        let terms = st.terms;
        // The yield term's fitted pre-yield velocity.
        let yield_velocity = param_value(h, "effects.polynomial_force.smoothing_velocity");
        // The Dahl term's fitted pre-yield travel.
        let dahl_travel = param_value(h, "effects.polynomial_force.dahl_travel");
        let accepted = !terms.is_empty();
        // The pressure-dependent friction at the extended model's median load pressure while
        // sliding, so that the yield force is comparable whichever term carries it.
        let median_load_pressure = terms
            .iter()
            .any(|t| t.path.ends_with(".pressure_coulomb"))
            .then(|| self.frozen.fit_replay(&h.build(&self.base_fit)).ok())
            .flatten()
            .and_then(|s| median_sliding_pressure(&s, self.frozen.n_fit(), 0.1 * self.vr));
        let yield_force = yield_force_of(&terms, median_load_pressure);
        let (val, _) = self.frozen.val_errors(h);
        let structure = structure_of(accepted.then(|| h.build(&self.base_fit)), &terms);
        let ratio = val.overall / baseline;
        GreyBox {
            structure,
            terms,
            nrmse_train_before: cur_train.sqrt(),
            nrmse_train: st.j_cur.sqrt(),
            nrmse_validation: val,
            ratio_to_baseline: ratio,
            accepted,
            transfer,
            yield_velocity,
            dahl_travel,
            yield_force,
            median_load_pressure,
            selection: st.log,
        }
    }
}

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
