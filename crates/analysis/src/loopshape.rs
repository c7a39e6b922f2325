//! Controller transfer functions, loop frequency responses and stability margins.
//!
//! The discrete laws are exactly those of `ehactl-control`:
//! PI (backward-Euler integral, 004 §6.2: K_i = K_P·T_s·I): C(z) = K_P·g·(1 + I·T·z/(z − 1));
//! PD (003 eq. 32 with the derivative filter T_f = T_D/N):
//! C(z) = K_P + K_P·T_D·(1 − z⁻¹)/((T_f + T) − T_f·z⁻¹).
//! Their continuous counterparts are K_P·g·(1 + I/s) and K_P·(1 + T_D·s/(1 + T_f·s)).

use crate::linear::{LinearModel, Output};
use ehactl_config::{ControlMode, RigConfig};
use nalgebra::{Complex, DMatrix, DVector};
use serde::Serialize;
use std::f64::consts::TAU;

/// A control law as a transfer function from error to command.
#[derive(Debug, Clone, Copy)]
pub enum Law {
    /// PI in the ideal form on scaled error: K_P·g·(1 + I/s).
    Pi {
        /// Proportional gain (V/V).
        kp: f64,
        /// Integral rate I (1/s).
        integral: f64,
        /// Error scale g (V per N).
        scale: f64,
    },
    /// PD with filtered derivative: K_P·(1 + T_D·s/(1 + T_f·s)).
    Pd {
        /// Proportional gain (V/m).
        kp: f64,
        /// Derivative time T_D (s).
        td: f64,
        /// Derivative filter time T_f (s).
        tf: f64,
    },
}

impl Law {
    /// The configured law, None in open loop.
    pub fn from_config(cfg: &RigConfig) -> Option<Law> {
        match cfg.control.mode {
            ControlMode::Force => cfg.pi_gains().map(|g| Law::Pi {
                kp: g.kp,
                integral: g.integral,
                scale: g.error_scale,
            }),
            ControlMode::Position => cfg.pd_gains().map(|g| Law::Pd {
                kp: g.kp,
                td: g.td,
                tf: if g.filter_n > 0.0 {
                    g.td / g.filter_n
                } else {
                    0.0
                },
            }),
            ControlMode::OpenLoop => None,
        }
    }

    /// The discrete law at period `dt` (s) as C(z) = (b₀ + b₁·z⁻¹)/(1 + a₁·z⁻¹): returns
    /// (b₀, b₁, a₁), the same transfer function as [`Law::eval`] with `Some(dt)` (module
    /// doc: PI b₀ = K_P·g·(1 + I·T), b₁ = −K_P·g, a₁ = −1; PD multiplied out over
    /// (T_f + T)).
    pub fn discrete_coefficients(&self, dt: f64) -> (f64, f64, f64) {
        match *self {
            Law::Pi {
                kp,
                integral,
                scale,
            } => (kp * scale * (1.0 + integral * dt), -kp * scale, -1.0),
            Law::Pd { kp, td, tf } => {
                let d = tf + dt;
                (kp * (d + td) / d, -kp * (tf + td) / d, -tf / d)
            }
        }
    }

    /// Output channel the law closes on.
    pub fn output(&self) -> Output {
        match self {
            Law::Pi { .. } => Output::Force,
            Law::Pd { .. } => Output::Position,
        }
    }

    /// C(z) at z (discrete, period `dt`) or C(s) at s (dt None).
    pub fn eval(&self, v: Complex<f64>, dt: Option<f64>) -> Complex<f64> {
        let one = Complex::new(1.0, 0.0);
        match (*self, dt) {
            (
                Law::Pi {
                    kp,
                    integral,
                    scale,
                },
                Some(t),
            ) => (one + v * (integral * t) / (v - one)) * (kp * scale),
            (
                Law::Pi {
                    kp,
                    integral,
                    scale,
                },
                None,
            ) => (one + integral / v) * (kp * scale),
            (Law::Pd { kp, td, tf }, Some(t)) => {
                let zi = one / v;
                one * kp + (one - zi) * (kp * td) / (one * (tf + t) - zi * tf)
            }
            (Law::Pd { kp, td, tf }, None) => one * kp + v * (kp * td) / (one + v * tf),
        }
    }
}

/// A loop: law, linear plant, and a pure command delay (s).
pub struct Loop<'a> {
    /// The plant.
    pub plant: &'a LinearModel,
    /// The law.
    pub law: Law,
    /// Command delay τ (s), applied as e^(−jωτ).
    pub delay: f64,
}

impl Loop<'_> {
    /// Loop gain L = C·P·e^(−jωτ) at `f_hz`.
    pub fn gain(&self, f_hz: f64) -> Complex<f64> {
        let v = self.plant.frequency_variable(f_hz);
        let p = self.plant.response(self.law.output(), f_hz);
        let d = Complex::from_polar(1.0, -TAU * f_hz * self.delay);
        self.law.eval(v, self.plant.dt) * p * d
    }

    /// Closed loop T = L/(1 + L) at `f_hz`.
    pub fn closed(&self, f_hz: f64) -> Complex<f64> {
        let l = self.gain(f_hz);
        l / (Complex::new(1.0, 0.0) + l)
    }
}

/// Longest command delay (control periods) whose delay line [`Loop::closed_loop_poles`]
/// builds into the closed-loop matrix: the eigenvalues of a matrix of that order take about
/// a second.
pub const MAX_DELAY_PERIODS: usize = 500;

impl Loop<'_> {
    /// Poles (z-plane) of the closed sampled loop: the plant x⁺ = A·x + B·u_v, y = C·x; the
    /// law C(z) (`Law::discrete_coefficients`) in the first-order realisation
    /// x_c⁺ = −a₁·x_c + e, u = (b₁ − a₁·b₀)·x_c + b₀·e, on the error e = −y; and the command
    /// delay τ = (d + f)·T as a line of past commands, u_v = (1 − f)·u[k − d] + f·u[k − d − 1]
    /// (exact for whole periods, f = 0; a linear blend of the two neighbouring periods'
    /// commands otherwise, as the plant's delay line averages them over its substeps).
    /// These are the eigenvalues of the loop whose frequency response is [`Loop::gain`]:
    /// the roots of 1 + L(z) = 0, plus any plant mode the loop cannot see. None for a
    /// continuous plant or a delay longer than [`MAX_DELAY_PERIODS`].
    pub fn closed_loop_poles(&self) -> Option<Vec<Complex<f64>>> {
        let t = self.plant.dt?;
        let periods = self.delay / t;
        let whole = periods.floor();
        let f = periods - whole;
        let d = whole as usize;
        let m = if f > 1e-9 { d + 1 } else { d };
        if m > MAX_DELAY_PERIODS {
            return None;
        }
        let c = self.plant.c(self.law.output());
        let (b0, b1, a1) = self.law.discrete_coefficients(t);
        let n = self.plant.a.nrows();
        let (ic, iw) = (n, n + 1);
        let size = n + 1 + m;
        // The command u as a row over the state [x, x_c, u[k−1] … u[k−m]].
        let mut u_row = DVector::<f64>::zeros(size);
        for j in 0..n {
            u_row[j] = -b0 * c[j];
        }
        u_row[ic] = b1 - a1 * b0;
        // The delayed command u_v: u[k − i] is u itself for i = 0, state iw + i − 1 otherwise.
        let mut uv_row = DVector::<f64>::zeros(size);
        let mut add = |i: usize, w: f64| {
            if i == 0 {
                uv_row += &u_row * w;
            } else {
                uv_row[iw + i - 1] += w;
            }
        };
        add(d, 1.0 - f);
        if f > 1e-9 {
            add(d + 1, f);
        }
        let mut a = DMatrix::<f64>::zeros(size, size);
        for i in 0..n {
            for j in 0..n {
                a[(i, j)] = self.plant.a[(i, j)];
            }
            for j in 0..size {
                a[(i, j)] += self.plant.b[i] * uv_row[j];
            }
            a[(ic, i)] = -c[i];
        }
        a[(ic, ic)] = -a1;
        if m > 0 {
            a.row_mut(iw).copy_from(&u_row.transpose());
            for i in 1..m {
                a[(iw + i, iw + i - 1)] = 1.0;
            }
        }
        Some(a.complex_eigenvalues().iter().copied().collect())
    }
}

/// Stability margins and bandwidths of a loop.
#[derive(Debug, Clone, Serialize, Default)]
pub struct Margins {
    /// Gain crossover |L| = 1 (Hz).
    pub gain_crossover_hz: Option<f64>,
    /// Phase margin 180° + ∠L at the gain crossover (deg).
    pub phase_margin_deg: Option<f64>,
    /// Phase crossover ∠L = −180° (Hz).
    pub phase_crossover_hz: Option<f64>,
    /// Gain margin −20·log₁₀|L| at the phase crossover (dB).
    pub gain_margin_db: Option<f64>,
    /// −3 dB bandwidth of the closed loop relative to its low-frequency gain (Hz).
    pub closed_loop_bandwidth_hz: Option<f64>,
    /// Peak of |T| (dB).
    pub closed_loop_peak_db: f64,
}

/// Log-spaced frequency grid.
pub fn log_grid(f0: f64, f1: f64, n: usize) -> Vec<f64> {
    let r = (f1 / f0).ln();
    (0..n)
        .map(|i| f0 * (r * i as f64 / (n - 1).max(1) as f64).exp())
        .collect()
}

fn bisect(mut a: f64, mut b: f64, g: impl Fn(f64) -> f64) -> f64 {
    let ga = g(a);
    for _ in 0..60 {
        let m = (a * b).sqrt();
        if (g(m) > 0.0) == (ga > 0.0) {
            a = m;
        } else {
            b = m;
        }
    }
    (a * b).sqrt()
}

/// Unwrapped phase (rad) along a grid, starting in (−2π, 0] at the first point.
fn unwrapped_phase(vals: &[Complex<f64>]) -> Vec<f64> {
    let mut out = Vec::with_capacity(vals.len());
    let mut prev = 0.0;
    for (i, v) in vals.iter().enumerate() {
        let mut ph = v.arg();
        if i == 0 {
            if ph > 0.0 {
                ph -= TAU;
            }
        } else {
            while ph - prev > std::f64::consts::PI {
                ph -= TAU;
            }
            while ph - prev < -std::f64::consts::PI {
                ph += TAU;
            }
        }
        prev = ph;
        out.push(ph);
    }
    out
}

/// Margins of `lp` on [f0, f1] Hz (f1 at most the Nyquist frequency for a discrete loop).
pub fn margins(lp: &Loop<'_>, f0: f64, f1: f64) -> Margins {
    let f1 = match lp.plant.dt {
        Some(t) => f1.min(0.4999 / t),
        None => f1,
    };
    let grid = log_grid(f0, f1, 1200);
    let l: Vec<Complex<f64>> = grid.iter().map(|&f| lp.gain(f)).collect();
    let ph = unwrapped_phase(&l);
    let mut m = Margins::default();
    // Gain crossover: last downward crossing of |L| = 1.
    for i in (1..grid.len()).rev() {
        if l[i - 1].norm() >= 1.0 && l[i].norm() < 1.0 {
            let f = bisect(grid[i - 1], grid[i], |f| lp.gain(f).norm().ln());
            let lf = lp.gain(f);
            // Phase at f consistent with the unwrapped branch of the grid.
            let mut p = lf.arg();
            while p - ph[i] > std::f64::consts::PI {
                p -= TAU;
            }
            while p - ph[i] < -std::f64::consts::PI {
                p += TAU;
            }
            m.gain_crossover_hz = Some(f);
            m.phase_margin_deg = Some(180.0 + p.to_degrees());
            break;
        }
    }
    // Phase crossover: first crossing of −180° (mod 360°) above the gain crossover region.
    for i in 1..grid.len() {
        let k0 = ((ph[i - 1] + std::f64::consts::PI) / TAU).floor();
        let k1 = ((ph[i] + std::f64::consts::PI) / TAU).floor();
        if k1 < k0 {
            let target = k0 * TAU - std::f64::consts::PI;
            let (a, b) = (grid[i - 1], grid[i]);
            let (pa, pb) = (ph[i - 1], ph[i]);
            // Linear interpolation in log f, refined by bisection on the wrapped phase.
            let f = bisect(a, b, |f| {
                let mut p = lp.gain(f).arg();
                let mid = 0.5 * (pa + pb);
                while p - mid > std::f64::consts::PI {
                    p -= TAU;
                }
                while p - mid < -std::f64::consts::PI {
                    p += TAU;
                }
                p - target
            });
            m.phase_crossover_hz = Some(f);
            m.gain_margin_db = Some(-20.0 * lp.gain(f).norm().log10());
            break;
        }
    }
    let t0 = lp.closed(f0).norm();
    let mut peak: f64 = 0.0;
    for (i, &f) in grid.iter().enumerate() {
        let t = lp.closed(f).norm();
        peak = peak.max(t / t0);
        if m.closed_loop_bandwidth_hz.is_none() && i > 0 && t < t0 / 2f64.sqrt() {
            let fb = bisect(grid[i - 1], f, |f| lp.closed(f).norm() - t0 / 2f64.sqrt());
            m.closed_loop_bandwidth_hz = Some(fb);
        }
    }
    m.closed_loop_peak_db = 20.0 * peak.log10();
    m
}

/// Margins of a loop known only on a frequency grid (a measured response, or a model
/// sampled for tuning), in the definitions of the Python tuner (`ehactl.tune`), which
/// calls this: phase unwrapped along the grid (numpy's `unwrap` rule) and shifted so that
/// it starts at or below +90°; crossings interpolated linearly in ln f; NaN where no
/// crossing lies in the grid or a needed point is NaN (NaN propagates as in numpy).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SampledMargins {
    /// First downward crossing of |L| = 1 (Hz).
    pub crossover_hz: f64,
    /// 180° + ∠L at that crossover (deg).
    pub phase_margin_deg: f64,
    /// First downward crossing of ∠L = −180° (Hz).
    pub phase_crossover_hz: f64,
    /// −20·log₁₀|L| there (dB).
    pub gain_margin_db: f64,
    /// First downward crossing of |L/(1+L)| = −3 dB (absolute, not relative) (Hz).
    pub bandwidth_hz: f64,
    /// Largest |L/(1+L)| on the grid (dB).
    pub peak_closed_db: f64,
}

/// Positions (in ln f) where `a − level` goes from > 0 to ≤ 0 between grid points.
fn downward_crossings<'a>(
    lf: &'a [f64],
    a: &'a [f64],
    level: f64,
) -> impl Iterator<Item = f64> + 'a {
    (0..a.len().saturating_sub(1)).filter_map(move |i| {
        let (y0, y1) = (a[i] - level, a[i + 1] - level);
        (y0 > 0.0 && 0.0 >= y1).then(|| lf[i] + (lf[i + 1] - lf[i]) * y0 / (y0 - y1))
    })
}

/// Linear interpolation of (xp, fp) at x inside the grid (xp increasing), like `numpy.interp`.
fn interp(x: f64, xp: &[f64], fp: &[f64]) -> f64 {
    let j = xp.partition_point(|&v| v <= x).clamp(1, xp.len() - 1);
    let (x0, x1) = (xp[j - 1], xp[j]);
    if x == x1 {
        return fp[j];
    }
    fp[j - 1] + (fp[j] - fp[j - 1]) * (x - x0) / (x1 - x0)
}

/// Phase (rad) unwrapped along the grid by numpy's rule: each step is brought into
/// [−π, π) (+π kept for a positive step of exactly π) when its size is at least π.
fn numpy_unwrap(p: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(p.len());
    let mut corr = 0.0;
    for (i, &v) in p.iter().enumerate() {
        if i > 0 {
            let d = v - p[i - 1];
            let mut dd = (d + std::f64::consts::PI).rem_euclid(TAU) - std::f64::consts::PI;
            if dd == -std::f64::consts::PI && d > 0.0 {
                dd = std::f64::consts::PI;
            }
            if d.abs() >= std::f64::consts::PI {
                corr += dd - d;
            } else if d.is_nan() {
                corr = f64::NAN;
            }
        }
        out.push(v + corr);
    }
    out
}

/// [`SampledMargins`] of L sampled at `f` (Hz, increasing, > 0). `f` and `l` have one
/// entry per frequency; fewer than two points give NaN everywhere.
pub fn sampled_margins(f: &[f64], l: &[Complex<f64>]) -> SampledMargins {
    let nan = SampledMargins {
        crossover_hz: f64::NAN,
        phase_margin_deg: f64::NAN,
        phase_crossover_hz: f64::NAN,
        gain_margin_db: f64::NAN,
        bandwidth_hz: f64::NAN,
        peak_closed_db: f64::NAN,
    };
    let n = f.len().min(l.len());
    if n < 2 {
        return nan;
    }
    let (f, l) = (&f[..n], &l[..n]);
    let lf: Vec<f64> = f.iter().map(|x| x.ln()).collect();
    let mag_db: Vec<f64> = l.iter().map(|v| 20.0 * v.norm().log10()).collect();
    let arg: Vec<f64> = l.iter().map(|v| v.arg()).collect();
    let mut ph: Vec<f64> = numpy_unwrap(&arg).iter().map(|p| p.to_degrees()).collect();
    if ph[0] > 90.0 {
        let shift = 360.0 * ((ph[0] - 90.0) / 360.0).ceil();
        ph.iter_mut().for_each(|p| *p -= shift);
    }
    let mut m = nan;
    if let Some(x) = downward_crossings(&lf, &mag_db, 0.0).next() {
        m.crossover_hz = x.exp();
        m.phase_margin_deg = 180.0 + interp(x, &lf, &ph);
    }
    if let Some(x) = downward_crossings(&lf, &ph, -180.0).next() {
        m.phase_crossover_hz = x.exp();
        m.gain_margin_db = -interp(x, &lf, &mag_db);
    }
    let one = Complex::new(1.0, 0.0);
    let tdb: Vec<f64> = l
        .iter()
        .map(|&v| 20.0 * (v / (one + v)).norm().log10())
        .collect();
    if let Some(x) = downward_crossings(&lf, &tdb, -3.0).next() {
        m.bandwidth_hz = x.exp();
    }
    m.peak_closed_db = if tdb.iter().any(|t| t.is_nan()) {
        f64::NAN
    } else {
        tdb.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
    };
    m
}

/// −3 dB bandwidth of a plant with a finite static gain (Hz); None for an integrating plant
/// (its gain still rising 20 dB/decade towards f0) or when |P| never falls 3 dB below it.
pub fn open_loop_bandwidth(p: &LinearModel, out: Output, f0: f64, f1: f64) -> Option<f64> {
    let g0 = p.response(out, f0).norm();
    let g0b = p.response(out, 2.0 * f0).norm();
    if g0 / g0b > 1.8 {
        return None;
    }
    let grid = log_grid(f0, f1, 800);
    for i in 1..grid.len() {
        if p.response(out, grid[i]).norm() < g0 / 2f64.sqrt() {
            return Some(bisect(grid[i - 1], grid[i], |f| {
                p.response(out, f).norm() - g0 / 2f64.sqrt()
            }));
        }
    }
    None
}
