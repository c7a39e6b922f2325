//! Cost of the plant's command path (the `time_delay` delay line, read at every substep) in
//! the real-time step.
//!
//! Run with `cargo bench -p ehactl-plant --bench command_path`.
//!
//! Rig: the plant of configs/sahu2022_force.toml (Sahu 2022 force rig, 5 kHz, 2 substeps per
//! period: the command path is read twice per period, the largest share of any shipped rig)
//! without `[effects.time_delay]`, with a delay of 1.55 control periods (0.31 ms: every
//! substep mixes two commands) and of 10 periods (2 ms). For each case: the median over
//! `EHACTL_BENCH_REPS` (default 7) repetitions of the wall time of 2 s simulated of
//! `Plant::step` calls with a 35 Hz sine command of 2 V, reported as ns per control cycle
//! and as × real time.

use ehactl_plant::params::{PlantParams, TimeDelay};
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
    println!("| rig | time_delay (s) | substeps / cycle | median ns / cycle | × real time |");
    println!("|---|---|---|---|---|");
    for delay in [None, Some(3.1e-4), Some(2e-3)] {
        let (mut p, dt) = plant_params("sahu2022_force.toml");
        p.effects.time_delay = delay.map(|delay| TimeDelay {
            enabled: true,
            delay,
        });
        let cycles = (2.0 / dt).round() as usize;
        let mut plant = Plant::configure(&p, dt).expect("plant");
        let mut times = Vec::with_capacity(reps);
        for _ in 0..reps {
            plant.initialize();
            let t0 = Instant::now();
            for k in 0..cycles {
                let u = 2.0 * (k as f64 * dt * 2.0 * std::f64::consts::PI * 35.0).sin();
                plant.step(u).expect("finite");
            }
            times.push(t0.elapsed().as_secs_f64());
            std::hint::black_box(plant.state());
        }
        times.sort_by(f64::total_cmp);
        let med = times[reps / 2];
        println!(
            "| sahu2022_force | {} | {} | {:.1} | {:.0}× |",
            delay.map_or("none".to_string(), |d| format!("{d:e}")),
            plant.substeps(),
            med / cycles as f64 * 1e9,
            cycles as f64 * dt / med
        );
    }
}
