"""`ehactl.diagnose` with several records (a campaign) and `ehactl.predict` from Python: the
same compiled sessions as `ehactl diagnose --data … --data …` and `ehactl predict`, on the
repository's real MR-damper chirps at 0 A and 1 A."""
from __future__ import annotations

import json
import subprocess

import pytest

import ehactl
from conftest import CONFIGS, REPO

MTS = REPO / "tests" / "data" / "measured" / "utfsm_mts"
CHIRPS = [MTS / "0A_5to15s.csv", MTS / "1A_5to15s.csv"]


def test_a_list_of_records_is_a_campaign_and_its_law_predicts_them(tmp_path):
    cfg = ehactl.Config.load(CONFIGS / "utfsm_mts_mrdamper.toml")
    res = ehactl.diagnose(cfg, CHIRPS, out=tmp_path / "c")
    assert isinstance(res, ehactl.CampaignResult)
    assert "current" in res.cause
    assert res.nrmse < res.nrmse_nominal and res.nrmse < res.nrmse_arx
    assert {r["operating_point"]["current"] for r in res.records} == {0.0, 1.0}
    pred = ehactl.predict(res.extended_config, CHIRPS, imposed_motion=True, held_out=True)
    assert isinstance(pred, ehactl.PredictionResult) and len(pred.records) == 2
    for rp, rc in zip(pred.records, res.records):
        assert rp.replay == "imposed_motion"
        assert rp.channels["force"] == pytest.approx(rc["nrmse"]["law"], rel=1e-9)


def test_predict_matches_the_cli(tmp_path):
    ext = CONFIGS / "utfsm_mts_mrdamper.toml"
    py = ehactl.predict(ext, CHIRPS[1]).to_dict()
    cli = subprocess.run([str(REPO / "target" / "release" / "ehactl"), "predict", "--config", str(ext),
                          "--data", str(CHIRPS[1]), "--json"], capture_output=True, text=True, check=False)
    if cli.returncode != 0:
        pytest.skip(f"no CLI binary: {cli.stderr[:200]}")
    assert json.loads(cli.stdout)["nrmse"] == py["nrmse"]


def test_predict_refuses_a_missing_record(tmp_path):
    with pytest.raises(FileNotFoundError):
        ehactl.predict(CONFIGS / "utfsm_mts_mrdamper.toml", tmp_path / "nope.csv")


@pytest.mark.parametrize("data", [None, []])
def test_predict_without_a_record_raises_like_diagnose(data):
    cfg = CONFIGS / "utfsm_mts_mrdamper.toml"
    with pytest.raises(ValueError, match="no record to predict"):
        ehactl.predict(cfg, data)
    with pytest.raises(ValueError):
        ehactl.diagnose(cfg, data)


def test_predict_of_a_constant_force_raises_a_value_error_naming_it(tmp_path):
    lines = CHIRPS[0].read_text().splitlines()
    j = lines[0].split(",").index("force")
    flat = tmp_path / "flat.csv"
    flat.write_text("\n".join([lines[0]] + [",".join(f if k != j else "120.0" for k, f in enumerate(row.split(",")))
                                            for row in lines[1:]]) + "\n")
    with pytest.raises(ValueError, match=r"column `force` is constant .*standard deviation"):
        ehactl.predict(CONFIGS / "utfsm_mts_mrdamper.toml", flat, imposed_motion=True)
