//! The fixed-step control loop: `Hal::read` → the cycle kernel (`ehactl_control::cycle`:
//! setpoint → supervisor → control law → supervisor command limit, saturation and
//! following-error watches; the loop body the diagnosis's replay steps too) → `Hal::write`
//! → record. The same code runs in simulated time
//! (the sim backend, as fast as the CPU allows) and against a wall clock: only the
//! [`Pacer`] differs. Nothing in the cycle allocates, locks or does blocking I/O.

use crate::live::LiveParams;
pub use ehactl_control::controller::Controller;
use ehactl_control::cycle::{self, CycleInput, Trip};
use ehactl_control::pi::ControlTerms;
use ehactl_control::setpoint::Setpoint;
use ehactl_control::supervisor::Supervisor;
use ehactl_hal::pacer::Pacer;
use ehactl_hal::{Hal, Measurements, Timebase};
use ehactl_log::record::{CycleRecord, CycleTiming, Event, EventKind, Severity};
use std::sync::atomic::{AtomicBool, Ordering};

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
/// Each cycle is `Loop::admit` (may it start?) then `Loop::execute` (the cycle itself);
/// `Loop::finish` brings the valve to its safe command and reports how the run ended.
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
    let n = settings.cycles;
    let step = (n / 100).max(1);
    event(Event::note(
        0.0,
        0,
        Severity::Info,
        EventKind::Start,
        hal.name(),
    ));
    let mut lp = Loop {
        hal,
        controller,
        supervisor,
        pacer,
        settings,
        record,
        event,
        // Front buffer of the live parameters (the back buffer is `settings.live`); cloning
        // a setpoint copies plain numbers, it does not allocate.
        setpoint: setpoint_in.clone(),
        held: None,
        dt: settings.timebase.period(),
        k: 0,
        errors: ErrorStats::default(),
    };
    let mut ending = None;
    while lp.k < n {
        if let Err(end) = lp.admit().and_then(|timing| lp.execute(timing)) {
            ending = Some(end);
            break;
        }
        if lp.k.is_multiple_of(step) {
            progress(lp.k);
        }
    }
    let outcome = lp.finish(ending);
    progress(outcome.cycles);
    outcome
}

/// Cycles `k0 .. k0 + n` of [`run_loop`]'s cycle, driven from outside (a co-simulation
/// step: `crates/fmu`): each is `Loop::admit` + `Loop::execute` in simulated time, with
/// `held` (setpoint in N or m, its rate per s) in place of sampling `setpoint` when given.
/// Unlike [`run_loop`] no start or end event is emitted and the backend is not
/// deactivated: the caller owns the run around the cycles. `Err` is the trip event that
/// ended the cycles (the tripping cycle is recorded as in [`run_loop`]); `Ok` the next cycle.
#[allow(clippy::too_many_arguments)]
pub fn step_cycles<H: Hal + ?Sized>(
    hal: &mut H,
    controller: &mut Controller,
    setpoint: &Setpoint,
    held: Option<(f64, f64)>,
    supervisor: &mut Supervisor,
    (timebase, k0, n): (Timebase, u64, u64),
    record: &mut dyn FnMut(&CycleRecord),
    event: &mut dyn FnMut(Event),
) -> Result<u64, Event> {
    let settings = LoopSettings {
        cycles: k0 + n,
        timebase,
        stop: None,
        settle_time: 0.0,
        live: None,
        log_failed: None,
    };
    let mut pacer = ehactl_hal::pacer::SimulatedTime;
    let mut lp = Loop {
        hal,
        controller,
        supervisor,
        pacer: &mut pacer,
        settings: &settings,
        record,
        event,
        setpoint: setpoint.clone(),
        held,
        dt: timebase.period(),
        k: k0,
        errors: ErrorStats::default(),
    };
    while lp.k < k0 + n {
        match lp.admit().and_then(|timing| lp.execute(timing)) {
            Ok(()) => {}
            Err(Ending::Trip(ev)) => return Err(ev),
            // Simulated time never stops and no stop flag is set.
            Err(Ending::Interrupted) => break,
        }
    }
    Ok(lp.k)
}

/// Why the loop ended before its last cycle.
enum Ending {
    /// A trip: supervisor, backend fault, failed log or the pacer's overrun policy.
    Trip(Event),
    /// A stop request (signal), or the pacer stopped without a trip.
    Interrupted,
}

/// The loop's parts and running state during one [`run_loop`].
struct Loop<'a, 's, H: ?Sized, P: ?Sized> {
    hal: &'a mut H,
    controller: &'a mut Controller,
    supervisor: &'a mut Supervisor,
    pacer: &'a mut P,
    settings: &'a LoopSettings<'s>,
    record: &'a mut dyn FnMut(&CycleRecord),
    event: &'a mut dyn FnMut(Event),
    /// Front buffer of the live setpoint.
    setpoint: Setpoint,
    /// A setpoint and its rate held from outside instead of sampling `setpoint` (the FMU's
    /// input, [`step_cycles`]); `None` in [`run_loop`].
    held: Option<(f64, f64)>,
    /// Nominal control period (s).
    dt: f64,
    /// The next cycle; also the count of cycles recorded.
    k: u64,
    errors: ErrorStats,
}

impl<H: Hal + ?Sized, P: Pacer + ?Sized> Loop<'_, '_, H, P> {
    /// Before cycle `k`: a stop request, a failed log, the pacer's wait (its events are
    /// forwarded) and the live hand-over at the cycle boundary. Returns the pacer's timing of
    /// the cycle that starts.
    fn admit(&mut self) -> Result<Option<CycleTiming>, Ending> {
        let (k, t) = (self.k, self.settings.timebase.time_of(self.k));
        if self
            .settings
            .stop
            .is_some_and(|s| s.load(Ordering::Relaxed))
        {
            return Err(Ending::Interrupted);
        }
        if self
            .settings
            .log_failed
            .is_some_and(|f| f.load(Ordering::Relaxed))
        {
            let ev = Event::note(t, k, Severity::Trip, EventKind::LogFailed, "mcap");
            return Err(Ending::Trip(ev));
        }
        let go = self.pacer.wait_for_cycle(k);
        while let Some(ev) = self.pacer.take_event() {
            (self.event)(ev);
        }
        if !go {
            return Err(self.pacer.trip().map_or(Ending::Interrupted, Ending::Trip));
        }
        // Cycle boundary: take over a pending gain / setpoint change (wait-free).
        if let Some(live) = self.settings.live {
            live.apply_pending(k, t, self.controller, &mut self.setpoint, self.event);
        }
        Ok(self.pacer.cycle_timing())
    }

    /// Cycle `k`: read → supervise → setpoint → control law → command limit → write →
    /// record. A trip ends it early; the tripping cycle is recorded when its sensors were
    /// read (with the safe command it applied) or its command was computed.
    fn execute(&mut self, timing: Option<CycleTiming>) -> Result<(), Ending> {
        let (k, dt) = (self.k, self.dt);
        let t = self.settings.timebase.time_of(k);
        // The measured period handed to the backend (ros2_control's `period`): wall-clock
        // pacers measure it, simulated time has the nominal one.
        let period = timing
            .map(|c| c.period_us * 1e-6)
            .filter(|p| p.is_finite() && *p > 0.0)
            .unwrap_or(dt);
        let meas = self
            .hal
            .read(t, period)
            .map_err(|e| Ending::Trip(hal_fault(t, k, e)))?;
        // The cycle kernel (`ehactl_control::cycle`, the loop body the diagnosis's replay
        // steps too): setpoint, sensor checks, law, command limit and watches.
        let input = CycleInput { k, t, dt, meas };
        let reference = HeldOr {
            held: self.held,
            setpoint: &self.setpoint,
        };
        let out = cycle::step(self.controller, self.supervisor, &reference, &input);
        let fb = out.feedback;
        match out.trip {
            Some(Trip::Sensors(ev)) => {
                // Recorded with the safe command it applied.
                let plant = self.hal.plant_state();
                let rec = cycle_record(
                    k,
                    t,
                    out.reference,
                    fb,
                    &out.terms,
                    out.u,
                    meas,
                    plant,
                    timing,
                );
                self.log(&rec, out.terms.error);
                return Err(Ending::Trip(ev));
            }
            Some(Trip::Law(ev)) => {
                if let Some(w) = out.warning {
                    (self.event)(w);
                }
                return Err(Ending::Trip(ev));
            }
            None => {}
        }
        if let Some(w) = out.warning {
            (self.event)(w);
        }
        let (terms, u) = (&out.terms, out.u);
        let plant = self.hal.plant_state();
        let rec = cycle_record(k, t, out.reference, fb, terms, u, meas, plant, timing);
        if let Err(e) = self.hal.write(t, period, u) {
            // Recorded, but its error is not counted: the command did not reach the valve.
            self.log(&rec, f64::NAN);
            return Err(Ending::Trip(hal_fault(t, k, e)));
        }
        self.log(&rec, terms.error);
        Ok(())
    }

    /// Record the cycle, count its control error `e` (NaN: not counted), move to the next.
    #[inline]
    fn log(&mut self, rec: &CycleRecord, e: f64) {
        (self.record)(rec);
        self.errors.add(e, rec.t, self.settings.settle_time);
        self.k += 1;
    }

    /// After the loop: the safe command to the valve, the end event (trip, signal or normal
    /// end) and the safe-stop event, and the outcome. A run that ended normally deactivates
    /// the backend ([`Hal::deactivate`]: valve to the safe command, out of its enabled state);
    /// [`Hal::safe_stop`] is the fallback when that fails, and what every trip and signal
    /// calls. The safe-stop event reports the last of them.
    fn finish(self, ending: Option<Ending>) -> RunOutcome {
        let (k, end_t) = (self.k, self.settings.timebase.time_of(self.k));
        let safe = self.supervisor.safe_command();
        let safe_result = match ending {
            None => self
                .hal
                .deactivate(safe)
                .or_else(|_| self.hal.safe_stop(safe)),
            Some(_) => self.hal.safe_stop(safe),
        };
        let (trip, interrupted) = match ending {
            Some(Ending::Trip(ev)) => (Some(ev), false),
            Some(Ending::Interrupted) => (None, true),
            None => (None, false),
        };
        (self.event)(match (trip, interrupted) {
            (Some(ev), _) => ev,
            (None, true) => Event::note(end_t, k, Severity::Trip, EventKind::Signal, "process"),
            (None, false) => Event::note(end_t, k, Severity::Info, EventKind::End, "run"),
        });
        (self.event)(Event {
            severity: if safe_result.is_ok() {
                Severity::Info
            } else {
                Severity::Warning
            },
            value: safe,
            unit: "V",
            ..Event::note(
                end_t,
                k,
                Severity::Info,
                EventKind::SafeStop,
                safe_result.as_ref().map_or_else(|e| e.what(), |()| "valve"),
            )
        });
        let e = &self.errors;
        RunOutcome {
            cycles: k,
            duration_s: end_t,
            trip,
            interrupted,
            rms_error: rms(e.sum_sq, e.n),
            max_abs_error: if e.n > 0 { e.max_abs } else { f64::NAN },
            rms_error_settled: rms(e.sum_sq_settled, e.n_settled),
        }
    }
}

/// The trip event of a backend fault in cycle `k` at `t` (s): a simulated plant beyond
/// what the rig can have is its own kind (`plant_implausible`, with the state, its value,
/// bound and unit), every other fault a `hal_fault`.
fn hal_fault(t: f64, k: u64, e: ehactl_hal::HalError) -> Event {
    match e {
        ehactl_hal::HalError::Implausible {
            what,
            value,
            bound,
            unit,
            ..
        } => Event {
            value,
            limit: bound,
            unit,
            ..Event::note(t, k, Severity::Trip, EventKind::PlantImplausible, what)
        },
        _ => Event::note(t, k, Severity::Trip, EventKind::HalFault, e.what()),
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

/// The loop's reference: a setpoint and its rate held from outside (the FMU's input, set
/// before each step) when given, else the configured generator.
struct HeldOr<'a> {
    held: Option<(f64, f64)>,
    setpoint: &'a Setpoint,
}

impl cycle::Reference for HeldOr<'_> {
    #[inline]
    fn sample(&self, k: u64, t: f64) -> (f64, f64) {
        self.held
            .unwrap_or_else(|| cycle::Reference::sample(self.setpoint, k, t))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session::build_plant;
    use crate::sim::SimHal;
    use ehactl_config::RigConfig;
    use ehactl_hal::pacer::SimulatedTime;
    use ehactl_hal::HalError;

    /// The simulated plant behind a backend that records its lifecycle calls, and whose
    /// deactivate can fail or whose read can trip.
    struct Recording {
        sim: SimHal,
        calls: Vec<&'static str>,
        deactivate_fails: bool,
        trip_at: Option<f64>,
    }

    impl Hal for Recording {
        fn name(&self) -> &'static str {
            "recording"
        }
        fn read(&mut self, t: f64, period: f64) -> Result<Measurements, HalError> {
            if self.trip_at.is_some_and(|at| t >= at) {
                return Err(HalError::Device {
                    code: 1,
                    what: "test trip",
                });
            }
            self.sim.read(t, period)
        }
        fn write(&mut self, t: f64, period: f64, command: f64) -> Result<(), HalError> {
            self.sim.write(t, period, command)
        }
        fn safe_stop(&mut self, command: f64) -> Result<(), HalError> {
            self.calls.push("safe_stop");
            self.sim.safe_stop(command)
        }
        fn deactivate(&mut self, safe_command: f64) -> Result<(), HalError> {
            self.calls.push("deactivate");
            if self.deactivate_fails {
                return Err(HalError::Device {
                    code: 0,
                    what: "safe stop not confirmed by the valve",
                });
            }
            self.sim.deactivate(safe_command)
        }
    }

    /// Runs 0.05 s of the Sahu 2022 force config; returns the calls and the safe-stop event.
    fn run(deactivate_fails: bool, trip_at: Option<f64>) -> (Vec<&'static str>, Event) {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/sahu2022_force.toml");
        let cfg = RigConfig::load(&path).unwrap();
        let mut hal = Recording {
            sim: SimHal::new(build_plant(&cfg).unwrap()),
            calls: Vec::new(),
            deactivate_fails,
            trip_at,
        };
        let mut controller = cfg.controller();
        let mut supervisor = Supervisor::new(&cfg.supervisor, controller.feedback_channel());
        let setpoint = Setpoint::new(&cfg.setpoint);
        let timebase = cfg.timebase();
        let settings = LoopSettings {
            cycles: timebase.cycles_in(0.05),
            timebase,
            stop: None,
            settle_time: 0.0,
            live: None,
            log_failed: None,
        };
        let mut events = Vec::new();
        run_loop(
            &mut hal,
            &mut controller,
            &setpoint,
            &mut supervisor,
            &mut SimulatedTime,
            &settings,
            &mut |_| {},
            &mut |e| events.push(e),
            &mut |_| {},
        );
        let safe = events
            .into_iter()
            .find(|e| e.kind == EventKind::SafeStop)
            .expect("a safe-stop event");
        (hal.calls, safe)
    }

    #[test]
    fn a_normal_end_deactivates_a_trip_safe_stops_a_failed_deactivate_falls_back() {
        let (calls, ev) = run(false, None);
        assert_eq!(calls, ["deactivate"]);
        assert_eq!((ev.severity, ev.channel), (Severity::Info, "valve"));
        let (calls, ev) = run(true, None);
        assert_eq!(calls, ["deactivate", "safe_stop"]);
        assert_eq!((ev.severity, ev.channel), (Severity::Info, "valve"));
        let (calls, _) = run(false, Some(0.01));
        assert_eq!(calls, ["safe_stop"]);
    }

    /// The simulated backend's lifecycle: configure and activate are no-ops that succeed in
    /// any order and leave the plant untouched, deactivate is its safe stop.
    #[test]
    fn the_sim_lifecycle_calls_succeed_and_leave_the_plant_alone() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/sahu2022_force.toml");
        let cfg = RigConfig::load(&path).unwrap();
        let mut sim = SimHal::new(build_plant(&cfg).unwrap());
        let before = *sim.plant().state();
        sim.activate().unwrap();
        sim.configure().unwrap();
        sim.activate().unwrap();
        sim.deactivate(0.0).unwrap();
        sim.deactivate(0.0).unwrap();
        sim.safe_stop(0.0).unwrap();
        assert_eq!(format!("{:?}", *sim.plant().state()), format!("{before:?}"));
        // and the cycle runs as before
        let dt = cfg.timebase().period();
        sim.read(0.0, dt).unwrap();
        sim.write(0.0, dt, 1.0).unwrap();
    }
}
