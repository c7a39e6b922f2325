"""Stop latency of a signal during the CANopen start-up (BENCHMARKS.md, fault injection).

    EHACTL_BIN=target/release/ehactl python3 bench/startup_signal.py [N]

Per run: `ehactl canbus hub` with no devices, `ehactl run configs/dindorf2022_boom.toml --hal
canopen` with `canopen.boot_timeout_s = 20` (so the start-up waits for boot-ups and probes by
SDO), SIGTERM or SIGINT at a random moment 0.3-2 s after launch; prints exit code and the time
from the signal to the exit, then the median / max per signal. Run from the repository root."""
import json
import pathlib
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests" / "python"))
from canhub import BIN, REPO, hub  # noqa: E402


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="ehactl_sigbench_"))
    cfg = tmp / "boom.toml"
    cfg.write_text((REPO / "configs" / "dindorf2022_boom.toml").read_text()
                   + "\n[canopen]\nboot_timeout_s = 20.0\n")
    res = {}
    for sig in ("SIGTERM", "SIGINT"):
        for k in range(n):
            at = random.uniform(0.3, 2.0)
            with hub() as (_, port):
                p = subprocess.Popen([BIN, "run", str(cfg), "--json", "--out",
                                      str(tmp / f"{sig}_{k}.mcap"), "--hal", "canopen",
                                      "--bus", f"socketcand://127.0.0.1:{port}/can0"],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                time.sleep(at)
                t0 = time.monotonic()
                p.send_signal(getattr(signal, sig))
                out, _ = p.communicate(timeout=60)
                dt = time.monotonic() - t0
            s = json.loads(out.strip().splitlines()[-1])
            res.setdefault(sig, []).append((p.returncode, dt, s.get("interrupted")))
            print(f"{sig} at {at:.2f} s: exit {p.returncode}, {dt * 1e3:.1f} ms, "
                  f"interrupted={s.get('interrupted')}", flush=True)
    for sig, r in res.items():
        ms = [dt * 1e3 for _, dt, _ in r]
        codes = sorted({c for c, _, _ in r})
        print(f"{sig}: {len(r)} runs, exit codes {codes}, signal → exit median "
              f"{statistics.median(ms):.1f} ms, max {max(ms):.1f} ms")


if __name__ == "__main__":
    main()
