"""One frame order for every receiver of python-can's virtual bus, as a real CAN bus has.

On a CAN bus, arbitration puts every frame on the wire one after the other, and every node sees the frames
in that order. ``can.interfaces.virtual.VirtualBus.send`` copies a frame into each receiver's queue in turn
without a lock. When two threads send at once (the master's setpoint RPDO and the SYNC, say), one receiver
can get [RPDO, SYNC] and another [SYNC, RPDO]. Then the master files the setpoint as in force at that SYNC
while the simulated drive applied it one cycle later. That is a bus no real device is on, so the simulated
devices make the order total before they go on the bus. :func:`one_bus_order` wraps ``send`` once, for the
process, in one lock: a frame reaches all receivers before the next frame reaches any.
"""

from __future__ import annotations

import functools
import threading

from can.interfaces.virtual import VirtualBus

_ORDER = threading.RLock()  # re-entrant: a subclass's send calls the wrapped base send


def one_bus_order() -> None:
    """Make every ``VirtualBus.send`` of this process deliver its frame to all receivers under one lock
    (idempotent). The queues are unbounded, so a send never waits on a receiver while holding it."""
    if getattr(VirtualBus.send, "_one_bus_order", False):
        return
    unordered = VirtualBus.send

    @functools.wraps(unordered)
    def send(self: VirtualBus, msg, timeout=None):  # type: ignore[no-untyped-def]
        with _ORDER:
            return unordered(self, msg, timeout)

    send._one_bus_order = True  # type: ignore[attr-defined]
    VirtualBus.send = send  # type: ignore[method-assign]
