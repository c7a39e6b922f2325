//! Phase 1 of a campaign: the records prepared (fitting parts, operating points, groups) and the
//! setup every later phase reads.

use super::*;

/// One record as the campaign uses it.
pub(super) struct Prepared<'a> {
    pub(super) rec: &'a Record,
    /// Rod force to explain (N): the load-cell force minus the config's load spring.
    pub(super) y: Vec<f64>,
    pub(super) force: &'a [f64],
    pub(super) x: &'a [f64],
    pub(super) dp: Option<Vec<f64>>,
    /// Operating input values per sample, in the order of the config's inputs.
    pub(super) op: Vec<Vec<f64>>,
    /// Median operating point per input.
    pub(super) at: Vec<f64>,
    /// Operating-point group (index into the campaign's distinct points).
    pub(super) group: usize,
    /// Samples the law is fitted on (the transfer split inside it) and the held-out samples.
    pub(super) fit: Range<usize>,
    pub(super) score: Range<usize>,
    pub(super) validation: bool,
}

/// What a campaign may fit: its records prepared and grouped by operating point, the law's
/// library and the dependence forms each input allows.
pub(super) struct Setup<'a> {
    pub(super) names: Vec<String>,
    /// Unit of each input.
    pub(super) units: Vec<String>,
    pub(super) notes: Vec<String>,
    pub(super) prepared: Vec<Prepared<'a>>,
    /// Operating-point groups with fitted records.
    pub(super) fit_groups: Vec<usize>,
    pub(super) library: Vec<LawTerm>,
    /// RMS velocity of the fitting parts (m/s).
    pub(super) v_rms: f64,
    /// Forms a term may take per input.
    pub(super) candidate_forms: Vec<Vec<Form>>,
    /// The form per input while the terms are chosen: linear where the campaign allows it.
    pub(super) default_forms: Vec<Form>,
    /// The library expanded with every candidate form.
    pub(super) expanded: Expanded,
}

/// Phase 1: prepare the records, group them by operating point, choose the library (the
/// load-pressure terms only when every record has p_a and p_b) and the forms per input.
pub(super) fn setup<'a>(
    cfg: &RigConfig,
    fit: &'a [Record],
    validation: &'a [Record],
) -> Result<Setup<'a>, String> {
    if fit.is_empty() {
        return Err("a campaign needs at least one --data record".into());
    }
    let names: Vec<String> = cfg.inputs.keys().cloned().collect();
    let mut notes = Vec::new();
    let mut prepared = Vec::new();
    for (rec, val) in fit
        .iter()
        .map(|r| (r, false))
        .chain(validation.iter().map(|r| (r, true)))
    {
        prepared.push(prepare(
            cfg,
            &names,
            rec,
            val,
            !validation.is_empty(),
            &mut notes,
        )?);
    }
    let fit_groups = group_by_point(&mut prepared);
    let has_dp = prepared.iter().all(|p| p.dp.is_some());
    let library: Vec<LawTerm> = LIBRARY
        .iter()
        .copied()
        .filter(|t| has_dp || !t.needs_pressure())
        .collect();
    let v_rms = {
        let v: Vec<f64> = prepared
            .iter()
            .flat_map(|p| record_velocity(p.rec, p.x, 8.0 * p.rec.dt)[p.fit.clone()].to_vec())
            .collect();
        (v.iter().map(|a| a * a).sum::<f64>() / v.len().max(1) as f64).sqrt()
    };
    if !(v_rms > 0.0) {
        return Err("the fitting parts of the records hold no motion (x is constant): a load law cannot be identified from them".into());
    }
    let candidate_forms = forms_per_input(&prepared, names.len());
    let fitted_points: Vec<Vec<f64>> = prepared
        .iter()
        .filter(|p| !p.validation)
        .map(|p| p.at.clone())
        .collect();
    let admissible = Admissible::new(&library, cfg.plant.mechanics.load_stiffness, &fitted_points);
    let expanded = expand(&library, &candidate_forms, &admissible);
    let default_forms: Vec<Form> = candidate_forms
        .iter()
        .map(|f| {
            if f.contains(&Form::Linear) {
                Form::Linear
            } else {
                Form::None
            }
        })
        .collect();
    Ok(Setup {
        units: names.iter().map(|n| cfg.inputs[n].unit.clone()).collect(),
        names,
        notes,
        prepared,
        fit_groups,
        library,
        v_rms,
        candidate_forms,
        default_forms,
        expanded,
    })
}

/// Number each record's distinct operating point (`group`); the groups with fitted records.
pub(super) fn group_by_point(prepared: &mut [Prepared<'_>]) -> Vec<usize> {
    let mut points: Vec<Vec<f64>> = Vec::new();
    for p in prepared.iter_mut() {
        let g = points
            .iter()
            .position(|q| same_point(q, &p.at))
            .unwrap_or_else(|| {
                points.push(p.at.clone());
                points.len() - 1
            });
        p.group = g;
    }
    let mut g: Vec<usize> = prepared
        .iter()
        .filter(|p| !p.validation)
        .map(|p| p.group)
        .collect();
    g.sort_unstable();
    g.dedup();
    g
}

pub(super) fn same_point(a: &[f64], b: &[f64]) -> bool {
    a.iter()
        .zip(b)
        .all(|(x, y)| (x - y).abs() <= 1e-9 * x.abs().max(y.abs()).max(1.0))
}

/// The distinct values of input `k` over the fitting records, in ascending order.
pub(super) fn distinct_values(prepared: &[Prepared<'_>], k: usize) -> Vec<f64> {
    let mut v: Vec<f64> = prepared
        .iter()
        .filter(|p| !p.validation)
        .map(|p| p.at[k])
        .collect();
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| same_point(&[*a], &[*b]));
    v
}

pub(super) fn prepare<'a>(
    cfg: &RigConfig,
    names: &[String],
    rec: &'a Record,
    validation: bool,
    whole_fit: bool,
    notes: &mut Vec<String>,
) -> Result<Prepared<'a>, String> {
    let src = &rec.source;
    let x = rec
        .channel(ChannelKind::Position)
        .ok_or_else(|| format!("{src}: a campaign imposes each record's measured motion on the rod and needs the position column `x` (m)"))?;
    let force = rec.channel(ChannelKind::Force).ok_or_else(|| {
        format!("{src}: a campaign predicts the load-cell force and needs the column `force` (N)")
    })?;
    let mut op = Vec::new();
    let mut at = Vec::new();
    for name in names {
        let inp = &cfg.inputs[name];
        match rec.input(name) {
            Some(v) => {
                at.push(rec.input_median(name).unwrap_or(inp.value));
                op.push(v.to_vec());
            }
            None => {
                notes.push(format!(
                    "{src}: no `{name}` column; taken at the config's operating point {} {}",
                    inp.value, inp.unit
                ));
                at.push(inp.value);
                op.push(vec![inp.value; rec.len()]);
            }
        }
    }
    let n = rec.len();
    let (fit, score) = if validation {
        (0..0, 0..n)
    } else if whole_fit {
        (0..n, 0..0)
    } else {
        let nf = ((1.0 - HOLDOUT) * n as f64).round() as usize;
        if nf < 20 || n - nf < 10 {
            return Err(format!(
                "{src}: {n} samples are too few to hold out {:.0} %",
                HOLDOUT * 100.0
            ));
        }
        (0..nf, nf..n)
    };
    let p = &cfg.plant;
    let y: Vec<f64> = force
        .iter()
        .zip(x)
        .map(|(f, xk)| f - p.mechanics.load_stiffness * (xk - p.mechanics.load_contact_position))
        .collect();
    let dp = match (
        rec.channel(ChannelKind::PressureA),
        rec.channel(ChannelKind::PressureB),
    ) {
        (Some(a), Some(b)) => Some(a.iter().zip(b).map(|(a, b)| a - b).collect()),
        _ => None,
    };
    Ok(Prepared {
        rec,
        y,
        force,
        x,
        dp,
        op,
        at,
        group: 0,
        fit,
        score,
        validation,
    })
}
