//! Every cycle of a run is in the MCAP file and reads back (Rust reader; the Python `mcap`
//! package and `@mcap/core` read the same files in tests/python).

use ehactl_runtime::session::{run_sim, SessionOptions};
use ehactl_tests::config;
use std::collections::BTreeMap;

#[test]
fn every_cycle_is_logged_and_the_run_is_deterministic() {
    let cfg = config("dindorf2022_boom.toml");
    let dir = std::env::temp_dir().join(format!("ehactl-test-{}", std::process::id()));
    let path = dir.join("boom.mcap");
    let s = run_sim(
        &cfg,
        SessionOptions {
            duration: Some(0.3),
            mcap: Some(path.clone()),
            capture: true,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(s.outcome.cycles, 1500);
    let bytes = std::fs::read(&path).unwrap();
    let mut counts: BTreeMap<String, u64> = BTreeMap::new();
    let mut seqs = Vec::new();
    let mut last_x = f64::NAN;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        *counts.entry(m.channel.topic.clone()).or_default() += 1;
        if m.channel.topic == "/control" {
            seqs.push(m.sequence);
            assert_eq!(m.data.len(), 4 + 8 + 16 * 8);
        }
        if m.channel.topic == "/plant" {
            let x = f64::from_le_bytes(m.data[4 + 7 * 8..4 + 8 * 8].try_into().unwrap());
            last_x = x;
        }
    }
    assert_eq!(counts["/control"], 1500);
    assert_eq!(counts["/plant"], 1500);
    assert_eq!(counts["/summary"], 1);
    assert!(counts["/events"] >= 2);
    assert!(seqs.iter().enumerate().all(|(i, s)| *s as usize == i));
    // The logged state equals the captured one (last cycle).
    assert_eq!(last_x, s.records.last().unwrap().plant.x);
    // Same config, same result: bit-identical rerun.
    let s2 = run_sim(
        &cfg,
        SessionOptions {
            duration: Some(0.3),
            capture: true,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(s.records, s2.records);
    std::fs::remove_dir_all(dir).ok();
}
