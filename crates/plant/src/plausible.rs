//! The states no rig can have: bounds on the chamber and supply pressures, the piston
//! velocity and the rod force, derived from the configured supply, valve and cylinder. A
//! state beyond them after a step is a simulation fault (an integration that ran away, a
//! fitted law far outside its data), reported by `Plant::step` like a non-finite state.
//!
//! The bounds are orders of magnitude beyond anything the modelled rig produces, so that
//! only a broken simulation reaches them:
//! - pressure above 10 × a reference pressure + 10 MPa. The reference is the largest
//!   pressure the rig itself can make: the supply, plus the pressure the largest imposed
//!   force makes on the smaller piston area (a load force blocked by the oil), plus the
//!   pressure peak of the moving mass stopped by the oil at the speed the fully open valve
//!   gives at the supply pressure (a mass m at speed v on the oil spring k_h = β·A²/V peaks
//!   at v·√(m·k_h) = v·A·√(m·β/V); the oil spring and the load mass as in Merritt,
//!   "Hydraulic Control Systems", 1967, ch. 5; with the largest bulk modulus and the smaller
//!   dead volume). The imposed forces are the
//!   excitation's |F₀| + |F_A| and the load spring's preload at the initial position;
//!   configured initial chamber pressures raise the reference to themselves;
//! - pressure below the cavitation floor (`fluid.cavitation_pressure`, ≥ −1 bar gauge) by
//!   more than 10 MPa, a hundred times the deepest vacuum (−1 bar gauge);
//! - |piston velocity| above the larger of ten times the speed the fully open valve can
//!   feed the smaller piston area at the pressure bound (Q = k·o·φ(Δp) of
//!   `crate::valve::EdgeLaw`) and the speed that crosses the whole stroke in one control
//!   period;
//! - |rod force| above the pressure bound on both piston areas plus the largest imposed
//!   force: more than the cylinder and its load can push.

use crate::params::PlantParams;
use crate::valve::{EdgeLaw, Saturation};
use ehactl_types::PlantState;

/// Pressure bound factor on the reference pressure (-).
const PRESSURE_FACTOR: f64 = 10.0;
/// Pressure margin (Pa) above the reference bound and below the cavitation floor.
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
    /// Largest plausible |rod force| (N).
    pub f_max: f64,
}

impl Plausible {
    /// The bounds of the rig `params` with its edge law `edges` and edge flow limit `limit`
    /// (`valve_saturation`'s component), stepped at `control_dt` (s),
    /// whose oil is at most `beta_max` (Pa) stiff.
    pub fn new(
        params: &PlantParams,
        edges: &EdgeLaw,
        limit: &Saturation,
        control_dt: f64,
        beta_max: f64,
    ) -> Self {
        let cyl = &params.cylinder;
        let smaller = cyl.area_a.min(cyl.area_b);
        let area = if smaller > 0.0 {
            smaller
        } else {
            cyl.area_a.max(cyl.area_b)
        };
        // Piston speed (m/s) of the fully open valve at the pressure drop `dp` (Pa).
        let speed = |dp: f64| {
            let dp = dp - params.supply.tank_pressure + edges.supply_offset;
            edges.edge(limit, 1.0 + edges.underlap, dp).0.abs() / area
        };
        let supply = params.supply.pressure.abs();
        let peak =
            speed(supply) * (moving_mass(params) * beta_max / smallest_volume(params)).sqrt();
        let initial = cyl
            .initial_pressure_a
            .unwrap_or(0.0)
            .abs()
            .max(cyl.initial_pressure_b.unwrap_or(0.0).abs());
        let f_in = imposed_force(params);
        let reference = (supply + f_in / area + peak).max(initial);
        let p_max = PRESSURE_FACTOR * reference + PRESSURE_MARGIN;
        Plausible {
            p_max,
            p_min: params.fluid.cavitation_pressure.min(0.0) - PRESSURE_MARGIN,
            v_max: (VELOCITY_FACTOR * speed(p_max)).max(cyl.stroke / control_dt),
            f_max: p_max * (cyl.area_a + cyl.area_b) + f_in,
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
        if s.rod_force.abs() > self.f_max {
            return Some(("rod_force", s.rod_force, self.f_max, "N"));
        }
        None
    }
}

/// The largest force (N) imposed on the rig from outside its hydraulics: the excitation's
/// |F₀| + |F_A| (`excitation`) plus the load spring's preload at the initial position.
fn imposed_force(params: &PlantParams) -> f64 {
    let e = &params.excitation;
    let excitation = if e.kind == crate::params::ExcitationKind::None {
        0.0
    } else {
        e.offset.abs() + e.amplitude.abs()
    };
    let m = &params.mechanics;
    let preload =
        (m.load_stiffness * (params.cylinder.initial_position - m.load_contact_position)).abs();
    excitation + preload
}

/// The mass (kg) the oil decelerates: the piston's, plus a flexibly mounted load's.
fn moving_mass(params: &PlantParams) -> f64 {
    let mount = params.effects.flexible_mount.as_ref().filter(|m| m.enabled);
    params.mechanics.mass + mount.map_or(0.0, |m| m.load_mass)
}

/// The smaller chamber dead volume (m³), where the oil spring is stiffest.
fn smallest_volume(params: &PlantParams) -> f64 {
    let c = &params.cylinder;
    c.dead_volume_a.min(c.dead_volume_b)
}
