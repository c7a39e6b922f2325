"""Batches on a Dask ``LocalCluster`` (two worker processes, the same code a remote scheduler
would run): the numbers equal the local rayon path's exactly, results come back as pandas
DataFrames in input order, tuning and batch diagnosis accept the client."""

from __future__ import annotations

import numpy as np
import pytest

import ehactl
from ehactl import tune

from conftest import REPO

distributed = pytest.importorskip("dask.distributed")
pd = pytest.importorskip("pandas")


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=40
    )
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


def test_cluster_batch_equals_local_rayon(client, force_cfg):
    grid = {"control.pi.kp": [0.2, 0.4, 0.57], "control.pi.integral": [200.0, 386.24]}
    local = ehactl.run_many(grid, base=force_cfg, duration=0.2)
    remote = ehactl.run_many(grid, base=force_cfg, duration=0.2, client=client, frame=False, chunk_size=2)
    assert len(remote) == len(local) == 6
    for a, b in zip(local, remote):
        assert a.config["control.pi.kp"] == b.config["control.pi.kp"]
        assert a.config["control.pi.integral"] == b.config["control.pi.integral"]
        for col in ("force", "u", "x", "p_a"):
            np.testing.assert_array_equal(a[col], b[col])
        assert a.summary.rms_error == b.summary.rms_error
    # different gains, different runs: the comparison is not between identical runs
    assert local[0].summary.rms_error != local[-1].summary.rms_error
    # both workers took part
    assert len(client.scheduler_info()["workers"]) == 2


def test_cluster_batch_returns_a_dataframe_in_grid_order(client, force_cfg):
    grid = {"control.pi.kp": [0.3, 0.4, 0.5, 0.6, 0.7]}
    df = ehactl.run_many(grid, base=force_cfg, duration=0.1, client=client)
    assert isinstance(df, pd.DataFrame)
    assert list(df["control.pi.kp"]) == grid["control.pi.kp"]
    local = ehactl.run_many(grid, base=force_cfg, duration=0.1, frame=True)
    pd.testing.assert_frame_equal(df, local)
    assert (df["error_unit"] == "N").all() and df["trip"].isna().all()


def test_tuning_on_the_cluster_gives_the_local_gains(client, force_cfg):
    kw = dict(generations=2, population=6, refine=1, seed=3)
    a = tune.optimize(force_cfg, "itae", **kw)
    b = tune.optimize(force_cfg, "itae", client=client, **kw)
    assert a.gains == b.gains
    assert a.metrics["itae"] == b.metrics["itae"]


def test_diagnose_many_on_the_cluster(client, tmp_path):
    # a small fleet: two 0.5 s logs of the diagnosis test rig, one with a hidden 5 ms delay
    rig = REPO / "configs/diagnose_testrig.toml"
    nominal = ehactl.Config.load(rig)
    delayed = ehactl.Config.from_toml(nominal.to_toml() + "\n[effects.time_delay]\ndelay = 0.005\n")
    logs = []
    for name, cfg in (("nominal", nominal), ("delayed", delayed)):
        ehactl.run(cfg, duration=0.5, mcap=tmp_path / f"{name}.mcap")
        logs.append(tmp_path / f"{name}.mcap")
    cases = [{"config": rig, "data": f} for f in logs]
    remote = ehactl.diagnose_many(cases, client=client)
    local = ehactl.diagnose_many(cases)
    assert list(remote["data"]) == [str(f) for f in logs]
    pd.testing.assert_frame_equal(remote, local)
    assert remote["nrmse_nominal"].notna().all()
    # the delayed rig fits the nominal model worse than the nominal one
    assert remote["nrmse_nominal"][1] > remote["nrmse_nominal"][0]


def test_a_campaign_case_on_the_cluster_equals_the_local_campaign(client):
    # the repository's real MR-damper chirps at 0 A and 1 A as one campaign, beside a
    # single-record case of the same press
    mts = REPO / "tests" / "data" / "measured" / "utfsm_mts"
    cfg = REPO / "configs" / "utfsm_mts_mrdamper.toml"
    chirps = [mts / "0A_5to15s.csv", mts / "1A_5to15s.csv"]
    cases = [{"config": cfg, "data": chirps}, (cfg, chirps[1])]
    remote = ehactl.diagnose_many(cases, client=client)
    local = ehactl.diagnose_many(cases)
    pd.testing.assert_frame_equal(remote, local)
    assert list(remote["mode"]) == ["campaign", "record"]
    assert remote["data"][0] == ";".join(str(p) for p in chirps)
    direct = ehactl.diagnose(cfg, chirps)
    assert remote["cause"][0] == direct.cause and "current" in direct.cause
    assert remote["nrmse_extended"][0] == direct.nrmse
    assert remote["nrmse_nominal"][0] == direct.nrmse_nominal


def test_bad_client_and_missing_file(force_cfg, tmp_path):
    with pytest.raises(TypeError, match="dask.distributed.Client"):
        ehactl.run_many([force_cfg], duration=0.01, client=object())
    with pytest.raises(FileNotFoundError):
        ehactl.diagnose_many([(REPO / "configs/utfsm_mts_mrdamper.toml", tmp_path / "nope.csv")])
    with pytest.raises(FileNotFoundError):
        ehactl.diagnose_many([(REPO / "configs/utfsm_mts_mrdamper.toml", [tmp_path / "nope.csv"])])


def test_monte_carlo_example_runs(tmp_path):
    import csv
    import subprocess
    import sys

    ex = REPO / "bindings/python/examples/monte_carlo_dask.py"
    r = subprocess.run([sys.executable, str(ex), "--samples", "6", "--workers", "2", "--duration", "0.2",
                        "--out", str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = list(csv.DictReader(open(tmp_path / "monte_carlo.csv")))
    assert len(rows) == 6
    pms = sorted(float(x["phase_margin_deg"]) for x in rows)
    # tuned for 60° on the nominal rig: the sampled rigs spread around it
    assert 45.0 < pms[len(pms) // 2] < 75.0, pms
    assert len({x["fluid.bulk_modulus"] for x in rows}) == 6  # every rig drawn anew
    assert all(float(x["rms_error"]) > 0 for x in rows)
