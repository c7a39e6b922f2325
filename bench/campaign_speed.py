"""Speed of a campaign diagnosis and of `ehactl predict` (BENCHMARKS.md, "Campaigns"): records of
the NumPy/SciPy modified Bouc–Wen damper (tests/python/bouc_wen.py) at 1 kHz — a campaign of 10
records × 10 000 samples (sines and random histories at 0 … 1 A), and one record of 60 000
samples predicted through the campaign's extended.toml. Each timed REPS times; prints wall and
CPU (user + sys of the child) per run, the load average before it, and the medians. Not a test.

Usage: python bench/campaign_speed.py [REPS=3]   (with tests/python on the path: run from the
repository root, numpy and scipy installed, target/release/ehactl built)."""
import os
import pathlib
import resource
import statistics
import subprocess
import sys
import tempfile
import time

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "python"))
import bouc_wen as bw  # noqa: E402

BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
CONFIG = REPO / "configs" / "utfsm_mts_mrdamper.toml"
RATE = 1000.0


def timed(args):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    r = subprocess.run([BIN, *map(str, args)], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        sys.exit(r.stderr)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, load


def main():
    reps = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    d = pathlib.Path(tempfile.mkdtemp(prefix="campaign_bench_"))
    files = []
    for i, cur in enumerate([0.0, 0.25, 0.5, 0.75, 1.0] * 2):
        motion = bw.sine(0.002 + 0.002 * i, 0.5 + 0.4 * i) if i % 2 else bw.random_history(i, 0.004, 5.0, 10.0)
        rec = bw.record(motion, cur, 10.0, rate=RATE, seed=i)
        rec["x"] = rec["x"] + 0.05
        p = d / f"r{i}_{cur:g}A.csv"
        bw.write_csv(p, rec)
        files.append(p)
    long = bw.record(bw.random_history(99, 0.004, 5.0, 60.0), 0.6, 60.0, rate=RATE, seed=99)
    long["x"] = long["x"] + 0.05
    bw.write_csv(d / "long.csv", long)
    print(f"nproc {os.cpu_count()}; records in {d}")
    camp, pred = [], []
    for r in range(reps):
        out = d / f"out{r}"
        args = ["diagnose", "--config", CONFIG, "--out", out] + [a for f in files for a in ("--data", f)]
        w, c, ld = timed(args)
        camp.append(w)
        print(f"campaign 10 × 10 000: wall {w:.2f} s, cpu {c:.2f} s, load {ld:.2f}")
        w, c, ld = timed(["predict", "--config", out / "extended.toml", "--data", d / "long.csv", "--json"])
        pred.append(w)
        print(f"predict 60 000: wall {w:.3f} s, cpu {c:.3f} s, load {ld:.2f}")
    print(f"median campaign {statistics.median(camp):.2f} s; median predict {statistics.median(pred):.3f} s")


if __name__ == "__main__":
    main()
