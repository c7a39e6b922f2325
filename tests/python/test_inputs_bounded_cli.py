"""Every reader of the CLI is bounded and every refusal is clear: `ehactl recover` keeps the
schema and channel records after a flipped byte outside the chunks, refuses FIFOs and
devices without blocking, fails when nothing is recovered, says when a running ehactl still
writes the log; `diagnose --data` quotes a few hundred bytes of an overlong line; `run
--duration` has the range of `run.duration`. Logs are read back with the official reader."""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

REPO = Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
RIG = REPO / "configs" / "diagnose_testrig.toml"
FORCE = REPO / "configs" / "sahu2022_force.toml"


def ehactl(*args: object, timeout: float = 60, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([BIN, *map(str, args)], capture_output=True, text=True, timeout=timeout, **kw)


def _footerless_log(tmp: Path) -> bytes:
    """A log cut where a killed writer leaves it: the data section up to its DataEnd, no
    summary, no footer (what a SIGKILLed `--realtime` run leaves)."""
    out = tmp / "full.mcap"
    r = ehactl("run", RIG, "--duration", "1", "--out", out)
    assert r.returncode == 0, r.stderr
    data = out.read_bytes()
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
    return data[:summary_start]


def _count(data: bytes) -> int:
    return sum(1 for _ in make_reader(io.BytesIO(data), validate_crcs=True).iter_messages(log_time_order=False))


@pytest.mark.parametrize("at, bit", [(25, 0x01), (25, 0x40), (9, 0x20), (22, 0x08)])
def test_recover_keeps_schemas_and_channels_after_a_flipped_byte_outside_chunks(tmp_path, at, bit):
    good = _footerless_log(tmp_path)
    (tmp_path / "good.mcap").write_bytes(good)
    r = ehactl("recover", tmp_path / "good.mcap", tmp_path / "good.rec.mcap", "--json")
    assert r.returncode == 0, r.stderr
    want = json.loads(r.stdout)["messages_total"]
    bad = bytearray(good)
    bad[at] ^= bit  # inside the Header record (its length, the profile or library string)
    (tmp_path / "bad.mcap").write_bytes(bytes(bad))
    fixed = tmp_path / "bad.rec.mcap"
    r = ehactl("recover", tmp_path / "bad.mcap", fixed, "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["messages_without_channel"] == 0, rep
    assert rep["messages_total"] == want and _count(fixed.read_bytes()) == want, rep


@pytest.mark.parametrize("kind", ["fifo", "dev_zero", "directory"])
def test_recover_refuses_what_is_not_a_regular_file_at_once(tmp_path, kind):
    src = {"dev_zero": Path("/dev/zero"), "directory": tmp_path}.get(kind, tmp_path / "pipe.mcap")
    if kind == "fifo":
        os.mkfifo(src)
    t0 = time.monotonic()
    r = ehactl("recover", src, tmp_path / "out.mcap", timeout=20)
    assert r.returncode == 2, r.stderr
    assert "not a regular file" in r.stderr and str(src) in r.stderr, r.stderr
    assert time.monotonic() - t0 < 10 and not (tmp_path / "out.mcap").exists()


def test_recover_fails_when_nothing_is_recovered(tmp_path):
    good = _footerless_log(tmp_path)
    # the magic and the header, then garbage where every chunk was
    header_end = 8 + 9 + struct.unpack_from("<Q", good, 9)[0]
    bad = good[:header_end] + bytes(range(256)) * 64
    (tmp_path / "bad.mcap").write_bytes(bad)
    r = ehactl("recover", tmp_path / "bad.mcap", tmp_path / "out.mcap")
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert "no message could be recovered" in r.stderr
    assert not (tmp_path / "out.mcap").exists()


def test_recover_says_a_running_ehactl_still_writes_the_log(tmp_path):
    log = tmp_path / "live.mcap"
    p = subprocess.Popen([BIN, "run", str(FORCE), "--realtime", "--duration", "6", "--out", str(log)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and (not log.exists() or log.stat().st_size < 200_000):
            time.sleep(0.1)
        r = ehactl("recover", log, tmp_path / "snap.mcap", "--json")
    finally:
        p.terminate()
        p.wait(timeout=30)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["writer_active"] is True
    assert "still being written by a running ehactl" in r.stderr, r.stderr


@pytest.mark.parametrize(
    "content, expected",
    [
        # 20 MB of NULs, one "line": refused at its first byte.
        (b"\0" * 20_000_000, "line 1 has a NUL byte at byte 1 of the line (byte 0 of the file)"),
        # A header, then a 20 MB "line" of digits: refused after 64 KiB of it.
        (b"t,u\n" + b"9" * 20_000_000, "line 2 is longer than the 65536 bytes a CSV line may have"),
    ],
    ids=["nul", "overlong"],
)
def test_diagnose_refuses_a_binary_or_overlong_line_quoting_a_few_hundred_bytes(tmp_path, content, expected):
    data = tmp_path / "bad.csv"
    data.write_bytes(content)
    r = ehactl("diagnose", "--config", RIG, "--data", data, "--out", tmp_path / "d")
    assert r.returncode == 2, r.stderr[:2000]
    assert expected in r.stderr, r.stderr[:2000]
    assert len(r.stderr) < 2_000, len(r.stderr)


@pytest.mark.parametrize("duration", ["1e9", "1000001"])
def test_run_duration_has_the_range_of_run_duration(tmp_path, duration):
    r = ehactl("run", FORCE, "--duration", duration, "--out", tmp_path / "a.mcap")
    assert r.returncode == 2, r.stderr
    assert "--duration " in r.stderr and "at most 1e6 s" in r.stderr, r.stderr
    assert not (tmp_path / "a.mcap").exists()
