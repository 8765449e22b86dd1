"""Checks shared by the figure tests: every axis of a figure is labelled with a unit."""

from __future__ import annotations

import re

from rig.report import ReportFigure

_UNIT = re.compile(r"\[[^\]]+\]")


def unlabelled_axes(report_figure: ReportFigure) -> list[str]:
    """Draw the figure off-screen and list the visible axes whose x or y label lacks a ``[unit]``."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figure = Figure(figsize=report_figure.size_in, layout="constrained")
    report_figure.draw(figure)
    problems = []
    for index, axes in enumerate(figure.axes):
        if not axes.get_visible():
            continue
        shares_x = any(other is not axes and axes in other.get_shared_x_axes().get_siblings(other)
                       for other in figure.axes)
        x_label, y_label = axes.get_xlabel(), axes.get_ylabel()
        # Stacked panels with a shared time axis label only the bottom one.
        if not _UNIT.search(x_label) and not (shares_x and not axes.get_subplotspec().is_last_row()):
            problems.append(f"{report_figure.name} axes {index}: x label {x_label!r}")
        if not _UNIT.search(y_label):
            problems.append(f"{report_figure.name} axes {index}: y label {y_label!r}")
    return problems
