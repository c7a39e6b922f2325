//! Phase 2 of a campaign: the law's shape (derivative window, Dahl travel, series velocity,
//! smoothing) and its terms, chosen by the transfer error.

use super::*;

/// The law's shape: what is not linear in the coefficients.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Shape {
    /// Pre-yield travel δ of the Dahl term (m).
    pub dahl_travel: f64,
    /// Series-dashpot velocity V of the Dahl term (m/s; 0: Dahl's law).
    pub dahl_velocity: f64,
    /// Smoothing velocity v_s of the yield term (m/s).
    pub smoothing_velocity: f64,
    /// Half-width of the derivative turning x into v (s); 0 when every record gives `v`.
    pub velocity_window: f64,
}

/// Phase 2: every shape of the grid, its terms chosen by the transfer error with the default
/// forms only (the normal equations' cost grows with the square of the columns; the full
/// expansion of the forms comes for the chosen shape only); the best shape, its structure and
/// its transfer error (NRMSE²).
pub(super) fn choose_shape(su: &Setup<'_>) -> Result<(Shape, Structure, f64), String> {
    let narrow = expand(
        &su.library,
        &su.default_forms
            .iter()
            .map(|f| vec![*f])
            .collect::<Vec<_>>(),
        &su.expanded.admissible,
    );
    let shapes: Vec<Shape> = shape_grid(su.v_rms, &su.library, &su.prepared);
    let best = try_shapes(su, &narrow, shapes)
        .into_iter()
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .ok_or_else(|| "no law shape could be fitted".to_string())?;
    if !su.library.contains(&LawTerm::Dahl) {
        return Ok(best);
    }
    // The Dahl term behind a series dashpot (V > 0), at the derivative window chosen above:
    // every travel, series velocity and smoothing velocity (the windows are not tried again,
    // which would multiply this stage's cost by their number).
    let series = shape_product(
        &[best.0.velocity_window],
        &DAHL_TRAVELS,
        &DAHL_VELOCITY_FRACTIONS.map(|f| f * su.v_rms),
        &SMOOTHING_FRACTIONS.map(|f| f * su.v_rms),
    );
    Ok(try_shapes(su, &narrow, series)
        .into_iter()
        .chain(std::iter::once(best))
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .expect("one shape at least"))
}

/// Each shape's terms chosen by the transfer error with the default forms; the shapes that
/// share the derivative window and the Dahl shape (travel, series velocity) share the
/// kinematics.
pub(super) fn try_shapes(
    su: &Setup<'_>,
    narrow: &Expanded,
    shapes: Vec<Shape>,
) -> Vec<(Shape, Structure, f64)> {
    let has_dahl = su.library.contains(&LawTerm::Dahl);
    let mut groups: Vec<Vec<Shape>> = Vec::new();
    for s in shapes {
        match groups.iter_mut().find(|g| {
            g[0].velocity_window == s.velocity_window
                && g[0].dahl_travel == s.dahl_travel
                && g[0].dahl_velocity == s.dahl_velocity
        }) {
            Some(g) => g.push(s),
            None => groups.push(vec![s]),
        }
    }
    groups
        .par_iter()
        .flat_map_iter(|g| {
            let kin = kinematics(&su.prepared, &g[0], has_dahl);
            g.iter()
                .map(|s| {
                    let data = normals(&su.prepared, &su.library, narrow, *s, &kin);
                    let (st, j) = select_terms(&data, &su.library, narrow, &su.default_forms);
                    (*s, st, j)
                })
                .collect::<Vec<_>>()
        })
        .collect()
}

pub(super) fn shape_grid(v_rms: f64, library: &[LawTerm], prepared: &[Prepared<'_>]) -> Vec<Shape> {
    let travels: Vec<f64> = if library.contains(&LawTerm::Dahl) {
        DAHL_TRAVELS.to_vec()
    } else {
        vec![PolynomialForce::zero().dahl_travel]
    };
    let windows: Vec<f64> = if prepared.iter().all(|p| p.rec.velocity.is_some()) {
        vec![0.0]
    } else {
        let dt = prepared
            .iter()
            .map(|p| p.rec.dt)
            .fold(f64::INFINITY, f64::min);
        VELOCITY_HALF_WIDTHS
            .iter()
            .map(|m| *m as f64 * dt)
            .collect()
    };
    shape_product(
        &windows,
        &travels,
        &[0.0],
        &SMOOTHING_FRACTIONS.map(|f| f * v_rms),
    )
}

/// Every shape of the given derivative windows (s), Dahl travels δ (m), series-dashpot
/// velocities V (m/s) and smoothing velocities v_s (m/s), in that order of nesting.
pub(super) fn shape_product(
    windows: &[f64],
    travels: &[f64],
    dahl_velocities: &[f64],
    smoothings: &[f64],
) -> Vec<Shape> {
    let mut out = Vec::new();
    for &velocity_window in windows {
        for &dahl_travel in travels {
            for &dahl_velocity in dahl_velocities {
                for &smoothing_velocity in smoothings {
                    out.push(Shape {
                        dahl_travel,
                        dahl_velocity,
                        smoothing_velocity,
                        velocity_window,
                    });
                }
            }
        }
    }
    out
}

pub(super) fn shape_law(shape: Shape) -> PolynomialForce {
    PolynomialForce {
        dahl_travel: shape.dahl_travel,
        dahl_velocity: shape.dahl_velocity,
        smoothing_velocity: shape.smoothing_velocity,
        origin: 0.0,
        ..PolynomialForce::zero()
    }
}

/// Velocity (m/s) and Dahl state (-) of every record at one derivative window and Dahl shape
/// (pre-yield travel, series velocity): shared by the shapes that differ only in the
/// smoothing velocity.
pub(super) struct Kinematics {
    pub(super) v: Vec<Vec<f64>>,
    pub(super) z: Vec<Vec<f64>>,
}

pub(super) fn kinematics(prepared: &[Prepared<'_>], shape: &Shape, dahl: bool) -> Kinematics {
    let law = PolynomialForce {
        dahl_travel: shape.dahl_travel,
        dahl_velocity: shape.dahl_velocity,
        ..PolynomialForce::zero()
    };
    let v: Vec<Vec<f64>> = prepared
        .iter()
        .map(|p| record_velocity(p.rec, p.x, shape.velocity_window))
        .collect();
    let z = prepared
        .iter()
        .zip(&v)
        .map(|(p, v)| {
            if !dahl {
                return Vec::new();
            }
            ehactl_plant::imposed::dahl_state(
                &law,
                &Motion {
                    dt: p.rec.dt,
                    x: p.x,
                    v,
                    dp: None,
                },
            )
        })
        .collect();
    Kinematics { v, z }
}

/// Transfer error J: fit on segments A of every record, predict segments B; the mean over
/// records of each record's NRMSE² (every record counts the same, whatever its force level:
/// a 0 A test of an MR damper weighs as much as a 1 A one).
pub(super) fn transfer_error(
    d: &ShapeData,
    ex: &Expanded,
    library: &[LawTerm],
    st: &Structure,
) -> Option<f64> {
    let p = ex.cols.len();
    let a = sum_normals(d.a.iter(), p);
    let cols = columns_of(st, ex, library);
    let th = a.solve(&cols, ex)?;
    let per: Vec<f64> =
        d.b.iter()
            .filter(|b| b.n > 0.0)
            .map(|b| b.sse(&cols, &th) / b.var_sum())
            .collect();
    Some(per.iter().sum::<f64>() / per.len().max(1) as f64)
}

pub(super) fn select_terms(
    d: &ShapeData,
    library: &[LawTerm],
    ex: &Expanded,
    default_forms: &[Form],
) -> (Structure, f64) {
    let mut st = Structure { terms: vec![] };
    let mut j = transfer_error(d, ex, library, &st).unwrap_or(1.0);
    loop {
        let best = library
            .iter()
            .filter(|t| !st.terms.iter().any(|(u, _)| u == *t))
            .filter_map(|t| {
                let mut s = st.clone();
                s.terms.push((*t, default_forms.to_vec()));
                transfer_error(d, ex, library, &s).map(|e| (s, e))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some((s, e)) if e < (1.0 - TERM_MIN_GAIN) * j => {
                st = s;
                j = e;
            }
            _ => break,
        }
    }
    (st, j)
}
