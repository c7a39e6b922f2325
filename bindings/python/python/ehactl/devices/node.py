"""One simulated CANopen slave (CiA 301 part) on top of ``canopen.LocalNode``.

``canopen.LocalNode`` gives the object dictionary read from our EDS and an SDO server. It does
not consume SYNC, does not gate PDOs by NMT state and does not write received RPDO data into
its object store, and its NMT slave sends heartbeats from python-can's own periodic thread. This
class therefore takes over NMT (boot-up, states, reset), the heartbeat producer (0x1017), the
PDO machinery (communication/mapping objects 0x1400/0x1600/0x1800/0x1A00 with the CiA 301
re-mapping rules) and EMCY (0x1001, 0x1003), and leaves the SDO server to ``LocalNode``.
"""

from __future__ import annotations

import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Tuple

import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.sdo.exceptions import SdoAbortedError

# NMT states as sent in the heartbeat (CiA 301 7.2.8.3.2.1).
INITIALISING = 0x00
STOPPED = 0x04
OPERATIONAL = 0x05
PRE_OPERATIONAL = 0x7F
NMT_NAMES = {INITIALISING: "INITIALISING", STOPPED: "STOPPED", OPERATIONAL: "OPERATIONAL",
             PRE_OPERATIONAL: "PRE-OPERATIONAL"}

# NMT command specifiers (CiA 301 7.2.8.3.1).
NMT_START, NMT_STOP, NMT_PRE_OP, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82

# SDO abort codes used here (CiA 301 table 22).
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_NOT_IN_OD = 0x06020000
ABORT_CANNOT_MAP = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_PARAM_INCOMPATIBLE = 0x06040043
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_HIGH = 0x06090031
ABORT_VALUE_LOW = 0x06090032
ABORT_DEVICE_STATE = 0x08000022

# EMCY error codes (CiA 301 table 21).
EMCY_PDO_LENGTH = 0x8210  # PDO not processed due to length error
EMCY_RPDO_TIMEOUT = 0x8250  # RPDO timeout (deadline of the event timer missed)

COB_INVALID = 0x80000000  # bit 31 of a PDO COB-ID: PDO does not exist / is disabled


@dataclass
class PdoConfig:
    """One PDO as configured by its communication and mapping objects."""

    comm_index: int
    cob_id: int = 0
    valid: bool = False
    trans_type: int = 1
    event_timer_ms: int = 0
    entries: List[Tuple[int, int, int]] = field(default_factory=list)  # (index, sub, bytes)

    @property
    def nbytes(self) -> int:
        return sum(n for _, _, n in self.entries)


class SimNode:
    """A CANopen slave: NMT, heartbeat, SDO server (LocalNode), PDOs, EMCY.

    Subclasses provide the device profile: ``live_value(index, sub)`` for read-only process
    data, ``on_app_write(index, sub, value)`` for side effects of writes and ``on_nmt_change``.
    """

    #: Short name used in events and messages.
    kind = "node"

    def __init__(self, network: canopen.Network, node_id: int, eds_path: str,
                 emit: Callable[..., None]):
        self.network = network
        self.node_id = node_id
        self.emit = emit
        self.node = canopen.LocalNode(node_id, eds_path)
        self.od = self.node.object_dictionary
        network.add_node(self.node)
        # Take NMT and heartbeat away from LocalNode's NmtSlave (python-can periodic thread,
        # bypasses the network send lock) and gate its SDO server by our NMT state.
        network.unsubscribe(0, self.node.nmt.on_command)
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        network.subscribe(self.node.sdo.rx_cobid, self._on_sdo_request)
        self.node.add_read_callback(self._read_cb)
        self.node.add_write_callback(self._write_cb)

        self.nmt_state = INITIALISING
        self.powered = False      # False until boot() and with the no-boot fault
        self.hb_period_s = 0.0
        self.hb_next = 0.0
        self.error_register = 0
        self.error_history: List[int] = []
        self.tpdos: Dict[int, PdoConfig] = {}
        self.rpdos: Dict[int, PdoConfig] = {}
        self._rpdo_subscribed: Dict[int, Callable] = {}
        self._latched: Dict[int, bytes] = {}   # RPDO comm index -> data waiting for SYNC
        self._sync_counter: Dict[int, int] = {}
        self._last_sent: Dict[int, bytes] = {}
        self._next_async: Dict[int, float] = {}
        self._abort_hooks: List[Callable[[int, int], Optional[int]]] = []
        self._pending_after: List[Callable[[], None]] = []
        self.lock = threading.RLock()
        # Heartbeat consumers (0x1016): producer node id -> [consumer time s, last seen or None]
        self._consumers: Dict[int, list] = {}
        self._consumer_subscribed: Dict[int, Callable] = {}
        # RPDO deadline monitoring (event timer 0x140x:05, CiA 301 v4.2 7.5.2.35): RPDO comm
        # index -> bus time of its last reception (None: not monitoring)
        self._rpdo_last: Dict[int, Optional[float]] = {}
        self.counters = {"rpdo": 0, "rpdo_bad_length": 0, "tpdo": 0, "sdo": 0,
                         "nmt": 0, "heartbeat_lost": 0, "rpdo_timeout": 0}

    # ----------------------------------------------------------------- object access
    def var(self, index: int, sub: int = 0) -> ODVariable:
        obj = self.od[index]
        return obj if isinstance(obj, ODVariable) else obj[sub]

    def value(self, index: int, sub: int = 0):
        """Current value of an object (stored, live or EDS default), decoded."""
        return self.var(index, sub).decode_raw(self.node.get_data(index, sub))

    def live_value(self, index: int, sub: int):
        """Process data computed by the device (None: use the stored value)."""
        if index == 0x1001:
            return self.error_register
        if index == 0x1003 and 0x1003 in self.od:
            if sub == 0:
                return len(self.error_history)
            return self.error_history[sub - 1] if sub <= len(self.error_history) else 0
        return None

    def _read_cb(self, index, subindex, od):
        return self.live_value(index, subindex)

    # ----------------------------------------------------------------- send path
    def send(self, cob_id: int, data: bytes) -> None:
        if not self.powered:
            return
        self.network.send_message(cob_id, bytes(data))

    # ----------------------------------------------------------------- NMT
    def boot(self) -> None:
        """Power-on / reset: INITIALISING → boot-up message → PRE-OPERATIONAL."""
        with self.lock:
            self.powered = True
            self.nmt_state = INITIALISING
            self.on_reset()
            self.reload_pdos()
            self.send(0x700 + self.node_id, b"\x00")
            self.emit(self.kind, "boot-up", node_id=self.node_id)
            self._set_nmt(PRE_OPERATIONAL)
            self._restart_heartbeat()
            self._reload_consumers()

    def on_nmt(self, data: bytes) -> None:
        """Handle an NMT command frame (COB-ID 0x000)."""
        if not self.powered or len(data) != 2:
            return
        cmd, target = data[0], data[1]
        if target not in (0, self.node_id):
            return
        self.counters["nmt"] += 1
        with self.lock:
            if cmd == NMT_START:
                self.reload_pdos()
                self._set_nmt(OPERATIONAL)
            elif cmd == NMT_STOP:
                self._set_nmt(STOPPED)
            elif cmd == NMT_PRE_OP:
                self._set_nmt(PRE_OPERATIONAL)
            elif cmd == NMT_RESET_NODE:
                self.emit(self.kind, "nmt-reset-node", node_id=self.node_id)
                self.node.data_store.clear()
                self.error_history.clear()
                self.error_register = 0
                self.boot()
            elif cmd == NMT_RESET_COMM:
                self.emit(self.kind, "nmt-reset-communication", node_id=self.node_id)
                for idx in [i for i in self.node.data_store if 0x1000 <= i <= 0x1FFF]:
                    del self.node.data_store[idx]
                self.boot()

    def _set_nmt(self, state: int) -> None:
        old = self.nmt_state
        self.nmt_state = state
        if old != state:
            self.emit(self.kind, "nmt", node_id=self.node_id, state=NMT_NAMES[state],
                      old=NMT_NAMES[old])
            self.on_nmt_change(old, state)

    def on_nmt_change(self, old: int, new: int) -> None:
        """Profile hook: NMT state changed."""

    def on_reset(self) -> None:
        """Profile hook: application reset at boot."""

    # ----------------------------------------------------------------- heartbeat
    def _restart_heartbeat(self) -> None:
        ms = self.value(0x1017)
        self.hb_period_s = ms / 1000.0
        self.hb_next = time.monotonic() + self.hb_period_s

    def heartbeat_due(self, now: float) -> None:
        """Called by the rig's timer thread: send the heartbeat if its period has elapsed."""
        if self.hb_period_s <= 0 or not self.powered or self.nmt_state == INITIALISING:
            return
        if now >= self.hb_next:
            self.send(0x700 + self.node_id, bytes([self.nmt_state]))
            self.hb_next += self.hb_period_s
            if self.hb_next < now:  # we fell behind (overloaded machine): do not burst
                self.hb_next = now + self.hb_period_s

    # ----------------------------------------------------------------- heartbeat consumer
    def _reload_consumers(self) -> None:
        """Re-read 0x1016 (CiA 301 7.5.2.14: sub k = producer node id << 16 | time ms; 0 off).
        A consumer starts monitoring at the first heartbeat it receives."""
        for cob, cb in self._consumer_subscribed.items():
            self.network.unsubscribe(cob, cb)
        self._consumer_subscribed = {}
        self._consumers = {}
        if 0x1016 not in self.od:
            return
        for k in range(1, self.value(0x1016, 0) + 1):
            v = self.value(0x1016, k)
            producer, ms = (v >> 16) & 0x7F, v & 0xFFFF
            if producer == 0 or ms == 0:
                continue
            self._consumers[producer] = [ms / 1000.0, None]
            cob = 0x700 + producer
            cb = (lambda p: (lambda can_id, data, ts: self._on_producer_heartbeat(p, data, ts)))(
                producer)
            self.network.subscribe(cob, cb)
            self._consumer_subscribed[cob] = cb

    def _on_producer_heartbeat(self, producer: int, data: bytes, ts: float) -> None:
        if len(data) != 1 or not self.powered:
            return
        c = self._consumers.get(producer)
        if c is not None:
            c[1] = ts if ts else time.time()

    def consumers_due(self, now: float) -> None:
        """A monitored producer silent for its consumer time is lost (heartbeat event, CiA 301
        7.2.8.3.2.2): EMCY 0x8130 and the profile's reaction; monitoring restarts with its next
        heartbeat. Times are bus times (the receive stamp of each frame, wall clock s): the rig
        checks at every received frame with that frame's stamp and, when nothing arrives, with
        the wall clock. A real device handles each frame as it arrives; this Python one may be
        behind its receive queue on a loaded machine, and a heartbeat still waiting in that
        queue is no loss."""
        if not self.powered or self.nmt_state == INITIALISING:
            return
        self.rpdo_deadlines_due(now)
        for producer, c in list(self._consumers.items()):
            t, last = c
            if last is not None and now - last > t:
                c[1] = None
                self.counters["heartbeat_lost"] += 1
                self.emit(self.kind, "heartbeat-lost", node_id=self.node_id, producer=producer,
                          consumer_time_s=t, silent_s=now - last)
                self.on_heartbeat_lost(producer)

    def rpdo_deadlines_due(self, now: float) -> None:
        """An RPDO with an event timer (0x140x:05, ms) not received for that long in
        OPERATIONAL: deadline missed (CiA 301 v4.2 7.5.2.35), EMCY 0x8250 and the profile's
        reaction; monitoring restarts with the next reception. Bus time as for heartbeats."""
        if self.nmt_state != OPERATIONAL:
            self._rpdo_last = {}
            return
        for comm, last in list(self._rpdo_last.items()):
            cfg = self.rpdos.get(comm)
            if last is None or cfg is None or cfg.event_timer_ms <= 0:
                continue
            if now - last > cfg.event_timer_ms / 1000.0:
                self._rpdo_last[comm] = None
                self.counters["rpdo_timeout"] += 1
                self.emit(self.kind, "rpdo-timeout", node_id=self.node_id,
                          rpdo=f"0x{comm:04X}", deadline_s=cfg.event_timer_ms / 1000.0,
                          silent_s=now - last)
                self.on_rpdo_timeout(comm)

    def on_rpdo_timeout(self, comm: int) -> None:
        """Profile hook: an RPDO missed its deadline (default: EMCY 0x8250, RPDO timeout)."""
        self.emcy(EMCY_RPDO_TIMEOUT, 0x10)

    def on_heartbeat_lost(self, producer: int) -> None:
        """Profile hook: the heartbeat of `producer` was lost (default: EMCY 0x8130)."""
        self.emcy(0x8130, 0x10)

    # ----------------------------------------------------------------- SDO
    def _on_sdo_request(self, can_id, data, timestamp):
        # SDO is served in PRE-OPERATIONAL and OPERATIONAL only (CiA 301 table 76).
        if not self.powered or self.nmt_state not in (PRE_OPERATIONAL,
                                                                        OPERATIONAL):
            return
        if len(data) != 8:
            return  # CiA 301: SDO frames have DLC 8; anything else is not an SDO request
        self.counters["sdo"] += 1
        with self.lock:
            self.node.sdo.on_request(can_id, data, timestamp)
            self.run_pending()

    def add_abort_hook(self, hook: Callable[[int, int], Optional[int]]) -> None:
        """Fault injection: hook(index, sub) returns an abort code to refuse a write."""
        self._abort_hooks.append(hook)

    def _write_cb(self, index, subindex, od, data):
        """Validate a write (SDO or RPDO) and apply its side effects; raise to abort."""
        for hook in self._abort_hooks:
            code = hook(index, subindex)
            if code is not None:
                self.emit(self.kind, "sdo-abort-injected", node_id=self.node_id,
                          index=f"0x{index:04X}", sub=subindex, code=f"0x{code:08X}")
                raise SdoAbortedError(code)
        value = od.decode_raw(data)
        if isinstance(value, int):
            if od.min is not None and value < od.min:
                raise SdoAbortedError(ABORT_VALUE_LOW)
            if od.max is not None and value > od.max:
                raise SdoAbortedError(ABORT_VALUE_HIGH)
        if 0x1400 <= index <= 0x1BFF:
            self._check_pdo_write(index, subindex, value)
        elif index == 0x1003:
            if subindex != 0 or value != 0:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            self.error_history.clear()
            return
        elif index not in (0x1016, 0x1017):
            self.on_app_write(index, subindex, value)
        # LocalNode stores the value after the callbacks: apply dependent state afterwards.
        if index == 0x1017:
            self.network_after(self._restart_heartbeat)
        elif index == 0x1016:
            self.network_after(self._reload_consumers)
        elif 0x1400 <= index <= 0x1BFF:
            self.network_after(self.reload_pdos)

    def network_after(self, fn: Callable[[], None]) -> None:
        """Run fn once the current write has been stored (LocalNode stores after callbacks)."""
        self._pending_after.append(fn)

    def run_pending(self) -> None:
        pending, self._pending_after = self._pending_after, []
        for fn in pending:
            fn()

    def on_app_write(self, index: int, sub: int, value) -> None:
        """Profile hook: validated write to a profile object (raise SdoAbortedError to refuse)."""

    # ----------------------------------------------------------------- PDO configuration
    def _comm_of(self, index: int) -> int:
        if 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF:
            return index - 0x200
        return index

    def _check_pdo_write(self, index: int, sub: int, value: int) -> None:
        """CiA 301 7.5.2.35-38 rules for PDO communication and mapping parameters."""
        is_rx = 0x1400 <= index <= 0x17FF
        comm = self._comm_of(index)
        cob_now = self.value(comm, 1)
        valid_now = not (cob_now & COB_INVALID)
        if index == comm:  # communication parameter
            if sub == 1:
                if value & 0x20000000 or value & 0x1FFFF800:
                    raise SdoAbortedError(ABORT_VALUE_RANGE)  # 29-bit ids not supported
                if valid_now and not (value & COB_INVALID) and (value & 0x7FF) != (cob_now & 0x7FF):
                    raise SdoAbortedError(ABORT_VALUE_RANGE)  # change COB-ID only when invalid
            elif sub == 2:
                if not (value <= 240 or value in (254, 255)):
                    raise SdoAbortedError(ABORT_VALUE_RANGE)
            return
        # mapping parameter
        if valid_now:
            raise SdoAbortedError(ABORT_DEVICE_STATE)  # disable the PDO first (bit 31)
        count = self.value(index, 0)
        if sub == 0:
            if value > 8:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            total = 0
            for k in range(1, value + 1):
                total += self._check_entry(self.value(index, k), is_rx)
            if total > 64:
                raise SdoAbortedError(ABORT_PDO_LENGTH)
            return
        if count != 0:
            raise SdoAbortedError(ABORT_PARAM_INCOMPATIBLE)  # set sub0 = 0 before entries
        self._check_entry(value, is_rx)

    def _check_entry(self, entry: int, is_rx: bool) -> int:
        idx, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        if idx not in self.od:
            raise SdoAbortedError(ABORT_NOT_IN_OD)
        obj = self.od[idx]
        if not isinstance(obj, ODVariable):
            if sub not in obj:
                raise SdoAbortedError(ABORT_CANNOT_MAP)
            obj = obj[sub]
        elif sub != 0:
            raise SdoAbortedError(ABORT_CANNOT_MAP)
        if not obj.pdo_mappable or bits != len(obj):
            raise SdoAbortedError(ABORT_CANNOT_MAP)
        if is_rx and not obj.writable:
            raise SdoAbortedError(ABORT_CANNOT_MAP)
        if not is_rx and not obj.readable:
            raise SdoAbortedError(ABORT_CANNOT_MAP)
        return bits

    def _read_pdo(self, comm: int) -> PdoConfig:
        cfg = PdoConfig(comm_index=comm)
        cob = self.value(comm, 1)
        cfg.cob_id = cob & 0x7FF
        cfg.valid = not (cob & COB_INVALID)
        cfg.trans_type = self.value(comm, 2)
        entry = self.od[comm]
        if isinstance(entry, (ODRecord, ODArray)) and 5 in entry:
            cfg.event_timer_ms = self.value(comm, 5)
        mapping = comm + 0x200
        for k in range(1, self.value(mapping, 0) + 1):
            e = self.value(mapping, k)
            cfg.entries.append((e >> 16, (e >> 8) & 0xFF, (e & 0xFF) // 8))
        return cfg

    def reload_pdos(self) -> None:
        """Re-read every PDO communication/mapping object (after boot, NMT start, SDO writes)."""
        self.tpdos = {c: self._read_pdo(c) for c in range(0x1800, 0x1A00) if c in self.od}
        self.rpdos = {c: self._read_pdo(c) for c in range(0x1400, 0x1600) if c in self.od}
        for cob, cb in self._rpdo_subscribed.items():
            self.network.unsubscribe(cob, cb)
        self._rpdo_subscribed = {}
        for comm, cfg in self.rpdos.items():
            if cfg.valid:
                cb = (lambda c: (lambda can_id, data, ts: self._on_rpdo(c, data, ts)))(comm)
                self.network.subscribe(cfg.cob_id, cb)
                self._rpdo_subscribed[cfg.cob_id] = cb
        self._latched.clear()
        self._rpdo_last = {}
        self._sync_counter = {c: 0 for c in self.tpdos}
        self._last_sent.clear()

    # ----------------------------------------------------------------- PDO traffic
    def _on_rpdo(self, comm: int, data: bytes, ts: float = 0.0) -> None:
        if self.nmt_state != OPERATIONAL or not self.powered:
            return  # PDOs are only processed in OPERATIONAL
        cfg = self.rpdos.get(comm)
        if cfg is None or not cfg.valid:
            return
        self.counters["rpdo"] += 1
        if cfg.event_timer_ms > 0:
            # deadline monitoring starts with the first reception (CiA 301 v4.2 7.5.2.35)
            self._rpdo_last[comm] = ts if ts else time.time()
        if len(data) < cfg.nbytes:
            self.counters["rpdo_bad_length"] += 1
            self.emcy(EMCY_PDO_LENGTH, 0x10)  # communication error bit (CiA 301 0x1001 bit 4)
            return
        if cfg.trans_type <= 240:
            self._latched[comm] = bytes(data)  # applied at the next SYNC
        else:
            self._apply_rpdo(cfg, bytes(data))

    def _apply_rpdo(self, cfg: PdoConfig, data: bytes) -> None:
        off = 0
        with self.lock:
            for idx, sub, n in cfg.entries:
                self.node.set_data(idx, sub, data[off:off + n])
                off += n
            self.run_pending()

    def apply_latched_rpdos(self) -> None:
        """SYNC: write the RPDO data received since the last SYNC into the object store."""
        latched, self._latched = self._latched, {}
        for comm, data in latched.items():
            try:
                self._apply_rpdo(self.rpdos[comm], data)
            except SdoAbortedError as e:
                self.emit(self.kind, "rpdo-rejected", node_id=self.node_id,
                          code=f"0x{e.code:08X}")

    def pack_tpdo(self, cfg: PdoConfig) -> bytes:
        return b"".join(bytes(self.node.get_data(i, s))[:n] for i, s, n in cfg.entries)

    def send_sync_tpdos(self) -> None:
        """SYNC: send the synchronous TPDOs (transmission type 0..240) that are due."""
        if self.nmt_state != OPERATIONAL:
            return
        for comm, cfg in self.tpdos.items():
            if not cfg.valid or cfg.trans_type > 240:
                continue
            data = self.pack_tpdo(cfg)
            if cfg.trans_type == 0:  # acyclic synchronous: on SYNC if the data changed
                if self._last_sent.get(comm) == data:
                    continue
            else:
                self._sync_counter[comm] = self._sync_counter.get(comm, 0) + 1
                if self._sync_counter[comm] < cfg.trans_type:
                    continue
                self._sync_counter[comm] = 0
            self._last_sent[comm] = data
            self.counters["tpdo"] += 1
            self.send(cfg.cob_id, data)

    def async_period_s(self, cfg: PdoConfig) -> float:
        """Period of an event-driven TPDO (type 254/255): its event timer 0x180x:05 (ms)."""
        return cfg.event_timer_ms / 1000.0

    def async_tpdos_due(self, now: float) -> None:
        """Timer thread: send event-driven TPDOs (type 254/255) whose timer has elapsed."""
        if self.nmt_state != OPERATIONAL:
            return
        for comm, cfg in list(self.tpdos.items()):
            if not cfg.valid or cfg.trans_type < 254:
                continue
            period = self.async_period_s(cfg)
            if period <= 0:
                continue
            due = self._next_async.get(comm)
            if due is None or due > now + period:
                self._next_async[comm] = now + period
                continue
            if now >= due:
                self._next_async[comm] = max(due + period, now)
                self.counters["tpdo"] += 1
                self.send(cfg.cob_id, self.pack_tpdo(cfg))

    # ----------------------------------------------------------------- EMCY
    def emcy(self, code: int, register_bits: int, manufacturer: bytes = b"") -> None:
        """Send an EMCY frame (error code, 0x1001, 5 manufacturer bytes) and record it."""
        if code != 0:
            self.error_register |= register_bits | 0x01  # bit 0 generic error
            self.error_history.insert(0, code)
            del self.error_history[4:]
        else:
            self.error_register = 0
        payload = struct.pack("<HB5s", code, self.error_register, manufacturer[:5])
        self.emit(self.kind, "emcy", node_id=self.node_id, code=f"0x{code:04X}",
                  error_register=self.error_register)
        if self.nmt_state in (PRE_OPERATIONAL, OPERATIONAL):
            self.send(0x80 + self.node_id, payload)
