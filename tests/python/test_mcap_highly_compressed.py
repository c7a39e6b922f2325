"""A valid MCAP file that compresses far more than 4096:1 (one message of a 10 MB string of
one character, zstd), written by the official `mcap` Python writer: ehactl's readers take it
(the chunk's declared uncompressed size is checked against a documented maximum, not against
a fixed ratio), as the official reader does with its CRC checks."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
BIG = "a" * 10_000_000


def write_official(path: Path) -> None:
    """Two JSON messages, the second holding BIG, in zstd chunks of the official writer."""
    pytest.importorskip("zstandard")
    from mcap.writer import CompressionType, Writer

    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="", library="official-python-writer")
        sid = w.register_schema("S", "jsonschema", b"{}")
        cid = w.register_channel("/text", "json", sid)
        w.add_message(cid, log_time=1000, data=b'{"s": "x"}', publish_time=1000, sequence=1)
        w.add_message(cid, log_time=2000, data=json.dumps({"s": BIG}).encode(), publish_time=2000, sequence=2)
        w.finish()


def official_messages(path: Path) -> list[bytes]:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [m.data for _s, _c, m in make_reader(f, validate_crcs=True).iter_messages()]


def test_recover_reads_a_highly_compressed_chunk_of_the_official_writer(tmp_path):
    src, out = tmp_path / "big.mcap", tmp_path / "copy.mcap"
    write_official(src)
    size = src.stat().st_size
    assert size * 4096 < len(BIG), f"{size} bytes: not compressed beyond 4096:1"
    assert json.loads(official_messages(src)[1])["s"] == BIG
    r = subprocess.run([BIN, "recover", str(src), str(out), "--json"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["bad_chunks"] == 0 and rep["messages"] == {"/text": 2}, rep
    assert official_messages(out) == official_messages(src)
