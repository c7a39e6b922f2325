"""Campaign diagnosis (one load law from many records) and ``ehactl predict``: the same
compiled sessions as the CLI, results as frozen dataclasses over the ``--json`` objects."""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence, Union

from . import _ehactl
from ._runs import ConfigLike, _as_config, _must_exist

PathLike = Union[str, "os.PathLike[str]"]


@dataclass(frozen=True)
class RecordPrediction:
    """One record replayed through a model (``ehactl predict``)."""

    source: str
    #: ``imposed_motion``, ``closed_loop`` or ``open_loop``.
    replay: str
    #: Operating input → value (its unit as the config declares it).
    operating_point: Mapping[str, float]
    #: First and end sample scored.
    scored: tuple[int, int]
    #: NRMSE over the scored samples: RMS over the channels (``None``: the replay diverged).
    nrmse: float | None
    #: Per channel (CSV column → NRMSE; ``None`` when the replay diverged).
    channels: Mapping[str, float | None]
    #: Where the replay left physical bounds (``t``, ``channel``, ``value``, ``bound``,
    #: ``unit``, ``reason``), or ``None``.
    diverged: Mapping[str, Any] | None = None
    #: The record against the model's fitted envelope (``inside``, ``excursions``), or
    #: ``None`` when the model states none.
    envelope: Mapping[str, Any] | None = None

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> RecordPrediction:
        if not isinstance(d, Mapping):
            raise TypeError(f"a prediction must be a mapping, got {type(d).__name__}")
        try:
            return cls(
                source=str(d["source"]),
                replay=str(d["replay"]),
                operating_point=dict(d["operating_point"]),
                scored=(int(d["scored"][0]), int(d["scored"][1])),
                nrmse=_maybe_float(d["nrmse"]["overall"]),
                channels={str(k): _maybe_float(v) for k, v in d["nrmse"]["channels"].items()},
                diverged=d.get("diverged"),
                envelope=d.get("envelope"),
            )
        except (KeyError, TypeError, IndexError, ValueError) as e:
            raise ValueError(f"not an `ehactl predict` record object: {e!r}") from e


def _maybe_float(v: Any) -> float | None:
    return None if v is None else float(v)


@dataclass(frozen=True)
class PredictionResult:
    """``ehactl predict --json`` as an object: one :class:`RecordPrediction` per record."""

    records: tuple[RecordPrediction, ...]
    #: RMS of the records' overall NRMSE (``None`` when a record's replay diverged).
    nrmse: float | None
    files: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    raw: Mapping[str, Any] = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The ``ehactl predict --json`` object."""
        return dict(self.raw)


@dataclass(frozen=True)
class CampaignResult:
    """A campaign diagnosis (``ehactl diagnose --data R1 --data R2 … --json``)."""

    #: Leading term of the law with its input dependence, e.g.
    #: ``load-side Dahl yield force 124 N + 1027 N/A·current``.
    cause: str
    summary: str
    #: Held-out force NRMSE pooled over the records: law, nominal, ARX.
    nrmse: float
    nrmse_nominal: float
    nrmse_arx: float
    #: Per record: ``source``, ``role``, ``operating_point``, ``nrmse`` (law / nominal / arx).
    records: tuple[Mapping[str, Any], ...]
    #: The law's terms (path, name, unit, ``at_zero``, ``dependence``, ``share``).
    terms: tuple[Mapping[str, Any], ...]
    dependence_check: str
    extended_config: str | None
    report: str | None
    warnings: tuple[str, ...] = ()
    raw: Mapping[str, Any] = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` object."""
        return dict(self.raw)


def _paths(v: PathLike | Sequence[PathLike] | None, what: str) -> list[str]:
    if v is None:
        return []
    items = [v] if isinstance(v, (str, os.PathLike)) else list(v)
    for p in items:
        _must_exist(p, what)
    return [os.fspath(p) for p in items]


def campaign(
    cfg: ConfigLike,
    data: Sequence[PathLike],
    validate: Sequence[PathLike] | None = None,
    out: PathLike | None = None,
    *,
    force: bool = False,
) -> CampaignResult:
    """One load law fitted to several records of a rig (``ehactl diagnose --data R1 --data R2 …``).

    Each record's measured motion is imposed on the rod and the law of
    ``[effects.polynomial_force]`` is fitted to every record at once; its coefficients may depend
    on the operating inputs the config declares (``[inputs.current]``, a record's ``current``
    column), kept only if they predict an operating point left out (DIAGNOSIS.md, "Campaigns").

    Args:
        cfg: the rig's ``Config`` or the path of its TOML.
        data: records to fit (CSV, or MCAP: an ehactl log or JSON samples on ``/measured``); their last 30 % is held out unless
            ``validate`` is given.
        validate: records held out whole (e.g. an operating point never fitted).
        out: directory for ``extended.toml``, ``report.md``, ``campaign.json``, ``campaign.svg``.
        force: write into an ``out`` directory that holds other files.

    Raises:
        FileNotFoundError: a record does not exist.
        ValueError: bad data or config (the message names the file, row or field), e.g. two
            records with the same samples, a constant force, an ehactl log of another rig.
        OSError: the report could not be written, or ``out`` is held by another running ehactl.
    """
    c = _as_config(cfg)
    raw = json.loads(_ehactl.campaign_json(c, _paths(data, "measured data file"),
                                           _paths(validate, "validation data file"),
                                           None if out is None else os.fspath(out), bool(force)))
    r = CampaignResult(
        cause=raw["cause"],
        summary=raw["summary"],
        nrmse=float(raw["pooled"]["law"]),
        nrmse_nominal=float(raw["pooled"]["nominal"]),
        nrmse_arx=float(raw["pooled"]["arx"]),
        records=tuple(raw["records"]),
        terms=tuple(raw["terms"]),
        dependence_check=raw["dependence_check"],
        extended_config=raw.get("extended_config"),
        report=raw.get("report"),
        warnings=tuple(raw.get("warnings", ())),
        raw=raw,
    )
    for w in r.warnings:
        warnings.warn(w, stacklevel=2)
    return r


def predict(
    cfg: ConfigLike,
    data: PathLike | Sequence[PathLike],
    *,
    imposed_motion: bool = False,
    held_out: bool = False,
    out: PathLike | None = None,
    force: bool = False,
) -> PredictionResult:
    """Replay records through a model and score each measured channel (``ehactl predict``).

    Args:
        cfg: the model: a ``Config`` or the path of a TOML (a shipped config or the
            ``extended.toml`` a diagnosis wrote); taken at each record's operating point.
        data: one record or several (CSV, or MCAP: an ehactl log or JSON samples on ``/measured``).
        imposed_motion: impose each record's measured motion on the rod and predict the force
            (a record with ``x`` and ``force`` but no ``u`` / ``ref`` always is).
        held_out: score only the last 30 % of each record.
        out: directory for ``prediction.json`` and ``prediction.svg``.
        force: write into an ``out`` directory that holds other files.

    Returns:
        :class:`PredictionResult`: ``records`` (per record ``nrmse`` and ``channels``),
        ``nrmse`` (RMS over records), ``to_dict()`` the ``--json`` object.

    Raises:
        FileNotFoundError: a record does not exist.
        ValueError: no record, bad data or config (the message names the file, column or
            field: e.g. a constant channel, an operating input that varies within a record).
        OSError: the output could not be written, or ``out`` is held by another running ehactl.
    """
    c = _as_config(cfg)
    raw = json.loads(_ehactl.predict_json(c, _paths(data, "measured data file"), bool(imposed_motion),
                                          bool(held_out), None if out is None else os.fspath(out),
                                          bool(force)))
    recs = [raw] if "records" not in raw else list(raw["records"])
    r = PredictionResult(
        records=tuple(RecordPrediction.from_dict(x) for x in recs),
        nrmse=_maybe_float(raw["nrmse"]["overall"]),
        files=tuple(raw.get("files", ())),
        warnings=tuple(raw.get("warnings", ())),
        raw=raw,
    )
    for w in r.warnings:
        warnings.warn(w, stacklevel=2)
    return r
