//! Four-edge valve: metering-edge flow. The spool dynamics are `valve_dynamics`'s
//! ([`crate::effects::valve_dynamics`]; [`SpoolModel`] re-exported here); the dead band and
//! the saturation that shape the edges are the components of `valve_deadband` and
//! `valve_saturation` ([`Deadband`], [`Saturation`], re-exported here): [`EdgeLaw`] holds
//! the flow law alone and takes the two stages by reference where it needs them (the
//! plant passes the components it configured, `Plant::configure` in
//! crates/plant/src/model.rs; a caller without a plant builds them from the sections,
//! [`EdgeLaw::stages`]).
//!
//! Flow per edge Q = k · o · φ(Δp) where o ≥ 0 is the edge opening (fraction of full
//! spool travel) and φ(Δp) = Δp·(Δp² + Δp_l²)^((n−1)/2) is the signed power law
//! |Δp|ⁿ·sign(Δp), regularised to laminar below Δp_l so that dQ/dp stays finite at Δp = 0.
//! - `orifice`: k = C_d·A_max·√(2/ρ), n = ½ (orifice equation, 002 eq. 1–8).
//! - `kq`: k = q_vn/√Δp_n, n = ½ (003 eq. 9–13).
//! - `power_law`: k = c/(1 MPa)ⁿ with the supply raised by P_o (004 eq. 20–23: P_d = P_s − P_L − P_T + P_o).

pub use crate::effects::valve_deadband::Deadband;
pub use crate::effects::valve_dynamics::SpoolModel;
pub use crate::effects::valve_saturation::Saturation;
use crate::effects::{LapStage, LimitStage};
use crate::params::{FlowForm, PlantParams};

/// Metering-edge geometry and flow law. The two effect components that shape the edges,
/// `valve_deadband`'s lap stage ([`LapStage`]) and `valve_saturation`'s limit stage
/// ([`LimitStage`]), are not held here: [`EdgeLaw::openings`], [`EdgeLaw::edge`] and
/// [`EdgeLaw::port`] take them by reference, so the plant's edges are its components.
#[derive(Debug, Clone)]
pub struct EdgeLaw {
    /// Flow coefficient k (m³/s per unit opening per Paⁿ).
    pub k: f64,
    /// Exponent n.
    pub n: f64,
    /// Laminar transition pressure Δp_l (Pa).
    pub dp_lam: f64,
    /// Supply pressure raise P_o for the power law (Pa).
    pub supply_offset: f64,
    /// Underlap (fraction).
    pub underlap: f64,
}

impl EdgeLaw {
    /// Derive the flow law from the parameters (assumes they passed validation).
    pub fn new(params: &PlantParams) -> Self {
        let v = &params.valve;
        let (k, n, po) = match v.flow_form {
            FlowForm::Orifice => (
                v.discharge_coefficient.unwrap_or(0.6)
                    * v.area_max.unwrap_or(0.0)
                    * (2.0 / params.fluid.density).sqrt(),
                0.5,
                0.0,
            ),
            FlowForm::Kq => (
                v.rated_flow.unwrap_or(0.0) / v.rated_pressure_drop.unwrap_or(1.0).sqrt(),
                0.5,
                0.0,
            ),
            FlowForm::PowerLaw => {
                let n = v.exponent.unwrap_or(0.5);
                (
                    v.flow_at_1mpa.unwrap_or(0.0) / 1.0e6_f64.powf(n),
                    n,
                    v.pressure_offset.unwrap_or(0.0),
                )
            }
        };
        Self {
            k,
            n,
            dp_lam: v.laminar_pressure,
            supply_offset: po,
            underlap: v.underlap,
        }
    }

    /// The lap and limit stages of `params`' sections (`valve_deadband`,
    /// `valve_saturation`), for a caller that steps the edges without a plant (the plant
    /// passes its own components).
    pub fn stages(params: &PlantParams) -> (Deadband, Saturation) {
        (
            Deadband::new(params.effects.valve_deadband.as_ref()),
            Saturation::new(params.effects.valve_saturation.as_ref()),
        )
    }

    /// Edge openings (P→A, A→T, P→B, B→T) for spool position `s` (fraction): the travel
    /// from the lap stage's zero offset ([`LapStage::travel`]), within the limit stage's
    /// travel limits ([`LimitStage::clip_travel`]), plus the underlap less the lap stage's
    /// overlap ([`LapStage::lap`]), ≥ 0.
    #[inline]
    pub fn openings(&self, lap: &impl LapStage, limit: &impl LimitStage, s: f64) -> [f64; 4] {
        let se = limit.clip_travel(lap.travel(s));
        let pos = lap.lap(se + self.underlap).max(0.0);
        let neg = lap.lap(-se + self.underlap).max(0.0);
        [pos, neg, neg, pos]
    }

    /// Signed, regularised power law φ(Δp) and its derivative dφ/dΔp.
    #[inline]
    pub fn phi(&self, dp: f64) -> (f64, f64) {
        let s2 = dp * dp + self.dp_lam * self.dp_lam;
        if self.n == 0.5 {
            let g = 1.0 / s2.sqrt().sqrt();
            (dp * g, g * (0.5 * dp * dp + self.dp_lam * self.dp_lam) / s2)
        } else {
            let g = s2.powf(0.5 * (self.n - 1.0));
            (
                dp * g,
                g * (self.n * dp * dp + self.dp_lam * self.dp_lam) / s2,
            )
        }
    }

    /// Flow through one edge of opening `o` at pressure drop `dp`, and dQ/d(Δp), within the
    /// limit stage's edge flow limit ([`LimitStage::clip_flow`]).
    #[inline]
    pub fn edge(&self, limit: &impl LimitStage, o: f64, dp: f64) -> (f64, f64) {
        if o <= 0.0 {
            return (0.0, 0.0);
        }
        let (f, df) = self.phi(dp);
        let q = self.k * o * f;
        limit.clip_flow(q, self.k * o * df)
    }

    /// Net flow into a port at pressure `p` from supply `ps` and to tank `pt` through the
    /// inlet edge opening `o_in` and outlet edge opening `o_out`, within the limit stage's
    /// edge flow limit; returns (Q, dQ/dp, Q from supply).
    #[inline]
    pub fn port(
        &self,
        limit: &impl LimitStage,
        o_in: f64,
        o_out: f64,
        ps: f64,
        pt: f64,
        p: f64,
    ) -> (f64, f64, f64) {
        let (qi, dqi) = self.edge(limit, o_in, ps + self.supply_offset - p);
        let (qo, dqo) = self.edge(limit, o_out, p - pt);
        (qi - qo, -dqi - dqo, qi)
    }
}
