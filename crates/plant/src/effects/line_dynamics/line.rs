//! Lumped R-L-C line between a valve port and a chamber (002 eq. 9–17).
//!
//! Variant `hose` (a compliant hose): the segment capacitance uses the effective bulk modulus
//! 1/β_eff = 1/β + `wall_compliance` (wall and oil compliances in series; thin wall
//! D/(t·E), Merritt 1967, "Hydraulic Control Systems", eq. 2-46) and each segment's resistance
//! gets `resistance`/N (hose ends and fittings, laminar) on top of Hagen–Poiseuille's.
//!
//! N segments, each a capacitance C = A·ℓ/β at its upstream node, an inductance
//! L = ρ·ℓ/A and a laminar resistance R = 128·μ·ℓ/(π·d⁴) (Hagen–Poiseuille) in series to the
//! next node; the last segment discharges into the chamber. Node 0 (the valve port) also
//! holds the optional lumped `port_volume` (capacitance V_port/β₀).
//!
//! # Two integrations of the segment chain (`integration.line_method`)
//!
//! - `symplectic` ([`Line::advance_interior_nodes`], [`Line::advance_flows`]): nodes from the
//!   old flows, flows from the new pressures with R implicit. Stable for ω·h < 2 and without
//!   amplitude error, but the chain's highest mode 2/√(LC) (the lumping's numerical Nyquist
//!   mode: 1.58·10⁵ rad/s for 001's 18 mm segments) enters the ω·h ≤ `max_omega_h` rule, so a
//!   short stiff line sets the substep (127 per 200 µs on Sirohi 2003).
//! - `implicit` ([`Line::advance_implicit`]): the whole chain — valve-side node, segment
//!   flows and the chamber as the end node — advanced by the trapezoidal rule (θ = ½,
//!   Crank–Nicolson) as one symmetric tridiagonal system per substep, solved by the Thomas
//!   algorithm in O(N) on preallocated buffers. The segment flows are eliminated per segment
//!   (each is affine in its two node pressures, the unsteady-friction states folded into the
//!   effective inductance as below), leaving N + 1 node pressures. Unconditionally stable,
//!   conserves the stored energy Σ C·p²/2 + Σ L·q²/2 of the frictionless chain exactly, and a
//!   mode ω is rotated per substep by 2·atan(ω·h/2) instead of ω·h (phase error ≈ (ω·h)²/12):
//!   no line mode bounds the step, so the substep rule only has to resolve the line's
//!   physical wave modes ([`Line::omega_wave`]) and the chambers'. The valve flow at node 0
//!   and the chamber's own leakage are linearised in their node pressure and taken
//!   implicitly (backward Euler in that linear term, as the exponential-Euler node update
//!   does), so the stiff flow–pressure terms stay monotone.
//!
//! Which one to use, by measurement (BENCHMARKS.md, "Short stiff lines", Sirohi 2003's 16
//! segments of 18 mm): at equal substeps both are about as accurate — the first-order
//! chamber–piston and valve-node coupling, not the line, sets the error — and the implicit
//! solve costs about twice as much per substep. So the Sirohi 2003 configs ship `symplectic` with
//! `integration.max_omega_h_line = 1.5`: the segment modes held to a stability margin
//! (ω·h ≤ 1.5 < 2; they are the lumping's numerical modes), the wave and chamber modes to the
//! accuracy rule: 22 substeps per 200 µs instead of 127. `implicit` pays off below ≈ 16
//! substeps (where the symplectic chain is unstable) and for finely segmented lines, whose
//! segment mode grows with the segment count while its rule does not.
//!
//! # Unsteady (frequency-dependent) laminar friction
//!
//! With `friction = "unsteady"` the wall shear follows Zielke (1968, "Frequency-dependent
//! friction in transient pipe flow", J. Basic Eng. 90:109–115): τ_w = 4μV/r + (2μ/r)·∫₀ᵗ W(t−u)·∂V/∂t(u) du with the weighting function W of the
//! dimensionless time τ = ν·t/r². Over a segment of length ℓ the wall shear costs the pressure
//! (2ℓ/r)·τ_w, i.e.
//!
//! L·dq/dt = p_j − p_{j+1} − R·q − (R/2)·Σᵢ yᵢ,   dyᵢ/dt = −aᵢ·yᵢ + mᵢ·dq/dt,
//!
//! with W(τ) ≈ Σᵢ mᵢ·e^(−nᵢτ), aᵢ = nᵢ·ν/r² (1/s) and the convolution states yᵢ (m³/s),
//! the method-of-lines form of Trikha (1975, "An efficient method for simulating
//! frequency-dependent friction in transient liquid flow", J. Fluids Eng. 97:97–105). Its series
//! impedance is Z(s) = L·s + R + (R/2)·Σᵢ mᵢ·s/(s + aᵢ).
//!
//! Zielke's W is exactly W(τ) = Σₖ exp(−λₖτ), λₖ = j²₂,ₖ the squared zeros of J₂ (his
//! τ > 0.02 form lists the first five: 26.3744, 70.8493, 135.0198, 218.9216,
//! 322.5544); its Laplace transform Σₖ 1/(ŝ + λₖ) reproduces the Bessel-function impedance
//! Z = (ρs/A)·I₀(√ŝ)/I₂(√ŝ), ŝ = s·r²/ν (001 eq. 6–8 with the exact B_r). The `unsteady`
//! model keeps modes 1–2 exact and lumps modes 3–4, 5–8, …, 65–128 into one term each,
//! with m = the number of modes (same high-frequency weight) and n such that m/n = Σ 1/λₖ
//! (same low-frequency inertance); modes above 128 (λ > 1.6·10⁵) act as a pure inertance
//! 4L·Σ_{k>128} 1/λₖ added to L, so the low-frequency limit is exact (inertance 4L/3,
//! Σₖ 1/λₖ = 1/12). λₖ for k > 5 come from McMahon's expansion (error < 1e-9).
//! `unsteady_trikha` uses Trikha's three published terms instead. Accuracy against the exact
//! impedance (tests/rust/unsteady_line.rs): `unsteady` within 0.16 % for ω·r²/ν ≤ 3·10⁴
//! (0.11 % at ω/ω_v ≈ 100, 001's 1.75 mm tube at 2 cSt and 350 Hz), Trikha within ≈ 2.4 %.
//!
//! Integration over a substep h: dq/dt is taken constant, Δq/h, so yᵢ advances exactly,
//! yᵢ' = e^(−aᵢh)·yᵢ + mᵢ·gᵢ·Δq with gᵢ = (1 − e^(−aᵢh))/(aᵢh), and the momentum balance is
//! implicit in q and y: Δq·(L + hR + hR·Σmᵢgᵢ/2) = h·(Δp − R·q − (R/2)·Σ e^(−aᵢh)·yᵢ).
//! Fast terms (aᵢh ≫ 1) act as added inertance, slow ones as added resistance; no term
//! limits the step (stiff-safe, like the plant's exponential Euler).

use super::{LineDynamics, LineFriction};
/// The end node of [`Line::advance_implicit`] (crates/plant/src/effects/component.rs).
pub use crate::effects::component::EndNode;

/// Number of convolution terms of the `unsteady` model.
pub const UNSTEADY_TERMS: usize = 8;

/// Zielke's (1968) first five exponents of W (his τ > 0.02 form), the squared zeros of J₂.
const ZIELKE_N: [f64; 5] = [26.3744, 70.8493, 135.0198, 218.9216, 322.5544];

/// k-th zero of J₂ (k ≥ 1) by McMahon's asymptotic expansion (Abramowitz & Stegun 9.5.12).
fn j2_zero(k: usize) -> f64 {
    let mu = 16.0; // 4ν², ν = 2
    let b = (k as f64 + 0.75) * std::f64::consts::PI;
    let e = 8.0 * b;
    b - (mu - 1.0) / e
        - 4.0 * (mu - 1.0) * (7.0 * mu - 31.0) / (3.0 * e.powi(3))
        - 32.0 * (mu - 1.0) * (83.0 * mu * mu - 982.0 * mu + 3779.0) / (15.0 * e.powi(5))
}

/// λₖ = j²₂,ₖ, Zielke's tabulated values for k ≤ 5.
fn zielke_lambda(k: usize) -> f64 {
    if k <= ZIELKE_N.len() {
        ZIELKE_N[k - 1]
    } else {
        j2_zero(k).powi(2)
    }
}

/// Weighting-function terms (mᵢ, nᵢ) in dimensionless time, W(τ) ≈ Σ mᵢ e^(−nᵢτ), and the
/// residual Σ 1/λₖ of the modes left out (added to the inertance as 4L·residual).
pub fn weighting_terms(model: LineFriction) -> (Vec<f64>, Vec<f64>, f64) {
    match model {
        LineFriction::Steady => (Vec::new(), Vec::new(), 0.0),
        LineFriction::UnsteadyTrikha => (vec![40.0, 8.1, 1.0], vec![8000.0, 200.0, 26.4], 0.0),
        LineFriction::Unsteady => {
            let (mut m, mut n) = (Vec::new(), Vec::new());
            let mut captured = 0.0;
            for k in 1..=2 {
                m.push(1.0);
                n.push(zielke_lambda(k));
                captured += 1.0 / zielke_lambda(k);
            }
            let mut first = 3;
            while m.len() < UNSTEADY_TERMS {
                let count = first - 1; // modes first ..= 2·(first − 1)
                let s1: f64 = (first..first + count).map(|k| 1.0 / zielke_lambda(k)).sum();
                m.push(count as f64);
                n.push(count as f64 / s1);
                captured += s1;
                first += count;
            }
            // Σₖ 1/j²₂,ₖ = 1/(4·(2 + 1)) = 1/12 (Rayleigh sum).
            (m, n, (1.0 / 12.0 - captured).max(0.0))
        }
    }
}

/// State and constants of one line.
#[derive(Debug, Clone)]
pub struct Line {
    /// Node pressures (Pa), node 0 at the valve.
    pub p: Vec<f64>,
    /// Segment flows (m³/s), segment j from node j to node j+1 (last: into the chamber).
    pub q: Vec<f64>,
    /// Unsteady-friction convolution states yᵢ (m³/s), segment-major: `y[j·terms + i]`.
    pub y: Vec<f64>,
    /// Node capacitance (m³/Pa).
    pub c: f64,
    /// Capacitance of the valve-side node 0 (m³/Pa): `c` plus the port volume's V_port/β₀.
    pub c0: f64,
    /// Segment inductance (kg/m⁴), incl. the inertance of unmodelled fast friction modes.
    pub l: f64,
    /// Segment resistance (Pa·s/m³).
    pub r: f64,
    /// Weights mᵢ (-) of the convolution terms.
    m: Vec<f64>,
    /// Decay rates aᵢ = nᵢ·ν/r² (1/s).
    a: Vec<f64>,
    /// Per-substep decay e^(−aᵢh) (-).
    decay: Vec<f64>,
    /// Per-substep gain mᵢ·gᵢ (-).
    gain: Vec<f64>,
    /// Σ mᵢ·gᵢ (-).
    gain_sum: f64,
    /// [`Line::advance_implicit`] (allocated once, factors set by [`Line::prepare`]): segment
    /// gain g = h/(L + θ·h·R + h·(R/2)·Σmᵢgᵢ) (m⁴·s/kg) and coupling h·k = h·g·θ² (m³/Pa).
    imp_g: f64,
    imp_hk: f64,
    /// LU factors of the interior nodes' constant tridiagonal block T (nodes 1..N−1):
    /// reciprocal pivots (Pa/m³) and super-diagonal multipliers (-).
    inv_pivot: Vec<f64>,
    upper: Vec<f64>,
    /// T⁻¹·e_first, T⁻¹·e_last (Pa/m³): the interior's response to the two end nodes.
    resp_first: Vec<f64>,
    resp_last: Vec<f64>,
    /// Per segment the flow at zero pressure change α (m³/s) and its θ-mean β (m³/s).
    alpha: Vec<f64>,
    beta: Vec<f64>,
    /// New node pressures 0..N (Pa), N = the end node.
    x: Vec<f64>,
}

/// Trapezoidal weight of [`Line::advance_implicit`] (-): ½, Crank–Nicolson.
const THETA: f64 = 0.5;

impl Line {
    /// Build a line filled at pressure `p0` (Pa) in a fluid of density `density` (kg/m³),
    /// kinematic viscosity `nu` (m²/s) and bulk modulus `beta0` (Pa).
    pub fn with_fluid(cfg: &LineDynamics, density: f64, nu: f64, beta0: f64, p0: f64) -> Self {
        let n = cfg.segments.max(1) as usize;
        let seg = cfg.length / n as f64;
        let area = std::f64::consts::PI * cfg.diameter * cfg.diameter / 4.0;
        let mut beta = cfg.bulk_modulus.unwrap_or(beta0);
        // Variant `hose`: the wall's compliance in series with the oil's (Merritt 1967
        // eq. 2-46), the fittings' resistance spread evenly over the segments.
        let hose = cfg.variant == super::LineVariant::Hose;
        let r_fit = if hose {
            beta = 1.0 / (1.0 / beta + cfg.wall_compliance.max(0.0));
            cfg.resistance.max(0.0) / n as f64
        } else {
            0.0
        };
        let mu = density * nu;
        let c = area * seg / beta;
        let (m, nn, residual) = weighting_terms(cfg.friction);
        let radius = 0.5 * cfg.diameter;
        let a: Vec<f64> = nn.iter().map(|x| x * nu / (radius * radius)).collect();
        let terms = m.len();
        let mut line = Self {
            p: vec![p0; n],
            q: vec![0.0; n],
            y: vec![0.0; n * terms],
            c,
            c0: c + cfg.port_volume.max(0.0) / beta0,
            l: density * seg / area * (1.0 + 4.0 * residual),
            r: 128.0 * mu * seg / (std::f64::consts::PI * cfg.diameter.powi(4)) + r_fit,
            decay: vec![1.0; terms],
            gain: m.clone(),
            gain_sum: m.iter().sum(),
            m,
            a,
            imp_g: 0.0,
            imp_hk: 0.0,
            inv_pivot: vec![0.0; n - 1],
            upper: vec![0.0; n - 1],
            resp_first: vec![0.0; n - 1],
            resp_last: vec![0.0; n - 1],
            alpha: vec![0.0; n],
            beta: vec![0.0; n],
            x: vec![0.0; n + 1],
        };
        line.prepare(0.0);
        line
    }

    /// Convolution terms per segment (0 for steady friction).
    pub fn terms(&self) -> usize {
        self.m.len()
    }

    /// At rest at pressure `p0` (Pa): every node at `p0`, no segment flow, no convolution
    /// state. No allocation.
    pub fn fill(&mut self, p0: f64) {
        self.p.iter_mut().for_each(|p| *p = p0);
        self.q.iter_mut().for_each(|q| *q = 0.0);
        self.y.iter_mut().for_each(|y| *y = 0.0);
    }

    /// Precompute the exact per-substep factors of the convolution states for substep `h`
    /// (s). Called at configure time, once the substep is known.
    pub fn prepare(&mut self, h: f64) {
        for i in 0..self.m.len() {
            let z = self.a[i] * h;
            self.decay[i] = (-z).exp();
            let g = if z < 1e-8 {
                1.0 - 0.5 * z
            } else {
                -(-z).exp_m1() / z
            };
            self.gain[i] = self.m[i] * g;
        }
        self.gain_sum = self.gain.iter().sum();
        // Implicit chain: factor the interior block T once per h (no allocation).
        self.imp_g = h / (self.l + THETA * h * self.r + h * 0.5 * self.r * self.gain_sum);
        self.imp_hk = h * self.imp_g * THETA * THETA;
        let off = -self.imp_hk;
        let diag = self.c + 2.0 * self.imp_hk;
        let mut up = 0.0;
        for (ip, u) in self.inv_pivot.iter_mut().zip(self.upper.iter_mut()) {
            let pivot = diag - off * up;
            *ip = 1.0 / pivot;
            up = off / pivot;
            *u = up;
        }
        let m = self.resp_first.len();
        if m > 0 {
            self.resp_first.iter_mut().for_each(|v| *v = 0.0);
            self.resp_last.iter_mut().for_each(|v| *v = 0.0);
            self.resp_first[0] = 1.0;
            self.resp_last[m - 1] = 1.0;
            solve_interior(&self.inv_pivot, &self.upper, off, &mut self.resp_first);
            solve_interior(&self.inv_pivot, &self.upper, off, &mut self.resp_last);
        }
    }

    /// Highest segment angular frequency 2/√(LC) (rad/s), for substep selection.
    pub fn omega_max(&self) -> f64 {
        2.0 / (self.l * self.c).sqrt()
    }

    /// [`Line::advance_flows`] with `T` convolution terms per segment (`T` = `self.terms()`).
    #[inline]
    fn advance_flows_terms<const T: usize>(&mut self, h: f64, p_end: f64) {
        let n = self.p.len();
        let half_r = 0.5 * self.r;
        let den = self.l + h * self.r + h * half_r * self.gain_sum;
        let mut decay = [0.0; T];
        decay.copy_from_slice(&self.decay[..T]);
        let mut gain = [0.0; T];
        gain.copy_from_slice(&self.gain[..T]);
        for (j, ys) in self.y.chunks_exact_mut(T).take(n).enumerate() {
            let down = if j + 1 < n { self.p[j + 1] } else { p_end };
            let history: f64 = ys.iter().zip(&decay).map(|(y, e)| e * y).sum();
            let dq = h * (self.p[j] - down - self.r * self.q[j] - half_r * history) / den;
            self.q[j] += dq;
            for ((y, e), g) in ys.iter_mut().zip(&decay).zip(&gain) {
                *y = e * *y + g * dq;
            }
        }
    }

    /// Lowest wave mode of the line on its own, the half-wave π/T (rad/s), T = N·√(LC) the
    /// wave delay of the chain (s) (1/√(LC) per segment of the distributed line: T = ℓ/c).
    /// It is the first mode of a line closed at both ends, the second of a line closed at one
    /// end and open at the other (quarter wave π/(2T)); the `implicit` line method resolves
    /// line modes up to it (the substep rule of [`crate::model`]).
    pub fn omega_wave(&self) -> f64 {
        std::f64::consts::PI / (self.p.len() as f64 * (self.l * self.c).sqrt())
    }

    /// Update interior nodes 1..N from the old flows (node 0 is updated by the caller).
    #[inline]
    pub fn advance_interior_nodes(&mut self, h: f64) {
        for j in 1..self.p.len() {
            self.p[j] += h / self.c * (self.q[j - 1] - self.q[j]);
        }
    }

    /// Update flows (and the unsteady-friction states) from the new node pressures over the
    /// substep `h` the line was [`Line::prepare`]d for; `p_end` is the chamber pressure.
    #[inline]
    pub fn advance_flows(&mut self, h: f64, p_end: f64) {
        let n = self.p.len();
        let terms = self.m.len();
        if terms == 0 {
            let k = h / self.l;
            let den = 1.0 + h * self.r / self.l;
            for j in 0..n {
                let down = if j + 1 < n { self.p[j + 1] } else { p_end };
                self.q[j] = (self.q[j] + k * (self.p[j] - down)) / den;
            }
            return;
        }
        // The two term counts of the shipped models with the count known at compile time
        // (unrolled, same arithmetic in the same order as the general loop below).
        if terms == UNSTEADY_TERMS {
            return self.advance_flows_terms::<UNSTEADY_TERMS>(h, p_end);
        }
        if terms == 3 {
            return self.advance_flows_terms::<3>(h, p_end);
        }
        let half_r = 0.5 * self.r;
        let den = self.l + h * self.r + h * half_r * self.gain_sum;
        for j in 0..n {
            let down = if j + 1 < n { self.p[j + 1] } else { p_end };
            let ys = &mut self.y[j * terms..(j + 1) * terms];
            let history: f64 = ys.iter().zip(&self.decay).map(|(y, e)| e * y).sum();
            let dq = h * (self.p[j] - down - self.r * self.q[j] - half_r * history) / den;
            self.q[j] += dq;
            for ((y, e), g) in ys.iter_mut().zip(&self.decay).zip(&self.gain) {
                *y = e * *y + g * dq;
            }
        }
    }

    /// One substep `h` (s) of the `implicit` method (module docs): trapezoidal rule on the
    /// whole chain, node 0 fed by the valve flow `q_valve` (m³/s) at the old node-0 pressure
    /// with derivative `dq_valve` (m³/(s·Pa)), the chamber `end` as node N. Updates the node
    /// pressures, segment flows and convolution states; returns the chamber's new pressure
    /// (Pa). No cavitation limit here (the caller clamps). No allocation.
    ///
    /// Per segment j (between node j and j+1, node N the chamber), with g = h/(L + θ·h·R +
    /// h·(R/2)·Σmᵢgᵢ) (the momentum balance of [`Line::advance_flows`] with the pressure
    /// difference and the steady resistance at θ-weight, so that friction only removes
    /// energy: ΔE = −h·R·Σ q̄²): q′ⱼ = αⱼ + g·θ·(p′ⱼ − p′ⱼ₊₁), αⱼ = qⱼ + g·((1 − θ)·(pⱼ − pⱼ₊₁)
    /// − R·qⱼ − (R/2)·Σ e^(−aᵢh)·yᵢ); its θ-mean flow is βⱼ + k·(p′ⱼ − p′ⱼ₊₁), βⱼ = (1 − θ)·qⱼ +
    /// θ·αⱼ, k = g·θ². Node r: Cᵣ·(p′ᵣ − pᵣ) = h·(inflow − outflow at θ-mean) + h·(sᵣ + λᵣ·(p′ᵣ −
    /// pᵣ)) with the external source sᵣ and its self-derivative λᵣ (valve at node 0, `end` at
    /// node N): a symmetric tridiagonal system with off-diagonal −h·k, diagonally dominant
    /// for λᵣ ≤ 0.
    #[inline]
    pub fn advance_implicit(&mut self, h: f64, q_valve: f64, dq_valve: f64, end: EndNode) -> f64 {
        let n = self.p.len();
        let terms = self.m.len();
        let half_r = 0.5 * self.r;
        let g = self.imp_g;
        let hk = self.imp_hk;
        let off = -hk;
        for j in 0..n {
            let down = if j + 1 < n { self.p[j + 1] } else { end.p };
            let history: f64 = if terms == 0 {
                0.0
            } else {
                self.y[j * terms..(j + 1) * terms]
                    .iter()
                    .zip(&self.decay)
                    .map(|(y, e)| e * y)
                    .sum()
            };
            let q = self.q[j];
            let a = q + g * ((1.0 - THETA) * (self.p[j] - down) - self.r * q - half_r * history);
            self.alpha[j] = a;
            self.beta[j] = (1.0 - THETA) * q + THETA * a;
        }
        // Right-hand sides: interior rows into x[1..n], then z = T⁻¹·b (prepared factors).
        for r in 1..n {
            self.x[r] = self.c * self.p[r] + h * (self.beta[r - 1] - self.beta[r]);
        }
        solve_interior(&self.inv_pivot, &self.upper, off, &mut self.x[1..n]);
        // End rows: D₀·x₀ + off·x₁ = b₀ and D_N·x_N + off·x_{N−1} = b_N, with the interior
        // x_I = z − off·(x₀·T⁻¹e_first + x_N·T⁻¹e_last): a 2×2 system in (x₀, x_N).
        let d0 = self.c0 + hk - h * dq_valve;
        let b0 = self.c0 * self.p[0] + h * (q_valve - dq_valve * self.p[0] - self.beta[0]);
        let dn = end.cap + hk - h * end.dflow;
        let bn = end.cap * end.p + h * (end.flow - end.dflow * end.p + self.beta[n - 1]);
        let (x0, xn) = if n == 1 {
            let det = d0 * dn - off * off;
            ((b0 * dn - off * bn) / det, (d0 * bn - off * b0) / det)
        } else {
            let m = n - 1;
            let off2 = off * off;
            let a11 = d0 - off2 * self.resp_first[0];
            let a12 = -off2 * self.resp_last[0];
            let a21 = -off2 * self.resp_first[m - 1];
            let a22 = dn - off2 * self.resp_last[m - 1];
            let r1 = b0 - off * self.x[1];
            let r2 = bn - off * self.x[m];
            let det = a11 * a22 - a12 * a21;
            ((r1 * a22 - a12 * r2) / det, (a11 * r2 - a21 * r1) / det)
        };
        for r in 1..n {
            self.x[r] -= off * (x0 * self.resp_first[r - 1] + xn * self.resp_last[r - 1]);
        }
        self.x[0] = x0;
        self.x[n] = xn;
        for j in 0..n {
            let q_new = self.alpha[j] + g * THETA * (self.x[j] - self.x[j + 1]);
            let dq = q_new - self.q[j];
            self.q[j] = q_new;
            self.p[j] = self.x[j];
            if terms > 0 {
                let ys = &mut self.y[j * terms..(j + 1) * terms];
                for ((y, e), gi) in ys.iter_mut().zip(&self.decay).zip(&self.gain) {
                    *y = e * *y + gi * dq;
                }
            }
        }
        xn
    }
}

/// Solve T·x = b in place for the interior block of [`Line::advance_implicit`] (constant
/// diagonal, off-diagonal `off`), from its LU factors: reciprocal pivots and multipliers.
#[inline]
fn solve_interior(inv_pivot: &[f64], upper: &[f64], off: f64, b: &mut [f64]) {
    let mut prev = 0.0;
    for (v, ip) in b.iter_mut().zip(inv_pivot) {
        prev = (*v - off * prev) * ip;
        *v = prev;
    }
    let mut next = 0.0;
    for (v, u) in b.iter_mut().zip(upper).rev() {
        next = *v - u * next;
        *v = next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::Fluid;

    /// A line in the fluid of a `[fluid]` section.
    fn new_line(cfg: &LineDynamics, fluid: &Fluid, p0: f64) -> Line {
        Line::with_fluid(
            cfg,
            fluid.density,
            fluid.kinematic_viscosity,
            fluid.bulk_modulus,
            p0,
        )
    }

    /// Sirohi 2003's tube (11.5 in × 1.753 mm) in `segments`, with a port volume (m³).
    fn sirohi_cfg(segments: u32, port_volume: f64, friction: LineFriction) -> LineDynamics {
        LineDynamics {
            enabled: true,
            length: 0.2921,
            diameter: 1.753e-3,
            segments,
            bulk_modulus: None,
            port_volume,
            variant: Default::default(),
            wall_compliance: 0.0,
            resistance: 0.0,
            friction,
        }
    }

    /// 001's fluid with kinematic viscosity `nu` (m²/s).
    fn sirohi_fluid(nu: f64) -> Fluid {
        Fluid {
            density: 859.0,
            bulk_modulus: 1.793e9,
            kinematic_viscosity: nu,
            cavitation_pressure: -1e5,
        }
    }

    /// Sirohi 2003's tube in 16 segments in 001's fluid; `nu` = 0 makes the segments
    /// frictionless (R = 0).
    fn sirohi_line(nu: f64, friction: LineFriction) -> Line {
        new_line(&sirohi_cfg(16, 0.0, friction), &sirohi_fluid(nu), 0.0)
    }

    /// The bordered solve of [`Line::advance_implicit`] against Gaussian elimination with
    /// partial pivoting of the full (N + 1)-node system written out row by row from the
    /// scheme's equations (the module docs), for 1, 2, 3 and 16 segments, both friction
    /// models, a valve flow with its derivative and a leaking end node.
    #[test]
    fn bordered_solve_equals_dense_elimination_of_the_scheme() {
        for (segments, friction) in [
            (1, LineFriction::Steady),
            (2, LineFriction::Unsteady),
            (3, LineFriction::Steady),
            (16, LineFriction::Unsteady),
        ] {
            let mut l = new_line(
                &sirohi_cfg(segments, 3e-6, friction),
                &sirohi_fluid(2e-6),
                2e6,
            );
            let h = 1.3e-5;
            l.prepare(h);
            let n = l.p.len();
            for j in 0..n {
                l.p[j] = 2e6 + 1e4 * ((j * 7 % 5) as f64 - 2.0);
                l.q[j] = 1e-7 * ((j * 3 % 4) as f64 - 1.5);
            }
            for (k, y) in l.y.iter_mut().enumerate() {
                *y = 1e-8 * ((k % 3) as f64 - 1.0);
            }
            let end = EndNode {
                p: 2.05e6,
                cap: 1.2e-15,
                flow: -3e-7,
                dflow: -2e-13,
            };
            let (qv, dqv) = (4e-7, -5e-13);
            // Dense system from the equations: unknowns p′₀..p′_N.
            let terms = l.terms();
            let theta = 0.5;
            let den = l.l + theta * h * l.r + h * 0.5 * l.r * l.gain.iter().sum::<f64>();
            let g = h / den;
            let old = |j: usize| if j < n { l.p[j] } else { end.p };
            let alpha: Vec<f64> = (0..n)
                .map(|j| {
                    let hist: f64 = (0..terms).map(|i| l.decay[i] * l.y[j * terms + i]).sum();
                    l.q[j]
                        + g * ((1.0 - theta) * (old(j) - old(j + 1))
                            - l.r * l.q[j]
                            - 0.5 * l.r * hist)
                })
                .collect();
            let size = n + 1;
            let mut a = vec![vec![0.0; size + 1]; size];
            for (r, row) in a.iter_mut().enumerate() {
                let (cap, src, lam) = match r {
                    0 => (l.c0, qv, dqv),
                    r if r == n => (end.cap, end.flow, end.dflow),
                    _ => (l.c, 0.0, 0.0),
                };
                // cap·(x_r − p_r) = h·(θ-mean inflow − θ-mean outflow + src + lam·(x_r − p_r)),
                // θ-mean flow of segment j: (1 − θ)·q_j + θ·(α_j + g·θ·(x_j − x_{j+1})).
                row[r] += cap - h * lam;
                row[size] += cap * old(r) + h * (src - lam * old(r));
                let flow = |j: usize, sign: f64, row: &mut Vec<f64>| {
                    row[size] += sign * h * ((1.0 - theta) * l.q[j] + theta * alpha[j]);
                    row[j] -= sign * h * theta * theta * g;
                    row[j + 1] += sign * h * theta * theta * g;
                };
                if r > 0 {
                    flow(r - 1, 1.0, row);
                }
                if r < n {
                    flow(r, -1.0, row);
                }
            }
            // Gaussian elimination with partial pivoting.
            for col in 0..size {
                let piv = (col..size)
                    .max_by(|&i, &k| a[i][col].abs().partial_cmp(&a[k][col].abs()).unwrap())
                    .unwrap();
                a.swap(col, piv);
                let pivot_row = a[col].clone();
                for row in a.iter_mut().skip(col + 1) {
                    let f = row[col] / pivot_row[col];
                    for (v, p) in row.iter_mut().zip(&pivot_row).skip(col) {
                        *v -= f * p;
                    }
                }
            }
            let mut x = vec![0.0; size];
            for r in (0..size).rev() {
                let s: f64 = (r + 1..size).map(|k| a[r][k] * x[k]).sum();
                x[r] = (a[r][size] - s) / a[r][r];
            }
            let p_end = l.advance_implicit(h, qv, dqv, end);
            for j in 0..n {
                assert!(
                    (l.p[j] - x[j]).abs() < 1e-6,
                    "{segments}: node {j}: {} vs {}",
                    l.p[j],
                    x[j]
                );
                let q = alpha[j] + g * theta * (x[j] - x[j + 1]);
                assert!(
                    (l.q[j] - q).abs() < 1e-12 * (1e-7 + q.abs()) + 1e-18,
                    "{segments}: q{j}"
                );
            }
            assert!(
                (p_end - x[n]).abs() < 1e-6,
                "{segments}: end {p_end} vs {}",
                x[n]
            );
        }
    }

    /// The unrolled flow update (8 and 3 terms) is the general one, bit for bit: the same
    /// formula written out here, 2000 substeps with moving node pressures.
    #[test]
    fn unrolled_flow_update_equals_the_general_loop_bitwise() {
        for friction in [LineFriction::Unsteady, LineFriction::UnsteadyTrikha] {
            let mut l = sirohi_line(2e-6, friction);
            let h = 9e-6;
            l.prepare(h);
            let mut r = l.clone();
            let t = r.terms();
            let den = r.l + h * r.r + h * 0.5 * r.r * r.gain_sum;
            for step in 0..2000 {
                let drive = 1e5 * (step as f64 * 0.01).sin();
                for (j, (a, b)) in l.p.iter_mut().zip(r.p.iter_mut()).enumerate() {
                    *a = drive * (j as f64 * 0.3).cos();
                    *b = *a;
                }
                l.advance_flows(h, 0.0);
                let n = r.p.len();
                for j in 0..n {
                    let down = if j + 1 < n { r.p[j + 1] } else { 0.0 };
                    let mut hist = 0.0;
                    for i in 0..t {
                        hist += r.decay[i] * r.y[j * t + i];
                    }
                    let dq = h * (r.p[j] - down - r.r * r.q[j] - 0.5 * r.r * hist) / den;
                    r.q[j] += dq;
                    for i in 0..t {
                        r.y[j * t + i] = r.decay[i] * r.y[j * t + i] + r.gain[i] * dq;
                    }
                }
            }
            assert_eq!(l.q, r.q, "{friction:?}");
            assert_eq!(l.y, r.y, "{friction:?}");
            assert!(l.q.iter().any(|q| q.abs() > 0.0));
        }
    }

    /// Stored energy Σ C·p²/2 + Σ L·q²/2 (J) of the chain and an end node of capacitance
    /// `cap_end` at `p_end`.
    fn energy(l: &Line, cap_end: f64, p_end: f64) -> f64 {
        let nodes: f64 =
            l.p.iter()
                .enumerate()
                .map(|(j, p)| if j == 0 { l.c0 } else { l.c } * p * p)
                .sum();
        let flows: f64 = l.q.iter().map(|q| l.l * q * q).sum();
        0.5 * (nodes + flows + cap_end * p_end * p_end)
    }

    /// Variant `hose`: capacitance from 1/β_eff = 1/β + wall compliance (Merritt 1967
    /// eq. 2-46), resistance Hagen–Poiseuille plus the fitting resistance spread over the
    /// segments; inertance unchanged. Hand figures for a 3 m × 10 mm hose in 3 segments.
    #[test]
    fn hose_capacitance_and_resistance_by_hand() {
        let fluid = Fluid {
            density: 860.0,
            bulk_modulus: 1.5e9,
            kinematic_viscosity: 32e-6,
            cavitation_pressure: -1e5,
        };
        let mut cfg = LineDynamics {
            enabled: true,
            variant: crate::params::LineVariant::Hose,
            length: 3.0,
            diameter: 0.01,
            segments: 3,
            bulk_modulus: None,
            port_volume: 0.0,
            friction: LineFriction::Steady,
            wall_compliance: 1e-9,
            resistance: 3e9,
        };
        let l = new_line(&cfg, &fluid, 0.0);
        let area = std::f64::consts::PI * 0.25e-4;
        // β_eff = 1/(1/1.5e9 + 1e-9) = 0.6 GPa.
        assert!((l.c - area * 1.0 / 0.6e9).abs() < 1e-12 * l.c);
        let r_hp = 128.0 * 860.0 * 32e-6 * 1.0 / (std::f64::consts::PI * 1e-8);
        assert!(
            (l.r - (r_hp + 1e9)).abs() < 1e-9 * l.r,
            "{} vs {}",
            l.r,
            r_hp + 1e9
        );
        assert!((l.l - 860.0 / area).abs() < 1e-9 * l.l);
        // The same numbers on a pipe are the fluid's.
        cfg.variant = crate::params::LineVariant::Pipe;
        let p = new_line(&cfg, &fluid, 0.0);
        assert!((p.c - area / 1.5e9).abs() < 1e-12 * p.c);
        assert!((p.r - r_hp).abs() < 1e-9 * p.r);
    }

    #[test]
    fn hand_figures_of_the_001_tube() {
        // c = √(β/ρ), wave delay T = L/c, quarter wave c/(4L): 1444.8 m/s, 202 µs, 1236.5 Hz.
        let c = (1.793e9f64 / 859.0).sqrt();
        assert!((c - 1444.8).abs() < 0.05, "c = {c}");
        let l = sirohi_line(0.0, LineFriction::Steady);
        let t = std::f64::consts::PI / l.omega_wave();
        assert!((t - 0.2921 / c).abs() < 1e-12, "T = {t}");
        assert!((t - 202.2e-6).abs() < 0.05e-6, "T = {t}");
        assert!((1.0 / (4.0 * t) - 1236.5).abs() < 0.1);
        // Segment mode 2/√(LC) = 2c/ℓ = 1.58e5 rad/s.
        assert!((l.omega_max() - 2.0 * c * 16.0 / 0.2921).abs() < 1e-6 * l.omega_max());
    }

    /// Closed at the valve end (no valve flow), open at the far end (a reservoir: an end node
    /// 10¹² times a segment's capacitance). The lumped chain's modes are the closed form
    /// p_j ∝ cos((j + ½)κ), cos((N + ½)κ) = 0, ω_k = (2/√(LC))·sin((2k − 1)π/(2(2N + 1))) (from
    /// C·L·p̈_j = p_{j−1} − 2p_j + p_{j+1}, p_{−1} = p_0, p_N = 0); the trapezoidal rule turns a
    /// mode by 2·atan(ω·h/2) per step and keeps its amplitude. Run at ω₁·h = 0.5, i.e. the
    /// segment mode at ω·h = 10.5 (symplectic Euler needs ω·h < 2).
    #[test]
    fn implicit_chain_rings_at_the_lumped_quarter_wave_closed_form() {
        let mut l = sirohi_line(0.0, LineFriction::Steady);
        let n = l.p.len();
        let kappa = std::f64::consts::PI / (2 * n + 1) as f64;
        let w1 = 2.0 / (l.l * l.c).sqrt() * (0.5 * kappa).sin();
        // The lumped chain's quarter wave lies below c/(4L) (1236.5 Hz) by the lumping.
        let f1 = w1 / std::f64::consts::TAU;
        assert!((f1 - 1198.6).abs() < 0.1, "f1 = {f1} Hz");
        let h = 0.5 / w1;
        l.prepare(h);
        let amp = 1e5;
        for (j, p) in l.p.iter_mut().enumerate() {
            *p = amp * ((j as f64 + 0.5) * kappa).cos();
        }
        let cap_end = 1e12 * l.c;
        let mut p_end = 0.0;
        let phi = 2.0 * (0.5 * w1 * h).atan();
        let mut worst: f64 = 0.0;
        for step in 1..=4000 {
            let end = EndNode {
                p: p_end,
                cap: cap_end,
                flow: 0.0,
                dflow: 0.0,
            };
            p_end = l.advance_implicit(h, 0.0, 0.0, end);
            let expect = amp * (0.5 * kappa).cos() * (step as f64 * phi).cos();
            worst = worst.max((l.p[0] - expect).abs());
        }
        // 4000 steps ≈ 318 periods; the reservoir's finite size perturbs ω by ~1e-11.
        assert!(worst < 1e-6 * amp, "worst deviation {worst} Pa");
    }

    /// Without friction the trapezoidal chain conserves the stored energy exactly (up to
    /// round-off), closed at both ends, at a step 4× beyond the symplectic limit (segment
    /// mode ω·h = 8); with laminar friction the energy only falls.
    #[test]
    fn implicit_chain_conserves_energy_without_friction_and_loses_it_with() {
        for nu in [0.0, 2e-6] {
            let mut l = sirohi_line(nu, LineFriction::Steady);
            let h = 8.0 / l.omega_max();
            l.prepare(h);
            for (j, p) in l.p.iter_mut().enumerate() {
                *p = 1e5 * (((j * 7 + 3) % 11) as f64 - 5.0);
            }
            for (j, q) in l.q.iter_mut().enumerate() {
                *q = 1e-6 * (((j * 5 + 1) % 7) as f64 - 3.0);
            }
            let cap_end = l.c;
            let mut p_end = 3e5;
            let e0 = energy(&l, cap_end, p_end);
            let mut prev = e0;
            for _ in 0..10_000 {
                let end = EndNode {
                    p: p_end,
                    cap: cap_end,
                    flow: 0.0,
                    dflow: 0.0,
                };
                p_end = l.advance_implicit(h, 0.0, 0.0, end);
                let e = energy(&l, cap_end, p_end);
                if nu > 0.0 {
                    assert!(e <= prev * (1.0 + 1e-12), "energy rose: {prev} → {e}");
                }
                prev = e;
            }
            if nu == 0.0 {
                assert!(
                    ((prev - e0) / e0).abs() < 1e-10,
                    "drift {}",
                    (prev - e0) / e0
                );
            } else {
                assert!(
                    prev < 0.999 * e0,
                    "friction dissipated nothing: {e0} → {prev}"
                );
            }
        }
    }

    /// A steady flow through the chain from a constant valve flow into a leaking end node
    /// settles at the Hagen–Poiseuille drop: Δp = N·R·Q across the line, p_end = Q/k_leak.
    #[test]
    fn implicit_chain_settles_at_the_poiseuille_drop() {
        for friction in [LineFriction::Steady, LineFriction::Unsteady] {
            let mut l = sirohi_line(2e-6, friction);
            // ω·h = 0.8 for the segment mode: the trapezoidal rule damps a mode by friction
            // 1 + (ω·h/2)² times more slowly than the ODE, so a coarse step settles late.
            let h = 5e-6;
            l.prepare(h);
            let q = 1e-6;
            let k_leak = 1e-12; // m³/(s·Pa)
            let cap_end = 100.0 * l.c;
            let mut p_end = 0.0;
            for _ in 0..800_000 {
                let end = EndNode {
                    p: p_end,
                    cap: cap_end,
                    flow: -k_leak * p_end,
                    dflow: -k_leak,
                };
                p_end = l.advance_implicit(h, q, 0.0, end);
            }
            let drop = l.p[0] - p_end;
            let expect = l.p.len() as f64 * l.r * q;
            assert!(
                (p_end - q / k_leak).abs() < 1e-6 * q / k_leak,
                "{friction:?}: {p_end}"
            );
            assert!(
                (drop - expect).abs() < 1e-6 * expect,
                "{friction:?}: {drop} vs {expect}"
            );
        }
    }
}
