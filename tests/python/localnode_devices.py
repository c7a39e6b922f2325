"""A CiA 406 transducer and a CiA 408 valve built on the `canopen` package's ``LocalNode`` as
it is: its own SDO server, its own NMT slave and heartbeat producer (python-can periodic
task), its own PDO maps (``node.tpdo`` / ``node.rpdo`` read from the object dictionary after
the master has mapped them) and its EMCY producer, loaded from the shipped EDS files
(configs/eds). Written independently of ``ehactl.devices`` (which replaces NMT,
heartbeat and PDO handling of LocalNode with its own): the only code on top is what a device
program must add to LocalNode, namely

- SYNC handling: apply the latched RPDO data, step the plant, send synchronous TPDOs;
- a small CiA 408 device state machine written from the table of Moog, "Moog ACV with CANopen
  bus interface", B99224-DV018-D-211 Rev. A (2018), §5.2 (status/control word bits 0..3 =
  D, H, M, R; RMHD codes INIT 1000, DISABLED 1001, HOLD 1011, ACTIVE 1111, FAULT_REACTION
  0111, FAULT_HOLD 0011, FAULT_DISABLED 0001, FAULT_INIT 0000; fault reset = rising edge of
  R with the D/H bits of the fault state held);
- live process values (position 0x6020:01 / 0x6004, status word 0x6041, actual spool
  0x6301:01) through LocalNode read callbacks.

Deliberately NOT added (LocalNode behaviour the master must live with): no boot-up after NMT
reset communication (the master answers with an SDO probe), no PDO gating other than the NMT
state check below, no heartbeat consumer (0x1016 is stored, not acted upon: this device does
not detect master loss; see DEPLOY.md for what a real valve does).

A third device, a CiA 404 pressure transmitter (``--pressure-id N``, the shipped
configs/eds/ehactl_pressure_404.eds), serves chamber A's pressure of the plant (Pa, as the
ground truth ``Plant.state()["p_a"]``) as its analogue input process value 0x9130:01
(INTEGER32 with the decimal digits of 0x6132:01, CiA DS 404 V1.2 §4.2.2) through a LocalNode
read callback; ``--fault pressure-heartbeat-loss@T`` silences it (heartbeat and TPDOs) at
SYNC T·1000, as a transmitter that loses power.

A transducer of another make can be built from its own EDS (``--transducer-eds PATH``), e.g.
one without the optional heartbeat consumer 0x1016 (``eds_without``), as many CiA 406 sensors
have: LocalNode then answers an SDO access to 0x1016 with abort 0x06020000 (object does not
exist).

Usage (from the repository root):
    python3 tests/python/localnode_devices.py --port PORT --config configs/dindorf2022_boom.toml
        [--events PATH] [--fault emcy@T] [--transducer-eds PATH] [--pressure-id N]
        [--fault pressure-heartbeat-loss@T]
Prints ``localnode devices ready`` on stdout once both nodes are on the bus; SIGTERM ends it
with a JSON summary on stdout."""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import signal
import struct
import sys
import threading
import time

import canopen

REPO = pathlib.Path(__file__).resolve().parents[2]
EDS = REPO / "configs" / "eds"

def eds_without(path, index):
    """The text of the EDS at `path` without object `index` (its sections and its line in the
    [MandatoryObjects] / [OptionalObjects] list, renumbered), as the file of a device that
    does not have the object."""
    out, skip, lists = [], False, {}
    section = None
    for line in pathlib.Path(path).read_text().splitlines():
        s = line.strip()
        if s.startswith("["):
            section = s[1:-1]
            skip = section.upper().split("SUB")[0] == f"{index:04X}"
            if section in ("MandatoryObjects", "OptionalObjects"):
                lists[section] = []
        if skip:
            continue
        if section in lists and "=" in s and not s.startswith("SupportedObjects"):
            if int(s.split("=", 1)[1], 16) != index:
                lists[section].append(s.split("=", 1)[1])
            continue
        out.append(line)
    text = "\n".join(out) + "\n"
    for sec, objs in lists.items():
        body = "".join(f"{k}={v}\n" for k, v in enumerate(objs, 1))
        head = f"[{sec}]\n"
        start = text.index(head)
        end = text.index("\n", text.index("SupportedObjects=", start)) + 1
        text = text[:start] + head + f"SupportedObjects={len(objs)}\n" + body + text[end:]
    return text


# ---------------------------------------------------------------- CiA 408 device state machine
D, H, M, R = 0x1, 0x2, 0x4, 0x8
CODE = {"INIT": 0b1000, "DISABLED": 0b1001, "HOLD": 0b1011, "ACTIVE": 0b1111,
        "FAULT_REACTION": 0b0111, "FAULT_HOLD": 0b0011, "FAULT_DISABLED": 0b0001,
        "FAULT_INIT": 0b0000}
# (transition, from, condition on the control word, to): Moog B99224-DV018 §5.2.2.
TABLE = [
    ("TR2", "INIT", lambda cw, rise: cw & D, "DISABLED"),
    ("TR3", "DISABLED", lambda cw, rise: cw & D and cw & H, "HOLD"),
    ("TR4", "HOLD", lambda cw, rise: cw & (D | H | M) == D | H | M, "ACTIVE"),
    ("TR5", "ACTIVE", lambda cw, rise: cw & (D | H | M) != D | H | M, "HOLD"),
    ("TR6", "HOLD", lambda cw, rise: not (cw & D and cw & H), "DISABLED"),
    ("TR7", "DISABLED", lambda cw, rise: not cw & D, "INIT"),
    ("TR10", "FAULT_DISABLED", lambda cw, rise: rise and cw & 0b111 == 0b001, "DISABLED"),
    ("TR11", "FAULT_HOLD", lambda cw, rise: rise and cw & 0b111 == 0b011, "HOLD"),
    ("TR14", "FAULT_INIT", lambda cw, rise: rise and cw & 0b111 == 0b000, "INIT"),
]
# Where a fault reaction ends (TR9/TR12/TR13): never above the state the fault came in.
REACTION_END = {"INIT": "FAULT_INIT", "DISABLED": "FAULT_DISABLED"}


class Dsm:
    def __init__(self, log):
        self.state = "INIT"   # TR1 done at power-on
        self.cw = 0
        self.came_from = "INIT"
        self.log = log

    def go(self, new, why):
        if new != self.state:
            self.log("state", old=self.state, state=new, why=why)
            self.state = new

    def control_word(self, cw):
        rise = bool(cw & R and not self.cw & R)
        self.cw = cw
        for _ in range(4):  # "every transition between actual and requested state"
            for tr, frm, cond, to in TABLE:
                if frm == self.state and cond(cw, rise):
                    self.go(to, tr)
                    rise = False
                    break
            else:
                return

    def fault(self, why):
        if self.state.startswith("FAULT"):
            return False
        self.came_from = self.state
        self.go("FAULT_REACTION", why)
        return True

    def sync(self):
        if self.state == "FAULT_REACTION":
            self.go(REACTION_END.get(self.came_from, "FAULT_HOLD"), "fault reaction done")


# ---------------------------------------------------------------- the device program
class Rig:
    def __init__(self, port, config, tr_id, va_id, faults, events, tr_eds=None, pr_id=None):
        import ehactl

        cfg = ehactl.Config.load(config)
        self.dt = float(cfg.control_dt)
        self.full_scale_v = float(cfg["valve.command_full_scale"])
        self.plant = ehactl.Plant(cfg, self.dt)
        self.events = open(events, "a") if events else None
        self.lock = threading.Lock()
        self.faults = faults
        self.net = canopen.Network()
        self.net.connect(interface="socketcand", host="127.0.0.1", port=port, channel="can0")
        self.tr = canopen.LocalNode(tr_id, str(tr_eds or EDS / "ehactl_transducer_406.eds"))
        self.va = canopen.LocalNode(va_id, str(EDS / "ehactl_valve_408.eds"))
        self.pr = None
        if pr_id is not None:
            self.pr = canopen.LocalNode(pr_id, str(EDS / "ehactl_pressure_404.eds"))
            self.pr.add_read_callback(self._pr_read)
        self.nodes = [n for n in (self.tr, self.va, self.pr) if n is not None]
        self.silent = set()  # node ids whose heartbeat and TPDOs were silenced (a fault)
        self.p_a = 0.0
        self.pressures = []  # process values sent in TPDOs (raw INTEGER32)
        for n in self.nodes:
            self.net.add_node(n)
        self.dsm = Dsm(lambda ev, **kw: self.log("valve", ev, **kw))
        self.position = 0.0
        self.spool = 0.0
        self.syncs = 0
        self.sync_period = None
        self._last_sync = None
        self.latched = {}
        self.sync_counter = {}
        self.sent = {}       # COB-ID -> TPDOs sent
        self.emcy_sent = 0
        self.tr.add_read_callback(self._tr_read)
        self.va.add_read_callback(self._va_read)
        self.va.add_write_callback(self._va_write)
        for n in self.nodes:
            n.rpdo.read(from_od=True)
            n.tpdo.read(from_od=True)
            for k, m in n.rpdo.map.items():
                m.add_callback(lambda m, n=n, k=k: self._on_rpdo(n, k, m))
        self.net.subscribe(0, self._on_nmt)        # after each LocalNode's own NMT slave
        self.net.subscribe(0x80, self._on_sync)

    def log(self, kind, event, **kw):
        if self.events:
            self.events.write(json.dumps({"t": time.time(), "kind": kind, "event": event,
                                          **kw}) + "\n")
            self.events.flush()

    # power-on: boot-up, then PRE-OPERATIONAL (LocalNode's NMT slave API)
    def power_on(self):
        for n in self.nodes:
            n.nmt.state = "INITIALISING"     # sends the boot-up 0x700+id [00]
            n.nmt.state = "PRE-OPERATIONAL"  # starts the heartbeat producer (0x1017)

    def _tr_read(self, index, subindex, od):
        if (index, subindex) in ((0x6020, 1), (0x6004, 0)):
            step_m = struct.unpack("<I", self.tr.get_data(0x6005, 1))[0] * 1e-9
            return max(-2**31, min(2**31 - 1, round(self.position / step_m)))
        return None

    def _pr_read(self, index, subindex, od):
        if (index, subindex) == (0x9130, 1):
            digits = struct.unpack("<B", self.pr.get_data(0x6132, 1))[0]
            return max(-2**31, min(2**31 - 1, round(self.p_a * 10**digits)))
        return None

    def _va_read(self, index, subindex, od):
        if index == 0x6041:
            return CODE[self.dsm.state]
        if index == 0x6301 and subindex == 1:
            return max(-32768, min(32767, round(self.spool * 16384)))
        return None

    def _va_write(self, index, subindex, od, data):
        if index == 0x6040:
            self.dsm.control_word(struct.unpack("<H", data)[0])

    def _on_nmt(self, can_id, data, ts):
        if len(data) == 2 and data[0] == 0x01:  # start: take the master's PDO mapping
            for n in self.nodes:
                if data[1] in (0, n.id):
                    with self.lock:
                        n.rpdo.read(from_od=False)
                        n.tpdo.read(from_od=False)
                        self.sync_counter.clear()
                    self.log("nmt", "start", node_id=n.id,
                             tpdo=[hex(m.cob_id) for m in n.tpdo.map.values() if m.enabled])

    def _on_rpdo(self, node, k, m):
        if node.nmt.state != "OPERATIONAL" or not m.enabled:
            return
        if m.trans_type is not None and m.trans_type <= 240:
            self.latched[(node.id, k)] = bytes(m.data)  # applied at the next SYNC
        else:
            self._apply(node, m, bytes(m.data))

    def _apply(self, node, m, data):
        off = 0
        for v in m.map:
            nb = v.length // 8
            node.set_data(v.index, v.subindex, data[off:off + nb])
            off += nb

    def _on_sync(self, can_id, data, ts):
        try:
            self._sync(ts)
        except Exception as e:  # logged, so that a failing test says why
            self.log("rig", "sync-error", why=repr(e), sync=self.syncs)
            raise

    def _sync(self, ts):
        with self.lock:
            self.syncs += 1
            if self._last_sync is not None:
                self.sync_period = ts - self._last_sync
            self._last_sync = ts
            for f in self.faults:
                if not f.get("done") and self.syncs * 1e-3 >= f["at"]:
                    f["done"] = True
                    if f["kind"] == "pressure-heartbeat-loss":
                        self.pr.nmt.stop_heartbeat()
                        self.silent.add(self.pr.id)
                        self.log("pressure", "fault-injected", fault=f["kind"], sync=self.syncs)
                    elif self.dsm.fault("injected EMCY fault"):
                        self.log("valve", "fault-injected", fault="emcy", sync=self.syncs)
                        self.va.emcy.send(0x5000, 0x01)
                        self.emcy_sent += 1
            latched, self.latched = self.latched, {}
            for (nid, k), d in latched.items():
                node = self.tr if nid == self.tr.id else self.va
                self._apply(node, node.rpdo.map[k], d)
            self.dsm.sync()
            st = self.dsm.state
            if st == "ACTIVE":
                sp = struct.unpack("<h", self.va.get_data(0x6300, 1))[0]
            elif st in ("HOLD", "FAULT_HOLD", "FAULT_REACTION"):
                sp = struct.unpack("<h", self.va.get_data(0x6314, 1))[0]
            else:
                sp = 0
            self.spool = sp / 16384.0
            n_steps = 5 if self.dt == 2e-4 else max(1, round(1e-3 / self.dt))
            self.plant.step(self.spool * self.full_scale_v, n_steps)
            meas = self.plant.measure()
            if math.isfinite(meas["position"]):
                self.position = meas["position"]
            self.p_a = float(self.plant.state()["p_a"])
            for node in self.nodes:
                if node.nmt.state != "OPERATIONAL" or node.id in self.silent:
                    continue
                for k, m in node.tpdo.map.items():
                    if not m.enabled or m.trans_type is None or not 1 <= m.trans_type <= 240:
                        continue
                    c = self.sync_counter.get((node.id, k), 0) + 1
                    if c < m.trans_type:
                        self.sync_counter[(node.id, k)] = c
                        continue
                    self.sync_counter[(node.id, k)] = 0
                    for v in m.map:  # pack the mapped objects as LocalNode's PDO map does
                        v.set_data(node.get_data(v.index, v.subindex))
                    m.transmit()
                    self.sent[m.cob_id] = self.sent.get(m.cob_id, 0) + 1
                    if node is self.pr:
                        self.pressures.append(struct.unpack("<i", bytes(m.data[:4]))[0])

    def summary(self):
        return {"syncs": self.syncs, "valve_state": self.dsm.state, "spool": self.spool,
                "tpdo_sent": {f"0x{k:03X}": v for k, v in self.sent.items()},
                "emcy_sent": self.emcy_sent,
                "control_word": self.dsm.cw,
                "setpoint": struct.unpack("<h", self.va.get_data(0x6300, 1))[0],
                "nmt": {"transducer": self.tr.nmt.state, "valve": self.va.nmt.state},
                "pressures_sent": self.pressures}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--config", required=True)
    ap.add_argument("--transducer-id", type=int, default=32)
    ap.add_argument("--valve-id", type=int, default=48)
    ap.add_argument("--events")
    ap.add_argument("--transducer-eds", help="the transducer's EDS (default: the shipped one)")
    ap.add_argument("--pressure-id", type=int,
                    help="node id of a CiA 404 pressure transmitter (default: none)")
    ap.add_argument("--fault", action="append", default=[],
                    help="emcy@T: valve fault (EMCY 0x5000, FAULT_REACTION) at SYNC T·1000; "
                    "pressure-heartbeat-loss@T: the pressure transmitter falls silent")
    a = ap.parse_args()
    faults = []
    for f in a.fault:
        kind, _, at = f.partition("@")
        if kind not in ("emcy", "pressure-heartbeat-loss"):
            ap.error(f"--fault {f}: expected emcy@T or pressure-heartbeat-loss@T")
        if kind == "pressure-heartbeat-loss" and a.pressure_id is None:
            ap.error(f"--fault {f}: needs --pressure-id")
        faults.append({"kind": kind, "at": float(at or 0)})
    rig = Rig(a.port, a.config, a.transducer_id, a.valve_id, faults, a.events,
              a.transducer_eds, a.pressure_id)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    rig.power_on()
    print("localnode devices ready", flush=True)
    while not stop.wait(0.05):
        pass
    s = rig.summary()
    for n in rig.nodes:
        n.nmt.stop_heartbeat()
    rig.net.disconnect()
    print(json.dumps(s), flush=True)


if __name__ == "__main__":
    sys.exit(main())
