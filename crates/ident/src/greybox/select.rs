//! The grey-box term selection: candidates fitted from equation-error starts, judged by the
//! transfer error, widened on their bounds, kept while they earn their place.

use super::*;

/// A candidate law of one selection round: the hypothesis with its costs.
pub(super) struct Candidate {
    pub(super) h: Hyp,
    /// Cost J on the selection segment (-).
    pub(super) cost: f64,
    /// Judged mean ln J_c ([`log_cost`]) (-).
    pub(super) judged_log: f64,
    /// Judged overall NRMSE (-).
    pub(super) judged: f64,
}

/// The state of the forward selection: the law so far, its costs and the log.
pub(super) struct Selection {
    /// The grey-box parameters selected so far.
    pub(super) h: Hyp,
    /// Cost J of `h` on the selection segment (-).
    pub(super) j_cur: f64,
    /// Judged mean ln J_c of `h` (-).
    pub(super) l_cur: f64,
    pub(super) terms: Vec<Term>,
    /// Selection log (see [`GreyBox::selection`]).
    pub(super) log: Vec<String>,
    /// Library terms selected (section, field).
    pub(super) used: Vec<(&'static str, &'static str)>,
    /// Force residual (N) of `h` on the fitting part, for the next starts (empty without a
    /// force channel).
    pub(super) resid: Vec<f64>,
}

/// The grey-box fit on top of a frozen catalogue model: its scales, the term library, the
/// force residual the terms start from and the transfer split that judges them.
pub(super) struct GreyBoxFit<'a> {
    /// The catalogue model frozen into the base parameters.
    pub(super) frozen: &'a Ctx<'a>,
    /// Transfer check, the measure of an extension's gain: terms are chosen on the first
    /// [`TRANSFER_SPLIT`] of the fitting part and judged by how they predict the rest, which a
    /// chirp or a sweep fills with other content (another band, other velocities). A term that
    /// only fits (a viscous coefficient fitted at low speed that extrapolates to forces the rig
    /// never saw, say) does not pass; the chosen law is then refit jointly on the whole fitting
    /// part. The held-out part still never enters a choice. `None`: too short to split.
    pub(super) split: Option<Ctx<'a>>,
    /// Base parameters of the fitting part (the frozen model).
    pub(super) base_fit: PlantParams,
    /// The base config's force law (zero without one).
    pub(super) prior: PolynomialForce,
    /// The base config's flow law.
    pub(super) prior_flow: Option<PolynomialFlow>,
    /// The force law a term's section is inserted with (smoothing velocity and origin set).
    pub(super) start: PolynomialForce,
    /// Robust velocity scale (m/s).
    pub(super) vr: f64,
    /// Force scale (N).
    pub(super) fs: f64,
    /// Sign smoothing velocity (m/s).
    pub(super) vs: f64,
    /// Position scale (m): the 99th percentile of |x − x₀| on the fitting part, for the Dahl
    /// term's pre-yield travel.
    pub(super) xr: f64,
    pub(super) lib: [Lib; 11],
    /// Force residual of the frozen model, when the record has a force channel.
    pub(super) force_resid: Option<ForceResidual>,
    pub(super) evals_per_param: usize,
}

impl<'a> GreyBoxFit<'a> {
    /// Scales, library, force residual and transfer split of the frozen model `frozen`.
    pub(super) fn new(frozen: &'a Ctx<'a>, scales: &Scales, evals_per_param: usize) -> Self {
        let base_fit = frozen.fit_base_params().clone();
        let sim = frozen.fit_replay(&base_fit).ok();
        let vr = sim
            .as_ref()
            .map(|s| v_scale(&s.v[..frozen.n_fit().min(s.v.len())]))
            .unwrap_or(0.0);
        let vr = if vr > 0.0 { vr } else { 1e-2 };
        let fs = scales.force.max(1e-9);
        let area = base_fit.cylinder.area_a;
        let prior = base_fit
            .effects
            .polynomial_force
            .unwrap_or_else(PolynomialForce::zero);
        // Sign smoothing at 2 % of the velocity scale; stiffness origin at the data's mean
        // position.
        let vs = if base_fit.effects.polynomial_force.is_some() {
            prior.smoothing_velocity
        } else {
            0.02 * vr
        };
        let rec = frozen.fit_rec();
        let n_fit = frozen.n_fit();
        let origin = if base_fit.effects.polynomial_force.is_some() {
            prior.origin
        } else {
            rec.channel(ChannelKind::Position)
                .map(|x| x[..n_fit].iter().sum::<f64>() / n_fit as f64)
                .unwrap_or(base_fit.cylinder.initial_position)
        };
        let lib = term_library(scales, fs, vr, area, base_fit.cylinder.stroke);
        check_library(&lib);
        let mut start = prior;
        start.enabled = true;
        start.smoothing_velocity = vs;
        start.origin = origin;
        let force_resid = sim
            .as_ref()
            .and_then(|s| force_residual_of(rec, s, n_fit, origin));
        let xr = rec
            .channel(ChannelKind::Position)
            .map(|x| robust_scale(&x[..n_fit], origin))
            .filter(|a| *a > 0.0)
            .unwrap_or(0.01 * base_fit.cylinder.stroke);
        Self {
            frozen,
            split: frozen.transfer_split(TRANSFER_SPLIT),
            prior_flow: base_fit.effects.polynomial_flow,
            base_fit,
            prior,
            start,
            vr,
            fs,
            vs,
            xr,
            lib,
            force_resid,
            evals_per_param,
        }
    }

    /// The fitting record.
    pub(super) fn rec(&self) -> &'a Record {
        self.frozen.fit_rec()
    }

    /// The context terms are chosen on: the transfer split's first segment, else the fitting
    /// part.
    pub(super) fn sel(&self) -> &Ctx<'a> {
        self.split.as_ref().unwrap_or(self.frozen)
    }

    /// The free coefficient of library term `l`, started at the prior plus `init` (SI), its
    /// bound widened `widen` times (-).
    pub(super) fn make_param(&self, l: &Lib, init: f64, widen: f64) -> FreeParam {
        // Every library field is a declared float of its section (tested), so the
        // accessor's `None` (0) is never taken.
        let p0 = if l.section == "polynomial_force" {
            self.prior.get_path(l.field)
        } else {
            self.prior_flow.and_then(|f| f.get_path(l.field))
        }
        .unwrap_or(0.0);
        let b = widen * l.bound.max(2.0 * p0.abs());
        // A rod force beyond what the actuator can push (supply pressure × cap area) is a
        // stand-in, not a load: force coefficients are never widened past it.
        let b = if l.unit() == "N" {
            b.min(self.fs.max(l.bound))
        } else {
            b
        };
        let field = l.field;
        let st = self.start;
        let set: crate::fit::Setter = if l.section == "polynomial_force" {
            Arc::new(move |p: &mut PlantParams, v| {
                // Inserted with the start's smoothing velocity and origin; an existing section
                // keeps its own (a pre-yield velocity fitted with the yield term must survive
                // the terms selected after it).
                let f = p.effects.polynomial_force.get_or_insert(st);
                f.enabled = true;
                // Declared float (checked above): the write cannot fail.
                let _ = f.set_path(field, v);
            })
        } else {
            Arc::new(move |p: &mut PlantParams, v| {
                let f = p
                    .effects
                    .polynomial_flow
                    .get_or_insert_with(PolynomialFlow::zero);
                f.enabled = true;
                // Declared float (checked above): the write cannot fail.
                let _ = f.set_path(field, v);
            })
        };
        // The Dahl force is a magnitude (F_d ≥ 0, the state carries the sign). A load-side
        // damping dissipates: its total coefficient is ≥ 0 (a negative quadratic damping fitted
        // at the speeds of one record injects energy at higher ones: the 0 A low-band law of
        // the MTS transfer check diverged on the high band with c_q < 0).
        let dissipative =
            l.section == "polynomial_force" && matches!(field, "viscous" | "quadratic");
        let lo = if field == "dahl" || dissipative {
            0.0
        } else {
            -b
        };
        FreeParam {
            name: format!("effects.{}.{field}", l.section),
            lo,
            hi: b,
            log: false,
            init: (p0 + init).clamp(lo, b),
            set,
        }
    }

    /// Per-channel cost (NRMSE² per channel, -) of parameters `p` on the samples of context
    /// `c`'s fit cost, normalised by its own stds.
    pub(super) fn channel_costs_on(&self, c: &Ctx, p: &PlantParams) -> Vec<f64> {
        let rec = self.rec();
        let (n_fit, sd) = (c.n_fit(), c.sd_fit());
        match c.fit_replay(p) {
            Ok(s) if !s.failed => rec
                .channels
                .iter()
                .zip(&s.y)
                .zip(sd)
                .map(|((c, y), sd)| {
                    c.values[..n_fit]
                        .iter()
                        .zip(y)
                        .map(|(a, b)| (a - b) * (a - b))
                        .sum::<f64>()
                        / n_fit as f64
                        / (sd * sd)
                })
                .collect(),
            _ => vec![1e6; rec.channels.len()],
        }
    }

    /// Mean per-channel cost J (-) of parameters `p` on the selection segment.
    pub(super) fn sel_cost(&self, p: &PlantParams) -> f64 {
        let jc = self.channel_costs_on(self.sel(), p);
        jc.iter().sum::<f64>() / jc.len().max(1) as f64
    }

    /// Judged cost of `hh`: mean ln NRMSE² over channels (-) and overall NRMSE (-) on the
    /// predicted segment (or, without a split, on the fitting part).
    pub(super) fn judge(&self, hh: &Hyp) -> (f64, f64) {
        match &self.split {
            Some(t) => {
                let (e, _) = t.val_errors(hh);
                let jc: Vec<f64> = e.channels.values().map(|x| x * x).collect();
                (log_cost(&jc), e.overall)
            }
            None => {
                let jc = self.channel_costs_on(self.frozen, &hh.build(&self.base_fit));
                let j = jc.iter().sum::<f64>() / jc.len().max(1) as f64;
                (log_cost(&jc), j.sqrt())
            }
        }
    }

    /// Least-squares start (SI) of library term `l` on the force residual `resid` (N), the
    /// equation-error estimate; 0 without a regressor or a force channel.
    pub(super) fn ls_start(&self, l: &Lib, resid: &[f64]) -> f64 {
        let (Some(feat), Some(fr)) = (l.feature, self.force_resid.as_ref()) else {
            return 0.0;
        };
        let (mut num, mut den) = (0.0, 0.0);
        for ((r, x), v) in resid.iter().zip(&fr.x).zip(&fr.v) {
            let phi = feat(*x, *v, &self.start);
            num += phi * r;
            den += phi * phi;
        }
        if den > 0.0 {
            num / den
        } else {
            0.0
        }
    }

    /// The yield term's pre-yield velocity v_y (m/s) started at `init`, fitted in log space
    /// with its force (from the base's smoothing velocity when the config has a force law: an
    /// assumption there). Written after its force term, which inserts the section.
    pub(super) fn yield_velocity_param(&self, init: f64) -> FreeParam {
        FreeParam::at(
            "effects.polynomial_force.smoothing_velocity",
            (0.005 * self.vr, 0.5 * self.vr, true, init),
            &self.base_fit,
        )
    }

    /// The Dahl term's pre-yield travel δ (m) started at `init`, fitted in log space with its
    /// force (written after it, as the yield velocity).
    pub(super) fn dahl_travel_param(&self, init: f64) -> FreeParam {
        FreeParam::at(
            "effects.polynomial_force.dahl_travel",
            (0.002 * self.xr, 0.5 * self.xr, true, init),
            &self.base_fit,
        )
    }

    /// Adds library term `l`'s coefficient (and the yield velocity or Dahl travel it carries)
    /// to `hh`, from its least-squares start on the force residual `resid` (N).
    pub(super) fn push_term(&self, hh: &mut Hyp, l: &Lib, resid: &[f64]) {
        let (init, partner) = match l.field {
            "coulomb" if l.section == "polynomial_force" => (
                self.ls_start(l, resid),
                Some(self.yield_velocity_param(self.vs)),
            ),
            "dahl" => {
                // Without a force channel, F_d = 0 and δ at 5 % of the position scale.
                let (fd, delta) = match self.force_resid.as_ref() {
                    Some(fr) => dahl_start(&fr.v, self.rec().dt, resid, self.xr),
                    None => (0.0, 0.05 * self.xr),
                };
                (fd, Some(self.dahl_travel_param(delta)))
            }
            _ => (self.ls_start(l, resid), None),
        };
        let fp = self.make_param(l, init, 1.0);
        hh.values.push(fp.init);
        hh.params.push(fp);
        if let Some(fv) = partner {
            hh.values.push(fv.init);
            hh.params.push(fv);
        }
    }

    /// The report of a selected term `l` in hypothesis `h` (fitting cost `train`, judged
    /// overall NRMSE `judged`, -).
    pub(super) fn term_of(&self, l: &Lib, h: &Hyp, train: f64, judged: f64) -> Term {
        let k = h.params.iter().rposition(|p| p.name == l.path());
        Term {
            path: l.path(),
            value: k.map_or(0.0, |k| h.values[k]),
            unit: l.unit().to_string(),
            name: l.name.to_string(),
            physics: l.physics.to_string(),
            nrmse_train: train.sqrt(),
            nrmse_transfer: self.split.as_ref().map(|_| judged),
            // Reported only: the held-out part never enters a choice.
            nrmse_validation: self.frozen.val_errors(h).0.overall,
            bound: k.map_or(0.0, |k| h.params[k].hi),
            at_bound: false,
        }
    }

    /// Force residual (N) of `h` on the fitting part, when the record has a force channel.
    pub(super) fn force_residual(&self, h: &Hyp) -> Option<Vec<f64>> {
        self.force_resid.as_ref()?;
        let rec = self.rec();
        let n_fit = self.frozen.n_fit();
        let s = self.frozen.fit_replay(&h.build(&self.base_fit)).ok()?;
        let fc = rec
            .channels
            .iter()
            .position(|c| c.kind == ChannelKind::Force)?;
        Some(
            rec.channels[fc].values[..n_fit]
                .iter()
                .zip(&s.y[fc][..n_fit])
                .map(|(a, b)| a - b)
                .collect(),
        )
    }

    /// The empty law to select on, judged, and its judged overall NRMSE (-) (the transfer
    /// check's before); `cur_train` is the catalogue model's fitting-part cost (-).
    pub(super) fn start_selection(&self, cur_train: f64) -> (Selection, f64) {
        let h = Hyp {
            effects: vec![],
            variants: vec![],
            params: vec![],
            values: vec![],
        };
        let j_cur = if self.split.is_some() {
            self.sel_cost(&self.base_fit)
        } else {
            cur_train
        };
        let (l_cur, transfer_before) = self.judge(&h);
        let mut log = Vec::new();
        if let Some(t) = &self.split {
            log.push(format!(
                "terms chosen on samples 0..{} of the fitting part and judged on how they predict samples {}..{} (transfer check); the chosen law refit on the whole fitting part",
                t.n_fit(),
                t.n_fit(),
                self.frozen.n_fit()
            ));
        }
        let resid = self
            .force_resid
            .as_ref()
            .map(|r| r.resid.clone())
            .unwrap_or_default();
        let st = Selection {
            h,
            j_cur,
            l_cur,
            terms: Vec::new(),
            log,
            used: Vec::new(),
            resid,
        };
        (st, transfer_before)
    }

    /// Every remaining term fitted on top of the law so far (in parallel), and the one with the
    /// lowest judged cost among those that do not raise the cost J; `None` when none is left.
    pub(super) fn best_candidate(&self, st: &Selection) -> Option<(&Lib, Candidate)> {
        let cands: Vec<&Lib> = self
            .lib
            .iter()
            .filter(|l| !st.used.contains(&(l.section, l.field)))
            .collect();
        let results: Vec<(usize, Candidate)> = cands
            .par_iter()
            .enumerate()
            .map(|(i, l)| {
                let mut hh = st.h.clone();
                let first_new = hh.params.len();
                self.push_term(&mut hh, l, &st.resid);
                let (hh, c) = self.sel().fit(hh, first_new, self.evals_per_param);
                let (lc, e) = self.judge(&hh);
                let cand = Candidate {
                    h: hh,
                    cost: c,
                    judged_log: lc,
                    judged: e,
                };
                (i, cand)
            })
            .collect();
        let (i, best) = results
            .into_iter()
            .filter(|r| r.1.cost <= st.j_cur)
            .min_by(|a, b| a.1.judged_log.total_cmp(&b.1.judged_log))?;
        Some((cands[i], best))
    }

    /// A coefficient of term `l` that ends on its bound says the bound, not the data, stopped
    /// it: widen the bound (4×, at most twice) and refit `best`, on the fitting segment only.
    pub(super) fn widen_on_bound(&self, l: &Lib, best: &mut Candidate, log: &mut Vec<String>) {
        let mut widen = 1.0;
        for _ in 0..2 {
            let path = l.path();
            let Some(k) = best.h.params.iter().rposition(|p| p.name == path) else {
                break;
            };
            let (fp, v) = (best.h.params[k].clone(), best.h.values[k]);
            if v.abs() < 0.98 * fp.hi {
                break;
            }
            widen *= 4.0;
            let wider = self.make_param(l, 0.0, widen);
            if wider.hi <= fp.hi * (1.0 + 1e-9) {
                log.push(format!(
                    "{}.{} ended on its bound ±{:.3e} {}: not widened (the actuator's force scale, supply pressure × cap area)",
                    l.section, l.field, fp.hi, l.unit()
                ));
                break;
            }
            let mut hw = best.h.clone();
            hw.params[k] = wider;
            hw.values[k] = v;
            let (hw, cw) = self.sel().fit(hw, k, self.evals_per_param);
            log.push(format!(
                "{}.{} ended on its bound ±{:.3e} {}: bound widened 4× and refit (fitting NRMSE {:.4} → {:.4})",
                l.section, l.field, fp.hi, l.unit(), best.cost.sqrt(), cw.sqrt()
            ));
            if cw < best.cost {
                (best.judged_log, best.judged) = self.judge(&hw);
                best.h = hw;
                best.cost = cw;
            }
        }
    }

    /// One round of the forward selection: the best remaining term, kept if it lowers the
    /// geometric mean of the judged per-channel J by [`MIN_REL_GAIN`]. Returns whether a term
    /// was kept (the selection goes on).
    pub(super) fn select_round(&self, st: &mut Selection) -> bool {
        let Some((l, mut best)) = self.best_candidate(st) else {
            return false;
        };
        self.widen_on_bound(l, &mut best, &mut st.log);
        // Geometric-mean reduction of the per-channel cost on the judged segment (a replay
        // that failed or diverged scores the failure cost: said so, not as a huge number).
        let gain = 1.0 - (best.judged_log - st.l_cur).exp();
        let gain_text = if gain.is_finite() && gain > -10.0 {
            format!("{:+.1} %", -100.0 * gain)
        } else {
            "replay failed or diverged".to_string()
        };
        st.log.push(format!(
            "round {}: best {}.{} ({}): fitting NRMSE {:.4} → {:.4}, {} geometric mean of the per-channel J {}{}",
            st.terms.len() + 1,
            l.section,
            l.field,
            l.physics,
            st.j_cur.sqrt(),
            best.cost.sqrt(),
            if self.split.is_some() { "predicted segment:" } else { "fitting part:" },
            gain_text,
            if gain >= MIN_REL_GAIN { "" } else { " — not a 5 % fall, stop" }
        ));
        if gain < MIN_REL_GAIN {
            return false;
        }
        st.used.push((l.section, l.field));
        st.h = best.h;
        st.j_cur = best.cost;
        st.l_cur = best.judged_log;
        st.terms
            .push(self.term_of(l, &st.h, best.cost, best.judged));
        // Force residual after this term (for the next starts).
        if let Some(r) = self.force_residual(&st.h) {
            st.resid = r;
        }
        true
    }

    /// The force residual still tracks velocity but no velocity term was kept: alone, each may
    /// fail the transfer check when the load both yields and flows viscously (an MR damper: a
    /// yield force alone misses the high-speed slope, a viscous term alone the reversals), so
    /// the velocity terms are fitted together once, judged by the same rule.
    pub(super) fn fit_velocity_terms_together(&self, st: &mut Selection) {
        let r_v = self
            .force_resid
            .as_ref()
            .map_or(0.0, |fr| crate::residual::corr(&st.resid, &fr.v));
        let velocity_terms = ["viscous", "coulomb", "dahl"];
        let kept_velocity = st
            .used
            .iter()
            .any(|(sec, f)| *sec == "polynomial_force" && velocity_terms.contains(f));
        if r_v.abs() < VELOCITY_CORRELATION || kept_velocity {
            return;
        }
        let group: Vec<&Lib> = self
            .lib
            .iter()
            .filter(|l| l.section == "polynomial_force" && velocity_terms.contains(&l.field))
            .collect();
        let mut hh = st.h.clone();
        let first_new = hh.params.len();
        for l in &group {
            self.push_term(&mut hh, l, &st.resid);
        }
        let (hh, c) = self.sel().fit(hh, first_new, self.evals_per_param);
        let (lc, e) = self.judge(&hh);
        let gain = 1.0 - (lc - st.l_cur).exp();
        let keep = c <= st.j_cur && gain >= MIN_REL_GAIN;
        st.log.push(format!(
            "the force residual tracks velocity (r = {r_v:+.2}) and no velocity term was kept: viscous, yield and Dahl terms fitted together: fitting NRMSE {:.4} → {:.4}, geometric mean of the per-channel J {:+.1} %{}",
            st.j_cur.sqrt(),
            c.sqrt(),
            -100.0 * gain,
            if keep { ", kept" } else { ", not kept" }
        ));
        if keep {
            st.h = hh;
            st.j_cur = c;
            for l in group {
                st.used.push((l.section, l.field));
                st.terms.push(self.term_of(l, &st.h, c, e));
            }
        }
    }

    /// The transfer check of the selected law, from the catalogue model's judged overall
    /// NRMSE `before` (-); `None` without a split.
    pub(super) fn transfer(&self, st: &Selection, before: f64) -> Option<Transfer> {
        self.split.as_ref().map(|t| Transfer {
            fit_samples: 0..t.n_fit(),
            predicted_samples: t.n_fit()..self.frozen.n_fit(),
            nrmse_before: before,
            nrmse_after: st
                .terms
                .last()
                .and_then(|x| x.nrmse_transfer)
                .unwrap_or(before),
        })
    }

    /// The chosen law refit jointly on the whole fitting part (starts: the segment's values),
    /// then the final values of every selected term (the joint fit moved the earlier ones too).
    pub(super) fn refit_on_fitting_part(&self, st: &mut Selection) {
        if self.split.is_some() && !st.h.params.is_empty() {
            let n = st.h.params.len();
            let (hf, cf) = self.frozen.fit(st.h.clone(), n, self.evals_per_param);
            if cf.is_finite() {
                st.h = hf;
                st.j_cur = cf;
            }
        }
        for t in st.terms.iter_mut() {
            if let Some(k) = st.h.params.iter().position(|p| p.name == t.path) {
                t.value = st.h.values[k];
                t.at_bound = t.value.abs() >= 0.98 * st.h.params[k].hi;
            }
        }
    }

    /// The report of the finished selection `st` (`cur_train`: the catalogue model's
    /// fitting-part cost, `baseline`: the ARX baseline's held-out overall NRMSE, -).
    pub(super) fn report(
        &self,
        st: Selection,
        transfer: Option<Transfer>,
        cur_train: f64,
        baseline: f64,
    ) -> GreyBox {
        let h = &st.h;
        let terms = st.terms;
        // The yield term's fitted pre-yield velocity.
        let yield_velocity = param_value(h, "effects.polynomial_force.smoothing_velocity");
        // The Dahl term's fitted pre-yield travel.
        let dahl_travel = param_value(h, "effects.polynomial_force.dahl_travel");
        let accepted = !terms.is_empty();
        // The pressure-dependent friction at the extended model's median load pressure while
        // sliding, so that the yield force is comparable whichever term carries it.
        let median_load_pressure = terms
            .iter()
            .any(|t| t.path.ends_with(".pressure_coulomb"))
            .then(|| self.frozen.fit_replay(&h.build(&self.base_fit)).ok())
            .flatten()
            .and_then(|s| median_sliding_pressure(&s, self.frozen.n_fit(), 0.1 * self.vr));
        let yield_force = yield_force_of(&terms, median_load_pressure);
        let (val, _) = self.frozen.val_errors(h);
        let structure = structure_of(accepted.then(|| h.build(&self.base_fit)), &terms);
        let ratio = val.overall / baseline;
        GreyBox {
            structure,
            terms,
            nrmse_train_before: cur_train.sqrt(),
            nrmse_train: st.j_cur.sqrt(),
            nrmse_validation: val,
            ratio_to_baseline: ratio,
            accepted,
            transfer,
            yield_velocity,
            dahl_travel,
            yield_force,
            median_load_pressure,
            selection: st.log,
        }
    }
}
