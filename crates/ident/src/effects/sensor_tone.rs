//! `sensor_tone`: periodic disturbance a·sin(ωt + φ) on one sensor. Model: `SensorTone` in
//! crates/plant/src/effects/sensor_tone.rs.
//!
//! Seeds: the (at most two) strongest lines of the residual spectra on the channel of the strongest
//! one (`crate::analysis`), frequency within ±0.02 Welch bin, sine and cosine amplitudes within ±4×
//! the line's amplitude. Not testable on a record whose residuals show no line.

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{FreeParam, Scales};
use ehactl_plant::params::{SensorChannel, SensorTone};
use ehactl_plant::{EffectId, PlantParams};
use std::sync::Arc;

/// The catalogue effect `sensor_tone`.
pub struct Effect;

impl EffectFit for Effect {
    fn signature(&self) -> Signature {
        Signature::Other
    }

    fn measurement_only(&self) -> bool {
        true
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        let _ = other;
        None
    }

    fn prior(&self, an: &Analysis, _dt: f64) -> (f64, String) {
        match an.tones.first() {
            Some(p) => (
                1.0 + p.prominence.log10(),
                format!(
                    "narrow residual line at {:.1} Hz on `{}` ({:.3e} amplitude, {:.0}× the neighbouring PSD)",
                    p.frequency, p.channel, p.amplitude, p.prominence
                ),
            ),
            None => (0.5, "no narrow line in the residual spectra".to_string()),
        }
    }

    fn params(&self, _nominal: &PlantParams, sc: &Scales, an: &Analysis) -> Option<Vec<FreeParam>> {
        let top = an.tones.first()?;
        let ch = match top.channel {
            "force" => SensorChannel::Force,
            "x" => SensorChannel::Position,
            "p_a" => SensorChannel::PressureA,
            "p_b" => SensorChannel::PressureB,
            _ => return None,
        };
        let lines: Vec<_> = an
            .tones
            .iter()
            .filter(|t| t.channel == top.channel)
            .take(2)
            .copied()
            .collect();
        let nt = lines.len();
        let base = SensorTone {
            enabled: true,
            channel: ch,
            frequencies: lines.iter().map(|l| l.frequency).collect(),
            amplitudes: vec![0.0; nt],
            phases: vec![0.0; nt],
        };
        // Frequencies are refined by the analysis to a small fraction of a Welch bin.
        let df = 0.02 / (sc.dt * 1024.0);
        let mut v = Vec::new();
        for (i, l) in lines.iter().enumerate() {
            let (a, b) = (base.clone(), base.clone());
            v.push(FreeParam::new(
                &format!("effects.sensor_tone.frequencies[{i}]"),
                (l.frequency - df).max(0.1),
                l.frequency + df,
                false,
                l.frequency,
                Arc::new(move |p, x| {
                    let t = p.effects.sensor_tone.get_or_insert_with(|| a.clone());
                    t.frequencies[i] = x;
                }),
            ));
            // Arbitrary phase: a·sin(ωt + φ) = a_s·sin ωt + a_c·cos ωt, with the sine and
            // cosine amplitudes fitted (a = √(a_s² + a_c²), φ = atan2(a_c, a_s)).
            let c = base.clone();
            let set_sc = |t: &mut SensorTone, i: usize, s: Option<f64>, co: Option<f64>| {
                if t.phases.len() != t.frequencies.len() {
                    t.phases = vec![0.0; t.frequencies.len()];
                }
                let (a, ph) = (t.amplitudes[i], t.phases[i]);
                let (mut a_s, mut a_c) = (a * ph.cos(), a * ph.sin());
                if let Some(s) = s {
                    a_s = s;
                }
                if let Some(co) = co {
                    a_c = co;
                }
                t.amplitudes[i] = a_s.hypot(a_c);
                t.phases[i] = a_c.atan2(a_s);
            };
            v.push(FreeParam::new(
                &format!("effects.sensor_tone.sine_amplitudes[{i}]"),
                -4.0 * l.amplitude,
                4.0 * l.amplitude,
                false,
                l.amplitude,
                Arc::new(move |p, x| {
                    let t = p.effects.sensor_tone.get_or_insert_with(|| b.clone());
                    set_sc(t, i, Some(x), None);
                }),
            ));
            v.push(FreeParam::new(
                &format!("effects.sensor_tone.cosine_amplitudes[{i}]"),
                -4.0 * l.amplitude,
                4.0 * l.amplitude,
                false,
                0.0,
                Arc::new(move |p, x| {
                    let t = p.effects.sensor_tone.get_or_insert_with(|| c.clone());
                    set_sc(t, i, None, Some(x));
                }),
            ));
        }
        Some(v)
    }
}
