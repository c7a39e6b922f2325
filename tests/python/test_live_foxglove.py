"""`ehactl run --live`: the running loop served over the Foxglove WebSocket protocol.

The client here is written against the published protocol spec (JSON ``serverInfo`` /
``advertise`` with inline schemas, client ``subscribe``, binary
``Message Data`` frames = opcode 0x01, uint32 subscription id, uint64 log time in ns, payload)
on the ``websockets`` package; the server is the Foxglove SDK's, which negotiates the
subprotocol ``foxglove.sdk.v1`` (the SDK's name for ``foxglove.websocket.v1``, same messages). CDR payloads are decoded with
the official ``mcap_ros2`` decoder from the advertised ros2msg schema, and every /control
message received is compared byte for byte with the MCAP log of the same run (official
``mcap`` reader). JSON messages are validated against the advertised JSON Schemas with
``jsonschema``.
"""

from __future__ import annotations

import json
import re
import struct
import subprocess
import time
from pathlib import Path

import jsonschema
import pytest
from mcap.reader import make_reader
from mcap_ros2._dynamic import generate_dynamic

websockets_sync = pytest.importorskip("websockets.sync.client")
from websockets.exceptions import ConnectionClosed  # noqa: E402

from test_mcap_roundtrip import FORCE_CONFIG, REPO, ehactl_bin, parse_json_stdout  # noqa: E402

SUBPROTOCOL = "foxglove.sdk.v1"
TOPICS = {"/control", "/plant", "/timing", "/config", "/events", "/log", "/summary"}
DURATION = 1.5  # s of wall-clock run


def start_live(out: Path, *extra: str, duration: float = DURATION) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [str(ehactl_bin()), "run", str(FORCE_CONFIG), "--realtime", "--duration", repr(duration),
         "--out", str(out), "--json", "--live", "127.0.0.1:0", *extra],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    url = None
    t_end = time.monotonic() + 30
    assert proc.stderr is not None
    while time.monotonic() < t_end:
        line = proc.stderr.readline()
        if not line:
            break
        m = re.search(r"live view \(Foxglove WebSocket\) on (ws://\S+)", line)
        if m:
            url = m.group(1)
            break
    if url is None:
        proc.kill()
        raise AssertionError(f"no live view URL on stderr: {proc.communicate()}")
    return proc, url


def test_live_view_streams_the_log_channels(tmp_path: Path) -> None:
    out = tmp_path / "live.mcap"
    proc, url = start_live(out)
    received: dict[str, list[tuple[int, bytes]]] = {t: [] for t in TOPICS}
    with websockets_sync.connect(url, subprotocols=[SUBPROTOCOL], open_timeout=10, max_size=None) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        channels: dict[int, dict] = {}
        server_info = None
        # serverInfo then advertise (all channels exist before the server starts)
        t_end = time.monotonic() + 10
        while time.monotonic() < t_end and not TOPICS <= {c["topic"] for c in channels.values()}:
            msg = ws.recv(timeout=5)
            if isinstance(msg, str):
                op = json.loads(msg)
                if op["op"] == "serverInfo":
                    server_info = op
                elif op["op"] == "advertise":
                    for c in op["channels"]:
                        channels[c["id"]] = c
        assert server_info is not None and server_info["name"].startswith("ehactl")
        by_topic = {c["topic"]: c for c in channels.values()}
        assert TOPICS <= set(by_topic), by_topic.keys()
        for t in ("/control", "/plant", "/timing"):
            assert by_topic[t]["encoding"] == "cdr" and by_topic[t]["schemaEncoding"] == "ros2msg"
        for t in ("/config", "/events", "/log", "/summary"):
            assert by_topic[t]["encoding"] == "json" and by_topic[t]["schemaEncoding"] == "jsonschema"
        assert by_topic["/log"]["schemaName"] == "foxglove.Log"
        assert by_topic["/control"]["schemaName"] == "ehactl_msgs/msg/ControlCycle"
        subs = {i + 1: c for i, c in enumerate(by_topic.values())}
        ws.send(json.dumps({"op": "subscribe",
                            "subscriptions": [{"id": sid, "channelId": c["id"]} for sid, c in subs.items()]}))
        try:
            while True:
                msg = ws.recv(timeout=15)
                if isinstance(msg, bytes):
                    assert msg[0] == 0x01, f"opcode {msg[0]}"
                    sid, ts = struct.unpack_from("<IQ", msg, 1)
                    received[subs[sid]["topic"]].append((ts, msg[13:]))
        except (ConnectionClosed, TimeoutError):  # the server closes at the end of the run
            pass
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    js = parse_json_stdout(stdout)
    live = js["live"]
    assert live["url"] == url
    n_control = len(received["/control"])
    assert n_control > 100, (n_control, live)
    # what the client got was published; nothing arrived that the server did not count
    assert live["messages_published"] >= n_control
    # CDR payloads decode with the official ROS 2 decoder from the advertised schema
    dec = generate_dynamic("ehactl_msgs/msg/ControlCycle", by_topic["/control"]["schema"])
    decode = dec["ehactl_msgs/msg/ControlCycle"]
    cycles = [decode(p).cycle for _, p in received["/control"]]
    assert cycles == sorted(cycles) and len(set(cycles)) == len(cycles)
    # byte-identical to the MCAP log of the same run (official reader)
    logged: dict[int, bytes] = {}
    with open(out, "rb") as f:
        for _s, _c, m in make_reader(f).iter_messages(topics=["/control"]):
            logged[m.sequence] = bytes(m.data)
    for _, p in received["/control"]:
        c = decode(p).cycle
        assert logged[c] == bytes(p), f"cycle {c} differs from the log"
    # log times increase and span the run (wall clock at the start + run time)
    ts = [t for t, _ in received["/control"]]
    assert ts == sorted(ts)
    assert (ts[-1] - ts[0]) * 1e-9 == pytest.approx(
        decode(received["/control"][-1][1]).t - decode(received["/control"][0][1]).t, abs=1e-6)
    # JSON channels validate against the schemas the server advertised
    for t in ("/config", "/events", "/log", "/summary"):
        schema = json.loads(by_topic[t]["schema"])
        for _, p in received[t]:
            jsonschema.validate(json.loads(p), schema)
    assert received["/config"], "no /config (it is repeated every second)"
    cfg = json.loads(received["/config"][0][1])
    assert cfg["config"]["rig"]["name"]
    kinds = [json.loads(p)["kind"] for _, p in received["/events"]]
    assert "end" in kinds, kinds
    logs = [json.loads(p) for _, p in received["/log"]]
    assert len(logs) == len(received["/events"])
    assert all(m["level"] in (2, 3, 4) and m["name"].startswith("ehactl/") for m in logs)
    assert received["/summary"], "no /summary at the end of the run"
    summ = json.loads(received["/summary"][-1][1])
    assert summ["cycles"] == js["cycles"]


def test_live_bad_address_is_one_line_error(tmp_path: Path) -> None:
    r = subprocess.run(
        [str(ehactl_bin()), "run", str(FORCE_CONFIG), "--duration", "0.01", "--out", str(tmp_path / "x.mcap"),
         "--live", "localhost"],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "--live localhost" in lines[0] and "HOST:PORT" in lines[0], r.stderr
    assert not (tmp_path / "x.mcap").exists()


# --- Slow clients and exposure -------------------------------------------------------------

import os  # noqa: E402
import socket  # noqa: E402
import base64  # noqa: E402


def _read_frames(buf: bytearray) -> list[tuple[int, bytes]]:
    """Complete server frames (unmasked, RFC 6455 §5.2) taken off the front of `buf`."""
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


def _masked_text(text: str) -> bytes:
    payload = text.encode()
    key = os.urandom(4)
    n = len(payload)
    head = bytes([0x81]) + (bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n))
    return head + key + bytes(b ^ key[i % 4] for i, b in enumerate(payload))


class SlowClient:
    """Upgrades, subscribes to every channel, then never reads (tiny receive buffer)."""

    def __init__(self, url: str, subprotocol: str) -> None:
        host, port = url.removeprefix("ws://").rsplit(":", 1)
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.settimeout(10)
        s.connect((host, int(port)))
        key = base64.b64encode(os.urandom(16)).decode()
        s.sendall((f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                   f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                   f"Sec-WebSocket-Protocol: {subprotocol}\r\n\r\n").encode())
        buf = bytearray()
        while b"\r\n\r\n" not in buf:
            buf += s.recv(4096)
        head, _, rest = bytes(buf).partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 101"), head
        assert f"sec-websocket-protocol: {subprotocol}".lower() in head.decode().lower(), head
        buf = bytearray(rest)
        channels: list[int] = []
        while not channels:
            for op, payload in _read_frames(buf):
                if op == 1 and json.loads(payload)["op"] == "advertise":
                    channels = [c["id"] for c in json.loads(payload)["channels"]]
            if not channels:
                buf += s.recv(65536)
        s.sendall(_masked_text(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i + 1, "channelId": c} for i, c in enumerate(channels)]})))
        self.sock = s
        self.port = s.getsockname()[1]
        self.buf = buf  # frames after the advertise, read with it

    def drain(self) -> int:
        """Read what reached this client until the server closes or resets the connection;
        returns the complete `Message Data` frames (opcode 0x01) among them."""
        self.sock.settimeout(5)
        try:
            while d := self.sock.recv(1 << 20):
                self.buf += d
        except OSError:  # reset: the server cut the client off
            pass
        self.sock.close()
        return sum(1 for op, p in _read_frames(self.buf) if op == 2 and p[:1] == b"\x01")


def test_slow_clients_dropped_messages_are_counted_per_client(tmp_path: Path) -> None:
    out = tmp_path / "slow.mcap"
    proc = subprocess.Popen(
        [str(ehactl_bin()), "run", str(FORCE_CONFIG), "--realtime", "--duration", "4",
         "--out", str(out), "--json", "--live", "127.0.0.1:0", "--live-max-clients", "20"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert proc.stderr is not None
    url = None
    while url is None:
        line = proc.stderr.readline()
        assert line, proc.communicate()
        m = re.search(r"on (ws://\S+)", line)
        url = m.group(1) if m else None
    # 20 clients that never read, half of them with each subprotocol name
    slow = [SlowClient(url, "foxglove.sdk.v1" if i % 2 else "foxglove.websocket.v1") for i in range(20)]
    stdout, stderr = proc.communicate(timeout=60)
    received = {c.port: c.drain() for c in slow}
    assert proc.returncode == 0, stderr
    live = parse_json_stdout(stdout)["live"]
    by_port = {int(c["peer"].rsplit(":", 1)[1]): c for c in live["clients"]}
    for c in slow:
        st = by_port[c.port]
        # each missed thousands of the ~60 000 messages published in 4 s at 5 kHz (4 s leaves
        # time for 20 handshakes on a loaded machine)
        assert st["messages_dropped"] > 1000, st
        # "sent" is what reached the client: exactly what it can read once it reads
        assert st["messages_sent"] == received[c.port], (st, received[c.port])
    assert live["client_messages_dropped"] == sum(c["messages_dropped"] for c in live["clients"])
    assert live["client_messages_dropped"] > 20 * 1000


def test_live_on_a_non_loopback_address_warns(tmp_path: Path) -> None:
    r = subprocess.run(
        [str(ehactl_bin()), "run", str(FORCE_CONFIG), "--duration", "0.05", "--out", str(tmp_path / "x.mcap"),
         "--live", "0.0.0.0:0"],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )
    assert r.returncode == 0, r.stderr
    warn = [ln for ln in r.stderr.splitlines() if "warning" in ln]
    assert len(warn) == 1, r.stderr
    assert "--live 0.0.0.0:" in warn[0] and "not a loopback address" in warn[0] and "network" in warn[0], warn
    # loopback: no warning
    r = subprocess.run(
        [str(ehactl_bin()), "run", str(FORCE_CONFIG), "--duration", "0.05", "--out", str(tmp_path / "y.mcap"),
         "--live", "127.0.0.1:0"],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr


def test_subprotocol_negotiation_through_the_front(tmp_path: Path) -> None:
    """The SDK's names pass through (v1.1 preferred, as the SDK does), the published name is
    answered as asked, an unknown one is refused with the SDK's HTTP 400 and counted."""
    from websockets.exceptions import InvalidStatus

    proc, url = start_live(tmp_path / "neg.mcap")
    try:
        for offered, answered in (
            (["foxglove.sdk.v1", "foxglove.sdk.v1.1"], "foxglove.sdk.v1.1"),
            (["foxglove.websocket.v1"], "foxglove.websocket.v1"),
            (["foxglove.websocket.v1", "foxglove.sdk.v1"], "foxglove.sdk.v1"),
        ):
            with websockets_sync.connect(url, subprotocols=offered, open_timeout=10) as ws:
                assert ws.subprotocol == answered, (offered, ws.subprotocol)
                first = json.loads(ws.recv(timeout=5))
                assert first["op"] == "serverInfo"
        with pytest.raises(InvalidStatus) as e:
            websockets_sync.connect(url, subprotocols=["bogus.v9"], open_timeout=10)
        assert e.value.response.status_code == 400
    finally:
        stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    live = parse_json_stdout(stdout)["live"]
    assert live["connections_refused"] == 1
    assert [c["subprotocol"] for c in live["clients"]] == [
        "foxglove.sdk.v1.1", "foxglove.websocket.v1", "foxglove.sdk.v1"]


def _listening_ports(pid: int) -> set[int]:
    """TCP ports process `pid` listens on (/proc/PID/net/tcp, its sockets from /proc/PID/fd)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            m = re.match(r"socket:\[(\d+)\]", str(fd.readlink()))
        except OSError:
            continue
        if m:
            inodes.add(m.group(1))
    ports = set()
    for line in Path(f"/proc/{pid}/net/tcp").read_text().splitlines()[1:]:
        f = line.split()
        if f[3] == "0A" and f[9] in inodes:  # state LISTEN
            ports.add(int(f[1].split(":")[1], 16))
    return ports


def test_a_direct_connection_to_the_internal_sdk_port_is_cut_off_and_counted(
        tmp_path: Path) -> None:
    """The SDK server's internal loopback port is reachable by any local process (the
    `foxglove` crate, 0.30, binds it itself): a client there would bypass the front's limit
    and per-client counts. It gets the SDK's handshake and `serverInfo`, then is cut off
    before any channel is advertised, counted in `live.direct_sdk_clients` and warned
    about; the front's clients are served as before, also one that connects after it."""
    proc, url = start_live(tmp_path / "direct.mcap")
    try:
        front = int(url.rsplit(":", 1)[1])
        t_end = time.monotonic() + 10
        internal: set[int] = set()
        while not internal and time.monotonic() < t_end:
            internal = _listening_ports(proc.pid) - {front}
            time.sleep(0.05)
        assert len(internal) == 1, (front, internal)
        sdk = f"ws://127.0.0.1:{internal.pop()}"
        with websockets_sync.connect(url, subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
            assert json.loads(ws.recv(timeout=5))["op"] == "serverInfo"
            assert json.loads(ws.recv(timeout=5))["op"] == "advertise"
        ops = []
        with websockets_sync.connect(sdk, subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
            with pytest.raises(ConnectionClosed):
                while True:
                    m = ws.recv(timeout=5)
                    ops.append(json.loads(m)["op"] if isinstance(m, str) else m[0])
        assert ops in ([], ["serverInfo"]), ops
        with websockets_sync.connect(url, subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
            assert json.loads(ws.recv(timeout=5))["op"] == "serverInfo"
            assert json.loads(ws.recv(timeout=5))["op"] == "advertise"
    finally:
        stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    live = parse_json_stdout(stdout)["live"]
    assert len(live["clients"]) == 2, live
    assert live["direct_sdk_clients"] == 1, live
    assert ("1 connection(s) reached the live view's internal Foxglove SDK port directly "
            "(a local process bypassing the front); each was cut off") in stderr


def _vm(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise AssertionError(f"no {key}")


def test_idle_clients_are_capped_and_cost_bounded_memory(tmp_path: Path) -> None:
    from faults import control_cycles

    out = tmp_path / "idle.mcap"
    proc = subprocess.Popen(
        [str(ehactl_bin()), "run", str(FORCE_CONFIG), "--realtime", "--duration", "8",
         "--out", str(out), "--json", "--live", "127.0.0.1:0", "--live-max-clients", "6"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert proc.stderr is not None
    url = None
    while url is None:
        line = proc.stderr.readline()
        assert line, proc.communicate()
        m = re.search(r"on (ws://\S+)", line)
        url = m.group(1) if m else None
    served, refused = [], []
    for _ in range(30):
        try:
            served.append(SlowClient(url, "foxglove.websocket.v1"))
        except (AssertionError, OSError) as e:
            refused.append(str(e))
    time.sleep(2.0)
    peak_mb = _vm(proc.pid, "VmHWM") / 1024
    stdout, stderr = proc.communicate(timeout=60)
    for c in served:
        c.sock.close()
    assert proc.returncode == 0, stderr
    # Six served, the others refused at once with a clear answer and counted.
    assert len(served) == 6 and len(refused) == 24, (len(served), refused[:2])
    assert all("503" in r for r in refused), refused[:2]
    live = parse_json_stdout(stdout)["live"]
    assert live["max_clients"] == 6
    assert live["clients_refused_over_limit"] == 24 and live["connections_refused"] == 24, live
    assert len(live["clients"]) == 6
    # An idle subscribed client costs a bounded, small amount (it was 7.5 MB each; the run
    # alone, locked in memory, is about 50 MB).
    assert peak_mb < 100, f"6 idle clients (24 refused): peak RSS {peak_mb:.0f} MB"
    # The loop and the log are untouched: every cycle logged, contiguous.
    assert control_cycles(out) == (int(8 * 5000), True)


def test_default_client_limit_holds_many_idle_clients_in_little_memory(tmp_path: Path) -> None:
    out = tmp_path / "many.mcap"
    proc = subprocess.Popen(
        [str(ehactl_bin()), "run", str(FORCE_CONFIG), "--realtime", "--duration", "6",
         "--out", str(out), "--json", "--live", "127.0.0.1:0"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert proc.stderr is not None
    url = None
    while url is None:
        line = proc.stderr.readline()
        assert line, proc.communicate()
        m = re.search(r"on (ws://\S+)", line)
        url = m.group(1) if m else None
    held = []
    for _ in range(60):
        try:
            held.append(SlowClient(url, "foxglove.websocket.v1"))
        except (AssertionError, OSError):
            pass
    time.sleep(1.5)
    peak_mb = _vm(proc.pid, "VmHWM") / 1024
    threads = _vm(proc.pid, "Threads")
    stdout, stderr = proc.communicate(timeout=60)
    for c in held:
        c.sock.close()
    assert proc.returncode == 0, stderr
    live = parse_json_stdout(stdout)["live"]
    assert live["clients_refused_over_limit"] == 60 - live["max_clients"], live
    assert peak_mb < 120, f"60 idle clients: peak RSS {peak_mb:.0f} MB"
    # The front's threads do not grow with the clients (it was three per client): the 16
    # served clients share its two workers, beside the run's own threads.
    assert threads <= 12, f"{threads} threads with {len(live['clients'])} clients"


def _closed_by_server(s: socket.socket) -> bool:
    """Whether the server closed or reset `s` (without waiting)."""
    s.setblocking(False)
    try:
        while s.recv(65536):
            pass
        return True  # end of stream
    except BlockingIOError:
        return False
    except OSError:
        return True  # reset
    finally:
        s.setblocking(True)


def test_connections_that_never_finish_the_handshake_lock_no_client_out(tmp_path: Path) -> None:
    """16 connections that send nothing, 4 that send half a request and one that trickles
    its request a byte every 0.5 s: none counts against --live-max-clients 2, so two real
    clients are served at once (a third is refused, the limit holds), and every stalled
    connection is closed by the server once its handshake time (5 s from accept, however
    often it sends) is over, well before the 14 s run ends."""
    out = tmp_path / "stall.mcap"
    proc, url = start_live(out, "--live-max-clients", "2", duration=14.0)
    host, port = url.removeprefix("ws://").rsplit(":", 1)
    stalled = []
    for k in range(20):
        s = socket.create_connection((host, int(port)), timeout=5)
        if k >= 16:
            s.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n")  # never ends its head
        stalled.append(s)
    trickle = socket.create_connection((host, int(port)), timeout=5)
    time.sleep(0.3)
    served = [SlowClient(url, "foxglove.websocket.v1") for _ in range(2)]
    with pytest.raises(AssertionError, match="503"):
        SlowClient(url, "foxglove.websocket.v1")
    request = b"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n" + b"X-Pad: " + b"a" * 200
    trickle_closed = False
    t0 = time.monotonic()
    for b in request:
        try:
            trickle.sendall(bytes([b]))
        except OSError:
            trickle_closed = True
            break
        if _closed_by_server(trickle):
            trickle_closed = True
            break
        if time.monotonic() - t0 > 10:
            break
        time.sleep(0.5)
    assert trickle_closed, "a request trickled a byte every 0.5 s was not cut off in 10 s"
    assert all(_closed_by_server(s) for s in stalled), "stalled connections still open"
    stdout, stderr = proc.communicate(timeout=60)
    for c in served:
        c.sock.close()
    assert proc.returncode == 0, stderr
    live = parse_json_stdout(stdout)["live"]
    assert len(live["clients"]) == 2, live
    assert live["clients_refused_over_limit"] == 1, live
    # The 21 stalled connections and the one over the limit.
    assert live["connections_refused"] == 22, live
