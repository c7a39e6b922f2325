//! Zero allocation in the cycle: a counting global allocator (per thread) watches the loop
//! thread of a wall-clock run — sim backend paced in real time by the real
//! `WallClockPacer`, every record pushed to the MCAP logger, and a live gain change
//! published from another thread in the middle — and every cycle after start-up must
//! allocate nothing. Its own test binary, because it installs its own #[global_allocator].

use ehactl_hal::pacer::{Pacer, TimingReport};
use ehactl_log::logger::Overflow;
use ehactl_log::record::{CycleTiming, Event};
use ehactl_runtime::live::{self, LiveParams};
use ehactl_runtime::realtime::{RtOptions, WallClockPacer};
use ehactl_runtime::session::{build_plant, run_with_live, Backend, SessionOptions};
use ehactl_runtime::sim::SimHal;
use ehactl_tests::config;
use ehactl_tests::{allocations, CountingAlloc};
use std::sync::Arc;
use std::time::Duration;

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// Wraps the real pacer and notes this thread's allocation count at every cycle boundary
/// into a preallocated array (indexing does not allocate).
struct Watch {
    inner: WallClockPacer,
    at: Vec<u64>,
}

impl Pacer for Watch {
    fn wait_for_cycle(&mut self, k: u64) -> bool {
        if let Some(slot) = self.at.get_mut(k as usize) {
            *slot = allocations();
        }
        self.inner.wait_for_cycle(k)
    }
    fn cycle_timing(&self) -> Option<CycleTiming> {
        self.inner.cycle_timing()
    }
    fn take_event(&mut self) -> Option<Event> {
        self.inner.take_event()
    }
    fn trip(&self) -> Option<Event> {
        self.inner.trip()
    }
    fn timing_report(&self) -> Option<TimingReport> {
        Pacer::timing_report(&self.inner)
    }
}

#[test]
fn no_allocation_per_cycle_after_start_up() {
    const CYCLES: u64 = 12_000; // 2.4 s at 5 kHz
    let cfg = config("sahu2022_force.toml");
    let mut cfg_run = cfg.clone();
    cfg_run.run.duration = CYCLES as f64 * cfg.timebase().period();
    let plant = build_plant(&cfg_run).unwrap();
    let substeps = plant.substeps();
    let mut hal = SimHal::new(plant);
    // Real-time settings as configured (they may be refused: a warning, still counted).
    let mut pacer = Watch {
        inner: WallClockPacer::new(cfg.timebase(), RtOptions::from_config(&cfg.realtime)),
        at: vec![u64::MAX; CYCLES as usize + 1],
    };
    let live = Arc::new(LiveParams::new());
    // A gain change published from another thread while the loop runs.
    let writer = {
        let live = live.clone();
        let mut cfg_w = cfg.clone();
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(800));
            let upd = live::prepare(&mut cfg_w, &[("control.pi.kp", 0.4)]).unwrap();
            let seq = live.publish(upd, Duration::from_secs(5)).unwrap();
            live.wait_applied(seq, Duration::from_secs(5))
        })
    };
    let dir = std::env::temp_dir().join(format!("ehactl-rt-alloc-{}", std::process::id()));
    let s = run_with_live(
        &cfg,
        Backend {
            hal: &mut hal,
            pacer: &mut pacer,
            overflow: Overflow::Drop,
            substeps,
        },
        SessionOptions {
            duration: Some(cfg_run.run.duration),
            mcap: Some(dir.join("alloc.mcap")),
            ..Default::default()
        },
        Some(&live),
    )
    .unwrap();
    let applied_at = writer.join().unwrap().expect("change applied");
    assert_eq!(s.outcome.cycles, CYCLES);
    assert!(s.outcome.trip.is_none(), "{:?}", s.outcome.trip);
    assert!(applied_at > 1 && applied_at < CYCLES, "{applied_at}");
    let at = &pacer.at;
    // Start-up = everything up to the first wait (k = 0: logger, RT set-up, first event).
    let mut bad = Vec::new();
    for k in 1..CYCLES as usize {
        let d = at[k] - at[k - 1];
        if d != 0 {
            bad.push((k - 1, d));
        }
    }
    assert!(
        bad.is_empty(),
        "cycles that allocated (cycle, allocations): {:?}",
        &bad[..bad.len().min(20)]
    );
    // Sanity: the counter works on this thread (this Vec allocates).
    let before = allocations();
    let v: Vec<u8> = Vec::with_capacity(10);
    assert!(allocations() > before && v.capacity() >= 10);
    let log = s.log.as_ref().unwrap();
    assert_eq!(log.records_written + log.records_dropped, CYCLES);
    println!(
        "{} cycles, 0 allocations per cycle; logger queue high water {} of {}; dropped {}",
        CYCLES, log.queue_high_water, log.queue_capacity, log.records_dropped
    );
    std::fs::remove_dir_all(dir).ok();
}

/// The counterbalance-valve plant (crates/plant/src/cbv.rs) steps without allocating:
/// raising then lowering through both CBVs of the Cristofori 2015 cycle config.
#[test]
fn counterbalance_valve_plant_step_does_not_allocate() {
    let cfg = config("cristofori2015_crane_cycle.toml");
    let mut plant = ehactl_plant::Plant::configure(&cfg.plant, cfg.timebase().period()).unwrap();
    plant.step(5.0).unwrap();
    let before = allocations();
    for k in 0..2000 {
        plant.step(if k < 1000 { 8.0 } else { -8.0 }).unwrap();
        let _ = plant.counterbalance_valves();
    }
    assert_eq!(allocations() - before, 0);
}

/// The delay line of `time_delay` (crates/plant/src/effects/time_delay.rs) pushes and reads
/// its ring buffer without allocating, through 250 wraps of its 4 slots, before and after a
/// restart (`Plant::initialize`, not itself a cycle): the Sahu 2022 force rig with a
/// fractional delay of 1.55 control periods.
#[test]
fn delay_line_plant_step_does_not_allocate() {
    let mut cfg = config("sahu2022_force.toml");
    cfg.plant.effects.time_delay = Some(ehactl_plant::params::TimeDelay {
        enabled: true,
        delay: 3.1e-4,
    });
    let mut plant = ehactl_plant::Plant::configure(&cfg.plant, cfg.timebase().period()).unwrap();
    for run in 0..2 {
        plant.step(1.0).unwrap();
        let before = allocations();
        for k in 0..1000 {
            plant.step(if k % 100 < 50 { 2.0 } else { -2.0 }).unwrap();
        }
        assert_eq!(allocations() - before, 0, "run {run}");
        plant.initialize();
    }
    for k in 0..1000 {
        plant.step(if k % 100 < 50 { 2.0 } else { -2.0 }).unwrap();
    }
    // The delay acts: in the period a new command is sent the valve still sees the old one
    // (τ = 1.55 T: the last substep of the period reads commands k − 2 and k − 1).
    plant.step(3.0).unwrap();
    let seen = plant.state().command;
    assert!((seen + 2.0).abs() < 1e-12, "valve command {seen} V");
}
