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
    data_path: &Path,
    validate: Option<&Path>,
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
    let (d, files) = (&run.diagnosis, &run.files);
    if json {
        println!("{}", run.json);
    } else {
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
    ExitCode::SUCCESS
}
