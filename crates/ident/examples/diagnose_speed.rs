//! Speed of one diagnosis (issue 17 item 8): a generated 4 s record at 2 kHz (8000 samples,
//! 4 channels, test bench `configs/diagnose_testrig.toml`, ±10 % nominal errors) with one
//! hidden effect, all 12 catalogue candidates, `THREADS` worker threads (0 = all cores).
//! Usage: `diagnose_speed SEED EFFECT|none THREADS`; prints one line: wall time (s), process
//! CPU time (user + sys, s, from /proc/self/stat), CPU/wall, cause and phase times.
//! Driven by `bench/diagnose_speed.sh` (interleaved runs, load average); not a test.
use ehactl_ident::{diagnose, Options};
use ehactl_plant::EffectId;

/// Process CPU time (user + sys) in s from /proc/self/stat (Linux; clock ticks of 100 Hz).
fn cpu_s() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name in parentheses: utime is the 14th, stime the 15th field.
    let rest = s.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 4 {
        eprintln!("usage: diagnose_speed SEED EFFECT|none THREADS");
        std::process::exit(2);
    }
    let seed: u64 = a[1].parse().expect("seed");
    let hidden: Vec<EffectId> = if a[2] == "none" {
        vec![]
    } else {
        vec![EffectId::parse(&a[2]).expect("effect id")]
    };
    let threads: usize = a[3].parse().expect("threads");
    let case = ehactl_ident::synth::make_case_at(seed, &hidden, 4.0, 1.0 / 2000.0);
    let opts = Options {
        threads,
        ..Options::default()
    };
    let (c0, t0) = (cpu_s(), std::time::Instant::now());
    let d = diagnose(&case.nominal.plant, &case.record, None, &opts).expect("diagnosis runs");
    let wall = t0.elapsed().as_secs_f64();
    let cpu = cpu_s() - c0;
    println!(
        "seed {seed} hidden {} threads {threads}: wall {wall:.2} s, cpu {cpu:.2} s, cpu/wall {:.2}, cause {} (samples {})",
        a[2],
        cpu / wall,
        d.cause,
        case.record.len()
    );
}
