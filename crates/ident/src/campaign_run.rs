//! A campaign diagnosis as the CLI and the Python bindings run it: load every record with the
//! config's declared inputs, fit the campaign law ([`crate::campaign`]), write the report
//! (`report.md`, `extended.toml`, `campaign.json`, `campaign.svg`) and return the JSON object.

use crate::campaign::{diagnose_campaign, Campaign};
use crate::data::ChannelKind;
use crate::session::{load_checked, SessionError};
use ehactl_config::inputs::describe_point;
use ehactl_config::RigConfig;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// A finished campaign.
pub struct CampaignRun {
    /// The law and its scores.
    pub campaign: Campaign,
    /// The `--json` object.
    pub json: Value,
    /// Warnings about the records.
    pub warnings: Vec<String>,
    /// Files written to `--out`.
    pub files: Vec<PathBuf>,
}

/// Run a campaign on `data` (fitting records) and `validate` (held out whole) against `cfg`;
/// `allow_config_mismatch`: take ehactl logs of a config that differs from `cfg` in what the
/// model takes as known ([`crate::session::check_logged_configs`]).
pub fn run(
    cfg: &RigConfig,
    config_path: &Path,
    data: &[PathBuf],
    validate: &[PathBuf],
    out: Option<&Path>,
    force: bool,
    allow_config_mismatch: bool,
) -> Result<CampaignRun, SessionError> {
    refuse_same_files(data, validate)?;
    if let Some(dir) = out {
        let mut inputs: Vec<(&str, &Path)> =
            data.iter().map(|d| ("--data file", d.as_path())).collect();
        inputs.extend(validate.iter().map(|v| ("--validate file", v.as_path())));
        inputs.push(("--config being run", config_path));
        crate::outdir::check(dir, &inputs, force, "diagnose").map_err(SessionError::Input)?;
    }
    // Held until the last file is written: a second run into `out` is refused meanwhile.
    let _lock = out
        .map(crate::outdir::lock)
        .transpose()
        .map_err(SessionError::Io)?;
    // Records load in parallel (a campaign of long CSVs is parse-bound).
    use rayon::prelude::*;
    let load = |ps: &[PathBuf]| -> Result<Vec<_>, SessionError> {
        ps.par_iter().map(|p| load_checked(cfg, p)).collect()
    };
    let fit = load(data)?;
    let val = load(validate)?;
    let mut warnings = check_records(cfg, config_path, &fit, &val, allow_config_mismatch)?;
    warnings.extend(
        fit.iter()
            .chain(&val)
            .flat_map(|r| r.warnings.iter().cloned()),
    );
    let c = diagnose_campaign(cfg, &fit, &val).map_err(SessionError::Input)?;
    // A record without a declared input is noted by the load and by the campaign: once.
    warnings.extend(
        c.notes
            .iter()
            .filter(|n| !warnings.contains(n))
            .cloned()
            .collect::<Vec<_>>(),
    );
    if let Some(why) = &c.closed_loop.dropped {
        warnings.push(format!("the campaign law is dropped: {why}"));
    }
    let files = match out {
        Some(dir) => write_outputs(dir, cfg, config_path, &c, &fit, &val)?,
        None => Vec::new(),
    };
    let json = campaign_json(&c, &files, &warnings);
    Ok(CampaignRun {
        campaign: c,
        json,
        warnings,
        files,
    })
}

/// Refuses a campaign that names one file twice (`--data` or `--validate`).
fn refuse_same_files(data: &[PathBuf], validate: &[PathBuf]) -> Result<(), SessionError> {
    let all: Vec<&PathBuf> = data.iter().chain(validate).collect();
    for (i, a) in all.iter().enumerate() {
        if let Some(b) = all[..i].iter().find(|b| crate::outdir::same_file(a, b)) {
            return Err(SessionError::Input(format!(
                "{} and {} are the same file; each record of a campaign must be another recording",
                b.display(),
                a.display()
            )));
        }
    }
    Ok(())
}

/// Writes the campaign's outputs into `dir`: `extended.toml` (unless the closed-loop check
/// dropped the law), `report.md`, `campaign.json` and `campaign.svg`; the paths written.
fn write_outputs(
    dir: &Path,
    cfg: &RigConfig,
    config_path: &Path,
    c: &Campaign,
    fit: &[crate::data::Record],
    val: &[crate::data::Record],
) -> Result<Vec<PathBuf>, SessionError> {
    let mut files = Vec::new();
    let mut od = crate::outdir::OutDir::create(dir).map_err(SessionError::Io)?;
    let toml = format!(
        "# Extended by `ehactl diagnose` from a campaign of {} records against {}.\n# {}\n# The law: [effects.polynomial_force] at the config's operating point; its dependence on\n# the operating inputs: [inputs.<name>.linear / .quadratic / .saturating / .hinge]\n# (ehactl_config::inputs);\n# what it was fitted on: [envelope] (ehactl predict says when a record lies outside).\n{}",
        fit.len() + val.len(),
        config_path.display(),
        c.cause,
        c.extended.to_toml_string()
    );
    if c.closed_loop.dropped.is_none() {
        files.push(
            od.write("extended.toml", toml.as_bytes())
                .map_err(SessionError::Io)?,
        );
    }
    files.push(
        od.write("report.md", report_md(c).as_bytes())
            .map_err(SessionError::Io)?,
    );
    let json = serde_json::to_string_pretty(c).unwrap_or_default();
    files.push(
        od.write("campaign.json", json.as_bytes())
            .map_err(SessionError::Io)?,
    );
    // Measured vs predicted force of every record (nominal beside it).
    let preds: Vec<(Vec<f64>, Vec<f64>)> = fit
        .iter()
        .chain(val)
        .map(|r| {
            let p = crate::predict::predict(&c.extended, r, true, None)
                .map(|p| p.predicted[0].1.clone())
                .unwrap_or_default();
            let n = crate::predict::predict(cfg, r, true, None)
                .map(|p| p.predicted[0].1.clone())
                .unwrap_or_default();
            (p, n)
        })
        .collect();
    let panels: Vec<crate::plots::PredictionPanel<'_>> = fit
        .iter()
        .chain(val)
        .zip(&preds)
        .zip(&c.records)
        .filter_map(|((r, (p, n)), s)| {
            Some(crate::plots::PredictionPanel {
                title: format!(
                    "{} force (N)",
                    Path::new(&r.source)
                        .file_name()
                        .map_or(r.source.clone(), |f| f.to_string_lossy().into_owned())
                ),
                t: &r.t,
                measured: r.channel(ChannelKind::Force)?,
                predicted: p,
                nominal: Some(n),
                shade_from: Some(s.scored.0),
                band: None,
            })
        })
        .collect();
    files.push(
        od.write_with("campaign.svg", |p| crate::plots::prediction(p, &panels))
            .map_err(SessionError::Io)?,
    );
    Ok(files)
}

/// The campaign's `--json`: the campaign with `mode`, `causes`, `nrmse`, the files written and
/// the warnings.
fn campaign_json(c: &Campaign, files: &[PathBuf], warnings: &[String]) -> Value {
    let mut json = serde_json::to_value(c).unwrap_or_default();
    json["mode"] = Value::from("campaign");
    json["causes"] = Value::from(if c.terms.is_empty() {
        Vec::<String>::new()
    } else {
        vec!["polynomial_force".to_string()]
    });
    json["nrmse"] = serde_json::json!({
        "overall": c.pooled.law,
        "nominal": c.pooled.nominal,
        "arx": c.pooled.arx,
    });
    let file = |name: &str| {
        files
            .iter()
            .find(|f| f.file_name().is_some_and(|n| n == name))
            .map_or(Value::Null, |f| Value::from(f.display().to_string()))
    };
    json["extended_config"] = file("extended.toml");
    json["report"] = file("report.md");
    json["warnings"] = Value::from(warnings.to_vec());
    json
}

/// The records as a campaign may take them: no two with the same samples, no ehactl log of
/// another rig (unless allowed; its warnings returned), and a force that varies over what is
/// fitted and what is scored (the last [`crate::campaign::HOLDOUT`] of a fitting record held
/// out when no validation record is given).
fn check_records(
    cfg: &RigConfig,
    config_path: &Path,
    fit: &[crate::data::Record],
    val: &[crate::data::Record],
    allow_config_mismatch: bool,
) -> Result<Vec<String>, SessionError> {
    let all: Vec<&crate::data::Record> = fit.iter().chain(val).collect();
    crate::record_checks::distinct(&all).map_err(SessionError::Input)?;
    let w = crate::session::check_logged_configs(
        cfg,
        &config_path.display().to_string(),
        &all,
        "diagnose",
        Some(allow_config_mismatch),
    )?;
    // The fitting and held-out parts, or the whole record fitted.
    let parts = |r: &crate::data::Record, held: bool| {
        let n = r.len();
        let nf = ((1.0 - crate::campaign::HOLDOUT) * n as f64).round() as usize;
        let cut = if held { nf.min(n) } else { n };
        [0..cut, cut..n]
    };
    let held = val.is_empty();
    for (r, part) in fit
        .iter()
        .flat_map(|r| parts(r, held).into_iter().map(move |p| (r, p)))
        .chain(val.iter().map(|r| (r, 0..r.len())))
    {
        if !part.is_empty() {
            crate::record_checks::scorable(r, true, part, &cfg.plant)
                .map_err(SessionError::Input)?;
        }
    }
    Ok(w)
}

fn report_md(c: &Campaign) -> String {
    let mut s = String::from("# Campaign diagnosis\n\n");
    let mut lines = c.summary.lines();
    if let Some(first) = lines.next() {
        s += &format!("**{first}**\n\n");
    }
    s += "| record | role | operating point | law | nominal | ARX | fitted envelope |\n|---|---|---|---|---|---|---|\n";
    for r in &c.records {
        s += &format!(
            "| {} | {} | {} | {:.4} | {:.4} | {:.4} | {} |\n",
            r.source,
            r.role,
            describe_point(&r.operating_point),
            r.nrmse.law,
            r.nrmse.nominal,
            r.nrmse.arx,
            r.envelope.describe()
        );
    }
    s += &format!(
        "| pooled | | | {:.4} | {:.4} | {:.4} | |\n\n",
        c.pooled.law, c.pooled.nominal, c.pooled.arx
    );
    s += "## Law\n\n| term | coefficient at zero input | unit | dependence | share of force variance |\n|---|---|---|---|---|\n";
    for t in &c.terms {
        s += &format!(
            "| {} (`{}`) | {:.6e} | {} | {} | {:.1} % |\n",
            t.name,
            t.path,
            t.at_zero,
            t.unit,
            if t.dependence.is_empty() {
                "none".to_string()
            } else {
                t.dependence
                    .iter()
                    .map(|(n, (f, k))| format!("{n}: {f:?} {k:?}"))
                    .collect::<Vec<_>>()
                    .join("; ")
            },
            100.0 * t.share
        );
    }
    s += "\n";
    for l in lines {
        s += &format!("{l}\n\n");
    }
    s += &format!(
        "Transfer NRMSE of the chosen law (fitted on the first 60 % of each fitting part, predicting the rest): {:.4}. Dependence: {}.\n\nPlot: campaign.svg (measured, nominal, predicted force; shaded: scored).\n",
        c.nrmse_transfer, c.dependence_check
    );
    s
}
