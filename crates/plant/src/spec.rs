//! Parameter registry: every numeric config field with its unit, meaning and admissible range.
//!
//! Hopsan-style: a component declares its parameters (name, unit, description); the loader,
//! the error messages, `ehactl params` and the Python bindings all read this one table.

use std::fmt;

/// Admissible range of a parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Range {
    /// Any finite value.
    Finite,
    /// Finite and > 0.
    Positive,
    /// Finite and ≥ 0.
    NonNegative,
    /// Finite and within [lo, hi].
    Within(f64, f64),
}

impl Range {
    /// Whether `v` is admissible.
    pub fn admits(self, v: f64) -> bool {
        if !v.is_finite() {
            return false;
        }
        match self {
            Range::Finite => true,
            Range::Positive => v > 0.0,
            Range::NonNegative => v >= 0.0,
            Range::Within(lo, hi) => v >= lo && v <= hi,
        }
    }

    /// Human description of the range.
    pub fn describe(self) -> String {
        match self {
            Range::Finite => "a finite number".into(),
            Range::Positive => "a finite number > 0".into(),
            Range::NonNegative => "a finite number ≥ 0".into(),
            Range::Within(lo, hi) => format!("a finite number in [{lo}, {hi}]"),
        }
    }
}

/// Kind of value a parameter holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Floating point number.
    Float,
    /// Non-negative integer.
    Integer,
    /// Array of floats.
    FloatArray,
    /// Boolean (`true` / `false`).
    Bool,
    /// One of the listed strings.
    Choice(&'static [&'static str]),
}

/// One declared parameter.
#[derive(Debug, Clone, Copy)]
pub struct Param {
    /// Dotted config path, e.g. `valve.command_full_scale`.
    pub path: &'static str,
    /// SI unit ("-" for dimensionless).
    pub unit: &'static str,
    /// Meaning and seed source.
    pub description: &'static str,
    /// Admissible range.
    pub range: Range,
    /// Value kind.
    pub kind: Kind,
}

impl Param {
    /// A registry entry; const so that every crate can build its parameter table statically.
    pub const fn new(
        path: &'static str,
        unit: &'static str,
        range: Range,
        description: &'static str,
        kind: Kind,
    ) -> Param {
        Param {
            path,
            unit,
            description,
            range,
            kind,
        }
    }

    /// A floating-point entry.
    pub const fn float(
        path: &'static str,
        unit: &'static str,
        range: Range,
        description: &'static str,
    ) -> Param {
        Param::new(path, unit, range, description, Kind::Float)
    }

    /// An integer entry.
    pub const fn int(
        path: &'static str,
        unit: &'static str,
        range: Range,
        description: &'static str,
    ) -> Param {
        Param::new(path, unit, range, description, Kind::Integer)
    }
}

use Param as P;
const fn p(path: &'static str, unit: &'static str, range: Range, d: &'static str) -> Param {
    P::float(path, unit, range, d)
}
const fn int(path: &'static str, unit: &'static str, range: Range, d: &'static str) -> Param {
    P::int(path, unit, range, d)
}
const fn arr(path: &'static str, unit: &'static str, range: Range, d: &'static str) -> Param {
    P::new(path, unit, range, d, Kind::FloatArray)
}
const fn choice(path: &'static str, choices: &'static [&'static str], d: &'static str) -> Param {
    P::new(path, "-", Finite, d, Kind::Choice(choices))
}

use Range::*;

/// The plant's parameters. Controller, setpoint, supervisor and run parameters are
/// declared in `ehactl-config` and appended there.
pub const PARAMS: &[Param] = &[
    p("fluid.density", "kg/m³", Positive, "fluid density ρ"),
    p(
        "fluid.bulk_modulus",
        "Pa",
        Positive,
        "effective bulk modulus β₀ (003 K, 004 β_e)",
    ),
    p(
        "fluid.kinematic_viscosity",
        "m²/s",
        Positive,
        "kinematic viscosity ν (001 eq. 6–12)",
    ),
    p(
        "fluid.cavitation_pressure",
        "Pa",
        Within(-1.0e5, 0.0),
        "cavitation floor, gauge",
    ),
    p(
        "supply.pressure",
        "Pa",
        Positive,
        "supply pressure p_s (003 p₀)",
    ),
    p(
        "supply.tank_pressure",
        "Pa",
        NonNegative,
        "tank pressure p_T",
    ),
    p(
        "valve.command_full_scale",
        "V",
        Positive,
        "command for full spool opening",
    ),
    p(
        "valve.underlap",
        "-",
        Within(0.0, 1.0),
        "underlap per edge, fraction of travel (003 z₀)",
    ),
    p(
        "valve.discharge_coefficient",
        "-",
        Within(0.01, 1.0),
        "discharge coefficient C_d (003: 0.56)",
    ),
    p(
        "valve.area_max",
        "m²",
        Positive,
        "metering area at full opening",
    ),
    p(
        "valve.rated_flow",
        "m³/s",
        Positive,
        "rated edge flow q_vn at full opening (003 eq. 13)",
    ),
    p(
        "valve.rated_pressure_drop",
        "Pa",
        Positive,
        "edge pressure drop Δp_n of the rating (003 eq. 13)",
    ),
    p(
        "valve.flow_at_1mpa",
        "m³/s",
        Positive,
        "edge flow at P_d = 1 MPa (004 eq. 20)",
    ),
    p(
        "valve.exponent",
        "-",
        Within(0.05, 1.0),
        "power-law exponent n (004 eq. 20: 0.4667)",
    ),
    p(
        "valve.pressure_offset",
        "Pa",
        NonNegative,
        "pressure offset P_o (004 eq. 22)",
    ),
    p(
        "valve.laminar_pressure",
        "Pa",
        Positive,
        "laminar regularisation pressure of each edge",
    ),
    p("cylinder.area_a", "m²", Positive, "piston area A₁"),
    p("cylinder.area_b", "m²", Positive, "annulus area A₂"),
    p("cylinder.dead_volume_a", "m³", Positive, "dead volume V₁₀"),
    p("cylinder.dead_volume_b", "m³", Positive, "dead volume V₂₀"),
    p("cylinder.stroke", "m", Positive, "stroke h"),
    p(
        "cylinder.initial_position",
        "m",
        NonNegative,
        "initial piston position",
    ),
    p(
        "cylinder.initial_pressure_a",
        "Pa",
        Finite,
        "initial chamber A pressure",
    ),
    p(
        "cylinder.initial_pressure_b",
        "Pa",
        Finite,
        "initial chamber B pressure",
    ),
    p("mechanics.mass", "kg", Positive, "moving mass"),
    p(
        "mechanics.damping",
        "N·s/m",
        NonNegative,
        "viscous damping d_y / C",
    ),
    p(
        "mechanics.load_stiffness",
        "N/m",
        NonNegative,
        "spring to ground K_L (004 load cell)",
    ),
    p(
        "mechanics.load_contact_position",
        "m",
        Finite,
        "position where the ground spring is relaxed",
    ),
    p(
        "excitation.offset",
        "N",
        Finite,
        "constant force F₀ (003 eq. 2)",
    ),
    p(
        "excitation.amplitude",
        "N",
        NonNegative,
        "harmonic amplitude / pulse height F_A",
    ),
    p(
        "excitation.frequency",
        "Hz",
        NonNegative,
        "harmonic frequency f_e",
    ),
    p(
        "excitation.blows_per_minute",
        "1/min",
        NonNegative,
        "impact rate (003 eq. 17)",
    ),
    p(
        "excitation.pulse_duration",
        "s",
        NonNegative,
        "impact pulse duration",
    ),
    p(
        "excitation.start_time",
        "s",
        NonNegative,
        "excitation start",
    ),
    p(
        "effects.friction.static_force",
        "N",
        NonNegative,
        "breakaway friction F_s (004: 44 N)",
    ),
    p(
        "effects.friction.coulomb_force",
        "N",
        NonNegative,
        "Coulomb friction F_C (004: 39 N)",
    ),
    p(
        "effects.friction.stribeck_velocity",
        "m/s",
        Positive,
        "Stribeck velocity",
    ),
    p(
        "effects.friction.viscous",
        "N·s/m",
        NonNegative,
        "extra viscous friction",
    ),
    p(
        "effects.valve_deadband.overlap",
        "-",
        Within(0.0, 0.95),
        "overlap per edge, fraction of travel",
    ),
    p(
        "effects.valve_deadband.zero_offset",
        "-",
        Within(-0.5, 0.5),
        "spool zero offset, fraction of travel",
    ),
    p(
        "effects.valve_saturation.spool_limit",
        "-",
        Within(0.01, 1.0),
        "spool travel limit, fraction",
    ),
    p(
        "effects.valve_saturation.max_flow",
        "m³/s",
        NonNegative,
        "edge flow limit (0 = none)",
    ),
    int(
        "effects.valve_dynamics.order",
        "-",
        Within(1.0, 2.0),
        "spool model order",
    ),
    p(
        "effects.valve_dynamics.time_constant",
        "s",
        NonNegative,
        "PT1 time constant T_z (003)",
    ),
    p(
        "effects.valve_dynamics.natural_frequency",
        "rad/s",
        Within(0.0, 1.0e6),
        "spool ω_nv (004: 1507.9)",
    ),
    p(
        "effects.valve_dynamics.damping_ratio",
        "-",
        NonNegative,
        "spool damping ratio ζ (004: 0.59)",
    ),
    p(
        "effects.internal_leakage.coefficient",
        "m³/(s·Pa)",
        NonNegative,
        "cross-piston leakage k_l",
    ),
    p(
        "effects.external_leakage.coefficient",
        "m³/(s·Pa)",
        NonNegative,
        "leakage to tank k_le",
    ),
    p(
        "effects.bulk_modulus_pressure.slope",
        "-",
        NonNegative,
        "dβ/dp K_b (002 eq. 35)",
    ),
    p(
        "effects.bulk_modulus_pressure.max",
        "Pa",
        Positive,
        "upper bound on β",
    ),
    p(
        "effects.line_dynamics.length",
        "m",
        Within(1.0e-3, 1.0e3),
        "line length per side",
    ),
    p(
        "effects.line_dynamics.diameter",
        "m",
        Within(1.0e-4, 0.5),
        "line inner diameter",
    ),
    int(
        "effects.line_dynamics.segments",
        "-",
        Within(1.0, 200.0),
        "lumped segments per side",
    ),
    p(
        "effects.line_dynamics.bulk_modulus",
        "Pa",
        Positive,
        "line effective bulk modulus",
    ),
    p(
        "effects.line_dynamics.port_volume",
        "m³",
        NonNegative,
        "lumped volume at the valve-side node (default 0)",
    ),
    choice(
        "effects.line_dynamics.friction",
        crate::params::LineFriction::NAMES,
        "segment wall friction: steady Hagen–Poiseuille (default), unsteady (Zielke 1968 \
         weighting function, 8 states per segment) or unsteady_trikha (Trikha 1975, 3 states)",
    ),
    // Counterbalance valve (crate::cbv; 002 fig. 2, eq. 18–19).
    choice(
        "effects.counterbalance_valve.sides",
        crate::cbv::CbvSides::NAMES,
        "lines fitted with a CBV at the cylinder end (default both)",
    ),
    p(
        "effects.counterbalance_valve.pilot_ratio",
        "-",
        Positive,
        "pilot ratio ψ: opens when p_load + ψ·p_pilot ≥ setting",
    ),
    p(
        "effects.counterbalance_valve.setting",
        "Pa",
        Positive,
        "relief setting p_set (cracking load pressure without pilot)",
    ),
    p(
        "effects.counterbalance_valve.opening_pressure",
        "Pa",
        Positive,
        "rise of p_load + ψ·p_pilot from cracking to full opening",
    ),
    p(
        "effects.counterbalance_valve.area_max",
        "m²",
        Positive,
        "poppet metering area fully open",
    ),
    p(
        "effects.counterbalance_valve.discharge_coefficient",
        "-",
        Within(0.01, 1.0),
        "poppet discharge coefficient (default 0.7)",
    ),
    p(
        "effects.counterbalance_valve.check_resistance",
        "Pa·s²/m⁶",
        Positive,
        "free-flow check R_UV, Δp = R_UV·Q² (002 eq. 18–19)",
    ),
    p(
        "effects.counterbalance_valve.check_cracking",
        "Pa",
        NonNegative,
        "check-valve cracking pressure (default 0)",
    ),
    p(
        "effects.counterbalance_valve.time_constant",
        "s",
        Positive,
        "poppet first-order time constant",
    ),
    p(
        "effects.counterbalance_valve.volume",
        "m³",
        Positive,
        "oil volume between line end and poppet",
    ),
    p(
        "effects.counterbalance_valve.port_bleed",
        "m³/(s·Pa)",
        NonNegative,
        "directional valve work port → tank bleed (neutral A,B→T), default 0",
    ),
    p(
        "effects.counterbalance_valve.laminar_pressure",
        "Pa",
        Positive,
        "laminar transition of the CBV orifice laws (default 5e4)",
    ),
    p(
        "effects.flexible_mount.load_mass",
        "kg",
        Positive,
        "load mass m_L (003: 250)",
    ),
    p(
        "effects.flexible_mount.stiffness",
        "N/m",
        Positive,
        "SDD stiffness k_m",
    ),
    p(
        "effects.flexible_mount.damping",
        "N·s/m",
        NonNegative,
        "SDD damping d_m",
    ),
    p(
        "effects.time_delay.delay",
        "s",
        Within(0.0, 1.0),
        "command delay",
    ),
    arr(
        "effects.sensor_tone.frequencies",
        "Hz",
        Positive,
        "tone frequencies (004: 225, 420)",
    ),
    arr(
        "effects.sensor_tone.amplitudes",
        "channel unit",
        NonNegative,
        "tone amplitudes",
    ),
    p(
        "effects.supply_pressure_drop.resistance",
        "Pa·s/m³",
        NonNegative,
        "supply flow resistance R",
    ),
    p(
        "effects.supply_pressure_drop.time_constant",
        "s",
        Positive,
        "supply time constant τ",
    ),
    // Structural variants of the catalogue effects (issue 17; DIAGNOSIS.md "Effect variants").
    choice(
        "effects.friction.variant",
        &["stribeck", "load_coulomb"],
        "stribeck: seal friction with stick (003 eq. 5, default); load_coulomb: F_C·tanh(v/v_s) \
         without stick (MR damper / guide, Spencer 1997 without hysteresis)",
    ),
    choice(
        "effects.valve_deadband.variant",
        &["overlap", "amplifier"],
        "overlap: spool overlap (default); amplifier: dead zone of the amplifier ahead of the \
         underlapped spool",
    ),
    p(
        "effects.valve_deadband.deadzone",
        "-",
        Within(0.0, 0.95),
        "amplifier dead zone, fraction of the full-scale command (variant amplifier)",
    ),
    choice(
        "effects.valve_saturation.variant",
        &["symmetric", "asymmetric"],
        "symmetric: one spool travel limit (default); asymmetric: spool_limit for + and \
         spool_limit_negative for − travel",
    ),
    p(
        "effects.valve_saturation.spool_limit_negative",
        "-",
        Within(0.01, 1.0),
        "negative spool travel limit, fraction (variant asymmetric)",
    ),
    choice(
        "effects.internal_leakage.variant",
        &["equal"],
        "cross-piston leakage has one coefficient",
    ),
    choice(
        "effects.external_leakage.variant",
        &["equal", "per_chamber"],
        "equal: both chambers leak to tank with `coefficient` (default); per_chamber: A with \
         `coefficient`, B with `coefficient_b`",
    ),
    p(
        "effects.internal_leakage.coefficient_b",
        "m³/(s·Pa)",
        NonNegative,
        "not used (cross-piston leakage has one coefficient)",
    ),
    p(
        "effects.external_leakage.coefficient_b",
        "m³/(s·Pa)",
        NonNegative,
        "chamber B leakage to tank (variant per_chamber)",
    ),
    choice(
        "effects.bulk_modulus_pressure.variant",
        &["linear", "entrained_air"],
        "linear: β₀ + K_b·p (002 eq. 35, default); entrained_air: Yu 1994 / Gholizadeh 2011 \
         air–oil mixture",
    ),
    p(
        "effects.bulk_modulus_pressure.air_fraction",
        "-",
        Within(0.0, 0.5),
        "undissolved air volume fraction at atmospheric pressure α₀ (variant entrained_air)",
    ),
    p(
        "effects.bulk_modulus_pressure.polytropic_index",
        "-",
        Within(1.0, 1.4),
        "polytropic index of the air n: 1 isothermal … 1.4 adiabatic (variant entrained_air)",
    ),
    choice(
        "effects.flexible_mount.variant",
        &["load_side", "piston_side"],
        "load_side: rod → spring-damper → load mass (003 SDD, default); piston_side: the \
         cylinder body (mass load_mass) on a spring-damper to ground",
    ),
    arr(
        "effects.sensor_tone.phases",
        "rad",
        Finite,
        "tone phases φ in a·sin(2πft + φ), one per frequency (default 0)",
    ),
    choice(
        "effects.supply_pressure_drop.variant",
        &["resistance", "pump_limit"],
        "resistance: p_s0 − R·Q_s with lag τ (000, default); pump_limit: pressure-compensated \
         pump with flow limit Q_max into a volume",
    ),
    p(
        "effects.supply_pressure_drop.max_flow",
        "m³/s",
        Positive,
        "pump flow limit Q_max (variant pump_limit)",
    ),
    p(
        "effects.supply_pressure_drop.regulation_band",
        "Pa",
        Positive,
        "compensator regulation band Δp_c below the setting (variant pump_limit)",
    ),
    p(
        "effects.supply_pressure_drop.volume",
        "m³",
        Positive,
        "oil volume between pump and valve (variant pump_limit)",
    ),
    p(
        "effects.polynomial_force.constant",
        "N",
        Finite,
        "constant rod force F₀ (opposing +x), e.g. a damper's gas preload",
    ),
    p(
        "effects.polynomial_force.viscous",
        "N·s/m",
        Finite,
        "viscous rod force coefficient c_v of c_v·v",
    ),
    p(
        "effects.polynomial_force.coulomb",
        "N",
        Finite,
        "Coulomb / yield force F_c of F_c·sign(v) (Bingham model)",
    ),
    p(
        "effects.polynomial_force.quadratic",
        "N·s²/m²",
        Finite,
        "quadratic damping c_q of c_q·|v|·v",
    ),
    p(
        "effects.polynomial_force.stiffness",
        "N/m",
        Finite,
        "stiffness k of k·(x − origin)",
    ),
    p(
        "effects.polynomial_force.origin",
        "m",
        Finite,
        "position at which the stiffness term is zero",
    ),
    p(
        "effects.polynomial_force.pressure",
        "m²",
        Finite,
        "area A_p of the load-pressure force A_p·(p_a − p_b)",
    ),
    p(
        "effects.polynomial_force.pressure_coulomb",
        "m²",
        Finite,
        "area A_c of the pressure-dependent friction A_c·sign(v)·|p_a − p_b|",
    ),
    p(
        "effects.polynomial_force.smoothing_velocity",
        "m/s",
        Positive,
        "smoothing velocity v_s of sign(v) ≈ tanh(v/v_s)",
    ),
    p(
        "effects.polynomial_flow.constant",
        "m³/s",
        Finite,
        "null-bias flow q₀ from port B to port A",
    ),
    p(
        "effects.polynomial_flow.spool",
        "m³/s",
        Finite,
        "flow-gain error q_s of q_s·x_v (x_v: spool, fraction of travel)",
    ),
    p(
        "effects.polynomial_flow.spool_abs",
        "m³/s",
        Finite,
        "direction asymmetry q_a of q_a·|x_v|",
    ),
    p(
        "sensors.force.sensitivity",
        "V/N",
        Positive,
        "load cell sensitivity (004: 0.5097 mV/N)",
    ),
    p("sensors.force.noise", "N", NonNegative, "load cell noise σ"),
    p(
        "sensors.pressure.noise",
        "Pa",
        NonNegative,
        "pressure noise σ",
    ),
    p(
        "sensors.position.resolution",
        "m",
        NonNegative,
        "position resolution",
    ),
    p(
        "sensors.position.update_period",
        "s",
        NonNegative,
        "position update period",
    ),
    p(
        "sensors.position.noise",
        "m",
        NonNegative,
        "position noise σ",
    ),
    p(
        "sensors.spool.noise",
        "-",
        NonNegative,
        "spool position noise σ",
    ),
    int("sensors.seed", "-", NonNegative, "noise seed"),
    int(
        "integration.substeps",
        "-",
        Within(0.0, 100000.0),
        "substeps per control period (0 = auto)",
    ),
    p(
        "integration.max_omega_h",
        "-",
        Within(0.01, 1.5),
        "largest ω·h for automatic substeps",
    ),
    choice(
        "integration.method",
        crate::params::IntegrationMethod::NAMES,
        "substep scheme: exponential_euler (default) or linear_exact (chambers + mechanics \
         discretised exactly; exponential_euler is used with lines, friction or polynomial effects)",
    ),
];

/// A configuration error that names the field, what is wrong and what was expected.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigError {
    /// Dotted path of the offending field (or section).
    pub path: String,
    /// What is wrong, with the expected unit where one applies.
    pub message: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "config error at `{}`: {}", self.path, self.message)
    }
}

impl std::error::Error for ConfigError {}

impl ConfigError {
    /// Build an error for `path`.
    pub fn new(path: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// Look a parameter up by dotted path in the given tables.
pub fn find<'a>(tables: &[&'a [Param]], path: &str) -> Option<&'a Param> {
    tables
        .iter()
        .flat_map(|t| t.iter())
        .find(|p| p.path == path)
}

/// "expected … in UNIT (description)" for a known path, or a generic phrase.
pub fn expectation(tables: &[&[Param]], path: &str) -> String {
    match find(tables, path) {
        Some(p) => format!(
            "expected {} in {} ({})",
            p.range.describe(),
            p.unit,
            p.description
        ),
        None => "see `ehactl params` for the expected fields and units".into(),
    }
}

/// Get the value at a dotted path in a TOML tree.
pub fn get<'a>(root: &'a toml::Value, path: &str) -> Option<&'a toml::Value> {
    let mut cur = root;
    for key in path.split('.') {
        cur = cur.as_table()?.get(key)?;
    }
    Some(cur)
}

/// Get a mutable value at a dotted path.
pub fn get_mut<'a>(root: &'a mut toml::Value, path: &str) -> Option<&'a mut toml::Value> {
    let mut cur = root;
    for key in path.split('.') {
        cur = cur.as_table_mut()?.get_mut(key)?;
    }
    Some(cur)
}

/// Normalise integers to floats for float parameters (TOML `5000` for a float field),
/// then check every declared parameter that is present: type, finiteness and range.
pub fn check_tree(root: &mut toml::Value, tables: &[&[Param]]) -> Result<(), ConfigError> {
    for param in tables.iter().flat_map(|t| t.iter()) {
        let Some(v) = get_mut(root, param.path) else {
            continue;
        };
        let bad = |what: String| {
            ConfigError::new(
                param.path,
                format!("{what}; {}", expectation(tables, param.path)),
            )
        };
        match param.kind {
            Kind::Float | Kind::Integer => {
                let x = match v {
                    toml::Value::Float(f) => *f,
                    toml::Value::Integer(i) => *i as f64,
                    other => {
                        return Err(bad(format!(
                            "wrong type: got {} `{}`",
                            other.type_str(),
                            other
                        )))
                    }
                };
                if param.kind == Kind::Float {
                    *v = toml::Value::Float(x);
                } else if x.fract() != 0.0 {
                    return Err(bad(format!("got {x}, not an integer")));
                }
                if !param.range.admits(x) {
                    let what = if x.is_finite() {
                        format!("value {x} is out of range")
                    } else {
                        format!("value {x} is not finite")
                    };
                    return Err(bad(what));
                }
            }
            Kind::Bool => {
                if !v.is_bool() {
                    return Err(ConfigError::new(
                        param.path,
                        format!(
                            "wrong type: got {} `{}`; expected true or false ({})",
                            v.type_str(),
                            v,
                            param.description
                        ),
                    ));
                }
            }
            Kind::Choice(choices) => {
                if !v.as_str().is_some_and(|x| choices.contains(&x)) {
                    let list = choices
                        .iter()
                        .map(|c| format!("\"{c}\""))
                        .collect::<Vec<_>>()
                        .join(", ");
                    return Err(ConfigError::new(
                        param.path,
                        format!("got `{v}`; expected one of {list} ({})", param.description),
                    ));
                }
            }
            Kind::FloatArray => {
                let Some(items) = v.as_array_mut() else {
                    return Err(bad(format!("wrong type: got {}", v.type_str())));
                };
                for (i, item) in items.iter_mut().enumerate() {
                    let x = match item {
                        toml::Value::Float(f) => *f,
                        toml::Value::Integer(n) => *n as f64,
                        other => {
                            return Err(bad(format!(
                                "element {i} has wrong type {}",
                                other.type_str()
                            )))
                        }
                    };
                    *item = toml::Value::Float(x);
                    if !param.range.admits(x) {
                        return Err(bad(format!("element {i} = {x} is out of range")));
                    }
                }
            }
        }
    }
    Ok(())
}

/// Turn a serde error (from `serde_path_to_error`) into a [`ConfigError`] naming the full
/// path and the expected unit.
pub fn from_serde(
    prefix: &str,
    err: serde_path_to_error::Error<toml::de::Error>,
    tables: &[&[Param]],
) -> ConfigError {
    let mut path = err.path().to_string();
    if path == "." {
        path.clear();
    }
    let full = |p: &str| -> String {
        match (prefix.is_empty(), p.is_empty()) {
            (true, _) => p.to_string(),
            (false, true) => prefix.to_string(),
            (false, false) => format!("{prefix}.{p}"),
        }
    };
    let inner = err.into_inner();
    let msg = inner.message().to_string();
    if let Some(field) = between(&msg, "missing field `", "`") {
        let base = full(&path);
        let fp = if base.is_empty() {
            field.to_string()
        } else {
            format!("{base}.{field}")
        };
        let exp = expectation(tables, &fp);
        return ConfigError::new(fp, format!("missing required field; {exp}"));
    }
    if let Some(field) = between(&msg, "unknown field `", "`") {
        // serde_path_to_error's path already ends with the unknown key.
        let fp = full(&path);
        let base = fp
            .strip_suffix(field)
            .map(|b| b.trim_end_matches('.').to_string())
            .unwrap_or_default();
        let fp = if fp.is_empty() { field.to_string() } else { fp };
        if base == "effects" {
            return ConfigError::new(
                fp,
                format!(
                    "unknown effect id `{field}`; expected one of: {}",
                    crate::effects::EffectId::ALL
                        .iter()
                        .map(|e| e.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            );
        }
        let rest = msg.split(", expected").nth(1).unwrap_or("").trim();
        return ConfigError::new(
            fp,
            format!(
                "unknown field; expected{}",
                if rest.is_empty() {
                    " no such field".to_string()
                } else {
                    format!(" {rest}")
                }
            ),
        );
    }
    let fp = full(&path);
    let exp = expectation(tables, &fp);
    ConfigError::new(fp, format!("{msg}; {exp}"))
}

fn between<'a>(s: &'a str, start: &str, end: &str) -> Option<&'a str> {
    let i = s.find(start)? + start.len();
    let j = s[i..].find(end)? + i;
    Some(&s[i..j])
}
