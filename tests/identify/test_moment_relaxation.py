"""The moment (SDP) relaxation of the coupled linear-block problem and its certified cuts."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

pytest.importorskip("cvxpy")

from identify import moment_relaxation  # noqa: E402
from identify.feasible_parameter_set import bound_backlash_parameters  # noqa: E402
from identify.inner_signal_bounds import bound_inner_signal, shared_backlash_constraints  # noqa: E402
from identify.linear_block_bounds import LinearModelOrders, bound_linear_block  # noqa: E402
from identify.linear_block_bounds.certified_lp import _LP, _bounds_over, _Counter  # noqa: E402
from identify.linear_block_bounds.final_tightening import _lifted_moment_lp  # noqa: E402
from identify.linear_block_bounds.problem import _prepare  # noqa: E402
from cerone2009_data import THETA, experiment  # noqa: E402

_THETA = np.array(list(THETA.values()))


def _problem(n_bit: int, seed: int, num_samples: int):
    data = experiment(n_bit, seed, num_samples)
    backlash = bound_backlash_parameters(data.steady_input_rad, data.steady_output_rad, data.noise_bound_rad)
    inner = bound_inner_signal(data.output_rad, data.noise_bound_rad, backlash)
    return data, inner, backlash


def test_the_cuts_hold_at_the_true_point_and_tighten_no_less_than_mccormick() -> None:
    # the true (θ, δx) lifted to z = a δx, A = a a^T, D = δx^2 must satisfy every row, cuts included; the
    # LP with the cuts is inside the McCormick LP on the same box
    data, inner, _ = _problem(8, 3, 40)
    problem = _prepare(data.input_rad, inner.lower_rad, inner.upper_rad, LinearModelOrders(2, 1, 2))
    low, high = _THETA - [0.03, 0.02, 0.3, 0.3], _THETA + [0.02, 0.03, 0.3, 0.3]
    A_ub, b_ub, A_eq, b_eq, lower, upper = _lifted_moment_lp(problem, low, high)
    delta = data.inner_rad - problem.xc
    a = _THETA[:2]
    truth = np.concatenate([_THETA, delta, a[0] * delta, a[1] * delta, [a[0] ** 2, a[0] * a[1], a[1] ** 2],
                            delta ** 2])
    assert truth.size == lower.size
    assert np.all(lower <= truth) and np.all(truth <= upper)
    assert np.allclose(A_eq @ truth, b_eq, atol=1e-12) and np.all(A_ub @ truth <= b_ub + 1e-12)
    cuts = moment_relaxation.moment_cuts(na=2, p=4, num_samples=problem.u.size, equations=A_eq, equation_rhs=b_eq,
                                         inequalities=A_ub, inequality_rhs=b_ub, lower=lower, upper=upper,
                                         objectives=[0, 1, 3], delta_bound_rad=problem.dx)
    assert cuts.solved == (0, 1, 3) and cuts.failed == ()
    assert cuts.rows.shape == (3 * problem.u.size, lower.size)
    assert np.all(cuts.rows @ truth <= cuts.rhs)
    counter = _Counter()
    plain_low, plain_high, _ = _bounds_over(_LP(A_ub, b_ub, A_eq, b_eq, lower, upper), 4, counter)
    cut_low, cut_high, _ = _bounds_over(_LP(sp.vstack([A_ub, cuts.rows]).tocsr(), np.concatenate([b_ub, cuts.rhs]), A_eq, b_eq,
                                            lower, upper), 4, counter)
    assert np.all(cut_low <= _THETA) and np.all(_THETA <= cut_high)
    assert np.all(cut_low >= plain_low - 1e-9) and np.all(cut_high <= plain_high + 1e-9)
    # the SDP of a1's lower bound tightens it beyond McCormick on this wide box
    assert cut_low[0] > plain_low[0] + 1e-6 * (plain_high[0] - plain_low[0])


def test_moment_tightening_in_the_pipeline_is_inside_the_lp_bounds_and_holds_the_truth() -> None:
    data, inner, backlash = _problem(8, 11, 40)
    shared = shared_backlash_constraints(data.output_rad, data.noise_bound_rad, backlash, inner)
    args = (data.input_rad, inner.lower_rad, inner.upper_rad)
    options = {"na": 2, "nk": 1, "nb": 2, "shared_backlash": shared, "verify_inner": False}
    lp = bound_linear_block(*args, **options)
    sdp = bound_linear_block(*args, moment_samples=100, **options)
    assert "moment (SDP)" in sdp.windowing and "moment" not in lp.windowing
    assert sdp.notes == ()
    for name, value in THETA.items():
        assert sdp.intervals[name].contains(value)
        assert lp.intervals[name].lower <= sdp.intervals[name].lower
        assert sdp.intervals[name].upper <= lp.intervals[name].upper


def test_a_failing_sdp_keeps_the_lp_bounds_with_a_note(monkeypatch) -> None:
    import cvxpy as cp

    data, inner, _ = _problem(10, 4, 40)
    args = (data.input_rad, inner.lower_rad, inner.upper_rad)
    options = {"na": 2, "nk": 1, "nb": 2, "verify_inner": False}
    lp = bound_linear_block(*args, **options)

    def failing(self, *args, **kwargs):
        raise cp.error.SolverError("simulated solver failure")

    monkeypatch.setattr(cp.Problem, "solve", failing)
    sdp = bound_linear_block(*args, moment_samples=100, **options)
    assert sdp.intervals == lp.intervals
    assert len(sdp.notes) == 8 and all("moment SDP gave no dual" in note for note in sdp.notes)
    assert "a1 lower bound" in sdp.notes[0] and "simulated solver failure" in sdp.notes[0]
