//! CAN round-trip latency through a bus (e.g. the `ehactl canbus hub`), as the ehactl
//! master sees it: (a) ping — a frame on 0x7E0 answered by a peer on 0x7E1 with the same
//! data; (b) an SDO expedited upload of 0x1000:00 from node `--node`. Prints one JSON
//! object with median / p99 / max in µs. Driven by bench/can_latency.py.
//!
//! `can_latency --bus socketcand://127.0.0.1:PORT/can0 [--n 2000] [--node 64] [--samples]`
//! (`--samples` adds the raw round trips in µs).

use ehactl_canopen::bus::BusUrl;
use ehactl_canopen::clock::MonotonicClock;
use ehactl_canopen::sdo::{transfer, SdoClient};
use ehactl_canopen::transport::open;
use ehactl_canopen::CanFrame;
use std::time::{Duration, Instant};

fn stats(mut v: Vec<f64>) -> String {
    v.sort_by(|a, b| a.total_cmp(b));
    let q = |p: f64| v[((v.len() as f64 - 1.0) * p).round() as usize];
    format!(
        "{{\"n\": {}, \"median_us\": {:.1}, \"p90_us\": {:.1}, \"p99_us\": {:.1}, \"max_us\": {:.1}, \"min_us\": {:.1}}}",
        v.len(),
        q(0.5),
        q(0.9),
        q(0.99),
        v[v.len() - 1],
        v[0]
    )
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let get = |k: &str| {
        args.iter()
            .position(|a| a == k)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let Some(bus) = get("--bus") else {
        eprintln!("usage: can_latency --bus URL [--n N] [--node ID]");
        std::process::exit(2);
    };
    let n: usize = get("--n").and_then(|s| s.parse().ok()).unwrap_or(2000);
    let node: u8 = get("--node").and_then(|s| s.parse().ok()).unwrap_or(64);
    let url = BusUrl::parse(&bus).unwrap_or_else(|e| {
        eprintln!("can_latency: {e}");
        std::process::exit(2)
    });
    let mut b = open(&url, Duration::from_secs(3)).unwrap_or_else(|e| {
        eprintln!("can_latency: {e}");
        std::process::exit(1)
    });
    let mut ping = Vec::with_capacity(n);
    let mut lost = 0usize;
    for i in 0..n + 50 {
        let seq = (i as u64).to_le_bytes();
        let f = CanFrame::std(0x7E0, seq);
        let t0 = Instant::now();
        b.send(&f).expect("send");
        let mut ok = false;
        while t0.elapsed() < Duration::from_millis(200) {
            match b.recv_timeout(Duration::from_millis(200)).expect("recv") {
                Some(r) if r.id == 0x7E1 && r.data == seq => {
                    ok = true;
                    break;
                }
                _ => {}
            }
        }
        let dt = t0.elapsed().as_secs_f64() * 1e6;
        if i >= 50 {
            if ok {
                ping.push(dt);
            } else {
                lost += 1;
            }
        }
    }
    let mut sdo = Vec::with_capacity(n);
    let clock = MonotonicClock::new();
    for i in 0..n + 50 {
        let mut c = SdoClient::new(node, Duration::from_millis(500));
        let req = c.upload(0x1000, 0);
        let t0 = Instant::now();
        transfer(&mut *b, &mut c, req, &clock, &mut |_, _| {}).expect("SDO upload");
        if i >= 50 {
            sdo.push(t0.elapsed().as_secs_f64() * 1e6);
        }
    }
    let raw = |v: &[f64]| {
        let s: Vec<String> = v.iter().map(|x| format!("{x:.1}")).collect();
        format!("[{}]", s.join(","))
    };
    let samples = if args.iter().any(|a| a == "--samples") {
        format!(
            ", \"ping_samples_us\": {}, \"sdo_samples_us\": {}",
            raw(&ping),
            raw(&sdo)
        )
    } else {
        String::new()
    };
    println!(
        "{{\"bus\": \"{url}\", \"ping\": {}, \"ping_lost\": {lost}, \"sdo_upload\": {}{samples}}}",
        stats(ping.clone()),
        stats(sdo.clone())
    );
}
