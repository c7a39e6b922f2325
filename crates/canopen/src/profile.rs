//! The device-profile seam: what the CiA 301 master (NMT, SDO, PDO, SYNC, heartbeat; the
//! start-up of crates/canopen/src/startup.rs) needs to know of a device profile, as one
//! [`Profile`] per CiA device profile and one line in `crate::profiles::PROFILES`
//! (crates/canopen/src/profiles.rs).
//!
//! The split follows ros2_canopen (a CiA 301 master with profile drivers beside it, as its
//! CiA 402 driver) and CANopenNode (the object dictionary the stack serves, the application
//! code that reads and writes it): a profile says which objects it sets at start-up, what
//! its PDOs map, how a received PDO becomes [`Measurements`] and, for a commanded device,
//! how the command becomes its setpoint; the master does the protocol.
//!
//! Profiles: [`crate::cia406`] (position transducer), [`crate::cia408`] (proportional valve),
//! [`crate::cia404`] (measuring device, one analogue input).

use crate::pdo::MapEntry;
use ehactl_hal::Measurements;
use ehactl_types::canopen::CanopenConfig;

/// One object a profile sets at start-up (an SDO step of the plan, crates/canopen/src/startup.rs:
/// read, and written where it differs).
#[derive(Debug, Clone, PartialEq)]
pub struct ProfileStep {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Value (little endian, the object's size).
    pub value: Vec<u8>,
    /// What it is for (start-up messages).
    pub what: String,
    /// Planned only if the device's EDS lists the object (else the step is left out).
    pub only_if_in_eds: bool,
    /// An optional feature: a device that answers "object does not exist" is used without it.
    pub optional: bool,
}

impl ProfileStep {
    /// A step the device must take.
    pub fn required(index: u16, sub: u8, value: Vec<u8>, what: impl Into<String>) -> Self {
        ProfileStep {
            index,
            sub,
            value,
            what: what.into(),
            only_if_in_eds: false,
            optional: false,
        }
    }

    /// A step planned where the EDS lists the object, optional on the bus.
    pub fn where_listed(index: u16, sub: u8, value: Vec<u8>, what: impl Into<String>) -> Self {
        ProfileStep {
            only_if_in_eds: true,
            optional: true,
            ..Self::required(index, sub, value, what)
        }
    }
}

/// Which PDO of the device (the first of each direction: CiA 301 default COB-IDs
/// 0x180 + node, 0x200 + node).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PdoDir {
    /// TPDO1: the device transmits on SYNC.
    Transmit,
    /// RPDO1: the device receives.
    Receive,
}

/// One PDO a profile maps at start-up.
#[derive(Debug, Clone, PartialEq)]
pub enum ProfilePdo {
    /// Map the PDO to `entries` (transmission on every SYNC).
    Map {
        /// Which PDO.
        dir: PdoDir,
        /// The mapped objects, in order.
        entries: &'static [MapEntry],
        /// What it is for (messages).
        what: &'static str,
    },
    /// Disable the PDO (COB-ID invalid bit).
    Disable {
        /// Which PDO.
        dir: PdoDir,
        /// What it is for (messages).
        what: &'static str,
    },
}

/// A received PDO that does not fit the profile's mapping.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DecodeError {
    /// Bytes received.
    pub got: usize,
    /// Bytes the mapping needs.
    pub need: usize,
}

impl std::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "PDO of {} bytes, the mapping needs {}",
            self.got, self.need
        )
    }
}

/// What the CiA 301 master needs to know of one CiA device profile. Every method is pure:
/// no bus, no clock, no allocation in [`Profile::decode`] and [`Profile::encode`] (they run
/// in the control cycle).
pub trait Profile: Sync {
    /// Short name for messages ("valve", "transducer", …).
    fn name(&self) -> &'static str;
    /// CiA profile number expected in the device type 0x1000 bits 0..15.
    fn number(&self) -> u16;
    /// Whether the device moves the load: it must then consume ehactl's heartbeat (0x1016)
    /// so that it stops the load itself when the master is lost, and ehactl refuses a file
    /// without that object. A sensor's consumer is used where the device has it.
    fn moves_the_load(&self) -> bool {
        false
    }
    /// The profile objects set at start-up, in order (after the CiA 301 communication
    /// objects, before the PDOs).
    fn start_steps(&self, c: &CanopenConfig) -> Vec<ProfileStep>;
    /// Objects the device's file must list although ehactl does not set them at start-up
    /// (index, sub, what).
    fn required_objects(&self) -> &'static [(u16, u8, &'static str)] {
        &[]
    }
    /// The PDOs, in the order they are mapped.
    fn pdos(&self, c: &CanopenConfig) -> Vec<ProfilePdo>;
    /// What a received TPDO1 (`data`, as mapped by [`Profile::pdos`]) sets in `m`; every
    /// other field is left as it is.
    fn decode(
        &self,
        c: &CanopenConfig,
        data: &[u8],
        m: &mut Measurements,
    ) -> Result<(), DecodeError>;
    /// The RPDO1 payload for the command `u` (V) of a device whose full scale is
    /// `full_scale_v` (V), for a commanded device; `None` for a sensor. Bounded: the payload
    /// never asks for more than the device's full scale, and a NaN command asks for zero.
    fn encode(&self, _u: f64, _full_scale_v: f64) -> Option<[u8; 8]> {
        None
    }
    /// The control words that walk the device's state machine from pre-operational to the
    /// state in which the command acts, in order (empty: a device without one).
    fn walk(&self) -> &'static [u16] {
        &[]
    }
    /// The control word of the safe stop (the state in which the device holds the load
    /// without a command from the bus), or `None` for a device that holds nothing.
    fn safe_stop(&self) -> Option<u16> {
        None
    }
    /// The object the control words of [`Profile::walk`] and [`Profile::safe_stop`] are
    /// written to (index, sub): the control word 0x6040 of CiA 402 and CiA 408.
    fn control_object(&self) -> (u16, u8) {
        (0x6040, 0)
    }
    /// What a received TPDO1 (`data`, as mapped) says of the device's state machine:
    /// `None` when it says nothing (a sensor); else the state's name, the status word and
    /// whether the command acts in it (any other state trips the run). No allocation.
    fn tpdo_state(&self, _data: &[u8]) -> Option<DeviceState> {
        None
    }
    /// The EDS of the project's simulated device of this profile (text, name for messages),
    /// used when the config names no file.
    fn builtin_eds(&self) -> Option<(&'static str, &'static str)> {
        None
    }
}

/// A device's state as its TPDO1 reports it ([`Profile::tpdo_state`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceState {
    /// The state's name ("ACTIVE", "HOLD", …).
    pub name: &'static str,
    /// The status word it was read from.
    pub word: u16,
    /// `None`: the command acts in this state; else why the run must trip.
    pub trip: Option<&'static str>,
}

/// Total size (bytes) of a PDO that maps `entries`.
pub fn mapped_bytes(entries: &[MapEntry]) -> usize {
    entries.iter().map(|e| usize::from(e.bits) / 8).sum()
}

/// Little-endian bytes `at..at + N` of `data`, or the error naming the size the mapping needs.
pub fn field<const N: usize>(data: &[u8], at: usize, need: usize) -> Result<[u8; N], DecodeError> {
    data.get(at..at + N)
        .and_then(|b| b.try_into().ok())
        .ok_or(DecodeError {
            got: data.len(),
            need,
        })
}

impl std::fmt::Debug for dyn Profile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "CiA {} {}", self.number(), self.name())
    }
}
