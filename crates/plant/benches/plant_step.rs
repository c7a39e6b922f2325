//! Cost of `Plant::step` on every shipped rig (configs/*.toml), open loop.
//!
//! Run with `cargo bench -p ehactl-plant --bench plant_step [-- NAME…]` (NAME: a config's
//! file stem, e.g. `dindorf2022_boom`; all configs without one).
//!
//! For each rig: its plant sections (the rig config less its control, setpoint, run, …
//! sections), discretised at its `run.control_rate_hz`, stepped for `EHACTL_BENCH_SECONDS`
//! (default 0.5 s) of simulated time under a 5 Hz sine command of 10 % of the valve's full
//! scale (V). Prints the median over `EHACTL_BENCH_REPS` (default 7) repetitions of the wall
//! time per control cycle (ns) and the substeps taken per cycle. Under
//! `valgrind --tool=callgrind --toggle-collect='ehactl_plant::model::Plant::step'` with
//! `EHACTL_BENCH_REPS=1` it gives the instructions of the plant step alone, per rig
//! (BENCHMARKS.md, "The plant step per rig").

use ehactl_plant::params::PlantParams;
use ehactl_plant::Plant;
use std::time::Instant;

/// The plant sections of the rig config `path` and its control period (s).
fn plant_params(path: &std::path::Path) -> (PlantParams, f64) {
    let text = std::fs::read_to_string(path).expect("config");
    let mut root: toml::Value = toml::from_str(&text).expect("toml");
    let t = root.as_table_mut().expect("a TOML table");
    let rate = t["run"]["control_rate_hz"]
        .as_float()
        .expect("run.control_rate_hz");
    for k in [
        "rig",
        "control",
        "setpoint",
        "supervisor",
        "run",
        "inputs",
        "log",
        "realtime",
        "canopen",
    ] {
        t.remove(k);
    }
    let p = root
        .try_into()
        .unwrap_or_else(|e| panic!("{}: plant sections: {e}", path.display()));
    (p, 1.0 / rate)
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let reps: usize = env_or("EHACTL_BENCH_REPS", 7);
    let seconds: f64 = env_or("EHACTL_BENCH_SECONDS", 0.5);
    let only: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
    let mut configs: Vec<_> = std::fs::read_dir(&dir)
        .expect("configs/")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    configs.sort();
    println!("| rig | substeps / cycle | median ns / cycle |");
    println!("|---|---|---|");
    for path in configs {
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        if !only.is_empty() && !only.contains(&name) {
            continue;
        }
        let (p, dt) = plant_params(&path);
        let amplitude = 0.1 * p.valve.command_full_scale;
        let cycles = (seconds / dt).round() as usize;
        let mut plant = Plant::configure(&p, dt).expect("plant");
        let mut times = Vec::with_capacity(reps);
        let mut substeps = 0;
        for _ in 0..reps {
            plant.initialize();
            let before = plant.substeps_taken();
            let t0 = Instant::now();
            for k in 0..cycles {
                let u = amplitude * (k as f64 * dt * 2.0 * std::f64::consts::PI * 5.0).sin();
                plant.step(u).expect("a plausible state");
            }
            times.push(t0.elapsed().as_secs_f64());
            substeps = plant.substeps_taken() - before;
            std::hint::black_box(plant.state());
        }
        times.sort_by(f64::total_cmp);
        let med = times[reps / 2];
        println!(
            "| {name} | {:.1} | {:.1} |",
            substeps as f64 / cycles as f64,
            med / cycles as f64 * 1e9
        );
    }
}
