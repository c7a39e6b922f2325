//! The seed papers' published numbers, reproduced from their own parameters (issue 3).
//! Each test prints the figures it measured; REPRODUCTION.md tabulates them.

use ehactl_analysis::analyze::{analyze, natural_frequency};
use ehactl_analysis::sdd::implied_mount;
use ehactl_analysis::sweep::{sweep, Channel, SweepOptions};
use ehactl_controller::session::{run_sim, SessionOptions};
use ehactl_plant::Plant;
use ehactl_tests::config;

fn within(v: f64, target: f64, rel: f64) -> bool {
    (v - target).abs() <= rel * target.abs()
}

/// 004 §6.1: PM 60° (±4°), gain crossover ≈ 100 Hz (±10 %), closed-loop bandwidth in
/// 170–240 Hz, open-loop bandwidth below 80 Hz, from the sampled (5 kHz ZOH) linearisation.
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
    let pm = d.phase_margin_deg.expect("phase margin");
    assert!((pm - 60.0).abs() <= 4.0, "sampled-loop phase margin {pm}°");
    let gc = d.gain_crossover_hz.expect("gain crossover");
    assert!(within(gc, 100.0, 0.10), "gain crossover {gc} Hz");
    let bw = d.closed_loop_bandwidth_hz.expect("bandwidth");
    assert!(
        (170.0..=240.0).contains(&bw),
        "closed-loop bandwidth {bw} Hz"
    );
    let ol = a.open_loop_bandwidth_hz.expect("open-loop bandwidth");
    assert!(ol < 80.0, "open-loop bandwidth {ol} Hz");
    // The continuous loop (the paper's MATLAB analysis) has more phase: sampling and hold
    // cost about ωT/2 at crossover.
    let pm_c = c.phase_margin_deg.expect("continuous PM");
    assert!(
        pm_c > pm,
        "continuous PM {pm_c}° should exceed sampled {pm}°"
    );
    let gm = d.gain_margin_db.expect("gain margin");
    assert!(gm > 6.0 && gm < 12.0, "gain margin {gm} dB");
}

/// 004 §6.2: 785 N static + ±196 N swept on the nonlinear plant, closed loop: −3 dB
/// bandwidth 170–240 Hz; and the measured points agree with the linearisation.
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
    assert!((170.0..=240.0).contains(&bw), "bandwidth {bw} Hz");
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

/// 004 §5: open-loop bandwidth of the actuator (valve command → force) below 80 Hz (the
/// paper measured < 50 Hz), from an open-loop sweep of the nonlinear plant around the
/// command that holds 785 N.
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
    assert!(bw < 80.0, "open-loop bandwidth {bw} Hz");
    // Table 1's static gain K_Qv·A_p/K_Ct = 5214 N/V within 15 % (the valve's own K_c and
    // the offset shift it a little).
    assert!(
        within(r.points[0].gain, 5214.0, 0.15),
        "gain {}",
        r.points[0].gain
    );
}

/// 003: rigid connection, m_y + m_L: lowest natural frequency over the stroke ≈ 30 Hz (±10 %).
#[test]
fn seed003_lowest_natural_frequency_over_the_stroke() {
    let a = analyze(&config("dindorf2022_boom.toml")).expect("analyze");
    println!(
        "003 lowest natural frequency {:.2} Hz at {:.3} m; at y_set {:.2} Hz",
        a.min_natural_frequency_over_stroke_hz,
        a.min_natural_frequency_position_m,
        a.hydraulic_natural_frequency_hz
    );
    assert!(within(a.min_natural_frequency_over_stroke_hz, 30.0, 0.10));
}

/// 003 eq. 23–29 at y_set = 0.6 m: fr_ym 95.01 (±3 %), fr_em 9.7 (±3 %), rd_my 11.4 (±5 %);
/// and the config's k_m, d_m are the ones the published ratios imply.
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
    assert!(within(s.fr_ym, 95.01, 0.03));
    assert!(within(s.fr_em.expect("harmonic excitation"), 9.7, 0.03));
    assert!(within(s.rd_my, 11.4, 0.05));
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
/// length goes from 250 mm to 50 mm: ratio 2.234 (±2 %).
#[test]
fn seed000_natural_frequency_rises_as_the_chamber_shortens() {
    let cfg = config("ideko_machine_tool.toml");
    let f = |stroke: f64| {
        let mut p = cfg.plant.clone();
        p.cylinder.stroke = stroke;
        p.cylinder.initial_position = stroke / 2.0;
        p.mechanics.load_contact_position = stroke / 2.0;
        let plant = Plant::configure(&p, cfg.control_dt()).expect("plant");
        natural_frequency(&plant, stroke / 2.0, p.mechanics.mass)
    };
    let (f250, f50) = (f(0.25), f(0.05));
    println!(
        "000 natural frequency {f250:.1} Hz at 250 mm, {f50:.1} Hz at 50 mm, ratio {:.4}",
        f50 / f250
    );
    assert!(within(f50 / f250, 2.234, 0.02));
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
