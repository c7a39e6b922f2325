//! Cristofori 2015 (Cristofori & Vacca) reproduction: piston motion estimated from the pressures at
//! the valve ports (eq. 1–36) on a simulation of configs/cristofori2015_crane.toml, whose
//! lines make the port pressures differ from the chamber pressures; and the swing of the
//! pressure-dependent bulk modulus (eq. 35–36) over the run.
//!
//! Run: `cargo test --release -p ehactl-tests --test repro_002 -- --nocapture`.

use ehactl_analysis::motion::{LineTerms, MotionEstimator, PortSample};
use ehactl_control::setpoint::Setpoint;
use ehactl_plant::rng::NoiseRng;
use ehactl_plant::Plant;
use ehactl_tests::config;

/// One closed-loop run of the crane config, sampled at the control rate.
struct Run {
    dt: f64,
    x0: f64,
    /// Per sample k ≥ 1: command held over (k−1, k], port pressures, chamber pressures,
    /// piston position at k.
    u: Vec<f64>,
    p_port: Vec<(f64, f64)>,
    p_chamber: Vec<(f64, f64)>,
    x: Vec<f64>,
    p_supply: f64,
    p_tank: f64,
}

fn simulate() -> (Run, ehactl_config::RigConfig) {
    let cfg = config("cristofori2015_crane.toml");
    let dt = cfg.timebase().period();
    let mut plant = Plant::configure(&cfg.plant, dt).expect("crane config");
    let mut ctrl = cfg.controller();
    let sp = Setpoint::new(&cfg.setpoint);
    let n = (cfg.run.duration / dt).round() as usize;
    let x0 = plant.state().x;
    let mut run = Run {
        dt,
        x0,
        u: Vec::with_capacity(n),
        p_port: Vec::with_capacity(n),
        p_chamber: Vec::with_capacity(n),
        x: Vec::with_capacity(n),
        p_supply: cfg.plant.supply.pressure,
        p_tank: cfg.plant.supply.tank_pressure,
    };
    for _ in 0..n {
        let m = plant.measure();
        let (r, rate) = sp.sample(m.t);
        let u = ctrl.step(r, rate, &m, dt).u;
        plant.step(u).expect("finite plant");
        let s = plant.state();
        run.u.push(u);
        run.p_port.push(
            plant
                .valve_port_pressures()
                .expect("crane config has lines"),
        );
        run.p_chamber.push((s.p_a, s.p_b));
        run.x.push(s.x);
    }
    (run, cfg)
}

struct Errors {
    rms_err: f64,
    rms_true: f64,
    peak_true: f64,
    max_err: f64,
    stroke_err: f64,
}

/// Velocity error of the extension-chamber estimate (eq. 31, used by 002 for raising) with
/// port-pressure noise σ (Pa).
fn estimate(
    run: &Run,
    cfg: &ehactl_config::RigConfig,
    terms: LineTerms,
    noise: f64,
    side: usize,
) -> Errors {
    let mut est = MotionEstimator::new(&cfg.plant, run.dt, run.x0)
        .expect("spool of the shipped config")
        .with_line_terms(terms);
    let mut rng = NoiseRng::new(7);
    let (mut se, mut st, mut pk, mut mx) = (0.0, 0.0, 0.0f64, 0.0f64);
    let mut x_prev = run.x0;
    let mut last = 0.0;
    for k in 0..run.u.len() {
        let (pa, pb) = run.p_port[k];
        let e = est.update(&PortSample {
            command: run.u[k],
            p_supply: run.p_supply,
            p_tank: run.p_tank,
            p_we: pa + noise * rng.normal(),
            p_wr: pb + noise * rng.normal(),
        });
        let v_true = (run.x[k] - x_prev) / run.dt;
        x_prev = run.x[k];
        if k > 0 {
            let err = e.v[side] - v_true;
            se += err * err;
            st += v_true * v_true;
            pk = pk.max(v_true.abs());
            mx = mx.max(err.abs());
        }
        last = e.x[side];
    }
    let m = (run.u.len() - 1) as f64;
    Errors {
        rms_err: (se / m).sqrt(),
        rms_true: (st / m).sqrt(),
        peak_true: pk,
        max_err: mx,
        stroke_err: last - run.x[run.x.len() - 1],
    }
}

#[test]
fn port_pressures_differ_from_chamber_pressures() {
    let (run, _) = simulate();
    let max_diff = run
        .p_port
        .iter()
        .zip(&run.p_chamber)
        .map(|(p, c)| (p.0 - c.0).abs().max((p.1 - c.1).abs()))
        .fold(0.0, f64::max);
    println!("002: largest |port − chamber| pressure difference {max_diff:.0} Pa");
    assert!(
        max_diff > 1e4,
        "lines must separate port and chamber pressure"
    );
}

#[test]
fn motion_estimate_recovers_piston_velocity() {
    let (run, cfg) = simulate();
    let travel = run.x[run.x.len() - 1] - run.x0;
    println!(
        "002 crane run: {:.3} m travel in {} samples at {} Hz",
        travel,
        run.u.len(),
        1.0 / run.dt
    );
    assert!(travel > 0.3, "the boom must lift: {travel}");
    for (side, name) in [(0, "eq. 31 extension"), (1, "eq. 32 retraction")] {
        for (terms, noise) in [
            (LineTerms::Full, 0.0),
            (LineTerms::Resistive, 0.0),
            (LineTerms::Full, 2.0e4),
            (LineTerms::Resistive, 2.0e4),
        ] {
            let e = estimate(&run, &cfg, terms, noise, side);
            println!(
                "  {name}, {terms:?} line, port noise {noise:>6} Pa: RMS velocity error {:.4} m/s = {:.2} % of \
                 RMS velocity {:.4} m/s ({:.2} % of peak {:.3} m/s), max error {:.4} m/s, \
                 final position error {:+.2} mm",
                e.rms_err,
                100.0 * e.rms_err / e.rms_true,
                e.rms_true,
                100.0 * e.rms_err / e.peak_true,
                e.peak_true,
                e.max_err,
                1e3 * e.stroke_err
            );
            // 002's method (resistive line): the velocity within 5 % RMS without sensor noise,
            // and, for eq. 31 (the one 002 uses while raising), within 10 % with the config's
            // 0.2 bar pressure noise; the position drift (002: "a certain extent of drift")
            // within 2 % of the travel.
            if terms == LineTerms::Resistive && (noise == 0.0 || side == 0) {
                let tol = if noise == 0.0 { 0.05 } else { 0.10 };
                assert!(e.rms_err < tol * e.rms_true, "{name}: {} m/s", e.rms_err);
                assert!(
                    e.stroke_err.abs() < 0.02 * travel,
                    "{name}: {}",
                    e.stroke_err
                );
            }
        }
    }
}

#[test]
fn bulk_modulus_swing_over_the_run() {
    let (run, cfg) = simulate();
    let law = MotionEstimator::new(&cfg.plant, run.dt, run.x0)
        .expect("spool of the shipped config")
        .bulk_modulus_law();
    // The estimator's eq. 35 law is the plant's.
    let plant = Plant::configure(&cfg.plant, run.dt).unwrap();
    for p in [0.0, 5e6, 1e7, 2e7] {
        assert!((law.beta(p) / plant.bulk_modulus(p) - 1.0).abs() < 1e-12);
    }
    let b_ref = law.beta(10.0e6); // 002: "of the constant value at 30 °C and 100 bar"
    let range = |it: &mut dyn Iterator<Item = f64>| {
        it.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| {
            (l.min(p), h.max(p))
        })
    };
    let (lo_a, hi_a) = range(&mut run.p_chamber.iter().map(|p| p.0));
    let (lo, hi) = range(&mut run.p_chamber.iter().flat_map(|p| [p.0, p.1]));
    let swing_a = (law.beta(hi_a) - law.beta(lo_a)) / b_ref;
    let swing = (law.beta(hi) - law.beta(lo)) / b_ref;
    // Over the pressure range a crane chamber can see, tank (0) to supply.
    let ps = run.p_supply;
    let swing_range = (law.beta(ps) - law.beta(0.0)) / b_ref;
    println!(
        "002 β(p) = {:.3e} Pa + {}·p (eq. 35): swing in % of β(100 bar) = {:.4e} Pa\n  \
         over this run, extension chamber {:.2}–{:.2} MPa: {:.2} %; both chambers \
         {:.2}–{:.2} MPa: {:.2} %\n  over 0 – {:.0} MPa (tank to supply): {:.2} %",
        law.beta0,
        law.slope,
        b_ref,
        lo_a / 1e6,
        hi_a / 1e6,
        100.0 * swing_a,
        lo / 1e6,
        hi / 1e6,
        100.0 * swing,
        ps / 1e6,
        100.0 * swing_range
    );
    // 002 (fig. 19): the variation reaches 10 % over its test cycles, whose chamber pressures
    // span the working range. The config's K_b gives that over tank-to-supply (±1 %) ...
    assert!((swing_range - 0.10).abs() < 0.01, "{swing_range}");
    // ... while this lift at constant load only spans a few MPa (reported, see
    // REPRODUCTION.md, Cristofori 2015): the swing over the run must be the law applied to its range.
    assert!(swing > 0.0 && swing < swing_range, "{swing}");
}

/// The raise / stop / lower / stop cycle of `configs/cristofori2015_crane_cycle.toml`: 100 kN
/// on the rod, counterbalance valves on both lines, open-loop 0.1 Hz sine command.
struct Cycle {
    t: Vec<f64>,
    u: Vec<f64>,
    x: Vec<f64>,
    p_port: Vec<(f64, f64)>,
    p_chamber: Vec<(f64, f64)>,
    /// CBV port-2 node pressures (Pa) and poppet openings (-), A and B.
    node: Vec<(f64, f64)>,
    opening: Vec<(f64, f64)>,
    /// Supply pressure at the valve's P port (Pa): 002 measures it (p_P).
    p_supply: Vec<f64>,
}

/// Phase of 002's test cycles from the command (dead band 42 % of 10 V): 0 raise, 1 stop
/// after raise, 2 lower, 3 stop after lowering.
fn phase(u: f64, after_lower: bool) -> usize {
    if u > 4.2 {
        0
    } else if u < -4.2 {
        2
    } else if after_lower {
        3
    } else {
        1
    }
}

fn simulate_cycle() -> (Cycle, ehactl_config::RigConfig) {
    simulate_cycle_with(config("cristofori2015_crane_cycle.toml"))
}

fn simulate_cycle_with(cfg: ehactl_config::RigConfig) -> (Cycle, ehactl_config::RigConfig) {
    let dt = cfg.timebase().period();
    let mut plant = Plant::configure(&cfg.plant, dt).expect("cycle config");
    let mut ctrl = cfg.controller();
    let sp = Setpoint::new(&cfg.setpoint);
    let n = (cfg.run.duration / dt).round() as usize;
    let mut c = Cycle {
        t: vec![],
        u: vec![],
        x: vec![],
        p_port: vec![],
        p_chamber: vec![],
        node: vec![],
        opening: vec![],
        p_supply: vec![],
    };
    for _ in 0..n {
        let m = plant.measure();
        let (r, rate) = sp.sample(m.t);
        let u = ctrl.step(r, rate, &m, dt).u;
        plant.step(u).expect("finite plant");
        let s = *plant.state();
        let [a, b] = plant.counterbalance_valves();
        let (a, b) = (a.expect("CBV on A"), b.expect("CBV on B"));
        c.t.push(s.t);
        c.u.push(u);
        c.x.push(s.x);
        c.p_port.push(plant.valve_port_pressures().expect("lines"));
        c.p_chamber.push((s.p_a, s.p_b));
        c.node.push((a.p_node, b.p_node));
        c.opening.push((a.opening, b.opening));
        c.p_supply.push(s.p_s);
    }
    (c, cfg)
}

#[test]
fn crane_cycle_with_counterbalance_valves() {
    let (c, cfg) = simulate_cycle();
    let n = c.t.len();
    // At rest before the raise counts as "stop after lowering" (same switching in 002).
    let mut after_lower = true;
    let ph: Vec<usize> =
        c.u.iter()
            .map(|&u| {
                let p = phase(u, after_lower);
                if p == 0 {
                    after_lower = false;
                }
                if p == 2 {
                    after_lower = true;
                }
                p
            })
            .collect();
    let names = ["raise", "stop after raise", "lower", "stop after lowering"];
    let x0 = c.x[0];
    let x_top = c.x[ph.iter().rposition(|&p| p == 1).expect("stop after raise")];
    let x_end = c.x[n - 1];
    println!(
        "002 cycle: x {:.3} m → {:.3} m (raised) → {:.3} m (lowered)",
        x0, x_top, x_end
    );
    for (k, name) in names.iter().enumerate() {
        let idx: Vec<usize> = (0..n).filter(|&i| ph[i] == k).collect();
        let range = |f: &dyn Fn(usize) -> f64| {
            idx.iter()
                .map(|&i| f(i))
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                    (l.min(v), h.max(v))
                })
        };
        let pa = range(&|i| c.p_chamber[i].0);
        let pb = range(&|i| c.p_chamber[i].1);
        let wa = range(&|i| c.p_port[i].0);
        let wb = range(&|i| c.p_port[i].1);
        let oa = range(&|i| c.opening[i].0);
        let ob = range(&|i| c.opening[i].1);
        println!(
            "  {name:<20} {:5.2}–{:5.2} s: p_A {:5.2}–{:5.2} MPa (port {:5.2}–{:5.2}), p_B {:5.2}–{:5.2} MPa (port {:5.2}–{:5.2}), CBV opening A {:.2}–{:.2}, B {:.2}–{:.2}",
            c.t[idx[0]], c.t[*idx.last().unwrap()],
            pa.0 / 1e6, pa.1 / 1e6, wa.0 / 1e6, wa.1 / 1e6, pb.0 / 1e6, pb.1 / 1e6,
            wb.0 / 1e6, wb.1 / 1e6, oa.0, oa.1, ob.0, ob.1
        );
    }
    // The cycle moves the boom up and back down.
    assert!(x_top - x0 > 0.1, "raised {} m", x_top - x0);
    assert!(x_top - x_end > 0.1, "lowered {} m", x_top - x_end);
    // Holding: while stopped after the raise the load-holding CBV (A) is shut and the boom
    // stays put (creep below 1 mm over the stop).
    let stop1: Vec<usize> = (0..n).filter(|&i| ph[i] == 1).collect();
    let settle = stop1[0] + 300; // 0.3 s for the spool (15 Hz) to close
    let creep = (c.x[*stop1.last().unwrap()] - c.x[settle]).abs();
    println!(
        "  creep while holding after the raise: {:.3} mm",
        creep * 1e3
    );
    assert!(creep < 1e-3, "creep {creep} m");
    // Lowering is metered by the A-side CBV, opened by the B-line pilot: p_A + ψ·p_B reaches
    // the setting (16.5 MPa) while the A chamber drains, and the A chamber then sits above the
    // A port by the CBV's pressure drop (the CBV's effect on the port pressures).
    let cbv = cfg.plant.effects.counterbalance_valve.as_ref().unwrap();
    let lower: Vec<usize> = (0..n).filter(|&i| ph[i] == 2).collect();
    let mid = &lower[lower.len() / 4..3 * lower.len() / 4];
    let mean = |f: &dyn Fn(usize) -> f64| mid.iter().map(|&i| f(i)).sum::<f64>() / mid.len() as f64;
    let drop_a = mean(&|i| c.p_chamber[i].0 - c.p_port[i].0);
    let pilot_sum = mean(&|i| c.p_chamber[i].0 + cbv.pilot_ratio * c.node[i].1);
    let open_a = mean(&|i| c.opening[i].0);
    println!(
        "  lowering (middle half): p_A − p_port,A {:.2} MPa, p_A + ψ·p_pilot {:.2} MPa (setting {:.2}), CBV A opening {:.2}",
        drop_a / 1e6,
        pilot_sum / 1e6,
        cbv.setting / 1e6,
        open_a
    );
    // Lowering is metered by the A-side CBV, held partly open by the B-line pilot: in the middle
    // of the lowering p_A + ψ·p_pilot sits at setting + opening·Δp_open (the opening law with
    // the poppet lag settled; 10 % of Δp_open for the lag and the averaging), and the A chamber
    // stays above its port by the CBV's drop (its effect on the port pressures).
    assert!(
        open_a > 0.0 && open_a < 1.0,
        "metering, not fully open: {open_a}"
    );
    assert!(
        (pilot_sum - (cbv.setting + open_a * cbv.opening_pressure)).abs()
            < 0.1 * cbv.opening_pressure,
        "opening law: {pilot_sum} Pa"
    );
    assert!(drop_a > 2.0e6, "the CBV holds back the load: {drop_a} Pa");
    // Holding: the A poppet is shut once the pilot has bled off; lowering: the B-line pilot
    // opens it (pilot-assisted opening, p_A + ψ·p_pilot ≥ setting).
    let shut = stop1[stop1.len() / 2..]
        .iter()
        .all(|&i| c.opening[i].0 < 1e-3);
    assert!(shut, "the load-holding CBV must be shut while stopped");
    let opened = lower.iter().map(|&i| c.opening[i].0).fold(0.0, f64::max);
    assert!(opened > 0.5, "lowering opens the A-side CBV: {opened}");
    // β(p) over the cycle (002 eq. 35–36), relative to β(100 bar).
    let plant = Plant::configure(&cfg.plant, cfg.timebase().period()).unwrap();
    let (lo, hi) = c
        .p_chamber
        .iter()
        .flat_map(|p| [p.0, p.1])
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| {
            (l.min(p), h.max(p))
        });
    let swing = (plant.bulk_modulus(hi) - plant.bulk_modulus(lo)) / plant.bulk_modulus(10.0e6);
    println!(
        "  chamber pressures over the cycle {:.2}–{:.2} MPa: β swing {:.2} % of β(100 bar)",
        lo / 1e6,
        hi / 1e6,
        100.0 * swing
    );
    // 002 fig. 19: ≈ 10 %. MISSED: 7.31 % here (the same at 8× the substeps: converged) (K_b is calibrated to give 9.5 % over 0–20 MPa;
    // this cycle's chambers span −0.1…16 MPa with the assumed load and supply). Asserted at
    // the measured value (±0.2 points) and as a miss.
    assert!((swing - 0.0731).abs() < 0.002, "β swing {swing}");
    assert!(
        swing < 0.095,
        "the 10 % of 002 is reached now: update REPRODUCTION.md ({swing})"
    );

    // Motion estimate from the port pressures (002 eq. 31–36), switching as 002 does: eq. 31
    // for raise and stop after lowering, eq. 32 otherwise. Resistive line (002's choice), no
    // noise. The estimator does not model the CBV (002 eq. 18–26 are not implemented).
    let dt = cfg.timebase().period();
    let mut est = MotionEstimator::new(&cfg.plant, dt, x0).expect("spool of the shipped config");
    let pt = cfg.plant.supply.tank_pressure;
    let mut x_prev = x0;
    let mut per = [(0.0, 0.0, 0usize); 4];
    // Steady motion: the middle half of the raise and of the lowering.
    let mid_of = |k: usize| {
        let idx: Vec<usize> = (0..n).filter(|&i| ph[i] == k).collect();
        (idx[idx.len() / 4], idx[3 * idx.len() / 4])
    };
    let (r0, r1, l0, l1) = {
        let (a, b) = mid_of(0);
        let (c2, d) = mid_of(2);
        (a, b, c2, d)
    };
    let mut steady = [(0.0, 0.0); 2];
    for i in 0..n {
        let (pa, pb) = c.p_port[i];
        let e = est.update(&PortSample {
            command: c.u[i],
            p_supply: c.p_supply[i],
            p_tank: pt,
            p_we: pa,
            p_wr: pb,
        });
        let v_true = (c.x[i] - x_prev) / dt;
        x_prev = c.x[i];
        let side = if ph[i] == 0 || ph[i] == 3 { 0 } else { 1 };
        if i > 0 {
            let err = e.v[side] - v_true;
            per[ph[i]].0 += err * err;
            per[ph[i]].1 += v_true * v_true;
            per[ph[i]].2 += 1;
            for (j, (lo, hi)) in [(r0, r1), (l0, l1)].into_iter().enumerate() {
                if (lo..hi).contains(&i) {
                    steady[j].0 += err * err;
                    steady[j].1 += v_true * v_true;
                }
            }
        }
    }
    for (k, name) in names.iter().enumerate() {
        let (se, st, m) = per[k];
        println!(
            "  motion estimate, {name:<20}: RMS velocity error {:.4} m/s (RMS velocity {:.4} m/s)",
            (se / m as f64).sqrt(),
            (st / m as f64).sqrt()
        );
    }
    let rel = |(se, st): (f64, f64)| (se / st).sqrt();
    println!(
        "  whole phases: raise {:.1} %, lower {:.1} % RMS; middle half (steady motion): raise {:.2} %, lower {:.2} % RMS",
        100.0 * rel((per[0].0, per[0].1)),
        100.0 * rel((per[2].0, per[2].1)),
        100.0 * rel(steady[0]),
        100.0 * rel(steady[1])
    );
    // 002 gives no number ("accurate"). In steady motion eq. 31/32 with the CBV check
    // (eq. 18–19) and the stop hold (eq. 25) track the piston within 2 %; the start of each
    // motion (CBV chatter, the boom's oscillation) is where the error is.
    assert!(
        rel(steady[0]) < 0.02 && rel(steady[1]) < 0.02,
        "steady tracking {steady:?}"
    );
}

/// The cycle at the substeps the automatic rule picks is converged: within 0.05 % (rod
/// position) and 0.5 % (chamber pressures) NRMSE of the same cycle at 8× those substeps. Before
/// the CBV node handed the chamber the volume it actually passed on, the automatic
/// 46 substeps chattered numerically in the raise (position 10 % NRMSE, p_A 66 %).
#[test]
fn crane_cycle_is_converged_at_the_automatic_step() {
    let cfg = config("cristofori2015_crane_cycle.toml");
    let dt = cfg.timebase().period();
    let auto = Plant::configure(&cfg.plant, dt).unwrap().substeps();
    let mut fine = cfg.clone();
    fine.plant.integration.substeps = 8 * auto;
    let (a, _) = simulate_cycle_with(cfg);
    let (b, _) = simulate_cycle_with(fine);
    let nrmse = |f: &dyn Fn(&Cycle, usize) -> f64| {
        let n = a.t.len();
        let r: Vec<f64> = (0..n).map(|i| f(&b, i)).collect();
        let span = r.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
            - r.iter().cloned().fold(f64::INFINITY, f64::min);
        let mse = (0..n).map(|i| (f(&a, i) - r[i]).powi(2)).sum::<f64>() / n as f64;
        mse.sqrt() / span
    };
    let nx = nrmse(&|c, i| c.x[i]);
    let npa = nrmse(&|c, i| c.p_chamber[i].0);
    let npb = nrmse(&|c, i| c.p_chamber[i].1);
    println!(
        "crane cycle, {auto} vs {} substeps: NRMSE x {nx:.2e}, p_A {npa:.2e}, p_B {npb:.2e}",
        8 * auto
    );
    assert!(
        nx < 5e-4 && npa < 5e-3 && npb < 5e-3,
        "x {nx}, p_A {npa}, p_B {npb}"
    );
}

#[test]
fn counterbalance_valve_needs_lines() {
    let mut cfg = config("cristofori2015_crane_cycle.toml");
    cfg.plant.effects.line_dynamics = None;
    let e = Plant::configure(&cfg.plant, cfg.timebase().period()).expect_err("a CBV without lines");
    let msg = e.to_string();
    assert!(
        msg.contains("effects.counterbalance_valve") && msg.contains("line_dynamics"),
        "{msg}"
    );
}
