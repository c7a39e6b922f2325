//! Bad measured data gives one clear error naming file, line/column and expectation;
//! nothing is dropped silently. Also checks the noise estimate and the replay against
//! the generator (a model with the true parameters reproduces the data to the noise).

use ehactl_ident::data::{check_against, parse_csv};
use ehactl_ident::replay::{noise_level, nrmse, replay, replay_params};
use ehactl_ident_eval::synth::{make_case, testrig, to_csv, Rng};

fn csv(rows: &[&str]) -> String {
    rows.join("\n")
}

fn good_rows(n: usize) -> Vec<String> {
    (0..n)
        .map(|k| format!("{},{},{},{}", k as f64 * 1e-3, 0.1, 5.0e6, 4.0e6))
        .collect()
}

#[test]
fn missing_u_column_is_named() {
    let e = parse_csv("f.csv", &csv(&["t,p_a", "0,1", "0.001,2"]))
        .unwrap_err()
        .0;
    assert!(
        e.contains("missing required column `u`") && e.contains("f.csv"),
        "{e}"
    );
}

#[test]
fn nan_row_is_named_with_its_line() {
    let mut rows = vec!["t,u,p_a,p_b".to_string()];
    rows.extend(good_rows(30));
    rows[13] = "0.012,0.1,nan,4e6".into(); // file line 14 (header is line 1)
    let text = rows.join("\n");
    let e = parse_csv("f.csv", &text).unwrap_err().0;
    assert!(e.contains("`p_a`") && e.contains("line 14"), "{e}");
}

#[test]
fn non_increasing_time_is_named() {
    let mut rows = vec!["t,u,p_a,p_b".to_string()];
    rows.extend(good_rows(30));
    rows[21] = "0.005,0.1,5e6,4e6".into();
    let e = parse_csv("f.csv", &rows.join("\n")).unwrap_err().0;
    assert!(e.contains("not increasing") && e.contains("line 22"), "{e}");
}

#[test]
fn pressures_in_bar_are_refused() {
    let mut rows = vec!["t,u,p_a,p_b".to_string()];
    rows.extend((0..30).map(|k| format!("{},0.1,50.0,40.0", k as f64 * 1e-3)));
    let rec = parse_csv("f.csv", &rows.join("\n")).unwrap();
    let cfg = testrig();
    let e = check_against(&rec, &cfg.plant, cfg.timebase().period())
        .unwrap_err()
        .0;
    assert!(e.contains("looks like bar") && e.contains("`p_a`"), "{e}");
}

#[test]
fn positions_in_mm_are_refused_and_rate_mismatch_is_warned() {
    let mut rows = vec!["t,u,x".to_string()];
    rows.extend((0..30).map(|k| format!("{},0.1,{}", k as f64 * 2e-4, 100.0 + k as f64)));
    let rec = parse_csv("f.csv", &rows.join("\n")).unwrap();
    let cfg = testrig();
    let e = check_against(&rec, &cfg.plant, cfg.timebase().period())
        .unwrap_err()
        .0;
    assert!(e.contains("looks like mm"), "{e}");
    let mut rows = vec!["t,u,x".to_string()];
    rows.extend((0..30).map(|k| format!("{},0.1,{}", k as f64 * 2e-4, 0.1)));
    let rec = parse_csv("f.csv", &rows.join("\n")).unwrap();
    let w = check_against(&rec, &cfg.plant, cfg.timebase().period()).unwrap();
    assert!(
        w.iter()
            .any(|w| w.contains("differs from the config's control period")),
        "{w:?}"
    );
}

#[test]
fn noise_level_recovers_white_noise() {
    let mut rng = Rng::new(5);
    // Box–Muller normal samples of σ = 0.3 on a slow sine.
    let y: Vec<f64> = (0..20000)
        .map(|k| {
            let (a, b) = (rng.uniform().max(1e-12), rng.uniform());
            (k as f64 * 1e-3).sin()
                + 0.3 * (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        })
        .collect();
    let s = noise_level(&y);
    assert!((s - 0.3).abs() < 0.02, "estimated {s}, expected 0.3");
}

#[test]
fn true_model_replays_generated_data_to_the_noise_and_csv_round_trips() {
    let case = make_case(7, &[], 1.0);
    let text = to_csv(&case.record);
    let rec = parse_csv("gen.csv", &text).unwrap();
    assert_eq!(rec.len(), case.record.len());
    let p = replay_params(&case.truth, &rec);
    let sim = replay(&p, &rec, rec.len()).unwrap();
    let e = nrmse(&rec, &sim, 0..rec.len());
    for (c, v) in rec.channels.iter().zip(&e) {
        let floor = noise_level(&c.values) / ehactl_ident::replay::std(&c.values);
        assert!(
            *v < 3.0 * floor + 0.01,
            "{}: NRMSE {v} vs noise floor {floor}",
            c.kind.column()
        );
    }
}
