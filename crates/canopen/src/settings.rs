//! [`CanopenSettings`]: everything the CANopen backend needs besides the bus, shared by the
//! start-up ([`crate::startup`]) and the run-time backend ([`crate::hal`]).

use crate::bus::BusUrl;
use ehactl_types::canopen::CanopenConfig;
use std::path::PathBuf;

/// Everything the backend needs besides the bus.
#[derive(Debug, Clone)]
pub struct CanopenSettings {
    /// Bus address.
    pub bus: BusUrl,
    /// `[canopen]` section.
    pub canopen: CanopenConfig,
    /// Valve command for 100 % spool (V), `plant.valve.command_full_scale`.
    pub command_full_scale: f64,
    /// Control rate (Hz), `run.control_rate_hz`.
    pub control_rate_hz: f64,
    /// Command of the safe stop (V), `supervisor.safe_command`: must be closed centre
    /// (spool setpoint 0) on a CAN valve, checked before the bus is opened.
    pub safe_command: f64,
    /// Print start-up progress on stderr.
    pub verbose: bool,
    /// Directory of the config file: relative `canopen.transducer_eds` / `valve_eds` /
    /// `devices[i].eds` paths are taken from here (None: the current directory).
    pub config_dir: Option<PathBuf>,
}
