//! Detection limits: for every catalogue effect the diagnosis did not name, the smallest size
//! this record would have revealed, in the effect's own parameter and unit (DIAGNOSIS.md
//! "Detection limits").
//!
//! The effect is injected into the final model's held-out replay at a trial size (its other
//! parameters at their start values), the change it makes is what a record with the effect
//! would show beyond the model; the part of that change the nominal refit could absorb (its
//! linearised sensitivities, one replay per refit parameter) is projected out, and the
//! acceptance test of step 7 is evaluated at its expected values: the model without the
//! effect leaves the change plus the noise floor on every channel, the model with it the
//! floor alone. The size is bisected on a log scale across the catalogue range.

use crate::ctx::{Ctx, Hyp};
use crate::evidence::Analysis;
use crate::fit::effect_variants;
use crate::freeparam::Scales;
use crate::replay::std;
use ehactl_plant::{EffectId, PlantParams};
use serde::Serialize;
use std::collections::BTreeMap;

/// Bisection steps on the log scale of the catalogue range (-): six halve a range of 10⁴ to a
/// factor 10^(4/64) ≈ 1.15.
pub const BISECTION_STEPS: usize = 6;

/// A model within this factor × the noise floor on every channel is not extended (-): the
/// decision's own `FLOOR_FACTOR` (`crate::diagnose` takes it from here).
pub const FLOOR_FACTOR: f64 = 1.2;

/// Lower end of the search for a parameter whose range starts at 0, as a share of its upper
/// bound (-): a log scale needs a positive start.
const ZERO_START: f64 = 1e-4;

/// One effect's detection limit.
#[derive(Debug, Clone, Serialize)]
pub struct DetectionLimit {
    /// The sizing parameter (dotted path).
    pub parameter: String,
    /// Its unit.
    pub unit: String,
    /// `larger` when a larger value is a stronger effect, `smaller` otherwise (a spool limit,
    /// a mount stiffness).
    pub stronger: String,
    /// The smallest size (in the direction of `stronger`) this record would have revealed;
    /// `None` when no size in the catalogue range would have been, or when the effect is not
    /// testable on this record (`note`).
    pub limit: Option<f64>,
    /// The catalogue range searched [weakest, strongest].
    pub range: [f64; 2],
    /// `not detectable with this record`, `not testable on this record`, `in the nominal
    /// config already`, or empty.
    pub note: String,
    /// Position of the limit on the log scale from the weakest (0) to the strongest (1) end
    /// of the range; 1 when not detectable (-). The loosest limits have the largest.
    pub looseness: f64,
    /// The structure (catalogue variant) the limit holds for: of the effect's structures sized
    /// by `parameter`, the one hardest to see on this record (`-` when it has one).
    pub variant: String,
    /// The shape the limit holds for where it is not the catalogue's start values: one shape
    /// parameter moved ([`SHAPE_POSITIONS`]), the hardest to see. Absent otherwise.
    #[serde(skip_serializing_if = "String::is_empty")]
    pub shape: String,
    /// How the limit was found: `linearised` (the acceptance test at its expected values on
    /// the linearised refit), or `injected` (also confirmed by fitting the effect to the
    /// record with the effect added at that size, under the search's own acceptance test);
    /// `raised by injection` when that fit moved the limit up.
    pub method: String,
}

impl DetectionLimit {
    /// The limit in words: "`time_delay` ≥ 4.0e-4 s" or why there is none.
    pub fn text(&self, effect: &str) -> String {
        let short = self.parameter.rsplit('.').next().unwrap_or(&self.parameter);
        match self.limit {
            Some(v) => format!(
                "`{effect}` {short} {} {v:.2e} {}",
                if self.stronger == "larger" {
                    "≥"
                } else {
                    "≤"
                },
                self.unit
            ),
            None => format!("`{effect}`: {}", self.note),
        }
    }
}

/// The sizing parameters of effect `e`, the first its fitted variant has: (name, unit, a
/// larger value is a stronger effect).
fn size_params(e: EffectId) -> &'static [(&'static str, &'static str, bool)] {
    use EffectId::*;
    const SPOOL: &str = "(fraction of the spool stroke)";
    match e {
        Friction => &[("effects.friction.coulomb_force", "N", true)],
        ValveDeadband => &[
            ("effects.valve_deadband.overlap", SPOOL, true),
            ("effects.valve_deadband.deadzone", SPOOL, true),
        ],
        ValveSaturation => &[("effects.valve_saturation.spool_limit", SPOOL, false)],
        ValveDynamics => &[
            ("effects.valve_dynamics.natural_frequency", "rad/s", false),
            ("effects.valve_dynamics.time_constant", "s", true),
        ],
        InternalLeakage => &[("effects.internal_leakage.coefficient", "m³/(s·Pa)", true)],
        ExternalLeakage => &[("effects.external_leakage.coefficient", "m³/(s·Pa)", true)],
        BulkModulusPressure => &[("effects.bulk_modulus_pressure.slope", "(dβ/dp, -)", true)],
        LineDynamics => &[("effects.line_dynamics.length", "m", true)],
        FlexibleMount => &[("effects.flexible_mount.stiffness", "N/m", false)],
        TimeDelay => &[("effects.time_delay.delay", "s", true)],
        SensorTone => &[(
            "effects.sensor_tone.sine_amplitudes[0]",
            "(the channel's SI unit)",
            true,
        )],
        SupplyPressureDrop => &[("effects.supply_pressure_drop.resistance", "Pa·s/m³", true)],
    }
}

/// What every limit is judged against: the final model's held-out replay, the measured
/// channels' std and noise floors over the held-out range, and the refit's sensitivities.
pub(crate) struct Reference<'c, 'a> {
    ctx: &'c Ctx<'a>,
    pub(crate) model: &'c Hyp,
    /// Held-out replay of `model`, per channel over the held-out range.
    y0: Vec<Vec<f64>>,
    /// Std of each measured channel over the held-out range.
    sd: Vec<f64>,
    /// Noise floor per channel (NRMSE units).
    floor: Vec<f64>,
    /// Change of the held-out replay per unit step of each refit parameter (normalised
    /// coordinates), floor-weighted and flattened over channels.
    sens: Vec<Vec<f64>>,
}

/// Whether `p` is one of a model's nominal parameters (refit by the refit phase), not an
/// effect's or the grey-box law's.
pub(crate) fn is_nominal(p: &crate::freeparam::FreeParam) -> bool {
    !p.name.starts_with("effects.")
}

/// The held-out replay of `h` over the held-out range, per channel.
fn held_out(ctx: &Ctx<'_>, h: &Hyp) -> Vec<Vec<f64>> {
    let (_, sim) = ctx.val_errors(h);
    sim.y
        .iter()
        .map(|y| y[ctx.val_range.clone()].to_vec())
        .collect()
}

impl<'c, 'a> Reference<'c, 'a> {
    /// The reference of model `model` with noise floors `floor` (NRMSE units per channel):
    /// one replay, and one more per refit parameter of the model (not an effect's).
    pub(crate) fn new(ctx: &'c Ctx<'a>, model: &'c Hyp, floor: &[f64]) -> Self {
        let y0 = held_out(ctx, model);
        let sd: Vec<f64> = ctx
            .val_rec
            .channels
            .iter()
            .map(|c| std(&c.values[ctx.val_range.clone()]).max(1e-300))
            .collect();
        let mut r = Reference {
            ctx,
            model,
            y0,
            sd,
            floor: floor.iter().map(|f| f.max(1e-300)).collect(),
            sens: Vec::new(),
        };
        for i in 0..model.params.len() {
            let p = &model.params[i];
            if !is_nominal(p) || p.hi <= p.lo {
                continue;
            }
            let u = p.to_unit(model.values[i]);
            let step = if u > 0.5 { -0.02 } else { 0.02 };
            let mut h = model.clone();
            h.values[i] = p.from_unit(u + step);
            let y = held_out(ctx, &h);
            r.sens.push(r.weighted_change(&y));
        }
        r
    }

    /// The change from the reference replay to `y`, each channel over its std and floor
    /// (floor-weighted NRMSE units) and over √(samples · channels), flattened.
    fn weighted_change(&self, y: &[Vec<f64>]) -> Vec<f64> {
        let n = self.y0.first().map_or(1, Vec::len).max(1) as f64;
        let k = self.y0.len().max(1) as f64;
        let mut out = Vec::new();
        for (c, (y, y0)) in y.iter().zip(&self.y0).enumerate() {
            let w = 1.0 / (self.sd[c] * self.floor[c] * (n * k).sqrt());
            out.extend(y.iter().zip(y0).map(|(a, b)| (a - b) * w));
        }
        out
    }

    /// Per channel, (the change over the floor)² that the refit cannot absorb, for the
    /// replay `y` of a model with the effect: the weighted change less its least-squares
    /// projection on the refit's sensitivities, its mean square per channel × channels.
    fn excess(&self, y: &[Vec<f64>]) -> Vec<f64> {
        let d = self.weighted_change(y);
        let r = residual_of_projection(&d, &self.sens);
        let k = self.y0.len().max(1);
        let n = r.len() / k;
        (0..k)
            .map(|c| r[c * n..(c + 1) * n].iter().map(|v| v * v).sum::<f64>() * k as f64)
            .collect()
    }

    /// Whether a record holding the effect of model `h` (the reference model plus the effect)
    /// would pass the acceptance test of step 7 with `n_new` parameters of its own.
    fn detected(&self, h: &Hyp, n_new: usize) -> bool {
        let y = held_out(self.ctx, h);
        if y.iter().flatten().any(|v| !v.is_finite()) {
            return false;
        }
        let m = self.excess(&y);
        passes(&m, &self.floor, n_new)
    }
}

/// `d` less its least-squares projection on the columns `cols` (normal equations with a
/// relative ridge of 1e-9, Gaussian elimination with partial pivoting).
fn residual_of_projection(d: &[f64], cols: &[Vec<f64>]) -> Vec<f64> {
    let k = cols.len();
    if k == 0 {
        return d.to_vec();
    }
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let mut a: Vec<Vec<f64>> = (0..k)
        .map(|i| {
            let mut row: Vec<f64> = (0..k).map(|j| dot(&cols[i], &cols[j])).collect();
            row.push(dot(&cols[i], d));
            row
        })
        .collect();
    let scale = (0..k).map(|i| a[i][i]).fold(0.0, f64::max).max(1e-300);
    for (i, row) in a.iter_mut().enumerate() {
        row[i] += 1e-9 * scale;
    }
    for c in 0..k {
        let p = (c..k)
            .max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))
            .unwrap_or(c);
        a.swap(c, p);
        if a[c][c].abs() < 1e-300 {
            continue;
        }
        for r in (c + 1)..k {
            let (top, bottom) = a.split_at_mut(r);
            let (pivot, row) = (&top[c], &mut bottom[0]);
            let f = row[c] / pivot[c];
            for (x, p) in row[c..].iter_mut().zip(&pivot[c..]) {
                *x -= f * p;
            }
        }
    }
    let mut beta = vec![0.0; k];
    for c in (0..k).rev() {
        let s: f64 = ((c + 1)..k).map(|j| a[c][j] * beta[j]).sum();
        beta[c] = if a[c][c].abs() < 1e-300 {
            0.0
        } else {
            (a[c][k] - s) / a[c][c]
        };
    }
    d.iter()
        .enumerate()
        .map(|(i, v)| v - cols.iter().zip(&beta).map(|(c, b)| c[i] * b).sum::<f64>())
        .collect()
}

/// The acceptance test of step 7 (round 0) at its expected values, for a record whose model
/// without the effect leaves, per channel, the floor plus `m`·floor² (the effect's change over
/// the floor, squared) and whose model with the effect leaves the floor (`floor`, NRMSE
/// units): not every channel within [`FLOOR_FACTOR`] × its floor, and on the channel-mean
/// J or on the floor-weighted J the fall by ≥ 10 %, a lower score with `n_new` parameters more
/// (and at least half of the weighted excess explained, which a perfect fit always does).
pub(crate) fn passes(m: &[f64], floor: &[f64], n_new: usize) -> bool {
    if m.iter().all(|x| (1.0 + x).sqrt() < FLOOR_FACTOR) {
        return false;
    }
    let k = m.len().max(1) as f64;
    let j_with = floor.iter().map(|f| f * f).sum::<f64>() / k;
    let j_cur = floor
        .iter()
        .zip(m)
        .map(|(f, x)| f * f * (1.0 + x))
        .sum::<f64>()
        / k;
    let jw_cur = 1.0 + m.iter().sum::<f64>() / k;
    let penalty = 0.02 * n_new as f64;
    let explains = |new: f64, old: f64| new < 0.9 * old && new.ln() + penalty < old.ln();
    explains(j_with, j_cur) || explains(1.0, jw_cur)
}

/// The limits of every effect of `effects` (the caller leaves out those it named) that is not
/// in the final model `model` either, against that model (floors per channel `floor`);
/// `scales` and `an` give each effect's parameters as the search fitted them (first variant,
/// start values).
pub(crate) fn detection_limits(
    ctx: &Ctx<'_>,
    model: &Hyp,
    floor: &[f64],
    effects: &[EffectId],
    nominal: &PlantParams,
    scales: &Scales,
    an: &Analysis,
) -> BTreeMap<String, (DetectionLimit, Option<Injection>)> {
    let reference = Reference::new(ctx, model, floor);
    effects
        .iter()
        .filter(|e| !model.effects.contains(e))
        .map(|&e| {
            (
                e.as_str().to_string(),
                limit_of(&reference, e, nominal, scales, an),
            )
        })
        .collect()
}

/// The start value of an effect's parameter for a limit: its start value, except a zero
/// offset of a dead band and the cosine part of a tone, which are 0 so that the effect
/// vanishes with its size (a dead band of zero width with the analysis' offset still shifts
/// the spool: on the MTS record it was "detected" at the smallest overlap searched).
fn neutral_start(p: &crate::freeparam::FreeParam) -> f64 {
    let neutral = p.name.ends_with(".zero_offset") || p.name.contains(".cosine_amplitudes[");
    if neutral && p.lo <= 0.0 && p.hi >= 0.0 {
        0.0
    } else {
        p.init
    }
}

/// Share of the moving mass a load-side mount's injection puts behind the spring (-): the
/// piston keeps the rest, so the total mass is the model's and a stiff mount converges to the
/// model itself (with the catalogue's start value, a load mass equal to the moving mass added
/// on top, the injection doubled the mass at any stiffness and the limit pinned at the
/// stiffest end). One share only, and the mount's damping not moved (`shapes`): with shares
/// of 0.2, 0.5 and 0.8 and the damping ratio moved, the loosest injection (a load-side mount
/// with half the mass on the spring) was not recovered by the search's own fit at any
/// stiffness on the clean generator record 7020, whose rich multisine shows mounts: every
/// mount read "not detectable" (a stated gap: the limit holds for this split).
pub const MOUNT_LOAD_SHARE: f64 = 0.5;

/// One structure of an effect injected at a trial size: its variant, its parameters (the
/// others at their neutral start values) and which of them sets the size, searched on a log
/// scale from `weak` to `strong`.
#[derive(Clone)]
pub(crate) struct Injection {
    pub(crate) effect: EffectId,
    pub(crate) variant: &'static str,
    pub(crate) params: Vec<crate::freeparam::FreeParam>,
    /// The values `added_to` gives the parameters (the size's is replaced): their neutral
    /// start values ([`neutral_start`]), one of them moved for a shape alternative.
    start: Vec<f64>,
    /// The shape parameter this injection moves from its start value, in words; empty when
    /// none.
    pub(crate) shape: String,
    /// Index of the sizing parameter in `params`.
    pub(crate) size_at: usize,
    weak: f64,
    strong: f64,
}

impl Injection {
    /// The injections of structure `variant` of effect `e` with parameters `params`, sized
    /// by `name` (a larger value stronger when `up`): at the start values, then each shape
    /// alternative ([`shapes`]); none when it lacks that parameter or its range is empty.
    fn new(
        e: EffectId,
        (variant, params): (&'static str, Vec<crate::freeparam::FreeParam>),
        name: &str,
        up: bool,
    ) -> Vec<Injection> {
        let Some(i) = params.iter().position(|p| p.name == name) else {
            return Vec::new();
        };
        let p = &params[i];
        let lo = if p.lo > 0.0 { p.lo } else { p.hi * ZERO_START };
        if !(p.hi > lo && lo > 0.0) {
            return Vec::new();
        }
        let (weak, strong) = if up { (lo, p.hi) } else { (p.hi, lo) };
        let mut injected = params.clone();
        if e == EffectId::FlexibleMount && variant == "load_side" {
            split_mass(&mut injected);
        }
        let neutral: Vec<f64> = params.iter().map(neutral_start).collect();
        shapes(e, &params, i)
            .into_iter()
            .map(|(shape, start)| Injection {
                effect: e,
                variant,
                params: injected.clone(),
                start: start.unwrap_or_else(|| neutral.clone()),
                shape,
                size_at: i,
                weak,
                strong,
            })
            .collect()
    }

    /// The size at position `s` ∈ [0, 1] of the log scale from the weakest to the strongest.
    pub(crate) fn at(&self, s: f64) -> f64 {
        self.weak * (self.strong / self.weak).powf(s)
    }

    /// `model` with this structure at size `v`.
    pub(crate) fn added_to(&self, model: &Hyp, v: f64) -> Hyp {
        self.with_values(model, &self.start, Some(v))
    }

    /// `model` with this structure at parameter values `values` (in the order of `params`),
    /// its size replaced by `size` when given.
    pub(crate) fn with_values(&self, model: &Hyp, values: &[f64], size: Option<f64>) -> Hyp {
        let mut h = model.clone();
        let first = h.params.len();
        h.effects.push(self.effect);
        h.variants.push(self.variant);
        h.values.extend_from_slice(values);
        h.params.extend(self.params.iter().cloned());
        if let Some(v) = size {
            h.values[first + self.size_at] = v;
        }
        h
    }
}

/// Positions on a shape parameter's normalised range (`FreeParam::from_unit`) its
/// alternatives are injected at, one parameter at a time (-).
pub const SHAPE_POSITIONS: [f64; 2] = [0.25, 0.75];

/// The shapes a structure is injected in for its limit: (words, the start values when
/// moved). At the catalogue's start values first; then every parameter but the size
/// (`size_at`), a zero offset and a tone's cosine part and frequency moved alone to each of
/// [`SHAPE_POSITIONS`]; a mount in the first shape only ([`MOUNT_LOAD_SHARE`]). The record
/// does not say the hidden effect's shape, and a recovery that starts its fit at the very
/// shape injected finds it more easily than the search finds a hidden effect: on the PI force
/// rig's LuGre case 7400 made physical at half its size (12.7 N, bristles of 20 µm
/// pre-sliding where the catalogue starts at a fraction of a µm), the search named nothing
/// while the limit at the start values read 8.9 N.
fn shapes(
    e: EffectId,
    params: &[crate::freeparam::FreeParam],
    size_at: usize,
) -> Vec<(String, Option<Vec<f64>>)> {
    let plain = std::iter::once((String::new(), None));
    if e == EffectId::FlexibleMount {
        return plain.collect();
    }
    let neutral: Vec<f64> = params.iter().map(neutral_start).collect();
    plain
        .chain(
            moved(params, &neutral, size_at)
                .into_iter()
                .map(|(w, start)| (w, Some(start))),
        )
        .collect()
}

/// Every parameter of `params` but the size (`size_at`), a zero offset and a tone's cosine
/// part and frequency, moved alone from `neutral` to each of [`SHAPE_POSITIONS`]: (words,
/// start values).
fn moved(
    params: &[crate::freeparam::FreeParam],
    neutral: &[f64],
    size_at: usize,
) -> Vec<(String, Vec<f64>)> {
    let mut out = Vec::new();
    for (j, p) in params.iter().enumerate() {
        // A tone's frequency is the residual line's, not a shape to move.
        let fixed = p.name.ends_with(".zero_offset")
            || p.name.contains(".cosine_amplitudes[")
            || p.name.contains(".frequencies[");
        if j == size_at || fixed || p.hi <= p.lo {
            continue;
        }
        for u in SHAPE_POSITIONS {
            let mut start = neutral.to_vec();
            start[j] = p.from_unit(u);
            out.push((format!("{} = {:.3e}", p.name, start[j]), start));
        }
    }
    out
}

/// Makes a load-side mount's load mass [`MOUNT_LOAD_SHARE`] of the moving mass, taken from
/// the piston (the parameter's own value is ignored).
fn split_mass(params: &mut [crate::freeparam::FreeParam]) {
    if let Some(p) = params
        .iter_mut()
        .find(|p| p.name == "effects.flexible_mount.load_mass")
    {
        let set = p.set.clone();
        p.set = std::sync::Arc::new(move |q: &mut PlantParams, _v: f64| {
            let m = q.mechanics.mass;
            set(q, MOUNT_LOAD_SHARE * m);
            q.mechanics.mass = (1.0 - MOUNT_LOAD_SHARE) * m;
        });
    }
}

/// One structure of an effect with its linearised limit: the position on the log scale of
/// the range ([`Injection::at`]), `None` when even the strongest is not detected.
type Structure = (Option<f64>, Injection);

/// Bisection of the detection of `inj` on top of the reference model: the position on the
/// log scale of the smallest size detected, `None` when even the strongest is not.
fn bisect(reference: &Reference<'_, '_>, inj: &Injection) -> Option<f64> {
    let n_new = inj.params.len();
    let detected = |s: f64| reference.detected(&inj.added_to(reference.model, inj.at(s)), n_new);
    if !detected(1.0) {
        return None;
    }
    if detected(0.0) {
        return Some(0.0);
    }
    // `hi` is always detected.
    let (mut lo_s, mut hi_s) = (0.0, 1.0);
    for _ in 0..BISECTION_STEPS {
        let mid = 0.5 * (lo_s + hi_s);
        if detected(mid) {
            hi_s = mid;
        } else {
            lo_s = mid;
        }
    }
    Some(hi_s)
}

/// The detection limit of effect `e` against `reference`, and the structure it holds for.
/// Every variant of the effect sized by the same parameter, in each of its shapes
/// ([`shapes`]), is bisected and the loosest is the limit: the record does not say which
/// structure a hidden effect would have, so only the hardest to see bounds them all.
fn limit_of(
    reference: &Reference<'_, '_>,
    e: EffectId,
    nominal: &PlantParams,
    scales: &Scales,
    an: &Analysis,
) -> (DetectionLimit, Option<Injection>) {
    let variants = effect_variants(e, nominal, scales, an);
    let sizes = size_params(e);
    let found = sizes.iter().find(|s| {
        variants
            .first()
            .is_some_and(|v| v.1.iter().any(|p| p.name == s.0))
    });
    let (name, unit, up) = *found.unwrap_or(&sizes[0]);
    let mut out = DetectionLimit {
        parameter: name.to_string(),
        unit: unit.to_string(),
        stronger: if up { "larger" } else { "smaller" }.to_string(),
        limit: None,
        range: [f64::NAN, f64::NAN],
        note: "not testable on this record".to_string(),
        looseness: 1.0,
        variant: String::new(),
        shape: String::new(),
        method: String::new(),
    };
    if nominal.effects.is_enabled(e) {
        // A configured effect's size is the config's (or the identified loop's): what it
        // would take to reveal it on top of itself is no limit.
        out.note = "in the nominal config already".to_string();
        return (out, None);
    }
    let mut bisected: Vec<Structure> = variants
        .into_iter()
        .flat_map(|v| Injection::new(e, v, name, up))
        .map(|inj| (bisect(reference, &inj), inj))
        .collect();
    // The loosest structure first; one not detected at all is the loosest there is. Among
    // equally loose ones the last (a later variant, a moved shape) first, as `max_by` chose
    // before the shapes: on the clean generator record 7020 a load-side mount and a
    // body-side one tie at the stiffest end, and the load-side one, split, is recovered by
    // injection at no stiffness (a stated gap) where the body-side one is at the stiffest.
    bisected.reverse();
    bisected.sort_by(|a, b| b.0.unwrap_or(2.0).total_cmp(&a.0.unwrap_or(2.0)));
    let Some((s, inj)) = bisected.first() else {
        return (out, None);
    };
    out.range = [inj.weak, inj.strong];
    out.variant = inj.variant.to_string();
    out.shape = inj.shape.clone();
    out.method = "linearised".to_string();
    match s {
        None => {
            out.note = "not detectable with this record".to_string();
            // Not detected in any shape, the structure's own is the one to name.
            let plain = bisected
                .iter()
                .any(|(s, i)| s.is_none() && i.variant == inj.variant && i.shape.is_empty());
            if plain {
                out.shape = String::new();
            }
        }
        Some(s) => {
            out.limit = Some(inj.at(*s));
            out.note = String::new();
            out.looseness = *s;
        }
    }
    (out, bisected.into_iter().next().map(|(_, inj)| inj))
}

/// The two or three loosest limits of `limits` (largest looseness first), in words.
pub fn loosest(limits: &BTreeMap<String, DetectionLimit>, n: usize) -> Vec<String> {
    let mut v: Vec<(&String, &DetectionLimit)> = limits
        .iter()
        .filter(|(_, l)| l.limit.is_some() || l.note == "not detectable with this record")
        .collect();
    v.sort_by(|a, b| b.1.looseness.total_cmp(&a.1.looseness));
    v.into_iter().take(n).map(|(e, l)| l.text(e)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Nothing at all (every channel at its floor) is not detected; a change of 3× the floor
    /// on one of two channels is (weighted J 1 → 5.5); a change of 0.5× the floor on both is
    /// not (each channel within 1.2× its floor: √1.25 = 1.118).
    #[test]
    fn the_acceptance_test_at_its_expected_values() {
        let floor = [0.001, 0.01];
        assert!(!passes(&[0.0, 0.0], &floor, 1));
        assert!(passes(&[9.0, 0.0], &floor, 1));
        assert!(!passes(&[0.25, 0.25], &floor, 1));
        // 0.7× the floor on both: 1.22× > 1.2, J and weighted J fall by 1/1.49 = 33 %.
        assert!(passes(&[0.49, 0.49], &floor, 1));
    }

    /// A change that is a multiple of a sensitivity column is absorbed entirely; one
    /// orthogonal to it is left whole.
    #[test]
    fn the_refit_absorbs_what_it_can() {
        let col = vec![1.0, 2.0, 0.0, 0.0];
        let r = residual_of_projection(&[3.0, 6.0, 0.0, 0.0], std::slice::from_ref(&col));
        assert!(r.iter().all(|v| v.abs() < 1e-6), "{r:?}");
        let r = residual_of_projection(&[0.0, 0.0, 1.0, -1.0], &[col]);
        assert_eq!(r, vec![0.0, 0.0, 1.0, -1.0]);
    }

    /// The test bench's nominal plant, rig scales and a neutral residual analysis.
    fn testbench() -> (PlantParams, Scales, Analysis) {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/diagnose_testrig.toml");
        let nominal = ehactl_config::RigConfig::load(&path).unwrap().plant;
        let sc = Scales {
            force: 1e4,
            flow: 1e-4,
            pressure: 1e7,
            mass: nominal.mechanics.mass,
            stiffness: 1e7,
            dt: 2e-4,
            spool_reach: [1.0, 1.0],
        };
        let an = Analysis::neutral();
        (nominal, sc, an)
    }

    /// A LuGre friction is injected at the catalogue's start values, then with each other
    /// parameter moved alone to a quarter and three quarters of its range; the size is never
    /// moved, and the plant built from an injection holds the moved value.
    #[test]
    fn each_shape_parameter_is_moved_alone() {
        let (nominal, sc, an) = testbench();
        let lugre = effect_variants(EffectId::Friction, &nominal, &sc, &an)
            .into_iter()
            .find(|v| v.0 == "lugre")
            .expect("a LuGre variant");
        let n = lugre.1.len();
        let size = "effects.friction.coulomb_force";
        let injs = Injection::new(EffectId::Friction, lugre, size, true);
        assert_eq!(injs.len(), 1 + SHAPE_POSITIONS.len() * (n - 1));
        let neutral = &injs[0].start;
        assert!(injs[0].shape.is_empty());
        for inj in &injs[1..] {
            let moved: Vec<usize> = (0..n).filter(|&j| inj.start[j] != neutral[j]).collect();
            assert_eq!(moved.len(), 1, "{}", inj.shape);
            let p = &inj.params[moved[0]];
            assert_ne!(p.name, size);
            let u = p.to_unit(inj.start[moved[0]]);
            assert!(
                SHAPE_POSITIONS.iter().any(|&w| (u - w).abs() < 1e-9),
                "{}",
                inj.shape
            );
            assert!(inj.shape.starts_with(&p.name));
        }
        let bristle = injs
            .iter()
            .find(|i| i.shape.starts_with("effects.friction.bristle_stiffness"))
            .expect("the bristle stiffness moved");
        let j = bristle
            .params
            .iter()
            .position(|p| p.name == "effects.friction.bristle_stiffness")
            .unwrap();
        let built = bristle.added_to(&Hyp::empty(), 30.0).build(&nominal);
        let f = built.effects.friction.as_ref().unwrap();
        assert_eq!(f.bristle_stiffness, bristle.start[j]);
        assert_eq!(f.coulomb_force, 30.0);
    }

    /// A load-side mount injected for a limit takes its load mass from the piston: the total
    /// mass stays the config's at every stiffness, so a stiff mount is the model itself. The
    /// piston-side structure (the cylinder body on the mount) keeps the moving mass.
    #[test]
    fn a_mount_injection_keeps_the_total_mass() {
        let (nominal, sc, an) = testbench();
        let m = nominal.mechanics.mass;
        let variants = effect_variants(EffectId::FlexibleMount, &nominal, &sc, &an);
        assert_eq!(variants.len(), 2);
        for v in variants {
            let name = v.0;
            let injs = Injection::new(
                EffectId::FlexibleMount,
                v,
                "effects.flexible_mount.stiffness",
                false,
            );
            // One shape each: a load-side mount split, a body-side one as the catalogue's.
            assert_eq!(injs.len(), 1, "{name}");
            for inj in injs {
                for s in [0.0, 0.5, 1.0] {
                    let p = inj.added_to(&Hyp::empty(), inj.at(s)).build(&nominal);
                    let mount = p.effects.flexible_mount.as_ref().unwrap();
                    assert_eq!(mount.stiffness, inj.at(s));
                    if name == "load_side" {
                        assert!((p.mechanics.mass + mount.load_mass - m).abs() < 1e-12 * m);
                        assert!((mount.load_mass - MOUNT_LOAD_SHARE * m).abs() < 1e-12 * m);
                    } else {
                        assert_eq!(p.mechanics.mass, m, "{name}");
                    }
                }
            }
        }
    }

    #[test]
    fn limits_in_words() {
        let l = DetectionLimit {
            parameter: "effects.time_delay.delay".into(),
            unit: "s".into(),
            stronger: "larger".into(),
            limit: Some(4e-4),
            range: [1.2e-6, 0.012],
            note: String::new(),
            looseness: 0.6,
            variant: "-".into(),
            shape: String::new(),
            method: "linearised".into(),
        };
        assert_eq!(l.text("time_delay"), "`time_delay` delay ≥ 4.00e-4 s");
    }
}
