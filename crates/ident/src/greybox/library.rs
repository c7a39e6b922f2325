//! The grey-box term library (each term's physics, bound and regressor) and the force
//! residual the equation-error starts regress on.

use super::*;

/// A library entry: section, field name, physics and coefficient bound (the unit is the
/// registry's, [`Lib::unit`]).
pub(super) struct Lib {
    /// `polynomial_force` or `polynomial_flow`.
    pub(super) section: &'static str,
    pub(super) field: &'static str,
    /// What the term is, in words a user of the rig reads as a cause.
    pub(super) name: &'static str,
    pub(super) physics: &'static str,
    pub(super) bound: f64,
    /// Regressor for the least-squares start (force records): f(x, v) or None.
    pub(super) feature: Option<fn(f64, f64, &PolynomialForce) -> f64>,
}

impl Lib {
    /// Dotted registry path, e.g. `effects.polynomial_force.viscous`.
    pub(super) fn path(&self) -> String {
        format!("effects.{}.{}", self.section, self.field)
    }

    /// SI unit from the parameter registry (the field's `#[param(unit)]`).
    pub(super) fn unit(&self) -> &'static str {
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
pub(super) fn dahl_trace(v: &[f64], dt: f64, delta: f64) -> Vec<f64> {
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
pub(super) fn robust_scale(v: &[f64], c: f64) -> f64 {
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
pub(super) fn v_scale(v: &[f64]) -> f64 {
    robust_scale(v, 0.0)
}

/// The term library: every candidate term with its bound, from the force scale `fs` (N), the
/// velocity scale `vr` (m/s), the cap area `area` (m²), the stroke (m) and the flow and
/// stiffness scales of `scales`.
pub(super) fn term_library(scales: &Scales, fs: f64, vr: f64, area: f64, stroke: f64) -> [Lib; 11] {
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
pub(super) fn check_library(lib: &[Lib]) {
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
pub(super) struct ForceResidual {
    /// Measured minus simulated force (N).
    pub(super) resid: Vec<f64>,
    /// Simulated position (m), or the stiffness origin without a position channel.
    pub(super) x: Vec<f64>,
    /// Simulated velocity (m/s).
    pub(super) v: Vec<f64>,
}

/// The force residual of replay `s` on the first `n_fit` samples of `rec`, when the record has
/// a force channel; `origin` (m) stands in for a missing position channel.
pub(super) fn force_residual_of(
    rec: &Record,
    s: &Replay,
    n_fit: usize,
    origin: f64,
) -> Option<ForceResidual> {
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
pub(super) fn log_cost(jc: &[f64]) -> f64 {
    jc.iter().map(|j| j.max(1e-300).ln()).sum::<f64>() / jc.len().max(1) as f64
}

/// Start of the Dahl term (force F_d in N, travel δ in m): least squares of the force residual
/// `resid` on the Dahl state of the velocity `v` (m/s, period `dt` s), over a log grid of δ from
/// 0.2 % to 50 % of the position scale `xr` (m) (the equation-error estimate of
/// scripts/mts_force_law_check.py).
pub(super) fn dahl_start(v: &[f64], dt: f64, resid: &[f64], xr: f64) -> (f64, f64) {
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
pub(super) fn param_value(h: &Hyp, name: &str) -> Option<f64> {
    h.params
        .iter()
        .position(|p| p.name == name)
        .map(|k| h.values[k])
}

/// Median |p_a − p_b| (Pa) of replay `s` over its first `n_fit` samples while sliding (|v| above
/// `v_min`, m/s); `None` when it never slides.
pub(super) fn median_sliding_pressure(s: &Replay, n_fit: usize, v_min: f64) -> Option<f64> {
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
pub(super) fn yield_force_of(terms: &[Term], dp: Option<f64>) -> Option<f64> {
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
pub(super) fn structure_of(p: Option<PlantParams>, terms: &[Term]) -> String {
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
