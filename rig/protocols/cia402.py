"""CiA 402 drive profile: the controlword/statusword state machine, shared by the host side of every
transport (which drives a drive to *Operation Enabled*) and by the simulated drives (which implement it).

The serial protocol (docs/serial_protocol.md) carries the same controlword and statusword, so one state
machine serves the CANopen drive, the raw-CAN responder and the serial device.

States and their statusword patterns (CiA 402 / IEC 61800-7-201, table "state coding")::

    state                    mask    value
    NOT_READY_TO_SWITCH_ON   0x004F  0x0000
    SWITCH_ON_DISABLED       0x004F  0x0040
    READY_TO_SWITCH_ON       0x006F  0x0021
    SWITCHED_ON              0x006F  0x0023
    OPERATION_ENABLED        0x006F  0x0027
    QUICK_STOP_ACTIVE        0x006F  0x0007
    FAULT_REACTION_ACTIVE    0x004F  0x000F
    FAULT                    0x004F  0x0008
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from rig.protocols.errors import DeviceFault, TransportError

__all__ = [
    "CONTROLWORD_DISABLE_VOLTAGE", "CONTROLWORD_ENABLE_OPERATION", "CONTROLWORD_FAULT_RESET",
    "CONTROLWORD_QUICK_STOP", "CONTROLWORD_SHUTDOWN", "CONTROLWORD_SWITCH_ON", "DriveScaling", "DriveState",
    "BringUpTiming", "StopReport", "bring_to_operation_enabled", "fault_code_or_none", "next_controlword",
    "quick_stop_then_disable", "next_state", "state_from_statusword", "state_from_statusword_or_none", "statusword_for",
]

CONTROLWORD_SHUTDOWN = 0x0006
CONTROLWORD_SWITCH_ON = 0x0007  # also "disable operation" from OPERATION_ENABLED
CONTROLWORD_ENABLE_OPERATION = 0x000F
CONTROLWORD_DISABLE_VOLTAGE = 0x0000
CONTROLWORD_QUICK_STOP = 0x0002
CONTROLWORD_FAULT_RESET = 0x0080  # acts on the rising edge of bit 7

STATUSWORD_WARNING = 0x0080
STATUSWORD_TARGET_REACHED = 0x0400
STATUSWORD_HOMING_ATTAINED = 0x1000  # bit 12 in homing mode
STATUSWORD_FOLLOWS_TARGET = 0x1000  # bit 12 in cyclic synchronous position mode: the drive follows 0x607A
STATUSWORD_HOMING_ERROR = 0x2000  # bit 13 in homing mode
CONTROLWORD_START_HOMING = 0x001F  # enable operation + bit 4 (operation mode specific: start homing)
HOMING_MODE = 6
INTERPOLATED_POSITION_MODE = 7  # with a FIFO of interpolation data records (0x60C1, 0x60C4)
CYCLIC_SYNCHRONOUS_POSITION_MODE = 8
CONTROLWORD_ENABLE_INTERPOLATION = 0x001F  # enable operation + bit 4 (in interpolated position: enable ip mode)
STATUSWORD_IP_MODE_ACTIVE = 0x1000  # bit 12 in interpolated position mode
TORQUE_ACTUAL_UNIT = "permille_of_rated_torque"
"""The unit of the torque actual value 0x6077 (INTEGER16): per mille of the motor rated torque 0x6076."""


class DriveState(Enum):
    """The states of the CiA 402 power state machine, valued by their statusword bits."""

    NOT_READY_TO_SWITCH_ON = (0x004F, 0x0000)
    SWITCH_ON_DISABLED = (0x004F, 0x0040)
    READY_TO_SWITCH_ON = (0x006F, 0x0021)
    SWITCHED_ON = (0x006F, 0x0023)
    OPERATION_ENABLED = (0x006F, 0x0027)
    QUICK_STOP_ACTIVE = (0x006F, 0x0007)
    FAULT_REACTION_ACTIVE = (0x004F, 0x000F)
    FAULT = (0x004F, 0x0008)


def _decode_state_bits(bits: int) -> DriveState | None:
    for state in DriveState:
        mask, value = state.value
        if bits & mask == value:
            return state
    return None


_STATE_BITS = 0x007F
"""Every state mask of CiA 402 table 30 lies within the statusword's bits 0-6."""
_STATE_BY_BITS = tuple(_decode_state_bits(bits) for bits in range(_STATE_BITS + 1))
"""The state for each value of bits 0-6: decoding runs once per sample, so it is a table lookup."""


def state_from_statusword(statusword: int) -> DriveState:
    """Decode the state from a statusword (0x6041); raises :class:`TransportError` on a pattern that is no
    state (a corrupted frame or a device that does not follow CiA 402)."""
    state = _STATE_BY_BITS[statusword & _STATE_BITS]
    if state is None:
        raise TransportError(f"statusword 0x{statusword:04X} encodes no CiA 402 state")
    return state


def state_from_statusword_or_none(statusword: int) -> DriveState | None:
    """Like :func:`state_from_statusword`, but None for a pattern that is no state."""
    return _STATE_BY_BITS[statusword & _STATE_BITS]


def statusword_for(state: DriveState, *, voltage: bool = True, remote: bool = True,
                   target_reached: bool = False) -> int:
    """The statusword a device reports in ``state`` (bit 4 voltage enabled, bit 9 remote, bit 10 target
    reached)."""
    word = state.value[1]
    if voltage and state not in (DriveState.NOT_READY_TO_SWITCH_ON, DriveState.SWITCH_ON_DISABLED):
        word |= 0x0010
    if remote:
        word |= 0x0200
    if target_reached:
        word |= STATUSWORD_TARGET_REACHED
    return word


def next_state(state: DriveState, controlword: int, previous_controlword: int) -> DriveState:
    """Device side: the state after receiving ``controlword`` (transitions 2-12, 15, 16 of CiA 402).

    A fault reset acts only on the rising edge of bit 7 (``previous_controlword`` has it clear).
    """
    if state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
        rising = controlword & 0x0080 and not previous_controlword & 0x0080
        return DriveState.SWITCH_ON_DISABLED if state is DriveState.FAULT and rising else state
    if controlword & 0x0080:
        return state  # fault reset outside FAULT: no effect
    disable_voltage = controlword & 0x0002 == 0
    quick_stop = controlword & 0x0006 == 0x0002
    shutdown = controlword & 0x0007 == 0x0006
    switch_on = controlword & 0x000F == 0x0007
    enable = controlword & 0x000F == 0x000F
    if state is DriveState.NOT_READY_TO_SWITCH_ON:
        return DriveState.SWITCH_ON_DISABLED
    if state is DriveState.SWITCH_ON_DISABLED:
        return DriveState.READY_TO_SWITCH_ON if shutdown else state
    if disable_voltage:
        return DriveState.SWITCH_ON_DISABLED  # transitions 7, 9, 10, 12
    if quick_stop:
        return DriveState.QUICK_STOP_ACTIVE if state is DriveState.OPERATION_ENABLED else DriveState.SWITCH_ON_DISABLED
    if state is DriveState.QUICK_STOP_ACTIVE:
        return state  # leaves only by disable voltage (transition 12)
    if shutdown:
        return DriveState.READY_TO_SWITCH_ON  # transitions 2, 6, 8
    if state is DriveState.READY_TO_SWITCH_ON:
        return DriveState.OPERATION_ENABLED if enable else DriveState.SWITCHED_ON if switch_on else state
    if state is DriveState.SWITCHED_ON:
        return DriveState.OPERATION_ENABLED if enable else state
    if state is DriveState.OPERATION_ENABLED:
        return DriveState.SWITCHED_ON if switch_on else state
    return state


def next_controlword(state: DriveState, previous_controlword: int) -> int | None:
    """Host side: the controlword that moves a drive in ``state`` one step towards OPERATION_ENABLED
    (None once there). From FAULT it first clears bit 7, so that the reset is a rising edge."""
    if state is DriveState.OPERATION_ENABLED:
        return None
    if state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
        return CONTROLWORD_DISABLE_VOLTAGE if previous_controlword & 0x0080 else CONTROLWORD_FAULT_RESET
    if state is DriveState.QUICK_STOP_ACTIVE:
        return CONTROLWORD_DISABLE_VOLTAGE
    if state in (DriveState.SWITCH_ON_DISABLED, DriveState.NOT_READY_TO_SWITCH_ON):
        return CONTROLWORD_SHUTDOWN
    if state is DriveState.READY_TO_SWITCH_ON:
        return CONTROLWORD_SWITCH_ON
    return CONTROLWORD_ENABLE_OPERATION  # SWITCHED_ON


@dataclass(frozen=True)
class BringUpTiming:
    """Deadlines and pacing of the host side of the state machine (every value in seconds).

    Attributes
    ----------
    enable_timeout_s
        The whole walk to OPERATION ENABLED (transitions 2, 3, 4 of CiA 402) may take this long.
    fault_reset_timeout_s
        After the rising edge of controlword bit 7 (transition 15) the drive may stay in FAULT this long
        (drives take from microseconds to a few hundred milliseconds to clear a fault).
    quick_stop_timeout_s
        How long the stop waits for a quick stop to bring the motor to rest (QUICK STOP ACTIVE with
        statusword bit 10, or SWITCH ON DISABLED for 0x605A options 1-3) before it disables the voltage anyway.
    poll_interval_s
        Pause between two statusword reads while waiting for a transition: a controlword is written once
        per transition, and the statusword is polled at this pace, not in a busy loop.
    """

    enable_timeout_s: float = 5.0
    fault_reset_timeout_s: float = 1.0
    quick_stop_timeout_s: float = 0.5
    poll_interval_s: float = 0.002

    def __post_init__(self) -> None:
        for name in ("enable_timeout_s", "fault_reset_timeout_s", "quick_stop_timeout_s", "poll_interval_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: expected a number of seconds >= 0, got {value!r}")


_FAULT_STATES = (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)


def fault_code_or_none(read_fault_code: Callable[[], int | None] | None) -> int | None:
    """The drive's error code (0x603F) for a message; None when there is no way to read it, the read
    fails, or the drive reports 0 (CiA 402: 0x0000 is "no error", not a code to explain)."""
    if read_fault_code is None:
        return None
    try:
        code = read_fault_code()
    except Exception:  # noqa: BLE001 - the code only decorates a message about a fault already found
        return None
    return int(code) if code else None


def _wait_for_state(read_statusword: Callable[[], int], done: Callable[[DriveState, int], bool], deadline: float,
                    timing: BringUpTiming, clock: Callable[[], float], sleep: Callable[[float], None]) -> DriveState:
    """Poll the statusword at ``timing.poll_interval_s`` until ``done(state, statusword)`` or ``deadline``;
    return the last state read."""
    while True:
        word = read_statusword()
        state = state_from_statusword(word)
        if done(state, word) or clock() >= deadline:
            return state
        sleep(timing.poll_interval_s)


def bring_to_operation_enabled(write_controlword: Callable[[int], None], read_statusword: Callable[[], int],
                               device: str, *, timing: BringUpTiming = BringUpTiming(),
                               read_fault_code: Callable[[], int | None] | None = None,
                               clock: Callable[[], float] = time.monotonic,
                               sleep: Callable[[float], None] = time.sleep) -> list[int]:
    """Walk a drive through the state machine to OPERATION_ENABLED; returns the controlwords sent.

    Each controlword of :func:`next_controlword` is written once; the statusword is then polled
    (paced by ``timing.poll_interval_s``) until the state changes. A drive found in FAULT gets one fault
    reset, on a rising edge of bit 7 (0x0000 first, then 0x0080, transition 15: the drive may still hold
    0x0080 from an earlier host), and may take ``timing.fault_reset_timeout_s`` to leave FAULT. The error code
    (0x603F through ``read_fault_code``) is read when the fault is first seen, so every message names it.

    Raises
    ------
    DeviceFault
        The drive stays in FAULT after the reset, or does not reach OPERATION ENABLED within
        ``timing.enable_timeout_s`` (the message names the state it is stuck in).
    """
    deadline = clock() + timing.enable_timeout_s
    sent: list[int] = []
    previous = CONTROLWORD_DISABLE_VOLTAGE
    fault_code: int | None = None
    reset_done = False

    def write(controlword: int) -> None:
        nonlocal previous
        write_controlword(controlword)
        sent.append(controlword)
        previous = controlword

    state = state_from_statusword(read_statusword())
    while state is not DriveState.OPERATION_ENABLED:
        if state in _FAULT_STATES:
            if fault_code is None:
                fault_code = fault_code_or_none(read_fault_code)
            if reset_done:
                raise DeviceFault(device, fault_code, (
                    f"the drive stays in FAULT {timing.fault_reset_timeout_s:g} s after a fault reset "
                    "(clear the cause named by the code, then run again)"))
            reset_until = clock() + timing.fault_reset_timeout_s
            if state is DriveState.FAULT_REACTION_ACTIVE:  # the reset acts only in FAULT
                state = _wait_for_state(read_statusword, lambda s, _: s is not DriveState.FAULT_REACTION_ACTIVE,
                                        reset_until, timing, clock, sleep)
            # bit 7 clear first, always: the drive may still hold 0x0080 from an earlier host (transition 15
            # acts on the rising edge), and 0x0000 leaves FAULT as it is
            write(CONTROLWORD_DISABLE_VOLTAGE)
            write(CONTROLWORD_FAULT_RESET)
            reset_done = True
            state = _wait_for_state(read_statusword, lambda s, _: s not in _FAULT_STATES, reset_until, timing,
                                    clock, sleep)
            deadline = max(deadline, clock() + timing.enable_timeout_s)  # the reset's wait is its own budget
            continue
        if clock() >= deadline:
            raise DeviceFault(device, fault_code_or_none(read_fault_code), (
                f"the drive did not reach OPERATION ENABLED within {timing.enable_timeout_s:g} s (stuck in "
                f"{state.name}{_STUCK_HINTS.get(state, '')})"))
        controlword = next_controlword(state, previous)
        assert controlword is not None  # only None in OPERATION_ENABLED
        write(controlword)
        before = state
        state = _wait_for_state(read_statusword, lambda s, _, before=before: s is not before, deadline, timing,
                                clock, sleep)
    return sent


_STUCK_HINTS = {
    DriveState.SWITCH_ON_DISABLED: ": is the enable input or safe torque off active?",
    DriveState.READY_TO_SWITCH_ON: ": is the main voltage on?",
    DriveState.SWITCHED_ON: ": does the drive wait for SYNC, or refuse the mode of operation?",
}


@dataclass(frozen=True)
class StopReport:
    """What the controlled stop did (:func:`quick_stop_then_disable`, and the link's escalation where that did
    not disable the drive), for the message of whatever ended the run.

    Attributes
    ----------
    steps
        One phrase per step, in order ("quick stop sent", "disable failed: ...", "NMT stop sent").
    final_state
        The drive state read after the last step (None if it could not be read).
    last_seen
        The last drive state read during the stop (equal to ``final_state`` when that was read; what the
        drive last said when it then fell silent).
    escalated
        The quick stop and disable did not leave the drive seen disabled, and the link went further (CANopen:
        NMT stop, then NMT reset node, CiA 301 7.2.8.2.1).
    """

    steps: tuple[str, ...]
    final_state: DriveState | None
    last_seen: DriveState | None = None
    escalated: bool = False

    @property
    def disabled(self) -> bool:
        """True when the drive was read back with its power stage off (not OPERATION ENABLED or QUICK STOP)."""
        return self.final_state is not None and self.final_state not in (DriveState.OPERATION_ENABLED,
                                                                          DriveState.QUICK_STOP_ACTIVE)

    @property
    def confirmed(self) -> bool:
        """The stop did what it commands: the drive was seen disabled after the quick stop and the disable,
        without escalation. Only then may a run end with exit status 0."""
        return self.disabled and not self.escalated

    def __str__(self) -> str:
        if self.final_state is not None:
            end = f"ends {_state_text(self.final_state)}"
        elif self.last_seen is not None:
            end = f"state unknown (the drive stopped answering; last seen {_state_text(self.last_seen)})"
        else:
            end = "state unknown (the drive did not answer)"
        return f"{', then '.join(self.steps)}; {end}"


def _state_text(state: DriveState) -> str:
    return state.name.replace("_", " ")


def quick_stop_then_disable(write_controlword: Callable[[int], None], read_statusword: Callable[[], int], *,
                            timing: BringUpTiming = BringUpTiming(), clock: Callable[[], float] = time.monotonic,
                            sleep: Callable[[float], None] = time.sleep) -> StopReport:
    """The controlled stop: quick stop (controlword 0x0002, transition 11), wait until the motor is at rest
    (QUICK STOP ACTIVE with statusword bit 10, or the drive went on to SWITCH ON DISABLED by its 0x605A
    option) at most ``timing.quick_stop_timeout_s``, then disable voltage (0x0000, transition 12/9/7), then
    read the state back.

    Every step is attempted even when an earlier one failed (a lost answer must not leave the power stage
    on), and nothing raises: a step's failure is reported in the returned :class:`StopReport`, whose
    ``last_seen`` keeps the last state the drive reported.
    """
    steps: list[str] = []
    seen: list[DriveState] = []

    def read_and_remember() -> int:
        word = read_statusword()
        seen.append(state_from_statusword(word))
        return word

    try:
        write_controlword(CONTROLWORD_QUICK_STOP)
        steps.append("quick stop sent")
    except Exception as err:  # noqa: BLE001 - report it and go on to disable
        steps.append(f"quick stop failed ({err})")
    try:
        _wait_for_state(read_and_remember, _at_rest_after_quick_stop, clock() + timing.quick_stop_timeout_s,
                        timing, clock, sleep)
    except Exception:  # noqa: BLE001 - no answer: disable anyway
        pass
    try:
        write_controlword(CONTROLWORD_DISABLE_VOLTAGE)
        steps.append("disable sent")
    except Exception as err:  # noqa: BLE001
        steps.append(f"disable failed ({err})")
    try:
        final: DriveState | None = state_from_statusword(read_and_remember())
    except Exception:  # noqa: BLE001
        final = None
    return StopReport(tuple(steps), final, seen[-1] if seen else None)


def _at_rest_after_quick_stop(state: DriveState, statusword: int) -> bool:
    """Quick stop done: halted in QUICK STOP ACTIVE (bit 10 "target reached" means at rest there), or the
    drive left it on its own (0x605A options 1-3 end in SWITCH ON DISABLED; a fault ends the same way)."""
    if state is DriveState.QUICK_STOP_ACTIVE:
        return bool(statusword & STATUSWORD_TARGET_REACHED)
    return state is not DriveState.OPERATION_ENABLED


@dataclass(frozen=True)
class DriveScaling:
    """Drive position units: ``counts_per_revolution`` increments per motor revolution (the drive's
    position factor, CiA 402 0x6091/0x608F). Conversion of drive targets happens here and only here."""

    counts_per_revolution: int = 1 << 17

    def counts_from_rad(self, position_rad: float) -> int:
        return int(round(position_rad * self.counts_per_revolution / (2.0 * math.pi)))

    def rad_from_counts(self, counts: int) -> float:
        return counts * (2.0 * math.pi) / self.counts_per_revolution

    def quantize_rad(self, position_rad: float) -> float:
        """The target the drive actually receives for ``position_rad``."""
        return self.rad_from_counts(self.counts_from_rad(position_rad))
