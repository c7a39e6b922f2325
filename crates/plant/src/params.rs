//! Plant parameters as they appear in a rig config (TOML), in SI units.
//!
//! Each struct is one component; each field carries its unit in the doc comment and
//! in the parameter registry ([`crate::spec::params`], generated from the `#[param(...)]` declarations below), which is what error messages,
//! `ehactl params` and the Python bindings read. Effects from the catalogue of
//! `docs/design.md` live under `[effects.<id>]` and are switched on by their presence
//! (and `enabled = true`, the default).

use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};
use std::sync::LazyLock;

fn yes() -> bool {
    true
}

/// Hydraulic fluid properties.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Fluid {
    /// Density ρ (kg/m³); 003: 900. At most 2e4 kg/m³: denser than any liquid (mercury
    /// 1.35e4 kg/m³).
    #[param(unit = "kg/m³", range = PositiveAtMost(2.0e4), desc = "fluid density ρ")]
    pub density: f64,
    /// Effective bulk modulus β₀ at zero gauge pressure (Pa); 003: K = 1.8e9, 004: 1.75e9.
    /// At most 1e11 Pa: stiffer than any liquid by 40× (water 2.2e9 Pa) and within the
    /// steel of the cylinder (1.6e11 Pa).
    #[param(unit = "Pa", range = PositiveAtMost(1.0e11), desc = "effective bulk modulus β₀ (003 K, 004 β_e)", uncertain(order = 4, default), estimated)]
    pub bulk_modulus: f64,
    /// Kinematic viscosity ν (m²/s), used by line resistance (001 eq. 6–12, 002 eq. 9–17).
    #[serde(default = "Fluid::default_viscosity")]
    #[param(unit = "m²/s", range = Positive, desc = "kinematic viscosity ν (001 eq. 6–12)")]
    pub kinematic_viscosity: f64,
    /// Cavitation floor for chamber pressures (Pa, gauge); pressures never fall below it.
    #[serde(default = "Fluid::default_cavitation")]
    #[param(unit = "Pa", range = Within(-1.0e5, 0.0), desc = "cavitation floor, gauge")]
    pub cavitation_pressure: f64,
}

impl Fluid {
    fn default_viscosity() -> f64 {
        32e-6
    }
    fn default_cavitation() -> f64 {
        -0.95e5
    }
}

/// Hydraulic supply (gauge pressures).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Supply {
    /// Supply pressure p_s (Pa); 003: p₀ = 24 MPa. At most 1e9 Pa: industrial hydraulics
    /// stop near 70 MPa, pressure intensifiers near 700 MPa.
    #[param(unit = "Pa", range = PositiveAtMost(1.0e9), desc = "supply pressure p_s (003 p₀)", uncertain(order = 11))]
    pub pressure: f64,
    /// Tank (return) pressure p_T (Pa).
    #[serde(default)]
    #[param(unit = "Pa", range = NonNegative, desc = "tank pressure p_T")]
    pub tank_pressure: f64,
}

/// Which metering-edge flow law the valve uses.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum FlowForm {
    /// Orifice equation Q = C_d·A(x)·√(2|Δp|/ρ)·sign(Δp) (002 eq. 1–8, 003 eq. 9).
    Orifice,
    /// Q = K_q·x·√|Δp|·sign(Δp) with K_q = q_vn/(z_n√Δp_n) (003 eq. 9–13).
    Kq,
    /// Q = c·x·(P_d/1 MPa)^n with P_d = Δp + P_o: the K_C(P_d) law of 004 eq. 20–23.
    PowerLaw,
}

/// Four-edge proportional/servo valve (critical or underlapped centre).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Valve {
    /// Command that drives the spool to full opening (V); spool target = u / command_full_scale.
    #[param(unit = "V", range = Positive, desc = "command for full spool opening", uncertain(order = 12))]
    pub command_full_scale: f64,
    /// Flow law of each metering edge.
    pub flow_form: FlowForm,
    /// Underlap per edge as a fraction of full spool travel (-); 003: z₀/z_n = 2.16/6.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 1.0), desc = "underlap per edge, fraction of travel (003 z₀)", uncertain(order = 8, to_range_end))]
    pub underlap: f64,
    /// Discharge coefficient C_d (-) for `orifice`; 003: 0.56.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.01, 1.0), desc = "discharge coefficient C_d (003: 0.56)")]
    pub discharge_coefficient: Option<f64>,
    /// Metering area at full opening (m²) for `orifice`.
    #[serde(default)]
    #[param(unit = "m²", range = Positive, desc = "metering area at full opening", uncertain(order = 2, default, role = flow_gain), estimated)]
    pub area_max: Option<f64>,
    /// Rated flow per edge at full opening (m³/s) for `kq`; 003: 35 L/min.
    #[serde(default)]
    #[param(unit = "m³/s", range = Positive, desc = "rated edge flow q_vn at full opening (003 eq. 13)", uncertain(order = 1, default, role = flow_gain), estimated)]
    pub rated_flow: Option<f64>,
    /// Pressure drop per edge at which `rated_flow` is given (Pa) for `kq`; 003: 1 MPa.
    #[serde(default)]
    #[param(unit = "Pa", range = Positive, desc = "edge pressure drop Δp_n of the rating (003 eq. 13)")]
    pub rated_pressure_drop: Option<f64>,
    /// Flow per edge at full opening and P_d = 1 MPa (m³/s) for `power_law`; 004 eq. 20: 1.4075e-4.
    #[serde(default)]
    #[param(unit = "m³/s", range = Positive, desc = "edge flow at P_d = 1 MPa (004 eq. 20)", uncertain(order = 3, default, role = flow_gain), estimated)]
    pub flow_at_1mpa: Option<f64>,
    /// Exponent n of the power law (-) for `power_law`; 004 eq. 20: 0.4667.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.05, 1.0), desc = "power-law exponent n (004 eq. 20: 0.4667)")]
    pub exponent: Option<f64>,
    /// Pressure offset P_o added to each edge's Δp (Pa) for `power_law`; 004 eq. 22: 1.1157 MPa.
    #[serde(default)]
    #[param(unit = "Pa", range = NonNegative, desc = "pressure offset P_o (004 eq. 22)")]
    pub pressure_offset: Option<f64>,
    /// Pressure drop below which each edge flow is regularised to laminar (Pa).
    #[serde(default = "Valve::default_laminar")]
    #[param(unit = "Pa", range = Positive, desc = "laminar regularisation pressure of each edge")]
    pub laminar_pressure: f64,
}

impl Valve {
    fn default_laminar() -> f64 {
        2.0e4
    }
}

/// Asymmetric double-acting cylinder (003 eq. 7–8, 004 eq. 9–10).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Cylinder {
    /// Piston area on the A (cap) side A₁ (m²). At most 10 m² (a 3.6 m bore, beyond the
    /// largest press cylinders).
    #[param(unit = "m²", range = PositiveAtMost(10.0), desc = "piston area A₁")]
    pub area_a: f64,
    /// Annulus area on the B (rod) side A₂ (m²). At most 10 m², as A₁.
    #[param(unit = "m²", range = PositiveAtMost(10.0), desc = "annulus area A₂")]
    pub area_b: f64,
    /// Dead volume of chamber A incl. hose to the valve V₁₀ (m³).
    #[param(unit = "m³", range = Positive, desc = "dead volume V₁₀", uncertain(order = 9))]
    pub dead_volume_a: f64,
    /// Dead volume of chamber B V₂₀ (m³).
    #[param(unit = "m³", range = Positive, desc = "dead volume V₂₀", uncertain(order = 10))]
    pub dead_volume_b: f64,
    /// Stroke h (m); position x ∈ [0, stroke]. At most 100 m (beyond the longest
    /// telescopic and ship-lift cylinders, ≈ 30 m).
    #[param(unit = "m", range = PositiveAtMost(100.0), desc = "stroke h")]
    pub stroke: f64,
    /// Initial piston position x₀ (m).
    #[serde(default)]
    #[param(unit = "m", range = NonNegative, desc = "initial piston position", estimated)]
    pub initial_position: f64,
    /// Initial pressure in chamber A (Pa); default: 003 eq. 14 balance.
    #[serde(default)]
    #[param(unit = "Pa", range = Finite, desc = "initial chamber A pressure", estimated)]
    pub initial_pressure_a: Option<f64>,
    /// Initial pressure in chamber B (Pa); default: 003 eq. 14 balance.
    #[serde(default)]
    #[param(unit = "Pa", range = Finite, desc = "initial chamber B pressure", estimated)]
    pub initial_pressure_b: Option<f64>,
}

/// Rigid-body mechanics of the piston (and rigidly attached load).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Mechanics {
    /// Moving mass m (kg): piston + rod (+ load for a rigid connection); 004: 0.893. At
    /// most 1e6 kg: a 1000 t load, beyond the heaviest loads hydraulic cylinders move (ship
    /// lifts, heavy presses).
    #[param(unit = "kg", range = PositiveAtMost(1.0e6), desc = "moving mass", uncertain(order = 5, default), estimated)]
    pub mass: f64,
    /// Viscous damping d_y (N·s/m); 003: 2500, 004: C = 10.587.
    #[serde(default)]
    #[param(unit = "N·s/m", range = NonNegative, desc = "viscous damping d_y / C", uncertain(order = 6, default), estimated)]
    pub damping: f64,
    /// Stiffness of a spring to ground, e.g. load cell + frame K_L (N/m); 0 = none; 004: 4.83e8.
    #[serde(default)]
    #[param(unit = "N/m", range = NonNegative, desc = "spring to ground K_L (004 load cell)", uncertain(order = 7, default), estimated)]
    pub load_stiffness: f64,
    /// Piston position at which the spring to ground is relaxed (m).
    #[serde(default)]
    #[param(unit = "m", range = Finite, desc = "position where the ground spring is relaxed")]
    pub load_contact_position: f64,
    /// Hard end stops at x = 0 and x = stroke (inelastic).
    #[serde(default = "yes")]
    pub end_stops: bool,
}

/// Kind of external excitation force.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum ExcitationKind {
    /// No external force.
    #[default]
    None,
    /// F = F₀.
    Constant,
    /// F = F₀ + F_A sin(2π f t) (003 eq. 2).
    Harmonic,
    /// F = F₀ + half-sine pulses of height F_A, `blows_per_minute` per minute (003 eq. 17).
    Impact,
}

/// External force on the rod end (or on the load mass with a flexible mount), opposing +x.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct Excitation {
    /// Excitation kind.
    #[serde(default)]
    pub kind: ExcitationKind,
    /// Constant part F₀ (N); 003: 2500.
    #[serde(default)]
    #[param(unit = "N", range = Finite, desc = "constant force F₀ (003 eq. 2)")]
    pub offset: f64,
    /// Amplitude F_A (N) of the harmonic or pulse height of the impact.
    #[serde(default)]
    #[param(unit = "N", range = NonNegative, desc = "harmonic amplitude / pulse height F_A")]
    pub amplitude: f64,
    /// Frequency f_e (Hz) of the harmonic; 003: 21.8.
    #[serde(default)]
    #[param(unit = "Hz", range = NonNegative, desc = "harmonic frequency f_e")]
    pub frequency: f64,
    /// Blows per minute of the impact train (1/min); 003 eq. 17: f_e = f_rb/60.
    #[serde(default)]
    #[param(unit = "1/min", range = NonNegative, desc = "impact rate (003 eq. 17)")]
    pub blows_per_minute: f64,
    /// Duration of each impact pulse (s).
    #[serde(default)]
    #[param(unit = "s", range = NonNegative, desc = "impact pulse duration")]
    pub pulse_duration: f64,
    /// Time at which the excitation starts (s).
    #[serde(default)]
    #[param(unit = "s", range = NonNegative, desc = "excitation start")]
    pub start_time: f64,
}

// The catalogue effects' sections live in their effect's module (crates/plant/src/effects/,
// with their defaults and cross-field checks); re-exported here so that `crate::params` names
// every config section.
pub use crate::effects::bulk_modulus_pressure::{BulkModulusPressure, BulkVariant};
pub use crate::effects::flexible_mount::{FlexibleMount, MountVariant};
pub use crate::effects::friction::{Friction, FrictionVariant};
pub use crate::effects::leakage::{Leakage, LeakageVariant};
pub use crate::effects::line_dynamics::{LineDynamics, LineFriction, LineVariant};
pub use crate::effects::sensor_tone::{SensorChannel, SensorTone};
pub use crate::effects::supply_pressure_drop::{SupplyPressureDrop, SupplyVariant};
pub use crate::effects::time_delay::TimeDelay;
pub use crate::effects::valve_deadband::{DeadbandVariant, ValveDeadband};
pub use crate::effects::valve_dynamics::ValveDynamics;
pub use crate::effects::valve_saturation::{SaturationVariant, ValveSaturation};

/// The effect catalogue (docs/design.md): every section is optional.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct Effects {
    /// `friction`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub friction: Option<Friction>,
    /// `valve_deadband`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub valve_deadband: Option<ValveDeadband>,
    /// `valve_saturation`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub valve_saturation: Option<ValveSaturation>,
    /// `valve_dynamics`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub valve_dynamics: Option<ValveDynamics>,
    /// `internal_leakage`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested, with(variant(choices = &["equal"], desc = "cross-piston leakage has one coefficient"), coefficient(desc = "cross-piston leakage k_l"), coefficient_b(desc = "not used (cross-piston leakage has one coefficient)")))]
    pub internal_leakage: Option<Leakage>,
    /// `external_leakage`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub external_leakage: Option<Leakage>,
    /// `bulk_modulus_pressure`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub bulk_modulus_pressure: Option<BulkModulusPressure>,
    /// `line_dynamics`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub line_dynamics: Option<LineDynamics>,
    /// `flexible_mount`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub flexible_mount: Option<FlexibleMount>,
    /// `time_delay`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub time_delay: Option<TimeDelay>,
    /// `sensor_tone`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub sensor_tone: Option<SensorTone>,
    /// `supply_pressure_drop`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub supply_pressure_drop: Option<SupplyPressureDrop>,
    /// `counterbalance_valve`: a circuit component (002 fig. 2), not a catalogue effect
    /// (see [`crate::cbv`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub counterbalance_valve: Option<crate::cbv::CounterbalanceValve>,
    /// `polynomial_force`: a force law on the rod as a sum of declared terms, the grey-box
    /// extension of `ehactl diagnose` (not a catalogue effect, see
    /// [`PolynomialForce`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub polynomial_force: Option<PolynomialForce>,
    /// `polynomial_flow`: a B→A flow law as a sum of declared spool terms, the flow-side
    /// grey-box extension (see [`PolynomialFlow`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub polynomial_flow: Option<PolynomialFlow>,
}

/// Load-cell model.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ForceSensor {
    /// Sensitivity g (V/N); 004: 0.5097e-3.
    #[serde(default = "ForceSensor::default_sens")]
    #[param(unit = "V/N", range = Positive, desc = "load cell sensitivity (004: 0.5097 mV/N)")]
    pub sensitivity: f64,
    /// White noise standard deviation (N).
    #[serde(default)]
    #[param(unit = "N", range = NonNegative, desc = "load cell noise σ")]
    pub noise: f64,
}

impl ForceSensor {
    fn default_sens() -> f64 {
        1.0e-3
    }
}

impl Default for ForceSensor {
    fn default() -> Self {
        Self {
            sensitivity: Self::default_sens(),
            noise: 0.0,
        }
    }
}

/// Chamber pressure transducers.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct PressureSensor {
    /// White noise standard deviation (Pa).
    #[serde(default)]
    #[param(unit = "Pa", range = NonNegative, desc = "pressure noise σ")]
    pub noise: f64,
}

/// Magnetostrictive position transducer (003: CANopen TMI).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct PositionSensor {
    /// Resolution (quantisation step) (m); 0 = continuous.
    #[serde(default)]
    #[param(unit = "m", range = NonNegative, desc = "position resolution")]
    pub resolution: f64,
    /// Measurement update period (s); 0 = every control cycle.
    #[serde(default)]
    #[param(unit = "s", range = NonNegative, desc = "position update period")]
    pub update_period: f64,
    /// White noise standard deviation (m).
    #[serde(default)]
    #[param(unit = "m", range = NonNegative, desc = "position noise σ")]
    pub noise: f64,
    /// Half-width (s) of the least-squares derivative that turns this sensor's recorded
    /// position into a velocity where the velocity is not measured: an imposed-motion replay
    /// (`ehactl predict`, a campaign diagnosis, which chooses it and writes it here); 0 = ±2 ms.
    #[serde(default, skip_serializing_if = "is_zero")]
    #[param(unit = "s", range = Within(0.0, 1.0), desc = "half-width of the derivative turning recorded x into v (imposed motion; 0 = 2 ms)")]
    pub velocity_window: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// Spool position (LVDT) sensor.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct SpoolSensor {
    /// White noise standard deviation (fraction of full travel).
    #[serde(default)]
    #[param(unit = "-", range = NonNegative, desc = "spool position noise σ")]
    pub noise: f64,
}

/// All sensors of the simulated rig.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct Sensors {
    /// Load cell.
    #[serde(default)]
    #[param(nested)]
    pub force: ForceSensor,
    /// Chamber pressures.
    #[serde(default)]
    #[param(nested)]
    pub pressure: PressureSensor,
    /// Position transducer.
    #[serde(default)]
    #[param(nested)]
    pub position: PositionSensor,
    /// Spool position.
    #[serde(default)]
    #[param(nested)]
    pub spool: SpoolSensor,
    /// Seed of the sensor noise generator.
    #[serde(default)]
    #[param(unit = "-", range = NonNegative, desc = "noise seed")]
    pub seed: u64,
}

/// Numerical integration settings.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Integration {
    /// Fixed substeps per control period; 0 = automatic from `max_omega_h`.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 100000.0), desc = "substeps per control period (0 = auto)")]
    pub substeps: u32,
    /// Largest ω·h (-) allowed for the fastest oscillatory mode when choosing substeps.
    #[serde(default = "Integration::default_omega_h")]
    #[param(unit = "-", range = Within(0.01, 1.5), desc = "largest ω·h for automatic substeps")]
    pub max_omega_h: f64,
    /// Largest ω·h (-) for the line segment modes of the `symplectic` line scheme (the
    /// segment mode 2/√(LC) and the last segment against the chamber): a *stability* margin
    /// (the scheme is stable for ω·h < 2, without amplitude error; these modes are the
    /// lumping's numerical modes, far above the line's physical ones); default: `max_omega_h`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(unit = "-", range = Within(0.01, 1.9), desc = "largest ω·h for the line segment modes (symplectic line scheme; default max_omega_h)")]
    pub max_omega_h_line: Option<f64>,
    /// Integration scheme of the substep (see [`crate::model`]).
    #[serde(default)]
    #[param(
        choice,
        desc = "substep scheme: exponential_euler (default) or linear_exact (chambers + mechanics \
         discretised exactly; exponential_euler is used with lines, friction or polynomial effects)"
    )]
    pub method: IntegrationMethod,
    /// Integration of the `line_dynamics` segment chains (see [`crate::line`]).
    #[serde(default)]
    #[param(
        choice,
        desc = "line segment scheme: symplectic (default; the segment mode 2/√(LC) enters the \
         ω·h rule) or implicit (trapezoidal chain solved per substep; only the line's wave \
         mode and the chambers set the substep; not with counterbalance_valve)"
    )]
    pub line_method: LineMethod,
}

/// Integration of the lumped line segments ([`crate::line`] explains both).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum LineMethod {
    /// Nodes from the old flows, flows from the new pressures (symplectic Euler, R
    /// implicit): stable for ω·h < 2, so the highest segment mode 2/√(LC) sets the substep.
    #[default]
    Symplectic,
    /// Trapezoidal rule on the whole chain (valve node, segments, chamber) as one
    /// tridiagonal system per substep: unconditionally stable, energy-conserving without
    /// friction; the substep resolves the line's half-wave mode π/T instead of 2/√(LC).
    Implicit,
}

/// Integration scheme of one substep ([`crate::model`] explains both).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum IntegrationMethod {
    /// Exponential Euler per pressure node, symplectic Euler mechanics (first order).
    #[default]
    ExponentialEuler,
    /// Chambers, piston (and load mass) as one linear system discretised exactly per substep,
    /// valve flow at the mid-step spool position; rigs with lines, friction or the polynomial
    /// grey-box effects run `exponential_euler` instead.
    LinearExact,
}

impl Integration {
    fn default_omega_h() -> f64 {
        0.25
    }
}

impl Default for Integration {
    fn default() -> Self {
        Self {
            substeps: 0,
            max_omega_h: Self::default_omega_h(),
            max_omega_h_line: None,
            method: IntegrationMethod::default(),
            line_method: LineMethod::default(),
        }
    }
}

/// Everything the plant needs.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlantParams {
    /// Fluid.
    #[param(nested)]
    pub fluid: Fluid,
    /// Supply.
    #[param(nested)]
    pub supply: Supply,
    /// Valve.
    #[param(nested)]
    pub valve: Valve,
    /// Cylinder.
    #[param(nested)]
    pub cylinder: Cylinder,
    /// Mechanics.
    #[param(nested)]
    pub mechanics: Mechanics,
    /// External force.
    #[serde(default)]
    #[param(nested)]
    pub excitation: Excitation,
    /// Optional effects.
    #[serde(default)]
    #[param(nested)]
    pub effects: Effects,
    /// Sensors.
    #[serde(default)]
    #[param(nested)]
    pub sensors: Sensors,
    /// Integration.
    #[serde(default)]
    #[param(nested)]
    pub integration: Integration,
    /// Stated uncertainty of nominal parameters (`[uncertainty]`, dotted path → "15%" or an
    /// absolute number in the parameter's SI unit): the bounds within which `ehactl diagnose`
    /// refits them. See [`UNCERTAIN_PARAMS`]; unlisted defaults are ±15 %.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub uncertainty: std::collections::BTreeMap<String, Uncertainty>,
}

/// Stated uncertainty of one nominal parameter.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum Uncertainty {
    /// ± this amount in the parameter's SI unit.
    Absolute(f64),
    /// ± this percentage of the nominal value, written like `"15%"`.
    Relative(String),
}

/// Nominal parameters whose uncertainty a config may state (registry paths, in the order
/// the diagnosis refits them), and whether the diagnosis refits them by default
/// (±[`DEFAULT_UNCERTAINTY`]) when the config is silent: the valve's flow gain (the one of
/// its `flow_form`), β₀, mass, damping and load stiffness (the last two when nonzero). The
/// others are refit only when listed. Units, ranges and meanings are the registry's
/// ([`crate::spec::params`]).
///
/// The last five are the loop's assumptions when the rig's controller and valve electronics
/// are not recorded (the valve's bandwidth, the loop's transport delay, the valve's null
/// offset and null dead band; with a proportional loop its gain is the valve flow gain's, which is already
/// here): an effect section the config carries with its assumed nominal value, refit within
/// the stated range like any other nominal parameter (DIAGNOSIS.md "Assumed loop").
///
/// Read from the declarations: each entry is a float field declared with
/// `#[param(…, uncertain(order = N, default, to_range_end))]` ([`crate::spec::Uncertain`]),
/// in ascending `order`.
pub static UNCERTAIN_PARAMS: LazyLock<Vec<(&'static str, bool)>> = LazyLock::new(|| {
    let mut v: Vec<(u16, &'static str, bool)> = crate::spec::params()
        .iter()
        .filter_map(|p| p.uncertain.map(|u| (u.order, p.path, u.default)))
        .collect();
    v.sort_by_key(|e| e.0);
    v.into_iter()
        .map(|(_, path, default)| (path, default))
        .collect()
});

/// Whether the refit range of an [`UNCERTAIN_PARAMS`] path may reach the lower end of its
/// registry range (0 for an underlap, a time constant or a delay; a signed null offset may
/// change sign; declared `to_range_end`): the range is clamped there instead of refused.
/// Every other one must stay > 0.
fn may_reach_range_end(path: &str) -> bool {
    crate::spec::params()
        .iter()
        .find(|p| p.path == path)
        .and_then(|p| p.uncertain)
        .is_some_and(|u| u.to_range_end)
}

/// Admissible range of a registry path (`Finite` for a path the registry does not know,
/// which no [`UNCERTAIN_PARAMS`] entry is).
fn registry_range(path: &str) -> crate::spec::Range {
    crate::spec::params()
        .iter()
        .find(|p| p.path == path)
        .map_or(crate::spec::Range::Finite, |p| p.range)
}

/// SI unit of a registry path ("-" for a path the registry does not know, which no
/// [`UNCERTAIN_PARAMS`] entry is).
fn registry_unit(path: &str) -> &'static str {
    crate::spec::params()
        .iter()
        .find(|p| p.path == path)
        .map_or("-", |p| p.unit)
}

/// Relative uncertainty assumed for a default-refit nominal parameter the config is silent
/// about (-).
pub const DEFAULT_UNCERTAINTY: f64 = 0.15;

impl PlantParams {
    /// Value of an [`UNCERTAIN_PARAMS`] path (`None` for another path or a flow-gain path
    /// not used by this valve's `flow_form`), read through the declared-parameter accessor.
    pub fn nominal_value(&self, path: &str) -> Option<f64> {
        let form = match path {
            "valve.rated_flow" => Some(FlowForm::Kq),
            "valve.area_max" => Some(FlowForm::Orifice),
            "valve.flow_at_1mpa" => Some(FlowForm::PowerLaw),
            _ => None,
        };
        if form.is_some_and(|f| f != self.valve.flow_form)
            || !UNCERTAIN_PARAMS.iter().any(|u| u.0 == path)
        {
            return None;
        }
        crate::spec::ParamTree::get_path(self, path)
    }

    /// Why an `[uncertainty]` key on an effect's parameter cannot be refit: its section is
    /// switched off, or it is declared for another model order than the section's
    /// (`needs_order` in its `uncertain(…)`: a spool's bandwidth is a time constant at order
    /// 1, a natural frequency at order 2); `None` when it fits or the section is absent.
    fn spool_order_mismatch(&self, path: &str) -> Option<String> {
        let u = crate::spec::params()
            .iter()
            .find(|p| p.path == path)?
            .uncertain?;
        let (section, _) = path.strip_prefix("effects.")?.rsplit_once('.')?;
        if !self.section_switch(section)? {
            return Some(format!("[effects.{section}] has enabled = false; a switched-off effect is not refit (remove the switch or the uncertainty)"));
        }
        let want = u.needs_order?;
        let order = self.section_order(section)?;
        (order != want).then(|| {
            // The parameter declared for the configured order.
            let fits = crate::spec::params()
                .iter()
                .filter(|p| p.path.starts_with(&format!("effects.{section}.")))
                .find(|p| p.uncertain.is_some_and(|q| q.needs_order == Some(order)))
                .map_or("", |p| p.path);
            format!(
                "the spool model is order {order}; its bandwidth is {fits} (order 1: time_constant in s, order 2: natural_frequency in rad/s)"
            )
        })
    }

    /// The model order effect section `section` is configured with, for the one section that
    /// has one.
    fn section_order(&self, section: &str) -> Option<u8> {
        (section == "valve_dynamics")
            .then(|| self.effects.valve_dynamics.as_ref().map(|d| d.order))
            .flatten()
    }

    /// The `enabled` switch of catalogue section `section` (its field name in [`Effects`]),
    /// `None` when the section is absent. (`Effects::is_enabled` in crates/plant/src/effects
    /// answers by `EffectId`, which this file does not use: that module uses this one.)
    fn section_switch(&self, section: &str) -> Option<bool> {
        macro_rules! switch {
            ($($f:ident),*) => {
                match section {
                    $(stringify!($f) => self.effects.$f.as_ref().map(|s| s.enabled),)*
                    _ => None,
                }
            };
        }
        switch!(
            friction,
            valve_deadband,
            valve_saturation,
            valve_dynamics,
            internal_leakage,
            external_leakage,
            bulk_modulus_pressure,
            line_dynamics,
            flexible_mount,
            time_delay,
            sensor_tone,
            supply_pressure_drop
        )
    }

    /// The refit range of every nominal parameter the diagnosis refits: (path, nominal value,
    /// lower bound, upper bound) in SI units, from `[uncertainty]` and the defaults; a stated
    /// uncertainty of 0 keeps the parameter fixed. Errors name the `[uncertainty]` key.
    pub fn refit_ranges(
        &self,
    ) -> Result<Vec<(&'static str, f64, f64, f64)>, crate::spec::ConfigError> {
        use crate::spec::ConfigError;
        let key = |k: &str| format!("uncertainty.\"{k}\"");
        self.check_uncertainty_keys()?;
        let mut out = Vec::new();
        for &(path, default) in UNCERTAIN_PARAMS.iter() {
            let Some(v) = self.nominal_value(path) else {
                continue;
            };
            let unit = registry_unit(path);
            let half = match self.uncertainty.get(path) {
                None if default && v > 0.0 => DEFAULT_UNCERTAINTY * v,
                None => continue,
                Some(Uncertainty::Absolute(a)) => {
                    if !(a.is_finite() && *a >= 0.0) {
                        return Err(ConfigError::new(
                            key(path),
                            format!("absolute uncertainty {a} is not a finite number ≥ 0; expected ± an amount in {unit} or a percentage like \"15%\""),
                        ));
                    }
                    *a
                }
                Some(Uncertainty::Relative(t)) => {
                    let r = t
                        .trim()
                        .strip_suffix('%')
                        .and_then(|x| x.trim().parse::<f64>().ok())
                        .filter(|r| r.is_finite() && (0.0..100.0).contains(r))
                        .ok_or_else(|| {
                            ConfigError::new(
                                key(path),
                                format!("got \"{t}\"; expected a percentage in [0, 100) like \"15%\", or an absolute number in {unit}"),
                            )
                        })?;
                    if v == 0.0 && r > 0.0 {
                        return Err(ConfigError::new(
                            key(path),
                            format!("the nominal value is 0, so a relative uncertainty is meaningless; state an absolute one in {unit}"),
                        ));
                    }
                    r / 100.0 * v.abs()
                }
            };
            if half == 0.0 {
                continue;
            }
            // Physical parameters stay > 0 (an underlap, a delay or a time constant may reach
            // 0, a null offset may change sign: clamped to the registry's range).
            let (lo, hi) = (v - half, v + half);
            if may_reach_range_end(path) {
                let (r_lo, r_hi) = match registry_range(path) {
                    crate::spec::Range::Within(a, b) => (a, b),
                    crate::spec::Range::NonNegative | crate::spec::Range::Positive => {
                        (0.0, f64::INFINITY)
                    }
                    crate::spec::Range::PositiveAtMost(b) => (0.0, b),
                    crate::spec::Range::Finite => (f64::NEG_INFINITY, f64::INFINITY),
                };
                out.push((path, v, lo.max(r_lo), hi.min(r_hi)));
            } else if lo <= 0.0 {
                return Err(ConfigError::new(
                    key(path),
                    format!("± {half} {unit} around the nominal {v} {unit} reaches 0 or below; expected less than the nominal value"),
                ));
            } else {
                out.push((path, v, lo, hi));
            }
        }
        Ok(out)
    }

    /// Every `[uncertainty]` key names a parameter the diagnosis refits and this config uses
    /// (its effect's section present, its spool order and flow form the ones that have it).
    /// Errors name the key.
    fn check_uncertainty_keys(&self) -> Result<(), crate::spec::ConfigError> {
        use crate::spec::ConfigError;
        let key = |k: &str| format!("uncertainty.\"{k}\"");
        for k in self.uncertainty.keys() {
            match UNCERTAIN_PARAMS.iter().find(|u| u.0 == k) {
                None => {
                    return Err(ConfigError::new(
                        key(k),
                        format!(
                            "not a parameter whose uncertainty can be stated; expected one of: {}",
                            UNCERTAIN_PARAMS.iter().map(|u| u.0).collect::<Vec<_>>().join(", ")
                        ),
                    ))
                }
                Some(_) if self.nominal_value(k).is_none() && k.starts_with("effects.") => {
                    let section = k.rsplit_once('.').map_or(k.as_str(), |s| s.0);
                    return Err(ConfigError::new(
                        key(k),
                        format!("the config has no [{section}] section; add it with the assumed nominal value (e.g. 0 for a delay or a null offset) to state how uncertain that value is"),
                    ));
                }
                Some(_) if self.spool_order_mismatch(k).is_some() => {
                    return Err(ConfigError::new(
                        key(k),
                        self.spool_order_mismatch(k).unwrap_or_default(),
                    ));
                }
                Some(_) if self.nominal_value(k).is_none() => {
                    return Err(ConfigError::new(
                        key(k),
                        "this valve's flow_form does not use the parameter (or it is not set); state the uncertainty of its own flow gain (kq: valve.rated_flow, orifice: valve.area_max, power_law: valve.flow_at_1mpa)",
                    ))
                }
                Some(_) => {}
            }
        }
        Ok(())
    }
}

/// `polynomial_force`: a force on the rod between piston and ground, written as a short
/// sum of declared terms on physical states. It is what `ehactl diagnose` writes when it
/// extends a model beyond the catalogue (grey-box extension, DIAGNOSIS.md), and it can also
/// state a known load law in a nominal config (e.g. the Bingham model of an MR damper,
/// Stanway et al. 1987: F = c₀·v + F_y·sign(v) + F₀, with F₀ the accumulator preload):
///
/// F = F₀ + c_v·v + F_c·tanh(v/v_s) + c_q·|v|·v + k·(x − x₀) + A_p·(p_a − p_b)
///     + A_c·tanh(v/v_s)·|p_a − p_b| + F_d·z,   dz/dt = (r − |r|·z)/δ,  r = v − V·z
///
/// The last term is Dahl's solid-friction model with exponent 1 (Dahl, "A solid friction
/// model", Aerospace Corp. TOR-0158(3107-18)-1, 1968), used for MR dampers with a viscous
/// term by Ikhouane & Dyke (Smart Mater. Struct. 16(3):605–616, 2007): a yield force F_d that
/// builds up over a pre-yield travel δ after each reversal (pre-yield stiffness F_d/δ) instead
/// of following the sign of the velocity at once; z ∈ [−1, 1] is a state of the plant. With
/// V > 0 (`dahl_velocity`) the element is driven by v − V·z: a dashpot in series with it, as
/// in the modified Bouc–Wen model of Spencer, Dyke, Sain & Carlson (J. Eng. Mech.
/// 123(3):230–238, 1997), where it gives the roll-off of the force at low velocity; at steady
/// velocity the force is F_d·clamp(v/V, −1, 1), a bi-viscous law of pre-yield slope F_d/V.
///
/// F opposes +x on the piston and is carried by the rod, so a load cell sees it (it is added
/// to the rod force). All coefficients default to 0 (term absent). The sign is smoothed by
/// tanh with `smoothing_velocity` so that the velocity update can treat the term implicitly.
#[derive(Params, Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PolynomialForce {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Constant force F₀ (N), e.g. the gas preload of a damper's accumulator.
    #[serde(default)]
    #[param(unit = "N", range = Finite, desc = "constant rod force F₀ (opposing +x), e.g. a damper's gas preload")]
    pub constant: f64,
    /// Viscous coefficient c_v (N·s/m) of the term c_v·v.
    #[serde(default)]
    #[param(unit = "N·s/m", range = Finite, desc = "viscous rod force coefficient c_v of c_v·v")]
    pub viscous: f64,
    /// Coulomb / yield force F_c (N) of the term F_c·tanh(v/v_s).
    #[serde(default)]
    #[param(unit = "N", range = Finite, desc = "Coulomb / yield force F_c of F_c·sign(v) (Bingham model)")]
    pub coulomb: f64,
    /// Quadratic (turbulent) damping c_q (N·s²/m²) of the term c_q·|v|·v.
    #[serde(default)]
    #[param(unit = "N·s²/m²", range = Finite, desc = "quadratic damping c_q of c_q·|v|·v")]
    pub quadratic: f64,
    /// Stiffness k (N/m) of the term k·(x − x₀).
    #[serde(default)]
    #[param(unit = "N/m", range = Finite, desc = "stiffness k of k·(x − origin)")]
    pub stiffness: f64,
    /// Position x₀ (m) at which the stiffness term is zero.
    #[serde(default)]
    #[param(unit = "m", range = Finite, desc = "position at which the stiffness term is zero")]
    pub origin: f64,
    /// Area A_p (m²) of the term A_p·(p_a − p_b): a load-pressure force not in the nominal
    /// areas (area error, pressure-loaded seal).
    #[serde(default)]
    #[param(unit = "m²", range = Finite, desc = "area A_p of the load-pressure force A_p·(p_a − p_b)")]
    pub pressure: f64,
    /// Area A_c (m²) of the term A_c·tanh(v/v_s)·|p_a − p_b|: seal friction growing with
    /// the load pressure (Coulomb force ∝ |Δp|).
    #[serde(default)]
    #[param(unit = "m²", range = Finite, desc = "area A_c of the pressure-dependent friction A_c·sign(v)·|p_a − p_b|")]
    pub pressure_coulomb: f64,
    /// Dahl force F_d (N) of the term F_d·z: the yield force reached after the pre-yield
    /// travel (≥ 0).
    #[serde(default)]
    #[param(unit = "N", range = NonNegative, desc = "Dahl yield force F_d of F_d·z, dz/dt = (v − |v|·z)/δ (pre-yield hysteresis)")]
    pub dahl: f64,
    /// Pre-yield travel δ (m) of the Dahl term: the travel after a reversal over which the
    /// force builds up (1 − 1/e of F_d after δ); the pre-yield stiffness is F_d/δ.
    #[serde(default = "PolynomialForce::default_dahl_travel")]
    #[param(unit = "m", range = Positive, desc = "pre-yield travel δ of the Dahl term (pre-yield stiffness F_d/δ)")]
    pub dahl_travel: f64,
    /// Series-dashpot velocity V (m/s) of the Dahl term: the state is driven by v − V·z
    /// instead of v, so below V the force rolls off to the viscous slope F_d/V with a lag
    /// δ/V (the dashpot c₁ in series with the hysteretic element in the model of Spencer,
    /// Dyke, Sain & Carlson 1997, J. Eng. Mech. 123(3):230–238); 0 is Dahl's law.
    #[serde(default)]
    #[param(unit = "m/s", range = NonNegative, desc = "series-dashpot velocity V of the Dahl term: dz/dt = (r − |r|·z)/δ with r = v − V·z (0: Dahl's law)")]
    pub dahl_velocity: f64,
    /// Bouc–Wen exponent n (-) of the Dahl term: dz/dt = (r − |r|·|z|^(n−1)·z)/δ, the
    /// hysteretic element of Bouc–Wen (Wen 1976, J. Eng. Mech. Div. 102(2):249–263) with
    /// A = β = 1, γ = 0, normalised so that |z| ≤ 1. n = 1 is Dahl's law (the force builds up
    /// exponentially after a reversal); a larger n keeps the pre-yield branch straight for
    /// longer and turns sharply into the yield force (Spencer et al. 1997 fit n = 2).
    #[serde(default = "PolynomialForce::default_dahl_exponent")]
    #[param(unit = "-", range = Within(1.0, 10.0), desc = "Bouc–Wen exponent n of the Dahl term: dz/dt = (r − |r|·|z|^(n−1)·z)/δ (1: Dahl's law)")]
    pub dahl_exponent: f64,
    /// Smoothing velocity v_s (m/s) of the sign terms.
    #[serde(default = "PolynomialForce::default_vs")]
    #[param(unit = "m/s", range = Positive, desc = "smoothing velocity v_s of sign(v) ≈ tanh(v/v_s)")]
    pub smoothing_velocity: f64,
}

/// `polynomial_flow`: a flow from port B to port A (into chamber A, out of chamber B, m³/s)
/// as a short sum of declared terms on the spool position x_v (fraction of travel), the
/// flow-side counterpart of [`PolynomialForce`] for the grey-box extension of
/// `ehactl diagnose`:
///
/// Q = q₀ + q_s·x_v + q_a·|x_v|
///
/// q₀ is a null-bias flow (a spool or torque-motor offset, or a bias in the drive
/// electronics: ISO 10770-1 "null bias"), q_s a flow-gain error, q_a a direction asymmetry of
/// the flow gain (different metering edges for A and B). All default to 0 (term absent).
#[derive(Params, Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PolynomialFlow {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Null-bias flow q₀ (m³/s) from B to A.
    #[serde(default)]
    #[param(unit = "m³/s", range = Finite, desc = "null-bias flow q₀ from port B to port A")]
    pub constant: f64,
    /// Flow-gain error q_s (m³/s per unit spool travel) of the term q_s·x_v.
    #[serde(default)]
    #[param(unit = "m³/s", range = Finite, desc = "flow-gain error q_s of q_s·x_v (x_v: spool, fraction of travel)")]
    pub spool: f64,
    /// Direction asymmetry q_a (m³/s per unit spool travel) of the term q_a·|x_v|.
    #[serde(default)]
    #[param(unit = "m³/s", range = Finite, desc = "direction asymmetry q_a of q_a·|x_v|")]
    pub spool_abs: f64,
}
