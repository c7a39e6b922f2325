"""Read an ehactl MCAP log back into numpy arrays — the tests' own reader, independent of
the Rust decoder (``ehactl_log::record``) and of the Python bindings.

Uses the official ``mcap`` package (``mcap.reader.make_reader``) with chunk CRC
validation on, and decodes the ROS 2 CDR payloads of every CDR channel with numpy from
the ``ros2msg`` schema the log publishes for it (a small generic decoder: a numpy
structured dtype built from the schema's primitive fields with CDR alignment, so no byte
offset is written here). The field *names* the schemas document (crates/log/src/record.rs) are listed
below and checked against the published schemas; the byte layout itself is pinned by
``test_mcap_roundtrip.py`` and cross-checked there with the official ``mcap_ros2`` decoder.

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
TIMING_SCHEMA = "ehactl_msgs/msg/CycleTiming"  # wall-clock runs only (`ehactl run --realtime`)

# Documented field names of each message, in order (the ros2msg schemas in crates/log/src/record.rs).
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

CDR_TOPICS = {
    "/control": (CONTROL_SCHEMA, CONTROL_FIELDS),
    "/plant": (PLANT_SCHEMA, PLANT_FIELDS),
    "/timing": (TIMING_SCHEMA, TIMING_FIELDS),
}
JSON_TOPICS = ("/config", "/events", "/summary")

# ros2msg primitive -> numpy type (size = CDR alignment); bool is read as a byte and checked.
ROS2_PRIMITIVES = {
    "float64": "f8",
    "float32": "f4",
    "int64": "i8",
    "int32": "i4",
    "int16": "i2",
    "int8": "i1",
    "uint64": "u8",
    "uint32": "u4",
    "uint16": "u2",
    "uint8": "u1",
    "byte": "u1",
    "char": "u1",
    "bool": "u1",
}


class McapContentError(ValueError):
    """The file is valid MCAP but its content does not match the ehactl layout."""


def schema_fields(schema_text: str) -> list[tuple[str, str]]:
    """(name, ros2msg type) of each field of a flat ros2msg schema, in order (comments and
    constants skipped; the first ``====`` line ends the message)."""
    fields = []
    for raw in schema_text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if line.startswith("===="):
            break
        parts = line.split()
        if len(parts) < 2:
            raise McapContentError(f"cannot parse schema line {raw!r}")
        ty, name = parts[0], parts[1]
        if "=" in name or (len(parts) > 2 and parts[2].startswith("=")):
            continue  # constant
        if ty not in ROS2_PRIMITIVES:
            raise McapContentError(f"schema field {name!r} has type {ty!r}; only flat primitive messages are read")
        fields.append((name, ty))
    return fields


def schema_dtype(schema_text: str) -> np.dtype:
    """numpy structured dtype of one little-endian CDR message of a flat ros2msg schema:
    the 4-byte encapsulation header, then each field aligned to its own size counted from
    the end of the header (XCDR1, as ROS 2 writes it)."""
    names, formats, offsets = ["_cdr_header"], ["V4"], [0]
    off = 0
    for name, ty in schema_fields(schema_text):
        t = np.dtype("<" + ROS2_PRIMITIVES[ty])
        off = -(-off // t.itemsize) * t.itemsize
        names.append(name)
        formats.append(t)
        offsets.append(4 + off)
        off += t.itemsize
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": 4 + off})


def decode_cdr(topic: str, schema_text: str, payloads: list[bytes]) -> dict[str, np.ndarray]:
    """Decode the payloads of one CDR channel with the dtype of its published schema."""
    dtype = schema_dtype(schema_text)
    sizes = {len(p) for p in payloads}
    if sizes and sizes != {dtype.itemsize}:
        raise McapContentError(f"{topic}: payload sizes {sorted(sizes)}, schema gives {dtype.itemsize}")
    arr = np.frombuffer(b"".join(payloads), dtype=dtype)
    if len(arr) and not np.all(arr["_cdr_header"] == np.void(CDR_LE_HEADER)):
        raise McapContentError(f"{topic}: a CDR encapsulation header is not {CDR_LE_HEADER.hex()}")
    out = {}
    for name, ty in schema_fields(schema_text):
        col = arr[name].copy()
        if ty == "bool":
            if np.any(col > 1):
                raise McapContentError(f"{topic}: bool {name!r} has a byte other than 0/1")
            col = col.astype(bool)
        out[name] = col
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
    payloads: dict[str, list[bytes]] = {}
    seq: dict[str, list[int]] = {}
    log_time: dict[str, list[int]] = {}
    pub_time: dict[str, list[int]] = {}
    cdr_schema: dict[str, str] = {}
    json_msgs: dict[str, list[Any]] = {t: [] for t in JSON_TOPICS}
    counts: dict[str, int] = {}
    schemas: dict[str, tuple[str, str]] = {}
    encodings: dict[str, str] = {}

    def see(schema, channel) -> None:
        topic = channel.topic
        if topic in schemas:
            return
        schemas[topic] = (schema.name if schema else "", schema.encoding if schema else "")
        encodings[topic] = channel.message_encoding
        if channel.message_encoding == "cdr":
            if schema is None or schema.encoding != "ros2msg":
                raise McapContentError(f"{topic}: CDR channel without a ros2msg schema")
            cdr_schema[topic] = schema.data.decode()
            for d in (payloads, seq, log_time, pub_time):
                d[topic] = []

    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=validate_crcs)
        header = reader.get_header()
        summary_rec = reader.get_summary()
        if summary_rec is not None:  # channels registered without messages
            for ch in summary_rec.channels.values():
                see(summary_rec.schemas.get(ch.schema_id), ch)
        # File order (chunk by chunk) rather than a log-time merge: cheaper, and the
        # sequence check below then also tests the writer's ordering.
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            see(schema, channel)
            if topic in cdr_schema:
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
    for topic, (schema_name, fields) in CDR_TOPICS.items():
        if topic not in cdr_schema:
            # channel never registered (e.g. /timing of a simulated-time run): empty columns
            cols = {f: np.empty(0) for f in fields}
        else:
            if schemas[topic][0] != schema_name:
                raise McapContentError(f"{topic}: schema {schemas[topic][0]!r}, expected {schema_name!r}")
            published = tuple(n for n, _ in schema_fields(cdr_schema[topic]))
            if published != fields:
                raise McapContentError(f"{topic}: schema fields {published}, documented {fields}")
            cols = decode_cdr(topic, cdr_schema[topic], payloads[topic])
        cols["_sequence"] = np.asarray(seq.get(topic, []), dtype=np.uint64)
        cols["_log_time"] = np.asarray(log_time.get(topic, []), dtype=np.uint64)
        cols["_publish_time"] = np.asarray(pub_time.get(topic, []), dtype=np.uint64)
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
    "decode_cdr",
    "read_can",
    "read_run",
    "schema_dtype",
    "schema_fields",
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
