#!/usr/bin/env python3
"""Memory of `ehactl run --live` with many clients that subscribe and then never read.

Starts a real-time run of configs/sahu2022_force.toml with the live view on a free loopback
port, connects N WebSocket clients (HTTP upgrade with `foxglove.websocket.v1`, subscribe to
every advertised channel, tiny receive buffer, never read again), waits, and samples the
controller's resident memory (VmRSS, and VmHWM = peak) from /proc. Prints one JSON line with
the figures and the run's own live summary (clients served, connections refused, messages
dropped) and the machine's load average.

    python3 bench/live_idle_clients.py --clients 300 [--duration 60] [--bin target/release/ehactl]

Exit status 1 if the peak RSS is above --limit-mb (default 200).
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import re
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _status(pid: int) -> dict[str, int]:
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, rest = line.partition(":")
        if key in ("VmRSS", "VmHWM", "Threads"):
            out[key] = int(rest.split()[0])
    return out


def _masked_text(text: str) -> bytes:
    payload = text.encode()
    key = os.urandom(4)
    n = len(payload)
    head = bytes([0x81]) + (bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n))
    return head + key + bytes(b ^ key[i % 4] for i, b in enumerate(payload))


def _frames(buf: bytearray) -> list[tuple[int, bytes]]:
    out = []
    while len(buf) >= 2:
        n, hdr = buf[1] & 0x7F, 2
        if n == 126:
            if len(buf) < 4:
                break
            n, hdr = struct.unpack_from(">H", buf, 2)[0], 4
        elif n == 127:
            if len(buf) < 10:
                break
            n, hdr = struct.unpack_from(">Q", buf, 2)[0], 10
        if len(buf) < hdr + n:
            break
        out.append((buf[0] & 0x0F, bytes(buf[hdr:hdr + n])))
        del buf[:hdr + n]
    return out


def idle_client(host: str, port: int) -> socket.socket | None:
    """Upgrade, subscribe to every channel, return the socket (never read again); None if
    the server refused the connection."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.settimeout(10)
    try:
        s.connect((host, port))
        key = base64.b64encode(os.urandom(16)).decode()
        s.sendall((f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                   f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                   "Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n").encode())
        buf = bytearray()
        while b"\r\n\r\n" not in buf:
            d = s.recv(4096)
            if not d:
                s.close()
                return None
            buf += d
        head, _, rest = bytes(buf).partition(b"\r\n\r\n")
        if not head.startswith(b"HTTP/1.1 101"):
            s.close()
            return None
        buf = bytearray(rest)
        channels: list[int] = []
        while not channels:
            for op, payload in _frames(buf):
                if op == 1 and json.loads(payload).get("op") == "advertise":
                    channels = [c["id"] for c in json.loads(payload)["channels"]]
            if not channels:
                d = s.recv(65536)
                if not d:
                    s.close()
                    return None
                buf += d
        s.sendall(_masked_text(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i + 1, "channelId": c} for i, c in enumerate(channels)]})))
        return s
    except OSError:
        s.close()
        return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=300)
    ap.add_argument("--duration", type=float, default=60.0,
                    help="run length (s, wall clock); 300 clients took 25-42 s to connect on a loaded 2-core machine")
    ap.add_argument("--hold", type=float, default=6.0, help="s to hold all clients before sampling")
    ap.add_argument("--bin", default=os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl")))
    ap.add_argument("--limit-mb", type=float, default=200.0)
    ap.add_argument("extra", nargs="*", help="more `ehactl run` arguments, after --")
    a = ap.parse_args()
    out = Path(os.environ.get("TMPDIR", "/tmp")) / f"live_idle_{os.getpid()}.mcap"
    proc = subprocess.Popen(
        [a.bin, "run", str(REPO / "configs" / "sahu2022_force.toml"), "--realtime", "--duration",
         repr(a.duration), "--out", str(out), "--json", "--live", "127.0.0.1:0", *a.extra],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    url = None
    while url is None:
        line = proc.stderr.readline()
        if not line:
            print(proc.communicate(), file=sys.stderr)
            return 2
        m = re.search(r"on ws://(\S+):(\d+)", line)
        url = (m.group(1), int(m.group(2))) if m else None
    rss0 = _status(proc.pid)["VmRSS"]
    t0 = time.monotonic()
    clients = [idle_client(*url) for _ in range(a.clients)]
    connect_s = time.monotonic() - t0
    served = [c for c in clients if c is not None]
    time.sleep(a.hold)
    if proc.poll() is not None:
        print(f"the run ended before the clients were held ({connect_s:.0f} s to connect): raise --duration",
              file=sys.stderr)
        return 2
    st = _status(proc.pid)
    st["fds"] = len(os.listdir(f"/proc/{proc.pid}/fd"))
    stdout, stderr = proc.communicate(timeout=a.duration + 120)
    for c in served:
        c.close()
    out.unlink(missing_ok=True)
    try:
        live = json.loads(stdout.strip().splitlines()[-1]).get("live", {})
    except (json.JSONDecodeError, IndexError):
        live = {}
    result = {
        "clients_tried": a.clients,
        "clients_upgraded": len(served),
        "connect_s": round(connect_s, 2),
        "rss_before_clients_mb": round(rss0 / 1024, 1),
        "rss_with_clients_mb": round(st["VmRSS"] / 1024, 1),
        "peak_rss_mb": round(st["VmHWM"] / 1024, 1),
        "threads": st["Threads"],
        "open_files": st["fds"],
        "exit": proc.returncode,
        "live_clients_served": len(live.get("clients", [])),
        "live_connections_refused": live.get("connections_refused"),
        "live_clients_refused_over_limit": live.get("clients_refused_over_limit"),
        "loop_messages_dropped_before_server": live.get("messages_dropped"),
        "loadavg": os.getloadavg(),
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
    }
    print(json.dumps(result))
    if proc.returncode != 0:
        print(stderr, file=sys.stderr)
        return 2
    return 0 if st["VmHWM"] / 1024 <= a.limit_mb else 1


if __name__ == "__main__":
    sys.exit(main())
