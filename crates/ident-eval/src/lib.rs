//! # ehactl-ident-eval
//!
//! The evaluation harness of the diagnosis (`ehactl-ident`, `ehactl diagnose`): what makes the
//! measured-like records the diagnosis is graded on, kept out of the library the CLI and the
//! Python bindings compile.
//!
//! Modules: [`synth`] (seeded records of the test bench `configs/diagnose_testrig.toml` with
//! catalogue effects hidden in ehactl's own plant), [`hide`] (how each catalogue effect is
//! switched on in a plant config, one function per effect), [`limscore`] (small cases scored against the stated detection limits), [`indep`] (a second generator
//! written from the physics independently of `crates/plant`), [`rng`] (the synthetic cases'
//! generator). The evaluation examples (`evaluate`, `evaluate_indep`, `diagnose_speed`,
//! `integration_check`, `make_csv`) and the diagnosis' integration tests live in this crate's
//! `examples/` and `tests/`.
#![deny(missing_docs)]

pub mod hide;
pub mod indep;
pub mod limscore;
pub mod rng;
pub mod synth;
