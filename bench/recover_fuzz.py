#!/usr/bin/env python3
"""Fuzz `ehactl recover` with damaged copies of logs written by `ehactl run`.

Two base logs of a 1 s run of configs/diagnose_testrig.toml (LZ4 chunks): the complete file and
the same file cut at its DataEnd record (footerless: no summary, as a killed writer leaves
it). Each mutant damages one base by one of: a flipped bit, a truncation, a zeroed range of
1–4096 bytes, placed at a random offset inside a chunk record or outside every chunk (header,
schema / channel / metadata records, message indexes, summary, footer), in equal numbers.

Each mutant goes through `ehactl recover MUTANT OUT --json` (10 s timeout). Checked:
- no panic, no timeout, the input unchanged;
- exit 1 and no output file when nothing is recovered; exit 0 and an output the official
  `mcap` reader reads with CRCs validated otherwise (any other exit is counted);
- messages are lost only inside damaged chunks: every message of the original is keyed by
  (sequence, log time, publish time, CRC-32 of its data) and attributed to its chunk; for each
  chunk the damage does not touch, every one of its messages must be in the output. Damage
  outside the chunks may also lose the messages of a channel whose only Schema / Channel
  record it hit, every copy of it (a footerless log has no second copy): counted apart. A message in the output
  that the original did not hold is counted as invented.

Usage: python3 bench/recover_fuzz.py [--mutants 540] [--seed 1] [--bin target/release/ehactl]
Needs the `mcap` and `lz4` packages (tests/python/requirements.txt).
"""
import argparse
import collections
import hashlib
import json
import os
import pathlib
import random
import struct
import subprocess
import sys
import tempfile
import time
import zlib

import lz4.frame
from mcap.reader import make_reader

REPO = pathlib.Path(__file__).resolve().parents[1]
CHUNK, MESSAGE, SCHEMA, CHANNEL, DATA_END = 0x06, 0x05, 0x03, 0x04, 0x0F


def records(d, start=8, end=None):
    """(offset, opcode, length) of the records of `d` from `start` (MCAP framing)."""
    end = len(d) if end is None else end
    p, out = start, []
    while p + 9 <= end:
        op = d[p]
        (ln,) = struct.unpack_from("<Q", d, p + 1)
        out.append((p, op, ln))
        if op == 0x02:  # footer
            break
        p += 9 + ln
    return out


def chunk_messages(d, at):
    """Keys of the messages in the chunk record at `at`, with their channel ids."""
    body = at + 9
    usize, crc, clen = struct.unpack_from("<QII", d, body + 16)
    comp = d[body + 32: body + 32 + clen].decode()
    (csize,) = struct.unpack_from("<Q", d, body + 32 + clen)
    rec = body + 32 + clen + 8
    stored = d[rec: rec + csize]
    plain = lz4.frame.decompress(stored) if comp == "lz4" else stored
    out, q = [], 0
    while q < len(plain):
        op = plain[q]
        (ln,) = struct.unpack_from("<Q", plain, q + 1)
        if op == MESSAGE:
            cid, seq, lt, pt = struct.unpack_from("<HIQQ", plain, q + 9)
            data = plain[q + 9 + 22: q + 9 + ln]
            out.append((cid, (seq, lt, pt, zlib.crc32(data))))
        q += 9 + ln
    return out


def layout(d):
    """Chunks (start, end, [(channel id, key)]), and the Schema / Channel records outside the
    chunks: (start, end, channel ids whose decoding needs the record)."""
    recs = records(d)
    chunks, meta = [], []
    chan_schema = {}
    for at, op, ln in recs:
        if op == CHANNEL:
            cid, sid = struct.unpack_from("<HH", d, at + 9)
            chan_schema.setdefault(cid, sid)
    for at, op, ln in recs:
        if op == CHUNK:
            chunks.append((at, at + 9 + ln, chunk_messages(d, at)))
        elif op == CHANNEL:
            (cid,) = struct.unpack_from("<H", d, at + 9)
            meta.append((at, at + 9 + ln, ("channel", cid), {cid}))
        elif op == SCHEMA:
            (sid,) = struct.unpack_from("<H", d, at + 9)
            meta.append((at, at + 9 + ln, ("schema", sid),
                         {c for c, s in chan_schema.items() if s == sid}))
    return chunks, meta


def channels_lost_with_records(meta, a, b):
    """Channels every copy of whose Channel record, or of whose Schema record, [a, b) hit."""
    copies = collections.defaultdict(list)
    for s, e, rid, cids in meta:
        copies[rid].append((s < b and a < e, cids))
    out = set()
    for rid, cs in copies.items():
        if all(hit for hit, _ in cs):
            for _, cids in cs:
                out |= cids
    return out


def outside_ranges(d, chunks):
    """Byte ranges of `d` after the magic that no chunk record covers."""
    out, p = [], 8
    for s, e, _ in chunks:
        if s > p:
            out.append((p, s))
        p = e
    if len(d) > p:
        out.append((p, len(d)))
    return out


def pick(rng, ranges):
    total = sum(e - s for s, e in ranges)
    k = rng.randrange(total)
    for s, e in ranges:
        if k < e - s:
            return s + k
        k -= e - s
    raise AssertionError


def mutate(rng, d, kind, where, chunks):
    """Damaged copy of `d` and the damaged byte range [a, b)."""
    ranges = ([(s, e) for s, e, _ in chunks] if where == "in a chunk"
              else outside_ranges(d, chunks))
    at = pick(rng, ranges)
    m = bytearray(d)
    if kind == "bit flip":
        m[at] ^= 1 << rng.randrange(8)
        return bytes(m), (at, at + 1)
    if kind == "truncation":
        return bytes(m[:at]), (at, len(d))
    n = rng.randint(1, 4096)
    b = min(len(d), at + n)
    m[at:b] = bytes(b - at)
    return bytes(m), (at, b)


def recovered_keys(path):
    with open(path, "rb") as f:
        r = make_reader(f, validate_crcs=True)
        return collections.Counter(
            (m.sequence, m.log_time, m.publish_time, zlib.crc32(m.data))
            for _, _, m in r.iter_messages(log_time_order=False))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mutants", type=int, default=540)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--bin", default=os.environ.get("EHACTL_BIN",
                                                    str(REPO / "target" / "release" / "ehactl")))
    ap.add_argument("--keep", help="directory to keep the failing mutants in")
    a = ap.parse_args()
    rng = random.Random(a.seed)
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="recover_fuzz_"))
    keep = pathlib.Path(a.keep) if a.keep else None
    if keep:
        keep.mkdir(parents=True, exist_ok=True)
    log = tmp / "run.mcap"
    r = subprocess.run([a.bin, "run", str(REPO / "configs" / "diagnose_testrig.toml"),
                        "--duration", "1", "--out", str(log)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    full = log.read_bytes()
    data_end = next(at for at, op, _ in records(full) if op == DATA_END)
    bases = {"complete": full, "footerless": full[:data_end]}
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}; load "
          f"{os.getloadavg()[0]:.2f}; {a.bin}; seed {a.seed}; base log {len(full)} bytes, "
          f"footerless {data_end} bytes", flush=True)
    cells = [(b, k, w) for b in bases for k in ("bit flip", "truncation", "zeroed range")
             for w in ("in a chunk", "outside chunks")]
    stats = collections.defaultdict(collections.Counter)
    problems = []
    lay = {}
    for name, d in bases.items():
        chunks, meta = layout(full)
        chunks = [c for c in chunks if c[1] <= len(d)]
        meta = [m for m in meta if m[1] <= len(d)]
        lay[name] = (chunks, meta)
    t_start = time.monotonic()
    for i in range(a.mutants):
        base, kind, where = cells[i % len(cells)]
        d = bases[base]
        chunks, meta = lay[base]
        m, (ra, rb) = mutate(rng, d, kind, where, chunks)
        st = stats[(base, kind, where)]
        st["mutants"] += 1
        mp, out = tmp / f"m{i}.mcap", tmp / f"m{i}.out.mcap"
        mp.write_bytes(m)
        digest = hashlib.sha256(m).digest()
        try:
            p = subprocess.run([a.bin, "recover", str(mp), str(out), "--json"],
                               capture_output=True, text=True, timeout=10)
        except subprocess.TimeoutExpired:
            st["timeouts"] += 1
            problems.append(f"mutant {i} ({base}, {kind} at {ra}..{rb}): timeout")
            continue
        bad = []
        if "panicked" in p.stderr or p.returncode not in (0, 1):
            st["panics or other exits"] += 1
            bad.append(f"exit {p.returncode}: {p.stderr[-300:]}")
        if hashlib.sha256(mp.read_bytes()).digest() != digest:
            bad.append("input modified")
        original = collections.Counter()
        for s, e, msgs in chunks:
            original.update(k for _, k in msgs)
        got = recovered_keys(out) if p.returncode == 0 and out.exists() else collections.Counter()
        if p.returncode == 1:
            st["exit 1"] += 1
            if out.exists():
                bad.append("exit 1 left an output file")
        elif p.returncode == 0:
            st["exit 0"] += 1
            if not got:
                bad.append("exit 0 with nothing recovered")
            rep = json.loads(p.stdout)
            if rep["messages_total"] != sum(got.values()):
                bad.append(f"reported {rep['messages_total']} messages, the file holds "
                           f"{sum(got.values())}")
        invented = got - original
        if invented:
            st["invented messages"] += sum(invented.values())
            bad.append(f"{sum(invented.values())} messages the original does not hold")
        # channels whose only Schema / Channel record (in what is left) the damage hit
        hit_chan = channels_lost_with_records(meta, ra, rb)
        left = got.copy()
        for s, e, msgs in chunks:
            st["messages"] += len(msgs)
            damaged = s < rb and ra < e
            kept = 0
            lost_ok = 0
            for cid, k in msgs:
                if left[k] > 0:
                    left[k] -= 1
                    kept += 1
                elif cid in hit_chan:
                    lost_ok += 1
            st["messages kept"] += kept
            if damaged:
                st["chunks damaged"] += 1
                st["lost in damaged chunks"] += len(msgs) - kept
            else:
                st["chunks intact"] += 1
                st["lost with their channel record"] += lost_ok
                lost = len(msgs) - kept - lost_ok
                if lost:
                    st["lost in intact chunks"] += lost
                    bad.append(f"{lost} of {len(msgs)} messages of intact chunk at {s} lost")
        if sum(got.values()) == 0 and p.returncode == 0:
            bad.append("nothing recovered, exit 0")
        if bad:
            st["mutants failing a check"] += 1
            problems.append(f"mutant {i} ({base}, {kind}, {where}, bytes {ra}..{rb}): "
                            + "; ".join(bad))
            if keep:
                (keep / f"m{i}.mcap").write_bytes(m)
        mp.unlink()
        out.unlink(missing_ok=True)
    el = time.monotonic() - t_start
    cols = ["mutants", "exit 0", "exit 1", "panics or other exits", "timeouts",
            "chunks damaged", "lost in damaged chunks", "chunks intact", "lost in intact chunks",
            "lost with their channel record", "invented messages", "mutants failing a check"]
    print("| base | damage | where | " + " | ".join(cols) + " |")
    print("|---|---|---|" + "---|" * len(cols))
    tot = collections.Counter()
    for (b, k, w) in cells:
        st = stats[(b, k, w)]
        tot.update(st)
        print(f"| {b} | {k} | {w} | " + " | ".join(str(st[c]) for c in cols) + " |")
    print("| **all** | | | " + " | ".join(f"**{tot[c]}**" for c in cols) + " |")
    print(f"{a.mutants} mutants in {el:.1f} s; load {os.getloadavg()[0]:.2f}")
    for pr in problems[:40]:
        print(pr)
    if len(problems) > 40:
        print(f"... {len(problems) - 40} more")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
