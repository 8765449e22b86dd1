"""The master's SYNC producer thread: what it tells the receive checks about its own sends."""

from __future__ import annotations

import threading
import time

from rig.transports.canopen_sync import SyncThread


class SteppedClock:
    """A realtime clock that time synchronisation steps forward by ``step_s`` at every ``every``-th reading
    (a freshly booted host being brought onto its time server)."""

    def __init__(self, step_s: float, every: int) -> None:
        self.step_s, self.every, self.readings, self.offset = step_s, every, 0, 0.0
        self._lock = threading.Lock()

    def __call__(self) -> float:
        with self._lock:
            self.readings += 1
            if self.readings % self.every == 0:
                self.offset += self.step_s
            return time.time() + self.offset


class EchoingBus:
    """A bus that stamps each frame sent with ``clock`` on its way back, as python-can's interfaces stamp
    their echoes."""

    def __init__(self, clock) -> None:
        self.clock, self.stamps = clock, []

    def send(self, message, timeout=None) -> None:
        self.stamps.append(self.clock())


def test_a_stepped_realtime_clock_never_reads_as_a_lost_sync_echo():
    """The echo of each SYNC is stamped by the bus's clock between the thread's readings just before and just
    after its send, so the spacing the thread reports bounds every gap between two echoes, however the realtime
    clock is stepped: a gap wider than the spacing is the receive checks' proof of a lost echo."""
    clock = SteppedClock(step_s=3e-4, every=7)
    bus = EchoingBus(clock)
    thread = SyncThread(bus, period_s=1e-3, min_spacing_s=1e-4, wall_clock=clock)
    try:
        deadline = time.monotonic() + 5.0
        while thread.sent < 80 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        thread.stop()
    stamps = bus.stamps[:thread.sent]
    assert len(stamps) >= 80 and clock.offset > 0
    checked = 0
    for number in range(2, len(stamps) + 1):
        spacing = thread.longest_spacing_s(number)
        if spacing is not None:
            assert stamps[number - 1] - stamps[number - 2] <= spacing, number
            checked += 1
    assert checked >= 79
    assert thread.longest_spacing_s(1) is None and thread.longest_spacing_s(len(stamps) + 1) is None
