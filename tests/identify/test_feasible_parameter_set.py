"""D_γ of eqs. (11)-(20): exact polygons, exact orthotope, empty-set explanation, input validation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial import HalfspaceIntersection

from identify.feasible_parameter_set import (IntervalSetSummary, ParameterInterval, bound_backlash_parameters,
                                            median_width_ratio)
from identify.validation import InvalidInputError
from cerone2009_data import GAMMA, STEADY_INPUT, experiment, noise_bound

# two points per side on m = 0.25 (c_r = 0.04, c_l = 0.06), Δη = 1e-3
U = np.array([1.0, 2.0, -1.0, -2.0])
Y = np.array([0.24, 0.49, -0.235, -0.485])


def test_hand_checked_parallelogram_vertices_and_orthotope() -> None:
    fps = bound_backlash_parameters(U, Y, 1e-3)
    # right side: m - p = A, 2m - p = B with A in 0.24 +- 1e-3, B in 0.49 +- 1e-3 -> m = B - A, p = B - 2A
    vertices = {(round(m, 12), round(p, 12)) for m, p in zip(fps.right.slope_vertices, fps.right.slope_times_deadband_vertices)}
    assert vertices == {(0.25, 0.011), (0.252, 0.013), (0.248, 0.007), (0.25, 0.009)}
    assert fps.m_r.lower == pytest.approx(0.248, abs=1e-12) and fps.m_r.upper == pytest.approx(0.252, abs=1e-12)
    assert fps.c_r.lower == pytest.approx(0.007 / 0.248, abs=1e-12)
    assert fps.c_r.upper == pytest.approx(0.013 / 0.252, abs=1e-12)
    # left side: -m + p = A', -2m + p = B' with A' = -0.235 +- 1e-3, B' = -0.485 +- 1e-3 -> m = A' - B',
    # p = 2A' - B': vertices (0.25, 0.014), (0.248, 0.012), (0.252, 0.018), (0.25, 0.016)
    assert fps.m_l.lower == pytest.approx(0.248, abs=1e-12) and fps.m_l.upper == pytest.approx(0.252, abs=1e-12)
    assert fps.c_l.lower == pytest.approx(0.012 / 0.248, abs=1e-12)
    assert fps.c_l.upper == pytest.approx(0.018 / 0.252, abs=1e-12)
    assert fps.m_r.lower <= 0.248 and fps.m_r.upper >= 0.252  # padding only widens


def test_band_width_and_central_line_of_the_hand_checked_parallelogram() -> None:
    fps = bound_backlash_parameters(U, Y, 1e-3)
    # at the largest input |u| = 2 the strips are y +- 1e-3, and every vertex lies on one of their edges:
    # right w = 2m - p in {0.489, 0.491}, left w = -2m + p in {-0.486, -0.484}
    assert fps.right.band_width_at_largest_input_rad() == pytest.approx(2e-3, abs=1e-12)
    assert fps.left.band_width_at_largest_input_rad() == pytest.approx(2e-3, abs=1e-12)
    assert fps.right.central_line() == pytest.approx((0.25, 0.010), abs=1e-12)
    assert fps.left.central_line() == pytest.approx((0.25, 0.015), abs=1e-12)
    slope, offset = fps.right.central_line()
    assert fps.right.contains(slope, offset)  # the vertex mean of a convex polygon lies inside it


def test_interval_summaries_count_the_truth_and_compare_widths() -> None:
    tight = {"a1": ParameterInterval(0.9, 1.1), "a2": ParameterInterval(-0.1, 0.3), "b1": ParameterInterval(2.0, 2.0)}
    loose = {"a1": ParameterInterval(0.0, 2.0), "a2": ParameterInterval(-1.0, 1.0), "b1": ParameterInterval(1.0, 3.0)}
    summary = IntervalSetSummary.of(tight, truth={"a1": 1.05, "a2": 0.5})
    assert summary.median_half_width == pytest.approx(0.1)  # half-widths 0.1, 0.2, 0
    assert (summary.truth_inside, summary.truth_known) == (1, 2)  # a2's 0.5 lies above 0.3
    assert IntervalSetSummary.of(tight, names=["a2", "c9"]).median_half_width == pytest.approx(0.2)
    # ratios 0.1/1, 0.2/1, 0/1 -> median 0.1; a parameter the reference lacks or with zero width is left out
    assert median_width_ratio(tight, loose, ["a1", "a2", "b1"]) == pytest.approx(0.1)
    assert median_width_ratio(loose, tight, ["a1", "a2", "b1"]) == pytest.approx(7.5)  # 10, 5; b1's 0 left out
    assert median_width_ratio(tight, loose, ["c9"]) is None
    with pytest.raises(InvalidInputError, match="none of the parameters"):
        IntervalSetSummary.of(tight, names=["c9"])


def test_alpha_widens_the_noise_interval_by_two_noise_bounds_times_u_over_step() -> None:
    plain = bound_backlash_parameters(U, Y, 1e-3)
    widened = bound_backlash_parameters(U, Y, 1e-3, filter_step_amplitude_rad=2.0)
    assert np.allclose(widened.alpha_rad, 2e-3 * np.abs(U) / 2.0)
    # with alpha_1 = 1e-3, alpha_2 = 2e-3: m = B - A ranges over (0.49 +- 3e-3) - (0.24 +- 2e-3)
    assert widened.m_r.lower == pytest.approx(0.245, abs=1e-12) and widened.m_r.upper == pytest.approx(0.255, abs=1e-12)
    assert plain.m_r.half_width < widened.m_r.half_width


def _independent_orthotope(u: np.ndarray, y: np.ndarray, delta: float, sign_p: float) -> dict[str, float]:
    """Vertices by qhull's half-space intersection (not clipping), then min/max of m and p/m."""
    rows = np.column_stack([u, np.full(u.size, sign_p)])
    halfspaces = np.vstack([np.column_stack([rows, -(y + delta)]), np.column_stack([-rows, y - delta]),
                            [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]])
    # interior point: Chebyshev centre by LP
    norms = np.linalg.norm(halfspaces[:, :2], axis=1)
    centre = linprog([0, 0, -1], A_ub=np.column_stack([halfspaces[:, :2], norms]), b_ub=-halfspaces[:, 2],
                     bounds=[(None, None), (None, None), (0, None)], method="highs")
    vertices = HalfspaceIntersection(halfspaces, centre.x[:2]).intersections
    m, p = vertices[:, 0], vertices[:, 1]
    return {"m_min": m.min(), "m_max": m.max(), "c_min": (p / m).min(), "c_max": (p / m).max()}


@pytest.mark.parametrize("n_bit", [15, 12, 10, 8])
def test_orthotope_equals_independent_vertex_enumeration_and_contains_truth(n_bit: int) -> None:
    data = experiment(n_bit, seed=n_bit)
    fps = bound_backlash_parameters(data.steady_input_rad, data.steady_output_rad, data.noise_bound_rad)
    for side, sign_p, m_name, c_name in (("right", -1.0, "m_r", "c_r"), ("left", 1.0, "m_l", "c_l")):
        mask = data.steady_input_rad > 0 if side == "right" else data.steady_input_rad < 0
        exact = _independent_orthotope(data.steady_input_rad[mask], data.steady_output_rad[mask], data.noise_bound_rad, sign_p)
        m, c = getattr(fps, m_name), getattr(fps, c_name)
        scale = 1e-9
        assert m.lower == pytest.approx(exact["m_min"], abs=scale) and m.upper == pytest.approx(exact["m_max"], abs=scale)
        assert c.lower == pytest.approx(exact["c_min"], abs=scale) and c.upper == pytest.approx(exact["c_max"], abs=scale)
    for name, value in GAMMA.items():
        assert fps.intervals()[name].contains(value), (name, n_bit)


def test_fifteen_bit_backlash_to_the_papers_precision() -> None:
    data = experiment(15, seed=1)
    fps = bound_backlash_parameters(data.steady_input_rad, data.steady_output_rad, data.noise_bound_rad)
    table_one = {"m_l": 1.1e-4, "c_l": 4.8e-4, "m_r": 2.1e-5, "c_r": 1.0e-4}  # Δγ of Table I, 15 bits
    for name, interval in fps.intervals().items():
        assert abs(interval.center - GAMMA[name]) <= 3 * table_one[name]
        assert interval.half_width <= 3 * table_one[name]


def test_empty_set_names_the_conflicting_points_and_what_to_check() -> None:
    data = experiment(12, seed=2)
    y = data.steady_output_rad.copy()
    y[10] += 0.05  # a positive half-wave point far off its line
    fps = bound_backlash_parameters(data.steady_input_rad, y, data.noise_bound_rad)
    assert fps.is_empty and fps.m_r is None
    explanation = fps.explanation
    assert explanation is not None and explanation.side == "right"
    assert 10 in explanation.conflicting_samples
    assert explanation.required_noise_scale > 1.0
    assert "noise bound is too small" in explanation.message and "steady state" in explanation.message
    with pytest.raises(InvalidInputError, match="empty"):
        fps.intervals()


def test_input_validation_names_the_argument() -> None:
    with pytest.raises(InvalidInputError, match="steady_output_rad: sample 2 is nan"):
        bound_backlash_parameters(U, [0.24, 0.49, np.nan, -0.485], 1e-3)
    with pytest.raises(InvalidInputError, match="steady_input_rad: expected at least 4"):
        bound_backlash_parameters(U[:3], Y[:3], 1e-3)
    with pytest.raises(InvalidInputError, match="same number of samples"):
        bound_backlash_parameters(U, np.append(Y, 0.1), 1e-3)
    with pytest.raises(InvalidInputError, match="expected a 1-D array"):
        bound_backlash_parameters(np.ones((2, 2)), Y, 1e-3)
    with pytest.raises(InvalidInputError, match="noise_bound_rad"):
        bound_backlash_parameters(U, Y, -1.0)
    with pytest.raises(InvalidInputError, match="positive half-waves give 1 distinct"):
        bound_backlash_parameters([1.0, 1.0, -1.0, -2.0], Y, 1e-3)
    with pytest.raises(InvalidInputError, match="sample 1 is 0"):
        bound_backlash_parameters([1.0, 0.0, -1.0, -2.0], Y, 1e-3)
    assert noise_bound(8) == pytest.approx(2 * np.pi / 256) and STEADY_INPUT.size == 100
