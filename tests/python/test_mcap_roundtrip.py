"""Round-trip tests: run the real ehactl binary, read its MCAP log back with the official
``mcap`` reader (CRC validation on) and check it against the run's JSON summary.

The binary is ``$EHACTL_BIN`` or ``<repo>/target/release/ehactl``
(build it with ``cargo build --release -p ehactl-cli``).
"""

from __future__ import annotations

import itertools
import json
import os
import signal
import struct
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.stream_reader import CRCValidationError
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

import ehactl_mcap
from ehactl_mcap import CONTROL_FIELDS, PLANT_FIELDS, read_run

REPO = Path(__file__).resolve().parents[2]
CONFIGS = REPO / "configs"
FORCE_CONFIG = CONFIGS / "sahu2022_force.toml"
BOOM_CONFIG = CONFIGS / "dindorf2022_boom.toml"
RATE_HZ = 5000.0
SHORT_DURATION = 0.4

# The simulation is not paced to wall-clock time: it runs at roughly 60-110x real time
# here, so `--duration 60` finishes in about 0.6 s of wall time. The signal tests
# therefore ask for a much longer simulated run and send the signal once logging is
# visibly under way, well before the run could end by itself.
SIGNAL_RUN_DURATION = 600.0  # s simulated (several seconds of wall time)
SIGNAL_MIN_WALL = 0.3  # s of wall time the process must have run before the signal
SIGNAL_MIN_BYTES = 256 * 1024  # and this much MCAP must be on disk

# The byte layout of one message (the ros2msg schemas of crates/log/src/record.rs): CDR little-endian header, then
# /control: uint64 cycle + 16 float64; /plant: 16 float64 + bool. The reader derives its
# layout from the schema in the file; these pins keep the format itself from drifting.
CONTROL_STRUCT = struct.Struct("<4sQ16d")
PLANT_STRUCT = struct.Struct("<4s16d?")


def ehactl_bin() -> Path:
    path = Path(os.environ.get("EHACTL_BIN", REPO / "target" / "release" / "ehactl"))
    if not path.is_file() or not os.access(path, os.X_OK):
        pytest.fail(
            f"ehactl binary not found at {path}: build it with "
            "`cargo build --release -p ehactl-cli` or set EHACTL_BIN"
        )
    return path


def run_ehactl(config: Path, out: Path, duration: float, expect_rc: int = 0) -> dict:
    """Run `ehactl run CONFIG --duration D --out OUT --json`; return the parsed JSON."""
    proc = subprocess.run(
        [str(ehactl_bin()), "run", str(config), "--duration", repr(duration), "--out", str(out), "--json"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == expect_rc, (
        f"exit {proc.returncode} (expected {expect_rc})\nstdout: {proc.stdout}\nstderr: {proc.stderr}"
    )
    return parse_json_stdout(proc.stdout)


def parse_json_stdout(stdout: str) -> dict:
    lines = [line for line in stdout.splitlines() if line.strip()]
    assert len(lines) == 1, f"--json must print exactly one JSON object, got: {stdout!r}"
    return json.loads(lines[0])


def assert_cycles_contiguous(run: dict, n: int) -> None:
    """Both CDR channels hold exactly n messages, cycles and sequences 0..n-1 in order,
    t = cycle / rate, log_time = t in ns."""
    idx = np.arange(n, dtype=np.uint64)
    for topic in ("control", "plant"):
        ch = run[topic]
        assert len(ch["t"]) == n, f"/{topic}: {len(ch['t'])} messages, expected {n}"
        np.testing.assert_array_equal(ch["_sequence"], idx, err_msg=f"/{topic} sequence numbers")
        np.testing.assert_allclose(ch["t"], idx / RATE_HZ, rtol=0, atol=1e-9, err_msg=f"/{topic} t")
        if n > 1:
            np.testing.assert_allclose(np.diff(ch["t"]), 1.0 / RATE_HZ, rtol=0, atol=1e-12)
        log_t = ch["_log_time"].astype(np.int64)
        np.testing.assert_array_less(np.abs(log_t - np.round(ch["t"] * 1e9).astype(np.int64)), 2)
    np.testing.assert_array_equal(run["control"]["cycle"], idx, err_msg="/control cycle field")
    # /control t is exactly cycle / rate; /plant t is the plant's own clock, accumulated
    # substep by substep, so it drifts by float rounding (about 2e-11 s after 20 s): allow
    # up to 1 ns, the resolution of log_time.
    np.testing.assert_allclose(run["plant"]["t"], run["control"]["t"], rtol=0, atol=1e-9)


def assert_crcs_present(run: dict) -> None:
    """A zero CRC means 'not computed' and makes readers skip the check silently."""
    crcs = run["crcs"]
    assert crcs["chunk"], "no chunks seen in the linear CRC pass"
    assert all(c != 0 for c in crcs["chunk"]), f"chunk CRCs: {crcs['chunk']}"
    assert crcs["data_section"], "DataEnd data-section CRC is 0 / missing"
    assert crcs["summary"], "footer summary CRC is 0"
    assert len(crcs["chunk"]) == run["chunk_count"], "chunk index count != chunks in the file"


def assert_summary_matches(run: dict, js: dict, out: Path) -> None:
    summary = run["summary"]
    assert summary is not None, "no /summary message"
    n = js["cycles"]
    assert summary["cycles"] == n
    assert summary["records_written"] == n
    assert js["log"]["records_written"] == n
    assert js["log"]["records_dropped"] == 0
    assert js["log"]["events_written"] == len(run["events"])
    assert Path(js["mcap"]).resolve() == out.resolve()
    for key in ("control_rate_hz", "duration_s", "rms_error", "max_abs_error", "interrupted", "trip", "trip_kind"):
        assert summary[key] == js[key], f"/summary {key}={summary[key]!r} but stdout JSON {js[key]!r}"
    assert js["control_rate_hz"] == RATE_HZ
    assert js["duration_s"] == pytest.approx(n / RATE_HZ, abs=1e-9)
    # the error statistics recomputed from the logged /control records
    err = run["control"]["error"]
    if n:
        assert np.sqrt(np.mean(err**2)) == pytest.approx(js["rms_error"], rel=1e-9, abs=1e-12)
        assert np.max(np.abs(err)) == pytest.approx(js["max_abs_error"], rel=1e-12)
    stats = run["statistics_counts"]
    assert stats.get("/control") == n and stats.get("/plant") == n
    for topic, count in run["message_counts"].items():
        assert stats.get(topic) == count, f"Statistics count for {topic}"


def assert_layout(run: dict, rig_name: str) -> None:
    assert run["header"]["profile"] == "ros2"
    assert run["schemas"]["/control"] == ("ehactl_msgs/msg/ControlCycle", "ros2msg")
    assert run["schemas"]["/plant"] == ("ehactl_msgs/msg/PlantState", "ros2msg")
    for topic in ("/control", "/plant"):
        assert run["message_encodings"][topic] == "cdr"
    for topic in ("/config", "/events", "/summary"):
        assert run["schemas"][topic][1] == "jsonschema"
        assert run["message_encodings"][topic] == "json"
    assert run["message_counts"]["/config"] == 1
    assert run["message_counts"]["/summary"] == 1
    # /config parses and names the rig; so does the ehactl_run metadata record's TOML
    assert isinstance(run["config"], dict)
    assert run["config"]["config"]["rig"]["name"] == rig_name
    assert run["config_toml"] is not None, "no ehactl_run metadata with config_toml"
    assert run["config_toml"]["rig"]["name"] == rig_name
    for ev in run["events"]:
        assert {"kind", "severity", "t"} <= ev.keys(), ev


def ros2_cross_check(path: Path, run: dict, k: int = 5) -> None:
    """Decode the first and last k messages of each CDR channel with mcap_ros2 and
    compare every field with the schema-driven numpy decoding."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for topic, fields in (("/control", CONTROL_FIELDS), ("/plant", PLANT_FIELDS)):
            cols = run[topic.lstrip("/")]
            n = len(cols["t"])
            picks = list(itertools.islice(reader.iter_decoded_messages(topics=[topic]), k))
            picks += list(itertools.islice(reader.iter_decoded_messages(topics=[topic], reverse=True), k))
            assert picks, f"no {topic} messages decoded by mcap_ros2"
            for _schema, _channel, message, decoded in picks:
                i = int(message.sequence)
                assert 0 <= i < n
                for field in fields:
                    ours = cols[field][i]
                    theirs = getattr(decoded, field)
                    if field == "stuck":
                        assert bool(ours) == bool(theirs), f"{topic}[{i}].{field}"
                    else:
                        assert ours == theirs, f"{topic}[{i}].{field}: numpy {ours!r} vs mcap_ros2 {theirs!r}"
                # and the byte layout of the schemas holds: the format must not change
                # silently even if writer and schema change together
                layout = CONTROL_STRUCT if topic == "/control" else PLANT_STRUCT
                header, *values = layout.unpack(message.data)
                assert header == ehactl_mcap.CDR_LE_HEADER
                np.testing.assert_array_equal(
                    np.array(values, dtype=float), np.array([cols[f][i] for f in fields], dtype=float)
                )


@pytest.mark.parametrize(
    ("config", "rig_name"),
    [(FORCE_CONFIG, "sahu2022_force"), (BOOM_CONFIG, "dindorf2022_boom")],
    ids=["sahu2022_force", "dindorf2022_boom"],
)
def test_roundtrip(tmp_path: Path, config: Path, rig_name: str) -> None:
    out = tmp_path / f"{rig_name}.mcap"
    js = run_ehactl(config, out, SHORT_DURATION)
    n = round(SHORT_DURATION * RATE_HZ)
    assert js["cycles"] == n
    assert js["interrupted"] is False and js["trip"] is None

    run = read_run(out)  # chunk CRCs (indexed), data-section CRC (linear pass), summary CRC
    assert_crcs_present(run)
    assert_layout(run, rig_name)
    assert run["message_counts"]["/control"] == run["message_counts"]["/plant"] == n
    assert run["summary"]["cycles"] == n
    assert_cycles_contiguous(run, n)
    kinds = [ev["kind"] for ev in run["events"]]
    assert "start" in kinds and "end" in kinds, kinds
    assert run["events"][0]["kind"] == "start" and run["events"][0]["t"] == 0.0
    end = next(ev for ev in run["events"] if ev["kind"] == "end")
    assert end["t"] == pytest.approx(SHORT_DURATION, abs=1e-9)
    assert_summary_matches(run, js, out)
    assert not run["plant"]["stuck"].all()
    assert np.all(np.isfinite(run["control"]["command"]))
    ros2_cross_check(out, run)


def _chunk_offsets(path: Path):
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.chunk_indexes
    # the chunk holding the bulk of the /control and /plant records
    return max(summary.chunk_indexes, key=lambda ci: ci.compressed_size)


def test_corrupt_chunk_payload_is_rejected(tmp_path: Path) -> None:
    """Flip one byte in the middle of a chunk's compressed records: the CRC-validating
    reader must raise. (The LZ4 frames carry no content checksum of their own: the MCAP
    chunk CRC, or the LZ4 decoder on a broken sequence, is what notices.)"""
    good = tmp_path / "good.mcap"
    run_ehactl(FORCE_CONFIG, good, SHORT_DURATION)
    ci = _chunk_offsets(good)
    raw = bytearray(good.read_bytes())
    records_end = ci.chunk_start_offset + ci.chunk_length
    offset = records_end - ci.compressed_size // 2
    raw[offset] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(raw))

    with pytest.raises((CRCValidationError, McapError, RuntimeError, ValueError)):
        with open(bad, "rb") as f:
            for _ in make_reader(f, validate_crcs=True).iter_messages():
                pass
    with pytest.raises((CRCValidationError, McapError, RuntimeError, ValueError)):
        read_run(bad)


def test_corrupt_chunk_crc_is_detected_only_with_validation(tmp_path: Path) -> None:
    """Flip one byte of a chunk's uncompressed CRC field: the records still decompress
    fine, so only MCAP CRC validation can notice."""
    good = tmp_path / "good.mcap"
    run_ehactl(FORCE_CONFIG, good, SHORT_DURATION)
    ci = _chunk_offsets(good)
    raw = bytearray(good.read_bytes())
    # Chunk record: opcode u8, length u64, message_start_time u64, message_end_time u64,
    # uncompressed_size u64, uncompressed_crc u32, ...
    crc_at = ci.chunk_start_offset + 1 + 8 + 8 + 8 + 8
    (stored,) = struct.unpack_from("<I", raw, crc_at)
    assert stored != 0
    raw[crc_at] ^= 0x01
    bad = tmp_path / "bad_crc.mcap"
    bad.write_bytes(bytes(raw))

    with open(bad, "rb") as f:
        n = sum(1 for _ in make_reader(f, validate_crcs=False).iter_messages())
    assert n > 0
    with pytest.raises(CRCValidationError):
        with open(bad, "rb") as f:
            for _ in make_reader(f, validate_crcs=True).iter_messages():
                pass
    with pytest.raises(CRCValidationError):
        read_run(bad)


def _wait_until_logging(proc: subprocess.Popen, out: Path) -> float:
    t0 = time.monotonic()
    deadline = t0 + 30.0
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            stdout, stderr = proc.communicate()
            pytest.fail(
                f"ehactl exited ({proc.returncode}) before it could be signalled\n"
                f"stdout: {stdout}\nstderr: {stderr}"
            )
        elapsed = time.monotonic() - t0
        if elapsed >= SIGNAL_MIN_WALL and out.exists() and out.stat().st_size >= SIGNAL_MIN_BYTES:
            return elapsed
        time.sleep(0.01)
    proc.kill()
    proc.communicate()
    pytest.fail("ehactl did not start logging within 30 s")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_finalises_log(tmp_path: Path, sig: signal.Signals) -> None:
    out = tmp_path / "interrupted.mcap"
    proc = subprocess.Popen(
        [
            str(ehactl_bin()),
            "run",
            str(FORCE_CONFIG),
            "--duration",
            repr(SIGNAL_RUN_DURATION),
            "--out",
            str(out),
            "--json",
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _wait_until_logging(proc, out)
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, f"exit {proc.returncode}\nstdout: {stdout}\nstderr: {stderr}"
    js = parse_json_stdout(stdout)
    assert js["interrupted"] is True
    assert js["trip"] is None
    n = js["cycles"]
    assert 0 < n < round(SIGNAL_RUN_DURATION * RATE_HZ)

    run = read_run(out)
    assert_crcs_present(run)
    assert_layout(run, "sahu2022_force")
    assert run["message_counts"]["/control"] == run["message_counts"]["/plant"] == n
    assert run["summary"]["cycles"] == n
    assert run["summary"]["interrupted"] is True
    assert_cycles_contiguous(run, n)
    kinds = [ev["kind"] for ev in run["events"]]
    assert "start" in kinds and "signal" in kinds, kinds
    sig_ev = next(ev for ev in run["events"] if ev["kind"] == "signal")
    assert sig_ev["t"] == pytest.approx(n / RATE_HZ, abs=1e-9)
    assert_summary_matches(run, js, out)
    out.unlink()  # tens of MB; do not leave it in pytest's retained tmp dirs


def test_supervisor_trip_finalises_log(tmp_path: Path) -> None:
    text = FORCE_CONFIG.read_text()
    lines = text.splitlines(keepends=True)
    hits = [i for i, line in enumerate(lines) if line.lstrip().startswith("max_force")]
    assert len(hits) == 1, "expected exactly one max_force line in sahu2022_force.toml"
    lines[hits[0]] = "max_force = 100.0             # N (test: forces a supervisor trip)\n"
    config = tmp_path / "sahu2022_force_trip.toml"
    config.write_text("".join(lines))
    out = tmp_path / "trip.mcap"

    js = run_ehactl(config, out, SHORT_DURATION, expect_rc=3)
    assert js["trip"], js
    assert js["trip_kind"] == "force_limit"
    assert js["interrupted"] is False
    n = js["cycles"]
    assert n < round(SHORT_DURATION * RATE_HZ)

    run = read_run(out)  # finalised: footer, summary section, CRCs all present and valid
    assert_crcs_present(run)
    assert_layout(run, "sahu2022_force")
    assert run["config_toml"]["supervisor"]["max_force"] == 100.0
    assert run["summary"]["cycles"] == n
    assert run["summary"]["trip_kind"] == "force_limit"
    assert_cycles_contiguous(run, n)
    trips = [ev for ev in run["events"] if ev["kind"] == "force_limit"]
    assert trips, [ev["kind"] for ev in run["events"]]
    assert trips[0]["severity"] == "trip"
    assert "start" in [ev["kind"] for ev in run["events"]]
    assert_summary_matches(run, js, out)
