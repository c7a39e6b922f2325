//! The plant linearised around its operating point by `ehactl-analysis` (the same model as
//! `ehactl analyze`): sampled-data response P(e^{jωT}) of the controlled output per valve
//! volt, including the zero-order hold and any command delay, for model-based tuning.

use crate::config::Config;
use ehactl_analysis::linear::{self, Output};
use ehactl_analysis::loopshape::Law;
use ehactl_analysis::oppoint;
use ehactl_config::ControlMode;
use ehactl_plant::effects::time_delay;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::f64::consts::TAU;

/// Linearise `cfg` at its operating point (noise-free loop run to rest, at most `max_time`
/// s) and evaluate the discrete plant response at `f_hz` (Hz). Returns (real parts,
/// imaginary parts, info dict: output, u0_V, reference, feedback, settled, time_s, delay_s,
/// states). Units: N/V (force mode) or m/V (position mode).
#[pyfunction]
#[pyo3(signature = (cfg, f_hz, max_time = 5.0))]
pub fn linear_plant_response<'py>(
    py: Python<'py>,
    cfg: &Config,
    f_hz: Vec<f64>,
    max_time: f64,
) -> PyResult<(Vec<f64>, Vec<f64>, Bound<'py, PyDict>)> {
    let nyq = 0.5 / cfg.cfg.timebase().period();
    if let Some(f) = f_hz
        .iter()
        .find(|f| !(f.is_finite() && **f > 0.0 && **f < nyq))
    {
        return Err(PyValueError::new_err(format!(
            "frequency {f} Hz is outside (0, {nyq}) Hz, the band below the Nyquist frequency"
        )));
    }
    if !(max_time.is_finite() && max_time > 0.0) {
        return Err(PyValueError::new_err(format!(
            "max_time = {max_time} is not valid; expected a finite number > 0 in s"
        )));
    }
    let rc = cfg.cfg.clone();
    let out = py.detach(|| -> Result<_, String> {
        let op = oppoint::find(&rc, max_time).map_err(|e| e.to_string())?;
        let model = linear::discrete(&op).map_err(|e| e.to_string())?;
        let delay = time_delay::delay(rc.plant.effects.time_delay.as_ref());
        let output = match Law::from_config(&rc) {
            Some(l) => l.output(),
            None if rc.control.mode == ControlMode::OpenLoop
                && rc.plant.mechanics.load_stiffness > 0.0 =>
            {
                Output::Force
            }
            None => Output::Position,
        };
        let (re, im): (Vec<f64>, Vec<f64>) = f_hz
            .iter()
            .map(|&f| {
                let p = model.response(output, f);
                let (s, c) = (-TAU * f * delay).sin_cos(); // × e^(−jωτ)
                (p.re * c - p.im * s, p.re * s + p.im * c)
            })
            .unzip();
        Ok((re, im, op, delay, output, model.a.nrows()))
    });
    let (re, im, op, delay, output, n) = out.map_err(PyValueError::new_err)?;
    let info = PyDict::new(py);
    info.set_item(
        "output",
        match output {
            Output::Force => "force",
            Output::Position => "position",
        },
    )?;
    info.set_item("u0_V", op.u0)?;
    info.set_item("reference", op.reference)?;
    info.set_item("feedback", op.feedback)?;
    info.set_item("settled", op.settled)?;
    info.set_item("time_s", op.time_s)?;
    info.set_item("delay_s", delay)?;
    info.set_item("states", n)?;
    Ok((re, im, info))
}

/// Discrete controller response C(e^{jωT}) of `cfg`'s law (`ehactl-analysis`
/// `loopshape::Law`, the exact discrete PI / PD of the loop) at `f_hz` (Hz): (real parts,
/// imaginary parts) in V/N (force) or V/m (position). ValueError in open loop.
#[pyfunction]
pub fn controller_response(cfg: &Config, f_hz: Vec<f64>) -> PyResult<(Vec<f64>, Vec<f64>)> {
    let law = Law::from_config(&cfg.cfg).ok_or_else(|| {
        PyValueError::new_err("controller_response: open_loop mode has no controller")
    })?;
    let dt = cfg.cfg.timebase().period();
    Ok(f_hz
        .iter()
        .map(|&f| {
            let c = law.eval(nalgebra::Complex::from_polar(1.0, TAU * f * dt), Some(dt));
            (c.re, c.im)
        })
        .unzip())
}

/// Margins of a loop L sampled at `f_hz` (Hz, increasing) given as real and imaginary
/// parts (`ehactl-analysis` `loopshape::sampled_margins`): dict with crossover_hz,
/// phase_margin_deg, phase_crossover_hz, gain_margin_db, bandwidth_hz, peak_closed_db
/// (NaN where no crossing lies in the grid).
#[pyfunction]
pub fn sampled_margins<'py>(
    py: Python<'py>,
    f_hz: Vec<f64>,
    re: Vec<f64>,
    im: Vec<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    if f_hz.len() != re.len() || re.len() != im.len() {
        return Err(PyValueError::new_err(format!(
            "sampled_margins: {} frequencies but {} real and {} imaginary parts; expected one of each per frequency",
            f_hz.len(),
            re.len(),
            im.len()
        )));
    }
    let ascending = |w: &[f64]| w[1].partial_cmp(&w[0]) == Some(std::cmp::Ordering::Greater);
    let positive = |f: &f64| f.partial_cmp(&0.0) == Some(std::cmp::Ordering::Greater);
    if !f_hz.windows(2).all(ascending) || f_hz.first().is_some_and(|f| !positive(f)) {
        return Err(PyValueError::new_err(
            "sampled_margins: frequencies must be > 0 Hz and strictly increasing",
        ));
    }
    let l: Vec<nalgebra::Complex<f64>> = re
        .iter()
        .zip(&im)
        .map(|(&a, &b)| nalgebra::Complex::new(a, b))
        .collect();
    let m = ehactl_analysis::loopshape::sampled_margins(&f_hz, &l);
    let d = PyDict::new(py);
    d.set_item("crossover_hz", m.crossover_hz)?;
    d.set_item("phase_margin_deg", m.phase_margin_deg)?;
    d.set_item("phase_crossover_hz", m.phase_crossover_hz)?;
    d.set_item("gain_margin_db", m.gain_margin_db)?;
    d.set_item("bandwidth_hz", m.bandwidth_hz)?;
    d.set_item("peak_closed_db", m.peak_closed_db)?;
    Ok(d)
}
