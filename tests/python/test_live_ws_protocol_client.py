"""`ehactl run --live` with Foxglove's maintained protocol client, `@foxglove/ws-protocol`.

`FoxgloveClient` (npm ``@foxglove/ws-protocol`` 0.8.0, the library of the open-source viewers and
ROS tooling) offers the subprotocol ``foxglove.websocket.v1``, the protocol's published name; the
Foxglove SDK server inside ehactl names the same protocol ``foxglove.sdk.v1``. The Node script
tests/node/live_client.mjs connects with it over the ``ws`` package, subscribes to ``/control``
and decodes the CDR messages with Foxglove's ROS 2 decoder (``@foxglove/rosmsg2-serialization``)
from the advertised ros2msg schema; each decoded message is compared with the MCAP log of the
same run (official ``mcap`` reader, ``mcap_ros2`` decoder).

Skipped only when ``node`` is not installed; installs tests/node's locked dependencies
(``npm ci``) when they are missing.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap_ros2._dynamic import generate_dynamic

from test_live_foxglove import start_live
from test_mcap_roundtrip import parse_json_stdout

REPO = Path(__file__).resolve().parents[2]
NODE_DIR = REPO / "tests" / "node"

pytestmark = pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")


@pytest.fixture(scope="module")
def node() -> str:
    node = shutil.which("node")
    assert node is not None
    if not (NODE_DIR / "node_modules" / "@foxglove" / "ws-protocol").is_dir():
        npm = shutil.which("npm")
        assert npm is not None, "node is installed but npm is not: cannot install tests/node dependencies"
        proc = subprocess.run(
            [npm, "ci", "--no-audit", "--no-fund"], cwd=NODE_DIR, capture_output=True, text=True, timeout=600
        )
        assert proc.returncode == 0, f"npm ci failed:\n{proc.stdout}\n{proc.stderr}"
    return node


# s of wall-clock run: room for Node to start and connect on a loaded machine (in CI it once
# took longer than the 1.5 s run of the other live tests: the server had closed, ECONNREFUSED)
RUN_S = 6.0
MESSAGES = 2000  # the client disconnects after this many; the run goes on to its end


def test_foxglove_ws_protocol_client_receives_control(tmp_path: Path, node: str) -> None:
    out = tmp_path / "live.mcap"
    proc, url = start_live(out, duration=RUN_S)
    try:
        client = subprocess.run(
            [node, str(NODE_DIR / "live_client.mjs"), url, "/control", str(MESSAGES), "20"],
            cwd=NODE_DIR, capture_output=True, text=True, timeout=60,
        )
    finally:
        stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    assert client.returncode == 0, (client.stdout, client.stderr, stderr)
    res = json.loads(client.stdout.strip().splitlines()[-1])
    assert res["errors"] == [], res["errors"]
    # the client asked for the protocol's published name and got it
    assert res["subprotocol"] == "foxglove.websocket.v1"
    assert res["server_name"].startswith("ehactl")
    assert res["channel"]["schemaName"] == "ehactl_msgs/msg/ControlCycle"
    assert res["trailing_bytes"] == 0
    n = res["messages"]
    assert n >= 100, res
    cycles = [d["cycle"] for d in res["decoded"]]
    assert cycles == sorted(cycles) and len(set(cycles)) == n
    log_times = [int(t) for t in res["log_times_ns"]]
    assert log_times == sorted(log_times)
    # what the npm decoder read is what the run logged (official reader and decoder)
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        schema = next(s for s in summary.schemas.values() if s.name == "ehactl_msgs/msg/ControlCycle")
        decode = generate_dynamic(schema.name, schema.data.decode())[schema.name]
        logged = {m.sequence: decode(m.data).t for _s, _c, m in reader.iter_messages(topics=["/control"])}
    for d in res["decoded"]:
        assert d["t"] == logged[d["cycle"]], d
    js = parse_json_stdout(stdout)
    assert js["live"]["messages_published"] >= n
