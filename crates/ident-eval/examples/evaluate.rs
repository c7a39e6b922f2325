//! Slow evaluation of `diagnose` over seeded hidden-effect cases (not part of CI):
//! `cargo run --release -p ehactl-ident-eval --example evaluate -- [per_effect] [clean] [pairs] [first_seed] [OUT.md] [per_variant] [small]`.
//! After the single-effect, clean and two-effect cases come `per_variant` (default
//! `per_effect`) cases of each structural variant in `synth::VARIANT_CASES` (LuGre friction, a
//! compliant hose), counted with their effect and scored also on the variant named. Last come
//! `small` (default 3) small-magnitude cases of each catalogue effect
//! (`synth::make_case_small`: the residual of the channel it moves most at 2, 3, 4, 2, …× the
//! sensor noise), scored on their own, false `none` apart.
//! Writes a Markdown section (confusion matrix, rates, gains) to OUT.md (default
//! bench/results/diagnose_eval.md) and one line per case to stdout. With `OFFSETS=1` in the
//! environment every record also gets `synth::realistic_offsets` (sensor zero errors); with
//! `SENSOR_OFFSETS=1` the diagnosis estimates them (`Options::sensor_offsets`).
//! `DEBUG=1` prints every candidate and the final residual test per channel (level, Ljung–Box
//! Q) to stderr. The case index picks effect and level, so `0 0 0 5112 OUT.md 0 3` runs the
//! full run's 36 small cases alone and `0 20 0 5072 OUT.md 0 0` its 20 clean cases.
//! `ONLY=S1,S2` runs those seeds alone. `PHYSICAL=1` makes the small cases physical effects at the blend's α
//! (`synth::make_case_small_physical`), to check the detection limits on effects of a known
//! size.
use ehactl_ident::{diagnose, Options};
use ehactl_ident_eval::synth::{make_case, make_case_small, make_case_variant, VARIANT_CASES};
use ehactl_plant::EffectId;
use std::collections::BTreeMap;
use std::fmt::Write as _;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let arg = |i: usize, d: u64| a.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    let (per_effect, clean, pairs, first) = (arg(1, 6), arg(2, 20), arg(3, 8), arg(4, 5000));
    let out = a
        .get(5)
        .cloned()
        .unwrap_or_else(|| "bench/results/diagnose_eval.md".into());
    let per_variant = arg(6, per_effect);
    let per_small = arg(7, 3);
    let env_on = |k: &str| std::env::var(k).is_ok_and(|v| v == "1");
    let settings = Settings {
        with_offsets: env_on("OFFSETS"),
        estimate_offsets: env_on("SENSOR_OFFSETS"),
        debug: env_on("DEBUG"),
        physical: env_on("PHYSICAL"),
    };
    let plan = Plan::new([per_effect, clean, pairs, per_variant, per_small], first);
    let bar = indicatif::ProgressBar::new(plan.cases.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} evaluate [{bar:40}] {pos}/{len} {elapsed_precise} eta {eta}",
        )
        .unwrap()
        .progress_chars("=> "),
    );
    let mut tally = Tally::default();
    // `ONLY=5121,5133`: those seeds alone (the plan, and so each seed's case, unchanged).
    let only: Vec<u64> = std::env::var("ONLY")
        .map(|v| v.split(',').filter_map(|s| s.trim().parse().ok()).collect())
        .unwrap_or_default();
    for i in 0..plan.cases.len() {
        let seed = first + i as u64;
        if only.is_empty() || only.contains(&seed) {
            run_case(&plan, i, seed, &settings, &bar, &mut tally);
        }
        bar.inc(1);
    }
    bar.finish();
    tally.gains.sort_by(f64::total_cmp);
    tally.times.sort_by(f64::total_cmp);
    let mut s = String::new();
    let _ = writeln!(s, "Cases: {} ({per_effect} per catalogue effect, {clean} clean, {pairs} with two effects, {per_variant} per structural variant of `synth::VARIANT_CASES`, {per_small} small-magnitude per effect), seeds {first}–{}, 2 s at 1 kHz each, test bench `configs/diagnose_testrig.toml`, nominal errors ±10 %{}{}.\n", plan.cases.len(), first + plan.cases.len() as u64 - 1, if settings.with_offsets { ", sensor zero errors on every channel (+2 / −1.5 bar, 5 % of the force std, +0.5 mm)" } else { "" }, if settings.estimate_offsets { "; diagnosed with `--sensor-offsets`" } else { "" });
    tally.rates(&mut s);
    tally.confusion(&mut s);
    s.push_str(&tally.small.table());
    if tally.small.n > 0 {
        s.push_str(&tally.small_limits.table());
    }
    let _ = writeln!(
        s,
        "\n<details><summary>Per-case results</summary>\n\n```\n{}```\n</details>",
        tally.lines
    );
    if let Some(dir) = std::path::Path::new(&out).parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    std::fs::write(&out, &s).expect("write evaluation");
    println!("{s}");
}

/// The switches read from the environment.
struct Settings {
    /// `OFFSETS=1`: realistic sensor zero errors added to every record.
    with_offsets: bool,
    /// `SENSOR_OFFSETS=1`: the diagnosis estimates them.
    estimate_offsets: bool,
    /// `DEBUG=1`: every candidate and the final residual test to stderr.
    debug: bool,
    /// `PHYSICAL=1`: small cases with their effect physically at the blend's α
    /// (`synth::make_case_small_physical`).
    physical: bool,
}

/// The cases in order: their hidden effects, the structural variant of a variant case and
/// the level (× the sensor noise) of a small case.
struct Plan {
    cases: Vec<Vec<EffectId>>,
    variant_of: Vec<Option<&'static str>>,
    level_of: Vec<Option<f64>>,
}

impl Plan {
    /// `counts`: per catalogue effect, clean, pairs, per structural variant, small per
    /// effect; the pairs are drawn from `first`.
    fn new(counts: [u64; 5], first: u64) -> Self {
        let [per_effect, clean, pairs, per_variant, per_small] = counts;
        let mut cases: Vec<Vec<EffectId>> = Vec::new();
        for _ in 0..per_effect {
            for e in EffectId::ALL {
                cases.push(vec![e]);
            }
        }
        for _ in 0..clean {
            cases.push(vec![]);
        }
        let mut pr = ehactl_ident_eval::synth::Rng::new(first);
        for _ in 0..pairs {
            let i = (pr.uniform() * 12.0) as usize;
            let mut j = (pr.uniform() * 11.0) as usize;
            if j >= i {
                j += 1;
            }
            cases.push(vec![EffectId::ALL[i], EffectId::ALL[j]]);
        }
        // Variant cases last, so that the seeds of the cases above do not move.
        let n_plain = cases.len();
        let mut variant_of: Vec<Option<&str>> = vec![None; n_plain];
        for _ in 0..per_variant {
            for (e, v) in VARIANT_CASES {
                cases.push(vec![e]);
                variant_of.push(Some(v));
            }
        }
        // Small-magnitude cases last (levels over the sensor noise cycle through 2, 3, 4).
        let mut level_of: Vec<Option<f64>> = vec![None; cases.len()];
        for k in 0..per_small {
            for e in EffectId::ALL {
                cases.push(vec![e]);
                variant_of.push(None);
                level_of.push(Some([2.0, 3.0, 4.0][k as usize % 3]));
            }
        }
        Plan {
            cases,
            variant_of,
            level_of,
        }
    }
}

/// Case `i` of the plan made with `seed`, diagnosed, printed and counted.
fn run_case(
    plan: &Plan,
    i: usize,
    seed: u64,
    settings: &Settings,
    bar: &indicatif::ProgressBar,
    tally: &mut Tally,
) {
    let hidden = &plan.cases[i];
    let (mut case, alpha) = match (plan.variant_of[i], plan.level_of[i]) {
        (_, Some(l)) if settings.physical => {
            ehactl_ident_eval::synth::make_case_small_physical(seed, hidden[0], l, 2.0)
        }
        (_, Some(l)) => make_case_small(seed, hidden[0], l, 2.0),
        (Some(v), None) => (make_case_variant(seed, hidden[0], v, 2.0), 1.0),
        (None, None) => (make_case(seed, hidden, 2.0), 1.0),
    };
    if settings.with_offsets {
        let b = ehactl_ident_eval::synth::realistic_offsets(&case.record);
        ehactl_ident_eval::synth::add_sensor_offsets(&mut case.record, &b);
    }
    let t0 = std::time::Instant::now();
    let opts = Options {
        sensor_offsets: settings.estimate_offsets,
        // INTEGRATION_COST=4 gives the CLI's replay-accuracy choice (slower).
        integration_max_cost: std::env::var("INTEGRATION_COST")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(ehactl_ident::replay::DEFAULT_INTEGRATION_COST),
        ..Options::default()
    };
    let d = diagnose(&case.nominal.plant, &case.record, None, &opts).expect("diagnosis runs");
    let dt = t0.elapsed().as_secs_f64();
    tally.times.push(dt);
    let hn: Vec<&str> = hidden.iter().map(|e| e.as_str()).collect();
    let label = if hn.is_empty() {
        "none".to_string()
    } else {
        hn.join("+")
    };
    let shown = match plan.variant_of[i] {
        Some(v) => {
            tally.n_variant += 1;
            let named = d.variants.get(hn[0]).map(String::as_str);
            tally.variant_ok += (named == Some(v)) as usize;
            format!("{label} ({v}, named {})", named.unwrap_or("-"))
        }
        None => match plan.level_of[i] {
            Some(l) => format!("{label} (small, {l}× noise)"),
            None => label.clone(),
        },
    };
    if settings.debug {
        for c in &d.candidates {
            eprintln!(
                "  {} [{}] {:.4} {:?} {}",
                c.effect, c.variant, c.nrmse_validation, c.params, c.evidence
            );
        }
        for (e, l) in &d.detection_limits {
            eprintln!(
                "  limit {e} [{}] {:?} {} ({}; {}) {}",
                l.variant, l.limit, l.unit, l.method, l.shape, l.note
            );
        }
        eprintln!("  residual {:?}", d.residual_test.channels);
        eprintln!("  floor {:.5} refit {:?}", d.noise_floor, d.nrmse_refit);
    }
    let line = format!("seed {seed} hidden {shown} -> {} (gain {:.1} %, nominal {:.4} → {:.4}, floor {:.4}, {dt:.1} s)", if d.causes.is_empty() { d.cause.clone() } else { d.causes.join("+") }, d.gain * 100.0, d.nrmse_nominal.overall, d.nrmse_extended.overall, d.noise_floor);
    bar.suspend(|| eprintln!("{line}"));
    let _ = writeln!(tally.lines, "{line}");
    if plan.level_of[i].is_some() {
        tally.small.add(&label, &d.cause, dt);
        let (r, from, detail) = limit_ratio(&case, hidden[0], alpha, &d, &opts);
        let named = ehactl_ident_eval::limscore::names(&d, hn[0]);
        let closest = ehactl_ident_eval::limscore::closest_is(&d, hn[0]);
        let r_text = r.map_or("n/a".to_string(), |r| format!("{r:.3}"));
        let text = format!(
            "  limit_ratio {r_text} limit_from {from} named {named} closest {closest} {detail}"
        );
        let _ = writeln!(tally.lines, "{text}");
        bar.suspend(|| eprintln!("{text}"));
        tally
            .small_limits
            .add(&format!("{seed} {label}"), &d.cause, r, named, closest);
    } else if hidden.is_empty() {
        tally.clean(&d);
    } else {
        tally.hidden(&hn, &label, &d);
    }
}

/// What the cases gave, counted.
#[derive(Default)]
struct Tally {
    /// (hidden, named) → cases, for the single-effect and clean cases.
    conf: BTreeMap<(String, String), usize>,
    top_ok: usize,
    exact_ok: usize,
    false_none: usize,
    n_hidden: usize,
    unexplained_hidden: usize,
    unexplained_clean: usize,
    clean_ok: usize,
    n_clean: usize,
    pair_both: usize,
    n_pair: usize,
    variant_ok: usize,
    n_variant: usize,
    /// Held-out gains of the hidden-effect cases (-).
    gains: Vec<f64>,
    gain50: usize,
    /// Wall time per case (s).
    times: Vec<f64>,
    small: SmallScore,
    small_limits: ehactl_ident_eval::limscore::LimitScore,
    /// One line per case (and a limit line per small case).
    lines: String,
}

impl Tally {
    /// A clean case's answer.
    fn clean(&mut self, d: &ehactl_ident::Diagnosis) {
        self.n_clean += 1;
        self.clean_ok += (d.cause == "none") as usize;
        self.unexplained_clean += (d.cause == "unexplained") as usize;
        *self
            .conf
            .entry(("none".into(), d.cause.clone()))
            .or_default() += 1;
    }

    /// The answer on a case with the hidden effects `hn` (`label`: joined by `+`).
    fn hidden(&mut self, hn: &[&str], label: &str, d: &ehactl_ident::Diagnosis) {
        self.n_hidden += 1;
        let top = hn.contains(&d.cause.as_str());
        self.top_ok += top as usize;
        self.false_none += (d.cause == "none") as usize;
        self.unexplained_hidden += (d.cause == "unexplained") as usize;
        let mut a: Vec<&str> = d.causes.iter().map(|s| s.as_str()).collect();
        let mut b = hn.to_vec();
        a.sort();
        b.sort();
        self.exact_ok += (a == b) as usize;
        self.gains.push(d.gain);
        self.gain50 += (d.gain >= 0.5) as usize;
        if hn.len() == 1 {
            *self
                .conf
                .entry((label.to_string(), d.cause.clone()))
                .or_default() += 1;
        } else {
            self.n_pair += 1;
            self.pair_both += hn.iter().all(|h| d.causes.iter().any(|c| c == h)) as usize;
        }
    }

    /// The table of rates against their targets (gains and times sorted).
    fn rates(&self, s: &mut String) {
        let Tally {
            top_ok,
            exact_ok,
            false_none,
            n_hidden,
            unexplained_hidden,
            unexplained_clean,
            clean_ok,
            n_clean,
            pair_both,
            n_pair,
            variant_ok,
            n_variant,
            gain50,
            ..
        } = *self;
        let (gains, times) = (&self.gains, &self.times);
        let pct = |a: usize, b: usize| 100.0 * a as f64 / b.max(1) as f64;
        let _ = writeln!(s, "| measure | result | target |\n|---|---|---|");
        let _ = writeln!(s, "| top cause is a hidden effect (cases with hidden effects) | {top_ok}/{n_hidden} = {:.1} % | ≥ 90 % |", pct(top_ok, n_hidden));
        let _ = writeln!(
            s,
            "| accepted set equals the hidden set exactly | {exact_ok}/{n_hidden} = {:.1} % | — |",
            pct(exact_ok, n_hidden)
        );
        let _ = writeln!(
            s,
            "| both hidden effects named (two-effect cases) | {pair_both}/{n_pair} = {:.1} % | — |",
            pct(pair_both, n_pair)
        );
        if n_variant > 0 {
            let _ = writeln!(
                s,
                "| variant named (cases of `synth::VARIANT_CASES`) | {variant_ok}/{n_variant} = {:.1} % | — |",
                pct(variant_ok, n_variant)
            );
        }
        let _ = writeln!(s, "| false `none` | {false_none}/{n_hidden} | 0 |");
        let _ = writeln!(s, "| `unexplained` (hidden-effect cases / clean cases) | {unexplained_hidden}/{n_hidden} / {unexplained_clean}/{n_clean} | — |");
        let _ = writeln!(
            s,
            "| clean cases answered `none` | {clean_ok}/{n_clean} = {:.1} % | ≥ 95 % |",
            pct(clean_ok, n_clean)
        );
        let _ = writeln!(
            s,
            "| held-out NRMSE gain ≥ 50 % (hidden cases) | {gain50}/{n_hidden} = {:.1} % | — |",
            pct(gain50, n_hidden)
        );
        if !gains.is_empty() {
            let _ = writeln!(
                s,
                "| gain min / median / max | {:.1} % / {:.1} % / {:.1} % | — |",
                gains[0] * 100.0,
                gains[gains.len() / 2] * 100.0,
                gains[gains.len() - 1] * 100.0
            );
        }
        let _ = writeln!(
            s,
            "| wall time per case min / median / max | {:.1} s / {:.1} s / {:.1} s | — |\n",
            times[0],
            times[times.len() / 2],
            times[times.len() - 1]
        );
    }

    /// The confusion matrix of the single-effect and clean cases.
    fn confusion(&self, s: &mut String) {
        let conf = &self.conf;
        let cols: Vec<String> = EffectId::ALL
            .iter()
            .map(|e| e.as_str().to_string())
            .chain(["none".to_string(), "unexplained".to_string()])
            .collect();
        let _ = writeln!(s, "Confusion matrix (rows: hidden, single-effect and clean cases; columns: top cause named):\n");
        let _ = writeln!(
            s,
            "| hidden \\ named | {} |",
            cols.iter()
                .map(|c| format!("`{c}`"))
                .collect::<Vec<_>>()
                .join(" | ")
        );
        let _ = writeln!(s, "|---|{}", "---|".repeat(cols.len()));
        for r in &cols {
            let _ = writeln!(
                s,
                "| `{r}` | {} |",
                cols.iter()
                    .map(|c| conf
                        .get(&(r.clone(), c.clone()))
                        .map_or(String::new(), |n| n.to_string()))
                    .collect::<Vec<_>>()
                    .join(" | ")
            );
        }
    }
}

/// A small case's hidden size over the detection limit the diagnosis `d` stated for the
/// hidden effect `e` (`stated`), or, when it stated none (it named the effect), the limit
/// stated on its clean twin (the same seed, excitation and noise without the effect,
/// diagnosed with `e` the only effect tested: `twin`); `None` without a size map; and the
/// limit, the hidden size and the parameter in words.
fn limit_ratio(
    case: &ehactl_ident_eval::synth::Case,
    e: EffectId,
    alpha: f64,
    d: &ehactl_ident::Diagnosis,
    opts: &Options,
) -> (Option<f64>, &'static str, String) {
    use ehactl_ident_eval::limscore;
    let (limit, from) = match d.detection_limits.get(e.as_str()) {
        Some(l) => (Some(l.clone()), "stated"),
        None => {
            let mut clean_truth = ehactl_ident_eval::synth::testrig().plant;
            clean_truth.sensors.seed = case.seed;
            let twin =
                ehactl_ident_eval::synth::simulate(&clean_truth, &case.record.u, 1e-3, "twin");
            let o = Options {
                effects: vec![e],
                ..opts.clone()
            };
            let l = diagnose(&case.nominal.plant, &twin, None, &o)
                .ok()
                .and_then(|t| t.detection_limits.get(e.as_str()).cloned());
            (l, "twin")
        }
    };
    let size = limit.as_ref().and_then(|l| {
        let full = limscore::synth_value(&case.truth, &l.parameter)?;
        Some(limscore::small_size(l, full, alpha))
    });
    let r = limit
        .as_ref()
        .zip(size)
        .and_then(|(l, s)| limscore::ratio(l, s));
    let num = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.4e}"));
    let detail = format!(
        "limit {} size {} parameter {}",
        num(limit.as_ref().and_then(|l| l.limit)),
        num(size),
        limit.as_ref().map_or("-", |l| l.parameter.as_str())
    );
    (r, from, detail)
}

/// Scores of the small-magnitude cases, kept apart from the full-size ones.
#[derive(Default)]
struct SmallScore {
    n: usize,
    correct: usize,
    false_none: usize,
    unexplained: usize,
    /// (hidden, named) → cases, for the named ≠ hidden ones.
    confusions: BTreeMap<(String, String), usize>,
    times: Vec<f64>,
}

impl SmallScore {
    fn add(&mut self, hidden: &str, named: &str, time: f64) {
        self.n += 1;
        self.correct += (hidden == named) as usize;
        self.false_none += (named == "none") as usize;
        self.unexplained += (named == "unexplained") as usize;
        if hidden != named && named != "none" && named != "unexplained" {
            *self
                .confusions
                .entry((hidden.to_string(), named.to_string()))
                .or_default() += 1;
        }
        self.times.push(time);
    }

    fn table(&self) -> String {
        if self.n == 0 {
            return String::new();
        }
        let mut t = self.times.clone();
        t.sort_by(f64::total_cmp);
        let conf: Vec<String> = self
            .confusions
            .iter()
            .map(|((h, g), n)| format!("`{h}` → `{g}` {n}"))
            .collect();
        format!(
            "\nSmall-magnitude cases (one effect, residual 2–4× the sensor noise on the channel it moves most, `synth::make_case_small`):\n\n| measure | result | target |\n|---|---|---|\n| top cause = hidden effect | {}/{} | — |\n| false `none` | {}/{} | 0 |\n| `unexplained` | {}/{} | — |\n| another effect named | {} | — |\n| median wall time per case | {:.1} s | — |\n",
            self.correct,
            self.n,
            self.false_none,
            self.n,
            self.unexplained,
            self.n,
            if conf.is_empty() { "0".to_string() } else { conf.join(", ") },
            t[t.len() / 2]
        )
    }
}
