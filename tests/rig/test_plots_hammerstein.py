"""Figures of a Hammerstein model identified by subspace on a short noise-free simulation (Pouliquen 2013)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from plot_checks import unlabelled_axes

from identify.border_lifting import PathNodes
from identify.cyclic_excitation import cyclic_random_excitation
from identify.hammerstein_subspace import HammersteinModel, identify_hammerstein
from identify.plant_blocks import LinearBlock, PlantModel, pouliquen2013_backlash
from rig.plots.hammerstein import borders_figure, hammerstein_figures, poles_figure, singular_values_figure
from rig.report import ReportSection, missing_images, write_report

G = LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=0.01)
BACKLASH = pouliquen2013_backlash()
TRUE_POLES = np.roots([1.0, -1.8858, 0.9048])
U_MIN, U_MAX = -3.0, 3.0


def true_ascending(u: float) -> float:
    """The path travelled from rest at u_min: the output stays at H_d(u_min) until H_a reaches it."""
    return max(BACKLASH.ascending(u), BACKLASH.descending(U_MIN))


def true_descending(u: float) -> float:
    return min(BACKLASH.descending(u), BACKLASH.ascending(U_MAX))


@pytest.fixture(scope="module")
def model():
    u = cyclic_random_excitation(1200, U_MIN, U_MAX, hold_samples=50, rng=0)
    y = PlantModel((BACKLASH, G)).simulate(u)
    return identify_hammerstein(u, y, PathNodes.uniform(U_MIN, U_MAX, 8), hold_samples=50)


def _drawn(report_figure):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=report_figure.size_in, layout="constrained")
    report_figure.draw(figure)
    return figure


def test_poles_figure_draws_the_identified_and_the_true_poles_inside_the_unit_circle(model):
    figure = _drawn(poles_figure(model, "poles", true_poles=TRUE_POLES, sample_period_s=0.01))
    whole, zoom = figure.axes
    lines = {line.get_label(): line for line in whole.get_lines()}
    identified = lines["identified poles"].get_xdata() + 1j * lines["identified poles"].get_ydata()
    np.testing.assert_allclose(np.sort_complex(identified), np.sort_complex(model.poles))
    true = lines["true poles"].get_xdata() + 1j * lines["true poles"].get_ydata()
    np.testing.assert_allclose(np.sort_complex(true), np.sort_complex(TRUE_POLES))
    assert model.stable and model.pole_distance(TRUE_POLES) < 2e-3  # the numbers the caption formats
    # The true poles' natural frequency: |ln p| / (2 pi T) = 2.25 Hz.
    np.testing.assert_allclose(model.natural_frequencies_hz(0.01), [2.25], atol=0.01)
    low, high = zoom.get_xlim()
    assert low <= float(np.min(true.real)) and float(np.max(true.real)) <= high and high - low < 1.0


def test_borders_figure_draws_the_paths_and_their_gap_against_the_truth(model):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    report_figure = borders_figure(model, "borders", true_ascending=true_ascending, true_descending=true_descending)
    figure = Figure(figsize=report_figure.size_in, layout="constrained")
    report_figure.draw(figure)
    paths_axes, gap_axes = figure.axes
    lines = {line.get_label(): line for line in paths_axes.get_lines()}
    np.testing.assert_allclose(lines["ascending path P_a"].get_ydata(), model.ascending_border.values)
    nodes_u = np.asarray(model.ascending_border.nodes_u)
    true_at_nodes = np.array([true_ascending(float(u)) for u in nodes_u])
    assert np.max(np.abs(lines["ascending path P_a"].get_ydata() - true_at_nodes)) < 0.1
    gaps = {line.get_label(): line for line in gap_axes.get_lines()}
    gap = np.asarray(gaps["P_d - P_a at the nodes"].get_ydata()) * 1e-3
    play = model.play_at_nodes()
    np.testing.assert_allclose(gap, play.gaps_rad)
    assert float(np.max(gap)) == pytest.approx(model.largest_play_rad)  # the same reading as identify's
    assert play.lowest_rad <= play.median_rad <= play.highest_rad
    true_gaps = np.array([true_descending(float(u)) - true_ascending(float(u)) for u in play.nodes_rad])
    np.testing.assert_allclose(play.gaps_rad, true_gaps, atol=0.1)
    # The play at the output: the true paths are arctan(u + 1) - arctan(u - 1) apart at u = 0, i.e. 1.57 rad.
    true_gap = gaps["true gap"]
    assert np.interp(0.0, true_gap.get_xdata(), true_gap.get_ydata()) * 1e-3 == pytest.approx(np.pi / 2, abs=1e-3)
    assert model.largest_play_rad == pytest.approx(np.pi / 2, abs=0.1)
    # the caption states the comparison the figure shows, computed from the same paths, and invites no check
    true_play = max(true_descending(float(u)) - true_ascending(float(u)) for u in nodes_u)
    caption = report_figure.caption
    assert f"against the true play's {true_play * 1e3:.3g} mrad" in caption and "Look for" not in caption
    assert f"{100 * (model.largest_play_rad / true_play - 1):+.0f} %" in caption


def test_singular_values_figure_marks_the_order_at_the_gap(model):
    figure = _drawn(singular_values_figure(model, "sv"))
    axes = figure.axes[0]
    lines = {line.get_label(): line for line in axes.get_lines()}
    np.testing.assert_allclose(lines["kept (order 2)"].get_ydata(), model.singular_values[:2])
    assert lines["chosen order"].get_xdata()[0] == pytest.approx(2.5)
    assert model.singular_values[1] / model.singular_values[2] > 10


def test_figures_of_a_saved_and_reopened_model_match_the_model_and_a_dictionary_is_refused(model):
    reopened = HammersteinModel.from_dict(json.loads(json.dumps(model.to_dict())))
    for make in (poles_figure, borders_figure, singular_values_figure):
        assert make(reopened, "from_json").caption == make(model, "from_model").caption
    with pytest.raises(TypeError, match="expected a HammersteinModel"):
        poles_figure(model.to_dict(), "bad")


def test_every_figure_renders_with_units_and_no_missing_image(model, tmp_path):
    figures = hammerstein_figures(model, "h_", true_poles=TRUE_POLES, true_ascending=true_ascending,
                                  true_descending=true_descending, sample_period_s=0.01)
    assert [f.name for f in figures] == ["h_poles", "h_borders", "h_singular_values"]
    assert [problem for figure in figures for problem in unlabelled_axes(figure)] == []
    index = write_report(tmp_path, "Hammerstein", [ReportSection("Hammerstein", figures=tuple(figures))])
    assert missing_images(index) == []
