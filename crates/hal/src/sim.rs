//! Simulation backend: the in-process nonlinear plant behind the [`Hal`] trait.

use crate::{Hal, HalError, Measurements, PlantState};
use ehactl_plant::Plant;

/// The plant as hardware: `read` samples the sensor models, `write` integrates one period.
#[derive(Debug, Clone)]
pub struct SimHal {
    plant: Plant,
}

impl SimHal {
    /// Wrap a configured plant.
    pub fn new(plant: Plant) -> Self {
        Self { plant }
    }

    /// The plant.
    pub fn plant(&self) -> &Plant {
        &self.plant
    }

    /// Mutable plant (set-up only, never from the cycle).
    pub fn plant_mut(&mut self) -> &mut Plant {
        &mut self.plant
    }
}

impl Hal for SimHal {
    fn name(&self) -> &'static str {
        "sim"
    }

    /// Samples the sensor models at the plant's current time. Real-time safe.
    fn read(&mut self, _t: f64, _period: f64) -> Result<Measurements, HalError> {
        Ok(self.plant.measure())
    }

    /// Advances the plant by one control period (`period` must equal the configured one).
    /// Real-time safe: fixed substeps, no allocation.
    fn write(&mut self, _t: f64, _period: f64, command: f64) -> Result<(), HalError> {
        self.plant.step(command).map_err(|e| HalError::Numerical {
            t: e.t,
            what: e.what,
        })
    }

    fn safe_stop(&mut self, _command: f64) -> Result<(), HalError> {
        Ok(())
    }

    fn plant_state(&self) -> Option<PlantState> {
        Some(*self.plant.state())
    }
}
