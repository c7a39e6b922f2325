#!/usr/bin/env python3
"""The CAN demo of docs/canopen.md, run N times, with the heartbeats timed at each stage.

One `ehactl canbus hub`, one `python -m ehactl.devices` (as the docs start them, in the
background for all runs) and N × `ehactl run CONFIG --hal canopen --bus …` with the config's
own heartbeat times (defaults: ehactl's heartbeat every 20 ms, consumed by the devices with
100 ms; the devices' every 20 ms, consumed by ehactl with 60 ms). A python-can listener on
the hub records the hub's receive stamp of every heartbeat. Per run:

- exit code and trip;
- ehactl's heartbeat 0x700 + master node (default 0x701): largest gap between the frames the
  TX thread sent (its /can log, ehactl's clock) and between the hub's stamps;
- the devices' heartbeats (0x720, 0x730): largest gap between the hub's stamps from the first
  to the last SYNC (the loop; the start-up resets the devices and sets their period);
- the transducer's answer to each SYNC (its synchronous TPDO 0x1A0): largest delay at the hub
  (hub stamps) and in ehactl (/can: SYNC sent by the TX thread → TPDO taken in by the RX
  thread), which the PDO age check (`canopen.max_pdo_age_syncs`) counts in SYNC periods;
- the loop's wake-up overruns, skipped deadlines, and how far loop time lagged the wall clock
  at the end (/timing: wall_t − t), which a heartbeat counted in loop time stretches by.

Usage: python3 bench/can_demo_heartbeat.py [--runs 10] [--duration 3] [--hogs 0]
       [--bin target/release/ehactl] [--config configs/dindorf2022_boom.toml]
Needs python-can, the ehactl bindings (ehactl.devices) and tests/python/ehactl_mcap.py.
"""
import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import threading
import time

import can
import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "python"))
from ehactl_mcap import read_can, read_run  # noqa: E402


def max_gap_ms(ts):
    """Largest gap between consecutive times (s) in ms, and the count above 50 ms."""
    d = np.diff(np.asarray(ts, dtype=float)) * 1e3
    return (float(d.max()) if len(d) else float("nan")), int((d > 50).sum())


def answer_ms(syncs, answers):
    """Largest time (ms) from SYNC k to the k-th answer (each SYNC gets one synchronous TPDO)."""
    n = min(len(syncs), len(answers))
    if n == 0:
        return float("nan")
    return float((np.asarray(answers[:n]) - np.asarray(syncs[:n])).max() * 1e3)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--duration", type=float, default=3.0, help="s per run")
    ap.add_argument("--hogs", type=int, default=0, help="busy-loop processes during the runs")
    ap.add_argument("--bin", default=os.environ.get("EHACTL_BIN",
                                                    str(REPO / "target" / "release" / "ehactl")))
    ap.add_argument("--config", default=str(REPO / "configs" / "dindorf2022_boom.toml"))
    a = ap.parse_args()
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="can_demo_"))
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}; "
          f"load {os.getloadavg()[0]:.2f}; {a.bin}; {a.config}; {a.hogs} hogs", flush=True)
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.hogs)]
    hub = subprocess.Popen([a.bin, "canbus", "hub", "--listen", "127.0.0.1:0"],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    dev = None
    bus = None
    trips = 0
    try:
        port = int(hub.stdout.readline().strip().rsplit(":", 1)[1])
        url = f"socketcand://127.0.0.1:{port}/can0"
        dev = subprocess.Popen([sys.executable, "-m", "ehactl.devices", "--bus", url,
                                "--config", a.config], stdout=subprocess.PIPE,
                               stderr=subprocess.DEVNULL, text=True, cwd=str(REPO))
        ready = dev.stdout.readline()
        if not ready.startswith("ehactl.devices ready"):
            raise SystemExit(f"devices did not start: {ready!r}")
        bus = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0",
                      tcp_tune=True)
        hb = {}
        stop = threading.Event()

        def listen():
            while not stop.is_set():
                m = bus.recv(0.05)
                if m is not None and (0x701 <= m.arbitration_id <= 0x77F
                                      or m.arbitration_id in (0x080, 0x1A0)):
                    hb.setdefault(m.arbitration_id, []).append(m.timestamp)

        th = threading.Thread(target=listen, daemon=True)
        th.start()
        print("| run | exit | trip | 0x701 TX max gap (ms) | 0x701 hub max gap (ms) "
              "| 0x720 / 0x730 hub max gap (ms) | SYNC → TPDO max at hub / in ehactl (ms) "
              "| overruns | skipped | loop lag (ms) |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for i in range(a.runs):
            out = tmp / f"run{i}.mcap"
            hb.clear()
            p = subprocess.run([a.bin, "run", a.config, "--hal", "canopen", "--bus", url,
                                "--json", "--duration", str(a.duration), "--out", str(out)],
                               capture_output=True, text=True, cwd=str(REPO))
            time.sleep(0.05)  # the listener takes the last frames in
            lines = [ln for ln in p.stdout.splitlines() if ln.strip()]
            s = json.loads(lines[-1]) if lines else {}
            trip = s.get("trip")
            trips += p.returncode != 0
            master = 0x700 + 1
            try:
                run = read_run(out, full_crc_pass=False)
                tm = run["timing"]
                lag = (float(tm["wall_t"][-1]) - float(tm["t"][-1])) * 1e3
                frames = read_can(out)
                tx = [f["t"] for f in frames
                      if f["dir"] == "tx" and f["id"] == master and f["t"] > 0]
                syncs = [f["t"] for f in frames if f["dir"] == "tx" and f["id"] == 0x080]
                tpdos = [f["t"] for f in frames if f["dir"] == "rx" and f["id"] == 0x1A0]
            except Exception as e:  # a start-up failure leaves no /timing
                lag, tx, syncs, tpdos = float("nan"), [], [], []
                trip = trip or str(e)
            g_tx, _ = max_gap_ms(tx)
            g_hub, n50 = max_gap_ms(hb.get(master, []))
            # the devices' heartbeats while the loop ran (first to last SYNC): in the start-up
            # the master resets them and sets their period
            sy = hb.get(0x080, [0.0])
            g_dev = [max_gap_ms([t for t in hb.get(c, []) if sy[0] <= t <= sy[-1]])[0]
                     for c in (0x720, 0x730)]
            # the transducer's answer to SYNC k (its k-th TPDO 0x1A0), at the hub and in ehactl
            r_hub = answer_ms(hb.get(0x080, []), hb.get(0x1A0, []))
            r_eh = answer_ms(syncs, tpdos)
            print(f"| {i} | {p.returncode} | {trip or '—'} | {g_tx:.1f} | {g_hub:.1f} ({n50} > 50) "
                  f"| {g_dev[0]:.1f} / {g_dev[1]:.1f} | {r_hub:.1f} / {r_eh:.1f} "
                  f"| {s.get('overruns_wakeup', '—')} "
                  f"| {s.get('skipped_deadlines', '—')} | {lag:.0f} |", flush=True)
        stop.set()
        th.join()
    finally:
        if bus is not None:
            bus.shutdown()
        for p in [dev, hub, *hogs]:
            if p is not None and p.poll() is None:
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
    print(f"{a.runs - trips} of {a.runs} runs without a trip; load {os.getloadavg()[0]:.2f}")
    return 1 if trips else 0


if __name__ == "__main__":
    sys.exit(main())
