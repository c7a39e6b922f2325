"""Self-consistency of `ehactl diagnose`: a log written by `ehactl run` from a shipped config,
diagnosed against that same config, must be answered `none` — from the MCAP log and from its
CSV export. The CSV is written here from the MCAP with the official `mcap` reader (not with
ehactl's own loader), so the two inputs take independent paths into the diagnosis.

The configs hold disturbances the log does not record as such (sensor noise, tones, random
impacts, chirps): the replay reproduces the declared ones from the config and the noise is the
noise floor, so none of them may be reported as a discrepancy."""
import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

from ehactl_mcap import read_run

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
CONFIGS = sorted((REPO / "configs").glob("*.toml"))

# CSV column ← /control field (SI); a column whose sensor the backend lacks (NaN) is left out.
COLUMNS = [
    ("t", "t"),
    ("u", "command"),
    ("force", "force"),
    ("x", "position"),
    ("p_a", "p_a"),
    ("p_b", "p_b"),
    ("x_v", "spool"),
    ("ref", "setpoint"),
]


def run(*args, timeout=1800):
    return subprocess.run([BIN, *args], capture_output=True, text=True, timeout=timeout)


def export_csv(mcap: pathlib.Path, csv: pathlib.Path) -> None:
    c = read_run(mcap)["control"]
    cols = [(name, field) for name, field in COLUMNS if np.all(np.isfinite(c[field]))]
    data = np.column_stack([c[field] for _, field in cols])
    # 17 significant digits: the CSV carries the same doubles as the MCAP.
    np.savetxt(csv, data, delimiter=",", header=",".join(n for n, _ in cols), comments="", fmt="%.17g")


def test_every_shipped_config_is_found():
    assert len(CONFIGS) >= 10, CONFIGS


@pytest.mark.parametrize("config", CONFIGS, ids=[c.stem for c in CONFIGS])
def test_own_log_is_answered_none(config, tmp_path):
    mcap = tmp_path / f"{config.stem}.mcap"
    r = run("run", str(config), "--duration", "1", "--out", str(mcap), "--json")
    assert r.returncode == 0, r.stderr
    csv = tmp_path / f"{config.stem}.csv"
    export_csv(mcap, csv)
    for data in (mcap, csv):
        r = run("diagnose", "--config", str(config), "--data", str(data), "--json")
        assert r.returncode == 0, r.stderr
        d = json.loads(r.stdout)
        assert d["cause"] == "none", f"{data.name}: {d['summary']}"
        assert d["causes"] == [], d["causes"]
        # The replay reproduced the run at the config's own step (not a finer one that would
        # differ from it by the run's integration error), or the finer one was within noise.
        ig = d["integration"]
        assert ig["configured_step_explains"] or ig["met"], ig
