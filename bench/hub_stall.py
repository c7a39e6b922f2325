#!/usr/bin/env python3
"""Latency of a healthy client through `ehactl canbus hub` while other clients stall.

Clients (raw socketcand rawmode over TCP, no library in the way):
- a probe sender: every 1 ms one frame 0x7E0 carrying its send time (time.perf_counter_ns);
- a probe receiver: the latency of each probe = receive time - send time (same clock);
- a bulk sender: 8 frames 0x181 every 1 ms (8 kframes/s, about a fully loaded 1 Mbit/s bus),
  so that clients that do not read fill their socket buffers within seconds;
- --stalled K clients that complete the handshake into rawmode and then never read.
The two senders read (and discard) what the hub sends them, as healthy clients do.

Reports p50 / p99 / max of the probe latency, lost probes and the hub's "dropped" lines.
Run it against the old hub binary to compare (EHACTL_BIN=...).

Usage: python3 bench/hub_stall.py [--stalled 3] [--seconds 20]
"""
import argparse
import os
import pathlib
import re
import socket
import statistics
import subprocess
import sys
import threading
import time

REPO = pathlib.Path(__file__).resolve().parents[1]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))


def rawmode(port):
    s = socket.create_connection(("127.0.0.1", port))
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    for send, want in ((None, b"< hi >"), (b"< open can0 >", b"< ok >"), (b"< rawmode >", b"< ok >")):
        if send:
            s.sendall(send)
        got = s.recv(64)
        if got != want:
            raise SystemExit(f"handshake: expected {want!r}, got {got!r}")
    return s


def frame(cob, data):
    return f"< send {cob:X} {len(data)} {' '.join(f'{b:02X}' for b in data)} >".encode()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--stalled", type=int, default=3, help="clients that never read")
    ap.add_argument("--seconds", type=float, default=20.0, help="probe duration (s)")
    a = ap.parse_args()
    hub = subprocess.Popen([BIN, "canbus", "hub", "--listen", "127.0.0.1:0"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    port = int(hub.stdout.readline().strip().rsplit(":", 1)[1])
    hub_err = []
    threading.Thread(target=lambda: hub_err.extend(hub.stderr), daemon=True).start()
    rx, tx, bulk = rawmode(port), rawmode(port), rawmode(port)
    _stalled = [rawmode(port) for _ in range(a.stalled)]  # kept referenced: their sockets stay open, unread
    time.sleep(0.5)  # past the join delays
    lat, stop = [], threading.Event()

    def receive():
        buf = b""
        rx.settimeout(0.2)
        while not stop.is_set():
            try:
                chunk = rx.recv(65536)
            except socket.timeout:
                continue
            if not chunk:
                return
            buf += chunk
            now = time.perf_counter_ns()
            while b">" in buf:
                msg, _, buf = buf.partition(b">")
                m = re.match(rb"\s*< frame 7E0 \S+ ([0-9A-F]{16})", msg + b">")
                if m:
                    lat.append((now - int(m.group(1), 16)) * 1e-9)

    def flood():
        k = 0
        burst = b"".join(frame(0x181, (i & 0xFF,) * 8) for i in range(8))
        while not stop.is_set():
            bulk.sendall(burst)
            k += 1
            time.sleep(0.001)

    def drain(sock):  # the two senders are healthy clients too: they read what they get
        sock.settimeout(0.2)
        while not stop.is_set():
            try:
                if not sock.recv(65536):
                    return
            except socket.timeout:
                continue
            except OSError:
                return

    threads = [threading.Thread(target=receive, daemon=True), threading.Thread(target=flood, daemon=True),
               threading.Thread(target=drain, args=(tx,), daemon=True),
               threading.Thread(target=drain, args=(bulk,), daemon=True)]
    for t in threads:
        t.start()
    sent, t_end = 0, time.monotonic() + a.seconds
    next_t = time.monotonic()
    while time.monotonic() < t_end:
        tx.sendall(frame(0x7E0, time.perf_counter_ns().to_bytes(8, "big")))
        sent += 1
        next_t += 0.001
        time.sleep(max(0.0, next_t - time.monotonic()))
    time.sleep(0.5)
    stop.set()
    for t in threads:
        t.join(2)
    hub.terminate()
    hub.wait(5)
    dropped = [ln.strip() for ln in hub_err if "dropped" in ln]
    lat.sort()
    if not lat:
        print(f"stalled={a.stalled}: no probe received ({sent} sent)")
        return 1
    def p(q: float) -> float:
        return lat[min(len(lat) - 1, int(q * len(lat)))] * 1e3

    print(f"stalled={a.stalled} seconds={a.seconds:g} probes sent={sent} received={len(lat)} "
          f"p50={p(0.50):.3f} ms p99={p(0.99):.3f} ms max={lat[-1] * 1e3:.3f} ms "
          f"mean={statistics.mean(lat) * 1e3:.3f} ms; hub dropped {len(dropped)} client(s)")
    for d in dropped:
        print("  " + d)
    return 0


if __name__ == "__main__":
    sys.exit(main())
