"""A minimal raw-CAN rig device written only from ``configs/raw_can.dbc`` (its frames, signals and comments)
and ``docs/serial_protocol.md`` (the CiA 402 state machine of section 5, the request rules of section 6 and
protocol v2 of section 16, which the DBC's v2/v3 comments refer to): it imports nothing from ``rig`` or
``sim_backend``. The protocol logic is the serial spec device's (:class:`SpecSerialDevice`, the same spec
sections); only the wire differs: CAN frames laid out as the DBC says instead of COBS frames. Raw-CAN v3
is serial v2's protocol with other tick frames (the DBC's comments on RIG_HELLO and RIG_DEVICE_INFO).

Frames (DBC ``BO_`` lines; every signal little-endian, ``@1``; ``+`` unsigned, ``-`` signed; all byte-aligned):

====  ==================  ===  ====================================================================
id    name                DLC  signals (start bit | length)
====  ==================  ===  ====================================================================
256   RIG_CONTROL         4    seq 0|16, controlword 16|16
257   RIG_STATUS_REQUEST  2    seq 0|16
258   RIG_HELLO           3    seq 0|16, version 16|8                                   (v2, v3)
259   RIG_START           2    seq 0|16                                                 (v2, v3)
272   RIG_SETPOINT        6    seq 0|16, target_counts 16|32 signed
384   RIG_STATUS          8    seq 0|16, statusword 16|16, actual_counts 32|32 signed
385   RIG_DEVICE_INFO     8    seq 0|16, version 16|8, buffer_capacity 24|8, sample_period_ns 32|32  (v2, v3)
386   RIG_DEVICE_INFO_V4  8    seq 0|16, buffer_capacity 16|16, sample_period_ns 32|32              (v4)
400   RIG_FEEDBACK        8    seq 0|16, statusword 16|16, encoder_counts 32|32
401   RIG_DRIVE_FEEDBACK  6    seq 0|16, actual_counts 16|32 signed
402   RIG_TICK_APPLIED    8    seq 0|16, applied_counts 16|32 signed, tick_flags 48|8, buffer_level 56|8  (v2)
403   RIG_DRIVE_TICK      8    seq 0|16, actual_counts 16|32 signed, buffer_level 48|8, applied_age 56|8  (v3)
416   RIG_FAULT           2    error_code 0|16
====  ==================  ===  ====================================================================

What the DBC does not say, taken from the serial spec it points to: the link watchdog (section 10 and
16.4; on expiry an unprompted RIG_STATUS with seq 0, as serial's STATUS seq 0) and the buffer rules of
section 16.3. The raw-CAN protocol has no ERROR_REQUEST: the error code travels only in RIG_FAULT.

A tick (DBC comments on RIG_DEVICE_INFO, RIG_TICK_APPLIED and RIG_DRIVE_TICK): in v2 RIG_FEEDBACK,
RIG_DRIVE_FEEDBACK and RIG_TICK_APPLIED; in v3 RIG_FEEDBACK and RIG_DRIVE_TICK, whose ``applied_age`` is 0 when
setpoint k was applied, k - j while the setpoint of tick j (the last one applied) is held, and 255 when that
is 255 or more ticks back or no setpoint was applied since RIG_START.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from spec_serial_device import (
    CONTROL, DEVICE_INFO, FAULT, FEEDBACK, HELLO, SETPOINT, START, STATUS, STATUS_REQUEST, TICK, TICK_HELD,
    SpecSerialDevice,
)

# host -> device: arbitration id -> (message, struct layout of the DBC's signals)
HOST_FRAMES = {256: (CONTROL, "<HH"), 257: (STATUS_REQUEST, "<H"), 272: (SETPOINT, "<Hi")}
HOST_FRAMES_V2 = HOST_FRAMES | {258: (HELLO, "<HB"), 259: (START, "<H")}
RIG_STATUS, RIG_DEVICE_INFO, RIG_FEEDBACK, RIG_DRIVE_FEEDBACK, RIG_TICK_APPLIED, RIG_DRIVE_TICK, RIG_FAULT = (
    384, 385, 400, 401, 402, 403, 416)
RIG_DEVICE_INFO_V4 = 386
TICK_FRAMES = {2: (RIG_FEEDBACK, RIG_DRIVE_FEEDBACK, RIG_TICK_APPLIED), 3: (RIG_FEEDBACK, RIG_DRIVE_TICK),
               4: (RIG_FEEDBACK, RIG_DRIVE_TICK)}  # v4: v3's ticks (DBC comment on RIG_DEVICE_INFO_V4)
AGE_OLD = 255  # RIG_DRIVE_TICK applied_age: 255 or more ticks back, or no setpoint applied since RIG_START


class SpecRawCanDevice(SpecSerialDevice):
    """The device on python-can's ``virtual`` bus ``channel`` (a wall-clock thread), or scripted through
    ``output`` (called with ``(arbitration_id, data)``) on a simulated ``clock``.

    Parameters
    ----------
    channel
        The virtual bus the host's ``can://virtual/<channel>`` opens.
    protocol_version
        The highest version the device speaks: 3 (default), 4, 2 or 1 (``RIG_DEVICE_INFO`` answers the lower of
        it and the host's; in v4 ``RIG_DEVICE_INFO_V4``).
    tick_frame_order
        The order in which the frames of a tick leave (the DBC names them, not their order): an order of
        :data:`TICK_FRAMES` of ``protocol_version`` (default: as the DBC lists them).
    **options
        As :class:`SpecSerialDevice` (``buffer_capacity`` at most 255: one byte in RIG_DEVICE_INFO).
    """

    def __init__(self, *, channel: str = "", protocol_version: int = 3, tick_frame_order: tuple[int, ...] | None = None,
                 output: Callable[[int, bytes], object] | None = None, **options) -> None:
        frames = TICK_FRAMES.get(protocol_version, ())
        order = frames if tick_frame_order is None else tuple(tick_frame_order)
        if sorted(order) != sorted(frames):
            raise ValueError(f"tick_frame_order: expected an order of {frames}, got {tick_frame_order}")
        self.channel, self.tick_frame_order = channel, order
        self._bus = None
        self._frame_output = output
        self._applied_tick: int | None = None  # v3: the tick whose setpoint is in force (None: none since START)
        self._tick_sent = 0  # the next tick to send, counted from the session's START
        self._session_mode = 2  # the protocol of the session START began (its tick frames)
        super().__init__(output=(lambda data: None) if output is not None else None,
                         protocol_version=protocol_version, **options)
        most = 65535 if protocol_version >= 4 else 255  # RIG_DEVICE_INFO_V4's two bytes, RIG_DEVICE_INFO's one
        if not 1 <= self.buffer_capacity <= most:
            raise ValueError(f"buffer_capacity: the device's answer to RIG_HELLO carries 1..{most}, got "
                             f"{self.buffer_capacity}")
        self._host_frames = HOST_FRAMES_V2 if self.protocol_version >= 2 else HOST_FRAMES

    # -- the link: a virtual CAN bus ---------------------------------------------------------------------------

    def _open_link(self) -> Callable[[bytes], object]:
        import can

        self._bus = can.Bus(interface="virtual", channel=self.channel)

        def send(arbitration_id: int, data: bytes) -> None:
            self._bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))

        self._frame_output = send
        return lambda data: None

    def _close_link(self) -> None:
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def _serve(self) -> None:
        while not self._stop.is_set():
            timeout_s = min(0.01, max(0.0, self.next_event_s() - self._clock()))
            message = self._bus.recv(timeout_s)
            if message is not None and not (message.is_extended_id or message.is_remote_frame
                                            or message.is_error_frame):
                self.feed_frame(message.arbitration_id, bytes(message.data))
            else:
                self.run_due()

    def _start(self, seq: int) -> None:
        sessions = self.sessions
        super()._start(seq)
        if self.sessions != sessions:  # tick 0 of a new session: no setpoint applied yet (RIG_DRIVE_TICK, 255)
            self._applied_tick, self._tick_sent, self._session_mode = None, 0, self.mode

    def feed_frame(self, arbitration_id: int, data: bytes) -> None:
        """One CAN frame from the host, received now; a frame of an unknown id or of another length than
        the DBC's is dropped (and not answered); then whatever is due by now."""
        known = self._host_frames.get(arbitration_id)
        if known is not None and len(data) == struct.calcsize(known[1]):
            seq, *fields = struct.unpack(known[1], data)
            self._handle(known[0], seq, tuple(fields))
        self.run_due()

    def _send(self, kind: int, seq: int, *fields: int) -> None:
        """A message of the spec's as the DBC's frames."""
        out = self._frame_output
        if kind == STATUS:
            statusword, actual = fields
            out(RIG_STATUS, struct.pack("<HHi", seq, statusword, actual))
        elif kind == DEVICE_INFO and fields[0] >= 4:  # v4: the version is the frame's, the capacity two bytes
            out(RIG_DEVICE_INFO_V4, struct.pack("<HHI", seq, *fields[1:]))
        elif kind == DEVICE_INFO:
            out(RIG_DEVICE_INFO, struct.pack("<HBBI", seq, *fields))
        elif kind == FAULT:
            out(RIG_FAULT, struct.pack("<H", fields[0]))
        elif kind == FEEDBACK:  # v1: per SETPOINT, RIG_FEEDBACK and RIG_DRIVE_FEEDBACK with its seq
            statusword, actual, encoder = fields
            out(RIG_FEEDBACK, struct.pack("<HHI", seq, statusword, encoder))
            out(RIG_DRIVE_FEEDBACK, struct.pack("<Hi", seq, actual))
        elif kind == TICK:  # the frames of tick seq (DBC comments of RIG_TICK_APPLIED, v2, RIG_DRIVE_TICK, v3)
            statusword, actual, encoder, applied, flags, level = fields
            k, self._tick_sent = self._tick_sent, self._tick_sent + 1  # ticks go out in order from START's 0
            if not flags & TICK_HELD:
                self._applied_tick = k
            age = AGE_OLD if self._applied_tick is None else min(k - self._applied_tick, AGE_OLD)
            frames = {RIG_FEEDBACK: struct.pack("<HHI", seq, statusword, encoder),
                      RIG_DRIVE_FEEDBACK: struct.pack("<Hi", seq, actual),
                      RIG_TICK_APPLIED: struct.pack("<HiBB", seq, applied, flags, min(level, 255)),
                      RIG_DRIVE_TICK: struct.pack("<HiBB", seq, actual, min(level, 255), age)}
            mode_frames = TICK_FRAMES[self._session_mode]  # a faulted tick is sent after its session ended
            ids = [i for i in self.tick_frame_order if i in mode_frames]
            for arbitration_id in ids + [i for i in mode_frames if i not in ids]:
                out(arbitration_id, frames[arbitration_id])
        else:
            raise AssertionError(f"no raw-CAN frame carries message type 0x{kind:02X}")  # ERROR: none in the DBC
