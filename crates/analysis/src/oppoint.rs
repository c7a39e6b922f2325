//! The operating point a rig is linearised around: the noise-free closed loop (or the open
//! loop with a constant command) run to rest at the setpoint's static value.

use crate::AnalysisError;
use ehactl_config::{ControlMode, RigConfig};
use ehactl_control::setpoint::{SetpointConfig, SetpointKind};
use ehactl_plant::params::{ExcitationKind, PlantParams};
use ehactl_plant::Plant;

/// The static value of a setpoint (N, m or V): the offset of a sine, chirp or static + dynamic
/// setpoint, the final value of a step or ramp, the middle of random steps.
pub fn operating_reference(sp: &SetpointConfig) -> f64 {
    match sp.kind {
        SetpointKind::Step | SetpointKind::Ramp => sp.final_value,
        SetpointKind::Sine | SetpointKind::Chirp | SetpointKind::StaticDynamic => sp.offset,
        SetpointKind::RandomSteps => 0.5 * (sp.initial + sp.final_value),
    }
}

/// The plant parameters used for linearisation: sensor noise, quantisation and tones off,
/// Coulomb/static friction off (its viscous part moved into the mechanical damping: a
/// linear model cannot hold a stick–slip switch), the command delay off (applied as
/// e^(−jωτ) in the frequency response instead), the external force frozen at its
/// static part F₀ (003 eq. 2 without the harmonic), and no `[uncertainty]` (never refit).
pub fn linearisation_params(p: &PlantParams) -> PlantParams {
    let mut q = p.clone();
    q.sensors.force.noise = 0.0;
    q.sensors.pressure.noise = 0.0;
    q.sensors.position.noise = 0.0;
    q.sensors.position.resolution = 0.0;
    q.sensors.position.update_period = 0.0;
    q.sensors.spool.noise = 0.0;
    if let Some(t) = q.effects.sensor_tone.as_mut() {
        t.enabled = false;
    }
    if let Some(f) = q.effects.friction.as_mut() {
        if f.enabled {
            q.mechanics.damping += f.viscous;
            f.enabled = false;
        }
    }
    if let Some(d) = q.effects.time_delay.as_mut() {
        d.enabled = false;
    }
    // The linearised copy is never refit: the diagnosis's refit bounds would only make the
    // effects switched off above invalid.
    q.uncertainty.clear();
    if q.excitation.kind != ExcitationKind::None {
        q.excitation.kind = ExcitationKind::Constant;
        q.excitation.amplitude = 0.0;
        q.excitation.start_time = 0.0;
    }
    q
}

/// A rig at rest at its operating point.
#[derive(Debug, Clone)]
pub struct OperatingPoint {
    /// The plant (linearisation parameters) at the operating point.
    pub plant: Plant,
    /// Valve command holding it there (V).
    pub u0: f64,
    /// Reference (N, m, or V in open loop).
    pub reference: f64,
    /// Feedback value reached (N or m).
    pub feedback: f64,
    /// Whether the loop came to rest (|Δfeedback| over the last 0.1 s below 1e-6 of scale).
    pub settled: bool,
    /// Time simulated to get there (s).
    pub time_s: f64,
}

/// Run the noise-free rig to rest at its operating point (at most `max_time` s). In position
/// mode the piston starts at the reference to save the approach.
pub fn find(cfg: &RigConfig, max_time: f64) -> Result<OperatingPoint, AnalysisError> {
    let mut params = linearisation_params(&cfg.plant);
    let reference = operating_reference(&cfg.setpoint);
    if cfg.control.mode == ControlMode::Position {
        params.cylinder.initial_position = reference.clamp(0.0, params.cylinder.stroke);
    }
    let dt = cfg.timebase().period();
    let mut plant = Plant::configure(&params, dt)?;
    let mut controller = cfg.controller();
    let n = (max_time / dt).ceil() as u64;
    let window = ((0.1 / dt).ceil() as u64).max(10);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut u = 0.0;
    let mut settled = false;
    let mut k = 0;
    let mut fb = 0.0;
    while k < n {
        let m = plant.measure();
        fb = controller.feedback(&m);
        u = match cfg.control.mode {
            ControlMode::OpenLoop => reference,
            _ => controller.step(reference, 0.0, &m, dt).u,
        };
        plant
            .step(u)
            .map_err(|e| AnalysisError::Numerical(format!("operating point search: {e}")))?;
        k += 1;
        lo = lo.min(fb);
        hi = hi.max(fb);
        if k % window == 0 {
            let scale = fb.abs().max(reference.abs()).max(1e-3);
            if k >= 2 * window && (hi - lo) <= 1e-6 * scale {
                settled = true;
                break;
            }
            lo = f64::INFINITY;
            hi = f64::NEG_INFINITY;
        }
    }
    Ok(OperatingPoint {
        plant,
        u0: u,
        reference,
        feedback: fb,
        settled,
        time_s: k as f64 * dt,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `[uncertainty]` bounds the diagnosis refit of the config's effects; the linearised copy
    /// switches some of them off (time delay, friction, sensor tone) and is never refit, so
    /// its bounds must not make the copy invalid. `configs/utfsm_mts_mrdamper.toml` declares
    /// the delay's uncertainty (its loop is identified by `ehactl diagnose`); `ehactl analyze`
    /// refused it with "a switched-off effect is not refit".
    #[test]
    fn the_operating_point_of_a_config_with_uncertain_effects_is_found() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../configs/utfsm_mts_mrdamper.toml"
        );
        let text = std::fs::read_to_string(path).unwrap();
        let cfg = RigConfig::from_toml_str(&text).unwrap();
        assert!(cfg
            .plant
            .uncertainty
            .contains_key("effects.time_delay.delay"));
        let op = find(&cfg, 2.0).expect("operating point of the MTS config");
        assert!(op.settled, "{op:?}");
    }
}
