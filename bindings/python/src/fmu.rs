//! `ehactl.export_fmu` for Python: the same export as `ehactl export-fmu` (crates/fmu), the
//! library to pack found by the Python side (`ehactl._fmu`).

use ehactl_fmu::export::{write_fmu, Export};
use ehactl_fmu::variables::Variant;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::path::PathBuf;

/// Write the FMU of the config `config_text` (TOML) to `out`: the closed loop or the plant,
/// with `binaries` as (platform directory, library path) pairs. ValueError with the loader's
/// message for a config it refuses, an unreadable library or a failed write.
#[pyfunction]
pub fn export_fmu_file(
    config_text: &str,
    out: PathBuf,
    closed_loop: bool,
    binaries: Vec<(String, PathBuf)>,
) -> PyResult<()> {
    let e = Export {
        config_text,
        variant: if closed_loop {
            Variant::ClosedLoop
        } else {
            Variant::Plant
        },
        binaries,
    };
    write_fmu(&e, &out).map_err(PyValueError::new_err)
}
