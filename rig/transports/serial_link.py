"""Serial transport (pyserial): the COBS/CRC-16 protocol of :mod:`rig.protocols.serial_frames`
(specified for firmware authors in ``docs/serial_protocol.md``).

Per sample the host sends one SETPOINT frame with the sample number; the device applies it, samples the
load encoder and answers with one FEEDBACK frame carrying the same sequence number. Bring-up walks the
drive's CiA 402 state machine with CONTROL frames (the device answers each with STATUS) and reads the
drive's error code with ERROR_REQUEST. A request whose answer does not come within ``reply_timeout_s`` is
sent again, unchanged (same request number), up to ``reply_retries`` times; the device answers a repeated
request number without applying it twice.

Protocol v2 (spec section 16): the device owns the sample clock. At :meth:`_prepare` the host sends HELLO;
a device that answers DEVICE_INFO with version 2 reports its buffer capacity and its tick period (checked
against the config's rate). The runner then queues SETPOINTs tagged with their tick number up to
:attr:`lead_samples` ahead of the last tick the device reported; the first receive after the first setpoint
sends START (the device's tick 0); each TICK frame becomes a :class:`FeedbackSample` with ``held`` and the
target the device really applied. A device that does not answer HELLO (a v1 device drops unknown types) is
driven the v1 way, host-paced (``lead_samples = 0``), unless ``protocol = "v2"`` demands v2.

Checked when the transport is built (so at config load, before anything is opened): the baud rate carries
one SETPOINT and one FEEDBACK per sample at the sample rate (:func:`rig.protocols.serial_frames.link_load`;
v2's TICK, 24 bytes up, and SETPOINT, 11 bytes down, need less of each direction than v1's 28 bytes in
series).
"""

from __future__ import annotations

import collections
import math
import random
import select

from rig.protocols import cia402
from rig.protocols.errors import ConfigError, DeviceFault, TransportError
from rig.protocols.serial_frames import (
    PROTOCOL_VERSION, TICK_HELD, UART_BITS_PER_BYTE, FrameDecoder, MessageType, SerialMessage, encode_frame, link_load,
    unwrap_seq,
)
from rig.transports.base import FeedbackSample, Setpoint, Transport
from rig.transports.tick_buffer import TickBuffer

__all__ = ["DEFAULT_LEAD_S", "MAX_REPLY_TIMEOUT_S", "SerialTransport"]

MAX_REPLY_TIMEOUT_S = 1.0
"""The host never waits longer than this for an answer before it sends again: the spec promises the
device a frame at least this often while it is enabled and waiting for the first SETPOINT."""
DEFAULT_LEAD_S = 0.25
"""v2: the default lead (``lead_s``), longer than the ~205 ms starvation measured under load (see SerialTransport)."""
_PORT_GONE_HINT = "(the port disappeared: adapter unplugged or device powered off?)"
_FAULT_STATES = (cia402.DriveState.FAULT, cia402.DriveState.FAULT_REACTION_ACTIVE)
_ANSWER_TO = {MessageType.CONTROL: MessageType.STATUS, MessageType.STATUS_REQUEST: MessageType.STATUS,
              MessageType.ERROR_REQUEST: MessageType.ERROR, MessageType.HELLO: MessageType.DEVICE_INFO,
              MessageType.START: MessageType.STATUS}
PROTOCOLS = ("auto", "v1", "v2")
REQUEST_ORIGINS = random.SystemRandom()
"""Where each session's request numbers start (spec section 6, across host sessions): the device may still
remember the last request number an earlier host's CONTROL had it apply, so a host counting from 1 again would
find its first CONTROL taken for a repeat; from a random origin that happens once in 65535 sessions."""
HELLO_ATTEMPTS = 2
"""HELLO is sent at most this often (once more after a lost answer): a device that answered the STATUS_REQUEST
before it but not two HELLOs is a v1 device, which drops unknown message types."""


class SerialTransport(Transport):
    """The rig over a serial port.

    Parameters
    ----------
    port
        Device path (``/dev/ttyUSB0``, a pty) or any pyserial URL.
    baudrate
        Line rate in bit/s; one sample's SETPOINT and FEEDBACK must fit in a sample period on an 8N1 UART
        (:class:`ConfigError` naming the highest sample rate it carries if not).
    reply_timeout_s
        How long a request (CONTROL, STATUS_REQUEST, ERROR_REQUEST) waits for its answer before it is sent
        again (at most :data:`MAX_REPLY_TIMEOUT_S`).
    reply_retries
        How many times a request whose answer was lost is sent again (same request number) before the
        link counts as failed.
    protocol
        ``"auto"`` (default): protocol v2 if the device answers HELLO, else v1 (host-paced, with a warning);
        ``"v2"``: refuse a device that does not speak v2; ``"v1"``: send no HELLO, drive it host-paced.
    lead_s
        v2: how far ahead of the device's ticks setpoints are queued, as ``ceil(lead_s / T)`` setpoints, at most
        the device's buffer capacity. Default :data:`DEFAULT_LEAD_S` (250 ms): Klipper schedules 100 ms or more
        ahead; the longest host starvation measured on the 2-core test machine with both cores busy was about
        205 ms (BENCHMARKS.md), and a serial device's buffer is cheap (6 bytes a setpoint, spec 16.5).
    **kwargs
        See :class:`~rig.transports.base.Transport`.
    """

    def __init__(self, port: str, *, baudrate: int = 2_000_000, reply_timeout_s: float = 0.5, reply_retries: int = 3,
                 protocol: str = "auto", lead_s: float = DEFAULT_LEAD_S, **kwargs) -> None:
        super().__init__(**kwargs)
        if protocol not in PROTOCOLS:
            raise ConfigError("<transport>", "protocol", f"expected one of {', '.join(map(repr, PROTOCOLS))}, got {protocol!r}")
        self.protocol = protocol
        if not (math.isfinite(lead_s) and lead_s > 0):
            raise ConfigError("<transport>", "lead_s", f"expected a lead > 0 s, got {lead_s!r}")
        self.lead_s = float(lead_s)
        self.port = port
        self.baudrate = int(baudrate)
        self.reply_timeout_s = float(reply_timeout_s)
        self.reply_retries = int(reply_retries)
        if self.baudrate <= 0:
            raise ConfigError("<transport>", "baudrate", f"expected a baud rate > 0, got {baudrate!r}")
        if not 0 < self.reply_timeout_s <= MAX_REPLY_TIMEOUT_S:
            raise ConfigError("<transport>", "reply_timeout_s", (
                f"expected a number of seconds in (0, {MAX_REPLY_TIMEOUT_S:g}], got {reply_timeout_s!r} (the device's "
                "link watchdog may expect a frame at least every second; a slow device is served by reply_retries)"))
        if not 0 <= self.reply_retries <= 10:
            raise ConfigError("<transport>", "reply_retries",
                              f"expected an integer from 0 to 10, got {reply_retries!r}")
        rate_hz = 1.0 / self.sample_period_s
        self.load = link_load(rate_hz, self.baudrate)
        if self.load.load > 1.0:
            needed = self.load.bits_per_cycle * rate_hz
            raise ConfigError("<transport>", "baudrate", (
                f"{self.baudrate} baud cannot carry {rate_hz:g} Hz: one sample's SETPOINT and FEEDBACK take "
                f"{self.load.bits_per_cycle} bit on an 8N1 UART ({UART_BITS_PER_BYTE} bit per byte), "
                f"{100 * self.load.load:.0f}% of the line; the highest sample rate it carries is "
                f"{self.load.max_rate_hz:.0f} Hz (or raise the baud rate to at least {needed:.0f})"))
        self.retries = 0  # requests sent again because their answer was lost
        self._serial = None
        self._decoder = FrameDecoder()
        # samples in wire order; in v2 a FAULT frame waits here behind the TICKs that came before it (and
        # lets the faulted tick's own TICK pass), so that every tick the device reported is filed
        self._feedback: collections.deque[FeedbackSample | DeviceFault] = collections.deque()
        self._answers: dict[tuple[MessageType, int], SerialMessage] = {}
        self._request = 0
        self._last_seq = 0
        self._valid_frames = 0
        self._code_needed = False  # a faulted statusword came without a FAULT frame: read the code
        self._reset_clock()

    def _reset_clock(self) -> None:
        """Forget the device clock of a previous bring-up (v2 state)."""
        self.version = 1  # the protocol this bring-up speaks (from the handshake)
        self.buffer_capacity = 0
        self._started = False  # START sent and answered
        self._queued_any = False
        self._device_sample = -1  # the highest tick the device reported
        self._ticks: TickBuffer | None = None  # the device's clock and the targets it may hold, from the first SETPOINT
        self._queued_at: dict[int, float] = {}  # tick -> host time its SETPOINT was written
        self._min_lead_s = math.inf
        self._fault_sample: int | None = None
        self._fault_heard_s = math.inf  # when the FAULT frame arrived (v2)

    @property
    def lead_samples(self) -> int:
        if self.version < 2:
            return 0  # v1: host-paced
        return self._samples_ahead(self.lead_s, self.buffer_capacity)

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
        self._request = REQUEST_ORIGINS.randrange(0xFFFF)  # the next request number is 1 more (spec section 6)
        status = self._request_reply(MessageType.STATUS_REQUEST)
        self._negotiate()
        return self.drive.rad_from_counts(status.fields[1])

    def _negotiate(self) -> None:
        """The version handshake (spec section 16.2), before anything enabling: HELLO -> DEVICE_INFO."""
        self._reset_clock()
        if self.protocol == "v1":
            return
        try:
            info = self._request_reply(MessageType.HELLO, PROTOCOL_VERSION, attempts=HELLO_ATTEMPTS)
        except TransportError:
            if self.protocol == "v2":
                raise TransportError(
                    f"{self.name}: no DEVICE_INFO answer to HELLO ({HELLO_ATTEMPTS} attempts): the device speaks only "
                    "protocol v1 (it drops HELLO); set [transport] protocol = \"auto\" to drive it host-paced, or update "
                    "its firmware (docs/serial_protocol.md, section 16)") from None
            self._ride_through("the device did not answer HELLO: driven as a protocol v1 device (host-paced; the host's "
                               "timing decides the sample instants)")
            return
        version, capacity, period_ns = info.fields
        if version > PROTOCOL_VERSION or version < 1:
            raise TransportError(f"{self.name}: DEVICE_INFO says protocol version {version}; this host asked for at most "
                                 f"{PROTOCOL_VERSION} (the device must answer with the lower of the two)")
        if version < 2:
            if self.protocol == "v2":
                raise TransportError(f"{self.name}: the device answers HELLO with protocol version {version}; "
                                     "[transport] protocol = \"v2\" needs 2")
            return
        period_s = period_ns * 1e-9
        if not math.isclose(period_s, self.sample_period_s, rel_tol=1e-6, abs_tol=1e-9):
            raise ConfigError("<transport>", "sample_rate_hz", (
                f"{1 / self.sample_period_s:g} Hz, but the device ticks every {period_ns} ns ({1 / period_s:g} Hz, "
                "DEVICE_INFO): set sample_rate_hz to the device's rate" if period_ns else
                "the device reports a sample period of 0 ns in DEVICE_INFO"))
        if capacity < 1:
            raise TransportError(f"{self.name}: DEVICE_INFO reports a setpoint buffer of {capacity}; v2 needs at least 1")
        self.version, self.buffer_capacity = 2, int(capacity)

    def _write_controlword(self, controlword: int) -> None:
        self._request_reply(MessageType.CONTROL, controlword)

    def _read_statusword(self) -> int:
        return self._request_reply(MessageType.STATUS_REQUEST).fields[0]

    def _read_error_code(self) -> int | None:
        return self._request_reply(MessageType.ERROR_REQUEST).fields[0]

    def _after_enabled(self) -> None:
        # A FAULT frame that came before the drive reached OPERATION ENABLED reported a fault the bring-up
        # has since reset (the walk succeeded): it must not stop the run.
        with self._fault_lock:
            earlier, self._fault = self._fault, None
        self._code_needed = False
        if earlier is not None:
            self._ride_through(f"before enabling: {earlier} (reset by the bring-up)")
        return None

    def _send(self, setpoint: Setpoint) -> None:
        """v1: the setpoint of this sample, now. v2: queued in the device's buffer for tick ``seq``, nearer the
        target in force than the plan after a stall (:mod:`rig.transports.tick_buffer`); not written at all when
        the device has reported tick ``seq`` (it would drop it, spec 16.3: that tick was HELD)."""
        counts = self.drive.counts_from_rad(setpoint.position_rad)
        self._last_seq = setpoint.seq
        if self.version < 2:
            self._write(encode_frame(MessageType.SETPOINT, setpoint.seq, counts))
            return
        now = self.clock()
        self._queued_any = True
        ticks = self._tick_buffer()
        counts = ticks.place(setpoint.seq, counts, now, reported=self._device_sample, toward_plan=self._toward_plan)
        if counts is None:  # too late: its lead, from the device clock's estimate
            self._min_lead_s = min(self._min_lead_s, ticks.instant_s(setpoint.seq) - now)
            return
        self._write(encode_frame(MessageType.SETPOINT, setpoint.seq, counts))
        if self._started:  # queued before START, a setpoint is ahead of a clock that has not started
            self._queued_at[setpoint.seq] = now

    def _tick_buffer(self) -> TickBuffer:
        if self._ticks is None:  # before the first setpoint the drive holds where it stood when enabled (spec 16.3)
            self._ticks = TickBuffer(self.sample_period_s, self.drive.counts_from_rad(self.initial_position_rad))
        return self._ticks

    def _received_without_starting(self) -> FeedbackSample | None:
        """Before START (version 2 on) nothing: the device's clock is not started after a failure."""
        if self.version >= 2 and not self._started:
            return None
        return self._recv_internal(0.0)

    def _recv_internal(self, timeout_s: float) -> FeedbackSample | None:
        if self.version >= 2 and not self._started and self._queued_any:
            self._started = True
            self._request_reply(MessageType.START)  # the device's tick 0: the setpoints queued so far are its lead
        deadline = self.clock() + timeout_s
        while True:
            if self._feedback:
                item = self._feedback[0]
                if not isinstance(item, DeviceFault):
                    return self._feedback.popleft()
                # the device's FAULT frame, after every sample that came before it; it acts once the faulted
                # tick's TICK (sent right after it, spec 16.3) is filed, or when that does not come in time
                faulted_tick_in = self._fault_sample is None or self._device_sample >= self._fault_sample
                if faulted_tick_in or self.clock() >= self._fault_heard_s + self._fault_grace_s:
                    self._feedback.popleft()
                    self._report_fault(item)
                    return None
            if self._code_needed:
                self._report_faulted_statusword()
            if self._fault is not None:
                return None
            remaining = deadline - self.clock()
            if not self._poll(max(remaining, 0.0)) and remaining <= 0:
                return None

    @property
    def _fault_grace_s(self) -> float:
        """How long after the FAULT frame the host listens for the faulted tick's TICK (it leaves before the next
        tick, spec 16.5): four periods, at least 10 ms (a loaded host's read delay)."""
        return max(4 * self.sample_period_s, 0.01)

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
            raise TransportError(f"{self.name}: write to {self.port} failed: {err} {_PORT_GONE_HINT}") from err

    def _poll(self, timeout_s: float) -> bool:
        """Read what is there (waiting up to ``timeout_s`` for the first byte) and dispatch the messages."""
        if self._serial is None:
            raise TransportError(f"{self.name}: the port is closed")
        try:
            ready, _, _ = select.select([self._serial.fileno()], [], [], timeout_s)
            if not ready:
                return False
            data = self._serial.read(self._serial.in_waiting or 1)
        except Exception as err:  # serial.SerialException, OSError, ValueError on a closed port
            raise TransportError(f"{self.name}: read from {self.port} failed: {err} {_PORT_GONE_HINT}") from err
        received = self.clock()
        errors_before = self._decoder.errors
        before_first_frame = self._valid_frames == 0
        messages = self._decoder.feed(data)
        self._valid_frames += len(messages)
        if not before_first_frame:  # bytes before the device's first frame are its boot output, not line noise
            self._count_frame_errors("CRC or COBS failure, or an unknown frame type", self._decoder.errors - errors_before)
        for message in messages:
            self._dispatch(message, received)
        return True

    def _dispatch(self, message: SerialMessage, received_s: float) -> None:
        if message.type is MessageType.FEEDBACK:
            statusword, actual, encoder_raw = message.fields
            seq = unwrap_seq(message.seq, self._last_seq)
            try:
                counts = self._encoder_value(encoder_raw, seq)
            except TransportError as err:  # reported like a device fault: a request/answer in progress goes on
                self._report_fault(err)
                return
            state = cia402.state_from_statusword_or_none(statusword)
            self._feedback.append(FeedbackSample(
                seq=seq, encoder_counts=counts, load_angle_rad=self._decode_encoder(counts),
                drive_position_rad=self.drive.rad_from_counts(actual), statusword=statusword, host_time_s=received_s,
                target_ignored=(state is cia402.DriveState.OPERATION_ENABLED
                                and not statusword & cia402.STATUSWORD_FOLLOWS_TARGET)))
            if state in _FAULT_STATES:
                self._code_needed = self._fault is None
        elif message.type is MessageType.TICK and self.version >= 2:
            self._tick(message, received_s)
        elif message.type is MessageType.STATUS and message.seq == 0:
            self._unprompted_status(message.fields[0])
        elif message.type is MessageType.FAULT:
            self._code_needed = False
            fault = DeviceFault(self.drive_label, message.fields[0], "the device reported a fault")
            if self._started:
                if self._fault_sample is None:
                    self._fault_sample = self._device_sample + 1  # it comes before the TICK of the tick it happened in
                    self._fault_heard_s = received_s
                self._feedback.append(fault)  # raised once the TICKs received before it are filed
            else:
                self._report_fault(fault)
        elif message.type in (MessageType.STATUS, MessageType.ERROR, MessageType.DEVICE_INFO):
            self._answers[message.type, message.seq] = message

    def _tick(self, message: SerialMessage, received_s: float) -> None:
        """TICK k (v2): what the device measured at its own tick k, the target it applied, whether it held."""
        statusword, actual, encoder_raw, applied, flags, _level = message.fields
        k = unwrap_seq(message.seq, self._device_sample + 1)
        try:
            counts = self._encoder_value(encoder_raw, k)
        except TransportError as err:
            self._report_fault(err)
            return
        held = bool(flags & TICK_HELD)
        ticks = self._tick_buffer()
        ticks.heard(k, received_s)
        ticks.in_force(k, applied)
        queued = self._queued_at.pop(k, None)
        if queued is not None:
            lead = ticks.instant_s(k) - queued
            self._min_lead_s = min(self._min_lead_s, min(lead, 0.0) if held else lead)
        if k > self._device_sample:
            if len(self._queued_at) > 4 * max(self.buffer_capacity, 16):  # setpoints whose TICK was lost
                for old in [seq for seq in self._queued_at if seq < k]:
                    del self._queued_at[old]
            self._device_sample = k
        state = cia402.state_from_statusword_or_none(statusword)
        sample = FeedbackSample(
            seq=k, encoder_counts=counts, load_angle_rad=self._decode_encoder(counts),
            drive_position_rad=self.drive.rad_from_counts(actual), statusword=statusword, host_time_s=received_s,
            target_ignored=(state is cia402.DriveState.OPERATION_ENABLED
                            and not statusword & cia402.STATUSWORD_FOLLOWS_TARGET),
            held=held, applied_position_rad=self.drive.rad_from_counts(applied),
            limited=ticks.limited(k) and not held)  # a HELD tick applied none of it
        fault_waiting = bool(self._feedback) and isinstance(self._feedback[-1], DeviceFault)
        if fault_waiting and state in _FAULT_STATES:  # the faulted tick's TICK: filed before its FAULT frame acts
            self._feedback.insert(len(self._feedback) - 1, sample)
        else:
            self._feedback.append(sample)
        if state in _FAULT_STATES:
            self._code_needed = self._fault is None and not fault_waiting

    def _unprompted_status(self, statusword: int) -> None:
        """STATUS with seq 0: the device says on its own that the drive changed state (its link watchdog
        stopped it, the enable input dropped, it faulted)."""
        state = cia402.state_from_statusword_or_none(statusword)
        if state in _FAULT_STATES:
            self._code_needed = self._fault is None
        elif self._state == "open" and state is not cia402.DriveState.OPERATION_ENABLED:
            self._report_fault(DeviceFault(self.drive_label, None, (
                f"left OPERATION ENABLED without a fault (unprompted STATUS 0x{statusword:04X}: "
                f"{state.name if state else 'no CiA 402 state'}); it no longer follows the targets")))

    def _report_faulted_statusword(self) -> None:
        """A statusword said FAULT but no FAULT frame came (lost to line noise, or a device that sends it
        late): read the code, so that the message names it."""
        self._code_needed = False
        code = cia402.fault_code_or_none(self._read_error_code)
        self._report_fault(DeviceFault(self.drive_label, code, (
            "the drive reports FAULT in its statusword (no FAULT frame came; the code was read with ERROR_REQUEST)"
            if code is not None else "the drive reports FAULT in its statusword")))

    def _encoder_value(self, raw: int, seq: int) -> int:
        """The position value from FEEDBACK's 32 bits: zero-extended (unsigned encoder) or sign-extended
        (signed) from the encoder's n+m bits; anything else is a device or config error, named."""
        width = self.encoder.bits + self.encoder.multi_turn_bits
        value = raw - (1 << 32) if self.encoder.signed and raw >= 1 << 31 else raw
        low = -(1 << (width - 1)) if self.encoder.signed else 0
        if not low <= value < low + (1 << width):
            raise TransportError(
                f"{self.name}: FEEDBACK {seq}: encoder_counts 0x{raw:08X} is no {width}-bit "
                f"{'signed (sign-extended)' if self.encoder.signed else 'unsigned (zero-extended)'} position value; "
                "check [encoder] bits, multi_turn_bits and signed against the firmware (docs/serial_protocol.md, "
                "FEEDBACK)")
        return value

    def _request_reply(self, kind: MessageType, *fields: int, attempts: int | None = None) -> SerialMessage:
        """Send a request and return its answer, sending the same frame again (same request number) after
        each ``reply_timeout_s`` without an answer, at most ``reply_retries`` times (``attempts``: at most
        that many sends in all)."""
        self._request = self._request % 0xFFFF + 1  # 1..65535: 0 marks unprompted STATUS
        request, answer = self._request, _ANSWER_TO[kind]
        self._answers.clear()  # one request at a time: anything left is a late copy of an older answer
        frame = encode_frame(kind, request, *fields)
        attempts = 1 + self.reply_retries if attempts is None else min(attempts, 1 + self.reply_retries)
        for attempt in range(attempts):
            if attempt:
                self.retries += 1
            self._write(frame)
            deadline = self.clock() + self.reply_timeout_s
            while (answer, request) not in self._answers:
                remaining = deadline - self.clock()
                if remaining <= 0:
                    break
                self._poll(remaining)
            else:
                return self._answers.pop((answer, request))
        hint = ""
        if self._valid_frames == 0 and self._decoder.errors:
            hint = (f"; {self._decoder.errors} damaged frames and no valid one came: is the baud rate "
                    f"{self.baudrate} the firmware's?")
        raise TransportError(f"{self.name}: no {answer.name} answer to {kind.name} (request {request}) within "
                             f"{self.reply_timeout_s:g} s, {attempts} attempts{hint}")
