"""The figure of ``rig trend``: the guaranteed bounds on the play, window by window, as a band over time.

It draws a :class:`identify.backlash_trend.BacklashTrend` and, when known, the true play of a simulation
(:class:`rig.truth_file.PlayTruth`); it computes nothing a test should check as a number.
"""

from __future__ import annotations

from identify.backlash_trend import BacklashTrend
from rig.report import ReportFigure
from rig.truth_file import PlayTruth

__all__ = ["trend_figure"]

MAX_TRUTH_POINTS = 4000
"""The truth line is drawn through at most this many of its rows (a line is all the figure's width shows)."""


def _time_scale(span_s: float) -> tuple[float, str]:
    if span_s >= 3 * 3600:
        return 3600.0, "h"
    if span_s >= 180:
        return 60.0, "min"
    return 1.0, "s"


def trend_figure(trend: BacklashTrend, name: str, truth: PlayTruth | None = None) -> ReportFigure:
    """The play's bounds per window as a band (one step per window), the windows that cannot bound it
    shaded grey, the windows with an empty feasible set red, and the true play as a line when given."""
    windows = trend.windows
    span = (windows[-1].end_s - windows[0].start_s) if windows else 1.0
    scale, unit = _time_scale(span)

    def draw(figure) -> None:
        axes = figure.add_subplot(1, 1, 1)
        labelled = {"band": False, "grey": False, "red": False}
        for window in windows:
            start, end = window.start_s / scale, window.end_s / scale
            if window.play_rad is not None:
                axes.fill_between([start, end], [window.play_rad.lower] * 2, [window.play_rad.upper] * 2,
                                  color="tab:blue", alpha=0.35, lw=0,
                                  label=None if labelled["band"] else "guaranteed bounds on the play")
                labelled["band"] = True
            elif window.status == "empty":
                axes.axvspan(start, end, color="tab:red", alpha=0.2, lw=0,
                             label=None if labelled["red"] else "empty feasible set")
                labelled["red"] = True
            else:
                axes.axvspan(start, end, color="0.6", alpha=0.25, lw=0,
                             label=None if labelled["grey"] else "cannot bound (see the table)")
                labelled["grey"] = True
        if truth is not None and truth.time_s.size:
            step = max(1, truth.time_s.size // MAX_TRUTH_POINTS)
            axes.step(truth.time_s[::step] / scale, truth.play_rad[::step], where="post", color="black", lw=1.0,
                      label="true play (simulation)")
        axes.set_xlabel(f"time [{unit}]")
        axes.set_ylabel("play c_l + c_r [rad]")
        allowance = f" + wear allowance {trend.wear_allowance_rad:.3g}" if trend.wear_allowance_rad else ""
        axes.set_title(f"play per {trend.window_s:g} s window, noise bound {trend.noise_bound_rad:.3g}{allowance} rad")
        axes.grid(True, alpha=0.3)
        axes.legend(loc="upper left", fontsize="small")

    bounded = len(trend.bounded)
    inside, judged = trend.truth_inside_count
    caption = (f"Guaranteed bounds on the total play c_l + c_r in each of {len(windows)} windows of "
               f"{trend.window_s:g} s ({bounded} bounded; Cerone et al. 2009, eqs. (11)-(20)). A band that rises "
               "is play that grows with wear.")
    if judged:
        caption += f" The true play (line) meets the bounds in {inside} of {judged} windows."
    return ReportFigure(name, caption, draw, size_in=(8.0, 4.0))
