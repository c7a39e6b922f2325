//! Structural effect variants of the plant against closed forms written here from
//! their sources, not from the plant code: the entrained-air bulk modulus of Yu et al. (1994)
//! as given by Gholizadeh et al. (2011), the pressure-compensated pump's droop and flow-limit
//! collapse, the amplifier dead zone, asymmetric spool limits, the tone phase, the static
//! deflection of a compliant cylinder mount, per-chamber leakage decay and the load-side
//! Coulomb force's terminal velocity.

use ehactl_plant::effects::{entrained_air_bulk_modulus, LapStage, SupplyModel};
use ehactl_plant::params::*;
use ehactl_plant::valve::EdgeLaw;
use ehactl_plant::Plant;
use ehactl_tests::blocked_cylinder;

#[test]
fn entrained_air_bulk_modulus_matches_the_mixture_law() {
    // β = V/(−dV/dp) of oil (β_l) plus air following P·V^n = const from P0 = 101325 Pa with
    // volume fraction α0 at P0: V_air = α0·(P0/P)^(1/n), dV_air/dP = −V_air/(n·P),
    // V_oil = (1−α0)·(1 − p/β_l) ≈ (1−α0), dV_oil/dp = −(1−α0)/β_l.
    let (bl, a0, n): (f64, f64, f64) = (1.6e9, 0.01, 1.4);
    for p_gauge in [0.0f64, 1.0e6, 5.0e6, 20.0e6] {
        let pa = p_gauge + 101_325.0;
        let vair = a0 * (101_325.0 / pa).powf(1.0 / n);
        let v = (1.0 - a0) + vair;
        let dv = (1.0 - a0) / bl + vair / (n * pa);
        let exact = v / dv;
        let got = entrained_air_bulk_modulus(bl, a0, n, p_gauge);
        assert!(
            (got - exact).abs() / exact < 1e-12,
            "p {p_gauge}: {got} vs {exact}"
        );
    }
    // 1 % air: at atmosphere the mixture is ~ n·P0/α0 ≈ 14 MPa stiff; at 20 MPa within 10 %
    // of the liquid.
    assert!(entrained_air_bulk_modulus(bl, a0, n, 0.0) < 20e6);
    assert!(entrained_air_bulk_modulus(bl, a0, n, 20e6) > 0.9 * bl);
}

#[test]
fn pump_limit_droops_in_its_band_and_collapses_beyond_its_flow() {
    let s = SupplyPressureDrop {
        enabled: true,
        variant: SupplyVariant::PumpLimit,
        resistance: 0.0,
        time_constant: 0.0,
        max_flow: 2.0e-4,
        regulation_band: 1.0e6,
        volume: 1.0e-3,
    };
    let m = SupplyModel::new(&s, 20e6, 1.5e9);
    // Steady state within the band: p = p0 − Δp_c·Q/Q_max.
    let mut p = 20e6;
    for _ in 0..200_000 {
        p = m.advance(p, 1.0e-4, 0.0, 1e-5);
    }
    assert!((p - 19.5e6).abs() < 1.0, "{p}");
    // Demand above Q_max below the band: dp/dt = β/V·(Q_max − Q) exactly.
    let p0 = 18.0e6;
    let p1 = m.advance(p0, 3.0e-4, 0.0, 1e-4);
    let exact = p0 + 1e-4 * 1.5e9 / 1.0e-3 * (2.0e-4 - 3.0e-4);
    assert!((p1 - exact).abs() < 1e-6 * p0, "{p1} vs {exact}");
}

#[test]
fn amplifier_dead_zone_and_asymmetric_limits() {
    let mut p = blocked_cylinder(10.0, 0.0, 0.5);
    p.effects.valve_deadband = Some(ValveDeadband {
        enabled: true,
        variant: DeadbandVariant::Amplifier,
        deadzone: 0.1,
        overlap: 0.3, // ignored by the amplifier variant
        zero_offset: 0.02,
    });
    p.effects.valve_saturation = Some(ValveSaturation {
        enabled: true,
        variant: SaturationVariant::Asymmetric,
        spool_limit: 0.5,
        spool_limit_negative: 0.8,
        max_flow: 0.0,
    });
    let e = EdgeLaw::new(&p);
    let (lap, limit) = EdgeLaw::stages(&p);
    // sign(c + 0.02)·max(|c + 0.02| − 0.1, 0)
    for (c, want) in [(0.05, 0.0), (-0.11, 0.0), (0.3, 0.22), (-0.5, -0.38)] {
        assert!(
            (lap.target(c) - want).abs() < 1e-12,
            "target({c}) = {}",
            lap.target(c)
        );
    }
    // No overlap with the amplifier variant; +0.5 / −0.8 spool limits.
    assert_eq!(e.openings(&lap, &limit, 0.9), [0.5, 0.0, 0.0, 0.5]);
    assert_eq!(e.openings(&lap, &limit, -0.9), [0.0, 0.8, 0.8, 0.0]);
    assert_eq!(e.openings(&lap, &limit, 0.0), [0.0; 4]);
}

#[test]
fn tone_phase_is_applied() {
    let mut p = blocked_cylinder(10.0, 0.0, 0.5);
    p.effects.sensor_tone = Some(SensorTone {
        enabled: true,
        channel: SensorChannel::PressureA,
        frequencies: vec![50.0],
        amplitudes: vec![1.0e5],
        phases: vec![4.2],
    });
    let mut plant = Plant::configure(&p, 1e-3).unwrap();
    let pa0 = plant.state().p_a;
    let m = plant.measure();
    // Sample at t = 0: a·sin(φ), the chamber pressure is still its initial value.
    assert!(
        (m.p_a - pa0 - 1.0e5 * 4.2f64.sin()).abs() < 1e-6,
        "{}",
        m.p_a - pa0
    );
}

/// The blocked cylinder of the closed-form tests with its spring, for the mount tests.
fn sprung(mass: f64) -> PlantParams {
    let mut p = blocked_cylinder(mass, 2.0e4, 0.5);
    p.mechanics.load_stiffness = 1.0e6;
    p.mechanics.load_contact_position = 0.5;
    p
}

#[test]
fn piston_side_mount_deflects_by_the_reaction_over_its_stiffness() {
    // Closed valve, constant force on the rod: at rest the body carries the oil's reaction,
    // x_body = −F_hyd/k_m, and the spring sees the absolute piston position x + x_body.
    let km = 2.0e7;
    let mut p = sprung(50.0);
    p.excitation = Excitation {
        kind: ExcitationKind::Constant,
        offset: 4000.0,
        ..Default::default()
    };
    p.effects.flexible_mount = Some(FlexibleMount {
        enabled: true,
        variant: MountVariant::PistonSide,
        load_mass: 40.0,
        stiffness: km,
        damping: 2.0 * 0.5 * (km * 40.0f64).sqrt(),
    });
    let mut plant = Plant::configure(&p, 1e-3).unwrap();
    for _ in 0..3000 {
        plant.step(0.0).unwrap();
    }
    let s = *plant.state();
    let f_hyd = s.p_a * p.cylinder.area_a - s.p_b * p.cylinder.area_b;
    assert!(s.v.abs() < 1e-6 && s.v_load.abs() < 1e-6, "at rest: {s:?}");
    assert!(
        (s.x_load + f_hyd / km).abs() < 1e-3 * (f_hyd / km).abs(),
        "x_body {} vs −F/k {}",
        s.x_load,
        -f_hyd / km
    );
    // Force balance on the piston: F_hyd = k_L·(x + x_body − x_c) + F_ext.
    let spring = 1.0e6 * (s.x + s.x_load - 0.5);
    assert!(
        (f_hyd - spring - 4000.0).abs() < 1.0,
        "{f_hyd} vs {}",
        spring + 4000.0
    );
    assert!((s.rod_force - spring - 4000.0).abs() < 1e-6);
}

#[test]
fn per_chamber_leakage_drains_one_chamber_only() {
    // Piston held by its spring, closed critical-centre valve, leakage to tank from A only:
    // p_b stays put to within the small piston motion; p_a falls.
    let mut p = sprung(50.0);
    p.effects.external_leakage = Some(Leakage {
        enabled: true,
        variant: LeakageVariant::PerChamber,
        coefficient: 2e-12,
        coefficient_b: 0.0,
    });
    let mut plant = Plant::configure(&p, 1e-3).unwrap();
    let (a0, b0) = (plant.state().p_a, plant.state().p_b);
    for _ in 0..200 {
        plant.step(0.0).unwrap();
    }
    let s = plant.state();
    assert!(s.p_a < a0 - 1e5, "p_a {a0} → {}", s.p_a);
    // B only follows the piston: its change is the compression by the piston's motion.
    let vb = p.cylinder.dead_volume_b + p.cylinder.area_b * (p.cylinder.stroke - s.x);
    let expect_b = b0 + 1.8e9 / vb * p.cylinder.area_b * (s.x - 0.5);
    assert!(
        (s.p_b - expect_b).abs() < 0.05 * (s.p_b - b0).abs().max(1e4),
        "p_b {} vs {expect_b}",
        s.p_b
    );
}

#[test]
fn load_coulomb_friction_terminal_velocity() {
    // Mass pushed by a constant force F against F_C·tanh(v/v_s) and damping c, no oil
    // (valve closed, chambers huge so the hydraulic spring is negligible):
    // terminal v solves F = F_C·tanh(v/v_s) + c·v.
    let mut p = blocked_cylinder(20.0, 1000.0, 0.5);
    p.cylinder.dead_volume_a = 1.0e3;
    p.cylinder.dead_volume_b = 1.0e3;
    p.cylinder.initial_pressure_a = Some(0.0);
    p.cylinder.initial_pressure_b = Some(0.0);
    p.excitation = Excitation {
        kind: ExcitationKind::Constant,
        offset: -600.0, // the external force opposes +x: −600 N pushes the piston to +x
        ..Default::default()
    };
    p.effects.friction = Some(Friction {
        enabled: true,
        variant: FrictionVariant::LoadCoulomb,
        static_force: 400.0,
        coulomb_force: 400.0,
        stribeck_velocity: 0.01,
        viscous: 0.0,
        bristle_stiffness: 0.0,
        bristle_damping: 0.0,
    });
    let mut plant = Plant::configure(&p, 1e-3).unwrap();
    for _ in 0..300 {
        plant.step(0.0).unwrap();
    }
    let v = plant.state().v;
    // F_ext = −600 N opposing +x means a +600 N push; solve 600 = 400·tanh(v/0.01) + 1000·v.
    let (mut lo, mut hi) = (0.0, 10.0);
    for _ in 0..100 {
        let m: f64 = 0.5 * (lo + hi);
        if 400.0 * (m / 0.01).tanh() + 1000.0 * m > 600.0 {
            hi = m;
        } else {
            lo = m;
        }
    }
    assert!((v - lo).abs() < 0.01 * lo, "v {v} vs {lo}");
}

/// `[uncertainty]` of the nominal parameters: parsed from a rig config, turned into refit
/// ranges, and refused with a one-line error naming the key when wrong.
mod uncertainty {
    use ehactl_plant::PlantParams;

    fn with(table: &str) -> Result<PlantParams, String> {
        let base = ehactl_ident_eval::synth::TESTRIG_TOML;
        let text = format!("{base}\n[uncertainty]\n{table}\n");
        ehactl_config::RigConfig::from_toml_str(&text)
            .map(|c| c.plant)
            .map_err(|e| e.to_string())
    }

    fn range(p: &PlantParams, path: &str) -> Option<(f64, f64, f64)> {
        p.refit_ranges()
            .unwrap()
            .into_iter()
            .find(|r| r.0 == path)
            .map(|r| (r.1, r.2, r.3))
    }

    #[test]
    fn default_is_fifteen_percent_on_the_five_and_stated_values_replace_it() {
        let p = with("").unwrap();
        let (v, lo, hi) = range(&p, "mechanics.mass").unwrap();
        assert!((lo - 0.85 * v).abs() < 1e-9 && (hi - 1.15 * v).abs() < 1e-9);
        assert!(
            range(&p, "valve.underlap").is_none(),
            "not refit unless stated"
        );
        let p = with(
            "\"valve.rated_flow\" = \"30%\"\n\"mechanics.mass\" = 2.5\n\"valve.underlap\" = 0.01\n\"mechanics.damping\" = \"0%\"",
        )
        .unwrap();
        let (q, lo, hi) = range(&p, "valve.rated_flow").unwrap();
        assert!((lo - 0.7 * q).abs() < 1e-15 && (hi - 1.3 * q).abs() < 1e-15);
        let (m, lo, hi) = range(&p, "mechanics.mass").unwrap();
        assert_eq!((lo, hi), (m - 2.5, m + 2.5));
        let (u, lo, hi) = range(&p, "valve.underlap").unwrap();
        assert!((lo - (u - 0.01)).abs() < 1e-15 && (hi - (u + 0.01)).abs() < 1e-15);
        assert!(
            range(&p, "mechanics.damping").is_none(),
            "0 % keeps it fixed"
        );
        // The diagnosis refits exactly these.
        let names: Vec<String> = ehactl_ident::fit::base_params(&p)
            .iter()
            .map(|f| f.name.clone())
            .collect();
        assert!(
            names.contains(&"valve.underlap/nominal".to_string()),
            "{names:?}"
        );
        assert!(
            !names.iter().any(|n| n.starts_with("mechanics.damping")),
            "{names:?}"
        );
    }

    /// The loop's assumptions (valve bandwidth, delay, null offset and dead band) are refit
    /// from 0 (or across 0 for the signed null offset) within the registry's range; a
    /// bandwidth key of the other spool order or a switched-off section is refused.
    #[test]
    fn loop_keys_reach_their_range_end_and_wrong_ones_are_refused() {
        let sections = "[effects.time_delay]\ndelay = 0.002\n[effects.valve_dynamics]\norder = 1\ntime_constant = 0.0\n[effects.valve_deadband]\noverlap = 0.0\nzero_offset = 0.01\n";
        let text = format!(
            "{}\n{sections}\n[uncertainty]\n\"effects.time_delay.delay\" = 0.02\n\"effects.valve_dynamics.time_constant\" = 0.02\n\"effects.valve_deadband.zero_offset\" = 0.05\n\"effects.valve_deadband.overlap\" = 0.05\n",
            ehactl_ident_eval::synth::TESTRIG_TOML
        );
        let p = ehactl_config::RigConfig::from_toml_str(&text)
            .unwrap()
            .plant;
        assert_eq!(
            range(&p, "effects.time_delay.delay"),
            Some((0.002, 0.0, 0.022))
        );
        assert_eq!(
            range(&p, "effects.valve_dynamics.time_constant"),
            Some((0.0, 0.0, 0.02))
        );
        let (z, lo, hi) = range(&p, "effects.valve_deadband.zero_offset").unwrap();
        assert!((z - 0.01).abs() < 1e-15 && (lo + 0.04).abs() < 1e-12 && (hi - 0.06).abs() < 1e-12);
        assert_eq!(
            range(&p, "effects.valve_deadband.overlap"),
            Some((0.0, 0.0, 0.05))
        );
        for (sections, key, needle) in [
            (
                "[effects.valve_dynamics]\norder = 2\nnatural_frequency = 600.0\ndamping_ratio = 0.7\n",
                "effects.valve_dynamics.time_constant",
                "its bandwidth is effects.valve_dynamics.natural_frequency",
            ),
            (
                "[effects.time_delay]\nenabled = false\ndelay = 0.0\n",
                "effects.time_delay.delay",
                "enabled = false",
            ),
        ] {
            let text = format!(
                "{}\n{sections}\n[uncertainty]\n\"{key}\" = 0.01\n",
                ehactl_ident_eval::synth::TESTRIG_TOML
            );
            let e = ehactl_config::RigConfig::from_toml_str(&text)
                .map(|_| ())
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle) && e.contains(key), "{key}: {e}");
            assert!(!e.contains('\n'), "one line: {e}");
        }
    }

    #[test]
    fn bad_uncertainty_is_refused_with_the_key_named() {
        for (table, needle) in [
            (
                "\"valve.rated_flw\" = \"10%\"",
                "uncertainty.\"valve.rated_flw\"",
            ),
            ("\"valve.area_max\" = \"10%\"", "flow_form"),
            (
                "\"mechanics.mass\" = \"ten percent\"",
                "expected a percentage",
            ),
            ("\"mechanics.mass\" = \"150%\"", "expected a percentage"),
            ("\"mechanics.mass\" = 40.0", "reaches 0"),
            ("\"mechanics.mass\" = -1.0", "≥ 0"),
            // A loop key needs its effect section with the assumed nominal value.
            (
                "\"effects.time_delay.delay\" = 0.01",
                "no [effects.time_delay] section",
            ),
        ] {
            let e = with(table).expect_err(table);
            assert!(e.contains(needle), "{table}: {e}");
            assert!(!e.contains('\n'), "one line: {e}");
        }
    }
}

/// A `lugre` friction without its bristle spring, and a `hose` fitting resistance with the
/// unsteady wall friction, are refused by the plant naming the parameter and the unit.
#[test]
fn lugre_without_bristles_and_hose_resistance_with_unsteady_friction_are_refused() {
    let mut p = blocked_cylinder(10.0, 100.0, 0.05);
    p.effects.friction = Some(Friction {
        enabled: true,
        variant: FrictionVariant::Lugre,
        static_force: 120.0,
        coulomb_force: 100.0,
        stribeck_velocity: 0.01,
        viscous: 0.0,
        bristle_stiffness: 0.0,
        bristle_damping: 0.0,
    });
    let e = Plant::configure(&p, 1e-3).unwrap_err();
    assert_eq!(e.path, "effects.friction", "{e}");
    assert!(e.message.contains("bristle_stiffness > 0 N/m"), "{e}");
    p.effects.friction.as_mut().unwrap().bristle_stiffness = 1e7;
    assert!(Plant::configure(&p, 1e-3).is_ok());
    p.effects.line_dynamics = Some(LineDynamics {
        enabled: true,
        variant: LineVariant::Hose,
        length: 2.0,
        diameter: 0.01,
        segments: 2,
        bulk_modulus: None,
        port_volume: 0.0,
        friction: LineFriction::Unsteady,
        wall_compliance: 1e-9,
        resistance: 1e9,
    });
    let e = Plant::configure(&p, 1e-3).unwrap_err();
    assert_eq!(e.path, "effects.line_dynamics.resistance", "{e}");
    p.effects.line_dynamics.as_mut().unwrap().friction = LineFriction::Steady;
    assert!(Plant::configure(&p, 1e-3).is_ok());
}

/// A transport delay between two substep boundaries delays the command by that fraction of a
/// substep (the valve sees the mean of the delayed command over each substep): the travel
/// after a step command falls steadily as the delay grows by quarter substeps. With the
/// command taken at the substep's start it stepped once per substep and stood still between
/// (a delay fit on a closed-loop record could not resolve it below a substep).
#[test]
fn a_delay_between_substeps_is_a_fractional_delay() {
    let mut p = ehactl_ident_eval::synth::testrig().plant;
    p.integration.substeps = 4;
    let dt = 1e-3;
    let h = dt / 4.0;
    let travel = |delay: f64| {
        let mut q = p.clone();
        q.effects.time_delay = Some(TimeDelay {
            enabled: true,
            delay,
        });
        let mut plant = Plant::configure(&q, dt).unwrap();
        let x0 = plant.state().x;
        for _ in 0..5 {
            plant.step(3.0).unwrap();
        }
        plant.state().x - x0
    };
    let x: Vec<f64> = (0..=8).map(|j| travel(2e-3 + j as f64 * h / 4.0)).collect();
    let steps: Vec<f64> = x.windows(2).map(|w| w[0] - w[1]).collect();
    assert!(steps.iter().all(|s| *s > 0.0), "travel {x:?}");
    let (lo, hi) = steps
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(a, b), s| (a.min(*s), b.max(*s)));
    assert!(hi < 3.0 * lo, "uneven steps {steps:?}");
}
