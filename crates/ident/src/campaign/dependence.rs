//! How each coefficient depends on the operating inputs: the forms, chosen by leaving one
//! operating point out (three or more points) or by the transfer error.

use super::*;

/// How one coefficient depends on one input.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "form", rename_all = "snake_case")]
pub enum Form {
    /// Constant.
    None,
    /// c₀ + c₁·i.
    Linear,
    /// c₀ + c₁·(1 − exp(−i/scale)), `scale` in the input's unit.
    Saturating {
        /// Saturation scale i_s (input unit).
        scale: f64,
    },
    /// c₀ + c₁·i + c₂·i².
    Quadratic,
    /// c₀ + c₁·i + c₂·max(i − knot, 0): piecewise linear with its knee at a fitted operating
    /// point between the outer ones.
    Piecewise {
        /// The knee i_k (input unit).
        knot: f64,
    },
}

impl Form {
    /// Basis functions of the input beyond the constant.
    pub(super) fn basis(self, i: f64) -> [Option<f64>; 2] {
        match self {
            Form::None => [None, None],
            Form::Linear => [Some(i), None],
            Form::Saturating { scale } => [Some(1.0 - (-i / scale).exp()), None],
            Form::Quadratic => [Some(i), Some(i * i)],
            Form::Piecewise { knot } => [Some(i), Some((i - knot).max(0.0))],
        }
    }

    pub(super) fn parameters(self) -> usize {
        match self {
            Form::None => 0,
            Form::Quadratic | Form::Piecewise { .. } => 2,
            _ => 1,
        }
    }

    pub(super) fn describe(self) -> String {
        match self {
            Form::None => "none".into(),
            Form::Linear => "linear".into(),
            Form::Saturating { scale } => format!("saturating (scale {scale:.4})"),
            Form::Quadratic => "quadratic".into(),
            Form::Piecewise { knot } => format!("piecewise linear (knee at {knot:.4})"),
        }
    }
}

/// A term and its dependence on each input.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Structure {
    pub(super) terms: Vec<(LawTerm, Vec<Form>)>,
}

/// The forms a term may take per input, given the fitting operating points: none, linear
/// (two distinct values), saturating (three), quadratic and piecewise linear with its knee at
/// each inner fitted value (four: a three-parameter form left one point out still has three
/// to pass through, so leaving one out can judge it).
pub(super) fn forms_per_input(prepared: &[Prepared<'_>], inputs: usize) -> Vec<Vec<Form>> {
    (0..inputs)
        .map(|k| {
            let i_max = prepared
                .iter()
                .filter(|p| !p.validation)
                .map(|p| p.at[k].abs())
                .fold(0.0, f64::max);
            let values = distinct_values(prepared, k);
            let distinct = values.len();
            let mut f = vec![Form::None];
            if distinct >= 2 && i_max > 0.0 {
                f.push(Form::Linear);
            }
            if distinct >= 3 && i_max > 0.0 {
                f.extend(
                    SATURATION_SCALES
                        .iter()
                        .map(|s| Form::Saturating { scale: s * i_max }),
                );
            }
            if distinct >= 4 {
                f.push(Form::Quadratic);
                f.extend(
                    values[1..distinct - 1]
                        .iter()
                        .map(|&knot| Form::Piecewise { knot }),
                );
            }
            f
        })
        .collect()
}

/// Leave-one-operating-point-out error: per operating point, fit on every other one and
/// predict its records; the mean over records of their NRMSE² (`None` when a fold cannot be
/// fitted).
pub(super) fn loco_error(
    d: &ShapeData,
    prepared: &[Prepared<'_>],
    ex: &Expanded,
    library: &[LawTerm],
    st: &Structure,
    groups: &[usize],
) -> Option<f64> {
    let p = ex.cols.len();
    let cols = columns_of(st, ex, library);
    let mut per = Vec::new();
    for &g in groups {
        let mut train = Normal::zero(p);
        for (i, pr) in prepared.iter().enumerate() {
            if !pr.validation && pr.group != g {
                train.add(&d.a[i]);
                train.add(&d.b[i]);
            }
        }
        let th = train.solve(&cols, ex)?;
        for (i, pr) in prepared.iter().enumerate() {
            if !pr.validation && pr.group == g {
                let mut test = d.a[i].clone();
                test.add(&d.b[i]);
                per.push(test.sse(&cols, &th) / test.var_sum());
            }
        }
    }
    Some(per.iter().sum::<f64>() / per.len().max(1) as f64)
}

#[allow(clippy::too_many_arguments)]
pub(super) fn choose_dependence(
    d: &ShapeData,
    prepared: &[Prepared<'_>],
    library: &[LawTerm],
    ex: &Expanded,
    mut st: Structure,
    candidates: &[Vec<Form>],
    groups: &[usize],
    names: &[String],
) -> (Structure, String) {
    if names.is_empty() {
        return (st, "no operating inputs declared".into());
    }
    let by_loco = groups.len() >= 3;
    let score = |s: &Structure| -> f64 {
        let e = if by_loco {
            loco_error(d, prepared, ex, library, s, groups)
        } else {
            transfer_error(d, ex, library, s)
        };
        e.unwrap_or(f64::INFINITY)
    };
    // Greedy moves from two starts — no dependence, and the selection's (linear in every input
    // where the campaign allows it) — each move changing one term's form in one input, kept
    // while it lowers the score by at least 1 % (a parameter must earn its place); the better
    // end point wins.
    let selected = st.clone();
    for t in st.terms.iter_mut() {
        t.1 = vec![Form::None; names.len()];
    }
    let start = score(&st);
    let (a, ea) = descend(st, start, candidates, &score);
    let s1 = score(&selected);
    let (b, eb) = descend(selected, s1, candidates, &score);
    let (st, best) = if eb < ea { (b, eb) } else { (a, ea) };
    let how = if by_loco {
        format!(
            "by leaving one operating point out ({} points): rms over records of the NRMSE on the point left out {:.4} without any dependence, {:.4} with the chosen ones",
            groups.len(),
            start.sqrt(),
            best.sqrt()
        )
    } else if groups.len() == 2 {
        format!(
            "by the transfer error only (transfer NRMSE {:.4} without, {:.4} with): with two operating points any two-parameter form passes through both, so the dependence is NOT validated across operating points; a third operating point would test it",
            start.sqrt(),
            best.sqrt()
        )
    } else {
        "one operating point: no dependence can be identified".into()
    };
    (st, how)
}

/// Greedy descent over the forms from `st` (score `best`): each step takes the single change
/// of one term's form in one input that lowers `score` most, if by at least 1 %.
pub(super) fn descend(
    mut st: Structure,
    mut best: f64,
    candidates: &[Vec<Form>],
    score: &dyn Fn(&Structure) -> f64,
) -> (Structure, f64) {
    loop {
        let mut improved: Option<(Structure, f64)> = None;
        for ti in 0..st.terms.len() {
            for (k, forms) in candidates.iter().enumerate() {
                for f in forms {
                    if *f == st.terms[ti].1[k] {
                        continue;
                    }
                    let mut s = st.clone();
                    s.terms[ti].1[k] = *f;
                    let e = score(&s);
                    if e < 0.99 * improved.as_ref().map_or(best, |i| i.1) {
                        improved = Some((s, e));
                    }
                }
            }
        }
        match improved {
            Some((s, e)) => {
                st = s;
                best = e;
            }
            None => break,
        }
    }
    (st, best)
}
