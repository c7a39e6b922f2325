"""`ehactl analyze` and `ehactl sweep` from the command line: JSON contract, MCAP log of the
sweep read back with the official `mcap` reader, and clear errors for bad arguments."""
import json
import os
import pathlib
import subprocess

import numpy as np

from ehactl_mcap import read_run

ROOT = pathlib.Path(__file__).resolve().parents[2]
EHACTL = os.environ.get("EHACTL_BIN", str(ROOT / "target" / "release" / "ehactl"))
SAHU = str(ROOT / "configs" / "sahu2022_force.toml")
BOOM = str(ROOT / "configs" / "dindorf2022_boom.toml")


def run(*args):
    return subprocess.run([EHACTL, *args], capture_output=True, text=True, timeout=300)


def test_analyze_json_has_the_issue_keys_and_says_the_loop_is_sampled():
    p = run("analyze", SAHU, "--json")
    assert p.returncode == 0, p.stderr
    lines = [ln for ln in p.stdout.splitlines() if ln.strip()]
    assert len(lines) == 1, "exactly one JSON object"
    a = json.loads(lines[0])
    for k in ("hydraulic_natural_frequency_hz", "min_natural_frequency_over_stroke_hz",
              "open_loop_bandwidth_hz", "gain_crossover_hz", "phase_margin_deg",
              "phase_crossover_hz", "gain_margin_db", "closed_loop_bandwidth_hz"):
        assert isinstance(a[k], float), k
    assert a["sampled_loop"] is True and "zero-order hold" in a["loop_model"]
    assert a["continuous"]["phase_margin_deg"] > a["phase_margin_deg"]
    assert "fr_ym" not in a  # no spring-damper on this rig
    b = json.loads(run("analyze", BOOM, "--json").stdout)
    assert {"fr_ym", "fr_em", "rd_my"} <= set(b)


def test_sweep_json_points_and_log(tmp_path):
    out = tmp_path / "sweep.mcap"
    p = run("sweep", SAHU, "--from", "5", "--to", "300", "--points", "8", "--json", "--out", str(out),
            "--log-every", "1")
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    assert r["mode"] == "closed_loop" and len(r["points"]) == 8
    f = [q["f_hz"] for q in r["points"]]
    assert abs(f[0] - 5) < 1e-9 and abs(f[-1] - 300) < 1e-9 and np.all(np.diff(f) > 0)
    for q in r["points"]:
        assert set(q) >= {"f_hz", "mag_db", "phase_deg", "coherence"}
        assert 0.0 <= q["coherence"] <= 1.0 + 1e-12
    assert 170 <= r["bandwidth_hz"] <= 240
    # The sweep is an ordinary logged run: with --log-every 1 every cycle is in the MCAP
    # (by default one in 5, see test_newcomer.py), setpoint = the stepped sine.
    run_log = read_run(out)
    c = run_log["control"]
    assert len(c["t"]) == round(r["duration_s"] * 5000)
    assert abs(np.mean(c["setpoint"][c["t"] > 0.2]) - 785.0) < 5.0
    assert abs(np.max(c["setpoint"]) - (785.0 + 196.0)) < 1.0


def test_sweep_bad_arguments_are_named():
    for args, needle in ((["--to", "4000"], "--to"), (["--points", "1"], "--points"),
                         (["--from", "-3"], "--from"), (["--output", "torque"], "--output"),
                         (["--amplitude", "0"], "--amplitude")):
        p = run("sweep", SAHU, *args)
        assert p.returncode == 2, (args, p.stderr)
        assert needle in p.stderr and "Traceback" not in p.stderr and "panicked" not in p.stderr
        assert len(p.stderr.strip().splitlines()) == 1, p.stderr
