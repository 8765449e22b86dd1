"""Raw-CAN transport: the fixed frame layout of ``configs/raw_can.dbc`` over any python-can interface.

Per sample the host sends RIG_SETPOINT with the sample number; the device answers with RIG_FEEDBACK
(encoder, statusword) and RIG_DRIVE_FEEDBACK (drive position), both with the same sequence number, so
every answer is attributed to its sample exactly. Bring-up walks the CiA 402 state machine with
RIG_CONTROL frames (each answered by RIG_STATUS); RIG_FAULT from the device stops the run.
The receive side runs in the caller's thread (``bus.recv``): no background threads.

Protocols v4, v3 and v2 (the DBC's comments on RIG_HELLO, RIG_START, RIG_DEVICE_INFO, RIG_DEVICE_INFO_V4,
RIG_DRIVE_TICK, RIG_TICK_APPLIED; the serial spec's section 16, which they mirror): the device owns the sample
clock. :meth:`_prepare` sends RIG_HELLO with the highest version the DBC has the frames for (4); a device
answering RIG_DEVICE_INFO_V4 (v4: v3 with a two-byte buffer capacity, so the lead is not capped at 255 ticks)
or RIG_DEVICE_INFO with version 3 or 2 buffers RIG_SETPOINTs by tick number, ticks from RIG_START on at its own
period, and reports each tick k: in v3 with RIG_FEEDBACK and RIG_DRIVE_TICK (the drive position, the buffer
level and ``applied_age``, from which the host takes the target in force out of the setpoints it sent: 2
frames a tick, 394 bit with the setpoint, so 1 Mbit/s carries 2538 Hz; v4 alike), in v2 with RIG_FEEDBACK,
RIG_DRIVE_FEEDBACK and RIG_TICK_APPLIED (512 bit: 1953 Hz; a v2 device is refused above the rate its bus
carries). A device that does not answer (a v1 device), or a DBC without the v2/v3 frames, is driven
host-paced, the v1 way, unless ``protocol = "v2"``.
"""

from __future__ import annotations

import collections
import math
import time
from typing import Any

from rig.protocols import cia402
from rig.protocols.can_bus_load import BusLoad, bus_load
from rig.protocols.can_interfaces import open_bus
from rig.protocols.can_error_frames import describe_error_frame, is_bus_off
from rig.protocols.errors import ConfigError, DeviceFault, TransportError
from rig.protocols.raw_can_frames import DEFAULT_DBC, RawCanCodec
from rig.protocols.serial_frames import unwrap_seq
from rig.transports.base import FeedbackSample, Setpoint, Transport, check_trace_path
from rig.transports import serial_link
from rig.transports.serial_link import DEFAULT_LEAD_S
from rig.transports.tick_buffer import TickBuffer

__all__ = ["RawCanTransport"]

_PROTOCOLS = ("auto", "v1", "v2")
_CLOCKED_MESSAGES = ("RIG_HELLO", "RIG_START", "RIG_DEVICE_INFO")  # the handshake of v2 and v3
_TICK_FRAMES = {1: ("RIG_FEEDBACK", "RIG_DRIVE_FEEDBACK"),  # per sample (v1) or per tick (v2, v3, v4), by version
                2: ("RIG_FEEDBACK", "RIG_DRIVE_FEEDBACK", "RIG_TICK_APPLIED"),
                3: ("RIG_FEEDBACK", "RIG_DRIVE_TICK"),
                4: ("RIG_FEEDBACK", "RIG_DRIVE_TICK")}
_V4_INFO = "RIG_DEVICE_INFO_V4"  # v4's answer to RIG_HELLO: v3 with a two-byte buffer capacity
_AGE_UNKNOWN = 255  # RIG_DRIVE_TICK applied_age: the target of tick k-1 (DBC comment on RIG_DRIVE_TICK)
_FAULT_STATES = (cia402.DriveState.FAULT, cia402.DriveState.FAULT_REACTION_ACTIVE)


class RawCanTransport(Transport):
    """The rig over raw CAN frames.

    Parameters
    ----------
    interface, channel, port
        python-can interface name and channel (from ``can://INTERFACE/CHANNEL``), and the UDP port of
        ``can://udp_multicast:PORT/GROUP`` (:mod:`rig.protocols.can_interfaces`).
    bitrate
        Bus bit rate; a cycle's frames (RIG_SETPOINT and the device's: 3 frames in v1 and v3, 4 in v2) must fit
        at the sample rate (:class:`ConfigError` if not: at config load for the best version the DBC has, after
        the handshake for the version the device speaks).
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
    protocol
        ``"auto"`` (default): v4, v3 or v2 (the device's clock) if the device answers RIG_HELLO, else v1 (host-paced,
        with a warning); ``"v2"``: refuse a device that does not own the clock (v2, v3 or v4 is accepted);
        ``"v1"``: send no RIG_HELLO.
    lead_s
        v2-v4: how far ahead of the device's ticks setpoints are queued, at most its buffer (RIG_DEVICE_INFO: at
        most 255 setpoints, 127.5 ms at 2 kHz; RIG_DEVICE_INFO_V4: at most 65535). Default: serial's :data:`~rig.transports.serial_link.DEFAULT_LEAD_S`
        (250 ms; why: see there), the protocol this one mirrors.
    """

    def __init__(self, interface: str, channel: str, *, port: int | None = None, bitrate: int = 1_000_000,
                 dbc: str = str(DEFAULT_DBC),
                 reply_timeout_s: float = 0.5, reply_retries: int = 3, trace_path: str | None = None,
                 protocol: str = "auto", lead_s: float = DEFAULT_LEAD_S, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if protocol not in _PROTOCOLS:
            raise ConfigError("<transport>", "protocol", f"expected one of {', '.join(map(repr, _PROTOCOLS))}, got {protocol!r}")
        if not (math.isfinite(lead_s) and lead_s > 0):
            raise ConfigError("<transport>", "lead_s", f"expected a lead > 0 s, got {lead_s!r}")
        self.protocol, self.lead_s = protocol, float(lead_s)
        self.interface, self.channel, self.port, self.bitrate = interface, channel, port, int(bitrate)
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
        handshake = protocol != "v1" and all(name in lengths for name in _CLOCKED_MESSAGES)
        # the highest version the DBC has the frames of: what RIG_HELLO asks for
        self.max_version = max([1] + [version for version in (2, 3, 4) if handshake
                                      and all(name in lengths for name in _TICK_FRAMES[version])
                                      and (version < 4 or _V4_INFO in lengths)])
        self.speaks_v2 = self.max_version >= 2
        self.load = self._cycle_load(self.max_version)
        if self.load.load > 1.0:
            raise ConfigError("<transport>", "bitrate", (
                f"{self.bitrate} bit/s cannot carry {1 / self.sample_period_s:g} Hz: one cycle takes "
                f"{self.load.bits_per_cycle} bit ({100 * self.load.load:.0f}% load); the limit is "
                f"{self.load.max_rate_hz:.0f} Hz (protocol v{self.max_version}, {len(_TICK_FRAMES[self.max_version]) + 1} "
                "frames a cycle)"))
        if protocol == "v2" and not self.speaks_v2:
            raise ConfigError("<transport>", "dbc", f"protocol = \"v2\" needs the frames {', '.join(_CLOCKED_MESSAGES)} "
                              f"and {' or '.join(', '.join(_TICK_FRAMES[v][1:]) for v in (3, 2))} in {dbc}")
        self.trace_path = check_trace_path(trace_path)
        self._trace = None
        self._bus = None
        self._request = 0
        self._status: dict[int, dict[str, int]] = {}
        self._parts: dict[int, dict[str, Any]] = {}
        self._last_seq = 0
        self._reset_clock()

    def _reset_clock(self) -> None:
        self.version, self.buffer_capacity = 1, 0
        self._started = self._queued_any = False
        self._device_sample = -1
        self._ticks: TickBuffer | None = None  # the device's clock and the targets it may hold, from the first setpoint
        self._queued_at: dict[int, float] = {}
        self._min_lead_s = math.inf
        self._sent_counts: dict[int, int] = {}  # v3: tick -> target_counts sent for it (applied_age looks back)
        self._in_force: tuple[int, int] | None = None  # v3: (tick, target counts in force) of the latest tick filed
        self._fault_sample: int | None = None
        self._pending_fault: DeviceFault | None = None  # v2: RIG_FAULT, until the faulted tick's frames are in
        self._pending_fault_s = math.inf  # when that RIG_FAULT arrived
        self._fault_after: tuple[int, DeviceFault] | None = None  # a faulted statusword's tick, and its fault
        self._info: dict[int, dict[str, int]] = {}
        # samples completed while the host waited for an answer (RIG_START's may take 100 ms: the device
        # ticks meanwhile), handed out by the next receives in order
        self._ready: collections.deque[FeedbackSample] = collections.deque()
        # v3 ticks completed before RIG_START's answer, which says the target in force before any setpoint
        self._unresolved: list[tuple[int, dict[str, Any], float]] = []
        self._target_unknown_warned = False

    @property
    def lead_samples(self) -> int:
        if self.version < 2:
            return 0
        return self._samples_ahead(self.lead_s, self.buffer_capacity)

    def _cycle_load(self, version: int) -> BusLoad:
        """The bus load of one cycle (RIG_SETPOINT and the device's frames of ``version``) at the sample rate."""
        names = ("RIG_SETPOINT",) + _TICK_FRAMES[version]
        return bus_load(tuple(self.codec.lengths[name] for name in names), 1.0 / self.sample_period_s, self.bitrate)

    # -- seam ----------------------------------------------------------------------------------------------

    @property
    def min_cycle_s(self) -> float:
        """One cycle's frames on the bus (worst-case bit stuffing): SYNCs/commands are never closer."""
        return 1.0 / self.load.max_rate_hz

    def _connect(self) -> None:
        import can

        try:
            self._bus = open_bus(self.interface, self.channel, port=self.port, bitrate=self.bitrate)
        except (can.CanError, OSError, ValueError) as err:
            raise TransportError(f"{self.name}: cannot open CAN {self.interface}/{self.channel}: {err}") from err
        if self.trace_path is not None:
            self._trace = can.Logger(self.trace_path)

    def _prepare(self) -> float:
        self._request = serial_link.REQUEST_ORIGINS.randrange(0xFFFF)  # as serial (its spec, section 6)
        position = self.drive.rad_from_counts(self._request_reply("RIG_STATUS_REQUEST")["actual_counts"])
        self._negotiate()
        self.load = self._cycle_load(self.version)  # the frames this device really sends
        return position

    def _negotiate(self) -> None:
        """RIG_HELLO -> RIG_DEVICE_INFO, before anything enabling (as serial v2, spec section 16.2)."""
        self._reset_clock()
        if not self.speaks_v2:
            return
        try:
            info = self._request_reply("RIG_HELLO", answer="RIG_DEVICE_INFO", attempts=2, version=self.max_version)
        except TransportError:
            if self.protocol == "v2":
                raise TransportError(f"{self.name}: no RIG_DEVICE_INFO answer to RIG_HELLO: the device speaks only "
                                     "protocol v1; set [transport] protocol = \"auto\" to drive it host-paced") from None
            self._ride_through("the device did not answer RIG_HELLO: driven as a protocol v1 device (host-paced; the "
                               "host's timing decides the sample instants)")
            return
        version, capacity, period_ns = info["version"], info["buffer_capacity"], info["sample_period_ns"]
        if version > self.max_version or version < 1:
            raise TransportError(f"{self.name}: RIG_DEVICE_INFO says protocol version {version}; the host asked for "
                                 f"at most {self.max_version}")
        if version < 2:
            if self.protocol == "v2":
                raise TransportError(f"{self.name}: the device answers RIG_HELLO with version {version}; "
                                     "protocol = \"v2\" needs 2 or later")
            return
        load = self._cycle_load(version)
        if load.load > 1.0:
            raise ConfigError("<transport>", "sample_rate_hz", (
                f"{1 / self.sample_period_s:g} Hz, but the device speaks raw-CAN protocol v{version} "
                f"({len(_TICK_FRAMES[version])} frames a tick, {load.bits_per_cycle} bit a cycle with the setpoint): "
                f"{self.bitrate} bit/s carries at most {load.max_rate_hz:.0f} Hz; lower sample_rate_hz to that, or "
                "update the device to protocol v3 or later (configs/raw_can.dbc, RIG_DRIVE_TICK)"))
        if not math.isclose(period_ns * 1e-9, self.sample_period_s, rel_tol=1e-6, abs_tol=1e-9):
            raise ConfigError("<transport>", "sample_rate_hz", (
                f"{1 / self.sample_period_s:g} Hz, but the device ticks every {period_ns} ns (RIG_DEVICE_INFO): set "
                "sample_rate_hz to the device's rate"))
        if capacity < 1:
            raise TransportError(f"{self.name}: RIG_DEVICE_INFO reports a setpoint buffer of {capacity}")
        self.version, self.buffer_capacity = int(version), int(capacity)

    def _write_controlword(self, controlword: int) -> None:
        self._request_reply("RIG_CONTROL", controlword=controlword)

    def _read_statusword(self) -> int:
        return self._request_reply("RIG_STATUS_REQUEST")["statusword"]

    def _send(self, setpoint: Setpoint) -> None:
        """v1: the setpoint of this sample, now. v2-v4: buffered by the device for tick ``seq``, nearer the target
        in force than the plan after a stall (:mod:`rig.transports.tick_buffer`); not sent at all when the device
        has reported tick ``seq`` (it would drop it, DBC: after a long stall the host does not flood the bus, and
        its own receive queue, with hundreds of them)."""
        counts = self.drive.counts_from_rad(setpoint.position_rad)
        self._last_seq = setpoint.seq
        if self.version < 2:
            self._transmit(self.codec.encode("RIG_SETPOINT", seq=setpoint.seq, target_counts=counts))
            return
        now = self.clock()
        self._queued_any = True
        ticks = self._tick_buffer()
        counts = ticks.place(setpoint.seq, counts, now, reported=self._device_sample, toward_plan=self._toward_plan)
        if counts is None:  # its tick has been reported: HELD
            self._min_lead_s = min(self._min_lead_s, ticks.instant_s(setpoint.seq) - now)
            return
        self._transmit(self.codec.encode("RIG_SETPOINT", seq=setpoint.seq, target_counts=counts))
        if self.version >= 3:
            self._sent_counts[setpoint.seq] = counts
        if self._started:  # queued before START, a setpoint is ahead of a clock that has not started
            self._queued_at[setpoint.seq] = now

    def _tick_buffer(self) -> TickBuffer:
        if self._ticks is None:  # before the first setpoint the drive holds where it stood when enabled
            self._ticks = TickBuffer(self.sample_period_s, self.drive.counts_from_rad(self.initial_position_rad))
        return self._ticks

    def _received_without_starting(self) -> FeedbackSample | None:
        """Before RIG_START (version 2 on) nothing: the device's clock is not started after a failure."""
        if self.version >= 2 and not self._started:
            return None
        return self._recv_internal(0.0)

    def _recv_internal(self, timeout_s: float) -> FeedbackSample | None:
        if self.version >= 2 and not self._started and self._queued_any:
            self._started = True
            status = self._request_reply("RIG_START")  # the device's tick 0: the setpoints queued so far are its lead
            self._in_force = (-1, status["actual_counts"])  # before any setpoint: the position held since enabling
            unresolved, self._unresolved = self._unresolved, []
            for seq, parts, received in unresolved:  # ticks that came before this answer, in their order
                self._ready.append(self._tick_sample(seq, parts, received))
        if self._ready:
            self._read_waiting_frames()
            return self._hand_out(self._ready.popleft())
        if self._fault_after is not None:  # its tick's sample is no longer waiting
            self._report_fault(self._fault_after[1])
            return None
        deadline = self.clock() + timeout_s
        while True:
            sample = self._receive_one(max(deadline - self.clock(), 0.0))
            if isinstance(sample, FeedbackSample):
                return self._hand_out(sample)
            if self._pending_fault is not None and self.clock() >= self._pending_fault_s + self._fault_grace_s:
                self._report_fault(self._pending_fault)  # the faulted tick's frames did not follow
            if sample is None and self.clock() >= deadline:
                return None
            if self._fault is not None:
                return None

    def _hand_out(self, sample: FeedbackSample) -> FeedbackSample:
        """``sample`` to the caller; once the faulted tick's sample is out, its fault is raised by the next
        receive (the samples before it, also those that waited in ``_ready``, are all filed first)."""
        if self._fault_after is not None and sample.seq >= self._fault_after[0]:
            self._report_fault(self._fault_after[1])
        return sample

    def _read_waiting_frames(self, limit: int = 64) -> None:
        """While samples wait to be handed out (those that came during an answer's wait), read the frames that
        have arrived meanwhile too (at most ``limit``): the device goes on sending two or three a tick, and an
        adapter's (or udp_multicast's) receive queue that is not read overflows."""
        for _ in range(limit):
            sample = self._receive_one(0.0)
            if sample is None:
                return
            if isinstance(sample, FeedbackSample):
                self._ready.append(sample)

    @property
    def _fault_grace_s(self) -> float:
        """How long after RIG_FAULT the host waits for the frames of the faulted tick (they leave before the
        next tick, DBC comment on RIG_FAULT): four periods, at least 10 ms (a loaded host's read delay)."""
        return max(4 * self.sample_period_s, 0.01)

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
            self._count_frame_errors(f"CAN error frame {bytes(msg.data).hex()}")
            if is_bus_off(msg):
                self._report_fault(TransportError(
                    f"{self.name}: the CAN controller went bus off ({describe_error_frame(msg)}): nothing can be "
                    "sent or received; check wiring, termination and the bit rate of every node"))
            return True
        try:
            decoded = self.codec.decode(msg)
        except ValueError as err:
            self._count_frame_errors(f"0x{msg.arbitration_id:X}: {err}")
            return True
        if decoded is None:
            return True
        name, signals = decoded
        if name == "RIG_STATUS" and signals["seq"] == 0:
            self._unprompted_status(signals["statusword"])
        elif name == "RIG_STATUS":
            self._status[signals["seq"]] = signals
        elif name == "RIG_DEVICE_INFO":
            self._info[signals["seq"]] = signals
        elif name == _V4_INFO:  # the version is the frame's
            self._info[signals["seq"]] = {**signals, "version": 4}
        elif name == "RIG_FAULT":
            fault = DeviceFault(self.name, signals["error_code"], "the device reported a fault")
            if self._started:  # sent before the frames of the tick it happened in: that tick is filed first
                if self._fault_sample is None:
                    self._fault_sample = self._device_sample + 1
                self._pending_fault, self._pending_fault_s = fault, self.clock()
            else:
                self._report_fault(fault)
        elif name in _TICK_FRAMES[self.version]:
            v2 = self.version >= 2
            seq = unwrap_seq(signals["seq"], self._device_sample + 1 if v2 else self._last_seq)
            parts = self._parts.setdefault(seq, {})
            parts[name] = signals
            if len(parts) == len(_TICK_FRAMES[self.version]):
                del self._parts[seq]
                received = self.clock()
                if v2:
                    self._account_tick(seq, self._tick_held(parts), received)
                statusword = parts["RIG_FEEDBACK"]["statusword"]
                if cia402.state_from_statusword_or_none(statusword) in _FAULT_STATES:
                    self._faulted_statusword(seq, statusword)
                if self.version >= 3 and self._in_force is None:  # before RIG_START's answer: resolved with it
                    self._unresolved.append((seq, parts, received))
                    return True
                return self._tick_sample(seq, parts, received)
            if len(self._parts) > 256:
                for old in sorted(self._parts)[:128]:
                    del self._parts[old]
        return True

    def _tick_held(self, parts: dict[str, Any]) -> bool:
        if self.version >= 3:
            return parts["RIG_DRIVE_TICK"]["applied_age"] > 0
        return bool(parts["RIG_TICK_APPLIED"]["tick_flags"] & 1)

    def _tick_sample(self, seq: int, parts: dict[str, Any], received: float) -> FeedbackSample:
        """The sample of one complete tick (v1: one answer): encoder and statusword of RIG_FEEDBACK, drive position,
        and on a device-clocked link whether it was HELD and the target in force. Statusword bit 12 clear in
        OPERATION ENABLED: the drive did not follow the target (NOT_FOLLOWED; serial spec section 5)."""
        feedback = parts["RIG_FEEDBACK"]
        drive = parts["RIG_DRIVE_TICK" if self.version >= 3 else "RIG_DRIVE_FEEDBACK"]
        raw = feedback["encoder_counts"]
        counts = raw - (1 << 32) if self.encoder.signed and raw >= 1 << 31 else raw
        held, applied, unknown, limited = False, None, False, False
        if self.version >= 3:
            age = drive["applied_age"]
            held, applied_counts = age > 0, self._target_in_force(seq, age)
            if applied_counts is None:
                applied_counts, unknown = self._last_known_target(seq), True
            applied = self.drive.rad_from_counts(applied_counts)
        elif self.version >= 2:
            tick = parts["RIG_TICK_APPLIED"]
            held, applied_counts = bool(tick["tick_flags"] & 1), tick["applied_counts"]
            applied = self.drive.rad_from_counts(applied_counts)
        if self.version >= 2:
            ticks = self._tick_buffer()
            if not unknown:
                ticks.in_force(seq, applied_counts)
            limited = ticks.limited(seq) and not held  # a HELD tick applied none of it
        statusword = feedback["statusword"]
        state = cia402.state_from_statusword_or_none(statusword)
        return FeedbackSample(seq=seq, encoder_counts=counts, load_angle_rad=self._decode_encoder(counts),
                              drive_position_rad=self.drive.rad_from_counts(drive["actual_counts"]),
                              statusword=statusword, host_time_s=received, held=held, applied_position_rad=applied,
                              target_ignored=(state is cia402.DriveState.OPERATION_ENABLED
                                              and not statusword & cia402.STATUSWORD_FOLLOWS_TARGET),
                              ambiguous=unknown, limited=limited)

    def _last_known_target(self, k: int) -> int:
        """v3, tick k's target not known (``applied_age`` 255 and the frames of the ticks before lost): the
        latest target known, logged with the sample flagged AMBIGUOUS (unusable), and said once in a warning."""
        if not self._target_unknown_warned:
            self._target_unknown_warned = True
            self._ride_through(
                f"tick {k}: the target in force is not known (RIG_DRIVE_TICK applied_age 255 after a hold of more "
                "than 254 ticks whose earlier tick frames were lost): such samples are logged HELD and AMBIGUOUS "
                "(unusable), with the latest target known")
        return self._in_force[1] if self._in_force is not None else self.drive.counts_from_rad(self.initial_position_rad)

    def _unprompted_status(self, statusword: int) -> None:
        """RIG_STATUS with seq 0 (never a request number): the device says on its own that the drive changed
        state (its link watchdog stopped it, the enable input dropped), as serial's STATUS seq 0."""
        state = cia402.state_from_statusword_or_none(statusword)
        if state in _FAULT_STATES:
            self._report_fault(DeviceFault(self.name, None, f"the drive reports FAULT (unprompted RIG_STATUS "
                                                            f"0x{statusword:04X}; no RIG_FAULT frame came)"))
        elif self._state == "open" and state is not cia402.DriveState.OPERATION_ENABLED:
            self._report_fault(DeviceFault(self.name, None, (
                f"left OPERATION ENABLED without a fault (unprompted RIG_STATUS 0x{statusword:04X}: "
                f"{state.name if state else 'no CiA 402 state'}); it no longer follows the targets")))

    def _faulted_statusword(self, seq: int, statusword: int) -> None:
        """A statusword says FAULT: the run stops at this sample even if RIG_FAULT was lost on the bus (the
        serial spec's section 9, which the DBC follows). Raw CAN has no request for the error code."""
        if self._pending_fault is not None:  # the faulted tick after its RIG_FAULT: the code is known
            fault = self._pending_fault
        else:
            if self._fault is None and self._fault_sample is None:
                self._fault_sample = seq
            fault = DeviceFault(self.name, None, (
                f"the drive reports FAULT in its statusword 0x{statusword:04X} at sample {seq} (no RIG_FAULT frame "
                "came with the error code: lost on the bus?)"))
        if self._fault_after is None:  # raised once this tick's sample is handed out (it may wait in _ready)
            self._fault_after = (seq, fault)

    def _target_in_force(self, k: int, age: int) -> int | None:
        """v3: the target counts in force at tick k from RIG_DRIVE_TICK's ``applied_age`` (DBC comment): the
        setpoint sent for tick k - age, or for age 255 the target of the latest tick filed if no setpoint can
        have been applied since (it is at most 255 ticks back; the position at START before any). None: not
        known (every tick of a hold longer than 254 ticks lost on the bus): the sample stays HELD."""
        if age < _AGE_UNKNOWN:
            counts = self._sent_counts.get(k - age)
        elif self._in_force is not None and self._in_force[0] >= k - _AGE_UNKNOWN:
            counts = self._in_force[1]
        else:
            counts = None
        if counts is not None and (self._in_force is None or k > self._in_force[0]):
            self._in_force = (k, counts)
        return counts

    def _account_tick(self, k: int, held: bool, received_s: float) -> None:
        """Tick k's lead (as on serial v2: tick 0's host time estimated from the earliest arrival) and the
        device's position in its clock."""
        ticks = self._tick_buffer()
        ticks.heard(k, received_s)
        queued = self._queued_at.pop(k, None)
        if queued is not None:
            lead = ticks.instant_s(k) - queued
            self._min_lead_s = min(self._min_lead_s, min(lead, 0.0) if held else lead)
        if k > self._device_sample:
            if len(self._queued_at) > 4 * max(self.buffer_capacity, 16):
                for old in [seq for seq in self._queued_at if seq < k]:
                    del self._queued_at[old]
            if len(self._sent_counts) > 4 * max(self.buffer_capacity, _AGE_UNKNOWN):  # applied_age looks 254 back
                for old in [seq for seq in self._sent_counts if seq < k - _AGE_UNKNOWN]:
                    del self._sent_counts[old]
            self._device_sample = k

    def _request_reply(self, name: str, *, answer: str = "RIG_STATUS", attempts: int | None = None,
                       **signals: int) -> dict[str, int]:
        """Send a request and return its answer (RIG_STATUS, or ``answer``), sending the same frame again (same
        ``seq``) after each ``reply_timeout_s`` without one, at most ``reply_retries`` times (``attempts``: at
        most that many sends in all)."""
        self._request = self._request % 0xFFFF + 1  # 1..65535, as on the serial link
        request = self._request
        self._status.clear()  # one request at a time: anything left is a late copy of an older answer
        self._info.clear()
        answers = self._info if answer == "RIG_DEVICE_INFO" else self._status
        attempts = 1 + self.reply_retries if attempts is None else min(attempts, 1 + self.reply_retries)
        for attempt in range(attempts):
            if attempt:
                self.retries += 1
            self._transmit(self.codec.encode(name, seq=request, **signals))
            deadline = self.clock() + self.reply_timeout_s
            while request not in answers:
                remaining = deadline - self.clock()
                if remaining <= 0:
                    break
                sample = self._receive_one(remaining)
                if isinstance(sample, FeedbackSample):  # a tick while waiting: kept for the next receive
                    self._ready.append(sample)
            else:
                return answers.pop(request)
        raise TransportError(f"{self.name}: no {answer} answer to {name} (seq {request}) within "
                             f"{self.reply_timeout_s:g} s, {attempts} attempts")
