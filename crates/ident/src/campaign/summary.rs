//! A campaign's cause and summary in words.

use super::*;

/// Four significant digits, in scientific notation outside 0.01 … 10⁵.
pub(super) fn fmt_coef(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 1e5 || v.abs() < 1e-2 {
        format!("{v:.3e}")
    } else {
        let digits = (3 - v.abs().log10().floor() as i32).max(0) as usize;
        format!("{v:.digits$}")
    }
}

/// `+ v` or `− |v|` for a term of a sum.
pub(super) fn signed(v: f64) -> String {
    if v < 0.0 {
        format!("− {}", fmt_coef(-v))
    } else {
        format!("+ {}", fmt_coef(v))
    }
}

/// The leading term and its dependence in words, e.g.
/// `load-side Dahl yield force 124 N + 1027 N/A·current`.
pub(super) fn cause_of(terms: &[TermFit], cfg: &RigConfig, names: &[String]) -> String {
    let Some(t) = terms.first() else {
        return "none".into();
    };
    let mut s = format!("{} {} {}", t.name, fmt_coef(t.at_zero), t.unit);
    for n in names {
        let Some((form, c)) = t.dependence.get(n) else {
            continue;
        };
        let (tu, u) = (&t.unit, &cfg.inputs[n].unit);
        s += &match form {
            Form::None => String::new(),
            Form::Linear => format!(" {} {tu}/{u}·{n}", signed(c[0])),
            Form::Quadratic => format!(
                " {} {tu}/{u}·{n} {} {tu}/{u}²·{n}²",
                signed(c[0]),
                signed(c[1])
            ),
            Form::Saturating { scale } => format!(
                " {} {tu}·(1 − exp(−{n}/{} {u}))",
                signed(c[0]),
                fmt_coef(*scale)
            ),
            Form::Piecewise { knot } => format!(
                " {} {tu}/{u}·{n} {} {tu}/{u}·max({n} − {} {u}, 0)",
                signed(c[0]),
                signed(c[1]),
                fmt_coef(*knot)
            ),
        };
    }
    s
}

/// The summary's sentence on a Dahl shape (pre-yield travel, series velocity) that follows the
/// input.
pub(super) fn travel_text(t: &TravelDependence) -> String {
    let line = |a: f64, b: f64, u: &str| {
        format!(
            "{a:.3e} {u} {} {:.3e} {u}/{}·{}",
            if b < 0.0 { "−" } else { "+" },
            b.abs(),
            t.unit,
            t.input
        )
    };
    let what = match (t.travel_varies(), t.velocity_varies()) {
        (true, true) => format!(
            "The pre-yield travel follows {}: δ = {}, and the series-dashpot velocity too: V = {}",
            t.input,
            line(t.at_zero, t.slope, "m"),
            line(t.velocity_at_zero, t.velocity_slope, "m/s")
        ),
        (false, true) => format!(
            "The series-dashpot velocity follows {}: V = {} (δ = {:.3e} m)",
            t.input,
            line(t.velocity_at_zero, t.velocity_slope, "m/s"),
            t.at_zero
        ),
        _ => format!(
            "The pre-yield travel follows {}: δ = {}{}",
            t.input,
            line(t.at_zero, t.slope, "m"),
            if t.velocity_at_zero > 0.0 {
                format!(" (V = {:.3e} m/s)", t.velocity_at_zero)
            } else {
                String::new()
            }
        ),
    };
    format!(
        "{what} (chosen per operating point: {}; transfer NRMSE {:.4} with one shape for all, {:.4} with the shape following {}).",
        t.per_point
            .iter()
            .map(|(i, d, v)| format!("δ {d:.1e} m, V {v:.1e} m/s at {i} {}", t.unit))
            .collect::<Vec<_>>()
            .join("; "),
        t.nrmse_transfer_shared,
        t.nrmse_transfer,
        t.input
    )
}

pub(super) fn summary_of(
    cause: &str,
    pooled: &Scores,
    records: &[RecordScore],
    terms: &[TermFit],
    shape: Shape,
    dependence: &str,
    arx: &str,
) -> String {
    let verdict = if pooled.law <= pooled.arx {
        "beats the linear black box"
    } else {
        "does NOT beat the linear black box: the law's library misses what the records hold"
    };
    let mut s = format!(
        "Campaign law: held-out force NRMSE {:.4} pooled over {} records (nominal {:.4}, ARX {:.4}): it {verdict}. Cause: {cause}.\n",
        pooled.law,
        records.len(),
        pooled.nominal,
        pooled.arx
    );
    s += &format!(
        "Law: {} (pre-yield travel δ = {:.3e} m, series-dashpot velocity V = {:.3e} m/s, smoothing velocity v_s = {:.3e} m/s; velocity from x by a least-squares derivative over ±{:.0} ms where a record gives no `v`, all four chosen by the transfer error). Input dependence chosen {dependence}.\n",
        terms
            .iter()
            .map(|t| {
                let deps: String = t
                    .dependence
                    .iter()
                    .map(|(n, (f, _))| format!(", {} in {n}", f.describe()))
                    .collect();
                format!("{} ({:.0} % of the force variance{deps})", t.name, 100.0 * t.share)
            })
            .collect::<Vec<_>>()
            .join(", "),
        shape.dahl_travel,
        shape.dahl_velocity,
        shape.smoothing_velocity,
        shape.velocity_window * 1e3
    );
    for r in records {
        s += &format!(
            "  {} [{}] at {}: law {:.4}, nominal {:.4}, ARX {:.4}; {:.0} % band covers {:.0} %{}\n",
            r.source,
            r.role,
            ehactl_config::inputs::describe_point(&r.operating_point),
            r.nrmse.law,
            r.nrmse.nominal,
            r.nrmse.arx,
            100.0 * r.band.level,
            100.0 * r.band.coverage,
            if r.envelope.inside {
                String::new()
            } else {
                format!(" — {}", r.envelope.describe())
            }
        );
    }
    s += &format!("Baseline: {arx}.");
    s
}
