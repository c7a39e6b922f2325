"""Simulated CiA 408 proportional valve with on-board electronics (like the Rexroth 4WRSE of
seed 003) with the device state machine (DSM) of CiA 408 as published by Moog, "Moog ACV with
CANopen bus interface", B99224-DV018-D-211 Rev. A (2018), §5.2 "Device state machine (DSM)"
(fig. 19 and the transition tables of §5.2.2):

Status word 0x6041 bits 0..3 = D, H, M, R (R = Ready), RMHD codes
    NOT_READY 0000, INIT 1000, DISABLED 1001, HOLD 1011, ACTIVE 1111,
    FAULT_REACTION 0111, FAULT_HOLD 0011, FAULT_DISABLED 0001, FAULT_INIT 0000.
Control word 0x6040 bits 0..3 = D, H, M, R (R = reset fault). Transitions:
    TR1  NOT_READY → INIT (device initialised, here: boot-up sent)
    TR2  INIT → DISABLED          control word xxx1
    TR3  DISABLED → HOLD          control word x011 or x111 (H = 1, D = 1)
    TR4  HOLD → ACTIVE            control word x111
    TR5  ACTIVE → HOLD            M = 0
    TR6  HOLD → DISABLED          M = 0, H = 0
    TR7  DISABLED → INIT          M = 0, H = 0, D = 0
    TR8  any (from INIT on) → FAULT_REACTION on a fault; EMCY sent on entry
    TR9/12/13 FAULT_REACTION → FAULT_HOLD (fault reaction of this simulation), redirected to
         FAULT_DISABLED when the fault came in DISABLED / FAULT_DISABLED and to FAULT_INIT when
         it came in INIT / FAULT_INIT (the DSM is never raised by a fault)
    TR10 FAULT_DISABLED → DISABLED  rising edge of R with MHD = 001 held (0001 → 1001)
    TR11 FAULT_HOLD → HOLD          rising edge of R with MHD = 011 held (0011 → 1011)
    TR14 FAULT_INIT → INIT          rising edge of R with MHD = 000 held (0000 → 1000)
    TR15 FAULT_HOLD → FAULT_DISABLED, TR16 FAULT_DISABLED → FAULT_INIT: the control word lowers
         the state in a fault state as in TR6/TR7 (it never raises it: "the RMHD bits of the
         control word do not increase the state of the DSM").
"Every transition between the actual state and the requested state will be processed": one
control word may pass several transitions (e.g. ACTIVE with 0000 → INIT).
In HOLD, FAULT_HOLD and FAULT_REACTION the spool is controlled to the hold setpoint 0x6314:01
(control mode 0x6043 = 2, spool position closed loop); in ACTIVE to the bus setpoint 0x6300:01
(device mode 0x6042 = 1); in every other state it is at its failsafe position, closed centre
in this plant. The master's heartbeat is consumed through 0x1016 (node.py): its loss is a
fault (EMCY 0x8130) and so leads to FAULT_HOLD; so is a missed RPDO deadline in ACTIVE (RPDO1
event timer 0x1400:05, CiA 301 v4.2: the setpoint stream stopped; EMCY 0x8250), which catches a
hung master whose heartbeat still runs."""

from __future__ import annotations

import enum
import time

from canopen.sdo.exceptions import SdoAbortedError

from .node import ABORT_VALUE_RANGE, EMCY_RPDO_TIMEOUT, OPERATIONAL, SimNode

CW_D, CW_H, CW_M, CW_R = 0x1, 0x2, 0x4, 0x8
CW_A = CW_M  # older name of the M bit ("device mode active enable")
SPOOL_FULL = 16384  # ±16384 = ±100 % spool (CiA 408 percent scaling)
EMCY_DEVICE_HARDWARE = 0x5000
EMCY_HEARTBEAT = 0x8130  # CiA 301 table 21: life guard error or heartbeat error
#: The fault reaction ends at the next SYNC, or after this long without SYNC (s).
FAULT_REACTION_MAX_S = 0.005


class ValveState(enum.Enum):
    """CiA 408 device states (fig. 19 of Moog B99224-DV018)."""

    NOT_READY = "NOT_READY"
    INIT = "INIT"
    DISABLED = "DISABLED"
    HOLD = "HOLD"
    ACTIVE = "ACTIVE"
    FAULT_REACTION = "FAULT_REACTION"
    FAULT_HOLD = "FAULT_HOLD"
    FAULT_DISABLED = "FAULT_DISABLED"
    FAULT_INIT = "FAULT_INIT"

    @property
    def bits(self) -> int:
        """Status word 0x6041 bits 0..3 (RMHD)."""
        return STATUS_BITS[self]

    @property
    def is_fault(self) -> bool:
        return self in FAULT_STATES


STATUS_BITS = {ValveState.NOT_READY: 0b0000, ValveState.INIT: 0b1000,
               ValveState.DISABLED: 0b1001, ValveState.HOLD: 0b1011,
               ValveState.ACTIVE: 0b1111, ValveState.FAULT_REACTION: 0b0111,
               ValveState.FAULT_HOLD: 0b0011, ValveState.FAULT_DISABLED: 0b0001,
               ValveState.FAULT_INIT: 0b0000}
FAULT_STATES = (ValveState.FAULT_REACTION, ValveState.FAULT_HOLD, ValveState.FAULT_DISABLED,
                ValveState.FAULT_INIT)
#: Fault state → (MHD bits held during the reset edge, state after the reset): TR10, TR11, TR14.
RESETS = {ValveState.FAULT_DISABLED: (0b001, ValveState.DISABLED),
          ValveState.FAULT_HOLD: (0b011, ValveState.HOLD),
          ValveState.FAULT_INIT: (0b000, ValveState.INIT)}
#: Fault reaction target by the state the fault came in (TR9/TR12/TR13, never raising the DSM).
REACTION_TARGET = {ValveState.INIT: ValveState.FAULT_INIT,
                   ValveState.FAULT_INIT: ValveState.FAULT_INIT,
                   ValveState.DISABLED: ValveState.FAULT_DISABLED,
                   ValveState.FAULT_DISABLED: ValveState.FAULT_DISABLED}


class ValveDsm:
    """The device state machine alone (no bus): control words, faults, the end of the fault
    reaction. ``on_change(old, new, why)`` is called for every transition."""

    def __init__(self, on_change=None):
        self.state = ValveState.NOT_READY
        self.cw = 0
        self._reaction_to = ValveState.FAULT_HOLD
        self.on_change = on_change or (lambda old, new, why: None)

    def _go(self, new: ValveState, why: str) -> None:
        if new is not self.state:
            old, self.state = self.state, new
            self.on_change(old, new, why)

    def power_on(self) -> None:
        """TR0 then TR1: NOT_READY → INIT (control word cleared)."""
        self.cw = 0
        self._go(ValveState.NOT_READY, "power-on (TR0)")
        self._go(ValveState.INIT, "device initialised (TR1)")
        self._follow()

    def control_word(self, cw: int) -> None:
        prev, self.cw = self.cw, cw & 0xFFFF
        st = self.state
        if st in RESETS:
            held, to = RESETS[st]
            if cw & CW_R and not prev & CW_R and (cw & 0b111) == held:
                tr = {ValveState.FAULT_DISABLED: "TR10", ValveState.FAULT_HOLD: "TR11",
                      ValveState.FAULT_INIT: "TR14"}[st]
                self._go(to, f"fault reset, rising edge of R ({tr})")
                self._follow()
                return
        self._follow()

    def _follow(self) -> None:
        """Process every transition the control word requests from the current state."""
        d, h, m = bool(self.cw & CW_D), bool(self.cw & CW_H), bool(self.cw & CW_M)
        for _ in range(4):
            st = self.state
            if st is ValveState.INIT and d:
                self._go(ValveState.DISABLED, "control word D=1 (TR2)")
            elif st is ValveState.DISABLED and d and h:
                self._go(ValveState.HOLD, "control word D=1,H=1 (TR3)")
            elif st is ValveState.DISABLED and not (d or h or m):
                self._go(ValveState.INIT, "control word MHD=000 (TR7)")
            elif st is ValveState.HOLD and d and h and m:
                self._go(ValveState.ACTIVE, "control word MHD=111 (TR4)")
            elif st is ValveState.HOLD and not (h or m):
                self._go(ValveState.DISABLED, "control word M=0,H=0 (TR6)")
            elif st is ValveState.ACTIVE and not m:
                self._go(ValveState.HOLD, "control word M=0 (TR5)")
            elif st is ValveState.FAULT_HOLD and not (h or m):
                self._go(ValveState.FAULT_DISABLED, "control word M=0,H=0 (TR15)")
            elif st is ValveState.FAULT_DISABLED and not (d or h or m):
                self._go(ValveState.FAULT_INIT, "control word MHD=000 (TR16)")
            else:
                return

    def fault(self, why: str) -> bool:
        """TR8: a fault enters FAULT_REACTION (True: entered now, send the EMCY)."""
        if self.state in (ValveState.NOT_READY, ValveState.FAULT_REACTION):
            return False
        self._reaction_to = REACTION_TARGET.get(self.state, ValveState.FAULT_HOLD)
        self._go(ValveState.FAULT_REACTION, f"{why} (TR8)")
        return True

    def end_reaction(self) -> None:
        """TR9/TR12/TR13: the fault reaction is done."""
        if self.state is ValveState.FAULT_REACTION:
            self._go(self._reaction_to, "fault reaction done (TR9/TR12/TR13)")
            self._follow()

    def leave_active(self, why: str) -> None:
        """Vendor behaviour outside the control word (local fail-safe): ACTIVE → HOLD."""
        if self.state is ValveState.ACTIVE:
            self._go(ValveState.HOLD, why)


class ValveObe(SimNode):
    """Valve OBE node; the rig asks it for the valve command each SYNC."""

    kind = "valve"

    def __init__(self, *args, full_scale_v: float, **kwargs):
        super().__init__(*args, **kwargs)
        self.full_scale_v = full_scale_v  # valve command (V) at 100 % spool
        self.dsm = ValveDsm(self._on_change)
        self.actual_spool = 0.0  # measured spool position, fraction of travel
        self._reaction_since: float | None = None  # monotonic time FAULT_REACTION was entered

    @property
    def state(self) -> ValveState:
        return self.dsm.state

    @property
    def cw(self) -> int:
        return self.dsm.cw

    # ----------------------------------------------------------------- state machine
    def _on_change(self, old: ValveState, new: ValveState, why: str) -> None:
        self.emit(self.kind, "state", node_id=self.node_id, state=new.name, old=old.name,
                  why=why)
        if new is ValveState.FAULT_REACTION:
            self._reaction_since = time.monotonic()
        if old.is_fault and not new.is_fault:
            self.emcy(0x0000, 0)  # error reset (CiA 301 7.2.7.1)

    def on_reset(self) -> None:
        self.dsm.power_on()

    def fault(self, code: int, why: str, register_bits: int = 0x01) -> None:
        """Internal fault: FAULT_REACTION (TR8) with its EMCY on entry."""
        with self.lock:
            if self.dsm.fault(why):
                self.emcy(code, register_bits)

    def sync_tick(self) -> None:
        """SYNC: a fault reaction entered before this SYNC is done (TR9/TR12/TR13)."""
        with self.lock:
            self.dsm.end_reaction()

    def timer_tick(self, now: float) -> None:
        """Timer thread: without SYNC the fault reaction ends after FAULT_REACTION_MAX_S."""
        with self.lock:
            if (self.dsm.state is ValveState.FAULT_REACTION and self._reaction_since is not None
                    and now - self._reaction_since >= FAULT_REACTION_MAX_S):
                self.dsm.end_reaction()

    def leave_active(self, why: str) -> None:
        self.dsm.leave_active(why)

    def on_heartbeat_lost(self, producer: int) -> None:
        # CiA 301 heartbeat event → device fault → FAULT_REACTION → FAULT_HOLD (the hold
        # setpoint 0x6314 acts; a real valve does what its fault reaction type says, DEPLOY.md).
        self.fault(EMCY_HEARTBEAT, f"heartbeat of node {producer} lost (0x1016)", 0x11)

    def on_rpdo_timeout(self, comm: int) -> None:
        # The setpoint stream stopped (ehactl dead or its cycle hung) while the heartbeat may
        # still run: a fault in ACTIVE (FAULT_REACTION → FAULT_HOLD, hold setpoint 0x6314),
        # as the heartbeat loss; in other states the setpoint is not used: EMCY only.
        if self.state is ValveState.ACTIVE:
            self.fault(EMCY_RPDO_TIMEOUT, f"RPDO 0x{comm:04X} deadline missed (0x{comm:04X}:05)",
                       0x11)
        else:
            super().on_rpdo_timeout(comm)

    def on_nmt_change(self, old: int, new: int) -> None:
        # Without OPERATIONAL there is no setpoint stream: an ACTIVE valve holds.
        if old == OPERATIONAL and self.state is ValveState.ACTIVE:
            self.dsm.leave_active("left NMT OPERATIONAL")

    def status_word(self) -> int:
        return self.state.bits

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
            self.dsm.control_word(value)
        elif index == 0x6042 and value != 1:
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # only "setpoint via bus" is simulated
        elif index == 0x6043 and value != 2:
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # only spool position closed loop

    # ----------------------------------------------------------------- process
    def setpoint(self) -> int:
        return self.value(0x6300, 1)

    def hold_setpoint(self) -> int:
        return self.value(0x6314, 1)

    def command_volts(self) -> float:
        """Valve command (V) for the plant: bus setpoint in ACTIVE, hold setpoint 0x6314 in
        HOLD / FAULT_HOLD / FAULT_REACTION, else 0 (failsafe, closed centre)."""
        st = self.state
        if st is ValveState.ACTIVE and self.value(0x6042) == 1:
            s = self.setpoint()
        elif st in (ValveState.HOLD, ValveState.FAULT_HOLD, ValveState.FAULT_REACTION):
            s = self.hold_setpoint()
        else:
            return 0.0
        s = max(-SPOOL_FULL, min(SPOOL_FULL, s))
        return s / SPOOL_FULL * self.full_scale_v
