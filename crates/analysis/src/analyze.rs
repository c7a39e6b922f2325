//! `ehactl analyze`: the configured rig and loop linearised around their operating point.

use crate::linear::{self, LinearModel, Output};
use crate::loopshape::{log_grid, margins, open_loop_bandwidth, Law, Loop, Margins};
use crate::oppoint;
use crate::sdd::{self, SddRatios};
use crate::AnalysisError;
use ehactl_config::RigConfig;
use ehactl_plant::effects::time_delay;
use ehactl_plant::Plant;
use serde::Serialize;
use serde_json::{json, Value};
use std::f64::consts::TAU;

/// A pole of the continuous linear model.
#[derive(Debug, Clone, Serialize)]
pub struct Pole {
    /// Natural frequency |λ|/2π (Hz).
    pub frequency_hz: f64,
    /// Damping ratio −Re λ/|λ| (-).
    pub damping_ratio: f64,
}

/// One frequency of the sampled loop: loop gain L and closed loop T = L/(1 + L).
#[derive(Debug, Clone, Serialize)]
pub struct LoopPoint {
    /// Frequency (Hz).
    pub f_hz: f64,
    /// |L| (dB).
    pub loop_mag_db: f64,
    /// ∠L (deg, wrapped to (−360°, 0°]).
    pub loop_phase_deg: f64,
    /// |T| (dB).
    pub closed_mag_db: f64,
    /// ∠T (deg, wrapped to (−360°, 0°]).
    pub closed_phase_deg: f64,
}

/// A pole of the closed sampled loop outside or on the unit circle.
#[derive(Debug, Clone, Serialize)]
pub struct UnstablePole {
    /// |z| (-): how much an oscillation at this pole grows per control period.
    pub magnitude: f64,
    /// |arg z|/(2π·T) (Hz): its frequency (0 for a real pole, the Nyquist frequency for a
    /// negative one).
    pub frequency_hz: f64,
    /// Re z (-).
    pub re: f64,
    /// Im z (-), ≥ 0 (each complex pair is listed once).
    pub im: f64,
}

/// The stability verdict of the linearised sampled loop.
#[derive(Debug, Clone, Serialize)]
pub struct Stability {
    /// No closed-loop pole outside the unit circle (beyond [`ON_THE_CIRCLE`]).
    pub stable: bool,
    /// Largest |z| of the closed-loop poles (-).
    pub max_pole_magnitude: f64,
    /// The poles with |z| ≥ 1 + [`ON_THE_CIRCLE`], largest first.
    pub unstable_poles: Vec<UnstablePole>,
    /// The poles within [`ON_THE_CIRCLE`] of the unit circle.
    pub marginal_poles: Vec<UnstablePole>,
}

/// How close to the unit circle (in |z|) a closed-loop pole counts as on it (-): the
/// linearisation is a central difference of the plant's step map, whose rounding moves a
/// pole that lies on the circle (an integrator the loop does not act on at its operating
/// point, e.g. a piston whose valve rests in its dead band) by about 1e-9 either way.
pub const ON_THE_CIRCLE: f64 = 1e-6;

impl Stability {
    /// The verdict on the closed-loop poles `poles` (z-plane) of a loop sampled at `dt` (s):
    /// unstable when any has |z| ≥ 1 (Franklin, Powell & Workman, "Digital Control of
    /// Dynamic Systems", 3rd ed., 1998, §4.3: a discrete system is stable iff every pole lies
    /// inside the unit circle), up to the linearisation's rounding ([`ON_THE_CIRCLE`]): the
    /// poles within it are listed as marginal.
    pub fn of_poles(poles: &[nalgebra::Complex<f64>], dt: f64) -> Self {
        let listed = |keep: &dyn Fn(f64) -> bool| {
            let mut v: Vec<UnstablePole> = poles
                .iter()
                .filter(|z| keep(z.norm()) && z.im >= 0.0)
                .map(|z| UnstablePole {
                    magnitude: z.norm(),
                    frequency_hz: z.arg().abs() / (TAU * dt),
                    re: z.re,
                    im: z.im,
                })
                .collect();
            v.sort_by(|a, b| b.magnitude.total_cmp(&a.magnitude));
            v
        };
        let unstable_poles = listed(&|m| m >= 1.0 + ON_THE_CIRCLE);
        Stability {
            stable: unstable_poles.is_empty(),
            max_pole_magnitude: poles.iter().map(|z| z.norm()).fold(0.0, f64::max),
            unstable_poles,
            marginal_poles: listed(&|m| (m - 1.0).abs() < ON_THE_CIRCLE),
        }
    }
}

/// Everything `ehactl analyze` reports.
#[derive(Debug, Clone, Serialize)]
pub struct Analysis {
    /// Rig name.
    pub rig: String,
    /// Operating point: reference, feedback, valve command, position, pressures.
    pub operating_point: Value,
    /// √(K_h/m)/2π at the operating position (Hz), K_h = β·(A_A²/V_A + A_B²/V_B), m the
    /// piston mass plus a flexibly mounted load taken as rigidly connected.
    pub hydraulic_natural_frequency_hz: f64,
    /// Lowest of the above over the stroke (Hz) and where (m).
    pub min_natural_frequency_over_stroke_hz: f64,
    /// Position of the lowest natural frequency (m).
    pub min_natural_frequency_position_m: f64,
    /// −3 dB bandwidth of the plant (command → controlled output) when it has a static gain (Hz).
    pub open_loop_bandwidth_hz: Option<f64>,
    /// Margins of the sampled loop (zero-order hold at the control rate, discrete law).
    pub discrete: Option<Margins>,
    /// Margins of the continuous-time loop (ideal PI/PD, no sampling), as the papers compute.
    pub continuous: Option<Margins>,
    /// Stability of the linearised sampled loop from its closed-loop poles (None in open
    /// loop, or with a command delay longer than `loopshape::MAX_DELAY_PERIODS` periods).
    /// An unstable loop has no closed-loop bandwidth or peak: both are left out of the
    /// margins (they describe a steady response that an unstable loop never reaches).
    pub stability: Option<Stability>,
    /// Command delay included as e^(−jωτ) (s).
    pub delay_s: f64,
    /// Dindorf 2022 SDD ratios, with a flexible mount.
    pub sdd: Option<SddRatios>,
    /// Slowest poles of the continuous plant model.
    pub poles: Vec<Pole>,
    /// Sampled-loop frequency response on a log grid (empty in open loop).
    pub loop_response: Vec<LoopPoint>,
    /// Control rate (Hz).
    pub control_rate_hz: f64,
}

/// Natural frequency √(K_h(x)/m)/2π (Hz) of `plant` at `x`, with `mass` (kg).
pub fn natural_frequency(plant: &Plant, x: f64, mass: f64) -> f64 {
    (plant.hydraulic_stiffness(x) / mass).sqrt() / TAU
}

fn rigid_mass(plant: &Plant) -> f64 {
    let p = plant.params();
    p.mechanics.mass
        + p.effects
            .flexible_mount
            .as_ref()
            .filter(|m| m.enabled)
            .map_or(0.0, |m| m.load_mass)
}

/// Lowest natural frequency over the stroke (Hz) and its position (m), scanning 2001 points.
pub fn min_over_stroke(plant: &Plant) -> (f64, f64) {
    let stroke = plant.params().cylinder.stroke;
    let m = rigid_mass(plant);
    (0..=2000)
        .map(|i| {
            let x = stroke * i as f64 / 2000.0;
            (natural_frequency(plant, x, m), x)
        })
        .fold((f64::INFINITY, 0.0), |a, b| if b.0 < a.0 { b } else { a })
}

fn slow_poles(m: &LinearModel) -> Vec<Pole> {
    let mut poles: Vec<Pole> = m
        .eigenvalues()
        .into_iter()
        .filter(|l| l.im >= 0.0 && l.norm() > 1e-9)
        .map(|l| Pole {
            frequency_hz: l.norm() / TAU,
            damping_ratio: -l.re / l.norm(),
        })
        .filter(|p| p.frequency_hz < 1e5)
        .collect();
    poles.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
    poles.truncate(12);
    poles
}

/// The stability verdict of `cfg`'s linearised sampled loop alone (what `ehactl run` checks
/// before it starts): the operating point, the discrete linearisation and the closed-loop
/// poles, without the margins. None in open loop or with a delay too long to build in.
pub fn stability(cfg: &RigConfig) -> Result<Option<Stability>, AnalysisError> {
    let Some(law) = Law::from_config(cfg) else {
        return Ok(None);
    };
    let op = oppoint::find(cfg, 5.0)?;
    let dmodel = linear::discrete(&op)?;
    let lp = Loop {
        plant: &dmodel,
        law,
        delay: time_delay::delay(cfg.plant.effects.time_delay.as_ref()),
    };
    let dt = cfg.timebase().period();
    Ok(lp.closed_loop_poles().map(|p| Stability::of_poles(&p, dt)))
}

/// `m` without its closed-loop bandwidth and peak (NaN), for an unstable loop.
fn without_bandwidth(m: Margins) -> Margins {
    Margins {
        closed_loop_bandwidth_hz: None,
        closed_loop_peak_db: f64::NAN,
        ..m
    }
}

/// Linearise and analyse `cfg`.
pub fn analyze(cfg: &RigConfig) -> Result<Analysis, AnalysisError> {
    let op = oppoint::find(cfg, 5.0)?;
    let plant = &op.plant;
    let s = *plant.state();
    let m_rigid = rigid_mass(plant);
    let (fmin, xmin) = min_over_stroke(plant);
    let dt = cfg.timebase().period();
    let nyquist = 0.5 / dt;
    let dmodel = linear::discrete(&op)?;
    let cmodel = linear::continuous(&op, 1e-7)?;
    let delay = time_delay::delay(cfg.plant.effects.time_delay.as_ref());
    let law = Law::from_config(cfg);
    let out = law.map_or_else(
        || {
            if cfg.plant.mechanics.load_stiffness > 0.0 {
                Output::Force
            } else {
                Output::Position
            }
        },
        |l| l.output(),
    );
    let f_lo = 0.1;
    let mut loop_response = Vec::new();
    let mut stability = None;
    let (discrete, continuous) = match law {
        Some(law) => {
            let ld = Loop {
                plant: &dmodel,
                law,
                delay,
            };
            let lc = Loop {
                plant: &cmodel,
                law,
                delay,
            };
            let wrap = |d: f64| if d > 0.0 { d - 360.0 } else { d };
            loop_response = log_grid(1.0, 0.999 * nyquist, 200)
                .into_iter()
                .map(|f| {
                    let l = ld.gain(f);
                    let t = ld.closed(f);
                    LoopPoint {
                        f_hz: f,
                        loop_mag_db: 20.0 * l.norm().log10(),
                        loop_phase_deg: wrap(l.arg().to_degrees()),
                        closed_mag_db: 20.0 * t.norm().log10(),
                        closed_phase_deg: wrap(t.arg().to_degrees()),
                    }
                })
                .collect();
            stability = ld.closed_loop_poles().map(|p| Stability::of_poles(&p, dt));
            (
                Some(margins(&ld, f_lo, nyquist)),
                Some(margins(&lc, f_lo, 10.0 * nyquist)),
            )
        }
        None => (None, None),
    };
    let (discrete, continuous) = if stability.as_ref().is_some_and(|s| !s.stable) {
        (
            discrete.map(without_bandwidth),
            continuous.map(without_bandwidth),
        )
    } else {
        (discrete, continuous)
    };
    Ok(Analysis {
        rig: cfg.rig.name.clone(),
        operating_point: json!({
            "reference": op.reference,
            "feedback": op.feedback,
            "command_V": op.u0,
            "position_m": s.x,
            "p_a_Pa": s.p_a,
            "p_b_Pa": s.p_b,
            "rod_force_N": s.rod_force,
            "settled": op.settled,
            "search_time_s": op.time_s,
        }),
        hydraulic_natural_frequency_hz: natural_frequency(plant, s.x, m_rigid),
        min_natural_frequency_over_stroke_hz: fmin,
        min_natural_frequency_position_m: xmin,
        open_loop_bandwidth_hz: open_loop_bandwidth(&dmodel, out, f_lo, nyquist),
        discrete,
        continuous,
        stability,
        delay_s: delay,
        sdd: sdd::ratios(plant, s.x, sdd::excitation_frequency(&cfg.plant)),
        loop_response,
        poles: slow_poles(&cmodel),
        control_rate_hz: cfg.run.control_rate_hz,
    })
}

/// Why an unstable loop's analysis gives no closed-loop bandwidth or peak.
pub const UNSTABLE_BANDWIDTH_NOTE: &str =
    "left out: the closed loop is unstable, so its bandwidth and peak are meaningless";

impl Analysis {
    /// The `ehactl analyze --json` object: the flat keys (those that apply) plus the
    /// details.
    pub fn to_json(&self) -> Value {
        let mut o = json!({
            "rig": self.rig,
            "hydraulic_natural_frequency_hz": self.hydraulic_natural_frequency_hz,
            "min_natural_frequency_over_stroke_hz": self.min_natural_frequency_over_stroke_hz,
            "min_natural_frequency_position_m": self.min_natural_frequency_position_m,
            "operating_point": self.operating_point,
            "control_rate_hz": self.control_rate_hz,
            "delay_s": self.delay_s,
            "poles": self.poles,
            "loop_response": self.loop_response,
        });
        if let Some(b) = self.open_loop_bandwidth_hz {
            o["open_loop_bandwidth_hz"] = json!(b);
        }
        if let Some(d) = &self.discrete {
            o["sampled_loop"] = json!(true);
            o["loop_model"] = json!(format!(
                "discrete-time: plant step map linearised over one {:.1} µs control period with the command held (zero-order hold), discrete control law",
                1e6 / self.control_rate_hz
            ));
            for (k, v) in [
                ("gain_crossover_hz", d.gain_crossover_hz),
                ("phase_margin_deg", d.phase_margin_deg),
                ("phase_crossover_hz", d.phase_crossover_hz),
                ("gain_margin_db", d.gain_margin_db),
                ("closed_loop_bandwidth_hz", d.closed_loop_bandwidth_hz),
            ] {
                if let Some(v) = v {
                    o[k] = json!(v);
                }
            }
            o["closed_loop_peak_db"] = json!(d.closed_loop_peak_db);
        } else {
            o["sampled_loop"] = json!(false);
            o["loop_model"] = json!("open loop: no control law configured");
        }
        if let Some(st) = &self.stability {
            o["stable"] = json!(st.stable);
            o["max_closed_loop_pole_magnitude"] = json!(st.max_pole_magnitude);
            o["unstable_poles"] = serde_json::to_value(&st.unstable_poles).unwrap_or(Value::Null);
            o["marginal_poles"] = serde_json::to_value(&st.marginal_poles).unwrap_or(Value::Null);
            if !st.stable {
                o["closed_loop_bandwidth_note"] = json!(UNSTABLE_BANDWIDTH_NOTE);
            }
        }
        if let Some(c) = &self.continuous {
            o["continuous"] = serde_json::to_value(c).unwrap_or(Value::Null);
        }
        if let Some(s) = &self.sdd {
            o["fr_ym"] = json!(s.fr_ym);
            if let Some(v) = s.fr_em {
                o["fr_em"] = json!(v);
            }
            o["rd_my"] = json!(s.rd_my);
            o["sdd"] = serde_json::to_value(s).unwrap_or(Value::Null);
        }
        o
    }
}
