//! Control socket: a Unix stream socket next to a running `ehactl run --control-socket
//! PATH` through which `ehactl set --socket PATH control.pi.kp=0.5 …` changes gains and
//! setpoint parameters while the loop runs. The server is a normal (non-real-time) thread:
//! it parses and validates the request against the running config ([`live::prepare`]),
//! publishes it into the [`LiveParams`] back buffer and replies once the loop has taken it
//! over at a cycle boundary.
//!
//! Protocol: one request line `set PATH=VALUE [PATH=VALUE …]`, one reply line
//! `ok cycle N: PATH=VALUE UNIT, …` or `error: …`.

use crate::live::{self, LiveParams};
use ehactl_config::RigConfig;
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long a request waits for the loop to take a change over (s).
const APPLY_TIMEOUT: Duration = Duration::from_secs(2);
/// Longest request line (bytes); a longer one is refused and the client dropped.
pub const MAX_LINE: usize = 4096;
/// A client must deliver its whole request line within this time (s), however it trickles.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(2);
/// Clients served at once; more are told to retry and closed.
pub const MAX_CLIENTS: usize = 8;

/// A running control-socket server; stops and removes the socket file when dropped.
pub struct ControlServer {
    path: PathBuf,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

/// Why the control socket could not be opened.
#[derive(Debug)]
pub enum StartError {
    /// Something that is not a stale socket is at the path (file, symlink, directory,
    /// or a socket another process still serves): it is left alone.
    PathInUse(String),
    /// The OS refused (permissions, path too long, …).
    Io(std::io::Error),
}

impl std::fmt::Display for StartError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StartError::PathInUse(m) => f.write_str(m),
            StartError::Io(e) => e.fmt(f),
        }
    }
}

impl std::error::Error for StartError {}

impl From<std::io::Error> for StartError {
    fn from(e: std::io::Error) -> Self {
        StartError::Io(e)
    }
}

impl ControlServer {
    /// Bind `path` with mode 0600 and serve requests for the run of `cfg` through `live`.
    /// Only a stale socket (one nobody serves) is replaced; a file, symlink, directory or
    /// live socket at `path` is an error and is left untouched.
    pub fn start(
        path: &Path,
        cfg: RigConfig,
        live: Arc<LiveParams>,
    ) -> Result<ControlServer, StartError> {
        if let Ok(meta) = std::fs::symlink_metadata(path) {
            let ft = meta.file_type();
            if !ft.is_socket() {
                let what = if ft.is_symlink() {
                    "a symbolic link"
                } else if ft.is_dir() {
                    "a directory"
                } else {
                    "a file that is not a socket"
                };
                return Err(StartError::PathInUse(format!(
                    "is {what}; refusing to replace it (give a path that does not exist or holds a stale ehactl socket)"
                )));
            }
            // Refuse to steal a socket another process still serves.
            if UnixStream::connect(path).is_ok() {
                return Err(StartError::PathInUse(
                    "another process is serving this socket".into(),
                ));
            }
            std::fs::remove_file(path)?;
        }
        let listener = bind_private(path)?;
        listener.set_nonblocking(true)?;
        let stop = Arc::new(AtomicBool::new(false));
        let st = stop.clone();
        let thread = std::thread::Builder::new()
            .name("ehactl-ctl".into())
            .spawn(move || serve(listener, cfg, live, st))?;
        Ok(ControlServer {
            path: path.to_path_buf(),
            stop,
            thread: Some(thread),
        })
    }

    /// Socket path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Bind a Unix socket readable and writable by the owner only (0600), whatever the umask:
/// the umask is narrowed around `bind` (so the file never exists with wider rights) and the
/// mode is then set explicitly and checked.
fn bind_private(path: &Path) -> std::io::Result<UnixListener> {
    // SAFETY: umask only swaps the process file-creation mask; it cannot fail.
    let old = unsafe { libc::umask(0o177) };
    let bound = UnixListener::bind(path);
    // SAFETY: as above.
    unsafe { libc::umask(old) };
    let listener = bound?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600))?;
    let mode = std::fs::metadata(path)?.permissions().mode() & 0o777;
    if mode != 0o600 {
        let _ = std::fs::remove_file(path);
        return Err(std::io::Error::new(
            std::io::ErrorKind::PermissionDenied,
            format!("socket mode is {mode:o}, expected 600"),
        ));
    }
    Ok(listener)
}

impl Drop for ControlServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Accept clients and serve each on its own thread (at most [`MAX_CLIENTS`] at once), so a
/// slow or hostile client never blocks another; each must send its line within
/// [`REQUEST_TIMEOUT`] and [`MAX_LINE`] bytes.
fn serve(listener: UnixListener, cfg: RigConfig, live: Arc<LiveParams>, stop: Arc<AtomicBool>) {
    let cfg = Arc::new(Mutex::new(cfg));
    let active = Arc::new(AtomicUsize::new(0));
    while !stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((mut stream, _)) => {
                if active.load(Ordering::Acquire) >= MAX_CLIENTS {
                    let _ = stream.set_write_timeout(Some(Duration::from_millis(100)));
                    let _ = stream.write_all(b"error: too many control clients; retry\n");
                    continue;
                }
                active.fetch_add(1, Ordering::AcqRel);
                let (cfg, live, active2) = (cfg.clone(), live.clone(), active.clone());
                let spawned = std::thread::Builder::new()
                    .name("ehactl-ctl-client".into())
                    .spawn(move || {
                        let _ = handle(stream, &cfg, &live);
                        active2.fetch_sub(1, Ordering::AcqRel);
                    });
                if spawned.is_err() {
                    active.fetch_sub(1, Ordering::AcqRel);
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

/// Read one request line of at most [`MAX_LINE`] bytes within [`REQUEST_TIMEOUT`].
pub fn read_request(stream: &mut UnixStream) -> Result<String, String> {
    stream.set_nonblocking(false).map_err(|e| e.to_string())?;
    let t0 = Instant::now();
    let mut buf = Vec::with_capacity(256);
    let mut chunk = [0u8; 512];
    loop {
        let left = REQUEST_TIMEOUT.saturating_sub(t0.elapsed());
        if left.is_zero() {
            return Err(format!(
                "request not complete within {} s",
                REQUEST_TIMEOUT.as_secs_f64()
            ));
        }
        stream
            .set_read_timeout(Some(left))
            .map_err(|e| e.to_string())?;
        let n = match stream.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e.to_string()),
        };
        let part = &chunk[..n];
        if let Some(i) = part.iter().position(|&b| b == b'\n') {
            buf.extend_from_slice(&part[..i]);
            break;
        }
        buf.extend_from_slice(part);
        if buf.len() > MAX_LINE {
            return Err(format!("request longer than {MAX_LINE} bytes"));
        }
    }
    if buf.len() > MAX_LINE {
        return Err(format!("request longer than {MAX_LINE} bytes"));
    }
    String::from_utf8(buf).map_err(|_| "request is not UTF-8 text".to_string())
}

fn handle(
    mut stream: UnixStream,
    cfg: &Mutex<RigConfig>,
    live: &LiveParams,
) -> std::io::Result<()> {
    let reply = match read_request(&mut stream) {
        Ok(line) => {
            let mut cfg = cfg.lock().unwrap_or_else(|p| p.into_inner());
            respond(line.trim(), &mut cfg, live)
        }
        Err(e) => format!("error: {e}"),
    };
    stream.set_write_timeout(Some(REQUEST_TIMEOUT))?;
    stream.write_all(reply.as_bytes())?;
    stream.write_all(b"\n")
}

/// Parse one request line and validate it against the running config `cfg` (the same
/// checks as a config file): the config it would produce and the update to publish. `cfg`
/// itself is not changed.
pub fn parse_request(line: &str, cfg: &RigConfig) -> Result<(RigConfig, live::Update), String> {
    let mut words = line.split_whitespace();
    match words.next() {
        Some("set") => {}
        Some(other) => {
            return Err(format!(
                "unknown request `{other}`; expected `set PATH=VALUE …`"
            ))
        }
        None => return Err("empty request; expected `set PATH=VALUE …`".into()),
    }
    let parsed = words
        .map(live::parse_assignment)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| e.to_string())?;
    let mut trial = cfg.clone();
    let update = live::prepare(&mut trial, &parsed).map_err(|e| e.to_string())?;
    Ok((trial, update))
}

/// Handle one request line; returns the reply line.
pub fn respond(line: &str, cfg: &mut RigConfig, live: &LiveParams) -> String {
    let (trial, update) = match parse_request(line, cfg) {
        Ok(r) => r,
        Err(e) => return format!("error: {e}"),
    };
    let text: Vec<String> = update
        .changes
        .iter()
        .flatten()
        .map(|a| format!("{}={} {}", a.param.path, a.value, a.param.unit))
        .collect();
    let seq = match live.publish(update, APPLY_TIMEOUT) {
        Ok(s) => s,
        Err(e) => return format!("error: {e}"),
    };
    *cfg = trial;
    match live.wait_applied(seq, APPLY_TIMEOUT) {
        Some(cycle) => format!("ok cycle {cycle}: {}", text.join(", ")),
        None => format!(
            "error: change published but not applied within {} s (loop stopped?)",
            APPLY_TIMEOUT.as_secs()
        ),
    }
}

/// Client side of `ehactl set`: send one request, return the reply line.
pub fn send(path: &Path, assignments: &[String]) -> std::io::Result<String> {
    let mut s = UnixStream::connect(path)?;
    s.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut req = String::from("set");
    for a in assignments {
        req.push(' ');
        req.push_str(a);
    }
    req.push('\n');
    s.write_all(req.as_bytes())?;
    let mut reply = String::new();
    BufReader::new(s).read_line(&mut reply)?;
    Ok(reply.trim_end().to_string())
}
