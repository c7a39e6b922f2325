//! # ehactl-ident
//!
//! Model-discrepancy diagnosis (`ehactl diagnose`): given a record measured on a rig and the
//! nominal config of that rig, replay the measured valve command through the plant, find where
//! the residual concentrates (time, frequency, state space), fit every effect of the catalogue
//! of docs/design.md (with the nominal parameters refit within ±15 %), score each on held-out data
//! with a parameter penalty and accept effects greedily while the gain is significant.
//!
//! Modules: [`baseline`] (linear ARX reference model), [`data`] (CSV / MCAP loading and checks), [`replay`] (open-loop replay, NRMSE,
//! noise level), [`spectrum`] (Welch PSD, H1 frequency response), [`analysis`] (residual analysis), [`evidence`] (its findings and shared evidence rules), [`fit`] (nominal refit, bounded
//! Nelder–Mead), [`freeparam`] (a fit's free parameters and rig scales), [`effects`] (one module per catalogue effect: its fit parameters, variants and evidence score), [`ctx`] (the replay context and the hypotheses fitted in it), [`mod@diagnose`] (the decision), [`edge`] (a fit at the edge of its range is not a cause), [`limits`] (detection limits of the effects not named), `weigh` (a weak round winner against the runner-up, the order of the accepted causes), [`greybox`] (rod-force law from a term library when the catalogue is exhausted), [`report`] (JSON, extended config, Markdown),
//! [`session`] (one complete diagnosis as the CLI and Python run it), [`progress`] (progress
//! reports through the caller's callback; the library draws nothing).
//!
//! The evaluation harness (the seeded synthetic and independent cases, how each effect is
//! hidden in them, the evaluation examples and the integration tests) is the dev-only crate
//! `ehactl-ident-eval` (crates/ident-eval), which this library does not depend on.
#![deny(missing_docs)]

pub mod analysis;
pub mod band;
pub mod baseline;
pub mod campaign;
pub mod campaign_run;
pub mod ctx;
pub mod data;
pub mod diagnose;
pub mod edge;
pub mod effects;
pub mod envelope;
pub mod evidence;
pub mod fit;
pub mod freeparam;
pub mod greybox;
pub mod limits;
pub mod loopid;
pub mod motion;
pub mod nexttest;
pub mod outdir;
pub mod plots;
pub mod predict;
pub mod progress;
pub mod record_checks;
pub mod replay;
pub mod report;
pub mod residual;
pub mod session;
pub mod signlsq;
pub mod spectrum;
pub(crate) mod weigh;

pub use data::{load, ChannelKind, DataError, Record};
pub use diagnose::{diagnose, Diagnosis, Options};
