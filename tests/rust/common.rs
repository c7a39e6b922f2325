//! Shared helpers for the integration tests.

use ehactl_controller::RigConfig;
use ehactl_plant::PlantParams;
use std::path::PathBuf;

/// Repository root.
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Load a config from configs/.
pub fn config(name: &str) -> RigConfig {
    RigConfig::load(&repo().join("configs").join(name)).expect("config loads")
}

/// A minimal blocked-cylinder plant: zero-lapped valve held closed, the 003 cylinder,
/// given mass and damping, no effects. Used for closed-form checks.
pub fn blocked_cylinder(mass: f64, damping: f64, x0: f64) -> PlantParams {
    let text = format!(
        r#"
[fluid]
density = 900.0
bulk_modulus = 1.8e9
[supply]
pressure = 24.0e6
[valve]
command_full_scale = 10.0
flow_form = "kq"
rated_flow = 5.8333e-4
rated_pressure_drop = 1.0e6
[cylinder]
area_a = 1.96e-3
area_b = 1.3e-3
dead_volume_a = 1.0e-4
dead_volume_b = 1.0e-4
stroke = 1.2
initial_position = {x0}
[mechanics]
mass = {mass}
damping = {damping}
end_stops = false
"#
    );
    toml::from_str(&text).expect("valid plant")
}
