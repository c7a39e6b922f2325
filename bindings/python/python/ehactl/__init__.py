"""ehactl: simulate, tune and analyse electro-hydraulic force / position loops from Python.

The package wraps the compiled Rust crates that run the 5 kHz loop (``ehactl-plant``,
``ehactl-control``, ``ehactl-runtime``, ``ehactl-hal``), so a gain tuned here is exactly the one the CLI
and the real-time loop use. Units are SI throughout: s, N, m, Pa, V, m³/s.

    import ehactl
    cfg = ehactl.Config.load("configs/sahu2022_force.toml")
    cfg["control.pi.kp"] = 0.4                    # V/V
    res = ehactl.run(cfg, duration=1.0)           # GIL released while Rust simulates
    res.t, res.force, res.u                       # NumPy arrays (s, N, V)
    many = ehactl.run_many({"control.pi.kp": [0.3, 0.4, 0.5]}, base=cfg, duration=0.5)

``ehactl.export_fmu(cfg, "rig.fmu")`` writes the config as an FMI 2.0 co-simulation FMU, as
``ehactl export-fmu`` does (docs/fmu.md).

``ehactl.analyze(cfg)``, ``ehactl.sweep(cfg, ...)`` and ``ehactl.diagnose(cfg, data)`` mirror
``ehactl analyze`` / ``ehactl sweep`` / ``ehactl diagnose`` (margins and bandwidths of the
linearised sampled loop; stepped-sine frequency response of the nonlinear plant; model
discrepancy on measured data). They return immutable result objects (:mod:`ehactl.results`)
with the CLI's JSON fields as attributes, units in the names and docstrings, ``to_dict()``
(the CLI's JSON) and ``to_pandas()``:

    a = ehactl.analyze(cfg)
    a.phase_margin_deg, a.gain_crossover_hz       # deg, Hz (sampled loop)
    sw = ehactl.sweep(cfg, 5.0, 300.0, points=12)
    sw.frf.f_hz, sw.frf.mag_db, sw.bandwidth_hz   # NumPy arrays (Hz, dB), Hz

Submodules: :mod:`ehactl.results` (the result classes), :mod:`ehactl.tune` (critical-gain, model-based and optimisation tuning),
:mod:`ehactl.metrics` (step / tracking metrics), :mod:`ehactl.plot` (matplotlib figures,
optional dependency).
"""

from __future__ import annotations

from types import ModuleType

from ._ehactl import (  # noqa: F401  (re-exported)
    Config,
    NumericalError,
    Plant,
    __version__,
)
from ._analysis import analyze, diagnose, diagnose_many, sweep
from ._fmu import export_fmu
from ._campaign import CampaignResult, PredictionResult, RecordPrediction, campaign, predict
from ._runs import RunResult, param_grid, params, read_mcap, results_frame, run, run_many
from . import results
from .results import AnalysisResult, DiagnosisResult, RunSummary, SweepResult

__all__ = [
    "AnalysisResult",
    "Config",
    "DiagnosisResult",
    "NumericalError",
    "Plant",
    "RunResult",
    "RunSummary",
    "SweepResult",
    "__version__",
    "analyze",
    "diagnose",
    "campaign",
    "predict",
    "export_fmu",
    "CampaignResult",
    "PredictionResult",
    "RecordPrediction",
    "diagnose_many",
    "param_grid",
    "params",
    "read_mcap",
    "results_frame",
    "run",
    "run_many",
    "sweep",
    "tune",
    "metrics",
    "plot",
    "results",
]


def __getattr__(name: str) -> ModuleType:
    # Lazy submodules: `ehactl.plot` imports matplotlib only when used.
    if name in ("tune", "metrics", "plot"):
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'ehactl' has no attribute {name!r}")
