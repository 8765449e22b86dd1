"""A simulated rig on the raw-CAN protocol of ``configs/raw_can.dbc``: a responder on a python-can bus
(the ``virtual`` interface in tests) around a simulated gearbox.

Each RIG_SETPOINT received in OPERATION ENABLED advances the gearbox exactly one sample and is answered by
RIG_FEEDBACK and RIG_DRIVE_FEEDBACK with the same sequence number, so a run is deterministic whatever the
host's timing. RIG_CONTROL runs the CiA 402 state machine (:mod:`rig.protocols.cia402`).
"""

from __future__ import annotations

import threading
from collections.abc import Iterable

import can

from rig.protocols import cia402
from rig.protocols.can_bus_load import frame_bits
from rig.protocols.raw_can_frames import DEFAULT_DBC, RawCanCodec
from sim_backend.plant import SimulatedGearbox

__all__ = ["SimulatedRawCanDevice"]


class SimulatedRawCanDevice(can.Listener):
    """Drive + load encoder of a simulated gearbox answering raw CAN frames.

    Parameters
    ----------
    gearbox
        The plant; stepped once per RIG_SETPOINT in OPERATION ENABLED.
    channel
        The ``virtual`` channel (the host joins the same one).
    drive_counts_per_revolution
        Drive position scaling.
    dbc_path
        The frame layout.
    silent_seqs, fault_at_seq, fault_code
        Fault injection: samples whose answers are not sent (the plant still steps); the sample at which
        the drive faults (RIG_FAULT with ``fault_code``) instead of moving.
    error_frame_at
        ``(error class bits, sample)``: an error frame (:mod:`rig.protocols.can_error_frames`) goes on the
        bus before that sample's answers, e.g. a protocol violation or bus-off.
    disable_at_seq
        The sample at which the drive drops out of OPERATION ENABLED without a fault (enable input or safe
        torque off lost): it answers with its new statusword and follows no target after.
    lost_status_after_enable
        This many RIG_STATUS answers from the transition to OPERATION ENABLED on are lost; the host sends
        the request again with the same ``seq``, which the device answers without applying it twice.
    """

    def __init__(self, gearbox: SimulatedGearbox, *, channel: str, drive_counts_per_revolution: int = 1 << 17,
                 dbc_path: str = str(DEFAULT_DBC), bitrate: int = 1_000_000, silent_seqs: Iterable[int] = (),
                 fault_at_seq: int | None = None, fault_code: int = 0x7500,
                 disable_at_seq: int | None = None, error_frame_at: tuple[int, int] | None = None,
                 lost_status_after_enable: int = 0) -> None:
        self.gearbox = gearbox
        self.channel = channel
        self.drive = cia402.DriveScaling(int(drive_counts_per_revolution))
        self.codec = RawCanCodec(dbc_path)
        self.bitrate = int(bitrate)
        self.silent_seqs = frozenset(int(seq) & 0xFFFF for seq in silent_seqs)
        self.fault_at_seq = fault_at_seq
        self.fault_code = fault_code
        self.disable_at_seq = disable_at_seq
        self.error_frame_at = error_frame_at
        self.encoder_counts = 0
        self.state = cia402.DriveState.SWITCH_ON_DISABLED
        self.controlword = 0
        self.controlwords: list[int] = []
        self.requests: list[tuple[str, int]] = []  # every request received, repeats included
        self.lost_status_after_enable = int(lost_status_after_enable)
        self.lost_answers = 0
        self._to_lose = 0
        self._last_control_seq: int | None = None
        self.actual_counts = 0
        self.setpoints = 0
        self.frames = 0
        self.bits = 0
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._lock = threading.Lock()

    def start(self) -> SimulatedRawCanDevice:
        self._bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        self._notifier = can.Notifier(self._bus, [self], timeout=0.05)
        return self

    def close(self) -> None:
        """Stop the receive thread and leave the bus (idempotent)."""
        if self._notifier is not None:
            self._notifier.stop()
            self._notifier = None
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def __enter__(self) -> SimulatedRawCanDevice:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _send(self, name: str, **signals: int) -> None:
        msg = self.codec.encode(name, **signals)
        self._count(msg)
        self._bus.send(msg)

    def _count(self, msg: can.Message) -> None:
        with self._lock:
            self.frames += 1
            self.bits += frame_bits(msg.dlc, extended=msg.is_extended_id)

    def on_message_received(self, msg: can.Message) -> None:
        self._count(msg)
        try:
            decoded = self.codec.decode(msg)
        except ValueError:
            return  # a malformed frame of ours: a real device drops it too
        if decoded is None:
            return
        name, signals = decoded
        if name == "RIG_CONTROL":
            self.requests.append((name, signals["seq"]))
            if signals["seq"] != self._last_control_seq:  # a repeated seq is answered, not applied again
                self._last_control_seq = signals["seq"]
                controlword = signals["controlword"]
                self.controlwords.append(controlword)
                previous_state = self.state
                self.state = cia402.next_state(self.state, controlword, self.controlword)
                self.controlword = controlword
                if self.state is cia402.DriveState.OPERATION_ENABLED and previous_state is not self.state:
                    self._to_lose = self.lost_status_after_enable  # the target starts at the actual position
            self._status(signals["seq"])
        elif name == "RIG_STATUS_REQUEST":
            self.requests.append((name, signals["seq"]))
            self._status(signals["seq"])
        elif name == "RIG_SETPOINT":
            self._setpoint(signals["seq"], signals["target_counts"])

    def _status(self, seq: int) -> None:
        if self._to_lose > 0:
            self._to_lose -= 1
            self.lost_answers += 1
            return
        self._send("RIG_STATUS", seq=seq, statusword=cia402.statusword_for(self.state), actual_counts=self.actual_counts)

    def _setpoint(self, seq: int, target_counts: int) -> None:
        if self.state is not cia402.DriveState.OPERATION_ENABLED:
            return
        if self.error_frame_at is not None and seq == self.error_frame_at[1] & 0xFFFF:
            self._bus.send(can.Message(arbitration_id=self.error_frame_at[0], is_error_frame=True, dlc=8,
                                       data=bytes(8), is_extended_id=False))
        if self.fault_at_seq is not None and seq == self.fault_at_seq & 0xFFFF:
            self.state = cia402.DriveState.FAULT
            self._send("RIG_FAULT", error_code=self.fault_code)
            return
        if self.disable_at_seq is not None and seq == self.disable_at_seq & 0xFFFF:
            self.state = cia402.DriveState.SWITCH_ON_DISABLED
            self._send("RIG_FEEDBACK", seq=seq, statusword=cia402.statusword_for(self.state),
                       encoder_counts=self.encoder_counts & 0xFFFFFFFF)
            self._send("RIG_DRIVE_FEEDBACK", seq=seq, actual_counts=self.actual_counts)
            return
        sample = self.gearbox.step(self.drive.rad_from_counts(target_counts))
        self.encoder_counts = sample.encoder_counts
        self.actual_counts = target_counts
        self.setpoints += 1
        if seq in self.silent_seqs:
            return
        statusword = cia402.statusword_for(self.state, target_reached=True)
        self._send("RIG_FEEDBACK", seq=seq, statusword=statusword, encoder_counts=sample.encoder_counts & 0xFFFFFFFF)
        self._send("RIG_DRIVE_FEEDBACK", seq=seq, actual_counts=self.actual_counts)
