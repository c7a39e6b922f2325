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
//!
//! Isolation: each client has its own bounded queue ([`CLIENT_QUEUE`] frames) and its own
//! writer thread. Relaying a frame formats it once and, for every other client, writes it
//! to the socket without waiting (`MSG_DONTWAIT`) while that client's queue is empty, else
//! (or for the part that did not fit) pushes it into the queue; a client whose queue is full (it stopped reading: its
//! socket buffer and then its queue filled up) is dropped (its connection is shut down,
//! `clients_dropped` counts it, one line on stderr), so a stalled client never delays the
//! others. Text a client sent is quoted in the hub's log lines only sanitised (printable
//! ASCII, at most 80 characters, see [`sanitize`]).
//!
//! Log volume: malformed input is reported per client without flooding stderr (a client
//! sending megabytes of junk must not fill the disk through the journal or stall the hub on a
//! full stderr pipe): the first [`QUOTED_COMPLAINTS`] messages are quoted, then one line per
//! [`COMPLAINT_INTERVAL`] with the count, and the total on the disconnect line (see
//! [`Complaints`]).

use crate::frame::CanFrame;
use crate::socketcand::{format_frame, parse_send, words, Framer};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Counters of a running hub.
#[derive(Debug, Default)]
pub struct HubStats {
    /// Frames received from clients.
    pub frames_in: AtomicU64,
    /// Frame deliveries to clients.
    pub frames_out: AtomicU64,
    /// Malformed messages received (reported on stderr).
    pub malformed: AtomicU64,
    /// Clients dropped because their queue was full (they did not read).
    pub clients_dropped: AtomicU64,
}

/// Malformed messages of one client quoted in full on stderr; the rest are counted.
pub const QUOTED_COMPLAINTS: u64 = 5;
/// At most one summary line per client per interval for its further malformed messages.
pub const COMPLAINT_INTERVAL: Duration = Duration::from_secs(10);

/// One client's malformed input as reported on stderr: rate-limited and summarised.
#[derive(Debug)]
pub struct Complaints {
    /// Malformed messages from this client so far.
    pub total: u64,
    /// Counted since the last line that mentioned them.
    unreported: u64,
    last_line: Instant,
    latest: String,
}

impl Default for Complaints {
    fn default() -> Self {
        Complaints {
            total: 0,
            unreported: 0,
            last_line: Instant::now(),
            latest: String::new(),
        }
    }
}

impl Complaints {
    /// Count one malformed message; returns the line to print, if any (the first
    /// [`QUOTED_COMPLAINTS`] in full, then at most one count per [`COMPLAINT_INTERVAL`]).
    pub fn add(&mut self, who: &str, what: &str) -> Option<String> {
        self.total += 1;
        if self.total < QUOTED_COMPLAINTS {
            self.last_line = Instant::now();
            return Some(format!("hub: client {who}: {}", sanitize(what)));
        }
        if self.total == QUOTED_COMPLAINTS {
            self.last_line = Instant::now();
            return Some(format!(
                "hub: client {who}: {} (further malformed messages from this client are counted: one line per {} s, the total when it disconnects)",
                sanitize(what),
                COMPLAINT_INTERVAL.as_secs()
            ));
        }
        self.unreported += 1;
        if self.latest.is_empty() || self.unreported == 1 {
            self.latest = sanitize(what);
        }
        let dt = self.last_line.elapsed();
        if dt < COMPLAINT_INTERVAL {
            return None;
        }
        let line = format!(
            "hub: client {who}: {} more malformed messages in the last {:.0} s ({} in all); e.g. {}",
            self.unreported,
            dt.as_secs_f64(),
            self.total,
            self.latest
        );
        self.unreported = 0;
        self.latest.clear();
        self.last_line = Instant::now();
        Some(line)
    }

    /// What to append to the disconnect line: the total, if there was any malformed input.
    pub fn at_disconnect(&self) -> Option<String> {
        (self.total > 0).then(|| {
            format!(
                "{} malformed messages in all ({} not shown one by one)",
                self.total,
                self.total.saturating_sub(QUOTED_COMPLAINTS)
            )
        })
    }
}

/// Frames queued per client before it counts as not reading and is dropped: 2048 frames
/// are 0.5 s of a 1 kHz SYNC cycle with 4 frames per period, more than a join delay holds.
pub const CLIENT_QUEUE: usize = 2048;

struct Client {
    id: u64,
    channel: String,
    /// Handle for shutting the connection down when the client is dropped.
    stream: TcpStream,
    /// This client's queue; its writer thread writes the frames to the socket.
    queue: SyncSender<Arc<[u8]>>,
    /// Messages in `queue` not yet completely written by the writer thread. While it is 0
    /// the relay writes to the socket itself without waiting (`MSG_DONTWAIT`): no thread
    /// hop for a client that keeps up; what does not fit goes to the queue, in order.
    queued: Arc<AtomicU64>,
    /// Raw socket for the non-waiting send.
    fd: std::os::fd::RawFd,
}

impl Client {
    /// Send without waiting; returns how many bytes went out (0 if the socket is full).
    fn send_now(&self, b: &[u8]) -> std::io::Result<usize> {
        // SAFETY: `fd` is the open socket of `self.stream` (kept alive by it); `b` is a
        // valid buffer of `b.len()` bytes.
        let n = unsafe {
            libc::send(
                self.fd,
                b.as_ptr().cast(),
                b.len(),
                libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL,
            )
        };
        if n >= 0 {
            return Ok(n as usize);
        }
        let e = std::io::Error::last_os_error();
        if e.kind() == std::io::ErrorKind::WouldBlock {
            Ok(0)
        } else {
            Err(e)
        }
    }

    /// Queue `m` for the writer thread; an error if the queue is full (client not reading).
    fn enqueue(&self, m: Arc<[u8]>) -> Result<(), TrySendError<Arc<[u8]>>> {
        self.queued.fetch_add(1, Ordering::AcqRel);
        self.queue.try_send(m).inspect_err(|_| {
            self.queued.fetch_sub(1, Ordering::AcqRel);
        })
    }
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
        // Accept failures (out of descriptors…) repeat as fast as the loop turns: one line
        // per interval with the count, and a pause so the loop does not spin.
        let (mut failed, mut failed_line) = (0u64, None::<Instant>);
        for conn in self.listener.incoming() {
            let stream = match conn {
                Ok(s) => s,
                Err(e) => {
                    failed += 1;
                    if failed_line.is_none_or(|t| t.elapsed() >= COMPLAINT_INTERVAL) {
                        eprintln!("hub: accept failed: {e} ({failed} failures so far)");
                        failed_line = Some(Instant::now());
                    }
                    std::thread::sleep(Duration::from_millis(10));
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
                    let mut complaints = Complaints::default();
                    let why = client_loop(
                        id,
                        stream,
                        &reg,
                        &stats,
                        quiet,
                        &peer,
                        delay,
                        &mut complaints,
                    );
                    if let Ok(mut r) = reg.lock() {
                        r.clients.retain(|c| c.id != id);
                    }
                    match complaints.at_disconnect() {
                        Some(total) => {
                            eprintln!("hub: client {id} ({peer}) disconnected: {why}; {total}")
                        }
                        None if !quiet => {
                            eprintln!("hub: client {id} ({peer}) disconnected: {why}")
                        }
                        None => {}
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
    let msg: Arc<[u8]> = Arc::from(format_frame(f, now()).as_bytes());
    let Ok(mut r) = reg.lock() else { return };
    let mut dead = Vec::new();
    for c in r.clients.iter() {
        if c.id == from || c.channel != channel {
            continue;
        }
        // Fast path: nothing queued, write directly (never waits); the rest is queued.
        let r = if c.queued.load(Ordering::Acquire) == 0 {
            match c.send_now(&msg) {
                Ok(n) if n == msg.len() => {
                    stats.frames_out.fetch_add(1, Ordering::Relaxed);
                    Ok(())
                }
                Ok(n) => c.enqueue(Arc::from(&msg[n..])),
                Err(_) => Err(TrySendError::Disconnected(msg.clone())),
            }
        } else {
            c.enqueue(msg.clone())
        };
        match r {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                stats.clients_dropped.fetch_add(1, Ordering::Relaxed);
                eprintln!(
                    "hub: client {} dropped: it did not read ({CLIENT_QUEUE} frames queued); the others are not held up",
                    c.id
                );
                dead.push(c.id);
            }
            Err(TrySendError::Disconnected(_)) => dead.push(c.id),
        }
    }
    if !dead.is_empty() {
        for c in r.clients.iter().filter(|c| dead.contains(&c.id)) {
            let _ = c.stream.shutdown(std::net::Shutdown::Both);
        }
        r.clients.retain(|c| !dead.contains(&c.id));
    }
}

/// A client's writer thread: after the join delay, writes its queued frames in order
/// until the queue is dropped (client removed) or a write fails.
fn writer_loop(
    mut stream: TcpStream,
    q: Receiver<Arc<[u8]>>,
    queued: Arc<AtomicU64>,
    join_delay: Duration,
    stats: &HubStats,
) {
    std::thread::sleep(join_delay);
    while let Ok(m) = q.recv() {
        if stream.write_all(&m).is_err() {
            let _ = stream.shutdown(std::net::Shutdown::Both);
            return;
        }
        if !m.is_empty() {
            stats.frames_out.fetch_add(1, Ordering::Relaxed);
        }
        queued.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Client text for a log line: printable ASCII kept, everything else (control characters,
/// escape sequences, non-ASCII) as `\xNN` / `\u{..}`, at most 80 characters (then `…`).
pub fn sanitize(s: &str) -> String {
    let mut out = String::new();
    for (n, c) in s.chars().enumerate() {
        if n >= 80 {
            out.push('…');
            break;
        }
        if c.is_ascii_graphic() || c == ' ' {
            out.push(c);
        } else if c.is_ascii() {
            out.push_str(&format!("\\x{:02X}", c as u32));
        } else {
            out.push_str(&format!("\\u{{{:X}}}", c as u32));
        }
    }
    out
}

enum State {
    Greeted,
    Opened(String),
    Raw(String),
}

/// One client's connection as its reader thread serves it (see [`client_loop`]).
struct Session<'a> {
    id: u64,
    stream: TcpStream,
    reg: &'a Arc<Mutex<Registry>>,
    stats: &'a Arc<HubStats>,
    quiet: bool,
    peer: &'a str,
    join_delay: Duration,
    complaints: &'a mut Complaints,
    who: String,
    state: State,
}

#[allow(clippy::too_many_arguments)]
fn client_loop(
    id: u64,
    mut stream: TcpStream,
    reg: &Arc<Mutex<Registry>>,
    stats: &Arc<HubStats>,
    quiet: bool,
    peer: &str,
    join_delay: Duration,
    complaints: &mut Complaints,
) -> String {
    let _ = stream.set_nodelay(true);
    // Only this client's writer thread waits on a client that stops reading; its queue fills
    // and the relay drops it (see the module docs).
    let _ = stream.set_write_timeout(Some(Duration::from_millis(500)));
    if let Err(e) = stream.write_all(b"< hi >") {
        return format!("cannot greet: {e}");
    }
    let mut session = Session {
        id,
        stream,
        reg,
        stats,
        quiet,
        peer,
        join_delay,
        complaints,
        who: format!("{id} ({peer})"),
        state: State::Greeted,
    };
    let mut framer = Framer::new();
    let mut buf = [0u8; 4096];
    loop {
        let n = match session.stream.read(&mut buf) {
            Ok(0) => return "connection closed".into(),
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return format!("read error: {e}"),
        };
        framer.push(&buf[..n]);
        loop {
            let r = match framer.next_message() {
                Ok(Some(m)) => session.on_message(m),
                Ok(None) => break,
                Err(e) => {
                    session.complain(&e);
                    continue;
                }
            };
            if let Err(why) = r {
                return why;
            }
        }
    }
}

impl Session<'_> {
    /// A malformed or unsupported message: counted, quoted (the first few) or summed up.
    fn complain(&mut self, what: &str) {
        self.stats.malformed.fetch_add(1, Ordering::Relaxed);
        if let Some(line) = self.complaints.add(&self.who, what) {
            eprintln!("{line}");
        }
    }

    /// One message of the client; `Err` ends the connection with the reason.
    fn on_message(&mut self, msg: &str) -> Result<(), String> {
        match std::mem::replace(&mut self.state, State::Greeted) {
            State::Raw(ch) => {
                // taken out and put back: no copy of the channel name per frame
                let r = self.on_raw(&ch, msg);
                self.state = State::Raw(ch);
                r
            }
            other => {
                self.state = other;
                self.on_command(msg)
            }
        }
    }

    /// A message in rawmode on channel `ch`: a frame to relay, or an echo.
    fn on_raw(&mut self, ch: &str, msg: &str) -> Result<(), String> {
        if msg.starts_with("< send ") {
            match parse_send(msg) {
                Ok(f) => {
                    self.stats.frames_in.fetch_add(1, Ordering::Relaxed);
                    relay(self.reg, self.stats, self.id, ch, &f);
                }
                Err(e) => self.complain(&format!("{e}; frame not relayed")),
            }
        } else if msg == "< echo >" {
            if self.stream.write_all(b"< echo >").is_err() {
                return Err("write error".into());
            }
        } else {
            self.complain(&format!(
                "unsupported command `{msg}` in rawmode (expected `< send ID DLC BYTES >`); ignored"
            ));
        }
        Ok(())
    }

    /// A command before rawmode: `< open CHANNEL >`, then `< rawmode >`.
    fn on_command(&mut self, msg: &str) -> Result<(), String> {
        let w: Vec<&str> = match words(msg) {
            Ok(w) => w.collect(),
            Err(e) => {
                self.complain(&e);
                return Ok(());
            }
        };
        let reply: &[u8] = match (w.as_slice(), &self.state) {
            (["open", ch], _) => {
                self.state = State::Opened(ch.to_string());
                b"< ok >"
            }
            (["rawmode"], State::Opened(ch)) => {
                let ch = ch.clone();
                return self.enter_rawmode(ch);
            }
            (["rawmode"], State::Greeted) => {
                self.complain("`< rawmode >` before `< open CHANNEL >`");
                b"< error open a channel first >"
            }
            _ => {
                self.complain(&format!(
                    "unsupported command `{msg}` (this hub supports `< open CHANNEL >` and `< rawmode >`)"
                ));
                b"< error unsupported command >"
            }
        };
        if self.stream.write_all(reply).is_err() {
            return Err("write error".into());
        }
        Ok(())
    }

    /// `< rawmode >` on channel `ch`: the client is registered for relayed frames, answered,
    /// and its writer thread started.
    fn enter_rawmode(&mut self, ch: String) -> Result<(), String> {
        let id = self.id;
        let writer = self
            .stream
            .try_clone()
            .map_err(|e| format!("cannot clone socket: {e}"))?;
        // Register first (frames from now on are queued for this client, none lost in the
        // gap), reply, then start the writer: it waits the join delay before the first
        // frame, so no frame precedes the `< ok >` or shares its `recv`.
        let (tx, rx) = sync_channel::<Arc<[u8]>>(CLIENT_QUEUE);
        // An empty marker message, counted as queued, keeps the relay queueing (not
        // sending) until the writer has passed the join delay and taken it off.
        let queued = Arc::new(AtomicU64::new(1));
        let _ = tx.try_send(Arc::from(&b""[..]));
        let shut = self
            .stream
            .try_clone()
            .map_err(|e| format!("cannot clone socket: {e}"))?;
        if let Ok(mut r) = self.reg.lock() {
            let fd = std::os::fd::AsRawFd::as_raw_fd(&shut);
            r.clients.push(Client {
                id,
                channel: ch.clone(),
                stream: shut,
                queue: tx,
                queued: queued.clone(),
                fd,
            });
        }
        if self.stream.write_all(b"< ok >").is_err() {
            return Err("write error".into());
        }
        let (st, join_delay) = (self.stats.clone(), self.join_delay);
        std::thread::Builder::new()
            .name(format!("hub-writer-{id}"))
            .spawn(move || writer_loop(writer, rx, queued, join_delay, &st))
            .map_err(|e| format!("cannot start a writer thread: {e}"))?;
        if !self.quiet {
            eprintln!("hub: client {id} ({}) in rawmode on {ch}", self.peer);
        }
        self.state = State::Raw(ch);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{Complaints, QUOTED_COMPLAINTS};

    #[test]
    fn complaints_are_quoted_then_counted() {
        let mut c = Complaints::default();
        let lines: Vec<String> = (0..10_000)
            .filter_map(|i| c.add("1 (peer)", &format!("junk {i}")))
            .collect();
        // within one interval: only the first ones, the last of them announcing the counting
        assert_eq!(lines.len() as u64, QUOTED_COMPLAINTS);
        assert!(lines[0].contains("junk 0"));
        assert!(lines[4].contains("counted"), "{}", lines[4]);
        // once the interval has passed, the next one brings a line with the counts
        c.last_line -= super::COMPLAINT_INTERVAL;
        let line = c.add("1 (peer)", "junk last").unwrap();
        assert!(
            line.contains("9996 more malformed messages") && line.contains("(10001 in all)"),
            "{line}"
        );
        assert!(c.add("1 (peer)", "junk").is_none());
        let end = c.at_disconnect().unwrap();
        assert!(end.starts_with("10002 malformed messages"), "{end}");
        assert!(Complaints::default().at_disconnect().is_none());
    }
}
