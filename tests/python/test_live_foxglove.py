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


def start_live(out: Path, *extra: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [str(ehactl_bin()), "run", str(FORCE_CONFIG), "--realtime", "--duration", repr(DURATION),
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
