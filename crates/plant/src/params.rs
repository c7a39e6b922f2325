//! Plant parameters as they appear in a rig config (TOML), in SI units.
//!
//! Each struct is one component; each field carries its unit in the doc comment and
//! in the parameter registry ([`crate::spec::params`], generated from the `#[param(...)]` declarations below), which is what error messages,
//! `ehactl params` and the Python bindings read. Effects from the catalogue of
//! `docs/design.md` live under `[effects.<id>]` and are switched on by their presence
//! (and `enabled = true`, the default).

use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

fn yes() -> bool {
    true
}

/// Hydraulic fluid properties.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Fluid {
    /// Density ρ (kg/m³); 003: 900.
    #[param(unit = "kg/m³", range = Positive, desc = "fluid density ρ")]
    pub density: f64,
    /// Effective bulk modulus β₀ at zero gauge pressure (Pa); 003: K = 1.8e9, 004: 1.75e9.
    #[param(unit = "Pa", range = Positive, desc = "effective bulk modulus β₀ (003 K, 004 β_e)")]
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
    /// Supply pressure p_s (Pa); 003: p₀ = 24 MPa.
    #[param(unit = "Pa", range = Positive, desc = "supply pressure p_s (003 p₀)")]
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
    #[param(unit = "V", range = Positive, desc = "command for full spool opening")]
    pub command_full_scale: f64,
    /// Flow law of each metering edge.
    pub flow_form: FlowForm,
    /// Underlap per edge as a fraction of full spool travel (-); 003: z₀/z_n = 2.16/6.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 1.0), desc = "underlap per edge, fraction of travel (003 z₀)")]
    pub underlap: f64,
    /// Discharge coefficient C_d (-) for `orifice`; 003: 0.56.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.01, 1.0), desc = "discharge coefficient C_d (003: 0.56)")]
    pub discharge_coefficient: Option<f64>,
    /// Metering area at full opening (m²) for `orifice`.
    #[serde(default)]
    #[param(unit = "m²", range = Positive, desc = "metering area at full opening")]
    pub area_max: Option<f64>,
    /// Rated flow per edge at full opening (m³/s) for `kq`; 003: 35 L/min.
    #[serde(default)]
    #[param(unit = "m³/s", range = Positive, desc = "rated edge flow q_vn at full opening (003 eq. 13)")]
    pub rated_flow: Option<f64>,
    /// Pressure drop per edge at which `rated_flow` is given (Pa) for `kq`; 003: 1 MPa.
    #[serde(default)]
    #[param(unit = "Pa", range = Positive, desc = "edge pressure drop Δp_n of the rating (003 eq. 13)")]
    pub rated_pressure_drop: Option<f64>,
    /// Flow per edge at full opening and P_d = 1 MPa (m³/s) for `power_law`; 004 eq. 20: 1.4075e-4.
    #[serde(default)]
    #[param(unit = "m³/s", range = Positive, desc = "edge flow at P_d = 1 MPa (004 eq. 20)")]
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
    /// Piston area on the A (cap) side A₁ (m²).
    #[param(unit = "m²", range = Positive, desc = "piston area A₁")]
    pub area_a: f64,
    /// Annulus area on the B (rod) side A₂ (m²).
    #[param(unit = "m²", range = Positive, desc = "annulus area A₂")]
    pub area_b: f64,
    /// Dead volume of chamber A incl. hose to the valve V₁₀ (m³).
    #[param(unit = "m³", range = Positive, desc = "dead volume V₁₀")]
    pub dead_volume_a: f64,
    /// Dead volume of chamber B V₂₀ (m³).
    #[param(unit = "m³", range = Positive, desc = "dead volume V₂₀")]
    pub dead_volume_b: f64,
    /// Stroke h (m); position x ∈ [0, stroke].
    #[param(unit = "m", range = Positive, desc = "stroke h")]
    pub stroke: f64,
    /// Initial piston position x₀ (m).
    #[serde(default)]
    #[param(unit = "m", range = NonNegative, desc = "initial piston position")]
    pub initial_position: f64,
    /// Initial pressure in chamber A (Pa); default: 003 eq. 14 balance.
    #[serde(default)]
    #[param(unit = "Pa", range = Finite, desc = "initial chamber A pressure")]
    pub initial_pressure_a: Option<f64>,
    /// Initial pressure in chamber B (Pa); default: 003 eq. 14 balance.
    #[serde(default)]
    #[param(unit = "Pa", range = Finite, desc = "initial chamber B pressure")]
    pub initial_pressure_b: Option<f64>,
}

/// Rigid-body mechanics of the piston (and rigidly attached load).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Mechanics {
    /// Moving mass m (kg): piston + rod (+ load for a rigid connection); 004: 0.893.
    #[param(unit = "kg", range = Positive, desc = "moving mass")]
    pub mass: f64,
    /// Viscous damping d_y (N·s/m); 003: 2500, 004: C = 10.587.
    #[serde(default)]
    #[param(unit = "N·s/m", range = NonNegative, desc = "viscous damping d_y / C")]
    pub damping: f64,
    /// Stiffness of a spring to ground, e.g. load cell + frame K_L (N/m); 0 = none; 004: 4.83e8.
    #[serde(default)]
    #[param(unit = "N/m", range = NonNegative, desc = "spring to ground K_L (004 load cell)")]
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

/// Structural variant of `friction`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum FrictionVariant {
    /// Seal friction on the piston: Stribeck curve with a true stick phase (003 eq. 5,
    /// 004 eq. 28–34).
    #[default]
    Stribeck,
    /// Load-side Coulomb force without stick, F = F_C·tanh(v/v_s) (the smooth Coulomb term of
    /// MR-damper and guide models, e.g. Spencer et al. 1997 without the Bouc–Wen hysteresis);
    /// `stribeck_velocity` is the smoothing velocity v_s, `static_force` is not used.
    LoadCoulomb,
    /// Seal friction with pre-sliding (bristle) dynamics, the LuGre model (Canudas de Wit,
    /// Olsson, Åström & Lischinsky 1995, "A new model for control of systems with friction",
    /// IEEE TAC 40(3):419–425, eq. 1–3): ż = v − σ₀·|v|·z/g(v), F = σ₀·z + σ₁·ż (+ `viscous`·v),
    /// g(v) = F_C + (F_s − F_C)·e^(−(v/v_s)²). Before breakaway the seal is a spring of
    /// stiffness σ₀ (`bristle_stiffness`, pre-sliding displacement ≈ F_C/σ₀) damped by σ₁
    /// (`bristle_damping`); with `static_force` = `coulomb_force` and σ₁ = 0 it is Dahl's
    /// (1968, "A solid friction model", Aerospace Corp. TOR-0158(3107-18)-1) model with
    /// exponent 1, dF/dx = σ₀·(1 − F·sign(v)/F_C). See [`crate::friction`].
    Lugre,
}

/// `friction`: Stribeck seal friction with stick (003 eq. 5, 004 eq. 28–34), a load-side
/// Coulomb force (variant `load_coulomb`) or LuGre / Dahl pre-sliding friction (variant `lugre`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Friction {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`stribeck`, `load_coulomb` or `lugre`).
    #[serde(default)]
    #[param(
        choice,
        desc = "stribeck: seal friction with stick (003 eq. 5, default); load_coulomb: F_C·tanh(v/v_s) \
         without stick (MR damper / guide, Spencer 1997 without hysteresis); lugre: pre-sliding \
         bristle dynamics (Canudas de Wit 1995; Dahl 1968 with F_s = F_C, σ₁ = 0)"
    )]
    pub variant: FrictionVariant,
    /// Breakaway (static) friction F_s (N); 004: 44.
    #[param(unit = "N", range = NonNegative, desc = "breakaway friction F_s (004: 44 N)")]
    pub static_force: f64,
    /// Coulomb friction F_C (N); 004: 39, 003: 500.
    #[param(unit = "N", range = NonNegative, desc = "Coulomb friction F_C (004: 39 N)")]
    pub coulomb_force: f64,
    /// Stribeck velocity v_s (m/s): (F_s − F_C) decays as exp(−(|v|/v_s)²).
    #[serde(default = "Friction::default_vs")]
    #[param(unit = "m/s", range = Positive, desc = "Stribeck velocity")]
    pub stribeck_velocity: f64,
    /// Additional viscous friction (N·s/m), on top of `mechanics.damping`.
    #[serde(default)]
    #[param(unit = "N·s/m", range = NonNegative, desc = "extra viscous friction")]
    pub viscous: f64,
    /// Bristle (pre-sliding) stiffness σ₀ (N/m), variant `lugre`; Canudas de Wit 1995 eq. 2.
    #[serde(default)]
    #[param(unit = "N/m", range = NonNegative, desc = "bristle stiffness σ₀ of the pre-sliding spring (variant lugre)")]
    pub bristle_stiffness: f64,
    /// Bristle damping σ₁ (N·s/m), variant `lugre`; Canudas de Wit 1995 eq. 2.
    #[serde(default)]
    #[param(unit = "N·s/m", range = NonNegative, desc = "bristle damping σ₁ (variant lugre; 0 with F_s = F_C is Dahl 1968)")]
    pub bristle_damping: f64,
}

impl Friction {
    fn default_vs() -> f64 {
        0.01
    }
}

/// Structural variant of `valve_deadband`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum DeadbandVariant {
    /// Spool overlap: each metering edge opens only after `overlap` of travel (002, 004).
    #[default]
    Overlap,
    /// Dead zone of the valve amplifier ahead of the (underlapped) spool: spool target =
    /// sign(c)·max(|c| − `deadzone`, 0) with c = u/full scale + `zero_offset` (the
    /// amplifier's dead-band setting of proportional-valve electronics, e.g. Bosch Rexroth
    /// VT-VRPA1 "dead band compensation" set to 0; 004 models it as a command dead zone).
    Amplifier,
}

/// `valve_deadband`: spool overlap (dead zone) and zero offset (002: 42 %, 004: 0.0375 V), or
/// an amplifier dead zone ahead of the spool (variant `amplifier`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveDeadband {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`overlap` or `amplifier`).
    #[serde(default)]
    #[param(
        choice,
        desc = "overlap: spool overlap (default); amplifier: dead zone of the amplifier ahead of the \
         underlapped spool"
    )]
    pub variant: DeadbandVariant,
    /// Amplifier dead zone as a fraction of the full-scale command (-), variant `amplifier`.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 0.95), desc = "amplifier dead zone, fraction of the full-scale command (variant amplifier)")]
    pub deadzone: f64,
    /// Overlap per edge as a fraction of full spool travel (-).
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 0.95), desc = "overlap per edge, fraction of travel")]
    pub overlap: f64,
    /// Zero offset of the spool as a fraction of full travel (-), signed.
    #[serde(default)]
    #[param(unit = "-", range = Within(-0.5, 0.5), desc = "spool zero offset, fraction of travel")]
    pub zero_offset: f64,
}

/// Structural variant of `valve_saturation`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum SaturationVariant {
    /// The same travel limit in both directions.
    #[default]
    Symmetric,
    /// Different limits for positive (`spool_limit`) and negative (`spool_limit_negative`)
    /// spool travel: asymmetric amplifier clipping or end stops of the spool (002 fig. 6
    /// shows an 87 % limit on one side).
    Asymmetric,
}

/// `valve_saturation`: spool travel limit and/or edge flow limit (002: 87 %).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveSaturation {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`symmetric` or `asymmetric`).
    #[serde(default)]
    #[param(
        choice,
        desc = "symmetric: one spool travel limit (default); asymmetric: spool_limit for + and \
         spool_limit_negative for − travel"
    )]
    pub variant: SaturationVariant,
    /// Limit of negative spool travel as a fraction of full travel (-), variant `asymmetric`.
    #[serde(default = "ValveSaturation::one")]
    #[param(unit = "-", range = Within(0.01, 1.0), desc = "negative spool travel limit, fraction (variant asymmetric)")]
    pub spool_limit_negative: f64,
    /// Maximum spool opening as a fraction of full travel (-), 0 < limit ≤ 1.
    #[serde(default = "ValveSaturation::one")]
    #[param(unit = "-", range = Within(0.01, 1.0), desc = "spool travel limit, fraction")]
    pub spool_limit: f64,
    /// Maximum flow through any one edge (m³/s); 0 = unlimited.
    #[serde(default)]
    #[param(unit = "m³/s", range = NonNegative, desc = "edge flow limit (0 = none)")]
    pub max_flow: f64,
}

impl ValveSaturation {
    fn one() -> f64 {
        1.0
    }
}

/// `valve_dynamics`: spool dynamics, PT1 (003 eq. 1) or second order (004 eq. 1, 000).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveDynamics {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Order of the spool model: 1 (PT1) or 2.
    #[param(unit = "-", range = Within(1.0, 2.0), desc = "spool model order")]
    pub order: u8,
    /// PT1 time constant T_z (s) for order 1; 003: 0.01.
    #[serde(default)]
    #[param(unit = "s", range = NonNegative, desc = "PT1 time constant T_z (003)")]
    pub time_constant: f64,
    /// Natural frequency ω_nv (rad/s) for order 2; 004: 1507.9.
    #[serde(default)]
    #[param(unit = "rad/s", range = Within(0.0, 1.0e6), desc = "spool ω_nv (004: 1507.9)")]
    pub natural_frequency: f64,
    /// Damping ratio ζ (-) for order 2; 004: 0.59.
    #[serde(default)]
    #[param(unit = "-", range = NonNegative, desc = "spool damping ratio ζ (004: 0.59)")]
    pub damping_ratio: f64,
}

/// Structural variant of a leakage.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum LeakageVariant {
    /// One coefficient: across the piston (`internal_leakage`) or from both chambers to tank
    /// with the same coefficient (`external_leakage`).
    #[default]
    Equal,
    /// `external_leakage` only: chamber A leaks with `coefficient`, chamber B with
    /// `coefficient_b` (rod seal vs. a worn port or fitting; one chamber when the other is 0).
    PerChamber,
}

/// `internal_leakage` / `external_leakage`: laminar leakage (003 eq. 1 k_l, k_le; 004 C_in).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Leakage {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`equal` or, external leakage only, `per_chamber`).
    #[serde(default)]
    #[param(
        choice,
        desc = "equal: both chambers leak to tank with `coefficient` (default); per_chamber: A with \
         `coefficient`, B with `coefficient_b`"
    )]
    pub variant: LeakageVariant,
    /// Leakage coefficient (m³/(s·Pa)); chamber A's for `per_chamber`.
    #[param(unit = "m³/(s·Pa)", range = NonNegative, desc = "leakage to tank k_le")]
    pub coefficient: f64,
    /// Chamber B's leakage coefficient to tank (m³/(s·Pa)), variant `per_chamber`.
    #[serde(default)]
    #[param(unit = "m³/(s·Pa)", range = NonNegative, desc = "chamber B leakage to tank (variant per_chamber)")]
    pub coefficient_b: f64,
}

/// Structural variant of `bulk_modulus_pressure`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum BulkVariant {
    /// β(p) = β₀ + K_b·p, capped at `max` (002 eq. 35).
    #[default]
    Linear,
    /// Entrained air compressed polytropically (Yu, Chen & Lu 1994; the "Yu" model of
    /// Gholizadeh, Burton & Schoenau 2011, Int. J. Fluid Power 12(3)): with absolute pressure
    /// P = p + 101325 Pa, air fraction at atmosphere α₀ and polytropic index n,
    /// β(p) = [(1−α₀) + α₀(P₀/P)^(1/n)] / [(1−α₀)/β₀ + α₀(P₀/P)^(1/n)/(n·P)].
    EntrainedAir,
}

/// `bulk_modulus_pressure`: β(p) = β₀ + K_b·p, capped at `max` (002 eq. 35), or entrained air
/// (variant `entrained_air`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BulkModulusPressure {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`linear` or `entrained_air`).
    #[serde(default)]
    #[param(
        choice,
        desc = "linear: β₀ + K_b·p (002 eq. 35, default); entrained_air: Yu 1994 / Gholizadeh 2011 \
         air–oil mixture"
    )]
    pub variant: BulkVariant,
    /// Pressure slope K_b (-): dβ/dp, variant `linear`.
    #[serde(default)]
    #[param(unit = "-", range = NonNegative, desc = "dβ/dp K_b (002 eq. 35)")]
    pub slope: f64,
    /// Volume fraction of undissolved air at atmospheric pressure α₀ (-), variant
    /// `entrained_air`; Gholizadeh 2011: 0.5–5 % typical.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 0.5), desc = "undissolved air volume fraction at atmospheric pressure α₀ (variant entrained_air)")]
    pub air_fraction: f64,
    /// Polytropic index n of the air (-), variant `entrained_air`: 1 isothermal, 1.4 adiabatic.
    #[serde(default = "BulkModulusPressure::default_n")]
    #[param(unit = "-", range = Within(1.0, 1.4), desc = "polytropic index of the air n: 1 isothermal … 1.4 adiabatic (variant entrained_air)")]
    pub polytropic_index: f64,
    /// Upper bound on β (Pa).
    #[serde(default = "BulkModulusPressure::default_max")]
    #[param(unit = "Pa", range = Positive, desc = "upper bound on β")]
    pub max: f64,
}

impl BulkModulusPressure {
    fn default_max() -> f64 {
        2.2e9
    }
    fn default_n() -> f64 {
        1.4
    }
}

/// Structural variant of `line_dynamics`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum LineVariant {
    /// Rigid pipe: segment capacitance A·ℓ/β with β the fluid's (or `bulk_modulus`),
    /// Hagen–Poiseuille resistance (002 eq. 9–17).
    #[default]
    Pipe,
    /// Compliant hose: the wall adds its compliance to the oil's, 1/β_eff = 1/β + `wall_compliance`
    /// (thin wall: D/(t·E), Merritt 1967, "Hydraulic Control Systems", §2.7 eq. 2-46; or a
    /// hose maker's volumetric expansion ΔV/(V·Δp)), and the hose ends / fittings add a
    /// laminar `resistance` between valve and chamber on top of the Hagen–Poiseuille one.
    Hose,
}

/// `line_dynamics`: lumped R-L-C segments between valve ports and chambers (002 eq. 9–17),
/// rigid pipes or compliant hoses (variant `hose`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LineDynamics {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`pipe` or `hose`).
    #[serde(default)]
    #[param(
        choice,
        desc = "pipe: rigid line (002 eq. 9–17, default); hose: wall compliance added to the oil's \
         and a lumped fitting resistance"
    )]
    pub variant: LineVariant,
    /// Line length per side (m).
    #[param(unit = "m", range = Within(1.0e-3, 1.0e3), desc = "line length per side")]
    pub length: f64,
    /// Inner diameter (m).
    #[param(unit = "m", range = Within(1.0e-4, 0.5), desc = "line inner diameter")]
    pub diameter: f64,
    /// Number of lumped segments per side (-).
    #[param(unit = "-", range = Within(1.0, 200.0), desc = "lumped segments per side")]
    pub segments: u32,
    /// Effective bulk modulus of the line incl. hose wall compliance (Pa); default: fluid β₀.
    #[serde(default)]
    #[param(unit = "Pa", range = Positive, desc = "line effective bulk modulus")]
    pub bulk_modulus: Option<f64>,
    /// Lumped oil volume at the valve-side node of each line (m³), default 0: valve port and
    /// manifold passages, or (001 eq. 14–15) a pumping chamber with its piezo-stack compliance
    /// as an equivalent volume a_p·Δ_gap + β·a_p²/k_p. Compressed with the fluid β₀.
    #[serde(default)]
    #[param(unit = "m³", range = NonNegative, desc = "lumped volume at the valve-side node (default 0)")]
    pub port_volume: f64,
    /// Wall-friction model of the segments (default `steady`, Hagen–Poiseuille only).
    #[serde(default)]
    #[param(
        choice,
        desc = "segment wall friction: steady Hagen–Poiseuille (default), unsteady (Zielke 1968 \
         weighting function, 8 states per segment) or unsteady_trikha (Trikha 1975, 3 states)"
    )]
    pub friction: LineFriction,
    /// Wall compliance of a hose (1/Pa), variant `hose`: 1/β_eff = 1/β + this. Thin wall
    /// D/(t·E) (Merritt 1967 eq. 2-46); 1·10⁻⁹ 1/Pa makes β_eff ≈ 0.6 GPa of a 1.5 GPa oil.
    #[serde(default)]
    #[param(unit = "1/Pa", range = NonNegative, desc = "hose wall compliance ΔV/(V·Δp), e.g. D/(t·E) thin wall (variant hose)")]
    pub wall_compliance: f64,
    /// Laminar resistance of the hose ends and fittings per side (Pa·s/m³), variant `hose`,
    /// added to the segments' Hagen–Poiseuille resistance (spread evenly over them).
    #[serde(default)]
    #[param(unit = "Pa·s/m³", range = NonNegative, desc = "laminar fitting resistance per side, added to the Hagen–Poiseuille one (variant hose)")]
    pub resistance: f64,
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

/// Structural variant of `flexible_mount`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum MountVariant {
    /// Compliance on the load side: rod → spring-damper → load mass (003 eq. 1, SDD).
    #[default]
    LoadSide,
    /// Compliance on the piston side: the cylinder body (mass `load_mass`) sits on a
    /// spring-damper to ground and takes the reaction of the chamber pressures, seal friction
    /// and viscous force; the position transducer measures the piston relative to the body
    /// (chamber volumes follow it), the load spring acts on the absolute piston position
    /// (two-mass frame-compliance model, e.g. Jelali & Kroll 2003, "Hydraulic Servo-systems",
    /// §4.4 "mechanical structure").
    PistonSide,
}

/// `flexible_mount`: spring-damper (SDD) from rod to a load mass (003 eq. 1), or a compliant
/// cylinder mount (variant `piston_side`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FlexibleMount {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`load_side` or `piston_side`).
    #[serde(default)]
    #[param(
        choice,
        desc = "load_side: rod → spring-damper → load mass (003 SDD, default); piston_side: the \
         cylinder body (mass load_mass) on a spring-damper to ground"
    )]
    pub variant: MountVariant,
    /// Load mass m_L (kg); 003: 250. Variant `piston_side`: the cylinder body's mass.
    #[param(unit = "kg", range = Positive, desc = "load mass m_L (003: 250)")]
    pub load_mass: f64,
    /// SDD stiffness k_m (N/m); 003 range 1e4–1e5.
    #[param(unit = "N/m", range = Positive, desc = "SDD stiffness k_m")]
    pub stiffness: f64,
    /// SDD damping d_m (N·s/m); 003 range 1e4–2.5e4.
    #[param(unit = "N·s/m", range = NonNegative, desc = "SDD damping d_m")]
    pub damping: f64,
}

/// `time_delay`: transport / communication delay on the valve command.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TimeDelay {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Delay (s).
    #[param(unit = "s", range = Within(0.0, 1.0), desc = "command delay")]
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
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SensorTone {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Channel the tones are added to.
    #[serde(default = "SensorTone::default_channel")]
    pub channel: SensorChannel,
    /// Tone frequencies (Hz).
    #[param(unit = "Hz", range = Positive, desc = "tone frequencies (004: 225, 420)")]
    pub frequencies: Vec<f64>,
    /// Tone amplitudes in the channel's unit (N, m or Pa), one per frequency.
    #[param(unit = "channel unit", range = NonNegative, desc = "tone amplitudes")]
    pub amplitudes: Vec<f64>,
    /// Tone phases φ (rad), one per frequency (empty = all 0): a·sin(2πft + φ).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    #[param(unit = "rad", range = Finite, desc = "tone phases φ in a·sin(2πft + φ), one per frequency (default 0)")]
    pub phases: Vec<f64>,
}

impl SensorTone {
    fn default_channel() -> SensorChannel {
        SensorChannel::Force
    }
}

/// Structural variant of `supply_pressure_drop`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum SupplyVariant {
    /// p_s → p_s0 − R·Q_s with time constant τ (000): accumulator behind a supply resistance.
    #[default]
    Resistance,
    /// Pressure-compensated pump with a flow limit feeding a supply volume V:
    /// (V/β₀)·ṗ_s = Q_p − Q_s with Q_p = Q_max·clamp((p_s0 − p_s)/Δp_c, 0, 1): the compensator
    /// destrokes linearly over its regulation band Δp_c below the setting p_s0, and the supply
    /// collapses when the valve draws more than Q_max (Manring, "Hydraulic Control Systems"
    /// 2005, §6.5 pressure-compensated pumps).
    PumpLimit,
}

/// `supply_pressure_drop`: supply sags with flow, p_s → p_s0 − R·Q_s with time constant τ (000),
/// or a flow-limited pressure-compensated pump (variant `pump_limit`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SupplyPressureDrop {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`resistance` or `pump_limit`).
    #[serde(default)]
    #[param(
        choice,
        desc = "resistance: p_s0 − R·Q_s with lag τ (000, default); pump_limit: pressure-compensated \
         pump with flow limit Q_max into a volume"
    )]
    pub variant: SupplyVariant,
    /// Flow resistance R (Pa·s/m³), variant `resistance`.
    #[serde(default)]
    #[param(unit = "Pa·s/m³", range = NonNegative, desc = "supply flow resistance R")]
    pub resistance: f64,
    /// Time constant τ of the supply (accumulator / pump) (s), variant `resistance`.
    #[serde(default)]
    #[param(unit = "s", range = Positive, desc = "supply time constant τ")]
    pub time_constant: f64,
    /// Pump flow limit Q_max (m³/s), variant `pump_limit`.
    #[serde(default)]
    #[param(unit = "m³/s", range = Positive, desc = "pump flow limit Q_max (variant pump_limit)")]
    pub max_flow: f64,
    /// Compensator regulation band Δp_c (Pa), variant `pump_limit`.
    #[serde(default)]
    #[param(unit = "Pa", range = Positive, desc = "compensator regulation band Δp_c below the setting (variant pump_limit)")]
    pub regulation_band: f64,
    /// Oil volume between pump and valve V (m³), variant `pump_limit`.
    #[serde(default)]
    #[param(unit = "m³", range = Positive, desc = "oil volume between pump and valve (variant pump_limit)")]
    pub volume: f64,
}

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
/// ([`crate::spec::params`]); every path here is a float entry of it (tested).
///
/// The last five are the loop's assumptions when the rig's controller and valve electronics
/// are not recorded (the valve's bandwidth, the loop's transport delay, the valve's null
/// offset and null dead band; with a proportional loop its gain is the valve flow gain's, which is already
/// here): an effect section the config carries with its assumed nominal value, refit within
/// the stated range like any other nominal parameter (DIAGNOSIS.md "Assumed loop").
pub const UNCERTAIN_PARAMS: &[(&str, bool)] = &[
    ("valve.rated_flow", true),
    ("valve.area_max", true),
    ("valve.flow_at_1mpa", true),
    ("fluid.bulk_modulus", true),
    ("mechanics.mass", true),
    ("mechanics.damping", true),
    ("mechanics.load_stiffness", true),
    ("valve.underlap", false),
    ("cylinder.dead_volume_a", false),
    ("cylinder.dead_volume_b", false),
    ("supply.pressure", false),
    ("valve.command_full_scale", false),
    ("effects.valve_dynamics.time_constant", false),
    ("effects.valve_dynamics.natural_frequency", false),
    ("effects.time_delay.delay", false),
    ("effects.valve_deadband.zero_offset", false),
    ("effects.valve_deadband.overlap", false),
];

/// [`UNCERTAIN_PARAMS`] whose refit range may reach the lower end of their registry range
/// (0 for an underlap, a time constant or a delay; a signed null offset may change sign):
/// the range is clamped there instead of refused. Every other one must stay > 0.
const MAY_REACH_RANGE_END: &[&str] = &[
    "valve.underlap",
    "effects.valve_dynamics.time_constant",
    "effects.time_delay.delay",
    "effects.valve_deadband.zero_offset",
    "effects.valve_deadband.overlap",
];

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

    /// Why an `[uncertainty]` key on the spool model does not fit the configured one (a time
    /// constant is the bandwidth of order 1, a natural frequency that of order 2), or why the
    /// section it names is switched off; `None` when it fits.
    fn spool_order_mismatch(&self, path: &str) -> Option<String> {
        let section = |s: &str| {
            format!("[effects.{s}] has enabled = false; a switched-off effect is not refit (remove the switch or the uncertainty)")
        };
        match path {
            "effects.valve_dynamics.time_constant" | "effects.valve_dynamics.natural_frequency" => {
                let d = self.effects.valve_dynamics.as_ref()?;
                let want = if path.ends_with("time_constant") {
                    1
                } else {
                    2
                };
                if !d.enabled {
                    Some(section("valve_dynamics"))
                } else if d.order != want {
                    Some(format!(
                        "the spool model is order {}; its bandwidth is {} (order 1: time_constant in s, order 2: natural_frequency in rad/s)",
                        d.order,
                        if d.order == 1 { "effects.valve_dynamics.time_constant" } else { "effects.valve_dynamics.natural_frequency" }
                    ))
                } else {
                    None
                }
            }
            "effects.time_delay.delay" => {
                let d = self.effects.time_delay.as_ref()?;
                (!d.enabled).then(|| section("time_delay"))
            }
            "effects.valve_deadband.zero_offset" | "effects.valve_deadband.overlap" => {
                let d = self.effects.valve_deadband.as_ref()?;
                (!d.enabled).then(|| section("valve_deadband"))
            }
            _ => None,
        }
    }

    /// The refit range of every nominal parameter the diagnosis refits: (path, nominal value,
    /// lower bound, upper bound) in SI units, from `[uncertainty]` and the defaults; a stated
    /// uncertainty of 0 keeps the parameter fixed. Errors name the `[uncertainty]` key.
    pub fn refit_ranges(
        &self,
    ) -> Result<Vec<(&'static str, f64, f64, f64)>, crate::spec::ConfigError> {
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
        let mut out = Vec::new();
        for &(path, default) in UNCERTAIN_PARAMS {
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
            if MAY_REACH_RANGE_END.contains(&path) {
                let (r_lo, r_hi) = match registry_range(path) {
                    crate::spec::Range::Within(a, b) => (a, b),
                    crate::spec::Range::NonNegative | crate::spec::Range::Positive => {
                        (0.0, f64::INFINITY)
                    }
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
}

/// `polynomial_force`: a force on the rod between piston and ground, written as a short
/// sum of declared terms on physical states. It is what `ehactl diagnose` writes when it
/// extends a model beyond the catalogue (grey-box extension, DIAGNOSIS.md), and it can also
/// state a known load law in a nominal config (e.g. the Bingham model of an MR damper,
/// Stanway et al. 1987: F = c₀·v + F_y·sign(v) + F₀, with F₀ the accumulator preload):
///
/// F = F₀ + c_v·v + F_c·tanh(v/v_s) + c_q·|v|·v + k·(x − x₀) + A_p·(p_a − p_b)
///     + A_c·tanh(v/v_s)·|p_a − p_b| + F_d·z,   dz/dt = (v − |v|·z)/δ
///
/// The last term is Dahl's solid-friction model with exponent 1 (Dahl, "A solid friction
/// model", Aerospace Corp. TOR-0158(3107-18)-1, 1968), used for MR dampers with a viscous
/// term by Ikhouane & Dyke (Smart Mater. Struct. 16(3):605–616, 2007): a yield force F_d that
/// builds up over a pre-yield travel δ after each reversal (pre-yield stiffness F_d/δ) instead
/// of following the sign of the velocity at once; z ∈ [−1, 1] is a state of the plant.
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
