"""The simulated CiA 402 drive against CiA 301 PDO semantics and CiA 402 interpolated position mode, SYNC by
SYNC on a simulated clock (``tests/transports/clocked_canopen.py``: no thread, no sleep), scripted from
canopen's own ``RemoteNode`` and raw frames.

What each test expects is written from the standards, not read from the simulator:

* CiA 301, RPDO communication parameter 0x1400 sub 2 (transmission type): 0..240 synchronous, the device
  has one receive buffer per RPDO, a frame overwrites the one before, and the data are applied at the next
  SYNC; 254/255 event-driven, applied on arrival; 241..253 are not RPDO types (SDO abort 0x06090030).
* CiA 402 interpolated position mode (0x6060 = 7): 0x60C0 sub-mode (0 linear), 0x60C1:1 records into the
  buffer configured by 0x60C4, 0x60C2 interpolation time period; controlword bit 4 enables ip mode in
  OPERATION ENABLED and statusword bit 12 shows it; each SYNC with ip mode active takes the oldest record.
"""

from __future__ import annotations

import contextlib
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import canopen
import pytest
from canopen import objectdictionary as od_types

from canopen_bench import DRIVE_ID, FAULT, OPERATION_ENABLED, gearbox, is_state, no_leaks  # noqa: F401
from clocked_canopen import ClockedCanBus  # tests/transports, on the path canopen_bench sets
from clocked_line import SimulatedClock
from identify.validation import InvalidInputError
from rig.protocols.cia402 import STATUSWORD_IP_MODE_ACTIVE
from sim_backend.canopen_behaviour import DriveBehaviour, error_register_for
from sim_backend.canopen_nodes import DRIVE_EDS, SimulatedCanOpenRig
from sim_backend.eds_variants import eds_without

SYNC_PERIOD_S = 0.001
RPDO1_COB_ID = 0x200 + DRIVE_ID
INTERPOLATION_RECORD_MAPPING = 0x60C1_01_20  # 0x60C1 sub 1, 32 bits
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_TOO_HIGH = 0x06090031
ABORT_VALUE_TOO_LOW = 0x06090032
ABORT_READ_ONLY = 0x06010002
ABORT_WRITE_ONLY = 0x06010001
EMCY_POSITIONING_CONTROLLER = 0x8600  # CiA 402
EMCY_PARAMETER_ERROR = 0x6320  # CiA 301
IP_MODE = 7
CSP = 8


@dataclass
class Master:
    """canopen's ``RemoteNode`` for the drive, the raw frames of a master, and the bus's clock."""

    rig: SimulatedCanOpenRig
    bus: ClockedCanBus
    network: canopen.Network
    drive: canopen.RemoteNode

    def sync(self) -> None:
        """One SYNC period passes, then the SYNC."""
        self.bus.stall(SYNC_PERIOD_S)
        self.network.sync.transmit()

    def rpdo1(self, *values: int) -> None:
        """One RPDO1 frame per value, each a 32-bit signed payload."""
        for value in values:
            self.network.send_message(RPDO1_COB_ID, struct.pack("<i", value))

    def statusword(self) -> int:
        return self.drive.sdo[0x6041].raw

    def buffer_position(self) -> int:
        """0x60C4:4: with a FIFO, the records the buffer holds."""
        return self.drive.sdo[0x60C4][4].raw

    def demand(self) -> int:
        """0x6062, the position demand value: the target the drive applied at the last SYNC."""
        return self.drive.sdo[0x6062].raw

    def emcy_codes(self) -> list[int]:
        return [entry.code for entry in self.drive.emcy.log]

    def abort_code(self, variable: Any, value: int) -> int | None:
        """The SDO abort code of writing ``value`` to ``variable`` (``drive.sdo[...]``; None: accepted)."""
        try:
            variable.raw = value
        except canopen.SdoAbortedError as error:
            return error.code
        return None

    def ip_mode_set_up(self, *, transmission_type: int | None = None, mode: int = IP_MODE) -> None:
        """Pre-operational set-up by SDO: RPDO1 carries 0x60C1:1 (or the EDS's 0x607A in CSP), the
        transmission type if given, mode, interpolation buffer cleared and enabled; OPERATIONAL; enabled
        without bit 4 (0x0F)."""
        sdo = self.drive.sdo
        self.drive.nmt.state = "PRE-OPERATIONAL"
        if mode == IP_MODE:
            sdo[0x1600][0].raw = 0  # CiA 301 mapping procedure: count 0, entries, count
            sdo[0x1600][1].raw = INTERPOLATION_RECORD_MAPPING
            sdo[0x1600][0].raw = 1
            sdo[0x60C0].raw = 0
            sdo[0x60C4][6].raw = 0
            sdo[0x60C4][6].raw = 1
        if transmission_type is not None:
            sdo[0x1400][2].raw = transmission_type
        sdo[0x6060].raw = mode
        self.drive.nmt.state = "OPERATIONAL"
        for word in (0x06, 0x07, 0x0F):
            sdo[0x6040].raw = word
        assert is_state(self.statusword(), OPERATION_ENABLED)


@contextlib.contextmanager
def clocked_drive(plant: Any = None, **rig_options: Any) -> Iterator[Master]:
    """The simulated drive (on ``plant``, a simulated gearbox; the bench's by default) and canopen's master on one
    scripted bus and simulated clock."""
    clock = SimulatedClock(10.0)
    bus = ClockedCanBus(clock)
    rig_options.setdefault("hold_plant_until_first_target", False)
    rig = SimulatedCanOpenRig(gearbox() if plant is None else plant, channel="clocked", clock=clock, **rig_options)
    bus.devices(rig)
    endpoint = bus.endpoint(receive_own_messages=False)
    network = canopen.Network(endpoint)
    endpoint.join(network)
    drive = canopen.RemoteNode(DRIVE_ID, str(rig_options.get("drive_eds", DRIVE_EDS)))
    network.add_node(drive)
    try:
        yield Master(rig, bus, network, drive)
    finally:
        network.disconnect()
        rig.close()


# -- CiA 301: the transmission type of an RPDO -------------------------------------------------------------

def test_frames_between_two_syncs_on_a_synchronous_rpdo_leave_one_record_the_last(no_leaks):
    with clocked_drive() as m:
        m.ip_mode_set_up()
        assert m.drive.sdo[0x1400][2].raw == 1  # the EDS default: synchronous, every SYNC
        m.rpdo1(100, 200, 300)
        assert m.buffer_position() == 0  # a synchronous RPDO acts at the SYNC, not on arrival
        m.sync()
        assert m.buffer_position() == 1  # one receive buffer: the last frame overwrote the others
        m.drive.sdo[0x6040].raw = 0x1F  # enable ip mode
        m.sync()
        assert m.demand() == 300 and m.buffer_position() == 0
        assert m.rig.ip_overruns == 0


def test_a_synchronous_rpdo_is_applied_once_at_the_next_sync_only(no_leaks):
    with clocked_drive() as m:
        m.ip_mode_set_up(transmission_type=0)  # acyclic synchronous: also acts at the next SYNC
        m.rpdo1(100)
        m.sync()
        m.sync()  # nothing received since: nothing applied again
        assert m.buffer_position() == 1


def test_each_frame_on_an_event_driven_rpdo_is_a_record_at_once(no_leaks):
    with clocked_drive() as m:
        m.ip_mode_set_up(transmission_type=255)
        assert m.drive.sdo[0x1400][2].raw == 255
        m.rpdo1(100, 200, 300)
        assert m.buffer_position() == 3  # before any SYNC
        m.drive.sdo[0x6040].raw = 0x1F
        demands = []
        for _ in range(3):
            m.sync()
            demands.append(m.demand())
        assert demands == [100, 200, 300]


def test_a_synchronous_csp_target_is_the_last_frame_and_acts_at_the_sync(no_leaks):
    with clocked_drive() as m:
        m.ip_mode_set_up(mode=CSP)  # RPDO1 carries 0x607A (EDS default), synchronous
        m.rpdo1(1000, 2000)
        assert m.drive.sdo[0x607A].raw == 0  # not applied on arrival
        m.sync()
        assert m.drive.sdo[0x607A].raw == m.demand() == 2000


def test_a_frame_latched_before_the_node_leaves_operational_is_not_applied(no_leaks):
    with clocked_drive() as m:
        m.ip_mode_set_up()
        m.rpdo1(100)
        m.drive.nmt.state = "PRE-OPERATIONAL"
        m.sync()
        m.drive.nmt.state = "OPERATIONAL"
        m.sync()
        assert m.buffer_position() == 0


@pytest.mark.parametrize("transmission_type", [0, 1, 240, 254, 255])
def test_rpdo_transmission_types_of_cia_301_are_written_and_read_back(transmission_type, no_leaks):
    with clocked_drive() as m:
        m.drive.nmt.state = "PRE-OPERATIONAL"
        assert m.abort_code(m.drive.sdo[0x1400][2], transmission_type) is None
        assert m.drive.sdo[0x1400][2].raw == transmission_type


@pytest.mark.parametrize("transmission_type", [241, 245, 251, 252, 253])
def test_reserved_rpdo_transmission_types_are_refused_with_value_range(transmission_type, no_leaks):
    with clocked_drive() as m:
        m.drive.nmt.state = "PRE-OPERATIONAL"
        assert m.abort_code(m.drive.sdo[0x1400][2], transmission_type) == ABORT_VALUE_RANGE
        assert m.drive.sdo[0x1400][2].raw == 1  # unchanged


# -- CiA 402: ip mode, controlword bit 4, statusword bit 12 --------------------------------------------------

def test_statusword_bit_12_follows_controlword_bit_4_and_records_wait_while_it_is_clear(no_leaks):
    with clocked_drive() as m:
        m.ip_mode_set_up(transmission_type=255)
        assert not m.statusword() & STATUSWORD_IP_MODE_ACTIVE
        m.rpdo1(500, 600)
        for _ in range(3):
            m.sync()
        assert m.buffer_position() == 2 and m.demand() == 0  # bit 4 clear: buffered, the axis holds
        m.drive.sdo[0x6040].raw = 0x1F
        assert m.statusword() & STATUSWORD_IP_MODE_ACTIVE
        m.sync()
        assert m.demand() == 500
        m.drive.sdo[0x6040].raw = 0x0F  # bit 4 clear again: ip mode inactive, the axis holds
        assert not m.statusword() & STATUSWORD_IP_MODE_ACTIVE
        m.sync()
        assert m.demand() == 500 and m.buffer_position() == 1
        m.drive.sdo[0x6040].raw = 0x07  # disable operation: SWITCHED ON, bit 4 has no meaning
        assert not m.statusword() & STATUSWORD_IP_MODE_ACTIVE
        m.drive.sdo[0x6040].raw = 0x1F  # enable operation with bit 4: ip mode active at once
        assert m.statusword() & STATUSWORD_IP_MODE_ACTIVE
        m.sync()
        assert m.demand() == 600


def test_bit_4_in_another_mode_is_not_ip_mode(no_leaks):
    with clocked_drive() as m:
        m.ip_mode_set_up(transmission_type=255)
        m.drive.sdo[0x6060].raw = CSP
        m.rpdo1(700)
        m.drive.sdo[0x6040].raw = 0x1F
        m.sync()
        assert m.buffer_position() == 1 and m.rig.ip_levels == []


# -- CiA 402: what an empty buffer at a SYNC does (DriveBehaviour.ip_underflow) ----------------------------

def test_an_empty_buffer_holds_the_last_position_by_default(no_leaks):
    with clocked_drive() as m:
        m.ip_mode_set_up(transmission_type=255)
        m.rpdo1(400)
        m.drive.sdo[0x6040].raw = 0x1F
        m.sync()
        m.sync()
        assert m.demand() == 400 and is_state(m.statusword(), OPERATION_ENABLED)
        assert m.rig.ip_underruns == 1 and m.rig.faults == []


@pytest.mark.parametrize("hold_plant_until_first_target", [False, True])
def test_a_drive_that_faults_on_underflow_faults_at_the_first_sync_with_bit_4_on_an_empty_buffer(
        hold_plant_until_first_target, no_leaks):
    with clocked_drive(drive_behaviour=DriveBehaviour(ip_underflow="fault"),
                       hold_plant_until_first_target=hold_plant_until_first_target) as m:
        m.ip_mode_set_up()
        m.drive.sdo[0x6040].raw = 0x1F
        assert is_state(m.statusword(), OPERATION_ENABLED)  # no SYNC yet
        m.sync()
        assert is_state(m.statusword(), FAULT)
        assert m.drive.sdo[0x603F].raw == EMCY_POSITIONING_CONTROLLER
        assert m.drive.sdo[0x1001].raw == error_register_for(EMCY_POSITIONING_CONTROLLER) == 0x21
        assert m.emcy_codes() == [EMCY_POSITIONING_CONTROLLER]


def test_a_drive_that_faults_on_underflow_runs_while_the_master_keeps_records_ahead(no_leaks):
    with clocked_drive(drive_behaviour=DriveBehaviour(ip_underflow="fault")) as m:
        m.ip_mode_set_up()
        m.rpdo1(10)
        m.sync()  # bit 4 clear: the record waits in the buffer
        m.drive.sdo[0x6040].raw = 0x1F
        for k in range(1, 6):  # one record per cycle: latched before SYNC k, in the FIFO when SYNC k takes one
            m.rpdo1(10 * (k + 1))
            m.sync()
            assert m.demand() == 10 * k
        assert is_state(m.statusword(), OPERATION_ENABLED) and m.rig.faults == []
        m.sync()
        m.sync()  # the last record taken, then an empty buffer
        assert is_state(m.statusword(), FAULT) and m.rig.faults == [EMCY_POSITIONING_CONTROLLER]


def test_a_drive_that_faults_after_the_first_record_holds_until_it_took_one(no_leaks):
    with clocked_drive(drive_behaviour=DriveBehaviour(ip_underflow="fault_after_first")) as m:
        m.ip_mode_set_up(transmission_type=255)
        m.drive.sdo[0x6040].raw = 0x1F
        m.sync()
        m.sync()
        assert is_state(m.statusword(), OPERATION_ENABLED) and m.rig.ip_underruns == 2
        m.rpdo1(800)
        m.sync()
        assert m.demand() == 800 and is_state(m.statusword(), OPERATION_ENABLED)
        m.sync()
        assert is_state(m.statusword(), FAULT) and m.drive.sdo[0x603F].raw == EMCY_POSITIONING_CONTROLLER

        for word in (0x00, 0x80, 0x00, 0x06, 0x07, 0x0F, 0x1F):  # fault reset, enable, ip mode again
            m.drive.sdo[0x6040].raw = word
        m.sync()  # a new start of ip mode: no record taken since, so it holds
        assert is_state(m.statusword(), OPERATION_ENABLED) and m.rig.faults == [EMCY_POSITIONING_CONTROLLER]


def test_underflow_behaviours_are_validated():
    assert DriveBehaviour().ip_underflow == "hold" and DriveBehaviour().requires_ip_period is False
    with pytest.raises(InvalidInputError, match="ip_underflow"):
        DriveBehaviour(ip_underflow="drop")
    with pytest.raises(InvalidInputError, match="requires_ip_period"):
        DriveBehaviour(requires_ip_period=1)


# -- CiA 402: 0x60C2, the interpolation time period (DriveBehaviour.requires_ip_period) ----------------------

def test_the_eds_has_the_interpolation_objects_with_their_cia_402_types():
    od = canopen.import_od(str(DRIVE_EDS), DRIVE_ID)
    period = od[0x60C2]
    assert (period[1].data_type, period[2].data_type) == (od_types.UNSIGNED8, od_types.INTEGER8)
    assert od[0x60C0].data_type == od_types.INTEGER16 and od[0x60C1][1].data_type == od_types.INTEGER32
    buffer = od[0x60C4]
    assert [buffer[sub].data_type for sub in range(1, 7)] == [
        od_types.UNSIGNED32, od_types.UNSIGNED32, od_types.UNSIGNED8, od_types.UNSIGNED16, od_types.UNSIGNED8,
        od_types.UNSIGNED8]
    assert not buffer[1].writable and not buffer[6].readable and buffer[6].writable


@pytest.mark.parametrize("cycle_period_us, value, index, faults", [
    (0, 0, -3, True),  # 0x60C2 not set
    (1000, 0, -3, True),
    (1000, 2, -3, True),  # 2 ms against a 1 ms SYNC
    (1000, 1, -3, False),
    (1000, 10, -4, False),  # the same 1 ms, written otherwise
    (0, 2, -3, False),  # 0x1006 not written: 0x60C2 alone says the period
])
def test_a_drive_that_requires_the_ip_period_checks_0x60c2_when_ip_mode_is_enabled(
        cycle_period_us, value, index, faults, no_leaks):
    with clocked_drive(drive_behaviour=DriveBehaviour(requires_ip_period=True)) as m:
        m.drive.nmt.state = "PRE-OPERATIONAL"
        m.drive.sdo[0x1006].raw = cycle_period_us
        m.drive.sdo[0x60C2][1].raw = value
        m.drive.sdo[0x60C2][2].raw = index
        assert (m.drive.sdo[0x60C2][1].raw, m.drive.sdo[0x60C2][2].raw) == (value, index)
        m.ip_mode_set_up()
        assert m.rig.faults == []  # enabling without bit 4 is not enabling ip mode
        m.drive.sdo[0x6040].raw = 0x1F
        word = m.statusword()
        if faults:
            assert is_state(word, FAULT) and not word & STATUSWORD_IP_MODE_ACTIVE
            assert m.drive.sdo[0x603F].raw == EMCY_PARAMETER_ERROR
            assert m.emcy_codes() == [EMCY_PARAMETER_ERROR]
        else:
            assert is_state(word, OPERATION_ENABLED) and word & STATUSWORD_IP_MODE_ACTIVE
            assert m.rig.faults == []


def test_ip_mode_that_becomes_active_by_the_drives_own_clock_is_checked_too(no_leaks):
    """Bit 4 already set when 0x6061 turns to 7 after a slow mode switch: ip mode becomes active at that
    instant of the drive's clock, with no frame to trigger it (scripted: ``next_event_s``/``run_due``)."""
    delay_s = 0.01
    behaviour = DriveBehaviour(requires_ip_period=True, mode_switch_delay_s=delay_s)
    with clocked_drive(drive_behaviour=behaviour) as m:
        m.drive.nmt.state = "PRE-OPERATIONAL"
        m.drive.sdo[0x60C2][1].raw = 2  # 2 ms
        m.drive.sdo[0x1006].raw = 1000  # against a 1 ms SYNC
        m.drive.sdo[0x6060].raw = CSP
        m.bus.stall(2 * delay_s)
        m.ip_mode_set_up(mode=CSP)
        m.drive.sdo[0x6040].raw = 0x1F  # bit 4 in CSP: nothing
        m.drive.sdo[0x6060].raw = IP_MODE
        assert m.rig.faults == []
        m.bus.stall(2 * delay_s)  # no SDO, no SYNC: only the drive's clock
        assert m.rig.faults == [EMCY_PARAMETER_ERROR] and m.emcy_codes() == [EMCY_PARAMETER_ERROR]
        assert is_state(m.statusword(), FAULT)


def test_without_0x1006_in_the_eds_0x60c2_is_the_only_period(tmp_path, no_leaks):
    eds = eds_without(DRIVE_EDS, [0x1006], tmp_path / "drive_without_1006.eds")
    with clocked_drive(drive_eds=eds, drive_behaviour=DriveBehaviour(requires_ip_period=True)) as m:
        m.drive.nmt.state = "PRE-OPERATIONAL"
        m.drive.sdo[0x60C2][1].raw = 5
        m.drive.sdo[0x60C2][2].raw = -3
        m.ip_mode_set_up()
        m.drive.sdo[0x6040].raw = 0x1F
        assert m.statusword() & STATUSWORD_IP_MODE_ACTIVE and m.rig.faults == []


def test_a_drive_that_does_not_require_the_ip_period_ignores_0x60c2(no_leaks):
    with clocked_drive() as m:
        m.ip_mode_set_up()
        assert m.drive.sdo[0x60C2][1].raw == 0
        m.drive.sdo[0x6040].raw = 0x1F
        assert m.statusword() & STATUSWORD_IP_MODE_ACTIVE and m.rig.faults == []


def test_requiring_the_ip_period_needs_0x60c2_in_the_eds(tmp_path):
    eds = eds_without(DRIVE_EDS, [0x60C2], tmp_path / "drive_without_60c2.eds")
    with pytest.raises(InvalidInputError, match="0x60C2"):
        SimulatedCanOpenRig(gearbox(), channel="unused", drive_eds=eds,
                            drive_behaviour=DriveBehaviour(requires_ip_period=True))


# -- CiA 402: 0x60C0 and the buffer configuration 0x60C4 -----------------------------------------------------

def test_only_linear_interpolation_is_selectable(no_leaks):
    with clocked_drive() as m:
        m.drive.nmt.state = "PRE-OPERATIONAL"
        assert m.abort_code(m.drive.sdo[0x60C0], 0) is None
        assert m.abort_code(m.drive.sdo[0x60C0], 1) == ABORT_VALUE_RANGE
        assert m.abort_code(m.drive.sdo[0x60C0], -1) == ABORT_VALUE_RANGE  # INTEGER16: negative is manufacturer's


def test_the_buffer_configuration_objects_follow_cia_402(no_leaks):
    with clocked_drive() as m:
        m.ip_mode_set_up(transmission_type=255)
        assert m.drive.sdo[0x60C4][1].raw == m.drive.sdo[0x60C4][2].raw == 64
        assert m.drive.sdo[0x60C4][5].raw == 4 and m.drive.sdo[0x60C4][3].raw == 0
        assert m.abort_code(m.drive.sdo[0x60C4][2], 0) == ABORT_VALUE_TOO_LOW
        assert m.abort_code(m.drive.sdo[0x60C4][2], 65) == ABORT_VALUE_TOO_HIGH
        assert m.abort_code(m.drive.sdo[0x60C4][1], 32) == ABORT_READ_ONLY
        assert m.abort_code(m.drive.sdo[0x60C4][4], 0) == ABORT_READ_ONLY
        assert m.abort_code(m.drive.sdo[0x60C4][3], 1) == ABORT_VALUE_RANGE  # FIFO only
        assert m.abort_code(m.drive.sdo[0x60C4][5], 8) == ABORT_VALUE_RANGE  # a record is 4 bytes
        assert m.abort_code(m.drive.sdo[0x60C4][6], 2) == ABORT_VALUE_RANGE
        with pytest.raises(canopen.SdoAbortedError) as refused:
            m.drive.sdo[0x60C4][6].raw  # noqa: B018  (write-only)
        assert refused.value.code == ABORT_WRITE_ONLY

        m.rpdo1(1, 2)
        assert m.buffer_position() == 2
        m.drive.sdo[0x60C4][2].raw = 2  # a new actual buffer size clears the buffer
        assert m.buffer_position() == 0 and m.drive.sdo[0x60C4][2].raw == 2
        m.rpdo1(1, 2, 3)  # the third finds the buffer full
        assert m.buffer_position() == 2 and m.rig.ip_overruns == 1
        m.drive.sdo[0x60C4][6].raw = 0  # clear and disable access
        m.rpdo1(4)
        assert m.buffer_position() == 0
        m.drive.sdo[0x60C4][6].raw = 1
        m.drive.sdo[0x60C1][1].raw = 5  # a record written by SDO is a record too
        assert m.buffer_position() == 1


# -- CiA 402: the motor rated torque 0x6076 scales the torque actual value 0x6077 -----------------------------------

def test_a_written_rated_torque_rescales_the_torque_actual_value_and_zero_is_refused(no_leaks):
    from pathlib import Path

    from sim_backend.plant_config import load_plant_config

    configs = Path(__file__).resolve().parents[2] / "configs"
    servo = load_plant_config(configs / "plants" / "pendulum_servo.toml").gearbox(seed=1)
    with clocked_drive(servo, drive_eds=configs / "eds" / "sim_servo_drive_cia402.eds") as m:
        m.ip_mode_set_up(mode=8)  # cyclic synchronous position: RPDO1 is the target 0x607A
        m.rpdo1(int(0.5 * (1 << 17) / (2 * 3.141592653589793)))  # hold the arm at 0.5 rad
        for _ in range(600):  # 6 s of the 100 Hz plant: the arm settles, the drive holds its weight
            m.sync()
        rated = m.drive.sdo[0x6076].raw
        held = m.drive.sdo[0x6077].raw
        # 9 mN m (the motor's torque limit); the drive holds part of the weight at 0.5 rad (121 per mille with no
        # friction; the load's stiction takes the rest)
        assert rated == 9 and 20 < held <= 121
        assert m.abort_code(m.drive.sdo[0x6076], 0) == 0x06090030  # per mille of nothing: value range
        m.drive.sdo[0x6076].raw = 2 * rated
        m.sync()
        assert abs(m.drive.sdo[0x6077].raw - held / 2) <= 1  # the same torque, per mille of twice the rating
