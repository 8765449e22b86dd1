"""Figures of a Hammerstein model identified by subspace (Pouliquen et al., CDC 2013;
:mod:`identify.hammerstein_subspace`).

* :func:`poles_figure`: the poles of G in the z-plane with the unit circle, and a zoom on them;
* :func:`borders_figure`: the ascending and descending paths P_a, P_d (eq. (3)) with their nodes;
* :func:`singular_values_figure`: the singular values of the PI-MOESP projection (eq. (12)) with the chosen
  order marked.

Each function takes a :class:`identify.hammerstein_model.HammersteinModel` (a saved one is read with
``HammersteinModel.from_dict``) and a figure name, and returns a :class:`rig.report.ReportFigure`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.hammerstein_subspace import HammersteinModel
from rig.report import ReportFigure

__all__ = ["HammersteinSource", "borders_figure", "hammerstein_figures", "poles_figure", "singular_values_figure"]

HammersteinSource = HammersteinModel
"""What the figures draw: the model itself, never its JSON."""


@dataclass(frozen=True)
class _ModelView:
    """The numbers the figures need, from a model or from its JSON."""

    order: int
    poles: NDArray[np.complex128]
    ascending_u: NDArray[np.float64]
    ascending_h: NDArray[np.float64]
    descending_u: NDArray[np.float64]
    descending_h: NDArray[np.float64]
    singular_values: NDArray[np.float64]
    fit_percent: float | None


def _view(model: HammersteinModel) -> _ModelView:
    if not isinstance(model, HammersteinModel):
        raise TypeError(f"model: expected a HammersteinModel (read a saved one with HammersteinModel.from_dict), "
                        f"got {type(model).__name__}")
    return _ModelView(model.order, np.asarray(model.poles, dtype=complex),
                      np.asarray(model.ascending_border.nodes_u), np.asarray(model.ascending_border.values),
                      np.asarray(model.descending_border.nodes_u), np.asarray(model.descending_border.values),
                      np.asarray(model.singular_values), float(model.fit_percent))


def poles_figure(model: HammersteinSource, name: str, *, true_poles: ArrayLike | None = None,
                 sample_period_s: float | None = None) -> ReportFigure:
    """The poles of the identified G (eigenvalues of A, step 1 of Section III) in the z-plane.

    Left: the whole unit circle (stability: every pole inside). Right: a zoom on the poles, where the
    distance to the true poles reads.

    Parameters
    ----------
    true_poles
        Poles of the true G (simulation), drawn as circles.
    sample_period_s
        When given, the caption also states the poles' natural frequencies in Hz.
    """
    view = _view(model)
    truth = None if true_poles is None else np.atleast_1d(np.asarray(true_poles, dtype=complex))
    pole_text = ", ".join(f"{p.real:.4f}{p.imag:+.4f}j" for p in np.sort_complex(view.poles))
    notes = [f"order {view.order}, poles {pole_text}, largest |p| = {model.max_pole_magnitude:.4f}"
             f" ({'stable' if model.stable else 'NOT stable'})"]
    if sample_period_s is not None and view.poles.size:
        notes.append("natural frequencies " + ", ".join(f"{f:.3g} Hz"
                                                        for f in model.natural_frequencies_hz(sample_period_s)))
    if truth is not None:
        notes.append(f"farthest true pole is {model.pole_distance(truth):.3g} from an estimated one")

    def draw(figure) -> None:
        whole, zoom = figure.subplots(1, 2)
        angle = np.linspace(0.0, 2 * np.pi, 400)
        points = [view.poles] + ([truth] if truth is not None else [])
        everything = np.concatenate(points) if points else np.empty(0, dtype=complex)
        for axes in (whole, zoom):
            axes.plot(np.cos(angle), np.sin(angle), color="0.6", lw=0.8, label="unit circle")
            axes.plot(view.poles.real, view.poles.imag, "x", color="tab:blue", ms=8, mew=1.5, label="identified poles")
            if truth is not None:
                axes.plot(truth.real, truth.imag, "o", mfc="none", color="tab:red", ms=9, label="true poles")
            axes.axhline(0.0, color="0.85", lw=0.5)
            axes.axvline(0.0, color="0.85", lw=0.5)
            axes.set_xlabel("real part [-]")
            axes.set_ylabel("imaginary part [-]")
        whole.set_aspect("equal")
        whole.set_xlim(-1.15, 1.15)
        whole.set_ylim(-1.15, 1.15)
        whole.legend(loc="lower left", fontsize=7)
        if everything.size:
            centre_re, centre_im = float(np.mean(everything.real)), float(np.mean(everything.imag))
            half = max(float(np.max(np.abs(everything.real - centre_re))),
                       float(np.max(np.abs(everything.imag - centre_im))), 1e-3) * 1.3
            zoom.set_xlim(centre_re - half, centre_re + half)
            zoom.set_ylim(centre_im - half, centre_im + half)
        zoom.set_title("zoom on the poles", fontsize=9)

    caption = (f"Poles of the identified linear part G in the z-plane (Pouliquen et al. 2013, step 1 of Section III: "
               f"eigenvalues of A), with the unit circle{' and the true poles (red circles)' if truth is not None else ''}; "
               f"right: zoom. {'; '.join(notes)}. Look for every pole inside the unit circle"
               f"{' and on its true pole' if truth is not None else ''}.")
    return ReportFigure(name, caption, draw, size_in=(8.0, 4.0))


def borders_figure(model: HammersteinSource, name: str, *, true_ascending: Callable[[float], float] | None = None,
                   true_descending: Callable[[float], float] | None = None) -> ReportFigure:
    """The ascending and descending paths P_a, P_d of the nonlinearity (eq. (3)) with their nodes.

    Parameters
    ----------
    true_ascending, true_descending
        The true paths as callables u -> H (e.g. a border of :mod:`identify.plant_blocks`), drawn dashed;
        the caption gives the largest error at the nodes. For a backlash, pass the paths the input actually
        travels (the ascending path from u_min stays at H[u_min] until the ascending border reaches it).
    """
    view = _view(model)
    notes = [f"{view.ascending_u.size} ascending and {view.descending_u.size} descending nodes on "
             f"[{view.ascending_u[0]:.4g}, {view.ascending_u[-1]:.4g}] rad"]
    play = model.play_at_nodes()
    notes.append(f"the play seen at the output {play.describe()}; the subspace method gives no interval")
    errors = []
    for label, nodes_u, nodes_h, border in (("ascending", view.ascending_u, view.ascending_h, true_ascending),
                                            ("descending", view.descending_u, view.descending_h, true_descending)):
        if border is not None:
            true_values = np.array([float(border(float(u))) for u in nodes_u])
            errors.append(f"{label} {float(np.max(np.abs(nodes_h - true_values))):.3g} rad")
    if errors:
        notes.append("largest error at the nodes against the true paths: " + ", ".join(errors))
    if view.fit_percent is not None:
        notes.append(f"simulation fit {view.fit_percent:.1f} %")

    # The play is a few mrad on a range of a rad: drawn again as the gap P_d - P_a at the ascending nodes,
    # against the true paths' gap when known.
    gap_mrad = play.gaps_rad * 1e3

    def draw(figure) -> None:
        axes, gap_axes = figure.subplots(2, 1, sharex=True, height_ratios=(3, 1.4))
        low, high = float(view.ascending_u[0]), float(view.ascending_u[-1])
        grid = np.linspace(low, high, 300)
        axes.plot(view.ascending_u, view.ascending_h, "-o", color="tab:orange", ms=4, label="ascending path P_a")
        axes.plot(view.descending_u, view.descending_h, "-s", color="tab:blue", ms=4, label="descending path P_d")
        if true_ascending is not None:
            axes.plot(grid, [true_ascending(float(u)) for u in grid], "--", color="tab:red", lw=1.0,
                      label="true ascending")
        if true_descending is not None:
            axes.plot(grid, [true_descending(float(u)) for u in grid], "--", color="navy", lw=1.0,
                      label="true descending")
        axes.set_ylabel("nonlinearity output H[u] [rad]")
        axes.grid(True, lw=0.3, alpha=0.5)
        axes.legend(loc="upper left", fontsize=7)
        gap_axes.plot(view.ascending_u, gap_mrad, "o-", color="tab:purple", ms=4, lw=0.8,
                      label="P_d - P_a at the nodes")
        if true_ascending is not None and true_descending is not None:
            true_gap = [(true_descending(float(u)) - true_ascending(float(u))) * 1e3 for u in grid]
            gap_axes.plot(grid, true_gap, "k--", lw=1.0, label="true gap")
        gap_axes.axhline(0.0, color="0.6", lw=0.5)
        gap_axes.set_xlabel("input u [rad]")
        gap_axes.set_ylabel("gap [mrad]")
        gap_axes.grid(True, lw=0.3, alpha=0.5)
        gap_axes.legend(loc="lower center", fontsize=7)

    opened = int(np.count_nonzero(play.gaps_rad > 0.0))
    verdict = (f" The ascending path lies below the descending one (a play) at {opened} of {play.gaps_rad.size} "
               "ascending nodes.")
    if true_ascending is not None and true_descending is not None:
        true_play = max(float(true_descending(float(u)) - true_ascending(float(u))) for u in view.ascending_u)
        estimated = float(np.max(play.gaps_rad))
        if true_play > 0.0:
            verdict += (f" The largest gap is {estimated * 1e3:.3g} mrad against the true play's "
                        f"{true_play * 1e3:.3g} mrad ({100 * (estimated / true_play - 1):+.0f} %): the subspace "
                        "estimate carries no interval, so a difference this size is not flagged by the method.")
    caption = (f"Borders of the input nonlinearity (Pouliquen et al. 2013, eq. (3)): piecewise-linear paths with "
               f"their nodes{', true paths dashed' if errors else ''}; below, the gap P_d - P_a at the nodes in mrad. "
               f"{'; '.join(notes)}.{verdict}")
    return ReportFigure(name, caption, draw, size_in=(7.0, 5.5))


def singular_values_figure(model: HammersteinSource, name: str) -> ReportFigure:
    """Singular values of the PI-MOESP projection (eq. (12)) on a log scale, the chosen order marked."""
    view = _view(model)
    values = view.singular_values
    order = view.order
    if order < values.size and values[order] > 0:
        gap_text = f"σ_{order}/σ_{order + 1} = {values[order - 1] / values[order]:.3g}"
    else:
        gap_text = "no singular value after the chosen order"
    shown = min(values.size, max(3 * order, 12))

    def draw(figure) -> None:
        axes = figure.subplots()
        index = np.arange(1, shown + 1)
        axes.semilogy(index, values[:shown], "o-", color="tab:gray", ms=4, lw=0.8, label="singular values")
        axes.semilogy(index[:order], values[:order], "o", color="tab:blue", ms=7, label=f"kept (order {order})")
        axes.axvline(order + 0.5, color="tab:red", lw=1.0, ls="--", label="chosen order")
        axes.set_xlabel("index k [-]")
        axes.set_ylabel("singular value σ_k [rad]")
        axes.grid(True, which="both", lw=0.3, alpha=0.5)
        axes.legend(loc="upper right", fontsize=7)

    caption = (f"Singular values of the PI-MOESP projection (Pouliquen et al. 2013, eqs. (11)-(12)), largest first, "
               f"first {shown} of {values.size}; the order n = {order} is left of the dashed line, {gap_text}. Look "
               "for a clear drop right after the chosen order: without one, the order is uncertain.")
    return ReportFigure(name, caption, draw, size_in=(6.5, 3.8))


def hammerstein_figures(model: HammersteinSource, prefix: str, *, true_poles: ArrayLike | None = None,
                        true_ascending: Callable[[float], float] | None = None,
                        true_descending: Callable[[float], float] | None = None,
                        sample_period_s: float | None = None) -> list[ReportFigure]:
    """The three figures of a Hammerstein model (poles, borders, singular values), names prefixed by ``prefix``."""
    return [poles_figure(model, f"{prefix}poles", true_poles=true_poles, sample_period_s=sample_period_s),
            borders_figure(model, f"{prefix}borders", true_ascending=true_ascending, true_descending=true_descending),
            singular_values_figure(model, f"{prefix}singular_values")]
