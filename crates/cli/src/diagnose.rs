//! `ehactl diagnose`: name what the simulation gets wrong on measured data (see ehactl-ident).

use ehactl_config::RigConfig;
use ehactl_ident::progress::{Progress, ProgressSink};
use ehactl_ident::session::{self, SessionError};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// The on/off options of `ehactl diagnose`.
pub struct Switches {
    /// `--sensor-offsets`.
    pub sensor_offsets: bool,
    /// `--force`: write into an --out directory holding other files.
    pub force: bool,
    /// `--allow-config-mismatch`.
    pub allow_config_mismatch: bool,
}

/// Run the diagnosis of `data_path` against the nominal `config`; exit 0 ok, 2 bad config,
/// data or --out directory, 1 other failure (I/O).
pub fn cmd_diagnose(
    config: &Path,
    data: &[PathBuf],
    validate: &[PathBuf],
    out: Option<PathBuf>,
    json: bool,
    sw: Switches,
) -> ExitCode {
    let bad = |msg: String| {
        eprintln!("ehactl: {msg}");
        ExitCode::from(2)
    };
    let cfg = match RigConfig::load(config) {
        Ok(c) => c,
        Err(e) => return bad(crate::config_load_message(config, &e)),
    };
    // Several records, or one displacement-controlled record: a campaign.
    let motion_only =
        data.len() == 1 && ehactl_ident::data::is_motion_only(&data[0]).unwrap_or(false);
    if data.len() > 1 || validate.len() > 1 || motion_only {
        return cmd_campaign(&cfg, config, data, validate, out.as_deref(), json, &sw);
    }
    let data_path = data[0].as_path();
    let validate = validate.first().map(PathBuf::as_path);
    let bar =
        crate::styled_bar("{spinner} diagnose {msg} [{bar:30}] {pos}/{len} fits {elapsed_precise}");
    let b = bar.clone();
    let progress = ProgressSink::new(move |p: &Progress| {
        b.set_message(p.stage.clone());
        b.set_length(p.total);
        b.set_position(p.done);
    });
    let run = session::run(
        &cfg,
        &config.display().to_string(),
        data_path,
        validate,
        out.as_deref(),
        session::RunChoices {
            progress,
            sensor_offsets: sw.sensor_offsets,
            config_path: Some(config.to_path_buf()),
            force: sw.force,
            allow_config_mismatch: sw.allow_config_mismatch,
        },
    );
    bar.finish_and_clear();
    let run = match run {
        Ok(r) => r,
        Err(SessionError::Input(e)) => return bad(e),
        Err(SessionError::Io(e)) => {
            eprintln!("ehactl: {e}");
            return ExitCode::from(1);
        }
    };
    for w in &run.warnings {
        eprintln!("ehactl: warning: {w}");
    }
    for n in &run.notes {
        eprintln!("ehactl: note: {n}");
    }
    if json {
        println!("{}", run.json);
    } else {
        print_text(&run, data_path, config);
    }
    ExitCode::SUCCESS
}

/// The text report of a diagnosis of `data_path` against `config`: the cause and status,
/// the held-out errors, the candidates, the ambiguities, the summary and the files written.
fn print_text(run: &session::DiagnoseRun, data_path: &Path, config: &Path) {
    let (d, files) = (&run.diagnosis, &run.files);
    println!("{}", ehactl_ident::report::headline(d));
    println!(
        "ehactl diagnose {} (config {})",
        data_path.display(),
        config.display()
    );
    println!("  {}", d.split);
    println!(
        "  cause         {}{}",
        d.cause,
        if d.causes.len() > 1 {
            format!(" (accepted: {})", d.causes.join(", "))
        } else {
            String::new()
        }
    );
    println!("  status        {}", d.status);
    println!("  held-out NRMSE nominal {:.4} → refit {:.4} → extended {:.4} (gain {:.1} %, noise floor {:.4})", d.nrmse_nominal.overall, d.nrmse_refit.overall, d.nrmse_extended.overall, d.gain * 100.0, d.noise_floor);
    println!(
        "  ARX baseline held-out NRMSE {:.4} (same split)",
        d.nrmse_baseline.overall
    );
    println!("  candidates:");
    for c in &d.candidates {
        println!(
            "    {} {:<22} held-out {:.4}  {}",
            if c.accepted { "*" } else { " " },
            c.effect,
            c.nrmse_validation,
            c.evidence
        );
    }
    for a in &d.ambiguities {
        println!("  ambiguity: {a}");
    }
    println!("  {}", d.summary);
    if let Some(f) = &files {
        println!("  extended config {}", f.extended_config.display());
        println!("  report          {}", f.report.display());
    }
}

fn exit_of(e: SessionError) -> ExitCode {
    match e {
        SessionError::Input(e) => {
            eprintln!("ehactl: {e}");
            ExitCode::from(2)
        }
        SessionError::Io(e) => {
            eprintln!("ehactl: {e}");
            ExitCode::from(1)
        }
    }
}

/// `ehactl diagnose` with several records: one load law for the campaign.
fn cmd_campaign(
    cfg: &RigConfig,
    config: &Path,
    data: &[PathBuf],
    validate: &[PathBuf],
    out: Option<&Path>,
    json: bool,
    sw: &Switches,
) -> ExitCode {
    let run = match ehactl_ident::campaign_run::run(
        cfg,
        config,
        data,
        validate,
        out,
        sw.force,
        sw.allow_config_mismatch,
    ) {
        Ok(r) => r,
        Err(e) => return exit_of(e),
    };
    for w in &run.warnings {
        eprintln!("ehactl: warning: {w}");
    }
    if json {
        println!("{}", run.json);
    } else {
        println!("{}", run.campaign.summary);
        for f in &run.files {
            println!("  wrote {}", f.display());
        }
    }
    ExitCode::SUCCESS
}

/// The on/off options of `ehactl predict`.
pub struct PredictSwitches {
    /// `--imposed-motion`.
    pub imposed_motion: bool,
    /// `--held-out`.
    pub held_out: bool,
    /// `--force`.
    pub force: bool,
    /// `--json`.
    pub json: bool,
}

/// `ehactl predict`: exit 0 ok, 2 bad config, data or --out, 1 I/O failure, 5 a replay
/// diverged (the results are printed and written all the same).
pub fn cmd_predict(
    config: &Path,
    data: &[PathBuf],
    sw: PredictSwitches,
    out: Option<&Path>,
) -> ExitCode {
    let cfg = match RigConfig::load(config) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("ehactl: {}", crate::config_load_message(config, &e));
            return ExitCode::from(2);
        }
    };
    let run = match ehactl_ident::predict::run(
        &cfg,
        config,
        data,
        sw.imposed_motion,
        sw.held_out,
        out,
        sw.force,
    ) {
        Ok(r) => r,
        Err(e) => return exit_of(e),
    };
    for w in &run.warnings {
        eprintln!("ehactl: warning: {w}");
    }
    let status = if run.predictions.iter().any(|p| p.diverged.is_some()) {
        ExitCode::from(5)
    } else {
        ExitCode::SUCCESS
    };
    if sw.json {
        println!("{}", run.json);
        return status;
    }
    for p in &run.predictions {
        println!("{}", prediction_line(p));
        for (c, e) in &p.nrmse.channels {
            match e {
                Some(e) => println!("  {c:<6} {e:.4}"),
                None => println!("  {c:<6} —"),
            }
        }
    }
    for f in &run.files {
        println!("wrote {}", f.display());
    }
    status
}

/// The summary line of one prediction: its score (or where it diverged) and whether it lies
/// inside the model's fitted envelope.
fn prediction_line(p: &ehactl_ident::predict::Prediction) -> String {
    let op = ehactl_config::inputs::describe_point(&p.operating_point);
    let score = match (&p.diverged, p.nrmse.overall) {
        (Some(d), _) => format!("DIVERGED at t = {:.4} s: {}; no NRMSE", d.t, d.reason),
        (None, Some(e)) => format!("NRMSE {e:.4} over samples {}..{}", p.scored.0, p.scored.1),
        (None, None) => "no NRMSE".to_string(),
    };
    let band = p.band.as_ref().map_or(String::new(), |b| {
        format!(
            "; {:.0} % band covers {:.1} %",
            100.0 * b.level,
            100.0 * b.coverage
        )
    });
    let envelope = p
        .envelope
        .as_ref()
        .map_or(String::new(), |e| format!("; {}", e.describe()));
    format!(
        "{} ({} replay{}{}): {score}{band}{envelope}",
        p.source,
        p.replay.replace('_', "-"),
        if op.is_empty() { "" } else { " at " },
        op,
    )
}
