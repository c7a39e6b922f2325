//! The Dahl term's shape following one operating input: the travel δ(i) and series velocity
//! V(i) through the values chosen per fitted operating point.

use super::*;

/// The Dahl term's shape depending on one operating input i: the pre-yield travel
/// δ(i) = δ₀ + δ₁·i and the series-dashpot velocity V(i) = V₀ + V₁·i, through the pairs
/// (δ, V) chosen per fitted operating point (least squares over the points). Published models
/// of MR dampers let a shape parameter follow the current as well (Quiroz, UTFSM 2022, ch. 7:
/// β of the Bouc–Wen model exponential in i; in Spencer et al. 1997 the roll-off velocity of
/// the series dashpot, α·z/(c₀ + c₁), grows with α, affine in the coil input); kept only when
/// it lowers the transfer error of the shared shape by [`TERM_MIN_GAIN`].
#[derive(Debug, Clone, Serialize)]
pub struct TravelDependence {
    /// The input (a declared `[inputs]` name).
    pub input: String,
    /// The input's unit (its `[inputs.<name>] unit`).
    pub unit: String,
    /// δ₀ (m): the travel at i = 0.
    pub at_zero: f64,
    /// δ₁ (m per unit of the input).
    pub slope: f64,
    /// V₀ (m/s): the series-dashpot velocity at i = 0.
    pub velocity_at_zero: f64,
    /// V₁ (m/s per unit of the input).
    pub velocity_slope: f64,
    /// The travel and series velocity chosen per fitted operating point (input value, δ in
    /// m, V in m/s).
    pub per_point: Vec<(f64, f64, f64)>,
    /// Transfer error (NRMSE) with the shared shape, and with δ(i), V(i) (-).
    pub nrmse_transfer_shared: f64,
    /// See `nrmse_transfer_shared`.
    pub nrmse_transfer: f64,
    /// Largest series velocity searched (m/s): V(i) is kept within [0, this].
    #[serde(skip)]
    pub(super) velocity_max: f64,
}

impl TravelDependence {
    /// δ (m) and V (m/s) at input value `i`, kept within the values the campaign searches
    /// (within the fitted operating points they always are; the extended config's linear
    /// dependence is not clamped beyond them).
    pub(super) fn at(&self, i: f64) -> (f64, f64) {
        (
            (self.at_zero + self.slope * i)
                .clamp(DAHL_TRAVELS[0], DAHL_TRAVELS[DAHL_TRAVELS.len() - 1]),
            (self.velocity_at_zero + self.velocity_slope * i).clamp(0.0, self.velocity_max),
        )
    }

    /// Whether δ, V follow the input.
    pub(super) fn travel_varies(&self) -> bool {
        self.slope != 0.0
    }

    pub(super) fn velocity_varies(&self) -> bool {
        self.velocity_slope != 0.0
    }
}

/// Per-record normal equations with record `r` at the Dahl shape `dahl[r]` (δ m, V m/s).
pub(super) fn normals_at_travels(
    prepared: &[Prepared<'_>],
    library: &[LawTerm],
    expanded: &Expanded,
    shape: Shape,
    dahl: &[(f64, f64)],
) -> ShapeData {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for (r, (d, vd)) in dahl.iter().enumerate() {
        let one = std::slice::from_ref(&prepared[r]);
        let sh = Shape {
            dahl_travel: *d,
            dahl_velocity: *vd,
            ..shape
        };
        let kin = kinematics(one, &sh, true);
        let mut n = normals(one, library, expanded, sh, &kin);
        a.append(&mut n.a);
        b.append(&mut n.b);
    }
    ShapeData { shape, a, b }
}

/// Least-squares line through points (i, y): (value at 0, slope); exact through two.
pub(super) fn line_through(pts: &[(f64, f64)]) -> (f64, f64) {
    let n = pts.len() as f64;
    let (mi, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sii: f64 = pts.iter().map(|p| (p.0 - mi).powi(2)).sum();
    let slope = if sii > 0.0 {
        pts.iter().map(|p| (p.0 - mi) * (p.1 - my)).sum::<f64>() / sii
    } else {
        0.0
    };
    (my - slope * mi, slope)
}

/// The Dahl term's shape per fitted operating point (one declared input, two or more fitted
/// points): coordinate descent over the points on the grid of pairs (δ, V) — the travels of
/// [`DAHL_TRAVELS`] next to the shared one (and it) × (0 and [`DAHL_VELOCITY_FRACTIONS`] of
/// the rms velocity `v_rms`) — by the transfer error,
/// then δ(i) and V(i) by least squares through them, refit and kept if the transfer error
/// falls by [`TERM_MIN_GAIN`] against the shared shape (`j_shared`, NRMSE²). Returns the
/// dependence and the per-record normal equations at each record's δ(i), V(i).
#[allow(clippy::too_many_arguments)]
pub(super) fn travel_by_point(
    v_rms: f64,
    prepared: &[Prepared<'_>],
    library: &[LawTerm],
    expanded: &Expanded,
    structure: &Structure,
    shape: Shape,
    fit_groups: &[usize],
    names: &[String],
    j_shared: f64,
) -> Option<(TravelDependence, ShapeData)> {
    if names.len() != 1
        || fit_groups.len() < 2
        || !structure.terms.iter().any(|t| t.0 == LawTerm::Dahl)
    {
        return None;
    }
    let velocities: Vec<f64> = std::iter::once(0.0)
        .chain(DAHL_VELOCITY_FRACTIONS.iter().map(|f| f * v_rms))
        .collect();
    // Travels within one step of the grid of the shared one (the cost of each pair is a set of
    // normal equations on the full expansion of the forms, for every record).
    let at = DAHL_TRAVELS
        .iter()
        .position(|d| *d == shape.dahl_travel)
        .unwrap_or(0);
    let travels = &DAHL_TRAVELS[at.saturating_sub(1)..(at + 2).min(DAHL_TRAVELS.len())];
    let pairs: Vec<(f64, f64)> = travels
        .iter()
        .flat_map(|d| velocities.iter().map(move |v| (*d, *v)))
        .collect();
    let grid: Vec<ShapeData> = pairs
        .par_iter()
        .map(|(d, vd)| {
            let sh = Shape {
                dahl_travel: *d,
                dahl_velocity: *vd,
                ..shape
            };
            let kin = kinematics(prepared, &sh, true);
            normals(prepared, library, expanded, sh, &kin)
        })
        .collect();
    // The shared shape's pair (the series velocity of the second stage of `choose_shape` is
    // on the same grid of fractions).
    let start = pairs
        .iter()
        .position(|(d, vd)| {
            *d == shape.dahl_travel && (vd - shape.dahl_velocity).abs() <= 1e-12 * v_rms
        })
        .unwrap_or(0);
    let choice = descend((&grid, start, shape), prepared, fit_groups, |data| {
        transfer_error(data, expanded, library, structure)
    })?;
    let pts: Vec<(f64, f64, f64)> = fit_groups
        .iter()
        .zip(&choice)
        .map(|(g, k)| {
            let i = prepared
                .iter()
                .find(|p| p.group == *g)
                .map_or(0.0, |p| p.at[0]);
            (i, pairs[*k].0, pairs[*k].1)
        })
        .collect();
    let (at_zero, slope) = line_through(&pts.iter().map(|p| (p.0, p.1)).collect::<Vec<_>>());
    let (velocity_at_zero, velocity_slope) =
        line_through(&pts.iter().map(|p| (p.0, p.2)).collect::<Vec<_>>());
    let mut dep = TravelDependence {
        input: names[0].clone(),
        unit: String::new(),
        at_zero,
        slope,
        velocity_at_zero,
        velocity_slope,
        per_point: pts,
        nrmse_transfer_shared: j_shared.sqrt(),
        nrmse_transfer: f64::NAN,
        velocity_max: velocities[velocities.len() - 1],
    };
    let dahl: Vec<(f64, f64)> = prepared.iter().map(|p| dep.at(p.at[0])).collect();
    let data = normals_at_travels(prepared, library, expanded, shape, &dahl);
    let j = transfer_error(&data, expanded, library, structure)?;
    dep.nrmse_transfer = j.sqrt();
    (j < (1.0 - TERM_MIN_GAIN) * j_shared).then_some((dep, data))
}

/// Coordinate descent over the fitted points (`fit_groups`): two passes in which each point
/// takes the grid entry (`grid`, normal equations per record at one shape) that gives the
/// lowest transfer `error` (NRMSE²) with the others' choices fixed, all starting at `start`;
/// the mixed data carry the shared `shape`. Returns each point's choice; `None` when no
/// entry gives an error.
fn descend(
    (grid, start, shape): (&[ShapeData], usize, Shape),
    prepared: &[Prepared<'_>],
    fit_groups: &[usize],
    error: impl Fn(&ShapeData) -> Option<f64>,
) -> Option<Vec<usize>> {
    let mut choice: Vec<usize> = vec![start; fit_groups.len()];
    let mixed = |choice: &[usize]| -> ShapeData {
        let pick = |r: usize| {
            let g = fit_groups.iter().position(|g| *g == prepared[r].group);
            &grid[g.map_or(start, |g| choice[g])]
        };
        ShapeData {
            shape,
            a: (0..prepared.len()).map(|r| pick(r).a[r].clone()).collect(),
            b: (0..prepared.len()).map(|r| pick(r).b[r].clone()).collect(),
        }
    };
    for _pass in 0..2 {
        for g in 0..fit_groups.len() {
            // Each pair's transfer error once (a comparator would recompute both sides).
            let (best, _) = (0..grid.len())
                .map(|k| {
                    let mut c = choice.clone();
                    c[g] = k;
                    let j = error(&mixed(&c));
                    (k, j.unwrap_or(f64::INFINITY))
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))?;
            choice[g] = best;
        }
    }
    Some(choice)
}
