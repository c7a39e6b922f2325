//! The FMU's variables, from the config and the variant: one table that both the export
//! (`modelDescription.xml`, [`crate::xml`]) and the shared library at instantiate
//! ([`crate::instance`]) build from the same config text, so that a value reference means
//! the same variable on both sides.
//!
//! Value references: the outputs first, then the inputs, then the parameters, numbered from 0
//! in that order (FMI 2.0 §2.2.7: a value reference is unique per base type; here it is
//! unique over all).

use ehactl_config::RigConfig;
use ehactl_plant::spec::{Kind, Param, Range};

/// Which model the FMU holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Variant {
    /// The plant alone: input the valve command (V) and the operating inputs.
    Plant,
    /// ehactl's control law and supervisor around the plant: input the setpoint.
    ClosedLoop,
}

impl Variant {
    /// The name written into the FMU's resources (`resources/variant`).
    pub fn as_str(self) -> &'static str {
        match self {
            Variant::Plant => "plant",
            Variant::ClosedLoop => "closed_loop",
        }
    }

    /// The variant named `s` (the text of `resources/variant`).
    pub fn parse(s: &str) -> Option<Variant> {
        match s.trim() {
            "plant" => Some(Variant::Plant),
            "closed_loop" => Some(Variant::ClosedLoop),
            _ => None,
        }
    }
}

/// What a variable stands for.
#[derive(Debug, Clone, PartialEq)]
pub enum Role {
    /// An output of the plant or of the loop.
    Output(Out),
    /// The valve command u (V) of the plant variant.
    Command,
    /// The setpoint (N or m) of the closed loop.
    Setpoint,
    /// The setpoint's rate (N/s or m/s) of the closed loop (the PD law's feed-forward).
    SetpointRate,
    /// Closed loop: take the setpoint from the config's `[setpoint]` generator instead.
    SetpointFromConfig,
    /// A declared operating input (`[inputs.<name>]`).
    Operating(String),
    /// A registry parameter at its dotted config path.
    Param(&'static str),
}

/// The outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Out {
    /// Piston position (m).
    X,
    /// Piston velocity (m/s).
    V,
    /// Chamber A pressure (Pa).
    PA,
    /// Chamber B pressure (Pa).
    PB,
    /// Measured force, the load cell's reading (N).
    ForceMeasured,
    /// The rod force on the load side, without sensor effects (N).
    ForceLoad,
    /// Measured position (m).
    PositionMeasured,
    /// Measured chamber A pressure (Pa).
    PAMeasured,
    /// Measured chamber B pressure (Pa).
    PBMeasured,
    /// Closed loop: the valve command applied over the last control period (V).
    LoopCommand,
    /// Closed loop: whether the supervisor has tripped (the valve then holds the safe command).
    Trip,
}

/// A value of a variable.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    /// fmi2Real.
    Real(f64),
    /// fmi2Integer.
    Integer(i64),
    /// fmi2Boolean.
    Boolean(bool),
}

/// One scalar variable.
#[derive(Debug, Clone, PartialEq)]
pub struct Var {
    /// Name (the dotted config path for a parameter).
    pub name: String,
    /// What it stands for.
    pub role: Role,
    /// FMI causality: `output`, `input` or `parameter`.
    pub causality: &'static str,
    /// FMI variability: `continuous`, `discrete` or `fixed`.
    pub variability: &'static str,
    /// SI unit (empty: none).
    pub unit: String,
    /// Description.
    pub description: String,
    /// Start value (type of the variable); outputs carry one of their type without a start.
    pub start: Value,
    /// Declared minimum (Real and Integer).
    pub min: Option<f64>,
    /// Declared maximum (Real and Integer).
    pub max: Option<f64>,
    /// The registry's range of a parameter (enforced when set), `None` for the others.
    pub range: Option<Range>,
}

impl Var {
    fn output(name: &str, out: Out, unit: &str, description: &str) -> Var {
        let discrete = matches!(out, Out::LoopCommand | Out::Trip);
        Var {
            name: name.into(),
            role: Role::Output(out),
            causality: "output",
            variability: if discrete { "discrete" } else { "continuous" },
            unit: unit.into(),
            description: description.into(),
            start: if out == Out::Trip {
                Value::Boolean(false)
            } else {
                Value::Real(0.0)
            },
            min: None,
            max: None,
            range: None,
        }
    }

    fn input(name: &str, role: Role, unit: &str, description: &str, start: f64) -> Var {
        Var {
            name: name.into(),
            role,
            causality: "input",
            variability: "continuous",
            unit: unit.into(),
            description: description.into(),
            start: Value::Real(start),
            min: None,
            max: None,
            range: None,
        }
    }
}

/// The sections whose registry parameters an FMU variant exposes: the plant's for both, the
/// control law's and the supervisor's for the closed loop, and its setpoint generator's
/// (used with `setpoint_from_config`). `run`, `log`, `realtime` and `canopen` change
/// nothing a co-simulation sees (the control period is the FMU's step grid, read from the
/// config; the log, the wall-clock pacer and the bus are not in an FMU).
fn exposed(variant: Variant, path: &str) -> bool {
    let head = path.split('.').next().unwrap_or("");
    match head {
        "run" | "log" | "realtime" | "canopen" => false,
        "control" | "supervisor" | "setpoint" => variant == Variant::ClosedLoop,
        _ => true,
    }
}

/// The registry parameter `p` as an FMU parameter, if the config has a value for it of a
/// kind FMI 2.0 holds as a scalar (Real, Integer, Boolean; choices and arrays are left out).
fn parameter(p: &'static Param, tree: &toml::Value) -> Option<Var> {
    let v = ehactl_config::tree::get(tree, p.path)?;
    let start = match (p.kind, v) {
        (Kind::Float, toml::Value::Float(f)) => Value::Real(*f),
        (Kind::Float, toml::Value::Integer(i)) => Value::Real(*i as f64),
        (Kind::Integer, toml::Value::Integer(i)) => Value::Integer(*i),
        (Kind::Bool, toml::Value::Boolean(b)) => Value::Boolean(*b),
        _ => return None,
    };
    let (min, max) = match p.range {
        Range::Finite => (None, None),
        Range::Positive | Range::NonNegative => (Some(0.0), None),
        Range::Within(lo, hi) => (Some(lo), Some(hi)),
        Range::PositiveAtMost(hi) => (Some(0.0), Some(hi)),
    };
    let bounded = !matches!(start, Value::Boolean(_));
    Some(Var {
        name: p.path.to_string(),
        role: Role::Param(p.path),
        causality: "parameter",
        variability: "fixed",
        unit: if p.unit == "-" {
            String::new()
        } else {
            p.unit.to_string()
        },
        description: format!("{} (admitted: {})", p.description, p.range.describe()),
        start,
        min: min.filter(|_| bounded),
        max: max.filter(|_| bounded),
        range: Some(p.range),
    })
}

/// The plant's outputs, state and measured, common to both variants.
fn outputs() -> Vec<Var> {
    vec![
        Var::output("x", Out::X, "m", "piston position"),
        Var::output("v", Out::V, "m/s", "piston velocity"),
        Var::output("p_a", Out::PA, "Pa", "chamber A pressure"),
        Var::output("p_b", Out::PB, "Pa", "chamber B pressure"),
        Var::output(
            "force_measured",
            Out::ForceMeasured,
            "N",
            "measured force: the load cell's reading with its sensor model",
        ),
        Var::output(
            "force_load",
            Out::ForceLoad,
            "N",
            "load-side force: the rod force a load cell sees, without sensor effects",
        ),
        Var::output(
            "position_measured",
            Out::PositionMeasured,
            "m",
            "measured position (sensor model)",
        ),
        Var::output(
            "p_a_measured",
            Out::PAMeasured,
            "Pa",
            "measured chamber A pressure (sensor model)",
        ),
        Var::output(
            "p_b_measured",
            Out::PBMeasured,
            "Pa",
            "measured chamber B pressure (sensor model)",
        ),
    ]
}

/// The variables of the loop's side: the valve command input of the plant alone, or the
/// closed loop's command and trip outputs and its setpoint inputs.
fn loop_variables(cfg: &RigConfig, variant: Variant) -> Vec<Var> {
    let mut vars = Vec::new();
    let full_scale = cfg.plant.valve.command_full_scale;
    match variant {
        Variant::Plant => {
            let mut u = Var::input(
                "u",
                Role::Command,
                "V",
                "valve command; |u| at most valve.command_full_scale",
                0.0,
            );
            (u.min, u.max) = (Some(-full_scale), Some(full_scale));
            vars.push(u);
        }
        Variant::ClosedLoop => {
            vars.push(Var::output(
                "command",
                Out::LoopCommand,
                "V",
                "valve command applied over the last control period",
            ));
            vars.push(Var::output(
                "trip",
                Out::Trip,
                "",
                "the supervisor tripped; the valve holds its safe command since",
            ));
            let (unit, rate) = match cfg.controller().feedback_channel() {
                ehactl_control::supervisor::FeedbackChannel::Position => ("m", "m/s"),
                _ => ("N", "N/s"),
            };
            let (r0, _) = ehactl_control::setpoint::Setpoint::new(&cfg.setpoint).sample(0.0);
            vars.push(Var::input(
                "setpoint",
                Role::Setpoint,
                unit,
                "setpoint of the control law",
                r0,
            ));
            vars.push(Var::input(
                "setpoint_rate",
                Role::SetpointRate,
                rate,
                "rate of the setpoint (the PD law's feed-forward; unused by the PI law)",
                0.0,
            ));
        }
    }
    vars
}

/// The variables of `variant` for the config `cfg`, in value-reference order.
pub fn table(cfg: &RigConfig, variant: Variant) -> Vec<Var> {
    let mut vars = outputs();
    vars.extend(loop_variables(cfg, variant));
    for (name, inp) in &cfg.inputs {
        vars.push(Var::input(
            name,
            Role::Operating(name.clone()),
            &inp.unit,
            "operating input ([inputs] of the config); fixed from the end of initialisation",
            inp.value,
        ));
    }
    if variant == Variant::ClosedLoop {
        vars.push(Var {
            name: "setpoint_from_config".into(),
            role: Role::SetpointFromConfig,
            causality: "parameter",
            variability: "fixed",
            unit: String::new(),
            description: "take the setpoint from the config's [setpoint] generator (as ehactl run) instead of the input".into(),
            start: Value::Boolean(false),
            min: None,
            max: None,
            range: None,
        });
    }
    let tree = cfg.to_value();
    for table in ehactl_config::registries() {
        for p in table.iter().filter(|p| exposed(variant, p.path)) {
            if let Some(v) = parameter(p, &tree) {
                vars.push(v);
            }
        }
    }
    vars
}
