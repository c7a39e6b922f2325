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
use crate::RigConfig;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// How long a request waits for the loop to take a change over (s).
const APPLY_TIMEOUT: Duration = Duration::from_secs(2);

/// A running control-socket server; stops and removes the socket file when dropped.
pub struct ControlServer {
    path: PathBuf,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl ControlServer {
    /// Bind `path` (a stale socket file is replaced) and serve requests for the run of
    /// `cfg` through `live`.
    pub fn start(
        path: &Path,
        cfg: RigConfig,
        live: Arc<LiveParams>,
    ) -> std::io::Result<ControlServer> {
        if path.exists() {
            // Refuse to steal a socket another process still serves.
            if UnixStream::connect(path).is_ok() {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::AddrInUse,
                    "another ehactl run is serving this socket",
                ));
            }
            std::fs::remove_file(path)?;
        }
        let listener = UnixListener::bind(path)?;
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

impl Drop for ControlServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let _ = std::fs::remove_file(&self.path);
    }
}

fn serve(listener: UnixListener, mut cfg: RigConfig, live: Arc<LiveParams>, stop: Arc<AtomicBool>) {
    while !stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((stream, _)) => {
                let _ = stream.set_nonblocking(false);
                let _ = stream.set_read_timeout(Some(Duration::from_secs(5)));
                let _ = handle(stream, &mut cfg, &live);
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

fn handle(stream: UnixStream, cfg: &mut RigConfig, live: &LiveParams) -> std::io::Result<()> {
    let mut reader = BufReader::new(stream.try_clone()?);
    let mut line = String::new();
    reader.read_line(&mut line)?;
    let reply = respond(line.trim(), cfg, live);
    let mut w = stream;
    w.write_all(reply.as_bytes())?;
    w.write_all(b"\n")
}

/// Handle one request line; returns the reply line.
pub fn respond(line: &str, cfg: &mut RigConfig, live: &LiveParams) -> String {
    let mut words = line.split_whitespace();
    match words.next() {
        Some("set") => {}
        Some(other) => {
            return format!("error: unknown request `{other}`; expected `set PATH=VALUE …`")
        }
        None => return "error: empty request; expected `set PATH=VALUE …`".into(),
    }
    let mut parsed = Vec::new();
    for w in words {
        match live::parse_assignment(w) {
            Ok(a) => parsed.push(a),
            Err(e) => return format!("error: {e}"),
        }
    }
    let mut trial = cfg.clone();
    let update = match live::prepare(&mut trial, &parsed) {
        Ok(u) => u,
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
