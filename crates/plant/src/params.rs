//! Plant parameters as they appear in a rig config (TOML), in SI units.
//!
//! Each struct is one component; each field carries its unit in the doc comment and
//! in the parameter registry ([`crate::spec::PARAMS`]), which is what error messages,
//! `ehactl params` and the Python bindings read. Effects from the catalogue of
//! `DESIGN.md` live under `[effects.<id>]` and are switched on by their presence
//! (and `enabled = true`, the default).

use serde::{Deserialize, Serialize};

fn yes() -> bool {
    true
}

/// Hydraulic fluid properties.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Fluid {
    /// Density ρ (kg/m³); 003: 900.
    pub density: f64,
    /// Effective bulk modulus β₀ at zero gauge pressure (Pa); 003: K = 1.8e9, 004: 1.75e9.
    pub bulk_modulus: f64,
    /// Kinematic viscosity ν (m²/s), used by line resistance (001 eq. 6–12, 002 eq. 9–17).
    #[serde(default = "Fluid::default_viscosity")]
    pub kinematic_viscosity: f64,
    /// Cavitation floor for chamber pressures (Pa, gauge); pressures never fall below it.
    #[serde(default = "Fluid::default_cavitation")]
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
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Supply {
    /// Supply pressure p_s (Pa); 003: p₀ = 24 MPa.
    pub pressure: f64,
    /// Tank (return) pressure p_T (Pa).
    #[serde(default)]
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
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Valve {
    /// Command that drives the spool to full opening (V); spool target = u / command_full_scale.
    pub command_full_scale: f64,
    /// Flow law of each metering edge.
    pub flow_form: FlowForm,
    /// Underlap per edge as a fraction of full spool travel (-); 003: z₀/z_n = 2.16/6.
    #[serde(default)]
    pub underlap: f64,
    /// Discharge coefficient C_d (-) for `orifice`; 003: 0.56.
    #[serde(default)]
    pub discharge_coefficient: Option<f64>,
    /// Metering area at full opening (m²) for `orifice`.
    #[serde(default)]
    pub area_max: Option<f64>,
    /// Rated flow per edge at full opening (m³/s) for `kq`; 003: 35 L/min.
    #[serde(default)]
    pub rated_flow: Option<f64>,
    /// Pressure drop per edge at which `rated_flow` is given (Pa) for `kq`; 003: 1 MPa.
    #[serde(default)]
    pub rated_pressure_drop: Option<f64>,
    /// Flow per edge at full opening and P_d = 1 MPa (m³/s) for `power_law`; 004 eq. 20: 1.4075e-4.
    #[serde(default)]
    pub flow_at_1mpa: Option<f64>,
    /// Exponent n of the power law (-) for `power_law`; 004 eq. 20: 0.4667.
    #[serde(default)]
    pub exponent: Option<f64>,
    /// Pressure offset P_o added to each edge's Δp (Pa) for `power_law`; 004 eq. 22: 1.1157 MPa.
    #[serde(default)]
    pub pressure_offset: Option<f64>,
    /// Pressure drop below which each edge flow is regularised to laminar (Pa).
    #[serde(default = "Valve::default_laminar")]
    pub laminar_pressure: f64,
}

impl Valve {
    fn default_laminar() -> f64 {
        2.0e4
    }
}

/// Asymmetric double-acting cylinder (003 eq. 7–8, 004 eq. 9–10).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Cylinder {
    /// Piston area on the A (cap) side A₁ (m²).
    pub area_a: f64,
    /// Annulus area on the B (rod) side A₂ (m²).
    pub area_b: f64,
    /// Dead volume of chamber A incl. hose to the valve V₁₀ (m³).
    pub dead_volume_a: f64,
    /// Dead volume of chamber B V₂₀ (m³).
    pub dead_volume_b: f64,
    /// Stroke h (m); position x ∈ [0, stroke].
    pub stroke: f64,
    /// Initial piston position x₀ (m).
    #[serde(default)]
    pub initial_position: f64,
    /// Initial pressure in chamber A (Pa); default: 003 eq. 14 balance.
    #[serde(default)]
    pub initial_pressure_a: Option<f64>,
    /// Initial pressure in chamber B (Pa); default: 003 eq. 14 balance.
    #[serde(default)]
    pub initial_pressure_b: Option<f64>,
}

/// Rigid-body mechanics of the piston (and rigidly attached load).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Mechanics {
    /// Moving mass m (kg): piston + rod (+ load for a rigid connection); 004: 0.893.
    pub mass: f64,
    /// Viscous damping d_y (N·s/m); 003: 2500, 004: C = 10.587.
    #[serde(default)]
    pub damping: f64,
    /// Stiffness of a spring to ground, e.g. load cell + frame K_L (N/m); 0 = none; 004: 4.83e8.
    #[serde(default)]
    pub load_stiffness: f64,
    /// Piston position at which the spring to ground is relaxed (m).
    #[serde(default)]
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
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct Excitation {
    /// Excitation kind.
    #[serde(default)]
    pub kind: ExcitationKind,
    /// Constant part F₀ (N); 003: 2500.
    #[serde(default)]
    pub offset: f64,
    /// Amplitude F_A (N) of the harmonic or pulse height of the impact.
    #[serde(default)]
    pub amplitude: f64,
    /// Frequency f_e (Hz) of the harmonic; 003: 21.8.
    #[serde(default)]
    pub frequency: f64,
    /// Blows per minute of the impact train (1/min); 003 eq. 17: f_e = f_rb/60.
    #[serde(default)]
    pub blows_per_minute: f64,
    /// Duration of each impact pulse (s).
    #[serde(default)]
    pub pulse_duration: f64,
    /// Time at which the excitation starts (s).
    #[serde(default)]
    pub start_time: f64,
}

/// `friction`: Stribeck seal friction with stick (003 eq. 5, 004 eq. 28–34).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Friction {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Breakaway (static) friction F_s (N); 004: 44.
    pub static_force: f64,
    /// Coulomb friction F_C (N); 004: 39, 003: 500.
    pub coulomb_force: f64,
    /// Stribeck velocity v_s (m/s): (F_s − F_C) decays as exp(−(|v|/v_s)²).
    #[serde(default = "Friction::default_vs")]
    pub stribeck_velocity: f64,
    /// Additional viscous friction (N·s/m), on top of `mechanics.damping`.
    #[serde(default)]
    pub viscous: f64,
}

impl Friction {
    fn default_vs() -> f64 {
        0.01
    }
}

/// `valve_deadband`: spool overlap (dead zone) and zero offset (002: 42 %, 004: 0.0375 V).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveDeadband {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Overlap per edge as a fraction of full spool travel (-).
    #[serde(default)]
    pub overlap: f64,
    /// Zero offset of the spool as a fraction of full travel (-), signed.
    #[serde(default)]
    pub zero_offset: f64,
}

/// `valve_saturation`: spool travel limit and/or edge flow limit (002: 87 %).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveSaturation {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Maximum spool opening as a fraction of full travel (-), 0 < limit ≤ 1.
    #[serde(default = "ValveSaturation::one")]
    pub spool_limit: f64,
    /// Maximum flow through any one edge (m³/s); 0 = unlimited.
    #[serde(default)]
    pub max_flow: f64,
}

impl ValveSaturation {
    fn one() -> f64 {
        1.0
    }
}

/// `valve_dynamics`: spool dynamics, PT1 (003 eq. 1) or second order (004 eq. 1, 000).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveDynamics {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Order of the spool model: 1 (PT1) or 2.
    pub order: u8,
    /// PT1 time constant T_z (s) for order 1; 003: 0.01.
    #[serde(default)]
    pub time_constant: f64,
    /// Natural frequency ω_nv (rad/s) for order 2; 004: 1507.9.
    #[serde(default)]
    pub natural_frequency: f64,
    /// Damping ratio ζ (-) for order 2; 004: 0.59.
    #[serde(default)]
    pub damping_ratio: f64,
}

/// `internal_leakage` / `external_leakage`: laminar leakage (003 eq. 1 k_l, k_le; 004 C_in).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Leakage {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Leakage coefficient (m³/(s·Pa)).
    pub coefficient: f64,
}

/// `bulk_modulus_pressure`: β(p) = β₀ + K_b·p, capped at `max` (002 eq. 35).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BulkModulusPressure {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Pressure slope K_b (-): dβ/dp.
    pub slope: f64,
    /// Upper bound on β (Pa).
    #[serde(default = "BulkModulusPressure::default_max")]
    pub max: f64,
}

impl BulkModulusPressure {
    fn default_max() -> f64 {
        2.2e9
    }
}

/// `line_dynamics`: lumped R-L-C segments between valve ports and chambers (002 eq. 9–17).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LineDynamics {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Line length per side (m).
    pub length: f64,
    /// Inner diameter (m).
    pub diameter: f64,
    /// Number of lumped segments per side (-).
    pub segments: u32,
    /// Effective bulk modulus of the line incl. hose wall compliance (Pa); default: fluid β₀.
    #[serde(default)]
    pub bulk_modulus: Option<f64>,
    /// Lumped oil volume at the valve-side node of each line (m³), default 0: valve port and
    /// manifold passages, or (001 eq. 14–15) a pumping chamber with its piezo-stack compliance
    /// as an equivalent volume a_p·Δ_gap + β·a_p²/k_p. Compressed with the fluid β₀.
    #[serde(default)]
    pub port_volume: f64,
    /// Wall-friction model of the segments (default `steady`, Hagen–Poiseuille only).
    #[serde(default)]
    pub friction: LineFriction,
}

/// Wall friction of a `line_dynamics` segment (laminar flow).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum LineFriction {
    /// Steady Hagen–Poiseuille resistance R = 128μℓ/(πd⁴) with plug-flow inertance ρℓ/A
    /// (002 eq. 9–17).
    #[default]
    Steady,
    /// Frequency-dependent (unsteady) laminar friction: Zielke's (1968) weighting-function
    /// convolution, W(τ) = Σₖ exp(−j²₂,ₖ τ) over the zeros of J₂, with the first two modes
    /// exact and the higher ones lumped per octave of mode number (8 states per segment);
    /// propagation constant within 0.08 % (series impedance within 0.16 %) of the exact
    /// Bessel-function line (001 eq. 6–8) for ω·r²/ν ≤ 3·10⁴. See [`crate::line`].
    Unsteady,
    /// As `unsteady` with Trikha's (1975) three-term fit of W (m = 40, 8.1, 1;
    /// n = 8000, 200, 26.4): cheaper, ≈ 1 % off the exact impedance near ω·r²/ν ≈ 10²–10³.
    UnsteadyTrikha,
}

impl LineFriction {
    /// Config spelling of each model.
    pub const NAMES: &'static [&'static str] = &["steady", "unsteady", "unsteady_trikha"];
}

/// `flexible_mount`: spring-damper (SDD) from rod to a load mass (003 eq. 1).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FlexibleMount {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Load mass m_L (kg); 003: 250.
    pub load_mass: f64,
    /// SDD stiffness k_m (N/m); 003 range 1e4–1e5.
    pub stiffness: f64,
    /// SDD damping d_m (N·s/m); 003 range 1e4–2.5e4.
    pub damping: f64,
}

/// `time_delay`: transport / communication delay on the valve command.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TimeDelay {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Delay (s).
    pub delay: f64,
}

/// Sensor channel a tone is added to.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SensorChannel {
    /// Load cell force (N).
    Force,
    /// Piston position (m).
    Position,
    /// Chamber A pressure (Pa).
    PressureA,
    /// Chamber B pressure (Pa).
    PressureB,
}

/// `sensor_tone`: periodic disturbance on a sensor (004: 225 Hz and 420 Hz on the load cell).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SensorTone {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Channel the tones are added to.
    #[serde(default = "SensorTone::default_channel")]
    pub channel: SensorChannel,
    /// Tone frequencies (Hz).
    pub frequencies: Vec<f64>,
    /// Tone amplitudes in the channel's unit (N, m or Pa), one per frequency.
    pub amplitudes: Vec<f64>,
}

impl SensorTone {
    fn default_channel() -> SensorChannel {
        SensorChannel::Force
    }
}

/// `supply_pressure_drop`: supply sags with flow, p_s → p_s0 − R·Q_s with time constant τ (000).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SupplyPressureDrop {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Flow resistance R (Pa·s/m³).
    pub resistance: f64,
    /// Time constant τ of the supply (accumulator / pump) (s).
    pub time_constant: f64,
}

/// The effect catalogue of DESIGN.md: every section is optional.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct Effects {
    /// `friction`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction: Option<Friction>,
    /// `valve_deadband`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub valve_deadband: Option<ValveDeadband>,
    /// `valve_saturation`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub valve_saturation: Option<ValveSaturation>,
    /// `valve_dynamics`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub valve_dynamics: Option<ValveDynamics>,
    /// `internal_leakage`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub internal_leakage: Option<Leakage>,
    /// `external_leakage`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub external_leakage: Option<Leakage>,
    /// `bulk_modulus_pressure`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bulk_modulus_pressure: Option<BulkModulusPressure>,
    /// `line_dynamics`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub line_dynamics: Option<LineDynamics>,
    /// `flexible_mount`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flexible_mount: Option<FlexibleMount>,
    /// `time_delay`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_delay: Option<TimeDelay>,
    /// `sensor_tone`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor_tone: Option<SensorTone>,
    /// `supply_pressure_drop`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub supply_pressure_drop: Option<SupplyPressureDrop>,
    /// `counterbalance_valve`: a circuit component (002 fig. 2), not a catalogue effect
    /// (see [`crate::cbv`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub counterbalance_valve: Option<crate::cbv::CounterbalanceValve>,
    /// `polynomial_force`: a force law on the rod as a sum of declared terms, the grey-box
    /// extension of `ehactl diagnose` (not a catalogue effect, see
    /// [`crate::effects::PolynomialForce`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub polynomial_force: Option<crate::effects::PolynomialForce>,
    /// `polynomial_flow`: a B→A flow law as a sum of declared spool terms, the flow-side
    /// grey-box extension (see [`crate::effects::PolynomialFlow`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub polynomial_flow: Option<crate::effects::PolynomialFlow>,
}

/// Load-cell model.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ForceSensor {
    /// Sensitivity g (V/N); 004: 0.5097e-3.
    #[serde(default = "ForceSensor::default_sens")]
    pub sensitivity: f64,
    /// White noise standard deviation (N).
    #[serde(default)]
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
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct PressureSensor {
    /// White noise standard deviation (Pa).
    #[serde(default)]
    pub noise: f64,
}

/// Magnetostrictive position transducer (003: CANopen TMI).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct PositionSensor {
    /// Resolution (quantisation step) (m); 0 = continuous.
    #[serde(default)]
    pub resolution: f64,
    /// Measurement update period (s); 0 = every control cycle.
    #[serde(default)]
    pub update_period: f64,
    /// White noise standard deviation (m).
    #[serde(default)]
    pub noise: f64,
}

/// Spool position (LVDT) sensor.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct SpoolSensor {
    /// White noise standard deviation (fraction of full travel).
    #[serde(default)]
    pub noise: f64,
}

/// All sensors of the simulated rig.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct Sensors {
    /// Load cell.
    #[serde(default)]
    pub force: ForceSensor,
    /// Chamber pressures.
    #[serde(default)]
    pub pressure: PressureSensor,
    /// Position transducer.
    #[serde(default)]
    pub position: PositionSensor,
    /// Spool position.
    #[serde(default)]
    pub spool: SpoolSensor,
    /// Seed of the sensor noise generator.
    #[serde(default)]
    pub seed: u64,
}

/// Numerical integration settings.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Integration {
    /// Fixed substeps per control period; 0 = automatic from `max_omega_h`.
    #[serde(default)]
    pub substeps: u32,
    /// Largest ω·h (-) allowed for the fastest oscillatory mode when choosing substeps.
    #[serde(default = "Integration::default_omega_h")]
    pub max_omega_h: f64,
    /// Integration scheme of the substep (see [`crate::model`]).
    #[serde(default)]
    pub method: IntegrationMethod,
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

impl IntegrationMethod {
    /// Config spellings.
    pub const NAMES: &'static [&'static str] = &["exponential_euler", "linear_exact"];
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
            method: IntegrationMethod::default(),
        }
    }
}

/// Everything the plant needs.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlantParams {
    /// Fluid.
    pub fluid: Fluid,
    /// Supply.
    pub supply: Supply,
    /// Valve.
    pub valve: Valve,
    /// Cylinder.
    pub cylinder: Cylinder,
    /// Mechanics.
    pub mechanics: Mechanics,
    /// External force.
    #[serde(default)]
    pub excitation: Excitation,
    /// Optional effects.
    #[serde(default)]
    pub effects: Effects,
    /// Sensors.
    #[serde(default)]
    pub sensors: Sensors,
    /// Integration.
    #[serde(default)]
    pub integration: Integration,
}
