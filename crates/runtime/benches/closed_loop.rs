//! Closed-loop simulation speed and accuracy of the `sahu2022_force` rig (BENCHMARKS.md,
//! section "Closed-loop simulation speed").
//!
//! Run with `cargo bench -p ehactl-runtime --bench closed_loop`.
//!
//! What it measures, for the rig config `configs/sahu2022_force.toml` (PI force loop at
//! 5 kHz, 785 N + 196 N log chirp 1–300 Hz), 3 s simulated per run:
//!
//! 1. A convergence ladder of high-substep runs (22·2^k substeps per 200 µs period; 22 is the
//!    automatic count at the default `max_omega_h` = 0.25); the
//!    finest is the reference. Because every part of the plant scheme is first order in the
//!    substep h, the NRMSE between the two finest rungs bounds the reference's own error.
//! 2. For several substep counts: the median wall time of `EHACTL_BENCH_REPS` (default 7)
//!    repetitions of the whole loop (`run_sim` with no MCAP and no capture: one thread,
//!    nothing logged), the speed as simulated time / wall time (× real time), the time per
//!    cycle and per substep, and the NRMSE of the true rod force against the reference.
//! 3. The same at the config's automatic substep count with MCAP logging to a temporary file (the
//!    writer thread runs on the second core), reported separately.
//!
//! Two variants of the config are measured: `as configured` (sensor noise 1 N rms and the
//! 225/420 Hz tones, seed 4: every run sees the same noise sequence, so the comparison with
//! the reference measures only the integration error) and `noise-free` (noise 0, no tones),
//! which is the one `bench/scipy_baseline.py` compares against.
//!
//! NRMSE = sqrt(mean_k (F_k − F_ref,k)²) / (max_k F_ref,k − min_k F_ref,k), where F is the
//! plant's true rod force (`CycleRecord::plant.rod_force`, N) at the 15 000 control instants
//! t_k = k·200 µs, k = 0 … 14 999.
//!
//! Outputs: a markdown report on stdout and in `target/bench/closed_loop.md`, and CSV
//! traces and timings for the SciPy comparison in `target/bench/` (`reference_noisefree.csv`
//! with the reference's Richardson extrapolation as an extra column, `rust_sNN_noisefree.csv`,
//! `rust_timing_noisefree.csv`, `rust_timing_configured.csv`).
//!
//! Environment knobs: `EHACTL_BENCH_REPS` (timed repetitions, default 7),
//! `EHACTL_BENCH_DURATION` (simulated s per run, default 3.0), `EHACTL_BENCH_REF_LEVELS`
//! (rungs of the reference ladder above 22 substeps, default 7, i.e. up to 22·128 = 2816),
//! `EHACTL_BENCH_PROFILE=N` (profiling mode: only N timed runs of the configured rig at
//! `EHACTL_BENCH_SUBSTEPS`, default auto; for `perf record`).

use ehactl_config::RigConfig;
use ehactl_hal::record::CycleRecord;
use ehactl_runtime::session::{run_sim, Session, SessionOptions};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Substep counts of the timing table (the config's own automatic count is marked in the table).
const SUBSTEPS: [u32; 9] = [4, 6, 8, 11, 16, 22, 32, 44, 88];

/// Base of the reference ladder: the automatic count at the default `max_omega_h` = 0.25.
const REF_BASE: u32 = 22;

/// Substeps the config chooses itself (`integration.substeps` = 0: from `max_omega_h`).
fn auto_substeps(variant: Variant) -> u32 {
    ehactl_runtime::session::build_plant(&config(variant, 0))
        .expect("plant")
        .substeps()
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .expect("workspace root")
}

fn out_dir() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("target"));
    let d = target.join("bench");
    std::fs::create_dir_all(&d).expect("create target/bench");
    d
}

#[derive(Clone, Copy, PartialEq)]
enum Variant {
    AsConfigured,
    NoiseFree,
}

impl Variant {
    fn name(self) -> &'static str {
        match self {
            Variant::AsConfigured => "as configured (noise + tones)",
            Variant::NoiseFree => "noise-free",
        }
    }
    fn tag(self) -> &'static str {
        match self {
            Variant::AsConfigured => "configured",
            Variant::NoiseFree => "noisefree",
        }
    }
}

fn config(variant: Variant, substeps: u32) -> RigConfig {
    let path = workspace_root().join("configs/sahu2022_force.toml");
    let mut cfg = RigConfig::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    if variant == Variant::NoiseFree {
        cfg.plant.sensors.force.noise = 0.0;
        cfg.plant.effects.sensor_tone = None;
    }
    cfg.plant.integration.substeps = substeps;
    cfg
}

fn run(cfg: &RigConfig, duration: f64, capture: bool, mcap: Option<PathBuf>) -> (Session, f64) {
    let t0 = Instant::now();
    let s = run_sim(
        cfg,
        SessionOptions {
            duration: Some(duration),
            mcap,
            stop: None,
            capture,
            progress: None,
            observer: None,
            ..Default::default()
        },
    )
    .expect("run_sim");
    let total = t0.elapsed().as_secs_f64();
    assert!(
        s.outcome.trip.is_none(),
        "run tripped at {} substeps: {:?}",
        s.substeps,
        s.outcome.trip.map(|e| e.describe())
    );
    assert!(!s.outcome.interrupted);
    (s, total)
}

fn forces(s: &Session) -> Vec<f64> {
    s.records.iter().map(|r| r.plant.rod_force).collect()
}

/// RMS(f − r) / (max r − min r).
fn nrmse(f: &[f64], r: &[f64]) -> f64 {
    assert_eq!(f.len(), r.len());
    let n = r.len() as f64;
    let ss: f64 = f.iter().zip(r).map(|(a, b)| (a - b) * (a - b)).sum();
    let (lo, hi) = r
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    (ss / n).sqrt() / (hi - lo)
}

fn max_abs_diff(f: &[f64], r: &[f64]) -> f64 {
    f.iter()
        .zip(r)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max)
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

fn write_csv(path: &Path, records: &[CycleRecord], richardson: Option<&[f64]>) {
    let f = std::fs::File::create(path).expect("create csv");
    let mut w = std::io::BufWriter::new(f);
    // State at t_k before the period's step; i_term is the integrator after cycle k's update.
    writeln!(
        w,
        "cycle,t,setpoint,command,i_term,rod_force,meas_force,spool,spool_velocity,p_a,p_b,x,v{}",
        if richardson.is_some() {
            ",rod_force_richardson"
        } else {
            ""
        }
    )
    .unwrap();
    for (i, r) in records.iter().enumerate() {
        let p = &r.plant;
        write!(
            w,
            "{},{:.9},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e}",
            r.cycle,
            r.t,
            r.setpoint,
            r.command,
            r.i_term,
            p.rod_force,
            r.meas.force,
            p.spool,
            p.spool_velocity,
            p.p_a,
            p.p_b,
            p.x,
            p.v
        )
        .unwrap();
        match richardson {
            Some(rf) => writeln!(w, ",{:.17e}", rf[i]).unwrap(),
            None => writeln!(w).unwrap(),
        }
    }
}

struct Reference {
    substeps: u32,
    force: Vec<f64>,
    /// 2·F(N) − F(N/2): Richardson extrapolation of the two finest rungs (second order).
    richardson: Vec<f64>,
    records: Vec<CycleRecord>,
}

/// Convergence ladder 22·2^k; returns the finest run.
fn reference(variant: Variant, duration: f64, levels: u32, md: &mut String) -> Reference {
    let _ = writeln!(
        md,
        "\n#### Reference ladder, {}: {REF_BASE}·2^k substeps per 200 µs\n",
        variant.name()
    );
    let _ = writeln!(
        md,
        "| substeps | NRMSE vs previous rung | max abs diff vs previous rung (N) | min p_a, p_b (MPa) | wall (s) |"
    );
    let _ = writeln!(md, "|---:|---:|---:|---:|---:|");
    let mut prev: Option<Vec<f64>> = None;
    let mut last = None;
    for k in 0..=levels {
        let n = REF_BASE << k;
        let (s, _) = run(&config(variant, n), duration, true, None);
        let f = forces(&s);
        let pmin = s
            .records
            .iter()
            .map(|r| r.plant.p_a.min(r.plant.p_b))
            .fold(f64::INFINITY, f64::min);
        let (e, m) = match &prev {
            Some(p) => (
                format!("{:.3e} %", 100.0 * nrmse(p, &f)),
                format!("{:.3e}", max_abs_diff(p, &f)),
            ),
            None => ("–".into(), "–".into()),
        };
        let _ = writeln!(
            md,
            "| {n} | {e} | {m} | {:.2} | {:.2} |",
            pmin / 1e6,
            s.wall_time_s
        );
        eprintln!("  ladder {}: {n} substeps, {e}", variant.tag());
        let richardson = match &prev {
            Some(p) => f.iter().zip(p).map(|(a, b)| 2.0 * a - b).collect(),
            None => f.clone(),
        };
        prev = Some(f.clone());
        last = Some(Reference {
            substeps: n,
            force: f,
            richardson,
            records: s.records,
        });
    }
    let r = last.expect("at least one rung");
    let _ = writeln!(
        md,
        "\nReference = the {} substep run (h = {:.3} ns). The scheme is first order in h (each \
         rung halves the difference), so the reference's own NRMSE is about the last rung's \
         difference; against the Richardson extrapolation 2·F({}) − F({}) it is {:.2e} %.",
        r.substeps,
        2.0e5 / r.substeps as f64,
        r.substeps,
        r.substeps / 2,
        100.0 * nrmse(&r.force, &r.richardson)
    );
    r
}

struct Row {
    label: String,
    substeps: u32,
    walls: Vec<f64>,
    nrmse: f64,
    max_err: f64,
}

fn timing_table(
    variant: Variant,
    duration: f64,
    reps: usize,
    reference: &Reference,
    md: &mut String,
) {
    let auto = auto_substeps(variant);
    let mut rows: Vec<Row> = Vec::new();
    for &n in SUBSTEPS.iter() {
        let cfg = config(variant, n);
        // Accuracy run (capture on; deterministic, so identical to the timed runs).
        let (s, _) = run(&cfg, duration, true, None);
        let f = forces(&s);
        if variant == Variant::NoiseFree {
            write_csv(
                &out_dir().join(format!("rust_s{}_noisefree.csv", s.substeps)),
                &s.records,
                None,
            );
        }
        rows.push(Row {
            label: match n {
                n if n == auto => format!(
                    "**{n}** (config's auto, max_omega_h = {})",
                    cfg.plant.integration.max_omega_h
                ),
                22 => format!("{n} (auto at the default max_omega_h = 0.25)"),
                n => format!("{n}"),
            },
            substeps: s.substeps,
            walls: Vec::with_capacity(reps),
            nrmse: nrmse(&f, &reference.force),
            max_err: max_abs_diff(&f, &reference.force),
        });
    }
    // Warm-up, then round-robin repetitions so that drift of the machine hits every row alike.
    for &n in SUBSTEPS.iter() {
        let _ = run(&config(variant, n), duration.min(0.5), false, None);
    }
    for rep in 0..reps {
        for (i, &n) in SUBSTEPS.iter().enumerate() {
            let (s, _) = run(&config(variant, n), duration, false, None);
            rows[i].walls.push(s.wall_time_s);
        }
        eprintln!("  timing {}: repetition {}/{reps}", variant.tag(), rep + 1);
    }
    let cycles = (duration * 5000.0).round();
    let _ = writeln!(
        md,
        "\n#### Speed and accuracy, {}: {duration} s simulated, median of {reps} runs, one thread, no MCAP\n",
        variant.name()
    );
    let _ = writeln!(
        md,
        "| substeps / 200 µs | median wall (ms) | min–max wall (ms) | × real time (median) | µs / cycle | ns / substep | force NRMSE vs ref | max abs force error (N) | ≥ 200× and ≤ 0.5 % |"
    );
    let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|:---:|");
    let mut csv = String::from("substeps,duration_s,median_wall_s,min_wall_s,max_wall_s,nrmse\n");
    for r in &rows {
        let med = median(&r.walls);
        let _ = writeln!(
            csv,
            "{},{duration},{:.6e},{:.6e},{:.6e},{:.6e}",
            r.substeps,
            med,
            r.walls.iter().cloned().fold(f64::INFINITY, f64::min),
            r.walls.iter().cloned().fold(0.0, f64::max),
            r.nrmse
        );
        let lo = r.walls.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = r.walls.iter().cloned().fold(0.0, f64::max);
        let speed = duration / med;
        let ok = speed >= 200.0 && r.nrmse <= 0.005;
        let _ = writeln!(
            md,
            "| {} | {:.1} | {:.1}–{:.1} | {:.0}× | {:.3} | {:.1} | {:.4} % | {:.3} | {} |",
            r.label,
            med * 1e3,
            lo * 1e3,
            hi * 1e3,
            speed,
            med / cycles * 1e6,
            med / (cycles * r.substeps as f64) * 1e9,
            100.0 * r.nrmse,
            r.max_err,
            if ok { "yes" } else { "no" }
        );
    }
    std::fs::write(
        out_dir().join(format!("rust_timing_{}.csv", variant.tag())),
        csv,
    )
    .expect("write timing csv");
}

fn mcap_table(duration: f64, reps: usize, md: &mut String) {
    let cfg = config(Variant::AsConfigured, 0);
    let auto = auto_substeps(Variant::AsConfigured);
    let dir = std::env::temp_dir().join(format!("ehactl-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join("closed_loop.mcap");
    let mut loop_walls = Vec::new();
    let mut totals = Vec::new();
    let mut plain_walls = Vec::new();
    let mut plain_totals = Vec::new();
    let mut size = 0u64;
    let mut stats = String::new();
    let _ = run(&cfg, duration.min(0.5), false, Some(path.clone()));
    for _ in 0..reps {
        let (s, total) = run(&cfg, duration, false, Some(path.clone()));
        loop_walls.push(s.wall_time_s);
        totals.push(total);
        size = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        if let Some(l) = &s.log {
            stats = format!(
                "records written {}, dropped {}, pushes that waited {}, queue high water {} of {}",
                l.records_written,
                l.records_dropped,
                l.pushes_waited,
                l.queue_high_water,
                l.queue_capacity
            );
        }
        let (p, p_total) = run(&cfg, duration, false, None);
        plain_walls.push(p.wall_time_s);
        plain_totals.push(p_total);
    }
    let _ = std::fs::remove_dir_all(&dir);
    let m_loop = median(&loop_walls);
    let m_total = median(&totals);
    let m_plain = median(&plain_walls);
    let m_plain_total = median(&plain_totals);
    let _ = writeln!(
        md,
        "\n#### With MCAP logging, as configured ({auto} substeps, the config's auto): {duration} s simulated, median of {reps} runs (interleaved with runs without MCAP)\n"
    );
    let _ = writeln!(md, "| run | median wall (ms) | × real time |");
    let _ = writeln!(md, "|---|---:|---:|");
    let _ = writeln!(
        md,
        "| no MCAP (loop) | {:.1} | {:.0}× |",
        m_plain * 1e3,
        duration / m_plain
    );
    let _ = writeln!(
        md,
        "| no MCAP, whole `run_sim` call incl. plant set-up | {:.1} | {:.0}× |",
        m_plain_total * 1e3,
        duration / m_plain_total
    );
    let _ = writeln!(
        md,
        "| MCAP, loop only (writer thread on the other core) | {:.1} | {:.0}× |",
        m_loop * 1e3,
        duration / m_loop
    );
    let _ = writeln!(
        md,
        "| MCAP, whole `run_sim` call incl. plant set-up, logger start and the wait for the writer to flush and close | {:.1} | {:.0}× |",
        m_total * 1e3,
        duration / m_total
    );
    let _ = writeln!(
        md,
        "\nMCAP file {:.1} MiB (lz4), {stats}.",
        size as f64 / (1024.0 * 1024.0)
    );
}

fn main() {
    // `cargo bench` passes `--bench`; a filter argument is not supported (everything runs).
    let reps: usize = env_or("EHACTL_BENCH_REPS", 7usize).max(1);
    let duration: f64 = env_or("EHACTL_BENCH_DURATION", 3.0f64);
    let levels: u32 = env_or("EHACTL_BENCH_REF_LEVELS", 7u32);
    // Profiling mode: only the timed loop, as configured, at `EHACTL_BENCH_SUBSTEPS` (0 = auto),
    // repeated N times, e.g. `EHACTL_BENCH_PROFILE=100 perf record -g <bench binary>`.
    let profile: usize = env_or("EHACTL_BENCH_PROFILE", 0usize);
    if profile > 0 {
        let cfg = config(Variant::AsConfigured, env_or("EHACTL_BENCH_SUBSTEPS", 0u32));
        let walls: Vec<f64> = (0..profile)
            .map(|_| run(&cfg, duration, false, None).0.wall_time_s)
            .collect();
        let m = median(&walls);
        println!(
            "profile mode: {profile} runs of {duration} s, median wall {:.2} ms = {:.0}× real time",
            m * 1e3,
            duration / m
        );
        return;
    }
    let started = Instant::now();
    let mut md = String::new();
    let _ = writeln!(
        md,
        "### closed_loop bench: sahu2022_force, {duration} s simulated per run, {reps} timed repetitions"
    );
    let _ = writeln!(
        md,
        "\nNRMSE = RMS over the 5 kHz control instants of (rod force − reference rod force) / \
         (max − min of the reference rod force); rod force = `plant.rod_force`, the true force."
    );

    for variant in [Variant::AsConfigured, Variant::NoiseFree] {
        eprintln!("reference ladder, {}", variant.name());
        let r = reference(variant, duration, levels, &mut md);
        if variant == Variant::NoiseFree {
            write_csv(
                &out_dir().join("reference_noisefree.csv"),
                &r.records,
                Some(&r.richardson),
            );
        }
        eprintln!("timing, {}", variant.name());
        timing_table(variant, duration, reps, &r, &mut md);
    }
    eprintln!("MCAP");
    mcap_table(duration, reps.min(5), &mut md);
    let _ = writeln!(
        md,
        "\n(bench wall time {:.0} s; CSV traces in {})",
        started.elapsed().as_secs_f64(),
        out_dir().display()
    );
    println!("{md}");
    std::fs::write(out_dir().join("closed_loop.md"), &md).expect("write report");
}
