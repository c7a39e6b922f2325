#!/usr/bin/env python3
"""Speed of ``ehactl.run_many`` on a Dask LocalCluster with 1 and 2 worker processes (one
thread each) against the local rayon path, on the same batch; checks that all three give
identical rms errors.

    python3 bench/dask_speedup.py [--runs 200] [--duration 0.5] [--repeat 3]

Prints one JSON object: wall times (best of --repeat, s), speed-ups.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import ehactl
from dask.distributed import Client, LocalCluster

REPO = Path(__file__).resolve().parents[1]


def best(f, repeat: int) -> tuple[float, object]:
    out, t_best = None, float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = f()
        t_best = min(t_best, time.perf_counter() - t0)
    return t_best, out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--duration", type=float, default=0.5)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    base = ehactl.Config.load(REPO / "configs/sahu2022_force.toml")
    kps = [0.2 + 0.4 * i / (a.runs - 1) for i in range(a.runs)]
    grid = {"control.pi.kp": kps}
    res = {"runs": a.runs, "duration_s": a.duration, "cycles_per_run": round(a.duration * 5000),
           "cpus": os.cpu_count()}
    t, local = best(lambda: ehactl.run_many(grid, base=base, duration=a.duration, fields=["t"], frame=True), a.repeat)
    res["rayon_local_s"] = t
    for n in (1, 2):
        with LocalCluster(n_workers=n, threads_per_worker=1, dashboard_address=None, silence_logs=40) as cl, Client(cl) as c:
            ehactl.run_many([base], duration=0.01, client=c)  # warm the workers (import, load)
            t, df = best(lambda: ehactl.run_many(grid, base=base, duration=a.duration, fields=["t"], client=c), a.repeat)
            res[f"dask_{n}_workers_s"] = t
            assert (df["rms_error"] == local["rms_error"]).all(), "cluster numbers differ from the local path"
    res["speedup_2_vs_1_worker"] = res["dask_1_workers_s"] / res["dask_2_workers_s"]
    res["dask_2_workers_vs_rayon"] = res["rayon_local_s"] / res["dask_2_workers_s"]
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
