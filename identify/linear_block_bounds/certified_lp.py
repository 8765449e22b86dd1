"""Certified LP bounds: the LP (:class:`_LP`), one HiGHS model of it re-solved for many objectives from the previous
basis, with the settings that recover from a failed solve (:class:`_Solver`), and every bound replaced by the
Neumaier-Shcherbina bound from the solver's duals, so that it holds whatever the solver's tolerances
(:meth:`_Solver.minimize`, :func:`_bounds_over`, :func:`_proven_infeasible`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray


_DEFAULT_SETTINGS = {"solver": "simplex", "simplex_strategy": 1, "presolve": "on", "run_crossover": "on",
                     "simplex_scale_strategy": 2}
"""Dual simplex with HiGHS's own pricing for every model's first solve. Devex pricing
(``simplex_dual_edge_weight_strategy`` 1) made one 3000-sample part's 8 LPs 3-28 % faster, but with it a worker
segfaulted inside HiGHS 1.16 (a stack overflow: the ``HEkkDualRHS::chooseNormal`` recursion of the dual simplex)
on N = 100 000, 8 bits, run 0, which this setting had solved: not used."""
_RECOVERY_SETTINGS = (
    {"solver": "simplex", "simplex_strategy": 1, "presolve": "on"},
    {"solver": "simplex", "simplex_strategy": 1, "presolve": "off"},
    # the chained equations of long records have rows of very different size; unscaled dual simplex solved
    # the bounding LP of benchmark record [2009, 10000, 12, 1] that every scaled setting stopped on with
    # "Solve error"
    {"solver": "simplex", "simplex_strategy": 1, "presolve": "on", "simplex_scale_strategy": 0},
    {"solver": "ipm", "run_crossover": "off", "presolve": "on"},
    {"solver": "ipm", "run_crossover": "off", "presolve": "off"},
)
_RECOVERY_NAMES = "warm start dropped, dual simplex with and without presolve and without scaling, interior point"
_TIME_LIMIT_S = 20.0
"""HiGHS time limit per attempt on one LP (plus 0.2 ms per row); a time-out counts as a failed attempt."""


@dataclass
class _LP:
    """min c^T z subject to A_ub z <= b_ub, A_eq z = b_eq, range_lower <= A_range z <= range_upper,
    lower <= z <= upper (all bounds finite).

    A two-sided row |r^T z - c| <= s is one ranged row, not two inequalities: HiGHS keeps it as one row with a
    boxed slack, which halved the rows of the interval relaxation and cut its simplex time about four-fold."""

    A_ub: sp.csr_matrix
    b_ub: NDArray[np.float64]
    A_eq: sp.csr_matrix
    b_eq: NDArray[np.float64]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]
    A_range: sp.csr_matrix | None = None
    range_lower: NDArray[np.float64] | None = None
    range_upper: NDArray[np.float64] | None = None
    solver_options: Mapping[str, Any] | None = None
    """HiGHS options every solve of this LP needs, on top of :data:`_DEFAULT_SETTINGS` (a caller's
    ``first_solve`` options go over them), e.g. feasibility tolerances below the width of its rows."""

    def ranged(self) -> tuple[sp.csr_matrix, NDArray[np.float64], NDArray[np.float64]]:
        """The ranged rows (an empty block when there are none)."""
        if self.A_range is None or self.range_lower is None or self.range_upper is None:
            return sp.csr_matrix((0, self.lower.size)), np.zeros(0), np.zeros(0)
        return self.A_range, self.range_lower, self.range_upper

    def rows(self) -> tuple[sp.csr_matrix, NDArray[np.float64], NDArray[np.float64]]:
        """All rows as row_lower <= A z <= row_upper: the inequalities, the ranged rows, the equalities."""
        A_range, range_lower, range_upper = self.ranged()
        return (sp.vstack([self.A_ub, A_range, self.A_eq]).tocsr(),
                np.concatenate([np.full(self.b_ub.size, -np.inf), range_lower, self.b_eq]),
                np.concatenate([self.b_ub, range_upper, self.b_eq]))


class _SolverFailure(RuntimeError):
    """HiGHS stopped on an LP without an optimum or a proof of infeasibility, after every recovery setting."""

    def __init__(self, status: str) -> None:
        super().__init__(f"HiGHS failed on a bounding LP: {status} (tried: {_RECOVERY_NAMES})")
        self.status = status


class _Counter:
    def __init__(self) -> None:
        self.solves = 0
        self.max_gap = 0.0
        # (parameter index, "lower"/"upper", HiGHS status, stage) of every bound kept at its previous value
        self.fallbacks: list[tuple[int, str, str, str]] = []
        self.stage = "paper method"
        # (stage, reason) of every stage whose worker processes were lost (:class:`~.windows._GuardedMap`)
        self.lost_stages: list[tuple[str, str]] = []

    def merge(self, other: "_Counter") -> None:
        """Add the counts of work done elsewhere (a window solved in another process)."""
        self.solves += other.solves
        self.max_gap = max(self.max_gap, other.max_gap)
        self.fallbacks.extend(other.fallbacks)


_UNPRESOLVED = {"presolve": "off", "simplex_dual_edge_weight_strategy": 2}
"""First-solve settings of a part whose presolved first solve failed in an earlier pass (:class:`_PartStart`):
dual simplex without presolve, with dual steepest-edge pricing that does not switch to Devex. At N = 100 000,
8 bits, run 0 of the benchmark, 28 % of the parts' presolved first solves ended in "excessive primal values"
after postsolve, mostly the same parts pass after pass; on them this setting needed no recovery, and on the part
whose presolved first solve crashed HiGHS 1.16 (the ``chooseNormal`` recursion) it solved in about a second where
presolve off with HiGHS's own pricing (steepest edge switching to Devex) failed and its recovery crashed. Not the
default: at 12 bits it is about 40 % slower on the parts than the presolved solve, which fails there on 3 % of
them (measured on the parts of that record at 8 and 12 bits)."""


_FROM_BASIS = {"presolve": "off"}
"""Settings of a first solve that goes on from a given basis (:class:`_PartStart`)."""


@dataclass
class _PartStart:
    """What a part's solves in one pass hand on to the same part's solves in the next
    (:func:`~.windows._coupled_bounds`): the part's LP keeps its rows and columns from pass to pass (only the envelopes
    of the narrower box change), so its last optimal basis (HiGHS basis status codes of the columns and rows) is a start
    for the next pass's first solve; a part whose presolved first solve failed hands on no basis (a start from it
    crashed HiGHS, :meth:`_Solver.minimize`), only that failure, which will likely recur (:data:`_UNPRESOLVED`). A start
    only chooses where the simplex begins: the bounds are certified as always."""

    col_status: NDArray[np.int8] | None = None
    row_status: NDArray[np.int8] | None = None
    presolve_failed: bool = False


class _Solver:
    """One HiGHS model of an :class:`_LP`, re-solved for many objectives from the previous basis."""

    def __init__(self, lp: _LP, settings: Mapping[str, Any] | None = None,
                 first_solve: Mapping[str, Any] | None = None, start: _PartStart | None = None) -> None:
        """``settings``: HiGHS options for every solve (no switch to the primal simplex warm start after the
        first); ``first_solve``: options of the model's first solve (and of a solve after a recovery), on top of
        :data:`_DEFAULT_SETTINGS`; ``start``: the basis and experience of the same part's model in the previous
        pass (ignored with ``settings``)."""
        # highspy.Highs() prints a banner (it would break ``--json`` output): the adapter gives a quiet instance.
        from identify.highs_solver import (HighsBasis, HighsBasisStatus, HighsLp, HighsModelStatus, MatrixFormat,
                                           quiet_highs)

        self.lp = lp
        self.A, self.row_lower, self.row_upper = lp.rows()
        A = self.A.tocsc()
        model = HighsLp()
        model.num_col_ = int(A.shape[1])
        model.num_row_ = int(A.shape[0])
        model.col_cost_ = np.zeros(A.shape[1])
        model.col_lower_ = lp.lower
        model.col_upper_ = lp.upper
        model.row_lower_ = self.row_lower
        model.row_upper_ = self.row_upper
        model.a_matrix_.format_ = MatrixFormat.kColwise
        model.a_matrix_.start_ = A.indptr.astype(np.int32)
        model.a_matrix_.index_ = A.indices.astype(np.int32)
        model.a_matrix_.value_ = A.data.astype(float)
        self.highs = quiet_highs()
        self.fixed_settings = dict(settings or {})
        self.presolve_failed = start is not None and start.presolve_failed
        start = None if self.fixed_settings else start
        unpresolved = _UNPRESOLVED if self.presolve_failed else {}
        self.base_settings = {**_DEFAULT_SETTINGS, **(lp.solver_options or {}), **(first_solve or {}), **unpresolved,
                              **self.fixed_settings}
        self._set(self.base_settings)
        # A bounded time per attempt: a warm start that stalls on a long record's LP (one part of a
        # 100 000-sample record kept a worker busy for over 15 minutes) goes on to the recovery settings and,
        # at worst, to the fallback bound, instead of holding up the whole record.
        # HiGHS counts its time limit over all runs of one model, so each run sets it from the time used so far.
        self.time_limit_s = _TIME_LIMIT_S + 2e-4 * float(A.shape[0])
        self.highs.passModel(model)
        if (start is not None and start.col_status is not None and start.row_status is not None
                and start.col_status.size == model.num_col_ and start.row_status.size == model.num_row_):
            basis = HighsBasis()
            basis.col_status = [HighsBasisStatus(int(code)) for code in start.col_status]
            basis.row_status = [HighsBasisStatus(int(code)) for code in start.row_status]
            basis.valid = True
            self.highs.setBasis(basis)
            self._set(_FROM_BASIS)
        self.from_basis = self.highs.getBasis().valid

        self._status = HighsModelStatus
        self.columns = np.arange(A.shape[1], dtype=np.int32)
        self.warm = False
        self.solved = False

    def add_rows(self, rows: sp.csr_matrix, lower: NDArray[np.float64], upper: NDArray[np.float64]) -> None:
        """Append ranged rows to the model (and to the rows the certificate reads). The basis stays valid (the new
        rows' slacks are basic), so the next solve goes on from it, by the dual simplex: the basis may now be primal
        infeasible, but it stays dual feasible."""
        rows = rows.tocsr()
        self.highs.addRows(rows.shape[0], np.asarray(lower, dtype=float), np.asarray(upper, dtype=float), rows.nnz,
                           rows.indptr[:-1].astype(np.int32), rows.indices.astype(np.int32),
                           rows.data.astype(float))
        self.A = sp.vstack([self.A, rows]).tocsr()
        self.row_lower = np.concatenate([self.row_lower, lower])
        self.row_upper = np.concatenate([self.row_upper, upper])
        if self.warm:
            self.highs.setOptionValue("simplex_strategy", 1)
            self.warm = False

    def handoff(self) -> _PartStart:
        """This model's last basis (none if it has no valid one, e.g. after the interior-point method without
        crossover) and whether a presolved first solve failed on it, for the same part's next pass."""
        basis = self.highs.getBasis()
        if not (self.solved and basis.valid) or self.presolve_failed:
            return _PartStart(presolve_failed=self.presolve_failed)
        return _PartStart(np.array([int(code) for code in basis.col_status], dtype=np.int8),
                          np.array([int(code) for code in basis.row_status], dtype=np.int8), self.presolve_failed)

    def _set(self, settings: Mapping[str, Any]) -> None:
        for option, value in settings.items():
            self.highs.setOptionValue(option, value)

    def _run(self) -> None:
        self.highs.setOptionValue("time_limit", self.highs.getRunTime() + self.time_limit_s)
        self.highs.run()

    def minimize(self, cost: NDArray[np.float64], counter: _Counter) -> tuple[float, NDArray[np.float64] | None]:
        """Certified lower bound of min cost^T z (Neumaier-Shcherbina: valid for any dual vector, given the
        finite column boxes) and the solver's minimiser; (inf, None) if the solver reports infeasibility.

        Each solve starts from this model's previous optimal basis; the first from the basis of the same part's
        model in the previous pass, if :class:`_PartStart` hands one on. Not from a part whose presolved solve
        failed: at N = 100 000, 8 bits, such a re-started solve of a joint part sent HiGHS 1.16 into an
        unbounded recursion (``HEkkDualRHS::chooseNormal``, a segfault by stack overflow), with HiGHS's own
        pricing and with dual steepest edge alike; the same part solves in about a second from scratch without
        presolve (:data:`_UNPRESOLVED`)."""
        counter.solves += 1
        highs = self.highs
        highs.changeColsCost(self.columns.size, self.columns, np.asarray(cost, dtype=float))
        self._run()
        status = highs.getModelStatus()
        if status not in (self._status.kOptimal, self._status.kInfeasible):
            if not (self.solved or self.from_basis) and self.base_settings["presolve"] == "on":
                self.presolve_failed = True
            # Recover from a stalled warm start or a numerically poor basis (the chained equations can make
            # a basis very ill-conditioned): solve again from scratch, by dual simplex with and without
            # presolve, then by the interior-point method without crossover (its duals are all the
            # certificate needs). HiGHS is deterministic: settings that failed from scratch (the model's
            # first solve has no basis to drop) are not tried again.
            tried = [] if (self.solved or self.from_basis) else [self.base_settings]
            for recovery in _RECOVERY_SETTINGS:
                settings = {**self.base_settings, **recovery}
                if settings in tried:
                    continue
                tried.append(settings)
                highs.clearSolver()
                self._set(settings)
                self._run()
                status = highs.getModelStatus()
                if status in (self._status.kOptimal, self._status.kInfeasible):
                    break
            self._set(self.base_settings)
            self.warm = False
        self.solved = True
        if status == self._status.kOptimal and not self.warm and not self.fixed_settings:
            # The optimal basis stays primal feasible when only the objective changes, so primal simplex
            # without presolve continues from it for the next objectives.
            highs.setOptionValue("simplex_strategy", 4)
            highs.setOptionValue("presolve", "off")
            self.warm = True
        if status == self._status.kInfeasible:
            return math.inf, None
        if status != self._status.kOptimal:
            raise _SolverFailure(highs.modelStatusToString(status))
        solution = highs.getSolution()
        x = np.asarray(solution.col_value, dtype=float)
        y = np.asarray(solution.row_dual, dtype=float)
        # keep only dual signs that the finite row bounds support
        y = np.where((y > 0.0) & ~np.isfinite(self.row_lower), 0.0, y)
        y = np.where((y < 0.0) & ~np.isfinite(self.row_upper), 0.0, y)
        row_term = np.where(y > 0.0, y * np.where(np.isfinite(self.row_lower), self.row_lower, 0.0),
                            y * np.where(np.isfinite(self.row_upper), self.row_upper, 0.0))
        reduced = cost - self.A.T @ y
        box_term = np.minimum(reduced * self.lp.lower, reduced * self.lp.upper)
        bound = float(row_term.sum() + box_term.sum())
        bound -= 1e-13 * (float(np.abs(row_term).sum() + np.abs(box_term).sum()) + 1.0)  # rounding of the sums
        objective = float(cost @ x)
        bound = min(bound, objective)
        counter.max_gap = max(counter.max_gap, objective - bound)
        return bound, x


_TALL_RATIO = 50
"""An LP with this many ranged rows per column or more is solved by row generation (:class:`_RowGeneratedSolver`)."""
_TALL_START_ROWS = 200
"""Ranged rows of the first subset (evenly spread) of :class:`_RowGeneratedSolver`."""
_TALL_ROWS_ADDED = 30
"""Most violated ranged rows added per turn."""
_TALL_TURNS = 40
"""Turns of the row generation per objective at most (the bound after any turn is valid, only possibly looser)."""
_TALL_VIOLATION = 1e-10
"""A ranged row counts as violated by a subset's minimiser beyond this (absolute; the rows of the LPs this serves
are angles in rad)."""


class _RowGeneratedSolver:
    """:meth:`_Solver.minimize` of a tall LP (few columns, many ranged rows: the trajectory LPs of
    :mod:`~.trajectory_lp`, one row per sample) on a subset of its ranged rows that grows by the rows its minimisers
    violate (row generation, the dual of column generation), the other rows (inequalities, equalities) kept whole.

    Fewer rows give a relaxation, so the certified bound of the subset LP is a valid bound of the whole LP at every
    turn, and a subset proven infeasible proves the whole LP infeasible; once a minimiser violates no row it is a
    minimiser of the whole LP. After ``_TALL_TURNS`` turns the bound is kept and the last minimiser returned as it
    is (it may then violate rows of the whole LP by a little: callers use such points only as candidates). The
    subset carries over from objective to objective: the rows one objective needed are likely needed again."""

    def __init__(self, lp: _LP, first_solve: Mapping[str, Any] | None = None) -> None:
        self.lp = lp
        self._rows, self._row_lower, self._row_upper = lp.ranged()
        count = self._rows.shape[0]
        self._chosen = np.zeros(count, dtype=bool)
        self._chosen[:: max(1, -(-count // _TALL_START_ROWS))] = True
        chosen = self._chosen
        subset = _LP(lp.A_ub, lp.b_ub, lp.A_eq, lp.b_eq, lp.lower, lp.upper, self._rows[chosen],
                     self._row_lower[chosen], self._row_upper[chosen], lp.solver_options)
        self._solver = _Solver(subset, first_solve={**(first_solve or {}), "presolve": "off"})

    @staticmethod
    def suits(lp: _LP) -> bool:
        return lp.ranged()[0].shape[0] >= _TALL_RATIO * max(lp.lower.size, 1)

    @property
    def warm(self) -> bool:
        return self._solver.warm

    @warm.setter
    def warm(self, value: bool) -> None:
        self._solver.warm = value

    def minimize(self, cost: NDArray[np.float64], counter: _Counter) -> tuple[float, NDArray[np.float64] | None]:
        bound, x = math.inf, None
        for _ in range(_TALL_TURNS):
            bound, x = self._solver.minimize(cost, counter)
            if x is None:
                return bound, None
            values = self._rows @ x
            violation = np.maximum(values - self._row_upper, self._row_lower - values)
            violated = np.flatnonzero((violation > _TALL_VIOLATION) & ~self._chosen)
            if not violated.size:
                break
            if violated.size > _TALL_ROWS_ADDED:
                violated = violated[np.argpartition(violation[violated], -_TALL_ROWS_ADDED)[-_TALL_ROWS_ADDED:]]
            self._chosen[violated] = True
            self._solver.add_rows(self._rows[violated], self._row_lower[violated], self._row_upper[violated])
        return bound, x


def _solver_for(lp: _LP, first_solve: Mapping[str, Any] | None = None) -> _Solver | _RowGeneratedSolver:
    """The solver of an LP: by row generation when it is tall (:class:`_RowGeneratedSolver`), else one HiGHS model."""
    if _RowGeneratedSolver.suits(lp):
        return _RowGeneratedSolver(lp, first_solve)
    return _Solver(lp, first_solve=first_solve)


def _certified_minimum(lp: _LP, cost: NDArray[np.float64], counter: _Counter) -> tuple[float, NDArray[np.float64] | None]:
    return _Solver(lp).minimize(cost, counter)


def _proven_infeasible(lp: _LP, counter: _Counter) -> bool:
    """Phase 1: min τ >= 0 with every row relaxed by τ (equalities to |row| <= τ); infeasible iff the
    certified lower bound on τ is > 0."""
    A_range, range_lower, range_upper = lp.ranged()
    A_all = sp.vstack([lp.A_ub, A_range, -A_range, lp.A_eq, -lp.A_eq]).tocsr()
    b_all = np.concatenate([lp.b_ub, range_upper, -range_lower, lp.b_eq, -lp.b_eq])
    relaxed = _LP(sp.hstack([A_all, -sp.csr_matrix(np.ones((A_all.shape[0], 1)))]).tocsr(), b_all,
                  sp.csr_matrix((0, lp.lower.size + 1)), np.zeros(0),
                  np.append(lp.lower, 0.0), np.append(lp.upper, 1e6), solver_options=lp.solver_options)
    cost = np.zeros(lp.lower.size + 1)
    cost[-1] = 1.0
    reported_gap = counter.max_gap
    try:
        bound, _ = _certified_minimum(relaxed, cost, counter)
    except _SolverFailure:
        return False  # not proven: the caller keeps the set (a valid, looser answer)
    finally:
        # max_certificate_gap describes the reported bounds; a loose phase-1 certificate only makes the proof
        # fail (the cell or orthant is then kept), it loosens no bound
        counter.max_gap = reported_gap
    return bound > 0.0


def _bounds_over(lp: _LP, p: int, counter: _Counter, wanted: NDArray[np.bool_] | None = None, retry: bool = False,
                 start: _PartStart | None = None
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.float64] | None]]:
    """Certified min and max of each of the first p variables, with the minimisers/maximisers
    (``points[2k]`` minimises and ``points[2k + 1]`` maximises variable k), on one HiGHS model whose
    objective changes (each solve continues from the previous optimal basis).

    ``wanted`` (2p booleans in the order of ``points``; all by default) names the bounds to solve: the others
    are the LP's own column bounds (the caller's box, valid for every point of the set) with point None, so a
    caller that needs only the bounds still moving saves their LPs (:func:`~.windows._coupled_bounds`). ``retry``: every
    solve by :data:`RETRY_SETTINGS` (a task solved again after a crash, :class:`~.windows._GuardedMap`). ``start`` (in
    and out): the model starts from it (:class:`_PartStart`) and it is overwritten with the model's hand-off.

    A bound whose LP HiGHS cannot solve (after the recovery settings of :meth:`_Solver.minimize`) is the
    LP's own column bound for that variable, which holds for every point of the set (the caller's current
    box); it is recorded in ``counter.fallbacks`` and its point is None."""
    if not retry and start is None and _RowGeneratedSolver.suits(lp):
        return _solved_bounds(_RowGeneratedSolver(lp), lp, p, counter, wanted)
    solver = _Solver(lp, settings=RETRY_SETTINGS if retry else None, start=start)
    try:
        return _solved_bounds(solver, lp, p, counter, wanted)
    finally:
        if start is not None:
            handoff = solver.handoff()
            start.col_status, start.row_status, start.presolve_failed = (handoff.col_status, handoff.row_status,
                                                                         handoff.presolve_failed)


def _solved_bounds(solver: _Solver | _RowGeneratedSolver, lp: _LP, p: int, counter: _Counter,
                   wanted: NDArray[np.bool_] | None
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.float64] | None]]:
    """The solves of :func:`_bounds_over` on its model."""
    lows, highs = lp.lower[:p].copy(), lp.upper[:p].copy()
    points: list[NDArray[np.float64] | None] = [None] * (2 * p)
    for index in range(2 * p):
        if wanted is not None and not wanted[index]:
            continue
        k, side = divmod(index, 2)
        cost = np.zeros(lp.lower.size)
        cost[k] = -1.0 if side else 1.0
        try:
            value, x = solver.minimize(cost, counter)
        except _SolverFailure as failure:
            counter.fallbacks.append((k, "upper" if side else "lower", failure.status, counter.stage))
            solver.warm = False
            continue
        if x is None:  # infeasible: no other objective can do better
            return np.full(p, math.inf), np.full(p, -math.inf), []
        if side:
            highs[k] = -value
        else:
            lows[k] = value
        points[index] = x
    return lows, highs, points


RETRY_SETTINGS = {"solver": "ipm", "run_crossover": "off", "presolve": "on"}
"""HiGHS settings for every solve of a task a dead worker left unfinished, solved once more
(:class:`~.windows._GuardedMap`): the interior-point method without crossover (its duals are all the certificate of
:meth:`_Solver.minimize` needs). The worker deaths met so far were HiGHS 1.16 overflowing its stack in the dual
simplex (``HEkkDualRHS::chooseNormal``), which the interior-point method does not run; the solver is
deterministic, so the same task by the dual simplex would die again (and did, with presolve off: N = 100 000,
8 bits, run 0 of the record-length benchmark). It costs about 3 times the simplex on a part."""


_WIDENING = 1e-6
"""Relative widening of every row by :func:`_widened` (ten times HiGHS's primal feasibility tolerance)."""


def _widened(lp: _LP) -> _LP:
    """The LP with every row relaxed by ``_WIDENING`` (1 + |its bound|), equalities becoming ranged rows: its
    feasible set contains the LP's, so its certified bounds are bounds of the LP's set too."""
    def slack(bound: NDArray[np.float64]) -> NDArray[np.float64]:
        return _WIDENING * (1.0 + np.abs(bound))

    A_range, range_lower, range_upper = lp.ranged()
    return _LP(lp.A_ub, lp.b_ub + slack(lp.b_ub), sp.csr_matrix((0, lp.lower.size)), np.zeros(0), lp.lower, lp.upper,
               sp.vstack([A_range, lp.A_eq]).tocsr(),
               np.concatenate([range_lower - slack(range_lower), lp.b_eq - slack(lp.b_eq)]),
               np.concatenate([range_upper + slack(range_upper), lp.b_eq + slack(lp.b_eq)]), lp.solver_options)
