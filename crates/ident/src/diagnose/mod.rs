//! The diagnosis: replay, residual analysis, hypothesis fits for every catalogue effect,
//! held-out scoring with a parameter penalty, greedy acceptance.
//!
//! Typed phases (`Phase`), one file each, called in order by `pipeline`; the contract is
//! written in ARCHITECTURE.md "The diagnosis as phases". A new phase: its file here and its
//! one line in the `phases!` list below the `Phase` trait, which declares the file's module
//! and calls the phase in `pipeline`.

use crate::analysis::{analyse, Analysis};
use crate::baseline::Baseline;
pub use crate::ctx::Errors;
use crate::ctx::{errors, Ctx, Hyp};
use crate::data::Record;
use crate::fit::{base_params, effect_variants, Scales};
use crate::progress::Tracker;
use crate::replay::{overall, replay_params, replay_with, std, Drive, Replay};
use ehactl_plant::{EffectId, PlantParams};
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

// The phases' own modules are declared by `phases!` (below `Phase`); these are the tools
// they share and the report.
mod judge;
mod report;
mod round;
mod summary;

pub use judge::WEIGHTED_EXPLAINED;
use judge::*;
use round::*;
use summary::*;

/// A model whose held-out NRMSE is below this factor × the estimated noise floor on every
/// channel is not extended further (-); the detection limits judge with the same.
pub const FLOOR_FACTOR: f64 = crate::limits::FLOOR_FACTOR;

/// The configured-step shortcut accepts the model as configured only while every channel's
/// held-out residual is white and at most this many times its noise floor (-). The floor is
/// the residual's own white level (PSD median over the upper half band), so a white residual
/// sits at ≈ 1; 1.5 leaves room for the median estimate's spread on short records.
pub const SHORTCUT_LEVEL: f64 = 1.5;

/// Whiteness bound of the shortcut (-): the 99.9 % quantile of χ² with 20 degrees of freedom
/// (NIST/SEMATECH e-Handbook §1.3.6.7.4), stricter than the final test's 99 % because it is
/// applied to up to five channels and two drives at once, where a clean log of the
/// Cristofori crane config showed Q = 37.8 on `x`, just above the 99 % value 37.6. A channel at
/// or below its floor (level ≤ 1: a residual at the rounding or quantisation floor, whose
/// colour is the rounding's) needs no whiteness. The false-`none` records this rule refuses
/// had Q of 75 to 8·10⁴ on a channel 1.2–6× its floor.
pub const SHORTCUT_LB_CRIT: f64 = 45.315;

/// After the first accepted effect, the search also stops when the overall held-out NRMSE is
/// below this factor × the overall noise floor (-): the per-channel test alone lets a second
/// effect soak up the small remainder of an imperfect lumped fit on a low-noise channel.
pub const LATER_FLOOR_FACTOR: f64 = 1.5;

/// Evaluation budget of the nominal refit (the reference every effect must beat and the model
/// a `none` stands on) as a multiple of the candidates' per-parameter budget (-). With the
/// candidates' budget the simplex stopped short on clean test-bench records: the refit left a
/// position residual of 2.7× its floor, coloured (Ljung–Box Q ≈ 7900, seed 5075), which the
/// final test ([`crate::residual::LEVEL_SOFT`]) cannot call noise; with 4× and one restart it
/// left 1.09× (Q ≈ 180; DIAGNOSIS.md, "Small magnitudes").
pub const REFIT_BUDGET: usize = 4;

/// Restarts of the nominal refit from its own result while they lower the fitting cost (-): a
/// simplex that has collapsed short of the minimum is restarted from the point it claims
/// (Press et al., *Numerical Recipes* 3rd ed. §10.5).
pub const REFIT_RESTARTS: usize = 1;

/// Smallest noise floor of a channel (NRMSE units, -): a noise-free channel (a simulated log,
/// a spool signal) replayed by the same model still differs by rounding (≈ 1e-15 of its std in
/// a different order of operations); differences below this are numerically insignificant,
/// not a discrepancy.
pub const NUMERICAL_FLOOR: f64 = 1e-9;

/// Least share of a candidate's held-out gain that the effect itself must carry (-). A
/// candidate's fit also refits the nominal parameters; replayed with those parameters and
/// without the effect, the model must lose at least this share of the gain,
/// (J_without − J_with)/(J_current − J_with). Below it, the gain is the refit's (more
/// iterations from another start), not the effect's: a clean independent-rig record
/// (`bench/indep_cases.txt` seed 7086) had an internal leakage of 2e-16 m³/(s·Pa) accepted.
pub const MIN_EFFECT_SHARE: f64 = 0.5;

/// Settings of a diagnosis.
#[derive(Debug, Clone)]
pub struct Options {
    /// Fraction of the record held out for validation when no separate file is given (-).
    pub holdout: f64,
    /// Where progress reports go (default: nowhere; the front ends draw the bar).
    pub progress: crate::progress::ProgressSink,
    /// Worker threads for the candidate fits (0 = available cores).
    pub threads: usize,
    /// At most this many effects are accepted.
    pub max_effects: usize,
    /// Effects to test (default: the whole catalogue).
    pub effects: Vec<EffectId>,
    /// Nelder–Mead evaluation budget per free parameter (plus a fixed 60).
    pub evals_per_param: usize,
    /// Valve command during replay: recorded (open loop) or the rig's PD on `ref`.
    pub drive: Drive,
    /// At most this many samples from the start of the fitting part enter the fit cost (the
    /// held-out part is always scored whole); bounds the run time on long, fast records.
    pub max_fit_samples: usize,
    /// Estimate a constant offset per measured channel (transducer zero error) for every
    /// model on the fitting part and apply it to the held-out part too. Off by default: the
    /// sensors' zeros are trusted and a level shift counts as model error (on data with good
    /// zeros the offsets cost accuracy, see DIAGNOSIS.md).
    pub sensor_offsets: bool,
    /// Largest replay cost factor (substeps / the config's substeps) the integration choice
    /// may spend to bring the replay's integration error below
    /// [`crate::replay::INTEGRATION_RATIO`] × the noise floor
    /// ([`crate::replay::choose_integration`]). Whatever error the chosen substeps leave is
    /// reported and added to the noise floor, so it is never blamed on an effect. Default
    /// [`crate::replay::DEFAULT_INTEGRATION_COST`].
    pub integration_max_cost: f64,
    /// Smallest replay cost factor the integration choice may take when the config's
    /// substeps are more accurate than required (0 = down to the stability guard
    /// [`crate::replay::REPLAY_MAX_OMEGA_H`]; 1 = never fewer than the config's, the library
    /// default: the evaluations' figures rest on it), see
    /// [`crate::replay::choose_integration_between`].
    pub integration_min_cost: f64,
    /// Run the grey-box extension ([`crate::greybox`]) when the catalogue is exhausted (the
    /// held-out residual of the catalogue model is not noise). Off in the library default
    /// (the synthetic suites measure the catalogue); on in `ehactl diagnose` and Python.
    pub greybox: bool,
    /// State the detection limit of every catalogue effect not named ([`crate::limits`]):
    /// about 100 replays of the held-out record more. On by default.
    pub detection_limits: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            holdout: 0.3,
            progress: crate::progress::ProgressSink::none(),
            threads: 0,
            max_effects: 3,
            effects: EffectId::ALL.to_vec(),
            evals_per_param: 30,
            drive: Drive::Recorded,
            max_fit_samples: 12_000,
            sensor_offsets: false,
            integration_max_cost: crate::replay::DEFAULT_INTEGRATION_COST,
            integration_min_cost: 1.0,
            greybox: false,
            detection_limits: true,
        }
    }
}

/// One hypothesis test.
#[derive(Debug, Clone, Serialize)]
pub struct Candidate {
    /// Effect id.
    pub effect: String,
    /// Structural variant of the effect that fitted best (`-` for effects with one form).
    pub variant: String,
    /// Fitted parameters (dotted path → value; `<path>/nominal` marks factors on nominal values).
    pub params: BTreeMap<String, f64>,
    /// Overall NRMSE on the fitting data (-).
    pub nrmse_train: f64,
    /// Overall NRMSE on the held-out data (-).
    pub nrmse_validation: f64,
    /// ln(J_validation) + 0.02·(free parameters) (lower is better; J = mean NRMSE²).
    pub score: f64,
    /// Whether the effect was accepted into the extended model.
    pub accepted: bool,
    /// One line: what the residual analysis and the fit say.
    pub evidence: String,
}

/// Full result of a diagnosis.
#[derive(Debug, Clone, Serialize)]
pub struct Diagnosis {
    /// Top effect id, `none` (the nominal model explains the data within the noise), the
    /// grey-box law in physical terms when no catalogue effect explains the data but the law
    /// does (its first term with value and unit, e.g. `load-side yield force 576 N (…)`), or
    /// `unexplained` (the residual is not noise and nothing explains it).
    pub cause: String,
    /// How far the answer goes: `none` (the residual is noise), `explained` (a catalogue
    /// effect or the grey-box law is the cause), `edge_fit` (the closest catalogue effect's fit
    /// sits on a bound of its range or outside what the record can show: `closest`, and the
    /// cause is `unexplained`), `not_explained` (the closest catalogue effect leaves a channel
    /// far above its noise floor: likewise) or `unexplained`.
    pub status: String,
    /// The closest catalogue effect when it is not the cause (`status` `edge_fit` or
    /// `not_explained`, or replaced by the grey-box law), with the reasons; `None` otherwise.
    pub closest: Option<crate::edge::Closest>,
    /// For every catalogue effect tested and not named: the smallest size of it this record
    /// would have revealed, in its own parameter and unit (`crate::limits`; effect id →
    /// limit). Empty when `Options::detection_limits` is off.
    pub detection_limits: BTreeMap<String, crate::limits::DetectionLimit>,
    /// The tests that would tighten the loose limits and separate the ambiguities, as
    /// `[setpoint]` sections for `ehactl run` ([`crate::nexttest`]).
    pub next_tests: Vec<crate::nexttest::NextTest>,
    /// Accepted effect ids, the one that explains most of the held-out error on the final model
    /// first (each removed in turn and the rest refit, `crate::weigh`); `cause` is the first.
    pub causes: Vec<String>,
    /// Structural variant of each accepted effect (effect id → variant, `-` for effects with
    /// one form; see DIAGNOSIS.md "Effect variants").
    pub variants: BTreeMap<String, String>,
    /// Nominal model (no refit) on the held-out data.
    pub nrmse_nominal: Errors,
    /// Nominal parameters refit within their stated uncertainty (`[uncertainty]`, default
    /// ±15 %), no effect added, on the held-out data.
    pub nrmse_refit: Errors,
    /// Extended model on the held-out data.
    pub nrmse_extended: Errors,
    /// Black-box baseline (linear ARX per channel, [`crate::baseline`]) fitted on the same
    /// fitting part and scored free-run on the same held-out data.
    pub nrmse_baseline: Errors,
    /// The baseline's structure and coefficients.
    pub baseline: Baseline,
    /// Whether the extended model's held-out residual is noise (level and whiteness per
    /// channel) and, if not, its signature.
    pub residual_test: crate::residual::ResidualTest,
    /// Replay accuracy: substeps chosen and the integration error left (step-halving test).
    pub integration: crate::replay::IntegrationCheck,
    /// Grey-box extension (a rod-force law from a library of physical-state terms) when the
    /// catalogue was exhausted; `None` when it did not run. When accepted, `extended`,
    /// `extended_params` and the extended traces include it; `nrmse_extended` stays the
    /// catalogue model's figure and `greybox.nrmse_validation` is the combined model's.
    pub greybox: Option<crate::greybox::GreyBox>,
    /// 1 − overall_extended/overall_nominal (-).
    pub gain: f64,
    /// Estimated noise floor of the overall held-out NRMSE (-).
    pub noise_floor: f64,
    /// Every catalogue effect tested against the refit nominal model.
    pub candidates: Vec<Candidate>,
    /// Parameters of the extended model (dotted path → value).
    pub extended_params: BTreeMap<String, f64>,
    /// The rig's loop identified on the position channel when the config marks it as an
    /// assumption (loop keys in `[uncertainty]` on a closed-loop replay, [`crate::loopid`]);
    /// `None` otherwise. Part of every model from the refit on.
    pub identified_loop: Option<crate::loopid::IdentifiedLoop>,
    /// Nominal parameters that the refit (no effect) left on a bound of their stated
    /// uncertainty (`[uncertainty]` in the config, default ±15 %): evidence of a missing effect.
    pub refit_at_bounds: Vec<String>,
    /// The same for the final (extended) model.
    pub extended_at_bounds: Vec<String>,
    /// Sensor offsets estimated with the extended model (measured − model on the fitting
    /// part), per channel in its SI unit (N, m, Pa); empty when `sensor_offsets` is off.
    pub sensor_offsets: BTreeMap<String, f64>,
    /// Effect pairs the data cannot separate, with the experiment that would.
    pub ambiguities: Vec<String>,
    /// Where the search went on from a better nominal fit than the refit's: a candidate whose
    /// gain its effect did not carry (`MIN_EFFECT_SHARE`), its fit without the effect becoming
    /// the current model; one sentence each, in order.
    pub refit_continued: Vec<String>,
    /// Catalogue effects accepted on the fitting part but dropped for a grey-box law that
    /// predicts the held-out part better, while they lost to the ARX baseline there.
    pub dropped_effects: Option<DroppedEffects>,
    /// Whether the catalogue model lost to the ARX baseline on the held-out part and no
    /// grey-box law beat the baseline either (the cause is then `unexplained`).
    pub beaten_by_baseline: bool,
    /// Warnings from loading and checking the data.
    pub warnings: Vec<String>,
    /// Residual analysis of the nominal replay (fitting part).
    pub analysis: Analysis,
    /// Residual analysis after refitting the nominal parameters (fitting part): the evidence.
    pub analysis_refit: Analysis,
    /// How the data were split.
    pub split: String,
    /// Plain-words conclusion.
    pub summary: String,
    /// Extended plant parameters (for the extended config).
    #[serde(skip)]
    pub extended: PlantParams,
    /// Replays over the fit record: nominal, extended (for plots).
    #[serde(skip)]
    pub traces: Traces,
}

/// Simulated traces for the report.
#[derive(Debug, Clone, Default)]
pub struct Traces {
    /// Fit record replay by the nominal model.
    pub nominal: Option<Replay>,
    /// Fit record replay by the extended model.
    pub extended: Option<Replay>,
    /// Validation record replays (nominal, extended) when a separate file was given.
    pub validation: Option<(Replay, Replay)>,
    /// First held-out sample index in the fit record (== len when a separate file is used).
    pub split_index: usize,
}

/// What every phase reads: the caller's inputs and the progress bar.
pub(crate) struct Inputs<'a> {
    /// The config's plant parameters (the loop phase's copy has the identified loop in).
    pub(crate) nominal: &'a PlantParams,
    /// The record fitted (and held out from, without `val`).
    pub(crate) rec: &'a Record,
    /// A separate held-out record.
    pub(crate) val: Option<&'a Record>,
    /// The settings.
    pub(crate) opts: &'a Options,
    bar: std::sync::OnceLock<Tracker>,
}

impl Inputs<'_> {
    /// The progress bar, started on the first call ([`pipeline`] starts it with the refit).
    pub(crate) fn bar(&self) -> &Tracker {
        self.bar
            .get_or_init(|| Tracker::new(&self.opts.progress, 1, "refit nominal"))
    }
}

/// Worker threads of a parallel stage: `Options::threads`, 0 meaning the available cores.
fn worker_threads(opts: &Options) -> usize {
    if opts.threads == 0 {
        std::thread::available_parallelism().map_or(2, |n| n.get())
    } else {
        opts.threads
    }
}

/// `f` of every job of `jobs` on `threads` workers, which take the jobs in the order `order`
/// (job indices, e.g. the longest first, so that no worker is left with a long job while the
/// other idles); `bar` advances once per job. Results are keyed by job index and returned in
/// job order, so the order of execution does not change them.
fn in_parallel<J: Sync, R: Send>(
    jobs: &[J],
    order: &[usize],
    threads: usize,
    bar: &Tracker,
    f: impl Fn(&J) -> R + Sync,
) -> Vec<(usize, R)> {
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<(usize, R)>> = Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..threads.min(jobs.len()).max(1) {
            s.spawn(|| loop {
                let k = next.fetch_add(1, Ordering::SeqCst);
                let Some(&i) = order.get(k) else {
                    break;
                };
                let r = f(&jobs[i]);
                if let Ok(mut out) = results.lock() {
                    out.push((i, r));
                }
                bar.inc();
            });
        }
    });
    let mut results = results.into_inner().unwrap_or_default();
    results.sort_by_key(|r| r.0);
    results
}

/// One phase of the diagnosis (ARCHITECTURE.md "The diagnosis as phases"): a type that reads
/// the inputs and the earlier phases' results by shared reference and returns its own.
pub(crate) trait Phase<'a>: Sized {
    /// The earlier phases' results it reads: `()` or a tuple of shared references (`Copy`, so
    /// that a phase can never take an earlier result by `&mut`).
    type Needs<'p>: Copy
    where
        'a: 'p;

    /// Runs the phase.
    fn run(inp: &Inputs<'a>, needs: Self::Needs<'_>) -> Result<Self, String>;
}

/// Run the diagnosis. `val` is an optional separate validation record; without it the last
/// `opts.holdout` of `rec` is held out. The phases, in the order `pipeline` calls them:
/// `NominalPhase` (split, replay accuracy, nominal replay, residual analysis, ARX baseline),
/// `LoopPhase` (an assumed loop identified first, on its own output, and kept by every later
/// model), `RefitPhase` (nominal parameters refit within their stated uncertainty, noise
/// floor), `SearchPhase` (greedy rounds; each round fits every catalogue effect in each of
/// its structural variants), `ResidualPhase` (`none` / `unexplained`), `ClosestPhase`,
/// `GreyPhase` (the grey-box law), `LimitsPhase` (detection limits), `ReloopPhase` (the loop
/// again with a law in place), then the report.
pub fn diagnose(
    nominal: &PlantParams,
    rec: &Record,
    val: Option<&Record>,
    opts: &Options,
) -> Result<Diagnosis, String> {
    let inp = Inputs {
        nominal,
        rec,
        val,
        opts,
        bar: std::sync::OnceLock::new(),
    };
    pipeline(&inp)
}

/// Declares the phases and the pipeline that runs them. Each phase is one line,
/// `module::Type(needs…) => name;`: the line declares `mod module;` (the phase's file beside
/// this one) with a glob import of it, and in `pipeline` runs `Type::run(inp, (&need, …))`
/// and binds its result to `name`, which later lines may list among their needs. The needs
/// are the `Phase::Needs` tuple in order, so a line that names the wrong results, or an
/// earlier result that does not exist yet, does not compile. A `{ … }` between the lines is
/// pasted into `pipeline` as it stands (the glue that is no phase); the last one ends it with
/// the result.
macro_rules! phases {
    ($(#[$meta:meta])* fn $name:ident($inp:ident) { $($list:tt)* }) => {
        phases!(@mods $($list)*);
        phases!(@fn $inp [$(#[$meta])* fn $name] [] $($list)*);
    };
    (@mods) => {};
    (@mods $m:ident :: $t:ident ($($need:ident),*) => $bind:ident; $($rest:tt)*) => {
        mod $m;
        use $m::*;
        phases!(@mods $($rest)*);
    };
    (@mods { $($glue:tt)* } $($rest:tt)*) => {
        phases!(@mods $($rest)*);
    };
    // The body, statement by statement into the brackets, then the function.
    (@fn $inp:ident $head:tt [$($body:tt)*]
        $m:ident :: $t:ident ($($need:ident),*) => $bind:ident; $($rest:tt)*) => {
        phases!(@fn $inp $head [$($body)* let $bind = $m::$t::run($inp, ($(&$need,)*))?;]
            $($rest)*);
    };
    (@fn $inp:ident $head:tt [$($body:tt)*] { $($glue:tt)* } $($rest:tt)*) => {
        phases!(@fn $inp $head [$($body)* $($glue)*] $($rest)*);
    };
    (@fn $inp:ident [$(#[$meta:meta])* fn $name:ident] [$($body:tt)*]) => {
        $(#[$meta])*
        fn $name($inp: &Inputs<'_>) -> Result<Diagnosis, String> {
            $($body)*
        }
    };
}

phases! {
    /// The phases in order, each on the results of those before it.
    fn pipeline(inp) {
        nominal::NominalPhase() => nom;
        { inp.bar(); }
        loop_id::LoopPhase(nom) => lp;
        refit::RefitPhase(nom, lp) => rf;
        search::SearchPhase(nom, lp, rf) => search;
        residual_test::ResidualPhase(nom, lp, rf, search) => resid;
        closest::ClosestPhase(nom, rf, search, resid) => closest;
        grey::GreyPhase(nom, lp, rf, search, resid, closest) => grey;
        {
            // When the law alone wins, the refit's search and residual test replace the
            // catalogue model's for every later phase.
            let (search, resid) = grey.kept(search, resid);
        }
        limits::LimitsPhase(nom, lp, rf, search, grey) => limits;
        reloop::ReloopPhase(nom, lp, grey) => reloop;
        {
            let phases = report::Phases {
                nom,
                lp,
                rf,
                search,
                resid,
                closest,
                grey,
                limits,
                reloop,
            };
            let mut d = report::assemble(inp, phases);
            d.next_tests =
                crate::nexttest::next_tests(&d.ambiguities, &d.detection_limits, inp.rec);
            Ok(d)
        }
    }
}

/// Catalogue effects dropped for a grey-box law: they predicted the held-out part worse than
/// the ARX baseline, and the law alone (on the nominal refit) predicted it better than the
/// catalogue model with or without a law on top.
#[derive(Debug, Clone, Serialize)]
pub struct DroppedEffects {
    /// The effect ids that had been accepted on the fitting part.
    pub effects: Vec<String>,
    /// Held-out overall NRMSE of the catalogue model with them (-).
    pub nrmse_catalogue: f64,
    /// Held-out overall NRMSE of the catalogue model with a grey-box law on top, when one was
    /// accepted there (-).
    pub nrmse_catalogue_with_law: Option<f64>,
    /// Held-out overall NRMSE of the grey-box law on the nominal refit alone, the kept model (-).
    pub nrmse_law: f64,
    /// Held-out overall NRMSE of the ARX baseline (-).
    pub nrmse_baseline: f64,
    /// Why the catalogue model had to compete: it predicts worse than the ARX baseline, or
    /// an accepted effect was weak evidence (its fit at a corner of its range, or most of the
    /// error above the floor left unexplained).
    pub why: String,
}
