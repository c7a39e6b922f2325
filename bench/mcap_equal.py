#!/usr/bin/env python3
"""Check that two MCAP logs of the same run hold the same messages (BENCHMARKS.md, "Whole
`ehactl run` process with MCAP on": the hand-written writer against the `mcap` crate's).

Both files are read with the official `mcap` reader, CRCs validated, once linearly (file
order, chunk by chunk) and once through the summary's chunk indexes (the seeking reader),
and must give the same (sequence, log_time, publish_time, bytes) for every message of
each topic, in file order,
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


def by_topic(msgs):
    out = {}
    for topic, *rest in msgs:
        out.setdefault(topic, []).append(tuple(rest))
    return out


def main():
    a, b = sys.argv[1], sys.argv[2]
    ra, rb = read(a), read(b)
    for r, p in ((ra, a), (rb, b)):
        if r["indexed"] != r["linear"]:
            sys.exit(f"{p}: the seeking reader and the linear reader disagree")
    # Per topic, in file order: the order of messages of different topics in the file
    # depends on when the writer thread found them in their queues (records and events are
    # separate queues), not on the writer.
    ma, mb = by_topic(strip(ra["linear"])), by_topic(strip(rb["linear"]))
    for topic in sorted(set(ma) | set(mb)):
        xa, xb = ma.get(topic, []), mb.get(topic, [])
        for i, (x, y) in enumerate(zip(xa, xb)):
            if x != y:
                sys.exit(f"{topic} message {i} differs:\n  {a}: {x[:3]} {x[3][:80]!r}\n"
                         f"  {b}: {y[:3]} {y[3][:80]!r}")
        if len(xa) != len(xb):
            sys.exit(f"{topic}: {len(xa)} messages in {a}, {len(xb)} in {b}")
    for key in ("channels", "metadata", "counts"):
        if ra[key] != rb[key]:
            sys.exit(f"{key} differ:\n  {a}: {ra[key]}\n  {b}: {rb[key]}")
    per_topic = {t: len(v) for t, v in sorted(ma.items())}
    print(f"equal: {sum(per_topic.values())} messages {per_topic}; "
          f"chunks {ra['chunks']} / {rb['chunks']}")


if __name__ == "__main__":
    main()
