//! What the campaign, the envelope, `predict` and the single-record diagnosis share about a
//! record's motion: its velocity from the position (a least-squares derivative) and the share
//! of a record held out. Below all four, so that none imports another for it.

use crate::data::Record;

/// Fraction of each record held out when no validation records are given (-).
pub const HOLDOUT: f64 = 0.3;

/// Half-width (s) of the least-squares derivative that turns x into v when a config states
/// none (`sensors.position.velocity_window` = 0): ±2 ms.
pub const DEFAULT_VELOCITY_WINDOW: f64 = 2e-3;

/// Piston velocity (m/s) of a record: its `v` column, or the least-squares derivative of `x`
/// over ±`window` s (0: [`DEFAULT_VELOCITY_WINDOW`]), at least one sample each side.
pub fn record_velocity(rec: &Record, x: &[f64], window: f64) -> Vec<f64> {
    match &rec.velocity {
        Some(v) => v.clone(),
        None => {
            let w = if window > 0.0 {
                window
            } else {
                DEFAULT_VELOCITY_WINDOW
            };
            derivative(x, rec.dt, ((w / rec.dt).round() as usize).clamp(1, 1000))
        }
    }
}

/// Least-squares derivative (m/s) of x with half-width `m` samples: the slope of the straight
/// line through 2m + 1 samples (Savitzky & Golay 1964, first derivative, degree 1–2), the
/// window shrinking at the ends. Written here: a single convolution, no crate offers it
/// for plain slices.
pub fn derivative(x: &[f64], dt: f64, m: usize) -> Vec<f64> {
    let n = x.len();
    (0..n)
        .map(|k| {
            let h = m.min(k).min(n - 1 - k);
            if h == 0 {
                return if k + 1 < n {
                    (x[k + 1] - x[k]) / dt
                } else if k > 0 {
                    (x[k] - x[k - 1]) / dt
                } else {
                    0.0
                };
            }
            let (mut num, mut den) = (0.0, 0.0);
            for j in 1..=h {
                num += j as f64 * (x[k + j] - x[k - j]);
                den += 2.0 * (j * j) as f64;
            }
            num / (den * dt)
        })
        .collect()
}
