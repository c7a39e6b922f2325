//! Is the held-out residual noise? Per channel a level test (NRMSE over the channel's noise
//! floor) and a whiteness test (Ljung–Box portmanteau statistic, Ljung & Box, Biometrika
//! 65(2):297–303, 1978; also Ljung, *System Identification* 2nd ed. §16.6), and, when it is not
//! noise, the residual's signature: frequency band, the state it depends on most, its lag
//! behind the command. `diagnose` answers `none` only when the residual is noise, and
//! `unexplained` (with this signature) when it is not and no catalogue effect explains it.

use crate::data::{ChannelKind, Record};
use crate::replay::{std, Replay};
use crate::spectrum::welch;
use serde::Serialize;

/// Lags in the Ljung–Box statistic.
pub const LB_LAGS: usize = 20;
/// 99 % quantile of χ² with 20 degrees of freedom (tables, e.g. NIST/SEMATECH e-Handbook
/// §1.3.6.7.4): above it the residual is not white at the 1 % level.
pub const LB_CRIT_20: f64 = 37.566;
/// A residual this many times its noise floor (NRMSE units) is not noise even when the
/// whiteness test passes (a white but too large residual: wrong noise model or a broadband
/// error) (-).
pub const LEVEL_HARD: f64 = 10.0;
/// Below this level the residual counts as noise whatever its colour (-); above it only a
/// white residual does. A coloured residual (Ljung–Box above [`LB_CRIT_20`]) holds structure
/// the model lacks; it passes as noise only below this multiple of the noise floor.
/// Calibrated on clean records only, never on hidden effects: after the nominal refit (with
/// [`crate::diagnose::REFIT_BUDGET`] and a restart) the clean records leave a coloured
/// residual of at most 1.92× on the test bench (seed 5081, position: the refit's cost is the
/// mean NRMSE² over channels and barely weighs the low-noise position channel) and on the
/// independent generator (seed 7020, position), and 2.36× on its PI force rig (seed 7200,
/// force: the generator's loop and load are not ehactl's structure); 2.5 is above all of them.
/// It was 6.0 until 2026-11-28 (calibrated with the shorter refit, which left up to 4.3×); with
/// 6.0, effects at 2–4× the sensor noise that left a residual 2.5–5× the floor and thousands
/// of Ljung–Box units from white were answered `none` (DIAGNOSIS.md, "Small magnitudes"). The
/// configured-step shortcut, which refits nothing, is stricter
/// ([`crate::diagnose::SHORTCUT_LEVEL`], white on every channel).
pub const LEVEL_SOFT: f64 = 2.5;
/// The soft level when nothing was fitted to the record (every stated `[uncertainty]` 0, no
/// assumed loop identified, no effect accepted) (-): no fit left colour to excuse, so a
/// coloured residual counts as noise only at or below its floor, as in the configured-step
/// shortcut ([`crate::diagnose::SHORTCUT_LB_CRIT`]). With [`LEVEL_SOFT`] there, a line at 2.5×
/// the noise on the test bench's exact config, stated as known, was answered `none` with its
/// position residual 2.0× the floor and Ljung–Box Q ≈ 5900 (`tests/false_none.rs`).
pub const LEVEL_SOFT_UNFITTED: f64 = 1.0;
/// A residual this many times its noise floor is large: the weak-winner rule of
/// `crate::weigh` uses it (a winner that leaves it on some channel is compared with the
/// runner-up), and the evaluation on the independent generator counts a final residual above
/// it (against the generator's true noise) as clearly above the noise (-).
pub const LEVEL_LARGE: f64 = 6.0;

/// Test result of one channel.
#[derive(Debug, Clone, Serialize)]
pub struct ChannelTest {
    /// Channel (CSV column).
    pub channel: String,
    /// Held-out NRMSE over the noise floor (-).
    pub level: f64,
    /// Ljung–Box Q over lags 1…20 of the held-out residual (-).
    pub ljung_box: f64,
    /// Whether Q is below the 1 % critical value (white).
    pub white: bool,
    /// Whether this channel's residual counts as noise: level ≤ the soft level
    /// ([`ResidualTest::soft_level`]), or level ≤ [`LEVEL_HARD`] and white.
    pub noise: bool,
}

/// Where a residual that is not noise lives.
#[derive(Debug, Clone, Serialize)]
pub struct Signature {
    /// Channel with the largest level.
    pub channel: String,
    /// Band holding 10 … 90 % of the residual energy above the noise floor (Hz).
    pub band_hz: (f64, f64),
    /// Frequency of the largest excess PSD (Hz).
    pub peak_hz: f64,
    /// The regressor the residual correlates with most (`velocity`, `sign(velocity)`,
    /// `command`, `position`, `load pressure p_a − p_b`) and the correlation coefficient.
    pub depends_on: (String, f64),
    /// All correlation coefficients, same names (-).
    pub correlations: Vec<(String, f64)>,
    /// Lag of the residual behind the command at the largest |cross-correlation| (s).
    pub lag_s: f64,
    /// The signature in words.
    pub text: String,
}

/// The whole test.
#[derive(Debug, Clone, Serialize)]
pub struct ResidualTest {
    /// Which model was tested (`extended` / `nominal refit`).
    pub model: String,
    /// Per channel.
    pub channels: Vec<ChannelTest>,
    /// Level below which a channel counts as noise whatever its colour (-): [`LEVEL_SOFT`]
    /// after a fit, [`LEVEL_SOFT_UNFITTED`] when nothing was fitted.
    pub soft_level: f64,
    /// Whether every channel is noise.
    pub noise: bool,
    /// Signature when not noise.
    pub signature: Option<Signature>,
}

/// Ljung–Box Q = N(N+2) Σ_{k=1..m} r_k²/(N−k) of `e` (mean removed: the level test covers a
/// bias).
pub fn ljung_box(e: &[f64], m: usize) -> f64 {
    let n = e.len();
    if n <= m + 1 {
        return 0.0;
    }
    let mu = e.iter().sum::<f64>() / n as f64;
    let d: Vec<f64> = e.iter().map(|v| v - mu).collect();
    let c0: f64 = d.iter().map(|v| v * v).sum::<f64>();
    if c0 <= 0.0 {
        return 0.0;
    }
    let nf = n as f64;
    (1..=m)
        .map(|k| {
            let ck: f64 = d[k..].iter().zip(&d[..n - k]).map(|(a, b)| a * b).sum();
            let r = ck / c0;
            r * r / (nf - k as f64)
        })
        .sum::<f64>()
        * nf
        * (nf + 2.0)
}

/// Pearson correlation of two traces over their common length (0 when either is constant).
pub(crate) fn corr(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    if n < 3 {
        return 0.0;
    }
    let (ma, mb) = (
        a[..n].iter().sum::<f64>() / n as f64,
        b[..n].iter().sum::<f64>() / n as f64,
    );
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for k in 0..n {
        let (x, y) = (a[k] - ma, b[k] - mb);
        sab += x * y;
        saa += x * x;
        sbb += y * y;
    }
    if saa <= 0.0 || sbb <= 0.0 {
        0.0
    } else {
        sab / (saa * sbb).sqrt()
    }
}

/// Test the residual of `sim` against `rec` on `range`; `floor` per channel in NRMSE units;
/// `soft_level` as [`ResidualTest::soft_level`].
pub fn test(
    model: &str,
    rec: &Record,
    sim: &Replay,
    range: std::ops::Range<usize>,
    floor: &[f64],
    soft_level: f64,
) -> ResidualTest {
    let mut channels = Vec::new();
    let mut worst: Option<(f64, usize)> = None;
    for (c, (ch, yh)) in rec.channels.iter().zip(&sim.y).enumerate() {
        let y = &ch.values[range.clone()];
        let e: Vec<f64> = y
            .iter()
            .zip(&yh[range.clone()])
            .map(|(a, b)| a - b)
            .collect();
        let nr = (e.iter().map(|v| v * v).sum::<f64>() / e.len().max(1) as f64).sqrt()
            / std(y).max(1e-300);
        let level = nr / floor.get(c).copied().unwrap_or(0.0).max(1e-12);
        let q = ljung_box(&e, LB_LAGS);
        let white = q <= LB_CRIT_20;
        let noise = level <= soft_level || (level <= LEVEL_HARD && white);
        if !noise && worst.is_none_or(|w| level > w.0) {
            worst = Some((level, c));
        }
        channels.push(ChannelTest {
            channel: ch.kind.column().to_string(),
            level,
            ljung_box: q,
            white,
            noise,
        });
    }
    let signature = worst.map(|(_, c)| signature(rec, sim, range.clone(), c, floor[c]));
    ResidualTest {
        model: model.to_string(),
        noise: signature.is_none(),
        channels,
        soft_level,
        signature,
    }
}

/// Where the residual of channel `c` over `range` departs from noise: the band and peak of
/// its energy above the white `floor` (NRMSE units), the state it correlates with most and
/// its lag behind the command.
fn signature(
    rec: &Record,
    sim: &Replay,
    range: std::ops::Range<usize>,
    c: usize,
    floor: f64,
) -> Signature {
    let ch = &rec.channels[c];
    let y = &ch.values[range.clone()];
    let e: Vec<f64> = y
        .iter()
        .zip(&sim.y[c][range.clone()])
        .map(|(a, b)| a - b)
        .collect();
    let (lo, hi, peak_hz) = excess_band(&e, rec.dt, (floor * std(y)).powi(2));
    let correlations: Vec<(String, f64)> = state_regressors(rec, sim, range.clone())
        .iter()
        .map(|(n, r)| (n.clone(), corr(&e, r)))
        .collect();
    let depends_on = correlations
        .iter()
        .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
        .cloned()
        .unwrap_or(("none".into(), 0.0));
    let lag_s = command_lag(&e, &rec.u[range.clone()], rec.dt);
    let text = format!(
        "residual on `{}` is not noise: energy above the floor in {:.1}–{:.1} Hz (peak {:.1} Hz); it correlates most with {} (r = {:+.2}); largest correlation with the command at a lag of {:.1} ms",
        ch.kind.column(),
        lo,
        hi,
        peak_hz,
        depends_on.0,
        depends_on.1,
        lag_s * 1e3
    );
    Signature {
        channel: ch.kind.column().to_string(),
        band_hz: (lo, hi),
        peak_hz,
        depends_on,
        correlations,
        lag_s,
        text,
    }
}

/// The band holding the 10–90 % of the residual `e`'s power above the white floor of
/// variance `var_floor` (the channel's unit squared) and the frequency of its largest excess:
/// (low, high, peak) in Hz. `dt` is the sample period (s).
fn excess_band(e: &[f64], dt: f64, var_floor: f64) -> (f64, f64, f64) {
    // Excess PSD over the white floor (floor in NRMSE units → variance per Hz).
    let (f, psd) = welch(e, dt);
    let fnyq = 0.5 / dt;
    let white = var_floor / fnyq;
    let excess: Vec<f64> = psd.iter().map(|p| (p - white).max(0.0)).collect();
    let total: f64 = excess.iter().sum();
    let (mut lo, mut hi, mut acc) = (f[0], *f.last().unwrap_or(&0.0), 0.0);
    let mut lo_set = false;
    for (fk, xk) in f.iter().zip(&excess) {
        acc += xk;
        if !lo_set && acc >= 0.1 * total {
            lo = *fk;
            lo_set = true;
        }
        if acc >= 0.9 * total {
            hi = *fk;
            break;
        }
    }
    let peak_hz = f
        .iter()
        .zip(&excess)
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map_or(0.0, |p| *p.0);
    (lo, hi, peak_hz)
}

/// The states a residual may depend on over `range`, named: measured where available, else
/// the model's velocity.
fn state_regressors(
    rec: &Record,
    sim: &Replay,
    range: std::ops::Range<usize>,
) -> Vec<(String, Vec<f64>)> {
    let v = &sim.v[range.clone()];
    let mut regs: Vec<(String, Vec<f64>)> = vec![
        ("velocity".into(), v.to_vec()),
        (
            "sign(velocity)".into(),
            v.iter().map(|x| x.signum()).collect(),
        ),
        ("command".into(), rec.u[range.clone()].to_vec()),
    ];
    if let Some(x) = rec.channel(ChannelKind::Position) {
        regs.push(("position".into(), x[range.clone()].to_vec()));
    }
    if let (Some(pa), Some(pb)) = (
        rec.channel(ChannelKind::PressureA),
        rec.channel(ChannelKind::PressureB),
    ) {
        regs.push((
            "load pressure p_a − p_b".into(),
            pa[range.clone()]
                .iter()
                .zip(&pb[range.clone()])
                .map(|(a, b)| a - b)
                .collect(),
        ));
    } else if let Some(pa) = rec.channel(ChannelKind::PressureA) {
        regs.push(("pressure p_a".into(), pa[range].to_vec()));
    }
    regs
}

/// The residual's lag behind the command (s): the lag l of its largest |cross-correlation|
/// with u_{k−l}, up to a quarter of the record and at most 0.2 s.
fn command_lag(e: &[f64], u: &[f64], dt: f64) -> f64 {
    let max_lag = (e.len() / 4).min((0.2 / dt) as usize).max(1);
    let mut best = (0.0f64, 0usize);
    for l in 0..=max_lag {
        let r = corr(&e[l..], &u[..u.len() - l]).abs();
        if r > best.0 {
            best = (r, l);
        }
    }
    best.1 as f64 * dt
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Q of white noise is χ²(20)-distributed: mean 20; an AR(1) residual with pole 0.5 has
    /// r_k = 0.5^k, so Q ≈ N·Σ0.25^k ≈ N/3 (closed form), far above the critical value.
    #[test]
    fn ljung_box_white_vs_ar1() {
        let mut s = 12345u64;
        let mut g = || {
            // Sum of 12 uniforms − 6: approximately standard normal.
            (0..12)
                .map(|_| {
                    s = s
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (s >> 11) as f64 / (1u64 << 53) as f64
                })
                .sum::<f64>()
                - 6.0
        };
        let n = 3000;
        let w: Vec<f64> = (0..n).map(|_| g()).collect();
        let q = ljung_box(&w, LB_LAGS);
        assert!(q < LB_CRIT_20, "white noise Q = {q}");
        let mut ar = vec![0.0; n];
        for k in 1..n {
            ar[k] = 0.5 * ar[k - 1] + w[k];
        }
        let q = ljung_box(&ar, LB_LAGS);
        let expect = n as f64 / 3.0;
        assert!(
            (q - expect).abs() < 0.15 * expect,
            "AR(1) Q = {q}, closed form ≈ {expect}"
        );
    }
}
