//! Free parameters of a fit: a dotted config path with bounds, scale, start value and the
//! setter that writes it (through the declared-parameter accessors of
//! `ehactl_plant::spec::ParamTree`), and the rig scales that bound them. Used by the nominal
//! refit ([`crate::fit`]) and by every catalogue effect's module ([`crate::effects`]).

use crate::data::Record;
use ehactl_plant::params::Effects;
use ehactl_plant::spec::ParamTree;
use ehactl_plant::{EffectId, PlantParams};
use std::sync::Arc;

/// Writes a free parameter's value into the plant parameters.
pub type Setter = Arc<dyn Fn(&mut PlantParams, f64) + Send + Sync>;

/// One free parameter: dotted config path, bounds (SI), scale, start value and how to set it.
#[derive(Clone)]
pub struct FreeParam {
    /// Dotted config path (or `<path>/nominal` for a factor on the nominal value).
    pub name: String,
    /// Lower bound (SI or factor).
    pub lo: f64,
    /// Upper bound.
    pub hi: f64,
    /// Search in log space (bounds must be > 0).
    pub log: bool,
    /// Start value.
    pub init: f64,
    /// Writes the value into the parameters.
    pub set: Setter,
}

impl std::fmt::Debug for FreeParam {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ∈ [{}, {}]", self.name, self.lo, self.hi)
    }
}

impl FreeParam {
    pub(crate) fn new(name: &str, lo: f64, hi: f64, log: bool, init: f64, set: Setter) -> Self {
        // Bounds derived from the data (e.g. a tone frequency up to Nyquist) can cross on
        // odd records: the parameter is then pinned at `lo` instead of panicking in clamp.
        let hi = if hi >= lo { hi } else { lo };
        Self {
            name: name.to_string(),
            lo,
            hi,
            log,
            init: init.clamp(lo, hi),
            set,
        }
    }
    /// Value → normalised coordinate in [0, 1].
    pub fn to_unit(&self, v: f64) -> f64 {
        let v = v.clamp(self.lo, self.hi);
        if self.hi <= self.lo {
            return 0.0;
        }
        if self.log {
            (v / self.lo).ln() / (self.hi / self.lo).ln()
        } else {
            (v - self.lo) / (self.hi - self.lo)
        }
    }
    /// Normalised coordinate → value.
    pub fn from_unit(&self, s: f64) -> f64 {
        let s = s.clamp(0.0, 1.0);
        if self.log {
            self.lo * (self.hi / self.lo).powf(s)
        } else {
            self.lo + s * (self.hi - self.lo)
        }
    }
}

impl FreeParam {
    /// The declared float parameter at `path` (bounds, log scale, start value), written
    /// through the accessor `#[derive(Params)]` generates from its field declaration; see
    /// [`write()`].
    pub(crate) fn at(
        path: &'static str,
        bounds: (f64, f64, bool, f64),
        seed: &PlantParams,
    ) -> Self {
        Self::at_then(path, bounds, seed, |_| {})
    }
    /// As [`FreeParam::at`], then `then` (structural variant, coupled fields).
    pub(crate) fn at_then(
        path: &'static str,
        (lo, hi, log, init): (f64, f64, bool, f64),
        seed: &PlantParams,
        then: impl Fn(&mut PlantParams) + Send + Sync + 'static,
    ) -> Self {
        Self::new(path, lo, hi, log, init, write(path, seed, then))
    }
}

/// Setter of the declared float parameter at `path` (`ehactl_plant::spec::ParamTree`): an
/// effect section the parameters lack is first copied from `seed` (the section the fit starts
/// from), the value is written, the effect is switched on (`enabled = true`), then `then`
/// runs. The path is checked against the registry when the fit is set up (debug builds) and
/// by `every_setter_writes_its_declared_parameter` in `crate::fit`'s tests.
pub(crate) fn write(
    path: &'static str,
    seed: &PlantParams,
    then: impl Fn(&mut PlantParams) + Send + Sync + 'static,
) -> Setter {
    debug_assert!(
        PlantParams::knows(path),
        "{path} is not a declared parameter"
    );
    let id = path
        .strip_prefix("effects.")
        .and_then(|r| r.split('.').next())
        .and_then(EffectId::parse);
    let seed = seed.clone();
    Arc::new(move |p, v| {
        // Cannot fail for a declared path whose section `seed` holds (tested below).
        let written = p.set_path_or_insert(path, v, &seed);
        debug_assert!(written.is_ok(), "{written:?}");
        if let Some(on) = id.and_then(|id| p.effects.enabled_mut(id)) {
            *on = true;
        }
        then(p);
    })
}

/// `nominal` with its effect sections changed by `f`: the seed a fit's setters copy an
/// absent section from.
pub(crate) fn seeded(nominal: &PlantParams, f: impl FnOnce(&mut Effects)) -> PlantParams {
    let mut seed = nominal.clone();
    f(&mut seed.effects);
    seed
}

/// Scales of the rig used to bound effect parameters.
#[derive(Debug, Clone, Copy)]
pub struct Scales {
    /// Supply pressure × cap area (N).
    pub force: f64,
    /// Edge flow at full opening and Δp = p_s/2 (m³/s).
    pub flow: f64,
    /// Supply pressure (Pa).
    pub pressure: f64,
    /// Moving mass (kg).
    pub mass: f64,
    /// Hydraulic stiffness at the initial position (N/m).
    pub stiffness: f64,
    /// Sample period (s).
    pub dt: f64,
    /// Largest spool target the record's valve command reaches, as a fraction of full travel
    /// (|u| / `valve.command_full_scale`), in the positive and the negative direction (-).
    /// A travel limit above it never clips the recorded command: the fit cost is flat there.
    pub spool_reach: [f64; 2],
}

impl Scales {
    /// Derive from the nominal parameters and the record.
    pub fn new(p: &PlantParams, rec: &Record) -> Self {
        let law = ehactl_plant::valve::EdgeLaw::new(p);
        let ps = p.supply.pressure - p.supply.tank_pressure;
        let flow = law.k * (0.5 * ps).powf(law.n);
        let stiffness = ehactl_plant::Plant::configure(p, rec.dt)
            .map(|pl| pl.hydraulic_stiffness(p.cylinder.initial_position))
            .unwrap_or(1e7)
            + p.mechanics.load_stiffness;
        let fs = p.valve.command_full_scale;
        let reach = |sign: f64| {
            rec.u
                .iter()
                .map(|u| sign * u / fs)
                .filter(|s| s.is_finite())
                .fold(0.0, f64::max)
        };
        Self {
            force: ps * p.cylinder.area_a,
            flow,
            pressure: ps,
            mass: p.mechanics.mass,
            stiffness,
            dt: rec.dt,
            spool_reach: [reach(1.0), reach(-1.0)],
        }
    }
}
