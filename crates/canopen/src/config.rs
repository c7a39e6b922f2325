//! The `[canopen]` section of the rig config. Compatibility path, to be removed: the section
//! moved to `ehactl_types::canopen` (crates/types/src/canopen.rs) so that `ehactl-config`
//! reads it without depending on the CANopen master.

pub use ehactl_types::canopen::*;
