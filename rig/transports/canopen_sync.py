"""The CANopen master's SYNC producer where the interface has no periodic sending of its own, and its listener
for error frames (canopen's own listener ignores them)."""

from __future__ import annotations

import collections
import math
import threading
import time
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

    It keeps, for its recent SYNCs, the host's time just before and just after each send
    (:meth:`longest_spacing_s`): a thread is late when the host is busy, so a long gap between two SYNC echoes
    is a SYNC that went out late only if the thread's own sends were that far apart; otherwise a SYNC echo was
    lost on receive."""

    KEPT = 4096  # sends whose times are kept

    def __init__(self, bus: Any, period_s: float, min_spacing_s: float) -> None:
        self.bus, self.period_s, self.min_spacing_s = bus, period_s, min_spacing_s
        self.sent = 0
        self._sends: collections.deque[tuple[float, float]] = collections.deque(maxlen=self.KEPT)
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
            before = time.perf_counter()
            self._sends.append((before, math.inf))  # (before the echo can arrive)
            try:
                self.bus.send(message)
            except Exception:  # noqa: BLE001 - the bus is going down; the master sees SYNCs stop
                return
            last = time.perf_counter()
            self._sends[-1] = (before, last)
            self.sent += 1
            k += 1

    def longest_spacing_s(self, number: int) -> float | None:
        """The longest the host's time between the sends of SYNC ``number - 1`` and SYNC ``number`` (1: the
        first sent) can have been: from just before the one to just after the other (inf while the second is
        being sent); None where they are not both kept."""
        sends = list(self._sends)
        first = self.sent + (1 if sends and math.isinf(sends[-1][1]) else 0) - len(sends) + 1
        if not first < number <= first + len(sends) - 1:
            return None
        return sends[number - first][1] - sends[number - 1 - first][0]

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
