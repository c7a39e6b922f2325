//! A test campaign: one load law from many records of a rig or specimen, with coefficients
//! that may depend on declared operating inputs (an MR damper's coil current).
//!
//! Each record's measured motion x(t) is imposed on the rod ([`ehactl_plant::imposed`]), so
//! closed-loop, open-loop and motion-only (displacement-controlled) records all enter the same
//! way: the model predicts the load-cell force from the motion. The law is the rod-force law of
//! `[effects.polynomial_force]` (constant, viscous, yield F_c·tanh(v/v_s), quadratic, stiffness,
//! Dahl's pre-yield hysteresis; the load-pressure terms when every record has p_a and p_b),
//! so the extended config stays runnable by `ehactl run`. A coefficient c of term φ depends on
//! an input i as c₀ + c₁·g(i) with g one of: none, linear (g = i), saturating
//! (g = 1 − exp(−i/i_s), magnetic saturation of an MR coil), quadratic (c₀ + c₁·i + c₂·i²).
//!
//! Given the law's shape (pre-yield travel δ, smoothing velocity v_s, the derivative window
//! that turns x into v), the force is linear in every coefficient, so each fit is linear least
//! squares on the regressors the plant itself evaluates ([`ehactl_plant::imposed::term_series`]),
//! accumulated once per shape as normal equations per record and segment (Ljung, *System
//! Identification* 2nd ed. 1999, eq. 7.34; Gram matrices make each candidate's fit and score
//! cost O(p³), independent of the record length). Every choice is made without the held-out
//! part:
//! - the shape and the terms by the *transfer* error: fitted on the first 60 % of each record's
//!   fitting part, scored on the rest (forward stepwise, a term kept when it lowers that error
//!   by at least [`TERM_MIN_GAIN`]);
//! - the input dependence of each kept term by *leave one operating point out* (fit on every
//!   other operating point, predict the one left out) when the campaign has three or more
//!   operating points; with two, any two-parameter form passes through both, so only "none" vs
//!   "linear" is decided, by the transfer error, and the report says it was not validated
//!   across operating points.
//!
//! The held-out part (the last [`HOLDOUT`] of each record, replayed continuously from its start,
//! or whole validation records) is scored once at the end, per record and pooled, beside the
//! nominal model and a linear ARX black box fitted on the same fitting parts
//! ([`crate::baseline`], input x, output force).
//!
//! The phases, one file each, in the order [`diagnose_campaign`] calls them: `setup.rs` (1:
//! the records prepared, their operating points and groups), `shape.rs` (2: the law's shape
//! and terms), `law.rs` (3: the fitted law, its bootstrap members, its terms ranked),
//! `scoring.rs` (4: every record scored, the band and the envelope); the tools they share:
//! `normal_eq.rs` (regressors, normal equations, sign constraints), `dependence.rs` (the
//! input forms), `travel.rs` (the Dahl shape following an input); `summary.rs` the words.

use crate::baseline;
use crate::data::{Channel, ChannelKind, Record};
pub use crate::motion::{derivative, record_velocity, DEFAULT_VELOCITY_WINDOW, HOLDOUT};
use ehactl_config::RigConfig;
use ehactl_plant::effects::PolynomialForce;
use ehactl_plant::imposed::{term_series, ImposedMotion, LawTerm, Motion};
use ehactl_plant::PlantParams;
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::ops::Range;

/// A term joins the law when it lowers the transfer error J (NRMSE²) by at least this
/// fraction (-).
pub const TERM_MIN_GAIN: f64 = 0.02;
/// Fraction of each fitting part the transfer check fits on (-); the rest is predicted.
pub const TRANSFER_SPLIT: f64 = 0.6;
/// Pre-yield travels δ tried for the Dahl term (m).
pub const DAHL_TRAVELS: [f64; 7] = [1e-5, 2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3];
/// Series-dashpot velocities V of the Dahl term tried (beside V = 0, Dahl's law), as fractions
/// of the campaign's rms velocity (-): the element is driven by v − V·z (Spencer, Dyke, Sain
/// & Carlson 1997, J. Eng. Mech. 123(3):230–238: the dashpot c₁ in series with the Bouc–Wen
/// element), so the force rolls off below V to the pre-yield slope F_d/V.
pub const DAHL_VELOCITY_FRACTIONS: [f64; 5] = [0.025, 0.05, 0.1, 0.2, 0.4];
/// Smoothing velocities v_s of the yield term tried, as fractions of the campaign's rms
/// velocity (-).
pub const SMOOTHING_FRACTIONS: [f64; 6] = [0.02, 0.05, 0.15, 0.4, 0.8, 1.5];

/// Half-widths of the derivative tried, in samples of the campaign's shortest period: a
/// noisy position (a 2 mm sweep read at ±20 µm) needs a wide window, a sharp reversal of a
/// yield force a narrow one, so the window is chosen with the law's shape (by the transfer
/// error) and written to `sensors.position.velocity_window` of the extended config.
pub const VELOCITY_HALF_WIDTHS: [usize; 9] = [1, 2, 3, 4, 6, 8, 12, 16, 24];

/// Relative operating-point spans of the saturating form's scale i_s (× the campaign's largest
/// |input|) tried (-).
pub const SATURATION_SCALES: [f64; 3] = [0.25, 0.5, 1.0];

/// The library of the campaign law (terms that need pressures join only when every record has
/// p_a and p_b).
const LIBRARY: [LawTerm; 8] = LawTerm::ALL;

mod dependence;
mod law;
mod normal_eq;
mod scoring;
mod setup;
mod shape;
mod summary;
mod travel;
pub use dependence::Form;
use dependence::*;
use law::*;
use normal_eq::*;
use scoring::*;
use setup::*;
pub use shape::Shape;
use shape::*;
use summary::*;
pub use travel::TravelDependence;
use travel::*;

/// What a campaign found and how well it predicts.
#[derive(Debug, Clone, Serialize)]
pub struct Campaign {
    /// The leading term and its dependence, e.g. `load-side Dahl yield force 124 N + 1027 N/A·current`.
    pub cause: String,
    /// Plain-words summary (first line: the recommended model against nominal and ARX).
    pub summary: String,
    /// The law's terms with their coefficients (at input 0) and input dependences.
    pub terms: Vec<TermFit>,
    /// The law's shape.
    pub shape: Shape,
    /// The Dahl term's pre-yield travel as a function of the operating input, when one per
    /// operating point predicted the fitting parts better than the shared `shape.dahl_travel`.
    pub travel_dependence: Option<TravelDependence>,
    /// How each kept term's dependence was chosen.
    pub dependence_check: String,
    /// Per record: operating point and held-out NRMSE of nominal, law, ARX.
    pub records: Vec<RecordScore>,
    /// Pooled held-out NRMSE (all held-out samples, each record about its own mean).
    pub pooled: Scores,
    /// Transfer error (NRMSE) of the chosen law on the fitting parts (-).
    pub nrmse_transfer: f64,
    /// Structure of the ARX baseline.
    pub baseline: String,
    /// Notes (inputs taken from the config, warnings of the records).
    pub notes: Vec<String>,
    /// The extended config's closed-loop replays against the nominal one's.
    pub closed_loop: ClosedLoopCheck,
    /// The extended config (the law written into `[effects.polynomial_force]` at the config's
    /// operating point, the dependences into `[inputs.<name>]`).
    #[serde(skip)]
    pub extended: RigConfig,
}

/// One fitted term.
#[derive(Debug, Clone, Serialize)]
pub struct TermFit {
    /// Config path of the coefficient.
    pub path: String,
    /// What it is (e.g. `load-side Dahl yield force`).
    pub name: String,
    /// Unit of the coefficient.
    pub unit: String,
    /// Coefficient at every input zero (SI).
    pub at_zero: f64,
    /// Per input: its form and the coefficients of its basis functions.
    pub dependence: BTreeMap<String, (Form, Vec<f64>)>,
    /// Share of the fitting parts' force variance lost when the term is removed and the rest
    /// refit (-): what ranks the terms.
    pub share: f64,
}

/// Held-out NRMSE of the three models.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Scores {
    /// The config as given.
    pub nominal: f64,
    /// The campaign law.
    pub law: f64,
    /// The linear ARX black box (x → force) fitted on the same fitting parts.
    pub arx: f64,
}

/// One record's result.
#[derive(Debug, Clone, Serialize)]
pub struct RecordScore {
    /// Where it came from.
    pub source: String,
    /// `fit` (its last part held out) or `validation` (whole record held out).
    pub role: String,
    /// Operating point (median per input).
    pub operating_point: BTreeMap<String, f64>,
    /// Samples scored.
    pub scored: (usize, usize),
    /// Force NRMSE on the scored samples.
    pub nrmse: Scores,
    /// Whether the scored samples lie inside the motion and operating inputs the law was
    /// fitted on ([`crate::envelope`]).
    pub envelope: crate::envelope::EnvelopeCheck,
    /// The law's uncertainty band on the scored samples and its coverage ([`crate::band`]).
    pub band: crate::band::BandScore,
}

/// Display name and unit of a term.
fn term_name(t: LawTerm) -> (&'static str, &'static str) {
    match t {
        LawTerm::Constant => ("load-side constant force", "N"),
        LawTerm::Viscous => ("load-side viscous damping", "N·s/m"),
        LawTerm::Coulomb => ("load-side yield force", "N"),
        LawTerm::Quadratic => ("load-side quadratic damping", "N·s²/m²"),
        LawTerm::Stiffness => ("load-side stiffness", "N/m"),
        LawTerm::Pressure => ("load-pressure force", "m²"),
        LawTerm::PressureCoulomb => ("pressure-dependent friction", "m²"),
        LawTerm::Dahl => ("load-side Dahl yield force", "N"),
    }
}

fn path_of(t: LawTerm) -> String {
    format!("effects.polynomial_force.{}", t.field())
}

/// Run a campaign: `fit` records (their last [`HOLDOUT`] held out unless `validation` records
/// are given, which are then held out whole) against the config `cfg`. Phases: the records
/// and what the campaign may fit (`setup`), the law's shape and terms (`choose_shape`),
/// each term's input dependence and the travel per operating point (`fit_law`), each term's
/// share (`rank_terms`), the held-out scores (`score`).
pub fn diagnose_campaign(
    cfg: &RigConfig,
    fit: &[Record],
    validation: &[Record],
) -> Result<Campaign, String> {
    let su = setup(cfg, fit, validation)?;
    let (shape, structure, j_shape) = choose_shape(&su)?;
    let fitted = fit_law(&su, shape, structure, j_shape)?;
    let terms = rank_terms(&su, &fitted);
    let envelope = fitted_envelope(&su, fitted.law.shape.velocity_window);
    let members = bootstrap(&fitted, &su.expanded);
    let spread = Spread {
        members: &members,
        relative_residual: fitted.j_transfer.sqrt(),
    };
    let (records, pooled, baseline) = score(cfg, &su, &fitted.law, &envelope, &spread)?;
    let mut extended = fitted.law.extended(cfg, &su.names)?;
    extended.envelope = Some(envelope);
    extended.band = band_section(cfg, &su.names, &spread)?;
    let closed_loop = closed_loop_check(cfg, &extended, fit.iter().chain(validation));
    let cause = cause_of(&terms, cfg, &su.names);
    let travel = fitted
        .law
        .travel
        .as_ref()
        .map_or(String::new(), |t| format!("\n{}", travel_text(t)));
    let summary = summary_of(
        &cause,
        &pooled,
        &records,
        &terms,
        fitted.law.shape,
        &fitted.dependence_check,
        &baseline,
    ) + &travel
        + "\n"
        + &closed_loop.describe();
    Ok(Campaign {
        cause,
        summary,
        terms,
        shape: fitted.law.shape,
        travel_dependence: fitted.law.travel.clone(),
        dependence_check: fitted.dependence_check,
        records,
        pooled,
        nrmse_transfer: fitted.j_transfer.sqrt(),
        baseline,
        notes: su.notes,
        closed_loop,
        extended,
    })
}

/// The extended config replayed in closed loop (the config's own controller on the record's
/// setpoint `ref`, as `ehactl predict` replays it) beside the nominal config, on every record
/// with a setpoint.
#[derive(Debug, Clone, Serialize)]
pub struct ClosedLoopCheck {
    /// Records replayed in closed loop.
    pub records: usize,
    /// Why the law was dropped: the extended config's replay of a record diverged
    /// ([`crate::predict::check_divergence`]) where the nominal one stayed bounded. `None`:
    /// kept.
    pub dropped: Option<String>,
}

impl ClosedLoopCheck {
    /// One sentence for the summary and the report.
    pub fn describe(&self) -> String {
        match (&self.dropped, self.records) {
            (Some(why), _) => format!("The law is DROPPED and no extended.toml is written: {why}."),
            (None, 0) => "Closed-loop check: no record has a setpoint `ref`, so the extended config was not replayed in closed loop.".into(),
            (None, n) => format!("Closed-loop check: the extended config replayed in closed loop on the {n} record(s) with a setpoint stays within physical bounds (crates/ident/src/predict.rs, check_divergence)."),
        }
    }
}

/// Replay `ext` and `cfg` in closed loop on each record with a setpoint; the first record on
/// which `ext` diverges and `cfg` does not drops the law.
fn closed_loop_check<'r>(
    cfg: &RigConfig,
    ext: &RigConfig,
    records: impl Iterator<Item = &'r Record>,
) -> ClosedLoopCheck {
    let mut n = 0;
    for rec in records.filter(|r| r.reference.is_some()) {
        let run = |c: &RigConfig| crate::predict::predict(c, rec, false, None);
        let Ok(e) = run(ext) else { continue };
        if e.replay != "closed_loop" {
            continue;
        }
        n += 1;
        let Some(d) = e.diverged else { continue };
        if run(cfg).is_ok_and(|p| p.diverged.is_none()) {
            return ClosedLoopCheck {
                records: n,
                dropped: Some(format!(
                    "its closed-loop replay of {} diverged at t = {:.4} s ({}) where the nominal config stays bounded",
                    rec.source, d.t, d.reason
                )),
            };
        }
    }
    ClosedLoopCheck {
        records: n,
        dropped: None,
    }
}

#[cfg(test)]
mod tests;
