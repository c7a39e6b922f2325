//! Write a generated hidden-effect record as CSV plus its nominal config:
//! `make_csv SEED DURATION_S RATE_HZ OUT.csv [effects...]` (writes OUT.csv and OUT.csv.nominal.toml).
use ehactl_plant::EffectId;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 5 {
        eprintln!("usage: make_csv SEED DURATION_S RATE_HZ OUT.csv [effect ...]");
        std::process::exit(2);
    }
    let seed: u64 = a[1].parse().expect("seed");
    let dur: f64 = a[2].parse().expect("duration s");
    let rate: f64 = a[3].parse().expect("rate Hz");
    let hidden: Vec<EffectId> = a[5..]
        .iter()
        .map(|s| EffectId::parse(s).unwrap_or_else(|| panic!("unknown effect id {s}")))
        .collect();
    let case = ehactl_ident_eval::synth::make_case_at(seed, &hidden, dur, 1.0 / rate);
    std::fs::write(&a[4], ehactl_ident_eval::synth::to_csv(&case.record)).expect("write csv");
    std::fs::write(
        format!("{}.nominal.toml", a[4]),
        case.nominal.to_toml_string(),
    )
    .expect("write toml");
}
