//! The `[canopen]` section: defaults, round trip through TOML, registry coverage, bus-load
//! refusal with the worst-case bit-stuffing formula.

use ehactl_config::RigConfig;
use ehactl_types::canopen::{canopen_params, frame_bits, CanopenConfig};

fn boom() -> String {
    let p =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/dindorf2022_boom.toml");
    std::fs::read_to_string(p).unwrap()
}

#[test]
fn section_is_optional_with_icd_defaults() {
    let cfg = RigConfig::from_toml_str(&boom()).unwrap();
    assert_eq!(cfg.canopen, CanopenConfig::default());
    let c = &cfg.canopen;
    assert_eq!(
        (
            c.bitrate,
            c.heartbeat_ms,
            c.heartbeat_timeout_ms,
            c.sdo_timeout_ms
        ),
        (1_000_000, 20, 60, 500)
    );
    assert_eq!(
        (c.transducer_node_id, c.valve_node_id, c.position_step_nm),
        (32, 48, 1000)
    );
    assert!(c.valve_status_pdo && c.sync_rate_hz == 1000.0 && c.boot_timeout_s == 3.0);
}

#[test]
fn custom_values_round_trip_through_toml() {
    let text = boom()
        + "\n[canopen]\nbitrate = 500000\nsync_rate_hz = 500\nheartbeat_ms = 50\nheartbeat_timeout_ms = 150\nvalve_node_id = 5\nvalve_status_pdo = false\n";
    let cfg = RigConfig::from_toml_str(&text).unwrap();
    assert_eq!(cfg.canopen.bitrate, 500_000);
    assert_eq!(cfg.canopen.valve_node_id, 5);
    assert!(!cfg.canopen.valve_status_pdo);
    let again = RigConfig::from_toml_str(&cfg.to_toml_string()).unwrap();
    assert_eq!(again, cfg);
}

#[test]
fn every_field_is_in_the_registry_with_a_unit() {
    let v = toml::Value::try_from(CanopenConfig::default()).unwrap();
    let keys: Vec<String> = v
        .as_table()
        .unwrap()
        .keys()
        .map(|k| format!("canopen.{k}"))
        .collect();
    assert_eq!(keys.len(), canopen_params().len());
    for k in &keys {
        let p = canopen_params()
            .iter()
            .find(|p| p.path == k)
            .unwrap_or_else(|| panic!("{k} not in registry"));
        assert!(!p.unit.is_empty() && !p.description.is_empty());
    }
    assert!(ehactl_config::registries()
        .iter()
        .any(|t| t.iter().any(|p| p.path == "canopen.sync_rate_hz")));
}

#[test]
fn bus_load_limit_follows_the_formula() {
    // Largest SYNC rate at 80 % on 1 Mbit/s with the default set (SYNC, 4, 2, 4 bytes).
    let per_sync: u32 = [0, 4, 2, 4].into_iter().map(frame_bits).sum();
    let hb = 3.0 * f64::from(frame_bits(1)) / 0.020; // 2 devices + ehactl, every 20 ms
    let f_max = (0.8e6 - hb) / f64::from(per_sync);
    let ok = boom() + &format!("\n[canopen]\nsync_rate_hz = {}\n", (f_max - 1.0).floor());
    assert!(RigConfig::from_toml_str(&ok).is_ok());
    let bad = boom() + &format!("\n[canopen]\nsync_rate_hz = {}\n", (f_max + 1.0).ceil());
    let e = RigConfig::from_toml_str(&bad).unwrap_err();
    assert_eq!(e.path, "canopen.sync_rate_hz");
    assert!(e.message.contains("exceeds 80 %"), "{e}");
    let e = RigConfig::from_toml_str(&(boom() + "\n[canopen]\nvalve_status_pdo = \"yes\"\n"))
        .unwrap_err();
    assert_eq!(e.path, "canopen.valve_status_pdo");
    assert!(e.message.contains("expected true or false"), "{e}");
}

#[test]
fn safe_command_outside_the_valve_range_is_refused() {
    // Found in review: -1e9 V passed check-config and saturated to a fully open spool.
    for v in ["-1e9", "10.5", "-10.000001"] {
        let text = boom().replace("safe_command = 0.0 ", &format!("safe_command = {v} "));
        let e = RigConfig::from_toml_str(&text).unwrap_err();
        assert_eq!(e.path, "supervisor.safe_command", "{e}");
        assert!(e.message.contains("valve.command_full_scale = 10 V"), "{e}");
    }
    let ok = boom().replace("safe_command = 0.0 ", "safe_command = -10.0 ");
    assert!(RigConfig::from_toml_str(&ok).is_ok());
    let clamp = boom().replace(
        "safe_command = 0.0 ",
        "safe_command = 3.0\nmax_command = 2.0 ",
    );
    let e = RigConfig::from_toml_str(&clamp).unwrap_err();
    assert!(e.message.contains("supervisor.max_command = 2 V"), "{e}");
}
