"""Time-domain metrics of closed-loop runs (step response, tracking, vibration).

All functions take plain NumPy arrays in SI units, so they apply to simulated runs
(:class:`ehactl.RunResult`), MCAP logs read with :func:`ehactl.read_mcap` and measured data
alike. The variable ``y`` is whatever is controlled: force (N) or position (m).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _trapz(y: np.ndarray, t: np.ndarray) -> float:
    if len(t) < 2:
        return 0.0
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(t)))


def step_metrics(
    t: np.ndarray,
    y: np.ndarray,
    r_final: float,
    r_initial: float = 0.0,
    t_step: float = 0.0,
    u: np.ndarray | None = None,
    u_unsat: np.ndarray | None = None,
    u_limit: float | None = None,
    settle_band: float = 0.02,
) -> dict[str, float]:
    """Metrics of a step from ``r_initial`` to ``r_final`` applied at ``t_step`` (s).

    Returns (units of y = N or m):

    - ``itae``: ∫ (t − t_step)·|r − y| dt over the window after the step (unit·s²);
      ``iae`` (unit·s) and ``ise`` (unit²·s) likewise;
    - ``overshoot_pct``: peak beyond ``r_final`` in % of the step size (≥ 0);
    - ``rise_time``: 10 → 90 % of the step (s), NaN if never reached;
    - ``settling_time``: last time outside ±``settle_band``·|step| of ``r_final`` (s after
      the step), NaN if the response ends outside the band;
    - ``steady_state_error``: mean of r − y over the last 10 % of the window;
    - ``peak_command``: max |u| (V); with ``u_limit`` (V): ``saturation_fraction``, the
      share of cycles from the 90 % rise on whose unsaturated command is at or beyond the
      limit (saturation while settling: chatter or a limit cycle; slewing at full valve
      opening during a long move does not count), and ``saturation_fraction_total`` over
      the whole window.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    m = t >= t_step
    tt = t[m] - t_step
    yy = y[m]
    step = float(r_final - r_initial)
    out: dict[str, float] = {}
    if len(tt) < 2 or step == 0.0:
        raise ValueError("step_metrics: need a non-zero step and samples after t_step")
    e = r_final - yy
    out["itae"] = _trapz(tt * np.abs(e), tt)
    out["iae"] = _trapz(np.abs(e), tt)
    out["ise"] = _trapz(e * e, tt)
    s = np.sign(step)
    out["overshoot_pct"] = float(max(0.0, np.max(s * (yy - r_final))) / abs(step) * 100.0)
    frac = s * (yy - r_initial) / abs(step)
    i10 = np.argmax(frac >= 0.1) if np.any(frac >= 0.1) else None
    i90 = np.argmax(frac >= 0.9) if np.any(frac >= 0.9) else None
    out["rise_time"] = float(tt[i90] - tt[i10]) if i10 is not None and i90 is not None else math.nan
    outside = np.nonzero(np.abs(e) > settle_band * abs(step))[0]
    if len(outside) == 0:
        out["settling_time"] = 0.0
    elif outside[-1] == len(tt) - 1:
        out["settling_time"] = math.nan
    else:
        out["settling_time"] = float(tt[outside[-1] + 1])
    tail = max(1, len(e) // 10)
    out["steady_state_error"] = float(np.mean(e[-tail:]))
    if u is not None:
        out["peak_command"] = float(np.max(np.abs(np.asarray(u)[m])))
    if u_unsat is not None and u_limit is not None:
        sat = np.abs(np.asarray(u_unsat)[m]) >= u_limit
        out["saturation_fraction_total"] = float(np.mean(sat))
        after = sat[i90:] if i90 is not None else sat
        out["saturation_fraction"] = float(np.mean(after))
    return out


def tone_amplitude(t: np.ndarray, y: np.ndarray, frequency: float) -> float:
    """Amplitude of the ``frequency`` (Hz) component of ``y`` (least-squares sine fit with
    offset and linear trend removed), in the unit of y."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    w = 2.0 * np.pi * frequency
    a = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t), t - t.mean()])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    return float(math.hypot(coef[0], coef[1]))


def vibration_metrics(
    t: np.ndarray, y: np.ndarray, target: float, t_from: float, frequency: float | None = None
) -> dict[str, float]:
    """Vibration of ``y`` about its mean after ``t_from`` (s): ``vibration_rms``
    (std, unit of y), ``vibration_p2p`` (peak to peak), ``position_error`` (target − mean),
    ``rms_error`` (RMS of target − y), and ``tone_amplitude`` at ``frequency`` (Hz) if given."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    m = t >= t_from
    if np.count_nonzero(m) < 4:
        raise ValueError(f"vibration_metrics: fewer than 4 samples after t_from = {t_from} s")
    yy = y[m]
    out = {
        "vibration_rms": float(np.std(yy)),
        "vibration_p2p": float(np.ptp(yy)),
        "position_error": float(target - np.mean(yy)),
        "rms_error": float(np.sqrt(np.mean((target - yy) ** 2))),
    }
    if frequency is not None:
        out["tone_amplitude"] = tone_amplitude(t[m], yy, frequency)
    return out


def oscillation_growth(t: np.ndarray, y: np.ndarray, t_from: float) -> dict[str, Any]:
    """Split the window after ``t_from`` (s) in two halves, remove a linear trend from each
    and compare the RMS of what is left: ``ratio`` = RMS(second) / RMS(first) (< 1 decaying,
    ≥ 1 sustained or growing), ``rms_first``, ``rms_second`` and the oscillation ``period``
    (s, from zero crossings of the detrended second half; NaN if fewer than 3 crossings)."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    m = t >= t_from
    tt, yy = t[m], y[m]
    h = len(tt) // 2
    if h < 8:
        raise ValueError("oscillation_growth: window too short")

    def detrend(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        p = np.polyfit(a - a[0], b, 1)
        return b - np.polyval(p, a - a[0])

    d1 = detrend(tt[:h], yy[:h])
    d2 = detrend(tt[h:], yy[h:])
    r1 = float(np.sqrt(np.mean(d1**2)))
    r2 = float(np.sqrt(np.mean(d2**2)))
    sign = np.signbit(d2)
    cross = np.nonzero(sign[1:] != sign[:-1])[0]
    if len(cross) >= 3:
        tc = tt[h:][cross]
        period = float(2.0 * (tc[-1] - tc[0]) / (len(cross) - 1))
    else:
        period = math.nan
    ratio = r2 / r1 if r1 > 0 else (math.inf if r2 > 0 else 0.0)
    return {"ratio": ratio, "rms_first": r1, "rms_second": r2, "period": period}
