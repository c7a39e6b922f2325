"""ehactl.metrics and loop margins against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ehactl import metrics
from ehactl import tune


def test_first_order_step_closed_forms():
    tau = 0.01
    t = np.arange(0, 0.5, 1e-5)
    y = np.where(t >= 0.1, 1.0 - np.exp(-(t - 0.1) / tau), 0.0) * 2.0
    m = metrics.step_metrics(t, y, r_final=2.0, r_initial=0.0, t_step=0.1)
    assert m["itae"] == pytest.approx(2.0 * tau**2, rel=1e-3)  # ∫ t·A e^{-t/τ} dt = A τ²
    assert m["iae"] == pytest.approx(2.0 * tau, rel=1e-3)
    assert m["ise"] == pytest.approx(4.0 * tau / 2, rel=1e-3)
    assert m["rise_time"] == pytest.approx(tau * math.log(9), rel=1e-3)
    assert m["settling_time"] == pytest.approx(tau * math.log(50), rel=1e-3)
    assert m["overshoot_pct"] == 0.0
    assert abs(m["steady_state_error"]) < 1e-12


def test_second_order_overshoot():
    zeta, wn = 0.3, 2 * np.pi * 10
    t = np.arange(0, 2.0, 1e-5)
    wd = wn * math.sqrt(1 - zeta**2)
    y = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * t))
    m = metrics.step_metrics(t, y, 1.0)
    assert m["overshoot_pct"] == pytest.approx(100 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2)), rel=1e-4)


def test_saturation_counts_only_while_settling():
    t = np.linspace(0, 1, 1001)
    y = np.clip(t / 0.5, 0, 1)
    u_unsat = np.where(t < 0.4, 20.0, 1.0)  # saturated while slewing only
    m = metrics.step_metrics(t, y, 1.0, u=np.clip(u_unsat, -10, 10), u_unsat=u_unsat, u_limit=10.0)
    assert m["saturation_fraction"] == 0.0
    assert m["saturation_fraction_total"] == pytest.approx(0.4, abs=0.002)
    assert m["peak_command"] == 10.0


def test_tone_amplitude_and_vibration():
    t = np.arange(0, 1, 1e-4)
    y = 0.6 + 3e-6 * np.sin(2 * np.pi * 21.8 * t + 0.3) + 1e-6 * np.sin(2 * np.pi * 90 * t)
    # 21.8 periods in the window: the 90 Hz tone leaks a little into the fit
    assert metrics.tone_amplitude(t, y, 21.8) == pytest.approx(3e-6, rel=5e-3)
    v = metrics.vibration_metrics(t, y, 0.6, 0.0, 21.8)
    assert v["vibration_rms"] == pytest.approx(math.sqrt((3e-6**2 + 1e-6**2) / 2), rel=1e-2)
    assert abs(v["position_error"]) < 1e-8


def test_oscillation_growth():
    t = np.arange(0, 1, 1e-4)
    f = 50.0
    dec = np.exp(-3 * t) * np.sin(2 * np.pi * f * t)
    gro = np.exp(+3 * t) * np.sin(2 * np.pi * f * t)
    gd = metrics.oscillation_growth(t, dec, 0.0)
    gg = metrics.oscillation_growth(t, gro, 0.0)
    assert gd["ratio"] == pytest.approx(math.exp(-1.5), rel=0.05)
    assert gg["ratio"] == pytest.approx(math.exp(1.5), rel=0.05)
    assert gd["period"] == pytest.approx(1 / f, rel=1e-3)


def test_loop_margins_closed_form():
    # L(s) = k / (s (s + a)(s + b)): phase crossover at ω = √(ab), GM = (a + b)ab / k
    a, b, k = 50.0, 400.0, 2.0e6
    f = np.geomspace(0.5, 500, 4000)
    s = 2j * np.pi * f
    L = k / (s * (s + a) * (s + b))
    m = tune.loop_margins(f, L)
    wp = math.sqrt(a * b)
    assert m["phase_crossover_hz"] == pytest.approx(wp / (2 * np.pi), rel=1e-3)
    assert m["gain_margin_db"] == pytest.approx(20 * math.log10((a + b) * a * b / k), abs=0.01)
    # gain crossover: |L(jω)| = 1 solved numerically, PM = 90° − atan(ω/a) − atan(ω/b)
    # ω²(ω² + a²)(ω² + b²) = k²  → cubic in x = ω²
    roots = np.roots([1, a * a + b * b, a * a * b * b, -k * k])
    wc = math.sqrt(max(r.real for r in roots if abs(r.imag) < 1e-6))
    assert m["crossover_hz"] == pytest.approx(wc / (2 * np.pi), rel=1e-3)
    pm = 90 - math.degrees(math.atan(wc / a)) - math.degrees(math.atan(wc / b))
    assert m["phase_margin_deg"] == pytest.approx(pm, abs=0.05)


def test_discrete_pi_response_tends_to_continuous(force_cfg):
    f = np.array([1.0, 10.0])
    C = tune.controller_response(force_cfg, f)
    g, kp, integ = 0.5097e-3, 0.57, 386.24
    cont = g * kp * (1 + integ / (2j * np.pi * f))
    # backward Euler: C(z) = g K_P (1 + I T / (1 − z⁻¹)) → continuous PI + g K_P I T / 2
    np.testing.assert_allclose(C, cont + g * kp * integ * 2e-4 / 2, rtol=2e-3)
