//! # ehactl-input
//!
//! Bounded reads of the files a user hands to ehactl (config TOML, EDS / DCF, `diagnose
//! --data` CSV / MCAP): a regular file of at most a given size, or one clear error.
//!
//! `std::fs::read` on a FIFO blocks until a writer appears, and on `/dev/zero` (or a file
//! that keeps growing) grows memory until the allocator fails. Every reader of user input
//! goes through [`read_bounded`] instead: it refuses anything that is not a regular file
//! (FIFO, character or block device, socket, directory) before reading, opens without
//! blocking, and reads at most `max_bytes` (a file that grows past it while being read is
//! refused too).
//!
//! A crate of its own (only `libc` below it), so that the config loader, the CANopen EDS
//! reader, `ehactl diagnose` and the Python bindings read input files without compiling the
//! hardware contract or the logger.
#![deny(missing_docs)]

use std::io::Read;
use std::path::{Path, PathBuf};

/// One MB (10⁶ bytes), the unit of the limits in messages.
pub const MB: u64 = 1_000_000;
/// Largest config file (TOML) read (bytes): the shipped configs are at most 6 kB.
pub const CONFIG_MAX_BYTES: u64 = 16 * MB;
/// Largest EDS / DCF file read (bytes): the shipped EDS files are 10 kB; a device with
/// thousands of objects stays far below the limit (≈ 150 bytes of text per object).
pub const EDS_MAX_BYTES: u64 = 64 * MB;
/// Largest `diagnose --data` / `--validate` / `predict` file (CSV or MCAP log) read (bytes):
/// 10 000 MB, hours of logs. An ehactl MCAP log of every cycle takes 1.15 MB per second at
/// 5 kHz (`ehactl run configs/sahu2022_force.toml --duration 10`: 11.5 MB) and 0.23 MB per
/// second at 1 kHz (`configs/diagnose_testrig.toml`: 2.3 MB), so 2.4 h at 5 kHz, 12 h at
/// 1 kHz; a CSV of 8 columns of ≈ 12 characters at 5 kHz takes about 0.5 MB per second.
/// Both readers stream the file (one line, or one MCAP chunk, at a time) and keep only the
/// record's columns (8 bytes per number): measured peaks of `ehactl diagnose` reading a file
/// in full are 0.80 × a CSV's size (458 MB for 574 MB) and 0.35 × an ehactl log's (159 MB
/// for 458 MB), the Python bindings' `read_mcap` 1.3 × a log's (it keeps every field), so
/// reading a file at this limit needs at most 13 GB (BENCHMARKS.md, "Memory of the data
/// readers").
pub const DATA_MAX_BYTES: u64 = 10_000 * MB;
/// Largest log `ehactl recover` reads (bytes): recovery holds the whole damaged file and
/// every message it recovers (it walks the file back and forth to resynchronise after
/// corrupt bytes), measured 2.6 × the file (1 211 MB for a 458 MB log), so 6 000 MB needs
/// about 16 GB of the 24 GB machine.
pub const RECOVER_MAX_BYTES: u64 = 6_000 * MB;

/// What kind of file system object `m` is, for messages.
fn kind(m: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = m.file_type();
    if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_char_device() {
        "a character device (such as /dev/zero)"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

/// Why a file was not read: its path and the reason (what is wrong, what was expected).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong and what was expected (without the path).
    pub reason: String,
}

impl std::fmt::Display for InputError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.reason)
    }
}

impl std::error::Error for InputError {}

fn check_meta(m: &std::fs::Metadata, max_bytes: u64, what: &str) -> Result<(), String> {
    if !m.is_file() {
        return Err(format!(
            "is {}, not a regular file; expected a {what} file",
            kind(m)
        ));
    }
    if m.len() > max_bytes {
        return Err(too_large(m.len(), max_bytes, what));
    }
    Ok(())
}

fn too_large(len: u64, max_bytes: u64, what: &str) -> String {
    format!(
        "{:.1} MB is larger than the {} MB limit for a {what} file; expected a smaller file",
        len as f64 / MB as f64,
        max_bytes / MB
    )
}

/// Open the regular file `path` of at most `max_bytes` bytes for reading, with the checks of
/// [`read_bounded`]; returns the file and its length (bytes). For a reader that streams the
/// file (and so needs no more memory than what it keeps of it) or checks its first bytes
/// before reading the rest.
pub fn open_bounded(
    path: &Path,
    max_bytes: u64,
    what: &str,
) -> Result<(std::fs::File, u64), InputError> {
    let err = |reason: String| InputError {
        path: path.to_path_buf(),
        reason,
    };
    let io = |e: std::io::Error| err(format!("cannot read {what} file: {e}"));
    // Checked before opening: opening a FIFO for reading blocks until a writer opens it.
    let m = std::fs::metadata(path).map_err(io)?;
    check_meta(&m, max_bytes, what).map_err(err)?;
    // Opened non-blocking, and checked again on the open file (it may have been replaced in
    // between); O_NONBLOCK changes nothing for reads of a regular file.
    use std::os::unix::fs::OpenOptionsExt;
    let f = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .map_err(io)?;
    let m = f.metadata().map_err(io)?;
    check_meta(&m, max_bytes, what).map_err(err)?;
    Ok((f, m.len()))
}

/// Read the regular file `path` of at most `max_bytes` bytes; `what` names the kind of file
/// in messages ("config", "EDS / DCF", "data").
pub fn read_bounded(path: &Path, max_bytes: u64, what: &str) -> Result<Vec<u8>, InputError> {
    let err = |reason: String| InputError {
        path: path.to_path_buf(),
        reason,
    };
    let io = |e: std::io::Error| err(format!("cannot read {what} file: {e}"));
    let (f, len) = open_bounded(path, max_bytes, what)?;
    let mut buf = Vec::with_capacity(len as usize);
    f.take(max_bytes + 1).read_to_end(&mut buf).map_err(io)?;
    if buf.len() as u64 > max_bytes {
        return Err(err(too_large(buf.len() as u64, max_bytes, what)));
    }
    Ok(buf)
}

/// [`read_bounded`] of a UTF-8 text file.
pub fn read_bounded_string(path: &Path, max_bytes: u64, what: &str) -> Result<String, InputError> {
    let b = read_bounded(path, max_bytes, what)?;
    String::from_utf8(b).map_err(|e| InputError {
        path: path.to_path_buf(),
        reason: format!(
            "not a text file (invalid UTF-8 at byte {}); expected a {what} file",
            e.utf8_error().valid_up_to()
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regular_files_are_read_and_everything_else_is_refused_without_blocking() {
        let dir = std::env::temp_dir().join(format!("ehactl_input_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("a.txt");
        std::fs::write(&f, "hello").unwrap();
        assert_eq!(read_bounded_string(&f, 5, "test").unwrap(), "hello");
        let e = read_bounded(&f, 4, "test").unwrap_err().to_string();
        assert!(e.contains("limit") && e.contains("a.txt"), "{e}");
        let e = read_bounded(Path::new("/dev/zero"), MB, "test")
            .unwrap_err()
            .to_string();
        assert!(e.contains("character device"), "{e}");
        let e = read_bounded(&dir, MB, "test").unwrap_err().to_string();
        assert!(e.contains("directory"), "{e}");
        // A FIFO without a writer: refused at once (opening it would block).
        let fifo = dir.join("p");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: mkfifo with a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = read_bounded(&fifo, MB, "test").unwrap_err().to_string();
        assert!(e.contains("FIFO"), "{e}");
        let e = read_bounded(&dir.join("missing"), MB, "test")
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing") && e.contains("cannot read"), "{e}");
        std::fs::write(&f, [0xFF, 0xFE]).unwrap();
        assert!(read_bounded_string(&f, MB, "test")
            .unwrap_err()
            .reason
            .contains("UTF-8"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
