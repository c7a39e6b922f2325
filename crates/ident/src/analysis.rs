//! Residual analysis: where in time, frequency and state space the error of a replay
//! concentrates. Produces evidence strings and a prior ranking of catalogue effects
//! (the reasoning of Sirohi 2003 §5 done by machine: error at velocity reversal → friction,
//! error near zero command → dead band, a narrow residual line → sensor tone, a broad
//! residual peak → an unmodelled mode, constant lag → delay or spool dynamics).
//! Each effect's rule lives in its module ([`crate::effects`], `EffectFit::prior`); the
//! findings are [`Analysis`] (`crate::evidence`).

use crate::data::{ChannelKind, Record};
use crate::effects;
use crate::replay::{std, Replay};
use crate::spectrum::welch;
use ehactl_plant::EffectId;

pub use crate::evidence::{Analysis, Peak};

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
    use rayon::prelude::*;
    let n = e.len() as f64;
    let steps = 600;
    // The scan's frequencies are independent: evaluated on every core, the maximum then taken
    // in scan order (the first of equal amplitudes, as a sequential scan would).
    let amp: Vec<(f64, f64)> = (0..=steps)
        .into_par_iter()
        .map(|i| {
            let f = f0 - 1.5 * df + 3.0 * df * i as f64 / steps as f64;
            let w = std::f64::consts::TAU * f * dt;
            let (mut c, mut s) = (0.0, 0.0);
            for (k, v) in e.iter().enumerate() {
                let ph = w * (k0 + k) as f64;
                c += v * ph.cos();
                s += v * ph.sin();
            }
            (f, 2.0 * (c * c + s * s).sqrt() / n)
        })
        .collect();
    let mut best = (f0, 0.0);
    for (f, a) in amp {
        if a > best.1 {
            best = (f, a);
        }
    }
    best
}

/// RMS of the normalised residual energy `w` (per sample, -) over the samples `mask` selects,
/// relative to its RMS `total` over every sample (-); 1 when fewer than 1 % (+3) are selected.
fn error_ratio(w: &[f64], total: f64, mask: &dyn Fn(usize) -> bool) -> f64 {
    let n = w.len();
    let sel: Vec<f64> = (0..n).filter(|&k| mask(k)).map(|k| w[k]).collect();
    if sel.len() < n / 100 + 3 {
        return 1.0;
    }
    (sel.iter().sum::<f64>() / sel.len() as f64).sqrt() / total
}

/// Velocity (m/s) per record sample: the smoothed derivative (±5 ms) of the measured position
/// when present, else the model's.
fn velocity(rec: &Record, sim: &Replay) -> Vec<f64> {
    match rec.channel(ChannelKind::Position) {
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
    }
}

/// Which samples of `r` lie near a velocity reversal of `vel` (m/s): from 2·`win` samples
/// before a sign change to `win` after it, ignoring |v| below 5 % of its maximum.
fn near_reversals(vel: &[f64], r: std::ops::Range<usize>, win: usize) -> Vec<bool> {
    let n = r.len();
    let vmax = r.clone().fold(0.0f64, |a, k| a.max(vel[k].abs()));
    let mut near_rev = vec![false; n];
    let mut last_sign = 0.0;
    for (i, k) in r.enumerate() {
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
    near_rev
}

/// Level shift of the pressure residuals `resid` before any sensor offset was profiled out of
/// the replay `sim`: |mean| over RMS, averaged over the pressure channels (-); `None` without
/// one. A zero error and a leak both shift the level; only the leak's shift moves with the
/// operating point, which the fits tell apart.
fn pressure_bias_share(rec: &Record, sim: &Replay, resid: &[Vec<f64>], n: usize) -> Option<f64> {
    let mut bias = Vec::new();
    for (i, (c, e)) in rec.channels.iter().zip(resid).enumerate() {
        if matches!(c.kind, ChannelKind::PressureA | ChannelKind::PressureB) {
            let b = sim.offsets.get(i).copied().unwrap_or(0.0);
            let m = e.iter().sum::<f64>() / n as f64;
            let r2 = rms(e.iter().copied()).powi(2) + 2.0 * b * m + b * b;
            bias.push((m + b).abs() / r2.max(0.0).sqrt().max(1e-300));
        }
    }
    if bias.is_empty() {
        None
    } else {
        Some(bias.iter().sum::<f64>() / bias.len() as f64)
    }
}

/// Median over channels of the lag (s) by which the measured outputs follow the model over
/// `r` (cross-correlation, |lag| ≤ 50 ms).
fn median_lag(rec: &Record, sim: &Replay, r: std::ops::Range<usize>) -> f64 {
    let n = r.len();
    let max_lag = ((0.05 / rec.dt).round() as usize).clamp(2, n / 4);
    let mut lags: Vec<f64> = rec
        .channels
        .iter()
        .zip(&sim.y)
        .map(|(c, yh)| best_lag(&c.values[r.clone()], &yh[r.clone()], max_lag) as f64 * rec.dt)
        .collect();
    lags.sort_by(f64::total_cmp);
    lags.get(lags.len() / 2).copied().unwrap_or(0.0)
}

/// Narrow lines of the residual PSD `pe` (frequencies `f`, Hz, resolution `df`) of residual `e`
/// of `channel` (sample k at time (k0 + k)·`dt`): the lines pushed onto `tones`, and which bins
/// they cover.
fn narrow_lines(
    e: &[f64],
    (f, pe, df): (&[f64], &[f64], f64),
    (dt, k0): (f64, usize),
    channel: &'static str,
    tones: &mut Vec<Peak>,
) -> Vec<bool> {
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
            let (fr, amp) = refine_line(e, dt, k0, f[k], df);
            tones.push(Peak {
                channel,
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
    is_tone
}

/// Broad mismatch: residual PSD `pe` over signal PSD `py` (frequencies `f`, Hz), smoothed over
/// 5 bins, below Nyquist/2, the bins of narrow lines `is_tone` left out; raises the running
/// best `mode` (frequency in Hz, score -) where a bin's score beats it.
fn broad_mismatch(f: &[f64], pe: &[f64], py: &[f64], is_tone: &[bool], mode: &mut (f64, f64)) {
    let m = pe.len();
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
        if score > mode.1 {
            *mode = (f[k], score);
        }
    }
}

/// Spectra of the residuals `resid` over `r`: the narrow lines (most prominent first) and the
/// broad mismatch's frequency (Hz) and score (-).
fn spectral_findings(
    rec: &Record,
    resid: &[Vec<f64>],
    r: std::ops::Range<usize>,
) -> (Vec<Peak>, f64, f64) {
    let mut tones = Vec::new();
    let mut mode = (0.0, 0.0);
    for (c, e) in rec.channels.iter().zip(resid) {
        let (f, pe) = welch(e, rec.dt);
        let (_, py) = welch(&c.values[r.clone()], rec.dt);
        let df = f.get(1).copied().unwrap_or(1.0);
        let is_tone = narrow_lines(
            e,
            (&f, &pe, df),
            (rec.dt, r.start),
            c.kind.column(),
            &mut tones,
        );
        broad_mismatch(&f, &pe, &py, &is_tone, &mut mode);
    }
    tones.sort_by(|a, b| b.prominence.total_cmp(&a.prominence));
    (tones, mode.0, mode.1)
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
    let sd: Vec<f64> = rec
        .channels
        .iter()
        .map(|c| std(&c.values[r.clone()]).max(1e-300))
        .collect();
    let w: Vec<f64> = (0..n)
        .map(|k| {
            resid
                .iter()
                .zip(&sd)
                .map(|(e, sd)| (e[k] / sd).powi(2))
                .sum::<f64>()
        })
        .collect();
    let total = (w.iter().sum::<f64>() / n.max(1) as f64).sqrt().max(1e-300);
    let vel = velocity(rec, sim);
    let win = ((0.01 / rec.dt).round() as usize).max(1);
    let near_rev = near_reversals(&vel, r.clone(), win);
    let reversal_ratio = error_ratio(&w, total, &|k| near_rev[k]);
    let umax = r.clone().fold(0.0f64, |a, k| a.max(rec.u[k].abs()));
    let small_command_ratio = error_ratio(&w, total, &|k| rec.u[r.start + k].abs() < 0.05 * umax);
    let large_command_ratio = error_ratio(&w, total, &|k| rec.u[r.start + k].abs() > 0.7 * umax);
    let bias_share = pressure_bias_share(rec, sim, &resid, n);
    let lag = median_lag(rec, sim, r.clone());
    let (tones, mode_frequency, mode_ratio) = spectral_findings(rec, &resid, r.clone());
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
    let _ = (nr, noise_share);
    let mut an = Analysis {
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
        prior: Vec::new(),
    };
    // Each effect's evidence rule lives in its module (`crate::effects`).
    an.prior = EffectId::ALL
        .iter()
        .map(|&e| {
            let (score, ev) = effects::of(e).prior(&an, rec.dt);
            (e, score, ev)
        })
        .collect();
    an
}
