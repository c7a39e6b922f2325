//! The effect catalogue (docs/design.md): stable ids shared by configs, diagnosis and tests
//! ([`EffectId`]), and the plant side of each catalogue effect, one module per effect (named
//! as the diagnosis side's, crates/ident/src/effects/): its config section `[effects.<id>]`
//! with the `#[param]` declarations, defaults and cross-field checks, and its physics where it
//! is that effect's alone.
//!
//! Adding an effect on the plant side: its module here with its section struct (the
//! `#[param]` declarations, defaults) and its component, a type implementing
//! [`Component`] (cross-field checks, the constants derived from the section, its state and
//! reset) and the trait of its stage: [`CommandStage`] on the command path (`time_delay`:
//! `DelayLine`), [`LapStage`] for where the valve's metering edges open (`valve_deadband`:
//! `Deadband`) and [`LimitStage`] for their travel and flow limits (`valve_saturation`:
//! `Saturation`), [`SpoolStage`] for the spool's dynamics (`valve_dynamics`: `Spool`),
//! [`SupplyStage`] for the supply pressure (`supply_pressure_drop`: `Supply`),
//! [`FlowStage`] for flows out of the chambers (`internal_leakage`: `CrossPiston`,
//! `external_leakage`: `ToTank`), [`BulkStage`] for the chambers' bulk modulus
//! (`bulk_modulus_pressure`: `BulkModulus`), [`ForceStage`] in the piston's velocity update
//! (`friction`: `FrictionStage`), [`MountStage`] for the mass on the far side of the rod or
//! body (`flexible_mount`: `Mount`), [`LineStage`] for the line chains between the valve
//! ports and the chambers (`line_dynamics`: `Lines`) or [`SensorStage`] on a measured channel
//! (`sensor_tone`: `Tones`), or a new stage trait in `component.rs` where the effect acts elsewhere
//! (statically dispatched, no allocation in the step); registered by one line in
//! `components!` below. What the configure phase may read besides the section is in
//! [`Setup`] (plain numbers the plant owns; add a field there if the effect needs another).
//! Beside it here: its `pub mod` line, its `EffectId` variant with the lines in
//! [`EffectId::ALL`], [`EffectId::as_str`] and the [`Effects`] switch matches below
//! (exhaustive: a new id does not build without them); in crates/plant/src/params.rs its
//! `Option` field in [`Effects`] and its re-export line. In [`crate::model`] the component's
//! stage is called where the cycle reaches it (`Plant::step` calls `time_delay`'s `push`
//! once per period and `command` per substep; `Plant::advance_substep` calls
//! `valve_deadband`'s `target`, then `valve_dynamics`'s `advance` (and
//! `advance_substep_linear` its `midstep` too), then the valve's edge law (`EdgeLaw` in
//! crates/plant/src/valve.rs, which takes the two edge components by reference) for the
//! `openings` (the lap stage's `travel`, the limit stage's `clip_travel`, the lap stage's
//! `lap`) and in its `port` flows the limit stage's `clip_flow`; reads
//! `bulk_modulus_pressure`'s `bulk_modulus` (through `Plant::bulk_modulus`) and the two
//! leakages' `flows` and `conductances` (one call, `linearised`) into the chambers'
//! balances (crates/plant/src/chambers.rs, written once); `Plant::advance_chambers` reads
//! `line_dynamics`' `port_pressures` (the pressures the valve ports see) and couples the ports to the
//! chambers in one of three ways: directly, through the lines' `advance_implicit`
//! (`integration.line_method = "implicit"`) or, symplectic, their `advance_nodes` before the
//! counterbalance valves (crates/plant/src/cbv.rs, which the plant keeps: they sit between
//! a line's end and its chamber) and `advance_flows` after the chamber pressures; `supply_pressure_drop`'s `advance` after the chamber pressures,
//! `flexible_mount`'s `drift` with the position drift, its `piston_force` and `friction`'s
//! `kick` in the velocity update and the mount's `follow` after it;
//! `Plant::update_rod_force` the mount's `rod_force`; `Plant::measure` hands `sensor_tone` to
//! the sensor model, whose `sample` calls its `add` per channel); `Plant::configure` reads the
//! constants the plant folds into its own: friction's viscous coefficient and bristle
//! stiffness, the mount's coefficients, the supply's droop and time constant, the bulk
//! stage's β_max and `is_linear`, the spool's bandwidth, the leakages' conductances and
//! whether lines are present (`is_active`, `is_implicit`) for the substep rule,
//! `linear_exact` and the linearisation, and calls the spool's and the lines' `discretise`
//! once the substep is chosen, as `Plant::set_substeps` does when it changes; the substep
//! rule (`fastest_mode` in model.rs) adds the lines' `fastest_mode`; `Plant::initialize`
//! `fill`s the lines at the chambers' start pressures after the reset; the linearisation's
//! state reads the spool's `order` and the lines' `state_names` / `state` / `set_state`);
//! validation, configuration and reset go through [`Components`]; every catalogue effect is
//! a component. The registry test `every_registered_effect_acts_on_the_cycle` (below)
//! holds the two lists together and the cycle to its components: `components!` and
//! [`EffectId::ALL`] name the same effects, and each effect's section (its line in the
//! test's exhaustive `acting_section`) changes what the sensors read, so a stage the plant
//! never calls fails there instead of silently doing nothing.
//!
//! `polynomial_force` / `polynomial_flow` are the grey-box extension of `ehactl diagnose`, not
//! catalogue effects; their sections are in crates/plant/src/params.rs, their laws below.

use crate::params::Effects;
pub use crate::params::{PolynomialFlow, PolynomialForce};

pub mod bulk_modulus_pressure;
pub mod component;
pub mod flexible_mount;
pub mod friction;
pub mod leakage;
pub mod line_dynamics;
pub mod sensor_tone;
pub mod supply_pressure_drop;
mod switch;
pub mod time_delay;
pub mod valve_deadband;
pub mod valve_dynamics;
pub mod valve_saturation;

pub use bulk_modulus_pressure::entrained_air_bulk_modulus;
pub use component::{
    phi1, BulkStage, CommandStage, Component, EndNode, FlowStage, ForceStage, Kick, LapStage,
    LimitStage, LineStage, LoadSpring, MountStage, PistonForces, SensorChannel, SensorStage, Setup,
    SpoolStage, SupplyStage,
};
pub use flexible_mount::body_mount_step;
pub use supply_pressure_drop::SupplyModel;

/// One effect of the catalogue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum EffectId {
    /// Static + Coulomb + viscous + Stribeck seal friction (001, 003 eq. 5, 004 eq. 28–34).
    Friction,
    /// Spool overlap / dead zone / zero offset (002, 003, 004).
    ValveDeadband,
    /// Spool travel or flow limit (002, 004).
    ValveSaturation,
    /// Spool dynamics (000, 002, 003, 004).
    ValveDynamics,
    /// Cross-piston leakage (003 k_l, 004 C_in).
    InternalLeakage,
    /// Leakage to tank (003 k_le).
    ExternalLeakage,
    /// Pressure-dependent bulk modulus (002 eq. 35–36).
    BulkModulusPressure,
    /// Lines between valve and cylinder (001, 002 eq. 9–17).
    LineDynamics,
    /// Compliant connection to a load mass (003 SDD).
    FlexibleMount,
    /// Transport / communication delay.
    TimeDelay,
    /// Periodic disturbance on a sensor (004).
    SensorTone,
    /// Supply pressure sags with flow (000).
    SupplyPressureDrop,
}

impl EffectId {
    /// Every effect, in catalogue order.
    pub const ALL: [EffectId; 12] = [
        EffectId::Friction,
        EffectId::ValveDeadband,
        EffectId::ValveSaturation,
        EffectId::ValveDynamics,
        EffectId::InternalLeakage,
        EffectId::ExternalLeakage,
        EffectId::BulkModulusPressure,
        EffectId::LineDynamics,
        EffectId::FlexibleMount,
        EffectId::TimeDelay,
        EffectId::SensorTone,
        EffectId::SupplyPressureDrop,
    ];

    /// The stable id string.
    pub fn as_str(self) -> &'static str {
        match self {
            EffectId::Friction => "friction",
            EffectId::ValveDeadband => "valve_deadband",
            EffectId::ValveSaturation => "valve_saturation",
            EffectId::ValveDynamics => "valve_dynamics",
            EffectId::InternalLeakage => "internal_leakage",
            EffectId::ExternalLeakage => "external_leakage",
            EffectId::BulkModulusPressure => "bulk_modulus_pressure",
            EffectId::LineDynamics => "line_dynamics",
            EffectId::FlexibleMount => "flexible_mount",
            EffectId::TimeDelay => "time_delay",
            EffectId::SensorTone => "sensor_tone",
            EffectId::SupplyPressureDrop => "supply_pressure_drop",
        }
    }

    /// Parse an id string.
    pub fn parse(s: &str) -> Option<EffectId> {
        EffectId::ALL.iter().copied().find(|e| e.as_str() == s)
    }
}

impl std::fmt::Display for EffectId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl Effects {
    /// Whether an effect is present and enabled.
    pub fn is_enabled(&self, id: EffectId) -> bool {
        match id {
            EffectId::Friction => self.friction.as_ref().is_some_and(|e| e.enabled),
            EffectId::ValveDeadband => self.valve_deadband.as_ref().is_some_and(|e| e.enabled),
            EffectId::ValveSaturation => self.valve_saturation.as_ref().is_some_and(|e| e.enabled),
            EffectId::ValveDynamics => self.valve_dynamics.as_ref().is_some_and(|e| e.enabled),
            EffectId::InternalLeakage => self.internal_leakage.as_ref().is_some_and(|e| e.enabled),
            EffectId::ExternalLeakage => self.external_leakage.as_ref().is_some_and(|e| e.enabled),
            EffectId::BulkModulusPressure => self
                .bulk_modulus_pressure
                .as_ref()
                .is_some_and(|e| e.enabled),
            EffectId::LineDynamics => self.line_dynamics.as_ref().is_some_and(|e| e.enabled),
            EffectId::FlexibleMount => self.flexible_mount.as_ref().is_some_and(|e| e.enabled),
            EffectId::TimeDelay => self.time_delay.as_ref().is_some_and(|e| e.enabled),
            EffectId::SensorTone => self.sensor_tone.as_ref().is_some_and(|e| e.enabled),
            EffectId::SupplyPressureDrop => self
                .supply_pressure_drop
                .as_ref()
                .is_some_and(|e| e.enabled),
        }
    }

    /// The `enabled` switch of effect `id`'s section, `None` when the section is absent.
    pub fn enabled_mut(&mut self, id: EffectId) -> Option<&mut bool> {
        match id {
            EffectId::Friction => self.friction.as_mut().map(|e| &mut e.enabled),
            EffectId::ValveDeadband => self.valve_deadband.as_mut().map(|e| &mut e.enabled),
            EffectId::ValveSaturation => self.valve_saturation.as_mut().map(|e| &mut e.enabled),
            EffectId::ValveDynamics => self.valve_dynamics.as_mut().map(|e| &mut e.enabled),
            EffectId::InternalLeakage => self.internal_leakage.as_mut().map(|e| &mut e.enabled),
            EffectId::ExternalLeakage => self.external_leakage.as_mut().map(|e| &mut e.enabled),
            EffectId::BulkModulusPressure => {
                self.bulk_modulus_pressure.as_mut().map(|e| &mut e.enabled)
            }
            EffectId::LineDynamics => self.line_dynamics.as_mut().map(|e| &mut e.enabled),
            EffectId::FlexibleMount => self.flexible_mount.as_mut().map(|e| &mut e.enabled),
            EffectId::TimeDelay => self.time_delay.as_mut().map(|e| &mut e.enabled),
            EffectId::SensorTone => self.sensor_tone.as_mut().map(|e| &mut e.enabled),
            EffectId::SupplyPressureDrop => {
                self.supply_pressure_drop.as_mut().map(|e| &mut e.enabled)
            }
        }
    }

    /// Ids of every enabled effect.
    pub fn enabled(&self) -> Vec<EffectId> {
        EffectId::ALL
            .iter()
            .copied()
            .filter(|e| self.is_enabled(*e))
            .collect()
    }
}

/// Declares [`Components`], the plant's effect components, one field per effect named as its
/// section in [`Effects`], with the phases that run every component in declaration order.
macro_rules! components {
    ($($id:ident: $ty:ty),* $(,)?) => {
        /// The effect components the plant holds by value ([`component`]): one field per
        /// effect, named as its section in [`Effects`].
        #[derive(Debug, Clone)]
        pub struct Components {
            $(
                #[doc = concat!("`", stringify!($id), "`.")]
                pub $id: $ty,
            )*
        }

        impl Components {
            /// The registered components' names, in declaration order (each its section's
            /// field in [`Effects`] and its [`EffectId::as_str`]).
            pub const NAMES: &'static [&'static str] = &[$(stringify!($id)),*];

            /// Every present section's cross-field checks ([`Component::validate`]).
            pub fn validate(e: &Effects) -> Result<(), crate::spec::ConfigError> {
                $(
                    if let Some(s) = e.$id.as_ref() {
                        <$ty as Component>::validate(s)?;
                    }
                )*
                Ok(())
            }

            /// Every component's constants and state ([`Component::configure`]).
            pub fn configure(e: &Effects, setup: &Setup) -> Self {
                Components {
                    $($id: <$ty as Component>::configure(e.$id.as_ref(), setup),)*
                }
            }

            /// Every component back to its initial state ([`Component::reset`]).
            pub fn reset(&mut self) {
                $(Component::reset(&mut self.$id);)*
            }
        }
    };
}

// The registration of each effect component: its section's field in `Effects` and its type.
components! {
    line_dynamics: line_dynamics::Lines,
    friction: friction::FrictionStage,
    internal_leakage: leakage::CrossPiston,
    external_leakage: leakage::ToTank,
    bulk_modulus_pressure: bulk_modulus_pressure::BulkModulus,
    flexible_mount: flexible_mount::Mount,
    supply_pressure_drop: supply_pressure_drop::Supply,
    time_delay: time_delay::DelayLine,
    valve_dynamics: valve_dynamics::Spool,
    valve_deadband: valve_deadband::Deadband,
    valve_saturation: valve_saturation::Saturation,
    sensor_tone: sensor_tone::Tones,
}

/// The checks across sections that no component can make alone: the refit ranges of the
/// nominal parameters the diagnosis refits ([`crate::params::PlantParams::refit_ranges`]).
/// Each effect's own cross-field checks are its component's ([`Components::validate`]).
pub fn validate_variants(p: &crate::params::PlantParams) -> Result<(), crate::spec::ConfigError> {
    p.refit_ranges()?;
    Ok(())
}

impl PolynomialForce {
    pub(crate) fn default_vs() -> f64 {
        1e-3
    }

    pub(crate) fn default_dahl_travel() -> f64 {
        1e-4
    }

    pub(crate) fn default_dahl_exponent() -> f64 {
        1.0
    }

    /// A section with every term zero (the neutral element the diagnosis starts from).
    pub fn zero() -> Self {
        Self {
            enabled: true,
            constant: 0.0,
            viscous: 0.0,
            coulomb: 0.0,
            quadratic: 0.0,
            stiffness: 0.0,
            origin: 0.0,
            pressure: 0.0,
            pressure_coulomb: 0.0,
            dahl: 0.0,
            dahl_travel: Self::default_dahl_travel(),
            dahl_velocity: 0.0,
            dahl_exponent: Self::default_dahl_exponent(),
            smoothing_velocity: Self::default_vs(),
        }
    }

    /// Force (N, opposing +x, carried by the rod) of the whole law at Dahl state `z` (-): the
    /// stateless terms of [`Self::force`] plus F_d·z; what the load cell sees of it.
    #[inline]
    pub fn rod_force(&self, x: f64, v: f64, p_a: f64, p_b: f64, z: f64) -> f64 {
        self.force(x, v, p_a, p_b).0 + self.dahl * z
    }

    /// One substep `h` (s) of the Dahl state `z` (-), backward Euler about the velocity at
    /// the start of the step `v_old` (m/s): z' = (z + h·v'/δ)/(1 + h·|v_old|/δ) for Dahl's
    /// law (the general denominator with the series velocity and the Bouc–Wen exponent is
    /// `dahl_denominator`'s), which stays in [−1, 1] at any step. Returns (f₀, d) with the
    /// force F_d·z' = f₀ + d·v' (N, N·s/m) for the implicit velocity update; (0, 0) without
    /// the term.
    #[inline]
    pub fn dahl_implicit(&self, z: f64, v_old: f64, h: f64) -> (f64, f64) {
        if self.dahl == 0.0 {
            return (0.0, 0.0);
        }
        let delta = self.dahl_travel.max(1e-12);
        let den = self.dahl_denominator(z, v_old, h);
        (self.dahl * z / den, self.dahl * h / (delta * den))
    }

    /// 1 + h·(|v_old − V·z|·|z|^(n−1) + V)/δ: the backward-Euler denominator of the Dahl state
    /// with the series-dashpot velocity V (`dahl_velocity`; V = 0 and n = 1 give
    /// 1 + h·|v_old|/δ), from dz/dt = (r − |r|·|z|^(n−1)·z)/δ, r = v − V·z, with |r| and
    /// |z|^(n−1) about the start of the step and r and the last z implicit. With n = 1,
    /// |z'| ≤ 1 whenever |v'| ≤ |r_old| + V; with n > 1 the state is clamped to [−1, 1].
    #[inline]
    fn dahl_denominator(&self, z: f64, v_old: f64, h: f64) -> f64 {
        let delta = self.dahl_travel.max(1e-12);
        let vd = self.dahl_velocity;
        let r = (v_old - vd * z).abs();
        // n = 1 keeps Dahl's law bit for bit (no `powf`).
        let r = if self.dahl_exponent == 1.0 {
            r
        } else {
            r * z.abs().powf(self.dahl_exponent - 1.0)
        };
        1.0 + h * (r + vd) / delta
    }

    /// The Dahl state after the substep of [`Self::dahl_implicit`], given the new velocity
    /// `v_new` (m/s).
    #[inline]
    pub fn dahl_advance(&self, z: f64, v_old: f64, v_new: f64, h: f64) -> f64 {
        if self.dahl == 0.0 {
            return 0.0;
        }
        let delta = self.dahl_travel.max(1e-12);
        ((z + h * v_new / delta) / self.dahl_denominator(z, v_old, h)).clamp(-1.0, 1.0)
    }

    /// Force F (N, opposing +x) at position `x` (m), velocity `v` (m/s) and chamber
    /// pressures `p_a`, `p_b` (Pa), and its derivative ∂F/∂v (N·s/m) for an implicit
    /// velocity update.
    #[inline]
    pub fn force(&self, x: f64, v: f64, p_a: f64, p_b: f64) -> (f64, f64) {
        let vs = self.smoothing_velocity.max(1e-12);
        // The smoothed sign only where a sign term is present (the replay's inner loop: a
        // `tanh` per substep is a measurable share of a viscous-only law's cost).
        let (th, dth) = if self.coulomb != 0.0 || self.pressure_coulomb != 0.0 {
            let th = (v / vs).tanh();
            (th, (1.0 - th * th) / vs)
        } else {
            (0.0, 0.0)
        };
        let dp = p_a - p_b;
        let f = self.constant
            + self.viscous * v
            + self.coulomb * th
            + self.quadratic * v.abs() * v
            + self.stiffness * (x - self.origin)
            + self.pressure * dp
            + self.pressure_coulomb * th * dp.abs();
        let dfdv = self.viscous
            + self.coulomb * dth
            + 2.0 * self.quadratic * v.abs()
            + self.pressure_coulomb * dth * dp.abs();
        (f, dfdv)
    }

    /// The terms that are present, in words with their values and units (for reports).
    pub fn describe(&self) -> Vec<String> {
        let mut s = Vec::new();
        let mut t = |c: f64, what: String| {
            if c != 0.0 {
                s.push(what);
            }
        };
        t(
            self.constant,
            format!("constant force {:.4e} N", self.constant),
        );
        t(
            self.viscous,
            format!("viscous force {:.4e} N·s/m · v", self.viscous),
        );
        t(
            self.coulomb,
            format!(
                "Coulomb/yield force {:.4e} N · sign(v) (smoothed over {:.1e} m/s)",
                self.coulomb, self.smoothing_velocity
            ),
        );
        t(
            self.quadratic,
            format!("quadratic damping {:.4e} N·s²/m² · |v|·v", self.quadratic),
        );
        t(
            self.stiffness,
            format!(
                "stiffness {:.4e} N/m · (x − {:.4} m)",
                self.stiffness, self.origin
            ),
        );
        t(
            self.pressure,
            format!("load-pressure force {:.4e} m² · (p_a − p_b)", self.pressure),
        );
        t(
            self.pressure_coulomb,
            format!(
                "pressure-dependent friction {:.4e} m² · sign(v)·|p_a − p_b|",
                self.pressure_coulomb
            ),
        );
        if self.dahl_velocity > 0.0 {
            t(
                self.dahl,
                format!(
                    "Dahl yield force {:.4e} N · z behind a series dashpot, dz/dt = (r − |r|·z)/δ, r = v − V·z, pre-yield travel δ = {:.3e} m, V = {:.3e} m/s",
                    self.dahl, self.dahl_travel, self.dahl_velocity
                ),
            );
        } else {
            t(
                self.dahl,
                format!(
                    "Dahl yield force {:.4e} N · z, dz/dt = (v − |v|·z)/δ, pre-yield travel δ = {:.3e} m",
                    self.dahl, self.dahl_travel
                ),
            );
        }
        if self.dahl != 0.0 && self.dahl_exponent != 1.0 {
            s.push(format!(
                "Bouc–Wen exponent n = {} of z: |r|·|z|^(n−1)·z in place of |r|·z",
                self.dahl_exponent
            ));
        }
        s
    }
}

impl PolynomialFlow {
    /// A section with every term zero.
    pub fn zero() -> Self {
        Self {
            enabled: true,
            constant: 0.0,
            spool: 0.0,
            spool_abs: 0.0,
        }
    }

    /// Flow Q (m³/s) from port B to port A at spool position `x_v` (fraction of travel).
    #[inline]
    pub fn flow(&self, x_v: f64) -> f64 {
        self.constant + self.spool * x_v + self.spool_abs * x_v.abs()
    }

    /// The terms that are present, in words with their values and units (for reports).
    pub fn describe(&self) -> Vec<String> {
        let mut s = Vec::new();
        if self.constant != 0.0 {
            s.push(format!("null-bias flow {:.4e} m³/s", self.constant));
        }
        if self.spool != 0.0 {
            s.push(format!("flow-gain error {:.4e} m³/s · x_v", self.spool));
        }
        if self.spool_abs != 0.0 {
            s.push(format!(
                "direction asymmetry {:.4e} m³/s · |x_v|",
                self.spool_abs
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::PlantParams;
    use crate::Plant;

    /// Enabled sections of effect `id` that act on the registry test's rig
    /// ([`registry_rig`]) within its first 0.3 s, with values of the shipped configs'
    /// order (configs/*.toml): one per variant that the plant reaches by a call of its own
    /// (`valve_deadband`'s amplifier on the spool target, its overlap on the edges;
    /// `valve_saturation`'s travel limit on the openings, its flow limit on each edge's flow;
    /// `flexible_mount` on the load side and under the cylinder body). Exhaustive: a new
    /// effect does not build without its line.
    fn acting_sections(id: EffectId) -> &'static [&'static str] {
        match id {
            EffectId::Friction => {
                &["static_force = 300.0\ncoulomb_force = 200.0\nstribeck_velocity = 0.005"]
            }
            EffectId::ValveDeadband => {
                &["overlap = 0.1", "variant = \"amplifier\"\ndeadzone = 0.1"]
            }
            EffectId::ValveSaturation => &["spool_limit = 0.2", "max_flow = 1.0e-4"],
            EffectId::ValveDynamics => &["order = 1\ntime_constant = 0.01"],
            EffectId::InternalLeakage => &["coefficient = 1.0e-11"],
            EffectId::ExternalLeakage => &["coefficient = 1.0e-11"],
            EffectId::BulkModulusPressure => &["slope = 7.0\nmax = 2.0e9"],
            EffectId::LineDynamics => {
                &["length = 2.5\ndiameter = 0.0127\nsegments = 8\nbulk_modulus = 1.0e9"]
            }
            EffectId::FlexibleMount => &[
                "load_mass = 250.0\nstiffness = 5.0e4\ndamping = 1.5e4",
                "variant = \"piston_side\"\nload_mass = 250.0\nstiffness = 5.0e4\ndamping = 1.5e4",
            ],
            EffectId::TimeDelay => &["delay = 0.005"],
            EffectId::SensorTone => {
                &["channel = \"force\"\nfrequencies = [225.0]\namplitudes = [2.0]"]
            }
            EffectId::SupplyPressureDrop => &["resistance = 3.75e10\ntime_constant = 0.02"],
        }
    }

    /// The integration sections the registry test runs every effect under: the default
    /// exponential-Euler substep (`Plant::advance_substep` in crates/plant/src/model.rs),
    /// `linear_exact` (`Plant::advance_substep_linear`; an effect it cannot hold switches
    /// the plant back to exponential Euler, `Plant::method`) and the implicit line chains
    /// (`integration.line_method`, the lines' `advance_implicit`).
    const INTEGRATIONS: [&str; 3] = [
        "",
        "[integration]\nmethod = \"linear_exact\"",
        "[integration]\nline_method = \"implicit\"",
    ];

    /// The registry test's rig: a `kq` valve, a differential cylinder mid-stroke on a load
    /// spring, with the lines `extra` appended (an effect's section).
    fn registry_rig(extra: &str) -> PlantParams {
        let toml = format!(
            r#"
            [fluid]
            density = 870.0
            bulk_modulus = 1.4e9
            [supply]
            pressure = 21.0e6
            [valve]
            command_full_scale = 10.0
            flow_form = "kq"
            rated_flow = 5.4e-4
            rated_pressure_drop = 3.5e6
            [cylinder]
            area_a = 2.0e-3
            area_b = 1.0e-3
            dead_volume_a = 1.0e-4
            dead_volume_b = 1.0e-4
            stroke = 0.5
            initial_position = 0.25
            [mechanics]
            mass = 50.0
            load_stiffness = 1.0e5
            load_contact_position = 0.2
            end_stops = false
            {extra}
            "#
        );
        toml::from_str(&toml).unwrap_or_else(|e| panic!("registry rig with {extra:?}: {e}"))
    }

    /// The measurements (force, position, p_a, p_b, spool) of 300 periods of 1 ms under a
    /// ±3 V, 5 Hz sine command, and the load's states x_L, v_L (`flexible_mount`; the
    /// piston's without a mount).
    fn registry_run(p: &PlantParams) -> Vec<[f64; 7]> {
        let mut plant = Plant::configure(p, 1e-3).expect("the registry rig configures");
        (0..300)
            .map(|k| {
                let u = 3.0 * (2.0 * std::f64::consts::PI * 5.0 * k as f64 * 1e-3).sin();
                plant.step(u).expect("the registry rig steps");
                let m = plant.measure();
                let s = plant.state();
                [
                    m.force, m.position, m.p_a, m.p_b, m.spool, s.x_load, s.v_load,
                ]
            })
            .collect()
    }

    /// Whether every column of `run` moves: a stage the plant calls only in part (the
    /// spool's or the load's state never advanced) leaves its state where it started.
    fn all_move(run: &[[f64; 7]]) -> bool {
        (0..7).all(|c| run.iter().any(|m| m[c] != run[0][c]))
    }

    /// Every catalogue effect is one registered component (`components!`) and the plant's
    /// cycle calls it: each effect's section, enabled alone on the same rig, changes what
    /// the sensors read. An effect whose stage the plant never calls (crates/plant/src/
    /// model.rs) would be configured and silently do nothing; this test names it.
    #[test]
    fn every_registered_effect_acts_on_the_cycle() {
        let mut registered: Vec<&str> = Components::NAMES.to_vec();
        let mut ids: Vec<&str> = EffectId::ALL.iter().map(|e| e.as_str()).collect();
        registered.sort_unstable();
        ids.sort_unstable();
        assert_eq!(
            registered, ids,
            "components! and EffectId::ALL list the same effects"
        );
        for integration in INTEGRATIONS {
            let rig = registry_rig(integration);
            // The base rig runs the scheme the section asks for.
            let linear = Plant::configure(&rig, 1e-3)
                .expect("the registry rig configures")
                .method()
                == crate::params::IntegrationMethod::LinearExact;
            assert_eq!(
                linear,
                integration.contains("linear_exact"),
                "{integration:?}"
            );
            let base = registry_run(&rig);
            assert!(
                all_move(&base),
                "{integration:?}: a state of the base rig stands still"
            );
            for id in EffectId::ALL {
                for acting in acting_sections(id) {
                    let section = format!("{integration}\n[effects.{id}]\n{acting}");
                    let p = registry_rig(&section);
                    assert!(p.effects.is_enabled(id), "{id}: the section enables it");
                    let run = registry_run(&p);
                    let change = largest_change(&base, &run);
                    assert!(
                        change > 1e-3,
                        "effect `{id}` ({acting:?}, {integration:?}) is configured but changes no measurement (largest relative change {change:e}): is its stage called in crates/plant/src/model.rs?"
                    );
                    assert!(
                        all_move(&run),
                        "effect `{id}` ({acting:?}, {integration:?}): a measured channel or the load's state stands still: is each of its stage's calls made in crates/plant/src/model.rs?"
                    );
                }
            }
        }
    }

    /// The largest change of any measured channel of `run` from `base` (the first five
    /// columns), relative to the channel's range over `base`.
    fn largest_change(base: &[[f64; 7]], run: &[[f64; 7]]) -> f64 {
        (0..5)
            .map(|c| {
                let (lo, hi) = base
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |a, m| {
                        (a.0.min(m[c]), a.1.max(m[c]))
                    });
                let d = base
                    .iter()
                    .zip(run)
                    .map(|(a, b)| (a[c] - b[c]).abs())
                    .fold(0.0, f64::max);
                d / (hi - lo).max(1e-12)
            })
            .fold(0.0, f64::max)
    }

    /// The rig of the two tests below: a closed critical-centre valve (no opening at zero
    /// command), a double-ended cylinder of area `area` (m²) with 0.1 L dead volumes, 10 kg,
    /// no end stops, a null-bias flow `q0` (m³/s, B→A) and the `[effects.polynomial_force]`
    /// lines `force_law`.
    fn null_bias_rig(area: f64, q0: f64, force_law: &str) -> PlantParams {
        let toml = format!(
            r#"
            [fluid]
            density = 870.0
            bulk_modulus = 1.4e9
            [supply]
            pressure = 21.0e6
            [valve]
            command_full_scale = 10.0
            flow_form = "kq"
            rated_flow = 5.4e-5
            rated_pressure_drop = 1.0e6
            [cylinder]
            area_a = {area}
            area_b = {area}
            dead_volume_a = 1.0e-4
            dead_volume_b = 1.0e-4
            stroke = 0.1
            initial_position = 0.02
            [mechanics]
            mass = 10.0
            end_stops = false
            [effects.polynomial_force]
            {force_law}
            [effects.polynomial_flow]
            constant = {q0}
            "#
        );
        toml::from_str(&toml).unwrap()
    }

    /// A closed critical-centre valve, a double-ended cylinder, no leakage: the only flow is
    /// the null bias q₀, so in steady state (dp/dt = 0 in both chambers) the piston moves at
    /// v = q₀/A (continuity), the chambers hold p_a − p_b = F/A (force balance on the
    /// massive piston, a = 0) and the load cell reads F = c_v·v + F_c·tanh(v/v_s) + F₀.
    #[test]
    fn null_bias_flow_against_a_damper_closed_form() {
        let area = 7.0e-4;
        let (q0, cv, fc, f0, vs): (f64, f64, f64, f64, f64) = (3.5e-6, 2.0e4, 150.0, -40.0, 1e-3);
        let p = null_bias_rig(
            area,
            q0,
            &format!("viscous = {cv}\ncoulomb = {fc}\nconstant = {f0}\nsmoothing_velocity = {vs}"),
        );
        let mut plant = Plant::configure(&p, 1e-3).unwrap();
        for _ in 0..2000 {
            plant.step(0.0).unwrap();
        }
        let s = *plant.state();
        let v = q0 / area;
        let f = cv * v + fc * (v / vs).tanh() + f0;
        assert!(
            (s.v - v).abs() < 1e-9 * v.max(1.0) + 1e-6 * v,
            "v {} vs {v}",
            s.v
        );
        assert!(
            (s.rod_force - f).abs() < 1e-6 * f.abs(),
            "F {} vs {f}",
            s.rod_force
        );
        let dp = s.p_a - s.p_b;
        assert!(
            (dp - f / area).abs() < 1e-6 * (f / area).abs(),
            "Δp {dp} vs {}",
            f / area
        );
    }

    /// Linearisation writes the state back with [`Plant::set_linear_state`]; the rod force
    /// it then reports is the load cell's at that state for every mount variant. With the
    /// cylinder body on a compliant mount (`piston_side`) the load spring sees the absolute
    /// piston position x + x_body and the rod passes the external force on, not the mount's
    /// spring-damper force (which acts on the body).
    #[test]
    fn writing_the_state_back_keeps_the_rod_force_of_every_mount() {
        for variant in ["load_side", "piston_side"] {
            let mut p = null_bias_rig(7.0e-4, 3.5e-6, "viscous = 2.0e4");
            p.mechanics.load_stiffness = 2.0e5;
            p.mechanics.load_contact_position = 0.01;
            let mount = format!(
                "variant = \"{variant}\"\nload_mass = 50.0\nstiffness = 3.0e5\ndamping = 2.0e3"
            );
            p.effects.flexible_mount = Some(toml::from_str(&mount).unwrap());
            let mut plant = Plant::configure(&p, 1e-3).unwrap();
            for _ in 0..200 {
                plant.step(1.0).unwrap();
            }
            let before = *plant.state();
            assert!(before.x_load.abs() > 1e-7, "{variant}: the mount moved");
            plant.set_linear_state(&plant.linear_state());
            let after = *plant.state();
            assert_eq!(after.rod_force, before.rod_force, "{variant}");
            // The piston-side reading, written out: k·(x + x_body − x_c) + F_ext.
            if variant == "piston_side" {
                let f = 2.0e5 * (after.x + after.x_load - 0.01) + after.external + 2.0e4 * after.v;
                assert!(
                    (after.rod_force - f).abs() <= 1e-9 * f.abs(),
                    "{} vs {f}",
                    after.rod_force
                );
            }
        }
    }

    /// The Dahl term on the rig of the test above, pushed by the null-bias flow alone: while
    /// v ≥ 0, dz/dx = (1 − z)/δ, so the load cell reads c_v·v + F_d·(1 − e^(−Δx/δ)) with Δx the
    /// travel from rest (Dahl 1968, exponent 1), and F_d + c_v·q₀/A once Δx ≫ δ.
    #[test]
    fn dahl_force_builds_up_over_the_pre_yield_travel() {
        let area = 7.0e-4;
        let (q0, cv, fd, delta): (f64, f64, f64, f64) = (3.5e-6, 2.0e4, 300.0, 5e-4);
        let p = null_bias_rig(
            area,
            q0,
            &format!("viscous = {cv}\ndahl = {fd}\ndahl_travel = {delta}"),
        );
        let mut plant = Plant::configure(&p, 1e-3).unwrap();
        let x0 = plant.state().x;
        let mut worst: f64 = 0.0;
        for _ in 0..2000 {
            plant.step(0.0).unwrap();
            let s = *plant.state();
            assert!(s.v >= 0.0, "the null-bias flow never reverses the piston");
            let want = cv * s.v + fd * (1.0 - (-(s.x - x0) / delta).exp());
            worst = worst.max((s.rod_force - want).abs());
        }
        // Backward Euler in z: the error per substep is O((h·v/δ)²) ≈ 1e-4 of F_d here.
        assert!(
            worst < 5e-3 * fd,
            "rod force vs the Dahl closed form: worst {worst} N"
        );
        let s = *plant.state();
        assert!(
            s.x - x0 > 10.0 * delta,
            "the test must pass the pre-yield travel"
        );
        let f = cv * q0 / area + fd * (1.0 - (-(s.x - x0) / delta).exp());
        assert!(
            (s.rod_force - f).abs() < 1e-4 * f,
            "F {} vs {f}",
            s.rod_force
        );
    }

    /// The Dahl state stays in [−1, 1] at any step and reverses to −1 + 2·e^(−Δx/δ).
    #[test]
    fn dahl_state_is_bounded_and_reverses() {
        let f = PolynomialForce {
            dahl: 100.0,
            dahl_travel: 1e-4,
            ..PolynomialForce::zero()
        };
        let mut z = 0.0;
        for v in [1e3, -1e3, 1e-3, -5.0] {
            z = f.dahl_advance(z, v, v, 1.0);
            assert!(z.abs() <= 1.0, "z {z} at v {v}");
        }
        // From z = 1, travel back by 3δ in small steps.
        let (v, h): (f64, f64) = (-1e-3, 1e-4); // h·|v|/δ = 1e-3
        let mut z = 1.0;
        let n = (3e-4 / (-v * h)).round() as usize;
        for _ in 0..n {
            z = f.dahl_advance(z, v, v, h);
        }
        let want = -1.0 + 2.0 * (-3.0_f64).exp();
        assert!((z - want).abs() < 1e-3, "z {z} vs {want}");
    }

    /// Every term of the force law against its formula, and ∂F/∂v against a central
    /// difference.
    #[test]
    fn force_terms_and_derivative() {
        let f = PolynomialForce {
            constant: 10.0,
            viscous: 300.0,
            coulomb: 50.0,
            quadratic: 2.0e3,
            stiffness: 1.0e4,
            origin: 0.05,
            pressure: 1e-5,
            pressure_coulomb: 2e-6,
            smoothing_velocity: 2e-3,
            ..PolynomialForce::zero()
        };
        let (x, v, pa, pb) = (0.06, -0.004, 5.0e6, 2.0e6);
        let th = (v / 2e-3_f64).tanh();
        let want = 10.0
            + 300.0 * v
            + 50.0 * th
            + 2.0e3 * v.abs() * v
            + 1.0e4 * 0.01
            + 1e-5 * 3.0e6
            + 2e-6 * th * 3.0e6;
        let (got, d) = f.force(x, v, pa, pb);
        assert!(
            (got - want).abs() < 1e-12 * want.abs().max(1.0),
            "{got} vs {want}"
        );
        let h = 1e-7;
        let num = (f.force(x, v + h, pa, pb).0 - f.force(x, v - h, pa, pb).0) / (2.0 * h);
        assert!((d - num).abs() < 1e-5 * num.abs(), "{d} vs {num}");
    }
}
