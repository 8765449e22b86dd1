"""The CANopen master's SYNC producer where the interface has no periodic sending of its own, and its listener
for error frames (canopen's own listener ignores them)."""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["SYNC_COB_ID", "ErrorFrameListener", "SyncThread", "sync_message"]

SYNC_COB_ID = 0x80  # CiA 301 default (0x1005); the master produces the SYNC


def sync_message() -> Any:
    import can

    return can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False)


class SyncThread:
    """A SYNC producer thread for interfaces without periodic sending of their own: SYNC k is due at
    t_0 + k T; one that comes late goes out as soon as possible, but never closer than ``min_spacing_s``
    (one cycle's bus time) to the one before, and the following ones return to the grid. The master sees
    each SYNC's real instant in its echo's timestamp and flags samples that are off the period (LATE).

    It keeps, for its recent SYNCs, the bus timestamps' clock (``wall_clock``: python-can stamps frames with
    :func:`time.time`, SocketCAN with the kernel's realtime clock) just before and just after each send
    (:meth:`longest_spacing_s`): a thread is late when the host is busy, so a long gap between two SYNC echoes
    is a SYNC that went out late only if the thread's own sends were that far apart; otherwise a SYNC echo was
    lost on receive. The grid itself runs on :func:`time.perf_counter`; the realtime clock can be stepped or
    slewed (time synchronisation on a freshly booted host), which must not read as a lost SYNC."""

    KEPT = 4096  # sends whose times are kept

    def __init__(self, bus: Any, period_s: float, min_spacing_s: float,
                 wall_clock: Callable[[], float] = time.time) -> None:
        self.bus, self.period_s, self.min_spacing_s = bus, period_s, min_spacing_s
        self.wall_clock = wall_clock
        self.sent = 0
        # (number from 1, wall clock just before the send, just after it: inf while it is being sent), one
        # tuple each, so that a reader on another thread never pairs a number with another send's times
        self._sends: collections.deque[tuple[int, float, float]] = collections.deque(maxlen=self.KEPT)
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._run, name="canopen-sync", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        message = sync_message()
        start = last = time.perf_counter()
        k = 0
        while not self._stopped.is_set():
            due = max(start + k * self.period_s, last + self.min_spacing_s)
            remaining = due - time.perf_counter()
            if remaining > 0 and self._stopped.wait(remaining):
                return
            number, before = k + 1, self.wall_clock()
            self._sends.append((number, before, math.inf))  # (before the echo can arrive)
            try:
                self.bus.send(message)
            except Exception:  # noqa: BLE001 - the bus is going down; the master sees SYNCs stop
                return
            self._sends[-1] = (number, before, self.wall_clock())
            last = time.perf_counter()
            self.sent = number
            k += 1

    def longest_spacing_s(self, number: int) -> float | None:
        """The longest the time between the sends of SYNC ``number - 1`` and SYNC ``number`` (1: the first
        sent) can have been, on the bus timestamps' clock: from just before the one to just after the other
        (inf while the second is being sent); None where they are not both kept."""
        sends = list(self._sends)
        if not sends:
            return None
        first = sends[0][0]
        if not first < number <= sends[-1][0]:
            return None
        return sends[number - first][2] - sends[number - 1 - first][1]

    def stop(self) -> None:
        self._stopped.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)


class ErrorFrameListener:
    """python-can listener passing error frames to ``callback`` (notifier thread)."""

    def __init__(self, callback: Any) -> None:
        self.callback = callback

    def on_message_received(self, message: Any) -> None:
        if message.is_error_frame:
            self.callback(message)

    __call__ = on_message_received  # python-can's notifier calls its listeners

    def on_error(self, exc: Exception) -> None:  # the notifier's own receive errors: nothing to add
        pass

    def stop(self) -> None:
        pass
