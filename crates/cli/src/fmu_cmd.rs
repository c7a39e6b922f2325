//! `ehactl export-fmu CONFIG --out RIG.fmu [--closed-loop]`: the config as an FMI 2.0
//! co-simulation FMU (crates/fmu, docs/fmu.md).
//!
//! The FMU's binary is the one generic shared library `libehactl_fmu.so` (crate
//! `ehactl-fmu`), found at export time in this order: `--binary`, `$EHACTL_FMU_LIB`, beside
//! the `ehactl` executable (a cargo build puts both in `target/<profile>/`), and in
//! `../lib/ehactl/` from it (where scripts/install_and_run.sh installs it). An aarch64 build
//! (scripts/cross_build.sh) is added as `binaries/aarch64-linux/` when given with
//! `--aarch64-binary` or found as `aarch64-linux/libehactl_fmu.so` beside the native one.

use ehactl_fmu::export::{native_platform, write_fmu, Export};
use ehactl_fmu::variables::Variant;
use ehactl_fmu::LIBRARY_FILE;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// The command line of `ehactl export-fmu`.
#[derive(clap::Args)]
pub struct ExportFmuArgs {
    /// Rig config (TOML): any shipped config or a diagnosis' extended.toml.
    pub config: PathBuf,
    /// FMU file to write (ends in .fmu).
    #[arg(long)]
    pub out: PathBuf,
    /// Export the closed loop (control law + supervisor + plant; input: the setpoint)
    /// instead of the plant (input: the valve command).
    #[arg(long)]
    pub closed_loop: bool,
    /// The FMU shared library to pack (default: $EHACTL_FMU_LIB, else libehactl_fmu.so
    /// beside this executable or in ../lib/ehactl/ from it).
    #[arg(long, value_name = "PATH")]
    pub binary: Option<PathBuf>,
    /// An aarch64 build of the library to pack as binaries/aarch64-linux (default:
    /// aarch64-linux/libehactl_fmu.so beside the native library, if there).
    #[arg(long, value_name = "PATH")]
    pub aarch64_binary: Option<PathBuf>,
}

/// Where the native library is looked for, in order, with what told us to look there.
fn candidates(args: &ExportFmuArgs) -> Vec<(PathBuf, &'static str)> {
    if let Some(b) = &args.binary {
        return vec![(b.clone(), "--binary")];
    }
    if let Some(p) = std::env::var_os("EHACTL_FMU_LIB") {
        return vec![(PathBuf::from(p), "$EHACTL_FMU_LIB")];
    }
    let mut out = Vec::new();
    if let Some(dir) = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf))
    {
        out.push((dir.join(LIBRARY_FILE), "beside the ehactl executable"));
        out.push((
            dir.join("../lib/ehactl").join(LIBRARY_FILE),
            "the install directory",
        ));
    }
    out
}

/// The binaries to pack by platform, or the reason there is none.
fn binaries(args: &ExportFmuArgs) -> Result<Vec<(String, PathBuf)>, String> {
    let tried = candidates(args);
    let Some((native, _)) = tried.iter().find(|(p, _)| p.is_file()) else {
        let list = tried
            .iter()
            .map(|(p, why)| format!("{} ({why})", p.display()))
            .collect::<Vec<_>>()
            .join(", ");
        return Err(format!(
            "the FMU library {LIBRARY_FILE} was not found; looked at {list}. Build it with `cargo build --release -p ehactl-fmu` (scripts/install_and_run.sh installs it) or give --binary PATH"
        ));
    };
    let mut out = vec![(native_platform().to_string(), native.clone())];
    let arm = match &args.aarch64_binary {
        Some(p) if !p.is_file() => {
            return Err(format!("--aarch64-binary {}: no such file", p.display()))
        }
        Some(p) => Some(p.clone()),
        None => native
            .parent()
            .map(|d| d.join("aarch64-linux").join(LIBRARY_FILE))
            .filter(|p| p.is_file()),
    };
    if let Some(p) = arm.filter(|_| native_platform() != "aarch64-linux") {
        out.push(("aarch64-linux".to_string(), p));
    }
    Ok(out)
}

/// Run `ehactl export-fmu`.
pub fn cmd_export_fmu(args: &ExportFmuArgs) -> ExitCode {
    match export(args) {
        Ok(platforms) => {
            println!(
                "wrote {} ({} FMU, FMI 2.0 co-simulation; binaries: {})",
                args.out.display(),
                if args.closed_loop {
                    "closed-loop"
                } else {
                    "plant"
                },
                platforms.join(", ")
            );
            ExitCode::SUCCESS
        }
        Err((code, e)) => {
            eprintln!("error: {e}");
            ExitCode::from(code)
        }
    }
}

/// The export; returns the platforms packed, or the exit code (2: a bad argument or config,
/// 1: a file that cannot be read or written, the library missing) and the reason.
fn export(args: &ExportFmuArgs) -> Result<Vec<String>, (u8, String)> {
    if args.out.extension().and_then(|e| e.to_str()) != Some("fmu") {
        let e = format!(
            "--out {}: expected a file name ending in .fmu",
            args.out.display()
        );
        return Err((2, e));
    }
    let text =
        ehactl_input::read_bounded_string(&args.config, ehactl_input::CONFIG_MAX_BYTES, "config")
            .map_err(|e| (1, format!("{}: {}", args.config.display(), e.reason)))?;
    if let Err(e) = ehactl_config::RigConfig::from_toml_str(&text) {
        return Err((2, format!("{}: {e}", args.config.display())));
    }
    let bins = binaries(args).map_err(|e| (1, e))?;
    let platforms = bins.iter().map(|(p, _)| p.clone()).collect();
    let e = Export {
        config_text: &text,
        variant: if args.closed_loop {
            Variant::ClosedLoop
        } else {
            Variant::Plant
        },
        binaries: bins,
    };
    write_fmu(&e, &args.out).map_err(|err| (1, format!("{}: {err}", args.config.display())))?;
    Ok(platforms)
}
