//! Data that diagnose cannot use gets a one-line error (exit 2 in the
//! CLI) and doubtful units a warning — never a panic or a NaN result. Expected unit names
//! come from the conversion factors (1 bar = 1e5 Pa, 1 psi = 6894.757 Pa, 1 MPa = 1e6 Pa).

use ehactl_ident::data::{check_against, parse_csv};
use ehactl_ident_eval::synth::testrig;

fn rows(header: &str, n: usize, dt: f64, row: impl Fn(usize) -> String) -> String {
    let mut v = vec![header.to_string()];
    v.extend((0..n).map(|k| format!("{},{}", k as f64 * dt, row(k))));
    v.join("\n")
}

fn check(text: &str) -> Result<Vec<String>, String> {
    let rec = parse_csv("f.csv", text).map_err(|e| e.0)?;
    let cfg = testrig();
    check_against(&rec, &cfg.plant, cfg.timebase().period()).map_err(|e| e.0)
}

/// Supply pressure of the test rig (Pa): pressures below are a plausible 50 % / 40 % of it.
fn ps() -> f64 {
    testrig().plant.supply.pressure
}

#[test]
fn pressures_in_mpa_and_psi_are_named_as_such() {
    let (a, b) = (0.5 * ps(), 0.4 * ps());
    for (unit, factor) in [("MPa", 1e6), ("psi", 6894.757), ("bar", 1e5)] {
        let text = rows("t,u,p_a,p_b", 50, 1e-3, |_| {
            format!("0.1,{},{}", a / factor, b / factor)
        });
        let e = check(&text).unwrap_err();
        assert!(e.contains(&format!("looks like {unit}")), "{unit}: {e}");
    }
}

#[test]
fn an_impossible_pressure_is_an_error_naming_the_row() {
    let text = rows("t,u,p_a,p_b", 50, 1e-3, |k| {
        let p = if k == 7 { 1e300 } else { 0.5 * ps() };
        format!("0.1,{p},{}", 0.4 * ps())
    });
    let e = check(&text).unwrap_err();
    assert!(
        e.contains("`p_a`") && e.contains("row 8") && e.contains("not a plausible"),
        "{e}"
    );
}

#[test]
fn time_in_integer_samples_or_microseconds_is_refused() {
    for (dt, hint) in [(1.0, "ms or µs"), (1e3, "ms or µs")] {
        let text = rows("t,u,x", 100, dt, |k| {
            format!("{},{}", (k as f64 * 0.2).sin(), 0.1)
        });
        let e = check(&text).unwrap_err();
        assert!(e.contains("sample period") && e.contains(hint), "{e}");
    }
}

#[test]
fn force_in_kn_is_warned() {
    let cfg = testrig();
    let cap = cfg.plant.supply.pressure * cfg.plant.cylinder.area_a.max(cfg.plant.cylinder.area_b);
    // A force that peaks at 20 % of capacity, written in kN.
    let text = rows("t,u,force", 50, 1e-3, |k| {
        format!("0.1,{}", 0.2 * cap * (k as f64 * 0.3).sin() / 1e3)
    });
    let w = check(&text).unwrap();
    assert!(w.iter().any(|w| w.contains("kN")), "{w:?}");
    // The same in N passes without that warning.
    let text = rows("t,u,force", 50, 1e-3, |k| {
        format!("0.1,{}", 0.2 * cap * (k as f64 * 0.3).sin())
    });
    let w = check(&text).unwrap();
    assert!(!w.iter().any(|w| w.contains("kN")), "{w:?}");
}
