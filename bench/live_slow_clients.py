"""Fault-injection row for BENCHMARKS.md: 20 live-view clients that subscribe to every channel
and never read, against `ehactl run configs/sahu2022_force.toml --realtime --duration 2
--live 127.0.0.1:0` (5 kHz).

    EHACTL_BIN=target/release/ehactl python3 bench/live_slow_clients.py [RUNS] [--sdk-only]

`--sdk-only`: every client offers `foxglove.sdk.v1` (for builds before `foxglove.websocket.v1`
was accepted). A process still running 30 s after the end of its run is reported as hung, and
the clients are then closed.

Per run: exit code, records lost (cycles run minus `/control` records the official `mcap`
reader finds), the time from the end of the run's duration to the process's exit (launch →
exit minus 2 s, so it includes the start-up), the messages each slow client missed
(`live.clients[].messages_dropped`) and the loop's overruns. Prints one Markdown row in the
format of the fault-injection table, then the per-client drops and overruns."""

from __future__ import annotations

import json
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from mcap.reader import make_reader  # noqa: E402
from test_live_foxglove import FORCE_CONFIG, REPO, SlowClient, ehactl_bin  # noqa: E402

DURATION = 2.0
CLIENTS = 20
HANG_S = 30.0


def one_run(out: Path, sdk_only: bool) -> dict:
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [str(ehactl_bin()), "run", str(FORCE_CONFIG), "--realtime", "--duration", repr(DURATION),
         "--out", str(out), "--force", "--json", "--live", "127.0.0.1:0", "--live-max-clients", "20"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert proc.stderr is not None
    url = None
    while url is None:
        line = proc.stderr.readline()
        if not line:
            raise SystemExit(f"no live URL: {proc.communicate()}")
        m = re.search(r"on (ws://\S+)", line)
        url = m.group(1) if m else None
    slow = [SlowClient(url, "foxglove.websocket.v1" if i % 2 and not sdk_only else "foxglove.sdk.v1")
            for i in range(CLIENTS)]
    hung = False
    try:
        stdout, _ = proc.communicate(timeout=DURATION + HANG_S)
        t_exit = time.monotonic() - t0
    except subprocess.TimeoutExpired:
        hung = True
        t_exit = time.monotonic() - t0
        for c in slow:
            c.sock.close()
        stdout, _ = proc.communicate(timeout=60)
    finally:
        for c in slow:
            c.sock.close()
    js = json.loads(stdout.strip().splitlines()[-1])
    with open(out, "rb") as f:
        records = sum(1 for _ in make_reader(f).iter_messages(topics=["/control"]))
    ports = {c.port for c in slow}
    dropped = [c["messages_dropped"] for c in js["live"].get("clients", [])
               if int(c["peer"].rsplit(":", 1)[1]) in ports]
    return {
        "hung": hung,
        "code": proc.returncode,
        "lost": js["cycles"] - records,
        "end_to_exit_ms": (t_exit - DURATION) * 1e3,
        "dropped": dropped,
        "published": js["live"]["messages_published"],
        "live_dropped": js["live"]["messages_dropped"],
        "overruns": js.get("overruns"),
    }


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    runs = int(args[0]) if args else 5
    sdk_only = "--sdk-only" in sys.argv
    res = []
    with tempfile.TemporaryDirectory() as d:
        for i in range(runs):
            res.append(one_run(Path(d) / f"r{i}.mcap", sdk_only))
    codes = ", ".join(f"{c}×{sum(r['code'] == c for r in res)}" for c in sorted({r["code"] for r in res}))
    lost = [r["lost"] for r in res]
    ex = [r["end_to_exit_ms"] for r in res]
    print(f"| {CLIENTS} `--live` clients that never read | realtime | {runs} | {codes} | "
          f"{statistics.median(lost):.0f} / {max(lost)} | yes | "
          f"{statistics.median(ex):.0f} / {max(ex):.0f} ms from the end of the {DURATION:g} s run |")
    for r in res:
        d = sorted(r["dropped"])
        counts = (f"dropped min {d[0]} / median {statistics.median(d):.0f} / max {d[-1]}" if d
                  else "no per-client counts")
        print(f"  {'HUNG (no exit within 30 s of the end, exited after the clients closed); ' if r['hung'] else ''}"
              f"clients {len(d)}: {counts} of {r['published']} published; "
              f"live.messages_dropped {r['live_dropped']}; overruns {r['overruns']}")


if __name__ == "__main__":
    main()
