//! The analysis machinery against closed forms: margins of a textbook loop, the exact ZOH
//! model of a first-order plant, and the linearised plant's modes against √(K/m).

use ehactl_analysis::linear::{self, LinearModel, Output};
use ehactl_analysis::loopshape::{margins, Law, Loop};
use ehactl_analysis::oppoint::OperatingPoint;
use ehactl_plant::Plant;
use ehactl_tests::blocked_cylinder;
use nalgebra::{DMatrix, DVector};
use std::f64::consts::TAU;

fn model(a: DMatrix<f64>, b: DVector<f64>, c: DVector<f64>, dt: Option<f64>) -> LinearModel {
    let n = a.nrows();
    LinearModel {
        names: (0..n).map(|i| format!("s{i}")).collect(),
        a,
        b,
        c_force: c.clone(),
        c_position: c,
        dt,
        scale: vec![1.0; n],
    }
}

/// L(s) = K/(s + 1)³ with K = 2: phase crossover at ω = √3 rad/s where |L| = K/8, so
/// GM = 20·log₁₀(8/K) = 12.04 dB; gain crossover at ω = √(K^(2/3) − 1) = 0.7664 rad/s,
/// PM = 180° − 3·atan(ω) = 67.61°.
#[test]
fn margins_of_a_triple_lag_match_the_closed_form() {
    let a = DMatrix::from_row_slice(3, 3, &[-1.0, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 1.0, -1.0]);
    let b = DVector::from_vec(vec![1.0, 0.0, 0.0]);
    let c = DVector::from_vec(vec![0.0, 0.0, 1.0]);
    let p = model(a, b, c, None);
    let lp = Loop {
        plant: &p,
        law: Law::Pd {
            kp: 2.0,
            td: 0.0,
            tf: 0.0,
        },
        delay: 0.0,
    };
    let m = margins(&lp, 1e-3, 100.0);
    let wc = (2f64.powf(2.0 / 3.0) - 1.0).sqrt();
    let pm = 180.0 - 3.0 * wc.atan().to_degrees();
    assert!((m.gain_crossover_hz.unwrap() - wc / TAU).abs() < 1e-6);
    assert!((m.phase_margin_deg.unwrap() - pm).abs() < 1e-4);
    assert!((m.phase_crossover_hz.unwrap() - 3f64.sqrt() / TAU).abs() < 1e-6);
    assert!((m.gain_margin_db.unwrap() - 20.0 * 4f64.log10()).abs() < 1e-6);
    // A pure delay τ takes ωτ of phase at crossover.
    let tau = 0.1;
    let lpd = Loop { delay: tau, ..lp };
    let md = margins(&lpd, 1e-3, 100.0);
    assert!((md.phase_margin_deg.unwrap() - (pm - (wc * tau).to_degrees())).abs() < 1e-4);
}

/// The sampled model of a real plant step map equals the exact zero-order-hold
/// discretisation: for a blocked cylinder with a valve held closed the plant has no input
/// path, so instead check the free modes: the undamped linearised frequency equals
/// √(K_h/m) with K_h = β(A_A²/V_A + A_B²/V_B), and the sampled eigenvalue is e^(λT).
#[test]
fn linearised_cylinder_mode_matches_the_hydraulic_stiffness() {
    for x0 in [0.2, 0.6, 1.0] {
        let params = blocked_cylinder(255.0, 0.0, x0);
        let plant = Plant::configure(&params, 2e-4).expect("plant");
        let k = plant.hydraulic_stiffness(x0);
        let w = (k / 255.0).sqrt();
        let op = OperatingPoint {
            plant,
            u0: 0.0,
            reference: 0.0,
            feedback: 0.0,
            settled: true,
            time_s: 0.0,
        };
        let c = linear::continuous(&op, 1e-7).expect("continuous");
        let wl = c
            .eigenvalues()
            .iter()
            .map(|l| l.im.abs())
            .fold(0.0, f64::max);
        assert!((wl / w - 1.0).abs() < 1e-3, "x0 {x0}: {wl} vs {w} rad/s");
        let d = linear::discrete(&op).expect("discrete");
        let zl = d
            .eigenvalues()
            .iter()
            .map(|z| z.ln().im.abs() / 2e-4)
            .fold(0.0, f64::max);
        assert!(
            (zl / w - 1.0).abs() < 5e-3,
            "x0 {x0}: sampled {zl} vs {w} rad/s"
        );
        // And the static response to a force at the output row: position per unit state.
        assert!(c.c(Output::Position).iter().any(|v| *v != 0.0));
    }
}
