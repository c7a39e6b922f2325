//! Friction: breakaway at F_s, a true stick phase (no drift, no chatter) at zero velocity,
//! Coulomb level while sliding (003 eq. 5, 004 eq. 28–34).

use ehactl_plant::friction::FrictionModel;
use ehactl_plant::params::{ExcitationKind, Friction, PlantParams};
use ehactl_plant::Plant;
use ehactl_tests::blocked_cylinder;

fn soft_with_friction(force: f64, kind: ExcitationKind, freq: f64) -> PlantParams {
    // Huge dead volumes make the closed chambers a negligible spring, so the external
    // force meets only friction and inertia.
    let mut p = blocked_cylinder(20.0, 0.0, 0.6);
    p.cylinder.dead_volume_a = 1.0e4;
    p.cylinder.dead_volume_b = 1.0e4;
    p.effects.friction = Some(Friction {
        enabled: true,
        variant: Default::default(),
        static_force: 700.0,
        coulomb_force: 500.0,
        stribeck_velocity: 0.01,
        viscous: 0.0,
        bristle_stiffness: 0.0,
        bristle_damping: 0.0,
    });
    p.excitation.kind = kind;
    p.excitation.amplitude = force;
    p.excitation.offset = if kind == ExcitationKind::Constant {
        force
    } else {
        0.0
    };
    p.excitation.frequency = freq;
    // Start with zero hydraulic force (p_a·A₁ = p_b·A₂) instead of pressures that balance
    // the load, so the external force meets only friction and inertia.
    p.cylinder.initial_pressure_a = Some(1.0e6);
    p.cylinder.initial_pressure_b = Some(1.0e6 * 1.96e-3 / 1.3e-3);
    p
}

#[test]
fn below_breakaway_the_piston_does_not_move_at_all() {
    for f in [100.0, 400.0, 690.0, -690.0] {
        let p = soft_with_friction(f, ExcitationKind::Constant, 0.0);
        let mut plant = Plant::configure(&p, 2e-4).unwrap();
        let x0 = plant.state().x;
        for _ in 0..5000 {
            plant.step(0.0).unwrap();
            assert!(plant.state().stuck);
            assert_eq!(plant.state().v, 0.0);
        }
        assert_eq!(plant.state().x, x0, "drift while stuck at F = {f} N");
    }
}

#[test]
fn above_breakaway_it_slides_with_coulomb_friction() {
    let f = 1000.0;
    let p = soft_with_friction(f, ExcitationKind::Constant, 0.0);
    let mut plant = Plant::configure(&p, 2e-4).unwrap();
    for _ in 0..500 {
        plant.step(0.0).unwrap();
    }
    // After 0.5 s at well above the Stribeck velocity: a = (F − F_C)/m, force opposes +x.
    let v1 = plant.state().v;
    for _ in 0..500 {
        plant.step(0.0).unwrap();
    }
    let v2 = plant.state().v;
    let a = (v2 - v1) / 0.1;
    let expected = -(f - 500.0) / 20.0;
    assert!(
        v2 < -0.1,
        "sliding in −x: v1 {v1} v2 {v2} x {}",
        plant.state().x
    );
    assert!(
        (a - expected).abs() / expected.abs() < 0.02,
        "a {a} vs {expected}"
    );
    assert!((plant.state().friction.abs() - 500.0).abs() < 1.0);
}

#[test]
fn harmonic_force_gives_stick_slip_without_chatter() {
    // ±1000 N at 2 Hz: sliding near the peaks, stuck around the reversals.
    let p = soft_with_friction(1000.0, ExcitationKind::Harmonic, 2.0);
    let mut plant = Plant::configure(&p, 2e-4).unwrap();
    let mut stuck_runs = 0;
    let mut was_stuck = true;
    let mut sign_flips_while_moving = 0;
    let mut last_v: f64 = 0.0;
    let mut x_at_stick = plant.state().x;
    for _ in 0..10_000 {
        plant.step(0.0).unwrap();
        let s = *plant.state();
        if s.stuck {
            if !was_stuck {
                stuck_runs += 1;
                x_at_stick = s.x;
            }
            assert_eq!(s.x, x_at_stick, "no drift during a stick phase");
        } else if last_v != 0.0 && s.v != 0.0 && (s.v > 0.0) != (last_v > 0.0) {
            sign_flips_while_moving += 1;
        }
        was_stuck = s.stuck;
        last_v = s.v;
    }
    // 2 s at 2 Hz: 8 reversals, each passing through a stick phase.
    assert!((7..=9).contains(&stuck_runs), "stick phases {stuck_runs}");
    assert_eq!(
        sign_flips_while_moving, 0,
        "velocity reverses only through stick"
    );
}

#[test]
fn projection_is_exact_at_the_breakaway_boundary() {
    let mut fm = FrictionModel::new(&Friction {
        variant: Default::default(),
        enabled: true,
        static_force: 44.0,
        coulomb_force: 39.0,
        stribeck_velocity: 0.001,
        viscous: 0.0,
        bristle_stiffness: 0.0,
        bristle_damping: 0.0,
    });
    let (m, h) = (0.893, 1e-5);
    // Net force just below / above F_s from rest.
    let below = 43.9 * h / m;
    let (v, f, stuck) = fm.project(0.0, below, m, h);
    assert!(stuck && v == 0.0 && (f - 43.9).abs() < 1e-9);
    let above = 44.1 * h / m;
    let (v, _, stuck) = fm.project(0.0, above, m, h);
    assert!(!stuck && v > 0.0 && (v - 0.1 * h / m).abs() < 1e-12);
}
