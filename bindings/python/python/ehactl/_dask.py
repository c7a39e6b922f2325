"""Batches on a Dask distributed cluster (``client=`` of :func:`ehactl.run_many`, the
:mod:`ehactl.tune` functions and :func:`ehactl.diagnose_many`, whose cases may be campaigns).

The work is cut into chunks, one Dask task per chunk; each task runs its chunk with the same
compiled code as the local path (a rayon batch of ``_ehactl.run_batch`` with one thread, or
``diagnose``), so a cluster returns the same numbers as a local run. Configs travel as their
TOML text (``Config`` pickles that way); results come back as NumPy arrays and dicts. Every
worker needs the same ``ehactl`` version installed (``pip install ./bindings/python``); a
worker with another version is refused by the task's version check.
"""

from __future__ import annotations

from typing import Any, Callable, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _ehactl


def _check_version(version: str) -> None:
    if version != _ehactl.__version__:
        raise RuntimeError(
            f"ehactl {_ehactl.__version__} on this Dask worker, {version} on the client: "
            "install the same ehactl on every worker (pip install ./bindings/python)"
        )


def _run_chunk(
    version: str,
    tomls: Sequence[str],
    duration: float | None,
    mcaps: Sequence[str] | None,
    fields: Sequence[str] | None,
    overwrite: bool = False,
) -> list[tuple[dict[str, np.ndarray], str]]:
    """Worker side of :func:`run_many`: one chunk, sequentially (one rayon thread)."""
    _check_version(version)
    cfgs = [_ehactl.Config.from_toml(t) for t in tomls]
    return _ehactl.run_batch(cfgs, duration, mcaps, fields, 1, None, overwrite)


#: One diagnosis case: config TOML, the record (or a campaign's records), validation
#: record(s) or None, report directory or None.
Case = Tuple[str, Union[str, List[str]], Union[str, List[str], None], Optional[str]]


def diagnose_case(
    version: str,
    toml: str,
    data: str | list[str],
    validate: str | list[str] | None,
    out: str | None,
    sensor_offsets: bool,
) -> tuple[str, list[str]]:
    """Worker side of :func:`diagnose_many` (and its local path): one case, the JSON report
    and notes; a list of records is a campaign (``_ehactl.campaign_json``)."""
    _check_version(version)
    cfg = _ehactl.Config.from_toml(toml)
    if isinstance(data, list):
        val = [] if validate is None else [validate] if isinstance(validate, str) else list(validate)
        return _ehactl.campaign_json(cfg, data, val, out, False), []
    assert not isinstance(validate, list), "a single record takes one validation record"
    raw, notes = _ehactl.diagnose_json(cfg, data, validate, out, None, sensor_offsets)
    return raw, list(notes)


def _client(client: Any) -> Any:
    """Accept a ``dask.distributed.Client`` (anything with ``submit`` and ``gather``)."""
    if not (hasattr(client, "submit") and hasattr(client, "gather")):
        raise TypeError(
            f"client: expected a dask.distributed.Client (e.g. Client(LocalCluster()) or "
            f"Client('tcp://scheduler:8786')), got {type(client).__name__}"
        )
    return client


def chunks(n: int, client: Any, chunk_size: int | None) -> list[range]:
    """Split ``n`` items into chunks: by default 4 per worker thread (load balance), at most
    64 items each."""
    if chunk_size is None:
        try:
            threads = sum(client.nthreads().values())
        except Exception:  # pragma: no cover - a client without nthreads()
            threads = 1
        chunk_size = max(1, min(64, -(-n // max(1, 4 * threads))))
    if chunk_size < 1:
        raise ValueError(f"chunk_size = {chunk_size}: expected an integer ≥ 1")
    return [range(i, min(n, i + chunk_size)) for i in range(0, n, chunk_size)]


def run_batch(
    client: Any,
    configs: Sequence[_ehactl.Config],
    duration: float | None,
    mcaps: Sequence[str] | None,
    fields: Sequence[str] | None,
    chunk_size: int | None,
    progress_cb: Callable[[int, int], None] | None,
    overwrite: bool = False,
) -> list[tuple[dict[str, np.ndarray], str]]:
    """``_ehactl.run_batch`` on the cluster: same inputs, same outputs, input order."""
    from dask.distributed import as_completed

    client = _client(client)
    tomls = [c.to_toml() for c in configs]
    parts = chunks(len(tomls), client, chunk_size)
    futs = []
    for r in parts:
        futs.append(
            client.submit(
                _run_chunk,
                _ehactl.__version__,
                [tomls[i] for i in r],
                duration,
                None if mcaps is None else [mcaps[i] for i in r],
                fields,
                overwrite,
                pure=False,
            )
        )
    index = {f.key: k for k, f in enumerate(futs)}
    out: list[Any] = [None] * len(tomls)
    done = 0
    for fut in as_completed(futs):  # type: ignore[no-untyped-call]  # dask ships no annotation for it
        k = index[fut.key]
        res = fut.result()
        for i, o in zip(parts[k], res):
            out[i] = o
        done += len(parts[k])
        if progress_cb is not None:
            progress_cb(done, len(tomls))
    return out


def diagnose_batch(client: Any, cases: Sequence[Case], sensor_offsets: bool) -> list[tuple[str, list[str]]]:
    """Diagnose every case (:data:`Case`) on the cluster, one task each; input order."""
    client = _client(client)
    futs = [
        client.submit(diagnose_case, _ehactl.__version__, t, d, v, o, sensor_offsets, pure=False)
        for (t, d, v, o) in cases
    ]
    out: list[tuple[str, list[str]]] = client.gather(futs)
    return out


def summary_row(summary: dict[str, Any]) -> dict[str, Any]:
    """Flat scalar fields of a run summary for a DataFrame row."""
    keys = (
        "rms_error",
        "rms_error_settled",
        "max_abs_error",
        "error_unit",
        "trip",
        "interrupted",
        "cycles",
        "duration_s",
        "mcap",
    )
    return {k: summary.get(k) for k in keys}


def diagnose_row(r: dict[str, Any]) -> dict[str, Any]:
    """Flat fields of a diagnosis (or of a campaign: its pooled force NRMSE) for a DataFrame row."""
    if r.get("mode") == "campaign":
        pooled = r.get("pooled") or {}
        nom, law = pooled.get("nominal"), pooled.get("law")
        return {
            "mode": "campaign",
            "cause": r.get("cause"),
            "causes": "",
            "gain": None if not nom or law is None else 1.0 - law / nom,
            "nrmse_nominal": nom,
            "nrmse_extended": law,
            "warnings": len(r.get("warnings") or []),
            "report": r.get("report"),
        }
    nom = r.get("nrmse_nominal") or {}
    ext = r.get("nrmse_extended") or {}
    return {
        "mode": "record",
        "cause": r.get("cause"),
        "causes": ",".join(r.get("causes") or []),
        "gain": r.get("gain"),
        "nrmse_nominal": nom.get("overall") if isinstance(nom, dict) else nom,
        "nrmse_extended": ext.get("overall") if isinstance(ext, dict) else ext,
        "warnings": len(r.get("warnings") or []),
        "report": r.get("report"),
    }
