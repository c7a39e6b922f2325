"""The CLI answers bad input with exit code 2 and one message naming the field and unit."""
import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
BASE = (REPO / "configs" / "sahu2022_force.toml").read_text()


def run(*args, cwd=None):
    return subprocess.run([BIN, *args], capture_output=True, text=True, cwd=cwd, timeout=60)


@pytest.mark.parametrize(
    "old,new,expect",
    [
        ("mass = 0.893", "", ["mechanics.mass", "kg", "missing"]),
        ("mass = 0.893", 'mass = "x"', ["mechanics.mass", "kg", "wrong type"]),
        ("mass = 0.893", "mass = -0.893", ["mechanics.mass", "kg"]),
        ("mass = 0.893", "mass = nan", ["mechanics.mass", "not finite"]),
        # An upper bound on physical quantities (1000 t), and a huge value written as one.
        ("mass = 0.893", "mass = 1e300", ["mechanics.mass", "value 1e300 is out of range", "≤ 1000000 in kg"]),
        ("mass = 0.893", "mass = 1.7e308", ["mechanics.mass", "value 1.7e308 is out"]),
        ("pressure = 20.0e6", "pressure = 5e9", ["supply.pressure", "value 5e9 is out", "≤ 1e9 in Pa"]),
        ("[effects.sensor_tone]", "[effects.sensor_tones]", ["effects.sensor_tones", "unknown effect id"]),
    ],
)
def test_bad_config_exits_2_with_one_message(tmp_path, old, new, expect):
    assert old in BASE
    cfg = tmp_path / "bad.toml"
    cfg.write_text(BASE.replace(old, new, 1))
    for cmd in (["check-config", str(cfg)], ["run", str(cfg), "--json", "--out", str(tmp_path / "x.mcap")]):
        r = run(*cmd)
        assert r.returncode == 2, r
        assert r.stdout == ""
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1, r.stderr
        for word in expect:
            assert word in lines[0], lines[0]
        assert "panicked" not in r.stderr and "backtrace" not in r.stderr.lower()
        assert not (tmp_path / "x.mcap").exists()


def test_bad_arguments_exit_2(tmp_path):
    r = run("run", str(REPO / "configs" / "sahu2022_force.toml"), "--duration", "-1")
    assert r.returncode == 2 and "--duration" in r.stderr and " s" in r.stderr
    r = run("run", str(tmp_path / "missing.toml"))
    assert r.returncode == 2 and "cannot read config file" in r.stderr
    r = run("run", str(REPO / "configs" / "sahu2022_force.toml"), "--duration", "abc")
    assert r.returncode == 2


def test_json_is_exactly_one_object(tmp_path):
    import json

    r = run("run", str(REPO / "configs" / "dindorf2022_boom.toml"), "--duration", "0.2", "--json", "--out", str(tmp_path / "b.mcap"))
    assert r.returncode == 0, r.stderr
    obj = json.loads(r.stdout)
    for key in ("cycles", "control_rate_hz", "duration_s", "rms_error", "max_abs_error", "mcap", "trip", "sim_speed_x_realtime"):
        assert key in obj
    assert obj["cycles"] == 1000 and obj["trip"] is None
    assert pathlib.Path(obj["mcap"]).exists()


def test_json_reports_a_start_up_io_failure(tmp_path):
    """`run --json` promises one object on stdout for an I/O failure too (docs/usage.md:
    `error` and `exit_code`, exit 1): an unwritable `--out` and a `--live` port in use used to
    print nothing on stdout."""
    import json
    import socket

    cfg = str(REPO / "configs" / "sahu2022_force.toml")
    r = run("run", cfg, "--duration", "0.1", "--json", "--out", "/proc/nope/x.mcap")
    assert r.returncode == 1, r
    obj = json.loads(r.stdout)
    assert obj["exit_code"] == 1 and obj["error_kind"] == "out" and "/proc/nope/x.mcap" in obj["error"]
    assert obj["error"] in r.stderr
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        addr = f"127.0.0.1:{busy.getsockname()[1]}"
        r = run("run", cfg, "--duration", "0.1", "--json", "--out", str(tmp_path / "l.mcap"), "--live", addr)
    assert r.returncode == 1, r
    obj = json.loads(r.stdout)
    assert obj["exit_code"] == 1 and obj["error_kind"] == "live" and addr in obj["error"]
    assert not (tmp_path / "l.mcap").exists()
