//! Property test: for randomised valid configs (every effect on or off, parameters across
//! realistic ranges, random commands) the plant never produces a non-finite state.

use ehactl_plant::params::*;
use ehactl_plant::Plant;
use ehactl_tests::blocked_cylinder;
use proptest::prelude::*;

fn arb_params() -> impl Strategy<Value = (PlantParams, Vec<f64>)> {
    (
        (
            1e8f64..2.2e9,
            1e6f64..35e6,
            1e-5f64..5e-3,
            0.3f64..1.0,
            1e-7f64..1e-3,
            0.01f64..2.0,
        ),
        (
            0.05f64..500.0,
            0.0f64..5e4,
            prop::bool::ANY,
            0.0f64..5e8,
            0.0f64..0.4,
            1e-6f64..1e-2,
        ),
        (
            prop::bool::ANY,
            prop::bool::ANY,
            prop::bool::ANY,
            prop::bool::ANY,
            prop::bool::ANY,
            prop::bool::ANY,
        ),
        (
            prop::bool::ANY,
            prop::bool::ANY,
            prop::bool::ANY,
            prop::bool::ANY,
            prop::bool::ANY,
            1u32..8,
        ),
        (1u8..=2, 50.0f64..3000.0, 0.2f64..1.5, 0.0f64..1.0),
        prop::collection::vec(-12.0f64..12.0, 8),
    )
        .prop_map(|(a, b, c, d, e, cmds)| {
            let (beta, ps, area, ratio, dead, stroke) = a;
            let (mass, damping, load, k_load, underlap, rated) = b;
            let (fric, dband, sat, leak_i, leak_e, bmp) = c;
            let (lines, mount, delay, tone, sdrop, nseg) = d;
            let (order, wn, zeta, pos) = e;
            let mut p = blocked_cylinder(mass, damping, pos * stroke);
            p.fluid.bulk_modulus = beta;
            p.supply.pressure = ps;
            p.cylinder.area_a = area;
            p.cylinder.area_b = area * ratio;
            p.cylinder.dead_volume_a = dead;
            p.cylinder.dead_volume_b = dead;
            p.cylinder.stroke = stroke;
            p.valve.underlap = underlap;
            p.valve.rated_flow = Some(rated);
            if load {
                p.mechanics.load_stiffness = k_load;
                p.mechanics.load_contact_position = pos * stroke;
            }
            // The structural effect variants on the odd segment counts (friction: by nseg mod 3).
            let alt = nseg % 2 == 1;
            p.effects.friction = fric.then_some(Friction {
                enabled: true,
                variant: match nseg % 3 {
                    0 => FrictionVariant::Stribeck,
                    1 => FrictionVariant::LoadCoulomb,
                    _ => FrictionVariant::Lugre,
                },
                static_force: 200.0,
                coulomb_force: 150.0,
                stribeck_velocity: 0.01,
                viscous: 10.0,
                bristle_stiffness: 1e7,
                bristle_damping: 2e4,
            });
            p.effects.valve_deadband = dband.then_some(ValveDeadband {
                enabled: true,
                variant: if alt {
                    DeadbandVariant::Amplifier
                } else {
                    DeadbandVariant::Overlap
                },
                deadzone: 0.05,
                overlap: 0.05,
                zero_offset: 0.01,
            });
            p.effects.valve_saturation = sat.then_some(ValveSaturation {
                enabled: true,
                variant: if alt {
                    SaturationVariant::Asymmetric
                } else {
                    SaturationVariant::Symmetric
                },
                spool_limit_negative: 0.6,
                spool_limit: 0.8,
                max_flow: rated * 0.5,
            });
            p.effects.valve_dynamics = Some(ValveDynamics {
                enabled: true,
                order,
                time_constant: 1.0 / wn,
                natural_frequency: wn,
                damping_ratio: zeta,
            });
            p.effects.internal_leakage = leak_i.then_some(Leakage {
                enabled: true,
                variant: LeakageVariant::Equal,
                coefficient_b: 0.0,
                coefficient: 1e-11,
            });
            p.effects.external_leakage = leak_e.then_some(Leakage {
                enabled: true,
                variant: if alt {
                    LeakageVariant::PerChamber
                } else {
                    LeakageVariant::Equal
                },
                coefficient_b: 3e-12,
                coefficient: 1e-12,
            });
            p.effects.bulk_modulus_pressure = bmp.then_some(BulkModulusPressure {
                enabled: true,
                variant: if alt {
                    BulkVariant::EntrainedAir
                } else {
                    BulkVariant::Linear
                },
                air_fraction: 0.02,
                polytropic_index: 1.4,
                slope: 10.0,
                max: 2.2e9,
            });
            p.effects.line_dynamics = lines.then_some(LineDynamics {
                enabled: true,
                length: 1.0,
                diameter: 0.01,
                segments: nseg,
                bulk_modulus: Some(1.2e9),
                port_volume: 0.0,
                // A compliant hose with a fitting resistance on the steady (odd) counts.
                variant: if alt {
                    LineVariant::Hose
                } else {
                    LineVariant::Pipe
                },
                wall_compliance: 1e-9,
                resistance: 1e9,
                // Both wall-friction models (the unsteady one adds convolution states).
                friction: if nseg % 2 == 0 {
                    LineFriction::Unsteady
                } else {
                    LineFriction::Steady
                },
            });
            p.effects.flexible_mount = mount.then_some(FlexibleMount {
                enabled: true,
                variant: if alt {
                    MountVariant::PistonSide
                } else {
                    MountVariant::LoadSide
                },
                load_mass: 100.0,
                stiffness: 5e4,
                damping: 1e4,
            });
            p.effects.time_delay = delay.then_some(TimeDelay {
                enabled: true,
                delay: 0.0013,
            });
            p.effects.sensor_tone = tone.then(|| SensorTone {
                enabled: true,
                channel: SensorChannel::Force,
                frequencies: vec![225.0],
                amplitudes: vec![1.0],
                phases: vec![1.3],
            });
            p.effects.supply_pressure_drop = sdrop.then_some(SupplyPressureDrop {
                enabled: true,
                variant: if alt {
                    SupplyVariant::PumpLimit
                } else {
                    SupplyVariant::Resistance
                },
                max_flow: rated,
                regulation_band: 1.0e6,
                volume: 5e-4,
                resistance: 1e10,
                time_constant: 0.01,
            });
            p.excitation = Excitation {
                kind: ExcitationKind::Harmonic,
                offset: 100.0,
                amplitude: 500.0,
                frequency: 20.0,
                ..Default::default()
            };
            p.sensors.force.noise = 1.0;
            // Both line schemes, decorrelated from the friction model.
            p.integration.line_method = if nseg % 3 == 0 {
                LineMethod::Implicit
            } else {
                LineMethod::Symplectic
            };
            (p, cmds)
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, .. ProptestConfig::default() })]
    #[test]
    fn never_nan((params, cmds) in arb_params()) {
        let mut plant = Plant::configure(&params, 2e-4).unwrap();
        for (i, u) in cmds.iter().enumerate() {
            for _ in 0..(60 + 10 * i) {
                plant.step(*u).unwrap();
                let s = plant.state();
                prop_assert!(s.p_a.is_finite() && s.p_b.is_finite() && s.x.is_finite() && s.v.is_finite());
                prop_assert!(s.p_a >= params.fluid.cavitation_pressure && s.p_b >= params.fluid.cavitation_pressure);
                let m = plant.measure();
                prop_assert!(m.force.is_finite() && m.position.is_finite());
            }
        }
    }
}
