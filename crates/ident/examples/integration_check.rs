//! Replay integration error of one generated case at the automatic substeps and after each
//! refinement: `integration_check SEED [effects...]` (step-halving difference per channel in
//! NRMSE units, next to the noise floor).
use ehactl_ident::replay::{check_integration, replay_params, Drive};
use ehactl_plant::EffectId;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let seed: u64 = a[1].parse().unwrap();
    let hidden: Vec<EffectId> = a[2..].iter().filter_map(|s| EffectId::parse(s)).collect();
    let case = ehactl_ident::synth::make_case(seed, &hidden, 2.0);
    let mut p = replay_params(&case.nominal.plant, &case.record);
    let n = (0.7 * case.record.len() as f64) as usize;
    for moh in [0.25, 0.125, 0.0625, 0.03125] {
        p.integration.max_omega_h = moh;
        // One refinement step at most: report the figures at this ω·h.
        let (_, c) = check_integration(&p, &case.record, n, Drive::Recorded, 0);
        println!(
            "max_omega_h {moh}: substeps {} error {:?} floor {:?}",
            c.substeps, c.error, c.floor
        );
    }
}
