//! Scratch: one case, refit nominal only, offsets on/off.
use ehactl_ident::synth::make_case;
use ehactl_ident::{diagnose, Options};
use ehactl_plant::EffectId;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let seed: u64 = a[1].parse().unwrap();
    let hidden: Vec<EffectId> = a[2..].iter().filter_map(|s| EffectId::parse(s)).collect();
    let case = make_case(seed, &hidden, 2.0);
    for on in [true, false] {
        let o = Options {
            sensor_offsets: on,
            effects: vec![],
            ..Options::default()
        };
        let d = diagnose(&case.nominal.plant, &case.record, None, &o).unwrap();
        println!(
            "offsets={on}: nom {:?}\n refit {:?}\n offsets {:?}\n params {:?}",
            d.nrmse_nominal, d.nrmse_refit, d.sensor_offsets, d.extended_params
        );
    }
}
