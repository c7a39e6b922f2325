//! Sign-constrained least squares on normal equations: minimise ½·θᵀGθ − bᵀθ subject to
//! Cθ + h ≥ 0 (h ≥ 0), with G symmetric positive definite. The campaign's law is fitted this way so that
//! its dissipative coefficients (viscous, yield, quadratic, Dahl, and the stiffness of a
//! passive element) keep the sign physics gives them at every fitted operating point
//! (crates/ident/src/campaign/normal_eq.rs), instead of being filtered after an unconstrained fit.
//!
//! Primal active-set method (Nocedal & Wright, *Numerical Optimization*, 2nd ed. 2006,
//! Algorithm 16.3), started at θ = 0, which satisfies every constraint since h ≥ 0. Written here
//! because it is small and exact: the campaign solves thousands of these problems of at most a
//! few dozen unknowns on Gram matrices it already holds, the active-set method returns the exact
//! least-squares solution on the active face (an interior-point solver such as Clarabel or OSQP
//! returns one to a tolerance, so equal candidates would tie differently), and nalgebra, which
//! the crate uses for the rest, has no constrained solver.

use nalgebra::{DMatrix, DVector};

/// Largest number of active-set iterations (each adds or drops one constraint; a problem of
/// p unknowns and m constraints needs about p + m).
const MAX_ITERATIONS: usize = 200;

/// The minimiser of ½·θᵀGθ − bᵀθ subject to `c`·θ + `h` ≥ 0 (`c`: one row per constraint,
/// may have none; `h` ≥ 0, one per row). `None` when an equality-constrained step cannot be
/// solved or the iterations run out (a degenerate problem), or when some `h` < 0.
pub fn solve(
    g: &DMatrix<f64>,
    b: &DVector<f64>,
    c: &DMatrix<f64>,
    h: &DVector<f64>,
) -> Option<DVector<f64>> {
    let p = b.len();
    if h.len() != c.nrows() || h.iter().any(|v| !(*v >= 0.0)) {
        return None;
    }
    let unconstrained = equality_step(g, b, c, &[], &DVector::zeros(p))?.0;
    let tol = 1e-12 * scale(c, &unconstrained);
    if (c * &unconstrained + h).iter().all(|v| *v >= -tol) {
        return Some(unconstrained);
    }
    let mut theta = DVector::zeros(p);
    let mut active: Vec<usize> = Vec::new();
    for _ in 0..MAX_ITERATIONS {
        let (step, lambda) = equality_step(g, b, c, &active, &theta)?;
        let size = step.amax().max(1e-300);
        if size <= 1e-12 * theta.amax().max(1e-300) || step.iter().all(|s| *s == 0.0) {
            // Stationary on the working set: done when every multiplier is ≥ 0, else drop the
            // most negative one.
            match lambda
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(b.1))
                .filter(|(_, l)| **l < 0.0)
            {
                None => return Some(theta),
                Some((i, _)) => {
                    active.remove(i);
                }
            }
            continue;
        }
        // The longest step along `step` that keeps every inactive constraint satisfied.
        let mut alpha = 1.0;
        let mut blocking = None;
        for j in (0..c.nrows()).filter(|j| !active.contains(j)) {
            let row = c.row(j);
            let along = row.dot(&step.transpose());
            if along < 0.0 {
                let to_bound = -(row.dot(&theta.transpose()) + h[j]).max(0.0) / along;
                if to_bound < alpha {
                    alpha = to_bound;
                    blocking = Some(j);
                }
            }
        }
        theta += alpha * &step;
        if let Some(j) = blocking {
            active.push(j);
        }
    }
    None
}

/// Scale of the constraint values at `theta` (for the feasibility tolerance).
fn scale(c: &DMatrix<f64>, theta: &DVector<f64>) -> f64 {
    if c.nrows() == 0 {
        return 1.0;
    }
    c.abs().column_sum().max() * theta.amax() + 1e-300
}

/// The step p from `theta` to the minimiser on the working set (`c`'s rows `active` held as
/// equalities, Cₐ·p = 0) and the multipliers λ of those rows: the KKT system
/// [G Cₐᵀ; Cₐ 0]·[p; −λ] = [b − Gθ; 0], solved by LU and, when the working set's rows are
/// dependent, by SVD.
fn equality_step(
    g: &DMatrix<f64>,
    b: &DVector<f64>,
    c: &DMatrix<f64>,
    active: &[usize],
    theta: &DVector<f64>,
) -> Option<(DVector<f64>, DVector<f64>)> {
    let (p, m) = (b.len(), active.len());
    let mut k = DMatrix::zeros(p + m, p + m);
    k.view_mut((0, 0), (p, p)).copy_from(g);
    for (r, &j) in active.iter().enumerate() {
        for i in 0..p {
            k[(p + r, i)] = c[(j, i)];
            k[(i, p + r)] = c[(j, i)];
        }
    }
    let mut rhs = DVector::zeros(p + m);
    rhs.rows_mut(0, p).copy_from(&(b - g * theta));
    let sol = k
        .clone()
        .lu()
        .solve(&rhs)
        .filter(|s| s.iter().all(|v| v.is_finite()))
        .or_else(|| k.svd(true, true).solve(&rhs, 1e-12).ok())?;
    let step = sol.rows(0, p).into_owned();
    let lambda = -sol.rows(p, m).into_owned();
    Some((step, lambda))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Non-negative least squares of the textbook case (Lawson & Hanson, *Solving Least
    /// Squares Problems*, 1974, ch. 23): A = [[1, 0], [0, 1], [1, 1]], y = [−1, 2, 0]; the
    /// unconstrained solution is (−4/3, 5/3); with θ ≥ 0 it is (0, 1) (minimise
    /// θ₁² + (θ₂ − 2)² + θ₂² over θ₂ ≥ 0 at θ₁ = 0).
    #[test]
    fn nonnegative_least_squares_of_a_small_case() {
        let a = DMatrix::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
        let y = DVector::from_vec(vec![-1.0, 2.0, 0.0]);
        let g = a.transpose() * &a;
        let b = a.transpose() * &y;
        let free = solve(&g, &b, &DMatrix::zeros(0, 2), &DVector::zeros(0)).unwrap();
        assert!((free[0] + 4.0 / 3.0).abs() < 1e-12 && (free[1] - 5.0 / 3.0).abs() < 1e-12);
        let th = solve(&g, &b, &DMatrix::identity(2, 2), &DVector::zeros(2)).unwrap();
        assert!(th[0].abs() < 1e-12, "{th}");
        assert!((th[1] - 1.0).abs() < 1e-12, "{th}");
    }

    /// A coefficient c(i) = c₀ + c₁·i that must stay ≥ 0 at i = 0 and i = 1, fitted to data
    /// that ask for c(0) < 0: the fit puts c(0) on 0 and is the least-squares line through
    /// the origin (c₁ = Σ i·y / Σ i²).
    #[test]
    fn a_line_kept_non_negative_over_a_range() {
        let i = [0.0, 0.25, 0.5, 0.75, 1.0];
        let y = [-1.0, 0.0, 1.0, 2.0, 3.0];
        let a = DMatrix::from_fn(5, 2, |r, c| if c == 0 { 1.0 } else { i[r] });
        let yv = DVector::from_row_slice(&y);
        let g = a.transpose() * &a;
        let b = a.transpose() * &yv;
        let c = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 1.0, 1.0]);
        let th = solve(&g, &b, &c, &DVector::zeros(2)).unwrap();
        let slope: f64 = i.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>()
            / i.iter().map(|a| a * a).sum::<f64>();
        assert!(th[0].abs() < 1e-12, "{th}");
        assert!((th[1] - slope).abs() < 1e-12, "{th} vs {slope}");
    }

    /// A bound θ ≥ −1 (h = 1) on a one-parameter fit whose free minimiser is −3: θ = −1.
    #[test]
    fn a_shifted_bound_is_met_on_its_edge() {
        let g = DMatrix::from_element(1, 1, 2.0);
        let b = DVector::from_element(1, -6.0);
        let th = solve(
            &g,
            &b,
            &DMatrix::identity(1, 1),
            &DVector::from_element(1, 1.0),
        )
        .unwrap();
        assert!((th[0] + 1.0).abs() < 1e-12, "{th}");
        assert!(solve(
            &g,
            &b,
            &DMatrix::identity(1, 1),
            &DVector::from_element(1, -1.0)
        )
        .is_none());
    }

    /// When the unconstrained minimiser is feasible it is returned unchanged.
    #[test]
    fn a_feasible_minimiser_is_untouched() {
        let g = DMatrix::from_row_slice(2, 2, &[2.0, 0.5, 0.5, 1.0]);
        let b = DVector::from_vec(vec![1.0, 1.0]);
        let th = solve(&g, &b, &DMatrix::identity(2, 2), &DVector::zeros(2)).unwrap();
        let exact = g.clone().lu().solve(&b).unwrap();
        assert!((th - exact).amax() < 1e-14);
    }
}
