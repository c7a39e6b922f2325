"""Runs, batches, results and MCAP reading (thin Python layer over ``ehactl._ehactl``)."""

from __future__ import annotations

import errno
import itertools
import json
import os
from pathlib import Path
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Generic, Iterable, Literal, Mapping, NoReturn, Sequence, TypeVar, Union, overload

import numpy as np
import numpy.typing as npt

from . import _ehactl
from ._ehactl import Config
if TYPE_CHECKING:
    import pandas as pd
    from tqdm import tqdm

from .results import FrozenMap, RunSummary, _fmt, _setstate_frozen

ConfigLike = Union[Config, str, "os.PathLike[str]"]

#: (name, unit) of every float column of a run result, in order.
FIELDS: tuple[tuple[str, str], ...] = tuple(_ehactl.record_fields())
_UNITS = dict(FIELDS)
_UNITS.update({"cycle": "-", "stuck": "bool"})
_ALIASES = {"command": "u", "valve_command": "plant_command"}
# Columns whose unit follows the control mode (u = N, m or V).
_MODE_COLUMNS = {"setpoint": "{u}", "feedback": "{u}", "error": "{u}", "setpoint_rate": "{u}/s"}


def _must_exist(path: str | os.PathLike[str], what: str) -> None:
    """Raise FileNotFoundError (errno ENOENT, with the path) if ``path`` does not exist."""
    if not os.path.exists(path):
        raise FileNotFoundError(errno.ENOENT, f"{what} not found", os.fspath(path))


def _as_config(cfg: ConfigLike) -> Config:
    if isinstance(cfg, Config):
        return cfg
    if isinstance(cfg, (str, os.PathLike)):
        _must_exist(cfg, "config file")
        return Config.load(cfg)
    raise TypeError(f"expected an ehactl.Config or a path to a TOML config, got {type(cfg).__name__}")


def _setpoint_edits(setpoint: Any) -> dict[str, Any]:
    """`setpoint=` argument → dotted-path edits of the ``[setpoint]`` section."""
    if setpoint is None:
        return {}
    if isinstance(setpoint, Mapping):
        out = {}
        for k, v in setpoint.items():
            k = str(k)
            out[k if k.startswith("setpoint.") else f"setpoint.{k}"] = v
        return out
    if isinstance(setpoint, (int, float, np.floating, np.integer)) and not isinstance(setpoint, bool):
        return {"setpoint.kind": "step", "setpoint.final": float(setpoint)}
    raise TypeError(
        "setpoint: expected None, a number (step to that value at setpoint.start, N or m) "
        f"or a dict of [setpoint] fields, got {type(setpoint).__name__}"
    )


def _prepare(cfg: ConfigLike, setpoint: Any, overrides: Mapping[str, Any] | None) -> Config:
    c = _as_config(cfg)
    edits = dict(overrides or {})
    edits.update(_setpoint_edits(setpoint))
    if edits:
        c = c.with_values(edits)
    return c


_DT = TypeVar("_DT", bound=np.generic)


class _Column(Generic[_DT]):
    """Descriptor of one run column: ``res.force`` is ``res.columns["force"]`` (read-only
    NumPy array); a column left out with ``fields=`` raises AttributeError naming those
    that are there."""

    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, obj: None, owner: type) -> _Column[_DT]: ...
    @overload
    def __get__(self, obj: RunResult, owner: type) -> npt.NDArray[_DT]: ...
    def __get__(self, obj: RunResult | None, owner: type) -> _Column[_DT] | npt.NDArray[_DT]:
        if obj is None:
            return self
        try:
            col: npt.NDArray[_DT] = obj.columns[self.name]
            return col
        except KeyError:
            raise AttributeError(
                f"RunResult has no column {self.name!r} (not among fields=); available: {', '.join(obj.columns)}"
            ) from None


@dataclass(frozen=True, eq=False)
class RunResult:
    """One closed-loop run: every cycle's record as read-only NumPy arrays plus the run summary.

    Columns (attribute or item access): ``t`` (s), ``setpoint``/``feedback``/``error``
    (N in force mode, m in position mode), ``setpoint_rate`` (N/s or m/s), ``u`` (valve
    command after limits, V; alias ``command``), ``command_unsat``, ``p_term``, ``i_term``,
    ``d_term``, ``ff_term`` (V), sensor readings ``force`` (N), ``position`` (m), ``p_a``,
    ``p_b`` (Pa), ``spool`` (fraction of travel), and the ground-truth plant states ``x``,
    ``x_load`` (m), ``v``, ``v_load`` (m/s), ``plant_p_a``, ``plant_p_b``, ``p_s`` (Pa),
    ``plant_spool`` (-), ``spool_velocity`` (1/s), ``q_a``, ``q_b`` (m³/s), ``friction``,
    ``external``, ``rod_force`` (N), ``plant_command`` (V, after any delay), ``stuck``
    (bool), ``cycle``. ``units`` maps every column to its unit; ``unit`` is
    ``units["error"]``, the unit of setpoint / feedback / error in this run's control mode.
    ``summary`` is a :class:`ehactl.results.RunSummary` (``res.summary.rms_error`` …).

    Immutable: a frozen dataclass whose ``columns`` mapping and arrays are read-only
    (copy an array to change it: ``res.force.copy()``).

    Attributes:
        columns: Column name → NumPy array, one entry per control cycle (read-only).
        summary: Run summary (errors, trip, duration …).
        config: The config that ran (overrides applied).
    """

    columns: Mapping[str, np.ndarray]
    summary: RunSummary
    config: Config

    t = _Column[np.float64]("t")
    setpoint = _Column[np.float64]("setpoint")
    setpoint_rate = _Column[np.float64]("setpoint_rate")
    feedback = _Column[np.float64]("feedback")
    error = _Column[np.float64]("error")
    u = _Column[np.float64]("u")
    command = _Column[np.float64]("u")
    command_unsat = _Column[np.float64]("command_unsat")
    p_term = _Column[np.float64]("p_term")
    i_term = _Column[np.float64]("i_term")
    d_term = _Column[np.float64]("d_term")
    ff_term = _Column[np.float64]("ff_term")
    force = _Column[np.float64]("force")
    position = _Column[np.float64]("position")
    p_a = _Column[np.float64]("p_a")
    p_b = _Column[np.float64]("p_b")
    spool = _Column[np.float64]("spool")
    plant_command = _Column[np.float64]("plant_command")
    valve_command = _Column[np.float64]("plant_command")
    plant_spool = _Column[np.float64]("plant_spool")
    spool_velocity = _Column[np.float64]("spool_velocity")
    plant_p_a = _Column[np.float64]("plant_p_a")
    plant_p_b = _Column[np.float64]("plant_p_b")
    p_s = _Column[np.float64]("p_s")
    x = _Column[np.float64]("x")
    v = _Column[np.float64]("v")
    x_load = _Column[np.float64]("x_load")
    v_load = _Column[np.float64]("v_load")
    q_a = _Column[np.float64]("q_a")
    q_b = _Column[np.float64]("q_b")
    friction = _Column[np.float64]("friction")
    external = _Column[np.float64]("external")
    rod_force = _Column[np.float64]("rod_force")
    stuck = _Column[np.bool_]("stuck")
    cycle = _Column[np.uint64]("cycle")

    @classmethod
    def from_raw(cls, columns: Mapping[str, np.ndarray], summary_json: str, config: Config) -> RunResult:
        """From the compiled core's (columns, summary JSON): arrays made read-only."""
        cols: dict[str, np.ndarray] = {}
        for k, a in columns.items():
            arr = np.asarray(a)
            arr.setflags(write=False)
            cols[str(k)] = arr
        return cls(columns=FrozenMap(cols), summary=RunSummary.from_dict(json.loads(summary_json)), config=config)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[_ALIASES.get(name, name)]

    def __setstate__(self, state: Mapping[str, Any]) -> None:
        _setstate_frozen(self, state)  # arrays read-only again after unpickling

    def keys(self) -> list[str]:
        """Column names."""
        return list(self.columns)

    def __dir__(self) -> list[str]:
        # Tab completion offers the columns this run has (and their aliases), not all of them.
        have = set(self.columns) | {a for a, c in _ALIASES.items() if c in self.columns}
        cls = type(self)
        return sorted(n for n in object.__dir__(self) if not isinstance(cls.__dict__.get(n), _Column) or n in have)

    def __len__(self) -> int:
        if "cycle" in self.columns:
            return len(self.columns["cycle"])
        return len(next(iter(self.columns.values()))) if self.columns else 0

    @property
    def units(self) -> dict[str, str]:
        """Unit of each column; setpoint / feedback / error (and their rates) in this run's
        control mode: N (force), m (position) or V (open loop)."""
        u = self.unit
        out = {}
        for k in self.columns:
            v = _UNITS.get(k, "")
            if k in _MODE_COLUMNS:
                v = _MODE_COLUMNS[k].format(u=u) if u else v
            out[k] = v
        return out

    @property
    def unit(self) -> str:
        """Unit of setpoint / feedback / error (= ``units["error"]``): "N" (force mode),
        "m" (position) or "V" (open loop)."""
        return self.summary.error_unit

    @property
    def trip(self) -> str | None:
        """None, or the supervisor's one-line reason if the run tripped."""
        return self.summary.trip

    @property
    def ok(self) -> bool:
        """True when the run completed its duration without trip or interruption."""
        return self.trip is None and not self.summary.interrupted

    @property
    def dt(self) -> float:
        """Control period (s)."""
        return 1.0 / self.summary.control_rate_hz

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible: ``{"columns": {name: list}, "summary": <summary JSON>}``."""
        return {"columns": {k: np.asarray(v).tolist() for k, v in self.columns.items()},
                "summary": self.summary.to_dict()}

    def to_pandas(self) -> Any:
        """All columns as a ``pandas.DataFrame`` indexed by ``t`` (s). Needs pandas."""
        try:
            import pandas as pd
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError("RunResult.to_pandas() needs pandas: pip install pandas") from e
        df = pd.DataFrame({k: np.array(v) for k, v in self.columns.items()})
        if "t" in df:
            df = df.set_index("t", drop=False).rename_axis("time_s")
        return df

    def __repr__(self) -> str:
        s = self.summary
        return (
            f"RunResult({len(self)} cycles, {s.duration_s:.4g} s, "
            f"rms_error={_fmt(s.rms_error)} {self.unit}, trip={self.trip!r})"
        )


def _progress_bar(total: int, desc: str, unit: str) -> tuple[tqdm[NoReturn] | None, Callable[[int, int], None] | None]:
    """A tqdm bar and the progress callback that moves it; (None, None) without tqdm."""
    try:
        from tqdm.auto import tqdm
    except ImportError:  # pragma: no cover - tqdm is optional
        return None, None
    # disable=None: no bar when stderr is not a terminal (logs, CI, Dask workers).
    bar = tqdm(total=total, desc=desc, unit=unit, disable=None)

    def cb(done: int, _total: int) -> None:
        bar.n = done
        bar.refresh()

    return bar, cb


def run(
    cfg: ConfigLike,
    duration: float | None = None,
    setpoint: Any = None,
    mcap: str | os.PathLike[str] | None = None,
    *,
    params: Mapping[str, Any] | None = None,
    fields: Sequence[str] | None = None,
    progress: bool | Callable[[int, int], None] = False,
    overwrite: bool = False,
) -> RunResult:
    """Run one closed loop of ``cfg`` against the simulated plant, in simulated time.

    Args:
        cfg: ``Config`` or path of a TOML config.
        duration: run length (s); default ``run.duration``.
        setpoint: None (as configured), a number (step to it at ``setpoint.start``, N or m)
            or a dict of ``[setpoint]`` fields, e.g. ``{"kind": "sine", "f0": 20.0}``.
        mcap: write the MCAP log of the run there (same format and same rules as ``ehactl
            run --out``): an earlier MCAP log there is replaced, but never the config being
            run, a directory, or a file that is not an MCAP log (ValueError) unless
            ``overwrite=True``. The log is written under a temporary name beside it and
            renamed when complete, so the path never holds a half-written log.
        params: extra dotted-path overrides, e.g. ``{"control.pi.kp": 0.4}``.
        fields: subset of columns to return (default all).
        progress: True for a tqdm bar, or a callable ``(done_cycles, total_cycles)``.
        overwrite: allow ``mcap`` to replace an existing file that is not an MCAP log.

    ``duration`` (and ``run.duration``) is at most 10⁶ s, and the returned columns at most
    2 000 MB (8 bytes per column and cycle): a longer run raises ValueError naming the limit
    (select fewer columns with ``fields=``).

    The GIL is released while Rust simulates; Ctrl-C stops the run and raises
    KeyboardInterrupt (the MCAP log is finalised first).
    """
    c = _prepare(cfg, setpoint, params)
    bar = None
    cb = None
    if progress is True:
        total = int(round((duration or c["run.duration"]) / c.control_dt))
        bar, cb = _progress_bar(total, c.name or "run", "cycle")
    elif callable(progress):
        cb = progress
    try:
        cols, summary = _ehactl.run_one(
            c, duration, None if mcap is None else os.fspath(mcap), None if fields is None else list(fields), cb,
            overwrite,
        )
    finally:
        if bar is not None:
            bar.close()
    return RunResult.from_raw(cols, summary, c)


def param_grid(base: ConfigLike, grid: Mapping[str, Iterable[Any]]) -> list[Config]:
    """Cartesian product of ``grid`` ({dotted path: values}) applied to ``base``.

    Every combination is validated; the first invalid one raises ValueError naming the field.
    An empty grid ``{}`` varies nothing: the base alone (one config). A path with no values
    (``{"control.pi.kp": []}``) raises ValueError naming it, rather than silently making
    the whole product empty.
    """
    b = _as_config(base)
    keys = list(grid)
    values = _axes(grid)
    return [b.with_values(dict(zip(keys, combo))) for combo in itertools.product(*values)]


def _axes(grid: Mapping[str, Iterable[Any]]) -> list[list[Any]]:
    """The values of each path of ``grid`` as lists; ValueError for a path without values."""
    values = [list(v) for v in grid.values()]
    for k, v in zip(grid, values):
        if not v:
            raise ValueError(
                f"parameter grid: {k!r} has no values; give at least one (an empty grid {{}} runs the base once)"
            )
    return values


@overload
def run_many(
    cfgs: Iterable[ConfigLike] | Mapping[str, Iterable[Any]],
    duration: float | None = None,
    setpoint: Any = None,
    *,
    base: ConfigLike | None = None,
    params: Mapping[str, Any] | None = None,
    fields: Sequence[str] | None = None,
    threads: int | None = None,
    mcap_dir: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    progress: bool | Callable[[int, int], None] = False,
    client: None = None,
    chunk_size: int | None = None,
    frame: Literal[False] | None = None,
) -> list[RunResult]: ...
@overload
def run_many(
    cfgs: Iterable[ConfigLike] | Mapping[str, Iterable[Any]],
    duration: float | None = None,
    setpoint: Any = None,
    *,
    base: ConfigLike | None = None,
    params: Mapping[str, Any] | None = None,
    fields: Sequence[str] | None = None,
    threads: int | None = None,
    mcap_dir: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    progress: bool | Callable[[int, int], None] = False,
    client: Any = None,
    chunk_size: int | None = None,
    frame: Literal[False],
) -> list[RunResult]: ...
@overload
def run_many(
    cfgs: Iterable[ConfigLike] | Mapping[str, Iterable[Any]],
    duration: float | None = None,
    setpoint: Any = None,
    *,
    base: ConfigLike | None = None,
    params: Mapping[str, Any] | None = None,
    fields: Sequence[str] | None = None,
    threads: int | None = None,
    mcap_dir: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    progress: bool | Callable[[int, int], None] = False,
    client: Any = None,
    chunk_size: int | None = None,
    frame: Literal[True],
) -> pd.DataFrame: ...
@overload
def run_many(
    cfgs: Iterable[ConfigLike] | Mapping[str, Iterable[Any]],
    duration: float | None = None,
    setpoint: Any = None,
    *,
    base: ConfigLike | None = None,
    params: Mapping[str, Any] | None = None,
    fields: Sequence[str] | None = None,
    threads: int | None = None,
    mcap_dir: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    progress: bool | Callable[[int, int], None] = False,
    client: Any = None,
    chunk_size: int | None = None,
    frame: bool | None = None,
) -> list[RunResult] | pd.DataFrame: ...
def run_many(
    cfgs: Iterable[ConfigLike] | Mapping[str, Iterable[Any]],
    duration: float | None = None,
    setpoint: Any = None,
    *,
    base: ConfigLike | None = None,
    params: Mapping[str, Any] | None = None,
    fields: Sequence[str] | None = None,
    threads: int | None = None,
    mcap_dir: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    progress: bool | Callable[[int, int], None] = False,
    client: Any = None,
    chunk_size: int | None = None,
    frame: bool | None = None,
) -> list[RunResult] | pd.DataFrame:
    """Run many closed loops in parallel on all cores (rayon), GIL released — or on a Dask
    cluster with ``client=``.

    Args:
        cfgs: a list of ``Config``/paths, or a parameter grid ``{dotted path: values}``
            expanded over ``base`` (see :func:`param_grid`: ``{}`` runs the base once, a
            path with no values is a ValueError).
        duration, setpoint, params, fields: as in :func:`run`, applied to every run.
        threads: worker threads (default: one per core).
        mcap_dir: if given, write ``run_0000.mcap``, ``run_0001.mcap``, … there (the rules
            of :func:`run`'s ``mcap``; ``overwrite`` as there).
        progress: True for a tqdm bar over runs, or a callable ``(done_runs, total_runs)``.
        client: a ``dask.distributed.Client`` (``Client(LocalCluster())``, or
            ``Client("tcp://scheduler:8786")`` for a remote cluster whose workers have the
            same ehactl installed): the runs go to its workers in chunks of ``chunk_size``
            (default: about 4 chunks per worker thread), each chunk run by the same compiled
            code as the local path, so the numbers are identical. ``mcap_dir`` must then be
            a path every worker can write (shared file system).
        frame: return a ``pandas.DataFrame`` (one row per run: the grid's parameters or
            the config name, then ``rms_error``, ``rms_error_settled``, ``max_abs_error``,
            ``error_unit``, ``trip``, ``interrupted``, ``cycles``, ``duration_s``, ``mcap``)
            instead of the list of results; default True with a client, False without.

    Returns the results in input order (a list of :class:`RunResult`, or a DataFrame).
    """
    grid_rows: list[dict[str, Any]] | None = None
    if isinstance(cfgs, Mapping):
        if base is None:
            raise ValueError("run_many: a parameter grid needs base=<Config or path>")
        keys = list(cfgs)
        axes = _axes(cfgs)  # once: the values may be one-shot iterators
        grid = dict(zip(keys, axes))
        configs = param_grid(base, grid)
        grid_rows = [dict(zip(keys, combo)) for combo in itertools.product(*axes)]
    else:
        configs = [_as_config(c) for c in cfgs]
    configs = [_prepare(c, setpoint, params) for c in configs]
    mcap = None
    if mcap_dir is not None:
        d = Path(mcap_dir)
        d.mkdir(parents=True, exist_ok=True)
        mcap = [os.fspath(d / f"run_{i:04d}.mcap") for i in range(len(configs))]
    bar = None
    cb = None
    if progress is True:
        bar, cb = _progress_bar(len(configs), "run_many", "run")
    elif callable(progress):
        cb = progress
    flist = None if fields is None else list(fields)
    try:
        if client is not None:
            from . import _dask

            outs = _dask.run_batch(client, configs, duration, mcap, flist, chunk_size, cb, overwrite)
        else:
            outs = _ehactl.run_batch(configs, duration, mcap, flist, threads, cb, overwrite)
    finally:
        if bar is not None:
            bar.close()
    results = [RunResult.from_raw(cols, s, c) for (cols, s), c in zip(outs, configs)]
    if frame is None:
        frame = client is not None
    if not frame:
        return results
    return results_frame(results, grid_rows)


def results_frame(results: Sequence[RunResult], params: Sequence[Mapping[str, Any]] | None = None) -> pd.DataFrame:
    """One ``pandas.DataFrame`` row per run: ``params`` (e.g. the grid point) or the config
    name, then the scalar summary fields (see :func:`run_many`'s ``frame``)."""
    try:
        import pandas as pd
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("a DataFrame of results needs pandas: pip install pandas") from e
    from ._dask import summary_row

    rows = []
    for i, r in enumerate(results):
        row: dict[str, Any] = dict(params[i]) if params is not None else {"config": r.config.name}
        row.update(summary_row(r.summary.to_dict()))
        rows.append(row)
    return pd.DataFrame(rows)


def params() -> list[dict[str, str]]:
    """Every registered config parameter: path, unit, kind (float, int, float[], bool, choice), range, description."""
    return [
        {"path": p, "unit": u, "kind": k, "range": r, "description": d}
        for (p, u, k, r, d) in _ehactl.param_table()
    ]


def read_mcap(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read any ehactl MCAP log (Rust ``mcap`` reader, chunk CRCs checked).

    Returns a dict with one entry per channel: CDR channels (``control``, ``plant``) as
    {field: NumPy array} decoded from the log's own ros2msg schema, plus ``_log_time`` (ns)
    and ``_sequence``; JSON channels parsed: ``config`` (first message), ``events`` (list),
    ``summary`` (last message); and ``metadata`` ({record name: {key: value}}), ``schemas``
    ({topic: (name, encoding)}), ``profile``, ``library``. Topics other than the standard
    ones appear under their name without the leading slash (JSON → list of messages).
    """
    raw = _ehactl.read_mcap_raw(os.fspath(path))
    out: dict[str, Any] = {}
    for topic, cols in raw["cdr"].items():
        out[topic.lstrip("/")] = cols
    for topic, msgs in raw["json"].items():
        parsed = [json.loads(m) for m in msgs]
        name = topic.lstrip("/")
        if name == "config":
            out[name] = parsed[0] if parsed else None
        elif name == "summary":
            out[name] = parsed[-1] if parsed else None
        else:
            out[name] = parsed
    out.setdefault("events", [])
    out["metadata"] = raw["metadata"]
    out["schemas"] = raw["schemas"]
    out["other_counts"] = raw["other"]
    out["profile"] = raw["profile"]
    out["library"] = raw["library"]
    return out
