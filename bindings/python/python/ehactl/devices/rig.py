"""The simulated rig: one CAN connection, the CiA 406 transducer and the CiA 408 valve OBE
sharing one ``ehactl.Plant``, SYNC-driven plant time, heartbeat/event timers and fault injection.

Plant time advances only on SYNC: each SYNC applies the latched RPDO setpoint, steps the plant by
one SYNC period (n = round(sync_period / control_dt) control periods with the valve command held)
and then sends the synchronous TPDOs (transducer position, valve status word + actual spool).
"""

from __future__ import annotations

import json
import math
import select
import socket
import sys
import threading
import time
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

import can
from can.interfaces.socketcand import SocketCanDaemonBus
import canopen

from .node import OPERATIONAL, PRE_OPERATIONAL
from .transducer import Transducer
from .valve import EMCY_DEVICE_HARDWARE, ValveObe

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - older interpreters
    import tomli as tomllib

#: EDS files shipped in the repository (configs/eds) and, for installed wheels, next to us.
EDS_NAMES = {"transducer": "ehactl_transducer_406.eds", "valve": "ehactl_valve_408.eds"}

FAULT_KINDS = ("heartbeat-loss", "emcy", "sdo-abort", "no-boot", "leave-active", "malformed")
#: COB-ID of the "unknown" frame of the malformed fault: TPDO2 of the transducer, which is never
#: configured (the master has no use for it).
MALFORMED_UNKNOWN_COB_ID = 0x2A0


class DeviceError(Exception):
    """Bad command-line argument, config field or bus address (one-line message)."""


# --------------------------------------------------------------------------- settings
@dataclass
class CanopenSettings:
    """The [canopen] section of a rig config (defaults of the ICD)."""

    bitrate: int = 1_000_000            # bit/s
    sync_rate_hz: float = 1000.0        # Hz
    heartbeat_ms: int = 20              # ms (set by the master over SDO)
    heartbeat_timeout_ms: int = 60      # ms (master's consumer timeout)
    transducer_node_id: int = 32
    valve_node_id: int = 48

    @property
    def sync_period_s(self) -> float:
        return 1.0 / self.sync_rate_hz


def load_canopen_settings(config_path: str) -> CanopenSettings:
    """Read [canopen] from a rig TOML (all fields optional) with one-line errors."""
    try:
        with open(config_path, "rb") as f:
            doc = tomllib.load(f)
    except FileNotFoundError:
        raise DeviceError(f"config {config_path}: file not found") from None
    except tomllib.TOMLDecodeError as e:
        raise DeviceError(f"config {config_path}: invalid TOML: {e}") from None
    sec = doc.get("canopen", {})
    if not isinstance(sec, dict):
        raise DeviceError(f"config {config_path}: [canopen] must be a table")
    s = CanopenSettings()

    def num(key, lo, hi, unit, integer):
        if key not in sec:
            return getattr(s, key)
        v = sec[key]
        ok = isinstance(v, int) if integer else isinstance(v, (int, float))
        if isinstance(v, bool) or not ok or not math.isfinite(v) or not lo <= v <= hi:
            kind = "an integer" if integer else "a number"
            raise DeviceError(f"config {config_path}: canopen.{key} = {v!r}: expected {kind} "
                              f"in [{lo}, {hi}] {unit}")
        return v

    s.bitrate = num("bitrate", 10_000, 1_000_000, "bit/s", True)
    s.sync_rate_hz = float(num("sync_rate_hz", 1.0, 10_000.0, "Hz", False))
    s.heartbeat_ms = num("heartbeat_ms", 0, 65535, "ms", True)
    s.heartbeat_timeout_ms = num("heartbeat_timeout_ms", 0, 65535, "ms", True)
    s.transducer_node_id = num("transducer_node_id", 1, 127, "(node id)", True)
    s.valve_node_id = num("valve_node_id", 1, 127, "(node id)", True)
    if s.transducer_node_id == s.valve_node_id:
        raise DeviceError(f"config {config_path}: canopen.transducer_node_id and "
                          f"canopen.valve_node_id are both {s.valve_node_id}; expected two "
                          "different node ids")
    return s


@dataclass
class Fault:
    """One injected fault: KIND[@T], T in simulated seconds counted from the first SYNC."""

    kind: str
    at_s: float = 0.0
    done: bool = False


def parse_fault(spec: str) -> Fault:
    kind, _, t = spec.partition("@")
    if kind not in FAULT_KINDS:
        raise DeviceError(f"--fault {spec!r}: unknown kind {kind!r}; expected one of "
                          f"{', '.join(FAULT_KINDS)} with optional @T (s)")
    at = 0.0
    if t:
        try:
            at = float(t)
        except ValueError:
            at = float("nan")
        if not math.isfinite(at) or at < 0:
            raise DeviceError(f"--fault {spec!r}: time {t!r} is not a number ≥ 0 (s)")
    return Fault(kind, at)


def find_eds(name: str, eds_dir: Optional[str]) -> str:
    """Locate an EDS file: --eds-dir, the package data, or configs/eds of the checkout."""
    candidates = []
    if eds_dir:
        candidates.append(Path(eds_dir) / name)
    here = Path(__file__).resolve()
    candidates.append(here.parent / "eds" / name)
    for parent in here.parents:
        candidates.append(parent / "configs" / "eds" / name)
    candidates.append(Path.cwd() / "configs" / "eds" / name)
    for c in candidates:
        if c.is_file():
            return str(c)
    raise DeviceError(f"EDS file {name} not found (looked in --eds-dir, the package and "
                      "configs/eds of the checkout); pass --eds-dir DIR")


# --------------------------------------------------------------------------- bus
class _HubBus(SocketCanDaemonBus):
    """python-can's socketcand client, plus detection of a closed TCP connection (the stock
    client then spins on select()/recv() returning nothing forever)."""

    #: Bytes or a frame taken from the socket and not yet handled: set before the notifier
    #: thread reads, cleared when it found nothing or (by the rig) once the frame has been
    #: dispatched. python-can's client holds what it read in locals while it parses and
    #: between handing a frame over and the first listener; a timer thread that took that
    #: moment for an idle bus judged the heartbeat consumers on the wall clock with the
    #: heartbeat in flight, and lost ehactl's heartbeat (tests/python/test_can_demo.py).
    in_flight = False

    def _recv_internal(self, timeout):
        sock = getattr(self, "_SocketCanDaemonBus__socket", None)
        if sock is not None and not getattr(self, "_SocketCanDaemonBus__message_buffer", None):
            try:
                ready, _, _ = select.select([sock], [], [], timeout)
            except OSError:
                ready = [sock]  # the read below reports it
            if not ready:
                return None, False
            timeout = 0
        self.in_flight = True
        msg, filtered = super()._recv_internal(timeout)
        if msg is None:
            self.in_flight = False
            sock = getattr(self, "_SocketCanDaemonBus__socket", None)
            if sock is not None:
                try:
                    ready, _, _ = select.select([sock], [], [], 0)
                    if ready and sock.recv(1, socket.MSG_PEEK) == b"":
                        raise can.CanOperationError("socketcand server closed the connection")
                except OSError as e:
                    raise can.CanOperationError(f"socketcand connection lost: {e}") from e
        return msg, filtered


    def rx_pending(self) -> bool:
        """Frames received but not yet handled (in flight, parsed or still in the socket)."""
        if self.in_flight or getattr(self, "_SocketCanDaemonBus__message_buffer", None):
            return True
        sock = getattr(self, "_SocketCanDaemonBus__socket", None)
        if sock is None:
            return False
        try:
            ready, _, _ = select.select([sock], [], [], 0)
        except (OSError, ValueError):
            return False
        return bool(ready)


class _DispatchStart(can.Listener):
    """First listener of the notifier: marks that a frame is being dispatched."""

    def __init__(self):
        self.busy = False

    def on_message_received(self, msg) -> None:
        self.busy = True


def open_bus(url: str) -> can.BusABC:
    """Open `socketcand://HOST:PORT/CHANNEL` or `socketcan://CHANNEL` with python-can."""
    u = urllib.parse.urlparse(url)
    if u.scheme == "socketcand":
        channel = u.path.lstrip("/")
        if not u.hostname or not u.port or not channel:
            raise DeviceError(f"--bus {url!r}: expected socketcand://HOST:PORT/CHANNEL, "
                              "e.g. socketcand://127.0.0.1:29536/can0")
        try:
            # Fail fast with one line: python-can itself retries for 10 s, warning each time.
            socket.create_connection((u.hostname, u.port), timeout=3.0).close()
            return _HubBus(channel=channel, host=u.hostname, port=u.port, tcp_tune=True)
        except (OSError, TimeoutError, can.CanError) as e:
            raise DeviceError(f"--bus {url!r}: cannot connect to socketcand at "
                              f"{u.hostname}:{u.port}: {e}") from None
    if u.scheme == "socketcan":
        channel = u.netloc or u.path.lstrip("/")
        if not channel:
            raise DeviceError(f"--bus {url!r}: expected socketcan://CHANNEL, e.g. socketcan://can0")
        try:
            return can.Bus(interface="socketcan", channel=channel)
        except (OSError, can.CanError) as e:
            raise DeviceError(f"--bus {url!r}: cannot open SocketCAN {channel}: {e}") from None
    raise DeviceError(f"--bus {url!r}: unknown scheme; expected socketcand://HOST:PORT/CHANNEL "
                      "or socketcan://CHANNEL")


# --------------------------------------------------------------------------- rig
class RigNetwork(canopen.Network):
    """canopen.Network that counts every frame and drops those of silenced (TX-dead) nodes."""

    def __init__(self, bus):
        super().__init__(bus)
        self.silenced_nodes: set = set()
        self._count_lock = threading.Lock()
        self.frames_sent: Dict[int, int] = {}      # COB-ID -> frames sent by this process
        self.frames_received: Dict[int, int] = {}  # COB-ID -> frames received
        self.dispatching = _DispatchStart()
        # canopen types `listeners` by its own listener class; python-can's Notifier takes
        # any can.Listener (it calls on_message_received), which these two are.
        self.listeners.insert(0, self.dispatching)  # type: ignore[arg-type]
        self.counting = _CountingListener(self.frames_received)
        self.listeners.append(self.counting)  # type: ignore[arg-type]

    def rx_idle(self) -> bool:
        """Every received frame has been handled (nothing queued, none being dispatched)."""
        if self.dispatching.busy:
            return False
        pending = getattr(self.bus, "rx_pending", None)
        return not pending() if pending is not None else True

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        if can_id not in (0x000, 0x080) and (can_id & 0x7F) in self.silenced_nodes:
            return
        super().send_message(can_id, data, remote)
        with self._count_lock:  # senders: notifier thread and timer thread
            self.frames_sent[can_id] = self.frames_sent.get(can_id, 0) + 1


class _CountingListener(can.Listener):
    """Counts frames; after each frame has been dispatched (this listener comes after
    canopen's), calls ``after(bus_time)`` with its receive stamp (s)."""

    def __init__(self, counts: Dict[int, int]):
        self.counts = counts
        #: called with the frame's time (s) after each frame is counted
        self.after: Optional[Callable[[float], None]] = None

    def on_message_received(self, msg) -> None:
        self.counts[msg.arbitration_id] = self.counts.get(msg.arbitration_id, 0) + 1
        if self.after is not None:
            self.after(msg.timestamp or time.time())


class EventLog:
    """Device events as JSON lines (file) and one-line messages (stderr)."""

    def __init__(self, path: Optional[str], rig: "SimRig", quiet: bool = False):
        self.rig = rig
        self.quiet = quiet
        self.f = open(path, "a", encoding="utf-8") if path else None
        self.lock = threading.Lock()
        self.events: List[dict] = []

    def __call__(self, device: str, event: str, **fields) -> None:
        rec = {"t_wall": time.time(), "t_sim": self.rig.t_sim, "sync": self.rig.sync_count,
               "device": device, "event": event, **fields}
        with self.lock:
            self.events.append(rec)
            if self.f:
                self.f.write(json.dumps(rec) + "\n")
                self.f.flush()
        if not self.quiet:
            extra = " ".join(f"{k}={v}" for k, v in fields.items())
            print(f"[{rec['t_sim']:9.4f} s] {device}: {event} {extra}", file=sys.stderr,
                  flush=True)

    def close(self):
        if self.f:
            self.f.close()


class SimRig:
    """Transducer + valve OBE on one bus, sharing one plant (``ehactl.Plant``)."""

    def __init__(self, bus_url: str, config_path: str, faults: Sequence[Fault] = (),
                 events_path: Optional[str] = None, eds_dir: Optional[str] = None,
                 quiet: bool = False):
        import ehactl  # the compiled bindings (plant)

        self.settings = load_canopen_settings(config_path)
        try:
            self.cfg = ehactl.Config.load(config_path)
            # Plant steps that tile one SYNC period exactly, no longer than the control
            # period (1 kHz SYNC, 5 kHz control: 5 steps of 0.2 ms).
            period, dt = self.settings.sync_period_s, self.cfg.control_dt
            n = max(1, math.ceil(period / dt - 1e-9))
            if abs(n * dt - period) > 1e-12 * period:
                dt = period / n
            self.plant = ehactl.Plant(self.cfg, dt)
        except (ValueError, OSError) as e:
            raise DeviceError(f"config {config_path}: {e}") from None
        self.control_dt = dt
        self.steps_per_sync = n
        self.full_scale_v = float(self.cfg["valve.command_full_scale"])
        self.faults = list(faults)
        self.sync_count = 0
        self.t_sim = 0.0
        self.events = EventLog(events_path, self, quiet)
        self.stop_event = threading.Event()
        self.bus_lost: Optional[str] = None
        self.last_command_v = 0.0
        self.numerical_failure = False

        self.bus_url = bus_url
        self.bus = open_bus(bus_url)
        self.network = RigNetwork(self.bus)
        self.network.NOTIFIER_CYCLE = 0.1  # s, bus.recv timeout: prompt shutdown
        s = self.settings
        self.transducer = Transducer(self.network, s.transducer_node_id,
                                     find_eds(EDS_NAMES["transducer"], eds_dir), self.events)
        self.valve = ValveObe(self.network, s.valve_node_id,
                              find_eds(EDS_NAMES["valve"], eds_dir), self.events,
                              full_scale_v=self.full_scale_v)
        self.nodes = [self.transducer, self.valve]
        #: wall time (s) the last received frame was handled (heartbeat consumers, see node.py)
        self._rx_handled = 0.0
        self.network.counting.after = self._after_frame
        self.network.subscribe(0x000, self._on_nmt)
        self.network.subscribe(0x080, self._on_sync)
        for f in self.faults:
            if f.kind == "sdo-abort":
                self._arm_sdo_abort(f)
        self._timer = threading.Thread(target=self._timer_loop, name="ehactl-devices-timers",
                                       daemon=True)

    # ------------------------------------------------------------------ lifecycle
    def start(self, boot_delay_s: float = 0.0) -> None:
        """Connect the notifier, power the devices on (boot-up) and start the timers."""
        self.network.connect()
        if boot_delay_s > 0:
            time.sleep(boot_delay_s)
        self.transducer.boot()
        if any(f.kind == "no-boot" for f in self.faults):
            self.events("valve", "fault-injected", fault="no-boot")
        else:
            self.valve.boot()
        self._timer.start()

    def run_forever(self) -> int:
        """Serve until stop() or the bus connection is lost; return the exit code."""
        while not self.stop_event.wait(0.05):
            exc = self.network.notifier.exception if self.network.notifier else None
            if exc is not None and self.bus_lost is None:
                self._on_bus_lost(str(exc))
        return 1 if self.bus_lost else 0

    def stop(self) -> None:
        self.stop_event.set()

    def close(self) -> None:
        """Write the final summary event and release the bus."""
        self.stop_event.set()
        self.events("rig", "summary", **self.summary())
        try:
            self.network.disconnect()
        except Exception:  # the connection may already be gone; nothing to release then
            pass
        self.events.close()

    def summary(self) -> dict:
        v = self.valve
        return {
            "sync_count": self.sync_count, "t_sim": self.t_sim,
            "t_plant": self.plant.measure()["t"],
            "valve_state": v.state.name, "valve_control_word": v.cw,
            "valve_setpoint": v.setpoint() if v.powered else None,
            "valve_nmt": v.nmt_state, "transducer_nmt": self.transducer.nmt_state,
            "last_command_v": self.last_command_v,
            # what the valve would drive now (V): hold setpoint / failsafe after a fault
            "valve_command_v": v.command_volts() if v.powered else 0.0,
            "position_m": self.transducer.position_m,
            "bus_lost": self.bus_lost,
            "frames_sent": {f"0x{k:03X}": v for k, v in sorted(self.network.frames_sent.items())},
            "frames_received": {f"0x{k:03X}": v
                                for k, v in sorted(self.network.frames_received.items())},
            "counters": {"valve": dict(v.counters), "transducer": dict(self.transducer.counters)},
        }

    def _on_bus_lost(self, why: str) -> None:
        self.bus_lost = why
        # Local fail-safe of the valve electronics: without a bus there is no setpoint stream.
        if self.valve.state.name == "ACTIVE":
            self.valve.leave_active("bus connection lost")
        self.last_command_v = self.valve.command_volts() if self.valve.powered else 0.0
        self.events("rig", "bus-lost", why=why)
        self.stop_event.set()

    # ------------------------------------------------------------------ frames
    #: The receive side counts as idle (nothing queued) after this long without a frame (s).
    RX_IDLE_S = 0.002

    def _after_frame(self, bus_time: float) -> None:
        """Notifier thread, after each frame: heartbeat consumers checked at its bus time."""
        self._rx_handled = time.time()
        self.network.dispatching.busy = False
        if isinstance(self.bus, _HubBus):
            self.bus.in_flight = False
        for n in self.nodes:
            with n.lock:
                n.consumers_due(bus_time)

    def _on_nmt(self, can_id, data, timestamp) -> None:
        for n in self.nodes:
            n.on_nmt(bytes(data))

    def _on_sync(self, can_id, data, timestamp) -> None:
        if len(data) > 1:
            return  # SYNC has no data or a 1-byte counter (CiA 301 7.2.5)
        self.sync_count += 1
        if self.valve.powered:
            self.valve.sync_tick()
        self._inject_faults()
        for n in self.nodes:
            if n.powered and n.nmt_state in (PRE_OPERATIONAL, OPERATIONAL):
                n.apply_latched_rpdos()
        u = self.valve.command_volts() if self.valve.powered else 0.0
        self.last_command_v = u
        if not self.numerical_failure:
            try:
                self.plant.step(u, self.steps_per_sync)
            except Exception as e:  # ehactl.NumericalError: the simulated hardware broke
                self.numerical_failure = True
                self.events("rig", "plant-numerical-failure", why=str(e))
                self.valve.fault(0x6000, "plant numerical failure")
        self.t_sim = self.sync_count * self.settings.sync_period_s
        m = self.plant.measure()
        self.transducer.sample(m["t"], m["position"])
        spool = m["spool"]
        self.valve.actual_spool = spool if math.isfinite(spool) else u / self.full_scale_v
        if self._malformed_now():
            return
        for n in self.nodes:
            n.send_sync_tpdos()

    # ------------------------------------------------------------------ faults
    def _arm_sdo_abort(self, f: Fault) -> None:
        def hook(index: int, sub: int):
            if not f.done and index in (0x1600, 0x1A00):
                f.done = True
                self.events("valve", "fault-injected", fault="sdo-abort",
                            index=f"0x{index:04X}", sub=sub)
                return 0x06090030  # value range of parameter exceeded
            return None
        self.valve.add_abort_hook(hook)

    def _inject_faults(self) -> None:
        t = self.sync_count * self.settings.sync_period_s
        for f in self.faults:
            if f.done or t + 1e-12 < f.at_s or f.kind in ("sdo-abort", "no-boot", "malformed"):
                continue
            if f.kind == "heartbeat-loss":
                f.done = True
                self.events("valve", "fault-injected", fault="heartbeat-loss", at_s=f.at_s)
                self.network.silenced_nodes.add(self.valve.node_id)
            elif f.kind == "emcy":
                f.done = True
                self.events("valve", "fault-injected", fault="emcy", at_s=f.at_s)
                self.valve.fault(EMCY_DEVICE_HARDWARE, "injected fault (emcy)")
            elif f.kind == "leave-active" and self.valve.state.name == "ACTIVE":
                f.done = True
                self.events("valve", "fault-injected", fault="leave-active", at_s=f.at_s)
                self.valve.leave_active("injected fault (leave-active)")

    def _malformed_now(self) -> bool:
        """malformed@T: instead of its TPDO1 the transducer sends it with a wrong DLC (2 bytes
        instead of the mapped length) and a frame on an unknown COB-ID."""
        t = self.sync_count * self.settings.sync_period_s
        for f in self.faults:
            if f.kind == "malformed" and not f.done and t + 1e-12 >= f.at_s:
                td = self.transducer
                if td.nmt_state != OPERATIONAL:
                    return False
                f.done = True
                cfg = td.tpdos.get(0x1800)
                if cfg is None or not cfg.valid:
                    return False
                data = td.pack_tpdo(cfg)
                short = data[: max(0, min(2, len(data) - 1))]
                self.events("transducer", "fault-injected", fault="malformed",
                            wrong_dlc_cob_id=f"0x{cfg.cob_id:03X}", dlc=len(short),
                            expected_dlc=len(data),
                            unknown_cob_id=f"0x{MALFORMED_UNKNOWN_COB_ID:03X}")
                td.send(cfg.cob_id, short)
                td.send(MALFORMED_UNKNOWN_COB_ID, b"\xde\xad\xbe\xef")
                self.valve.send_sync_tpdos()
                return True
        return False

    # ------------------------------------------------------------------ timers
    def _timer_loop(self) -> None:
        """Heartbeats and event-driven TPDOs; 1 ms tick."""
        while not self.stop_event.is_set():
            now = time.monotonic()
            try:
                wall = time.time()
                # With nothing left to handle, the wall clock is the bus time of the next frame.
                idle = self.network.rx_idle() and wall - self._rx_handled > self.RX_IDLE_S
                for n in self.nodes:
                    if idle:
                        with n.lock:
                            n.consumers_due(wall)
                    n.heartbeat_due(now)
                    n.async_tpdos_due(now)
                self.valve.timer_tick(now)
            except (OSError, can.CanError) as e:
                if self.bus_lost is None:
                    self._on_bus_lost(f"send failed: {e}")
                return
            time.sleep(0.001)
