//! `friction`: Stribeck seal friction with stick (003 eq. 5, 004 eq. 28–34), a load-side
//! Coulomb force (variant `load_coulomb`) or LuGre / Dahl pre-sliding friction (variant
//! `lugre`): the config section [`Friction`] (`[effects.friction]`), its law with the stick
//! state, [`FrictionModel`], and its component [`FrictionStage`], the force stage of the
//! piston's velocity update ([`ForceStage`]).
//!
//! Seal friction with a true stick phase (003 eq. 5, 004 eq. 28–34).
//!
//! Slip: F_f = (F_C + (F_s − F_C)·e^(−(|v|/v_s)²))·sign(v) (Stribeck; 003 eq. 5 writes the
//! decay as e^(−σ|v|), we use the Gaussian form of 004's static/Coulomb split), viscous
//! friction is handled with the mechanical damping. Stick is solved as a velocity
//! projection (Moreau time stepping): when the force needed to hold v = 0 over the substep
//! is at most F_s the piston stays exactly at rest, so there is no chatter and no drift.
//!
//! Variant `lugre` (Canudas de Wit, Olsson, Åström & Lischinsky 1995, IEEE TAC 40(3), eq. 1–3)
//! replaces the stick projection by a bristle state z (m): ż = v − σ₀·|v|·z/g(v),
//! F = σ₀·z + σ₁·ż with the Stribeck curve above as g(v). Over a substep h it is taken
//! backward Euler in z and in the new velocity, with the rate a = σ₀·|v|/g(v) frozen at the
//! old velocity: z' = (z + h·v')/(1 + a·h), so F is affine in v' and the mechanics solve
//! stays one division (no iteration). Unconditionally stable for any σ₀, σ₁ and h; at a
//! constant velocity z relaxes monotonically to g(v)·sign(v)/σ₀ (the update's fixed point,
//! the steady-state LuGre force g(v)), so z stays of the order of F_s/σ₀ (only the step in
//! which sliding starts from rest, a = 0, can overshoot by h·v). The pre-sliding spring
//! √(σ₀/m) enters the substep rule
//! (`crate::model`, `fastest_mode`), so its oscillation is resolved, not only damped.

use super::component::{Component, ForceStage, Kick, Setup};
use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

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
    /// exponent 1, dF/dx = σ₀·(1 − F·sign(v)/F_C). See [`FrictionModel`].
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

impl Friction {
    /// Check of the forces: the breakaway force F_s is at least the Coulomb force F_C (N).
    pub(crate) fn validate_forces(&self) -> Result<(), ConfigError> {
        if self.static_force < self.coulomb_force {
            return Err(ConfigError::new(
                "effects.friction.static_force",
                format!(
                    "static (breakaway) force {} N must be ≥ coulomb_force {} N",
                    self.static_force, self.coulomb_force
                ),
            ));
        }
        Ok(())
    }
}

impl Friction {
    /// Cross-field check of the variant: `lugre` needs its bristle stiffness and a Coulomb force.
    pub(crate) fn validate_variant(&self) -> Result<(), ConfigError> {
        if self.variant == FrictionVariant::Lugre
            && !(self.bristle_stiffness > 0.0 && self.coulomb_force > 0.0)
        {
            return Err(ConfigError::new(
                "effects.friction",
                format!(
                    "variant = \"lugre\" needs bristle_stiffness > 0 N/m and coulomb_force > 0 N; got {} N/m, {} N",
                    self.bristle_stiffness, self.coulomb_force
                ),
            ));
        }
        Ok(())
    }
}

/// Friction law with stick state.
#[derive(Debug, Clone)]
pub struct FrictionModel {
    fs: f64,
    fc: f64,
    vs: f64,
    /// Variant `load_coulomb`: F = F_C·tanh(v/v_s), no stick.
    smooth: bool,
    /// Variant `lugre`: bristle stiffness σ₀ (N/m) and damping σ₁ (N·s/m).
    lugre: Option<(f64, f64)>,
    /// Bristle deflection z (m) of the `lugre` variant.
    z: f64,
}

impl FrictionModel {
    /// From the config section.
    pub fn new(p: &Friction) -> Self {
        Self {
            fs: p.static_force.max(p.coulomb_force),
            fc: p.coulomb_force,
            vs: p.stribeck_velocity,
            smooth: p.variant == FrictionVariant::LoadCoulomb,
            lugre: (p.variant == FrictionVariant::Lugre)
                .then_some((p.bristle_stiffness, p.bristle_damping)),
            z: 0.0,
        }
    }

    /// Bristle stiffness σ₀ (N/m) of the `lugre` variant (0 otherwise): the pre-sliding spring
    /// that the substep rule has to resolve.
    pub fn bristle_stiffness(&self) -> f64 {
        self.lugre.map_or(0.0, |(s0, _)| s0)
    }

    /// Bristle deflection z (m) of the `lugre` variant (0 otherwise).
    pub fn bristle_deflection(&self) -> f64 {
        self.z
    }

    /// Relax the bristles (z = 0), as at the start of a run.
    pub fn reset(&mut self) {
        self.z = 0.0;
    }

    /// Slip friction magnitude at speed |v| (N).
    #[inline]
    pub fn slip_force(&self, speed: f64) -> f64 {
        let r = speed / self.vs;
        self.fc + (self.fs - self.fc) * (-r * r).exp()
    }

    /// Apply friction to the friction-free velocity `v_free` (m/s) reached from `v_old`.
    /// `m_eff` (kg) is the mass including the implicit damping term (m + h·c) and `h` the
    /// substep (s). Returns (new velocity, friction force on the body opposing motion, stuck).
    #[inline]
    pub fn project(&mut self, v_old: f64, v_free: f64, m_eff: f64, h: f64) -> (f64, f64, bool) {
        if let Some((s0, s1)) = self.lugre {
            // Backward Euler in z and v' (module docs): z' = (z + h·v')/(1 + a·h),
            // F = σ₀·z' + σ₁·(z' − z)/h = F₀ + D·v'.
            let a = s0 * v_old.abs() / self.slip_force(v_old.abs());
            let den = 1.0 + a * h;
            let f0 = (s0 - s1 * a) * self.z / den;
            let d = (s0 * h + s1) / den;
            let v_new = (m_eff * v_free - h * f0) / (m_eff + h * d);
            let z_new = (self.z + h * v_new) / den;
            let f = s0 * z_new + s1 * (z_new - self.z) / h;
            self.z = z_new;
            return (v_new, f, false);
        }
        if self.smooth {
            // F = F_C·tanh(v/v_s), linearly implicit about v_old (stable for any slope).
            let th = (v_old / self.vs).tanh();
            let f0 = self.fc * th;
            let df = self.fc / self.vs * (1.0 - th * th);
            let v_new = (m_eff * v_free - h * (f0 - df * v_old)) / (m_eff + h * df);
            return (v_new, f0 + df * (v_new - v_old), false);
        }
        let crossing = v_old == 0.0 || v_free == 0.0 || (v_old > 0.0) != (v_free > 0.0);
        if crossing {
            let f_hold = m_eff * v_free / h;
            if f_hold.abs() <= self.fs {
                return (0.0, f_hold, true);
            }
            let f = self.fs.copysign(v_free);
            return (v_free - h * f / m_eff, f, false);
        }
        let f = self.slip_force(v_old.abs()).copysign(v_old);
        let v_new = v_free - h * f / m_eff;
        if (v_new > 0.0) != (v_old > 0.0) {
            // Friction would reverse the motion: it stops the body instead.
            (0.0, m_eff * v_free / h, true)
        } else {
            (v_new, f, false)
        }
    }
}

/// The component of `friction`: the law with its stick (or bristle) state, absent without
/// the effect, and the extra viscous friction that the mechanics take into their damping.
#[derive(Debug, Clone)]
pub struct FrictionStage {
    /// The law, `None` when the section is absent or switched off.
    law: Option<FrictionModel>,
    /// Extra viscous friction `viscous` (N·s/m), 0 without the effect.
    viscous: f64,
}

impl FrictionStage {
    /// The law with its state, `None` without the effect.
    pub fn law(&self) -> Option<&FrictionModel> {
        self.law.as_ref()
    }
}

impl Component for FrictionStage {
    type Section = Friction;

    /// F_s ≥ F_C, and variant `lugre` has its bristle stiffness and a Coulomb force.
    fn validate(s: &Friction) -> Result<(), ConfigError> {
        s.validate_forces()?;
        s.validate_variant()
    }

    fn configure(s: Option<&Friction>, _setup: &Setup) -> Self {
        let f = s.filter(|f| f.enabled);
        FrictionStage {
            law: f.map(FrictionModel::new),
            viscous: f.map_or(0.0, |f| f.viscous),
        }
    }

    /// Relaxed bristles (z = 0).
    fn reset(&mut self) {
        if let Some(f) = self.law.as_mut() {
            f.reset();
        }
    }
}

impl ForceStage for FrictionStage {
    #[inline]
    fn is_active(&self) -> bool {
        self.law.is_some()
    }

    fn viscous(&self) -> f64 {
        self.viscous
    }

    /// The bristle stiffness σ₀ of variant `lugre` (the pre-sliding spring √(σ₀/m)), else 0.
    fn stiffness(&self) -> f64 {
        self.law
            .as_ref()
            .map_or(0.0, FrictionModel::bristle_stiffness)
    }

    /// [`FrictionModel::project`]: stick as a velocity projection, slip on the Stribeck
    /// curve, or the LuGre bristles.
    #[inline]
    fn kick(&mut self, v_old: f64, v_free: f64, m_eff: f64, h: f64) -> Kick {
        let (v, force, stuck) = match self.law.as_mut() {
            Some(fm) => fm.project(v_old, v_free, m_eff, h),
            None => (v_free, 0.0, false),
        };
        Kick { v, force, stuck }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lugre(fs: f64, fc: f64, vs: f64, s0: f64, s1: f64) -> FrictionModel {
        FrictionModel::new(&Friction {
            enabled: true,
            variant: FrictionVariant::Lugre,
            static_force: fs,
            coulomb_force: fc,
            stribeck_velocity: vs,
            viscous: 0.0,
            bristle_stiffness: s0,
            bristle_damping: s1,
        })
    }

    /// Dahl's model (LuGre with F_s = F_C, σ₁ = 0) pushed at a constant speed from relaxed
    /// bristles follows the closed form of dF/dx = σ₀·(1 − F/F_C):
    /// F(x) = F_C·(1 − e^(−σ₀·x/F_C)) (Dahl 1968). A body of huge mass keeps v' = v_free.
    #[test]
    fn dahl_presliding_curve_is_the_closed_form() {
        let (fc, s0, v) = (300.0, 1e7, 0.1);
        let mut f = lugre(fc, fc, 0.01, s0, 0.0);
        let (m, h) = (1e15, 1e-6);
        let mut x = 0.0;
        let mut worst: f64 = 0.0;
        for _ in 0..30_000 {
            let (v_new, force, stuck) = f.project(v, v, m, h);
            assert!(!stuck);
            assert!((v_new - v).abs() < 1e-12);
            x += h * v_new;
            let expect = fc * (1.0 - (-s0 * x / fc).exp());
            worst = worst.max((force - expect).abs());
        }
        // x = 3 mm ≫ F_C/σ₀ = 30 µm: the curve has saturated at F_C.
        assert!((f.bristle_deflection() - fc / s0).abs() < 1e-3 * fc / s0);
        // Backward Euler: error O(σ₀·v·h) = 1 N at most at the start, far less later.
        assert!(worst < 1.0, "worst {worst} N");
    }

    /// In steady sliding LuGre gives the Stribeck curve g(v) (Canudas de Wit 1995 eq. 4).
    #[test]
    fn lugre_steady_sliding_is_the_stribeck_curve() {
        let (fs, fc, vs) = (450.0, 300.0, 0.01);
        for v in [0.003, 0.01, 0.05] {
            let mut f = lugre(fs, fc, vs, 1e7, 2e3);
            let mut force = 0.0;
            for _ in 0..60_000 {
                force = f.project(v, v, 1e15, 1e-5).1;
            }
            let g = fc + (fs - fc) * (-(v / vs) * (v / vs)).exp();
            assert!((force - g).abs() < 1e-6 * g, "v {v}: {force} vs {g}");
        }
    }

    /// A 10 kg body pushed by 60 % of F_C from rest does not slide: it deflects the bristles
    /// to F/σ₀ and rests there (σ₁ damps the pre-sliding oscillation), for any substep,
    /// with z bounded by F_s/σ₀.
    #[test]
    fn lugre_presliding_rest_under_a_force_below_breakaway() {
        let (fc, s0, m): (f64, f64, f64) = (300.0, 1e7, 10.0);
        let s1 = 2.0 * (s0 * m).sqrt();
        for h in [1e-6, 1e-4, 1e-2] {
            let mut f = lugre(1.3 * fc, fc, 0.01, s0, s1);
            let (mut v, mut x) = (0.0, 0.0);
            let push = 0.6 * fc;
            for _ in 0..((0.5 / h) as usize).max(50) {
                let v_free = v + h * push / m;
                let (v_new, _, _) = f.project(v, v_free, m, h);
                v = v_new;
                x += h * v;
                assert!(f.bristle_deflection().abs() <= 1.3 * fc / s0 * (1.0 + 1e-9));
            }
            // Dahl's hysteresis makes x slightly above F/σ₀ (z lags x while moving).
            let z = f.bristle_deflection();
            assert!((z - push / s0).abs() < 1e-3 * push / s0, "h {h}: z {z}");
            assert!(x > 0.0 && x < 2.0 * push / s0, "h {h}: x {x}");
            assert!(v.abs() < 1e-9, "h {h}: v {v}");
        }
    }

    fn section(variant: FrictionVariant) -> Friction {
        Friction {
            enabled: true,
            variant,
            static_force: 450.0,
            coulomb_force: 300.0,
            stribeck_velocity: 0.01,
            viscous: 120.0,
            bristle_stiffness: 1e7,
            bristle_damping: 2e3,
        }
    }

    /// Without the effect (absent or switched off) the stage passes the velocity on, with no
    /// force, damping or stiffness; with it, it is the law's projection.
    #[test]
    fn stage_without_the_effect_passes_the_velocity() {
        let setup = Setup {
            control_dt: 1e-3,
            supply_pressure: 20e6,
            bulk_modulus: 1.5e9,
            ..Setup::TEST
        };
        let mut off = section(FrictionVariant::Stribeck);
        off.enabled = false;
        for s in [None, Some(&off)] {
            let mut st = FrictionStage::configure(s, &setup);
            assert!(!st.is_active());
            assert_eq!((st.viscous(), st.stiffness()), (0.0, 0.0));
            let k = st.kick(0.1, 0.2, 10.0, 1e-4);
            assert_eq!((k.v, k.force, k.stuck), (0.2, 0.0, false));
        }
        let on = section(FrictionVariant::Stribeck);
        let mut st = FrictionStage::configure(Some(&on), &setup);
        assert!(st.is_active());
        assert_eq!((st.viscous(), st.stiffness()), (120.0, 0.0));
        // 10 kg pushed from rest by less than F_s over the substep: held.
        let k = st.kick(0.0, 1e-3, 10.0, 1e-4);
        assert_eq!((k.v, k.stuck), (0.0, true));
        assert!((k.force - 100.0).abs() < 1e-9, "{}", k.force);
    }

    /// Variant `lugre`: the substep rule sees σ₀; a reset relaxes the bristles.
    #[test]
    fn lugre_stage_has_the_bristle_spring_and_resets() {
        let s = section(FrictionVariant::Lugre);
        let mut st = FrictionStage::configure(
            Some(&s),
            &Setup {
                control_dt: 1e-3,
                supply_pressure: 20e6,
                bulk_modulus: 1.5e9,
                ..Setup::TEST
            },
        );
        assert_eq!(st.stiffness(), 1e7);
        st.kick(0.01, 0.01, 1e3, 1e-5);
        let z = st.law().map_or(0.0, FrictionModel::bristle_deflection);
        assert!(z > 0.0, "z {z}");
        st.reset();
        assert_eq!(st.law().map(FrictionModel::bristle_deflection), Some(0.0));
    }

    /// The component's checks are the section's: F_s < F_C and a `lugre` without σ₀ are
    /// refused, naming the parameter.
    #[test]
    fn validate_refuses_breakaway_below_coulomb_and_lugre_without_bristles() {
        let mut s = section(FrictionVariant::Lugre);
        assert!(FrictionStage::validate(&s).is_ok());
        s.static_force = 200.0;
        let e = FrictionStage::validate(&s).unwrap_err();
        assert!(
            e.to_string().contains("effects.friction.static_force"),
            "{e}"
        );
        s.static_force = 450.0;
        s.bristle_stiffness = 0.0;
        let e = FrictionStage::validate(&s).unwrap_err();
        assert!(e.to_string().contains("bristle_stiffness"), "{e}");
    }
}
