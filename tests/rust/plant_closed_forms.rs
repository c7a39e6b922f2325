//! Plant components against closed forms: orifice flow, K_q rating, hydraulic stiffness
//! k = β(A₁²/V₁ + A₂²/V₂) (003 eq. 15), natural frequency f = √(k/m)/2π (003 eq. 16),
//! exact second-order spool step response (004 eq. 1).

use ehactl_plant::params::{FlowForm, PlantParams, ValveDynamics};
use ehactl_plant::valve::{EdgeLaw, SpoolModel};
use ehactl_plant::Plant;
use ehactl_tests::blocked_cylinder;

fn orifice_params() -> PlantParams {
    let mut p = blocked_cylinder(10.0, 0.0, 0.5);
    p.valve.flow_form = FlowForm::Orifice;
    p.valve.discharge_coefficient = Some(0.61);
    p.valve.area_max = Some(2.0e-5);
    p
}

#[test]
fn orifice_flow_matches_cd_a_sqrt_2dp_over_rho() {
    let p = orifice_params();
    let e = EdgeLaw::new(&p);
    let (_, limit) = EdgeLaw::stages(&p);
    for dp in [1.0e6, 5.0e6, 20.0e6] {
        for o in [0.1, 0.5, 1.0] {
            let (q, _) = e.edge(&limit, o, dp);
            let exact = 0.61 * 2.0e-5 * o * (2.0 * dp / 900.0).sqrt();
            let rel = (q - exact).abs() / exact;
            // Laminar regularisation changes the flow by ≈ (Δp_l/Δp)²/4 ≤ 1e-4 here.
            assert!(rel < 2e-4, "dp {dp} o {o}: {q} vs {exact} ({rel})");
            let (qn, _) = e.edge(&limit, o, -dp);
            assert!((qn + q).abs() < 1e-15, "flow is odd in Δp");
        }
    }
    // Finite, positive slope at Δp = 0 (no infinite K_c).
    let (q0, dq0) = e.edge(&limit, 1.0, 0.0);
    assert_eq!(q0, 0.0);
    assert!(dq0.is_finite() && dq0 > 0.0);
}

#[test]
fn kq_form_gives_rated_flow_at_rated_drop() {
    let p = blocked_cylinder(10.0, 0.0, 0.5);
    let e = EdgeLaw::new(&p);
    let (_, limit) = EdgeLaw::stages(&p);
    let (q, _) = e.edge(&limit, 1.0, 1.0e6);
    assert!((q - 5.8333e-4).abs() / 5.8333e-4 < 1e-3, "{q}");
    // √Δp law: four times the drop, twice the flow.
    let (q4, _) = e.edge(&limit, 1.0, 4.0e6);
    assert!((q4 / q - 2.0).abs() < 1e-3);
}

#[test]
fn power_law_matches_004_eq20_and_its_kc() {
    let mut p = blocked_cylinder(10.0, 0.0, 0.5);
    p.valve.flow_form = FlowForm::PowerLaw;
    p.valve.flow_at_1mpa = Some(1.4075e-4);
    p.valve.exponent = Some(0.4667);
    p.valve.laminar_pressure = 1.0e3;
    let e = EdgeLaw::new(&p);
    let (_, limit) = EdgeLaw::stages(&p);
    for pd_mpa in [2.0_f64, 7.0, 15.0] {
        let (q, dq) = e.edge(&limit, 1.0, pd_mpa * 1e6);
        let exact = 1.4075e-4 * pd_mpa.powf(0.4667);
        assert!((q - exact).abs() / exact < 1e-4, "Q at {pd_mpa} MPa");
        // 004 eq. 21: K_Cnl = 1.0407e-7·P_d^−0.5333 with P_d in Pa.
        let kc = 1.0407e-7 * (pd_mpa * 1e6).powf(-0.5333);
        assert!(
            (dq - kc).abs() / kc < 2e-3,
            "K_C at {pd_mpa} MPa: {dq} vs {kc}"
        );
    }
}

#[test]
fn hydraulic_stiffness_from_simulated_static_deflection() {
    // Closed valve, constant force step; the piston settles at Δx = ΔF / k (003 eq. 15).
    for x0 in [0.2, 0.6, 1.0] {
        let p = blocked_cylinder(255.0, 2.0e5, x0);
        let plant = Plant::configure(&p, 2e-4).unwrap();
        let x_start = plant.state().x;
        let f_step = 5000.0;
        // Same initial pressures as the unloaded equilibrium, then a constant 5 kN load.
        let mut q = p.clone();
        q.excitation.kind = ehactl_plant::params::ExcitationKind::Constant;
        q.excitation.offset = f_step;
        q.cylinder.initial_pressure_a = Some(plant.state().p_a);
        q.cylinder.initial_pressure_b = Some(plant.state().p_b);
        let mut loaded = Plant::configure(&q, 2e-4).unwrap();
        for _ in 0..10_000 {
            loaded.step(0.0).unwrap();
        }
        let dx = x_start - loaded.state().x;
        let (v1, v2) = plant.volumes(x0);
        let k = 1.8e9 * (1.96e-3_f64.powi(2) / v1 + 1.3e-3_f64.powi(2) / v2);
        let expected = f_step / k;
        assert!(
            (dx - expected).abs() / expected < 0.01,
            "x0 {x0}: deflection {dx} m vs F/k {expected} m"
        );
        assert!((plant.hydraulic_stiffness(x0) - k).abs() / k < 1e-12);
    }
}

fn oscillation_frequency(plant: &mut Plant, dt: f64, cycles: usize) -> f64 {
    let xs: Vec<f64> = (0..cycles)
        .map(|_| {
            plant.step(0.0).unwrap();
            plant.state().x
        })
        .collect();
    let mean = xs.iter().sum::<f64>() / xs.len() as f64;
    let mut crossings = Vec::new();
    for k in 1..xs.len() {
        let (a, b) = (xs[k - 1] - mean, xs[k] - mean);
        if a < 0.0 && b >= 0.0 {
            // Linear interpolation of the upward crossing of the mean.
            crossings.push((k as f64 - 1.0 + (-a) / (b - a)) * dt);
        }
    }
    let n = crossings.len();
    assert!(n >= 3, "need oscillation");
    (n - 1) as f64 / (crossings[n - 1] - crossings[0])
}

#[test]
fn natural_frequency_matches_003_eq16_over_the_stroke() {
    // Rigid connection m_y + m_L = 255 kg, closed valve, small initial velocity kick via a
    // pressure imbalance; measured frequency vs √(k/m)/2π.
    let dt = 1e-4;
    let mut lowest = f64::INFINITY;
    for x0 in [0.1, 0.4, 0.7, 0.9, 1.1] {
        let p = blocked_cylinder(255.0, 0.0, x0);
        let eq = Plant::configure(&p, dt).unwrap();
        let mut q = p.clone();
        q.cylinder.initial_pressure_a = Some(eq.state().p_a + 2.0e5);
        q.cylinder.initial_pressure_b = Some(eq.state().p_b);
        let mut plant = Plant::configure(&q, dt).unwrap();
        let f_meas = oscillation_frequency(&mut plant, dt, 20_000);
        let k = eq.hydraulic_stiffness(x0);
        let f = (k / 255.0).sqrt() / std::f64::consts::TAU;
        lowest = lowest.min(f);
        assert!(
            (f_meas - f).abs() / f < 0.01,
            "x0 {x0}: {f_meas} Hz vs {f} Hz"
        );
    }
    // 003: "the lowest value of the natural frequency ... f_y ≈ 30 Hz".
    assert!((lowest - 30.0).abs() / 30.0 < 0.10, "lowest {lowest} Hz");
}

#[test]
fn second_order_spool_matches_analytic_step() {
    let mut p = blocked_cylinder(10.0, 0.0, 0.5);
    p.effects.valve_dynamics = Some(ValveDynamics {
        enabled: true,
        order: 2,
        time_constant: 0.0,
        natural_frequency: 1507.9,
        damping_ratio: 0.59,
    });
    let h = 1e-5;
    let m = SpoolModel::new(p.effects.valve_dynamics.as_ref(), h).expect("spool discretises");
    let (w, z) = (1507.9_f64, 0.59_f64);
    let wd = w * (1.0 - z * z).sqrt();
    let (mut s, mut sd) = (0.0, 0.0);
    for k in 1..=500 {
        m.advance(&mut s, &mut sd, 1.0);
        let t = k as f64 * h;
        let exact = 1.0 - (-z * w * t).exp() * ((wd * t).cos() + z * w / wd * (wd * t).sin());
        assert!((s - exact).abs() < 1e-9, "t {t}: {s} vs {exact}");
    }
}

#[test]
fn first_order_spool_matches_pt1() {
    let mut p = blocked_cylinder(10.0, 0.0, 0.5);
    p.effects.valve_dynamics = Some(ValveDynamics {
        enabled: true,
        order: 1,
        time_constant: 0.01,
        natural_frequency: 0.0,
        damping_ratio: 0.0,
    });
    let h = 1e-4;
    let m = SpoolModel::new(p.effects.valve_dynamics.as_ref(), h).expect("spool discretises");
    let (mut s, mut sd) = (0.0, 0.0);
    for k in 1..=300 {
        m.advance(&mut s, &mut sd, 0.5);
        let exact = 0.5 * (1.0 - (-(k as f64) * h / 0.01).exp());
        assert!((s - exact).abs() < 1e-12);
    }
}

#[test]
fn spool_beyond_the_exponential_bound_is_a_config_error() {
    // ζ = 1e53 at ω = 1507.9 rad/s: ‖A·h‖₁ ≈ 3e56·h, far beyond what `expm_checked` accepts
    // (it hung nalgebra's exponential before, BENCHMARKS.md "Fuzzed parsers").
    let mut p = blocked_cylinder(10.0, 0.0, 0.5);
    p.effects.valve_dynamics = Some(ValveDynamics {
        enabled: true,
        order: 2,
        time_constant: 0.0,
        natural_frequency: 1507.9,
        damping_ratio: 1e53,
    });
    let e = SpoolModel::new(p.effects.valve_dynamics.as_ref(), 1e-5).expect_err("refused");
    assert!(
        e.to_string()
            .contains("effects.valve_dynamics.damping_ratio"),
        "{e}"
    );
    assert!(Plant::configure(&p, 2e-4).is_err());
}

#[test]
fn sealed_chambers_keep_their_oil_mass_at_every_substep() {
    // Closed valve, no leakage: each chamber holds a fixed oil mass, ρ(p)·V(x) = const with
    // ρ ∝ exp(p/β) at constant β, so p(x) = p(x₀) + β·ln(V(x₀)/V(x)) (003 eq. 4, integrated)
    // at every instant of the undamped oscillation that a 5 kN load step starts. Pressure
    // and position must be at one time level: with the position drifted after the velocity
    // kick, the position ran one substep ahead of the pressures: here 1.9 % of the swing.
    let p = blocked_cylinder(255.0, 0.0, 0.6);
    let plant = Plant::configure(&p, 2e-4).unwrap();
    let mut q = p.clone();
    q.excitation.kind = ehactl_plant::params::ExcitationKind::Constant;
    q.excitation.offset = 5000.0;
    q.cylinder.initial_pressure_a = Some(plant.state().p_a);
    q.cylinder.initial_pressure_b = Some(plant.state().p_b);
    let mut loaded = Plant::configure(&q, 2e-4).unwrap();
    let s0 = *loaded.state();
    let beta = loaded.bulk_modulus(s0.p_a);
    assert_eq!(beta, loaded.bulk_modulus(s0.p_b), "constant β in this test");
    let (va0, vb0) = loaded.volumes(s0.x);
    let (mut worst, mut lo, mut hi) = (0.0_f64, f64::INFINITY, f64::NEG_INFINITY);
    // 2 000 periods of 0.2 ms: about 8 oscillation periods (f = √(k/m)/2π ≈ 20 Hz).
    for _ in 0..2000 {
        loaded.step(0.0).unwrap();
        let s = loaded.state();
        assert_eq!(beta, loaded.bulk_modulus(s.p_a));
        assert_eq!(beta, loaded.bulk_modulus(s.p_b));
        let (va, vb) = loaded.volumes(s.x);
        let pa = s0.p_a + beta * (va0 / va).ln();
        let pb = s0.p_b + beta * (vb0 / vb).ln();
        worst = worst.max((s.p_a - pa).abs()).max((s.p_b - pb).abs());
        lo = lo.min(s.p_a);
        hi = hi.max(s.p_a);
    }
    let swing = hi - lo;
    assert!(
        swing > 1e5,
        "the load step moves the piston: p_a swing {swing} Pa"
    );
    assert!(
        worst < 1e-3 * swing,
        "chamber pressure off the sealed-chamber closed form by {worst:.3e} Pa, {:.2e} of the {swing:.3e} Pa swing",
        worst / swing
    );
}

/// `integration.method = "linear_exact"` with the amplifier dead zone (`valve_deadband`
/// variant `amplifier`): the spool target is sign(c')·max(|c'| − d, 0), c' = c + offset,
/// c = u/full scale, as in the exponential-Euler substep. A command held inside the dead
/// zone leaves the spool at 0 exactly; one beyond it drives the first-order spool (T_z =
/// 10 ms, exact zero-order-hold discretisation) along s(t) = s∞·(1 − e^(−t/T_z)).
#[test]
fn linear_exact_applies_the_amplifier_dead_zone() {
    use ehactl_plant::params::{DeadbandVariant, IntegrationMethod, ValveDeadband};
    let (d, offset, tz, dt) = (0.1, 0.02, 0.01, 1e-3);
    let mut p = blocked_cylinder(10.0, 0.0, 0.5);
    p.integration.method = IntegrationMethod::LinearExact;
    p.effects.valve_dynamics = Some(ValveDynamics {
        enabled: true,
        order: 1,
        time_constant: tz,
        natural_frequency: 0.0,
        damping_ratio: 0.0,
    });
    p.effects.valve_deadband = Some(ValveDeadband {
        enabled: true,
        variant: DeadbandVariant::Amplifier,
        deadzone: d,
        overlap: 0.0,
        zero_offset: offset,
    });
    // Inside the dead zone: c' = 0.05 + 0.02 and −0.11 + 0.02, |c'| < d.
    for u in [0.5, -1.1] {
        let mut plant = Plant::configure(&p, dt).unwrap();
        assert_eq!(plant.method(), IntegrationMethod::LinearExact);
        for _ in 0..200 {
            plant.step(u).unwrap();
            assert_eq!(plant.state().spool, 0.0, "u {u} V");
        }
    }
    // Beyond it: c = 0.5, s∞ = 0.5 + 0.02 − 0.1; c = −0.5, s∞ = −(0.5 − 0.02 − 0.1).
    for (u, s_inf) in [(5.0, 0.5 + offset - d), (-5.0, -(0.5 - offset - d))] {
        let mut plant = Plant::configure(&p, dt).unwrap();
        for k in 1..=100 {
            plant.step(u).unwrap();
            let exact = s_inf * (1.0 - (-(k as f64) * dt / tz).exp());
            let s = plant.state().spool;
            assert!(
                (s - exact).abs() < 1e-12,
                "u {u} V, t {} s: {s} vs {exact}",
                k as f64 * dt
            );
        }
    }
}

/// The bounds of the states a rig can have (crates/plant/src/plausible.rs), worked out by
/// hand for Sahu 2022 (20 MPa supply, 2.364e-4 m² on both sides, 1.182e-6 m³ dead volumes,
/// 0.893 kg, β = 1.75e9 Pa, 2 mm stroke, 5 kHz, K_q valve k = 1.4299e-5 m³/s / √(1 MPa), no
/// excitation, the load cell relaxed at the initial position): the open valve's speed at
/// the supply v_s = k·√(20 MPa)/A = 0.2705 m/s, the oil-spring pressure peak of the mass
/// v_s·√(m·β/V) = 9.84 MPa, so p ≤ 10·(20 MPa + 9.84 MPa) + 10 MPa = 308 MPa and
/// ≥ −0.95 bar − 10 MPa; rod force ≤ that on 2 · 2.364e-4 m²; |v| ≤ the larger of
/// 10·k·√(p_max)/A = 10.6 m/s and 2 mm / 0.2 ms = 10 m/s. (√Δp stands for the edge law's
/// regularised power, within 1e-5 at these drops.) A state beyond a bound is named with its
/// value and bound; the probe's runaway (a chamber at 1e11 Pa) makes the step an
/// implausible-state error, not a result.
#[test]
fn an_impossible_state_is_refused_with_its_bound() {
    let cfg = ehactl_tests::config("sahu2022_force.toml");
    let mut plant = Plant::configure(&cfg.plant, cfg.timebase().period()).unwrap();
    let b = *plant.plausible();
    let close = |a: f64, e: f64| (a - e).abs() <= 1e-4 * e.abs();
    let (k, area, ps) = (1.4299e-5 / 1.0e3, 2.364e-4, 20.0e6_f64);
    let v_s = k * ps.sqrt() / area;
    let peak = v_s * (0.893 * 1.75e9 / 1.182e-6_f64).sqrt();
    let p_max = 10.0 * (ps + peak) + 10.0e6;
    assert!((peak - 9.84e6).abs() < 0.01e6, "{peak}");
    assert!(close(b.p_max, p_max), "{b:?} vs {p_max}");
    assert!(close(b.p_min, -0.95e5 - 10.0e6), "{b:?}");
    assert!(close(b.f_max, p_max * 2.0 * area), "{b:?}");
    let v_valve = 10.0 * k * p_max.sqrt() / area;
    assert!(
        close(b.v_max, v_valve.max(2.0e-3 / 2.0e-4)),
        "{b:?} ({v_valve} m/s)"
    );
    let mut s = *plant.state();
    assert_eq!(b.check(&s), None, "the initial state is plausible");
    s.p_b = 1.1 * p_max;
    assert_eq!(b.check(&s), Some(("p_b", 1.1 * p_max, b.p_max, "Pa")));
    s.p_b = 1.0e7;
    s.v = -1.1 * b.v_max;
    assert_eq!(b.check(&s), Some(("v", -1.1 * b.v_max, b.v_max, "m/s")));
    // The probe's runaway chamber: one step from 1e11 Pa fails as implausible.
    let names = plant.linear_state_names();
    let mut x = plant.linear_state();
    x[names.iter().position(|n| n == "p_a").unwrap()] = 1.0e11;
    plant.set_linear_state(&x);
    let e = plant.step(0.0).unwrap_err();
    assert!(e.is_implausible() && e.bound.is_finite(), "{e}");
    assert!(
        e.to_string().contains("beyond what the rig can reach"),
        "{e}"
    );
}
