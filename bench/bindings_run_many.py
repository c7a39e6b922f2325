#!/usr/bin/env python3
"""Benchmark (BENCHMARKS.md): 200 closed-loop runs of 1 s of configs/sahu2022_force.toml through
the Python bindings — ehactl.run_many (rayon, all cores) vs a Python loop calling
ehactl.run one by one. Every run returns all 33 result columns as NumPy arrays.

    python3 -m pip install ./bindings/python && python3 bench/bindings_run_many.py [--repeats 5]

Prints one JSON object: medians and all repeats (s), speed-up = loop / run_many.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import ehactl

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--duration", type=float, default=1.0, help="simulated seconds per run")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    cfg = ehactl.Config.load(REPO / "configs" / "sahu2022_force.toml")
    cfgs = [cfg] * args.runs

    def t_many(threads=None):
        t0 = time.perf_counter()
        res = ehactl.run_many(cfgs, duration=args.duration, threads=threads)
        dt = time.perf_counter() - t0
        assert len(res) == args.runs and all(r.ok and len(r) == round(args.duration / cfg.control_dt) for r in res)
        return dt

    loop_rust_s: list[float] = []

    def t_loop():
        t0 = time.perf_counter()
        res = [ehactl.run(c, duration=args.duration) for c in cfgs]
        dt = time.perf_counter() - t0
        assert all(r.ok for r in res)
        loop_rust_s.append(sum(r.summary.wall_time_s for r in res))
        return dt

    t_many()  # warm-up (page faults, thread pool)
    many, many1, loop = [], [], []
    for _ in range(args.repeats):
        many.append(t_many())
        many1.append(t_many(threads=1))
        loop.append(t_loop())
    med = statistics.median
    out = {
        "runs": args.runs,
        "sim_seconds_per_run": args.duration,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "ehactl": ehactl.__version__,
        "run_many_s_median": med(many),
        "run_many_1_thread_s_median": med(many1),
        "python_loop_s_median": med(loop),
        "speedup_run_many_vs_loop": med(loop) / med(many),
        "speedup_run_many_vs_1_thread": med(many1) / med(many),
        "sim_x_realtime_run_many": args.runs * args.duration / med(many),
        "python_loop_rust_loop_time_s_median": med(loop_rust_s),
        "load_average_at_end": os.getloadavg(),
        "repeats": {"run_many": many, "run_many_1_thread": many1, "python_loop": loop},
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
