//! Sirohi 2003 (Sirohi & Chopra) reproduction: the transfer-matrix model of the piezohydraulic
//! circuit (eq. 1–22, dissipative lines eq. 6–12) against the paper's trends, and the plant's
//! lumped R-L-C line (002 eq. 9–17) against the transfer matrix as the segments grow.
//!
//! Run: `cargo test --release -p ehactl-tests --test repro_001 -- --nocapture` (prints the
//! figures quoted in REPRODUCTION.md, "Sirohi 2003").

use ehactl_analysis::linear::{self, Output};
use ehactl_analysis::oppoint;
use ehactl_analysis::tline::{
    first_peak, Chamber, Circuit, Friction, LineSection, OutputCylinder, PiezoPump, Source, INCH,
    SIROHI_TUBE_ID,
};
use ehactl_config::RigConfig;
use ehactl_plant::params::LineFriction;
use ehactl_tests::config;
use std::f64::consts::PI;

const TUBES_IN: [f64; 3] = [0.0, 4.5, 11.5];
const CST: f64 = 1e-6;

/// First resonance of the paper's circuit, output displacement per stack volt (001 fig. 8–10).
fn paper_peak(tube_in: f64, nu: f64) -> (f64, f64) {
    let (f, g, _) = paper_peak_pc(tube_in, nu);
    (f, g)
}

/// As [`paper_peak`], plus the pumping-chamber pressure amplitude there (Pa per V).
fn paper_peak_pc(tube_in: f64, nu: f64) -> (f64, f64, f64) {
    let c = Circuit::sirohi2003(tube_in * INCH, nu);
    let static_gain = c.response(1.0).displacement.norm();
    let p = first_peak(|f| c.response(f).displacement.norm(), 20.0, 5000.0, 400)
        .expect("a resonance below 5 kHz");
    let pc = c.response(p.f_hz).source_pressure.norm();
    (p.f_hz, p.gain / static_gain, pc)
}

/// The transfer-matrix model of exactly the circuit the plant config realises.
fn plant_circuit(cfg: &RigConfig, friction: Friction) -> Circuit {
    let p = &cfg.plant;
    let line = p.effects.line_dynamics.as_ref().expect("config has lines");
    let x = p.cylinder.initial_position;
    let beta = p.fluid.bulk_modulus;
    Circuit {
        fluid: ehactl_analysis::tline::Fluid {
            density: p.fluid.density,
            bulk_modulus: beta,
            kinematic_viscosity: p.fluid.kinematic_viscosity,
        },
        friction,
        source: Source::Flow {
            port_volume: line.port_volume,
        },
        tube: LineSection::tube(line.length, line.diameter),
        cylinder: OutputCylinder {
            area: p.cylinder.area_a,
            high_chamber: Chamber::Volume(p.cylinder.dead_volume_a + p.cylinder.area_a * x),
            low_chamber: Chamber::Volume(0.0),
            mass: p.mechanics.mass,
            damping: p.mechanics.damping,
            stiffness: p.mechanics.load_stiffness,
        },
        accumulator: (p.cylinder.dead_volume_b + p.cylinder.area_b * (p.cylinder.stroke - x))
            / beta,
    }
}

/// First resonance of a flow-driven circuit: piston velocity per source flow.
fn flow_peak(c: &Circuit, lo: f64, hi: f64) -> f64 {
    first_peak(|f| c.response(f).velocity().norm(), lo, hi, 300)
        .expect("a resonance in the band")
        .f_hz
}

/// First resonance of the linearised plant (continuous time): piston velocity per volt;
/// frequency (Hz) and peak gain over the gain at 20 Hz.
fn plant_peak(cfg: &RigConfig, segments: u32, lo: f64, hi: f64) -> (f64, f64) {
    let mut cfg = cfg.clone();
    cfg.plant
        .effects
        .line_dynamics
        .as_mut()
        .expect("config has lines")
        .segments = segments;
    let op = oppoint::find(&cfg, 0.05).expect("operating point");
    let m = linear::continuous(&op, 1e-8).expect("linearisation");
    let gain = |f: f64| (m.response(Output::Position, f) * (2.0 * PI * f)).norm();
    let p = first_peak(gain, lo, hi, 60).unwrap_or_else(|| {
        panic!("no plant resonance in [{lo}, {hi}] Hz with {segments} segments")
    });
    (p.f_hz, p.gain / gain(20.0))
}

fn circuit_config(tube_in: f64) -> RigConfig {
    let mut cfg = config("sirohi2003_circuit.toml");
    cfg.plant.effects.line_dynamics.as_mut().unwrap().length = tube_in * INCH;
    cfg
}

/// The circuit config with the line's wall-friction model replaced.
fn with_friction(cfg: &RigConfig, friction: LineFriction) -> RigConfig {
    let mut cfg = cfg.clone();
    cfg.plant.effects.line_dynamics.as_mut().unwrap().friction = friction;
    cfg
}

#[test]
fn config_matches_the_paper_dimensions() {
    let cfg = config("sirohi2003_circuit.toml");
    let p = &cfg.plant;
    let pump = PiezoPump::sirohi2003();
    let out = OutputCylinder::sirohi2003();
    let fl = ehactl_analysis::tline::Fluid::sirohi2003(2.0 * CST);
    let line = p.effects.line_dynamics.as_ref().unwrap();
    let rel = |a: f64, b: f64| (a / b - 1.0).abs();
    assert!(rel(line.port_volume, pump.equivalent_volume(&fl)) < 1e-4);
    assert!(rel(line.diameter, SIROHI_TUBE_ID) < 1e-4);
    assert!(rel(p.cylinder.area_a, out.area) < 1e-4);
    assert!(rel(p.fluid.bulk_modulus, fl.bulk_modulus) < 1e-4);
    // Moving mass = 001's piston and shaft + the oil of both chambers (their line inertance).
    let oil = 2.0 * fl.density * out.area * INCH;
    assert!(rel(p.mechanics.mass, out.mass + oil) < 1e-4);
}

#[test]
fn first_resonance_falls_as_the_tube_grows() {
    let f: Vec<(f64, f64)> = TUBES_IN.iter().map(|&l| paper_peak(l, 2.0 * CST)).collect();
    for &l in &TUBES_IN {
        let (fr, g, pc) = paper_peak_pc(l, 2.0 * CST);
        println!(
            "001 TM, 2 cSt, tube {l:>4} in: first resonance {fr:7.1} Hz, peak/static {:5.1} dB, \
             P_c there {:8.1} psi/V",
            20.0 * g.log10(),
            pc / ehactl_analysis::tline::PSI
        );
    }
    for w in f.windows(2) {
        assert!(
            w[1].0 < 0.9 * w[0].0,
            "resonance must fall with length: {f:?}"
        );
    }
}

#[test]
fn resonant_peak_drops_as_viscosity_grows() {
    let nus = [2.0, 20.0, 200.0];
    let f: Vec<(f64, f64)> = nus.iter().map(|&n| paper_peak(4.5, n * CST)).collect();
    for (n, (fr, g)) in nus.iter().zip(&f) {
        println!(
            "001 TM, tube 4.5 in, {n:>5} cSt: first resonance {fr:7.1} Hz, peak/static {:5.1} dB",
            20.0 * g.log10()
        );
    }
    // Sensitivity to the output damping b_o, which 001 does not give (printed only): seal
    // damping caps the low-viscosity peak and shrinks the 2 → 20 cSt step.
    for b_o in [0.0, 5.0, 20.0] {
        let db: Vec<String> = nus
            .iter()
            .map(|&n| {
                let mut c = Circuit::sirohi2003(4.5 * INCH, n * CST);
                c.cylinder.damping = b_o;
                let s = c.response(1.0).displacement.norm();
                let p = first_peak(|f| c.response(f).displacement.norm(), 20.0, 5000.0, 400)
                    .expect("peak");
                format!("{:.1} dB", 20.0 * (p.gain / s).log10())
            })
            .collect();
        println!(
            "  with b_o = {b_o:>4} N·s/m: peaks at 2/20/200 cSt {}",
            db.join(" / ")
        );
    }
    for w in f.windows(2) {
        assert!(w[1].1 < w[0].1, "peak must drop with viscosity: {f:?}");
        // Viscous damping also lowers the damped resonance a little (001 fig. 9).
        assert!(w[1].0 <= w[0].0, "{f:?}");
    }
}

#[test]
fn lumped_line_converges_to_the_transfer_matrix() {
    let segments = [1u32, 2, 4, 8, 16, 32, 64];
    for tube in [4.5, 11.5] {
        // Steady Hagen–Poiseuille friction (the plant's default), kept for comparison with
        // the unsteady model that sirohi2003_circuit.toml uses (next test).
        let cfg = with_friction(&circuit_config(tube), LineFriction::Steady);
        let (f_paper, _) = paper_peak(tube, 2.0 * CST);
        // The same circuit in the transfer-matrix model: with the plant's own (steady
        // Hagen–Poiseuille) friction, and with 001's dissipative model.
        let f_lin = flow_peak(&plant_circuit(&cfg, Friction::Linear), 20.0, 5000.0);
        let f_dis = flow_peak(&plant_circuit(&cfg, Friction::Dissipative), 20.0, 5000.0);
        // Without the port volume the plant could not hold the pump's compliance: how far off
        // that circuit would be (TM, same dissipative lines).
        let mut no_port = plant_circuit(&cfg, Friction::Dissipative);
        no_port.source = Source::Flow { port_volume: 0.0 };
        let f_no_port = flow_peak(&no_port, 20.0, 5000.0);
        println!("  without port_volume the first resonance would be {f_no_port:.1} Hz");
        assert!(f_no_port > 1.5 * f_paper, "{f_no_port}");
        // The plant's circuit is 001's circuit: the two TMs agree within 0.2 %.
        assert!(
            (f_dis / f_paper - 1.0).abs() < 0.002,
            "{f_dis} vs {f_paper}"
        );
        let (lo, hi) = (0.6 * f_paper, 1.6 * f_paper);
        let peaks: Vec<(f64, f64)> = segments
            .iter()
            .map(|&n| plant_peak(&cfg, n, lo, hi))
            .collect();
        let f_plant: Vec<f64> = peaks.iter().map(|p| p.0).collect();
        // 001's model normalised the same way (gain at the peak over the gain at 20 Hz).
        let c = Circuit::sirohi2003(tube * INCH, 2.0 * CST);
        let tm_peak_db = 20.0
            * (c.response(f_paper).displacement.norm() / c.response(20.0).displacement.norm())
                .log10();
        println!(
            "001 tube {tube} in: TM paper circuit {f_paper:.1} Hz, TM plant circuit \
             dissipative {f_dis:.1} Hz, linear friction {f_lin:.1} Hz"
        );
        println!("  001 TM peak {tm_peak_db:.1} dB over the 20 Hz gain");
        for (n, (f, g)) in segments.iter().zip(&peaks) {
            println!(
                "  plant {n:>3} segments: {f:7.1} Hz  ({:+.2} % vs TM paper, {:+.2} % vs TM \
                 same friction), peak {:.1} dB",
                100.0 * (f / f_paper - 1.0),
                100.0 * (f / f_lin - 1.0),
                20.0 * g.log10()
            );
        }
        // Steady (DC) friction underestimates the viscous loss at the resonance, where the
        // boundary layer is thin: the lumped line's peak must stand above 001's.
        let plant_peak_db = 20.0 * peaks.last().unwrap().1.log10();
        assert!(
            plant_peak_db > tm_peak_db + 3.0,
            "{plant_peak_db} vs {tm_peak_db}"
        );
        // 1. Discretisation converges to the distributed line of the same physics.
        let last = *f_plant.last().unwrap();
        assert!((last / f_lin - 1.0).abs() < 0.005, "{last} vs {f_lin}");
        let d_late = (f_plant[6] - f_plant[5]).abs();
        let d_early = (f_plant[3] - f_plant[2]).abs();
        assert!(d_late < 0.25 * d_early, "{f_plant:?}");
        // 2. Segments needed: from which count on every finer line stays within `tol` of
        // `reference`.
        let needed = |reference: f64, tol: f64| {
            let ok: Vec<bool> = f_plant
                .iter()
                .map(|f| (f / reference - 1.0).abs() <= tol)
                .collect();
            (0..segments.len())
                .find(|&i| ok[i..].iter().all(|&w| w))
                .map(|i| segments[i])
        };
        let (n_same_2, n_same_1) = (needed(f_lin, 0.02), needed(f_lin, 0.01));
        let n_paper_2 = needed(f_paper, 0.02);
        println!(
            "  segments needed: within 2 % / 1 % of the same-friction TM {n_same_2:?} / \
             {n_same_1:?}; within 2 % of 001's TM {n_paper_2:?}"
        );
        assert!(n_same_1.is_some_and(|n| n <= 8), "{f_plant:?}");
        // 3. Against 001's transfer matrix (dissipative lines, eq. 6–12): the steady-friction
        // lumped line cannot carry the frequency-dependent viscous inertance, so its limit
        // differs from 001's resonance by exactly the two transfer matrices' difference.
        let model_gap = f_lin / f_paper - 1.0;
        assert!(
            ((last / f_paper - 1.0) - model_gap).abs() < 0.005,
            "residual {} vs model gap {}",
            last / f_paper - 1.0,
            model_gap
        );
        println!(
            "  converged plant line vs 001 TM {:+.2} %; steady vs dissipative friction TM gap \
             {:+.2} %",
            100.0 * (last / f_paper - 1.0),
            100.0 * model_gap
        );
        if tube == 4.5 {
            // The 2 % bar holds for the 4.5 in tube (001 fig. 9's case) at every count.
            assert_eq!(n_paper_2, Some(1), "{f_plant:?}");
        } else {
            // ... and not for the 11.5 in tube: the friction-model gap exceeds 2 % (reported).
            assert!(model_gap > 0.02, "{model_gap}");
        }
    }
}

#[test]
fn unsteady_lumped_line_converges_to_the_transfer_matrix() {
    // The 2 % bar: the plant's lumped line converges to 001's transfer-matrix first
    // resonance within 2 % as the segments grow, here with frequency-dependent friction.
    let segments = [1u32, 2, 4, 8, 16, 32];
    for tube in [4.5, 11.5] {
        let cfg = circuit_config(tube);
        let friction = cfg.plant.effects.line_dynamics.as_ref().unwrap().friction;
        assert_eq!(
            friction,
            LineFriction::Unsteady,
            "001 circuit config: unsteady friction"
        );
        let (f_paper, _) = paper_peak(tube, 2.0 * CST);
        // The same circuit with the exact Bessel B_r instead of Woods' approximation.
        let f_bessel = flow_peak(&plant_circuit(&cfg, Friction::Bessel), 20.0, 5000.0);
        let (lo, hi) = (0.6 * f_paper, 1.6 * f_paper);
        let c = Circuit::sirohi2003(tube * INCH, 2.0 * CST);
        let tm_peak_db = 20.0
            * (c.response(f_paper).displacement.norm() / c.response(20.0).displacement.norm())
                .log10();
        println!(
            "001 tube {tube} in, unsteady friction: TM paper (Woods) {f_paper:.1} Hz, TM exact \
             Bessel {f_bessel:.1} Hz, TM peak {tm_peak_db:.1} dB"
        );
        let peaks: Vec<(f64, f64)> = segments
            .iter()
            .map(|&n| plant_peak(&cfg, n, lo, hi))
            .collect();
        for (n, (f, g)) in segments.iter().zip(&peaks) {
            println!(
                "  plant {n:>3} segments: {f:7.1} Hz  ({:+.2} % vs TM paper, {:+.2} % vs TM \
                 Bessel), peak {:.1} dB",
                100.0 * (f / f_paper - 1.0),
                100.0 * (f / f_bessel - 1.0),
                20.0 * g.log10()
            );
        }
        let f_plant: Vec<f64> = peaks.iter().map(|p| p.0).collect();
        let last = *f_plant.last().unwrap();
        // 1. Discretisation converges (differences shrink) towards the distributed line of
        // the same physics (exact Bessel TM), and the limit is 001's resonance within 2 %.
        let d_late = (f_plant[5] - f_plant[4]).abs();
        let d_early = (f_plant[2] - f_plant[1]).abs();
        assert!(d_late < 0.25 * d_early, "{f_plant:?}");
        assert!(
            (last / f_bessel - 1.0).abs() < 0.005,
            "{last} vs {f_bessel}"
        );
        assert!((last / f_paper - 1.0).abs() < 0.02, "{last} vs {f_paper}");
        // 2. Segments needed: from which count on every finer line stays within 2 % of 001's TM.
        let n_needed = (0..segments.len())
            .find(|&i| {
                f_plant[i..]
                    .iter()
                    .all(|f| (f / f_paper - 1.0).abs() <= 0.02)
            })
            .map(|i| segments[i]);
        println!("  segments needed within 2 % of 001's TM: {n_needed:?}");
        assert!(n_needed.is_some_and(|n| n <= 8), "{f_plant:?}");
        // 3. The resonance is damped like 001's (steady friction: 15–17 dB too high).
        let plant_db = 20.0 * peaks.last().unwrap().1.log10();
        assert!(
            (plant_db - tm_peak_db).abs() < 1.5,
            "{plant_db} vs {tm_peak_db}"
        );
        // Trikha's three-term fit, for comparison (printed only).
        let trikha = with_friction(&cfg, LineFriction::UnsteadyTrikha);
        let (t_f, t_g) = plant_peak(&trikha, 32, lo, hi);
        println!(
            "  plant  32 segments, Trikha 3 terms: {t_f:7.1} Hz ({:+.2} % vs TM paper), peak \
             {:.1} dB",
            100.0 * (t_f / f_paper - 1.0),
            20.0 * t_g.log10()
        );
    }
}

#[test]
fn unsteady_lumped_line_follows_viscosity() {
    // 001 fig. 9's viscosity sweep with the plant's unsteady line (16 segments) against the
    // TM of the same circuit with the exact Bessel B_r, and against Woods' B_r (001 eq. 12).
    for tube in [4.5, 11.5] {
        for nu_cst in [2.0, 20.0, 200.0] {
            let mut cfg = circuit_config(tube);
            cfg.plant.fluid.kinematic_viscosity = nu_cst * CST;
            let velocity_peak = |friction: Friction| {
                let c = plant_circuit(&cfg, friction);
                let g = |f: f64| c.response(f).velocity().norm();
                let p = first_peak(g, 20.0, 5000.0, 300).expect("a TM resonance");
                (p.f_hz, 20.0 * (p.gain / g(20.0)).log10())
            };
            let (f_b, db_b) = velocity_peak(Friction::Bessel);
            let (f_w, db_w) = velocity_peak(Friction::Dissipative);
            let (f, g) = plant_peak(&cfg, 16, 0.6 * f_b, 1.6 * f_b);
            let db = 20.0 * g.log10();
            println!(
                "tube {tube:>4} in {nu_cst:>5} cSt: plant 16 seg {f:6.1} Hz {db:5.1} dB | TM \
                 Bessel {f_b:6.1} Hz {db_b:5.1} dB ({:+.2} %) | TM Woods {f_w:6.1} Hz {db_w:5.1} \
                 dB ({:+.2} %)",
                100.0 * (f / f_b - 1.0),
                100.0 * (f / f_w - 1.0)
            );
            // Same physics: only the first-order discretisation error of 16 segments
            // (−0.2 … −0.4 % at 2 cSt, previous test) separates the two.
            assert!((f / f_b - 1.0).abs() < 0.01, "{f} vs {f_b}");
            assert!((db - db_b).abs() < 0.5, "{db} vs {db_b}");
            if nu_cst == 200.0 {
                // Woods' B_r (001 eq. 12) is exact only at both ends of ω/ω_v; at 200 cSt the
                // resonance sits at ω/ω_v ≈ 1–3, where it moves the TM's peak by > 2 %.
                assert!((f_b / f_w - 1.0).abs() > 0.02, "{f_b} vs {f_w}");
            }
        }
    }
}
