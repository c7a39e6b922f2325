"""Fault-injection table for BENCHMARKS.md: each fault injected RUNS times at a
random moment into `ehactl run` of the Sahu 2022 rig, in simulated and in wall-clock time.

    python3 bench/fault_injection.py [RUNS] [--seed N]

Prints a Markdown table: fault, mode, runs, exit codes, records lost (cycles run minus
records readable from the log, after `ehactl recover` where needed; median / max), whether
every log was contiguous, and the time from the fault to the process's exit (the safe stop
for SIGINT/SIGTERM; median / max). For SIGKILL in real time, "cycles run" is the wall time
from launch to the kill × 5 kHz, an upper bound (the loop starts a little after launch), so
the loss shown includes the start-up. SIGKILL in simulated time has no wall-clock cycle count:
its loss is not measurable and shown as "—"."""

from __future__ import annotations

import random
import statistics
import sys
import tempfile
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from faults import RATE_HZ, run_with_fault  # noqa: E402

FAULTS = [
    ("sigint", "sim"), ("sigint", "realtime"),
    ("sigterm", "sim"), ("sigterm", "realtime"),
    ("sigkill", "sim"), ("sigkill", "realtime"),
    ("disk_full", "sim"), ("disk_full", "realtime"),
    ("read_only", "sim"),
]


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    runs = int(args[0]) if args else 5
    seed = int(sys.argv[sys.argv.index("--seed") + 1]) if "--seed" in sys.argv else 1
    rng = random.Random(seed)
    print("| fault | mode | runs | exit codes | records lost (median / max) | logs contiguous | fault → exit (median / max) |")
    print("|---|---|---|---|---|---|---|")
    for fault, mode in FAULTS:
        losses, exits, codes, contiguous = [], [], Counter(), True
        for _ in range(runs):
            with tempfile.TemporaryDirectory() as d:
                r = run_with_fault(Path(d), fault, mode, rng.uniform(0.3, 2.0))
            codes[r.rc] += 1
            exits.append(r.exit_after_fault_s)
            contiguous &= r.contiguous
            if r.cycles_run >= 0 and fault != "read_only":
                losses.append(max(r.cycles_run - r.records_back, 0))
        loss = (f"{statistics.median(losses):.0f} / {max(losses)} cycles "
                f"({max(losses) / RATE_HZ * 1e3:.0f} ms max)") if losses else "—"
        code_text = ", ".join(f"{c}×{n}" for c, n in sorted(codes.items()))
        print(f"| {fault} | {mode} | {runs} | {code_text} | {loss} | {'yes' if contiguous else 'NO'} | "
              f"{statistics.median(exits) * 1e3:.0f} / {max(exits) * 1e3:.0f} ms |")


if __name__ == "__main__":
    main()
