"""A simulated rig behind a serial port: the device side of ``docs/serial_protocol.md`` on a pty pair.

The host opens :attr:`SimulatedSerialDevice.port` (``/dev/pts/N``) with pyserial as it would open
``/dev/ttyUSB0``. Each SETPOINT frame advances the simulated gearbox exactly one sample and is answered by
one FEEDBACK frame with the same sequence number, so a run is deterministic whatever the host's timing.
"""

from __future__ import annotations

import collections
import os
import random
import select
import threading
import time
import tty
from collections.abc import Iterable

from rig.protocols import cia402
from rig.protocols.serial_frames import FrameDecoder, MessageType, SerialMessage, encode_frame
from sim_backend.plant import SimulatedGearbox

__all__ = ["SimulatedSerialDevice"]


class SimulatedSerialDevice:
    """Drive + load encoder of a simulated gearbox, answering on a pty.

    Parameters
    ----------
    gearbox
        The plant; stepped once per SETPOINT frame received in OPERATION ENABLED.
    drive_counts_per_revolution
        Drive position scaling (target counts -> motor radians).
    silent_seqs
        Sample numbers whose FEEDBACK is not sent (the plant still steps): injected frame loss.
    fault_at_seq
        Sample number at which the drive goes to FAULT (error code ``fault_code``) and reports it.
    garbage_probability, bitflip_probability, truncate_probability
        Injected line noise (:mod:`sim_backend.faults`): random bytes before a reply, one bit of a reply
        flipped, or a reply cut short, each with this probability per reply (drawn from ``seed``).
    reply_lag
        ``(seconds, first sample)``: from that sample on, every reply leaves this much later (a device
        that answers late).
    disable_at_seq
        At this sample the drive drops out of OPERATION ENABLED without a fault (enable input or safe
        torque off lost): it answers that setpoint with its new statusword and follows no target after.
    unplug_at_seq
        At this sample the device closes its end of the port, like a USB adapter pulled out; its own link
        watchdog disables the drive.
    """

    def __init__(self, gearbox: SimulatedGearbox, *, drive_counts_per_revolution: int = 1 << 17,
                 silent_seqs: Iterable[int] = (), fault_at_seq: int | None = None, fault_code: int = 0x7500,
                 garbage_probability: float = 0.0, bitflip_probability: float = 0.0,
                 truncate_probability: float = 0.0, reply_lag: tuple[float, int] | None = None,
                 unplug_at_seq: int | None = None, disable_at_seq: int | None = None, seed: int = 0) -> None:
        self.gearbox = gearbox
        self.drive = cia402.DriveScaling(int(drive_counts_per_revolution))
        self.silent_seqs = frozenset(int(seq) & 0xFFFF for seq in silent_seqs)
        self.fault_at_seq = fault_at_seq
        self.fault_code = fault_code
        self.state = cia402.DriveState.SWITCH_ON_DISABLED
        self.controlword = 0
        self.target_counts = 0
        self.actual_counts = 0
        self.setpoints = 0
        self.controlwords: list[int] = []
        self.frame_errors = 0
        self.garbage_probability = float(garbage_probability)
        self.bitflip_probability = float(bitflip_probability)
        self.truncate_probability = float(truncate_probability)
        self.reply_lag = reply_lag
        self.unplug_at_seq = unplug_at_seq
        self.disable_at_seq = disable_at_seq
        self.encoder_counts = 0
        self.unplugged = False
        self._rng = random.Random(seed)
        self._decoder = FrameDecoder()
        self._master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)
        self.port = os.ttyname(self._slave_fd)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> SimulatedSerialDevice:
        self._thread = threading.Thread(target=self._serve, name=f"sim-serial-{self.port}", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the device thread and close the pty (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd_name in ("_master_fd", "_slave_fd"):
            fd = getattr(self, fd_name)
            if fd is not None:
                os.close(fd)
                setattr(self, fd_name, None)

    def __enter__(self) -> SimulatedSerialDevice:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- device loop ----------------------------------------------------------------------------------------

    def _serve(self) -> None:
        delayed: collections.deque[tuple[float, bytes]] = collections.deque()  # (due time, reply), in order
        while not self._stop.is_set():
            timeout_s = 0.05 if not delayed else min(0.05, max(0.0, delayed[0][0] - time.perf_counter()))
            ready, _, _ = select.select([self._master_fd], [], [], timeout_s)
            while delayed and delayed[0][0] <= time.perf_counter():
                os.write(self._master_fd, delayed.popleft()[1])
            if not ready:
                continue
            try:
                data = os.read(self._master_fd, 4096)
            except OSError:
                return
            for message in self._decoder.feed(data):
                if self._unplugs_at(message):
                    self._unplug()
                    return
                reply = self.handle(message)
                if not reply:
                    continue
                reply = self._line_noise(reply)
                if self.reply_lag is not None and self.setpoints > self.reply_lag[1]:
                    delayed.append((time.perf_counter() + self.reply_lag[0], reply))  # latency, not throughput
                else:
                    os.write(self._master_fd, reply)
            self.frame_errors = self._decoder.errors

    def _unplugs_at(self, message: SerialMessage) -> bool:
        return (self.unplug_at_seq is not None and message.type is MessageType.SETPOINT
                and message.seq == self.unplug_at_seq & 0xFFFF)

    def _unplug(self) -> None:
        """The port disappears; the drive's link watchdog disables it (a real drive's communication
        watchdog, e.g. CiA 402 0x6007 abort connection option code)."""
        self.state = cia402.DriveState.SWITCH_ON_DISABLED
        self.unplugged = True
        fd, self._master_fd = self._master_fd, None
        os.close(fd)

    def _line_noise(self, reply: bytes) -> bytes:
        """The reply as the line delivers it: maybe one bit flipped (not in the 0x00 delimiter, so the
        frame's CRC fails), maybe cut short (an early delimiter), maybe preceded by random bytes."""
        if self.bitflip_probability and self._rng.random() < self.bitflip_probability:
            noisy = bytearray(reply)
            noisy[self._rng.randrange(len(reply) - 1)] ^= 1 << self._rng.randrange(8)
            reply = bytes(noisy)
        if self.truncate_probability and self._rng.random() < self.truncate_probability:
            reply = reply[:self._rng.randrange(1, len(reply) - 1)] + b"\x00"
        if self.garbage_probability and self._rng.random() < self.garbage_probability:
            reply = self._rng.randbytes(self._rng.randint(1, 16)) + reply
        return reply

    def handle(self, message: SerialMessage) -> bytes:
        """The bytes the device answers to ``message`` (public so that tests can script exchanges)."""
        if message.type is MessageType.CONTROL:
            (controlword,) = message.fields
            self.controlwords.append(controlword)
            previous_state = self.state
            self.state = cia402.next_state(self.state, controlword, self.controlword)
            self.controlword = controlword
            if self.state is cia402.DriveState.OPERATION_ENABLED and previous_state is not self.state:
                self.target_counts = self.actual_counts  # no jump on enable
            return self._status(message.seq)
        if message.type is MessageType.STATUS_REQUEST:
            return self._status(message.seq)
        if message.type is MessageType.SETPOINT:
            return self._setpoint(message)
        return b""

    def _status(self, seq: int) -> bytes:
        return encode_frame(MessageType.STATUS, seq, cia402.statusword_for(self.state), self.actual_counts)

    def _setpoint(self, message: SerialMessage) -> bytes:
        if self.state is not cia402.DriveState.OPERATION_ENABLED:
            return b""  # a drive not enabled ignores targets; the host sees the sample as lost
        if self.fault_at_seq is not None and message.seq == self.fault_at_seq & 0xFFFF:
            self.state = cia402.DriveState.FAULT
            return encode_frame(MessageType.FAULT, 0, self.fault_code)
        if self.disable_at_seq is not None and message.seq == self.disable_at_seq & 0xFFFF:
            self.state = cia402.DriveState.SWITCH_ON_DISABLED
            return encode_frame(MessageType.FEEDBACK, message.seq, cia402.statusword_for(self.state),
                                self.actual_counts, self.encoder_counts & 0xFFFFFFFF)
        (self.target_counts,) = message.fields
        command_rad = self.drive.rad_from_counts(self.target_counts)
        sample = self.gearbox.step(command_rad)
        self.encoder_counts = sample.encoder_counts
        self.actual_counts = self.target_counts
        self.setpoints += 1
        if message.seq in self.silent_seqs:
            return b""
        return encode_frame(MessageType.FEEDBACK, message.seq, cia402.statusword_for(self.state, target_reached=True),
                            self.actual_counts, sample.encoder_counts & 0xFFFFFFFF)
