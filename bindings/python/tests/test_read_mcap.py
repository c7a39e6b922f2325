"""ehactl.read_mcap (Rust mcap crate) against the official Python `mcap` reader."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import ehactl
from conftest import REPO


@pytest.fixture
def official_reader():
    pytest.importorskip("mcap")
    sys.path.insert(0, str(REPO / "tests" / "python"))
    try:
        import ehactl_mcap
    finally:
        sys.path.pop(0)
    return ehactl_mcap


@pytest.mark.parametrize("rig", ["sahu2022_force", "dindorf2022_boom"])
def test_every_channel_matches_the_official_reader(rig, official_reader, tmp_path):
    cfg = ehactl.Config.load(REPO / "configs" / f"{rig}.toml")
    p = tmp_path / f"{rig}.mcap"
    ehactl.run(cfg, duration=0.1, mcap=p)
    ours = ehactl.read_mcap(p)
    ref = official_reader.read_run(p)
    for topic in ("control", "plant"):
        assert set(ref[topic]) - {"_publish_time"} <= set(ours[topic])
        for k, v in ref[topic].items():
            if k == "_publish_time":
                continue
            np.testing.assert_array_equal(np.asarray(ours[topic][k]), np.asarray(v), err_msg=f"{topic}.{k}")
    assert ours["events"] == ref["events"]
    assert ours["summary"] == ref["summary"]
    assert ours["config"] == ref["config"]
    assert ours["metadata"] == ref["metadata"]
    assert ours["profile"] == ref["header"]["profile"]


def test_bad_files(tmp_path):
    with pytest.raises(OSError):
        ehactl.read_mcap(tmp_path / "missing.mcap")
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(ValueError, match="bad.mcap"):
        ehactl.read_mcap(bad)
