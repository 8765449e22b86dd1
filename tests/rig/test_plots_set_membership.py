"""Figures of the output-backlash set-membership results, drawn from a real identification on simulated data."""

from __future__ import annotations

import re

import numpy as np
import pytest
from plot_checks import unlabelled_axes

from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.feasible_parameter_set import ParameterInterval
from identify.output_backlash_identification import bound_output_backlash_system
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
from rig.plots.set_membership import (
    backlash_characteristic_figure,
    box_magnitude_envelope,
    default_result_figures,
    feasible_polygons_figure,
    inner_signal_figure,
    linear_block_bode_figure,
    parameter_intervals_figure,
)
from rig.report import ReportSection, missing_images, write_report

LINEAR = LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 0.01)
BACKLASH = OutputBacklash(0.248, 0.0698, 0.252, 0.0349)
PLANT = PlantModel((LINEAR, BACKLASH))
NOISE = 1e-3
TRUE_VALUES = {"m_l": 0.248, "c_l": 0.0698, "m_r": 0.252, "c_r": 0.0349, "a1": 0.5, "a2": 0.7, "b1": 1.4, "b2": 0.8}


@pytest.fixture(scope="module")
def experiment():
    rng = np.random.default_rng(0)
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 6)), 0.8125, 100)
    steady = staircase_steady_state_indices(6, 100)
    steady_y = PLANT.simulate(staircase)[steady] + rng.uniform(-NOISE, NOISE, steady.size)
    u = prbs_sequence(60, 1.0, rng=1)
    y = PLANT.simulate(u) + rng.uniform(-NOISE, NOISE, u.size)
    return staircase[steady], steady_y, u, y


@pytest.fixture(scope="module")
def results(experiment):
    steady_u, steady_y, u, y = experiment
    return {method: bound_output_backlash_system(steady_u, steady_y, u, y, NOISE, na=2, nk=1, nb=2, method=method)
            for method in ("paper", "coupled")}


def _number(pattern: str, text: str) -> float:
    match = re.search(pattern, text)
    assert match, f"{pattern!r} not in {text!r}"
    return float(match.group(1))


def test_characteristic_and_polygons_contain_the_true_backlash(results):
    characteristic = backlash_characteristic_figure(results["coupled"], "characteristic", true_backlash=BACKLASH)
    assert "12 steady-state points" in characteristic.caption
    assert "±Δη = ±0.001 rad" in characteristic.caption
    assert "inside the band on 2 of 2 sides" in characteristic.caption
    polygons = feasible_polygons_figure(results["coupled"], "polygons", true_backlash=BACKLASH)
    assert polygons.caption.count("rad, true point inside") == 2
    # A backlash with twice the right dead band is not in D_γ^r: the figure must say so.
    wrong = {"m_l": 0.248, "c_l": 0.0698, "m_r": 0.252, "c_r": 2 * 0.0349}
    assert "true point OUTSIDE" in feasible_polygons_figure(results["coupled"], "p", true_backlash=wrong).caption
    assert "on 1 of 2 sides (left)" in backlash_characteristic_figure(results["coupled"], "c", true_backlash=wrong).caption


def test_inner_signal_figure_counts_invertible_samples_and_checks_the_truth(results, experiment):
    _, _, u, _ = experiment
    inner = results["paper"].inner_signal
    true_x = LINEAR.apply(u)
    figure = inner_signal_figure(results["paper"], "inner", sample_period_s=0.01, true_inner_rad=true_x)
    assert f"{inner.num_invertible} samples" in figure.caption
    assert "inside the bounds at 60 of 60 samples" in figure.caption
    with pytest.raises(ValueError, match="true_inner_rad: expected 60 samples"):
        inner_signal_figure(results["paper"], "inner", true_inner_rad=true_x[:10])


def test_interval_figure_compares_methods_against_the_truth(results):
    figure = parameter_intervals_figure(results, "intervals", true_values=TRUE_VALUES)
    assert "paper: median half-width" in figure.caption and "coupled: median half-width" in figure.caption
    assert figure.caption.count("true value inside 8 of 8") == 2
    # The coupled bounds are much tighter on the linear block (about 6 % of the paper widths here).
    assert _number(r"coupled/paper on the linear block = ([0-9.eE+-]*[0-9])", figure.caption) < 0.5
    shifted = {**TRUE_VALUES, "a1": 0.6}
    assert figure.caption != parameter_intervals_figure(results, "i", true_values=shifted).caption
    assert "true value inside 7 of 8" in parameter_intervals_figure(results, "i", true_values=shifted).caption


def test_bode_envelope_contains_the_true_model(results):
    figure = linear_block_bode_figure(results, "bode", sample_period_s=0.01, true_linear=LINEAR)
    assert "Nyquist frequency 50 Hz" in figure.caption
    assert figure.caption.count("true |G| inside the envelope at 100 %") == 2
    paper = _number(r"paper: median envelope width ([0-9.eE+-]*[0-9]) dB", figure.caption)
    coupled = _number(r"coupled: median envelope width ([0-9.eE+-]*[0-9]) dB", figure.caption)
    assert coupled < paper
    # Without a sample period the axis is normalised; from plain intervals (JSON) it draws the same model.
    intervals = dict(results["coupled"].linear_intervals)
    normalised = linear_block_bode_figure(intervals, "bode_plain")
    assert "0.5 cycles/sample" in normalised.caption
    assert f"median envelope width {coupled:.3g} dB" in normalised.caption
    with pytest.raises(ValueError, match="no linear-block intervals"):
        linear_block_bode_figure({"m_l": ParameterInterval(0.2, 0.3)}, "none")


def test_box_envelope_is_exact_on_a_hand_case_and_contains_every_box_model():
    # G = b0 / (1 + a1 q^-1), a1 in [0.4, 0.6], b0 in [1, 2]: at ω = 0, |A| = 1 + a1; at ω = π, |A| = 1 - a1.
    lower, upper = box_magnitude_envelope({"a1": ParameterInterval(0.4, 0.6), "b0": ParameterInterval(1.0, 2.0)},
                                          [0.0, np.pi])
    np.testing.assert_allclose(lower, [1 / 1.6, 1 / 0.6], rtol=1e-12)
    np.testing.assert_allclose(upper, [2 / 1.4, 2 / 0.4], rtol=1e-12)
    # A box around a second-order model: every sampled model lies inside the envelope, and the upper envelope
    # is reached. |B| is largest at a corner of the b-box; |A| is smallest on the boundary of its zonotope,
    # where every a_i but one sits at a bound: searching those edges finds the supremum.
    rng = np.random.default_rng(3)
    box = {"a1": ParameterInterval(-1.25, -1.15), "a2": ParameterInterval(0.45, 0.5),
           "b1": ParameterInterval(0.1, 0.2), "b2": ParameterInterval(0.05, 0.1)}
    omega = np.linspace(0.01, np.pi, 200)
    z = np.exp(-1j * omega)
    lower, upper = box_magnitude_envelope(box, omega)

    def magnitude(a1, a2, b1, b2):
        return np.abs((b1 * z + b2 * z**2) / (1 + a1 * z + a2 * z**2))

    samples = np.array([magnitude(*(rng.uniform(box[k].lower, box[k].upper) for k in ("a1", "a2", "b1", "b2")))
                        for _ in range(300)])
    assert np.all(samples >= lower * (1 - 1e-12)) and np.all(samples <= upper * (1 + 1e-12))
    dense = np.linspace(0.0, 1.0, 201)
    a_edges = [(box["a1"].lower + t * 0.1, a2) for t in dense for a2 in (0.45, 0.5)]
    a_edges += [(a1, 0.45 + t * 0.05) for t in dense for a1 in (-1.25, -1.15)]
    largest = np.max([magnitude(a1, a2, b1, b2) for a1, a2 in a_edges for b1 in (0.1, 0.2) for b2 in (0.05, 0.1)],
                     axis=0)
    assert np.all(largest <= upper * (1 + 1e-12))
    assert np.min(largest / upper) > 0.999
    # A box of zero width is one model: the envelope collapses onto it.
    point = {k: ParameterInterval(v.center, v.center) for k, v in box.items()}
    lower, upper = box_magnitude_envelope(point, omega)
    z = np.exp(-1j * omega)
    exact = np.abs((0.15 * z + 0.075 * z**2) / (1 - 1.2 * z + 0.475 * z**2))
    np.testing.assert_allclose(lower, exact, rtol=1e-9)
    np.testing.assert_allclose(upper, exact, rtol=1e-9)


def test_every_figure_renders_with_units_and_no_missing_image(results, experiment, tmp_path):
    _, _, u, _ = experiment
    figures = default_result_figures(results, "sm_", sample_period_s=0.01, true_backlash=BACKLASH,
                                     true_linear=LINEAR, true_values=TRUE_VALUES, true_inner_rad=LINEAR.apply(u))
    assert [f.name for f in figures] == ["sm_backlash", "sm_polygons", "sm_inner_signal", "sm_intervals", "sm_bode"]
    problems = [problem for figure in figures for problem in unlabelled_axes(figure)]
    assert problems == []
    index = write_report(tmp_path, "set membership", [ReportSection("Set membership", figures=tuple(figures))])
    assert missing_images(index) == []
    import matplotlib.image

    for figure in figures:
        image = matplotlib.image.imread(tmp_path / f"{figure.name}.png")
        assert image.shape[0] > 200 and image.shape[1] > 400


def test_empty_feasible_set_is_shown_not_hidden(experiment):
    steady_u, steady_y, u, y = experiment
    # A noise bound 100 times too small: no backlash line passes within it of every steady-state point.
    result = bound_output_backlash_system(steady_u, steady_y, u, y, NOISE / 100, na=2, nk=1, nb=2, method="paper")
    assert result.is_empty
    figures = default_result_figures({"paper": result}, "empty_")
    assert [f.name for f in figures] == ["empty_backlash", "empty_polygons"]
    assert "The feasible set is EMPTY" in figures[0].caption
    assert "EMPTY" in figures[1].caption
    assert unlabelled_axes(figures[0]) == []
