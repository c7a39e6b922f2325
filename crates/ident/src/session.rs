//! One complete diagnosis as the CLI and the Python bindings run it: load and check the data
//! against the nominal config, choose the replay drive, diagnose, write the report, and
//! return the `ehactl diagnose --json` object. Messages meant for the user (warnings, notes)
//! are returned, not printed, so each front end shows them its own way.

use crate::diagnose::{diagnose, Diagnosis, Options};
use crate::replay::Drive;
use crate::{data, report};
use ehactl_config::ControlMode;
use ehactl_config::RigConfig;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// Why a diagnosis could not be made.
#[derive(Debug)]
pub enum SessionError {
    /// Bad config, data or argument (CLI exit code 2, Python `ValueError`).
    Input(String),
    /// The report could not be written (CLI exit code 1, Python `OSError`).
    Io(String),
}

impl std::fmt::Display for SessionError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SessionError::Input(s) | SessionError::Io(s) => f.write_str(s),
        }
    }
}

impl std::error::Error for SessionError {}

/// A finished diagnosis.
pub struct DiagnoseRun {
    /// The decision and its numbers.
    pub diagnosis: Diagnosis,
    /// The `--json` object: the diagnosis plus `extended_config`, `report`, `plots` paths.
    pub json: Value,
    /// Warnings about the data or the report (unit look, sample rate, missing plots, …).
    pub warnings: Vec<String>,
    /// Notes on how the data were replayed.
    pub notes: Vec<String>,
    /// Paths written by `--out`, if any.
    pub files: Option<report::ReportFiles>,
}

/// How a diagnosis runs (what the front ends let the user choose); the default reports no
/// progress and trusts the sensors' zeros.
#[derive(Debug, Clone, Default)]
pub struct RunChoices {
    /// Where the fits' progress goes ([`crate::progress`]; the front end draws it).
    pub progress: crate::progress::ProgressSink,
    /// Estimate a constant offset per measured channel ([`Options::sensor_offsets`]).
    pub sensor_offsets: bool,
}

/// Largest replay cost factor the integration choice may spend for `ehactl diagnose` and the
/// Python bindings ([`Options::integration_max_cost`]): up to 4× the config's substeps to bring
/// the replay's integration error below 0.3 × the noise floor; what remains is reported and
/// counted as noise.
pub const USER_INTEGRATION_COST: f64 = 4.0;

/// Smallest replay cost factor of the integration choice for `ehactl diagnose` and the Python
/// bindings ([`Options::integration_min_cost`]): where the config's substeps leave less than
/// half the allowed integration error, down to half of them (the MTS records: 10 → 5
/// substeps per sample, error still ≤ 0.3 × the noise floor by step halving; BENCHMARKS.md
/// "Diagnosis speed").
pub const USER_INTEGRATION_MIN_COST: f64 = 0.5;

/// Diagnose `data_path` (CSV or ehactl MCAP) against the nominal `cfg` (labelled
/// `config_label` in the report), holding out `validate` or the last 30 %; write the report to
/// `out` when given.
pub fn run(
    cfg: &RigConfig,
    config_label: &str,
    data_path: &Path,
    validate: Option<&Path>,
    out: Option<&Path>,
    choices: RunChoices,
) -> Result<DiagnoseRun, SessionError> {
    let load = |p: &Path| -> Result<data::Record, SessionError> {
        let mut r = data::load(p).map_err(|e| SessionError::Input(e.to_string()))?;
        let w = data::check_against(&r, &cfg.plant, cfg.timebase().period())
            .map_err(|e| SessionError::Input(e.to_string()))?;
        r.warnings.extend(w);
        Ok(r)
    };
    let rec = load(data_path)?;
    let val = validate.map(load).transpose()?;
    // Long records take minutes; say so at once instead of going silent (a front end's
    // progress bar is hidden when stderr is not a terminal). Figure: 50 000 samples of the
    // 5 kHz bench record take ≈ 21 s on 2 idle cores (BENCHMARKS.md, bench/diagnose_bench.sh).
    let n_total = rec.t.len() + val.as_ref().map_or(0, |v| v.t.len());
    if n_total > 50_000 {
        eprintln!(
            "ehactl: note: {n_total} samples to replay per candidate model; expect about {:.0} s or more on 2 cores (fits use the first {} samples of the fitting part, scoring uses all held-out samples)",
            21.0 * n_total as f64 / 50_000.0,
            crate::diagnose::Options::default().max_fit_samples
        );
    }
    if let Some(v) = &val {
        let a: Vec<_> = rec.channels.iter().map(|c| c.kind).collect();
        let b: Vec<_> = v.channels.iter().map(|c| c.kind).collect();
        if a != b {
            return Err(SessionError::Input(format!(
                "{}: channels [{}] differ from the data file's [{}]; the validation file must have the same output columns",
                v.source,
                b.iter().map(|k| k.column()).collect::<Vec<_>>().join(", "),
                a.iter().map(|k| k.column()).collect::<Vec<_>>().join(", ")
            )));
        }
        if (v.dt - rec.dt).abs() > 1e-6 * rec.dt {
            return Err(SessionError::Input(format!(
                "{}: sample period {} s differs from the data file's {} s",
                v.source, v.dt, rec.dt
            )));
        }
    }
    let mut warnings: Vec<String> = rec
        .warnings
        .iter()
        .chain(val.iter().flat_map(|v| v.warnings.iter()))
        .cloned()
        .collect();
    let mut notes = Vec::new();
    // Closed-loop position records (a `ref` column and a PD position loop in the config) are
    // replayed through the same controller: an integrating plant would drift open loop.
    let drive = match (&cfg.control.mode, cfg.pd_gains(), &rec.reference) {
        (ControlMode::Position, Some(g), Some(_)) => {
            notes.push("closed-loop replay: the config's PD position controller acts on the recorded `ref`; the recorded `u` is not used".to_string());
            Drive::PositionPd(g)
        }
        _ => {
            if rec.reference.is_some() {
                notes.push("open-loop replay with the recorded valve command `u` (the config has no PD position loop to replay `ref` through)".to_string());
            }
            Drive::Recorded
        }
    };
    if let (Drive::PositionPd(_), Some(v)) = (&drive, &val) {
        if v.reference.is_none() {
            return Err(SessionError::Input(format!(
                "{}: closed-loop replay needs a `ref` column in the validation file too",
                v.source
            )));
        }
    }
    let opts = Options {
        progress: choices.progress,
        sensor_offsets: choices.sensor_offsets,
        drive,
        // Replay accuracy is checked and reported (DIAGNOSIS.md "Replay accuracy").
        integration_max_cost: USER_INTEGRATION_COST,
        integration_min_cost: USER_INTEGRATION_MIN_COST,
        // Grey-box extension when the catalogue is exhausted (DIAGNOSIS.md "Grey-box").
        greybox: true,
        ..Options::default()
    };
    let d = diagnose(&cfg.plant, &rec, val.as_ref(), &opts).map_err(SessionError::Input)?;
    let files = match out {
        Some(dir) => {
            let f = report::write_report(dir, cfg, config_label, &rec, val.as_ref(), &d)
                .map_err(|e| SessionError::Io(e.to_string()))?;
            warnings.extend(f.warnings.iter().cloned());
            Some(f)
        }
        None => None,
    };
    let path = |p: &PathBuf| Value::from(p.display().to_string());
    let mut json = serde_json::to_value(&d).unwrap_or_default();
    json["extended_config"] = files
        .as_ref()
        .map_or(Value::Null, |f| path(&f.extended_config));
    json["report"] = files.as_ref().map_or(Value::Null, |f| path(&f.report));
    json["plots"] = files.as_ref().map_or(Value::Null, |f| {
        Value::from(f.plots.iter().map(path).collect::<Vec<_>>())
    });
    json["warnings"] = Value::from(warnings.clone());
    Ok(DiagnoseRun {
        diagnosis: d,
        json,
        warnings,
        notes,
        files,
    })
}
