//! [`CanopenHal`]: the `Hal` of a CAN rig with a CiA 406 position transducer and a CiA 408
//! valve (Dindorf 2022's boom: magnetostrictive transducer + 4WRSE OBE), and any further
//! sensors of `[[canopen.devices]]` (e.g. a CiA 404 pressure transmitter). The backend holds
//! the plan's list of devices, each with its profile ([`crate::profile::Profile`]): every
//! device is brought up, its heartbeat consumed, its EMCY and NMT state watched, its TPDO1
//! aged and decoded into [`Measurements`]; the commanded device (the one whose profile moves
//! the load: the valve) gets the command as its profile encodes it and the safe stop.
//!
//! Lifecycle (the states of [`Hal`]; the start-up steps are [`crate::startup`]):
//! - [`CanopenHal::new`] / [`CanopenHal::new_with`]: **Unconfigured**, no bus I/O;
//! - [`Hal::configure`] → **Configured**: a plan is made from the settings and the devices'
//!   EDS / DCF files without the bus ([`CanopenHal::check_settings`]); the bus is opened; NMT
//!   reset communication → boot-ups (or an SDO probe, `boot_timeout_s`), NMT
//!   pre-operational, device type and identity 0x1018 against the files, the planned objects
//!   (heartbeat 0x1017, consumer 0x1016 of ehactl's heartbeat, SYNC objects
//!   0x1006/0x1019/0x1007, transducer step, PDO mappings, valve device mode 0x6042 / control
//!   mode 0x6043 / hold setpoint 0x6314, RPDO deadline 0x1400:05: read first, written and
//!   read back where the file allows, read-only ones checked), NMT start and heartbeats
//!   OPERATIONAL. The valve's CiA 408 device state is not touched: it is not enabled;
//! - [`Hal::activate`] → **Active**: a fault reset of the valve if it is in a fault state
//!   (rising edge of control-word R with its D/H bits held, CiA 408 as published in Moog
//!   B99224-DV018 §5.2), valve DISABLED → HOLD → ACTIVE by SDO control word, one priming SYNC
//!   so that the first cycle has a position, then the I/O threads below; a failure after the
//!   valve is ACTIVE (priming) first returns it to HOLD with setpoint 0;
//! - [`Hal::deactivate`] (Active only) → **Configured**: the safe stop below. In Configured
//!   (never activated, or already deactivated) deactivate is a [`HalError::Lifecycle`]
//!   error and sends nothing to the valve (documented decision: it is not ACTIVE, there is
//!   nothing to undo, and an unexpected HOLD command could surprise whoever configured it);
//!   a later activate enables the valve again on the same bus;
//! - [`Hal::safe_stop`], in every state: Active as below (then Configured); Configured:
//!   setpoint 0 and control word HOLD (on the start-up bus before the first activation, by
//!   SDO after a deactivation); Unconfigured: nothing to send;
//! - a failed configure or activate → **Failed**: only safe_stop (nothing sent: the failed
//!   start-up already returned a valve it had enabled to HOLD);
//!   [`CanopenHal::take_startup_failure`] hands back the error with every frame of the
//!   attempt, for the log (a failed start-up is recorded like a trip, see
//!   [`StartupFailure`]; [`Hal::take_startup_report`] gives the same as the
//!   backend-neutral [`StartupReport`], with which the session, `ehactl_runtime::session`,
//!   logs it). A safe stop the valve did not confirm also leaves the backend Failed; there
//!   a safe stop tries the HOLD again (by SDO, if the bus is still there) and
//!   fails again without one. Read and write are refused outside Active.
//!
//! `ehactl run --hal canopen` builds the backend with [`CanopenHal::new_until`] and hands it
//! to the session, which configures and activates it as any backend. [`CanopenHal::connect`]
//! and its variants are new + configure + activate in one call and may block for at most
//! `boot_timeout_s` plus a few SDO timeouts; [`CanopenHal::connect_logged`] hands back every
//! frame of a failed attempt.
//!
//! Threads and queues:
//! - start-up (the lifecycle calls, [`crate::startup`]) runs before the loop and may block;
//! - an RX thread owns the receiving side of the bus and pushes every frame into a
//!   lock-free queue for the cycle (and into the `/can` log queue);
//! - a TX thread owns the sending side and sends what the cycle pushed into another
//!   lock-free queue (woken by `unpark`, which does not block the cycle);
//! - ehactl's own heartbeat (0x700 + `master_node_id`): during start-up sent by the start-up
//!   bus wrapper while it waits for frames (in configure, activate and a Configured
//!   safe stop), from the end of activate until the first cycle by the TX thread, then
//!   queued by the control cycle in `write` every `master_heartbeat_ms` of the caller's
//!   clock (not of loop time, which lags it by the deadlines the pacer skips), so that a
//!   dead or hung cycle silences it and the devices' consumers (0x1016) react. Limitation:
//!   nothing sends it between the lifecycle calls (after configure returns and before
//!   activate, after a deactivate): a pause longer than the devices' consumer time
//!   (`device_heartbeat_timeout_ms`) lets their consumers time out, and they enter their
//!   fault reaction — safe (the valve leaves ACTIVE or is not in it; activate resets a
//!   FAULT_HOLD). The connect functions call activate right after configure;
//! - the cycle (`read` / `write`) never touches the bus: `read` drains the RX queue
//!   (TPDO decode, PDO age, heartbeat consumer, EMCY consumer, valve status) with the loop
//!   time as injected time base — except the heartbeat consumers, which time from each
//!   heartbeat's receive stamp against the present time of the caller's clock
//!   ([`crate::clock`]; the monotonic clock in a run) (CiA 301 §7.2.8.3.2.2), judged up to
//!   the RX thread's last look at the bus (at most one consumer time back); `write`
//!   converts the command to the spool setpoint and, when the
//!   SYNC producer is due, queues RPDO1 (setpoint) then SYNC. Between SYNCs the control law
//!   runs on held samples (sample-and-hold): CAN I/O at `sync_rate_hz`, control at
//!   `run.control_rate_hz`.
//!
//! Faults become `HalError::Device`, so the loop trips, calls `safe_stop` and ends the run
//! with the reason: heartbeat timeout (detected in the first cycle more than
//! `heartbeat_timeout_ms` after the reception of the last heartbeat), a device leaving OPERATIONAL or rebooting, EMCY with a non-zero code, the
//! valve leaving ACTIVE or reporting a fault state (next status TPDO, i.e. within one SYNC), the
//! bus connection dropping (next cycle), queue overflow.
//!
//! Malformed and unexpected frames (documented decision): a frame with a wrong DLC for its
//! COB-ID, or an unknown COB-ID, is logged as a `can_bus` warning event (with the COB-ID as
//! value, first 100 of each kind) and counted in the summary, and otherwise ignored: the
//! held sample stays in use. A single bad frame is no hazard; persistent loss of a PDO is
//! caught by the supervisor's staleness check (`supervisor.stale_timeout`) and loss of a
//! device by the heartbeat consumer, both of which trip.
//!
//! Safe stop: RPDO setpoint for the safe command (0) + SYNC, then the I/O threads are
//! stopped and the valve control word is set to HOLD (D=1, H=1, A=0) by SDO.
//! Dropping an Active `CanopenHal` whose safe stop was never called performs it (see its
//! `Drop`); a Configured one sends nothing when dropped.

use crate::bus::{BusError, BusErrorKind, CanBus};
use crate::cia408::{self, ValveState};
use crate::clock::{Clock, MonotonicClock};
use crate::emcy::{Emcy, EMCY_BASE};
use crate::frame::{CanFrame, Direction};
use crate::heartbeat::{HeartbeatConsumer, HeartbeatEvent};
use crate::nmt::{NmtState, HEARTBEAT_BASE};
use crate::pdo::TPDO1_BASE;
use crate::profile::Profile;
use crate::sdo::{self, SdoClient, SDO_TX_BASE};
pub use crate::settings::CanopenSettings;
use crate::startup::{rpdo_frame, Activated, Bringup, Plan, StartBus, Startup};
pub use crate::startup::{StartupError, StartupFailure};
use crate::sync::{self, SyncProducer};
use crate::transport;
use crossbeam_queue::ArrayQueue;
use ehactl_hal::{Hal, HalError, Measurements, StartupReport};
use ehactl_types::event::{Event, EventKind, Severity};
use ehactl_types::frames::{CanFrameRecord, FrameLog};
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

/// State shared by the cycle and the I/O threads (atomics only, plus one error text that
/// the I/O threads set once and that is read outside the cycle).
struct IoShared {
    stop: AtomicBool,
    /// Set by the first cycle: from then on the cycle produces ehactl's heartbeat; before
    /// (between start-up and the loop's first cycle) the TX thread does.
    cycle_started: AtomicBool,
    failed: AtomicBool,
    error: Mutex<Option<String>>,
    /// The caller's clock (see [`crate::clock`]) and its reading at the start of the
    /// start-up (ns): every stamp below is counted from there.
    clock: Arc<dyn Clock>,
    epoch_ns: u64,
    /// ns since `epoch_ns` of loop time 0.
    zero_ns: AtomicI64,
    /// ns ([`IoShared::mono`]) when the RX thread last found the bus drained: every frame
    /// received before it is in the RX queue (stored after the pushes, Release).
    drained_ns: AtomicI64,
    /// Longest time between two looks of the RX thread at the bus (ns): at most its
    /// receive timeout ([`RX_WAIT`]) plus the time to take a frame in while the thread is
    /// scheduled; more is a stall of the thread (reported as `can_rx_gap_max_us`).
    rx_gap_max_ns: AtomicI64,
    rx_frames: AtomicU64,
    tx_frames: AtomicU64,
    rx_overflow: AtomicU64,
    transport_errors: AtomicU64,
}

impl IoShared {
    /// Fresh state on `clock` whose stamps count from `epoch_ns`; loop time 0 and the RX
    /// thread's last look at the bus are now.
    fn new(clock: Arc<dyn Clock>, epoch_ns: u64) -> IoShared {
        let now = clock.now_ns().saturating_sub(epoch_ns) as i64;
        IoShared {
            stop: AtomicBool::new(false),
            cycle_started: AtomicBool::new(false),
            failed: AtomicBool::new(false),
            error: Mutex::new(None),
            clock,
            epoch_ns,
            zero_ns: AtomicI64::new(now),
            drained_ns: AtomicI64::new(now),
            rx_gap_max_ns: AtomicI64::new(0),
            rx_frames: AtomicU64::new(0),
            tx_frames: AtomicU64::new(0),
            rx_overflow: AtomicU64::new(0),
            transport_errors: AtomicU64::new(0),
        }
    }

    /// The present time on the caller's clock (ns).
    #[inline]
    fn now(&self) -> u64 {
        self.clock.now_ns()
    }

    /// Time of the /can log (ns since loop time 0) of clock reading `at` (ns).
    #[inline]
    fn stamp(&self, at: u64) -> i64 {
        self.mono(at) - self.zero_ns.load(Ordering::Relaxed)
    }

    /// ns since `epoch_ns` of clock reading `at` (monotonic; unlike `stamp` it does not move
    /// when the first cycle sets loop time 0): the clock of the receive stamps the heartbeat
    /// consumers use.
    #[inline]
    fn mono(&self, at: u64) -> i64 {
        at.saturating_sub(self.epoch_ns).min(i64::MAX as u64) as i64
    }

    fn fail(&self, msg: String) {
        if let Ok(mut e) = self.error.lock() {
            if e.is_none() {
                *e = Some(msg);
            }
        }
        self.failed.store(true, Ordering::Release);
    }
}

#[inline]
fn record(f: &CanFrame, t_ns: i64, tx: bool) -> CanFrameRecord {
    CanFrameRecord {
        t_ns,
        id: f.id,
        extended: f.extended,
        dlc: f.dlc,
        data: f.data,
        tx,
    }
}

const RX_QUEUE: usize = 4096;
const TX_QUEUE: usize = 1024;
const FRAME_LOG: usize = 1 << 17;
/// Warning events logged per kind (the counters in the summary keep counting).
const MAX_WARNINGS: u64 = 100;

/// Where a [`CanopenHal`] is in its lifecycle (see the module docs and [`Hal`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Lifecycle {
    /// Made by [`CanopenHal::new`]: no bus I/O yet.
    Unconfigured,
    /// The devices are configured and OPERATIONAL, the valve is not enabled (never
    /// activated, or deactivated / safe-stopped since).
    Configured,
    /// The valve is ACTIVE and the I/O threads run the cyclic exchange.
    Active,
    /// A configure or activate failed (the reason: [`CanopenHal::take_startup_failure`]), or
    /// a safe stop was not confirmed: only [`Hal::safe_stop`] is allowed.
    Failed,
}

impl Lifecycle {
    fn as_str(self) -> &'static str {
        match self {
            Lifecycle::Unconfigured => "unconfigured",
            Lifecycle::Configured => "configured",
            Lifecycle::Active => "active",
            Lifecycle::Failed => "failed",
        }
    }
}

/// The start-up between configure and activate: the start-up bus (ehactl's heartbeat keeps
/// its period across the calls), the plan and what configure found.
struct Pending {
    bus: Box<StartBus>,
    names: Vec<Option<String>>,
    skipped: Vec<String>,
}

/// The texts of one device's warnings and trips (event channels and [`HalError::Device`]
/// reasons are `&'static str`): made once per device name when the backend is activated
/// ([`intern`]), so that the cycle formats nothing.
#[derive(Debug, Clone, Copy)]
struct DeviceText {
    wrong_dlc: &'static str,
    too_old: &'static str,
    rebooted: &'static str,
    left_operational: &'static str,
    emcy: &'static str,
    heartbeat_lost: &'static str,
}

impl DeviceText {
    fn new(name: &str, tpdo_len: Option<usize>) -> DeviceText {
        let len = tpdo_len.unwrap_or(0);
        DeviceText {
            wrong_dlc: intern(format!(
                "wrong DLC on {name} TPDO1 (expected {len}), ignored"
            )),
            too_old: intern(format!("{name} TPDO older than canopen.max_pdo_age_syncs")),
            rebooted: intern(format!("{name} rebooted (boot-up during the run)")),
            left_operational: intern(format!("{name} left NMT OPERATIONAL")),
            emcy: intern(format!("EMCY from the {name}")),
            heartbeat_lost: intern(format!("{name} heartbeat lost (consumer timeout)")),
        }
    }
}

/// `text` as a `&'static str`: each distinct text is leaked once per process and reused,
/// so the memory is bounded by the device names and PDO sizes of the rig (a few hundred
/// bytes), however often backends are activated.
fn intern(text: String) -> &'static str {
    static TEXTS: Mutex<Vec<&'static str>> = Mutex::new(Vec::new());
    let Ok(mut v) = TEXTS.lock() else {
        return "CANopen device";
    };
    if let Some(t) = v.iter().find(|t| **t == text) {
        return t;
    }
    let t: &'static str = Box::leak(text.into_boxed_str());
    v.push(t);
    t
}

/// One device of the run as the control cycle follows it (built when the backend is
/// activated, from the plan; the cycle updates it in place and allocates nothing).
struct RunDevice {
    node: u8,
    profile: &'static dyn Profile,
    /// Size of its TPDO1 as mapped (bytes; `None`: it sends none).
    tpdo_len: Option<usize>,
    /// Size of its RPDO1 as mapped (bytes; `None`: it receives none).
    rpdo_len: Option<usize>,
    /// The consumer of its heartbeat.
    hb: HeartbeatConsumer,
    /// PDO age: SYNCs queued whose synchronous TPDO has not arrived yet.
    pending_syncs: u32,
    /// Synchronous TPDOs that arrived after the next SYNC had been sent (age ≥ 1 SYNC).
    late: u64,
    /// Largest TPDO age seen (SYNC periods).
    max_age: u32,
    text: DeviceText,
    /// Its key in the report: the profile's name, with the node id where two devices share it.
    key: String,
}

impl RunDevice {
    /// The devices of `plan`, their heartbeat consumers with timeout `hb_ns` (ns).
    fn from_plan(plan: &Plan, hb_ns: u64) -> Vec<RunDevice> {
        let devices = &plan.devices;
        devices
            .iter()
            .map(|d| {
                let name = d.device.name();
                let shared = devices.iter().filter(|o| o.device.name() == name).count() > 1;
                RunDevice {
                    node: d.node,
                    profile: d.device,
                    tpdo_len: d.tpdo_len,
                    rpdo_len: d.rpdo_len,
                    hb: HeartbeatConsumer::new(d.node, hb_ns),
                    pending_syncs: 0,
                    late: 0,
                    max_age: 0,
                    text: DeviceText::new(name, d.tpdo_len),
                    key: if shared {
                        format!("{name} {}", d.node)
                    } else {
                        name.to_string()
                    },
                }
            })
            .collect()
    }
}

/// The device whose TPDO1 stamps the sample time [`Measurements::t`] (and ends the
/// start-up grace): the transducer, first in the plan, whose position closes the loop.
const CLOCK_DEVICE: usize = 0;

/// The CANopen backend (see the module docs).
pub struct CanopenHal {
    s: CanopenSettings,
    /// The devices of the run, in the plan's order (empty until activated).
    devices: Vec<RunDevice>,
    /// Index in `devices` of the commanded device (the valve, [`Plan::commanded`]).
    cmd: usize,
    lifecycle: Lifecycle,
    /// The bus handed to [`CanopenHal::new_with`], opened by configure (`None`: configure
    /// opens `s.bus`).
    given_bus: Option<Box<dyn CanBus>>,
    /// Stop request (SIGINT / SIGTERM) honoured by every blocking phase of the start-up.
    stop: Option<Arc<AtomicBool>>,
    /// The start-up's bookkeeping (frames for the log, device states) and the clock.
    st: Startup,
    /// Clock reading at the start of configure (ns): the epoch of the run's stamps.
    t_start: u64,
    /// The plan of the last configure (for a re-activation after deactivate).
    plan: Option<Plan>,
    /// Between configure and activate.
    pending: Option<Pending>,
    /// The start-up step in progress or, after a failure, the one that failed.
    phase: &'static str,
    /// The failure of the last configure / activate, with its frames.
    failure: Option<StartupFailure>,
    /// Failed because a configure / activate failed (not a safe stop).
    startup_failed: bool,
    shared: Arc<IoShared>,
    frame_log: Arc<FrameLog>,
    /// Received frames with their receive time (ns, [`IoShared::mono`]).
    rxq: Arc<ArrayQueue<(CanFrame, i64)>>,
    txq: Arc<ArrayQueue<CanFrame>>,
    rx_thread: Option<JoinHandle<Box<dyn CanBus>>>,
    tx_thread: Option<JoinHandle<Box<dyn CanBus>>>,
    tx_waker: Option<std::thread::Thread>,
    bus_after_stop: Option<Box<dyn CanBus>>,
    /// Start-up frames with their clock reading (ns), handed to the log in the first cycle.
    startup_frames: Vec<(u64, CanFrame, bool)>,
    started: bool,
    last_write_t: Option<f64>,
    sync: SyncProducer,
    /// ehactl's heartbeat frame, its producer period (ns) and the clock reading at which the
    /// next one is due (ns, [`IoShared::now`]; 0: at the first cycle).
    master_hb: CanFrame,
    master_hb_period_ns: u64,
    master_hb_next_ns: u64,
    meas: Measurements,
    /// The commanded device's state as its last TPDO1 reported it ([`Profile::tpdo_state`]).
    cmd_state: Option<&'static str>,
    /// The transducer's first TPDO of the loop has arrived (start-up grace, see `read`).
    first_tpdo: bool,
    /// Loop time of the first cycle (s).
    loop_t0: Option<f64>,
    /// Start-up grace (s): `heartbeat_timeout_ms`.
    grace_s: f64,
    /// `heartbeat_timeout_ms` (ns): the longest RX-thread stall the consumers bridge.
    hb_timeout_ns: i64,
    fault: Option<HalError>,
    wrong_dlc: u64,
    unknown: u64,
    emcy_count: u64,
    last_emcy: Option<Emcy>,
    safe_stop_result: Option<String>,
    startup_s: f64,
    names: Vec<Option<String>>,
    /// Optional start-up steps the devices did not support.
    skipped: Vec<String>,
}

impl std::fmt::Debug for CanopenHal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CanopenHal")
            .field("bus", &self.s.bus.to_string())
            .field(
                "nodes",
                &self.devices.iter().map(|d| d.node).collect::<Vec<_>>(),
            )
            .field("lifecycle", &self.lifecycle.as_str())
            .finish()
    }
}

impl CanopenHal {
    /// Open the bus and bring both devices up (see the module docs). Blocks for at most
    /// `boot_timeout_s` plus a few SDO timeouts.
    pub fn connect(s: CanopenSettings) -> Result<CanopenHal, StartupError> {
        Self::connect_logged(s).map_err(|f| f.error)
    }

    /// [`CanopenHal::connect`], and on failure also every frame of the attempt (for the
    /// log: a failed start-up is recorded like a trip, see [`StartupFailure`]).
    pub fn connect_logged(s: CanopenSettings) -> Result<CanopenHal, StartupFailure> {
        Self::connect_until(s, None)
    }

    /// [`CanopenHal::connect_logged`] that ends early when `stop` is set (SIGINT / SIGTERM):
    /// every blocking phase of the start-up checks it at least once per master heartbeat
    /// period and ends with [`StartupError::Stopped`] (the valve back to HOLD if it was being
    /// enabled).
    pub fn connect_until(
        s: CanopenSettings,
        stop: Option<Arc<AtomicBool>>,
    ) -> Result<CanopenHal, StartupFailure> {
        Self::connect_with(s, None, stop, Arc::new(MonotonicClock::new()))
    }

    /// [`CanopenHal::connect_until`] on `bus` (`None`: the bus at `s.bus` is opened once the
    /// settings are checked) with the caller's `clock`: every timeout of the start-up, ehactl's
    /// heartbeat, the frames' times and the heartbeat consumers' receive stamps come from it
    /// (see [`crate::clock`]; a [`crate::clock::ManualClock`] makes them simulated time).
    /// [`CanopenHal::new_with`], then configure and activate.
    pub fn connect_with(
        s: CanopenSettings,
        bus: Option<Box<dyn CanBus>>,
        stop: Option<Arc<AtomicBool>>,
        clock: Arc<dyn Clock>,
    ) -> Result<CanopenHal, StartupFailure> {
        let mut hal = Self::new_with(s, bus, stop, clock);
        match hal.configure_step().and_then(|()| hal.activate_step()) {
            Ok(()) => Ok(hal),
            Err(e) => Err(hal.fail(e)),
        }
    }

    /// An unconfigured backend for the bus at `s.bus`: no bus I/O, nothing checked yet
    /// (configure checks the settings first, [`CanopenHal::check_settings`]). Then
    /// [`Hal::configure`] and [`Hal::activate`]; [`CanopenHal::connect`] does all three.
    pub fn new(s: CanopenSettings) -> CanopenHal {
        Self::new_with(s, None, None, Arc::new(MonotonicClock::new()))
    }

    /// [`CanopenHal::new`] with the stop request `stop` (SIGINT / SIGTERM), honoured by every
    /// blocking phase of [`Hal::configure`] and [`Hal::activate`] as by
    /// [`CanopenHal::connect_until`]: what `ehactl run --hal canopen` hands to the session,
    /// which brings it up.
    pub fn new_until(s: CanopenSettings, stop: Option<Arc<AtomicBool>>) -> CanopenHal {
        Self::new_with(s, None, stop, Arc::new(MonotonicClock::new()))
    }

    /// [`CanopenHal::new`] on `bus` (`None`: configure opens the bus at `s.bus`), with the
    /// stop request `stop` (see [`CanopenHal::connect_until`]) and the caller's `clock` (see
    /// [`CanopenHal::connect_with`]).
    pub fn new_with(
        s: CanopenSettings,
        bus: Option<Box<dyn CanBus>>,
        stop: Option<Arc<AtomicBool>>,
        clock: Arc<dyn Clock>,
    ) -> CanopenHal {
        let c = &s.canopen;
        let t_start = clock.now_ns();
        CanopenHal {
            sync: SyncProducer::with_counter(1.0 / c.sync_rate_hz, c.sync_counter_overflow, 1),
            master_hb: CanFrame::std(
                HEARTBEAT_BASE + u16::from(c.master_node_id),
                [0x05], // OPERATIONAL (CiA 301 7.2.8.3.2.1)
            ),
            master_hb_period_ns: u64::from(c.master_heartbeat_ms) * 1_000_000,
            master_hb_next_ns: 0,
            devices: Vec::new(),
            cmd: 0,
            lifecycle: Lifecycle::Unconfigured,
            given_bus: bus,
            stop,
            st: Startup::new(&[], s.verbose, clock.clone()),
            t_start,
            plan: None,
            pending: None,
            phase: "the bus connection",
            failure: None,
            startup_failed: false,
            shared: Arc::new(IoShared::new(clock, t_start)),
            frame_log: Arc::new(FrameLog::new(FRAME_LOG)),
            rxq: Arc::new(ArrayQueue::new(RX_QUEUE)),
            txq: Arc::new(ArrayQueue::new(TX_QUEUE)),
            rx_thread: None,
            tx_thread: None,
            tx_waker: None,
            bus_after_stop: None,
            startup_frames: Vec::new(),
            started: false,
            last_write_t: None,
            meas: Measurements::UNMEASURED,
            cmd_state: None,
            first_tpdo: false,
            loop_t0: None,
            grace_s: f64::from(c.heartbeat_timeout_ms) * 1e-3,
            hb_timeout_ns: i64::from(c.heartbeat_timeout_ms) * 1_000_000,
            fault: None,
            wrong_dlc: 0,
            unknown: 0,
            emcy_count: 0,
            last_emcy: None,
            safe_stop_result: None,
            startup_s: 0.0,
            names: Vec::new(),
            skipped: Vec::new(),
            s,
        }
    }

    /// The failure of the last [`Hal::configure`] / [`Hal::activate`] that returned
    /// [`HalError::Startup`]: the start-up error with every frame of the attempt (for the
    /// log, as [`CanopenHal::connect_logged`] returns it). Taken: a second call gives `None`.
    pub fn take_startup_failure(&mut self) -> Option<StartupFailure> {
        self.failure.take()
    }

    /// A configure / activate failed with `error`: the backend is `Failed`; the failure
    /// with every frame of the attempt, times relative to now.
    fn fail(&mut self, error: StartupError) -> StartupFailure {
        self.lifecycle = Lifecycle::Failed;
        self.startup_failed = true;
        self.pending = None;
        let failed_at = self.st.clock.now_ns();
        self.st.merge();
        StartupFailure {
            error,
            frames: self
                .st
                .frames
                .iter()
                .map(|(at, f, tx)| {
                    let before = failed_at.saturating_sub(*at);
                    record(f, -(before.min(i64::MAX as u64) as i64), *tx)
                })
                .collect(),
            elapsed_s: failed_at.saturating_sub(self.t_start) as f64 * 1e-9,
        }
    }

    /// The call `call` needs state `want`: [`HalError::Lifecycle`] otherwise.
    #[inline]
    fn expect(&self, call: &'static str, want: Lifecycle) -> Result<(), HalError> {
        if self.lifecycle == want {
            Ok(())
        } else {
            Err(HalError::Lifecycle {
                call,
                state: self.lifecycle.as_str(),
            })
        }
    }

    /// The checks of the settings that need no bus (config consistency, SYNC rate against
    /// the control rate, valve full scale, closed-centre safe command, the EDS / DCF files
    /// and the start-up plan made from them): run by [`CanopenHal::connect`] first, and by
    /// the CLI before it opens the log.
    pub fn check_settings(s: &CanopenSettings) -> Result<Plan, StartupError> {
        let c = s.canopen.clone();
        c.validate()
            .map_err(|e| StartupError::Settings(e.to_string()))?;
        if c.sync_rate_hz > s.control_rate_hz * (1.0 + 1e-9) {
            return Err(StartupError::Settings(format!(
                "canopen.sync_rate_hz = {} Hz exceeds run.control_rate_hz = {} Hz; SYNC is produced by the control cycle, expected sync_rate_hz <= control rate",
                c.sync_rate_hz, s.control_rate_hz
            )));
        }
        // SYNC is produced by the control cycle: a SYNC period that is no whole number of
        // control periods would jitter by one control period (e.g. 400/600 µs for 2 kHz SYNC
        // at 5 kHz control), so it is refused.
        let ratio = s.control_rate_hz / c.sync_rate_hz;
        if (ratio - ratio.round()).abs() > 1e-9 * ratio.max(1.0) {
            return Err(StartupError::Settings(format!(
                "canopen.sync_rate_hz = {} Hz does not divide run.control_rate_hz = {} Hz ({ratio:.4} control periods per SYNC); SYNC is sent by the control cycle and would jitter by one control period; expected control_rate_hz / sync_rate_hz to be a whole number, e.g. {} Hz",
                c.sync_rate_hz,
                s.control_rate_hz,
                s.control_rate_hz / ratio.round().max(1.0)
            )));
        }
        if !(s.command_full_scale.is_finite() && s.command_full_scale > 0.0) {
            return Err(StartupError::Settings(format!(
                "valve.command_full_scale = {} V; expected a finite number > 0 V",
                s.command_full_scale
            )));
        }
        // Closed centre only: the safe stop sends this setpoint and then HOLD, where the valve
        // controls to the hold setpoint 0x6314:01 = 0; any other value would open the valve
        // on a trip (a huge value saturates to a fully open spool).
        let safe_sp = cia408::setpoint_from_command(s.safe_command, s.command_full_scale);
        if !s.safe_command.is_finite() || safe_sp != 0 {
            return Err(StartupError::Settings(format!(
                "supervisor.safe_command = {} V is no closed-centre command for the CAN valve: it is spool setpoint {safe_sp} of ±{} (expected 0, i.e. |safe_command| < {:.3e} V with valve.command_full_scale = {} V)",
                s.safe_command,
                cia408::FULL_SCALE,
                s.command_full_scale / f64::from(cia408::FULL_SCALE) / 2.0,
                s.command_full_scale
            )));
        }
        Plan::new(s)
    }

    /// configure (see [`crate::startup`]): the settings, the bus, the devices up to NMT
    /// OPERATIONAL with the valve not enabled. Unconfigured → Configured.
    fn configure_step(&mut self) -> Result<(), StartupError> {
        self.t_start = self.st.clock.now_ns();
        self.phase = "the settings check";
        let plan = Self::check_settings(&self.s)?;
        self.phase = "the bus connection";
        let bus = match self.given_bus.take() {
            Some(b) => b,
            None => transport::open(&self.s.bus, Duration::from_secs(3))?,
        };
        let mut b = Bringup::open(
            &self.s,
            bus,
            plan.clone(),
            &mut self.st,
            self.master_hb,
            self.stop.clone(),
        );
        let r = b.configure().and_then(|()| b.start());
        self.phase = b.phase();
        let (bus, _, names, skipped) = b.into_parts();
        r?;
        self.plan = Some(plan);
        self.pending = Some(Pending {
            bus,
            names,
            skipped,
        });
        self.lifecycle = Lifecycle::Configured;
        Ok(())
    }

    /// activate (see [`crate::startup`]): the valve to ACTIVE, the priming SYNC, the I/O
    /// threads. Configured → Active. After a deactivate the start-up bus is the one the I/O
    /// threads handed back.
    fn activate_step(&mut self) -> Result<(), StartupError> {
        let (bus, names, skipped) = match self.pending.take() {
            Some(p) => (p.bus, p.names, p.skipped),
            None => {
                // re-activation: the bus the I/O threads handed back, a new start-up bus
                self.t_start = self.st.clock.now_ns();
                let bus = self.bus_after_stop.take().ok_or_else(|| {
                    StartupError::Bus(BusError::new(
                        BusErrorKind::Io,
                        "the bus is gone (it failed during the run before)",
                    ))
                })?;
                let b = Bringup::open(
                    &self.s,
                    bus,
                    self.plan.clone().expect("configured before"),
                    &mut self.st,
                    self.master_hb,
                    self.stop.clone(),
                );
                let (bus, _, _, _) = b.into_parts();
                (
                    bus,
                    std::mem::take(&mut self.names),
                    std::mem::take(&mut self.skipped),
                )
            }
        };
        let plan = self.plan.clone().expect("configured before");
        let mut b = Bringup::resume(&self.s, bus, plan, &mut self.st, names, skipped);
        let r = b.activate();
        self.phase = b.phase();
        let Activated { mut meas } = r?;
        if self.s.verbose {
            eprintln!(
                "canopen: start-up done in {:.2} s; first position {:.6} m",
                b.now().saturating_sub(self.t_start) as f64 * 1e-9,
                meas.position
            );
        }
        meas.t = 0.0;
        let names = std::mem::take(&mut b.names);
        let skipped = std::mem::take(&mut b.skipped);
        let (bus, _, _, _) = b.into_parts();
        self.start_io(bus.inner, meas, names)?;
        self.skipped = skipped;
        Ok(())
    }

    /// The I/O threads and the run-time state, after a successful activation (the valve
    /// ACTIVE, the priming SYNC answered with `meas`): the backend is Active.
    fn start_io(
        &mut self,
        bus: Box<dyn CanBus>,
        meas: Measurements,
        names: Vec<Option<String>>,
    ) -> Result<(), StartupError> {
        let c = self.s.canopen.clone();
        let plan = self.plan.as_ref().expect("configured before");
        let hb_ns = u64::from(c.heartbeat_timeout_ms) * 1_000_000;
        self.devices = RunDevice::from_plan(plan, hb_ns);
        self.cmd = plan.commanded;
        let shared = Arc::new(IoShared::new(self.st.clock.clone(), self.t_start));
        // frames a previous activation left in the queues are no part of this one
        while self.rxq.pop().is_some() {}
        while self.txq.pop().is_some() {}
        self.spawn_io(bus, &shared)?;
        // the devices were OPERATIONAL with heartbeats at the end of start-up: the windows
        // start now (the receive clock), the devices' next heartbeats come through the RX queue
        let armed_at = shared.mono(shared.now());
        for d in self.devices.iter_mut() {
            d.hb.on_heartbeat(NmtState::Operational, armed_at);
        }
        self.startup_s = shared.now().saturating_sub(self.t_start) as f64 * 1e-9;
        self.shared = shared;
        // the start-up's priming SYNC was SYNC 1 (for the SYNC counter)
        self.sync = SyncProducer::with_counter(1.0 / c.sync_rate_hz, c.sync_counter_overflow, 1);
        self.master_hb_next_ns = 0;
        self.bus_after_stop = None;
        self.st.merge();
        self.startup_frames = std::mem::take(&mut self.st.frames);
        self.started = false;
        self.last_write_t = None;
        self.meas = meas;
        self.cmd_state = Some(ValveState::Active.as_str());
        self.first_tpdo = false;
        self.loop_t0 = None;
        self.fault = None;
        self.safe_stop_result = None;
        self.names = names;
        self.lifecycle = Lifecycle::Active;
        Ok(())
    }

    /// The RPDO1 of the commanded device for the command `u` (V). No allocation.
    #[inline]
    fn command_frame(&self, u: f64) -> CanFrame {
        let d = &self.devices[self.cmd];
        rpdo_frame(
            d.profile,
            d.node,
            d.rpdo_len.unwrap_or(0),
            u,
            self.s.command_full_scale,
        )
    }

    /// The RX and TX threads on `bus` (and a clone of it) with the state `shared`.
    fn spawn_io(
        &mut self,
        bus: Box<dyn CanBus>,
        shared: &Arc<IoShared>,
    ) -> Result<(), StartupError> {
        let master_hb = self.master_hb;
        let master_hb_period = Duration::from_millis(u64::from(self.s.canopen.master_heartbeat_ms));
        let keepalive = self.command_frame(0.0);
        let tx_bus = bus.try_clone_bus()?;
        let spawn_err = |e: std::io::Error| {
            StartupError::Bus(BusError::new(
                BusErrorKind::Io,
                format!("cannot start a CAN I/O thread: {e}"),
            ))
        };
        let rx_thread = {
            let (sh, q, lg) = (shared.clone(), self.rxq.clone(), self.frame_log.clone());
            std::thread::Builder::new()
                .name("ehactl-can-rx".into())
                .spawn(move || rx_loop(bus, &sh, &q, &lg))
                .map_err(spawn_err)?
        };
        let tx_thread = {
            let (sh, q, lg) = (shared.clone(), self.txq.clone(), self.frame_log.clone());
            std::thread::Builder::new()
                .name("ehactl-can-tx".into())
                .spawn(move || {
                    tx_loop(tx_bus, &sh, &q, &lg, master_hb, master_hb_period, keepalive)
                })
                .map_err(spawn_err)?
        };
        self.tx_waker = Some(tx_thread.thread().clone());
        self.rx_thread = Some(rx_thread);
        self.tx_thread = Some(tx_thread);
        Ok(())
    }

    #[inline]
    fn warn(&self, t: f64, what: &'static str, value: f64, count: u64) {
        if count <= MAX_WARNINGS {
            self.frame_log.push_event(Event {
                t,
                cycle: 0,
                severity: Severity::Warning,
                kind: EventKind::CanBus,
                channel: what,
                value,
                limit: f64::NAN,
                unit: "COB-ID",
            });
        }
    }

    #[inline]
    fn trip(
        &mut self,
        t: f64,
        code: u32,
        what: &'static str,
        value: f64,
        unit: &'static str,
    ) -> HalError {
        let e = HalError::Device { code, what };
        if self.fault.is_none() {
            self.frame_log.push_event(Event {
                t,
                cycle: 0,
                severity: Severity::Warning,
                kind: EventKind::CanBus,
                channel: what,
                value,
                limit: f64::NAN,
                unit,
            });
            self.fault = Some(e);
        }
        e
    }

    /// Index of the device with node id `node`.
    #[inline]
    fn dev_of(&self, node: u32) -> Option<usize> {
        self.devices.iter().position(|d| u32::from(d.node) == node)
    }

    /// PDO age check of a synchronous TPDO of device `i` (any DLC: it answers one SYNC).
    /// Its age is the number of SYNCs the cycle queued after the one it answers: 0 = before
    /// the next SYNC; ≥ 1 = late (counted); above `canopen.max_pdo_age_syncs` = trip. The
    /// cycle takes frames in once per control period, so ages are exact to one control
    /// period. A TPDO the device never sent counts as late for the rest of the run (CAN
    /// retransmits lost frames: a missing TPDO is a device fault).
    #[inline]
    fn pdo_age(&mut self, i: usize, t: f64) -> Result<(), HalError> {
        let max = self.s.canopen.max_pdo_age_syncs;
        let d = &mut self.devices[i];
        let age = d.pending_syncs.saturating_sub(1);
        d.pending_syncs = d.pending_syncs.saturating_sub(1);
        if age >= 1 {
            d.late += 1;
            d.max_age = d.max_age.max(age);
            if age > max {
                let (node, what) = (d.node, d.text.too_old);
                return Err(self.trip(t, u32::from(node), what, f64::from(age), "SYNC periods"));
            }
        }
        Ok(())
    }

    /// Handle one received frame in the cycle, by its function code (CiA 301 predefined
    /// connection set): TPDO1, heartbeat, EMCY of the devices; a late SDO response or any
    /// other COB-ID is counted and ignored.
    /// `rx_ns`: its receive time ([`IoShared::mono`]), from which the heartbeat consumer's
    /// window runs.
    #[inline]
    fn dispatch(&mut self, f: &CanFrame, t: f64, rx_ns: i64) -> Result<(), HalError> {
        let id = f.id;
        if f.extended {
            self.unknown += 1;
            self.warn(
                t,
                "unknown COB-ID (29-bit frame)",
                f64::from(id),
                self.unknown,
            );
            return Ok(());
        }
        let (base, node) = (id & 0x780, id & 0x7F);
        let dev = self.dev_of(node);
        let sends_tpdo = dev.is_some_and(|i| self.devices[i].tpdo_len.is_some());
        match (base as u16, dev) {
            (TPDO1_BASE, Some(i)) if sends_tpdo => {
                self.pdo_age(i, t)?;
                self.on_tpdo(i, f, t)
            }
            (HEARTBEAT_BASE, Some(i)) => self.on_heartbeat(f, t, rx_ns, i),
            (EMCY_BASE, Some(i)) if node != 0 => self.on_emcy(f, t, i),
            (0x580, Some(_)) => {
                // A late SDO response (e.g. after a start-up timeout): harmless.
                self.unknown += 1;
                self.warn(
                    t,
                    "unexpected SDO response during the run, ignored",
                    f64::from(id),
                    self.unknown,
                );
                Ok(())
            }
            _ => {
                self.unknown += 1;
                self.warn(t, "unknown COB-ID, ignored", f64::from(id), self.unknown);
                Ok(())
            }
        }
    }

    /// A frame of a known kind with another length: counted, warned, ignored.
    #[inline]
    fn wrong_dlc(&mut self, f: &CanFrame, t: f64, what: &'static str) {
        self.wrong_dlc += 1;
        self.warn(t, what, f64::from(f.id), self.wrong_dlc);
    }

    /// The TPDO1 of device `i`, decoded by its profile into the held measurements (the
    /// transducer: the position; the valve: the spool; a CiA 404 transmitter: a pressure).
    /// The transducer's stamps the sample time. A device whose TPDO reports a state in
    /// which the command does not act (the valve's status word: any state but ACTIVE) trips.
    #[inline]
    fn on_tpdo(&mut self, i: usize, f: &CanFrame, t: f64) -> Result<(), HalError> {
        let d = &self.devices[i];
        let (profile, what) = (d.profile, d.text.wrong_dlc);
        let data = f.payload();
        if Some(data.len()) != d.tpdo_len
            || profile
                .decode(&self.s.canopen, data, &mut self.meas)
                .is_err()
        {
            self.wrong_dlc(f, t, what);
            return Ok(());
        }
        if i == CLOCK_DEVICE {
            self.meas.t = t;
            self.first_tpdo = true;
        }
        let Some(st) = profile.tpdo_state(data) else {
            return Ok(());
        };
        if i == self.cmd {
            self.cmd_state = Some(st.name);
        }
        match st.trip {
            None => Ok(()),
            Some(why) => Err(self.trip(
                t,
                u32::from(st.word),
                why,
                f64::from(st.word),
                "status word",
            )),
        }
    }

    /// A heartbeat of device `i` (CiA 301 error control, 1 byte NMT state): fed to its
    /// consumer; a boot-up or any state but OPERATIONAL trips.
    #[inline]
    fn on_heartbeat(&mut self, f: &CanFrame, t: f64, rx_ns: i64, i: usize) -> Result<(), HalError> {
        if f.dlc != 1 {
            self.wrong_dlc(f, t, "wrong DLC on heartbeat (expected 1), ignored");
            return Ok(());
        }
        let node = f.id & 0x7F;
        let st = NmtState::from_byte(f.data[0]);
        if let Some(s) = st {
            self.devices[i].hb.on_heartbeat(s, rx_ns);
        }
        let text = self.devices[i].text;
        match st {
            None => {
                self.unknown += 1;
                self.warn(
                    t,
                    "heartbeat with an undefined NMT state, ignored",
                    f64::from(f.id),
                    self.unknown,
                );
            }
            Some(NmtState::Operational) => {}
            Some(NmtState::BootUp) => {
                return Err(self.trip(t, node, text.rebooted, f64::from(node), "node"));
            }
            Some(s) => {
                let state = f64::from(s as u8 as u32);
                return Err(self.trip(t, node, text.left_operational, state, "NMT state"));
            }
        }
        Ok(())
    }

    /// An EMCY of device `i` (CiA 301, 8 bytes): an error reset is warned, any other code
    /// trips.
    #[inline]
    fn on_emcy(&mut self, f: &CanFrame, t: f64, i: usize) -> Result<(), HalError> {
        let node = f.id & 0x7F;
        match Emcy::parse(node as u8, f.payload()) {
            Err(_) => self.wrong_dlc(f, t, "wrong DLC on EMCY (expected 8), ignored"),
            Ok(e) if e.is_reset() => {
                self.warn(t, "EMCY error reset (code 0x0000)", f64::from(f.id), 0);
            }
            Ok(e) => {
                self.emcy_count += 1;
                self.last_emcy = Some(e);
                let what = self.devices[i].text.emcy;
                return Err(self.trip(t, u32::from(e.code), what, f64::from(e.code), "EMCY code"));
            }
        }
        Ok(())
    }

    /// Stop the I/O threads and take the bus back (outside the cycle).
    fn stop_io(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(w) = &self.tx_waker {
            w.unpark();
        }
        if let Some(h) = self.tx_thread.take() {
            let _ = h.join();
        }
        if let Some(h) = self.rx_thread.take() {
            if let Ok(b) = h.join() {
                self.bus_after_stop = Some(b);
            }
        }
    }

    fn log_now(&self, f: &CanFrame, dir: Direction) {
        let t = self.shared.stamp(self.shared.now());
        self.frame_log.push(record(f, t, dir == Direction::Tx));
    }

    /// [`Hal::safe_stop`] between configure and the first activate: setpoint 0 and control
    /// word HOLD on the start-up bus (which keeps ehactl's heartbeat going while it waits).
    fn safe_stop_configured(&mut self) -> Result<(), HalError> {
        let Some(p) = self.pending.take() else {
            return Ok(());
        };
        let plan = self.plan.clone().expect("configured");
        let mut b = Bringup::resume(&self.s, p.bus, plan, &mut self.st, p.names, p.skipped);
        let r = b.safe_stop_checked("safe stop of the configured valve");
        let (bus, _, names, skipped) = b.into_parts();
        self.pending = Some(Pending {
            bus,
            names,
            skipped,
        });
        match r {
            Ok(m) => {
                self.safe_stop_result = Some(m);
                Ok(())
            }
            Err(m) => {
                eprintln!("ehactl: canopen: safe stop: {m}");
                self.safe_stop_result = Some(format!("failed: {m}"));
                Err(HalError::Device {
                    code: 0,
                    what: "safe stop not confirmed by the valve",
                })
            }
        }
    }

    /// After the I/O threads stopped: the commanded device's safe-stop control word (the
    /// valve: HOLD) by SDO on the bus they handed back; `Err` with why it was not confirmed.
    fn safe_stop_by_sdo(&mut self) -> Result<(), String> {
        let d = &self.devices[self.cmd];
        let (node, profile) = (d.node, d.profile);
        let failed = self.shared.failed.load(Ordering::Acquire);
        let Some(mut bus) = self.bus_after_stop.take().filter(|_| !failed) else {
            return Err(format!(
                "bus unavailable ({}); {} HOLD could not be commanded — the {} must fall back to its own safe state (heartbeat loss reaction)",
                self.shared
                    .error
                    .lock()
                    .ok()
                    .and_then(|e| e.clone())
                    .unwrap_or_else(|| "not connected".into()),
                profile.name(),
                profile.name()
            ));
        };
        let sdo_t = Duration::from_millis(u64::from(self.s.canopen.sdo_timeout_ms));
        let mut cl = SdoClient::new(node, sdo_t);
        let (index, sub) = profile.control_object();
        let cw = profile.safe_stop().unwrap_or(0);
        let req = cl.download(index, sub, &cw.to_le_bytes());
        let mut frames: Vec<(CanFrame, Direction)> = Vec::new();
        let r = sdo::transfer(&mut *bus, &mut cl, req, &*self.shared.clock, &mut |f, d| {
            frames.push((*f, d))
        });
        for (f, d) in &frames {
            self.log_now(f, *d);
        }
        self.bus_after_stop = Some(bus);
        r.map_err(|e| e.to_string())
    }

    /// `{key: value}` over the devices of the run (keys: their profiles' names).
    fn per_device(&self, value: impl Fn(&RunDevice) -> serde_json::Value) -> serde_json::Value {
        self.per_device_i(|i| value(&self.devices[i]))
    }

    /// [`CanopenHal::per_device`] by the device's index.
    fn per_device_i(&self, value: impl Fn(usize) -> serde_json::Value) -> serde_json::Value {
        let m: serde_json::Map<String, serde_json::Value> = (0..self.devices.len())
            .map(|i| (self.devices[i].key.clone(), value(i)))
            .collect();
        serde_json::Value::Object(m)
    }

    /// The lifecycle state: "unconfigured", "configured", "active" or "failed".
    pub fn lifecycle_state(&self) -> &'static str {
        self.lifecycle.as_str()
    }

    /// How long start-up took (s).
    pub fn startup_seconds(&self) -> f64 {
        self.startup_s
    }

    /// Bus load of the configured PDO set (fraction).
    pub fn bus_load(&self) -> f64 {
        self.s.canopen.bus_load().load
    }
}

/// How long the RX thread blocks for a frame before it looks at the stop flag again.
const RX_WAIT: Duration = Duration::from_millis(20);

fn rx_loop(
    mut bus: Box<dyn CanBus>,
    sh: &IoShared,
    q: &ArrayQueue<(CanFrame, i64)>,
    log: &FrameLog,
) -> Box<dyn CanBus> {
    let mut last_look_ns = sh.mono(sh.now());
    while !sh.stop.load(Ordering::Acquire) {
        // Nothing waiting at `t0`: every frame received before it is in the queue (the
        // heartbeat consumers judge silence up to there, see `read`); then block.
        let t0 = sh.mono(sh.now());
        sh.rx_gap_max_ns
            .fetch_max(t0 - last_look_ns, Ordering::Relaxed);
        last_look_ns = t0;
        let got = match bus.try_recv() {
            Ok(None) => {
                sh.drained_ns.store(t0, Ordering::Release);
                bus.recv_timeout(RX_WAIT)
            }
            r => r,
        };
        match got {
            Ok(Some(f)) => {
                let rx_ns = sh.mono(sh.now());
                log.push(record(
                    &f,
                    rx_ns - sh.zero_ns.load(Ordering::Relaxed),
                    false,
                ));
                sh.rx_frames.fetch_add(1, Ordering::Relaxed);
                if q.push((f, rx_ns)).is_err() {
                    sh.rx_overflow.fetch_add(1, Ordering::Relaxed);
                }
            }
            Ok(None) => {}
            Err(e) if e.kind == BusErrorKind::Protocol => {
                let n = sh.transport_errors.fetch_add(1, Ordering::Relaxed) + 1;
                if n <= MAX_WARNINGS {
                    eprintln!("ehactl: canopen: malformed bus message ignored: {e}");
                    log.push_event(Event {
                        t: sh.stamp(sh.now()) as f64 * 1e-9,
                        cycle: 0,
                        severity: Severity::Warning,
                        kind: EventKind::CanBus,
                        channel: "malformed socketcand message, ignored",
                        value: n as f64,
                        limit: f64::NAN,
                        unit: "count",
                    });
                }
            }
            Err(e) => {
                sh.fail(e.message);
                break;
            }
        }
    }
    // the stretch since the last look counts too (a stall just before the stop)
    sh.rx_gap_max_ns
        .fetch_max(sh.mono(sh.now()) - last_look_ns, Ordering::Relaxed);
    bus
}

fn tx_loop(
    mut bus: Box<dyn CanBus>,
    sh: &IoShared,
    q: &ArrayQueue<CanFrame>,
    log: &FrameLog,
    master_hb: CanFrame,
    master_hb_period: Duration,
    keepalive: CanFrame,
) -> Box<dyn CanBus> {
    let period_ns = u64::try_from(master_hb_period.as_nanos()).unwrap_or(u64::MAX);
    let mut next_hb = sh.now();
    loop {
        // Until the first cycle runs (the run loop still sets up), ehactl's heartbeat and the
        // valve's setpoint RPDO (0, as primed) come from here, so that the devices' consumers
        // (0x1016) and the valve's RPDO deadline (0x1400:05) do not fire in the hand-over.
        if !sh.cycle_started.load(Ordering::Acquire) && sh.now() >= next_hb {
            next_hb = sh.now().saturating_add(period_ns);
            for f in [&master_hb, &keepalive] {
                if let Err(e) = bus.send(f) {
                    sh.fail(e.message);
                    return bus;
                }
                log.push(record(f, sh.stamp(sh.now()), true));
                sh.tx_frames.fetch_add(1, Ordering::Relaxed);
            }
        }
        while let Some(f) = q.pop() {
            match bus.send(&f) {
                Ok(()) => {
                    log.push(record(&f, sh.stamp(sh.now()), true));
                    sh.tx_frames.fetch_add(1, Ordering::Relaxed);
                }
                Err(e) => {
                    sh.fail(e.message);
                    return bus;
                }
            }
        }
        if sh.stop.load(Ordering::Acquire) {
            return bus;
        }
        std::thread::park_timeout(Duration::from_millis(5));
    }
}

impl Hal for CanopenHal {
    fn name(&self) -> &'static str {
        "canopen"
    }

    /// Drains received frames (TPDOs, heartbeats, EMCY) and returns the held samples.
    /// Real-time safe: lock-free queue pops, no allocation (except the one-time hand-over
    /// of the start-up frames to the log queue in the first cycle, which does not allocate).
    fn read(&mut self, t: f64, _period: f64) -> Result<Measurements, HalError> {
        self.expect("read", Lifecycle::Active)?;
        if !self.started {
            self.started = true;
            self.shared.cycle_started.store(true, Ordering::Release);
            let zero = self.shared.mono(self.shared.now());
            self.shared.zero_ns.store(zero, Ordering::Relaxed);
            for (at, f, tx) in self.startup_frames.drain(..) {
                let tn = self.shared.mono(at) - zero;
                self.frame_log.push(record(&f, tn, tx));
            }
        }
        // Heartbeat consumers (CiA 301 §7.2.8.3.2.2) time from the reception of each
        // heartbeat (the RX thread's stamp), checked against the present time on the same
        // clock — not loop time, which lags the wall clock when the pacer skips deadlines
        // (a consumer counting loop time trips late by the skipped time). `now` is taken
        // before the queue is drained, so every frame taken in below was received before it.
        // Silence is judged only up to the moment the RX thread last found the bus drained
        // (loaded before the queue is drained: the frames before it are in the queue), but
        // at least up to one consumer time before now: a heartbeat waiting unread in the
        // receive buffer while the RX thread was not scheduled has been received and is no
        // loss (a whole-process stall of 72 ms tripped the documented CAN demo this way,
        // BENCHMARKS.md "CAN demo"); an RX thread stalled for longer delays the detection
        // by at most one consumer time, and the staleness check sees its missing TPDOs.
        let now_ns = self.shared.mono(self.shared.now());
        let drained_ns = self.shared.drained_ns.load(Ordering::Acquire);
        let judged_ns = now_ns.min(drained_ns.max(now_ns.saturating_sub(self.hb_timeout_ns)));
        if let Some(e) = self.fault {
            return Err(e);
        }
        if self.shared.failed.load(Ordering::Acquire) {
            return Err(self.trip(t, 0, "CAN bus connection lost", f64::NAN, ""));
        }
        if self.shared.rx_overflow.load(Ordering::Relaxed) > 0 {
            return Err(self.trip(t, 0, "CAN receive queue overflow", f64::NAN, ""));
        }
        while let Some((f, rx_ns)) = self.rxq.pop() {
            self.dispatch(&f, t, rx_ns)?;
        }
        // Start-up grace: until the transducer's first TPDO of the loop has arrived, at most
        // `heartbeat_timeout_ms` of loop time, the primed position counts as fresh, so the
        // supervisor's staleness check starts with the first PDO (a device answering the
        // first SYNCs late on a loaded machine is no stale sensor). Bounded: after the grace
        // the sample time stops and `supervisor.stale_timeout` trips as usual.
        if !self.first_tpdo {
            let t0 = *self.loop_t0.get_or_insert(t);
            if t - t0 <= self.grace_s {
                self.meas.t = t;
            }
        }
        for i in 0..self.devices.len() {
            let d = &mut self.devices[i];
            if let Some(HeartbeatEvent::Timeout { silent_ns }) = d.hb.process(judged_ns) {
                let (node, what) = (u32::from(d.node), d.text.heartbeat_lost);
                return Err(self.trip(t, node, what, silent_ns as f64 * 1e-9, "s"));
            }
        }
        Ok(self.meas)
    }

    /// Converts the command to the spool setpoint; when SYNC is due, queues RPDO1 then
    /// SYNC for the TX thread. Real-time safe (lock-free push + unpark).
    fn write(&mut self, t: f64, _period: f64, command: f64) -> Result<(), HalError> {
        self.expect("write", Lifecycle::Active)?;
        if let Some(e) = self.fault {
            return Err(e);
        }
        let elapsed_ns = match self.last_write_t {
            None => 0,
            Some(l) => ((t - l).max(0.0) * 1e9).round() as u64,
        };
        self.last_write_t = Some(t);
        // ehactl's heartbeat comes from the control cycle itself: if the cycle stops (crash,
        // SIGKILL, hang), the devices' consumers (0x1016) notice within their consumer time.
        // It is due by the caller's clock, as the devices' consumers time it — not by loop
        // time, which lags the clock by every deadline the pacer skips: 20 ms of loop time
        // measured 51 ms of wall time on an idle 2-core VM (BENCHMARKS.md "CAN demo").
        // A cycle later than one period sends one heartbeat and the period restarts there.
        let now = self.shared.now();
        if now >= self.master_hb_next_ns {
            let on_grid = self
                .master_hb_next_ns
                .saturating_add(self.master_hb_period_ns);
            self.master_hb_next_ns = if on_grid > now {
                on_grid
            } else {
                now.saturating_add(self.master_hb_period_ns)
            };
            if self.txq.push(self.master_hb).is_err() {
                return Err(self.trip(t, 0, "CAN transmit queue overflow", f64::NAN, ""));
            }
            if let Some(w) = &self.tx_waker {
                w.unpark();
            }
        }
        if self.sync.process(elapsed_ns) {
            let rpdo = self.command_frame(command);
            for d in self.devices.iter_mut() {
                d.pending_syncs = d.pending_syncs.saturating_add(1);
            }
            if self.txq.push(rpdo).is_err() || self.txq.push(self.sync.frame()).is_err() {
                return Err(self.trip(t, 0, "CAN transmit queue overflow", f64::NAN, ""));
            }
            if let Some(w) = &self.tx_waker {
                w.unpark();
            }
        }
        Ok(())
    }

    /// Unconfigured → Configured: the settings check, the bus, the CANopen configuration
    /// and NMT start; the valve is not enabled (see the module docs). On failure the backend
    /// is Failed and [`CanopenHal::take_startup_failure`] has the reason and the frames.
    fn configure(&mut self) -> Result<(), HalError> {
        self.expect("configure", Lifecycle::Unconfigured)?;
        self.configure_step().map_err(|e| {
            let f = self.fail(e);
            self.failure = Some(f);
            HalError::Startup { what: self.phase }
        })
    }

    /// Configured → Active: the valve to ACTIVE, the priming SYNC, the I/O threads (see
    /// the module docs). On failure the backend is Failed (a valve that was being enabled is
    /// back in HOLD with setpoint 0) and [`CanopenHal::take_startup_failure`] has the reason.
    fn activate(&mut self) -> Result<(), HalError> {
        self.expect("activate", Lifecycle::Configured)?;
        self.activate_step().map_err(|e| {
            let f = self.fail(e);
            self.failure = Some(f);
            HalError::Startup { what: self.phase }
        })
    }

    /// Active → Configured: what [`Hal::safe_stop`] does in Active (setpoint for
    /// `safe_command` + SYNC, the I/O threads stopped, control word HOLD). In any other state
    /// a [`HalError::Lifecycle`] error, and nothing is sent: in Configured the valve was
    /// never enabled (or is already out of ACTIVE), so there is nothing to undo.
    fn deactivate(&mut self, safe_command: f64) -> Result<(), HalError> {
        self.expect("deactivate", Lifecycle::Active)?;
        self.safe_stop(safe_command)
    }

    /// In Active: RPDO setpoint for `command` + SYNC, stop the I/O threads, valve control
    /// word HOLD by SDO; then Configured (Failed when the valve did not confirm). Blocks for
    /// at most two SYNC periods plus one SDO timeout. In Configured: setpoint 0 and control
    /// word HOLD (by the start-up bus before the first activation, by SDO after a
    /// deactivation). Unconfigured or after a failed configure / activate: nothing sent (the
    /// valve was never commanded, or the failed start-up already returned a valve it had
    /// enabled to HOLD), `Ok`. After an unconfirmed safe stop: the HOLD by SDO again.
    fn safe_stop(&mut self, command: f64) -> Result<(), HalError> {
        match self.lifecycle {
            Lifecycle::Unconfigured => {
                self.safe_stop_result = Some("not sent: the backend was never configured".into());
                return Ok(());
            }
            Lifecycle::Failed if self.startup_failed => {
                if self.safe_stop_result.is_none() {
                    self.safe_stop_result = Some(
                        "not sent: the start-up failed (a valve it had enabled was returned to HOLD)"
                            .into(),
                    );
                }
                return Ok(());
            }
            Lifecycle::Configured if self.pending.is_some() => {
                return self.safe_stop_configured();
            }
            _ => {}
        }
        let rpdo = self.command_frame(command);
        if self.tx_thread.is_some() && !self.shared.failed.load(Ordering::Acquire) {
            let _ = self.txq.push(rpdo);
            let _ = self.txq.push(sync::frame_with_counter(
                self.s.canopen.sync_counter_overflow,
                2 + self.sync.count(),
            ));
            if let Some(w) = &self.tx_waker {
                w.unpark();
            }
            self.shared.clock.sleep(Duration::from_secs_f64(
                (2.0 / self.s.canopen.sync_rate_hz).min(0.05),
            ));
        }
        self.stop_io();
        let d = &self.devices[self.cmd];
        let (name, cw) = (d.profile.name(), d.profile.safe_stop().unwrap_or(0));
        match self.safe_stop_by_sdo() {
            Ok(()) => {
                self.safe_stop_result = Some(format!(
                    "RPDO1 {:02X?} (command {command} V) and control word HOLD (0x{cw:04X}) sent to the {name}",
                    rpdo.payload()
                ));
                self.lifecycle = Lifecycle::Configured;
                Ok(())
            }
            Err(m) => {
                eprintln!("ehactl: canopen: safe stop: {m}");
                self.safe_stop_result = Some(format!("failed: {m}"));
                self.lifecycle = Lifecycle::Failed;
                Err(HalError::Device {
                    code: 0,
                    what: "safe stop not confirmed by the valve",
                })
            }
        }
    }

    fn frame_log(&self) -> Option<Arc<FrameLog>> {
        Some(self.frame_log.clone())
    }

    /// [`CanopenHal::take_startup_failure`] as the backend-neutral report.
    fn take_startup_report(&mut self) -> Option<StartupReport> {
        self.take_startup_failure().map(StartupFailure::report)
    }

    fn report(&self) -> Option<serde_json::Value> {
        let l = self.s.canopen.bus_load();
        let sh = &self.shared;
        Some(serde_json::json!({
            "bus": self.s.bus.to_string(),
            "bus_load_percent": l.load * 100.0,
            "bus_time_per_sync_us": l.time_per_sync_s * 1e6,
            "sync_rate_hz": self.s.canopen.sync_rate_hz,
            "syncs_sent": self.sync.count(),
            "sync_counter_overflow": self.s.canopen.sync_counter_overflow,
            "pdo_late": self.per_device(|d| d.late.into()),
            "pdo_max_age_syncs": self.per_device(|d| d.max_age.into()),
            "can_rx_frames": sh.rx_frames.load(Ordering::Relaxed),
            "can_tx_frames": sh.tx_frames.load(Ordering::Relaxed),
            "can_wrong_dlc": self.wrong_dlc,
            "can_unknown_cob_id": self.unknown,
            "can_transport_errors": sh.transport_errors.load(Ordering::Relaxed),
            "can_rx_overflow": sh.rx_overflow.load(Ordering::Relaxed),
            "can_rx_gap_max_us": sh.rx_gap_max_ns.load(Ordering::Relaxed) as f64 * 1e-3,
            "can_log_frames_dropped": self.frame_log.dropped(),
            "can_bus_error": sh.error.lock().ok().and_then(|e| e.clone()),
            "emcy_count": self.emcy_count,
            "last_emcy_code": self.last_emcy.map(|e| e.code),
            "valve_state": self.cmd_state,
            "startup_s": self.startup_s,
            "device_names": self.per_device_i(|i| self.names.get(i).cloned().flatten().into()),
            "startup_skipped": self.skipped,
            "safe_stop": self.safe_stop_result,
        }))
    }
}

/// A rig released without its safe stop (an error of the session before the loop ran, such
/// as a log that cannot be created or a plant section the plant refuses, or a panic that
/// unwinds past the loop) is safe-stopped here, with the configured safe command
/// (`supervisor.safe_command`, closed centre by [`CanopenHal::check_settings`]): the RPDO
/// setpoint 0 and a SYNC, then control word HOLD, as at the end of every run. Without it
/// the valve would stay ACTIVE at its last setpoint until its consumer of ehactl's heartbeat
/// (0x1016) timed out. After a [`Hal::safe_stop`], successful or not, only the I/O threads
/// are stopped.
///
/// Only an Active backend is safe-stopped: a Configured one never enabled the valve (or
/// already took it out of ACTIVE), and dropping it only ends ehactl's heartbeat, so that the
/// devices' consumers (0x1016) time out and they go to their fault reaction.
impl Drop for CanopenHal {
    fn drop(&mut self) {
        if self.lifecycle == Lifecycle::Active && self.safe_stop_result.is_none() {
            let _ = self.safe_stop(self.s.safe_command);
        }
        self.stop_io();
    }
}

/// SDO response COB-ID of `node` (for tools and tests).
pub fn sdo_response_id(node: u8) -> u16 {
    SDO_TX_BASE + u16::from(node)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::BusUrl;
    use crate::clock::ManualClock;
    use crate::simbus::SimBus;
    use ehactl_types::canopen::CanopenConfig;

    const MS: u64 = 1_000_000;

    fn settings(c: CanopenConfig) -> CanopenSettings {
        CanopenSettings {
            bus: BusUrl::parse("socketcand://127.0.0.1:1/can0").unwrap(),
            canopen: c,
            command_full_scale: 10.0,
            control_rate_hz: 5000.0,
            safe_command: 0.0,
            verbose: false,
            config_dir: None,
        }
    }

    /// A HAL with its I/O threads on simulated time, as after a start-up that began at the
    /// clock's present reading and took `startup` (default config; the bus's receive queue
    /// for the test to fill); with the config and ehactl's heartbeat frame.
    fn spawned_after_startup(
        clock: &Arc<ManualClock>,
        startup: Duration,
    ) -> (
        CanopenHal,
        Arc<std::sync::Mutex<std::collections::VecDeque<CanFrame>>>,
        CanopenConfig,
        CanFrame,
    ) {
        spawned_with(clock, startup, CanopenConfig::default())
    }

    /// [`spawned_after_startup`] with the config `c`.
    fn spawned_with(
        clock: &Arc<ManualClock>,
        startup: Duration,
        c: CanopenConfig,
    ) -> (
        CanopenHal,
        Arc<std::sync::Mutex<std::collections::VecDeque<CanFrame>>>,
        CanopenConfig,
        CanFrame,
    ) {
        let bus = SimBus::new(clock.clone(), false);
        let rx = bus.rx.clone();
        let mut hal = CanopenHal::new_with(settings(c.clone()), None, None, clock.clone());
        hal.t_start = clock.now_ns();
        clock.advance(startup);
        let meas = Measurements {
            t: 0.0,
            force: f64::NAN,
            position: 0.1,
            p_a: f64::NAN,
            p_b: f64::NAN,
            spool: 0.0,
        };
        let master_hb = CanFrame::std(HEARTBEAT_BASE + u16::from(c.master_node_id), [0x05]);
        assert_eq!(hal.master_hb, master_hb);
        let plan = CanopenHal::check_settings(&hal.s).unwrap();
        let names = vec![None; plan.devices.len()];
        hal.plan = Some(plan);
        hal.start_io(Box::new(bus), meas, names).unwrap();
        // Released without the drop's safe stop: nobody answers its SDO on this bus and the
        // clock moves only when the test moves it, so the SDO would wait forever (a failed
        // assertion would hang instead of failing). The drop's safe stop is tested against
        // the scripted rig (crates/canopen/tests/hal_rig.rs).
        hal.safe_stop_result = Some("not sent (unit test on simulated time)".into());
        (hal, rx, c, master_hb)
    }

    /// Wait (at most 10 s of real time) until the RX thread has taken in `frames` frames and
    /// looked at an empty bus at or after the clock's present reading.
    fn wait_for_rx(hal: &CanopenHal, clock: &ManualClock, frames: u64) {
        let want = hal.shared.mono(clock.now_ns());
        let waited = std::time::Instant::now();
        while hal.shared.drained_ns.load(Ordering::Acquire) < want
            || hal.shared.rx_frames.load(Ordering::Acquire) < frames
        {
            assert!(waited.elapsed() < Duration::from_secs(10), "RX thread idle");
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// The heartbeat consumers of the run on simulated time: the window of each device runs
    /// from the reception of its last heartbeat (the RX thread's stamp on the caller's clock),
    /// checked against the present time on that clock when the cycle reads — not against loop
    /// time, which here does not move at all. With `heartbeat_timeout_ms` = 60 a device is
    /// lost exactly when more than 60 ms have passed: not at 60 ms, at 60 ms + 1 ns.
    #[test]
    fn a_lost_heartbeat_trips_at_the_exact_simulated_time() {
        let clock = Arc::new(ManualClock::at(7_000 * MS));
        // the start-up took 2 s
        let (mut hal, rx, c, _) = spawned_after_startup(&clock, Duration::from_secs(2));
        assert_eq!(c.heartbeat_timeout_ms, 60);
        let (tr, va) = (c.transducer_node_id, c.valve_node_id);
        assert_eq!(hal.startup_seconds(), 2.0);
        // armed at 9.000 s; the valve's heartbeat arrives at 9.030 s
        clock.set(9_030 * MS);
        rx.lock()
            .unwrap()
            .push_back(CanFrame::std(HEARTBEAT_BASE + u16::from(va), [0x05]));
        wait_for_rx(&hal, &clock, 1);
        // the consumers judge silence up to the RX thread's last look at the bus
        // 9.060 s: the transducer has been silent for exactly 60 ms — not lost yet
        clock.set(9_060 * MS);
        wait_for_rx(&hal, &clock, 1);
        hal.read(0.0, 2e-4)
            .expect("60 ms of silence is within the consumer time");
        // 1 ns later it is lost; the valve (heard at 9.030 s, taken in only at 9.060 s) is not
        clock.set(9_060 * MS + 1);
        wait_for_rx(&hal, &clock, 1);
        match hal.read(0.0, 2e-4) {
            Err(HalError::Device { code, what }) => {
                assert_eq!(code, u32::from(tr));
                assert_eq!(what, "transducer heartbeat lost (consumer timeout)");
            }
            r => panic!("expected the transducer's heartbeat loss, got {r:?}"),
        }
        let ev = std::iter::from_fn(|| hal.frame_log.pop_event())
            .find(|e| e.channel == "transducer heartbeat lost (consumer timeout)")
            .expect("the trip is logged");
        assert_eq!((ev.value, ev.unit), (60_000_001.0 * 1e-9, "s")); // silent_ns in s
                                                                     // the valve's window ran from its reception at 9.030 s (2.030 s after the start):
                                                                     // lost after 9.090 s, not 60 ms after the cycle took its heartbeat in (9.120 s)
        let at = |ms: u64, extra: u64| ((ms - 7_000) * MS + extra) as i64;
        assert_eq!(hal.devices[1].hb.clone().process(at(9_090, 0)), None);
        assert_eq!(
            hal.devices[1].hb.clone().process(at(9_090, 1)),
            Some(HeartbeatEvent::Timeout {
                silent_ns: 60 * MS + 1
            })
        );
    }

    /// A third device of `[[canopen.devices]]` (a CiA 404 pressure transmitter at node 64)
    /// in the run on simulated time: its TPDO1 (INTEGER32 process value, 0 decimal digits)
    /// becomes `p_a` in Pa and nothing else; a TPDO1 of another length is counted and
    /// ignored under its own name; its heartbeat is consumed like the transducer's and the
    /// valve's: lost exactly at 60 ms + 1 ns of silence while the two others keep beating,
    /// and the run trips under its name and node.
    #[test]
    fn a_third_device_is_decoded_and_its_heartbeat_loss_trips() {
        use ehactl_types::canopen::CanopenDevice;
        let clock = Arc::new(ManualClock::at(7_000 * MS));
        let c = CanopenConfig {
            devices: vec![CanopenDevice {
                profile: "cia404".into(),
                node_id: 64,
                eds: String::new(),
            }],
            ..Default::default()
        };
        let (mut hal, rx, c, _) = spawned_with(&clock, Duration::from_secs(2), c);
        let (tr, va, pr) = (c.transducer_node_id, c.valve_node_id, 64u16);
        let push = |f: CanFrame| rx.lock().unwrap().push_back(f);
        // armed at 9.000 s; at 9.010 s the transmitter's TPDO1 reads 12 345 678 Pa
        clock.set(9_010 * MS);
        push(CanFrame::std(TPDO1_BASE + pr, 12_345_678i32.to_le_bytes()));
        wait_for_rx(&hal, &clock, 1);
        let m = hal.read(0.0, 2e-4).unwrap();
        assert_eq!(m.p_a, 12_345_678.0);
        assert_eq!((m.position, m.spool), (0.1, 0.0)); // the primed values, untouched
        assert!(m.p_b.is_nan() && m.force.is_nan());
        // a 2-byte TPDO1: counted, the held pressure stays
        push(CanFrame::std(TPDO1_BASE + pr, [1, 2]));
        wait_for_rx(&hal, &clock, 2);
        assert_eq!(hal.read(0.0, 2e-4).unwrap().p_a, 12_345_678.0);
        assert_eq!(hal.wrong_dlc, 1);
        assert!(std::iter::from_fn(|| hal.frame_log.pop_event())
            .any(|e| e.channel == "wrong DLC on pressure transmitter TPDO1 (expected 4), ignored"));
        // the transducer and the valve beat at 9.050 s; the transmitter stays silent
        clock.set(9_050 * MS);
        for n in [tr, va] {
            push(CanFrame::std(HEARTBEAT_BASE + u16::from(n), [0x05]));
        }
        wait_for_rx(&hal, &clock, 4);
        clock.set(9_060 * MS);
        wait_for_rx(&hal, &clock, 4);
        hal.read(0.0, 2e-4)
            .expect("60 ms of silence is within the consumer time");
        clock.set(9_060 * MS + 1);
        wait_for_rx(&hal, &clock, 4);
        match hal.read(0.0, 2e-4) {
            Err(HalError::Device { code, what }) => {
                assert_eq!(code, u32::from(pr));
                assert_eq!(
                    what,
                    "pressure transmitter heartbeat lost (consumer timeout)"
                );
            }
            r => panic!("expected the transmitter's heartbeat loss, got {r:?}"),
        }
        let rep = hal.report().unwrap();
        assert_eq!(rep["pdo_late"]["pressure transmitter"], 0);
        assert!(rep["device_names"]
            .as_object()
            .unwrap()
            .contains_key("pressure transmitter"));
    }

    /// A heartbeat that waits unread in the receive buffer because the RX thread was not
    /// scheduled (the whole process stalled on a loaded machine) has been received: the
    /// consumers do not count that stall as silence. They judge silence only up to the last
    /// moment the RX thread found the bus drained, or at most one consumer time before the
    /// present; a device that is really silent is still lost one consumer time after its
    /// last heartbeat once the RX thread runs.
    #[test]
    fn heartbeats_waiting_for_a_stalled_rx_thread_are_no_loss() {
        let clock = Arc::new(ManualClock::at(7_000 * MS));
        let (mut hal, rx, c, _) = spawned_after_startup(&clock, Duration::from_secs(2));
        assert_eq!(c.heartbeat_timeout_ms, 60);
        let (tr, va) = (c.transducer_node_id, c.valve_node_id);
        let wait_rx = |hal: &CanopenHal, frames: u64| wait_for_rx(hal, &clock, frames);
        // armed at 9.000 s; the RX thread has looked at the bus at 9.000 s
        wait_rx(&hal, 0);
        hal.read(0.0, 2e-4).unwrap();
        // the RX thread stalls (it blocks on the bus) while both heartbeats arrive at 9.030 s
        let mut held = rx.lock().unwrap();
        held.push_back(CanFrame::std(HEARTBEAT_BASE + u16::from(tr), [0x05]));
        held.push_back(CanFrame::std(HEARTBEAT_BASE + u16::from(va), [0x05]));
        // 9.091 s: 91 ms since the last heartbeat taken in, but the RX thread has not looked
        clock.set(9_091 * MS);
        hal.read(2e-4, 2e-4)
            .expect("heartbeats still in the receive buffer are no loss");
        // the RX thread runs again and takes them in (stamped 9.091 s)
        drop(held);
        wait_rx(&hal, 2);
        hal.read(4e-4, 2e-4).unwrap();
        // nothing more from either device: lost 60 ms + 1 ns after 9.091 s, as ever
        clock.set(9_151 * MS);
        wait_rx(&hal, 2);
        hal.read(6e-4, 2e-4)
            .expect("60 ms of silence is within the consumer time");
        clock.set(9_151 * MS + 1);
        wait_rx(&hal, 2);
        match hal.read(8e-4, 2e-4) {
            Err(HalError::Device { code, what }) => {
                assert_eq!(code, u32::from(tr));
                assert_eq!(what, "transducer heartbeat lost (consumer timeout)");
            }
            r => panic!("expected the transducer's heartbeat loss, got {r:?}"),
        }
    }

    /// ehactl's heartbeat keeps `master_heartbeat_ms` of the caller's clock while the loop
    /// lags it. With the wall-clock pacer's `skip` policy loop time advances one control
    /// period per cycle that runs, so after wake-up overruns 20 ms of loop time can span
    /// 100 ms of wall time — the devices' consumer time (0x1016) — and a heartbeat counted in
    /// loop time fell silent for it. Here each cycle advances loop time by 0.2 ms and the
    /// clock by 1 ms (4 deadlines skipped per cycle); then one cycle stalls 50 ms.
    #[test]
    fn the_master_heartbeat_keeps_its_period_on_the_clock_when_the_loop_lags() {
        let clock = Arc::new(ManualClock::at(7_000 * MS));
        let (mut hal, _, c, master_hb) = spawned_after_startup(&clock, Duration::ZERO);
        assert_eq!(c.master_heartbeat_ms, 20);
        // the I/O threads stopped: the test takes the cycle's frames off the TX queue itself
        hal.stop_io();
        hal.started = true;
        hal.shared.cycle_started.store(true, Ordering::Release);
        let mut beats: Vec<u64> = Vec::new();
        let mut k = 0u32;
        let mut cycle = |hal: &mut CanopenHal, beats: &mut Vec<u64>, step_ms: u64| {
            clock.advance(Duration::from_millis(step_ms));
            hal.write(f64::from(k) * 2e-4, 2e-4, 0.0).unwrap();
            k += 1;
            while let Some(f) = hal.txq.pop() {
                if f == master_hb {
                    beats.push((clock.now_ns() - 7_000 * MS) / MS);
                }
            }
        };
        for _ in 0..200 {
            cycle(&mut hal, &mut beats, 1);
        }
        // every 20 ms of the clock from the first cycle (at 1 ms), not every 100 cycles
        assert_eq!(beats, (0..10).map(|i| 1 + 20 * i).collect::<Vec<_>>());
        // a cycle 50 ms late sends one heartbeat (no burst for the missed ones), and the
        // period runs on from it
        beats.clear();
        cycle(&mut hal, &mut beats, 50);
        for _ in 0..45 {
            cycle(&mut hal, &mut beats, 1);
        }
        assert_eq!(beats, [250, 270, 290]);
    }

    /// The boot-up wait on simulated time: two devices that never answer. The probes, their
    /// SDO timeouts, ehactl's heartbeat and the final NoBoot fall on exact instants of the
    /// caller's clock: probes every BOOT_PROBE_EVERY (250 ms) after the last round ended, each
    /// unanswered probe aborted after min(sdo timeout, 250 ms), a last round at
    /// boot_timeout_s with the full SDO timeout; the heartbeat every master_heartbeat_ms.
    #[test]
    fn a_silent_rig_fails_the_boot_up_at_an_exact_simulated_time() {
        const MS: i64 = 1_000_000;
        let clock = Arc::new(ManualClock::at(42_000 * MS as u64));
        let bus = SimBus::new(clock.clone(), true);
        let sent = bus.sent.clone();
        let c = CanopenConfig {
            boot_timeout_s: 1.0,
            sdo_timeout_ms: 100,
            ..Default::default()
        };
        let (tr, va, master) = (c.transducer_node_id, c.valve_node_id, c.master_node_id);
        // on simulated time a wait that lets no time pass would spin for ever: bounded here
        let (done, result) = std::sync::mpsc::channel();
        let s = settings(c);
        let sim = clock.clone();
        std::thread::spawn(move || {
            let r = CanopenHal::connect_with(s, Some(Box::new(bus)), None, sim).map(|_| ());
            let _ = done.send(r);
        });
        let f = result
            .recv_timeout(std::time::Duration::from_secs(60))
            .expect("the start-up on simulated time did not end (a wait that lets no time pass?)")
            .unwrap_err();
        match &f.error {
            StartupError::NoBoot {
                device, timeout_s, ..
            } => assert_eq!((*device, *timeout_s), ("transducer", 1.0)),
            e => panic!("expected NoBoot, got {e}"),
        }
        // rounds at 250 ms (transducer 250..350, valve 350..450), at 450 + 250 = 700 (700..800,
        // 800..900) and the last at 1000 ms with the full SDO timeout: 1000..1100.
        assert_eq!(f.elapsed_s, 1.1);
        assert_eq!(clock.now_ns(), 42_000 * MS as u64 + 1_100 * MS as u64);
        // the failure's frames are timed relative to the failure (at 1100 ms)
        let at = |id: u16, first: u8| -> Vec<i64> {
            f.frames
                .iter()
                .filter(|r| r.id == u32::from(id) && r.data[0] == first && r.tx)
                .map(|r| r.t_ns / MS + 1_100)
                .collect()
        };
        let (sdo_tr, sdo_va) = (0x600 + u16::from(tr), 0x600 + u16::from(va));
        assert_eq!(at(sdo_tr, 0x40), [250, 700, 1000], "transducer probes (ms)");
        assert_eq!(at(sdo_tr, 0x80), [350, 800, 1100], "transducer aborts (ms)");
        assert_eq!(at(sdo_va, 0x40), [350, 800], "valve probes (ms)");
        assert_eq!(at(sdo_va, 0x80), [450, 900], "valve aborts (ms)");
        // ehactl's heartbeat every 20 ms from the first frame to the failure, none missed
        let hb = at(0x700 + u16::from(master), 0x05);
        assert_eq!(hb, (0..=55).map(|k| 20 * k).collect::<Vec<_>>());
        // the log's frames are those the bus saw, at the same instants (frames of one
        // instant may be listed in another order: the log merges the heartbeats by time)
        let mut bus_saw: Vec<(i64, u32, [u8; 8])> = sent
            .lock()
            .unwrap()
            .iter()
            .map(|(t, fr)| (*t as i64 - 43_100 * MS, fr.id, fr.data))
            .collect();
        let mut logged: Vec<(i64, u32, [u8; 8])> = f
            .frames
            .iter()
            .filter(|r| r.tx)
            .map(|r| (r.t_ns, r.id, r.data))
            .collect();
        bus_saw.sort();
        logged.sort();
        assert_eq!(bus_saw, logged);
    }
}
