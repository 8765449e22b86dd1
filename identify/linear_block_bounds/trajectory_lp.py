"""The exact problem at fixed a with the inner signal eliminated (:class:`_TrajectoryProblem`): an LP of a handful of
columns however long the record.

With a fixed, the equations x_t = Σ_j b_j u_{t-j} - Σ_i a_i x_{t-i} (eq. (7) of Cerone et al. 2009) make the inner
signal an affine function of b and of the values that start each chain of equations (the first na samples, and
every sample after a gap where no equation holds): x = M(a) [b; s]. The exact problem at that a is then the LP in
(b, s, and the shared backlash [ρ_l, c_l, ρ_r, c_r]) whose rows keep every x_t within its interval (x_t^c ± Δx_t,
and ρ y_t ± c ± ζ^max_t for an inverted sample) and b on unit gain (eq. (8)): p + 4 + na columns and about N + K
rows, where the LP with δx as columns (:class:`~.inner_values._ExactProblemAtFixedA`) has N + K more columns and the
equations as rows. For a stable A (assumption (i) of Section 2) the columns of M are impulse and step responses
that decay or settle, so the rows are well scaled.

Its solutions only propose points: every value reported from them is that of a point the exact check
(:class:`~.point_check._PointCheck`) accepted. The rows are shrunk by ``_ROW_MARGIN`` of their width so that an
optimal vertex keeps the room that check needs.

Over a box of a, the same elimination at the box's centre gives an outer relaxation of the exact set
(:func:`_trajectory_relaxation`): what the centre leaves out is kept linearly in a, or bounded through the impulse
response of 1/A at the centre (:func:`_response_bound`). A box whose centre is not stable is bounded by the interval
relaxation instead."""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from identify.linear_block_bounds.certified_lp import _LP
from identify.linear_block_bounds.point_check import ACCEPTED, _PointCheck
from identify.linear_block_bounds.problem import _Data, _gain_row, _interval_lp

_ROW_MARGIN = 1e-6
"""Share of each row's width given up by the LP (the exact check needs 1e-9 of it, and HiGHS's tolerances are set
below it: :data:`SOLVER_SETTINGS`)."""
_POLYGON_MARGIN = 1e-8
"""Margin of the backlash polygon rows, relative to 1 + |their bound| (their scale), in the LPs that propose points."""
SOLVER_SETTINGS = {"presolve": "off", "primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}
"""HiGHS settings of every trajectory LP (:attr:`~.certified_lp._LP.solver_options`), the relaxation's and the exact
one's alike: few columns, no presolve needed, and feasibility tolerances far below the width of the set. A certified
bound holds for any duals, but loses about what the solver's point may violate: with HiGHS's default 1e-7, the
relaxation's bounds of b lay 4-9 % of their width outside the exact set at N = 100 000, 15 bits (half-widths 1e-7).
In the LPs that propose points, primal feasibility stays well inside the rows' margin."""
_MAX_CHAIN_STARTS = 200
"""Chains of equations at most (na per chain): a record with more gaps is left to the LP with δx as columns."""


def eliminates_inner_signal(num_samples: int, num_equations: int, na: int) -> bool:
    """Whether a record of ``num_samples`` samples, ``num_equations`` of them with an equation of eq. (7) (its
    inner signal and the na before it bounded), is bounded with the inner signal eliminated: every sample without an
    equation starts a chain and is a column of the trajectory LPs, so at most :data:`_MAX_CHAIN_STARTS` chains
    (na samples each)."""
    return num_samples - num_equations <= _MAX_CHAIN_STARTS * max(na, 1)


@numba.njit(cache=True)
def _responses(a: NDArray[np.float64], u: NDArray[np.float64], nk: int, nb: int, equation: NDArray[np.bool_],
               start_column: NDArray[np.int64], num_starts: int) -> NDArray[np.float64]:
    """M(a): x_t as a linear function of [b_nk..b_nb, s_1..s_S] (s: the free value of each sample where no
    equation holds)."""
    n, na, num_b = u.size, a.size, nb - nk + 1
    M = np.zeros((n, num_b + num_starts))
    for t in range(n):
        if not equation[t]:
            M[t, num_b + start_column[t]] = 1.0
            continue
        for j in range(num_b):
            M[t, j] = u[t - nk - j]
        for i in range(1, na + 1):
            for c in range(M.shape[1]):
                M[t, c] -= a[i - 1] * M[t - i, c]
    return M


@numba.njit(cache=True)
def _a_sensitivities(a: NDArray[np.float64], x: NDArray[np.float64],
                     equation: NDArray[np.bool_]) -> NDArray[np.float64]:
    """∂x_t/∂a_i at the trajectory x (b and the chain starts held): D_{t,i} = -x_{t-i} - Σ_j a_j D_{t-j,i}."""
    n, na = x.size, a.size
    D = np.zeros((n, na))
    for t in range(n):
        if not equation[t]:
            continue
        for i in range(1, na + 1):
            value = -x[t - i]
            for j in range(1, na + 1):
                value -= a[j - 1] * D[t - j, i - 1]
            D[t, i - 1] = value
    return D


class _TrajectoryProblem:
    """The exact LP at fixed a in (θ, backlash, chain starts) (see the module), with the same use as
    :class:`~.inner_values._ExactProblemAtFixedA`: :meth:`at`, :meth:`linearized`, :meth:`verified`."""

    def __init__(self, data: _Data, theta_low: NDArray[np.float64], theta_high: NDArray[np.float64],
                 check: _PointCheck | None = None) -> None:
        self._data = data
        self._check = check
        N = data.u.size
        self._equation = np.zeros(N, dtype=bool)
        self._equation[data.times] = True
        starts = np.flatnonzero(~self._equation)
        self._start_column = np.full(N, -1, dtype=np.int64)
        self._start_column[starts] = np.arange(starts.size)
        self._num_starts = int(starts.size)
        self._theta_low, self._theta_high = theta_low, theta_high
        self._low, self._high = data.xc - data.dx, data.xc + data.dx

    @staticmethod
    def suits(data: _Data) -> bool:
        """Whether the record's chains of equations are few enough (:func:`eliminates_inner_signal`)."""
        return eliminates_inner_signal(data.u.size, data.times.size, data.orders.na)

    @property
    def _p(self) -> int:
        return self._data.orders.num_parameters

    def _columns(self) -> int:
        return self._p + (0 if self._data.shared is None else 4) + self._num_starts

    def _lp(self, trajectory: NDArray[np.float64], a_block: NDArray[np.float64] | None, row_shift: NDArray[np.float64],
            a_low: NDArray[np.float64], a_high: NDArray[np.float64],
            widening: NDArray[np.float64] | None = None) -> _LP:
        """Rows lo_t <= [a_block | M_b | 0 | M_s] z - row_shift_t <= hi_t over the columns (θ, backlash, s), with
        every interval shrunk by ``_ROW_MARGIN`` of its width, or, given ``widening``, widened by it on both sides
        (the x_t^c ± Δx_t rows and the backlash rows alike)."""
        data = self._data
        orders = data.orders
        na, p, N = orders.na, self._p, data.u.size
        num_b = orders.nb - orders.nk + 1
        width = self._columns()
        quad = 0 if data.shared is None else 4
        dense = np.zeros((N, width))
        if a_block is not None:
            dense[:, :na] = a_block
        dense[:, na: p] = trajectory[:, :num_b]
        dense[:, p + quad:] = trajectory[:, num_b:]
        rows = sp.csr_matrix(dense)
        if widening is None:
            margin = _ROW_MARGIN * (self._high - self._low)
            row_low, row_high = self._low + margin, self._high - margin
        else:
            row_low, row_high = self._low - widening, self._high + widening
        range_low, range_high = row_low + row_shift, row_high + row_shift
        lower = np.concatenate([self._theta_low, np.full(self._num_starts, -np.inf)])
        upper = np.concatenate([self._theta_high, np.full(self._num_starts, np.inf)])
        lower[:na], upper[:na] = a_low, a_high
        start_samples = np.flatnonzero(~self._equation)
        lower[p:], upper[p:] = row_low[start_samples], row_high[start_samples]
        A_ub, b_ub = sp.csr_matrix((0, width)), np.zeros(0)
        shared = data.shared
        if shared is not None:
            # inside the polygons of D_γ and their box by a margin too (the exact check takes them as they are)
            box_margin = 0.0 if widening is not None else _ROW_MARGIN * (shared.upper - shared.lower)
            lower = np.concatenate([lower[:p], shared.lower + box_margin, lower[p:]])
            upper = np.concatenate([upper[:p], shared.upper - box_margin, upper[p:]])
            # x_t - y_t ρ - (±c) within ±ζ^max_t at the inverted samples
            K = shared.sample_indices.size
            backlash_entries = sp.csr_matrix(
                (np.concatenate([-shared.output_rad, np.where(shared.rising, -1.0, 1.0)]),
                 (np.tile(np.arange(K), 2), np.concatenate([np.where(shared.rising, p + 2, p + 0),
                                                            np.where(shared.rising, p + 3, p + 1)]))),
                shape=(K, width))
            rows = sp.vstack([rows, rows[shared.sample_indices] + backlash_entries]).tocsr()
            shift = row_shift[shared.sample_indices]
            zeta = (shared.zeta_bound_rad * (1.0 - _ROW_MARGIN) if widening is None
                    else shared.zeta_bound_rad + widening[shared.sample_indices])
            range_low = np.concatenate([range_low, -zeta + shift])
            range_high = np.concatenate([range_high, zeta + shift])
            A_ub = sp.hstack([sp.csr_matrix((shared.rows.shape[0], p)), sp.csr_matrix(shared.rows),
                              sp.csr_matrix((shared.rows.shape[0], self._num_starts))]).tocsr()
            b_ub = shared.rhs if widening is not None else shared.rhs - _POLYGON_MARGIN * (1.0 + np.abs(shared.rhs))
        gain, gain_rhs = _gain_row(orders, width)
        return _LP(A_ub, b_ub, gain, gain_rhs, lower, upper, rows, range_low, range_high, SOLVER_SETTINGS)

    def at(self, fixed_a: NDArray[np.float64]) -> _LP:
        """The exact LP for this a (a's columns fixed by their bounds)."""
        data = self._data
        trajectory = _responses(np.asarray(fixed_a, dtype=float), data.u, data.orders.nk, data.orders.nb,
                                self._equation, self._start_column, self._num_starts)
        return self._lp(trajectory, None, np.zeros(data.u.size), fixed_a, fixed_a)

    def linearized(self, a0: NDArray[np.float64], point: NDArray[np.float64], a_low: NDArray[np.float64],
                   a_high: NDArray[np.float64]) -> _LP:
        """The trajectory linearised in a at an exact point (a0, b0, s0): x ≈ M(a0)[b; s] + D (a - a0), with a free
        in [a_low, a_high]. Not a relaxation and not exact: it only proposes the next a, which :meth:`at` and
        :meth:`verified` then decide."""
        data = self._data
        orders = data.orders
        p, quad = self._p, 0 if data.shared is None else 4
        trajectory = _responses(np.asarray(a0, dtype=float), data.u, orders.nk, orders.nb, self._equation,
                                self._start_column, self._num_starts)
        coefficients = np.concatenate([point[orders.na: p], point[p + quad:]])
        D = _a_sensitivities(np.asarray(a0, dtype=float), trajectory @ coefficients, self._equation)
        return self._lp(trajectory, D, D @ np.asarray(a0, dtype=float), a_low, a_high)

    def verified(self, lp: _LP, x: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """The solution ``x`` of ``lp`` with its last b set to unit gain exactly, if the exact check accepts its θ
        and backlash; else None."""
        orders = self._data.orders
        na, p = orders.na, self._p
        point = x.copy()
        point[p - 1] = 1.0 + np.sum(point[:na]) - np.sum(point[na: p - 1])
        assert self._check is not None, "verified needs the exact check"
        return point if self._check.status(point) == ACCEPTED else None

    def over_box(self) -> _LP:
        """The trajectory relaxation over the box of a (see :func:`_trajectory_relaxation`)."""
        data = self._data
        na = data.orders.na
        centre = 0.5 * (self._theta_low[:na] + self._theta_high[:na])
        radius = np.maximum(0.5 * (self._theta_high[:na] - self._theta_low[:na]), 0.0)
        trajectory = _responses(centre, data.u, data.orders.nk, data.orders.nb, self._equation, self._start_column,
                                self._num_starts)
        sensitivity = _a_sensitivities(centre, data.xc, self._equation)
        widening = _response_bound(centre, radius, data.dx)
        if not np.all(np.isfinite(widening)):
            widening = np.full(data.u.size, 1e300)  # A(a^c) far from stable: the relaxation bounds nothing
        return self._lp(trajectory, sensitivity, sensitivity @ centre, self._theta_low[:na], self._theta_high[:na],
                        widening)



_TAIL_SHARE = 1e-6
"""The impulse response of 1/A(a^c) is summed term by term until its remaining l1 mass is this share of the whole;
the rest enters :func:`_response_bound` as its sum times the largest G."""


@numba.njit(cache=True)
def _impulse_response(a: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    """h_k of 1/A(q^-1) for k = 0..n-1."""
    h = np.zeros(n)
    h[0] = 1.0
    for k in range(1, n):
        value = 0.0
        for i in range(1, min(a.size, k) + 1):
            value -= a[i - 1] * h[k - i]
        h[k] = value
    return h


@numba.njit(cache=True)
def _truncated_convolution(h: NDArray[np.float64], g: NDArray[np.float64], length: int) -> NDArray[np.float64]:
    """Σ_{k < length} h_k g_{t-k} for every t."""
    out = np.zeros(g.size)
    for t in range(g.size):
        total = 0.0
        for k in range(min(length, t + 1)):
            total += h[k] * g[t - k]
        out[t] = total
    return out


def _response_bound(centre: NDArray[np.float64], radius: NDArray[np.float64],
                    half_width: NDArray[np.float64]) -> NDArray[np.float64]:
    """E_t = Σ_k |h_k| G_{t-k}, G_t = Σ_i r_i Δx_{t-i}, with h the impulse response of 1/A(a^c): the bound on
    the part of x - x^c that :func:`_trajectory_relaxation` does not keep (its d² term).

    The sum runs term by term while the l1 mass of h left is above ``_TAIL_SHARE`` of the whole, the rest is bounded
    by that mass times max G; the factor 1 + 1e-9 covers the rounding of these sums of non-negative terms and of h
    itself (for a stable A(a^c), whose h decays). Infinite where h does not stay finite."""
    n = half_width.size
    h = np.abs(_impulse_response(np.asarray(centre, dtype=float), n))
    G = np.zeros(n)
    for i in range(1, radius.size + 1):
        G[i:] += radius[i - 1] * half_width[:-i]
    total = float(np.sum(h))
    if not np.isfinite(total):
        return np.full(n, np.inf)
    left = total - np.cumsum(h)
    length = min(int(np.searchsorted(-left, -_TAIL_SHARE * total)) + 1, n)
    tail = float(np.sum(h[length:]))
    return (_truncated_convolution(h, G, length) + tail * float(np.max(G, initial=0.0))) * (1.0 + 1e-9)


def _trajectory_relaxation(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64]) -> _LP:
    """A relaxation of the exact set over the box [low, high] with the inner signal eliminated.

    Let x solve the equations at a (within r of a^c, the centre of the box of a) with b and chain starts s, and
    x^c = M(a^c)[b; s] solve them at a^c. Their difference d = x - x^c solves d_t + Σ_i a^c_i d_{t-i} =
    -Σ_i (a_i - a^c_i) x_{t-i} from zero at each chain's start. With x_s = x_s^c(data) + δ_s, |δ_s| <= Δx_s, d
    splits into Σ_i (a_i - a^c_i) φ_{t,i}, where φ_i solves the same recursion forced by -x^c(data)_{t-i}
    (:func:`_a_sensitivities` at the data's centres: exact and linear in a), and d² forced by -Σ_i (a_i - a^c_i)
    δ_{t-i}, with |d²_t| <= E_t (:func:`_response_bound`; a chain that starts later only drops terms). So every point
    of the set with a in the box satisfies

        x_t^min - E_t <= M(a^c)[b; s]_t + Σ_i (a_i - a^c_i) φ_{t,i} <= x_t^max + E_t,

    and its backlash rows within ζ^max_t + E_t: an LP in (θ, backlash, chain starts), all columns bounded, so the
    certified bounds of :func:`~.certified_lp._bounds_over` hold. E shrinks with the radius of the box of a (it is
    about Σ|h| r Δx), so over a narrow cell this relaxation comes close to the exact set: the cells of
    :func:`~.final_tightening._partitioned_bounds`.

    If A(a^c) is not stable (a root of modulus 1 - 1e-9 or more), its responses do not decay and the widening would
    make the rows useless or badly scaled: the box is then bounded by the interval relaxation
    (:func:`~.problem._interval_lp`) instead, valid over the same box."""
    na = data.orders.na
    centre = 0.5 * (low[:na] + high[:na])
    if na and np.max(np.abs(np.roots(np.concatenate([[1.0], centre])))) >= 1.0 - 1e-9:
        return _interval_lp(data, low, high)
    return _TrajectoryProblem(data, low, high).over_box()
