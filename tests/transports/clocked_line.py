"""The real host transport and a serial device on one simulated line and one simulated clock: no pty, no
thread, no sleep, so a test of the v2 streaming logic depends on nothing but the code.

* A frame the host writes reaches the device at once, at the clock's present time.
* What the device sends waits until the host polls.
* Time passes only while the host waits for something (a poll with a timeout): the clock moves to the
  device's next event (a tick, its link watchdog) or to the end of the wait, whichever comes first, and the
  device does what falls due. The host's own computing takes no time, so every tick's TICK arrives at the
  tick's instant, unless the test stalls the host (:meth:`ClockedLine.stall`), during which the device goes
  on ticking on its own clock.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable

import numpy as np

from rig.protocols.serial_frames import FrameDecoder
from rig.transports.serial_link import SerialTransport


def _wait_for_the_device(clock, timeout_s: float, next_event_s, run_due) -> None:
    """The host waits up to ``timeout_s``: the clock moves to the device's next event (which happens) or to
    the end of the wait, whichever comes first."""
    end = clock() + timeout_s
    when = next_event_s()
    clock.advance_to(min(end, max(when, clock())) if math.isfinite(when) else end)
    run_due()


def _live_through(clock, seconds: float, next_event_s, run_due) -> None:
    """``seconds`` pass with the host doing nothing; the device does every event that falls in them."""
    end = clock() + seconds
    while (when := next_event_s()) <= end:
        clock.advance_to(max(when, clock()))
        run_due()
    clock.advance_to(end)


class SimulatedClock:
    """Seconds that move only when told to (``clock()`` reads it)."""

    def __init__(self, start_s: float = 0.0) -> None:
        self.now_s = float(start_s)

    def __call__(self) -> float:
        return self.now_s

    def advance_to(self, when_s: float) -> None:
        if when_s < self.now_s:
            raise ValueError(f"a clock does not go back: {when_s} < {self.now_s}")
        self.now_s = when_s


def simulated_device_line(transport: SerialTransport, clock: SimulatedClock, device) -> ClockedLine:
    """A :class:`ClockedLine` to :class:`sim_backend.serial_device.SimulatedSerialDevice` (built with
    ``clock=clock``), scripted through its ``handle`` / ``next_tick_s`` / ``run_due``."""
    decoder = FrameDecoder()

    def feed(data: bytes) -> None:
        for message in decoder.feed(data):
            line.device_writes(device.handle(message))

    line = ClockedLine(transport, clock, feed=feed, next_event_s=device.next_tick_s,
                       run_due=lambda: line.device_writes(device.run_due()))
    return line


class ClockedLine:
    """Joins ``transport`` (built with ``clock=clock``) to a device that runs on ``clock``.

    The device side is three functions: ``feed(data)`` (bytes from the host, now), ``next_event_s()``
    (when its next event is due; inf for none) and ``run_due()`` (do what is due by now); the device sends
    through the ``output`` callable it was given, :meth:`device_writes`.
    """

    def __init__(self, transport: SerialTransport, clock: SimulatedClock, *, feed: Callable[[bytes], None],
                 next_event_s: Callable[[], float], run_due: Callable[[], None]) -> None:
        self.transport, self.clock = transport, clock
        self._feed, self._next_event_s, self._run_due = feed, next_event_s, run_due
        self._to_host = bytearray()
        self._decoder = FrameDecoder()
        self.to_host: list = []  # every SerialMessage the host received, in order
        transport._connect = lambda: None
        transport._write = self._feed
        transport._poll = self._host_polls

    def device_writes(self, data: bytes) -> None:
        self._to_host += data

    def stall(self, seconds: float) -> None:
        """The host does nothing for ``seconds``; the device lives through them event by event."""
        _live_through(self.clock, seconds, self._next_event_s, self._run_due)

    def _host_polls(self, timeout_s: float) -> bool:
        if not self._to_host and timeout_s > 0:
            _wait_for_the_device(self.clock, timeout_s, self._next_event_s, self._run_due)
        if not self._to_host:
            return False
        data, self._to_host = bytes(self._to_host), bytearray()
        for message in self._decoder.feed(data):
            self.to_host.append(message)
            self.transport._dispatch(message, self.clock())
        return True


class ClockedBus:
    """A python-can bus between :class:`rig.transports.raw_can.RawCanTransport` (built with ``clock=clock``)
    and the raw-CAN spec device on ``clock``, with :class:`ClockedLine`'s rules: ``send`` reaches the device at
    once; ``recv(timeout)`` returns the device's next frame, the clock moving to the device's next event or
    the timeout while there is none. The device sends through :meth:`device_sends`."""

    def __init__(self, transport, clock: SimulatedClock, device) -> None:
        import can

        self._message = can.Message
        self.transport, self.clock, self.device = transport, clock, device
        self._to_host: collections.deque = collections.deque()
        self.to_host: list = []  # (arbitration_id, data) the host received, in order
        transport._connect = lambda: setattr(transport, "_bus", self)

    def device_sends(self, arbitration_id: int, data: bytes) -> None:
        self._to_host.append((arbitration_id, bytes(data)))

    def stall(self, seconds: float) -> None:
        _live_through(self.clock, seconds, self.device.next_event_s, self.device.run_due)

    def send(self, message, timeout=None) -> None:
        self.device.feed_frame(message.arbitration_id, bytes(message.data))

    def recv(self, timeout: float | None = None):
        if not self._to_host and timeout:
            _wait_for_the_device(self.clock, timeout, self.device.next_event_s, self.device.run_due)
        if not self._to_host:
            return None
        arbitration_id, data = self._to_host.popleft()
        self.to_host.append((arbitration_id, data))
        return self._message(arbitration_id=arbitration_id, data=data, is_extended_id=False,
                             timestamp=self.clock())

    def shutdown(self) -> None:
        pass


class SimulatedRawCanEndpoint:
    """:class:`sim_backend.raw_can_device.SimulatedRawCanDevice` (built with ``clock=``) as the device of a
    :class:`ClockedBus`: ``endpoint = SimulatedRawCanEndpoint(device); bus = ClockedBus(transport, clock,
    endpoint); endpoint.connect(bus)``."""

    def __init__(self, device) -> None:
        import can

        self.device, self._message = device, can.Message
        self._bus: ClockedBus | None = None

    def connect(self, bus: ClockedBus) -> None:
        self._bus = bus
        self.device.start_scripted(self)

    def send(self, message, timeout=None) -> None:  # the device's frames, to the host
        self._bus.device_sends(message.arbitration_id, bytes(message.data))

    def shutdown(self) -> None:
        pass

    def feed_frame(self, arbitration_id: int, data: bytes) -> None:
        self.device.on_message_received(self._message(arbitration_id=arbitration_id, data=data, is_extended_id=False))
        self.device.run_due()

    def next_event_s(self) -> float:
        return self.device.next_tick_s()

    def run_due(self) -> None:
        self.device.run_due()


def check_the_way_back_to_the_plan(sink, device, command, drive, step_rad: float) -> np.ndarray:
    """After a host stall on a clocked, buffering device (serial spec 16.3; the raw-CAN DBC), row by row: the
    target the device applied (its own record, ``device.ticks[k]``) never steps farther than ``step_rad`` (in
    whole drive counts) from the one it applied the tick before, from the drive's position at enable (0) on; each
    row logs that target, HELD exactly where the device held, and LIMITED exactly where the device applied a
    target the host had brought nearer the one in force than ``command``. Returns the LIMITED rows."""
    from identify.experiment_record import SampleFlag

    step_counts = math.floor(step_rad * drive.counts_per_revolution / (2 * math.pi) + 1e-9)
    rows = range(len(sink.rows))
    applied = np.array([device.ticks[k].applied_counts for k in rows])
    assert np.abs(np.diff(applied, prepend=0)).max() <= step_counts
    flags = np.array([row[4] for row in sink.rows])
    assert [row[1] for row in sink.rows] == [drive.rad_from_counts(counts) for counts in applied]
    assert [bool(flag & SampleFlag.HELD) for flag in flags] == [device.ticks[k].held for k in rows]
    planned = np.array([drive.counts_from_rad(value) for value in command[:len(sink.rows)]])
    limited = (flags & SampleFlag.LIMITED) != 0
    assert limited.tolist() == [not device.ticks[k].held and applied[k] != planned[k] for k in rows]
    return np.flatnonzero(limited)
