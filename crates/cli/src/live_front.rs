//! The front of the live view: the socket the user's Foxglove clients connect to, in front of
//! the Foxglove SDK's WebSocket server (which listens on an internal loopback port).
//!
//! Why a front at all (both written by hand because neither the SDK nor a maintained crate
//! offers them):
//!
//! 1. **Subprotocol name.** The Foxglove WebSocket protocol is published as
//!    `foxglove.websocket.v1` (<https://github.com/foxglove/ws-protocol/blob/main/docs/spec.md>),
//!    and Foxglove's own client library `@foxglove/ws-protocol` (`FoxgloveClient`, used by the
//!    open-source viewers and ROS tooling) offers only that name. The SDK server of the
//!    `foxglove` crate we use (0.30) negotiates only `foxglove.sdk.v1` / `foxglove.sdk.v1.1`
//!    (its `websocket/handshake.rs`: exact match, else HTTP 400) and has no option to accept
//!    another name. `foxglove.sdk.v1` carries the same messages as `foxglove.websocket.v1`
//!    (inline schemas in `advertise`; `v1.1` uses a schema table the older clients do not
//!    know), so the front reads the client's HTTP upgrade request, offers `foxglove.sdk.v1`
//!    to the SDK in place of `foxglove.websocket.v1`, and answers the client with the name it
//!    asked for. The `Sec-WebSocket-Accept` key does not depend on the subprotocol, so the
//!    rest of the handshake passes through unchanged. Clients offering an SDK name pass
//!    through untouched.
//! 2. **Per-client accounting.** The SDK drops the oldest queued messages of a client that
//!    does not keep up and only says so in a throttled `tracing` line, with no count. Here
//!    each client's server-to-client byte stream is read as WebSocket frames (RFC 6455 §5.2)
//!    into a bounded per-client queue, which is where the dropping now happens, counted:
//!    only `Message Data` frames (binary, first payload byte 0x01, spec "Message Data") are
//!    ever dropped, oldest first; text (JSON control messages such as `advertise`), other
//!    binary messages and WebSocket control frames are always delivered, and a client whose
//!    undelivered backlog exceeds [`MAX_QUEUED_BYTES`] anyway is disconnected (as the SDK
//!    does when its control queue overflows). The thread that reads from the SDK only moves
//!    bytes into memory, so the SDK's own queue for the connection stays near empty.
//!    A message counts as sent once the client's TCP has acknowledged it: what still sits in
//!    the kernel's send buffer when the connection is cut (Linux `SIOCOUTQ`) counts as
//!    dropped, and that buffer is capped ([`send_buffer_bytes`]) so a client that stops reading
//!    reaches the counted queue soon.
//!
//! Client-to-server bytes (masked frames: subscribe, unsubscribe…) are copied unchanged.
//!
//! Every connection is one task on a tokio runtime (the runtime the SDK itself is built on)
//! of two worker threads of normal priority, whatever the number of clients; none of it touches the control loop, which never waits for the live view (see
//! `live.rs`). What an idle client costs is its queue ([`data_queue_bytes`]: the
//! [`DATA_QUEUE_BUDGET`] shared out among `--live-max-clients`) and a few kB of buffers.
//! Only clients with a complete upgrade request count against `--live-max-clients`: a
//! connection still in its handshake has [`HANDSHAKE_TIMEOUT`] to complete it, and at most
//! [`MAX_PENDING_HANDSHAKES`] may be, so connections that never finish the handshake lock
//! no client out.

use std::collections::VecDeque;
use std::io::Write;
use std::net::{Shutdown, SocketAddr};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::Notify;

/// The subprotocol name of the published protocol spec (what `FoxgloveClient` offers).
pub const WS_PROTOCOL_V1: &str = "foxglove.websocket.v1";
/// The SDK's name for the same protocol with inline schemas.
pub const SDK_V1: &str = "foxglove.sdk.v1";
/// The SDK's newer variant (schema table); passed through when a client offers it.
pub const SDK_V1_1: &str = "foxglove.sdk.v1.1";

/// `Message Data` frames queued per client before the oldest is dropped: 0.27 s of a 5 kHz
/// run publishing /control, /plant and /timing (15 000 messages/s).
pub const MAX_QUEUED_MESSAGES: usize = 4096;
/// Most bytes of `Message Data` queued per client before the oldest is dropped: 0.45 s of
/// the 2.3 MB/s a 5 kHz run publishes. Bounds what an idle subscribed client costs.
pub const MAX_QUEUED_DATA_BYTES: usize = 1 << 20;
/// Fewest bytes of `Message Data` queued per client: 14 ms of a 5 kHz run.
pub const MIN_QUEUED_DATA_BYTES: usize = 32 << 10;
/// Bytes of `Message Data` queued for all clients together at most, shared out by
/// [`data_queue_bytes`]: what idle clients that never read can cost in all (each queued
/// message costs about 50 bytes more in bookkeeping).
pub const DATA_QUEUE_BUDGET: usize = 16 << 20;
/// Clients served at once unless `--live-max-clients` says otherwise.
pub const DEFAULT_MAX_CLIENTS: u16 = 16;
/// Worker threads of the front's runtime: every connection's relaying shares them.
const FRONT_WORKERS: usize = 2;
/// Stack of each worker thread (bytes): resident under `--realtime` (`mlockall`); the tasks
/// themselves live on the heap.
const FRONT_STACK: usize = 512 << 10;
/// Connections in their handshake at once (accepted, upgrade not completed) beyond which a
/// new connection is answered HTTP 503 at once. They do not count against
/// `--live-max-clients`, and each has [`HANDSHAKE_TIMEOUT`].
pub const MAX_PENDING_HANDSHAKES: usize = 64;
/// Undelivered bytes per client (all kinds) beyond which the client is disconnected.
pub const MAX_QUEUED_BYTES: usize = 64 << 20;
/// Largest `SO_SNDBUF` of a client's socket (bytes; Linux doubles it): 1 MiB holds 0.4 s of
/// the 2.3 MB/s a 5 kHz run publishes, so a client on a slow link is not starved, while a
/// client that stops reading leaves at most that much outside the counted queue. With more
/// than 16 clients allowed each gets less ([`send_buffer_bytes`]): kernel memory too.
const SEND_BUFFER: usize = 1 << 20;
/// Written bytes remembered per client to tell which messages the client's TCP has not
/// acknowledged: more than the doubled send buffer.
fn written_window(send_buffer: usize) -> u64 {
    4 * send_buffer as u64
}
/// Longest HTTP request or response head accepted (bytes).
const MAX_HEAD: usize = 16 << 10;
/// Time a connection has from accept to a completed HTTP upgrade (its request, the SDK's
/// answer): a connection that sends nothing, or its request a byte at a time, is closed then.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);
/// Largest WebSocket frame passed on (bytes); the SDK's messages are far smaller.
const MAX_FRAME: u64 = 256 << 20;

/// What one client got.
#[derive(Debug, Clone)]
pub struct ClientStats {
    /// The client's address as the front saw it.
    pub peer: SocketAddr,
    /// Subprotocol answered to the client (empty if the upgrade failed).
    pub subprotocol: String,
    /// `Message Data` messages written completely to the client's socket.
    pub messages_sent: u64,
    /// `Message Data` messages the client did not get: dropped because its queue was full,
    /// or still queued (or partly written) when it or the run ended.
    pub messages_dropped: u64,
}

struct Counters {
    peer: SocketAddr,
    subprotocol: Mutex<String>,
    sent: AtomicU64,
    dropped: AtomicU64,
    written: Mutex<Written>,
}

/// Bytes written to the client's socket, and where the recent `Message Data` ones end.
struct Written {
    bytes: u64,
    data_ends: VecDeque<u64>,
    /// Written bytes remembered ([`written_window`]).
    window: u64,
}

impl Default for Written {
    fn default() -> Self {
        Written {
            bytes: 0,
            data_ends: VecDeque::new(),
            window: written_window(SEND_BUFFER),
        }
    }
}

impl Written {
    /// `len` more bytes written (part of a message, or all of it).
    fn bytes(&mut self, len: usize) {
        self.bytes += len as u64;
    }

    /// The message written last is complete.
    fn end(&mut self, data: bool) {
        if data {
            self.data_ends.push_back(self.bytes);
        }
        while self
            .data_ends
            .front()
            .is_some_and(|&e| self.bytes - e > self.window)
        {
            self.data_ends.pop_front();
        }
    }

    /// `Message Data` messages not completely acknowledged when `unacked` bytes are.
    fn unacknowledged(&self, unacked: u64) -> u64 {
        let acked = self.bytes.saturating_sub(unacked);
        self.data_ends
            .iter()
            .rev()
            .take_while(|&&e| e > acked)
            .count() as u64
    }
}

/// Bytes written to `s` that the peer has not acknowledged (Linux `SIOCOUTQ`; 0 elsewhere).
fn unacknowledged_bytes(s: &std::net::TcpStream) -> u64 {
    #[cfg(target_os = "linux")]
    {
        let mut n: libc::c_int = 0;
        // SAFETY: `s` owns an open socket; TIOCOUTQ (= SIOCOUTQ) writes one c_int.
        let r = unsafe {
            libc::ioctl(
                std::os::fd::AsRawFd::as_raw_fd(s),
                libc::TIOCOUTQ,
                &mut n as *mut libc::c_int,
            )
        };
        if r == 0 {
            return n.max(0) as u64;
        }
    }
    let _ = s;
    0
}

#[derive(Debug)]
struct Unit {
    bytes: Vec<u8>,
    /// A `Message Data` message: may be dropped, and is counted.
    data: bool,
}

#[derive(Default)]
struct QueueState {
    units: VecDeque<Unit>,
    data_units: usize,
    /// Bytes of the queued `Message Data` units.
    data_bytes: usize,
    bytes: usize,
    /// No more units will come (the SDK closed its side).
    closed: bool,
    /// The client is gone or was cut off: nothing more is written.
    dead: bool,
}

struct Queue {
    state: Mutex<QueueState>,
    /// Wakes the client's writer task.
    ready: Notify,
}

/// Bytes of `Message Data` queued per client when at most `max_clients` are served: the
/// [`DATA_QUEUE_BUDGET`] shared out, within [`MIN_QUEUED_DATA_BYTES`] and
/// [`MAX_QUEUED_DATA_BYTES`] (1 MiB for up to 16 clients, 55 KiB each for 300).
pub fn data_queue_bytes(max_clients: usize) -> usize {
    (DATA_QUEUE_BUDGET / max_clients.max(1)).clamp(MIN_QUEUED_DATA_BYTES, MAX_QUEUED_DATA_BYTES)
}

/// Messages the SDK server queues per client before its front reads them
/// (`message_backlog_size`) when at most `max_clients` are served: the SDK's default 1024
/// for up to 16 clients, 16 384 shared out beyond, at least 128 (300 clients: 128, 27 ms of
/// a 5 kHz run). The front reads every client's SDK side at once into its counted queue, so
/// the SDK's backlog only fills (and drops, uncounted) when the machine cannot give the
/// front's threads the time to relay to every client.
pub fn sdk_backlog(max_clients: usize) -> usize {
    (16_384 / max_clients.max(1)).clamp(128, 1024)
}

/// `SO_SNDBUF` of each client's socket when at most `max_clients` are served: 16 MiB shared
/// out, within 64 KiB and [`SEND_BUFFER`] (1 MiB for up to 16 clients, 64 KiB each for 300).
fn send_buffer_bytes(max_clients: usize) -> usize {
    ((16 << 20) / max_clients.max(1)).clamp(64 << 10, SEND_BUFFER)
}

/// One connection: duplicates of the client's socket and the SDK-side socket (for
/// `shutdown` and `SIOCOUTQ` from any thread), the counters, the queue.
struct Conn {
    counters: Arc<Counters>,
    client: std::net::TcpStream,
    upstream: Mutex<Option<std::net::TcpStream>>,
    queue: Queue,
    /// Bytes of `Message Data` queued at most ([`data_queue_bytes`]).
    data_cap: usize,
}

impl Conn {
    /// Cut the connection off (both sockets), count what was still queued as dropped.
    fn kill(&self) {
        // Linger 0: when the last descriptor closes, the connection is reset and what the
        // client's TCP has not acknowledged is discarded, not delivered later by the kernel
        // (so counting it as dropped, in `Front::finish`, is true).
        set_linger_zero(&self.client);
        let _ = self.client.shutdown(Shutdown::Both);
        if let Ok(u) = self.upstream.lock() {
            if let Some(u) = u.as_ref() {
                let _ = u.shutdown(Shutdown::Both);
            }
        }
        let mut q = lock(&self.queue.state);
        q.dead = true;
        let n = q.data_units as u64;
        q.units.clear();
        q.data_units = 0;
        q.data_bytes = 0;
        q.bytes = 0;
        self.counters.dropped.fetch_add(n, Ordering::Relaxed);
        self.queue.ready.notify_one();
    }

    /// Queue one unit for the client (dropping the oldest `Message Data` if full).
    fn push(&self, unit: Unit) {
        let mut q = lock(&self.queue.state);
        if q.dead {
            if unit.data {
                self.counters.dropped.fetch_add(1, Ordering::Relaxed);
            }
            return;
        }
        while unit.data
            && q.data_units > 0
            && (q.data_units >= MAX_QUEUED_MESSAGES
                || q.data_bytes + unit.bytes.len() > self.data_cap)
        {
            let Some(i) = q.units.iter().position(|u| u.data) else {
                break;
            };
            let Some(old) = q.units.remove(i) else {
                break;
            };
            q.bytes -= old.bytes.len();
            q.data_bytes -= old.bytes.len();
            q.data_units -= 1;
            self.counters.dropped.fetch_add(1, Ordering::Relaxed);
        }
        q.bytes += unit.bytes.len();
        if unit.data {
            q.data_bytes += unit.bytes.len();
        }
        q.data_units += usize::from(unit.data);
        q.units.push_back(unit);
        let over = q.bytes > MAX_QUEUED_BYTES;
        drop(q);
        self.queue.ready.notify_one();
        if over {
            self.kill();
        }
    }

    fn close_queue(&self) {
        lock(&self.queue.state).closed = true;
        self.queue.ready.notify_one();
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// The running front.
pub struct Front {
    stop: Arc<AtomicBool>,
    /// Wakes the accept loop when `stop` is set.
    stop_wake: Arc<Notify>,
    /// Ends the front's runtime (after `finish` has cut off every connection).
    shutdown: Arc<Notify>,
    thread: Option<JoinHandle<()>>,
    conns: Arc<Mutex<Vec<Arc<Conn>>>>,
    /// Connection tasks still running.
    active: Arc<AtomicUsize>,
    /// Clients whose upgrade failed (bad request, refused by the SDK, over the limit, too
    /// slow).
    rejected: Arc<AtomicU64>,
    /// Of `rejected`: refused because `max_clients` clients were served.
    over_limit: Arc<AtomicU64>,
    max_clients: usize,
    /// Connections the SDK upgraded for the front (HTTP 101).
    upgraded: Arc<AtomicU64>,
}

/// The local addresses of the front's connections to the SDK server: the peers the SDK
/// server may serve (see `live.rs`, `SdkGate`); every other connection there is a process
/// that bypassed the front.
#[derive(Default)]
pub struct FrontPeers(Mutex<std::collections::HashSet<SocketAddr>>);

impl FrontPeers {
    /// `peer` is one of the front's connections to the SDK server.
    pub fn contains(&self, peer: &SocketAddr) -> bool {
        lock(&self.0).contains(peer)
    }
}

/// Keeps an upstream connection's local address in [`FrontPeers`] while it is open.
struct PeerEntry<'a>(&'a FrontPeers, SocketAddr);

impl Drop for PeerEntry<'_> {
    fn drop(&mut self) {
        lock(&(self.0).0).remove(&self.1);
    }
}

/// One unit of a counter (a served client, a connection in its handshake, a running
/// task), given back when dropped.
struct Slot(Arc<AtomicUsize>);

impl Slot {
    /// Take a unit if fewer than `max` are taken.
    fn take(count: &Arc<AtomicUsize>, max: usize) -> Option<Slot> {
        count
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < max).then_some(n + 1)
            })
            .ok()
            .map(|_| Slot(count.clone()))
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

impl Front {
    /// Listen on `listener` (already bound to the user's address) and relay every client to
    /// the SDK server at `upstream` (loopback).
    /// At most `max_clients` clients are served at once (counted from a complete upgrade
    /// request); more are answered HTTP 503 and closed, and counted. A connection has
    /// [`HANDSHAKE_TIMEOUT`] to complete its upgrade; at most [`MAX_PENDING_HANDSHAKES`] may
    /// be in their handshake at once.
    pub fn start(
        listener: std::net::TcpListener,
        upstream: SocketAddr,
        max_clients: usize,
        peers: Arc<FrontPeers>,
    ) -> std::io::Result<Front> {
        listener.set_nonblocking(true)?;
        let stop = Arc::new(AtomicBool::new(false));
        let (stop_wake, shutdown) = (Arc::new(Notify::new()), Arc::new(Notify::new()));
        let conns: Arc<Mutex<Vec<Arc<Conn>>>> = Arc::default();
        let active = Arc::new(AtomicUsize::new(0));
        let rejected = Arc::new(AtomicU64::new(0));
        let over_limit = Arc::new(AtomicU64::new(0));
        let upgraded = Arc::new(AtomicU64::new(0));
        let max_clients = max_clients.max(1);
        let cx = Arc::new(AcceptCtx {
            upstream,
            stop: stop.clone(),
            stop_wake: stop_wake.clone(),
            conns: conns.clone(),
            active: active.clone(),
            rejected: rejected.clone(),
            over_limit: over_limit.clone(),
            served: Arc::new(AtomicUsize::new(0)),
            pending: Arc::new(AtomicUsize::new(0)),
            max_clients,
            data_cap: data_queue_bytes(max_clients),
            upgraded: upgraded.clone(),
            peers,
        });
        // A fixed number of threads whatever the number of clients: one task per
        // connection on FRONT_WORKERS worker threads.
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(FRONT_WORKERS)
            .thread_name("ehactl-live-io")
            .thread_stack_size(FRONT_STACK)
            .enable_all()
            .build()?;
        let listener = {
            let _g = rt.enter();
            tokio::net::TcpListener::from_std(listener)?
        };
        let down = shutdown.clone();
        let thread = std::thread::Builder::new()
            .name("ehactl-live-front".into())
            .spawn(move || {
                rt.block_on(async move {
                    accept_loop(&listener, &cx).await;
                    // Connections keep running until `finish` has cut them off.
                    down.notified().await;
                });
            })?;
        Ok(Front {
            stop,
            stop_wake,
            shutdown,
            thread: Some(thread),
            conns,
            active,
            rejected,
            over_limit,
            max_clients,
            upgraded,
        })
    }

    /// Stop accepting; give the connections `grace` to deliver what they hold (the SDK
    /// server must have been stopped, which closes their SDK side), then cut off the rest.
    /// Returns every client that completed the upgrade, in connection order, the number of
    /// connections refused and, of those, the number refused over the client limit.
    pub fn finish(mut self, grace: Duration) -> (Vec<ClientStats>, u64, u64) {
        self.stop.store(true, Ordering::Release);
        self.stop_wake.notify_one();
        let t0 = Instant::now();
        while self.active.load(Ordering::Acquire) > 0 && t0.elapsed() < grace {
            std::thread::sleep(Duration::from_millis(5));
        }
        let conns = lock(&self.conns).clone();
        for c in &conns {
            c.kill();
        }
        // The writers see their sockets shut down at once; wait for their final counts.
        let t0 = Instant::now();
        while self.active.load(Ordering::Acquire) > 0 && t0.elapsed() < Duration::from_secs(2) {
            std::thread::sleep(Duration::from_millis(5));
        }
        self.shutdown.notify_one();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        // Written but never acknowledged by the client: not delivered. Every socket has been
        // shut down, so a non-empty send queue ends with the FIN (one sequence number).
        for c in &conns {
            let unacked = unacknowledged_bytes(&c.client).saturating_sub(1);
            let n = lock(&c.counters.written).unacknowledged(unacked);
            if n > 0 {
                c.counters.sent.fetch_sub(n, Ordering::Relaxed);
                c.counters.dropped.fetch_add(n, Ordering::Relaxed);
            }
        }
        let stats = conns
            .iter()
            .filter(|c| !lock(&c.counters.subprotocol).is_empty())
            .map(|c| ClientStats {
                peer: c.counters.peer,
                subprotocol: lock(&c.counters.subprotocol).clone(),
                messages_sent: c.counters.sent.load(Ordering::Relaxed),
                messages_dropped: c.counters.dropped.load(Ordering::Relaxed),
            })
            .collect();
        (
            stats,
            self.rejected.load(Ordering::Relaxed),
            self.over_limit.load(Ordering::Relaxed),
        )
    }

    /// Most clients served at once.
    pub fn max_clients(&self) -> usize {
        self.max_clients
    }

    /// Connections the SDK server upgraded for the front so far: every SDK client beyond
    /// these connected to its port directly (see `LiveStats::direct_sdk_clients`).
    pub fn upgraded(&self) -> u64 {
        self.upgraded.load(Ordering::Acquire)
    }
}

struct AcceptCtx {
    upstream: SocketAddr,
    stop: Arc<AtomicBool>,
    stop_wake: Arc<Notify>,
    conns: Arc<Mutex<Vec<Arc<Conn>>>>,
    active: Arc<AtomicUsize>,
    rejected: Arc<AtomicU64>,
    over_limit: Arc<AtomicU64>,
    /// Clients served now: from a complete upgrade request until the connection ends.
    served: Arc<AtomicUsize>,
    /// Connections in their handshake now.
    pending: Arc<AtomicUsize>,
    max_clients: usize,
    /// Bytes of `Message Data` queued per client ([`data_queue_bytes`]).
    data_cap: usize,
    /// Connections the SDK upgraded for the front (HTTP 101).
    upgraded: Arc<AtomicU64>,
    peers: Arc<FrontPeers>,
}

async fn accept_loop(listener: &tokio::net::TcpListener, cx: &Arc<AcceptCtx>) {
    let mut reported = false;
    while !cx.stop.load(Ordering::Acquire) {
        let accepted = tokio::select! {
            a = listener.accept() => a,
            () = cx.stop_wake.notified() => continue,
        };
        let (client, peer) = match accepted {
            Ok(c) => c,
            Err(e) => {
                // Out of descriptors and the like: say it once, keep serving.
                if !reported {
                    eprintln!("ehactl: --live: accepting a client failed: {e}");
                    reported = true;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let Some(pending) = Slot::take(&cx.pending, MAX_PENDING_HANDSHAKES) else {
            // Refused before anything is allocated for it: a short answer, then closed.
            cx.rejected.fetch_add(1, Ordering::Relaxed);
            let why = format!(
                "{MAX_PENDING_HANDSHAKES} live-view connections are in their handshake; retry later"
            );
            let _ = answer_503(client, &why).await;
            continue;
        };
        let _ = client.set_nodelay(true);
        let Ok((client, dup)) = with_dup(client) else {
            continue;
        };
        let conn = new_conn(peer, dup, cx);
        lock(&cx.conns).push(conn.clone());
        let task = Slot(cx.active.clone());
        cx.active.fetch_add(1, Ordering::AcqRel);
        let cx = cx.clone();
        tokio::spawn(async move {
            let _task = task;
            // On failure the client got its HTTP answer (or went away): counted, not logged
            // (a port scanner must not flood stderr), and forgotten unless it had upgraded.
            if serve(client, &conn, &cx, pending).await.is_err() {
                cx.rejected.fetch_add(1, Ordering::Relaxed);
                conn.kill();
                if lock(&conn.counters.subprotocol).is_empty() {
                    lock(&cx.conns).retain(|c| !Arc::ptr_eq(c, &conn));
                }
            }
        });
    }
}

/// The bookkeeping of the connection from `peer` (`dup`: a duplicate of its socket).
fn new_conn(peer: SocketAddr, dup: std::net::TcpStream, cx: &AcceptCtx) -> Arc<Conn> {
    let send_buffer = send_buffer_bytes(cx.max_clients);
    set_send_buffer(&dup, send_buffer);
    Arc::new(Conn {
        counters: Arc::new(Counters {
            peer,
            subprotocol: Mutex::new(String::new()),
            sent: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            written: Mutex::new(Written {
                window: written_window(send_buffer),
                ..Written::default()
            }),
        }),
        client: dup,
        upstream: Mutex::new(None),
        queue: Queue {
            state: Mutex::new(QueueState::default()),
            ready: Notify::new(),
        },
        data_cap: cx.data_cap,
    })
}

/// The tokio stream `s` and a duplicate descriptor of its socket (for `shutdown`, socket
/// options and `SIOCOUTQ` from any thread).
fn with_dup(s: TcpStream) -> std::io::Result<(TcpStream, std::net::TcpStream)> {
    let s = s.into_std()?;
    let dup = s.try_clone()?;
    Ok((TcpStream::from_std(s)?, dup))
}

/// Answer HTTP 503 with `why` and close (a write that does not fit the socket's buffer at
/// once is not waited for).
async fn answer_503(mut client: TcpStream, why: &str) -> std::io::Result<()> {
    let body = format!("{why}\n");
    let msg = format!(
        "HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain\r\nContent-Length: {}\r\nRetry-After: 5\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    let _ =
        tokio::time::timeout(Duration::from_millis(100), client.write_all(msg.as_bytes())).await;
    client.shutdown().await
}

fn set_send_buffer(s: &std::net::TcpStream, bytes: usize) {
    let v = libc::c_int::try_from(bytes).unwrap_or(libc::c_int::MAX);
    // SAFETY: `s` owns an open socket; SO_SNDBUF takes one c_int. A failure only leaves the
    // kernel's default (auto-tuned) buffer.
    unsafe {
        libc::setsockopt(
            std::os::fd::AsRawFd::as_raw_fd(s),
            libc::SOL_SOCKET,
            libc::SO_SNDBUF,
            (&v as *const libc::c_int).cast(),
            std::mem::size_of::<libc::c_int>() as libc::socklen_t,
        );
    }
}

fn set_linger_zero(s: &std::net::TcpStream) {
    let v = libc::linger {
        l_onoff: 1,
        l_linger: 0,
    };
    // SAFETY: `s` owns an open socket; SO_LINGER takes one `struct linger`.
    unsafe {
        libc::setsockopt(
            std::os::fd::AsRawFd::as_raw_fd(s),
            libc::SOL_SOCKET,
            libc::SO_LINGER,
            (&v as *const libc::linger).cast(),
            std::mem::size_of::<libc::linger>() as libc::socklen_t,
        );
    }
}

/// Read an HTTP head (up to the blank line); returns (head, bytes read after it).
async fn read_head(s: &mut TcpStream) -> std::io::Result<(Vec<u8>, Vec<u8>)> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 2048];
    loop {
        if let Some(i) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            let rest = buf.split_off(i + 4);
            return Ok((buf, rest));
        }
        if buf.len() > MAX_HEAD {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("HTTP head longer than {MAX_HEAD} bytes"),
            ));
        }
        let n = s.read(&mut chunk).await?;
        if n == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        buf.extend_from_slice(&chunk[..n]);
    }
}

async fn bad_request(client: &mut TcpStream, why: &str) -> std::io::Error {
    let body = format!("{why}\n");
    let msg = format!(
        "HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    let _ = client.write_all(msg.as_bytes()).await;
    std::io::Error::new(std::io::ErrorKind::InvalidData, why.to_string())
}

/// The request to send to the SDK and the subprotocol name to answer the client with
/// instead of the SDK's (`None`: pass the SDK's answer through).
fn rewrite_request(head: &[u8]) -> Result<(Vec<u8>, Option<&'static str>), String> {
    let mut headers = [httparse::EMPTY_HEADER; 64];
    let mut req = httparse::Request::new(&mut headers);
    match req.parse(head) {
        Ok(httparse::Status::Complete(_)) => {}
        Ok(httparse::Status::Partial) => return Err("incomplete HTTP request".into()),
        Err(e) => return Err(format!("malformed HTTP request: {e}")),
    }
    let offered: Vec<String> = req
        .headers
        .iter()
        .filter(|h| h.name.eq_ignore_ascii_case("sec-websocket-protocol"))
        .flat_map(|h| {
            String::from_utf8_lossy(h.value)
                .split(',')
                .map(|p| p.trim().to_string())
                .collect::<Vec<_>>()
        })
        .collect();
    let has = |p: &str| offered.iter().any(|o| o == p);
    let rename = !has(SDK_V1) && !has(SDK_V1_1) && has(WS_PROTOCOL_V1);
    let mut out = Vec::with_capacity(head.len());
    let _ = write!(
        out,
        "{} {} HTTP/1.1\r\n",
        req.method.unwrap_or("GET"),
        req.path.unwrap_or("/")
    );
    for h in req.headers.iter() {
        let name = h.name;
        if name.eq_ignore_ascii_case("sec-websocket-protocol") && rename {
            continue;
        }
        // No extension (permessage-deflate): the accounting reads plain frames.
        if name.eq_ignore_ascii_case("sec-websocket-extensions") {
            continue;
        }
        out.extend_from_slice(name.as_bytes());
        out.extend_from_slice(b": ");
        out.extend_from_slice(h.value);
        out.extend_from_slice(b"\r\n");
    }
    if rename {
        let _ = write!(out, "Sec-WebSocket-Protocol: {SDK_V1}\r\n");
    }
    out.extend_from_slice(b"\r\n");
    Ok((out, rename.then_some(WS_PROTOCOL_V1)))
}

/// The SDK's response for the client: status, the response head with the subprotocol
/// renamed if asked, and the subprotocol the client ends up with.
fn rewrite_response(head: &[u8], rename: Option<&str>) -> Result<(u16, Vec<u8>, String), String> {
    let mut headers = [httparse::EMPTY_HEADER; 64];
    let mut res = httparse::Response::new(&mut headers);
    match res.parse(head) {
        Ok(httparse::Status::Complete(_)) => {}
        Ok(httparse::Status::Partial) => return Err("incomplete HTTP response".into()),
        Err(e) => return Err(format!("malformed HTTP response: {e}")),
    }
    let code = res.code.unwrap_or(0);
    let mut out = Vec::with_capacity(head.len());
    let _ = write!(out, "HTTP/1.1 {code} {}\r\n", res.reason.unwrap_or(""));
    let mut proto = String::new();
    for h in res.headers.iter() {
        let mut value = h.value.to_vec();
        if h.name.eq_ignore_ascii_case("sec-websocket-protocol") {
            if let Some(r) = rename {
                value = r.as_bytes().to_vec();
            }
            proto = String::from_utf8_lossy(&value).into_owned();
        }
        out.extend_from_slice(h.name.as_bytes());
        out.extend_from_slice(b": ");
        out.extend_from_slice(&value);
        out.extend_from_slice(b"\r\n");
    }
    out.extend_from_slice(b"\r\n");
    Ok((code, out, proto))
}

/// A connection upgraded by the SDK: the client's and the SDK's streams, and the client's
/// served slot.
struct Upgraded {
    client: TcpStream,
    up: TcpStream,
    rest: Vec<u8>,
    served: Slot,
}

/// The handshake of one connection: the client's upgrade request (within the deadline the
/// caller sets), a served slot, the SDK's answer passed on with the subprotocol renamed.
async fn handshake(
    mut client: TcpStream,
    conn: &Arc<Conn>,
    cx: &AcceptCtx,
) -> std::io::Result<Upgraded> {
    let (head, early) = match read_head(&mut client).await {
        Ok(h) => h,
        Err(e) => {
            return Err(bad_request(&mut client, &format!("bad HTTP upgrade request: {e}")).await)
        }
    };
    let (request, rename) = match rewrite_request(&head) {
        Ok(r) => r,
        Err(e) => return Err(bad_request(&mut client, &e).await),
    };
    // Only a client with a complete upgrade request counts against the limit.
    let Some(served) = Slot::take(&cx.served, cx.max_clients) else {
        cx.over_limit.fetch_add(1, Ordering::Relaxed);
        let why = format!(
            "too many live-view clients: {} connected (limit --live-max-clients {}); retry later",
            cx.max_clients, cx.max_clients
        );
        answer_503(client, &why).await?;
        return Err(std::io::Error::other("over the client limit"));
    };
    let up = TcpStream::connect(cx.upstream).await?;
    let _ = up.set_nodelay(true);
    let local = up.local_addr()?;
    let (mut up, up_dup) = with_dup(up)?;
    *lock(&conn.upstream) = Some(up_dup);
    // Known to the SDK's gate before the request is written, so before the SDK can
    // register the connection; forgotten when the connection ends (see `serve`).
    lock(&cx.peers.0).insert(local);
    up.write_all(&request).await?;
    up.write_all(&early).await?;
    let (rhead, rest) = read_head(&mut up).await?;
    let (code, response, proto) = match rewrite_response(&rhead, rename) {
        Ok(r) => r,
        Err(e) => return Err(bad_request(&mut client, &e).await),
    };
    client.write_all(&response).await?;
    if code != 101 {
        // The SDK's refusal (e.g. 400: no subprotocol it knows): pass its body on.
        client.write_all(&rest).await?;
        let mut body = Vec::new();
        let _ = (&mut up).take(MAX_HEAD as u64).read_to_end(&mut body).await;
        let _ = client.write_all(&body).await;
        return Err(std::io::Error::other(format!(
            "upgrade refused: HTTP {code}"
        )));
    }
    cx.upgraded.fetch_add(1, Ordering::AcqRel);
    *lock(&conn.counters.subprotocol) = proto;
    Ok(Upgraded {
        client,
        up,
        rest,
        served,
    })
}

/// One connection: the handshake within [`HANDSHAKE_TIMEOUT`], then relay until either side
/// ends.
async fn serve(
    client: TcpStream,
    conn: &Arc<Conn>,
    cx: &AcceptCtx,
    pending: Slot,
) -> std::io::Result<()> {
    let shook = tokio::time::timeout(HANDSHAKE_TIMEOUT, handshake(client, conn, cx)).await;
    drop(pending);
    let up_local = lock(&conn.upstream)
        .as_ref()
        .and_then(|u| u.local_addr().ok());
    let _entry = up_local.map(|a| PeerEntry(&cx.peers, a));
    let Upgraded {
        mut client,
        mut up,
        rest,
        served,
    } = shook.map_err(|_| {
        // Said in one short non-blocking write on the socket's duplicate (the stream went
        // with the handshake); the connection is cut off after.
        let body = format!(
            "upgrade not completed within {} s\n",
            HANDSHAKE_TIMEOUT.as_secs()
        );
        let _ = (&conn.client).write_all(
            format!(
                "HTTP/1.1 408 Request Timeout\r\nContent-Type: text/plain\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
                body.len()
            )
            .as_bytes(),
        );
        std::io::Error::new(std::io::ErrorKind::TimedOut, body.trim_end().to_string())
    })??;
    let _served = served;
    relay(&mut client, &mut up, &rest, conn).await
}

/// Relay an upgraded connection until either side ends: the client's bytes to the SDK, the
/// SDK's frames into the client's queue, the queue to the client.
async fn relay(
    client: &mut TcpStream,
    up: &mut TcpStream,
    rest: &[u8],
    conn: &Arc<Conn>,
) -> std::io::Result<()> {
    let (mut client_rd, mut client_wr) = client.split();
    let (mut up_rd, mut up_wr) = up.split();
    // Client → SDK: bytes copied unchanged; when the client leaves, the SDK side is closed
    // too (the SDK then drops the client).
    let upward = async {
        let mut buf = [0u8; 4096];
        loop {
            match client_rd.read(&mut buf).await {
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    if up_wr.write_all(&buf[..n]).await.is_err() {
                        break;
                    }
                }
            }
        }
        conn.kill();
    };
    // SDK → queue.
    let from_sdk = async {
        let mut frames = FrameSplitter::default();
        frames.push(rest);
        let mut buf = vec![0u8; 16 << 10];
        loop {
            loop {
                match frames.next_unit() {
                    Ok(Some(u)) => conn.push(u),
                    Ok(None) => break,
                    Err(e) => {
                        conn.kill();
                        return Err(std::io::Error::new(std::io::ErrorKind::InvalidData, e));
                    }
                }
            }
            match up_rd.read(&mut buf).await {
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Ok(0) | Err(_) => break,
                Ok(n) => frames.push(&buf[..n]),
            }
        }
        conn.close_queue();
        Ok(())
    };
    // Queue → client.
    let downward = write_loop(&mut client_wr, conn);
    let ((), sdk, ()) = tokio::join!(upward, from_sdk, downward);
    sdk
}

/// What the writer does next.
enum Next {
    Unit(Unit),
    Wait,
    Closed,
}

async fn write_loop(to: &mut (impl AsyncWrite + Unpin), conn: &Conn) {
    loop {
        let next = {
            let mut q = lock(&conn.queue.state);
            if q.dead {
                return;
            }
            match q.units.pop_front() {
                Some(u) => {
                    q.bytes -= u.bytes.len();
                    if u.data {
                        q.data_bytes -= u.bytes.len();
                    }
                    q.data_units -= usize::from(u.data);
                    Next::Unit(u)
                }
                None if q.closed => Next::Closed,
                None => Next::Wait,
            }
        };
        let unit = match next {
            Next::Unit(u) => u,
            // A notification sent since the check is kept by `Notify` (a permit).
            Next::Wait => {
                conn.queue.ready.notified().await;
                continue;
            }
            Next::Closed => {
                // Everything the SDK sent (its close frame last) is delivered.
                let _ = to.shutdown().await;
                return;
            }
        };
        // Not `write_all`: the bytes of a message cut off half-way count too (to tell later
        // which complete messages the client acknowledged).
        let mut b = &unit.bytes[..];
        while !b.is_empty() {
            match to.write(b).await {
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Ok(0) | Err(_) => {
                    if unit.data {
                        conn.counters.dropped.fetch_add(1, Ordering::Relaxed);
                    }
                    conn.kill();
                    return;
                }
                Ok(n) => {
                    lock(&conn.counters.written).bytes(n);
                    b = &b[n..];
                }
            }
        }
        lock(&conn.counters.written).end(unit.data);
        if unit.data {
            conn.counters.sent.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Splits the server-to-client byte stream into whole WebSocket messages (RFC 6455 §5.2):
/// a data message with its continuation frames, or one control frame.
#[derive(Default)]
struct FrameSplitter {
    buf: Vec<u8>,
    start: usize,
    /// Frames of a fragmented message so far, and whether it is `Message Data`.
    partial: Option<(Vec<u8>, bool)>,
}

impl FrameSplitter {
    /// Append bytes read from the SDK. What was split off already is dropped first (only a
    /// partial frame is kept, moved to the front), so the buffer stays at one read plus one
    /// message: it is resident memory of every client (all of it under `--realtime`'s
    /// `mlockall`).
    fn push(&mut self, b: &[u8]) {
        if self.start > 0 {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        self.buf.extend_from_slice(b);
    }

    fn next_unit(&mut self) -> Result<Option<Unit>, String> {
        loop {
            let b = &self.buf[self.start..];
            if b.len() < 2 {
                return Ok(None);
            }
            let (fin, rsv, opcode) = (b[0] & 0x80 != 0, b[0] & 0x70, b[0] & 0x0F);
            let masked = b[1] & 0x80 != 0;
            let (len, mut hdr) = match b[1] & 0x7F {
                126 if b.len() >= 4 => (u64::from(u16::from_be_bytes([b[2], b[3]])), 4),
                127 if b.len() >= 10 => {
                    let mut l = [0u8; 8];
                    l.copy_from_slice(&b[2..10]);
                    (u64::from_be_bytes(l), 10)
                }
                126 | 127 => return Ok(None),
                n => (u64::from(n), 2),
            };
            if len > MAX_FRAME {
                return Err(format!(
                    "WebSocket frame of {len} bytes from the SDK (at most {MAX_FRAME})"
                ));
            }
            if masked {
                hdr += 4;
            }
            let total = hdr + len as usize;
            if b.len() < total {
                return Ok(None);
            }
            let frame = &b[..total];
            // Server frames are not masked (RFC 6455 §5.1); a masked one is never dropped.
            let first = (!masked && len > 0).then(|| frame[hdr]);
            let is_data = |op: u8| op == 2 && rsv == 0 && first == Some(0x01);
            self.start += total;
            match opcode {
                // Control frames (close, ping, pong): alone, may sit inside a fragmented
                // message.
                8..=15 => {
                    return Ok(Some(Unit {
                        bytes: frame.to_vec(),
                        data: false,
                    }))
                }
                0 => {
                    let Some((mut acc, data)) = self.partial.take() else {
                        return Err("WebSocket continuation frame without a message".into());
                    };
                    acc.extend_from_slice(frame);
                    if fin {
                        return Ok(Some(Unit { bytes: acc, data }));
                    }
                    self.partial = Some((acc, data));
                }
                _ if fin => {
                    return Ok(Some(Unit {
                        bytes: frame.to_vec(),
                        data: is_data(opcode),
                    }))
                }
                _ => self.partial = Some((frame.to_vec(), is_data(opcode))),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(fin: bool, opcode: u8, payload: &[u8]) -> Vec<u8> {
        let mut f = vec![(u8::from(fin) << 7) | opcode];
        match payload.len() {
            n if n < 126 => f.push(n as u8),
            n if n < 65536 => {
                f.push(126);
                f.extend_from_slice(&(n as u16).to_be_bytes());
            }
            n => {
                f.push(127);
                f.extend_from_slice(&(n as u64).to_be_bytes());
            }
        }
        f.extend_from_slice(payload);
        f
    }

    #[test]
    fn splits_messages_and_classifies_message_data() {
        let data = [1u8, 0, 0, 0, 0, 9, 9, 9];
        let big = vec![1u8; 70_000];
        let mut s = FrameSplitter::default();
        let mut stream = Vec::new();
        stream.extend(frame(true, 1, br#"{"op":"advertise"}"#));
        stream.extend(frame(true, 2, &data));
        stream.extend(frame(true, 2, &[2, 0, 0]));
        stream.extend(frame(false, 2, &data[..3]));
        stream.extend(frame(true, 9, b"ping"));
        stream.extend(frame(true, 0, &data[3..]));
        stream.extend(frame(true, 2, &big));
        // byte by byte: nothing is emitted before a message is complete
        let mut units = Vec::new();
        for b in &stream {
            s.push(std::slice::from_ref(b));
            while let Some(u) = s.next_unit().unwrap() {
                units.push(u);
            }
        }
        let kinds: Vec<bool> = units.iter().map(|u| u.data).collect();
        assert_eq!(kinds, [false, true, false, false, true, true]);
        assert_eq!(
            units.iter().map(|u| u.bytes.len()).sum::<usize>(),
            stream.len()
        );
        assert!(FrameSplitter::default().next_unit().unwrap().is_none());
        let mut bad = FrameSplitter::default();
        bad.push(&frame(true, 0, b"x"));
        assert!(bad.next_unit().unwrap_err().contains("continuation"));
    }

    #[test]
    fn unacknowledged_messages() {
        let mut w = Written::default();
        w.bytes(100); // advertise
        w.end(false);
        for _ in 0..10 {
            w.bytes(20);
            w.bytes(30);
            w.end(true);
        }
        assert_eq!(w.unacknowledged(0), 0);
        assert_eq!(w.unacknowledged(50), 1);
        assert_eq!(w.unacknowledged(51), 2);
        assert_eq!(w.unacknowledged(10_000), 10);
    }

    #[test]
    fn renames_the_published_subprotocol_only() {
        let req = b"GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\nSec-WebSocket-Extensions: permessage-deflate\r\n\r\n";
        let (out, rename) = rewrite_request(req).unwrap();
        let out = String::from_utf8(out).unwrap();
        assert_eq!(rename, Some(WS_PROTOCOL_V1));
        assert!(
            out.contains("Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n"),
            "{out}"
        );
        assert!(
            !out.contains("websocket.v1") && !out.contains("deflate"),
            "{out}"
        );
        let sdk = b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol: foxglove.websocket.v1, foxglove.sdk.v1\r\n\r\n";
        assert_eq!(rewrite_request(sdk).unwrap().1, None);
        let res =
            b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n\r\n";
        let (code, out, proto) = rewrite_response(res, Some(WS_PROTOCOL_V1)).unwrap();
        assert_eq!((code, proto.as_str()), (101, WS_PROTOCOL_V1));
        assert!(String::from_utf8(out)
            .unwrap()
            .contains("foxglove.websocket.v1"));
        assert!(rewrite_request(b"\x00garbage\r\n\r\n").is_err());
    }
}
