//! Writes the Cristofori 2015 crane cycle with counterbalance valves as CSV (SI units):
//! `configs/cristofori2015_crane_cycle.toml` run open loop (raise / stop / lower / stop),
//! chamber, port and CBV-node pressures, CBV openings, supply pressure, β(p) of both chambers
//! (002 eq. 35–36), the true piston velocity and the port-pressure estimate of 002 eq. 31/32
//! switched as 002 does (eq. 31 for raise and stop after lowering, eq. 32 otherwise), every
//! 10 ms of the 1 kHz run.
//!
//! `cargo run --release -p ehactl-analysis --example repro_002_cycle_csv -- docs/repro/data`
//! then `python3 scripts/repro_002_cycle_plot.py` (which runs this itself if the data are absent).

use ehactl_analysis::motion::{MotionEstimator, PortSample};
use ehactl_config::RigConfig;
use ehactl_control::setpoint::Setpoint;
use ehactl_plant::Plant;
use std::fmt::Write as _;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "docs/repro/data".into()),
    );
    std::fs::create_dir_all(&out)?;
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let cfg = RigConfig::load(&root.join("configs/cristofori2015_crane_cycle.toml"))?;
    let dt = cfg.timebase().period();
    let mut plant = Plant::configure(&cfg.plant, dt)?;
    let mut ctrl = cfg.controller();
    let sp = Setpoint::new(&cfg.setpoint);
    let x0 = plant.state().x;
    let mut est = MotionEstimator::new(&cfg.plant, dt, x0).expect("spool of the shipped config");
    let band = cfg
        .plant
        .effects
        .valve_deadband
        .as_ref()
        .map_or(0.0, |d| d.overlap)
        * cfg.plant.valve.command_full_scale;
    let n = (cfg.run.duration / dt).round() as usize;
    let mut s = String::from(
        "t_s,command_v,phase,x_m,v_true_m_s,v_est_m_s,p_chamber_a_pa,p_chamber_b_pa,p_port_a_pa,\
         p_port_b_pa,p_cbv_node_a_pa,p_cbv_node_b_pa,cbv_opening_a,cbv_opening_b,p_supply_pa,\
         beta_a_pa,beta_b_pa\n",
    );
    let (mut x_prev, mut after_lower) = (x0, true);
    let every = ((0.01 / dt).round() as usize).max(1); // write at 100 Hz
    for k in 0..n {
        let m = plant.measure();
        let (r, rate) = sp.sample(m.t);
        let u = ctrl.step(r, rate, &m, dt).u;
        plant.step(u).map_err(|e| e.to_string())?;
        let st = *plant.state();
        let (pa, pb) = plant
            .valve_port_pressures()
            .ok_or("the cycle config has lines")?;
        let [ca, cb] = plant.counterbalance_valves();
        let (ca, cb) = (ca.ok_or("CBV A")?, cb.ok_or("CBV B")?);
        // Phases of 002's test cycles: 0 raise, 1 stop after raise, 2 lower, 3 stop after lowering.
        let phase = if u > band {
            after_lower = false;
            0
        } else if u < -band {
            after_lower = true;
            2
        } else if after_lower {
            3
        } else {
            1
        };
        let e = est.update(&PortSample {
            command: u,
            p_supply: st.p_s,
            p_tank: cfg.plant.supply.tank_pressure,
            p_we: pa,
            p_wr: pb,
        });
        let side = if phase == 0 || phase == 3 { 0 } else { 1 };
        let v_true = (st.x - x_prev) / dt;
        x_prev = st.x;
        if k % every != every - 1 {
            continue;
        }
        writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            st.t,
            u,
            phase,
            st.x,
            v_true,
            e.v[side],
            st.p_a,
            st.p_b,
            pa,
            pb,
            ca.p_node,
            cb.p_node,
            ca.opening,
            cb.opening,
            st.p_s,
            plant.bulk_modulus(st.p_a),
            plant.bulk_modulus(st.p_b)
        )?;
    }
    let path = out.join("002_cycle.csv");
    std::fs::write(&path, s)?;
    eprintln!("wrote {}", path.display());
    Ok(())
}
