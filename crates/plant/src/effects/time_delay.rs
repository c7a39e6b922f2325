//! `time_delay`: transport / communication delay on the valve command: the config section
//! [`TimeDelay`] (`[effects.time_delay]`). The delay line is the plant's command buffer
//! (crates/plant/src/model.rs).

use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// `time_delay`: transport / communication delay on the valve command.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TimeDelay {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Delay (s).
    #[param(unit = "s", range = Within(0.0, 1.0), desc = "command delay")]
    pub delay: f64,
}

impl TimeDelay {
    /// Check: the delay is at most 1 s.
    pub(crate) fn validate_delay(&self) -> Result<(), ConfigError> {
        if self.delay > 1.0 {
            return Err(ConfigError::new(
                "effects.time_delay.delay",
                "must be ≤ 1 s",
            ));
        }
        Ok(())
    }
}

/// The command delay (s) of the section `s`, 0 when it is absent or switched off
/// (`Plant::configure`, crates/plant/src/model.rs).
pub(crate) fn delay(s: Option<&TimeDelay>) -> f64 {
    s.filter(|d| d.enabled).map_or(0.0, |d| d.delay)
}
