"""Hold-out by frequency on measured data: the README's campaign law, fitted on the slow start of
the UTFSM MTS chirps (5–15 s, 0.1–0.9 Hz, ±2 mm, 0 A and 1 A), predicts the rest of the same
sweeps (15 s to the end: 1–20 Hz, ±2 to ±0.9 mm), which it never saw.

What a law that knows its limits must do there, and what this one does (figures in
DIAGNOSIS.md, "Hold-out by frequency"):
- every held-out segment is flagged outside the fitted envelope (motion band above the fitted
  one, velocity several times the fitted range), the fitting segments are not (beyond the
  tail of the chirp segment they were partly fitted on, a little faster than the fitted part);
- the 90 % band widens out of the envelope and still covers at least 80 % of the samples;
- in closed loop (the record's setpoint through the loop) the law stays bounded and predicts
  the force no worse than the nominal config on every segment; the replay carries the band of
  10 members, which covers the fitted segments and 0 A but misses at 1 A above 9 Hz (strict
  xfail: the band holds the law's uncertainty, not the loop's);
- with the motion imposed it beats the nominal config at 1 A, and misses at 0 A above 7 Hz
  (documented by a strict xfail): fitted at |v| ≤ 0.01 m/s, where the 0 A damper's force is a
  yield force, the law has no viscous part at 0 A, while at 8–20 Hz (|v| up to 0.08 m/s) the
  0 A force is mostly viscous (≈ 2.9 kN·s/m, the nominal config's value).

Records: tests/data/measured/utfsm_mts/ (README_source.md there gives the source and the
conversion, scripts/convert_measured.py).
"""
import json
import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
CONFIG = REPO / "configs" / "utfsm_mts_mrdamper.toml"
MTS = REPO / "tests" / "data" / "measured" / "utfsm_mts"
FITTED = ("0A_5to15s", "1A_5to15s")
HELD_OUT = ("0A_15to30s", "0A_30to45s", "0A_45toEnd", "1A_15to30s", "1A_30to45s", "1A_45toEnd")


def ehactl(*args, timeout=600):
    return subprocess.run([BIN, *map(str, args)], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def law(tmp_path_factory):
    out = tmp_path_factory.mktemp("holdout") / "campaign"
    r = ehactl("diagnose", "--config", CONFIG, *(a for f in FITTED for a in ("--data", MTS / f"{f}.csv")),
               "--out", out)
    assert r.returncode == 0, r.stderr
    return out / "extended.toml"


def predict(config, record, *extra):
    r = ehactl("predict", "--config", config, "--data", MTS / f"{record}.csv", "--json", *extra)
    assert r.returncode == 0, (record, r.returncode, r.stderr)
    return json.loads(r.stdout)


@pytest.fixture(scope="module")
def imposed(law):
    """Imposed-motion predictions of every segment: {record: (extended, nominal)}."""
    return {rec: (predict(law, rec, "--imposed-motion"), predict(CONFIG, rec, "--imposed-motion"))
            for rec in FITTED + HELD_OUT}


def force_nrmse(p):
    return p["nrmse"]["channels"]["force"]


def test_held_out_frequencies_are_flagged_and_the_fitted_ones_are_not(imposed):
    for rec, (ext, _) in imposed.items():
        excursions = (ext["envelope"] or {}).get("excursions", [])
        quantities = {e["quantity"] for e in excursions}
        if rec in FITTED:
            # The law was fitted on the first 70 % of these records; the sweep speeds up in
            # the held-out tail, so the whole record may go a little faster than the fitted
            # part (1.3x at 1 A), but it stays in the fitted band.
            assert "band" not in quantities, (rec, excursions)
            assert all(e["beyond"] < 1.5 for e in excursions), (rec, excursions)
            continue
        assert {"band", "velocity"} <= quantities, (rec, quantities)
        velocity = next(e for e in excursions if e["quantity"] == "velocity")
        assert velocity["beyond"] > 3.0, (rec, velocity)
        assert any("OUTSIDE the fitted envelope" in w for w in ext["warnings"]), (rec, ext["warnings"])


def test_the_band_widens_out_of_band_and_still_covers(imposed):
    for rec in HELD_OUT:
        ext = imposed[rec][0]
        inside = imposed[rec[:2] + "_5to15s"][0]
        assert ext["band"]["coverage"] >= 0.80, (rec, ext["band"])
        assert ext["band"]["half_width_rms"] > 1.3 * inside["band"]["half_width_rms"], (
            rec, ext["band"], inside["band"])


def test_with_imposed_motion_the_law_beats_the_nominal_config_at_1_A(imposed):
    for rec in HELD_OUT:
        if rec.startswith("1A"):
            ext, nom = imposed[rec]
            assert force_nrmse(ext) < 0.5 * force_nrmse(nom), (rec, force_nrmse(ext), force_nrmse(nom))


@pytest.mark.xfail(strict=True, reason="measured miss: the 0 A law fitted at 0.1-0.9 Hz has no viscous part; above 7 Hz "
                   "the 0 A force is mostly viscous (DIAGNOSIS.md, Hold-out by frequency)")
def test_with_imposed_motion_the_law_is_no_worse_than_nominal_at_0_A(imposed):
    for rec in HELD_OUT:
        if rec.startswith("0A"):
            ext, nom = imposed[rec]
            assert force_nrmse(ext) <= force_nrmse(nom), (rec, force_nrmse(ext), force_nrmse(nom))


@pytest.fixture(scope="module")
def closed(law):
    """Closed-loop predictions of every segment: {record: (extended, nominal)}."""
    return {rec: (predict(law, rec), predict(CONFIG, rec)) for rec in FITTED + HELD_OUT}


def test_in_closed_loop_the_law_stays_bounded_and_no_worse_than_nominal(closed):
    for rec in HELD_OUT:
        ext, nom = closed[rec]
        assert ext["diverged"] is None and nom["diverged"] is None, rec
        assert force_nrmse(ext) <= force_nrmse(nom), (rec, force_nrmse(ext), force_nrmse(nom))


def test_a_closed_loop_replay_carries_the_band(closed):
    for rec, (ext, nom) in closed.items():
        assert ext["replay"] == "closed_loop", rec
        assert nom["band"] is None, rec  # the nominal config has no [band]
        assert ext["band"]["spread_rms"] > 0, (rec, ext["band"])
    for rec in FITTED + tuple(r for r in HELD_OUT if r.startswith("0A")):
        assert closed[rec][0]["band"]["coverage"] >= 0.80, (rec, closed[rec][0]["band"])


@pytest.mark.xfail(strict=True, reason="measured miss: the band holds the law's uncertainty, not the loop's; at 1 A "
                   "above 9 Hz the replayed position is 19-22 % off and the closed-loop band covers 0.57-0.67")
def test_the_closed_loop_band_covers_at_1_A_above_9_Hz(closed):
    for rec in ("1A_30to45s", "1A_45toEnd"):
        assert closed[rec][0]["band"]["coverage"] >= 0.80, (rec, closed[rec][0]["band"])
