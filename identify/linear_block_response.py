"""The frequency response of the linear block G(q) = B(q^-1)/A(q^-1) of Section 5 of Cerone, Piga and
Regruto (2009), over a box of its parameters, and the one parser of the parameter names ``a1``, ``b2``.

The envelope is guaranteed: the box of :class:`identify.linear_block_bounds.LinearBlockBounds` contains the
feasible set, so the |G| of every feasible model lies in it (it is wider than the set's own, because box
models need not be feasible nor have unit static gain, eq. (8)). ``LinearBlockBounds.magnitude_envelope``
is the usual entry point.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.feasible_parameter_set import ParameterInterval
from identify.validation import InvalidInputError

__all__ = ["MagnitudeEnvelope", "box_magnitude_envelope", "linear_parameter", "magnitude", "polynomials"]

_NAME = re.compile(r"([ab])(\d+)")


def linear_parameter(name: str) -> tuple[str, int] | None:
    """``("a", i)`` for ``a<i>`` (a coefficient of A(q^-1)), ``("b", j)`` for ``b<j>`` (of B(q^-1)), None for
    any other name (``m_l``, ``c_r``, ...). The one reading of these names in the package."""
    match = _NAME.fullmatch(name)
    return None if match is None else (match.group(1), int(match.group(2)))


def polynomials(theta: Mapping[str, float]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(B coefficients of q^0..q^-nb, A coefficients 1, a_1..a_na) from ``{a1.., b<nk>..}``; other names are
    ignored. Raises InvalidInputError without any ``b<j>``."""
    terms: dict[str, dict[int, float]] = {"a": {}, "b": {}}
    for key, value in theta.items():
        parsed = linear_parameter(key)
        if parsed is not None:
            terms[parsed[0]][parsed[1]] = float(value)
    if not terms["b"]:
        raise InvalidInputError(f"linear parameters: expected b<k> of B(q^-1), got {', '.join(sorted(theta)) or 'none'}")
    a = np.zeros(max(terms["a"], default=0) + 1)
    a[0] = 1.0
    for index, value in terms["a"].items():
        a[index] = value
    b = np.zeros(max(terms["b"]) + 1)
    for index, value in terms["b"].items():
        b[index] = value
    return b, a


def magnitude(b: ArrayLike, a: ArrayLike, omega_rad_per_sample: ArrayLike) -> NDArray[np.float64]:
    """|B(e^{-jω}) / A(e^{-jω})| at normalised angular frequencies ω (rad/sample); +inf at a pole."""
    omega = np.atleast_1d(np.asarray(omega_rad_per_sample, dtype=float))
    z_inv = np.exp(-1j * omega)
    numerator = np.polyval(np.asarray(b, dtype=float)[::-1], z_inv)
    denominator = np.polyval(np.asarray(a, dtype=float)[::-1], z_inv)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(numerator) / np.abs(denominator)


def _zonotope_modulus_range(centre: NDArray[np.complex128],
                            generators: NDArray[np.complex128]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Smallest and largest |z| over z = centre + Σ_k t_k g_k, |t_k| <= 1, per row (one row per frequency).

    The set is a zonotope of the complex plane, a convex polygon with at most 2p vertices: with every
    generator turned into the upper half-plane and sorted by angle, the boundary runs from centre - Σ g_k
    by steps 2 g_k up to centre + Σ g_k and back by -2 g_k. |z| is convex, so its maximum is at a vertex; its
    minimum is 0 if the polygon holds the origin, else the distance from the origin to the nearest edge.
    """
    flip = (generators.imag < 0) | ((generators.imag == 0) & (generators.real < 0))
    g = np.where(flip, -generators, generators)
    g = np.take_along_axis(g, np.argsort(np.angle(g), axis=1, kind="stable"), axis=1)
    total = g.sum(axis=1)
    steps = np.concatenate([2.0 * g, -2.0 * g], axis=1)
    vertices = (centre - total)[:, None] + np.concatenate(
        [np.zeros((g.shape[0], 1)), np.cumsum(steps, axis=1)[:, :-1]], axis=1)
    largest = np.max(np.abs(vertices), axis=1)
    start, edge = vertices, steps
    to_origin = -start
    cross = edge.real * to_origin.imag - edge.imag * to_origin.real
    length2 = np.abs(edge) ** 2
    inside = np.all(cross >= -1e-15 * np.maximum(length2, 1e-300), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        along = np.where(length2 > 0, (to_origin.real * edge.real + to_origin.imag * edge.imag) / length2, 0.0)
    nearest = start + np.clip(along, 0.0, 1.0) * edge
    # A flat zonotope (collinear generators) has no interior: the origin is in it only if it is on an edge.
    following = np.roll(vertices, -1, axis=1)
    area = 0.5 * np.abs(np.sum(vertices.real * following.imag - following.real * vertices.imag, axis=1))
    perimeter = np.sum(np.sqrt(length2), axis=1)
    has_interior = area > 1e-12 * perimeter**2
    smallest = np.where(inside & has_interior, 0.0, np.min(np.abs(nearest), axis=1))
    return smallest, largest


def box_magnitude_envelope(box: Mapping[str, ParameterInterval],
                           omega_rad_per_sample: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact lowest and highest |G(e^{jω})| over a box of θ = (a_1..a_na, b_nk..b_nb), G = B(q^-1)/A(q^-1).

    B(e^{-jω}) depends only on b and A(e^{-jω}) only on a, each linearly, so over the box each ranges over a
    zonotope of the complex plane, independently of the other; hence sup |G| = max|B| / min|A| and
    inf |G| = min|B| / max|A| exactly (+inf where some A of the box vanishes on the unit circle, i.e. a model
    of the box has a pole there). Names other than ``a<i>``/``b<j>`` are ignored.
    """
    omega = np.atleast_1d(np.asarray(omega_rad_per_sample, dtype=float))
    terms: dict[str, dict[int, ParameterInterval]] = {"a": {}, "b": {}}
    for key, interval in box.items():
        parsed = linear_parameter(key)
        if parsed is not None:
            terms[parsed[0]][parsed[1]] = interval
    if not terms["b"]:
        raise InvalidInputError(f"box: expected parameters b<k> of B(q^-1), got {', '.join(sorted(box)) or 'none'}")

    def zonotope(part: Mapping[int, ParameterInterval], constant: float) -> tuple[NDArray, NDArray]:
        if not part:
            return np.full(omega.shape, constant, dtype=complex), np.zeros((omega.size, 1), dtype=complex)
        powers = np.array(sorted(part))
        phasors = np.exp(-1j * np.outer(omega, powers))
        centre = constant + phasors @ np.array([part[k].center for k in powers])
        return centre, phasors * np.array([part[k].half_width for k in powers])[None, :]

    b_min, b_max = _zonotope_modulus_range(*zonotope(terms["b"], 0.0))
    a_min, a_max = _zonotope_modulus_range(*zonotope(terms["a"], 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        upper = np.where(a_min > 0, b_max / np.where(a_min > 0, a_min, 1.0), np.inf)
        lower = b_min / a_max
    return lower, upper


_TOLERANCE = 1e-9
"""Relative slack of :meth:`MagnitudeEnvelope.contains` (the envelope is exact up to rounding)."""


@dataclass(frozen=True)
class MagnitudeEnvelope:
    """The guaranteed range of |G(e^{jω})| over a parameter box, and the central model's |G|.

    Attributes
    ----------
    omega_rad_per_sample
        ω, 0..π.
    lower, upper
        inf and sup of |G| over the box (``upper`` is +inf where a box model has a pole on the unit circle,
        ``lower`` is 0 where one has a zero there).
    central
        |G| of the box's centre θ^c (eq. (19) applied to Section 5).
    """

    omega_rad_per_sample: NDArray[np.float64]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]
    central: NDArray[np.float64]

    @classmethod
    def of_box(cls, box: Mapping[str, ParameterInterval], omega_rad_per_sample: ArrayLike) -> MagnitudeEnvelope:
        """The envelope of a box ``{a1.., b<k>..: interval}`` (:func:`box_magnitude_envelope`)."""
        omega = np.atleast_1d(np.asarray(omega_rad_per_sample, dtype=float))
        lower, upper = box_magnitude_envelope(box, omega)
        centre = polynomials({name: interval.center for name, interval in box.items()})
        return cls(omega, lower, upper, magnitude(*centre, omega))

    @staticmethod
    def _db(values: NDArray[np.float64]) -> NDArray[np.float64]:
        with np.errstate(divide="ignore"):
            return 20.0 * np.log10(values)

    @property
    def lower_db(self) -> NDArray[np.float64]:
        return self._db(self.lower)

    @property
    def upper_db(self) -> NDArray[np.float64]:
        return self._db(self.upper)

    @property
    def central_db(self) -> NDArray[np.float64]:
        return self._db(self.central)

    @property
    def bounded(self) -> NDArray[np.bool_]:
        """Frequencies with a finite width in dB (an upper bound, and a lower bound above 0)."""
        return np.isfinite(self.upper_db - self.lower_db)

    @property
    def bounded_fraction(self) -> float:
        return float(np.mean(self.bounded))

    @property
    def unbounded_above_fraction(self) -> float:
        """Fraction of frequencies where some box model has a pole on the unit circle."""
        return float(np.mean(~np.isfinite(self.upper)))

    @property
    def zero_below_fraction(self) -> float:
        """Fraction of frequencies where some box model has a zero on the unit circle (lower bound 0)."""
        return float(np.mean(self.lower <= 0.0))

    @property
    def median_width_db(self) -> float:
        """Median of upper_db - lower_db where it is bounded (nan if nowhere)."""
        width = (self.upper_db - self.lower_db)[self.bounded]
        return float(np.median(width)) if width.size else float("nan")

    def contains(self, magnitude_values: ArrayLike) -> NDArray[np.bool_]:
        """Per frequency, whether a |G| lies in the envelope (up to rounding)."""
        values = np.asarray(magnitude_values, dtype=float)
        return (self.lower * (1 - _TOLERANCE) <= values) & (values <= self.upper * (1 + _TOLERANCE))

    def fraction_containing(self, magnitude_values: ArrayLike) -> float:
        """Fraction of frequencies where a |G| (e.g. the true model's) lies in the envelope."""
        return float(np.mean(self.contains(magnitude_values)))
