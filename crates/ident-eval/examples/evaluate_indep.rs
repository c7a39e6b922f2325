//! Evaluation of `diagnose` on the independent generator (`ehactl_ident_eval::indep`, not part of
//! CI): `cargo run --release -p ehactl-ident-eval --example evaluate_indep -- CASES.txt OUT.md [DURATION_S]`.
//! Reads the fixed case list (`bench/indep_cases.txt`), diagnoses each case, appends one line
//! per case to OUT.md.cases as it goes (so a partial run is reportable) and writes the summary
//! (top-cause accuracy, variant agreement, `none` / `unexplained` rates, gains, confusion
//! matrix) to OUT.md. Kinds with a level suffix (`lines@3`: the effect at a small magnitude,
//! `indep::make_case_small`) are scored apart, with their false `none`; `PHYSICAL=1` makes
//! them physical effects at the blend's α (`indep::make_case_small_physical`). "Above noise" for the false-`none` count: the refit nominal model's
//! held-out residual fails the residual test (level or whiteness) on some channel.
use ehactl_ident::{diagnose, Options};
use ehactl_ident_eval::indep::{expected, make_case, parse_cases};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::Write as _;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let list = a.get(1).cloned().unwrap_or("bench/indep_cases.txt".into());
    let out = a
        .get(2)
        .cloned()
        .unwrap_or("bench/results/diagnose_eval_indep.md".into());
    let duration: f64 = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(1.5);
    // `INTEGRATION_COST=4` runs the diagnosis with the replay cost cap of `ehactl diagnose`
    // (`session::USER_INTEGRATION_COST`) instead of the library default 1×.
    let opts = Options {
        integration_max_cost: std::env::var("INTEGRATION_COST")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(Options::default().integration_max_cost),
        ..Options::default()
    };
    let text = std::fs::read_to_string(&list).expect("read case list");
    let cases = parse_cases(&text);
    let log_path = format!("{out}.cases");
    if let Some(dir) = std::path::Path::new(&out).parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    // Resume: cases already in the log are not run again.
    let done: BTreeMap<u64, String> = std::fs::read_to_string(&log_path)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| Some((l.split_whitespace().nth(1)?.parse().ok()?, l.to_string())))
        .collect();
    let mut log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .expect("open case log");
    for (seed, kind) in &cases {
        if done.contains_key(seed) {
            continue;
        }
        if let Some(line) = run_case(*seed, kind, duration, &opts) {
            eprintln!("{line}");
            let _ = writeln!(log, "{line}");
            let _ = log.flush();
        }
    }
    let lines: Vec<String> = std::fs::read_to_string(&log_path)
        .unwrap_or_default()
        .lines()
        .map(String::from)
        .collect();
    let s = summarise(&lines, cases.len(), duration, &list);
    std::fs::write(&out, &s).expect("write summary");
    println!("{s}");
}

/// Case `kind` of `seed` generated and diagnosed: its line for the log (`None` with
/// `GEN_ONLY=1`, which prints the generated channels instead).
fn run_case(seed: u64, kind: &str, duration: f64, opts: &Options) -> Option<String> {
    // `PHYSICAL=1`: a small case (`kind@L`) with its effects physically at the blend's α
    // (`indep::make_case_small_physical`), to check the limits on effects of a known size.
    let physical = std::env::var("PHYSICAL").is_ok_and(|v| v == "1");
    let make = if physical {
        ehactl_ident_eval::indep::make_case_physical
    } else {
        make_case
    };
    let case = match make(seed, kind, duration, 1e-3) {
        Ok(c) => c,
        Err(e) => {
            return Some(format!(
                "seed {seed} kind {kind} expect - - -> GENERATOR_FAILED {e}"
            ));
        }
    };
    let (want, want_var) = case.hidden.as_ref().map_or(("none", "-"), expected);
    // A case with two or three effects: every one must be among the accepted causes.
    let want_all: Vec<&str> = case.all_hidden().iter().map(|h| expected(h).0).collect();
    if std::env::var("GEN_ONLY").is_ok_and(|v| v == "1") {
        print_generated(&case, kind, (want, want_var));
        return None;
    }
    let t0 = std::time::Instant::now();
    // The rig's own loop for closed-loop (`pi_`) cases, as `ehactl diagnose` chooses it.
    // `OPEN_LOOP=1`: the recorded command instead (the diagnosis before `Drive::ForcePi`).
    let open_loop = std::env::var("OPEN_LOOP").is_ok_and(|v| v == "1");
    let opts = Options {
        drive: if open_loop {
            ehactl_ident::replay::Drive::Recorded
        } else {
            case.drive
        },
        ..opts.clone()
    };
    let d = match diagnose(&case.nominal, &case.record, None, &opts) {
        Ok(d) => d,
        Err(e) => {
            return Some(format!(
                "seed {seed} kind {kind} expect {want} {want_var} -> ERROR {e}"
            ));
        }
    };
    let dt = t0.elapsed().as_secs_f64();
    if std::env::var("DEBUG").is_ok_and(|v| v == "1") {
        print_debug(&d);
    }
    let variant = d
        .candidates
        .iter()
        .find(|c| c.effect == d.cause)
        .map_or("-".to_string(), |c| c.variant.clone());
    // Whether the refit nominal model's held-out residual is above the noise.
    let ratio = over_true_noise(&case, &d.nrmse_refit);
    // The same for the final model, the one a `none` stands on: the refit, or a better
    // nominal-only model that a candidate's fit found (the effect carrying none of its
    // gain, `MIN_EFFECT_SHARE`).
    let ratio_final = over_true_noise(&case, &d.nrmse_extended);
    let above_final = ratio_final > ehactl_ident::residual::LEVEL_LARGE;
    let above = ratio > ehactl_ident::residual::LEVEL_LARGE;
    // A small case: its hidden size over the detection limit stated for it.
    let limit = if kind.contains('@') {
        limit_field(&case, kind, want, &d, &opts, duration)
    } else {
        String::new()
    };
    let line = format!(
        "seed {seed} kind {kind} expect {want} {want_var} -> {} {variant} causes {} gain {:.3} nominal {:.4} refit {:.4} extended {:.4} floor {:.4} refit_over_true_noise {ratio:.1} refit_above_noise {above} final_over_true_noise {ratio_final:.1} final_above_noise {above_final} refit_continued {} time {dt:.1}{}",
        d.cause,
        if d.causes.is_empty() { "-".to_string() } else { d.causes.join("+") },
        d.gain,
        d.nrmse_nominal.overall,
        d.nrmse_refit.overall,
        d.nrmse_extended.overall,
        d.noise_floor,
        d.refit_continued.len(),
        if want_all.len() > 1 {
            format!(
                " expect_all {} all_named {}",
                want_all.join("+"),
                want_all.iter().all(|w| d.causes.iter().any(|c| c == w))
            )
        } else {
            String::new()
        },
    ) + &limit;
    Some(line)
}

/// `GEN_ONLY=1`: each channel's std and minimum and the hidden effect, no diagnosis.
fn print_generated(
    case: &ehactl_ident_eval::indep::Case,
    kind: &str,
    (want, want_var): (&str, &str),
) {
    let sd: Vec<String> = case
        .record
        .channels
        .iter()
        .map(|c| {
            format!(
                "{} std {:.3e} min {:.3e}",
                c.kind.column(),
                ehactl_ident::replay::std(&c.values),
                c.values.iter().cloned().fold(f64::INFINITY, f64::min)
            )
        })
        .collect();
    println!(
        "seed {} {kind} ({want} {want_var}): {} | {:?}",
        case.seed,
        sd.join(", "),
        case.hidden
    );
}

/// `DEBUG=1`: the tones, every candidate, the residual test and the ambiguities.
fn print_debug(d: &ehactl_ident::Diagnosis) {
    println!("tones {:?}", d.analysis_refit.tones);
    for c in &d.candidates {
        println!(
            "  {} [{}] {:.4} {:?} {}",
            c.effect, c.variant, c.nrmse_validation, c.params, c.evidence
        );
    }
    println!("  residual {:?}", d.residual_test.channels);
    for a in &d.ambiguities {
        println!("  ambiguity: {a}");
    }
    for (e, l) in &d.detection_limits {
        println!(
            "  limit {e} [{}; {}] {:?} {} ({}; looseness {:.3}) {}",
            l.variant, l.shape, l.limit, l.unit, l.method, l.looseness, l.note
        );
    }
}

/// How far a model's held-out errors `e` are above the noise, judged with the generator's
/// true noise σ (not the diagnosis' own estimate): the largest ratio over channels of the
/// NRMSE to σ/std(held-out channel) (-). Above noise when > 6 (the residual test's level at
/// which a residual is never counted as noise before 2026-11-28, `residual::LEVEL_LARGE`;
/// clean cases show ≈ 3, mostly the replay's own integration error on the low-noise
/// position channel).
fn over_true_noise(
    case: &ehactl_ident_eval::indep::Case,
    e: &ehactl_ident::diagnose::Errors,
) -> f64 {
    let rig = ehactl_ident_eval::indep::Rig::default();
    let n = case.record.len();
    let split = ((1.0 - Options::default().holdout) * n as f64).round() as usize;
    case.record
        .channels
        .iter()
        .map(|c| {
            let sigma = match c.kind {
                ehactl_ident::ChannelKind::Force => rig.noise.0,
                ehactl_ident::ChannelKind::Position => rig.noise.1,
                _ => rig.noise.2,
            };
            let floor = sigma / ehactl_ident::replay::std(&c.values[split..]);
            e.channels.get(c.kind.column()).copied().unwrap_or(0.0) / floor
        })
        .fold(0.0, f64::max)
}

/// ` limit_ratio R limit_from F named B closest C limit L size S` of a small case: its hidden size over the limit the
/// diagnosis `d` stated for the hidden effect `want` (`stated`), or, when it stated none (it
/// named the effect), the limit stated on its clean twin (the same draws without the effect,
/// `twin`: diagnosed with `want` the only effect tested); R `n/a` without a size map.
fn limit_field(
    case: &ehactl_ident_eval::indep::Case,
    kind: &str,
    want: &str,
    d: &ehactl_ident::Diagnosis,
    opts: &Options,
    duration: f64,
) -> String {
    use ehactl_ident_eval::limscore;
    let named = limscore::names(d, want);
    let (limit, from) = match d.detection_limits.get(want) {
        Some(l) => (Some(l.clone()), "stated"),
        None => {
            let base = kind.split('@').next().unwrap_or(kind);
            let twin =
                ehactl_ident_eval::indep::make_case_without(case.seed, base, 0, duration, 1e-3);
            let effect = ehactl_plant::EffectId::parse(want);
            let l = twin.ok().zip(effect).and_then(|(t, e)| {
                let o = Options {
                    effects: vec![e],
                    ..opts.clone()
                };
                diagnose(&t.nominal, &t.record, None, &o)
                    .ok()?
                    .detection_limits
                    .get(want)
                    .cloned()
            });
            (l, "twin")
        }
    };
    let alpha = ehactl_ident_eval::limscore::alpha_from_source(&case.record.source);
    let size = limit.as_ref().zip(alpha).and_then(|(l, a)| {
        let full = limscore::indep_value(case.hidden.as_ref()?, &l.parameter)?;
        Some(limscore::small_size(l, full, a))
    });
    let r = limit
        .as_ref()
        .zip(size)
        .and_then(|(l, s)| limscore::ratio(l, s));
    let num = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.4e}"));
    format!(
        " limit_ratio {} limit_from {from} named {named} closest {} limit {} size {} parameter {}",
        r.map_or("n/a".to_string(), |r| format!("{r:.3}")),
        limscore::closest_is(d, want),
        num(limit.as_ref().and_then(|l| l.limit)),
        num(size),
        limit.as_ref().map_or("-", |l| l.parameter.as_str()),
    )
}

fn field<'a>(l: &'a str, key: &str) -> Option<&'a str> {
    let mut it = l.split_whitespace();
    while let Some(w) = it.next() {
        if w == key {
            return it.next();
        }
    }
    None
}

fn summarise(lines: &[String], listed: usize, duration: f64, list: &str) -> String {
    let mut sum = Summary::default();
    for l in lines {
        sum.add(l);
    }
    sum.gains.sort_by(f64::total_cmp);
    sum.times.sort_by(f64::total_cmp);
    let mut s = String::new();
    let _ = writeln!(s, "Independent generator (`crates/ident-eval/src/indep.rs`, RK4, own equations per variant), cases from `{list}` ({listed} listed, {} run, {} failed to generate or diagnose), {duration} s at 1 kHz each, nominal errors ±10 %.\n", lines.len(), sum.failed);
    sum.table(&mut s, lines.len());
    sum.small_table(&mut s);
    sum.per_kind_and_confusion(&mut s);
    let _ = writeln!(s, "\n<details><summary>Per-case results</summary>\n\n```");
    for l in lines {
        let _ = writeln!(s, "{l}");
    }
    let _ = writeln!(s, "```\n</details>");
    s
}

/// The case lines counted.
#[derive(Default)]
struct Summary {
    /// Hidden-effect cases: run, top cause right, variant right of `var_n`, `none`,
    /// `unexplained`.
    n_h: usize,
    top: usize,
    var_ok: usize,
    var_n: usize,
    none_h: usize,
    unexpl_h: usize,
    /// False `none` with the refit's / the final model's residual above the true noise.
    false_none_above: usize,
    false_none_final: usize,
    /// Clean cases: run, `none`, `unexplained`.
    n_c: usize,
    none_c: usize,
    unexpl_c: usize,
    /// Cases that failed to generate or diagnose.
    failed: usize,
    /// Cases with several hidden effects, and those with every one named.
    n_multi: usize,
    all_named: usize,
    /// Hidden-effect cases with a cause named that was not hidden.
    extra: usize,
    /// Cases whose search went on from a better nominal fit than the refit's.
    continued: usize,
    /// Small-magnitude cases (`kind@level`): run, correct, false `none`, `unexplained`,
    /// others (hidden, named) → cases; their detection limits.
    s_n: usize,
    s_ok: usize,
    s_none: usize,
    s_unexpl: usize,
    s_other: BTreeMap<(String, String), usize>,
    s_limits: ehactl_ident_eval::limscore::LimitScore,
    /// Gains of the hidden-effect cases (-) and wall times (s).
    gains: Vec<f64>,
    times: Vec<f64>,
    /// Per generator variant: (correct, run).
    per_kind: BTreeMap<String, (usize, usize)>,
    /// (hidden, named) → cases.
    conf: BTreeMap<(String, String), usize>,
}

impl Summary {
    /// One case line of the log.
    fn add(&mut self, l: &str) {
        let kind = field(l, "kind").unwrap_or("?").to_string();
        let want = l.split_whitespace().nth(5).unwrap_or("?").to_string();
        let got = field(l, "->").unwrap_or("?").to_string();
        if got == "ERROR" || got == "GENERATOR_FAILED" {
            self.failed += 1;
            return;
        }
        if let Some(t) = field(l, "time").and_then(|v| v.parse::<f64>().ok()) {
            self.times.push(t);
        }
        self.continued += field(l, "refit_continued").is_some_and(|v| v != "0") as usize;
        if kind.contains('@') {
            self.add_small(l, &kind, &want, &got);
            return;
        }
        *self.conf.entry((want.clone(), got.clone())).or_default() += 1;
        let e = self.per_kind.entry(kind.clone()).or_default();
        e.1 += 1;
        if want == "none" {
            self.n_c += 1;
            self.none_c += (got == "none") as usize;
            self.unexpl_c += (got == "unexplained") as usize;
            e.0 += (got == "none") as usize;
            return;
        }
        e.0 += (got == want) as usize;
        self.add_hidden(l, &want, &got);
    }

    /// A small-magnitude case's line.
    fn add_small(&mut self, l: &str, kind: &str, want: &str, got: &str) {
        if field(l, "limit_ratio").is_some() {
            self.s_limits.add(
                &format!("{} {kind}", field(l, "seed").unwrap_or("?")),
                got,
                field(l, "limit_ratio").and_then(|v| v.parse().ok()),
                field(l, "named") == Some("true"),
                field(l, "closest") == Some("true"),
            );
        }
        self.s_n += 1;
        self.s_ok += (got == want) as usize;
        self.s_none += (got == "none") as usize;
        self.s_unexpl += (got == "unexplained") as usize;
        if got != want && got != "none" && got != "unexplained" {
            *self
                .s_other
                .entry((want.to_string(), got.to_string()))
                .or_default() += 1;
        }
    }

    /// A hidden-effect case's line (not small).
    fn add_hidden(&mut self, l: &str, want: &str, got: &str) {
        let want_var = l.split_whitespace().nth(6).unwrap_or("-").to_string();
        let got_var = l
            .split("-> ")
            .nth(1)
            .and_then(|r| r.split_whitespace().nth(1))
            .unwrap_or("-")
            .to_string();
        self.n_h += 1;
        if let Some(a) = field(l, "all_named") {
            self.n_multi += 1;
            self.all_named += (a == "true") as usize;
        }
        let ok = got == want;
        self.top += ok as usize;
        if ok && want_var != "-" {
            self.var_n += 1;
            self.var_ok += (got_var == want_var) as usize;
        }
        self.none_h += (got == "none") as usize;
        self.unexpl_h += (got == "unexplained") as usize;
        if got == "none" && field(l, "refit_above_noise") == Some("true") {
            self.false_none_above += 1;
        }
        if got == "none" && field(l, "final_above_noise") == Some("true") {
            self.false_none_final += 1;
        }
        // A cause named beside the hidden effect(s) that the generator did not hide.
        let hidden_all = field(l, "expect_all").unwrap_or(want).to_string();
        let hidden: Vec<&str> = hidden_all.split('+').collect();
        if field(l, "causes")
            .is_some_and(|c| c != "-" && c.split('+').any(|x| !hidden.contains(&x)))
        {
            self.extra += 1;
        }
        if let Some(g) = field(l, "gain").and_then(|v| v.parse::<f64>().ok()) {
            self.gains.push(g);
        }
    }

    /// The main table of rates (`run`: lines in the log).
    fn table(&self, s: &mut String, run: usize) {
        let Summary {
            n_h,
            top,
            var_ok,
            var_n,
            none_h,
            unexpl_h,
            false_none_above,
            n_c,
            none_c,
            unexpl_c,
            failed,
            n_multi,
            all_named,
            false_none_final,
            extra,
            continued,
            ..
        } = *self;
        let (gains, times) = (&self.gains, &self.times);
        let pct = |a: usize, b: usize| 100.0 * a as f64 / b.max(1) as f64;
        let _ = writeln!(s, "| measure | result | target |\n|---|---|---|");
        let _ = writeln!(
            s,
            "| top cause = hidden effect id | {top}/{n_h} = {:.1} % | ≥ 92 % |",
            pct(top, n_h)
        );
        let _ = writeln!(s, "| variant named = generator's structure (correct id, variant-bearing effects) | {var_ok}/{var_n} = {:.1} % | — |", pct(var_ok, var_n));
        let _ = writeln!(s, "| `none` on hidden-effect cases (all / refit residual above noise / final model's residual above noise) | {none_h}/{n_h} / {false_none_above} / {false_none_final} | 0 above noise |");
        let _ = writeln!(
            s,
            "| hidden-effect cases with a cause named that was not hidden | {extra}/{n_h} | — |"
        );
        let _ = writeln!(
            s,
            "| `unexplained` on hidden-effect cases | {unexpl_h}/{n_h} = {:.1} % | — |",
            pct(unexpl_h, n_h)
        );
        let _ = writeln!(
            s,
            "| clean cases: `none` / `unexplained` | {none_c}/{n_c} / {unexpl_c}/{n_c} | — |"
        );
        let _ = writeln!(
        s,
        "| cases whose search went on from a better nominal fit than the refit's (`refit_continued`) | {continued}/{} | — |",
        run - failed
    );
        if n_multi > 0 {
            let _ = writeln!(
            s,
            "| cases with two or three hidden effects: every one named | {all_named}/{n_multi} | — |"
        );
        }
        if !gains.is_empty() {
            let _ = writeln!(
                s,
                "| gain (hidden cases) min / median / max | {:.1} % / {:.1} % / {:.1} % | — |",
                gains[0] * 100.0,
                gains[gains.len() / 2] * 100.0,
                gains[gains.len() - 1] * 100.0
            );
        }
        if !times.is_empty() {
            let _ = writeln!(s, "| wall time per case min / median / max (shared 2-core machine) | {:.1} s / {:.1} s / {:.1} s | — |", times[0], times[times.len() / 2], times[times.len() - 1]);
        }
    }

    /// The small-magnitude cases' table and their detection limits.
    fn small_table(&self, s: &mut String) {
        let (s_n, s_ok, s_none, s_unexpl) = (self.s_n, self.s_ok, self.s_none, self.s_unexpl);
        let (s_other, s_limits) = (&self.s_other, &self.s_limits);
        if s_n > 0 {
            let other: Vec<String> = s_other
                .iter()
                .map(|((w, g), n)| format!("`{w}` → `{g}` {n}"))
                .collect();
            let _ = writeln!(s, "\nSmall-magnitude cases (`kind@L`: the effects at L × the sensor noise on the channel they move most), not counted above:\n");
            let _ = writeln!(s, "| measure | result | target |\n|---|---|---|");
            let _ = writeln!(s, "| top cause = hidden effect id | {s_ok}/{s_n} | — |");
            let _ = writeln!(s, "| false `none` | {s_none}/{s_n} | 0 |");
            let _ = writeln!(s, "| `unexplained` | {s_unexpl}/{s_n} | — |");
            let _ = writeln!(
                s,
                "| another effect named | {} | — |",
                if other.is_empty() {
                    "0".to_string()
                } else {
                    other.join(", ")
                }
            );
        }
        if s_limits.scored + s_limits.not_scored.len() > 0 {
            s.push_str(&s_limits.table());
        }
    }

    /// Correct / run per generator variant and the confusion table.
    fn per_kind_and_confusion(&self, s: &mut String) {
        let (per_kind, conf) = (&self.per_kind, &self.conf);
        let _ = writeln!(s, "\nPer generator variant (correct / run):\n");
        let _ = writeln!(s, "| variant | correct |\n|---|---|");
        for (k, (ok, n)) in per_kind {
            let _ = writeln!(s, "| `{k}` | {ok}/{n} |");
        }
        let _ = writeln!(s, "\nConfusion (hidden id → named top cause):\n");
        let _ = writeln!(s, "| hidden | named | cases |\n|---|---|---|");
        for ((w, g), n) in conf {
            let _ = writeln!(s, "| `{w}` | `{g}` | {n} |");
        }
    }
}
