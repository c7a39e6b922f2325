//! Replay of a record through the plant, and error measures. Every replay steps `ehactl
//! run`'s cycle kernel (`ehactl_control::cycle::step`) fed by a recorded-reference source
//! (`ehactl_control::cycle::Recorded`): the recorded valve command `u` through the open-loop
//! law, or the recorded setpoint `ref` through the rig's PD or PI ([`Drive`]), so the
//! diagnosis, `predict` and `run` step the same cycle.

use crate::data::{ChannelKind, Record};
use ehactl_control::controller::Controller;
use ehactl_control::cycle::{self, CycleInput, Recorded};
use ehactl_control::pd::Pd;
use ehactl_control::pi::Pi;
use ehactl_control::supervisor::{Supervisor, SupervisorConfig};
use ehactl_plant::{NumericalFailure, Plant, PlantParams};

/// Simulated outputs of one replay: `y[c][k]` for the record's channels in order.
#[derive(Debug, Clone)]
pub struct Replay {
    /// Predicted channels, same order and length as the record's (up to `n`).
    pub y: Vec<Vec<f64>>,
    /// Piston velocity of the model (m/s), for residual analysis.
    pub v: Vec<f64>,
    /// Load pressure p_a − p_b of the model (Pa), for the grey-box law's report.
    pub dp: Vec<f64>,
    /// Whether the integration failed (outputs after failure are held).
    pub failed: bool,
    /// Where it failed: the sample k whose step failed and the plant's failure (the state
    /// variable, its value and the bound it crossed).
    pub failed_at: Option<(usize, NumericalFailure)>,
    /// Sensor offsets already added to `y`, per channel in the channel's SI unit (zero
    /// unless [`apply_offsets`] was called).
    pub offsets: Vec<f64>,
}

/// Parameters as used for replay: sensor noise off (the data carry their own), initial
/// position and pressures from the first samples of the record (the first sample; the median
/// of up to 10 on a sensor the config declares noisy).
pub fn replay_params(nominal: &PlantParams, rec: &Record) -> PlantParams {
    replay_params_zeroed(nominal, rec, &[])
}

/// [`replay_params`] with the initial position and pressures taken from the first samples
/// less the channels' sensor offsets `b` (per record channel, SI; missing = 0): a zero error
/// of the position transducer must not preload the model's spring, nor one of a pressure
/// transducer start the model off its equilibrium.
pub fn replay_params_zeroed(nominal: &PlantParams, rec: &Record, b: &[f64]) -> PlantParams {
    let offset = |kind: ChannelKind| {
        rec.channels
            .iter()
            .position(|c| c.kind == kind)
            .and_then(|i| b.get(i).copied())
            .unwrap_or(0.0)
    };
    let mut p = nominal.clone();
    p.sensors.force.noise = 0.0;
    p.sensors.pressure.noise = 0.0;
    p.sensors.position.noise = 0.0;
    p.sensors.spool.noise = 0.0;
    // Initial value of a channel: its first sample, the measurement of the state at t = 0
    // (sample 0 is taken before the first command, as `ehactl run` logs it); the median of up
    // to 10 first samples only where the config declares the sensor noisy (σ > 0), since the
    // median of a moving start (a step, a transient) sets the replay off the rig's state.
    let head = |v: &[f64], noisy: bool| {
        if !noisy {
            return v[0];
        }
        let mut h: Vec<f64> = v[..v.len().min(10)].to_vec();
        h.sort_by(f64::total_cmp);
        h[h.len() / 2]
    };
    let (x_noisy, p_noisy) = (
        nominal.sensors.position.noise > 0.0,
        nominal.sensors.pressure.noise > 0.0,
    );
    if let Some(x) = rec.channel(ChannelKind::Position) {
        p.cylinder.initial_position =
            (head(x, x_noisy) - offset(ChannelKind::Position)).clamp(0.0, p.cylinder.stroke);
    }
    if let Some(pa) = rec.channel(ChannelKind::PressureA) {
        p.cylinder.initial_pressure_a = Some(head(pa, p_noisy) - offset(ChannelKind::PressureA));
    }
    if let Some(pb) = rec.channel(ChannelKind::PressureB) {
        p.cylinder.initial_pressure_b = Some(head(pb, p_noisy) - offset(ChannelKind::PressureB));
    }
    p
}

/// How the valve command is produced during a replay.
#[derive(Debug, Clone, Copy, Default)]
pub enum Drive {
    /// Open loop: the recorded command `u` (V).
    #[default]
    Recorded,
    /// Closed loop: the rig's PD position controller (the config's `[control.pd]`) acting on
    /// the recorded setpoint `ref` (m) and the model's own position, for integrating plants
    /// whose open-loop replay would drift.
    PositionPd(ehactl_control::pd::PdGains),
    /// Closed loop: the rig's PI force controller (the config's `[control.pi]`, the same
    /// `ehactl_control::pi::Pi` that `ehactl run` steps, anti-windup and output limits
    /// included) acting on the recorded force setpoint `ref` (N) and the model's own measured
    /// force, followed by the supervisor's command limit `max_command` (V, `f64::INFINITY`
    /// when the config sets none), as in `ehactl run`'s cycle. A force rig pressing on a stiff
    /// load is near-integrating from the valve command: an open-loop replay from `u` amplifies
    /// every model error into a drift.
    ForcePi {
        /// The config's PI gains and limits.
        gains: ehactl_control::pi::PiGains,
        /// `supervisor.max_command` (V), `f64::INFINITY` when unset.
        max_command: f64,
    },
}

impl Drive {
    /// The law and the supervisor of `ehactl run`'s cycle kernel (`ehactl_control::cycle`)
    /// for this drive: the rig's PD or PI on the recorded setpoint, or open loop (the law
    /// passes the recorded command `u` through); the supervisor holds the command limit
    /// (`max_command`, V) alone, no trip limits or watches (the plant's own check ends a
    /// diverging replay).
    fn kernel(&self) -> (Controller, Supervisor) {
        let (law, max_command) = match *self {
            Drive::PositionPd(g) => (Controller::Position(Pd::new(g)), None),
            Drive::ForcePi { gains, max_command } => (
                Controller::Force(Pi::new(gains)),
                max_command.is_finite().then_some(max_command),
            ),
            Drive::Recorded => (Controller::OpenLoop, None),
        };
        let cfg = SupervisorConfig {
            max_command,
            ..SupervisorConfig::default()
        };
        let supervisor = Supervisor::new(&cfg, law.feedback_channel());
        (law, supervisor)
    }

    /// Whether the replay closes the rig's loop on the recorded setpoint `ref`.
    pub fn closed_loop(&self) -> bool {
        !matches!(self, Drive::Recorded)
    }

    /// One line for the report: how the valve command is produced.
    pub fn describe(&self) -> String {
        match self {
            Drive::Recorded => "open-loop replay of the recorded valve command `u`".to_string(),
            Drive::PositionPd(g) => format!(
                "closed-loop replay: the rig's PD position loop (k_p = {} V/m, T_D = {} s) on the recorded `ref`",
                g.kp, g.td
            ),
            Drive::ForcePi { gains: g, .. } => format!(
                "closed-loop replay: the rig's PI force loop (K_P = {} V/V, I = {} 1/s, error scale {} V/N, output {}…{} V) on the recorded force setpoint `ref`",
                g.kp, g.integral, g.error_scale, g.u_min, g.u_max
            ),
        }
    }
}

/// Replay the first `n` samples of `rec` through a plant with `params` at the record's
/// sample period, open loop. Sample k of the output is measured before command u_k is
/// applied (the order of `ehactl run`'s loop: read, compute, write).
pub fn replay(params: &PlantParams, rec: &Record, n: usize) -> Result<Replay, String> {
    replay_with(params, rec, n, Drive::Recorded)
}

/// Replay with the given [`Drive`] (see [`replay`]).
pub fn replay_with(
    params: &PlantParams,
    rec: &Record,
    n: usize,
    drive: Drive,
) -> Result<Replay, String> {
    replay_guarded(params, rec, n, drive, 0)
}

/// [`replay_with`] whose fixed substeps are raised, up to `max_substeps`, where the
/// parameters step the fastest mode beyond ω·h = [`REPLAY_MAX_OMEGA_H`]
/// ([`configure_stable`]): how a diagnosis replays its candidates after the integration
/// choice took fewer substeps than the config's (`max_substeps`: the config's count, so a
/// candidate never costs more than the config's own step; 0 = no guard).
pub fn replay_guarded(
    params: &PlantParams,
    rec: &Record,
    n: usize,
    drive: Drive,
    max_substeps: u32,
) -> Result<Replay, String> {
    let n = n.min(rec.len());
    let mut y: Vec<Vec<f64>> = rec.channels.iter().map(|_| Vec::with_capacity(n)).collect();
    let mut v = Vec::with_capacity(n);
    let mut dp = Vec::with_capacity(n);
    let failed_at = run(params, rec, n, drive, max_substeps, |_, out, vk, dpk| {
        for (yc, o) in y.iter_mut().zip(out) {
            yc.push(*o);
        }
        v.push(vk);
        dp.push(dpk);
        true
    })?;
    let offsets = vec![0.0; y.len()];
    Ok(Replay {
        y,
        v,
        dp,
        failed: failed_at.is_some(),
        failed_at,
        offsets,
    })
}

/// The fit cost of a replay of the first `n` samples, computed as the replay runs: the mean
/// over the used channels (all, or `channel` only) of Σ(measured − model)²/n / `sd`², plus
/// 10³ when the integration failed — exactly the value the same sums over a
/// [`replay_guarded`] give. The replay stops as soon as that cost can no longer fall below
/// `bound` (each channel's sum only grows), and then returns a value ≥ `bound`: a
/// Nelder–Mead step that only needs to know whether a point is better than its worst vertex
/// does not pay for the rest of a record it already lost on
/// ([`crate::fit::nelder_mead`]; `f64::INFINITY`: the whole record).
#[allow(clippy::too_many_arguments)]
pub fn replay_cost(
    params: &PlantParams,
    rec: &Record,
    n: usize,
    drive: Drive,
    max_substeps: u32,
    sd: &[f64],
    channel: Option<usize>,
    bound: f64,
) -> Result<f64, String> {
    let n = n.min(rec.len());
    let mut sums = vec![0.0; rec.channels.len()];
    // The cost of the sums so far: a monotone lower bound of the whole replay's and, at the
    // end, equal to it.
    let cost = |sums: &[f64], failed: bool| fit_cost(sums, n, sd, channel, failed);
    let mut lost = None;
    let failed = run(params, rec, n, drive, max_substeps, |k, out, _, _| {
        for ((s, o), ch) in sums.iter_mut().zip(out).zip(&rec.channels) {
            let e = ch.values[k] - o;
            *s += e * e;
        }
        // Checked every 32 samples: the cost of the check stays below 1 % of the replay's.
        if k % 32 == 31 && bound.is_finite() {
            let j = cost(&sums, false);
            if j >= bound {
                lost = Some(j);
                return false;
            }
        }
        true
    })?;
    Ok(lost.unwrap_or_else(|| cost(&sums, failed.is_some())))
}

/// The fit cost from the per-channel sums of squared residuals `sums` over `n` samples: the
/// mean over the used channels (all, or `channel` only) of sum/n / `sd`², plus 10³ when the
/// integration `failed` (the one definition [`replay_cost`] and a fit with sensor offsets
/// share).
pub(crate) fn fit_cost(
    sums: &[f64],
    n: usize,
    sd: &[f64],
    channel: Option<usize>,
    failed: bool,
) -> f64 {
    let mut j = 0.0;
    let mut used = 0;
    for (c, s) in sums.iter().enumerate() {
        if channel.is_some_and(|k| k != c) {
            continue;
        }
        used += 1;
        j += s / n as f64 / (sd[c] * sd[c]).max(1e-300);
    }
    let j = j / used.max(1) as f64;
    if failed {
        j + 1e3
    } else {
        j
    }
}

/// The replay loop: for each sample k < `n` the record channels' measured outputs (taken
/// before command u_k is applied, the order of `ehactl run`'s loop: read, compute, write; set
/// to 0 where non-finite once the integration failed), the model's velocity (m/s) and load
/// pressure p_a − p_b (Pa) go to `sample`, which returns `false` to stop. Returns where the
/// integration failed, if it did (the sample and the state variable; the state is then held).
fn run(
    params: &PlantParams,
    rec: &Record,
    n: usize,
    drive: Drive,
    max_substeps: u32,
    mut sample: impl FnMut(usize, &[f64], f64, f64) -> bool,
) -> Result<Option<(usize, NumericalFailure)>, String> {
    if drive.closed_loop() && rec.reference.is_none() {
        return Err(format!(
            "{}: closed-loop replay needs a `ref` column",
            rec.source
        ));
    }
    let (mut law, mut supervisor) = drive.kernel();
    // The recorded-reference source the kernel samples: the setpoint `ref` in closed loop,
    // the valve command `u` (V) in open loop.
    let column = match &rec.reference {
        Some(r) if drive.closed_loop() => r.as_slice(),
        _ => rec.u.as_slice(),
    };
    let source = Recorded::new(column);
    let t_start = std::time::Instant::now();
    let mut plant = configure_stable(params, rec.dt, max_substeps)?;
    let t_configured = std::time::Instant::now();
    let n = n.min(rec.len());
    let kinds: Vec<ChannelKind> = rec.channels.iter().map(|c| c.kind).collect();
    let mut out = vec![0.0; kinds.len()];
    let mut failed: Option<(usize, NumericalFailure)> = None;
    let mut samples = 0;
    for k in 0..n {
        let m = plant.measure();
        for (o, kind) in out.iter_mut().zip(&kinds) {
            *o = kind.pick(&m);
        }
        let (v, dp) = (plant.state().v, plant.state().p_a - plant.state().p_b);
        // `ehactl run`'s cycle kernel: the law on the measured feedback (the record has no
        // setpoint rate), then the supervisor's command limit.
        let input = CycleInput {
            k: k as u64,
            t: k as f64 * rec.dt,
            dt: rec.dt,
            meas: m,
        };
        let u = cycle::step(&mut law, &mut supervisor, &source, &input).u;
        if failed.is_none() {
            if let Err(e) = plant.step(u) {
                failed = Some((k, e));
            }
        }
        if failed.is_some() {
            // Keep the last good outputs; the fit sees a large error, never a NaN.
            for o in out.iter_mut() {
                if !o.is_finite() {
                    *o = 0.0;
                }
            }
        }
        samples = k + 1;
        if !sample(k, &out, v, dp) {
            break;
        }
    }
    STATS.add(
        samples,
        &plant,
        t_configured - t_start,
        t_configured.elapsed(),
    );
    Ok(failed)
}

/// Largest ω·h a replay steps its fastest mode at (-): half the stability limit ω·h < 2 of
/// the plant's explicit (symplectic Euler) mechanics ([`Plant::fastest_mode`]). A replay with
/// fixed substeps whose parameters put the fastest mode above it (a fit that stiffens a mount
/// or the oil column after the integration choice took fewer substeps than the config's)
/// takes, for that replay alone, the substeps that bring it back to this value, at most the
/// config's own ([`replay_guarded`]).
pub const REPLAY_MAX_OMEGA_H: f64 = 1.0;

/// Fewest fixed substeps per period of `dt` (s) that hold `plant`'s fastest mode to
/// ω·h ≤ [`REPLAY_MAX_OMEGA_H`], capped at [`ehactl_plant::model::MAX_SUBSTEPS`].
fn stable_substeps(plant: &Plant, dt: f64) -> u32 {
    let n = (dt * plant.fastest_mode() / REPLAY_MAX_OMEGA_H).ceil();
    if n.is_finite() {
        (n.max(1.0) as u32).min(ehactl_plant::model::MAX_SUBSTEPS)
    } else {
        ehactl_plant::model::MAX_SUBSTEPS
    }
}

/// [`Plant::configure`] for a replay at period `dt` (s): fixed substeps are raised for this
/// replay towards `stable_substeps`, at most to `max_substeps`, where the parameters would
/// step the fastest mode beyond [`REPLAY_MAX_OMEGA_H`] (automatic substeps hold their own,
/// tighter, rule).
pub fn configure_stable(params: &PlantParams, dt: f64, max_substeps: u32) -> Result<Plant, String> {
    let plant = Plant::configure(params, dt).map_err(|e| e.to_string())?;
    if params.integration.substeps == 0 || max_substeps <= plant.substeps() {
        return Ok(plant);
    }
    let n = stable_substeps(&plant, dt).min(max_substeps);
    if n <= plant.substeps() {
        return Ok(plant);
    }
    let mut p = params.clone();
    p.integration.substeps = n;
    Plant::configure(&p, dt).map_err(|e| e.to_string())
}

/// Cumulative counters of every replay in this process ([`replay_stats`]): what a diagnosis
/// spends its time on (BENCHMARKS.md "Diagnosis speed"). Relaxed atomics, one update per
/// replay (a replay takes milliseconds), so counting costs nothing measurable.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReplayStats {
    /// Replays run.
    pub replays: u64,
    /// Samples replayed (sum of `n` over replays).
    pub samples: u64,
    /// Plant substeps taken (sum of [`Plant::substeps_taken`]).
    pub substeps: u64,
    /// `linear_exact` transitions computed (sum of [`Plant::discretisations`]).
    pub discretisations: u64,
    /// Time in [`Plant::configure`] (ns, summed over threads).
    pub configure_ns: u64,
    /// Time in the replay loops (ns, summed over threads).
    pub run_ns: u64,
}

struct AtomicStats([std::sync::atomic::AtomicU64; 6]);

impl AtomicStats {
    fn add(
        &self,
        n: usize,
        plant: &Plant,
        configure: std::time::Duration,
        run: std::time::Duration,
    ) {
        use std::sync::atomic::Ordering::Relaxed;
        let v = [
            1,
            n as u64,
            plant.substeps_taken(),
            plant.discretisations(),
            configure.as_nanos() as u64,
            run.as_nanos() as u64,
        ];
        for (a, v) in self.0.iter().zip(v) {
            a.fetch_add(v, Relaxed);
        }
    }
}

#[allow(clippy::declare_interior_mutable_const)]
const ZERO: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
static STATS: AtomicStats = AtomicStats([ZERO; 6]);

/// The replay counters of this process so far (differences between two calls measure a
/// stage).
pub fn replay_stats() -> ReplayStats {
    use std::sync::atomic::Ordering::Relaxed;
    let v: Vec<u64> = STATS.0.iter().map(|a| a.load(Relaxed)).collect();
    ReplayStats {
        replays: v[0],
        samples: v[1],
        substeps: v[2],
        discretisations: v[3],
        configure_ns: v[4],
        run_ns: v[5],
    }
}

/// Sensor offsets: per channel, the mean of measured − model over `range` (channel's SI
/// unit). A constant offset is how a zero error of a transducer or its amplifier shows up; it
/// is a nuisance parameter of every model, profiled out in closed form (the least-squares
/// offset of a residual is its mean).
pub fn offsets(rec: &Record, sim: &Replay, range: std::ops::Range<usize>) -> Vec<f64> {
    rec.channels
        .iter()
        .zip(&sim.y)
        .map(|(c, yh)| {
            let r = range.start..range.end.min(yh.len()).min(c.values.len());
            if r.is_empty() {
                return 0.0;
            }
            c.values[r.clone()]
                .iter()
                .zip(&yh[r.clone()])
                .map(|(a, b)| a - b)
                .sum::<f64>()
                / r.len() as f64
        })
        .collect()
}

/// Add per-channel sensor offsets `b` to the model outputs (so model + offset ≈ measured).
pub fn apply_offsets(sim: &mut Replay, b: &[f64]) {
    for ((yc, o), bc) in sim.y.iter_mut().zip(sim.offsets.iter_mut()).zip(b) {
        for v in yc.iter_mut() {
            *v += bc;
        }
        *o += bc;
    }
}

/// Per-channel normalised RMS error over `range`: rms(y − ŷ)/std(y).
pub fn nrmse(rec: &Record, sim: &Replay, range: std::ops::Range<usize>) -> Vec<f64> {
    rec.channels
        .iter()
        .zip(&sim.y)
        .map(|(c, yh)| {
            let r = range.start..range.end.min(yh.len());
            let y = &c.values[r.clone()];
            let e = y
                .iter()
                .zip(&yh[r])
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                / y.len() as f64;
            let sd = std(y);
            if sd > 0.0 {
                e.sqrt() / sd
            } else {
                e.sqrt()
            }
        })
        .collect()
}

/// Overall NRMSE: root mean square over channels.
pub fn overall(per_channel: &[f64]) -> f64 {
    if per_channel.is_empty() {
        return f64::NAN;
    }
    (per_channel.iter().map(|v| v * v).sum::<f64>() / per_channel.len() as f64).sqrt()
}

/// Standard deviation.
pub fn std(y: &[f64]) -> f64 {
    if y.len() < 2 {
        return 0.0;
    }
    let m = y.iter().sum::<f64>() / y.len() as f64;
    (y.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / y.len() as f64).sqrt()
}

/// White-noise level of a sampled signal (same unit): the median one-sided PSD over the upper
/// half of the band (f_s/4 … f_s/2) times f_s/2. The median ignores narrow lines (tones) and
/// the band excludes the slow signal content; a signal with broadband content up there is
/// counted as noise (conservative: it raises the floor, so fewer effects are accepted).
pub fn noise_level(y: &[f64]) -> f64 {
    if y.len() < 64 {
        return 0.0;
    }
    // dt = 1: the PSD per cycle/sample; variance = PSD·(1/2) for white noise.
    let (f, psd) = crate::spectrum::welch(y, 1.0);
    let mut band: Vec<f64> = f
        .iter()
        .zip(&psd)
        .filter(|(f, _)| **f >= 0.25)
        .map(|(_, p)| *p)
        .collect();
    if band.is_empty() {
        return 0.0;
    }
    band.sort_by(f64::total_cmp);
    // Median of an averaged periodogram is below its mean (χ² with few degrees of freedom);
    // with ≥ 3 half-overlapping segments the ratio is ≈ 0.9.
    (band[band.len() / 2] / 0.9 * 0.5).sqrt()
}

/// Noise floor of one channel in NRMSE units (-): the white-noise level of the residual
/// `y − yh` (or of `y` itself, if lower: a residual with model error in the upper band must
/// not raise the floor above the data's own noise) over the std of `y`.
pub fn residual_floor(y: &[f64], yh: &[f64]) -> f64 {
    let e: Vec<f64> = y.iter().zip(yh).map(|(a, b)| a - b).collect();
    noise_level(&e).min(noise_level(y)) / std(y).max(1e-300)
}

/// Replay accuracy: how the substeps were chosen and the integration error they leave.
#[derive(Debug, Clone, serde::Serialize)]
pub struct IntegrationCheck {
    /// Substeps per sample period chosen for the replay.
    pub substeps: u32,
    /// Substeps the config's `[plant.integration]` gives at this sample period.
    pub config_substeps: u32,
    /// `integration.max_omega_h` of the config (-).
    pub max_omega_h: f64,
    /// Per channel: rms difference between the replay with the chosen substeps and with twice
    /// as many, on the fitting window, over the measured channel's std (NRMSE units, -): the
    /// step-halving estimate of the replay's own integration error (for the first-order scheme
    /// the error itself is ≈ 2× this).
    pub error: std::collections::BTreeMap<String, f64>,
    /// Per channel: the noise floor it is compared with (NRMSE units, -), from the nominal
    /// replay's residual on the fitting window.
    pub floor: std::collections::BTreeMap<String, f64>,
    /// Required: error ≤ this fraction of the floor on every channel (-).
    pub ratio_limit: f64,
    /// Largest cost factor (substeps / config substeps) the choice was allowed (-).
    pub max_cost: f64,
    /// Whether the requirement was met within that cost. When not, the remaining error is
    /// added to the noise floor of the diagnosis (it is never blamed on an effect).
    pub met: bool,
    /// Whether the nominal model at the config's own integration (its substeps, automatic
    /// where the config says so, exactly as `ehactl run` steps it) already reproduces the
    /// held-out data within the noise. Then the replay keeps that integration: the data are
    /// explained by the model as configured, numerics included (a log of `ehactl run` carries
    /// the config's integration error, so a finer replay would differ from it by that error).
    pub configured_step_explains: bool,
}

/// The integration error must stay below this fraction of the noise floor (-): added in
/// quadrature to white noise it raises the residual RMS by at most √(1 + 0.3²) − 1 ≈ 4.4 %.
pub const INTEGRATION_RATIO: f64 = 0.3;

/// Default largest replay cost factor of the integration choice for the library
/// ([`crate::Options`]); `ehactl diagnose` and the Python bindings use
/// [`crate::session::USER_INTEGRATION_COST`].
pub const DEFAULT_INTEGRATION_COST: f64 = 1.0;

/// Choose the replay's integration so that its own error is well below the noise floor: on
/// the first `n` samples, measure the step-halving difference at the config's substeps N
/// (replays with N and 2N); where it exceeds [`INTEGRATION_RATIO`] × the noise floor on a
/// channel, predict the substeps that meet it from the scheme's first order (error ∝ step,
/// with a 20 % margin), capped at `max_cost` × N, and check them the same way (at most twice).
/// Returns the parameters to replay with (fixed substeps) and the figures for the report.
pub fn choose_integration(
    p: &PlantParams,
    rec: &Record,
    n: usize,
    drive: Drive,
    max_cost: f64,
) -> (PlantParams, IntegrationCheck) {
    choose_integration_between(p, rec, n, drive, 1.0, max_cost)
}

/// [`choose_integration`] that may also take fewer substeps than the config's N, down to
/// `min_cost` × N (0 = no such floor; 1 = never fewer) and never below the stability guard
/// ω·h ≤ [`REPLAY_MAX_OMEGA_H`], where N leaves less than half the allowed error: the fewest
/// that leave at most half of it by their own step-halving check (first order: error ∝
/// step). `ehactl diagnose` uses [`crate::session::USER_INTEGRATION_MIN_COST`].
pub fn choose_integration_between(
    p: &PlantParams,
    rec: &Record,
    n: usize,
    drive: Drive,
    min_cost: f64,
    max_cost: f64,
) -> (PlantParams, IntegrationCheck) {
    let n = n.min(rec.len());
    let mut p = p.clone();
    let halving = Halving::new(&p, rec, n, drive);
    // Fewest substeps the replays may take at all (ω·h ≤ REPLAY_MAX_OMEGA_H at the nominal
    // parameters; each replay guards its own parameters the same way, `configure_stable`).
    // The config's substeps per sample and the fewest the guard allows (one configuration).
    let (n0, stable_ns) = Plant::configure(&p, rec.dt)
        .map_or((1, 1), |pl| (pl.substeps(), stable_substeps(&pl, rec.dt)));
    let cap = ((n0 as f64 * max_cost.max(1.0)).floor() as u32)
        .clamp(n0, ehactl_plant::model::MAX_SUBSTEPS);
    let (mut ns, mut err) = halving.refine(&p, n0, cap);
    // Cheaper when the config's substeps are far more accurate than required: the fewest
    // that leave at most half the allowed error (first order: error ∝ step), no fewer than
    // `min_cost` × the config's and than the nominal stability guard (ω·h ≤
    // REPLAY_MAX_OMEGA_H; a fit that moves a mode faster gets more substeps in its own
    // replays, up to the config's, `replay_guarded`), checked by step halving like any other
    // choice and kept only when it holds.
    let floor_ns = ((n0 as f64 * min_cost.clamp(0.0, 1.0)).ceil() as u32)
        .max(stable_ns)
        .max(1);
    if ns == n0 && floor_ns < n0 {
        if let Some(fewer) = halving.fewer(&p, n0, floor_ns, &err) {
            (ns, err) = fewer;
        }
    }
    let met = halving.worst(&err) <= 1.0;
    p.integration.substeps = ns;
    let names = || rec.channels.iter().map(|c| c.kind.column().to_string());
    let check = IntegrationCheck {
        substeps: ns,
        config_substeps: n0,
        max_omega_h: p.integration.max_omega_h,
        error: names().zip(err).collect(),
        floor: names().zip(halving.floor.iter().copied()).collect(),
        ratio_limit: INTEGRATION_RATIO,
        max_cost,
        met,
        configured_step_explains: false,
    };
    (p, check)
}

/// The step-halving check of [`choose_integration_between`] on the first `n` samples of a
/// record: each channel's std and noise floor, and the replays at N and 2N substeps.
struct Halving<'r> {
    rec: &'r Record,
    n: usize,
    drive: Drive,
    /// Std of each measured channel over the window (its unit).
    sd: Vec<f64>,
    /// Noise floor per channel from the nominal replay's residual (NRMSE units, -).
    floor: Vec<f64>,
}

impl<'r> Halving<'r> {
    /// The channels' stds and floors at the nominal parameters `p` (as in the diagnosis).
    fn new(p: &PlantParams, rec: &'r Record, n: usize, drive: Drive) -> Self {
        let sd: Vec<f64> = rec
            .channels
            .iter()
            .map(|c| std(&c.values[..n]).max(1e-300))
            .collect();
        let floor: Vec<f64> = match replay_with(p, rec, n, drive) {
            Ok(sim) => rec
                .channels
                .iter()
                .zip(&sim.y)
                .map(|(c, yh)| residual_floor(&c.values[..n], yh))
                .collect(),
            Err(_) => vec![0.0; sd.len()],
        };
        Self {
            rec,
            n,
            drive,
            sd,
            floor,
        }
    }

    /// Per channel: rms difference of the replays with `ns` and 2·`ns` substeps over the
    /// channel's std (-); infinite when a replay fails.
    fn error(&self, p: &PlantParams, ns: u32) -> Vec<f64> {
        let (rec, n, drive) = (self.rec, self.n, self.drive);
        let mut a = p.clone();
        a.integration.substeps = ns;
        let mut b = p.clone();
        b.integration.substeps = 2 * ns;
        // The two replays are independent: one per core.
        match rayon::join(
            || replay_with(&a, rec, n, drive),
            || replay_with(&b, rec, n, drive),
        ) {
            (Ok(a), Ok(b)) => {
                a.y.iter()
                    .zip(&b.y)
                    .zip(&self.sd)
                    .map(|((ya, yb), s)| {
                        (ya.iter()
                            .zip(yb)
                            .map(|(x, y)| (x - y) * (x - y))
                            .sum::<f64>()
                            / n.max(1) as f64)
                            .sqrt()
                            / s
                    })
                    .collect()
            }
            _ => vec![f64::INFINITY; self.sd.len()],
        }
    }

    /// Worst ratio error / allowed over channels (1e-6 of the std: numerically insignificant
    /// even on noise-free data).
    fn worst(&self, err: &[f64]) -> f64 {
        err.iter()
            .zip(&self.floor)
            .map(|(e, f)| e / (INTEGRATION_RATIO * f).max(1e-6))
            .fold(0.0, f64::max)
    }

    /// From the config's `n0` substeps: while the error exceeds the allowed one, the substeps
    /// predicted to meet it (first order, 20 % margin), up to `cap`, at most twice. Returns
    /// the substeps and their error.
    fn refine(&self, p: &PlantParams, n0: u32, cap: u32) -> (u32, Vec<f64>) {
        let mut ns = n0;
        let mut err = self.error(p, ns);
        for _ in 0..2 {
            let r = self.worst(&err);
            if r <= 1.0 || ns >= cap || !r.is_finite() {
                break;
            }
            let next = ((ns as f64 * r * 1.2).ceil() as u32).clamp(ns + 1, cap);
            ns = next;
            err = self.error(p, ns);
        }
        (ns, err)
    }

    /// Fewer substeps than the config's `n0`, no fewer than `floor_ns`, when the first that
    /// leaves at most half the allowed error by its own check is found among the predicted
    /// count and the next three up (a prediction that misses, the error not yet first order
    /// at so few substeps, is followed by the next counts up: each check is two replays of
    /// the fit cost's samples, against the thousands of a diagnosis). `err0` is the error at
    /// `n0`.
    fn fewer(
        &self,
        p: &PlantParams,
        n0: u32,
        floor_ns: u32,
        err0: &[f64],
    ) -> Option<(u32, Vec<f64>)> {
        let r = self.worst(err0);
        let fewer = ((n0 as f64 * r / 0.5).ceil() as u32).max(floor_ns);
        if !r.is_finite() {
            return None;
        }
        for k in (fewer..n0).take(4) {
            let e = self.error(p, k);
            if self.worst(&e) <= 0.5 {
                return Some((k, e));
            }
        }
        None
    }
}
