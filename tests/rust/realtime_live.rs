//! Live gain / setpoint changes land at a cycle boundary and are logged as events; the
//! wall-clock run reports timing in its summary and logs `/timing`.

use ehactl_config::RigConfig;
use ehactl_control::setpoint::Setpoint;
use ehactl_hal::pacer::Pacer;
use ehactl_log::logger::Overflow;
use ehactl_log::record::CycleRecord;
use ehactl_runtime::control_socket::{self, ControlServer};
use ehactl_runtime::live::{self, LiveParams};
use ehactl_runtime::realtime::{RtOptions, WallClockPacer};
use ehactl_runtime::session::{build_plant, run_with_live, Backend, SessionOptions};
use ehactl_runtime::sim::SimHal;
use ehactl_tests::config;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

/// Simulated time; publishes `update` at the boundary before cycle `at` (as a writer
/// thread would between two cycles).
struct PublishAt {
    live: Arc<LiveParams>,
    at: u64,
    update: Option<live::Update>,
}

impl Pacer for PublishAt {
    fn wait_for_cycle(&mut self, k: u64) -> bool {
        if k == self.at {
            let u = self.update.take().unwrap();
            self.live.publish(u, Duration::from_secs(1)).unwrap();
        }
        true
    }
}

fn events(path: &Path) -> Vec<serde_json::Value> {
    let bytes = std::fs::read(path).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| m.channel.topic == "/events")
        .map(|m| serde_json::from_slice(&m.data).unwrap())
        .collect()
}

fn kp_used(r: &CycleRecord, error_scale: f64) -> f64 {
    r.p_term / (error_scale * r.error)
}

fn run(
    cfg: &RigConfig,
    pacer: &mut dyn Pacer,
    duration: f64,
    mcap: &Path,
    live: &LiveParams,
    overflow: Overflow,
) -> ehactl_runtime::session::Session {
    let mut c = cfg.clone();
    c.run.duration = duration;
    let plant = build_plant(&c).unwrap();
    let substeps = plant.substeps();
    let mut hal = SimHal::new(plant);
    run_with_live(
        cfg,
        Backend {
            hal: &mut hal,
            pacer,
            overflow,
            substeps,
        },
        SessionOptions {
            duration: Some(duration),
            mcap: Some(mcap.to_path_buf()),
            capture: true,
            ..Default::default()
        },
        Some(live),
    )
    .unwrap()
}

#[test]
fn change_lands_exactly_at_the_cycle_boundary_and_is_logged() {
    let cfg = config("sahu2022_force.toml");
    let es = cfg.control.pi.as_ref().unwrap().error_scale;
    let kp_old = cfg.control.pi.as_ref().unwrap().kp;
    let offset_old = cfg.setpoint.offset;
    let mut cfg_new = cfg.clone();
    let upd = live::prepare(
        &mut cfg_new,
        &[
            ("control.pi.kp", 0.3),
            ("setpoint.offset", offset_old - 100.0),
        ],
    )
    .unwrap();
    const AT: u64 = 1234;
    let live = Arc::new(LiveParams::new());
    let mut pacer = PublishAt {
        live: live.clone(),
        at: AT,
        update: Some(upd),
    };
    let dir = std::env::temp_dir().join(format!("ehactl-live-{}", std::process::id()));
    let path = dir.join("boundary.mcap");
    let s = run(&cfg, &mut pacer, 0.5, &path, &live, Overflow::Block);
    assert_eq!(s.outcome.cycles, 2500);
    let old_sp = Setpoint::new(&cfg.setpoint);
    let new_sp = Setpoint::new(&cfg_new.setpoint);
    let mut checked = 0;
    for r in &s.records {
        let (kp, sp) = if r.cycle < AT {
            (kp_old, &old_sp)
        } else {
            (0.3, &new_sp)
        };
        assert_eq!(
            r.setpoint,
            sp.sample(r.t).0,
            "setpoint at cycle {}",
            r.cycle
        );
        if r.error.abs() > 1e-6 {
            let k = kp_used(r, es);
            assert!(
                (k - kp).abs() < 1e-9 * kp,
                "cycle {}: kp {k}, expected {kp}",
                r.cycle
            );
            checked += 1;
        }
    }
    assert!(checked > 2000, "{checked}");
    let ev: Vec<_> = events(&path)
        .into_iter()
        .filter(|e| e["kind"] == "param_change")
        .collect();
    assert_eq!(ev.len(), 2, "{ev:?}");
    for e in &ev {
        assert_eq!(e["cycle"], AT);
        // (serde_json's default float parser is not exactly round-trip: compare to 1e-12 s)
        assert!((e["t"].as_f64().unwrap() - AT as f64 * cfg.timebase().period()).abs() < 1e-12);
    }
    assert_eq!(ev[0]["channel"], "control.pi.kp");
    assert_eq!(ev[0]["value"], 0.3);
    assert_eq!(ev[0]["unit"], "V/V");
    assert_eq!(ev[1]["channel"], "setpoint.offset");
    assert!((ev[1]["value"].as_f64().unwrap() - (offset_old - 100.0)).abs() < 1e-9);
    assert_eq!(live.applied_count(), 1);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn control_socket_changes_gain_of_a_wall_clock_run_without_torn_state() {
    let cfg = config("sahu2022_force.toml");
    let es = cfg.control.pi.as_ref().unwrap().error_scale;
    let kp_old = cfg.control.pi.as_ref().unwrap().kp;
    let dir = std::env::temp_dir().join(format!("ehactl-sock-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let sock = dir.join("ctl.sock");
    let live = Arc::new(LiveParams::new());
    let server = ControlServer::start(&sock, cfg.clone(), live.clone()).unwrap();
    let client = {
        let sock = sock.clone();
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(300));
            let bad_range = control_socket::send(&sock, &["control.pi.kp=-1".into()]).unwrap();
            let wrong_law = control_socket::send(&sock, &["control.pd.kp=1".into()]).unwrap();
            let not_live = control_socket::send(&sock, &["supervisor.max_force=1".into()]).unwrap();
            let ok = control_socket::send(&sock, &["control.pi.kp=0.3".into()]).unwrap();
            (bad_range, wrong_law, not_live, ok)
        })
    };
    // Real settings off: this test is about the hand-over, not about scheduling.
    let mut pacer = WallClockPacer::new(cfg.timebase(), RtOptions::default());
    let path = dir.join("socket.mcap");
    let s = run(&cfg, &mut pacer, 1.0, &path, &live, Overflow::Drop);
    let (bad_range, wrong_law, not_live, ok) = client.join().unwrap();
    drop(server);
    assert!(!sock.exists(), "socket file removed on drop");
    assert!(
        bad_range.starts_with("error: ")
            && bad_range.contains("control.pi.kp")
            && bad_range.contains("out of range"),
        "{bad_range}"
    );
    assert!(
        wrong_law.starts_with("error: ") && wrong_law.contains("control.pd.kp"),
        "{wrong_law}"
    );
    assert!(
        not_live.contains("cannot be changed while running"),
        "{not_live}"
    );
    assert!(ok.starts_with("ok cycle "), "{ok}");
    let cycle: u64 = ok["ok cycle ".len()..]
        .split(':')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(cycle > 0 && cycle < s.outcome.cycles, "{cycle}");
    // Every record used exactly the old gain before the boundary and the new one after.
    for r in &s.records {
        if r.error.abs() > 1e-6 {
            let want = if r.cycle < cycle { kp_old } else { 0.3 };
            let k = kp_used(r, es);
            assert!(
                (k - want).abs() < 1e-9,
                "cycle {} (change at {cycle}): kp {k}",
                r.cycle
            );
        }
    }
    let ev: Vec<_> = events(&path)
        .into_iter()
        .filter(|e| e["kind"] == "param_change")
        .collect();
    assert_eq!(ev.len(), 1, "only the valid change is logged: {ev:?}");
    assert_eq!(ev[0]["cycle"], cycle);
    // The wall-clock run measured its timing and logged it per cycle.
    let tm = s.timing.as_ref().expect("timing report");
    assert_eq!(tm.jitter.count, s.outcome.cycles);
    assert_eq!(tm.period.count, s.outcome.cycles - 1);
    let js = s.summary_json();
    for key in [
        "jitter_p99_us",
        "jitter_max_us",
        "overruns",
        "period_p50_us",
    ] {
        assert!(js.get(key).is_some(), "summary lacks {key}: {js}");
    }
    assert!(s.records.iter().all(|r| r.timing.is_some()));
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn bad_assignments_name_the_parameter_and_unit() {
    let mut cfg = config("dindorf2022_boom.toml");
    let e = live::parse_assignment("control.pd.kp")
        .unwrap_err()
        .to_string();
    assert!(e.contains("PATH=VALUE"), "{e}");
    let e = live::parse_assignment("control.pd.kp=abc")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("control.pd.kp") && e.contains("not a number"),
        "{e}"
    );
    let e = live::prepare(&mut cfg, &[("control.pd.nope", 1.0)])
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown parameter"), "{e}");
    let e = live::prepare(&mut cfg, &[("control.pd.td", -0.1)])
        .unwrap_err()
        .to_string();
    assert!(e.contains("control.pd.td") && e.contains(" s"), "{e}");
    // A failed change leaves the running config untouched.
    assert_eq!(cfg, config("dindorf2022_boom.toml"));
    live::prepare(&mut cfg, &[("control.pd.kp", 12.5)]).unwrap();
    assert_eq!(cfg.control.pd.as_ref().unwrap().kp, 12.5);
}
