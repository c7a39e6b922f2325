//! `integration.method = "linear_exact"`: chambers, piston (and load mass) as one linear
//! system, discretised exactly over a substep (zero-order hold on its inputs), as the spool
//! already is ([`crate::effects::valve_dynamics::SpoolModel`]).
//!
//! States z = (p_A, p_B, x, v, x_L, v_L) (Pa, Pa, m, m/s, m, m/s; the last two only with a
//! flexible mount), inputs w = (Q_A, Q_B, F_ext, 1) (m³/s, m³/s, N, -):
//!
//! - ṗ_A = c_A·(Q_A − A_A·v − k_in·(p_A − p_B) − k_ext·p_A),  c_A = β(p_A)/V_A(x) (003 eq. 1, 7–8);
//! - ṗ_B = c_B·(Q_B + A_B·v + k_in·(p_A − p_B) − k_ext·p_B);
//! - ẋ = v,  m·v̇ = A_A·p_A − A_B·p_B − K_L·(x − x_c) − d·v − F_mount − F_ext (003 eq. 3, 004 eq. 9–10);
//! - with a mount: ẋ_L = v_L, m_L·v̇_L = k_m·(x − x_L) + d_m·(v − v_L) − F_ext (003 eq. 1).
//!
//! Over a substep h with c_A, c_B frozen and w held, z(h) = Φ·z(0) + Γ·w with Φ = e^(Ah),
//! Γ = ∫₀ʰ e^(Aτ)dτ·B, taken together from the exponential of the augmented matrix
//! [[A h, B h, 0], [0, 0, 0], [I h, 0, 0]] (Van Loan 1978), whose last block row also gives
//! the step means of the pressures (∫₀ʰ z dτ / h), used to evaluate the valve flow at the
//! pressures it actually sees during the step (the 3.9 kHz load-cell mode of Sahu 2022 swings
//! the chamber pressures within one 200 µs step). The hydraulic spring, the load-cell spring, the
//! leakage and the mount are then exact for any h: no ω·h limit. What is not exact is what
//! enters through w: the valve flow (evaluated at the mid-step spool position, with its own
//! pressure derivative taken trapezoidally, see [`crate::model`]) and c_A, c_B, which are
//! re-discretised whenever either has drifted by more than [`REDISCRETISE_TOL`] (relative)
//! from the value Φ was computed with — on rigs whose volumes hardly change (Sahu 2022: the
//! piston moves ≈ 2 µm) that is never after start-up.
//!
//! Hand-written because no maintained Rust crate offers a ZOH discretisation; the matrix
//! exponential itself is nalgebra's (Padé with scaling and squaring), on a balanced matrix
//! (states span Pa to µm) of fixed size, so a re-discretisation does not allocate.

use nalgebra::SMatrix;

/// Relative drift of c_A = β/V_A or c_B that triggers a new discretisation (-). The
/// hydraulic stiffness is then at most this fraction off, its frequency half of it.
pub const REDISCRETISE_TOL: f64 = 1e-3;

const NS: usize = 6;
const NI: usize = 4;
/// Augmented state (z, w, ∫z): its exponential gives Φ, Γ and their integrals over the step.
const NA: usize = NS + NI + NS;
type Aug = SMatrix<f64, NA, NA>;

/// The constant coefficients of the linear system.
#[derive(Debug, Clone, Copy)]
pub struct LinearCoefficients {
    /// Piston area A (m²).
    pub a_a: f64,
    /// Annulus area B (m²).
    pub a_b: f64,
    /// Cross-piston leakage (m³/(s·Pa)).
    pub k_in: f64,
    /// Leakage to tank per chamber (m³/(s·Pa)).
    pub k_ext: f64,
    /// Piston mass (kg).
    pub mass: f64,
    /// Viscous damping on the piston (N·s/m).
    pub damping: f64,
    /// Spring to ground (N/m).
    pub k_load: f64,
    /// Relaxed position of the spring to ground (m).
    pub x_contact: f64,
    /// Flexible mount: load mass (kg), stiffness (N/m), damping (N·s/m).
    pub mount: Option<(f64, f64, f64)>,
}

/// Exact one-substep transition of the linear part.
#[derive(Debug, Clone)]
pub struct LinearExact {
    k: LinearCoefficients,
    h: f64,
    /// Number of states in use (4, or 6 with a mount).
    n: usize,
    phi: [[f64; NS]; NS],
    gam: [[f64; NI]; NS],
    /// Rows p_A, p_B of (1/h)∫₀ʰ Φ(τ)dτ: the step mean of the pressures from z(0).
    psi: [[f64; NS]; 2],
    /// Rows p_A, p_B of (1/h)∫₀ʰ Γ(τ)dτ: the step mean of the pressures from w.
    lam: [[f64; NI]; 2],
    /// c_A (Pa/m³) Φ was computed with.
    pub ca: f64,
    /// c_B (Pa/m³) Φ was computed with.
    pub cb: f64,
    /// Discretisations so far (including the first).
    pub count: u64,
}

impl LinearExact {
    /// Discretise for substep `h` (s) at c_A = `ca`, c_B = `cb` (Pa/m³); `None` when A·h is
    /// not representable ([`expm_checked`]).
    pub fn new(k: LinearCoefficients, h: f64, ca: f64, cb: f64) -> Option<Self> {
        let mut s = Self {
            n: if k.mount.is_some() { 6 } else { 4 },
            k,
            h,
            phi: [[0.0; NS]; NS],
            gam: [[0.0; NI]; NS],
            psi: [[0.0; NS]; 2],
            lam: [[0.0; NI]; 2],
            ca,
            cb,
            count: 0,
        };
        s.discretise(ca, cb).then_some(s)
    }

    /// Continuous-time A (6×6) and B (6×4) at the given c_A, c_B.
    pub fn continuous(&self, ca: f64, cb: f64) -> (SMatrix<f64, NS, NS>, SMatrix<f64, NS, NI>) {
        let k = &self.k;
        let mut a = SMatrix::<f64, NS, NS>::zeros();
        let mut b = SMatrix::<f64, NS, NI>::zeros();
        let m = k.mass;
        a[(0, 0)] = -ca * (k.k_in + k.k_ext);
        a[(0, 1)] = ca * k.k_in;
        a[(0, 3)] = -ca * k.a_a;
        b[(0, 0)] = ca;
        a[(1, 0)] = cb * k.k_in;
        a[(1, 1)] = -cb * (k.k_in + k.k_ext);
        a[(1, 3)] = cb * k.a_b;
        b[(1, 1)] = cb;
        a[(2, 3)] = 1.0;
        a[(3, 0)] = k.a_a / m;
        a[(3, 1)] = -k.a_b / m;
        a[(3, 2)] = -k.k_load / m;
        a[(3, 3)] = -k.damping / m;
        b[(3, 3)] = k.k_load * k.x_contact / m;
        match k.mount {
            None => b[(3, 2)] = -1.0 / m,
            Some((ml, km, dm)) => {
                a[(3, 2)] -= km / m;
                a[(3, 4)] = km / m;
                a[(3, 3)] -= dm / m;
                a[(3, 5)] = dm / m;
                a[(4, 5)] = 1.0;
                a[(5, 2)] = km / ml;
                a[(5, 4)] = -km / ml;
                a[(5, 3)] = dm / ml;
                a[(5, 5)] = -dm / ml;
                b[(5, 2)] = -1.0 / ml;
            }
        }
        (a, b)
    }

    /// Recompute Φ and Γ at c_A = `ca`, c_B = `cb`. Does not allocate. Returns `false` (and
    /// keeps the previous Φ, Γ) when A·h is not representable ([`expm_checked`]).
    pub fn discretise(&mut self, ca: f64, cb: f64) -> bool {
        let (a, b) = self.continuous(ca, cb);
        let mut m = Aug::zeros();
        m.fixed_view_mut::<NS, NS>(0, 0).copy_from(&(a * self.h));
        m.fixed_view_mut::<NS, NI>(0, NS).copy_from(&(b * self.h));
        for i in 0..NS {
            m[(NS + NI + i, i)] = self.h;
        }
        // Balance (Parlett–Reinsch, powers of 2): M' = D⁻¹ M D, e^M = D e^(M') D⁻¹.
        let mut d = [1.0f64; NA];
        balancing_scales(&mut d, |i, j| m[(i, j)], 64);
        let mut mb = m;
        for i in 0..NA {
            for j in 0..NA {
                mb[(i, j)] = m[(i, j)] * d[j] / d[i];
            }
        }
        let Some(e) = expm_checked(&mb) else {
            return false;
        };
        for i in 0..NS {
            for j in 0..NS {
                self.phi[i][j] = e[(i, j)] * d[i] / d[j];
            }
            for j in 0..NI {
                self.gam[i][j] = e[(i, NS + j)] * d[i] / d[NS + j];
            }
        }
        // The ∫ rows hold ∫₀ʰ z dτ (τ = h·s in the augmented system): divide by h for the mean.
        let r0 = NS + NI;
        for i in 0..2 {
            for j in 0..NS {
                self.psi[i][j] = e[(r0 + i, j)] * d[r0 + i] / d[j] / self.h;
            }
            for j in 0..NI {
                self.lam[i][j] = e[(r0 + i, NS + j)] * d[r0 + i] / d[NS + j] / self.h;
            }
        }
        self.ca = ca;
        self.cb = cb;
        self.count += 1;
        true
    }

    /// Whether c_A, c_B have drifted beyond [`REDISCRETISE_TOL`] from Φ's values.
    #[inline]
    pub fn stale(&self, ca: f64, cb: f64) -> bool {
        (ca - self.ca).abs() > REDISCRETISE_TOL * self.ca
            || (cb - self.cb).abs() > REDISCRETISE_TOL * self.cb
    }

    /// Mean of (p_A, p_B) over the step from z(0) = `z` with the inputs `w` held (Pa), and
    /// ∂(mean p_A)/∂Q_A, ∂(mean p_B)/∂Q_B (Pa·s/m³).
    #[inline]
    pub fn mean_pressures(&self, z: &[f64; NS], w: &[f64; NI]) -> ([f64; 2], [f64; 2]) {
        let out = if self.n == 4 {
            self.mean_n::<4>(z, w)
        } else {
            self.mean_n::<NS>(z, w)
        };
        (out, [self.lam[0][0], self.lam[1][1]])
    }

    #[inline(always)]
    fn mean_n<const N: usize>(&self, z: &[f64; NS], w: &[f64; NI]) -> [f64; 2] {
        let mut out = [0.0; 2];
        for (i, o) in out.iter_mut().enumerate() {
            let g = &self.lam[i];
            let mut acc = g[0] * w[0] + g[1] * w[1] + g[2] * w[2] + g[3] * w[3];
            for (psi, zj) in self.psi[i].iter().zip(z).take(N) {
                acc += psi * zj;
            }
            *o = acc;
        }
        out
    }

    /// z ← Φ·z + Γ·w.
    #[inline]
    pub fn advance(&self, z: &mut [f64; NS], w: &[f64; NI]) {
        if self.n == 4 {
            self.advance_n::<4>(z, w)
        } else {
            self.advance_n::<NS>(z, w)
        }
    }

    #[inline(always)]
    fn advance_n<const N: usize>(&self, z: &mut [f64; NS], w: &[f64; NI]) {
        let mut out = [0.0; N];
        for (i, o) in out.iter_mut().enumerate() {
            let row = &self.phi[i];
            let g = &self.gam[i];
            let mut acc = g[0] * w[0] + g[1] * w[1] + g[2] * w[2] + g[3] * w[3];
            for j in 0..N {
                acc += row[j] * z[j];
            }
            *o = acc;
        }
        z[..N].copy_from_slice(&out);
    }
}

/// Largest 1-norm of `M` (= A·h, after balancing) whose exponential the plant computes. Far
/// above any physical substep (ω·h ≤ 10⁶ means a mode decays by e^(−10⁶) per substep) and far
/// below where nalgebra's scaling-and-squaring breaks: its Padé-order selection takes
/// ‖Mᵏ‖^(1/k) up to k = 10, which overflows to inf for ‖M‖ ≳ 10³⁰ and then asks for 2⁶⁴
/// squarings (a hang, found by the config fuzzer with `damping_ratio = 1.6e53`).
pub const EXPM_MAX_NORM: f64 = 1.0e12;

/// e^M, or `None` when an entry of `M` is not finite or ‖M‖₁ > [`EXPM_MAX_NORM`].
pub fn expm_checked<const N: usize>(m: &SMatrix<f64, N, N>) -> Option<SMatrix<f64, N, N>>
where
    nalgebra::Const<N>: nalgebra::DimMin<nalgebra::Const<N>, Output = nalgebra::Const<N>>,
{
    let mut norm: f64 = 0.0;
    for j in 0..N {
        let mut col = 0.0;
        for i in 0..N {
            if !m[(i, j)].is_finite() {
                return None;
            }
            col += m[(i, j)].abs();
        }
        norm = norm.max(col);
    }
    (norm <= EXPM_MAX_NORM).then(|| m.exp())
}

/// Parlett–Reinsch balancing: powers of 2 `d` (written into `d`, length n) such that every
/// row and column of `D⁻¹ A D` has comparable off-diagonal norm, where `entry(i, j)` is
/// `A[i][j]`. At most `max_sweeps` sweeps; stops when no scale changes. Powers of 2 make the
/// scaling exact in floating point. No allocation (used when the plant re-discretises in
/// the cycle). Source: Parlett & Reinsch, "Balancing a matrix for calculation of eigenvalues
/// and eigenvectors", Numer. Math. 13 (1969).
pub fn balancing_scales(d: &mut [f64], entry: impl Fn(usize, usize) -> f64, max_sweeps: usize) {
    let n = d.len();
    d.fill(1.0);
    for _ in 0..max_sweeps {
        let mut done = true;
        for i in 0..n {
            let (mut c, mut r) = (0.0f64, 0.0f64);
            for j in 0..n {
                if j != i {
                    c += (entry(j, i) * d[i] / d[j]).abs();
                    r += (entry(i, j) * d[j] / d[i]).abs();
                }
            }
            // A zero row/column needs no scaling; a non-finite one cannot be balanced (and
            // would never leave the halving loops below: inf / 2 = inf).
            if c == 0.0 || r == 0.0 || !(c + r).is_finite() {
                continue;
            }
            let mut f = 1.0;
            let s = c + r;
            let (mut cc, mut rr) = (c, r);
            while cc < rr / 2.0 {
                cc *= 2.0;
                rr /= 2.0;
                f *= 2.0;
            }
            while cc >= rr * 2.0 {
                cc /= 2.0;
                rr *= 2.0;
                f /= 2.0;
            }
            if (cc + rr) < 0.95 * s {
                d[i] *= f;
                done = false;
            }
        }
        if done {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::params::PlantParams;
    use crate::Plant;

    /// Blocked cylinder (closed zero-lapped valve, Q = 0) with a spring to ground: a pressure
    /// step ΔP in chamber A makes the piston a damped mass–spring with
    /// k = β·A²·(1/V_A + 1/V_B) + K_L (003 eq. 15), ω₀ = √(k/m), ζ = d/(2·m·ω₀):
    /// x(t) − x₀ = (A·ΔP/k)·(1 − e^(−ζω₀t)·(cos ω_d t + ζ/√(1−ζ²)·sin ω_d t)). With ω₀·h ≈ 1.2
    /// (one substep per 1 ms period) the exact discretisation must still follow it to round-off.
    #[test]
    fn linear_exact_matches_the_damped_chamber_mass_closed_form() {
        let (beta, a, v0, m, d, kl, p0, dp) =
            (1.8e9, 1.96e-3, 1.0e-4, 100.0, 2.0e4, 5.0e7, 10.0e6, 1.0e4);
        let text = format!(
            r#"
[fluid]
density = 900.0
bulk_modulus = {beta}
cavitation_pressure = -1.0e9
[supply]
pressure = 24.0e6
[valve]
command_full_scale = 10.0
flow_form = "kq"
rated_flow = 5.8333e-4
rated_pressure_drop = 1.0e6
[cylinder]
area_a = {a}
area_b = {a}
dead_volume_a = {v0}
dead_volume_b = {v0}
stroke = 1.0
initial_position = 0.0
initial_pressure_a = {pa}
initial_pressure_b = {p0}
[mechanics]
mass = {m}
damping = {d}
load_stiffness = {kl}
end_stops = false
[integration]
method = "linear_exact"
substeps = 1
"#,
            pa = p0 + dp
        );
        let params: PlantParams = toml::from_str(&text).expect("params");
        let dt = 1e-3;
        let mut plant = Plant::configure(&params, dt).expect("plant");
        // Chamber volumes at x = 0 are the dead volumes (V_A = V₀ + A·x, V_B = V₀ + A·(1 − x)).
        let (va, vb) = plant.volumes(0.0);
        let k = beta * a * a * (1.0 / va + 1.0 / vb) + kl;
        let w0 = (k / m).sqrt();
        assert!(w0 * dt > 1.0, "the test needs ω₀·h > 1, has {}", w0 * dt);
        let zeta = d / (2.0 * m * w0);
        let wd = w0 * (1.0 - zeta * zeta).sqrt();
        // Net static force at t = 0: A·(p_A − p_B) = A·ΔP against the spring relaxed at x = 0.
        let xs = a * dp / k;
        let mut worst: f64 = 0.0;
        for n in 1..=200 {
            plant.step(0.0).expect("step");
            let t = n as f64 * dt;
            let x = xs
                * (1.0
                    - (-zeta * w0 * t).exp()
                        * ((wd * t).cos() + zeta / (1.0 - zeta * zeta).sqrt() * (wd * t).sin()));
            worst = worst.max((plant.state().x - x).abs());
        }
        assert_eq!(
            plant.discretisations(),
            1,
            "volumes drifted: a re-discretisation"
        );
        // Round-off of a 6×6 transition applied 200 times to a 1e-7 m motion at 1e7 Pa.
        assert!(
            worst <= 1e-6 * xs,
            "max |x − closed form| = {worst:e} m of {xs:e} m"
        );
    }
}
