//! Replay integration choice of one generated case: `integration_check SEED [effects...]`
//! (prints, for cost limits 1, 2, 4, 8 × the config's substeps, the substeps chosen and the
//! step-halving difference per channel in NRMSE units next to the noise floor). With
//! `INDEP=KIND` the case comes from the independent generator instead (seed SEED).
use ehactl_ident::replay::{choose_integration, replay_params, Drive};
use ehactl_plant::EffectId;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let seed: u64 = a[1].parse().unwrap();
    let (nominal, record) = match std::env::var("INDEP") {
        Ok(kind) => {
            let c = ehactl_ident_eval::indep::make_case(seed, &kind, 1.5, 1e-3).expect("generate");
            (c.nominal, c.record)
        }
        Err(_) => {
            let hidden: Vec<EffectId> = a[2..].iter().filter_map(|s| EffectId::parse(s)).collect();
            let c = ehactl_ident_eval::synth::make_case(seed, &hidden, 2.0);
            (c.nominal.plant, c.record)
        }
    };
    let p = replay_params(&nominal, &record);
    let n = (0.7 * record.len() as f64) as usize;
    for cost in [1.0, 2.0, 4.0, 8.0] {
        let (_, c) = choose_integration(&p, &record, n, Drive::Recorded, cost);
        println!(
            "max cost {cost}: substeps {} (config {}) met {} error {:?} floor {:?}",
            c.substeps, c.config_substeps, c.met, c.error, c.floor
        );
    }
}
