"""Campaign diagnosis (`ehactl diagnose --data R1 --data R2 …`) and `ehactl predict`, checked
against records ehactl did not make:

- an MR damper written in NumPy/SciPy from the modified Bouc–Wen model of Spencer et al. 1997
  (tests/python/bouc_wen.py), tested at 0 … 1 A by sines of several amplitudes and
  frequencies and a broadband displacement: fitted at 0, 0.5 and 1 A, it must predict 0.25 and
  0.75 A, operating points it never saw;
- the real UTFSM MTS chirps at 0 A and 1 A (tests/data/measured/utfsm_mts/), one campaign.
"""
import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

import bouc_wen as bw

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
CONFIG = REPO / "configs" / "utfsm_mts_mrdamper.toml"
MTS = REPO / "tests" / "data" / "measured" / "utfsm_mts"
CURRENTS_FIT = (0.0, 0.5, 1.0)
CURRENTS_NEW = (0.25, 0.75)
RATE = 500.0  # Hz, the config's control rate


def ehactl(*args, timeout=600):
    return subprocess.run([BIN, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def records_at(current):
    """The tests of one operating point: sines of 2–10 mm at 1–5 Hz and a random history."""
    k = int(current * 100)
    motions = [(f"sine_{a * 1e3:g}mm_{f:g}Hz", bw.sine(a, f), 3.0) for a, f in ((0.005, 1.0), (0.01, 2.0), (0.002, 5.0))]
    motions.append(("random", bw.random_history(k + 3, 0.004, 5.0, 6.0), 6.0))
    out = []
    for i, (name, motion, duration) in enumerate(motions):
        rec = bw.record(motion, current, duration, rate=RATE, seed=1000 * k + i)
        rec["x"] = rec["x"] + 0.05  # mid stroke of the rig config
        out.append((f"{name}_{current:g}A", rec))
    return out


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("bouc_wen")
    files = {}
    for c in CURRENTS_FIT + CURRENTS_NEW:
        for name, rec in records_at(c):
            p = d / f"{name}.csv"
            bw.write_csv(p, rec)
            files.setdefault(c, []).append(p)
    args = ["diagnose", "--config", CONFIG, "--json", "--out", d / "out"]
    for c in CURRENTS_FIT:
        args += [a for p in files[c] for a in ("--data", p)]
    for c in CURRENTS_NEW:
        args += [a for p in files[c] for a in ("--validate", p)]
    r = ehactl(*args)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout), files, d


def test_campaign_names_the_current_dependence(campaign):
    j, _, _ = campaign
    assert j["mode"] == "campaign"
    assert "current" in j["cause"] and "N/A" in j["cause"], j["cause"]
    # Three fitting operating points: the dependence was kept by leaving one out.
    assert "leaving one operating point out (3 points)" in j["dependence_check"], j["dependence_check"]
    assert any(t["dependence"] for t in j["terms"]), j["terms"]


def test_unseen_currents_are_predicted_far_better_than_nominal_and_arx(campaign):
    j, _, _ = campaign
    new = [r for r in j["records"] if r["role"] == "validation"]
    assert len(new) == 8
    assert {r["operating_point"]["current"] for r in new} == set(CURRENTS_NEW)
    for r in new:
        s = r["nrmse"]
        assert s["law"] < 0.25 * s["nominal"], r
        assert s["law"] < 0.5 * s["arx"], r
    # Measured 2026-11-28: pooled 0.029 (0.011 … 0.054 per unseen-current test) with the Dahl
    # term behind a series dashpot, its δ and V following the current (0.067 with Dahl's law).
    assert j["pooled"]["law"] <= 0.035, j["pooled"]


def test_unseen_currents_meet_the_five_percent_target(campaign):
    j, _, _ = campaign
    assert j["pooled"]["law"] <= 0.05, j["pooled"]
    # The element's drive v − V·z with V following the current (Spencer et al. 1997: the
    # roll-off velocity α·z/(c₀ + c₁) grows with α, affine in the coil input).
    t = j["travel_dependence"]
    assert t is not None and t["velocity_slope"] > 0, j["summary"]
    assert j["shape"]["dahl_velocity"] > 0, j["shape"]


def chirp(amplitude, f0, f1, duration):
    """x(t) = a·sin(2π(f0·t + ½·k·t²)), k = (f1 − f0)/T, and its exact velocity (m, m/s)."""
    k = (f1 - f0) / duration

    def x(t):
        return amplitude * np.sin(2 * np.pi * (f0 * t + 0.5 * k * t * t))

    def v(t):
        return amplitude * 2 * np.pi * (f0 + k * t) * np.cos(2 * np.pi * (f0 * t + 0.5 * k * t * t))

    return x, v


def test_two_chirps_predict_sines_of_other_amplitudes_at_unseen_currents(tmp_path):
    """The practice the published model is measured against, on the independent generator:
    fitted on two short 2 mm chirps (0.5–10 Hz) at 0 and 1 A only, the law predicts sines of
    2–25 mm at 0.1–5 Hz (up to 12× the chirps' stroke) at 0.25, 0.5 and 0.75 A."""
    args = ["diagnose", "--config", CONFIG, "--json", "--out", tmp_path / "out"]
    for c in (0.0, 1.0):
        rec = bw.record(chirp(0.002, 0.5, 10.0, 10.0), c, 10.0, rate=RATE, seed=int(c * 10) + 1)
        rec["x"] = rec["x"] + 0.05
        bw.write_csv(tmp_path / f"chirp_{c:g}A.csv", rec)
        args += ["--data", tmp_path / f"chirp_{c:g}A.csv"]
    for c in (0.25, 0.5, 0.75):
        for a, f in ((0.025, 0.1), (0.015, 0.5), (0.01, 1.0), (0.005, 2.0), (0.002, 5.0)):
            rec = bw.record(bw.sine(a, f), c, max(3.0, 2.0 / f), rate=RATE, seed=int(c * 100 + a * 1e4 + f))
            rec["x"] = rec["x"] + 0.05
            p = tmp_path / f"sine_{a * 1e3:g}mm_{f:g}Hz_{c:g}A.csv"
            bw.write_csv(p, rec)
            args += ["--validate", p]
    r = ehactl(*args)
    assert r.returncode == 0, r.stderr
    j = json.loads(r.stdout)
    sines = [x for x in j["records"] if x["role"] == "validation"]
    assert len(sines) == 15
    for x in sines:
        assert x["nrmse"]["law"] < 0.35 * x["nrmse"]["nominal"], x
        assert x["nrmse"]["law"] < x["nrmse"]["arx"], x
    # Measured 2026-11-28: median 0.069 over the 15 sines (0.027 … 0.160, the largest at
    # 25 mm / 0.1 Hz, 0.25 A: slow travel far beyond the chirps' 2 mm); 0.093 with Dahl's
    # law (no series dashpot).
    law = sorted(x["nrmse"]["law"] for x in sines)
    assert law[len(law) // 2] < 0.085, law


def test_predict_with_the_extended_config_reproduces_the_campaign(campaign, tmp_path):
    j, files, d = campaign
    ext = d / "out" / "extended.toml"
    text = ext.read_text()
    assert "[inputs.current.linear]" in text
    by_source = {r["source"]: r for r in j["records"]}
    for p in files[0.75][:2]:
        r = ehactl("predict", "--config", ext, "--data", p, "--json")
        assert r.returncode == 0, r.stderr
        pj = json.loads(r.stdout)
        assert pj["replay"] == "imposed_motion"
        assert pj["operating_point"] == {"current": 0.75}
        assert pj["nrmse"]["channels"]["force"] == pytest.approx(by_source[str(p)]["nrmse"]["law"], rel=1e-9)
    # The same records predicted by the config without the campaign's law: far worse.
    r = ehactl("predict", "--config", CONFIG, "--data", files[0.75][0], "--json")
    assert json.loads(r.stdout)["nrmse"]["overall"] > 3 * by_source[str(files[0.75][0])]["nrmse"]["law"]


def test_predict_writes_a_plot_and_json(campaign, tmp_path):
    _, files, d = campaign
    out = tmp_path / "pred"
    r = ehactl("predict", "--config", d / "out" / "extended.toml", "--data", files[0.25][0],
               "--data", files[0.25][1], "--out", out)
    assert r.returncode == 0, r.stderr
    assert (out / "prediction.svg").read_text().startswith("<svg")
    assert len(json.loads((out / "prediction.json").read_text())["records"]) == 2


def with_current(src: pathlib.Path, dst: pathlib.Path, drop=()):
    import csv
    rows = list(csv.reader(src.open()))
    keep = [i for i, n in enumerate(rows[0]) if n not in drop]
    with dst.open("w", newline="") as f:
        w = csv.writer(f)
        for row in rows:
            w.writerow([row[i] for i in keep])
    return dst


def test_june_chirps_as_one_campaign(diagnosis):
    j, out = diagnosis("--config", CONFIG, "--data", MTS / "0A_5to15s.csv", "--data", MTS / "1A_5to15s.csv")
    assert "current" in j["cause"], j["cause"]
    # Two operating points: the report says the dependence is not validated across them.
    assert "NOT validated" in j["dependence_check"]
    ext = out / "extended.toml"
    for name in ("0A_5to15s.csv", "1A_5to15s.csv"):
        p = ehactl("predict", "--config", ext, "--data", MTS / name, "--imposed-motion", "--held-out", "--json")
        assert p.returncode == 0, p.stderr
        f = json.loads(p.stdout)["nrmse"]["channels"]["force"]
        rec = next(x for x in j["records"] if x["source"].endswith(name))
        assert f == pytest.approx(rec["nrmse"]["law"], rel=1e-9)
        # far better than the config without the law, and than the linear black box
        assert f < 0.5 * rec["nrmse"]["nominal"] and f < rec["nrmse"]["arx"], rec


@pytest.fixture(scope="module")
def june(diagnosis):
    """The June chirps as one campaign, and each diagnosed on its own (closed loop); the same
    diagnoses as test_diagnose_greybox.py's (conftest.py runs each once)."""
    j, _ = diagnosis("--config", CONFIG, "--data", MTS / "0A_5to15s.csv", "--data", MTS / "1A_5to15s.csv")
    single = {a: diagnosis("--config", CONFIG, "--data", MTS / f"{a}_5to15s.csv")[0] for a in ("0A", "1A")}
    return j, single


def campaign_vs_single(june, a):
    j, single = june
    rec = next(x for x in j["records"] if x["source"].endswith(f"{a}_5to15s.csv"))
    g = single[a]["greybox"]
    return rec["nrmse"]["law"], g["nrmse_validation"]["channels"]["force"]


def test_the_pre_yield_travel_follows_the_current(june):
    j, _ = june
    t = j["travel_dependence"]
    assert t is not None and t["input"] == "current", j["summary"]
    assert t["nrmse_transfer"] < 0.98 * t["nrmse_transfer_shared"]
    assert "pre-yield travel follows current" in j["summary"]


def test_the_1A_chirp_is_predicted_within_10_percent_of_its_own_diagnosis(june):
    law, own = campaign_vs_single(june, "1A")
    # Measured 2026-11-28: 0.122 against 0.142 (0.137 with Dahl's law, no series dashpot;
    # 0.204 with one travel for both currents).
    assert law <= 1.10 * own, (law, own)


@pytest.mark.xfail(strict=True, reason="0 A chirp: campaign 0.245 vs its own closed-loop diagnosis 0.198 "
                   "(force); alone as an imposed-motion campaign it reaches 0.238, so the imposed-motion "
                   "replay, not the pooling, is what is missing (the closed-loop diagnosis models the loop "
                   "and a pressure-dependent friction)")
def test_the_0A_chirp_is_predicted_within_10_percent_of_its_own_diagnosis(june):
    law, own = campaign_vs_single(june, "0A")
    assert law <= 1.10 * own, (law, own)


def test_motion_only_record_is_a_campaign_of_one(tmp_path):
    _, rec = records_at(0.5)[3]
    p = tmp_path / "motion_only.csv"
    bw.write_csv(p, rec)
    r = ehactl("diagnose", "--config", CONFIG, "--data", p, "--json")
    assert r.returncode == 0, r.stderr
    j = json.loads(r.stdout)
    assert j["mode"] == "campaign" and j["pooled"]["law"] < 0.2, j["summary"]
    assert "one operating point" in j["dependence_check"]


def write_lab_mcap(path, rec):
    """A lab record in MCAP as another tool writes it: the official `mcap` writer, JSON samples
    on /measured with the CSV format's column names (no `t`: the log time carries it)."""
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("Sample", "jsonschema", json.dumps({"type": "object"}).encode())
        ch = w.register_channel("/measured", "json", sid)
        for i, t in enumerate(rec["t"]):
            sample = {k: float(rec[k][i]) for k in ("x", "force", "current")}
            ns = int(round(t * 1e9))
            w.add_message(ch, log_time=ns, publish_time=ns, data=json.dumps(sample).encode(), sequence=i)
        w.finish()


def test_motion_only_mcap_is_the_same_record_as_its_csv(tmp_path):
    _, rec = records_at(0.5)[3]
    csv, lab = tmp_path / "motion_only.csv", tmp_path / "motion_only.mcap"
    bw.write_csv(csv, rec)
    write_lab_mcap(lab, rec)
    runs = [ehactl("diagnose", "--config", CONFIG, "--data", p, "--json") for p in (csv, lab)]
    for r in runs:
        assert r.returncode == 0, r.stderr
    a, b = (json.loads(r.stdout) for r in runs)
    assert b["mode"] == "campaign" and b["records"][0]["source"].endswith("motion_only.mcap (/measured)")
    # The same samples (the MCAP's times from nanosecond log times): the same law.
    assert b["pooled"]["law"] == pytest.approx(a["pooled"]["law"], rel=1e-6)
    p = ehactl("predict", "--config", CONFIG, "--data", lab, "--imposed-motion", "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["nrmse"]["channels"]["force"] > 0


def test_a_mcap_with_neither_log_nor_lab_record_is_refused(tmp_path):
    from mcap.writer import Writer

    p = tmp_path / "other.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("X", "jsonschema", b"{}")
        ch = w.register_channel("/imu", "json", sid)
        w.add_message(ch, log_time=0, publish_time=0, data=b"{}", sequence=0)
        w.finish()
    r = ehactl("diagnose", "--config", CONFIG, "--data", p)
    assert r.returncode == 2
    assert "no /control messages" in r.stderr and "/measured" in r.stderr, r.stderr


def test_a_record_with_neither_command_nor_motion_is_refused(tmp_path):
    p = tmp_path / "force_only.csv"
    t = np.arange(100) / RATE
    np.savetxt(p, np.column_stack([t, np.sin(t)]), delimiter=",", header="t,force", comments="")
    r = ehactl("diagnose", "--config", CONFIG, "--data", p)
    assert r.returncode == 2
    assert "missing required column `u`" in r.stderr and "`x` (m)" in r.stderr, r.stderr


def test_an_undeclared_column_is_an_error_naming_it(tmp_path):
    p = with_current(MTS / "1A_5to15s.csv", tmp_path / "renamed.csv")
    p.write_text(p.read_text().replace("current", "curent", 1))
    r = ehactl("diagnose", "--config", CONFIG, "--data", p)
    assert r.returncode == 2
    assert "`curent`" in r.stderr and "[current]" in r.stderr, r.stderr
