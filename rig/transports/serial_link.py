"""Serial transport (pyserial): the COBS/CRC-16 protocol of :mod:`rig.protocols.serial_frames`
(specified for firmware authors in ``docs/serial_protocol.md``).

Per sample the host sends one SETPOINT frame with the sample number; the device applies it, samples the
load encoder and answers with one FEEDBACK frame carrying the same sequence number. Bring-up walks the
drive's CiA 402 state machine with CONTROL frames (the device answers each with STATUS).
"""

from __future__ import annotations

import collections
import select
import time

from rig.protocols import cia402
from rig.protocols.errors import DeviceFault, TransportError
from rig.protocols.serial_frames import FrameDecoder, MessageType, SerialMessage, encode_frame, unwrap_seq
from rig.transports.base import FeedbackSample, Setpoint, Transport

__all__ = ["SerialTransport"]


class SerialTransport(Transport):
    """The rig over a serial port.

    Parameters
    ----------
    port
        Device path (``/dev/ttyUSB0``, a pty) or any pyserial URL.
    baudrate
        Line rate in bit/s.
    reply_timeout_s
        How long a CONTROL request may wait for its STATUS answer.
    **kwargs
        See :class:`~rig.transports.base.Transport`.
    """

    def __init__(self, port: str, *, baudrate: int = 2_000_000, reply_timeout_s: float = 0.5, **kwargs) -> None:
        super().__init__(**kwargs)
        self.port = port
        self.baudrate = int(baudrate)
        self.reply_timeout_s = float(reply_timeout_s)
        self._serial = None
        self._decoder = FrameDecoder()
        self._feedback: collections.deque[FeedbackSample] = collections.deque()
        self._status: dict[int, SerialMessage] = {}
        self._request = 0
        self._last_seq = 0

    # -- seam ----------------------------------------------------------------------------------------------

    def _connect(self) -> None:
        try:
            import serial
        except ImportError as err:  # pragma: no cover - pyserial is a dependency
            raise TransportError("the serial transport needs pyserial: pip install pyserial") from err
        try:
            self._serial = serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=0)
        except (serial.SerialException, OSError, ValueError) as err:
            raise TransportError(f"{self.name}: cannot open serial port {self.port}: {err}") from err
        self._serial.reset_input_buffer()

    def _prepare(self) -> float:
        status = self._request_reply(MessageType.STATUS_REQUEST)
        return self.drive.rad_from_counts(status.fields[1])

    def _send(self, setpoint: Setpoint) -> None:
        self._write(encode_frame(MessageType.SETPOINT, setpoint.seq, self.drive.counts_from_rad(setpoint.position_rad)))
        self._last_seq = setpoint.seq

    def _recv_internal(self, timeout_s: float) -> FeedbackSample | None:
        deadline = time.perf_counter() + timeout_s
        while not self._feedback:
            remaining = deadline - time.perf_counter()
            if not self._poll(max(remaining, 0.0)) and remaining <= 0:
                return None
            if self._fault is not None:
                return None
        return self._feedback.popleft()

    def _close(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            finally:
                self._serial = None

    # -- protocol ----------------------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        if self._serial is None:
            raise TransportError(f"{self.name}: the port is closed")
        try:
            self._serial.write(data)
        except Exception as err:  # serial.SerialException, OSError
            raise TransportError(f"{self.name}: write to {self.port} failed: {err}") from err

    def _poll(self, timeout_s: float) -> bool:
        """Read what is there (waiting up to ``timeout_s`` for the first byte) and dispatch the messages."""
        try:
            ready, _, _ = select.select([self._serial.fileno()], [], [], timeout_s)
            if not ready:
                return False
            data = self._serial.read(self._serial.in_waiting or 1)
        except Exception as err:  # serial.SerialException, OSError, ValueError on a closed port
            raise TransportError(f"{self.name}: read from {self.port} failed: {err} (the port disappeared: "
                                 "adapter unplugged or device powered off?)") from err
        received = time.perf_counter()
        errors_before = self._decoder.errors
        for message in self._decoder.feed(data):
            self._dispatch(message, received)
        self.frame_errors += self._decoder.errors - errors_before
        return True

    def _dispatch(self, message: SerialMessage, received_s: float) -> None:
        if message.type is MessageType.FEEDBACK:
            statusword, actual, encoder_raw = message.fields
            counts = encoder_raw - (1 << 32) if self.encoder.signed and encoder_raw >= 1 << 31 else encoder_raw
            self._feedback.append(FeedbackSample(
                seq=unwrap_seq(message.seq, self._last_seq), encoder_counts=counts,
                load_angle_rad=self._decode_encoder(counts), drive_position_rad=self.drive.rad_from_counts(actual),
                statusword=statusword, host_time_s=received_s))
            if cia402.state_from_statusword(statusword) in (cia402.DriveState.FAULT,
                                                              cia402.DriveState.FAULT_REACTION_ACTIVE):
                self._report_fault(DeviceFault(self.name, None, "the drive reports FAULT in its statusword"))
        elif message.type is MessageType.STATUS:
            self._status[message.seq] = message
        elif message.type is MessageType.FAULT:
            self._report_fault(DeviceFault(self.name, message.fields[0], "the device reported a fault"))

    def _request_reply(self, kind: MessageType, *fields: int) -> SerialMessage:
        self._request = (self._request + 1) & 0xFFFF
        request = self._request
        self._write(encode_frame(kind, request, *fields))
        deadline = time.perf_counter() + self.reply_timeout_s
        while request not in self._status:
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                raise TransportError(f"{self.name}: no STATUS answer to {kind.name} within {self.reply_timeout_s:g} s")
            self._poll(remaining)
        return self._status.pop(request)

    def _write_controlword(self, controlword: int) -> None:
        self._request_reply(MessageType.CONTROL, controlword)

    def _read_statusword(self) -> int:
        return self._request_reply(MessageType.STATUS_REQUEST).fields[0]
