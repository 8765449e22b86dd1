"""A simulated CANopen rig: a CiA 402 servo drive and a CiA 406 absolute encoder, each a real
``canopen.LocalNode`` on a python-can bus (the ``virtual`` interface in tests), sharing one simulated
gearbox.

``LocalNode`` gives us the object dictionary (from the EDS files in ``configs/eds``), the SDO server and
NMT commands. This module adds what it lacks for a cyclic synchronous or interpolated position rig:

* PDO mapping taken from the object dictionary when the node enters OPERATIONAL (after the master has
  configured 0x1400/0x1600/0x1800/0x1A00 by SDO), TPDOs sent on SYNC (transmission type n: after every n-th
  SYNC), and no PDO traffic outside OPERATIONAL (NMT gating; no SDO in STOPPED either);
* RPDOs as CiA 301 has them (0x1400 + n sub 2): a synchronous RPDO (transmission type 0..240) has one
  receive buffer, a frame overwrites the one before, and the data are written into the dictionary at the
  next SYNC, before that SYNC's cycle uses them; an event-driven one (254, 255) at once; other types are
  refused by SDO (abort 0x06090030);
* the CiA 402 state machine on 0x6040/0x6041 (:mod:`rig.protocols.cia402`; the drive's side in
  :mod:`sim_backend.canopen_drive_states`), by default with the target
  set to the actual position on enable (no jump); statusword bit 12 in CSP = "drive follows the command
  value", in interpolated position = "ip mode active" (controlword bit 4 in OPERATION ENABLED);
* interpolated position mode (0x6060 = 7): 0x60C0 (linear only), 0x60C2 interpolation time period and the
  FIFO of interpolation data records 0x60C1:1 configured by 0x60C4
  (:class:`~sim_backend.interpolation_buffer.InterpolationBuffer`); with ip mode active each SYNC takes
  the oldest record as its target;
* the plant: on each SYNC in OPERATION ENABLED, from the first target (RPDO, or a record with ip mode
  active) on, the drive applies its target (0x607A) and the gearbox advances exactly one sample; the position demand value 0x6062 is the target it applied, the actual
  position 0x6064 follows it (an ideal drive); the encoder's position value (0x6004) is the gearbox's
  encoder reading; with an EDS that has 0x6077 (``configs/eds/sim_servo_drive_cia402.eds``) on a plant that
  models a motor, the torque actual value 0x6077 is the motor's torque at that SYNC
  (:mod:`sim_backend.drive_torque`);
* EMCY, 0x603F and the error register 0x1001 on a fault, heartbeats (0x1017) from both nodes;
* the encoder's resolution objects (0x6001, 0x6002, 0x6501, 0x6502) and code sequence (0x6000) from the
  gearbox's EncoderResolution;
* the legal behaviours of real devices, switched on by :class:`~sim_backend.canopen_behaviour.DriveBehaviour`
  and :class:`~sim_backend.canopen_behaviour.EncoderBehaviour` (slow fault reset, slow mode switch, enable
  only with SYNC, SYNC watchdog, TPDO latency, static PDOs, quick stop options, NMT state on fault, an
  empty interpolation buffer that faults, 0x60C2 required, ...);
* a count of every frame on the bus, for the bus load against the configured bit rate.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import can
import canopen

from identify.validation import InvalidInputError
from rig.protocols import cia402
from rig.protocols.can_bus_load import frame_bits
from rig.protocols.can_interfaces import echoes_own_frames, open_bus, receive_drops
from sim_backend.canopen_behaviour import (
    EMCY_ERROR_RESET, EMCY_FOLLOWING_ERROR, EMCY_POSITIONING_CONTROLLER,
    DriveBehaviour, EncoderBehaviour, NodeBehaviour, error_register_for,
)
from sim_backend.canopen_drive_states import CLOCK_TICK_S, CanOpenDriveStates
from sim_backend.canopen_pdos import (
    RPDO_COMMUNICATION_INDICES, RpdoReception, RpdoValues, Tpdo, is_rpdo_transmission_type,
)
from sim_backend.device_record import AppliedTargets, DeviceRecord
from sim_backend.drive_torque import drive_torque_of
from sim_backend.eds_variants import eds_text, is_pdo_parameter, load_eds_text, static_pdo_access, with_entries
from sim_backend.interpolation_buffer import InterpolationBuffer
from sim_backend.plant import SimulatedGearbox
from sim_backend.wire_time_bus import FrameCounter, InterfaceBus, WireTimeBus

__all__ = ["DRIVE_EDS", "EDS_DIRECTORY", "ENCODER_EDS", "SimulatedCanOpenRig", "u32_range"]

EDS_DIRECTORY = Path(__file__).resolve().parents[1] / "configs" / "eds"
DRIVE_EDS = EDS_DIRECTORY / "sim_drive_cia402.eds"
ENCODER_EDS = EDS_DIRECTORY / "sim_encoder_cia406.eds"
SYNC_COB_ID = 0x80
SDO_ABORT_VALUE_RANGE = 0x06090030  # CiA 301: value range of parameter exceeded
SDO_ABORT_READ_ONLY = 0x06010002  # CiA 301: attempt to write a read only object
FOLLOWING_ERROR_OFF = 0xFFFFFFFF  # CiA 402 0x6065: the following error is not supervised
NOTIFIER_CYCLE_S = 0.05  # how often the notifier thread looks up from an idle bus: close() waits that long
_ENCODER_FIXED_OBJECTS = (0x6000, 0x6001, 0x6002, 0x6003)  # set from the plant's encoder: not changeable
CONTROLWORD_ENABLE_IP_MODE = 0x0010  # bit 4 in interpolated position mode (CiA 402)


def u32_range(value: int) -> int:
    """An UNSIGNED32 range object (CiA 406 0x6001, 0x6002, 0x6501) for a range of ``value`` counts: 2**32
    is written as 0, the convention of CiA 406 encoders with a full 32-bit range (TR-Electronic's CiA 406
    manuals: "it can be set 0 to display the value 0x100000000"); CiA 406 has no other encoding for it."""
    if value == 1 << 32:
        return 0
    if not 0 < value < 1 << 32:
        raise InvalidInputError(f"a CiA 406 range must lie in 1..2**32 counts, got {value}")
    return value


def _vendor_eds_text(text: str, behaviour: NodeBehaviour) -> str:
    """The EDS of a device with ``behaviour``: for ``static_pdos`` the PDO parameters read-only and the static
    TPDO1 layout; a drive's interpolation buffer capacity (0x60C4:1/2, ``ip_buffer_records``)."""
    records = getattr(behaviour, "ip_buffer_records", None)
    if records is not None:
        try:
            text = with_entries(text, defaults={(0x60C4, 1): records, (0x60C4, 2): records})
        except KeyError as err:
            raise InvalidInputError(f"drive_behaviour.ip_buffer_records: the drive's EDS has no 0x60C4 "
                                    f"(interpolation data configuration): {err}") from err
    if not behaviour.static_pdos:
        return text
    defaults: dict[tuple[int, int], int] = {}
    if behaviour.static_tpdo_transmission_type is not None:
        defaults[(0x1800, 2)] = behaviour.static_tpdo_transmission_type
    if behaviour.static_tpdo_mapping is not None:
        defaults[(0x1A00, 0)] = len(behaviour.static_tpdo_mapping)
        for subindex in range(1, 9):
            mapping = behaviour.static_tpdo_mapping
            defaults[(0x1A00, subindex)] = mapping[subindex - 1] if subindex <= len(mapping) else 0
    return with_entries(text, access=static_pdo_access(text), defaults=defaults)


class SimulatedCanOpenRig(CanOpenDriveStates):
    """Drive (CiA 402) and load encoder (CiA 406) of a simulated gearbox on one CAN bus.

    Parameters
    ----------
    gearbox
        The plant; stepped once per SYNC while the drive is in OPERATION ENABLED.
    channel
        The python-can channel the nodes join (the master joins the same channel).
    interface, port
        The python-can interface of ``channel`` (default ``virtual``: in this process, frames stamped with
        their wire time); ``udp_multicast`` with its ``port`` puts the devices in a process of their own
        (:mod:`sim_backend.can_device_process`), where the master stamps each frame on arrival.
    drive_node_id, encoder_node_id
        Node-IDs of the two devices.
    drive_counts_per_revolution
        Drive position units per motor revolution.
    bitrate
        The bus's bit rate, for :meth:`bus_load`.
    drive_behaviour, encoder_behaviour
        Legal behaviours of real devices (:mod:`sim_backend.canopen_behaviour`); the defaults are the
        forgiving devices this simulator always had.
    drive_eds, encoder_eds
        The devices' object dictionaries (default ``configs/eds``); e.g. a variant without optional objects
        (:func:`sim_backend.eds_variants.eds_without`). The device then lacks those objects too.
    silent_seqs
        Sample numbers (SYNCs counted from 0 in OPERATION ENABLED) after which the encoder sends no TPDO
        (the plant still steps): injected frame loss.
    silent_drive_seqs
        The same for the drive's TPDOs (e.g. ``range(50, 100_000)``: a drive that goes silent at sample 50 while
        its heartbeat goes on).
    fault_at_seq, fault_code
        At that sample the drive faults instead of moving (once): EMCY with ``fault_code``, 0x603F =
        ``fault_code``, 0x1001, FAULT state.
    stop_heartbeat_at_seq
        At that sample both nodes stop their heartbeats (a device that fell off the bus).
    disable_at_seq
        At that sample the drive drops out of OPERATION ENABLED without a fault (enable input or safe torque
        off lost; once); its TPDOs go on, with the new statusword.
    error_frame_at
        ``(error class bits, sample)``: an error frame (:mod:`rig.protocols.can_error_frames`) goes on the
        bus before that sample's TPDOs, e.g. a protocol violation or bus-off.
    delayed_tpdo
        ``(seconds, sample)``: the encoder's TPDO answering that sample goes on the bus this much later,
        after later SYNCs (a device that misses its synchronous window; frames out of order).
    refuse_sdo_index
        The drive aborts every SDO write to this object (abort code 0x06090030, value range exceeded), as a
        drive that does not support a mode or mapping the master configures.
    clock
        The devices' clock in seconds (:func:`time.monotonic`): every timed behaviour (a slow fault reset or
        mode switch, the SYNC watchdog, a delayed TPDO, the bus load) reads it. A scripted test passes a
        simulated clock together with a bus on it (:meth:`start`).
    hold_plant_until_first_target
        True (for the driver's tests and the simulated rigs of ``rig run``): the gearbox stays exactly at
        rest from enabling until the first target (RPDO) is applied or ip mode is active with a record in
        the buffer, so that a run's samples do not depend on how many SYNCs the host let pass between
        enabling and its first setpoint (a real gearbox at rest with its target at the actual position does
        not move either; only the simulated noise would be drawn). An empty buffer with ip mode active still
        faults a drive whose ``ip_underflow`` says so. False: the drive acts on every SYNC in OPERATION
        ENABLED, as a device-level test of a stale target at enable needs.
    """

    def __init__(self, gearbox: SimulatedGearbox, *, channel: str, interface: str = "virtual", port: int | None = None,
                 drive_node_id: int = 1, encoder_node_id: int = 2, drive_counts_per_revolution: int = 1 << 17,
                 bitrate: int = 1_000_000, drive_behaviour: DriveBehaviour | None = None,
                 encoder_behaviour: EncoderBehaviour | None = None, drive_eds: str | Path = DRIVE_EDS,
                 encoder_eds: str | Path = ENCODER_EDS, silent_seqs: Iterable[int] = (),
                 fault_at_seq: int | None = None, fault_code: int = 0x7500, stop_heartbeat_at_seq: int | None = None,
                 disable_at_seq: int | None = None, refuse_sdo_index: int | None = None,
                 delayed_tpdo: tuple[float, int] | None = None,
                 error_frame_at: tuple[int, int] | None = None, hold_plant_until_first_target: bool = True,
                 silent_drive_seqs: Iterable[int] = (), clock: Callable[[], float] = time.monotonic) -> None:
        self.gearbox = gearbox
        self.clock = clock
        self.hold_plant_until_first_target = bool(hold_plant_until_first_target)
        self.channel, self.interface, self.port = channel, interface, port
        self.drive_scaling = cia402.DriveScaling(int(drive_counts_per_revolution))
        self.bitrate = int(bitrate)
        self.drive_behaviour = DriveBehaviour() if drive_behaviour is None else drive_behaviour
        self.encoder_behaviour = EncoderBehaviour() if encoder_behaviour is None else encoder_behaviour
        if not isinstance(self.drive_behaviour, DriveBehaviour):
            raise InvalidInputError(f"drive_behaviour: expected a DriveBehaviour, got {drive_behaviour!r}")
        if not isinstance(self.encoder_behaviour, EncoderBehaviour):
            raise InvalidInputError(f"encoder_behaviour: expected an EncoderBehaviour, got {encoder_behaviour!r}")
        encoder = gearbox.encoder
        if encoder.bits + encoder.multi_turn_bits > 32:
            raise InvalidInputError(
                f"encoder: a CiA 406 position value (0x6004) is UNSIGNED32; {encoder.bits}+{encoder.multi_turn_bits} "
                "bits do not fit")
        self.silent_seqs = frozenset(silent_seqs)
        self.silent_drive_seqs = frozenset(silent_drive_seqs)
        self.fault_at_seq = fault_at_seq
        self.fault_code = fault_code
        self.stop_heartbeat_at_seq = stop_heartbeat_at_seq
        self.disable_at_seq = disable_at_seq
        self.refuse_sdo_index = refuse_sdo_index
        self.delayed_tpdo = delayed_tpdo
        self.error_frame_at = error_frame_at
        self.network: canopen.Network | None = None
        self.drive_eds_text = _vendor_eds_text(eds_text(drive_eds), self.drive_behaviour)
        self.encoder_eds_text = _vendor_eds_text(eds_text(encoder_eds), self.encoder_behaviour)
        self.drive = canopen.LocalNode(drive_node_id, load_eds_text(self.drive_eds_text, Path(drive_eds).name))
        self.encoder = canopen.LocalNode(encoder_node_id, load_eds_text(self.encoder_eds_text, Path(encoder_eds).name))
        self.torque = drive_torque_of(gearbox, str(drive_eds), 0x6077 in self.drive.object_dictionary)
        if self.torque is not None:
            self._store(self.drive, 0x6076, self.torque.rated_torque_mnm, 4)
        self.state = cia402.DriveState.SWITCH_ON_DISABLED
        self.controlword = 0
        self.controlwords: list[int] = []
        self.setpoints = 0  # SYNCs sampled since the first target (RPDO) in OPERATION ENABLED
        # what the drive really did, sample by sample (on disk, for comparing a master's log with it): sample k's
        # target (drive counts), i.e. the position demand 0x6062 after the k-th sampled SYNC;
        # position_before_samples = the actual position 0x6064 just before sample 0 (the step into the first
        # target counts as a step too)
        self.applied_targets = AppliedTargets()
        self.position_before_samples: int | None = None
        self.streaming = False  # the plant holds exactly at rest until the first target arrives
        if self.drive_behaviour.requires_ip_period and 0x60C2 not in self.drive.object_dictionary:
            raise InvalidInputError("drive_behaviour.requires_ip_period: the drive's EDS has no 0x60C2 "
                                    "(interpolation time period)")
        self.interpolation = self._interpolation_buffer()
        self._ip_was_active = False  # ip mode active at the last look (_follow_ip_mode)
        self._rpdos = RpdoReception()
        self.syncs = 0
        self._answered = threading.Condition()  # SYNCs whose TPDOs are on the bus: wait_for_answers
        self.syncs_answered = 0
        self.homed = False
        self.faults: list[int] = []  # error codes of every fault the drive entered, in order
        self._counter = FrameCounter(clock)
        self._lock = threading.RLock()
        self._operational: set[int] = set()
        self._tpdos: dict[int, list[Tpdo]] = {}
        self._started = False
        self._mode_display = self._i8(self.drive, 0x6060) if 0x6060 in self.drive.object_dictionary else 0
        self._mode_pending: tuple[int, float] | None = None
        self._reset_due: float | None = None
        self._quick_stop_since: float | None = None
        self._enabled_at = 0.0
        self._sync_times: collections.deque[float] = collections.deque(maxlen=3)
        self._following_error = False
        self._warning_registers: dict[int, int] = {}  # node-ID -> error register bits of an active warning
        self._one_shots: set[str] = set()
        self._clock: threading.Thread | None = None
        self._clock_stop = threading.Event()
        self._scripted = False  # started on a scripted bus: no threads, the bus calls next_event_s/run_due
        self._next_tick_s = 0.0  # scripted: when the drive's clock ticks next (CLOCK_TICK_S)
        self._late_frames: list[tuple[float, can.Message]] = []  # scripted: delayed TPDOs, (when due, frame)

    def _interpolation_buffer(self) -> InterpolationBuffer:
        """The FIFO of 0x60C4; a drive without 0x60C4 has the one-record buffer of CiA 402, always open."""
        if 0x60C4 not in self.drive.object_dictionary:
            buffer = InterpolationBuffer(1, 1)
            buffer.clear(enable_access=True)
            return buffer
        max_records, size_records = (int.from_bytes(self.drive.get_data(0x60C4, sub), "little") for sub in (1, 2))
        return InterpolationBuffer(max_records, size_records)

    @property
    def ip_underruns(self) -> int:
        """SYNCs with ip mode active that found the interpolation buffer empty."""
        return self.interpolation.underflows

    @property
    def ip_overruns(self) -> int:
        """Interpolation data records that found the buffer full (discarded)."""
        return self.interpolation.overflows

    @property
    def ip_levels(self) -> list[int]:
        """The records each SYNC with ip mode active found in the buffer, before taking one: the last
        :data:`~sim_backend.interpolation_buffer.LEVELS_KEPT` SYNCs' (all of a shorter run's)."""
        return list(self.interpolation.levels)

    # -- lifecycle ------------------------------------------------------------------------------------------

    def start(self, bus: object | None = None) -> SimulatedCanOpenRig:
        """Join the bus: :attr:`channel` of :attr:`interface` with a notifier thread (default),
        or a scripted ``bus`` on the devices' :attr:`clock`, which feeds the network itself (``bus.join(network)``)
        and calls :meth:`next_event_s` / :meth:`run_due` instead of the drive's clock thread
        (``tests/transports/clocked_canopen.py``). The bus must offer ``send_at(message, wire_time)``."""
        self._scripted = bus is not None
        if bus is None and self.interface != "virtual":
            self.network = canopen.Network(InterfaceBus(
                open_bus(self.interface, self.channel, port=self.port, bitrate=self.bitrate), self._counter,
                echoes_own_frames=echoes_own_frames(self.interface)))
            self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
            self.network.connect()
        elif bus is None:
            self.network = canopen.Network(WireTimeBus(self.channel, self._counter))
            self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
            self.network.connect()
        else:
            self.network = canopen.Network(bus)
            bus.join(self.network)
        self.network.notifier.add_listener(self._counter)
        for node in (self.drive, self.encoder):
            self.network.add_node(node)
            self._gate_sdo_when_stopped(node)
        self.drive.add_write_callback(self._on_drive_write)
        self.drive.add_read_callback(self._on_drive_read)
        self.encoder.add_write_callback(self._on_encoder_write)
        self.network.subscribe(0, self._on_nmt)  # after the nodes' own NMT handlers
        self.network.subscribe(SYNC_COB_ID, self._on_sync)
        encoder = self.gearbox.encoder
        self._store(self.encoder, 0x6501, u32_range(encoder.counts_per_revolution), 4)
        self._store(self.encoder, 0x6001, u32_range(encoder.counts_per_revolution), 4)
        # CiA 406 0x6502 is UNSIGNED16: 2**16 revolutions and more keep only the low 16 bits (0 for 2**16),
        # so a master takes the number of revolutions from 0x6002 / 0x6001
        self._store(self.encoder, 0x6502, (1 << encoder.multi_turn_bits) & 0xFFFF, 2)
        self._store(self.encoder, 0x6002, u32_range(encoder.modulus), 4)
        self._store(self.encoder, 0x6000, 0 if encoder.direction > 0 else 1, 2)
        behaviour = self.drive_behaviour
        self._store(self.drive, 0x607A, behaviour.initial_target_counts, 4, signed=True)
        if behaviour.following_error_window_counts is not None:
            self._store(self.drive, 0x6065, behaviour.following_error_window_counts, 4)
        if behaviour.quick_stop_option is not None:
            self._store(self.drive, 0x605A, behaviour.quick_stop_option, 2, signed=True)
        for node in (self.drive, self.encoder):
            node.nmt.state = "PRE-OPERATIONAL"  # boot-up message, heartbeat per 0x1017
        self._started = True
        self._next_tick_s = self.clock() + CLOCK_TICK_S
        if behaviour.needs_clock and not self._scripted:
            self._clock_stop.clear()
            self._clock = threading.Thread(target=self._run_clock, name="sim-canopen-drive-clock", daemon=True)
            self._clock.start()
        return self

    def close(self) -> None:
        """Stop the drive's clock and the heartbeats, leave the bus and stop the notifier thread
        (idempotent)."""
        if not self._started:
            return
        self._started = False
        if self._clock is not None:
            self._clock_stop.set()
            self._clock.join()
            self._clock = None
        for node in (self.drive, self.encoder):
            node.nmt.stop_heartbeat()
        self.network.disconnect()
        self.network = None
        self.applied_targets.close()

    def next_event_s(self) -> float:
        """Scripted bus: when the devices next do something no frame triggers (a tick of the drive's clock,
        :data:`CLOCK_TICK_S`, where its behaviour has timed transitions; a delayed TPDO); inf for nothing."""
        with self._lock:
            due = [when for when, _ in self._late_frames]
            if self.drive_behaviour.needs_clock and self._started:
                due.append(self._next_tick_s)
            return min(due, default=float("inf"))

    def run_due(self) -> None:
        """Scripted bus: do what is due by :attr:`clock`'s time (the drive's clock thread's work, delayed
        TPDOs)."""
        now = self.clock()
        with self._lock:
            if self.drive_behaviour.needs_clock and self._started and now >= self._next_tick_s:
                self._advance_locked(now)
                while self._next_tick_s <= now:
                    self._next_tick_s += CLOCK_TICK_S
            due = [frame for when, frame in self._late_frames if when <= now]
            self._late_frames = [(when, frame) for when, frame in self._late_frames if when > now]
        for frame in due:
            self.network.bus.send_at(frame, now)

    def record(self) -> DeviceRecord:
        """What the drive did: the target applied at each sample, and (interpolated position) the SYNCs that found
        its buffer empty; a CSP drive cannot tell a held target from a repeated one."""
        with self._lock:
            bus = None if self.network is None else self.network.bus
            return DeviceRecord(self.applied_targets.array(), tuple(self.controlwords), self.ip_underruns,
                                receive_drops=None if bus is None else receive_drops(bus),
                                position_before_counts=self.position_before_samples)

    def __enter__(self) -> SimulatedCanOpenRig:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def bus_load(self) -> float:
        """Fraction of the bit rate used by every frame seen since start (worst-case bit stuffing)."""
        elapsed = self.clock() - self._counter.started
        return self._counter.bits / (elapsed * self.bitrate) if elapsed > 0 else 0.0

    @property
    def frames(self) -> int:
        return self._counter.frames

    def write_eds(self, directory: str | Path) -> tuple[Path, Path]:
        """Write the EDS files that describe these devices as they behave (what their vendor would ship,
        e.g. with read-only PDO parameters for ``static_pdos``) into ``directory``; returns (drive,
        encoder) paths, for a master's ``drive_eds``/``encoder_eds``."""
        directory = Path(directory)
        paths = (directory / f"sim_drive_{self.drive.id}.eds", directory / f"sim_encoder_{self.encoder.id}.eds")
        for path, text in zip(paths, (self.drive_eds_text, self.encoder_eds_text)):
            path.write_text(text)
        return paths

    def inject_fault(self, code: int) -> None:
        """Fault the drive now with EMCY ``code`` (tests)."""
        with self._lock:
            self._fault_locked(code)

    # -- object dictionary hooks -------------------------------------------------------------------------

    def _on_drive_read(self, index: int, subindex: int, od: object) -> int | None:
        if index == 0x6041:
            with self._lock:
                self._advance_locked(self.clock())
                return self._statusword_locked()
        if index == 0x6061:
            with self._lock:
                self._advance_locked(self.clock())
                return self._mode_display
        if (index, subindex) == (0x60C4, 4):  # buffer position: with a FIFO, the records held (CiA 402)
            with self._lock:
                return len(self.interpolation)
        return None

    def _on_drive_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        if index == self.refuse_sdo_index:
            raise canopen.SdoAbortedError(SDO_ABORT_VALUE_RANGE)
        if self.drive_behaviour.static_pdos and is_pdo_parameter(index):
            raise canopen.SdoAbortedError(SDO_ABORT_READ_ONLY)
        value = od.decode_raw(data)  # type: ignore[attr-defined]
        if index in RPDO_COMMUNICATION_INDICES and subindex == 2 and not is_rpdo_transmission_type(value):
            raise canopen.SdoAbortedError(SDO_ABORT_VALUE_RANGE)
        with self._lock:
            if index == 0x6060:
                delay_s = self.drive_behaviour.mode_switch_delay_s
                if delay_s > 0:
                    self._mode_pending = (value, self.clock() + delay_s)
                else:
                    self._mode_display, self._mode_pending = value, None
                    self._follow_ip_mode()
            elif index == 0x6040:
                self._on_controlword(value, self.clock())
                self._follow_ip_mode()
            elif index == 0x6076 and value == 0:  # the torque actual value is per mille of it
                raise canopen.SdoAbortedError(SDO_ABORT_VALUE_RANGE)
            elif index == 0x60C0 and value != 0:  # interpolation sub-mode: linear (0) only
                raise canopen.SdoAbortedError(SDO_ABORT_VALUE_RANGE)
            elif (index, subindex) == (0x60C1, 1):  # each record applied, by SDO or RPDO, goes to the buffer
                self.interpolation.append(value)
            elif index == 0x60C4:
                self.interpolation.configure(subindex, value)

    def _on_encoder_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        if self.encoder_behaviour.static_pdos and is_pdo_parameter(index):
            raise canopen.SdoAbortedError(SDO_ABORT_READ_ONLY)
        if index in _ENCODER_FIXED_OBJECTS and bytes(data) != self.encoder.get_data(index, subindex):
            # the simulated encoder has no scaling function (0x6000 bit 2), no preset and a fixed code sequence
            raise canopen.SdoAbortedError(SDO_ABORT_VALUE_RANGE)

    def _gate_sdo_when_stopped(self, node: canopen.LocalNode) -> None:
        """CiA 301: a node in STOPPED answers no SDO (only NMT and heartbeat)."""
        handler = node.sdo.on_request
        self.network.unsubscribe(node.sdo.rx_cobid, handler)

        def gated(can_id: int, data: bytes, timestamp: float) -> None:
            if node.nmt.state != "STOPPED":
                handler(can_id, data, timestamp)

        self.network.subscribe(node.sdo.rx_cobid, gated)

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            self._follow_nmt_states()

    def _follow_nmt_states(self) -> None:
        for node in (self.drive, self.encoder):
            if node.nmt.state == "OPERATIONAL" and node.id not in self._operational:
                self._operational.add(node.id)
                self._configure_pdos(node)
            elif node.nmt.state != "OPERATIONAL" and node.id in self._operational:
                self._operational.discard(node.id)
                if node is self.drive:
                    self._rpdos.clear()
                for pdo_map in list(node.rpdo.map.values()):
                    if pdo_map.cob_id and pdo_map.on_message in self.network.subscribers.get(pdo_map.cob_id, ()):
                        self.network.unsubscribe(pdo_map.cob_id, pdo_map.on_message)

    def _configure_pdos(self, node: canopen.LocalNode) -> None:
        """Take the PDO mapping the master wrote by SDO (or the EDS default) from the dictionary."""
        node.tpdo.read(from_od=False)
        self._tpdos[node.id] = [
            Tpdo(pdo_map.cob_id, [(variable.index, variable.subindex, variable.length // 8) for variable in pdo_map
                                  if variable.length], pdo_map.trans_type)
            for pdo_map in node.tpdo.map.values()
            if pdo_map.enabled and pdo_map.trans_type is not None and 1 <= pdo_map.trans_type <= 240]
        if node is self.drive:
            node.rpdo.read(from_od=False)  # subscribes the enabled RPDOs
            for pdo_map in node.rpdo.map.values():
                if pdo_map.enabled and not pdo_map.callbacks:
                    pdo_map.add_callback(self._on_rpdo)

    def _on_rpdo(self, pdo_map: object) -> None:
        """An RPDO received: applied now if event-driven, else at the next SYNC (CiA 301, by the transmission
        type in 0x1400 + n sub 2; :class:`~sim_backend.canopen_pdos.RpdoReception`)."""
        communication = pdo_map.com_record.od.index  # type: ignore[attr-defined]
        with self._lock:
            values = self._rpdos.receive(pdo_map, int.from_bytes(self.drive.get_data(communication, 2), "little"))
            if values is not None:
                self._apply_rpdo(values)

    def _apply_rpdo(self, values: RpdoValues) -> None:
        """RPDO data written to the mapped objects (the write hooks act on them: a controlword, a record
        into the interpolation buffer); a value the drive refuses is not written. A target position (0x607A)
        in OPERATION ENABLED is the first target; an interpolation data record (0x60C1) is not: it waits in
        the buffer until ip mode takes it (:meth:`_plant_runs`)."""
        target = False
        for index, subindex, data in values:
            try:
                self.drive.set_data(index, subindex, data)
            except canopen.SdoAbortedError:
                continue
            target = target or index == 0x607A
        self.streaming = self.streaming or (target and self.state is cia402.DriveState.OPERATION_ENABLED)

    @staticmethod
    def _store(node: canopen.LocalNode, index: int, value: int, size: int, *, signed: bool = False) -> None:
        """Set an object the device owns, if its dictionary has it (a variant EDS may lack it)."""
        if index in node.object_dictionary:
            node.data_store.setdefault(index, {})[0] = value.to_bytes(size, "little", signed=signed)

    @staticmethod
    def _i32(node: canopen.LocalNode, index: int) -> int:
        return int.from_bytes(node.get_data(index, 0), "little", signed=True)

    @staticmethod
    def _i8(node: canopen.LocalNode, index: int) -> int:
        return int.from_bytes(node.get_data(index, 0), "little", signed=True)

    @staticmethod
    def _u(node: canopen.LocalNode, index: int) -> int | None:
        if index not in node.object_dictionary:
            return None
        return int.from_bytes(node.get_data(index, 0), "little")

    # -- the cycle -------------------------------------------------------------------------------------------

    def _once(self, name: str, happens: bool) -> bool:
        if happens and name not in self._one_shots:
            self._one_shots.add(name)
            return True
        return False

    def _ip_active(self) -> bool:
        return (self._mode_display == cia402.INTERPOLATED_POSITION_MODE
                and self.state is cia402.DriveState.OPERATION_ENABLED
                and bool(self.controlword & CONTROLWORD_ENABLE_IP_MODE))

    def _plant_runs(self) -> bool:
        """Whether this SYNC in OPERATION ENABLED is a sample: from the first target on (an RPDO applied in
        OPERATION ENABLED outside interpolated position, or a record in the buffer with ip mode active), or
        always where the plant is not held until the first target."""
        self.streaming = self.streaming or (self._ip_active() and len(self.interpolation) > 0)
        return self.streaming or not self.hold_plant_until_first_target

    def _step_locked(self) -> None:
        """One SYNC in OPERATION ENABLED: apply the target (or hold), step the plant, latch the values. With
        ip mode active the target is the oldest record of the FIFO; on an empty FIFO the drive holds the last
        one (an underrun) or faults with 0x8600 (``ip_underflow``)."""
        if self._ip_active():
            record = self.interpolation.take()
            if record is not None:
                self._store(self.drive, 0x607A, record, 4, signed=True)
            elif self.interpolation.underflow_faults(self.drive_behaviour.ip_underflow):
                self._fault_locked(EMCY_POSITIONING_CONTROLLER)
                return
        target = self._i32(self.drive, 0x607A)
        actual = self._i32(self.drive, 0x6064)
        follows = self._mode_display == cia402.CYCLIC_SYNCHRONOUS_POSITION_MODE or self._ip_active()
        if follows and not self.drive_behaviour.copy_target_on_enable:
            window = self._u(self.drive, 0x6065)
            if window is not None and window != FOLLOWING_ERROR_OFF and abs(target - actual) > window:
                self._fault_locked(EMCY_FOLLOWING_ERROR)
                return
        applied = target if follows else actual  # statusword bit 12 clear: the drive holds its position
        if self.position_before_samples is None:
            self.position_before_samples = actual
        self.applied_targets.append(applied)
        sample = self.gearbox.step(self.drive_scaling.rad_from_counts(applied))
        applied_bytes = applied.to_bytes(4, "little", signed=True)
        self.drive.data_store.setdefault(0x6064, {})[0] = applied_bytes
        self._store(self.drive, 0x6062, applied, 4, signed=True)
        if self.torque is not None:
            rated = self._u(self.drive, 0x6076) or self.torque.rated_torque_mnm
            self._store(self.drive, 0x6077, self.torque.per_mille(sample.motor_torque_nm, rated), 2, signed=True)
        self.encoder.data_store.setdefault(0x6004, {})[0] = (sample.encoder_counts & 0xFFFFFFFF).to_bytes(4, "little")
        self.setpoints += 1

    def _warnings_locked(self, number: int) -> None:
        for node, behaviour in ((self.drive, self.drive_behaviour), (self.encoder, self.encoder_behaviour)):
            faulted = node is self.drive and self.state is cia402.DriveState.FAULT
            fault = error_register_for(self.faults[-1]) if faulted else 0
            if self._once(f"warning {node.id}", number == behaviour.emcy_warning_at_seq):
                register = error_register_for(behaviour.emcy_warning_code)
                self._warning_registers[node.id] = register
                self._store(node, 0x1001, register | fault, 1)
                node.emcy.send(behaviour.emcy_warning_code, register=register | fault)
            if self._once(f"warning cleared {node.id}", number == behaviour.emcy_warning_cleared_at_seq):
                self._warning_registers.pop(node.id, None)
                self._store(node, 0x1001, fault, 1)
                node.emcy.send(EMCY_ERROR_RESET, register=fault)

    def _latch_locked(self, node: canopen.LocalNode, tpdo: Tpdo) -> bytes:
        return b"".join(node.get_data(index, subindex)[:size] for index, subindex, size in tpdo.entries)

    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        now = self.clock()
        frames: list[tuple[canopen.LocalNode, can.Message]] = []
        with self._lock:
            self._sync_times.append(now)
            self._advance_locked(now)
            for values in self._rpdos.take_latched():  # synchronous RPDOs: before this SYNC's cycle
                self._apply_rpdo(values)
            behaviours = {self.drive.id: self.drive_behaviour, self.encoder.id: self.encoder_behaviour}
            for node in (self.drive, self.encoder):  # what a late-answering device sends first
                latency = behaviours[node.id].tpdo_latency_cycles
                for tpdo in self._tpdos.get(node.id, ()) if node.id in self._operational else ():
                    if not tpdo.primed:
                        tpdo.history.extend([self._latch_locked(node, tpdo)] * latency)
                        tpdo.primed = True
            silent = silent_drive = False
            delay_s = None
            if self.state is not cia402.DriveState.OPERATION_ENABLED:
                self.streaming = False
            enabled = self.state is cia402.DriveState.OPERATION_ENABLED and self.drive.id in self._operational
            if enabled and not self._plant_runs():
                if self._ip_active() and self.interpolation.underflow_faults(self.drive_behaviour.ip_underflow):
                    self._fault_locked(EMCY_POSITIONING_CONTROLLER)
            elif enabled:
                number = self.setpoints
                if self._once("fault", self.fault_at_seq is not None and number == self.fault_at_seq):
                    self._fault_locked(self.fault_code)
                elif self._once("disable", number == self.disable_at_seq):
                    self.state = cia402.DriveState.SWITCH_ON_DISABLED
                else:
                    self._step_locked()
                self._warnings_locked(number)
                if self.stop_heartbeat_at_seq is not None and number == self.stop_heartbeat_at_seq:
                    for node in (self.drive, self.encoder):
                        node.nmt.stop_heartbeat()
                silent = number in self.silent_seqs
                silent_drive = number in self.silent_drive_seqs
                delay_s = self.delayed_tpdo[0] if self.delayed_tpdo and number == self.delayed_tpdo[1] else None
                if self.error_frame_at is not None and number == self.error_frame_at[1]:
                    self.network.bus.send(can.Message(arbitration_id=self.error_frame_at[0], is_error_frame=True,
                                                      dlc=8, data=bytes(8), is_extended_id=False))
            self.syncs += 1
            for node in (self.drive, self.encoder):
                if node.id not in self._operational:
                    continue
                for tpdo in self._tpdos.get(node.id, ()):
                    tpdo.history.append(self._latch_locked(node, tpdo))
                    payload = tpdo.history.popleft()
                    tpdo.count += 1
                    muted = silent if node is self.encoder else silent_drive
                    if tpdo.count % tpdo.every or muted:
                        continue
                    frames.append((node, can.Message(arbitration_id=tpdo.cob_id, data=payload, is_extended_id=False)))
        wire_time = timestamp + frame_bits(len(data)) / self.bitrate
        bus = self.network.bus
        for node, frame in frames:
            wire_time += frame_bits(len(frame.data)) / self.bitrate
            if delay_s is not None and node is self.encoder and self._scripted:
                with self._lock:
                    self._late_frames.append((self.clock() + delay_s, frame))
                continue
            if delay_s is not None and node is self.encoder:
                # the bus, not self.network: a late frame after close() finds the bus shut down and is dropped
                late = threading.Timer(delay_s, lambda frame=frame: bus.send_at(frame, time.time()))
                late.daemon = True
                late.start()
                continue
            bus.send_at(frame, wire_time)
        with self._answered:
            self.syncs_answered += 1
            self._answered.notify_all()

    def wait_for_answers(self, syncs: int, timeout_s: float) -> bool:
        """Wait until the devices have answered ``syncs`` SYNCs (their TPDOs on the bus), at most ``timeout_s``;
        whether they have. A SYNC producer in the devices' process waits for it before the next SYNC, so that a
        starved process delays its whole cycle, as a real drive's CPU would, instead of answering after the
        next SYNC (:class:`sim_backend.device_process.SyncProducer`)."""
        with self._answered:
            return self._answered.wait_for(lambda: self.syncs_answered >= syncs, timeout_s)
