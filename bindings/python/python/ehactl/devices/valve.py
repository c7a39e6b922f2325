"""Simulated CiA 408 proportional valve with on-board electronics (like the Rexroth 4WRSE of
seed 003), simplified device state machine of the ehactl CANopen ICD:

NOT_READY → INIT → DISABLED (automatic after boot-up) → HOLD (cw D=1,H=1) → ACTIVE (D=1,H=1,A=1);
ACTIVE → HOLD (A=0 or H=0); HOLD → DISABLED (H=0); any → DISABLED (D=0); FAULT on an internal
fault, left to DISABLED on a rising edge of R. Status word bits 0..2 mirror D,H,A of the state,
bit 3 = fault. The spool setpoint 0x6300:01 (±16384 = ±100 %) acts only in ACTIVE; in every other
state the spool is driven to 0 (closed centre)."""

from __future__ import annotations

import enum

from canopen.sdo import SdoAbortedError

from .node import ABORT_VALUE_RANGE, OPERATIONAL, SimNode

CW_D, CW_H, CW_A, CW_R = 0x1, 0x2, 0x4, 0x8
SPOOL_FULL = 16384  # ±16384 = ±100 % spool (CiA 408 percent scaling)
EMCY_DEVICE_HARDWARE = 0x5000


class ValveState(enum.Enum):
    """CiA 408 device states (simplified, see the module doc)."""

    NOT_READY = "NOT_READY"
    INIT = "INIT"
    DISABLED = "DISABLED"
    HOLD = "HOLD"
    ACTIVE = "ACTIVE"
    FAULT = "FAULT"

    @property
    def bits(self) -> int:
        """Status word 0x6041: bits 0..2 mirror D,H,A of the state, bit 3 = fault."""
        return STATUS_BITS[self]


STATUS_BITS = {ValveState.NOT_READY: 0b0000, ValveState.INIT: 0b0000,
               ValveState.DISABLED: 0b0001, ValveState.HOLD: 0b0011,
               ValveState.ACTIVE: 0b0111, ValveState.FAULT: 0b1000}


class ValveObe(SimNode):
    """Valve OBE node; the rig asks it for the valve command each SYNC."""

    kind = "valve"

    def __init__(self, *args, full_scale_v: float, **kwargs):
        super().__init__(*args, **kwargs)
        self.full_scale_v = full_scale_v  # valve command (V) at 100 % spool
        self.state = ValveState.NOT_READY
        self.cw = 0
        self.actual_spool = 0.0  # measured spool position, fraction of travel

    # ----------------------------------------------------------------- state machine
    def _set_state(self, new: ValveState, why: str) -> None:
        if new is not self.state:
            old, self.state = self.state, new
            self.emit(self.kind, "state", node_id=self.node_id, state=new.name, old=old.name,
                      why=why)

    def on_reset(self) -> None:
        self.cw = 0
        self._set_state(ValveState.NOT_READY, "power-on")
        self._set_state(ValveState.INIT, "init")

    def boot(self) -> None:
        super().boot()
        self._set_state(ValveState.DISABLED, "boot-up sent")

    def _control_word(self, cw: int) -> None:
        prev, self.cw = self.cw, cw
        if self.state is ValveState.FAULT:
            if cw & CW_R and not prev & CW_R:
                self.emcy(0x0000, 0)  # error reset (CiA 301 7.2.7.1)
                self._set_state(ValveState.DISABLED, "fault reset (rising edge of R)")
            # No re-activation by the same write: after a fault the master must command
            # HOLD / ACTIVE again with a new control word.
            return
        self._evaluate(cw)

    def _evaluate(self, cw: int) -> None:
        d, h, a = bool(cw & CW_D), bool(cw & CW_H), bool(cw & CW_A)
        if self.state in (ValveState.NOT_READY, ValveState.INIT, ValveState.FAULT):
            return
        if not d:
            self._set_state(ValveState.DISABLED, "control word D=0")
            return
        if self.state is ValveState.DISABLED and h:
            self._set_state(ValveState.HOLD, "control word D=1,H=1")
        if self.state is ValveState.HOLD:
            if h and a:
                self._set_state(ValveState.ACTIVE, "control word D=1,H=1,A=1")
            elif not h:
                self._set_state(ValveState.DISABLED, "control word H=0")
        elif self.state is ValveState.ACTIVE and not (h and a):
            self._set_state(ValveState.HOLD, "control word A=0 or H=0")
            if not h:
                self._set_state(ValveState.DISABLED, "control word H=0")

    def status_word(self) -> int:
        return self.state.bits

    def fault(self, code: int, why: str) -> None:
        """Internal fault: EMCY, FAULT state, spool to 0."""
        self._set_state(ValveState.FAULT, why)
        self.emcy(code, 0x01)

    def leave_active(self, why: str) -> None:
        if self.state is ValveState.ACTIVE:
            self._set_state(ValveState.HOLD, why)

    def on_nmt_change(self, old: int, new: int) -> None:
        # Without OPERATIONAL there is no setpoint stream: an ACTIVE valve holds.
        if old == OPERATIONAL and self.state is ValveState.ACTIVE:
            self._set_state(ValveState.HOLD, "left NMT OPERATIONAL")

    # ----------------------------------------------------------------- objects
    def live_value(self, index: int, sub: int):
        if index == 0x6041:
            return self.status_word()
        if index == 0x6040:
            return self.cw
        if index == 0x6301 and sub == 1:
            v = round(self.actual_spool * SPOOL_FULL)
            return max(-32768, min(32767, v))
        return super().live_value(index, sub)

    def on_app_write(self, index: int, sub: int, value) -> None:
        if index == 0x6040:
            self._control_word(value)
        elif index == 0x6042 and value != 1:
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # only "setpoint via bus" is simulated

    # ----------------------------------------------------------------- process
    def setpoint(self) -> int:
        return self.value(0x6300, 1)

    def command_volts(self) -> float:
        """Valve command (V) for the plant: setpoint · full scale in ACTIVE, else 0."""
        if self.state is not ValveState.ACTIVE or self.value(0x6042) != 1:
            return 0.0
        s = max(-SPOOL_FULL, min(SPOOL_FULL, self.setpoint()))
        return s / SPOOL_FULL * self.full_scale_v
