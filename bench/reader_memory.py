#!/usr/bin/env python3
"""Peak memory (max resident set size, `/usr/bin/time -v`) of ehactl's readers of data files.

Makes the inputs in DIR (once; about 3.5 GB of disk): a CSV of --csv-rows rows of 6 columns
whose last row breaks the uniform sampling (so `diagnose` reads every row, builds the columns
and then refuses the record, before any diagnosis), a one-line 520 MB file of digits, a 1 GB
file of NUL bytes, and an ehactl MCAP log of --log-seconds of configs/sahu2022_force.toml.
Then runs each reader on them and prints one JSON line per case: the command, its exit code,
the peak RSS in MB, the first line of its error, and the machine's load average.

    python3 bench/reader_memory.py --bin target/release/ehactl --dir /tmp/memb [--python-path DIR]

`--python-path` is a directory holding the `ehactl` Python package with its compiled
extension (the bindings' `read_mcap` is measured only then).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "configs" / "diagnose_testrig.toml"


def make_csv(path: Path, rows: int) -> None:
    with open(path, "w") as f:
        f.write("t,u,x,force,p_a,p_b\n")
        buf = []
        for k in range(rows):
            buf.append(
                f"{k * 1e-3:.6f},{0.123456789 + (k % 97) * 1e-3:.9f},{0.0123456789 + (k % 89) * 1e-6:.10f},"
                f"{1234.56789 + k % 83:.6f},{5012345.678 + k % 79:.3f},{4012345.678 + k % 73:.3f}\n"
            )
            if len(buf) == 100_000:
                f.write("".join(buf))
                buf = []
        # The last row breaks the uniform sampling: read in full, then refused.
        buf.append(f"{(rows + 5) * 1e-3:.6f},0.1,0.01,1234.5,5000000.0,4000000.0\n")
        f.write("".join(buf))


def inputs(d: Path, rows: int, log_s: float, binary: str) -> dict[str, Path]:
    d.mkdir(parents=True, exist_ok=True)
    files = {"csv": d / "big.csv", "oneline": d / "oneline.csv", "nul": d / "nul.csv", "log": d / "log.mcap"}
    if not files["csv"].exists():
        make_csv(files["csv"], rows)
    if not files["oneline"].exists():
        with open(files["oneline"], "wb") as f:
            for _ in range(52):
                f.write(b"9" * 10_000_000)
    if not files["nul"].exists():
        with open(files["nul"], "wb") as f:
            f.truncate(1_000_000_000)
    if not files["log"].exists():
        subprocess.run([binary, "run", str(REPO / "configs" / "sahu2022_force.toml"), "--duration", repr(log_s),
                        "--out", str(files["log"])], check=True, capture_output=True)
    return files


def peak(cmd: list[str], env: dict[str, str] | None = None) -> dict[str, object]:
    t0 = time.monotonic()
    r = subprocess.run(["/usr/bin/time", "-v", *cmd], capture_output=True, text=True, env=env)
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
    err = next((ln for ln in (r.stdout + r.stderr).splitlines()
                if ln.startswith(("ehactl", "kept", "/")) or "MCAP" in ln), "")
    return {
        "cmd": " ".join(cmd),
        "exit": r.returncode,
        "peak_rss_mb": round(int(m.group(1)) / 1024, 1) if m else None,
        "wall_s": round(time.monotonic() - t0, 1),
        "error": err[:300],
        "loadavg": os.getloadavg(),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default=str(REPO / "target" / "release" / "ehactl"))
    ap.add_argument("--dir", type=Path, default=Path("/tmp/ehactl_reader_memory"))
    ap.add_argument("--csv-rows", type=int, default=7_880_000, help="rows of the big CSV (7.88 M: 574 MB)")
    ap.add_argument("--log-seconds", type=float, default=400.0, help="length of the MCAP log (s at 5 kHz)")
    ap.add_argument("--python-path", type=Path, help="directory with the compiled ehactl Python package")
    a = ap.parse_args()
    f = inputs(a.dir, a.csv_rows, a.log_seconds, a.bin)
    sizes = {k: round(p.stat().st_size / 1e6, 1) for k, p in f.items()}
    print(json.dumps({"date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "bin": a.bin, "sizes_mb": sizes}))
    out = a.dir / "out"
    cases = [
        [a.bin, "diagnose", "--config", str(RIG), "--data", str(f["csv"]), "--out", str(out)],
        [a.bin, "diagnose", "--config", str(RIG), "--data", str(f["oneline"]), "--out", str(out)],
        [a.bin, "diagnose", "--config", str(RIG), "--data", str(f["nul"]), "--out", str(out)],
        [a.bin, "predict", "--config", str(RIG), "--data", str(f["nul"])],
        [a.bin, "recover", str(f["nul"]), str(a.dir / "recovered.mcap")],
        [a.bin, "recover", str(f["log"]), str(a.dir / "recovered.mcap")],
        # A 5 kHz log against the 1 kHz test bench: read in full, then refused by the
        # config check, before any diagnosis.
        [a.bin, "diagnose", "--config", str(RIG), "--data", str(f["log"]), "--out", str(out)],
    ]
    for cmd in cases:
        (a.dir / "recovered.mcap").unlink(missing_ok=True)
        print(json.dumps(peak(cmd)))
    (a.dir / "recovered.mcap").unlink(missing_ok=True)
    if a.python_path:
        env = dict(os.environ, PYTHONPATH=str(a.python_path))
        py = [sys.executable, "-c"]
        for key in ("csv", "log"):
            # Prints the bytes of the arrays it returns: the data kept in memory.
            code = (f"import ehactl\ntry:\n    r = ehactl.read_mcap({str(f[key])!r})\n"
                    "    print('kept', sum(a.nbytes for c in r.values() if isinstance(c, dict)"
                    " for a in c.values() if hasattr(a, 'nbytes')))\n"
                    "except ValueError as e:\n    print(e)")
            print(json.dumps(peak([*py, code], env) | {"reader": f"read_mcap({key})"}))
        print(json.dumps(peak([*py, "import ehactl"], env) | {"reader": "python + import ehactl (baseline)"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
