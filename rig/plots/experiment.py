"""Figures of a captured experiment: the signals, and the timing of the sample loop."""

from __future__ import annotations

import numpy as np

from identify.experiment_record import ExperimentRecord, SampleFlag
from rig.report import ReportFigure


def signal_figure(record: ExperimentRecord, name: str) -> ReportFigure:
    """Command and measured load angle against time, with unusable samples marked."""

    def draw(figure) -> None:
        command_axes, angle_axes = figure.subplots(2, 1, sharex=True)
        command_axes.plot(record.time_s, record.command_rad, lw=0.8, color="tab:blue")
        command_axes.set_ylabel("command u [rad]")
        angle_axes.plot(record.time_s, record.angle_rad, lw=0.8, color="tab:green")
        unusable = ~record.valid_mask
        if np.any(unusable):
            for time_s in record.time_s[unusable]:
                angle_axes.axvline(time_s, color="tab:red", lw=0.5, alpha=0.6)
        angle_axes.set_ylabel("load angle y [rad]")
        angle_axes.set_xlabel("time [s]")

    lost = record.lost_count
    return ReportFigure(
        name, f"{record.metadata.excitation or 'experiment'}: command (top) and measured load angle (bottom) "
        f"over {len(record)} samples; red lines mark the {int(np.count_nonzero(~record.valid_mask))} unusable "
        f"samples ({lost} lost). Look for a clean response with no gaps.", draw, size_in=(7.0, 4.5))


def timing_figure(record: ExperimentRecord, name: str) -> ReportFigure:
    """Deviation of each sample period from the nominal one, over time and as a histogram."""
    nominal_s = record.sample_period_s
    deviation_us = (np.diff(record.time_s) - nominal_s) * 1e6
    late = record.count_flag(SampleFlag.LATE)
    p99 = float(np.percentile(np.abs(deviation_us), 99)) if deviation_us.size else 0.0

    def draw(figure) -> None:
        trace_axes, histogram_axes = figure.subplots(1, 2, width_ratios=(2, 1))
        trace_axes.plot(record.time_s[1:], deviation_us, lw=0.6)
        late_mask = (record.flags[1:] & SampleFlag.LATE) != 0
        trace_axes.plot(record.time_s[1:][late_mask], deviation_us[late_mask], "r.", ms=3, label="late")
        trace_axes.set_xlabel("time [s]")
        trace_axes.set_ylabel("period - nominal [us]")
        if np.any(late_mask):
            trace_axes.legend(loc="upper right")
        histogram_axes.hist(deviation_us, bins=40, orientation="horizontal", color="tab:gray")
        histogram_axes.set_xlabel("samples [-]")
        histogram_axes.set_ylabel("period - nominal [us]")

    return ReportFigure(
        name, f"Sample-period jitter against the nominal {nominal_s * 1e3:g} ms: p99 |deviation| = {p99:.0f} us, "
        f"{late} late cycles. Look for a narrow band around zero and no late cycles.", draw)
