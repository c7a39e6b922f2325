//! `Plant`: the bare simulated actuator, stepped one control period at a time from Python
//! (for simulated CAN devices, custom controllers and identification experiments). It is
//! `ehactl_plant::Plant` itself: configure → initialize → step(u) / measure().

use crate::config::{config_err, Config};
use crate::NumericalError;
use ehactl_plant::{Measurements, Plant as RustPlant, PlantState};
use numpy::{IntoPyArray, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The simulated plant of a config, advanced in control periods with a held valve command.
#[pyclass(module = "ehactl", name = "Plant")]
pub struct Plant {
    plant: RustPlant,
}

fn meas_dict<'py>(py: Python<'py>, m: &Measurements) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("t", m.t)?;
    d.set_item("force", m.force)?;
    d.set_item("position", m.position)?;
    d.set_item("p_a", m.p_a)?;
    d.set_item("p_b", m.p_b)?;
    d.set_item("spool", m.spool)?;
    Ok(d)
}

fn state_dict<'py>(py: Python<'py>, s: &PlantState) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("t", s.t)?;
    d.set_item("command", s.command)?;
    d.set_item("spool", s.spool)?;
    d.set_item("spool_velocity", s.spool_velocity)?;
    d.set_item("p_a", s.p_a)?;
    d.set_item("p_b", s.p_b)?;
    d.set_item("p_s", s.p_s)?;
    d.set_item("x", s.x)?;
    d.set_item("v", s.v)?;
    d.set_item("x_load", s.x_load)?;
    d.set_item("v_load", s.v_load)?;
    d.set_item("q_a", s.q_a)?;
    d.set_item("q_b", s.q_b)?;
    d.set_item("friction", s.friction)?;
    d.set_item("external", s.external)?;
    d.set_item("rod_force", s.rod_force)?;
    d.set_item("stuck", s.stuck)?;
    Ok(d)
}

fn check_u(u: f64) -> PyResult<()> {
    if u.is_finite() {
        Ok(())
    } else {
        Err(PyValueError::new_err(format!(
            "valve command u = {u} is not finite; expected a finite number in V"
        )))
    }
}

/// Most control periods one `Plant.step` call advances (a bound against a mistyped `n`:
/// 1e12 periods would take days).
const MAX_STEPS: u64 = 1_000_000_000;

/// Periods between two checks for a pending signal (Ctrl-C) in `Plant.step`: about 0.1 s
/// of CPU at 1 µs per period.
const SIGNAL_EVERY: u64 = 100_000;

fn numerical(e: ehactl_plant::NumericalFailure) -> PyErr {
    NumericalError::new_err(e.to_string())
}

#[pymethods]
impl Plant {
    /// Configure and initialise the plant of `cfg` at its control period
    /// (1 / run.control_rate_hz, s), or at `control_dt` (s) if given.
    #[new]
    #[pyo3(signature = (cfg, control_dt = None))]
    fn new(cfg: &Config, control_dt: Option<f64>) -> PyResult<Plant> {
        let dt = control_dt.unwrap_or_else(|| cfg.cfg.timebase().period());
        if !(dt.is_finite() && dt > 0.0) {
            return Err(PyValueError::new_err(format!(
                "control_dt = {dt} is not valid; expected a finite number > 0 in s"
            )));
        }
        let plant = RustPlant::configure(&cfg.cfg.plant, dt).map_err(config_err)?;
        Ok(Plant { plant })
    }

    /// Back to the initial state (t = 0, at rest, sensor noise generator re-seeded).
    fn reset(&mut self) {
        self.plant.initialize();
    }

    /// Advance `n` control periods (at most 1e9 per call) holding the valve command `u_volts`
    /// (V). Raises NumericalError if the state becomes non-finite or implausible, ValueError
    /// for `n` above the bound. The GIL is released meanwhile; Ctrl-C is honoured every
    /// 100 000 periods (KeyboardInterrupt, the plant advanced by the periods done).
    #[pyo3(signature = (u_volts, n = 1))]
    fn step(&mut self, py: Python<'_>, u_volts: f64, n: u64) -> PyResult<()> {
        check_u(u_volts)?;
        if n > MAX_STEPS {
            return Err(PyValueError::new_err(format!(
                "n = {n} control periods is above the bound of {MAX_STEPS:e} per call (about 20 min of CPU at 1 µs per period); call step repeatedly for longer runs"
            )));
        }
        let plant = &mut self.plant;
        if n == 1 {
            return plant.step(u_volts).map_err(numerical);
        }
        py.detach(|| {
            let mut done = 0;
            while done < n {
                let chunk = SIGNAL_EVERY.min(n - done);
                for _ in 0..chunk {
                    plant.step(u_volts).map_err(numerical)?;
                }
                done += chunk;
                if done < n {
                    Python::attach(|py| py.check_signals())?;
                }
            }
            Ok(())
        })
    }

    /// Apply a command sequence `u` (V, one value per control period) and return the sensor
    /// readings taken at the start of each period, as a dict of NumPy arrays (t s, force N,
    /// position m, p_a Pa, p_b Pa, spool fraction). Open-loop identification helper.
    fn run_commands<'py>(
        &mut self,
        py: Python<'py>,
        u: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let u: Vec<f64> = u.as_slice()?.to_vec();
        if let Some((i, x)) = u.iter().enumerate().find(|(_, x)| !x.is_finite()) {
            return Err(PyValueError::new_err(format!(
                "u[{i}] = {x} is not finite; expected finite valve commands in V"
            )));
        }
        let plant = &mut self.plant;
        let n = u.len();
        let out = py.detach(|| {
            let mut cols: [Vec<f64>; 6] = std::array::from_fn(|_| Vec::with_capacity(n));
            for &uk in &u {
                let m = plant.measure();
                for (c, v) in cols
                    .iter_mut()
                    .zip([m.t, m.force, m.position, m.p_a, m.p_b, m.spool])
                {
                    c.push(v);
                }
                plant.step(uk)?;
            }
            Ok(cols)
        });
        let cols = out.map_err(numerical)?;
        let d = PyDict::new(py);
        for (name, c) in ["t", "force", "position", "p_a", "p_b", "spool"]
            .into_iter()
            .zip(cols)
        {
            d.set_item(name, c.into_pyarray(py))?;
        }
        Ok(d)
    }

    /// Sample every sensor now: dict t (s), force (N), position (m), p_a, p_b (Pa),
    /// spool (fraction of travel). Noise and tones as configured; NaN for absent channels.
    fn measure<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let m = self.plant.measure();
        meas_dict(py, &m)
    }

    /// Ground-truth state (SI units): t, command (V after delay), spool, spool_velocity,
    /// p_a, p_b, p_s (Pa), x (m), v (m/s), x_load, v_load, q_a, q_b (m³/s), friction,
    /// external, rod_force (N), stuck (bool).
    fn state<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        state_dict(py, self.plant.state())
    }

    /// Simulated time (s).
    #[getter]
    fn t(&self) -> f64 {
        self.plant.state().t
    }

    /// Control period (s): one `step` advances this much.
    #[getter]
    fn control_dt(&self) -> f64 {
        self.plant.control_dt()
    }

    /// Integration substeps per control period.
    #[getter]
    fn substeps(&self) -> u32 {
        self.plant.substeps()
    }

    /// Hydraulic stiffness A₁²β/V₁ + A₂²β/V₂ at piston position `x` (m), in N/m (003 eq. 15).
    fn hydraulic_stiffness(&self, x: f64) -> f64 {
        self.plant.hydraulic_stiffness(x)
    }

    /// Chamber volumes (V_A, V_B) at piston position `x` (m), in m³ (003 eq. 7–8).
    fn volumes(&self, x: f64) -> (f64, f64) {
        self.plant.volumes(x)
    }

    fn __repr__(&self) -> String {
        format!(
            "Plant(t={} s, control_dt={} s, substeps={})",
            self.plant.state().t,
            self.plant.control_dt(),
            self.plant.substeps()
        )
    }
}
