//! The uncertainty band on a prediction: the spread of the law's bootstrap refits
//! ([`ehactl_config::envelope::Band`]) and the residual the law leaves out of sample, combined
//! as independent errors,
//!
//! h(t) = z·√(σ_θ(t)² + (r·s_F)²),
//!
//! with σ_θ(t) the standard deviation of the members' predictions at t, r the law's transfer
//! NRMSE on its fitting records (fitted on the first 60 % of each fitting part, scored on the
//! rest), s_F the standard deviation of the predicted force over the scored samples and z the
//! normal quantile of the two-sided level. The members are refits on resamples (with
//! replacement) of the fitting segments — a bootstrap over records and segments (Efron &
//! Tibshirani, *An Introduction to the Bootstrap*, 1993, ch. 9, resampling cases): where the
//! segments disagree about the coefficients, and the more so the further a record's motion
//! goes beyond theirs, the band widens. Its coverage, the share of measured samples inside,
//! is reported beside the NRMSE.

use serde::Serialize;
use std::ops::Range;

/// Two-sided level of the band (-).
pub const LEVEL: f64 = 0.9;
/// Bootstrap refits a campaign keeps for the band (-).
pub const MEMBERS: usize = 40;

/// A band on one predicted channel and how well it covers the measurement.
#[derive(Debug, Clone, Serialize)]
pub struct BandScore {
    /// Two-sided level (-).
    pub level: f64,
    /// Share of the scored measured samples inside the band (-).
    pub coverage: f64,
    /// RMS half-width of the band over the scored samples (unit of the channel).
    pub half_width_rms: f64,
    /// Half of the band's width from the members' spread alone, RMS (unit of the channel).
    pub spread_rms: f64,
    /// Half-width per sample (unit of the channel; the whole record).
    #[serde(skip)]
    pub half_width: Vec<f64>,
}

/// The band around `pred` from the members' predictions `members` (each the length of
/// `pred`), the relative residual `r` and `level`; its coverage of `measured` on `scored`.
pub fn band(
    pred: &[f64],
    members: &[Vec<f64>],
    r: f64,
    level: f64,
    measured: &[f64],
    scored: Range<usize>,
) -> BandScore {
    let n = pred.len();
    let scored = scored.start.min(n)..scored.end.min(n);
    let z = normal_quantile(0.5 + 0.5 * level);
    let s_f = std(&pred[scored.clone()]);
    let spread: Vec<f64> = (0..n)
        .map(|k| {
            let m = members.len() as f64;
            if members.len() < 2 {
                return 0.0;
            }
            let mean = members.iter().map(|p| p[k]).sum::<f64>() / m;
            (members.iter().map(|p| (p[k] - mean).powi(2)).sum::<f64>() / (m - 1.0)).sqrt()
        })
        .collect();
    let half_width: Vec<f64> = spread
        .iter()
        .map(|s| z * (s * s + (r * s_f).powi(2)).sqrt())
        .collect();
    let inside = scored
        .clone()
        .filter(|&k| (measured[k] - pred[k]).abs() <= half_width[k])
        .count();
    let rms = |v: &[f64]| (v.iter().map(|a| a * a).sum::<f64>() / v.len().max(1) as f64).sqrt();
    BandScore {
        level,
        coverage: inside as f64 / scored.len().max(1) as f64,
        half_width_rms: rms(&half_width[scored.clone()]),
        spread_rms: z * rms(&spread[scored]),
        half_width,
    }
}

fn std(y: &[f64]) -> f64 {
    let n = y.len().max(1) as f64;
    let m = y.iter().sum::<f64>() / n;
    (y.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n).sqrt()
}

/// The standard normal quantile Φ⁻¹(p), 0 < p < 1: Acklam's rational approximation (relative
/// error below 1.2e-9), written here as one function instead of a statistics crate.
#[allow(clippy::excessive_precision)] // the published coefficients, as printed
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383577518672690e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// A splitmix64 stream (Steele, Lea & Flood, OOPSLA 2014): the bootstrap's resampling draws,
/// seeded so that a campaign writes the same band every time.
pub struct SplitMix(u64);

impl SplitMix {
    /// A stream from `seed`.
    pub fn new(seed: u64) -> Self {
        SplitMix(seed)
    }

    /// A uniform index in 0..n (n ≥ 1).
    pub fn below(&mut self, n: usize) -> usize {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z as u128 * n as u128) >> 64) as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Φ⁻¹ at the levels of a table of the normal distribution (Abramowitz & Stegun 26.2):
    /// 0.95 → 1.644854, 0.975 → 1.959964, 0.995 → 2.575829, and symmetric.
    #[test]
    fn normal_quantiles_match_the_table() {
        for (p, z) in [
            (0.95, 1.644854),
            (0.975, 1.959964),
            (0.995, 2.575829),
            (0.5, 0.0),
        ] {
            assert!((normal_quantile(p) - z).abs() < 2e-6, "{p}");
            assert!((normal_quantile(1.0 - p) + z).abs() < 2e-6, "{p}");
        }
    }

    /// Gaussian noise of σ = 1 about a prediction whose relative residual says σ: the 90 %
    /// band covers 90 % of the samples (to the binomial scatter of 20 000 samples).
    #[test]
    fn a_band_of_the_true_spread_covers_its_level() {
        let n = 20_000;
        let mut rng = SplitMix::new(3);
        // A sum of 12 uniforms less 6: unit variance, close to normal.
        let noise: Vec<f64> = (0..n)
            .map(|_| {
                (0..12)
                    .map(|_| rng.below(1 << 20) as f64 / (1 << 20) as f64)
                    .sum::<f64>()
                    - 6.0
            })
            .collect();
        let pred: Vec<f64> = (0..n).map(|k| 10.0 * (k as f64 * 0.01).sin()).collect();
        let measured: Vec<f64> = pred.iter().zip(&noise).map(|(p, e)| p + e).collect();
        let r = 1.0 / std(&pred);
        let b = band(&pred, &[], r, 0.9, &measured, 0..n);
        assert!((b.coverage - 0.9).abs() < 0.01, "{}", b.coverage);
    }
}
