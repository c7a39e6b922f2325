//! # ehactl-log
//!
//! The run log of ehactl, beside the hardware abstraction (`ehactl-hal`) that produces what
//! it records:
//! - [`record`], the fixed-size per-cycle records and their CDR encoding and decoding (the
//!   events themselves are `ehactl_types::event`, re-exported here),
//! - [`logger`], the MCAP writer fed through a bounded lock-free queue from another thread
//!   (the MCAP records are written by a private hand-written writer, `mcap_writer.rs`),
//! - [`schemas`], the JSON schemas of the JSON channels, and
//! - [`outpath`], where a log may be written (never over an input or a file that is not
//!   an MCAP log),
//! - [`recover`], rebuilding a valid MCAP file from a damaged or cut-off log,
//! - [`mcap_read`], reading an MCAP file as a stream, checked record by record.
#![deny(missing_docs)]

pub mod logger;
pub mod mcap_read;
mod mcap_writer;
pub mod outpath;
pub mod record;
pub mod recover;
pub mod schemas;
