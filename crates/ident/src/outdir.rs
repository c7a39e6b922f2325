//! The output directory of `ehactl diagnose --out DIR`: what may be written there, and how.
//!
//! - Never over an input: a file the diagnosis would write that is the data, the validation
//!   record or the config being run (same device and inode: hard links and symbolic links
//!   included) is refused, `--force` or not.
//! - Only into a directory that is new, empty, or holds nothing but what an earlier diagnosis
//!   wrote there (listed in its manifest, [`MANIFEST`]); anything else is the user's, and the
//!   directory is refused unless `--force` (then same-named files are replaced, others left).
//! - Every file atomically: written under a temporary name in the same directory, flushed to
//!   the disk (fsync), then renamed over the final name; a failure (full disk, size limit)
//!   leaves the previous file or none, never half a file.

use std::collections::BTreeSet;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Manifest of the files `ehactl diagnose` wrote into a directory, one name a line.
pub const MANIFEST: &str = ".ehactl-diagnose";

/// Every file `ehactl diagnose` may write into its output directory.
pub const OUTPUTS: &[&str] = &[
    "extended.toml",
    "traces.csv",
    "validation_traces.csv",
    "diagnosis.json",
    "traces.svg",
    "residual.svg",
    "residual_state.svg",
    "frf.svg",
    "validation.svg",
    "report.md",
    "campaign.json",
    "campaign.svg",
    "prediction.json",
    "prediction.svg",
    // `crate::nexttest::MAX_TESTS` proposals.
    "next_test_1.toml",
    "next_test_2.toml",
    "next_test_3.toml",
    "next_test_4.toml",
    "next_test_5.toml",
    "next_test_6.toml",
];

/// Whether `a` and `b` are the same file (same device and inode, whatever the names).
/// False when either does not exist.
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => (x.dev(), x.ino()) == (y.dev(), y.ino()),
        _ => false,
    }
}

/// Temporary name of `name` while it is written (hidden, per process).
fn temp_name(name: &str) -> String {
    format!(".{name}.tmp-{}", std::process::id())
}

/// Whether `entry` is a temporary file left by a diagnosis that was killed while writing.
fn is_temp(entry: &str) -> bool {
    OUTPUTS
        .iter()
        .chain(std::iter::once(&MANIFEST))
        .any(|n| entry.starts_with(&format!(".{n}.tmp-")))
}

/// The names listed in the manifest of `dir` (only names diagnose writes count).
fn manifest(dir: &Path) -> BTreeSet<String> {
    std::fs::read_to_string(dir.join(MANIFEST))
        .unwrap_or_default()
        .lines()
        .filter(|l| OUTPUTS.contains(l))
        .map(str::to_string)
        .collect()
}

/// Check `dir` before anything is computed: refuse (with the reason) an output that would be
/// one of `inputs` (label, path), a path that is not a directory, and a directory holding
/// files ehactl did not write (unless `force`). `command` (`diagnose`, `predict`) names the
/// command in the messages.
pub fn check(
    dir: &Path,
    inputs: &[(&str, &Path)],
    force: bool,
    command: &str,
) -> Result<(), String> {
    for name in OUTPUTS.iter().chain(std::iter::once(&MANIFEST)) {
        let p = dir.join(name);
        for (label, input) in inputs {
            if same_file(&p, input) {
                return Err(format!(
                    "--out {}: {} is the {label} ({}); {command} never writes over its inputs: choose another --out directory",
                    dir.display(),
                    p.display(),
                    input.display()
                ));
            }
        }
    }
    let meta = match std::fs::metadata(dir) {
        Ok(m) => m,
        Err(_) => return Ok(()), // created when the report is written
    };
    if !meta.is_dir() {
        return Err(format!(
            "--out {}: exists and is not a directory; expected a directory for the report",
            dir.display()
        ));
    }
    if force {
        return Ok(());
    }
    let ours = manifest(dir);
    let entries = std::fs::read_dir(dir)
        .map_err(|e| format!("--out {}: cannot read the directory: {e}", dir.display()))?;
    let mut foreign: Vec<String> = entries
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n != MANIFEST && !ours.contains(n) && !is_temp(n))
        .collect();
    foreign.sort();
    if !foreign.is_empty() {
        let n = foreign.len();
        foreign.truncate(5);
        return Err(format!(
            "--out {}: holds {n} file(s) ehactl did not write ({}{}); ehactl {command} writes only into a new or empty directory or one ehactl wrote before: choose another --out, or add --force to write beside them (files named like its outputs are then replaced)",
            dir.display(),
            foreign.join(", "),
            if n > 5 { ", …" } else { "" }
        ));
    }
    Ok(())
}

/// An output directory held by one ehactl (`diagnose`, a campaign, `predict`) from its check
/// to its last file: an advisory lock (flock(2),
/// [`ehactl_log::logger::try_lock_exclusive`]) on the directory itself, so that no lock file
/// is left among the outputs and a killed run's lock goes with its process. A directory
/// [`lock`] created is removed again when the run ends without writing into it (a refused
/// record leaves no empty directory behind).
pub struct DirLock {
    dir: PathBuf,
    created: bool,
    _file: std::fs::File,
}

/// Create `dir` if needed and lock it; a directory another running ehactl holds is refused
/// (the message names it), never waited for.
pub fn lock(dir: &Path) -> Result<DirLock, String> {
    use std::os::unix::fs::MetadataExt;
    let created = !dir.exists();
    // A directory removed and made again by another run between our open and our lock is
    // another directory: lock the one at the path (a few tries).
    for _ in 0..3 {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("{}: cannot create output directory: {e}", dir.display()))?;
        let file = std::fs::File::open(dir)
            .map_err(|e| format!("--out {}: cannot open the directory: {e}", dir.display()))?;
        match ehactl_log::logger::try_lock_exclusive(&file) {
            Ok(true) => {}
            Ok(false) => {
                return Err(format!(
                    "--out {}: another running ehactl (diagnose or predict) is writing into this directory (it holds the directory's lock); wait for it to end or choose another --out",
                    dir.display()
                ))
            }
            Err(e) => {
                return Err(format!(
                    "--out {}: cannot lock the directory: {e}",
                    dir.display()
                ))
            }
        }
        let id = |m: std::fs::Metadata| (m.dev(), m.ino());
        if file.metadata().map(id).ok() == std::fs::metadata(dir).map(id).ok() {
            return Ok(DirLock {
                dir: dir.to_path_buf(),
                created,
                _file: file,
            });
        }
    }
    Err(format!(
        "--out {}: the directory keeps being replaced while it is locked; choose another --out",
        dir.display()
    ))
}

impl Drop for DirLock {
    fn drop(&mut self) {
        if self.created {
            // Only an empty directory is removed (remove_dir fails otherwise), under the lock.
            let _ = std::fs::remove_dir(&self.dir);
        }
    }
}

/// The output directory while the report is written: every file goes through
/// [`OutDir::write`] or [`OutDir::write_with`] (atomic), after its name is in the manifest.
pub struct OutDir {
    dir: PathBuf,
    listed: BTreeSet<String>,
}

impl OutDir {
    /// Create `dir` if needed (checked beforehand with [`check`]).
    pub fn create(dir: &Path) -> Result<OutDir, String> {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("{}: cannot create output directory: {e}", dir.display()))?;
        Ok(OutDir {
            dir: dir.to_path_buf(),
            listed: manifest(dir),
        })
    }

    /// Final path of `name`.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Write `text` to `name` atomically.
    pub fn write(&mut self, name: &str, text: &[u8]) -> Result<PathBuf, String> {
        self.write_with(name, |tmp| {
            std::fs::write(tmp, text).map_err(|e| format!("cannot write: {e}"))
        })
    }

    /// Let `make` write the file at the temporary path it is given, then flush it to the disk
    /// and rename it to `name`. On failure the temporary file is removed and the error names
    /// the final path.
    pub fn write_with(
        &mut self,
        name: &str,
        make: impl FnOnce(&Path) -> Result<(), String>,
    ) -> Result<PathBuf, String> {
        debug_assert!(OUTPUTS.contains(&name), "{name} is not listed in OUTPUTS");
        if self.listed.insert(name.to_string()) {
            let list: String = self.listed.iter().map(|n| format!("{n}\n")).collect();
            self.commit(MANIFEST, |tmp| {
                std::fs::write(tmp, list).map_err(|e| format!("cannot write: {e}"))
            })?;
        }
        self.commit(name, make)
    }

    fn commit(
        &self,
        name: &str,
        make: impl FnOnce(&Path) -> Result<(), String>,
    ) -> Result<PathBuf, String> {
        let tmp = self.dir.join(temp_name(name));
        let fin = self.dir.join(name);
        let tmp_s = tmp.display().to_string();
        let fail = |e: String| {
            let _ = std::fs::remove_file(&tmp);
            // Messages name the file the user asked for, not the temporary one.
            let e = e.replace(&tmp_s, &fin.display().to_string());
            if e.contains(&fin.display().to_string()) {
                e
            } else {
                format!("{}: {e}", fin.display())
            }
        };
        make(&tmp).map_err(fail)?;
        std::fs::File::options()
            .write(true)
            .open(&tmp)
            .and_then(|mut f| f.flush().and_then(|()| f.sync_all()))
            .map_err(|e| fail(format!("cannot write: {e}")))?;
        std::fs::rename(&tmp, &fin).map_err(|e| fail(format!("cannot rename into place: {e}")))?;
        // The rename itself reaches the disk with the directory.
        if let Ok(d) = std::fs::File::open(&self.dir) {
            let _ = d.sync_all();
        }
        Ok(fin)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("ehactl-outdir-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_directory_of_the_users_is_refused_unless_forced() {
        let d = tmp("user");
        std::fs::write(d.join("report.md"), "mine").unwrap();
        let e = check(&d, &[], false, "diagnose").unwrap_err();
        assert!(e.contains("report.md") && e.contains("--force"), "{e}");
        assert!(check(&d, &[], true, "diagnose").is_ok());
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn what_diagnose_wrote_may_be_replaced_but_never_an_input() {
        let d = tmp("ours");
        let mut o = OutDir::create(&d).unwrap();
        o.write("report.md", b"one").unwrap();
        o.write("extended.toml", b"x = 1").unwrap();
        assert!(check(&d, &[], false, "diagnose").is_ok());
        let cfg = d.join("extended.toml");
        let e = check(&d, &[("--config", &cfg)], true, "predict").unwrap_err();
        assert!(
            e.contains("--config") && e.contains("predict never writes over"),
            "{e}"
        );
        // A hard link elsewhere is the same file.
        let link = std::env::temp_dir().join(format!("ehactl-outdir-link-{}", std::process::id()));
        let _ = std::fs::remove_file(&link);
        std::fs::hard_link(d.join("report.md"), &link).unwrap();
        assert!(check(&d, &[("--data", &link)], true, "diagnose").is_err());
        let _ = std::fs::remove_file(&link);
        // No temporary file is left behind.
        let names: Vec<String> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(names.iter().all(|n| !n.contains(".tmp-")), "{names:?}");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_locked_directory_is_refused_and_an_unused_new_one_removed() {
        let d = tmp("lock").join("new");
        let held = lock(&d).unwrap();
        assert!(d.is_dir());
        let e = lock(&d).err().expect("a second lock is refused");
        assert!(
            e.contains(&d.display().to_string()) && e.contains("another running ehactl"),
            "{e}"
        );
        drop(held);
        // Created by the lock and left empty: removed with it.
        assert!(!d.exists());
        // Released: the next run takes it, and what it writes stays.
        let held = lock(&d).unwrap();
        OutDir::create(&d)
            .unwrap()
            .write("report.md", b"one")
            .unwrap();
        drop(held);
        assert!(d.join("report.md").is_file());
        let _ = std::fs::remove_dir_all(d.parent().unwrap());
    }

    #[test]
    fn a_failed_write_leaves_the_previous_file_and_no_temporary() {
        let d = tmp("fail");
        let mut o = OutDir::create(&d).unwrap();
        o.write("diagnosis.json", b"{\"ok\": 1}").unwrap();
        let e = o
            .write_with("diagnosis.json", |p| {
                std::fs::write(p, b"{\"half").unwrap();
                Err("disk full".into())
            })
            .unwrap_err();
        assert!(e.contains("diagnosis.json") && !e.contains(".tmp-"), "{e}");
        assert_eq!(
            std::fs::read(d.join("diagnosis.json")).unwrap(),
            b"{\"ok\": 1}"
        );
        assert_eq!(std::fs::read_dir(&d).unwrap().count(), 2); // the file and the manifest
        let _ = std::fs::remove_dir_all(&d);
    }
}
