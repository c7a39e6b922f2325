"""Predictions that know their limits (`ehactl diagnose` campaigns and `ehactl predict`):

- a campaign's law keeps the signs physics gives its dissipative terms, and its extended config
  runs bounded in `ehactl run` and in closed-loop `predict` (the README's campaign);
- every record outside the motion or operating inputs the law was fitted on is flagged, with
  how far (stroke, current, frequency band);
- a saturating coil's dependence reaches `predict` exactly, not as a Taylor series;
- a replay that leaves physical bounds is reported as diverged, with no NRMSE, exit 5.

The records come from the NumPy/SciPy modified Bouc–Wen damper (tests/python/bouc_wen.py,
Spencer et al. 1997) and the UTFSM MTS chirps (tests/data/measured/utfsm_mts/).
"""
import json
import math
import os
import pathlib
import subprocess
import tomllib

import numpy as np
import pytest

import bouc_wen as bw

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
CONFIG = REPO / "configs" / "utfsm_mts_mrdamper.toml"
MTS = REPO / "tests" / "data" / "measured" / "utfsm_mts"
RATE = 500.0  # Hz, the config's control rate
MID = 0.05  # m, mid stroke of the rig config
DISSIPATIVE = ("viscous", "coulomb", "quadratic", "dahl", "pressure_coulomb")


def ehactl(*args, timeout=600):
    return subprocess.run([BIN, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def coefficient(ext, name, current):
    """`effects.polynomial_force.<name>` of an extended config at `current` (A), from the
    dependence docs/usage.md documents: p(i) = p₀ + a·(i − i₀) + b·(i − i₀)² +
    g·(e^(−i₀/i_s) − e^(−i/i_s)) + s·(max(i − i_k, 0) − max(i₀ − i_k, 0))."""
    path = f"effects.polynomial_force.{name}"
    p0 = ext["effects"]["polynomial_force"][name]
    inp = ext["inputs"]["current"]
    i0 = inp.get("value", 0.0)
    d = current - i0
    a = inp.get("linear", {}).get(path, 0.0)
    b = inp.get("quadratic", {}).get(path, 0.0)
    s = inp.get("saturating", {}).get(path)
    sat = 0.0 if s is None else s["gain"] * (math.exp(-i0 / s["scale"]) - math.exp(-current / s["scale"]))
    h = inp.get("hinge", {}).get(path)
    knee = 0.0 if h is None else h["slope"] * (max(current - h["knot"], 0.0) - max(i0 - h["knot"], 0.0))
    return p0 + a * d + b * d * d + sat + knee


@pytest.fixture(scope="module")
def readme_campaign(tmp_path_factory):
    out = tmp_path_factory.mktemp("readme") / "campaign"
    r = ehactl("diagnose", "--config", CONFIG, "--data", MTS / "0A_5to15s.csv",
               "--data", MTS / "1A_5to15s.csv", "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout), out


def test_the_readme_campaign_law_keeps_physical_signs(readme_campaign):
    _, out = readme_campaign
    ext = tomllib.loads((out / "extended.toml").read_text())
    k_load = ext["mechanics"].get("load_stiffness", 0.0)
    for i in np.linspace(0.0, 1.0, 11):
        for name in DISSIPATIVE:
            assert coefficient(ext, name, i) >= -1e-9, (name, i)
        assert coefficient(ext, "stiffness", i) + k_load >= -1e-9, i


def test_the_readme_campaign_law_runs_bounded_where_the_nominal_does(readme_campaign, tmp_path):
    j, out = readme_campaign
    assert j["closed_loop"]["dropped"] is None and j["closed_loop"]["records"] == 2, j["closed_loop"]
    runs = {}
    for name, cfg in (("nominal", CONFIG), ("extended", out / "extended.toml")):
        r = ehactl("run", cfg, "--out", tmp_path / f"{name}.mcap", "--json")
        assert r.returncode == 0, r.stderr
        runs[name] = json.loads(r.stdout)
        assert runs[name]["trip"] is None, runs[name]
    # The same 2 s PD position test: the extended damper may track a little differently, never
    # run away (it used to be driven from end stop to end stop at a rod force of 1e13 N).
    assert runs["extended"]["max_abs_error"] < 2.0 * runs["nominal"]["max_abs_error"], runs
    for rec in ("0A_5to15s.csv", "1A_5to15s.csv"):
        p = ehactl("predict", "--config", out / "extended.toml", "--data", MTS / rec, "--json")
        assert p.returncode == 0, p.stderr
        pj = json.loads(p.stdout)
        assert pj["replay"] == "closed_loop" and pj["diverged"] is None, pj
        assert pj["nrmse"]["overall"] < 1.0, pj["nrmse"]


def chirp(amplitude, f0, f1, duration):
    """x(t) = a·sin(2π(f0·t + ½·k·t²)), k = (f1 − f0)/T, and its exact velocity (m, m/s)."""
    k = (f1 - f0) / duration
    return (lambda t: amplitude * np.sin(2 * np.pi * (f0 * t + 0.5 * k * t * t)),
            lambda t: amplitude * 2 * np.pi * (f0 + k * t) * np.cos(2 * np.pi * (f0 * t + 0.5 * k * t * t)))


def write(path, rec):
    rec = dict(rec)
    rec["x"] = rec["x"] + MID
    bw.write_csv(path, rec)
    return path


@pytest.fixture(scope="module")
def chirp_campaign(tmp_path_factory):
    """Two 2 mm chirps (0.5–10 Hz) at 0 and 1 A, fitted whole; sines of 2–25 mm held out."""
    d = tmp_path_factory.mktemp("chirps")
    args = ["diagnose", "--config", CONFIG, "--json", "--out", d / "out"]
    for c in (0.0, 1.0):
        p = write(d / f"chirp_{c:g}A.csv", bw.record(chirp(0.002, 0.5, 10.0, 10.0), c, 10.0, rate=RATE, seed=7 + int(c)))
        args += ["--data", p]
    sines = {}
    for a, f in ((0.025, 0.5), (0.01, 1.0), (0.002, 5.0)):
        p = write(d / f"sine_{a * 1e3:g}mm_{f:g}Hz.csv", bw.record(bw.sine(a, f), 0.5, max(3.0, 2.0 / f), rate=RATE, seed=int(a * 1e4 + f)))
        sines[(a, f)] = p
        args += ["--validate", p]
    r = ehactl(*args)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout), sines, d


def test_sines_beyond_the_chirps_stroke_are_flagged_with_how_far(chirp_campaign):
    j, sines, _ = chirp_campaign
    by_source = {r["source"]: r for r in j["records"]}
    chirp_pp = 2 * 0.002
    for (a, f), p in sines.items():
        env = by_source[str(p)]["envelope"]
        stroke = [e for e in env["excursions"] if e["quantity"] == "stroke"]
        ratio = 2 * a / chirp_pp  # peak-to-peak of the sine over the chirps'
        if ratio > 1.5:
            assert not env["inside"] and stroke, (a, f, env)
            # Within the load-cell-free motion's own precision: the records' x is exact.
            assert stroke[0]["beyond"] == pytest.approx(ratio, rel=0.02), stroke
            line = next(ln for ln in j["summary"].splitlines() if str(p) in ln)
            assert "OUTSIDE the fitted envelope: stroke" in line, line
        else:
            assert not stroke, (a, f, env)


def test_predict_flags_a_record_beyond_the_fitted_stroke_and_current(chirp_campaign, tmp_path):
    _, sines, d = chirp_campaign
    ext = d / "out" / "extended.toml"
    r = ehactl("predict", "--config", ext, "--data", sines[(0.025, 0.5)], "--json")
    assert r.returncode == 0, r.stderr
    pj = json.loads(r.stdout)
    assert pj["envelope"]["inside"] is False
    assert any("stroke" in w and "12.5× the fitted range" in w for w in pj["warnings"]), pj["warnings"]
    # The same motion labelled 1.2 A: outside the fitted 0–1 A by 0.2 A, predicted and flagged.
    rec = bw.record(bw.sine(0.002, 5.0), 1.0, 3.0, rate=RATE, seed=3)
    rec["current"] = np.full(rec["t"].size, 1.2)
    r = ehactl("predict", "--config", ext, "--data", write(tmp_path / "at_1.2A.csv", rec), "--json")
    assert r.returncode == 0, r.stderr
    pj = json.loads(r.stdout)
    cur = [e for e in pj["envelope"]["excursions"] if e["quantity"] == "current"]
    assert cur and cur[0]["beyond"] == pytest.approx(0.2, rel=1e-9), pj["envelope"]
    assert "current 1.2 A outside the fitted 0–1 A" in cur[0]["text"], cur
    assert any("outside the fitted 0–1 A" in w for w in pj["warnings"]), pj["warnings"]
    # At −0.34 A and 5 A the law's linear dependence leaves a parameter's range (a negative
    # Dahl force or travel): refused (exit 2), and the message says the record lies beyond
    # what the law was fitted on (it used to answer 7e12 and 1.85 without a word).
    for current in (-0.34, 5.0):
        rec["current"] = np.full(rec["t"].size, current)
        r = ehactl("predict", "--config", ext, "--data", write(tmp_path / f"at_{current:g}A.csv", rec), "--json")
        assert r.returncode == 2, r.stdout
        assert "out of range" in r.stderr, r.stderr
        assert f"current {current:g} A outside the fitted 0–1 A" in r.stderr, r.stderr


def test_a_chirp_fitted_on_part_of_its_sweep_flags_the_other_frequencies(tmp_path):
    """Hold out by frequency: fit on the 5–15 s part of a 0.5→20 Hz sweep of 20 s, predict
    the whole sweep: its band reaches beyond the part's, and the report says so."""
    motion = chirp(0.002, 0.5, 20.0, 20.0)
    whole = bw.record(motion, 0.5, 20.0, rate=RATE, seed=11)
    part = {k: v[int(5 * RATE):int(15 * RATE)] for k, v in whole.items()}
    part["t"] = part["t"] - part["t"][0]
    fit = write(tmp_path / "part.csv", part)
    r = ehactl("diagnose", "--config", CONFIG, "--data", fit, "--out", tmp_path / "out", "--json")
    assert r.returncode == 0, r.stderr
    p = ehactl("predict", "--config", tmp_path / "out" / "extended.toml",
               "--data", write(tmp_path / "whole.csv", whole), "--json")
    assert p.returncode == 0, p.stderr
    env = json.loads(p.stdout)["envelope"]
    band = [e for e in env["excursions"] if e["quantity"] == "band"]
    assert band, env
    # A single record is fitted on its first 70 % (the rest held out): 5–12 s of the sweep,
    # whose instantaneous frequency 0.5 + 0.975·t Hz runs 5.4–12.2 Hz there; the central 90 %
    # of that flat band is 5.7–11.9 Hz. The whole sweep (0.5–20 Hz) lies on both sides.
    lo, hi = band[0]["fitted"]
    assert lo == pytest.approx(5.7, abs=0.3) and hi == pytest.approx(11.9, abs=0.3), band
    assert "on both sides of the fitted" in band[0]["text"], band


def test_a_saturating_coil_reaches_predict_exactly(tmp_path):
    """Fitted at 0, 0.5 and 1 A on a coil that saturates (i_s = 0.3 A), the campaign may pick
    a saturating dependence; `predict` with its extended config must reproduce the campaign's
    own held-out score at 0.25 A (a Taylor series of the saturating form would not)."""
    args = ["diagnose", "--config", CONFIG, "--json", "--out", tmp_path / "out"]
    for c in (0.0, 0.5, 1.0):
        for a, f in ((0.005, 1.0), (0.002, 4.0)):
            rec = bw.record(bw.sine(a, f), c, 3.0, rate=RATE, seed=int(c * 10 + f), saturation=0.3)
            args += ["--data", write(tmp_path / f"s_{a * 1e3:g}_{f:g}_{c:g}.csv", rec)]
    new = write(tmp_path / "new_0.25A.csv", bw.record(bw.sine(0.004, 2.0), 0.25, 3.0, rate=RATE, seed=99, saturation=0.3))
    args += ["--validate", new]
    r = ehactl(*args)
    assert r.returncode == 0, r.stderr
    j = json.loads(r.stdout)
    rec = next(x for x in j["records"] if x["source"] == str(new))
    p = ehactl("predict", "--config", tmp_path / "out" / "extended.toml", "--data", new, "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["nrmse"]["channels"]["force"] == pytest.approx(rec["nrmse"]["law"], rel=1e-6)
    # Fitted between 0 and 1 A: 0.25 A is inside the envelope.
    assert rec["envelope"]["inside"], rec["envelope"]


def test_a_knee_in_the_coil_is_found_piecewise_and_reaches_predict(tmp_path):
    """A coil that saturates hard at 0.5 A (its amplifier's current limit: the coefficients rise
    linearly to 0.5 A and stay flat beyond), fitted at five currents: leaving one current out
    picks the piecewise form with its knee at 0.5 A for the yield force, whose slope beyond the
    knee is about zero, and `predict` reproduces the campaign's score at an unseen current
    through `[inputs.current.hinge]`.

    Measured 2026-12-07: yield force 840 N/A·i − 844 N/A·max(i − 0.5 A, 0); rms NRMSE on the
    current left out 0.097 (0.113 with the quadratic form chosen when the piecewise one is not
    offered); unseen 0.375 and 0.625 A pooled 0.060 (0.060 with the quadratic form: between the
    fitted currents both bend enough)."""
    args = ["diagnose", "--config", CONFIG, "--json", "--out", tmp_path / "out"]

    def records(c):
        k = int(c * 1000)
        motions = (("sine", bw.sine(0.005, 1.0), 3.0), ("random", bw.random_history(k + 3, 0.004, 5.0, 6.0), 6.0))
        return [write(tmp_path / f"{name}_{c:g}A.csv", bw.record(m, c, d, rate=RATE, seed=7000 + k + i, saturation=-0.5))
                for i, (name, m, d) in enumerate(motions)]

    for c in (0.0, 0.25, 0.5, 0.75, 1.0):
        args += [a for p in records(c) for a in ("--data", p)]
    unseen = [p for c in (0.375, 0.625) for p in records(c)]
    args += [a for p in unseen for a in ("--validate", p)]
    r = ehactl(*args)
    assert r.returncode == 0, r.stderr
    j = json.loads(r.stdout)
    yield_force = next(t for t in j["terms"] if t["name"] == "load-side yield force")
    form, (slope, change) = yield_force["dependence"]["current"]
    assert form == {"form": "piecewise", "knot": 0.5}, yield_force
    assert slope > 0 and abs(slope + change) < 0.1 * slope, yield_force
    assert "leaving one operating point out (5 points)" in j["dependence_check"], j["dependence_check"]
    ext = tomllib.loads((tmp_path / "out" / "extended.toml").read_text())
    hinge = ext["inputs"]["current"]["hinge"]["effects.polynomial_force.coulomb"]
    assert hinge["knot"] == 0.5 and hinge["slope"] == pytest.approx(change, rel=1e-9), hinge
    assert j["pooled"]["law"] < 0.1 and j["pooled"]["law"] < 0.2 * j["pooled"]["nominal"], j["pooled"]
    rec = next(x for x in j["records"] if x["source"] == str(unseen[0]))
    p = ehactl("predict", "--config", tmp_path / "out" / "extended.toml", "--data", unseen[0], "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["nrmse"]["channels"]["force"] == pytest.approx(rec["nrmse"]["law"], rel=1e-6)


def unstable_config(tmp_path):
    """The MTS rig with a damper law no passive damper has: negative viscous damping."""
    text = CONFIG.read_text()
    old = "viscous = 2900.0"
    assert old in text
    text = text.replace(old, "viscous = -2.0e6", 1)
    p = tmp_path / "unstable.toml"
    p.write_text(text)
    return p


def test_a_diverging_replay_is_an_outcome_not_a_number(tmp_path):
    cfg = unstable_config(tmp_path)
    chk = ehactl("check-config", cfg)
    assert chk.returncode == 0, chk.stderr
    data = MTS / "0A_5to15s.csv"
    r = ehactl("predict", "--config", cfg, "--data", data, "--json")
    assert r.returncode == 5, (r.returncode, r.stderr)
    pj = json.loads(r.stdout)
    d = pj["diverged"]
    assert pj["nrmse"]["overall"] is None and all(v is None for v in pj["nrmse"]["channels"].values()), pj
    assert d is not None and d["channel"], d
    assert d["t"] == pytest.approx(d["sample"] * 0.002), d  # the record's 500 Hz
    # The bound is read from the record independently: 10× its largest |force|.
    f = np.loadtxt(data, delimiter=",", skiprows=1, usecols=4)
    # The first sample out of bounds: the plant's own check (a state no rig can have), or the
    # predicted force against the record's range.
    if d["channel"] == "force":
        assert abs(d["value"]) > 10 * np.abs(f).max() or not math.isfinite(d["value"]), d
        assert d["bound"] == pytest.approx(10 * np.abs(f).max(), rel=1e-9), d
    assert any("DIVERGED" in w for w in pj["warnings"]), pj["warnings"]
    text = ehactl("predict", "--config", cfg, "--data", data)
    assert text.returncode == 5
    assert "DIVERGED at t = " in text.stdout and "no NRMSE" in text.stdout, text.stdout


def band_campaign(tmp_path, saturation):
    """Fitted at 0, 0.5 and 1 A (sines of 2–10 mm at 1–5 Hz and a random history each),
    predicting 0.25 and 0.75 A, on a linear or a saturating coil."""
    args = ["diagnose", "--config", CONFIG, "--json", "--out", tmp_path / "out"]
    for c in (0.0, 0.25, 0.5, 0.75, 1.0):
        k = int(c * 100)
        motions = [(f"sine_{a * 1e3:g}mm_{f:g}Hz", bw.sine(a, f), 3.0) for a, f in ((0.005, 1.0), (0.01, 2.0), (0.002, 5.0))]
        motions.append(("random", bw.random_history(k + 3, 0.004, 5.0, 6.0), 6.0))
        for i, (name, motion, duration) in enumerate(motions):
            rec = bw.record(motion, c, duration, rate=RATE, seed=1000 * k + i, saturation=saturation)
            p = write(tmp_path / f"{name}_{c:g}A.csv", rec)
            args += ["--validate" if c in (0.25, 0.75) else "--data", p]
    r = ehactl(*args)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.mark.parametrize("saturation", [None, 0.3], ids=["linear_coil", "saturating_coil"])
def test_the_band_covers_its_level_at_unseen_currents(tmp_path, saturation):
    j = band_campaign(tmp_path, saturation)
    new = [r for r in j["records"] if r["role"] == "validation"]
    assert len(new) == 8
    inside = sum(r["band"]["coverage"] * (r["scored"][1] - r["scored"][0]) for r in new)
    total = sum(r["scored"][1] - r["scored"][0] for r in new)
    # Nominal 90 %: pooled over the 8 unseen-current records, 80–97 %. Measured 2026-12-07:
    # 0.87 (linear coil; 0.56 … 1.0 per record), 0.92 (saturating coil; 0.73 … 1.0).
    assert 0.80 <= inside / total <= 0.97, [(r["source"], r["band"]["coverage"]) for r in new]
    assert all(r["band"]["level"] == 0.9 for r in new)


def test_predict_carries_the_band_and_draws_it(chirp_campaign, tmp_path):
    _, sines, d = chirp_campaign
    out = tmp_path / "pred"
    r = ehactl("predict", "--config", d / "out" / "extended.toml", "--data", sines[(0.002, 5.0)],
               "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    pj = json.loads(r.stdout)
    b = pj["band"]
    assert b["level"] == 0.9 and 0.0 <= b["coverage"] <= 1.0 and b["half_width_rms"] > 0, b
    # The coverage is the share of measured samples within the band: recomputed here from
    # the half-width would need the series; at least it is not vacuous (a band that covers
    # everything would be as useless as none).
    svg = (out / "prediction.svg").read_text()
    assert "band, upper" in svg and "band, lower" in svg


def test_the_band_stays_honest_beyond_the_fitted_stroke(chirp_campaign):
    """Beyond the chirps' stroke (the 10 and 25 mm sines, 5× and 12.5×) the band must not be
    overconfident: the refits disagree more there and the band grows with the force, so it
    still covers about its level. Measured 2026-12-07: 0.99 at 25 mm, against 0.92 for the
    2 mm sine inside the envelope."""
    j, sines, _ = chirp_campaign
    by_source = {r["source"]: r for r in j["records"]}
    for (a, f), p in sines.items():
        r = by_source[str(p)]
        if not r["envelope"]["inside"]:
            assert r["band"]["coverage"] >= 0.85, (a, f, r["band"])
