//! The default of every effect section's `enabled` switch (an effect is on when its section is
//! present). A leaf module so that the effect modules need neither the registry (`mod.rs`)
//! nor `crate::params`, which re-exports their sections (scripts/file_cycles.py).

/// `enabled = true`, the serde default of each section's switch.
pub(crate) fn yes() -> bool {
    true
}
