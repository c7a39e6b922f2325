//! `ehactl predict`: replay a record through a model (a shipped config or the `extended.toml`
//! a diagnosis or campaign wrote) and score every measured channel. A closed-loop record (a
//! `ref` and the config's loop) is replayed through the config's controller, an open-loop one
//! with its recorded `u`, a displacement-controlled one (x and force only) by imposing its
//! motion on the rod ([`ehactl_plant::imposed`]); `imposed` asks for the last on any record
//! with x and force. The model is taken at the record's operating point (its declared input
//! columns, [`ehactl_config::inputs`]).
//!
//! A prediction knows its limits: a record outside the motion and operating inputs the model
//! was fitted on (its `[envelope]`, [`crate::envelope`]) is flagged with how far outside, and a
//! replay that leaves physical bounds ([`check_divergence`]) is reported as diverged, with the
//! time, channel and value, never as a number.

use crate::data::{ChannelKind, Record};
use crate::replay::{replay_params, replay_with, std};
use crate::session::{drive_for, load_checked, SessionError};
use ehactl_config::RigConfig;
use ehactl_plant::imposed::{ImposedMotion, Motion};
use ehactl_plant::PlantParams;
use serde::Serialize;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// NRMSE of a prediction (`None`: the replay diverged, there is no score).
#[derive(Debug, Clone, Serialize)]
pub struct Nrmse {
    /// Root mean square over the channels (-).
    pub overall: Option<f64>,
    /// Per channel (CSV column → NRMSE, -).
    pub channels: BTreeMap<String, Option<f64>>,
}

/// Where a replay left physical bounds: it stopped there and has no score.
#[derive(Debug, Clone, Serialize)]
pub struct Divergence {
    /// Time of the first sample out of bounds (s from the record's start).
    pub t: f64,
    /// Its sample index.
    pub sample: usize,
    /// The channel or state variable (`force`, `p_a`, `x`, or a plant state).
    pub channel: String,
    /// Its value there (SI unit of the channel).
    pub value: f64,
    /// The bound it crossed (same unit; NaN for a non-finite value or a failed step).
    pub bound: f64,
    /// Unit of `value` and `bound`.
    pub unit: String,
    /// In words, e.g. `force −1.9e9 N beyond ±1.5e4 N (10× the record's largest |force|)`.
    pub reason: String,
}

/// A predicted force beyond this many times the record's largest |force| is a divergence (-):
/// far beyond any modelling error, as no law fitted to a record predicts ten times its range.
pub const FORCE_BOUND_FACTOR: f64 = 10.0;
/// A predicted chamber pressure beyond this many times the larger of the supply pressure and
/// the record's largest pressure is a divergence (-).
pub const PRESSURE_BOUND_FACTOR: f64 = 2.0;
/// A predicted chamber pressure below this (Pa, gauge) is a divergence: an order of magnitude
/// below the cavitation limit of about −1 bar gauge.
pub const PRESSURE_FLOOR: f64 = -1.0e6;
/// A predicted position beyond the cylinder's stroke by this share of it is a divergence (-).
pub const POSITION_MARGIN: f64 = 0.1;

/// One record's prediction.
#[derive(Debug, Clone, Serialize)]
pub struct Prediction {
    /// The record.
    pub source: String,
    /// How it was replayed: `imposed_motion`, `closed_loop` or `open_loop`.
    pub replay: String,
    /// The operating point the model was taken at (input → value in its unit).
    pub operating_point: BTreeMap<String, f64>,
    /// Samples scored (start, end).
    pub scored: (usize, usize),
    /// Scores.
    pub nrmse: Nrmse,
    /// Where the replay left physical bounds (`None`: it stayed within them).
    pub diverged: Option<Divergence>,
    /// The record against the model's `[envelope]` (`None`: the model states none).
    pub envelope: Option<crate::envelope::EnvelopeCheck>,
    /// The force's uncertainty band and its coverage ([`crate::band`]): for a prediction by
    /// a model with a `[band]` (a campaign's extended config) of a record with a force
    /// channel, imposed-motion (every member) or replayed ([`REPLAY_BAND_MEMBERS`] members);
    /// `None` otherwise.
    pub band: Option<crate::band::BandScore>,
    /// Predicted channels (column → values, up to the divergence if any).
    #[serde(skip)]
    pub predicted: Vec<(ChannelKind, Vec<f64>)>,
}

/// Median of each declared input the record carries (others stay at the config's value).
fn operating_point(cfg: &RigConfig, rec: &Record) -> BTreeMap<String, f64> {
    cfg.inputs
        .keys()
        .filter_map(|n| rec.input_median(n).map(|m| (n.clone(), m)))
        .collect()
}

fn nrmse_on(y: &[f64], yh: &[f64], r: std::ops::Range<usize>) -> f64 {
    let r = r.start.min(yh.len())..r.end.min(yh.len());
    let e = y[r.clone()]
        .iter()
        .zip(&yh[r.clone()])
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        / r.len().max(1) as f64;
    let v = e.sqrt() / std(&y[r]).max(1e-300);
    if v.is_finite() {
        v
    } else {
        f64::INFINITY
    }
}

/// Predict `rec` with the model `cfg`, scoring samples `score` (the whole record if `None`).
pub fn predict(
    cfg: &RigConfig,
    rec: &Record,
    imposed: bool,
    score: Option<std::ops::Range<usize>>,
) -> Result<Prediction, String> {
    let src = &rec.source;
    let at = operating_point(cfg, rec);
    let plant = ehactl_config::inputs::plant_at(&cfg.inputs, &cfg.plant, &at).map_err(|e| {
        // Most often the law taken beyond what it was fitted on: say so.
        let outside = crate::envelope::check_record(cfg, rec)
            .filter(|c| !c.inside)
            .map_or(String::new(), |c| {
                format!("; the record lies {}", c.describe())
            });
        format!("{src}: {e}{outside}")
    })?;
    let n = rec.len();
    let score = score.unwrap_or(0..n);
    let Predicted {
        replay,
        mut predicted,
        failed_at,
        band,
    } = if imposed || rec.imposed_motion() {
        imposed_prediction(cfg, rec, &plant, &at, score.clone())?
    } else {
        replayed_prediction(cfg, rec, &plant, &at, score.clone())?
    };
    let diverged = check_divergence(&plant, rec, &predicted, failed_at);
    if let Some(d) = &diverged {
        for (_, yh) in predicted.iter_mut() {
            yh.truncate(d.sample);
        }
    }
    let channels: BTreeMap<String, Option<f64>> = predicted
        .iter()
        .filter_map(|(k, yh)| {
            rec.channel(*k).map(|y| {
                let e = diverged.is_none().then(|| nrmse_on(y, yh, score.clone()));
                (k.column().to_string(), e)
            })
        })
        .collect();
    let overall = diverged.is_none().then(|| {
        let v: Vec<f64> = channels.values().flatten().copied().collect();
        (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt()
    });
    let band = band.filter(|_| diverged.is_none());
    Ok(Prediction {
        source: src.clone(),
        replay: replay.to_string(),
        operating_point: at,
        scored: (score.start, score.end),
        nrmse: Nrmse { overall, channels },
        diverged,
        envelope: crate::envelope::check_record(cfg, rec),
        band,
        predicted,
    })
}

/// A replay's channels and its failed plant step, if any.
type Replayed = (Vec<(ChannelKind, Vec<f64>)>, Option<FailedStep>);

/// The sample at which a plant step failed, and how.
type FailedStep = (usize, ehactl_plant::NumericalFailure);

/// What one way of predicting a record gives: how it was replayed, the predicted channels,
/// the failed plant step if any, and the force band.
struct Predicted {
    replay: &'static str,
    predicted: Vec<(ChannelKind, Vec<f64>)>,
    failed_at: Option<FailedStep>,
    band: Option<crate::band::BandScore>,
}

/// The rod force along the record's measured motion, with the band over every member.
fn imposed_prediction(
    cfg: &RigConfig,
    rec: &Record,
    plant: &PlantParams,
    at: &BTreeMap<String, f64>,
    score: std::ops::Range<usize>,
) -> Result<Predicted, String> {
    let src = &rec.source;
    let (Some(x), Some(_)) = (
        rec.channel(ChannelKind::Position),
        rec.channel(ChannelKind::Force),
    ) else {
        return Err(format!(
            "{src}: an imposed-motion prediction needs the motion `x` (m) and the load-cell `force` (N)"
        ));
    };
    let f = imposed_force(plant, rec, x).map_err(|e| format!("{src}: {e}"))?;
    let band = force_band(cfg, rec, at, &f, score, usize::MAX, |p| {
        imposed_force(p, rec, x).ok()
    });
    Ok(Predicted {
        replay: "imposed_motion",
        predicted: vec![(ChannelKind::Force, f)],
        failed_at: None,
        band,
    })
}

/// The record replayed through the plant and the config's loop (closed loop on a `ref`, else
/// the recorded command), with the band over [`REPLAY_BAND_MEMBERS`] members.
fn replayed_prediction(
    cfg: &RigConfig,
    rec: &Record,
    plant: &PlantParams,
    at: &BTreeMap<String, f64>,
    score: std::ops::Range<usize>,
) -> Result<Predicted, String> {
    let n = rec.len();
    let (drive, _) = drive_for(cfg, rec);
    let replay_of = |p: &PlantParams| -> Result<Replayed, String> {
        let s = replay_with(&replay_params(p, rec), rec, n, drive)?;
        Ok((
            rec.channels.iter().map(|c| c.kind).zip(s.y).collect(),
            s.failed_at,
        ))
    };
    let (y, failed_at) = replay_of(plant)
        .map_err(|e| format!("{}: the model cannot be replayed: {e}", rec.source))?;
    // A member's force along its own replay; a member that fails or diverges gives none.
    let member_force = |p: &PlantParams| -> Option<Vec<f64>> {
        let (yk, failed) = replay_of(p).ok()?;
        check_divergence(p, rec, &yk, failed)
            .is_none()
            .then_some(())?;
        yk.into_iter()
            .find(|(k, _)| *k == ChannelKind::Force)
            .map(|(_, f)| f)
    };
    let band = y
        .iter()
        .find(|(k, _)| *k == ChannelKind::Force)
        .and_then(|(_, f)| force_band(cfg, rec, at, f, score, REPLAY_BAND_MEMBERS, member_force));
    Ok(Predicted {
        replay: if drive.closed_loop() {
            "closed_loop"
        } else {
            "open_loop"
        },
        predicted: y,
        failed_at,
        band,
    })
}

/// Members of a campaign's `[band]` replayed for the band of a closed- or open-loop
/// prediction: each member is a whole replay of the plant (an imposed-motion member is a
/// pass over the law), so the band takes the first 10 of the bootstrap's 40 (the members
/// are independent resamples: any 10 are a smaller bootstrap; the spread's relative
/// standard error is then about 1/√(2·9) ≈ 24 % instead of 11 %).
pub const REPLAY_BAND_MEMBERS: usize = 10;

/// The force band of a prediction `f` (N) of `rec` by a model with a `[band]`: the first
/// `max_members` members, each at the record's operating point `at`, predicted in parallel
/// by `member_force` (None: left out), and their spread with the law's residual
/// ([`crate::band::band`]). `None` without a `[band]`.
fn force_band(
    cfg: &RigConfig,
    rec: &Record,
    at: &BTreeMap<String, f64>,
    f: &[f64],
    score: std::ops::Range<usize>,
    max_members: usize,
    member_force: impl Fn(&PlantParams) -> Option<Vec<f64>> + Sync,
) -> Option<crate::band::BandScore> {
    use rayon::prelude::*;
    let b = cfg.band.as_ref()?;
    let members: Vec<Vec<f64>> = b
        .members
        .par_iter()
        .take(max_members)
        .filter_map(|m| {
            let c = m.apply(cfg);
            let p = ehactl_config::inputs::plant_at(&c.inputs, &c.plant, at).ok()?;
            member_force(&p)
        })
        .collect();
    let measured = rec.channel(ChannelKind::Force).unwrap_or(&[]);
    Some(crate::band::band(
        f,
        &members,
        b.relative_residual,
        b.level,
        measured,
        score,
    ))
}

/// The rod force (N) the law of `plant` gives along the record's measured motion `x` (m) and
/// its velocity, with the load pressure p_a − p_b where the record has both.
fn imposed_force(plant: &PlantParams, rec: &Record, x: &[f64]) -> Result<Vec<f64>, String> {
    let v = crate::motion::record_velocity(rec, x, plant.sensors.position.velocity_window);
    let dp = match (
        rec.channel(ChannelKind::PressureA),
        rec.channel(ChannelKind::PressureB),
    ) {
        (Some(a), Some(b)) => Some(a.iter().zip(b).map(|(a, b)| a - b).collect::<Vec<_>>()),
        _ => None,
    };
    ImposedMotion::new(plant)?.rod_forces(&Motion {
        dt: rec.dt,
        x,
        v: &v,
        dp: dp.as_deref(),
    })
}

/// The first sample at which a prediction leaves physical bounds, if any: a failed plant
/// step (`failed_at`: sample and state variable), a non-finite value, a force beyond
/// [`FORCE_BOUND_FACTOR`] × the record's largest |force|, a chamber pressure beyond
/// [`PRESSURE_BOUND_FACTOR`] × max(supply, the record's largest pressure) or below
/// [`PRESSURE_FLOOR`], a position beyond the stroke by [`POSITION_MARGIN`] of it.
pub fn check_divergence(
    plant: &PlantParams,
    rec: &Record,
    predicted: &[(ChannelKind, Vec<f64>)],
    failed_at: Option<(usize, ehactl_plant::NumericalFailure)>,
) -> Option<Divergence> {
    let peak = |k: ChannelKind| {
        rec.channel(k)
            .map_or(0.0, |y| y.iter().fold(0.0_f64, |m, v| m.max(v.abs())))
    };
    let p_hi = PRESSURE_BOUND_FACTOR
        * plant
            .supply
            .pressure
            .max(peak(ChannelKind::PressureA))
            .max(peak(ChannelKind::PressureB));
    let stroke = plant.cylinder.stroke;
    let x_margin = POSITION_MARGIN * stroke;
    let f_bound = FORCE_BOUND_FACTOR * peak(ChannelKind::Force);
    let mut first: Option<Divergence> = None;
    let mut note = |d: Divergence| {
        if first.as_ref().is_none_or(|f| d.sample < f.sample) {
            first = Some(d);
        }
    };
    let at =
        |k: usize, channel: &str, value: f64, bound: f64, unit: &str, reason: String| Divergence {
            t: k as f64 * rec.dt,
            sample: k,
            channel: channel.into(),
            value,
            bound,
            unit: unit.into(),
            reason,
        };
    if let Some((k, e)) = failed_at {
        let reason = if e.bound.is_finite() {
            format!(
                "the plant's {} reached {:.3e} {}, beyond {:.3e} {}, a state no rig can have (crates/plant/src/plausible.rs)",
                e.what, e.value, e.unit, e.bound, e.unit
            )
        } else {
            format!("the plant's {} is not finite ({})", e.what, e.value)
        };
        note(at(k, e.what, e.value, e.bound, e.unit, reason));
    }
    for (kind, yh) in predicted {
        let (ch, unit) = (kind.column(), kind.unit());
        let bound = |v: f64| -> Option<(f64, String)> {
            if !v.is_finite() {
                return Some((f64::NAN, format!("{ch} is not finite ({v})")));
            }
            match kind {
                ChannelKind::Force if f_bound > 0.0 && v.abs() > f_bound => Some((
                    f_bound,
                    format!("{ch} {v:.3e} {unit} beyond ±{f_bound:.3e} {unit} ({FORCE_BOUND_FACTOR}× the record's largest |{ch}|)"),
                )),
                ChannelKind::PressureA | ChannelKind::PressureB if v > p_hi || v < PRESSURE_FLOOR => Some((
                    if v > p_hi { p_hi } else { PRESSURE_FLOOR },
                    format!("{ch} {v:.3e} {unit} outside {PRESSURE_FLOOR:.1e}…{p_hi:.3e} {unit} ({PRESSURE_BOUND_FACTOR}× the larger of the supply and the record's pressures)"),
                )),
                ChannelKind::Position if v < -x_margin || v > stroke + x_margin => Some((
                    if v < 0.0 { -x_margin } else { stroke + x_margin },
                    format!("{ch} {v:.4} {unit} beyond the stroke 0…{stroke} {unit}"),
                )),
                _ => None,
            }
        };
        if let Some((k, (b, reason))) = yh
            .iter()
            .enumerate()
            .find_map(|(k, v)| bound(*v).map(|b| (k, b)))
        {
            note(at(k, ch, yh[k], b, unit, reason));
        }
    }
    first
}

/// The warnings a prediction's limits give: a divergence, and a record outside the model's
/// fitted envelope (one line each, naming the record).
fn limits_warnings(p: &Prediction) -> Vec<String> {
    let mut w = Vec::new();
    if let Some(d) = &p.diverged {
        w.push(format!(
            "{}: the {} replay DIVERGED at t = {:.4} s (sample {}): {}; it has no NRMSE",
            p.source,
            p.replay.replace('_', "-"),
            d.t,
            d.sample,
            d.reason
        ));
    }
    if let Some(e) = p.envelope.as_ref().filter(|e| !e.inside) {
        w.push(format!(
            "{}: the model extrapolates, the record lies {}",
            p.source,
            e.describe()
        ));
    }
    w
}

/// `p` without the scores of the constant channels `flat` (each with its warning, added to
/// `warnings`): the overall NRMSE is the RMS over the channels that remain.
fn leave_out(
    mut p: Prediction,
    flat: &[(ChannelKind, String)],
    warnings: &mut Vec<String>,
) -> Prediction {
    for (k, w) in flat {
        p.nrmse.channels.remove(k.column());
        warnings.push(w.clone());
    }
    if !flat.is_empty() && p.diverged.is_none() {
        let v: Vec<f64> = p.nrmse.channels.values().flatten().copied().collect();
        p.nrmse.overall =
            Some((v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt());
    }
    p
}

/// A finished `ehactl predict`.
pub struct PredictRun {
    /// One prediction per record.
    pub predictions: Vec<Prediction>,
    /// The `--json` object.
    pub json: Value,
    /// Warnings about the records.
    pub warnings: Vec<String>,
    /// Files written to `--out`.
    pub files: Vec<PathBuf>,
}

/// Predict each of `data` with the model `cfg`; `held_out` scores only the last 30 % of each
/// record (the part a single-record diagnosis holds out); write `prediction.json` and
/// `prediction.svg` to `out`.
pub fn run(
    cfg: &RigConfig,
    config_path: &Path,
    data: &[PathBuf],
    imposed: bool,
    held_out: bool,
    out: Option<&Path>,
    force: bool,
) -> Result<PredictRun, SessionError> {
    if data.is_empty() {
        return Err(SessionError::Input(
            "no record to predict; give one or more --data files (CSV or MCAP)".into(),
        ));
    }
    if let Some(dir) = out {
        let mut inputs: Vec<(&str, &Path)> =
            data.iter().map(|d| ("--data file", d.as_path())).collect();
        inputs.push(("--config being run", config_path));
        crate::outdir::check(dir, &inputs, force, "predict").map_err(SessionError::Input)?;
    }
    // Held until the last file is written: a second run into `out` is refused meanwhile.
    let _lock = out
        .map(crate::outdir::lock)
        .transpose()
        .map_err(SessionError::Io)?;
    let mut predictions = Vec::new();
    let mut warnings = Vec::new();
    let mut records = Vec::new();
    for d in data {
        let rec = load_checked(cfg, d)?;
        warnings.extend(rec.warnings.iter().cloned());
        let n = rec.len();
        let score = held_out.then(|| {
            let nf = ((1.0 - crate::motion::HOLDOUT) * n as f64).round() as usize;
            nf..n
        });
        let flat =
            crate::session::check_for_prediction(cfg, config_path, &rec, imposed, score.clone())?;
        let p = predict(cfg, &rec, imposed, score).map_err(SessionError::Input)?;
        warnings.extend(limits_warnings(&p));
        predictions.push(leave_out(p, &flat, &mut warnings));
        records.push(rec);
    }
    let mut files = Vec::new();
    if let Some(dir) = out {
        let mut od = crate::outdir::OutDir::create(dir).map_err(SessionError::Io)?;
        files.push(write_plot(&mut od, &predictions, &records).map_err(SessionError::Io)?);
        // Written below: the `--json` object, which lists it among the files.
        files.push(od.path("prediction.json"));
    }
    let json = run_json(&predictions, config_path, &files, &warnings);
    if let Some(dir) = out {
        let text = serde_json::to_string_pretty(&json).unwrap_or_default();
        crate::outdir::OutDir::create(dir)
            .and_then(|mut od| od.write("prediction.json", text.as_bytes()))
            .map_err(SessionError::Io)?;
    }
    Ok(PredictRun {
        predictions,
        json,
        warnings,
        files,
    })
}

/// `prediction.svg` in `od`: every predicted channel of every record against its
/// measurement, the force band's edges where a band was fitted. Returns the file's path.
fn write_plot(
    od: &mut crate::outdir::OutDir,
    predictions: &[Prediction],
    records: &[Record],
) -> Result<PathBuf, String> {
    // The force band's edges, predicted ∓ half-width.
    let edges: Vec<Option<(Vec<f64>, Vec<f64>)>> = predictions
        .iter()
        .map(|p| {
            let b = p.band.as_ref()?;
            let (_, f) = p.predicted.iter().find(|(k, _)| *k == ChannelKind::Force)?;
            let lo = f.iter().zip(&b.half_width).map(|(y, h)| y - h).collect();
            let hi = f.iter().zip(&b.half_width).map(|(y, h)| y + h).collect();
            Some((lo, hi))
        })
        .collect();
    let panels: Vec<crate::plots::PredictionPanel<'_>> = predictions
        .iter()
        .zip(records)
        .zip(&edges)
        .flat_map(|((p, r), e)| {
            p.predicted.iter().filter_map(move |(k, yh)| {
                r.channel(*k).map(|y| crate::plots::PredictionPanel {
                    title: format!(
                        "{} {} ({})",
                        Path::new(&r.source)
                            .file_name()
                            .map_or(r.source.clone(), |f| f.to_string_lossy().into_owned()),
                        k.column(),
                        k.unit()
                    ),
                    t: &r.t,
                    measured: y,
                    predicted: yh,
                    nominal: None,
                    shade_from: (p.scored.0 > 0).then_some(p.scored.0),
                    band: e
                        .as_ref()
                        .filter(|_| *k == ChannelKind::Force)
                        .map(|(lo, hi)| (lo.as_slice(), hi.as_slice())),
                })
            })
        })
        .collect();
    od.write_with("prediction.svg", |path| {
        crate::plots::prediction(path, &panels)
    })
}

/// The `--json` object: the one prediction, or every record's with the pooled NRMSE (-),
/// and the config, the files written, the warnings and the count of diverged records.
fn run_json(
    predictions: &[Prediction],
    config_path: &Path,
    files: &[PathBuf],
    warnings: &[String],
) -> Value {
    let one = |p: &Prediction| serde_json::to_value(p).unwrap_or_default();
    let mut json = if predictions.len() == 1 {
        one(&predictions[0])
    } else {
        // No pooled score when a record has none (it diverged).
        let v: Option<Vec<f64>> = predictions.iter().map(|p| p.nrmse.overall).collect();
        let pooled =
            v.map(|v| (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt());
        serde_json::json!({
            "records": predictions.iter().map(one).collect::<Vec<_>>(),
            "nrmse": {"overall": pooled},
        })
    };
    json["config"] = Value::from(config_path.display().to_string());
    json["files"] = Value::from(
        files
            .iter()
            .map(|f| f.display().to_string())
            .collect::<Vec<_>>(),
    );
    json["warnings"] = Value::from(warnings.to_vec());
    json["diverged_records"] =
        Value::from(predictions.iter().filter(|p| p.diverged.is_some()).count());
    json
}
