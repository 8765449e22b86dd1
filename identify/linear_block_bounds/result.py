"""The result of :func:`~identify.linear_block_bounds.bound_linear_block` (:class:`LinearBlockBounds`, and its
result-file form) and the explanation of an empty set (:class:`EmptyLinearSetExplanation`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from numpy.typing import ArrayLike

from identify.feasible_parameter_set import ParameterInterval
from identify.linear_block_bounds.problem import LinearModelOrders
from identify.result_format import check_kind, malformed, number, tagged
from identify.validation import InvalidInputError

if TYPE_CHECKING:
    from identify.linear_block_response import MagnitudeEnvelope


@dataclass(frozen=True)
class EmptyLinearSetExplanation:
    """Why no linear block fits: the equations that conflict and the extra error they would need."""

    conflicting_samples: tuple[int, ...]
    required_extra_error_rad: float
    message: str


@dataclass(frozen=True, kw_only=True)
class LinearBlockBounds:
    """Guaranteed parameter bounds of the linear block (Section 5), as data; built from keywords only.

    Attributes
    ----------
    method
        ``"paper"`` or ``"coupled"``.
    orders
        The model structure.
    intervals
        Outer bounds per parameter name (``a1``, ..., ``b<nb>``); empty when the set is empty.
    inner_lower, inner_upper
        Per parameter, values attained by points verified to satisfy the exact (coupled) equations; the
        exact bounds lie between these and the outer ones. None for the paper method.
    inner_point
        One verified point θ of the exact feasible set (coupled method), or None.
    explanation
        Set when the feasible set is empty.
    num_linear_programs, num_tightening_rounds, feasible_orthants
        Solver diagnostics.
    max_certificate_gap
        Largest difference between a solver's optimum and the certified (Neumaier-Shcherbina) bound used.
    notes
        One sentence per bound that is looser than the method would give, saying which parameter and why
        (a bounding LP that HiGHS could not solve: the bound is the last valid one before that LP).
    windowing
        How the record was split for the bounding LPs (windows, passes, joint samples), in words.
    """

    method: str
    orders: LinearModelOrders
    intervals: dict[str, ParameterInterval]
    inner_lower: dict[str, float] | None = None
    inner_upper: dict[str, float] | None = None
    inner_point: dict[str, float] | None = None
    explanation: EmptyLinearSetExplanation | None = None
    num_linear_programs: int = 0
    num_tightening_rounds: int = 0
    feasible_orthants: tuple[tuple[int, ...], ...] = ()
    max_certificate_gap: float = field(default=0.0)
    notes: tuple[str, ...] = field(default=())
    windowing: str = field(default="")

    @property
    def is_empty(self) -> bool:
        return self.explanation is not None

    @property
    def outer_inner_ratio(self) -> dict[str, float | None] | None:
        """How tight the guarantee is, per parameter: the width of the outer (guaranteed) interval over the width
        the verified inner values span. The exact feasible set's projection lies between the two, so the ratio
        bounds how much wider than exact the guaranteed interval can be: 1 means the interval is the exact one,
        4 that it may be up to four times too wide. None for a parameter without two distinct verified values,
        and None altogether when no inner values were computed (the paper method, or a record longer than the
        inner-values limit)."""
        if self.inner_lower is None or self.inner_upper is None:
            return None
        ratios: dict[str, float | None] = {}
        for name, interval in self.intervals.items():
            low, high = self.inner_lower.get(name, math.nan), self.inner_upper.get(name, math.nan)
            inner = high - low
            ratios[name] = ((interval.upper - interval.lower) / inner
                            if math.isfinite(inner) and inner > 0 else None)
        return ratios

    def magnitude_envelope(self, omega_rad_per_sample: ArrayLike) -> MagnitudeEnvelope:
        """The guaranteed range of |G(e^{jω})| over the parameter box at ω (rad/sample), with the central
        model's |G| (:class:`identify.linear_block_response.MagnitudeEnvelope`); raises for an empty set."""
        from identify.linear_block_response import MagnitudeEnvelope

        if self.is_empty:
            raise InvalidInputError("the linear-block feasible set is empty: no envelope")
        return MagnitudeEnvelope.of_box(self.intervals, omega_rad_per_sample)

    KIND = "linear_block_bounds"
    VERSION = 2
    READS = (1, 2)
    """Version 2 added ``outer_inner_ratio`` (derived from the intervals and the inner values; read back from
    them, so version 1 documents read the same)."""

    def to_dict(self) -> dict[str, Any]:
        """``{"kind": "linear_block_bounds", "version": 2, ...}``: every attribute as plain JSON values, and
        :attr:`outer_inner_ratio`."""
        def values(mapping: dict[str, float] | None) -> dict[str, float | str] | None:
            return None if mapping is None else {name: number(value) for name, value in mapping.items()}

        explanation = None if self.explanation is None else {
            "conflicting_samples": list(self.explanation.conflicting_samples),
            "required_extra_error_rad": number(self.explanation.required_extra_error_rad),
            "message": self.explanation.message}
        return tagged(self.KIND, self.VERSION, {
            "method": self.method, "orders": {"na": self.orders.na, "nk": self.orders.nk, "nb": self.orders.nb},
            "intervals": {name: interval.to_dict() for name, interval in self.intervals.items()},
            "inner_lower": values(self.inner_lower), "inner_upper": values(self.inner_upper),
            "inner_point": values(self.inner_point), "explanation": explanation,
            "outer_inner_ratio": None if self.outer_inner_ratio is None else {
                name: None if ratio is None else number(ratio) for name, ratio in self.outer_inner_ratio.items()},
            "num_linear_programs": self.num_linear_programs, "num_tightening_rounds": self.num_tightening_rounds,
            "feasible_orthants": [list(orthant) for orthant in self.feasible_orthants],
            "max_certificate_gap": number(self.max_certificate_gap), "notes": list(self.notes),
            "windowing": self.windowing})

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LinearBlockBounds:
        """Inverse of :meth:`to_dict`; a document of another kind or version is a ResultFormatError."""
        check_kind(data, cls.KIND, cls.READS)
        with malformed(cls.KIND):
            def values(key: str) -> dict[str, float] | None:
                return None if data[key] is None else {str(k): float(v) for k, v in data[key].items()}

            explained = data["explanation"]
            orders = data["orders"]
            return cls(
                method=str(data["method"]),
                orders=LinearModelOrders(int(orders["na"]), int(orders["nk"]), int(orders["nb"])),
                intervals={str(k): ParameterInterval.from_dict(v) for k, v in data["intervals"].items()},
                inner_lower=values("inner_lower"), inner_upper=values("inner_upper"),
                inner_point=values("inner_point"),
                explanation=None if explained is None else EmptyLinearSetExplanation(
                    tuple(int(i) for i in explained["conflicting_samples"]),
                    float(explained["required_extra_error_rad"]), str(explained["message"])),
                num_linear_programs=int(data["num_linear_programs"]),
                num_tightening_rounds=int(data["num_tightening_rounds"]),
                feasible_orthants=tuple(tuple(int(sign) for sign in orthant) for orthant in data["feasible_orthants"]),
                max_certificate_gap=float(data["max_certificate_gap"]),
                notes=tuple(str(note) for note in data.get("notes", ())), windowing=str(data.get("windowing", "")))
