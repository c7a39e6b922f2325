"""Wall-clock jitter benchmark (BENCHMARKS.md): `ehactl run --realtime` with the sim backend paced
in real time at 5 kHz for 20 s per scenario, the control loop pinned to CPU 0:

  idle            nothing else started by this script
  idle_nospin     same, busy-wait tail off (realtime.spin = 0): sleep-only wake-ups
  other_core_busy a busy process pinned to CPU 1 (the other core)
  same_core_busy  a busy process (normal scheduler) pinned to CPU 0, next to the loop

Reads each run's summary (constant-memory histograms, --json) and its MCAP /timing channel
(per-cycle start lateness) back with the official `mcap` reader, prints a markdown table,
writes bench/results/jitter.json and bench/results/jitter.png (lateness CCDF per scenario).

    bash bench/jitter.sh                      # all scenarios, 20 s each
    python3 bench/jitter.py --duration 5 --scenarios idle
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

REPO = Path(__file__).resolve().parents[1]
try:
    import ehactl  # noqa: E402  (the log reader of the Python bindings: ehactl.read_mcap)
except ImportError as e:  # pragma: no cover
    raise SystemExit(f"{e}: install the Python bindings first: python3 -m pip install ./bindings/python")

CONFIG = REPO / "configs" / "sahu2022_force.toml"
# Busy-wait tail of the scenarios that spin (s); --spin changes it.
SPIN_S = 20e-6
SCENARIOS = ("idle", "idle_nospin", "other_core_busy", "same_core_busy")


def busy(cpu: int) -> subprocess.Popen:
    """A CPU hog pinned to `cpu` (normal scheduler)."""
    return subprocess.Popen(
        [sys.executable, "-c", f"import os\nos.sched_setaffinity(0, {{{cpu}}})\nwhile True: pass"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def run(binary: Path, scenario: str, duration: float, tmp: Path) -> dict:
    spin = 0.0 if scenario == "idle_nospin" else SPIN_S
    cfg = tmp / f"{scenario}.toml"
    cfg.write_text(
        CONFIG.read_text()
        + f"\n[realtime]\npriority = 80\ncpu = 0\nlock_memory = true\nspin = {spin!r}\noverrun_policy = \"skip\"\n"
    )
    out = tmp / f"{scenario}.mcap"
    hog = None
    if scenario == "other_core_busy":
        hog = busy(1)
    elif scenario == "same_core_busy":
        hog = busy(0)
    try:
        if hog:
            time.sleep(0.5)
        proc = subprocess.run(
            [str(binary), "run", str(cfg), "--realtime", "--duration", repr(duration), "--out", str(out), "--json"],
            capture_output=True,
            text=True,
            cwd=REPO,
        )
    finally:
        if hog:
            hog.kill()
            hog.wait()
    if proc.returncode != 0:
        raise SystemExit(f"{scenario}: ehactl exited {proc.returncode}: {proc.stderr.strip()}")
    js = json.loads(proc.stdout)
    tm = ehactl.read_mcap(out)["timing"]
    late = np.sort(tm["lateness_us"])
    out.unlink()
    return {
        "scenario": scenario,
        "spin_us": spin * 1e6,
        "warnings": [line for line in proc.stderr.splitlines() if "warning" in line],
        "summary": {k: js[k] for k in js if k.endswith("_us") or k in ("cycles", "overruns", "overruns_exec", "overruns_wakeup", "longest_overrun_streak", "skipped_deadlines", "log_queue_high_water")},
        "rt": js["timing"]["rt"],
        "records_dropped": js["log"]["records_dropped"],
        "lateness_us_sorted": late,
    }


def main() -> None:
    global SPIN_S
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=20.0, help="s per scenario (default 20)")
    ap.add_argument("--scenarios", default=",".join(SCENARIOS), help="comma-separated subset of " + ", ".join(SCENARIOS))
    ap.add_argument("--bin", type=Path, default=REPO / "target" / "release" / "ehactl")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--note", default="", help="conditions to record (e.g. 'other builds running')")
    ap.add_argument("--spin", type=float, default=SPIN_S, help="realtime.spin of the spinning scenarios (s, default 20e-6)")
    a = ap.parse_args()
    if not (0.0 <= a.spin < 200e-6):
        raise SystemExit(f"--spin {a.spin}: expected a busy-wait tail in seconds, 0 ≤ spin < the 200 µs period")
    SPIN_S = a.spin
    chosen = [s.strip() for s in a.scenarios.split(",") if s.strip()]
    for s in chosen:
        if s not in SCENARIOS:
            raise SystemExit(f"--scenarios: unknown scenario `{s}`; expected any of {', '.join(SCENARIOS)}")
    if os.cpu_count() is None or os.cpu_count() < 2:
        print("warning: fewer than 2 CPUs; the core-pinned scenarios share one core", file=sys.stderr)
    a.out.mkdir(parents=True, exist_ok=True)
    results = []
    with tempfile.TemporaryDirectory() as d:
        for s in tqdm(chosen, desc=f"jitter benchmark ({a.duration:g} s per scenario)", unit="scenario"):
            results.append(run(a.bin, s, a.duration, Path(d)))

    print(f"load average at the end: {' / '.join(f'{x:.2f}' for x in os.getloadavg())} (1/5/15 min), {os.cpu_count()} CPUs")
    hdr = ("| scenario | cycles | wake-up lateness (jitter) p50 / p99 / p99.9 / max (µs) | execution wall p50 / p99 / p99.9 / max (µs) "
           "| execution CPU p50 / p99 / p99.9 / max (µs) | period p50 / p99 / max (µs) | overruns = our execution (CPU) + thread not running (longest streak) | log queue high water |")
    print(hdr)
    print("|" + "---|" * 8)
    for r in results:
        s = r["summary"]
        print(
            f"| {r['scenario']} | {s['cycles']} | {s['jitter_p50_us']:.1f} / {s['jitter_p99_us']:.1f} / {s['jitter_p999_us']:.1f} / {s['jitter_max_us']:.1f} "
            f"| {s['exec_p50_us']:.1f} / {s['exec_p99_us']:.1f} / {s['exec_p999_us']:.1f} / {s['exec_max_us']:.1f} "
            f"| {s['exec_cpu_p50_us']:.1f} / {s['exec_cpu_p99_us']:.1f} / {s['exec_cpu_p999_us']:.1f} / {s['exec_cpu_max_us']:.1f} "
            f"| {s['period_p50_us']:.1f} / {s['period_p99_us']:.1f} / {s['period_max_us']:.1f} "
            f"| {s['overruns']} = {s['overruns_exec']} + {s['overruns_wakeup']} ({s['longest_overrun_streak']}) | {s['log_queue_high_water']} |"
        )
    for r in results:
        for w in r["warnings"]:
            print(f"{r['scenario']}: {w}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for r in results:
        late = r["lateness_us_sorted"]
        ccdf = 1.0 - np.arange(len(late)) / len(late)
        ax.loglog(np.maximum(late, 0.1), ccdf, label=f"{r['scenario']} (p99 {r['summary']['jitter_p99_us']:.1f} µs)")
    ax.axvline(50, color="k", ls="--", lw=0.8, label="target p99 50 µs")
    ax.axvline(200, color="r", ls=":", lw=0.8, label="period 200 µs")
    ax.set_xlabel("cycle start lateness vs absolute deadline (µs)")
    ax.set_ylabel("fraction of cycles later than x")
    ax.set_title(f"ehactl --realtime, 5 kHz, {a.duration:g} s per scenario\n{a.note or platform.node()}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    png = a.out / "jitter.png"
    fig.savefig(png, dpi=120)
    meta = {
        "command": " ".join(sys.argv),
        "duration_s": a.duration,
        "note": a.note,
        "kernel": platform.release(),
        "cpus": os.cpu_count(),
        "loadavg_after": os.getloadavg(),
        "results": [{k: v for k, v in r.items() if k != "lateness_us_sorted"} for r in results],
    }
    (a.out / "jitter.json").write_text(json.dumps(meta, indent=2))
    print(f"wrote {png} and {a.out / 'jitter.json'}")


if __name__ == "__main__":
    main()
