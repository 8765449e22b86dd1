"""The bounds of the linear block in order (:func:`bound_linear_block`): the paper method's, then the coupled
method's stages (:func:`_coupled_stages`), and the result with its notes."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.feasible_parameter_set import ParameterInterval
from identify.linear_block_bounds import DEFAULT_MOMENT_SAMPLES, DEFAULT_PARTITION_SAMPLES, MapFunction, Progress
from identify.linear_block_bounds.certified_lp import _RECOVERY_NAMES, _Counter
from identify.linear_block_bounds.final_tightening import _closed_relaxation_gap, _moment_bounds, _partitioned_bounds
from identify.linear_block_bounds.inner_values import _explain, _inner_values
from identify.linear_block_bounds.problem import (_B_BOX, LinearModelOrders, SharedBacklashConstraints, _Data,
                                                  _interval_lp, _paper_bounds, _prepare, _tighten)
from identify.linear_block_bounds.result import LinearBlockBounds
from identify.linear_block_bounds.trajectory_lp import _trajectory_relaxation, _TrajectoryProblem
from identify.linear_block_bounds.windows import _JOINT_SAMPLES, _WINDOW, _coupled_bounds, _describe
from identify.validation import InvalidInputError


LINEAR_BOUND_METHODS = ("paper", "coupled")


def bound_linear_block(input_rad: ArrayLike, inner_lower_rad: ArrayLike, inner_upper_rad: ArrayLike, *,
                       na: int, nk: int, nb: int, method: str = "coupled", max_tightening_rounds: int = 6,
                       tightening_tolerance: float = 0.02,
                       shared_backlash: SharedBacklashConstraints | None = None,
                       verify_inner: bool = True, window_samples: int = _WINDOW,
                       joint_samples: int = _JOINT_SAMPLES, partition_samples: int = DEFAULT_PARTITION_SAMPLES,
                       moment_samples: int = DEFAULT_MOMENT_SAMPLES, map_windows: MapFunction | None = None,
                       progress: Progress | None = None, eliminate_inner_signal: bool = True) -> LinearBlockBounds:
    """Guaranteed bounds on θ = [a_1..a_na, b_nk..b_nb] with unit static gain (eq. (8)), Section 5.

    Parameters
    ----------
    input_rad
        u_t of the dynamic experiment.
    inner_lower_rad, inner_upper_rad
        x_t^min, x_t^max from :func:`identify.inner_signal_bounds.bound_inner_signal` (eq. (23)); NaN where
        x_t is not bounded (a sample whose output was not measured). An equation of eq. (7) is used only when
        its regressors are complete: the equation at t needs x_t, ..., x_{t-na}, so each missing sample sets
        aside up to na + 1 equations. The bounds hold as before (fewer equations give a set that contains the
        one of all of them), only possibly wider.
    na, nk, nb
        Orders: A = 1 + a_1 q^-1 + ... + a_na q^-na, B = b_nk q^-nk + ... + b_nb q^-nb.
    method
        ``"paper"`` (per-equation errors, Cerone 1993) or ``"coupled"`` (shared errors, McCormick
        relaxation with iterated tightening; never wider than ``"paper"``).
    max_tightening_rounds, tightening_tolerance
        Coupled method: stop after this many rounds (twice as many for the trajectory relaxation, which starts from
        the paper method's box) or when no interval shrinks by more than this fraction.
    shared_backlash
        Coupled method: tie the inverted samples to one backlash in D_γ instead of letting each sample take
        its own worst case (from :func:`identify.inner_signal_bounds.shared_backlash_constraints`).
    verify_inner
        Coupled method: compute the verified inner values (2p or more extra LPs at fixed a; with the inner signal
        eliminated they have a few columns, else one per sample, which makes them most of the time of a long
        record). The outer bounds do not depend on it.
    eliminate_inner_signal
        Coupled method: bound by the trajectory relaxation, the inner signal eliminated (x = M(a)[b; s], a few
        columns and one row per sample: :func:`~.trajectory_lp._trajectory_relaxation`), whenever the record has
        few gaps (:meth:`~.trajectory_lp._TrajectoryProblem.suits`): rounds over all samples, then the partition of
        the box of a into cells at every record length, made again while the verified inner values show a gap
        above :data:`~.final_tightening.RELAXATION_GAP_TARGET`. False, or a record of many gaps: the windows and
        joint parts below, with δx as columns.
    window_samples, joint_samples
        Coupled method without the trajectory relaxation, on records longer than two windows: windows of this many
        samples are bounded one by one and their boxes intersected; the final relaxation is solved jointly over all
        samples if there are at most ``joint_samples``, else over the windows that decide the bounds, up to that
        many samples (see :func:`~.windows._coupled_bounds`; the time grows about linearly with the record).
    partition_samples
        Coupled method: the final tightening cuts the box of a into cells, each bounded by its own relaxation, and
        takes the hull (spatial branch and bound, :func:`~.final_tightening._partitioned_bounds`; narrows the outer
        bounds towards the exact set at a few times the cost). With the trajectory relaxation every record gets it
        (a cell costs O(N)); without, records up to this length (a cell's LP has δx as columns). 0 switches it off.
    moment_samples
        Coupled method on records up to this length: a last tightening by the first-order moment (SDP)
        relaxation, solved with cvxpy and certified through LP cuts (:func:`~.final_tightening._moment_bounds`). 0 (the
        default) switches it off; it needs cvxpy (``pip install 'gearbox-rig[sdp]'``), else a note says it did not run.
    map_windows
        ``map(function, tasks)`` used for the windows, e.g. ``executor.map`` of a process pool or a Dask
        client's executor; the builtin ``map`` (one process) by default. The tasks and results are plain data.
        HiGHS 1.16 can crash the process solving a bounding LP of a long record (BENCHMARKS.md, "Record
        length"); run in worker processes, a crash costs only their tasks, which are solved again
        (:class:`~.windows._GuardedMap`). ``rig identify output-backlash`` does so even with ``--jobs 1``; from Python,
        pass ``executor.map`` of ``rig.batch.executor_for(1, isolated=True)`` for a record of many windows. The
        trajectory relaxation (``eliminate_inner_signal``) maps nothing: its LPs have about ten columns.
    progress
        ``progress(stage, done, total)``, called as windows finish (for long records).
    """
    _check_settings(method, window_samples=window_samples, joint_samples=joint_samples,
                    partition_samples=partition_samples, moment_samples=moment_samples)
    orders = LinearModelOrders(na, nk, nb)
    data = _prepare(input_rad, inner_lower_rad, inner_upper_rad, orders, shared_backlash)
    counter = _Counter()
    names = orders.parameter_names
    low, high, feasible = _paper_bounds(data, counter)
    if not feasible:
        return LinearBlockBounds(method=method, orders=orders, intervals={}, explanation=_explain(data, counter),
                                 num_linear_programs=counter.solves, max_certificate_gap=counter.max_gap)
    rounds = 0
    inner = (None, None, None)
    moment_notes: list[str] = []
    windowing = f"all {data.u.size} samples in one relaxation per orthant"
    trajectory = method == "coupled" and eliminate_inner_signal and _TrajectoryProblem.suits(data)
    partitioned = bool(orders.na) and (data.u.size <= partition_samples or (trajectory and partition_samples > 0))
    if method == "coupled":
        low, high, rounds, points, windowing = _coupled_stages(
            data, low, high, counter, moment_notes, max_tightening_rounds=max_tightening_rounds,
            tightening_tolerance=tightening_tolerance, map_windows=map if map_windows is None else map_windows,
            progress=progress, window_samples=window_samples, joint_samples=joint_samples, trajectory=trajectory,
            partitioned=partitioned, moment_samples=moment_samples)
        if np.any(np.isnan(low)):
            return LinearBlockBounds(method=method, orders=orders, intervals={}, explanation=_explain(data, counter),
                                     num_linear_programs=counter.solves, num_tightening_rounds=rounds,
                                     feasible_orthants=tuple(feasible), max_certificate_gap=counter.max_gap,
                                     windowing=windowing)
        if verify_inner and any(point is not None for point in points):
            refine = trajectory or data.u.size <= max(partition_samples, 2 * window_samples)
            verified = _inner_values(data, low, high, points, counter, refine)
            if partitioned:
                low, high, verified, cells = _closed_relaxation_gap(
                    data, low, high, points, verified, counter, progress,
                    _trajectory_relaxation if trajectory else _interval_lp)
                if cells:
                    windowing += f", partitioned again, patient, for the gap to the verified values ({cells} solved)"
            inner_low, inner_high, witness = verified
            inner = ({n: float(v) for n, v in zip(names, inner_low)}, {n: float(v) for n, v in zip(names, inner_high)},
                     None if witness is None else {n: float(v) for n, v in zip(names, witness)})
    notes = _fallback_notes(names, counter) + tuple(moment_notes)
    return LinearBlockBounds(method=method, orders=orders, intervals=_intervals_of_box(orders, low, high),
                             inner_lower=inner[0], inner_upper=inner[1], inner_point=inner[2],
                             num_linear_programs=counter.solves, num_tightening_rounds=rounds,
                             feasible_orthants=tuple(feasible), max_certificate_gap=counter.max_gap, notes=notes,
                             windowing=windowing)


def _check_settings(method: str, **sample_counts: int) -> None:
    """Refuse an unknown method or a window, joint, partition or moment length that is no integer above its
    least useful value (20 samples for windows and joint parts, 0 = off for the partition and the moments)."""
    if method not in LINEAR_BOUND_METHODS:
        raise InvalidInputError(f"method: expected one of {', '.join(LINEAR_BOUND_METHODS)}, got {method!r}")
    least = {"window_samples": 20, "joint_samples": 20, "partition_samples": 0, "moment_samples": 0}
    for name, value in sample_counts.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least[name]:
            raise InvalidInputError(f"{name}: expected an integer >= {least[name]}, got {value!r}")


def _coupled_stages(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], counter: _Counter,
                    moment_notes: list[str], *, max_tightening_rounds: int, tightening_tolerance: float,
                    map_windows: MapFunction, progress: Progress | None, window_samples: int, joint_samples: int,
                    trajectory: bool, partitioned: bool, moment_samples: int
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], int, list[Any], str]:
    """The coupled method's stages after the paper's bounds: rounds of the trajectory relaxation over all samples
    (``trajectory``) or the McCormick relaxation with iterated tightening over windows and joint parts
    (:func:`~.windows._coupled_bounds`), then (``partitioned``) the partition of the box of a
    (:func:`~.final_tightening._partitioned_bounds`) by the same relaxation and the moment cuts
    (:func:`~.final_tightening._moment_bounds`). Returns the box (NaN where the set is empty), the rounds, the
    feasible points found, and the windowing in words."""
    na = data.orders.na
    if trajectory:
        counter.stage = f"trajectory relaxation of all {data.u.size} samples"
        # twice the rounds: they start from the paper method's box, not from a first window's (N = 10 000, 8 bits,
        # run 0 of the record-length benchmark: 7 rounds, 1.0 s, to the box of the windows and joint parts)
        low, high, rounds, points, empty = _tighten(data, low, high, counter, 2 * max_tightening_rounds,
                                                    tightening_tolerance, True, _trajectory_relaxation,
                                                    full_rounds=True)
        if empty:
            low, high, points = np.full(low.size, math.nan), np.full(low.size, math.nan), []
        windowing = (f"all {data.u.size} samples in the trajectory relaxation (inner signal eliminated), {rounds} "
                     f"round{'s' if rounds > 1 else ''}")
    else:
        low, high, rounds, points, plan = _coupled_bounds(data, low, high, counter, max_tightening_rounds,
                                                          tightening_tolerance, map_windows, progress, window_samples,
                                                          joint_samples)
        windowing = _describe(plan, data.u.size, window_samples, joint_samples)
    if not np.any(np.isnan(low)) and na and partitioned:
        low, high, cell_points, cells = _partitioned_bounds(
            data, low, high, counter, progress=progress,
            relaxation=_trajectory_relaxation if trajectory else _interval_lp)
        points = [new if new is not None else old for new, old in zip(cell_points, points)] if points else cell_points
        windowing += f", then the box of a partitioned into cells ({cells} solved)"
    if not np.any(np.isnan(low)) and na and data.u.size <= moment_samples:
        low, high, sdp_s = _moment_bounds(data, low, high, counter, moment_notes)
        windowing += f", then cuts from the moment (SDP) relaxation ({sdp_s:.1f} s in cvxpy)"
    return low, high, rounds, points, windowing


def _intervals_of_box(orders: LinearModelOrders, low: NDArray[np.float64],
                      high: NDArray[np.float64]) -> dict[str, ParameterInterval]:
    """The box as named intervals; a bound of b at the artificial box ±_B_BOX is reported infinite (no
    information about that coefficient)."""
    intervals = {}
    for k, name in enumerate(orders.parameter_names):
        lo, hi = float(low[k]), float(high[k])
        if k >= orders.na:
            lo = -math.inf if lo <= -_B_BOX * (1 - 1e-9) else lo
            hi = math.inf if hi >= _B_BOX * (1 - 1e-9) else hi
        intervals[name] = ParameterInterval(lo, hi)
    return intervals


def _fallback_notes(names: tuple[str, ...], counter: _Counter) -> tuple[str, ...]:
    """One note per (parameter, side) whose bounding LP HiGHS could not solve at some stage."""
    seen: dict[tuple[int, str], list[str]] = {}
    for k, side, status, stage in counter.fallbacks:
        seen.setdefault((k, side), [])
        if f"{stage} ({status})" not in seen[(k, side)]:
            seen[(k, side)].append(f"{stage} ({status})")
    solver_notes = tuple(
        f"{names[k]} {side} bound: HiGHS could not solve its bounding LP in the {', '.join(where)} after "
        f"the retries ({_RECOVERY_NAMES}); the bound there is the previous valid one, so it may be looser "
        "than the method allows (still guaranteed)" for (k, side), where in sorted(seen.items()))
    lost_notes = tuple(
        f"all parameters: a process running the windows stopped in the {stage} ({reason}); the bounds are the "
        "intersection of the windows and parts solved before that (still guaranteed, possibly looser than the "
        "method allows); rerun with fewer jobs or another joint_samples for the rest"
        for stage, reason in counter.lost_stages)
    return solver_notes + lost_notes
