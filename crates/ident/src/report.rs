//! Report output: extended config (TOML runnable by `ehactl run`), trace CSVs, the SVG plots
//! ([`crate::plots`]) and the Markdown report.

use crate::data::Record;
use crate::diagnose::Diagnosis;
use crate::replay::Replay;
use ehactl_config::RigConfig;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Files written by [`write_report`].
#[derive(Debug, Clone)]
pub struct ReportFiles {
    /// Extended config.
    pub extended_config: PathBuf,
    /// Markdown report.
    pub report: PathBuf,
    /// SVG plots that were made.
    pub plots: Vec<PathBuf>,
    /// Warnings about the report (e.g. no traces to plot).
    pub warnings: Vec<String>,
}

/// The nominal config with the plant replaced by the extended plant, as TOML text with a
/// comment header naming the accepted effects.
pub fn extended_config_text(nominal: &RigConfig, d: &Diagnosis, data: &str) -> String {
    let mut cfg = nominal.clone();
    cfg.plant = d.extended.clone();
    cfg.rig.name = format!("{}_extended", nominal.rig.name);
    cfg.rig.description = format!(
        "{} — extended by `ehactl diagnose` with [{}]",
        nominal.rig.description,
        d.causes.join(", ")
    );
    let mut s = String::new();
    let _ = writeln!(s, "# Written by `ehactl diagnose` from data {data}.");
    let _ = writeln!(
        s,
        "# Nominal config plus accepted effects [{}] with fitted parameters",
        d.causes.join(", ")
    );
    let _ = writeln!(
        s,
        "# (nominal valve gain, β₀, damping and spring rate refit within ±15 %). SI units."
    );
    for (k, v) in &d.extended_params {
        let _ = writeln!(s, "#   {k} = {v:.6e}");
    }
    let _ = writeln!(
        s,
        "# Held-out NRMSE: nominal {:.4} → extended {:.4} (gain {:.1} %).",
        d.nrmse_nominal.overall,
        d.nrmse_extended.overall,
        d.gain * 100.0
    );
    if let Some(g) = d.greybox.as_ref().filter(|g| g.accepted) {
        let _ = writeln!(
            s,
            "# Grey-box extension (catalogue exhausted): {}.\n# Held-out NRMSE with it: {:.4} ({:.2} × the ARX baseline).",
            g.structure, g.nrmse_validation.overall, g.ratio_to_baseline
        );
    }
    s.push('\n');
    s.push_str(&cfg.to_toml_string());
    s
}

fn trace_csv(rec: &Record, nom: &Replay, ext: &Replay, split: usize) -> String {
    let mut s = String::from("t,u,held_out,v_model");
    for c in &rec.channels {
        let n = c.kind.column();
        let _ = write!(s, ",meas_{n},nom_{n},ext_{n}");
    }
    s.push('\n');
    for k in 0..rec.len() {
        let _ = write!(
            s,
            "{:e},{:e},{},{:e}",
            rec.t[k],
            rec.u[k],
            (k >= split) as u8,
            nom.v.get(k).copied().unwrap_or(f64::NAN)
        );
        for (c, ch) in rec.channels.iter().enumerate() {
            let _ = write!(
                s,
                ",{:e},{:e},{:e}",
                ch.values[k],
                nom.y[c].get(k).copied().unwrap_or(f64::NAN),
                ext.y[c].get(k).copied().unwrap_or(f64::NAN)
            );
        }
        s.push('\n');
    }
    s
}

/// The grey-box section of report.md ([`crate::greybox`]).
fn greybox_section(d: &Diagnosis, g: &crate::greybox::GreyBox) -> String {
    let mut s = format!(
        "## Grey-box extension (catalogue exhausted)\n\n{}: {}.\n\n",
        if g.accepted {
            "Accepted"
        } else {
            "Not accepted"
        },
        g.structure
    );
    if !g.terms.is_empty() {
        s.push_str("| term | coefficient | fitting-part NRMSE after | held-out NRMSE after (reported only) |\n|---|---|---|---|\n");
        for t in &g.terms {
            let _ = writeln!(
                s,
                "| {} (`{}`) | {:.4e} {}{} | {:.4} | {:.4} |",
                t.physics,
                t.path,
                t.value,
                t.unit,
                if t.at_bound {
                    " (on its bound: a proxy)"
                } else {
                    ""
                },
                t.nrmse_train,
                t.nrmse_validation
            );
        }
    }
    s.push_str("\n| channel | extended (catalogue) | extended + grey-box | ARX baseline |\n|---|---|---|---|\n");
    for (k, v) in &g.nrmse_validation.channels {
        let _ = writeln!(
            s,
            "| `{k}` | {:.4} | {:.4} | {:.4} |",
            d.nrmse_extended
                .channels
                .get(k)
                .copied()
                .unwrap_or(f64::NAN),
            v,
            d.nrmse_baseline
                .channels
                .get(k)
                .copied()
                .unwrap_or(f64::NAN)
        );
    }
    let _ = writeln!(
        s,
        "| **overall** | **{:.4}** | **{:.4}** | **{:.4}** |\n\nExtended + grey-box / ARX baseline held-out NRMSE = **{:.2}**. Terms were chosen on the fitting part only (fitting-part NRMSE {:.4} → {:.4}); the held-out part was scored afterwards. Selection:\n",
        d.nrmse_extended.overall,
        g.nrmse_validation.overall,
        d.nrmse_baseline.overall,
        g.ratio_to_baseline,
        g.nrmse_train_before,
        g.nrmse_train
    );
    for l in &g.selection {
        let _ = writeln!(s, "- {l}");
    }
    s.push('\n');
    if g.accepted {
        s.push_str("The extended config (`extended.toml`) carries these terms; the plots show the extended + grey-box model.\n\n");
    }
    s
}

fn table(d: &Diagnosis) -> String {
    let mut s = String::from(
        "| channel | nominal | nominal refit | extended | ARX baseline |\n|---|---|---|---|---|\n",
    );
    let get = |e: &crate::diagnose::Errors, k: &str| e.channels.get(k).copied().unwrap_or(f64::NAN);
    for (k, v) in &d.nrmse_nominal.channels {
        let _ = writeln!(
            s,
            "| `{k}` | {v:.4} | {:.4} | {:.4} | {:.4} |",
            get(&d.nrmse_refit, k),
            get(&d.nrmse_extended, k),
            get(&d.nrmse_baseline, k)
        );
    }
    let _ = writeln!(
        s,
        "| **overall** | **{:.4}** | **{:.4}** | **{:.4}** | **{:.4}** |",
        d.nrmse_nominal.overall,
        d.nrmse_refit.overall,
        d.nrmse_extended.overall,
        d.nrmse_baseline.overall
    );
    s
}

/// The model the diagnosis recommends — the one `extended.toml` holds — in words, and its
/// held-out errors: the grey-box law on the catalogue model when one was accepted, else the
/// catalogue model with the accepted effects, else the nominal model refit within its stated
/// uncertainty.
pub fn recommended(d: &Diagnosis) -> (String, &crate::ctx::Errors) {
    match &d.greybox {
        Some(g) if g.accepted => (
            format!(
                "grey-box rod-force law of {} term(s){}",
                g.terms.len(),
                if d.causes.is_empty() {
                    String::new()
                } else {
                    format!(" on {}", d.causes.join(" + "))
                }
            ),
            &g.nrmse_validation,
        ),
        _ if d.causes.is_empty() => (
            "nominal model, refit within its uncertainty".into(),
            &d.nrmse_extended,
        ),
        _ => (
            format!("catalogue model with {}", d.causes.join(" + ")),
            &d.nrmse_extended,
        ),
    }
}

/// First line of the text output and of report.md: the recommended model's held-out NRMSE
/// beside the nominal model's and the ARX baseline's, overall and per channel.
pub fn headline(d: &Diagnosis) -> String {
    let (model, e) = recommended(d);
    let per: Vec<String> = e
        .channels
        .iter()
        .map(|(c, v)| {
            format!(
                "{c} {v:.4} (nominal {:.4}, ARX {:.4})",
                d.nrmse_nominal.channels.get(c).copied().unwrap_or(f64::NAN),
                d.nrmse_baseline
                    .channels
                    .get(c)
                    .copied()
                    .unwrap_or(f64::NAN)
            )
        })
        .collect();
    let opening = match (&d.closest, d.status.as_str()) {
        (Some(c), "edge_fit" | "not_explained") => format!(
            "Closest catalogue effect: {}{} ({}); the record is not explained. Recommended model (extended.toml)",
            c.effect,
            if c.at_edge { " at the edge of its range" } else { "" },
            c.reasons.join("; ")
        ),
        _ if d.cause == "none" && !d.detection_limits.is_empty() => format!(
            "No discrepancy beyond noise, no effect above these detection limits (the loosest: {})",
            crate::limits::loosest(&d.detection_limits, 3).join("; ")
        ),
        _ if d.cause == "none" => "No discrepancy beyond noise".to_string(),
        _ => "Recommended model (extended.toml)".to_string(),
    };
    format!(
        "{opening}: {model}: held-out NRMSE {:.4} vs nominal {:.4} and ARX {:.4}; per channel: {}",
        e.overall,
        d.nrmse_nominal.overall,
        d.nrmse_baseline.overall,
        per.join(", ")
    )
}

/// Write extended.toml, traces.csv (and validation_traces.csv), diagnosis.json, the plots
/// and report.md into `dir`.
pub fn write_report(
    dir: &Path,
    nominal: &RigConfig,
    config_path: &str,
    rec: &Record,
    val: Option<&Record>,
    d: &Diagnosis,
) -> Result<ReportFiles, String> {
    // Every file atomically, listed in the directory's manifest (`crate::outdir`); the
    // caller checked the directory with `outdir::check` before the diagnosis.
    let mut out = crate::outdir::OutDir::create(dir)?;
    let mut w = |name: &str, text: &str| out.write(name, text.as_bytes());
    let extended_config = w(
        "extended.toml",
        &extended_config_text(nominal, d, &rec.source),
    )?;
    let mut warnings = Vec::new();
    if let (Some(nom), Some(ext)) = (&d.traces.nominal, &d.traces.extended) {
        w(
            "traces.csv",
            &trace_csv(rec, nom, ext, d.traces.split_index),
        )?;
    }
    if let (Some(v), Some((nom, ext))) = (val, &d.traces.validation) {
        w("validation_traces.csv", &trace_csv(v, nom, ext, 0))?;
    }
    let json = serde_json::to_string_pretty(d).map_err(|e| e.to_string())?;
    w("diagnosis.json", &json)?;
    for t in &d.next_tests {
        w(&t.file, &crate::nexttest::toml_text(t))?;
    }
    let plots = match (&d.traces.nominal, &d.traces.extended) {
        (Some(nom), Some(ext)) => {
            let v = val
                .zip(d.traces.validation.as_ref())
                .map(|(v, (vn, ve))| (v, vn, ve));
            crate::plots::draw(&mut out, rec, nom, ext, d.traces.split_index, v)?
        }
        _ => {
            warnings.push("plots not made: the diagnosis kept no replay traces".to_string());
            Vec::new()
        }
    };
    let r = report_text(config_path, rec, d, &warnings, &plots);
    let report = out.write("report.md", r.as_bytes())?;
    Ok(ReportFiles {
        extended_config,
        report,
        plots,
        warnings,
    })
}

/// report.md: the conclusion, the held-out errors against the nominal model and the ARX
/// baseline, the grey-box law and every section after them (`warnings`: the report's own,
/// `plots`: the plots made).
fn report_text(
    config_path: &str,
    rec: &Record,
    d: &Diagnosis,
    warnings: &[String],
    plots: &[PathBuf],
) -> String {
    let mut r = String::new();
    let _ = writeln!(r, "# ehactl diagnose: {}\n", rec.source);
    let _ = writeln!(r, "**{}**\n", headline(d));
    let _ = writeln!(r, "Nominal config: `{config_path}`. {}.\n", d.split);
    let _ = writeln!(
        r,
        "## Conclusion\n\n**Cause: `{}`** (status `{}`){}\n",
        d.cause,
        d.status,
        if d.causes.len() > 1 {
            format!(" (accepted in order: {})", d.causes.join(", "))
        } else {
            String::new()
        }
    );
    let _ = writeln!(r, "{}\n", d.summary);
    let _ = writeln!(
        r,
        "Extended config: [`extended.toml`](extended.toml) (runnable with `ehactl run`).\n"
    );
    let _ = writeln!(
        r,
        "## Held-out NRMSE (rms error / std of the measured channel)\n\n{}",
        table(d)
    );
    let _ = writeln!(
        r,
        "Gain (1 − extended/nominal overall): **{:.1} %**; estimated noise floor {:.4}.\n",
        d.gain * 100.0,
        d.noise_floor
    );
    let _ = writeln!(
        r,
        "ARX baseline: {}. Extended / baseline held-out NRMSE = {:.2} ({}).\n",
        d.baseline.structure,
        d.nrmse_extended.overall / d.nrmse_baseline.overall,
        if d.nrmse_extended.overall < d.nrmse_baseline.overall {
            "the physical model is better than the black-box baseline"
        } else {
            "the black-box baseline is as good or better: the physical model does not yet earn its keep on this record"
        }
    );
    if let Some(g) = &d.greybox {
        r.push_str(&greybox_section(d, g));
    }
    write_residual_test(&mut r, d);
    write_fit_notes(&mut r, d);
    write_residual_analysis(&mut r, d);
    write_hypothesis_tests(&mut r, d);
    write_detection_limits(&mut r, d);
    crate::nexttest::write_section(&mut r, &d.next_tests);
    write_closing(&mut r, d, warnings, plots);
    r
}

/// The section on whether the held-out residual is noise (per-channel level and whiteness).
fn write_residual_test(r: &mut String, d: &Diagnosis) {
    let rt = &d.residual_test;
    let _ = writeln!(
        r,
        "## Is the held-out residual noise? ({} model)\n\n| channel | NRMSE / noise floor | Ljung–Box Q (20 lags; white if ≤ {:.1}) | noise |\n|---|---|---|---|",
        rt.model,
        crate::residual::LB_CRIT_20
    );
    for c in &rt.channels {
        let _ = writeln!(
            r,
            "| `{}` | {:.2} | {:.1} | {} |",
            c.channel,
            c.level,
            c.ljung_box,
            if c.noise { "yes" } else { "**no**" }
        );
    }
    let _ = writeln!(
        r,
        "\nA channel counts as noise when its level is ≤ {} or ≤ {} and white. {}\n",
        rt.soft_level,
        crate::residual::LEVEL_HARD,
        rt.signature
            .as_ref()
            .map_or("Every channel is noise.".to_string(), |s| format!(
                "Signature: {}.",
                s.text
            ))
    );
}

/// The replay accuracy, the nominal parameters on a bound and the sensor offsets.
fn write_fit_notes(r: &mut String, d: &Diagnosis) {
    let ig = &d.integration;
    let _ = writeln!(
        r,
        "Replay accuracy: {} substeps per sample (the config gives {}; cost limit {}×); integration error by step halving on the fitting window {} vs noise floor {} — {}.\n",
        ig.substeps,
        ig.config_substeps,
        ig.max_cost,
        ig.error.iter().map(|(k, v)| format!("`{k}` {v:.2e}")).collect::<Vec<_>>().join(", "),
        ig.floor.iter().map(|(k, v)| format!("`{k}` {v:.2e}")).collect::<Vec<_>>().join(", "),
        if ig.met {
            format!("below {:.0} % of the floor on every channel", ig.ratio_limit * 100.0)
        } else {
            "NOT below the required fraction of the floor within the cost limit: the remaining integration error is counted as noise (added to the floor)".to_string()
        }
    );
    if !d.refit_at_bounds.is_empty() || !d.extended_at_bounds.is_empty() {
        let _ = writeln!(
            r,
            "Nominal parameters on a bound of their stated uncertainty (`[uncertainty]`, default ±15 %) — evidence of a missing effect or a wrong nominal value: refit {}; final model {}.\n",
            if d.refit_at_bounds.is_empty() { "none".to_string() } else { d.refit_at_bounds.join("; ") },
            if d.extended_at_bounds.is_empty() { "none".to_string() } else { d.extended_at_bounds.join("; ") },
        );
    }
    if d.sensor_offsets.is_empty() {
        let _ = writeln!(
            r,
            "Sensor offsets: not estimated (the sensors' zeros are trusted and a level shift counts as model error; `--sensor-offsets` estimates one per channel).\n"
        );
    } else {
        let unit = |ch: &str| match ch {
            "force" => "N",
            "x" => "m",
            "p_a" | "p_b" => "Pa",
            "x_v" => "(fraction of spool travel)",
            _ => "",
        };
        let list: Vec<String> = d
            .sensor_offsets
            .iter()
            .map(|(ch, b)| format!("`{ch}` {b:+.4e} {}", unit(ch)))
            .collect();
        let _ = writeln!(
            r,
            "Sensor offsets (measured − extended model, mean over the fitting part; every model gets its own, fitted the same way, and they carry over to the held-out part): {}.\n",
            list.join(", ")
        );
    }
}

/// The residual analyses of the nominal replay and of the refit nominal model.
fn write_residual_analysis(r: &mut String, d: &Diagnosis) {
    for (title, a) in [
        ("nominal replay", &d.analysis),
        (
            "nominal parameters refit within ±15 % (the evidence used)",
            &d.analysis_refit,
        ),
    ] {
        let _ = writeln!(r, "## Residual analysis: {title} (fitting part)\n");
        let _ = writeln!(r, "- velocity reversals: residual RMS within 10 ms of a reversal is {:.2}× the overall RMS", a.reversal_ratio);
        let _ = writeln!(r, "- small command (|u| < 5 % of max): {:.2}× the overall RMS; large command (> 70 %): {:.2}×", a.small_command_ratio, a.large_command_ratio);
        if let Some(b) = a.bias_share {
            let _ = writeln!(
                r,
                "- mean pressure residual (before any sensor offset) is {:.0} % of its RMS (level shift)",
                b * 100.0
            );
        }
        let _ = writeln!(
            r,
            "- measured outputs lag the model by {:.2} ms (cross-correlation)",
            a.lag * 1e3
        );
        let _ = writeln!(
            r,
            "- residual-to-signal spectrum ratio peaks near {:.1} Hz",
            a.mode_frequency
        );
        for t in &a.tones {
            let _ = writeln!(r, "- narrow residual line: {:.1} Hz on `{}`, amplitude ≈ {:.3e}, {:.0}× its neighbourhood", t.frequency, t.channel, t.amplitude, t.prominence);
        }
        r.push('\n');
    }
}

/// The table of the hypothesis tests (every catalogue effect).
fn write_hypothesis_tests(r: &mut String, d: &Diagnosis) {
    let _ = writeln!(
        r,
        "## Hypothesis tests (every catalogue effect against the refit nominal model)\n"
    );
    let _ = writeln!(r, "| effect | accepted | NRMSE train | NRMSE held-out | score | parameters | evidence |\n|---|---|---|---|---|---|---|");
    for c in &d.candidates {
        let _ = writeln!(
            r,
            "| `{}` | {} | {:.4} | {:.4} | {:.3} | {} | {} |",
            c.effect,
            if c.accepted { "**yes**" } else { "no" },
            c.nrmse_train,
            c.nrmse_validation,
            c.score,
            c.params
                .iter()
                .map(|(k, v)| format!("{k} = {v:.3e}"))
                .collect::<Vec<_>>()
                .join("<br>"),
            c.evidence.replace('|', "/")
        );
    }
}

/// The table of detection limits (every catalogue effect tested and not named).
fn write_detection_limits(r: &mut String, d: &Diagnosis) {
    if d.detection_limits.is_empty() {
        return;
    }
    let _ = writeln!(
        r,
        "\n## Detection limits (the smallest size of each effect not named that this record would have revealed)\n\nEach structure of the effect injected into the final model's held-out replay, the part the nominal refit absorbs projected out, judged by the acceptance test at the noise floor; the structure hardest to see gives the limit, which is then checked by adding the effect at that size to the record itself and fitting it under the search's acceptance test, raised where that fit is not accepted (DIAGNOSIS.md \"Detection limits\").\n\n| effect | parameter | limit | unit | structure | found by | range searched (weakest → strongest) |\n|---|---|---|---|---|---|---|"
    );
    for (e, l) in &d.detection_limits {
        let _ = writeln!(
            r,
            "| `{e}` | `{}` | {} | {} | {} | {} | {} |",
            l.parameter,
            match l.limit {
                Some(v) => format!("{} {v:.3e}", if l.stronger == "larger" { "≥" } else { "≤" }),
                None => l.note.clone(),
            },
            l.unit,
            match (l.variant.as_str(), l.shape.as_str()) {
                ("", _) => "-".to_string(),
                (v, "") => v.to_string(),
                (v, shape) => format!("{v}, {shape}"),
            },
            if l.method.is_empty() { "-" } else { &l.method },
            if l.range[0].is_finite() {
                format!("{:.3e} → {:.3e}", l.range[0], l.range[1])
            } else {
                "-".to_string()
            }
        );
    }
}

/// The closing sections: a better nominal fit, ambiguities, warnings (the diagnosis's and
/// the report's own `warnings`) and the `plots`.
fn write_closing(r: &mut String, d: &Diagnosis, warnings: &[String], plots: &[PathBuf]) {
    if !d.refit_continued.is_empty() {
        let _ = writeln!(r, "\n## A better nominal fit than the refit's\n");
        for a in &d.refit_continued {
            let _ = writeln!(r, "- {a}.");
        }
    }
    if !d.ambiguities.is_empty() {
        let _ = writeln!(r, "\n## What the data cannot tell apart\n");
        for a in &d.ambiguities {
            let _ = writeln!(r, "- {a}");
        }
    }
    let all_warn: Vec<&String> = d.warnings.iter().chain(warnings).collect();
    if !all_warn.is_empty() {
        let _ = writeln!(r, "\n## Warnings\n");
        for w in all_warn {
            let _ = writeln!(r, "- {w}");
        }
    }
    if !plots.is_empty() {
        let _ = writeln!(r, "\n## Plots\n");
        for p in plots {
            let name = p
                .file_name()
                .map_or(String::new(), |n| n.to_string_lossy().into_owned());
            let _ = writeln!(r, "![{name}]({name})\n");
        }
    }
}
