//! Phase 2: the rig's loop, when the config marks it as an assumption, identified on its own
//! output before anything else ([`crate::loopid`]); every later model keeps it.

use super::*;

/// What the loop phase hands on.
pub(super) struct LoopPhase<'a> {
    /// The replay context every later phase replays in: the nominal phase's, with the
    /// identified loop in its base parameters.
    pub(super) ctx: Ctx<'a>,
    /// The config's nominal parameters with the identified loop written in and its
    /// uncertainty spent (the later refit leaves it).
    pub(super) nominal: PlantParams,
    /// The identified loop (its report and hypothesis), `None` when the loop is not an
    /// assumption.
    pub(super) identified: Option<(crate::loopid::IdentifiedLoop, Hyp)>,
}

impl<'a> Phase<'a> for LoopPhase<'a> {
    type Needs<'p>
        = (&'p NominalPhase<'a>,)
    where
        'a: 'p;

    /// Nothing to identify when the configured step explains the record (nothing is
    /// refitted then).
    fn run(inp: &Inputs<'a>, (nom,): Self::Needs<'_>) -> Result<Self, String> {
        let (ctx, nominal, identified) = if nom.integration.configured_step_explains {
            (nom.ctx.clone(), inp.nominal.clone(), None)
        } else {
            crate::loopid::identify(nom.ctx.clone(), inp.nominal, inp.opts.evals_per_param)
        };
        Ok(LoopPhase {
            ctx,
            nominal,
            identified,
        })
    }
}
