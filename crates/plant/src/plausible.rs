//! The states no rig can have: bounds on the chamber and supply pressures, the piston
//! velocity and the rod force, derived from the configured supply, valve and cylinder. A
//! state beyond them after a step is a simulation fault (an integration that ran away, a
//! fitted law far outside its data), reported by `Plant::step` like a non-finite state.
//!
//! The bounds are orders of magnitude beyond anything the modelled rig produces, so that
//! only a broken simulation reaches them:
//! - pressure above 10 × the supply pressure + 10 MPa: a valve-controlled cylinder cannot
//!   raise a chamber above the supply by more than the area ratio (pressure intensification
//!   of a differential cylinder, Merritt, "Hydraulic Control Systems", 1967, §5.3) plus a
//!   pressure peak of a decelerated load; both stay within a few times the supply;
//! - pressure below the cavitation floor (`fluid.cavitation_pressure`, ≥ −1 bar gauge) by
//!   more than 10 MPa, a hundred times the deepest vacuum (−1 bar gauge);
//! - |piston velocity| above the larger of ten times the speed the fully open valve can
//!   feed the smaller piston area at the pressure bound (Q = k·o·φ(Δp) of
//!   `crate::valve::EdgeLaw`) and the speed that crosses the whole stroke in one control
//!   period;
//! - |rod force| above the pressure bound on both piston areas plus the external force
//!   acting at the step: more than the cylinder and its load can push.

use crate::params::PlantParams;
use crate::valve::EdgeLaw;
use ehactl_types::PlantState;

/// Pressure bound factor on the supply pressure (-).
const PRESSURE_FACTOR: f64 = 10.0;
/// Pressure margin (Pa) above the supply bound and below the cavitation floor.
const PRESSURE_MARGIN: f64 = 10.0e6;
/// Velocity margin on the fully open valve's piston speed (-).
const VELOCITY_FACTOR: f64 = 10.0;

/// A state beyond its bound: the state's name, its value, the bound it crossed, the unit.
pub type Implausible = (&'static str, f64, f64, &'static str);

/// The bounds of the states a rig can have (module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plausible {
    /// Highest plausible pressure (Pa).
    pub p_max: f64,
    /// Lowest plausible pressure (Pa, gauge).
    pub p_min: f64,
    /// Largest plausible |piston velocity| (m/s).
    pub v_max: f64,
    /// Largest plausible |rod force| without the external force (N).
    pub f_max: f64,
}

impl Plausible {
    /// The bounds of the rig `params` with its edge law `edges`, stepped at `control_dt` (s).
    pub fn new(params: &PlantParams, edges: &EdgeLaw, control_dt: f64) -> Self {
        let cyl = &params.cylinder;
        let p_max = PRESSURE_FACTOR * params.supply.pressure.abs() + PRESSURE_MARGIN;
        let p_min = params.fluid.cavitation_pressure.min(0.0) - PRESSURE_MARGIN;
        let opening = 1.0 + edges.underlap;
        let dp = p_max - params.supply.tank_pressure + edges.supply_offset;
        let q_full = edges.edge(opening, dp).0.abs();
        let smaller = cyl.area_a.min(cyl.area_b);
        let area = if smaller > 0.0 {
            smaller
        } else {
            cyl.area_a.max(cyl.area_b)
        };
        let v_valve = VELOCITY_FACTOR * q_full / area;
        let v_stroke = cyl.stroke / control_dt;
        Plausible {
            p_max,
            p_min,
            v_max: v_valve.max(v_stroke),
            f_max: p_max * (cyl.area_a + cyl.area_b),
        }
    }

    /// The first state of `s` beyond its bound, if any (pressures, velocity, rod force).
    /// Allocation-free.
    #[inline]
    pub fn check(&self, s: &PlantState) -> Option<Implausible> {
        for (what, p) in [("p_a", s.p_a), ("p_b", s.p_b), ("p_s", s.p_s)] {
            if p > self.p_max {
                return Some((what, p, self.p_max, "Pa"));
            }
            if p < self.p_min {
                return Some((what, p, self.p_min, "Pa"));
            }
        }
        if s.v.abs() > self.v_max {
            return Some(("v", s.v, self.v_max, "m/s"));
        }
        let f_max = self.f_max + s.external.abs();
        if s.rod_force.abs() > f_max {
            return Some(("rod_force", s.rod_force, f_max, "N"));
        }
        None
    }
}
