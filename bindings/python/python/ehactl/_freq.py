"""Loop frequency response measured on the nonlinear plant, loop margins, and model-based
PI / PD tuning for a target phase margin and crossover frequency (:mod:`ehactl.tune`).

The plant response P(jω) = Y/U (controlled variable per valve volt) is measured in closed
loop with the configured gains: one stepped-sine run per frequency, all frequencies in one
parallel :func:`ehactl.run_many` batch, Fourier coefficients of the fed-back signal and of
the valve command over whole periods after a settling time. Because y and u are both
taken at the cycle instants, P includes the zero-order hold, the one-cycle computation
delay and the sensor path exactly as the controller sees them; the controller's own
discrete transfer function C(z) (PI 004 §6 backward-Euler integral, PD 003 eq. 32 with the
configured derivative filter) is known in closed form, so the loop is L = C·P.
"""

from __future__ import annotations

import math
import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
import numpy.typing as npt

from . import _ehactl
from ._ehactl import Config
from ._runs import ConfigLike, _as_config, run_many
from ._tunebase import StepTest, TrackingTest, TuneResult, _finish, _identification_base, gain_paths
from .results import FloatArray, FrozenMap, _setstate_frozen, _thaw

if TYPE_CHECKING:
    import pandas as pd

ComplexArray = npt.NDArray[np.complex128]


def controller_response(cfg: Config, f_hz: np.ndarray, gains: dict[str, float] | None = None) -> np.ndarray:
    """Discrete controller frequency response C(e^{jωT}) in V per unit of the controlled
    variable (V/N for force, V/m for position) at ``f_hz``, for the config's gains or
    ``gains`` (dotted path → value). Evaluated by ``ehactl-analysis`` (``loopshape::Law``,
    the loop's own discrete PI / PD), not re-implemented here."""
    c = cfg.with_values(gains) if gains else cfg
    f = np.atleast_1d(np.asarray(f_hz, dtype=float))
    re, im = _ehactl.controller_response(c, [float(x) for x in f])
    return (np.asarray(re) + 1j * np.asarray(im)).reshape(np.shape(f_hz))


def _fourier(t: np.ndarray, x: np.ndarray, f: float) -> complex:
    x = x - x.mean()
    return complex(2.0 / len(x) * np.sum(x * np.exp(-1j * 2 * np.pi * f * t)))


@dataclass(frozen=True, eq=False)
class FrequencyResponse:
    """Loop frequency response, measured on the nonlinear plant (:func:`frequency_response`)
    or from the linearised plant (:func:`linear_response`). Construct with keywords.

    Immutable (frozen dataclass, read-only arrays); :meth:`with_gains` returns a new one.

    Attributes:
        f: Frequency (Hz).
        plant: Plant response P = Y/U (N/V or m/V), complex.
        controller: Controller response C (V/N or V/m), complex.
        closed: Closed loop T = Y/R (measured directly, or L/(1 + L) for a model), complex.
        unit: Unit of the controlled variable y: "N" or "m".
        gains: Gains the controller response was computed for (dotted path → value).
        purity: |Y| share at the test frequency vs the RMS of the periodic window (1 = pure
            sinusoid, lower = nonlinear or noisy) (-).
        details: How it was obtained: ``source`` ("measured" or "linear") and its parameters.
    """

    f: FloatArray
    plant: ComplexArray
    controller: ComplexArray
    closed: ComplexArray
    unit: str
    gains: Mapping[str, float]
    purity: FloatArray
    details: Mapping[str, Any] = field(default_factory=lambda: FrozenMap({}))

    def __post_init__(self) -> None:
        # Read-only copies: the object is shared by with_gains() results and tuning details.
        for name in ("f", "plant", "controller", "closed", "purity"):
            a = np.array(getattr(self, name))
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "gains", FrozenMap({str(k): float(v) for k, v in self.gains.items()}))
        if not isinstance(self.details, FrozenMap):
            object.__setattr__(self, "details", FrozenMap(dict(self.details)))

    def __setstate__(self, state: Mapping[str, Any]) -> None:
        _setstate_frozen(self, state)  # arrays read-only again after unpickling

    @property
    def loop(self) -> ComplexArray:
        """Loop gain L = C·P (-), complex."""
        return self.controller * self.plant

    def with_gains(self, cfg: ConfigLike, gains: Mapping[str, float]) -> FrequencyResponse:
        """Same plant response, loop recomputed for other gains (closed = L/(1+L))."""
        c = _as_config(cfg)
        C = controller_response(c, self.f, dict(gains))
        L = C * self.plant
        return dataclasses.replace(self, controller=C, closed=L / (1 + L), gains=dict(gains))

    def margins(self) -> dict[str, float]:
        """Loop margins from L on the measured grid (log-f interpolation):
        ``phase_margin_deg`` at the gain crossover ``crossover_hz`` (|L| = 1, first
        downward crossing), ``gain_margin_db`` at the phase crossover ``phase_crossover_hz``
        (arg L = −180°, first crossing above the gain crossover), the closed-loop
        ``bandwidth_hz`` where |L/(1+L)| first drops below −3 dB and its peak
        ``peak_closed_db``."""
        return loop_margins(self.f, self.loop)

    def to_pandas(self) -> pd.DataFrame:
        """``pandas.DataFrame`` indexed by ``f_hz`` with complex columns ``plant``,
        ``controller``, ``loop``, ``closed`` and ``purity``."""
        try:
            import pandas as pd
        except ImportError as e:
            raise ImportError("FrequencyResponse.to_pandas() needs pandas: pip install pandas") from e
        return pd.DataFrame(
            {"plant": np.array(self.plant), "controller": np.array(self.controller), "loop": self.loop,
             "closed": np.array(self.closed), "purity": np.array(self.purity)},
            index=pd.Index(np.array(self.f), name="f_hz"),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible: ``f_hz``, complex responses as ``{"re": [...], "im": [...]}``,
        ``purity``, ``unit``, ``gains`` and ``details`` (non-finite numbers as None)."""

        def cplx(z: ComplexArray) -> dict[str, Any]:
            return {"re": _thaw(z.real), "im": _thaw(z.imag)}

        return {"f_hz": _thaw(self.f), "plant": cplx(self.plant), "controller": cplx(self.controller),
                "closed": cplx(self.closed), "purity": _thaw(self.purity), "unit": self.unit,
                "gains": _thaw(self.gains), "details": _thaw(self.details)}

    def __repr__(self) -> str:
        m = self.margins()
        src = self.details.get("source", "?")
        return (f"FrequencyResponse({src}, {len(self.f)} points {self.f[0]:.4g}–{self.f[-1]:.4g} Hz, "
                f"phase_margin_deg={m['phase_margin_deg']:.4g} at {m['crossover_hz']:.4g} Hz, "
                f"gain_margin_db={m['gain_margin_db']:.4g}, unit={self.unit!r})")


def loop_margins(f: np.ndarray, L: np.ndarray) -> dict[str, float]:
    """Phase margin (deg), gain margin (dB), crossovers (Hz) and closed-loop −3 dB bandwidth
    (Hz) of the loop L(j2πf) sampled at ``f`` (Hz); NaN where no crossing lies in the grid.
    Computed by ``ehactl-analysis`` (``loopshape::sampled_margins``): first downward
    crossings interpolated in log f, phase unwrapped along the grid."""
    f = np.asarray(f, dtype=float)
    L = np.asarray(L, dtype=complex)
    return dict(_ehactl.sampled_margins([float(x) for x in f], L.real.tolist(), L.imag.tolist()))


def _identification_config(cfg: Config, amplitude: float | None, settle: float, f0: float) -> tuple[Config, float, float]:

    c = _identification_base(cfg)
    edits: dict[str, Any] = {}
    kind = c["setpoint.kind"]
    if c.mode == "force":
        offset = c["setpoint.offset"] if kind not in ("step", "ramp") else c["setpoint.final"]
        amp = amplitude if amplitude is not None else (c["setpoint.amplitude"] or 0.1 * abs(offset) or 10.0)
    else:
        offset = c["setpoint.final"] if kind in ("step", "ramp") else c["setpoint.offset"]
        amp = amplitude if amplitude is not None else 0.01 * max(abs(offset), 0.1)
        edits["cylinder.initial_position"] = float(offset)
    edits.update({"setpoint.kind": "sine", "setpoint.offset": float(offset), "setpoint.amplitude": float(amp), "setpoint.start": settle, "setpoint.f0": float(f0)})
    c.update(edits)
    return c, float(offset), float(amp)


def frequency_response(
    cfg: ConfigLike,
    f_hz: Sequence[float] | None = None,
    amplitude: float | None = None,
    gains: dict[str, float] | None = None,
    settle: float | None = None,
    min_periods: int = 4,
    min_window: float = 0.05,
    threads: int | None = None,
    client: Any = None,
    progress: bool = False,
) -> FrequencyResponse:
    """Measure the loop's frequency response on the nonlinear plant (stepped sine, one run
    per frequency, all in one parallel batch).

    The setpoint is ``offset + amplitude·sin(2πf(t − settle))`` around the config's
    operating point (force: setpoint.offset, default amplitude setpoint.amplitude or 10 %;
    position: setpoint.final with the piston starting there, default amplitude 1 % of it,
    excitation amplitude set to 0 so only its static part loads the actuator). Sensor noise
    and tones are off. ``f_hz`` default: 24 log-spaced frequencies from 2 Hz (force) or
    0.5 Hz (position) to 0.3 × the control rate. Analysis window: the last
    max(``min_periods`` periods, ``min_window`` s) of each run.
    """
    base = _as_config(cfg)
    if gains:
        base = base.with_values(gains)
    fs = 1.0 / base.control_dt
    if f_hz is None:
        f0 = 2.0 if base.mode == "force" else 0.5
        f1 = min(0.3 * fs, 1500.0 if base.mode == "force" else 200.0)
        f = np.geomspace(f0, f1, 24)
    else:
        f = np.asarray(f_hz, dtype=float)
    if np.any(f <= 0) or np.any(f >= fs / 2):
        raise ValueError(f"frequency_response: frequencies must be in (0, {fs / 2}) Hz (Nyquist)")
    if settle is None:
        settle = 0.05 if base.mode == "force" else 0.5
    ident, offset, amp = _identification_config(base, amplitude, settle, float(f[0]))
    windows = np.maximum(min_periods / f, min_window)
    # whole periods in the window
    windows = np.ceil(windows * f) / f
    durations = settle + 1.0 / f + windows
    cfgs = [ident.with_values({"setpoint.f0": float(fi)}) for fi in f]
    P = np.empty(len(f), dtype=complex)
    T = np.empty(len(f), dtype=complex)
    purity = np.empty(len(f))
    trips = []
    # one batch per distinct duration would waste cores; run all at the longest duration
    # needed by each frequency by grouping into at most 4 duration classes
    order = np.argsort(durations)
    groups = np.array_split(order, min(4, len(order)))
    results: dict[int, Any] = {}
    for gidx in groups:
        if len(gidx) == 0:
            continue
        dur = float(durations[gidx].max())
        rs = run_many([cfgs[i] for i in gidx], duration=dur, fields=["t", "setpoint", "feedback", "u"], threads=threads, client=client, frame=False, progress=progress)
        for i, r in zip(gidx, rs):
            results[int(i)] = r
    for i, fi in enumerate(f):
        r = results[i]
        if not r.ok:
            trips.append((float(fi), r.trip))
            P[i] = T[i] = complex("nan")
            purity[i] = math.nan
            continue
        m = r.t >= (r.t[-1] + r.dt - windows[i] - 1e-12)
        t = r.t[m]
        y = r.feedback[m]
        U = _fourier(t, r.u[m], fi)
        Y = _fourier(t, y, fi)
        R = _fourier(t, r.setpoint[m], fi)
        P[i] = Y / U
        T[i] = Y / R
        yd = y - y.mean()
        purity[i] = min(1.0, abs(Y) / math.sqrt(2) / max(float(np.sqrt(np.mean(yd**2))), 1e-300))
    unit = "N" if base.mode == "force" else "m"

    g = {p: float(base[p]) for p in gain_paths(base)}
    C = controller_response(base, f)
    return FrequencyResponse(
        f=f, plant=P, controller=C, closed=T, unit=unit, gains=g, purity=purity,
        details={"source": "measured", "offset": offset, "amplitude": amp, "settle_s": settle, "trips": trips},
    )


def linear_response(
    cfg: ConfigLike,
    f_hz: Sequence[float] | None = None,
    gains: dict[str, float] | None = None,
    max_time: float = 5.0,
) -> FrequencyResponse:
    """Loop frequency response from the plant linearised at its operating point by
    ``ehactl-analysis`` (the model of ``ehactl analyze``: the plant's own step map over one
    control period differentiated numerically, so the sample and hold are exact; a command
    delay enters as e^(−jωτ)). ``closed`` is the predicted L/(1+L); ``details`` holds the
    operating point. ``f_hz`` default: 200 log-spaced points from 1 Hz (force) or 0.1 Hz
    (position) to 0.95 × Nyquist."""
    base = _as_config(cfg)
    if gains:
        base = base.with_values(gains)
    fs = 1.0 / base.control_dt
    if f_hz is None:
        f = np.geomspace(1.0 if base.mode == "force" else 0.1, 0.95 * fs / 2, 200)
    else:
        f = np.asarray(f_hz, dtype=float)
    re, im, info = _ehactl.linear_plant_response(base, [float(x) for x in f], max_time)
    P = np.asarray(re) + 1j * np.asarray(im)

    g = {p: float(base[p]) for p in gain_paths(base)}
    C = controller_response(base, f)
    L = C * P
    details = {"source": "linear", **info}
    return FrequencyResponse(f=f, plant=P, controller=C, closed=L / (1 + L), unit="N" if base.mode == "force" else "m",
                             gains=g, purity=np.ones(len(f)), details=details)


def _interp_P(fr: FrequencyResponse, fc: float) -> complex:
    ok = np.isfinite(fr.plant)
    lf = np.log(fr.f[ok])
    mag = np.log(np.abs(fr.plant[ok]))
    ph = np.unwrap(np.angle(fr.plant[ok]))
    x = math.log(fc)
    return complex(math.exp(np.interp(x, lf, mag)) * np.exp(1j * np.interp(x, lf, ph)))


def _design_at(cfg: Config, fr: FrequencyResponse, fc: float, pm_deg: float, paths: tuple[str, str]) -> dict[str, float] | None:
    """Gains putting |L| = 1 with phase margin ``pm_deg`` at ``fc`` (Hz), or None if the
    controller's phase range cannot reach it there."""
    P = _interp_P(fr, fc)
    target = math.radians(-180.0 + pm_deg)
    argP = math.atan2(P.imag, P.real)
    kp_path, second = paths

    def C1(x: float) -> complex:  # controller response with kp = 1 and second gain x
        return complex(controller_response(cfg, np.array([fc]), {kp_path: 1.0, second: x})[0])

    def err(x: float) -> float:
        a = argP + math.atan2(C1(x).imag, C1(x).real) - target
        return (a + math.pi) % (2 * math.pi) - math.pi

    if cfg.mode == "force":
        lo, hi = 0.0, 2 * math.pi * fc * 50  # integral 1/s: phase lag grows with I
    else:
        lo, hi = 0.0, 50.0 / (2 * math.pi * fc)  # T_D s: phase lead grows with T_D
    e_lo, e_hi = err(lo), err(hi)
    if e_lo * e_hi > 0:
        return None
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        e = err(mid)
        if e * e_lo > 0:
            lo, e_lo = mid, e
        else:
            hi = mid
    x = 0.5 * (lo + hi)
    L1 = P * C1(x)
    # the phase condition holds modulo 360°: accept only the branch where the loop phase
    # itself is −180° + PM (the usual stable-loop branch, arg L in (−360°, 0°])
    ang = math.degrees(math.atan2(L1.imag, L1.real))
    if ang > 0:
        ang -= 360.0
    if abs(180.0 + ang - pm_deg) > 1.0:
        return None
    kp = 1.0 / abs(L1)
    return {kp_path: float(kp), second: float(x)}


def model_based(
    cfg: ConfigLike,
    phase_margin_deg: float = 60.0,
    crossover_hz: float | None = None,
    bandwidth_hz: float | None = None,
    min_gain_margin_db: float = 6.0,
    max_peak_db: float = 3.0,
    source: str = "linear",
    fr: FrequencyResponse | None = None,
    test: StepTest | TrackingTest | None = None,
    threads: int | None = None,
    client: Any = None,
    progress: bool = False,
) -> TuneResult:
    """Model-based tuning: PI (force) or PD (position) gains that give ``phase_margin_deg``
    at a gain crossover on the loop model L = C·P.

    The plant response P comes from the linearised plant (``source="linear"``,
    :func:`linear_response`, the ``ehactl analyze`` model) or from a stepped-sine
    measurement on the nonlinear plant (``source="measured"``, :func:`frequency_response`);
    pass ``fr`` to reuse one. At a crossover f_c the
    controller term that sets the phase is solved exactly on the discrete C(z) — the PI
    integral rate I (1/s) for its lag, the PD derivative time T_D (s) for its lead — and
    K_P then sets |L(f_c)| = 1. The crossover is ``crossover_hz`` (Hz) if given; otherwise
    every f_c on a log grid over the measured range is designed and, among the designs with
    the phase margin met (±5°), gain margin ≥ ``min_gain_margin_db`` and closed-loop peak
    ≤ ``max_peak_db``, the one whose predicted −3 dB closed-loop bandwidth is closest to
    ``bandwidth_hz`` (Hz) is taken — or, when ``bandwidth_hz`` is None, the one with the
    largest integral gain K_P·I (PI: best low-frequency disturbance rejection under the
    robustness limits, as in Åström–Hägglund's MIGO design) or the largest K_P (PD: stiffest
    position hold).
    Returns a :class:`ehactl.tune.TuneResult`; ``details`` holds the predicted margins,
    the candidate designs and the loop model.
    """

    base = _as_config(cfg)
    paths = gain_paths(base)
    if fr is None:
        if source == "linear":
            fr = linear_response(base)
        elif source == "measured":
            fr = frequency_response(base, threads=threads, client=client, progress=progress)
        else:
            raise ValueError(f"source = {source!r}; expected \"linear\" or \"measured\"")
    ok = np.isfinite(fr.plant)
    if np.count_nonzero(ok) < 4:
        raise RuntimeError("model_based: fewer than 4 usable points in the frequency response")
    fmin, fmax = float(fr.f[ok].min()), float(fr.f[ok].max())
    candidates: list[dict[str, Any]] = []
    gains: dict[str, float] | None
    if crossover_hz is not None:
        if not (fmin <= crossover_hz <= fmax):
            raise ValueError(f"crossover_hz = {crossover_hz} Hz is outside the measured range {fmin:.3g}–{fmax:.3g} Hz")
        gains = _design_at(base, fr, crossover_hz, phase_margin_deg, paths)
        if gains is None:
            raise ValueError(
                f"a {'PI' if base.mode == 'force' else 'PD'} controller cannot give "
                f"{phase_margin_deg}° phase margin at {crossover_hz} Hz on this plant"
            )
        chosen = crossover_hz
    else:
        for fc in np.geomspace(fmin * 1.02, fmax / 1.02, 80):
            g = _design_at(base, fr, float(fc), phase_margin_deg, paths)
            if g is None:
                continue
            m = fr.with_gains(base, g).margins()
            gm = m["gain_margin_db"]
            okm = (
                (math.isnan(gm) or gm >= min_gain_margin_db)
                and abs(m["phase_margin_deg"] - phase_margin_deg) < 5.0
                and m["peak_closed_db"] <= max_peak_db
                and math.isfinite(m["bandwidth_hz"])
            )
            candidates.append({"crossover_hz": float(fc), "gains": g, "predicted": m, "admissible": okm})
        adm = [c for c in candidates if c["admissible"]]
        if not adm:
            raise RuntimeError("model_based: no crossover on the measured grid meets the margins")
        if bandwidth_hz is None:
            kp_path, second = paths

            def strength(c: dict[str, Any]) -> float:
                g = c["gains"]
                return float(g[kp_path] * g[second] if base.mode == "force" else g[kp_path])

            pick = max(adm, key=strength)
        else:
            pick = min(adm, key=lambda c: abs(math.log(c["predicted"]["bandwidth_hz"] / bandwidth_hz)))
        chosen, gains = float(pick["crossover_hz"]), dict(pick["gains"])
    predicted = fr.with_gains(base, gains).margins()
    test = test or StepTest.default(base)
    details = {
        "phase_margin_target_deg": phase_margin_deg,
        "bandwidth_target_hz": bandwidth_hz,
        "crossover_hz": chosen,
        "predicted": predicted,
        "baseline_predicted": fr.margins(),
        "candidates": candidates,
        "plant_model": fr.details.get("source", "measured"),
        "frequency_response": fr,
    }
    return _finish("model_based", base, gains, test, details, threads, client=client)
