"""Linear-block bounds of Section 5 and the whole pipeline on the simulated example of Section 6."""

from __future__ import annotations

import numpy as np
import pytest

from identify.inner_signal_bounds import shared_backlash_constraints
from identify.linear_block_bounds import bound_linear_block
from identify.output_backlash_identification import bound_output_backlash_system
from identify.validation import InvalidInputError
from cerone2009_data import GAMMA, THETA, experiment

TABLE_II_15_BIT = {"a1": 4.3e-4, "a2": 2.5e-4, "b1": 4.3e-4, "b2": 7.2e-4}


def _run(n_bit: int, seed: int, method: str = "coupled", num_samples: int = 100, **options):
    data = experiment(n_bit, seed, num_samples)
    return data, bound_output_backlash_system(data.steady_input_rad, data.steady_output_rad, data.input_rad,
                                              data.output_rad, data.noise_bound_rad, na=2, nk=1, nb=2, method=method,
                                              **options)


def test_fifteen_bit_example_recovers_theta_to_the_papers_precision() -> None:
    _, paper = _run(15, 11, "paper")
    _, coupled = _run(15, 11, "coupled")
    for name, value in THETA.items():
        for result in (paper, coupled):
            interval = result.linear_intervals[name]
            assert interval.contains(value)
            assert abs(interval.center - value) <= TABLE_II_15_BIT[name]
        assert paper.linear_intervals[name].half_width <= 2.5 * TABLE_II_15_BIT[name]
        # the coupled relaxation: several times tighter than Table II (the benchmark reports the medians)
        assert coupled.linear_intervals[name].half_width <= TABLE_II_15_BIT[name] / 3
    for name, value in GAMMA.items():
        assert coupled.backlash_intervals[name].contains(value)


@pytest.mark.parametrize("n_bit", [15, 12, 10, 8])
def test_true_parameters_inside_every_bound_and_coupled_inside_paper(n_bit: int) -> None:
    for seed in (100 + n_bit, 200 + n_bit):
        data, paper = _run(n_bit, seed, "paper")
        inner = paper.inner_signal
        assert inner is not None
        shared = shared_backlash_constraints(data.output_rad, data.noise_bound_rad, paper.backlash, inner)
        # the true (1/m, c) of both sides satisfy the polygon rows in (ρ, c)
        truth = np.array([1 / GAMMA["m_l"], GAMMA["c_l"], 1 / GAMMA["m_r"], GAMMA["c_r"]])
        assert np.all(shared.rows @ truth <= shared.rhs + 1e-12)
        assert np.all((shared.lower <= truth) & (truth <= shared.upper))
        coupled = bound_linear_block(data.input_rad, inner.lower_rad, inner.upper_rad, na=2, nk=1, nb=2,
                                     method="coupled", shared_backlash=shared)
        assert inner.num_invertible < data.input_rad.size  # non-invertible samples are used, not dropped
        for name, value in THETA.items():
            outer_paper, outer = paper.linear_intervals[name], coupled.intervals[name]
            assert outer_paper.contains(value), (n_bit, seed, name, outer_paper)
            assert outer.contains(value), (n_bit, seed, name, outer)
            assert outer_paper.lower <= outer.lower and outer.upper <= outer_paper.upper
            # verified inner values lie inside the outer bounds
            assert coupled.inner_lower is not None and coupled.inner_upper is not None
            assert outer.lower <= coupled.inner_lower[name] <= coupled.inner_upper[name] <= outer.upper
        assert coupled.max_certificate_gap < 1e-6


@pytest.mark.parametrize("n_bit, seed", [(8, 71), (12, 72)])
def test_partition_of_the_box_of_a_brings_the_outer_bounds_to_the_verified_points(n_bit: int, seed: int) -> None:
    # Without the partition, at 8 bits the outer interval is 1.25-2 times the span of verified feasible points.
    # The partition (spatial branch and bound on a) must stay an outer bound, inside the one-relaxation bound,
    # and with the verified points (bisection and local steps) come within 10 % of them.
    data, paper = _run(n_bit, seed, "paper")
    inner = paper.inner_signal
    shared = shared_backlash_constraints(data.output_rad, data.noise_bound_rad, paper.backlash, inner)
    args = (data.input_rad, inner.lower_rad, inner.upper_rad)
    single = bound_linear_block(*args, na=2, nk=1, nb=2, shared_backlash=shared, partition_samples=0)
    seen = []
    cells = bound_linear_block(*args, na=2, nk=1, nb=2, shared_backlash=shared,
                               progress=lambda stage, done, total: seen.append((stage, done, total)))
    assert "partitioned into cells" in cells.windowing and "partitioned" not in single.windowing
    stage, done, total = seen[-1]  # the progress of the partition ends with done == total
    assert stage.startswith("partition of the box of a") and done == total > 0
    slack = single.max_certificate_gap + cells.max_certificate_gap
    for name, value in THETA.items():
        outer, wide = cells.intervals[name], single.intervals[name]
        assert outer.contains(value)
        assert wide.lower - slack <= outer.lower and outer.upper <= wide.upper + slack
        low, high = cells.inner_lower[name], cells.inner_upper[name]
        assert outer.lower <= low <= high <= outer.upper
        assert outer.upper - outer.lower <= 1.1 * (high - low), (name, outer, low, high)


def test_a_partition_that_stopped_early_is_made_again_until_the_bounds_come_within_a_tenth_of_the_verified_values(
) -> None:
    # The first partition ends on a refinement that moves the hull by under 0.1 %, which the first
    # halvings along one a_i can do before the next move it by much. On 13 of 30 records at 8 bits (seeds 60-89)
    # that left an outer interval over 1.1 times the span of the verified points (seed 61: 1.165 after 6 cells);
    # the verified values show it, and the partition is made again, patient, from the first one's hull.
    data, paper = _run(8, 61, "paper")
    inner = paper.inner_signal
    shared = shared_backlash_constraints(data.output_rad, data.noise_bound_rad, paper.backlash, inner)
    result = bound_linear_block(data.input_rad, inner.lower_rad, inner.upper_rad, na=2, nk=1, nb=2,
                                shared_backlash=shared, eliminate_inner_signal=False)
    assert "partitioned again" in result.windowing
    for name, value in THETA.items():
        outer = result.intervals[name]
        assert outer.contains(value)
        low, high = result.inner_lower[name], result.inner_upper[name]
        assert outer.lower <= low <= high <= outer.upper
        assert outer.upper - outer.lower <= 1.1 * (high - low), (name, outer, low, high)


def test_unit_static_gain_holds_across_the_bounds() -> None:
    _, result = _run(12, 5)
    iv = result.linear_intervals
    # Σb - Σa = 1 (eq. (8)) is a constraint: the centre of the box satisfies it to the box's size
    gain_residual = iv["b1"].center + iv["b2"].center - iv["a1"].center - iv["a2"].center - 1.0
    assert abs(gain_residual) <= sum(interval.half_width for interval in iv.values())
    witness = result.linear.inner_point
    assert witness is not None
    assert witness["b1"] + witness["b2"] - witness["a1"] - witness["a2"] == pytest.approx(1.0, abs=1e-7)


def test_wrong_orders_give_an_explained_empty_set() -> None:
    data = experiment(12, 7)
    result = bound_output_backlash_system(data.steady_input_rad, data.steady_output_rad, data.input_rad,
                                          data.output_rad, data.noise_bound_rad, na=1, nk=0, nb=0)
    assert result.is_empty and not result.backlash.is_empty
    explanation = result.linear.explanation
    assert explanation is not None and explanation.conflicting_samples
    assert all(1 <= t < 100 for t in explanation.conflicting_samples)
    assert explanation.required_extra_error_rad > 0.0
    assert "orders" in result.explanation and "noise bound is too small" in result.explanation
    with pytest.raises(InvalidInputError, match="empty"):
        result.linear_intervals


def test_empty_steady_state_set_stops_before_the_dynamic_stages() -> None:
    data = experiment(12, 8)
    steady_y = data.steady_output_rad.copy()
    steady_y[3] -= 0.1
    result = bound_output_backlash_system(data.steady_input_rad, steady_y, data.input_rad, data.output_rad,
                                          data.noise_bound_rad, na=2, nk=1, nb=2)
    assert result.is_empty and result.inner_signal is None and result.linear is None
    assert result.explanation.startswith("steady-state data") and "[3" in result.explanation


def test_validation_names_the_argument() -> None:
    data = experiment(12, 9)
    lower, upper = data.inner_rad - 0.01, data.inner_rad + 0.01
    with pytest.raises(InvalidInputError, match="method"):
        bound_linear_block(data.input_rad, lower, upper, na=2, nk=1, nb=2, method="best")
    with pytest.raises(InvalidInputError, match="nb: expected nb >= nk"):
        bound_linear_block(data.input_rad, lower, upper, na=2, nk=3, nb=2)
    with pytest.raises(InvalidInputError, match="na: expected an integer >= 0"):
        bound_linear_block(data.input_rad, lower, upper, na=-1, nk=1, nb=2)
    with pytest.raises(InvalidInputError, match=r"3 equations for the 4 parameters .* too high for the data "
                                                r"\(at least 8 equations are needed\)"):
        bound_linear_block(data.input_rad[:5], lower[:5], upper[:5], na=2, nk=1, nb=2)
    with pytest.raises(InvalidInputError, match=r"7 equations for the 4 parameters"):  # determined, still too few
        bound_linear_block(data.input_rad[:9], lower[:9], upper[:9], na=2, nk=1, nb=2)
    with pytest.raises(InvalidInputError, match=r"input_rad: the input is constant .* use a persistently exciting"):
        bound_linear_block(np.ones(data.input_rad.size), lower, upper, na=2, nk=1, nb=2)
    with pytest.raises(InvalidInputError, match="inner_lower_rad: sample 0 is above"):
        bound_linear_block(data.input_rad, upper, lower, na=2, nk=1, nb=2)
    with pytest.raises(InvalidInputError, match="same number of samples"):
        bound_linear_block(data.input_rad[:50], lower, upper, na=2, nk=1, nb=2)
    with pytest.raises(InvalidInputError, match="input_rad: sample 4 is nan"):
        bad = data.input_rad.copy()
        bad[4] = np.nan
        bound_output_backlash_system(data.steady_input_rad, data.steady_output_rad, bad, data.output_rad,
                                     data.noise_bound_rad, na=2, nk=1, nb=2)
    with pytest.raises(InvalidInputError, match="noise_bound_rad"):
        bound_output_backlash_system(data.steady_input_rad, data.steady_output_rad, data.input_rad,
                                     data.output_rad, 0.0, na=2, nk=1, nb=2)


def test_long_record_tightens_on_a_window_first_and_still_contains_the_truth() -> None:
    # N = 500 > 2 x 200: the box of a is tightened on the first 200 samples, then rounds of the interval
    # relaxation over all the data
    _, paper = _run(10, 21, "paper", num_samples=500)
    _, coupled = _run(10, 21, "coupled", num_samples=500, partition_samples=0,  # the windows, not the partition
                      eliminate_inner_signal=False)
    for name, value in THETA.items():
        outer_paper, outer = paper.linear_intervals[name], coupled.linear_intervals[name]
        assert outer.contains(value)
        assert outer_paper.lower <= outer.lower and outer.upper <= outer_paper.upper
        assert outer.half_width < outer_paper.half_width / 5
    assert coupled.linear.num_tightening_rounds >= 2


def test_skipping_the_inner_verification_leaves_the_outer_bounds_unchanged() -> None:
    data = experiment(12, 31)
    args = (data.steady_input_rad, data.steady_output_rad, data.input_rad, data.output_rad, data.noise_bound_rad)
    full = bound_output_backlash_system(*args, na=2, nk=1, nb=2)
    fast = bound_output_backlash_system(*args, na=2, nk=1, nb=2, verify_inner=False)
    assert fast.linear.inner_lower is None and full.linear.inner_lower is not None
    assert fast.linear_intervals == full.linear_intervals


def test_interval_relaxation_holds_at_the_truth_and_contains_the_mccormick_one() -> None:
    # The full-data relaxation of long records (a δx = a^c δx + e, |e| <= r Δx): the true (θ, δx) must satisfy
    # it, and its bounds must contain the McCormick relaxation's on the same box (it is an outer set of it).
    from identify.feasible_parameter_set import bound_backlash_parameters
    from identify.inner_signal_bounds import bound_inner_signal
    from identify.linear_block_bounds import LinearModelOrders
    from identify.linear_block_bounds.certified_lp import _bounds_over, _Counter
    from identify.linear_block_bounds.problem import _coupled_lp, _interval_lp, _prepare

    data = experiment(10, 5, num_samples=60)
    backlash = bound_backlash_parameters(data.steady_input_rad, data.steady_output_rad, data.noise_bound_rad)
    inner = bound_inner_signal(data.output_rad, data.noise_bound_rad, backlash)
    problem = _prepare(data.input_rad, inner.lower_rad, inner.upper_rad, LinearModelOrders(2, 1, 2))
    theta = np.array([THETA["a1"], THETA["a2"], THETA["b1"], THETA["b2"]])
    low, high = theta - [0.02, 0.01, 0.5, 0.5], theta + [0.01, 0.03, 0.5, 0.5]
    interval = _interval_lp(problem, low, high)
    truth = np.concatenate([theta, data.inner_rad - problem.xc])
    assert np.all(np.abs(truth[4:]) <= problem.dx + 1e-12)
    A_range, range_lower, range_upper = interval.ranged()
    assert A_range.shape[0] == problem.times.size  # one ranged row per equation
    assert np.all(range_lower - 1e-9 <= A_range @ truth) and np.all(A_range @ truth <= range_upper + 1e-9)
    assert np.allclose(interval.A_eq @ truth, interval.b_eq)
    counter = _Counter()
    outer_low, outer_high, _ = _bounds_over(interval, 4, counter)
    mccormick_low, mccormick_high, _ = _bounds_over(_coupled_lp(problem, low, high), 4, counter)
    assert np.all(outer_low <= theta) and np.all(theta <= outer_high)
    assert np.all(outer_low <= mccormick_low + 1e-9) and np.all(mccormick_high <= outer_high + 1e-9)
    # and it is not vacuous: it tightens the box it was given
    assert np.all(outer_high - outer_low < high - low)


@pytest.mark.parametrize("eliminate_inner_signal", [True, False])
def test_a_bounding_lp_that_highs_cannot_solve_falls_back_to_a_valid_bound_with_a_note(
        monkeypatch, eliminate_inner_signal: bool) -> None:
    # At N = 10 000, 12 bits (benchmark seed [2009, 10000, 12, 1]) one LP of the full-data relaxation
    # stopped with "Solve error" under every recovery setting, which must not end in a traceback. Here every LP
    # that bounds b2 from above in the coupled or trajectory rounds "fails" the same way: the result must still
    # contain the truth, stay inside the paper method's box, and name the parameter.
    import identify.linear_block_bounds.certified_lp as module

    data = experiment(12, 41)
    route = {"eliminate_inner_signal": eliminate_inner_signal}
    _, reference = _run(12, 41, "coupled", **route)
    original = module._Solver.minimize

    def failing(self, cost, counter):
        if counter.stage.startswith(("coupled", "trajectory")) and cost.size > 4 and cost[3] == -1.0:
            counter.solves += 1
            raise module._SolverFailure("Solve error")
        return original(self, cost, counter)

    monkeypatch.setattr(module._Solver, "minimize", failing)
    _, paper = _run(12, 41, "paper")
    _, result = _run(12, 41, "coupled", **route)
    linear = result.linear
    assert len(linear.notes) == 1 and linear.notes[0].startswith("b2 upper bound: HiGHS could not solve")
    assert "Solve error" in linear.notes[0]
    for name, value in THETA.items():
        interval = linear.intervals[name]
        assert interval.contains(value)
        assert paper.linear_intervals[name].lower <= interval.lower and interval.upper <= paper.linear_intervals[name].upper
    # the other bounds are unaffected by the one that fell back
    assert linear.intervals["a1"].lower == pytest.approx(reference.linear_intervals["a1"].lower, abs=1e-6)
    assert reference.linear.notes == ()


def _old_all_data_bounds(data, inner):
    """The coupled bounds over all the data at once (the reference): McCormick rounds on the first 200
    samples, then rounds of the interval relaxation over all the data."""
    from identify.linear_block_bounds import LinearModelOrders
    from identify.linear_block_bounds.certified_lp import _Counter
    from identify.linear_block_bounds.problem import _interval_lp, _paper_bounds, _prepare, _tighten
    from identify.linear_block_bounds.windows import _subset

    shared = shared_backlash_constraints(data.output_rad, data.noise_bound_rad, inner.backlash, inner.inner)
    problem = _prepare(data.input_rad, inner.inner.lower_rad, inner.inner.upper_rad, LinearModelOrders(2, 1, 2), shared)
    counter = _Counter()
    low, high, _ = _paper_bounds(problem, counter)
    low, high, _, _, _ = _tighten(_subset(problem, 200), low, high, counter, 6, 0.02, False)
    low, high, _, _, _ = _tighten(problem, low, high, counter, 6, 0.02, True, _interval_lp)
    return low, high, shared, counter.max_gap


class _Stages:
    def __init__(self, backlash, inner):
        self.backlash, self.inner = backlash, inner


@pytest.mark.parametrize("n_bit, seed", [(12, 51), (8, 52)])
def test_windowed_bounds_are_at_least_as_tight_as_the_all_data_relaxation(n_bit: int, seed: int) -> None:
    # N = 700: three windows of 200 samples, their boxes intersected and fed back, then all samples jointly
    data, paper = _run(n_bit, seed, "paper", num_samples=700)
    low, high, shared, old_gap = _old_all_data_bounds(data, _Stages(paper.backlash, paper.inner_signal))
    inner = paper.inner_signal
    new = bound_linear_block(data.input_rad, inner.lower_rad, inner.upper_rad, na=2, nk=1, nb=2,
                             shared_backlash=shared, verify_inner=False, eliminate_inner_signal=False)
    assert new.windowing.startswith("4 windows of 200 samples") and "then all 700 samples jointly" in new.windowing
    # at least as tight, up to what the certificates give away against the LP optima (both report it: about
    # 1e-8 here, against half-widths of 1e-5..1e-3)
    slack = new.max_certificate_gap + old_gap
    assert slack < 1e-6
    for k, (name, value) in enumerate(THETA.items()):
        interval = new.intervals[name]
        assert interval.contains(value)
        assert interval.lower >= low[k] - slack and interval.upper <= high[k] + slack, (name, interval, low[k], high[k])


def test_parts_of_a_long_record_run_through_a_map_and_give_the_same_bounds() -> None:
    from concurrent.futures import ThreadPoolExecutor

    data, paper = _run(10, 61, "paper", num_samples=900)
    inner = paper.inner_signal
    shared = shared_backlash_constraints(data.output_rad, data.noise_bound_rad, paper.backlash, inner)
    args = (data.input_rad, inner.lower_rad, inner.upper_rad)
    seen = []
    # the map runs the windows and parts; the partition of short records (in-process) is switched off here
    options = {"joint_samples": 400, "partition_samples": 0, "verify_inner": False, "eliminate_inner_signal": False}
    serial = bound_linear_block(*args, na=2, nk=1, nb=2, shared_backlash=shared, **options,
                                progress=lambda stage, done, total: seen.append((stage, done, total)))
    with ThreadPoolExecutor(2) as pool:
        parallel = bound_linear_block(*args, na=2, nk=1, nb=2, shared_backlash=shared, **options,
                                      map_windows=pool.map)
    assert parallel.intervals == serial.intervals
    assert "then 3 of 3 overlapping parts of 400 samples jointly" in serial.windowing
    assert any(stage.startswith("window pass 1") and done == total == 5 for stage, done, total in seen)
    assert any(stage.startswith("joint relaxation of 3 part") and done == total == 3 for stage, done, total in seen)
    for name, value in THETA.items():
        interval = serial.intervals[name]
        assert interval.contains(value)
        assert paper.linear_intervals[name].lower <= interval.lower and interval.upper <= paper.linear_intervals[name].upper


def test_row_generation_gives_the_paper_bounds_of_the_whole_orthant_lps(monkeypatch) -> None:
    # Long records bound each orthant's LP on a growing subset of its rows (the whole LPs of a
    # 100 000-sample record take 8.5 CPU-s in one process before the windows could start); here the subset
    # starts at 300 of the 1796 rows of a 900-sample record and must end at the whole LP's bounds.
    import identify.linear_block_bounds.problem as module
    from identify.linear_block_bounds.certified_lp import _Counter

    data, paper = _run(10, 63, "paper", num_samples=900)
    inner = paper.inner_signal
    problem = module._prepare(data.input_rad, inner.lower_rad, inner.upper_rad, module.LinearModelOrders(2, 1, 2))
    whole_low, whole_high, whole_orthants = module._paper_bounds(problem, _Counter())
    monkeypatch.setattr(module, "_PAPER_ROWS", 300)
    monkeypatch.setattr(module, "_PAPER_ROWS_ADDED", 20)
    counter = _Counter()
    low, high, orthants = module._paper_bounds(problem, counter)
    assert orthants == whole_orthants
    assert counter.solves > 8 * len(whole_orthants)  # several turns of the row generation ran
    scale = 1e-8 * (1.0 + np.abs(whole_high))  # the certificates of different LPs differ by their rounding
    assert np.all(np.abs(low - whole_low) <= scale) and np.all(np.abs(high - whole_high) <= scale)


def test_a_pass_re_solves_only_the_bounds_still_moving_that_a_task_could_decide() -> None:
    from identify.linear_block_bounds.windows import _moving, _TaskBounds

    low, high = np.array([0.0, 10.0]), np.array([1.0, 11.0])
    tasks = _TaskBounds(3, 2)
    tasks.record(0, np.array([-0.5, 9.0]), np.array([2.0, 12.0]), None)  # an earlier solve of task 0
    tasks.record(0, np.array([0.0, 9.9]), np.array([1.5, 11.0]), None)  # decides low_0 and high_1
    tasks.record(1, np.array([-0.05, 10.0]), np.array([1.0, 11.5]), None)  # once: decides low_1 and high_0
    tasks.record(2, np.array([-3.0, 5.0]), np.array([4.0, 16.0]), None)  # far from every bound
    # with no a (na = 0) the upper bound of the second parameter is left out: it did not move in the last pass
    moving = _moving(np.array([-0.1, 9.0]), np.array([1.1, 11.0]), low, high, 0.02, 0)
    assert moving.tolist() == [True, True, True, False]
    # while the box of a (the first parameter, na = 1) moves, every bound is solved again
    assert _moving(np.array([-0.1, 9.0]), np.array([1.1, 11.0]), low, high, 0.02, 1).tolist() == [True] * 4
    assert _moving(np.array([0.0, 9.0]), np.array([1.0, 11.0]), low, high, 0.02, 1).tolist() == [False, False,
                                                                                                  True, False]
    chosen, wanted = tasks.candidates(low, high, moving, np.full(4, 0.2), np.full(4, 0.1))
    assert chosen == [0, 1]
    # task 0: low_0 (it decides it), low_1 (9.9 plus its last gain of 0.9 reaches 10); its high_0 (1.5) lies
    # beyond the margin of 0.2
    assert wanted[0].tolist() == [True, False, True, False]
    # task 1 was solved once, so any gain is possible: low_0 (within the margin), high_0 and low_1 (it decides)
    assert wanted[1].tolist() == [True, True, True, False]
    # a pass later task 0 gained 0.05 on low_1 (9.95, enough to reach 10 if it gained as much again), but the
    # intersection advanced a tenth as far as the pass before: task 0 is expected to gain a fifth of that
    tasks.record(0, np.array([0.0, 9.95]), np.array([1.5, 11.0]), np.array([False, False, True, False]))
    chosen, wanted = tasks.candidates(low, high, moving, np.full(4, 0.5), np.full(4, 0.01))
    assert chosen == [0, 1] and wanted[0].tolist() == [True, False, False, False]


def test_the_passes_over_the_parts_iterate_to_a_fixed_point_that_one_pass_contains(monkeypatch) -> None:
    # The parts of a long record are solved one round each per pass, every pass from the
    # intersection of the previous one, until a pass shrinks no interval by the tightening tolerance. More
    # passes only intersect more valid boxes: never wider than one pass, and the truth stays inside.
    import identify.linear_block_bounds.windows as module

    data, paper = _run(8, 62, "paper", num_samples=900)
    inner = paper.inner_signal
    shared = shared_backlash_constraints(data.output_rad, data.noise_bound_rad, paper.backlash, inner)
    args = (data.input_rad, inner.lower_rad, inner.upper_rad)
    options = {"na": 2, "nk": 1, "nb": 2, "shared_backlash": shared, "joint_samples": 400, "partition_samples": 0,
               "verify_inner": False, "eliminate_inner_signal": False}
    passes = bound_linear_block(*args, **options)
    monkeypatch.setattr(module, "_PART_PASSES", 1)
    single = bound_linear_block(*args, **options)
    assert "(1 pass of one round each)" in single.windowing
    used = int(passes.windowing.split("intersected (")[1].split(" pass")[0])
    assert 2 <= used <= 6, passes.windowing
    narrower = 0
    for name, value in THETA.items():
        many, one = passes.intervals[name], single.intervals[name]
        assert many.contains(value)
        assert one.lower <= many.lower and many.upper <= one.upper
        narrower += many.half_width < one.half_width * (1 - 1e-6)
    assert narrower >= 1


def _long_record_options(seed: int):
    data, paper = _run(8, seed, "paper", num_samples=900)
    inner = paper.inner_signal
    shared = shared_backlash_constraints(data.output_rad, data.noise_bound_rad, paper.backlash, inner)
    return (data.input_rad, inner.lower_rad, inner.upper_rad), {
        "na": 2, "nk": 1, "nb": 2, "shared_backlash": shared, "joint_samples": 400, "partition_samples": 0,
        "verify_inner": False, "eliminate_inner_signal": False}, paper


def test_a_part_starts_its_next_pass_from_its_last_basis_and_gets_the_bounds_of_a_cold_start(monkeypatch) -> None:
    # A part's LP keeps its rows and columns from pass to pass, so its next pass starts from its last
    # basis (HiGHS's first solve of a 3000-sample part is most of its time). Only the start differs: the
    # certified bounds are those of parts solved from scratch, up to the rounding of the certificates.
    import identify.linear_block_bounds.certified_lp as module

    args, options, paper = _long_record_options(64)
    starts = []
    original = module._Solver.__init__

    def spied(self, *a, **k):
        original(self, *a, **k)
        starts.append(self.from_basis)

    monkeypatch.setattr(module._Solver, "__init__", spied)
    handed_on = bound_linear_block(*args, **options)
    assert sum(starts) >= 3, handed_on.windowing  # at least one later pass of the 3 parts went on from a basis
    starts.clear()
    monkeypatch.setattr(module._Solver, "handoff", lambda self: module._PartStart())
    cold = bound_linear_block(*args, **options)
    assert not any(starts)
    assert cold.windowing == handed_on.windowing
    for name, value in THETA.items():
        warm, scratch = handed_on.intervals[name], cold.intervals[name]
        assert warm.contains(value)
        tolerance = 1e-8 * (1.0 + abs(scratch.upper))
        assert abs(warm.lower - scratch.lower) <= tolerance and abs(warm.upper - scratch.upper) <= tolerance


def test_a_part_whose_presolved_solve_failed_solves_its_next_passes_without_presolve(monkeypatch) -> None:
    # At N = 100 000, 8 bits, 28 % of the parts' presolved first solves failed ("excessive primal
    # values" after postsolve), mostly the same parts pass after pass, and one crashed HiGHS. Here every
    # presolved solve of a part stops at once (a time limit of zero): each part may pay for it once, not in
    # every pass, and the bounds still contain the truth.
    import identify.linear_block_bounds.certified_lp as module

    args, options, paper = _long_record_options(62)
    failed = []
    original = module._Solver._run

    def presolve_fails_on_parts(self):
        ranged = self.lp.A_range
        if ranged is not None and ranged.shape[0] > 300 and self.highs.getOptionValue("presolve")[1] == "on":
            failed.append(ranged.shape)  # one equation per ranged row: a part of 400 samples, not a window
            self.highs.setOptionValue("time_limit", 0.0)
            self.highs.run()
            return
        original(self)

    monkeypatch.setattr(module._Solver, "_run", presolve_fails_on_parts)
    result = bound_linear_block(*args, **options)
    used = int(result.windowing.split("intersected (")[1].split(" pass")[0])
    assert used >= 2, result.windowing
    assert 1 <= len(failed) <= 3  # the 3 parts of 400 samples, once each
    for name, value in THETA.items():
        assert result.intervals[name].contains(value)
        assert paper.linear_intervals[name].lower <= result.intervals[name].lower
    assert result.notes == ()


def _window_task_whose_joint_parts_kill_their_process(task):
    """A worker that dies as in a segfault inside HiGHS, here by SIGKILL."""
    import os
    import signal

    import identify.linear_block_bounds.windows as module

    if task[0] == "joint":
        os.kill(os.getpid(), signal.SIGKILL)
    return module._ORIGINAL_WINDOW_TASK(task)


def test_a_worker_process_that_dies_gives_valid_looser_bounds_with_a_note(monkeypatch) -> None:
    # At N = 100 000, 8 bits, a worker can segfault inside HiGHS: no BrokenProcessPool may reach the user.
    # Here every worker that starts a joint part dies: the window bounds must be returned, with a note.
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    import identify.linear_block_bounds.windows as module

    data, paper = _run(10, 61, "paper", num_samples=900)
    inner = paper.inner_signal
    shared = shared_backlash_constraints(data.output_rad, data.noise_bound_rad, paper.backlash, inner)
    args = (data.input_rad, inner.lower_rad, inner.upper_rad)
    options = {"joint_samples": 400, "partition_samples": 0, "eliminate_inner_signal": False}
    serial = bound_linear_block(*args, na=2, nk=1, nb=2, shared_backlash=shared, **options)
    monkeypatch.setattr(module, "_ORIGINAL_WINDOW_TASK", module._window_task, raising=False)
    monkeypatch.setattr(module, "_window_task", _window_task_whose_joint_parts_kill_their_process)
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("fork")) as pool:
        lost = bound_linear_block(*args, na=2, nk=1, nb=2, shared_backlash=shared, map_windows=pool.map, **options)
    assert len(lost.notes) == 1
    assert lost.notes[0].startswith("all parameters: a process running the windows stopped in the joint relaxation")
    assert "BrokenProcessPool" in lost.notes[0]
    assert serial.notes == ()
    for name, value in THETA.items():
        interval = lost.intervals[name]
        assert interval.contains(value)
        # the windows' bound: inside the paper method's, around the full method's
        assert paper.linear_intervals[name].lower <= interval.lower and interval.upper <= paper.linear_intervals[name].upper
        assert interval.lower <= serial.intervals[name].lower and serial.intervals[name].upper <= interval.upper
    assert lost.inner_lower is None  # no joint part finished, so no extreme points to verify


_WINDOWS_SLOW = pytest.mark.skipif(__import__("os").environ.get("RIG_SLOW") != "1",
                                   reason="about a minute: opt-in with RIG_SLOW=1")


@pytest.mark.slow
@pytest.mark.parametrize("eliminate_inner_signal", [True, pytest.param(False, marks=_WINDOWS_SLOW)])
def test_the_record_that_stopped_highs_gives_bounds(eliminate_inner_signal: bool) -> None:
    # The benchmark's run 1 at N = 10 000, 12 bits (seed [2009, 10000, 12, 1]): the all-data LP with δx as columns
    # stopped with "HiGHS failed on a bounding LP: Solve error" and a traceback. Now: bounds that contain the truth,
    # by the windows and by the trajectory relaxation (a few seconds, with the verified inner values within 10 %).
    from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
    from identify.feasible_parameter_set import bound_backlash_parameters
    from identify.inner_signal_bounds import bound_inner_signal
    from cerone2009_data import PLANT

    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    rng = np.random.default_rng([2009, 10000, 12, 1])
    delta = 2.0 * np.pi / 2**12
    steady_y = PLANT.simulate(staircase)[steady] + rng.uniform(-delta, delta, steady.size)
    u = prbs_sequence(10000, 1.0, rng=rng)
    y = PLANT.simulate(u) + rng.uniform(-delta, delta, u.size)
    backlash = bound_backlash_parameters(staircase[steady], steady_y, delta)
    inner = bound_inner_signal(y, delta, backlash)
    shared = shared_backlash_constraints(y, delta, backlash, inner)
    result = bound_linear_block(u, inner.lower_rad, inner.upper_rad, na=2, nk=1, nb=2, shared_backlash=shared,
                                verify_inner=eliminate_inner_signal, eliminate_inner_signal=eliminate_inner_signal)
    for name, value in THETA.items():
        assert result.intervals[name].contains(value)
        assert result.intervals[name].half_width < 1e-4
    if eliminate_inner_signal:
        assert result.notes == ()
        assert all(ratio <= 1.1 for ratio in result.outer_inner_ratio.values()), result.outer_inner_ratio


def test_linear_block_bounds_are_built_from_keywords() -> None:
    # keyword fields, not 11 positional arguments; the diagnostics default to "none"
    from identify.feasible_parameter_set import ParameterInterval
    from identify.linear_block_bounds import LinearBlockBounds, LinearModelOrders

    orders = LinearModelOrders(1, 0, 0)
    bounds = LinearBlockBounds(method="paper", orders=orders, intervals={"a1": ParameterInterval(-0.5, -0.4),
                                                                         "b0": ParameterInterval(0.5, 0.6)})
    assert not bounds.is_empty and bounds.notes == () and bounds.num_linear_programs == 0
    assert LinearBlockBounds.from_dict(bounds.to_dict()) == bounds
    with pytest.raises(TypeError):
        LinearBlockBounds("paper", orders, {})  # type: ignore[misc]


def test_the_widened_relaxation_of_a_sliver_cell_contains_its_set_and_little_more() -> None:
    # a cell of the partition whose relaxation HiGHS calls infeasible without a certificate is bounded on the
    # LP with every row widened by _WIDENING (1 + |bound|): a superset, so its bounds hold
    import scipy.sparse as sp

    from identify.linear_block_bounds.certified_lp import _LP, _WIDENING, _bounds_over, _Counter, _widened

    # x0 + x1 = 1 (equality), 0.2 <= x0 - x1 <= 0.4 (ranged), x0 <= 0.69 (inequality), box [0, 1]^2
    lp = _LP(sp.csr_matrix([[1.0, 0.0]]), np.array([0.69]), sp.csr_matrix([[1.0, 1.0]]), np.array([1.0]),
             np.zeros(2), np.ones(2), sp.csr_matrix([[1.0, -1.0]]), np.array([0.2]), np.array([0.4]))
    low, high, _ = _bounds_over(lp, 2, _Counter())
    wide_low, wide_high, _ = _bounds_over(_widened(lp), 2, _Counter())
    assert np.allclose([low[0], high[0], low[1], high[1]], [0.6, 0.69, 0.31, 0.4])
    assert np.all(wide_low <= low) and np.all(wide_high >= high)
    assert np.all(low - wide_low <= 4 * _WIDENING) and np.all(wide_high - high <= 4 * _WIDENING)
