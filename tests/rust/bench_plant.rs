//! Accuracy against cost of the plant integration, per shipped rig (BENCHMARKS.md, section
//! "Plant integration: accuracy against cost per rig", in docs/benchmarks-archive.md).
//!
//! Run with `cargo bench -p ehactl-tests --bench plant_accuracy` (all rigs) or
//! `cargo bench -p ehactl-tests --bench plant_accuracy -- sahu2022_force ideko_machine_tool`.
//!
//! For every rig config `configs/<rig>.toml`, over `EHACTL_BENCH_DURATION` simulated seconds
//! (default: the config's `run.duration`, at most 3 s), closed loop as configured (sensor noise
//! on: the noise sequence is the same in every run, so differences are integration error):
//!
//! 1. Reference: `exponential_euler` at `EHACTL_BENCH_REF_MULT` (default 16) times the
//!    automatic substeps at the default ω·h ≤ 0.25, and at half that; the scheme is first
//!    order, so the NRMSE between the two bounds the finer one's own error (column "ref err").
//! 2. Each candidate (method, substeps): NRMSE of the controlled variable (rod force in force
//!    mode, piston position otherwise) and of the chamber-A pressure against the reference,
//!    over the whole run; NRMSE = RMS(y − y_ref)/(max y_ref − min y_ref).
//! 3. Cost: `EHACTL_BENCH_REPS` (default 5) timed runs of every candidate, interleaved
//!    (rep 1 of every candidate, then rep 2, …), `run_sim` without MCAP and without capture
//!    (one thread, nothing logged); median wall time of the loop (`Session::wall_time_s`) and
//!    median CPU time of the calling thread over the whole `run_sim` call
//!    (`CLOCK_THREAD_CPUTIME_ID`), both as × real time. On a shared machine the CPU-time
//!    figure is the one to trust: it excludes time the thread was not running.
//!
//! `EHACTL_BENCH_SUBSTEPS=a,b,…`: also run the shipped method at these fixed substep counts
//! (a convergence ladder).
//! `EHACTL_BENCH_PROFILE=N`: only N runs of each selected rig as shipped (for `perf record`).
//!
//! Output: a markdown table on stdout and in `target/bench/plant_accuracy.md`; for
//! `sahu2022_force`, CSV traces for `bench/scipy_baseline.py` and `bench/python_fixed_step.py`
//! in `target/bench/` (`sahu_reference_noisefree.csv`, noise-free variant, and
//! `sahu_rust_timing_noisefree.csv`).

use ehactl_config::ControlMode;
use ehactl_config::RigConfig;
use ehactl_plant::params::{IntegrationMethod, LineMethod};
use ehactl_runtime::session::{build_plant, run_sim, Session, SessionOptions};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .canonicalize()
        .expect("workspace root")
}

fn out_dir() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("target"));
    let d = target.join("bench");
    std::fs::create_dir_all(&d).expect("create target/bench");
    d
}

fn thread_cpu_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid pointer to a timespec; CLOCK_THREAD_CPUTIME_ID is always available on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

fn load_avg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "?".into())
}

#[derive(Clone, Copy, PartialEq, Debug)]
struct Candidate {
    method: IntegrationMethod,
    /// Line scheme (rigs with `line_dynamics` only).
    line: LineMethod,
    /// `max_omega_h_line` (symplectic line scheme's segment-mode margin; None = max_omega_h).
    line_moh: Option<f64>,
    /// 0 = automatic.
    substeps: u32,
    max_omega_h: Option<f64>,
    shipped: bool,
}

impl Candidate {
    /// `cfg` with this candidate's integration settings.
    fn config(&self, cfg: &RigConfig) -> RigConfig {
        with_line(
            cfg,
            self.method,
            self.line,
            self.line_moh,
            self.substeps,
            self.max_omega_h,
        )
    }
}

fn method_name(m: IntegrationMethod) -> &'static str {
    match m {
        IntegrationMethod::ExponentialEuler => "exponential_euler",
        IntegrationMethod::LinearExact => "linear_exact",
    }
}

fn with(cfg: &RigConfig, method: IntegrationMethod, substeps: u32, moh: Option<f64>) -> RigConfig {
    let ig = &cfg.plant.integration;
    with_line(
        cfg,
        method,
        ig.line_method,
        ig.max_omega_h_line,
        substeps,
        moh,
    )
}

fn with_line(
    cfg: &RigConfig,
    method: IntegrationMethod,
    line: LineMethod,
    line_moh: Option<f64>,
    substeps: u32,
    moh: Option<f64>,
) -> RigConfig {
    let mut c = cfg.clone();
    c.plant.integration.method = method;
    c.plant.integration.line_method = line;
    c.plant.integration.max_omega_h_line = line_moh;
    c.plant.integration.substeps = substeps;
    if let Some(m) = moh {
        c.plant.integration.max_omega_h = m;
    }
    c
}

fn run(cfg: &RigConfig, duration: f64, capture: bool) -> (Session, f64) {
    let c0 = thread_cpu_s();
    let s = run_sim(
        cfg,
        SessionOptions {
            duration: Some(duration),
            capture,
            ..Default::default()
        },
    )
    .expect("run_sim");
    let cpu = thread_cpu_s() - c0;
    assert!(
        s.outcome.trip.is_none(),
        "run tripped: {:?}",
        s.outcome.trip.map(|e| e.describe())
    );
    (s, cpu)
}

fn output(cfg: &RigConfig, s: &Session) -> (Vec<f64>, Vec<f64>) {
    let force = cfg.control.mode == ControlMode::Force;
    (
        s.records
            .iter()
            .map(|r| if force { r.plant.rod_force } else { r.plant.x })
            .collect(),
        s.records.iter().map(|r| r.plant.p_a).collect(),
    )
}

/// RMS(f − r) / (max r − min r).
fn nrmse(f: &[f64], r: &[f64]) -> f64 {
    let n = r.len().min(f.len());
    let ss: f64 = f[..n]
        .iter()
        .zip(&r[..n])
        .map(|(a, b)| (a - b) * (a - b))
        .sum();
    let (lo, hi) = r[..n]
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    (ss / n as f64).sqrt() / (hi - lo)
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

/// Candidates per rig: what ships, the old default rule, and the cheaper settings tried.
fn candidates(cfg: &RigConfig) -> Vec<Candidate> {
    let ee = IntegrationMethod::ExponentialEuler;
    let le = IntegrationMethod::LinearExact;
    let ig = &cfg.plant.integration;
    let sy = LineMethod::Symplectic;
    let im = LineMethod::Implicit;
    let mut v = vec![Candidate {
        method: ig.method,
        line: ig.line_method,
        line_moh: ig.max_omega_h_line,
        substeps: ig.substeps,
        max_omega_h: None,
        shipped: true,
    }];
    let mut push = |c: Candidate| {
        let probe = c.config(cfg);
        let same = probe.plant.integration == *ig;
        if !same && build_plant(&probe).is_ok() && !v.contains(&c) {
            v.push(c);
        }
    };
    push(Candidate {
        method: ee,
        line: sy,
        line_moh: None,
        substeps: 0,
        max_omega_h: Some(0.25),
        shipped: false,
    });
    // Before 2026-11-26 the automatic count was fixed at the smallest chamber volumes
    // (stroke ends) for the whole run: that is `substeps` = the worst-case count.
    if ig.method == ee {
        let worst = build_plant(&with_line(cfg, ee, sy, None, 0, None))
            .map(|p| p.substeps())
            .unwrap_or(0);
        if worst > 0 {
            push(Candidate {
                method: ee,
                line: sy,
                line_moh: None,
                substeps: worst,
                max_omega_h: None,
                shipped: false,
            });
        }
    }
    // Extra fixed counts of the shipped method, for convergence ladders:
    // EHACTL_BENCH_SUBSTEPS=92,184,368.
    let extra = std::env::var("EHACTL_BENCH_SUBSTEPS").unwrap_or_default();
    for n in extra
        .split(',')
        .filter_map(|x| x.trim().parse::<u32>().ok())
    {
        push(Candidate {
            method: ig.method,
            line: ig.line_method,
            line_moh: ig.max_omega_h_line,
            substeps: n,
            max_omega_h: None,
            shipped: false,
        });
    }
    let e = &cfg.plant.effects;
    // Line rigs (short stiff lines): both line schemes at fixed substeps and the
    // implicit scheme's automatic rule.
    if e.line_dynamics.as_ref().is_some_and(|l| l.enabled) {
        push(Candidate {
            method: ee,
            line: im,
            line_moh: None,
            substeps: 0,
            max_omega_h: Some(0.25),
            shipped: false,
        });
        for m in [1.0, 1.5] {
            push(Candidate {
                method: ee,
                line: sy,
                line_moh: Some(m),
                substeps: 0,
                max_omega_h: Some(0.25),
                shipped: false,
            });
        }
        for (line, n) in [
            (sy, 16),
            (sy, 24),
            (sy, 32),
            (sy, 64),
            (im, 4),
            (im, 8),
            (im, 12),
            (im, 16),
            (im, 24),
            (im, 32),
        ] {
            push(Candidate {
                method: ee,
                line,
                line_moh: None,
                substeps: n,
                max_omega_h: None,
                shipped: false,
            });
        }
    }
    let linear_ok = !e.line_dynamics.as_ref().is_some_and(|l| l.enabled)
        && !e.friction.as_ref().is_some_and(|f| f.enabled);
    if linear_ok {
        for n in [1, 2, 4, 8] {
            push(Candidate {
                method: le,
                line: sy,
                line_moh: None,
                substeps: n,
                max_omega_h: None,
                shipped: false,
            });
        }
    }
    v
}

fn write_trace(path: &Path, s: &Session) {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path).expect("create csv"));
    writeln!(
        w,
        "cycle,t,setpoint,command,i_term,rod_force,meas_force,spool,spool_velocity,p_a,p_b,x,v"
    )
    .unwrap();
    for r in &s.records {
        let p = &r.plant;
        writeln!(
            w,
            "{},{:.9},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e},{:.17e}",
            r.cycle, r.t, r.setpoint, r.command, r.i_term, p.rod_force, r.meas.force, p.spool,
            p.spool_velocity, p.p_a, p.p_b, p.x, p.v
        )
        .unwrap();
    }
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let reps: usize = env_or("EHACTL_BENCH_REPS", 5);
    let ref_mult: u32 = env_or("EHACTL_BENCH_REF_MULT", 16);
    let dur_env: f64 = env_or("EHACTL_BENCH_DURATION", 0.0);
    let mut rigs: Vec<String> = std::fs::read_dir(root().join("configs"))
        .expect("configs/")
        .filter_map(|e| {
            let p = e.ok()?.path();
            if p.extension()? == "toml" {
                Some(p.file_stem()?.to_string_lossy().into_owned())
            } else {
                None
            }
        })
        .collect();
    rigs.sort();
    if !args.is_empty() {
        rigs.retain(|r| args.iter().any(|a| a == r));
    }
    // Profiling mode (`perf record`): only N runs of each selected rig as shipped.
    let profile: usize = env_or("EHACTL_BENCH_PROFILE", 0);
    if profile > 0 {
        for rig in &rigs {
            let cfg = RigConfig::load(&root().join("configs").join(format!("{rig}.toml")))
                .expect("config");
            let d = if dur_env > 0.0 {
                dur_env
            } else {
                cfg.run.duration.min(3.0)
            };
            let mut cpu = Vec::new();
            for _ in 0..profile {
                cpu.push(run(&cfg, d, false).1);
            }
            println!(
                "{rig}: {:.0}× real time (thread CPU, median of {profile})",
                d / median(&cpu)
            );
        }
        return;
    }
    let mut md = String::new();
    let _ = writeln!(
        md,
        "load average at start: {}; reps {reps}, reference = exponential_euler (lines symplectic) at {ref_mult} × auto(ω·h ≤ 0.25)\n",
        load_avg()
    );
    let _ = writeln!(
        md,
        "| rig | sim s | candidate | mean substeps / period | NRMSE output | NRMSE p_A | ref err | × real time (wall, median) | × real time (thread CPU, median) | re-discretisations |"
    );
    let _ = writeln!(md, "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|");
    print!("{md}");
    for rig in &rigs {
        let path = root().join("configs").join(format!("{rig}.toml"));
        let cfg = RigConfig::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let duration = if dur_env > 0.0 {
            dur_env
        } else {
            cfg.run.duration.min(3.0)
        };
        // Mean substeps per period of the default rule (ω·h ≤ 0.25, re-chosen per period).
        // The reference integrates lines with the `symplectic` scheme (the one whose
        // accuracy rule includes every segment mode), whatever the rig ships.
        let sy = LineMethod::Symplectic;
        let auto = {
            let c = with_line(
                &cfg,
                IntegrationMethod::ExponentialEuler,
                sy,
                None,
                0,
                Some(0.25),
            );
            let (s, _) = run(&c, duration, true);
            let mut plant = build_plant(&c).expect("plant");
            for r in &s.records {
                plant.step(r.command).expect("replay");
            }
            (plant.substeps_taken() as f64 / s.records.len() as f64).ceil() as u32
        };
        let ref_cfg = |n: u32| {
            with_line(
                &cfg,
                IntegrationMethod::ExponentialEuler,
                sy,
                None,
                n,
                Some(0.25),
            )
        };
        let (r_fine, _) = run(&ref_cfg(auto * ref_mult), duration, true);
        let (r_half, _) = run(&ref_cfg(auto * ref_mult / 2), duration, true);
        let (y_ref, pa_ref) = output(&cfg, &r_fine);
        let (y_half, _) = output(&cfg, &r_half);
        let ref_err = nrmse(&y_half, &y_ref);
        let cands = candidates(&cfg);
        let cfgs: Vec<RigConfig> = cands.iter().map(|c| c.config(&cfg)).collect();
        let mut acc = Vec::new();
        for c in &cfgs {
            let (s, _) = run(c, duration, true);
            let (y, pa) = output(&cfg, &s);
            // Re-discretisations of `linear_exact` over the run: replay the commands (the
            // plant is deterministic, so this is the same trajectory).
            let mut plant = build_plant(c).expect("plant");
            for r in &s.records {
                plant.step(r.command).expect("replay");
            }
            acc.push((
                nrmse(&y, &y_ref),
                nrmse(&pa, &pa_ref),
                plant.substeps_taken() as f64 / s.records.len() as f64,
                plant.discretisations(),
            ));
        }
        let mut walls = vec![Vec::new(); cfgs.len()];
        let mut cpus = vec![Vec::new(); cfgs.len()];
        for _ in 0..reps {
            for (i, c) in cfgs.iter().enumerate() {
                let (s, cpu) = run(c, duration, false);
                walls[i].push(s.wall_time_s);
                cpus[i].push(cpu);
            }
        }
        for (i, c) in cands.iter().enumerate() {
            let line = format!(
                "| {rig} | {duration} | {}{}{}{}{} | {:.1} | {:.4} % | {:.4} % | {:.1e} % | {:.0}× | {:.0}× | {} |\n",
                method_name(c.method),
                if cfg.plant.effects.line_dynamics.as_ref().is_some_and(|l| l.enabled) {
                    match c.line {
                        LineMethod::Symplectic => " + lines symplectic",
                        LineMethod::Implicit => " + lines implicit",
                    }
                } else {
                    ""
                },
                match (c.substeps, c.max_omega_h) {
                    (0, Some(m)) => format!(" auto ω·h ≤ {m}"),
                    (0, None) => " auto".to_string(),
                    (n, _) => format!(" fixed {n}"),
                },
                match (c.substeps, c.line_moh) {
                    (0, Some(m)) => format!(", segment modes ω·h ≤ {m}"),
                    _ => String::new(),
                },
                if c.shipped { " (shipped)" } else { "" },
                acc[i].2,
                100.0 * acc[i].0,
                100.0 * acc[i].1,
                100.0 * ref_err,
                duration / median(&walls[i]),
                duration / median(&cpus[i]),
                acc[i].3,
            );
            print!("{line}");
            md.push_str(&line);
        }
        let _ = std::io::stdout().flush();
        if rig == "sahu2022_force" {
            let mut nf = cfg.clone();
            nf.plant.sensors.force.noise = 0.0;
            nf.plant.effects.sensor_tone = None;
            let n_ref = 2816;
            let (s, _) = run(
                &with(&nf, IntegrationMethod::ExponentialEuler, n_ref, None),
                duration,
                true,
            );
            write_trace(&out_dir().join("sahu_reference_noisefree.csv"), &s);
            let mut t = String::from("method,substeps,duration_s,median_wall_s,median_cpu_s\n");
            for (m, n) in [
                (IntegrationMethod::LinearExact, 1),
                (IntegrationMethod::LinearExact, 2),
                (IntegrationMethod::ExponentialEuler, 8),
                (IntegrationMethod::ExponentialEuler, 22),
            ] {
                let c = with(&nf, m, n, None);
                let (s, _) = run(&c, duration, true);
                write_trace(
                    &out_dir().join(format!("sahu_{}_s{n}_noisefree.csv", method_name(m))),
                    &s,
                );
                let (mut w, mut u) = (Vec::new(), Vec::new());
                for _ in 0..reps {
                    let (s, cpu) = run(&c, duration, false);
                    w.push(s.wall_time_s);
                    u.push(cpu);
                }
                let _ = writeln!(
                    t,
                    "{},{n},{duration},{},{}",
                    method_name(m),
                    median(&w),
                    median(&u)
                );
            }
            std::fs::write(out_dir().join("sahu_rust_timing_noisefree.csv"), t).unwrap();
        }
    }
    let _ = writeln!(md, "\nload average at end: {}", load_avg());
    println!("\nload average at end: {}", load_avg());
    std::fs::write(out_dir().join("plant_accuracy.md"), md).expect("write report");
}
