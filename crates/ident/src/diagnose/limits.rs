//! Phase 8: the detection limits of the catalogue effects not named ([`crate::limits`]).

use super::*;

/// The smallest size of every catalogue effect tested and not named that this record would
/// have revealed (effect id → limit); empty when `Options::detection_limits` is off.
pub(super) struct LimitsPhase(pub(super) BTreeMap<String, crate::limits::DetectionLimit>);

impl<'a> Phase<'a> for LimitsPhase {
    type Needs<'p>
        = (
        &'p LoopPhase<'a>,
        &'p RefitPhase,
        &'p SearchPhase,
        &'p GreyPhase,
    )
    where
        'a: 'p;

    /// Judged on the recommended model (the grey-box phase's), for the effects the kept
    /// search did not accept.
    fn run(inp: &Inputs<'a>, (lp, rf, search, grey): Self::Needs<'_>) -> Result<Self, String> {
        if !inp.opts.detection_limits {
            return Ok(LimitsPhase(BTreeMap::new()));
        }
        let bar = inp.bar();
        bar.add_stage(1, "detection limits".to_string());
        let not_named: Vec<EffectId> = inp
            .opts
            .effects
            .iter()
            .copied()
            .filter(|e| !search.accepted.contains(e))
            .collect();
        let l = crate::limits::detection_limits(
            &lp.ctx,
            &grey.final_hyp,
            &rf.floor_ch,
            &not_named,
            &lp.nominal,
            &rf.scales,
            &rf.analysis_refit,
        );
        bar.inc();
        Ok(LimitsPhase(l))
    }
}
