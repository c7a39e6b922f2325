//! Writes the data behind the Sirohi 2003 and Cristofori 2015 reproduction plots as CSV (SI units):
//!
//! - `001_tube_lengths.csv`: transfer-matrix output displacement and pumping-chamber pressure
//!   per stack volt for tubes of 0, 4.5 and 11.5 in at 2 cSt (001 fig. 8);
//! - `001_viscosity.csv`: the same for the 4.5 in tube at 2, 20 and 200 cSt (001 fig. 9);
//! - `001_segments.csv`: 001's transfer matrix against the plant's linearised lumped line with
//!   2, 8, 32 segments and unsteady friction (configs/sirohi2003_circuit.toml) and 64 segments
//!   with steady friction, gains normalised to 1 at 20 Hz;
//! - `002_motion.csv`: the crane run (configs/cristofori2015_crane.toml) with the true piston
//!   velocity and the port-pressure estimates of 002 eq. 31.
//!
//! `cargo run --release -p ehactl-analysis --example repro_001_002_csv -- docs/repro/data`
//! then `python3 scripts/repro_001_002_plots.py` (which runs this itself if the data are absent).

use ehactl_analysis::linear::{self, Output};
use ehactl_analysis::motion::{LineTerms, MotionEstimator, PortSample};
use ehactl_analysis::oppoint;
use ehactl_analysis::tline::{Circuit, INCH};
use ehactl_config::RigConfig;
use ehactl_control::setpoint::Setpoint;
use ehactl_plant::params::LineFriction;
use ehactl_plant::rng::NoiseRng;
use ehactl_plant::Plant;
use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn freqs(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64))
        .collect()
}

fn tm_table(path: &Path, cases: &[(String, Circuit)]) -> std::io::Result<()> {
    let mut s = String::from("f_hz");
    for (name, _) in cases {
        write!(
            s,
            ",{name}_x_mag_m_per_v,{name}_x_phase_deg,{name}_pc_mag_pa_per_v"
        )
        .unwrap();
    }
    s.push('\n');
    for f in freqs(20.0, 3000.0, 1500) {
        write!(s, "{f:.6}").unwrap();
        for (_, c) in cases {
            let r = c.response(f);
            write!(
                s,
                ",{:.6e},{:.4},{:.6e}",
                r.displacement.norm(),
                r.displacement.arg().to_degrees(),
                r.source_pressure.norm()
            )
            .unwrap();
        }
        s.push('\n');
    }
    std::fs::write(path, s)
}

fn segments_table(path: &Path, root: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let f = freqs(20.0, 1500.0, 400);
    let mut cols: Vec<(String, Vec<f64>)> = Vec::new();
    for tube in [4.5, 11.5] {
        let c = Circuit::sirohi2003(tube * INCH, 2e-6);
        let g: Vec<f64> = f
            .iter()
            .map(|&f| c.response(f).displacement.norm())
            .collect();
        let g0 = g[0];
        cols.push((format!("tm_{tube}in"), g.iter().map(|v| v / g0).collect()));
        let mut cfg = RigConfig::load(&root.join("configs/sirohi2003_circuit.toml"))?;
        // The config's unsteady friction at 2–32 segments, steady friction at 64 (comparison).
        let runs = [
            (2u32, LineFriction::Unsteady, ""),
            (8, LineFriction::Unsteady, ""),
            (32, LineFriction::Unsteady, ""),
            (64, LineFriction::Steady, "_steady"),
        ];
        for (n, friction, tag) in runs {
            let l = cfg.plant.effects.line_dynamics.as_mut().unwrap();
            l.length = tube * INCH;
            l.segments = n;
            l.friction = friction;
            let op = oppoint::find(&cfg, 0.05)?;
            let m = linear::continuous(&op, 1e-8)?;
            let g: Vec<f64> = f
                .iter()
                .map(|&f| (m.response(Output::Position, f) * (2.0 * PI * f)).norm())
                .collect();
            let g0 = g[0];
            cols.push((
                format!("plant_{tube}in_n{n}{tag}"),
                g.iter().map(|v| v / g0).collect(),
            ));
            eprintln!("001 segments: tube {tube} in, {n} segments done");
        }
    }
    let mut s = String::from("f_hz");
    for (n, _) in &cols {
        write!(s, ",{n}").unwrap();
    }
    s.push('\n');
    for (i, fi) in f.iter().enumerate() {
        write!(s, "{fi:.6}").unwrap();
        for (_, v) in &cols {
            write!(s, ",{:.6e}", v[i]).unwrap();
        }
        s.push('\n');
    }
    std::fs::write(path, s)?;
    Ok(())
}

fn motion_table(path: &Path, root: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let cfg = RigConfig::load(&root.join("configs/cristofori2015_crane.toml"))?;
    let dt = cfg.timebase().period();
    let mut plant = Plant::configure(&cfg.plant, dt)?;
    let mut ctrl = cfg.controller();
    let sp = Setpoint::new(&cfg.setpoint);
    let x0 = plant.state().x;
    let mut est = MotionEstimator::new(&cfg.plant, dt, x0).expect("spool of the shipped config");
    let mut est_full = MotionEstimator::new(&cfg.plant, dt, x0)
        .expect("spool of the shipped config")
        .with_line_terms(LineTerms::Full);
    let mut est_noisy =
        MotionEstimator::new(&cfg.plant, dt, x0).expect("spool of the shipped config");
    let mut rng = NoiseRng::new(7);
    let noise = cfg.plant.sensors.pressure.noise;
    let n = (cfg.run.duration / dt).round() as usize;
    let mut s = String::from(
        "t_s,x_m,v_true_m_s,v_est_m_s,v_est_full_line_m_s,v_est_noisy_m_s,p_port_a_pa,p_chamber_a_pa,p_port_b_pa,p_chamber_b_pa,command_v\n",
    );
    let mut x_prev = x0;
    for _ in 0..n {
        let m = plant.measure();
        let (r, rate) = sp.sample(m.t);
        let u = ctrl.step(r, rate, &m, dt).u;
        plant.step(u).map_err(|e| e.to_string())?;
        let st = *plant.state();
        let (pa, pb) = plant
            .valve_port_pressures()
            .ok_or("crane config has no lines")?;
        let sample = PortSample {
            command: u,
            p_supply: cfg.plant.supply.pressure,
            p_tank: cfg.plant.supply.tank_pressure,
            p_we: pa,
            p_wr: pb,
        };
        let e = est.update(&sample);
        let ef = est_full.update(&sample);
        let en = est_noisy.update(&PortSample {
            p_we: pa + noise * rng.normal(),
            p_wr: pb + noise * rng.normal(),
            ..sample
        });
        let v_true = (st.x - x_prev) / dt;
        x_prev = st.x;
        writeln!(
            s,
            "{:.6},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6}",
            st.t, st.x, v_true, e.v[0], ef.v[0], en.v[0], pa, st.p_a, pb, st.p_b, u
        )
        .unwrap();
    }
    std::fs::write(path, s)?;
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "docs/repro/data".into()),
    );
    std::fs::create_dir_all(&out)?;
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let lengths: Vec<(String, Circuit)> = [0.0, 4.5, 11.5]
        .iter()
        .map(|&l| (format!("l{l}in"), Circuit::sirohi2003(l * INCH, 2e-6)))
        .collect();
    tm_table(&out.join("001_tube_lengths.csv"), &lengths)?;
    let visc: Vec<(String, Circuit)> = [2.0, 20.0, 200.0]
        .iter()
        .map(|&n| {
            (
                format!("nu{n}cst"),
                Circuit::sirohi2003(4.5 * INCH, n * 1e-6),
            )
        })
        .collect();
    tm_table(&out.join("001_viscosity.csv"), &visc)?;
    segments_table(&out.join("001_segments.csv"), &root)?;
    motion_table(&out.join("002_motion.csv"), &root)?;
    eprintln!("wrote CSVs to {}", out.display());
    Ok(())
}
