//! Spectra of sampled signals: Welch's averaged periodogram and the H1 frequency-response
//! estimate, with the segmentation `ehactl diagnose` uses. FFTs by the `realfft` crate.

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

#[cfg(test)]
mod tests {
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
