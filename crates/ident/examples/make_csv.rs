//! Write a generated hidden-effect record as CSV: `make_csv SEED DURATION OUT.csv [effects...]`.
use ehactl_plant::EffectId;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let seed: u64 = a[1].parse().expect("seed");
    let dur: f64 = a[2].parse().expect("duration s");
    let hidden: Vec<EffectId> = a[4..].iter().filter_map(|s| EffectId::parse(s)).collect();
    let case = ehactl_ident::synth::make_case(seed, &hidden, dur);
    std::fs::write(&a[3], ehactl_ident::synth::to_csv(&case.record)).expect("write csv");
    std::fs::write(format!("{}.nominal.toml", a[3]), case.nominal.to_toml_string()).expect("write toml");
}
