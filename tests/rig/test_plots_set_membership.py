"""Figures of the output-backlash set-membership results, drawn from a real identification on simulated data."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from plot_checks import unlabelled_axes

from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.feasible_parameter_set import ParameterInterval
from identify.linear_block_bounds import EmptyLinearSetExplanation
from identify.output_backlash_identification import bound_output_backlash_system
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
from rig.plots.set_membership import (
    backlash_characteristic_figure,
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


def _drawn(report_figure):
    """The matplotlib figure a ReportFigure draws (off-screen)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=report_figure.size_in, layout="constrained")
    report_figure.draw(figure)
    return figure


def _labels(axes) -> list[str]:
    return [line.get_label() for line in axes.get_lines()] + [c.get_label() for c in axes.collections]


def test_characteristic_and_polygons_show_both_sides_the_points_and_the_true_backlash(results):
    characteristic = _drawn(backlash_characteristic_figure(results["coupled"], "c", true_backlash=BACKLASH))
    full, zoom = characteristic.axes[:2]
    assert {"left lines of D_γ", "right lines of D_γ", "true lines"} <= set(_labels(full))
    # the 12 steady-state points with their error bars, 6 per side
    points = [c for c in full.containers if hasattr(c, "lines")]
    assert sorted(len(c.lines[0].get_xdata()) for c in points) == [6, 6]
    polygons = _drawn(feasible_polygons_figure(results["coupled"], "p", true_backlash=BACKLASH))
    for axes, letter in zip(polygons.axes, ("l", "r")):
        star = next(line for line in axes.get_lines() if line.get_label() == "true (m, m·c)")
        m_true = TRUE_VALUES[f"m_{letter}"]
        assert star.get_xdata()[0] == pytest.approx(m_true)
        assert star.get_ydata()[0] == pytest.approx(m_true * TRUE_VALUES[f"c_{letter}"])
        assert axes.patches, "the polygon is drawn filled"
        assert axes.get_xlabel() == f"slope m_{letter} [rad/rad]"


def test_inner_signal_figure_shows_bounds_invertible_samples_and_the_truth(results, experiment):
    _, _, u, _ = experiment
    inner = results["paper"].inner_signal
    true_x = LINEAR.apply(u)
    figure = _drawn(inner_signal_figure(results["paper"], "inner", sample_period_s=0.01, true_inner_rad=true_x))
    bounds_axes = figure.axes[0]
    truth = next(line for line in bounds_axes.get_lines() if line.get_label() == "true x_t")
    np.testing.assert_allclose(truth.get_ydata(), true_x)
    invertible = next(c for c in bounds_axes.containers if c.get_label() == "invertible samples (Prop. 2)")
    assert len(invertible.lines[0].get_xdata()) == inner.num_invertible
    with pytest.raises(ValueError, match="true_inner_rad: expected 60 samples"):
        inner_signal_figure(results["paper"], "inner", true_inner_rad=true_x[:10])


def test_interval_figure_has_one_panel_per_parameter_and_a_row_per_method(results):
    figure = _drawn(parameter_intervals_figure(results, "intervals", true_values=TRUE_VALUES))
    visible = [axes for axes in figure.axes if axes.get_visible()]
    assert len(visible) == 8
    for axes in visible:
        assert [label.get_text() for label in axes.get_yticklabels()] == ["paper", "coupled"]
    with pytest.raises(TypeError, match="expected an OutputBacklashIdentification or LinearBlockBounds"):
        parameter_intervals_figure({"json": {"a1": ParameterInterval(0.4, 0.6)}}, "i")


def test_bode_figure_draws_each_method_s_envelope_and_the_true_model(results):
    figure = _drawn(linear_block_bode_figure(results, "bode", sample_period_s=0.01, true_linear=LINEAR))
    magnitude_axes = figure.axes[0]
    labels = _labels(magnitude_axes)
    for method in ("paper", "coupled"):
        assert f"{method}: envelope over the box" in labels and f"{method}: central model θ^c" in labels
    assert "true G" in labels
    assert magnitude_axes.get_xlim()[1] >= 50.0 * 0.9  # Hz up to Nyquist of 10 ms
    # the envelope drawn is the result's own
    coupled = next(line for line in magnitude_axes.get_lines() if line.get_label() == "coupled: central model θ^c")
    omega = 2 * np.pi * np.asarray(coupled.get_xdata()) * 0.01
    np.testing.assert_allclose(coupled.get_ydata(), results["coupled"].linear.magnitude_envelope(omega).central_db)
    normalised = _drawn(linear_block_bode_figure(results["coupled"].linear, "bode_plain"))
    assert normalised.axes[1].get_xlabel() == "frequency [cycles/sample]"
    with pytest.raises(ValueError, match="no linear-block intervals"):
        empty = dataclasses.replace(results["coupled"].linear, explanation=EmptyLinearSetExplanation((), 0.0, "none"))
        linear_block_bode_figure({"empty": empty}, "none")


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
    assert result.backlash.explanation is not None  # the caption's reason is the result's own
    polygons = _drawn(figures[1])
    empty_sides = [axes for axes in polygons.axes if any("empty" in text.get_text() for text in axes.texts)]
    assert len(empty_sides) == sum(side.is_empty for side in (result.backlash.left, result.backlash.right)) >= 1
    assert not any(axes.patches for axes in empty_sides)
    assert unlabelled_axes(figures[0]) == []


def test_bode_figure_leaves_out_an_envelope_that_is_unbounded_at_most_frequencies(results):
    # a box wide enough in a1 to hold models with a pole on the unit circle at every frequency it reaches
    coupled = results["coupled"].linear
    wide = dataclasses.replace(coupled, intervals={**coupled.intervals, "a1": ParameterInterval(-3.0, 3.0),
                                                   "a2": ParameterInterval(-3.0, 3.0)})
    omega = 2 * np.pi * np.logspace(-3, np.log10(0.5), 50)
    assert wide.magnitude_envelope(omega).bounded_fraction < 0.5  # the premise of the test
    figure = _drawn(linear_block_bode_figure({"tight": coupled, "wide": wide}, "bode", true_linear=LINEAR))
    labels = _labels(figure.axes[0])
    assert "wide: envelope over the box" not in labels and "wide: central model θ^c" in labels
    tight_band = next(c for c in figure.axes[0].collections if c.get_label() == "tight: envelope over the box")
    # the band drawn reaches no further than the result's own envelope (it is drawn only where it is bounded)
    frequencies = np.asarray(next(line for line in figure.axes[0].get_lines()
                                  if line.get_label() == "tight: central model θ^c").get_xdata())
    envelope = coupled.magnitude_envelope(2 * np.pi * frequencies)
    band_y = np.concatenate([path.vertices[:, 1] for path in tight_band.get_paths()])
    finite = envelope.upper_db[envelope.bounded]
    assert band_y.max() <= finite.max() + 1e-9 and band_y.min() >= envelope.lower_db[envelope.bounded].min() - 1e-9


def test_interval_figure_draws_inner_bars_only_for_a_method_that_has_them(results):
    figure = _drawn(parameter_intervals_figure(results, "intervals", true_values=TRUE_VALUES))
    thick = [line for axes in figure.axes for line in axes.get_lines() if line.get_linewidth() >= 6.0]
    coupled = results["coupled"].linear
    verified = [name for name in (coupled.inner_lower or {})
                if np.isfinite(coupled.inner_lower[name]) and np.isfinite(coupled.inner_upper[name])]
    assert len(thick) == len(verified)
    # a method whose search for a verified point failed (NaN inner values) draws none
    failed = dataclasses.replace(coupled, inner_lower=dict.fromkeys(coupled.intervals, float("nan")),
                                 inner_upper=dict.fromkeys(coupled.intervals, float("nan")), inner_point=None)
    none_drawn = _drawn(parameter_intervals_figure({"coupled": failed}, "failed"))
    assert not [line for axes in none_drawn.axes for line in axes.get_lines() if line.get_linewidth() >= 6.0]
    paper_only = _drawn(parameter_intervals_figure({"paper": results["paper"]}, "paper_only"))
    assert not [line for axes in paper_only.axes for line in axes.get_lines() if line.get_linewidth() >= 6.0]


def test_a_bound_the_data_did_not_tighten_is_named_as_the_prior_box():
    """Bounds on the edge of the a-priori box of a stable A(q^-1), |a_i| <= C(na, i), are the assumption, not
    the data's: the caption names them, and only them."""
    from rig.plots.set_membership import _intervals_caption

    intervals = {"paper": {"a1": ParameterInterval(-2.0, 0.7), "a2": ParameterInterval(0.5, 1.0),
                           "b1": ParameterInterval(1.3, 1.5)},
                 "coupled": {"a1": ParameterInterval(0.4, 0.6), "a2": ParameterInterval(0.6, 0.8),
                             "b1": ParameterInterval(1.35, 1.45)}}
    caption = _intervals_caption(intervals, {"paper": None, "coupled": None}, ["a1", "a2", "b1"], {})
    assert "a-priori stability box |a_i| <= C(na, i), not the data's: paper a1 lower (-2), paper a2 upper (1)" in caption
    assert "coupled a" not in caption.split("not the data's:")[1] and "Look for" not in caption


def test_the_interval_caption_says_how_tight_each_verified_guarantee_is(results):
    caption = parameter_intervals_figure(results, "intervals", true_values=TRUE_VALUES).caption
    ratios = results["coupled"].linear.outer_inner_ratio
    assert ratios is not None and all(ratio is not None and ratio >= 1.0 - 1e-9 for ratio in ratios.values())
    assert "outer/inner (how many times wider than the verified span the guarantee is; 1: exact) " + " ".join(
        f"{name} {ratio:.3g}" for name, ratio in ratios.items()) in caption
    assert results["paper"].linear.outer_inner_ratio is None  # no verified inner values: nothing claimed


def test_the_half_width_axis_of_the_inner_signal_figure_labels_a_few_round_values(results):
    """Within a decade the log axis labelled every minor tick (6x10^1, 4x10^1, 3x10^1, ...) on top of each other."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    figure = _drawn(inner_signal_figure(results["paper"], "inner", sample_period_s=0.01))
    FigureCanvasAgg(figure).draw()
    width_axes = figure.axes[1]
    low, high = width_axes.get_ylim()
    labels = [tick.get_text() for tick in width_axes.get_yticklabels(minor=False) + width_axes.get_yticklabels(minor=True)
              if tick.get_text() and low <= tick.get_position()[1] <= high]
    assert 1 <= len(labels) <= 7, labels
    assert all(float(text) / 10 ** np.floor(np.log10(float(text))) in (1.0, 2.0, 5.0) for text in labels), labels


# The intervals `rig demo --quick` found for the precision gearbox (na = 4, nk = 2, nb = 5): a paper-method box
# whose central model is 12 dB low, a coupled one on the true curve; the true G has a double zero at z = -1.
DEMO_INTERVALS = {
    "paper": {"a1": (-4, -2.105), "a2": (1.5522, 6), "a3": (-4, -0.0755), "a4": (-0.31978, 1),
              "b2": (-0.065431, 0.066787), "b3": (-0.059558, 0.074443), "b4": (-0.067433, 0.066342),
              "b5": (-0.06788, 0.065879)},
    "coupled": {"a1": (-3.2168, -3.1396), "a2": (4.1464, 4.331), "a3": (-2.8792, -2.7038), "a4": (0.7143, 0.77955),
                "b2": (-0.0021896, 0.0059428), "b3": (2.9733e-05, 0.015171), "b4": (-0.0032461, 0.011491),
                "b5": (-0.002399, 0.0073905)},
}


def test_bode_figure_shows_every_curve_whole_and_names_what_falls_to_minus_infinity():
    from pathlib import Path

    from plot_checks import lines_beyond_limits

    from identify.linear_block_bounds import LinearBlockBounds, LinearModelOrders
    from rig.demo_outcome import true_gearbox
    from sim_backend.plant_config import load_plant_config

    plant = load_plant_config(Path(__file__).resolve().parents[2] / "configs" / "plants" / "precision_gearbox.toml")
    truth = true_gearbox(plant.plant).linear
    bounds = {method: LinearBlockBounds(method=method, orders=LinearModelOrders(4, 2, 5),
                                        intervals={name: ParameterInterval(*ends) for name, ends in box.items()})
              for method, box in DEMO_INTERVALS.items()}
    report_figure = linear_block_bode_figure(bounds, "bode", sample_period_s=truth.sample_period_s, true_linear=truth)
    assert lines_beyond_limits(report_figure) == []
    # |G_true| falls to -inf dB at the Nyquist frequency (its zeros at z = -1): the figure cuts it and says where
    figure = _drawn(report_figure)
    said = " ".join(text.get_text() for axes in figure.axes for text in [axes.title, axes._right_title, *axes.texts])
    assert re.search(r"true G below -\d+ dB from 4\d\d Hz", said), said
    assert re.search(r"true G below -\d+ dB from 4\d\d Hz", report_figure.caption), report_figure.caption
    # neither box's envelope is bounded enough to draw: the caption does not send the reader looking for one
    assert "no envelope drawn" in report_figure.caption and "narrow envelope" not in report_figure.caption
