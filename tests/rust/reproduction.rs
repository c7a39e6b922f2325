//! The seed papers' published numbers (REPRODUCTION.md). Each test prints the
//! figures it measured; REPRODUCTION.md tabulates them with their status (reproduced,
//! calibrated, missed, or no paper number).
//!
//! Tolerances: half a unit of the paper's last printed digit plus the model difference that
//! REPRODUCTION.md documents for that row. A paper number ehactl misses is asserted at ehactl's
//! measured value (within its numerical resolution) together with the size of the miss, so a
//! change that closes or widens the gap fails here and the document must follow.

use ehactl_analysis::analyze::{analyze, natural_frequency};
use ehactl_analysis::sdd::implied_mount;
use ehactl_analysis::sweep::{sweep, Channel, SweepOptions};
use ehactl_plant::Plant;
use ehactl_runtime::session::{run_sim, SessionOptions};
use ehactl_tests::config;

fn within(v: f64, target: f64, rel: f64) -> bool {
    (v - target).abs() <= rel * target.abs()
}

/// 004 §6.1, from the linearisation (continuous: the paper's analysis; sampled: the 5 kHz
/// loop with zero-order hold). Status per REPRODUCTION.md: PM calibrated (K_Ct/K_Qv refit to
/// eq. 17), the crossovers and the gain margin missed.
#[test]
fn seed004_margins_of_the_sampled_loop() {
    let a = analyze(&config("sahu2022_force.toml")).expect("analyze");
    let d = a.discrete.as_ref().expect("closed loop");
    let c = a.continuous.as_ref().expect("closed loop");
    println!(
        "004 sampled: gc {:?} Hz PM {:?}° pc {:?} Hz GM {:?} dB BW {:?} Hz; continuous: gc {:?} PM {:?} pc {:?} GM {:?} BW {:?}; open-loop BW {:?} Hz",
        d.gain_crossover_hz, d.phase_margin_deg, d.phase_crossover_hz, d.gain_margin_db,
        d.closed_loop_bandwidth_hz, c.gain_crossover_hz, c.phase_margin_deg,
        c.phase_crossover_hz, c.gain_margin_db, c.closed_loop_bandwidth_hz, a.open_loop_bandwidth_hz
    );
    let pm_c = c.phase_margin_deg.expect("continuous PM");
    let pm = d.phase_margin_deg.expect("phase margin");
    let gc_c = c.gain_crossover_hz.expect("continuous gain crossover");
    let gc = d.gain_crossover_hz.expect("gain crossover");
    let pc_c = c.phase_crossover_hz.expect("continuous phase crossover");
    let gm_c = c.gain_margin_db.expect("continuous gain margin");
    let gm = d.gain_margin_db.expect("gain margin");
    // PM, paper "60°": ±0.5° (its last digit) + 0.3° (the refit's residual against eq. 17,
    // 0.24°, and eq. 17's own 60.3°): calibrated, and met.
    assert!(
        (pm_c - 60.0).abs() <= 0.8,
        "continuous phase margin {pm_c}°"
    );
    // Sample and hold cost at most ωT/2 at the crossover (3.5° at 96 Hz, 5 kHz).
    let zoh = 180.0 * gc * 2e-4; // deg: ω·T/2 = 2π·f·T/2
    assert!(
        pm < pm_c && pm_c - pm <= zoh,
        "sampled {pm}° vs continuous {pm_c}° (ωT/2 {zoh}°)"
    );
    // |L| = 1 crossover, paper 99.63 Hz: MISSED. ehactl 93.4 Hz continuous (−6.3 %), 95.9 Hz
    // sampled (since 2026-11-26 the sampled figures are now those of the converged plant map; the
    // 8-substep exponential-Euler map gave 96.07 Hz, 58.05°, 227.3 Hz, 8.84 dB, 209.2 Hz); the plant's slow pole sits 9 % below eq. 17's 66 Hz. Asserted at the measured
    // values (grid resolution 0.3 %) and as a miss of more than 5 %.
    assert!(
        (gc_c - 93.37).abs() <= 0.3,
        "continuous gain crossover {gc_c} Hz"
    );
    assert!((gc - 95.92).abs() <= 0.3, "sampled gain crossover {gc} Hz");
    assert!(gc_c < 0.95 * 99.63, "the −6 % miss closed? {gc_c} Hz");
    // ∠L = −180° crossover, paper 262.6 Hz: MISSED (eq. 17 with Table 1 gives 241.8 Hz).
    assert!(
        (pc_c - 238.08).abs() <= 0.8,
        "continuous phase crossover {pc_c} Hz"
    );
    assert!(pc_c < 0.95 * 262.6);
    // Gain margin, paper 10.8 dB: MISSED (eq. 17 with Table 1 gives 9.25 dB). ehactl 9.90 dB
    // continuous, 8.39 dB sampled, within ±0.05 dB (the paper's own precision).
    assert!(
        (gm_c - 9.90).abs() <= 0.05,
        "continuous gain margin {gm_c} dB"
    );
    assert!((gm - 8.39).abs() <= 0.05, "sampled gain margin {gm} dB");
    assert!(10.8 - gm_c > 0.5, "the gain-margin miss closed? {gm_c} dB");
    // Closed-loop bandwidth from the sampled linearisation, paper "≈ 200 Hz" (one digit:
    // 150–250 Hz); ehactl 209.5 Hz pinned to the grid resolution.
    let bw = d.closed_loop_bandwidth_hz.expect("bandwidth");
    assert!(
        (150.0..=250.0).contains(&bw),
        "closed-loop bandwidth {bw} Hz"
    );
    assert!((bw - 209.5).abs() <= 1.0, "closed-loop bandwidth {bw} Hz");
}

/// 004 §6.2: 785 N static + ±196 N swept on the nonlinear plant, closed loop: −3 dB
/// bandwidth, paper "≈ 200 Hz" (one printed digit: 150–250 Hz), CALIBRATED (follows from the
/// K_Ct/K_Qv refit); ehactl's 208.3 Hz pinned within ±2 Hz (interpolation between 16 points);
/// and the measured points agree with the linearisation.
#[test]
fn seed004_closed_loop_bandwidth_from_a_sweep_of_the_nonlinear_plant() {
    let cfg = config("sahu2022_force.toml");
    let r = sweep(
        &cfg,
        SweepOptions {
            from_hz: Some(1.0),
            to_hz: Some(300.0),
            points: 16,
            ..Default::default()
        },
    )
    .expect("sweep");
    for p in &r.points {
        println!(
            "004 sweep {:8.2} Hz {:8.3} dB {:8.2}° γ² {:.4} distortion {:.4}",
            p.f_hz, p.mag_db, p.phase_deg, p.coherence, p.distortion
        );
    }
    let bw = r.bandwidth_hz.expect("bandwidth reached");
    println!("004 sweep closed-loop bandwidth {bw:.2} Hz");
    assert!(r.complete && r.points.len() == 16);
    assert!((150.0..=250.0).contains(&bw), "bandwidth {bw} Hz");
    assert!((bw - 208.3).abs() <= 2.0, "bandwidth {bw} Hz");
    assert!(r.points.iter().all(|p| p.coherence > 0.99));
    // Small-signal consistency: the nonlinear sweep matches the linearised sampled loop.
    let a = analyze(&cfg).expect("analyze");
    for p in r.points.iter().filter(|p| p.f_hz < 250.0) {
        let lin = a
            .loop_response
            .iter()
            .min_by(|x, y| {
                (x.f_hz / p.f_hz)
                    .ln()
                    .abs()
                    .total_cmp(&(y.f_hz / p.f_hz).ln().abs())
            })
            .expect("grid");
        let df = (lin.f_hz / p.f_hz).ln().abs();
        if df < 0.02 {
            assert!(
                (lin.closed_mag_db - p.mag_db).abs() < 1.0,
                "{} Hz: sweep {} dB vs linear {} dB",
                p.f_hz,
                p.mag_db,
                lin.closed_mag_db
            );
        }
    }
}

/// 004 §5: open-loop bandwidth of the actuator (valve command → force), paper "< 50 Hz"
/// (measured): MISSED. ehactl's open-loop sweep of the nonlinear plant around the command that
/// holds 785 N gives 58.5 Hz (eq. 17 with Table 1 has its slow pole at 66 Hz, so the paper's
/// own model misses the bound too). Asserted: the measured value (±1 Hz, 12 points) and the miss.
#[test]
fn seed004_open_loop_bandwidth_from_a_sweep() {
    let r = sweep(
        &config("sahu2022_force.toml"),
        SweepOptions {
            from_hz: Some(2.0),
            to_hz: Some(300.0),
            points: 12,
            amplitude: Some(0.0376),
            open_loop: true,
            output: Some(Channel::Force),
            ..Default::default()
        },
    )
    .expect("sweep");
    let bw = r.bandwidth_hz.expect("bandwidth reached");
    println!(
        "004 open-loop sweep: static gain {:.1} N/V, bandwidth {bw:.2} Hz",
        r.points[0].gain
    );
    assert!((bw - 58.54).abs() <= 1.0, "open-loop bandwidth {bw} Hz");
    assert!(
        bw > 50.0,
        "the paper's < 50 Hz is met now: update REPRODUCTION.md ({bw} Hz)"
    );
    // Static gain K_Qv·A_p/K_Ct = 5213 N/V from Table 1 (3 significant digits each: ±0.5 %),
    // CALIBRATED (the refit keeps the ratio); +0.9 % from the valve's own K_c at the 785 N
    // operating point (documented): within 1.5 %, and ehactl's 5262 N/V within 0.3 %.
    let g = r.points[0].gain;
    assert!(within(g, 5213.3, 0.015), "gain {g}");
    assert!(within(g, 5262.3, 0.003), "gain {g}");
}

/// 003: rigid connection, m_y + m_L: lowest natural frequency over the stroke, paper "≈ 30 Hz"
/// read off fig. 6 (two digits: ±1 Hz). REPRODUCED from 003's own parameters (29.48 Hz).
#[test]
fn seed003_lowest_natural_frequency_over_the_stroke() {
    let a = analyze(&config("dindorf2022_boom.toml")).expect("analyze");
    println!(
        "003 lowest natural frequency {:.2} Hz at {:.3} m; at y_set {:.2} Hz",
        a.min_natural_frequency_over_stroke_hz,
        a.min_natural_frequency_position_m,
        a.hydraulic_natural_frequency_hz
    );
    assert!((a.min_natural_frequency_over_stroke_hz - 30.0).abs() <= 1.0);
}

/// 003 eq. 23–29 at y_set = 0.6 m. Only fr_ym (95.01) is an independent check: REPRODUCED
/// within 1 % (0.9 % documented: k_y from the plant's chamber volumes; 0.005 % print
/// precision). fr_em (9.7) and rd_my (11.4) are the numbers k_m and d_m were derived from:
/// CALIBRATION consistency checks, within the config's rounding of k_m, d_m (5.0e4, 1.5e4)
/// and the fr_ym difference; and the config's k_m, d_m are the ones the published ratios imply.
#[test]
fn seed003_sdd_ratios() {
    let cfg = config("dindorf2022_boom.toml");
    let a = analyze(&cfg).expect("analyze");
    let s = a.sdd.as_ref().expect("SDD");
    println!(
        "003 fr_ym {:.3} fr_em {:.3} rd_my {:.3} (k_y {:.4e} N/m, f_y {:.2} Hz, f_m {:.3} Hz)",
        s.fr_ym,
        s.fr_em.unwrap_or(f64::NAN),
        s.rd_my,
        s.k_y,
        s.f_y_hz,
        s.f_m_hz
    );
    // Independent check.
    assert!(within(s.fr_ym, 95.01, 0.01), "fr_ym {}", s.fr_ym);
    // Calibration consistency (circular by construction: k_m, d_m come from these two).
    // fr_em ∝ 1/√k_m: rounding 4.985e4 → 5.0e4 moves it 0.15 %, so ±0.3 %.
    let fr_em = s.fr_em.expect("harmonic excitation");
    assert!(within(fr_em, 9.7, 0.003), "fr_em {fr_em}");
    // rd_my ∝ d_m·√k_y/√k_m: d_m rounded (−0.7 %), k_m (−0.15 %), k_y 1.8 % low (−0.9 %): ±2 %.
    assert!(within(s.rd_my, 11.4, 0.02), "rd_my {}", s.rd_my);
    let mount = cfg.plant.effects.flexible_mount.as_ref().expect("mount");
    let (k_m, d_m) = implied_mount(
        9.7,
        11.4,
        cfg.plant.excitation.frequency,
        s.k_y,
        cfg.plant.mechanics.mass,
        cfg.plant.mechanics.damping,
        mount.load_mass,
    );
    println!("003 implied k_m {k_m:.4e} N/m, d_m {d_m:.4e} N·s/m");
    assert!(within(mount.stiffness, k_m, 0.02), "k_m {k_m}");
    assert!(within(mount.damping, d_m, 0.02), "d_m {d_m}");
    // Inside the paper's stated ranges.
    assert!((1e4..=1e5).contains(&k_m) && (1e4..=2.5e4).contains(&d_m));
}

fn amplitude(v: &[f64]) -> f64 {
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    0.5 * (hi - lo)
}

/// 003 figures 13–16: PD positioning to 0.6 m under the 21.8 Hz force, rigid vs flexible.
/// The SDD isolates the actuator: its piston and pressure vibrate far less, the load more.
#[test]
fn seed003_rigid_versus_flexible_connection() {
    let mut out = Vec::new();
    for name in ["dindorf2022_boom_rigid.toml", "dindorf2022_boom.toml"] {
        let s = run_sim(
            &config(name),
            SessionOptions {
                capture: true,
                ..Default::default()
            },
        )
        .expect("run");
        let tail: Vec<_> = s.records.iter().filter(|r| r.t >= 2.0).collect();
        let x: Vec<f64> = tail.iter().map(|r| r.plant.x).collect();
        let xl: Vec<f64> = tail.iter().map(|r| r.plant.x_load).collect();
        let pl: Vec<f64> = tail.iter().map(|r| r.plant.p_a - r.plant.p_b).collect();
        let mean = x.iter().sum::<f64>() / x.len() as f64;
        let row = (mean, amplitude(&x), amplitude(&xl), amplitude(&pl));
        println!(
            "003 {name}: mean y {:.4} m, piston amplitude {:.2} µm, load amplitude {:.2} µm, p_L amplitude {:.3} bar",
            row.0,
            row.1 * 1e6,
            row.2 * 1e6,
            row.3 / 1e5
        );
        assert!(s.outcome.trip.is_none());
        assert!(
            (row.0 - 0.6).abs() < 0.01,
            "{name}: positioned at {}",
            row.0
        );
        out.push(row);
    }
    let (rigid, flex) = (out[0], out[1]);
    // 003 prints plots only (figs. 13–16), no numbers: ehactl's own amplitudes with its
    // assumed PD gains and F_A, asserted as regression values (±5 %: stick-slip sensitive), so
    // the figures REPRODUCTION.md quotes cannot drift unnoticed. Not an agreement with 003.
    for (what, v, expect) in [
        ("rigid piston (µm)", rigid.1 * 1e6, 60.53),
        ("flexible piston (µm)", flex.1 * 1e6, 2.23),
        ("flexible load (µm)", flex.2 * 1e6, 248.43),
        ("rigid p_L (bar)", rigid.3 / 1e5, 3.120),
        // 0.0203 since the drift–kick substep (0.019 before): the converged value at 64
        // substeps is 0.0210 with either ordering, so the config's 4 substeps now sit 3 %
        // from it instead of 10 % (BENCHMARKS.md "Diagnosis speed: drift before kick").
        ("flexible p_L (bar)", flex.3 / 1e5, 0.0203),
    ] {
        assert!(within(v, expect, 0.05), "{what}: {v} vs {expect}");
    }
    assert!(
        flex.1 < 0.2 * rigid.1,
        "piston: flexible {} vs rigid {}",
        flex.1,
        rigid.1
    );
    assert!(
        flex.3 < 0.2 * rigid.3,
        "p_L: flexible {} vs rigid {}",
        flex.3,
        rigid.3
    );
    assert!(
        flex.2 > flex.1,
        "the load, not the actuator, takes the vibration"
    );
}

/// 000: the hydrodynamic natural frequency rises from 350 Hz to 782 Hz when the chamber
/// length goes from 250 mm to 50 mm. The ratio 782/350 = 2.234 (two 3-digit numbers: ±0.2 %)
/// is REPRODUCED (independent of the mass; √5 with 000 eq. 11's V = A·L/2); the absolute
/// 350 Hz is CALIBRATED (the mass 5.231 kg was chosen for it): a consistency check.
#[test]
fn seed000_natural_frequency_rises_as_the_chamber_shortens() {
    let cfg = config("ideko_machine_tool.toml");
    let f = |stroke: f64| {
        let mut p = cfg.plant.clone();
        p.cylinder.stroke = stroke;
        p.cylinder.initial_position = stroke / 2.0;
        p.mechanics.load_contact_position = stroke / 2.0;
        let plant = Plant::configure(&p, cfg.timebase().period()).expect("plant");
        natural_frequency(&plant, stroke / 2.0, p.mechanics.mass)
    };
    let (f250, f50) = (f(0.25), f(0.05));
    println!(
        "000 natural frequency {f250:.1} Hz at 250 mm, {f50:.1} Hz at 50 mm, ratio {:.4}",
        f50 / f250
    );
    assert!(
        within(f50 / f250, 782.0 / 350.0, 0.003),
        "ratio {}",
        f50 / f250
    );
    // Calibration consistency: the mass was chosen for 350 Hz at 250 mm.
    assert!((f250 - 350.0).abs() <= 0.5, "{f250} Hz");
    // Not calibrated: 782 Hz at 50 mm follows (3 digits: ±0.5 Hz, plus the ratio's 0.08 %).
    assert!((f50 - 782.0).abs() <= 1.2, "{f50} Hz");
}

/// The disagreement documented in REPRODUCTION.md: Table 1 taken literally in the exact
/// physical model (K_Ct = 1.51e-10 as leakage, K_Qv = 3.33e-3 at the valve centre) is a far
/// faster plant than eq. 17 describes: its open-loop bandwidth is above 200 Hz, not < 80 Hz.
#[test]
fn seed004_table1_literal_is_not_eq17() {
    let mut cfg = config("sahu2022_force.toml");
    cfg.plant
        .effects
        .internal_leakage
        .as_mut()
        .expect("leakage")
        .coefficient = 1.51e-10;
    cfg.plant.valve.rated_flow = Some(1.0530e-2);
    let a = analyze(&cfg).expect("analyze");
    let ol = a.open_loop_bandwidth_hz.expect("open-loop bandwidth");
    let d = a.discrete.as_ref().expect("loop");
    println!(
        "004 Table 1 literal: open-loop BW {ol:.1} Hz, gc {:?} Hz, PM {:?}°",
        d.gain_crossover_hz, d.phase_margin_deg
    );
    assert!(ol > 200.0, "open-loop bandwidth {ol} Hz");
    assert!(d.gain_crossover_hz.expect("gc") > 200.0);
}
