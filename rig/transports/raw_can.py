"""Raw-CAN transport: the fixed frame layout of ``configs/raw_can.dbc`` over any python-can interface.

Per sample the host sends RIG_SETPOINT with the sample number; the device answers with RIG_FEEDBACK
(encoder, statusword) and RIG_DRIVE_FEEDBACK (drive position), both with the same sequence number, so
every answer is attributed to its sample exactly. Bring-up walks the CiA 402 state machine with
RIG_CONTROL frames (each answered by RIG_STATUS); RIG_FAULT from the device stops the run.
The receive side runs in the caller's thread (``bus.recv``): no background threads.
"""

from __future__ import annotations

import time
from typing import Any

from rig.protocols.can_bus_load import bus_load
from rig.protocols.can_error_frames import describe_error_frame, is_bus_off
from rig.protocols.errors import ConfigError, DeviceFault, TransportError
from rig.protocols.raw_can_frames import DEFAULT_DBC, RawCanCodec
from rig.protocols.serial_frames import unwrap_seq
from rig.transports.base import FeedbackSample, Setpoint, Transport, check_trace_path

__all__ = ["RawCanTransport"]


class RawCanTransport(Transport):
    """The rig over raw CAN frames.

    Parameters
    ----------
    interface, channel
        python-can interface name and channel (from ``can://INTERFACE/CHANNEL``).
    bitrate
        Bus bit rate; the cycle's three frames must fit at the sample rate (:class:`ConfigError` if not).
    dbc
        The DBC file with the frame layout (``configs/raw_can.dbc`` by default).
    reply_timeout_s
        How long a RIG_CONTROL/RIG_STATUS_REQUEST waits for its RIG_STATUS before it is sent again.
    reply_retries
        How many times a request whose RIG_STATUS was lost is sent again, unchanged (same ``seq``; the
        device answers a repeated ``seq`` without applying the controlword twice, see the DBC comments).
    trace_path
        Write every frame sent and received to this file with python-can's writers (``.blf``, ``.asc``,
        ``.log``, ``.csv``, ``.trc``; not ``.db``).
    """

    def __init__(self, interface: str, channel: str, *, bitrate: int = 1_000_000, dbc: str = str(DEFAULT_DBC),
                 reply_timeout_s: float = 0.5, reply_retries: int = 3, trace_path: str | None = None,
                 **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.interface, self.channel, self.bitrate = interface, channel, int(bitrate)
        self.reply_timeout_s = float(reply_timeout_s)
        self.reply_retries = int(reply_retries)
        if not 0 <= self.reply_retries <= 10:
            raise ConfigError("<transport>", "reply_retries", f"expected an integer from 0 to 10, got {reply_retries!r}")
        self.retries = 0  # requests sent again because their RIG_STATUS was lost
        try:
            self.codec = RawCanCodec(dbc)
        except ValueError as err:
            raise ConfigError("<transport>", "dbc", str(err)) from err
        lengths = self.codec.lengths
        self.load = bus_load((lengths["RIG_SETPOINT"], lengths["RIG_FEEDBACK"], lengths["RIG_DRIVE_FEEDBACK"]),
                             1.0 / self.sample_period_s, self.bitrate)
        if self.load.load > 1.0:
            raise ConfigError("<transport>", "bitrate", (
                f"{self.bitrate} bit/s cannot carry {1 / self.sample_period_s:g} Hz: one cycle takes "
                f"{self.load.bits_per_cycle} bit ({100 * self.load.load:.0f}% load); the limit is "
                f"{self.load.max_rate_hz:.0f} Hz"))
        self.trace_path = check_trace_path(trace_path)
        self._trace = None
        self._bus = None
        self._request = 0
        self._status: dict[int, dict[str, int]] = {}
        self._parts: dict[int, dict[str, Any]] = {}
        self._last_seq = 0

    # -- seam ----------------------------------------------------------------------------------------------

    @property
    def min_cycle_s(self) -> float:
        """One cycle's frames on the bus (worst-case bit stuffing): SYNCs/commands are never closer."""
        return 1.0 / self.load.max_rate_hz

    def _connect(self) -> None:
        import can

        try:
            self._bus = can.Bus(interface=self.interface, channel=self.channel, bitrate=self.bitrate)
        except (can.CanError, OSError, ValueError) as err:
            raise TransportError(f"{self.name}: cannot open CAN {self.interface}/{self.channel}: {err}") from err
        if self.trace_path is not None:
            self._trace = can.Logger(self.trace_path)

    def _prepare(self) -> float:
        return self.drive.rad_from_counts(self._request_reply("RIG_STATUS_REQUEST")["actual_counts"])

    def _write_controlword(self, controlword: int) -> None:
        self._request_reply("RIG_CONTROL", controlword=controlword)

    def _read_statusword(self) -> int:
        return self._request_reply("RIG_STATUS_REQUEST")["statusword"]

    def _send(self, setpoint: Setpoint) -> None:
        self._transmit(self.codec.encode("RIG_SETPOINT", seq=setpoint.seq,
                                         target_counts=self.drive.counts_from_rad(setpoint.position_rad)))
        self._last_seq = setpoint.seq

    def _recv_internal(self, timeout_s: float) -> FeedbackSample | None:
        deadline = time.perf_counter() + timeout_s
        while True:
            sample = self._receive_one(max(deadline - time.perf_counter(), 0.0))
            if isinstance(sample, FeedbackSample):
                return sample
            if sample is None and time.perf_counter() >= deadline:
                return None
            if self._fault is not None:
                return None

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()
        trace, self._trace = self._trace, None
        if trace is not None:
            trace.stop()

    # -- protocol ----------------------------------------------------------------------------------------

    def _transmit(self, msg: Any) -> None:
        import can

        if self._bus is None:
            raise TransportError(f"{self.name}: the bus is closed")
        try:
            self._bus.send(msg)
        except can.CanError as err:
            raise TransportError(f"{self.name}: sending {msg.arbitration_id:#x} failed: {err}") from err
        if self._trace is not None:
            msg.timestamp = time.time()
            self._trace.on_message_received(msg)

    def _receive_one(self, timeout_s: float) -> FeedbackSample | bool | None:
        """Read one frame and dispatch it: a completed FeedbackSample, True for another frame, None if
        nothing arrived."""
        import can

        try:
            msg = self._bus.recv(timeout_s)
        except can.CanError as err:
            raise TransportError(f"{self.name}: receive failed: {err}") from err
        if msg is None:
            return None
        if self._trace is not None:
            self._trace.on_message_received(msg)
        if msg.is_error_frame:
            self.frame_errors += 1
            if is_bus_off(msg):
                self._report_fault(TransportError(
                    f"{self.name}: the CAN controller went bus off ({describe_error_frame(msg)}): nothing can be "
                    "sent or received; check wiring, termination and the bit rate of every node"))
            return True
        try:
            decoded = self.codec.decode(msg)
        except ValueError:
            self.frame_errors += 1
            return True
        if decoded is None:
            return True
        name, signals = decoded
        if name == "RIG_STATUS":
            self._status[signals["seq"]] = signals
        elif name == "RIG_FAULT":
            self._report_fault(DeviceFault(self.name, signals["error_code"], "the device reported a fault"))
        elif name in ("RIG_FEEDBACK", "RIG_DRIVE_FEEDBACK"):
            seq = unwrap_seq(signals["seq"], self._last_seq)
            parts = self._parts.setdefault(seq, {})
            parts[name] = signals
            if len(parts) == 2:
                del self._parts[seq]
                feedback, drive = parts["RIG_FEEDBACK"], parts["RIG_DRIVE_FEEDBACK"]
                raw = feedback["encoder_counts"]
                counts = raw - (1 << 32) if self.encoder.signed and raw >= 1 << 31 else raw
                return FeedbackSample(seq=seq, encoder_counts=counts, load_angle_rad=self._decode_encoder(counts),
                                      drive_position_rad=self.drive.rad_from_counts(drive["actual_counts"]),
                                      statusword=feedback["statusword"], host_time_s=time.perf_counter())
            if len(self._parts) > 256:
                for old in sorted(self._parts)[:128]:
                    del self._parts[old]
        return True

    def _request_reply(self, name: str, **signals: int) -> dict[str, int]:
        """Send a request and return its RIG_STATUS, sending the same frame again (same ``seq``) after each
        ``reply_timeout_s`` without an answer, at most ``reply_retries`` times."""
        self._request = self._request % 0xFFFF + 1  # 1..65535, as on the serial link
        request = self._request
        self._status.clear()  # one request at a time: anything left is a late copy of an older answer
        attempts = 1 + self.reply_retries
        for attempt in range(attempts):
            if attempt:
                self.retries += 1
            self._transmit(self.codec.encode(name, seq=request, **signals))
            deadline = time.perf_counter() + self.reply_timeout_s
            while request not in self._status:
                remaining = deadline - time.perf_counter()
                if remaining <= 0:
                    break
                self._receive_one(remaining)
            else:
                return self._status.pop(request)
        raise TransportError(f"{self.name}: no RIG_STATUS answer to {name} (seq {request}) within "
                             f"{self.reply_timeout_s:g} s, {attempts} attempts")
