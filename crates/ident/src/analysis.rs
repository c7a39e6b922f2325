//! Residual analysis: where in time, frequency and state space the error of a replay
//! concentrates. Produces evidence strings and a prior ranking of catalogue effects
//! (the reasoning of Sirohi 2003 §5 done by machine: error at velocity reversal → friction,
//! error near zero command → dead band, a narrow residual line → sensor tone, a broad
//! residual peak → an unmodelled mode, constant lag → delay or spool dynamics).

use crate::data::{ChannelKind, Record};
use crate::replay::{std, Replay};
use ehactl_plant::EffectId;

/// A narrow line in a residual spectrum.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Peak {
    /// Channel (CSV column name).
    pub channel: &'static str,
    /// Frequency (Hz).
    pub frequency: f64,
    /// Amplitude of the equivalent sine (channel unit).
    pub amplitude: f64,
    /// Peak PSD over the median PSD of its neighbourhood (-).
    pub prominence: f64,
}

/// Findings of the residual analysis of one replay.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Analysis {
    /// Residual RMS over the record's RMS deviation, per channel (-).
    pub nrmse: Vec<f64>,
    /// Estimated sensor noise per channel (channel unit).
    pub noise: Vec<f64>,
    /// RMS residual within ±10 ms of velocity reversals over overall RMS (-).
    pub reversal_ratio: f64,
    /// RMS residual where |u| < 5 % of max |u| over overall RMS (-).
    pub small_command_ratio: f64,
    /// RMS residual where |u| > 70 % of max |u| over overall RMS (-).
    pub large_command_ratio: f64,
    /// |mean residual| / RMS residual, averaged over pressure channels (-): a level shift;
    /// None when the data has no pressure channel.
    pub bias_share: Option<f64>,
    /// Lag of the measured signal behind the model by cross-correlation (s), median over channels.
    pub lag: f64,
    /// Narrow residual lines (tones), strongest first.
    pub tones: Vec<Peak>,
    /// Frequency (Hz) where the residual-to-signal PSD ratio is largest below Nyquist/2
    /// (tones excluded): an unmodelled or shifted mode.
    pub mode_frequency: f64,
    /// That ratio (-).
    pub mode_ratio: f64,
    /// Prior score per effect (higher = more suspicious) and its evidence, catalogue order.
    #[serde(skip)]
    pub prior: Vec<(EffectId, f64, String)>,
}

/// Welch one-sided PSD with the segment length diagnose uses: a power of two, the largest
/// ≤ n/2 from 256 up to 4096, capped at `n.next_power_of_two() / 2` and at least 16 for
/// short records. Returns (frequencies Hz, PSD unit²/Hz); see [`welch_segments`].
pub fn welch(y: &[f64], dt: f64) -> (Vec<f64>, Vec<f64>) {
    let n = y.len();
    let mut seg = 256usize;
    while seg * 2 <= n / 2 && seg < 4096 {
        seg *= 2;
    }
    let seg = seg.min(n.next_power_of_two() / 2).max(16);
    welch_segments(y, dt, seg)
}

/// Welch one-sided PSD (unit²/Hz) of `y` sampled every `dt` s, over segments of `seg`
/// samples (any length ≥ 2) overlapping by `seg / 2`: periodic Hann window, mean removed
/// per segment, density scaling, segment spectra averaged — the definition of
/// `scipy.signal.welch(y, fs=1/dt, window="hann", nperseg=seg, noverlap=seg//2)` (checked
/// against it in the tests). FFTs by the `realfft` crate (planned once per call). A record
/// shorter than one segment gives an all-zero PSD. Returns (frequencies Hz, PSD).
pub fn welch_segments(y: &[f64], dt: f64, seg: usize) -> (Vec<f64>, Vec<f64>) {
    let n = y.len();
    let seg = seg.max(2);
    let step = seg - seg / 2;
    let fft = realfft::RealFftPlanner::<f64>::new().plan_fft_forward(seg);
    let mut input = fft.make_input_vec();
    let mut spec = fft.make_output_vec();
    let win: Vec<f64> = (0..seg)
        .map(|i| 0.5 - 0.5 * (std::f64::consts::TAU * i as f64 / seg as f64).cos())
        .collect();
    let wss: f64 = win.iter().map(|w| w * w).sum();
    let mut psd = vec![0.0; seg / 2 + 1];
    let mut count = 0;
    let mut start = 0;
    while start + seg <= n {
        let part = &y[start..start + seg];
        let m = part.iter().sum::<f64>() / seg as f64;
        for ((x, v), w) in input.iter_mut().zip(part).zip(&win) {
            *x = (v - m) * w;
        }
        fft.process(&mut input, &mut spec)
            .expect("buffers made by the plan have its lengths");
        for (k, (p, c)) in psd.iter_mut().zip(&spec).enumerate() {
            // one-sided: every bin but DC and (even length) Nyquist stands for two
            let s = if k == 0 || (seg.is_multiple_of(2) && k == seg / 2) {
                1.0
            } else {
                2.0
            };
            *p += s * c.norm_sqr() * dt / wss;
        }
        count += 1;
        start += step;
    }
    let count = count.max(1) as f64;
    psd.iter_mut().for_each(|p| *p /= count);
    let f = (0..=seg / 2)
        .map(|k| k as f64 / (seg as f64 * dt))
        .collect();
    (f, psd)
}

/// H1 frequency-response estimate u → y (unit of y per unit of u) over Welch segments of
/// `seg` samples overlapping by `seg / 2` (periodic Hann window, mean removed per segment):
/// H1(f) = S_uy(f) / S_uu(f), the estimator that is unbiased for noise on the output
/// (Bendat & Piersol, *Random Data*, 4th ed., §9.1). Same segmentation as
/// [`welch_segments`]. Returns (frequencies Hz, H as (re, im) pairs); bins where u has no
/// power are (0, 0).
pub fn h1_estimate(u: &[f64], y: &[f64], dt: f64, seg: usize) -> (Vec<f64>, Vec<(f64, f64)>) {
    let n = u.len().min(y.len());
    let seg = seg.max(2);
    let step = seg - seg / 2;
    let fft = realfft::RealFftPlanner::<f64>::new().plan_fft_forward(seg);
    let (mut iu, mut iy) = (fft.make_input_vec(), fft.make_input_vec());
    let (mut su, mut sy) = (fft.make_output_vec(), fft.make_output_vec());
    let win: Vec<f64> = (0..seg)
        .map(|i| 0.5 - 0.5 * (std::f64::consts::TAU * i as f64 / seg as f64).cos())
        .collect();
    let mut suu = vec![0.0; seg / 2 + 1];
    let mut suy = vec![(0.0, 0.0); seg / 2 + 1];
    let mut start = 0;
    while start + seg <= n {
        for (buf, src) in [
            (&mut iu, &u[start..start + seg]),
            (&mut iy, &y[start..start + seg]),
        ] {
            let m = src.iter().sum::<f64>() / seg as f64;
            for ((x, v), w) in buf.iter_mut().zip(src).zip(&win) {
                *x = (v - m) * w;
            }
        }
        fft.process(&mut iu, &mut su)
            .expect("buffers made by the plan have its lengths");
        fft.process(&mut iy, &mut sy)
            .expect("buffers made by the plan have its lengths");
        for k in 0..suu.len() {
            suu[k] += su[k].norm_sqr();
            let c = su[k].conj() * sy[k];
            suy[k].0 += c.re;
            suy[k].1 += c.im;
        }
        start += step;
    }
    let h = suu
        .iter()
        .zip(&suy)
        .map(|(p, c)| {
            if *p > 0.0 {
                (c.0 / p, c.1 / p)
            } else {
                (0.0, 0.0)
            }
        })
        .collect();
    let f = (0..=seg / 2)
        .map(|k| k as f64 / (seg as f64 * dt))
        .collect();
    (f, h)
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v {
        s += x * x;
        n += 1;
    }
    if n == 0 {
        0.0
    } else {
        (s / n as f64).sqrt()
    }
}

/// Lag (samples) maximising the cross-correlation of `y` with `yh` shifted, |lag| ≤ max_lag.
fn best_lag(y: &[f64], yh: &[f64], max_lag: usize) -> i64 {
    let n = y.len().min(yh.len());
    let my = y[..n].iter().sum::<f64>() / n as f64;
    let mh = yh[..n].iter().sum::<f64>() / n as f64;
    let mut best = (f64::NEG_INFINITY, 0i64);
    for l in -(max_lag as i64)..=(max_lag as i64) {
        let mut s = 0.0;
        for (k, yk) in y.iter().enumerate().take(n - max_lag).skip(max_lag) {
            let j = (k as i64 - l) as usize;
            s += (yk - my) * (yh[j] - mh);
        }
        if s > best.0 {
            best = (s, l);
        }
    }
    best.1
}

/// Frequency (Hz) and amplitude of the sine in `e` (sample k at time (k0 + k)·dt) nearest to
/// `f0`, by a fine scan of |DFT| over f0 ± 1.5·df.
fn refine_line(e: &[f64], dt: f64, k0: usize, f0: f64, df: f64) -> (f64, f64) {
    let n = e.len() as f64;
    let mut best = (f0, 0.0);
    let steps = 600;
    for i in 0..=steps {
        let f = f0 - 1.5 * df + 3.0 * df * i as f64 / steps as f64;
        let w = std::f64::consts::TAU * f * dt;
        let (mut c, mut s) = (0.0, 0.0);
        for (k, v) in e.iter().enumerate() {
            let ph = w * (k0 + k) as f64;
            c += v * ph.cos();
            s += v * ph.sin();
        }
        let a = 2.0 * (c * c + s * s).sqrt() / n;
        if a > best.1 {
            best = (f, a);
        }
    }
    best
}

/// Analyse residuals of `sim` against `rec` over `range`.
pub fn analyse(rec: &Record, sim: &Replay, range: std::ops::Range<usize>) -> Analysis {
    let r = range.start..range.end.min(sim.y.first().map_or(0, |y| y.len()));
    let n = r.len();
    let resid: Vec<Vec<f64>> = rec
        .channels
        .iter()
        .zip(&sim.y)
        .map(|(c, yh)| r.clone().map(|k| c.values[k] - yh[k]).collect())
        .collect();
    let nrmse: Vec<f64> = rec
        .channels
        .iter()
        .zip(&resid)
        .map(|(c, e)| {
            let sd = std(&c.values[r.clone()]);
            rms(e.iter().copied()) / if sd > 0.0 { sd } else { 1.0 }
        })
        .collect();
    let noise: Vec<f64> = rec
        .channels
        .iter()
        .map(|c| crate::replay::noise_level(&c.values[r.clone()]))
        .collect();
    // Normalised residual energy per sample (sum over channels of (e/σ_y)²).
    let w: Vec<f64> = (0..n)
        .map(|k| {
            rec.channels
                .iter()
                .zip(&resid)
                .map(|(c, e)| {
                    let sd = std(&c.values[r.clone()]).max(1e-300);
                    (e[k] / sd).powi(2)
                })
                .sum::<f64>()
        })
        .collect();
    let total = (w.iter().sum::<f64>() / n.max(1) as f64).sqrt().max(1e-300);
    let ratio = |mask: &dyn Fn(usize) -> bool| -> f64 {
        let sel: Vec<f64> = (0..n).filter(|&k| mask(k)).map(|k| w[k]).collect();
        if sel.len() < n / 100 + 3 {
            return 1.0;
        }
        (sel.iter().sum::<f64>() / sel.len() as f64).sqrt() / total
    };
    // Velocity: smoothed derivative of measured position when present, else the model's.
    let vel: Vec<f64> = match rec.channel(ChannelKind::Position) {
        Some(x) => {
            let h = ((0.005 / rec.dt).round() as usize).max(1);
            (0..rec.len())
                .map(|k| {
                    let a = k.saturating_sub(h);
                    let b = (k + h).min(rec.len() - 1);
                    (x[b] - x[a]) / ((b - a).max(1) as f64 * rec.dt)
                })
                .collect()
        }
        None => sim.v.clone(),
    };
    let vmax = r.clone().fold(0.0f64, |a, k| a.max(vel[k].abs()));
    let win = ((0.01 / rec.dt).round() as usize).max(1);
    let mut near_rev = vec![false; n];
    let mut last_sign = 0.0;
    for (i, k) in r.clone().enumerate() {
        if vel[k].abs() < 0.05 * vmax {
            continue;
        }
        let s = vel[k].signum();
        if last_sign != 0.0 && s != last_sign {
            // Mark back to the previous zero crossing region and forward.
            let a = i.saturating_sub(2 * win);
            let b = (i + win).min(n);
            near_rev[a..b].iter_mut().for_each(|m| *m = true);
        }
        last_sign = s;
    }
    let reversal_ratio = ratio(&|k| near_rev[k]);
    let umax = r.clone().fold(0.0f64, |a, k| a.max(rec.u[k].abs()));
    let small_command_ratio = ratio(&|k| rec.u[r.start + k].abs() < 0.05 * umax);
    let large_command_ratio = ratio(&|k| rec.u[r.start + k].abs() > 0.7 * umax);
    // Level shift of the pressure residual before any sensor offset was profiled out of the
    // replay (a zero error and a leak both shift the level; only the leak's shift moves
    // with the operating point, which the fits tell apart).
    let mut bias = Vec::new();
    for (i, (c, e)) in rec.channels.iter().zip(&resid).enumerate() {
        if matches!(c.kind, ChannelKind::PressureA | ChannelKind::PressureB) {
            let b = sim.offsets.get(i).copied().unwrap_or(0.0);
            let m = e.iter().sum::<f64>() / n as f64;
            let r2 = rms(e.iter().copied()).powi(2) + 2.0 * b * m + b * b;
            bias.push((m + b).abs() / r2.max(0.0).sqrt().max(1e-300));
        }
    }
    let bias_share = if bias.is_empty() {
        None
    } else {
        Some(bias.iter().sum::<f64>() / bias.len() as f64)
    };
    let max_lag = ((0.05 / rec.dt).round() as usize).clamp(2, n / 4);
    let mut lags: Vec<f64> = rec
        .channels
        .iter()
        .zip(&sim.y)
        .map(|(c, yh)| best_lag(&c.values[r.clone()], &yh[r.clone()], max_lag) as f64 * rec.dt)
        .collect();
    lags.sort_by(f64::total_cmp);
    let lag = lags.get(lags.len() / 2).copied().unwrap_or(0.0);
    // Spectra.
    let mut tones = Vec::new();
    let (mut mode_frequency, mut mode_ratio) = (0.0, 0.0);
    for (c, e) in rec.channels.iter().zip(&resid) {
        let (f, pe) = welch(e, rec.dt);
        let (_, py) = welch(&c.values[r.clone()], rec.dt);
        let df = f.get(1).copied().unwrap_or(1.0);
        let m = pe.len();
        let mut is_tone = vec![false; m];
        for k in 3..m.saturating_sub(3) {
            let lo = k.saturating_sub(12).max(1);
            let hi = (k + 13).min(m);
            let mut nb: Vec<f64> = (lo..hi)
                .filter(|&j| j.abs_diff(k) > 2)
                .map(|j| pe[j])
                .collect();
            nb.sort_by(f64::total_cmp);
            let med = nb[nb.len() / 2].max(1e-300);
            if pe[k] > pe[k - 1] && pe[k] >= pe[k + 1] && pe[k] / med > 30.0 {
                // Sum the Hann main lobe to get the line's power: A = √(2·Σ PSD·df).
                let p: f64 = pe[k - 1..=k + 1].iter().sum::<f64>() * df;
                // Refine the frequency far below the Welch resolution by scanning the DFT of
                // the whole residual: a tone model must keep its phase over the record.
                let (fr, amp) = refine_line(e, rec.dt, r.start, f[k], df);
                tones.push(Peak {
                    channel: c.kind.column(),
                    frequency: fr,
                    amplitude: if amp > 0.0 {
                        amp
                    } else {
                        (2.0 * p / 1.5).sqrt()
                    },
                    prominence: pe[k] / med,
                });
                for t in is_tone
                    .iter_mut()
                    .take((k + 4).min(m))
                    .skip(k.saturating_sub(3))
                {
                    *t = true;
                }
            }
        }
        // Broad mismatch: residual over signal PSD, smoothed, below Nyquist/2.
        for k in 2..m / 2 {
            if is_tone[k] || py[k] <= 0.0 {
                continue;
            }
            let a = k.saturating_sub(2);
            let b = (k + 3).min(m);
            let num: f64 = (a..b).filter(|&j| !is_tone[j]).map(|j| pe[j]).sum();
            let den: f64 = (a..b).map(|j| py[j]).sum::<f64>().max(1e-300);
            let ratio = num / den;
            // Weight by the share of residual power near k so noise-only bins do not win.
            let share = num / pe.iter().sum::<f64>().max(1e-300);
            let score = ratio.min(10.0) * share;
            if score > mode_ratio {
                mode_ratio = score;
                mode_frequency = f[k];
            }
        }
    }
    tones.sort_by(|a, b| b.prominence.total_cmp(&a.prominence));
    let nr = crate::replay::overall(&nrmse);
    let noise_share = {
        let v: Vec<f64> = rec
            .channels
            .iter()
            .zip(&noise)
            .map(|(c, s)| s / std(&c.values[r.clone()]).max(1e-300))
            .collect();
        crate::replay::overall(&v)
    };
    let mut prior = Vec::new();
    for e in EffectId::ALL {
        let (score, ev) = match e {
            EffectId::Friction => (
                reversal_ratio,
                format!("residual RMS within 10 ms of velocity reversals is {reversal_ratio:.2}× the overall RMS"),
            ),
            EffectId::ValveDeadband => (
                small_command_ratio,
                format!("residual RMS where |u| < 5 % of its maximum is {small_command_ratio:.2}× the overall RMS"),
            ),
            EffectId::ValveSaturation | EffectId::SupplyPressureDrop => (
                large_command_ratio,
                format!("residual RMS where |u| > 70 % of its maximum is {large_command_ratio:.2}× the overall RMS"),
            ),
            EffectId::ValveDynamics | EffectId::TimeDelay => (
                1.0 + (lag / rec.dt).abs() / 2.0,
                format!(
                    "measured outputs lag the model by {:.2} ms (cross-correlation, median over channels)",
                    lag * 1e3
                ),
            ),
            EffectId::InternalLeakage | EffectId::ExternalLeakage => (
                1.0 + bias_share.unwrap_or(0.0),
                match bias_share {
                    Some(b) => format!("mean pressure residual is {:.0} % of its RMS (a level shift)", b * 100.0),
                    None => "no pressure measured: judged by the fits alone".into(),
                },
            ),
            EffectId::SensorTone => match tones.first() {
                Some(p) => (
                    1.0 + p.prominence.log10(),
                    format!(
                        "narrow residual line at {:.1} Hz on `{}` ({:.3e} amplitude, {:.0}× the neighbouring PSD)",
                        p.frequency, p.channel, p.amplitude, p.prominence
                    ),
                ),
                None => (0.5, "no narrow line in the residual spectra".to_string()),
            },
            EffectId::FlexibleMount | EffectId::LineDynamics | EffectId::BulkModulusPressure => (
                1.0 + mode_ratio,
                format!(
                    "residual-to-signal spectrum ratio peaks near {mode_frequency:.1} Hz (a shifted or unmodelled mode)"
                ),
            ),
        };
        prior.push((e, score, ev));
    }
    let _ = (nr, noise_share);
    Analysis {
        nrmse,
        noise,
        reversal_ratio,
        small_command_ratio,
        large_command_ratio,
        bias_share,
        lag,
        tones,
        mode_frequency,
        mode_ratio,
        prior,
    }
}

#[cfg(test)]
mod welch_tests {
    use super::*;

    /// H1 of a known FIR filter y[k] = b0·u[k] + b1·u[k−1] driven by white noise is
    /// H(f) = b0 + b1·e^(−j2πf·dt) (closed form): the estimate must follow it.
    #[test]
    fn h1_recovers_a_known_fir_response() {
        let (b0, b1, dt) = (0.5, 0.3, 1e-3);
        // Deterministic white-ish input: a 64-bit LCG mapped to [−1, 1).
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let u: Vec<f64> = (0..65_536)
            .map(|_| {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
            })
            .collect();
        let y: Vec<f64> = (0..u.len())
            .map(|k| b0 * u[k] + if k > 0 { b1 * u[k - 1] } else { 0.0 })
            .collect();
        let (f, h) = h1_estimate(&u, &y, dt, 1024);
        assert_eq!(f.len(), 513);
        assert!((f[1] - 1.0 / (1024.0 * dt)).abs() < 1e-12);
        let mut worst: f64 = 0.0;
        for (fk, (re, im)) in f.iter().zip(&h).skip(1) {
            let w = std::f64::consts::TAU * fk * dt;
            let (er, ei) = (b0 + b1 * w.cos(), -b1 * w.sin());
            worst = worst.max(((re - er).powi(2) + (im - ei).powi(2)).sqrt());
        }
        // Windowing leaks the one-sample delay's edge term: a few 1e-3 at most.
        assert!(worst < 5e-3, "worst |H1 − H| = {worst}");
    }

    /// The reference signal of tests/data/welch_scipy.py.
    fn signal(n: usize, dt: f64) -> Vec<f64> {
        (0..n)
            .map(|i| {
                let t = i as f64 * dt;
                let noise = ((i * 7919) % 101) as f64 / 101.0 - 0.5;
                (std::f64::consts::TAU * 50.0 * t).sin()
                    + 0.5 * (std::f64::consts::TAU * 173.3 * t + 1.0).sin()
                    + 0.2 * noise
                    + 0.7
            })
            .collect()
    }

    /// Equal to scipy.signal.welch (values stored by tests/data/welch_scipy.py) for even,
    /// non-power-of-two and odd segment lengths, within float rounding.
    #[test]
    fn equals_scipy_welch() {
        let v: serde_json::Value =
            serde_json::from_str(include_str!("../tests/data/welch_scipy.json")).unwrap();
        for case in v["cases"].as_array().unwrap() {
            let n = case["n"].as_u64().unwrap() as usize;
            let dt = case["dt"].as_f64().unwrap();
            let seg = case["seg"].as_u64().unwrap() as usize;
            let num = |k: &str| -> Vec<f64> {
                case[k]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap())
                    .collect()
            };
            let (f, p) = welch_segments(&signal(n, dt), dt, seg);
            let (fr, pr) = (num("f"), num("psd"));
            assert_eq!(f.len(), fr.len(), "seg {seg}");
            let peak = pr.iter().cloned().fold(0.0, f64::max);
            for k in 0..f.len() {
                assert!(
                    (f[k] - fr[k]).abs() <= 1e-12 * fr[fr.len() - 1],
                    "seg {seg} f[{k}]"
                );
                assert!(
                    (p[k] - pr[k]).abs() <= 1e-10 * peak,
                    "seg {seg} psd[{k}]: {} vs scipy {}",
                    p[k],
                    pr[k]
                );
            }
        }
    }

    /// Parseval: the PSD of white noise integrates to its variance (the density scaling).
    #[test]
    fn default_segment_and_variance() {
        let y: Vec<f64> = (0..8192u64)
            .map(|i| {
                let mut z = i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
                z ^= z >> 29;
                z = z.wrapping_mul(0xBF58_476D_1CE4_E5B9);
                z ^= z >> 32;
                (z >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            })
            .collect();
        let (f, p) = welch(&y, 1e-3);
        assert_eq!(f.len(), 4096 / 2 + 1, "8192 samples: 4096-sample segments");
        let df = f[1] - f[0];
        let var: f64 = p.iter().sum::<f64>() * df;
        assert!(
            (var - 1.0 / 12.0).abs() < 0.05 / 12.0,
            "variance {var}, uniform noise 1/12"
        );
    }
}
