//! `ehactl run --live [ADDR]`: the running loop served to Foxglove over the Foxglove WebSocket
//! protocol by Foxglove's own SDK (the `foxglove` crate's `WebSocketServer`), with the
//! channels, schemas and message bytes of the MCAP log. Clients connect to a front
//! ([`crate::live_front`]) on ADDR that accepts the published subprotocol name
//! `foxglove.websocket.v1` as well as the SDK's `foxglove.sdk.v1`/`v1.1`, hands each connection
//! to the SDK server on an internal loopback port and counts per client what it delivers and
//! drops. A connection to that internal port that did not come through the front is cut off
//! as the SDK registers it ([`SdkGate`]).
//!
//! Data path: the cycle pushes records to the MCAP logger's lock-free queue as always; the
//! logger's writer thread offers each message it writes to a bounded [`LogTap`] (dropped and
//! counted when full); this module's thread takes them from the tap and publishes them. So
//! neither the cycle nor the log ever waits for a viewer. The front then queues per client and
//! drops (and counts) the oldest messages for a slow client.

use crate::live_front::{ClientStats, Front, FrontPeers};
use ehactl_log::logger::{LogTap, TapMessage};
use ehactl_log::record::{control_schema, plant_schema, timing_schema};
use ehactl_log::schemas;
use foxglove::{Context, PartialMetadata, RawChannel, Schema, WebSocketServer};
use std::sync::atomic::{AtomicBool, AtomicU16, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Default address, the Foxglove app's default connection (`ws://localhost:8765`).
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";

/// Tap capacity (messages): about 0.4 s of a 5 kHz run with /control, /plant and /timing.
const TAP_CAPACITY: usize = 8192;

/// What the live view did.
#[derive(Debug, Clone)]
pub struct LiveStats {
    /// Messages handed to the server (all channels).
    pub published: u64,
    /// Messages dropped before the server because the tap was full (no client got them).
    pub dropped: u64,
    /// Clients connected when the run ended.
    pub clients: usize,
    /// Every client that connected (completed the WebSocket upgrade): what it got and missed.
    pub per_client: Vec<ClientStats>,
    /// Connections refused (bad upgrade request, no subprotocol the server speaks, over the
    /// client limit) or failed.
    pub refused: u64,
    /// Of `refused`: connections refused because `max_clients` were already served.
    pub over_limit: u64,
    /// Most clients served at once (`--live-max-clients`).
    pub max_clients: usize,
    /// Connections that reached the SDK server's internal loopback port directly, not
    /// through the front (SDK connections minus the front's), each cut off by [`SdkGate`]
    /// once the SDK registered it: before any channel is advertised to it.
    pub direct_sdk_clients: u64,
}

/// Lets the SDK server serve the front's connections only. The `foxglove` crate (0.30)
/// binds its port itself (any local process can connect) and offers no hook to refuse a
/// connection: `ServerListener::on_client_connect` takes no client and returns nothing,
/// `Client` and `SinkChannelFilter` carry no address. But the SDK calls it synchronously
/// when it registers a client, after the WebSocket handshake and its `serverInfo`, before
/// it adds the client as a sink (which advertises the channels). Here, then, every TCP
/// connection of this process accepted on the SDK's port whose peer is not one of the
/// front's upstream sockets ([`FrontPeers`], recorded before the front writes its request)
/// is shut down (`shutdown(2)` on the SDK's own descriptor, found through `/proc/self/fd`):
/// the SDK's sends to it fail and it drops the client.
struct SdkGate {
    connects: Arc<AtomicU64>,
    /// The SDK server's port (0 until it is known: nothing is cut off before).
    port: Arc<AtomicU16>,
    front: Arc<FrontPeers>,
}

impl foxglove::websocket::ServerListener for SdkGate {
    fn on_client_connect(&self) {
        self.connects.fetch_add(1, Ordering::AcqRel);
        let port = self.port.load(Ordering::Acquire);
        if port != 0 {
            cut_off_direct(port, &self.front);
        }
    }
}

/// The IPv4 address `f` (`getsockname` / `getpeername`) gives for descriptor `fd`.
fn sock_addr(
    fd: libc::c_int,
    f: unsafe extern "C" fn(libc::c_int, *mut libc::sockaddr, *mut libc::socklen_t) -> libc::c_int,
) -> Option<std::net::SocketAddr> {
    // SAFETY: `sa` is a zeroed sockaddr_in and `len` its size; the call writes at most
    // `len` bytes into it. A descriptor that is no socket (or closed) only returns -1.
    let mut sa: libc::sockaddr_in = unsafe { std::mem::zeroed() };
    let mut len = std::mem::size_of::<libc::sockaddr_in>() as libc::socklen_t;
    let r = unsafe { f(fd, (&mut sa as *mut libc::sockaddr_in).cast(), &mut len) };
    if r != 0 || sa.sin_family != libc::AF_INET as libc::sa_family_t {
        return None;
    }
    let ip = std::net::Ipv4Addr::from(u32::from_be(sa.sin_addr.s_addr));
    Some(std::net::SocketAddr::from((ip, u16::from_be(sa.sin_port))))
}

/// Shut down every connection of this process accepted on 127.0.0.1:`port` whose peer is
/// not one of the front's; returns how many.
fn cut_off_direct(port: u16, front: &FrontPeers) -> u64 {
    let Ok(dir) = std::fs::read_dir("/proc/self/fd") else {
        return 0;
    };
    let mut n = 0;
    for e in dir.flatten() {
        let Some(fd) = e.file_name().to_str().and_then(|s| s.parse().ok()) else {
            continue;
        };
        let Some(local) = sock_addr(fd, libc::getsockname) else {
            continue;
        };
        if local.port() != port || !local.ip().is_loopback() {
            continue;
        }
        // the listening socket has no peer
        let Some(peer) = sock_addr(fd, libc::getpeername) else {
            continue;
        };
        if !front.contains(&peer) {
            // SAFETY: shutdown(2) on a descriptor number; it closes nothing, and at worst
            // (the number reused meanwhile by another accepted SDK connection) it cuts off
            // that connection, which this check would cut off too.
            unsafe { libc::shutdown(fd, libc::SHUT_RDWR) };
            n += 1;
        }
    }
    n
}

impl LiveStats {
    /// Messages subscribed clients missed, summed over clients.
    pub fn client_dropped(&self) -> u64 {
        self.per_client.iter().map(|c| c.messages_dropped).sum()
    }
}

/// A running live view.
pub struct LiveView {
    // Channels and the server belong to this context; it lives as long as the view.
    _ctx: Arc<Context>,
    tap: Arc<LogTap>,
    server: Option<foxglove::WebSocketServerHandle>,
    /// Clients the SDK server registered (through the front or not).
    sdk_connects: Arc<AtomicU64>,
    front: Option<Front>,
    thread: Option<JoinHandle<()>>,
    published: Arc<AtomicU64>,
    abort: Arc<AtomicBool>,
    /// `ws://host:port` the server listens on.
    pub url: String,
}

struct Channels {
    control: Arc<RawChannel>,
    plant: Arc<RawChannel>,
    timing: Arc<RawChannel>,
    config: Arc<RawChannel>,
    events: Arc<RawChannel>,
    log: Arc<RawChannel>,
    summary: Arc<RawChannel>,
}

impl Channels {
    /// The live view's channels in `ctx`: the cycle records (CDR) and the JSON channels of
    /// the MCAP log, with their schemas.
    fn declare(ctx: &Arc<Context>) -> Result<Channels, String> {
        Ok(Channels {
            control: channel(
                ctx,
                "/control",
                "cdr",
                Schema::new(
                    "ehactl_msgs/msg/ControlCycle",
                    "ros2msg",
                    control_schema().into_bytes(),
                ),
            )?,
            plant: channel(
                ctx,
                "/plant",
                "cdr",
                Schema::new(
                    "ehactl_msgs/msg/PlantState",
                    "ros2msg",
                    plant_schema().into_bytes(),
                ),
            )?,
            timing: channel(
                ctx,
                "/timing",
                "cdr",
                Schema::new(
                    "ehactl_msgs/msg/CycleTiming",
                    "ros2msg",
                    timing_schema().into_bytes(),
                ),
            )?,
            config: channel(
                ctx,
                "/config",
                "json",
                json_schema(
                    schemas::CONFIG_SCHEMA_NAME,
                    schemas::config_schema(ehactl_runtime::session::config_json_schema()),
                ),
            )?,
            events: channel(
                ctx,
                "/events",
                "json",
                json_schema(schemas::EVENT_SCHEMA_NAME, schemas::event_schema()),
            )?,
            log: channel(
                ctx,
                "/log",
                "json",
                json_schema(
                    schemas::FOXGLOVE_LOG_SCHEMA_NAME,
                    schemas::foxglove_log_schema(),
                ),
            )?,
            summary: channel(
                ctx,
                "/summary",
                "json",
                json_schema(schemas::SUMMARY_SCHEMA_NAME, schemas::summary_schema()),
            )?,
        })
    }
}

fn channel(
    ctx: &Arc<Context>,
    topic: &str,
    encoding: &str,
    schema: Schema,
) -> Result<Arc<RawChannel>, String> {
    ctx.channel_builder(topic)
        .message_encoding(encoding)
        .schema(schema)
        .build_raw()
        .map_err(|e| format!("--live: channel {topic}: {e}"))
}

fn json_schema(name: &str, schema: serde_json::Value) -> Schema {
    Schema::new(name, "jsonschema", schema.to_string().into_bytes())
}

/// A warning when `addr` (bound) is not a loopback address: `what` is then reachable from the
/// network, without authentication or encryption.
pub fn exposure_warning(flag: &str, addr: std::net::SocketAddr, what: &str) -> Option<String> {
    (!addr.ip().is_loopback()).then(|| {
        format!(
            "ehactl: warning: {flag} {addr} is not a loopback address: {what} is reachable from the network by anyone who can reach this machine (no authentication, no encryption); bind 127.0.0.1 and use an SSH tunnel to reach it from elsewhere"
        )
    })
}

/// Parse `HOST:PORT` (port 0 = any free port).
pub fn parse_addr(addr: &str) -> Result<(String, u16), String> {
    let (host, port) = addr.rsplit_once(':').ok_or_else(|| {
        format!("--live {addr}: expected HOST:PORT, e.g. {DEFAULT_ADDR} (port 0 = any free port)")
    })?;
    let port: u16 = port
        .parse()
        .map_err(|_| format!("--live {addr}: port {port:?} is not an integer in 0..=65535"))?;
    let host = host.trim_start_matches('[').trim_end_matches(']');
    if host.is_empty() {
        return Err(format!("--live {addr}: empty host; e.g. {DEFAULT_ADDR}"));
    }
    Ok((host.to_string(), port))
}

impl LiveView {
    /// Start the server on `addr` (`HOST:PORT`) and the publishing thread.
    pub fn start(addr: &str, max_clients: usize) -> Result<LiveView, String> {
        let (host, port) = parse_addr(addr)?;
        let ctx = Context::new();
        let ch = Channels::declare(&ctx)?;
        // The user's address is the front's; the SDK server listens on loopback only.
        let listener = std::net::TcpListener::bind((host.as_str(), port))
            .map_err(|e| format!("--live {addr}: cannot listen ({e}); expected a free HOST:PORT such as {DEFAULT_ADDR} (port 0 = any free port)"))?;
        let bound = listener
            .local_addr()
            .map_err(|e| format!("--live {addr}: {e}"))?;
        if let Some(w) = exposure_warning(
            "--live",
            bound,
            "the rig's live data (every logged channel, the config included)",
        ) {
            eprintln!("{w}");
        }
        let sdk_connects = Arc::new(AtomicU64::new(0));
        let sdk_port = Arc::new(AtomicU16::new(0));
        let front_peers = Arc::new(FrontPeers::default());
        let server = WebSocketServer::new()
            .name(concat!("ehactl ", env!("CARGO_PKG_VERSION")))
            .context(&ctx)
            .listener(Arc::new(SdkGate {
                connects: sdk_connects.clone(),
                port: sdk_port.clone(),
                front: front_peers.clone(),
            }))
            .message_backlog_size(crate::live_front::sdk_backlog(max_clients))
            .bind("127.0.0.1", 0)
            .start_blocking()
            .map_err(|e| {
                format!("--live {addr}: cannot start the Foxglove WebSocket server: {e}")
            })?;
        sdk_port.store(server.port(), Ordering::Release);
        let front = Front::start(
            listener,
            std::net::SocketAddr::from(([127, 0, 0, 1], server.port())),
            max_clients,
            front_peers,
        )
        .map_err(|e| format!("--live {addr}: cannot start the live view's listener: {e}"))?;
        let url = if host.contains(':') {
            format!("ws://[{}]:{}", host, bound.port())
        } else {
            format!("ws://{}:{}", host, bound.port())
        };
        let tap = Arc::new(LogTap::new(TAP_CAPACITY));
        let published = Arc::new(AtomicU64::new(0));
        let abort = Arc::new(AtomicBool::new(false));
        let thread = {
            let (tap, published, abort) = (tap.clone(), published.clone(), abort.clone());
            std::thread::Builder::new()
                .name("ehactl-live".into())
                .spawn(move || publish_loop(&ch, &tap, &published, &abort))
                .map_err(|e| format!("--live: cannot start the publishing thread: {e}"))?
        };
        Ok(LiveView {
            _ctx: ctx,
            tap,
            server: Some(server),
            sdk_connects,
            front: Some(front),
            thread: Some(thread),
            published,
            abort,
            url,
        })
    }

    /// The tap to attach to the run's logger.
    pub fn tap(&self) -> Arc<LogTap> {
        self.tap.clone()
    }

    /// Publish what is left (up to `drain` if the log never closed the tap), give connected
    /// clients `linger` to receive the last messages, stop the server.
    pub fn finish(mut self, drain: Duration, linger: Duration) -> LiveStats {
        let t0 = Instant::now();
        while !self.tap.is_closed() && t0.elapsed() < drain {
            std::thread::sleep(Duration::from_millis(5));
        }
        self.abort.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let clients = self.server.as_ref().map_or(0, |s| s.client_count());
        if clients > 0 {
            std::thread::sleep(linger);
        }
        if let Some(s) = self.server.take() {
            s.stop().wait_blocking();
        }
        // The SDK closed its side of every connection: the front delivers what it still
        // holds for clients that read (up to `linger`) and cuts off the others.
        let max_clients = self.front.as_ref().map_or(0, |f| f.max_clients());
        let direct_sdk_clients = self
            .sdk_connects
            .load(Ordering::Acquire)
            .saturating_sub(self.front.as_ref().map_or(0, |f| f.upgraded()));
        let (per_client, refused, over_limit) = self
            .front
            .take()
            .map_or((Vec::new(), 0, 0), |f| f.finish(linger));
        LiveStats {
            published: self.published.load(Ordering::Relaxed),
            dropped: self.tap.dropped(),
            clients,
            per_client,
            refused,
            over_limit,
            max_clients,
            direct_sdk_clients,
        }
    }
}

fn publish_loop(ch: &Channels, tap: &LogTap, published: &AtomicU64, abort: &AtomicBool) {
    // Log times: the wall clock at the start of the view + the run time of each message, so
    // that the Foxglove timeline shows the run as it happens.
    let t0_ns = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    let at = |t: f64| PartialMetadata::with_log_time(t0_ns + (t.max(0.0) * 1e9) as u64);
    let mut buf = Vec::with_capacity(256);
    let mut last_t = 0.0;
    let mut n = 0u64;
    // The config is sent once by the log; repeat it every second for clients that connect
    // later (a live stream has no history).
    let mut config: Option<String> = None;
    let mut config_sent = Instant::now();
    loop {
        if let Some(c) = &config {
            if config_sent.elapsed() >= Duration::from_secs(1) {
                ch.config.log_with_meta(c.as_bytes(), at(last_t));
                config_sent = Instant::now();
                n += 1;
            }
        }
        let m = tap.pop();
        if let Some(TapMessage::Config(c)) = &m {
            config = Some(c.clone());
            config_sent = Instant::now();
        }
        let Some(m) = m else {
            // Closed and drained, or told to stop (the log failed and never closed the tap).
            if tap.is_closed() && tap.pop().is_none() || abort.load(Ordering::Acquire) {
                while let Some(m) = tap.pop() {
                    n += publish(ch, m, &mut buf, &mut last_t, &at);
                }
                published.store(n, Ordering::Relaxed);
                return;
            }
            published.store(n, Ordering::Relaxed);
            std::thread::sleep(Duration::from_micros(500));
            continue;
        };
        n += publish(ch, m, &mut buf, &mut last_t, &at);
    }
}

fn publish(
    ch: &Channels,
    m: TapMessage,
    buf: &mut Vec<u8>,
    last_t: &mut f64,
    at: &dyn Fn(f64) -> PartialMetadata,
) -> u64 {
    match m {
        TapMessage::Record(r) => {
            *last_t = r.t;
            let mut k = 1;
            r.encode_control(buf);
            ch.control.log_with_meta(buf, at(r.t));
            if r.has_plant {
                r.encode_plant(buf);
                ch.plant.log_with_meta(buf, at(r.t));
                k += 1;
            }
            if r.encode_timing(buf) {
                ch.timing.log_with_meta(buf, at(r.t));
                k += 1;
            }
            k
        }
        TapMessage::Event(ev) => {
            ch.events
                .log_with_meta(ev.to_json().to_string().as_bytes(), at(ev.t));
            ch.log.log_with_meta(
                schemas::event_to_foxglove_log(&ev).to_string().as_bytes(),
                at(ev.t),
            );
            2
        }
        TapMessage::Config(s) => {
            ch.config.log_with_meta(s.as_bytes(), at(0.0));
            1
        }
        TapMessage::Summary(s) => {
            ch.summary.log_with_meta(s.as_bytes(), at(*last_t));
            1
        }
    }
}

#[cfg(test)]
mod tests {
    use super::parse_addr;

    #[test]
    fn addresses() {
        assert_eq!(
            parse_addr("127.0.0.1:8765").unwrap(),
            ("127.0.0.1".into(), 8765)
        );
        assert_eq!(parse_addr("[::1]:0").unwrap(), ("::1".into(), 0));
        assert!(parse_addr("8765").unwrap_err().contains("HOST:PORT"));
        assert!(parse_addr("localhost:99999")
            .unwrap_err()
            .contains("0..=65535"));
    }
}
