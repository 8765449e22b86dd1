"""Figures of the set-membership identification of a linear system with output backlash (Cerone, Piga and
Regruto 2009; :mod:`identify.output_backlash_identification`).

Each function takes a result and a figure name and returns a :class:`rig.report.ReportFigure` whose caption
says what to look for, with the numbers that matter; matplotlib is used only inside the drawing functions.

* :func:`backlash_characteristic_figure`: the lines w = m_r (x - c_r) and w = m_l (x + c_l) of every point of
  D_γ (eqs. (13)-(17)) as a band, and the steady-state points (ū, ȳ) with their noise intervals;
* :func:`feasible_polygons_figure`: D_γ^l and D_γ^r in the coordinates (m, m·c) where they are polygons;
* :func:`inner_signal_figure`: the bounds x_t^min <= x_t <= x_t^max of eq. (23), invertible samples
  (Proposition 2) marked;
* :func:`parameter_intervals_figure`: the intervals of eqs. (18)-(20) and of Section 5, per method, against
  the true values when known;
* :func:`linear_block_bode_figure` (from :mod:`rig.plots.linear_block_bode`): |G(e^{jω})| of the central
  model θ^c and its envelope over the parameter box.

Functions that only need intervals also take plain ``{name: ParameterInterval}`` mappings, so that
``rig report`` can draw them from the JSON of ``rig identify output-backlash --json``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Union

import numpy as np
from numpy.typing import ArrayLike

from identify.feasible_parameter_set import (BacklashFeasibleSet, IntervalSetSummary, ParameterInterval,
                                            median_width_ratio)
from identify.inner_signal_bounds import InnerSignalBounds
from identify.linear_block_bounds import LinearBlockBounds
from identify.linear_block_response import linear_parameter
from identify.output_backlash_identification import OutputBacklashIdentification
from rig.plots.linear_block_bode import METHOD_COLOURS, IntervalSource, linear_block_bode_figure
from rig.report import ReportFigure, format_interval

__all__ = [
    "IntervalSource",
    "backlash_characteristic_figure",
    "default_result_figures",
    "feasible_polygons_figure",
    "inner_signal_figure",
    "linear_block_bode_figure",
    "parameter_intervals_figure",
    "parameter_sort_key",
    "parameter_unit",
]

_BACKLASH_ORDER = ("m_l", "c_l", "m_r", "c_r")


def parameter_unit(name: str) -> str:
    """Unit of a parameter of the output-backlash model: slopes m are rad/rad, dead bands c rad, a_i and b_j
    dimensionless (the linear block maps rad to rad)."""
    if name.startswith("m_"):
        return "rad/rad"
    if name.startswith("c_"):
        return "rad"
    return "-"


# ----------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------


def _backlash_set(result: OutputBacklashIdentification | BacklashFeasibleSet) -> BacklashFeasibleSet:
    if isinstance(result, OutputBacklashIdentification):
        return result.backlash
    if isinstance(result, BacklashFeasibleSet):
        return result
    raise TypeError(f"result: expected an OutputBacklashIdentification or a BacklashFeasibleSet, got "
                    f"{type(result).__name__}")


def _true_backlash(true_backlash: Any) -> dict[str, float] | None:
    """``{m_l, c_l, m_r, c_r}`` from an object with those attributes (e.g. plant_blocks.OutputBacklash) or a
    mapping; None stays None."""
    if true_backlash is None:
        return None
    if isinstance(true_backlash, Mapping):
        return {name: float(true_backlash[name]) for name in _BACKLASH_ORDER}
    fields = {"m_l": "m_l", "c_l": "c_l_rad", "m_r": "m_r", "c_r": "c_r_rad"}  # OutputBacklash's field names
    return {name: float(getattr(true_backlash, fields[name])) for name in _BACKLASH_ORDER}


def _interval_text(interval: ParameterInterval | None, unit: str = "") -> str:
    if interval is None:
        return "empty"
    return format_interval(interval.lower, interval.upper, unit=unit)


# ----------------------------------------------------------------------------------------------------------
# backlash characteristic and polygons
# ----------------------------------------------------------------------------------------------------------


def backlash_characteristic_figure(result: OutputBacklashIdentification | BacklashFeasibleSet, name: str, *,
                                   true_backlash: Any = None) -> ReportFigure:
    """The backlash characteristic w(x): the feasible band of D_γ and the steady-state points.

    Left panel: for each side, the band swept by the lines w = m_r x - p_r (right, eq. (11)) and
    w = m_l x + p_l (left, eq. (12)) over all (m, p) of the polygon D_γ^r, D_γ^l (eqs. (14)-(17)), and the
    2M steady-state points (ū_s, ȳ_s) with the interval ±(Δη̄ + α_s) that defines the strips. Right panel: the
    same relative to a central line of each side (the vertex mean), in mrad, where the band's width is visible.

    Parameters
    ----------
    result
        The identification result (its ``backlash``) or the feasible set itself; the steady-state points are
        read from its polygons.
    name
        File stem of the figure.
    true_backlash
        The true backlash (an object or mapping with ``m_l c_l m_r c_r``), drawn dashed when given.
    """
    backlash = _backlash_set(result)
    truth = _true_backlash(true_backlash)
    return ReportFigure(name, _characteristic_caption(backlash, truth), _characteristic_drawing(backlash, truth),
                        size_in=(9.0, 4.0))


_SIDE_COLOURS = {"left": "tab:blue", "right": "tab:orange"}


def _true_side_line(truth: Mapping[str, float], side: str) -> tuple[float, float]:
    """(m, p = m·c) of the true backlash on ``side``."""
    slope = truth[f"m_{side[0]}"]
    return slope, slope * truth[f"c_{side[0]}"]


def _characteristic_drawing(backlash: BacklashFeasibleSet, truth: Mapping[str, float] | None):
    """The drawing of :func:`backlash_characteristic_figure`: the full characteristic and its zoom."""
    sides = (backlash.left, backlash.right)
    reach = 1.1 * float(np.max(np.abs(np.concatenate([side.steady_input_rad for side in sides]))))
    x_full = np.linspace(-reach, reach, 200)

    def draw(figure) -> None:
        full_axes, zoom_axes = figure.subplots(1, 2)
        for side in sides:
            colour = _SIDE_COLOURS[side.side]
            centre = 0.5 * (side.strip_lower_rad + side.strip_upper_rad)
            half = 0.5 * (side.strip_upper_rad - side.strip_lower_rad)
            full_axes.errorbar(side.steady_input_rad, centre, yerr=half, fmt=".", ms=4, color=colour,
                               label=f"{side.side} half-wave points", capsize=2, lw=0.8)
            if side.is_empty:
                continue
            low, high = side.output_band(x_full)
            full_axes.fill_between(x_full, low, high, color=colour, alpha=0.35, lw=0.8, edgecolor=colour,
                                   label=f"{side.side} lines of D_γ")
            slope, offset = side.central_line()
            x_side = np.linspace(0.0, reach, 100) if side.side == "right" else np.linspace(-reach, 0.0, 100)
            reference = side.side_line(slope, offset, x_side)
            low, high = side.output_band(x_side)
            zoom_axes.fill_between(x_side, (low - reference) * 1e3, (high - reference) * 1e3, color=colour,
                                   alpha=0.35, lw=0, label=f"{side.side} band")
            point_reference = side.side_line(slope, offset, side.steady_input_rad)
            zoom_axes.errorbar(side.steady_input_rad, (centre - point_reference) * 1e3, yerr=half * 1e3, fmt=".",
                               ms=4, color=colour, capsize=2, lw=0.8)
            if truth is not None:
                zoom_axes.plot(x_side, (side.side_line(*_true_side_line(truth, side.side), x_side) - reference) * 1e3,
                               "k--", lw=0.9)
        if truth is not None:
            for side in sides:
                full_axes.plot(x_full, side.side_line(*_true_side_line(truth, side.side), x_full), "k--", lw=0.8,
                               label="true lines" if side.side == "left" else None)
        full_axes.axhline(0.0, color="0.7", lw=0.5)
        full_axes.axvline(0.0, color="0.7", lw=0.5)
        full_axes.set_xlabel("inner signal x [rad]")
        full_axes.set_ylabel("backlash output w [rad]")
        full_axes.legend(loc="upper left", fontsize=7)
        zoom_axes.axhline(0.0, color="0.7", lw=0.5)
        zoom_axes.set_xlabel("inner signal x [rad]")
        zoom_axes.set_ylabel("w - central line [mrad]")

    return draw


def _characteristic_caption(backlash: BacklashFeasibleSet, truth: Mapping[str, float] | None) -> str:
    """The caption of :func:`backlash_characteristic_figure`: band widths, intervals, where the truth lies."""
    count = int(backlash.left.steady_input_rad.size + backlash.right.steady_input_rad.size)
    alpha_max = float(np.max(backlash.alpha_rad)) if backlash.alpha_rad.size else 0.0
    widening = f" widened by α up to {alpha_max:.3g} rad (filter step known)" if alpha_max > 0 else ""
    if backlash.is_empty:
        assert backlash.explanation is not None
        state = (f"The feasible set is EMPTY: {backlash.explanation.message} Look for the conflicting points "
                 f"{list(backlash.explanation.conflicting_samples)} (indices of the steady-state points).")
    else:
        truth_text = ""
        if truth is not None:
            membership = backlash.contains(truth["m_l"], truth["c_l"], truth["m_r"], truth["c_r"])
            inside = [side for side, holds in membership.items() if holds]
            truth_text = (f" The true lines (dashed) are inside the band on {len(inside)} of 2 sides"
                          f"{' (' + ', '.join(inside) + ')' if inside else ''}.")
        left_mrad = backlash.left.band_width_at_largest_input_rad() * 1e3
        right_mrad = backlash.right.band_width_at_largest_input_rad() * 1e3
        state = (f"Band width at the largest amplitude: left {left_mrad:.3g} mrad, right {right_mrad:.3g} mrad; "
                 f"m_l in {_interval_text(backlash.m_l)}, c_l in {_interval_text(backlash.c_l, 'rad')}, m_r in "
                 f"{_interval_text(backlash.m_r)}, c_r in {_interval_text(backlash.c_r, 'rad')}.{truth_text} Look "
                 "for every error bar touching its band (it must, by construction) and for a band that narrows "
                 "where the points are dense.")
    return (f"Backlash characteristic w(x) (Cerone et al. 2009, eqs. (11)-(17)): shaded, every line of the "
            f"feasible set D_γ (exact, from the polygon vertices); dots, the {count} steady-state points with "
            f"their noise interval ±Δη = ±{backlash.noise_bound_rad:.3g} rad{widening}. Right: the same relative "
            f"to a central line of each side, in mrad. {state}")


def feasible_polygons_figure(result: OutputBacklashIdentification | BacklashFeasibleSet, name: str, *,
                             true_backlash: Any = None) -> ReportFigure:
    """D_γ^l and D_γ^r (eqs. (14)-(17)) as polygons in (m, m·c), with the true point when given.

    In these coordinates each steady-state point is a strip and each side of D_γ their intersection; the
    orthotope B_γ of eqs. (18)-(20) is the range of m and of c = p/m over the vertices.
    """
    backlash = _backlash_set(result)
    truth = _true_backlash(true_backlash)
    sides = (backlash.left, backlash.right)
    verdicts = []
    for side in sides:
        letter = side.side[0]
        if side.is_empty:
            verdicts.append(f"{side.side}: EMPTY")
            continue
        text = (f"{side.side}: {side.slope_vertices.size} vertices, m_{letter} in "
                f"{_interval_text(getattr(backlash, f'm_{letter}'))}, c_{letter} in "
                f"{_interval_text(getattr(backlash, f'c_{letter}'), 'rad')}")
        if truth is not None:
            inside = side.contains(truth[f"m_{letter}"], truth[f"m_{letter}"] * truth[f"c_{letter}"])
            text += f", true point {'inside' if inside else 'OUTSIDE'}"
        verdicts.append(text)

    def draw(figure) -> None:
        from matplotlib.ticker import MaxNLocator

        axes_pair = figure.subplots(1, 2)
        for axes, side, colour in zip(axes_pair, sides, ("tab:blue", "tab:orange")):
            letter = side.side[0]
            if not side.is_empty:
                m = np.r_[side.slope_vertices, side.slope_vertices[:1]]
                p = np.r_[side.slope_times_deadband_vertices, side.slope_times_deadband_vertices[:1]]
                axes.fill(m, p, color=colour, alpha=0.35, lw=0)
                axes.plot(m, p, "-o", color=colour, ms=3, lw=1.0, label=f"D_γ^{letter} vertices")
            else:
                axes.text(0.5, 0.5, f"{side.side} side: empty", ha="center", va="center", transform=axes.transAxes)
            if truth is not None:
                axes.plot(truth[f"m_{letter}"], truth[f"m_{letter}"] * truth[f"c_{letter}"], "k*", ms=10,
                          label="true (m, m·c)")
            axes.set_title(f"{side.side} side ({'negative' if letter == 'l' else 'positive'} half-waves)",
                           fontsize=9)
            axes.set_xlabel(f"slope m_{letter} [rad/rad]")
            axes.set_ylabel(f"m_{letter}·c_{letter} [rad]")
            axes.xaxis.set_major_locator(MaxNLocator(4))
            if axes.get_legend_handles_labels()[0]:  # an empty side without a true point has nothing to list
                axes.legend(loc="best", fontsize=7)

    caption = ("Feasible polygons of the backlash in (m, m·c) coordinates (Cerone et al. 2009, eqs. (14)-(17): "
               "each steady-state point is a strip, each side the intersection of its strips). "
               + "; ".join(verdicts) + ". Look for small polygons (tight bounds) and the true point inside.")
    return ReportFigure(name, caption, draw, size_in=(8.0, 3.8))


# ----------------------------------------------------------------------------------------------------------
# inner signal
# ----------------------------------------------------------------------------------------------------------


def inner_signal_figure(result: OutputBacklashIdentification | InnerSignalBounds, name: str, *,
                        sample_period_s: float | None = None, true_inner_rad: ArrayLike | None = None) -> ReportFigure:
    """Bounds on the unmeasured inner signal x_t over time (eq. (23)), invertible samples marked.

    Top: x_t^min..x_t^max; samples inverted through one backlash line (Proposition 2, eqs. (24)-(27)) as
    points with error bars, the others as the band between the two lines (the band bound of
    :mod:`identify.inner_signal_bounds`). Bottom: the half-width Δx_t of eq. (28) on a log scale.

    Parameters
    ----------
    result
        The identification result (its ``inner_signal``) or the bounds themselves.
    sample_period_s
        Time axis in seconds when given, else sample index.
    true_inner_rad
        The true x_t (simulation), drawn when given.
    """
    inner = result.inner_signal if isinstance(result, OutputBacklashIdentification) else result
    if not isinstance(inner, InnerSignalBounds):
        raise ValueError("result: the inner-signal bounds are missing (the backlash feasible set is empty)")
    count = int(inner.lower_rad.size)
    if sample_period_s is None:
        time_axis, time_label = np.arange(count, dtype=float), "sample t [-]"
    else:
        time_axis, time_label = np.arange(count) * float(sample_period_s), "time [s]"
    truth = None if true_inner_rad is None else np.asarray(true_inner_rad, dtype=float)
    if truth is not None and truth.shape != (count,):
        raise ValueError(f"true_inner_rad: expected {count} samples like the bounds, got shape {truth.shape}")
    invertible = np.asarray(inner.invertible, dtype=bool)
    half = inner.half_width_rad
    median_inv = inner.median_half_width_rad(invertible=True) * 1e3
    median_band = inner.median_half_width_rad(invertible=False) * 1e3
    truth_text = ""
    if truth is not None:
        inside = int(np.count_nonzero(inner.contains(truth)))
        truth_text = f" The true x_t (black) is inside the bounds at {inside} of {count} samples."

    def draw(figure) -> None:
        bound_axes, width_axes = figure.subplots(2, 1, sharex=True, height_ratios=(2, 1))
        bound_axes.fill_between(time_axis, inner.lower_rad, inner.upper_rad, step="mid", color="0.8", lw=0,
                                label="bounds x_t^min..x_t^max")
        if (~invertible).any():
            bound_axes.vlines(time_axis[~invertible], inner.lower_rad[~invertible], inner.upper_rad[~invertible],
                              color="tab:gray", lw=1.5, label="band-bounded samples")
        if invertible.any():
            bound_axes.errorbar(time_axis[invertible], inner.center_rad[invertible], yerr=half[invertible],
                                fmt="o", ms=2.5, color="tab:red", lw=0.8, label="invertible samples (Prop. 2)")
        if truth is not None:
            bound_axes.plot(time_axis, truth, "k-", lw=0.7, label="true x_t")
        bound_axes.set_ylabel("inner signal x [rad]")
        bound_axes.legend(loc="upper right", fontsize=7)
        width_axes.semilogy(time_axis[~invertible], half[~invertible] * 1e3, "s", ms=3, color="tab:gray",
                            label="band-bounded")
        width_axes.semilogy(time_axis[invertible], half[invertible] * 1e3, "o", ms=2.5, color="tab:red",
                            label="invertible")
        width_axes.set_ylabel("half-width Δx [mrad]")
        # within a decade matplotlib labels every minor tick (6x10^1, 4x10^1, 3x10^1, ...): 1-2-5 labels only
        from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

        width_axes.yaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
        width_axes.yaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
        width_axes.yaxis.set_minor_formatter(NullFormatter())
        width_axes.set_xlabel(time_label)
        width_axes.legend(loc="upper right", fontsize=7)

    caption = (f"Bounds on the inner signal x_t over {count} samples (Cerone et al. 2009, Section 4, eqs. (23)-(28)): "
               f"{inner.num_invertible} samples ({100.0 * inner.num_invertible / max(count, 1):.0f} %) are invertible "
               f"(red, |y_t - y_(t-1)| > 2Δη), with median half-width {median_inv:.3g} mrad; the "
               f"{count - inner.num_invertible} others (gray) are bounded by the band between the two backlash lines, "
               f"median half-width {median_band:.3g} mrad.{truth_text} Look for many invertible samples: the linear "
               "block's bounds are tight only where x_t is known closely.")
    return ReportFigure(name, caption, draw, size_in=(8.0, 5.0))


# ----------------------------------------------------------------------------------------------------------
# parameter intervals
# ----------------------------------------------------------------------------------------------------------


def _intervals_of(source: IntervalSource) -> dict[str, ParameterInterval]:
    """All intervals of a source, backlash first then the linear block, or ``{}`` for an empty result."""
    if isinstance(source, OutputBacklashIdentification):
        if source.is_empty:
            return {}
        return {**source.backlash_intervals, **source.linear_intervals}
    if isinstance(source, LinearBlockBounds):
        return {} if source.is_empty else dict(source.intervals)
    raise TypeError(f"expected an OutputBacklashIdentification or LinearBlockBounds (a saved one is read with "
                    f"its from_dict), got {type(source).__name__}")


def _outer_inner_ratio(source: IntervalSource) -> dict[str, float | None] | None:
    """:attr:`LinearBlockBounds.outer_inner_ratio` of a source, or None (no linear bounds or no inner values)."""
    linear = source.linear if isinstance(source, OutputBacklashIdentification) else source
    return linear.outer_inner_ratio if isinstance(linear, LinearBlockBounds) else None


def _inner_values(source: IntervalSource) -> tuple[dict[str, float], dict[str, float]] | None:
    """The verified inner values (lower, upper) of the parameters that have them (finite: the coupled
    method found a verified point reaching them), or None when no parameter has."""
    linear = source.linear if isinstance(source, OutputBacklashIdentification) else source
    if not isinstance(linear, LinearBlockBounds) or linear.inner_lower is None or linear.inner_upper is None:
        return None
    names = [name for name in linear.inner_lower if name in linear.inner_upper
             and np.isfinite(linear.inner_lower[name]) and np.isfinite(linear.inner_upper[name])]
    if not names:
        return None
    return {name: linear.inner_lower[name] for name in names}, {name: linear.inner_upper[name] for name in names}


def parameter_sort_key(name: str) -> tuple[int, int, str]:
    """Model order: m_l c_l m_r c_r, then a1, a2, ..., then b<nk>.., then anything else by name."""
    if name in _BACKLASH_ORDER:
        return (0, _BACKLASH_ORDER.index(name), name)
    parsed = linear_parameter(name)
    if parsed is not None:
        return (1 if parsed[0] == "a" else 2, parsed[1], name)
    return (3, 0, name)


def parameter_intervals_figure(results: Mapping[str, IntervalSource], name: str, *,
                               true_values: Mapping[str, float] | None = None,
                               parameters: Sequence[str] | None = None) -> ReportFigure:
    """Guaranteed parameter intervals of one or several methods side by side, against the true values.

    One panel per parameter (``m_l c_l m_r c_r`` of eqs. (18)-(20), then ``a1.. b<nk>..`` of Section 5); in
    each, one bar per method, and for the coupled method the verified inner values (points of the exact
    feasible set reach at least these) as a thicker bar. The axis shows the deviation from the true value
    (or, without it, from the first method's centre) so that intervals of widths 1e-4 and 1e-1 both read.

    Parameters
    ----------
    results
        Method label -> result or linear-block bounds; an empty result shows as "empty".
    true_values
        Parameter name -> true value (simulation), drawn as a red line at 0.
    parameters
        Which parameters to show (default: all, in model order).
    """
    if not results:
        raise ValueError("results: expected at least one method's intervals")
    intervals = {label: _intervals_of(source) for label, source in results.items()}
    inner = {label: _inner_values(source) for label, source in results.items()}
    names = list(parameters) if parameters is not None else sorted(
        {key for per_method in intervals.values() for key in per_method}, key=parameter_sort_key)
    if not names:
        raise ValueError("results: no intervals to draw (every result is empty)")
    truth = dict(true_values or {})
    rows = -(-len(names) // min(4, len(names)))
    ratios = {label: _outer_inner_ratio(source) for label, source in results.items()}
    return ReportFigure(name, _intervals_caption(intervals, inner, names, truth, ratios),
                        _intervals_drawing(intervals, inner, names, truth), size_in=(9.0, 1.0 + 1.35 * rows))


_InnerValues = Union[tuple[dict[str, float], dict[str, float]], None]


def _interval_references(intervals: Mapping[str, Mapping[str, ParameterInterval]], names: Sequence[str],
                         truth: Mapping[str, float]) -> dict[str, float]:
    """Per parameter, the value its axis is drawn relative to: the truth, else the first method's centre."""
    references: dict[str, float] = {}
    for parameter in names:
        if parameter in truth:
            references[parameter] = float(truth[parameter])
        else:
            first = next((per[parameter] for per in intervals.values() if parameter in per), None)
            references[parameter] = first.center if first is not None else 0.0
    return references


def _intervals_caption(intervals: Mapping[str, Mapping[str, ParameterInterval]],
                       inner: Mapping[str, _InnerValues], names: Sequence[str], truth: Mapping[str, float],
                       ratios: Mapping[str, dict[str, float | None] | None] | None = None) -> str:
    """The caption of :func:`parameter_intervals_figure`: each method's :class:`IntervalSetSummary`, the
    :func:`median_width_ratio` of the last method to the first on the linear block, and each method's
    outer/inner ratios (:attr:`LinearBlockBounds.outer_inner_ratio`: how tight its guarantee is)."""
    labels = list(intervals)
    summary = []
    for label in labels:
        if not intervals[label]:
            summary.append(f"{label}: empty feasible set")
            continue
        numbers = IntervalSetSummary.of(intervals[label], names, truth)
        text = f"{label}: median half-width {numbers.median_half_width:.3g}"
        if numbers.truth_known:
            text += f", true value inside {numbers.truth_inside} of {numbers.truth_known}"
        tightness = {name: ratio for name, ratio in ((ratios or {}).get(label) or {}).items()
                     if ratio is not None and name in names}
        if tightness:
            text += (", outer/inner (how many times wider than the verified span the guarantee is; 1: exact) "
                     + " ".join(f"{name} {ratio:.3g}" for name, ratio in tightness.items()))
        summary.append(text)
    if len(labels) >= 2:
        linear_names = [p for p in names if linear_parameter(p) is not None]
        ratio = median_width_ratio(intervals[labels[-1]], intervals[labels[0]], linear_names)
        if ratio is not None:
            summary.append(f"median width ratio {labels[-1]}/{labels[0]} on the linear block = {ratio:.3g}")
    prior = _prior_box_bounds(intervals, names)
    if prior:
        summary.append("bounds that are the a-priori stability box |a_i| <= C(na, i), not the data's: "
                       + ", ".join(prior))
    with_inner = [label for label in labels if inner[label] is not None]
    inner_text = (f"; thick pale bars: verified inner values of {', '.join(with_inner)} (the exact bounds lie between "
                  "them and the thin bars)") if with_inner else ""
    what = "true value (red line at 0)" if truth else "first method's centre (no true values given)"
    return (f"Guaranteed parameter intervals per method ({', '.join(labels)}), each axis relative to the {what}; "
            "backlash m, c from eqs. (18)-(20), linear block a_i, b_j from Section 5 of Cerone et al. (2009)"
            f"{inner_text}. {'; '.join(summary)}.")


def _prior_box_bounds(intervals: Mapping[str, Mapping[str, ParameterInterval]], names: Sequence[str]) -> list[str]:
    """``"<method> <a_i> lower|upper"`` for every bound on the edge of the a-priori box of a stable A(q^-1),
    |a_i| <= C(na, i) (:mod:`identify.linear_block_bounds`): where the data did not tighten it."""
    orders = [parsed[1] for parsed in map(linear_parameter, names) if parsed is not None and parsed[0] == "a"]
    if not orders:
        return []
    na = max(orders)
    found = []
    for label, per in intervals.items():
        for name in names:
            parsed = linear_parameter(name)
            if parsed is None or parsed[0] != "a" or name not in per:
                continue
            edge = float(math.comb(na, parsed[1]))
            for side, value, at in (("lower", per[name].lower, -edge), ("upper", per[name].upper, edge)):
                if math.isclose(value, at, rel_tol=1e-9, abs_tol=1e-9):
                    found.append(f"{label} {name} {side} ({at:g})")
    return found


def _intervals_drawing(intervals: Mapping[str, Mapping[str, ParameterInterval]],
                       inner: Mapping[str, _InnerValues], names: Sequence[str], truth: Mapping[str, float]):
    """The drawing of :func:`parameter_intervals_figure`: one panel per parameter, one bar per method."""
    labels = list(intervals)
    references = _interval_references(intervals, names, truth)
    columns = min(4, len(names))
    rows = -(-len(names) // columns)

    def draw(figure) -> None:
        from matplotlib.ticker import MaxNLocator

        axes_grid = np.atleast_1d(figure.subplots(rows, columns, squeeze=False)).ravel()
        for axes, parameter in zip(axes_grid, names):
            reference = references[parameter]
            spans = [abs(value - reference) for per in intervals.values() if parameter in per
                     for value in (per[parameter].lower, per[parameter].upper) if np.isfinite(value)]
            exponent = int(np.floor(np.log10(max(spans)))) if spans and max(spans) > 0 else 0
            exponent = 0 if -1 <= exponent <= 2 else exponent
            scale = 10.0 ** -exponent
            for row, label in enumerate(labels):
                colour = METHOD_COLOURS[row % len(METHOD_COLOURS)]
                interval = intervals[label].get(parameter)
                if interval is None:
                    axes.text(0.5, row, "empty", ha="center", va="center", fontsize=7, color=colour,
                              transform=axes.get_yaxis_transform())
                    continue
                low, high = (interval.lower - reference) * scale, (interval.upper - reference) * scale
                axes.plot([low, high], [row, row], "-", color=colour, lw=2.0, solid_capstyle="butt")
                axes.plot([low, high], [row, row], "|", color=colour, ms=8)
                values = inner[label]
                if values is not None and parameter in values[0]:
                    axes.plot([(values[0][parameter] - reference) * scale, (values[1][parameter] - reference) * scale],
                              [row, row], "-", color=colour, lw=6.0, alpha=0.4, solid_capstyle="butt")
            if parameter in truth:
                axes.axvline(0.0, color="tab:red", lw=1.0)
            axes.set_ylim(-0.8, len(labels) - 0.2)
            axes.set_yticks(range(len(labels)), labels, fontsize=7)
            axes.set_ylabel("method [-]", fontsize=7)
            axes.tick_params(axis="x", labelsize=7)
            axes.xaxis.set_major_locator(MaxNLocator(5))
            sign = "-" if reference >= 0 else "+"
            unit = parameter_unit(parameter)
            scaled_unit = (f"1e{exponent} {unit}" if unit != "-" else f"1e{exponent}") if exponent else unit
            axes.set_xlabel(f"{parameter} {sign} {abs(reference):.5g} [{scaled_unit}]", fontsize=8)
        for axes in axes_grid[len(names):]:
            axes.set_visible(False)

    return draw


def default_result_figures(results: Mapping[str, OutputBacklashIdentification], prefix: str, *,
                           sample_period_s: float | None = None, true_backlash: Any = None,
                           true_linear: Any = None, true_values: Mapping[str, float] | None = None,
                           true_inner_rad: ArrayLike | None = None) -> list[ReportFigure]:
    """The five set-membership figures for one or several methods, names prefixed by ``prefix``.

    The backlash, polygon and inner-signal figures come from the first non-empty result (they are the same
    for every method: the methods differ only in Section 5); intervals and Bode show every method.
    """
    figures: list[ReportFigure] = []
    non_empty = [result for result in results.values() if not result.backlash.is_empty]
    first = non_empty[0] if non_empty else next(iter(results.values()))
    figures.append(backlash_characteristic_figure(first, f"{prefix}backlash", true_backlash=true_backlash))
    figures.append(feasible_polygons_figure(first, f"{prefix}polygons", true_backlash=true_backlash))
    if first.inner_signal is not None:
        figures.append(inner_signal_figure(first, f"{prefix}inner_signal", sample_period_s=sample_period_s,
                                           true_inner_rad=true_inner_rad))
    if any(not result.is_empty for result in results.values()):
        figures.append(parameter_intervals_figure(results, f"{prefix}intervals", true_values=true_values))
        figures.append(linear_block_bode_figure(results, f"{prefix}bode", sample_period_s=sample_period_s,
                                                true_linear=true_linear))
    return figures
