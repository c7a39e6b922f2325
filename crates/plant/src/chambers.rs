//! The chambers' pressure balance (continuity with the bulk modulus, 003 eq. 7–8 for the
//! volumes; 002 eq. 18–19), written once for every way the valve ports reach the chambers:
//! directly, through symplectic line chains (with counterbalance valves between a line's
//! end and its chamber, crates/plant/src/cbv.rs) or through implicit ones
//! (`crate::line::Line::advance_implicit`, which takes the chamber as its chain's end node).
//!
//! A chamber of pressure p, bulk modulus β and volume V takes the flow `inflow` from its
//! port or line, loses ∓A·v to the piston's motion, exchanges ∓q_in across the piston and
//! loses q_ext to tank:
//!
//! dp/dt = β/V · (inflow ∓ A·v ∓ q_in − q_ext),
//!
//! stepped by exponential Euler linearised in p (see crates/plant/src/model.rs, step 2):
//! p⁺ = p + h·f·φ₁(λh), λ = β/V · (∂inflow/∂p − k_in − k_ext − ∂q_end/∂p), the two
//! derivatives being the valve port's (direct coupling) and the counterbalance valve's
//! (through its node).

use crate::effects::{phi1, EndNode};

/// The flow stages' terms of both chambers' balances at the start of a substep (SI units).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Leaks {
    /// Cross-piston flow A→B q_in (m³/s).
    pub q_in: f64,
    /// Flows to tank of A and B (m³/s).
    pub q_ext: [f64; 2],
    /// Cross-piston conductance k_in (m³/(s·Pa)).
    pub k_in: f64,
    /// Conductances to tank of A and B (m³/(s·Pa)).
    pub k_ext: [f64; 2],
}

/// One chamber's side of the balance over a substep, at the start of the substep: every
/// term but the inflow from its port or line (SI units).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Chamber {
    /// Pressure p (Pa).
    pub p: f64,
    /// Bulk modulus β at p (Pa).
    pub beta: f64,
    /// Volume V (m³).
    pub volume: f64,
    /// Flow into the chamber from the piston's motion (m³/s): −A_A·v for A, +A_B·v for B.
    pub piston: f64,
    /// Cross-piston flow into the chamber (m³/s): −q_in for A, +q_in for B.
    pub cross: f64,
    /// Flow to tank (m³/s).
    pub q_ext: f64,
    /// Cross-piston conductance k_in (m³/(s·Pa)).
    pub k_in: f64,
    /// Conductance to tank k_ext (m³/(s·Pa)).
    pub k_ext: f64,
}

impl Chamber {
    /// The pressure (Pa) after a substep `h` (s) with the flow `inflow` (m³/s) from its
    /// port or line, whose derivatives in the chamber pressure are `d_port` (a valve port
    /// feeding the chamber directly, m³/(s·Pa)) and −`d_end` (what a counterbalance valve
    /// passes on, m³/(s·Pa)); at least `p_cav` (Pa). The sums keep the order of the
    /// balances this replaced term by term, so the step is bit-identical: the flow sum
    /// ((inflow ∓ A·v) ∓ q_in) − q_ext, the linearisation ((d_port − k_in) − k_ext) − d_end
    /// (an absent derivative is 0, at most the sign of a zero λ changes, and φ₁(±0) = 1).
    #[inline]
    pub fn advance(&self, inflow: f64, d_port: f64, d_end: f64, h: f64, p_cav: f64) -> f64 {
        let f = self.beta / self.volume * (inflow + self.piston + self.cross - self.q_ext);
        let lam = self.beta / self.volume * (d_port - self.k_in - self.k_ext - d_end);
        (self.p + h * f * phi1(lam * h)).max(p_cav)
    }

    /// The chamber as the end node of an implicit line chain: its pressure, capacitance
    /// V/β (m³/Pa), the flow into it besides the line's (m³/s) and that flow's derivative in
    /// its pressure (m³/(s·Pa)).
    #[inline]
    pub fn end_node(&self) -> EndNode {
        EndNode {
            p: self.p,
            cap: self.volume / self.beta,
            flow: self.piston + self.cross - self.q_ext,
            dflow: -self.k_in - self.k_ext,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sealed chamber (no leakage) filled at constant flow Q: dp/dt = β·Q/V exactly
    /// (λ = 0, φ₁ = 1), so one step raises p by h·β·Q/V; a chamber with only a conductance
    /// to tank decays as p·e^(−β·k·h/V), which exponential Euler in p reproduces exactly.
    #[test]
    fn fill_and_decay_closed_forms() {
        let (beta, v, h) = (1.4e9, 1e-4, 1e-5);
        let sealed = Chamber {
            p: 1e6,
            beta,
            volume: v,
            piston: 0.0,
            cross: 0.0,
            q_ext: 0.0,
            k_in: 0.0,
            k_ext: 0.0,
        };
        let q = 2e-5;
        let p1 = sealed.advance(q, 0.0, 0.0, h, -1e5);
        assert!((p1 - (1e6 + h * beta * q / v)).abs() < 1e-6);
        let k = 1e-11;
        let leaky = Chamber {
            q_ext: k * 1e6,
            k_ext: k,
            ..sealed
        };
        let p1 = leaky.advance(0.0, 0.0, 0.0, h, -1e5);
        let want = 1e6 * (-beta * k * h / v).exp();
        assert!((p1 - want).abs() < 1e-9 * want, "{p1} vs {want}");
        let node = leaky.end_node();
        assert_eq!(node.cap, v / beta);
        assert_eq!(node.flow, -k * 1e6);
        assert_eq!(node.dflow, -k);
    }
}
