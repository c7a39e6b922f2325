//! Simulation backend: the in-process nonlinear plant behind the [`Hal`] trait. Here, beside
//! the sessions that build it, rather than in `ehactl-hal`: the contract stays bare (no
//! plant, no nalgebra), so that the CANopen backend compiles no physics.

use ehactl_hal::{Hal, HalError, Measurements, PlantState, Timebase};
use ehactl_plant::Plant;

/// Relative deviation of a measured period from the nominal one above which a cycle is
/// counted as off the grid (-).
const OFF_GRID_TOLERANCE: f64 = 0.1;

/// The plant as hardware: `read` samples the sensor models, `write` integrates one period.
///
/// The plant is discretised at the [`Timebase`] period, so each write advances exactly one
/// nominal period whatever the measured one: simulated time stays on the control grid. The
/// measured periods are checked: cycles more than 10 % off the nominal period (a late
/// wall-clock start under `--realtime`) are counted and reported in the summary
/// (`sim_off_grid_cycles`, `sim_max_period_s`), because the plant then runs slower than
/// the wall clock.
#[derive(Debug, Clone)]
pub struct SimHal {
    plant: Plant,
    timebase: Timebase,
    off_grid: u64,
    max_period: f64,
}

impl SimHal {
    /// Wrap a configured plant; its timebase is the plant's discretisation step.
    pub fn new(plant: Plant) -> Self {
        // `Plant::configure` accepted the period, so it is finite and > 0.
        let timebase = Timebase::at_rate_hz(1.0 / plant.control_dt());
        Self {
            plant,
            timebase,
            off_grid: 0,
            max_period: 0.0,
        }
    }

    /// The control timebase the plant was discretised with.
    pub fn timebase(&self) -> Timebase {
        self.timebase
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

    /// Advances the plant by one nominal control period and checks the measured `period`
    /// (s) against it. Real-time safe: fixed substeps, no allocation.
    fn write(&mut self, _t: f64, period: f64, command: f64) -> Result<(), HalError> {
        if period.is_finite() {
            self.max_period = self.max_period.max(period);
            if self.timebase.is_off(period, OFF_GRID_TOLERANCE) {
                self.off_grid += 1;
            }
        }
        self.plant.step(command).map_err(|e| {
            if e.is_implausible() {
                HalError::Implausible {
                    t: e.t,
                    what: e.what,
                    value: e.value,
                    bound: e.bound,
                    unit: e.unit,
                }
            } else {
                HalError::Numerical {
                    t: e.t,
                    what: e.what,
                }
            }
        })
    }

    fn safe_stop(&mut self, _command: f64) -> Result<(), HalError> {
        Ok(())
    }

    fn plant_state(&self) -> Option<PlantState> {
        Some(*self.plant.state())
    }

    /// Off-grid cycles only when there were any (simulated time never has them).
    fn report(&self) -> Option<serde_json::Value> {
        (self.off_grid > 0).then(|| {
            serde_json::json!({
                "sim_off_grid_cycles": self.off_grid,
                "sim_max_period_s": self.max_period,
            })
        })
    }
}
