//! One FMU instance: the config read from the FMU's resources, the values of its inputs and
//! parameters, and from the end of initialisation the model itself — the plant behind the
//! simulated backend `ehactl_runtime::sim::SimHal`, and for the closed loop the control law
//! and supervisor stepped by `ehactl_runtime::runloop::step_cycles`, the cycle of
//! `ehactl run`. All state is here; the C boundary ([`crate::ffi`]) holds it behind the
//! instance pointer.

use crate::variables::{Out, Role, Value, Var, Variant};
use ehactl_config::RigConfig;
use ehactl_control::controller::Controller;
use ehactl_control::setpoint::Setpoint;
use ehactl_control::supervisor::Supervisor;
use ehactl_hal::{Hal, HalError, Measurements, PlantState, Timebase};
use ehactl_runtime::sim::SimHal;
use std::collections::BTreeMap;
use std::path::Path;

/// The FMI 2.0 co-simulation states an instance moves through (FMI 2.0 §4.2.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// After fmi2Instantiate or fmi2Reset: parameters and inputs may be set.
    Instantiated,
    /// Between fmi2EnterInitializationMode and fmi2ExitInitializationMode.
    Initialization,
    /// Ready for fmi2DoStep.
    StepComplete,
    /// After fmi2Terminate.
    Terminated,
}

/// The simulated backend with the cycle's sensor reading held: the measurement an output
/// shows at a communication point is the one the next cycle's `read` takes, so that the
/// sensor models (sample-and-hold, seeded noise) are sampled once per cycle as in
/// `ehactl run`, however often a host reads the outputs.
struct HeldHal {
    sim: SimHal,
    pending: Option<Measurements>,
}

impl HeldHal {
    /// The measurement of the plant's present state (taken once, then held).
    fn peek(&mut self) -> Measurements {
        let sim = &mut self.sim;
        *self
            .pending
            .get_or_insert_with(|| sim.plant_mut().measure())
    }
}

impl Hal for HeldHal {
    fn name(&self) -> &'static str {
        "fmu"
    }
    fn read(&mut self, t: f64, period: f64) -> Result<Measurements, HalError> {
        match self.pending.take() {
            Some(m) => Ok(m),
            None => self.sim.read(t, period),
        }
    }
    fn write(&mut self, t: f64, period: f64, command: f64) -> Result<(), HalError> {
        self.pending = None;
        self.sim.write(t, period, command)
    }
    fn safe_stop(&mut self, command: f64) -> Result<(), HalError> {
        self.sim.safe_stop(command)
    }
    fn plant_state(&self) -> Option<PlantState> {
        self.sim.plant_state()
    }
}

/// The model from the end of initialisation.
struct Sim {
    hal: HeldHal,
    controller: Controller,
    supervisor: Supervisor,
    setpoint: Setpoint,
    from_config: bool,
    timebase: Timebase,
    /// The next control cycle.
    k: u64,
    /// The command applied over the last cycle (V).
    command: f64,
    tripped: bool,
    /// The operating point the plant was built at.
    point: BTreeMap<String, f64>,
}

/// One instance.
pub struct Instance {
    variant: Variant,
    cfg: RigConfig,
    vars: Vec<Var>,
    values: Vec<Value>,
    mode: Mode,
    sim: Option<Sim>,
    start_time: f64,
    /// Events to hand to the host's logger (trips), taken by the C boundary.
    pub events: Vec<String>,
    /// Where the valve command, the setpoint and its rate are in `values` (looked up once:
    /// a step reads them without searching the table).
    inputs: [Option<usize>; 3],
}

/// The FMU's resources as the library reads them: the config text and the variant.
pub fn read_resources(dir: &Path) -> Result<(String, Variant), String> {
    let cfg_path = dir.join("config.toml");
    let text = std::fs::read_to_string(&cfg_path)
        .map_err(|e| format!("cannot read {}: {e}", cfg_path.display()))?;
    let var_path = dir.join("variant");
    let v = std::fs::read_to_string(&var_path)
        .map_err(|e| format!("cannot read {}: {e}", var_path.display()))?;
    let variant = Variant::parse(&v).ok_or_else(|| {
        format!(
            "{}: `{}` is no variant; expected `plant` or `closed_loop`",
            var_path.display(),
            v.trim()
        )
    })?;
    Ok((text, variant))
}

impl Instance {
    /// An instance of the FMU whose resources are `config_text` and `variant`; `guid` is
    /// the host's (from the model description) and must match.
    pub fn new(config_text: &str, variant: Variant, guid: &str) -> Result<Instance, String> {
        let expected = crate::xml::guid(config_text, variant);
        if guid != expected {
            return Err(format!(
                "fmuGUID {guid} does not match the FMU's resources ({expected}): the modelDescription.xml and resources/config.toml come from different exports"
            ));
        }
        let cfg = RigConfig::from_toml_str(config_text)
            .map_err(|e| format!("resources/config.toml: {e}"))?;
        let vars = crate::variables::table(&cfg, variant);
        let values = vars.iter().map(|v| v.start).collect();
        let at = |role: Role| vars.iter().position(|v| v.role == role);
        let inputs = [
            at(Role::Command),
            at(Role::Setpoint),
            at(Role::SetpointRate),
        ];
        Ok(Instance {
            inputs,
            variant,
            cfg,
            vars,
            values,
            mode: Mode::Instantiated,
            sim: None,
            start_time: 0.0,
            events: Vec::new(),
        })
    }

    /// The present mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// fmi2SetupExperiment: the time of the first communication point (s).
    pub fn setup(&mut self, start_time: f64) -> Result<(), String> {
        if self.mode != Mode::Instantiated {
            return Err(format!(
                "fmi2SetupExperiment in state {:?}; it needs the instantiated state",
                self.mode
            ));
        }
        if !start_time.is_finite() {
            return Err(format!("startTime {start_time} s is not finite"));
        }
        self.start_time = start_time;
        Ok(())
    }

    /// fmi2EnterInitializationMode.
    pub fn enter_init(&mut self) -> Result<(), String> {
        if self.mode != Mode::Instantiated {
            return Err(format!(
                "fmi2EnterInitializationMode in state {:?}; it needs the instantiated state",
                self.mode
            ));
        }
        self.mode = Mode::Initialization;
        Ok(())
    }

    /// fmi2Terminate.
    pub fn terminate(&mut self) -> Result<(), String> {
        if self.mode != Mode::StepComplete {
            return Err(format!(
                "fmi2Terminate in state {:?}; it needs a stepping instance",
                self.mode
            ));
        }
        self.mode = Mode::Terminated;
        Ok(())
    }

    /// fmi2Reset: back to the state after instantiation, every value at its start.
    pub fn reset(&mut self) {
        self.values = self.vars.iter().map(|v| v.start).collect();
        self.sim = None;
        self.mode = Mode::Instantiated;
        self.start_time = 0.0;
        self.events.clear();
    }

    /// The variable of value reference `vr`.
    fn var(&self, vr: u32) -> Result<&Var, String> {
        self.vars.get(vr as usize).ok_or_else(|| {
            format!(
                "value reference {vr} does not exist; this FMU has 0 to {}",
                self.vars.len().saturating_sub(1)
            )
        })
    }

    /// Set the variable `vr` to `value` (of its type), checked: a parameter only before
    /// the end of initialisation and within its registry range, the command finite and
    /// within ± the valve's full scale, an operating input fixed after initialisation.
    pub fn set(&mut self, vr: u32, value: Value) -> Result<(), String> {
        let var = self.var(vr)?;
        let name = &var.name;
        if std::mem::discriminant(&var.start) != std::mem::discriminant(&value) {
            return Err(format!(
                "`{name}` is a {:?}-typed variable; it was set as {value:?}",
                var.start
            ));
        }
        let fixed = self.mode == Mode::StepComplete || self.mode == Mode::Terminated;
        match &var.role {
            Role::Output(_) => return Err(format!("`{name}` is an output; it cannot be set")),
            Role::Param(_) | Role::SetpointFromConfig if fixed => {
                return Err(format!(
                    "`{name}` is a fixed parameter; set it before fmi2ExitInitializationMode (or after fmi2Reset)"
                ))
            }
            _ => {}
        }
        let numeric = match value {
            Value::Real(x) => Some(x),
            Value::Integer(i) => Some(i as f64),
            Value::Boolean(_) => None,
        };
        if let Some(x) = numeric {
            // The full scale as the parameters set it from the end of initialisation.
            let full_scale = self
                .sim
                .as_ref()
                .map_or(self.cfg.plant.valve.command_full_scale, |s| {
                    s.hal.sim.plant().params().valve.command_full_scale
                });
            check_value(var, x, full_scale)?;
            if let (Role::Operating(op), Some(sim)) = (&var.role, &self.sim) {
                if sim.point.get(op) != Some(&x) {
                    return Err(format!(
                        "operating input `{name}` = {x} {}: it sets the plant's parameters, which are fixed from the end of initialisation (at {} {}); set it before fmi2ExitInitializationMode",
                        var.unit,
                        sim.point.get(op).copied().unwrap_or(f64::NAN),
                        var.unit
                    ));
                }
            }
        }
        self.values[vr as usize] = value;
        Ok(())
    }

    /// The value of `vr`: an output from the model (its start before the end of
    /// initialisation), an input or parameter as set.
    pub fn get(&mut self, vr: u32) -> Result<Value, String> {
        let Role::Output(out) = self.var(vr)?.role else {
            return Ok(self.values[vr as usize]);
        };
        let Some(sim) = self.sim.as_mut() else {
            return Ok(self.values[vr as usize]);
        };
        let m = sim.hal.peek();
        let s = sim.hal.sim.plant().state();
        Ok(match out {
            Out::X => Value::Real(s.x),
            Out::V => Value::Real(s.v),
            Out::PA => Value::Real(s.p_a),
            Out::PB => Value::Real(s.p_b),
            Out::ForceMeasured => Value::Real(m.force),
            Out::ForceLoad => Value::Real(s.rod_force),
            Out::PositionMeasured => Value::Real(m.position),
            Out::PAMeasured => Value::Real(m.p_a),
            Out::PBMeasured => Value::Real(m.p_b),
            Out::LoopCommand => Value::Real(sim.command),
            Out::Trip => Value::Boolean(sim.tripped),
        })
    }

    /// The config as the parameters now set it, at the operating point the inputs set.
    fn config_as_set(&self) -> Result<(RigConfig, BTreeMap<String, f64>), String> {
        let mut tree = self.cfg.to_value();
        let mut point = BTreeMap::new();
        for (var, value) in self.vars.iter().zip(&self.values) {
            match (&var.role, value) {
                (Role::Param(path), v) => {
                    let slot = ehactl_config::tree::get_mut(&mut tree, path)
                        .ok_or_else(|| format!("`{path}` is not in the config"))?;
                    *slot = match *v {
                        Value::Real(x) => toml::Value::Float(x),
                        Value::Integer(i) => toml::Value::Integer(i),
                        Value::Boolean(b) => toml::Value::Boolean(b),
                    };
                }
                (Role::Operating(name), Value::Real(x)) => {
                    point.insert(name.clone(), *x);
                }
                _ => {}
            }
        }
        let mut cfg = RigConfig::from_value(tree)
            .map_err(|e| format!("the parameters as set are refused: {e}"))?;
        cfg.plant = ehactl_config::inputs::plant_at(&cfg.inputs, &cfg.plant, &point)?;
        Ok((cfg, point))
    }

    /// fmi2ExitInitializationMode: build the model from the config as set.
    pub fn exit_init(&mut self) -> Result<(), String> {
        if self.mode != Mode::Initialization {
            return Err(format!(
                "fmi2ExitInitializationMode in state {:?}; it needs initialisation mode",
                self.mode
            ));
        }
        let (cfg, point) = self.config_as_set()?;
        let timebase = cfg.timebase();
        let plant = ehactl_plant::Plant::configure(&cfg.plant, timebase.period())
            .map_err(|e| format!("the plant is refused: {e}"))?;
        let controller = cfg.controller();
        let supervisor = Supervisor::new(&cfg.supervisor_settings(), controller.feedback_channel());
        let from_config = self
            .vars
            .iter()
            .zip(&self.values)
            .any(|(v, x)| v.role == Role::SetpointFromConfig && *x == Value::Boolean(true));
        let mut sim = Sim {
            hal: HeldHal {
                sim: SimHal::new(plant),
                pending: None,
            },
            controller,
            supervisor,
            setpoint: Setpoint::new(&cfg.setpoint),
            from_config,
            timebase,
            k: 0,
            command: 0.0,
            tripped: false,
            point,
        };
        sim.hal.peek();
        self.sim = Some(sim);
        self.mode = Mode::StepComplete;
        Ok(())
    }

    /// The number of control periods in a step of `h` (s) from `t` (s); an error unless `t`
    /// is the instance's time and `h` a whole number (≥ 1) of periods.
    fn cycles_of(&self, sim: &Sim, t: f64, h: f64) -> Result<u64, String> {
        let dt = sim.timebase.period();
        let now = self.start_time + sim.timebase.time_of(sim.k);
        if !(t.is_finite() && (t - now).abs() <= 1e-6 * dt) {
            return Err(format!(
                "fmi2DoStep from t = {t} s, but the FMU is at t = {now} s (a step starts where the last one ended)"
            ));
        }
        let n = h / dt;
        let whole = n.round();
        if !(h.is_finite() && whole >= 1.0 && (n - whole).abs() <= 1e-6 * whole) {
            return Err(format!(
                "step size {h} s is not a whole multiple of the control period {dt} s (run.control_rate_hz = {} Hz); expected k · {dt} s with k ≥ 1",
                sim.timebase.rate_hz()
            ));
        }
        Ok(whole as u64)
    }

    /// fmi2DoStep from `t` over `h` (s).
    pub fn do_step(&mut self, t: f64, h: f64) -> Result<(), String> {
        if self.mode != Mode::StepComplete {
            return Err(format!(
                "fmi2DoStep in state {:?}; it needs fmi2ExitInitializationMode first",
                self.mode
            ));
        }
        let Some(sim) = self.sim.as_ref() else {
            return Err("no model: fmi2ExitInitializationMode did not succeed".into());
        };
        let n = self.cycles_of(sim, t, h)?;
        let input = |i: Option<usize>| match i.map(|i| self.values[i]) {
            Some(Value::Real(x)) => x,
            _ => 0.0,
        };
        let [u, r, rdot] = self.inputs.map(input);
        let held = (r, rdot);
        let variant = self.variant;
        let Some(sim) = self.sim.as_mut() else {
            return Err("no model".into());
        };
        match variant {
            Variant::Plant => hold(sim, n, u),
            Variant::ClosedLoop if sim.tripped => {
                let safe = sim.supervisor.safe_command();
                hold(sim, n, safe)
            }
            Variant::ClosedLoop => {
                let trip = close_loop(sim, n, held)?;
                if let Some(ev) = trip {
                    self.events.push(ev);
                }
                Ok(())
            }
        }
    }
}

/// Check a Real or Integer value `x` for `var`: finite, within the registry range of a
/// parameter, within ± `full_scale` (V) for the valve command.
fn check_value(var: &Var, x: f64, full_scale: f64) -> Result<(), String> {
    let name = &var.name;
    if !x.is_finite() {
        return Err(format!(
            "`{name}` = {x} {} is not finite; expected a finite number",
            var.unit
        ));
    }
    if let Some(range) = var.range {
        if !range.admits(x) {
            return Err(format!(
                "`{name}` = {x} {} is out of range; expected {} (`ehactl params`)",
                var.unit,
                range.describe()
            ));
        }
    }
    if var.role == Role::Command && x.abs() > full_scale {
        return Err(format!(
            "valve command u = {x} V is out of range; expected |u| ≤ {full_scale} V (valve.command_full_scale)"
        ));
    }
    Ok(())
}

/// `n` cycles of the plant with the valve at `u` (V): read (the held measurement), write.
fn hold(sim: &mut Sim, n: u64, u: f64) -> Result<(), String> {
    let dt = sim.timebase.period();
    for _ in 0..n {
        let t = sim.timebase.time_of(sim.k);
        sim.hal.read(t, dt).map_err(|e| format!("t = {t} s: {e}"))?;
        sim.hal
            .write(t, dt, u)
            .map_err(|e| format!("t = {t} s: the plant failed: {e}"))?;
        sim.command = u;
        sim.k += 1;
    }
    sim.hal.peek();
    Ok(())
}

/// `n` cycles of the closed loop from cycle `sim.k` (`ehactl run`'s cycle,
/// `step_cycles`), the setpoint `held` unless it comes from the config. A trip holds the
/// valve at the safe command for the rest of the step and from then on; it is returned as
/// text for the host's log.
fn close_loop(sim: &mut Sim, n: u64, held: (f64, f64)) -> Result<Option<String>, String> {
    let held = (!sim.from_config).then_some(held);
    let (k0, dt) = (sim.k, sim.timebase.period());
    let mut command = sim.command;
    let r = ehactl_runtime::runloop::step_cycles(
        &mut sim.hal,
        &mut sim.controller,
        &sim.setpoint,
        held,
        &mut sim.supervisor,
        (sim.timebase, k0, n),
        &mut |rec| command = rec.command,
        &mut |_| {},
    );
    sim.command = command;
    match r {
        Ok(k) => {
            sim.k = k;
            sim.hal.peek();
            Ok(None)
        }
        Err(ev) => {
            sim.tripped = true;
            // The plant has advanced by the cycles that wrote a command; the rest of the
            // step holds the safe command.
            let done = (sim.hal.sim.plant().state().t / dt).round() as u64;
            let end = k0 + n;
            sim.k = done.min(end);
            let safe = sim.supervisor.safe_command();
            hold(sim, end - sim.k, safe)?;
            Ok(Some(format!(
                "supervisor trip at t = {} s (cycle {}): {:?} on {} ({} {}, limit {} {}); the valve holds the safe command {safe} V",
                ev.t, ev.cycle, ev.kind, ev.channel, ev.value, ev.unit, ev.limit, ev.unit
            )))
        }
    }
}
