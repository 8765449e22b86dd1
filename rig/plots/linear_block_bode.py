"""The Bode magnitude figure of a linear-block set (Cerone, Piga and Regruto 2009, Section 5;
:class:`identify.linear_block_bounds.LinearBlockBounds`): |G(e^{jω})| of the central model θ^c of each method,
the parameter box's envelope, a verified feasible model and the true model, and below them each curve relative
to the reference. Part of :mod:`rig.plots.set_membership`, which draws it among the result's figures.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Union

import numpy as np
from numpy.typing import NDArray

from identify.linear_block_bounds import LinearBlockBounds
from identify.linear_block_response import MagnitudeEnvelope, magnitude, polynomials
from identify.output_backlash_identification import OutputBacklashIdentification
from rig.report import ReportFigure

__all__ = ["ENVELOPE_DRAWN_FROM", "MAGNITUDE_DEPTH_DB", "METHOD_COLOURS", "IntervalSource", "linear_block_bode_figure"]

IntervalSource = Union[OutputBacklashIdentification, LinearBlockBounds]
"""What the interval figures accept: a full result or the linear-block bounds (result objects, never JSON)."""

METHOD_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink")
"""One colour per method, in the order the methods are given, in every figure that compares them."""




def _true_polynomials(true_linear: Any) -> tuple[NDArray, NDArray]:
    if isinstance(true_linear, Mapping):
        return polynomials(true_linear)
    if isinstance(true_linear, tuple) and len(true_linear) == 2:
        a_part, b_part = true_linear
    else:
        a_part, b_part = true_linear.a, true_linear.b
    return np.asarray(b_part, dtype=float), np.r_[1.0, np.asarray(a_part, dtype=float)]


@dataclass(frozen=True)
class _FrequencyAxis:
    omega: NDArray[np.float64]  # rad/sample, π/1000..π
    values: NDArray[np.float64]  # what the axis shows
    unit: str

    @property
    def label(self) -> str:
        return f"frequency [{self.unit}]"

    @property
    def nyquist_text(self) -> str:
        return f"{self.values[-1]:.4g} {self.unit}"


def _frequency_axis(sample_period_s: float | None, num_frequencies: int) -> _FrequencyAxis:
    """ω log-spaced up to Nyquist, shown in Hz when the sample period is known, else in cycles per sample."""
    omega = np.logspace(np.log10(np.pi / 1000.0), np.log10(np.pi), num_frequencies)
    if sample_period_s is None:
        return _FrequencyAxis(omega, omega / (2 * np.pi), "cycles/sample")
    return _FrequencyAxis(omega, omega / (2 * np.pi * float(sample_period_s)), "Hz")


def _linear_bounds_of(results: IntervalSource | Mapping[str, IntervalSource]) -> dict[str, LinearBlockBounds]:
    """Method label ("" for a single source) -> its non-empty linear-block bounds."""
    sources: dict[str, Any] = ({"": results} if isinstance(results, (OutputBacklashIdentification, LinearBlockBounds))
                               else dict(results))
    linear_of = {label: source.linear if isinstance(source, OutputBacklashIdentification) else source
                 for label, source in sources.items()}
    for label, linear in linear_of.items():
        if linear is not None and not isinstance(linear, LinearBlockBounds):
            raise TypeError(f"results: expected OutputBacklashIdentification or LinearBlockBounds, got "
                            f"{type(linear).__name__}{' for ' + label if label else ''}")
    linear_of = {label: linear for label, linear in linear_of.items() if linear is not None and not linear.is_empty}
    if not linear_of:
        raise ValueError("results: no linear-block intervals to draw (empty feasible set?)")
    return linear_of


def _decibels(values: NDArray[np.float64]) -> NDArray[np.float64]:
    with np.errstate(divide="ignore"):
        return 20.0 * np.log10(values)


def _percent(fraction: float) -> str:
    """A fraction as a percentage that never rounds a few frequencies to "0 %" or all but a few to "100 %"."""
    if 0.0 < fraction < 0.01:
        return "< 1 %"
    if 0.99 < fraction < 1.0:
        return "> 99 %"
    return f"{100.0 * fraction:.0f} %"


ENVELOPE_DRAWN_FROM = 0.5
"""The box's envelope is drawn for a method only where it is bounded, and only if it is bounded at this
fraction of the frequencies at least: a band of a few disjoint slivers between infinite stretches tells
nothing, and the caption gives the fraction instead."""


def _envelope_note(label: str, envelope: MagnitudeEnvelope, true_magnitude: NDArray[np.float64] | None) -> str:
    """What the caption says of one method's envelope: the numbers :class:`MagnitudeEnvelope` computed."""
    prefix = f"{label}: " if label else ""
    bounded = envelope.bounded_fraction
    reasons = []
    if envelope.unbounded_above_fraction > 0.0:
        reasons.append(f"no upper bound at {_percent(envelope.unbounded_above_fraction)}, where a model of the box "
                       "has a pole on the unit circle")
    if envelope.zero_below_fraction > 0.0:
        reasons.append(f"lower bound 0 at {_percent(envelope.zero_below_fraction)}, where one has a zero there")
    why = f" ({'; '.join(reasons)})" if reasons else ""
    if bounded < ENVELOPE_DRAWN_FROM:
        return f"{prefix}envelope not drawn, bounded at {_percent(bounded)} of the frequencies{why}"
    text = (f"{prefix}envelope bounded at {_percent(bounded)} of the frequencies{why}, median width "
            f"{envelope.median_width_db:.3g} dB there")
    if true_magnitude is not None:
        text += f", true |G| inside it at {_percent(envelope.fraction_containing(true_magnitude))} of them"
    return text


def linear_block_bode_figure(results: IntervalSource | Mapping[str, IntervalSource], name: str, *,
                             sample_period_s: float | None = None, true_linear: Any = None,
                             num_frequencies: int = 400) -> ReportFigure:
    """Bode magnitude of the linear block G(q) = B(q^-1)/A(q^-1): central model and the parameter box's envelope.

    The central model is θ^c, the centre of the intervals (eq. (19) applied to Section 5). The envelope is
    :meth:`identify.linear_block_bounds.LinearBlockBounds.magnitude_envelope`, the exact range of |G(e^{jω})|
    over the box of θ; the box contains the feasible set, so the envelope is guaranteed to contain the |G| of
    every feasible model, but it is wider than the set's own (box models need not be feasible nor have unit
    static gain, eq. (8)). A box that holds a model with a pole on the unit circle has no upper bound there:
    the envelope is drawn only where it is bounded, and only for a method whose envelope is bounded at
    :data:`ENVELOPE_DRAWN_FROM` of the frequencies; the caption says which. The figure formats the numbers
    the envelope computed. Every curve is drawn whole, except below :data:`MAGNITUDE_DEPTH_DB` under the
    highest point drawn (a |G| that falls towards -inf dB at a zero on the unit circle), which the figure and
    the caption name.

    Parameters
    ----------
    results
        One result or linear-block bounds, or method label -> either to overlay several methods.
    sample_period_s
        Frequencies in Hz when given, else in cycles per sample.
    true_linear
        The true block: an object with ``a`` (a_1..a_na) and ``b`` (b_0..b_nb), e.g.
        :class:`identify.plant_blocks.LinearBlock`, a tuple ``(a, b)`` or a mapping ``{a1.., b<k>..}``.
    """
    linear_of = _linear_bounds_of(results)
    axis = _frequency_axis(sample_period_s, num_frequencies)
    envelopes = {label: linear.magnitude_envelope(axis.omega) for label, linear in linear_of.items()}
    feasible_db = {label: _decibels(magnitude(*polynomials(linear.inner_point), axis.omega))
                   for label, linear in linear_of.items() if linear.inner_point}
    true_magnitude = None if true_linear is None else magnitude(*_true_polynomials(true_linear), axis.omega)
    drawn_envelopes = {label for label, envelope in envelopes.items()
                       if envelope.bounded_fraction >= ENVELOPE_DRAWN_FROM}
    notes = [_envelope_note(label, envelope, true_magnitude) for label, envelope in envelopes.items()]
    curves = _bode_curves(axis, envelopes, drawn_envelopes, feasible_db,
                          None if true_magnitude is None else _decibels(true_magnitude))
    shaded = ("shaded, the exact range of |G| over the parameter box where it is bounded (it contains the |G| of "
              "every model of the feasible set, but box models need not be feasible nor have unit static gain, so "
              "it is wider than the set's own)") if drawn_envelopes else "no envelope drawn"
    has_true = curves.true is not None
    cut = (f" Not drawn, more than {MAGNITUDE_DEPTH_DB:g} dB under the highest point: {'; '.join(curves.cut)}."
           if curves.cut else "")
    caption = (f"Bode magnitude of the linear block G = B/A (Cerone et al. 2009, Section 5) up to the Nyquist "
               f"frequency {axis.nyquist_text}: line, the central model θ^c of each method; {shaded}"
               f"{'; dotted, a model verified to satisfy the exact constraints' if feasible_db else ''}"
               f"{'; dashed, the true model' if has_true else ''}. {'. '.join(notes)}.{cut} Bottom: the same "
               f"relative to {'the true model' if has_true else 'the last central model'} (linear within ±1 dB, "
               "logarithmic beyond). Look for "
               + " and ".join([*(["the central models on the true curve"] if has_true else []),
                               *(["a narrow envelope where the excitation had power"] if drawn_envelopes else []),
                               *([] if has_true or drawn_envelopes else ["the methods' central models together"])])
               + ".")
    return ReportFigure(name, caption, _bode_drawing(axis, curves), size_in=(7.5, 5.5))


MAGNITUDE_DEPTH_DB = 120.0
"""How far under the highest point drawn the Bode magnitude axis reaches. A |G| that falls further, towards
-inf dB at a zero on the unit circle (a continuous model discretised by Tustin's rule has zeros at z = -1, the
Nyquist frequency), is not drawn below it, and the figure names the curve and the frequencies left out."""


@dataclass(frozen=True)
class _BodeCurves:
    """What the Bode figure draws, in dB, NaN where a curve is not drawn (below :attr:`floor_db`, or where an
    envelope is unbounded). ``bands`` are (lower, upper) edges, the lower one raised to the floor where only it
    falls below; ``cut`` says per curve what was left out."""

    central: dict[str, NDArray[np.float64]]
    feasible: dict[str, NDArray[np.float64]]
    true: NDArray[np.float64] | None
    bands: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]
    band_deviation_shown: dict[str, NDArray[np.bool_]]  # where both edges are drawn as computed
    floor_db: float
    top_db: float
    cut: tuple[str, ...]

    @property
    def reference(self) -> NDArray[np.float64]:
        """The curve the bottom panel subtracts: the true model, else the last central model."""
        return self.true if self.true is not None else list(self.central.values())[-1]


def _cut_text(name: str, cut: NDArray[np.bool_], axis: _FrequencyAxis, floor_db: float) -> str | None:
    """"<name> below <floor> dB from <f> Hz" (or "at <f1>..<f2> Hz" when the cut does not reach Nyquist)."""
    where = np.flatnonzero(cut)
    if where.size == 0:
        return None
    low, high = axis.values[where[0]], axis.values[where[-1]]
    span = (f"from {low:.3g} {axis.unit}" if where[-1] == cut.size - 1 and where.size == where[-1] - where[0] + 1
            else f"at {low:.3g}..{high:.3g} {axis.unit}")
    return f"{name} below {floor_db:.0f} dB {span}"


def _bode_curves(axis: _FrequencyAxis, envelopes: Mapping[str, MagnitudeEnvelope], drawn_envelopes: set[str],
                 feasible_db: Mapping[str, NDArray[np.float64]], true_db: NDArray[np.float64] | None) -> _BodeCurves:
    """Cut every curve :data:`MAGNITUDE_DEPTH_DB` under the highest point drawn (lines and envelope edges)."""
    prefix = {label: f"{label}: " if label else "" for label in envelopes}
    bands = {label: (np.where(envelopes[label].bounded, envelopes[label].lower_db, np.nan),
                     np.where(envelopes[label].bounded, envelopes[label].upper_db, np.nan))
             for label in envelopes if label in drawn_envelopes}
    lines = {**{f"{prefix[label]}central model θ^c": envelope.central_db for label, envelope in envelopes.items()},
             **{f"{prefix[label]}verified feasible model": curve for label, curve in feasible_db.items()},
             **({"true G": true_db} if true_db is not None else {})}
    values = np.concatenate([curve[np.isfinite(curve)] for curve in [*lines.values(), *(
        edge for pair in bands.values() for edge in pair)]])
    top = float(values.max())
    floor = max(float(values.min()), top - MAGNITUDE_DEPTH_DB)
    cut = [_cut_text(name, ~(curve >= floor), axis, floor) for name, curve in lines.items()]
    drawn = {name: np.where(curve >= floor, curve, np.nan) for name, curve in lines.items()}
    drawn_bands, deviation_shown = {}, {}
    for label, (lower, upper) in bands.items():
        cut.append(_cut_text(f"{prefix[label]}envelope's lower edge", lower < floor, axis, floor))
        shown = upper >= floor
        drawn_bands[label] = (np.where(shown, np.maximum(lower, floor), np.nan), np.where(shown, upper, np.nan))
        deviation_shown[label] = lower >= floor
    return _BodeCurves(
        central={label: drawn[f"{prefix[label]}central model θ^c"] for label in envelopes},
        feasible={label: drawn[f"{prefix[label]}verified feasible model"] for label in feasible_db},
        true=drawn.get("true G"), bands=drawn_bands, band_deviation_shown=deviation_shown, floor_db=floor, top_db=top,
        cut=tuple(text for text in cut if text))


def _bode_drawing(axis: _FrequencyAxis, curves: _BodeCurves) -> Any:
    """The drawing function of :func:`linear_block_bode_figure`: |G| on top, from the floor of the cut curves
    to the highest point; |G| relative to the reference below, on a scale linear within ±1 dB and logarithmic
    beyond, so that every deviation is shown whole and a fraction of a dB still reads."""
    labels = list(curves.central)
    colour = {label: METHOD_COLOURS[index % len(METHOD_COLOURS)] for index, label in enumerate(labels)}
    prefix = {label: f"{label}: " if label else "" for label in labels}
    reference = curves.reference
    reference_label = ("|G_true|" if curves.true is not None
                       else f"|G({labels[-1] + ' ' if labels[-1] else ''}θ^c)|")
    deviations = [curve - reference for curve in [*curves.central.values(), *curves.feasible.values()]]
    band_deviations = {label: tuple(np.where(curves.band_deviation_shown[label], edge - reference, np.nan)
                                    for edge in edges) for label, edges in curves.bands.items()}
    shown = np.concatenate([values[np.isfinite(values)] for values in
                            [*deviations, *(edge for pair in band_deviations.values() for edge in pair)]])
    deviation_low = min(float(shown.min()), -1.0) if shown.size else -1.0
    deviation_high = max(float(shown.max()), 1.0) if shown.size else 1.0
    margin = max(0.05 * (curves.top_db - curves.floor_db), 1.0)

    def draw(figure) -> None:
        from matplotlib.ticker import FuncFormatter, SymmetricalLogLocator

        axes, deviation_axes = figure.subplots(2, 1, sharex=True, height_ratios=(3, 2))
        for label, (low, high) in curves.bands.items():
            axes.fill_between(axis.values, low, high, where=np.isfinite(high), color=colour[label], alpha=0.25,
                              lw=0, label=f"{prefix[label]}envelope over the box")
            deviation_low_edge, deviation_high_edge = band_deviations[label]
            deviation_axes.fill_between(axis.values, deviation_low_edge, deviation_high_edge,
                                        where=np.isfinite(deviation_high_edge), color=colour[label], alpha=0.25,
                                        lw=0)
        for label, central in curves.central.items():
            axes.plot(axis.values, central, color=colour[label], lw=1.2, label=f"{prefix[label]}central model θ^c")
            deviation_axes.plot(axis.values, central - reference, color=colour[label], lw=1.0)
        for label, point_db in curves.feasible.items():
            axes.plot(axis.values, point_db, ":", color=colour[label], lw=1.2,
                      label=f"{prefix[label]}a verified feasible model")
            deviation_axes.plot(axis.values, point_db - reference, ":", color=colour[label], lw=1.2)
        if curves.true is not None:
            axes.plot(axis.values, curves.true, "k--", lw=1.0, label="true G")
        axes.set_ylim(curves.floor_db - margin, curves.top_db + margin)
        axes.set_xscale("log")
        axes.set_ylabel("magnitude |G| [dB]")
        axes.grid(True, which="both", lw=0.3, alpha=0.5)
        axes.legend(loc="lower left", fontsize=7)
        if curves.cut:
            axes.set_title("not drawn: " + "; ".join(curves.cut), fontsize=7, loc="right")
        deviation_axes.axhline(0.0, color="k", ls="--" if curves.true is not None else "-", lw=1.0)
        deviation_axes.set_yscale("symlog", linthresh=1.0)
        deviation_axes.set_ylim(1.25 * deviation_low, 1.25 * deviation_high)
        deviation_axes.yaxis.set_major_locator(SymmetricalLogLocator(base=10.0, linthresh=1.0, subs=(1.0, 3.0)))
        deviation_axes.yaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
        deviation_axes.set_xlabel(axis.label)
        deviation_axes.set_ylabel(f"|G| - {reference_label} [dB]", fontsize=8)
        deviation_axes.grid(True, which="both", lw=0.3, alpha=0.5)

    return draw
