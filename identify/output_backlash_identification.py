"""The three-stage bounding procedure of Cerone, Piga and Regruto (2009) in one call.

1. Steady-state points -> exact backlash feasible set D_γ and orthotope B_γ (Section 3,
   :mod:`identify.feasible_parameter_set`).
2. Dynamic (PRBS) output -> bounds on the inner signal x_t for every sample (Section 4,
   :mod:`identify.inner_signal_bounds`).
3. Input and inner-signal bounds -> guaranteed bounds on the linear block with unit static gain (Section 5,
   :mod:`identify.linear_block_bounds`).

An empty feasible set at stage 1 or 3 is returned as a result whose ``explanation`` says which samples
conflict and what to check.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from numpy.typing import ArrayLike

from identify.feasible_parameter_set import BacklashFeasibleSet, ParameterInterval, bound_backlash_parameters
from identify.inner_signal_bounds import InnerSignalBounds, bound_inner_signal, shared_backlash_constraints
from identify.linear_block_bounds import (DEFAULT_JOINT_SAMPLES, DEFAULT_MOMENT_SAMPLES, DEFAULT_PARTITION_SAMPLES,
                                          DEFAULT_WINDOW_SAMPLES, LINEAR_BOUND_METHODS, LinearBlockBounds, LinearModelOrders, MapFunction, Progress,
                                          bound_linear_block)
from identify.result_format import check_kind, malformed, number, tagged
from identify.validation import InvalidInputError, as_signal, same_length

__all__ = ["OutputBacklashIdentification", "bound_output_backlash_system"]


@dataclass(frozen=True)
class OutputBacklashIdentification:
    """Result of :func:`bound_output_backlash_system`.

    Attributes
    ----------
    backlash
        D_γ, its polygons and orthotope (stage 1).
    inner_signal
        Bounds on x_t and the invertible-sample mask (stage 2); None if stage 1 found an empty set.
    linear
        Bounds on θ (stage 3); None if stage 1 found an empty set.
    noise_bound_rad
        Δη used for both experiments.
    method
        The linear-block method, ``"coupled"`` or ``"paper"``.
    """

    backlash: BacklashFeasibleSet
    inner_signal: InnerSignalBounds | None
    linear: LinearBlockBounds | None
    noise_bound_rad: float
    method: str = "coupled"

    KIND = "output_backlash"
    VERSION = 1

    def __eq__(self, other: object) -> bool:
        """Field by field, arrays element-wise (:func:`identify.result_format.results_equal`)."""
        from identify.result_format import results_equal

        return results_equal(self, other)

    def to_pandas(self) -> Any:
        """The parameter intervals as a ``pandas.DataFrame``: one row per parameter (``m_l c_l m_r c_r``, then
        ``a1..`` ``b..`` unless the set is empty), columns ``block`` (``backlash``/``linear``), ``parameter``,
        ``lower``, ``upper``, ``center``. Needs pandas (not a dependency)."""
        from identify.result_format import require_pandas

        pandas = require_pandas("OutputBacklashIdentification.to_pandas()")
        blocks = [("backlash", self.backlash.intervals())]
        if self.linear is not None and not self.linear.is_empty:
            blocks.append(("linear", self.linear.intervals))
        rows = [(block, name, interval.lower, interval.upper, interval.center)
                for block, intervals in blocks for name, interval in intervals.items()]
        return pandas.DataFrame(rows, columns=["block", "parameter", "lower", "upper", "center"])

    def to_dict(self) -> dict[str, Any]:
        """The ``rig identify output-backlash --json`` document: ``kind`` ``"output_backlash"``, ``version``
        1, the documented keys (``backlash`` and ``linear`` intervals, ``method``, ``invertible_samples``,
        ``samples``; for an empty set ``empty`` and ``explanation``), and the whole result for
        :meth:`from_dict`: ``noise_bound_rad``, ``backlash_set``, ``inner_signal``, ``linear_bounds``."""
        whole = {"noise_bound_rad": number(self.noise_bound_rad), "backlash_set": self.backlash.to_dict(),
                 "inner_signal": None if self.inner_signal is None else self.inner_signal.to_dict(),
                 "linear_bounds": None if self.linear is None else self.linear.to_dict()}
        if self.is_empty:
            return tagged(self.KIND, self.VERSION, {"empty": True, "explanation": self.explanation,
                                                    "method": self.method, **whole})
        assert self.inner_signal is not None
        return tagged(self.KIND, self.VERSION, {
            "backlash": {name: interval.to_dict() for name, interval in self.backlash_intervals.items()},
            "linear": {name: interval.to_dict() for name, interval in self.linear_intervals.items()},
            "method": self.method,
            "invertible_samples": self.inner_signal.num_invertible,
            "samples": int(self.inner_signal.lower_rad.size),
            **whole})

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> OutputBacklashIdentification:
        """Inverse of :meth:`to_dict` (the summary keys are recomputed from the whole result); a document of
        another kind or version is a ResultFormatError naming both."""
        check_kind(data, cls.KIND, (cls.VERSION,))
        with malformed(cls.KIND):
            inner, linear = data["inner_signal"], data["linear_bounds"]
            return cls(BacklashFeasibleSet.from_dict(data["backlash_set"]),
                       None if inner is None else InnerSignalBounds.from_dict(inner),
                       None if linear is None else LinearBlockBounds.from_dict(linear),
                       float(data["noise_bound_rad"]), str(data["method"]))

    @property
    def is_empty(self) -> bool:
        return self.backlash.is_empty or (self.linear is not None and self.linear.is_empty)

    @property
    def explanation(self) -> str | None:
        """Why the feasible set is empty (None if it is not)."""
        if self.backlash.explanation is not None:
            return "steady-state data: " + self.backlash.explanation.message
        if self.linear is not None and self.linear.explanation is not None:
            return "dynamic data: " + self.linear.explanation.message
        return None

    @property
    def backlash_intervals(self) -> dict[str, ParameterInterval]:
        """``m_l c_l m_r c_r`` -> interval (eqs. (18)-(20))."""
        return self.backlash.intervals()

    @property
    def linear_intervals(self) -> dict[str, ParameterInterval]:
        """``a1..a<na> b<nk>..b<nb>`` -> interval."""
        if self.linear is None or self.linear.is_empty:
            raise InvalidInputError(f"the feasible set is empty: {self.explanation}")
        return self.linear.intervals


def bound_output_backlash_system(steady_input_rad: ArrayLike, steady_output_rad: ArrayLike, input_rad: ArrayLike,
                                 output_rad: ArrayLike, noise_bound_rad: float, *, na: int, nk: int, nb: int,
                                 method: str = "coupled",
                                 filter_step_amplitude_rad: float | None = None,
                                 verify_inner: bool = True, window_samples: int = DEFAULT_WINDOW_SAMPLES,
                                 joint_samples: int = DEFAULT_JOINT_SAMPLES,
                                 partition_samples: int = DEFAULT_PARTITION_SAMPLES,
                                 moment_samples: int = DEFAULT_MOMENT_SAMPLES,
                                 map_windows: MapFunction | None = None,
                                 progress: Progress | None = None,
                                 eliminate_inner_signal: bool = True) -> OutputBacklashIdentification:
    """Bound the parameters of a linear system with output backlash (Cerone et al. 2009, Sections 3-5).

    Parameters
    ----------
    steady_input_rad, steady_output_rad
        The 2M steady-state points (ū_s, ȳ_s) of the filtered staircase experiment, both half-waves mixed.
    input_rad, output_rad
        u_t and y_t of the dynamic (PRBS) experiment. NaN in ``output_rad`` marks a sample not measured (a
        LOST sample): the equations of eq. (7) that need its inner signal are left out (see
        :func:`identify.linear_block_bounds.bound_linear_block`); the others still bound every parameter.
    noise_bound_rad
        Δη > 0 (eq. (5)), the same for both experiments (for an n-bit encoder, 2π/2^n).
    na, nk, nb
        Orders of A(q^-1) = 1 + a_1 q^-1 + ... + a_na q^-na and B(q^-1) = b_nk q^-nk + ... + b_nb q^-nb.
    method
        ``"coupled"`` (default, tightest) or ``"paper"`` (Cerone 1993 errors-in-variables bounds).
    filter_step_amplitude_rad
        r̄_F of the filter-pole search if known (α terms of eqs. (14)-(15)).
    verify_inner
        Coupled method: also compute verified inner values (see :func:`identify.linear_block_bounds.bound_linear_block`).
    window_samples, joint_samples, partition_samples, moment_samples, map_windows, progress, eliminate_inner_signal
        Coupled method: the windowing of long records, the length up to which the box of a is partitioned
        (the final tightening of short records), the length up to which the moment (SDP) cuts follow (0: off),
        a ``map`` that may run the windows in other processes
        (``executor.map``), a ``progress(stage, done, total)`` callback and whether a record of few gaps is
        bounded by the trajectory relaxation instead of windows; see
        :func:`identify.linear_block_bounds.bound_linear_block`.

    Examples
    --------
    >>> import numpy as np
    >>> from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
    >>> from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
    >>> plant = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))
    >>> staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    >>> steady = staircase_steady_state_indices(50, 100)
    >>> u = prbs_sequence(100, 1.0, rng=1)
    >>> result = bound_output_backlash_system(staircase[steady], plant.simulate(staircase)[steady], u,
    ...                                       plant.simulate(u), 1e-5, na=2, nk=1, nb=2)
    >>> [round(result.linear_intervals[name].center, 3) for name in ("a1", "a2", "b1", "b2")]
    [0.5, 0.7, 1.4, 0.8]
    """
    LinearModelOrders(na, nk, nb)  # validate the structure before any work
    if method not in LINEAR_BOUND_METHODS:
        raise InvalidInputError(f"method: expected one of {', '.join(LINEAR_BOUND_METHODS)}, got {method!r}")
    noise = float(noise_bound_rad)
    if not (noise > 0.0 and noise < float("inf")):
        raise InvalidInputError(f"noise_bound_rad: expected a finite number > 0, got {noise_bound_rad!r}")
    u = as_signal("input_rad", input_rad, min_samples=2)
    y = as_signal("output_rad", output_rad, min_samples=2, missing_allowed=True)
    same_length(input_rad=u, output_rad=y)
    backlash = bound_backlash_parameters(steady_input_rad, steady_output_rad, noise,
                                         filter_step_amplitude_rad=filter_step_amplitude_rad)
    if backlash.is_empty:
        return OutputBacklashIdentification(backlash, None, None, noise, method)
    inner = bound_inner_signal(y, noise, backlash)
    shared = shared_backlash_constraints(y, noise, backlash, inner) if method == "coupled" else None
    linear = bound_linear_block(u, inner.lower_rad, inner.upper_rad, na=na, nk=nk, nb=nb, method=method,
                                shared_backlash=shared, verify_inner=verify_inner, window_samples=window_samples,
                                joint_samples=joint_samples, partition_samples=partition_samples,
                                moment_samples=moment_samples, map_windows=map_windows, progress=progress,
                                eliminate_inner_signal=eliminate_inner_signal)
    return OutputBacklashIdentification(backlash, inner, linear, noise, method)
