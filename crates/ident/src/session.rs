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
    /// The file the config was read from, if any: never written over by the report.
    pub config_path: Option<PathBuf>,
    /// Write into an output directory that holds files diagnose did not write (same-named
    /// ones are replaced; inputs never are).
    pub force: bool,
    /// Diagnose an ehactl MCAP log against a config that differs from the one it was logged
    /// with in what the diagnosis takes as known ([`config_mismatch`]).
    pub allow_config_mismatch: bool,
}

/// Whether the diagnosis estimates config field `path`, or takes it from the data, rather
/// than trusting it: declared `estimated` in its `#[param(…)]` (crates/plant/src/params.rs).
/// A log's config may differ from `--config` in these (that is what a diagnosis is for).
/// Every effect (`effects.*`) is estimated too.
fn estimated(path: &str) -> bool {
    ehactl_plant::spec::params()
        .iter()
        .any(|p| p.path == path && p.estimated)
}

/// Sections of the config that describe the rig's hydraulics and mechanics.
const RIG_SECTIONS: &[&str] = &["fluid", "supply", "valve", "cylinder", "mechanics"];

/// Fields in which the config an MCAP record was logged with (`logged`, the `config` of its
/// `/config` message) differs from `cfg` among what the diagnosis takes as known: the rig's
/// fluid, supply, valve, cylinder and mechanics except the estimated ones (declared `estimated`), and
/// `control.mode`.
/// Each as "path: logged A, --config B (unit)". A log of another rig (another geometry,
/// supply pressure, valve) replayed through this one gives a confident wrong answer.
pub fn config_mismatch(cfg: &RigConfig, logged: &Value) -> Vec<String> {
    let mine = cfg.to_json();
    let mut out = Vec::new();
    let unit = |path: &str| {
        ehactl_plant::spec::find(&[ehactl_plant::spec::params()], path)
            .map_or("", |p| p.unit)
            .to_string()
    };
    let show = |v: Option<&Value>| match v {
        Some(Value::String(s)) => format!("`{s}`"),
        Some(v) => v.to_string(),
        None => String::new(),
    };
    let mut compare = |path: String, a: Option<&Value>, b: Option<&Value>| {
        // A field only one side has (a log of another ehactl version, an optional field
        // left unset) is not a difference that can be judged.
        if a.is_none_or(Value::is_null) || b.is_none_or(Value::is_null) {
            return;
        }
        let same = match (a.and_then(Value::as_f64), b.and_then(Value::as_f64)) {
            (Some(x), Some(y)) => x == y || (x - y).abs() <= 1e-12 * x.abs().max(y.abs()),
            _ => a == b,
        };
        if !same {
            let u = unit(&path);
            out.push(format!(
                "{path}: logged {}, --config {}{}",
                show(a),
                show(b),
                if u.is_empty() || u == "-" {
                    String::new()
                } else {
                    format!(" {u}")
                }
            ));
        }
    };
    for sec in RIG_SECTIONS {
        let (a, b) = (logged.get(sec), mine.get(sec));
        let mut keys: Vec<&String> = a
            .and_then(Value::as_object)
            .into_iter()
            .chain(b.and_then(Value::as_object))
            .flat_map(|m| m.keys())
            .collect();
        keys.sort();
        keys.dedup();
        for k in keys {
            let path = format!("{sec}.{k}");
            if estimated(&path) {
                continue;
            }
            compare(path, a.and_then(|m| m.get(k)), b.and_then(|m| m.get(k)));
        }
    }
    compare(
        "control.mode".into(),
        logged.get("control").and_then(|c| c.get("mode")),
        mine.get("control").and_then(|c| c.get("mode")),
    );
    out
}

/// Largest replay cost factor the integration choice may spend for `ehactl diagnose` and the
/// Python bindings ([`Options::integration_max_cost`]): up to 4× the config's substeps to bring
/// the replay's integration error below 0.3 × the noise floor; what remains is reported and
/// counted as noise.
pub const USER_INTEGRATION_COST: f64 = 4.0;

/// Smallest replay cost factor of the integration choice for `ehactl diagnose` and the Python
/// bindings ([`Options::integration_min_cost`]): none. Where the config's substeps leave less
/// than half the allowed integration error, the choice takes the fewest that leave at most
/// half of it by step halving, bounded below only by the stability guard ω·h ≤
/// [`crate::replay::REPLAY_MAX_OMEGA_H`] (the MTS records: 10 → 3 substeps per sample;
/// BENCHMARKS.md "Diagnosis speed").
pub const USER_INTEGRATION_MIN_COST: f64 = 0.0;

/// Load a record (CSV with the config's declared operating inputs, or an ehactl MCAP log) and
/// check it against the rig (sample period, units) and the config's operating inputs (one
/// operating point per record, a missing one warned about:
/// [`crate::record_checks::operating_inputs`]).
pub fn load_checked(cfg: &RigConfig, p: &Path) -> Result<data::Record, SessionError> {
    let inputs: Vec<String> = cfg.inputs.keys().cloned().collect();
    let mut r = data::load_with(p, &inputs).map_err(|e| SessionError::Input(e.to_string()))?;
    let w = data::check_against(&r, &cfg.plant, cfg.timebase().period())
        .map_err(|e| SessionError::Input(e.to_string()))?;
    r.warnings.extend(w);
    let w = crate::record_checks::operating_inputs(cfg, &r).map_err(SessionError::Input)?;
    r.warnings.extend(w);
    Ok(r)
}

/// What `ehactl predict` checks on a loaded record `rec` before it scores samples `score`
/// (all when `None`) of the model at `config_path`: no ehactl log of another rig
/// ([`check_logged_configs`]) and a scored channel that varies
/// ([`crate::record_checks::unscorable`]; only the force when `imposed` or the record is a
/// displacement-controlled one). Returns the constant channels to leave out of the score,
/// each with its warning, when others remain (e.g. the zero force of an ehactl log of a rig
/// without a load cell); an error when none does.
pub fn check_for_prediction(
    cfg: &RigConfig,
    config_path: &Path,
    rec: &data::Record,
    imposed: bool,
    score: Option<std::ops::Range<usize>>,
) -> Result<Vec<(data::ChannelKind, String)>, SessionError> {
    use crate::record_checks::{unscorable, CANNOT_SCORE};
    let label = config_path.display().to_string();
    check_logged_configs(cfg, &label, &[rec], "predict", None)?;
    let only_force = imposed || rec.imposed_motion();
    let r = score.unwrap_or(0..rec.len());
    let flat = unscorable(rec, only_force, r, &cfg.plant);
    let scored = if only_force { 1 } else { rec.channels.len() };
    if !flat.is_empty() && flat.len() >= scored {
        let what: Vec<&str> = flat.iter().map(|(_, w)| w.as_str()).collect();
        return Err(SessionError::Input(format!(
            "{}; {CANNOT_SCORE}: give a record in which it varies",
            what.join("; ")
        )));
    }
    Ok(flat
        .into_iter()
        .map(|(k, w)| {
            (
                k,
                format!(
                    "{w}; {CANNOT_SCORE}: left out of the NRMSE, the other channels are scored"
                ),
            )
        })
        .collect())
}

/// How a record is replayed through `cfg` and a note saying so: closed-loop records (a `ref`
/// column and the config's PD position or PI force loop) through the same controller, since
/// an integrating plant (a piston under position control, a force rig pressing on a stiff
/// load) would drift open loop; otherwise the recorded valve command.
pub fn drive_for(cfg: &RigConfig, rec: &data::Record) -> (Drive, Option<String>) {
    let mut note = None;
    let drive = match (&cfg.control.mode, &rec.reference) {
        (ControlMode::Position, Some(_)) if cfg.pd_gains().is_some() => {
            note = Some("closed-loop replay: the config's PD position controller acts on the recorded `ref`; the recorded `u` is not used".to_string());
            Drive::PositionPd(cfg.pd_gains().expect("checked"))
        }
        (ControlMode::Force, Some(_)) if cfg.pi_gains().is_some() => {
            note = Some("closed-loop replay: the config's PI force controller acts on the recorded force setpoint `ref` (N) and the model's force; the recorded `u` is not used".to_string());
            Drive::ForcePi {
                gains: cfg.pi_gains().expect("checked"),
                max_command: cfg.supervisor.max_command.unwrap_or(f64::INFINITY),
            }
        }
        _ => {
            if rec.reference.is_some() {
                note = Some("open-loop replay with the recorded valve command `u` (the config has no PD position or PI force loop to replay `ref` through)".to_string());
            }
            Drive::Recorded
        }
    };
    (drive, note)
}

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
    check_paths(data_path, validate, out, &choices)?;
    // Held until the report is written: a second run into `out` is refused meanwhile.
    let _lock = out
        .map(crate::outdir::lock)
        .transpose()
        .map_err(SessionError::Io)?;
    let rec = load_single(cfg, data_path)?;
    let val = validate.map(|p| load_single(cfg, p)).transpose()?;
    let mismatch = logged_config_mismatches(cfg, config_label, &rec, val.as_ref(), &choices)?;
    note_long_records(&rec, val.as_ref());
    if let Some(v) = &val {
        check_validation_record(&rec, v)?;
    }
    let mut notes = Vec::new();
    let (drive, note) = drive_for(cfg, &rec);
    notes.extend(note);
    if let (true, Some(v)) = (drive.closed_loop(), &val) {
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
    // The diagnosis's own list: the records' warnings and its findings (replay accuracy).
    let mut warnings: Vec<String> = d.warnings.iter().chain(&mismatch).cloned().collect();
    let (fitted_on, held_out) = single_envelope(cfg, &rec, val.as_ref());
    // A note, not a warning: a held-out part beyond the fitted motion is how a diagnosis tests
    // transfer, and the JSON's `envelope` carries it.
    if let Some(e) = held_out.as_ref().filter(|e| !e.inside) {
        notes.push(format!(
            "the held-out {} lies {}: its score tells how the model extrapolates",
            val.as_ref()
                .map_or("part of the record".to_string(), |v| v.source.clone()),
            e.describe()
        ));
    }
    let with_envelope = RigConfig {
        envelope: fitted_on,
        ..cfg.clone()
    };
    let files = match out {
        Some(dir) => {
            let f = report::write_report(dir, &with_envelope, config_label, &rec, val.as_ref(), &d)
                .map_err(|e| SessionError::Io(e.to_string()))?;
            warnings.extend(f.warnings.iter().cloned());
            Some(f)
        }
        None => None,
    };
    let mut json = run_json(&d, files.as_ref(), &warnings);
    json["envelope"] = serde_json::to_value(&held_out).unwrap_or_default();
    Ok(DiagnoseRun {
        diagnosis: d,
        json,
        warnings,
        notes,
        files,
    })
}

/// The motion a single-record diagnosis fitted (the record, less its held-out last 30 % when
/// no validation record is given; `[envelope]` of its extended config) and the check of the
/// held-out part against it (`None` without a position column).
fn single_envelope(
    cfg: &RigConfig,
    rec: &data::Record,
    val: Option<&data::Record>,
) -> (
    Option<ehactl_config::envelope::Envelope>,
    Option<crate::envelope::EnvelopeCheck>,
) {
    let point = |r: &data::Record, range: std::ops::Range<usize>| {
        let x = r.channel(data::ChannelKind::Position)?;
        let inputs = cfg
            .inputs
            .iter()
            .map(|(n, i)| (n.clone(), r.input_median(n).unwrap_or(i.value)))
            .collect();
        let w = cfg.plant.sensors.position.velocity_window;
        Some(crate::envelope::motion_point(r, x, range, w, inputs))
    };
    let n = rec.len();
    let split = ((1.0 - crate::motion::HOLDOUT) * n as f64).round() as usize;
    let (fit, held) = match val {
        Some(v) => (point(rec, 0..n), point(v, 0..v.len())),
        None => (point(rec, 0..split), point(rec, split..n)),
    };
    let Some(fit) = fit else {
        return (None, None);
    };
    let env = crate::envelope::merge(vec![fit]);
    let check = held.map(|h| crate::envelope::check(&env, &h, &cfg.inputs));
    (Some(env), check)
}

/// Refuses a `validate` file that is `data_path` itself, and an output directory `out` that
/// would write over an input or over files diagnose did not write ([`crate::outdir::check`]).
fn check_paths(
    data_path: &Path,
    validate: Option<&Path>,
    out: Option<&Path>,
    choices: &RunChoices,
) -> Result<(), SessionError> {
    if let Some(v) = validate.filter(|v| crate::outdir::same_file(v, data_path)) {
        return Err(SessionError::Input(format!(
            "--validate {}: is the same file as --data {}; the held-out record must be another recording (or leave --validate out to hold out the last 30 % of --data)",
            v.display(),
            data_path.display()
        )));
    }
    if let Some(dir) = out {
        let mut inputs = vec![("--data file", data_path)];
        inputs.extend(validate.map(|v| ("--validate file", v)));
        inputs.extend(
            choices
                .config_path
                .as_deref()
                .map(|c| ("--config being run", c)),
        );
        crate::outdir::check(dir, &inputs, choices.force, "diagnose")
            .map_err(SessionError::Input)?;
    }
    Ok(())
}

/// [`load_checked`], refusing a displacement-controlled record (diagnosed as a campaign).
fn load_single(cfg: &RigConfig, p: &Path) -> Result<data::Record, SessionError> {
    let r = load_checked(cfg, p)?;
    if r.imposed_motion() {
        return Err(SessionError::Input(format!(
            "{}: a displacement-controlled record (x and force, no `u` or `ref`) is diagnosed as a campaign: the measured motion drives the rod and the load law is fitted (`ehactl diagnose` does this for such a record, or for several --data)",
            r.source
        )));
    }
    Ok(r)
}

/// One warning per MCAP record logged with a config that differs from `cfg` in what the
/// diagnosis takes as known ([`config_mismatch`]); an error unless
/// `choices.allow_config_mismatch`.
fn logged_config_mismatches(
    cfg: &RigConfig,
    config_label: &str,
    rec: &data::Record,
    val: Option<&data::Record>,
    choices: &RunChoices,
) -> Result<Vec<String>, SessionError> {
    let recs: Vec<&data::Record> = std::iter::once(rec).chain(val).collect();
    check_logged_configs(
        cfg,
        config_label,
        &recs,
        "diagnose",
        Some(choices.allow_config_mismatch),
    )
}

/// Refuse an ehactl MCAP log among `recs` that was logged with a config that differs from
/// `cfg` (labelled `config_label`) in what the rig's model takes as known
/// ([`config_mismatch`]): a log of another rig. `allow`: the `--allow-config-mismatch` of a
/// `command` that has the option (then each mismatch is returned as a warning); `None` for
/// one that has not (`predict`). The one check of `diagnose`, a campaign and `predict`.
pub fn check_logged_configs(
    cfg: &RigConfig,
    config_label: &str,
    recs: &[&data::Record],
    command: &str,
    allow: Option<bool>,
) -> Result<Vec<String>, SessionError> {
    let mut mismatch = Vec::new();
    for r in recs {
        let Some(logged) = &r.logged_config else {
            continue;
        };
        let diff = config_mismatch(cfg, logged);
        if diff.is_empty() {
            continue;
        }
        let what = format!(
            "{}: logged with a config that differs from --config {config_label} in what the model takes as known (another rig, or the config changed since): {}",
            r.source,
            diff.join("; ")
        );
        match allow {
            Some(true) => mismatch.push(format!("{what} (accepted by --allow-config-mismatch)")),
            Some(false) => return Err(SessionError::Input(format!(
                "{what}; {command} it against the config it was logged with, or add --allow-config-mismatch if the rig really is the one --config describes"
            ))),
            None => return Err(SessionError::Input(format!(
                "{what}; {command} it with the config it was logged with or the extended.toml of its diagnosis"
            ))),
        }
    }
    Ok(mismatch)
}

/// Long records take minutes; say so at once instead of going silent (a front end's
/// progress bar is hidden when stderr is not a terminal). Figure: 50 000 samples of the
/// 5 kHz bench record take ≈ 21 s on 2 idle cores (BENCHMARKS.md, bench/diagnose_bench.sh).
fn note_long_records(rec: &data::Record, val: Option<&data::Record>) {
    let n_total = rec.t.len() + val.map_or(0, |v| v.t.len());
    if n_total > 50_000 {
        eprintln!(
            "ehactl: note: {n_total} samples to replay per candidate model; expect about {:.0} s or more on 2 cores (fits use the first {} samples of the fitting part, scoring uses all held-out samples)",
            21.0 * n_total as f64 / 50_000.0,
            crate::diagnose::Options::default().max_fit_samples
        );
    }
}

/// Refuses a validation record `v` whose output channels or sample period differ from `rec`'s.
fn check_validation_record(rec: &data::Record, v: &data::Record) -> Result<(), SessionError> {
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
    Ok(())
}

/// The `--json` object of diagnosis `d`: the diagnosis plus the written `files`' paths, the
/// `warnings`, the recommended model and the headline.
fn run_json(d: &Diagnosis, files: Option<&report::ReportFiles>, warnings: &[String]) -> Value {
    let path = |p: &PathBuf| Value::from(p.display().to_string());
    let mut json = serde_json::to_value(d).unwrap_or_default();
    json["extended_config"] = files.map_or(Value::Null, |f| path(&f.extended_config));
    json["report"] = files.map_or(Value::Null, |f| path(&f.report));
    json["plots"] = files.map_or(Value::Null, |f| {
        Value::from(f.plots.iter().map(path).collect::<Vec<_>>())
    });
    json["warnings"] = Value::from(warnings.to_vec());
    let (model, errors) = report::recommended(d);
    json["recommended"] = serde_json::json!({
        "model": model,
        "nrmse": errors,
        "nominal": d.nrmse_nominal,
        "arx": d.nrmse_baseline,
    });
    json["headline"] = Value::from(report::headline(d));
    json
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The diagnosis test bench, configs/diagnose_testrig.toml.
    const TESTRIG_TOML: &str = include_str!("../../../configs/diagnose_testrig.toml");

    /// The fields declared `estimated`: the quantities a diagnosis refits by default and
    /// the initial state it reads from the record.
    #[test]
    fn estimated_fields() {
        let mut v: Vec<&str> = ehactl_plant::spec::params()
            .iter()
            .map(|p| p.path)
            .filter(|p| estimated(p))
            .collect();
        v.sort_unstable();
        assert_eq!(
            v,
            [
                "cylinder.initial_position",
                "cylinder.initial_pressure_a",
                "cylinder.initial_pressure_b",
                "fluid.bulk_modulus",
                "mechanics.damping",
                "mechanics.load_stiffness",
                "mechanics.mass",
                "valve.area_max",
                "valve.flow_at_1mpa",
                "valve.rated_flow",
            ]
        );
    }

    #[test]
    fn a_log_of_another_rig_differs_and_a_hidden_effect_does_not() {
        let rig = RigConfig::from_toml_str(TESTRIG_TOML).unwrap();
        let other =
            RigConfig::from_toml_str(include_str!("../../../configs/sahu2022_force.toml")).unwrap();
        let d = config_mismatch(&rig, &other.to_json());
        assert!(
            d.iter()
                .any(|m| m.starts_with("cylinder.area_a: logged") && m.ends_with(" m²")),
            "{d:?}"
        );
        assert!(d.iter().any(|m| m.starts_with("control.mode")), "{d:?}");
        // The truth of a diagnosis test: the same rig with a hidden effect and other
        // estimated quantities.
        let truth = RigConfig::from_toml_str(&format!(
            "{}\n[effects.time_delay]\ndelay = 0.005\n",
            TESTRIG_TOML.replace("bulk_modulus = 1.4e9", "bulk_modulus = 1.2e9")
        ))
        .unwrap();
        assert_eq!(
            config_mismatch(&rig, &truth.to_json()),
            Vec::<String>::new()
        );
    }
}
