//! Control socket: a Unix stream socket next to a running `ehactl run --control-socket
//! PATH` through which `ehactl set --socket PATH control.pi.kp=0.5 …` changes gains and
//! setpoint parameters while the loop runs. The server is a normal (non-real-time) thread:
//! it parses and validates the request against the running config ([`live::prepare`]),
//! publishes it into the [`LiveParams`] back buffer and replies once the loop has taken it
//! over at a cycle boundary.
//!
//! Protocol: request lines `set PATH=VALUE [PATH=VALUE …]`, each answered in order by one
//! reply line `ok cycle N: PATH=VALUE UNIT, …` or `error: …` (several lines may be sent on
//! one connection). Every refused request is logged as a `param_refused` event in the
//! run's `/events` and on stderr, with the request and the reason.

use crate::live::{self, LiveParams};
use ehactl_config::RigConfig;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::Shutdown;
use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long a request waits for the loop to take a change over (s).
const APPLY_TIMEOUT: Duration = Duration::from_secs(2);
/// Longest request line (bytes); a longer one is refused and the client dropped.
pub const MAX_LINE: usize = 4096;
/// A client must deliver its whole request line within this time (s), however it trickles.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(2);
/// Connections open at once; beyond it the longest-idle one is closed to make room.
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

/// Accept clients and serve each on its own thread, so a slow or hostile client never
/// blocks another; each request line must arrive within [`REQUEST_TIMEOUT`] and
/// [`MAX_LINE`] bytes. With [`MAX_CLIENTS`] connections open, the one that has waited
/// longest for a request line is closed (with an answer) to make room: idle connections
/// never lock out `ehactl set`. Only when every connection is busy with a request is the
/// newcomer told to retry.
fn serve(listener: UnixListener, cfg: RigConfig, live: Arc<LiveParams>, stop: Arc<AtomicBool>) {
    let cfg = Arc::new(Mutex::new(cfg));
    let conns: Arc<Mutex<Vec<Conn>>> = Arc::new(Mutex::new(Vec::new()));
    let mut next_id = 0u64;
    while !stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((mut stream, _)) => {
                let Ok(handle_copy) = stream.try_clone() else {
                    continue;
                };
                let evicted = Arc::new(AtomicBool::new(false));
                {
                    let mut list = conns.lock().unwrap_or_else(|p| p.into_inner());
                    if list.len() >= MAX_CLIENTS {
                        let oldest = list
                            .iter()
                            .enumerate()
                            .filter(|(_, c)| c.reading)
                            .min_by_key(|(_, c)| c.since)
                            .map(|(i, _)| i);
                        match oldest {
                            Some(i) => {
                                let c = list.swap_remove(i);
                                c.evicted.store(true, Ordering::Release);
                                let _ = c.stream.shutdown(Shutdown::Read);
                            }
                            None => {
                                drop(list);
                                let _ = stream.set_write_timeout(Some(Duration::from_millis(100)));
                                let _ = stream.write_all(
                                    b"error: too many control clients, all busy with a request; retry\n",
                                );
                                continue;
                            }
                        }
                    }
                    next_id += 1;
                    list.push(Conn {
                        id: next_id,
                        stream: handle_copy,
                        reading: true,
                        since: Instant::now(),
                        evicted: evicted.clone(),
                    });
                }
                let id = next_id;
                let (cfg, live, conns2) = (cfg.clone(), live.clone(), conns.clone());
                let spawned = std::thread::Builder::new()
                    .name("ehactl-ctl-client".into())
                    .spawn(move || {
                        let _ = handle(
                            stream,
                            &cfg,
                            &live,
                            &Registry {
                                conns: &conns2,
                                id,
                                evicted,
                            },
                        );
                        let mut list = conns2.lock().unwrap_or_else(|p| p.into_inner());
                        list.retain(|c| c.id != id);
                    });
                if spawned.is_err() {
                    let mut list = conns.lock().unwrap_or_else(|p| p.into_inner());
                    list.retain(|c| c.id != id);
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

/// An open client connection, as the accept loop sees it.
struct Conn {
    id: u64,
    /// A handle on the client's socket, to close it if it must make room.
    stream: UnixStream,
    /// Waiting for a request line (not serving one).
    reading: bool,
    /// Since when it has been waiting.
    since: Instant,
    /// Set when the accept loop closed it to make room.
    evicted: Arc<AtomicBool>,
}

/// A connection's entry in the accept loop's list.
struct Registry<'a> {
    conns: &'a Mutex<Vec<Conn>>,
    id: u64,
    evicted: Arc<AtomicBool>,
}

impl Registry<'_> {
    fn set_reading(&self, reading: bool) {
        let mut list = self.conns.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(c) = list.iter_mut().find(|c| c.id == self.id) {
            c.reading = reading;
            c.since = Instant::now();
        }
    }
}

/// Why no request line could be read.
#[derive(Debug, PartialEq)]
pub enum ReadError {
    /// The client closed the connection with nothing pending.
    Closed,
    /// Nothing at all arrived within [`REQUEST_TIMEOUT`].
    Idle,
    /// A partial line, a line too long, not text, or an I/O error; the bytes received
    /// so far (at most [`MAX_LINE`]) and the message.
    Bad(String, String),
}

/// Reads request lines one at a time from a stream, keeping what follows a line for the
/// next call (a client may send several lines at once).
#[derive(Default)]
pub struct LineReader {
    pending: Vec<u8>,
}

impl LineReader {
    /// The next line (without its newline) of at most [`MAX_LINE`] bytes, which must
    /// arrive within [`REQUEST_TIMEOUT`] from this call.
    pub fn next_line(&mut self, stream: &mut UnixStream) -> Result<String, ReadError> {
        stream
            .set_nonblocking(false)
            .map_err(|e| ReadError::Bad(String::new(), e.to_string()))?;
        let t0 = Instant::now();
        let mut chunk = [0u8; 512];
        loop {
            if let Some(i) = self.pending.iter().position(|&b| b == b'\n') {
                let line: Vec<u8> = self.pending.drain(..=i).take(i).collect();
                if line.len() > MAX_LINE {
                    return Err(self.bad(line, format!("request longer than {MAX_LINE} bytes")));
                }
                return String::from_utf8(line)
                    .map_err(|e| self.bad(e.into_bytes(), "request is not UTF-8 text".into()));
            }
            if self.pending.len() > MAX_LINE {
                let line = std::mem::take(&mut self.pending);
                return Err(self.bad(line, format!("request longer than {MAX_LINE} bytes")));
            }
            let left = REQUEST_TIMEOUT.saturating_sub(t0.elapsed());
            if left.is_zero() {
                if self.pending.is_empty() {
                    return Err(ReadError::Idle);
                }
                let line = std::mem::take(&mut self.pending);
                return Err(self.bad(
                    line,
                    format!(
                        "request not complete within {} s (no newline)",
                        REQUEST_TIMEOUT.as_secs_f64()
                    ),
                ));
            }
            stream
                .set_read_timeout(Some(left))
                .map_err(|e| ReadError::Bad(String::new(), e.to_string()))?;
            match stream.read(&mut chunk) {
                Ok(0) if self.pending.is_empty() => return Err(ReadError::Closed),
                // A last line without its newline, then end of stream: take it as a line.
                Ok(0) => self.pending.push(b'\n'),
                Ok(n) => self.pending.extend_from_slice(&chunk[..n]),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock
                            | std::io::ErrorKind::TimedOut
                            | std::io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => {
                    let line = std::mem::take(&mut self.pending);
                    return Err(self.bad(line, e.to_string()));
                }
            }
        }
    }

    fn bad(&mut self, mut line: Vec<u8>, why: String) -> ReadError {
        line.truncate(MAX_LINE);
        ReadError::Bad(String::from_utf8_lossy(&line).into_owned(), why)
    }
}

/// Read one request line of at most [`MAX_LINE`] bytes within [`REQUEST_TIMEOUT`].
pub fn read_request(stream: &mut UnixStream) -> Result<String, String> {
    LineReader::default()
        .next_line(stream)
        .map_err(|e| match e {
            ReadError::Closed => "connection closed before a request".to_string(),
            ReadError::Idle => format!(
                "request not complete within {} s",
                REQUEST_TIMEOUT.as_secs_f64()
            ),
            ReadError::Bad(_, why) => why,
        })
}

/// Most request lines served on one connection; the next is refused and the client closed.
pub const MAX_REQUESTS_PER_CONNECTION: usize = 64;

/// Serve one connection: every request line gets one reply line, in order, until the
/// client closes, stays idle for [`REQUEST_TIMEOUT`] after a reply, or sends a bad line
/// (refused with an answer, then closed). Every refused request is logged
/// ([`LiveParams::refused`]).
fn handle(
    mut stream: UnixStream,
    cfg: &Mutex<RigConfig>,
    live: &LiveParams,
    reg: &Registry<'_>,
) -> std::io::Result<()> {
    stream.set_write_timeout(Some(REQUEST_TIMEOUT))?;
    let mut reader = LineReader::default();
    let mut served = 0usize;
    loop {
        reg.set_reading(true);
        let got = reader.next_line(&mut stream);
        reg.set_reading(false);
        if reg.evicted.load(Ordering::Acquire) {
            let msg = format!(
                "error: closed: no complete request line while {MAX_CLIENTS} connections were open and another client connected; send the request at once after connecting\n"
            );
            return stream.write_all(msg.as_bytes());
        }
        let line = match got {
            Ok(line) => line,
            Err(ReadError::Closed) => return Ok(()),
            Err(ReadError::Idle) if served > 0 => return Ok(()),
            Err(ReadError::Idle) => {
                let msg = format!(
                    "error: no request within {} s; expected `set PATH=VALUE …` and a newline\n",
                    REQUEST_TIMEOUT.as_secs_f64()
                );
                return stream.write_all(msg.as_bytes());
            }
            Err(ReadError::Bad(partial, why)) => {
                live.refused(partial.trim(), &why, None);
                stream.write_all(format!("error: {why}\n").as_bytes())?;
                return Ok(());
            }
        };
        served += 1;
        if served > MAX_REQUESTS_PER_CONNECTION {
            let why = format!(
                "more than {MAX_REQUESTS_PER_CONNECTION} requests on one connection; reconnect"
            );
            live.refused(line.trim(), &why, None);
            return stream.write_all(format!("error: {why}\n").as_bytes());
        }
        let reply = {
            let mut cfg = cfg.lock().unwrap_or_else(|p| p.into_inner());
            match apply(line.trim(), &mut cfg, live) {
                Ok(ok) => ok,
                Err(r) => {
                    live.refused(line.trim(), &r.reason, r.param);
                    format!("error: {}", r.reason)
                }
            }
        };
        stream.write_all(reply.as_bytes())?;
        stream.write_all(b"\n")?;
    }
}

/// A refused request: the field concerned (a registry path) when known, and why.
#[derive(Debug)]
pub struct Refusal {
    /// Registry path of the refused field, if the refusal concerns one.
    pub param: Option<&'static str>,
    /// Why (the reply's text after `error: `).
    pub reason: String,
}

/// The registry's own `&'static` spelling of `path`, if it is a parameter.
fn registry_path(path: &str) -> Option<&'static str> {
    ehactl_config::registries()
        .into_iter()
        .flat_map(|t| t.iter())
        .find(|p| p.path == path)
        .map(|p| p.path)
}

/// [`parse_request`] with the refused field kept apart from the message.
fn parse_checked(line: &str, cfg: &RigConfig) -> Result<(RigConfig, live::Update), Refusal> {
    let mut words = line.split_whitespace();
    let refuse = |reason: String| Refusal {
        param: None,
        reason,
    };
    match words.next() {
        Some("set") => {}
        Some(other) => {
            return Err(refuse(format!(
                "unknown request `{other}`; expected `set PATH=VALUE …`"
            )))
        }
        None => return Err(refuse("empty request; expected `set PATH=VALUE …`".into())),
    }
    let from_config = |e: ehactl_plant::ConfigError| Refusal {
        param: registry_path(&e.path),
        reason: e.to_string(),
    };
    let parsed = words
        .map(live::parse_assignment)
        .collect::<Result<Vec<_>, _>>()
        .map_err(from_config)?;
    let mut trial = cfg.clone();
    let update = live::prepare(&mut trial, &parsed).map_err(from_config)?;
    Ok((trial, update))
}

/// Parse one request line and validate it against the running config `cfg` (the same
/// checks as a config file): the config it would produce and the update to publish. `cfg`
/// itself is not changed.
pub fn parse_request(line: &str, cfg: &RigConfig) -> Result<(RigConfig, live::Update), String> {
    parse_checked(line, cfg).map_err(|r| r.reason)
}

/// Handle one request line; returns the reply line (refusals are not logged here; the
/// server logs them).
pub fn respond(line: &str, cfg: &mut RigConfig, live: &LiveParams) -> String {
    match apply(line, cfg, live) {
        Ok(s) => s,
        Err(r) => format!("error: {}", r.reason),
    }
}

/// Validate, publish and wait for one request; `Ok` is the reply line.
fn apply(line: &str, cfg: &mut RigConfig, live: &LiveParams) -> Result<String, Refusal> {
    let (trial, update) = parse_checked(line, cfg)?;
    let first = update.changes.iter().flatten().next().map(|a| a.param.path);
    let text: Vec<String> = update
        .changes
        .iter()
        .flatten()
        .map(|a| format!("{}={} {}", a.param.path, a.value, a.param.unit))
        .collect();
    let seq = live.publish(update, APPLY_TIMEOUT).map_err(|e| Refusal {
        param: first,
        reason: e.to_string(),
    })?;
    *cfg = trial;
    match live.wait_applied(seq, APPLY_TIMEOUT) {
        Some(cycle) => Ok(format!("ok cycle {cycle}: {}", text.join(", "))),
        None => Err(Refusal {
            param: first,
            reason: format!(
                "change published but not applied within {} s (loop stopped?)",
                APPLY_TIMEOUT.as_secs()
            ),
        }),
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
