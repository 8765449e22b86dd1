"""The latest trend window's guaranteed bounds on the play, for ``rig run --live`` of the steady staircase.

The live view (:mod:`rig.live_view`) hands each batch of rows it takes to :class:`LiveTrend`, on its own thread:
the steady-state points are picked from them as ``rig trend`` picks them from the log
(:func:`rig.staircase_points.staircase_plan`: the last usable angle of each half-wave's settled
tail, none after a wrap that steps), and a window, once the rows have passed its end, is bounded by
:func:`identify.backlash_trend.bound_window_play` (eqs. (11)-(20) of Cerone, Piga, Regruto 2009) in a process of
its own, so that neither the capture nor the view waits for its linear programs. A point whose rows the view
did not see (it fell behind and its buffer dropped them) is missing from the window: fewer points give wider
bounds, still guaranteed, and the log has them all for ``rig trend``.
"""

from __future__ import annotations

import collections
import concurrent.futures
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from identify.backlash_trend import TrendWindow

__all__ = ["LiveTrend", "trend_text"]

FINISH_TIMEOUT_S = 30.0
"""At the end of the run the final frame waits this long at most for the windows still being bounded."""


def trend_text(window: TrendWindow | None) -> str:
    """One line for the view: the latest window's play, or why it has none."""
    if window is None:
        return "trend: no window complete yet"
    span = f"window {window.index}, {window.start_s:g}-{window.end_s:g} s"
    if window.play_rad is not None:
        return (f"trend: play [{window.play_rad.lower:.6g}, {window.play_rad.upper:.6g}] rad ({span}, "
                f"{window.right_points}/{window.left_points} points)")
    return f"trend: {window.status.replace('_', ' ')} ({span}): {window.reason}"


class LiveTrend:
    """Steady-state points by window from the rows of a run, and each complete window's bounds.

    Parameters
    ----------
    plan
        Where the log's steady-state points fall (:class:`~rig.staircase_points.StaircasePlan`).
    sample_period_s
        The rig's sample period: row time k T is sample k.
    window_s
        The trend's window length (as ``rig trend --window``).
    noise_bound_rad
        Δη of eq. (5) (the log's ``noise_bound_rad``).
    executor
        Where the windows are bounded (a :class:`concurrent.futures.Executor`); None: a process of its own, started
        at the first complete window and shut down by :meth:`close`.
    """

    def __init__(self, plan: Any, sample_period_s: float, window_s: float, noise_bound_rad: float, *,
                 executor: concurrent.futures.Executor | None = None) -> None:
        if not (math.isfinite(window_s) and window_s > 0):
            raise ValueError(f"trend window: expected a length > 0 s, got {window_s!r}")
        if not (math.isfinite(noise_bound_rad) and noise_bound_rad > 0):
            raise ValueError(f"noise bound: expected a number of rad > 0, got {noise_bound_rad!r}")
        self.plan, self.sample_period_s = plan, float(sample_period_s)
        self.window_s, self.noise_bound_rad = float(window_s), float(noise_bound_rad)
        self._ends = frozenset(int(end) for end in plan.ends)
        self._executor, self._owns_executor = executor, executor is None
        self._window = 0  # the window being filled
        self._points: list[tuple[float, float]] = []  # its (command, angle) points
        self._last_usable = (-1, math.nan)  # (sample, angle) of the last usable row seen
        self._pending: collections.deque[concurrent.futures.Future] = collections.deque()
        self.latest: TrendWindow | None = None
        self.error: BaseException | None = None

    def add(self, time_s: ArrayLike, command_rad: ArrayLike, angle_rad: ArrayLike, usable: ArrayLike) -> None:
        """Rows the view took, in time order (later than any before; rows it missed leave gaps)."""
        samples = np.rint(np.asarray(time_s, dtype=float) / self.sample_period_s).astype(np.int64)
        plan = self.plan
        for k, command, angle, ok in zip(samples.tolist(), np.asarray(command_rad, dtype=float).tolist(),
                                         np.asarray(angle_rad, dtype=float).tolist(), np.asarray(usable).tolist()):
            window = self._window_of(k)
            while window > self._window:
                self._submit()
            if ok:
                self._last_usable = (k, angle)
            if k % plan.cycle in self._ends and not plan.after_wrap(k) and self._last_usable[0] > k - plan.tail:
                self._points.append((command, self._last_usable[1]))

    def current(self) -> TrendWindow | None:
        """The latest window bounded so far (windows complete in order)."""
        while self._pending and self._pending[0].done():
            self._collect(self._pending.popleft())
        return self.latest

    def finish(self, timeout_s: float = FINISH_TIMEOUT_S) -> TrendWindow | None:
        """After the run: wait up to ``timeout_s`` for the windows being bounded; the latest (the window the run
        ended in is not complete and is not bounded: ``rig trend`` bounds it from the log)."""
        concurrent.futures.wait(list(self._pending), timeout=timeout_s)
        return self.current()

    def close(self) -> None:
        """Drop what is still being bounded; end the process of its own (idempotent)."""
        for future in self._pending:
            future.cancel()
        self._pending.clear()
        if self._owns_executor and self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None

    def _window_of(self, sample: int) -> int:
        guard = 1e-6 * self.sample_period_s  # k T in floating point: a sample at 60 s belongs to the window from 60 s
        return int(math.floor((sample * self.sample_period_s + guard) / self.window_s))

    def _submit(self) -> None:
        """The window being filled is complete: bound it off this process; the next one starts empty."""
        index, points = self._window, self._points
        self._window, self._points = index + 1, []
        from identify.backlash_trend import bound_window_play

        if self._executor is None:
            import multiprocessing

            self._executor = concurrent.futures.ProcessPoolExecutor(
                max_workers=1, mp_context=multiprocessing.get_context("spawn"))  # no forked threads or locks
        command, angle = (np.array(values, dtype=float) for values in zip(*points)) if points else (np.zeros(0),) * 2
        self._pending.append(self._executor.submit(
            bound_window_play, index, index * self.window_s, (index + 1) * self.window_s, command, angle,
            self.noise_bound_rad))

    def _collect(self, future: concurrent.futures.Future) -> None:
        if future.cancelled():
            return
        error = future.exception()
        if error is not None:
            self.error = error
            return
        self.latest = future.result()
