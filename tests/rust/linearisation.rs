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

/// Roots of z² + p·z + q (complex).
fn quadratic_roots(p: f64, q: f64) -> [nalgebra::Complex<f64>; 2] {
    let disc = nalgebra::Complex::new(p * p - 4.0 * q, 0.0).sqrt();
    [(-p + disc) / 2.0, (-p - disc) / 2.0]
}

/// The closed-loop poles of [`Loop::closed_loop_poles`] hold `roots` (each found within
/// 1e-9), whatever else they hold (a law state the loop cannot see sits at 0).
fn assert_poles_hold(lp: &Loop<'_>, roots: &[nalgebra::Complex<f64>]) {
    let poles = lp.closed_loop_poles().expect("a discrete loop has poles");
    for r in roots {
        assert!(
            poles.iter().any(|p| (p - r).norm() < 1e-9),
            "{r} not among {poles:?}"
        );
    }
}

/// Closed forms of the sampled loop's poles on the first-order plant x⁺ = a·x + b·u, y = x
/// (T = 1 ms): a P law puts the pole at a − b·K (Franklin, Powell & Workman, "Digital
/// Control of Dynamic Systems", 3rd ed., 1998, §7.2: the characteristic equation
/// 1 + C(z)·P(z) = 0); one period of command delay makes it z² − a·z + b·K = 0; the PI law
/// K·((1 + I·T) − z⁻¹)/(1 − z⁻¹) makes it (z − a)(z − 1) + b·K·((1 + I·T)·z − 1) = 0.
#[test]
fn closed_loop_poles_of_a_first_order_plant_match_the_characteristic_equation() {
    let (a, b, t) = (0.9, 0.1, 1e-3);
    let p = model(
        DMatrix::from_element(1, 1, a),
        DVector::from_element(1, b),
        DVector::from_element(1, 1.0),
        Some(t),
    );
    let p_law = |kp: f64| Law::Pd {
        kp,
        td: 0.0,
        tf: 0.0,
    };
    for kp in [5.0, 20.0] {
        let lp = Loop {
            plant: &p,
            law: p_law(kp),
            delay: 0.0,
        };
        assert_poles_hold(&lp, &[nalgebra::Complex::new(a - b * kp, 0.0)]);
        let delayed = Loop { delay: t, ..lp };
        assert_poles_hold(&delayed, &quadratic_roots(-a, b * kp));
    }
    let (kp, integral) = (3.0, 200.0);
    let pi = Loop {
        plant: &p,
        law: Law::Pi {
            kp,
            integral,
            scale: 1.0,
        },
        delay: 0.0,
    };
    // (z − a)(z − 1) + b·K·((1 + I·T)·z − 1) = z² + (b·K·(1 + I·T) − a − 1)·z + (a − b·K).
    let roots = quadratic_roots(b * kp * (1.0 + integral * t) - a - 1.0, a - b * kp);
    assert_poles_hold(&pi, &roots);
}

/// Against the margins, which come from the frequency response alone: the gain margin of
/// Sahu 2022's sampled force loop says by how much K_P may grow before the loop goes
/// unstable, so 0.9 of that factor leaves every closed-loop pole inside the unit circle and
/// 1.1 of it puts one outside.
#[test]
fn the_gain_margin_is_where_a_closed_loop_pole_leaves_the_unit_circle() {
    let cfg = ehactl_tests::config("sahu2022_force.toml");
    let op = ehactl_analysis::oppoint::find(&cfg, 5.0).unwrap();
    let plant = linear::discrete(&op).unwrap();
    let Some(Law::Pi {
        kp,
        integral,
        scale,
    }) = Law::from_config(&cfg)
    else {
        panic!("a PI law")
    };
    let lp = |kp: f64| Loop {
        plant: &plant,
        law: Law::Pi {
            kp,
            integral,
            scale,
        },
        delay: 0.0,
    };
    let nyquist = 0.5 * cfg.run.control_rate_hz;
    let gm = margins(&lp(kp), 0.1, nyquist).gain_margin_db.unwrap();
    let critical = kp * 10f64.powf(gm / 20.0);
    let largest = |kp: f64| {
        lp(kp)
            .closed_loop_poles()
            .unwrap()
            .iter()
            .map(|p| p.norm())
            .fold(0.0, f64::max)
    };
    assert!(largest(kp) < 1.0, "{}", largest(kp));
    assert!(largest(0.9 * critical) < 1.0, "{}", largest(0.9 * critical));
    assert!(largest(1.1 * critical) > 1.0, "{}", largest(1.1 * critical));
}

/// The verdict on given poles: one outside the unit circle makes the loop unstable and is
/// listed with its frequency (arg z/(2π·T): z = 1.1·e^(jπ/2) at T = 1 ms is 250 Hz); one
/// within the linearisation's rounding of the circle (1 + 1e-9) is marginal, not unstable.
#[test]
fn the_verdict_separates_unstable_from_marginal_poles() {
    use ehactl_analysis::analyze::Stability;
    use nalgebra::Complex;
    let t = 1e-3;
    let inside = [Complex::new(0.5, 0.2), Complex::new(0.5, -0.2)];
    let s = Stability::of_poles(&inside, t);
    assert!(s.stable && s.unstable_poles.is_empty() && s.marginal_poles.is_empty());
    let marginal = [inside[0], Complex::new(1.0 + 1e-9, 0.0)];
    let s = Stability::of_poles(&marginal, t);
    assert!(s.stable && s.unstable_poles.is_empty());
    assert_eq!(s.marginal_poles.len(), 1);
    let outside = [inside[0], Complex::new(0.0, 1.1), Complex::new(0.0, -1.1)];
    let s = Stability::of_poles(&outside, t);
    assert!(!s.stable);
    assert_eq!(s.unstable_poles.len(), 1, "a complex pair is listed once");
    let p = &s.unstable_poles[0];
    assert!((p.magnitude - 1.1).abs() < 1e-12 && (p.frequency_hz - 250.0).abs() < 1e-9);
}
