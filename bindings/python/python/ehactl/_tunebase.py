"""What :mod:`ehactl.tune` and :mod:`ehactl._freq` share: the gain paths of a control mode,
the step and tracking experiments that score gains on the nonlinear plant, their scoring,
:class:`TuneResult` and its assembly, and the identification copy of a config.

Both modules import it one way (tune → _freq → here, tune → here); :mod:`ehactl.tune`
re-exports the public names, which is where users find them.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from . import metrics as _m
from ._ehactl import Config
from ._runs import ConfigLike, RunResult, _as_config, run_many


def gain_paths(cfg: Config) -> tuple[str, str]:
    """Dotted paths of the two tuned gains for the config's control mode."""
    if cfg.mode == "force":
        return ("control.pi.kp", "control.pi.integral")
    if cfg.mode == "position":
        return ("control.pd.kp", "control.pd.td")
    raise ValueError("tuning needs control.mode = \"force\" or \"position\" (open_loop has no gains)")


@dataclass
class StepTest:
    """The step experiment that scores gains on the nonlinear plant.

    ``initial`` → ``final`` (N or m) at ``start`` (s), run for ``duration`` (s); the error
    is measured on the ground-truth column ``signal`` (``rod_force`` or ``x``). If
    ``vibration_from`` (s) is set, vibration metrics of ``signal`` after that time are added,
    with the amplitude of the ``vibration_frequency`` (Hz) component when given.
    """

    initial: float
    final: float
    start: float
    duration: float
    signal: str
    vibration_from: float | None = None
    vibration_frequency: float | None = None

    @classmethod
    def default(cls, cfg: Config) -> "StepTest":
        """Force mode: 0 → the config's static force (setpoint.offset, or setpoint.final for
        a step), step at 10 ms, 0.1 s long. Position mode: setpoint.initial →
        setpoint.final at setpoint.start over run.duration, vibration scored over the last
        half (at the excitation frequency when the excitation is harmonic)."""
        kind = cfg["setpoint.kind"]
        if cfg.mode == "force":
            target = cfg["setpoint.final"] if kind in ("step", "ramp") else cfg["setpoint.offset"]
            if not target:
                target = cfg["setpoint.final"] or cfg["setpoint.offset"]
            if not target:
                raise ValueError("StepTest.default: setpoint has no non-zero target force; give a StepTest")
            return cls(initial=0.0, final=float(target), start=0.01, duration=0.1, signal="rod_force")
        if cfg.mode == "position":
            dur = float(cfg["run.duration"])
            freq = None
            if "excitation.kind" in cfg and cfg["excitation.kind"] == "harmonic":
                freq = float(cfg["excitation.frequency"])
            start = float(cfg["setpoint.start"])
            return cls(
                initial=float(cfg["setpoint.initial"]),
                final=float(cfg["setpoint.final"]),
                start=start,
                duration=dur,
                signal="x",
                vibration_from=start + 0.5 * (dur - start),
                vibration_frequency=freq,
            )
        raise ValueError(f"StepTest.default: control.mode is {cfg.mode!r}; expected \"force\" or \"position\"")

    def setpoint(self) -> dict[str, Any]:
        """The ``[setpoint]`` edits of this test."""
        return {"kind": "step", "initial": self.initial, "final": self.final, "start": self.start}

    def fields(self) -> list[str]:
        return ["t", "setpoint", "u", "command_unsat", self.signal]


@dataclass
class TrackingTest:
    """Tracking of the config's own setpoint (e.g. the 004 785 N ± 196 N sweep), or of
    ``setpoint_edits`` applied to it, for ``duration`` (s); scored on the ground-truth
    column ``signal`` after ``t_from`` (s): ``rms_error``, ``max_abs_error`` (N or m),
    ``peak_command`` (V) and ``saturation_fraction`` (share of scored cycles with the
    unsaturated command at the output limit)."""

    duration: float
    t_from: float
    signal: str
    setpoint_edits: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def default(cls, cfg: Config) -> "TrackingTest":
        """The config's setpoint over run.duration, scored from its dynamic start
        (setpoint.ramp_time for static_dynamic, else setpoint.start)."""
        kind = cfg["setpoint.kind"]
        t_from = float(cfg["setpoint.ramp_time"]) if kind == "static_dynamic" else float(cfg["setpoint.start"])
        t_from = max(t_from, float(cfg["setpoint.start"]))
        sig = {"force": "rod_force", "position": "x"}.get(cfg.mode)
        if sig is None:
            raise ValueError(f"TrackingTest.default: control.mode is {cfg.mode!r}; expected \"force\" or \"position\"")
        return cls(duration=float(cfg["run.duration"]), t_from=t_from, signal=sig)

    def setpoint(self) -> dict[str, Any] | None:
        return dict(self.setpoint_edits) or None

    def fields(self) -> list[str]:
        return ["t", "setpoint", "u", "command_unsat", self.signal]


def _u_limit(cfg: Config) -> float:
    if cfg.mode == "force":
        return float(min(abs(cfg["control.pi.u_min"]), abs(cfg["control.pi.u_max"])))
    return float(cfg["control.pd.u_max"])


def score(res: RunResult, test: "StepTest | TrackingTest") -> dict[str, float]:
    """Metrics of one test run (step: :func:`ehactl.metrics.step_metrics`; tracking: RMS
    and peak error); adds ``tripped`` (1.0 if the supervisor tripped, then every metric is
    inf)."""
    if not res.ok or len(res) < 4:
        keys = ("itae", "iae", "ise", "overshoot_pct", "settling_time", "rms_error", "max_abs_error")
        bad = {k: math.inf for k in keys}
        bad["tripped"] = 1.0
        return bad
    if isinstance(test, TrackingTest):
        m = res.t >= test.t_from
        e = res.setpoint[m] - res[test.signal][m]
        return {
            "rms_error": float(np.sqrt(np.mean(e**2))),
            "max_abs_error": float(np.max(np.abs(e))),
            "peak_command": float(np.max(np.abs(res.u[m]))),
            "saturation_fraction": float(np.mean(np.abs(res.command_unsat[m]) >= _u_limit(res.config))),
            "tripped": 0.0,
        }
    y = res[test.signal]
    out = _m.step_metrics(
        res.t,
        y,
        test.final,
        test.initial,
        test.start,
        u=res.u,
        u_unsat=res.command_unsat,
        u_limit=_u_limit(res.config),
    )
    if test.vibration_from is not None:
        out.update(_m.vibration_metrics(res.t, y, test.final, test.vibration_from, test.vibration_frequency))
    out["tripped"] = 0.0
    return out


def evaluate(
    cfg: ConfigLike,
    gains: Sequence[dict[str, float]] | None = None,
    test: "StepTest | TrackingTest | None" = None,
    threads: int | None = None,
    client: Any = None,
) -> list[dict[str, float]]:
    """Score each gain set (dict dotted path → value; ``{}`` = the config as is) with the
    test (default :meth:`StepTest.default`) on the nonlinear plant, in one parallel batch."""
    base = _as_config(cfg)
    test = test or StepTest.default(base)
    gains = list(gains) if gains is not None else [{}]
    cfgs = [base.with_values(g) if g else base for g in gains]
    res = run_many(cfgs, duration=test.duration, setpoint=test.setpoint(), fields=test.fields(), threads=threads, client=client, frame=False)
    return [score(r, test) for r in res]


@dataclass
class TuneResult:
    """Outcome of a tuning method.

    ``gains``: dotted path → tuned value; ``metrics``: achieved on the nonlinear plant with
    the step test; ``baseline_gains`` / ``baseline``: the same for the starting config;
    ``config``: the tuned config; ``details``: method-specific data (K_Pcr, T_pcr,
    search history, margins, ...)."""

    method: str
    gains: dict[str, float]
    metrics: dict[str, float]
    baseline_gains: dict[str, float]
    baseline: dict[str, float]
    config: Config
    test: StepTest | TrackingTest
    details: dict[str, Any] = field(default_factory=dict)

    def write_config(self, path: str | os.PathLike[str]) -> None:
        """Save the tuned config as TOML (loads with ``ehactl run`` and ``Config.load``)."""
        self.config.save(path)

    def improvement(self, metric: str = "itae") -> float:
        """baseline / tuned for ``metric`` (> 1 means the tuned gains are better)."""
        b, t = self.baseline.get(metric, math.nan), self.metrics.get(metric, math.nan)
        return b / t if t else math.inf

    def table(self, keys: Sequence[str] = ("itae", "rms_error", "overshoot_pct", "settling_time", "rise_time", "peak_command")) -> str:
        """Plain-text comparison of baseline and tuned gains and metrics."""
        rows = [("", "baseline", "tuned")]
        for k in self.gains:
            rows.append((k, f"{self.baseline_gains.get(k, math.nan):.6g}", f"{self.gains[k]:.6g}"))
        for k in keys:
            if k in self.metrics or k in self.baseline:
                rows.append((k, f"{self.baseline.get(k, math.nan):.4g}", f"{self.metrics.get(k, math.nan):.4g}"))
        w = [max(len(r[i]) for r in rows) for i in range(3)]
        return "\n".join(f"{a:<{w[0]}}  {b:>{w[1]}}  {c:>{w[2]}}" for a, b, c in rows)

    def __repr__(self) -> str:
        g = ", ".join(f"{k}={v:.6g}" for k, v in self.gains.items())
        key = "itae" if "itae" in self.metrics else "rms_error"
        return f"TuneResult({self.method}: {g}; {key} {self.baseline.get(key, math.nan):.4g} → {self.metrics.get(key, math.nan):.4g})"


def _finish(
    method: str,
    base: Config,
    gains: dict[str, float],
    test: StepTest | TrackingTest,
    details: dict[str, Any],
    threads: int | None,
    constraint_test: StepTest | None = None,
    client: Any = None,
) -> TuneResult:
    paths = gain_paths(base)
    base_gains = {p: float(base[p]) for p in paths}
    tuned = base.with_values(gains)
    m_base, m_tuned = evaluate(base, [{}, gains], test, threads, client=client)
    if constraint_test is not None:
        c_base, c_tuned = evaluate(base, [{}, gains], constraint_test, threads, client=client)
        m_base = _merge(m_base, c_base)
        m_tuned = _merge(m_tuned, c_tuned)
    return TuneResult(method, dict(gains), m_tuned, base_gains, m_base, tuned, test, details)


def _merge(primary: dict[str, float], constraint: dict[str, float]) -> dict[str, float]:
    """Primary metrics plus the constraint test's as ``constraint_<name>``; overshoot,
    saturation and trips count from either test."""
    out = dict(primary)
    out.update({f"constraint_{k}": v for k, v in constraint.items()})
    out["overshoot_pct"] = max(primary.get("overshoot_pct", 0.0), constraint.get("overshoot_pct", 0.0))
    out["saturation_fraction"] = max(primary.get("saturation_fraction", 0.0), constraint.get("saturation_fraction", 0.0))
    out["tripped"] = max(primary.get("tripped", 0.0), constraint.get("tripped", 0.0))
    return out


def _without_loop_watches(c: Config) -> None:
    """Switch off, in place, the supervisor's watches that stop a loop which tracks badly or
    oscillates (``supervisor.following_error``, ``supervisor.saturation_window``): an
    identification experiment that runs the loop up to and past instability on purpose, and
    judges it by the growth of its oscillation, must not be cut short by them. The tuned
    config keeps them."""
    if "supervisor.saturation_window" in c:
        del c["supervisor.saturation_window"]
    c["supervisor.following_error"] = 1e9


def _identification_base(cfg: Config) -> Config:
    """Copy of ``cfg`` for an identification experiment: sensor noise and tones off, and
    the dynamic part of the external excitation off (its static offset stays), so that what
    is measured is the loop's own behaviour and not a forced vibration."""
    c = cfg.copy()
    edits = {k: 0.0 for k in c.keys() if k.startswith("sensors.") and k.endswith(".noise")}
    if "excitation.amplitude" in c:
        edits["excitation.amplitude"] = 0.0
    if edits:
        c.update(edits)
    if "effects.sensor_tone" in c:
        del c["effects.sensor_tone"]
    return c
