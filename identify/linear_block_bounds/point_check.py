"""An exact check of one candidate point of the linear block's feasible set in O(N) (:class:`_PointCheck`).

With θ and the shared backlash (ρ_l, c_l, ρ_r, c_r) fixed, what is left of the coupled problem is whether some
inner signal x_s within its interval (x_s^c ± Δx_s, and for an inverted sample also ρ y_s ± c ± ζ^max_s, the rows
of :class:`~.problem.SharedBacklashConstraints`) satisfies every equation

    x_t + Σ_i a_i x_{t-i} = Σ_j b_j u_{t-j} =: v_t                                   (eq. (7) of Cerone et al. 2009)

That is linear and banded in time: the set of the last na values (x_{t-na+1}..x_t) that some history satisfies is
an interval (na = 1) or a convex polygon (na = 2), carried forward sample by sample by the affine map of the
equation and cut by the next sample's interval. A witness sequence is then read backwards from the last set.

Guarantee. The forward sets are made with every interval shrunk by ``_MARGIN`` of its width; the witness x is
clamped into the shrunk intervals, so it keeps at least that margin to the true ones; its equations hold up to the
rounding residuals r_t. The correction e with e_t + Σ_i a_i e_{t-i} = r_t (over the equation times, e = 0
elsewhere) makes x - e satisfy every equation exactly, and the point is accepted only if |e_t| is at most half of
x_t's margin at every sample: then x - e is an exact solution inside every interval (the rounding left in
computing e is about 1e-16 of e, far below the other half). A point the check accepts is therefore a point of the
exact feasible set; a point whose slack is under ``_MARGIN`` of an interval's width may be refused (conservative).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from identify.linear_block_bounds.problem import _Data

_MARGIN = 1e-9
"""Share of each sample's interval width kept free by the forward sets (the room for the exact correction)."""
_MAX_VERTICES = 16
"""Vertices of a forward polygon at most (na = 2); a point whose polygon needs more is not decided here."""

ACCEPTED, REFUSED, UNDECIDED = 0, 1, 2


@numba.njit(cache=True)
def _slice_of_polygon(vertices: NDArray[np.float64], count: int, second: float) -> tuple[float, float]:
    """The interval of the first coordinate over the polygon's points whose second coordinate is ``second``
    (nearest level of the polygon if ``second`` is outside it by rounding)."""
    low_q, high_q = vertices[0, 1], vertices[0, 1]
    for k in range(1, count):
        low_q = min(low_q, vertices[k, 1])
        high_q = max(high_q, vertices[k, 1])
    q = min(max(second, low_q), high_q)
    first_low, first_high = math.inf, -math.inf
    for k in range(count):
        p0, q0 = vertices[k, 0], vertices[k, 1]
        p1, q1 = vertices[(k + 1) % count, 0], vertices[(k + 1) % count, 1]
        if (q0 - q) * (q1 - q) > 0.0:
            continue
        if q0 == q1:
            first_low, first_high = min(first_low, p0, p1), max(first_high, p0, p1)
        else:
            p = p0 + (q - q0) / (q1 - q0) * (p1 - p0)
            first_low, first_high = min(first_low, p), max(first_high, p)
    if first_low > first_high:  # only by rounding at a vertex: take the nearest vertex
        best = 0
        for k in range(1, count):
            if abs(vertices[k, 1] - q) < abs(vertices[best, 1] - q):
                best = k
        first_low = first_high = vertices[best, 0]
    return first_low, first_high


@numba.njit(cache=True)
def _clip(vertices: NDArray[np.float64], count: int, out: NDArray[np.float64], bound: float, sign: float,
          scale: float) -> int:
    """Sutherland-Hodgman: the polygon cut to sign * second <= sign * bound, written to ``out``; returns its
    vertex count (0: empty; -1: more than the room in ``out``). Consecutive vertices closer than 1e-15 of
    ``scale`` are merged."""
    written = 0
    for k in range(count):
        p0, q0 = vertices[k, 0], vertices[k, 1]
        p1, q1 = vertices[(k + 1) % count, 0], vertices[(k + 1) % count, 1]
        inside0 = sign * (q0 - bound) <= 0.0
        inside1 = sign * (q1 - bound) <= 0.0
        for emit in range(2):
            if emit == 0 and inside0:
                px, qx = p0, q0
            elif emit == 1 and inside0 != inside1:
                s = (bound - q0) / (q1 - q0)
                px, qx = p0 + s * (p1 - p0), bound
            else:
                continue
            if written and abs(out[written - 1, 0] - px) + abs(out[written - 1, 1] - qx) <= 1e-15 * scale:
                continue
            if written >= out.shape[0]:
                return -1
            out[written, 0], out[written, 1] = px, qx
            written += 1
    while written > 1 and abs(out[written - 1, 0] - out[0, 0]) + abs(out[written - 1, 1] - out[0, 1]) <= 1e-15 * scale:
        written -= 1
    return written


@numba.njit(cache=True)
def _second_order_witness(a1: float, a2: float, v: NDArray[np.float64], equation: NDArray[np.bool_],
                          low: NDArray[np.float64], high: NDArray[np.float64], scale: float
                          ) -> tuple[int, NDArray[np.float64]]:
    """na = 2: the forward polygons of (x_{t-1}, x_t) within [low, high], then a witness read backwards.
    Returns (ACCEPTED-or-REFUSED-or-UNDECIDED status, witness x)."""
    n = v.size
    x = np.zeros(n)
    polygons = np.empty((n, _MAX_VERTICES, 2))
    counts = np.zeros(n, dtype=np.int64)
    work = np.empty((_MAX_VERTICES, 2))
    middle = np.empty((_MAX_VERTICES, 2))
    polygons[1, 0, 0], polygons[1, 0, 1] = low[0], low[1]
    polygons[1, 1, 0], polygons[1, 1, 1] = high[0], low[1]
    polygons[1, 2, 0], polygons[1, 2, 1] = high[0], high[1]
    polygons[1, 3, 0], polygons[1, 3, 1] = low[0], high[1]
    counts[1] = 4
    for t in range(2, n):
        previous, count = polygons[t - 1], counts[t - 1]
        if equation[t]:
            for k in range(count):
                work[k, 0] = previous[k, 1]
                work[k, 1] = v[t] - a1 * previous[k, 1] - a2 * previous[k, 0]
        else:
            first_low, first_high = previous[0, 1], previous[0, 1]
            for k in range(1, count):
                first_low, first_high = min(first_low, previous[k, 1]), max(first_high, previous[k, 1])
            work[0, 0], work[0, 1] = first_low, -1e300
            work[1, 0], work[1, 1] = first_high, -1e300
            work[2, 0], work[2, 1] = first_high, 1e300
            work[3, 0], work[3, 1] = first_low, 1e300
            count = 4
        count = _clip(work, count, middle, high[t], 1.0, scale)
        if count > 0:
            count = _clip(middle, count, polygons[t], low[t], -1.0, scale)
        if count == 0:
            return REFUSED, x
        if count < 0:
            return UNDECIDED, x
        counts[t] = count
    last, count = polygons[n - 1], counts[n - 1]
    x[n - 2], x[n - 1] = 0.0, 0.0
    for k in range(count):
        x[n - 2] += last[k, 0] / count
        x[n - 1] += last[k, 1] / count
    for t in range(n - 1, 1, -1):
        first_low, first_high = _slice_of_polygon(polygons[t - 1], counts[t - 1], x[t - 1])
        if equation[t] and a2 != 0.0:
            wanted = (v[t] - x[t] - a1 * x[t - 1]) / a2
        else:
            wanted = 0.5 * (first_low + first_high)
        x[t - 2] = min(max(wanted, first_low), first_high)
    return ACCEPTED, x


@numba.njit(cache=True)
def _first_order_witness(a1: float, v: NDArray[np.float64], equation: NDArray[np.bool_], low: NDArray[np.float64],
                         high: NDArray[np.float64]) -> tuple[int, NDArray[np.float64]]:
    """na = 1: the forward intervals of x_t within [low, high], then a witness read backwards."""
    n = v.size
    x = np.zeros(n)
    lows, highs = np.empty(n), np.empty(n)
    lows[0], highs[0] = low[0], high[0]
    for t in range(1, n):
        if equation[t]:
            ends0, ends1 = v[t] - a1 * lows[t - 1], v[t] - a1 * highs[t - 1]
            lows[t], highs[t] = max(min(ends0, ends1), low[t]), min(max(ends0, ends1), high[t])
        else:
            lows[t], highs[t] = low[t], high[t]
        if lows[t] > highs[t]:
            return REFUSED, x
    x[n - 1] = 0.5 * (lows[n - 1] + highs[n - 1])
    for t in range(n - 1, 0, -1):
        wanted = (v[t] - x[t]) / a1 if (equation[t] and a1 != 0.0) else 0.5 * (lows[t - 1] + highs[t - 1])
        x[t - 1] = min(max(wanted, lows[t - 1]), highs[t - 1])
    return ACCEPTED, x


@numba.njit(cache=True)
def _exact_correction_fits(a: NDArray[np.float64], v: NDArray[np.float64], equation: NDArray[np.bool_],
                           x: NDArray[np.float64], room: NDArray[np.float64]) -> bool:
    """Whether the correction e (e_t + Σ a_i e_{t-i} = r_t, the residual of x at each equation time, else 0)
    stays within half of ``room`` at every sample (see the module's guarantee)."""
    na = a.size
    e = np.zeros(x.size)
    for t in range(x.size):
        if not equation[t]:
            continue
        residual = x[t] - v[t]
        lagged = 0.0
        for i in range(1, na + 1):
            residual += a[i - 1] * x[t - i]
            lagged += a[i - 1] * e[t - i]
        e[t] = residual - lagged
        if not abs(e[t]) <= 0.5 * room[t]:
            return False
    return True


class _PointCheck:
    """The exact check of candidate points (θ and, with a shared backlash, [ρ_l, c_l, ρ_r, c_r]) on one record:
    :meth:`status` says ACCEPTED only for a point of the exact feasible set (see the module's guarantee), in
    O(N) for na <= 2 (UNDECIDED for higher orders: the caller solves the exact LP instead)."""

    def __init__(self, data: _Data) -> None:
        self._data = data
        N = data.u.size
        self._equation = np.zeros(N, dtype=bool)
        self._equation[data.times] = True
        self._low, self._high = data.xc - data.dx, data.xc + data.dx
        self._scale = max(1.0, float(np.max(np.abs(data.xc))))

    @property
    def decides(self) -> bool:
        """Whether :meth:`status` can decide points of this model order (na <= 2)."""
        return self._data.orders.na <= 2

    def status(self, point: NDArray[np.float64]) -> int:
        """ACCEPTED (a point of the exact set), REFUSED or UNDECIDED for ``point`` = θ (p values), followed by
        [ρ_l, c_l, ρ_r, c_r] when the record has a shared backlash."""
        data = self._data
        orders = data.orders
        na, p = orders.na, orders.num_parameters
        if na > 2:
            return UNDECIDED
        theta = np.asarray(point[:p], dtype=float)
        gain = float(np.sum(theta[na:]) - np.sum(theta[:na]))
        if not np.all(np.isfinite(theta)) or gain != 1.0 and abs(gain - 1.0) > 1e-12:
            return REFUSED  # eq. (8), up to the rounding of the sum
        low, high = self._low, self._high
        shared = data.shared
        if shared is not None:
            backlash = np.asarray(point[p: p + 4], dtype=float)
            if not (np.all(backlash >= shared.lower) and np.all(backlash <= shared.upper)
                    and np.all(shared.rows @ backlash <= shared.rhs)):
                return REFUSED
            rho = np.where(shared.rising, backlash[2], backlash[0])
            offset = np.where(shared.rising, backlash[3], -backlash[1])
            centre = shared.output_rad * rho + offset
            low, high = low.copy(), high.copy()
            np.maximum.at(low, shared.sample_indices, centre - shared.zeta_bound_rad)
            np.minimum.at(high, shared.sample_indices, centre + shared.zeta_bound_rad)
        if np.any(low > high):
            return REFUSED
        room = _MARGIN * (high - low)
        shrunk_low, shrunk_high = low + room, high - room
        v = np.zeros(data.u.size)
        for j in range(orders.nk, orders.nb + 1):
            v[j:] += theta[na + j - orders.nk] * data.u[: data.u.size - j]
        if na == 0:
            x = np.clip(v, shrunk_low, shrunk_high)
            found = ACCEPTED
        elif na == 1:
            found, x = _first_order_witness(float(theta[0]), v, self._equation, shrunk_low, shrunk_high)
        else:
            found, x = _second_order_witness(float(theta[0]), float(theta[1]), v, self._equation, shrunk_low,
                                             shrunk_high, self._scale)
        if found != ACCEPTED:
            return found
        x = np.clip(x, shrunk_low, shrunk_high)
        return ACCEPTED if _exact_correction_fits(theta[:na].copy(), v, self._equation, x, room) else REFUSED
