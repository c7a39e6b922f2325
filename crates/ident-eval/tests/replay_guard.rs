//! The replay's stability guard (`ehactl_ident::replay::replay_guarded`): a replay with fixed
//! substeps whose parameters would step the plant's fastest mode beyond ω·h =
//! `REPLAY_MAX_OMEGA_H` takes more substeps, never more than its ceiling. The fastest mode is
//! checked against the textbook hydraulic spring, ω² = (β·(A_a²/V_a + A_b²/V_b) + k)/m at the
//! smallest chamber volumes (e.g. Merritt, Hydraulic Control Systems, 1967, ch. 5); the guard
//! holds ω·h to half the stability limit ω·h < 2 of the symplectic Euler step the plant's
//! mechanics take (Hairer, Lubich & Wanner, Geometric Numerical Integration, 2006, ch. I.1).
//! At the dead volumes the bound is conservative: mid-stroke the chambers are larger and the
//! mode slower.

use ehactl_ident::data::ChannelKind;
use ehactl_ident::replay::{replay_guarded, replay_with, Drive, REPLAY_MAX_OMEGA_H};
use ehactl_ident_eval::synth::{make_case_at, testrig};
use ehactl_plant::{Plant, PlantParams};

/// The test bench (`configs/diagnose_testrig.toml`) with fixed substeps and its centring
/// spring set to `k_load` (N/m).
fn rig(substeps: u32, k_load: f64) -> PlantParams {
    let mut p = testrig().plant;
    p.integration.substeps = substeps;
    p.mechanics.load_stiffness = k_load;
    p
}

/// ω (rad/s) of the hydraulic spring and the load spring on the piston mass, at the dead
/// volumes (the piston at a stroke end is the stiffest place only for the chamber it
/// compresses; the sum at both dead volumes bounds every position).
fn closed_form_omega(p: &PlantParams) -> f64 {
    let c = &p.cylinder;
    let k_h = p.fluid.bulk_modulus
        * (c.area_a * c.area_a / c.dead_volume_a + c.area_b * c.area_b / c.dead_volume_b);
    ((k_h + p.mechanics.load_stiffness) / p.mechanics.mass).sqrt()
}

#[test]
fn the_fastest_mode_is_the_hydraulic_spring_at_the_dead_volumes() {
    for k in [0.0, 1e6, 1e8] {
        let p = rig(5, k);
        let plant = Plant::configure(&p, 1e-3).expect("test bench configures");
        let w = closed_form_omega(&p);
        assert!(
            (plant.fastest_mode() - w).abs() <= 1e-9 * w,
            "k = {k:e} N/m: plant {} rad/s, closed form {w} rad/s",
            plant.fastest_mode()
        );
    }
}

fn outputs(p: &PlantParams, max_substeps: Option<u32>) -> (Vec<Vec<f64>>, bool) {
    let case = make_case_at(11, &[], 0.5, 1e-3);
    let rec = &case.record;
    let r = match max_substeps {
        Some(m) => replay_guarded(p, rec, rec.len(), Drive::Recorded, m),
        None => replay_with(p, rec, rec.len(), Drive::Recorded),
    }
    .expect("replay runs");
    (r.y, r.failed)
}

#[test]
fn a_replay_beyond_the_guard_takes_the_fewest_substeps_within_it() {
    // Centring spring 1e8 N/m: ω ≈ 2143 rad/s, ω·h = 2.14 at one substep of 1 ms (beyond
    // the stability limit 2), 1.07 at two, 0.71 at three.
    let stiff = rig(1, 1e8);
    let w = closed_form_omega(&stiff);
    let need = (1e-3 * w / REPLAY_MAX_OMEGA_H).ceil() as u32;
    assert_eq!(need, 3, "ω = {w} rad/s");
    let (guarded, failed) = outputs(&stiff, Some(10));
    let (explicit, _) = outputs(&rig(need, 1e8), None);
    assert!(!failed);
    assert_eq!(
        guarded, explicit,
        "the guard replays at ceil(ω·dt / {REPLAY_MAX_OMEGA_H}) substeps"
    );
    // The ceiling holds: at most two substeps when the context allows two.
    let (capped, _) = outputs(&stiff, Some(2));
    let (two, _) = outputs(&rig(2, 1e8), None);
    assert_eq!(capped, two);
    // The guarded replay stays within 1 % of a converged one (40 substeps).
    let (fine, _) = outputs(&rig(40, 1e8), None);
    let x = make_case_at(11, &[], 0.5, 1e-3)
        .record
        .channels
        .iter()
        .position(|c| c.kind == ChannelKind::Position)
        .expect("the test bench logs x");
    let scale = fine[x].iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let dev = guarded[x]
        .iter()
        .zip(&fine[x])
        .map(|(a, b)| (a - b).abs())
        .fold(0.0_f64, f64::max)
        / scale;
    assert!(
        dev < 0.01,
        "guarded replay {dev} of full scale from the converged one"
    );
}

#[test]
fn a_replay_within_the_guard_is_untouched() {
    // The bench as configured: ω·h = 0.23 at its 5 substeps.
    let p = rig(5, 1e6);
    assert_eq!(outputs(&p, Some(100)), outputs(&p, None));
    // Automatic substeps hold their own rule (ω·h ≤ max_omega_h): never changed.
    let auto = rig(0, 1e8);
    assert_eq!(outputs(&auto, Some(100)), outputs(&auto, None));
}

/// The fit cost computed while replaying (`replay_cost`) is the textbook cost of the whole
/// replay, mean over channels of Σ(y − ŷ)²/n / σ², to the last bit; given a bound below it,
/// it stops early with a value between the bound and the full cost.
#[test]
fn the_running_cost_is_the_replays_cost_and_stops_at_its_bound() {
    use ehactl_ident::replay::{replay_cost, replay_params};
    let case = make_case_at(12, &[], 1.0, 1e-3);
    let rec = &case.record;
    let p = replay_params(&case.nominal.plant, rec);
    let n = rec.len();
    let sd: Vec<f64> = rec
        .channels
        .iter()
        .map(|c| {
            let m = c.values.iter().sum::<f64>() / n as f64;
            (c.values.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / n as f64)
                .sqrt()
                .max(1e-300)
        })
        .collect();
    let sim = replay_with(&p, rec, n, Drive::Recorded).expect("replay runs");
    let mut j = 0.0;
    for (c, (ch, y)) in rec.channels.iter().zip(&sim.y).enumerate() {
        let e: f64 = ch
            .values
            .iter()
            .zip(y)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>();
        j += e / n as f64 / (sd[c] * sd[c]).max(1e-300);
    }
    let j = j / rec.channels.len() as f64;
    assert!(j > 0.0 && j.is_finite(), "cost {j}");
    let full = replay_cost(&p, rec, n, Drive::Recorded, 0, &sd, None, f64::INFINITY).unwrap();
    assert_eq!(
        full.to_bits(),
        j.to_bits(),
        "running {full} vs after the replay {j}"
    );
    // One channel only: the same sum for that channel.
    let one = replay_cost(&p, rec, n, Drive::Recorded, 0, &sd, Some(0), f64::INFINITY).unwrap();
    let e0: f64 = rec.channels[0]
        .values
        .iter()
        .zip(&sim.y[0])
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>();
    assert_eq!(
        one.to_bits(),
        (e0 / n as f64 / (sd[0] * sd[0]).max(1e-300)).to_bits()
    );
    let bound = 0.3 * j;
    let early = replay_cost(&p, rec, n, Drive::Recorded, 0, &sd, None, bound).unwrap();
    assert!(
        early >= bound && early < j,
        "bound {bound}, early {early}, full {j}"
    );
}
