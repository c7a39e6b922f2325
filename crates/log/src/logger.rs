//! MCAP logger: the cycle pushes fixed-size [`CycleRecord`]s and [`Event`]s into bounded
//! lock-free queues; a writer thread serialises them (CDR, ros2msg schemas) into an MCAP
//! file with chunk, data and summary CRCs (written by `crate::mcap_writer`, which says why
//! it is not the `mcap` crate's writer). Overflow is never silent: with [`Overflow::Block`]
//! (simulated time, nothing to miss) the producer waits for room; with [`Overflow::Drop`]
//! (wall-clock runs) the record is dropped and counted. The file is finalised by
//! [`Logger::finish`], and by `Drop` if a run unwinds.

use crate::mcap_writer::{Compression, Writer};
use crate::record::{control_schema, plant_schema, timing_schema, CycleRecord, Event};
use crate::schemas;
use crossbeam_queue::ArrayQueue;
pub use ehactl_types::frames::{CanFrameRecord, FrameLog};
pub use ehactl_types::queue::LossyQueue;
use std::collections::BTreeMap;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::thread::JoinHandle;
use std::time::Duration;

/// What to do when the record queue is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overflow {
    /// Wait for the writer (simulated time: no deadline can be missed).
    Block,
    /// Drop the record and count it (wall-clock time).
    Drop,
}

/// Chunk compression.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogCompression {
    /// No compression.
    None,
    /// LZ4 frames.
    Lz4,
}

/// Logger options.
#[derive(Debug, Clone, Copy)]
pub struct LogOptions {
    /// Chunk compression.
    pub compression: LogCompression,
    /// Capacity of the record queue (records).
    pub queue_capacity: usize,
    /// Overflow policy.
    pub overflow: Overflow,
    /// Longest span of record time an open chunk may hold before it is closed and flushed
    /// to the file (s). Bounds what a SIGKILL or power loss can take: at most this much in
    /// the open chunk, plus what waits in the queue (see `max_lag`).
    pub chunk_interval: f64,
    /// With [`Overflow::Block`], the producer waits while this many records are queued
    /// (records; 0 or more than `queue_capacity` = the whole queue). Set from `chunk_interval` × the record rate so that
    /// a simulated run, whose loop outpaces the writer, never runs more than one chunk
    /// interval ahead of the file.
    pub max_lag: usize,
}

impl Default for LogOptions {
    fn default() -> Self {
        Self {
            compression: LogCompression::Lz4,
            queue_capacity: 65_536,
            overflow: Overflow::Block,
            chunk_interval: 0.1,
            max_lag: 0,
        }
    }
}

/// Run description written at the start of the file.
#[derive(Debug, Clone)]
pub struct RunMetadata {
    /// The config as TOML text (as loaded, with defaults filled in).
    pub config_toml: String,
    /// The config as JSON.
    pub config_json: serde_json::Value,
    /// Backend name.
    pub backend: String,
    /// Control rate (Hz).
    pub control_rate_hz: f64,
    /// JSON Schema of the `config` object (fields with units), for `/config`'s schema.
    pub config_schema: serde_json::Value,
}

/// What the writer thread hands to a [`LogTap`]: the same messages it logs.
/// Records are not boxed: the writer hands them over by value, and a box would allocate
/// once per cycle for every tap.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum TapMessage {
    /// A cycle record (`/control`, `/plant`, `/timing`).
    Record(CycleRecord),
    /// An event (`/events` and `/log`).
    Event(Event),
    /// The `/config` message (JSON text).
    Config(String),
    /// The `/summary` message (JSON text).
    Summary(String),
}

/// A copy of the log for a live viewer (`ehactl run --live`): the writer thread — never the
/// cycle — offers every message it writes to a bounded lock-free queue; when the queue is
/// full the message is dropped and counted, so a slow viewer never slows the log or the loop.
#[derive(Debug)]
pub struct LogTap {
    queue: LossyQueue<TapMessage>,
    closed: AtomicBool,
}

impl LogTap {
    /// A tap holding up to `capacity` messages (at least 16).
    pub fn new(capacity: usize) -> LogTap {
        LogTap {
            queue: LossyQueue::new(capacity.max(16)),
            closed: AtomicBool::new(false),
        }
    }

    /// Queue a message (never blocks; counted as dropped if full).
    pub fn offer(&self, m: TapMessage) {
        self.queue.push(m);
    }

    /// Take the oldest message.
    pub fn pop(&self) -> Option<TapMessage> {
        self.queue.pop()
    }

    /// Messages dropped because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.queue.dropped()
    }

    /// True once the log is finalised (nothing more will be offered).
    pub fn is_closed(&self) -> bool {
        self.closed.load(Ordering::Acquire)
    }

    /// Mark the tap closed.
    pub fn close(&self) {
        self.closed.store(true, Ordering::Release);
    }
}

/// Counters reported at the end of a run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LogStats {
    /// Path of the MCAP file.
    pub path: PathBuf,
    /// Cycle records written.
    pub records_written: u64,
    /// Records dropped because the queue was full.
    pub records_dropped: u64,
    /// Pushes that had to wait for room (Block policy).
    pub pushes_waited: u64,
    /// Events written.
    pub events_written: u64,
    /// Highest queue occupancy seen (records).
    pub queue_high_water: usize,
    /// Queue capacity (records).
    pub queue_capacity: usize,
    /// Raw CAN frames written to `/can` (CAN backends only).
    pub frames_written: u64,
    /// Raw CAN frames lost because the frame queue was full.
    pub frames_dropped: u64,
}

/// JSON form of a frame for the `/can` channel:
/// `{"t": s, "id": int, "ext": bool, "dlc": int, "data": "hex", "dir": "rx"|"tx"}`.
fn can_frame_json(f: &CanFrameRecord) -> serde_json::Value {
    let n = usize::from(f.dlc.min(8));
    let hex: String = f.data[..n].iter().map(|b| format!("{b:02X}")).collect();
    serde_json::json!({
        "t": f.t_ns as f64 * 1e-9,
        "id": f.id,
        "ext": f.extended,
        "dlc": f.dlc,
        "data": hex,
        "dir": if f.tx { "tx" } else { "rx" },
    })
}

/// An event with text that is not known at compile time (a refused live change: the
/// request and the reason), queued off the loop for `/events` and `/log`.
#[derive(Debug, Clone)]
pub struct Note {
    /// The event (time, cycle, kind, channel, …).
    pub event: Event,
    /// Extra string fields of the `/events` message, e.g. `("request", …)`, `("reason", …)`.
    pub fields: Vec<(&'static str, String)>,
}

impl Note {
    /// The `/events` JSON: the event's fields plus `fields`; a `reason` is appended to `text`.
    pub fn to_json(&self) -> serde_json::Value {
        let mut v = self.event.to_json();
        if let Some(o) = v.as_object_mut() {
            for (k, val) in &self.fields {
                o.insert((*k).to_string(), serde_json::Value::String(val.clone()));
            }
            o.insert("text".into(), serde_json::Value::String(self.text()));
        }
        v
    }

    /// One-line description: the event's, then the request and the reason if given.
    pub fn text(&self) -> String {
        let mut s = self.event.describe();
        for key in ["request", "reason"] {
            if let Some((_, v)) = self.fields.iter().find(|(k, _)| *k == key) {
                s.push_str(&format!("; {key}: {v}"));
            }
        }
        s
    }
}

/// Bounded queue of [`Note`]s from threads off the loop (the control socket) to the MCAP
/// writer: a [`LossyQueue`] (`push`, `pop`, `dropped`). Never blocks: when full a note is
/// dropped and counted.
pub type NoteLog = LossyQueue<Note>;

/// Take the exclusive advisory lock (flock(2)) of the open log file without waiting.
fn lock_exclusive(file: &File) -> Result<(), String> {
    match try_lock_exclusive(file) {
        Ok(true) => Ok(()),
        Ok(false) => Err("is being written by another running ehactl (it holds the file's lock); choose another --out".to_string()),
        Err(e) => Err(format!("cannot lock the file: {e}")),
    }
}

/// Take the exclusive advisory lock (flock(2)) of an open file or directory without waiting:
/// `Ok(false)` when another open file description holds it (another process, or another
/// `open` of the same path). Released when `file` is closed. Also the lock of
/// `ehactl diagnose` / `predict` on their `--out` directory (crates/ident/src/outdir.rs).
pub fn try_lock_exclusive(file: &File) -> std::io::Result<bool> {
    use std::os::fd::AsRawFd;
    // SAFETY: flock on a file descriptor this `File` owns for the duration of the call.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.kind() == std::io::ErrorKind::WouldBlock {
        Ok(false)
    } else {
        Err(e)
    }
}

/// Whether another process holds the lock of the log file at `path` (a run writing it).
/// False when the file cannot be opened.
pub fn is_locked(path: &Path) -> bool {
    use std::os::fd::AsRawFd;
    let Ok(f) = File::open(path) else {
        return false;
    };
    // SAFETY: flock on a descriptor owned by `f`; the probe lock is dropped with `f`.
    let r = unsafe { libc::flock(f.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    r != 0 && std::io::Error::last_os_error().kind() == std::io::ErrorKind::WouldBlock
}

/// Logger failure (file or MCAP error), with the path.
#[derive(Debug)]
pub struct LogError {
    /// File concerned.
    pub path: PathBuf,
    /// What failed.
    pub message: String,
    /// The log could not be created (nothing was run, nothing to recover).
    pub at_create: bool,
}

impl std::fmt::Display for LogError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MCAP log {}: {}", self.path.display(), self.message)
    }
}

impl std::error::Error for LogError {}

struct Shared {
    records: ArrayQueue<CycleRecord>,
    events: ArrayQueue<Event>,
    closing: AtomicBool,
    dropped: AtomicU64,
    waited: AtomicU64,
    high_water: AtomicUsize,
    summary: Mutex<Option<serde_json::Value>>,
    frames: OnceLock<Arc<FrameLog>>,
    notes: OnceLock<Arc<NoteLog>>,
    frames_written: AtomicU64,
    /// Set by the writer when it can no longer write (disk full, I/O error): producers stop
    /// waiting for it and the run trips (see [`Logger::failed_flag`]).
    failed: AtomicBool,
    tap: OnceLock<Arc<LogTap>>,
    config_msg: String,
    /// The thread that pushes records (the loop), set the first time it waits for room.
    producer: OnceLock<std::thread::Thread>,
    /// Set while the producer sleeps in [`Logger::wait_for_room`].
    producer_waiting: AtomicBool,
    /// Queue occupancy (records) at or below which a waiting producer is woken.
    resume_at: usize,
    /// The writer thread, set when it starts.
    writer: OnceLock<std::thread::Thread>,
    /// Set while the writer, with nothing queued, sleeps (at most `IDLE_WAIT`).
    writer_waiting: AtomicBool,
    /// Under [`Overflow::Block`], a push that leaves this many records queued wakes a
    /// sleeping writer (a batch, so that one wake-up serves many records).
    wake_writer_at: usize,
}

/// Longest sleep of the writer when the queues are empty (the wall-clock runs' polling
/// period; under [`Overflow::Block`] the producer wakes it earlier).
const IDLE_WAIT: Duration = Duration::from_micros(200);

impl Shared {
    /// Empty queues for `capacity` records; `config_msg` is the `/config` message.
    fn new(capacity: usize, config_msg: String) -> Shared {
        Shared {
            records: ArrayQueue::new(capacity),
            events: ArrayQueue::new(1024),
            closing: AtomicBool::new(false),
            dropped: AtomicU64::new(0),
            waited: AtomicU64::new(0),
            high_water: AtomicUsize::new(0),
            summary: Mutex::new(None),
            frames: OnceLock::new(),
            notes: OnceLock::new(),
            frames_written: AtomicU64::new(0),
            failed: AtomicBool::new(false),
            tap: OnceLock::new(),
            config_msg,
            producer: OnceLock::new(),
            producer_waiting: AtomicBool::new(false),
            resume_at: capacity / 2,
            writer: OnceLock::new(),
            writer_waiting: AtomicBool::new(false),
            wake_writer_at: (capacity / 4).max(1),
        }
    }

    /// Wake the writer if it sleeps (one wake-up per sleep).
    #[inline]
    fn wake_writer(&self) {
        if self.writer_waiting.load(Ordering::SeqCst)
            && self.writer_waiting.swap(false, Ordering::SeqCst)
        {
            if let Some(t) = self.writer.get() {
                t.unpark();
            }
        }
    }

    /// Writer side: wake the producer if it waits for room and there is enough.
    #[inline]
    fn wake_producer(&self) {
        if self.producer_waiting.load(Ordering::SeqCst) && self.records.len() <= self.resume_at {
            if let Some(t) = self.producer.get() {
                t.unpark();
            }
        }
    }
}

/// A chunk is closed once its records reach this many bytes (uncompressed), whatever
/// time it spans (`LogOptions::chunk_interval` closes it earlier at 5 kHz: ≈ 170 kB).
const CHUNK_LIMIT: usize = 1 << 20;

/// Record queue capacity for `opts`: `queue_capacity` (at least 16), and under
/// [`Overflow::Block`] no more than `max_lag` (see [`LogOptions::max_lag`]).
fn effective_capacity(opts: &LogOptions) -> usize {
    let cap = opts.queue_capacity.max(16);
    match (opts.overflow, opts.max_lag) {
        (Overflow::Block, n) if n > 0 => n.clamp(16, cap),
        _ => cap,
    }
}

/// Handle owned by the run; cheap to push from the cycle.
pub struct Logger {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<Result<(u64, u64), String>>>,
    overflow: Overflow,
    path: PathBuf,
    capacity: usize,
    max_lag: usize,
}

impl Logger {
    /// Create the file, write schemas, channels and the run metadata, start the writer.
    pub fn create(path: &Path, opts: LogOptions, meta: &RunMetadata) -> Result<Logger, LogError> {
        let err = |m: String| LogError {
            path: path.to_path_buf(),
            message: m,
            at_create: true,
        };
        let file = open_locked(path).map_err(err)?;
        let compression = match opts.compression {
            LogCompression::None => Compression::None,
            LogCompression::Lz4 => Compression::Lz4,
        };
        let mut w = Writer::new(
            file,
            "ros2",
            concat!("ehactl ", env!("CARGO_PKG_VERSION")),
            compression,
            CHUNK_LIMIT,
        )
        .map_err(|e| err(format!("cannot start MCAP: {e}")))?;
        let me = |e: std::io::Error| err(e.to_string());
        let (ch, ch_config) = write_header(&mut w, meta).map_err(me)?;
        // Header, schemas, channels and metadata reach the file now: from here on it is an
        // MCAP file (for `ehactl recover` and the `--out` checks).
        w.flush()
            .map_err(|e| err(format!("cannot write the MCAP header: {e}")))?;
        let config_msg = serde_json::json!({"toml": meta.config_toml, "config": meta.config_json, "backend": meta.backend}).to_string();
        w.write_message(ch_config, 0, 0, 0, config_msg.as_bytes())
            .map_err(me)?;
        // Under Block the producer never holds more than `max_lag` records in the queue, so a
        // bigger queue would only be allocated (and its slots initialised: ≈ 22 MB and
        // ≈ 10 ms for 65 536 records) without ever being used: the queue is sized to what
        // the run can use. Under Drop (wall clock) the whole capacity absorbs writer stalls
        // and is allocated up front, before the loop (and locked with it by mlockall).
        let capacity = effective_capacity(&opts);
        let shared = Arc::new(Shared::new(capacity, config_msg));
        let sh = shared.clone();
        let chunk_ns = (opts.chunk_interval.max(0.0) * 1e9) as u64;
        let thread = std::thread::Builder::new()
            .name("ehactl-mcap".into())
            .spawn(move || {
                let r = WriterThread::new(w, sh.clone(), ch, chunk_ns).run();
                if r.is_err() {
                    sh.failed.store(true, Ordering::Release);
                    if let Some(t) = sh.producer.get() {
                        t.unpark();
                    }
                }
                r
            })
            .map_err(|e| err(format!("cannot start writer thread: {e}")))?;
        Ok(Logger {
            shared,
            thread: Some(thread),
            overflow: opts.overflow,
            path: path.to_path_buf(),
            capacity,
            max_lag: capacity,
        })
    }

    /// Queue one cycle record. Lock-free and allocation-free; never silently loses data.
    #[inline]
    pub fn push(&self, rec: &CycleRecord) {
        let q = &self.shared.records;
        if self.overflow == Overflow::Block && q.len() >= self.max_lag {
            self.wait_for_room();
        }
        if q.push(*rec).is_err() {
            // Wall clock with a full queue, or a writer that failed: lost, and counted.
            self.shared.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        let n = q.len();
        if n > self.shared.high_water.load(Ordering::Relaxed) {
            self.shared.high_water.store(n, Ordering::Relaxed);
        }
        // Simulated time: wake the writer once a batch is queued rather than leave it asleep
        // for the rest of its idle wait (a wake-up is a system call, so not on every push,
        // and never under Drop: a wall-clock cycle makes no system call for the log).
        if self.overflow == Overflow::Block && n >= self.shared.wake_writer_at {
            self.shared.wake_writer();
        }
    }

    /// Simulated time, full queue: sleep until the writer has drained the queue to half
    /// (it wakes this thread then; it always does, unless it has failed). Sleeping rather
    /// than spinning leaves the CPU to the writer, and the half-queue hysteresis makes one
    /// wake-up serve `max_lag / 2` pushes. The loop is the only producer, so the push
    /// after this succeeds.
    #[cold]
    fn wait_for_room(&self) {
        let sh = &*self.shared;
        sh.waited.fetch_add(1, Ordering::Relaxed);
        let me = sh.producer.get_or_init(std::thread::current);
        debug_assert_eq!(me.id(), std::thread::current().id(), "one producer thread");
        while sh.records.len() > sh.resume_at && !sh.failed.load(Ordering::Relaxed) {
            sh.producer_waiting.store(true, Ordering::SeqCst);
            // Re-check after announcing, so a wake-up sent in between is not missed; the
            // timeout only bounds the cost of a lost race (never observed to matter).
            if sh.records.len() > sh.resume_at && !sh.failed.load(Ordering::Relaxed) {
                std::thread::park_timeout(Duration::from_millis(1));
            }
            sh.producer_waiting.store(false, Ordering::SeqCst);
        }
    }

    /// Queue an event (lock-free; waits for room rather than losing a trip).
    pub fn event(&self, ev: Event) {
        let mut e = ev;
        while let Err(back) = self.shared.events.push(e) {
            if self.shared.failed.load(Ordering::Relaxed) {
                return;
            }
            e = back;
            std::thread::yield_now();
        }
    }

    /// Set once the writer has failed (disk full, I/O error); the loop checks it every
    /// cycle and trips, so a run never goes on without its log.
    pub fn failed_flag(&self) -> &AtomicBool {
        &self.shared.failed
    }

    /// Log every frame of `frames` to the `/can` channel (JSON, see `can_frame_json`).
    /// The channel is created when the first frame arrives; one source per logger.
    pub fn attach_frames(&self, frames: Arc<FrameLog>) {
        let _ = self.shared.frames.set(frames);
    }

    /// Log every note of `notes` to `/events` and `/log`; one source per logger.
    pub fn attach_notes(&self, notes: Arc<NoteLog>) {
        let _ = self.shared.notes.set(notes);
    }

    /// Offer everything written from now on (and the `/config` message) to `tap` as well;
    /// one tap per logger. The writer thread closes the tap when the file is finalised.
    pub fn attach_tap(&self, tap: Arc<LogTap>) {
        tap.offer(TapMessage::Config(self.shared.config_msg.clone()));
        let _ = self.shared.tap.set(tap);
    }

    /// Path of the file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Write the summary, drain the queues and finalise the file (footer, summary section,
    /// CRCs). Blocks until the writer is done.
    pub fn finish(mut self, summary: serde_json::Value) -> Result<LogStats, LogError> {
        self.finish_inner(Some(summary))
    }

    fn finish_inner(&mut self, summary: Option<serde_json::Value>) -> Result<LogStats, LogError> {
        if let Ok(mut s) = self.shared.summary.lock() {
            *s = summary;
        }
        self.shared.closing.store(true, Ordering::SeqCst);
        self.shared.wake_writer();
        let Some(t) = self.thread.take() else {
            return Err(LogError {
                path: self.path.clone(),
                message: "already finished".into(),
                at_create: false,
            });
        };
        let res = t.join().map_err(|_| LogError {
            path: self.path.clone(),
            message: "writer thread panicked".into(),
            at_create: false,
        })?;
        let (written, events) = res.map_err(|m| LogError {
            path: self.path.clone(),
            message: m,
            at_create: false,
        })?;
        Ok(LogStats {
            path: self.path.clone(),
            records_written: written,
            records_dropped: self.shared.dropped.load(Ordering::Relaxed),
            pushes_waited: self.shared.waited.load(Ordering::Relaxed),
            events_written: events,
            queue_high_water: self.shared.high_water.load(Ordering::Relaxed),
            queue_capacity: self.capacity,
            frames_written: self.shared.frames_written.load(Ordering::Relaxed),
            frames_dropped: self.shared.frames.get().map_or(0, |f| f.dropped()),
        })
    }
}

impl Drop for Logger {
    fn drop(&mut self) {
        if self.thread.is_some() {
            let _ = self.finish_inner(None);
        }
    }
}

/// An I/O error of the writer as text (the OS error, e.g. "No space left on device").
fn io_error(e: std::io::Error) -> String {
    e.to_string()
}

/// `path` created (with its directory), locked against a second run and emptied.
fn open_locked(path: &Path) -> Result<File, String> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| format!("cannot create directory: {e}"))?;
    }
    // Opened without truncation and locked first: a second run to the same path is
    // refused before it can truncate the first run's log. The lock is advisory (flock)
    // and held by the open file until the writer drops it; a killed run's lock goes with
    // its process and its log stays where it was, for `ehactl recover`. (Writing to a
    // temporary name renamed at the end would leave a killed run's log under a name the
    // user does not know, and the previous log in its place.)
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)
        .map_err(|e| format!("cannot create file: {e}"))?;
    lock_exclusive(&file)?;
    file.set_len(0)
        .map_err(|e| format!("cannot truncate file: {e}"))?;
    Ok(file)
}

/// The file's schemas, channels and run metadata; returns the channels the writer thread
/// writes to and `/config`'s.
fn write_header(w: &mut Writer, meta: &RunMetadata) -> std::io::Result<(Channels, u16)> {
    let s_control = w.add_schema(
        "ehactl_msgs/msg/ControlCycle",
        "ros2msg",
        control_schema().as_bytes(),
    )?;
    let s_plant = w.add_schema(
        "ehactl_msgs/msg/PlantState",
        "ros2msg",
        plant_schema().as_bytes(),
    )?;
    let s_timing = w.add_schema(
        "ehactl_msgs/msg/CycleTiming",
        "ros2msg",
        timing_schema().as_bytes(),
    )?;
    let mut json_schema = |name: &str, schema: serde_json::Value| {
        w.add_schema(name, "jsonschema", schema.to_string().as_bytes())
    };
    let s_config = json_schema(
        schemas::CONFIG_SCHEMA_NAME,
        schemas::config_schema(meta.config_schema.clone()),
    )?;
    let s_events = json_schema(schemas::EVENT_SCHEMA_NAME, schemas::event_schema())?;
    let s_summary = json_schema(schemas::SUMMARY_SCHEMA_NAME, schemas::summary_schema())?;
    let s_log = json_schema(
        schemas::FOXGLOVE_LOG_SCHEMA_NAME,
        schemas::foxglove_log_schema(),
    )?;
    let none = BTreeMap::new();
    let ch_control = w.add_channel(s_control, "/control", "cdr", &none)?;
    let ch_plant = w.add_channel(s_plant, "/plant", "cdr", &none)?;
    // Written only by wall-clock runs (records with timing); empty otherwise.
    let ch_timing = w.add_channel(s_timing, "/timing", "cdr", &none)?;
    let ch_config = w.add_channel(s_config, "/config", "json", &none)?;
    let ch_events = w.add_channel(s_events, "/events", "json", &none)?;
    let ch_summary = w.add_channel(s_summary, "/summary", "json", &none)?;
    // The events again as foxglove.Log, for Foxglove's Log panel.
    let ch_log = w.add_channel(s_log, "/log", "json", &none)?;
    let md = BTreeMap::from([
        ("config_toml".to_string(), meta.config_toml.clone()),
        ("backend".to_string(), meta.backend.clone()),
        (
            "control_rate_hz".to_string(),
            meta.control_rate_hz.to_string(),
        ),
        (
            "ehactl_version".to_string(),
            env!("CARGO_PKG_VERSION").to_string(),
        ),
    ]);
    w.write_metadata("ehactl_run", &md)?;
    let ch = Channels {
        control: ch_control,
        plant: ch_plant,
        timing: ch_timing,
        events: ch_events,
        summary: ch_summary,
        log: ch_log,
    };
    Ok((ch, ch_config))
}

/// The channels the writer thread writes to (`/config` is written once at creation).
#[derive(Clone, Copy)]
struct Channels {
    control: u16,
    plant: u16,
    timing: u16,
    events: u16,
    summary: u16,
    log: u16,
}

/// Records in a row before the writer turns to the other queues.
const BATCH: u64 = 4096;

/// The writer thread: takes the queues in turn (records, events, notes, CAN frames) and
/// writes them to the MCAP file until the logger closes, then the summary and the footer.
struct WriterThread {
    w: Writer,
    sh: Arc<Shared>,
    ch: Channels,
    /// `/can`, added with the first frame (runs without CAN have no such channel).
    ch_can: Option<u16>,
    chunk_ns: u64,
    /// Record time (ns) of the first message in the open chunk; the chunk is closed and
    /// flushed to the file once it spans `chunk_ns`, and whenever the queues run dry, so a
    /// killed process loses at most one chunk interval of what the writer had taken.
    chunk_start: Option<u64>,
    /// When the open chunk was last flushed (wall clock).
    wall_flush: std::time::Instant,
    /// Latest record time written (ns): the summary's time.
    last_ns: u64,
    written: u64,
    events: u64,
    frames_written: u64,
}

fn to_ns(t: f64) -> u64 {
    (t.max(0.0) * 1e9).round() as u64
}

/// `/can` of `w`, added on first use (`ch_can` holds it then).
fn can_channel(w: &mut Writer, ch_can: &mut Option<u16>) -> Result<u16, String> {
    if let Some(c) = *ch_can {
        return Ok(c);
    }
    let schema = serde_json::json!({"type": "object", "properties": {
        "t": {"type": "number", "description": "time from the start of the control loop (s); negative during start-up"},
        "id": {"type": "integer", "description": "CAN identifier"},
        "ext": {"type": "boolean", "description": "29-bit identifier"},
        "dlc": {"type": "integer", "description": "data length (bytes)"},
        "data": {"type": "string", "description": "data bytes, hex"},
        "dir": {"type": "string", "enum": ["rx", "tx"], "description": "received or sent by ehactl"}}})
    .to_string();
    let s = w
        .add_schema("ehactl.CanFrame", "jsonschema", schema.as_bytes())
        .map_err(io_error)?;
    let c = w
        .add_channel(s, "/can", "json", &BTreeMap::new())
        .map_err(io_error)?;
    *ch_can = Some(c);
    Ok(c)
}

impl WriterThread {
    fn new(w: Writer, sh: Arc<Shared>, ch: Channels, chunk_ns: u64) -> WriterThread {
        WriterThread {
            w,
            sh,
            ch,
            ch_can: None,
            chunk_ns,
            chunk_start: None,
            wall_flush: std::time::Instant::now(),
            last_ns: 0,
            written: 0,
            events: 0,
            frames_written: 0,
        }
    }

    /// Write until the logger closes and its queues are empty; returns (records, events).
    fn run(mut self) -> Result<(u64, u64), String> {
        let _ = self.sh.writer.set(std::thread::current());
        loop {
            let closing = self.sh.closing.load(Ordering::Acquire);
            let mut busy = self.take_records()?;
            busy |= self.take_events()?;
            busy |= self.take_notes()?;
            busy |= self.take_frames(closing)?;
            if closing && self.sh.records.is_empty() && self.sh.events.is_empty() {
                break;
            }
            if !busy {
                self.wait_for_work()?;
            }
        }
        self.finish()
    }

    /// Close the open chunk and flush it to the file; the chunk clock starts again.
    fn close_chunk(&mut self) -> Result<(), String> {
        self.w.flush().map_err(io_error)?;
        self.chunk_start = None;
        self.wall_flush = std::time::Instant::now();
        Ok(())
    }

    /// Up to [`BATCH`] cycle records; true if there was any.
    fn take_records(&mut self) -> Result<bool, String> {
        let mut any = false;
        while let Some(rec) = self.sh.records.pop() {
            any = true;
            self.sh.wake_producer();
            let ns = to_ns(rec.t);
            self.last_ns = self.last_ns.max(ns);
            let seq = rec.cycle as u32;
            let (w, ch) = (&mut self.w, self.ch);
            w.write_message_with(ch.control, seq, ns, ns, |b| rec.append_control(b))
                .map_err(io_error)?;
            if rec.has_plant {
                w.write_message_with(ch.plant, seq, ns, ns, |b| rec.append_plant(b))
                    .map_err(io_error)?;
            }
            if rec.timing.is_some() {
                w.write_message_with(ch.timing, seq, ns, ns, |b| {
                    rec.append_timing(b);
                })
                .map_err(io_error)?;
            }
            if let Some(tp) = self.sh.tap.get() {
                tp.offer(TapMessage::Record(rec));
            }
            self.written += 1;
            let start = *self.chunk_start.get_or_insert(ns);
            if ns.saturating_sub(start) >= self.chunk_ns {
                self.close_chunk()?;
            }
            if self.written.is_multiple_of(BATCH) {
                break;
            }
        }
        Ok(any)
    }

    /// One event on `/events` (as `event_json`) and `/log` (as `log`), numbered in order.
    fn write_event(&mut self, t: f64, event_json: &str, log: &str) -> Result<(), String> {
        let ns = to_ns(t);
        let seq = self.events as u32;
        self.w
            .write_message(self.ch.events, seq, ns, ns, event_json.as_bytes())
            .map_err(io_error)?;
        self.w
            .write_message(self.ch.log, seq, ns, ns, log.as_bytes())
            .map_err(io_error)?;
        self.events += 1;
        self.chunk_start.get_or_insert(ns);
        Ok(())
    }

    /// Every queued event (the run's and the CAN threads'); true if there was any.
    fn take_events(&mut self) -> Result<bool, String> {
        let mut any = false;
        while let Some(ev) = self
            .sh
            .events
            .pop()
            .or_else(|| self.sh.frames.get().and_then(|f| f.pop_event()))
        {
            any = true;
            let log = schemas::event_to_foxglove_log(&ev).to_string();
            self.write_event(ev.t, &ev.to_json().to_string(), &log)?;
            if let Some(tp) = self.sh.tap.get() {
                tp.offer(TapMessage::Event(ev));
            }
        }
        Ok(any)
    }

    /// Every queued note (an event with a text of its own); true if there was any.
    fn take_notes(&mut self) -> Result<bool, String> {
        let mut any = false;
        while let Some(note) = self.sh.notes.get().and_then(|n| n.pop()) {
            any = true;
            let mut log = schemas::event_to_foxglove_log(&note.event);
            log["message"] = serde_json::Value::String(note.text());
            self.write_event(note.event.t, &note.to_json().to_string(), &log.to_string())?;
            if let Some(tp) = self.sh.tap.get() {
                tp.offer(TapMessage::Event(note.event));
            }
        }
        Ok(any)
    }

    /// Up to [`BATCH`] CAN frames, or while closing every frame queued now (the I/O threads
    /// may still be receiving); true if there was any.
    fn take_frames(&mut self, closing: bool) -> Result<bool, String> {
        let Some(fl) = self.sh.frames.get() else {
            return Ok(false);
        };
        let limit = if closing { fl.len() } else { usize::MAX };
        let mut n = 0usize;
        while n < limit {
            let Some(f) = fl.pop() else { break };
            n += 1;
            let ch = can_channel(&mut self.w, &mut self.ch_can)?;
            let ns = f.t_ns.max(0) as u64;
            let seq = self.frames_written as u32;
            self.w
                .write_message(ch, seq, ns, ns, can_frame_json(&f).to_string().as_bytes())
                .map_err(io_error)?;
            self.frames_written += 1;
            self.chunk_start.get_or_insert(ns);
            self.sh
                .frames_written
                .store(self.frames_written, Ordering::Relaxed);
            if !closing && n >= BATCH as usize {
                break;
            }
        }
        Ok(n > 0)
    }

    /// Nothing queued: close the open chunk once it is older than one interval of wall time
    /// too (a paused or slow loop must not keep records unflushed), then sleep until there
    /// is work (see `Logger::push`) or `IDLE_WAIT` has passed. Announce first, then check
    /// again, so that a wake-up in between is not missed.
    fn wait_for_work(&mut self) -> Result<(), String> {
        if self.chunk_start.is_some()
            && self.wall_flush.elapsed().as_nanos() as u64 >= self.chunk_ns
        {
            self.close_chunk()?;
        }
        let sh = &self.sh;
        sh.writer_waiting.store(true, Ordering::SeqCst);
        if sh.records.is_empty() && sh.events.is_empty() && !sh.closing.load(Ordering::SeqCst) {
            std::thread::park_timeout(IDLE_WAIT);
        }
        sh.writer_waiting.store(false, Ordering::SeqCst);
        Ok(())
    }

    /// The summary (with the records written) and the file's footer.
    fn finish(mut self) -> Result<(u64, u64), String> {
        let summary = self.sh.summary.lock().ok().and_then(|mut s| s.take());
        if let Some(mut summary) = summary {
            if let Some(obj) = summary.as_object_mut() {
                obj.insert("records_written".into(), self.written.into());
            }
            let text = summary.to_string();
            let ns = self.last_ns;
            self.w
                .write_message(self.ch.summary, 0, ns, ns, text.as_bytes())
                .map_err(io_error)?;
            if let Some(tp) = self.sh.tap.get() {
                tp.offer(TapMessage::Summary(text));
            }
        }
        if let Some(tp) = self.sh.tap.get() {
            tp.close();
        }
        self.w.finish().map_err(io_error)?;
        Ok((self.written, self.events))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta() -> RunMetadata {
        RunMetadata {
            config_toml: String::new(),
            config_json: serde_json::json!({}),
            backend: "test".into(),
            control_rate_hz: 5000.0,
            config_schema: serde_json::json!({"type": "object"}),
        }
    }

    /// `/control` sequence numbers of `path`, read back with the mcap crate's reader.
    fn control_sequences(path: &Path) -> Vec<u32> {
        let bytes = std::fs::read(path).unwrap();
        mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| m.unwrap())
            .filter(|m| m.channel.topic == "/control")
            .map(|m| m.sequence)
            .collect()
    }

    #[test]
    fn block_queue_holds_max_lag_records_and_loses_none() {
        let dir = std::env::temp_dir().join(format!("ehactl_logger_{}", std::process::id()));
        let path = dir.join("block.mcap");
        let opts = LogOptions {
            max_lag: 64,
            ..LogOptions::default()
        };
        let log = Logger::create(&path, opts, &meta()).unwrap();
        let n = 20_000u64;
        for k in 0..n {
            let rec = CycleRecord {
                cycle: k,
                t: k as f64 * 2e-4,
                has_plant: true,
                ..CycleRecord::default()
            };
            log.push(&rec);
        }
        let st = log.finish(serde_json::json!({})).unwrap();
        // The queue is allocated for what the producer may hold, not for 65 536 records.
        assert_eq!(st.queue_capacity, 64);
        assert!(
            st.queue_high_water <= 64,
            "high water {}",
            st.queue_high_water
        );
        assert_eq!((st.records_written, st.records_dropped), (n, 0));
        // The producer outruns the writer here, so it must have waited for room; each
        // wait lasts until the queue is down to half (32), so it buys at least 32 pushes.
        assert!(st.pushes_waited > 0);
        assert!(st.pushes_waited <= n / 32 + 1, "{} waits", st.pushes_waited);
        let seq = control_sequences(&path);
        assert_eq!(seq.len() as u64, n);
        assert!(seq.iter().enumerate().all(|(i, &s)| s as usize == i));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn drop_queue_keeps_its_configured_capacity() {
        let opts = LogOptions {
            overflow: Overflow::Drop,
            queue_capacity: 4096,
            max_lag: 64,
            ..LogOptions::default()
        };
        assert_eq!(effective_capacity(&opts), 4096);
        let block = LogOptions {
            overflow: Overflow::Block,
            ..opts
        };
        assert_eq!(effective_capacity(&block), 64);
        let whole = LogOptions {
            max_lag: 0,
            ..block
        };
        assert_eq!(effective_capacity(&whole), 4096);
    }
}
