//! # ehactl-fmu
//!
//! ehactl's model as an FMI 2.0 co-simulation FMU (Functional Mock-up Interface 2.0,
//! Modelica Association 2014), for Simulink, OpenModelica, Dymola, Hopsan or FMPy:
//! - [`ffi`] — the C API of the FMU's one generic binary (`ehactl_fmu.so`), which reads the
//!   config from the FMU's `resources/` at instantiate and runs the plant crate with the
//!   substep integration of `ehactl run` (`ehactl_runtime::sim::SimHal`), and for the closed
//!   loop the cycle of `ehactl run` (`ehactl_runtime::runloop::step_cycles`),
//! - [`instance`] — one instance's state and its checks (modes, ranges, step sizes),
//! - [`variables`] — the variables of a config and variant (outputs, inputs, every registry
//!   parameter the config holds), shared by the export and the binary,
//! - [`xml`] — the model description (`modelDescription.xml`),
//! - [`export`] — the `.fmu` file (`ehactl export-fmu`),
//! - [`zip`] — its container.
//!
//! docs/fmu.md is the user's page.
#![deny(missing_docs)]

pub mod export;
pub mod ffi;
pub mod instance;
pub mod variables;
pub mod xml;
pub mod zip;

/// The FMU's model identifier: the binary is `binaries/<platform>/ehactl_fmu.so`.
pub const MODEL_IDENTIFIER: &str = "ehactl_fmu";

/// The file name cargo gives the shared library (`lib` + crate name + `.so`).
pub const LIBRARY_FILE: &str = "libehactl_fmu.so";
