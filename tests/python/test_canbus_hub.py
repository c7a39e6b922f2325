"""`ehactl canbus hub` against the real python-can `socketcand` interface as peers."""
import json
import random
import re
import socket
import subprocess
import threading
import time

import can
import pytest

from canhub import BIN, REPO, hub
from ehactl_mcap import read_can, read_run


def bus(port, channel="can0"):
    return can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel=channel, tcp_tune=True)


def drain(b, timeout=0.3):
    out = []
    while True:
        m = b.recv(timeout=timeout)
        if m is None:
            return out
        out.append(m)


def test_frames_relay_between_python_can_clients_without_echo():
    with hub() as (_, port):
        a, b, c = bus(port), bus(port), bus(port, channel="can1")
        try:
            sent = [
                can.Message(arbitration_id=0x080, data=b"", is_extended_id=False),  # SYNC, empty
                can.Message(arbitration_id=0x1A0, data=bytes([0xDE, 0xAD, 0xBE, 0xEF]), is_extended_id=False),
                can.Message(arbitration_id=0x7FF, data=bytes(range(8)), is_extended_id=False),
                can.Message(arbitration_id=0x005, data=b"\x01", is_extended_id=False),  # 3-digit "005"
                can.Message(arbitration_id=0x1ABCDEF0, data=b"\x00\xff", is_extended_id=True),
            ]
            for m in sent:
                a.send(m)
            got = []
            deadline = time.monotonic() + 5
            while len(got) < len(sent) and time.monotonic() < deadline:
                m = b.recv(timeout=0.5)
                if m is not None:
                    got.append(m)
            assert [(m.arbitration_id, bytes(m.data), m.is_extended_id, m.dlc) for m in got] == [
                (m.arbitration_id, bytes(m.data), m.is_extended_id, len(m.data)) for m in sent
            ]
            assert got[0].dlc == 0 and bytes(got[0].data) == b""
            # No echo to the sender, nothing on another channel.
            assert drain(a) == []
            assert drain(c) == []
            # And back the other way.
            b.send(can.Message(arbitration_id=0x5B0, data=b"\x43\x00\x10\x00", is_extended_id=False))
            m = a.recv(timeout=2)
            assert m is not None and m.arbitration_id == 0x5B0 and bytes(m.data) == b"\x43\x00\x10\x00"
        finally:
            for x in (a, b, c):
                x.shutdown()


def test_handshake_stays_clean_while_traffic_flows():
    """python-can compares each handshake reply verbatim: a client joining a busy bus must
    not get frames before its rawmode `< ok >`."""
    with hub() as (_, port):
        a = bus(port)
        stop = threading.Event()

        def spam():
            while not stop.is_set():
                a.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
                time.sleep(0.0002)

        t = threading.Thread(target=spam)
        t.start()
        try:
            for _ in range(20):
                late = bus(port)  # raises CanError if a frame arrived with a handshake reply
                m = late.recv(timeout=2)
                assert m is not None and m.arbitration_id == 0x080 and m.dlc == 0
                late.shutdown()
        finally:
            stop.set()
            t.join()
            a.shutdown()


def rawmode_client(port: int) -> socket.socket:
    """A socketcand client on `port` past its handshake, in raw mode (socketcand protocol:
    `< hi >`, `< open can0 >`, `< rawmode >`)."""
    raw = socket.create_connection(("127.0.0.1", port))
    assert raw.recv(64) == b"< hi >"
    raw.sendall(b"< open can0 >")
    assert raw.recv(64) == b"< ok >"
    raw.sendall(b"< rawmode >")
    assert raw.recv(64) == b"< ok >"
    return raw


def test_malformed_input_is_reported_and_does_not_break_the_bus():
    with hub() as (proc, port):
        b = bus(port)
        raw = rawmode_client(port)
        try:
            raw.sendall(b"< send 800 0 >< send 123 9 >< send 123 2 01 >garbage< bogus >< send 123 1 AB >")
            m = b.recv(timeout=2)
            assert m is not None and m.arbitration_id == 0x123 and bytes(m.data) == b"\xab"
            assert drain(b) == []
        finally:
            raw.close()
            b.shutdown()
        proc.terminate()
        err = proc.stderr.read()
        for what in ("exceeds 0x7FF", "DLC `9`", "DLC 2 but 1 data bytes", "`garbage`", "unsupported command `< bogus >`"):
            assert what in err, err
        assert "panicked" not in err


# --- `ehactl run --hal canopen`: argument and start-up errors (the end-to-end runs with the
# --- simulated devices live with the devices' tests).
BOOM = REPO / "configs" / "dindorf2022_boom.toml"


def run_cli(*args):
    return subprocess.run([BIN, *args], capture_output=True, text=True, timeout=60)


def one_line(stderr):
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert "panicked" not in stderr
    return lines[0]


@pytest.mark.parametrize(
    "args,words",
    [
        (["--hal", "canopen", "--bus", "can0"], ["--bus", "no scheme", "socketcand://HOST:PORT/CHANNEL"]),
        (["--hal", "canopen", "--bus", "socketcand://127.0.0.1/can0"], ["missing :PORT"]),
        (["--hal", "canopen"], ["needs --bus"]),
        (["--bus", "socketcand://127.0.0.1:1/can0"], ["needs --hal canopen"]),
    ],
)
def test_bad_bus_arguments_exit_2(tmp_path, args, words):
    out = tmp_path / "x.mcap"
    r = run_cli("run", str(BOOM), "--json", "--out", str(out), *args)
    assert r.returncode == 2, r
    line = one_line(r.stderr)
    for w in words:
        assert w in line, line
    assert r.stdout == "" and not out.exists()


def startup_failure(r, out):
    """Exit 4 with the reason on the first stderr line, the log's path on the second, the
    same summary on stdout (--json) as in the log; the MCAP reads back with the official
    reader: /config, one hal_fault trip on /events, /summary with trip_kind `startup`,
    no cycle records. Returns (reason line, summary, /can frames)."""
    assert r.returncode == 4, r
    assert "panicked" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 2 and lines[1] == f"ehactl: start-up attempt logged to {out}", r.stderr
    run = read_run(out)
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert run["summary"] == summary
    assert summary["trip_kind"] == "startup" and summary["exit_code"] == 4
    assert summary["trip"] in lines[0] and summary["cycles"] == 0
    assert run["config"]["backend"] == "canopen"
    assert run["config"]["config"]["canopen"]["valve_node_id"] == 48
    assert len(run["control"]["t"]) == 0
    trips = [e for e in run["events"] if e["severity"] == "trip"]
    assert len(trips) == 1 and trips[0]["kind"] == "hal_fault", run["events"]
    assert trips[0]["channel"] == "canopen start-up"
    assert trips[0]["value"] == pytest.approx(summary["startup_s"])
    frames = read_can(out, require_channel=summary["can_startup_frames"] > 0)
    assert len(frames) == summary["can_startup_frames"]
    return lines[0], summary, frames


def test_no_devices_on_the_bus_is_a_startup_failure_exit_4(tmp_path):
    cfg = tmp_path / "boom.toml"
    cfg.write_text(BOOM.read_text() + "\n[canopen]\nboot_timeout_s = 0.3\n")
    out = tmp_path / "x.mcap"
    with hub() as (_, port):
        r = run_cli("run", str(cfg), "--json", "--out", str(out), "--hal", "canopen",
                    "--bus", f"socketcand://127.0.0.1:{port}/can0")
    line, summary, frames = startup_failure(r, out)
    assert "transducer (node 32 = 0x20) sent no boot-up" in line and "0.3 s" in line, line
    assert summary["startup_s"] >= 0.3
    # the attempt on /can: NMT reset communication to both nodes, then SDO probes of the
    # silent nodes (upload 0x1000, every 250 ms while waiting and once at the deadline), each
    # ended by its abort on timeout (0x05040000); the last one, of the transducer, ends the
    # start-up. All sent by us, nothing back.
    seq = [(f["dir"], f["id"], f["data"]) for f in frames if f["id"] != 0x701]
    assert seq[:2] == [("tx", 0x000, "8220"), ("tx", 0x000, "8230")], seq
    probes = seq[2:]
    assert len(probes) >= 2 and len(probes) % 2 == 0, seq
    for (d1, id1, req), (d2, id2, abort) in zip(probes[::2], probes[1::2]):
        assert (d1, d2) == ("tx", "tx") and id1 == id2 and id1 in (0x620, 0x630), seq
        assert (req, abort) == ("4000100000000000", "8000100000000405"), seq
    assert probes[-2][1] == 0x620, seq
    # ehactl's own heartbeat (node 1, OPERATIONAL) every 20 ms from the start of the attempt
    beats = [f for f in frames if f["id"] == 0x701]
    assert {(f["dir"], f["data"]) for f in beats} == {("tx", "05")}
    assert 0.3 / 0.020 * 0.5 <= len(beats) <= summary["startup_s"] / 0.020 + 2, len(beats)
    assert all(-summary["startup_s"] - 1e-6 <= f["t"] <= 0 for f in frames), frames
    assert frames[0]["t"] <= -0.3


def test_nothing_listening_is_a_startup_failure_exit_4(tmp_path):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    out = tmp_path / "x.mcap"
    r = run_cli("run", str(BOOM), "--json", "--out", str(out), "--hal", "canopen",
                "--bus", f"socketcand://127.0.0.1:{port}/can0")
    line, summary, frames = startup_failure(r, out)
    assert "cannot connect" in line
    assert frames == []


def test_bus_overload_is_refused_by_check_config(tmp_path):
    cfg = tmp_path / "boom.toml"
    cfg.write_text(BOOM.read_text() + "\n[canopen]\nsync_rate_hz = 3000.0\n")
    r = run_cli("check-config", str(cfg))
    assert r.returncode == 2, r
    line = one_line(r.stderr)
    # Worst-case frame length 8N + 47 + floor((34 + 8N - 1)/4) bits: SYNC, position (4),
    # setpoint (2), valve status (4) per SYNC, plus two 1-byte heartbeats every 20 ms.
    def bits(n: int) -> int:
        return 8 * n + 47 + (34 + 8 * n - 1) // 4

    per_sync = sum(bits(n) for n in (0, 4, 2, 4))
    assert per_sync == 320
    # + heartbeats of the two devices and of ehactl itself (master_heartbeat_ms), 20 ms each
    load = (per_sync * 3000.0 + 3 * bits(1) / 0.020) / 1e6
    assert "canopen.sync_rate_hz" in line and f"bus load {load * 100:.1f} % exceeds 80 %" in line, line


# --- Log flood and exposure ---------------------------------------------------------------


def test_garbage_flood_is_summarised_per_client_not_logged_line_by_line():
    """A client sending megabytes of junk gets a few lines and a count, not a line per message."""
    bogus = 400_000  # `< bogus >` messages: 3.6 MB, each one malformed (unsupported in rawmode)
    with hub() as (proc, port):
        # stderr read all along, so that a flood shows as lines rather than a blocked hub
        chunks: list[str] = []
        reader = threading.Thread(target=lambda: chunks.extend(iter(proc.stderr.readline, "")), daemon=True)
        reader.start()
        b = bus(port)
        raw = rawmode_client(port)
        try:
            raw.sendall(b"< bogus >" * bogus + b"< send 123 1 AB >")
            # the bus still works for the others, and all the junk has been read
            m = b.recv(timeout=30)
            assert m is not None and m.arbitration_id == 0x123 and bytes(m.data) == b"\xab"
            # a second client sends 2 MB of random bytes before its handshake
            noise = socket.create_connection(("127.0.0.1", port))
            assert noise.recv(64) == b"< hi >"
            noise.sendall(random.Random(1).randbytes(2_000_000) + b"< echo >")
            noise.close()
        finally:
            raw.close()
            b.shutdown()
        time.sleep(0.5)  # the hub notices the disconnect
        proc.terminate()
        reader.join(timeout=10)
        err = "".join(chunks)
    lines = err.splitlines()
    assert len(lines) < 50, (len(lines), len(err), lines[:60])
    assert len(err) < 10_000, len(err)
    assert "panicked" not in err
    # the first ones are quoted, then a count: at the disconnect, the total for that client
    assert "unsupported command `< bogus >`" in err
    summary = [ln for ln in lines if "malformed" in ln and "disconnected" in ln]
    assert len(summary) == 2, lines
    flood = [ln for ln in summary if f"; {bogus} malformed messages in all" in ln]
    assert len(flood) == 1, summary
    other = next(ln for ln in summary if ln is not flood[0])
    assert re.search(r"; [1-9]\d* malformed messages in all", other), summary


def test_hub_on_a_non_loopback_address_warns():
    proc = subprocess.Popen([BIN, "canbus", "hub", "--listen", "0.0.0.0:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert line.startswith("listening on 0.0.0.0:"), line
        time.sleep(0.3)
    finally:
        proc.terminate()
        proc.wait(timeout=5)
    err = proc.stderr.read()
    warn = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(warn) == 1, err
    assert "not a loopback address" in warn[0] and "CAN bus" in warn[0] and "network" in warn[0], warn
    with hub() as (proc, _port):
        time.sleep(0.3)
        proc.terminate()
        assert "warning" not in proc.stderr.read()


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_a_signal_during_startup_stops_it_at_once_exit_130(tmp_path, sig):
    """A hub and no devices, `canopen.boot_timeout_s = 20`: SIGTERM / SIGINT 0.7 s into the
    start-up (waiting for boot-ups, probing by SDO) ends ehactl with exit 130 within a few
    seconds — not at the boot timeout with exit 4 (`systemctl stop` must not wait it out).
    The attempt is still logged: the frames on /can and the summary (interrupted, no trip)."""
    import signal

    cfg = tmp_path / "boom.toml"
    cfg.write_text(BOOM.read_text() + "\n[canopen]\nboot_timeout_s = 20.0\n")
    out = tmp_path / "x.mcap"
    with hub() as (_, port):
        t_spawn = time.monotonic()
        p = subprocess.Popen([BIN, "run", str(cfg), "--json", "--out", str(out), "--hal",
                              "canopen", "--bus", f"socketcand://127.0.0.1:{port}/can0"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(0.7)
        assert p.poll() is None, p.communicate()
        t0 = time.monotonic()
        p.send_signal(getattr(signal, sig))
        try:
            stdout, stderr = p.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            stdout, stderr = p.communicate()
            raise AssertionError(f"{sig} during start-up ignored for 10 s: {stderr}")
        t_end = time.monotonic()
        latency = t_end - t0
    assert p.returncode == 130, (p.returncode, stderr)
    assert latency < 3.0, latency
    assert "panicked" not in stderr
    assert "start-up stopped by signal" in stderr, stderr
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["interrupted"] is True and summary["trip"] is None, summary
    assert summary["exit_code"] == 130 and summary["cycles"] == 0
    # the start-up ran from (after) the spawn to (before) the exit, and past the signal
    assert t0 - t_spawn - 0.3 <= summary["startup_s"] < t_end - t_spawn, (summary, t0 - t_spawn)
    run = read_run(out)
    assert run["summary"] == summary
    frames = read_can(out)
    # NMT reset communication of both nodes went out before the signal
    assert [f["data"] for f in frames if f["id"] == 0][:2] == ["8220", "8230"], frames[:5]
