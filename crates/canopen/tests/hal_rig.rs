//! `CanopenHal` against a scripted CANopen rig on the in-process hub: the exact start-up
//! sequence, closed data path (RPDO → SYNC → TPDO), and every fault of issue 5 detected
//! within one heartbeat timeout plus two SYNC periods.
//!
//! The scripted rig is a minimal CiA 301 slave pair written for this test (expedited SDO
//! server, NMT, heartbeat producer, SYNC-driven TPDOs, the simplified CiA 408 state
//! machine of the ICD); the full simulated devices with the plant are the Python ones.

use ehactl_canopen::cia408;
use ehactl_canopen::hal::{CanopenHal, CanopenSettings, StartupError};
use ehactl_canopen::hub::Hub;
use ehactl_canopen::sdo::SdoError;
use ehactl_canopen::socketcand::SocketcandBus;
use ehactl_canopen::{BusUrl, CanBus, CanFrame, CanopenConfig};
use ehactl_hal::{Hal, HalError};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Counts heap allocations made by the thread that has `ARMED` set (the control cycle).
struct CountingAlloc;

thread_local! {
    static ARMED: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}
static CYCLE_ALLOCS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

unsafe impl std::alloc::GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, l: std::alloc::Layout) -> *mut u8 {
        if ARMED.try_with(|a| a.get()).unwrap_or(false) {
            CYCLE_ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        std::alloc::System.alloc(l)
    }
    unsafe fn dealloc(&self, p: *mut u8, l: std::alloc::Layout) {
        std::alloc::System.dealloc(p, l)
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

const TR: u8 = 0x20;
const VA: u8 = 0x30;
/// Piston speed at 100 % spool in the scripted plant (m/s).
const V_FULL: f64 = 0.1;

#[derive(Default)]
struct Knobs {
    no_boot_valve: AtomicBool,
    silence_valve: AtomicBool,
    emcy: AtomicBool,
    leave_active: AtomicBool,
    malformed: AtomicBool,
    abort_index: AtomicU32,
    stop: AtomicBool,
    /// Every frame the rig received (id, data), for sequence checks.
    seen: Mutex<Vec<(u32, Vec<u8>)>>,
}

struct Node {
    id: u8,
    nmt: u8,
    od: HashMap<(u16, u8), Vec<u8>>,
    last_hb: Instant,
}

fn rig(port: u16, knobs: Arc<Knobs>) -> std::thread::JoinHandle<()> {
    let mut bus =
        SocketcandBus::connect("127.0.0.1", port, "can0", Duration::from_secs(2)).unwrap();
    std::thread::spawn(move || {
        let mut nodes = [TR, VA].map(|id| Node {
            id,
            nmt: 0,
            od: HashMap::new(),
            last_hb: Instant::now(),
        });
        nodes[0]
            .od
            .insert((0x1000, 0), 0x0001_0196u32.to_le_bytes().to_vec());
        nodes[1]
            .od
            .insert((0x1000, 0), 0x0001_0198u32.to_le_bytes().to_vec());
        let mut state: u16 = 0b001;
        let mut latched: i16 = 0;
        let mut spool: i16;
        let mut pos = 0.0f64;
        let mut emcy_sent = false;
        let mut malformed_sent = false;
        let send = |bus: &mut SocketcandBus, silent: bool, f: CanFrame| {
            if !silent {
                let _ = bus.send(&f);
            }
        };
        while !knobs.stop.load(Ordering::Relaxed) {
            let silent_va = knobs.silence_valve.load(Ordering::Relaxed);
            let now = Instant::now();
            for n in nodes.iter_mut() {
                let hb =
                    n.od.get(&(0x1017, 0))
                        .map_or(0, |v| u16::from_le_bytes([v[0], v[1]]));
                if n.nmt != 0
                    && hb > 0
                    && now.duration_since(n.last_hb) >= Duration::from_millis(u64::from(hb))
                {
                    n.last_hb = now;
                    let silent = n.id == VA && silent_va;
                    send(
                        &mut bus,
                        silent,
                        CanFrame::std(0x700 + u16::from(n.id), [n.nmt]),
                    );
                }
            }
            if knobs.emcy.load(Ordering::Relaxed) && !emcy_sent {
                emcy_sent = true;
                state = 0b1000;
                send(
                    &mut bus,
                    false,
                    CanFrame::std(0x080 + u16::from(VA), [0x00, 0x50, 0x01, 0, 0, 0, 0, 0]),
                );
            }
            if knobs.leave_active.load(Ordering::Relaxed) && state == 0b111 {
                state = 0b011;
            }
            if knobs.malformed.load(Ordering::Relaxed) && !malformed_sent {
                malformed_sent = true;
                send(
                    &mut bus,
                    false,
                    CanFrame::std(0x180 + u16::from(TR), [1, 2, 3]),
                );
                send(&mut bus, false, CanFrame::std(0x3FF, [0xAA]));
            }
            let Ok(Some(f)) = bus.recv_timeout(Duration::from_millis(1)) else {
                continue;
            };
            knobs
                .seen
                .lock()
                .unwrap()
                .push((f.id, f.payload().to_vec()));
            match f.id {
                0x000 => {
                    let (cmd, target) = (f.data[0], f.data[1]);
                    for n in nodes.iter_mut().filter(|n| target == 0 || target == n.id) {
                        match cmd {
                            0x81 | 0x82 => {
                                let silent =
                                    n.id == VA && knobs.no_boot_valve.load(Ordering::Relaxed);
                                if !silent {
                                    n.nmt = 0x7F;
                                    send(
                                        &mut bus,
                                        false,
                                        CanFrame::std(0x700 + u16::from(n.id), [0]),
                                    );
                                }
                            }
                            0x01 => n.nmt = 5,
                            0x02 => n.nmt = 4,
                            0x80 => n.nmt = 0x7F,
                            _ => {}
                        }
                    }
                }
                0x080 if f.dlc == 0 => {
                    if nodes[1].nmt == 5 {
                        spool = if state == 0b111 { latched } else { 0 };
                        pos += f64::from(spool) / 16384.0 * V_FULL * 1e-3;
                        let sw = state;
                        send(&mut bus, silent_va, {
                            let mut d = [0u8; 4];
                            d[..2].copy_from_slice(&sw.to_le_bytes());
                            d[2..].copy_from_slice(&spool.to_le_bytes());
                            CanFrame::std(0x180 + u16::from(VA), d)
                        });
                    }
                    if nodes[0].nmt == 5 {
                        let steps = (pos * 1e6).round() as i32; // 1000 nm steps
                        send(
                            &mut bus,
                            false,
                            CanFrame::std(0x180 + u16::from(TR), steps.to_le_bytes()),
                        );
                    }
                }
                id if id == 0x200 + u32::from(VA) && f.dlc == 2 && nodes[1].nmt == 5 => {
                    latched = i16::from_le_bytes([f.data[0], f.data[1]]);
                }
                id if (0x600..0x680).contains(&id) => {
                    let Some(k) = nodes.iter().position(|n| u32::from(n.id) == id - 0x600) else {
                        continue;
                    };
                    let node = nodes[k].id;
                    let silent = node == VA && silent_va;
                    let index = u16::from_le_bytes([f.data[1], f.data[2]]);
                    let sub = f.data[3];
                    let cs = f.data[0];
                    let reply = |cs: u8, data: &[u8]| {
                        let mut d = [cs, f.data[1], f.data[2], sub, 0, 0, 0, 0];
                        d[4..4 + data.len()].copy_from_slice(data);
                        CanFrame::std(0x580 + u16::from(node), d)
                    };
                    if cs & 0xE0 == 0x20 {
                        if node == VA
                            && u32::from(index) == knobs.abort_index.load(Ordering::Relaxed)
                        {
                            send(&mut bus, silent, reply(0x80, &0x0609_0030u32.to_le_bytes()));
                            continue;
                        }
                        let n = 4 - usize::from((cs >> 2) & 3);
                        let v = f.data[4..4 + n].to_vec();
                        if node == VA && index == 0x6040 {
                            let cw = u16::from_le_bytes([v[0], v[1]]);
                            state = match (state, cw) {
                                (0b1000, c) if c & 0x08 != 0 => 0b001,
                                (0b1000, _) => 0b1000,
                                (_, c) if c & 1 == 0 => 0b001,
                                (0b001 | 0b011 | 0b111, 0x03) => 0b011,
                                (0b011 | 0b111, 0x07) => 0b111,
                                (s, _) => s,
                            };
                        }
                        nodes[k].od.insert((index, sub), v);
                        if index == 0x1017 {
                            nodes[k].last_hb = Instant::now();
                        }
                        send(&mut bus, silent, reply(0x60, &[]));
                    } else if cs == 0x40 {
                        let v = if node == VA && index == 0x6041 {
                            Some(state.to_le_bytes().to_vec())
                        } else {
                            nodes[k].od.get(&(index, sub)).cloned()
                        };
                        match v {
                            Some(v) if v.len() <= 4 => {
                                let cs = 0x43 | (((4 - v.len()) as u8) << 2);
                                send(&mut bus, silent, reply(cs, &v));
                            }
                            _ => send(&mut bus, silent, reply(0x80, &0x0602_0000u32.to_le_bytes())),
                        }
                    }
                }
                _ => {}
            }
        }
    })
}

fn start() -> (u16, Arc<Knobs>) {
    let hub = Hub::bind("127.0.0.1:0", true).unwrap();
    let port = hub.local_addr().unwrap().port();
    std::thread::spawn(move || hub.serve());
    (port, Arc::new(Knobs::default()))
}

fn settings(port: u16, cfg: CanopenConfig) -> CanopenSettings {
    CanopenSettings {
        bus: BusUrl::parse(&format!("socketcand://127.0.0.1:{port}/can0")).unwrap(),
        canopen: cfg,
        command_full_scale: 10.0,
        control_rate_hz: 2000.0,
        verbose: false,
    }
}

/// Drive the HAL against the wall clock at 2 kHz with `command` (V) until `secs` (s) or a
/// fault; calls `at` with the loop time before each cycle. Returns (last position, t, error).
fn drive(
    hal: &mut CanopenHal,
    secs: f64,
    command: f64,
    at: &mut dyn FnMut(f64),
) -> (f64, f64, Option<HalError>) {
    let dt = 1.0 / 2000.0;
    let t0 = Instant::now();
    let mut pos = f64::NAN;
    let mut k = 0u64;
    loop {
        let t = k as f64 * dt;
        if t > secs {
            return (pos, t, None);
        }
        let due = t0 + Duration::from_secs_f64(t);
        if let Some(w) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(w);
        }
        at(t);
        // Count allocations of read/write from the second cycle on (the first hands the
        // start-up frames to the log queue).
        ARMED.with(|a| a.set(k > 0));
        let r = hal.read(t, dt);
        let w = r.as_ref().ok().map(|_| hal.write(t, dt, command));
        ARMED.with(|a| a.set(false));
        match r {
            Ok(m) => pos = m.position,
            Err(e) => return (pos, t, Some(e)),
        }
        if let Some(Err(e)) = w {
            return (pos, t, Some(e));
        }
        k += 1;
    }
}

#[test]
fn start_up_sequence_and_closed_data_path() {
    let (port, knobs) = start();
    let rig_thread = rig(port, knobs.clone());
    let mut hal = CanopenHal::connect(settings(port, CanopenConfig::default())).unwrap();
    // The configuration the ICD prescribes, in order (subsequence of what the rig saw).
    let seen = knobs.seen.lock().unwrap().clone();
    let want: Vec<(u32, Vec<u8>)> = vec![
        (0x000, vec![0x82, TR]),
        (0x000, vec![0x82, VA]),
        (0x000, vec![0x80, TR]),
        (0x620, vec![0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]),
        (0x620, vec![0x2B, 0x17, 0x10, 0x00, 20, 0, 0, 0]),
        (0x620, vec![0x23, 0x05, 0x60, 0x01, 0xE8, 0x03, 0, 0]),
        (0x620, vec![0x23, 0x00, 0x18, 0x01, 0xA0, 0x01, 0x00, 0x80]),
        (0x620, vec![0x2F, 0x00, 0x1A, 0x00, 0, 0, 0, 0]),
        (0x620, vec![0x23, 0x00, 0x1A, 0x01, 0x20, 0x01, 0x20, 0x60]),
        (0x620, vec![0x2F, 0x00, 0x1A, 0x00, 1, 0, 0, 0]),
        (0x620, vec![0x23, 0x00, 0x18, 0x01, 0xA0, 0x01, 0x00, 0x00]),
        (0x630, vec![0x2F, 0x42, 0x60, 0x00, 1, 0, 0, 0]),
        (0x630, vec![0x23, 0x00, 0x16, 0x01, 0x10, 0x01, 0x00, 0x63]),
        (0x630, vec![0x23, 0x00, 0x1A, 0x02, 0x10, 0x01, 0x01, 0x63]),
        (0x000, vec![0x01, TR]),
        (0x630, vec![0x2B, 0x40, 0x60, 0x00, 0x03, 0x00, 0, 0]),
        (0x630, vec![0x2B, 0x40, 0x60, 0x00, 0x07, 0x00, 0, 0]),
        (0x230, vec![0x00, 0x00]),
        (0x080, vec![]),
    ];
    let mut it = seen.iter();
    for w in &want {
        assert!(
            it.any(|s| s == w),
            "expected {:03X} {:02X?} in order; rig saw {:?}",
            w.0,
            w.1,
            seen.iter()
                .map(|(i, d)| format!("{i:03X} {d:02X?}"))
                .collect::<Vec<_>>()
        );
    }
    // +5 V = +50 % spool → the scripted piston moves at 0.05 m/s.
    let before = CYCLE_ALLOCS.load(Ordering::Relaxed);
    let (pos, t, err) = drive(&mut hal, 0.6, 5.0, &mut |_| {});
    assert!(err.is_none(), "{err:?}");
    assert_eq!(
        CYCLE_ALLOCS.load(Ordering::Relaxed) - before,
        0,
        "read/write allocated in the cycle"
    );
    let expect = 0.5 * V_FULL * t;
    assert!(
        pos > 0.0 && (pos - expect).abs() < 0.25 * expect,
        "position {pos} m, expected ≈ {expect} m"
    );
    let rep = hal.report().unwrap();
    assert!(rep["syncs_sent"].as_u64().unwrap() >= 550, "{rep}");
    hal.safe_stop(0.0).unwrap();
    // Safe stop ends with setpoint 0 and control word HOLD.
    let seen = knobs.seen.lock().unwrap().clone();
    let tail: Vec<_> = seen.iter().rev().take(8).cloned().collect();
    assert!(tail.contains(&(0x230, vec![0, 0])), "{tail:?}");
    assert!(
        tail.contains(&(0x630, vec![0x2B, 0x40, 0x60, 0x00, 0x03, 0x00, 0, 0])),
        "{tail:?}"
    );
    knobs.stop.store(true, Ordering::Relaxed);
    rig_thread.join().unwrap();
}

fn fault_case(set: fn(&Knobs), expect: &str) -> f64 {
    let (port, knobs) = start();
    let rig_thread = rig(port, knobs.clone());
    let cfg = CanopenConfig::default();
    let mut hal = CanopenHal::connect(settings(port, cfg.clone())).unwrap();
    let mut fault_t = f64::NAN;
    let (_, t, err) = drive(&mut hal, 2.0, 1.0, &mut |t| {
        if t >= 0.3 && fault_t.is_nan() {
            fault_t = t;
            set(&knobs);
        }
    });
    let Some(HalError::Device { what, .. }) = err else {
        panic!("no trip for {expect}: {err:?}")
    };
    assert!(what.contains(expect), "{what} vs {expect}");
    let _ = hal.safe_stop(0.0);
    knobs.stop.store(true, Ordering::Relaxed);
    rig_thread.join().unwrap();
    let delay = t - fault_t;
    let bound = f64::from(cfg.heartbeat_timeout_ms) * 1e-3 + 2.0 / cfg.sync_rate_hz;
    eprintln!(
        "{expect}: detected {:.1} ms after the fault (bound {:.1} ms)",
        delay * 1e3,
        bound * 1e3
    );
    // Scheduling slack for a loaded 2-core CI machine: 25 ms.
    assert!(delay <= bound + 0.025, "{expect}: {delay} s > {bound} s");
    delay
}

#[test]
fn heartbeat_loss_trips_within_timeout_plus_two_syncs() {
    let d = fault_case(
        |k| k.silence_valve.store(true, Ordering::Relaxed),
        "valve heartbeat lost",
    );
    // Not before the consumer time minus one producer period (the last heartbeat may be 20 ms old).
    assert!(d >= 0.040 - 0.001, "{d}");
}

#[test]
fn emcy_trips_at_once() {
    fault_case(
        |k| k.emcy.store(true, Ordering::Relaxed),
        "EMCY from the valve",
    );
}

#[test]
fn valve_leaving_active_trips_within_one_sync() {
    let d = fault_case(
        |k| k.leave_active.store(true, Ordering::Relaxed),
        "valve left ACTIVE",
    );
    assert!(d < 0.025, "{d}");
}

#[test]
fn malformed_frames_are_counted_and_ignored() {
    let (port, knobs) = start();
    let rig_thread = rig(port, knobs.clone());
    let mut hal = CanopenHal::connect(settings(port, CanopenConfig::default())).unwrap();
    let (_, _, err) = drive(&mut hal, 0.5, 1.0, &mut |t| {
        if t >= 0.1 {
            knobs.malformed.store(true, Ordering::Relaxed);
        }
    });
    assert!(err.is_none(), "{err:?}");
    let rep = hal.report().unwrap();
    assert_eq!(rep["can_wrong_dlc"], 1, "{rep}");
    assert_eq!(rep["can_unknown_cob_id"], 1, "{rep}");
    let _ = hal.safe_stop(0.0);
    knobs.stop.store(true, Ordering::Relaxed);
    rig_thread.join().unwrap();
}

#[test]
fn sdo_abort_at_configuration_names_step_object_and_meaning() {
    let (port, knobs) = start();
    knobs.abort_index.store(0x1600, Ordering::Relaxed);
    let rig_thread = rig(port, knobs.clone());
    let e = CanopenHal::connect(settings(port, CanopenConfig::default())).unwrap_err();
    let StartupError::Sdo {
        error: SdoError::Abort {
            node, index, code, ..
        },
        ..
    } = &e
    else {
        panic!("{e}")
    };
    assert_eq!((*node, *index, *code), (VA, 0x1600, 0x0609_0030));
    let msg = e.to_string();
    assert!(
        msg.contains("valve RPDO1") && msg.contains("invalid value for parameter"),
        "{msg}"
    );
    knobs.stop.store(true, Ordering::Relaxed);
    rig_thread.join().unwrap();
}

#[test]
fn a_device_that_never_boots_is_named() {
    let (port, knobs) = start();
    knobs.no_boot_valve.store(true, Ordering::Relaxed);
    let rig_thread = rig(port, knobs.clone());
    let cfg = CanopenConfig {
        boot_timeout_s: 0.3,
        ..Default::default()
    };
    let t0 = Instant::now();
    let e = CanopenHal::connect(settings(port, cfg)).unwrap_err();
    assert!(
        matches!(
            e,
            StartupError::NoBoot {
                node: VA,
                device: "valve",
                ..
            }
        ),
        "{e}"
    );
    assert!(t0.elapsed() >= Duration::from_millis(300) && t0.elapsed() < Duration::from_secs(2));
    knobs.stop.store(true, Ordering::Relaxed);
    rig_thread.join().unwrap();
}

#[test]
fn connection_drop_trips_on_the_next_cycle() {
    // A relay we can kill: the master connects through a TCP proxy in front of the hub.
    let (port, knobs) = start();
    let rig_thread = rig(port, knobs.clone());
    let proxy = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let pport = proxy.local_addr().unwrap().port();
    let kill = Arc::new(AtomicBool::new(false));
    let k2 = kill.clone();
    std::thread::spawn(move || {
        let (client, _) = proxy.accept().unwrap();
        let upstream = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        let pipe =
            |mut a: std::net::TcpStream, mut b: std::net::TcpStream, kill: Arc<AtomicBool>| {
                std::thread::spawn(move || {
                    let mut buf = [0u8; 4096];
                    a.set_read_timeout(Some(Duration::from_millis(5))).unwrap();
                    loop {
                        if kill.load(Ordering::Relaxed) {
                            let _ = a.shutdown(std::net::Shutdown::Both);
                            let _ = b.shutdown(std::net::Shutdown::Both);
                            return;
                        }
                        match std::io::Read::read(&mut a, &mut buf) {
                            Ok(0) => return,
                            Ok(n) => {
                                if std::io::Write::write_all(&mut b, &buf[..n]).is_err() {
                                    return;
                                }
                            }
                            Err(_) => {}
                        }
                    }
                })
            };
        pipe(
            client.try_clone().unwrap(),
            upstream.try_clone().unwrap(),
            k2.clone(),
        );
        pipe(upstream, client, k2);
    });
    let mut hal = CanopenHal::connect(settings(pport, CanopenConfig::default())).unwrap();
    let mut fault_t = f64::NAN;
    let (_, t, err) = drive(&mut hal, 2.0, 1.0, &mut |t| {
        if t >= 0.3 && fault_t.is_nan() {
            fault_t = t;
            kill.store(true, Ordering::Relaxed);
        }
    });
    assert!(
        matches!(
            err,
            Some(HalError::Device {
                what: "CAN bus connection lost",
                ..
            })
        ),
        "{err:?}"
    );
    assert!(t - fault_t < 0.05, "{}", t - fault_t);
    assert!(
        hal.safe_stop(0.0).is_err(),
        "HOLD cannot be confirmed without a bus"
    );
    knobs.stop.store(true, Ordering::Relaxed);
    rig_thread.join().unwrap();
    let _ = cia408::CW_HOLD_STATE;
}
