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

/// How one coefficient depends on one input.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "form", rename_all = "snake_case")]
pub enum Form {
    /// Constant.
    None,
    /// c₀ + c₁·i.
    Linear,
    /// c₀ + c₁·(1 − exp(−i/scale)), `scale` in the input's unit.
    Saturating {
        /// Saturation scale i_s (input unit).
        scale: f64,
    },
    /// c₀ + c₁·i + c₂·i².
    Quadratic,
}

impl Form {
    /// Basis functions of the input beyond the constant.
    fn basis(self, i: f64) -> [Option<f64>; 2] {
        match self {
            Form::None => [None, None],
            Form::Linear => [Some(i), None],
            Form::Saturating { scale } => [Some(1.0 - (-i / scale).exp()), None],
            Form::Quadratic => [Some(i), Some(i * i)],
        }
    }

    fn parameters(self) -> usize {
        match self {
            Form::None => 0,
            Form::Quadratic => 2,
            _ => 1,
        }
    }

    fn describe(self) -> String {
        match self {
            Form::None => "none".into(),
            Form::Linear => "linear".into(),
            Form::Saturating { scale } => format!("saturating (scale {scale:.4})"),
            Form::Quadratic => "quadratic".into(),
        }
    }
}

/// One record as the campaign uses it.
struct Prepared<'a> {
    rec: &'a Record,
    /// Rod force to explain (N): the load-cell force minus the config's load spring.
    y: Vec<f64>,
    force: &'a [f64],
    x: &'a [f64],
    dp: Option<Vec<f64>>,
    /// Operating input values per sample, in the order of the config's inputs.
    op: Vec<Vec<f64>>,
    /// Median operating point per input.
    at: Vec<f64>,
    /// Operating-point group (index into the campaign's distinct points).
    group: usize,
    /// Samples the law is fitted on (the transfer split inside it) and the held-out samples.
    fit: Range<usize>,
    score: Range<usize>,
    validation: bool,
}

/// A term and its dependence on each input.
#[derive(Debug, Clone, PartialEq)]
struct Structure {
    terms: Vec<(LawTerm, Vec<Form>)>,
}

/// The law's shape: what is not linear in the coefficients.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Shape {
    /// Pre-yield travel δ of the Dahl term (m).
    pub dahl_travel: f64,
    /// Series-dashpot velocity V of the Dahl term (m/s; 0: Dahl's law).
    pub dahl_velocity: f64,
    /// Smoothing velocity v_s of the yield term (m/s).
    pub smoothing_velocity: f64,
    /// Half-width of the derivative turning x into v (s); 0 when every record gives `v`.
    pub velocity_window: f64,
}

/// Normal equations of one segment over every column of the expanded library.
#[derive(Clone)]
struct Normal {
    g: DMatrix<f64>,
    b: DVector<f64>,
    yy: f64,
    ysum: f64,
    n: f64,
}

impl Normal {
    fn zero(p: usize) -> Self {
        Normal {
            g: DMatrix::zeros(p, p),
            b: DVector::zeros(p),
            yy: 0.0,
            ysum: 0.0,
            n: 0.0,
        }
    }

    fn add(&mut self, o: &Normal) {
        self.g += &o.g;
        self.b += &o.b;
        self.yy += o.yy;
        self.ysum += o.ysum;
        self.n += o.n;
    }

    /// Sum of squares about the mean of y (the NRMSE² denominator).
    fn var_sum(&self) -> f64 {
        (self.yy - self.ysum * self.ysum / self.n.max(1.0)).max(1e-300)
    }

    /// Least-squares coefficients on columns `cols` (scaled to unit diagonal, tiny ridge),
    /// each term's coefficient held admissible at the operating points of `ex`
    /// ([`Admissible`], [`crate::signlsq`]).
    fn solve(&self, cols: &[usize], ex: &Expanded) -> Option<DVector<f64>> {
        let p = cols.len();
        if p == 0 {
            return Some(DVector::zeros(0));
        }
        let d: Vec<f64> = cols
            .iter()
            .map(|&c| 1.0 / self.g[(c, c)].max(1e-300).sqrt())
            .collect();
        let mut g = DMatrix::zeros(p, p);
        let mut b = DVector::zeros(p);
        for (r, &cr) in cols.iter().enumerate() {
            b[r] = self.b[cr] * d[r];
            for (c, &cc) in cols.iter().enumerate() {
                g[(r, c)] = self.g[(cr, cc)] * d[r] * d[c];
            }
            g[(r, r)] += 1e-10;
        }
        let (c, h) = constraints(ex, cols, &d);
        let th = crate::signlsq::solve(&g, &b, &c, &h)?;
        Some(DVector::from_iterator(
            p,
            th.iter().zip(&d).map(|(t, s)| t * s),
        ))
    }

    /// Residual sum of squares of coefficients `th` on columns `cols`.
    fn sse(&self, cols: &[usize], th: &DVector<f64>) -> f64 {
        let mut s = self.yy;
        for (r, &cr) in cols.iter().enumerate() {
            s -= 2.0 * th[r] * self.b[cr];
            for (c, &cc) in cols.iter().enumerate() {
                s += th[r] * th[c] * self.g[(cr, cc)];
            }
        }
        s.max(0.0)
    }
}

/// The rows C and offsets h of the admissibility constraints C·θ̃ + h ≥ 0 on the scaled
/// coefficients θ̃ (θ = d·θ̃) of columns `cols`: per bounded term and grid point, the
/// coefficient there, c₀ + Σ c_b·basis_b(i), at least its floor.
fn constraints(ex: &Expanded, cols: &[usize], d: &[f64]) -> (DMatrix<f64>, DVector<f64>) {
    let adm = &ex.admissible;
    let mut terms: Vec<usize> = cols.iter().map(|&c| ex.cols[c].term).collect();
    terms.sort_unstable();
    terms.dedup();
    let (mut rows, mut h) = (Vec::new(), Vec::new());
    for t in terms {
        let Some(floor) = adm.floor.get(t).copied().flatten() else {
            continue;
        };
        for q in &adm.grid {
            rows.extend(cols.iter().zip(d).map(|(&c, s)| {
                let col = ex.cols[c];
                let basis = match col.part {
                    _ if col.term != t => 0.0,
                    None => 1.0,
                    Some((k, slot)) => ex.forms[k][slot / 2].basis(q[k])[slot % 2].unwrap_or(0.0),
                };
                basis * s
            }));
            h.push(-floor);
        }
    }
    (
        DMatrix::from_row_slice(h.len(), cols.len(), &rows),
        DVector::from_vec(h),
    )
}

/// Columns of the expanded library: term × (constant, basis 1, basis 2 per input and form).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Column {
    term: usize,
    /// `None`: the constant part; `Some((input, basis))`.
    part: Option<(usize, usize)>,
}

/// The expanded library for a set of forms per input (one form set for all terms: each term
/// picks which of its columns it uses).
struct Expanded {
    cols: Vec<Column>,
    /// Forms per input whose bases the columns carry: the union used below.
    forms: Vec<Vec<Form>>,
    /// Where each library term's coefficient must stay admissible (see [`Admissible`]).
    admissible: Admissible,
}

/// The sign physics gives the law's coefficients, held at operating points spanning the
/// fitted ones: viscous, yield, quadratic and Dahl forces and pressure-dependent friction
/// dissipate (coefficient ≥ 0), and a passive element's stiffness keeps the total stiffness
/// with the config's load spring ≥ 0 (k + k_load ≥ 0). The constant and the load-pressure
/// area take either sign. Enforced in every least-squares fit of the campaign
/// ([`crate::signlsq`]), so the term selection and the input dependences only ever compare
/// admissible laws.
#[derive(Debug, Clone, Default)]
struct Admissible {
    /// Per library term: the lower bound of its coefficient, −h (h ≥ 0), or `None` if free.
    floor: Vec<Option<f64>>,
    /// Operating points (one value per input) at which the bound is held: the fitted values
    /// and, with one input, 9 points evenly across their range (a quadratic dependence may
    /// dip between the fitted points).
    grid: Vec<Vec<f64>>,
}

impl Admissible {
    fn new(library: &[LawTerm], load_stiffness: f64, fitted: &[Vec<f64>]) -> Self {
        let floor = library
            .iter()
            .map(|t| match t {
                LawTerm::Constant | LawTerm::Pressure => None,
                LawTerm::Stiffness => Some(-load_stiffness.max(0.0)),
                _ => Some(0.0),
            })
            .collect();
        let mut grid: Vec<Vec<f64>> = fitted.to_vec();
        if fitted.first().is_some_and(|p| p.len() == 1) {
            let lo = fitted.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min);
            let hi = fitted
                .iter()
                .map(|p| p[0])
                .fold(f64::NEG_INFINITY, f64::max);
            grid.extend((0..9).map(|k| vec![lo + (hi - lo) * k as f64 / 8.0]));
        }
        if grid.is_empty() {
            grid.push(Vec::new());
        }
        Admissible { floor, grid }
    }
}

/// Per shape: normal equations per record for the transfer-fit segment (A), the
/// transfer-predicted segment (B).
struct ShapeData {
    shape: Shape,
    a: Vec<Normal>,
    b: Vec<Normal>,
}

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

/// What a campaign may fit: its records prepared and grouped by operating point, the law's
/// library and the dependence forms each input allows.
struct Setup<'a> {
    names: Vec<String>,
    /// Unit of each input.
    units: Vec<String>,
    notes: Vec<String>,
    prepared: Vec<Prepared<'a>>,
    /// Operating-point groups with fitted records.
    fit_groups: Vec<usize>,
    library: Vec<LawTerm>,
    /// RMS velocity of the fitting parts (m/s).
    v_rms: f64,
    /// Forms a term may take per input.
    candidate_forms: Vec<Vec<Form>>,
    /// The form per input while the terms are chosen: linear where the campaign allows it.
    default_forms: Vec<Form>,
    /// The library expanded with every candidate form.
    expanded: Expanded,
}

/// Phase 1: prepare the records, group them by operating point, choose the library (the
/// load-pressure terms only when every record has p_a and p_b) and the forms per input.
fn setup<'a>(
    cfg: &RigConfig,
    fit: &'a [Record],
    validation: &'a [Record],
) -> Result<Setup<'a>, String> {
    if fit.is_empty() {
        return Err("a campaign needs at least one --data record".into());
    }
    let names: Vec<String> = cfg.inputs.keys().cloned().collect();
    let mut notes = Vec::new();
    let mut prepared = Vec::new();
    for (rec, val) in fit
        .iter()
        .map(|r| (r, false))
        .chain(validation.iter().map(|r| (r, true)))
    {
        prepared.push(prepare(
            cfg,
            &names,
            rec,
            val,
            !validation.is_empty(),
            &mut notes,
        )?);
    }
    let fit_groups = group_by_point(&mut prepared);
    let has_dp = prepared.iter().all(|p| p.dp.is_some());
    let library: Vec<LawTerm> = LIBRARY
        .iter()
        .copied()
        .filter(|t| has_dp || !t.needs_pressure())
        .collect();
    let v_rms = {
        let v: Vec<f64> = prepared
            .iter()
            .flat_map(|p| record_velocity(p.rec, p.x, 8.0 * p.rec.dt)[p.fit.clone()].to_vec())
            .collect();
        (v.iter().map(|a| a * a).sum::<f64>() / v.len().max(1) as f64).sqrt()
    };
    if !(v_rms > 0.0) {
        return Err("the fitting parts of the records hold no motion (x is constant): a load law cannot be identified from them".into());
    }
    let candidate_forms = forms_per_input(&prepared, names.len());
    let fitted_points: Vec<Vec<f64>> = prepared
        .iter()
        .filter(|p| !p.validation)
        .map(|p| p.at.clone())
        .collect();
    let admissible = Admissible::new(&library, cfg.plant.mechanics.load_stiffness, &fitted_points);
    let expanded = expand(&library, &candidate_forms, &admissible);
    let default_forms: Vec<Form> = candidate_forms
        .iter()
        .map(|f| {
            if f.contains(&Form::Linear) {
                Form::Linear
            } else {
                Form::None
            }
        })
        .collect();
    Ok(Setup {
        units: names.iter().map(|n| cfg.inputs[n].unit.clone()).collect(),
        names,
        notes,
        prepared,
        fit_groups,
        library,
        v_rms,
        candidate_forms,
        default_forms,
        expanded,
    })
}

/// Number each record's distinct operating point (`group`); the groups with fitted records.
fn group_by_point(prepared: &mut [Prepared<'_>]) -> Vec<usize> {
    let mut points: Vec<Vec<f64>> = Vec::new();
    for p in prepared.iter_mut() {
        let g = points
            .iter()
            .position(|q| same_point(q, &p.at))
            .unwrap_or_else(|| {
                points.push(p.at.clone());
                points.len() - 1
            });
        p.group = g;
    }
    let mut g: Vec<usize> = prepared
        .iter()
        .filter(|p| !p.validation)
        .map(|p| p.group)
        .collect();
    g.sort_unstable();
    g.dedup();
    g
}

/// The forms a term may take per input, given the fitting operating points: none, linear
/// (two distinct values), saturating (three), quadratic (four).
fn forms_per_input(prepared: &[Prepared<'_>], inputs: usize) -> Vec<Vec<Form>> {
    (0..inputs)
        .map(|k| {
            let i_max = prepared
                .iter()
                .filter(|p| !p.validation)
                .map(|p| p.at[k].abs())
                .fold(0.0, f64::max);
            let distinct = distinct_values(prepared, k);
            let mut f = vec![Form::None];
            if distinct >= 2 && i_max > 0.0 {
                f.push(Form::Linear);
            }
            if distinct >= 3 && i_max > 0.0 {
                f.extend(
                    SATURATION_SCALES
                        .iter()
                        .map(|s| Form::Saturating { scale: s * i_max }),
                );
            }
            if distinct >= 4 {
                f.push(Form::Quadratic);
            }
            f
        })
        .collect()
}

/// Phase 2: every shape of the grid, its terms chosen by the transfer error with the default
/// forms only (the normal equations' cost grows with the square of the columns; the full
/// expansion of the forms comes for the chosen shape only); the best shape, its structure and
/// its transfer error (NRMSE²).
fn choose_shape(su: &Setup<'_>) -> Result<(Shape, Structure, f64), String> {
    let narrow = expand(
        &su.library,
        &su.default_forms
            .iter()
            .map(|f| vec![*f])
            .collect::<Vec<_>>(),
        &su.expanded.admissible,
    );
    let shapes: Vec<Shape> = shape_grid(su.v_rms, &su.library, &su.prepared);
    let best = try_shapes(su, &narrow, shapes)
        .into_iter()
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .ok_or_else(|| "no law shape could be fitted".to_string())?;
    if !su.library.contains(&LawTerm::Dahl) {
        return Ok(best);
    }
    // The Dahl term behind a series dashpot (V > 0), at the derivative window chosen above:
    // every travel, series velocity and smoothing velocity (the windows are not tried again,
    // which would multiply this stage's cost by their number).
    let series = shape_product(
        &[best.0.velocity_window],
        &DAHL_TRAVELS,
        &DAHL_VELOCITY_FRACTIONS.map(|f| f * su.v_rms),
        &SMOOTHING_FRACTIONS.map(|f| f * su.v_rms),
    );
    Ok(try_shapes(su, &narrow, series)
        .into_iter()
        .chain(std::iter::once(best))
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .expect("one shape at least"))
}

/// Each shape's terms chosen by the transfer error with the default forms; the shapes that
/// share the derivative window and the Dahl shape (travel, series velocity) share the
/// kinematics.
fn try_shapes(
    su: &Setup<'_>,
    narrow: &Expanded,
    shapes: Vec<Shape>,
) -> Vec<(Shape, Structure, f64)> {
    let has_dahl = su.library.contains(&LawTerm::Dahl);
    let mut groups: Vec<Vec<Shape>> = Vec::new();
    for s in shapes {
        match groups.iter_mut().find(|g| {
            g[0].velocity_window == s.velocity_window
                && g[0].dahl_travel == s.dahl_travel
                && g[0].dahl_velocity == s.dahl_velocity
        }) {
            Some(g) => g.push(s),
            None => groups.push(vec![s]),
        }
    }
    groups
        .par_iter()
        .flat_map_iter(|g| {
            let kin = kinematics(&su.prepared, &g[0], has_dahl);
            g.iter()
                .map(|s| {
                    let data = normals(&su.prepared, &su.library, narrow, *s, &kin);
                    let (st, j) = select_terms(&data, &su.library, narrow, &su.default_forms);
                    (*s, st, j)
                })
                .collect::<Vec<_>>()
        })
        .collect()
}

/// What phase 3 hands on.
struct Fitted {
    law: LawFit,
    /// Normal equations of every fitting part, summed.
    all: Normal,
    /// The fitting segments' normal equations (the transfer split's two per record), which
    /// the band's bootstrap resamples.
    segments: Vec<Normal>,
    dependence_check: String,
    /// Transfer error of the final structure (NRMSE²).
    j_transfer: f64,
}

/// Phase 3: each kept term's dependence on each input, the Dahl travel per operating point,
/// then the final least-squares fit on every fitting part (a validation record's fitting
/// segments are empty: it adds nothing there).
fn fit_law(
    su: &Setup<'_>,
    shape: Shape,
    structure: Structure,
    j_shape: f64,
) -> Result<Fitted, String> {
    let (lib, ex) = (&su.library, &su.expanded);
    let has_dahl = lib.contains(&LawTerm::Dahl);
    let kin = kinematics(&su.prepared, &shape, has_dahl);
    let data = normals(&su.prepared, lib, ex, shape, &kin);
    let by_point = |st: &Structure, j: f64| {
        travel_by_point(
            su.v_rms,
            &su.prepared,
            lib,
            ex,
            st,
            shape,
            &su.fit_groups,
            &su.names,
            j,
        )
    };
    // The Dahl shape per operating point first for the selected terms (every coefficient
    // following the input where the campaign allows it: a shape that follows the input is
    // found with coefficients that follow it too), then each term's dependence at that shape;
    // if none was found so, again for the terms with their chosen dependences.
    let j_selected = transfer_error(&data, ex, lib, &structure).unwrap_or(j_shape);
    let (first, data) = match by_point(&structure, j_selected) {
        Some((dep, per_record)) => (Some(dep), per_record),
        None => (None, data),
    };
    let (structure, dependence_check) = choose_dependence(
        &data,
        &su.prepared,
        lib,
        ex,
        structure,
        &su.candidate_forms,
        &su.fit_groups,
        &su.names,
    );
    let j_transfer = transfer_error(&data, ex, lib, &structure).unwrap_or(j_shape);
    let (travel, data, j_transfer) = match first {
        Some(dep) => (Some(dep), data, j_transfer),
        None => match by_point(&structure, j_transfer) {
            Some((dep, per_record)) => {
                let j = dep.nrmse_transfer.powi(2);
                (Some(dep), per_record, j)
            }
            None => (None, data, j_transfer),
        },
    };
    let travel = travel.map(|mut dep| {
        dep.unit = su.units[0].clone();
        dep
    });
    let all: Normal = sum_normals(data.a.iter().chain(&data.b), ex.cols.len());
    let segments: Vec<Normal> = data
        .a
        .iter()
        .chain(&data.b)
        .filter(|n| n.n > 0.0)
        .cloned()
        .collect();
    let cols = columns_of(&structure, ex, lib);
    let theta = all
        .solve(&cols, ex)
        .ok_or("the campaign law's least-squares problem is singular")?;
    Ok(Fitted {
        law: LawFit {
            shape: data.shape,
            travel,
            structure,
            cols,
            theta,
            expanded_cols: ex.cols.clone(),
            forms: ex.forms.clone(),
            library: lib.clone(),
        },
        all,
        segments,
        dependence_check,
        j_transfer,
    })
}

/// The law refitted on [`crate::band::MEMBERS`] bootstrap resamples of its fitting segments
/// (the same structure, shape and admissibility; a resample whose fit fails is left out).
fn bootstrap(f: &Fitted, ex: &Expanded) -> Vec<LawFit> {
    let k = f.segments.len();
    if k < 2 {
        return Vec::new();
    }
    let mut rng = crate::band::SplitMix::new(0x5EED_0000 + k as u64);
    (0..crate::band::MEMBERS)
        .filter_map(|_| {
            let mut sum = Normal::zero(ex.cols.len());
            for _ in 0..k {
                sum.add(&f.segments[rng.below(k)]);
            }
            let theta = sum.solve(&f.law.cols, ex)?;
            Some(LawFit {
                theta,
                ..f.law.clone()
            })
        })
        .collect()
}

/// Phase 4: each term with its coefficients and the share of the force variance it carries
/// (removed and the rest refit), largest first.
fn rank_terms(su: &Setup<'_>, f: &Fitted) -> Vec<TermFit> {
    let law = &f.law;
    let total = f.all.var_sum();
    let base_sse = f.all.sse(&law.cols, &law.theta);
    let mut terms = Vec::new();
    for (ti, (term, forms)) in law.structure.terms.iter().enumerate() {
        let mut without = law.structure.clone();
        without.terms.remove(ti);
        let c2 = columns_of(&without, &su.expanded, &su.library);
        let share = f
            .all
            .solve(&c2, &su.expanded)
            .map_or(1.0, |th| (f.all.sse(&c2, &th) - base_sse).max(0.0) / total);
        let (name, unit) = term_name(*term);
        let mut dependence = BTreeMap::new();
        for (k, fm) in forms.iter().enumerate() {
            if *fm != Form::None {
                dependence.insert(su.names[k].clone(), (*fm, law.basis_coefficients(*term, k)));
            }
        }
        terms.push(TermFit {
            path: path_of(*term),
            name: name.to_string(),
            unit: unit.to_string(),
            at_zero: law.constant_part(*term),
            dependence,
            share,
        });
    }
    terms.sort_by(|a, b| b.share.total_cmp(&a.share));
    terms
}

/// Phase 5: the held-out part of every record predicted by the law, the nominal config and the
/// ARX baseline; per record and pooled (all scored samples, each record about its own mean),
/// with the baseline's structure.
fn score(
    cfg: &RigConfig,
    su: &Setup<'_>,
    law: &LawFit,
    envelope: &ehactl_config::envelope::Envelope,
    spread: &Spread<'_>,
) -> Result<(Vec<RecordScore>, Scores, String), String> {
    let arx = arx_baseline(&su.prepared)?;
    let mut records = Vec::new();
    let (mut sse, mut var, mut sse_nom, mut sse_arx) = (0.0, 0.0, 0.0, 0.0);
    for (p, arx_pred) in su.prepared.iter().zip(&arx.1) {
        if p.score.is_empty() {
            continue;
        }
        let law_pred = law.predict(cfg, p)?;
        let member_preds: Vec<Vec<f64>> = spread
            .members
            .iter()
            .map(|m| m.predict(cfg, p))
            .collect::<Result<_, _>>()?;
        let band = crate::band::band(
            &law_pred,
            &member_preds,
            spread.relative_residual,
            crate::band::LEVEL,
            p.force,
            p.score.clone(),
        );
        let nom_pred = nominal_prediction(cfg, p, &su.names)?;
        let r = p.score.clone();
        let f = &p.force[r.clone()];
        let mean = f.iter().sum::<f64>() / f.len() as f64;
        let v: f64 = f
            .iter()
            .map(|a| (a - mean).powi(2))
            .sum::<f64>()
            .max(1e-300);
        let e = |pred: &[f64]| -> f64 {
            f.iter()
                .zip(&pred[r.clone()])
                .map(|(a, b)| (a - b).powi(2))
                .sum()
        };
        let (el, en, ea) = (e(&law_pred), e(&nom_pred), e(arx_pred));
        sse += el;
        sse_nom += en;
        sse_arx += ea;
        var += v;
        let inputs: BTreeMap<String, f64> =
            su.names.iter().cloned().zip(p.at.iter().copied()).collect();
        let motion =
            crate::envelope::motion_point(p.rec, p.x, r.clone(), law.shape.velocity_window, inputs);
        records.push(RecordScore {
            envelope: crate::envelope::check(envelope, &motion, &cfg.inputs),
            band,
            source: p.rec.source.clone(),
            role: if p.validation { "validation" } else { "fit" }.into(),
            operating_point: su.names.iter().cloned().zip(p.at.iter().copied()).collect(),
            scored: (r.start, r.end),
            nrmse: Scores {
                nominal: (en / v).sqrt(),
                law: (el / v).sqrt(),
                arx: (ea / v).sqrt(),
            },
        });
    }
    let pooled = Scores {
        nominal: (sse_nom / var).sqrt(),
        law: (sse / var).sqrt(),
        arx: (sse_arx / var).sqrt(),
    };
    Ok((records, pooled, arx.0))
}

/// The law's bootstrap refits and its out-of-sample relative residual (the band's inputs).
struct Spread<'m> {
    members: &'m [LawFit],
    relative_residual: f64,
}

/// The `[band]` section of the extended config: each member as the law and dependences it
/// writes.
fn band_section(
    cfg: &RigConfig,
    names: &[String],
    spread: &Spread<'_>,
) -> Result<Option<ehactl_config::envelope::Band>, String> {
    if spread.members.is_empty() {
        return Ok(None);
    }
    // A member whose law the config cannot hold (a parameter out of its range) is left out.
    let members: Vec<_> = spread
        .members
        .iter()
        .filter_map(|m| {
            let c = m.extended(cfg, names).ok()?;
            ehactl_config::envelope::BandMember::of(&c)
        })
        .collect();
    if members.len() < 2 {
        return Ok(None);
    }
    Ok(Some(ehactl_config::envelope::Band {
        level: crate::band::LEVEL,
        relative_residual: spread.relative_residual,
        members,
    }))
}

/// The motion and operating inputs of the fitting parts, merged per operating point
/// (`[envelope]` of the extended config).
fn fitted_envelope(su: &Setup<'_>, window: f64) -> ehactl_config::envelope::Envelope {
    crate::envelope::merge(
        su.prepared
            .iter()
            .filter(|p| !p.validation && !p.fit.is_empty())
            .map(|p| {
                let inputs = su.names.iter().cloned().zip(p.at.iter().copied()).collect();
                crate::envelope::motion_point(p.rec, p.x, p.fit.clone(), window, inputs)
            })
            .collect(),
    )
}

fn same_point(a: &[f64], b: &[f64]) -> bool {
    a.iter()
        .zip(b)
        .all(|(x, y)| (x - y).abs() <= 1e-9 * x.abs().max(y.abs()).max(1.0))
}

fn distinct_values(prepared: &[Prepared<'_>], k: usize) -> usize {
    let mut v: Vec<f64> = prepared
        .iter()
        .filter(|p| !p.validation)
        .map(|p| p.at[k])
        .collect();
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| same_point(&[*a], &[*b]));
    v.len()
}

fn prepare<'a>(
    cfg: &RigConfig,
    names: &[String],
    rec: &'a Record,
    validation: bool,
    whole_fit: bool,
    notes: &mut Vec<String>,
) -> Result<Prepared<'a>, String> {
    let src = &rec.source;
    let x = rec
        .channel(ChannelKind::Position)
        .ok_or_else(|| format!("{src}: a campaign imposes each record's measured motion on the rod and needs the position column `x` (m)"))?;
    let force = rec.channel(ChannelKind::Force).ok_or_else(|| {
        format!("{src}: a campaign predicts the load-cell force and needs the column `force` (N)")
    })?;
    let mut op = Vec::new();
    let mut at = Vec::new();
    for name in names {
        let inp = &cfg.inputs[name];
        match rec.input(name) {
            Some(v) => {
                at.push(rec.input_median(name).unwrap_or(inp.value));
                op.push(v.to_vec());
            }
            None => {
                notes.push(format!(
                    "{src}: no `{name}` column; taken at the config's operating point {} {}",
                    inp.value, inp.unit
                ));
                at.push(inp.value);
                op.push(vec![inp.value; rec.len()]);
            }
        }
    }
    let n = rec.len();
    let (fit, score) = if validation {
        (0..0, 0..n)
    } else if whole_fit {
        (0..n, 0..0)
    } else {
        let nf = ((1.0 - HOLDOUT) * n as f64).round() as usize;
        if nf < 20 || n - nf < 10 {
            return Err(format!(
                "{src}: {n} samples are too few to hold out {:.0} %",
                HOLDOUT * 100.0
            ));
        }
        (0..nf, nf..n)
    };
    let p = &cfg.plant;
    let y: Vec<f64> = force
        .iter()
        .zip(x)
        .map(|(f, xk)| f - p.mechanics.load_stiffness * (xk - p.mechanics.load_contact_position))
        .collect();
    let dp = match (
        rec.channel(ChannelKind::PressureA),
        rec.channel(ChannelKind::PressureB),
    ) {
        (Some(a), Some(b)) => Some(a.iter().zip(b).map(|(a, b)| a - b).collect()),
        _ => None,
    };
    Ok(Prepared {
        rec,
        y,
        force,
        x,
        dp,
        op,
        at,
        group: 0,
        fit,
        score,
        validation,
    })
}

fn expand(library: &[LawTerm], forms: &[Vec<Form>], admissible: &Admissible) -> Expanded {
    let mut cols = Vec::new();
    for ti in 0..library.len() {
        cols.push(Column {
            term: ti,
            part: None,
        });
        for (k, fs) in forms.iter().enumerate() {
            for (fi, f) in fs.iter().enumerate() {
                for b in 0..f.parameters() {
                    cols.push(Column {
                        term: ti,
                        part: Some((k, fi * 2 + b)),
                    });
                }
            }
        }
    }
    Expanded {
        cols,
        forms: forms.to_vec(),
        admissible: admissible.clone(),
    }
}

fn shape_grid(v_rms: f64, library: &[LawTerm], prepared: &[Prepared<'_>]) -> Vec<Shape> {
    let travels: Vec<f64> = if library.contains(&LawTerm::Dahl) {
        DAHL_TRAVELS.to_vec()
    } else {
        vec![PolynomialForce::zero().dahl_travel]
    };
    let windows: Vec<f64> = if prepared.iter().all(|p| p.rec.velocity.is_some()) {
        vec![0.0]
    } else {
        let dt = prepared
            .iter()
            .map(|p| p.rec.dt)
            .fold(f64::INFINITY, f64::min);
        VELOCITY_HALF_WIDTHS
            .iter()
            .map(|m| *m as f64 * dt)
            .collect()
    };
    shape_product(
        &windows,
        &travels,
        &[0.0],
        &SMOOTHING_FRACTIONS.map(|f| f * v_rms),
    )
}

/// Every shape of the given derivative windows (s), Dahl travels δ (m), series-dashpot
/// velocities V (m/s) and smoothing velocities v_s (m/s), in that order of nesting.
fn shape_product(
    windows: &[f64],
    travels: &[f64],
    dahl_velocities: &[f64],
    smoothings: &[f64],
) -> Vec<Shape> {
    let mut out = Vec::new();
    for &velocity_window in windows {
        for &dahl_travel in travels {
            for &dahl_velocity in dahl_velocities {
                for &smoothing_velocity in smoothings {
                    out.push(Shape {
                        dahl_travel,
                        dahl_velocity,
                        smoothing_velocity,
                        velocity_window,
                    });
                }
            }
        }
    }
    out
}

/// The Dahl term's shape depending on one operating input i: the pre-yield travel
/// δ(i) = δ₀ + δ₁·i and the series-dashpot velocity V(i) = V₀ + V₁·i, through the pairs
/// (δ, V) chosen per fitted operating point (least squares over the points). Published models
/// of MR dampers let a shape parameter follow the current as well (Quiroz, UTFSM 2022, ch. 7:
/// β of the Bouc–Wen model exponential in i; in Spencer et al. 1997 the roll-off velocity of
/// the series dashpot, α·z/(c₀ + c₁), grows with α, affine in the coil input); kept only when
/// it lowers the transfer error of the shared shape by [`TERM_MIN_GAIN`].
#[derive(Debug, Clone, Serialize)]
pub struct TravelDependence {
    /// The input (a declared `[inputs]` name).
    pub input: String,
    /// The input's unit (its `[inputs.<name>] unit`).
    pub unit: String,
    /// δ₀ (m): the travel at i = 0.
    pub at_zero: f64,
    /// δ₁ (m per unit of the input).
    pub slope: f64,
    /// V₀ (m/s): the series-dashpot velocity at i = 0.
    pub velocity_at_zero: f64,
    /// V₁ (m/s per unit of the input).
    pub velocity_slope: f64,
    /// The travel and series velocity chosen per fitted operating point (input value, δ in
    /// m, V in m/s).
    pub per_point: Vec<(f64, f64, f64)>,
    /// Transfer error (NRMSE) with the shared shape, and with δ(i), V(i) (-).
    pub nrmse_transfer_shared: f64,
    /// See `nrmse_transfer_shared`.
    pub nrmse_transfer: f64,
    /// Largest series velocity searched (m/s): V(i) is kept within [0, this].
    #[serde(skip)]
    velocity_max: f64,
}

impl TravelDependence {
    /// δ (m) and V (m/s) at input value `i`, kept within the values the campaign searches
    /// (within the fitted operating points they always are; the extended config's linear
    /// dependence is not clamped beyond them).
    fn at(&self, i: f64) -> (f64, f64) {
        (
            (self.at_zero + self.slope * i)
                .clamp(DAHL_TRAVELS[0], DAHL_TRAVELS[DAHL_TRAVELS.len() - 1]),
            (self.velocity_at_zero + self.velocity_slope * i).clamp(0.0, self.velocity_max),
        )
    }

    /// Whether δ, V follow the input.
    fn travel_varies(&self) -> bool {
        self.slope != 0.0
    }

    fn velocity_varies(&self) -> bool {
        self.velocity_slope != 0.0
    }
}

/// Per-record normal equations with record `r` at the Dahl shape `dahl[r]` (δ m, V m/s).
fn normals_at_travels(
    prepared: &[Prepared<'_>],
    library: &[LawTerm],
    expanded: &Expanded,
    shape: Shape,
    dahl: &[(f64, f64)],
) -> ShapeData {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for (r, (d, vd)) in dahl.iter().enumerate() {
        let one = std::slice::from_ref(&prepared[r]);
        let sh = Shape {
            dahl_travel: *d,
            dahl_velocity: *vd,
            ..shape
        };
        let kin = kinematics(one, &sh, true);
        let mut n = normals(one, library, expanded, sh, &kin);
        a.append(&mut n.a);
        b.append(&mut n.b);
    }
    ShapeData { shape, a, b }
}

/// Least-squares line through points (i, y): (value at 0, slope); exact through two.
fn line_through(pts: &[(f64, f64)]) -> (f64, f64) {
    let n = pts.len() as f64;
    let (mi, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sii: f64 = pts.iter().map(|p| (p.0 - mi).powi(2)).sum();
    let slope = if sii > 0.0 {
        pts.iter().map(|p| (p.0 - mi) * (p.1 - my)).sum::<f64>() / sii
    } else {
        0.0
    };
    (my - slope * mi, slope)
}

/// The Dahl term's shape per fitted operating point (one declared input, two or more fitted
/// points): coordinate descent over the points on the grid of pairs (δ, V) — the travels of
/// [`DAHL_TRAVELS`] next to the shared one (and it) × (0 and [`DAHL_VELOCITY_FRACTIONS`] of
/// the rms velocity `v_rms`) — by the transfer error,
/// then δ(i) and V(i) by least squares through them, refit and kept if the transfer error
/// falls by [`TERM_MIN_GAIN`] against the shared shape (`j_shared`, NRMSE²). Returns the
/// dependence and the per-record normal equations at each record's δ(i), V(i).
#[allow(clippy::too_many_arguments)]
fn travel_by_point(
    v_rms: f64,
    prepared: &[Prepared<'_>],
    library: &[LawTerm],
    expanded: &Expanded,
    structure: &Structure,
    shape: Shape,
    fit_groups: &[usize],
    names: &[String],
    j_shared: f64,
) -> Option<(TravelDependence, ShapeData)> {
    if names.len() != 1
        || fit_groups.len() < 2
        || !structure.terms.iter().any(|t| t.0 == LawTerm::Dahl)
    {
        return None;
    }
    let velocities: Vec<f64> = std::iter::once(0.0)
        .chain(DAHL_VELOCITY_FRACTIONS.iter().map(|f| f * v_rms))
        .collect();
    // Travels within one step of the grid of the shared one (the cost of each pair is a set of
    // normal equations on the full expansion of the forms, for every record).
    let at = DAHL_TRAVELS
        .iter()
        .position(|d| *d == shape.dahl_travel)
        .unwrap_or(0);
    let travels = &DAHL_TRAVELS[at.saturating_sub(1)..(at + 2).min(DAHL_TRAVELS.len())];
    let pairs: Vec<(f64, f64)> = travels
        .iter()
        .flat_map(|d| velocities.iter().map(move |v| (*d, *v)))
        .collect();
    let grid: Vec<ShapeData> = pairs
        .par_iter()
        .map(|(d, vd)| {
            let sh = Shape {
                dahl_travel: *d,
                dahl_velocity: *vd,
                ..shape
            };
            let kin = kinematics(prepared, &sh, true);
            normals(prepared, library, expanded, sh, &kin)
        })
        .collect();
    // The shared shape's pair (the series velocity of the second stage of `choose_shape` is
    // on the same grid of fractions).
    let start = pairs
        .iter()
        .position(|(d, vd)| {
            *d == shape.dahl_travel && (vd - shape.dahl_velocity).abs() <= 1e-12 * v_rms
        })
        .unwrap_or(0);
    let mut choice: Vec<usize> = vec![start; fit_groups.len()];
    let mixed = |choice: &[usize]| -> ShapeData {
        let pick = |r: usize| {
            let g = fit_groups.iter().position(|g| *g == prepared[r].group);
            &grid[g.map_or(start, |g| choice[g])]
        };
        ShapeData {
            shape,
            a: (0..prepared.len()).map(|r| pick(r).a[r].clone()).collect(),
            b: (0..prepared.len()).map(|r| pick(r).b[r].clone()).collect(),
        }
    };
    for _pass in 0..2 {
        for g in 0..fit_groups.len() {
            // Each pair's transfer error once (a comparator would recompute both sides).
            let (best, _) = (0..grid.len())
                .map(|k| {
                    let mut c = choice.clone();
                    c[g] = k;
                    let j = transfer_error(&mixed(&c), expanded, library, structure);
                    (k, j.unwrap_or(f64::INFINITY))
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))?;
            choice[g] = best;
        }
    }
    let pts: Vec<(f64, f64, f64)> = fit_groups
        .iter()
        .zip(&choice)
        .map(|(g, k)| {
            let i = prepared
                .iter()
                .find(|p| p.group == *g)
                .map_or(0.0, |p| p.at[0]);
            (i, pairs[*k].0, pairs[*k].1)
        })
        .collect();
    let (at_zero, slope) = line_through(&pts.iter().map(|p| (p.0, p.1)).collect::<Vec<_>>());
    let (velocity_at_zero, velocity_slope) =
        line_through(&pts.iter().map(|p| (p.0, p.2)).collect::<Vec<_>>());
    let mut dep = TravelDependence {
        input: names[0].clone(),
        unit: String::new(),
        at_zero,
        slope,
        velocity_at_zero,
        velocity_slope,
        per_point: pts,
        nrmse_transfer_shared: j_shared.sqrt(),
        nrmse_transfer: f64::NAN,
        velocity_max: velocities[velocities.len() - 1],
    };
    let dahl: Vec<(f64, f64)> = prepared.iter().map(|p| dep.at(p.at[0])).collect();
    let data = normals_at_travels(prepared, library, expanded, shape, &dahl);
    let j = transfer_error(&data, expanded, library, structure)?;
    dep.nrmse_transfer = j.sqrt();
    (j < (1.0 - TERM_MIN_GAIN) * j_shared).then_some((dep, data))
}

fn shape_law(shape: Shape) -> PolynomialForce {
    PolynomialForce {
        dahl_travel: shape.dahl_travel,
        dahl_velocity: shape.dahl_velocity,
        smoothing_velocity: shape.smoothing_velocity,
        origin: 0.0,
        ..PolynomialForce::zero()
    }
}

/// Velocity (m/s) and Dahl state (-) of every record at one derivative window and Dahl shape
/// (pre-yield travel, series velocity): shared by the shapes that differ only in the
/// smoothing velocity.
struct Kinematics {
    v: Vec<Vec<f64>>,
    z: Vec<Vec<f64>>,
}

fn kinematics(prepared: &[Prepared<'_>], shape: &Shape, dahl: bool) -> Kinematics {
    let law = PolynomialForce {
        dahl_travel: shape.dahl_travel,
        dahl_velocity: shape.dahl_velocity,
        ..PolynomialForce::zero()
    };
    let v: Vec<Vec<f64>> = prepared
        .iter()
        .map(|p| record_velocity(p.rec, p.x, shape.velocity_window))
        .collect();
    let z = prepared
        .iter()
        .zip(&v)
        .map(|(p, v)| {
            if !dahl {
                return Vec::new();
            }
            ehactl_plant::imposed::dahl_state(
                &law,
                &Motion {
                    dt: p.rec.dt,
                    x: p.x,
                    v,
                    dp: None,
                },
            )
        })
        .collect();
    Kinematics { v, z }
}

/// Regressor columns of record `p` at `shape` (each expanded column's series), with its
/// velocity `v` and Dahl state `z` at that shape.
fn regressors(
    p: &Prepared<'_>,
    library: &[LawTerm],
    expanded: &Expanded,
    shape: Shape,
    v: &[f64],
    z: &[f64],
) -> Vec<Vec<f64>> {
    let law = shape_law(shape);
    let m = Motion {
        dt: p.rec.dt,
        x: p.x,
        v,
        dp: p.dp.as_deref(),
    };
    let base: Vec<Vec<f64>> = library
        .iter()
        .map(|t| match t {
            LawTerm::Dahl => z.to_vec(),
            _ => term_series(*t, &law, &m).unwrap_or_else(|| vec![0.0; p.x.len()]),
        })
        .collect();
    expanded
        .cols
        .iter()
        .map(|c| match c.part {
            None => base[c.term].clone(),
            Some((k, slot)) => {
                let f = expanded.forms[k][slot / 2];
                base[c.term]
                    .iter()
                    .zip(&p.op[k])
                    .map(|(phi, i)| phi * f.basis(*i)[slot % 2].unwrap_or(0.0))
                    .collect()
            }
        })
        .collect()
}

/// Normal equations ΦᵀΦ, Φᵀy of the regressor columns `cols` on samples `r` (nalgebra's
/// matrix product).
fn normal_of(cols: &[Vec<f64>], y: &[f64], r: Range<usize>) -> Normal {
    let p = cols.len();
    let rows = r.len();
    let phi = DMatrix::from_fn(rows, p, |i, j| cols[j][r.start + i]);
    let yv = DVector::from_fn(rows, |i, _| y[r.start + i]);
    let ys = &y[r];
    Normal {
        g: phi.tr_mul(&phi),
        b: phi.tr_mul(&yv),
        yy: ys.iter().map(|v| v * v).sum(),
        ysum: ys.iter().sum(),
        n: rows as f64,
    }
}

fn normals(
    prepared: &[Prepared<'_>],
    library: &[LawTerm],
    expanded: &Expanded,
    shape: Shape,
    kin: &Kinematics,
) -> ShapeData {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for (i, p) in prepared.iter().enumerate() {
        let z = kin.z.get(i).map_or(&[][..], Vec::as_slice);
        let cols = regressors(p, library, expanded, shape, &kin.v[i], z);
        let split = p.fit.start + ((p.fit.len() as f64) * TRANSFER_SPLIT).round() as usize;
        a.push(normal_of(&cols, &p.y, p.fit.start..split));
        b.push(normal_of(&cols, &p.y, split..p.fit.end));
    }
    ShapeData { shape, a, b }
}

fn sum_normals<'n>(it: impl Iterator<Item = &'n Normal>, p: usize) -> Normal {
    let mut s = Normal::zero(p);
    for n in it {
        s.add(n);
    }
    s
}

/// Columns a structure uses.
fn columns_of(st: &Structure, ex: &Expanded, library: &[LawTerm]) -> Vec<usize> {
    let mut out = Vec::new();
    for (term, forms) in &st.terms {
        let ti = library.iter().position(|t| t == term).unwrap_or(usize::MAX);
        for (ci, c) in ex.cols.iter().enumerate() {
            if c.term != ti {
                continue;
            }
            let keep = match c.part {
                None => true,
                Some((k, slot)) => ex.forms[k].get(slot / 2) == Some(&forms[k]),
            };
            if keep {
                out.push(ci);
            }
        }
    }
    out
}

/// Transfer error J: fit on segments A of every record, predict segments B; the mean over
/// records of each record's NRMSE² (every record counts the same, whatever its force level:
/// a 0 A test of an MR damper weighs as much as a 1 A one).
fn transfer_error(
    d: &ShapeData,
    ex: &Expanded,
    library: &[LawTerm],
    st: &Structure,
) -> Option<f64> {
    let p = ex.cols.len();
    let a = sum_normals(d.a.iter(), p);
    let cols = columns_of(st, ex, library);
    let th = a.solve(&cols, ex)?;
    let per: Vec<f64> =
        d.b.iter()
            .filter(|b| b.n > 0.0)
            .map(|b| b.sse(&cols, &th) / b.var_sum())
            .collect();
    Some(per.iter().sum::<f64>() / per.len().max(1) as f64)
}

fn select_terms(
    d: &ShapeData,
    library: &[LawTerm],
    ex: &Expanded,
    default_forms: &[Form],
) -> (Structure, f64) {
    let mut st = Structure { terms: vec![] };
    let mut j = transfer_error(d, ex, library, &st).unwrap_or(1.0);
    loop {
        let best = library
            .iter()
            .filter(|t| !st.terms.iter().any(|(u, _)| u == *t))
            .filter_map(|t| {
                let mut s = st.clone();
                s.terms.push((*t, default_forms.to_vec()));
                transfer_error(d, ex, library, &s).map(|e| (s, e))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some((s, e)) if e < (1.0 - TERM_MIN_GAIN) * j => {
                st = s;
                j = e;
            }
            _ => break,
        }
    }
    (st, j)
}

/// Leave-one-operating-point-out error: per operating point, fit on every other one and
/// predict its records; the mean over records of their NRMSE² (`None` when a fold cannot be
/// fitted).
fn loco_error(
    d: &ShapeData,
    prepared: &[Prepared<'_>],
    ex: &Expanded,
    library: &[LawTerm],
    st: &Structure,
    groups: &[usize],
) -> Option<f64> {
    let p = ex.cols.len();
    let cols = columns_of(st, ex, library);
    let mut per = Vec::new();
    for &g in groups {
        let mut train = Normal::zero(p);
        for (i, pr) in prepared.iter().enumerate() {
            if !pr.validation && pr.group != g {
                train.add(&d.a[i]);
                train.add(&d.b[i]);
            }
        }
        let th = train.solve(&cols, ex)?;
        for (i, pr) in prepared.iter().enumerate() {
            if !pr.validation && pr.group == g {
                let mut test = d.a[i].clone();
                test.add(&d.b[i]);
                per.push(test.sse(&cols, &th) / test.var_sum());
            }
        }
    }
    Some(per.iter().sum::<f64>() / per.len().max(1) as f64)
}

#[allow(clippy::too_many_arguments)]
fn choose_dependence(
    d: &ShapeData,
    prepared: &[Prepared<'_>],
    library: &[LawTerm],
    ex: &Expanded,
    mut st: Structure,
    candidates: &[Vec<Form>],
    groups: &[usize],
    names: &[String],
) -> (Structure, String) {
    if names.is_empty() {
        return (st, "no operating inputs declared".into());
    }
    let by_loco = groups.len() >= 3;
    let score = |s: &Structure| -> f64 {
        let e = if by_loco {
            loco_error(d, prepared, ex, library, s, groups)
        } else {
            transfer_error(d, ex, library, s)
        };
        e.unwrap_or(f64::INFINITY)
    };
    // Greedy moves from two starts — no dependence, and the selection's (linear in every input
    // where the campaign allows it) — each move changing one term's form in one input, kept
    // while it lowers the score by at least 1 % (a parameter must earn its place); the better
    // end point wins.
    let selected = st.clone();
    for t in st.terms.iter_mut() {
        t.1 = vec![Form::None; names.len()];
    }
    let start = score(&st);
    let (a, ea) = descend(st, start, candidates, &score);
    let s1 = score(&selected);
    let (b, eb) = descend(selected, s1, candidates, &score);
    let (st, best) = if eb < ea { (b, eb) } else { (a, ea) };
    let how = if by_loco {
        format!(
            "by leaving one operating point out ({} points): rms over records of the NRMSE on the point left out {:.4} without any dependence, {:.4} with the chosen ones",
            groups.len(),
            start.sqrt(),
            best.sqrt()
        )
    } else if groups.len() == 2 {
        format!(
            "by the transfer error only (transfer NRMSE {:.4} without, {:.4} with): with two operating points any two-parameter form passes through both, so the dependence is NOT validated across operating points; a third operating point would test it",
            start.sqrt(),
            best.sqrt()
        )
    } else {
        "one operating point: no dependence can be identified".into()
    };
    (st, how)
}

/// Greedy descent over the forms from `st` (score `best`): each step takes the single change
/// of one term's form in one input that lowers `score` most, if by at least 1 %.
fn descend(
    mut st: Structure,
    mut best: f64,
    candidates: &[Vec<Form>],
    score: &dyn Fn(&Structure) -> f64,
) -> (Structure, f64) {
    loop {
        let mut improved: Option<(Structure, f64)> = None;
        for ti in 0..st.terms.len() {
            for (k, forms) in candidates.iter().enumerate() {
                for f in forms {
                    if *f == st.terms[ti].1[k] {
                        continue;
                    }
                    let mut s = st.clone();
                    s.terms[ti].1[k] = *f;
                    let e = score(&s);
                    if e < 0.99 * improved.as_ref().map_or(best, |i| i.1) {
                        improved = Some((s, e));
                    }
                }
            }
        }
        match improved {
            Some((s, e)) => {
                st = s;
                best = e;
            }
            None => break,
        }
    }
    (st, best)
}

/// The fitted law.
#[derive(Clone)]
struct LawFit {
    shape: Shape,
    /// The Dahl travel's dependence on the input, if kept (else `shape.dahl_travel`).
    travel: Option<TravelDependence>,
    structure: Structure,
    cols: Vec<usize>,
    theta: DVector<f64>,
    expanded_cols: Vec<Column>,
    forms: Vec<Vec<Form>>,
    library: Vec<LawTerm>,
}

impl LawFit {
    fn coefficient_of(&self, term: LawTerm, part: Option<(usize, usize)>) -> f64 {
        let ti = self.library.iter().position(|t| *t == term);
        self.cols
            .iter()
            .zip(self.theta.iter())
            .find(|(c, _)| {
                let col = self.expanded_cols[**c];
                Some(col.term) == ti && col.part == part
            })
            .map_or(0.0, |(_, v)| *v)
    }

    fn constant_part(&self, term: LawTerm) -> f64 {
        self.coefficient_of(term, None)
    }

    /// The forms (one per input) of a term of the law.
    fn forms_of(&self, term: LawTerm) -> &[Form] {
        &self
            .structure
            .terms
            .iter()
            .find(|t| t.0 == term)
            .expect("term in structure")
            .1
    }

    /// Coefficients of the basis functions of input `k` for `term`.
    fn basis_coefficients(&self, term: LawTerm, k: usize) -> Vec<f64> {
        let forms = self.forms_of(term);
        let fi = self.forms[k]
            .iter()
            .position(|f| *f == forms[k])
            .unwrap_or(0);
        (0..forms[k].parameters())
            .map(|b| self.coefficient_of(term, Some((k, fi * 2 + b))))
            .collect()
    }

    /// Coefficient of `term` at operating point `at` (per input).
    fn coefficient_at(&self, term: LawTerm, at: &[f64]) -> f64 {
        let forms = self.forms_of(term);
        let mut c = self.constant_part(term);
        for (k, f) in forms.iter().enumerate() {
            let basis = f.basis(at[k]);
            for (b, coef) in self.basis_coefficients(term, k).iter().enumerate() {
                c += coef * basis[b].unwrap_or(0.0);
            }
        }
        c
    }

    /// The shape at operating point `at` (the Dahl travel δ(i) and series velocity V(i) when
    /// they depend on the input).
    fn shape_at(&self, at: &[f64]) -> Shape {
        let (dahl_travel, dahl_velocity) = self
            .travel
            .as_ref()
            .map_or((self.shape.dahl_travel, self.shape.dahl_velocity), |t| {
                t.at(at[0])
            });
        Shape {
            dahl_travel,
            dahl_velocity,
            ..self.shape
        }
    }

    /// The law at operating point `at`.
    fn law_at(&self, at: &[f64]) -> PolynomialForce {
        let mut law = shape_law(self.shape_at(at));
        for (term, _) in &self.structure.terms {
            law = term.with(law, self.coefficient_at(*term, at));
        }
        law
    }

    /// Force prediction along record `p` (time-varying inputs followed sample by sample).
    fn predict(&self, cfg: &RigConfig, p: &Prepared<'_>) -> Result<Vec<f64>, String> {
        let v = record_velocity(p.rec, p.x, self.shape.velocity_window);
        let m = Motion {
            dt: p.rec.dt,
            x: p.x,
            v: &v,
            dp: p.dp.as_deref(),
        };
        // The record's own travel (at its median operating point), as `ehactl predict` takes
        // the extended config at it.
        let law0 = shape_law(self.shape_at(&p.at));
        let pm = &cfg.plant.mechanics;
        let mut f: Vec<f64> =
            p.x.iter()
                .map(|x| pm.load_stiffness * (x - pm.load_contact_position))
                .collect();
        for (term, _) in &self.structure.terms {
            let s = term_series(*term, &law0, &m)
                .ok_or_else(|| format!("{}: the law needs p_a and p_b", p.rec.source))?;
            for (k, (fk, sk)) in f.iter_mut().zip(s).enumerate() {
                let at: Vec<f64> = p.op.iter().map(|o| o[k]).collect();
                *fk += self.coefficient_at(*term, &at) * sk;
            }
        }
        Ok(f)
    }

    /// The config extended with the law at its own operating point and the dependences as
    /// local derivatives there ([`ehactl_config::inputs`]).
    fn extended(&self, cfg: &RigConfig, names: &[String]) -> Result<RigConfig, String> {
        let mut out = cfg.clone();
        let at0: Vec<f64> = names.iter().map(|n| cfg.inputs[n].value).collect();
        out.plant.effects.polynomial_force = Some(self.law_at(&at0));
        out.plant.sensors.position.velocity_window = self.shape.velocity_window;
        for (k, name) in names.iter().enumerate() {
            let inp = out.inputs.get_mut(name).expect("declared");
            inp.linear
                .retain(|p, _| !p.starts_with("effects.polynomial_force."));
            inp.quadratic
                .retain(|p, _| !p.starts_with("effects.polynomial_force."));
            inp.saturating
                .retain(|p, _| !p.starts_with("effects.polynomial_force."));
            let i0 = at0[k];
            if let Some(t) = &self.travel {
                inp.linear
                    .insert("effects.polynomial_force.dahl_travel".into(), t.slope);
                if t.velocity_varies() {
                    inp.linear.insert(
                        "effects.polynomial_force.dahl_velocity".into(),
                        t.velocity_slope,
                    );
                }
            }
            for (term, forms) in &self.structure.terms {
                let c = self.basis_coefficients(*term, k);
                // About i₀: the linear and quadratic forms exactly as Taylor terms, the
                // saturating one as itself (`[inputs.<name>.saturating]`): a second-order
                // Taylor form of 1 − e^(−i/i_s) turns negative within a few i_s of i₀.
                let (a, b) = match forms[k] {
                    Form::None => continue,
                    Form::Linear => (c[0], 0.0),
                    Form::Quadratic => (c[0] + 2.0 * c[1] * i0, c[1]),
                    Form::Saturating { scale } => {
                        inp.saturating.insert(
                            path_of(*term),
                            ehactl_config::inputs::Saturating { gain: c[0], scale },
                        );
                        continue;
                    }
                };
                inp.linear.insert(path_of(*term), a);
                if b != 0.0 {
                    inp.quadratic.insert(path_of(*term), b);
                }
            }
        }
        out.validate()
            .map_err(|e| format!("the extended config is not valid: {e}"))?;
        Ok(out)
    }
}

/// The nominal model's force along record `p`: the config at the record's operating point.
fn nominal_prediction(
    cfg: &RigConfig,
    p: &Prepared<'_>,
    names: &[String],
) -> Result<Vec<f64>, String> {
    let at: BTreeMap<String, f64> = names.iter().cloned().zip(p.at.iter().copied()).collect();
    let plant: PlantParams = ehactl_config::inputs::plant_at(&cfg.inputs, &cfg.plant, &at)?;
    let im = ImposedMotion::new(&plant).map_err(|e| format!("{}: {e}", p.rec.source))?;
    let v = record_velocity(p.rec, p.x, plant.sensors.position.velocity_window);
    im.rod_forces(&Motion {
        dt: p.rec.dt,
        x: p.x,
        v: &v,
        dp: p.dp.as_deref(),
    })
    .map_err(|e| format!("{}: {e}", p.rec.source))
}

/// Pooled ARX baseline x → force on the fitting parts (concatenated; the few regressor rows
/// that straddle a junction are a negligible share), simulated free-run over each record.
fn arx_baseline(prepared: &[Prepared<'_>]) -> Result<(String, Vec<Vec<f64>>), String> {
    let mut x = Vec::new();
    let mut f = Vec::new();
    for p in prepared.iter().filter(|p| !p.validation) {
        x.extend_from_slice(&p.x[p.fit.clone()]);
        f.extend_from_slice(&p.force[p.fit.clone()]);
    }
    let dt = prepared[0].rec.dt;
    let t: Vec<f64> = (0..x.len()).map(|k| k as f64 * dt).collect();
    let n = x.len();
    let concat = Record::from_columns(
        "campaign fitting parts",
        t,
        Vec::new(),
        vec![Channel {
            kind: ChannelKind::Force,
            values: f,
        }],
        None,
        0,
    )
    .map_err(|e| e.to_string())?;
    let b = baseline::fit(&concat, &x, n, "x");
    let m = b.models.first();
    let preds = prepared
        .iter()
        .map(|p| {
            m.and_then(|m| m.simulate(p.x, p.force))
                .unwrap_or_else(|| vec![f64::INFINITY; p.x.len()])
        })
        .collect();
    Ok((b.structure, preds))
}

/// Four significant digits, in scientific notation outside 0.01 … 10⁵.
fn fmt_coef(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 1e5 || v.abs() < 1e-2 {
        format!("{v:.3e}")
    } else {
        let digits = (3 - v.abs().log10().floor() as i32).max(0) as usize;
        format!("{v:.digits$}")
    }
}

/// `+ v` or `− |v|` for a term of a sum.
fn signed(v: f64) -> String {
    if v < 0.0 {
        format!("− {}", fmt_coef(-v))
    } else {
        format!("+ {}", fmt_coef(v))
    }
}

/// The leading term and its dependence in words, e.g.
/// `load-side Dahl yield force 124 N + 1027 N/A·current`.
fn cause_of(terms: &[TermFit], cfg: &RigConfig, names: &[String]) -> String {
    let Some(t) = terms.first() else {
        return "none".into();
    };
    let mut s = format!("{} {} {}", t.name, fmt_coef(t.at_zero), t.unit);
    for n in names {
        let Some((form, c)) = t.dependence.get(n) else {
            continue;
        };
        let (tu, u) = (&t.unit, &cfg.inputs[n].unit);
        s += &match form {
            Form::None => String::new(),
            Form::Linear => format!(" {} {tu}/{u}·{n}", signed(c[0])),
            Form::Quadratic => format!(
                " {} {tu}/{u}·{n} {} {tu}/{u}²·{n}²",
                signed(c[0]),
                signed(c[1])
            ),
            Form::Saturating { scale } => format!(
                " {} {tu}·(1 − exp(−{n}/{} {u}))",
                signed(c[0]),
                fmt_coef(*scale)
            ),
        };
    }
    s
}

/// The summary's sentence on a Dahl shape (pre-yield travel, series velocity) that follows the
/// input.
fn travel_text(t: &TravelDependence) -> String {
    let line = |a: f64, b: f64, u: &str| {
        format!(
            "{a:.3e} {u} {} {:.3e} {u}/{}·{}",
            if b < 0.0 { "−" } else { "+" },
            b.abs(),
            t.unit,
            t.input
        )
    };
    let what = match (t.travel_varies(), t.velocity_varies()) {
        (true, true) => format!(
            "The pre-yield travel follows {}: δ = {}, and the series-dashpot velocity too: V = {}",
            t.input,
            line(t.at_zero, t.slope, "m"),
            line(t.velocity_at_zero, t.velocity_slope, "m/s")
        ),
        (false, true) => format!(
            "The series-dashpot velocity follows {}: V = {} (δ = {:.3e} m)",
            t.input,
            line(t.velocity_at_zero, t.velocity_slope, "m/s"),
            t.at_zero
        ),
        _ => format!(
            "The pre-yield travel follows {}: δ = {}{}",
            t.input,
            line(t.at_zero, t.slope, "m"),
            if t.velocity_at_zero > 0.0 {
                format!(" (V = {:.3e} m/s)", t.velocity_at_zero)
            } else {
                String::new()
            }
        ),
    };
    format!(
        "{what} (chosen per operating point: {}; transfer NRMSE {:.4} with one shape for all, {:.4} with the shape following {}).",
        t.per_point
            .iter()
            .map(|(i, d, v)| format!("δ {d:.1e} m, V {v:.1e} m/s at {i} {}", t.unit))
            .collect::<Vec<_>>()
            .join("; "),
        t.nrmse_transfer_shared,
        t.nrmse_transfer,
        t.input
    )
}

fn summary_of(
    cause: &str,
    pooled: &Scores,
    records: &[RecordScore],
    terms: &[TermFit],
    shape: Shape,
    dependence: &str,
    arx: &str,
) -> String {
    let verdict = if pooled.law <= pooled.arx {
        "beats the linear black box"
    } else {
        "does NOT beat the linear black box: the law's library misses what the records hold"
    };
    let mut s = format!(
        "Campaign law: held-out force NRMSE {:.4} pooled over {} records (nominal {:.4}, ARX {:.4}): it {verdict}. Cause: {cause}.\n",
        pooled.law,
        records.len(),
        pooled.nominal,
        pooled.arx
    );
    s += &format!(
        "Law: {} (pre-yield travel δ = {:.3e} m, series-dashpot velocity V = {:.3e} m/s, smoothing velocity v_s = {:.3e} m/s; velocity from x by a least-squares derivative over ±{:.0} ms where a record gives no `v`, all four chosen by the transfer error). Input dependence chosen {dependence}.\n",
        terms
            .iter()
            .map(|t| {
                let deps: String = t
                    .dependence
                    .iter()
                    .map(|(n, (f, _))| format!(", {} in {n}", f.describe()))
                    .collect();
                format!("{} ({:.0} % of the force variance{deps})", t.name, 100.0 * t.share)
            })
            .collect::<Vec<_>>()
            .join(", "),
        shape.dahl_travel,
        shape.dahl_velocity,
        shape.smoothing_velocity,
        shape.velocity_window * 1e3
    );
    for r in records {
        s += &format!(
            "  {} [{}] at {}: law {:.4}, nominal {:.4}, ARX {:.4}; {:.0} % band covers {:.0} %{}\n",
            r.source,
            r.role,
            ehactl_config::inputs::describe_point(&r.operating_point),
            r.nrmse.law,
            r.nrmse.nominal,
            r.nrmse.arx,
            100.0 * r.band.level,
            100.0 * r.band.coverage,
            if r.envelope.inside {
                String::new()
            } else {
                format!(" — {}", r.envelope.describe())
            }
        );
    }
    s += &format!("Baseline: {arx}.");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The least-squares derivative is exact on a quadratic (central window) and on a line.
    #[test]
    fn derivative_is_exact_on_polynomials() {
        let dt = 0.01;
        let x: Vec<f64> = (0..50).map(|k| 3.0 + 2.0 * (k as f64 * dt)).collect();
        for m in [1, 2, 4] {
            for v in derivative(&x, dt, m) {
                assert!((v - 2.0).abs() < 1e-9);
            }
        }
        let q: Vec<f64> = (0..50).map(|k| (k as f64 * dt).powi(2)).collect();
        let v = derivative(&q, dt, 3);
        for (k, vk) in v.iter().enumerate().take(47).skip(3) {
            assert!((vk - 2.0 * k as f64 * dt).abs() < 1e-9, "{k}");
        }
    }
}
