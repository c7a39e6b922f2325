"""ehactl.Config: dict-like access by dotted path, validation through the Rust loader."""

from __future__ import annotations

import json
import os
import pickle
import subprocess

import pytest

import ehactl


def test_get_matches_the_file(force_cfg):
    assert force_cfg["control.pi.kp"] == 0.57
    assert force_cfg["control.pi.integral"] == 386.24
    assert force_cfg["mechanics.load_stiffness"] == 4.83e8
    assert force_cfg["control.mode"] == "force"
    assert force_cfg["effects.sensor_tone.frequencies"] == [225.0, 420.0]
    sec = force_cfg["control.pi"]
    assert isinstance(sec, dict) and sec["error_scale"] == 0.5097e-3
    assert force_cfg.name == "sahu2022_force" and force_cfg.mode == "force"
    assert force_cfg.control_dt == pytest.approx(2e-4)


def test_set_validates_and_names_field_and_unit(force_cfg):
    force_cfg["valve.rated_flow"] = 2.0e-2
    assert force_cfg["valve.rated_flow"] == 2.0e-2
    with pytest.raises(ValueError) as e:
        force_cfg["valve.rated_flow"] = -1.0
    msg = str(e.value)
    assert "valve.rated_flow" in msg and "m³/s" in msg
    assert force_cfg["valve.rated_flow"] == 2.0e-2  # unchanged after a rejected set
    with pytest.raises(ValueError, match=r"control\.pi\.kp.*V/V"):
        force_cfg["control.pi.kp"] = "fast"
    with pytest.raises(ValueError, match=r"run\.control_rate_hz.*Hz"):
        force_cfg["run.control_rate_hz"] = 0.0
    with pytest.raises(ValueError, match=r"control\.pi\.nonsense"):
        force_cfg["control.pi.nonsense"] = 1.0
    # cross-field rule of the Rust loader
    with pytest.raises(ValueError, match=r"u_min.*V"):
        force_cfg["control.pi.u_min"] = 20.0


def test_int_for_float_and_new_optional_section(boom_cfg):
    boom_cfg["run.control_rate_hz"] = 2000  # int accepted for a float field
    assert boom_cfg["run.control_rate_hz"] == 2000.0
    assert boom_cfg.control_dt == pytest.approx(5e-4)
    assert "effects.internal_leakage" not in boom_cfg
    boom_cfg["effects.internal_leakage.coefficient"] = 1e-12
    assert boom_cfg["effects.internal_leakage.coefficient"] == 1e-12
    del boom_cfg["effects.internal_leakage"]
    assert "effects.internal_leakage" not in boom_cfg
    with pytest.raises(KeyError):
        boom_cfg["effects.internal_leakage.coefficient"]
    with pytest.raises(KeyError):
        del boom_cfg["no.such.field"]


def test_with_values_copies_and_update_is_atomic(force_cfg):
    c2 = force_cfg.with_values({"control.pi.kp": 0.4, "control.pi.integral": 100})
    assert c2["control.pi.kp"] == 0.4 and force_cfg["control.pi.kp"] == 0.57
    with pytest.raises(ValueError):
        force_cfg.update({"control.pi.kp": 0.3, "fluid.density": -5.0})
    assert force_cfg["control.pi.kp"] == 0.57  # first edit not applied either


def test_save_load_roundtrip_and_pickle(force_cfg, tmp_path):
    force_cfg["control.pi.kp"] = 0.33
    p = tmp_path / "c.toml"
    force_cfg.save(p)
    back = ehactl.Config.load(p)
    assert back == force_cfg
    assert back["control.pi.kp"] == 0.33
    assert pickle.loads(pickle.dumps(force_cfg)) == force_cfg
    assert ehactl.Config.from_toml(force_cfg.to_toml()) == force_cfg
    assert ehactl.Config.from_dict(force_cfg.to_dict()) == force_cfg


def test_load_errors():
    with pytest.raises(FileNotFoundError, match="config file not found"):
        ehactl.Config.load("/nonexistent/x.toml")
    with pytest.raises(ValueError, match="TOML syntax error"):
        ehactl.Config.from_toml("[fluid\n")


def test_params_registry_has_units():
    ps = {p["path"]: p for p in ehactl.params()}
    assert ps["control.pi.kp"]["unit"] == "V/V"
    assert ps["fluid.bulk_modulus"]["unit"] == "Pa"
    assert ehactl.Config.unit("control.pd.td") == "s"
    assert len(ps) > 50


@pytest.mark.skipif(not os.environ.get("EHACTL_BIN"), reason="EHACTL_BIN (the CLI binary) not set")
def test_python_config_runs_identically_in_the_cli(force_cfg, tmp_path):
    """A config edited in Python, saved, and run by the CLI gives the run ehactl.run gives."""
    force_cfg["control.pi.kp"] = 0.45
    p = tmp_path / "tuned.toml"
    force_cfg.save(p)
    cli = subprocess.run(
        [os.environ["EHACTL_BIN"], "run", str(p), "--duration", "0.2", "--out", str(tmp_path / "r.mcap"), "--json"],
        capture_output=True, text=True, check=True,
    )
    js = json.loads(cli.stdout)
    res = ehactl.run(force_cfg, duration=0.2)
    assert js["cycles"] == len(res)
    assert js["rms_error"] == pytest.approx(res.summary.rms_error, rel=1e-12)
    assert js["max_abs_error"] == pytest.approx(res.summary.max_abs_error, rel=1e-12)


def test_version_matches_the_rust_crates():
    tomllib = pytest.importorskip("tomllib")  # Python ≥ 3.11
    from conftest import REPO

    ws = tomllib.loads((REPO / "Cargo.toml").read_text())
    assert ehactl.__version__ == ws["workspace"]["package"]["version"]
