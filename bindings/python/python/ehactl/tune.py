"""Loop tuning on the compiled nonlinear plant.

Three methods, each returning a :class:`TuneResult` (gains, metrics achieved on the
nonlinear plant next to those of the starting gains, the tuned :class:`ehactl.Config`):

- :func:`critical_gain` — the critical-gain (ultimate sensitivity) experiment of seed 003
  §5: close the loop with P only, raise K_P until the loop oscillates without decay
  (K_Pcr), read the oscillation period T_pcr, then set the gains by a rule
  (Ziegler–Nichols by default);
- :func:`optimize` — minimise a time-domain cost (ITAE by default) of a step response on
  the nonlinear plant, with overshoot and command-saturation limits, by a cross-entropy
  search whose every generation is one parallel :func:`ehactl.run_many` batch;
- :func:`model_based` — PI (force) / PD (position) gains for a target phase margin and
  bandwidth on the loop linearised at its operating point (``ehactl-analysis``, the model
  of ``ehactl analyze``), or on a frequency response measured on the nonlinear plant.

Gains: force mode → ``control.pi.kp`` (V/V) and ``control.pi.integral`` (1/s, the I of
K_P(1 + I/s), 004 §6); position mode → ``control.pd.kp`` (V/m) and ``control.pd.td`` (s,
003 eq. 32). Every metric is computed on the nonlinear simulated plant from the ground
truth (``rod_force`` or ``x``), so sensor noise does not enter the score.

Every function that runs batches (:func:`evaluate`, :func:`critical_gain`,
:func:`optimize`, :func:`model_based`, :func:`frequency_response`) takes ``client=``, a
``dask.distributed.Client``: its batches then run on the cluster's workers (see
:func:`ehactl.run_many`) with the same numbers; the default is the local rayon path.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np

from . import metrics as _m
from ._ehactl import Config
from ._runs import ConfigLike, RunResult, _as_config, run_many
from ._freq import (
    FrequencyResponse,
    controller_response,
    frequency_response,
    linear_response,
    loop_margins,
    model_based,
)
from ._tunebase import (
    StepTest,
    TrackingTest,
    TuneResult,
    _finish,
    _identification_base,
    _without_loop_watches,
    _merge,
    evaluate,
    gain_paths,
    score as score,
)
from .results import FloatArray

__all__ = [
    "StepTest",
    "TrackingTest",
    "TuneResult",
    "gain_paths",
    "evaluate",
    "critical_gain",
    "optimize",
    "model_based",
    "frequency_response",
    "FrequencyResponse",
    "controller_response",
    "linear_response",
    "loop_margins",
]


#: Gain rules from (K_Pcr, T_pcr): name → (kp factor, second-gain function).
#: PI: integral I = 1/T_i; PD: T_D. Ziegler & Nichols (1942) ultimate-sensitivity rules;
#: Tyreus–Luyben (1992) for a less oscillatory PI.
PI_RULES: dict[str, tuple[float, Callable[[float], float]]] = {
    "zn": (0.45, lambda tcr: 1.2 / tcr),  # T_i = T_cr / 1.2
    "tyreus_luyben": (1.0 / 3.2, lambda tcr: 1.0 / (2.2 * tcr)),  # T_i = 2.2 T_cr
}
PD_RULES: dict[str, tuple[float, Callable[[float], float]]] = {
    "zn": (0.8, lambda tcr: tcr / 8.0),  # K_P = 0.8 K_cr, T_D = T_cr / 8
    "conservative": (0.5, lambda tcr: tcr / 8.0),
}


def critical_gain(
    cfg: ConfigLike,
    rule: str = "zn",
    test: StepTest | None = None,
    kp_range: tuple[float, float] | None = None,
    rel_tol: float = 0.02,
    growth_threshold: float = 0.9,
    noise_free: bool = True,
    threads: int | None = None,
    client: Any = None,
    progress: bool = False,
) -> TuneResult:
    """Critical-gain tuning (seed 003 §5, Ziegler–Nichols ultimate sensitivity).

    1. Proportional-only loop (I = 0 or T_D = 0) with the step test's setpoint.
    2. K_P scanned geometrically over ``kp_range`` (default current K_P /30 … ×300) in one
       parallel batch, then the bracket stable/unstable is narrowed by batches until
       hi/lo ≤ 1 + ``rel_tol``. A run counts as unstable when it trips or when the
       detrended oscillation of the ground-truth signal in the second half of the analysis
       window has at least ``growth_threshold`` × the RMS of the first half (no decay).
    3. T_pcr = period of the sustained oscillation just above K_Pcr (zero crossings).
    4. Gains from ``rule``: PI ``"zn"`` K_P = 0.45 K_Pcr, T_i = T_pcr/1.2; ``"tyreus_luyben"``
       K_P = K_Pcr/3.2, T_i = 2.2 T_pcr; PD ``"zn"`` K_P = 0.8 K_Pcr, T_D = T_pcr/8;
       ``"conservative"`` K_P = 0.5 K_Pcr, T_D = T_pcr/8.

    ``noise_free`` switches sensor noise, tones and the dynamic part of the excitation
    force off for the identification experiment only (they would mask a slowly decaying
    oscillation or pass a forced vibration off as the critical one); the tuned gains are
    scored on the config as given, excitation included.
    """
    base = _as_config(cfg)
    kp_path, second = gain_paths(base)
    test = test or StepTest.default(base)
    rules = PI_RULES if base.mode == "force" else PD_RULES
    if rule not in rules:
        raise ValueError(f"rule {rule!r} is not known for {base.mode} mode; expected one of {sorted(rules)}")
    ident = _identification_base(base) if noise_free else base.copy()
    ident[second] = 0.0
    _without_loop_watches(ident)
    kp0 = float(base[kp_path]) or 1.0
    lo_r, hi_r = kp_range or (kp0 / 30.0, kp0 * 300.0)
    window_from = test.start + 0.4 * (test.duration - test.start)
    scanned: list[tuple[float, float, bool]] = []

    def classify(kps: np.ndarray) -> list[tuple[bool, RunResult]]:
        res = run_many(
            [ident.with_values({kp_path: float(k)}) for k in kps],
            duration=test.duration,
            setpoint=test.setpoint(),
            fields=["t", test.signal],
            threads=threads, client=client, frame=False,
        )
        out = []
        for k, r in zip(kps, res):
            if not r.ok:
                out.append((True, r))
                scanned.append((float(k), math.inf, True))
                continue
            g = _m.oscillation_growth(r.t, r[test.signal], window_from)
            floor = 1e-9 * abs(test.final - test.initial)
            unstable = g["ratio"] >= growth_threshold and g["rms_second"] > floor
            scanned.append((float(k), g["ratio"], unstable))
            out.append((unstable, r))
        return out

    bar = None
    if progress:
        try:
            from tqdm.auto import tqdm

            bar = tqdm(desc="critical gain", unit="batch", disable=None)
        except ImportError:  # pragma: no cover
            bar = None
    grid = np.geomspace(lo_r, hi_r, 16)
    cls = classify(grid)
    if bar:
        bar.update()
    flags = [c[0] for c in cls]
    if not any(flags):
        raise RuntimeError(
            f"critical_gain: the P-only loop stayed stable up to K_P = {hi_r:.4g} "
            f"({gain_paths(base)[0]}); widen kp_range"
        )
    i = flags.index(True)
    if i == 0:
        raise RuntimeError(f"critical_gain: already unstable at K_P = {lo_r:.4g}; lower kp_range")
    lo, hi = float(grid[i - 1]), float(grid[i])
    hi_res = cls[i][1]
    n = 4
    while hi / lo > 1.0 + rel_tol:
        pts = np.geomspace(lo, hi, n + 2)[1:-1]
        cls = classify(pts)
        if bar:
            bar.update()
        for k, (u, r) in zip(pts, cls):
            if u:
                hi, hi_res = float(k), r
                break
            lo = float(k)
    if bar:
        bar.close()
    k_cr = math.sqrt(lo * hi)
    g = _m.oscillation_growth(hi_res.t, hi_res[test.signal], window_from)
    t_cr = g["period"]
    if not math.isfinite(t_cr):
        raise RuntimeError("critical_gain: could not read the oscillation period at K_Pcr")
    kf, second_fn = rules[rule]
    gains = {kp_path: kf * k_cr, second: second_fn(t_cr)}
    details = {
        "K_Pcr": k_cr,
        "T_pcr": t_cr,
        "f_cr_hz": 1.0 / t_cr,
        "bracket": (lo, hi),
        "rule": rule,
        "scanned": sorted(scanned),
        "noise_free_identification": noise_free,
    }
    return _finish("critical_gain", base, gains, test, details, threads, client=client)


def _cost(
    m: dict[str, float], objective: str | Callable[[dict[str, float]], float], max_overshoot_pct: float, max_saturation: float, limits: dict[str, float] | None = None
) -> tuple[float, bool]:
    if m.get("tripped", 0.0):
        return math.inf, False
    if not callable(objective) and objective not in m:
        raise ValueError(f"optimize: objective {objective!r} is not a metric of the test; available: {sorted(m)}")
    obj = objective(m) if callable(objective) else m[objective]
    if not math.isfinite(obj):
        return math.inf, False
    v = max(0.0, m.get("overshoot_pct", 0.0) - max_overshoot_pct) / max(max_overshoot_pct, 1.0)
    v += max(0.0, m.get("saturation_fraction", 0.0) - max_saturation) / max(max_saturation, 1e-3)
    for k, ub in (limits or {}).items():
        x = m.get(k, math.inf)
        v += math.inf if not math.isfinite(x) else max(0.0, x - ub) / max(abs(ub), 1e-12)
    if not math.isfinite(v):
        return math.inf, False
    return obj * (1.0 + 10.0 * v), v == 0.0


def _search_space(
    base: Config, bounds: dict[str, tuple[float, float]] | None
) -> tuple[
    tuple[str, str],
    dict[str, tuple[float, float]],
    FloatArray,
    FloatArray,
    FloatArray,
    Callable[[FloatArray], dict[str, float]],
]:
    """Search variables, their log bounds and the map back to config gains.

    Force mode searches K_P (V/V) and K_I = K_P·I (1/s): the integral action the loop
    actually sees, so the two axes are independent. Position mode searches K_P (V/m) and
    T_D (s)."""
    paths = gain_paths(base)
    x0 = {p: float(base[p]) for p in paths}
    if base.mode == "force":
        names = ("control.pi.kp", "ki")
        q0 = np.array([x0["control.pi.kp"], x0["control.pi.kp"] * x0["control.pi.integral"]])

        def to_gains(q: FloatArray) -> dict[str, float]:
            return {"control.pi.kp": float(q[0]), "control.pi.integral": float(q[1] / q[0])}

    else:
        names = ("control.pd.kp", "control.pd.td")
        q0 = np.array([x0["control.pd.kp"], x0["control.pd.td"]])

        def to_gains(q: FloatArray) -> dict[str, float]:
            return {"control.pd.kp": float(q[0]), "control.pd.td": float(q[1])}

    b = dict(bounds or {})
    for i, n in enumerate(names):
        if n in b:
            continue
        if n.endswith(".td"):
            b[n] = (5e-5, 5e-2)
        elif q0[i] > 0:
            b[n] = (q0[i] / 100.0, q0[i] * 100.0)
        else:
            b[n] = (1.0, 1e5) if n == "ki" else (1e-3, 1e3)
    for n in b:
        if n not in names:
            raise ValueError(f"optimize: unknown bound {n!r}; expected {names}")
        if not (0 < b[n][0] < b[n][1]):
            raise ValueError(f"optimize: bound {n} = {b[n]} must satisfy 0 < low < high")
    lo = np.log([b[n][0] for n in names])
    hi = np.log([b[n][1] for n in names])
    q0 = np.where(q0 > 0, q0, np.exp(0.5 * (lo + hi)))
    return names, b, lo, hi, np.log(np.clip(q0, np.exp(lo), np.exp(hi))), to_gains


def optimize(
    cfg: ConfigLike,
    objective: str | Callable[[dict[str, float]], float] = "itae",
    test: "StepTest | TrackingTest | None" = None,
    max_overshoot_pct: float = 5.0,
    max_saturation: float = 0.01,
    constraint_test: StepTest | None = None,
    bounds: dict[str, tuple[float, float]] | None = None,
    generations: int = 8,
    population: int = 16,
    elite_fraction: float = 0.25,
    refine: int = 10,
    start: Sequence[dict[str, float]] = (),
    limits: dict[str, float] | None = None,
    seed: int = 0,
    threads: int | None = None,
    client: Any = None,
    progress: bool = False,
) -> TuneResult:
    """Minimise a time-domain cost of the step test on the nonlinear plant.

    ``objective``: a metric name of :func:`ehactl.metrics.step_metrics` /
    ``vibration_metrics`` (default ``"itae"``, unit·s²), of a :class:`TrackingTest`
    (``"rms_error"``), or a callable on the metrics dict. ``constraint_test`` (e.g. a
    :class:`StepTest` while optimising tracking) is run for every candidate too; its
    overshoot, saturation and trips count in the constraints and its metrics appear as
    ``constraint_<name>``. ``limits`` adds upper bounds on any metric by name (e.g.
    ``{"constraint_settling_time": 0.008}``). Constraints: overshoot ≤ ``max_overshoot_pct`` (% of the step) and share of cycles
    after the 90 % rise with the unsaturated command at the controller's output limit ≤
    ``max_saturation`` (see :func:`ehactl.metrics.step_metrics`); violations multiply the cost by 1 + 10·(relative violation), trips
    cost ∞. Search: cross-entropy method in log space over K_P and K_I = K_P·I (force) or
    K_P and T_D (position) within ``bounds`` (keys ``"control.pi.kp"``, ``"ki"`` (1/s) or
    ``"control.pd.kp"``, ``"control.pd.td"`` (s); default starting value /100 … ×100, T_D
    0.05–50 ms). Generation 0 is a log grid plus the starting gains; each later one samples
    ``population`` points around the elites; ``start`` adds gain sets (dotted path →
    value) to generation 0. Then ``refine`` rounds of a batch pattern search polish the
    best point (8 neighbours on the axes and diagonals, step halved when none improves).
    Every generation and round is one parallel :func:`ehactl.run_many` batch. The best
    feasible gains are returned.
    """
    base = _as_config(cfg)
    gain_paths(base)  # clear error for open_loop configs
    test = test or StepTest.default(base)
    names, b, lo, hi, q0, to_gains = _search_space(base, bounds)
    rng = np.random.default_rng(seed)
    history: list[dict[str, Any]] = []
    best: tuple[float, bool, dict[str, float], dict[str, float]] | None = None

    def run_gen(z: FloatArray) -> list[tuple[float, bool, dict[str, float], dict[str, float]]]:
        gains = [to_gains(np.exp(row)) for row in z]
        ms = evaluate(base, gains, test, threads, client=client)
        if constraint_test is not None:
            ms = [_merge(a, c) for a, c in zip(ms, evaluate(base, gains, constraint_test, threads, client=client))]
        out = []
        for g, m in zip(gains, ms):
            c, feas = _cost(m, objective, max_overshoot_pct, max_saturation, limits)
            out.append((c, feas, g, m))
            history.append({"gains": g, "cost": c, "feasible": feas, "metrics": m})
        return out

    def qrow(g: dict[str, float]) -> np.ndarray:
        if base.mode == "force":
            return np.log([g["control.pi.kp"], g["control.pi.kp"] * g["control.pi.integral"]])
        return np.log([g["control.pd.kp"], g["control.pd.td"]])

    side = max(4, int(round(math.sqrt(population))))
    g0 = np.array(np.meshgrid(*[np.linspace(a, b, side) for a, b in zip(lo, hi)])).reshape(len(names), -1).T
    extra = [qrow({**{p: float(base[p]) for p in gain_paths(base)}, **g}) for g in start]
    z = np.clip(np.vstack([g0, q0[None, :], *[e[None, :] for e in extra]]), lo, hi)
    mu: FloatArray | None = None
    sd: FloatArray | None = None
    bar = None
    if progress:
        try:
            from tqdm.auto import tqdm

            bar = tqdm(total=generations, desc="optimize", unit="gen", disable=None)
        except ImportError:  # pragma: no cover
            bar = None
    for gen in range(generations):
        res = run_gen(z)
        for r in res:
            if best is None or (r[1], -r[0]) > (best[1], -best[0]):
                best = r
        assert best is not None  # a generation has at least one candidate
        ranked = sorted(res + [best], key=lambda r: r[0])  # penalised cost
        n_el = max(2, int(round(elite_fraction * len(res))))
        el_rows = [qrow(r[2]) for r in ranked[:n_el] if math.isfinite(r[0])]
        el = np.array(el_rows) if el_rows else q0[None, :]
        new_mu = el.mean(axis=0)
        new_sd = np.maximum(el.std(axis=0), 0.02 * (hi - lo))
        if mu is None or sd is None:
            mu, sd = new_mu, new_sd
        else:
            mu = 0.7 * new_mu + 0.3 * mu
            sd = 0.7 * new_sd + 0.3 * sd
        if bar:
            bar.update()
            bar.set_postfix(best=f"{best[0]:.4g}")
        if gen + 1 < generations:
            z = np.clip(rng.normal(mu, sd, size=(population, len(names))), lo, hi)
    # pattern search around the best point
    step = np.maximum(sd if sd is not None else 0.1 * (hi - lo), 0.01 * (hi - lo))
    dirs = np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=float)
    for _ in range(refine):
        assert best is not None
        if not math.isfinite(best[0]):
            break
        c = qrow(best[2])
        cand = np.clip(c[None, :] + dirs * step[None, :], lo, hi)
        res = run_gen(cand)
        improved = False
        for r in res:
            if (r[1], -r[0]) > (best[1], -best[0]):
                best, improved = r, True
        if not improved:
            step = step / 2.0
        if np.all(step < 1e-3):
            break
    if bar:
        bar.close()
    assert best is not None
    if not math.isfinite(best[0]):
        raise RuntimeError("optimize: every candidate tripped or failed; check bounds and the step test")
    at_bound = [n for n, v, a, b in zip(names, qrow(best[2]), lo, hi) if min(v - a, b - v) < 1e-3 * (b - a)]
    details = {
        "objective": objective if isinstance(objective, str) else getattr(objective, "__name__", "callable"),
        "cost": best[0],
        "feasible": best[1],
        "bounds": b,
        "at_bound": at_bound,
        "evaluations": len(history),
        "history": history,
        "max_overshoot_pct": max_overshoot_pct,
        "max_saturation": max_saturation,
        "constraint_test": constraint_test,
        "limits": dict(limits or {}),
    }
    return _finish("optimize", base, best[2], test, details, threads, constraint_test, client=client)
