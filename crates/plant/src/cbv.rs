//! Counterbalance valves (CBVs) at the cylinder ends of the lines (Cristofori 2015 fig. 2; the crane
//! of 002 fig. 9 has one per line, items 8, 9, 15, 16).
//!
//! Cristofori 2015 models the CBV only inside its estimator and with one parameter: the free-flow
//! check ("unidirectional valve integrated in the CBV") as Δp = R_UV·Q² (002 eq. 18–19);
//! the pilot-operated side is not modelled but bypassed by the chamber pressure build-up
//! (002 eq. 20–24). 002 names the pilot ratio ("low pilot ratios are used to pressurize the
//! cylinder chambers", §Case study) but prints no ratio, setting or valve data; it refers to
//! Ritelli & Vacca (2013, Energ. Convers. Manage. 76:701–711, 002 ref. 6) for the detailed
//! model. The opening law here is the CBV's catalogue definition (e.g. Sun Hydraulics CBEA:
//! "the check valve allows free flow from the directional valve (port 2) to the load (port 1)
//! while a direct-acting, pilot-assisted relief valve controls flow from port 1 to port 2.
//! Pilot assist at port 3 lowers the effective setting at a rate determined by the pilot
//! ratio"), with the spring chamber referred to tank (back pressure at port 2 ignored):
//!
//! - relief poppet target opening  x* = clamp((p₁ + ψ·p₃ − p_set)/Δp_open, 0, 1), with p₁ the
//!   chamber (load) pressure, p₃ the pilot pressure (the other line at the cylinder), ψ the
//!   pilot ratio, p_set the setting (cracking pressure without pilot) and Δp_open the rise of
//!   p₁ + ψ·p₃ from cracking to full opening (spring rate over seat area);
//! - poppet lag τ·ẋ = x* − x (first order; 002 gives no CBV dynamics, τ is assumed);
//! - poppet flow (both ways, orifice 002 eq. 2): Q = C_d·A_max·x·√(2/ρ)·φ(p₂ − p₁);
//! - check flow, port 2 → 1 only (002 eq. 18 inverted): Q = φ(p₂ − p₁ − p_crack)/√R_UV for
//!   p₂ − p₁ > p_crack, else 0;
//!
//! with φ(Δp) = Δp/(Δp² + Δp_l²)^¼ the signed square root regularised to laminar below
//! Δp_l (as the spool edges, [`crate::valve`]) so that dQ/dp stays finite for the implicit
//! pressure update. Between the line's last segment and the poppet sits the valve body and
//! cylinder port, a lumped volume `volume` (port 2 node, compressed with β₀).

use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// Which lines carry a CBV.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum CbvSides {
    /// Both lines (002 fig. 2 and 9).
    #[default]
    Both,
    /// Only line A (piston side holds the load).
    A,
    /// Only line B (rod side holds the load).
    B,
}

fn yes() -> bool {
    true
}

/// `counterbalance_valve`: pilot-assisted relief with free-flow check at the cylinder end of
/// each line (needs `line_dynamics`). Same valve on every side it is fitted to.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CounterbalanceValve {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Lines fitted with a CBV (default both).
    #[serde(default)]
    #[param(
        choice,
        desc = "lines fitted with a CBV at the cylinder end (default both)"
    )]
    pub sides: CbvSides,
    /// Pilot ratio ψ (-): pilot area over relief seat area.
    #[param(unit = "-", range = Positive, desc = "pilot ratio ψ: opens when p_load + ψ·p_pilot ≥ setting")]
    pub pilot_ratio: f64,
    /// Setting p_set (Pa): load pressure that cracks the relief without pilot.
    #[param(unit = "Pa", range = Positive, desc = "relief setting p_set (cracking load pressure without pilot)")]
    pub setting: f64,
    /// Rise of p₁ + ψ·p₃ from cracking to full opening Δp_open (Pa).
    #[param(unit = "Pa", range = Positive, desc = "rise of p_load + ψ·p_pilot from cracking to full opening")]
    pub opening_pressure: f64,
    /// Metering area of the fully open poppet A_max (m²).
    #[param(unit = "m²", range = Positive, desc = "poppet metering area fully open")]
    pub area_max: f64,
    /// Discharge coefficient C_d of the poppet (-).
    #[serde(default = "default_cd")]
    #[param(unit = "-", range = Within(0.01, 1.0), desc = "poppet discharge coefficient (default 0.7)")]
    pub discharge_coefficient: f64,
    /// Check-valve resistance R_UV (Pa·s²/m⁶), Δp = R_UV·Q² (002 eq. 18–19).
    #[param(unit = "Pa·s²/m⁶", range = Positive, desc = "free-flow check R_UV, Δp = R_UV·Q² (002 eq. 18–19)")]
    pub check_resistance: f64,
    /// Check-valve cracking pressure p_crack (Pa), default 0.
    #[serde(default)]
    #[param(unit = "Pa", range = NonNegative, desc = "check-valve cracking pressure (default 0)")]
    pub check_cracking: f64,
    /// Poppet time constant τ (s).
    #[param(unit = "s", range = Positive, desc = "poppet first-order time constant")]
    pub time_constant: f64,
    /// Oil volume between the line end and the poppet (valve body, cylinder port) (m³).
    #[param(unit = "m³", range = Positive, desc = "oil volume between line end and poppet")]
    pub volume: f64,
    /// Work-port-to-tank conductance of the directional valve (m³/(s·Pa)), default 0: the
    /// neutral A,B→T bleed ("motor spool") a CBV circuit needs so that the pilot pressure
    /// decays and the CBV locks the load at stop; the plant's spool edges close at null.
    #[serde(default)]
    #[param(unit = "m³/(s·Pa)", range = NonNegative, desc = "directional valve work port → tank bleed (neutral A,B→T), default 0")]
    pub port_bleed: f64,
    /// Laminar transition pressure Δp_l of the orifice laws (Pa), default 0.05 MPa.
    #[serde(default = "default_lam")]
    #[param(unit = "Pa", range = Positive, desc = "laminar transition of the CBV orifice laws (default 5e4)")]
    pub laminar_pressure: f64,
}

fn default_cd() -> f64 {
    0.7
}

fn default_lam() -> f64 {
    5.0e4
}

/// State of one CBV.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CbvState {
    /// Port-2 node pressure: line end / valve body (Pa).
    pub p_node: f64,
    /// Relief poppet opening (fraction of full stroke, 0–1).
    pub opening: f64,
    /// Flow from the node into the chamber (m³/s), negative while the load drains.
    pub q: f64,
}

/// One configured CBV with its constants.
#[derive(Debug, Clone)]
pub struct Cbv {
    /// State.
    pub s: CbvState,
    psi: f64,
    p_set: f64,
    dp_open: f64,
    /// C_d·A_max·√(2/ρ) (m³/s/√Pa).
    k_poppet: f64,
    /// 1/√R_UV (m³/s/√Pa).
    k_check: f64,
    p_crack: f64,
    tau: f64,
    dp_lam: f64,
    /// Node capacitance V/β₀ (m³/Pa).
    pub c_node: f64,
}

impl Cbv {
    /// From the config section and the fluid (ρ kg/m³, β₀ Pa).
    pub fn new(p: &CounterbalanceValve, density: f64, beta0: f64) -> Self {
        Self {
            s: CbvState::default(),
            psi: p.pilot_ratio,
            p_set: p.setting,
            dp_open: p.opening_pressure,
            k_poppet: p.discharge_coefficient * p.area_max * (2.0 / density).sqrt(),
            k_check: 1.0 / p.check_resistance.sqrt(),
            p_crack: p.check_cracking,
            tau: p.time_constant,
            dp_lam: p.laminar_pressure,
            c_node: p.volume / beta0,
        }
    }

    /// Regularised signed square root φ(Δp) and dφ/dΔp.
    #[inline]
    fn phi(&self, dp: f64) -> (f64, f64) {
        let l2 = self.dp_lam * self.dp_lam;
        let s2 = dp * dp + l2;
        let g = 1.0 / s2.sqrt().sqrt();
        (dp * g, g * (0.5 * dp * dp + l2) / s2)
    }

    /// Advance the poppet over `h` (s) towards the opening set by the chamber pressure
    /// `p_load` (Pa) and the pilot pressure `p_pilot` (Pa), exact for the first-order lag.
    #[inline]
    pub fn advance_poppet(&mut self, h: f64, p_load: f64, p_pilot: f64) {
        let target = ((p_load + self.psi * p_pilot - self.p_set) / self.dp_open).clamp(0.0, 1.0);
        self.s.opening += (target - self.s.opening) * -(-h / self.tau).exp_m1();
    }

    /// Flow from the node into the chamber (m³/s) at node pressure `p_node` and chamber
    /// pressure `p_ch` (Pa), and its derivative with respect to p_node (m³/(s·Pa); the
    /// derivative with respect to p_ch is its negative).
    #[inline]
    pub fn flow(&self, p_node: f64, p_ch: f64) -> (f64, f64) {
        let dp = p_node - p_ch;
        let (f, df) = self.phi(dp);
        let mut q = self.k_poppet * self.s.opening * f;
        let mut dq = self.k_poppet * self.s.opening * df;
        let dc = dp - self.p_crack;
        if dc > 0.0 {
            let (fc, dfc) = self.phi(dc);
            q += self.k_check * fc;
            dq += self.k_check * dfc;
        }
        (q, dq)
    }
}
