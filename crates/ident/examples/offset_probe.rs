//! Scratch: refit-nominal held-out NRMSE with and without sensor offsets, on data with and
//! without zero errors (threshold for deciding whether a record has sensor offsets).
use ehactl_ident::synth::{add_sensor_offsets, make_case, realistic_offsets};
use ehactl_ident::{diagnose, Options};
use ehactl_plant::EffectId;
fn main() {
    let mut cases: Vec<(u64, Vec<EffectId>)> = EffectId::ALL
        .iter()
        .enumerate()
        .map(|(i, e)| (5000 + i as u64, vec![*e]))
        .collect();
    cases.push((5037, vec![EffectId::ValveDeadband]));
    cases.push((5070, vec![EffectId::SensorTone]));
    for s in [5080u64, 5090, 5091, 5095] {
        cases.push((s, vec![]));
    }
    for (seed, hidden) in cases {
        let case = make_case(seed, &hidden, 2.0);
        let mut shifted = case.record.clone();
        add_sensor_offsets(&mut shifted, &realistic_offsets(&case.record));
        let mut line = format!(
            "{seed} {:?}:",
            hidden.iter().map(|e| e.as_str()).collect::<Vec<_>>()
        );
        for (label, rec) in [("clean", &case.record), ("zero-err", &shifted)] {
            let r = |on: bool| {
                let o = Options {
                    sensor_offsets: on,
                    effects: vec![],
                    ..Options::default()
                };
                diagnose(&case.nominal.plant, rec, None, &o)
                    .unwrap()
                    .nrmse_refit
                    .overall
            };
            let (on, off) = (r(true), r(false));
            line += &format!("  {label}: on {on:.4} off {off:.4} ratio {:.3}", on / off);
        }
        println!("{line}");
    }
}
