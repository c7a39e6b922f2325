"""The loop analysis of ehactl.tune (controller response, sampled-loop margins) now comes
from ehactl-analysis through the bindings; it must equal, within float rounding, the
closed forms the Python code used before (kept here as the oracle: PI 004 §6 backward-Euler
integral, PD 003 eq. 32 with its derivative filter; margins by first crossings in log f)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import ehactl
from ehactl._freq import controller_response, linear_response, loop_margins
from conftest import REPO


def oracle_controller(c, f):
    T = c.control_dt
    zi = np.exp(-1j * 2 * np.pi * np.asarray(f, dtype=float) * T)
    if c.mode == "force":
        kp, integ, g = c["control.pi.kp"], c["control.pi.integral"], c["control.pi.error_scale"]
        return g * kp * (1.0 + integ * T / (1.0 - zi))
    kp, td, n = c["control.pd.kp"], c["control.pd.td"], c["control.pd.filter_n"]
    tf = td / n if n > 0 else 0.0
    return kp + kp * td * (1.0 - zi) / ((tf + T) - tf * zi)


def _crossings(lf, a, level):
    out = []
    for i in range(len(a) - 1):
        y0, y1 = a[i] - level, a[i + 1] - level
        if y0 > 0 >= y1:
            out.append(float(lf[i] + (lf[i + 1] - lf[i]) * y0 / (y0 - y1)))
    return out


def oracle_margins(f, L):
    lf = np.log(f)
    mag_db = 20 * np.log10(np.abs(L))
    ph = np.degrees(np.unwrap(np.angle(L)))
    if ph[0] > 90:
        ph -= 360 * math.ceil((ph[0] - 90) / 360)
    out = {k: math.nan for k in ("crossover_hz", "phase_margin_deg", "phase_crossover_hz", "gain_margin_db")}
    gc = _crossings(lf, mag_db, 0.0)
    if gc:
        out["crossover_hz"] = math.exp(gc[0])
        out["phase_margin_deg"] = 180.0 + float(np.interp(gc[0], lf, ph))
    pc = _crossings(lf, ph, -180.0)
    if pc:
        out["phase_crossover_hz"] = math.exp(pc[0])
        out["gain_margin_db"] = -float(np.interp(pc[0], lf, mag_db))
    with np.errstate(invalid="ignore"):  # a NaN point stays NaN, as in ehactl
        tdb = 20 * np.log10(np.abs(L / (1 + L)))
    bw = _crossings(lf, tdb, -3.0)
    out["bandwidth_hz"] = math.exp(bw[0]) if bw else math.nan
    out["peak_closed_db"] = float(np.max(tdb))
    return out


def assert_same(ours, ref):
    assert set(ours) == set(ref)
    for k in ref:
        if math.isnan(ref[k]):
            assert math.isnan(ours[k]), k
        else:
            assert ours[k] == pytest.approx(ref[k], rel=1e-9, abs=1e-9), k


@pytest.mark.parametrize("rig", ["sahu2022_force", "dindorf2022_boom"])
def test_controller_response_and_margins_equal_the_closed_forms(rig):
    cfg = ehactl.Config.load(REPO / "configs" / f"{rig}.toml")
    f = np.geomspace(0.2, 0.45 / cfg.control_dt, 300)
    C = controller_response(cfg, f)
    np.testing.assert_allclose(C, oracle_controller(cfg, f), rtol=1e-12)
    paths = ("control.pi.kp", "control.pi.integral") if cfg.mode == "force" else ("control.pd.kp", "control.pd.td")
    g = {paths[0]: 1.7 * cfg[paths[0]], paths[1]: 0.5 * cfg[paths[1]]}
    np.testing.assert_allclose(controller_response(cfg, f, g), oracle_controller(cfg.with_values(g), f), rtol=1e-12)
    fr = linear_response(cfg, f)
    L = fr.loop
    m = loop_margins(f, L)
    assert math.isfinite(m["crossover_hz"]) and math.isfinite(m["phase_margin_deg"])
    assert_same(m, oracle_margins(f, L))
    # a stiffer loop shifts the crossover: same on both sides
    assert_same(fr.with_gains(cfg, g).margins(), oracle_margins(f, controller_response(cfg, f, g) * fr.plant))


def test_margins_of_textbook_loops_and_edge_cases():
    f = np.geomspace(0.1, 1000.0, 400)
    s = 2j * np.pi * f
    rng = np.random.default_rng(7)
    for k, tau in [(10.0, 1e-3), (50.0, 2e-3), (3.0, 5e-3)]:
        L = k / (s * (1 + s * tau)) * np.exp(-s * tau)  # integrator, lag and delay
        assert_same(loop_margins(f, L), oracle_margins(f, L))
        # noisy "measured" versions with wraps and a NaN point (a tripped frequency)
        Ln = L * np.exp(0.02 * rng.standard_normal(len(f)) + 1j * 0.3 * rng.standard_normal(len(f)))
        assert_same(loop_margins(f, Ln), oracle_margins(f, Ln))
        Ln[200] = complex("nan")
        assert_same(loop_margins(f, Ln), oracle_margins(f, Ln))
    # integrator k/s: |L| = 1 at k/2π, phase −90°: PM 90°, no phase crossover
    m = loop_margins(f, 100.0 / s)
    assert m["crossover_hz"] == pytest.approx(100 / (2 * np.pi), rel=1e-3)
    assert m["phase_margin_deg"] == pytest.approx(90.0, abs=1e-9)
    assert math.isnan(m["gain_margin_db"])
    with pytest.raises(ValueError, match="strictly increasing"):
        loop_margins(f[::-1], L)
    cfg = ehactl.Config.load(REPO / "configs" / "sahu2022_force.toml")
    cfg["control.mode"] = "open_loop"
    with pytest.raises(ValueError, match="open_loop"):
        controller_response(cfg, f)
