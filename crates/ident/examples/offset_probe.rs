use ehactl_ident::data::ChannelKind;
use ehactl_ident::synth::make_case;
use ehactl_ident::{diagnose, Options};
use ehactl_plant::EffectId;
fn main() {
    let effects: Vec<Vec<EffectId>> = vec![
        vec![],
        vec![EffectId::Friction],
        vec![EffectId::ValveDeadband],
        vec![EffectId::InternalLeakage],
        vec![EffectId::ExternalLeakage],
        vec![EffectId::TimeDelay],
        vec![EffectId::SensorTone],
    ];
    for (i, h) in effects.iter().enumerate() {
        for with in [false, true] {
            let mut case = make_case(1000 + i as u64, h, 2.0);
            if with {
                for c in case.record.channels.iter_mut() {
                    let sd = ehactl_ident::replay::std(&c.values);
                    let off = match c.kind {
                        ChannelKind::PressureA => 2e5,
                        ChannelKind::PressureB => -1.5e5,
                        ChannelKind::Force => 0.05 * sd,
                        ChannelKind::Position => 5e-4,
                        _ => 0.0,
                    };
                    for v in c.values.iter_mut() {
                        *v += off;
                    }
                    eprintln!("  {:?} sd {sd:.3e}", c.kind);
                }
            }
            let d = diagnose(&case.nominal.plant, &case.record, None, &Options::default()).unwrap();
            println!(
                "{:?} offsets={with}: causes {:?} nrmse {:.4} -> {:.4} gain {:.1}%",
                h.iter().map(|e| e.as_str()).collect::<Vec<_>>(),
                d.causes,
                d.nrmse_nominal.overall,
                d.nrmse_extended.overall,
                d.gain * 100.0
            );
        }
    }
}
