"""Matplotlib figures (optional dependency: ``pip install matplotlib``).

- :func:`bode` — magnitude (dB) and phase (deg) of frequency responses with the loop's
  gain/phase crossovers and margins marked;
- :func:`step` — step responses of several runs (controlled variable and valve command);
- :func:`tracking` — setpoint vs feedback of a run.

Every function returns the ``matplotlib.figure.Figure`` and saves it when ``path`` is given
(PNG by extension).
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any, Sequence, Union

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

_PathLike = Union[str, "os.PathLike[str]", None]


def _two_axes(figsize: tuple[float, float], ratios: Sequence[float] | None = None) -> tuple[Figure, Axes, Axes]:
    """A figure with two stacked axes sharing x; matplotlib imported only now."""
    try:
        import matplotlib.pyplot as plt  # headless: matplotlib falls back to Agg itself
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("ehactl.plot needs matplotlib: pip install matplotlib") from e
    kw: dict[str, Any] = {} if ratios is None else {"gridspec_kw": {"height_ratios": list(ratios)}}
    fig, axes = plt.subplots(2, 1, sharex=True, figsize=figsize, **kw)
    return fig, axes[0], axes[1]


def _save(fig: Figure, path: _PathLike) -> None:
    if path is not None:
        fig.savefig(path, dpi=120, bbox_inches="tight")


def bode(
    responses: Any,
    labels: Sequence[str] | None = None,
    which: str = "loop",
    title: str | None = None,
    margins: bool = True,
    path: _PathLike = None,
) -> Figure:
    """Bode plot of one or several responses.

    ``responses``: a :class:`ehactl.tune.FrequencyResponse` (plots ``which`` = ``"loop"``
    L = C·P, ``"plant"`` P, ``"closed"`` T = Y/R measured, or ``"controller"`` C), a list of
    them, or ``(f_hz, complex_array)`` tuples. For loop responses the gain crossover, phase
    margin and gain margin are marked (``margins=True``).
    """
    from ._freq import FrequencyResponse, loop_margins

    items = responses if isinstance(responses, (list, tuple)) and not (
        len(responses) == 2 and isinstance(responses[0], np.ndarray)
    ) else [responses]
    fig, ax_m, ax_p = _two_axes((7.5, 6.0))
    unit = ""
    for i, it in enumerate(items):
        if isinstance(it, FrequencyResponse):
            f = it.f
            h = getattr(it, which)
            unit = {"loop": "-", "plant": f"{it.unit}/V", "closed": f"{it.unit}/{it.unit}", "controller": f"V/{it.unit}"}[which]
            lab = labels[i] if labels else ", ".join(f"{k.split('.')[-1]}={v:.4g}" for k, v in it.gains.items())
        else:
            f, h = it
            lab = labels[i] if labels else f"response {i}"
        f = np.asarray(f)
        h = np.asarray(h)
        ok = np.isfinite(h)
        ph = np.degrees(np.unwrap(np.angle(h[ok])))
        if which == "loop" and len(ph) and ph[0] > 90:
            ph -= 360 * math.ceil((ph[0] - 90) / 360)
        (line,) = ax_m.semilogx(f[ok], 20 * np.log10(np.abs(h[ok])), "-o", ms=3, label=lab)
        ax_p.semilogx(f[ok], ph, "-o", ms=3, color=line.get_color())
        if margins and which == "loop":
            m = loop_margins(f[ok], h[ok])
            if math.isfinite(m["crossover_hz"]):
                ax_m.axvline(m["crossover_hz"], color=line.get_color(), ls=":", lw=1)
                ax_p.annotate(
                    f"PM {m['phase_margin_deg']:.0f}° @ {m['crossover_hz']:.3g} Hz",
                    (m["crossover_hz"], m["phase_margin_deg"] - 180),
                    textcoords="offset points", xytext=(5, 8 + 12 * i), fontsize=8, color=line.get_color(),
                )
            if math.isfinite(m["phase_crossover_hz"]):
                ax_m.annotate(
                    f"GM {m['gain_margin_db']:.1f} dB @ {m['phase_crossover_hz']:.3g} Hz",
                    (m["phase_crossover_hz"], -m["gain_margin_db"]),
                    textcoords="offset points", xytext=(5, -14 - 12 * i), fontsize=8, color=line.get_color(),
                )
    if which == "loop":
        ax_m.axhline(0, color="k", lw=0.6)
        ax_p.axhline(-180, color="k", lw=0.6)
    if which == "closed":
        ax_m.axhline(-3, color="k", lw=0.6, ls="--")
    ax_m.set_ylabel(f"magnitude (dB re 1 {unit})")
    ax_p.set_ylabel("phase (deg)")
    ax_p.set_xlabel("frequency (Hz)")
    ax_m.grid(True, which="both", alpha=0.3)
    ax_p.grid(True, which="both", alpha=0.3)
    ax_m.legend(fontsize=8)
    ax_m.set_title(title or {"loop": "Loop L = C·P", "plant": "Plant P = Y/U", "closed": "Closed loop Y/R", "controller": "Controller C"}[which])
    fig.tight_layout()
    _save(fig, path)
    return fig


def step(
    results: Any,
    labels: Sequence[str] | None = None,
    signal: str | None = None,
    title: str | None = None,
    t_range: tuple[float, float] | None = None,
    path: _PathLike = None,
) -> Figure:
    """Step responses: the controlled variable (ground truth ``rod_force`` in force mode,
    ``x`` in position mode, or ``signal``) with the setpoint, and the valve command (V), of
    one or several :class:`ehactl.RunResult`."""
    items = results if isinstance(results, (list, tuple)) else [results]
    fig, ax_y, ax_u = _two_axes((7.5, 6.0), (2, 1))
    unit = ""
    for i, r in enumerate(items):
        sig = signal or ("rod_force" if r.unit == "N" else "x")
        unit = r.unit
        t = r.t
        m = np.ones_like(t, dtype=bool) if t_range is None else (t >= t_range[0]) & (t <= t_range[1])
        lab = labels[i] if labels else f"run {i}"
        (line,) = ax_y.plot(t[m], r[sig][m], label=lab)
        ax_u.plot(t[m], r.u[m], color=line.get_color())
        if i == 0:
            ax_y.plot(t[m], r.setpoint[m], "k--", lw=1, label="setpoint")
    ax_y.set_ylabel(f"{signal or ('force' if unit == 'N' else 'position')} ({unit})")
    ax_u.set_ylabel("valve command (V)")
    ax_u.set_xlabel("time (s)")
    for ax in (ax_y, ax_u):
        ax.grid(True, alpha=0.3)
    ax_y.legend(fontsize=8)
    ax_y.set_title(title or "Step response (nonlinear plant)")
    fig.tight_layout()
    _save(fig, path)
    return fig


def tracking(
    result: Any,
    signal: str | None = None,
    title: str | None = None,
    t_range: tuple[float, float] | None = None,
    path: _PathLike = None,
) -> Figure:
    """Setpoint, feedback and error of one run over time."""
    r = result
    sig = signal or "feedback"
    t = r.t
    m = np.ones_like(t, dtype=bool) if t_range is None else (t >= t_range[0]) & (t <= t_range[1])
    fig, ax_y, ax_e = _two_axes((7.5, 5.5), (2, 1))
    ax_y.plot(t[m], r.setpoint[m], "k--", lw=1, label="setpoint")
    ax_y.plot(t[m], r[sig][m], lw=0.8, label=sig)
    ax_e.plot(t[m], (r.setpoint - r[sig])[m], lw=0.8)
    ax_y.set_ylabel(f"({r.unit})")
    ax_e.set_ylabel(f"error ({r.unit})")
    ax_e.set_xlabel("time (s)")
    for ax in (ax_y, ax_e):
        ax.grid(True, alpha=0.3)
    ax_y.legend(fontsize=8)
    ax_y.set_title(title or "Tracking")
    fig.tight_layout()
    _save(fig, path)
    return fig
