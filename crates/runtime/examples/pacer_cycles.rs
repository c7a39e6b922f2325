//! The wall-clock pacer's `wait_for_cycle` alone, on a scripted clock (no sleep, no system
//! call after the first cycle), for instruction counts under cachegrind:
//! `valgrind --tool=cachegrind --cache-sim=no target/fast/examples/pacer_cycles N` at two N,
//! the difference over the difference of N = instructions per cycle (BENCHMARKS.md).
//! Every cycle works 150 µs of a 200 µs period; every 50th works 450 µs (an overrun, skipped
//! deadlines) and every 70th is preempted 300 µs (an overrun not of its own making).
use ehactl_hal::clock::ScriptedClock;
use ehactl_hal::Timebase;
use ehactl_runtime::realtime::{RtOptions, WallClockPacer};

fn main() {
    let n: u64 = std::env::args()
        .nth(1)
        .map_or(Ok(10_000), |s| s.parse())
        .unwrap_or_else(|e| {
            eprintln!("pacer_cycles N: N is the number of cycles ({e})");
            std::process::exit(2)
        });
    let mut pacer = WallClockPacer::with_clock(
        Timebase::at_rate_hz(5e3),
        RtOptions::default(),
        ScriptedClock::at(1_000_000),
    );
    let mut ran = 0u64;
    for k in 0..n {
        if !ehactl_hal::pacer::Pacer::wait_for_cycle(&mut pacer, k) {
            break;
        }
        ran += 1;
        let clock = pacer.clock();
        clock.work(if k % 50 == 49 { 450_000 } else { 150_000 });
        if k % 70 == 69 {
            clock.preempted(300_000);
        }
    }
    let t = pacer.timing_report();
    println!(
        "{ran} cycles, {} overruns ({} ours), {} deadlines skipped",
        t.overruns, t.overruns_exec, t.skipped_deadlines
    );
}
