"""The Python API never overwrites a file of the user's, never aborts the interpreter on a
large duration, reads MCAP files with the CLI's bounded, checked reader, and names the field
in every refusal (the same rules as ``ehactl run --out`` / ``diagnose --data``)."""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import sys
import textwrap

import pytest

import ehactl
from conftest import CONFIGS


@pytest.fixture
def cfg_file(tmp_path):
    p = tmp_path / "x.toml"
    shutil.copy(CONFIGS / "sahu2022_force.toml", p)
    return p


def test_run_never_writes_over_the_config_or_a_file_that_is_not_a_log(cfg_file, tmp_path):
    before = cfg_file.read_bytes()
    with pytest.raises(ValueError, match="config being run"):
        ehactl.run(str(cfg_file), duration=0.01, mcap=str(cfg_file))
    with pytest.raises(ValueError, match="config being run"):
        ehactl.run(str(cfg_file), duration=0.01, mcap=str(cfg_file), overwrite=True)
    # a hard link to the config is the config too
    link = tmp_path / "link.mcap"
    os.link(cfg_file, link)
    with pytest.raises(ValueError, match="config being run"):
        ehactl.run(ehactl.Config.load(cfg_file), duration=0.01, mcap=link)
    assert cfg_file.read_bytes() == before

    notes = tmp_path / "notes.txt"
    notes.write_text("keep me\n")
    with pytest.raises(ValueError, match=r"notes\.txt: exists and is not an MCAP log.*overwrite=True"):
        ehactl.run(cfg_file, duration=0.01, mcap=notes)
    assert notes.read_text() == "keep me\n"
    with pytest.raises(ValueError, match="is a directory"):
        ehactl.run(cfg_file, duration=0.01, mcap=tmp_path)
    # explicit overwrite replaces it with a whole log
    r = ehactl.run(cfg_file, duration=0.01, mcap=notes, overwrite=True)
    assert r.summary.mcap == str(notes)
    assert notes.read_bytes()[:8] == b"\x89MCAP0\r\n"
    # an earlier MCAP log is replaced without the flag, as a re-run does
    ehactl.run(cfg_file, duration=0.02, mcap=notes)
    assert len(ehactl.read_mcap(notes)["control"]["t"]) == 100
    # no temporary file is left beside it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.mcap", "notes.txt", "x.toml"]


def test_run_many_applies_the_same_rules(cfg_file, tmp_path):
    d = tmp_path / "runs"
    d.mkdir()
    (d / "run_0001.mcap").write_text("not a log")
    with pytest.raises(ValueError, match=r"run_0001\.mcap: exists and is not an MCAP log"):
        ehactl.run_many([cfg_file, cfg_file], duration=0.01, mcap_dir=d)
    assert (d / "run_0001.mcap").read_text() == "not a log"
    assert not (d / "run_0000.mcap").exists()


def test_a_failed_run_leaves_the_earlier_log_in_place(cfg_file, tmp_path):
    log = tmp_path / "a.mcap"
    ehactl.run(cfg_file, duration=0.01, mcap=log)
    before = log.read_bytes()
    with pytest.raises(ValueError):
        ehactl.run(cfg_file, duration=0.01, mcap=log, fields=["bogus"])
    assert log.read_bytes() == before


def _in_subprocess(code: str) -> subprocess.CompletedProcess[str]:
    """Run `code` in a fresh interpreter: an abort there must not take pytest down."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize(
    "call",
    [
        "ehactl.run(cfg, duration=1e9)",
        "ehactl.run(cfg, duration=2**64)",
        "ehactl.run(cfg, duration=float('inf'))",
        "cfg['run.duration'] = 1e6; ehactl.run(cfg)",
        "ehactl.run_many([cfg, cfg], duration=1e5)",
    ],
)
def test_a_large_duration_is_a_value_error_naming_the_limit(call):
    r = _in_subprocess(
        f"""
        import ehactl
        cfg = ehactl.Config.load({str(CONFIGS / 'sahu2022_force.toml')!r})
        try:
            {call}
        except ValueError as e:
            print("VALUEERROR", e)
        """
    )
    assert r.returncode == 0, (r.returncode, r.stderr[-2000:])
    assert "VALUEERROR" in r.stdout, r.stdout
    assert "duration" in r.stdout and ("1e6 s" in r.stdout or "MB" in r.stdout), r.stdout


def _log(tmp_path):
    p = tmp_path / "good.mcap"
    ehactl.run(CONFIGS / "sahu2022_force.toml", duration=0.5, mcap=p)
    return p


def _first_chunk(b: bytes) -> int:
    pos = 8
    while b[pos] != 0x06:
        (n,) = struct.unpack_from("<Q", b, pos + 1)
        pos += 9 + n
    return pos


def test_read_mcap_reports_a_wrong_uncompressed_size_instead_of_hanging(tmp_path):
    b = bytearray(_log(tmp_path).read_bytes())
    c = _first_chunk(b)
    # chunk body: start time, end time (8 + 8), uncompressed size (8), …
    (u,) = struct.unpack_from("<Q", b, c + 9 + 16)
    struct.pack_into("<Q", b, c + 9 + 16, u + 4096)
    bad = tmp_path / "bad_size.mcap"
    bad.write_bytes(bytes(b))
    r = _in_subprocess(
        f"""
        import ehactl
        try:
            ehactl.read_mcap({str(bad)!r})
        except ValueError as e:
            print("VALUEERROR", e)
        """
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert f"decompresses to {u} bytes, its header says {u + 4096}" in r.stdout, r.stdout


def test_read_mcap_refuses_devices_and_fifos_without_blocking(tmp_path):
    with pytest.raises(ValueError, match="character device"):
        ehactl.read_mcap("/dev/zero")
    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    r = _in_subprocess(
        f"""
        import ehactl
        try:
            ehactl.read_mcap({str(fifo)!r})
        except ValueError as e:
            print("VALUEERROR", e)
        """
    )
    assert r.returncode == 0 and "FIFO" in r.stdout, (r.stdout, r.stderr[-1000:])


@pytest.mark.parametrize("bad", [None, [], "str", 3])
def test_run_summary_from_dict_refuses_what_is_not_a_mapping(bad):
    with pytest.raises(TypeError, match="expected a mapping"):
        ehactl.RunSummary.from_dict(bad)


def test_run_summary_from_dict_names_missing_and_bad_fields(force_cfg):
    with pytest.raises(ValueError, match="missing field.*cycles.*control_rate_hz.*duration_s"):
        ehactl.RunSummary.from_dict({})
    good = ehactl.run(force_cfg, duration=0.01).summary.to_dict()
    assert ehactl.RunSummary.from_dict(good).cycles == 50
    for key, value in [("cycles", "many"), ("control_rate_hz", -1.0), ("duration_s", None), ("rms_error", "x")]:
        with pytest.raises(ValueError, match=f"`{key}`"):
            ehactl.RunSummary.from_dict({**good, key: value})


def test_a_huge_integer_names_the_field(force_cfg):
    with pytest.raises(ValueError, match=r"config error at `control\.pi\.kp`: an integer of 401 digits"):
        force_cfg["control.pi.kp"] = 10**400
    with pytest.raises(ValueError, match=r"`control\.pi\.kp`"):
        force_cfg.with_values({"control.pi.kp": -(10**30)})
