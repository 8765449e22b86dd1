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
    "bring_to_operation_enabled", "next_controlword", "next_state", "state_from_statusword", "state_from_statusword_or_none", "statusword_for",
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
STATUSWORD_HOMING_ERROR = 0x2000  # bit 13 in homing mode
CONTROLWORD_START_HOMING = 0x001F  # enable operation + bit 4 (operation mode specific: start homing)
HOMING_MODE = 6
CYCLIC_SYNCHRONOUS_POSITION_MODE = 8


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


def bring_to_operation_enabled(write_controlword: Callable[[int], None], read_statusword: Callable[[], int],
                               device: str, *, timeout_s: float = 2.0,
                               read_fault_code: Callable[[], int | None] | None = None) -> list[int]:
    """Walk a drive through the state machine to OPERATION_ENABLED; returns the controlwords sent.

    ``read_statusword`` must return the statusword as it is after the last written controlword. A drive
    found in FAULT is reset once (its error code, e.g. 0x603F, is read through ``read_fault_code`` for the
    message if the reset does not clear it). Raises :class:`DeviceFault` if the drive does not reach the
    state within ``timeout_s`` or falls back into FAULT after a reset.
    """
    deadline = time.monotonic() + timeout_s
    sent: list[int] = []
    previous = CONTROLWORD_DISABLE_VOLTAGE
    resets = 0
    while True:
        state = state_from_statusword(read_statusword())
        controlword = next_controlword(state, previous)
        if controlword is None:
            return sent
        if controlword == CONTROLWORD_FAULT_RESET:
            resets += 1
            if resets > 1:
                code = read_fault_code() if read_fault_code is not None else None
                raise DeviceFault(device, code, "the drive stays in FAULT after a fault reset")
        if time.monotonic() > deadline:
            code = read_fault_code() if read_fault_code is not None else None
            raise DeviceFault(device, code, f"the drive did not reach OPERATION ENABLED within {timeout_s:g} s "
                                            f"(stuck in {state.name})")
        write_controlword(controlword)
        sent.append(controlword)
        previous = controlword


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
