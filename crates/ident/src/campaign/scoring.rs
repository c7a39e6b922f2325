//! Phase 4 of a campaign: every record scored against the law, the nominal model and the ARX
//! baseline; the band and the fitted envelope written with the law.

use super::*;

/// Phase 5: the held-out part of every record predicted by the law, the nominal config and the
/// ARX baseline; per record and pooled (all scored samples, each record about its own mean),
/// with the baseline's structure.
pub(super) fn score(
    cfg: &RigConfig,
    su: &Setup<'_>,
    law: &LawFit,
    envelope: &ehactl_config::envelope::Envelope,
    spread: &Spread<'_>,
) -> Result<(Vec<RecordScore>, Scores, String), String> {
    let arx = arx_baseline(&su.prepared)?;
    let mut records = Vec::new();
    let (mut sse, mut var, mut sse_nom, mut sse_arx) = (0.0, 0.0, 0.0, 0.0);
    for (p, arx_pred) in su.prepared.iter().zip(&arx.1) {
        if p.score.is_empty() {
            continue;
        }
        let law_pred = law.predict(cfg, p)?;
        let member_preds: Vec<Vec<f64>> = spread
            .members
            .iter()
            .map(|m| m.predict(cfg, p))
            .collect::<Result<_, _>>()?;
        let band = crate::band::band(
            &law_pred,
            &member_preds,
            spread.relative_residual,
            crate::band::LEVEL,
            p.force,
            p.score.clone(),
        );
        let nom_pred = nominal_prediction(cfg, p, &su.names)?;
        let r = p.score.clone();
        let f = &p.force[r.clone()];
        let mean = f.iter().sum::<f64>() / f.len() as f64;
        let v: f64 = f
            .iter()
            .map(|a| (a - mean).powi(2))
            .sum::<f64>()
            .max(1e-300);
        let e = |pred: &[f64]| -> f64 {
            f.iter()
                .zip(&pred[r.clone()])
                .map(|(a, b)| (a - b).powi(2))
                .sum()
        };
        let (el, en, ea) = (e(&law_pred), e(&nom_pred), e(arx_pred));
        sse += el;
        sse_nom += en;
        sse_arx += ea;
        var += v;
        let inputs: BTreeMap<String, f64> =
            su.names.iter().cloned().zip(p.at.iter().copied()).collect();
        let motion =
            crate::envelope::motion_point(p.rec, p.x, r.clone(), law.shape.velocity_window, inputs);
        records.push(RecordScore {
            envelope: crate::envelope::check(envelope, &motion, &cfg.inputs),
            band,
            source: p.rec.source.clone(),
            role: if p.validation { "validation" } else { "fit" }.into(),
            operating_point: su.names.iter().cloned().zip(p.at.iter().copied()).collect(),
            scored: (r.start, r.end),
            nrmse: Scores {
                nominal: (en / v).sqrt(),
                law: (el / v).sqrt(),
                arx: (ea / v).sqrt(),
            },
        });
    }
    let pooled = Scores {
        nominal: (sse_nom / var).sqrt(),
        law: (sse / var).sqrt(),
        arx: (sse_arx / var).sqrt(),
    };
    Ok((records, pooled, arx.0))
}

/// The law's bootstrap refits and its out-of-sample relative residual (the band's inputs).
pub(super) struct Spread<'m> {
    pub(super) members: &'m [LawFit],
    pub(super) relative_residual: f64,
}

/// The `[band]` section of the extended config: each member as the law and dependences it
/// writes.
pub(super) fn band_section(
    cfg: &RigConfig,
    names: &[String],
    spread: &Spread<'_>,
) -> Result<Option<ehactl_config::envelope::Band>, String> {
    if spread.members.is_empty() {
        return Ok(None);
    }
    // A member whose law the config cannot hold (a parameter out of its range) is left out.
    let members: Vec<_> = spread
        .members
        .iter()
        .filter_map(|m| {
            let c = m.extended(cfg, names).ok()?;
            ehactl_config::envelope::BandMember::of(&c)
        })
        .collect();
    if members.len() < 2 {
        return Ok(None);
    }
    Ok(Some(ehactl_config::envelope::Band {
        level: crate::band::LEVEL,
        relative_residual: spread.relative_residual,
        members,
    }))
}

/// The motion and operating inputs of the fitting parts, merged per operating point
/// (`[envelope]` of the extended config).
pub(super) fn fitted_envelope(su: &Setup<'_>, window: f64) -> ehactl_config::envelope::Envelope {
    crate::envelope::merge(
        su.prepared
            .iter()
            .filter(|p| !p.validation && !p.fit.is_empty())
            .map(|p| {
                let inputs = su.names.iter().cloned().zip(p.at.iter().copied()).collect();
                crate::envelope::motion_point(p.rec, p.x, p.fit.clone(), window, inputs)
            })
            .collect(),
    )
}

/// The nominal model's force along record `p`: the config at the record's operating point.
pub(super) fn nominal_prediction(
    cfg: &RigConfig,
    p: &Prepared<'_>,
    names: &[String],
) -> Result<Vec<f64>, String> {
    let at: BTreeMap<String, f64> = names.iter().cloned().zip(p.at.iter().copied()).collect();
    let plant: PlantParams = ehactl_config::inputs::plant_at(&cfg.inputs, &cfg.plant, &at)?;
    let im = ImposedMotion::new(&plant).map_err(|e| format!("{}: {e}", p.rec.source))?;
    let v = record_velocity(p.rec, p.x, plant.sensors.position.velocity_window);
    im.rod_forces(&Motion {
        dt: p.rec.dt,
        x: p.x,
        v: &v,
        dp: p.dp.as_deref(),
    })
    .map_err(|e| format!("{}: {e}", p.rec.source))
}

/// Pooled ARX baseline x → force on the fitting parts (concatenated; the few regressor rows
/// that straddle a junction are a negligible share), simulated free-run over each record.
pub(super) fn arx_baseline(prepared: &[Prepared<'_>]) -> Result<(String, Vec<Vec<f64>>), String> {
    let mut x = Vec::new();
    let mut f = Vec::new();
    for p in prepared.iter().filter(|p| !p.validation) {
        x.extend_from_slice(&p.x[p.fit.clone()]);
        f.extend_from_slice(&p.force[p.fit.clone()]);
    }
    let dt = prepared[0].rec.dt;
    let t: Vec<f64> = (0..x.len()).map(|k| k as f64 * dt).collect();
    let n = x.len();
    let concat = Record::from_columns(
        "campaign fitting parts",
        t,
        Vec::new(),
        vec![Channel {
            kind: ChannelKind::Force,
            values: f,
        }],
        None,
        0,
    )
    .map_err(|e| e.to_string())?;
    let b = baseline::fit(&concat, &x, n, "x");
    let m = b.models.first();
    let preds = prepared
        .iter()
        .map(|p| {
            m.and_then(|m| m.simulate(p.x, p.force))
                .unwrap_or_else(|| vec![f64::INFINITY; p.x.len()])
        })
        .collect();
    Ok((b.structure, preds))
}
