"""Grey-box extension of `ehactl diagnose` on real data (DIAGNOSIS.md "Grey-box extension" and the real-data
"Done when" point): the UTFSM MTS press with an MR damper at 0 A and 1 A (the converted records
keep the load-cell force), and the Sjöberg actuator (estimation half fitted, validation half
held out).

What is checked against something we did not write:
- the physics of the MR damper: a higher coil current raises the yield force (Spencer et al.,
  J. Eng. Mech. 123(3):230–238, 1997, Fig. 4/eq. 12–13; Stanway et al. 1987 Bingham model):
  the diagnoses of the two records must differ that way and name the same cause;
- an independent estimate of the damper law from the data alone: numpy least squares of the
  measured force on [v, sign(v), 1] with v the central difference of the measured position;
  the same estimator applied to the diagnosed model's force (traces.csv) must find the same
  yield force, whatever terms the law was written in;
- the same for the MTS loop, whose controller and valve are assumptions: numpy least squares of
  the velocity on the tracking error gives its gain and the null offset's position error;
- the extended config is runnable by `ehactl run`.
The ratios to the ARX baseline are asserted at the achieved values (targets in comments).
Each record is diagnosed once per module (slow: about a minute of CPU per MTS record)."""
import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
MTS = REPO / "tests" / "data" / "measured" / "utfsm_mts"
SJ = REPO / "tests" / "data" / "measured" / "sjoberg"
CFG = REPO / "configs" / "utfsm_mts_mrdamper.toml"


def diagnose(out, *args):
    r = subprocess.run([BIN, "diagnose", *args, "--out", str(out), "--json"], capture_output=True,
                       text=True, timeout=1800)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.fixture(scope="module")
def mts(diagnosis):
    """Each MTS record's diagnosis (shared with the other modules: conftest.py)."""
    return {rec: diagnosis("--config", CFG, "--data", MTS / f"{rec}_5to15s.csv") for rec in ("0A", "1A")}


def numpy_damper(rec, force=None):
    """Equation-error estimate F ≈ c·v + F_c·tanh(v/v_s) + F₀ on the fitting part (70 %) of the
    measured force, or of `force` (a model's force on the same samples)."""
    f = np.genfromtxt(MTS / f"{rec}_5to15s.csv", delimiter=",", names=True)
    n = int(round(0.7 * len(f)))
    dt = f["t"][1] - f["t"][0]
    # Central difference of the position after a 9-sample (18 ms) moving average: the raw
    # difference is mostly quantisation noise at 500 Hz.
    xs = np.convolve(f["x"], np.ones(9) / 9, "same")
    v = np.gradient(xs, dt)[:n]
    a = np.column_stack([v, np.tanh(v / 1e-3), np.ones(n)])  # v_s as in the config: 1 mm/s
    y = f["force"] if force is None else force
    c, *_ = np.linalg.lstsq(a, y[:n], rcond=None)
    return c


def test_force_channel_is_used(mts):
    for rec, (d, _) in mts.items():
        assert set(d["nrmse_nominal"]["channels"]) == {"x", "force"}, rec
        # The nominal damper (2900 N·s/m, no yield) misses most of the measured force.
        assert d["nrmse_nominal"]["channels"]["force"] > 0.85, (rec, d["nrmse_nominal"])


def test_mr_damper_current_gives_consistent_diagnoses(mts):
    yields = {}
    for rec, (d, out) in mts.items():
        g = d["greybox"]
        assert g is not None and g["accepted"], (rec, g)
        paths = [t["path"] for t in g["terms"]]
        # The yield force of the damper is the first thing both records ask for, as a Dahl
        # (pre-yield) or a rate-only yield term. A viscous term of the Bingham model is not
        # asked for: fitted on the slow part of the chirp it did not predict the faster part
        # (the transfer check).
        assert paths[0] in ("effects.polynomial_force.coulomb", "effects.polynomial_force.dahl"), (rec, paths)
        # Named as the cause, in physical terms, with value and unit: consistent across currents.
        assert d["cause"].startswith("load-side yield force "), (rec, d["cause"])
        total = float(d["cause"].split()[3])
        assert total == pytest.approx(g["yield_force"], rel=1e-3), (d["cause"], g["yield_force"])
        assert d["causes"] == [], d["causes"]  # no catalogue effect
        # The terms were chosen by how they predict the part of the fitting data they were not
        # fitted on, and they do predict it better.
        t = g["transfer"]
        assert t["nrmse_after"] < 0.7 * t["nrmse_before"], (rec, t)
        if g["yield_velocity"] is not None:
            assert 0.0 < g["yield_velocity"] < 0.5, g["yield_velocity"]
        if g["dahl_travel"] is not None:
            # Pre-yield travel: a fraction of the ≈ ±2 mm stroke of the chirp.
            assert 1e-6 < g["dahl_travel"] < 2e-3, g["dahl_travel"]
        # The same independent estimator on the measured force and on the diagnosed model's
        # force: the law carries the damper's yield force, whatever its terms.
        tr = np.genfromtxt(out / "traces.csv", delimiter=",", names=True)
        meas, model = numpy_damper(rec, tr["meas_force"]), numpy_damper(rec, tr["ext_force"])
        assert meas[1] == pytest.approx(numpy_damper(rec)[1], rel=1e-6)  # same samples
        assert model[1] == pytest.approx(meas[1], rel=0.1), (rec, model, meas)
        yields[rec] = (g["yield_force"], model[1], meas[1])
    # Higher current: higher yield force (Spencer 1997), in the data, in the model's force, and
    # in the law's reported yield force.
    for k in range(3):
        assert yields["1A"][k] > 2.0 * yields["0A"][k] > 0.0, yields


def test_mts_ratios_to_arx_baseline(mts):
    for rec, (d, _) in mts.items():
        g = d["greybox"]
        # Target: extended ≤ 0.8 × the ARX baseline (overall held-out NRMSE). Met.
        assert g["ratio_to_baseline"] <= 0.8, (rec, g["ratio_to_baseline"])
        assert g["ratio_to_baseline"] == pytest.approx(
            g["nrmse_validation"]["overall"] / d["nrmse_baseline"]["overall"], rel=1e-9)
        # Per channel the force is where the physics wins.
        assert g["nrmse_validation"]["channels"]["force"] < 0.6 * d["nrmse_baseline"]["channels"]["force"]
    # The position, the loop's output: with the assumed loop identified (DIAGNOSIS.md "Assumed
    # loop") the refit model (no law) beats the ARX model on both (0.0191 vs 0.0199 at 0 A,
    # 0.0199 vs 0.0247 at 1 A; at 5 substeps per sample the 0 A refit was level, 0.0203; with
    # the loop assumed: 0.070 and 0.078). The final model with the yield law beats it on both
    # (0.0184 vs 0.0199 at 0 A; 0.0224 vs 0.0247 at 1 A, where the rate-only yield law alone
    # gave 0.0258: the Dahl pre-yield state carries the force's lag behind the velocity
    # reversal, DIAGNOSIS.md "Why the law cost the 1 A position").
    refit_x = {rec: d["nrmse_refit"]["channels"]["x"] / d["nrmse_baseline"]["channels"]["x"]
               for rec, (d, _) in mts.items()}
    assert refit_x["1A"] < 1.0, refit_x
    assert refit_x["0A"] < 1.0, refit_x
    for rec, (d, _) in mts.items():
        arx = d["nrmse_baseline"]["channels"]["x"]
        x = d["greybox"]["nrmse_validation"]["channels"]["x"]
        assert x < arx, (rec, x, arx)


def numpy_loop(rec):
    """Equation-error estimate of the proportional loop from the data alone: v ≈ K_v·(ref − x − e₀)
    by least squares on the fitting part (70 %), v from the smoothed position as in
    `numpy_damper`; returns (K_v in 1/s, e₀ = x − ref at rest in m). No valve lag or delay in
    it, so its K_v absorbs them and comes out lower than the loop's gain."""
    f = np.genfromtxt(MTS / f"{rec}_5to15s.csv", delimiter=",", names=True)
    n = int(round(0.7 * len(f)))
    dt = f["t"][1] - f["t"][0]
    xs = np.convolve(f["x"], np.ones(9) / 9, "same")
    rs = np.convolve(f["ref"], np.ones(9) / 9, "same")
    v = np.gradient(xs, dt)[5:n]
    e = (rs - xs)[5:n]
    (k, c), *_ = np.linalg.lstsq(np.column_stack([e, np.ones(len(e))]), v, rcond=None)
    return k, c / k


def test_mts_loop_is_identified_and_agrees_across_currents_and_with_numpy(mts):
    loops = {}
    for rec, (d, out) in mts.items():
        lp = d["identified_loop"]
        assert lp is not None, d["summary"]
        loops[rec] = lp
        # The report states the loop with units.
        assert "velocity gain K_v = " in lp["text"] and " 1/s" in lp["text"], lp["text"]
        assert "transport delay " in lp["text"] and " ms" in lp["text"], lp["text"]
        assert "Identified loop" in (out / "report.md").read_text(), rec
        paths = {p["path"] for p in lp["params"]}
        assert {"valve.rated_flow", "effects.time_delay.delay", "effects.valve_dynamics.time_constant",
                "effects.valve_deadband.zero_offset", "effects.valve_deadband.overlap"} <= paths, paths
        # Against numpy's equation-error estimate: the null offset's position error within
        # 15 µm (found 3 and 2 µm apart), the gain above numpy's lag-free one by < 40 % (found
        # 14 % and 19 %).
        k, e0 = numpy_loop(rec)
        assert abs(lp["position_offset"] - e0) < 15e-6, (rec, lp["position_offset"], e0)
        assert 1.0 < lp["velocity_gain"] / k < 1.4, (rec, lp["velocity_gain"], k)
        # The identified loop is the rig's: the extended config carries it.
        text = (out / "extended.toml").read_text()
        assert "[effects.valve_deadband]" in text and "[effects.time_delay]" in text, rec
    # One rig, two damper currents: the loop agrees (gain within 20 %, found 16 %; offset within
    # 15 µm, found 11 µm) while the damper's yield force grows 8×.
    a, b = loops["0A"], loops["1A"]
    assert abs(a["velocity_gain"] / b["velocity_gain"] - 1.0) < 0.2, (a["velocity_gain"], b["velocity_gain"])
    assert abs(a["position_offset"] - b["position_offset"]) < 15e-6, (a["position_offset"], b["position_offset"])


def test_extended_config_runs(mts):
    for rec, (_, out) in mts.items():
        cfg = out / "extended.toml"
        text = cfg.read_text()
        assert "[effects.polynomial_force]" in text and "coulomb" in text, rec
        r = subprocess.run([BIN, "run", str(cfg), "--duration", "0.2", "--out", str(out / "run.mcap")],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr


def numpy_arx_heldout(u_fit, y_fit, u_val, y_val):
    """Held-out free-run NRMSE of the ARX chosen by Akaike's criterion on the fitting part,
    computed with the independent numpy implementation of test_diagnose_baseline.py."""
    from test_diagnose_baseline import lstsq_arx, nrmse, simulate

    n, best = len(u_fit), None
    for na in range(1, 5):
        for nb in range(1, 5):
            for nk in range(1, 5):
                a, b, c = lstsq_arx(u_fit, y_fit, na, nb, nk, n)
                e = nrmse(y_fit, simulate(a, b, c, u_fit, y_fit, nk))
                aic = n * np.log(e * e) + 2 * (na + nb + 1)
                if best is None or aic < best[0]:
                    best = (aic, a, b, c, nk)
    _, a, b, c, nk = best
    return nrmse(y_val, simulate(a, b, c, u_val, y_val, nk))


def numpy_pressure_knees(u, p_a):
    """Where the quasi-static pressure stops following the opening, per direction (units of
    u): least squares of the 22-sample (one ringing period) moving average of p on
    [min(max(u, −k₋), 0), max(min(u, k₊), 0), 1], each knee scanned on a 0.01 grid."""
    w = np.ones(22) / 22
    ps = np.convolve(p_a, w, "same")[11:-11]
    us = np.convolve(u, w, "same")[11:-11]
    def knee(side):
        best = None
        for k in np.arange(0.1, 1.5, 0.01):
            if side < 0:
                cols = [np.minimum(np.maximum(us, -k), 0), np.maximum(us, 0)]
            else:
                cols = [np.maximum(np.minimum(us, k), 0), np.minimum(us, 0)]
            a = np.column_stack(cols + [np.ones_like(us)])
            c, *_ = np.linalg.lstsq(a, ps, rcond=None)
            s = float(np.sum((a @ c - ps) ** 2))
            if best is None or s < best[0]:
                best = (s, k)
        return best[1]
    return knee(-1), knee(+1)


def test_sjoberg_extended_beats_arx(tmp_path):
    """The catalogue's model must predict the held-out pressure at least as well as a linear
    ARX from the opening. The record's pressure response is one-sided: it levels off for
    negative openings beyond ≈ 0.6 units of u but keeps growing for positive ones (numpy knee
    estimate below). The `asymmetric` spool limit follows that once its limits start inside the
    travel the command reaches: started at 0.9 of the travel (this record reaches 16 % and
    18 %) a limit never clips the command, the cost is flat, the fit did not move it, and the
    diagnosis named no catalogue effect (or, with the earlier config, the symmetric limit, 0.625
    against the ARX's 0.621)."""
    d = diagnose(tmp_path, "--config", str(REPO / "configs" / "sjoberg1995_actuator.toml"),
                 "--data", str(SJ / "estimation.csv"), "--validate", str(SJ / "validation.csv"))
    est = np.genfromtxt(SJ / "estimation.csv", delimiter=",", names=True)
    val = np.genfromtxt(SJ / "validation.csv", delimiter=",", names=True)
    arx = numpy_arx_heldout(est["u"], est["p_a"], val["u"], val["p_a"])
    assert d["nrmse_baseline"]["channels"]["p_a"] == pytest.approx(arx, rel=1e-5)
    ext = d["nrmse_extended"]["channels"]["p_a"]
    # Achieved 0.458 against the ARX's 0.621 (ratio 0.74).
    assert ext < arx, (ext, arx)
    # The spool limit leaves p_a at ≈ 15× its noise floor: the closest catalogue effect, not
    # the cause (DIAGNOSIS.md step 7, "An edge fit is not a cause").
    assert d["causes"][0] == "valve_saturation", d["causes"]
    assert d["closest"]["effect"] == "valve_saturation", d["closest"]
    assert d["status"] == "not_explained" and d["cause"] == "unexplained", (d["status"], d["cause"])
    sat = [c for c in d["candidates"] if c["effect"] == "valve_saturation"][0]
    assert sat["variant"] == "asymmetric", sat
    # The fitted limits against the data's own knees (config: full travel = 8 units of u).
    k_neg, k_pos = numpy_pressure_knees(est["u"], 5.0 - est["p_a"] / 1e6)
    lim_neg = 8.0 * sat["params"]["effects.valve_saturation.spool_limit_negative"]
    lim_pos = 8.0 * sat["params"]["effects.valve_saturation.spool_limit"]
    assert k_neg < k_pos, (k_neg, k_pos)  # numpy: 0.67 and 0.94
    assert lim_neg < lim_pos, (lim_neg, lim_pos)
    assert abs(lim_neg - k_neg) < 0.25, (lim_neg, k_neg)  # fitted 0.57


def test_sjoberg_greybox_ratio(tmp_path):
    d = diagnose(tmp_path, "--config", str(REPO / "configs" / "sjoberg1995_actuator.toml"),
                 "--data", str(SJ / "estimation.csv"), "--validate", str(SJ / "validation.csv"))
    g = d["greybox"]
    assert g is not None, d["summary"]
    # The grey-box terms are chosen by how they predict the last 40 % of the estimation record
    # when fitted on its first 60 %; on this record none does, so the final model is the
    # catalogue's (test above): held-out 0.458, ratio 0.74 (target ≤ 0.8).
    ratio = g["nrmse_validation"]["overall"] / d["nrmse_baseline"]["overall"]
    assert ratio <= 0.8, ratio
