#!/usr/bin/env python3
"""Check that two MCAP logs of the same run hold the same messages (BENCHMARKS.md, "Whole
`ehactl run` process with MCAP on": the hand-written writer against the `mcap` crate's).

Both files are read with the official `mcap` reader, CRCs validated, once linearly (file
order, chunk by chunk) and once through the summary's chunk indexes (the seeking reader),
and must give the same (topic, sequence, log_time, publish_time, bytes) for every message,
the same channels (topic, encodings, schema name, encoding and text), the same metadata and
the same Statistics message counts. `/summary` is compared as JSON without the fields that
differ between two runs of the same config: wall time, speed, output path.

Usage: python3 bench/mcap_equal.py A.mcap B.mcap   (exit status 1 and the first difference
if they differ)
"""
import json
import sys

from mcap.reader import SeekingReader, StreamReader, make_reader
from mcap.records import Channel, Message

WALL_CLOCK_SUMMARY_KEYS = {"wall_time_s", "sim_speed_x_realtime", "mcap"}


def channels(summary):
    out = {}
    for c in summary.channels.values():
        s = summary.schemas.get(c.schema_id)
        out[c.topic] = (c.message_encoding, dict(c.metadata),
                        (s.name, s.encoding, s.data) if s else None)
    return out


def read(path):
    with open(path, "rb") as f:
        r = make_reader(f, validate_crcs=True)
        assert isinstance(r, SeekingReader)
        summary = r.get_summary()
        indexed = [(c.topic, m.sequence, m.log_time, m.publish_time, m.data)
                   for _, c, m in r.iter_messages(log_time_order=False)]
        metadata = {m.name: dict(m.metadata) for m in r.iter_metadata()}
    linear = []
    with open(path, "rb") as f:
        topics = {}
        for rec in StreamReader(f, validate_crcs=True).records:
            if isinstance(rec, Channel):
                topics[rec.id] = rec.topic
            elif isinstance(rec, Message):
                linear.append((topics[rec.channel_id], rec.sequence, rec.log_time,
                               rec.publish_time, rec.data))
    counts = {summary.channels[c].topic: n
              for c, n in summary.statistics.channel_message_counts.items()}
    return {"indexed": indexed, "linear": linear, "channels": channels(summary),
            "metadata": metadata, "counts": counts, "chunks": len(summary.chunk_indexes)}


def strip(msgs):
    """Messages with /summary replaced by its JSON minus the wall-clock fields."""
    out = []
    for topic, seq, lt, pt, data in msgs:
        if topic == "/summary":
            js = {k: v for k, v in json.loads(data).items() if k not in WALL_CLOCK_SUMMARY_KEYS}
            data = json.dumps(js, sort_keys=True).encode()
        out.append((topic, seq, lt, pt, data))
    return out


def main():
    a, b = sys.argv[1], sys.argv[2]
    ra, rb = read(a), read(b)
    for r, p in ((ra, a), (rb, b)):
        if r["indexed"] != r["linear"]:
            sys.exit(f"{p}: the seeking reader and the linear reader disagree")
    ma, mb = strip(ra["linear"]), strip(rb["linear"])
    for i, (x, y) in enumerate(zip(ma, mb)):
        if x != y:
            sys.exit(f"message {i} differs:\n  {a}: {x[:4]} {x[4][:80]!r}\n  {b}: {y[:4]} {y[4][:80]!r}")
    if len(ma) != len(mb):
        sys.exit(f"{len(ma)} messages in {a}, {len(mb)} in {b}")
    for key in ("channels", "metadata", "counts"):
        if ra[key] != rb[key]:
            sys.exit(f"{key} differ:\n  {a}: {ra[key]}\n  {b}: {rb[key]}")
    per_topic = {}
    for m in ma:
        per_topic[m[0]] = per_topic.get(m[0], 0) + 1
    print(f"equal: {len(ma)} messages {per_topic}; chunks {ra['chunks']} / {rb['chunks']}")


if __name__ == "__main__":
    main()
