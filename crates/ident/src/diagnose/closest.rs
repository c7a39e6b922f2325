//! Phase 6: the search's first named cause when it does not explain the record.

use super::*;

/// The refit's noise floor per channel, by column.
pub(super) fn floors_by_column(nom: &NominalPhase<'_>, rf: &RefitPhase) -> Vec<(String, f64)> {
    nom.val_rec
        .channels
        .iter()
        .zip(&rf.floor_ch)
        .map(|(c, f)| (c.kind.column().to_string(), *f))
        .collect()
}

/// The search's first named cause when it does not explain the record ([`closest_fit`]).
pub(super) struct ClosestPhase(pub(super) Option<crate::edge::Closest>);

impl<'a> Phase<'a> for ClosestPhase {
    type Needs<'p>
        = (
        &'p NominalPhase<'a>,
        &'p RefitPhase,
        &'p SearchPhase,
        &'p ResidualPhase,
    )
    where
        'a: 'p;

    fn run(inp: &Inputs<'a>, (nom, rf, search, resid): Self::Needs<'_>) -> Result<Self, String> {
        let _ = inp;
        Ok(ClosestPhase(closest_fit(nom, rf, search, &resid.ext_err)))
    }
}

/// The search's first named cause when it does not explain the record: its fit in the final
/// model is at the edge of its range or of the record ([`crate::edge::edge_reasons`]), or the
/// final model (held-out errors `ext_err`) leaves a channel far above its floor
/// ([`crate::edge::far_channels`]). `None` when nothing was accepted or the cause stands.
fn closest_fit(
    nom: &NominalPhase<'_>,
    rf: &RefitPhase,
    search: &SearchPhase,
    ext_err: &Errors,
) -> Option<crate::edge::Closest> {
    let e = *search.accepted.first()?;
    let h = &search.current;
    let edge = crate::edge::edge_reasons(h, e, nom.val_rec.dt, crate::edge::NAMED_BOUND_SHARE);
    let far = crate::edge::far_channels(ext_err, &floors_by_column(nom, rf));
    if edge.is_empty() && far.is_empty() {
        return None;
    }
    let variant = h
        .effects
        .iter()
        .zip(&h.variants)
        .find(|(x, _)| **x == e)
        .map_or("-", |(_, v)| *v);
    Some(crate::edge::Closest {
        effect: e.as_str().to_string(),
        variant: variant.to_string(),
        at_edge: !edge.is_empty(),
        reasons: edge.into_iter().chain(far).collect(),
        nrmse_validation: ext_err.overall,
    })
}
