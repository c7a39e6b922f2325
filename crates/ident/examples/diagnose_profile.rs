//! Where one `ehactl diagnose` spends its time (BENCHMARKS.md "Diagnosis speed"): runs the
//! CLI's diagnosis ([`ehactl_ident::session::run`], its options) on `CONFIG DATA [VALIDATE]`
//! and prints, per stage of the progress reports, the replays run, samples replayed, plant
//! substeps per sample, `linear_exact` re-discretisations, time in `Plant::configure` and in
//! the replay loops (summed over threads) and the wall time of the stage. The last row
//! ("after the rounds") is the grey-box extension and the final replays.
//! Usage: `diagnose_profile CONFIG DATA [VALIDATE]`. Not a test.
use ehactl_ident::progress::{Progress, ProgressSink};
use ehactl_ident::replay::{replay_stats, ReplayStats};
use std::sync::{Arc, Mutex};
use std::time::Instant;

type Snap = (String, Instant, ReplayStats);

fn row(label: &str, a: &Snap, b: (Instant, ReplayStats)) {
    let (s0, s1) = (a.2, b.1);
    let d = |f: fn(&ReplayStats) -> u64| f(&s1) - f(&s0);
    let samples = d(|s| s.samples).max(1);
    println!(
        "| {label} | {} | {} | {:.2} | {} | {:.2} | {:.2} | {:.2} |",
        d(|s| s.replays),
        d(|s| s.samples),
        d(|s| s.substeps) as f64 / samples as f64,
        d(|s| s.discretisations),
        d(|s| s.configure_ns) as f64 * 1e-9,
        d(|s| s.run_ns) as f64 * 1e-9,
        (b.0 - a.1).as_secs_f64()
    );
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 3 {
        eprintln!("usage: diagnose_profile CONFIG DATA [VALIDATE]");
        std::process::exit(2);
    }
    let cfg = ehactl_config::RigConfig::load(std::path::Path::new(&a[1])).expect("config");
    let snaps: Arc<Mutex<Vec<Snap>>> = Arc::new(Mutex::new(Vec::new()));
    let t0 = Instant::now();
    let s0 = replay_stats();
    let ends: Arc<Mutex<Vec<(Instant, ReplayStats)>>> = Arc::new(Mutex::new(Vec::new()));
    let en = ends.clone();
    let sn2 = snaps.clone();
    let sink = ProgressSink::new(move |p: &Progress| {
        en.lock().unwrap().push((Instant::now(), replay_stats()));
        let mut v = sn2.lock().unwrap();
        if v.last().is_none_or(|l| l.0 != p.stage) {
            v.push((p.stage.clone(), Instant::now(), replay_stats()));
        }
    });
    let choices = ehactl_ident::session::RunChoices {
        progress: sink,
        sensor_offsets: false,
        config_path: Some(std::path::PathBuf::from(&a[1])),
        force: false,
        allow_config_mismatch: false,
    };
    let val = a.get(3).map(std::path::PathBuf::from);
    let r = ehactl_ident::session::run(
        &cfg,
        &a[1],
        std::path::Path::new(&a[2]),
        val.as_deref(),
        None,
        choices,
    )
    .expect("diagnosis runs");
    let end = (Instant::now(), replay_stats());
    let snaps = snaps.lock().unwrap().clone();
    let ends = ends.lock().unwrap().clone();
    println!("| stage | replays | samples | substeps/sample | re-discretisations | configure s | replay s (threads) | wall s |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    let first = ("start".to_string(), t0, s0);
    row(
        "integration check + nominal + baseline",
        &first,
        (snaps[0].1, snaps[0].2),
    );
    for (i, s) in snaps.iter().enumerate() {
        // A stage ends at the last report before the next stage starts (or the last report).
        let next_start = snaps.get(i + 1).map(|n| n.1);
        let stop = ends
            .iter()
            .rfind(|e| next_start.is_none_or(|t| e.0 < t))
            .copied()
            .unwrap_or(end);
        row(&s.0, s, stop);
    }
    let last = ends.last().copied().unwrap_or(end);
    row(
        "after the rounds (grey-box, final replays)",
        &("".into(), last.0, last.1),
        end,
    );
    row("total", &first, end);
    println!(
        "cause {} | greybox {}",
        r.diagnosis.cause,
        r.diagnosis
            .greybox
            .as_ref()
            .map_or("-".to_string(), |g| g.structure.clone())
    );
}
