"""Simulated CANopen devices (`python -m ehactl.devices`) against a python `canopen` master
(RemoteNode) over `ehactl canbus hub` + python-can's socketcand interface: EDS content, boot-up,
SDO, NMT gating, heartbeat, PDO re-mapping, the CiA 408 state machine and SYNC-driven plant time
checked against the same plant stepped directly through the bindings."""
import configparser
import math
import statistics
import struct
import subprocess
import sys
import time

import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from canhub import hub
from simrig import (BOOM, REPO, TRANSDUCER_EDS, TRANSDUCER_ID, VALVE_EDS, VALVE_ID,
                    FrameLog, devices, master, require_bindings)

ehactl = require_bindings()


SYNC_PERIOD = 1e-3  # s, [canopen] sync_rate_hz default 1000 Hz (boom config has no override)


# ----------------------------------------------------------------------------- EDS files
# (index, sub, data type, access, default) from the ICD; data types CiA 301 table 44.
U8, U16, U32, I8, I16, I32 = 0x5, 0x6, 0x7, 0x2, 0x3, 0x4
COMMON = [(0x1000, 0, U32, "ro"), (0x1001, 0, U8, "ro"), (0x1017, 0, U16, "rw"),
          (0x1018, 1, U32, "ro"), (0x1018, 2, U32, "ro"), (0x1018, 3, U32, "ro"),
          (0x1018, 4, U32, "ro"), (0x1800, 1, U32, "rw"), (0x1800, 2, U8, "rw"),
          (0x1A00, 0, U8, "rw"), (0x1A00, 1, U32, "rw"), (0x1016, 1, U32, "rw")]
ICD_OBJECTS = {
    "transducer": COMMON + [(0x6005, 1, U32, "rw"), (0x6005, 2, U32, "rw"), (0x6004, 0, I32, "ro"),
                            (0x6020, 1, I32, "ro"), (0x6030, 1, I16, "ro"), (0x6200, 0, U16, "rw")],
    "valve": COMMON + [(0x1400, 1, U32, "rw"), (0x1400, 2, U8, "rw"), (0x1600, 0, U8, "rw"),
                       (0x1600, 1, U32, "rw"), (0x6040, 0, U16, "rw"), (0x6041, 0, U16, "ro"),
                       (0x6042, 0, I8, "rw"), (0x6043, 0, I8, "rw"), (0x6300, 1, I16, "rw"),
                       (0x6301, 1, I16, "ro"), (0x6314, 1, I16, "rw")],
}


def _obj(od, index, sub):
    o = od[index]
    return o if isinstance(o, canopen.objectdictionary.ODVariable) else o[sub]


@pytest.mark.parametrize("which,path,node_id", [("transducer", TRANSDUCER_EDS, TRANSDUCER_ID),
                                                ("valve", VALVE_EDS, VALVE_ID)])
def test_eds_has_icd_objects_and_defaults(which, path, node_id):
    od = canopen.import_od(path, node_id)
    for index, sub, dt, access in ICD_OBJECTS[which]:
        v = _obj(od, index, sub)
        assert (v.data_type, v.access_type) == (dt, access), (which, hex(index), sub)
    profile = 406 if which == "transducer" else 408
    assert _obj(od, 0x1000, 0).default & 0xFFFF == profile
    assert _obj(od, 0x1018, 2).default == profile
    assert _obj(od, 0x1800, 1).default == 0x180 + node_id
    assert _obj(od, 0x1800, 2).default == 1
    if which == "transducer":
        assert _obj(od, 0x6005, 1).default == 1000  # nm = 1 µm
        # speed step at 0x6005:02 as in the vendor manuals (Temposonics E-Series table 17)
        assert _obj(od, 0x6005, 2).default == 1000 and 0x6006 not in od  # µm/s = 1 mm/s
        assert _obj(od, 0x6004, 0).pdo_mappable
        assert _obj(od, 0x6200, 0).default == 0
        assert [_obj(od, 0x1A00, k).default for k in range(2)] == [1, 0x60200120]
        assert _obj(od, 0x6020, 1).pdo_mappable and _obj(od, 0x6030, 1).pdo_mappable
    else:
        assert _obj(od, 0x1400, 1).default == 0x200 + node_id
        assert [_obj(od, 0x1600, k).default for k in range(2)] == [1, 0x63000110]
        assert [_obj(od, 0x1A00, k).default for k in range(3)] == [2, 0x60410010, 0x63010110]
        assert _obj(od, 0x6042, 0).default == 1
        assert (_obj(od, 0x6300, 1).min, _obj(od, 0x6300, 1).max) == (-16384, 16384)


@pytest.mark.parametrize("path", [TRANSDUCER_EDS, VALVE_EDS])
def test_eds_is_consistent_cia306(path):
    """CiA 306 structure: object lists match the object sections, SubNumber matches the
    sub-sections, sub0 of every array/record equals its highest sub-index, data types known."""
    eds = configparser.RawConfigParser()
    eds.optionxform = str
    eds.read(path)
    for sec in ("FileInfo", "DeviceInfo", "MandatoryObjects", "OptionalObjects",
                "ManufacturerObjects"):
        assert eds.has_section(sec), sec
    listed = []
    for sec in ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"):
        n = int(eds.get(sec, "SupportedObjects"), 0)
        keys = [k for k in eds.options(sec) if k != "SupportedObjects"]
        assert sorted(int(k) for k in keys) == list(range(1, n + 1)), sec
        listed += [int(eds.get(sec, k), 0) for k in keys]
    sections = {int(s, 16) for s in eds.sections() if len(s) == 4 and all(
        c in "0123456789ABCDEF" for c in s)}
    assert sorted(listed) == sorted(sections)
    assert {0x1000, 0x1001, 0x1018} <= {int(eds.get("MandatoryObjects", k), 0)
                                        for k in eds.options("MandatoryObjects")
                                        if k != "SupportedObjects"}
    for idx in sections:
        s = f"{idx:04X}"
        otype = int(eds.get(s, "ObjectType"), 0)
        if otype == 0x7:
            assert int(eds.get(s, "DataType"), 0) in (1, 2, 3, 4, 5, 6, 7, 9)
            continue
        assert otype in (0x8, 0x9)
        subs = [x for x in eds.sections() if x.upper().startswith(s + "SUB")]
        assert int(eds.get(s, "SubNumber"), 0) == len(subs), s
        highest = max(int(x[7:], 16) for x in subs)
        assert int(eds.get(f"{s}sub0", "DefaultValue"), 0) in (highest, 0) or s in (
            "1600", "1A00"), s


# ----------------------------------------------------------------------------- helpers
def boot(port, tmp_path, *faults, **kw):
    """Hub client master first, then the devices: the master sees both boot-ups."""
    return devices(port, tmp_path, *faults, **kw)


def sync(net, n=1, log=None, cob=None, timeout=2.0):
    """Send n SYNCs, each after the previous one's TPDO `cob` has arrived (if given)."""
    for _ in range(n):
        before = len(log.of(cob)) if log is not None else 0
        net.send_message(0x080, b"")
        if log is not None:
            got = log.wait_count(cob, before + 1, timeout)
            assert len(got) >= before + 1, f"no TPDO 0x{cob:03X} after SYNC"


def no_frames(log, cob, dt=0.15):
    n = len(log.of(cob))
    time.sleep(dt)
    return len(log.of(cob)) == n


@pytest.fixture
def rig(tmp_path):
    with hub() as (_, port), master(port) as (net, td, va):
        log = FrameLog()
        net.notifier.add_listener(log)
        with boot(port, tmp_path) as dev:
            log.wait_count(0x700 + VALVE_ID, 1)
            yield net, td, va, log, dev


# ----------------------------------------------------------------------------- tests
def test_boot_up_and_sdo_reads(rig):
    net, td, va, log, dev = rig
    assert [d for _, d, _ in log.of(0x700 + TRANSDUCER_ID)][:1] == [b"\x00"]
    assert [d for _, d, _ in log.of(0x700 + VALVE_ID)][:1] == [b"\x00"]
    assert td.sdo[0x1000].raw & 0xFFFF == 406
    assert va.sdo[0x1000].raw & 0xFFFF == 408
    assert va.sdo[0x1018][2].raw == 408
    # 0x1008 is longer than 4 bytes: a segmented upload
    assert td.sdo[0x1008].raw == "ehactl sim CiA 406 linear transducer"
    assert td.sdo[0x6005][1].raw == 1000
    assert td.sdo[0x1A00][1].raw == 0x60200120
    assert va.sdo[0x6042].raw == 1
    assert va.sdo[0x6041].raw == 0x0008  # INIT after boot-up (RMHD 1000, Moog B99224-DV018)
    assert va.sdo[0x1A00][0].raw == 2
    # errors are SDO aborts with the CiA 301 codes
    with pytest.raises(SdoAbortedError) as e:
        va.sdo[0x6041].raw = 7
    assert e.value.code == 0x06010002  # attempt to write a read-only object
    with pytest.raises(SdoAbortedError) as e:
        va.sdo.upload(0x6500, 0)
    assert e.value.code == 0x06020000
    with pytest.raises(SdoAbortedError) as e:
        va.sdo[0x6300][1].raw = 20000
    assert e.value.code == 0x06090031  # above HighLimit 16384
    with pytest.raises(SdoAbortedError) as e:
        va.sdo[0x6042].raw = 0
    assert e.value.code in (0x06090032, 0x06090030)


def test_nmt_gating_heartbeat_and_reset(rig):
    net, td, va, log, dev = rig
    # 0x1017 = 20 ms: heartbeats with the NMT state, period measured on the master side
    va.sdo[0x1017].raw = 20
    log.clear()
    time.sleep(0.5)
    hb = log.of(0x700 + VALVE_ID)
    assert {d for _, d, _ in hb} == {b"\x7f"}  # PRE-OPERATIONAL
    period = statistics.median(b[2] - a[2] for a, b in zip(hb, hb[1:]))
    assert 0.015 < period < 0.030, period
    # PRE-OPERATIONAL: SYNC produces no PDO
    log.clear()
    net.send_message(0x080, b"")
    assert no_frames(log, 0x180 + TRANSDUCER_ID) and not log.of(0x180 + VALVE_ID)
    # OPERATIONAL: SYNC → TPDOs, heartbeat 0x05
    net.nmt.send_command(0x01)
    time.sleep(0.05)
    sync(net, 3, log, 0x180 + VALVE_ID)
    assert len(log.wait_count(0x180 + TRANSDUCER_ID, 3)) >= 3
    time.sleep(0.06)  # > 2 heartbeat periods
    assert log.of(0x700 + VALVE_ID)[-1][1] == b"\x05"
    # STOPPED: no PDO, no SDO answer, heartbeat 0x04
    va.nmt.send_command(0x02)
    time.sleep(0.05)
    log.clear()
    net.send_message(0x080, b"")
    assert no_frames(log, 0x180 + VALVE_ID)
    assert log.of(0x180 + TRANSDUCER_ID)  # the transducer is still OPERATIONAL
    with pytest.raises(SdoCommunicationError):
        va.sdo[0x6041].raw
    assert log.wait_count(0x700 + VALVE_ID, 2)[-1][1] == b"\x04"
    # reset communication: new boot-up, 0x1017 back to its EDS default 0 (no heartbeat)
    log.clear()
    va.nmt.send_command(0x82)
    deadline = time.monotonic() + 2
    while b"\x00" not in [d for _, d, _ in log.of(0x700 + VALVE_ID)]:
        assert time.monotonic() < deadline, "no boot-up after reset communication"
        time.sleep(0.005)
    assert va.sdo[0x1017].raw == 0
    time.sleep(0.1)
    hb = [d for _, d, _ in log.of(0x700 + VALVE_ID)]
    k = hb.index(b"\x00")
    # before: STOPPED heartbeats still in flight; after the boot-up: none (0x1017 = 0)
    assert set(hb[:k]) <= {b"\x04"} and hb[k + 1:] == [], hb


def test_pdo_remapping_by_sdo(rig):
    net, td, va, log, dev = rig
    # Standard CiA 301 procedure through python-canopen's PDO API: disable, count 0, entries,
    # count, enable. Transducer TPDO1 = position (4 bytes) + speed (2 bytes).
    td.tpdo.read()
    td.tpdo[1].clear()
    td.tpdo[1].add_variable(0x6020, 1)
    td.tpdo[1].add_variable(0x6030, 1)
    td.tpdo[1].trans_type = 1
    td.tpdo[1].enabled = True
    td.tpdo[1].save()
    assert [td.sdo[0x1A00][k].raw for k in range(3)] == [2, 0x60200120, 0x60300110]
    # rules of the procedure are enforced with the CiA 301 abort codes
    with pytest.raises(SdoAbortedError) as e:
        td.sdo[0x1A00][0].raw = 1  # PDO still valid
    assert e.value.code == 0x08000022
    td.sdo[0x1800][1].raw = 0x80000000 | (0x180 + TRANSDUCER_ID)
    with pytest.raises(SdoAbortedError) as e:
        td.sdo[0x1A00][1].raw = 0x60200120  # entries only while sub0 == 0
    assert e.value.code == 0x06040043
    td.sdo[0x1A00][0].raw = 0
    with pytest.raises(SdoAbortedError) as e:
        td.sdo[0x1A00][1].raw = 0x10080020  # device name is not mappable
    assert e.value.code == 0x06040041
    with pytest.raises(SdoAbortedError) as e:
        td.sdo[0x1A00][1].raw = 0x60200110  # wrong length for an INTEGER32
    assert e.value.code == 0x06040041
    td.sdo[0x1A00][1].raw = 0x60200120
    td.sdo[0x1A00][2].raw = 0x60300110
    td.sdo[0x1A00][0].raw = 2
    td.sdo[0x1800][1].raw = 0x180 + TRANSDUCER_ID
    # 0x6005:01 = 10 µm steps; run a few SYNCs with the valve open and check the frames
    td.sdo[0x6005][1].raw = 10000
    va.sdo[0x6040].raw = 0x0007
    va.sdo[0x6300][1].raw = 8192
    net.nmt.send_command(0x01)
    time.sleep(0.05)
    sync(net, 40, log, 0x180 + TRANSDUCER_ID)
    frames = log.of(0x180 + TRANSDUCER_ID)[-40:]
    assert {len(d) for _, d, _ in frames} == {6}
    pos = [struct.unpack("<ih", d)[0] for _, d, _ in frames]
    spd = [struct.unpack("<ih", d)[1] for _, d, _ in frames]
    # speed (mm/s units) is the difference quotient of the position (10 µm units) per SYNC
    for k in range(1, len(pos)):
        expect = (pos[k] - pos[k - 1]) * 10e-6 / SYNC_PERIOD / 1e-3
        # positions quantised to 10 µm per 1 ms SYNC = 10 mm/s, plus 1 count of rounding
        assert abs(spd[k] - expect) <= 11, (k, spd[k], expect)
    assert pos[-1] != pos[0]


def test_valve_state_machine_setpoint_only_in_active(rig):
    net, td, va, log, dev = rig
    net.nmt.send_command(0x01)
    time.sleep(0.05)
    cob_rpdo, cob_tpdo = 0x200 + VALVE_ID, 0x180 + VALVE_ID

    def step(n, setpoint):
        for _ in range(n):
            net.send_message(cob_rpdo, struct.pack("<h", setpoint))
            sync(net, 1, log, cob_tpdo)
        status, actual = struct.unpack("<Hh", log.of(cob_tpdo)[-1][1])
        return status, actual

    # INIT (RMHD 1000): setpoint ignored, spool at its failsafe position (closed centre)
    assert step(20, 8192) == (0x0008, 0)
    # HOLD (1011; INIT → DISABLED → HOLD by one control word): the hold setpoint 0x6314 acts
    va.sdo[0x6040].raw = 0x0003
    assert step(20, 8192) == (0x000B, 0)
    # ACTIVE (1111): 8192 = 50 % → spool follows the first-order valve (T_z = 10 ms, Dindorf 2022)
    va.sdo[0x6040].raw = 0x0007
    n = 30
    status, actual = step(n, 8192)
    assert status == 0x000F
    expect = 0.5 * (1 - math.exp(-n * SYNC_PERIOD / 0.01)) * 16384
    assert abs(actual - expect) < 0.01 * 16384, (actual, expect)
    # back to HOLD: the spool goes to the hold setpoint (here -25 %), not to the bus setpoint
    va.sdo[0x6314][1].raw = -4096
    va.sdo[0x6040].raw = 0x0003
    status, actual = step(80, 8192)
    assert status == 0x000B and abs(actual + 4096) < 0.01 * 16384, actual
    va.sdo[0x6314][1].raw = 0
    status, actual = step(80, 8192)
    assert abs(actual) < 0.01 * 16384
    # MHD = 000 from HOLD: TR6 then TR7 → INIT
    va.sdo[0x6040].raw = 0x0000
    assert va.sdo[0x6041].raw == 0x0008
    # events of the device log name every transition
    states = [e["state"] for e in dev.events("state")]
    assert states[-5:] == ["HOLD", "ACTIVE", "HOLD", "DISABLED", "INIT"]


def test_fault_reset_acts_on_rising_edge_only(tmp_path):
    """Published reset (Moog B99224-DV018 §5.2.2.1, TR11): a rising edge of R with D/H held
    (0011 → 1011) leaves FAULT_HOLD for HOLD; R as a level, R with M set or R without D/H do
    not."""
    with hub() as (_, port), master(port) as (net, td, va):
        log = FrameLog()
        net.notifier.add_listener(log)
        with boot(port, tmp_path, "--fault", "emcy@0.010") as dev:
            log.wait_count(0x700 + VALVE_ID, 1)
            va.sdo[0x6040].raw = 0x000F  # D,H,M with R already high
            assert va.sdo[0x6041].raw == 0x000F  # ACTIVE
            net.nmt.send_command(0x01)
            time.sleep(0.05)
            emcys = []
            va.emcy.add_callback(emcys.append)
            sync(net, 15, log, 0x180 + VALVE_ID)
            sws = [struct.unpack("<H", d[:2])[0] for _, d, _ in log.of(0x180 + VALVE_ID)]
            # ACTIVE, then FAULT_REACTION (0111) for one SYNC, then FAULT_HOLD (0011)
            k = sws.index(0x0007)
            assert sws[:k] and set(sws[:k]) == {0x000F} and set(sws[k + 1:]) == {0x0003}, sws
            assert va.sdo[0x6041].raw == 0x0003  # FAULT_HOLD
            assert emcys and emcys[0].code == 0x5000 and emcys[0].register & 0x01
            assert va.sdo[0x1001].raw & 0x01
            assert va.sdo[0x1003][0].raw == 1 and va.sdo[0x1003][1].raw == 0x5000
            va.sdo[0x6040].raw = 0x000F  # level, no edge
            assert va.sdo[0x6041].raw == 0x0003
            va.sdo[0x6040].raw = 0x0007  # R falls; M cannot raise a fault state
            assert va.sdo[0x6041].raw == 0x0003
            va.sdo[0x6040].raw = 0x000F  # rising edge, but M = 1: not the TR11 pattern
            assert va.sdo[0x6041].raw == 0x0003
            va.sdo[0x6040].raw = 0x0003  # R falls, D/H held
            va.sdo[0x6040].raw = 0x000B  # rising edge with D/H held → HOLD (TR11)
            assert va.sdo[0x6041].raw == 0x000B
            time.sleep(0.05)
            assert emcys[-1].code == 0x0000  # error reset EMCY
            assert va.sdo[0x1001].raw == 0
            va.sdo[0x6040].raw = 0x0007
            assert va.sdo[0x6041].raw == 0x000F
            ev = dev.wait_event("fault-injected", fault="emcy")
            assert abs(ev["t_sim"] - 0.010) < 1.5 * SYNC_PERIOD


# Transitions of the CiA 408 device state machine as published by Moog (B99224-DV018-D-211,
# §5.2 fig. 19 and the tables of §5.2.2), typed in from the manual: (state before as its RMHD
# status code, control words written in order, RMHD status code after). Codes: NOT_READY /
# FAULT_INIT 0000, INIT 1000, DISABLED 1001, HOLD 1011, ACTIVE 1111, FAULT_REACTION 0111,
# FAULT_HOLD 0011, FAULT_DISABLED 0001.
PUBLISHED_TRANSITIONS = [
    # TR2 INIT → DISABLED: xxx1
    ("INIT", [0b0001], 0b1001),
    # TR3 DISABLED → HOLD: x011
    ("DISABLED", [0b0011], 0b1011),
    # TR4 HOLD → ACTIVE: x111
    ("HOLD", [0b0111], 0b1111),
    # TR5 ACTIVE → HOLD: M = 0
    ("ACTIVE", [0b0011], 0b1011),
    # TR5 + TR6 ACTIVE → DISABLED: M = 0, H = 0 ("every transition ... will be processed")
    ("ACTIVE", [0b0001], 0b1001),
    # TR6 HOLD → DISABLED: M = 0, H = 0
    ("HOLD", [0b0001], 0b1001),
    # TR7 DISABLED → INIT: 000
    ("DISABLED", [0b0000], 0b1000),
    # INIT → ACTIVE by one control word 111 (TR2, TR3, TR4)
    ("INIT", [0b0111], 0b1111),
    # TR10 FAULT_DISABLED → DISABLED: 0001 → 1001 (rising edge of R, D held)
    ("FAULT_DISABLED", [0b0001, 0b1001], 0b1001),
    # TR11 FAULT_HOLD → HOLD: 0011 → 1011
    ("FAULT_HOLD", [0b0011, 0b1011], 0b1011),
    # TR14 FAULT_INIT → INIT: 0000 → 1000
    ("FAULT_INIT", [0b0000, 0b1000], 0b1000),
    # R as a level is no reset: its edge came with M = 1 (no TR11 pattern), D/H alone later
    ("FAULT_HOLD", [0b1111, 0b1011], 0b0011),
    # the control word never raises a fault state
    ("FAULT_HOLD", [0b0111], 0b0011),
    ("FAULT_DISABLED", [0b0011], 0b0001),
    # a reset edge with other D/H bits than the fault state's is no TR10/TR11
    ("FAULT_HOLD", [0b0111, 0b1111], 0b0011),
    # TR15 FAULT_HOLD → FAULT_DISABLED, TR16 FAULT_DISABLED → FAULT_INIT (control word lowers)
    ("FAULT_HOLD", [0b0001], 0b0001),
    ("FAULT_DISABLED", [0b0000], 0b0000),
]


def _dsm_in(state_name):
    """A ValveDsm brought into `state_name` through published transitions only."""
    from ehactl.devices.valve import ValveDsm

    m = ValveDsm()
    m.power_on()  # TR0, TR1 → INIT
    path = {"INIT": [], "DISABLED": [0b0001], "HOLD": [0b0011], "ACTIVE": [0b0111]}
    if state_name in path:
        for cw in path[state_name]:
            m.control_word(cw)
        return m
    # fault states: a fault in HOLD → FAULT_REACTION → FAULT_HOLD (TR8, TR9), then lowered by
    # the control word (TR15, TR16); or a fault in DISABLED / INIT (redirected, TR12 / TR13)
    before = {"FAULT_HOLD": 0b0011, "FAULT_DISABLED": 0b0001, "FAULT_INIT": 0b0000}[state_name]
    m.control_word(before)
    assert m.fault("test")
    assert m.state.bits == 0b0111  # FAULT_REACTION
    m.end_reaction()
    return m


@pytest.mark.parametrize("before,cws,after", PUBLISHED_TRANSITIONS)
def test_valve_dsm_follows_the_published_transition_table(before, cws, after):
    m = _dsm_in(before)
    assert m.state.name == before
    for cw in cws:
        m.control_word(cw)
    assert m.state.bits == after, (before, [bin(c) for c in cws], m.state)


def test_valve_fault_reaction_never_raises_the_state():
    """TR8 from each state and the fault state reached (TR9 / TR12 / TR13: FAULT_HOLD as this
    valve's fault reaction, redirected to FAULT_DISABLED / FAULT_INIT from DISABLED / INIT)."""
    for before, after in [("ACTIVE", 0b0011), ("HOLD", 0b0011), ("DISABLED", 0b0001),
                          ("INIT", 0b0000)]:
        m = _dsm_in(before)
        assert m.fault("x") and m.state.bits == 0b0111
        m.end_reaction()
        assert m.state.bits == after, (before, m.state)


def test_sync_position_matches_plant_stepped_directly(rig):
    """Setpoints over CAN move the shared plant one SYNC period per SYNC: the transducer TPDO
    equals the bindings' plant stepped with the same held commands (same code, no tolerance
    beyond the 1 µm position step)."""
    net, td, va, log, dev = rig
    va.sdo[0x6040].raw = 0x0007
    net.nmt.send_command(0x01)
    time.sleep(0.05)
    cfg = ehactl.Config.load(BOOM)
    plant = ehactl.Plant(cfg)
    steps = round(SYNC_PERIOD / cfg.control_dt)
    fs = cfg["valve.command_full_scale"]
    setpoints = [0] * 10 + [6000] * 150 + [-3000] * 100
    got, want = [], []
    for s in setpoints:
        net.send_message(0x200 + VALVE_ID, struct.pack("<h", s))
        sync(net, 1, log, 0x180 + TRANSDUCER_ID)
        got.append(struct.unpack("<i", log.of(0x180 + TRANSDUCER_ID)[-1][1])[0])
        plant.step(s / 16384 * fs, steps)
        want.append(round(plant.measure()["position"] / 1e-6))
    assert got == want
    # and the valve really moved the piston: out while the setpoint is positive, back after
    assert got[159] - got[10] > 1000  # > 1 mm
    assert got[-1] < got[159]


def test_plant_time_advances_one_sync_period_per_sync(tmp_path):
    """1500 Hz SYNC with 5 kHz control: 0.667 ms is no whole number of 0.2 ms periods, so the
    rig steps the plant 4 × 0.1667 ms per SYNC; plant time = SYNC count / SYNC rate."""
    cfg = tmp_path / "sync1500.toml"
    cfg.write_text(open(BOOM).read() + "\n[canopen]\nsync_rate_hz = 1500.0\n")
    with hub() as (_, port), master(port) as (net, td, va):
        log = FrameLog()
        net.notifier.add_listener(log)
        with devices(port, tmp_path, config=str(cfg)) as dev:
            assert "SYNC 1500 Hz = 4 plant steps of 0.166667 ms" in dev.ready_line
            log.wait_count(0x700 + VALVE_ID, 1)
            net.nmt.send_command(0x01)
            time.sleep(0.05)
            sync(net, 30, log, 0x180 + TRANSDUCER_ID)
            dev.stop()
            s = dev.summary()
    assert s["sync_count"] == 30
    assert abs(s["t_plant"] - 30 / 1500) < 1e-9, s["t_plant"]


def test_cyclic_timer_sends_without_sync(rig):
    net, td, va, log, dev = rig
    td.sdo[0x1800][2].raw = 255
    td.sdo[0x6200].raw = 10  # ms
    net.nmt.send_command(0x01)
    log.clear()
    time.sleep(0.5)
    fr = log.of(0x180 + TRANSDUCER_ID)
    assert 35 <= len(fr) <= 55, len(fr)
    assert 0.008 < statistics.median(b[2] - a[2] for a, b in zip(fr, fr[1:])) < 0.013
    assert not log.of(0x180 + VALVE_ID)  # the valve TPDO is synchronous: no SYNC, no frame


def test_short_rpdo_ignored_with_emcy(rig):
    net, td, va, log, dev = rig
    va.sdo[0x6040].raw = 0x0007
    net.nmt.send_command(0x01)
    time.sleep(0.05)
    emcys = []
    va.emcy.add_callback(emcys.append)
    net.send_message(0x200 + VALVE_ID, b"\x00")  # 1 byte, 2 mapped
    sync(net, 5, log, 0x180 + VALVE_ID)
    assert va.sdo[0x6300][1].raw == 0
    assert emcys and emcys[0].code == 0x8210


def test_rpdo_deadline_takes_an_active_valve_to_fault_hold(rig):
    """RPDO1 event timer 0x1400:05 as deadline (CiA 301 v4.2 7.5.2.35): with setpoints every
    SYNC the valve stays ACTIVE; when they stop (the master's cycle hung) it misses the
    deadline, sends EMCY 0x8250 (RPDO timeout) and goes FAULT_REACTION → FAULT_HOLD. Timing in
    bus time: not before the deadline after the last RPDO received (hub relay stamps)."""
    net, td, va, log, dev = rig
    deadline_s = 0.150
    va.sdo[0x1400][5].raw = round(deadline_s * 1e3)
    va.sdo[0x6040].raw = 0x0007
    net.nmt.send_command(0x01)
    time.sleep(0.05)
    emcys = []
    va.emcy.add_callback(emcys.append)
    cob_rpdo = 0x200 + VALVE_ID
    for _ in range(50):  # 50 setpoints over ~0.25 s, each within the deadline
        net.send_message(cob_rpdo, struct.pack("<h", 0))
        t_last = time.time()  # the hub stamps it at or after this (one host clock)
        sync(net, 1, log, 0x180 + VALVE_ID)
        time.sleep(0.004)
    assert va.sdo[0x6041].raw == 0x000F and not emcys
    ev = dev.wait_event("rpdo-timeout", timeout=5)
    assert abs(ev["deadline_s"] - deadline_s) < 1e-9 and ev["silent_s"] > deadline_s, ev
    # not before the deadline after the last setpoint was sent (1 ms for float rounding)
    assert ev["t_wall"] - t_last >= deadline_s - 0.001, (ev, t_last)
    dev.wait_event("state", timeout=2, state="FAULT_HOLD")
    states = [e["state"] for e in dev.events("state")]
    assert states[-2:] == ["FAULT_REACTION", "FAULT_HOLD"], states
    for _ in range(100):
        if emcys:
            break
        time.sleep(0.01)
    assert emcys and emcys[0].code == 0x8250, emcys


def test_malformed_requests_are_ignored(rig):
    """NMT with a wrong DLC, an SDO request shorter than 8 bytes and a SYNC with 2 data
    bytes are not CiA 301 frames: no state change, no answer, no plant step."""
    net, td, va, log, dev = rig
    net.send_message(0x000, b"\x01")  # NMT start without node id byte
    net.send_message(0x600 + VALVE_ID, b"\x40\x41\x60\x00")  # upload request, DLC 4
    time.sleep(0.1)
    assert not log.of(0x580 + VALVE_ID)
    assert va.sdo[0x6041].raw == 0x0008  # still answers proper requests
    net.send_message(0x080, b"")
    assert no_frames(log, 0x180 + TRANSDUCER_ID)  # still PRE-OPERATIONAL: no PDO
    net.nmt.send_command(0x01)
    time.sleep(0.05)
    log.clear()
    net.send_message(0x080, b"\x01\x02")
    assert no_frames(log, 0x180 + TRANSDUCER_ID)
    net.send_message(0x080, b"\x07")  # SYNC with a counter byte is valid
    assert log.wait_count(0x180 + TRANSDUCER_ID, 1)
    dev.stop()
    s = dev.summary()
    assert s["sync_count"] == 2 and s["transducer_nmt"] == 5  # the PRE-OP one and the last


def test_hub_drop_stops_devices_with_message(tmp_path):
    with hub() as (hproc, port):
        with devices(port, tmp_path) as dev:
            time.sleep(0.2)
            hproc.kill()
            hproc.wait()
            rc = dev.proc.wait(timeout=10)
            assert rc == 1
            assert dev.events("bus-lost")
            assert any("bus socketcand://127.0.0.1" in line and "connection" in line
                       for line in dev.stderr_lines), dev.stderr_lines


@pytest.mark.parametrize("args,needle", [
    (["--fault", "explode@1"], "unknown kind 'explode'"),
    (["--fault", "emcy@-1"], "is not a number ≥ 0"),
    (["--bus", "can0"], "unknown scheme"),
    (["--bus", "socketcand://127.0.0.1/can0"], "expected socketcand://HOST:PORT/CHANNEL"),
    (["--bus", "socketcand://127.0.0.1:9/can0"], "cannot connect to socketcand at 127.0.0.1:9"),
])
def test_bad_arguments_one_line_error(args, needle):
    base = {"--bus": "socketcand://127.0.0.1:9/can0", "--config": BOOM}
    argv = []
    for k, v in base.items():
        if k not in args:
            argv += [k, v]
    p = subprocess.run([sys.executable, "-m", "ehactl.devices", *argv, *args],
                       capture_output=True, text=True, timeout=60, cwd=str(REPO))
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0], p.stderr


def test_bad_canopen_config_field(tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(open(BOOM).read() + "\n[canopen]\nvalve_node_id = 200\n")
    p = subprocess.run([sys.executable, "-m", "ehactl.devices", "--bus",
                        "socketcand://127.0.0.1:9/can0", "--config", str(cfg)],
                       capture_output=True, text=True, timeout=60, cwd=str(REPO))
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [
        f"error: config {cfg}: canopen.valve_node_id = 200: expected an integer in [1, 127] "
        "(node id)"], p.stderr
