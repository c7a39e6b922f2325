//! The `[canopen]` section of the rig config (see the ICD), its parameter registry and
//! the bus load of the configured PDO set.
//!
//! Bus load: every SYNC period carries SYNC (0 bytes), the transducer TPDO1 (position,
//! 4 bytes), the valve RPDO1 (setpoint, 2 bytes) and, with `valve_status_pdo`, the valve
//! TPDO1 (status word + actual spool, 4 bytes); heartbeats of the devices add
//! 1-byte frames every `heartbeat_ms`, ehactl's own heartbeat one every `master_heartbeat_ms`. A classic frame with an 11-bit id and N data bytes
//! takes at most `8N + 47 + floor((34 + 8N − 1)/4)` bit times with worst-case bit stuffing
//! (55 bits for N = 0, 75 for N = 2, 95 for N = 4). At 1 Mbit/s SYNC + 4-byte position +
//! 2-byte setpoint therefore take 225 µs per SYNC period (320 µs with the valve status
//! TPDO): 22.5 % (32 %) of the bus at 1 kHz. A further device (`[[canopen.devices]]`) adds
//! one TPDO counted as 8 bytes (135 bit times) per SYNC period and one heartbeat producer.
//! Configs above 80 % are refused. 1 kHz is the practical ceiling: the remaining time in
//! each period is what SDO traffic, EMCY, heartbeats, error frames / retransmissions and the devices' SYNC-to-TPDO processing
//! need, and the loop closes over CAN only once per SYNC anyway.

use crate::spec::{self, ConfigError, Param};
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};
use std::sync::LazyLock;

/// `[canopen]` (all fields optional, defaults as in the ICD).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Params)]
#[serde(deny_unknown_fields, default)]
pub struct CanopenConfig {
    /// Bit rate (bit/s).
    #[param(unit = "bit/s", range = Within(10e3, 1e6), desc = "CAN bit rate (ICD default 1 Mbit/s)")]
    pub bitrate: u32,
    /// SYNC producer rate (Hz).
    #[param(unit = "Hz", range = Within(1.0, 10e3), desc = "SYNC producer rate; CAN I/O rate, sample-and-hold to the control rate")]
    pub sync_rate_hz: f64,
    /// Heartbeat producer time written to each device's 0x1017 (ms).
    #[param(unit = "ms", range = Within(1.0, 65535.0), desc = "heartbeat producer time written to 0x1017 of each device")]
    pub heartbeat_ms: u16,
    /// Heartbeat consumer timeout of the master (ms).
    #[param(unit = "ms", range = Within(1.0, 65535.0), desc = "master's heartbeat consumer timeout (> heartbeat_ms)")]
    pub heartbeat_timeout_ms: u32,
    /// Time allowed for every device's boot-up (s).
    #[param(unit = "s", range = Within(0.01, 600.0), desc = "time allowed for every device's boot-up")]
    pub boot_timeout_s: f64,
    /// SDO response timeout (ms).
    #[param(unit = "ms", range = Within(1.0, 60000.0), desc = "SDO response timeout")]
    pub sdo_timeout_ms: u32,
    /// Node id of the CiA 406 position transducer.
    #[param(unit = "-", range = Within(1.0, 127.0), desc = "node id of the CiA 406 position transducer (ICD 32 = 0x20)")]
    pub transducer_node_id: u8,
    /// Node id of the CiA 408 valve.
    #[param(unit = "-", range = Within(1.0, 127.0), desc = "node id of the CiA 408 valve (ICD 48 = 0x30)")]
    pub valve_node_id: u8,
    /// Position step written to 0x6005:01 (nm).
    #[param(unit = "nm", range = Within(1.0, 1e9), desc = "position step written to 0x6005:01")]
    pub position_step_nm: u32,
    /// Map the valve TPDO1 (status word + actual spool).
    #[param(unit = "bool", range = Finite, desc = "map valve TPDO1 (status word + actual spool); true or false")]
    pub valve_status_pdo: bool,
    /// Node id of ehactl itself (the NMT master's heartbeat is 0x700 + this id).
    #[param(unit = "-", range = Within(1.0, 127.0), desc = "node id of ehactl (its heartbeat COB-ID is 0x700 + id)")]
    pub master_node_id: u8,
    /// Heartbeat producer time of ehactl (ms): the control cycle sends 0x700 + master id
    /// `[05]` this often.
    #[param(unit = "ms", range = Within(1.0, 65535.0), desc = "heartbeat producer time of ehactl (sent by the control cycle)")]
    pub master_heartbeat_ms: u16,
    /// Consumer time of ehactl's heartbeat written to 0x1016:01 of every device (ms): a
    /// device that hears no master heartbeat for this long enters its fault reaction
    /// (valve: FAULT_HOLD, see DEPLOY.md).
    #[param(unit = "ms", range = Within(1.0, 65535.0), desc = "consumer time of ehactl's heartbeat written to 0x1016:01 of every device (> master_heartbeat_ms)")]
    pub device_heartbeat_timeout_ms: u16,
    /// EDS / DCF of the transducer (path, relative to the config file; `""` = the built-in
    /// EDS of the project's simulated transducer, configs/eds/ehactl_transducer_406.eds).
    /// Identity, object set, access types and DCF `ParameterValue`s drive the start-up.
    #[serde(skip_serializing_if = "String::is_empty")]
    pub transducer_eds: String,
    /// EDS / DCF of the valve (as `transducer_eds`; built-in: ehactl_valve_408.eds).
    #[serde(skip_serializing_if = "String::is_empty")]
    pub valve_eds: String,
    /// SYNC counter overflow value written to 0x1019 of every device that has it (0 = SYNC
    /// without counter, else 2..240: SYNC carries a counter 1..this value, CiA 301 7.5.2.22).
    #[param(unit = "-", range = Within(0.0, 240.0), desc = "SYNC counter overflow value written to 0x1019 where the EDS has it (0 = no counter, else 2..240)")]
    pub sync_counter_overflow: u8,
    /// Synchronous window length written to 0x1007 of every device that has it (µs, 0 = off).
    #[param(unit = "µs", range = Within(0.0, 4.0e9), desc = "synchronous window length written to 0x1007 where the EDS has it (0 = off; < SYNC period)")]
    pub sync_window_us: u32,
    /// PDO age limit (SYNC periods): a synchronous TPDO answering SYNC k that arrives after
    /// SYNC k + 1 is late (counted); one older than this many SYNC periods trips.
    #[param(unit = "SYNC periods", range = Within(1.0, 1.0e6), desc = "a synchronous TPDO older than this many SYNC periods on arrival trips (later than the next SYNC: counted)")]
    pub max_pdo_age_syncs: u32,
    /// RPDO deadline written to the valve's RPDO1 event timer 0x1400:05 where its EDS has it
    /// (ms, 0 = off): a valve that gets no setpoint for this long reacts as to a master loss.
    #[param(unit = "ms", range = Within(0.0, 65535.0), desc = "valve RPDO1 event timer 0x1400:05 (setpoint deadline) where the EDS has it (0 = off; > 2 SYNC periods)")]
    pub valve_rpdo_timeout_ms: u16,
    /// Further devices besides the transducer and the valve (`[[canopen.devices]]`), brought
    /// up, supervised, decoded and stopped as they are; empty by default.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub devices: Vec<CanopenDevice>,
}

/// One further device of the rig (`[[canopen.devices]]`): a CANopen node whose device
/// profile ehactl knows (crates/canopen/src/profiles.rs), read into the measurements its
/// profile decodes.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct CanopenDevice {
    /// Its device profile, `"cia"` + the CiA profile number (e.g. `"cia404"`, a measuring
    /// device); checked against the profiles ehactl knows before the bus is opened.
    pub profile: String,
    /// Node id (1..127, unique on the bus).
    pub node_id: i64,
    /// EDS / DCF of the device (path, relative to the config file; `""` = the built-in EDS
    /// of the profile's simulated device, e.g. configs/eds/ehactl_pressure_404.eds).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub eds: String,
}

impl Default for CanopenConfig {
    fn default() -> Self {
        CanopenConfig {
            bitrate: 1_000_000,
            sync_rate_hz: 1000.0,
            heartbeat_ms: 20,
            heartbeat_timeout_ms: 60,
            boot_timeout_s: 3.0,
            sdo_timeout_ms: 500,
            transducer_node_id: 32,
            valve_node_id: 48,
            position_step_nm: 1000,
            valve_status_pdo: true,
            master_node_id: 1,
            master_heartbeat_ms: 20,
            device_heartbeat_timeout_ms: 100,
            transducer_eds: String::new(),
            valve_eds: String::new(),
            sync_counter_overflow: 0,
            sync_window_us: 0,
            max_pdo_age_syncs: 50,
            valve_rpdo_timeout_ms: 100,
            devices: Vec::new(),
        }
    }
}

/// Registry of the `[canopen]` parameters (for `ehactl params` and config checks),
/// generated from the `#[param(...)]` declarations on the fields of [`CanopenConfig`].
pub fn canopen_params() -> &'static [Param] {
    static TABLE: LazyLock<Vec<Param>> = LazyLock::new(|| spec::table::<CanopenConfig>("canopen"));
    &TABLE
}

/// Largest bus load accepted (fraction).
pub const MAX_BUS_LOAD: f64 = 0.80;

/// Worst-case length (bit times) of a classic data frame with an 11-bit id and
/// `n` data bytes, including bit stuffing: 8N + 47 + floor((34 + 8N − 1)/4).
pub const fn frame_bits(n: u32) -> u32 {
    8 * n + 47 + (34 + 8 * n - 1) / 4
}

/// Bus load of one configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BusLoad {
    /// Bit times of the frames sent every SYNC period.
    pub bits_per_sync: u32,
    /// Time those frames occupy per SYNC period (s).
    pub time_per_sync_s: f64,
    /// Total load including heartbeats (fraction, 0..1+).
    pub load: f64,
}

impl CanopenConfig {
    /// Data lengths (bytes) of the frames sent every SYNC period.
    /// A further device's TPDO1 is counted as 8 bytes (the longest classic frame): its
    /// mapping is its profile's (crates/canopen/src), which this crate does not know.
    pub fn frames_per_sync(&self) -> Vec<u32> {
        let mut v = vec![0, 4, 2];
        if self.valve_status_pdo {
            v.push(4);
        }
        v.extend(self.devices.iter().map(|_| 8));
        v
    }

    /// Worst-case bus load of the configured PDO set and heartbeats.
    pub fn bus_load(&self) -> BusLoad {
        let bits: u32 = self.frames_per_sync().into_iter().map(frame_bits).sum();
        let br = f64::from(self.bitrate.max(1));
        let producers = 2.0 + self.devices.len() as f64;
        let hb = producers * f64::from(frame_bits(1))
            / (f64::from(self.heartbeat_ms.max(1)) * 1e-3)
            + f64::from(frame_bits(1)) / (f64::from(self.master_heartbeat_ms.max(1)) * 1e-3);
        BusLoad {
            bits_per_sync: bits,
            time_per_sync_s: f64::from(bits) / br,
            load: (f64::from(bits) * self.sync_rate_hz + hb) / br,
        }
    }

    /// Cross-field checks (ranges are checked by the registry).
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.transducer_node_id == self.valve_node_id {
            return Err(ConfigError::new(
                "canopen.valve_node_id",
                format!(
                    "node id {} is also the transducer's; expected two distinct node ids 1..127",
                    self.valve_node_id
                ),
            ));
        }
        if u32::from(self.heartbeat_ms) >= self.heartbeat_timeout_ms {
            return Err(ConfigError::new(
                "canopen.heartbeat_timeout_ms",
                format!(
                    "consumer timeout {} ms must exceed the producer time heartbeat_ms = {} ms (typically 2-3×)",
                    self.heartbeat_timeout_ms, self.heartbeat_ms
                ),
            ));
        }
        for (what, id) in [
            ("transducer", self.transducer_node_id),
            ("valve", self.valve_node_id),
        ] {
            if id == self.master_node_id {
                return Err(ConfigError::new(
                    "canopen.master_node_id",
                    format!(
                        "node id {id} is also the {what}'s; expected a node id 1..127 that no device uses"
                    ),
                ));
            }
        }
        self.validate_devices()?;
        if self.device_heartbeat_timeout_ms <= self.master_heartbeat_ms {
            return Err(ConfigError::new(
                "canopen.device_heartbeat_timeout_ms",
                format!(
                    "device consumer time {} ms must exceed ehactl's producer time master_heartbeat_ms = {} ms (typically 3-5×)",
                    self.device_heartbeat_timeout_ms, self.master_heartbeat_ms
                ),
            ));
        }
        if self.sync_counter_overflow == 1 {
            return Err(ConfigError::new(
                "canopen.sync_counter_overflow",
                "1 is no SYNC counter overflow value; expected 0 (no counter) or 2..240 (CiA 301 0x1019)",
            ));
        }
        let sync_period_us = 1e6 / self.sync_rate_hz;
        if f64::from(self.sync_window_us) >= sync_period_us {
            return Err(ConfigError::new(
                "canopen.sync_window_us",
                format!(
                    "synchronous window {} µs must be shorter than the SYNC period {sync_period_us:.0} µs (or 0 = off)",
                    self.sync_window_us
                ),
            ));
        }
        if self.valve_rpdo_timeout_ms != 0
            && (f64::from(self.valve_rpdo_timeout_ms) * 1e3 <= 2.0 * sync_period_us
                || self.valve_rpdo_timeout_ms <= self.master_heartbeat_ms)
        {
            return Err(ConfigError::new(
                "canopen.valve_rpdo_timeout_ms",
                format!(
                    "RPDO deadline {} ms must exceed two SYNC periods ({:.3} ms; the setpoint RPDO comes once per SYNC) and master_heartbeat_ms = {} ms (the keep-alive period before the first cycle), or be 0 = off",
                    self.valve_rpdo_timeout_ms,
                    2.0 * sync_period_us * 1e-3,
                    self.master_heartbeat_ms
                ),
            ));
        }
        let l = self.bus_load();
        if l.load > MAX_BUS_LOAD {
            return Err(ConfigError::new(
                "canopen.sync_rate_hz",
                format!(
                    "bus load {:.1} % exceeds {:.0} %: {} bit times ({:.0} µs) per SYNC at {} Hz on {} bit/s plus heartbeats; lower sync_rate_hz or raise bitrate",
                    l.load * 100.0,
                    MAX_BUS_LOAD * 100.0,
                    l.bits_per_sync,
                    l.time_per_sync_s * 1e6,
                    self.sync_rate_hz,
                    self.bitrate
                ),
            ));
        }
        Ok(())
    }
}

impl CanopenConfig {
    /// `[[canopen.devices]]`: a profile name of the form `cia<number>` (whether ehactl knows
    /// the profile is checked by the CANopen backend, which holds the profiles), node ids in
    /// 1..127 that no other node of the rig uses (CiA 301 7.3.1: one node per id).
    fn validate_devices(&self) -> Result<(), ConfigError> {
        let mut taken: Vec<(i64, String)> = vec![
            (
                i64::from(self.transducer_node_id),
                "the transducer's (canopen.transducer_node_id)".into(),
            ),
            (
                i64::from(self.valve_node_id),
                "the valve's (canopen.valve_node_id)".into(),
            ),
            (
                i64::from(self.master_node_id),
                "ehactl's own (canopen.master_node_id)".into(),
            ),
        ];
        for (i, d) in self.devices.iter().enumerate() {
            let at = format!("canopen.devices[{i}]");
            let number = d.profile.strip_prefix("cia").unwrap_or("");
            if number.is_empty() || !number.bytes().all(|b| b.is_ascii_digit()) {
                return Err(ConfigError::new(
                    format!("{at}.profile"),
                    format!(
                        "\"{}\" is no device profile name; expected \"cia\" and the CiA profile number, e.g. \"cia404\" (a measuring device)",
                        d.profile
                    ),
                ));
            }
            if !(1..=127).contains(&d.node_id) {
                return Err(ConfigError::new(
                    format!("{at}.node_id"),
                    format!(
                        "node id {} is out of range; expected 1..127 (CiA 301 node ids)",
                        d.node_id
                    ),
                ));
            }
            if let Some((_, whose)) = taken.iter().find(|(id, _)| *id == d.node_id) {
                return Err(ConfigError::new(
                    format!("{at}.node_id"),
                    format!(
                        "node id {} is also {whose}; expected a node id 1..127 that no other node uses",
                        d.node_id
                    ),
                ));
            }
            taken.push((d.node_id, format!("that of {at}")));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_lengths_match_the_worst_case_formula() {
        assert_eq!(frame_bits(0), 55);
        assert_eq!(frame_bits(2), 75);
        assert_eq!(frame_bits(4), 95);
        assert_eq!(frame_bits(8), 64 + 47 + 24);
    }

    #[test]
    fn sync_position_setpoint_take_225_us_at_1_mbit() {
        let c = CanopenConfig {
            valve_status_pdo: false,
            ..Default::default()
        };
        let l = c.bus_load();
        assert_eq!(l.bits_per_sync, 225);
        assert!((l.time_per_sync_s - 225e-6).abs() < 1e-12);
        // + 2 device heartbeats and the master's of 65 bits every 20 ms.
        assert!((l.load - (0.225 + 3.0 * 65.0 / 0.02 / 1e6)).abs() < 1e-12);
        let d = CanopenConfig::default().bus_load();
        assert_eq!(d.bits_per_sync, 320);
        assert!(CanopenConfig::default().validate().is_ok());
    }

    #[test]
    fn further_devices_are_checked_and_counted() {
        let dev = |profile: &str, node_id: i64| CanopenDevice {
            profile: profile.into(),
            node_id,
            eds: String::new(),
        };
        let with = |devices: Vec<CanopenDevice>| CanopenConfig {
            devices,
            ..Default::default()
        };
        assert!(with(vec![dev("cia404", 64), dev("cia404", 65)])
            .validate()
            .is_ok());
        let e = with(vec![dev("cia404", 64), dev("cia404", 64)])
            .validate()
            .unwrap_err();
        assert_eq!(e.path, "canopen.devices[1].node_id");
        assert!(e.message.contains("also that of canopen.devices[0]"), "{e}");
        let e = with(vec![dev("cia404", 48)]).validate().unwrap_err();
        assert_eq!(e.path, "canopen.devices[0].node_id");
        assert!(e.message.contains("the valve's"), "{e}");
        let e = with(vec![dev("cia404", 1)]).validate().unwrap_err();
        assert!(e.message.contains("ehactl's own"), "{e}");
        for bad in [0, 128, -3] {
            let e = with(vec![dev("cia404", bad)]).validate().unwrap_err();
            assert_eq!(e.path, "canopen.devices[0].node_id");
            assert!(e.message.contains("expected 1..127"), "{e}");
        }
        for bad in ["404", "cia", "ciaXYZ", "CiA404"] {
            let e = with(vec![dev(bad, 64)]).validate().unwrap_err();
            assert_eq!(e.path, "canopen.devices[0].profile", "{bad}");
        }
        // one more 8-byte TPDO per SYNC and one more heartbeat producer
        let base = CanopenConfig::default().bus_load();
        let more = with(vec![dev("cia404", 64)]).bus_load();
        assert_eq!(more.bits_per_sync - base.bits_per_sync, frame_bits(8));
        let hb = f64::from(frame_bits(1)) / 0.02 / 1e6;
        let per_sync = f64::from(frame_bits(8)) * 1000.0 / 1e6;
        assert!((more.load - base.load - per_sync - hb).abs() < 1e-12);
    }

    #[test]
    fn overload_and_inconsistent_settings_are_refused() {
        let c = CanopenConfig {
            sync_rate_hz: 4000.0,
            ..Default::default()
        };
        let e = c.validate().unwrap_err();
        assert_eq!(e.path, "canopen.sync_rate_hz");
        assert!(e.message.contains("exceeds 80 %"), "{e}");
        let c = CanopenConfig {
            bitrate: 250_000,
            ..Default::default()
        };
        assert!(c.validate().is_err(), "1 kHz at 250 kbit/s is 128 %");
        let c = CanopenConfig {
            valve_node_id: 32,
            ..Default::default()
        };
        assert_eq!(c.validate().unwrap_err().path, "canopen.valve_node_id");
        let c = CanopenConfig {
            heartbeat_timeout_ms: 20,
            ..Default::default()
        };
        assert_eq!(
            c.validate().unwrap_err().path,
            "canopen.heartbeat_timeout_ms"
        );
        let c = CanopenConfig {
            master_node_id: 48,
            ..Default::default()
        };
        let e = c.validate().unwrap_err();
        assert_eq!(e.path, "canopen.master_node_id");
        assert!(e.message.contains("valve"), "{e}");
        let c = CanopenConfig {
            device_heartbeat_timeout_ms: 20,
            ..Default::default()
        };
        assert_eq!(
            c.validate().unwrap_err().path,
            "canopen.device_heartbeat_timeout_ms"
        );
    }
}
