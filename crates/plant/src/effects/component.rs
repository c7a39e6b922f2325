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
//! | step ([`crate::model::Plant::step`]) | the effect's stage trait: [`CommandStage`], [`ForceStage`] | no |
//!
//! A leaf module like `switch.rs`: it uses neither `crate::params` nor the registry
//! (`mod.rs`), so that an effect module can implement it without a file circle
//! (scripts/file_cycles.py).

use crate::spec::ConfigError;

/// What a component's configure phase may read besides its own section: quantities the plant
/// owns, as plain numbers in SI units (an effect module does not read `crate::params`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setup {
    /// Control period T (s): the command is held over it (zero-order hold).
    pub control_dt: f64,
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
