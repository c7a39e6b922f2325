//! Check of the stated detection limits on physical effects of a known size (not part of CI).
//! For every small case of a list: the limit the diagnosis states for the case's effect on
//! its clean twin (the same seed, draws, excitation and noise, no effect: the record a user
//! would have diagnosed `none`), then the effect physically at FACTOR × that limit
//! (`indep::Hidden::at_strength`, `hide::at_strength`, the same draws otherwise) diagnosed:
//! is it named (a cause, or an ambiguity naming it)? A limit that holds names every effect
//! above it; the issue's bar is ≥ 90 % at 1.5×. Below 1 × FACTOR nothing is required.
//!
//! Usage:
//! `validate_limits indep CASES.txt OUT.md [FACTOR]` (the independent generator's small
//! cases, `kind@L`; clean lines skipped), or
//! `validate_limits own FIRST_SEED PER_EFFECT OUT.md [FACTOR]` (the own plant's small cases
//! of `evaluate`: seed FIRST + 12·k + the effect's index, k < PER_EFFECT).
//! FACTOR defaults to 1.5. One line per case on stdout and in OUT.md, then the summary.
use ehactl_ident::limits::DetectionLimit;
use ehactl_ident::{diagnose, Diagnosis, Options};
use ehactl_ident_eval::limscore;
use ehactl_plant::EffectId;
use std::fmt::Write as _;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let factor_at = |i: usize| a.get(i).and_then(|s| s.parse().ok()).unwrap_or(1.5);
    let (lines, out, factor) = match a.get(1).map(String::as_str) {
        Some("indep") if a.len() >= 4 => {
            let f = factor_at(4);
            (indep_cases(&a[2], f), a[3].clone(), f)
        }
        Some("own") if a.len() >= 5 => {
            let (first, per) = (
                a[2].parse().expect("FIRST_SEED"),
                a[3].parse().expect("PER_EFFECT"),
            );
            let f = factor_at(5);
            (own_cases(first, per, f), a[4].clone(), f)
        }
        _ => {
            eprintln!("usage: validate_limits indep CASES.txt OUT.md [FACTOR] | own FIRST_SEED PER_EFFECT OUT.md [FACTOR]");
            std::process::exit(2);
        }
    };
    let mut s = String::new();
    let scored: Vec<&Line> = lines.iter().filter(|l| l.named.is_some()).collect();
    let named = scored.iter().filter(|l| l.named == Some(true)).count();
    let _ = writeln!(
        s,
        "Limits checked on physical effects at {factor}× the limit stated on the clean twin: named {named}/{} ({:.0} %); not scored {}.\n",
        scored.len(),
        100.0 * named as f64 / scored.len().max(1) as f64,
        lines.len() - scored.len()
    );
    let misses: Vec<&str> = scored
        .iter()
        .filter(|l| l.named == Some(false))
        .map(|l| l.text.as_str())
        .collect();
    let _ = writeln!(
        s,
        "Not named: {}\n",
        if misses.is_empty() {
            "—".to_string()
        } else {
            misses.join("; ")
        }
    );
    s.push_str("```\n");
    for l in &lines {
        let _ = writeln!(s, "{}", l.text);
    }
    s.push_str("```\n");
    std::fs::write(&out, &s).expect("write OUT.md");
    println!("{s}");
}

/// One case's outcome: `named` `None` when it could not be scored.
struct Line {
    named: Option<bool>,
    text: String,
}

/// α putting the effect of full-size value `full` at `factor` × `limit` on the strength
/// scale of [`limscore::ratio`]; `None` when that needs more than the drawn size (α > 1).
fn alpha_for(limit: &DetectionLimit, full: f64, factor: f64) -> Option<f64> {
    let r = |al: f64| limscore::ratio(limit, limscore::small_size(limit, full, al));
    if r(1.0)? < factor {
        return None;
    }
    // The ratio rises with α: bisection on log α over [1e-9, 1].
    let (mut lo, mut hi) = (-9.0f64, 0.0f64);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if r(10f64.powf(mid))? < factor {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(10f64.powf(hi))
}

/// The limit on the twin, the case at `factor` × it and the diagnosis of that case, in a
/// line; `make(α)` gives the physical case's nominal config and record, `full(parameter)`
/// the drawn size in a catalogue parameter.
fn check(
    label: &str,
    want: &str,
    twin: Result<Diagnosis, String>,
    full: &dyn Fn(&str) -> Option<f64>,
    make: &dyn Fn(f64) -> Result<Diagnosis, String>,
    factor: f64,
) -> Line {
    let skip = |why: String| Line {
        named: None,
        text: format!("{label}: not scored ({why})"),
    };
    let twin = match twin {
        Ok(d) => d,
        Err(e) => return skip(format!("twin: {e}")),
    };
    let Some(limit) = twin
        .detection_limits
        .get(want)
        .filter(|l| l.limit.is_some())
    else {
        return skip(format!(
            "no finite limit for `{want}` on the twin, its answer `{}`",
            twin.cause
        ));
    };
    let Some(v) = full(&limit.parameter) else {
        return skip(format!("no size in `{}`", limit.parameter));
    };
    let Some(al) = alpha_for(limit, v, factor) else {
        return skip(format!("the drawn size is below {factor}× the limit"));
    };
    let size = limscore::small_size(limit, v, al);
    match make(al) {
        Ok(d) => {
            let named = limscore::names(&d, want);
            Line {
                named: Some(named),
                text: format!(
                    "{label}: limit {:.4e} ({}) on the twin, physical size {size:.4e} (α {al:.3e}) -> {} named {named}",
                    limit.limit.unwrap_or(f64::NAN),
                    limit.method,
                    d.cause
                ),
            }
        }
        Err(e) => skip(format!("the physical case: {e}")),
    }
}

/// The independent generator's small cases of list `path`.
fn indep_cases(path: &str, factor: f64) -> Vec<Line> {
    use ehactl_ident_eval::indep::{
        expected, make_case_at_strength, make_case_without, parse_cases,
    };
    let text = std::fs::read_to_string(path).expect("read case list");
    let mut out = Vec::new();
    for (seed, kind) in parse_cases(&text) {
        let Some((base, _)) = kind.split_once('@') else {
            continue;
        };
        let label = format!("{seed} {kind}");
        let Ok(full_case) = make_case_at_strength(seed, base, 1.0, 1.5, 1e-3) else {
            out.push(Line {
                named: None,
                text: format!("{label}: not generated"),
            });
            continue;
        };
        let Some(h) = full_case.hidden.clone() else {
            continue;
        };
        let want = expected(&h).0;
        let opts = Options {
            drive: full_case.drive,
            ..Options::default()
        };
        let run = |c: ehactl_ident_eval::indep::Case| {
            diagnose(&c.nominal, &c.record, None, &opts).map_err(|e| e.to_string())
        };
        let twin = make_case_without(seed, base, 0, 1.5, 1e-3).and_then(run);
        let full = |p: &str| limscore::indep_value(&h, p);
        let make = |al: f64| make_case_at_strength(seed, base, al, 1.5, 1e-3).and_then(run);
        let line = check(&label, want, twin, &full, &make, factor);
        println!("{}", line.text);
        out.push(line);
    }
    out
}

/// The own plant's small cases of `evaluate` (seeds `first` + 12·k + the effect's index).
fn own_cases(first: u64, per_effect: u64, factor: f64) -> Vec<Line> {
    use ehactl_ident_eval::synth::{make_case, simulate, testrig};
    let mut out = Vec::new();
    for k in 0..per_effect {
        for (i, &e) in EffectId::ALL.iter().enumerate() {
            let seed = first + 12 * k + i as u64;
            let label = format!("{seed} {}", e.as_str());
            let case = make_case(seed, &[e], 2.0);
            let run = |rec: ehactl_ident::Record| {
                diagnose(&case.nominal.plant, &rec, None, &Options::default())
                    .map_err(|e| e.to_string())
            };
            let mut clean = testrig().plant;
            clean.sensors.seed = seed;
            let twin = run(simulate(&clean, &case.record.u, 1e-3, "clean twin"));
            let full = |p: &str| limscore::synth_value(&case.truth, p);
            let make = |al: f64| {
                let mut truth = case.truth.clone();
                ehactl_ident_eval::hide::at_strength(e, &mut truth, al);
                run(simulate(&truth, &case.record.u, 1e-3, "physical"))
            };
            let line = check(&label, e.as_str(), twin, &full, &make, factor);
            println!("{}", line.text);
            out.push(line);
        }
    }
    out
}
