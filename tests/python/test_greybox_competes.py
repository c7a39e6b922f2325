"""A catalogue effect that a linear black box beats must compete with the grey-box law
(DIAGNOSIS.md "Grey-box extension", "When ARX beats the catalogue model").

The failure it reproduces: on a damper whose load force tracks velocity, the diagnosis once
accepted a mount compliance (`flexible_mount`) on the fitting part although the report's own
ARX baseline predicted the held-out part better, and the grey-box law fitted on top of it
stopped after one term, so the user got a wrong name and a poor model.

The record: `ehactl run` of the shipped MTS press config with an MR-damper-like rod force
(viscous 6000 N·s/m, yield 500 N, Dahl 250 N: a yield force of 750 N in steady sliding, the
order of the UTFSM damper's between 0 and 1 A, Spencer et al., J. Eng. Mech. 123(3):230–238,
1997, Fig. 4) on a 0.2–5 Hz chirp, exported with only what a displacement-controlled press logs
(t, u, x, ref, force), and diagnosed against the shipped config (viscous 2900 N·s/m only).

Checked: the failure mode is present on the fitting part (a catalogue effect accepted that
loses to ARX on the held-out part), the law alone wins the comparison and becomes the model,
the cause names a load-side yield force within 10 % of the generator's 750 N, and the
recommended model predicts the held-out part far better than ARX.

A second record shows the other way a catalogue effect is weak evidence: a damper of the
1 A order (viscous 3000 N·s/m, near the shipped 2900, yield 800 N + Dahl 350 N = 1150 N)
once gave `flexible_mount` with a 200 kg load mass at the end of its range, explaining 37 %
of the error above the floor, while ARX was worse still (0.585 against 0.449), so the ARX
rule alone did not make the law compete; the law on top of the mount kept no term."""
import json
import os
import pathlib
import re
import subprocess

import numpy as np
import pytest
from ehactl_mcap import read_run

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
CFG = REPO / "configs" / "utfsm_mts_mrdamper.toml"
# Generator's yield force in steady sliding: coulomb + Dahl (N).
TRUE_YIELD = 500.0 + 250.0


def truth_config(tmp, viscous=6000.0, coulomb=500.0, dahl=250.0):
    """The shipped config with the generator's rod force (N·s/m, N, N)."""
    s = CFG.read_text()
    law = "viscous = 2900.0"
    assert law in s, "the shipped config's damper law changed: update the generator"
    s = s.replace(law, f"viscous = {viscous}\ncoulomb = {coulomb}\nsmoothing_velocity = 0.002\n"
                  f"dahl = {dahl}\ndahl_travel = 4.0e-4\n# (was) viscous = 2900.0", 1)
    s, n = re.subn(r"\[setpoint\].*?\n\[run\]",
                   '[setpoint]\nkind = "chirp"\noffset = 0.05\namplitude = 0.006\nf0 = 0.2\n'
                   'f1 = 5.0\nduration = 10.0\nstart = 0.0\n\n[run]', s, flags=re.S)
    assert n == 1
    p = tmp / "truth.toml"
    p.write_text(s)
    return p


def diagnose_press_record(tmp, **law):
    """`ehactl run` of the generator, logged as a press logs it, diagnosed against the
    shipped config: the JSON."""
    mcap = tmp / "truth.mcap"
    r = subprocess.run([BIN, "run", str(truth_config(tmp, **law)), "--duration", "10", "--out", str(mcap)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    c = read_run(mcap)["control"]
    cols = np.column_stack([c["t"], c["command"], c["position"], c["setpoint"], c["force"]])
    csv = tmp / "press.csv"
    np.savetxt(csv, cols, delimiter=",", header="t,u,x,ref,force", comments="", fmt="%.9g")
    r = subprocess.run([BIN, "diagnose", "--config", str(CFG), "--data", str(csv), "--json",
                        "--out", str(tmp / "diag")], capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.fixture(scope="module")
def diagnosis(tmp_path_factory):
    return diagnose_press_record(tmp_path_factory.mktemp("competes"))


@pytest.fixture(scope="module")
def weak_mount(tmp_path_factory):
    return diagnose_press_record(tmp_path_factory.mktemp("weak"), viscous=3000.0, coulomb=800.0,
                                 dahl=350.0)


def test_the_failure_mode_is_present_on_the_fitting_part(diagnosis):
    d = diagnosis["dropped_effects"]
    assert d is not None, diagnosis["summary"]
    assert d["effects"], d
    # The catalogue model loses to ARX on the held-out part (1.1× here; the outside record
    # that showed it, 2.1×).
    assert d["nrmse_catalogue"] > d["nrmse_baseline"], d


def test_the_law_alone_wins_and_is_the_model(diagnosis):
    d = diagnosis["dropped_effects"]
    kept = [x for x in (d["nrmse_catalogue"], d["nrmse_catalogue_with_law"]) if x is not None]
    assert d["nrmse_law"] < min(kept), d
    assert diagnosis["causes"] == [], diagnosis["causes"]
    assert diagnosis["greybox"]["accepted"]
    assert not diagnosis["beaten_by_baseline"]
    assert "not kept" in diagnosis["summary"]
    # The recommended model predicts far better than the black box.
    g = diagnosis["greybox"]["nrmse_validation"]["overall"]
    assert g < 0.5 * diagnosis["nrmse_baseline"]["overall"], (g, diagnosis["nrmse_baseline"])


def test_the_cause_is_the_velocity_dependent_load(diagnosis):
    cause = diagnosis["cause"]
    assert cause.startswith("load-side"), cause
    assert diagnosis["greybox"]["yield_force"] == pytest.approx(TRUE_YIELD, rel=0.10), cause
    paths = {t["path"].rsplit(".", 1)[1] for t in diagnosis["greybox"]["terms"]}
    assert paths & {"viscous", "coulomb", "dahl"}, paths


def test_a_weak_catalogue_winner_competes_with_the_law_even_when_arx_is_worse(weak_mount):
    d = weak_mount["dropped_effects"]
    assert d is not None, weak_mount["summary"]
    # The rule that made it compete: weak evidence, not the ARX comparison.
    assert d["nrmse_catalogue"] <= d["nrmse_baseline"], d
    assert "weak evidence" in d["why"], d
    assert any("weak evidence" in a for a in weak_mount["ambiguities"]), weak_mount["ambiguities"]
    assert d["nrmse_law"] < d["nrmse_catalogue"], d
    assert weak_mount["causes"] == [] and weak_mount["greybox"]["accepted"]
    assert weak_mount["cause"].startswith("load-side"), weak_mount["cause"]
    assert weak_mount["greybox"]["yield_force"] == pytest.approx(800.0 + 350.0, rel=0.10)
    g = weak_mount["greybox"]["nrmse_validation"]["overall"]
    assert g < 0.5 * weak_mount["nrmse_baseline"]["overall"], (g, weak_mount["nrmse_baseline"])
