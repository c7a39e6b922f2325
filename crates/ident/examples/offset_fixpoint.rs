use ehactl_ident::replay::*;
use ehactl_ident::synth::*;
use ehactl_plant::EffectId;
fn main() {
    let mut case = make_case(1006, &[EffectId::SensorTone], 2.0);
    let off = realistic_offsets(&case.record);
    add_sensor_offsets(&mut case.record, &off);
    println!("true {:?}", off);
    let rec = &case.record;
    let n = (rec.len() as f64 * 0.7) as usize;
    for (label, p0) in [
        ("truth", case.truth.clone()),
        ("nominal", case.nominal.plant.clone()),
    ] {
        let mut b = vec![0.0; rec.channels.len()];
        for pass in 0..6 {
            let p = replay_params_zeroed(&p0, rec, &b);
            let sim = replay(&p, rec, n).unwrap();
            let nb = offsets(rec, &sim, 0..n);
            // residual after offsets in the last 80 % and first 10 %
            let mut sim2 = sim.clone();
            apply_offsets(&mut sim2, &nb);
            let e = nrmse(rec, &sim2, 0..n);
            println!(
                "{label} pass {pass}: b {:?} nrmse {:?}",
                nb.iter().map(|v| format!("{v:.4e}")).collect::<Vec<_>>(),
                e.iter().map(|v| format!("{v:.4}")).collect::<Vec<_>>()
            );
            b = nb;
        }
    }
}
