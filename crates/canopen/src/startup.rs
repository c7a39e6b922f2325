//! Start-up of the CAN rig, in the two lifecycle steps of ros2_control's hardware interfaces:
//!
//! - [`Plan::new`] (no bus; also run by `ehactl run` before the log file is created): the
//!   settings checks and the EDS / DCF files named in the config → one [`DevicePlan`] per
//!   device (the transducer, the valve, then `[[canopen.devices]]`, each with its profile):
//!   the identity to check, and every SDO object to configure with its value and the
//!   access type the file gives (ro / const objects are read and checked, never written);
//! - **configure** (`Bringup::configure`, then `Bringup::start`): NMT reset
//!   communication → boot-up, or an SDO probe for a node that sends none (`Bringup::boot`);
//!   NMT pre-operational; per device the device type and identity 0x1018 against its file,
//!   then the planned objects (`Bringup::apply_plan`); NMT start and OPERATIONAL
//!   heartbeats (`Bringup::start_nodes`). The valve is not enabled: it stays in the device
//!   state it booted in;
//! - **activate** (`Bringup::activate`): the CiA 408 device state machine of the valve
//!   from a fault state, if any, to ACTIVE (`Bringup::enable_valve`), one priming SYNC
//!   (`Bringup::prime`; a failure returns the valve to HOLD).
//!
//! These are the steps of `CanopenHal`'s `Hal::configure` and `Hal::activate`
//! ([`crate::hal`]); the bus and the bookkeeping are handed from one to the next
//! (`Bringup::into_parts`, `Bringup::resume`).
//!
//! Every frame of the attempt is kept (`Startup`) for the log, and ehactl's heartbeat runs
//! from the first frame on (`StartBus`). Every wait and timeout is counted on the caller's
//! [`Clock`] (ns); the bus waits at most until the next deadline.

use crate::bus::{BusError, BusErrorKind, CanBus};
use crate::cia406;
use crate::cia408::{self, ValveState};
use crate::clock::Clock;
use crate::eds::{Access, Eds};
use crate::emcy::{Emcy, EMCY_BASE};
use crate::frame::{CanFrame, Direction};
use crate::nmt::{self, NmtCommand, NmtState, HEARTBEAT_BASE};
use crate::pdo::{
    self, MapEntry, PdoMap, COB_ID_INVALID, RPDO1_BASE, RPDO1_COMM, RPDO1_MAP, TPDO1_BASE,
    TPDO1_COMM, TPDO1_MAP,
};
use crate::profile::{PdoDir, Profile, ProfilePdo};
use crate::sdo::{self, SdoClient, SdoError};
use crate::settings::CanopenSettings;
use crate::sync;
use ehactl_hal::{Measurements, StartupReport};
use ehactl_types::canopen::CanopenConfig;
use ehactl_types::frames::CanFrameRecord;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// While waiting for boot-ups, nodes not heard from are probed by SDO this often (and once
/// more at `boot_timeout_s`).
pub const BOOT_PROBE_EVERY: Duration = Duration::from_millis(250);

/// Why the rig could not be brought up (before the loop). One line each.
#[derive(Debug, Clone)]
pub enum StartupError {
    /// Inconsistent settings or device description files (no bus needed to see it).
    Settings(String),
    /// The bus could not be opened or failed.
    Bus(BusError),
    /// A device sent no boot-up in time.
    NoBoot {
        /// Device name.
        device: &'static str,
        /// Node id.
        node: u8,
        /// Allowed time (s).
        timeout_s: f64,
    },
    /// An SDO transfer of the configuration failed.
    Sdo {
        /// Configuration step.
        step: String,
        /// The SDO error (abort code and meaning, timeout, ...).
        error: SdoError,
    },
    /// A device did not do what the master asked (wrong profile or identity, state not
    /// reached, read-only object with another value).
    Device(String),
    /// A stop was requested (SIGINT / SIGTERM) during start-up; what was done with the valve.
    Stopped {
        /// The start-up step that was cut short.
        during: String,
        /// What happened to the valve (`None`: it was never commanded out of its state).
        valve: Option<String>,
    },
}

/// A failed start-up with what was on the bus meanwhile.
#[derive(Debug)]
pub struct StartupFailure {
    /// Why it failed.
    pub error: StartupError,
    /// Every frame sent and received during the attempt, in order; times relative to the
    /// failure (ns, all ≤ 0).
    pub frames: Vec<CanFrameRecord>,
    /// Time from the start of the attempt to the failure (s).
    pub elapsed_s: f64,
}

impl StartupFailure {
    /// The failure as the backend-neutral [`StartupReport`] the session logs (reason text,
    /// the settings / stop flags, the time limit, the frames of the attempt).
    pub fn report(self) -> StartupReport {
        StartupReport {
            reason: self.error.to_string(),
            channel: "canopen start-up",
            settings_error: matches!(self.error, StartupError::Settings(_)),
            stopped: matches!(self.error, StartupError::Stopped { .. }),
            elapsed_s: self.elapsed_s,
            time_limit_s: self.error.time_limit_s(),
            frames: self.frames,
        }
    }
}

impl StartupError {
    /// The time limit that ran out, if the failure is a timeout (s).
    pub fn time_limit_s(&self) -> Option<f64> {
        match self {
            StartupError::NoBoot { timeout_s, .. } => Some(*timeout_s),
            _ => None,
        }
    }
}

impl std::fmt::Display for StartupError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StartupError::Settings(m) => write!(f, "CANopen start-up: {m}"),
            StartupError::Bus(e) => write!(f, "CANopen start-up: {e}"),
            StartupError::NoBoot {
                device,
                node,
                timeout_s,
            } => write!(
                f,
                "CANopen start-up: {device} (node {node} = 0x{node:02X}) sent no boot-up (0x{:03X} [00]) within {timeout_s} s after NMT reset communication (canopen.boot_timeout_s) and did not answer an SDO probe of 0x1000; is it powered, on the bus and using this node id?",
                HEARTBEAT_BASE + u16::from(*node)
            ),
            StartupError::Sdo { step, error } => {
                write!(f, "CANopen start-up: {step}: {error}")
            }
            StartupError::Device(m) => write!(f, "CANopen start-up: {m}"),
            StartupError::Stopped { during, valve } => {
                write!(f, "CANopen start-up stopped by signal (SIGINT / SIGTERM) during {during}")?;
                match valve {
                    Some(v) => write!(f, "; {v}"),
                    None => write!(f, "; the valve was not enabled"),
                }
            }
        }
    }
}

impl std::error::Error for StartupError {}

impl From<BusError> for StartupError {
    fn from(e: BusError) -> Self {
        StartupError::Bus(e)
    }
}

// ------------------------------------------------------------------------------ the plan

/// How one planned object is brought to its value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StepKind {
    /// Read first; equal: nothing to do; different: write (writable objects) and read back.
    /// A read-only / const object with another value is an error; it is never written.
    Ensure,
    /// Always write (write-only objects, and steps of a procedure such as PDO re-mapping
    /// that must happen in order), then read back if readable.
    Write,
}

/// One planned SDO step.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Value (little endian, the object's size).
    pub value: Vec<u8>,
    /// Access type from the device's file.
    pub access: Access,
    /// How.
    pub kind: StepKind,
    /// What it is for (messages).
    pub what: String,
    /// An optional feature (SYNC objects at their neutral value, RPDO deadline, cyclic timer
    /// off): a device that answers "object does not exist" (0x06020000 / 0x06090011) although
    /// its file lists it is used without it, and the step is reported as skipped.
    pub optional: bool,
    /// Used where the device has it: before the step, `index:00` is read from the device;
    /// "object does not exist" (0x06020000 / 0x06090011) skips the step (reported), whatever
    /// the file says. The heartbeat consumer 0x1016 of a sensor (optional in CiA 301): a
    /// sensor need not react to the loss of ehactl, the valve does.
    pub if_device_has: bool,
}

/// What ehactl does to one device at start-up, decided from its EDS / DCF before the bus
/// is opened.
#[derive(Debug, Clone)]
pub struct DevicePlan {
    /// Its device profile.
    pub device: &'static dyn Profile,
    /// The config key of its file (messages): `canopen.transducer_eds`,
    /// `canopen.valve_eds`, `canopen.devices[i].eds`.
    pub config_key: String,
    /// Node id.
    pub node: u8,
    /// Its description file.
    pub eds: Eds,
    /// CiA profile number expected in 0x1000 bits 0..15 (406 / 408).
    pub profile: u16,
    /// Vendor-ID and product code to check in 0x1018:01 / :02 (from `[DeviceInfo]`).
    pub identity: (Option<u32>, Option<u32>),
    /// The SDO steps, in order.
    pub steps: Vec<Step>,
    /// Size of its TPDO1 as mapped (bytes; `None`: it sends none).
    pub tpdo_len: Option<usize>,
    /// Size of its RPDO1 as mapped (bytes; `None`: it receives none).
    pub rpdo_len: Option<usize>,
}

/// The start-up plan of every device of the rig.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The transducer, the valve, then the devices of `[[canopen.devices]]` in their order.
    pub devices: Vec<DevicePlan>,
    /// Index in `devices` of the commanded device: the one whose profile moves the load
    /// (the valve).
    pub commanded: usize,
}

/// Where a device of the rig comes from in the config.
struct DeviceEntry<'a> {
    profile: &'static dyn Profile,
    config_key: String,
    node: u8,
    path: &'a str,
}

/// The rig's devices as the config names them: the transducer, the valve, then
/// `[[canopen.devices]]` (profiles by name, sensors only; two devices may not decode into
/// the same measurement).
fn device_entries(c: &CanopenConfig) -> Result<Vec<DeviceEntry<'_>>, StartupError> {
    let mut v = vec![
        DeviceEntry {
            profile: &crate::cia406::Cia406,
            config_key: "canopen.transducer_eds".into(),
            node: c.transducer_node_id,
            path: &c.transducer_eds,
        },
        DeviceEntry {
            profile: &crate::cia408::Cia408,
            config_key: "canopen.valve_eds".into(),
            node: c.valve_node_id,
            path: &c.valve_eds,
        },
    ];
    for (i, d) in c.devices.iter().enumerate() {
        let at = format!("canopen.devices[{i}]");
        let profile = crate::profiles::by_name(&d.profile).ok_or_else(|| {
            settings_err(format!(
                "{at}.profile: unknown device profile \"{}\"; expected one of {}",
                d.profile,
                crate::profiles::names()
            ))
        })?;
        if profile.moves_the_load() {
            return Err(settings_err(format!(
                "{at}.profile: \"{}\" ({}) moves the load; ehactl commands one device, the valve (canopen.valve_node_id); expected a sensor profile",
                d.profile,
                profile.name()
            )));
        }
        let node = u8::try_from(d.node_id)
            .ok()
            .filter(|n| (1..=127).contains(n));
        let node = node.ok_or_else(|| {
            settings_err(format!(
                "{at}.node_id = {} is out of range; expected 1..127",
                d.node_id
            ))
        })?;
        v.push(DeviceEntry {
            profile,
            config_key: format!("{at}.eds"),
            node,
            path: &d.eds,
        });
    }
    check_disjoint(c, &v)?;
    Ok(v)
}

/// Two devices that decode into the same field of [`Measurements`] would overwrite each
/// other: refused. What a profile sets is what its decode of a zero TPDO sets.
fn check_disjoint(c: &CanopenConfig, v: &[DeviceEntry<'_>]) -> Result<(), StartupError> {
    let sets = |p: &dyn Profile| {
        let mut m = Measurements::UNMEASURED;
        let _ = p.decode(c, &[0; 8], &mut m);
        [m.position, m.p_a, m.p_b, m.spool, m.force].map(|x| !x.is_nan())
    };
    for (j, b) in v.iter().enumerate() {
        for a in &v[..j] {
            let (sa, sb) = (sets(a.profile), sets(b.profile));
            if sa.iter().zip(sb).any(|(x, y)| *x && y) {
                return Err(settings_err(format!(
                    "{}: the {} (CiA {}) and the {} (CiA {}, {}) would both set the same measurement; expected devices that measure different quantities",
                    b.config_key.trim_end_matches(".eds").trim_end_matches("_eds"),
                    b.profile.name(),
                    b.profile.number(),
                    a.profile.name(),
                    a.profile.number(),
                    a.config_key
                )));
            }
        }
    }
    Ok(())
}

/// The communication and mapping objects and the COB-ID of a device's first PDO of `dir`
/// (CiA 301 default connection set).
fn pdo_objects(dir: PdoDir, node: u16) -> (u16, u16, u16) {
    match dir {
        PdoDir::Transmit => (TPDO1_COMM, TPDO1_MAP, TPDO1_BASE + node),
        PdoDir::Receive => (RPDO1_COMM, RPDO1_MAP, RPDO1_BASE + node),
    }
}

fn settings_err(m: String) -> StartupError {
    StartupError::Settings(m)
}

impl DevicePlan {
    fn obj(&self, index: u16, sub: u8) -> Result<&crate::eds::EdsObject, StartupError> {
        self.eds.get(index, sub).ok_or_else(|| {
            settings_err(format!(
                "{} ({}): the {} has no object 0x{index:04X}:{sub:02X} in its EDS, which ehactl needs",
                self.eds.source,
                self.config_key,
                self.device.name()
            ))
        })
    }

    /// Plan `index:sub` = `value` (bytes), checked against the file: the object exists and
    /// has the value's size.
    fn push(
        &mut self,
        index: u16,
        sub: u8,
        value: Vec<u8>,
        kind: StepKind,
        what: impl Into<String>,
    ) -> Result<(), StartupError> {
        let o = self.obj(index, sub)?;
        if let Some(n) = o.size() {
            if n != value.len() {
                return Err(settings_err(format!(
                    "{} ({}): 0x{index:04X}:{sub:02X} ({}) has data type 0x{:04X} of {n} bytes, ehactl writes {} bytes there",
                    self.eds.source,
                    self.config_key,
                    o.name,
                    o.data_type,
                    value.len()
                )));
            }
        }
        let access = o.access;
        let kind = if access == Access::Wo {
            StepKind::Write
        } else {
            kind
        };
        self.steps.push(Step {
            index,
            sub,
            value,
            access,
            kind,
            what: what.into(),
            optional: false,
            if_device_has: false,
        });
        Ok(())
    }

    /// Mark the last planned step as used only where the device has it (see
    /// [`Step::if_device_has`]).
    fn if_device_has(&mut self) {
        if let Some(s) = self.steps.last_mut() {
            s.if_device_has = true;
        }
    }

    /// Mark the last planned step optional (see [`Step::optional`]).
    fn optional(&mut self) {
        if let Some(s) = self.steps.last_mut() {
            s.optional = true;
        }
    }

    /// Plan one PDO: the CiA 301 re-mapping procedure where the mapping object is writable,
    /// a check of the fixed mapping where the file makes it ro / const. The mapped objects
    /// must exist, be PDO-mappable and have the mapped size.
    fn pdo(
        &mut self,
        comm: u16,
        map_idx: u16,
        cob: u16,
        entries: &[MapEntry],
        what: &str,
    ) -> Result<(), StartupError> {
        let map = PdoMap::new(entries)
            .ok_or_else(|| settings_err(format!("{what}: mapping longer than 8 bytes")))?;
        for e in entries {
            let o = self.obj(e.index, e.sub)?;
            if !o.pdo_mapping || o.size().map(|n| 8 * n) != Some(usize::from(e.bits)) {
                return Err(settings_err(format!(
                    "{} ({}): {what}: 0x{:04X}:{:02X} ({}) is {} in the EDS; ehactl maps it with {} bits",
                    self.eds.source,
                    self.config_key,
                    e.index,
                    e.sub,
                    o.name,
                    if o.pdo_mapping { "of another size" } else { "not PDO-mappable" },
                    e.bits
                )));
            }
        }
        let fixed = !self.obj(map_idx, 0)?.access.writable();
        let what_m = format!("mapping {what}");
        if fixed {
            self.push(
                comm,
                2,
                vec![pdo::TRANSMISSION_SYNC_EVERY],
                StepKind::Ensure,
                &what_m,
            )?;
            self.push(
                map_idx,
                0,
                vec![map.count() as u8],
                StepKind::Ensure,
                &what_m,
            )?;
            for (i, e) in entries.iter().enumerate() {
                self.push(
                    map_idx,
                    (i + 1) as u8,
                    e.encode().to_le_bytes().to_vec(),
                    StepKind::Ensure,
                    &what_m,
                )?;
            }
            self.push(
                comm,
                1,
                u32::from(cob).to_le_bytes().to_vec(),
                StepKind::Ensure,
                &what_m,
            )?;
            return Ok(());
        }
        for w in pdo::remap_sequence(comm, map_idx, cob, pdo::TRANSMISSION_SYNC_EVERY, &map) {
            let (b, n) = w.bytes();
            self.push(w.index, w.sub, b[..n].to_vec(), StepKind::Write, &what_m)?;
        }
        Ok(())
    }
}

impl Plan {
    /// Build the plan from the settings and the device files (no bus). The phases follow
    /// the order in which the objects are written at start-up: the device's own DCF
    /// settings, then CiA 301 communication objects (error control, SYNC), then the profile
    /// objects and PDOs of each device's profile; last, a check that ehactl overrides no
    /// DCF value.
    pub fn new(s: &CanopenSettings) -> Result<Plan, StartupError> {
        let c = &s.canopen;
        // Every file is read before any error is looked at (in the devices' order).
        let loaded: Vec<_> = device_entries(c)?
            .into_iter()
            .map(|d| DevicePlan::load(s, d))
            .collect();
        let mut devices = loaded.into_iter().collect::<Result<Vec<_>, _>>()?;
        for p in devices.iter_mut() {
            p.plan_dcf_settings()?;
            p.plan_error_control(c)?;
            p.plan_sync_objects(c)?;
        }
        for p in devices.iter_mut() {
            p.plan_profile(p.device, c)?;
        }
        for p in &devices {
            p.check_dcf_not_overridden()?;
        }
        let commanded = devices
            .iter()
            .position(|d| d.device.moves_the_load())
            .ok_or_else(|| settings_err("no device moves the load".into()))?;
        Ok(Plan { devices, commanded })
    }

    /// The node ids of the devices, in their order.
    pub fn nodes(&self) -> Vec<u8> {
        self.devices.iter().map(|d| d.node).collect()
    }
}

impl DevicePlan {
    /// The device's EDS / DCF (the config's file or its profile's built-in one), checked
    /// against the config: the DCF's node id, the CiA profile in the device type 0x1000
    /// (CiA 301 7.5.2.1), and the identity 0x1018:01 / :02 to check on the bus. No steps yet.
    fn load(s: &CanopenSettings, d: DeviceEntry<'_>) -> Result<DevicePlan, StartupError> {
        let (builtin, name) = d.profile.builtin_eds().unwrap_or(("", "no built-in file"));
        let eds = Eds::from_config(d.path, s.config_dir.as_deref(), builtin, name)
            .map_err(|e| settings_err(format!("{}: {e}", d.config_key)))?;
        DevicePlan::from_file(d.profile, d.config_key, d.node, eds)
    }

    /// A device of profile `device` at `node` described by `eds` (`config_key` names the
    /// file in messages), checked: the DCF's node id, the CiA profile in the device type
    /// 0x1000 (CiA 301 7.5.2.1), and the identity 0x1018:01 / :02 to check on the bus. No
    /// steps yet.
    fn from_file(
        device: &'static dyn Profile,
        config_key: String,
        node: u8,
        eds: Eds,
    ) -> Result<DevicePlan, StartupError> {
        let profile = device.number();
        if let Some(dcf) = eds.dcf_node_id.filter(|n| *n != 0 && *n != node) {
            return Err(settings_err(format!(
                "{} ({config_key}): the DCF is for node {dcf}, the config has {} node id {node}",
                eds.source,
                device.name()
            )));
        }
        match eds.default_number(0x1000, 0, node) {
            Some(dt) if dt & 0xFFFF == i128::from(profile) => {}
            other => {
                return Err(settings_err(format!(
                    "{} ({config_key}): device type 0x1000 = {} is no CiA {profile} device; expected the {}'s file",
                    eds.source,
                    other.map_or("(missing)".into(), |v| format!("0x{v:08X}")),
                    device.name()
                )))
            }
        }
        let identity = (
            eds.vendor
                .or_else(|| eds.default_number(0x1018, 1, node).map(|v| v as u32)),
            eds.product
                .or_else(|| eds.default_number(0x1018, 2, node).map(|v| v as u32)),
        );
        Ok(DevicePlan {
            device,
            config_key,
            node,
            eds,
            profile,
            identity,
            steps: Vec::new(),
            tpdo_len: None,
            rpdo_len: None,
        })
    }

    /// 1. Device-specific settings of a DCF (ParameterValue), in index order.
    fn plan_dcf_settings(&mut self) -> Result<(), StartupError> {
        let dcf: Vec<(u16, u8, Vec<u8>, String)> = self
            .eds
            .parameter_values()
            .map(|((i, sub), o)| {
                self.eds
                    .encode(
                        i,
                        sub,
                        o.parameter_value.as_deref().unwrap_or(""),
                        self.node,
                    )
                    .map(|b| (i, sub, b, o.name.clone()))
            })
            .collect::<Result<_, _>>()
            .map_err(settings_err)?;
        for (i, sub, b, name) in dcf {
            self.push(i, sub, b, StepKind::Ensure, format!("DCF setting {name}"))?;
        }
        Ok(())
    }

    /// 2. Error control (CiA 301 heartbeat): the device's heartbeat producer 0x1017, its
    ///    consumer 0x1016:01 of ehactl's heartbeat.
    fn plan_error_control(&mut self, c: &CanopenConfig) -> Result<(), StartupError> {
        let name = self.device.name();
        self.push(
            0x1017,
            0,
            c.heartbeat_ms.to_le_bytes().to_vec(),
            StepKind::Ensure,
            format!("setting the {name} heartbeat producer time"),
        )?;
        // A device that moves the load (the valve) must detect a dead ehactl (its fault
        // reaction), so its consumer is mandatory. A sensor's is used where the device has it, decided
        // from what the device answers (an EDS may describe another make or revision).
        let consumer =
            (u32::from(c.master_node_id) << 16) | u32::from(c.device_heartbeat_timeout_ms);
        let what = format!("setting the {name} consumer of ehactl's heartbeat 0x1016:01 (canopen.device_heartbeat_timeout_ms)");
        match (
            self.device.moves_the_load(),
            self.eds.get(0x1016, 1).is_some(),
        ) {
            (true, false) => {
                return Err(settings_err(format!(
                    "{} ({}): the {name} has no heartbeat consumer 0x1016:01, so it cannot detect a dead ehactl (canopen.device_heartbeat_timeout_ms) and stop the load; ehactl refuses to drive it",
                    self.eds.source,
                    self.config_key
                )));
            }
            (moves_the_load, true) => {
                self.push(
                    0x1016,
                    1,
                    consumer.to_le_bytes().to_vec(),
                    StepKind::Ensure,
                    what,
                )?;
                if !moves_the_load {
                    self.if_device_has();
                }
            }
            (false, false) => {
                // Not in the file: still asked, as CiA 301 defines it (UNSIGNED32, rw).
                self.steps.push(Step {
                    index: 0x1016,
                    sub: 1,
                    value: consumer.to_le_bytes().to_vec(),
                    access: Access::Rw,
                    kind: StepKind::Ensure,
                    what,
                    optional: false,
                    if_device_has: true,
                });
            }
        }
        Ok(())
    }

    /// 3. SYNC objects where the file has them (CiA 301 7.5.2.6/7/22): 0x1019 may only
    ///    change while 0x1006 = 0, so the period is cleared first.
    fn plan_sync_objects(&mut self, c: &CanopenConfig) -> Result<(), StartupError> {
        let name = self.device.name();
        let sync_period_us = (1e6 / c.sync_rate_hz).round() as u32;
        if self.eds.get(0x1006, 0).is_some_and(|o| o.access.writable()) {
            self.push(
                0x1006,
                0,
                0u32.to_le_bytes().to_vec(),
                StepKind::Ensure,
                "clearing the communication cycle period 0x1006 (before 0x1019)",
            )?;
            self.optional();
        }
        if self.eds.get(0x1019, 0).is_some() {
            self.push(
                0x1019,
                0,
                vec![c.sync_counter_overflow],
                StepKind::Ensure,
                "setting the SYNC counter overflow 0x1019 (canopen.sync_counter_overflow)",
            )?;
            if c.sync_counter_overflow == 0 {
                self.optional();
            }
        } else if c.sync_counter_overflow != 0 {
            return Err(settings_err(format!(
                "{} ({}): canopen.sync_counter_overflow = {} but the {name} has no 0x1019 (its SYNC consumer expects SYNC without counter); set it to 0",
                self.eds.source,
                self.config_key,
                c.sync_counter_overflow
            )));
        }
        if self.eds.get(0x1007, 0).is_some() {
            self.push(
                0x1007,
                0,
                c.sync_window_us.to_le_bytes().to_vec(),
                StepKind::Ensure,
                "setting the synchronous window 0x1007 (canopen.sync_window_us)",
            )?;
            if c.sync_window_us == 0 {
                self.optional();
            }
        }
        if self.eds.get(0x1006, 0).is_some() {
            self.push(
                0x1006,
                0,
                sync_period_us.to_le_bytes().to_vec(),
                StepKind::Ensure,
                "setting the communication cycle period 0x1006 (µs, 1 / canopen.sync_rate_hz)",
            )?;
            self.optional();
        }
        Ok(())
    }

    /// 4. The profile's objects ([`Profile::start_steps`]: an object only in the file
    ///    where the step asks for it), the objects it needs the file to list, then its PDOs
    ///    ([`Profile::pdos`]: the CiA 301 re-mapping, or the PDO disabled).
    fn plan_profile(&mut self, p: &dyn Profile, c: &CanopenConfig) -> Result<(), StartupError> {
        for st in p.start_steps(c) {
            if st.only_if_in_eds && self.eds.get(st.index, st.sub).is_none() {
                continue;
            }
            self.push(st.index, st.sub, st.value, StepKind::Ensure, st.what)?;
            if st.optional {
                self.optional();
            }
        }
        for &(index, sub, what) in p.required_objects() {
            self.obj(index, sub).map_err(|_| {
                settings_err(format!(
                    "{}: no {what} in the {}'s EDS",
                    self.eds.source,
                    p.name()
                ))
            })?;
        }
        let node = u16::from(self.node);
        for pdo in p.pdos(c) {
            match pdo {
                ProfilePdo::Map { dir, entries, what } => {
                    let (comm, map, cob) = pdo_objects(dir, node);
                    self.pdo(comm, map, cob, entries, what)?;
                    let len = Some(crate::profile::mapped_bytes(entries));
                    match dir {
                        PdoDir::Transmit => self.tpdo_len = len,
                        PdoDir::Receive => self.rpdo_len = len,
                    }
                }
                ProfilePdo::Disable { dir, what } => {
                    let (comm, _, cob) = pdo_objects(dir, node);
                    self.push(
                        comm,
                        1,
                        (COB_ID_INVALID | u32::from(cob)).to_le_bytes().to_vec(),
                        StepKind::Ensure,
                        what,
                    )?;
                }
            }
        }
        Ok(())
    }

    /// A DCF value that ehactl overrides would be silently lost: refuse it.
    fn check_dcf_not_overridden(&self) -> Result<(), StartupError> {
        for ((i, sub), o) in self.eds.parameter_values() {
            let Some(last) = self
                .steps
                .iter()
                .rev()
                .find(|s| (s.index, s.sub) == (i, sub))
            else {
                continue;
            };
            let dcf = self
                .eds
                .encode(
                    i,
                    sub,
                    o.parameter_value.as_deref().unwrap_or(""),
                    self.node,
                )
                .map_err(settings_err)?;
            if last.value != dcf {
                return Err(settings_err(format!(
                    "{} ({}): the DCF sets 0x{i:04X}:{sub:02X} ({}) = {}, but ehactl sets it to {:02X?} ({}); remove the ParameterValue or change the config",
                    self.eds.source,
                    self.config_key,
                    o.name,
                    o.parameter_value.as_deref().unwrap_or(""),
                    last.value,
                    last.what
                )));
            }
        }
        Ok(())
    }
}

// ------------------------------------------------------------------------ the bus side

/// The bus during start-up: sends ehactl's heartbeat (0x700 + master id, state
/// OPERATIONAL `[05]`) every `master_heartbeat_ms` while the start-up waits for frames, so
/// that the devices' heartbeat consumers (0x1016) see the master alive from the moment
/// they are configured. The heartbeats it sent are kept for the log.
pub(crate) struct StartBus {
    pub(crate) inner: Box<dyn CanBus>,
    hb: CanFrame,
    /// Master heartbeat period and the time the next one is due (ns, `clock`).
    period_ns: u64,
    next_ns: u64,
    clock: Arc<dyn Clock>,
    sent: Arc<Mutex<Vec<(u64, CanFrame)>>>,
    /// Stop request (SIGINT / SIGTERM): every wait for a frame checks it at least every
    /// `period` (the master heartbeat period, 20 ms by default) and returns
    /// [`BusErrorKind::Interrupted`], so that every blocking phase of the start-up (boot-up
    /// wait, SDO transfers, NMT and valve state waits, priming) ends within one heartbeat
    /// period of the request, well inside one SDO timeout.
    stop: Option<Arc<AtomicBool>>,
    /// Cleared to bring the valve to its safe state after a stop.
    pub(crate) honour_stop: bool,
}

impl StartBus {
    fn stop_requested(&self) -> bool {
        self.honour_stop
            && self
                .stop
                .as_ref()
                .is_some_and(|s| s.load(Ordering::Relaxed))
    }

    fn check_stop(&self) -> Result<(), BusError> {
        if self.stop_requested() {
            return Err(BusError::new(
                BusErrorKind::Interrupted,
                "stopped by signal (SIGINT / SIGTERM)",
            ));
        }
        Ok(())
    }

    fn beat_if_due(&mut self) -> Result<(), BusError> {
        let now = self.clock.now_ns();
        if now >= self.next_ns {
            self.inner.send(&self.hb)?;
            if let Ok(mut v) = self.sent.lock() {
                v.push((now, self.hb));
            }
            self.next_ns += self.period_ns;
            if self.next_ns < now {
                self.next_ns = now + self.period_ns;
            }
        }
        Ok(())
    }
}

impl CanBus for StartBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
        self.inner.send(frame)
    }
    fn try_recv(&mut self) -> Result<Option<CanFrame>, BusError> {
        self.check_stop()?;
        self.beat_if_due()?;
        self.inner.try_recv()
    }
    fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        let end = self.clock.now_ns().saturating_add(ns(timeout));
        loop {
            self.check_stop()?;
            self.beat_if_due()?;
            let now = self.clock.now_ns();
            if now >= end {
                return Ok(None);
            }
            let wait = Duration::from_nanos(end.min(self.next_ns).saturating_sub(now));
            if let Some(f) = self.inner.recv_timeout(wait)? {
                return Ok(Some(f));
            }
        }
    }
    fn try_clone_bus(&self) -> Result<Box<dyn CanBus>, BusError> {
        self.inner.try_clone_bus()
    }
    fn describe(&self) -> String {
        self.inner.describe()
    }
}

/// Start-up bookkeeping: every frame (for the log) and what the devices reported.
pub(crate) struct Startup {
    /// Every frame with its time (ns, `clock`) and direction (true: sent).
    pub(crate) frames: Vec<(u64, CanFrame, bool)>,
    /// Master heartbeats sent by [`StartBus`] (merged into `frames` by [`Startup::merge`]).
    pub(crate) heartbeats: Arc<Mutex<Vec<(u64, CanFrame)>>>,
    /// The caller's clock: every wait and timeout of the start-up, every frame's time.
    pub(crate) clock: Arc<dyn Clock>,
    /// The devices' node ids, in the plan's order (set by [`Startup::set_nodes`]).
    ids: Vec<u8>,
    booted: Vec<bool>,
    state: Vec<Option<NmtState>>,
    /// The last EMCY (not an error reset) of each device since its boot-up.
    emcy: Vec<Option<Emcy>>,
    verbose: bool,
}

impl Startup {
    pub(crate) fn new(ids: &[u8], verbose: bool, clock: Arc<dyn Clock>) -> Startup {
        let mut st = Startup {
            frames: Vec::with_capacity(512),
            heartbeats: Arc::new(Mutex::new(Vec::new())),
            clock,
            ids: Vec::new(),
            booted: Vec::new(),
            state: Vec::new(),
            emcy: Vec::new(),
            verbose,
        };
        st.set_nodes(ids);
        st
    }

    /// The devices to follow (node ids in the plan's order), none booted yet.
    pub(crate) fn set_nodes(&mut self, ids: &[u8]) {
        let n = ids.len();
        self.ids = ids.to_vec();
        self.booted = vec![false; n];
        self.state = vec![None; n];
        self.emcy = vec![None; n];
    }

    /// Move the master heartbeats into `frames`, in time order.
    pub(crate) fn merge(&mut self) {
        let hb = self
            .heartbeats
            .lock()
            .map(|mut v| std::mem::take(&mut *v))
            .unwrap_or_default();
        if !hb.is_empty() {
            self.frames
                .extend(hb.into_iter().map(|(at, f)| (at, f, true)));
            self.frames.sort_by_key(|(at, _, _)| *at);
        }
    }

    fn observe(&mut self, f: &CanFrame, dir: Direction) {
        self.frames
            .push((self.clock.now_ns(), *f, dir == Direction::Tx));
        if dir == Direction::Tx {
            return;
        }
        if let Some((node, b)) = nmt::parse_error_control(f) {
            for i in 0..self.ids.len() {
                if self.ids[i] == node {
                    let st = NmtState::from_byte(b);
                    if st == Some(NmtState::BootUp) {
                        if self.verbose && !self.booted[i] {
                            eprintln!("canopen: node {node} (0x{node:02X}) boot-up");
                        }
                        self.booted[i] = true;
                        // an EMCY before the boot-up came from the session before the reset
                        self.emcy[i] = None;
                    }
                    self.state[i] = st;
                }
            }
        }
        for i in 0..self.ids.len() {
            if !f.extended && f.id == u32::from(EMCY_BASE + u16::from(self.ids[i])) {
                if let Ok(e) = Emcy::parse(self.ids[i], f.payload()) {
                    if !e.is_reset() {
                        self.emcy[i] = Some(e);
                    }
                }
            }
        }
    }
}

/// A value read back after a start-up write must be the value written.
fn readback(
    step: &str,
    node: u8,
    index: u16,
    sub: u8,
    wrote: &[u8],
    got: &[u8],
) -> Result<(), StartupError> {
    if !same_value(wrote, got) {
        return Err(StartupError::Device(format!(
            "{step}: node {node} (0x{node:02X}) accepted the write of 0x{index:04X}:{sub:02X} but reads back {:02X?} instead of {:02X?}",
            got, wrote
        )));
    }
    Ok(())
}

/// `got` holds the value `want` (an expedited upload may pad with zeros).
fn same_value(want: &[u8], got: &[u8]) -> bool {
    let n = want.len();
    got.len() >= n && got[..n] == *want && got[n..].iter().all(|b| *b == 0)
}

/// The start-up in progress: the bus, the plan and the bookkeeping.
pub(crate) struct Bringup<'a> {
    pub(crate) s: &'a CanopenSettings,
    plan: Plan,
    pub(crate) bus: Box<StartBus>,
    st: &'a mut Startup,
    sdo_t: Duration,
    /// The devices' node ids, in the plan's order.
    ids: Vec<u8>,
    /// Index of the commanded device (the valve) in `ids` ([`Plan::commanded`]).
    cmd: usize,
    /// Device names read from 0x1008 (optional object), in the plan's order.
    pub(crate) names: Vec<Option<String>>,
    /// Optional steps the devices did not support ("node N 0x1006:00 (what)").
    pub(crate) skipped: Vec<String>,
    /// The step in progress (for [`StartupError::Stopped`]).
    phase: &'static str,
}

/// What the activate step hands to the run: the first measurements.
pub(crate) struct Activated {
    pub(crate) meas: Measurements,
}

impl<'a> Bringup<'a> {
    /// Start on the opened `bus` (ehactl's heartbeat starts with it).
    pub(crate) fn open(
        s: &'a CanopenSettings,
        bus: Box<dyn CanBus>,
        plan: Plan,
        st: &'a mut Startup,
        master_hb: CanFrame,
        stop: Option<Arc<AtomicBool>>,
    ) -> Bringup<'a> {
        let c = &s.canopen;
        let bus = Box::new(StartBus {
            inner: bus,
            hb: master_hb,
            period_ns: u64::from(c.master_heartbeat_ms) * 1_000_000,
            next_ns: st.clock.now_ns(),
            clock: st.clock.clone(),
            sent: st.heartbeats.clone(),
            stop,
            honour_stop: true,
        });
        st.set_nodes(&plan.nodes());
        let names = vec![None; plan.devices.len()];
        Self::resume(s, bus, plan, st, names, Vec::new())
    }

    /// Go on with a start-up whose earlier step (configure) ended with `bus`, `names` and
    /// `skipped`: ehactl's heartbeat keeps its period across the steps.
    pub(crate) fn resume(
        s: &'a CanopenSettings,
        bus: Box<StartBus>,
        plan: Plan,
        st: &'a mut Startup,
        names: Vec<Option<String>>,
        skipped: Vec<String>,
    ) -> Bringup<'a> {
        let c = &s.canopen;
        Bringup {
            s,
            sdo_t: Duration::from_millis(u64::from(c.sdo_timeout_ms)),
            ids: plan.nodes(),
            cmd: plan.commanded,
            plan,
            bus,
            st,
            names,
            skipped,
            phase: "the bus connection",
        }
    }

    /// The step in progress or, after a failure, the step that failed.
    pub(crate) fn phase(&self) -> &'static str {
        self.phase
    }

    /// The bus and what configure found, to resume with ([`Bringup::resume`]).
    pub(crate) fn into_parts(self) -> (Box<StartBus>, Plan, Vec<Option<String>>, Vec<String>) {
        (self.bus, self.plan, self.names, self.skipped)
    }

    /// The present time (ns, the caller's clock).
    pub(crate) fn now(&self) -> u64 {
        self.st.clock.now_ns()
    }

    /// Time left until `deadline` (ns, the caller's clock); zero once it has passed.
    fn left_until(&self, deadline: u64) -> Duration {
        Duration::from_nanos(deadline.saturating_sub(self.now()))
    }

    /// A stop was requested (SIGINT / SIGTERM).
    fn stop_requested(&self) -> bool {
        self.bus
            .stop
            .as_ref()
            .is_some_and(|s| s.load(Ordering::Relaxed))
    }

    /// `e`, or [`StartupError::Stopped`] if a stop was requested meanwhile (the error is then
    /// its consequence: an interrupted wait).
    fn or_stopped(&self, e: StartupError, valve: Option<String>) -> StartupError {
        if self.stop_requested() {
            StartupError::Stopped {
                during: self.phase.to_string(),
                valve,
            }
        } else {
            e
        }
    }

    /// The commanded device (the valve) to its safe stop (best effort, also after a stop
    /// request); returns what was done.
    fn valve_to_hold(&mut self, why: &str) -> String {
        self.safe_stop_checked(why).unwrap_or_else(|e| e)
    }

    /// The commanded device's RPDO1 for the command 0 (the valve: spool setpoint 0) and
    /// the control word of its profile's safe stop (the valve: HOLD) by SDO: `Ok` with what
    /// was done when the device confirmed the control word, `Err` with why not.
    pub(crate) fn safe_stop_checked(&mut self, why: &str) -> Result<String, String> {
        self.bus.honour_stop = false;
        let (node, p) = (self.ids[self.cmd], self.plan.devices[self.cmd].device);
        self.await_late_sdo_answer(node);
        let sp = self.send(self.command_frame(0.0));
        let (cw, (index, sub)) = (p.safe_stop().unwrap_or(0), p.control_object());
        let r = self.write(node, index, sub, &cw.to_le_bytes(), why);
        self.bus.honour_stop = true;
        let name = p.name();
        match (sp, r) {
            (Ok(()), Ok(())) => Ok(format!(
                "{name} setpoint 0 and control word HOLD (0x{cw:04X}) sent"
            )),
            (Err(e), _) | (_, Err(e)) => Err(format!("{name} HOLD could not be commanded: {e}")),
        }
    }

    /// The commanded device's RPDO1 for the command `u` (V), as its profile encodes it.
    pub(crate) fn command_frame(&self, u: f64) -> CanFrame {
        let d = &self.plan.devices[self.cmd];
        command_frame(d, u, self.s.command_full_scale)
    }

    /// A stop request cuts an SDO transfer short: the answer of `node` to it may still be on
    /// its way and would be taken for the answer to the next request. Wait for it (at most
    /// 100 ms or one SDO timeout).
    fn await_late_sdo_answer(&mut self, node: u8) {
        let end = self.now() + ns(self.sdo_t.min(Duration::from_millis(100)));
        loop {
            let left = self.left_until(end);
            if left.is_zero() {
                break;
            }
            match self.bus.recv_timeout(left) {
                Ok(Some(f)) => {
                    self.st.observe(&f, Direction::Rx);
                    if !f.extended && f.id == u32::from(sdo::SDO_TX_BASE + u16::from(node)) {
                        break;
                    }
                }
                _ => break,
            }
        }
    }

    fn send(&mut self, f: CanFrame) -> Result<(), StartupError> {
        self.bus.send(&f)?;
        self.st.observe(&f, Direction::Tx);
        Ok(())
    }

    fn sdo_read(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
        let mut cl = SdoClient::new(node, self.sdo_t);
        let req = cl.upload(index, sub);
        let clock = self.st.clock.clone();
        let st = &mut *self.st;
        sdo::transfer(&mut *self.bus, &mut cl, req, &*clock, &mut |f, d| {
            st.observe(f, d)
        })?;
        Ok(cl.data().to_vec())
    }

    fn sdo_write(&mut self, node: u8, index: u16, sub: u8, bytes: &[u8]) -> Result<(), SdoError> {
        let mut cl = SdoClient::new(node, self.sdo_t);
        let req = cl.download(index, sub, bytes);
        let clock = self.st.clock.clone();
        let st = &mut *self.st;
        sdo::transfer(&mut *self.bus, &mut cl, req, &*clock, &mut |f, d| {
            st.observe(f, d)
        })
    }

    fn read(&mut self, node: u8, index: u16, sub: u8, step: &str) -> Result<Vec<u8>, StartupError> {
        self.sdo_read(node, index, sub)
            .map_err(|error| StartupError::Sdo {
                step: format!(
                    "{step} (read 0x{index:04X}:{sub:02X} on node {node} = 0x{node:02X})"
                ),
                error,
            })
    }

    fn write(
        &mut self,
        node: u8,
        index: u16,
        sub: u8,
        bytes: &[u8],
        step: &str,
    ) -> Result<(), StartupError> {
        self.sdo_write(node, index, sub, bytes)
            .map_err(|error| StartupError::Sdo {
                step: format!(
                    "{step} (write 0x{index:04X}:{sub:02X} on node {node} = 0x{node:02X})"
                ),
                error,
            })
    }

    /// configure: boot, pre-operational, identity, planned objects.
    pub(crate) fn configure(&mut self) -> Result<(), StartupError> {
        self.configure_steps().map_err(|e| self.or_stopped(e, None))
    }

    fn configure_steps(&mut self) -> Result<(), StartupError> {
        self.phase = "the wait for the boot-ups (canopen.boot_timeout_s)";
        self.boot()?;
        self.phase = "the SDO configuration";
        for n in self.ids.clone() {
            self.send(nmt::command(NmtCommand::EnterPreOperational, n))?;
        }
        for i in 0..self.ids.len() {
            self.identify(i)?;
        }
        for i in 0..self.ids.len() {
            self.apply_plan(i)?;
        }
        if self.s.verbose {
            eprintln!("canopen: configured from the EDS files (identity, heartbeats, SYNC objects, PDO mappings, profile objects)");
        }
        Ok(())
    }

    /// The end of configure: NMT start and OPERATIONAL heartbeats (the valve stays in its
    /// device state, not enabled).
    pub(crate) fn start(&mut self) -> Result<(), StartupError> {
        self.phase = "NMT start";
        self.start_nodes().map_err(|e| self.or_stopped(e, None))
    }

    /// activate: valve to ACTIVE, priming SYNC. A failure or a stop request once the valve
    /// is being enabled returns it to HOLD with setpoint 0 (best effort).
    pub(crate) fn activate(&mut self) -> Result<Activated, StartupError> {
        self.phase = "the valve state machine (DISABLED → HOLD → ACTIVE)";
        if let Err(e) = self.enable_valve() {
            if self.stop_requested() {
                let v = self.valve_to_hold("returning the valve to HOLD after a stop request");
                return Err(self.or_stopped(e, Some(v)));
            }
            return Err(e);
        }
        self.phase = "the priming SYNC";
        let meas = match self.prime() {
            Ok(m) => m,
            Err(e) => {
                // The valve is ACTIVE here: back to HOLD with setpoint 0 (best effort).
                let v = self.valve_to_hold("returning the valve to HOLD after a failed start-up");
                return Err(self.or_stopped(e, Some(v)));
            }
        };
        Ok(Activated { meas })
    }

    /// NMT reset communication → boot-up of every device; a node that sends none is probed
    /// by SDO (read 0x1000): some slaves (python `canopen`'s LocalNode) send no boot-up after
    /// reset communication, and a boot-up can be lost while the master connects. SDO is
    /// served in PRE-OPERATIONAL and OPERATIONAL only (CiA 301 table 76), so a node that
    /// answers has finished its initialisation. Probes every [`BOOT_PROBE_EVERY`] while
    /// waiting, a last one at `boot_timeout_s`; a node that never answers is reported.
    pub(crate) fn boot(&mut self) -> Result<(), StartupError> {
        let c = &self.s.canopen;
        for n in self.ids.clone() {
            self.send(nmt::command(NmtCommand::ResetCommunication, n))?;
        }
        let boot_deadline = self.now() + ns(Duration::from_secs_f64(c.boot_timeout_s));
        let mut next_probe = self.now() + ns(BOOT_PROBE_EVERY);
        while !self.st.booted.iter().all(|b| *b) {
            self.bus.check_stop()?;
            let now = self.now();
            let last = now >= boot_deadline;
            if last || now >= next_probe {
                for i in 0..self.ids.len() {
                    if self.st.booted[i] {
                        continue;
                    }
                    let wait = if last {
                        self.sdo_t
                    } else {
                        self.sdo_t.min(BOOT_PROBE_EVERY)
                    };
                    let mut cl = SdoClient::new(self.ids[i], wait);
                    let req = cl.upload(0x1000, 0);
                    let clock = self.st.clock.clone();
                    let st = &mut *self.st;
                    let ok = sdo::transfer(&mut *self.bus, &mut cl, req, &*clock, &mut |f, d| {
                        st.observe(f, d)
                    })
                    .is_ok();
                    if ok {
                        if self.s.verbose {
                            eprintln!(
                                "canopen: node {} (0x{:02X}) sent no boot-up but answered an SDO probe of 0x1000",
                                self.ids[i], self.ids[i]
                            );
                        }
                        self.st.booted[i] = true;
                    } else if last && !self.st.booted[i] {
                        return Err(StartupError::NoBoot {
                            device: self.plan.devices[i].device.name(),
                            node: self.ids[i],
                            timeout_s: c.boot_timeout_s,
                        });
                    }
                }
                next_probe = self.now() + ns(BOOT_PROBE_EVERY);
                continue;
            }
            let left = Duration::from_nanos(boot_deadline.min(next_probe).saturating_sub(now));
            if let Some(f) = self.bus.recv_timeout(left.min(Duration::from_millis(50)))? {
                self.st.observe(&f, Direction::Rx);
            }
        }
        Ok(())
    }

    /// Device type (profile), identity 0x1018:01/02 against the device's file, name 0x1008.
    fn identify(&mut self, i: usize) -> Result<(), StartupError> {
        let p = &self.plan.devices[i];
        let (n, dev, key, profile, identity, source) = (
            p.node,
            p.device,
            p.config_key.clone(),
            p.profile,
            p.identity,
            p.eds.source.clone(),
        );
        let d = self.read(n, 0x1000, 0, "reading the device type")?;
        let dt = u32::from_le_bytes(le4(&d));
        if dt & 0xFFFF != u32::from(profile) {
            return Err(StartupError::Device(format!(
                "node {n} (0x{n:02X}) should be the {} (CiA {profile}) but its device type 0x1000 is 0x{dt:08X} (profile {})",
                dev.name(),
                dt & 0xFFFF
            )));
        }
        for (sub, want, what) in [
            (1u8, identity.0, "vendor-ID"),
            (2, identity.1, "product code"),
        ] {
            let Some(want) = want else { continue };
            let got = u32::from_le_bytes(le4(&self.read(
                n,
                0x1018,
                sub,
                &format!("reading the {} identity", dev.name()),
            )?));
            if got != want {
                return Err(StartupError::Device(format!(
                    "{} (node {n} = 0x{n:02X}): {what} 0x1018:{sub:02X} is 0x{got:08X} but its device description {source} ({}) is for 0x{want:08X}; is this the right device or file?",
                    dev.name(),
                    key
                )));
            }
        }
        // Manufacturer device name (VISIBLE_STRING, segmented upload); optional object.
        match self.sdo_read(n, 0x1008, 0) {
            Ok(b) => {
                let name = String::from_utf8_lossy(&b)
                    .trim_end_matches('\0')
                    .to_string();
                if self.s.verbose {
                    eprintln!("canopen: node {n} (0x{n:02X}): \"{name}\" (CiA {profile})");
                }
                self.names[i] = Some(name);
            }
            Err(SdoError::Abort { .. }) => {}
            Err(error) => {
                return Err(StartupError::Sdo {
                    step: format!(
                        "reading the {} device name (read 0x1008:00 on node {n})",
                        dev.name()
                    ),
                    error,
                })
            }
        }
        Ok(())
    }

    /// The planned objects of device `i`, in order (see [`StepKind`]): each step asks the
    /// device whether it has the object where the step is conditional, reads an Ensure
    /// step's object first, writes it, and reads an Ensure step's value back.
    pub(crate) fn apply_plan(&mut self, i: usize) -> Result<(), StartupError> {
        let n = self.plan.devices[i].node;
        let steps = self.plan.devices[i].steps.clone();
        for step in &steps {
            self.bus.check_stop()?;
            if step.if_device_has && !self.device_has(i, step)? {
                continue;
            }
            if step.kind == StepKind::Ensure && self.already_set(i, step)? {
                continue;
            }
            if !self.write_step(i, step)? {
                continue;
            }
            if step.access.readable() && step.kind == StepKind::Ensure {
                let got = self.read(n, step.index, step.sub, &step.what)?;
                readback(&step.what, n, step.index, step.sub, &step.value, &got)?;
            }
        }
        Ok(())
    }

    /// Whether device `i` has the object of a conditional step ([`Step::if_device_has`]):
    /// `index:00` read; "object does not exist" (0x06020000 / 0x06090011) is `false` and the
    /// step is reported as skipped.
    fn device_has(&mut self, i: usize, step: &Step) -> Result<bool, StartupError> {
        let (n, dev) = (self.plan.devices[i].node, self.plan.devices[i].device);
        let (index, sub) = (step.index, step.sub);
        match self.sdo_read(n, index, 0) {
            Ok(_) => Ok(true),
            Err(SdoError::Abort {
                code: code @ (0x0602_0000 | 0x0609_0011),
                ..
            }) => {
                if self.s.verbose {
                    eprintln!(
                        "canopen: {} (node {n}) has no 0x{index:04X} (abort 0x{code:08X}); used without it ({})",
                        dev.name(),
                        step.what
                    );
                }
                self.skipped.push(format!(
                    "node {n} 0x{index:04X}:{sub:02X} ({}): the {} has no 0x{index:04X} (SDO read of 0x{index:04X}:00: abort 0x{code:08X}, object does not exist)",
                    step.what,
                    dev.name()
                ));
                Ok(false)
            }
            Err(error) => Err(StartupError::Sdo {
                step: format!(
                    "{} (read 0x{index:04X}:00 on node {n} = 0x{n:02X}: does the {} have it?)",
                    step.what,
                    dev.name()
                ),
                error,
            }),
        }
    }

    /// Whether the object of an Ensure step already holds its value on device `i` (read
    /// first); a read-only / const object with another value, or one that cannot be read,
    /// is an error: ehactl never writes it.
    fn already_set(&mut self, i: usize, step: &Step) -> Result<bool, StartupError> {
        let (n, dev) = (self.plan.devices[i].node, self.plan.devices[i].device);
        let (index, sub, want) = (step.index, step.sub, &step.value);
        match self.sdo_read(n, index, sub) {
            Ok(h) if same_value(want, &h) => Ok(true),
            Ok(h) if !step.access.writable() => {
                let extra = if (index, sub) == (cia406::POSITION_STEP, 1) {
                    format!(
                        "; set canopen.position_step_nm = {}",
                        u32::from_le_bytes(le4(&h))
                    )
                } else {
                    String::new()
                };
                Err(StartupError::Device(format!(
                    "{}: {} (node {n}) 0x{index:04X}:{sub:02X} is {} (AccessType={} in {}) and reads {:02X?}, not {:02X?}; ehactl never writes read-only objects{extra}",
                    step.what,
                    dev.name(),
                    if step.access == Access::Const { "constant" } else { "read-only" },
                    step.access.as_str(),
                    self.plan.devices[i].eds.source,
                    h,
                    want
                )))
            }
            Err(e) if !step.access.writable() => Err(StartupError::Sdo {
                step: format!(
                    "{} (read-only object: read 0x{index:04X}:{sub:02X} on node {n} = 0x{n:02X})",
                    step.what
                ),
                error: e,
            }),
            // Different, or not readable right now (e.g. no value yet): write it.
            _ => Ok(false),
        }
    }

    /// The write of a step to device `i`: `Ok(true)` when written, `Ok(false)` when an
    /// optional step's object does not exist on the device (reported as skipped); a write
    /// the device refuses is an error naming what it has.
    fn write_step(&mut self, i: usize, step: &Step) -> Result<bool, StartupError> {
        let (n, dev) = (self.plan.devices[i].node, self.plan.devices[i].device);
        let (index, sub, want) = (step.index, step.sub, &step.value);
        match self.sdo_write(n, index, sub, want) {
            Ok(()) => Ok(true),
            Err(SdoError::Abort {
                code: 0x0602_0000 | 0x0609_0011,
                ..
            }) if step.optional => {
                if self.s.verbose {
                    eprintln!(
                        "canopen: {} (node {n}) has no 0x{index:04X}:{sub:02X} although its EDS lists it; optional, skipped ({})",
                        dev.name(),
                        step.what
                    );
                }
                self.skipped
                    .push(format!("node {n} 0x{index:04X}:{sub:02X} ({})", step.what));
                Ok(false)
            }
            // The file says rw, the device refuses the write as read-only (0x06010002).
            Err(SdoError::Abort {
                code: 0x0601_0002, ..
            }) => Err(self.read_only_on_the_device(i, step)),
            Err(SdoError::Abort {
                code: code @ (0x0602_0000 | 0x0609_0011),
                ..
            }) if index == 0x1016 && dev.moves_the_load() => Err(StartupError::Device(format!(
                "{}: the {} (node {n}) has no heartbeat consumer 0x1016:{sub:02X} (abort 0x{code:08X}, object does not exist) although {} lists it; it could not detect a dead ehactl and stop the load: ehactl refuses to drive it",
                step.what,
                dev.name(),
                self.plan.devices[i].eds.source
            ))),
            Err(error) => Err(StartupError::Sdo {
                step: format!(
                    "{} (write 0x{index:04X}:{sub:02X} on node {n} = 0x{n:02X})",
                    step.what
                ),
                error,
            }),
        }
    }

    /// The error of a write that device `i` refused as read-only (abort 0x06010002) although
    /// its file says the object is writable: naming the device's value if it has one.
    fn read_only_on_the_device(&mut self, i: usize, step: &Step) -> StartupError {
        let (n, dev) = (self.plan.devices[i].node, self.plan.devices[i].device);
        let (index, sub, want) = (step.index, step.sub, &step.value);
        let h = self.sdo_read(n, index, sub).ok();
        let extra = match (&h, (index, sub) == (cia406::POSITION_STEP, 1)) {
            (Some(h), true) => format!(
                "; it is {} nm: set canopen.position_step_nm = {}",
                u32::from_le_bytes(le4(h)),
                u32::from_le_bytes(le4(h))
            ),
            (Some(h), false) => format!("; it reads {h:02X?}"),
            (None, _) => String::new(),
        };
        StartupError::Device(format!(
            "{}: {} (node {n}) 0x{index:04X}:{sub:02X} is read-only on the device (abort 0x06010002) although its EDS says {}; ehactl wanted {:02X?}{extra}",
            step.what,
            dev.name(),
            step.access.as_str(),
            want
        ))
    }

    /// NMT start; wait for OPERATIONAL heartbeats.
    pub(crate) fn start_nodes(&mut self) -> Result<(), StartupError> {
        let c = &self.s.canopen;
        for n in self.ids.clone() {
            self.send(nmt::command(NmtCommand::Start, n))?;
        }
        self.st.state.iter_mut().for_each(|x| *x = None);
        let op_wait = Duration::from_millis(
            (3 * u64::from(c.heartbeat_timeout_ms)).max(u64::from(c.sdo_timeout_ms)),
        );
        let deadline = self.now() + ns(op_wait);
        while !self
            .st
            .state
            .iter()
            .all(|x| *x == Some(NmtState::Operational))
        {
            let left = self.left_until(deadline);
            if left.is_zero() {
                let i = self
                    .st
                    .state
                    .iter()
                    .position(|x| *x != Some(NmtState::Operational))
                    .unwrap_or(0);
                return Err(StartupError::Device(format!(
                    "{} (node {}) did not report OPERATIONAL by heartbeat within {} ms after NMT start (last state: {})",
                    self.plan.devices[i].device.name(),
                    self.ids[i],
                    op_wait.as_millis(),
                    self.st.state[i].map_or("no heartbeat", |x| x.as_str())
                )));
            }
            if let Some(f) = self.bus.recv_timeout(left.min(Duration::from_millis(50)))? {
                self.st.observe(&f, Direction::Rx);
            }
        }
        Ok(())
    }

    fn status(&mut self) -> Result<u16, StartupError> {
        let d = self.read(
            self.ids[self.cmd],
            cia408::STATUS_WORD,
            0,
            "reading the valve status word",
        )?;
        Ok(u16::from_le_bytes([
            d.first().copied().unwrap_or(0),
            d.get(1).copied().unwrap_or(0),
        ]))
    }

    fn goto(&mut self, cw: u16, want: ValveState) -> Result<(), StartupError> {
        let va = self.ids[self.cmd];
        self.write(
            va,
            cia408::CONTROL_WORD,
            0,
            &cw.to_le_bytes(),
            &format!("commanding the valve to {}", want.as_str()),
        )?;
        let deadline = self.now() + ns(self.sdo_t);
        loop {
            let sw = self.status()?;
            let got = ValveState::from_status(sw);
            if got == want {
                if self.s.verbose {
                    eprintln!("canopen: valve {}", want.as_str());
                }
                return Ok(());
            }
            if self.now() >= deadline {
                return Err(StartupError::Device(format!(
                    "valve (node {va}) did not enter {} after control word 0x{cw:04X}: status word 0x{sw:04X} ({})",
                    want.as_str(),
                    got.as_str()
                )));
            }
            self.st.clock.sleep(Duration::from_millis(10));
        }
    }

    /// Valve state machine by SDO control word: (fault → reset) DISABLED → HOLD → ACTIVE.
    /// A valve in a fault state is reset as published (Moog B99224-DV018 §5.2.2.1):
    /// FAULT_REACTION ends by itself (TR9/12/13); then R rises with the D/H bits of the
    /// fault state held (TR10 FAULT_DISABLED 0001→1001, TR11 FAULT_HOLD 0011→1011, TR14
    /// FAULT_INIT 0000→1000).
    pub(crate) fn enable_valve(&mut self) -> Result<(), StartupError> {
        let va = self.ids[self.cmd];
        let mut sw = self.status()?;
        let deadline = self.now() + ns(self.sdo_t);
        while ValveState::from_status(sw) == ValveState::FaultReaction && self.now() < deadline {
            self.st.clock.sleep(Duration::from_millis(5));
            sw = self.status()?;
        }
        let fault = ValveState::from_status(sw);
        if fault.is_fault() {
            let Some(held) = fault.reset_hold_bits() else {
                return Err(StartupError::Device(format!(
                    "valve (node {va}) stayed in FAULT_REACTION (status word 0x{sw:04X}) for {} ms",
                    self.sdo_t.as_millis()
                )));
            };
            if self.s.verbose {
                eprintln!(
                    "canopen: valve in {} at start-up: fault reset (rising edge of control word bit R)",
                    fault.as_str()
                );
            }
            self.write(
                va,
                cia408::CONTROL_WORD,
                0,
                &held.to_le_bytes(),
                "preparing the valve fault reset (R = 0, D/H held)",
            )?;
            self.write(
                va,
                cia408::CONTROL_WORD,
                0,
                &(held | cia408::CW_RESET).to_le_bytes(),
                "resetting the valve fault (rising edge of R)",
            )?;
            let sw = self.status()?;
            let got = ValveState::from_status(sw);
            if got.is_fault() || matches!(got, ValveState::Unknown(_)) {
                return Err(StartupError::Device(format!(
                    "valve (node {va}) still in {} after the fault reset (control word 0x{:04X}): status word 0x{sw:04X}; the fault persists",
                    got.as_str(),
                    held | cia408::CW_RESET
                )));
            }
        }
        self.goto(cia408::CW_DISABLED_STATE, ValveState::Disabled)?;
        self.goto(cia408::CW_HOLD_STATE, ValveState::Hold)?;
        self.goto(cia408::CW_ACTIVE_STATE, ValveState::Active)
    }

    /// The commanded device's RPDO1 for the command 0 (the valve: setpoint 0) and one
    /// SYNC, so that the first cycle has every device's first TPDO1 decoded (the position,
    /// the spool, …); an EMCY any device sent since its boot-up fails the start-up.
    pub(crate) fn prime(&mut self) -> Result<Measurements, StartupError> {
        let c = &self.s.canopen;
        let mut meas = Measurements::UNMEASURED;
        self.send(self.command_frame(0.0))?;
        self.send(sync::frame_with_counter(c.sync_counter_overflow, 1))?;
        let deadline = self.now() + ns(self.sdo_t);
        let mut waiting: Vec<bool> = self
            .plan
            .devices
            .iter()
            .map(|d| d.tpdo_len.is_some())
            .collect();
        while let Some(i) = waiting.iter().position(|w| *w) {
            let left = self.left_until(deadline);
            if left.is_zero() {
                return Err(StartupError::Device(format!(
                    "no {} TPDO1 within {} ms after the first SYNC; are the PDOs mapped and the devices OPERATIONAL?",
                    self.plan.devices[i].device.name(),
                    self.sdo_t.as_millis()
                )));
            }
            if let Some(f) = self.bus.recv_timeout(left)? {
                self.st.observe(&f, Direction::Rx);
                for (d, w) in self.plan.devices.iter().zip(waiting.iter_mut()) {
                    let fits = f.id == u32::from(TPDO1_BASE + u16::from(d.node))
                        && Some(usize::from(f.dlc)) == d.tpdo_len;
                    if fits && d.device.decode(c, f.payload(), &mut meas).is_ok() {
                        *w = false;
                    }
                }
            }
        }
        if let Some(e) = self.st.emcy.iter().flatten().next().copied() {
            let name = self
                .plan
                .devices
                .iter()
                .find(|d| d.node == e.node)
                .map_or("device", |d| d.device.name());
            return Err(StartupError::Device(format!(
                "{name} (node {}) sent EMCY 0x{:04X} ({}) during start-up",
                e.node,
                e.code,
                e.class()
            )));
        }
        Ok(meas)
    }
}

/// `d` in ns (saturating; every duration here is a few seconds at most).
fn ns(d: Duration) -> u64 {
    d.as_nanos().min(u128::from(u64::MAX)) as u64
}

/// The RPDO1 of commanded device `d` for the command `u` (V; full scale `full_scale` V):
/// its profile's encoding, as long as its RPDO1 is mapped (CiA 301 default COB-ID 0x200 +
/// node).
pub(crate) fn command_frame(d: &DevicePlan, u: f64, full_scale: f64) -> CanFrame {
    rpdo_frame(d.device, d.node, d.rpdo_len.unwrap_or(0), u, full_scale)
}

/// The RPDO1 (`len` bytes, CiA 301 default COB-ID 0x200 + `node`) that `profile` encodes
/// for the command `u` (V; full scale `full_scale` V). No allocation (the control cycle
/// sends it).
#[inline]
pub(crate) fn rpdo_frame(
    profile: &dyn Profile,
    node: u8,
    len: usize,
    u: f64,
    full_scale: f64,
) -> CanFrame {
    let b = profile.encode(u, full_scale).unwrap_or([0; 8]);
    let n = len.min(8);
    let mut data = [0u8; 8];
    data[..n].copy_from_slice(&b[..n]);
    CanFrame {
        id: u32::from(RPDO1_BASE + u16::from(node)),
        dlc: n as u8,
        data,
        extended: false,
    }
}

fn le4(d: &[u8]) -> [u8; 4] {
    let mut b = [0u8; 4];
    b[..d.len().min(4)].copy_from_slice(&d[..d.len().min(4)]);
    b
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::BusUrl;
    use crate::eds::{BUILTIN_TRANSDUCER_EDS, BUILTIN_VALVE_EDS};
    use ehactl_types::canopen::CanopenConfig;

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

    #[test]
    fn the_plan_follows_the_built_in_eds_files() {
        let p = Plan::new(&settings(CanopenConfig::default())).unwrap();
        let [t, v] = &p.devices[..] else {
            panic!("two devices")
        };
        assert_eq!(
            (t.identity, v.identity),
            ((Some(0), Some(0x196)), (Some(0), Some(0x198)))
        );
        let at = |d: &DevicePlan, i: u16, s: u8| {
            d.steps
                .iter()
                .filter(|x| (x.index, x.sub) == (i, s))
                .count()
        };
        // heartbeat, consumer, SYNC objects (0x1006 cleared before 0x1019, then set), profile
        for d in [t, v] {
            assert_eq!(
                at(d, 0x1017, 0) + at(d, 0x1016, 1) + at(d, 0x1019, 0) + at(d, 0x1007, 0),
                4
            );
            assert_eq!(at(d, 0x1006, 0), 2);
            let k = |i| d.steps.iter().position(|x| x.index == i).unwrap();
            assert!(k(0x1006) < k(0x1019));
            let last = d.steps.iter().rev().find(|x| x.index == 0x1006).unwrap();
            assert_eq!(last.value, 1000u32.to_le_bytes()); // µs at 1 kHz SYNC
        }
        assert_eq!(at(t, 0x6005, 1), 1);
        assert_eq!(at(v, 0x1400, 5), 1); // RPDO deadline where the EDS has it
        assert!(v.steps.iter().all(|s| s.access.writable()));
    }

    /// A third profile planned with the same phases as the transducer and the valve: only its
    /// module (crates/canopen/src/cia404.rs) and its file are new.
    #[test]
    fn a_cia_404_device_is_planned_from_its_profile_and_file() {
        let text = include_str!("../../../configs/eds/ehactl_pressure_404.eds");
        let eds = Eds::parse(text, "ehactl_pressure_404.eds").unwrap();
        let c = CanopenConfig::default();
        let mut d = DevicePlan::from_file(&crate::cia404::Cia404, "test".into(), 64, eds).unwrap();
        d.plan_dcf_settings().unwrap();
        d.plan_error_control(&c).unwrap();
        d.plan_sync_objects(&c).unwrap();
        d.plan_profile(d.device, &c).unwrap();
        d.check_dcf_not_overridden().unwrap();
        assert_eq!((d.profile, d.identity), (404, (Some(0), Some(0x194))));
        let objs: Vec<(u16, u8)> = d.steps.iter().map(|s| (s.index, s.sub)).collect();
        let pos = |o: (u16, u8)| objs.iter().position(|x| *x == o).unwrap();
        // The sensor's consumer of ehactl's heartbeat is used where the device has it.
        let consumer = &d.steps[pos((0x1016, 1))];
        assert!(consumer.if_device_has);
        // Decimal digits 0 (Pa), then the TPDO1 re-mapping to 0x9130:01 (CiA 301: disable,
        // clear, map, count, enable).
        assert_eq!(d.steps[pos((0x6132, 1))].value, vec![0]);
        let map1 = d
            .steps
            .iter()
            .find(|s| (s.index, s.sub) == (0x1A00, 1))
            .unwrap();
        assert_eq!(map1.value, 0x9130_0120u32.to_le_bytes());
        assert!(pos((0x6132, 1)) < pos((0x1A00, 1)));
        let cob: Vec<&Step> = d
            .steps
            .iter()
            .filter(|s| (s.index, s.sub) == (0x1800, 1))
            .collect();
        assert_eq!(
            cob.first().unwrap().value,
            (0x8000_0000u32 | (0x180 + 64)).to_le_bytes()
        );
        assert_eq!(cob.last().unwrap().value, (0x180u32 + 64).to_le_bytes());
        // A 406 file is refused as a 404 device's, before the bus.
        let wrong = Eds::parse(BUILTIN_TRANSDUCER_EDS, "406.eds").unwrap();
        let e = DevicePlan::from_file(&crate::cia404::Cia404, "key".into(), 64, wrong).unwrap_err();
        assert!(e.to_string().contains("is no CiA 404 device"), "{e}");
    }

    /// `[[canopen.devices]]`: a further device is planned after the transducer and the valve
    /// from its profile's built-in file; an unknown profile, a second commanded device and a
    /// second device of a measurement already taken are refused before the bus, by key.
    #[test]
    fn further_devices_are_planned_in_order_or_refused_by_key() {
        use ehactl_types::canopen::CanopenDevice;
        let with = |profile: &str| {
            settings(CanopenConfig {
                devices: vec![CanopenDevice {
                    profile: profile.into(),
                    node_id: 64,
                    eds: String::new(),
                }],
                ..Default::default()
            })
        };
        let p = Plan::new(&with("cia404")).unwrap();
        let numbers: Vec<u16> = p.devices.iter().map(|d| d.profile).collect();
        assert_eq!(numbers, [406, 408, 404]);
        assert_eq!(p.nodes(), [32, 48, 64]);
        assert_eq!(p.commanded, 1);
        assert_eq!(p.devices[2].config_key, "canopen.devices[0].eds");
        assert_eq!(
            [
                p.devices[0].tpdo_len,
                p.devices[1].tpdo_len,
                p.devices[2].tpdo_len
            ],
            [Some(4), Some(4), Some(4)]
        );
        assert_eq!(p.devices[1].rpdo_len, Some(2));
        let refused = |profile: &str| Plan::new(&with(profile)).unwrap_err().to_string();
        let e = refused("cia999");
        assert!(e.contains("canopen.devices[0].profile") && e.contains("cia404, cia406, cia408"));
        assert!(refused("cia408").contains("moves the load"));
        assert!(refused("cia406").contains("would both set the same measurement"));
    }

    /// The commanded device's RPDO1 through its profile is the frame the backend sent for
    /// the valve before the seam (0x200 + node, the INT16 spool setpoint, 2 bytes), for
    /// commands inside, beyond and without full scale.
    #[test]
    fn the_valve_rpdo_through_its_profile_is_the_setpoint_frame() {
        for u in [0.0, 1.0, -3.3, 25.0, f64::NAN] {
            let sp = cia408::setpoint_from_command(u, 10.0);
            let want = CanFrame::std(RPDO1_BASE + 48, sp.to_le_bytes());
            assert_eq!(rpdo_frame(&cia408::Cia408, 48, 2, u, 10.0), want, "{u}");
        }
    }

    #[test]
    fn files_that_do_not_fit_are_refused_before_the_bus() {
        let dir = std::env::temp_dir().join(format!("ehactl_eds_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let w = |name: &str, text: String| {
            std::fs::write(dir.join(name), text).unwrap();
            name.to_string()
        };
        let run = |c: CanopenConfig| {
            let mut s = settings(c);
            s.config_dir = Some(dir.clone());
            Plan::new(&s).map(|_| ()).unwrap_err().to_string()
        };
        // the transducer file given as the valve's
        let e = run(CanopenConfig {
            valve_eds: w("t.eds", BUILTIN_TRANSDUCER_EDS.into()),
            ..Default::default()
        });
        assert!(
            e.contains("canopen.valve_eds") && e.contains("no CiA 408"),
            "{e}"
        );
        // no heartbeat consumer: no master-loss detection, refused
        let no_1016 = BUILTIN_VALVE_EDS.replace("[1016sub1]", "[1016subX]");
        let e = run(CanopenConfig {
            valve_eds: w("v.eds", no_1016),
            ..Default::default()
        });
        assert!(e.contains("0x1016:01") && e.contains("refuses"), "{e}");
        // a sensor without one is planned: used where the device has it (asked at start-up)
        let no_1016 = BUILTIN_TRANSDUCER_EDS.replace("[1016sub1]", "[1016subX]");
        let mut s = settings(CanopenConfig {
            transducer_eds: w("t_no1016.eds", no_1016),
            ..Default::default()
        });
        s.config_dir = Some(dir.clone());
        let p = Plan::new(&s).unwrap();
        let c = p.devices[0]
            .steps
            .iter()
            .find(|x| (x.index, x.sub) == (0x1016, 1))
            .unwrap();
        assert!(c.if_device_has && c.access == Access::Rw, "{c:?}");
        assert_eq!(c.value, 0x0001_0064u32.to_le_bytes()); // node 1, 100 ms
                                                           // with 0x1016 in the files: the valve's is mandatory, the transducer's if present
        let p = Plan::new(&settings(CanopenConfig::default())).unwrap();
        let has = |d: &DevicePlan| {
            d.steps
                .iter()
                .find(|x| (x.index, x.sub) == (0x1016, 1))
                .unwrap()
                .if_device_has
        };
        assert!(has(&p.devices[0]) && !has(&p.devices[1]));
        // position not PDO-mappable
        let e = run(CanopenConfig {
            transducer_eds: w(
                "t2.eds",
                BUILTIN_TRANSDUCER_EDS.replace(
                    "ParameterName=Position of magnet 1\nObjectType=0x7\nDataType=0x0004\nAccessType=ro\nDefaultValue=0\nPDOMapping=1",
                    "ParameterName=Position of magnet 1\nObjectType=0x7\nDataType=0x0004\nAccessType=ro\nDefaultValue=0\nPDOMapping=0",
                ),
            ),
            ..Default::default()
        });
        assert!(e.contains("not PDO-mappable"), "{e}");
        // a DCF value that ehactl would override
        let dcf = BUILTIN_TRANSDUCER_EDS.replace(
            "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\nAccessType=rw\nDefaultValue=0\n",
            "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\nAccessType=rw\nDefaultValue=0\nParameterValue=100\n",
        );
        assert!(dcf.contains("ParameterValue=100"));
        let e = run(CanopenConfig {
            transducer_eds: w("t.dcf", dcf),
            ..Default::default()
        });
        assert!(e.contains("the DCF sets 0x1017:00"), "{e}");
        let e = run(CanopenConfig {
            transducer_eds: "missing.eds".into(),
            ..Default::default()
        });
        assert!(
            e.contains("canopen.transducer_eds") && e.contains("missing.eds"),
            "{e}"
        );
        // a DCF setting of a device-specific object is planned first, as an Ensure step
        let dcf = BUILTIN_TRANSDUCER_EDS.replace(
            "[6000]\nParameterName=Operating parameters\nObjectType=0x7\nDataType=0x0006\nAccessType=rw\nDefaultValue=0x0000\n",
            "[6000]\nParameterName=Operating parameters\nObjectType=0x7\nDataType=0x0006\nAccessType=rw\nDefaultValue=0x0000\nParameterValue=0x0004\n",
        );
        let mut s = settings(CanopenConfig {
            transducer_eds: w("t3.dcf", dcf),
            ..Default::default()
        });
        s.config_dir = Some(dir.clone());
        let p = Plan::new(&s).unwrap();
        assert_eq!(p.devices[0].steps[0].index, 0x6000);
        assert_eq!(p.devices[0].steps[0].value, vec![4, 0]);
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// An EMCY a device sent before its boot-up belongs to the session before ehactl's NMT
    /// reset (e.g. the valve's RPDO deadline firing after the previous run ended, seen by
    /// the next run of the CAN demo 0.2 s later): its boot-up clears it. An EMCY after the
    /// boot-up ends the start-up as before.
    #[test]
    fn an_emcy_from_before_the_boot_up_is_the_previous_sessions() {
        let clock: Arc<dyn Clock> = Arc::new(crate::clock::ManualClock::at(0));
        let (tr, va) = (0x20u8, 0x30u8);
        let mut st = Startup::new(&[tr, va], false, clock);
        let emcy = |node: u8| {
            CanFrame::std(
                EMCY_BASE + u16::from(node),
                [0x50, 0x82, 0x11, 0, 0, 0, 0, 0],
            )
        };
        let boot = |node: u8| CanFrame::std(0x700 + u16::from(node), [0x00]);
        st.observe(&emcy(va), Direction::Rx);
        st.observe(&emcy(tr), Direction::Rx);
        st.observe(&boot(va), Direction::Rx);
        // the transducer's is still standing (it has not booted yet)
        let standing = |st: &Startup| {
            st.emcy
                .iter()
                .flatten()
                .map(|e| (e.node, e.code))
                .collect::<Vec<_>>()
        };
        assert_eq!(standing(&st), [(tr, 0x8250)]);
        st.observe(&boot(tr), Direction::Rx);
        assert_eq!(standing(&st), []);
        st.observe(&emcy(va), Direction::Rx);
        assert_eq!(standing(&st), [(va, 0x8250)]);
    }
}
