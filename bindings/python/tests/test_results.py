"""The result objects of ehactl.analyze / sweep / diagnose / run: typed attributes, short
reprs, immutability, to_pandas, and to_dict() checked against the CLI's own JSON
(`ehactl analyze --json`, `ehactl sweep --json`, `ehactl diagnose --json`, `ehactl run --json`)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pickle
import subprocess
import sys
import warnings

import numpy as np
import pytest

import ehactl
from conftest import CONFIGS, REPO
from ehactl.results import (
    AnalysisResult,
    DiagnosisCandidate,
    DiagnosisResult,
    FrozenMap,
    LoopResponse,
    Margins,
    NrmseErrors,
    RunSummary,
    SweepResult,
)

EHACTL = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
FORCE = CONFIGS / "sahu2022_force.toml"


def cli_json(*args: str) -> dict:
    out = subprocess.run([EHACTL, *args, "--json"], check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def assert_same_json(ours, cli, path="", skip=()):
    """Same keys at every level, same strings / bools / nulls, numbers equal to 1e-12."""
    if path in skip:
        return
    if isinstance(cli, dict):
        assert isinstance(ours, dict), path
        assert set(ours) == set(cli), f"{path}: keys differ: {set(ours) ^ set(cli)}"
        for k in cli:
            assert_same_json(ours[k], cli[k], f"{path}.{k}", skip)
    elif isinstance(cli, list):
        assert isinstance(ours, list) and len(ours) == len(cli), path
        for i, (a, b) in enumerate(zip(ours, cli)):
            assert_same_json(a, b, f"{path}[{i}]", skip)
    elif isinstance(cli, bool) or cli is None or isinstance(cli, str):
        assert ours == cli, f"{path}: {ours!r} != {cli!r}"
    else:
        assert isinstance(ours, (int, float)) and not isinstance(ours, bool), path
        assert ours == pytest.approx(cli, rel=1e-12, abs=1e-300), path


@pytest.fixture(scope="module")
def analysis():
    return ehactl.analyze(ehactl.Config.load(FORCE))


@pytest.fixture(scope="module")
def analysis_cli():
    return cli_json("analyze", str(FORCE))


def test_analyze_attributes_are_typed(analysis):
    a = analysis
    assert isinstance(a, AnalysisResult)
    assert isinstance(a.phase_margin_deg, float) and 0 < a.phase_margin_deg < 180
    assert isinstance(a.gain_crossover_hz, float) and a.gain_crossover_hz > 0
    assert isinstance(a.continuous, Margins) and isinstance(a.continuous.phase_margin_deg, float)
    assert isinstance(a.loop_response, LoopResponse)
    lr = a.loop_response
    assert lr.f_hz.dtype == np.float64 and lr.f_hz.ndim == 1 and len(lr) == lr.f_hz.size > 10
    assert all(getattr(lr, k).shape == lr.f_hz.shape for k in ("loop_mag_db", "loop_phase_deg", "closed_mag_db"))
    assert np.all(np.diff(lr.f_hz) > 0)
    # The loop gain is 0 dB at the gain crossover, as the margins say (log-f interpolation).
    mag_at_fc = np.interp(np.log(a.gain_crossover_hz), np.log(lr.f_hz), lr.loop_mag_db)
    assert abs(mag_at_fc) < 0.5
    assert a.operating_point.settled and isinstance(a.operating_point.command_V, float)
    assert a.poles and all(p.frequency_hz > 0 for p in a.poles)
    m = a.margins
    assert m.phase_margin_deg == a.phase_margin_deg and m.gain_margin_db == a.gain_margin_db


def test_analyze_to_dict_is_the_cli_json(analysis, analysis_cli):
    assert_same_json(analysis.to_dict(), analysis_cli)
    # JSON-compatible and a lossless round trip of the CLI's JSON.
    json.dumps(analysis.to_dict(), allow_nan=False)
    assert AnalysisResult.from_dict(analysis_cli).to_dict() == analysis_cli


def test_analyze_repr_summarises(analysis):
    r = repr(analysis)
    assert r.startswith("AnalysisResult(") and "phase_margin_deg=" in r and "gain_margin_db=" in r
    assert f"{analysis.phase_margin_deg:.4g}" in r
    assert len(r) < 300 and "array" not in r and "\n" not in r


def test_results_are_immutable(analysis):
    with pytest.raises(dataclasses.FrozenInstanceError):
        analysis.phase_margin_deg = 90.0  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        analysis.new_attribute = 1  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="read-only"):
        analysis.loop_response.f_hz[0] = 0.0
    r = ehactl.run(ehactl.Config.load(FORCE), duration=0.01)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.summary = None  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        r.force[0] = 0.0
    with pytest.raises(TypeError):
        r.columns["force"] = np.zeros(3)  # type: ignore[index]
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.summary.rms_error = 0.0  # type: ignore[misc]


def test_results_pickle(analysis):
    # Results travel through Dask and multiprocessing.
    b = pickle.loads(pickle.dumps(analysis))
    assert b.to_dict() == analysis.to_dict()
    assert not b.loop_response.f_hz.flags.writeable  # still immutable after the round trip
    with pytest.raises(dataclasses.FrozenInstanceError):
        b.rig = "x"  # type: ignore[misc]
    r = ehactl.run(ehactl.Config.load(FORCE), duration=0.01)
    r2 = pickle.loads(pickle.dumps(r))
    np.testing.assert_array_equal(r2.force, r.force)
    assert not r2.force.flags.writeable
    assert r2.summary.to_dict() == r.summary.to_dict()


def test_dict_access_still_works_with_a_deprecation_warning(analysis):
    with pytest.warns(DeprecationWarning, match=r"AnalysisResult\['phase_margin_deg'\].*deprecated"):
        pm = analysis["phase_margin_deg"]
    assert pm == analysis.phase_margin_deg
    with pytest.warns(DeprecationWarning):
        lr = analysis["loop_response"]
    assert isinstance(lr["f_hz"], np.ndarray)  # the earlier dict of arrays
    np.testing.assert_array_equal(lr["f_hz"], analysis.loop_response.f_hz)
    with pytest.warns(DeprecationWarning):
        assert analysis.get("no_such_key", 5) == 5
    with pytest.warns(DeprecationWarning):
        assert "gain_margin_db" in analysis
    with pytest.warns(DeprecationWarning):
        with pytest.raises(KeyError):
            analysis["no_such_key"]
    # Attribute access does not warn.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert analysis.phase_margin_deg == pm


def test_to_pandas(analysis):
    pd = pytest.importorskip("pandas")
    df = analysis.to_pandas()
    assert isinstance(df, pd.DataFrame)
    assert list(df.columns) == ["f_hz", "loop_mag_db", "loop_phase_deg", "closed_mag_db", "closed_phase_deg"]
    assert len(df) == len(analysis.loop_response)
    np.testing.assert_array_equal(df["closed_mag_db"].to_numpy(), analysis.loop_response.closed_mag_db)
    # the DataFrame owns its data: editing it leaves the result alone
    df.loc[0, "f_hz"] = -1.0
    assert analysis.loop_response.f_hz[0] > 0


def test_to_pandas_without_pandas_says_how_to_install(analysis, monkeypatch):
    monkeypatch.setitem(sys.modules, "pandas", None)  # import pandas → ImportError
    with pytest.raises(ImportError, match="pip install pandas"):
        analysis.to_pandas()


def test_sweep_to_dict_is_the_cli_json(tmp_path):
    args = dict(from_hz=20.0, to_hz=200.0, points=3)
    r = ehactl.sweep(FORCE, **args, mcap=tmp_path / "py.mcap")
    cli = cli_json("sweep", str(FORCE), "--from", "20", "--to", "200", "--points", "3",
                   "--out", str(tmp_path / "cli.mcap"))
    assert isinstance(r, SweepResult) and r.mode == "closed_loop" and r.complete
    assert r.frf.mag_db.shape == (3,) and r.frf.f_hz[0] == pytest.approx(20.0)
    assert_same_json(r.to_dict(), cli, skip={".mcap"})
    assert r.mcap == str(tmp_path / "py.mcap") and cli["mcap"] == str(tmp_path / "cli.mcap")
    assert SweepResult.from_dict(cli).to_dict() == cli
    rep = repr(r)
    assert rep.startswith("SweepResult(closed_loop") and "3 points" in rep and len(rep) < 300
    with pytest.warns(DeprecationWarning):
        f = r["f_hz"]  # the earlier flat dict form
    np.testing.assert_array_equal(f, r.frf.f_hz)
    pd = pytest.importorskip("pandas")
    df = r.to_pandas()
    assert isinstance(df, pd.DataFrame) and list(df["f_hz"]) == list(r.frf.f_hz)


def test_run_summary_is_the_cli_summary(tmp_path):
    cfg = ehactl.Config.load(FORCE)
    r = ehactl.run(cfg, duration=0.05)
    cli = cli_json("run", str(FORCE), "--duration", "0.05", "--out", str(tmp_path / "r.mcap"))
    s = r.summary
    assert isinstance(s, RunSummary) and s.cycles == len(r) == 250 and s.error_unit == "N"
    assert isinstance(s.rms_error, float) and s.rms_error == pytest.approx(cli["rms_error"], rel=1e-12)
    ours = s.to_dict()
    # The keys the CLI writes for a simulated run, and the same figures (wall time and the
    # log of the CLI's MCAP file differ by nature).
    assert set(ours) == set(cli)
    for k in ("cycles", "control_rate_hz", "duration_s", "rms_error", "rms_error_settled", "max_abs_error",
              "error_unit", "trip", "trip_kind", "interrupted", "substeps", "realtime"):
        assert ours[k] == cli[k], k
    assert RunSummary.from_dict(cli).to_dict() == cli
    assert "250 cycles" in repr(s) and "rms_error=" in repr(r)
    with pytest.warns(DeprecationWarning):
        assert r.summary["cycles"] == 250


def test_run_columns_are_typed_attributes():
    r = ehactl.run(ehactl.Config.load(FORCE), duration=0.01, fields=["t", "force", "u"])
    assert r.force.dtype == np.float64 and r.force.shape == (50,)
    np.testing.assert_array_equal(r.command, r.u)
    np.testing.assert_array_equal(r["force"], r.force)
    with pytest.raises(AttributeError, match="no column 'x'.*available: cycle, t, force, u"):
        r.x
    d = r.to_dict()
    assert set(d["columns"]) == {"cycle", "t", "force", "u"} and d["summary"]["cycles"] == 50
    json.dumps(d, allow_nan=False)


def test_diagnose_to_dict_is_the_cli_json(delay_diagnosis, tmp_path):
    mcap, out, d, _calls = delay_diagnosis
    cli = cli_json("diagnose", "--config", str(CONFIGS / "diagnose_testrig.toml"), "--data", str(mcap),
                   "--out", str(tmp_path / "cli"))
    assert isinstance(d, DiagnosisResult) and d.cause == "time_delay" and d.causes == ("time_delay",)
    assert isinstance(d.nrmse_extended, NrmseErrors) and d.nrmse_extended.overall < d.nrmse_nominal.overall
    assert all(isinstance(c, DiagnosisCandidate) for c in d.candidates)
    best = next(c for c in d.candidates if c.effect == "time_delay")
    assert best.accepted and abs(best.params["effects.time_delay.delay"] - 0.005) < 0.001
    # Same JSON but for the report files, written to each caller's own directory.
    assert_same_json(d.to_dict(), cli, skip={".extended_config", ".report", ".plots"})
    assert d.report == str(out / "report.md") and cli["report"] == str(tmp_path / "cli" / "report.md")
    assert d.plots is not None and [os.path.basename(p) for p in d.plots] == [os.path.basename(p) for p in cli["plots"]]
    assert DiagnosisResult.from_dict(cli).to_dict() == cli
    assert isinstance(d.residual_test, FrozenMap)
    with pytest.raises(TypeError):
        d.extended_params["x"] = 1.0  # type: ignore[index]
    rep = repr(d)
    assert rep.startswith("DiagnosisResult(cause='time_delay'") and "12 candidates" in rep and len(rep) < 300
    pytest.importorskip("pandas")
    df = d.to_pandas()
    assert len(df) == len(d.candidates) == 12
    assert df.loc[df["effect"] == "time_delay", "accepted"].item()
    assert "param:effects.time_delay.delay" in df.columns
    with pytest.warns(DeprecationWarning):
        assert d["cause"] == "time_delay"


def test_margins_none_where_no_crossing_round_trips():
    # A loop without a phase crossover: the CLI leaves the key out; the object says None.
    js = {"gain_crossover_hz": 10.0, "phase_margin_deg": 60.0, "phase_crossover_hz": None,
          "gain_margin_db": None, "closed_loop_bandwidth_hz": 12.0, "closed_loop_peak_db": 0.5}
    m = Margins.from_dict(js)
    assert m.gain_margin_db is None and m.to_dict() == js
    assert "gain_margin_db=None" in repr(m)
    assert math.isnan(Margins.from_dict({**js, "closed_loop_peak_db": None}).closed_loop_peak_db)


def test_frequency_response_is_frozen_and_keyword_built(force_cfg):
    from ehactl.tune import linear_response

    fr = linear_response(force_cfg, f_hz=np.geomspace(5, 500, 20))
    with pytest.raises(dataclasses.FrozenInstanceError):
        fr.unit = "m"  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        fr.plant[0] = 0
    g = fr.with_gains(force_cfg, {"control.pi.kp": 0.4, "control.pi.integral": 100.0})
    assert g.gains["control.pi.kp"] == 0.4 and fr.gains["control.pi.kp"] != 0.4
    np.testing.assert_array_equal(g.plant, fr.plant)
    r = repr(fr)
    assert r.startswith("FrequencyResponse(linear, 20 points") and "phase_margin_deg=" in r
    json.dumps(fr.to_dict(), allow_nan=False)
    pytest.importorskip("pandas")
    df = fr.to_pandas()
    assert df.index.name == "f_hz" and len(df) == 20
    np.testing.assert_allclose(df["loop"].to_numpy(), fr.loop)
