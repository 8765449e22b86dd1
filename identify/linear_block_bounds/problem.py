"""The problem data (:class:`_Data`, from :func:`_prepare`) and the LPs built from it: the paper method's orthant
LPs (:func:`_paper_bounds`), the coupled method's McCormick (:func:`_coupled_lp`) and interval
(:func:`_interval_lp`) relaxations, with the shared backlash (:class:`SharedBacklashConstraints`), and the rounds
that tighten the box of a (:func:`_tighten`)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from identify.linear_block_bounds.certified_lp import _LP, _bounds_over, _Counter, _PartStart, _proven_infeasible
from identify.validation import InvalidInputError, as_signal, same_length


_B_BOX = 1e6
"""A-priori box |b_j| <= 1e6; a bound that reaches it is reported as unbounded (infinite)."""


@dataclass(frozen=True)
class LinearModelOrders:
    """A(q^-1) = 1 + a_1 q^-1 + ... + a_na q^-na, B(q^-1) = b_nk q^-nk + ... + b_nb q^-nb."""

    na: int
    nk: int
    nb: int

    def __post_init__(self) -> None:
        for name in ("na", "nk", "nb"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise InvalidInputError(f"{name}: expected an integer >= 0, got {value!r}")
        if self.nb < self.nk:
            raise InvalidInputError(f"nb: expected nb >= nk (B has b_nk..b_nb), got nk={self.nk}, nb={self.nb}")

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """``a1..a<na>``, ``b<nk>..b<nb>`` (the order of θ)."""
        return tuple(f"a{i}" for i in range(1, self.na + 1)) + tuple(f"b{j}" for j in range(self.nk, self.nb + 1))

    @property
    def num_parameters(self) -> int:
        return self.na + self.nb - self.nk + 1

    @property
    def first_equation(self) -> int:
        """n = max(na, nb): the first t whose regressors are all measured."""
        return max(self.na, self.nb)


@dataclass(frozen=True)
class SharedBacklashConstraints:
    """The backlash parameters shared by every inverted sample, for the coupled method.

    For an inverted sample, x_t = ρ_r (y_t - η_t) + c_r (output rose) or x_t = ρ_l (y_t - η_t) - c_l (output
    fell), with ρ = 1/m the same for all samples; with ζ_t = ρ η_t, |ζ_t| <= ρ^max Δη, this is linear in
    (ρ_l, c_l, ρ_r, c_r, ζ_t), and D_γ is a polygon in (ρ, c) too
    (:meth:`identify.feasible_parameter_set.BacklashSidePolygon.inverse_slope_rows`). Built by
    :func:`identify.inner_signal_bounds.shared_backlash_constraints`.

    Attributes
    ----------
    sample_indices
        The inverted samples t.
    rising
        True where the output rose (right line), False where it fell (left line).
    output_rad
        y_t at those samples.
    zeta_bound_rad
        ρ^max Δη per sample.
    rows, rhs
        rows @ [ρ_l, c_l, ρ_r, c_r] <= rhs: both polygons.
    lower, upper
        Box of [ρ_l, c_l, ρ_r, c_r] (from the polygons' vertices).
    """

    sample_indices: NDArray[np.int64]
    rising: NDArray[np.bool_]
    output_rad: NDArray[np.float64]
    zeta_bound_rad: NDArray[np.float64]
    rows: NDArray[np.float64]
    rhs: NDArray[np.float64]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]


# ----------------------------------------------------------------------------------------------------------
# problem data
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Data:
    orders: LinearModelOrders
    u: NDArray[np.float64]
    xc: NDArray[np.float64]
    dx: NDArray[np.float64]
    times: NDArray[np.int64]  # equation times t = n..N-1
    regressors: NDArray[np.float64]  # psi_t: x_t^c = psi_t theta - (delta terms)
    shared: SharedBacklashConstraints | None = None

    @property
    def a_box(self) -> NDArray[np.float64]:
        return np.array([math.comb(self.orders.na, i) for i in range(1, self.orders.na + 1)], dtype=float)


def _prepare(input_rad: ArrayLike, inner_lower_rad: ArrayLike, inner_upper_rad: ArrayLike,
             orders: LinearModelOrders, shared: SharedBacklashConstraints | None = None) -> _Data:
    u = as_signal("input_rad", input_rad)
    lower = as_signal("inner_lower_rad", inner_lower_rad, missing_allowed=True)
    upper = as_signal("inner_upper_rad", inner_upper_rad, missing_allowed=True)
    same_length(input_rad=u, inner_lower_rad=lower, inner_upper_rad=upper)
    bad = np.flatnonzero(lower > upper)
    if bad.size:
        raise InvalidInputError(f"inner_lower_rad: sample {bad[0]} is above inner_upper_rad ({lower[bad[0]]} > {upper[bad[0]]})")
    n = orders.first_equation
    p = orders.num_parameters
    if u.size <= n:
        raise InvalidInputError(f"input_rad: na={orders.na}, nk={orders.nk}, nb={orders.nb} need {n} past samples "
                                f"before the first equation, but the record has {u.size} samples; the orders are "
                                f"too high for the data (at least {n + 2 * p} samples are needed): use lower orders "
                                "or a longer record")
    known = np.isfinite(lower) & np.isfinite(upper)
    times = np.arange(n, u.size)
    complete = np.all([known[times - i] for i in range(orders.na + 1)], axis=0)
    times = times[complete]
    missing = int(np.count_nonzero(~known))
    if times.size < 2 * p:
        left = (f"; {missing} samples without an inner-signal bound (output not measured) set aside "
                f"{u.size - n - times.size} of the {u.size - n} equations" if missing else "")
        raise InvalidInputError(f"input_rad: {u.size} samples give {times.size} equations for the {p} parameters of "
                                f"na={orders.na}, nk={orders.nk}, nb={orders.nb}{left}; the orders are too high for "
                                f"the data (at least {2 * p} equations are needed): use lower orders or a longer "
                                "record" + (" with fewer lost samples" if missing else ""))
    if np.ptp(u) == 0.0:
        raise InvalidInputError(f"input_rad: the input is constant ({u[0]:g} rad in all {u.size} samples), so it "
                                "excites nothing and the linear block cannot be bounded; use a persistently exciting "
                                "dynamic experiment such as the PRBS (configs/experiments/prbs.toml)")
    # a sample without bounds is in no equation; 0 +- 0 keeps its (unused) variable finite
    xc, dx = np.where(known, 0.5 * (lower + upper), 0.0), np.where(known, 0.5 * (upper - lower), 0.0)
    columns = [-xc[times - i] for i in range(1, orders.na + 1)] + [u[times - j] for j in range(orders.nk, orders.nb + 1)]
    if shared is not None:
        if not isinstance(shared, SharedBacklashConstraints):
            raise InvalidInputError(f"shared_backlash: expected SharedBacklashConstraints, got {type(shared).__name__}")
        if shared.sample_indices.size and (shared.sample_indices.min() < 0 or shared.sample_indices.max() >= u.size):
            raise InvalidInputError(f"shared_backlash: sample indices outside 0..{u.size - 1}")
    return _Data(orders, u, xc, dx, times, np.column_stack(columns), shared)


def _gain_row(orders: LinearModelOrders, width: int) -> tuple[sp.csr_matrix, NDArray[np.float64]]:
    """Σ b_j - Σ a_i = 1 (eq. (8)) as one equality row over the first p variables."""
    row = np.zeros(width)
    row[: orders.na] = -1.0
    row[orders.na: orders.num_parameters] = 1.0
    return sp.csr_matrix(row), np.array([1.0])


# ----------------------------------------------------------------------------------------------------------
# the paper's method: errors in variables per equation, one polytope per orthant of a
# ----------------------------------------------------------------------------------------------------------


def _orthant_lp(data: _Data, signs: tuple[int, ...]) -> _LP:
    orders = data.orders
    na, p = orders.na, orders.num_parameters
    psi = data.regressors
    # d_t theta = Σ_i s_i a_i Δx_{t-i} = Σ |a_i| Δx_{t-i} in this orthant
    d = np.zeros_like(psi)
    for i in range(1, na + 1):
        d[:, i - 1] = signs[i - 1] * data.dx[data.times - i]
    x_t, dx_t = data.xc[data.times], data.dx[data.times]
    # |x_t - psi theta| <= dx_t + d theta  <=>  psi theta - d theta <= x_t + dx_t ; -psi theta - d theta <= -x_t + dx_t
    A_ub = np.vstack([psi - d, -psi - d])
    b_ub = np.concatenate([x_t + dx_t, -x_t + dx_t])
    A_eq, b_eq = _gain_row(orders, p)
    lower = np.full(p, -_B_BOX)
    upper = np.full(p, _B_BOX)
    box = data.a_box
    for i in range(na):
        lower[i], upper[i] = (0.0, box[i]) if signs[i] > 0 else (-box[i], 0.0)
    return _LP(sp.csr_matrix(A_ub), b_ub, A_eq, b_eq, lower, upper)


_PAPER_ROWS = 20000
"""Inequality rows of an orthant's LP solved whole; longer records bound it on a subset of the rows that grows by
the rows its solutions violate (:func:`_row_generated_bounds`)."""
_PAPER_ROWS_ADDED = 200
"""Most violated rows added per objective and turn of the row generation."""
_PAPER_TURNS = 30
"""Turns of the row generation at most (the bounds after any turn are valid, only possibly looser)."""


def _row_generated_bounds(lp: _LP, p: int, counter: _Counter
                          ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.float64] | None], _LP]:
    """:func:`~.certified_lp._bounds_over` of an LP with many more inequality rows than variables (the paper method's
    orthant LPs: two rows per equation, p columns), solved on a subset of its rows (row generation, the dual of
    column generation): every ``stride``-th row first, then, turn by turn, the rows most violated by the
    subset's minimisers, until they violate none (beyond 1e-9 of the row's scale) or ``_PAPER_TURNS``.

    Fewer rows give a relaxation, so the certified bound of the subset LP is a valid bound of the whole one
    at every turn; once the minimisers violate no row they are optimal for the whole LP too. Returns the
    bounds, points and the subset LP (whose phase 1 then decides emptiness: infeasible rows are infeasible in
    any superset)."""
    rows = lp.A_ub.shape[0]
    if rows <= _PAPER_ROWS:
        low, high, points = _bounds_over(lp, p, counter)
        return low, high, points, lp
    chosen = np.zeros(rows, dtype=bool)
    chosen[:: -(-rows // _PAPER_ROWS)] = True
    scale = 1e-9 * (1.0 + np.abs(lp.b_ub))
    for _ in range(_PAPER_TURNS):
        subset = _LP(lp.A_ub[chosen], lp.b_ub[chosen], lp.A_eq, lp.b_eq, lp.lower, lp.upper)
        low, high, points = _bounds_over(subset, p, counter)
        if not np.all(np.isfinite(low)):
            return low, high, points, subset
        added = np.zeros(rows, dtype=bool)
        for x in points:
            if x is None:
                continue
            violation = np.where(chosen, 0.0, lp.A_ub @ x - lp.b_ub - scale)
            worst = np.argsort(violation)[-_PAPER_ROWS_ADDED:]
            added[worst[violation[worst] > 0.0]] = True
        if not added.any():
            break
        chosen |= added
    return low, high, points, subset


def _paper_bounds(data: _Data, counter: _Counter) -> tuple[NDArray[np.float64], NDArray[np.float64], list[tuple[int, ...]]]:
    p = data.orders.num_parameters
    lows, highs = np.full(p, math.inf), np.full(p, -math.inf)
    feasible: list[tuple[int, ...]] = []
    for signs in itertools.product((1, -1), repeat=data.orders.na):
        lp = _orthant_lp(data, signs)
        low, high, _, solved = _row_generated_bounds(lp, p, counter)
        if not np.all(np.isfinite(low)):
            if _proven_infeasible(solved, counter):
                continue
            # Not provably empty (a sliver within the solver tolerance): keep the orthant with its box.
            low, high = lp.lower[:p].copy(), lp.upper[:p].copy()
        feasible.append(tuple(signs))
        lows, highs = np.minimum(lows, low), np.maximum(highs, high)
    return lows, highs, feasible


# ----------------------------------------------------------------------------------------------------------
# the coupled method: shared δx, McCormick envelopes, iterated tightening
# ----------------------------------------------------------------------------------------------------------


def _coupled_lp(data: _Data, theta_low: NDArray[np.float64], theta_high: NDArray[np.float64]) -> _LP:
    """Variables: θ (p), δx_s (N), and for each lag i the products z_{i,s} = a_i δx_s (N each).

    Equations t: -psi_t θ + δx_t + Σ_i z_{i,t-i} = -x_t^c (for a fixed a see
    :class:`~.inner_values._ExactProblemAtFixedA`).
    """
    orders = data.orders
    na, p = orders.na, orders.num_parameters
    N = data.u.size
    m = data.times.size
    width = p + N + na * N
    rows, cols, vals = [], [], []
    eq_index = np.arange(m)
    # -psi θ
    for k in range(p):
        rows.append(eq_index); cols.append(np.full(m, k)); vals.append(-data.regressors[:, k])
    rows.append(eq_index); cols.append(p + data.times); vals.append(np.ones(m))
    for i in range(1, na + 1):
        rows.append(eq_index); cols.append(p + N + (i - 1) * N + data.times - i); vals.append(np.ones(m))
    A_eq = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m, width))
    b_eq = -data.xc[data.times]
    gain, gain_rhs = _gain_row(orders, width)
    lower = np.concatenate([theta_low, -data.dx, np.zeros(na * N)])
    upper = np.concatenate([theta_high, data.dx, np.zeros(na * N)])
    ub_rows, ub_cols, ub_vals, ub_rhs = [], [], [], []
    s_index = np.arange(N)
    D = data.dx
    base = 0
    for i in range(na):
        z_cols = p + N + i * N + s_index
        d_cols = p + s_index
        aL, aU = float(theta_low[i]), float(theta_high[i])
        magnitude = max(abs(aL), abs(aU))
        lower[z_cols], upper[z_cols] = -magnitude * D, magnitude * D
        # four McCormick inequalities per s, in the variables (a_i, δx_s, z_{i,s}):
        #   aL δ - D a - z <= -aL D ;  aU δ + D a - z <= aU D ;  -aU δ + D a + z <= aU D ;  -aL δ - D a + z <= -aL D
        for coef_d, coef_a, coef_z, rhs in ((aL, -1.0, -1.0, -aL), (aU, 1.0, -1.0, aU), (-aU, 1.0, 1.0, aU), (-aL, -1.0, 1.0, -aL)):
            r = base + s_index
            ub_rows.extend([r, r, r]); ub_cols.extend([d_cols, np.full(N, i), z_cols])
            ub_vals.extend([np.full(N, coef_d), coef_a * D, np.full(N, coef_z)])
            ub_rhs.append(rhs * D)
            base += N
    if ub_rhs:
        A_ub = sp.csr_matrix((np.concatenate(ub_vals), (np.concatenate(ub_rows), np.concatenate(ub_cols))),
                             shape=(sum(len(x) for x in ub_rhs), width))
        b_ub = np.concatenate(ub_rhs)
    else:
        A_ub, b_ub = sp.csr_matrix((0, width)), np.zeros(0)
    A_eq_all = sp.vstack([A_eq, gain]).tocsr()
    b_eq_all = np.concatenate([b_eq, gain_rhs])
    lp = _LP(A_ub, b_ub, A_eq_all, b_eq_all, lower, upper)
    return lp if data.shared is None else _with_shared_backlash(lp, data, p)


def _interval_lp(data: _Data, theta_low: NDArray[np.float64], theta_high: NDArray[np.float64]) -> _LP:
    """A smaller outer relaxation for a narrow box of a: a_i δx_s = a_i^c δx_s + e_{i,s} with
    |e_{i,s}| <= r_i Δx_s (a^c, r: centre and radius of the box of a_i), and the e eliminated, so

        |-psi_t θ + δx_t + Σ_i a_i^c δx_{t-i} + x_t^c| <= Σ_i r_i Δx_{t-i}.

    Variables θ (p) and δx (N) only, one ranged row per equation. Every point of the exact set with a in the box
    satisfies it (|a_i - a_i^c| |δx_s| <= r_i Δx_s), so its LP bounds are valid. It contains the McCormick
    relaxation (the set |z - a^c δx| <= r Δx is convex and holds on the graph of a δx, hence on its convex
    hull) and is looser only for a near a corner of its box, by at most r_i Δx_s per product: negligible once
    the box of a is narrow (r_i << |a_i|), while the LP has a third of the columns and a quarter of the rows.
    """
    orders = data.orders
    na, p = orders.na, orders.num_parameters
    N, m = data.u.size, data.times.size
    width = p + N
    centre = 0.5 * (theta_low[:na] + theta_high[:na])
    radius = np.maximum(0.5 * (theta_high[:na] - theta_low[:na]), 0.0)
    per_row = p + na + 1
    cols = np.empty((m, per_row), dtype=np.int64)
    vals = np.ones((m, per_row))
    cols[:, :p] = np.arange(p)
    vals[:, :p] = -data.regressors
    slack = np.zeros(m)
    for i in range(1, na + 1):
        cols[:, p + na - i] = p + data.times - i
        vals[:, p + na - i] = centre[i - 1]
        slack += radius[i - 1] * data.dx[data.times - i]
    cols[:, p + na] = p + data.times
    rows = sp.csr_matrix((vals.ravel(), cols.ravel(), np.arange(m + 1) * per_row), shape=(m, width))
    xt = data.xc[data.times]
    gain, gain_rhs = _gain_row(orders, width)
    lp = _LP(sp.csr_matrix((0, width)), np.zeros(0), gain, gain_rhs, np.concatenate([theta_low, -data.dx]),
             np.concatenate([theta_high, data.dx]), rows, -slack - xt, slack - xt)
    return lp if data.shared is None else _with_shared_backlash(lp, data, p)


def _with_shared_backlash(lp: _LP, data: _Data, p: int) -> _LP:
    """Append the columns [ρ_l, c_l, ρ_r, c_r, ζ_1..ζ_K] and the rows that tie the inverted samples to them:
    δx_t - y_t ρ_r - c_r + ζ_t = -x_t^c (rising), δx_t - y_t ρ_l + c_l + ζ_t = -x_t^c (falling)."""
    shared = data.shared
    assert shared is not None
    K = shared.sample_indices.size
    width = lp.lower.size
    new_width = width + 4 + K
    link_rows = np.arange(K)
    rho_col = np.where(shared.rising, width + 2, width + 0)
    c_col = np.where(shared.rising, width + 3, width + 1)
    c_val = np.where(shared.rising, -1.0, 1.0)
    link = sp.csr_matrix((np.concatenate([np.ones(K), -shared.output_rad, c_val, np.ones(K)]),
                          (np.tile(link_rows, 4), np.concatenate([p + shared.sample_indices, rho_col, c_col,
                                                                   width + 4 + link_rows]))), shape=(K, new_width))
    polygon = sp.hstack([sp.csr_matrix((shared.rows.shape[0], width)), sp.csr_matrix(shared.rows),
                         sp.csr_matrix((shared.rows.shape[0], K))]).tocsr()
    A_ub = sp.vstack([sp.hstack([lp.A_ub, sp.csr_matrix((lp.A_ub.shape[0], 4 + K))]), polygon]).tocsr()
    A_eq = sp.vstack([sp.hstack([lp.A_eq, sp.csr_matrix((lp.A_eq.shape[0], 4 + K))]), link]).tocsr()
    A_range, range_lower, range_upper = lp.ranged()
    return _LP(A_ub, np.concatenate([lp.b_ub, shared.rhs]), A_eq,
               np.concatenate([lp.b_eq, -data.xc[shared.sample_indices]]),
               np.concatenate([lp.lower, shared.lower, -shared.zeta_bound_rad]),
               np.concatenate([lp.upper, shared.upper, shared.zeta_bound_rad]),
               sp.hstack([A_range, sp.csr_matrix((A_range.shape[0], 4 + K))]).tocsr(), range_lower, range_upper)


def _tighten(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], counter: _Counter, max_rounds: int,
             relative_improvement: float, full_last_round: bool,
             relaxation: Callable[[_Data, NDArray[np.float64], NDArray[np.float64]], _LP] | None = None,
             full_rounds: bool = False, wanted: NDArray[np.bool_] | None = None, retry: bool = False,
             start: _PartStart | None = None
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], int, list[NDArray[np.float64]], bool]:
    """Rounds of the McCormick relaxation: LPs over a only tighten the box of a (which sets the envelopes)
    until no a-interval shrinks by more than ``relative_improvement`` or ``max_rounds`` relaxations were
    solved; with ``full_last_round`` the last round bounds every parameter, with ``full_rounds`` every round
    does (the bounds of b then tighten each other through the unit-gain row). Returns the box, the rounds,
    the extreme points of the last round and whether the relaxation was proven empty. ``relaxation`` builds
    the LP from (data, low, high); McCormick (:func:`_coupled_lp`) by default. ``wanted`` (2p booleans, see
    :func:`~.certified_lp._bounds_over`) limits every round to those bounds, ``retry`` and ``start`` are passed on to it
    (a start only to the first round: the model of a later round has another box)."""
    relaxation = _coupled_lp if relaxation is None else relaxation
    p, na = data.orders.num_parameters, data.orders.na
    rounds = 0
    converged = na == 0
    while True:
        rounds += 1
        final = converged or rounds >= max_rounds
        lp = relaxation(data, low, high)
        count = p if (full_rounds or (final and full_last_round)) else na
        new_low, new_high, points = _bounds_over(lp, count, counter, None if wanted is None else wanted[: 2 * count],
                                                 retry, start if rounds == 1 else None)
        if not np.all(np.isfinite(new_low)):
            if _proven_infeasible(lp, counter):
                return low, high, rounds, [], True
            if final:
                return low, high, rounds, [], False
            converged = True  # not provably empty: finish with the last round on the current box
            continue
        shrink = np.max((high[:count] - low[:count] - (np.minimum(new_high, high[:count]) - np.maximum(new_low, low[:count])))
                        / np.maximum(high[:count] - low[:count], 1e-300))
        low, high = low.copy(), high.copy()
        low[:count], high[:count] = np.maximum(new_low, low[:count]), np.minimum(new_high, high[:count])
        if final:
            return low, high, rounds, points, False
        converged = shrink < relative_improvement
