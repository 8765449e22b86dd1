"""Figures of the model-discrepancy workflow, drawn from a real diagnosis of a simulated hidden backlash."""

from __future__ import annotations

import numpy as np
import pytest
from plot_checks import legends_over_data, unlabelled_axes

from identify.discrepancy_cases import hidden_effect_record
from identify.model_discrepancy import diagnose_model
from rig.plots.discrepancy import ZOOM_SAMPLES, comparison_figure, windows_figure


@pytest.fixture(scope="module")
def diagnosis():
    record = hidden_effect_record(("backlash",), 3, num_samples=1200)  # long enough for the zoom (> 5 x 200)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            record.nominal_model)
    return record, result, np.arange(record.command_rad.size) * record.sample_period_s


def _drawn(report_figure):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=report_figure.size_in, layout="constrained")
    report_figure.draw(figure)
    return figure


def test_a_long_free_run_is_also_drawn_over_a_window_of_the_validation_segment(diagnosis):
    record, result, time_s = diagnosis
    report_figure = comparison_figure(result, record.angle_rad, time_s)
    assert unlabelled_axes(report_figure) == []
    figure = _drawn(report_figure)
    assert len(figure.axes) == 4
    zoom_top = figure.axes[1]
    measured = next(line for line in zoom_top.get_lines() if line.get_label() == "measured")
    start = result.estimation_samples
    np.testing.assert_allclose(measured.get_xdata(), time_s[start:start + ZOOM_SAMPLES])
    np.testing.assert_allclose(measured.get_ydata(), record.angle_rad[start:start + ZOOM_SAMPLES])
    zoom_residual = figure.axes[3]
    final = next(line for line in zoom_residual.get_lines() if line.get_label() == "final model")
    np.testing.assert_allclose(final.get_ydata(), result.final.residual_rad[start:start + ZOOM_SAMPLES])


def test_the_legend_of_the_comparison_hides_no_data(diagnosis):
    """A square wave fills its panel from edge to edge: a legend inside it covered the measured angle."""
    from identify.plant_blocks import LinearBlock, PlantModel

    record, result, time_s = diagnosis
    assert legends_over_data(comparison_figure(result, record.angle_rad, time_s)) == []
    nominal = LinearBlock(a=(-1.73691838, 0.76805512), b=(0.0, 0.01625312, 0.01488362), sample_period_s=0.001)
    square = 0.01 * np.sign(np.sin(np.arange(3000) / 37.0))
    angle = nominal.apply(square) + 0.004 + np.random.default_rng(1).uniform(-2e-4, 2e-4, square.size)
    filled = diagnose_model(square, angle, 0.001, 0.001, PlantModel((nominal,)))
    assert legends_over_data(comparison_figure(filled, angle, np.arange(square.size) * 0.001)) == []


def test_with_nothing_added_the_model_is_drawn_once_and_the_caption_says_so(diagnosis):
    """With no effect added the final model is the start model: its dashed green line lay exactly over the red
    one and hid it, and the caption spoke of a final model and a gap after."""
    import dataclasses

    record, result, time_s = diagnosis
    nothing = dataclasses.replace(result, steps=(), final=result.initial)
    report_figure = comparison_figure(nothing, record.angle_rad, time_s)
    figure = _drawn(report_figure)
    for axes in figure.axes:
        labels = [line.get_label() for line in axes.get_lines() if not line.get_label().startswith("_")]
        assert "final model" not in labels and "model (nothing added)" in labels
    assert "nothing was added, so the start model is the final one" in report_figure.caption
    assert "after" not in report_figure.caption
    drawn = comparison_figure(result, record.angle_rad, time_s)  # with the play added: both models
    assert "final model (green, dashed)" in drawn.caption


def test_windows_that_cover_most_of_the_record_are_not_called_a_cluster(diagnosis):
    """A hidden backlash makes the start model miss at nearly every reversal: its windows of falsified samples
    cover nearly the whole record, and the caption says so instead of pointing at a cluster."""
    record, result, time_s = diagnosis
    covered = sum(window.stop - window.start for window in result.initial.windows) / record.command_rad.size
    assert covered > 0.9  # the premise
    caption = windows_figure(result, time_s).caption
    assert f"cover {100 * covered:.0f} % of the record: they do not cluster" in caption, caption
    assert "where they cluster" not in caption



def test_a_diagnosis_on_restarted_windows_is_not_captioned_as_a_free_run(diagnosis):
    import dataclasses

    record, result, time_s = diagnosis
    assert "free-run simulation" in comparison_figure(result, record.angle_rad, time_s).caption
    restarted = dataclasses.replace(result, restart_window_samples=50)
    caption = comparison_figure(restarted, record.angle_rad, time_s).caption
    assert "free-run" not in caption and "run restarted from the measured angle every 50 samples" in caption
