"""``ehactl.analyze``, ``ehactl.sweep`` and ``ehactl.diagnose``: the CLI's ``ehactl analyze`` /
``ehactl sweep`` / ``ehactl diagnose`` from Python (same compiled code, same JSON), returned as
the typed, immutable result objects of :mod:`ehactl.results` (``to_dict()`` gives the JSON)."""

from __future__ import annotations

import json
import os
import warnings
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence, overload


from . import _ehactl

if TYPE_CHECKING:
    import pandas as pd
from ._runs import ConfigLike, _as_config, _must_exist, _progress_bar
from ._campaign import CampaignResult, _paths, campaign
from .results import AnalysisResult, DiagnosisResult, SweepResult


def analyze(cfg: ConfigLike, *, params: Mapping[str, Any] | None = None) -> AnalysisResult:
    """Linearise ``cfg`` around its operating point, like ``ehactl analyze --json``.

    The noise-free loop is run to rest at the setpoint's static value, the plant's step map
    is differentiated over one control period with the command held (so the loop includes
    the zero-order hold, ``sampled_loop`` is True), and margins are computed for the sampled
    loop (top-level attributes) and the continuous loop (``continuous``).

    Returns an :class:`ehactl.results.AnalysisResult`: ``phase_margin_deg`` (deg) at
    ``gain_crossover_hz``, ``gain_margin_db`` (dB) at ``phase_crossover_hz``,
    ``closed_loop_bandwidth_hz``, ``open_loop_bandwidth_hz``,
    ``hydraulic_natural_frequency_hz`` (Hz; None where a crossing does not exist), the
    ``operating_point``, the slowest ``poles``, ``loop_response`` (NumPy arrays ``f_hz``,
    ``loop_mag_db``, ``loop_phase_deg``, ``closed_mag_db``, ``closed_phase_deg``) and, with a
    flexibly mounted load, Dindorf et al.'s ``fr_ym``/``fr_em``/``rd_my``.
    ``res.to_dict()`` is the ``ehactl analyze --json`` object.

    Args:
        cfg: ``Config`` or path of a TOML config.
        params: dotted-path overrides, e.g. ``{"control.pi.kp": 0.4}``.
    """
    c = _as_config(cfg)
    if params:
        c = c.with_values(dict(params))
    return AnalysisResult.from_dict(json.loads(_ehactl.analyze_json(c)))


def sweep(
    cfg: ConfigLike,
    from_hz: float | None = None,
    to_hz: float | None = None,
    points: int = 30,
    amplitude: float | None = None,
    *,
    open_loop: bool = False,
    output: str | None = None,
    periods: float = 6.0,
    mcap: str | os.PathLike[str] | None = None,
    params: Mapping[str, Any] | None = None,
    progress: bool | Callable[[int, int], None] = False,
) -> SweepResult:
    """Frequency response of the nonlinear plant by a stepped sine, like ``ehactl sweep``.

    Closed loop: setpoint = operating value + ``amplitude``·sin (N or m); open loop
    (``open_loop=True``): valve command = operating command + ``amplitude``·sin (V). Each
    frequency is held for ``periods`` periods of the lowest one; a 3-parameter sine fit in 4
    blocks gives H, its coherence and the output distortion.

    Args:
        cfg: ``Config`` or path of a TOML config.
        from_hz, to_hz: frequency range (Hz); default the setpoint's f0/f1.
        points: number of log-spaced frequencies.
        amplitude: sine amplitude (N or m closed loop, V open loop).
        output: "force", "position", "p_a" or "p_b" (default the loop's feedback).
        mcap: MCAP log of the sweep run (one control cycle in 5, as `ehactl sweep`).
        params: dotted-path overrides.
        progress: True for a tqdm bar, or a callable ``(done_cycles, total_cycles)``.

    Returns:
        :class:`ehactl.results.SweepResult`: ``frf`` (NumPy arrays ``f_hz`` (Hz),
        ``mag_db`` (dB), ``phase_deg`` (deg), ``coherence``, ``gain``, ``distortion``),
        ``bandwidth_hz`` (−3 dB, Hz or None), ``mode``, ``input``, ``output``, ``offset``,
        ``amplitude``, ``dwell_s`` (s), ``complete``, ``trip``, ``mcap``;
        ``res.to_dict()`` is the ``ehactl sweep --json`` object.
    """
    c = _as_config(cfg)
    if params:
        c = c.with_values(dict(params))
    bar = None
    cb = progress if callable(progress) else None
    if progress is True:
        f0 = from_hz if from_hz is not None else (c["setpoint.f0"] or 1.0)
        total = int(round((0.2 + max(periods / f0, 0.05) * points) / c.control_dt))
        bar, cb = _progress_bar(total, f"sweep {c.name or ''}".strip(), "cycle")
    try:
        raw = _ehactl.sweep_json(c, from_hz, to_hz, int(points), amplitude, bool(open_loop),
                                 output, float(periods),
                                 None if mcap is None else os.fspath(mcap), cb)
    finally:
        if bar is not None:
            bar.close()
    return SweepResult.from_dict(json.loads(raw))


@overload
def diagnose(
    cfg: ConfigLike,
    data: str | os.PathLike[str],
    validate: str | os.PathLike[str] | None = None,
    out: str | os.PathLike[str] | None = None,
    *,
    progress: bool | Callable[[int, int], None] = False,
    sensor_offsets: bool = False,
) -> DiagnosisResult: ...


@overload
def diagnose(
    cfg: ConfigLike,
    data: list[str | os.PathLike[str]] | tuple[str | os.PathLike[str], ...],
    validate: list[str | os.PathLike[str]] | tuple[str | os.PathLike[str], ...] | None = None,
    out: str | os.PathLike[str] | None = None,
    *,
    progress: bool | Callable[[int, int], None] = False,
    sensor_offsets: bool = False,
) -> CampaignResult: ...


def diagnose(
    cfg: ConfigLike,
    data: Any,
    validate: Any = None,
    out: str | os.PathLike[str] | None = None,
    *,
    progress: bool | Callable[[int, int], None] = False,
    sensor_offsets: bool = False,
) -> DiagnosisResult | CampaignResult:
    """What the simulation of ``cfg`` gets wrong on measured data, like ``ehactl diagnose --json``.

    Replays the measured valve command (or, for closed-loop position records with ``ref``,
    the config's PD loop) through the plant, analyses the residual, fits every effect of the
    catalogue (nominal parameters refit within ±15 %), scores them on held-out data and names
    the cause.

    Args:
        cfg: nominal ``Config`` or path of its TOML.
        data: measured record, CSV (``t, u`` and any of ``force, x, p_a, p_b, x_v, ref``; SI)
            or an MCAP written by ehactl.
            A list or tuple of records runs a campaign instead (:func:`ehactl.campaign`: one
            load law for every record, ``validate`` then a list too) and returns a
            :class:`ehactl.CampaignResult`.
        validate: separate held-out record; default the last 30 % of ``data``.
        out: directory for ``extended.toml``, ``report.md`` and SVG plots.
        progress: True for a tqdm bar of the model fits, or a callable ``(done_fits,
            total_fits)`` (called on this thread; the total grows with each search round).
        sensor_offsets: estimate a constant zero error per measured channel for every model
            (on the fitting part; applied to the held-out part); default False trusts the zeros.

    Returns:
        :class:`ehactl.results.DiagnosisResult`: ``cause``, ``causes``, ``nrmse_nominal``,
        ``nrmse_extended`` (held-out, ``.channels`` and ``.overall``), ``gain``,
        ``candidates`` (``effect``, ``params``, ``nrmse_train``, ``nrmse_validation``,
        ``score``, ``accepted``, ``evidence``), ``sensor_offsets`` (channel → offset in N, m
        or Pa), ``extended_config``, ``report``, ``plots``, ``warnings``, ``notes``;
        ``res.to_dict()`` is the ``ehactl diagnose --json`` object, ``res.to_pandas()`` the
        candidates table. Data warnings are also issued as Python warnings.

    Raises:
        FileNotFoundError: ``cfg`` (a path), ``data`` or ``validate`` does not exist.
        ValueError: bad data or config (the message names the file, row or field).
        OSError: the report could not be written.
    """
    if not isinstance(data, (str, os.PathLike)) or not (
        validate is None or isinstance(validate, (str, os.PathLike))
    ):
        # Several records (a list or tuple of paths): one load law for the campaign.
        return campaign(cfg, data, validate, out)
    c = _as_config(cfg)
    _must_exist(data, "measured data file")
    if validate is not None:
        _must_exist(validate, "validation data file")
    cb: Callable[[int, int], None] | None = progress if callable(progress) else None
    bar = None
    if progress is True:
        bar, bar_cb = _progress_bar(1, "diagnose", "fit")
        if bar is not None and bar_cb is not None:
            # The total of fits grows with each search round: follow it on the bar.
            def bar_follows(done: int, total: int, bar: Any = bar, move: Callable[[int, int], None] = bar_cb) -> None:
                bar.total = total
                move(done, total)

            cb = bar_follows
    try:
        raw, notes = _ehactl.diagnose_json(c, os.fspath(data),
                                           None if validate is None else os.fspath(validate),
                                           None if out is None else os.fspath(out), cb,
                                           bool(sensor_offsets))
    finally:
        if bar is not None:
            bar.close()
    r = DiagnosisResult.from_dict(json.loads(raw), notes=list(notes))
    for w in r.warnings:
        warnings.warn(w, stacklevel=2)
    return r


def diagnose_many(
    cases: Sequence[Mapping[str, Any] | tuple[Any, ...]],
    *,
    client: Any = None,
    sensor_offsets: bool = False,
) -> pd.DataFrame:
    """Diagnose a fleet of records (e.g. one log per rig) or of campaigns, and tabulate the causes.

    Args:
        cases: each a dict with ``config`` (``Config`` or path), ``data`` (CSV or MCAP) and
            optionally ``validate`` and ``out`` (report directory), or a tuple
            ``(config, data[, validate[, out]])``. A ``data`` that is a list of records is a
            campaign (as :func:`diagnose` with a list: one load law for all of them, DIAGNOSIS.md
            "Campaigns"); its ``validate`` is then a list too (or None).
        client: a ``dask.distributed.Client``: one Dask task per case on its workers (data
            paths must be readable there, e.g. a shared file system); default: one after
            the other in this process.
        sensor_offsets: as in :func:`diagnose` (single-record cases).

    Returns:
        ``pandas.DataFrame`` with one row per case in input order: ``data`` (a campaign's
        records joined by ``;``), ``mode`` (``record`` or ``campaign``), ``cause``, ``causes``
        (comma-separated catalogue ids), ``gain``, ``nrmse_nominal`` and ``nrmse_extended``
        (held-out, overall; a campaign's pooled force NRMSE of the config and of its law),
        ``warnings`` (count), ``report`` (path or None).
    """
    import pandas as pd

    from . import _dask

    norm: list[_dask.Case] = []
    for case in cases:
        if isinstance(case, Mapping):
            cfg, data, val, out = case["config"], case["data"], case.get("validate"), case.get("out")
        else:
            padded = tuple(case) + (None,) * (4 - len(case))
            cfg, data, val, out = padded[:4]
        if isinstance(data, (str, os.PathLike)):
            _must_exist(data, "measured data file")
            if val is not None:
                _must_exist(val, "validation data file")
            d: str | list[str] = os.fspath(data)
            v: str | list[str] | None = None if val is None else os.fspath(val)
        else:
            d = _paths(data, "measured data file")
            v = _paths(val, "validation data file")
        norm.append((_as_config(cfg).to_toml(), d, v, None if out is None else os.fspath(out)))
    if client is not None:
        raws = _dask.diagnose_batch(client, norm, bool(sensor_offsets))
    else:
        raws = [_dask.diagnose_case(_ehactl.__version__, *c, bool(sensor_offsets)) for c in norm]
    rows = []
    for (_c, d, _v, _o), (raw, _notes) in zip(norm, raws):
        row: dict[str, Any] = {"data": d if isinstance(d, str) else ";".join(d)}
        row.update(_dask.diagnose_row(json.loads(raw)))
        rows.append(row)
    return pd.DataFrame(rows)
