"""Devices built on the `canopen` package's own `LocalNode` (its SDO server, NMT
slave, heartbeat producer, PDO maps and EMCY producer, loaded from the shipped EDS files, with
a small CiA 408 state machine on top: tests/python/localnode_devices.py, written apart from
ehactl.devices) run a closed loop with `ehactl run --hal canopen` over the hub.

Timing assertions count SYNCs on the CAN log (robust by design on a loaded machine: the
master's control cycle produces SYNC, so a stalled process stalls the count too), not wall ms."""
import contextlib
import json
import pathlib
import subprocess
import sys
import tempfile
import time

import numpy as np
import pytest

from canhub import BIN, hub
from ehactl_mcap import read_can, read_run
from simrig import BOOM, REPO, bus_url, require_bindings, syncs_between, trip_safe_setpoint

require_bindings()  # the devices' plant is ehactl.Plant

HERE = pathlib.Path(__file__).resolve().parent
TR, VA = 32, 48
# The master's timing for these tests, as in test_canopen_e2e.py (a loaded 2-core machine where
# the Python devices stall for ~100-300 ms): heartbeats 50 ms, PDO age limit 1000 SYNC periods.
# ehactl's consumer of the devices' heartbeats is 1 s here, not 250 ms: LocalNode produces its
# heartbeat from a python-can periodic thread that competes for the GIL with the SYNC handler,
# two receive threads and the other node's heartbeat, and on a loaded CI machine the valve's
# heartbeat went silent for more than 250 ms while its TPDOs kept coming (a correct trip at
# t = 0.63 s that these interoperability tests are not about; heartbeat-loss detection times
# are checked in test_canopen_e2e.py and crates/canopen/tests/hal_rig.rs). The devices'
# consumer of ehactl (written to their 0x1016) stays 250 ms. SYNC with counter 1..10 (0x1019
# in the EDS files; LocalNode stores it). Everything else (EDS files, node ids, SYNC 1 kHz) is
# the default.
CAN_BOOM = pathlib.Path(tempfile.mkdtemp(prefix="ehactl_ln_")) / "dindorf2022_boom_can.toml"
CAN_BOOM.write_text(pathlib.Path(BOOM).read_text() + "\n[canopen]\nheartbeat_ms = 50\n"
                    "heartbeat_timeout_ms = 1000\ndevice_heartbeat_timeout_ms = 250\n"
                    "max_pdo_age_syncs = 1000\nsync_counter_overflow = 10\n")


class LocalNodeDevices:
    def __init__(self, proc, events):
        self.proc, self.events_path, self.out = proc, events, None

    def events(self, kind=None, event=None):
        p = pathlib.Path(self.events_path)
        evs = [json.loads(ln) for ln in p.read_text().splitlines() if ln.strip()] if p.exists() else []
        return [e for e in evs if (kind is None or e["kind"] == kind)
                and (event is None or e["event"] == event)]

    def stop(self):
        """SIGTERM; returns the JSON summary the device program prints."""
        if self.out is None:
            self.proc.terminate()
            out, err = self.proc.communicate(timeout=20)
            lines = [ln for ln in out.splitlines() if ln.startswith("{")]
            assert lines, (out, err)
            self.out = json.loads(lines[-1])
        return self.out


@contextlib.contextmanager
def localnode_devices(port, tmp_path, *extra):
    events = str(tmp_path / f"localnode_{time.monotonic_ns()}.jsonl")
    proc = subprocess.Popen([sys.executable, str(HERE / "localnode_devices.py"), "--port",
                             str(port), "--config", BOOM, "--events", events, *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=str(REPO))
    line = proc.stdout.readline()
    d = LocalNodeDevices(proc, events)
    try:
        if not line.startswith("localnode devices ready"):
            proc.kill()
            raise AssertionError(f"LocalNode devices did not start: {line} {proc.stderr.read()}")
        # the devices are powered before the master starts: their power-on boot-ups are on the
        # bus before its NMT reset communication (so any later boot-up would be the reset's)
        time.sleep(0.5)
        yield d
    finally:
        if d.out is None and proc.poll() is None:
            proc.kill()
            proc.wait()


def run_master(port, out, duration):
    p = subprocess.run([BIN, "run", str(CAN_BOOM), "--hal", "canopen", "--bus", bus_url(port), "--json",
                        "--duration", str(duration), "--out", str(out)],
                       capture_output=True, text=True, timeout=90, cwd=str(REPO))
    lines = [ln for ln in p.stdout.splitlines() if ln.strip()]
    summary = json.loads(lines[-1]) if lines else None
    assert "panicked" not in p.stderr, p.stderr
    return p.returncode, summary, p.stderr


def why(summary, err):
    trip = summary.get("trip") if isinstance(summary, dict) else None
    return f"trip: {trip}; stderr: {err.strip()[-1500:]}"


def sim_final_position(duration, tmp_path):
    out = tmp_path / "sim.mcap"
    p = subprocess.run([BIN, "run", BOOM, "--duration", str(duration), "--out", str(out),
                        "--json"], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    c = read_run(out)["control"]
    return float(np.mean(c["position"][c["t"] > duration - 0.25]))


def test_localnode_devices_close_a_3s_loop(tmp_path):
    duration = 3.0
    with hub() as (_, port), localnode_devices(port, tmp_path) as dev:
        out = tmp_path / "ln.mcap"
        rc, summary, err = run_master(port, out, duration)
        time.sleep(0.1)
        dsum = dev.stop()
    assert rc == 0, why(summary, err)
    assert summary["trip"] is None
    assert summary["can_wrong_dlc"] == 0 and summary["can_unknown_cob_id"] == 0, summary
    # names read from the LocalNodes (0x1008 VISIBLE_STRING: segmented SDO upload)
    assert summary["device_names"] == {"transducer": "ehactl sim CiA 406 linear transducer",
                                       "valve": "ehactl sim CiA 408 valve OBE"}
    # the valve went DISABLED → HOLD → ACTIVE by the published transitions and the safe stop
    # left it in HOLD with the spool at the hold setpoint 0
    tr = [e["why"] for e in dev.events("valve", "state")]
    assert tr[:3] == ["TR2", "TR3", "TR4"] and tr[-1] == "TR5", tr
    assert dsum["valve_state"] == "HOLD" and dsum["spool"] == 0.0, dsum
    assert dsum["nmt"] == {"transducer": "OPERATIONAL", "valve": "OPERATIONAL"}
    frames = read_can(out)
    rx = [f for f in frames if f["dir"] == "rx"]
    tx = [f for f in frames if f["dir"] == "tx"]
    # LocalNode sends no boot-up after NMT reset communication: the master probed each node
    # by SDO (upload of 0x1000) and it answered
    for node in (TR, VA):
        reset = [f["t"] for f in tx if f["id"] == 0 and f["data"] == f"82{node:02x}"]
        assert reset, f"no NMT reset communication of node {node}"
        assert not [f for f in rx if f["id"] == 0x700 + node and f["data"] == "00"
                    and f["t"] > reset[0]], "LocalNode unexpectedly sent a boot-up"
        assert any(f["id"] == 0x600 + node and f["data"].startswith("40001000") for f in tx)
        assert any(f["id"] == 0x580 + node and f["data"].startswith("43001000") for f in rx)
    # SYNC counter (CiA 301 7.2.5): 0x1019 = 10 written to both nodes (SDO expedited download,
    # 1 byte) while 0x1006 is 0 (read first: 0 on a fresh node, so not written), then 0x1006 =
    # 1000 µs; SYNC k carries 1 + (k - 1) mod 10 (the priming SYNC is SYNC 1)
    for node in (TR, VA):
        writes = [f["data"].upper() for f in tx if f["id"] == 0x600 + node
                  and f["data"][:2].upper() in ("2F", "23")]
        assert "2F1910000A000000" in writes, writes
        k19 = writes.index("2F1910000A000000")
        assert "23061000E8030000" in writes[k19:], writes
    counters = [int(f["data"], 16) for f in tx if f["id"] == 0x80]
    assert counters == [1 + k % 10 for k in range(len(counters))], counters[:30]
    # every SYNC the master sent reached the devices; every TPDO LocalNode sent is in the
    # log but those answering the last SYNC (safe stop) after the master stopped listening
    syncs = sum(1 for f in tx if f["id"] == 0x80)
    assert dsum["syncs"] == syncs, (dsum["syncs"], syncs)
    for cob in ("0x1A0", "0x1B0"):
        logged = sum(1 for f in rx if f"0x{f['id']:03X}" == cob)
        assert 0 <= dsum["tpdo_sent"][cob] - logged <= 1, (cob, dsum["tpdo_sent"], logged)
    # closed loop: the piston settles at y_set = 0.6 m as in the in-process simulation
    c = read_run(out)["control"]
    settled = float(np.mean(c["position"][c["t"] > duration - 0.25]))
    assert abs(settled - 0.6) < 0.010, settled
    assert abs(settled - sim_final_position(duration, tmp_path)) < 0.002, settled


def test_localnode_valve_fault_trips_within_two_sync_periods(tmp_path):
    """An injected valve fault (FAULT_REACTION with EMCY 0x5000 at SYNC 1000) trips ehactl
    within 2 SYNC periods, counted on the CAN log from the valve's EMCY frame to the safe
    setpoint RPDO the trip sends; the valve ends in FAULT_HOLD at the hold setpoint 0."""
    with hub() as (_, port), localnode_devices(port, tmp_path, "--fault", "emcy@1.0") as dev:
        out = tmp_path / "f.mcap"
        rc, summary, err = run_master(port, out, 3.0)
        time.sleep(0.1)
        dsum = dev.stop()
    assert rc == 3, why(summary, err)
    assert "EMCY" in json.dumps(summary["trip"]), (summary["trip"], dsum, dev.events()[-5:])
    assert dsum["emcy_sent"] == 1
    frames = read_can(out)
    emcy = [f["t"] for f in frames if f["dir"] == "rx" and f["id"] == 0x80 + VA]
    assert emcy, "no EMCY on the bus"
    # the trip's safe setpoint (the master's last RPDO; a control setpoint crossing 0 after
    # the EMCY would give an early time)
    safe = trip_safe_setpoint(frames, 0x200 + VA)
    assert safe >= emcy[0], (safe, emcy[0])
    n = syncs_between(frames, emcy[0], safe)
    assert n <= 2, f"{n} SYNC periods from the EMCY to the trip; {why(summary, err)}"
    # the trip event is logged (its time is loop time, a different clock from the bus stamps)
    assert any("EMCY" in json.dumps(e) for e in read_run(out)["events"])
    states = [e["state"] for e in dev.events("valve", "state")]
    assert states[-2:] == ["FAULT_REACTION", "FAULT_HOLD"], states
    assert dsum["valve_state"] == "FAULT_HOLD" and dsum["spool"] == 0.0, dsum


@pytest.mark.parametrize("master_eds", ["built-in", "device's own"])
def test_a_localnode_transducer_without_0x1016_starts_and_is_reported(tmp_path, master_eds):
    """A CiA 406 transducer built on LocalNode from an EDS WITHOUT the heartbeat consumer
    0x1016 (optional in CiA 301, often omitted on sensors): ehactl asks the device (SDO read of
    0x1016:00 → abort 0x06020000, object does not exist), starts without it, lists it in
    `startup_skipped` and runs the 3 s loop to completion; the valve's consumer is still
    configured. With the built-in EDS (which lists 0x1016: it describes another device) and
    with the device's own EDS as canopen.transducer_eds."""
    from localnode_devices import EDS, eds_without

    eds = tmp_path / "transducer_no_1016.eds"
    eds.write_text(eds_without(EDS / "ehactl_transducer_406.eds", 0x1016))
    assert "[1016" not in eds.read_text()
    cfg = CAN_BOOM
    if master_eds == "device's own":
        cfg = tmp_path / "boom_own_eds.toml"
        cfg.write_text(CAN_BOOM.read_text() + f'transducer_eds = "{eds}"\n')
    with hub() as (_, port), localnode_devices(port, tmp_path, "--transducer-eds",
                                               str(eds)) as dev:
        out = tmp_path / "no1016.mcap"
        p = subprocess.run([BIN, "run", str(cfg), "--hal", "canopen", "--bus", bus_url(port),
                            "--json", "--duration", "3", "--out", str(out)],
                           capture_output=True, text=True, timeout=90, cwd=str(REPO))
        time.sleep(0.1)
        dsum = dev.stop()
    lines = [ln for ln in p.stdout.splitlines() if ln.strip()]
    summary = json.loads(lines[-1]) if lines else None
    assert p.returncode == 0, why(summary, p.stderr)
    assert summary["trip"] is None and summary["cycles"] > 0
    skipped = summary["startup_skipped"]
    assert any(s.startswith(f"node {TR} 0x1016:01") and "0x06020000" in s for s in skipped), skipped
    assert not any(s.startswith(f"node {VA} ") and "0x1016" in s for s in skipped), skipped
    frames = read_can(out)
    tx = [(f["id"], f["data"].upper()) for f in frames if f["dir"] == "tx"]
    rx = [(f["id"], f["data"].upper()) for f in frames if f["dir"] == "rx"]
    # the transducer was asked for 0x1016:00 and answered "object does not exist" (LocalNode's
    # own SDO server); it was never written 0x1016
    assert (0x600 + TR, "4016100000000000") in tx
    assert (0x580 + TR, "8016100000000206") in rx
    assert not [d for i, d in tx if i == 0x600 + TR and d[2:6] == "1610" and d[:2] != "40"]
    # the valve's consumer of ehactl's heartbeat: node 1, 250 ms (0x1016:01 = 0x000100FA)
    assert (0x600 + VA, "23161001FA000100") in tx, [d for i, d in tx if i == 0x600 + VA]
    assert dsum["valve_state"] == "HOLD" and dsum["spool"] == 0.0, dsum


# A third device, a CiA 404 pressure transmitter (crates/canopen/src/cia404.rs) at node 64,
# named in the master's config by one [[canopen.devices]] entry (built-in EDS
# configs/eds/ehactl_pressure_404.eds); the device is a LocalNode of that file serving the
# plant's chamber A pressure (tests/python/localnode_devices.py --pressure-id).
PR = 64
CAN_BOOM_404 = CAN_BOOM.with_name("dindorf2022_boom_can_404.toml")
CAN_BOOM_404.write_text(CAN_BOOM.read_text()
                        + f'\n[[canopen.devices]]\nprofile = "cia404"\nnode_id = {PR}\n')
HB_TIMEOUT_S = 1.0  # canopen.heartbeat_timeout_ms of CAN_BOOM (see above)
SYNC_PERIOD_S = 1e-3


def run_master_404(port, out, duration):
    p = subprocess.run([BIN, "run", str(CAN_BOOM_404), "--hal", "canopen", "--bus",
                        bus_url(port), "--json", "--duration", str(duration), "--out", str(out)],
                       capture_output=True, text=True, timeout=90, cwd=str(REPO))
    lines = [ln for ln in p.stdout.splitlines() if ln.strip()]
    summary = json.loads(lines[-1]) if lines else None
    assert "panicked" not in p.stderr, p.stderr
    return p.returncode, summary, p.stderr


def pressures_on_the_bus(frames):
    """(t, Pa) of the transmitter's TPDO1s on the /can log: 0x9130:01 as little-endian
    INTEGER32 with 0 decimal digits (what the master set in 0x6132:01)."""
    return [(f["t"], int.from_bytes(bytes.fromhex(f["data"]), "little", signed=True))
            for f in frames if f["dir"] == "rx" and f["id"] == 0x180 + PR]


def test_a_cia404_transmitter_is_brought_up_and_feeds_p_a(tmp_path):
    """The master brings the third device up from its profile (NMT, SDO configuration of its
    decimal digits and TPDO1 mapping, OPERATIONAL heartbeats) beside the transducer and the
    valve, and the process values it sends become `Measurements::p_a` in the MCAP control
    records: every logged p_a is a value the device sent, the last one the last it sent
    before the loop ended, and the settled values are the plant's chamber A pressure of
    the in-process simulation (independent of the bus: the units and the scaling hold)."""
    duration = 2.0
    with hub() as (_, port), localnode_devices(port, tmp_path, "--pressure-id", str(PR)) as dev:
        out = tmp_path / "p404.mcap"
        rc, summary, err = run_master_404(port, out, duration)
        time.sleep(0.1)
        dsum = dev.stop()
    assert rc == 0, why(summary, err)
    assert summary["trip"] is None
    assert summary["can_wrong_dlc"] == 0 and summary["can_unknown_cob_id"] == 0, summary
    assert summary["device_names"]["pressure transmitter"] == \
        "ehactl sim CiA 404 pressure transmitter", summary["device_names"]
    frames = read_can(out)
    tx = [(f["id"], f["data"].upper()) for f in frames if f["dir"] == "tx"]
    # NMT start of node 64, its decimal digits set to 0 (LocalNode's file default is 3) by an
    # expedited 1-byte download, its TPDO1 mapped to 0x9130:01 (32 bit) and enabled
    assert (0x000, f"01{PR:02X}") in tx
    assert (0x600 + PR, "2F32610100000000") in tx, [d for i, d in tx if i == 0x600 + PR]
    assert (0x600 + PR, "23001A0120013091") in tx
    assert (0x600 + PR, "23001801" + (0x180 + PR).to_bytes(4, "little").hex().upper()) in tx
    bus = pressures_on_the_bus(frames)
    assert len(bus) > 0.8 * duration * 1000, len(bus)  # one per SYNC
    sent = dsum["pressures_sent"]
    assert [p for _, p in bus] == sent[:len(bus)] and len(sent) - len(bus) <= 1
    c = read_run(out)["control"]
    p_a = c["p_a"]
    assert np.all(np.isfinite(p_a)), "a cycle without the transmitter's pressure"
    assert set(np.unique(p_a)) <= {float(p) for p in sent}, "a p_a the device never sent"
    assert len(np.unique(p_a)) > 100, np.unique(p_a)[:10]  # it follows the plant
    # the held sample at the end is a recent one: among the last 20 SYNC periods' TPDOs (the
    # last few may arrive in one burst after the loop's last read on a loaded machine)
    assert p_a[-1] in [float(p) for _, p in bus[-20:]], (p_a[-1], bus[-20:])
    sim = tmp_path / "sim.mcap"
    p = subprocess.run([BIN, "run", BOOM, "--duration", str(duration), "--out", str(sim),
                        "--json"], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    plant = read_run(sim)["plant"]
    sim_pa = float(np.mean(plant["p_a"][plant["t"] > duration - 0.25]))
    can_pa = float(np.mean(p_a[c["t"] > duration - 0.25]))
    assert abs(can_pa - sim_pa) < 0.02 * abs(sim_pa), (can_pa, sim_pa)


def test_the_transmitters_heartbeat_loss_trips_to_the_safe_state(tmp_path):
    """The pressure transmitter falls silent at SYNC 1000: ehactl's consumer of its heartbeat
    trips the run as for the transducer and the valve (exit 3, the trip named, the valve's
    safe setpoint and HOLD), no earlier than the consumer time after its last heartbeat on
    the /can log and no later than that plus 2 SYNC periods and 25 ms of scheduling slack
    (as test_canopen_e2e.py's heartbeat-loss test)."""
    with hub() as (_, port), localnode_devices(port, tmp_path, "--pressure-id", str(PR),
                                               "--fault", "pressure-heartbeat-loss@1.0") as dev:
        out = tmp_path / "p404_hb.mcap"
        rc, summary, err = run_master_404(port, out, 4.0)
        time.sleep(0.1)
        dsum = dev.stop()
    assert rc == 3, why(summary, err)
    assert "pressure transmitter heartbeat lost" in json.dumps(summary["trip"]), summary["trip"]
    assert dev.events("pressure", "fault-injected"), dev.events()[-5:]
    frames = read_can(out)
    t_safe = trip_safe_setpoint(frames, 0x200 + VA)
    hb = [f["t"] for f in frames if f["dir"] == "rx" and f["id"] == 0x700 + PR
          and f["t"] < t_safe]
    assert hb, "no heartbeat of the transmitter before the trip"
    gaps = [(h, nxt) for h, nxt in zip(hb, hb[1:] + [t_safe]) if nxt - h >= HB_TIMEOUT_S]
    assert gaps, f"early trip: no silence of the consumer time before it; {hb[-5:]}, {t_safe}"
    after_last = t_safe - gaps[0][0]
    assert after_last <= HB_TIMEOUT_S + 2 * SYNC_PERIOD_S + 0.025, (after_last, why(summary, ""))
    # its TPDOs stopped with its heartbeat; the valve was safe-stopped: HOLD, spool 0
    assert all(t <= gaps[0][0] + 0.1 for t, _ in pressures_on_the_bus(frames))
    assert (0x600 + VA, "2B40600003000000") in [(f["id"], f["data"].upper()) for f in frames
                                                if f["dir"] == "tx" and f["t"] >= t_safe]
    assert dsum["valve_state"] == "HOLD" and dsum["spool"] == 0.0, dsum
