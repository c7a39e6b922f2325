//! Debug one generated case: `debug_case SEED effects...` prints truth effects, analysis and
//! candidates; with `OFFSETS=1` in the environment the record gets `synth::realistic_offsets`.
use ehactl_plant::EffectId;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let seed: u64 = a[1].parse().unwrap();
    let hidden: Vec<EffectId> = a[2..].iter().filter_map(|s| EffectId::parse(s)).collect();
    let mut case = ehactl_ident::synth::make_case(seed, &hidden, 2.0);
    if std::env::var("OFFSETS").is_ok_and(|v| v == "1") {
        let b = ehactl_ident::synth::realistic_offsets(&case.record);
        println!("sensor offsets added: {b:?}");
        ehactl_ident::synth::add_sensor_offsets(&mut case.record, &b);
    }
    println!("truth effects: {:?}", case.truth.effects);
    for c in &case.record.channels {
        println!(
            "{} std {:.4e} noise est {:.4e}",
            c.kind.column(),
            ehactl_ident::replay::std(&c.values),
            ehactl_ident::replay::noise_level(&c.values)
        );
    }
    let d = ehactl_ident::diagnose(&case.nominal.plant, &case.record, None, &Default::default())
        .unwrap();
    println!("integration {:?}", d.integration);
    println!("baseline {:?}", d.nrmse_baseline);
    println!("tones {:?}", d.analysis_refit.tones);
    println!("estimated sensor offsets {:?}", d.sensor_offsets);
    println!(
        "causes {:?} gain {:.3} floor {} refit {:?}",
        d.causes, d.gain, d.noise_floor, d.nrmse_refit
    );
    for c in &d.candidates {
        println!("{} {:?} {}", c.effect, c.params, c.nrmse_validation);
    }
}
