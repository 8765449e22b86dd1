"""A simulated CANopen rig: a CiA 402 servo drive and a CiA 406 absolute encoder, each a real
``canopen.LocalNode`` on a python-can bus (the ``virtual`` interface in tests), sharing one simulated
gearbox.

``LocalNode`` gives us the object dictionary (from the EDS files in ``configs/eds``), the SDO server and
NMT commands. This module adds what it lacks for a cyclic synchronous position (CSP) rig:

* PDO mapping taken from the object dictionary when the node enters OPERATIONAL (after the master has
  configured 0x1400/0x1600/0x1800/0x1A00 by SDO), RPDOs written into the dictionary, TPDOs sent on SYNC,
  and no PDO traffic outside OPERATIONAL (NMT gating);
* the CiA 402 state machine on 0x6040/0x6041 (:mod:`rig.protocols.cia402`), with the target set to the
  actual position on enable (no jump);
* the plant: on each SYNC in OPERATION ENABLED the drive applies its target (0x607A) and the gearbox
  advances exactly one sample; the encoder's position value (0x6004) is the gearbox's encoder reading;
* EMCY and 0x603F on an injected fault, heartbeats (0x1017) from both nodes;
* the encoder's resolution objects (0x6501, 0x6502, 0x6002) from the gearbox's EncoderResolution;
* a count of every frame on the bus, for the bus load against the configured bit rate.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from pathlib import Path

import can
import canopen
from can.interfaces.virtual import VirtualBus

from rig.protocols import cia402
from rig.protocols.can_bus_load import frame_bits
from sim_backend.plant import SimulatedGearbox

__all__ = ["EDS_DIRECTORY", "SimulatedCanOpenRig"]

EDS_DIRECTORY = Path(__file__).resolve().parents[1] / "configs" / "eds"
DRIVE_EDS = EDS_DIRECTORY / "sim_drive_cia402.eds"
ENCODER_EDS = EDS_DIRECTORY / "sim_encoder_cia406.eds"
SYNC_COB_ID = 0x80
SDO_ABORT_VALUE_RANGE = 0x06090030  # CiA 301: value range of parameter exceeded


class _FrameCounter(can.Listener):
    """Counts the bits of every frame on the bus, received or sent by the simulated nodes (worst-case
    bit stuffing)."""

    def __init__(self) -> None:
        self.frames = 0
        self.bits = 0
        self.started = time.perf_counter()
        self._lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:  # the notifier thread and the heartbeat threads both count
            self.frames += 1
            self.bits += frame_bits(msg.dlc, extended=msg.is_extended_id)


class _WireTimeBus(VirtualBus):
    """python-can's virtual bus, but TPDOs can carry their wire time: the SYNC's timestamp plus the bits
    on the wire since, at the bus's bit rate, as a real bus with hardware timestamps would show them,
    however late the simulated device's thread got to answer."""

    def __init__(self, channel: str, counter: _FrameCounter) -> None:
        super().__init__(channel=channel, receive_own_messages=False, preserve_timestamps=False)
        self._stamp_lock = threading.Lock()
        self.counter = counter

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        with self._stamp_lock:
            if self._is_shutdown:
                return  # a heartbeat timer racing the shutdown: a node off the bus sends nothing
            self.counter.on_message_received(msg)
            try:
                super().send(msg, timeout)
            except can.CanOperationError:
                if not self._is_shutdown:
                    raise

    def send_at(self, msg: can.Message, wire_time: float) -> None:
        with self._stamp_lock:
            self.counter.on_message_received(msg)
            msg.timestamp = wire_time
            self.preserve_timestamps = True
            try:
                super().send(msg)
            finally:
                self.preserve_timestamps = False


class SimulatedCanOpenRig:
    """Drive (CiA 402) and load encoder (CiA 406) of a simulated gearbox on one CAN bus.

    Parameters
    ----------
    gearbox
        The plant; stepped once per SYNC while the drive is in OPERATION ENABLED.
    channel
        The python-can ``virtual`` channel the nodes join (the master joins the same channel).
    drive_node_id, encoder_node_id
        Node-IDs of the two devices.
    drive_counts_per_revolution
        Drive position units per motor revolution.
    bitrate
        The bus's bit rate, for :meth:`bus_load`.
    silent_seqs
        Sample numbers (SYNCs counted from 0 in OPERATION ENABLED) after which the encoder sends no TPDO
        (the plant still steps): injected frame loss.
    fault_at_seq, fault_code
        At that sample the drive faults instead of moving: EMCY with ``fault_code``, 0x603F =
        ``fault_code``, FAULT state.
    stop_heartbeat_at_seq
        At that sample both nodes stop their heartbeats (a device that fell off the bus).
    disable_at_seq
        At that sample the drive drops out of OPERATION ENABLED without a fault (enable input or safe torque
        off lost); its TPDOs go on, with the new statusword.
    error_frame_at
        ``(error class bits, sample)``: an error frame (:mod:`rig.protocols.can_error_frames`) goes on the
        bus before that sample's TPDOs, e.g. a protocol violation or bus-off.
    delayed_tpdo
        ``(seconds, sample)``: the encoder's TPDO answering that sample goes on the bus this much later,
        after later SYNCs (a device that misses its synchronous window; frames out of order).
    refuse_sdo_index
        The drive aborts every SDO write to this object (abort code 0x06090030, value range exceeded), as a
        drive that does not support a mode or mapping the master configures.
    """

    def __init__(self, gearbox: SimulatedGearbox, *, channel: str,
                 drive_node_id: int = 1, encoder_node_id: int = 2, drive_counts_per_revolution: int = 1 << 17,
                 bitrate: int = 1_000_000, silent_seqs: Iterable[int] = (), fault_at_seq: int | None = None,
                 fault_code: int = 0x7500, stop_heartbeat_at_seq: int | None = None,
                 disable_at_seq: int | None = None, refuse_sdo_index: int | None = None,
                 delayed_tpdo: tuple[float, int] | None = None,
                 error_frame_at: tuple[int, int] | None = None) -> None:
        self.gearbox = gearbox
        self.channel = channel
        self.drive_scaling = cia402.DriveScaling(int(drive_counts_per_revolution))
        self.bitrate = int(bitrate)
        self.silent_seqs = frozenset(silent_seqs)
        self.fault_at_seq = fault_at_seq
        self.fault_code = fault_code
        self.stop_heartbeat_at_seq = stop_heartbeat_at_seq
        self.disable_at_seq = disable_at_seq
        self.refuse_sdo_index = refuse_sdo_index
        self.delayed_tpdo = delayed_tpdo
        self.error_frame_at = error_frame_at
        self.network: canopen.Network | None = None
        self.drive = canopen.LocalNode(drive_node_id, str(DRIVE_EDS))
        self.encoder = canopen.LocalNode(encoder_node_id, str(ENCODER_EDS))
        self.state = cia402.DriveState.SWITCH_ON_DISABLED
        self.controlword = 0
        self.controlwords: list[int] = []
        self.setpoints = 0  # SYNCs sampled since the first target (RPDO) in OPERATION ENABLED
        self.streaming = False  # the plant holds exactly at rest until the first target arrives
        self.syncs = 0
        self.homed = False
        self._counter = _FrameCounter()
        self._lock = threading.Lock()
        self._operational: set[int] = set()
        self._sync_tpdos: dict[int, list[tuple[int, list[tuple[int, int, int]]]]] = {}
        self._started = False

    # -- lifecycle ------------------------------------------------------------------------------------------

    def start(self) -> SimulatedCanOpenRig:
        self.network = canopen.Network(_WireTimeBus(self.channel, self._counter))
        self.network.connect()
        self.network.notifier.add_listener(self._counter)
        for node in (self.drive, self.encoder):
            self.network.add_node(node)
        self.drive.add_write_callback(self._on_drive_write)
        self.drive.add_read_callback(self._on_drive_read)
        self.network.subscribe(0, self._on_nmt)  # after the nodes' own NMT handlers
        self.network.subscribe(SYNC_COB_ID, self._on_sync)
        encoder = self.gearbox.encoder
        self.encoder.set_data(0x6501, 0, encoder.counts_per_revolution.to_bytes(4, "little"))
        self.encoder.set_data(0x6502, 0, (1 << encoder.multi_turn_bits).to_bytes(2, "little"))
        self.encoder.set_data(0x6002, 0, encoder.modulus.to_bytes(4, "little"))
        self.encoder.set_data(0x6000, 0, (0 if encoder.direction > 0 else 1).to_bytes(2, "little"))
        for node in (self.drive, self.encoder):
            node.nmt.state = "PRE-OPERATIONAL"  # boot-up message, heartbeat per 0x1017
        self._started = True
        return self

    def close(self) -> None:
        """Stop heartbeats, leave the bus and stop the notifier thread (idempotent)."""
        if not self._started:
            return
        self._started = False
        for node in (self.drive, self.encoder):
            node.nmt.stop_heartbeat()
        self.network.disconnect()
        self.network = None

    def __enter__(self) -> SimulatedCanOpenRig:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def bus_load(self) -> float:
        """Fraction of the bit rate used by every frame seen since start (worst-case bit stuffing)."""
        elapsed = time.perf_counter() - self._counter.started
        return self._counter.bits / (elapsed * self.bitrate) if elapsed > 0 else 0.0

    @property
    def frames(self) -> int:
        return self._counter.frames

    # -- object dictionary hooks -------------------------------------------------------------------------

    def _on_drive_read(self, index: int, subindex: int, od: object) -> int | None:
        if index == 0x6041:
            word = cia402.statusword_for(self.state, target_reached=True)
            if self.homed and self._i8(self.drive, 0x6060) == cia402.HOMING_MODE:
                word |= cia402.STATUSWORD_HOMING_ATTAINED
            if (self.state is cia402.DriveState.OPERATION_ENABLED
                    and self._i8(self.drive, 0x6060) == cia402.CYCLIC_SYNCHRONOUS_POSITION_MODE):
                word |= cia402.STATUSWORD_FOLLOWS_TARGET
            return word
        if index == 0x6061:
            return self._i8(self.drive, 0x6060)  # the mode is taken over at once
        return None

    def _on_drive_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        if index == self.refuse_sdo_index:
            raise canopen.SdoAbortedError(SDO_ABORT_VALUE_RANGE)
        if index == 0x6040:
            controlword = int.from_bytes(data, "little")
            with self._lock:
                self.controlwords.append(controlword)
                previous_state = self.state
                self.state = cia402.next_state(self.state, controlword, self.controlword)
                starts_homing = controlword & 0x0010 and not self.controlword & 0x0010
                self.controlword = controlword
                if (starts_homing and self.state is cia402.DriveState.OPERATION_ENABLED
                        and self._i8(self.drive, 0x6060) == cia402.HOMING_MODE):
                    # homing method 37 (CiA 402: home on the current position): nothing moves
                    self.homed = True
                if previous_state is cia402.DriveState.OPERATION_ENABLED and self.state is not previous_state:
                    self.streaming = False
                if self.state is cia402.DriveState.OPERATION_ENABLED and previous_state is not self.state:
                    actual = self.drive.get_data(0x6064, 0)
                    self.drive.data_store.setdefault(0x607A, {})[0] = actual  # no jump on enable

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        for node in (self.drive, self.encoder):
            if node.nmt.state == "OPERATIONAL" and node.id not in self._operational:
                self._operational.add(node.id)
                self._configure_pdos(node)
            elif node.nmt.state != "OPERATIONAL" and node.id in self._operational:
                self._operational.discard(node.id)
                for pdo_map in list(node.rpdo.map.values()):
                    if pdo_map.cob_id:
                        self.network.unsubscribe(pdo_map.cob_id, pdo_map.on_message)

    def _configure_pdos(self, node: canopen.LocalNode) -> None:
        """Take the PDO mapping the master wrote by SDO (or the EDS default) from the dictionary."""
        node.tpdo.read(from_od=False)
        # synchronous TPDOs as (COB-ID, [(index, subindex, bytes)]), packed directly on each SYNC
        self._sync_tpdos[node.id] = [
            (pdo_map.cob_id, [(variable.index, variable.subindex, variable.length // 8) for variable in pdo_map
                              if variable.length])
            for pdo_map in node.tpdo.map.values()
            if pdo_map.enabled and pdo_map.trans_type is not None and 1 <= pdo_map.trans_type <= 240]
        if node is self.drive:
            node.rpdo.read(from_od=False)  # subscribes the enabled RPDOs
            for pdo_map in node.rpdo.map.values():
                if pdo_map.enabled and not pdo_map.callbacks:
                    pdo_map.add_callback(self._on_rpdo)

    def _on_rpdo(self, pdo_map: object) -> None:
        for variable in pdo_map:  # type: ignore[attr-defined]
            if variable.length:
                self.drive.set_data(variable.index, variable.subindex, variable.get_data())
        with self._lock:
            self.streaming = self.streaming or self.state is cia402.DriveState.OPERATION_ENABLED

    @staticmethod
    def _i32(node: canopen.LocalNode, index: int) -> int:
        return int.from_bytes(node.get_data(index, 0), "little", signed=True)

    @staticmethod
    def _i8(node: canopen.LocalNode, index: int) -> int:
        return int.from_bytes(node.get_data(index, 0), "little", signed=True)

    # -- the cycle -------------------------------------------------------------------------------------------

    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            if (self.state is cia402.DriveState.OPERATION_ENABLED and self.drive.id in self._operational
                    and self.streaming):
                number = self.setpoints
                if self.fault_at_seq is not None and number == self.fault_at_seq:
                    self.state = cia402.DriveState.FAULT
                    self.drive.data_store.setdefault(0x603F, {})[0] = self.fault_code.to_bytes(2, "little")
                    self.drive.emcy.send(self.fault_code, register=0x01)
                elif number == self.disable_at_seq:
                    self.state = cia402.DriveState.SWITCH_ON_DISABLED
                else:
                    target = self._i32(self.drive, 0x607A)
                    sample = self.gearbox.step(self.drive_scaling.rad_from_counts(target))
                    self.drive.data_store.setdefault(0x6064, {})[0] = target.to_bytes(4, "little", signed=True)
                    self.encoder.data_store.setdefault(0x6004, {})[0] = (
                        (sample.encoder_counts & 0xFFFFFFFF).to_bytes(4, "little"))
                    self.setpoints += 1
                if self.stop_heartbeat_at_seq is not None and number == self.stop_heartbeat_at_seq:
                    for node in (self.drive, self.encoder):
                        node.nmt.stop_heartbeat()
                silent = number in self.silent_seqs
                delay_s = self.delayed_tpdo[0] if self.delayed_tpdo and number == self.delayed_tpdo[1] else None
                if self.error_frame_at is not None and number == self.error_frame_at[1]:
                    self.network.bus.send(can.Message(arbitration_id=self.error_frame_at[0], is_error_frame=True,
                                                      dlc=8, data=bytes(8), is_extended_id=False))
            else:
                silent, delay_s = False, None
            self.syncs += 1
        wire_time = timestamp + frame_bits(len(data)) / self.bitrate
        for node in (self.drive, self.encoder):
            if node.id not in self._operational or (silent and node is self.encoder):
                continue
            for cob_id, entries in self._sync_tpdos.get(node.id, ()):
                payload = b"".join(node.get_data(index, subindex)[:size] for index, subindex, size in entries)
                frame = can.Message(arbitration_id=cob_id, data=payload, is_extended_id=False)
                wire_time += frame_bits(len(payload)) / self.bitrate
                if delay_s is not None and node is self.encoder:
                    late = threading.Timer(delay_s, lambda frame=frame: self.network.bus.send_at(frame, time.time()))
                    late.daemon = True
                    late.start()
                    continue
                self.network.bus.send_at(frame, wire_time)
