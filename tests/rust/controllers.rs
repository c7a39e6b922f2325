//! Control laws and setpoints against their closed forms.

use ehactl_control::pd::{Pd, PdGains};
use ehactl_control::pi::{Pi, PiGains};
use ehactl_control::setpoint::{Setpoint, SetpointConfig, SetpointKind, Sweep};

fn pi(kp: f64, i: f64) -> Pi {
    Pi::new(PiGains {
        kp,
        integral: i,
        error_scale: 0.5097e-3,
        u_min: -10.0,
        u_max: 10.0,
        tracking: 0.0,
        feedforward: 0.0,
    })
}

#[test]
fn pi_ideal_form_discrete_integral() {
    // 004: K_P 0.57, I 386.24 on load-cell volts; constant 100 N error.
    let mut c = pi(0.57, 386.24);
    let dt = 2e-4;
    let ev = 0.5097e-3 * 100.0;
    for k in 1..=50 {
        let t = c.step(100.0, 0.0, dt);
        let expected_i = 0.57 * 386.24 * dt * ev * k as f64;
        assert!((t.p - 0.57 * ev).abs() < 1e-15);
        assert!((t.i - expected_i).abs() < 1e-12);
        assert!((t.u - (t.p + t.i)).abs() < 1e-15);
    }
}

#[test]
fn pi_anti_windup_stops_integrating_in_saturation() {
    let mut c = pi(0.57, 386.24);
    let dt = 2e-4;
    // Huge error: saturates at +10 V and the integrator must not run away.
    let mut last_i = 0.0;
    for _ in 0..20_000 {
        let t = c.step(1.0e6, 0.0, dt);
        assert_eq!(t.u, 10.0);
        last_i = t.i;
    }
    assert!(last_i <= 10.0, "integrator wound up to {last_i}");
    // Error reverses: the output leaves saturation at once, not after unwinding.
    let t = c.step(-1.0e6, 0.0, dt);
    assert_eq!(t.u, -10.0);
}

#[test]
fn pd_without_filter_is_003_eq32() {
    let gains = PdGains {
        kp: 50.0,
        td: 0.004,
        filter_n: 0.0,
        u_max: 1e9,
        feedforward_velocity: 0.0,
    };
    let mut c = Pd::new(gains);
    let dt = 2e-4;
    let es = [0.6, 0.55, 0.5, 0.52, 0.3];
    let mut prev = es[0];
    for (k, e) in es.iter().enumerate() {
        let t = c.step(*e, 0.0, 0.0, dt);
        let expected = 50.0 * (e + 0.004 / dt * (e - prev));
        if k > 0 {
            assert!((t.u - expected).abs() < 1e-9, "{} vs {}", t.u, expected);
        }
        prev = *e;
    }
}

fn sp(kind: SetpointKind, sweep: Sweep) -> SetpointConfig {
    SetpointConfig {
        kind,
        initial: 0.0,
        final_value: 1.0,
        start: 0.0,
        duration: 3.0,
        offset: 785.0,
        amplitude: 196.0,
        f0: 1.0,
        f1: 300.0,
        sweep,
        steps: 10,
        ramp_time: 0.05,
        hold: 0.1,
        seed: 1,
    }
}

#[test]
fn chirp_instantaneous_frequency_and_rate() {
    for sweep in [Sweep::Linear, Sweep::Log] {
        let s = Setpoint::new(&sp(SetpointKind::Chirp, sweep));
        let (f_start, _) = s.sweep_phase(0.0);
        let (f_end, _) = s.sweep_phase(3.0);
        assert!((f_start - 1.0).abs() < 1e-9 && (f_end - 300.0).abs() < 1e-6);
        // Phase derivative equals 2π f.
        for tau in [0.5, 1.5, 2.9] {
            let h = 1e-7;
            let (f, p0) = s.sweep_phase(tau);
            let (_, p1) = s.sweep_phase(tau + h);
            assert!(((p1 - p0) / h / std::f64::consts::TAU - f).abs() / f < 1e-4);
            // Reported rate matches the numerical derivative of the value.
            let (v0, r) = s.sample(tau);
            let (v1, _) = s.sample(tau + h);
            assert!(((v1 - v0) / h - r).abs() < 1e-3 * 196.0 * std::f64::consts::TAU * f);
        }
    }
    let s = Setpoint::new(&sp(SetpointKind::Chirp, Sweep::Log));
    // Log sweep: geometric mean frequency at mid-time.
    let (fm, _) = s.sweep_phase(1.5);
    assert!((fm - 300.0_f64.sqrt()).abs() < 1e-6);
}

#[test]
fn static_dynamic_superposition_of_004() {
    let s = Setpoint::new(&sp(SetpointKind::StaticDynamic, Sweep::Log));
    assert!((s.sample(0.025).0 - 785.0 / 2.0).abs() < 1e-9);
    let vals: Vec<f64> = (0..30_000)
        .map(|k| s.sample(0.05 + k as f64 * 1e-4).0)
        .collect();
    let max = vals.iter().cloned().fold(f64::MIN, f64::max);
    let min = vals.iter().cloned().fold(f64::MAX, f64::min);
    assert!((max - (785.0 + 196.0)).abs() < 0.5 && (min - (785.0 - 196.0)).abs() < 0.5);
}

#[test]
fn random_steps_are_deterministic_and_bounded() {
    let c = sp(SetpointKind::RandomSteps, Sweep::Linear);
    let a = Setpoint::new(&c);
    let b = Setpoint::new(&c);
    let mut distinct = std::collections::BTreeSet::new();
    for k in 0..100 {
        let t = k as f64 * 0.05;
        let (va, _) = a.sample(t);
        assert_eq!(va, b.sample(t).0);
        assert!((0.0..=1.0).contains(&va));
        distinct.insert((va * 1e9) as i64);
    }
    assert!(distinct.len() > 40, "levels change every hold");
}
