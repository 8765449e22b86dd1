"""The simulated CiA 402 drive's power state machine and its own clock (a mixin of
:class:`sim_backend.canopen_nodes.SimulatedCanOpenRig`, whose ``__init__`` holds the state it uses): the
controlword's transitions, quick stop (0x605A), fault and fault reset, the mode of operation taking effect
(0x6060/0x6061), the statusword (0x6041) that shows them, and the transitions that happen in time with no frame
to trigger them (a slow fault reset, a slow mode switch, the SYNC watchdog)."""

from __future__ import annotations

from rig.protocols import cia402
from sim_backend.canopen_behaviour import (
    EMCY_ERROR_RESET, EMCY_FOLLOWING_ERROR, EMCY_PARAMETER_ERROR, EMCY_SYNC_LOSS, error_register_for,
)
from sim_backend.interpolation_buffer import ip_period_matches

__all__ = ["CLOCK_TICK_S", "CanOpenDriveStates"]

STATUSWORD_FOLLOWS_COMMAND = 0x1000  # bit 12 in CSP: drive follows the command value
STATUSWORD_FOLLOWING_ERROR = 0x2000  # bit 13 in CSP
SYNC_RUNNING_MIN_WINDOW_S = 0.05  # "SYNC running" tolerates this much host jitter whatever 0x1006 says
SYNC_RUNNING_DEFAULT_WINDOW_S = 0.3  # without a communication cycle period (0x1006 = 0 or absent)
CLOCK_TICK_S = 0.002  # the drive's own clock, for timed transitions that no frame triggers


class CanOpenDriveStates:
    """The drive's CiA 402 state machine and its clock (see the module docstring)."""

    def _quick_stop_option(self) -> int | None:
        if self.drive_behaviour.quick_stop_option is None:
            return None
        value = self._u(self.drive, 0x605A)
        return None if value is None else int.from_bytes(value.to_bytes(2, "little"), "little", signed=True)

    def _on_controlword(self, controlword: int, now: float) -> None:
        DS = cia402.DriveState
        previous_word, self.controlword = self.controlword, controlword
        self.controlwords.append(controlword)
        self._advance_locked(now)
        state = self.state
        if state in (DS.FAULT, DS.FAULT_REACTION_ACTIVE):
            rising = controlword & 0x0080 and not previous_word & 0x0080
            if state is DS.FAULT and rising and self._reset_due is None:
                self._reset_due = now + self.drive_behaviour.fault_reset_delay_s
                self._advance_locked(now)
            return
        option = self._quick_stop_option()
        if state is DS.QUICK_STOP_ACTIVE and option is not None:
            if controlword & 0x0002 == 0 or controlword & 0x0080:
                self.state = DS.SWITCH_ON_DISABLED  # transition 12 (disable voltage)
            elif (5 <= option <= 8 and controlword & 0x000F == 0x000F and self._quick_stop_since is not None
                  and now - self._quick_stop_since >= self.drive_behaviour.quick_stop_ramp_s):
                self._enter_operation_enabled(now)  # transition 16
            return
        new = cia402.next_state(state, controlword, previous_word)
        if new is DS.QUICK_STOP_ACTIVE and option is not None:
            if option == 0:
                new = DS.SWITCH_ON_DISABLED  # disable drive function: the motor coasts
            else:
                self._quick_stop_since = now
        if new is DS.OPERATION_ENABLED and state is not DS.OPERATION_ENABLED:
            if self.drive_behaviour.enable_requires_sync and not self._sync_running(now):
                self.state = DS.SWITCHED_ON  # transition 4 waits for SYNC (see _advance_locked)
            else:
                self._enter_operation_enabled(now)
        else:
            self.state = new
        starts_homing = controlword & 0x0010 and not previous_word & 0x0010
        if (starts_homing and self.state is DS.OPERATION_ENABLED
                and self._mode_display == cia402.HOMING_MODE):
            # homing method 37 (CiA 402: home on the current position): nothing moves
            self.homed = True

    def _enter_operation_enabled(self, now: float) -> None:
        self.state = cia402.DriveState.OPERATION_ENABLED
        self._enabled_at = now
        self._quick_stop_since = None
        if self.drive_behaviour.copy_target_on_enable:
            self.drive.data_store.setdefault(0x607A, {})[0] = self.drive.get_data(0x6064, 0)  # no jump on enable

    def _sync_running(self, now: float) -> bool:
        period_us = self._u(self.drive, 0x1006)
        window_s = max(3e-6 * period_us, SYNC_RUNNING_MIN_WINDOW_S) if period_us else SYNC_RUNNING_DEFAULT_WINDOW_S
        return len(self._sync_times) == 3 and now - self._sync_times[0] <= window_s

    def _advance_locked(self, now: float) -> None:
        """The transitions that take the drive's own time (called on every SYNC, statusword read,
        controlword write and by the drive's clock)."""
        DS = cia402.DriveState
        behaviour = self.drive_behaviour
        if self._reset_due is not None and now >= self._reset_due:
            self._complete_fault_reset()
        if self._mode_pending is not None and now >= self._mode_pending[1]:
            self._mode_display, self._mode_pending = self._mode_pending[0], None
        if self.state is DS.QUICK_STOP_ACTIVE and self._quick_stop_since is not None:
            option = self._quick_stop_option()
            if option is not None and 1 <= option <= 4 and now - self._quick_stop_since >= behaviour.quick_stop_ramp_s:
                self.state, self._quick_stop_since = DS.SWITCH_ON_DISABLED, None
        if (behaviour.enable_requires_sync and self.state is DS.SWITCHED_ON
                and self.controlword & 0x008F == 0x000F and self._sync_running(now)):
            self._enter_operation_enabled(now)
        if self.state is DS.OPERATION_ENABLED and behaviour.sync_loss_timeout_s is not None:
            last_sync = self._sync_times[-1] if self._sync_times else -float("inf")
            if now - max(last_sync, self._enabled_at) > behaviour.sync_loss_timeout_s:
                self._fault_locked(EMCY_SYNC_LOSS)
        self._follow_ip_mode()

    def _follow_ip_mode(self) -> None:
        """Where ip mode has just become active (CiA 402: controlword bit 4 in OPERATION ENABLED with
        0x6061 = 7; statusword bit 12): count the records taken afresh and, for a drive that
        ``requires_ip_period``, check 0x60C2 (EMCY 0x6320 on a missing or wrong period)."""
        active = self._ip_active()
        if active and not self._ip_was_active:
            self.interpolation.start_ip_mode()
            if self.drive_behaviour.requires_ip_period and not ip_period_matches(
                    int.from_bytes(self.drive.get_data(0x60C2, 1), "little"),
                    int.from_bytes(self.drive.get_data(0x60C2, 2), "little", signed=True), self._u(self.drive, 0x1006)):
                self._fault_locked(EMCY_PARAMETER_ERROR)
                active = False
        self._ip_was_active = active

    def _fault_locked(self, code: int) -> None:
        if self.state is cia402.DriveState.FAULT:
            return
        self.state = cia402.DriveState.FAULT
        self.faults.append(code)
        self._reset_due = None
        self._quick_stop_since = None
        self._following_error = code == EMCY_FOLLOWING_ERROR
        register = error_register_for(code) | self._warning_registers.get(self.drive.id, 0)
        self._store(self.drive, 0x603F, code, 2)
        self._store(self.drive, 0x1001, register, 1)
        if self.drive.nmt.state != "STOPPED":
            self.drive.emcy.send(code, register=register)
        nmt = self.drive_behaviour.nmt_on_fault
        if nmt is not None and self.drive.nmt.state != nmt.upper():
            self.drive.nmt.state = nmt.upper()  # heartbeat shows it (CiA 301 0x1029 error behaviour)
            self._follow_nmt_states()

    def _complete_fault_reset(self) -> None:
        self._reset_due = None
        self.state = cia402.DriveState.SWITCH_ON_DISABLED
        self._following_error = False
        register = self._warning_registers.get(self.drive.id, 0)
        self._store(self.drive, 0x1001, register, 1)
        if self.drive_behaviour.emcy_error_reset and self.drive.nmt.state != "STOPPED":
            self.drive.emcy.send(EMCY_ERROR_RESET, register=register)

    def _statusword_locked(self) -> int:
        DS = cia402.DriveState
        word = cia402.statusword_for(self.state, target_reached=True)
        if self._mode_display == cia402.HOMING_MODE:
            if self.homed:
                word |= cia402.STATUSWORD_HOMING_ATTAINED
        elif self._mode_display == cia402.INTERPOLATED_POSITION_MODE:
            if self._ip_active():
                word |= cia402.STATUSWORD_IP_MODE_ACTIVE
        elif self._mode_display == cia402.CYCLIC_SYNCHRONOUS_POSITION_MODE:
            if self.state is DS.OPERATION_ENABLED:
                word |= STATUSWORD_FOLLOWS_COMMAND
            if self._following_error:
                word |= STATUSWORD_FOLLOWING_ERROR
        if self.drive.id in self._warning_registers:
            word |= cia402.STATUSWORD_WARNING
        return word

    def _run_clock(self) -> None:
        while not self._clock_stop.wait(CLOCK_TICK_S):
            with self._lock:
                self._advance_locked(self.clock())
