"""The exact O(N) check of a candidate point of the linear block's feasible set, the exact LP at fixed a with the
inner signal eliminated, and the trajectory relaxation over a box of a (Cerone et al. 2009, eq. (7)-(8))."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from identify.inner_signal_bounds import shared_backlash_constraints
from identify.linear_block_bounds import LinearModelOrders, bound_linear_block
from identify.linear_block_bounds.certified_lp import _bounds_over, _Counter
from identify.linear_block_bounds.inner_values import _ExactProblemAtFixedA, _inner_values
from identify.linear_block_bounds.point_check import ACCEPTED, REFUSED, _PointCheck
from identify.linear_block_bounds.problem import _interval_lp, _prepare
from identify.linear_block_bounds.trajectory_lp import _trajectory_relaxation, _TrajectoryProblem
from identify.output_backlash_identification import bound_output_backlash_system
from cerone2009_data import GAMMA, THETA, experiment

TRUE_THETA = np.array(list(THETA.values()))
TRUE_BACKLASH = np.array([1 / GAMMA["m_l"], GAMMA["c_l"], 1 / GAMMA["m_r"], GAMMA["c_r"]])


def _record(n_bit: int, seed: int, num_samples: int, lost: slice | None = None):
    """The coupled problem of the paper's example (shared backlash) with, optionally, samples LOST."""
    data = experiment(n_bit, seed, num_samples)
    output = data.output_rad.copy()
    if lost is not None:
        output[lost] = np.nan
    paper = bound_output_backlash_system(data.steady_input_rad, data.steady_output_rad, data.input_rad, output,
                                         data.noise_bound_rad, na=2, nk=1, nb=2, method="paper")
    inner = paper.inner_signal
    shared = shared_backlash_constraints(output, data.noise_bound_rad, paper.backlash, inner)
    return _prepare(data.input_rad, inner.lower_rad, inner.upper_rad, LinearModelOrders(2, 1, 2), shared), data


def _synthetic(a: tuple[float, ...], b: tuple[float, ...], num_samples: int, half_width: float, seed: int):
    """A record without backlash: x from 1/A with unit gain, bounds x^c = x + uniform(±0.6 Δ), Δ = half_width."""
    rng = np.random.default_rng(seed)
    u = rng.choice([-1.0, 1.0], num_samples)
    na = len(a)
    x = np.zeros(num_samples)
    for t in range(num_samples):
        x[t] = sum(b[j - 1] * u[t - j] for j in range(1, len(b) + 1) if t >= j) - sum(
            a[i - 1] * x[t - i] for i in range(1, na + 1) if t >= i)
    centre = x + rng.uniform(-0.6, 0.6, num_samples) * half_width
    orders = LinearModelOrders(na, 1, len(b))
    return _prepare(u, centre - half_width, centre + half_width, orders), np.array([*a, *b])


def _exact_lp_feasible(data, point: np.ndarray, shrink: float) -> bool:
    """The exact LP with θ and the backlash fixed (δx and ζ as columns), with every δx and ζ bound scaled by
    1 - shrink: feasible or not (HiGHS through scipy)."""
    p, N = data.orders.num_parameters, data.u.size
    na = data.orders.na
    lp = _ExactProblemAtFixedA(data, np.full(p, -1e6), np.full(p, 1e6)).at(point[:na])
    lower, upper = lp.lower.copy(), lp.upper.copy()
    lower[:p] = upper[:p] = point[:p]
    lower[p: p + N] *= 1 - shrink
    upper[p: p + N] *= 1 - shrink
    if data.shared is not None:
        lower[p + N: p + N + 4] = upper[p + N: p + N + 4] = point[p: p + 4]
        lower[p + N + 4:] *= 1 - shrink
        upper[p + N + 4:] *= 1 - shrink
    result = linprog(np.zeros(lower.size), A_eq=lp.A_eq, b_eq=lp.b_eq, A_ub=lp.A_ub, b_ub=lp.b_ub,
                     bounds=np.column_stack([lower, upper]), method="highs")
    return result.status == 0


def test_the_true_point_passes_the_check_and_a_point_beyond_the_outer_bounds_fails() -> None:
    data, _ = _record(10, 5, 300)
    check = _PointCheck(data)
    truth = np.concatenate([TRUE_THETA, TRUE_BACKLASH])
    assert check.status(truth) == ACCEPTED  # the true x is within every interval, the true backlash in D_γ
    result = bound_linear_block(data.u, data.xc - data.dx, data.xc + data.dx, na=2, nk=1, nb=2,
                                shared_backlash=data.shared, verify_inner=False)
    for k, name in enumerate(THETA):
        for side, beyond in (("lower", -1.0), ("upper", 1.0)):
            moved = truth.copy()
            interval = result.intervals[name]
            moved[k] = (interval.upper if beyond > 0 else interval.lower) + beyond * 0.1 * (interval.upper - interval.lower)
            # back on unit gain (eq. (8)) through the last b, or b1 when the last b is the one moved
            fix = 3 if k != 3 else 2
            moved[fix] = 0.0
            moved[fix] = 1.0 + moved[0] + moved[1] - (moved[2] + moved[3])
            assert check.status(moved) == REFUSED, (name, side)
    # the truth with the backlash of another gearbox: its inverted samples leave their intervals
    assert check.status(np.concatenate([TRUE_THETA, TRUE_BACKLASH * [1.0, 1.5, 1.0, 1.5]])) == REFUSED
    # off unit gain by more than the rounding of the sum
    assert check.status(np.concatenate([TRUE_THETA + [0, 0, 1e-9, 0], TRUE_BACKLASH])) == REFUSED


def _points_around(data, a_centre: np.ndarray, a_spread: float, rng: np.random.Generator, count: int):
    """Points (θ, backlash) near the feasible set: at a random a, the mean of the exact LP's solutions for a few
    random objectives (feasible when that a is: the set at a fixed a is convex), and that mean with b1 moved by a
    random share of the spread of those solutions (often infeasible)."""
    p, N, na = data.orders.num_parameters, data.u.size, data.orders.na
    exact = _ExactProblemAtFixedA(data, np.full(p, -1e6), np.full(p, 1e6))
    width = 0 if data.shared is None else 4
    for _ in range(count):
        a = a_centre + rng.normal(0.0, a_spread, na)
        lp = exact.at(a)
        solutions = []
        for _ in range(4):
            cost = np.zeros(lp.lower.size)
            cost[na: p] = rng.normal(size=p - na)
            cost[p + N: p + N + width] = rng.normal(size=width)
            result = linprog(cost, A_eq=lp.A_eq, b_eq=lp.b_eq, A_ub=lp.A_ub, b_ub=lp.b_ub,
                             bounds=np.column_stack([lp.lower, lp.upper]), method="highs")
            if result.status == 0:
                solutions.append(np.concatenate([result.x[:p], result.x[p + N: p + N + width]]))
        if not solutions:
            continue
        mean = np.mean(solutions, axis=0)
        spread = np.ptp([x[na] for x in solutions]) + 1e-4 * abs(mean[na])
        for shift in (0.0, rng.uniform(-3.0, 3.0) * spread):
            point = mean.copy()
            point[na] += shift
            point[p - 1] = 1.0 + np.sum(point[:na]) - np.sum(point[na: p - 1])
            yield point


@pytest.mark.parametrize("case", ["shared backlash", "second order", "first order", "lost samples"])
def test_the_check_agrees_with_the_exact_lp_wherever_that_lp_decides_with_room(case: str) -> None:
    # Where the exact LP is still feasible with every interval shrunk by 0.1 %, the check must accept; where it is
    # infeasible with them widened by 0.1 %, it must refuse (in between, either is right).
    rng = np.random.default_rng(7)
    if case in ("shared backlash", "lost samples"):
        data, _ = _record(10, 9, 250, slice(120, 126) if case == "lost samples" else None)
        a_centre, a_spread = TRUE_THETA[:2], 2e-4
    elif case == "second order":
        data, theta = _synthetic((0.5, 0.7), (1.4, 0.8), 250, 0.02, 3)
        a_centre, a_spread = theta[:2], 1e-3
    else:
        data, theta = _synthetic((-0.6,), (0.15, 0.25), 250, 0.02, 4)
        a_centre, a_spread = theta[:1], 2e-3
    check = _PointCheck(data)
    seen = {ACCEPTED: 0, REFUSED: 0}
    for point in _points_around(data, a_centre, a_spread, rng, 16):
        inside, outside = _exact_lp_feasible(data, point, 1e-3), not _exact_lp_feasible(data, point, -1e-3)
        status = check.status(point)
        if inside:
            assert status == ACCEPTED, point
        if outside:
            assert status == REFUSED, point
        seen[status] += 1
    assert seen[ACCEPTED] >= 3 and seen[REFUSED] >= 3, seen  # both kinds of points were met


def test_the_exact_lp_without_the_inner_signal_gives_the_bounds_of_the_lp_with_it() -> None:
    # At a fixed a both LPs describe the same set of (b, backlash): the same extreme b (up to what the row margin
    # of 1e-6 of an interval's width, kept by the trajectory LP for the exact check, moves it: 3e-4 of the width
    # here), and its points pass the check.
    data, _ = _record(12, 13, 300)
    p = data.orders.num_parameters
    box_low, box_high = np.concatenate([[0.49, 0.69], np.full(2, -1e6)]), np.concatenate([[0.51, 0.71], np.full(2, 1e6)])
    check = _PointCheck(data)
    trajectory, columns = _TrajectoryProblem(data, box_low, box_high, check), _ExactProblemAtFixedA(data, box_low, box_high)
    counter = _Counter()
    a = TRUE_THETA[:2]  # the truth's a: feasible
    new_low, new_high, points = _bounds_over(trajectory.at(a), p, counter)
    old_low, old_high, _ = _bounds_over(columns.at(a), p, counter)
    assert np.all(np.isfinite(new_low)) and np.all(np.isfinite(old_low))
    width = old_high - old_low
    assert np.all(np.abs(new_low - old_low) <= 1e-3 * width + 1e-12)
    assert np.all(np.abs(new_high - old_high) <= 1e-3 * width + 1e-12)
    lp = trajectory.at(a)
    for x in points[4:]:  # the extreme points of b1 and b2
        assert trajectory.verified(lp, x) is not None


def test_the_verified_inner_values_come_only_from_points_the_check_accepts(monkeypatch) -> None:
    import identify.linear_block_bounds.point_check as module

    data, _ = _record(8, 17, 400)
    result = bound_linear_block(data.u, data.xc - data.dx, data.xc + data.dx, na=2, nk=1, nb=2,
                                shared_backlash=data.shared)
    assert result.windowing.startswith("all 400 samples in the trajectory relaxation")
    for name, value in THETA.items():
        interval = result.intervals[name]
        assert interval.contains(value)
        assert interval.lower <= result.inner_lower[name] <= result.inner_upper[name] <= interval.upper
        assert interval.upper - interval.lower <= 1.1 * (result.inner_upper[name] - result.inner_lower[name])
    low = np.array([interval.lower for interval in result.intervals.values()])
    high = np.array([interval.upper for interval in result.intervals.values()])
    points = [None if value is None else value for value in [np.array(list(result.inner_point.values()))] * 8]
    monkeypatch.setattr(module._PointCheck, "status", lambda self, point: REFUSED)
    refused_low, refused_high, witness = _inner_values(data, low, high, points, _Counter())
    assert np.all(np.isnan(refused_low)) and np.all(np.isnan(refused_high)) and witness is None


def test_the_trajectory_relaxation_holds_at_the_truth_and_is_as_tight_as_the_interval_relaxation() -> None:
    # Over a box of a around the truth, the true (θ, backlash, chain starts) must satisfy the trajectory relaxation
    # (its widening bounds what the fixed centre of a leaves out), and its bounds must come within a few per cent of
    # the interval relaxation's with δx as columns (both widen by about r Δx per lag).
    data, experiment_data = _record(10, 23, 300)
    p = data.orders.num_parameters
    radius = np.array([2e-3, 2e-3])
    low = np.concatenate([TRUE_THETA[:2] - radius * [0.3, 0.7], [-1e6, -1e6]])
    high = np.concatenate([TRUE_THETA[:2] + radius * [1.7, 1.3], [1e6, 1e6]])
    lp = _trajectory_relaxation(data, low, high)
    truth = np.concatenate([TRUE_THETA, TRUE_BACKLASH, experiment_data.inner_rad[:2]])
    A, row_lower, row_upper = lp.rows()
    values = A @ truth
    assert np.all(values >= row_lower - 1e-12) and np.all(values <= row_upper + 1e-12)
    assert np.all(truth >= lp.lower) and np.all(truth <= lp.upper)
    counter = _Counter()
    new_low, new_high, _ = _bounds_over(lp, p, counter)
    old_low, old_high, _ = _bounds_over(_interval_lp(data, low, high), p, counter)
    for k in range(p):
        assert new_low[k] <= TRUE_THETA[k] <= new_high[k]
        assert new_high[k] - new_low[k] <= 1.05 * (old_high[k] - old_low[k]), (k, new_high - new_low, old_high - old_low)


def test_the_trajectory_relaxation_at_one_a_bounds_b_where_the_checked_points_are() -> None:
    # Over a box of a that is one point the relaxation is the exact set at that a, so its certified bounds of b must
    # meet the points of that set the exact check accepts (up to the 1e-6 row margin those points keep). At 15 bits
    # on 20 000 samples that slice of b is 3e-7 wide; solved with HiGHS's default feasibility tolerance (1e-7), the
    # certified bounds fell 4 % of it short here.
    data, _ = _record(15, 37, 20000)
    p = data.orders.num_parameters
    a = TRUE_THETA[:2]
    low, high = np.concatenate([a, TRUE_THETA[2:] - 1e-3]), np.concatenate([a, TRUE_THETA[2:] + 1e-3])
    counter = _Counter()
    outer_low, outer_high, _ = _bounds_over(_trajectory_relaxation(data, low, high), p, counter)
    exact = _TrajectoryProblem(data, low, high, _PointCheck(data))
    lp = exact.at(a)
    _, _, points = _bounds_over(lp, p, counter)
    checked = [exact.verified(lp, x) for x in points[4:]]  # the points at the least and most b1, then b2
    assert all(point is not None for point in checked)
    for k in (2, 3):
        inner_low, inner_high = checked[2 * (k - 2)][k], checked[2 * (k - 2) + 1][k]
        width = inner_high - inner_low
        assert outer_low[k] <= inner_low and inner_high <= outer_high[k]
        assert inner_low - outer_low[k] <= 0.01 * width and outer_high[k] - inner_high <= 0.01 * width, (
            k, inner_low - outer_low[k], outer_high[k] - inner_high, width)
