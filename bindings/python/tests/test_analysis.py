"""ehactl.analyze / ehactl.sweep mirror the CLI: same numbers as `ehactl analyze --json` and
`ehactl sweep --json`, NumPy arrays, clear ValueErrors."""

from __future__ import annotations

import json
import os
import subprocess

import numpy as np
import pytest

import ehactl
from conftest import CONFIGS, REPO

EHACTL = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))


def test_analyze_matches_the_cli(force_cfg):
    a = ehactl.analyze(force_cfg)
    cli = json.loads(subprocess.run([EHACTL, "analyze", str(CONFIGS / "sahu2022_force.toml"), "--json"],
                                    check=True, capture_output=True, text=True).stdout)
    for k in ("phase_margin_deg", "gain_crossover_hz", "gain_margin_db", "closed_loop_bandwidth_hz",
              "open_loop_bandwidth_hz", "hydraulic_natural_frequency_hz"):
        assert getattr(a, k) == pytest.approx(cli[k], rel=1e-12), k
    assert a.sampled_loop is True
    lr = a.loop_response
    assert isinstance(lr.f_hz, np.ndarray) and lr.f_hz.shape == lr.closed_mag_db.shape
    # Changing the gain through params changes the margins the way loop shaping says: a
    # lower proportional gain lowers the crossover and raises the gain margin.
    b = ehactl.analyze(force_cfg, params={"control.pi.kp": 0.4})
    assert b.gain_crossover_hz < a.gain_crossover_hz
    assert b.gain_margin_db > a.gain_margin_db


def test_sweep_returns_arrays_and_the_paper_bandwidth(force_cfg, tmp_path):
    seen = []
    r = ehactl.sweep(force_cfg, 5.0, 300.0, points=8, mcap=tmp_path / "s.mcap",
                     progress=lambda d, n: seen.append((d, n)))
    assert r.mode == "closed_loop" and r.complete
    assert r.frf.f_hz.shape == (8,) and np.all(np.diff(r.frf.f_hz) > 0)
    assert np.all((r.frf.coherence >= 0) & (r.frf.coherence <= 1 + 1e-12))
    assert 170 <= r.bandwidth_hz <= 240
    assert (tmp_path / "s.mcap").stat().st_size > 0
    assert seen and seen[-1][0] == seen[-1][1]
    run = ehactl.read_mcap(tmp_path / "s.mcap")
    assert run is not None


def test_sweep_bad_arguments_raise_value_errors(force_cfg):
    with pytest.raises(ValueError, match="--to"):
        ehactl.sweep(force_cfg, 5.0, 4000.0, points=4)
    with pytest.raises(ValueError, match="output"):
        ehactl.sweep(force_cfg, 5.0, 100.0, points=4, output="torque")
    with pytest.raises(ValueError, match="--points"):
        ehactl.sweep(force_cfg, 5.0, 100.0, points=1)


def test_diagnose_names_a_hidden_delay_like_the_cli(delay_diagnosis, tmp_path):
    """A run of the test rig with a hidden 5 ms command delay, logged to MCAP from Python,
    diagnosed against the nominal rig from Python: the same session as `ehactl diagnose`."""
    mcap, _out, d, calls = delay_diagnosis
    rig = ehactl.Config.load(CONFIGS / "diagnose_testrig.toml")
    assert d.cause == "time_delay"
    # Progress came through the callback (the library draws nothing): fits counted up to a
    # total that covers the nominal refit and at least one fit per catalogue candidate.
    assert calls, "no progress reported"
    done = [n for n, _ in calls]
    assert done == sorted(done) and calls[-1][0] == calls[-1][1]
    assert calls[-1][1] >= 1 + len(d.candidates)
    assert abs(d.extended_params["effects.time_delay.delay"] - 0.005) < 0.001
    assert d.gain >= 0.5 and len(d.candidates) == 12
    assert d.extended_config is not None and os.path.exists(d.extended_config)
    assert d.report is not None and os.path.exists(d.report)
    assert d.sensor_offsets == {}  # the zeros are trusted by default
    # Estimating a zero offset per channel: the same answer here (the run has no zero
    # errors), and offsets far below each signal.
    t = ehactl.diagnose(rig, mcap, sensor_offsets=True)
    assert t.cause == "time_delay"
    assert set(t.sensor_offsets) == set(t.nrmse_nominal.channels)
    assert abs(t.sensor_offsets["x"]) < 1e-4 and abs(t.sensor_offsets["p_a"]) < 1e5
    with pytest.raises(ValueError, match="t"):
        bad = tmp_path / "bad.csv"
        bad.write_text("time,u\n0,0\n")
        ehactl.diagnose(rig, bad)
