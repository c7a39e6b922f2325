"""`ehactl export-fmu` checked with a real FMI client: FMPy (pip `fmpy`) validates every
exported FMU and simulates it through its own FMI 2.0 binding (`fmpy.fmi2.FMU2Slave`, ctypes
on the FMU's shared library), and the results are compared with `ehactl run` of the same
config, read back from its MCAP log by the tests' own reader (ehactl_mcap.py).

The FMU's library is found as the CLI finds it: beside the `ehactl` binary the tests run
(conftest.BIN; `cargo build --release -p ehactl-cli -p ehactl-fmu`, or the fast profile's
`target/fast/` with EHACTL_BIN), or through $EHACTL_FMU_LIB.
"""

from __future__ import annotations

import json
import math
import tomllib
import pathlib
import subprocess

import numpy as np
import pytest
from conftest import BIN, REPO
from ehactl_mcap import read_run

# FMPy is a test requirement (tests/python/requirements.txt, installed by both test scripts):
# a missing FMPy fails here rather than skipping the FMU's only outside client.
import fmpy
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.validation import validate_fmu

CONFIGS = sorted((REPO / "configs").glob("*.toml"))
# Plant outputs as (FMU name, MCAP channel, MCAP field): true states on /plant, sensor
# readings on /control.
PLANT_OUT = [
    ("x", "plant", "x"),
    ("v", "plant", "v"),
    ("p_a", "plant", "p_a"),
    ("p_b", "plant", "p_b"),
    ("force_load", "plant", "rod_force"),
    ("force_measured", "control", "force"),
    ("position_measured", "control", "position"),
    ("p_a_measured", "control", "p_a"),
    ("p_b_measured", "control", "p_b"),
]


def export(config, out, *extra):
    r = subprocess.run([BIN, "export-fmu", str(config), "--out", str(out), *extra],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return out


def ehactl_run(config, duration, out):
    r = subprocess.run([BIN, "run", str(config), "--duration", str(duration), "--out", str(out),
                        "--json"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return read_run(out)


class Fmu:
    """One FMPy instance of an FMU, with the messages its logger received."""

    def __init__(self, path, name="inst", starts=None):
        self.md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.types = {v.name: v.type for v in self.md.modelVariables}
        self.dt = float(self.md.defaultExperiment.stepSize)
        self.messages = []

        def logger(env, inst, status, category, message):
            self.messages.append((status, category.decode(), message.decode()))

        self._logger = fmi2CallbackLoggerTYPE(logger)
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = self._logger
        callbacks.allocateMemory = fmpy.fmi2.fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        callbacks.freeMemory = fmpy.fmi2.fmi2CallbackFreeMemoryTYPE(fmpy.free)
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=extract(str(path)),
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName=name)
        self.fmu.instantiate(callbacks=callbacks, loggingOn=True)
        self.t = 0.0
        self.init(starts or {})

    def init(self, starts):
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        for k, v in starts.items():
            self.set(k, v)
        self.fmu.exitInitializationMode()
        self.t = 0.0

    def set(self, name, value):
        vr = [self.vr[name]]
        setter = {"Real": self.fmu.setReal, "Integer": self.fmu.setInteger,
                  "Boolean": self.fmu.setBoolean}[self.types[name]]
        setter(vr, [value])

    def get(self, names):
        return self.fmu.getReal([self.vr[n] for n in names])

    def step(self, cycles=1):
        h = cycles * self.dt
        self.fmu.doStep(currentCommunicationPoint=self.t, communicationStepSize=h)
        self.t += h

    def close(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


def assert_close(got, want, what):
    """Every entry of `got` within 1e-9 of `want`, relative to the channel's largest |value|
    (a relative test per sample is meaningless where the channel crosses zero)."""
    got, want = np.asarray(got, float), np.asarray(want, float)
    scale = max(float(np.max(np.abs(want))), 1e-300)
    err = float(np.max(np.abs(got - want))) / scale
    assert err <= 1e-9, f"{what}: largest deviation {err:.3g} of the channel's scale"


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_every_shipped_config_exports_and_fmpy_validates_it(config, tmp_path):
    for variant in ([], ["--closed-loop"]):
        fmu = export(config, tmp_path / "rig.fmu", *variant)
        assert validate_fmu(str(fmu)) == [], (config.name, variant)
        md = read_model_description(str(fmu))
        params = [v for v in md.modelVariables if v.causality == "parameter"]
        # every registry parameter the config holds: at least the plant's mass, with unit and
        # a start value inside the declared range
        mass = next(v for v in params if v.name == "mechanics.mass")
        assert mass.unit == "kg" and float(mass.min) == 0.0 and float(mass.start) > 0.0
        for v in params:
            if v.type == "Real" and v.min is not None:
                assert float(v.start) >= float(v.min), v.name
            if v.type == "Real" and v.max is not None:
                assert float(v.start) <= float(v.max), v.name
        # the default experiment is the config's
        run = tomllib.loads(config.read_text())["run"]
        assert float(md.defaultExperiment.stepSize) == 1.0 / run["control_rate_hz"]
        assert float(md.defaultExperiment.stopTime) == run["duration"]


def test_closed_loop_fmu_equals_ehactl_run(tmp_path):
    """Sahu 2022 force loop: the FMU's closed loop, fed the setpoint `ehactl run` logged,
    gives the run's plant states, sensor readings and commands."""
    cfg = REPO / "configs" / "sahu2022_force.toml"
    run = ehactl_run(cfg, 0.2, tmp_path / "run.mcap")
    ctl, plant = run["control"], run["plant"]
    n = len(ctl["t"])
    assert n == 1000
    f = Fmu(export(cfg, tmp_path / "cl.fmu", "--closed-loop"))
    names = [o[0] for o in PLANT_OUT]
    got, cmd, trip = [], [], []
    for k in range(n):
        got.append(f.get(names))
        f.set("setpoint", ctl["setpoint"][k])
        f.set("setpoint_rate", ctl["setpoint_rate"][k])
        f.step()
        cmd.append(f.get(["command"])[0])
        trip.append(f.fmu.getBoolean([f.vr["trip"]])[0])
    f.close()
    got = np.array(got)
    for j, (name, chan, field) in enumerate(PLANT_OUT):
        assert_close(got[:, j], run[chan][field], name)
    assert_close(cmd, ctl["command"], "command")
    assert not any(trip)
    # the loop moved the plant: a vacuous comparison of constants would pass too
    assert np.ptp(plant["rod_force"]) > 100.0


def test_closed_loop_with_the_configs_setpoint_and_long_steps(tmp_path):
    """`setpoint_from_config` and steps of 7 control periods (the FMU substeps inside):
    the communication points equal every 7th cycle of `ehactl run`."""
    cfg = REPO / "configs" / "sahu2022_force.toml"
    run = ehactl_run(cfg, 0.14, tmp_path / "run.mcap")
    f = Fmu(export(cfg, tmp_path / "cl.fmu", "--closed-loop"),
            starts={"setpoint_from_config": True})
    names = [o[0] for o in PLANT_OUT]
    got = []
    for _ in range(len(run["control"]["t"]) // 7):
        got.append(f.get(names))
        f.step(7)
    f.close()
    got = np.array(got)
    for j, (name, chan, field) in enumerate(PLANT_OUT):
        assert_close(got[:, j], run[chan][field][::7][: len(got)], name)


def plant_replay(fmu_path, command, starts=None, name="inst"):
    """The plant FMU driven by `command` (V per cycle): outputs at every cycle's start."""
    f = Fmu(fmu_path, name=name, starts=starts)
    names = [o[0] for o in PLANT_OUT]
    got = []
    for u in command:
        got.append(f.get(names))
        f.set("u", u)
        f.step()
    f.close()
    return np.array(got)


@pytest.fixture(scope="module")
def boom(tmp_path_factory):
    """Dindorf 2022 boom: `ehactl run` of 0.3 s (its PD loop) and the plant FMU."""
    d = tmp_path_factory.mktemp("boom")
    cfg = REPO / "configs" / "dindorf2022_boom.toml"
    run = ehactl_run(cfg, 0.3, d / "run.mcap")
    return run, export(cfg, d / "plant.fmu"), d


def test_plant_fmu_with_the_recorded_command_equals_ehactl_run(boom):
    run, fmu, _ = boom
    command = run["control"]["command"]
    got = plant_replay(fmu, command)
    for j, (name, chan, field) in enumerate(PLANT_OUT):
        assert_close(got[:, j], run[chan][field], name)
    assert np.ptp(run["plant"]["x"]) > 0.01


def test_a_start_value_equals_editing_the_toml(boom):
    run, fmu, d = boom
    command = run["control"]["command"][:500]
    text = (REPO / "configs" / "dindorf2022_boom.toml").read_text()
    edited = d / "heavier.toml"
    assert "\nmass = 5.0 " in text
    edited.write_text(text.replace("\nmass = 5.0 ", "\nmass = 7.5 ", 1))
    from_toml = plant_replay(export(edited, d / "heavier.fmu"), command)
    from_start = plant_replay(fmu, command, starts={"mechanics.mass": 7.5})
    nominal = plant_replay(fmu, command)
    for j, (name, _, _) in enumerate(PLANT_OUT):
        assert_close(from_start[:, j], from_toml[:, j], name)
    # and the mass mattered
    assert np.max(np.abs(from_start[:, 0] - nominal[:, 0])) > 1e-5


def test_two_instances_in_one_process_stay_separate(boom):
    run, fmu, _ = boom
    command = run["control"]["command"][:400]
    alone_a = plant_replay(fmu, command)
    alone_b = plant_replay(fmu, command, starts={"mechanics.mass": 7.5})
    a = Fmu(fmu, name="a")
    b = Fmu(fmu, name="b", starts={"mechanics.mass": 7.5})
    names = [o[0] for o in PLANT_OUT]
    got_a, got_b = [], []
    for u in command:  # interleaved, cycle by cycle
        got_a.append(a.get(names))
        got_b.append(b.get(names))
        a.set("u", u)
        b.set("u", u)
        a.step()
        b.step()
    a.close()
    b.close()
    np.testing.assert_array_equal(np.array(got_a), alone_a)
    np.testing.assert_array_equal(np.array(got_b), alone_b)
    assert np.max(np.abs(alone_a[:, 0] - alone_b[:, 0])) > 1e-5


def refused(f, call, *args, expect):
    """`call(*args)` returns fmi2Error and logs a message containing `expect`."""
    before = len(f.messages)
    with pytest.raises(FMICallException) as e:
        call(*args)
    assert e.value.status == 3, e.value
    logged = [m for m in f.messages[before:] if m[0] == 3]
    assert logged and expect in logged[-1][2], f.messages[before:]


def test_hostile_inputs_return_fmi2error_with_a_message(boom):
    _, fmu, _ = boom
    f = Fmu(fmu)
    u = f.vr["u"]
    refused(f, f.fmu.setReal, [u], [math.nan], expect="not finite")
    refused(f, f.fmu.setReal, [u], [25.0], expect="out of range")
    refused(f, f.fmu.setReal, [f.vr["mechanics.mass"]], [2000.0], expect="fixed parameter")
    refused(f, f.fmu.setReal, [f.vr["x"]], [0.0], expect="is an output")
    refused(f, f.fmu.doStep, 0.0, 1.5 * f.dt, expect="not a whole multiple")
    refused(f, f.fmu.doStep, 0.0, -f.dt, expect="not a whole multiple")
    refused(f, f.fmu.doStep, 1.0, f.dt, expect="a step starts where the last one ended")
    refused(f, f.fmu.setReal, [10_000], [0.0], expect="value reference 10000 does not exist")
    # after the refusals the instance still steps, several periods at once included
    f.set("u", 1.0)
    f.step(5)
    assert f.get(["v"])[0] != 0.0
    f.close()
    # parameters outside their registry range, before initialisation
    g = FMU2Slave(guid=f.md.guid, unzipDirectory=extract(str(fmu)),
                  modelIdentifier="ehactl_fmu", instanceName="g")
    g.instantiate()
    g.setupExperiment(startTime=0.0)
    g.enterInitializationMode()
    for name, bad in [("mechanics.mass", -1.0), ("mechanics.mass", math.nan)]:
        with pytest.raises(FMICallException) as e:
            g.setReal([f.vr[name]], [bad])
        assert e.value.status == 3
    g.exitInitializationMode()
    g.terminate()
    g.freeInstance()


def test_reset_and_reinitialisation_repeat_the_run(boom):
    run, fmu, _ = boom
    command = run["control"]["command"][:300]
    f = Fmu(fmu)
    names = [o[0] for o in PLANT_OUT]

    def replay():
        out = []
        for u in command:
            out.append(f.get(names))
            f.set("u", u)
            f.step()
        return np.array(out)

    first = replay()
    f.fmu.reset()
    f.init({})
    second = replay()
    f.close()
    np.testing.assert_array_equal(first, second)
    assert np.ptp(first[:, 0]) > 0.0


def test_export_without_the_library_is_a_clear_error(tmp_path):
    r = subprocess.run([BIN, "export-fmu", str(CONFIGS[0]), "--out", str(tmp_path / "a.fmu"),
                        "--binary", str(tmp_path / "missing.so")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert "libehactl_fmu.so was not found" in r.stderr and "missing.so" in r.stderr
    assert not (tmp_path / "a.fmu").exists()
    r = subprocess.run([BIN, "export-fmu", str(CONFIGS[0]), "--out", str(tmp_path / "a.zip")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "ending in .fmu" in r.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text(CONFIGS[0].read_text().replace("[run]", "[run]\nbogus = 1", 1))
    r = subprocess.run([BIN, "export-fmu", str(bad), "--out", str(tmp_path / "b.fmu")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "bogus" in r.stderr, r.stderr
    assert not (tmp_path / "b.fmu").exists()


def test_the_fmu_carries_the_config_and_the_generic_library(tmp_path):
    fmu = export(REPO / "configs" / "sahu2022_force.toml", tmp_path / "s.fmu")
    import zipfile

    with zipfile.ZipFile(fmu) as z:
        assert z.testzip() is None
        names = set(z.namelist())
        assert {"modelDescription.xml", "resources/config.toml", "resources/variant",
                "binaries/linux64/ehactl_fmu.so"} <= names
        cfg_text = z.read("resources/config.toml").decode()
    assert cfg_text == (REPO / "configs" / "sahu2022_force.toml").read_text()
    lib = pathlib.Path(BIN).parent / "libehactl_fmu.so"
    if lib.is_file():
        with zipfile.ZipFile(fmu) as z:
            assert z.read("binaries/linux64/ehactl_fmu.so") == lib.read_bytes()


MTS = REPO / "tests" / "data" / "measured" / "utfsm_mts"


def test_the_campaigns_extended_toml_as_fmu_reproduces_ehactl_predict(diagnosis, tmp_path):
    """The README's campaign (conftest's shared diagnosis, the same command line as
    test_campaign.py): its extended.toml exports in both variants, FMPy validates them, and
    the closed-loop FMU driven by the 1 A record's `ref` at the record's operating point
    (current = 1 A, the start position the replay takes from the record) gives the scores
    `ehactl predict` gives for the same record's closed-loop replay, to 1e-6.

    Not the README's `--imposed-motion` prediction: it prescribes the rod's motion, which a
    plant FMU cannot take (its input is the valve command; x is an output). The series
    `predict` replays are not in its JSON, only their NRMSE per channel, so the scores are
    compared; an NRMSE equal to 1e-6 needs the series equal far below the record's noise."""
    _, out = diagnosis("--config", REPO / "configs" / "utfsm_mts_mrdamper.toml",
                       "--data", MTS / "0A_5to15s.csv", "--data", MTS / "1A_5to15s.csv")
    ext = out / "extended.toml"
    plant = export(ext, tmp_path / "plant.fmu")
    loop = export(ext, tmp_path / "loop.fmu", "--closed-loop")
    for fmu in (plant, loop):
        assert validate_fmu(str(fmu)) == []
        current = next(v for v in read_model_description(str(fmu)).modelVariables if v.name == "current")
        assert (current.causality, current.unit) == ("input", "A")
    record = MTS / "1A_5to15s.csv"
    r = subprocess.run([BIN, "predict", "--config", str(ext), "--data", str(record), "--json"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    pred = json.loads(r.stdout)
    assert pred["replay"] == "closed_loop" and pred["operating_point"] == {"current": 1.0}
    rec = np.genfromtxt(record, delimiter=",", names=True)
    f = Fmu(loop, starts={"current": 1.0, "cylinder.initial_position": float(rec["x"][0])})
    assert f.dt == rec["t"][1] - rec["t"][0]
    y = []
    for ref in rec["ref"]:
        y.append(f.get(["position_measured", "force_measured"]))
        f.set("setpoint", float(ref))
        f.set("setpoint_rate", 0.0)  # the replay's law has no setpoint rate either
        f.step()
    assert not f.fmu.getBoolean([f.vr["trip"]])[0]
    # the operating point is fixed from the end of initialisation: a change is refused
    refused(f, f.fmu.setReal, [f.vr["current"]], [0.5], expect="fixed from the end of initialisation")
    f.set("current", 1.0)  # the same value is no change
    f.close()
    y = np.array(y)
    for j, ch in enumerate(("x", "force")):
        nrmse = np.sqrt(np.mean((rec[ch] - y[:, j]) ** 2)) / np.std(rec[ch])
        want = pred["nrmse"]["channels"][ch]
        assert abs(nrmse - want) <= 1e-6 * want, (ch, nrmse, want)
        assert 0.01 < want < 1.0  # a real prediction, neither exact nor off


def test_the_readme_diagnosis_extended_toml_exports(diagnosis, tmp_path):
    """The README's single-record diagnosis (out/diag/ there; the command line test_campaign.py
    shares) writes an extended.toml that exports in both variants and that FMPy validates."""
    _, out = diagnosis("--config", REPO / "configs" / "utfsm_mts_mrdamper.toml", "--data", MTS / "1A_5to15s.csv")
    for extra in ([], ["--closed-loop"]):
        fmu = export(out / "extended.toml", tmp_path / "diag.fmu", *extra)
        assert validate_fmu(str(fmu)) == []
        names = {v.name for v in read_model_description(str(fmu)).modelVariables}
        # the grey-box law the diagnosis wrote is there as parameters
        assert any(n.startswith("effects.polynomial_force.") for n in names), sorted(names)[:20]
