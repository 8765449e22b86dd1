"""The verified inner values, attained by points of the exact feasible set (:class:`_ExactProblemAtFixedA`,
:func:`_inner_values`), and the explanation of an empty set (:func:`_explain`)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.optimize import linprog

from identify.linear_block_bounds.certified_lp import _LP, _Counter, _solver_for
from identify.linear_block_bounds.problem import _Data, _gain_row, _orthant_lp, _with_shared_backlash
from identify.linear_block_bounds.point_check import _PointCheck
from identify.linear_block_bounds.result import EmptyLinearSetExplanation
from identify.linear_block_bounds.trajectory_lp import _TrajectoryProblem


class _ExactProblemAtFixedA:
    """The coupled problem with a fixed: z_{i,s} = a_i δx_s is substituted, so the equations
    -psi_t θ + δx_t + Σ_i a_i δx_{t-i} = -x_t^c are linear in (θ, δx) and the LP is the exact feasible set for
    that a (no product columns, no envelope rows: about a third of the relaxation's columns). The matrix is
    built once; each a only rewrites the lag coefficients and the bounds of a."""

    def __init__(self, data: _Data, theta_low: NDArray[np.float64], theta_high: NDArray[np.float64]) -> None:
        orders = data.orders
        na, p = orders.na, orders.num_parameters
        N, m = data.u.size, data.times.size
        width = p + N
        # one row per equation: the p columns of θ, then δx_{t-na} .. δx_{t-1} (value a_i, set per a), then δx_t
        per_row = p + na + 1
        cols = np.empty((m, per_row), dtype=np.int64)
        vals = np.ones((m, per_row))
        cols[:, :p] = np.arange(p)
        vals[:, :p] = -data.regressors
        lag_cols = [p + data.times - i for i in range(1, na + 1)]
        for i in range(1, na + 1):
            cols[:, p + na - i] = lag_cols[i - 1]
        cols[:, p + na] = p + data.times
        A_eq = sp.csr_matrix((vals.ravel(), cols.ravel(), np.arange(m + 1) * per_row), shape=(m, width))
        gain, gain_rhs = _gain_row(orders, width)
        lp = _LP(sp.csr_matrix((0, width)), np.zeros(0), sp.vstack([A_eq, gain]).tocsr(),
                 np.concatenate([-data.xc[data.times], gain_rhs]),
                 np.concatenate([theta_low, -data.dx]), np.concatenate([theta_high, data.dx]))
        if data.shared is not None:
            lp = _with_shared_backlash(lp, data, p)
        lp.A_eq.sort_indices()
        # where each lag coefficient sits in the final matrix's data (rows stay in order under the stacking)
        A = lp.A_eq
        keys = np.repeat(np.arange(A.shape[0], dtype=np.int64), np.diff(A.indptr)) * A.shape[1] + A.indices
        self._lag_positions = [np.searchsorted(keys, np.arange(m, dtype=np.int64) * A.shape[1] + lag_cols[i])
                               for i in range(na)]
        for i in range(na):
            if not np.array_equal(keys[self._lag_positions[i]], np.arange(m) * A.shape[1] + lag_cols[i]):
                raise AssertionError("lag coefficients not found in the exact fixed-a matrix")  # pragma: no cover
        self._a_positions = [np.searchsorted(keys, np.arange(m, dtype=np.int64) * A.shape[1] + i) for i in range(na)]
        for i in range(na):
            if not np.array_equal(keys[self._a_positions[i]], np.arange(m) * A.shape[1] + i):
                raise AssertionError("a coefficients not found in the exact fixed-a matrix")  # pragma: no cover
        self._lp = lp
        self._na = na
        self._times = data.times
        self._p = p
        self._num_samples = N
        self._scale = max(1.0, float(np.max(np.abs(data.xc))))

    def linearized(self, a0: NDArray[np.float64], point: NDArray[np.float64], a_low: NDArray[np.float64],
                   a_high: NDArray[np.float64]) -> _LP:
        """The equations linearised at an exact point (a0, δx0): a_i δx_s ≈ a0_i δx_s + a_i δx0_s - a0_i δx0_s,
        with a free in [a_low, a_high]. Not a relaxation and not exact: it only proposes the next a, which
        :meth:`at` then verifies."""
        lp = self._lp
        dx0 = point[self._p: self._p + self._num_samples]
        values = lp.A_eq.data.copy()
        rhs = lp.b_eq.copy()
        m = self._times.size
        for i in range(self._na):
            lagged = dx0[self._times - (i + 1)]
            values[self._lag_positions[i]] = a0[i]
            values[self._a_positions[i]] += lagged
            rhs[:m] += a0[i] * lagged
        lower, upper = lp.lower.copy(), lp.upper.copy()
        lower[: self._na], upper[: self._na] = a_low, a_high
        A_eq = sp.csr_matrix((values, lp.A_eq.indices, lp.A_eq.indptr), shape=lp.A_eq.shape)
        return _LP(lp.A_ub, lp.b_ub, A_eq, rhs, lower, upper)

    def at(self, fixed_a: NDArray[np.float64]) -> _LP:
        """The exact LP for this a (a's columns fixed by their bounds)."""
        lp = self._lp
        values = lp.A_eq.data.copy()
        for i in range(self._na):
            values[self._lag_positions[i]] = fixed_a[i]
        lower, upper = lp.lower.copy(), lp.upper.copy()
        lower[: self._na] = upper[: self._na] = fixed_a
        A_eq = sp.csr_matrix((values, lp.A_eq.indices, lp.A_eq.indptr), shape=lp.A_eq.shape)
        return _LP(lp.A_ub, lp.b_ub, A_eq, lp.b_eq, lower, upper)

    def verified(self, lp: _LP, x: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """The solution ``x`` of ``lp`` (from :meth:`at`) if it satisfies the equations to 1e-7 of the inner
        signal's scale (the solver's point meets them only to its tolerance), else None."""
        residual = np.max(np.abs(lp.A_eq @ x - lp.b_eq)) if lp.A_eq.shape[0] else 0.0
        return x if residual <= 1e-7 * self._scale else None


_INNER_BISECTIONS = 5
"""Bisection steps between the last weight whose a admits no exact solution and the first that does."""
_INNER_LOCAL_STEPS = 4
"""Sequential-LP steps from each verified point along the exact set's boundary (:func:`_inner_values`)."""


def _exact_problem(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64]
                   ) -> tuple[_ExactProblemAtFixedA | _TrajectoryProblem, dict[str, object]]:
    """The exact LP at fixed a that the inner values solve, with the HiGHS settings of its solves: the inner signal
    eliminated (:class:`~.trajectory_lp._TrajectoryProblem`, its points decided by the exact check; its LPs carry
    their settings) for na <= 2 and a record of few gaps, else with δx as columns (without presolve: the chained
    equations are solved best so)."""
    check = _PointCheck(data)
    if check.decides and _TrajectoryProblem.suits(data):
        return _TrajectoryProblem(data, low, high, check), {}
    return _ExactProblemAtFixedA(data, low, high), {"presolve": "off"}


def _inner_values(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], points: list[NDArray[np.float64]],
                  counter: _Counter, refine: bool = True
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]:
    """Verified values of every parameter, attained by points of the exact feasible set.

    For each bound: fix a at the relaxation's extreme point's a, or, if that a admits no exact solution, at the
    farthest point towards it from an anchor that does (the centre of the box, else the first extreme point's
    a that does; weights 0.95, 0.8, 0.5, 0, then bisection);
    then local steps of a sequential LP: the bilinear terms linearised at the verified point propose a new a
    within a trust region (``linearized`` of the exact problem, :func:`_exact_problem`), which counts only once the
    exactly linear problem at that a (in b and δx, or b and the chain starts) has a solution. Every reported value
    is that of such a solution, verified: by the exact check of its θ and backlash (:mod:`~.point_check`) when the
    inner signal is eliminated, else against the equations to 1e-7 of the signal's scale. Without ``refine`` (long
    records whose exact LPs have a column per sample) only the weights are tried, without bisection and local
    steps."""
    orders = data.orders
    na, p = orders.na, orders.num_parameters
    inner_low, inner_high = np.full(p, math.nan), np.full(p, math.nan)
    witness = None
    exact, settings = _exact_problem(data, low, high)

    def checked(lp: _LP, k: int, direction: float) -> NDArray[np.float64] | None:
        cost = np.zeros(lp.lower.size)
        cost[k] = direction
        try:
            _, x = _solver_for(lp, first_solve=settings).minimize(cost, counter)
        except RuntimeError:
            return None  # a diagnostic only: the outer bounds do not depend on it
        return x

    def verified(fixed_a: NDArray[np.float64], k: int, direction: float) -> NDArray[np.float64] | None:
        lp = exact.at(fixed_a)
        x = checked(lp, k, direction)
        return None if x is None else exact.verified(lp, x)

    # the line searches start from an a that admits an exact solution: the centre of the box if it does, else
    # the first extreme point's a that does
    centre = 0.5 * (low[:na] + high[:na])
    candidates = [centre] + [np.clip(point[:na], low[:na], high[:na]) for point in points if point is not None]
    centre = next((candidate for candidate in candidates if verified(candidate, 0, 1.0) is not None), centre)
    for k in range(p):
        for direction, point in ((1.0, points[2 * k]), (-1.0, points[2 * k + 1])):
            if point is None:
                continue
            extreme = np.clip(point[:na], low[:na], high[:na])
            found, last_infeasible = None, None
            for weight in (1.0, 0.95, 0.8, 0.5, 0.0):
                x = verified(centre + weight * (extreme - centre), k, direction)
                if x is not None:
                    found = (weight, x)
                    break
                last_infeasible = weight
            if found is None:
                continue
            weight, best = found
            if refine and last_infeasible is not None:
                inside, outside = weight, last_infeasible
                for _ in range(_INNER_BISECTIONS):
                    middle = 0.5 * (inside + outside)
                    x = verified(centre + middle * (extreme - centre), k, direction)
                    if x is not None:
                        inside, best = middle, x
                    else:
                        outside = middle
            radius = 0.25 * (high[:na] - low[:na])
            for _ in range(_INNER_LOCAL_STEPS if refine else 0):
                a0 = best[:na]
                proposal = checked(exact.linearized(a0, best, np.maximum(low[:na], a0 - radius),
                                                    np.minimum(high[:na], a0 + radius)), k, direction)
                if proposal is None:
                    break
                x = None
                for step in (1.0, 0.5, 0.25):
                    x = verified(a0 + step * (proposal[:na] - a0), k, direction)
                    if x is not None and direction * x[k] < direction * best[k]:
                        break
                    x = None
                if x is None:
                    radius = 0.25 * radius
                    continue
                best = x
            value = float(best[k])
            if direction > 0:
                inner_low[k] = value if math.isnan(inner_low[k]) else min(inner_low[k], value)
            else:
                inner_high[k] = value if math.isnan(inner_high[k]) else max(inner_high[k], value)
            if witness is None:
                witness = best[:p].copy()
    return inner_low, inner_high, witness


def _explain(data: _Data, counter: _Counter) -> EmptyLinearSetExplanation:
    """Smallest extra equation error τ (added to every paper-method inequality) that makes some orthant feasible."""
    best_tau, best_rows = math.inf, np.zeros(0, dtype=int)
    m = data.times.size
    for signs in itertools.product((1, -1), repeat=data.orders.na):
        lp = _orthant_lp(data, signs)
        rows = lp.A_ub.shape[0]
        A = sp.hstack([lp.A_ub, -sp.csr_matrix(np.ones((rows, 1)))]).tocsr()
        cost = np.zeros(lp.lower.size + 1)
        cost[-1] = 1.0
        counter.solves += 1
        result = linprog(cost, A_ub=A, b_ub=lp.b_ub, A_eq=sp.hstack([lp.A_eq, sp.csr_matrix((1, 1))]), b_eq=lp.b_eq,
                         bounds=np.vstack([np.column_stack([lp.lower, lp.upper]), [[0.0, None]]]), method="highs")
        if result.status == 0 and result.fun < best_tau:
            best_tau = float(result.fun)
            marginals = np.abs(result.ineqlin.marginals)
            best_rows = np.flatnonzero(marginals[:m] + marginals[m:] > 1e-9)
    samples = tuple(int(data.times[r]) for r in best_rows)
    if best_tau <= 0.0:
        return EmptyLinearSetExplanation(samples, 0.0, (
            "the equations are consistent one by one (Cerone 1993 bounds) but no single inner-signal sequence "
            "satisfies them all with shared errors; the inner-signal bounds are probably too tight: check the noise "
            "bound, the orders and the delay nk, and that the backlash did not change between the experiments."))
    message = (
        f"no linear block with na={data.orders.na}, nk={data.orders.nk}, nb={data.orders.nb} and unit static gain "
        f"reproduces the inner-signal bounds; the equations at samples {list(samples)} conflict and would need an "
        f"extra error of {best_tau:.3g} rad. Check: the noise bound is too small, the orders or the delay nk are "
        "wrong, the backlash bounds do not hold for the dynamic experiment (different plant state, drift), or the "
        "data are not from the assumed structure."
    )
    return EmptyLinearSetExplanation(samples, best_tau, message)
