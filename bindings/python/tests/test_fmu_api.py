"""``ehactl.export_fmu``: the same FMU file as ``ehactl export-fmu`` writes, byte for byte
(one Rust export, crates/fmu), from a path or a Config; clear errors for a missing library,
a refused config and a wrong file name."""

import os
import pathlib
import subprocess
import zipfile
from xml.etree import ElementTree

import pytest

import ehactl

REPO = pathlib.Path(__file__).resolve().parents[3]
CONFIG = REPO / "configs" / "sahu2022_force.toml"
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
LIB = pathlib.Path(BIN).parent / "libehactl_fmu.so"

needs_lib = pytest.mark.skipif(not LIB.is_file(), reason=f"{LIB} not built (cargo build --release -p ehactl-fmu)")


@needs_lib
def test_the_python_export_is_the_cli_export(tmp_path):
    for extra in ([], ["--closed-loop"]):
        cli = tmp_path / "cli.fmu"
        r = subprocess.run([BIN, "export-fmu", str(CONFIG), "--out", str(cli), *extra],
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        py = ehactl.export_fmu(CONFIG, tmp_path / "py.fmu", closed_loop=bool(extra), binary=LIB)
        assert py.read_bytes() == cli.read_bytes()


@needs_lib
def test_a_config_object_with_a_changed_value_is_what_the_fmu_carries(tmp_path):
    cfg = ehactl.Config.load(CONFIG)
    cfg["mechanics.mass"] = 3.5
    fmu = ehactl.export_fmu(cfg, tmp_path / "m.fmu", binary=LIB)
    with zipfile.ZipFile(fmu) as z:
        inside = ehactl.Config.from_toml(z.read("resources/config.toml").decode())
        md = ElementTree.fromstring(z.read("modelDescription.xml"))
    assert inside["mechanics.mass"] == 3.5
    mass = md.find(".//ScalarVariable[@name='mechanics.mass']/Real")
    assert (mass.get("start"), mass.get("unit")) == ("3.5", "kg")


def test_errors_name_the_problem(tmp_path):
    with pytest.raises(FileNotFoundError, match="libehactl_fmu.so was not found"):
        ehactl.export_fmu(CONFIG, tmp_path / "a.fmu", binary=tmp_path / "missing.so")
    with pytest.raises(ValueError, match="ending in .fmu"):
        ehactl.export_fmu(CONFIG, tmp_path / "a.zip", binary=tmp_path / "missing.so")
    if LIB.is_file():
        bad = tmp_path / "bad.toml"
        bad.write_text(CONFIG.read_text().replace("control_rate_hz = 5000.0", "control_rate_hz = -1.0"))
        with pytest.raises(ValueError, match="control_rate_hz"):
            ehactl.export_fmu(bad, tmp_path / "b.fmu", binary=LIB)
    assert not list(tmp_path.glob("*.fmu"))
