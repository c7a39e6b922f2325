"""ehactl.Plant: the bare plant stepped from Python must be the plant the loop runs."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import ehactl


def test_initial_state_is_force_balance(force_cfg):
    p = ehactl.Plant(force_cfg)
    s = p.state()
    assert p.t == 0.0
    assert p.control_dt == pytest.approx(1.0 / 5000.0)
    # 003 eq. 14 with a symmetric cylinder and no load: both chambers at p_s / 2.
    assert s["p_a"] == pytest.approx(10.0e6, rel=1e-12)
    assert s["p_b"] == pytest.approx(10.0e6, rel=1e-12)
    assert s["x"] == 0.0 and s["v"] == 0.0
    m = p.measure()
    assert set(m) == {"t", "force", "position", "p_a", "p_b", "spool"}


def test_step_advances_n_periods_and_matches_the_closed_loop_records(force_cfg):
    """Open loop with a constant 1 V command: Plant.step must reproduce the ground truth
    and the sensor readings logged by ehactl.run (same plant, same noise sequence)."""
    cfg = force_cfg.with_values(
        {
            "control.mode": "open_loop",
            "setpoint.kind": "step",
            "setpoint.initial": 1.0,
            "setpoint.final": 1.0,
            "setpoint.start": 0.0,
        }
    )
    n = 300
    res = ehactl.run(cfg, duration=n * cfg.control_dt)
    assert len(res) == n and np.all(res.u == 1.0)
    p = ehactl.Plant(cfg)
    for k in (0, 1, 7, 50, 299):
        while round(p.t / p.control_dt) < k:
            p.measure()  # the loop samples the sensors once per cycle
            p.step(1.0)
        s = p.state()
        assert s["t"] == pytest.approx(res.t[k], abs=1e-12)
        assert s["x"] == res.x[k]
        assert s["rod_force"] == res.rod_force[k]
        assert s["p_a"] == res.plant_p_a[k]
    # measurement sequence identical too (noise generator seeded from the config)
    p.reset()
    forces = []
    for _ in range(n):
        forces.append(p.measure()["force"])
        p.step(1.0)
    np.testing.assert_array_equal(np.array(forces), res.force)


def test_step_n_equals_n_single_steps(force_cfg):
    a = ehactl.Plant(force_cfg)
    b = ehactl.Plant(force_cfg)
    a.step(0.5, n=250)
    for _ in range(250):
        b.step(0.5)
    assert a.t == pytest.approx(250 * a.control_dt, rel=1e-12)
    assert a.state() == b.state()


def test_noise_free_measure_equals_truth(force_cfg):
    cfg = force_cfg.copy()
    cfg["sensors.force.noise"] = 0.0
    del cfg["effects.sensor_tone"]
    p = ehactl.Plant(cfg)
    p.step(2.0, n=100)
    assert p.measure()["force"] == pytest.approx(p.state()["rod_force"], rel=1e-12)
    # positive command opens P→A: chamber A pressure rises, the rod pushes on the load cell
    assert p.state()["p_a"] > p.state()["p_b"]
    assert p.state()["rod_force"] > 100.0


def test_run_commands_matches_step(force_cfg):
    u = np.linspace(-1.0, 1.0, 200)
    p = ehactl.Plant(force_cfg)
    out = p.run_commands(u)
    q = ehactl.Plant(force_cfg)
    f = []
    for uk in u:
        f.append(q.measure()["force"])
        q.step(float(uk))
    np.testing.assert_array_equal(out["force"], np.array(f))
    assert p.state() == q.state()


def test_bad_command_and_period_are_rejected(force_cfg):
    p = ehactl.Plant(force_cfg)
    with pytest.raises(ValueError, match="valve command .* V"):
        p.step(float("nan"))
    with pytest.raises(ValueError, match="control_dt .* s"):
        ehactl.Plant(force_cfg, control_dt=-1.0)
    assert p.t == 0.0


def test_step_releases_the_gil(force_cfg):
    """Another Python thread must run while Rust integrates a long step."""
    p = ehactl.Plant(force_cfg)
    n = 1
    t0 = time.perf_counter()
    p.step(0.1, n=2000)
    per_step = (time.perf_counter() - t0) / 2000
    n = int(0.3 / max(per_step, 1e-7))  # ≈ 0.3 s of work
    stamps: list[float] = []
    done = threading.Event()

    def spin():
        while not done.is_set():
            stamps.append(time.perf_counter())

    th = threading.Thread(target=spin)
    th.start()
    time.sleep(0.02)
    a = time.perf_counter()
    p.step(0.1, n=n)
    b = time.perf_counter()
    done.set()
    th.join()
    assert b - a > 0.1
    inside = [s for s in stamps if a + 0.03 < s < b - 0.03]
    assert len(inside) > 100, "the other thread did not run: GIL held during step"


def test_step_count_is_bounded(force_cfg):
    """A mistyped n (1e12 periods: days of CPU) is refused with the bound, nothing stepped."""
    p = ehactl.Plant(force_cfg)
    with pytest.raises(ValueError, match=r"above the bound of 1e9"):
        p.step(1.0, n=10**12)
    assert p.t == 0.0


def test_a_long_step_honours_ctrl_c(force_cfg):
    """Ctrl-C (SIGINT, here `_thread.interrupt_main`) during a long step raises
    KeyboardInterrupt within a check interval, with the plant advanced by the periods done."""
    import _thread

    p = ehactl.Plant(force_cfg)
    timer = threading.Timer(0.2, _thread.interrupt_main)
    t0 = time.perf_counter()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        p.step(0.1, n=10**9)  # about 20 min of CPU without the interrupt
    timer.join()
    assert time.perf_counter() - t0 < 10.0
    assert 0.0 < p.t < 10**9 * p.control_dt
