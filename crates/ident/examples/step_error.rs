//! Replay integration error of a config on a record, as `ehactl diagnose` measures it:
//! `step_error CONFIG DATA [N...]` prints, for each substep count N (default 2 5 10 20 40),
//! the step-halving difference (replay with N vs 2N substeps, rms over the first
//! min(70 %, 12 000) samples, over the channel's std, NRMSE units) per channel divided by the
//! allowance 0.3 × the noise floor (≤ 1 = accurate enough; the `ehactl diagnose` criterion,
//! `replay::choose_integration_between`). The drive is chosen as the CLI chooses it (the
//! config's PD position or PI force loop on a recorded `ref`, else the recorded `u`).
//! Not a test; used for BENCHMARKS.md "Diagnosis speed: fewer substeps".
use ehactl_config::ControlMode;
use ehactl_ident::replay::{replay_params, replay_with, residual_floor, Drive, INTEGRATION_RATIO};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 3 {
        eprintln!("usage: step_error CONFIG DATA [N...]");
        std::process::exit(2);
    }
    let cfg = ehactl_config::RigConfig::load(std::path::Path::new(&a[1])).expect("config");
    let rec = ehactl_ident::data::load(std::path::Path::new(&a[2])).expect("data");
    let drive = match (&cfg.control.mode, &rec.reference) {
        (ControlMode::Position, Some(_)) if cfg.pd_gains().is_some() => {
            Drive::PositionPd(cfg.pd_gains().unwrap())
        }
        (ControlMode::Force, Some(_)) if cfg.pi_gains().is_some() => Drive::ForcePi {
            gains: cfg.pi_gains().unwrap(),
            max_command: cfg.supervisor.max_command.unwrap_or(f64::INFINITY),
        },
        _ => Drive::Recorded,
    };
    let ns: Vec<u32> = if a.len() > 3 {
        a[3..].iter().map(|s| s.parse().expect("N")).collect()
    } else {
        vec![2, 5, 10, 20, 40]
    };
    let n = ((0.7 * rec.len() as f64).round() as usize).min(12_000);
    let p = replay_params(&cfg.plant, &rec);
    let sd: Vec<f64> = rec
        .channels
        .iter()
        .map(|c| ehactl_ident::replay::std(&c.values[..n]).max(1e-300))
        .collect();
    let nominal = replay_with(&p, &rec, n, drive).expect("replay");
    let floor: Vec<f64> = rec
        .channels
        .iter()
        .zip(&nominal.y)
        .map(|(c, yh)| residual_floor(&c.values[..n], yh))
        .collect();
    let names: Vec<&str> = rec.channels.iter().map(|c| c.kind.column()).collect();
    println!("channels {names:?}, {n} samples, floors {floor:.3?}");
    for &ns in &ns {
        let run = |k: u32| {
            let mut q = p.clone();
            q.integration.substeps = k;
            replay_with(&q, &rec, n, drive).expect("replay")
        };
        let (ya, yb) = (run(ns), run(2 * ns));
        let r: Vec<String> = ya
            .y
            .iter()
            .zip(&yb.y)
            .zip(sd.iter().zip(&floor))
            .map(|((a, b), (s, f))| {
                let e = (a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / n as f64)
                    .sqrt()
                    / s;
                format!("{e:.2e} ({:.2})", e / (INTEGRATION_RATIO * f).max(1e-6))
            })
            .collect();
        println!("N {ns:3}: {}", r.join("  "));
    }
    if std::env::var("LAG").is_ok() {
        // Error against a fine reference (640 substeps) split into a time shift τ·ẏ and the
        // rest: τ in units of the substep h.
        let run = |k: u32| {
            let mut q = p.clone();
            q.integration.substeps = k;
            replay_with(&q, &rec, n, drive).expect("replay")
        };
        let r = run(640);
        for &ns in &ns {
            let a = run(ns);
            let h = rec.dt / ns as f64;
            let mut out = Vec::new();
            for ((ya, yr), s) in a.y.iter().zip(&r.y).zip(&sd) {
                let d: Vec<f64> = (0..n)
                    .map(|i| (yr[(i + 1).min(n - 1)] - yr[i.saturating_sub(1)]) / (2.0 * rec.dt))
                    .collect();
                let e: Vec<f64> = ya.iter().zip(yr).map(|(x, y)| x - y).collect();
                let dd: f64 = d.iter().map(|x| x * x).sum::<f64>().max(1e-300);
                let tau = e.iter().zip(&d).map(|(x, y)| x * y).sum::<f64>() / dd;
                let rms = |v: &mut dyn Iterator<Item = f64>| {
                    (v.map(|x| x * x).sum::<f64>() / n as f64).sqrt() / s
                };
                let tot = rms(&mut e.iter().copied());
                let rest = rms(&mut e.iter().zip(&d).map(|(x, y)| x - tau * y));
                out.push(format!(
                    "err {tot:.2e} lead {:.2}h rest {rest:.2e}",
                    -tau / h
                ));
            }
            println!("vs 640, N {ns:3}: {}", out.join(" | "));
        }
    }
}
