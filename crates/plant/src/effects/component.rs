//! The plant side of a catalogue effect as a component: one type per effect, in the effect's
//! module, that owns its config section's checks, the constants the plant derives from the
//! section, its state and its stage in the substep. The plant ([`crate::model::Plant`])
//! holds every component by value in [`super::Components`] (statically dispatched: no trait
//! objects, no allocation or locking in the cycle) and calls each one in the phases of
//! Hopsan's component life cycle (Hopsan user guide, "Component code": `configure`,
//! `initialize`, `simulateOneTimestep`):
//!
//! | phase | call | may allocate |
//! |---|---|---|
//! | validate (config load) | [`Component::validate`] | yes |
//! | configure ([`crate::model::Plant::configure`]) | [`Component::configure`] | yes |
//! | initialize ([`crate::model::Plant::initialize`]) | [`Component::reset`] | no |
//! | step ([`crate::model::Plant::step`]) | the effect's stage trait: [`CommandStage`], [`LapStage`], [`LimitStage`], [`SpoolStage`], [`SupplyStage`], [`BulkStage`], [`FlowStage`], [`ForceStage`], [`MountStage`], [`LineStage`]; sampling ([`crate::model::Plant::measure`]): [`SensorStage`] | no |
//!
//! A leaf module like `switch.rs`: it uses neither `crate::params` nor the registry
//! (`mod.rs`), so that an effect module can implement it without a file circle
//! (scripts/file_cycles.py).

use crate::spec::ConfigError;
use serde::{Deserialize, Serialize};

/// What a component's configure phase may read besides its own section: quantities the plant
/// owns, as plain numbers in SI units (an effect module does not read `crate::params`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setup {
    /// Control period T (s): the command is held over it (zero-order hold).
    pub control_dt: f64,
    /// Nominal supply pressure p_s0 (Pa, `supply.pressure`).
    pub supply_pressure: f64,
    /// The fluid's bulk modulus β₀ (Pa, `fluid.bulk_modulus`).
    pub bulk_modulus: f64,
    /// The fluid's density ρ (kg/m³, `fluid.density`).
    pub density: f64,
    /// The fluid's kinematic viscosity ν (m²/s, `fluid.kinematic_viscosity`).
    pub kinematic_viscosity: f64,
    /// Whether the line chains are solved whole per substep (`integration.line_method =
    /// "implicit"`) instead of the symplectic node/flow update.
    pub implicit_lines: bool,
}

impl Setup {
    /// The setup the components' unit tests configure against: a 1 kHz control period, a
    /// 20 MPa supply and β₀ = 1.5 GPa.
    #[cfg(test)]
    pub(crate) const TEST: Setup = Setup {
        control_dt: 1e-3,
        supply_pressure: 20e6,
        bulk_modulus: 1.5e9,
        density: 870.0,
        kinematic_viscosity: 4.6e-5,
        implicit_lines: false,
    };
}

/// A catalogue effect on the plant side.
pub trait Component: Sized {
    /// Its config section `[effects.<id>]` (the `#[param]` declarations, in the same module).
    type Section;

    /// Cross-field checks of a present section that the registry's per-field ranges cannot
    /// express (validate phase); the error names the parameter's registry path.
    fn validate(section: &Self::Section) -> Result<(), ConfigError>;

    /// Derive the constants and allocate the state (configure phase) from the section:
    /// `None` when it is absent; a section with `enabled = false` acts as absent.
    fn configure(section: Option<&Self::Section>, setup: &Setup) -> Self;

    /// Back to the initial state (initialize phase): no allocation.
    fn reset(&mut self);
}

/// A component on the command path between the controller and the spool: it sees the
/// command of each control period once and tells the valve the command of each substep.
pub trait CommandStage: Component {
    /// Take the command `u` (V, finite) held over control period `cycle` (0, 1, 2, …, one
    /// call per period, before its substeps). Real-time safe.
    fn push(&mut self, cycle: u64, u: f64);

    /// The command (V) the valve sees over the substep [t, t + h] (s) of period `cycle`,
    /// whose command was the last one pushed; `h` ≤ the control period. Real-time safe.
    fn command(&self, cycle: u64, t: f64, h: f64) -> f64;
}

/// A component between the command path and the metering edges: the spool's own dynamics
/// (`valve_dynamics`), linear and discretised exactly over the substep (zero-order hold on
/// the spool target). Its two states, the spool position and velocity (fractions of full
/// travel, 1/s), are the plant state's `spool` and `spool_velocity`, which the stage
/// advances in place once per substep (step 1 of crates/plant/src/model.rs), before the
/// valve edges open.
pub trait SpoolStage: Component {
    /// Order of the spool model, the count of its states in the linearisation's state
    /// (`Plant::linear_state`): 1 or 2, 0 without the effect.
    fn order(&self) -> u8;

    /// The spool's bandwidth (rad/s), that sets the substep of `integration.method =
    /// "linear_exact"`, where the spool is the fastest part integrated explicitly; 0 for an
    /// ideal spool.
    fn bandwidth(&self) -> f64;

    /// Discretise for the substep `h` (s) (configure phase, and again when the automatic
    /// substep rule changes `h`, for an `h` up to one the call accepted before: no
    /// allocation then). `Err` names the field when the discretisation is not representable
    /// at `h`; the stage then keeps its previous discretisation.
    fn discretise(&mut self, h: f64) -> Result<(), ConfigError>;

    /// Advance the spool position `spool` and velocity `velocity` towards `target`
    /// (fraction of full travel) over one substep. Real-time safe.
    fn advance(&self, spool: &mut f64, velocity: &mut f64, target: f64);

    /// The spool position half a substep on from `spool`, `velocity` towards `target`,
    /// without advancing them (the mid-step opening of `linear_exact`). Real-time safe.
    fn midstep(&self, spool: f64, velocity: f64, target: f64) -> f64;
}

/// A component that sets where the valve's four metering edges open (`valve_deadband`): the
/// spool target from the command (an amplifier's dead zone ahead of the spool), and the
/// spool's zero offset and overlap between its position and the edge openings. The plant calls
/// it in each substep (steps 1 and 2 of crates/plant/src/model.rs: the spool target before
/// the spool stage, then the openings through the valve's edge law, `EdgeLaw` in
/// crates/plant/src/valve.rs, which takes it by reference). All quantities are fractions of full spool travel (-).
pub trait LapStage: Component {
    /// The spool target for the command `c` = u / full scale (-): `c` without an amplifier
    /// dead zone. Real-time safe.
    fn target(&self, c: f64) -> f64;

    /// The spool travel the edges see at the spool position `s`: `s` without a zero
    /// offset. Real-time safe.
    fn travel(&self, s: f64) -> f64;

    /// An edge's opening from `x`, the (limited) travel towards it plus the valve's underlap,
    /// before it is cut at 0: `x` without an overlap. Real-time safe.
    fn lap(&self, x: f64) -> f64;
}

/// A component that limits the valve's metering edges (`valve_saturation`): the spool
/// travel they see (amplifier clipping or the spool's end stops) and the flow through any
/// one edge. The valve's edge law (`EdgeLaw` in crates/plant/src/valve.rs) takes it
/// by reference and calls it in each substep (step 2 of crates/plant/src/model.rs, the openings and the edge
/// flows), after the [`LapStage`]'s zero offset and before its overlap.
pub trait LimitStage: Component {
    /// The spool travel `travel` (fraction of full travel, -) within the travel limits:
    /// `travel` without the effect. Real-time safe.
    fn clip_travel(&self, travel: f64) -> f64;

    /// An edge's flow `q` (m³/s) and its derivative `dq` = dQ/dΔp (m³/(s·Pa)) within the
    /// edge flow limit: (q, dq) without it. Real-time safe.
    fn clip_flow(&self, q: f64, dq: f64) -> (f64, f64);
}

/// What a [`ForceStage`] does to the piston velocity over one substep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kick {
    /// Piston velocity at the end of the substep (m/s).
    pub v: f64,
    /// The stage's force on the piston over the substep, opposing +x (N).
    pub force: f64,
    /// Whether the stage holds the piston at rest (stick).
    pub stuck: bool,
}

/// A component in the piston's force balance whose force depends on the new velocity and on
/// a state of its own (stick, bristles), so that it cannot be one more explicit term: the
/// velocity update of the substep (step 3 of crates/plant/src/model.rs, the kick after the
/// position drift) first solves the rest of the balance, linearly implicit in the damping,
/// for the velocity without the stage, then hands it here.
pub trait ForceStage: Component {
    /// Whether the stage acts (false without the effect: the plant may then use a scheme
    /// that cannot hold it, e.g. `integration.method = "linear_exact"`).
    fn is_active(&self) -> bool;

    /// Viscous coefficient (N·s/m) the stage adds to the mechanical damping; the plant
    /// takes it into the implicit damping of the velocity update (configure phase).
    fn viscous(&self) -> f64;

    /// Stiffness (N/m) the stage puts on the piston mass, that the substep rule must
    /// resolve (configure phase); 0 for a stage without a spring.
    fn stiffness(&self) -> f64;

    /// One substep `h` (s): from the velocity `v_old` (m/s) at its start and the velocity
    /// `v_free` (m/s) the rest of the force balance reaches without the stage, with the
    /// effective mass `m_eff` (kg, the mass with the implicit damping h·c), the new
    /// velocity, the stage's force and whether it holds the piston. Without the effect
    /// `Kick { v: v_free, force: 0, stuck: false }`. Real-time safe.
    fn kick(&mut self, v_old: f64, v_free: f64, m_eff: f64, h: f64) -> Kick;
}

/// The load spring K_L on the piston (`mechanics.load_stiffness`, `load_contact_position`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoadSpring {
    /// Stiffness K_L (N/m).
    pub stiffness: f64,
    /// Piston position at which it is relaxed, x_c (m).
    pub contact: f64,
}

/// The piston's side of the force balance a [`MountStage`] reads in a substep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PistonForces {
    /// Piston position x (m), after the position drift of the substep.
    pub x: f64,
    /// Piston velocity v (m/s) at the start of the substep.
    pub v: f64,
    /// Hydraulic force A_A·p_A − A_B·p_B (N), at the new pressures.
    pub f_hyd: f64,
    /// External force (N), at the end of the substep.
    pub f_ext: f64,
    /// The force stage's force of the previous substep (N): the seal friction.
    pub friction: f64,
    /// The load spring.
    pub spring: LoadSpring,
    /// Piston mass m (kg).
    pub mass: f64,
    /// Viscous damping on the piston d (N·s/m), with the force stage's.
    pub damping: f64,
}

/// The component on the far side of the rod or of the cylinder body: a mass on a
/// spring-damper that the piston's velocity update (step 3 of crates/plant/src/model.rs,
/// drift–kick) couples to. Its two states, the mass's position x_L (m) and velocity v_L
/// (m/s), are the plant state's `x_load` and `v_load`, which the stage advances in place:
/// [`MountStage::drift`] with the piston's position drift, [`MountStage::piston_force`]
/// before the piston's kick, [`MountStage::follow`] after it.
pub trait MountStage: Component {
    /// (mass (kg), stiffness (N/m), damping (N·s/m)) of the mount, `None` without one: the
    /// constants the substep rule and the `linear_exact` scheme read.
    fn coefficients(&self) -> Option<(f64, f64, f64)>;

    /// Whether the compliance is the cylinder body's (x, v then relative to it).
    fn is_body(&self) -> bool;

    /// x_L (m) at the start of a run with the piston at `x0` (m).
    fn initial_load_position(&self, x0: f64) -> f64;

    /// The position drift of x_L over the substep `h` (s) with the velocity `v_load`
    /// (m/s). Real-time safe.
    fn drift(&self, x_load: &mut f64, v_load: f64, h: f64);

    /// The piston's force balance with the mount, before the grey-box and force-stage terms
    /// (N), and the damping (N·s/m) the piston's velocity update takes implicitly; a mount
    /// whose mass moves with the balance advances x_L, v_L here. Real-time safe.
    fn piston_force(
        &self,
        p: &PistonForces,
        x_load: &mut f64,
        v_load: &mut f64,
        h: f64,
    ) -> (f64, f64);

    /// After the piston's kick to the velocity `v` (m/s) at position `x` (m), with the
    /// external force `f_ext` (N): the mass's velocity update over `h` (s). Real-time safe.
    fn follow(&self, x_load: &mut f64, v_load: &mut f64, x: f64, v: f64, f_ext: f64, h: f64);

    /// Rod force (N) the load cell sees from the load spring, the mount and the external
    /// force (without the grey-box force law) at the piston state `x` (m), `v` (m/s).
    fn rod_force(
        &self,
        x: f64,
        v: f64,
        x_load: f64,
        v_load: f64,
        f_ext: f64,
        spring: LoadSpring,
    ) -> f64;
}

/// A component that sets the supply pressure p_s the valve draws from: a state of the plant
/// (`p_s` of the plant state), advanced once per substep after the chamber pressures with
/// the flow the valve took from the supply over it.
pub trait SupplyStage: Component {
    /// Equivalent droop (Pa·s/m³), > 0 when the supply pressure is a state (the substep
    /// rule, `linear_exact` and the linearisation read it); 0 without the effect.
    fn droop(&self) -> f64;

    /// Time constant τ (s) of a first-order supply, as `linear_exact` and the substep rule
    /// read it; 1 s without the effect.
    fn time_constant(&self) -> f64;

    /// Whether the supply is first order in p_s (or absent), which `linear_exact` holds.
    fn is_linear(&self) -> bool;

    /// Whether the effect acts (p_s stays at its initial value without it).
    fn is_active(&self) -> bool;

    /// The supply pressure (Pa) at the end of the substep `h` (s) from `ps` (Pa), with the
    /// supply flow `qs` (m³/s) and the tank pressure `pt` (Pa); `ps` without the effect.
    /// Real-time safe.
    fn advance(&self, ps: f64, qs: f64, pt: f64, h: f64) -> f64;
}

/// A component that takes flow out of the chambers as a function of their pressures: a
/// laminar leakage Q = k·Δp (`internal_leakage`, `external_leakage`). The chamber balances
/// of the substep (step 2 of crates/plant/src/model.rs) subtract its flows and take its
/// conductances into the exponential-Euler linearisation of each chamber in its own
/// pressure; `linear_exact` and the linearisation read the conductances as constants.
pub trait FlowStage: Component {
    /// The flows (m³/s) out of chamber A and out of chamber B at the chamber gauge pressures
    /// `p_a`, `p_b` (Pa); a flow into a chamber is negative. (0, 0) without the effect.
    /// Real-time safe.
    fn flows(&self, p_a: f64, p_b: f64) -> (f64, f64);

    /// ∂(flow out of A)/∂p_a and ∂(flow out of B)/∂p_b (m³/(s·Pa)), constant for a laminar
    /// leakage: what the chamber step takes implicitly; (0, 0) without the effect.
    fn conductances(&self) -> (f64, f64);

    /// [`FlowStage::flows`] at `p_a`, `p_b` (Pa) and [`FlowStage::conductances`]: the one
    /// call of the chamber step, which takes both or neither. Called apart, the step could
    /// take the conductances without the flows, and the stage would still change the
    /// chambers' step (through their linearisation): the registry test would not see the
    /// flows missing. Real-time safe.
    #[inline]
    fn linearised(&self, p_a: f64, p_b: f64) -> ((f64, f64), (f64, f64)) {
        (self.flows(p_a, p_b), self.conductances())
    }
}

/// A component that sets the effective bulk modulus β(p) of the oil in a chamber
/// (`bulk_modulus_pressure`): the chamber balances of the substep (step 2 of
/// crates/plant/src/model.rs) read β at each chamber's pressure at the start of the step;
/// the substep rule and `linear_exact` read its constants.
pub trait BulkStage: Component {
    /// β(p) (Pa) of the oil at gauge pressure `p` (Pa); β₀ (`fluid.bulk_modulus`) without
    /// the effect. Real-time safe.
    fn bulk_modulus(&self, p: f64) -> f64;

    /// The largest β (Pa) a chamber can see, which the substep rule holds the hydraulic
    /// spring to; β₀ without the effect.
    fn max(&self) -> f64;

    /// Whether `linear_exact` holds the law (β(p) re-discretised when it drifts): false for
    /// a law it does not (entrained air).
    fn is_linear(&self) -> bool;
}

/// A measured channel of the sensor set (crates/plant/src/sensors.rs), as a config names it
/// (`[effects.sensor_tone] channel`).
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

/// A component between the true value and the measurement: it adds to a sensor channel's
/// reading (`sensor_tone`), called once per channel each time the plant samples its sensors
/// (once per control period), after the channel's own noise.
pub trait SensorStage: Component {
    /// What the stage adds to channel `ch` (in the channel's unit: N, m or Pa) when it is
    /// sampled at time `t` (s); 0 for a channel it does not act on. Real-time safe.
    fn add(&mut self, ch: SensorChannel, t: f64) -> f64;
}

/// A component between the valve ports and the chambers: the two lumped line chains
/// (`line_dynamics`), valve port A → chamber A and valve port B → chamber B, each a
/// [`super::line_dynamics::line::Line`] of node pressures (Pa), segment flows (m³/s) and
/// unsteady-friction convolution states (m³/s). The valve's metering edges see the
/// valve-side node pressures ([`LineStage::port_pressures`]) instead of the chambers'; the
/// chamber balances take the last segment's flow (step 2 of crates/plant/src/model.rs), with
/// a counterbalance valve (crates/plant/src/cbv.rs) between the line end and the chamber
/// where one is fitted. Without the effect every call is a no-op and the ports see the
/// chambers.
pub trait LineStage: Component {
    /// Whether the lines are present.
    fn is_active(&self) -> bool;

    /// Whether the chains are solved whole per substep ([`LineStage::advance_implicit`],
    /// `integration.line_method = "implicit"`); false without the effect.
    fn is_implicit(&self) -> bool;

    /// Every node of line A at `p_a` and of line B at `p_b` (Pa), at rest: the start of a run
    /// (initialize phase, after [`Component::reset`]). No allocation.
    fn fill(&mut self, p_a: f64, p_b: f64);

    /// The per-substep factors for the substep `h` (s) (configure phase, and again when the
    /// automatic substep rule changes `h`). No allocation.
    fn discretise(&mut self, h: f64);

    /// Pressures (Pa) at the valve-side nodes of lines A and B (the valve ports), `None`
    /// without the effect.
    fn port_pressures(&self) -> Option<(f64, f64)>;

    /// The substep rule: `omega` (rad/s, the fastest mode of the rest of the rig) raised to
    /// the lines' fastest mode. `line_scale` (-) is `max_omega_h / max_omega_h_line`,
    /// `chamber_cap` (m³/Pa) the stiffest chamber's capacitance V_min/β_max, `cbv_caps`
    /// (m³/Pa) the node capacitance of a counterbalance valve at the end of line A, B. With
    /// the symplectic chain: the segment mode (scaled), the wave mode where the segment
    /// modes are held to a stability margin only (`line_scale` < 1), the last segment
    /// against the chamber (scaled) and against each counterbalance valve's node; with the
    /// implicit chain the half-wave mode only. `omega` without the effect.
    fn fastest_mode(
        &self,
        omega: f64,
        line_scale: f64,
        chamber_cap: f64,
        cbv_caps: [Option<f64>; 2],
    ) -> f64;

    /// The symplectic chain's first half of a substep `h` (s): the valve-side nodes in
    /// exponential Euler in their own pressure with the valve flows `q_valve` (m³/s) into
    /// them and their derivatives `dq_valve` (m³/(s·Pa)), then the interior nodes from the
    /// old segment flows, every node floored at `p_cav` (Pa). Returns per line the pressure
    /// (Pa) of its last node and the flow (m³/s) of its last segment, the inflow of the
    /// chamber or counterbalance valve at its end (`p_chamber` (Pa) and 0 for a line without
    /// nodes). Real-time safe.
    fn advance_nodes(
        &mut self,
        h: f64,
        q_valve: [f64; 2],
        dq_valve: [f64; 2],
        p_cav: f64,
        p_chamber: [f64; 2],
    ) -> [(f64, f64); 2];

    /// The symplectic chain's second half: the segment flows over `h` (s) from the new node
    /// pressures with the pressure `p_end` (Pa) at the cylinder end of each line (the
    /// chamber's or the counterbalance valve node's), resistance implicit. Real-time safe.
    fn advance_flows(&mut self, h: f64, p_end: [f64; 2]);

    /// The implicit chain over a substep `h` (s): valve-side node, segments and the chamber
    /// `ends` as the end node of each line, with the valve flows `q_valve` (m³/s) and their
    /// derivatives `dq_valve` (m³/(s·Pa)). Returns the chamber pressures A, B (Pa), every
    /// pressure floored at `p_cav` (Pa). Real-time safe.
    fn advance_implicit(
        &mut self,
        h: f64,
        q_valve: [f64; 2],
        dq_valve: [f64; 2],
        ends: [EndNode; 2],
        p_cav: f64,
    ) -> (f64, f64);

    /// Names of the line states in the linearisation's state (after the plant's own):
    /// `line_a.p[i]`, `line_a.q[j]`, `line_a.q[j].y[i]`, then line B's. Allocates.
    fn state_names(&self, names: &mut Vec<String>);

    /// The line states in the order of [`LineStage::state_names`]. Allocates.
    fn state(&self, v: &mut Vec<f64>);

    /// Overwrite the line states, in the order of [`LineStage::state_names`], from `next`.
    fn set_state(&mut self, next: &mut impl FnMut() -> f64);
}

/// The chamber (or any lumped volume) at the cylinder end of a line, as the end node of
/// [`LineStage::advance_implicit`] (`Line::advance_implicit` in
/// crates/plant/src/effects/line_dynamics/line.rs); its other flows linearised in its own pressure.
#[derive(Debug, Clone, Copy)]
pub struct EndNode {
    /// Pressure at the start of the substep (Pa).
    pub p: f64,
    /// Capacitance V/β (m³/Pa).
    pub cap: f64,
    /// Net flow into the node other than from the line, at `p` (m³/s): −A·v − leakage.
    pub flow: f64,
    /// Its derivative in the node's own pressure (m³/(s·Pa)), ≤ 0 for leakage.
    pub dflow: f64,
}

/// φ₁(z) = (eᶻ − 1)/z (-), the exponential-Euler weight (→ 1 as z → 0) of the plant's
/// pressure nodes: the chambers' (crates/plant/src/model.rs) and the lines' valve-side nodes.
#[inline]
pub fn phi1(z: f64) -> f64 {
    if z.abs() < 1e-6 {
        1.0 + 0.5 * z
    } else {
        z.exp_m1() / z
    }
}
