//! Lumped R-L-C line between a valve port and a chamber (002 eq. 9–17).
//!
//! N segments, each a capacitance C = A·ℓ/β at its upstream node, an inductance
//! L = ρ·ℓ/A and a laminar resistance R = 128·μ·ℓ/(π·d⁴) (Hagen–Poiseuille) in series to the
//! next node; the last segment discharges into the chamber. Node 0 (the valve port) also
//! holds the optional lumped `port_volume` (capacitance V_port/β₀). Nodes are updated from the
//! old flows, flows from the new pressures with R implicit (symplectic, stable for ω·h < 2).
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

use crate::params::{Fluid, LineDynamics, LineFriction};

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
}

impl Line {
    /// Build a line filled at pressure `p0`.
    pub fn new(cfg: &LineDynamics, fluid: &Fluid, p0: f64) -> Self {
        let n = cfg.segments.max(1) as usize;
        let seg = cfg.length / n as f64;
        let area = std::f64::consts::PI * cfg.diameter * cfg.diameter / 4.0;
        let beta = cfg.bulk_modulus.unwrap_or(fluid.bulk_modulus);
        let mu = fluid.density * fluid.kinematic_viscosity;
        let c = area * seg / beta;
        let (m, nn, residual) = weighting_terms(cfg.friction);
        let radius = 0.5 * cfg.diameter;
        let a: Vec<f64> = nn
            .iter()
            .map(|x| x * fluid.kinematic_viscosity / (radius * radius))
            .collect();
        let terms = m.len();
        let mut line = Self {
            p: vec![p0; n],
            q: vec![0.0; n],
            y: vec![0.0; n * terms],
            c,
            c0: c + cfg.port_volume.max(0.0) / fluid.bulk_modulus,
            l: fluid.density * seg / area * (1.0 + 4.0 * residual),
            r: 128.0 * mu * seg / (std::f64::consts::PI * cfg.diameter.powi(4)),
            decay: vec![1.0; terms],
            gain: m.clone(),
            gain_sum: m.iter().sum(),
            m,
            a,
        };
        line.prepare(0.0);
        line
    }

    /// Convolution terms per segment (0 for steady friction).
    pub fn terms(&self) -> usize {
        self.m.len()
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
    }

    /// Highest segment angular frequency 2/√(LC) (rad/s), for substep selection.
    pub fn omega_max(&self) -> f64 {
        2.0 / (self.l * self.c).sqrt()
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
}
