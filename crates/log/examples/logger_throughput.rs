//! Writer throughput of the MCAP logger alone (BENCHMARKS.md, "MCAP logger throughput"):
//! one producer pushes N cycle records as fast as it can (Block policy, as a simulated run
//! does), the writer thread encodes and writes them; the time from the first push to the
//! end of `finish` (file closed) over N is what the writer costs per record.
//!
//! Usage: `cargo run --release -p ehactl-log --example logger_throughput -- [N] [lz4|none] [OUT]`
//! (defaults 200000, lz4, $TMPDIR/ehactl_logger_throughput.mcap). Prints one JSON object;
//! `writer_cpu_us_per_record` is the process's CPU time minus this (producer) thread's, per
//! record: what the writer thread costs.
//! Records are synthetic but shaped like a simulated run's (smooth signals whose low
//! mantissa bits carry noise, so LZ4 finds as little to compress as in a real log).

use ehactl_log::logger::{LogCompression, LogOptions, Logger, Overflow, RunMetadata};
use ehactl_log::record::CycleRecord;
use std::time::Instant;

/// User + system CPU time (s) of the whole process (`libc::RUSAGE_SELF`: both threads) or
/// of the calling thread (`libc::RUSAGE_THREAD`).
fn cpu_time_s(who: libc::c_int) -> f64 {
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage only writes the struct it is given.
    unsafe { libc::getrusage(who, &mut ru) };
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

/// Cycle `k`'s record at `rate` (Hz): a 7 Hz sine on every channel with `noise` (uniform in
/// ±0.5) added, in magnitudes of the Sahu 2022 force rig (N, m, Pa, V).
fn fill(rec: &mut CycleRecord, k: u64, rate: f64, noise: &mut impl FnMut() -> f64) {
    let t = k as f64 / rate;
    let s = (2.0 * std::f64::consts::PI * 7.0 * t).sin();
    rec.cycle = k;
    rec.t = t;
    rec.setpoint = 785.0 + 196.0 * s;
    rec.setpoint_rate = 196.0 * 44.0 * (2.0 * std::f64::consts::PI * 7.0 * t).cos();
    rec.feedback = rec.setpoint + noise();
    rec.error = rec.setpoint - rec.feedback;
    rec.command = 0.5 * s + 1e-3 * noise();
    rec.command_unsat = rec.command;
    rec.p_term = 0.57 * rec.error;
    rec.i_term = rec.command - rec.p_term;
    rec.meas.t = t;
    rec.meas.force = rec.feedback;
    rec.meas.position = 1e-6 * s;
    rec.meas.p_a = 1.1e7 + 1e5 * s + noise();
    rec.meas.p_b = 0.9e7 - 1e5 * s + noise();
    rec.meas.spool = 0.05 * s;
    let p = &mut rec.plant;
    p.t = t;
    p.command = rec.command;
    p.spool = 0.05 * s + 1e-9 * noise();
    p.spool_velocity = 0.3 * s + noise();
    p.p_a = rec.meas.p_a + noise();
    p.p_b = rec.meas.p_b + noise();
    p.p_s = 2.1e7;
    p.x = rec.meas.position + 1e-12 * noise();
    p.v = 1e-4 * s + 1e-9 * noise();
    p.x_load = p.x;
    p.v_load = p.v;
    p.q_a = 1e-6 * s + 1e-12 * noise();
    p.q_b = -p.q_a;
    p.rod_force = rec.feedback + noise();
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: u64 = args
        .get(1)
        .map_or(200_000, |s| s.parse().expect("N: record count"));
    let compression = match args.get(2).map(String::as_str).unwrap_or("lz4") {
        "lz4" => LogCompression::Lz4,
        "none" => LogCompression::None,
        other => panic!("compression {other:?}: expected lz4 or none"),
    };
    let out = args
        .get(3)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("ehactl_logger_throughput.mcap"));
    let rate = 5000.0;
    let opts = LogOptions {
        compression,
        max_lag: (0.1 * rate) as usize,
        ..LogOptions::default()
    };
    assert_eq!(opts.overflow, Overflow::Block);
    let meta = RunMetadata {
        config_toml: String::new(),
        config_json: serde_json::json!({}),
        backend: "bench".into(),
        control_rate_hz: rate,
        config_schema: serde_json::json!({"type": "object"}),
    };
    let cpu0 = cpu_time_s(libc::RUSAGE_SELF);
    let main0 = cpu_time_s(libc::RUSAGE_THREAD);
    let t0 = Instant::now();
    let logger = Logger::create(&out, opts, &meta).expect("create log");
    let t_created = t0.elapsed().as_secs_f64();
    let mut rec = CycleRecord {
        has_plant: true,
        ..CycleRecord::default()
    };
    let mut lcg: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut noise = || {
        lcg = lcg
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (lcg >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let t_loop = Instant::now();
    for k in 0..n {
        fill(&mut rec, k, rate, &mut noise);
        logger.push(&rec);
    }
    let t_pushed = t_loop.elapsed().as_secs_f64();
    let stats = logger
        .finish(serde_json::json!({"bench": true}))
        .expect("finish log");
    let total = t0.elapsed().as_secs_f64();
    let cpu = cpu_time_s(libc::RUSAGE_SELF) - cpu0;
    // This thread made the records, pushed them and waited in `finish`: the rest of the
    // process's CPU is the writer thread's.
    let producer_cpu = cpu_time_s(libc::RUSAGE_THREAD) - main0;
    let size = std::fs::metadata(&out).map(|m| m.len()).unwrap_or(0);
    let obj = serde_json::json!({
        "records": n,
        "compression": format!("{compression:?}"),
        "create_s": t_created,
        "producer_s": t_pushed,
        "total_s": total,
        "us_per_record": total / n as f64 * 1e6,
        "records_per_s": n as f64 / total,
        "cpu_s": cpu,
        "cpu_us_per_record": cpu / n as f64 * 1e6,
        "producer_cpu_s": producer_cpu,
        "writer_cpu_us_per_record": (cpu - producer_cpu) / n as f64 * 1e6,
        "file_bytes": size,
        "bytes_per_record": size as f64 / n as f64,
        "records_written": stats.records_written,
        "records_dropped": stats.records_dropped,
        "pushes_waited": stats.pushes_waited,
        "queue_high_water": stats.queue_high_water,
        "queue_capacity": stats.queue_capacity,
    });
    println!("{obj}");
    assert_eq!(stats.records_written, n, "every record must be written");
    assert_eq!(stats.records_dropped, 0);
}
