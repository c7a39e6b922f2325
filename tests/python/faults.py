"""Fault injection against the `ehactl run` process, shared by
tests/python/test_reliability.py (a few runs per fault) and bench/fault_injection.py (the
table in BENCHMARKS.md).

Each fault runs one `ehactl run`, injects the fault, and reports what a user gets back:
cycles the loop ran (from the summary, or from wall time for SIGKILL), records readable
from the log (after `ehactl recover` when the file was not finalised), and the time from
the fault to the process's exit (for SIGINT/SIGTERM: the run's safe stop)."""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from mcap.reader import make_reader

REPO = Path(__file__).resolve().parents[2]
FORCE_CONFIG = REPO / "configs" / "sahu2022_force.toml"
RATE_HZ = 5000.0


def ehactl_bin() -> Path:
    return Path(os.environ.get("EHACTL_BIN", REPO / "target" / "release" / "ehactl"))


@dataclass
class FaultResult:
    fault: str
    mode: str
    rc: int
    cycles_run: int  # from the summary; for SIGKILL estimated from wall time (real time)
    records_back: int  # /control messages readable (after recover if needed)
    contiguous: bool  # cycles 0..n-1 without a gap
    recovered: bool  # `ehactl recover` was needed
    exit_after_fault_s: float  # fault → process exit (wall)
    stderr: str


def control_cycles(path: Path) -> tuple[int, bool]:
    """Count /control messages with the official reader (CRCs validated) and check that their
    sequence numbers (= cycle) run 0..n-1."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        seqs = [m.sequence for _, c, m in reader.iter_messages(topics=["/control"], log_time_order=False)]
    return len(seqs), seqs == list(range(len(seqs)))


def _readable(path: Path, tmp: Path) -> tuple[int, bool, bool]:
    try:
        n, ok = control_cycles(path)
        return n, ok, False
    except Exception:
        fixed = tmp / (path.stem + ".recovered.mcap")
        if fixed.exists():
            fixed.unlink()
        r = subprocess.run([str(ehactl_bin()), "recover", str(path), str(fixed), "--json"],
                           capture_output=True, text=True, timeout=60)
        if r.returncode != 0:
            raise AssertionError(f"recover failed: {r.stderr}")
        n, ok = control_cycles(fixed)
        return n, ok, True


def run_with_fault(tmp: Path, fault: str, mode: str, after_s: float, config: Path = FORCE_CONFIG) -> FaultResult:
    """fault: sigint | sigterm | sigkill | disk_full | read_only; mode: sim | realtime."""
    out_dir = tmp / "out"
    out_dir.mkdir(exist_ok=True)
    out = out_dir / f"{fault}_{mode}.mcap"
    if out.exists():
        out.unlink()
    cmd = [str(ehactl_bin()), "run", str(config), "--out", str(out), "--json"]
    cmd += ["--duration", "600" if mode == "sim" else "30"]
    if mode == "realtime":
        cmd.append("--realtime")
    preexec = None
    if fault == "disk_full":
        limit = 3_000_000  # bytes: the log hits it within a second

        def preexec():  # noqa: F811 - runs in the child before exec
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of death
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    if fault == "read_only":
        os.chmod(out_dir, 0o555)
        if os.geteuid() == 0:
            # root ignores directory modes: sysfs refuses new files even to root.
            out = Path("/sys/ehactl-fault-test.mcap")
            cmd[cmd.index("--out") + 1] = str(out)
    t0 = time.monotonic()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=preexec)
    t_fault = None
    if fault in ("sigint", "sigterm", "sigkill"):
        time.sleep(after_s)
        t_fault = time.monotonic()
        p.send_signal({"sigint": signal.SIGINT, "sigterm": signal.SIGTERM, "sigkill": signal.SIGKILL}[fault])
    try:
        stdout, stderr = p.communicate(timeout=120)
    finally:
        if fault == "read_only":
            os.chmod(out_dir, 0o755)
        if p.poll() is None:
            p.kill()
    t_end = time.monotonic()
    exit_after = t_end - (t_fault if t_fault is not None else t0)
    rc = p.returncode
    if fault == "read_only":
        return FaultResult(fault, mode, rc, 0, 0, True, False, exit_after, stderr)
    summary = None
    for line in stdout.splitlines():
        if line.strip().startswith("{"):
            obj = json.loads(line)
            # A failed run (full disk) prints its `error` object instead of the summary.
            summary = obj if "cycles" in obj else None
    n_back, contiguous, recovered = _readable(out, tmp) if out.exists() else (0, True, False)
    if summary is not None:
        cycles = int(summary["cycles"])
    elif fault == "sigkill" and mode == "realtime":
        cycles = int((t_fault - t0) * RATE_HZ)  # upper bound: the loop starts after launch
    else:
        cycles = -1  # unknown (simulated time runs ahead of the wall clock)
    return FaultResult(fault, mode, rc, cycles, n_back, contiguous, recovered, exit_after, stderr)
