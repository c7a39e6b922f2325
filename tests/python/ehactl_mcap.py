"""Read an ehactl MCAP log back into numpy arrays.

Uses the official ``mcap`` package (``mcap.reader.make_reader``) with chunk CRC
validation on, and decodes the ROS 2 CDR payloads of ``/control`` and ``/plant``
by hand with numpy (every field is 8 bytes wide and starts 8-aligned after the
4-byte encapsulation header, so there is no padding; ``/plant`` ends in one
``bool`` byte).

    run = read_run("out/sahu2022_force.mcap")
    run["control"]["t"]          # float64 array, one entry per cycle
    run["control"]["_sequence"]  # MCAP message sequence numbers
    run["events"]                # list of dicts from /events
    run["summary"]["cycles"]

Besides the chunk CRCs checked by the indexed (seeking) reader, ``read_run`` by
default also makes one linear ``StreamReader`` pass with ``validate_crcs=True``,
which checks the data-section CRC in the DataEnd record, and it checks the
footer's summary CRC itself (the ``mcap`` package does not). A CRC field that is
zero means "not computed" and would silently skip a check, so ``read_run``
reports them in ``run["crcs"]`` for callers to assert on.
"""

from __future__ import annotations

import json
import struct
import tomllib
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap.records import Chunk, DataEnd, Footer
from mcap.stream_reader import StreamReader, get_chunk_data_stream

CDR_LE_HEADER = b"\x00\x01\x00\x00"  # CDR, little endian, options 0

CONTROL_SCHEMA = "ehactl_msgs/msg/ControlCycle"
PLANT_SCHEMA = "ehactl_msgs/msg/PlantState"

CONTROL_FIELDS: tuple[str, ...] = (
    "cycle",
    "t",
    "setpoint",
    "setpoint_rate",
    "feedback",
    "error",
    "command",
    "command_unsat",
    "p_term",
    "i_term",
    "d_term",
    "ff_term",
    "force",
    "position",
    "p_a",
    "p_b",
    "spool",
)

PLANT_FIELDS: tuple[str, ...] = (
    "t",
    "command",
    "spool",
    "spool_velocity",
    "p_a",
    "p_b",
    "p_s",
    "x",
    "v",
    "x_load",
    "v_load",
    "q_a",
    "q_b",
    "friction",
    "external",
    "rod_force",
    "stuck",
)

CONTROL_DTYPE = np.dtype(
    [("_cdr_header", "V4"), ("cycle", "<u8")] + [(f, "<f8") for f in CONTROL_FIELDS[1:]]
)
PLANT_DTYPE = np.dtype(
    [("_cdr_header", "V4")] + [(f, "<f8") for f in PLANT_FIELDS[:-1]] + [("stuck", "u1")]
)
assert CONTROL_DTYPE.itemsize == 4 + 17 * 8
assert PLANT_DTYPE.itemsize == 4 + 16 * 8 + 1

# struct formats for one message, used for single-message decoding and cross-checks
CONTROL_STRUCT = struct.Struct("<4sQ16d")
PLANT_STRUCT = struct.Struct("<4s16d?")

# /timing: wall-clock runs only (`ehactl run --realtime`); empty otherwise.
TIMING_SCHEMA = "ehactl_msgs/msg/CycleTiming"
TIMING_FIELDS: tuple[str, ...] = (
    "cycle",
    "t",
    "wall_t",
    "lateness_us",
    "period_us",
    "exec_prev_us",
    "skipped",
    "overrun",
    "overrun_exec",
)
TIMING_DTYPE = np.dtype(
    [("_cdr_header", "V4"), ("cycle", "<u8")]
    + [(f, "<f8") for f in TIMING_FIELDS[1:6]]
    + [("skipped", "<u4"), ("overrun", "u1"), ("overrun_exec", "u1")]
)
assert TIMING_DTYPE.itemsize == 4 + 8 + 5 * 8 + 4 + 1 + 1

CDR_TOPICS = {
    "/control": (CONTROL_SCHEMA, CONTROL_DTYPE),
    "/plant": (PLANT_SCHEMA, PLANT_DTYPE),
    "/timing": (TIMING_SCHEMA, TIMING_DTYPE),
}
JSON_TOPICS = ("/config", "/events", "/summary")


class McapContentError(ValueError):
    """The file is valid MCAP but its content does not match the ehactl layout."""


def decode_control(data: bytes) -> dict[str, Any]:
    """Decode one /control CDR payload into a dict (struct-based, for spot checks)."""
    if len(data) != CONTROL_STRUCT.size:
        raise McapContentError(f"/control payload is {len(data)} bytes, expected {CONTROL_STRUCT.size}")
    header, *values = CONTROL_STRUCT.unpack(data)
    if header != CDR_LE_HEADER:
        raise McapContentError(f"/control CDR header {header.hex()} != {CDR_LE_HEADER.hex()}")
    return dict(zip(CONTROL_FIELDS, values))


def decode_plant(data: bytes) -> dict[str, Any]:
    """Decode one /plant CDR payload into a dict (struct-based, for spot checks)."""
    if len(data) != PLANT_STRUCT.size:
        raise McapContentError(f"/plant payload is {len(data)} bytes, expected {PLANT_STRUCT.size}")
    header, *values = PLANT_STRUCT.unpack(data)
    if header != CDR_LE_HEADER:
        raise McapContentError(f"/plant CDR header {header.hex()} != {CDR_LE_HEADER.hex()}")
    return dict(zip(PLANT_FIELDS, values))


def _decode_cdr_column(topic: str, dtype: np.dtype, payloads: list[bytes]) -> dict[str, np.ndarray]:
    sizes = {len(p) for p in payloads}
    if sizes and sizes != {dtype.itemsize}:
        raise McapContentError(f"{topic}: payload sizes {sorted(sizes)}, expected {dtype.itemsize}")
    arr = np.frombuffer(b"".join(payloads), dtype=dtype)
    if len(arr) and not np.all(arr["_cdr_header"] == np.void(CDR_LE_HEADER)):
        raise McapContentError(f"{topic}: a CDR encapsulation header is not {CDR_LE_HEADER.hex()}")
    out = {name: arr[name].copy() for name in dtype.names if name != "_cdr_header"}
    if "stuck" in out:
        if np.any(out["stuck"] > 1):
            raise McapContentError(f"{topic}: bool 'stuck' has a byte other than 0/1")
        out["stuck"] = out["stuck"].astype(bool)
    for flag in ("overrun", "overrun_exec"):
        if flag in out:
            if np.any(out[flag] > 1):
                raise McapContentError(f"{topic}: bool '{flag}' has a byte other than 0/1")
            out[flag] = out[flag].astype(bool)
    return out


def _linear_crc_pass(path: Path) -> dict[str, Any]:
    """One sequential pass with validate_crcs=True: checks every chunk CRC and the
    data-section CRC (DataEnd); returns what it saw."""
    chunk_crcs: list[int] = []
    data_section_crc = None
    footer = None
    with open(path, "rb") as f:
        for record in StreamReader(f, emit_chunks=True, validate_crcs=True).records:
            if isinstance(record, Chunk):
                chunk_crcs.append(record.uncompressed_crc)
                # emit_chunks=True hands chunks back undecoded; decode them here so
                # their CRC is checked in this pass too.
                get_chunk_data_stream(record, validate_crc=True)
            elif isinstance(record, DataEnd):
                data_section_crc = record.data_section_crc
            elif isinstance(record, Footer):
                footer = record
    return {"chunk_crcs": chunk_crcs, "data_section_crc": data_section_crc, "footer": footer}


def check_summary_crc(path: Path) -> int:
    """Verify the Footer's summary CRC (crc32 of the bytes from summary_start up to and
    including the footer's summary_offset_start field). Returns the stored value; 0 means
    'not computed'. Raises McapContentError on a mismatch."""
    raw = Path(path).read_bytes()
    # file ends: ... Footer(op 1 + len 8 + summary_start 8 + summary_offset_start 8 + crc 4) + magic 8
    if len(raw) < 8 + 29 + 8:
        raise McapContentError("file too short for header and footer")
    footer = raw[-(8 + 29) : -8]
    opcode, length, summary_start, _summary_offset_start, summary_crc = struct.unpack("<BQQQI", footer)
    if opcode != 0x02 or length != 20:
        raise McapContentError(f"footer record not where expected (opcode {opcode:#x}, length {length})")
    if summary_crc != 0 and summary_start != 0:
        actual = zlib.crc32(raw[summary_start : len(raw) - 8 - 4])
        if actual != summary_crc:
            raise McapContentError(f"summary CRC mismatch: stored {summary_crc:#010x}, computed {actual:#010x}")
    return summary_crc


def read_run(path: str | Path, validate_crcs: bool = True, full_crc_pass: bool = True) -> dict[str, Any]:
    """Read an ehactl MCAP file.

    Returns a dict with:
      control, plant, timing: dict field -> numpy array (plus _sequence, _log_time,
      _publish_time); timing is empty unless the run was paced in real time
      config: parsed /config JSON (first message); events: list of /events dicts;
      summary: parsed /summary JSON (last message); metadata: {name: {key: value}};
      config_toml: parsed TOML from the ehactl_run metadata record (None if absent);
      header: {profile, library}; schemas: {topic: (schema name, encoding)};
      message_encodings: {topic: encoding}; statistics_counts: {topic: count} from the
      summary's Statistics record; message_counts: {topic: count actually read};
      crcs: {chunk: [...], data_section: int, summary: int} (0 = not computed).
    """
    path = Path(path)
    payloads: dict[str, list[bytes]] = {t: [] for t in CDR_TOPICS}
    seq: dict[str, list[int]] = {t: [] for t in CDR_TOPICS}
    log_time: dict[str, list[int]] = {t: [] for t in CDR_TOPICS}
    pub_time: dict[str, list[int]] = {t: [] for t in CDR_TOPICS}
    json_msgs: dict[str, list[Any]] = {t: [] for t in JSON_TOPICS}
    counts: dict[str, int] = {}
    schemas: dict[str, tuple[str, str]] = {}
    encodings: dict[str, str] = {}

    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=validate_crcs)
        header = reader.get_header()
        summary_rec = reader.get_summary()
        # File order (chunk by chunk) rather than a log-time merge: cheaper, and the
        # sequence check below then also tests the writer's ordering.
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            if topic not in schemas:
                schemas[topic] = (schema.name if schema else "", schema.encoding if schema else "")
                encodings[topic] = channel.message_encoding
            if topic in CDR_TOPICS:
                payloads[topic].append(message.data)
                seq[topic].append(message.sequence)
                log_time[topic].append(message.log_time)
                pub_time[topic].append(message.publish_time)
            elif topic in JSON_TOPICS:
                json_msgs[topic].append(json.loads(message.data))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}

    out: dict[str, Any] = {
        "path": str(path),
        "header": {"profile": header.profile, "library": header.library},
        "schemas": schemas,
        "message_encodings": encodings,
        "message_counts": counts,
        "metadata": metadata,
    }
    for topic, (schema_name, dtype) in CDR_TOPICS.items():
        if topic in schemas and schemas[topic][0] != schema_name:
            raise McapContentError(f"{topic}: schema {schemas[topic][0]!r}, expected {schema_name!r}")
        cols = _decode_cdr_column(topic, dtype, payloads[topic])
        cols["_sequence"] = np.asarray(seq[topic], dtype=np.uint64)
        cols["_log_time"] = np.asarray(log_time[topic], dtype=np.uint64)
        cols["_publish_time"] = np.asarray(pub_time[topic], dtype=np.uint64)
        out[topic.lstrip("/")] = cols

    out["config"] = json_msgs["/config"][0] if json_msgs["/config"] else None
    out["events"] = json_msgs["/events"]
    out["summary"] = json_msgs["/summary"][-1] if json_msgs["/summary"] else None
    toml_text = metadata.get("ehactl_run", {}).get("config_toml")
    out["config_toml"] = tomllib.loads(toml_text) if toml_text is not None else None

    stats_counts: dict[str, int] = {}
    if summary_rec is not None and summary_rec.statistics is not None:
        for cid, n in summary_rec.statistics.channel_message_counts.items():
            stats_counts[summary_rec.channels[cid].topic] = n
    out["statistics_counts"] = stats_counts
    out["chunk_count"] = len(summary_rec.chunk_indexes) if summary_rec is not None else None

    crcs: dict[str, Any] = {"chunk": None, "data_section": None, "summary": None}
    if full_crc_pass and validate_crcs:
        seen = _linear_crc_pass(path)
        crcs["chunk"] = seen["chunk_crcs"]
        crcs["data_section"] = seen["data_section_crc"]
    if validate_crcs:
        crcs["summary"] = check_summary_crc(path)
    out["crcs"] = crcs
    return out


__all__ = [
    "CONTROL_FIELDS",
    "PLANT_FIELDS",
    "TIMING_FIELDS",
    "McapContentError",
    "check_summary_crc",
    "decode_control",
    "decode_plant",
    "read_run",
]


def read_can(path: str | Path, require_channel: bool = True) -> list[dict[str, Any]]:
    """Every record of the raw CAN channel `/can` (official `mcap` reader, JSON payloads).
    The channel is created with the first frame: `require_channel` asserts it exists."""
    frames = []
    with open(path, "rb") as f:
        reader = make_reader(f)
        topics = {c.topic for c in reader.get_summary().channels.values()}
        assert "/can" in topics or not require_channel, topics
        for _schema, _channel, msg in reader.iter_messages(topics=["/can"]):
            frames.append(json.loads(msg.data))
    return frames
