"""ehactl.run / run_many: the compiled loop, columns, batches, GIL release, errors."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import ehactl
from conftest import CONFIGS


def test_run_columns(force_cfg):
    r = ehactl.run(force_cfg, duration=0.1)
    n = 500
    assert len(r) == n and r.ok and r.trip is None
    np.testing.assert_allclose(np.diff(r.t), 2e-4, rtol=1e-9)
    for name in ("t", "force", "x", "u", "setpoint", "error", "p_a", "plant_p_a", "rod_force", "stuck", "cycle"):
        assert len(r[name]) == n
    np.testing.assert_array_equal(r.command, r.u)
    # error column is setpoint − measured feedback (the force sensor)
    np.testing.assert_allclose(r.error, r.setpoint - r.force, atol=1e-9)
    assert r.unit == "N" and r.units["p_a"] == "Pa" and r.units["x"] == "m"
    assert r.summary.cycles == n
    # PI terms add up to the unsaturated command (004: u = K_P·g·e + integral)
    np.testing.assert_allclose(r.p_term + r.i_term + r.ff_term, r.command_unsat, rtol=1e-12, atol=1e-12)


def test_setpoint_argument(force_cfg):
    r = ehactl.run(force_cfg, duration=0.05, setpoint=500.0)
    assert np.all(r.setpoint == 500.0)
    r2 = ehactl.run(force_cfg, duration=0.05, setpoint={"kind": "sine", "offset": 300.0, "amplitude": 50.0, "f0": 100.0})
    t = r2.t
    np.testing.assert_allclose(r2.setpoint, 300 + 50 * np.sin(2 * np.pi * 100 * t), atol=1e-9)
    with pytest.raises(ValueError, match="setpoint.f0"):
        ehactl.run(force_cfg, duration=0.05, setpoint={"kind": "sine", "f0": 0.0})


def test_to_pandas(force_cfg):
    pd = pytest.importorskip("pandas")
    df = ehactl.run(force_cfg, duration=0.02).to_pandas()
    assert isinstance(df, pd.DataFrame) and len(df) == 100
    assert {"force", "x", "u"} <= set(df.columns)


def test_bad_arguments(force_cfg):
    with pytest.raises(ValueError, match="duration .* s"):
        ehactl.run(force_cfg, duration=-1.0)
    with pytest.raises(ValueError, match="unknown result field `bogus`"):
        ehactl.run(force_cfg, duration=0.01, fields=["t", "bogus"])
    with pytest.raises(TypeError):
        ehactl.run(42)


def test_trip_is_reported(force_cfg):
    r = ehactl.run(force_cfg, duration=0.2, setpoint=3000.0, params={"supervisor.max_force": 1000.0})
    assert not r.ok
    assert "force_limit" in r.trip
    assert len(r) < 1000


def test_run_many_equals_single_runs_in_order(force_cfg):
    kps = [0.2, 0.4, 0.57, 0.8]
    many = ehactl.run_many({"control.pi.kp": kps}, base=force_cfg, duration=0.05)
    assert [m.config["control.pi.kp"] for m in many] == kps
    for kp, m in zip(kps, many):
        one = ehactl.run(force_cfg.with_values({"control.pi.kp": kp}), duration=0.05)
        np.testing.assert_array_equal(m.force, one.force)
        np.testing.assert_array_equal(m.x, one.x)
    # different gains give different runs
    assert not np.array_equal(many[0].u, many[3].u)


def test_param_grid_is_a_cartesian_product(force_cfg):
    g = ehactl.param_grid(force_cfg, {"control.pi.kp": [0.1, 0.2, 0.3], "control.pi.integral": [100.0, 200.0]})
    assert len(g) == 6
    assert {(c["control.pi.kp"], c["control.pi.integral"]) for c in g} == {
        (a, b) for a in (0.1, 0.2, 0.3) for b in (100.0, 200.0)
    }
    with pytest.raises(ValueError, match="control.pi.kp"):
        ehactl.param_grid(force_cfg, {"control.pi.kp": [0.1, -1.0]})


def test_an_empty_grid_runs_the_base_once_an_empty_axis_is_an_error(force_cfg):
    """`{}` varies nothing: the base alone, as `run_many([base])`; a path with no values is a
    ValueError naming it (it used to make the product silently empty: `[]`)."""
    assert len(ehactl.param_grid(force_cfg, {})) == 1
    (one,) = ehactl.run_many({}, base=force_cfg, duration=0.02)
    (ref,) = ehactl.run_many([force_cfg], duration=0.02)
    assert one.summary.rms_error == ref.summary.rms_error
    for grid in ({"control.pi.kp": []}, {"control.pi.kp": [0.3], "control.pi.integral": iter(())}):
        with pytest.raises(ValueError, match=r"'control.pi.(kp|integral)' has no values"):
            ehactl.run_many(grid, base=force_cfg, duration=0.02)
    # One-shot iterators as values: consumed once, rows and runs agree.
    df = ehactl.run_many({"control.pi.kp": iter([0.3, 0.4])}, base=force_cfg, duration=0.02, frame=True)
    assert list(df["control.pi.kp"]) == [0.3, 0.4]


def test_progress_callbacks(force_cfg):
    seen = []
    ehactl.run(force_cfg, duration=0.5, progress=lambda d, n: seen.append((d, n)))
    assert seen[-1] == (2500, 2500)
    seen2 = []
    ehactl.run_many([force_cfg] * 3, duration=0.05, progress=lambda d, n: seen2.append((d, n)))
    assert seen2[-1] == (3, 3)


def test_run_many_releases_the_gil(force_cfg):
    stamps: list[float] = []
    done = threading.Event()

    def spin():
        while not done.is_set():
            stamps.append(time.perf_counter())

    th = threading.Thread(target=spin)
    th.start()
    time.sleep(0.02)
    # The batch must last long enough to see the other thread run; the simulation's speed
    # changes with the integrator (the 2026-11-26 integration rework made the Sahu 2022 rig ~4x faster), so the batch is
    # doubled until it lasts at least 0.2 s instead of assuming a speed.
    n = 30
    while True:
        a = time.perf_counter()
        ehactl.run_many([force_cfg] * n, duration=1.0, fields=["t"])
        b = time.perf_counter()
        if b - a > 0.2 or n >= 30 * 2**6:
            break
        n *= 2
    done.set()
    th.join()
    assert b - a > 0.2, f"{n} runs of 1 s took only {b - a:.3f} s"
    inside = [s for s in stamps if a + 0.02 < s < b - 0.02]
    assert len(inside) > 100


def test_mcap_written_and_read_back(force_cfg, tmp_path):
    p = tmp_path / "run.mcap"
    r = ehactl.run(force_cfg, duration=0.05, mcap=p)
    log = ehactl.read_mcap(p)
    np.testing.assert_array_equal(log["control"]["force"], r.force)
    np.testing.assert_array_equal(log["control"]["command"], r.u)
    np.testing.assert_array_equal(log["plant"]["x"], r.x)
    np.testing.assert_array_equal(log["plant"]["stuck"], r.stuck)
    assert log["summary"]["cycles"] == len(r)
    kinds = [e["kind"] for e in log["events"]]
    assert log["config"] is not None and kinds[0] == "start"
    assert "end" in kinds and "signal" not in kinds
    ms = ehactl.run_many([force_cfg] * 2, duration=0.02, mcap_dir=tmp_path / "many")
    for i, m in enumerate(ms):
        lg = ehactl.read_mcap(tmp_path / "many" / f"run_{i:04d}.mcap")
        np.testing.assert_array_equal(lg["control"]["force"], m.force)


def test_ctrl_c_stops_the_run_and_finalises_the_log(force_cfg, tmp_path):
    import os
    import signal

    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        p = tmp_path / "interrupted.mcap"
        threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        t0 = time.perf_counter()
        with pytest.raises(KeyboardInterrupt):
            ehactl.run(force_cfg, duration=500.0, mcap=p)  # minutes of work if not stopped
        assert time.perf_counter() - t0 < 20.0
        log = ehactl.read_mcap(p)  # finalised: summary and footer written
        assert log["summary"]["interrupted"] is True
        assert "signal" in [e["kind"] for e in log["events"]]
        assert 0 < len(log["control"]["t"]) < 2_500_000
        threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        with pytest.raises(KeyboardInterrupt):
            ehactl.run_many([force_cfg] * 40, duration=50.0, fields=["t"])
    finally:
        signal.signal(signal.SIGINT, old)


def test_columns_are_in_dir_for_tab_completion(force_cfg):
    res = ehactl.run(force_cfg, duration=0.01, fields=["t", "force", "u", "setpoint"])
    names = dir(res)
    for col in ("t", "force", "u", "setpoint", "command"):  # command: alias of u
        assert col in names, col
    assert "x" not in names  # not requested, not offered
    assert "to_pandas" in names and "units" in names


def test_unit_and_units_agree_with_the_control_mode(force_cfg, boom_cfg):
    f = ehactl.run(force_cfg, duration=0.01)
    assert f.unit == f.units["error"] == f.units["setpoint"] == f.units["feedback"] == "N"
    assert f.units["setpoint_rate"] == "N/s" and f.units["force"] == "N" and f.units["p_a"] == "Pa"
    b = ehactl.run(boom_cfg, duration=0.01)
    assert b.unit == b.units["error"] == b.units["setpoint"] == "m"


def test_missing_files_raise_file_not_found(tmp_path):
    import errno

    for call in (
        lambda: ehactl.Config.load(tmp_path / "nope.toml"),
        lambda: ehactl.run(tmp_path / "nope.toml", duration=0.01),
        lambda: ehactl.read_mcap(tmp_path / "nope.mcap"),
        lambda: ehactl.diagnose(CONFIGS / "diagnose_testrig.toml", tmp_path / "nope.csv"),
    ):
        with pytest.raises(FileNotFoundError) as e:
            call()
        assert e.value.errno == errno.ENOENT and "nope" in str(e.value)


def test_progress_bars_stay_out_of_non_tty_logs(force_cfg, capfd):
    pytest.importorskip("tqdm")
    ehactl.run(force_cfg, duration=0.05, progress=True)
    ehactl.run_many([force_cfg] * 2, duration=0.02, progress=True)
    err = capfd.readouterr().err
    assert "it/s" not in err and "cycle" not in err and "%|" not in err, err
