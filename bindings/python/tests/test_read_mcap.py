"""ehactl.read_mcap (the Rust decoder of ehactl-log) against the official Python readers:
`mcap` for the container and `mcap_ros2` for the CDR payloads (decoded from the ros2msg
schema the log publishes), so nothing here shares code or layout knowledge with ehactl."""

from __future__ import annotations

import json

import numpy as np
import pytest

import ehactl
from conftest import REPO


def official_read(path):
    """{topic: {field: array}} of the CDR channels and {topic: [parsed JSON]} of the JSON
    ones, plus metadata and header, read by the official mcap / mcap_ros2 packages."""
    pytest.importorskip("mcap")
    pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    cdr: dict[str, dict[str, list]] = {}
    js: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        for _schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.message_encoding == "json":
                js.setdefault(channel.topic, []).append(json.loads(message.data))
        summary = reader.get_summary()
        cdr_topics = [c.topic for c in summary.channels.values() if c.message_encoding == "cdr"]
        for _schema, channel, message, decoded in reader.iter_decoded_messages(
            topics=cdr_topics, log_time_order=False
        ):
            cols = cdr.setdefault(channel.topic, {"_sequence": [], "_log_time": []})
            for name in decoded.__slots__:
                cols.setdefault(name, []).append(getattr(decoded, name))
            cols["_sequence"].append(message.sequence)
            cols["_log_time"].append(message.log_time)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return {"cdr": cdr, "json": js, "metadata": metadata, "profile": header.profile}


@pytest.mark.parametrize("rig", ["sahu2022_force", "dindorf2022_boom"])
def test_every_channel_matches_the_official_reader(rig, tmp_path):
    cfg = ehactl.Config.load(REPO / "configs" / f"{rig}.toml")
    p = tmp_path / f"{rig}.mcap"
    ehactl.run(cfg, duration=0.1, mcap=p)
    ours = ehactl.read_mcap(p)
    ref = official_read(p)
    assert set(ref["cdr"]) == {"/control", "/plant"}
    for topic, cols in ref["cdr"].items():
        mine = ours[topic.lstrip("/")]
        assert set(cols) == set(mine), topic
        for k, v in cols.items():
            np.testing.assert_array_equal(np.asarray(mine[k]), np.asarray(v), err_msg=f"{topic}.{k}")
        assert len(mine["t"]) == 500  # 0.1 s at 5 kHz
    assert ours["events"] == ref["json"]["/events"]
    assert ours["summary"] == ref["json"]["/summary"][-1]
    assert ours["config"] == ref["json"]["/config"][0]
    assert ours["metadata"] == ref["metadata"]
    assert ours["profile"] == ref["profile"]


def test_corrupt_payload_is_a_clear_error(tmp_path):
    """A /control message cut short inside a valid MCAP file: the one decoder names the
    topic, the size found and the size its schema needs."""
    pytest.importorskip("mcap")
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    src = tmp_path / "ok.mcap"
    ehactl.run(ehactl.Config.load(REPO / "configs" / "sahu2022_force.toml"), duration=0.01, mcap=src)
    bad = tmp_path / "short.mcap"
    with open(src, "rb") as f, open(bad, "wb") as g:
        reader = make_reader(f)
        summary = reader.get_summary()
        w = Writer(g, compression=CompressionType.LZ4)
        w.start(profile="ros2", library="test")
        ids = {}
        for sid, s in summary.schemas.items():
            ids[sid] = w.register_schema(s.name, s.encoding, s.data)
        chans = {}
        for cid, c in summary.channels.items():
            chans[cid] = w.register_channel(c.topic, c.message_encoding, ids.get(c.schema_id, 0))
        for _s, c, m in reader.iter_messages():
            data = m.data[:100] if c.topic == "/control" else m.data
            w.add_message(chans[c.id], m.log_time, data, m.publish_time, m.sequence)
        w.finish()
    with pytest.raises(ValueError, match=r"short\.mcap: .*/control message of 100 bytes; expected 140"):
        ehactl.read_mcap(bad)


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


def test_a_highly_compressed_file_of_the_official_writer_reads(tmp_path):
    """One message of a 10 MB string of one character compresses far beyond 4096:1 with
    zstd; the official writer makes the file and the official reader (CRC checks on) reads
    it, so must ehactl.read_mcap: a chunk is bounded by its declared size against a documented
    maximum, not by a fixed ratio."""
    pytest.importorskip("zstandard")
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    big = json.dumps({"s": "a" * 10_000_000}).encode()
    p = tmp_path / "big.mcap"
    with open(p, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="", library="official-python-writer")
        cid = w.register_channel("/text", "json", w.register_schema("S", "jsonschema", b"{}"))
        w.add_message(cid, log_time=1000, data=b'{"s": "x"}', publish_time=1000, sequence=1)
        w.add_message(cid, log_time=2000, data=big, publish_time=2000, sequence=2)
        w.finish()
    assert p.stat().st_size * 4096 < len(big)
    with open(p, "rb") as f:
        ref = [json.loads(m.data) for _s, _c, m in make_reader(f, validate_crcs=True).iter_messages()]
    ours = ehactl.read_mcap(p)
    assert ours["text"] == ref
