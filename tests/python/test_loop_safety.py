"""Loop safety from the command line: an unstable loop is told apart by `ehactl analyze`,
warned about by `ehactl run` and stopped by the supervisor's following-error watch (exit 3),
while every shipped config runs its documented duration without a false trip."""
import json
import os
import pathlib
import re
import subprocess
import tomllib

import pytest

from ehactl_mcap import read_run

ROOT = pathlib.Path(__file__).resolve().parents[2]
EHACTL = os.environ.get("EHACTL_BIN", str(ROOT / "target" / "release" / "ehactl"))
SAHU = ROOT / "configs" / "sahu2022_force.toml"
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))


def run(*args):
    return subprocess.run([EHACTL, *map(str, args)], capture_output=True, text=True, timeout=600)


def sahu_with_kp(tmp_path, kp):
    """Sahu 2022's config with K_P = `kp` (V/V) in `[control.pi]`."""
    text = SAHU.read_text()
    changed, n = re.subn(r"(?m)^kp = 0\.57 ", f"kp = {kp} ", text)
    assert n == 1, "the K_P line of the shipped config"
    path = tmp_path / f"sahu_kp{kp}.toml"
    path.write_text(changed)
    return path


@pytest.mark.parametrize("config", CONFIGS, ids=[c.stem for c in CONFIGS])
def test_every_shipped_config_runs_its_duration_without_a_trip(config, tmp_path):
    """The supervision that is on by default (following error, saturation watch) must not
    trip a healthy loop: each shipped config runs its whole `run.duration`, exit 0."""
    duration = tomllib.loads(config.read_text())["run"]["duration"]
    p = run("run", config, "--out", tmp_path / "run.mcap", "--json")
    assert p.returncode == 0, p.stdout + p.stderr
    s = json.loads(p.stdout)
    assert s["trip"] is None and s["trip_kind"] is None, s["trip"]
    assert s["duration_s"] == pytest.approx(duration, abs=1.5 / s["control_rate_hz"])
    assert "unstable" not in p.stderr.lower(), p.stderr


def test_closed_loop_configs_set_their_following_error():
    """Every shipped closed loop states its following-error bound and time and its
    saturation watch (with units in the comments), rather than relying on the defaults."""
    closed = 0
    for config in CONFIGS:
        cfg = tomllib.loads(config.read_text())
        if cfg["control"]["mode"] == "open_loop":
            continue
        closed += 1
        sup = cfg.get("supervisor", {})
        for key in ("following_error", "following_error_time", "saturation_window"):
            assert key in sup, f"{config.name}: supervisor.{key}"
    assert closed >= 5


def test_an_unstable_force_loop_trips_on_its_following_error(tmp_path):
    """K_P = 50 (instead of 0.57) on Sahu 2022's PI force loop: the loop limit-cycles
    bang-bang (±10 V). The run must trip within 0.5 s of simulated time with a
    following_error event naming the force, exit 3, and warn at start."""
    cfg = sahu_with_kp(tmp_path, 50)
    out = tmp_path / "kp50.mcap"
    p = run("run", cfg, "--out", out, "--json")
    assert p.returncode == 3, p.stdout + p.stderr
    s = json.loads(p.stdout)
    assert s["trip_kind"] == "following_error", s["trip"]
    assert s["duration_s"] <= 0.5
    assert "on force" in s["trip"] and "limit 600 N" in s["trip"], s["trip"]
    assert "unstable" in p.stderr.lower(), p.stderr
    events = read_run(out)["events"]
    kinds = [e["kind"] for e in events]
    assert kinds[:2] == ["start", "unstable_loop"], kinds
    warn = events[1]
    assert warn["severity"] == "warning" and warn["value"] > 1.0 and warn["limit"] == 1.0
    trip = next(e for e in events if e["kind"] == "following_error")
    assert trip["severity"] == "trip" and trip["unit"] == "N" and abs(trip["value"]) > 600


def test_without_the_section_the_derived_bound_still_trips(tmp_path):
    """A config that does not set the following error gets one derived from its setpoint
    (twice the largest |setpoint|: 2 × (785 + 196) N) and the unstable loop still trips."""
    cfg = sahu_with_kp(tmp_path, 50)
    text = re.sub(r"(?m)^(following_error|following_error_time|saturation_window) = .*\n", "",
                  cfg.read_text())
    cfg.write_text(text)
    p = run("run", cfg, "--out", tmp_path / "kp50.mcap", "--json")
    assert p.returncode == 3, p.stdout + p.stderr
    s = json.loads(p.stdout)
    assert s["trip_kind"] == "following_error" and "limit 1962 N" in s["trip"], s["trip"]


def test_analyze_gives_a_stability_verdict(tmp_path):
    """`ehactl analyze` says stable / unstable from the closed-loop poles, and leaves the
    closed-loop bandwidth out of an unstable loop (text and JSON)."""
    a = json.loads(run("analyze", SAHU, "--json").stdout)
    assert a["stable"] is True and a["unstable_poles"] == []
    assert 0 < a["max_closed_loop_pole_magnitude"] < 1
    assert isinstance(a["closed_loop_bandwidth_hz"], float)
    cfg = sahu_with_kp(tmp_path, 50)
    p = run("analyze", cfg, "--json")
    assert p.returncode == 0, p.stderr
    u = json.loads(p.stdout)
    assert u["stable"] is False and u["max_closed_loop_pole_magnitude"] > 1
    assert u["unstable_poles"] and all(q["magnitude"] >= 1 for q in u["unstable_poles"])
    assert "closed_loop_bandwidth_hz" not in u and u["closed_loop_peak_db"] is None
    assert u["continuous"]["closed_loop_bandwidth_hz"] is None
    assert "unstable" in u["closed_loop_bandwidth_note"]
    text = run("analyze", cfg).stdout
    assert "UNSTABLE" in text and "bandwidth meaningless" in text, text
    assert "closed-loop bandwidth 8" not in text
    assert "stable (" in run("analyze", SAHU).stdout


def test_a_runaway_plant_is_a_simulation_fault(tmp_path):
    """A damper law no passive damper has (the README campaign's law held a negative
    stiffness and quadratic damping before its fit was sign-constrained; here a negative
    viscous damping of −2e6 N·s/m in the MTS config) run closed loop used to drive the plant to
    1e11 Pa, 1.4e13 N and 1e7 m/s with exit 0. The plant must refuse such a state: a
    `plant_implausible` trip naming the state, its value, its bound and unit, exit 3 — with
    the following-error watch out of the way, so that the plant check alone is seen."""
    text = (ROOT / "configs" / "utfsm_mts_mrdamper.toml").read_text()
    text, n = re.subn(r"(?m)^viscous = 2900\.0", "viscous = -2.0e6", text)
    assert n == 1, "the shipped damper law"
    text, n = re.subn(r"(?m)^following_error = .*$", "following_error = 1e9", text)
    assert n == 1, "the shipped supervisor section"
    cfg = tmp_path / "runaway.toml"
    cfg.write_text(text)
    mcap = tmp_path / "ext.mcap"
    p = run("run", cfg, "--out", mcap, "--json")
    assert p.returncode == 3, p.stdout + p.stderr
    s = json.loads(p.stdout)
    assert s["trip_kind"] == "plant_implausible", s["trip"]
    trip = next(e for e in read_run(mcap)["events"] if e["kind"] == "plant_implausible")
    units = {"p_a": "Pa", "p_b": "Pa", "p_s": "Pa", "v": "m/s", "rod_force": "N"}
    assert trip["channel"] in units and trip["unit"] == units[trip["channel"]], trip
    assert abs(trip["value"]) > abs(trip["limit"]) > 0, trip
    # Far from the probe's figures: stopped before the state ran off by orders of magnitude.
    assert abs(trip["value"]) < 1e3 * abs(trip["limit"]), trip
