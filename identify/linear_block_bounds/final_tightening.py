"""The final tightenings of short records: the partition of the box of a into cells (:func:`_partitioned_bounds`),
made again where the verified inner values show a relaxation gap (:func:`_closed_relaxation_gap`), and the cuts
from the moment (SDP) relaxation (:func:`_moment_bounds`, :mod:`identify.moment_relaxation`)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from identify.linear_block_bounds import Progress
from identify.linear_block_bounds.certified_lp import _LP, _bounds_over, _Counter, _proven_infeasible, _widened
from identify.linear_block_bounds.inner_values import _inner_values
from identify.linear_block_bounds.problem import _coupled_lp, _Data, _interval_lp, _tighten

_LOG = logging.getLogger(__package__)  # the package's logger: ``rig -v`` names identify.linear_block_bounds


_PARTITION_BOXES = 48
"""Sub-boxes of a solved at most by the partition; it stops earlier once a refinement moves no bound by 1 %. N = 1000,
8 bits, run 0 of the benchmark: 24 cells left a2 1.117 times as wide as its verified inner values, 48 (36 solved
before the 1 % stop) 1.075, for 12.6 instead of 8.8 CPU-s."""


_PARTITION_STAGE = "partition of the box of a (cells)"


@dataclass(frozen=True)
class _SubBox:
    """One cell of the partition of the box of a, with the box of θ its relaxation gives and the extreme
    points (None where a bound fell back)."""

    a_low: NDArray[np.float64]
    a_high: NDArray[np.float64]
    low: NDArray[np.float64]
    high: NDArray[np.float64]
    points: tuple[NDArray[np.float64] | None, ...]
    depth: int = 0
    """Halvings from the whole box of a to this cell."""


def _partitioned_bounds(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], counter: _Counter,
                        max_boxes: int = _PARTITION_BOXES, relative_improvement: float = 0.01,
                        progress: Progress | None = None, patient: bool = False,
                        relaxation: Callable[[_Data, NDArray[np.float64], NDArray[np.float64]], _LP] = _interval_lp
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.float64] | None], int]:
    """The final tightening of short records: spatial branch and bound on the box of a.

    The relaxations replace a_i δx_s by a set that grows with the width of the box of a_i (McCormick:
    :func:`~.problem._coupled_lp`; the interval relaxation: r_i Δx_s per product), so the box that one relaxation gives
    for the whole box of a is wider than the exact set's (outer/inner 1.4-2 at 8 bits without the cells).
    Here the box of a is cut into cells; each cell's interval relaxation is tightened over the cell alone (narrower a,
    smaller envelopes), cells whose relaxation is proven empty (certified phase 1) are dropped, and the hull of
    the cells' boxes is the bound. Every feasible point has its a in some cell and satisfies that cell's
    relaxation, so the hull is a guaranteed outer bound. The cells that attain a bound of the hull are halved
    along their relatively widest a_i and solved again, until ``max_boxes`` cells were solved or a refinement
    moves no bound by more than ``relative_improvement`` of its width (``patient``: only once the cells were
    halved twice along every a_i, see :func:`_closed_relaxation_gap`). Returns the box, the extreme points
    (``points[2k]`` attains the lower bound of θ_k) and the number of cells solved."""
    na, p = data.orders.na, data.orders.num_parameters
    counter.stage = f"partition of the box of a ({data.u.size} samples)"

    def solve(a_low: NDArray[np.float64], a_high: NDArray[np.float64], depth: int) -> _SubBox | None:
        cell_low, cell_high = low.copy(), high.copy()
        cell_low[:na], cell_high[:na] = a_low, a_high
        box_low, box_high, _, points, empty = _tighten(data, cell_low, cell_high, counter, 3, 0.05, True, relaxation,
                                                       full_rounds=True)
        if empty:
            return None
        if not points:
            # HiGHS found the cell's relaxation infeasible, but the certificate cannot prove it: a sliver within
            # the solver's tolerance. Keeping the cell's box would give the hull the whole box of b (at
            # 96 cells at N = 1000, 8 bits left the bounds as before the partition); the relaxation widened by
            # the tolerance contains the cell's set, so its certified bounds hold (or prove the cell empty).
            widened = _widened(relaxation(data, box_low, box_high))
            wide_low, wide_high, _ = _bounds_over(widened, p, counter)
            if not np.all(np.isfinite(wide_low)):
                if _proven_infeasible(widened, counter):
                    return None
            else:
                box_low, box_high = np.maximum(box_low, wide_low), np.minimum(box_high, wide_high)
            points = [None] * (2 * p)
        return _SubBox(a_low, a_high, box_low, box_high, tuple(None if x is None else x[:p] for x in points), depth)

    def hull(cells: list[_SubBox]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return (np.min([c.low for c in cells], axis=0), np.max([c.high for c in cells], axis=0))

    def halves(cell: _SubBox) -> list[tuple[NDArray[np.float64], NDArray[np.float64], int]]:
        i = int(np.argmax((cell.a_high - cell.a_low) / np.maximum(high[:na] - low[:na], 1e-300)))
        middle = 0.5 * (cell.a_low[i] + cell.a_high[i])
        left_high, right_low = cell.a_high.copy(), cell.a_low.copy()
        left_high[i], right_low[i] = middle, middle
        return [(cell.a_low, left_high, cell.depth + 1), (right_low, cell.a_high, cell.depth + 1)]

    solved = 0
    cells: list[_SubBox] = []
    pending = halves(_SubBox(low[:na], high[:na], low, high, ()))
    current_low, current_high = low.copy(), high.copy()
    while True:
        for a_low, a_high, depth in pending:
            solved += 1
            cell = solve(a_low, a_high, depth)
            if cell is not None:
                cells.append(cell)
            if progress is not None:
                progress(_PARTITION_STAGE, solved, max_boxes)
        if not cells:  # every cell proven empty, the caller's relaxation not (tolerances): keep its box
            return low, high, [None] * (2 * p), solved
        cells_low, cells_high = hull(cells)
        new_low, new_high = np.maximum(cells_low, low), np.minimum(cells_high, high)
        moved = np.max(((current_high - current_low) - (new_high - new_low))
                       / np.maximum(current_high - current_low, 1e-300))
        current_low, current_high = new_low, new_high
        _LOG.debug("partition: %d cell(s) solved, the hull moved a bound by %.3g of its width, half-widths %s",
                   solved, moved, 0.5 * (current_high - current_low))
        deciding = sorted({int(np.argmin([c.low[k] for c in cells])) for k in range(p)}
                          | {int(np.argmax([c.high[k] for c in cells])) for k in range(p)})
        # A refinement that moves the hull by under a tenth of ``relative_improvement`` ends the partition (the
        # relaxation is about tight: 1e-4 of the width at 15 bits); one that moves it by less than
        # ``relative_improvement`` ends it only once the cells just solved were halved twice along every a_i:
        # one halving leaves a bound to the other axes, so the first refinements may move the hull by little
        # before the next ones move it by much (N = 100, 8 bits, run 9: b1 0.7 % and 0.3 %, then 3.6 %).
        # Waiting for the two halvings at every move below the tolerance made N = 1000, 15 bits 5 times slower.
        settled = min(depth for _, _, depth in pending) >= 2 * na
        tiny = moved < 0.1 * relative_improvement and solved > 2 * na and not patient
        if tiny or (moved < relative_improvement and settled) or solved + 2 * len(deciding) > max_boxes:
            break
        # a cell is replaced by its halves only once they are solved (in the next turn of the loop)
        pending = [half for index in deciding for half in halves(cells[index])]
        cells = [cell for index, cell in enumerate(cells) if index not in deciding]
    if progress is not None:
        progress(_PARTITION_STAGE, solved, solved)  # the stage ends, usually before the most cells it may take
    points: list[NDArray[np.float64] | None] = [None] * (2 * p)
    for k in range(p):
        if cells:
            lowest = min(cells, key=lambda c: c.low[k])
            highest = max(cells, key=lambda c: c.high[k])
            points[2 * k] = lowest.points[2 * k] if lowest.points else None
            points[2 * k + 1] = highest.points[2 * k + 1] if highest.points else None
    return current_low, current_high, points, solved


RELAXATION_GAP_TARGET = 1.1
"""Largest ratio of a parameter's outer interval to the span of its verified inner values that a partitioned
record is left with when a patient partition can do better (:func:`_closed_relaxation_gap`): the goal set
for N <= 1000 (above it a tenth of the reported width may be relaxation, not data). A lower target
costs time on most records at 8 bits: at 1.05 the median run of N = 100 was partitioned twice (2.4 times the
CPU) for 1.05 instead of 1.06."""


def _relaxation_gap(low: NDArray[np.float64], high: NDArray[np.float64], inner_low: NDArray[np.float64],
                    inner_high: NDArray[np.float64]) -> float:
    """The largest outer/inner ratio over the parameters with verified inner values on both sides."""
    inner = inner_high - inner_low
    known = np.isfinite(inner) & (inner > 0)
    return float(np.max((high - low)[known] / inner[known])) if np.any(known) else 1.0


def _closed_relaxation_gap(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64],
                           points: list[NDArray[np.float64] | None], inner: tuple[NDArray[np.float64], ...],
                           counter: _Counter, progress: Progress | None,
                           relaxation: Callable[[_Data, NDArray[np.float64], NDArray[np.float64]], _LP] = _interval_lp
                           ) -> tuple[NDArray[np.float64], NDArray[np.float64], tuple[NDArray[np.float64], ...], int]:
    """The partition made again, patient, where the verified inner values show that the first one stopped
    early: a gap above :data:`RELAXATION_GAP_TARGET`. A first partition ends on a refinement that moves the
    hull by under a tenth of its tolerance, which the first halvings along one a_i can do before the next
    move it by much (N = 100, 8 bits, run 8: b2 1.102 after 6 cells; with every cell halved twice along each
    a_i, 1.08 or less over 10 runs). Waiting for those halvings on every record made N = 1000, 15 bits 5 times
    slower where the first partition is already tight, so only a record whose gap shows it pays. It starts
    from the first partition's hull (a valid outer box, so its cells' relaxations are at least as tight); the
    inner values are searched again from its extreme points and kept where they are wider (every one is a
    verified point). Returns the box, the inner values and witness, and the cells solved (0: not needed)."""
    if _relaxation_gap(low, high, inner[0], inner[1]) <= RELAXATION_GAP_TARGET:
        return low, high, inner, 0
    new_low, new_high, cell_points, cells = _partitioned_bounds(data, low, high, counter, progress=progress,
                                                                patient=True, relaxation=relaxation)
    new_low, new_high = np.maximum(new_low, low), np.minimum(new_high, high)
    points = [new if new is not None else old for new, old in zip(cell_points, points)]
    inner_low, inner_high, witness = _inner_values(data, new_low, new_high, points, counter)
    inner_low, inner_high = np.fmin(inner_low, inner[0]), np.fmax(inner_high, inner[1])
    return new_low, new_high, (inner_low, inner_high, inner[2] if witness is None else witness), cells


_MOMENT_STAGE = "moment (SDP) relaxation"


def _lifted_moment_lp(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64]
                      ) -> tuple[sp.csr_matrix, NDArray[np.float64], sp.csr_matrix, NDArray[np.float64],
                                 NDArray[np.float64], NDArray[np.float64]]:
    """The McCormick LP (:func:`~.problem._coupled_lp`, with the shared backlash if any) lifted by the moment columns
    A_ij ~ a_i a_j (box from the products of the bounds of a, McCormick rows) and D_s ~ δx_s^2 (0 <= D_s <=
    Δx_s^2): (A_ub, b_ub, A_eq, b_eq, lower, upper). Without cuts it is the McCormick LP (A, D are free in
    their boxes); the cuts of :func:`identify.moment_relaxation.moment_cuts` are rows over these columns."""
    from identify import moment_relaxation as moments

    na, N = data.orders.na, data.u.size
    base = _coupled_lp(data, low, high)
    width = base.lower.size
    extra = moments.moment_columns(na, N)
    a_low, a_high = low[:na], high[:na]
    pair_low, pair_high = [], []
    for i, j in [(i, j) for i in range(na) for j in range(i, na)]:
        corners = [a_low[i] * a_low[j], a_low[i] * a_high[j], a_high[i] * a_low[j], a_high[i] * a_high[j]]
        # a_i^2 >= 0 even when the box of a_i holds 0
        least = 0.0 if i == j and a_low[i] <= 0.0 <= a_high[i] else min(corners)
        pair_low.append(least - 1e-12 * (1.0 + abs(least)))
        pair_high.append(max(corners) + 1e-12 * (1.0 + abs(max(corners))))
    lower = np.concatenate([base.lower, pair_low, np.zeros(N)])
    upper = np.concatenate([base.upper, pair_high, data.dx ** 2 * (1.0 + 1e-12)])

    def widen(matrix: sp.csr_matrix) -> sp.csr_matrix:
        return sp.hstack([matrix, sp.csr_matrix((matrix.shape[0], extra))]).tocsr()

    rlt, rlt_rhs = moments.moment_rows(na, a_low, a_high, width + extra, width)
    return (sp.vstack([widen(base.A_ub), rlt]).tocsr(), np.concatenate([base.b_ub, rlt_rhs]), widen(base.A_eq),
            base.b_eq, lower, upper)


def _moment_bounds(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], counter: _Counter,
                   notes: list[str]) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The final tightening by the first-order moment relaxation (:mod:`identify.moment_relaxation`): the SDP
    of every bound is solved with cvxpy, its PSD duals become cuts of the McCormick LP lifted by the moment
    columns (A, D), and that LP's certified bounds are intersected with the box. An SDP that fails, or a
    missing cvxpy, leaves the bound as it was and adds a note. Returns the box and the SDP time in seconds."""
    from identify import moment_relaxation as moments

    missing = moments.available()
    if missing is not None:
        notes.append(f"all parameters: the moment (SDP) relaxation was not run: {missing}; the bounds are the LP ones")
        return low, high, 0.0
    na, p, N = data.orders.na, data.orders.num_parameters, data.u.size
    A_ub, b_ub, A_eq, b_eq, lower, upper = _lifted_moment_lp(data, low, high)
    try:
        cuts = moments.moment_cuts(na=na, p=p, num_samples=N, equations=A_eq, equation_rhs=b_eq,
                                   inequalities=A_ub, inequality_rhs=b_ub, lower=lower, upper=upper,
                                   objectives=list(range(2 * p)), delta_bound_rad=data.dx)
    except Exception as error:  # noqa: BLE001 - any failure of the optional SDP path keeps the LP bounds
        notes.append(f"all parameters: the moment (SDP) relaxation failed ({type(error).__name__}: {error}); "
                     "the bounds are the LP ones (still guaranteed)")
        return low, high, 0.0
    names = data.orders.parameter_names
    for objective, status in cuts.failed:
        k, side = divmod(objective, 2)
        notes.append(f"{names[k]} {'upper' if side else 'lower'} bound: the moment SDP gave no dual ({status}); "
                     "that bound is the LP one (still guaranteed)")
    if not cuts.rhs.size:
        return low, high, cuts.sdp_s
    lp = _LP(sp.vstack([A_ub, cuts.rows]).tocsr(), np.concatenate([b_ub, cuts.rhs]), A_eq, b_eq, lower, upper)
    counter.stage = f"{_MOMENT_STAGE} of {N} samples"
    new_low, new_high, _ = _bounds_over(lp, p, counter)
    if not np.all(np.isfinite(new_low)):
        return low, high, cuts.sdp_s  # not proven empty here: keep the box (the LP path decides emptiness)
    return np.maximum(low, new_low), np.minimum(high, new_high), cuts.sdp_s
