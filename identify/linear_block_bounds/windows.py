"""Long records window by window and part by part (:func:`_coupled_bounds`): the windows and joint parts as tasks
for ``map_windows`` (:func:`_window_task`, a top-level function so that worker processes can run it), the guard
against lost workers (:class:`_GuardedMap`) and the choice of what each pass solves again (:class:`_TaskBounds`)."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from concurrent.futures import BrokenExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.linear_block_bounds import MapFunction, Progress
from identify.linear_block_bounds.certified_lp import _bounds_over, _Counter, _PartStart
from identify.linear_block_bounds.problem import SharedBacklashConstraints, _Data, _interval_lp, _tighten

_LOG = logging.getLogger(__package__)  # the package's logger: ``rig -v`` names identify.linear_block_bounds


_WINDOW = 200
"""Samples per window: the box of a is first tightened on the first window (the set from a subset of the
equations contains the full set, so its bounds are valid; the LPs are small), then every window is bounded."""
_WINDOW_OVERLAP = 20
"""Samples shared by consecutive windows (so that every equation lies whole inside some window)."""
_JOINT_SAMPLES = 3000
"""Samples of the final joint relaxation: all of them for records up to this length (the all-data relaxation),
else the windows that decide the bounds, up to this many samples."""
_FULL_DATA_RELAXATION = _interval_lp
_PART_ROUNDS = 1
"""Rounds of a part's interval relaxation per pass over the parts (its final round, all parameters). A part's own
further rounds tighten from its own box only, a further pass from the intersection of all parts: at N = 10 000,
12 bits (run 0), one round per pass over 4 passes gave a1 4.85e-6 in 9.9 CPU-s of joint LPs, six rounds per
pass over 2 passes 4.98e-6 in 13.9 CPU-s."""
_PART_PASSES = 6
"""Passes over the parts at most (they stop earlier once a pass shrinks no interval by ``tightening_tolerance``)."""

DEFAULT_WINDOW_SAMPLES = _WINDOW
DEFAULT_JOINT_SAMPLES = _JOINT_SAMPLES


@dataclass(frozen=True)
class _WindowPlan:
    """How the record was cut: ``segments`` (start, stop) of the windows and the joint samples used."""

    segments: tuple[tuple[int, int], ...]
    num_parts: int
    passes: int
    part_passes: int
    all_parts: int = 1
    second_pass_parts: int = 0


def _window_segments(num_samples: int, window: int, overlap: int) -> list[tuple[int, int]]:
    step = max(window - overlap, 1)
    starts = list(range(0, max(num_samples - window, 0) + 1, step))
    if starts[-1] + window < num_samples:
        starts.append(num_samples - window)
    return [(start, min(start + window, num_samples)) for start in starts]


def _restrict(data: _Data, segments: Sequence[tuple[int, int]]) -> _Data:
    """The problem on the equations that lie whole inside the given sample segments (overlapping or touching
    segments are merged first, so every sample appears once). The feasible set of a subset of the equations
    contains the full one."""
    n = data.orders.first_equation
    merged: list[list[int]] = []
    for start, stop in sorted(segments):
        if merged and start <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], stop)
        else:
            merged.append([start, stop])
    samples = np.concatenate([np.arange(start, stop) for start, stop in merged])
    keep = np.zeros(data.times.size, dtype=bool)
    for start, stop in merged:
        keep |= (data.times >= start + n) & (data.times < stop)
    position = np.full(data.u.size, -1, dtype=np.int64)
    position[samples] = np.arange(samples.size)
    shared = data.shared
    if shared is not None:
        inside = position[shared.sample_indices] >= 0
        shared = SharedBacklashConstraints(position[shared.sample_indices[inside]], shared.rising[inside],
                                           shared.output_rad[inside], shared.zeta_bound_rad[inside], shared.rows,
                                           shared.rhs, shared.lower, shared.upper)
    return _Data(data.orders, data.u[samples], data.xc[samples], data.dx[samples], position[data.times[keep]],
                 data.regressors[keep], shared)


def _window_task(task: tuple[str, _Data, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None,
                             NDArray[np.bool_] | None, _PartStart | None, bool]) -> tuple[Any, _Counter]:
    """One window's work, in this or another process (module level, plain data in and out).

    ``("bounds", window, low, high, None, wanted, None, retry)``: certified bounds on the window's interval
    relaxation over the box. ``("joint", part, low, high, [max_rounds, tolerance], wanted, start, retry)``: the
    rounds of the interval relaxation on a part of the record (:func:`~.problem._tighten`): its box, rounds, the θ of
    its extreme points, whether it is proven empty and the hand-off to the part's next pass, which starts from
    ``start`` (:class:`~.certified_lp._PartStart`; None: from scratch). ``wanted`` (2p booleans, None: all) names the
    bounds to solve (:func:`~.certified_lp._bounds_over`); the others come back as the box given. ``retry``: solved by
    :data:`~.certified_lp.RETRY_SETTINGS` (a task solved again after its worker died, :class:`_GuardedMap`)."""
    kind, window, low, high, settings, wanted, start, retry = task
    counter = _Counter()
    if kind == "joint":
        assert settings is not None
        counter.stage = f"joint relaxation of {window.u.size} samples"
        max_rounds, tolerance = int(settings[0]), float(settings[1])
        start = _PartStart() if start is None else start
        low, high, used, extreme, empty = _tighten(window, low, high, counter, max_rounds, tolerance, True,
                                                   _FULL_DATA_RELAXATION, wanted=wanted, retry=retry, start=start)
        return (low, high, used, [None if x is None else x[: window.orders.num_parameters] for x in extreme],
                empty, start), counter
    counter.stage = "window relaxation"
    new_low, new_high, _ = _bounds_over(_FULL_DATA_RELAXATION(window, low, high), window.orders.num_parameters,
                                        counter, wanted, retry)
    return (new_low, new_high), counter


class _GuardedMap:
    """``map_windows(_window_task, tasks)`` that survives the loss of the processes running it.

    A worker process that dies (a segfault inside HiGHS, the out-of-memory killer) breaks a process pool
    (``BrokenProcessPool``, a ``BrokenExecutor``) and a Dask cluster reports ``KilledWorker``. The tasks that
    did not finish are solved once more, each in its own map call and by :data:`~.certified_lp.RETRY_SETTINGS` (a pool
    that starts anew after a lost worker, ``rig.batch``'s, or a Dask cluster, takes them; a broken pool refuses them
    at once). If that fails too, every window's and part's box still contains the feasible set, so the results
    that did arrive give a valid bound: the map stops there, the failure is recorded for the notes, and every
    later stage gets no results (it keeps the box it was given) instead of the user getting a traceback."""

    def __init__(self, map_windows: MapFunction, counter: _Counter) -> None:
        self._map = map_windows
        self._counter = counter
        self.failure: str | None = None

    def results(self, tasks: Iterable[Any], stage: str, one_per_call: bool = False) -> Iterable[Any]:
        """The tasks' results in order; ``one_per_call`` hands each task to its own ``map`` call (all submitted
        before the first result is awaited, as ``Executor.map`` does), so that a pool's chunks of several tasks
        cannot leave a core idle on a few long tasks."""
        if self.failure is not None:
            return
        tasks = list(tasks)
        finished = 0
        try:
            for result in self._outcomes(tasks, one_per_call):
                finished += 1
                yield result
            return
        except Exception as error:  # noqa: BLE001 - only the executor's own failures, re-raised otherwise
            first = self._lost_worker(error)
        _LOG.warning("%s: %s; solving its %d unfinished task(s) again by the interior-point method", stage, first,
                     len(tasks) - finished)
        try:
            yield from self._outcomes([(*task[:-1], True) for task in tasks[finished:]], True)
        except Exception as error:  # noqa: BLE001 - as above
            self._lost_worker(error)
            self.failure = first
            self._counter.lost_stages.append((stage, first))

    def _outcomes(self, tasks: list[Any], one_per_call: bool) -> Iterable[Any]:
        if one_per_call:
            pending = [self._map(_window_task, [task]) for task in tasks]
            outcomes: Iterable[Any] = (outcome for batch in pending for outcome in batch)
        else:
            outcomes = self._map(_window_task, tasks)
        for result, done in outcomes:
            self._counter.merge(done)
            yield result

    @staticmethod
    def _lost_worker(error: Exception) -> str:
        """The message of an executor's lost worker; any other error is raised again."""
        if not (isinstance(error, BrokenExecutor) or type(error).__name__ == "KilledWorker"):
            raise error
        return f"{type(error).__name__}: {error}".rstrip(": ")


def _coupled_bounds(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], counter: _Counter,
                    max_rounds: int, relative_improvement: float, map_windows: MapFunction = map,
                    progress: Progress | None = None, window: int = _WINDOW,
                    joint_samples: int = _JOINT_SAMPLES
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], int, list[NDArray[np.float64]], _WindowPlan]:
    """Coupled bounds; records longer than two windows go window by window.

    1. The McCormick rounds on the first window make the box of a narrow.
    2. Every window (``window`` samples, consecutive ones sharing ``_WINDOW_OVERLAP``) is bounded on the
       interval relaxation over the current box; the boxes are intersected (each contains the whole record's
       set) and fed back into every window's relaxation, until no interval shrinks by more than
       ``relative_improvement``. The windows are independent: ``map_windows`` may run them in parallel.
    3. The final rounds solve the interval relaxation jointly over all samples when there are at most
       ``joint_samples`` (the all-data relaxation, from a narrower box than the first window's, so never
       wider than it); otherwise jointly over each of the overlapping parts of ``joint_samples`` samples
       (in parallel through ``map_windows``), their boxes intersected, and again from the intersection (one
       round of each part per pass) until a pass shrinks no interval by ``relative_improvement``.
       Intersecting window boxes alone is 1.1-2 times wider than the joint relaxation (the information of
       bounded-error data is spread over the whole record), so the parts are large.

    Each step's bounds are certified bounds of a valid relaxation of a subset of the equations over a box that
    contains the feasible set, so their intersection is a guaranteed outer bound."""
    p, na, N = data.orders.num_parameters, data.orders.na, data.u.size
    if N <= 2 * window or not na:
        counter.stage = f"coupled relaxation of all {N} samples"
        low, high, used, points, empty = _tighten(data, low, high, counter, max_rounds, relative_improvement, True)
        plan = _WindowPlan(((0, N),), 1, 0, 1)
        return (np.full(p, math.nan), np.full(p, math.nan), used, [], plan) if empty else (low, high, used, points, plan)
    counter.stage = f"coupled relaxation of the first {window} samples"
    low, high, rounds, _, empty = _tighten(_subset(data, window), low, high, counter, max_rounds,
                                           relative_improvement, False)
    segments = _window_segments(N, window, _WINDOW_OVERLAP)
    if empty:
        return np.full(p, math.nan), np.full(p, math.nan), rounds, [], _WindowPlan(tuple(segments), 0, 0, 0)
    windows = [_restrict(data, [segment]) for segment in segments]
    guarded = _GuardedMap(map_windows, counter)
    own = _TaskBounds(len(windows), p)
    active, wanted = list(range(len(windows))), [None] * len(windows)
    passes = 0
    for passes in range(1, max(max_rounds, 1) + 1):
        label = f"window pass {passes}"
        new_low, new_high = low.copy(), high.copy()
        tasks = (("bounds", windows[k], low, high, None, mask, None, False) for k, mask in zip(active, wanted))
        for count, (k, mask, (lows, highs)) in enumerate(zip(active, wanted, guarded.results(tasks, label))):
            own.record(k, lows, highs, mask)
            new_low, new_high = np.maximum(new_low, lows), np.minimum(new_high, highs)
            if progress is not None:
                progress(label, count + 1, len(active))
        if np.any(new_low > new_high):
            # every window is a valid relaxation, so disjoint boxes prove the set empty only up to solver
            # tolerances: let the joint relaxation below decide
            break
        moving, advance = _pass_result(f"window pass {passes}", wanted, p, low, high, new_low, new_high,
                                       relative_improvement, na)
        low, high = new_low, new_high
        if not moving.any():
            break
        # The next pass re-bounds, per window, only the bounds still moving for which the window's own bound
        # came within one box width of the intersection and could reach it (:meth:`_TaskBounds.candidates`);
        # the windows and bounds left out are still valid (only the tightening is given up, never the guarantee).
        active, wanted = own.candidates(low, high, moving, np.repeat(high - low, 2), advance)
        if not active:
            break
    rounds += passes
    chunks = _window_segments(N, max(joint_samples, window), _WINDOW_OVERLAP) if N > joint_samples else [(0, N)]
    all_parts = len(chunks)
    if len(chunks) > 1:
        # Only the parts that hold a window whose own bound came within one box width of the intersection in
        # some direction: the others are valid too, but far from deciding (the same rule as the passes').
        width = np.repeat(high - low, 2)
        near = np.any(own.own > _as_lower_bounds(low, high) - width, axis=1)
        starts = np.array([segment[0] for segment in segments])[near]
        stops = np.array([segment[1] for segment in segments])[near]
        deciding = [chunk for chunk in chunks if np.any((starts >= chunk[0]) & (stops <= chunk[1]))]
        chunks = deciding or chunks
    points: list[NDArray[np.float64] | None] = [None] * (2 * p)
    chunk_passes = 0
    # All data jointly: all max_rounds rounds unless nothing moves. Each round maps a box monotonically (a
    # smaller box gives a smaller relaxation) and this box lies inside the one the all-data rounds started
    # over all the data at once, so after as many rounds it lies inside their result too; stopping at the
    # passes' tolerance could stop earlier, from a box that is already close. Parts: a fixed point over the parts,
    # one round of each part's relaxation per pass (_PART_ROUNDS), every pass from the intersection of the
    # previous one, each part solving only the bounds still moving that it may decide, until no bound moves or
    # _PART_PASSES passes were run. The box after any pass is a guaranteed outer bound, so the stopping rule
    # trades only tightness, never validity.
    settings = np.array([max_rounds, 1e-6]) if all_parts == 1 else np.array([_PART_ROUNDS, relative_improvement])
    part_bounds = _TaskBounds(len(chunks), p)
    # each part's next pass starts from its last basis (and settings) on the same LP, apart from the new box
    starts: list[_PartStart | None] = [None] * len(chunks)
    active_parts, part_wanted = list(range(len(chunks))), [None] * len(chunks)
    last_pass_parts = 0
    for chunk_passes in range(1, (_PART_PASSES if all_parts > 1 else 1) + 1):
        label = f"joint relaxation of {len(active_parts)} part(s) of up to {min(N, joint_samples)} samples"
        last_pass_parts = len(active_parts)
        new_low, new_high = low.copy(), high.copy()
        best_low, best_high = np.full(p, -math.inf), np.full(p, math.inf)
        tasks = (("joint", _restrict(data, [chunks[c]]), low, high, settings, mask, starts[c], False)
                 for c, mask in zip(active_parts, part_wanted))
        if progress is not None:
            progress(label, 0, len(active_parts))
        # one part per map call: parts are few and long, so chunks of several would leave a core idle
        for k, (c, mask, (lows, highs, used, chunk_points, empty, starts[c])) in enumerate(
                zip(active_parts, part_wanted, guarded.results(tasks, label, one_per_call=True))):
            part_bounds.record(c, lows, highs, mask)
            if empty:
                # a part of the equations has no solution, so neither has the whole record
                return np.full(p, math.nan), np.full(p, math.nan), rounds + used, [], _WindowPlan(
                    tuple(segments), len(chunks), passes, chunk_passes)
            rounds = max(rounds, passes + used)
            for j in range(p):
                if chunk_points and chunk_points[2 * j] is not None and lows[j] > best_low[j]:
                    best_low[j], points[2 * j] = lows[j], chunk_points[2 * j]
                if chunk_points and chunk_points[2 * j + 1] is not None and highs[j] < best_high[j]:
                    best_high[j], points[2 * j + 1] = highs[j], chunk_points[2 * j + 1]
            new_low, new_high = np.maximum(new_low, lows), np.minimum(new_high, highs)
            if progress is not None:
                progress(label, k + 1, len(active_parts))
        new_high = np.maximum(new_high, new_low)
        moving, advance = _pass_result(f"joint pass {chunk_passes}", part_wanted, p, low, high, new_low,
                                       new_high, relative_improvement, na)
        gain = (high - low) - (new_high - new_low)
        low, high = new_low, new_high
        if not moving.any():
            break
        # The next pass re-solves, per part, only the bounds still moving whose own bound lies within this
        # pass's gain in width of the intersection and could reach it: a part's relaxation tightens with the
        # box (its envelopes are about r_i Δx_s), so a part further off is not expected to decide.
        active_parts, part_wanted = part_bounds.candidates(low, high, moving, np.repeat(gain, 2), advance)
        if not active_parts:
            break
    return low, high, rounds, points, _WindowPlan(tuple(segments), len(chunks), passes, chunk_passes, all_parts,
                                                  last_pass_parts if chunk_passes > 1 else 0)


def _as_lower_bounds(low: NDArray[np.float64], high: NDArray[np.float64]) -> NDArray[np.float64]:
    """The box as 2p lower bounds, larger = tighter: [low_0, -high_0, low_1, -high_1, ...] (the order of the
    extreme points of :func:`~.certified_lp._bounds_over`)."""
    return np.stack([low, -high], axis=-1).reshape(*np.shape(low)[:-1], -1)


def _pass_result(label: str, wanted: Sequence[NDArray[np.bool_] | None], p: int, low: NDArray[np.float64],
                 high: NDArray[np.float64], new_low: NDArray[np.float64], new_high: NDArray[np.float64],
                 relative_improvement: float, na: int) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """After a pass over windows or parts (``wanted``: each task's selected bounds, None for all 2p) from the
    box [low, high] to [new_low, new_high]: the bounds still moving (:func:`_moving`) and the advance of each
    of the 2p lower bounds (:func:`_as_lower_bounds`), logged with the pass's ``label``."""
    moving = _moving(low, high, new_low, new_high, relative_improvement, na)
    advance = _as_lower_bounds(new_low, new_high) - _as_lower_bounds(low, high)
    _LOG.debug("%s over %d task(s), %d LPs: moving bounds %s, half-widths %s", label, len(wanted),
               sum(p * 2 if mask is None else int(mask.sum()) for mask in wanted), moving.astype(int),
               0.5 * (new_high - new_low))
    return moving, advance


def _moving(low: NDArray[np.float64], high: NDArray[np.float64], new_low: NDArray[np.float64],
            new_high: NDArray[np.float64], relative_improvement: float, na: int) -> NDArray[np.bool_]:
    """Per bound (2p, the order of :func:`_as_lower_bounds`): whether the next pass should solve it again,
    that is whether this pass moved it, or any bound of a, by more than half of ``relative_improvement`` times
    the width of its interval before the pass (two sides moving by less shrink an interval by less than
    ``relative_improvement``). The box of a sets every relaxation's envelopes (r_i Δx_s), so while it shrinks
    every bound may move again: at N = 100 000, 12 bits, the upper bound of b2 moved 3.6 % in the pass after
    one that had not moved it."""
    width = np.repeat(np.maximum(high - low, 1e-300), 2)
    moved = (_as_lower_bounds(new_low, new_high) - _as_lower_bounds(low, high)) / width > 0.5 * relative_improvement
    return moved | bool(moved[: 2 * na].any())


class _TaskBounds:
    """The own bounds of every window or part (tasks x 2p, :func:`_as_lower_bounds`) from its last solve and
    from the solve before, and the advance of the intersection in the last two passes, to choose what the next
    pass re-solves."""

    def __init__(self, num_tasks: int, p: int) -> None:
        self.own = np.full((num_tasks, 2 * p), -math.inf)
        self.before = np.full((num_tasks, 2 * p), -math.inf)
        self.advance: NDArray[np.float64] | None = None

    def record(self, task: int, lows: NDArray[np.float64], highs: NDArray[np.float64],
               wanted: NDArray[np.bool_] | None) -> None:
        solved = np.ones(self.own.shape[1], dtype=bool) if wanted is None else wanted
        self.before[task, solved] = self.own[task, solved]
        self.own[task, solved] = _as_lower_bounds(lows, highs)[solved]

    def candidates(self, low: NDArray[np.float64], high: NDArray[np.float64], moving: NDArray[np.bool_],
                   margin: NDArray[np.float64], advance: NDArray[np.float64]
                   ) -> tuple[list[int], list[NDArray[np.bool_]]]:
        """The tasks to re-solve and, for each, the bounds (the ``wanted`` of :func:`~.certified_lp._bounds_over`): a
        bound still ``moving`` whose own value lies within ``margin`` (2p) of the intersection and would reach it
        with its expected gain. The intersection of a fixed point advances about geometrically (the benchmark's
        N = 100 000, 12 bits: shrinks of 0.64, 0.18, 0.036 per pass over the parts), and so does each task, so
        the expected gain is the task's gain in its last solve times twice the ratio of the intersection's
        last two advances (``advance``: this pass's, per bound), at most that gain; a task solved once may
        gain any amount. Only tightening is at stake: every bound left out stays a valid bound."""
        best = _as_lower_bounds(low, high)
        ratio = np.ones_like(advance)
        if self.advance is not None:
            ratio = np.clip(2.0 * advance / np.maximum(self.advance, 1e-300), 0.0, 1.0)
        self.advance = np.maximum(advance, 0.0)
        solved_twice = np.isfinite(self.before)
        gained = np.where(np.isfinite(self.own), math.inf, 0.0)  # never solved (own -inf): never chosen
        last_gain = np.zeros(self.own.shape)
        last_gain[solved_twice] = self.own[solved_twice] - self.before[solved_twice]
        gained[solved_twice] = (last_gain * ratio)[solved_twice]
        chosen = moving & (self.own > best - margin) & (self.own + gained >= best)
        rows = np.flatnonzero(chosen.any(axis=1))
        return [int(row) for row in rows], [chosen[row] for row in rows]


def _subset(data: _Data, count: int) -> _Data:
    """The problem restricted to the first ``count`` samples."""
    keep_eq = data.times < count
    shared = data.shared
    if shared is not None:
        keep = shared.sample_indices < count
        shared = SharedBacklashConstraints(shared.sample_indices[keep], shared.rising[keep], shared.output_rad[keep],
                                           shared.zeta_bound_rad[keep], shared.rows, shared.rhs, shared.lower,
                                           shared.upper)
    return _Data(data.orders, data.u[:count], data.xc[:count], data.dx[:count], data.times[keep_eq],
                 data.regressors[keep_eq], shared)


def _describe(plan: _WindowPlan, num_samples: int, window: int, joint_samples: int) -> str:
    if len(plan.segments) == 1:
        return f"all {num_samples} samples in one McCormick relaxation"
    joint = (f"then all {num_samples} samples jointly" if plan.all_parts <= 1 else
             f"then {plan.num_parts} of {plan.all_parts} overlapping parts of {joint_samples} samples jointly (those "
             f"holding a deciding window), intersected ({plan.part_passes} pass{'es' if plan.part_passes > 1 else ''}"
             f" of one round each" + (f", the last over the {plan.second_pass_parts} parts near the intersection"
                                      if plan.part_passes > 1 else "") + ")")
    return (f"{len(plan.segments)} windows of {window} samples (overlap {_WINDOW_OVERLAP}), {plan.passes} passes "
            f"of intersected window bounds, {joint}")
