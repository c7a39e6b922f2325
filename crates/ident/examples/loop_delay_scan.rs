//! Position error of an assumed loop against its transport delay, on a fine grid:
//! `loop_delay_scan CONFIG.toml DATA.csv [SUBSTEPS]` prints, for delays 0–6 ms in 0.1 ms
//! steps, the position NRMSE on the first 70 % of the record (the fit cost of the loop
//! identification) with the config's PD loop replayed on `ref`. It shows whether the cost is
//! smooth in the delay or steps with the plant's substep (the delay line switches the
//! valve command at substep boundaries), which decides how the delay is fitted
//! (DIAGNOSIS.md "Assumed loop").
use ehactl_ident::data::ChannelKind;
use ehactl_ident::replay::{nrmse, replay_params, replay_with, Drive};
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let cfg = ehactl_config::RigConfig::load(std::path::Path::new(&a[1])).expect("config");
    let rec = ehactl_ident::data::load(std::path::Path::new(&a[2])).expect("data");
    let mut p = replay_params(&cfg.plant, &rec);
    if let Some(n) = a.get(3) {
        p.integration.substeps = n.parse().expect("substeps");
    }
    let g = cfg.pd_gains().expect("a [control.pd] position loop");
    let c = rec
        .channels
        .iter()
        .position(|ch| ch.kind == ChannelKind::Position)
        .expect("x");
    let n = (0.7 * rec.len() as f64) as usize;
    for i in 0..=60 {
        let d = i as f64 * 1e-4;
        let mut q = p.clone();
        q.effects.time_delay = Some(ehactl_plant::params::TimeDelay {
            enabled: true,
            delay: d,
        });
        let sim = replay_with(&q, &rec, n, Drive::PositionPd(g)).expect("replay");
        println!(
            "{:.1} ms  x NRMSE {:.6}",
            d * 1e3,
            nrmse(&rec, &sim, 0..n)[c]
        );
    }
}
