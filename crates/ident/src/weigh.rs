//! Weighing the evidence between effects, after the held-out score has ranked them
//! ([`mod@crate::diagnose`]): the order of the accepted causes by the error each explains on the
//! final model ([`order_by_explained`]), and a second look at a weak round winner against the
//! runner-up on the evidence that tells the two apart ([`second_look`]).

use crate::analysis::{analyse, Analysis};
use crate::ctx::{Ctx, Errors, Hyp};
use crate::effects::{of, Signature};
use ehactl_plant::EffectId;

/// `h` without effect `e`: its parameters (dotted paths `effects.<id>.…`), its entry in the
/// effect and variant lists dropped; every other value as fitted.
pub(crate) fn without_effect(h: &Hyp, e: EffectId) -> Hyp {
    let prefix = format!("effects.{}.", e.as_str());
    let (params, values) = h
        .params
        .iter()
        .zip(&h.values)
        .filter(|(p, _)| !p.name.starts_with(&prefix))
        .map(|(p, v)| (p.clone(), *v))
        .unzip();
    let (effects, variants) = h
        .effects
        .iter()
        .zip(&h.variants)
        .filter(|(x, _)| **x != e)
        .map(|(x, v)| (*x, *v))
        .unzip();
    Hyp {
        effects,
        variants,
        params,
        values,
    }
}

/// The accepted effects of the final model `h` ordered by the held-out error each explains:
/// each is removed in turn, the other parameters refit from their final values (bounded
/// Nelder–Mead, [`Ctx::fit`]) and the model re-scored; the effect whose removal leaves the
/// larger held-out J = mean NRMSE² comes first. The refit matters: without it, an effect whose
/// fit balances another's (independent generator seed 7004 of `bench/indep_cases.txt`: a dead
/// band's zero offset balancing an asymmetric saturation fitted to a symmetric soft one)
/// looks indispensable, since removing either alone unbalances the pair. Returns the order
/// and, when it differs from the acceptance order `accepted`, a sentence with the figures
/// (held-out NRMSE without each effect, `final_err` with all of them). One refit per accepted
/// effect, only when two or more were accepted.
pub(crate) fn order_by_explained(
    ctx: &Ctx<'_>,
    h: &Hyp,
    accepted: &[EffectId],
    final_err: &Errors,
    evals_per_param: usize,
) -> (Vec<EffectId>, Option<String>) {
    if accepted.len() < 2 {
        return (accepted.to_vec(), None);
    }
    let mut without: Vec<(EffectId, f64)> = accepted
        .iter()
        .map(|&e| {
            let rest = without_effect(h, e);
            let n = rest.params.len();
            let (rest, _) = ctx.fit(rest, n, evals_per_param);
            let o = ctx.val_errors(&rest).0.overall;
            (e, if o.is_finite() { o } else { f64::INFINITY })
        })
        .collect();
    // Stable: equal figures keep the acceptance order.
    without.sort_by(|a, b| b.1.total_cmp(&a.1));
    let order: Vec<EffectId> = without.iter().map(|w| w.0).collect();
    let note = (order != accepted).then(|| {
        format!(
            "the causes are named in the order of the held-out error each explains on the final model (NRMSE {:.4} with all of them; without {}), not in the order they were accepted ({})",
            final_err.overall,
            without
                .iter()
                .map(|(e, o)| format!("`{}` {o:.4}", e.as_str()))
                .collect::<Vec<_>>()
                .join(", "),
            accepted
                .iter()
                .map(|e| format!("`{}`", e.as_str()))
                .collect::<Vec<_>>()
                .join(" then ")
        )
    });
    (order, note)
}

/// How much residual a model with held-out analysis `an` and overall NRMSE `overall` leaves
/// where signature `s` lives (-): the RMS of the normalised residual in that part of the
/// record (the analysis' ratio to the overall RMS × the overall NRMSE), or for a mode the
/// residual-to-signal spectrum ratio at its peak. `None` for [`Signature::Other`].
fn left_in(s: Signature, an: &Analysis, overall: f64) -> Option<f64> {
    match s {
        Signature::Level => Some(an.large_command_ratio * overall),
        Signature::SmallCommand => Some(an.small_command_ratio * overall),
        Signature::Reversal => Some(an.reversal_ratio * overall),
        Signature::Mode => Some(an.mode_ratio),
        Signature::Other => None,
    }
}

/// Least share of the error above the noise floor a round winner must explain to be named on
/// its score alone (-).
pub(crate) const WEAK_SHARE: f64 = 0.5;

/// A fitted candidate of one round as the second look needs it.
pub(crate) struct Fitted<'a> {
    /// The effect.
    pub(crate) e: EffectId,
    /// Current model + the effect, as fitted.
    pub(crate) h: &'a Hyp,
    /// Held-out errors.
    pub(crate) err: &'a Errors,
    /// Share of the current error above the floor it leaves (-), as `judge` computes it.
    pub(crate) excess: f64,
    /// Whether it passed the acceptance test.
    pub(crate) significant: bool,
}

/// Why a round winner is weak evidence, or `None`: one of its own parameters ended within
/// 0.5 % of the span from a bound of its range (a fit at a corner: the effect's shape is
/// forced onto an error of another shape); it explains less than [`WEAK_SHARE`] of the error
/// above the floor; or it leaves a residual above `residual::LEVEL_LARGE` × the floor on some
/// channel while the runner-up explains at least [`WEAK_SHARE`] too (two effects fitting the
/// same part of an error neither removes).
fn weakness(
    w: &Fitted<'_>,
    first_new: usize,
    floor_ch: &[(String, f64)],
    r: &Fitted<'_>,
) -> Option<String> {
    let corner: Vec<String> = w.h.params[first_new..]
        .iter()
        .zip(&w.h.values[first_new..])
        .filter(|(p, v)| {
            let u = p.to_unit(**v);
            p.hi > p.lo && !(0.005..=0.995).contains(&u)
        })
        .map(|(p, v)| {
            format!(
                "{} = {v:.4e} on a bound of [{:.4e}, {:.4e}]",
                p.name, p.lo, p.hi
            )
        })
        .collect();
    if !corner.is_empty() {
        return Some(format!(
            "its fit sits at a corner of its range ({})",
            corner.join("; ")
        ));
    }
    let share = 1.0 - w.excess.min(1.0);
    if share < WEAK_SHARE {
        return Some(format!(
            "it explains only {:.0} % of the error above the noise floor",
            100.0 * share
        ));
    }
    let worst = floor_ch
        .iter()
        .filter_map(|(c, f)| Some((c, w.err.channels.get(c)? / f.max(1e-300))))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    let r_share = 1.0 - r.excess.min(1.0);
    (worst.1 > crate::residual::LEVEL_LARGE && r_share >= WEAK_SHARE).then(|| {
        format!(
            "it leaves `{}` at {:.0}× its noise floor while {} explains {:.0} % of the error above the floor as well",
            worst.0,
            worst.1,
            r.e.as_str(),
            100.0 * r_share
        )
    })
}

/// The outcome of [`second_look`].
pub(crate) struct SecondLook {
    /// Name the runner-up instead of the winner (the evidence favours it and it passed the
    /// acceptance test itself).
    pub(crate) prefer_runner_up: bool,
    /// One sentence for `Diagnosis::ambiguities`: why the winner is weak, the evidence, the
    /// decision and the experiment that would separate the two.
    pub(crate) note: String,
}

/// Mode frequency of a fitted flexible mount, √(k/m)/2π (Hz), from its parameters in `h`
/// (stiffness k in N/m, moved mass m in kg); `None` when `h` has no mount.
pub(crate) fn mount_mode(h: &Hyp) -> Option<f64> {
    let get = |name: &str| {
        h.params
            .iter()
            .zip(&h.values)
            .find(|(p, _)| p.name == name)
            .map(|(_, v)| *v)
    };
    let k = get("effects.flexible_mount.stiffness")?;
    let m = get("effects.flexible_mount.load_mass")?;
    Some((k / m.max(1e-300)).sqrt() / std::f64::consts::TAU)
}

/// A second look at round winner `w` when it is weak evidence ([`weakness`]) against the
/// runner-up `r`, on the evidence that tells the two apart. Effects of different signatures
/// ([`Signature`]): the residual each leaves where the other's signature lives, from the
/// residual analysis of both held-out replays; the runner-up is favoured when it leaves less
/// where its own signature lives and no more where the winner's lives (a saturation against a
/// line: the level-dependent error at large commands, and the spectral peak). Two mode effects:
/// a mount whose fitted mode √(k/m)/2π is above the Nyquist frequency shows no mode in these
/// data (a quasi-static compliance fitted at a corner), so a line or β effect is favoured over
/// it. `None` when the winner is not weak. Two replays and two residual analyses.
pub(crate) fn second_look(
    ctx: &Ctx<'_>,
    w: &Fitted<'_>,
    r: &Fitted<'_>,
    first_new: usize,
    floor_ch: &[(String, f64)],
) -> Option<SecondLook> {
    let why = weakness(w, first_new, floor_ch, r)?;
    let an = |f: &Fitted<'_>| analyse(ctx.val_rec, &ctx.val_errors(f.h).1, ctx.val_range.clone());
    let (aw, ar) = (an(w), an(r));
    let (sw, sr) = (of(w.e).signature(), of(r.e).signature());
    let (we, re) = (w.e.as_str(), r.e.as_str());
    let lw = |s| left_in(s, &aw, w.err.overall);
    let lr = |s| left_in(s, &ar, r.err.overall);
    let (favours_r, evidence) = match (sw == sr, lw(sw), lr(sw), lw(sr), lr(sr)) {
        (false, Some(w_w), Some(r_w), Some(w_r), Some(r_r)) => (
            r_r < w_r && r_w <= w_w,
            format!(
                "residual left where the signature of `{re}` lives ({sr:?}): `{we}` {w_r:.4}, `{re}` {r_r:.4}; where that of `{we}` lives ({sw:?}): `{we}` {w_w:.4}, `{re}` {r_w:.4}"
            ),
        ),
        (true, ..) if sw == Signature::Mode => {
            let nyquist = 0.5 / ctx.val_rec.dt;
            match (mount_mode(w.h).filter(|_| w.e == EffectId::FlexibleMount), r.e) {
                (Some(f), re_id) if re_id != EffectId::FlexibleMount => (
                    f > nyquist,
                    format!(
                        "the fitted mount's mode √(k/m)/2π = {f:.0} Hz is {} the Nyquist frequency {nyquist:.0} Hz (the residual's spectral peak is near {:.1} Hz)",
                        if f > nyquist { "above" } else { "below" },
                        aw.mode_frequency
                    ),
                ),
                _ => (false, "both are modes; the residual analysis does not separate them".to_string()),
            }
        }
        _ => (false, "the residual analysis does not localise one of them".to_string()),
    };
    let prefer_runner_up = favours_r && r.significant;
    let decision = match (favours_r, prefer_runner_up) {
        (true, true) => format!("the evidence favours `{re}`, which is named"),
        (true, false) => format!("the evidence favours `{re}`, but it did not pass the acceptance test itself, so `{we}` is kept"),
        _ => format!("the evidence does not favour `{re}`, so `{we}` is kept"),
    };
    let note = format!(
        "`{we}` fits best by held-out score (NRMSE {:.4}) but is weak evidence: {why}. Runner-up `{re}`: NRMSE {:.4}, {:.0} % of the error above the noise floor explained. Evidence: {evidence}; {decision}. To separate them: {}",
        w.err.overall,
        r.err.overall,
        100.0 * (1.0 - r.excess.min(1.0)),
        separating_experiment(w.e, r.e)
    );
    Some(SecondLook {
        prefer_runner_up,
        note,
    })
}

/// Experiment that separates two effects the data could not tell apart (the rule of
/// either effect's module, [`crate::effects::EffectFit::separates_from`]).
pub fn separating_experiment(a: EffectId, b: EffectId) -> String {
    crate::effects::separating_experiment(a, b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::freeparam::FreeParam;
    use std::collections::BTreeMap;
    use std::sync::Arc;

    fn param(name: &str, lo: f64, hi: f64) -> FreeParam {
        FreeParam::new(name, lo, hi, false, lo, Arc::new(|_, _| {}))
    }

    /// A model: one nominal factor, then a dead band (2 parameters), then a delay (1).
    fn model(values: [f64; 4]) -> Hyp {
        Hyp {
            effects: vec![EffectId::ValveDeadband, EffectId::TimeDelay],
            variants: vec!["overlap", "-"],
            params: vec![
                param("valve.rated_flow/nominal", 0.9, 1.1),
                param("effects.valve_deadband.overlap", 0.0, 0.3),
                param("effects.valve_deadband.zero_offset", -0.1, 0.1),
                param("effects.time_delay.delay", 0.0, 0.02),
            ],
            values: values.to_vec(),
        }
    }

    fn errors(x: f64) -> Errors {
        Errors {
            channels: BTreeMap::from([("x".to_string(), x)]),
            overall: x,
        }
    }

    #[test]
    fn removing_an_effect_keeps_the_others_as_fitted() {
        let h = without_effect(&model([1.05, 0.02, -0.01, 0.004]), EffectId::ValveDeadband);
        assert_eq!(h.effects, vec![EffectId::TimeDelay]);
        assert_eq!(h.variants, vec!["-"]);
        let names: Vec<&str> = h.params.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(
            names,
            ["valve.rated_flow/nominal", "effects.time_delay.delay"]
        );
        assert_eq!(h.values, vec![1.05, 0.004]);
    }

    /// A winner on a bound of its range, one that explains less than half of the excess, and
    /// one that leaves 8× the floor beside a runner-up explaining 60 %, are weak; a winner
    /// inside its range explaining 80 % and leaving 2× the floor is not.
    #[test]
    fn weak_winners() {
        fn fitted<'a>(h: &'a Hyp, err: &'a Errors, excess: f64) -> Fitted<'a> {
            Fitted {
                e: EffectId::TimeDelay,
                h,
                err,
                excess,
                significant: true,
            }
        }
        let floor = [("x".to_string(), 0.01)];
        let (e2, e8) = (&errors(0.02), &errors(0.08));
        let inside = &model([1.0, 0.1, 0.0, 0.004]);
        let corner = &model([1.0, 0.1, 0.0, 0.02]);
        let runner = fitted(inside, e2, 0.4);
        // The delay's parameters start at index 3.
        assert!(weakness(&fitted(corner, e2, 0.2), 3, &floor, &runner)
            .is_some_and(|w| w.contains("corner")));
        assert!(weakness(&fitted(inside, e2, 0.6), 3, &floor, &runner)
            .is_some_and(|w| w.contains("40 %")));
        assert!(weakness(&fitted(inside, e8, 0.2), 3, &floor, &runner)
            .is_some_and(|w| w.contains("8×")));
        assert!(weakness(&fitted(inside, e2, 0.2), 3, &floor, &runner).is_none());
        // The leftover alone is not enough when the runner-up explains less than half.
        let weak_runner = fitted(inside, e2, 0.7);
        assert!(weakness(&fitted(inside, e8, 0.2), 3, &floor, &weak_runner).is_none());
    }
}
