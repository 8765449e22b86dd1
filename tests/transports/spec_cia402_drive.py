"""A CiA 402 servo drive and a CiA 406 encoder written only from the standards: CiA 301 (NMT, SDO, PDO,
SYNC, heartbeat, EMCY), CiA 402 (IEC 61800-7-201: the power state machine, cyclic synchronous position and
interpolated position with its buffer) and CiA 406 (the position value and its scaling). It imports nothing
from ``rig``, ``sim_backend`` or ``identify``: canopen's ``LocalNode`` is only the SDO server and the object
dictionary (read from ``configs/eds``, as data), and its ``NmtSlave`` the NMT states and the heartbeat.

Where the standards leave a choice, this drive makes another legal one than ``sim_backend/canopen_nodes.py``
(the master author's reading); each choice is named where it is made, and listed in
``test_spec_cia402_drive.py``. The drive is ideal (its actual position is its position demand), so what it
"really applied" at a SYNC is exactly its demand there: :attr:`SpecCia402Rig.cycles` records it, SYNC by
SYNC, for the tests to compare with the master's log.
"""

from __future__ import annotations

import collections
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
from can.interfaces.virtual import VirtualBus

EDS_DIRECTORY = Path(__file__).resolve().parents[2] / "configs" / "eds"
DRIVE_EDS = EDS_DIRECTORY / "sim_drive_cia402.eds"  # read as data: which objects exist, their types
ENCODER_EDS = EDS_DIRECTORY / "sim_encoder_cia406.eds"

SYNC_COB_ID = 0x80  # CiA 301 0x1005 default
BITRATE = 1_000_000  # for the frames' wire times
FRAME_OVERHEAD_BITS = 47  # CAN 2.0A data frame without data and stuff bits (ISO 11898-1)
# CiA 301 SDO abort codes (table 22)
ABORT_VALUE_RANGE = 0x06090030  # value range of parameter exceeded
ABORT_VALUE_TOO_HIGH = 0x06090031
# CiA 301 EMCY error codes (table 21) and error register bits (0x1001)
EMCY_ERROR_RESET = 0x0000
EMCY_FOLLOWING_ERROR = 0x8611  # CiA 402: control, following error
ERROR_REGISTER_GENERIC = 0x01

# CiA 402 modes of operation (0x6060 / 0x6061)
PROFILE_POSITION, INTERPOLATED_POSITION, CYCLIC_SYNCHRONOUS_POSITION = 1, 7, 8
SUPPORTED_MODES = 1 << 0 | 1 << 6 | 1 << 7  # 0x6502: pp, ip, csp (no homing: another legal choice)

# CiA 402 states and their statusword bits 0-3, 5, 6 (table "state coding")
NOT_READY, SWITCH_ON_DISABLED, READY_TO_SWITCH_ON, SWITCHED_ON = (
    "NOT READY TO SWITCH ON", "SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON")
OPERATION_ENABLED, QUICK_STOP_ACTIVE = "OPERATION ENABLED", "QUICK STOP ACTIVE"
FAULT_REACTION_ACTIVE, FAULT = "FAULT REACTION ACTIVE", "FAULT"
STATE_BITS = {NOT_READY: 0x00, SWITCH_ON_DISABLED: 0x40, READY_TO_SWITCH_ON: 0x21, SWITCHED_ON: 0x23,
              OPERATION_ENABLED: 0x27, QUICK_STOP_ACTIVE: 0x07, FAULT_REACTION_ACTIVE: 0x0F, FAULT: 0x08}
VOLTAGE_ENABLED, REMOTE, TARGET_REACHED = 0x0010, 0x0200, 0x0400
MODE_BIT_12, MODE_BIT_13 = 0x1000, 0x2000  # ip: ip mode active; csp: target used / following error

# CiA 402 controlword commands (table "device control commands": bits 7, 3, 2, 1, 0)
SHUTDOWN, SWITCH_ON, ENABLE = "shutdown", "switch on", "enable"
DISABLE_VOLTAGE, QUICK_STOP = "disable voltage", "quick stop"
# (state, command) -> (new state, transition number); anything else does nothing
TRANSITIONS = {
    (SWITCH_ON_DISABLED, SHUTDOWN): (READY_TO_SWITCH_ON, 2),
    (READY_TO_SWITCH_ON, SWITCH_ON): (SWITCHED_ON, 3),
    (READY_TO_SWITCH_ON, ENABLE): (OPERATION_ENABLED, 3),  # "switch on + enable operation": 3 then 4
    (READY_TO_SWITCH_ON, DISABLE_VOLTAGE): (SWITCH_ON_DISABLED, 7),
    (READY_TO_SWITCH_ON, QUICK_STOP): (SWITCH_ON_DISABLED, 7),
    (SWITCHED_ON, ENABLE): (OPERATION_ENABLED, 4),
    (SWITCHED_ON, SHUTDOWN): (READY_TO_SWITCH_ON, 6),
    (SWITCHED_ON, DISABLE_VOLTAGE): (SWITCH_ON_DISABLED, 10),
    (SWITCHED_ON, QUICK_STOP): (SWITCH_ON_DISABLED, 10),
    (OPERATION_ENABLED, SWITCH_ON): (SWITCHED_ON, 5),  # "disable operation"
    (OPERATION_ENABLED, SHUTDOWN): (READY_TO_SWITCH_ON, 8),
    (OPERATION_ENABLED, DISABLE_VOLTAGE): (SWITCH_ON_DISABLED, 9),
    (OPERATION_ENABLED, QUICK_STOP): (QUICK_STOP_ACTIVE, 11),
    (QUICK_STOP_ACTIVE, DISABLE_VOLTAGE): (SWITCH_ON_DISABLED, 12),
}
_DRIVE_STATE_OBJECTS = frozenset((0x6041, 0x6061, 0x6062, 0x6064, 0x603F, 0x1001, 0x6502))
CONTROLWORD_FAULT_RESET = 0x0080
CONTROLWORD_IP_ENABLE = 0x0010  # bit 4 in interpolated position: enable ip mode


def command_of(controlword: int) -> str | None:
    """The device control command a controlword codes (bit 7 is 0 in every one of them), or None."""
    if controlword & 0x0080:
        return None  # "fault reset" acts on its rising edge, in FAULT only (transition 15)
    if controlword & 0x0002 == 0:
        return DISABLE_VOLTAGE  # 0xxx xx0x
    if controlword & 0x0006 == 0x0002:
        return QUICK_STOP  # 0xxx x01x
    if controlword & 0x0007 == 0x0006:
        return SHUTDOWN  # 0xxx x110
    return ENABLE if controlword & 0x0008 else SWITCH_ON  # 0xxx 1111 / 0xxx 0111


@dataclass(frozen=True)
class Cycle:
    """What the drive did at one SYNC in OPERATION ENABLED.

    Attributes
    ----------
    sync
        The SYNC's number (counted from the drive's start).
    mode
        The mode of operation shown in 0x6061.
    demand_counts
        The position demand (0x6062) at this SYNC; the ideal drive's actual position (0x6064).
    in_force_counts
        The command the drive took up at this SYNC: CSP, the target 0x607A in force; interpolated position,
        the record taken (the end point it moves to by the next SYNC), or the last one taken (an underrun,
        bit 4 low); None before the first.
    record_taken
        Interpolated position: whether a record was taken from the buffer at this SYNC.
    rpdos
        RPDOs taken up at or before this SYNC, since the drive became OPERATIONAL.
    encoder_counts
        The encoder's position value (0x6004) latched at this SYNC.
    """

    sync: int
    mode: int
    demand_counts: int
    in_force_counts: int | None
    record_taken: bool
    rpdos: int
    encoder_counts: int


class _HardwareTimestampBus(VirtualBus):
    """python-can's virtual bus, but a frame sent with a time stamp keeps it: the TPDOs carry the wire time
    an interface with hardware time stamps would give them (the SYNC's time stamp plus the bits on the wire
    since), however late the device's thread got to answer on a loaded test machine."""

    def __init__(self, channel: str) -> None:
        super().__init__(channel=channel, receive_own_messages=False, preserve_timestamps=True)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not msg.timestamp:
            msg.timestamp = time.time()
        super().send(msg, timeout)


class SpecCia402Rig:
    """A CiA 402 drive and a CiA 406 encoder on python-can's ``virtual`` bus ``channel``.

    Parameters
    ----------
    channel
        The virtual bus the master's ``canopen://virtual/<channel>`` joins.
    drive_node_id, encoder_node_id
        Node-IDs.
    quick_stop_option
        0x605A: 2 (slow down on the quick stop ramp, then SWITCH ON DISABLED) or 6 (ramp, then stay in
        QUICK STOP ACTIVE with bit 10 set).
    start_position_counts
        The motor's position at power-on (0x6064), away from zero.
    stale_target_counts
        0x607A at power-on, away from the position: this drive does not copy the actual position into the
        target on enable (the simulated drive does), so a master that does not write it moves the motor.
    buffer_max_records, buffer_records
        0x60C4:1 (maximum buffer size) and the default of 0x60C4:2 (actual buffer size, writable up to it).
    encoder_bits, encoder_multi_turn_bits
        The encoder: 2**bits counts per revolution (0x6001), 2**(bits + multi_turn_bits) in all (0x6002);
        the load turns with the motor (gear ratio 1).
    drive_counts_per_revolution
        Drive position units per motor revolution.
    following_error_at_record
        Interpolated position: at the SYNC that would take this record (counted from 0), the drive detects a
        following error instead: FAULT REACTION ACTIVE, EMCY 0x8611, then FAULT.
    mode_switch_s, fault_reaction_s, fault_reset_s, quick_stop_ramp_s
        How long the drive takes to show a new mode in 0x6061, to go from FAULT REACTION ACTIVE to FAULT,
        to clear a fault after the reset edge, and to stop on the quick stop ramp.
    sdo_server_delay_s
        The drive's SDO server runs in a slower task than its SYNC and PDOs: each request is acted on, and
        answered, this long after it reaches the drive (CiA 301 sets no SDO response time), in the order the
        requests came. 0: at once.
    """

    def __init__(self, channel: str, *, drive_node_id: int = 1, encoder_node_id: int = 2, quick_stop_option: int = 2,
                 start_position_counts: int = 12_345, stale_target_counts: int = -40_000,
                 buffer_max_records: int = 32, buffer_records: int = 24, encoder_bits: int = 14,
                 encoder_multi_turn_bits: int = 4, drive_counts_per_revolution: int = 1 << 17,
                 following_error_at_record: int | None = None, mode_switch_s: float = 0.005,
                 fault_reaction_s: float = 0.005, fault_reset_s: float = 0.005,
                 quick_stop_ramp_s: float = 0.01, sdo_server_delay_s: float = 0.0) -> None:
        if quick_stop_option not in (2, 6):
            raise ValueError(f"quick_stop_option: this drive implements 2 and 6, got {quick_stop_option}")
        self.channel = channel
        self.drive = canopen.LocalNode(drive_node_id, canopen.import_od(str(DRIVE_EDS), drive_node_id))
        self.encoder = canopen.LocalNode(encoder_node_id, canopen.import_od(str(ENCODER_EDS), encoder_node_id))
        self.drive_counts_per_revolution = drive_counts_per_revolution
        self.encoder_counts_per_revolution = 1 << encoder_bits
        self.encoder_range = 1 << (encoder_bits + encoder_multi_turn_bits)
        self.following_error_at_record = following_error_at_record
        self.mode_switch_s, self.fault_reaction_s = mode_switch_s, fault_reaction_s
        self.fault_reset_s, self.quick_stop_ramp_s = fault_reset_s, quick_stop_ramp_s
        self._lock = threading.RLock()
        self.network: canopen.Network | None = None
        self.sdo_server_delay_s = sdo_server_delay_s
        self._sdo_requests: queue.Queue = queue.Queue()  # (due, cob-id, data, time stamp); None ends the task
        self._sdo_task: threading.Thread | None = None
        # the drive (CiA 402)
        self._state = SWITCH_ON_DISABLED  # transitions 0 and 1 are done at power-on
        self.transitions: list[int] = []  # every transition taken, in order
        self.controlword = 0
        self.mode_display = 0
        self._mode_due: tuple[int, float] | None = None
        self.position_counts = start_position_counts
        self.enable_positions: list[int] = []  # the position at each entry into OPERATION ENABLED
        self.error_code = 0
        self.error_register = 0
        self.faults: list[int] = []
        self._following_error = False  # statusword bit 13 in CSP, until the fault is reset
        self._state_due: tuple[str, float] | None = None  # a timed transition: (state, when)
        self._reset_due: float | None = None
        self.buffer: collections.deque[int] = collections.deque()
        self.buffer_enabled = False  # 0x60C4:6: 0 clears and disables access, 1 enables it
        self.records_discarded = 0  # written while access was disabled, or into a full buffer
        self.records_taken = 0
        self._segment_end: int | None = None  # the record the interpolator moves to (None: none taken yet)
        self.cycles: list[Cycle] = []
        self.syncs = 0
        # CiA 301 PDOs, as configured by SDO (read when a node enters OPERATIONAL)
        self._operational: set[int] = set()
        self._tpdos: dict[int, list[dict]] = {}
        self._rpdo: dict | None = None
        self._pending_rpdos: list[bytes] = []  # synchronous RPDOs: taken up at the next SYNC (CiA 301)
        self.rpdos = 0
        self._store(self.drive, 0x607A, 0, stale_target_counts)
        self._store(self.drive, 0x605A, 0, quick_stop_option)
        self._store(self.drive, 0x60C4, 1, buffer_max_records)
        self._store(self.drive, 0x60C4, 2, buffer_records)
        self._store(self.encoder, 0x6000, 0, 0)  # code sequence: counts up with the angle
        self._store(self.encoder, 0x6001, 0, self.encoder_counts_per_revolution)
        self._store(self.encoder, 0x6002, 0, self.encoder_range)

    # -- lifecycle -------------------------------------------------------------------------------------------

    def start(self) -> SpecCia402Rig:
        self.network = canopen.Network(_HardwareTimestampBus(self.channel))
        self.network.connect()
        for node in (self.drive, self.encoder):
            self.network.add_node(node)
        self.drive.add_read_callback(self._on_drive_read)
        self.drive.add_write_callback(self._on_drive_write)
        if self.sdo_server_delay_s > 0.0:  # the drive's SDO requests go through its slower task
            self.network.unsubscribe(self.drive.sdo.rx_cobid, self.drive.sdo.on_request)
            self.network.subscribe(self.drive.sdo.rx_cobid, self._queue_sdo_request)
            self._sdo_task = threading.Thread(target=self._serve_sdo_requests, name="spec402-sdo", daemon=True)
            self._sdo_task.start()
        self.encoder.add_read_callback(self._on_encoder_read)
        self.network.subscribe(0, self._on_nmt)  # after the nodes' own NMT handlers
        self.network.subscribe(SYNC_COB_ID, self._on_sync)
        for node in (self.drive, self.encoder):
            node.nmt.state = "PRE-OPERATIONAL"  # boot-up (CiA 301: INITIALISING -> PRE-OPERATIONAL)
        return self

    def close(self) -> None:
        if self.network is None:
            return
        if self._sdo_task is not None:
            self._sdo_requests.put(None)
            self._sdo_task.join()
            self._sdo_task = None
        for node in (self.drive, self.encoder):
            node.nmt.stop_heartbeat()
        self.network.disconnect()
        self.network = None

    def __enter__(self) -> SpecCia402Rig:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _queue_sdo_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._sdo_requests.put((time.monotonic() + self.sdo_server_delay_s, can_id, bytes(data), timestamp))

    def _serve_sdo_requests(self) -> None:
        """The drive's SDO task: each request acted on and answered ``sdo_server_delay_s`` after it came."""
        while (request := self._sdo_requests.get()) is not None:
            due, can_id, data, timestamp = request
            time.sleep(max(0.0, due - time.monotonic()))
            self.drive.sdo.on_request(can_id, bytearray(data), timestamp)

    @property
    def state(self) -> str:
        """The CiA 402 state now (after the timed transitions that are due)."""
        with self._lock:
            self._advance(time.monotonic())
            return self._state

    @property
    def nmt_states(self) -> tuple[str, str]:
        return self.drive.nmt.state, self.encoder.nmt.state

    # -- object dictionary ------------------------------------------------------------------------------------

    @staticmethod
    def _entry(node: canopen.LocalNode, index: int, subindex: int) -> canopen.objectdictionary.ODVariable:
        """The dictionary entry of index:subindex (a variable, or a sub-entry of an array or record)."""
        obj = node.object_dictionary[index]
        return obj if isinstance(obj, canopen.objectdictionary.ODVariable) else obj[subindex]

    def _store(self, node: canopen.LocalNode, index: int, subindex: int, value: int) -> None:
        """Set an object the device owns (no write callback: not a write from the bus)."""
        node.data_store.setdefault(index, {})[subindex] = self._entry(node, index, subindex).encode_raw(value)

    def _value(self, node: canopen.LocalNode, index: int, subindex: int = 0) -> int:
        return self._entry(node, index, subindex).decode_raw(node.get_data(index, subindex))

    def _on_drive_read(self, index: int, subindex: int, od: object) -> int | None:
        """The objects the drive's own state owns; everything else is what was written (or the EDS default)."""
        if index not in _DRIVE_STATE_OBJECTS:
            return None
        with self._lock:
            self._advance(time.monotonic())
            return {0x6041: self._statusword, 0x6061: lambda: self.mode_display,
                    0x6062: lambda: self.position_counts, 0x6064: lambda: self.position_counts,
                    0x603F: lambda: self.error_code, 0x1001: lambda: self.error_register,
                    0x6502: lambda: SUPPORTED_MODES}[index]()

    def _on_encoder_read(self, index: int, subindex: int, od: object) -> int | None:
        if index == 0x6004:  # CiA 406 position value: the load (gear ratio 1) in encoder counts
            with self._lock:
                return self._encoder_counts()
        return None

    def _encoder_counts(self) -> int:
        counts = self.position_counts * self.encoder_counts_per_revolution // self.drive_counts_per_revolution
        return counts % self.encoder_range

    def _on_drive_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        """SDO and RPDO writes (canopen stores the data after this returns; an abort refuses it)."""
        value = od.decode_raw(data)
        now = time.monotonic()
        with self._lock:
            self._advance(now)
            if index == 0x6040:
                self._on_controlword(value, now)
            elif index == 0x6060:
                if value not in (PROFILE_POSITION, INTERPOLATED_POSITION, CYCLIC_SYNCHRONOUS_POSITION):
                    raise canopen.SdoAbortedError(ABORT_VALUE_RANGE)
                self._mode_due = (value, now + self.mode_switch_s)  # 0x6061 follows after a while
            elif index == 0x605A and value not in (2, 6):
                raise canopen.SdoAbortedError(ABORT_VALUE_RANGE)
            elif index == 0x60C0 and value != 0:  # only linear interpolation
                raise canopen.SdoAbortedError(ABORT_VALUE_RANGE)
            elif index == 0x60C4:
                self._on_buffer_write(subindex, value)
            elif (index, subindex) == (0x60C1, 1):
                self._push_record(value)

    def _on_buffer_write(self, subindex: int, value: int) -> None:
        """CiA 402 0x60C4 interpolation data configuration: sub 2 actual buffer size (at most sub 1), sub 3
        buffer organisation (0 FIFO only), sub 6 buffer clear (0: clear and disable access, 1: enable)."""
        if subindex == 2 and value > self._value(self.drive, 0x60C4, 1):
            raise canopen.SdoAbortedError(ABORT_VALUE_TOO_HIGH)
        if subindex == 3 and value != 0:
            raise canopen.SdoAbortedError(ABORT_VALUE_RANGE)
        if subindex == 6:
            if value == 0:
                self.buffer.clear()
            self.buffer_enabled = value == 1

    def _push_record(self, counts: int) -> None:
        """An interpolation data record (0x60C1:1) into the FIFO; discarded while access is disabled or the
        buffer is full (another legal choice than an EMCY)."""
        if not self.buffer_enabled or len(self.buffer) >= self._value(self.drive, 0x60C4, 2):
            self.records_discarded += 1
            return
        self.buffer.append(counts)

    # -- the CiA 402 state machine ------------------------------------------------------------------------------

    def _on_controlword(self, controlword: int, now: float) -> None:
        previous, self.controlword = self.controlword, controlword
        if self._state == FAULT:
            if controlword & CONTROLWORD_FAULT_RESET and not previous & CONTROLWORD_FAULT_RESET:
                self._reset_due = now + self.fault_reset_s  # transition 15 on the rising edge, after a while
            return
        if self._state == QUICK_STOP_ACTIVE:
            command = command_of(controlword)
            if self._state_due is None and command == ENABLE and self._value(self.drive, 0x605A) == 6:
                self._enter(OPERATION_ENABLED, 16)  # at rest, option 5-8: back to OPERATION ENABLED
                return
            if command != DISABLE_VOLTAGE:
                return  # only disable voltage (12) acts
            self._state_due = None
        step = TRANSITIONS.get((self._state, command_of(controlword)))
        if step is None:
            return  # not a transition from this state: nothing happens
        new, number = step
        self._enter(new, number)
        if new == QUICK_STOP_ACTIVE:  # options 2 and 6: ramp first
            after = SWITCH_ON_DISABLED if self._value(self.drive, 0x605A) == 2 else QUICK_STOP_ACTIVE
            self._state_due = (after, now + self.quick_stop_ramp_s)

    def _enter(self, state: str, transition: int) -> None:
        self.transitions.append(transition)
        if state == OPERATION_ENABLED and self._state != OPERATION_ENABLED:
            self.enable_positions.append(self.position_counts)
            self._segment_end = None  # the interpolator starts where the motor is
        self._state = state

    def _advance(self, now: float) -> None:
        """The transitions that take the drive's own time (checked on every SYNC and SDO access)."""
        if self._mode_due is not None and now >= self._mode_due[1]:
            self.mode_display, self._mode_due = self._mode_due[0], None
        if self._state_due is not None and now >= self._state_due[1]:
            state, self._state_due = self._state_due[0], None
            if state != self._state:
                self._enter(state, {FAULT: 14, SWITCH_ON_DISABLED: 12}[state])
        if self._state == FAULT and self._reset_due is not None and now >= self._reset_due:
            self._reset_due = None
            self.error_code = self.error_register = 0
            self._following_error = False
            self._enter(SWITCH_ON_DISABLED, 15)
            self.drive.emcy.send(EMCY_ERROR_RESET, register=0)  # CiA 301: the error is gone

    def fault(self, code: int) -> None:
        """Transition 13: FAULT REACTION ACTIVE (EMCY, 0x603F, 0x1001), then FAULT after the reaction (14)."""
        with self._lock:
            if self._state in (FAULT_REACTION_ACTIVE, FAULT):
                return
            self.faults.append(code)
            self.error_code, self.error_register = code, ERROR_REGISTER_GENERIC
            self._following_error = code == EMCY_FOLLOWING_ERROR
            self._enter(FAULT_REACTION_ACTIVE, 13)
            self._state_due = (FAULT, time.monotonic() + self.fault_reaction_s)
            self.drive.emcy.send(code, register=self.error_register)

    def encoder_emcy(self, code: int) -> None:
        """The encoder reports an error (CiA 301 EMCY, 0x1001)."""
        self._store(self.encoder, 0x1001, 0, ERROR_REGISTER_GENERIC)
        self.encoder.emcy.send(code, register=ERROR_REGISTER_GENERIC)

    def _ip_active(self) -> bool:
        """Statusword bit 12 in interpolated position: OPERATION ENABLED, 0x6061 = 7 and controlword bit 4."""
        return (self._state == OPERATION_ENABLED and self.mode_display == INTERPOLATED_POSITION
                and bool(self.controlword & CONTROLWORD_IP_ENABLE))

    def _statusword(self) -> int:
        word = STATE_BITS[self._state] | REMOTE
        if self._state not in (NOT_READY, SWITCH_ON_DISABLED):
            word |= VOLTAGE_ENABLED
        if self._state == QUICK_STOP_ACTIVE and self._state_due is None:
            word |= TARGET_REACHED  # at rest after the ramp (option 6)
        if self.mode_display == INTERPOLATED_POSITION:
            if self._ip_active():
                word |= MODE_BIT_12
            if self._ip_active() and not self.buffer and self._segment_end in (None, self.position_counts):
                word |= TARGET_REACHED
        elif self.mode_display == CYCLIC_SYNCHRONOUS_POSITION:
            if self._state == OPERATION_ENABLED:
                word |= MODE_BIT_12  # the target is used as the position control's input
            if self._following_error:
                word |= MODE_BIT_13
        return word

    # -- NMT and PDOs (CiA 301) ------------------------------------------------------------------------------

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            for node in (self.drive, self.encoder):
                operational = node.nmt.state == "OPERATIONAL"
                if operational and node.id not in self._operational:
                    self._operational.add(node.id)
                    self._read_pdo_configuration(node)
                elif not operational and node.id in self._operational:
                    self._operational.discard(node.id)
                    if node is self.drive and self._rpdo is not None:
                        self.network.unsubscribe(self._rpdo["cob_id"], self._on_rpdo)
                        self._rpdo, self._pending_rpdos = None, []

    def _pdo(self, node: canopen.LocalNode, communication: int, mapping: int) -> dict | None:
        """One PDO from its communication (sub 1 COB-ID, bit 31 = not valid; sub 2 transmission type) and
        mapping parameters (sub 0 count, then 0xIIIISSLL: index, sub-index, length in bits)."""
        cob_id = self._value(node, communication, 1)
        if cob_id & 0x80000000:
            return None
        entries = []
        for sub in range(1, self._value(node, mapping, 0) + 1):
            entry = self._value(node, mapping, sub)
            entries.append((entry >> 16, entry >> 8 & 0xFF, (entry & 0xFF) // 8))
        return {"cob_id": cob_id & 0x7FF, "type": self._value(node, communication, 2), "entries": entries,
                "count": 0, "last": None}

    def _read_pdo_configuration(self, node: canopen.LocalNode) -> None:
        od = node.object_dictionary
        self._tpdos[node.id] = [pdo for n in range(4) if 0x1800 + n in od
                                for pdo in [self._pdo(node, 0x1800 + n, 0x1A00 + n)] if pdo is not None]
        if node is self.drive and 0x1400 in od:
            self._rpdo = self._pdo(node, 0x1400, 0x1600)
            if self._rpdo is not None:
                self.network.subscribe(self._rpdo["cob_id"], self._on_rpdo)

    def _on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        """Transmission types 0-240: synchronous, the data are taken up at the next SYNC; 254/255 at once."""
        with self._lock:
            if self._rpdo is None:
                return
            if self._rpdo["type"] <= 240:
                self._pending_rpdos.append(bytes(data))
            else:
                self._take_up(bytes(data))

    def _take_up(self, data: bytes) -> None:
        offset = 0
        for index, subindex, size in self._rpdo["entries"]:
            if len(data) < offset + size:
                return  # CiA 301: a PDO shorter than its mapping is not processed
            self.drive.set_data(index, subindex, data[offset:offset + size])
            offset += size
        self.rpdos += 1

    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        frames = []
        with self._lock:
            self._advance(time.monotonic())
            self.syncs += 1
            if self.drive.id in self._operational:
                pending, self._pending_rpdos = self._pending_rpdos, []
                for payload in pending:
                    self._take_up(payload)
                if self._state == OPERATION_ENABLED:
                    self._cycle()
            for node in (self.drive, self.encoder):
                if node.id in self._operational:
                    frames += self._due_tpdos(node)
        wire_time = timestamp + (FRAME_OVERHEAD_BITS + 8 * len(data)) / BITRATE
        for cob_id, payload in frames:
            wire_time += (FRAME_OVERHEAD_BITS + 8 * len(payload)) / BITRATE
            self.network.bus.send(can.Message(arbitration_id=cob_id, data=payload, is_extended_id=False,
                                              timestamp=wire_time))

    def _cycle(self) -> None:
        """One SYNC in OPERATION ENABLED. CSP: the demand is the target in force. Interpolated position
        (linear, 0x60C0 = 0): the interpolator arrives at the end of the segment begun at the last SYNC, so
        the demand here is the record taken at the last SYNC; then, with bit 12 set, it takes the next record
        as the end of the segment to the next SYNC (an empty buffer holds the last one); bit 4 low pauses."""
        taken = False
        if self.mode_display == CYCLIC_SYNCHRONOUS_POSITION:
            self.position_counts = in_force = self._value(self.drive, 0x607A)
        elif self.mode_display == INTERPOLATED_POSITION and self._ip_active():
            if self._segment_end is not None:
                self.position_counts = self._segment_end
            if self.buffer:
                if self.records_taken == self.following_error_at_record:
                    self.fault(EMCY_FOLLOWING_ERROR)
                    return
                self._segment_end, taken = self.buffer.popleft(), True
                self.records_taken += 1
            in_force = self._segment_end
        else:
            in_force = self._segment_end if self.mode_display == INTERPOLATED_POSITION else None
        self.cycles.append(Cycle(self.syncs, self.mode_display, self.position_counts, in_force, taken, self.rpdos,
                                 self._encoder_counts()))

    def _due_tpdos(self, node: canopen.LocalNode) -> list[tuple[int, bytes]]:
        """Transmission type n in 1..240: after every n-th SYNC; 0: at a SYNC when the data changed."""
        due = []
        for pdo in self._tpdos.get(node.id, ()):
            payload = b"".join(node.get_data(index, subindex)[:size] for index, subindex, size in pdo["entries"])
            pdo["count"] += 1
            kind = pdo["type"]
            if (1 <= kind <= 240 and pdo["count"] % kind == 0) or (kind == 0 and payload != pdo["last"]):
                due.append((pdo["cob_id"], payload))
                pdo["last"] = payload
        return due
