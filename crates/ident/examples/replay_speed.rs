//! Time one open-loop replay of a generated 2 s record.
fn main() {
    let case = ehactl_ident::synth::make_case(3, &[], 2.0);
    let p = ehactl_ident::replay::replay_params(&case.nominal.plant, &case.record);
    let pl = ehactl_plant::Plant::configure(&p, case.record.dt).unwrap();
    println!("substeps {}", pl.substeps());
    let t0 = std::time::Instant::now();
    for _ in 0..100 {
        ehactl_ident::replay::replay(&p, &case.record, case.record.len()).unwrap();
    }
    println!("replay {:.3} ms", t0.elapsed().as_secs_f64() * 10.0);
}
