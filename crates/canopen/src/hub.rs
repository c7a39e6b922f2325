//! `ehactl canbus hub`: a socketcand-compatible rawmode relay so that several processes
//! (the ehactl master, python-can / canopen devices) share one virtual CAN bus over TCP.
//!
//! Rules (see the ICD): every frame a client sends goes to every OTHER client that opened
//! the same channel and entered rawmode; no echo to the sender; TCP_NODELAY; handshake
//! replies (`< hi >`, `< ok >`) are written alone, and a client receives no frames before
//! its `< rawmode >` has been answered, because python-can reads each handshake reply
//! with a single `recv` and compares it verbatim. The hub cannot see when the client has
//! *read* its `< ok >` (a frame written right after it can land in the same `recv` on a
//! busy machine), so frames for a newly joined client are held for a join delay
//! (default 200 ms) after the `< ok >` and then delivered in order: nothing is lost.

use crate::frame::CanFrame;
use crate::socketcand::{format_frame, parse_send, words, Framer};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// Counters of a running hub.
#[derive(Debug, Default)]
pub struct HubStats {
    /// Frames received from clients.
    pub frames_in: AtomicU64,
    /// Frame deliveries to clients.
    pub frames_out: AtomicU64,
    /// Malformed messages received (reported on stderr).
    pub malformed: AtomicU64,
}

/// Most bytes held for a client during its join delay (≈ 4000 frames).
const MAX_PENDING: usize = 256 * 1024;

struct Client {
    id: u64,
    channel: String,
    stream: TcpStream,
    /// False during the join delay: frames go to `pending`.
    ready: bool,
    pending: Vec<u8>,
    overflowed: bool,
}

#[derive(Default)]
struct Registry {
    clients: Vec<Client>,
}

/// A bound hub; [`Hub::serve`] runs it.
pub struct Hub {
    listener: TcpListener,
    registry: Arc<Mutex<Registry>>,
    stats: Arc<HubStats>,
    quiet: bool,
    join_delay: Duration,
}

impl Hub {
    /// Bind to `addr` (port 0 = any free port).
    pub fn bind(addr: &str, quiet: bool) -> std::io::Result<Hub> {
        let listener = TcpListener::bind(addr)?;
        Ok(Hub {
            listener,
            registry: Arc::new(Mutex::new(Registry::default())),
            stats: Arc::new(HubStats::default()),
            quiet,
            join_delay: Duration::from_millis(200),
        })
    }

    /// Hold frames for this long after a client's rawmode `< ok >` (see the module docs).
    pub fn with_join_delay(mut self, d: Duration) -> Hub {
        self.join_delay = d;
        self
    }

    /// The bound address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    /// Shared counters.
    pub fn stats(&self) -> Arc<HubStats> {
        self.stats.clone()
    }

    /// Accept clients forever (one thread per client).
    pub fn serve(self) -> std::io::Result<()> {
        let mut next_id = 0u64;
        for conn in self.listener.incoming() {
            let stream = match conn {
                Ok(s) => s,
                Err(e) => {
                    eprintln!("hub: accept failed: {e}");
                    continue;
                }
            };
            next_id += 1;
            let id = next_id;
            let reg = self.registry.clone();
            let stats = self.stats.clone();
            let quiet = self.quiet;
            let delay = self.join_delay;
            let _ = std::thread::Builder::new()
                .name(format!("hub-client-{id}"))
                .spawn(move || {
                    let peer = stream
                        .peer_addr()
                        .map_or_else(|_| "?".to_string(), |a| a.to_string());
                    let why = client_loop(id, stream, &reg, &stats, quiet, &peer, delay);
                    if let Ok(mut r) = reg.lock() {
                        r.clients.retain(|c| c.id != id);
                    }
                    if !quiet {
                        eprintln!("hub: client {id} ({peer}) disconnected: {why}");
                    }
                });
        }
        Ok(())
    }
}

fn now() -> Duration {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default()
}

fn relay(reg: &Mutex<Registry>, stats: &HubStats, from: u64, channel: &str, f: &CanFrame) {
    let msg = format_frame(f, now());
    let Ok(mut r) = reg.lock() else { return };
    let mut dead = Vec::new();
    for c in r.clients.iter_mut() {
        if c.id == from || c.channel != channel {
            continue;
        }
        if !c.ready {
            if c.pending.len() + msg.as_bytes().len() <= MAX_PENDING {
                c.pending.extend_from_slice(msg.as_bytes());
            } else if !c.overflowed {
                c.overflowed = true;
                eprintln!("hub: client {}: more than {MAX_PENDING} bytes of frames during its join delay; later ones dropped until it is ready", c.id);
            }
            continue;
        }
        if c.stream.write_all(msg.as_bytes()).is_err() {
            dead.push(c.id);
        } else {
            stats.frames_out.fetch_add(1, Ordering::Relaxed);
        }
    }
    if !dead.is_empty() {
        for c in r.clients.iter().filter(|c| dead.contains(&c.id)) {
            let _ = c.stream.shutdown(std::net::Shutdown::Both);
        }
        r.clients.retain(|c| !dead.contains(&c.id));
    }
}

enum State {
    Greeted,
    Opened(String),
    Raw(String),
}

/// End of a client's join delay: deliver what was held, then relay directly.
fn make_ready(reg: &Mutex<Registry>, id: u64) {
    let Ok(mut r) = reg.lock() else { return };
    if let Some(c) = r.clients.iter_mut().find(|c| c.id == id) {
        let pending = std::mem::take(&mut c.pending);
        if !pending.is_empty() && c.stream.write_all(&pending).is_err() {
            let _ = c.stream.shutdown(std::net::Shutdown::Both);
        }
        c.ready = true;
    }
}

fn client_loop(
    id: u64,
    mut stream: TcpStream,
    reg: &Arc<Mutex<Registry>>,
    stats: &HubStats,
    quiet: bool,
    peer: &str,
    join_delay: Duration,
) -> String {
    let _ = stream.set_nodelay(true);
    // A client that stops reading must not stall the bus for long.
    let _ = stream.set_write_timeout(Some(Duration::from_millis(500)));
    if let Err(e) = stream.write_all(b"< hi >") {
        return format!("cannot greet: {e}");
    }
    let mut state = State::Greeted;
    let mut framer = Framer::new();
    let mut buf = [0u8; 4096];
    let complain = |what: &str| {
        stats.malformed.fetch_add(1, Ordering::Relaxed);
        eprintln!("hub: client {id} ({peer}): {what}");
    };
    loop {
        let n = match stream.read(&mut buf) {
            Ok(0) => return "connection closed".into(),
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return format!("read error: {e}"),
        };
        framer.push(&buf[..n]);
        loop {
            let msg = match framer.next_message() {
                Ok(Some(m)) => m,
                Ok(None) => break,
                Err(e) => {
                    complain(&e);
                    continue;
                }
            };
            match &state {
                State::Raw(ch) => {
                    if msg.starts_with("< send ") {
                        match parse_send(msg) {
                            Ok(f) => {
                                stats.frames_in.fetch_add(1, Ordering::Relaxed);
                                relay(reg, stats, id, ch, &f);
                            }
                            Err(e) => complain(&format!("{e}; frame not relayed")),
                        }
                    } else if msg == "< echo >" {
                        if stream.write_all(b"< echo >").is_err() {
                            return "write error".into();
                        }
                    } else {
                        let m = msg.to_string();
                        complain(&format!(
                            "unsupported command `{m}` in rawmode (expected `< send ID DLC BYTES >`); ignored"
                        ));
                    }
                }
                State::Greeted | State::Opened(_) => {
                    let w: Vec<&str> = match words(msg) {
                        Ok(w) => w.collect(),
                        Err(e) => {
                            complain(&e);
                            continue;
                        }
                    };
                    let reply: &[u8] = match (w.as_slice(), &state) {
                        (["open", ch], _) => {
                            state = State::Opened(ch.to_string());
                            b"< ok >"
                        }
                        (["rawmode"], State::Opened(ch)) => {
                            let ch = ch.clone();
                            let writer = match stream.try_clone() {
                                Ok(s) => s,
                                Err(e) => return format!("cannot clone socket: {e}"),
                            };
                            // Register first, held (not ready), then reply: frames relayed
                            // from now on are kept for this client, none is lost in the gap
                            // between the reply and the registration, and none can precede
                            // the `< ok >` because held frames are written only by
                            // `make_ready`, after the reply.
                            if let Ok(mut r) = reg.lock() {
                                r.clients.push(Client {
                                    id,
                                    channel: ch.clone(),
                                    stream: writer,
                                    ready: false,
                                    pending: Vec::new(),
                                    overflowed: false,
                                });
                            }
                            if stream.write_all(b"< ok >").is_err() {
                                return "write error".into();
                            }
                            let delayed = !join_delay.is_zero() && {
                                let reg = reg.clone();
                                std::thread::Builder::new()
                                    .name(format!("hub-join-{id}"))
                                    .spawn(move || {
                                        std::thread::sleep(join_delay);
                                        make_ready(&reg, id);
                                    })
                                    .is_ok()
                            };
                            if !delayed {
                                // No delay asked for, or no thread for it: sleep here (this
                                // client's own frames wait in its socket meanwhile).
                                std::thread::sleep(join_delay);
                                make_ready(reg, id);
                            }
                            if !quiet {
                                eprintln!("hub: client {id} ({peer}) in rawmode on {ch}");
                            }
                            state = State::Raw(ch);
                            continue;
                        }
                        (["rawmode"], State::Greeted) => {
                            complain("`< rawmode >` before `< open CHANNEL >`");
                            b"< error open a channel first >"
                        }
                        _ => {
                            let m = msg.to_string();
                            complain(&format!(
                                "unsupported command `{m}` (this hub supports `< open CHANNEL >` and `< rawmode >`)"
                            ));
                            b"< error unsupported command >"
                        }
                    };
                    if stream.write_all(reply).is_err() {
                        return "write error".into();
                    }
                }
            }
        }
    }
}
