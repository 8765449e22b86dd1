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


def legends_over_data(report_figure: ReportFigure) -> list[str]:
    """Draw the figure off-screen and list every legend (of an axes or of the figure) that covers points of a
    labelled line in any axes (the lines a legend names are the data; unlabelled ones are guides such as the
    noise bound): a legend must not hide data."""
    import matplotlib

    matplotlib.use("Agg")
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=report_figure.size_in, layout="constrained")
    report_figure.draw(figure)
    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    renderer = canvas.get_renderer()
    legends = [(f"axes {index}", axes.get_legend()) for index, axes in enumerate(figure.axes)] + \
              [("figure", legend) for legend in figure.legends]
    problems = []
    for where, legend in legends:
        if legend is None or not legend.get_visible():
            continue
        box = legend.get_window_extent(renderer)
        for index, axes in enumerate(figure.axes):
            for line in axes.lines:
                points = line.get_transform().transform(np.asarray(line.get_xydata(), dtype=float))
                points = points[np.all(np.isfinite(points), axis=1)]
                covered = int(np.count_nonzero((points[:, 0] >= box.x0) & (points[:, 0] <= box.x1)
                                               & (points[:, 1] >= box.y0) & (points[:, 1] <= box.y1)))
                if covered and not line.get_label().startswith("_"):
                    problems.append(f"{report_figure.name}: the legend of the {where} covers {covered} of "
                                    f"{len(points)} points of {line.get_label()!r} in axes {index}")
    return problems


def lines_beyond_limits(report_figure: ReportFigure) -> list[str]:
    """Draw the figure off-screen and list every line whose data reach beyond its axes' limits (a figure must
    show the whole of each curve it draws; what it leaves out it must not draw at all, and say so)."""
    import matplotlib

    matplotlib.use("Agg")
    import numpy as np
    from matplotlib.figure import Figure

    figure = Figure(figsize=report_figure.size_in, layout="constrained")
    report_figure.draw(figure)
    problems = []
    for index, axes in enumerate(figure.axes):
        (x_low, x_high), (y_low, y_high) = sorted(axes.get_xlim()), sorted(axes.get_ylim())
        for line in axes.lines:
            if line.get_transform() != axes.transData:  # a guide across the axes (axhline), not data
                continue
            x, y = (np.asarray(values, dtype=float) for values in (line.get_xdata(), line.get_ydata()))
            shown = np.isfinite(x) & np.isfinite(y)
            outside = shown & ((y < y_low) | (y > y_high) | (x < x_low) | (x > x_high))
            if np.any(outside):
                problems.append(f"{report_figure.name} axes {index}: {np.count_nonzero(outside)} points of "
                                f"{line.get_label()!r} lie outside y {y_low:.3g}..{y_high:.3g} (they span "
                                f"{np.min(y[shown]):.3g}..{np.max(y[shown]):.3g})")
    return problems
