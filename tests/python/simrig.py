"""Start the simulated CANopen devices (`python -m ehactl.devices`) and a python `canopen`
master on a hub for tests (shared by test_devices.py and test_canopen_e2e.py)."""
import contextlib
import json
import os
import pathlib
import subprocess
import sys
import threading
import time

import can
import canopen
import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
EDS_DIR = REPO / "configs" / "eds"
TRANSDUCER_EDS = str(EDS_DIR / "ehactl_transducer_406.eds")
VALVE_EDS = str(EDS_DIR / "ehactl_valve_408.eds")
BOOM = str(REPO / "configs" / "dindorf2022_boom.toml")
TRANSDUCER_ID, VALVE_ID = 32, 48


def require_bindings():
    """The ehactl Python bindings (they carry ehactl.devices): required when
    EHACTL_REQUIRE_BINDINGS is set (scripts/test_all.sh installs them), else skip."""
    if os.environ.get("EHACTL_REQUIRE_BINDINGS"):
        import ehactl

        return ehactl
    return pytest.importorskip("ehactl", reason="ehactl Python bindings not installed "
                                                "(pip install './bindings/python[devices]')")


def bus_url(port):
    return f"socketcand://127.0.0.1:{port}/can0"


class Devices:
    """A running `python -m ehactl.devices` process; events read back from its JSON lines."""

    def __init__(self, proc, events_path, ready_line):
        self.proc = proc
        self.events_path = events_path
        self.ready_line = ready_line
        self.stderr_lines = []
        self._t = threading.Thread(target=self._drain, daemon=True)
        self._t.start()

    def _drain(self):
        for line in self.proc.stderr:
            self.stderr_lines.append(line)

    def events(self, event=None):
        if not os.path.exists(self.events_path):
            return []
        with open(self.events_path) as f:
            evs = [json.loads(line) for line in f if line.strip()]
        return [e for e in evs if event is None or e["event"] == event]

    def wait_event(self, event, timeout=5.0, **match):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for e in self.events(event):
                if all(e.get(k) == v for k, v in match.items()):
                    return e
            time.sleep(0.01)
        raise AssertionError(f"no device event {event} {match} within {timeout} s; "
                             f"stderr: {''.join(self.stderr_lines)[-2000:]}")

    def stop(self, timeout=10):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._t.join(timeout=2)
        return self.proc.returncode

    def summary(self):
        s = self.events("summary")
        return s[-1] if s else None


@contextlib.contextmanager
def devices(port, tmp_path, *extra, config=BOOM, boot_delay=0.0):
    """Run the simulated rig on the hub at `port`; yields a Devices once it printed `ready`."""
    events = str(tmp_path / f"devices_events_{time.monotonic_ns()}.jsonl")
    cmd = [sys.executable, "-m", "ehactl.devices", "--bus", bus_url(port), "--config", config,
           "--eds-dir", str(EDS_DIR), "--events", events, "--boot-delay", str(boot_delay),
           *extra]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=str(REPO))
    line = proc.stdout.readline()
    d = Devices(proc, events, line)
    try:
        if not line.startswith("ehactl.devices ready"):
            rc = proc.wait(10)
            d._t.join(5)
            raise AssertionError(f"devices did not start (exit {rc}): {''.join(d.stderr_lines)}")
        yield d
    finally:
        d.stop()


@contextlib.contextmanager
def master(port):
    """A python-canopen master (RemoteNodes for both devices) on the hub."""
    bus = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0",
                  tcp_tune=True)
    net = canopen.Network(bus)
    net.NOTIFIER_CYCLE = 0.1  # s: prompt shutdown
    net.connect()
    td = canopen.RemoteNode(TRANSDUCER_ID, TRANSDUCER_EDS)
    va = canopen.RemoteNode(VALVE_ID, VALVE_EDS)
    net.add_node(td)
    net.add_node(va)
    for n in (td, va):
        n.sdo.RESPONSE_TIMEOUT = 1.0
    try:
        yield net, td, va
    finally:
        net.disconnect()


class FrameLog(can.Listener):
    """Collects every frame the master's connection receives (arbitration id, data, time)."""

    def __init__(self):
        self.frames = []
        self.lock = threading.Lock()

    def on_message_received(self, msg):
        with self.lock:
            self.frames.append((msg.arbitration_id, bytes(msg.data), time.monotonic()))

    def of(self, cob_id):
        with self.lock:
            return [f for f in self.frames if f[0] == cob_id]

    def clear(self):
        with self.lock:
            self.frames.clear()

    def wait_count(self, cob_id, n, timeout=2.0):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if len(self.of(cob_id)) >= n:
                return self.of(cob_id)
            time.sleep(0.002)
        return self.of(cob_id)


def syncs_between(frames, t0, t1):
    """SYNCs (0x080) the master sent with t0 < t <= t1 on the /can log (one clock): the
    number of SYNC periods between two bus events, independent of how fast the machine is."""
    return sum(1 for f in frames if f["dir"] == "tx" and f["id"] == 0x080 and t0 < f["t"] <= t1)


def trip_safe_setpoint(frames, rpdo_cob):
    """Bus time (/can log) of the safe setpoint RPDO the master's trip sent: its last RPDO
    on `rpdo_cob` (the safe stop queues it behind every control setpoint, then stops the I/O
    threads), which must carry setpoint 0. Not "the first RPDO 0 after the fault": the
    control command crosses zero during a run (the boom step's at ≈ 0.57 s), and such a
    setpoint taken for the trip's made a heartbeat-loss trip look 90 ms early."""
    rp = [f for f in frames if f["dir"] == "tx" and f["id"] == rpdo_cob]
    assert rp, f"no RPDO 0x{rpdo_cob:03X} on the bus"
    assert rp[-1]["data"] == "0000", f"last RPDO 0x{rpdo_cob:03X} is {rp[-1]}, not setpoint 0"
    return rp[-1]["t"]
