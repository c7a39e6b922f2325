//! Phase 5: the final catalogue model's held-out residual test.

use super::*;

/// What the residual test hands on.
#[derive(Clone)]
pub(super) struct ResidualPhase {
    pub(super) ext_err: Errors,
    pub(super) ext_val_sim: Replay,
    pub(super) test: crate::residual::ResidualTest,
    pub(super) cause: String,
}

impl<'a> Phase<'a> for ResidualPhase {
    type Needs<'p>
        = (
        &'p NominalPhase<'a>,
        &'p LoopPhase<'a>,
        &'p RefitPhase,
        &'p SearchPhase,
    )
    where
        'a: 'p;

    fn run(inp: &Inputs<'a>, (nom, lp, rf, search): Self::Needs<'_>) -> Result<Self, String> {
        let _ = inp;
        Ok(phase_residual_test(nom, &lp.ctx, rf, search))
    }
}

/// Test the final model's held-out residual per channel (level and whiteness):
/// `none` only when it is noise, `unexplained` when nothing was accepted and it is not.
/// With nothing fitted ([`RefitPhase::fitted`] false, no effect accepted) colour is excused
/// only at the floor ([`crate::residual::LEVEL_SOFT_UNFITTED`]).
pub(super) fn phase_residual_test(
    nom: &NominalPhase<'_>,
    ctx: &Ctx<'_>,
    rf: &RefitPhase,
    search: &SearchPhase,
) -> ResidualPhase {
    let (ext_err, ext_val_sim) = ctx.val_errors(&search.current);
    let soft_level = if rf.fitted || !search.accepted.is_empty() {
        crate::residual::LEVEL_SOFT
    } else {
        crate::residual::LEVEL_SOFT_UNFITTED
    };
    let test = crate::residual::test(
        if search.accepted.is_empty() {
            "nominal refit"
        } else {
            "extended"
        },
        nom.val_rec,
        &ext_val_sim,
        nom.val_range.clone(),
        &rf.floor_ch,
        soft_level,
    );
    let cause = search.accepted.first().map_or_else(
        || {
            if test.noise {
                "none".to_string()
            } else {
                "unexplained".to_string()
            }
        },
        |e| e.as_str().to_string(),
    );
    ResidualPhase {
        ext_err,
        ext_val_sim,
        test,
        cause,
    }
}
