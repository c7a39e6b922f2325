"""``ehactl.analyze``, ``ehactl.sweep`` and ``ehactl.diagnose``: the CLI's ``ehactl analyze`` /
``ehactl sweep`` / ``ehactl diagnose`` from Python (same compiled code, same JSON, arrays as NumPy)."""

from __future__ import annotations

import json
import os
import warnings
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from . import _ehactl
from ._runs import ConfigLike, _as_config, _must_exist, _progress_bar


def analyze(cfg: ConfigLike, *, params: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Linearise ``cfg`` around its operating point, like ``ehactl analyze --json``.

    The noise-free loop is run to rest at the setpoint's static value, the plant's step map
    is differentiated over one control period with the command held (so the loop includes
    the zero-order hold, ``sampled_loop`` is True), and margins are computed for the sampled
    loop (top-level keys) and the continuous loop (``continuous``).

    Returns a dict with, where they apply: ``hydraulic_natural_frequency_hz``,
    ``min_natural_frequency_over_stroke_hz``, ``open_loop_bandwidth_hz``,
    ``gain_crossover_hz``, ``phase_margin_deg``, ``phase_crossover_hz``, ``gain_margin_db``,
    ``closed_loop_bandwidth_hz`` (Hz, deg, dB), seed 003's ``fr_ym``/``fr_em``/``rd_my``, the
    operating point, the slowest ``poles`` and ``loop_response`` as NumPy arrays
    (``f_hz``, ``loop_mag_db``, ``loop_phase_deg``, ``closed_mag_db``, ``closed_phase_deg``).

    Args:
        cfg: ``Config`` or path of a TOML config.
        params: dotted-path overrides, e.g. ``{"control.pi.kp": 0.4}``.
    """
    c = _as_config(cfg)
    if params:
        c = c.with_values(dict(params))
    out = json.loads(_ehactl.analyze_json(c))
    lr = out.get("loop_response") or []
    out["loop_response"] = {k: np.array([p[k] for p in lr], dtype=float)
                            for k in ("f_hz", "loop_mag_db", "loop_phase_deg", "closed_mag_db",
                                      "closed_phase_deg")}
    return out


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
    mcap: str | os.PathLike | None = None,
    params: Mapping[str, Any] | None = None,
    progress: bool | Callable[[int, int], None] = False,
) -> dict[str, Any]:
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
        dict with ``f_hz``, ``mag_db``, ``phase_deg``, ``coherence``, ``gain``,
        ``distortion`` (NumPy arrays), ``bandwidth_hz`` (−3 dB, Hz or None), ``mode``,
        ``input``, ``output``, ``offset``, ``amplitude``, ``dwell_s``, ``complete``, ``trip``,
        ``mcap``.
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
    r = json.loads(raw)
    pts = r.pop("points")
    for k in ("f_hz", "mag_db", "phase_deg", "coherence", "gain", "distortion"):
        r[k] = np.array([p[k] for p in pts], dtype=float)
    return r


def diagnose(
    cfg: ConfigLike,
    data: str | os.PathLike,
    validate: str | os.PathLike | None = None,
    out: str | os.PathLike | None = None,
    *,
    progress: bool | Callable[[int, int], None] = False,
    sensor_offsets: bool = False,
) -> dict[str, Any]:
    """What the simulation of ``cfg`` gets wrong on measured data, like ``ehactl diagnose --json``.

    Replays the measured valve command (or, for closed-loop position records with ``ref``,
    the config's PD loop) through the plant, analyses the residual, fits every effect of the
    catalogue (nominal parameters refit within ±15 %), scores them on held-out data and names
    the cause.

    Args:
        cfg: nominal ``Config`` or path of its TOML.
        data: measured record, CSV (``t, u`` and any of ``force, x, p_a, p_b, x_v, ref``; SI)
            or an MCAP written by ehactl.
        validate: separate held-out record; default the last 30 % of ``data``.
        out: directory for ``extended.toml``, ``report.md`` and SVG plots.
        progress: True for a tqdm bar of the model fits, or a callable ``(done_fits,
            total_fits)`` (called on this thread; the total grows with each search round).
        sensor_offsets: estimate a constant zero error per measured channel for every model
            (on the fitting part; applied to the held-out part); default False trusts the zeros.

    Returns:
        dict with ``cause``, ``causes``, ``nrmse_nominal``, ``nrmse_extended`` (held-out, per
        channel and ``overall``), ``gain``, ``candidates`` (effect, params, nrmse_train,
        nrmse_validation, score, accepted, evidence), ``sensor_offsets`` (channel → offset in
        N, m or Pa), ``extended_config``, ``report``, ``plots``, ``warnings``. Data warnings are also issued as Python warnings.

    Raises:
        FileNotFoundError: ``cfg`` (a path), ``data`` or ``validate`` does not exist.
        ValueError: bad data or config (the message names the file, row or field).
        OSError: the report could not be written.
    """
    c = _as_config(cfg)
    _must_exist(data, "measured data file")
    if validate is not None:
        _must_exist(validate, "validation data file")
    cb = progress if callable(progress) else None
    bar = None
    if progress is True:
        bar, bar_cb = _progress_bar(1, "diagnose", "fit")
        if bar is not None:
            def cb(done: int, total: int) -> None:
                bar.total = total
                bar_cb(done, total)
    try:
        raw, notes = _ehactl.diagnose_json(c, os.fspath(data),
                                           None if validate is None else os.fspath(validate),
                                           None if out is None else os.fspath(out), cb,
                                           bool(sensor_offsets))
    finally:
        if bar is not None:
            bar.close()
    r = json.loads(raw)
    for w in r.get("warnings") or []:
        warnings.warn(w, stacklevel=2)
    r["notes"] = list(notes)
    return r


def diagnose_many(
    cases: Sequence[Mapping[str, Any] | tuple],
    *,
    client: Any = None,
    sensor_offsets: bool = False,
):
    """Diagnose a fleet of records (e.g. one log per rig) and tabulate the causes.

    Args:
        cases: each a dict with ``config`` (``Config`` or path), ``data`` (CSV or ehactl
            MCAP) and optionally ``validate`` and ``out`` (report directory), or a tuple
            ``(config, data[, validate[, out]])``.
        client: a ``dask.distributed.Client``: one Dask task per case on its workers (data
            paths must be readable there, e.g. a shared file system); default: one after
            the other in this process.
        sensor_offsets: as in :func:`diagnose`.

    Returns:
        ``pandas.DataFrame`` with one row per case in input order: ``data``, ``cause``,
        ``causes`` (comma-separated), ``gain``, ``nrmse_nominal`` and ``nrmse_extended``
        (held-out, overall), ``warnings`` (count), ``report`` (path or None).
    """
    import pandas as pd

    from . import _dask

    norm = []
    for c in cases:
        if isinstance(c, Mapping):
            cfg, data, val, out = c["config"], c["data"], c.get("validate"), c.get("out")
        else:
            c = tuple(c) + (None,) * (4 - len(c))
            cfg, data, val, out = c[:4]
        _must_exist(data, "measured data file")
        if val is not None:
            _must_exist(val, "validation data file")
        norm.append((_as_config(cfg), os.fspath(data), None if val is None else os.fspath(val),
                     None if out is None else os.fspath(out)))
    if client is not None:
        raws = _dask.diagnose_batch(client, [(c.to_toml(), d, v, o) for c, d, v, o in norm], bool(sensor_offsets))
    else:
        raws = [_ehactl.diagnose_json(c, d, v, o, None, bool(sensor_offsets)) for c, d, v, o in norm]
    rows = []
    for (c, d, _v, _o), (raw, _notes) in zip(norm, raws):
        row = {"data": d}
        row.update(_dask.diagnose_row(json.loads(raw)))
        rows.append(row)
    return pd.DataFrame(rows)
