"""The CiA 402 state machine, as scripted controlword/statusword exchanges."""

from __future__ import annotations

import pytest

from rig.protocols import cia402
from rig.protocols.cia402 import DriveState, next_state, state_from_statusword, statusword_for
from rig.protocols.errors import DeviceFault, TransportError


class ScriptedDrive:
    """A drive that follows the state machine and records the controlwords it receives."""

    def __init__(self, state: DriveState, refaults: bool = False) -> None:
        self.state, self.previous, self.received, self.refaults = state, 0, [], refaults

    def write(self, controlword: int) -> None:
        self.received.append(controlword)
        self.state = next_state(self.state, controlword, self.previous)
        if self.refaults and self.state is DriveState.SWITCH_ON_DISABLED:
            self.state = DriveState.FAULT
        self.previous = controlword

    def read(self) -> int:
        return statusword_for(self.state)


@pytest.mark.parametrize(("start", "controlwords"), [
    (DriveState.SWITCH_ON_DISABLED, [0x06, 0x07, 0x0F]),
    (DriveState.SWITCHED_ON, [0x0F]),
    (DriveState.OPERATION_ENABLED, []),
    (DriveState.QUICK_STOP_ACTIVE, [0x00, 0x06, 0x07, 0x0F]),
    # fault reset acts on a rising edge of bit 7: 0x80 after a word with bit 7 clear, sent first
    (DriveState.FAULT, [0x00, 0x80, 0x06, 0x07, 0x0F]),
])
def test_bring_up_sends_the_controlwords_of_the_profile(start, controlwords):
    drive = ScriptedDrive(start)
    sent = cia402.bring_to_operation_enabled(drive.write, drive.read, "drive")
    assert sent == drive.received == controlwords
    assert drive.state is DriveState.OPERATION_ENABLED


def test_fault_reset_needs_a_rising_edge():
    assert next_state(DriveState.FAULT, 0x80, 0x80) is DriveState.FAULT
    assert next_state(DriveState.FAULT, 0x80, 0x00) is DriveState.SWITCH_ON_DISABLED


def test_a_fault_reset_reaches_a_drive_that_still_holds_0x0080_from_an_earlier_host():
    """The host does not know the last controlword the drive received (an earlier session may have ended on a
    fault reset): 0x0000 goes first, so that 0x0080 is a rising edge of bit 7 whatever came before."""
    drive = ScriptedDrive(DriveState.FAULT)
    drive.previous = cia402.CONTROLWORD_FAULT_RESET
    sent = cia402.bring_to_operation_enabled(drive.write, drive.read, "drive")
    assert sent[:2] == [0x0000, 0x0080] and drive.state is DriveState.OPERATION_ENABLED


def test_quick_stop_then_disable_voltage_is_the_controlled_stop():
    state = next_state(DriveState.OPERATION_ENABLED, cia402.CONTROLWORD_QUICK_STOP, 0x0F)
    assert state is DriveState.QUICK_STOP_ACTIVE
    assert next_state(state, cia402.CONTROLWORD_DISABLE_VOLTAGE, 0x02) is DriveState.SWITCH_ON_DISABLED


def test_a_drive_that_faults_again_after_reset_is_reported_with_its_code():
    drive = ScriptedDrive(DriveState.FAULT, refaults=True)
    with pytest.raises(DeviceFault, match=r"drive \(code 0x2310: continuous over-current on the device output side\): the drive stays in FAULT"):
        cia402.bring_to_operation_enabled(drive.write, drive.read, "drive", read_fault_code=lambda: 0x2310)


def test_statuswords_decode_to_their_states():
    for state in DriveState:
        assert state_from_statusword(statusword_for(state)) is state
    assert state_from_statusword(0x0637) is DriveState.OPERATION_ENABLED  # a typical drive's word
    with pytest.raises(TransportError, match="0x0001 encodes no CiA 402 state"):
        state_from_statusword(0x0001)  # ready-to-switch-on bit without its partners
