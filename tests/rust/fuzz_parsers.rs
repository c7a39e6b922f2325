//! Fuzz targets for every parser that takes outside input: config TOML, data CSV,
//! MCAP input (diagnose and `ehactl recover`), control-socket requests, socketcand lines and
//! CAN frames / SDO responses into the master. Property-based (proptest): random bytes and
//! structured mutations of valid inputs; the property is "a clear error or a valid result,
//! never a panic, never a hang (per-case timeout), never a NaN accepted as valid".
//!
//! CI runs each target for `PROPTEST_CASES` cases (256 by default; a few seconds each). The
//! long runs in BENCHMARKS.md use e.g. `PROPTEST_CASES=20000 cargo test --release -p
//! ehactl-tests --test fuzz_parsers`.

use ehactl_canopen::frame::CanFrame;
use ehactl_canopen::sdo::{SdoClient, SdoStep};
use ehactl_canopen::socketcand::{self, Framer};
use ehactl_config::RigConfig;
use ehactl_runtime::control_socket;
use ehactl_runtime::session::{build_plant, run_sim, SessionOptions};
use ehactl_tests::repo;
use proptest::prelude::*;
use std::sync::OnceLock;
use std::time::Duration;

fn cfg() -> ProptestConfig {
    ProptestConfig {
        // Each case must finish within this (ms): a hang fails the target. Generous: a
        // mutant may legally cost 10 000 substeps × 200 line segments per cycle, and CI
        // machines are shared.
        timeout: 60_000,
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

fn shipped_configs() -> &'static Vec<String> {
    static C: OnceLock<Vec<String>> = OnceLock::new();
    C.get_or_init(|| {
        let mut v: Vec<_> = std::fs::read_dir(repo().join("configs"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .collect();
        v.sort();
        v.iter()
            .map(|p| std::fs::read_to_string(p).unwrap())
            .collect()
    })
}

/// Values a hostile or careless user writes into a TOML field.
fn hostile_value() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("0".to_string()),
        Just("-1".to_string()),
        Just("1e308".to_string()),
        Just("-1e308".to_string()),
        Just("5e-324".to_string()),
        Just("nan".to_string()),
        Just("inf".to_string()),
        Just("-inf".to_string()),
        Just("9223372036854775807".to_string()),
        Just("\"text\"".to_string()),
        Just("[1.0, 2.0]".to_string()),
        Just("[]".to_string()),
        Just("true".to_string()),
        Just("{ a = 1 }".to_string()),
        any::<f64>().prop_map(|v| format!("{v:e}")),
        (-1e6f64..1e6).prop_map(|v| format!("{v}")),
    ]
}

/// Run a config that validated for a few cycles: it must end (trip or complete) with
/// finite figures for the cycles it ran.
fn run_briefly(c: &RigConfig) {
    let dt = c.timebase().period();
    let s = run_sim(
        c,
        SessionOptions {
            duration: Some(5.0 * dt),
            mcap: None,
            capture: true,
            ..Default::default()
        },
    )
    .expect("a validated config must run");
    if s.outcome.trip.is_none() {
        for r in &s.records {
            assert!(r.command.is_finite(), "non-finite command without a trip");
        }
    }
}

proptest! {
    #![proptest_config(cfg())]

    /// Arbitrary text: an error or a config, never a panic.
    #[test]
    fn config_toml_arbitrary_text(text in "\\PC{0,400}") {
        let _ = RigConfig::from_toml_str(&text);
    }

    /// One field of a shipped config replaced by a hostile value (the review's 690-mutant
    /// probe as a property): an error naming a field, or a config that builds and runs.
    #[test]
    fn config_toml_field_mutants(which in 0usize..64, line in 0usize..400, value in hostile_value()) {
        let configs = shipped_configs();
        let text = &configs[which % configs.len()];
        let lines: Vec<&str> = text.lines().collect();
        let assign: Vec<usize> = lines
            .iter()
            .enumerate()
            .filter(|(_, l)| {
                let t = l.trim_start();
                !t.starts_with('#') && !t.starts_with('[') && t.contains('=')
            })
            .map(|(i, _)| i)
            .collect();
        let i = assign[line % assign.len()];
        let key = lines[i].split('=').next().unwrap().trim();
        let mut out: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
        out[i] = format!("{key} = {value}");
        match RigConfig::from_toml_str(&out.join("\n")) {
            Err(e) => prop_assert!(!e.to_string().is_empty()),
            Ok(c) => {
                if build_plant(&c).is_ok() {
                    run_briefly(&c);
                }
            }
        }
    }

    /// Arbitrary CSV text, and well-formed CSV with extreme numbers: an error or a record
    /// whose unit checks return (never panic).
    #[test]
    fn data_csv(text in "\\PC{0,300}",
                rows in proptest::collection::vec(proptest::collection::vec(any::<f64>(), 4), 0..40),
                dt in prop_oneof![Just(1e-3), Just(1.0), Just(0.0), Just(-1e-3), any::<f64>()]) {
        let _ = ehactl_ident::data::parse_csv("fuzz.csv", &text);
        let mut csv = String::from("t,u,x,p_a\n");
        for (k, r) in rows.iter().enumerate() {
            csv.push_str(&format!("{},{},{},{}\n", k as f64 * dt, r[0], r[1], r[2]));
        }
        if let Ok(rec) = ehactl_ident::data::parse_csv("fuzz.csv", &csv) {
            let rig = ehactl_ident_eval::synth::testrig();
            let _ = ehactl_ident::data::check_against(&rec, &rig.plant, rig.timebase().period());
        }
    }

    /// A valid ehactl log with bytes flipped and cut at a random point: diagnose's reader
    /// and `ehactl recover` give an error or a valid result; a recovered file always reads
    /// back with its CRCs.
    #[test]
    fn mcap_input(cut in 0usize..200_000, flips in proptest::collection::vec((0usize..200_000, any::<u8>()), 0..4)) {
        let mut bytes = sample_log().clone();
        for (pos, b) in flips {
            let n = bytes.len();
            bytes[pos % n] ^= b;
        }
        bytes.truncate(cut.min(bytes.len()));
        let _ = ehactl_ident::data::parse_mcap("fuzz.mcap", &bytes);
        let dir = tempdir();
        let input = dir.join("in.mcap");
        let output = dir.join("out.mcap");
        std::fs::write(&input, &bytes).unwrap();
        if ehactl_log::recover::recover(&input, &output).is_ok() {
            let data = std::fs::read(&output).unwrap();
            for m in mcap::MessageStream::new(&data).expect("recovered file opens") {
                m.expect("recovered message reads");
            }
            prop_assert!(mcap::Summary::read(&data).expect("summary").is_some());
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A control-socket request line through the server's own parser and validation: a
    /// clear error, or a config that validates.
    #[test]
    fn control_socket_requests(line in prop_oneof![
        "\\PC{0,200}",
        ("(control\\.pi\\.(kp|integral|u_min|u_max|tracking)|setpoint\\.(offset|amplitude|f0|f1|steps)|supervisor\\.max_force|x)",
         hostile_value()).prop_map(|(p, v)| format!("set {p}={v}")),
    ]) {
        let cfg = ehactl_tests::config("sahu2022_force.toml");
        match control_socket::parse_request(&line, &cfg) {
            Ok((trial, _)) => prop_assert!(trial.validate().is_ok()),
            Err(e) => prop_assert!(!e.is_empty()),
        }
    }

    /// socketcand byte stream: framing and both message parsers; a frame that parses
    /// formats back to a message that parses to the same frame.
    #[test]
    fn socketcand_lines(chunks in proptest::collection::vec(prop_oneof![
            "\\PC{0,80}".prop_map(|s| s.into_bytes()),
            proptest::collection::vec(any::<u8>(), 0..80),
            ("[0-9A-Fa-f]{1,9}", "[0-9]{1,3}\\.[0-9]{1,6}", "[0-9A-F]{0,20}")
                .prop_map(|(id, t, d)| format!("< frame {id} {t} {d} >").into_bytes()),
            ("[0-9A-Fa-f]{1,9}", 0u8..12, "( [0-9A-F]{1,2}){0,10}")
                .prop_map(|(id, n, d)| format!("< send {id} {n}{d} >").into_bytes()),
        ], 0..12)) {
        let mut fr = Framer::new();
        for c in &chunks {
            fr.push(c);
            for _ in 0..64 {
                let msg = match fr.next_message() {
                    Ok(Some(m)) => m.to_string(),
                    Ok(None) | Err(_) => break,
                };
                if let Ok((f, _)) = socketcand::parse_frame(&msg) {
                    let back = socketcand::format_frame(&f, Duration::from_micros(1));
                    let (g, _) = socketcand::parse_frame(back.as_str()).expect("own format parses");
                    prop_assert_eq!(f, g);
                }
                if let Ok(f) = socketcand::parse_send(&msg) {
                    let back = socketcand::format_send(&f);
                    let g = socketcand::parse_send(back.as_str()).expect("own format parses");
                    prop_assert_eq!(f, g);
                }
            }
        }
    }

    /// CAN frames into the master: SDO responses to an upload / download in progress,
    /// heartbeats, EMCY, valve status words and transducer values from arbitrary frames.
    #[test]
    fn can_frames_into_the_master(frames in proptest::collection::vec(
            (prop_oneof![Just(0x5A0u32), Just(0x5B0), Just(0x720), Just(0x0A0), 0u32..0x800], proptest::collection::vec(any::<u8>(), 0..9)),
            1..24),
            upload in any::<bool>()) {
        let mut sdo = SdoClient::new(0x20, Duration::from_millis(50));
        let _first = if upload { sdo.upload(0x1018, 1) } else { sdo.download(0x6005, 0, &[1, 2, 3, 4, 5, 6, 7]) };
        for (id, data) in &frames {
            let Some(f) = CanFrame::new(*id, data) else { continue };
            if sdo.busy()
                && sdo.on_frame(&f) == SdoStep::Done { let _ = sdo.data(); }
            let _ = ehactl_canopen::nmt::parse_error_control(&f);
            let _ = ehactl_canopen::emcy::Emcy::parse((id & 0x7F) as u8, f.payload());
            if f.payload().len() >= 2 {
                let sw = u16::from_le_bytes([f.payload()[0], f.payload()[1]]);
                let _ = ehactl_canopen::cia408::ValveState::from_status(sw);
                let s = i16::from_le_bytes([f.payload()[0], f.payload()[1]]);
                prop_assert!(ehactl_canopen::cia408::command_from_setpoint(s, 10.0).is_finite());
            }
            if f.payload().len() >= 4 {
                let raw = i32::from_le_bytes([f.payload()[0], f.payload()[1], f.payload()[2], f.payload()[3]]);
                prop_assert!(ehactl_canopen::cia406::position_m(raw, 1000).is_finite());
            }
        }
        let _ = sdo.process(1_000_000_000);
    }
}

/// A real ehactl log (0.2 s of the Sahu 2022 rig) for the MCAP target, made once.
fn sample_log() -> &'static Vec<u8> {
    static L: OnceLock<Vec<u8>> = OnceLock::new();
    L.get_or_init(|| {
        let dir = tempdir();
        let path = dir.join("sample.mcap");
        let mut cfg = ehactl_tests::config("sahu2022_force.toml");
        cfg.log.chunk_interval = 0.02;
        run_sim(
            &cfg,
            SessionOptions {
                duration: Some(0.2),
                mcap: Some(path.clone()),
                capture: false,
                ..Default::default()
            },
        )
        .unwrap();
        let b = std::fs::read(&path).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        b
    })
}

fn tempdir() -> std::path::PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let d = std::env::temp_dir().join(format!(
        "ehactl-fuzz-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Every assignment of every shipped config set to each extreme number in turn
/// (deterministic companion of `config_toml_field_mutants`, which samples them at random):
/// an error naming a field, or a config that builds and runs 5 cycles. Found by CI:
/// `mechanics.mass = 5e-324` on the ideko rig made the exact discretisation's balancing loop
/// spin forever; `damping_ratio = 1.6e53` (crane cycle) hung nalgebra's matrix exponential.
#[test]
fn config_extreme_numbers_in_every_field() {
    // 1e53: finite, but its 8th power overflows (nalgebra expm asked for 2⁶⁴ squarings).
    let extremes = ["0", "-1", "5e-324", "1e-53", "1e53", "1e308", "-1e308"];
    for text in shipped_configs() {
        let lines: Vec<&str> = text.lines().collect();
        for (i, l) in lines.iter().enumerate() {
            let t = l.trim_start();
            if t.starts_with('#') || t.starts_with('[') || !t.contains('=') {
                continue;
            }
            let key = l.split('=').next().unwrap().trim();
            for v in extremes {
                let mut out: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
                out[i] = format!("{key} = {v}");
                match RigConfig::from_toml_str(&out.join("\n")) {
                    Err(e) => assert!(!e.to_string().is_empty()),
                    Ok(c) => {
                        if build_plant(&c).is_ok() {
                            run_briefly(&c);
                        }
                    }
                }
            }
        }
    }
}
