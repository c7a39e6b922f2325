//! `ehactl predict`: replay a record through a model (a shipped config or the `extended.toml`
//! a diagnosis or campaign wrote) and score every measured channel. A closed-loop record (a
//! `ref` and the config's loop) is replayed through the config's controller, an open-loop one
//! with its recorded `u`, a displacement-controlled one (x and force only) by imposing its
//! motion on the rod ([`ehactl_plant::imposed`]); `imposed` asks for the last on any record
//! with x and force. The model is taken at the record's operating point (its declared input
//! columns, [`ehactl_config::inputs`]).

use crate::data::{ChannelKind, Record};
use crate::replay::{replay_params, replay_with, std};
use crate::session::{drive_for, load_checked, SessionError};
use ehactl_config::RigConfig;
use ehactl_plant::imposed::{ImposedMotion, Motion};
use serde::Serialize;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// NRMSE of a prediction.
#[derive(Debug, Clone, Serialize)]
pub struct Nrmse {
    /// Root mean square over the channels (-).
    pub overall: f64,
    /// Per channel (CSV column → NRMSE, -).
    pub channels: BTreeMap<String, f64>,
}

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
    /// Predicted channels (column → values, whole record).
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
    let plant = ehactl_config::inputs::plant_at(&cfg.inputs, &cfg.plant, &at)
        .map_err(|e| format!("{src}: {e}"))?;
    let n = rec.len();
    let score = score.unwrap_or(0..n);
    let (replay, predicted) = if imposed || rec.imposed_motion() {
        let (Some(x), Some(_)) = (
            rec.channel(ChannelKind::Position),
            rec.channel(ChannelKind::Force),
        ) else {
            return Err(format!(
                "{src}: an imposed-motion prediction needs the motion `x` (m) and the load-cell `force` (N)"
            ));
        };
        let v = crate::campaign::record_velocity(rec, x, plant.sensors.position.velocity_window);
        let dp = match (
            rec.channel(ChannelKind::PressureA),
            rec.channel(ChannelKind::PressureB),
        ) {
            (Some(a), Some(b)) => Some(a.iter().zip(b).map(|(a, b)| a - b).collect::<Vec<_>>()),
            _ => None,
        };
        let im = ImposedMotion::new(&plant).map_err(|e| format!("{src}: {e}"))?;
        let f = im
            .rod_forces(&Motion {
                dt: rec.dt,
                x,
                v: &v,
                dp: dp.as_deref(),
            })
            .map_err(|e| format!("{src}: {e}"))?;
        ("imposed_motion", vec![(ChannelKind::Force, f)])
    } else {
        let (drive, _) = drive_for(cfg, rec);
        let sim = replay_with(&replay_params(&plant, rec), rec, n, drive)
            .map_err(|e| format!("{src}: the model cannot be replayed: {e}"))?;
        let how = if drive.closed_loop() {
            "closed_loop"
        } else {
            "open_loop"
        };
        let y = rec.channels.iter().map(|c| c.kind).zip(sim.y).collect();
        (how, y)
    };
    let channels: BTreeMap<String, f64> = predicted
        .iter()
        .filter_map(|(k, yh)| {
            rec.channel(*k)
                .map(|y| (k.column().to_string(), nrmse_on(y, yh, score.clone())))
        })
        .collect();
    let v: Vec<f64> = channels.values().copied().collect();
    let overall = (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt();
    Ok(Prediction {
        source: src.clone(),
        replay: replay.to_string(),
        operating_point: at,
        scored: (score.start, score.end),
        nrmse: Nrmse { overall, channels },
        predicted,
    })
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
    if !flat.is_empty() {
        let v: Vec<f64> = p.nrmse.channels.values().copied().collect();
        p.nrmse.overall = (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt();
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
            let nf = ((1.0 - crate::campaign::HOLDOUT) * n as f64).round() as usize;
            nf..n
        });
        let flat =
            crate::session::check_for_prediction(cfg, config_path, &rec, imposed, score.clone())?;
        let p = predict(cfg, &rec, imposed, score).map_err(SessionError::Input)?;
        predictions.push(leave_out(p, &flat, &mut warnings));
        records.push(rec);
    }
    let mut files = Vec::new();
    if let Some(dir) = out {
        let mut od = crate::outdir::OutDir::create(dir).map_err(SessionError::Io)?;
        let panels: Vec<crate::plots::PredictionPanel<'_>> = predictions
            .iter()
            .zip(&records)
            .flat_map(|(p, r)| {
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
                    })
                })
            })
            .collect();
        files.push(
            od.write_with("prediction.svg", |path| {
                crate::plots::prediction(path, &panels)
            })
            .map_err(SessionError::Io)?,
        );
        // Written below: the `--json` object, which lists it among the files.
        files.push(od.path("prediction.json"));
    }
    let one = |p: &Prediction| serde_json::to_value(p).unwrap_or_default();
    let mut json = if predictions.len() == 1 {
        one(&predictions[0])
    } else {
        let v: Vec<f64> = predictions.iter().map(|p| p.nrmse.overall).collect();
        serde_json::json!({
            "records": predictions.iter().map(one).collect::<Vec<_>>(),
            "nrmse": {"overall": (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt()},
        })
    };
    json["config"] = Value::from(config_path.display().to_string());
    json["files"] = Value::from(
        files
            .iter()
            .map(|f| f.display().to_string())
            .collect::<Vec<_>>(),
    );
    json["warnings"] = Value::from(warnings.clone());
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
