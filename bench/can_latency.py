#!/usr/bin/env python3
"""CAN round-trip latency through `ehactl canbus hub` and its effect on the loop.

1. Starts the hub and a peer process built from the real python-can / canopen packages:
   it echoes ping frames (0x7E0 -> 0x7E1, same data) and serves SDO from a canopen
   LocalNode (node 0x40, object 0x1000).
2. Runs the Rust client (target/release/examples/can_latency, the same socketcand client
   and SDO code the master uses) for N pings and N SDO uploads; for context also a
   python-can client doing the same pings.
3. With --mcap RUN.mcap (a closed-loop `ehactl run --hal canopen` log), measures from the
   /can channel the time from each SYNC sent to the transducer TPDO that answers it (the k-th
   SYNC paired with the k-th TPDO), i.e. the extra dead time CAN adds to the loop on top of the
   SYNC period's sample-and-hold, and the fraction of TPDOs that arrive after the next SYNC.

Build first: cargo build --release -p ehactl-cli -p ehactl-canopen --examples
Usage: python3 bench/can_latency.py [--n 2000] [--mcap out/run.mcap] [--sim-mcap out/sim.mcap]
                                    [--plot bench/results/can_latency.png]
"""
import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import time

REPO = pathlib.Path(__file__).resolve().parents[1]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
CLIENT = str(REPO / "target" / "release" / "examples" / "can_latency")

PEER = r"""
import sys, time, canopen
from canopen.objectdictionary import ODVariable, UNSIGNED32
port = int(sys.argv[1])
net = canopen.Network()
net.connect(interface="socketcand", host="127.0.0.1", port=port, channel="can0", tcp_tune=True)
od = canopen.ObjectDictionary()
v = ODVariable("Device type", 0x1000, 0)
v.data_type = UNSIGNED32
v.access_type = "ro"
v.default = 0x00010196
od.add_object(v)
node = canopen.LocalNode(0x40, od)
net.add_node(node)
net.subscribe(0x7E0, lambda cob, data, ts: net.send_message(0x7E1, data))
print("ready", flush=True)
while True:
    time.sleep(1)
"""


def q(v, p):
    v = sorted(v)
    return v[round((len(v) - 1) * p)]


def python_ping(port, n):
    import can
    bus = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0", tcp_tune=True)
    rtt = []
    global PY_SAMPLES
    try:
        for i in range(n + 50):
            data = i.to_bytes(8, "little")
            t0 = time.perf_counter()
            bus.send(can.Message(arbitration_id=0x7E0, data=data, is_extended_id=False))
            while True:
                m = bus.recv(timeout=0.5)
                if m is None or (m.arbitration_id == 0x7E1 and bytes(m.data) == data):
                    break
            if i >= 50 and m is not None:
                rtt.append((time.perf_counter() - t0) * 1e6)
    finally:
        bus.shutdown()
    PY_SAMPLES = rtt
    return {"n": len(rtt), "median_us": statistics.median(rtt), "p99_us": q(rtt, 0.99), "max_us": max(rtt)}


PY_SAMPLES = []
LOOP_SAMPLES = []


def read_control(path):
    import ehactl  # the log reader of the Python bindings

    c = ehactl.read_mcap(path)["control"]
    return c["t"], c["position"], c["setpoint"]


def plot(out, rust, mcap, sim_mcap):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    fig, axes = plt.subplots(1, 2 if mcap else 1, figsize=(12 if mcap else 6.5, 4.5), squeeze=False)
    ax = axes[0][0]
    for label, v in [("ping, Rust master client", rust.get("ping_samples_us", [])),
                     ("SDO upload, Rust master client", rust.get("sdo_samples_us", [])),
                     ("ping, python-can client", PY_SAMPLES),
                     ("SYNC sent → position TPDO received (closed loop)", LOOP_SAMPLES)]:
        if len(v):
            x = np.sort(np.asarray(v))
            ax.plot(x, np.arange(1, len(x) + 1) / len(x), label=f"{label} (median {np.median(x):.0f} µs)")
    ax.set_xscale("log")
    ax.set_xlabel("round trip through the hub (µs)")
    ax.set_ylabel("fraction ≤ x")
    ax.set_title("CAN round trip via ehactl canbus hub (socketcand over loopback TCP)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    if mcap:
        ax = axes[0][1]
        t, x, r = read_control(mcap)
        ax.plot(t, r, "k--", lw=1, label="setpoint")
        ax.plot(t, x, label="position over CAN (--hal canopen)")
        if sim_mcap:
            ts, xs, _ = read_control(sim_mcap)
            ax.plot(ts, xs, ":", label="position, simulated time (--hal sim)")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("piston position (m)")
        ax.set_title("dindorf2022_boom step: CAN loop vs simulation")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    pathlib.Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)


def pair_sync_tpdo(frames, node):
    """Latency of each synchronous TPDO of `node` from the SYNC it answers (µs): the k-th SYNC
    the master sent (t >= 0) is paired with the k-th TPDO received. Pairing each TPDO with the
    latest SYNC before it (the earlier method, also returned) hides TPDOs that arrive after the
    next SYNC. Returns (latencies, fraction of TPDOs after the next SYNC, #SYNC, #TPDO, latest)."""
    syncs = [f["t"] for f in frames if f["t"] >= 0 and f["dir"] == "tx" and f["id"] == 0x080
             and f["dlc"] == 0]
    tpdos = [f["t"] for f in frames if f["t"] >= 0 and f["dir"] == "rx" and f["id"] == 0x180 + node]
    n = min(len(syncs), len(tpdos))
    lat = [(tpdos[k] - syncs[k]) * 1e6 for k in range(n)]
    late = sum(1 for k in range(n) if k + 1 < len(syncs) and tpdos[k] > syncs[k + 1])
    latest, j = [], -1
    for t in tpdos:
        while j + 1 < len(syncs) and syncs[j + 1] <= t:
            j += 1
        if j >= 0:
            latest.append((t - syncs[j]) * 1e6)
    return lat, (late / n if n else None), len(syncs), len(tpdos), latest


def loop_effect(mcap_path):
    from mcap.reader import make_reader
    frames = []
    with open(mcap_path, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages(topics=["/can"]):
            frames.append(json.loads(m.data))
    summary = None
    with open(mcap_path, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages(topics=["/summary"]):
            summary = json.loads(m.data)
    lat, late, n_sync, n_tpdo, latest = pair_sync_tpdo(frames, 0x20)
    LOOP_SAMPLES.extend(lat)
    sync_hz = (summary or {}).get("sync_rate_hz", 1000.0)
    return {
        "syncs": n_sync,
        "position_tpdos": n_tpdo,
        "pairing": "k-th SYNC with k-th TPDO (transmission type 1: one TPDO per SYNC, in order)",
        "tpdo_after_next_sync_fraction": late,
        "latest_sync_pairing_median_us": statistics.median(latest) if latest else None,
        "sync_to_position_tpdo_median_us": statistics.median(lat),
        "sync_to_position_tpdo_p99_us": q(lat, 0.99),
        "sync_to_position_tpdo_max_us": max(lat),
        "sync_period_us": 1e6 / sync_hz,
        "rms_error": (summary or {}).get("rms_error"),
        "max_abs_error": (summary or {}).get("max_abs_error"),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=2000, help="round trips per measurement")
    ap.add_argument("--mcap", help="closed-loop canopen run to analyse (/can channel)")
    ap.add_argument("--sim-mcap", help="the same config run in simulated time, for the plot")
    ap.add_argument("--plot", help="write a PNG: round-trip CDFs (and the step responses with --mcap)")
    a = ap.parse_args()
    for p in (BIN, CLIENT):
        if not os.path.exists(p):
            sys.exit(f"missing {p}; build with: cargo build --release -p ehactl-cli -p ehactl-canopen --examples")
    hub = subprocess.Popen([BIN, "canbus", "hub", "--listen", "127.0.0.1:0", "--quiet"], stdout=subprocess.PIPE, text=True)
    port = int(hub.stdout.readline().strip().rsplit(":", 1)[1])
    peer = subprocess.Popen([sys.executable, "-c", PEER, str(port)], stdout=subprocess.PIPE, text=True)
    try:
        assert peer.stdout.readline().strip() == "ready"
        r = subprocess.run([CLIENT, "--bus", f"socketcand://127.0.0.1:{port}/can0", "--n", str(a.n), "--node", "64", "--samples"],
                           capture_output=True, text=True, timeout=600, check=True)
        rust = json.loads(r.stdout)
        out = {"rust_client": {k: v for k, v in rust.items() if not k.endswith("_samples_us")},
               "python_can_client_ping": python_ping(port, a.n)}
    finally:
        peer.terminate()
        hub.terminate()
        peer.wait()
        hub.wait()
    if a.mcap:
        out["closed_loop"] = loop_effect(a.mcap)
    if a.plot:
        plot(a.plot, rust, a.mcap, a.sim_mcap)
        out["plot"] = a.plot
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
