//! The safety rules for where a run's MCAP log may be written, shared by `ehactl run --out`,
//! `ehactl sweep` and the Python bindings (`ehactl.run(…, mcap=…)`): never over a file the
//! run reads (the config), never over a directory, never over an existing file that is not
//! an MCAP log unless the caller says so explicitly, never over a log another running
//! ehactl is writing. An earlier MCAP log at the path is replaced, as a re-run is expected
//! to do.

use std::path::Path;

/// Why a log path was refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LogPathError {
    /// The path would destroy something of the user's (an input, a directory, a file that
    /// is not an MCAP log): a usage error.
    Refused(String),
    /// Another running ehactl holds the lock of the log at the path: try again later or
    /// choose another path.
    Busy(String),
}

impl std::fmt::Display for LogPathError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LogPathError::Refused(m) | LogPathError::Busy(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for LogPathError {}

/// How the caller names the log path and the explicit overwrite switch in messages, e.g.
/// `("--out", "add --force")` for the CLI, `("mcap", "pass overwrite=True")` for Python.
#[derive(Debug, Clone, Copy)]
pub struct Naming<'a> {
    /// Name of the argument holding the log path.
    pub arg: &'a str,
    /// What the user does to overwrite a file that is not an MCAP log.
    pub force_hint: &'a str,
}

/// Whether `a` and `b` are the same file: same device and inode, whatever the names (a hard
/// link, a symbolic link, `./x` and `x`). False when either does not exist.
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => (x.dev(), x.ino()) == (y.dev(), y.ino()),
        _ => false,
    }
}

/// Check the log path `out` of a run that reads `inputs` (the config file, when there is
/// one): refuse an input (always), a directory, anything that exists and is not a regular
/// MCAP file (unless `force`; a FIFO or device never, it would block or never end), and a
/// log another running ehactl holds the lock of.
pub fn check_log_path(
    out: &Path,
    inputs: &[&Path],
    force: bool,
    naming: Naming<'_>,
) -> Result<(), LogPathError> {
    let arg = naming.arg;
    if let Some(i) = inputs.iter().find(|i| same_file(out, i)) {
        return Err(LogPathError::Refused(format!(
            "{arg} {}: is the config being run ({}); choose another file for the MCAP log",
            out.display(),
            i.display()
        )));
    }
    let Ok(meta) = std::fs::symlink_metadata(out) else {
        return Ok(()); // nothing there yet
    };
    if meta.is_dir() {
        return Err(LogPathError::Refused(format!(
            "{arg} {}: is a directory; expected a file path for the MCAP log (e.g. {}/run.mcap)",
            out.display(),
            out.display()
        )));
    }
    // A symbolic link is followed for the checks (the link itself is replaced by a write).
    let target = std::fs::metadata(out).ok();
    let regular = target.as_ref().is_some_and(|m| m.is_file());
    if !regular && target.is_some() {
        return Err(LogPathError::Refused(format!(
            "{arg} {}: is not a regular file (a FIFO, device or socket); expected a file path for the MCAP log",
            out.display()
        )));
    }
    let is_mcap = regular && crate::recover::is_mcap_file(out);
    if !is_mcap && !force {
        return Err(LogPathError::Refused(format!(
            "{arg} {}: exists and is not an MCAP log; refusing to overwrite it (choose another path or {})",
            out.display(),
            naming.force_hint
        )));
    }
    if is_mcap && crate::logger::is_locked(out) {
        return Err(LogPathError::Busy(format!(
            "{arg} {}: is being written by another running ehactl (it holds the file's lock); choose another {arg}",
            out.display()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const N: Naming<'static> = Naming {
        arg: "mcap",
        force_hint: "pass overwrite=True",
    };

    #[test]
    fn inputs_directories_and_foreign_files_are_refused_and_mcap_logs_replaced() {
        let dir = std::env::temp_dir().join(format!("ehactl_outpath_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cfg = dir.join("x.toml");
        std::fs::write(&cfg, "[run]\n").unwrap();
        let e = check_log_path(&cfg, &[&cfg], true, N).unwrap_err();
        assert!(matches!(e, LogPathError::Refused(_)) && e.to_string().contains("config"));
        let e = check_log_path(&dir, &[], true, N).unwrap_err().to_string();
        assert!(e.contains("directory"), "{e}");
        let notes = dir.join("notes.txt");
        std::fs::write(&notes, "keep me").unwrap();
        let e = check_log_path(&notes, &[], false, N)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("not an MCAP log") && e.contains("overwrite=True"),
            "{e}"
        );
        assert!(check_log_path(&notes, &[], true, N).is_ok());
        let log = dir.join("old.mcap");
        std::fs::write(&log, mcap::MAGIC).unwrap();
        assert!(check_log_path(&log, &[], false, N).is_ok());
        assert!(check_log_path(&dir.join("new.mcap"), &[], false, N).is_ok());
        let e = check_log_path(Path::new("/dev/null"), &[], true, N).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
