"""ehactl.tune on the seed rigs: the three tuning methods demonstrated and cross-checked."""

from __future__ import annotations

import math

import numpy as np
import pytest

import ehactl
from ehactl import tune

PAPER_HAND_GAINS = [
    {"control.pi.kp": 0.57, "control.pi.integral": 386.24},  # 004 §6.1 model-based
    {"control.pi.kp": 0.4, "control.pi.integral": 386.24},  # 004 §6.2 experiment
]


@pytest.fixture(scope="module")
def force_fr():
    cfg = ehactl.Config.load(__import__("conftest").CONFIGS / "sahu2022_force.toml")
    return cfg, tune.frequency_response(cfg)


def test_measured_loop_matches_paper_and_linear_model(force_fr):
    """004 §6.1 (labels as corrected in REPRODUCTION.md: 99.63 Hz is the gain crossover):
    K_P 0.57, I 386.24 give PM 60° at 99.63 Hz. The loop measured by stepped sine on the
    nonlinear plant must land close, and agree with the linearised model of ehactl-analysis
    (two independent routes to the same loop)."""
    cfg, fr = force_fr
    m = fr.margins()
    assert m["phase_margin_deg"] == pytest.approx(60.0, abs=4.0)
    assert m["crossover_hz"] == pytest.approx(99.63, rel=0.08)
    assert m["gain_margin_db"] > 6.0
    lin = tune.linear_response(cfg).margins()
    assert m["phase_margin_deg"] == pytest.approx(lin["phase_margin_deg"], abs=1.5)
    assert m["crossover_hz"] == pytest.approx(lin["crossover_hz"], rel=0.02)
    assert m["gain_margin_db"] == pytest.approx(lin["gain_margin_db"], abs=0.5)
    # measured closed loop Y/R equals L/(1+L) from the measured P and the known C(z)
    L = fr.loop
    np.testing.assert_allclose(fr.closed, L / (1 + L), rtol=0.02, atol=0.005)


def test_linear_and_measured_plant_responses_agree(force_fr):
    cfg, fr = force_fr
    good = fr.purity > 0.99
    assert np.count_nonzero(good) >= 15
    lin = tune.linear_response(cfg, f_hz=fr.f[good]).plant
    meas = fr.plant[good]
    np.testing.assert_allclose(20 * np.log10(np.abs(meas)), 20 * np.log10(np.abs(lin)), atol=0.3)
    dphi = np.degrees(np.angle(meas / lin))
    assert np.max(np.abs(dphi)) < 2.0


def test_optimized_step_itae_vs_paper_hand_gains(force_cfg):
    """Stated metric 1: ITAE of the 0 → 785 N step (true rod force), overshoot ≤ 5 %,
    ≤ 1 % command saturation while settling. The optimum is far better than the
    model-based K_P 0.57 and at least as good as the experimental K_P 0.4, which turns out
    to sit at the ITAE optimum of this plant."""
    res = tune.optimize(force_cfg, "itae", generations=6, population=12)
    h57, h40 = tune.evaluate(force_cfg, PAPER_HAND_GAINS, res.test)
    assert res.details["feasible"]
    assert res.metrics["overshoot_pct"] <= 5.0
    assert res.metrics.get("saturation_fraction", 0.0) <= 0.01
    assert res.metrics["itae"] < 0.8 * h57["itae"]
    assert res.metrics["settling_time"] < h57["settling_time"]
    assert res.metrics["itae"] <= 1.005 * h40["itae"]


def test_sweep_optimisation_beats_paper_hand_gains_on_tracking(force_cfg):
    """Stated metric 2: RMS force error (true rod force) on the paper's 785 N ± 196 N,
    1–300 Hz sweep, with the step test's overshoot ≤ 5 % as a constraint."""
    track = tune.TrackingTest.default(force_cfg)
    step = tune.StepTest.default(force_cfg)
    res = tune.optimize(force_cfg, "rms_error", test=track, constraint_test=step, generations=5, population=9)
    hand = tune.evaluate(force_cfg, PAPER_HAND_GAINS, track)
    assert res.details["feasible"] and res.metrics["overshoot_pct"] <= 5.0
    for h in hand:
        assert res.metrics["rms_error"] < 0.97 * h["rms_error"]


def test_model_based_reproduces_paper_gains(force_cfg, force_fr, tmp_path):
    """004 §6.1 tuned K_P 0.57, I 386.24 for PM 60° (bandwidth ≈ 200 Hz) on its linearised
    model. The PM-60° design with the largest integral gain on the linearised loop must
    come out near those gains, and the loop re-measured on the nonlinear plant with the new
    gains must show the designed phase margin."""
    res = tune.model_based(force_cfg, phase_margin_deg=60.0)
    assert res.details["plant_model"] == "linear"
    assert res.gains["control.pi.kp"] == pytest.approx(0.57, rel=0.1)
    assert res.gains["control.pi.integral"] == pytest.approx(386.24, rel=0.1)
    again = tune.frequency_response(res.config).margins()
    assert again["phase_margin_deg"] == pytest.approx(60.0, abs=3.0)
    assert again["crossover_hz"] == pytest.approx(res.details["crossover_hz"], rel=0.05)
    # the same design from the measured response
    res_m = tune.model_based(force_cfg, phase_margin_deg=60.0, fr=force_fr[1])
    assert res_m.gains["control.pi.kp"] == pytest.approx(res.gains["control.pi.kp"], rel=0.1)
    p = tmp_path / "tuned.toml"
    res.write_config(p)
    back = ehactl.Config.load(p)
    assert back["control.pi.kp"] == pytest.approx(res.gains["control.pi.kp"])
    assert back["control.pi.integral"] == pytest.approx(res.gains["control.pi.integral"])


def test_critical_gain_agrees_with_the_frequency_response(force_cfg, force_fr):
    """Time-domain K_Pcr / T_pcr of the P-only loop vs the frequency-domain prediction
    from the measured plant: oscillation where arg P = −180°, K_cr = 1/(g |P|)."""
    res = tune.critical_gain(force_cfg, "zn")
    _, fr = force_fr
    ph = np.unwrap(np.angle(fr.plant))
    i = int(np.argmax(ph <= -np.pi))
    lf = np.log(fr.f)
    x = np.interp(-np.pi, [ph[i], ph[i - 1]], [lf[i], lf[i - 1]])
    f180 = math.exp(x)
    mag = math.exp(np.interp(x, lf, np.log(np.abs(fr.plant))))
    g = force_cfg["control.pi.error_scale"]
    # the P-only controller adds no phase, but the loop samples: allow 15 %
    assert res.details["K_Pcr"] == pytest.approx(1.0 / (g * mag), rel=0.15)
    assert res.details["f_cr_hz"] == pytest.approx(f180, rel=0.15)
    # Ziegler–Nichols PI rule
    assert res.gains["control.pi.kp"] == pytest.approx(0.45 * res.details["K_Pcr"])
    assert res.gains["control.pi.integral"] == pytest.approx(1.2 / res.details["T_pcr"])


def test_model_based_on_the_measured_loop_reproduces_paper_gains(force_cfg, force_fr, tmp_path):
    """004 §6.1 tuned K_P 0.57, I 386.24 for PM 60° at the widest bandwidth; our
    model-based design on the measured loop must come out near that, and the re-measured
    loop with the new gains must show the designed phase margin."""
    _, fr = force_fr
    res = tune.model_based(force_cfg, phase_margin_deg=60.0, fr=fr)
    assert res.gains["control.pi.kp"] == pytest.approx(0.57, rel=0.2)
    assert res.gains["control.pi.integral"] == pytest.approx(386.24, rel=0.3)
    again = tune.frequency_response(res.config).margins()
    assert again["phase_margin_deg"] == pytest.approx(60.0, abs=3.0)
    assert again["crossover_hz"] == pytest.approx(res.details["crossover_hz"], rel=0.05)
    p = tmp_path / "tuned.toml"
    res.write_config(p)
    back = ehactl.Config.load(p)
    assert back["control.pi.kp"] == pytest.approx(res.gains["control.pi.kp"])
    assert back["control.pi.integral"] == pytest.approx(res.gains["control.pi.integral"])


def test_boom_pd_critical_gain_positions_with_less_vibration(boom_cfg):
    """Dindorf 2022: PD tuned by the critical-gain method positions the piston at 0.6 m with
    less vibration under the 21.8 Hz force than the config's starting gains."""
    res = tune.critical_gain(boom_cfg, "zn")
    b, t = res.baseline, res.metrics
    assert 1.0 / res.details["T_pcr"] != pytest.approx(21.8, rel=0.05)  # not the forced vibration
    assert t["vibration_rms"] < 0.5 * b["vibration_rms"]
    assert t["vibration_p2p"] < 0.5 * b["vibration_p2p"]
    assert abs(t["position_error"]) < abs(b["position_error"])
    assert t["overshoot_pct"] < 5.0
    assert res.gains["control.pd.kp"] == pytest.approx(0.8 * res.details["K_Pcr"])
    assert res.gains["control.pd.td"] == pytest.approx(res.details["T_pcr"] / 8)


def test_boom_model_based_pd(boom_cfg):
    res = tune.model_based(boom_cfg, phase_margin_deg=60.0)
    assert res.details["predicted"]["phase_margin_deg"] == pytest.approx(60.0, abs=0.5)
    assert res.metrics["vibration_rms"] < res.baseline["vibration_rms"]
    assert abs(res.metrics["position_error"]) < abs(res.baseline["position_error"])


def test_bad_tuning_requests(force_cfg):
    with pytest.raises(ValueError, match="rule"):
        tune.critical_gain(force_cfg, "nope")
    with pytest.raises(RuntimeError, match="stayed stable"):
        tune.critical_gain(force_cfg, kp_range=(0.01, 0.1))
    with pytest.raises(ValueError, match="outside the measured range"):
        tune.model_based(force_cfg, crossover_hz=1e5, fr=tune.frequency_response(force_cfg, f_hz=[50, 100, 200, 400]))
    with pytest.raises(ValueError, match="source"):
        tune.model_based(force_cfg, source="guess")
    with pytest.raises(ValueError, match="Nyquist"):
        tune.linear_response(force_cfg, f_hz=[10.0, 3000.0])
    ol = force_cfg.with_values({"control.mode": "open_loop"})
    with pytest.raises(ValueError, match="open_loop"):
        tune.optimize(ol)
