//! Free parameters of the nominal model and of every catalogue effect (looked up in the
//! effect's module, [`crate::effects`]), and a bounded Nelder–Mead minimiser working in
//! normalised (optionally logarithmic) coordinates.

use crate::analysis::Analysis;
use crate::effects;
pub use crate::freeparam::{FreeParam, Scales, Setter};
use ehactl_plant::spec::ParamTree;
use ehactl_plant::{EffectId, PlantParams};
use std::sync::Arc;

/// Nominal parameters refit with every hypothesis, within the uncertainty the config states
/// for them (`[uncertainty]`, [`PlantParams::refit_ranges`]; ±15 % for the valve flow gain,
/// β₀, mass, damping and load stiffness when it is silent), so that realistic errors of the
/// nominal config are not blamed on an effect. Each is a factor on its nominal value
/// (`<path>/nominal`), or the value itself (`<path>`) when the nominal value is 0. A config
/// whose `[uncertainty]` is invalid gives no refit parameters (it fails validation first).
pub fn base_params(nominal: &PlantParams) -> Vec<FreeParam> {
    let ranges = nominal.refit_ranges().unwrap_or_default();
    ranges
        .into_iter()
        .map(|(path, v, lo, hi)| {
            if v != 0.0 {
                FreeParam::new(
                    &format!("{path}/nominal"),
                    lo / v,
                    hi / v,
                    false,
                    1.0,
                    write_nominal(path, move |s| v * s),
                )
            } else {
                FreeParam::new(path, lo, hi, false, v, write_nominal(path, |x| x))
            }
        })
        .collect()
}

/// Setter of a nominal parameter (`UNCERTAIN_PARAMS` path, always present) through the
/// declared-parameter accessor; `value` maps the free coordinate to the parameter value.
fn write_nominal(path: &'static str, value: impl Fn(f64) -> f64 + Send + Sync + 'static) -> Setter {
    debug_assert!(
        PlantParams::knows(path),
        "{path} is not a declared parameter"
    );
    Arc::new(move |p, s| {
        let written = p.set_path(path, value(s));
        debug_assert!(written.is_ok(), "{written:?}");
    })
}

/// The structural variants of effect `e` to fit (DIAGNOSIS.md "Effect variants"): variant
/// name (`-` for effects with one form) and its free parameters. Empty when the effect cannot
/// be tested on this record (e.g. a tone with no line in any residual spectrum). When the
/// nominal config already has the effect, only its configured variant is refit.
pub fn effect_variants(
    e: EffectId,
    nominal: &PlantParams,
    sc: &Scales,
    an: &Analysis,
) -> Vec<(&'static str, Vec<FreeParam>)> {
    let Some(first) = effect_params(e, nominal, sc, an) else {
        return Vec::new();
    };
    effects::of(e).variants(nominal, sc, first)
}

/// Free parameters of effect `e` in its first (or configured) variant (bounds from the rig
/// scales, start values from the nominal section if it exists, else from the residual
/// analysis). `None` when the effect cannot be tested on this record (e.g. a tone with no
/// line in any residual spectrum). [`effect_variants`] adds the other structures.
/// The rules live in the effect's module under crates/ident/src/effects/.
pub fn effect_params(
    e: EffectId,
    nominal: &PlantParams,
    sc: &Scales,
    an: &Analysis,
) -> Option<Vec<FreeParam>> {
    effects::of(e).params(nominal, sc, an)
}

/// Bounded Nelder–Mead in the unit cube. Returns (best point, best cost, evaluations).
/// `f(x, bound)` is the cost at `x`; where the method only needs to know whether it is below
/// `bound` (a reflection against the worst vertex, an expansion against the reflection, a
/// contraction against both), `f` may return any value ≥ `bound` once it knows the cost is at
/// least that, without computing it to the end: the points, the decisions and the result are
/// those of the exact costs (`bound` = `f64::INFINITY` where the value itself is kept).
pub fn nelder_mead(
    f: &mut dyn FnMut(&[f64], f64) -> f64,
    x0: &[f64],
    step: f64,
    max_evals: usize,
    tol: f64,
) -> (Vec<f64>, f64, usize) {
    let n = x0.len();
    let clamp = |x: &mut Vec<f64>| x.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
    let mut evals = 0;
    let mut eval = |x: &[f64], bound: f64, evals: &mut usize| {
        *evals += 1;
        let v = f(x, bound);
        if v.is_finite() {
            v
        } else {
            f64::MAX
        }
    };
    if n == 0 {
        let v = eval(x0, f64::INFINITY, &mut evals);
        return (vec![], v, evals);
    }
    let mut simplex: Vec<(Vec<f64>, f64)> = Vec::with_capacity(n + 1);
    let x0v = x0.to_vec();
    let f0 = eval(&x0v, f64::INFINITY, &mut evals);
    simplex.push((x0v.clone(), f0));
    for i in 0..n {
        let mut x = x0v.clone();
        x[i] += if x[i] + step <= 1.0 { step } else { -step };
        clamp(&mut x);
        let fx = eval(&x, f64::INFINITY, &mut evals);
        simplex.push((x, fx));
    }
    while evals < max_evals {
        simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
        if converged(&simplex, tol) {
            break;
        }
        let c = centroid(&simplex[..n]);
        let pt = |a: f64| -> Vec<f64> {
            let mut x: Vec<f64> = (0..n)
                .map(|j| c[j] + a * (simplex[n].0[j] - c[j]))
                .collect();
            x.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
            x
        };
        let xr = pt(-1.0);
        // Kept only if below the worst vertex; at or above it only min(worst, fr) is used.
        let fr = eval(&xr, simplex[n].1, &mut evals);
        if fr < simplex[0].1 {
            let xe = pt(-2.0);
            let fe = eval(&xe, fr, &mut evals);
            simplex[n] = if fe < fr { (xe, fe) } else { (xr, fr) };
        } else if fr < simplex[n - 1].1 {
            simplex[n] = (xr, fr);
        } else {
            let keep_below = simplex[n].1.min(fr);
            let (xc, fc) = if fr < simplex[n].1 {
                let x = pt(-0.5);
                let v = eval(&x, keep_below, &mut evals);
                (x, v)
            } else {
                let x = pt(0.5);
                let v = eval(&x, keep_below, &mut evals);
                (x, v)
            };
            if fc < simplex[n].1.min(fr) {
                simplex[n] = (xc, fc);
            } else {
                let x0 = simplex[0].0.clone();
                for s in simplex.iter_mut().skip(1) {
                    let x: Vec<f64> =
                        s.0.iter()
                            .zip(&x0)
                            .map(|(a, b)| b + 0.5 * (a - b))
                            .collect();
                    let v = eval(&x, f64::INFINITY, &mut evals);
                    *s = (x, v);
                }
            }
        }
    }
    simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
    let (x, v) = simplex.swap_remove(0);
    (x, v, evals)
}

/// Whether a simplex sorted by cost has converged: its costs within `tol` relative to the
/// best (at least 1e-12 absolute) and every vertex within 1e-3 of the best in each
/// coordinate of the unit cube.
fn converged(simplex: &[(Vec<f64>, f64)], tol: f64) -> bool {
    let (best, worst) = (simplex[0].1, simplex[simplex.len() - 1].1);
    let spread = simplex
        .iter()
        .skip(1)
        .map(|(x, _)| {
            x.iter()
                .zip(&simplex[0].0)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        })
        .fold(0.0, f64::max);
    (worst - best).abs() <= tol * best.abs().max(1e-12) && spread < 1e-3
}

/// The centroid of the given vertices (every vertex but the worst).
fn centroid(vertices: &[(Vec<f64>, f64)]) -> Vec<f64> {
    let n = vertices.len();
    let mut c = vec![0.0; n];
    for (x, _) in vertices {
        for j in 0..n {
            c[j] += x[j] / n as f64;
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::Peak;

    fn analysis() -> Analysis {
        Analysis {
            tones: vec![Peak {
                channel: "force",
                frequency: 225.0,
                amplitude: 3.0,
                prominence: 50.0,
            }],
            ..Analysis::neutral()
        }
    }

    /// Every free parameter named by a declared path writes exactly that parameter and
    /// switches its effect on, from every shipped config, with the section present
    /// (configured) and absent (copied from the fit's seed).
    #[test]
    fn every_setter_writes_its_declared_parameter() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        let mut checked = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "toml") {
                continue;
            }
            let nominal = ehactl_config::RigConfig::load(&path).unwrap().plant;
            let sc = Scales {
                force: 1e4,
                flow: 1e-4,
                pressure: 1e7,
                mass: 10.0,
                stiffness: 1e7,
                dt: 2e-4,
                spool_reach: [1.0, 1.0],
            };
            for &e in EffectId::ALL.iter() {
                for (variant, params) in effect_variants(e, &nominal, &sc, &analysis()) {
                    for fp in params {
                        let v = fp.from_unit(0.37);
                        for start in [nominal.clone(), {
                            let mut p = nominal.clone();
                            p.effects = Default::default();
                            p
                        }] {
                            let mut p = start;
                            (fp.set)(&mut p, v);
                            let what = format!("{} {e} {variant} {}", path.display(), fp.name);
                            assert!(p.effects.is_enabled(e), "{what}: not switched on");
                            if !fp.name.contains(['/', '[']) {
                                assert!(PlantParams::knows(&fp.name), "{what}");
                                assert_eq!(p.get_path(&fp.name), Some(v), "{what}");
                                checked += 1;
                            }
                        }
                    }
                }
            }
        }
        assert!(checked > 200, "{checked} checks");
    }

    /// A cost that gives up at `bound` (returns a value ≥ it without finishing) leads
    /// Nelder–Mead through the same points to the same result as the exact cost: Rosenbrock's
    /// function in 2 and 4 dimensions (minimum 0 at (1, …, 1), mapped into the unit cube).
    #[test]
    fn a_cost_that_stops_at_its_bound_gives_the_same_minimisation() {
        for dim in [2usize, 4] {
            let rosen = |u: &[f64]| -> f64 {
                let x: Vec<f64> = u.iter().map(|v| 4.0 * v - 2.0).collect();
                x.windows(2)
                    .map(|w| 100.0 * (w[1] - w[0] * w[0]).powi(2) + (1.0 - w[0]).powi(2))
                    .sum()
            };
            let x0 = vec![0.1; dim];
            let mut exact_calls = Vec::new();
            let mut exact = |u: &[f64], _bound: f64| {
                exact_calls.push(u.to_vec());
                rosen(u)
            };
            let (xa, fa, na) = nelder_mead(&mut exact, &x0, 0.15, 400, 1e-12);
            let (mut calls, mut stopped) = (Vec::new(), 0);
            let mut bounded = |u: &[f64], bound: f64| {
                calls.push(u.to_vec());
                let v = rosen(u);
                if v >= bound {
                    // What an early stop returns: some value at or above the bound.
                    stopped += 1;
                    bound + 0.5 * (v - bound)
                } else {
                    v
                }
            };
            let (xb, fb, nb) = nelder_mead(&mut bounded, &x0, 0.15, 400, 1e-12);
            assert_eq!((xa, fa, na), (xb, fb, nb), "dim {dim}");
            assert_eq!(
                exact_calls, calls,
                "dim {dim}: the same points in the same order"
            );
            assert!(
                stopped > 20,
                "dim {dim}: only {stopped} evaluations could stop early"
            );
        }
    }
}
