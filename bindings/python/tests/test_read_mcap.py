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


@pytest.mark.skipif(not __import__("os").environ.get("EHACTL_BIN"), reason="EHACTL_BIN (the CLI binary) not set")
def test_realtime_log_timing_channel_matches_official_reader(tmp_path):
    """A wall-clock run of the CLI adds /timing (uint64, float64s, uint32, bool): decoded
    from its own schema, it must equal a struct decode of the official reader's bytes."""
    import os
    import struct
    import subprocess

    pytest.importorskip("mcap")
    from mcap.reader import make_reader

    p = tmp_path / "rt.mcap"
    subprocess.run(
        [os.environ["EHACTL_BIN"], "run", str(REPO / "configs" / "sahu2022_force.toml"), "--duration", "0.05",
         "--realtime", "--out", str(p), "--json"],
        capture_output=True, check=True,
    )
    ours = ehactl.read_mcap(p)["timing"]
    rec = struct.Struct("<4sQ5dI?")
    rows = []
    with open(p, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages(topics=["/timing"]):
            rows.append(rec.unpack(msg.data[: rec.size]))
    assert len(rows) == len(ours["cycle"]) == 250
    np.testing.assert_array_equal(ours["cycle"], [r[1] for r in rows])
    np.testing.assert_array_equal(ours["lateness_us"], [r[4] for r in rows])
    np.testing.assert_array_equal(ours["skipped"], [r[7] for r in rows])
    np.testing.assert_array_equal(ours["overrun"], [r[8] for r in rows])
    assert ours["overrun"].dtype == bool
