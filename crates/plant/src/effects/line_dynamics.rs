//! `line_dynamics`: lumped R-L-C segments between the valve ports and the chambers
//! (001, 002 eq. 9–17), rigid pipes or compliant hoses (variant `hose`; Merritt 1967,
//! "Hydraulic Control Systems", §2.7 eq. 2-46): the config section [`LineDynamics`]
//! (`[effects.line_dynamics]`) with its wall-friction model [`LineFriction`]. The segment
//! chains themselves are [`line::Line`] in crates/plant/src/effects/line_dynamics/line.rs (it
//! also reads the fluid section), re-exported as `crate::line`.

pub mod line;

use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

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

impl LineDynamics {
    /// Cross-field check of the variant: a `hose` fitting resistance is steady, laminar.
    pub(crate) fn validate_variant(&self) -> Result<(), ConfigError> {
        if self.variant == LineVariant::Hose
            && self.resistance > 0.0
            && self.friction != LineFriction::Steady
        {
            return Err(ConfigError::new(
                "effects.line_dynamics.resistance",
                "a fitting resistance (variant = \"hose\") is laminar and steady; with it use friction = \"steady\" (the unsteady wall-friction terms scale with the wall resistance only)",
            ));
        }
        Ok(())
    }
}
