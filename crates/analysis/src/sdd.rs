//! Dindorf 2022 eq. 23–29: natural frequencies, frequency ratios and relative damping of an
//! actuator connected to a load mass through a spring–damper (SDD).

use ehactl_plant::params::{ExcitationKind, PlantParams};
use ehactl_plant::Plant;
use serde::Serialize;
use std::f64::consts::TAU;

/// The 003 ratios at one piston position.
#[derive(Debug, Clone, Serialize)]
pub struct SddRatios {
    /// Actuator (hydraulic) stiffness k_y at the position (N/m), β·(A₁²/V₁ + A₂²/V₂).
    pub k_y: f64,
    /// f_y = √(k_y/m_y)/2π (eq. 23) (Hz).
    pub f_y_hz: f64,
    /// f_m = √(k_m/m_L)/2π (eq. 24) (Hz).
    pub f_m_hz: f64,
    /// Excitation frequency f_e (Hz): the harmonic's, or blows per minute / 60 (eq. 17).
    pub f_e_hz: Option<f64>,
    /// fr_ym = f_y/f_m (eq. 25).
    pub fr_ym: f64,
    /// fr_em = f_e/f_m (eq. 26).
    pub fr_em: Option<f64>,
    /// ξ_y = d_y/(2√(k_y·m_y)) (eq. 27).
    pub xi_y: f64,
    /// ξ_m = d_m/(2√(k_m·m_L)) (eq. 28).
    pub xi_m: f64,
    /// rd_my = ξ_m/ξ_y (eq. 29).
    pub rd_my: f64,
}

/// Excitation frequency of a config (Hz), if periodic.
pub fn excitation_frequency(p: &PlantParams) -> Option<f64> {
    match p.excitation.kind {
        ExcitationKind::Harmonic if p.excitation.frequency > 0.0 => Some(p.excitation.frequency),
        ExcitationKind::Impact if p.excitation.blows_per_minute > 0.0 => {
            Some(p.excitation.blows_per_minute / 60.0)
        }
        _ => None,
    }
}

/// The ratios at piston position `x` (m) for the excitation frequency `f_e` (Hz, see
/// [`excitation_frequency`]); None without an enabled flexible mount.
pub fn ratios(plant: &Plant, x: f64, f_e: Option<f64>) -> Option<SddRatios> {
    let p = plant.params();
    let m = p.effects.flexible_mount.as_ref().filter(|m| m.enabled)?;
    let k_y = plant.hydraulic_stiffness(x);
    let m_y = p.mechanics.mass;
    let d_y = p.mechanics.damping
        + p.effects
            .friction
            .as_ref()
            .filter(|f| f.enabled)
            .map_or(0.0, |f| f.viscous);
    let f_y = (k_y / m_y).sqrt() / TAU;
    let f_m = (m.stiffness / m.load_mass).sqrt() / TAU;
    let xi_y = d_y / (2.0 * (k_y * m_y).sqrt());
    let xi_m = m.damping / (2.0 * (m.stiffness * m.load_mass).sqrt());
    Some(SddRatios {
        k_y,
        f_y_hz: f_y,
        f_m_hz: f_m,
        f_e_hz: f_e,
        fr_ym: f_y / f_m,
        fr_em: f_e.map(|f| f / f_m),
        xi_y,
        xi_m,
        rd_my: xi_m / xi_y,
    })
}

/// 003's SDD parameters implied by the published ratios: k_m from fr_em (eq. 24, 26) and d_m
/// from rd_my (eq. 27–29), given the actuator's k_y, m_y, d_y and the load mass m_L.
/// Returns (k_m in N/m, d_m in N·s/m).
pub fn implied_mount(
    fr_em: f64,
    rd_my: f64,
    f_e: f64,
    k_y: f64,
    m_y: f64,
    d_y: f64,
    m_l: f64,
) -> (f64, f64) {
    let f_m = f_e / fr_em;
    let k_m = m_l * (TAU * f_m).powi(2);
    let d_m = rd_my * d_y * (k_m / k_y).sqrt() * (m_l / m_y).sqrt();
    (k_m, d_m)
}
