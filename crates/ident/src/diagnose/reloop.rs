//! Phase 9: an identified loop fitted again with an accepted grey-box law in place (the
//! law's load slows the valve's flow), and the loop's final description.

use super::*;

/// What the loop's second look hands on.
pub(super) struct ReloopPhase {
    /// The recommended model's hypothesis: the grey-box phase's, plus the loop identified
    /// again when `reidentified`.
    pub(super) final_hyp: Hyp,
    /// The grey-box phase's law, scored afresh with the loop identified again.
    pub(super) greybox: Option<crate::greybox::GreyBox>,
    /// The identified loop for the report (the loop phase's, or described again with the law).
    pub(super) identified_loop: Option<crate::loopid::IdentifiedLoop>,
}

impl<'a> Phase<'a> for ReloopPhase {
    type Needs<'p>
        = (&'p NominalPhase<'a>, &'p LoopPhase<'a>, &'p GreyPhase)
    where
        'a: 'p;

    fn run(inp: &Inputs<'a>, (nom, lp, grey): Self::Needs<'_>) -> Result<Self, String> {
        let mut final_hyp = grey.final_hyp.clone();
        let mut greybox = grey.greybox.clone();
        // The loop identified again: (its hypothesis, held-out NRMSE before, after).
        let mut reidentified = None;
        let loop_h = lp.identified.as_ref().map(|l| &l.1);
        if let (Some(lh), Some(g)) = (loop_h, greybox.as_mut().filter(|g| g.accepted)) {
            if let Some((h, before, after)) =
                crate::loopid::reidentify(&lp.ctx, &final_hyp, lh, inp.opts.evals_per_param)
            {
                final_hyp.params.extend(h.params.iter().cloned());
                final_hyp.values.extend(h.values.iter().copied());
                g.nrmse_validation = lp.ctx.val_errors(&final_hyp).0;
                g.ratio_to_baseline = g.nrmse_validation.overall / nom.nrmse_baseline.overall;
                reidentified = Some((h, before, after));
            }
        }
        let config = inp.nominal;
        let identified_loop = match (&reidentified, &lp.identified, inp.opts.drive) {
            (Some((h, before, after)), Some(_), Drive::PositionPd(g)) => Some(
                crate::loopid::describe(config, &h.build(config), g.kp, h, *before, *after, true),
            ),
            (_, l, _) => l.as_ref().map(|l| l.0.clone()),
        };
        Ok(ReloopPhase {
            final_hyp,
            greybox,
            identified_loop,
        })
    }
}
