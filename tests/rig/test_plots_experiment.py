import numpy as np
import pytest
from plot_checks import unlabelled_axes

from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag
from rig.plots.experiment import signal_figure, timing_figure
from rig.report import ReportSection, missing_images, write_report


def make_record(time_s=None, command=None):
    n = 200 if command is None else command.size
    if time_s is None:
        time_s = np.arange(n) * 1e-3
    flags = np.zeros(n, dtype=np.uint8)
    flags[50] = SampleFlag.LOST
    flags[80] = SampleFlag.LATE
    flags[[90, 91]] = SampleFlag.HELD | SampleFlag.LATE
    angle = np.sin(time_s * 20)
    angle[50] = np.nan
    if command is None:
        command = np.sign(np.sin(time_s * 30))
    return ExperimentRecord(time_s, command, angle, None, flags,
                            ExperimentMetadata(sample_period_s=1e-3, excitation="prbs"))


def _drawn(report_figure):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=report_figure.size_in, layout="constrained")
    report_figure.draw(figure)
    return figure


def test_a_log_on_the_device_clock_shows_its_flags_and_the_lead_not_rounding_noise():
    # k·T computed as a device-clocked log writes it: spacing equal to T up to float64 rounding
    record = make_record(np.cumsum(np.full(200, 1e-3)) - 1e-3)
    assert record.time_column_is_nominal()
    figure = _drawn(timing_figure(record, "timing", lead_s=0.1, min_lead_s=0.0973))
    flag_axes, lead_axes = figure.axes
    # one row for HELD and LATE, and for each other flag that occurs (here LOST), in TIMING_FLAGS order
    assert [label.get_text() for label in flag_axes.get_yticklabels()] == ["HELD (2)", "LATE (3)", "LOST (1)"]
    events = dict(zip((SampleFlag.HELD, SampleFlag.LATE, SampleFlag.LOST),
                      (collection.get_positions() for collection in flag_axes.collections)))
    np.testing.assert_allclose(events[SampleFlag.HELD], record.time_s[[90, 91]])
    np.testing.assert_allclose(events[SampleFlag.LATE], record.time_s[[80, 90, 91]])
    np.testing.assert_allclose(events[SampleFlag.LOST], record.time_s[[50]])
    assert [bar.get_height() for bar in lead_axes.patches] == pytest.approx([100.0, 97.3])
    assert unlabelled_axes(timing_figure(record, "timing", lead_s=0.1, min_lead_s=0.0973)) == []
    # without a lead (a host-paced log read back by `rig report`) only the flags are drawn
    assert len(_drawn(timing_figure(record, "timing")).axes) == 1


def test_a_measured_time_column_shows_its_period_deviation():
    time_s = np.arange(200) * 1e-3 + np.r_[0.0, np.full(199, 2e-6)]
    record = make_record(time_s)
    assert not record.time_column_is_nominal()
    figure = _drawn(timing_figure(record, "timing"))
    trace = figure.axes[0].get_lines()[0]
    np.testing.assert_allclose(trace.get_ydata(), (np.diff(time_s) - 1e-3) * 1e6)


def test_a_command_that_reverses_often_is_also_drawn_over_a_window():
    rng = np.random.default_rng(0)
    command = np.repeat(rng.choice([-2.0, 2.0], 300), 5)  # a cyclic-like command: 1500 samples, ~150 reversals
    figure = _drawn(signal_figure(make_record(command=command), "cyclic"))
    full_command, zoom_command = figure.axes[0], figure.axes[1]
    assert len(figure.axes) == 4
    zoom_x = np.asarray(zoom_command.get_lines()[0].get_xdata())
    assert zoom_x[-1] < 0.5 * full_command.get_lines()[0].get_xdata()[-1]  # a window, not the whole record
    first = int(round(zoom_x[0] / 1e-3))
    np.testing.assert_array_equal(zoom_command.get_lines()[0].get_ydata(), command[first: first + zoom_x.size])
    reversals = np.count_nonzero(np.diff(np.sign(np.diff(command[first: first + zoom_x.size]))[
        np.diff(command[first: first + zoom_x.size]) != 0]) != 0)
    assert 15 <= reversals <= 25  # a window of about 20 reversals: each step reads
    assert len(_drawn(signal_figure(make_record(), "prbs")).axes) == 2  # a slow command needs no window


def test_a_log_with_the_drive_torque_shows_it_in_a_third_panel_with_its_unit():
    import dataclasses

    record = make_record()
    torque = np.round(300 * np.cos(record.time_s * 20))
    record = dataclasses.replace(record, drive_torque=torque, metadata=ExperimentMetadata(
        sample_period_s=1e-3, excitation="prbs", extra={"drive_torque_unit": "permille_of_rated_torque"}))
    report_figure = signal_figure(record, "signals")
    figure = _drawn(report_figure)
    assert len(figure.axes) == 3 and not unlabelled_axes(report_figure)
    np.testing.assert_array_equal(figure.axes[2].get_lines()[0].get_ydata(), torque)
    assert "permille of rated torque" in figure.axes[2].get_ylabel()
    assert "the drive's torque (bottom, permille of rated torque)" in report_figure.caption


def test_experiment_figures_render(tmp_path):
    record = make_record()
    figures = (signal_figure(record, "signals"), timing_figure(record, "timing", lead_s=0.1, min_lead_s=-0.002))
    index = write_report(tmp_path, "Experiment", [ReportSection("Run", figures=figures)])
    assert missing_images(index) == []


def test_the_timing_of_several_runs_shows_each_run_s_flags_and_leads():
    from rig.plots.experiment import RunTiming, runs_timing_figure

    flagged = make_record()
    clean = ExperimentRecord(flagged.time_s, flagged.command_rad, np.sin(flagged.time_s), None,
                             np.zeros(len(flagged), dtype=np.uint8), flagged.metadata)
    runs = [RunTiming("staircase", clean, 0.1, 0.0158), RunTiming("cyclic", flagged, 0.1, -0.002),
            RunTiming("old log", clean)]
    report_figure = runs_timing_figure(runs, "timing")
    assert unlabelled_axes(report_figure) == []
    flag_axes, lead_axes = _drawn(report_figure).axes
    ticks = {line.get_label(): line for line in flag_axes.get_lines() if line.get_marker() == "|"}
    np.testing.assert_allclose(ticks["HELD"].get_xdata(), flagged.time_s[[90, 91]])
    assert set(ticks["HELD"].get_ydata()) == {1}  # on the cyclic row only
    assert set(ticks) == {"HELD", "LATE", "LOST"}
    queued = [bar.get_width() for bar in lead_axes.patches[:3]]
    smallest = [bar.get_width() for bar in lead_axes.patches[3:]]
    assert queued == pytest.approx([100.0, 100.0, 0.0]) and smallest == pytest.approx([15.8, -2.0])


def test_a_timing_caption_says_what_its_figure_shows():
    """The caption is computed from the log it describes: with flagged samples it counts them and says they
    are set aside, never 'look for none'; without, it says every sample was taken at its instant."""
    from rig.plots.experiment import RunTiming, runs_timing_figure

    flagged = make_record(np.cumsum(np.full(200, 1e-3)) - 1e-3)
    caption = timing_figure(flagged, "timing", lead_s=0.1, min_lead_s=0.0973).caption
    assert "4 of 200" in caption and "These 4 samples are set aside" in caption and "Look for no" not in caption
    clean = ExperimentRecord(flagged.time_s, flagged.command_rad, np.sin(flagged.time_s), None,
                             np.zeros(len(flagged), dtype=np.uint8), flagged.metadata)
    assert "Every sample was taken at its instant" in timing_figure(clean, "timing", lead_s=0.1).caption
    several = runs_timing_figure([RunTiming("cyclic", flagged, 0.1, -0.002)], "timing").caption
    assert "Look for no ticks" not in several and "set aside" in several
    measured = make_record(np.arange(200) * 1e-3 + np.r_[0.0, np.full(199, 2e-6)])
    assert "3 late samples (red:" in timing_figure(measured, "timing").caption
