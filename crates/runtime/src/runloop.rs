//! The fixed-step control loop: `Hal::read` → supervisor → setpoint → control law →
//! supervisor command limit → `Hal::write` → record. The same code runs in simulated time
//! (the sim backend, as fast as the CPU allows) and against a wall clock: only the
//! [`Pacer`] differs. Nothing in the cycle allocates, locks or does blocking I/O.

use crate::live::LiveParams;
use ehactl_config::{ControlMode, RigConfig};
use ehactl_control::pd::Pd;
use ehactl_control::pi::{ControlTerms, Pi};
use ehactl_control::setpoint::Setpoint;
use ehactl_control::supervisor::{FeedbackChannel, Supervisor};
use ehactl_hal::pacer::Pacer;
use ehactl_hal::record::{CycleRecord, CycleTiming, Event, EventKind, Severity};
use ehactl_hal::{Hal, Measurements, Timebase};
use std::sync::atomic::{AtomicBool, Ordering};

/// The configured control law.
#[derive(Debug, Clone)]
pub enum Controller {
    /// PI on force (N), error scaled to load-cell volts.
    Force(Pi),
    /// PD on position (m).
    Position(Pd),
    /// Setpoint passed straight to the valve (V).
    OpenLoop,
}

impl Controller {
    /// From a validated config.
    pub fn from_config(cfg: &RigConfig) -> Controller {
        match cfg.control.mode {
            ControlMode::Force => Controller::Force(Pi::new(cfg.pi_gains().expect("validated"))),
            ControlMode::Position => {
                Controller::Position(Pd::new(cfg.pd_gains().expect("validated")))
            }
            ControlMode::OpenLoop => Controller::OpenLoop,
        }
    }

    /// Feedback channel the law closes on.
    pub fn feedback_channel(&self) -> FeedbackChannel {
        match self {
            Controller::Position(_) => FeedbackChannel::Position,
            _ => FeedbackChannel::Force,
        }
    }

    /// The measured value the law feeds back.
    #[inline]
    pub fn feedback(&self, m: &Measurements) -> f64 {
        match self {
            Controller::Position(_) => m.position,
            _ => m.force,
        }
    }

    /// One step. Pure: no I/O, no allocation.
    #[inline]
    pub fn step(&mut self, setpoint: f64, rate: f64, m: &Measurements, dt: f64) -> ControlTerms {
        match self {
            Controller::Force(pi) => pi.step(setpoint, m.force, dt),
            Controller::Position(pd) => pd.step(setpoint, rate, m.position, dt),
            Controller::OpenLoop => ControlTerms {
                u: setpoint,
                u_unsat: setpoint,
                error: f64::NAN,
                ff: setpoint,
                ..Default::default()
            },
        }
    }
}

/// How a run ended and what it measured.
#[derive(Debug, Clone, PartialEq)]
pub struct RunOutcome {
    /// Cycles executed.
    pub cycles: u64,
    /// Simulated / controlled time covered (s).
    pub duration_s: f64,
    /// The trip event, if the supervisor tripped.
    pub trip: Option<Event>,
    /// Whether a signal stopped the run.
    pub interrupted: bool,
    /// RMS of the control error over the run (N or m).
    pub rms_error: f64,
    /// Largest |error| over the run (N or m).
    pub max_abs_error: f64,
    /// RMS error after `settle_time` (N or m).
    pub rms_error_settled: f64,
}

/// Settings of one run.
pub struct LoopSettings<'a> {
    /// Number of cycles.
    pub cycles: u64,
    /// The control timebase: cycle `k` runs at `t = k · period`.
    pub timebase: Timebase,
    /// Set asynchronously (signal handler) to stop the run.
    pub stop: Option<&'a AtomicBool>,
    /// Errors before this time are excluded from `rms_error_settled` (s).
    pub settle_time: f64,
    /// Live gain / setpoint changes, taken over at cycle boundaries (None = fixed).
    pub live: Option<&'a LiveParams>,
    /// Set when the log writer has failed (disk full, I/O error): the run trips.
    pub log_failed: Option<&'a AtomicBool>,
}

/// Run the loop. `record` receives every cycle's record (the logger push), `event`
/// every event, `progress` the cycle count every 1 % (all called from the loop thread).
#[allow(clippy::too_many_arguments)]
pub fn run_loop<H: Hal + ?Sized, P: Pacer + ?Sized>(
    hal: &mut H,
    controller: &mut Controller,
    setpoint_in: &Setpoint,
    supervisor: &mut Supervisor,
    pacer: &mut P,
    settings: &LoopSettings<'_>,
    record: &mut dyn FnMut(&CycleRecord),
    event: &mut dyn FnMut(Event),
    progress: &mut dyn FnMut(u64),
) -> RunOutcome {
    let dt = settings.timebase.period();
    let n = settings.cycles;
    let step = (n / 100).max(1);
    let mut errors = ErrorStats::default();
    let mut trip = None;
    let mut interrupted = false;
    let mut k = 0u64;
    // Front buffer of the live parameters (the back buffer is `settings.live`); cloning a
    // setpoint copies plain numbers, it does not allocate.
    let mut setpoint = setpoint_in.clone();
    event(Event {
        t: 0.0,
        cycle: 0,
        severity: Severity::Info,
        kind: EventKind::Start,
        channel: hal.name(),
        value: f64::NAN,
        limit: f64::NAN,
        unit: "",
    });
    while k < n {
        if settings.stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            interrupted = true;
            break;
        }
        if settings
            .log_failed
            .is_some_and(|f| f.load(Ordering::Relaxed))
        {
            trip = Some(Event {
                t: k as f64 * dt,
                cycle: k,
                severity: Severity::Trip,
                kind: EventKind::LogFailed,
                channel: "mcap",
                value: f64::NAN,
                limit: f64::NAN,
                unit: "",
            });
            break;
        }
        let go = pacer.wait_for_cycle(k);
        while let Some(ev) = pacer.take_event() {
            event(ev);
        }
        if !go {
            match pacer.trip() {
                Some(ev) => trip = Some(ev),
                None => interrupted = true,
            }
            break;
        }
        let t = k as f64 * dt;
        // Cycle boundary: take over a pending gain / setpoint change (wait-free).
        if let Some(live) = settings.live {
            live.apply_pending(k, t, controller, &mut setpoint, event);
        }
        let timing = pacer.cycle_timing();
        // The measured period handed to the backend (ros2_control's `period`): wall-clock
        // pacers measure it, simulated time has the nominal one.
        let period = timing
            .map(|c| c.period_us * 1e-6)
            .filter(|p| p.is_finite() && *p > 0.0)
            .unwrap_or(dt);
        let hal_fault = |e: ehactl_hal::HalError| Event {
            t,
            cycle: k,
            severity: Severity::Trip,
            kind: EventKind::HalFault,
            channel: match e {
                ehactl_hal::HalError::Numerical { what, .. } => what,
                ehactl_hal::HalError::Device { what, .. } => what,
            },
            value: f64::NAN,
            limit: f64::NAN,
            unit: "",
        };
        let meas = match hal.read(t, period) {
            Ok(m) => m,
            Err(e) => {
                trip = Some(hal_fault(e));
                break;
            }
        };
        let (r, rdot) = setpoint.sample(t);
        if let Some(ev) = supervisor.check_sensors(t, k, &meas) {
            // The tripping cycle is logged too, with the safe command it applied.
            let plant = hal.plant_state();
            let safe = supervisor.safe_command();
            let fb = controller.feedback(&meas);
            let e = if matches!(controller, Controller::OpenLoop) {
                f64::NAN
            } else {
                r - fb
            };
            errors.add(e, t, settings.settle_time);
            let held = ControlTerms {
                u: safe,
                u_unsat: safe,
                error: e,
                p: f64::NAN,
                i: f64::NAN,
                d: f64::NAN,
                ff: f64::NAN,
            };
            record(&cycle_record(
                k,
                t,
                (r, rdot),
                fb,
                &held,
                safe,
                meas,
                plant,
                timing,
            ));
            k += 1;
            trip = Some(ev);
            break;
        }
        let terms = controller.step(r, rdot, &meas, dt);
        let (u, ev) = supervisor.limit_command(t, k, terms.u);
        if let Some(ev) = ev {
            if ev.severity == Severity::Trip {
                trip = Some(ev);
                break;
            }
            event(ev);
        }
        let saturated = terms.u != terms.u_unsat || u != terms.u;
        if let Some(ev) = supervisor.check_saturation(t, k, saturated, dt) {
            trip = Some(ev);
            break;
        }
        let plant = hal.plant_state();
        let fb = controller.feedback(&meas);
        let rec = cycle_record(k, t, (r, rdot), fb, &terms, u, meas, plant, timing);
        if let Err(e) = hal.write(t, period, u) {
            record(&rec);
            trip = Some(hal_fault(e));
            k += 1;
            break;
        }
        record(&rec);
        errors.add(terms.error, t, settings.settle_time);
        k += 1;
        if k.is_multiple_of(step) {
            progress(k);
        }
    }
    let safe = supervisor.safe_command();
    let safe_result = hal.safe_stop(safe);
    let end_t = k as f64 * dt;
    if let Some(ev) = trip {
        event(ev);
    } else if interrupted {
        event(Event {
            t: end_t,
            cycle: k,
            severity: Severity::Trip,
            kind: EventKind::Signal,
            channel: "process",
            value: f64::NAN,
            limit: f64::NAN,
            unit: "",
        });
    } else {
        event(Event {
            t: end_t,
            cycle: k,
            severity: Severity::Info,
            kind: EventKind::End,
            channel: "run",
            value: f64::NAN,
            limit: f64::NAN,
            unit: "",
        });
    }
    event(Event {
        t: end_t,
        cycle: k,
        severity: if safe_result.is_ok() {
            Severity::Info
        } else {
            Severity::Warning
        },
        kind: EventKind::SafeStop,
        channel: match safe_result {
            Ok(()) => "valve",
            Err(ehactl_hal::HalError::Numerical { what, .. }) => what,
            Err(ehactl_hal::HalError::Device { what, .. }) => what,
        },
        value: safe,
        limit: f64::NAN,
        unit: "V",
    });
    progress(k);
    RunOutcome {
        cycles: k,
        duration_s: end_t,
        trip,
        interrupted,
        rms_error: rms(errors.sum_sq, errors.n),
        max_abs_error: if errors.n > 0 {
            errors.max_abs
        } else {
            f64::NAN
        },
        rms_error_settled: rms(errors.sum_sq_settled, errors.n_settled),
    }
}

/// Control-error statistics of a run (N or m), accumulated without allocation.
#[derive(Default)]
struct ErrorStats {
    sum_sq: f64,
    n: u64,
    sum_sq_settled: f64,
    n_settled: u64,
    max_abs: f64,
}

impl ErrorStats {
    /// Add the error `e` of the cycle at `t` (s); errors after `settle` (s) also count as
    /// settled. Non-finite errors (open loop) are skipped.
    #[inline]
    fn add(&mut self, e: f64, t: f64, settle: f64) {
        if !e.is_finite() {
            return;
        }
        self.sum_sq += e * e;
        self.n += 1;
        self.max_abs = self.max_abs.max(e.abs());
        if t >= settle {
            self.sum_sq_settled += e * e;
            self.n_settled += 1;
        }
    }
}

fn rms(sum_sq: f64, n: u64) -> f64 {
    if n > 0 {
        (sum_sq / n as f64).sqrt()
    } else {
        f64::NAN
    }
}

/// The record of cycle `k` at `t` (s): setpoint and its rate, feedback, the law's terms and
/// the command `u` (V) actually applied. Fixed size, no allocation.
#[allow(clippy::too_many_arguments)]
#[inline]
fn cycle_record(
    k: u64,
    t: f64,
    (setpoint, setpoint_rate): (f64, f64),
    feedback: f64,
    terms: &ControlTerms,
    u: f64,
    meas: Measurements,
    plant: Option<ehactl_hal::PlantState>,
    timing: Option<CycleTiming>,
) -> CycleRecord {
    CycleRecord {
        cycle: k,
        t,
        setpoint,
        setpoint_rate,
        feedback,
        error: terms.error,
        command: u,
        command_unsat: terms.u_unsat,
        p_term: terms.p,
        i_term: terms.i,
        d_term: terms.d,
        ff_term: terms.ff,
        meas,
        plant: plant.unwrap_or_default(),
        has_plant: plant.is_some(),
        timing,
    }
}
