//! Lumped R-L-C line between a valve port and a chamber (002 eq. 9–17).
//!
//! N segments, each a capacitance C = A·ℓ/β at its upstream node, an inductance
//! L = ρ·ℓ/A and a laminar resistance R = 128·μ·ℓ/(π·d⁴) (Hagen–Poiseuille) in series to the
//! next node; the last segment discharges into the chamber. Node 0 (the valve port) also
//! holds the optional lumped `port_volume` (capacitance V_port/β₀). Nodes are updated from the
//! old flows, flows from the new pressures with R implicit (symplectic, stable for ω·h < 2).

use crate::params::{Fluid, LineDynamics};

/// State and constants of one line.
#[derive(Debug, Clone)]
pub struct Line {
    /// Node pressures (Pa), node 0 at the valve.
    pub p: Vec<f64>,
    /// Segment flows (m³/s), segment j from node j to node j+1 (last: into the chamber).
    pub q: Vec<f64>,
    /// Node capacitance (m³/Pa).
    pub c: f64,
    /// Capacitance of the valve-side node 0 (m³/Pa): `c` plus the port volume's V_port/β₀.
    pub c0: f64,
    /// Segment inductance (kg/m⁴).
    pub l: f64,
    /// Segment resistance (Pa·s/m³).
    pub r: f64,
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
        Self {
            p: vec![p0; n],
            q: vec![0.0; n],
            c,
            c0: c + cfg.port_volume.max(0.0) / fluid.bulk_modulus,
            l: fluid.density * seg / area,
            r: 128.0 * mu * seg / (std::f64::consts::PI * cfg.diameter.powi(4)),
        }
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

    /// Update flows from the new node pressures; `p_end` is the chamber pressure.
    #[inline]
    pub fn advance_flows(&mut self, h: f64, p_end: f64) {
        let n = self.p.len();
        let k = h / self.l;
        let den = 1.0 + h * self.r / self.l;
        for j in 0..n {
            let down = if j + 1 < n { self.p[j + 1] } else { p_end };
            self.q[j] = (self.q[j] + k * (self.p[j] - down)) / den;
        }
    }
}
