"""The host's side of a device that owns the sample clock and buffers setpoints by tick: serial protocol v2
(``docs/serial_protocol.md`` section 16) and raw CAN v2-v4 (``configs/raw_can.dbc``, which mirrors it).

Such a device applies setpoint k at its own tick k. A setpoint that reaches it after tick k is dropped there,
and the device holds the target it applied last (HELD, spec 16.3). After a host stall that target lags the
plan, and the first setpoint the device takes again must not jump from it to the plan
(docs/reference/faults.md, "Safety"; as CANopen CSP, :meth:`~rig.transports.base.Transport._toward_plan` is the one rule). :class:`TickBuffer` keeps
what the host knows of the device's clock and of the targets it may hold, and places each setpoint:

* not at all for a tick the device has reported (spec 16.3: it would drop it; the setpoint only costs line
  time). A tick that has passed only on the host's estimate of the device's clock still gets its setpoint: a
  device whose ticks run late (a burst, spec 16.3) may still take it, and every frame restarts its link
  watchdog (16.4), which a host that stays behind would otherwise starve;
* at most :attr:`~rig.transports.base.Transport.catch_up_step_rad` from every target that may be in force at
  the tick before: the target the device last reported in force, and every setpoint sent after that tick
  which may miss its own (sent less than :data:`MAY_MISS_S` before its tick's estimated instant, or after
  it), since the device then holds the one before. A setpoint sent earlier is taken to be applied.
  A setpoint so limited is flagged LIMITED on its tick's sample, which logs the target the device applied.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable

__all__ = ["CLOCK_WINDOW_S", "MAY_MISS_S", "TickBuffer"]

MAY_MISS_S = 0.002
"""A setpoint sent less than this (or two periods, if longer) before its tick's estimated instant may still
miss the tick: the estimate is when a tick's report reached the host at the earliest, and the setpoint's own
way to the device takes time too (an FTDI adapter's latency timer is 1 ms at best, each way: spec section 8)."""
CLOCK_WINDOW_S = 5.0
"""The device's tick 0 on the host's clock is estimated from the reports of the ticks of this many seconds
before the newest: long enough to reach back over any stall the device's link watchdog rides through (about
1 s, spec 16.4), short enough that a device crystal 100 ppm off the host's clock moves it by under 0.5 ms in an
endurance run of hours."""


class TickBuffer:
    """What the host knows of a clocked, buffering device (see the module docstring); one per session.

    Parameters
    ----------
    period_s
        The device's tick period T.
    in_force_counts
        The drive target in force before the first setpoint (the position the drive held when enabled).
    """

    def __init__(self, period_s: float, in_force_counts: int) -> None:
        self.period_s = float(period_s)
        self._window_ticks = max(1, math.ceil(CLOCK_WINDOW_S / self.period_s))
        self._may_miss_s = max(2 * self.period_s, MAY_MISS_S)
        # (k, arrival of k's report - k T), the values increasing: the window's minimum comes first
        self._origins: collections.deque[tuple[int, float]] = collections.deque()
        self._newest = -1
        # the targets that may be in force at the tick of the last setpoint sent: the anchor's (a tick and the
        # target in force there: the device reported it, or a setpoint sent in time), and those of the setpoints
        # sent for later ticks that may miss them
        self._anchor = (-1, int(in_force_counts))
        self._may_miss: collections.deque[tuple[int, int]] = collections.deque()
        self._limited: set[int] = set()

    def instant_s(self, k: int) -> float:
        """Tick k's instant on the host's clock: the earliest a report of the window's ticks came, less its
        ticks (a report cannot come before its tick); inf before the first report."""
        return self._origins[0][1] + k * self.period_s if self._origins else math.inf

    def heard(self, k: int, received_s: float) -> None:
        """Tick k's report reached the host at ``received_s``."""
        origin = received_s - k * self.period_s
        while self._origins and self._origins[-1][1] >= origin:
            self._origins.pop()
        self._origins.append((k, origin))
        self._newest = max(self._newest, k)
        while len(self._origins) > 1 and self._origins[0][0] < self._newest - self._window_ticks:
            self._origins.popleft()
        if len(self._limited) > 4096:  # ticks whose report never came
            self._limited = {tick for tick in self._limited if tick >= self._newest - self._window_ticks}

    def in_force(self, k: int, applied_counts: int) -> None:
        """Tick k's report says ``applied_counts`` was the target in force there: the setpoints sent for tick k
        and before are settled."""
        if k >= self._anchor[0]:
            self._anchor = (k, int(applied_counts))
            while self._may_miss and self._may_miss[0][0] <= k:
                self._may_miss.popleft()

    def place(self, k: int, plan_counts: int, now_s: float, *, reported: int,
              toward_plan: Callable[[int, int, int], int]) -> int | None:
        """The target to send now (``now_s``) for tick k, whose planned target is ``plan_counts``; None: send
        nothing, the device has reported tick k (``reported``: the latest tick it reported).
        ``toward_plan(plan, lowest, highest)`` is the link's way back to the plan."""
        if k <= reported:
            return None
        possible = [self._anchor[1], *(counts for _, counts in self._may_miss)]
        counts = toward_plan(plan_counts, min(possible), max(possible))
        if counts != plan_counts:
            self._limited.add(k)
        if self.instant_s(k) - now_s < self._may_miss_s:  # it may miss its tick: the targets before it stay possible
            self._may_miss.append((k, counts))
        else:
            self._anchor = (k, counts)
            self._may_miss.clear()
        return counts

    def limited(self, k: int) -> bool:
        """Tick k's setpoint was limited on its way back to the plan (asked once, for the tick's sample; whether
        the device applied it, its report says)."""
        if k in self._limited:
            self._limited.discard(k)
            return True
        return False
