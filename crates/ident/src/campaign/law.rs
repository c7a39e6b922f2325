//! Phase 3 of a campaign: the fitted law, its bootstrap members and its terms ranked.

use super::*;

/// What phase 3 hands on.
pub(super) struct Fitted {
    pub(super) law: LawFit,
    /// Normal equations of every fitting part, summed.
    pub(super) all: Normal,
    /// The fitting segments' normal equations (the transfer split's two per record), which
    /// the band's bootstrap resamples.
    pub(super) segments: Vec<Normal>,
    pub(super) dependence_check: String,
    /// Transfer error of the final structure (NRMSE²).
    pub(super) j_transfer: f64,
}

/// Phase 3: each kept term's dependence on each input, the Dahl travel per operating point,
/// then the final least-squares fit on every fitting part (a validation record's fitting
/// segments are empty: it adds nothing there).
pub(super) fn fit_law(
    su: &Setup<'_>,
    shape: Shape,
    structure: Structure,
    j_shape: f64,
) -> Result<Fitted, String> {
    let (lib, ex) = (&su.library, &su.expanded);
    let has_dahl = lib.contains(&LawTerm::Dahl);
    let kin = kinematics(&su.prepared, &shape, has_dahl);
    let data = normals(&su.prepared, lib, ex, shape, &kin);
    let by_point = |st: &Structure, j: f64| {
        travel_by_point(
            su.v_rms,
            &su.prepared,
            lib,
            ex,
            st,
            shape,
            &su.fit_groups,
            &su.names,
            j,
        )
    };
    // The Dahl shape per operating point first for the selected terms (every coefficient
    // following the input where the campaign allows it: a shape that follows the input is
    // found with coefficients that follow it too), then each term's dependence at that shape;
    // if none was found so, again for the terms with their chosen dependences.
    let j_selected = transfer_error(&data, ex, lib, &structure).unwrap_or(j_shape);
    let (first, data) = match by_point(&structure, j_selected) {
        Some((dep, per_record)) => (Some(dep), per_record),
        None => (None, data),
    };
    let (structure, dependence_check) = choose_dependence(
        &data,
        &su.prepared,
        lib,
        ex,
        structure,
        &su.candidate_forms,
        &su.fit_groups,
        &su.names,
    );
    let j_transfer = transfer_error(&data, ex, lib, &structure).unwrap_or(j_shape);
    let (travel, data, j_transfer) = match first {
        Some(dep) => (Some(dep), data, j_transfer),
        None => match by_point(&structure, j_transfer) {
            Some((dep, per_record)) => {
                let j = dep.nrmse_transfer.powi(2);
                (Some(dep), per_record, j)
            }
            None => (None, data, j_transfer),
        },
    };
    let travel = travel.map(|mut dep| {
        dep.unit = su.units[0].clone();
        dep
    });
    let all: Normal = sum_normals(data.a.iter().chain(&data.b), ex.cols.len());
    let segments: Vec<Normal> = data
        .a
        .iter()
        .chain(&data.b)
        .filter(|n| n.n > 0.0)
        .cloned()
        .collect();
    let cols = columns_of(&structure, ex, lib);
    let theta = all
        .solve(&cols, ex)
        .ok_or("the campaign law's least-squares problem is singular")?;
    Ok(Fitted {
        law: LawFit {
            shape: data.shape,
            travel,
            structure,
            cols,
            theta,
            expanded_cols: ex.cols.clone(),
            forms: ex.forms.clone(),
            library: lib.clone(),
        },
        all,
        segments,
        dependence_check,
        j_transfer,
    })
}

/// The law refitted on [`crate::band::MEMBERS`] bootstrap resamples of its fitting segments
/// (the same structure, shape and admissibility; a resample whose fit fails is left out).
pub(super) fn bootstrap(f: &Fitted, ex: &Expanded) -> Vec<LawFit> {
    let k = f.segments.len();
    if k < 2 {
        return Vec::new();
    }
    let mut rng = crate::band::SplitMix::new(0x5EED_0000 + k as u64);
    (0..crate::band::MEMBERS)
        .filter_map(|_| {
            let mut sum = Normal::zero(ex.cols.len());
            for _ in 0..k {
                sum.add(&f.segments[rng.below(k)]);
            }
            let theta = sum.solve(&f.law.cols, ex)?;
            Some(LawFit {
                theta,
                ..f.law.clone()
            })
        })
        .collect()
}

/// Phase 4: each term with its coefficients and the share of the force variance it carries
/// (removed and the rest refit), largest first.
pub(super) fn rank_terms(su: &Setup<'_>, f: &Fitted) -> Vec<TermFit> {
    let law = &f.law;
    let total = f.all.var_sum();
    let base_sse = f.all.sse(&law.cols, &law.theta);
    let mut terms = Vec::new();
    for (ti, (term, forms)) in law.structure.terms.iter().enumerate() {
        let mut without = law.structure.clone();
        without.terms.remove(ti);
        let c2 = columns_of(&without, &su.expanded, &su.library);
        let share = f
            .all
            .solve(&c2, &su.expanded)
            .map_or(1.0, |th| (f.all.sse(&c2, &th) - base_sse).max(0.0) / total);
        let (name, unit) = term_name(*term);
        let mut dependence = BTreeMap::new();
        for (k, fm) in forms.iter().enumerate() {
            if *fm != Form::None {
                dependence.insert(su.names[k].clone(), (*fm, law.basis_coefficients(*term, k)));
            }
        }
        terms.push(TermFit {
            path: path_of(*term),
            name: name.to_string(),
            unit: unit.to_string(),
            at_zero: law.constant_part(*term),
            dependence,
            share,
        });
    }
    terms.sort_by(|a, b| b.share.total_cmp(&a.share));
    terms
}

/// The fitted law.
#[derive(Clone)]
pub(super) struct LawFit {
    pub(super) shape: Shape,
    /// The Dahl travel's dependence on the input, if kept (else `shape.dahl_travel`).
    pub(super) travel: Option<TravelDependence>,
    pub(super) structure: Structure,
    pub(super) cols: Vec<usize>,
    pub(super) theta: DVector<f64>,
    pub(super) expanded_cols: Vec<Column>,
    pub(super) forms: Vec<Vec<Form>>,
    pub(super) library: Vec<LawTerm>,
}

impl LawFit {
    pub(super) fn coefficient_of(&self, term: LawTerm, part: Option<(usize, usize)>) -> f64 {
        let ti = self.library.iter().position(|t| *t == term);
        self.cols
            .iter()
            .zip(self.theta.iter())
            .find(|(c, _)| {
                let col = self.expanded_cols[**c];
                Some(col.term) == ti && col.part == part
            })
            .map_or(0.0, |(_, v)| *v)
    }

    pub(super) fn constant_part(&self, term: LawTerm) -> f64 {
        self.coefficient_of(term, None)
    }

    /// The forms (one per input) of a term of the law.
    pub(super) fn forms_of(&self, term: LawTerm) -> &[Form] {
        &self
            .structure
            .terms
            .iter()
            .find(|t| t.0 == term)
            .expect("term in structure")
            .1
    }

    /// Coefficients of the basis functions of input `k` for `term`.
    pub(super) fn basis_coefficients(&self, term: LawTerm, k: usize) -> Vec<f64> {
        let forms = self.forms_of(term);
        let fi = self.forms[k]
            .iter()
            .position(|f| *f == forms[k])
            .unwrap_or(0);
        (0..forms[k].parameters())
            .map(|b| self.coefficient_of(term, Some((k, fi * 2 + b))))
            .collect()
    }

    /// Coefficient of `term` at operating point `at` (per input).
    pub(super) fn coefficient_at(&self, term: LawTerm, at: &[f64]) -> f64 {
        let forms = self.forms_of(term);
        let mut c = self.constant_part(term);
        for (k, f) in forms.iter().enumerate() {
            let basis = f.basis(at[k]);
            for (b, coef) in self.basis_coefficients(term, k).iter().enumerate() {
                c += coef * basis[b].unwrap_or(0.0);
            }
        }
        c
    }

    /// The shape at operating point `at` (the Dahl travel δ(i) and series velocity V(i) when
    /// they depend on the input).
    pub(super) fn shape_at(&self, at: &[f64]) -> Shape {
        let (dahl_travel, dahl_velocity) = self
            .travel
            .as_ref()
            .map_or((self.shape.dahl_travel, self.shape.dahl_velocity), |t| {
                t.at(at[0])
            });
        Shape {
            dahl_travel,
            dahl_velocity,
            ..self.shape
        }
    }

    /// The law at operating point `at`.
    pub(super) fn law_at(&self, at: &[f64]) -> PolynomialForce {
        let mut law = shape_law(self.shape_at(at));
        for (term, _) in &self.structure.terms {
            law = term.with(law, self.coefficient_at(*term, at));
        }
        law
    }

    /// Force prediction along record `p` (time-varying inputs followed sample by sample).
    pub(super) fn predict(&self, cfg: &RigConfig, p: &Prepared<'_>) -> Result<Vec<f64>, String> {
        let v = record_velocity(p.rec, p.x, self.shape.velocity_window);
        let m = Motion {
            dt: p.rec.dt,
            x: p.x,
            v: &v,
            dp: p.dp.as_deref(),
        };
        // The record's own travel (at its median operating point), as `ehactl predict` takes
        // the extended config at it.
        let law0 = shape_law(self.shape_at(&p.at));
        let pm = &cfg.plant.mechanics;
        let mut f: Vec<f64> =
            p.x.iter()
                .map(|x| pm.load_stiffness * (x - pm.load_contact_position))
                .collect();
        for (term, _) in &self.structure.terms {
            let s = term_series(*term, &law0, &m)
                .ok_or_else(|| format!("{}: the law needs p_a and p_b", p.rec.source))?;
            for (k, (fk, sk)) in f.iter_mut().zip(s).enumerate() {
                let at: Vec<f64> = p.op.iter().map(|o| o[k]).collect();
                *fk += self.coefficient_at(*term, &at) * sk;
            }
        }
        Ok(f)
    }

    /// The config extended with the law at its own operating point and the dependences as
    /// local derivatives there ([`ehactl_config::inputs`]).
    pub(super) fn extended(&self, cfg: &RigConfig, names: &[String]) -> Result<RigConfig, String> {
        let mut out = cfg.clone();
        let at0: Vec<f64> = names.iter().map(|n| cfg.inputs[n].value).collect();
        out.plant.effects.polynomial_force = Some(self.law_at(&at0));
        out.plant.sensors.position.velocity_window = self.shape.velocity_window;
        for (k, name) in names.iter().enumerate() {
            let inp = out.inputs.get_mut(name).expect("declared");
            inp.linear
                .retain(|p, _| !p.starts_with("effects.polynomial_force."));
            inp.quadratic
                .retain(|p, _| !p.starts_with("effects.polynomial_force."));
            inp.saturating
                .retain(|p, _| !p.starts_with("effects.polynomial_force."));
            inp.hinge
                .retain(|p, _| !p.starts_with("effects.polynomial_force."));
            let i0 = at0[k];
            if let Some(t) = &self.travel {
                inp.linear
                    .insert("effects.polynomial_force.dahl_travel".into(), t.slope);
                if t.velocity_varies() {
                    inp.linear.insert(
                        "effects.polynomial_force.dahl_velocity".into(),
                        t.velocity_slope,
                    );
                }
            }
            for (term, forms) in &self.structure.terms {
                let c = self.basis_coefficients(*term, k);
                // About i₀: the linear and quadratic forms exactly as Taylor terms, the
                // saturating one as itself (`[inputs.<name>.saturating]`): a second-order
                // Taylor form of 1 − e^(−i/i_s) turns negative within a few i_s of i₀.
                let (a, b) = match forms[k] {
                    Form::None => continue,
                    Form::Linear => (c[0], 0.0),
                    Form::Quadratic => (c[0] + 2.0 * c[1] * i0, c[1]),
                    // p(i) − p(i₀) = c₁·(i − i₀) + c₂·(max(i − i_k, 0) − max(i₀ − i_k, 0)):
                    // the linear slope and the knee as they are.
                    Form::Piecewise { knot } => {
                        inp.hinge.insert(
                            path_of(*term),
                            ehactl_config::inputs::Hinge { knot, slope: c[1] },
                        );
                        (c[0], 0.0)
                    }
                    Form::Saturating { scale } => {
                        inp.saturating.insert(
                            path_of(*term),
                            ehactl_config::inputs::Saturating { gain: c[0], scale },
                        );
                        continue;
                    }
                };
                inp.linear.insert(path_of(*term), a);
                if b != 0.0 {
                    inp.quadratic.insert(path_of(*term), b);
                }
            }
        }
        out.validate()
            .map_err(|e| format!("the extended config is not valid: {e}"))?;
        Ok(out)
    }
}
