"""Feasible parameter set D_γ of an output backlash from steady-state data, eqs. (11)-(20) of Cerone et al. (2009).

At steady state (eqs. (11)-(12)) a positive half-wave gives ȳ_i = m_r(ū_i - c_r) + η̄_i and a negative one
ȳ_j = m_l(ū_j + c_l) + η̄_j. In the coordinates (m, p) = (m, m·c) both equations are linear,

    right side:  ȳ_i - η̄_i = m_r ū_i - p_r,        left side:  ȳ_j - η̄_j = m_l ū_j + p_l,

so each of D_γ^r (eq. (14)) and D_γ^l (eq. (15)) is a convex polygon: the intersection of M strips with
m >= 0 and p >= 0 (eqs. (16)-(17)). :func:`bound_backlash_parameters` computes the polygons' vertices by
exact half-plane clipping and, from them, the exact orthotope B_γ of eqs. (18)-(20): m is linear and
c = p/m is linear-fractional on each polygon, so both reach their extremes at vertices (this is the global
solution of problems (20) that the paper takes from Cerone and Regruto 2007).

When the filter-tuning step amplitude r̄_F is known, the noise interval of eqs. (14)-(15) is widened by
α_i = 2Δη|ū_i|/r̄_F. The paper widens only the lower end; the sign of the residual transient that the
test |y_s^ā - y_s^a*| <= 2Δη + ε leaves is not known, so both ends are widened here to keep D_γ a
guaranteed outer set.

An empty D_γ is a result (:class:`EmptyFeasibleSetExplanation`): the smallest noise bound that the data
would need and the steady-state points that conflict.
"""

from __future__ import annotations

import math

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linprog

from identify.result_format import check_kind, malformed, number, numbers, tagged
from identify.validation import InvalidInputError, as_signal, same_length

__all__ = [
    "BacklashFeasibleSet",
    "BacklashSidePolygon",
    "EmptyFeasibleSetExplanation",
    "IntervalSetSummary",
    "ParameterInterval",
    "bound_backlash_parameters",
    "clip_polygon",
    "median_width_ratio",
]

_PAD_RELATIVE = 1e-12
"""Relative padding of the orthotope, far above the rounding error of the vertex computation (~1e-15)."""


@dataclass(frozen=True)
class ParameterInterval:
    """Guaranteed bounds θ^min <= θ <= θ^max of one parameter; center and half-width as in eq. (19)."""

    lower: float
    upper: float

    @property
    def center(self) -> float:
        return 0.5 * (self.lower + self.upper)

    @property
    def half_width(self) -> float:
        return 0.5 * abs(self.upper - self.lower)

    def contains(self, value: float) -> bool:
        return self.lower <= value <= self.upper

    def as_dict(self) -> dict[str, float]:
        return {"lower": self.lower, "upper": self.upper, "center": self.center}

    def to_dict(self) -> dict[str, Any]:
        """``{"lower", "upper", "center"}`` for JSON (infinite ends as ``"inf"``/``"-inf"``)."""
        return {key: number(value) for key, value in self.as_dict().items()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ParameterInterval:
        """Inverse of :meth:`to_dict` (``center`` is recomputed)."""
        return cls(float(data["lower"]), float(data["upper"]))


@dataclass(frozen=True)
class IntervalSetSummary:
    """What one method's intervals say as a whole: the median half-width (eq. (19)) over the parameters
    compared, and how many of those whose true value is known contain it."""

    median_half_width: float
    truth_inside: int
    truth_known: int

    @classmethod
    def of(cls, intervals: Mapping[str, ParameterInterval], names: Sequence[str] | None = None,
           truth: Mapping[str, float] | None = None) -> IntervalSetSummary:
        """Summary over ``names`` (default: every interval) of ``intervals``; ``truth``: name -> true value."""
        compared = [name for name in (intervals if names is None else names) if name in intervals]
        if not compared:
            raise InvalidInputError("intervals: none of the parameters to summarise has an interval")
        truth = truth or {}
        known = [name for name in compared if name in truth]
        return cls(float(np.median([intervals[name].half_width for name in compared])),
                   sum(intervals[name].contains(float(truth[name])) for name in known), len(known))


def median_width_ratio(intervals: Mapping[str, ParameterInterval], reference: Mapping[str, ParameterInterval],
                       names: Sequence[str]) -> float | None:
    """Median over ``names`` of half-width(intervals) / half-width(reference), over the parameters both
    have and whose reference half-width is positive: below 1, ``intervals`` are the tighter; None when
    no parameter qualifies."""
    common = [name for name in names if name in intervals and name in reference and reference[name].half_width > 0]
    if not common:
        return None
    return float(np.median([intervals[name].half_width / reference[name].half_width for name in common]))


@dataclass(frozen=True)
class BacklashSidePolygon:
    """One side of D_γ (eq. (14) right, eq. (15) left) as a convex polygon in (m, m·c).

    Attributes
    ----------
    side
        ``"left"`` (m_l, c_l; negative half-waves) or ``"right"`` (m_r, c_r; positive half-waves).
    slope_vertices
        m at the vertices, counter-clockwise; empty when the side is infeasible.
    slope_times_deadband_vertices
        p = m·c at the same vertices.
    sample_indices
        Indices (into the steady-state arrays) of the points of this side.
    steady_input_rad, strip_lower_rad, strip_upper_rad
        ū_k and the strip lo_k <= m ū_k ∓ p <= hi_k of each point (ȳ_k ∓ the widened noise bound), which
        define the polygon (eqs. (16)-(17)).
    """

    side: str
    slope_vertices: NDArray[np.float64]
    slope_times_deadband_vertices: NDArray[np.float64]
    sample_indices: NDArray[np.int64]
    steady_input_rad: NDArray[np.float64] = field(default_factory=lambda: np.empty(0))
    strip_lower_rad: NDArray[np.float64] = field(default_factory=lambda: np.empty(0))
    strip_upper_rad: NDArray[np.float64] = field(default_factory=lambda: np.empty(0))

    def __eq__(self, other: object) -> bool:
        """Field by field, arrays element-wise (:func:`identify.result_format.results_equal`)."""
        from identify.result_format import results_equal

        return results_equal(self, other)

    def inverse_slope_rows(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The polygon in (ρ, c) = (1/m, p/m) as rows G [ρ, c] <= h.

        Dividing lo <= m ū ∓ p <= hi by m > 0 gives lo ρ <= ū ∓ c <= hi ρ, again linear: the same set,
        in the coordinates in which the inverted backlash x = ρ w ± c is linear.
        """
        sign_c = -1.0 if self.side == "right" else 1.0  # right: m ū - p ; left: m ū + p
        u, lo, hi = self.steady_input_rad, self.strip_lower_rad, self.strip_upper_rad
        # lo ρ - (ū + sign_c c) <= 0  and  (ū + sign_c c) - hi ρ <= 0
        rows = np.vstack([np.column_stack([lo, -sign_c * np.ones_like(u)]),
                          np.column_stack([-hi, sign_c * np.ones_like(u)])])
        rhs = np.concatenate([u, -u])
        return rows, rhs

    def to_dict(self) -> dict[str, Any]:
        """Every attribute as lists of numbers (a part of :meth:`BacklashFeasibleSet.to_dict`)."""
        return {"side": self.side, "slope_vertices": numbers(self.slope_vertices),
                "slope_times_deadband_vertices": numbers(self.slope_times_deadband_vertices),
                "sample_indices": [int(i) for i in self.sample_indices],
                "steady_input_rad": numbers(self.steady_input_rad), "strip_lower_rad": numbers(self.strip_lower_rad),
                "strip_upper_rad": numbers(self.strip_upper_rad)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BacklashSidePolygon:
        """Inverse of :meth:`to_dict`."""
        def floats(key: str) -> NDArray[np.float64]:
            return np.asarray([float(v) for v in data[key]], dtype=float)

        return cls(str(data["side"]), floats("slope_vertices"), floats("slope_times_deadband_vertices"),
                   np.asarray(data["sample_indices"], dtype=np.int64).reshape(-1), floats("steady_input_rad"),
                   floats("strip_lower_rad"), floats("strip_upper_rad"))

    def side_line(self, slope: float, slope_times_deadband_rad: float, x_rad: ArrayLike) -> NDArray[np.float64]:
        """w = m x - p on the right side (eq. (11)), w = m x + p on the left (eq. (12)); the slope m is
        dimensionless, p = m·c and w in rad."""
        x = np.asarray(x_rad, dtype=float)
        return slope * x + (-slope_times_deadband_rad if self.side == "right" else slope_times_deadband_rad)

    def contains(self, slope: float, slope_times_deadband_rad: float) -> bool:
        """Whether (m, p = m·c) lies in this side of D_γ: m > 0, p >= 0 and every strip
        lo_k <= m ū_k ∓ p <= hi_k (eqs. (16)-(17)), up to rounding (1e-12 relative)."""
        if self.is_empty:
            return False
        value = self.side_line(slope, slope_times_deadband_rad, self.steady_input_rad)
        tolerance = 1e-12 * max(1.0, float(np.max(np.abs(value)))) if value.size else 0.0
        return bool(np.all(self.strip_lower_rad - tolerance <= value)
                    and np.all(value <= self.strip_upper_rad + tolerance)
                    and slope > 0 and slope_times_deadband_rad >= 0)

    def output_band(self, x_rad: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Lowest and highest w over every line of this side at each x: w is linear in (m, p), so over the
        convex polygon its extremes are at vertices (exact, not sampled)."""
        x = np.atleast_1d(np.asarray(x_rad, dtype=float))
        if self.is_empty:
            raise InvalidInputError(f"the {self.side} side of the backlash feasible set is empty: no band")
        sign = -1.0 if self.side == "right" else 1.0
        lines = np.outer(x, self.slope_vertices) + sign * self.slope_times_deadband_vertices[None, :]
        return lines.min(axis=1), lines.max(axis=1)

    def central_line(self) -> tuple[float, float]:
        """(m, p) of the vertex mean: a point inside the convex polygon (a reference line of this side)."""
        if self.is_empty:
            raise InvalidInputError(f"the {self.side} side of the backlash feasible set is empty: no central line")
        return float(np.mean(self.slope_vertices)), float(np.mean(self.slope_times_deadband_vertices))

    def band_width_at_largest_input_rad(self) -> float:
        """Width of :meth:`output_band` at the side's largest steady-state input |ū| (signed to the side):
        how far apart the lines of D_γ are where the data reach furthest; NaN for an empty side."""
        if self.is_empty or not self.steady_input_rad.size:
            return float("nan")
        edge = float(np.max(np.abs(self.steady_input_rad))) * (1.0 if self.side == "right" else -1.0)
        low, high = self.output_band(edge)
        return float(high[0] - low[0])

    @property
    def deadband_vertices(self) -> NDArray[np.float64]:
        """c = p/m at the vertices."""
        return self.slope_times_deadband_vertices / self.slope_vertices

    @property
    def is_empty(self) -> bool:
        return self.slope_vertices.size == 0


@dataclass(frozen=True)
class EmptyFeasibleSetExplanation:
    """Why the steady-state data admit no backlash: the conflicting points and the noise bound they need."""

    side: str
    conflicting_samples: tuple[int, ...]
    required_noise_scale: float
    message: str


@dataclass(frozen=True)
class BacklashFeasibleSet:
    """D_γ (eq. (13)) as two polygons, and its exact outer orthotope B_γ (eqs. (18)-(20)).

    ``m_l``, ``c_l``, ``m_r``, ``c_r`` are None when the set is empty; ``explanation`` then says why.
    """

    left: BacklashSidePolygon
    right: BacklashSidePolygon
    m_l: ParameterInterval | None
    c_l: ParameterInterval | None
    m_r: ParameterInterval | None
    c_r: ParameterInterval | None
    noise_bound_rad: float
    alpha_rad: NDArray[np.float64]
    explanation: EmptyFeasibleSetExplanation | None

    def __eq__(self, other: object) -> bool:
        """Field by field, arrays element-wise (:func:`identify.result_format.results_equal`)."""
        from identify.result_format import results_equal

        return results_equal(self, other)

    @property
    def is_empty(self) -> bool:
        return self.explanation is not None

    def intervals(self) -> dict[str, ParameterInterval]:
        """The four intervals keyed ``m_l c_l m_r c_r`` (eq. (6) order); raises if the set is empty."""
        if self.explanation is not None:
            raise InvalidInputError(f"the backlash feasible set is empty: {self.explanation.message}")
        assert self.m_l and self.c_l and self.m_r and self.c_r
        return {"m_l": self.m_l, "c_l": self.c_l, "m_r": self.m_r, "c_r": self.c_r}

    def contains(self, m_l: float, c_l_rad: float, m_r: float, c_r_rad: float) -> dict[str, bool]:
        """Per side (``left``, ``right``), whether the backlash (m, c) lies in D_γ (eqs. (14)-(17)); both
        False for an empty set. The slopes are dimensionless, the half-widths in rad (the fields of
        :class:`identify.plant_blocks.OutputBacklash`)."""
        return {"left": self.left.contains(m_l, m_l * c_l_rad), "right": self.right.contains(m_r, m_r * c_r_rad)}

    KIND = "backlash_feasible_set"
    VERSION = 1

    def to_dict(self) -> dict[str, Any]:
        """``{"kind": "backlash_feasible_set", "version": 1, ...}``: both polygons, the four intervals (None
        when empty), the noise bound, α and the explanation of an empty set."""
        explanation = None if self.explanation is None else {
            "side": self.explanation.side, "conflicting_samples": list(self.explanation.conflicting_samples),
            "required_noise_scale": number(self.explanation.required_noise_scale),
            "message": self.explanation.message}
        return tagged(self.KIND, self.VERSION, {
            "left": self.left.to_dict(), "right": self.right.to_dict(),
            "intervals": {name: None if interval is None else interval.to_dict()
                          for name, interval in (("m_l", self.m_l), ("c_l", self.c_l), ("m_r", self.m_r),
                                                 ("c_r", self.c_r))},
            "noise_bound_rad": number(self.noise_bound_rad), "alpha_rad": numbers(np.ravel(self.alpha_rad)),
            "alpha_shape": list(np.shape(self.alpha_rad)), "explanation": explanation})

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BacklashFeasibleSet:
        """Inverse of :meth:`to_dict`; a document of another kind or version is a ResultFormatError."""
        check_kind(data, cls.KIND, (cls.VERSION,))
        with malformed(cls.KIND):
            intervals = {name: None if data["intervals"][name] is None else
                         ParameterInterval.from_dict(data["intervals"][name]) for name in ("m_l", "c_l", "m_r", "c_r")}
            explained = data["explanation"]
            explanation = None if explained is None else EmptyFeasibleSetExplanation(
                str(explained["side"]), tuple(int(i) for i in explained["conflicting_samples"]),
                float(explained["required_noise_scale"]), str(explained["message"]))
            alpha = np.asarray([float(v) for v in data["alpha_rad"]], dtype=float).reshape(data["alpha_shape"])
            return cls(BacklashSidePolygon.from_dict(data["left"]), BacklashSidePolygon.from_dict(data["right"]),
                       **intervals, noise_bound_rad=float(data["noise_bound_rad"]), alpha_rad=alpha,
                       explanation=explanation)


def clip_polygon(vertices: NDArray[np.float64], normal: NDArray[np.float64], offset: float) -> NDArray[np.float64]:
    """Intersect a convex polygon (k x 2, counter-clockwise) with the half-plane normal·z <= offset
    (one Sutherland-Hodgman step). Returns the clipped polygon's vertices (possibly none)."""
    if len(vertices) == 0:
        return vertices
    distance = vertices @ normal - offset
    kept: list[NDArray[np.float64]] = []
    count = len(vertices)
    for k in range(count):
        current, following = vertices[k], vertices[(k + 1) % count]
        d_current, d_following = distance[k], distance[(k + 1) % count]
        if d_current <= 0.0:
            kept.append(current)
        if (d_current < 0.0 < d_following) or (d_following < 0.0 < d_current):
            weight = d_current / (d_current - d_following)
            kept.append(current + weight * (following - current))
    if not kept:
        return np.empty((0, 2))
    polygon = np.array(kept)
    # Drop repeated points that clipping through a vertex creates.
    keep = np.ones(len(polygon), dtype=bool)
    for k in range(len(polygon)):
        if np.array_equal(polygon[k], polygon[(k + 1) % len(polygon)]) and len(polygon) > 1:
            keep[k] = False
    return polygon[keep] if keep.any() else polygon[:1]


def _side_polygon(u: NDArray[np.float64], y: NDArray[np.float64], below: NDArray[np.float64],
                  above: NDArray[np.float64], sign_p: float) -> NDArray[np.float64]:
    """Vertices of {(m, p) >= 0 : y_k - below_k <= m u_k + sign_p p <= y_k + above_k}.

    The starting box is large enough to contain every point of the strips' intersection: with two distinct
    |u| the strips bound m and p (checked by the caller), and the box is then taken 4x beyond the corners
    of the parallelogram of the two most distant points.
    """
    k_low, k_high = int(np.argmin(np.abs(u))), int(np.argmax(np.abs(u)))
    corners = []
    for lo_value in (y[k_low] - below[k_low], y[k_low] + above[k_low]):
        for hi_value in (y[k_high] - below[k_high], y[k_high] + above[k_high]):
            matrix = np.array([[u[k_low], sign_p], [u[k_high], sign_p]])
            corners.append(np.linalg.solve(matrix, [lo_value, hi_value]))
    extent = 4.0 * max(1.0, float(np.max(np.abs(corners))))
    polygon = np.array([[0.0, 0.0], [extent, 0.0], [extent, extent], [0.0, extent]])
    for k in np.argsort(-np.abs(u)):  # most informative strips first keeps the polygon small
        row = np.array([u[k], sign_p])
        polygon = clip_polygon(polygon, row, y[k] + above[k])
        polygon = clip_polygon(polygon, -row, -(y[k] - below[k]))
        if len(polygon) == 0:
            break
    return polygon


def _explain_empty(side: str, indices: NDArray[np.int64], u: NDArray[np.float64], y: NDArray[np.float64],
                   below: NDArray[np.float64], above: NDArray[np.float64], sign_p: float) -> EmptyFeasibleSetExplanation:
    """Smallest s such that the noise interval scaled by s makes the side feasible (an LP in m, p, s);
    the points whose constraints bind at the optimum are the ones that conflict."""
    count = len(u)
    # variables (m, p, s): m u + sign_p p - s above <= y ;  -(m u + sign_p p) - s below <= -y
    A = np.vstack([np.column_stack([u, np.full(count, sign_p), -above]),
                   np.column_stack([-u, np.full(count, -sign_p), -below])])
    b = np.concatenate([y, -y])
    solution = linprog([0.0, 0.0, 1.0], A_ub=A, b_ub=b, bounds=[(0, None), (0, None), (0, None)], method="highs")
    scale = float(solution.x[2]) if solution.status == 0 else float("inf")
    if solution.status == 0:
        marginals = np.abs(solution.ineqlin.marginals)
        binding = np.flatnonzero((marginals[:count] + marginals[count:]) > 1e-9)
        conflicting = tuple(int(indices[k]) for k in binding)
    else:
        conflicting = tuple(int(k) for k in indices)
    parameter = "m_r, c_r" if side == "right" else "m_l, c_l"
    shown = ", ".join(str(k) for k in conflicting[:10]) + (f" and {len(conflicting) - 10} more"
                                                           if len(conflicting) > 10 else "")
    halves = "positive" if side == "right" else "negative"
    if math.isfinite(scale):
        message = (
            f"no {side} backlash line ({parameter}) passes within the noise bound of all "
            f"{count} steady-state points of the {halves} half-waves; "
            f"the points [{shown}] conflict, and the noise bound would have to be {scale:.3g} times "
            "larger to reconcile them. Check: the noise bound is too small (quantisation, drift), the points are "
            "not at steady state (half-waves too short, or x_t overshoots: redesign the filter pole), or the "
            "model is not an output backlash (slopes not constant, other nonlinearity)."
        )
    else:
        message = (
            f"no {side} backlash line ({parameter}) fits the {count} steady-state points of the {halves} "
            f"half-waves (points [{shown}]), and no finite enlargement of the noise bound "
            f"({float(np.max(np.maximum(above, below))):.3g} rad at most) that the solver could compute reconciles "
            "them. Check: the noise bound is in radians and not far too small, the output grows with the input "
            "(the encoder's direction sign), u and y are the right columns, or the model is not an output backlash."
        )
    return EmptyFeasibleSetExplanation(side, conflicting, scale, message)


def _interval(values: NDArray[np.float64]) -> ParameterInterval:
    low, high = float(np.min(values)), float(np.max(values))
    pad_low = _PAD_RELATIVE * max(abs(low), abs(high), 1e-300)
    return ParameterInterval(low - pad_low, high + pad_low)


def bound_backlash_parameters(steady_input_rad: ArrayLike, steady_output_rad: ArrayLike, noise_bound_rad: float | ArrayLike,
                              *, filter_step_amplitude_rad: float | None = None) -> BacklashFeasibleSet:
    """Exact feasible parameter set D_γ and orthotope B_γ of the output backlash, eqs. (11)-(20).

    Parameters
    ----------
    steady_input_rad
        ū_s, the 2M steady-state inputs, positive (positive half-wave, eq. (11)) and negative (eq. (12))
        mixed in any order; with unit static gain (8) they equal the steady inner signal.
    steady_output_rad
        ȳ_s, the measured steady-state outputs.
    noise_bound_rad
        Δη̄ >= 0, one value or one per point (eq. (5)).
    filter_step_amplitude_rad
        r̄_F of the filter-pole search; gives α_s = 2Δη̄_s|ū_s|/r̄_F (eqs. (14)-(15)). None: α = 0.

    Returns
    -------
    BacklashFeasibleSet
        Polygons, orthotope (padded by 1e-12 relative against rounding), or an explanation if empty.

    Examples
    --------
    Two noise-free points per side on m = 0.25, c_r = 0.04, c_l = 0.06 with Δη = 1e-3: each side is a
    parallelogram with m in [0.25 - 2Δη, 0.25 + 2Δη]:

    >>> u = np.array([1.0, 2.0, -1.0, -2.0])
    >>> y = np.array([0.25 * (1 - 0.04), 0.25 * (2 - 0.04), 0.25 * (-1 + 0.06), 0.25 * (-2 + 0.06)])
    >>> fps = bound_backlash_parameters(u, y, 1e-3)
    >>> round(fps.m_r.lower, 9), round(fps.m_r.upper, 9)
    (0.248, 0.252)
    """
    u = as_signal("steady_input_rad", steady_input_rad, min_samples=4)
    y = as_signal("steady_output_rad", steady_output_rad, min_samples=4)
    same_length(steady_input_rad=u, steady_output_rad=y)
    noise = np.broadcast_to(np.asarray(noise_bound_rad, dtype=float), u.shape).copy() if np.ndim(noise_bound_rad) == 0 \
        else as_signal("noise_bound_rad", noise_bound_rad)
    if noise.shape != u.shape:
        raise InvalidInputError(f"noise_bound_rad: expected one value or {u.size} values, got {noise.size}")
    if not np.all(np.isfinite(noise)) or np.any(noise < 0.0):
        raise InvalidInputError(f"noise_bound_rad: expected finite values >= 0, got {noise_bound_rad!r}")
    zero = np.flatnonzero(u == 0.0)
    if zero.size:
        raise InvalidInputError(f"steady_input_rad: sample {zero[0]} is 0; a steady-state point must come from a "
                                "positive or a negative half-wave")
    if filter_step_amplitude_rad is None:
        alpha = np.zeros_like(u)
    else:
        step = float(filter_step_amplitude_rad)
        if not np.isfinite(step) or step == 0.0:
            raise InvalidInputError(f"filter_step_amplitude_rad: expected a finite non-zero number, got {filter_step_amplitude_rad!r}")
        alpha = 2.0 * noise * np.abs(u) / abs(step)
    widened = noise + alpha
    polygons: dict[str, BacklashSidePolygon] = {}
    explanation: EmptyFeasibleSetExplanation | None = None
    for side, mask, sign_p in (("right", u > 0.0, -1.0), ("left", u < 0.0, 1.0)):
        indices = np.flatnonzero(mask).astype(np.int64)
        distinct = np.unique(np.abs(u[indices]))
        if distinct.size < 2:
            half = "positive" if side == "right" else "negative"
            raise InvalidInputError(
                f"steady_input_rad: the {half} half-waves give {distinct.size} distinct amplitude(s); at least two "
                f"are needed to bound the {side} slope and dead band"
            )
        vertices = _side_polygon(u[indices], y[indices], widened[indices], widened[indices], sign_p)
        if len(vertices) == 0 and explanation is None:
            explanation = _explain_empty(side, indices, u[indices], y[indices], widened[indices], widened[indices], sign_p)
        if len(vertices) and np.min(vertices[:, 0]) <= 0.0:
            raise InvalidInputError(
                f"steady_output_rad: the {side} points admit a zero slope (outputs within the noise bound of 0); "
                "use larger amplitudes"
            )
        polygons[side] = BacklashSidePolygon(side, vertices[:, 0].copy() if len(vertices) else np.empty(0),
                                             vertices[:, 1].copy() if len(vertices) else np.empty(0), indices,
                                             u[indices], y[indices] - widened[indices], y[indices] + widened[indices])
    left, right = polygons["left"], polygons["right"]
    if explanation is not None:
        return BacklashFeasibleSet(left, right, None, None, None, None, float(np.max(noise)), alpha, explanation)
    return BacklashFeasibleSet(
        left, right,
        m_l=_interval(left.slope_vertices), c_l=_interval(left.deadband_vertices),
        m_r=_interval(right.slope_vertices), c_r=_interval(right.deadband_vertices),
        noise_bound_rad=float(np.max(noise)), alpha_rad=alpha, explanation=None,
    )
