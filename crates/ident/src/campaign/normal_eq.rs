//! The linear algebra of a campaign: the regressors, the normal equations per record and
//! segment, the expanded column library and the sign constraints that keep a law admissible.

use super::*;

/// Normal equations of one segment over every column of the expanded library.
#[derive(Clone)]
pub(super) struct Normal {
    pub(super) g: DMatrix<f64>,
    pub(super) b: DVector<f64>,
    pub(super) yy: f64,
    pub(super) ysum: f64,
    pub(super) n: f64,
}

impl Normal {
    pub(super) fn zero(p: usize) -> Self {
        Normal {
            g: DMatrix::zeros(p, p),
            b: DVector::zeros(p),
            yy: 0.0,
            ysum: 0.0,
            n: 0.0,
        }
    }

    pub(super) fn add(&mut self, o: &Normal) {
        self.g += &o.g;
        self.b += &o.b;
        self.yy += o.yy;
        self.ysum += o.ysum;
        self.n += o.n;
    }

    /// Sum of squares about the mean of y (the NRMSE² denominator).
    pub(super) fn var_sum(&self) -> f64 {
        (self.yy - self.ysum * self.ysum / self.n.max(1.0)).max(1e-300)
    }

    /// Least-squares coefficients on columns `cols` (scaled to unit diagonal, tiny ridge),
    /// each term's coefficient held admissible at the operating points of `ex`
    /// ([`Admissible`], [`crate::signlsq`]).
    pub(super) fn solve(&self, cols: &[usize], ex: &Expanded) -> Option<DVector<f64>> {
        let p = cols.len();
        if p == 0 {
            return Some(DVector::zeros(0));
        }
        let d: Vec<f64> = cols
            .iter()
            .map(|&c| 1.0 / self.g[(c, c)].max(1e-300).sqrt())
            .collect();
        let mut g = DMatrix::zeros(p, p);
        let mut b = DVector::zeros(p);
        for (r, &cr) in cols.iter().enumerate() {
            b[r] = self.b[cr] * d[r];
            for (c, &cc) in cols.iter().enumerate() {
                g[(r, c)] = self.g[(cr, cc)] * d[r] * d[c];
            }
            g[(r, r)] += 1e-10;
        }
        let (c, h) = constraints(ex, cols, &d);
        let th = crate::signlsq::solve(&g, &b, &c, &h)?;
        Some(DVector::from_iterator(
            p,
            th.iter().zip(&d).map(|(t, s)| t * s),
        ))
    }

    /// Residual sum of squares of coefficients `th` on columns `cols`.
    pub(super) fn sse(&self, cols: &[usize], th: &DVector<f64>) -> f64 {
        let mut s = self.yy;
        for (r, &cr) in cols.iter().enumerate() {
            s -= 2.0 * th[r] * self.b[cr];
            for (c, &cc) in cols.iter().enumerate() {
                s += th[r] * th[c] * self.g[(cr, cc)];
            }
        }
        s.max(0.0)
    }
}

/// The rows C and offsets h of the admissibility constraints C·θ̃ + h ≥ 0 on the scaled
/// coefficients θ̃ (θ = d·θ̃) of columns `cols`: per bounded term and grid point, the
/// coefficient there, c₀ + Σ c_b·basis_b(i), at least its floor.
pub(super) fn constraints(
    ex: &Expanded,
    cols: &[usize],
    d: &[f64],
) -> (DMatrix<f64>, DVector<f64>) {
    let adm = &ex.admissible;
    let mut terms: Vec<usize> = cols.iter().map(|&c| ex.cols[c].term).collect();
    terms.sort_unstable();
    terms.dedup();
    let (mut rows, mut h) = (Vec::new(), Vec::new());
    for t in terms {
        let Some(floor) = adm.floor.get(t).copied().flatten() else {
            continue;
        };
        for q in &adm.grid {
            rows.extend(cols.iter().zip(d).map(|(&c, s)| {
                let col = ex.cols[c];
                let basis = match col.part {
                    _ if col.term != t => 0.0,
                    None => 1.0,
                    Some((k, slot)) => ex.forms[k][slot / 2].basis(q[k])[slot % 2].unwrap_or(0.0),
                };
                basis * s
            }));
            h.push(-floor);
        }
    }
    (
        DMatrix::from_row_slice(h.len(), cols.len(), &rows),
        DVector::from_vec(h),
    )
}

/// Columns of the expanded library: term × (constant, basis 1, basis 2 per input and form).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Column {
    pub(super) term: usize,
    /// `None`: the constant part; `Some((input, basis))`.
    pub(super) part: Option<(usize, usize)>,
}

/// The expanded library for a set of forms per input (one form set for all terms: each term
/// picks which of its columns it uses).
pub(super) struct Expanded {
    pub(super) cols: Vec<Column>,
    /// Forms per input whose bases the columns carry: the union used below.
    pub(super) forms: Vec<Vec<Form>>,
    /// Where each library term's coefficient must stay admissible (see [`Admissible`]).
    pub(super) admissible: Admissible,
}

/// The sign physics gives the law's coefficients, held at operating points spanning the
/// fitted ones: viscous, yield, quadratic and Dahl forces and pressure-dependent friction
/// dissipate (coefficient ≥ 0), and a passive element's stiffness keeps the total stiffness
/// with the config's load spring ≥ 0 (k + k_load ≥ 0). The constant and the load-pressure
/// area take either sign. Enforced in every least-squares fit of the campaign
/// ([`crate::signlsq`]), so the term selection and the input dependences only ever compare
/// admissible laws.
#[derive(Debug, Clone, Default)]
pub(super) struct Admissible {
    /// Per library term: the lower bound of its coefficient, −h (h ≥ 0), or `None` if free.
    pub(super) floor: Vec<Option<f64>>,
    /// Operating points (one value per input) at which the bound is held: the fitted values
    /// and, with one input, 9 points evenly across their range (a quadratic dependence may
    /// dip between the fitted points).
    pub(super) grid: Vec<Vec<f64>>,
}

impl Admissible {
    pub(super) fn new(library: &[LawTerm], load_stiffness: f64, fitted: &[Vec<f64>]) -> Self {
        let floor = library
            .iter()
            .map(|t| match t {
                LawTerm::Constant | LawTerm::Pressure => None,
                LawTerm::Stiffness => Some(-load_stiffness.max(0.0)),
                _ => Some(0.0),
            })
            .collect();
        let mut grid: Vec<Vec<f64>> = fitted.to_vec();
        if fitted.first().is_some_and(|p| p.len() == 1) {
            let lo = fitted.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min);
            let hi = fitted
                .iter()
                .map(|p| p[0])
                .fold(f64::NEG_INFINITY, f64::max);
            grid.extend((0..9).map(|k| vec![lo + (hi - lo) * k as f64 / 8.0]));
        }
        if grid.is_empty() {
            grid.push(Vec::new());
        }
        Admissible { floor, grid }
    }
}

/// Per shape: normal equations per record for the transfer-fit segment (A), the
/// transfer-predicted segment (B).
pub(super) struct ShapeData {
    pub(super) shape: Shape,
    pub(super) a: Vec<Normal>,
    pub(super) b: Vec<Normal>,
}

pub(super) fn expand(
    library: &[LawTerm],
    forms: &[Vec<Form>],
    admissible: &Admissible,
) -> Expanded {
    let mut cols = Vec::new();
    for ti in 0..library.len() {
        cols.push(Column {
            term: ti,
            part: None,
        });
        for (k, fs) in forms.iter().enumerate() {
            for (fi, f) in fs.iter().enumerate() {
                for b in 0..f.parameters() {
                    cols.push(Column {
                        term: ti,
                        part: Some((k, fi * 2 + b)),
                    });
                }
            }
        }
    }
    Expanded {
        cols,
        forms: forms.to_vec(),
        admissible: admissible.clone(),
    }
}

/// Regressor columns of record `p` at `shape` (each expanded column's series), with its
/// velocity `v` and Dahl state `z` at that shape.
pub(super) fn regressors(
    p: &Prepared<'_>,
    library: &[LawTerm],
    expanded: &Expanded,
    shape: Shape,
    v: &[f64],
    z: &[f64],
) -> Vec<Vec<f64>> {
    let law = shape_law(shape);
    let m = Motion {
        dt: p.rec.dt,
        x: p.x,
        v,
        dp: p.dp.as_deref(),
    };
    let base: Vec<Vec<f64>> = library
        .iter()
        .map(|t| match t {
            LawTerm::Dahl => z.to_vec(),
            _ => term_series(*t, &law, &m).unwrap_or_else(|| vec![0.0; p.x.len()]),
        })
        .collect();
    expanded
        .cols
        .iter()
        .map(|c| match c.part {
            None => base[c.term].clone(),
            Some((k, slot)) => {
                let f = expanded.forms[k][slot / 2];
                base[c.term]
                    .iter()
                    .zip(&p.op[k])
                    .map(|(phi, i)| phi * f.basis(*i)[slot % 2].unwrap_or(0.0))
                    .collect()
            }
        })
        .collect()
}

/// Normal equations ΦᵀΦ, Φᵀy of the regressor columns `cols` on samples `r` (nalgebra's
/// matrix product).
pub(super) fn normal_of(cols: &[Vec<f64>], y: &[f64], r: Range<usize>) -> Normal {
    let p = cols.len();
    let rows = r.len();
    let phi = DMatrix::from_fn(rows, p, |i, j| cols[j][r.start + i]);
    let yv = DVector::from_fn(rows, |i, _| y[r.start + i]);
    let ys = &y[r];
    Normal {
        g: phi.tr_mul(&phi),
        b: phi.tr_mul(&yv),
        yy: ys.iter().map(|v| v * v).sum(),
        ysum: ys.iter().sum(),
        n: rows as f64,
    }
}

pub(super) fn normals(
    prepared: &[Prepared<'_>],
    library: &[LawTerm],
    expanded: &Expanded,
    shape: Shape,
    kin: &Kinematics,
) -> ShapeData {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for (i, p) in prepared.iter().enumerate() {
        let z = kin.z.get(i).map_or(&[][..], Vec::as_slice);
        let cols = regressors(p, library, expanded, shape, &kin.v[i], z);
        let split = p.fit.start + ((p.fit.len() as f64) * TRANSFER_SPLIT).round() as usize;
        a.push(normal_of(&cols, &p.y, p.fit.start..split));
        b.push(normal_of(&cols, &p.y, split..p.fit.end));
    }
    ShapeData { shape, a, b }
}

pub(super) fn sum_normals<'n>(it: impl Iterator<Item = &'n Normal>, p: usize) -> Normal {
    let mut s = Normal::zero(p);
    for n in it {
        s.add(n);
    }
    s
}

/// Columns a structure uses.
pub(super) fn columns_of(st: &Structure, ex: &Expanded, library: &[LawTerm]) -> Vec<usize> {
    let mut out = Vec::new();
    for (term, forms) in &st.terms {
        let ti = library.iter().position(|t| t == term).unwrap_or(usize::MAX);
        for (ci, c) in ex.cols.iter().enumerate() {
            if c.term != ti {
                continue;
            }
            let keep = match c.part {
                None => true,
                Some((k, slot)) => ex.forms[k].get(slot / 2) == Some(&forms[k]),
            };
            if keep {
                out.push(ci);
            }
        }
    }
    out
}
