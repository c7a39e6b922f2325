//! Python bindings of ehactl (`ehactl._ehactl`, wrapped by the pure-Python package
//! `ehactl`). Everything physical runs in the same compiled crates as the CLI:
//! `ehactl-plant` (plant), `ehactl-analysis` (linearisation), `ehactl-control` (PI/PD, setpoints, supervisor), `ehactl-config`, `ehactl-runtime` (loop,
//! `session::run_sim`) and `ehactl-log` (records, MCAP logger). The GIL is released while
//! Rust simulates; batches run in parallel on a rayon pool.
#![deny(missing_docs)]

mod analysis;
mod campaign;
mod columns;
mod config;
mod diagnose;
mod fmu;
mod linear;
mod mcapread;
mod plant;
mod runs;

use pyo3::prelude::*;

pyo3::create_exception!(
    _ehactl,
    NumericalError,
    pyo3::exceptions::PyRuntimeError,
    "The simulated plant produced a non-finite state (raised by Plant.step)."
);

/// The compiled core of the `ehactl` package.
#[pymodule]
fn _ehactl(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("NumericalError", m.py().get_type::<NumericalError>())?;
    m.add_class::<config::Config>()?;
    m.add_class::<plant::Plant>()?;
    m.add_function(wrap_pyfunction!(config::param_table, m)?)?;
    m.add_function(wrap_pyfunction!(runs::run_one, m)?)?;
    m.add_function(wrap_pyfunction!(runs::run_batch, m)?)?;
    m.add_function(wrap_pyfunction!(runs::record_fields, m)?)?;
    m.add_function(wrap_pyfunction!(mcapread::read_mcap_raw, m)?)?;
    m.add_function(wrap_pyfunction!(linear::linear_plant_response, m)?)?;
    m.add_function(wrap_pyfunction!(linear::controller_response, m)?)?;
    m.add_function(wrap_pyfunction!(linear::sampled_margins, m)?)?;
    m.add_function(wrap_pyfunction!(analysis::analyze_json, m)?)?;
    m.add_function(wrap_pyfunction!(analysis::sweep_json, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose::diagnose_json, m)?)?;
    m.add_function(wrap_pyfunction!(campaign::campaign_json, m)?)?;
    m.add_function(wrap_pyfunction!(campaign::predict_json, m)?)?;
    m.add_function(wrap_pyfunction!(fmu::export_fmu_file, m)?)?;
    Ok(())
}
