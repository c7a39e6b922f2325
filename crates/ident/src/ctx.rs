//! The replay context of one diagnosis and the hypotheses fitted in it: `Ctx` (fit and
//! held-out records, the base parameters, the drive, the cost), `Hyp` (effects, variants
//! and free-parameter values on top of the base) and [`Errors`] (held-out NRMSE per channel).
//! Shared by the decision ([`mod@crate::diagnose`]), the loop identification ([`crate::loopid`])
//! and the grey-box extension ([`crate::greybox`]), none of which the context uses.

use crate::data::Record;
use crate::fit::{nelder_mead, FreeParam};
use crate::replay::{
    apply_offsets, fit_cost, nrmse, offsets, overall, replay_cost, replay_guarded,
    replay_params_zeroed, std, Drive, Replay,
};
use ehactl_plant::{EffectId, PlantParams};
use serde::Serialize;
use std::collections::BTreeMap;

/// Held-out error of one model.
#[derive(Debug, Clone, Serialize)]
pub struct Errors {
    /// NRMSE per channel (rms error / std of the measured channel) (-).
    pub channels: BTreeMap<String, f64>,
    /// Root mean square over channels (-).
    pub overall: f64,
}

#[derive(Clone)]
pub(crate) struct Hyp {
    pub(crate) effects: Vec<EffectId>,
    /// Structural variant of each effect in `effects` (`-` for effects with one form).
    pub(crate) variants: Vec<&'static str>,
    pub(crate) params: Vec<FreeParam>,
    pub(crate) values: Vec<f64>,
}

impl Hyp {
    pub(crate) fn empty() -> Hyp {
        Hyp {
            effects: vec![],
            variants: vec![],
            params: vec![],
            values: vec![],
        }
    }

    pub(crate) fn build(&self, base: &PlantParams) -> PlantParams {
        with_values(base, &self.params, &self.values)
    }
}

/// `base` with free parameters `params` set to `values`.
pub(crate) fn with_values(base: &PlantParams, params: &[FreeParam], values: &[f64]) -> PlantParams {
    let mut p = base.clone();
    for (fp, v) in params.iter().zip(values) {
        (fp.set)(&mut p, *v);
    }
    p
}

#[derive(Clone)]
pub(crate) struct Ctx<'a> {
    pub(crate) fit_rec: &'a Record,
    pub(crate) fit_base: PlantParams,
    pub(crate) n_fit: usize,
    pub(crate) val_rec: &'a Record,
    pub(crate) val_base: PlantParams,
    pub(crate) val_range: std::ops::Range<usize>,
    pub(crate) sd_fit: Vec<f64>,
    pub(crate) drive: Drive,
    /// Profile out a constant sensor offset per channel (see `Options::sensor_offsets`).
    pub(crate) offsets: bool,
    /// The fit cost takes this channel only (record channel index); `None`: the mean over
    /// every channel. The assumed loop is identified on its own output ([`crate::loopid`]).
    pub(crate) cost_channel: Option<usize>,
    /// Most substeps per sample a replay's stability guard may take
    /// ([`crate::replay::replay_guarded`]): the config's own count (0 = no guard).
    pub(crate) max_substeps: u32,
}

impl<'a> Ctx<'a> {
    /// The same set-up with the fit cost on record channel `c` only.
    pub(crate) fn on_channel(&self, c: usize) -> Ctx<'a> {
        Ctx {
            cost_channel: Some(c),
            ..self.clone()
        }
    }
    /// The same set-up with hypothesis `h` written into the base parameters for good (the
    /// identified loop: every later model starts from it).
    pub(crate) fn with_base(self, h: &Hyp) -> Ctx<'a> {
        Ctx {
            fit_base: h.build(&self.fit_base),
            val_base: h.build(&self.val_base),
            ..self
        }
    }
}

impl Ctx<'_> {
    /// The same fit and held-out set-up with hypothesis `h` frozen into the base parameters
    /// (used by [`crate::greybox`] to fit terms on top of the catalogue model).
    pub(crate) fn frozen(&self, h: &Hyp) -> Ctx<'_> {
        Ctx {
            fit_rec: self.fit_rec,
            fit_base: h.build(&self.fit_base),
            n_fit: self.n_fit,
            val_rec: self.val_rec,
            val_base: h.build(&self.val_base),
            val_range: self.val_range.clone(),
            sd_fit: self.sd_fit.clone(),
            drive: self.drive,
            offsets: self.offsets,
            cost_channel: self.cost_channel,
            max_substeps: self.max_substeps,
        }
    }
    /// The fitting part cut in two for a transfer check: fit on its first `frac`, predict the
    /// rest (on a chirp or a sweep, other content). `None` when a segment would be shorter than
    /// 200 samples.
    pub(crate) fn transfer_split(&self, frac: f64) -> Option<Ctx<'_>> {
        let na = (self.n_fit as f64 * frac).round() as usize;
        if na < 200 || self.n_fit.saturating_sub(na) < 200 {
            return None;
        }
        Some(Ctx {
            fit_rec: self.fit_rec,
            fit_base: self.fit_base.clone(),
            n_fit: na,
            val_rec: self.fit_rec,
            val_base: self.fit_base.clone(),
            val_range: na..self.n_fit,
            sd_fit: self
                .fit_rec
                .channels
                .iter()
                .map(|c| std(&c.values[..na]).max(1e-300))
                .collect(),
            drive: self.drive,
            offsets: self.offsets,
            cost_channel: self.cost_channel,
            max_substeps: self.max_substeps,
        })
    }
    /// Drive of the replays.
    pub(crate) fn drive(&self) -> Drive {
        self.drive
    }
    /// Std of each channel over the samples in the fit cost (normalises the per-channel cost).
    pub(crate) fn sd_fit(&self) -> &[f64] {
        &self.sd_fit
    }
    /// Base parameters of the fit record.
    pub(crate) fn fit_base_params(&self) -> &PlantParams {
        &self.fit_base
    }
    /// Samples of the fit record in the fit cost.
    pub(crate) fn n_fit(&self) -> usize {
        self.n_fit
    }
    /// The fit record.
    pub(crate) fn fit_rec(&self) -> &Record {
        self.fit_rec
    }
    /// The sensor offsets of model `p` on `rec` (per channel, SI), estimated on samples
    /// `0..n_off` together with the initial state they imply: the replay starts from the
    /// data's first samples less the offsets (a position transducer's zero error must not
    /// preload the model's spring, nor a pressure transducer's start it off equilibrium), and
    /// the offsets are the mean residual of that replay: a fixed point b = F(b). F contracts
    /// geometrically (the initial-state error decays with the plant's slowest mode, so its
    /// share of the window mean falls by a constant factor per pass); three passes and
    /// Aitken's extrapolation per channel on the last two steps give the limit.
    fn offsets_fixed_point(&self, p: &PlantParams, rec: &Record, n_off: usize) -> Vec<f64> {
        let pass = |b: &[f64]| -> Option<Vec<f64>> {
            let sim = self
                .replay(&replay_params_zeroed(p, rec, b), rec, n_off)
                .ok()?;
            (!sim.failed).then(|| offsets(rec, &sim, 0..n_off))
        };
        let zero = vec![0.0; rec.channels.len()];
        let Some(x1) = pass(&zero) else { return zero };
        let Some(x2) = pass(&x1) else { return x1 };
        let Some(x3) = pass(&x2) else { return x2 };
        x1.iter()
            .zip(&x2)
            .zip(&x3)
            .map(|((a, b), c)| {
                let (d1, d2) = (b - a, c - b);
                let ratio = d2 / d1;
                if d1.abs() > 0.0 && ratio.is_finite() && (-0.5..0.9).contains(&ratio) {
                    b + d2 / (1.0 - ratio)
                } else {
                    *c
                }
            })
            .collect()
    }

    /// Replay the first `n` samples of `rec` with `p` and this context's drive and stability
    /// guard.
    fn replay(&self, p: &PlantParams, rec: &Record, n: usize) -> Result<Replay, String> {
        replay_guarded(p, rec, n, self.drive, self.max_substeps)
    }

    /// Replay the first `n` samples of `rec` with `p`; when `offsets` is on, from the initial
    /// state less this model's sensor offsets ([`Ctx::offsets_fixed_point`] on `0..n_off`),
    /// with the offsets (mean residual on `0..n_off`) added to its outputs.
    fn replay_zeroed(
        &self,
        p: &PlantParams,
        rec: &Record,
        n: usize,
        n_off: usize,
    ) -> Result<Replay, String> {
        if !self.offsets {
            return self.replay(p, rec, n);
        }
        let b = self.offsets_fixed_point(p, rec, n_off);
        let mut sim = self.replay(&replay_params_zeroed(p, rec, &b), rec, n)?;
        let b = offsets(rec, &sim, 0..n_off);
        apply_offsets(&mut sim, &b);
        Ok(sim)
    }

    /// Replay of the whole fit record with parameters `p` (offsets from the fitting part).
    pub(crate) fn fit_replay(&self, p: &PlantParams) -> Result<Replay, String> {
        self.replay_zeroed(p, self.fit_rec, self.fit_rec.len(), self.n_fit)
    }

    /// Fit cost of `p`: mean over channels of (rms residual / std of the channel)² on the
    /// fitting part. With offsets, `reference` holds the offsets solved at this fit's
    /// reference point ([`Ctx::offsets_fixed_point`]): the replay starts from the initial
    /// state they imply (the same for every evaluation, so the cost has no memory) and its own offsets
    /// are profiled out of the outputs in closed form. One replay per evaluation. Without
    /// offsets the replay stops once the cost cannot fall below `bound` and returns a value
    /// ≥ `bound` ([`crate::replay::replay_cost`]; the offsets are a mean over the whole
    /// fitting part, so with them every replay runs to the end).
    fn cost_fit(
        &self,
        p: &PlantParams,
        reference: &std::cell::RefCell<Vec<f64>>,
        bound: f64,
    ) -> f64 {
        if !self.offsets {
            return replay_cost(
                p,
                self.fit_rec,
                self.n_fit,
                self.drive,
                self.max_substeps,
                &self.sd_fit,
                self.cost_channel,
                bound,
            )
            .unwrap_or(1e6);
        }
        let start = replay_params_zeroed(p, self.fit_rec, &reference.borrow());
        match self.replay(&start, self.fit_rec, self.n_fit) {
            Ok(mut sim) => {
                let b = offsets(self.fit_rec, &sim, 0..self.n_fit);
                apply_offsets(&mut sim, &b);
                let sums: Vec<f64> = self
                    .fit_rec
                    .channels
                    .iter()
                    .zip(&sim.y)
                    .map(|(ch, yh)| {
                        ch.values[..self.n_fit]
                            .iter()
                            .zip(yh)
                            .map(|(a, b)| (a - b) * (a - b))
                            .sum::<f64>()
                    })
                    .collect();
                fit_cost(
                    &sums,
                    self.n_fit,
                    &self.sd_fit,
                    self.cost_channel,
                    sim.failed,
                )
            }
            Err(_) => 1e6,
        }
    }

    /// Held-out errors of hypothesis `h` and its replay of the validation record. Sensor
    /// offsets come from the fitting part only, never from the held-out samples.
    pub(crate) fn val_errors(&self, h: &Hyp) -> (Errors, Replay) {
        let n = self.val_rec.len();
        let failed = || Replay {
            y: vec![vec![0.0; n]; self.val_rec.channels.len()],
            v: vec![0.0; n],
            dp: vec![0.0; n],
            failed: true,
            failed_at: Some((
                0,
                ehactl_plant::NumericalFailure {
                    t: 0.0,
                    what: "parameters",
                    value: f64::NAN,
                    bound: f64::NAN,
                    unit: "",
                },
            )),
            offsets: vec![0.0; self.val_rec.channels.len()],
        };
        let p = h.build(&self.val_base);
        let sim = if std::ptr::eq(self.val_rec, self.fit_rec) {
            self.replay_zeroed(&p, self.val_rec, n, self.n_fit)
        } else if self.offsets {
            // A separate record taken with the same sensors: the fit record's offsets.
            self.fit_replay(&h.build(&self.fit_base)).and_then(|f| {
                let mut sim = self.replay(
                    &replay_params_zeroed(&p, self.val_rec, &f.offsets),
                    self.val_rec,
                    n,
                )?;
                apply_offsets(&mut sim, &f.offsets);
                Ok(sim)
            })
        } else {
            self.replay(&p, self.val_rec, n)
        };
        let sim = sim.unwrap_or_else(|_| failed());
        (errors(self.val_rec, &sim, self.val_range.clone()), sim)
    }

    /// Fit cost of hypothesis `h` as [`Ctx::fit`] reports it for its result (with offsets,
    /// from the initial state its own offsets imply).
    pub(crate) fn train_cost(&self, h: &Hyp) -> f64 {
        let p = h.build(&self.fit_base);
        let reference = std::cell::RefCell::new(if self.offsets {
            self.offsets_fixed_point(&p, self.fit_rec, self.n_fit)
        } else {
            Vec::new()
        });
        self.cost_fit(&p, &reference, f64::INFINITY)
    }

    pub(crate) fn fit(&self, mut h: Hyp, first_new: usize, evals_per_param: usize) -> (Hyp, f64) {
        let at = |vals: &[f64]| with_values(&self.fit_base, &h.params, vals);
        let from_units = |u: &[f64]| -> Vec<f64> {
            h.params
                .iter()
                .zip(u)
                .map(|(p, s)| p.from_unit(*s))
                .collect()
        };
        let reference = std::cell::RefCell::new(Vec::new());
        let cost = |vals: &[f64], bound: f64| self.cost_fit(&at(vals), &reference, bound);
        // With offsets: solve the initial state they imply at `vals` (the reference of the
        // memoryless cost). Done at the start, per coarse grid point (the points are far
        // apart: each starts from its own converged offsets, not from the previous point's)
        // and between simplex stages.
        let settle = |vals: &[f64]| {
            if self.offsets {
                *reference.borrow_mut() =
                    self.offsets_fixed_point(&at(vals), self.fit_rec, self.n_fit);
            }
        };
        settle(&h.values);
        // Coarse grid over the first new parameter (the effect's magnitude) before the simplex.
        if first_new < h.params.len() {
            let fp = h.params[first_new].clone();
            let mut best = (cost(&h.values, f64::INFINITY), h.values[first_new]);
            for s in [0.1, 0.3, 0.5, 0.7, 0.9] {
                let mut v = h.values.clone();
                v[first_new] = fp.from_unit(s);
                settle(&v);
                // Kept only if below the best so far.
                let c = cost(&v, best.0);
                if c < best.0 {
                    best = (c, v[first_new]);
                }
            }
            h.values[first_new] = best.1;
            settle(&h.values);
        }
        let u0: Vec<f64> = h
            .params
            .iter()
            .zip(&h.values)
            .map(|(p, v)| p.to_unit(*v))
            .collect();
        let mut fu = |u: &[f64], bound: f64| cost(&from_units(u), bound);
        let budget = 60 + evals_per_param * u0.len();
        let (u1, _, _) = nelder_mead(&mut fu, &u0, 0.15, budget * 2 / 3, 1e-6);
        settle(&from_units(&u1));
        let (mut u2, mut c2, _) = nelder_mead(&mut fu, &u1, 0.05, budget / 3, 1e-7);
        if self.offsets {
            // A third stage: the initial state follows the model.
            settle(&from_units(&u2));
            (u2, c2, _) = nelder_mead(&mut fu, &u2, 0.03, budget / 3, 1e-7);
        }
        h.values = from_units(&u2);
        (h, c2)
    }
}

pub(crate) fn errors(rec: &Record, sim: &Replay, range: std::ops::Range<usize>) -> Errors {
    let v = nrmse(rec, sim, range);
    Errors {
        channels: rec
            .channels
            .iter()
            .zip(&v)
            .map(|(c, e)| (c.kind.column().to_string(), *e))
            .collect(),
        overall: overall(&v),
    }
}
