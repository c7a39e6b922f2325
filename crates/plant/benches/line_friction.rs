//! Cost of the `line_dynamics` wall-friction models in the plant's real-time step.
//!
//! Run with `cargo bench -p ehactl-plant --bench line_friction`.
//!
//! Rigs: the plant of configs/cristofori2015_crane.toml (Cristofori 2015 crane, 2.5 m hoses with 8
//! segments, 1 kHz control rate) and of configs/sirohi2003_circuit.toml (Sirohi 2003 pump →
//! 11.5 in tube → output cylinder, 5 kHz; a stiff reproduction circuit, not a real-time rig)
//! with `segments` ∈ {4, 16, 64}; `friction` ∈ {steady, unsteady (8 convolution states per
//! segment), unsteady_trikha (3)}. For each case: the automatic substep count, and the median
//! over `EHACTL_BENCH_REPS` (default 7) repetitions of the wall time of 1 s simulated of
//! `Plant::step` calls with the valve command held at 0.5 V plus a small 35 Hz sine, reported
//! as µs per control cycle and as × real time, plus the ratio to steady friction.

use ehactl_plant::params::{LineFriction, PlantParams};
use ehactl_plant::Plant;
use std::time::Instant;

fn plant_params(config: &str) -> (PlantParams, f64) {
    let path = format!("{}/../../configs/{config}", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(path).expect("config");
    let mut root: toml::Value = toml::from_str(&text).expect("toml");
    let t = root.as_table_mut().unwrap();
    let rate = t["run"]["control_rate_hz"]
        .as_float()
        .expect("run.control_rate_hz");
    // Keep only the plant sections (the rig config also holds control, setpoint, run, …).
    for k in ["rig", "control", "setpoint", "supervisor", "run"] {
        t.remove(k);
    }
    (root.try_into().expect("plant params"), 1.0 / rate)
}

fn main() {
    let reps: usize = std::env::var("EHACTL_BENCH_REPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(7);
    println!("| rig | segments | friction | substeps / cycle | median µs / cycle | × real time | vs steady |");
    println!("|---|---|---|---|---|---|---|");
    for (config, segments) in [
        ("cristofori2015_crane.toml", 4u32),
        ("cristofori2015_crane.toml", 16),
        ("cristofori2015_crane.toml", 64),
        ("sirohi2003_circuit.toml", 4),
        ("sirohi2003_circuit.toml", 16),
        ("sirohi2003_circuit.toml", 64),
    ] {
        let mut steady_us = f64::NAN;
        for friction in [
            LineFriction::Steady,
            LineFriction::Unsteady,
            LineFriction::UnsteadyTrikha,
        ] {
            let (mut p, dt) = plant_params(config);
            let cycles = (1.0 / dt).round() as usize;
            let l = p.effects.line_dynamics.as_mut().unwrap();
            l.segments = segments;
            l.friction = friction;
            let mut plant = Plant::configure(&p, dt).expect("plant");
            let mut times = Vec::with_capacity(reps);
            for _ in 0..reps {
                plant.initialize();
                let t0 = Instant::now();
                for k in 0..cycles {
                    let u = 0.5 + 0.1 * (k as f64 * dt * 2.0 * std::f64::consts::PI * 35.0).sin();
                    plant.step(u).expect("finite");
                }
                times.push(t0.elapsed().as_secs_f64());
                std::hint::black_box(plant.state());
            }
            times.sort_by(f64::total_cmp);
            let med = times[reps / 2];
            let us = med / cycles as f64 * 1e6;
            if friction == LineFriction::Steady {
                steady_us = us;
            }
            println!(
                "| {config} | {segments} | {} | {} | {us:.2} | {:.1}× | {:.2} |",
                LineFriction::NAMES[friction as usize],
                plant.substeps(),
                cycles as f64 * dt / med,
                us / steady_us
            );
        }
    }
}
