#!/usr/bin/env python3
"""Whole-process speed of `ehactl run` with MCAP on (BENCHMARKS.md, "Whole `ehactl run`
process with MCAP"): interleaved runs of one or more binaries / configs, medians of wall time
and of the process's CPU time (user + sys of the child, from getrusage), × real time of the
whole process and of the loop alone (`sim_speed_x_realtime` of the summary), peak RSS, and
the logger counters (records written / dropped, queue high water / capacity). Every log is
read back with the official `mcap` reader and its `/control` message count checked.

Usage:
  python3 bench/process_speed.py [--bin A --bin B ...] [--config C ...] [--duration 3]
      [--reps 7] [--json out.json]
Prints a markdown table and the load average before and after.
"""
import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time


def run_once(binary, config, duration, out):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(
        [binary, "run", config, "--duration", str(duration), "--out", out, "--json"],
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        sys.exit(f"{binary} run {config} failed ({p.returncode}): {p.stderr.strip()}")
    s = json.loads(p.stdout)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    log = s.get("log") or {}
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "maxrss_kb": after.ru_maxrss,  # max over children so far: see note below
        "loop_x": s["sim_speed_x_realtime"],
        "cycles": s["cycles"],
        "records_written": log.get("records_written"),
        "records_dropped": log.get("records_dropped"),
        "queue_high_water": log.get("queue_high_water"),
        "queue_capacity": log.get("queue_capacity"),
        "bytes": os.path.getsize(out),
    }


def rss_kb(binary, config, duration, out):
    """Peak RSS of one run (GNU time, since RUSAGE_CHILDREN keeps the max of all children)."""
    p = subprocess.run(
        ["/usr/bin/time", "-f", "%M", binary, "run", config, "--duration", str(duration),
         "--out", out, "--json"],
        capture_output=True,
        text=True,
    )
    return int(p.stderr.strip().splitlines()[-1])


def count_control(path):
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        stats = make_reader(f).get_summary().statistics
        return stats.channel_message_counts


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", action="append", help="ehactl binary (repeatable)")
    ap.add_argument("--config", action="append", help="rig config (repeatable)")
    ap.add_argument("--duration", type=float, default=3.0, help="simulated time per run (s)")
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--json", help="write the raw runs here")
    a = ap.parse_args()
    bins = a.bin or [os.environ.get("EHACTL_BIN", "target/release/ehactl")]
    configs = a.config or ["configs/sahu2022_force.toml"]
    load0 = os.getloadavg()
    tmp = tempfile.mkdtemp(prefix="ehactl_speed_")
    runs = {(b, c): [] for b in bins for c in configs}
    for _ in range(a.reps):
        for b in bins:
            for c in configs:
                out = os.path.join(tmp, "run.mcap")
                r = run_once(b, c, a.duration, out)
                counts = count_control(out)
                assert sum(counts.values()) > 0, "empty log"
                r["mcap_messages"] = sum(counts.values())
                runs[(b, c)].append(r)
                os.remove(out)
    load1 = os.getloadavg()
    print(f"load average before {load0[0]:.2f} / {load0[1]:.2f} / {load0[2]:.2f}, "
          f"after {load1[0]:.2f} / {load1[1]:.2f} / {load1[2]:.2f}; nproc {os.cpu_count()}; "
          f"{a.reps} interleaved runs each, {a.duration} s simulated\n")
    print("| binary | config | wall median (ms) | × real time (process) | CPU user+sys median (ms) "
          "| loop × real time (median) | peak RSS (MB) | records written / dropped | queue high water / capacity | MiB |")
    print("|---|---|---:|---:|---:|---:|---:|---|---|---:|")
    report = []
    for (b, c), rs in runs.items():
        wall = statistics.median(r["wall_s"] for r in rs)
        cpu = statistics.median(r["cpu_s"] for r in rs)
        loop = statistics.median(r["loop_x"] for r in rs)
        rss = rss_kb(b, c, a.duration, os.path.join(tmp, "rss.mcap")) / 1024
        last = rs[-1]
        print(f"| {b} | {os.path.basename(c)} | {wall*1e3:.1f} | {a.duration/wall:.0f}× | {cpu*1e3:.1f} "
              f"| {loop:.0f}× | {rss:.1f} | {last['records_written']} / {last['records_dropped']} "
              f"| {last['queue_high_water']} / {last['queue_capacity']} | {last['bytes']/2**20:.2f} |")
        report.append({"bin": b, "config": c, "duration": a.duration, "runs": rs,
                       "wall_median_s": wall, "cpu_median_s": cpu, "loop_x_median": loop,
                       "rss_mb": rss, "load_before": load0, "load_after": load1})
    if a.json:
        with open(a.json, "w") as f:
            json.dump(report, f, indent=1)
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
