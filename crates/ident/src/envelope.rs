//! The fitted envelope of a law: what motion and operating inputs it was fitted on
//! ([`ehactl_config::envelope`], written into a campaign's `extended.toml`), and the check
//! of a record against it, so that `ehactl predict` and `diagnose --validate` say when a
//! prediction extrapolates, where and how far ("stroke 12.3× the fitted range", "current 5 A
//! outside the fitted 0–1 A").
//!
//! The motion is described by the range of x, the 99th percentiles of |v| and |a| (a
//! percentile, not the maximum, so that one noisy sample of a differentiated signal does not
//! set the envelope) and the band holding the central 90 % of the power of x (its
//! periodogram, [`power_band`]).

use crate::data::{ChannelKind, Record};
use crate::motion::{derivative, record_velocity};
use ehactl_config::envelope::{Envelope, EnvelopePoint};
use ehactl_config::inputs::Inputs;
use serde::Serialize;
use std::collections::BTreeMap;
use std::ops::Range;

/// Share of the motion's power inside the band an envelope records (-).
pub const BAND_POWER: f64 = 0.9;
/// Percentile of |v| and |a| an envelope records (-).
pub const PERCENTILE: f64 = 0.99;
/// A record's stroke, |v| or |a| percentile may exceed the fitted one by this factor before
/// it is called outside (-): percentiles of a differentiated, noisy signal scatter by a few
/// per cent between records of one test, and a law fitted on a motion holds a little beyond.
pub const MAGNITUDE_TOLERANCE: f64 = 1.25;
/// A record's band may reach this factor beyond the fitted band's edges (-), and at least
/// [`BAND_BINS`] frequency bins of the coarser of the two periodograms.
pub const BAND_TOLERANCE: f64 = 1.25;
/// Frequency bins (of the coarser resolution 1/T of the two periodograms compared) a band
/// edge may move before it counts as outside (-): a periodogram's band edge is uncertain by
/// about one bin on each side.
pub const BAND_BINS: f64 = 2.0;
/// A record's operating input may lie this share of the fitted inputs' span (or of 1 unit
/// when all fitted points share one value) outside the fitted range (-).
pub const INPUT_TOLERANCE: f64 = 0.05;

/// The motion of samples `r` of a record: x range (m), |v| and |a| percentiles (m/s, m/s²),
/// 90 % power band (Hz). `window` is the derivative's half-width (s; 0: the default).
pub fn motion_point(
    rec: &Record,
    x: &[f64],
    r: Range<usize>,
    window: f64,
    inputs: BTreeMap<String, f64>,
) -> EnvelopePoint {
    let v = record_velocity(rec, x, window);
    let w = if window > 0.0 {
        window
    } else {
        crate::motion::DEFAULT_VELOCITY_WINDOW
    };
    let a = derivative(&v, rec.dt, ((w / rec.dt).round() as usize).clamp(1, 1000));
    let xs = &x[r.clone()];
    let (lo, hi) = xs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(*v), h.max(*v))
        });
    EnvelopePoint {
        inputs,
        records: 1,
        position: [lo, hi],
        velocity: percentile_abs(&v[r.clone()], PERCENTILE),
        acceleration: percentile_abs(&a[r], PERCENTILE),
        band: power_band(xs, rec.dt, BAND_POWER),
        resolution: 1.0 / (xs.len().max(1) as f64 * rec.dt),
    }
}

/// The `q` quantile of |y| (0 for an empty slice).
fn percentile_abs(y: &[f64], q: f64) -> f64 {
    let mut a: Vec<f64> = y
        .iter()
        .map(|v| v.abs())
        .filter(|v| v.is_finite())
        .collect();
    if a.is_empty() {
        return 0.0;
    }
    a.sort_by(f64::total_cmp);
    a[((a.len() - 1) as f64 * q).round() as usize]
}

/// The band [f_lo, f_hi] (Hz) holding the central `share` of the power of `x`: the
/// frequencies where the cumulative power of its periodogram crosses (1 − share)/2 and
/// (1 + share)/2, interpolated within a bin. One rectangular window over the whole slice
/// (mean removed): every sample weighs the same, so the band of a sweep is the band it swept
/// (a tapered window would weigh its middle), at the finest resolution 1/T; a pure sine's
/// leakage keeps about 90 % of its power within ±1 bin, inside the band's tolerance
/// ([`BAND_BINS`]).
pub fn power_band(x: &[f64], dt: f64, share: f64) -> [f64; 2] {
    let p = periodogram(x);
    let df = 1.0 / (x.len().max(1) as f64 * dt);
    let total: f64 = p.iter().skip(1).sum();
    if p.len() < 3 || !(total > 0.0) {
        return [0.0, 0.0];
    }
    let cross = |level: f64| {
        let mut acc = 0.0;
        for (k, pk) in p.iter().enumerate().skip(1) {
            let next = acc + pk / total;
            if next >= level {
                let frac = if *pk > 0.0 {
                    (level - acc) / (pk / total)
                } else {
                    0.0
                };
                return ((k as f64 - 0.5 + frac) * df).max(0.0);
            }
            acc = next;
        }
        (p.len() - 1) as f64 * df
    };
    [cross(0.5 * (1.0 - share)), cross(0.5 * (1.0 + share))]
}

/// |X_k|² of `x` less its mean, k = 0 … n/2 (FFT by the `realfft` crate; unscaled: only the
/// shares of the power matter here).
fn periodogram(x: &[f64]) -> Vec<f64> {
    let n = x.len();
    if n < 4 {
        return Vec::new();
    }
    let fft = realfft::RealFftPlanner::<f64>::new().plan_fft_forward(n);
    let mean = x.iter().sum::<f64>() / n as f64;
    let mut input: Vec<f64> = x.iter().map(|v| v - mean).collect();
    let mut spec = fft.make_output_vec();
    if fft.process(&mut input, &mut spec).is_err() {
        return Vec::new();
    }
    spec.iter().map(|c| c.norm_sqr()).collect()
}

/// Merge points of one operating point (same inputs): the union of ranges and bands, the
/// largest percentiles, the records counted.
pub fn merge(points: Vec<EnvelopePoint>) -> Envelope {
    let mut out: Vec<EnvelopePoint> = Vec::new();
    for p in points {
        match out.iter_mut().find(|q| same_inputs(&q.inputs, &p.inputs)) {
            Some(q) => {
                q.records += p.records;
                q.position = [
                    q.position[0].min(p.position[0]),
                    q.position[1].max(p.position[1]),
                ];
                q.velocity = q.velocity.max(p.velocity);
                q.acceleration = q.acceleration.max(p.acceleration);
                q.band = [q.band[0].min(p.band[0]), q.band[1].max(p.band[1])];
                q.resolution = q.resolution.max(p.resolution);
            }
            None => out.push(p),
        }
    }
    Envelope { points: out }
}

fn same_inputs(a: &BTreeMap<String, f64>, b: &BTreeMap<String, f64>) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|((ka, va), (kb, vb))| {
            ka == kb && (va - vb).abs() <= 1e-9 * va.abs().max(vb.abs()).max(1.0)
        })
}

/// One way a record lies outside the envelope.
#[derive(Debug, Clone, Serialize)]
pub struct Excursion {
    /// What: `stroke`, `position`, `velocity`, `acceleration`, `band`, or an input's name.
    pub quantity: String,
    /// The record's value (SI or the input's unit).
    pub record: f64,
    /// The fitted range (low, high) it is compared with.
    pub fitted: [f64; 2],
    /// Unit of both.
    pub unit: String,
    /// How far: the ratio to the fitted value's edge it exceeds (-), or for an input the
    /// distance beyond the fitted range in its unit.
    pub beyond: f64,
    /// In words, e.g. `stroke 12.3× the fitted range (peak-to-peak 25 mm against 2.0 mm)`.
    pub text: String,
}

/// The check of one record against an envelope.
#[derive(Debug, Clone, Serialize)]
pub struct EnvelopeCheck {
    /// Whether the record lies inside on every quantity.
    pub inside: bool,
    /// Where it lies outside, and how far.
    pub excursions: Vec<Excursion>,
}

impl EnvelopeCheck {
    /// One line: "inside the fitted envelope" or the excursions joined.
    pub fn describe(&self) -> String {
        if self.inside {
            "inside the fitted envelope".into()
        } else {
            format!(
                "OUTSIDE the fitted envelope: {}",
                self.excursions
                    .iter()
                    .map(|e| e.text.as_str())
                    .collect::<Vec<_>>()
                    .join("; ")
            )
        }
    }
}

/// Check the motion `m` of a record (at operating point `m.inputs`) against `env`; the
/// inputs' units from `inputs`.
pub fn check(env: &Envelope, m: &EnvelopePoint, inputs: &Inputs) -> EnvelopeCheck {
    let mut ex = Vec::new();
    if env.points.is_empty() {
        return EnvelopeCheck {
            inside: true,
            excursions: ex,
        };
    }
    check_inputs(env, m, inputs, &mut ex);
    check_motion(env, m, &mut ex);
    EnvelopeCheck {
        inside: ex.is_empty(),
        excursions: ex,
    }
}

fn check_inputs(env: &Envelope, m: &EnvelopePoint, inputs: &Inputs, ex: &mut Vec<Excursion>) {
    for (name, value) in &m.inputs {
        let fitted: Vec<f64> = env
            .points
            .iter()
            .filter_map(|p| p.inputs.get(name).copied())
            .collect();
        if fitted.is_empty() {
            continue;
        }
        let lo = fitted.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = fitted.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let tol = INPUT_TOLERANCE * if hi > lo { hi - lo } else { 1.0 };
        let beyond = if *value < lo { lo - value } else { value - hi };
        if beyond > tol || !value.is_finite() {
            let unit = inputs.get(name).map_or(String::new(), |i| i.unit.clone());
            ex.push(Excursion {
                quantity: name.clone(),
                record: *value,
                fitted: [lo, hi],
                unit: unit.clone(),
                beyond,
                text: format!(
                    "{name} {} {unit} outside the fitted {}–{} {unit}",
                    g4(*value),
                    g4(lo),
                    g4(hi)
                ),
            });
        }
    }
}

fn check_motion(env: &Envelope, m: &EnvelopePoint, ex: &mut Vec<Excursion>) {
    check_magnitudes(&env.points, m, ex);
    check_position(&env.points, m, ex);
    check_band(&env.points, m, ex);
}

/// The largest of `f` over the fitted points.
fn max_of(pts: &[EnvelopePoint], f: &dyn Fn(&EnvelopePoint) -> f64) -> f64 {
    pts.iter().map(f).fold(0.0, f64::max)
}

/// Stroke, velocity and acceleration beyond [`MAGNITUDE_TOLERANCE`] × the fitted ones.
fn check_magnitudes(pts: &[EnvelopePoint], m: &EnvelopePoint, ex: &mut Vec<Excursion>) {
    let stroke = max_of(pts, &|p| p.position[1] - p.position[0]);
    let own = m.position[1] - m.position[0];
    let mut magnitude = |quantity: &str, what: &str, unit: &str, scale: f64, rec: f64, fit: f64| {
        if rec > MAGNITUDE_TOLERANCE * fit {
            let ratio = rec / fit.max(1e-300);
            ex.push(Excursion {
                quantity: quantity.into(),
                record: rec,
                fitted: [0.0, fit],
                unit: unit.into(),
                beyond: ratio,
                text: format!(
                    "{quantity} {}× the fitted range ({what} {} against {} {})",
                    g3(ratio),
                    g3(rec * scale),
                    g3(fit * scale),
                    if scale == 1e3 { "mm" } else { unit }
                ),
            });
        }
    };
    magnitude("stroke", "peak-to-peak", "m", 1e3, own, stroke);
    magnitude(
        "velocity",
        "99th percentile of |v|",
        "m/s",
        1.0,
        m.velocity,
        max_of(pts, &|p| p.velocity),
    );
    magnitude(
        "acceleration",
        "99th percentile of |a|",
        "m/s²",
        1.0,
        m.acceleration,
        max_of(pts, &|p| p.acceleration),
    );
}

/// A stroke within the fitted one, but placed beyond the fitted positions.
fn check_position(pts: &[EnvelopePoint], m: &EnvelopePoint, ex: &mut Vec<Excursion>) {
    let stroke = max_of(pts, &|p| p.position[1] - p.position[0]);
    let own = m.position[1] - m.position[0];
    let lo = pts
        .iter()
        .map(|p| p.position[0])
        .fold(f64::INFINITY, f64::min);
    let hi = pts
        .iter()
        .map(|p| p.position[1])
        .fold(f64::NEG_INFINITY, f64::max);
    let margin = (MAGNITUDE_TOLERANCE - 1.0) * (hi - lo);
    if own <= MAGNITUDE_TOLERANCE * stroke
        && (m.position[0] < lo - margin || m.position[1] > hi + margin)
    {
        let beyond = (lo - m.position[0]).max(m.position[1] - hi);
        ex.push(Excursion {
            quantity: "position".into(),
            record: if m.position[0] < lo - margin {
                m.position[0]
            } else {
                m.position[1]
            },
            fitted: [lo, hi],
            unit: "m".into(),
            beyond,
            text: format!(
                "position reaches {}–{} mm, {} mm beyond the fitted {}–{} mm",
                g4(m.position[0] * 1e3),
                g4(m.position[1] * 1e3),
                g3(beyond * 1e3),
                g4(lo * 1e3),
                g4(hi * 1e3)
            ),
        });
    }
}

/// A motion band beyond the fitted one by [`BAND_TOLERANCE`] or [`BAND_BINS`] bins.
fn check_band(pts: &[EnvelopePoint], m: &EnvelopePoint, ex: &mut Vec<Excursion>) {
    let f_lo = pts.iter().map(|p| p.band[0]).fold(f64::INFINITY, f64::min);
    let f_hi = pts.iter().map(|p| p.band[1]).fold(0.0, f64::max);
    let bins = BAND_BINS * max_of(pts, &|p| p.resolution).max(m.resolution);
    let above = m.band[1] > f_hi + (f_hi * (BAND_TOLERANCE - 1.0)).max(bins);
    let below = m.band[0] < f_lo - (f_lo * (1.0 - 1.0 / BAND_TOLERANCE)).max(bins);
    if above || below {
        ex.push(Excursion {
            quantity: "band".into(),
            record: if above { m.band[1] } else { m.band[0] },
            fitted: [f_lo, f_hi],
            unit: "Hz".into(),
            beyond: if above {
                m.band[1] / f_hi.max(1e-300)
            } else {
                f_lo / m.band[0].max(1e-300)
            },
            text: format!(
                "motion band {}–{} Hz {} the fitted {}–{} Hz",
                g3(m.band[0]),
                g3(m.band[1]),
                match (above, below) {
                    (true, true) => "on both sides of",
                    (true, false) => "above",
                    _ => "below",
                },
                g3(f_lo),
                g3(f_hi)
            ),
        });
    }
}

/// Three significant digits.
fn g3(v: f64) -> String {
    sig(v, 3)
}

/// Four significant digits.
fn g4(v: f64) -> String {
    sig(v, 4)
}

fn sig(v: f64, digits: i32) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let mag = v.abs().log10().floor() as i32;
    if !(-4..6).contains(&mag) {
        return format!("{:.*e}", (digits - 1).max(0) as usize, v);
    }
    let decimals = (digits - 1 - mag).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// The envelope check of `rec` against `cfg`'s `[envelope]`, if it has one: the record's
/// whole motion (its position column) at its operating point (median per declared input;
/// the config's value where the record has none). `None` without an envelope or without x.
pub fn check_record(cfg: &ehactl_config::RigConfig, rec: &Record) -> Option<EnvelopeCheck> {
    let env = cfg.envelope.as_ref()?;
    let x = rec.channel(ChannelKind::Position)?;
    let inputs: BTreeMap<String, f64> = cfg
        .inputs
        .iter()
        .map(|(n, i)| (n.clone(), rec.input_median(n).unwrap_or(i.value)))
        .collect();
    let m = motion_point(
        rec,
        x,
        0..rec.len(),
        cfg.plant.sensors.position.velocity_window,
        inputs,
    );
    Some(check(env, &m, &cfg.inputs))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pure sine's power sits in one bin: the 90 % band brackets its frequency within a
    /// Welch bin.
    #[test]
    fn the_band_of_a_sine_brackets_its_frequency() {
        let dt = 1e-3;
        let x: Vec<f64> = (0..20_000)
            .map(|k| (2.0 * std::f64::consts::PI * 7.0 * k as f64 * dt).sin())
            .collect();
        let [lo, hi] = power_band(&x, dt, 0.9);
        let df = 1.0 / (x.len() as f64 * dt);
        assert!(lo <= 7.0 && hi >= 7.0, "{lo}..{hi}");
        assert!(
            hi - lo <= 3.0 * df,
            "{lo}..{hi} wider than 3 bins of {df} Hz"
        );
    }

    /// A linear sweep of constant amplitude spreads its power evenly over the frequencies it
    /// sweeps: the central 90 % of 5…15 Hz is 5.5…14.5 Hz (to a bin).
    #[test]
    fn the_band_of_a_sweep_is_the_band_it_swept() {
        let (dt, t_end, f0, f1) = (1e-3, 20.0, 5.0, 15.0);
        let k = (f1 - f0) / t_end;
        let x: Vec<f64> = (0..(t_end / dt) as usize)
            .map(|i| {
                let t = i as f64 * dt;
                (std::f64::consts::TAU * (f0 * t + 0.5 * k * t * t)).sin()
            })
            .collect();
        let [lo, hi] = power_band(&x, dt, 0.9);
        assert!(
            (lo - 5.5).abs() < 0.2 && (hi - 14.5).abs() < 0.2,
            "{lo}..{hi}"
        );
    }

    fn point(stroke: f64, i: f64) -> EnvelopePoint {
        EnvelopePoint {
            inputs: [("current".to_string(), i)].into(),
            records: 1,
            position: [0.05 - stroke / 2.0, 0.05 + stroke / 2.0],
            velocity: 0.05,
            acceleration: 2.0,
            band: [1.0, 10.0],
            resolution: 0.1,
        }
    }

    fn inputs() -> Inputs {
        let current = ehactl_config::inputs::OperatingInput {
            unit: "A".into(),
            value: 0.0,
            linear: BTreeMap::new(),
            quadratic: BTreeMap::new(),
            saturating: BTreeMap::new(),
            hinge: BTreeMap::new(),
        };
        [("current".to_string(), current)].into()
    }

    /// A stroke 12× the fitted one and a current beyond the fitted 0–1 A are both named,
    /// with how far; the same motion at a fitted current is inside.
    #[test]
    fn excursions_name_the_quantity_and_how_far() {
        let env = merge(vec![point(0.004, 0.0), point(0.004, 1.0)]);
        let inside = check(&env, &point(0.004, 0.5), &inputs());
        assert!(inside.inside, "{:?}", inside.excursions);
        let mut far = point(0.048, 5.0);
        far.velocity = 0.05;
        let c = check(&env, &far, &inputs());
        assert!(!c.inside);
        let stroke = c
            .excursions
            .iter()
            .find(|e| e.quantity == "stroke")
            .unwrap();
        assert!((stroke.beyond - 12.0).abs() < 1e-9, "{}", stroke.text);
        assert!(
            stroke.text.contains("12× the fitted range"),
            "{}",
            stroke.text
        );
        let cur = c
            .excursions
            .iter()
            .find(|e| e.quantity == "current")
            .unwrap();
        assert!((cur.beyond - 4.0).abs() < 1e-12, "{}", cur.text);
        assert!(
            cur.text.contains("outside the fitted 0–1 A"),
            "{}",
            cur.text
        );
    }
}
