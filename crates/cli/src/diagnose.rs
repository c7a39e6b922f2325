//! `ehactl diagnose`: name what the simulation gets wrong on measured data (see ehactl-ident).

use ehactl_controller::RigConfig;
use ehactl_ident::{data, diagnose, report, Options};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Run the diagnosis of `data_path` against the nominal `config`; exit 0 ok, 2 bad config
/// or data, 1 other failure (I/O).
pub fn cmd_diagnose(
    config: &Path,
    data_path: &Path,
    validate: Option<&Path>,
    out: Option<PathBuf>,
    json: bool,
) -> ExitCode {
    let bad = |msg: String| {
        eprintln!("ehactl: {msg}");
        ExitCode::from(2)
    };
    let cfg = match RigConfig::load(config) {
        Ok(c) => c,
        Err(e) => return bad(format!("{}: {e}", config.display())),
    };
    let load = |p: &Path| -> Result<data::Record, String> {
        let mut r = data::load(p).map_err(|e| e.to_string())?;
        let w = data::check_against(&r, &cfg.plant, cfg.control_dt()).map_err(|e| e.to_string())?;
        r.warnings.extend(w);
        Ok(r)
    };
    let rec = match load(data_path) {
        Ok(r) => r,
        Err(e) => return bad(e),
    };
    let val = match validate.map(load).transpose() {
        Ok(v) => v,
        Err(e) => return bad(e),
    };
    if let Some(v) = &val {
        let a: Vec<_> = rec.channels.iter().map(|c| c.kind).collect();
        let b: Vec<_> = v.channels.iter().map(|c| c.kind).collect();
        if a != b {
            return bad(format!(
                "{}: channels [{}] differ from the data file's [{}]; the validation file must have the same output columns",
                v.source,
                b.iter().map(|k| k.column()).collect::<Vec<_>>().join(", "),
                a.iter().map(|k| k.column()).collect::<Vec<_>>().join(", ")
            ));
        }
        if (v.dt - rec.dt).abs() > 1e-6 * rec.dt {
            return bad(format!(
                "{}: sample period {} s differs from the data file's {} s",
                v.source, v.dt, rec.dt
            ));
        }
    }
    for w in rec
        .warnings
        .iter()
        .chain(val.iter().flat_map(|v| v.warnings.iter()))
    {
        eprintln!("ehactl: warning: {w}");
    }
    // Closed-loop position records (a `ref` column and a PD position loop in the config) are
    // replayed through the same controller: an integrating plant would drift open loop.
    let drive = match (&cfg.control.mode, cfg.pd_gains(), &rec.reference) {
        (ehactl_controller::config::ControlMode::Position, Some(g), Some(_)) => {
            eprintln!("ehactl: note: closed-loop replay: the config's PD position controller acts on the recorded `ref`; the recorded `u` is not used");
            ehactl_ident::replay::Drive::PositionPd(g)
        }
        _ => {
            if rec.reference.is_some() {
                eprintln!("ehactl: note: open-loop replay with the recorded valve command `u` (the config has no PD position loop to replay `ref` through)");
            }
            ehactl_ident::replay::Drive::Recorded
        }
    };
    if let (ehactl_ident::replay::Drive::PositionPd(_), Some(v)) = (&drive, &val) {
        if v.reference.is_none() {
            return bad(format!(
                "{}: closed-loop replay needs a `ref` column in the validation file too",
                v.source
            ));
        }
    }
    let opts = Options {
        progress: true,
        drive,
        ..Options::default()
    };
    let d = match diagnose(&cfg.plant, &rec, val.as_ref(), &opts) {
        Ok(d) => d,
        Err(e) => return bad(e),
    };
    let files = match &out {
        Some(dir) => match report::write_report(
            dir,
            &cfg,
            &config.display().to_string(),
            &rec,
            val.as_ref(),
            &d,
        ) {
            Ok(f) => {
                for w in &f.warnings {
                    eprintln!("ehactl: warning: {w}");
                }
                Some(f)
            }
            Err(e) => {
                eprintln!("ehactl: {e}");
                return ExitCode::from(1);
            }
        },
        None => None,
    };
    if json {
        let mut v = serde_json::to_value(&d).unwrap_or_default();
        v["extended_config"] = files.as_ref().map_or(serde_json::Value::Null, |f| {
            f.extended_config.display().to_string().into()
        });
        v["report"] = files.as_ref().map_or(serde_json::Value::Null, |f| {
            f.report.display().to_string().into()
        });
        v["plots"] = files.as_ref().map_or(serde_json::Value::Null, |f| {
            f.plots
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .into()
        });
        println!("{v}");
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
