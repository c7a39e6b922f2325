//! The nonlinear plant: valve → (lines) → chambers → piston (→ SDD → load mass).
//!
//! Phases follow Hopsan: [`Plant::configure`] derives constants and allocates,
//! [`Plant::initialize`] sets the initial state, [`Plant::step`] advances one control period
//! in fixed substeps without allocating.
//!
//! Integration scheme per substep h (stiff-safe, see docs/design.md "Numerics"):
//! 1. spool: exact zero-order-hold discretisation of its linear dynamics;
//! 2. pressures: exponential Euler on each chamber / line node, linearised in its own
//!    pressure, so the stiff leakage and valve flow–pressure terms (004: V/(β·K_Ct) ≈ 5 µs)
//!    are unconditionally stable and monotone;
//! 3. line flows with implicit resistance; piston and load positions drift with the
//!    velocities that drove the pressures, then the velocities take the forces at the new
//!    positions and pressures, with implicit self-damping and friction as a velocity
//!    projection (true stick).
//!
//! Steps 2→3 form a symplectic Euler (drift–kick) pair for the hydraulic spring, the load
//! spring and the mount, stable for ω·h < 2, with position, rod force and pressures at one
//! time level (a kick before the position drift put them one substep ahead of the
//! pressures);
//! the substep is chosen so that the fastest mode has ω·h ≤ `integration.max_omega_h`.
//! With `integration.line_method = "implicit"` step 2 for a rig with lines is one
//! trapezoidal solve of each chain from the valve-side node to the chamber
//! ([`crate::line::Line::advance_implicit`], through the line stage
//! [`LineStage::advance_implicit`]); no segment mode enters the rule then, only the line's
//! half-wave mode π/T (T = wave delay) and the chamber/mechanics modes (see `fastest_mode`).

use crate::cbv::{Cbv, CbvSides, CbvState};
use crate::chambers::{Chamber, Leaks};
use crate::effects::line_dynamics::Lines;
use crate::effects::{
    self, phi1, validate_variants, BulkStage, CommandStage, FlowStage, ForceStage, LapStage,
    LineStage, LoadSpring, MountStage, PistonForces, SpoolStage, SupplyStage,
};
use crate::exact::{LinearCoefficients, LinearExact};
use crate::excitation::ExcitationModel;
use crate::params::PlantParams;
use crate::sensors::{Measurements, SensorModel, TrueValues};
use crate::spec::ConfigError;
use crate::valve::EdgeLaw;

pub use ehactl_types::PlantState;

/// Derived constants.
#[derive(Debug, Clone)]
struct Consts {
    a_a: f64,
    a_b: f64,
    v_a0: f64,
    v_b0: f64,
    stroke: f64,
    beta0: f64,
    /// The largest bulk modulus (Pa) of the bulk stage ([`BulkStage::max`]), for the
    /// substep rule ([`fastest_mode`]); the substep calls the stage.
    beta_max: f64,
    p_cav: f64,
    ps0: f64,
    pt: f64,
    mass: f64,
    damping: f64,
    k_load: f64,
    /// Stiffness (N/m) of the force stage (`friction` variant `lugre`: the pre-sliding
    /// spring σ₀; [`ForceStage::stiffness`]), 0 otherwise: only the substep rule reads it
    /// ([`fastest_mode`]).
    k_bristle: f64,
    x_contact: f64,
    end_stops: bool,
    full_scale: f64,
    /// Equivalent supply droop (Pa·s/m³), > 0 when the supply pressure is a state.
    supply_r: f64,
    /// Supply time constant (s), variant `resistance` (the `linear_exact` step uses it).
    supply_tau: f64,
    /// The mount's (mass (kg), stiffness (N/m), damping (N·s/m)) for the substep rule and
    /// `linear_exact` ([`MountStage::coefficients`]); the substep calls the stage.
    mount: Option<(f64, f64, f64)>,
    /// The mount is the cylinder body's (`flexible_mount` variant `piston_side`).
    body_mount: bool,
    /// `max_omega_h / max_omega_h_line` (-): the line segment modes of the symplectic line
    /// scheme enter the substep rule scaled by it (a stability margin instead of the
    /// accuracy rule, see [`fastest_mode`]).
    line_scale: f64,
}

/// The simulated actuator.
#[derive(Debug, Clone)]
pub struct Plant {
    c: Consts,
    edges: EdgeLaw,
    /// Exact linear transition of chambers and mechanics (`integration.method = "linear_exact"`).
    linear: Option<LinearExact>,
    /// `polynomial_force` on the rod ([`crate::effects::PolynomialForce`]).
    poly: Option<crate::effects::PolynomialForce>,
    /// Dahl state z (-, in [−1, 1]) of the `polynomial_force` Dahl term
    /// ([`crate::effects::PolynomialForce::dahl_implicit`]); 0 without it.
    dahl_z: f64,
    /// `polynomial_flow` B→A ([`crate::effects::PolynomialFlow`]).
    poly_flow: Option<crate::effects::PolynomialFlow>,
    excitation: ExcitationModel,
    sensors: SensorModel,
    /// Counterbalance valves at the cylinder ends of lines A and B ([`crate::cbv`]).
    cbv: [Option<Cbv>; 2],
    /// Work port → tank bleed of the directional valve (m³/(s·Pa)), with the CBVs.
    port_bleed: f64,
    control_dt: f64,
    /// Substeps of the current period.
    substeps: u32,
    /// Most substeps any period may take: the count at the smallest chamber volumes.
    substeps_max: u32,
    /// `Some(max ω·h)`: automatic substeps re-chosen every period from the volumes the
    /// piston can reach within it (`exponential_euler` with `integration.substeps = 0`).
    adaptive: Option<f64>,
    /// Substeps taken since the start (for cost figures).
    substeps_taken: u64,
    /// Fastest mode the substep must resolve (rad/s), at the smallest chamber volumes: the
    /// one the substep rule holds to ω·h ≤ `max_omega_h` ([`Plant::fastest_mode`]).
    omega_max: f64,
    h: f64,
    state: PlantState,
    /// Control periods stepped since the start (the index of the next one).
    cycle: u64,
    /// The effect components ([`effects::Components`]), e.g. the command delay line.
    components: effects::Components,
    /// Bounds of the states the rig can have, checked after every step.
    plausible: crate::plausible::Plausible,
    params: PlantParams,
}

/// A state after a step that no rig can have: non-finite, or beyond the bounds of
/// [`crate::plausible::Plausible`] (`bound` finite). The run must stop.
#[derive(Debug, Clone, PartialEq)]
pub struct NumericalFailure {
    /// Time of the failure (s).
    pub t: f64,
    /// Which state went bad.
    pub what: &'static str,
    /// Its value (in `unit`).
    pub value: f64,
    /// The bound it crossed (in `unit`); NaN for a non-finite state.
    pub bound: f64,
    /// Unit of value and bound ("" for a non-finite state).
    pub unit: &'static str,
}

impl NumericalFailure {
    /// Whether the state is finite but implausible (beyond its bound), rather than
    /// non-finite.
    pub fn is_implausible(&self) -> bool {
        self.bound.is_finite()
    }
}

impl std::fmt::Display for NumericalFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.is_implausible() {
            write!(
                f,
                "plant state `{}` = {:e} {} at t = {} s is beyond what the rig can reach (bound {:e} {}): a simulation fault",
                self.what, self.value, self.unit, self.t, self.bound, self.unit
            )
        } else {
            write!(
                f,
                "plant state `{}` became non-finite at t = {} s",
                self.what, self.t
            )
        }
    }
}

/// Most substeps per control period the automatic choice may take: beyond this a run is
/// slower than real time on a desktop core (≈ 60 ns per substep at 5 kHz), which means a
/// parameter is outside what the rig can be.
pub const MAX_SUBSTEPS: u32 = 10_000;

/// Cross-field checks that the per-field registry cannot express.
pub fn validate(p: &PlantParams) -> Result<(), ConfigError> {
    use crate::params::FlowForm;
    let v = &p.valve;
    let need = |field: &'static str, val: Option<f64>, unit: &str| -> Result<(), ConfigError> {
        if val.is_none() {
            Err(ConfigError::new(
                format!("valve.{field}"),
                format!(
                    "missing; required when valve.flow_form = \"{}\"; expected a number in {unit}",
                    match v.flow_form {
                        FlowForm::Orifice => "orifice",
                        FlowForm::Kq => "kq",
                        FlowForm::PowerLaw => "power_law",
                    }
                ),
            ))
        } else {
            Ok(())
        }
    };
    match v.flow_form {
        FlowForm::Orifice => {
            need(
                "discharge_coefficient",
                v.discharge_coefficient,
                "- (0.01–1)",
            )?;
            need("area_max", v.area_max, "m²")?;
        }
        FlowForm::Kq => {
            need("rated_flow", v.rated_flow, "m³/s")?;
            need("rated_pressure_drop", v.rated_pressure_drop, "Pa")?;
        }
        FlowForm::PowerLaw => {
            need("flow_at_1mpa", v.flow_at_1mpa, "m³/s")?;
            need("exponent", v.exponent, "- (0.05–1)")?;
        }
    }
    if p.supply.tank_pressure >= p.supply.pressure {
        return Err(ConfigError::new(
            "supply.tank_pressure",
            format!(
                "tank pressure {} Pa must be below supply.pressure {} Pa",
                p.supply.tank_pressure, p.supply.pressure
            ),
        ));
    }
    if p.cylinder.initial_position > p.cylinder.stroke {
        return Err(ConfigError::new(
            "cylinder.initial_position",
            format!(
                "{} m lies outside the stroke [0, {}] m",
                p.cylinder.initial_position, p.cylinder.stroke
            ),
        ));
    }
    validate_variants(p)?;
    effects::Components::validate(&p.effects)?;
    if let Some(cb) = p
        .effects
        .counterbalance_valve
        .as_ref()
        .filter(|c| c.enabled)
    {
        if !p.effects.line_dynamics.as_ref().is_some_and(|l| l.enabled) {
            return Err(ConfigError::new(
                "effects.counterbalance_valve",
                "a counterbalance valve sits at the cylinder end of a line: it needs \
                 [effects.line_dynamics]",
            ));
        }
        if cb.setting <= p.supply.tank_pressure {
            return Err(ConfigError::new(
                "effects.counterbalance_valve.setting",
                format!(
                    "setting {} Pa must exceed the tank pressure {} Pa",
                    cb.setting, p.supply.tank_pressure
                ),
            ));
        }
    }
    Ok(())
}

impl Consts {
    /// The plant's constants from `params` and the configured effect components.
    fn new(params: &PlantParams, components: &effects::Components) -> Consts {
        let supply = &components.supply_pressure_drop;
        Consts {
            a_a: params.cylinder.area_a,
            a_b: params.cylinder.area_b,
            v_a0: params.cylinder.dead_volume_a,
            v_b0: params.cylinder.dead_volume_b,
            stroke: params.cylinder.stroke,
            beta0: params.fluid.bulk_modulus,
            beta_max: components.bulk_modulus_pressure.max(),
            p_cav: params.fluid.cavitation_pressure,
            ps0: params.supply.pressure,
            pt: params.supply.tank_pressure,
            mass: params.mechanics.mass,
            damping: params.mechanics.damping + components.friction.viscous(),
            k_load: params.mechanics.load_stiffness,
            k_bristle: components.friction.stiffness(),
            x_contact: params.mechanics.load_contact_position,
            end_stops: params.mechanics.end_stops,
            full_scale: params.valve.command_full_scale,
            supply_r: supply.droop(),
            supply_tau: supply.time_constant(),
            mount: components.flexible_mount.coefficients(),
            body_mount: components.flexible_mount.is_body(),
            line_scale: params.integration.max_omega_h
                / params
                    .integration
                    .max_omega_h_line
                    .unwrap_or(params.integration.max_omega_h),
        }
    }
}

/// The counterbalance valves on sides A and B as configured; an error with implicit lines,
/// which solve each line from the valve port to the chamber.
fn counterbalance_valves(
    params: &PlantParams,
    components: &effects::Components,
) -> Result<[Option<Cbv>; 2], ConfigError> {
    let cbv_cfg = params
        .effects
        .counterbalance_valve
        .as_ref()
        .filter(|c| c.enabled);
    let cbv = [CbvSides::A, CbvSides::B].map(|side| {
        cbv_cfg
            .filter(|c| c.sides == side || c.sides == CbvSides::Both)
            .map(|c| Cbv::new(c, params.fluid.density, params.fluid.bulk_modulus))
    });
    if components.line_dynamics.is_implicit() && cbv.iter().any(|c| c.is_some()) {
        return Err(ConfigError::new(
            "integration.line_method",
            "\"implicit\" solves each line from the valve port to the chamber; with \
             effects.counterbalance_valve between line end and chamber use \"symplectic\"",
        ));
    }
    Ok(cbv)
}

/// Fastest oscillatory mode over the whole stroke (rad/s): the smallest chamber volumes,
/// the lines and valves, and a compliant cylinder body on its mount; an error if it is not
/// representable.
fn fastest_mode_of_rig(
    c: &Consts,
    components: &effects::Components,
    cbv: &[Option<Cbv>; 2],
) -> Result<f64, ConfigError> {
    let mut omega_max = fastest_mode(c, &components.line_dynamics, cbv, c.v_a0, c.v_b0);
    if let (true, Some((ml, km, dm))) = (c.body_mount, c.mount) {
        // A compliant cylinder body sees its mount and the oil column.
        let k_oil = c.beta_max * (c.a_a * c.a_a / c.v_a0 + c.a_b * c.a_b / c.v_b0);
        omega_max = omega_max.max(((km + k_oil) / ml).sqrt()).max(dm / ml);
    }
    if omega_max.is_finite() {
        return Ok(omega_max);
    }
    // e.g. `mechanics.mass = 5e-324`: every parameter is admissible alone, but A/m or
    // β·A²/V overflows and no integrator (nor the exact discretisation) can step it.
    let path = if !(c.a_a / c.mass).is_finite() || !(c.k_load / c.mass).is_finite() {
        "mechanics.mass"
    } else {
        "cylinder.dead_volume_a"
    };
    Err(ConfigError::new(
        path,
        format!(
            "the fastest mode of this rig is not representable (ω = {omega_max:e} rad/s from the hydraulic spring √(β·A²/(V·m)), load spring, mount or lines); check the mass (kg), chamber volumes (m³), areas (m²) and stiffnesses (N/m) for values off by many orders of magnitude"
        ),
    ))
}

/// Whether the plant steps with `linear_exact`. It covers chambers, leakage, springs,
/// dampers and the mount; with lines, friction (stick) or the grey-box polynomial effects the
/// plant integrates with `exponential_euler` instead (e.g. when `ehactl diagnose` adds such
/// an effect to a `linear_exact` rig); [`Plant::method`] tells which one runs.
fn runs_linear_exact(params: &PlantParams, components: &effects::Components, c: &Consts) -> bool {
    let e = &params.effects;
    let (k_ext, k_ext_b) = components.external_leakage.conductances();
    params.integration.method == crate::params::IntegrationMethod::LinearExact
        && !components.line_dynamics.is_active()
        && !components.friction.is_active()
        && !e.polynomial_force.is_some_and(|f| f.enabled)
        && !e.polynomial_flow.is_some_and(|f| f.enabled)
        // The structural effect variants are integrated by the exponential-Euler substep only.
        && !c.body_mount
        && components.bulk_modulus_pressure.is_linear()
        && k_ext_b == k_ext
        && components.supply_pressure_drop.is_linear()
}

/// Substeps per control period: the configured number, else enough for ω·h ≤
/// `integration.max_omega_h` at the fastest mode `omega_max` (rad/s), at most
/// [`MAX_SUBSTEPS`].
fn substeps_for(params: &PlantParams, control_dt: f64, omega_max: f64) -> Result<u32, ConfigError> {
    if params.integration.substeps > 0 {
        return Ok(params.integration.substeps);
    }
    let n = (control_dt * omega_max / params.integration.max_omega_h).ceil();
    if n.is_nan() || n > MAX_SUBSTEPS as f64 {
        return Err(ConfigError::new(
            "integration.substeps",
            format!(
                "the fastest mode of this rig (ω = {omega_max:.3e} rad/s: hydraulic spring, mount or line segments) needs {n:.0} substeps per control period for ω·h ≤ {}; at most {MAX_SUBSTEPS} are allowed (slower than real time); check the line, volume, stiffness and mass parameters or raise integration.max_omega_h",
                params.integration.max_omega_h
            ),
        ));
    }
    Ok(n.max(1.0) as u32)
}

/// The exact discretisation of chambers, leakage, springs and mount at substep `h` (s),
/// at the initial position (re-discretised at the first substep if β(p) or the volume
/// differs by more than the tolerance).
fn linear_exact_model(
    params: &PlantParams,
    components: &effects::Components,
    c: &Consts,
    h: f64,
) -> Result<LinearExact, ConfigError> {
    let x0 = params.cylinder.initial_position.clamp(0.0, c.stroke);
    // The flow stages' conductances (m³/(s·Pa)): cross-piston k_in, to tank k_A.
    let (k_in, _) = components.internal_leakage.conductances();
    let (k_ext, _) = components.external_leakage.conductances();
    LinearExact::new(
        LinearCoefficients {
            a_a: c.a_a,
            a_b: c.a_b,
            k_in,
            k_ext,
            mass: c.mass,
            damping: c.damping,
            k_load: c.k_load,
            x_contact: c.x_contact,
            mount: c.mount,
        },
        h,
        c.beta0 / (c.v_a0 + c.a_a * x0),
        c.beta0 / (c.v_b0 + c.a_b * (c.stroke - x0)),
    )
    .ok_or_else(|| {
        ConfigError::new(
            "mechanics.mass",
            format!("the chambers, mass and springs give a system matrix A·h (h = {h:e} s) beyond what the exact discretisation can represent (‖A·h‖₁ > {:e}); check the mass (kg), chamber volumes (m³), areas (m²), stiffnesses (N/m) and damping (N·s/m)", crate::exact::EXPM_MAX_NORM),
        )
    })
}

impl Plant {
    /// Validate, derive constants, choose the substep and allocate (configure phase).
    /// `control_dt` is the control period (s).
    pub fn configure(params: &PlantParams, control_dt: f64) -> Result<Plant, ConfigError> {
        validate(params)?;
        if !(control_dt.is_finite() && control_dt > 0.0) {
            return Err(ConfigError::new(
                "run.control_rate_hz",
                "control period must be finite and > 0 s",
            ));
        }
        let e = &params.effects;
        // The effect components first: the constants below read the force stage's.
        let setup = effects::Setup {
            control_dt,
            supply_pressure: params.supply.pressure,
            bulk_modulus: params.fluid.bulk_modulus,
            density: params.fluid.density,
            kinematic_viscosity: params.fluid.kinematic_viscosity,
            implicit_lines: params.integration.line_method == crate::params::LineMethod::Implicit,
        };
        let mut components = effects::Components::configure(e, &setup);
        let c = Consts::new(params, &components);
        let cbv_cfg = e.counterbalance_valve.as_ref().filter(|c| c.enabled);
        let cbv = counterbalance_valves(params, &components)?;
        // Checked for every rig: its fastest mode must be representable.
        let rig_mode = fastest_mode_of_rig(&c, &components, &cbv)?;
        let linear_exact = runs_linear_exact(params, &components, &c);
        let omega_max = if linear_exact {
            // Hydraulic spring, load spring and mount are exact: the step is limited only by
            // what enters explicitly, the spool (its mid-step position sets the valve flow)
            // and the supply sag.
            let spool = components.valve_dynamics.bandwidth();
            if components.supply_pressure_drop.is_active() {
                spool.max(1.0 / c.supply_tau)
            } else {
                spool
            }
        } else {
            rig_mode
        };
        let substeps = substeps_for(params, control_dt, omega_max)?;
        let h = control_dt / substeps as f64;
        components.line_dynamics.discretise(h);
        // The spool stage (`valve_dynamics`) at the substep. The automatic substep rule may
        // later take any h up to the control period: the spool must discretise there too
        // (‖A·h‖₁ grows with h).
        components.valve_dynamics.discretise(control_dt)?;
        components.valve_dynamics.discretise(h)?;
        let linear = if linear_exact {
            Some(linear_exact_model(params, &components, &c, h)?)
        } else {
            None
        };
        // The edge law; its lap and limit stages are the components (`valve_deadband`,
        // `valve_saturation`) as configured.
        let edges = EdgeLaw::new(params);
        let plausible = crate::plausible::Plausible::new(
            params,
            &edges,
            &components.valve_saturation,
            control_dt,
            c.beta_max,
        );
        let mut plant = Plant {
            edges,
            plausible,
            linear,
            poly: e.polynomial_force.filter(|f| f.enabled),
            dahl_z: 0.0,
            poly_flow: e.polynomial_flow.filter(|f| f.enabled),
            excitation: ExcitationModel::new(&params.excitation),
            sensors: SensorModel::new(&params.sensors),
            cbv,
            port_bleed: cbv_cfg.map_or(0.0, |c| c.port_bleed),
            control_dt,
            substeps,
            substeps_max: substeps,
            adaptive: (params.integration.substeps == 0 && !linear_exact)
                .then_some(params.integration.max_omega_h),
            substeps_taken: 0,
            omega_max,
            h,
            state: PlantState::default(),
            cycle: 0,
            components,
            params: params.clone(),
            c,
        };
        plant.initialize();
        Ok(plant)
    }

    /// Reset to the initial state (initialize phase): at rest at the initial position with
    /// chamber pressures from the config or from the force balance of 003 eq. 14.
    pub fn initialize(&mut self) {
        let c = &self.c;
        let cyl = &self.params.cylinder;
        let x0 = cyl.initial_position;
        let f_ext0 = self.excitation.force(0.0);
        let f_poly0 = self.poly.map_or(0.0, |f| f.force(x0, 0.0, 0.0, 0.0).0);
        let f_load0 = f_ext0 + c.k_load * (x0 - c.x_contact) + f_poly0;
        // 003 eq. 14 with α = A₂/A₁ and p_L = F/A₁.
        let alpha = c.a_b / c.a_a;
        let p_l = f_load0 / c.a_a;
        let a3 = alpha.powi(3);
        let span = c.ps0 - c.pt;
        let p10 = c.pt + (a3 * span + p_l) / (1.0 + a3);
        let p20 = c.pt + alpha * alpha * (span - p_l) / (1.0 + a3);
        let p_a = cyl.initial_pressure_a.unwrap_or(p10).max(c.p_cav);
        let p_b = cyl.initial_pressure_b.unwrap_or(p20).max(c.p_cav);
        self.state = PlantState {
            t: 0.0,
            command: 0.0,
            spool: 0.0,
            spool_velocity: 0.0,
            p_a,
            p_b,
            p_s: c.ps0,
            x: x0,
            v: 0.0,
            // With a compliant cylinder mount x_load is the body's displacement.
            x_load: self.components.flexible_mount.initial_load_position(x0),
            v_load: 0.0,
            q_a: 0.0,
            q_b: 0.0,
            friction: 0.0,
            external: f_ext0,
            rod_force: f_load0,
            // A run starts at rest, held by friction if there is any.
            stuck: self.components.friction.is_active(),
        };
        self.dahl_z = 0.0;
        for (cb, p) in self.cbv.iter_mut().zip([p_a, p_b]) {
            if let Some(cb) = cb {
                cb.s = CbvState {
                    p_node: p,
                    opening: 0.0,
                    q: 0.0,
                };
            }
        }
        self.cycle = 0;
        if self.substeps != self.substeps_max {
            self.set_substeps(self.substeps_max);
        }
        self.substeps_taken = 0;
        self.components.reset();
        // The line stage (`line_dynamics`): every node at its chamber's start pressure.
        self.components.line_dynamics.fill(p_a, p_b);
        self.sensors = SensorModel::new(&self.params.sensors);
    }

    /// Parameters the plant was configured with.
    pub fn params(&self) -> &PlantParams {
        &self.params
    }

    /// Current state.
    pub fn state(&self) -> &PlantState {
        &self.state
    }

    /// Most substeps per control period: the configured count, or with automatic substeps
    /// the count at the smallest chamber volumes (stroke ends); a period mid-stroke may take
    /// fewer ([`Plant::substeps_taken`]).
    #[allow(clippy::misnamed_getters)] // `substeps` is the per-period count in use; this is its maximum
    pub fn substeps(&self) -> u32 {
        self.substeps_max
    }

    /// Fastest mode the substep must resolve (rad/s), at the smallest chamber volumes (stroke
    /// ends): with `exponential_euler` the hydraulic spring √(β·A²/(V·m)) with the load
    /// spring, the mount, line segments and LuGre bristles, whose explicit (symplectic) step
    /// is stable for ω·h < 2; with `linear_exact` what still enters explicitly (spool, supply
    /// sag). ω·h with [`Plant::substep_length`] is the step's stability and accuracy measure.
    pub fn fastest_mode(&self) -> f64 {
        self.omega_max
    }

    /// Substep length (s).
    pub fn substep_length(&self) -> f64 {
        self.h
    }

    /// Control period (s).
    pub fn control_dt(&self) -> f64 {
        self.control_dt
    }

    /// Effective bulk modulus at gauge pressure `p` (Pa): the bulk stage's
    /// (`bulk_modulus_pressure`: β₀ + K_b·p capped (002 eq. 35), or entrained air), β₀
    /// without the effect.
    #[inline]
    pub fn bulk_modulus(&self, p: f64) -> f64 {
        self.components.bulk_modulus_pressure.bulk_modulus(p)
    }

    /// Chamber volumes (m³) at piston position `x` (003 eq. 7–8).
    #[inline]
    pub fn volumes(&self, x: f64) -> (f64, f64) {
        let xc = x.clamp(0.0, self.c.stroke);
        (
            self.c.v_a0 + self.c.a_a * xc,
            self.c.v_b0 + self.c.a_b * (self.c.stroke - xc),
        )
    }

    /// Hydraulic stiffness k = β(A₁²/V₁ + A₂²/V₂) at position `x` (N/m) (003 eq. 15).
    pub fn hydraulic_stiffness(&self, x: f64) -> f64 {
        let (va, vb) = self.volumes(x);
        self.c.beta0 * (self.c.a_a * self.c.a_a / va + self.c.a_b * self.c.a_b / vb)
    }

    /// Pressures at the valve-side ends of the lines A and B (Pa), i.e. at the valve ports
    /// (002: pressures measured at the valve ports differ from the chamber pressures by the
    /// line dynamics of eq. 9–17); `None` without the `line_dynamics` effect, where the port
    /// pressures are the chamber pressures `state().p_a`, `state().p_b`.
    pub fn valve_port_pressures(&self) -> Option<(f64, f64)> {
        self.components.line_dynamics.port_pressures()
    }

    /// State of the counterbalance valves on lines A and B (`None` where none is fitted):
    /// port-2 node pressure (Pa), poppet opening (-), flow into the chamber (m³/s).
    pub fn counterbalance_valves(&self) -> [Option<CbvState>; 2] {
        self.cbv.each_ref().map(|c| c.as_ref().map(|c| c.s))
    }

    /// Names of the continuous states that [`Plant::linear_state`] returns, in order:
    /// spool (if the spool has dynamics), spool velocity (2nd order), p_a, p_b, p_s (with
    /// supply sag), x, v, x_load and v_load (with a flexible mount), then the line node
    /// pressures, segment flows and (unsteady friction) convolution states
    /// `line_a.q[j].y[i]` (m³/s) of line A and line B, the counterbalance valves' node pressure
    /// and opening, and the Dahl state `dahl_z` (-) of a `polynomial_force` with a Dahl term.
    /// Used for linearisation.
    pub fn linear_state_names(&self) -> Vec<String> {
        let mut n = Vec::new();
        let order = self.components.valve_dynamics.order();
        if order >= 1 {
            n.push("spool".to_string());
        }
        if order >= 2 {
            n.push("spool_velocity".to_string());
        }
        n.extend(["p_a", "p_b"].map(String::from));
        if self.c.supply_r > 0.0 {
            n.push("p_s".into());
        }
        n.extend(["x", "v"].map(String::from));
        if self.c.mount.is_some() {
            n.extend(["x_load", "v_load"].map(String::from));
        }
        self.components.line_dynamics.state_names(&mut n);
        for (tag, cb) in ["a", "b"].iter().zip(&self.cbv) {
            if cb.is_some() {
                n.push(format!("cbv_{tag}.p_node"));
                n.push(format!("cbv_{tag}.opening"));
            }
        }
        if self.has_dahl() {
            n.push("dahl_z".into());
        }
        n
    }

    /// Whether the rod force law has a Dahl term (its state z is then a continuous state).
    fn has_dahl(&self) -> bool {
        self.poly.is_some_and(|f| f.dahl != 0.0)
    }

    /// The continuous state as a vector (SI units, order of [`Plant::linear_state_names`]).
    /// Not for the real-time cycle (allocates).
    pub fn linear_state(&self) -> Vec<f64> {
        let s = &self.state;
        let mut v = Vec::new();
        let order = self.components.valve_dynamics.order();
        if order >= 1 {
            v.push(s.spool);
        }
        if order >= 2 {
            v.push(s.spool_velocity);
        }
        v.extend([s.p_a, s.p_b]);
        if self.c.supply_r > 0.0 {
            v.push(s.p_s);
        }
        v.extend([s.x, s.v]);
        if self.c.mount.is_some() {
            v.extend([s.x_load, s.v_load]);
        }
        self.components.line_dynamics.state(&mut v);
        for cb in self.cbv.iter().flatten() {
            v.extend([cb.s.p_node, cb.s.opening]);
        }
        if self.has_dahl() {
            v.push(self.dahl_z);
        }
        v
    }

    /// Overwrite the continuous state from a vector laid out as [`Plant::linear_state`]
    /// (used to perturb the state for linearisation). The stick flag is cleared and the
    /// valve command delay line is left as it is.
    pub fn set_linear_state(&mut self, v: &[f64]) {
        let mut it = v.iter().copied();
        let mut next = || it.next().unwrap_or(0.0);
        let order = self.components.valve_dynamics.order();
        let dahl = self.has_dahl();
        let s = &mut self.state;
        if order >= 1 {
            s.spool = next();
        }
        if order >= 2 {
            s.spool_velocity = next();
        }
        s.p_a = next();
        s.p_b = next();
        if self.c.supply_r > 0.0 {
            s.p_s = next();
        }
        s.x = next();
        s.v = next();
        if self.c.mount.is_some() {
            s.x_load = next();
            s.v_load = next();
        } else {
            s.x_load = s.x;
            s.v_load = s.v;
        }
        s.stuck = false;
        self.components.line_dynamics.set_state(&mut next);
        for cb in self.cbv.iter_mut().flatten() {
            cb.s.p_node = next();
            cb.s.opening = next();
        }
        if dahl {
            self.dahl_z = next();
        }
        self.update_rod_force();
    }

    /// Sample the sensors at the current state.
    pub fn measure(&mut self) -> Measurements {
        let s = &self.state;
        let tv = TrueValues {
            t: s.t,
            force: s.rod_force,
            position: s.x,
            p_a: s.p_a,
            p_b: s.p_b,
            spool: s.spool,
        };
        // The sensor stage (`sensor_tone`) adds its tones to its channel.
        self.sensors.sample(&tv, &mut self.components.sensor_tone)
    }

    /// Automatic substeps for the coming period: ω·h ≤ max ω·h at the smallest chamber
    /// volumes the piston can reach within it (|v| over two periods either side), so a
    /// piston mid-stroke is not integrated at the step its stroke ends would need. Raised at
    /// once, lowered only by a quarter or more (no flapping).
    fn choose_substeps(&mut self, max_omega_h: f64) {
        let c = &self.c;
        let s = &self.state;
        let reach = 2.0 * s.v.abs() * self.control_dt;
        let x_lo = (s.x - reach).clamp(0.0, c.stroke);
        let x_hi = (s.x + reach).clamp(0.0, c.stroke);
        let va = c.v_a0 + c.a_a * x_lo;
        let vb = c.v_b0 + c.a_b * (c.stroke - x_hi);
        let w = fastest_mode(c, &self.components.line_dynamics, &self.cbv, va, vb);
        let n = ((self.control_dt * w / max_omega_h).ceil() as u32).clamp(1, self.substeps_max);
        if n > self.substeps || 4 * n <= 3 * self.substeps {
            self.set_substeps(n);
        }
    }

    /// Re-discretise for `n` substeps per period (no allocation).
    fn set_substeps(&mut self, n: u32) {
        self.substeps = n;
        self.h = self.control_dt / n as f64;
        // h ≤ the control period, at which configure checked the spool: always Ok.
        let _ = self.components.valve_dynamics.discretise(self.h);
        self.components.line_dynamics.discretise(self.h);
    }

    /// Substeps taken since the start (sum over periods; cost figures).
    pub fn substeps_taken(&self) -> u64 {
        self.substeps_taken
    }

    /// Advance one control period with the command `u` (V) held (zero-order hold).
    /// Real-time safe: no allocation, no I/O, bounded time. An error when the state is then
    /// non-finite or beyond what the rig can have ([`crate::plausible`]).
    pub fn step(&mut self, u: f64) -> Result<(), NumericalFailure> {
        if let Some(moh) = self.adaptive {
            self.choose_substeps(moh);
        }
        self.substeps_taken += self.substeps as u64;
        let u = if u.is_finite() { u } else { 0.0 };
        self.components.time_delay.push(self.cycle, u);
        let t0 = self.state.t;
        for i in 0..self.substeps {
            let t = t0 + i as f64 * self.h;
            let uc = self.components.time_delay.command(self.cycle, t, self.h);
            self.advance_substep(t, uc);
        }
        self.update_rod_force();
        self.cycle += 1;
        // Time from the cycle count, so it does not drift by summed rounding.
        self.state.t = self.cycle as f64 * self.control_dt;
        self.check()
    }

    fn check(&self) -> Result<(), NumericalFailure> {
        let s = &self.state;
        let bad = [
            ("p_a", s.p_a),
            ("p_b", s.p_b),
            ("x", s.x),
            ("v", s.v),
            ("spool", s.spool),
            ("x_load", s.x_load),
            ("p_s", s.p_s),
        ]
        .into_iter()
        .find(|(_, v)| !v.is_finite());
        if let Some((what, value)) = bad {
            return Err(NumericalFailure {
                t: s.t,
                what,
                value,
                bound: f64::NAN,
                unit: "",
            });
        }
        match self.plausible.check(s) {
            Some((what, value, bound, unit)) => Err(NumericalFailure {
                t: s.t,
                what,
                value,
                bound,
                unit,
            }),
            None => Ok(()),
        }
    }

    /// The bounds of the states this rig can have (the check after every step).
    pub fn plausible(&self) -> &crate::plausible::Plausible {
        &self.plausible
    }

    /// The integration scheme that runs (`linear_exact` only where it applies, see
    /// [`Plant::configure`]).
    pub fn method(&self) -> crate::params::IntegrationMethod {
        if self.linear.is_some() {
            crate::params::IntegrationMethod::LinearExact
        } else {
            crate::params::IntegrationMethod::ExponentialEuler
        }
    }

    /// Times the `linear_exact` transition was computed (0 for `exponential_euler`).
    pub fn discretisations(&self) -> u64 {
        self.linear.as_ref().map_or(0, |l| l.count)
    }

    /// One substep of `linear_exact` ([`crate::exact`]): spool exact; valve flow at the
    /// mid-step spool opening, linearised in its port pressure about the start of the step
    /// and evaluated at the step-mean pressure of the exact linear solution (second order;
    /// the self term solved implicitly, so the stiff flow–pressure term stays stable);
    /// external force at mid-step; then the exact linear transition.
    #[inline]
    fn advance_substep_linear(&mut self, t: f64, u: f64) {
        let h = self.h;
        let c = &self.c;
        let mut s = self.state;
        s.command = u;
        // The amplifier's offset and dead zone (`valve_deadband` variant `amplifier`), as in
        // `advance_substep`.
        let target = self.components.valve_deadband.target(u / c.full_scale);
        // The spool stage (`valve_dynamics`): its mid-step position opens the edges.
        let spool = &self.components.valve_dynamics;
        let sm = spool.midstep(s.spool, s.spool_velocity, target);
        spool.advance(&mut s.spool, &mut s.spool_velocity, target);
        let (lap, limit) = (
            &self.components.valve_deadband,
            &self.components.valve_saturation,
        );
        let o = self.edges.openings(lap, limit, sm);
        let (va, vb) = self.volumes(s.x);
        let ca = self.bulk_modulus(s.p_a) / va;
        let cb = self.bulk_modulus(s.p_b) / vb;
        let (qa, dqa, qsa) = self.edges.port(limit, o[0], o[1], s.p_s, c.pt, s.p_a);
        let (qb, dqb, qsb) = self.edges.port(limit, o[2], o[3], s.p_s, c.pt, s.p_b);
        let f_mid = self.excitation.force(t + 0.5 * h);
        let lin = self.linear.as_mut().expect("linear_exact configured");
        if lin.stale(ca, cb) {
            // `false` (A·h beyond what expm represents, only near zero volume with
            // absurd parameters) keeps the previous, finite Φ.
            let _ = lin.discretise(ca, cb);
        }
        let mut z = [s.p_a, s.p_b, s.x, s.v, s.x_load, s.v_load];
        // Valve flow at the step-mean pressures: Q = Q₀ + dQ/dp·(p̄(Q) − p₀), with p̄ linear
        // in Q through the exact solution (self-coupling solved, cross-coupling predicted).
        let (pm, dpm) = lin.mean_pressures(&z, &[qa, qb, f_mid, 1.0]);
        let qa_eff = qa + dqa * (pm[0] - s.p_a) / (1.0 - dqa * dpm[0]);
        let qb_eff = qb + dqb * (pm[1] - s.p_b) / (1.0 - dqb * dpm[1]);
        lin.advance(&mut z, &[qa_eff, qb_eff, f_mid, 1.0]);
        s.p_a = z[0].max(c.p_cav);
        s.p_b = z[1].max(c.p_cav);
        s.x = z[2];
        s.v = z[3];
        if c.mount.is_some() {
            s.x_load = z[4];
            s.v_load = z[5];
        } else {
            s.x_load = s.x;
            s.v_load = s.v;
        }
        s.q_a = qa_eff;
        s.q_b = qb_eff;
        if c.supply_r > 0.0 {
            let target = (c.ps0 - c.supply_r * (qsa + qsb)).max(c.pt);
            s.p_s += (target - s.p_s) * (1.0 - (-h / c.supply_tau).exp());
        }
        let f_ext = self.excitation.force(t + h);
        s.external = f_ext;
        s.friction = 0.0;
        s.stuck = false;
        if c.end_stops {
            if s.x < 0.0 {
                s.x = 0.0;
                s.v = s.v.max(0.0);
            } else if s.x > c.stroke {
                s.x = c.stroke;
                s.v = s.v.min(0.0);
            }
        }
        self.state = s;
    }

    #[inline]
    fn advance_substep(&mut self, t: f64, u: f64) {
        if self.linear.is_some() {
            return self.advance_substep_linear(t, u);
        }
        let h = self.h;
        let c = &self.c;
        let mut s = self.state;
        s.command = u;
        // 1. Spool: the spool stage (`valve_dynamics`) towards the edge law's target.
        let target = self.components.valve_deadband.target(u / c.full_scale);
        self.components
            .valve_dynamics
            .advance(&mut s.spool, &mut s.spool_velocity, target);
        let (lap, limit) = (
            &self.components.valve_deadband,
            &self.components.valve_saturation,
        );
        let o = self.edges.openings(lap, limit, s.spool);
        // 2. Pressures: each chamber's balance (crate::chambers) and the line stage
        // (`line_dynamics`) between it and its valve port.
        let leaks = self.leaks(&s);
        let (q_sa, q_sb) = self.advance_chambers(&mut s, o, &leaks);
        let c = &self.c;
        // The supply stage (`supply_pressure_drop`: the sag towards p_s0 − R·Q_s (000) or
        // the pump's flow limit); p_s stays without it.
        s.p_s = self
            .components
            .supply_pressure_drop
            .advance(s.p_s, q_sa + q_sb, c.pt, h);
        // 3. Mechanics.
        self.advance_mechanics(&mut s, t);
        self.state = s;
    }

    /// The flow stages (`internal_leakage`, `external_leakage`) at the start of a substep
    /// from the state `s`: cross-piston flow A→B less the grey-box B→A flow
    /// (crate::effects::PolynomialFlow), flows to tank, and their conductances for the
    /// chambers' linearisation.
    #[inline(always)]
    fn leaks(&self, s: &PlantState) -> Leaks {
        let leak_in = &self.components.internal_leakage;
        let leak_ext = &self.components.external_leakage;
        let ((q_in, _), (k_in, _)) = leak_in.linearised(s.p_a, s.p_b);
        let q_in = q_in - self.poly_flow.as_ref().map_or(0.0, |f| f.flow(s.spool));
        let ((q_ext_a, q_ext_b), (k_ext, k_ext_b)) = leak_ext.linearised(s.p_a, s.p_b);
        Leaks {
            q_in,
            q_ext: [q_ext_a, q_ext_b],
            k_in,
            k_ext: [k_ext, k_ext_b],
        }
    }

    /// Chamber A's (`b` false) or B's balance at the state `s` with the flow stages
    /// `leaks`: its pressure, bulk modulus, volume (003 eq. 7–8), the piston's displacement
    /// flow and the leakages. Built where the coupling steps it, from the start-of-substep
    /// values.
    #[inline(always)]
    fn chamber(
        c: &Consts,
        bulk: &effects::bulk_modulus_pressure::BulkModulus,
        s: &PlantState,
        leaks: &Leaks,
        b: bool,
    ) -> Chamber {
        let xc = s.x.clamp(0.0, c.stroke);
        if b {
            Chamber {
                p: s.p_b,
                beta: bulk.bulk_modulus(s.p_b),
                volume: c.v_b0 + c.a_b * (c.stroke - xc),
                piston: c.a_b * s.v,
                cross: leaks.q_in,
                q_ext: leaks.q_ext[1],
                k_in: leaks.k_in,
                k_ext: leaks.k_ext[1],
            }
        } else {
            Chamber {
                p: s.p_a,
                beta: bulk.bulk_modulus(s.p_a),
                volume: c.v_a0 + c.a_a * xc,
                piston: -c.a_a * s.v,
                cross: -leaks.q_in,
                q_ext: leaks.q_ext[0],
                k_in: leaks.k_in,
                k_ext: leaks.k_ext[0],
            }
        }
    }

    /// Step 3 of a substep `h` from `t` (s): the mechanics of the state `s`, whose pressures
    /// are already the new ones.
    /// Positions drift with the velocities that drove the pressures, then the velocities
    /// take the forces at the new positions (drift–kick): piston, load and pressures stay at
    /// one time level. Drifting after the kick put the position (and the rod force) one
    /// substep ahead of the pressures, a first-order lead that was 95 % of the test bench's
    /// replay error (BENCHMARKS.md "Diagnosis speed: drift before kick").
    #[inline(always)]
    fn advance_mechanics(&mut self, s: &mut PlantState, t: f64) {
        let h = self.h;
        let c = &self.c;
        s.x += h * s.v;
        let mount = &self.components.flexible_mount;
        mount.drift(&mut s.x_load, s.v_load, h);
        let f_ext = self.excitation.force(t + h);
        s.external = f_ext;
        let f_hyd = s.p_a * c.a_a - s.p_b * c.a_b;
        // Rod force law, linearly implicit in v (stable for a stiff damper or smoothed sign),
        // and the Dahl pre-yield state, backward Euler: F_d·z' = f₀ + d·v' = (f₀ + d·v) +
        // d·(v' − v), folded into the linearisation about v so that the velocity update
        // stays one division. One look at the law (`as_ref`: no copy of it per substep).
        let (f_poly, df_poly, f_dahl0, d_dahl) = match self.poly.as_ref() {
            Some(f) => {
                let (f_poly, df_poly) = f.force(s.x, s.v, s.p_a, s.p_b);
                let (f_dahl0, d_dahl) = f.dahl_implicit(self.dahl_z, s.v, h);
                // A falling branch stays explicit.
                (f_poly, df_poly.max(0.0), f_dahl0, d_dahl)
            }
            None => (0.0, 0.0, 0.0, 0.0),
        };
        let (f_poly, df_poly) = (f_poly + f_dahl0 + d_dahl * s.v, df_poly + d_dahl);
        let v_old = s.v;
        // The mount stage (`flexible_mount`): hydraulic force, load spring, mount and
        // external force where each acts on the piston, and the mount's implicit damping.
        let piston = PistonForces {
            x: s.x,
            v: s.v,
            f_hyd,
            f_ext,
            friction: s.friction,
            spring: LoadSpring {
                stiffness: c.k_load,
                contact: c.x_contact,
            },
            mass: c.mass,
            damping: c.damping,
        };
        let (f_mounted, d_mount) = mount.piston_force(&piston, &mut s.x_load, &mut s.v_load, h);
        let f_other = f_mounted - f_poly + df_poly * s.v;
        let m_eff = c.mass + h * (c.damping + d_mount + df_poly);
        let v_free = (c.mass * s.v + h * f_other) / m_eff;
        // The force stage (`friction`: stick projection, Stribeck slip or LuGre bristles).
        let kick = self.components.friction.kick(s.v, v_free, m_eff, h);
        if let Some(f) = self.poly.as_ref() {
            self.dahl_z = f.dahl_advance(self.dahl_z, v_old, kick.v, h);
        }
        s.v = kick.v;
        s.friction = kick.force;
        s.stuck = kick.stuck;
        mount.follow(&mut s.x_load, &mut s.v_load, s.x, s.v, f_ext, h);
        if c.end_stops {
            if s.x < 0.0 {
                s.x = 0.0;
                s.v = s.v.max(0.0);
            } else if s.x > c.stroke {
                s.x = c.stroke;
                s.v = s.v.min(0.0);
            }
        }
    }

    /// Step 2 of a substep: the valve port flows at the pressures the ports see, and the
    /// chambers' balances (crate::chambers) stepped with them, by the one way the
    /// line stage (`line_dynamics`) couples them: ports straight on the chambers (no lines),
    /// the implicit chains valve node → chamber (`integration.line_method = "implicit"`,
    /// [`LineStage::advance_implicit`], the chamber its chain's end node), or the symplectic
    /// nodes ([`LineStage::advance_nodes`]), the counterbalance valves between line end and
    /// chamber ([`cbv_ends`]) and the line flows after the chamber pressures
    /// ([`LineStage::advance_flows`]). Each chamber's balance is built from `s` and the flow
    /// stages `leaks` where it is stepped (`Plant::chamber`). Writes the pressures and port
    /// flows into `s`; returns the flows from supply into ports A and B (m³/s).
    ///
    /// Each way evaluates its own valve ports: one evaluation ahead of the three ways (the
    /// port pressures from an `Option`, the way chosen after it) cost the exponential-Euler
    /// rigs up to 1.7 % of `Plant::step` in register spills (BENCHMARKS.md, "The plant step
    /// per rig").
    #[inline(always)]
    fn advance_chambers(&mut self, s: &mut PlantState, o: [f64; 4], leaks: &Leaks) -> (f64, f64) {
        let (h, pt, p_cav) = (self.h, self.c.pt, self.c.p_cav);
        let (c, bulk) = (&self.c, &self.components.bulk_modulus_pressure);
        let lines = &mut self.components.line_dynamics;
        let limit = &self.components.valve_saturation;
        let ports = lines.port_pressures();
        match ports {
            None => {
                let (qa, dqa, qsa) = self.edges.port(limit, o[0], o[1], s.p_s, pt, s.p_a);
                let (qb, dqb, qsb) = self.edges.port(limit, o[2], o[3], s.p_s, pt, s.p_b);
                (s.q_a, s.q_b) = (qa, qb);
                let (ch_a, ch_b) = (
                    Self::chamber(c, bulk, s, leaks, false),
                    Self::chamber(c, bulk, s, leaks, true),
                );
                s.p_a = ch_a.advance(qa, dqa, 0.0, h, p_cav);
                s.p_b = ch_b.advance(qb, dqb, 0.0, h, p_cav);
                (qsa, qsb)
            }
            Some((port_a, port_b)) if lines.is_implicit() => {
                // Whole chains valve node → chamber, trapezoidal (crate::line); no CBVs here
                // (configure refuses them), the port bleed is theirs too, so 0.
                let (qa, dqa, qsa) = self.edges.port(limit, o[0], o[1], s.p_s, pt, port_a);
                let (qb, dqb, qsb) = self.edges.port(limit, o[2], o[3], s.p_s, pt, port_b);
                (s.q_a, s.q_b) = (qa, qb);
                let ends = [
                    Self::chamber(c, bulk, s, leaks, false).end_node(),
                    Self::chamber(c, bulk, s, leaks, true).end_node(),
                ];
                (s.p_a, s.p_b) = lines.advance_implicit(h, [qa, qb], [dqa, dqb], ends, p_cav);
                (qsa, qsb)
            }
            Some((port_a, port_b)) => {
                // Valve-side nodes, exponential Euler in their own pressure, with the neutral
                // A,B→T bleed of the CBVs (crate::cbv, `port_bleed`).
                let (qa, dqa, qsa) = self.edges.port(limit, o[0], o[1], s.p_s, pt, port_a);
                let (qb, dqb, qsb) = self.edges.port(limit, o[2], o[3], s.p_s, pt, port_b);
                let kb = self.port_bleed;
                let (qa, dqa) = (qa - kb * (port_a - pt), dqa - kb);
                let (qb, dqb) = (qb - kb * (port_b - pt), dqb - kb);
                (s.q_a, s.q_b) = (qa, qb);
                let ends = lines.advance_nodes(h, [qa, qb], [dqa, dqb], p_cav, [s.p_a, s.p_b]);
                let (into, dinto, p_end) = cbv_ends(&mut self.cbv, h, ends, [s.p_a, s.p_b], p_cav);
                let (ch_a, ch_b) = (
                    Self::chamber(c, bulk, s, leaks, false),
                    Self::chamber(c, bulk, s, leaks, true),
                );
                s.p_a = ch_a.advance(into[0], 0.0, dinto[0], h, p_cav);
                s.p_b = ch_b.advance(into[1], 0.0, dinto[1], h, p_cav);
                let has = [self.cbv[0].is_some(), self.cbv[1].is_some()];
                let p_a_end = if has[0] { p_end[0] } else { s.p_a };
                let p_b_end = if has[1] { p_end[1] } else { s.p_b };
                lines.advance_flows(h, [p_a_end, p_b_end]);
                (qsa, qsb)
            }
        }
    }

    /// Rod force (N) at the current state, as the load cell sees it: load spring, mount (or
    /// the external force on a rigid rod) and the grey-box force law. Only the sensors read
    /// it, so [`Plant::step`] computes it once per control period, after the last substep,
    /// not in every substep (the same value: it depends on the state alone).
    fn update_rod_force(&mut self) {
        let c = &self.c;
        let s = &mut self.state;
        let spring = LoadSpring {
            stiffness: c.k_load,
            contact: c.x_contact,
        };
        s.rod_force = self
            .components
            .flexible_mount
            .rod_force(s.x, s.v, s.x_load, s.v_load, s.external, spring)
            + self
                .poly
                .as_ref()
                .map_or(0.0, |f| f.rod_force(s.x, s.v, s.p_a, s.p_b, self.dahl_z));
    }
}

/// The counterbalance valves between the lines' last nodes and the chambers over a
/// substep `h` (s) (crate::cbv): `ends` the lines' (last node pressure (Pa), flow out of the
/// line (m³/s)) on sides A and B, `p_ch` the chamber pressures (Pa). Returns per side the
/// flow into the chamber (m³/s), minus its derivative in the chamber pressure
/// (m³/(s·Pa)) and the pressure at the line's end (Pa): the line's own flow, 0 and the
/// chamber's without a CBV on that side.
///
/// The node (port 2) steps in exponential Euler in its own pressure; the chamber takes the
/// flow the node passed on over the substep (line inflow less the node's storage change), so
/// line, node and chamber exchange exactly the same volume. The CBV flow at the
/// start-of-step node pressure instead over-delivers whenever the check or the poppet opens
/// within the step (node time constant C/G ≈ 1 µs against a 5–20 µs substep): a numerical
/// chatter that needed 4× the substeps to converge (docs/benchmarks-archive.md, "Short
/// stiff lines").
#[inline(always)]
#[allow(clippy::type_complexity)]
fn cbv_ends(
    cbv: &mut [Option<Cbv>; 2],
    h: f64,
    ends: [(f64, f64); 2],
    p_ch: [f64; 2],
    p_cav: f64,
) -> ([f64; 2], [f64; 2], [f64; 2]) {
    let mut into = [ends[0].1, ends[1].1];
    let mut dinto = [0.0; 2];
    let mut p_end = p_ch;
    for i in 0..2 {
        // Pilot: the other line at the cylinder (its CBV node, else its last node).
        let pilot = match &cbv[1 - i] {
            Some(o) => o.s.p_node,
            None => ends[1 - i].0,
        };
        if let Some(cb) = cbv[i].as_mut() {
            let q_line = ends[i].1;
            cb.advance_poppet(h, p_ch[i], pilot);
            let (q, dq) = cb.flow(cb.s.p_node, p_ch[i]);
            let f = (q_line - q) / cb.c_node;
            let w = phi1(-dq / cb.c_node * h);
            let pn = (cb.s.p_node + h * f * w).max(p_cav);
            let q_out = q_line - cb.c_node * (pn - cb.s.p_node) / h;
            cb.s.p_node = pn;
            cb.s.q = q_out;
            into[i] = q_out;
            // ∂q_out/∂p_ch = −(C/h)·(1 − e^(λh)) = −dq·φ₁(λh), λ = −dq/C (→ −dq for λh → 0).
            dinto[i] = dq * w;
            p_end[i] = pn;
        }
    }
    (into, dinto, p_end)
}

/// Fastest oscillatory mode (rad/s) of the `exponential_euler` scheme with chamber volumes
/// `va`, `vb` (m³): hydraulic spring + load spring on the piston mass, mount, line segments,
/// line end against the chamber or a CBV body. The segment mode and the line end against the
/// chamber enter scaled by `max_omega_h / max_omega_h_line` (`Consts::line_scale`), so the
/// rule ω·h ≤ `max_omega_h` on the result holds them to ω·h ≤ `max_omega_h_line`; the
/// line stage adds its modes ([`LineStage::fastest_mode`]). With implicit lines (the
/// trapezoidal chain of [`crate::line::Line::advance_implicit`], stable at any step) the
/// segment modes and the line end against the chamber are no stability limit and the
/// lumping's high modes are numerical, not physical: the line contributes its half-wave mode
/// π/T ([`crate::line::Line::omega_wave`]) only.
#[inline]
fn fastest_mode(c: &Consts, lines: &Lines, cbv: &[Option<Cbv>; 2], va: f64, vb: f64) -> f64 {
    let mut k_total =
        c.beta_max * (c.a_a * c.a_a / va + c.a_b * c.a_b / vb) + c.k_load + c.k_bristle;
    let mut omega_max: f64 = 0.0;
    if let Some((ml, km, dm)) = c.mount {
        k_total += km;
        omega_max = omega_max.max((km / ml).sqrt()).max(dm / ml);
        omega_max = omega_max.max(dm / c.mass);
    }
    omega_max = omega_max.max((k_total / c.mass).sqrt());
    // The line stage (`line_dynamics`): segment modes, wave mode, line ends.
    lines.fastest_mode(
        omega_max,
        c.line_scale,
        va.min(vb) / c.beta_max,
        cbv.each_ref().map(|cb| cb.as_ref().map(|cb| cb.c_node)),
    )
}
