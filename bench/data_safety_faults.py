"""Data-safety rows of BENCHMARKS.md's fault-injection table: corrupt chunks through
`ehactl recover`, two runs to one `--out`, a full disk under `ehactl diagnose` and
`ehactl run --json`.

    EHACTL_BIN=target/release/ehactl python3 bench/data_safety_faults.py [RUNS]

Corrupt chunks: a 1 s log of configs/diagnose_testrig.toml (10 LZ4 chunks) damaged at chunk k
(k = 0, 1, … RUNS−1 in turn) by each kind of fault; "chunks kept / intact" compares what
`ehactl recover` kept with the chunks that were not damaged, "messages" what it kept with the
messages of the intact chunks (counted here by decompressing them, not by ehactl); every
recovered file is read back by the official reader with CRCs validated. Concurrent writers: a
1.5 s real-time run and, 0.3 s later, a second run to the same file. Full disk: a 256 KiB
tmpfs (needs root) with 8–40 KiB left free. Prints Markdown rows."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from test_data_safety import (  # noqa: E402
    BIN, FORCE, SJ, SJ_CONFIG, _chunk_indexes, _chunk_parts, _count_messages, _data_end, _log,
    _messages_in_chunk,
)


def damage(kind: str, data: bytes, k: int) -> bytes:
    d = bytearray(data)
    p = _chunk_parts(d, _chunk_indexes(data)[k])
    if kind == "flipped byte":
        d[p["rec"] + p["csize"] // 2] ^= 0x40
    elif kind == "bad chunk length":
        struct.pack_into("<Q", d, p["at"] + 1, p["length"] + 1000)
    elif kind == "bad chunk length, no summary":
        struct.pack_into("<Q", d, p["at"] + 1, p["length"] + 1000)
        d = d[: _data_end(data)]
    elif kind == "wrong uncompressed_size":
        struct.pack_into("<Q", d, p["body"] + 16, p["usize"] + 7)
    elif kind == "broken inner record, valid CRC":
        struct.pack_into("<Q", d, p["rec"] + 1, p["csize"] * 2)
        struct.pack_into("<I", d, p["body"] + 24, zlib.crc32(bytes(d[p["rec"]: p["rec"] + p["csize"]])))
    return bytes(d)


def corrupt_rows(runs: int) -> None:
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        lz4 = _log(tmp, "lz4.mcap").read_bytes()
        plain = _log(tmp, "plain.mcap", '\n[log]\ncompression = "none"\n').read_bytes()
        for kind in ("flipped byte", "bad chunk length", "bad chunk length, no summary",
                     "wrong uncompressed_size", "broken inner record, valid CRC"):
            base = plain if kind.startswith("broken") else lz4
            cis = _chunk_indexes(base)
            per = [_messages_in_chunk(base, c) for c in cis]
            kept_c = kept_m = intact_c = intact_m = 0
            for k in range(runs):
                bad = tmp / "bad.mcap"
                bad.write_bytes(damage(kind, base, k % len(cis)))
                fixed = tmp / "fixed.mcap"
                fixed.unlink(missing_ok=True)
                r = subprocess.run([BIN, "recover", str(bad), str(fixed), "--json"], capture_output=True, text=True)
                assert r.returncode == 0, r.stderr
                rep = json.loads(r.stdout)
                total = sum(rep["messages"].values())
                assert _count_messages(fixed) == total
                kept_c += rep["chunks"]
                kept_m += total
                intact_c += len(cis) - 1
                intact_m += sum(per) - per[k % len(cis)]
            print(f"| corrupt chunk: {kind} ({'uncompressed' if base is plain else 'lz4'}, chunk 0…{runs - 1}) | recover | {runs} | 0×{runs} | "
                  f"chunks kept {kept_c} of {intact_c} intact, messages {kept_m} of {intact_m} | — | — |")


def concurrent_rows(runs: int) -> None:
    refused = intact = 0
    with tempfile.TemporaryDirectory() as t:
        for i in range(runs):
            out = Path(t) / f"same{i}.mcap"
            first = subprocess.Popen([BIN, "run", str(FORCE), "--realtime", "--duration", "1.5", "--out", str(out), "--json"],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            while not (out.exists() and out.stat().st_size > 0):
                time.sleep(0.01)
            time.sleep(0.3)
            r = subprocess.run([BIN, "run", str(FORCE), "--duration", "0.2", "--out", str(out)], capture_output=True, text=True)
            refused += r.returncode == 1 and str(out) in r.stderr
            so, _ = first.communicate()
            cycles = json.loads(so)["cycles"]
            try:
                intact += first.returncode == 0 and _count_messages(out) > 0 and cycles > 0
            except Exception:  # the official reader refuses the file
                pass
    print(f"| concurrent writers (second run 0.3 s into a 1.5 s real-time run, same --out) | realtime | {runs} | "
          f"second run refused with exit 1: {refused} of {runs} | first run's log whole (exit 0, official reader, CRCs): {intact} of {runs} | — | — |")


def full_disk_rows(runs: int) -> None:
    mnt = Path(tempfile.mkdtemp())
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)]).returncode != 0:
        print("| full disk | — | — | not measured: cannot mount a tmpfs (needs root) | — | — | — |")
        return
    try:
        codes, half = [], 0
        for i in range(runs):
            free = 8 * 1024 * (i + 1)
            filler = mnt / "filler"
            with open(filler, "wb", buffering=0) as f:
                try:
                    while True:
                        f.write(b"\0" * 4096)
                except OSError:
                    pass
            os.truncate(filler, filler.stat().st_size - free)
            out = mnt / "diag"
            r = subprocess.run([BIN, "diagnose", "--config", str(SJ_CONFIG), "--data", str(SJ / "estimation.csv"),
                                "--out", str(out), "--json"], capture_output=True, text=True)
            codes.append(r.returncode)
            for n in os.listdir(out) if out.exists() else []:
                text = (out / n).read_bytes()
                if n == ".ehactl-diagnose":
                    continue
                if ".tmp-" in n or (n.endswith(".json") and not _json_ok(text)) or (n.endswith(".csv") and not text.endswith(b"\n")):
                    half += 1
            subprocess.run(["rm", "-rf", str(out), str(filler)])
        print(f"| full disk during diagnose (tmpfs, 8–{8 * runs} KiB free) | diagnose | {runs} | "
              f"{', '.join(f'{c}×{codes.count(c)}' for c in sorted(set(codes)))} | half-written files left: {half} | — | — |")
        ok = 0
        for _ in range(runs):
            r = subprocess.run([BIN, "run", str(FORCE), "--duration", "600", "--out", str(mnt / "r.mcap"), "--json"],
                               capture_output=True, text=True)
            try:
                ok += r.returncode == 1 and "No space left" in json.loads(r.stdout or "{}").get("error", "")
            except ValueError:
                pass
            (mnt / "r.mcap").unlink(missing_ok=True)
        print(f"| full disk during run --json (tmpfs 256 KiB) | sim | {runs} | exit 1 with the JSON error object: {ok} of {runs} | what reached the disk is recoverable (see disk full above) | — | — |")
    finally:
        subprocess.run(["umount", "-l", str(mnt)])


def _json_ok(b: bytes) -> bool:
    try:
        json.loads(b)
        return True
    except ValueError:
        return False


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    corrupt_rows(n)
    concurrent_rows(n)
    full_disk_rows(n)
