"""Typed, immutable result objects of :func:`ehactl.analyze`, :func:`ehactl.sweep`,
:func:`ehactl.diagnose` and the run summaries of :func:`ehactl.run` / :func:`ehactl.run_many`.

They follow the conventions of SciPy's and python-control's result objects
(``scipy.optimize.OptimizeResult``, ``control.FrequencyResponseData``): attribute access
with the quantity's name and unit in it (``res.phase_margin_deg``, ``res.frf.mag_db``),
NumPy arrays for sampled responses, a ``repr`` that summarises a few key figures, and
conversions:

* ``to_dict()`` — the JSON object of the matching CLI command (``ehactl analyze --json``,
  ``ehactl sweep --json``, ``ehactl diagnose --json``, the run summary of ``ehactl run
  --json``) with the same keys and values (non-finite numbers as ``None``, which the CLI
  writes as ``null``); ``from_dict()`` builds the object back from that JSON.
* ``to_pandas()`` — the tabular part as a ``pandas.DataFrame`` (pandas is imported only then;
  without it an ImportError says how to install it).

All classes are frozen dataclasses: assigning an attribute raises
``dataclasses.FrozenInstanceError``, NumPy arrays are read-only and nested mappings are
read-only :class:`FrozenMap` views. (``slots=True`` needs Python 3.10; the package supports
3.9 — Debian 11 / Raspberry Pi OS bullseye, see DEPLOY.md — and ``frozen=True`` already
refuses new attributes.) Construct them with keywords; the fields are in SI units, named
as in the CLI's JSON.

Compatibility: earlier releases returned plain dicts. ``res["phase_margin_deg"]``,
``res.get(...)``, ``res.keys()``, ``key in res`` and iteration still work on these objects
and return what the dict held (e.g. NumPy arrays under ``sweep(...)["f_hz"]``, the replay
``notes`` under ``diagnose(...)["notes"]``), but emit a ``DeprecationWarning``: dict-style
access is removed in the next release; use the attributes. (``RunResult["force"]``, item
access to a run's columns, is not deprecated.)
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Iterator, List, Mapping, Optional, Sequence, Tuple, TypeVar

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    import pandas as pd

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "AnalysisResult",
    "DiagnosisCandidate",
    "DiagnosisResult",
    "FrozenMap",
    "LoopResponse",
    "Margins",
    "NrmseErrors",
    "OperatingPoint",
    "Pole",
    "RunSummary",
    "SddRatios",
    "SweepResponse",
    "SweepResult",
    "UnstablePole",
]

V = TypeVar("V")


class FrozenMap(Mapping[str, V]):
    """A read-only mapping (a picklable stand-in for ``types.MappingProxyType``, which
    cannot be pickled: results travel to Dask workers and through ``multiprocessing``)."""

    __slots__ = ("_d",)
    _d: dict[str, V]

    def __init__(self, data: Mapping[str, V] | None = None) -> None:
        object.__setattr__(self, "_d", dict(data or {}))

    def __getitem__(self, key: str) -> V:
        return self._d[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._d)

    def __len__(self) -> int:
        return len(self._d)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("FrozenMap is read-only")

    def __repr__(self) -> str:
        return f"FrozenMap({self._d!r})"

    def __eq__(self, other: object) -> bool:
        if isinstance(other, Mapping):
            return dict(self.items()) == dict(other.items())
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]  # equal to dicts, which are unhashable

    def __reduce__(self) -> tuple[Any, ...]:
        return (FrozenMap, (dict(self._d),))


def _freeze(v: Any) -> Any:
    """JSON value → immutable: dict → FrozenMap, list → tuple, recursively."""
    if isinstance(v, Mapping):
        return FrozenMap({str(k): _freeze(x) for k, x in v.items()})
    if isinstance(v, (list, tuple)):
        return tuple(_freeze(x) for x in v)
    return v


def _thaw(v: Any) -> Any:
    """Immutable value → JSON value: FrozenMap/dict → dict, tuple → list, arrays → lists,
    non-finite floats → None (as serde_json writes them)."""
    if isinstance(v, Mapping):
        return {str(k): _thaw(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_thaw(x) for x in v]
    if isinstance(v, np.ndarray):
        return [_thaw(x) for x in v.tolist()]
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def _readonly(v: Any) -> Any:
    """Arrays (also inside a FrozenMap) made read-only again, e.g. after unpickling."""
    if isinstance(v, np.ndarray):
        v.setflags(write=False)
    elif isinstance(v, FrozenMap):
        for x in v.values():
            _readonly(x)
    return v


def _setstate_frozen(obj: object, state: Mapping[str, Any]) -> None:
    """``__setstate__`` of the frozen result classes: pickle restores arrays writeable; make
    them read-only again (and bypass the frozen ``__setattr__``)."""
    for k, v in state.items():
        object.__setattr__(obj, k, _readonly(v))


def _f(v: Any) -> float:
    """JSON number (or null for a non-finite value) → float (NaN for null)."""
    return math.nan if v is None else float(v)


def _opt(v: Any) -> Optional[float]:
    """JSON number or null → float or None."""
    return None if v is None else float(v)


def _arr(values: Sequence[Any]) -> FloatArray:
    """Read-only float64 array (null → NaN)."""
    a = np.array([math.nan if x is None else x for x in values], dtype=np.float64)
    a.setflags(write=False)
    return a


def _fmt(x: Optional[float], spec: str = ".4g") -> str:
    return "None" if x is None else format(x, spec)


def _dataframe(columns: Mapping[str, Any]) -> pd.DataFrame:
    """``pandas.DataFrame(columns)``, pandas imported only now (an optional dependency)."""
    try:
        import pandas
    except ImportError as e:
        raise ImportError("to_pandas() needs pandas: pip install pandas (or pip install 'ehactl[pandas]')") from e
    return pandas.DataFrame(columns)


class _DictCompat:
    """Deprecated dict-style access to the result's earlier dict form (see the module doc)."""

    __slots__ = ()

    def to_dict(self) -> dict[str, Any]:  # pragma: no cover - every result overrides it
        raise NotImplementedError

    def _legacy(self) -> dict[str, Any]:
        """The dict earlier releases returned (default: the JSON form)."""
        return self.to_dict()

    def _warn(self, what: str) -> None:
        warnings.warn(
            f"{type(self).__name__}{what}: dict-style access is deprecated and will be removed in "
            "the next release; use the attributes (e.g. res.phase_margin_deg) or res.to_dict()",
            DeprecationWarning,
            stacklevel=3,
        )

    def __setstate__(self, state: Mapping[str, Any]) -> None:
        _setstate_frozen(self, state)

    def __getitem__(self, key: str) -> Any:
        self._warn(f"[{key!r}]")
        return self._legacy()[key]

    def __iter__(self) -> Iterator[str]:
        self._warn(" iteration")
        return iter(self._legacy())

    def get(self, key: str, default: Any = None) -> Any:
        """Deprecated: ``getattr(res, key, default)`` or ``res.to_dict().get(key)``."""
        self._warn(f".get({key!r})")
        return self._legacy().get(key, default)

    def keys(self) -> List[str]:
        """Deprecated: the keys of :meth:`to_dict`."""
        self._warn(".keys()")
        return list(self._legacy())

    def __contains__(self, key: object) -> bool:
        self._warn(f".__contains__({key!r})")
        return key in self._legacy()


# --------------------------------------------------------------------------------------
# ehactl analyze


@dataclass(frozen=True, eq=False)
class Margins(_DictCompat):
    """Stability margins and bandwidths of a loop (``None`` where no crossing exists).

    Attributes:
        gain_crossover_hz: Gain crossover |L| = 1 (Hz).
        phase_margin_deg: Phase margin 180° + ∠L at the gain crossover (deg).
        phase_crossover_hz: Phase crossover ∠L = −180° (Hz).
        gain_margin_db: Gain margin −20·log₁₀|L| at the phase crossover (dB).
        closed_loop_bandwidth_hz: −3 dB bandwidth of the closed loop relative to its low-frequency gain (Hz).
        closed_loop_peak_db: Peak of |T| (dB).
    """

    gain_crossover_hz: Optional[float]
    phase_margin_deg: Optional[float]
    phase_crossover_hz: Optional[float]
    gain_margin_db: Optional[float]
    closed_loop_bandwidth_hz: Optional[float]
    closed_loop_peak_db: float

    _KEYS = ("gain_crossover_hz", "phase_margin_deg", "phase_crossover_hz", "gain_margin_db",
             "closed_loop_bandwidth_hz")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Margins:
        return cls(
            gain_crossover_hz=_opt(d.get("gain_crossover_hz")),
            phase_margin_deg=_opt(d.get("phase_margin_deg")),
            phase_crossover_hz=_opt(d.get("phase_crossover_hz")),
            gain_margin_db=_opt(d.get("gain_margin_db")),
            closed_loop_bandwidth_hz=_opt(d.get("closed_loop_bandwidth_hz")),
            closed_loop_peak_db=_f(d.get("closed_loop_peak_db")),
        )

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: getattr(self, k) for k in self._KEYS}
        out["closed_loop_peak_db"] = _thaw(self.closed_loop_peak_db)
        return out

    def __repr__(self) -> str:
        return (f"Margins(phase_margin_deg={_fmt(self.phase_margin_deg)} at {_fmt(self.gain_crossover_hz)} Hz, "
                f"gain_margin_db={_fmt(self.gain_margin_db)} at {_fmt(self.phase_crossover_hz)} Hz, "
                f"closed_loop_bandwidth_hz={_fmt(self.closed_loop_bandwidth_hz)})")


@dataclass(frozen=True, eq=False)
class OperatingPoint(_DictCompat):
    """The operating point the loop was linearised at (noise-free loop run to rest).

    Attributes:
        reference: Setpoint (N in force mode, m in position mode, V open loop).
        feedback: Fed-back measurement at rest (same unit as ``reference``).
        command_V: Valve command at rest (V).
        position_m: Piston position (m).
        p_a_Pa, p_b_Pa: Chamber pressures (Pa).
        rod_force_N: Rod force (N).
        settled: Whether the loop came to rest within the search time.
        search_time_s: Simulated time the search took (s).
    """

    reference: float
    feedback: float
    command_V: float
    position_m: float
    p_a_Pa: float
    p_b_Pa: float
    rod_force_N: float
    settled: bool
    search_time_s: float

    _FLOATS = ("reference", "feedback", "command_V", "position_m", "p_a_Pa", "p_b_Pa", "rod_force_N",
               "search_time_s")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> OperatingPoint:
        kw: dict[str, Any] = {k: _f(d.get(k)) for k in cls._FLOATS}
        return cls(settled=bool(d.get("settled")), **kw)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: _thaw(getattr(self, k)) for k in self._FLOATS if k != "search_time_s"}
        out["settled"] = self.settled
        out["search_time_s"] = _thaw(self.search_time_s)
        return out

    def __repr__(self) -> str:
        return (f"OperatingPoint(reference={self.reference:.6g}, command_V={self.command_V:.4g}, "
                f"position_m={self.position_m:.4g}, settled={self.settled})")


@dataclass(frozen=True, eq=False)
class Pole(_DictCompat):
    """A pole of the continuous linear plant model.

    Attributes:
        frequency_hz: Natural frequency |λ|/2π (Hz).
        damping_ratio: Damping ratio −Re λ/|λ| (-).
    """

    frequency_hz: float
    damping_ratio: float

    def to_dict(self) -> dict[str, Any]:
        return {"frequency_hz": _thaw(self.frequency_hz), "damping_ratio": _thaw(self.damping_ratio)}

    def __repr__(self) -> str:
        return f"Pole(frequency_hz={self.frequency_hz:.4g}, damping_ratio={self.damping_ratio:.3g})"


@dataclass(frozen=True, eq=False)
class UnstablePole(_DictCompat):
    """A pole of the closed sampled loop outside or on the unit circle.

    Attributes:
        magnitude: |z| (-): growth per control period.
        frequency_hz: |arg z|/(2π·T) (Hz).
        re: Re z (-).
        im: Im z (-), ≥ 0 (each complex pair listed once).
    """

    magnitude: float
    frequency_hz: float
    re: float
    im: float

    _KEYS = ("magnitude", "frequency_hz", "re", "im")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> UnstablePole:
        return cls(**{k: _f(d.get(k)) for k in cls._KEYS})

    def to_dict(self) -> dict[str, Any]:
        return {k: _thaw(getattr(self, k)) for k in self._KEYS}

    def __repr__(self) -> str:
        return f"UnstablePole(magnitude={self.magnitude:.4g}, frequency_hz={self.frequency_hz:.4g})"


@dataclass(frozen=True, eq=False)
class SddRatios(_DictCompat):
    """Frequency ratios and relative damping of an actuator on a spring–damper-mounted load
    (Dindorf et al. 2022, eq. 23–29).

    Attributes:
        k_y: Actuator (hydraulic) stiffness k_y at the position (N/m).
        f_y_hz: f_y = √(k_y/m_y)/2π (Hz).
        f_m_hz: f_m = √(k_m/m_L)/2π (Hz).
        f_e_hz: Excitation frequency (Hz), if periodic.
        fr_ym: f_y/f_m (-).
        fr_em: f_e/f_m (-), if periodic.
        xi_y: ξ_y = d_y/(2√(k_y·m_y)) (-).
        xi_m: ξ_m = d_m/(2√(k_m·m_L)) (-).
        rd_my: ξ_m/ξ_y (-).
    """

    k_y: float
    f_y_hz: float
    f_m_hz: float
    f_e_hz: Optional[float]
    fr_ym: float
    fr_em: Optional[float]
    xi_y: float
    xi_m: float
    rd_my: float

    _ORDER = ("k_y", "f_y_hz", "f_m_hz", "f_e_hz", "fr_ym", "fr_em", "xi_y", "xi_m", "rd_my")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SddRatios:
        return cls(k_y=_f(d.get("k_y")), f_y_hz=_f(d.get("f_y_hz")), f_m_hz=_f(d.get("f_m_hz")),
                   f_e_hz=_opt(d.get("f_e_hz")), fr_ym=_f(d.get("fr_ym")), fr_em=_opt(d.get("fr_em")),
                   xi_y=_f(d.get("xi_y")), xi_m=_f(d.get("xi_m")), rd_my=_f(d.get("rd_my")))

    def to_dict(self) -> dict[str, Any]:
        return {k: _thaw(getattr(self, k)) for k in self._ORDER}

    def __repr__(self) -> str:
        return f"SddRatios(fr_ym={self.fr_ym:.4g}, fr_em={_fmt(self.fr_em)}, rd_my={self.rd_my:.4g})"


class _FrequencyColumns(_DictCompat):
    """A table over frequency held as equal-length arrays, one per name in ``_KEYS`` (the
    first is the frequency in Hz): the shared behaviour of :class:`LoopResponse` and
    :class:`SweepResponse`."""

    __slots__ = ()
    _KEYS: ClassVar[Tuple[str, ...]] = ()

    @classmethod
    def from_points(cls: type[C], points: Sequence[Mapping[str, Any]]) -> C:
        """From the JSON's list of per-frequency objects."""
        return cls(**{k: _arr([p.get(k) for p in points]) for k in cls._KEYS})

    def to_points(self) -> list[dict[str, Any]]:
        cols = [getattr(self, k) for k in self._KEYS]
        return [{k: _thaw(float(c[i])) for k, c in zip(self._KEYS, cols)} for i in range(len(self))]

    def to_dict(self) -> dict[str, Any]:
        """Column form: ``{name: list}``."""
        return {k: _thaw(getattr(self, k)) for k in self._KEYS}

    def __len__(self) -> int:
        return len(getattr(self, self._KEYS[0]))

    def to_pandas(self) -> pd.DataFrame:
        """``pandas.DataFrame`` with one row per frequency, the columns above."""
        return _dataframe({k: np.array(getattr(self, k)) for k in self._KEYS})

    def __repr__(self) -> str:
        name = type(self).__name__
        if len(self) == 0:
            return f"{name}(0 points)"
        f = getattr(self, self._KEYS[0])
        return f"{name}({len(self)} points, {f[0]:.4g}–{f[-1]:.4g} Hz)"


C = TypeVar("C", bound=_FrequencyColumns)


@dataclass(frozen=True, eq=False)
class LoopResponse(_FrequencyColumns):
    """Frequency response of the sampled loop on a log grid: loop gain L and closed loop
    T = L/(1 + L). Arrays of equal length (empty in open loop).

    Attributes:
        f_hz: Frequency (Hz).
        loop_mag_db: |L| (dB).
        loop_phase_deg: ∠L (deg, wrapped to (−360°, 0°]).
        closed_mag_db: |T| (dB).
        closed_phase_deg: ∠T (deg, wrapped to (−360°, 0°]).
    """

    f_hz: FloatArray
    loop_mag_db: FloatArray
    loop_phase_deg: FloatArray
    closed_mag_db: FloatArray
    closed_phase_deg: FloatArray

    _KEYS = ("f_hz", "loop_mag_db", "loop_phase_deg", "closed_mag_db", "closed_phase_deg")

    def _legacy(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self._KEYS}


@dataclass(frozen=True, eq=False)
class AnalysisResult(_DictCompat):
    """The loop linearised at its operating point: ``ehactl analyze --json`` as an object.

    The top-level margins are those of the sampled loop (zero-order hold at the control
    rate, discrete control law; ``sampled_loop`` True); ``continuous`` holds the
    continuous-time loop's (ideal PI/PD, no sampling), as the papers compute them. A margin
    is ``None`` where its crossing does not exist (e.g. no phase crossover: no gain margin).

    Attributes:
        rig: Rig name.
        sampled_loop: True when a control law is configured and the margins are the sampled loop's.
        loop_model: The loop model in words.
        control_rate_hz: Control rate (Hz).
        delay_s: Command delay included as e^(−jωτ) (s).
        hydraulic_natural_frequency_hz: √(K_h/m)/2π at the operating position (Hz).
        min_natural_frequency_over_stroke_hz: Lowest hydraulic natural frequency over the stroke (Hz) …
        min_natural_frequency_position_m: … and where it is (m).
        open_loop_bandwidth_hz: −3 dB bandwidth of the plant (command → output) when it has a static gain (Hz).
        gain_crossover_hz: Sampled loop: gain crossover |L| = 1 (Hz).
        phase_margin_deg: Sampled loop: phase margin at the gain crossover (deg).
        phase_crossover_hz: Sampled loop: phase crossover ∠L = −180° (Hz).
        gain_margin_db: Sampled loop: gain margin at the phase crossover (dB).
        closed_loop_bandwidth_hz: Sampled loop: closed-loop −3 dB bandwidth (Hz).
        closed_loop_peak_db: Sampled loop: peak of |T| (dB).
        continuous: Margins of the continuous-time loop.
        stable: Stability of the linearised sampled loop from its closed-loop poles (every
            |z| < 1); None in open loop. An unstable loop has no closed-loop bandwidth or
            peak (``None``; ``closed_loop_bandwidth_note`` says why).
        max_closed_loop_pole_magnitude: Largest |z| of the closed-loop poles (-), or None.
        unstable_poles: The closed-loop poles with |z| ≥ 1 + 1e-6 (:class:`UnstablePole`), largest first.
        marginal_poles: The closed-loop poles within 1e-6 of the unit circle (modes the loop
            does not act on at its operating point; they do not make it unstable).
        closed_loop_bandwidth_note: Why the bandwidth is left out (unstable loop), or None.
        operating_point: Operating point of the linearisation.
        poles: Slowest poles of the continuous plant model.
        loop_response: Sampled-loop frequency response (``res.loop_response.f_hz`` …).
        fr_ym, fr_em, rd_my: Dindorf et al. 2022 ratios f_y/f_m, f_e/f_m, ξ_m/ξ_y (-) with a
            flexibly mounted load; None otherwise (``fr_em`` also without a periodic excitation).
        sdd: All Dindorf et al. 2022 quantities (:class:`SddRatios`), or None.
    """

    rig: str
    sampled_loop: bool
    loop_model: str
    control_rate_hz: float
    delay_s: float
    hydraulic_natural_frequency_hz: float
    min_natural_frequency_over_stroke_hz: float
    min_natural_frequency_position_m: float
    open_loop_bandwidth_hz: Optional[float]
    gain_crossover_hz: Optional[float]
    phase_margin_deg: Optional[float]
    phase_crossover_hz: Optional[float]
    gain_margin_db: Optional[float]
    closed_loop_bandwidth_hz: Optional[float]
    closed_loop_peak_db: Optional[float]
    continuous: Optional[Margins]
    stable: Optional[bool]
    max_closed_loop_pole_magnitude: Optional[float]
    unstable_poles: Tuple[UnstablePole, ...]
    marginal_poles: Tuple[UnstablePole, ...]
    closed_loop_bandwidth_note: Optional[str]
    operating_point: OperatingPoint
    poles: Tuple[Pole, ...]
    loop_response: LoopResponse
    fr_ym: Optional[float]
    fr_em: Optional[float]
    rd_my: Optional[float]
    sdd: Optional[SddRatios]

    _SAMPLED = ("gain_crossover_hz", "phase_margin_deg", "phase_crossover_hz", "gain_margin_db",
                "closed_loop_bandwidth_hz", "closed_loop_peak_db")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> AnalysisResult:
        """From the ``ehactl analyze --json`` object."""
        cont = d.get("continuous")
        sdd = d.get("sdd")
        return cls(
            rig=str(d["rig"]),
            sampled_loop=bool(d.get("sampled_loop")),
            loop_model=str(d.get("loop_model", "")),
            control_rate_hz=_f(d.get("control_rate_hz")),
            delay_s=_f(d.get("delay_s")),
            hydraulic_natural_frequency_hz=_f(d.get("hydraulic_natural_frequency_hz")),
            min_natural_frequency_over_stroke_hz=_f(d.get("min_natural_frequency_over_stroke_hz")),
            min_natural_frequency_position_m=_f(d.get("min_natural_frequency_position_m")),
            open_loop_bandwidth_hz=_opt(d.get("open_loop_bandwidth_hz")),
            gain_crossover_hz=_opt(d.get("gain_crossover_hz")),
            phase_margin_deg=_opt(d.get("phase_margin_deg")),
            phase_crossover_hz=_opt(d.get("phase_crossover_hz")),
            gain_margin_db=_opt(d.get("gain_margin_db")),
            closed_loop_bandwidth_hz=_opt(d.get("closed_loop_bandwidth_hz")),
            closed_loop_peak_db=_opt(d.get("closed_loop_peak_db")),
            continuous=None if cont is None else Margins.from_dict(cont),
            stable=None if d.get("stable") is None else bool(d["stable"]),
            max_closed_loop_pole_magnitude=_opt(d.get("max_closed_loop_pole_magnitude")),
            unstable_poles=tuple(UnstablePole.from_dict(q) for q in d.get("unstable_poles") or []),
            marginal_poles=tuple(UnstablePole.from_dict(q) for q in d.get("marginal_poles") or []),
            closed_loop_bandwidth_note=d.get("closed_loop_bandwidth_note"),
            operating_point=OperatingPoint.from_dict(d.get("operating_point") or {}),
            poles=tuple(Pole(frequency_hz=_f(p.get("frequency_hz")), damping_ratio=_f(p.get("damping_ratio")))
                        for p in d.get("poles") or []),
            loop_response=LoopResponse.from_points(d.get("loop_response") or []),
            fr_ym=_opt(d.get("fr_ym")),
            fr_em=_opt(d.get("fr_em")),
            rd_my=_opt(d.get("rd_my")),
            sdd=None if sdd is None else SddRatios.from_dict(sdd),
        )

    def to_dict(self) -> dict[str, Any]:
        """The ``ehactl analyze --json`` object (keys that do not apply are left out, as the
        CLI leaves them out)."""
        out: dict[str, Any] = {
            "rig": self.rig,
            "hydraulic_natural_frequency_hz": _thaw(self.hydraulic_natural_frequency_hz),
            "min_natural_frequency_over_stroke_hz": _thaw(self.min_natural_frequency_over_stroke_hz),
            "min_natural_frequency_position_m": _thaw(self.min_natural_frequency_position_m),
            "operating_point": self.operating_point.to_dict(),
            "control_rate_hz": _thaw(self.control_rate_hz),
            "delay_s": _thaw(self.delay_s),
            "poles": [p.to_dict() for p in self.poles],
            "loop_response": self.loop_response.to_points(),
        }
        if self.open_loop_bandwidth_hz is not None:
            out["open_loop_bandwidth_hz"] = self.open_loop_bandwidth_hz
        out["sampled_loop"] = self.sampled_loop
        out["loop_model"] = self.loop_model
        if self.sampled_loop:
            for k in self._SAMPLED[:-1]:  # written only where the crossing exists
                v = getattr(self, k)
                if v is not None:
                    out[k] = v
            out["closed_loop_peak_db"] = self.closed_loop_peak_db  # always (null if not finite)
        if self.stable is not None:  # with the poles of a sampled loop
            out["stable"] = self.stable
            out["max_closed_loop_pole_magnitude"] = self.max_closed_loop_pole_magnitude
            out["unstable_poles"] = [q.to_dict() for q in self.unstable_poles]
            out["marginal_poles"] = [q.to_dict() for q in self.marginal_poles]
            if self.closed_loop_bandwidth_note is not None:
                out["closed_loop_bandwidth_note"] = self.closed_loop_bandwidth_note
        if self.continuous is not None:
            out["continuous"] = self.continuous.to_dict()
        if self.sdd is not None:  # the ratios come with the SDD section
            out["fr_ym"] = self.fr_ym
            if self.fr_em is not None:
                out["fr_em"] = self.fr_em
            out["rd_my"] = self.rd_my
            out["sdd"] = self.sdd.to_dict()
        return out

    def _legacy(self) -> dict[str, Any]:
        out = self.to_dict()
        out["loop_response"] = self.loop_response._legacy()
        return out

    @property
    def margins(self) -> Margins:
        """The sampled loop's margins as a :class:`Margins` (like ``continuous``)."""
        return Margins(
            gain_crossover_hz=self.gain_crossover_hz,
            phase_margin_deg=self.phase_margin_deg,
            phase_crossover_hz=self.phase_crossover_hz,
            gain_margin_db=self.gain_margin_db,
            closed_loop_bandwidth_hz=self.closed_loop_bandwidth_hz,
            closed_loop_peak_db=math.nan if self.closed_loop_peak_db is None else self.closed_loop_peak_db,
        )

    def to_pandas(self) -> pd.DataFrame:
        """The sampled-loop frequency response (:meth:`LoopResponse.to_pandas`)."""
        return self.loop_response.to_pandas()

    def __repr__(self) -> str:
        return (f"AnalysisResult(rig={self.rig!r}, phase_margin_deg={_fmt(self.phase_margin_deg)} at "
                f"{_fmt(self.gain_crossover_hz)} Hz, gain_margin_db={_fmt(self.gain_margin_db)}, "
                f"closed_loop_bandwidth_hz={_fmt(self.closed_loop_bandwidth_hz)}, "
                f"hydraulic_natural_frequency_hz={self.hydraulic_natural_frequency_hz:.4g}, "
                f"sampled_loop={self.sampled_loop})")


# --------------------------------------------------------------------------------------
# ehactl sweep


@dataclass(frozen=True, eq=False)
class SweepResponse(_FrequencyColumns):
    """Measured frequency response H = output/input, one entry per frequency.

    Attributes:
        f_hz: Frequency (Hz).
        mag_db: 20·log₁₀|H| (dB of output unit per input unit).
        phase_deg: ∠H (deg), unwrapped along the sweep.
        coherence: Magnitude coherence γ² over the 4 fit blocks (-).
        gain: |H| (output unit per input unit).
        distortion: RMS of the output's sine-fit residual over the fitted amplitude (-).
    """

    f_hz: FloatArray
    mag_db: FloatArray
    phase_deg: FloatArray
    coherence: FloatArray
    gain: FloatArray
    distortion: FloatArray

    _KEYS = ("f_hz", "mag_db", "phase_deg", "coherence", "gain", "distortion")


@dataclass(frozen=True, eq=False)
class SweepResult(_DictCompat):
    """Stepped-sine frequency response of the nonlinear plant: ``ehactl sweep --json`` as
    an object; the measured points are ``res.frf`` (``res.frf.f_hz``, ``res.frf.mag_db`` …).

    Attributes:
        mode: ``"closed_loop"`` (setpoint → output) or ``"open_loop"`` (valve command → output).
        input: Input signal and its unit.
        output: Output channel and its unit.
        offset: Static value the sine rides on (input units).
        amplitude: Sine amplitude (input units).
        dwell_s: Dwell per frequency (s).
        frf: The measured frequency response.
        bandwidth_hz: −3 dB bandwidth relative to the lowest frequency's gain (Hz), None if not reached.
        duration_s: Simulated time (s).
        complete: False when the run was cut short (signal or trip); ``frf`` then covers what was
            measured.
        trip: Trip reason, if the supervisor stopped the sweep.
        mcap: MCAP log path.
    """

    mode: str
    input: str
    output: str
    offset: float
    amplitude: float
    dwell_s: float
    frf: SweepResponse
    bandwidth_hz: Optional[float]
    duration_s: float
    complete: bool
    trip: Optional[str]
    mcap: Optional[str]

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SweepResult:
        """From the ``ehactl sweep --json`` object."""
        return cls(
            mode=str(d["mode"]), input=str(d["input"]), output=str(d["output"]),
            offset=_f(d.get("offset")), amplitude=_f(d.get("amplitude")), dwell_s=_f(d.get("dwell_s")),
            frf=SweepResponse.from_points(d.get("points") or []),
            bandwidth_hz=_opt(d.get("bandwidth_hz")), duration_s=_f(d.get("duration_s")),
            complete=bool(d.get("complete")), trip=d.get("trip"), mcap=d.get("mcap"),
        )

    def to_dict(self) -> dict[str, Any]:
        """The ``ehactl sweep --json`` object."""
        return {
            "mode": self.mode, "input": self.input, "output": self.output,
            "offset": _thaw(self.offset), "amplitude": _thaw(self.amplitude), "dwell_s": _thaw(self.dwell_s),
            "points": self.frf.to_points(), "bandwidth_hz": self.bandwidth_hz,
            "duration_s": _thaw(self.duration_s), "complete": self.complete, "trip": self.trip, "mcap": self.mcap,
        }

    def _legacy(self) -> dict[str, Any]:
        out = self.to_dict()
        del out["points"]
        for k in SweepResponse._KEYS:
            out[k] = getattr(self.frf, k)
        return out

    def to_pandas(self) -> pd.DataFrame:
        """The measured points (:meth:`SweepResponse.to_pandas`)."""
        return self.frf.to_pandas()

    def __repr__(self) -> str:
        r = (f"SweepResult({self.mode}, {self.input} → {self.output}, {len(self.frf)} points"
             + (f" {self.frf.f_hz[0]:.4g}–{self.frf.f_hz[-1]:.4g} Hz" if len(self.frf) else "")
             + f", bandwidth_hz={_fmt(self.bandwidth_hz)}, complete={self.complete}")
        return r + (f", trip={self.trip!r})" if self.trip else ")")


# --------------------------------------------------------------------------------------
# ehactl diagnose


@dataclass(frozen=True, eq=False)
class NrmseErrors(_DictCompat):
    """Held-out error of one model: NRMSE (rms error / std of the measured channel, -).

    Attributes:
        channels: NRMSE per measured channel (-).
        overall: Root mean square over the channels (-).
    """

    channels: Mapping[str, float]
    overall: float

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> NrmseErrors:
        return cls(channels=FrozenMap({str(k): _f(v) for k, v in (d.get("channels") or {}).items()}),
                   overall=_f(d.get("overall")))

    def to_dict(self) -> dict[str, Any]:
        return {"channels": _thaw(self.channels), "overall": _thaw(self.overall)}

    def __repr__(self) -> str:
        ch = ", ".join(f"{k}={v:.4g}" for k, v in self.channels.items())
        return f"NrmseErrors(overall={self.overall:.4g}; {ch})"


@dataclass(frozen=True, eq=False)
class DiagnosisCandidate(_DictCompat):
    """One catalogue effect tested against the refit nominal model.

    Attributes:
        effect: Effect id.
        variant: Structural variant that fitted best (``-`` for effects with one form).
        params: Fitted parameters (dotted config path → value in the path's SI unit;
            ``<path>/nominal`` marks factors on nominal values).
        nrmse_train: Overall NRMSE on the fitting data (-).
        nrmse_validation: Overall NRMSE on the held-out data (-).
        score: ln(J_validation) + 0.02·(free parameters), lower is better (-).
        accepted: Whether the effect was accepted into the extended model.
        evidence: What the residual analysis and the fit say, in one line.
    """

    effect: str
    variant: str
    params: Mapping[str, float]
    nrmse_train: float
    nrmse_validation: float
    score: float
    accepted: bool
    evidence: str

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> DiagnosisCandidate:
        return cls(effect=str(d["effect"]), variant=str(d.get("variant", "-")),
                   params=FrozenMap({str(k): _f(v) for k, v in (d.get("params") or {}).items()}),
                   nrmse_train=_f(d.get("nrmse_train")), nrmse_validation=_f(d.get("nrmse_validation")),
                   score=_f(d.get("score")), accepted=bool(d.get("accepted")), evidence=str(d.get("evidence", "")))

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "variant": self.variant, "params": _thaw(self.params),
                "nrmse_train": _thaw(self.nrmse_train), "nrmse_validation": _thaw(self.nrmse_validation),
                "score": _thaw(self.score), "accepted": self.accepted, "evidence": self.evidence}

    def __repr__(self) -> str:
        return (f"DiagnosisCandidate({self.effect!r}, nrmse_validation={self.nrmse_validation:.4g}, "
                f"score={self.score:.4g}, accepted={self.accepted})")


@dataclass(frozen=True, eq=False)
class DiagnosisResult(_DictCompat):
    """What the simulation of a config gets wrong on measured data: ``ehactl diagnose
    --json`` as an object (see DIAGNOSIS.md for every field's method).

    The deeper sections (``baseline``, ``residual_test``, ``integration``, ``greybox``,
    ``analysis``, ``analysis_refit``) are read-only mappings in the JSON's form.

    Attributes:
        cause: Top effect id, ``"none"`` (the nominal model explains the data within the noise) or
            ``"unexplained"``.
        status: ``"none"``, ``"explained"``, ``"edge_fit"`` (the closest catalogue effect's fit
            sits on a bound of its range or outside what the record can show; the cause is then
            ``"unexplained"``), ``"not_explained"`` (it leaves a channel far above its noise
            floor; likewise) or ``"unexplained"``.
        closest: The closest catalogue effect when it is not the cause (``effect``,
            ``variant``, ``at_edge``, ``reasons``, ``nrmse_validation``), or None.
        detection_limits: For every catalogue effect tested and not named, the smallest size
            this record would have revealed (effect id → ``parameter``, ``unit``, ``stronger``,
            ``limit`` or None, ``range``, ``note``, ``looseness``, ``variant``: the structure
            hardest to see that the limit holds for, ``shape`` where it is not the
            catalogue's start values (a mount's mass, one shape parameter moved), ``method``:
            ``linearised``, ``injected`` or ``raised by injection``).
        next_tests: The tests that would tighten the loose limits and separate the
            ambiguities (``purpose``, ``effects``, ``excitation``, ``why``, ``file``, ``setpoint``:
            a ``[setpoint]`` section for ``ehactl run``, ``duration`` in s).
        envelope: The held-out part (or ``--validate`` record) against the motion the
            diagnosis fitted (``inside``, ``excursions``: quantity, record, fitted, unit,
            beyond, text), or None without a position column.
        causes: Accepted effect ids, the one that explains most of the held-out error on the final model first.
        variants: Structural variant of each accepted effect.
        nrmse_nominal, nrmse_refit, nrmse_extended, nrmse_baseline: held-out NRMSE of
            the nominal model, the refit nominal model (nominal parameters within their
            stated uncertainty), the extended model and the ARX baseline.
        gain: 1 − overall extended / overall nominal NRMSE (-).
        noise_floor: Estimated noise floor of the overall held-out NRMSE (-).
        candidates: Every catalogue effect tested.
        extended_params: Parameters of the extended model (dotted path → SI value).
        refit_at_bounds, extended_at_bounds: Nominal parameters the refit / the extended model left on a bound of their
            uncertainty.
        sensor_offsets: Sensor offsets per channel (N, m or Pa); empty unless ``sensor_offsets=True``.
        ambiguities: Effect pairs the data cannot separate, with the experiment that would.
        refit_continued: Where the search went on from a better nominal fit than the refit's (a
            candidate whose effect did not carry its gain; one sentence each).
        dropped_effects: Catalogue effects accepted on the fitting part but dropped for a
            grey-box law that predicts the held-out part better, while they lost to the ARX
            baseline there (``effects`` and the held-out NRMSEs), or None.
        beaten_by_baseline: True when the catalogue model lost to ARX on the held-out part and
            no grey-box law beat ARX either (the cause is then ``unexplained``).
        warnings: Warnings from loading and checking the data (also issued as Python warnings).
        split, summary: How the data were split; plain-words conclusion.
        extended_config, report, plots: Written files (None when no ``out`` directory was given).
        identified_loop: the assumed loop identified on the position channel (None when the
            config does not mark its loop as an assumption).
        baseline, residual_test, integration, greybox, analysis, analysis_refit: sections
            kept in the JSON's form (read-only mappings; ``greybox`` None when it did not run).
        notes: Replay notes of the Python call (not part of the CLI's JSON).
        headline: The text output's first line: the recommended model (the one
            ``extended.toml`` holds) with its held-out NRMSE beside nominal and ARX.
        recommended: That model in words (``model``) and its held-out ``nrmse``, with the
            ``nominal`` and ``arx`` figures on the same split.
    """

    cause: str
    causes: Tuple[str, ...]
    variants: Mapping[str, str]
    nrmse_nominal: NrmseErrors
    nrmse_refit: NrmseErrors
    nrmse_extended: NrmseErrors
    nrmse_baseline: NrmseErrors
    gain: float
    noise_floor: float
    candidates: Tuple[DiagnosisCandidate, ...]
    extended_params: Mapping[str, float]
    refit_at_bounds: Tuple[str, ...]
    extended_at_bounds: Tuple[str, ...]
    sensor_offsets: Mapping[str, float]
    ambiguities: Tuple[str, ...]
    warnings: Tuple[str, ...]
    split: str
    summary: str
    extended_config: Optional[str]
    report: Optional[str]
    plots: Optional[Tuple[str, ...]]
    baseline: Mapping[str, Any]
    residual_test: Mapping[str, Any]
    integration: Mapping[str, Any]
    greybox: Optional[Mapping[str, Any]]
    analysis: Mapping[str, Any]
    analysis_refit: Mapping[str, Any]
    identified_loop: Optional[Mapping[str, Any]] = None
    refit_continued: Tuple[str, ...] = ()
    dropped_effects: Optional[Mapping[str, Any]] = None
    beaten_by_baseline: bool = False
    notes: Tuple[str, ...] = ()
    headline: str = ""
    recommended: Optional[Mapping[str, Any]] = None
    status: str = ""
    closest: Optional[Mapping[str, Any]] = None
    detection_limits: Mapping[str, Any] = field(default_factory=lambda: FrozenMap({}))
    next_tests: Tuple[Mapping[str, Any], ...] = ()
    envelope: Optional[Mapping[str, Any]] = None

    # JSON key order of `ehactl diagnose --json` (serde field order, then the files).
    _ORDER = ("cause", "status", "closest", "detection_limits", "next_tests", "causes", "variants", "nrmse_nominal", "nrmse_refit", "nrmse_extended",
              "nrmse_baseline", "baseline", "residual_test", "integration", "greybox", "gain",
              "noise_floor", "candidates", "extended_params", "identified_loop", "refit_at_bounds", "extended_at_bounds",
              "sensor_offsets", "ambiguities", "refit_continued",
              "dropped_effects", "beaten_by_baseline", "warnings", "analysis", "analysis_refit", "split",
              "summary", "extended_config", "report", "plots", "recommended", "headline", "envelope")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], notes: Sequence[str] = ()) -> DiagnosisResult:
        """From the ``ehactl diagnose --json`` object (``notes``: replay notes, Python only)."""

        def strs(k: str) -> Tuple[str, ...]:
            return tuple(str(x) for x in d.get(k) or [])

        def floats(k: str) -> FrozenMap[float]:
            return FrozenMap({str(a): _f(b) for a, b in (d.get(k) or {}).items()})

        plots = d.get("plots")
        gb = d.get("greybox")
        return cls(
            cause=str(d["cause"]), causes=strs("causes"),
            variants=FrozenMap({str(a): str(b) for a, b in (d.get("variants") or {}).items()}),
            nrmse_nominal=NrmseErrors.from_dict(d.get("nrmse_nominal") or {}),
            nrmse_refit=NrmseErrors.from_dict(d.get("nrmse_refit") or {}),
            nrmse_extended=NrmseErrors.from_dict(d.get("nrmse_extended") or {}),
            nrmse_baseline=NrmseErrors.from_dict(d.get("nrmse_baseline") or {}),
            gain=_f(d.get("gain")), noise_floor=_f(d.get("noise_floor")),
            candidates=tuple(DiagnosisCandidate.from_dict(c) for c in d.get("candidates") or []),
            extended_params=floats("extended_params"),
            refit_at_bounds=strs("refit_at_bounds"), extended_at_bounds=strs("extended_at_bounds"),
            sensor_offsets=floats("sensor_offsets"), ambiguities=strs("ambiguities"), warnings=strs("warnings"),
            split=str(d.get("split", "")), summary=str(d.get("summary", "")),
            extended_config=d.get("extended_config"), report=d.get("report"),
            plots=None if plots is None else tuple(str(p) for p in plots),
            baseline=_freeze(d.get("baseline") or {}), residual_test=_freeze(d.get("residual_test") or {}),
            integration=_freeze(d.get("integration") or {}), greybox=None if gb is None else _freeze(gb),
            analysis=_freeze(d.get("analysis") or {}), analysis_refit=_freeze(d.get("analysis_refit") or {}),
            identified_loop=None if d.get("identified_loop") is None else _freeze(d["identified_loop"]),
            refit_continued=strs("refit_continued"),
            dropped_effects=None if d.get("dropped_effects") is None else _freeze(d["dropped_effects"]),
            beaten_by_baseline=bool(d.get("beaten_by_baseline", False)),
            notes=tuple(str(n) for n in notes),
            headline=str(d.get("headline", "")),
            recommended=None if d.get("recommended") is None else _freeze(d["recommended"]),
            status=str(d.get("status", "")),
            closest=None if d.get("closest") is None else _freeze(d["closest"]),
            detection_limits=_freeze(d.get("detection_limits") or {}),
            next_tests=tuple(_freeze(t) for t in d.get("next_tests") or []),
            envelope=None if d.get("envelope") is None else _freeze(d["envelope"]),
        )

    def to_dict(self) -> dict[str, Any]:
        """The ``ehactl diagnose --json`` object (``notes`` are not part of it)."""
        out: dict[str, Any] = {}
        for k in self._ORDER:
            v = getattr(self, k)
            if isinstance(v, _DictCompat):
                out[k] = v.to_dict()
            elif k == "candidates":
                out[k] = [c.to_dict() for c in self.candidates]
            else:
                out[k] = _thaw(v)
        return out

    def _legacy(self) -> dict[str, Any]:
        out = self.to_dict()
        out["notes"] = list(self.notes)
        return out

    def to_pandas(self) -> pd.DataFrame:
        """The candidates as a ``pandas.DataFrame`` (one row per effect, fitted parameters
        as ``param:<dotted path>`` columns, NaN where an effect has no such parameter)."""
        cols: dict[str, list[Any]] = {k: [getattr(c, k) for c in self.candidates]
                                      for k in ("effect", "variant", "nrmse_train", "nrmse_validation", "score",
                                                "accepted", "evidence")}
        params = sorted({k for c in self.candidates for k in c.params})
        for k in params:
            cols[f"param:{k}"] = [c.params.get(k, math.nan) for c in self.candidates]
        return _dataframe(cols)

    def __repr__(self) -> str:
        return (f"DiagnosisResult(cause={self.cause!r}, causes={list(self.causes)}, "
                f"nrmse {self.nrmse_nominal.overall:.4g} → {self.nrmse_extended.overall:.4g} "
                f"(gain {self.gain:.1%}), {len(self.candidates)} candidates, {len(self.warnings)} warnings)")


# --------------------------------------------------------------------------------------
# runs


@dataclass(frozen=True, eq=False)
class RunSummary(_DictCompat):
    """Summary of one closed-loop run (the ``summary`` JSON of ``ehactl run``).

    Attributes:
        cycles: Control cycles run.
        control_rate_hz: Control rate (Hz).
        duration_s: Simulated duration (s).
        rms_error, rms_error_settled, max_abs_error: RMS setpoint error over the run and after settling, largest |error|
            (``error_unit``); None when not finite.
        error_unit: Unit of the errors: "N" (force), "m" (position) or "V" (open loop).
        mcap: MCAP log path, if one was written.
        trip, trip_kind: The supervisor's one-line trip reason and its kind, if the run tripped.
        interrupted: Whether the run was interrupted (Ctrl-C).
        sim_speed_x_realtime, wall_time_s: Simulated time over wall time (-); wall time (s).
        substeps, log_decimation: Plant integration substeps per control cycle; one logged cycle in
            ``log_decimation``.
        log: Log statistics (records written / dropped, queue high water …) when an MCAP was
            written.
        realtime: Whether the run was paced in real time (never from Python).
        extra: Any further keys of the summary JSON (real-time timing, backend report), read-only.
    """

    cycles: int
    control_rate_hz: float
    duration_s: float
    rms_error: Optional[float]
    rms_error_settled: Optional[float]
    max_abs_error: Optional[float]
    error_unit: str
    mcap: Optional[str]
    trip: Optional[str]
    trip_kind: Optional[str]
    interrupted: bool
    sim_speed_x_realtime: float
    wall_time_s: float
    substeps: int
    log_decimation: int
    log: Optional[Mapping[str, Any]]
    realtime: bool
    extra: Mapping[str, Any]

    _ORDER = ("cycles", "control_rate_hz", "duration_s", "rms_error", "rms_error_settled", "max_abs_error",
              "error_unit", "mcap", "trip", "trip_kind", "interrupted", "sim_speed_x_realtime",
              "wall_time_s", "substeps", "log_decimation", "log", "realtime")

    # Keys every run summary has (``ehactl run --json``); from_dict refuses a dict without them.
    _REQUIRED = ("cycles", "control_rate_hz", "duration_s", "error_unit")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> RunSummary:
        """Summary from its JSON object (``ehactl run --json``, ``to_dict()``).

        Raises TypeError when ``d`` is not a mapping and ValueError naming the field when a
        required field (``cycles``, ``control_rate_hz``, ``duration_s``, ``error_unit``) is
        missing or a field has the wrong type or an impossible value.
        """
        if not isinstance(d, Mapping):
            raise TypeError(
                f"RunSummary.from_dict: got {type(d).__name__}; expected a mapping (the run summary JSON object)"
            )
        missing = [k for k in cls._REQUIRED if k not in d]
        if missing:
            raise ValueError(
                f"RunSummary.from_dict: missing field(s) {', '.join(missing)}; expected a run summary "
                f"(keys {', '.join(cls._REQUIRED)}, …)"
            )

        def num(key: str, kind: type, optional: bool = False, default: Any = None) -> Any:
            v = d.get(key, default)
            if v is None and (optional or key not in d):
                return None if optional else (math.nan if kind is float else 0)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(
                    f"RunSummary.from_dict: field `{key}` = {v!r:.80}; expected a {kind.__name__}"
                    + (" or None" if optional else "")
                )
            if kind is int:
                if isinstance(v, float) and not v.is_integer():
                    raise ValueError(f"RunSummary.from_dict: field `{key}` = {v!r}; expected an int")
                if v < 0:
                    raise ValueError(f"RunSummary.from_dict: field `{key}` = {v!r}; expected an int ≥ 0")
                return int(v)
            return float(v)

        def text(key: str, optional: bool = True) -> Optional[str]:
            v = d.get(key)
            if v is None and optional:
                return None
            if not isinstance(v, str):
                raise ValueError(f"RunSummary.from_dict: field `{key}` = {v!r:.80}; expected a str")
            return v

        log = d.get("log")
        if log is not None and not isinstance(log, Mapping):
            raise ValueError(f"RunSummary.from_dict: field `log` = {log!r:.80}; expected a mapping or None")
        cycles = num("cycles", int)
        rate = num("control_rate_hz", float)
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"RunSummary.from_dict: field `control_rate_hz` = {rate!r}; expected a finite number > 0 in Hz")
        duration = num("duration_s", float)
        if not (math.isfinite(duration) and duration >= 0):
            raise ValueError(f"RunSummary.from_dict: field `duration_s` = {duration!r}; expected a finite number ≥ 0 in s")
        return cls(
            cycles=cycles, control_rate_hz=rate, duration_s=duration,
            rms_error=num("rms_error", float, optional=True),
            rms_error_settled=num("rms_error_settled", float, optional=True),
            max_abs_error=num("max_abs_error", float, optional=True),
            error_unit=str(text("error_unit", optional=False)), mcap=text("mcap"), trip=text("trip"),
            trip_kind=text("trip_kind"), interrupted=bool(d.get("interrupted")),
            sim_speed_x_realtime=num("sim_speed_x_realtime", float), wall_time_s=num("wall_time_s", float),
            substeps=num("substeps", int), log_decimation=num("log_decimation", int),
            log=None if log is None else _freeze(log), realtime=bool(d.get("realtime")),
            extra=_freeze({k: v for k, v in d.items() if k not in cls._ORDER}),
        )

    def to_dict(self) -> dict[str, Any]:
        out = {k: _thaw(getattr(self, k)) for k in self._ORDER}
        out.update(_thaw(self.extra))
        return out

    def __repr__(self) -> str:
        u = self.error_unit
        r = (f"RunSummary({self.cycles} cycles, {self.duration_s:.4g} s, rms_error={_fmt(self.rms_error)} {u}, "
             f"max_abs_error={_fmt(self.max_abs_error)} {u}")
        return r + (f", trip={self.trip!r})" if self.trip else ")")

