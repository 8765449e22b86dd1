"""Bounds on the unmeasured inner signal x_t of a linear system with output backlash (Section 4 of Cerone et al. 2009).

Invertible samples (Proposition 2): if y_t > y_{t-1} + 2Δη the backlash output rose, so it moved along the
right line, w_t = m_r(x_t - c_r), and x_t = (y_t - η_t)/m_r + c_r (eqs. (25), (27)); if y_t < y_{t-1} - 2Δη it
fell along the left line and x_t = (y_t - η_t)/m_l - c_l (eqs. (24), (26)). In (m, p = m·c) this is
(y - η ± p)/m, linear-fractional in (m, p, η), so its extremes over D_γ and |η| <= Δη are at the polygon
vertices and η = ±Δη (Proposition 4): every bound here is exact over D_γ.

Beyond the paper, a non-invertible sample is not dropped. Every branch of eq. (2) puts x_t between
w_t/m_l - c_l (left line: equality) and w_t/m_r + c_r (right line: equality; inside the dead band x_t lies
strictly between the two), so

    min(w/m_l - c_l, w/m_r + c_r) <= x_t <= max(w/m_l - c_l, w/m_r + c_r),

which is the band w/m_l - c_l <= x_t <= w/m_r + c_r wherever the two lines do not cross, and stays valid
where they do. Its extremes over D_γ and the noise are again at vertices and η = ±Δη.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.feasible_parameter_set import BacklashFeasibleSet
from identify.linear_block_bounds import SharedBacklashConstraints
from identify.result_format import check_kind, malformed, numbers, tagged
from identify.validation import InvalidInputError, as_signal

__all__ = ["InnerSignalBounds", "bound_inner_signal", "shared_backlash_constraints"]

_PAD_RELATIVE = 1e-12


@dataclass(frozen=True)
class InnerSignalBounds:
    """x_t^min <= x_t <= x_t^max for every sample (eq. (23)), with x^c and Δx of eq. (28).

    Attributes
    ----------
    lower_rad, upper_rad
        x_t^min and x_t^max; NaN where y_t is missing (not measured), where nothing bounds x_t.
    invertible
        True where Proposition 2 holds (|y_t - y_{t-1}| > 2Δη; sample 0 has no predecessor and is never
        invertible); elsewhere the band bound applies.
    direction
        +1 where the output rose (right line), -1 where it fell (left line), 0 for non-invertible samples.
    """

    lower_rad: NDArray[np.float64]
    upper_rad: NDArray[np.float64]
    invertible: NDArray[np.bool_]
    direction: NDArray[np.int8]

    def __eq__(self, other: object) -> bool:
        """Field by field, arrays element-wise (:func:`identify.result_format.results_equal`)."""
        from identify.result_format import results_equal

        return results_equal(self, other)

    @property
    def center_rad(self) -> NDArray[np.float64]:
        """x_t^c of eq. (28)."""
        return 0.5 * (self.lower_rad + self.upper_rad)

    @property
    def half_width_rad(self) -> NDArray[np.float64]:
        """Δx_t of eq. (28)."""
        return 0.5 * (self.upper_rad - self.lower_rad)

    @property
    def num_invertible(self) -> int:
        return int(np.count_nonzero(self.invertible))

    def contains(self, inner_rad: ArrayLike) -> NDArray[np.bool_]:
        """Per sample, whether x_t^min <= x_t <= x_t^max for a signal of the same length (e.g. a simulated
        true x_t)."""
        x = np.asarray(inner_rad, dtype=float)
        if x.shape != self.lower_rad.shape:
            raise InvalidInputError(f"inner_rad: expected {self.lower_rad.size} samples like the bounds, got shape "
                                    f"{x.shape}")
        return (self.lower_rad <= x) & (x <= self.upper_rad)

    def median_half_width_rad(self, *, invertible: bool) -> float:
        """Median Δx_t over the invertible samples (``invertible=True``) or the others; nan if there are none."""
        chosen = self.half_width_rad[self.invertible == invertible]
        chosen = chosen[np.isfinite(chosen)]  # a missing sample has no bound
        return float(np.median(chosen)) if chosen.size else float("nan")

    KIND = "inner_signal_bounds"
    VERSION = 1

    def to_dict(self) -> dict[str, Any]:
        """``{"kind": "inner_signal_bounds", "version": 1, ...}``: the four per-sample arrays as lists."""
        return tagged(self.KIND, self.VERSION, {
            "lower_rad": numbers(self.lower_rad), "upper_rad": numbers(self.upper_rad),
            "invertible": [bool(v) for v in self.invertible], "direction": [int(v) for v in self.direction]})

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> InnerSignalBounds:
        """Inverse of :meth:`to_dict`; a document of another kind or version is a ResultFormatError."""
        check_kind(data, cls.KIND, (cls.VERSION,))
        with malformed(cls.KIND):
            lower = np.asarray([float(v) for v in data["lower_rad"]], dtype=float)
            upper = np.asarray([float(v) for v in data["upper_rad"]], dtype=float)
            invertible = np.asarray(data["invertible"], dtype=bool).reshape(-1)
            direction = np.asarray(data["direction"], dtype=np.int8).reshape(-1)
            if not lower.shape == upper.shape == invertible.shape == direction.shape:
                raise ValueError("lower_rad, upper_rad, invertible and direction differ in length")
            return cls(lower, upper, invertible, direction)


def _line_extremes(y: NDArray[np.float64], noise: float, slopes: NDArray[np.float64],
                   offsets: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """min and max over vertices (slope m, offset ±p) and η = ±Δη of (y_t - η + offset)/m, per sample."""
    values = np.concatenate([
        (y[:, None] - noise + offsets[None, :]) / slopes[None, :],
        (y[:, None] + noise + offsets[None, :]) / slopes[None, :],
    ], axis=1)
    return values.min(axis=1), values.max(axis=1)


def bound_inner_signal(output_rad: ArrayLike, noise_bound_rad: float, backlash: BacklashFeasibleSet) -> InnerSignalBounds:
    """Bounds on x_t from the dynamic experiment's outputs, Propositions 2-4 plus the band bound.

    Parameters
    ----------
    output_rad
        y_t, t = 0..N-1, measured output of the dynamic (PRBS) experiment; NaN marks a sample not measured
        (its bounds are NaN, and the sample after it is not invertible: Proposition 2 needs y_{t-1}).
    noise_bound_rad
        Δη >= 0 of eq. (5).
    backlash
        D_γ from :func:`identify.feasible_parameter_set.bound_backlash_parameters` (not empty).

    Returns
    -------
    InnerSignalBounds
        Guaranteed bounds (padded by 1e-12 relative against rounding) and the invertible-sample mask.
    """
    y = as_signal("output_rad", output_rad, min_samples=2, missing_allowed=True)
    noise = float(noise_bound_rad)
    if not np.isfinite(noise) or noise < 0.0:
        raise InvalidInputError(f"noise_bound_rad: expected a finite number >= 0, got {noise_bound_rad!r}")
    if not isinstance(backlash, BacklashFeasibleSet):
        raise InvalidInputError(f"backlash: expected a BacklashFeasibleSet, got {type(backlash).__name__}")
    if backlash.is_empty:
        raise InvalidInputError(f"backlash: the feasible set is empty ({backlash.explanation and backlash.explanation.message})")
    right_low, right_high = _line_extremes(y, noise, backlash.right.slope_vertices,
                                           backlash.right.slope_times_deadband_vertices)
    left_low, left_high = _line_extremes(y, noise, backlash.left.slope_vertices,
                                         -backlash.left.slope_times_deadband_vertices)
    lower = np.minimum(left_low, right_low)
    upper = np.maximum(left_high, right_high)
    with np.errstate(invalid="ignore"):
        step = np.diff(y)  # NaN next to a missing sample: neither rising nor falling
    direction = np.zeros(y.size, dtype=np.int8)
    direction[1:][step > 2.0 * noise] = 1
    direction[1:][step < -2.0 * noise] = -1
    rising, falling = direction == 1, direction == -1
    lower = np.where(rising, right_low, np.where(falling, left_low, lower))
    upper = np.where(rising, right_high, np.where(falling, left_high, upper))
    pad = _PAD_RELATIVE * np.maximum(1.0, np.maximum(np.abs(lower), np.abs(upper)))
    return InnerSignalBounds(lower - pad, upper + pad, direction != 0, direction)


def shared_backlash_constraints(output_rad: ArrayLike, noise_bound_rad: float, backlash: BacklashFeasibleSet,
                                inner: InnerSignalBounds) -> SharedBacklashConstraints:
    """Constraints that make every inverted sample use the same backlash (for the coupled linear bounds).

    Eqs. (24)-(27) bound each x_t over all of D_γ separately; but the true γ is one point of D_γ for all t.
    With ρ = 1/m the inversions x_t = ρ_r(y_t - η_t) + c_r and x_t = ρ_l(y_t - η_t) - c_l are linear in
    (ρ, c) up to ζ_t = ρ η_t, |ζ_t| <= ρ^max Δη, and D_γ is a polygon in (ρ, c): see
    :class:`identify.linear_block_bounds.SharedBacklashConstraints`.
    """
    y = as_signal("output_rad", output_rad, min_samples=2, missing_allowed=True)
    if y.size != inner.lower_rad.size:
        raise InvalidInputError(f"output_rad: expected {inner.lower_rad.size} samples like the inner-signal bounds, got {y.size}")
    noise = float(noise_bound_rad)
    if not np.isfinite(noise) or noise < 0.0:
        raise InvalidInputError(f"noise_bound_rad: expected a finite number >= 0, got {noise_bound_rad!r}")
    if backlash.is_empty:
        raise InvalidInputError("backlash: the feasible set is empty")
    left_rows, left_rhs = backlash.left.inverse_slope_rows()
    right_rows, right_rhs = backlash.right.inverse_slope_rows()
    rows = np.zeros((left_rows.shape[0] + right_rows.shape[0], 4))
    rows[: left_rows.shape[0], 0:2] = left_rows
    rows[left_rows.shape[0]:, 2:4] = right_rows
    rhs = np.concatenate([left_rhs, right_rhs])
    bounds = []
    for polygon in (backlash.left, backlash.right):
        rho = 1.0 / polygon.slope_vertices
        c = polygon.deadband_vertices
        bounds.append((rho.min(), rho.max(), c.min(), c.max()))
    pad = _PAD_RELATIVE
    lower = np.array([bounds[0][0], bounds[0][2], bounds[1][0], bounds[1][2]])
    upper = np.array([bounds[0][1], bounds[0][3], bounds[1][1], bounds[1][3]])
    lower, upper = lower - pad * np.abs(lower) - 1e-15, upper + pad * np.abs(upper) + 1e-15
    indices = np.flatnonzero(inner.invertible).astype(np.int64)
    rising = inner.direction[indices] == 1
    rho_max = np.where(rising, upper[2], upper[0])
    return SharedBacklashConstraints(indices, rising, y[indices], rho_max * noise * (1.0 + pad), rows, rhs, lower, upper)
