//! Evaluation over seeded hidden-effect cases: `cargo run --release -p ehactl-ident --example evaluate -- [cases] [first_seed] [effects...]`.
use ehactl_ident::synth::make_case;
use ehactl_ident::{diagnose, Options};
use ehactl_plant::EffectId;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let cases: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(13);
    let first: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let only: Vec<EffectId> = args.iter().skip(3).filter_map(|s| EffectId::parse(s)).collect();
    for i in 0..cases {
        let seed = first + i;
        let hidden: Vec<EffectId> = if !only.is_empty() {
            vec![only[(i as usize) % only.len()]]
        } else {
            let k = (seed % 13) as usize;
            if k == 12 { vec![] } else { vec![EffectId::ALL[k]] }
        };
        let case = make_case(seed, &hidden, 2.0);
        let t0 = std::time::Instant::now();
        let d = diagnose(&case.nominal.plant, &case.record, None, &Options::default()).unwrap();
        println!(
            "seed {seed:3} hidden {:<24} -> {:<40} nom {:.4} refit {:.4} ext {:.4} gain {:5.1}% floor {:.4} ({:.1}s)",
            hidden.iter().map(|e| e.as_str()).collect::<Vec<_>>().join("+"),
            d.causes.join("+"),
            d.nrmse_nominal.overall, d.nrmse_refit.overall, d.nrmse_extended.overall, d.gain * 100.0, d.noise_floor, t0.elapsed().as_secs_f64()
        );
        if std::env::var("VERBOSE").is_ok() {
            for c in &d.candidates { println!("    {:<22} val {:.4} train {:.4} score {:.3} {}", c.effect, c.nrmse_validation, c.nrmse_train, c.score, c.evidence); }
        }
    }
}
