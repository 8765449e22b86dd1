"""Guaranteed bounds on the linear block A(q^-1) x_t = B(q^-1) u_t from bounded inner-signal data
(Section 5 of Cerone et al. 2009).

The inner signal is known only within bounds, x_t = x_t^c + δx_t with |δx_t| <= Δx_t (eqs. (28)-(30)),
and the parameters θ = [a_1..a_na, b_nk..b_nb] satisfy, for t = n..N-1 with n = max(na, nb),

    x_t^c + δx_t + Σ_i a_i (x_{t-i}^c + δx_{t-i}) = Σ_j b_j u_{t-j},        Σ_j b_j = 1 + Σ_i a_i  (eq. (8)).

Two bounding methods, both returning guaranteed outer bounds:

``"paper"`` (Cerone 1993, as the paper applies it): every equation's errors are taken on their own,
|x_t^c + Σ a_i x_{t-i}^c - Σ b_j u_{t-j}| <= Δx_t + Σ |a_i| Δx_{t-i}; in each orthant of (a_1..a_na) the
absolute values are linear, so the set is a polytope and every bound is an LP (2p LPs per orthant).

``"coupled"`` (not in the paper): the same δx_s enters up to na+1 equations, so the exact feasible set is
the projection of {(θ, δx) : all equations hold with shared δx}. The bilinear terms a_i δx_s are replaced by
variables with McCormick envelopes over the current box of a_i and |δx_s| <= Δx_s, which is a convex outer
relaxation; its LP bounds tighten the box of a_i, which tightens the envelopes, and this is iterated. The
paper method's box is the starting box, so the coupled bounds are never wider. With ``shared_backlash``
the inverted samples are moreover tied to one backlash in D_γ (:class:`SharedBacklashConstraints`), rather
than each taking its own worst case over D_γ as in eqs. (24)-(27). For every bound, the a-part
of the extreme LP solution is then fixed and the (now exactly linear) problem in b and δx is solved again:
that gives a point of the exact feasible set, so ``inner_lower``/``inner_upper`` show how close the outer
bounds are to the exact ones (if that a admits no exact solution, a is moved towards the box centre in
steps 0.95, 0.8, 0.5, 0 and bisection; then a few sequential-LP steps move along the exact set's boundary,
each new a counting only once the exact problem at it is solved: :func:`_inner_values`).

For records longer than two windows (400 samples) the work goes window by window, so that it grows about
linearly with the record (:func:`_coupled_bounds`). The feasible set of any subset of the
equations contains the full one, so every window's bounds are valid. The box of a is first tightened on the
first 200 samples (McCormick); the box of a is then narrow, and the later LPs use a smaller relaxation that is
tight for a narrow box (:func:`_interval_lp`: a_i δx_s = a_i^c δx_s + e, |e| <= r_i Δx_s, without product
columns or envelope rows). Every 200-sample window (consecutive ones share 20 samples) is bounded, the boxes
are intersected and fed back into every window's relaxation until they stop shrinking; the windows are
independent tasks for ``map_windows`` (a process pool's or a Dask client's ``executor.map``). The final rounds
solve the relaxation jointly over all samples when there are at most ``joint_samples`` (3000): the all-data
relaxation, from a box inside the one it started from before, and never wider. Longer records are solved
jointly in overlapping parts of ``joint_samples`` samples, one round each, whose boxes are intersected and fed
back for further passes over the parts (a fixed point like the windows'): about linear in N, but
wider than one relaxation over everything would be (bounded-error information is spread over the record).
After the first pass, a pass over the windows or parts solves, per task, only the bounds still moving that the
task may still decide (:class:`_TaskBounds`); the paper method's orthant LPs of such records are solved by row
generation (:func:`_row_generated_bounds`), so that the windows start within about a second.
Within one LP, the bounds of the parameters are solved on one HiGHS model whose objective changes, each
solve starting from the previous optimal basis.

Records up to ``partition_samples`` (1000) get a final tightening by spatial branch and bound on the box of
a (:func:`_partitioned_bounds`): the box is cut into cells, each bounded by its own interval relaxation, and
the hull of the cells is the bound; the cells that decide a bound are halved again. One relaxation over the
whole box left up to half of the reported width to the relaxation at 8 bits; the cells bring the
outer bounds to within about 5-10 % of the verified inner values.

Records up to ``moment_samples`` (0 by default: off) get a last tightening by the first-order moment (SDP)
relaxation of the bilinear terms (:func:`_moment_bounds`, :mod:`identify.moment_relaxation`, with cvxpy): the
duals of its PSD constraints become cuts of the lifted McCormick LP, whose bound HiGHS certifies as every other
LP's. On the paper's example it narrows the bounds by under 1 % at about twice the cost (BENCHMARKS.md).

A window or part whose worker process dies (a segfault inside the solver, the out-of-memory killer; a process
pool's ``BrokenProcessPool``, Dask's ``KilledWorker``) is not a traceback either: the bounds are those of the
windows and parts that finished (:class:`_GuardedMap`), with a note.

A bounding LP that HiGHS cannot solve under any recovery setting (warm start dropped, dual simplex with and
without presolve and without scaling, interior point) keeps that bound at its previous valid value, and
``LinearBlockBounds.notes`` says which parameter and why.

Guarantees against solver tolerances: every LP bound is replaced by the Neumaier-Shcherbina bound computed
from the solver's dual values and the finite variable boxes (a valid bound for any dual vector), and an
orthant is discarded only if a phase-1 LP proves it infeasible the same way. The a-priori box of a_i is
|a_i| <= C(na, i), which holds for every asymptotically stable A (assumption (i) of Section 2): the coefficients
of Π_k (1 - p_k q^-1) with |p_k| < 1 are bounded by the binomial ones.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import BrokenExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linprog

from identify.feasible_parameter_set import ParameterInterval
from identify.result_format import check_kind, malformed, number, tagged

if TYPE_CHECKING:
    from identify.linear_block_response import MagnitudeEnvelope
from identify.validation import InvalidInputError, as_signal, same_length

__all__ = ["DEFAULT_JOINT_SAMPLES", "DEFAULT_MOMENT_SAMPLES", "DEFAULT_PARTITION_SAMPLES", "DEFAULT_WINDOW_SAMPLES", "LINEAR_BOUND_METHODS", "EmptyLinearSetExplanation", "LinearBlockBounds", "LinearModelOrders", "MapFunction",
           "Progress", "SharedBacklashConstraints", "bound_linear_block"]

LINEAR_BOUND_METHODS = ("paper", "coupled")

_LOG = logging.getLogger(__name__)

_DEFAULT_SETTINGS = {"solver": "simplex", "simplex_strategy": 1, "presolve": "on", "run_crossover": "on",
                     "simplex_scale_strategy": 2}
"""Dual simplex with HiGHS's own pricing for every model's first solve. Devex pricing
(``simplex_dual_edge_weight_strategy`` 1) made one 3000-sample part's 8 LPs 3-28 % faster, but with it a worker
segfaulted inside HiGHS 1.16 (a stack overflow: the ``HEkkDualRHS::chooseNormal`` recursion of the dual simplex)
on N = 100 000, 8 bits, run 0, which this setting had solved: not used."""
_RECOVERY_SETTINGS = (
    {"solver": "simplex", "simplex_strategy": 1, "presolve": "on"},
    {"solver": "simplex", "simplex_strategy": 1, "presolve": "off"},
    # the chained equations of long records have rows of very different size; unscaled dual simplex solved
    # the bounding LP of benchmark record [2009, 10000, 12, 1] that every scaled setting stopped on with
    # "Solve error"
    {"solver": "simplex", "simplex_strategy": 1, "presolve": "on", "simplex_scale_strategy": 0},
    {"solver": "ipm", "run_crossover": "off", "presolve": "on"},
    {"solver": "ipm", "run_crossover": "off", "presolve": "off"},
)
_RECOVERY_NAMES = "warm start dropped, dual simplex with and without presolve and without scaling, interior point"
_TIME_LIMIT_S = 20.0
"""HiGHS time limit per attempt on one LP (plus 0.2 ms per row); a time-out counts as a failed attempt."""
_B_BOX = 1e6
"""A-priori box |b_j| <= 1e6; a bound that reaches it is reported as unbounded (infinite)."""


@dataclass(frozen=True)
class LinearModelOrders:
    """A(q^-1) = 1 + a_1 q^-1 + ... + a_na q^-na, B(q^-1) = b_nk q^-nk + ... + b_nb q^-nb."""

    na: int
    nk: int
    nb: int

    def __post_init__(self) -> None:
        for name in ("na", "nk", "nb"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise InvalidInputError(f"{name}: expected an integer >= 0, got {value!r}")
        if self.nb < self.nk:
            raise InvalidInputError(f"nb: expected nb >= nk (B has b_nk..b_nb), got nk={self.nk}, nb={self.nb}")

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """``a1..a<na>``, ``b<nk>..b<nb>`` (the order of θ)."""
        return tuple(f"a{i}" for i in range(1, self.na + 1)) + tuple(f"b{j}" for j in range(self.nk, self.nb + 1))

    @property
    def num_parameters(self) -> int:
        return self.na + self.nb - self.nk + 1

    @property
    def first_equation(self) -> int:
        """n = max(na, nb): the first t whose regressors are all measured."""
        return max(self.na, self.nb)


@dataclass(frozen=True)
class SharedBacklashConstraints:
    """The backlash parameters shared by every inverted sample, for the coupled method.

    For an inverted sample, x_t = ρ_r (y_t - η_t) + c_r (output rose) or x_t = ρ_l (y_t - η_t) - c_l (output
    fell), with ρ = 1/m the same for all samples; with ζ_t = ρ η_t, |ζ_t| <= ρ^max Δη, this is linear in
    (ρ_l, c_l, ρ_r, c_r, ζ_t), and D_γ is a polygon in (ρ, c) too
    (:meth:`identify.feasible_parameter_set.BacklashSidePolygon.inverse_slope_rows`). Built by
    :func:`identify.inner_signal_bounds.shared_backlash_constraints`.

    Attributes
    ----------
    sample_indices
        The inverted samples t.
    rising
        True where the output rose (right line), False where it fell (left line).
    output_rad
        y_t at those samples.
    zeta_bound_rad
        ρ^max Δη per sample.
    rows, rhs
        rows @ [ρ_l, c_l, ρ_r, c_r] <= rhs: both polygons.
    lower, upper
        Box of [ρ_l, c_l, ρ_r, c_r] (from the polygons' vertices).
    """

    sample_indices: NDArray[np.int64]
    rising: NDArray[np.bool_]
    output_rad: NDArray[np.float64]
    zeta_bound_rad: NDArray[np.float64]
    rows: NDArray[np.float64]
    rhs: NDArray[np.float64]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]


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


# ----------------------------------------------------------------------------------------------------------
# certified LP bounds
# ----------------------------------------------------------------------------------------------------------


@dataclass
class _LP:
    """min c^T z subject to A_ub z <= b_ub, A_eq z = b_eq, range_lower <= A_range z <= range_upper,
    lower <= z <= upper (all bounds finite).

    A two-sided row |r^T z - c| <= s is one ranged row, not two inequalities: HiGHS keeps it as one row with a
    boxed slack, which halved the rows of the interval relaxation and cut its simplex time about four-fold."""

    A_ub: sp.csr_matrix
    b_ub: NDArray[np.float64]
    A_eq: sp.csr_matrix
    b_eq: NDArray[np.float64]
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]
    A_range: sp.csr_matrix | None = None
    range_lower: NDArray[np.float64] | None = None
    range_upper: NDArray[np.float64] | None = None

    def ranged(self) -> tuple[sp.csr_matrix, NDArray[np.float64], NDArray[np.float64]]:
        """The ranged rows (an empty block when there are none)."""
        if self.A_range is None or self.range_lower is None or self.range_upper is None:
            return sp.csr_matrix((0, self.lower.size)), np.zeros(0), np.zeros(0)
        return self.A_range, self.range_lower, self.range_upper

    def rows(self) -> tuple[sp.csr_matrix, NDArray[np.float64], NDArray[np.float64]]:
        """All rows as row_lower <= A z <= row_upper: the inequalities, the ranged rows, the equalities."""
        A_range, range_lower, range_upper = self.ranged()
        return (sp.vstack([self.A_ub, A_range, self.A_eq]).tocsr(),
                np.concatenate([np.full(self.b_ub.size, -np.inf), range_lower, self.b_eq]),
                np.concatenate([self.b_ub, range_upper, self.b_eq]))


class _SolverFailure(RuntimeError):
    """HiGHS stopped on an LP without an optimum or a proof of infeasibility, after every recovery setting."""

    def __init__(self, status: str) -> None:
        super().__init__(f"HiGHS failed on a bounding LP: {status} (tried: {_RECOVERY_NAMES})")
        self.status = status


class _Counter:
    def __init__(self) -> None:
        self.solves = 0
        self.max_gap = 0.0
        # (parameter index, "lower"/"upper", HiGHS status, stage) of every bound kept at its previous value
        self.fallbacks: list[tuple[int, str, str, str]] = []
        self.stage = "paper method"
        # (stage, reason) of every stage whose worker processes were lost (:class:`_GuardedMap`)
        self.lost_stages: list[tuple[str, str]] = []

    def merge(self, other: "_Counter") -> None:
        """Add the counts of work done elsewhere (a window solved in another process)."""
        self.solves += other.solves
        self.max_gap = max(self.max_gap, other.max_gap)
        self.fallbacks.extend(other.fallbacks)


_UNPRESOLVED = {"presolve": "off", "simplex_dual_edge_weight_strategy": 2}
"""First-solve settings of a part whose presolved first solve failed in an earlier pass (:class:`_PartStart`):
dual simplex without presolve, with dual steepest-edge pricing that does not switch to Devex. At N = 100 000,
8 bits, run 0 of the benchmark, 28 % of the parts' presolved first solves ended in "excessive primal values"
after postsolve, mostly the same parts pass after pass; on them this setting needed no recovery, and on the part
whose presolved first solve crashed HiGHS 1.16 (the ``chooseNormal`` recursion) it solved in about a second where
presolve off with HiGHS's own pricing (steepest edge switching to Devex) failed and its recovery crashed. Not the
default: at 12 bits it is about 40 % slower on the parts than the presolved solve, which fails there on 3 % of
them (measured on the parts of that record at 8 and 12 bits)."""


_FROM_BASIS = {"presolve": "off"}
"""Settings of a first solve that goes on from a given basis (:class:`_PartStart`)."""


@dataclass
class _PartStart:
    """What a part's solves in one pass hand on to the same part's solves in the next (:func:`_coupled_bounds`):
    the part's LP keeps its rows and columns from pass to pass (only the envelopes of the narrower box change),
    so its last optimal basis (HiGHS basis status codes of the columns and rows) is a start for the next
    pass's first solve; a part whose presolved first solve failed hands on no basis (a start from it crashed
    HiGHS, :meth:`_Solver.minimize`), only that failure, which will likely recur (:data:`_UNPRESOLVED`). A start
    only chooses where the simplex begins: the bounds are certified as always."""

    col_status: NDArray[np.int8] | None = None
    row_status: NDArray[np.int8] | None = None
    presolve_failed: bool = False


class _Solver:
    """One HiGHS model of an :class:`_LP`, re-solved for many objectives from the previous basis."""

    def __init__(self, lp: _LP, settings: Mapping[str, Any] | None = None,
                 first_solve: Mapping[str, Any] | None = None, start: _PartStart | None = None) -> None:
        """``settings``: HiGHS options for every solve (no switch to the primal simplex warm start after the
        first); ``first_solve``: options of the model's first solve (and of a solve after a recovery), on top of
        :data:`_DEFAULT_SETTINGS`; ``start``: the basis and experience of the same part's model in the previous
        pass (ignored with ``settings``)."""
        # highspy.Highs() prints a banner (it would break ``--json`` output): the adapter gives a quiet instance.
        from identify.highs_solver import (HighsBasis, HighsBasisStatus, HighsLp, HighsModelStatus, MatrixFormat,
                                           quiet_highs)

        self.lp = lp
        self.A, self.row_lower, self.row_upper = lp.rows()
        A = self.A.tocsc()
        model = HighsLp()
        model.num_col_ = int(A.shape[1])
        model.num_row_ = int(A.shape[0])
        model.col_cost_ = np.zeros(A.shape[1])
        model.col_lower_ = lp.lower
        model.col_upper_ = lp.upper
        model.row_lower_ = self.row_lower
        model.row_upper_ = self.row_upper
        model.a_matrix_.format_ = MatrixFormat.kColwise
        model.a_matrix_.start_ = A.indptr.astype(np.int32)
        model.a_matrix_.index_ = A.indices.astype(np.int32)
        model.a_matrix_.value_ = A.data.astype(float)
        self.highs = quiet_highs()
        self.fixed_settings = dict(settings or {})
        self.presolve_failed = start is not None and start.presolve_failed
        start = None if self.fixed_settings else start
        unpresolved = _UNPRESOLVED if self.presolve_failed else {}
        self.base_settings = {**_DEFAULT_SETTINGS, **(first_solve or {}), **unpresolved, **self.fixed_settings}
        self._set(self.base_settings)
        # A bounded time per attempt: a warm start that stalls on a long record's LP (one part of a
        # 100 000-sample record kept a worker busy for over 15 minutes) goes on to the recovery settings and,
        # at worst, to the fallback bound, instead of holding up the whole record.
        # HiGHS counts its time limit over all runs of one model, so each run sets it from the time used so far.
        self.time_limit_s = _TIME_LIMIT_S + 2e-4 * float(A.shape[0])
        self.highs.passModel(model)
        if (start is not None and start.col_status is not None and start.row_status is not None
                and start.col_status.size == model.num_col_ and start.row_status.size == model.num_row_):
            basis = HighsBasis()
            basis.col_status = [HighsBasisStatus(int(code)) for code in start.col_status]
            basis.row_status = [HighsBasisStatus(int(code)) for code in start.row_status]
            basis.valid = True
            self.highs.setBasis(basis)
            self._set(_FROM_BASIS)
        self.from_basis = self.highs.getBasis().valid

        self._status = HighsModelStatus
        self.columns = np.arange(A.shape[1], dtype=np.int32)
        self.warm = False
        self.solved = False

    def handoff(self) -> _PartStart:
        """This model's last basis (none if it has no valid one, e.g. after the interior-point method without
        crossover) and whether a presolved first solve failed on it, for the same part's next pass."""
        basis = self.highs.getBasis()
        if not (self.solved and basis.valid) or self.presolve_failed:
            return _PartStart(presolve_failed=self.presolve_failed)
        return _PartStart(np.array([int(code) for code in basis.col_status], dtype=np.int8),
                          np.array([int(code) for code in basis.row_status], dtype=np.int8), self.presolve_failed)

    def _set(self, settings: Mapping[str, Any]) -> None:
        for option, value in settings.items():
            self.highs.setOptionValue(option, value)

    def _run(self) -> None:
        self.highs.setOptionValue("time_limit", self.highs.getRunTime() + self.time_limit_s)
        self.highs.run()

    def minimize(self, cost: NDArray[np.float64], counter: _Counter) -> tuple[float, NDArray[np.float64] | None]:
        """Certified lower bound of min cost^T z (Neumaier-Shcherbina: valid for any dual vector, given the
        finite column boxes) and the solver's minimiser; (inf, None) if the solver reports infeasibility.

        Each solve starts from this model's previous optimal basis; the first from the basis of the same part's
        model in the previous pass, if :class:`_PartStart` hands one on. Not from a part whose presolved solve
        failed: at N = 100 000, 8 bits, such a re-started solve of a joint part sent HiGHS 1.16 into an
        unbounded recursion (``HEkkDualRHS::chooseNormal``, a segfault by stack overflow), with HiGHS's own
        pricing and with dual steepest edge alike; the same part solves in about a second from scratch without
        presolve (:data:`_UNPRESOLVED`)."""
        counter.solves += 1
        highs = self.highs
        highs.changeColsCost(self.columns.size, self.columns, np.asarray(cost, dtype=float))
        self._run()
        status = highs.getModelStatus()
        if status not in (self._status.kOptimal, self._status.kInfeasible):
            if not (self.solved or self.from_basis) and self.base_settings["presolve"] == "on":
                self.presolve_failed = True
            # Recover from a stalled warm start or a numerically poor basis (the chained equations can make
            # a basis very ill-conditioned): solve again from scratch, by dual simplex with and without
            # presolve, then by the interior-point method without crossover (its duals are all the
            # certificate needs). HiGHS is deterministic: settings that failed from scratch (the model's
            # first solve has no basis to drop) are not tried again.
            tried = [] if (self.solved or self.from_basis) else [self.base_settings]
            for recovery in _RECOVERY_SETTINGS:
                settings = {**self.base_settings, **recovery}
                if settings in tried:
                    continue
                tried.append(settings)
                highs.clearSolver()
                self._set(settings)
                self._run()
                status = highs.getModelStatus()
                if status in (self._status.kOptimal, self._status.kInfeasible):
                    break
            self._set(self.base_settings)
            self.warm = False
        self.solved = True
        if status == self._status.kOptimal and not self.warm and not self.fixed_settings:
            # The optimal basis stays primal feasible when only the objective changes, so primal simplex
            # without presolve continues from it for the next objectives.
            highs.setOptionValue("simplex_strategy", 4)
            highs.setOptionValue("presolve", "off")
            self.warm = True
        if status == self._status.kInfeasible:
            return math.inf, None
        if status != self._status.kOptimal:
            raise _SolverFailure(highs.modelStatusToString(status))
        solution = highs.getSolution()
        x = np.asarray(solution.col_value, dtype=float)
        y = np.asarray(solution.row_dual, dtype=float)
        # keep only dual signs that the finite row bounds support
        y = np.where((y > 0.0) & ~np.isfinite(self.row_lower), 0.0, y)
        y = np.where((y < 0.0) & ~np.isfinite(self.row_upper), 0.0, y)
        row_term = np.where(y > 0.0, y * np.where(np.isfinite(self.row_lower), self.row_lower, 0.0),
                            y * np.where(np.isfinite(self.row_upper), self.row_upper, 0.0))
        reduced = cost - self.A.T @ y
        box_term = np.minimum(reduced * self.lp.lower, reduced * self.lp.upper)
        bound = float(row_term.sum() + box_term.sum())
        bound -= 1e-13 * (float(np.abs(row_term).sum() + np.abs(box_term).sum()) + 1.0)  # rounding of the sums
        objective = float(cost @ x)
        bound = min(bound, objective)
        counter.max_gap = max(counter.max_gap, objective - bound)
        return bound, x


def _certified_minimum(lp: _LP, cost: NDArray[np.float64], counter: _Counter) -> tuple[float, NDArray[np.float64] | None]:
    return _Solver(lp).minimize(cost, counter)


def _proven_infeasible(lp: _LP, counter: _Counter) -> bool:
    """Phase 1: min τ >= 0 with every row relaxed by τ (equalities to |row| <= τ); infeasible iff the
    certified lower bound on τ is > 0."""
    A_range, range_lower, range_upper = lp.ranged()
    A_all = sp.vstack([lp.A_ub, A_range, -A_range, lp.A_eq, -lp.A_eq]).tocsr()
    b_all = np.concatenate([lp.b_ub, range_upper, -range_lower, lp.b_eq, -lp.b_eq])
    relaxed = _LP(sp.hstack([A_all, -sp.csr_matrix(np.ones((A_all.shape[0], 1)))]).tocsr(), b_all,
                  sp.csr_matrix((0, lp.lower.size + 1)), np.zeros(0),
                  np.append(lp.lower, 0.0), np.append(lp.upper, 1e6))
    cost = np.zeros(lp.lower.size + 1)
    cost[-1] = 1.0
    reported_gap = counter.max_gap
    try:
        bound, _ = _certified_minimum(relaxed, cost, counter)
    except _SolverFailure:
        return False  # not proven: the caller keeps the set (a valid, looser answer)
    finally:
        # max_certificate_gap describes the reported bounds; a loose phase-1 certificate only makes the proof
        # fail (the cell or orthant is then kept), it loosens no bound
        counter.max_gap = reported_gap
    return bound > 0.0


# ----------------------------------------------------------------------------------------------------------
# problem data
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Data:
    orders: LinearModelOrders
    u: NDArray[np.float64]
    xc: NDArray[np.float64]
    dx: NDArray[np.float64]
    times: NDArray[np.int64]  # equation times t = n..N-1
    regressors: NDArray[np.float64]  # psi_t: x_t^c = psi_t theta - (delta terms)
    shared: SharedBacklashConstraints | None = None

    @property
    def a_box(self) -> NDArray[np.float64]:
        return np.array([math.comb(self.orders.na, i) for i in range(1, self.orders.na + 1)], dtype=float)


def _prepare(input_rad: ArrayLike, inner_lower_rad: ArrayLike, inner_upper_rad: ArrayLike,
             orders: LinearModelOrders, shared: SharedBacklashConstraints | None = None) -> _Data:
    u = as_signal("input_rad", input_rad)
    lower = as_signal("inner_lower_rad", inner_lower_rad, missing_allowed=True)
    upper = as_signal("inner_upper_rad", inner_upper_rad, missing_allowed=True)
    same_length(input_rad=u, inner_lower_rad=lower, inner_upper_rad=upper)
    bad = np.flatnonzero(lower > upper)
    if bad.size:
        raise InvalidInputError(f"inner_lower_rad: sample {bad[0]} is above inner_upper_rad ({lower[bad[0]]} > {upper[bad[0]]})")
    n = orders.first_equation
    p = orders.num_parameters
    if u.size <= n:
        raise InvalidInputError(f"input_rad: na={orders.na}, nk={orders.nk}, nb={orders.nb} need {n} past samples "
                                f"before the first equation, but the record has {u.size} samples; the orders are "
                                f"too high for the data (at least {n + 2 * p} samples are needed): use lower orders "
                                "or a longer record")
    known = np.isfinite(lower) & np.isfinite(upper)
    times = np.arange(n, u.size)
    complete = np.all([known[times - i] for i in range(orders.na + 1)], axis=0)
    times = times[complete]
    missing = int(np.count_nonzero(~known))
    if times.size < 2 * p:
        left = (f"; {missing} samples without an inner-signal bound (output not measured) set aside "
                f"{u.size - n - times.size} of the {u.size - n} equations" if missing else "")
        raise InvalidInputError(f"input_rad: {u.size} samples give {times.size} equations for the {p} parameters of "
                                f"na={orders.na}, nk={orders.nk}, nb={orders.nb}{left}; the orders are too high for "
                                f"the data (at least {2 * p} equations are needed): use lower orders or a longer "
                                "record" + (" with fewer lost samples" if missing else ""))
    if np.ptp(u) == 0.0:
        raise InvalidInputError(f"input_rad: the input is constant ({u[0]:g} rad in all {u.size} samples), so it "
                                "excites nothing and the linear block cannot be bounded; use a persistently exciting "
                                "dynamic experiment such as the PRBS (configs/experiments/prbs.toml)")
    # a sample without bounds is in no equation; 0 +- 0 keeps its (unused) variable finite
    xc, dx = np.where(known, 0.5 * (lower + upper), 0.0), np.where(known, 0.5 * (upper - lower), 0.0)
    columns = [-xc[times - i] for i in range(1, orders.na + 1)] + [u[times - j] for j in range(orders.nk, orders.nb + 1)]
    if shared is not None:
        if not isinstance(shared, SharedBacklashConstraints):
            raise InvalidInputError(f"shared_backlash: expected SharedBacklashConstraints, got {type(shared).__name__}")
        if shared.sample_indices.size and (shared.sample_indices.min() < 0 or shared.sample_indices.max() >= u.size):
            raise InvalidInputError(f"shared_backlash: sample indices outside 0..{u.size - 1}")
    return _Data(orders, u, xc, dx, times, np.column_stack(columns), shared)


def _gain_row(orders: LinearModelOrders, width: int) -> tuple[sp.csr_matrix, NDArray[np.float64]]:
    """Σ b_j - Σ a_i = 1 (eq. (8)) as one equality row over the first p variables."""
    row = np.zeros(width)
    row[: orders.na] = -1.0
    row[orders.na: orders.num_parameters] = 1.0
    return sp.csr_matrix(row), np.array([1.0])


# ----------------------------------------------------------------------------------------------------------
# the paper's method: errors in variables per equation, one polytope per orthant of a
# ----------------------------------------------------------------------------------------------------------


def _orthant_lp(data: _Data, signs: tuple[int, ...]) -> _LP:
    orders = data.orders
    na, p = orders.na, orders.num_parameters
    psi = data.regressors
    # d_t theta = Σ_i s_i a_i Δx_{t-i} = Σ |a_i| Δx_{t-i} in this orthant
    d = np.zeros_like(psi)
    for i in range(1, na + 1):
        d[:, i - 1] = signs[i - 1] * data.dx[data.times - i]
    x_t, dx_t = data.xc[data.times], data.dx[data.times]
    # |x_t - psi theta| <= dx_t + d theta  <=>  psi theta - d theta <= x_t + dx_t ; -psi theta - d theta <= -x_t + dx_t
    A_ub = np.vstack([psi - d, -psi - d])
    b_ub = np.concatenate([x_t + dx_t, -x_t + dx_t])
    A_eq, b_eq = _gain_row(orders, p)
    lower = np.full(p, -_B_BOX)
    upper = np.full(p, _B_BOX)
    box = data.a_box
    for i in range(na):
        lower[i], upper[i] = (0.0, box[i]) if signs[i] > 0 else (-box[i], 0.0)
    return _LP(sp.csr_matrix(A_ub), b_ub, A_eq, b_eq, lower, upper)


def _bounds_over(lp: _LP, p: int, counter: _Counter, wanted: NDArray[np.bool_] | None = None, retry: bool = False,
                 start: _PartStart | None = None
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.float64] | None]]:
    """Certified min and max of each of the first p variables, with the minimisers/maximisers
    (``points[2k]`` minimises and ``points[2k + 1]`` maximises variable k), on one HiGHS model whose
    objective changes (each solve continues from the previous optimal basis).

    ``wanted`` (2p booleans in the order of ``points``; all by default) names the bounds to solve: the others
    are the LP's own column bounds (the caller's box, valid for every point of the set) with point None, so a
    caller that needs only the bounds still moving saves their LPs (:func:`_coupled_bounds`). ``retry``: every
    solve by :data:`RETRY_SETTINGS` (a task solved again after a crash, :class:`_GuardedMap`). ``start`` (in and
    out): the model starts from it (:class:`_PartStart`) and it is overwritten with the model's hand-off.

    A bound whose LP HiGHS cannot solve (after the recovery settings of :meth:`_Solver.minimize`) is the
    LP's own column bound for that variable, which holds for every point of the set (the caller's current
    box); it is recorded in ``counter.fallbacks`` and its point is None."""
    solver = _Solver(lp, settings=RETRY_SETTINGS if retry else None, start=start)
    try:
        return _solved_bounds(solver, lp, p, counter, wanted)
    finally:
        if start is not None:
            handoff = solver.handoff()
            start.col_status, start.row_status, start.presolve_failed = (handoff.col_status, handoff.row_status,
                                                                         handoff.presolve_failed)


def _solved_bounds(solver: _Solver, lp: _LP, p: int, counter: _Counter, wanted: NDArray[np.bool_] | None
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.float64] | None]]:
    """The solves of :func:`_bounds_over` on its model."""
    lows, highs = lp.lower[:p].copy(), lp.upper[:p].copy()
    points: list[NDArray[np.float64] | None] = [None] * (2 * p)
    for index in range(2 * p):
        if wanted is not None and not wanted[index]:
            continue
        k, side = divmod(index, 2)
        cost = np.zeros(lp.lower.size)
        cost[k] = -1.0 if side else 1.0
        try:
            value, x = solver.minimize(cost, counter)
        except _SolverFailure as failure:
            counter.fallbacks.append((k, "upper" if side else "lower", failure.status, counter.stage))
            solver.warm = False
            continue
        if x is None:  # infeasible: no other objective can do better
            return np.full(p, math.inf), np.full(p, -math.inf), []
        if side:
            highs[k] = -value
        else:
            lows[k] = value
        points[index] = x
    return lows, highs, points


_PAPER_ROWS = 20000
"""Inequality rows of an orthant's LP solved whole; longer records bound it on a subset of the rows that grows by
the rows its solutions violate (:func:`_row_generated_bounds`)."""
_PAPER_ROWS_ADDED = 200
"""Most violated rows added per objective and turn of the row generation."""
_PAPER_TURNS = 30
"""Turns of the row generation at most (the bounds after any turn are valid, only possibly looser)."""


def _row_generated_bounds(lp: _LP, p: int, counter: _Counter
                          ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.float64] | None], _LP]:
    """:func:`_bounds_over` of an LP with many more inequality rows than variables (the paper method's orthant
    LPs: two rows per equation, p columns), solved on a subset of its rows (row generation, the dual of
    column generation): every ``stride``-th row first, then, turn by turn, the rows most violated by the
    subset's minimisers, until they violate none (beyond 1e-9 of the row's scale) or ``_PAPER_TURNS``.

    Fewer rows give a relaxation, so the certified bound of the subset LP is a valid bound of the whole one
    at every turn; once the minimisers violate no row they are optimal for the whole LP too. Returns the
    bounds, points and the subset LP (whose phase 1 then decides emptiness: infeasible rows are infeasible in
    any superset)."""
    rows = lp.A_ub.shape[0]
    if rows <= _PAPER_ROWS:
        low, high, points = _bounds_over(lp, p, counter)
        return low, high, points, lp
    chosen = np.zeros(rows, dtype=bool)
    chosen[:: -(-rows // _PAPER_ROWS)] = True
    scale = 1e-9 * (1.0 + np.abs(lp.b_ub))
    for _ in range(_PAPER_TURNS):
        subset = _LP(lp.A_ub[chosen], lp.b_ub[chosen], lp.A_eq, lp.b_eq, lp.lower, lp.upper)
        low, high, points = _bounds_over(subset, p, counter)
        if not np.all(np.isfinite(low)):
            return low, high, points, subset
        added = np.zeros(rows, dtype=bool)
        for x in points:
            if x is None:
                continue
            violation = np.where(chosen, 0.0, lp.A_ub @ x - lp.b_ub - scale)
            worst = np.argsort(violation)[-_PAPER_ROWS_ADDED:]
            added[worst[violation[worst] > 0.0]] = True
        if not added.any():
            break
        chosen |= added
    return low, high, points, subset


def _paper_bounds(data: _Data, counter: _Counter) -> tuple[NDArray[np.float64], NDArray[np.float64], list[tuple[int, ...]]]:
    p = data.orders.num_parameters
    lows, highs = np.full(p, math.inf), np.full(p, -math.inf)
    feasible: list[tuple[int, ...]] = []
    for signs in itertools.product((1, -1), repeat=data.orders.na):
        lp = _orthant_lp(data, signs)
        low, high, _, solved = _row_generated_bounds(lp, p, counter)
        if not np.all(np.isfinite(low)):
            if _proven_infeasible(solved, counter):
                continue
            # Not provably empty (a sliver within the solver tolerance): keep the orthant with its box.
            low, high = lp.lower[:p].copy(), lp.upper[:p].copy()
        feasible.append(tuple(signs))
        lows, highs = np.minimum(lows, low), np.maximum(highs, high)
    return lows, highs, feasible


# ----------------------------------------------------------------------------------------------------------
# the coupled method: shared δx, McCormick envelopes, iterated tightening
# ----------------------------------------------------------------------------------------------------------


def _coupled_lp(data: _Data, theta_low: NDArray[np.float64], theta_high: NDArray[np.float64]) -> _LP:
    """Variables: θ (p), δx_s (N), and for each lag i the products z_{i,s} = a_i δx_s (N each).

    Equations t: -psi_t θ + δx_t + Σ_i z_{i,t-i} = -x_t^c (for a fixed a see :class:`_ExactProblemAtFixedA`).
    """
    orders = data.orders
    na, p = orders.na, orders.num_parameters
    N = data.u.size
    m = data.times.size
    width = p + N + na * N
    rows, cols, vals = [], [], []
    eq_index = np.arange(m)
    # -psi θ
    for k in range(p):
        rows.append(eq_index); cols.append(np.full(m, k)); vals.append(-data.regressors[:, k])
    rows.append(eq_index); cols.append(p + data.times); vals.append(np.ones(m))
    for i in range(1, na + 1):
        rows.append(eq_index); cols.append(p + N + (i - 1) * N + data.times - i); vals.append(np.ones(m))
    A_eq = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m, width))
    b_eq = -data.xc[data.times]
    gain, gain_rhs = _gain_row(orders, width)
    lower = np.concatenate([theta_low, -data.dx, np.zeros(na * N)])
    upper = np.concatenate([theta_high, data.dx, np.zeros(na * N)])
    ub_rows, ub_cols, ub_vals, ub_rhs = [], [], [], []
    s_index = np.arange(N)
    D = data.dx
    base = 0
    for i in range(na):
        z_cols = p + N + i * N + s_index
        d_cols = p + s_index
        aL, aU = float(theta_low[i]), float(theta_high[i])
        magnitude = max(abs(aL), abs(aU))
        lower[z_cols], upper[z_cols] = -magnitude * D, magnitude * D
        # four McCormick inequalities per s, in the variables (a_i, δx_s, z_{i,s}):
        #   aL δ - D a - z <= -aL D ;  aU δ + D a - z <= aU D ;  -aU δ + D a + z <= aU D ;  -aL δ - D a + z <= -aL D
        for coef_d, coef_a, coef_z, rhs in ((aL, -1.0, -1.0, -aL), (aU, 1.0, -1.0, aU), (-aU, 1.0, 1.0, aU), (-aL, -1.0, 1.0, -aL)):
            r = base + s_index
            ub_rows.extend([r, r, r]); ub_cols.extend([d_cols, np.full(N, i), z_cols])
            ub_vals.extend([np.full(N, coef_d), coef_a * D, np.full(N, coef_z)])
            ub_rhs.append(rhs * D)
            base += N
    if ub_rhs:
        A_ub = sp.csr_matrix((np.concatenate(ub_vals), (np.concatenate(ub_rows), np.concatenate(ub_cols))),
                             shape=(sum(len(x) for x in ub_rhs), width))
        b_ub = np.concatenate(ub_rhs)
    else:
        A_ub, b_ub = sp.csr_matrix((0, width)), np.zeros(0)
    A_eq_all = sp.vstack([A_eq, gain]).tocsr()
    b_eq_all = np.concatenate([b_eq, gain_rhs])
    lp = _LP(A_ub, b_ub, A_eq_all, b_eq_all, lower, upper)
    return lp if data.shared is None else _with_shared_backlash(lp, data, p)


def _interval_lp(data: _Data, theta_low: NDArray[np.float64], theta_high: NDArray[np.float64]) -> _LP:
    """A smaller outer relaxation for a narrow box of a: a_i δx_s = a_i^c δx_s + e_{i,s} with
    |e_{i,s}| <= r_i Δx_s (a^c, r: centre and radius of the box of a_i), and the e eliminated, so

        |-psi_t θ + δx_t + Σ_i a_i^c δx_{t-i} + x_t^c| <= Σ_i r_i Δx_{t-i}.

    Variables θ (p) and δx (N) only, one ranged row per equation. Every point of the exact set with a in the box
    satisfies it (|a_i - a_i^c| |δx_s| <= r_i Δx_s), so its LP bounds are valid. It contains the McCormick
    relaxation (the set |z - a^c δx| <= r Δx is convex and holds on the graph of a δx, hence on its convex
    hull) and is looser only for a near a corner of its box, by at most r_i Δx_s per product: negligible once
    the box of a is narrow (r_i << |a_i|), while the LP has a third of the columns and a quarter of the rows.
    """
    orders = data.orders
    na, p = orders.na, orders.num_parameters
    N, m = data.u.size, data.times.size
    width = p + N
    centre = 0.5 * (theta_low[:na] + theta_high[:na])
    radius = np.maximum(0.5 * (theta_high[:na] - theta_low[:na]), 0.0)
    per_row = p + na + 1
    cols = np.empty((m, per_row), dtype=np.int64)
    vals = np.ones((m, per_row))
    cols[:, :p] = np.arange(p)
    vals[:, :p] = -data.regressors
    slack = np.zeros(m)
    for i in range(1, na + 1):
        cols[:, p + na - i] = p + data.times - i
        vals[:, p + na - i] = centre[i - 1]
        slack += radius[i - 1] * data.dx[data.times - i]
    cols[:, p + na] = p + data.times
    rows = sp.csr_matrix((vals.ravel(), cols.ravel(), np.arange(m + 1) * per_row), shape=(m, width))
    xt = data.xc[data.times]
    gain, gain_rhs = _gain_row(orders, width)
    lp = _LP(sp.csr_matrix((0, width)), np.zeros(0), gain, gain_rhs, np.concatenate([theta_low, -data.dx]),
             np.concatenate([theta_high, data.dx]), rows, -slack - xt, slack - xt)
    return lp if data.shared is None else _with_shared_backlash(lp, data, p)


def _with_shared_backlash(lp: _LP, data: _Data, p: int) -> _LP:
    """Append the columns [ρ_l, c_l, ρ_r, c_r, ζ_1..ζ_K] and the rows that tie the inverted samples to them:
    δx_t - y_t ρ_r - c_r + ζ_t = -x_t^c (rising), δx_t - y_t ρ_l + c_l + ζ_t = -x_t^c (falling)."""
    shared = data.shared
    assert shared is not None
    K = shared.sample_indices.size
    width = lp.lower.size
    new_width = width + 4 + K
    link_rows = np.arange(K)
    rho_col = np.where(shared.rising, width + 2, width + 0)
    c_col = np.where(shared.rising, width + 3, width + 1)
    c_val = np.where(shared.rising, -1.0, 1.0)
    link = sp.csr_matrix((np.concatenate([np.ones(K), -shared.output_rad, c_val, np.ones(K)]),
                          (np.tile(link_rows, 4), np.concatenate([p + shared.sample_indices, rho_col, c_col,
                                                                   width + 4 + link_rows]))), shape=(K, new_width))
    polygon = sp.hstack([sp.csr_matrix((shared.rows.shape[0], width)), sp.csr_matrix(shared.rows),
                         sp.csr_matrix((shared.rows.shape[0], K))]).tocsr()
    A_ub = sp.vstack([sp.hstack([lp.A_ub, sp.csr_matrix((lp.A_ub.shape[0], 4 + K))]), polygon]).tocsr()
    A_eq = sp.vstack([sp.hstack([lp.A_eq, sp.csr_matrix((lp.A_eq.shape[0], 4 + K))]), link]).tocsr()
    A_range, range_lower, range_upper = lp.ranged()
    return _LP(A_ub, np.concatenate([lp.b_ub, shared.rhs]), A_eq,
               np.concatenate([lp.b_eq, -data.xc[shared.sample_indices]]),
               np.concatenate([lp.lower, shared.lower, -shared.zeta_bound_rad]),
               np.concatenate([lp.upper, shared.upper, shared.zeta_bound_rad]),
               sp.hstack([A_range, sp.csr_matrix((A_range.shape[0], 4 + K))]).tocsr(), range_lower, range_upper)


def _tighten(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], counter: _Counter, max_rounds: int,
             relative_improvement: float, full_last_round: bool,
             relaxation: Callable[[_Data, NDArray[np.float64], NDArray[np.float64]], _LP] | None = None,
             full_rounds: bool = False, wanted: NDArray[np.bool_] | None = None, retry: bool = False,
             start: _PartStart | None = None
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], int, list[NDArray[np.float64]], bool]:
    """Rounds of the McCormick relaxation: LPs over a only tighten the box of a (which sets the envelopes)
    until no a-interval shrinks by more than ``relative_improvement`` or ``max_rounds`` relaxations were
    solved; with ``full_last_round`` the last round bounds every parameter, with ``full_rounds`` every round
    does (the bounds of b then tighten each other through the unit-gain row). Returns the box, the rounds,
    the extreme points of the last round and whether the relaxation was proven empty. ``relaxation`` builds
    the LP from (data, low, high); McCormick (:func:`_coupled_lp`) by default. ``wanted`` (2p booleans, see
    :func:`_bounds_over`) limits every round to those bounds, ``retry`` and ``start`` are passed on to it (a start
    only to the first round: the model of a later round has another box)."""
    relaxation = _coupled_lp if relaxation is None else relaxation
    p, na = data.orders.num_parameters, data.orders.na
    rounds = 0
    converged = na == 0
    while True:
        rounds += 1
        final = converged or rounds >= max_rounds
        lp = relaxation(data, low, high)
        count = p if (full_rounds or (final and full_last_round)) else na
        new_low, new_high, points = _bounds_over(lp, count, counter, None if wanted is None else wanted[: 2 * count],
                                                 retry, start if rounds == 1 else None)
        if not np.all(np.isfinite(new_low)):
            if _proven_infeasible(lp, counter):
                return low, high, rounds, [], True
            if final:
                return low, high, rounds, [], False
            converged = True  # not provably empty: finish with the last round on the current box
            continue
        shrink = np.max((high[:count] - low[:count] - (np.minimum(new_high, high[:count]) - np.maximum(new_low, low[:count])))
                        / np.maximum(high[:count] - low[:count], 1e-300))
        low, high = low.copy(), high.copy()
        low[:count], high[:count] = np.maximum(new_low, low[:count]), np.minimum(new_high, high[:count])
        if final:
            return low, high, rounds, points, False
        converged = shrink < relative_improvement


_WINDOW = 200
"""Samples per window: the box of a is first tightened on the first window (the set from a subset of the
equations contains the full set, so its bounds are valid; the LPs are small), then every window is bounded."""
_WINDOW_OVERLAP = 20
"""Samples shared by consecutive windows (so that every equation lies whole inside some window)."""
_JOINT_SAMPLES = 3000
"""Samples of the final joint relaxation: all of them for records up to this length (the all-data relaxation),
else the windows that decide the bounds, up to this many samples."""
_FULL_DATA_RELAXATION = _interval_lp
_PART_ROUNDS = 1
"""Rounds of a part's interval relaxation per pass over the parts (its final round, all parameters). A part's own
further rounds tighten from its own box only, a further pass from the intersection of all parts: at N = 10 000,
12 bits (run 0), one round per pass over 4 passes gave a1 4.85e-6 in 9.9 CPU-s of joint LPs, six rounds per
pass over 2 passes 4.98e-6 in 13.9 CPU-s."""
_PART_PASSES = 6
"""Passes over the parts at most (they stop earlier once a pass shrinks no interval by ``tightening_tolerance``)."""

DEFAULT_WINDOW_SAMPLES = _WINDOW
DEFAULT_JOINT_SAMPLES = _JOINT_SAMPLES

MapFunction = Callable[..., Iterable[Any]]
"""``map(function, tasks)``: the builtin, or ``Executor.map`` to run the windows in other processes."""
Progress = Callable[[str, int, int], None]
"""``progress(stage, done, total)``, called as windows finish."""


@dataclass(frozen=True)
class _WindowPlan:
    """How the record was cut: ``segments`` (start, stop) of the windows and the joint samples used."""

    segments: tuple[tuple[int, int], ...]
    num_parts: int
    passes: int
    part_passes: int
    all_parts: int = 1
    second_pass_parts: int = 0


def _window_segments(num_samples: int, window: int, overlap: int) -> list[tuple[int, int]]:
    step = max(window - overlap, 1)
    starts = list(range(0, max(num_samples - window, 0) + 1, step))
    if starts[-1] + window < num_samples:
        starts.append(num_samples - window)
    return [(start, min(start + window, num_samples)) for start in starts]


def _restrict(data: _Data, segments: Sequence[tuple[int, int]]) -> _Data:
    """The problem on the equations that lie whole inside the given sample segments (overlapping or touching
    segments are merged first, so every sample appears once). The feasible set of a subset of the equations
    contains the full one."""
    n = data.orders.first_equation
    merged: list[list[int]] = []
    for start, stop in sorted(segments):
        if merged and start <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], stop)
        else:
            merged.append([start, stop])
    samples = np.concatenate([np.arange(start, stop) for start, stop in merged])
    keep = np.zeros(data.times.size, dtype=bool)
    for start, stop in merged:
        keep |= (data.times >= start + n) & (data.times < stop)
    position = np.full(data.u.size, -1, dtype=np.int64)
    position[samples] = np.arange(samples.size)
    shared = data.shared
    if shared is not None:
        inside = position[shared.sample_indices] >= 0
        shared = SharedBacklashConstraints(position[shared.sample_indices[inside]], shared.rising[inside],
                                           shared.output_rad[inside], shared.zeta_bound_rad[inside], shared.rows,
                                           shared.rhs, shared.lower, shared.upper)
    return _Data(data.orders, data.u[samples], data.xc[samples], data.dx[samples], position[data.times[keep]],
                 data.regressors[keep], shared)


def _window_task(task: tuple[str, _Data, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None,
                             NDArray[np.bool_] | None, _PartStart | None, bool]) -> tuple[Any, _Counter]:
    """One window's work, in this or another process (module level, plain data in and out).

    ``("bounds", window, low, high, None, wanted, None, retry)``: certified bounds on the window's interval
    relaxation over the box. ``("joint", part, low, high, [max_rounds, tolerance], wanted, start, retry)``: the
    rounds of the interval relaxation on a part of the record (:func:`_tighten`): its box, rounds, the θ of its
    extreme points, whether it is proven empty and the hand-off to the part's next pass, which starts from
    ``start`` (:class:`_PartStart`; None: from scratch). ``wanted`` (2p booleans, None: all) names the bounds to solve
    (:func:`_bounds_over`); the others come back as the box given. ``retry``: solved by :data:`RETRY_SETTINGS`
    (a task solved again after its worker died, :class:`_GuardedMap`)."""
    kind, window, low, high, settings, wanted, start, retry = task
    counter = _Counter()
    if kind == "joint":
        assert settings is not None
        counter.stage = f"joint relaxation of {window.u.size} samples"
        max_rounds, tolerance = int(settings[0]), float(settings[1])
        start = _PartStart() if start is None else start
        low, high, used, extreme, empty = _tighten(window, low, high, counter, max_rounds, tolerance, True,
                                                   _FULL_DATA_RELAXATION, wanted=wanted, retry=retry, start=start)
        return (low, high, used, [None if x is None else x[: window.orders.num_parameters] for x in extreme],
                empty, start), counter
    counter.stage = "window relaxation"
    new_low, new_high, _ = _bounds_over(_FULL_DATA_RELAXATION(window, low, high), window.orders.num_parameters,
                                        counter, wanted, retry)
    return (new_low, new_high), counter


DEFAULT_PARTITION_SAMPLES = 1000
"""Records up to this length get the final tightening by partition of the box of a (:func:`_partitioned_bounds`)."""
DEFAULT_MOMENT_SAMPLES = 0
"""Records up to this length get the moment (SDP) cuts as a last tightening (:func:`_moment_bounds`); off by default."""
_PARTITION_BOXES = 48
"""Sub-boxes of a solved at most by the partition; it stops earlier once a refinement moves no bound by 1 %. N = 1000,
8 bits, run 0 of the benchmark: 24 cells left a2 1.117 times as wide as its verified inner values, 48 (36 solved
before the 1 % stop) 1.075, for 12.6 instead of 8.8 CPU-s."""


_PARTITION_STAGE = "partition of the box of a (cells)"


@dataclass(frozen=True)
class _SubBox:
    """One cell of the partition of the box of a, with the box of θ its relaxation gives and the extreme
    points (None where a bound fell back)."""

    a_low: NDArray[np.float64]
    a_high: NDArray[np.float64]
    low: NDArray[np.float64]
    high: NDArray[np.float64]
    points: tuple[NDArray[np.float64] | None, ...]
    depth: int = 0
    """Halvings from the whole box of a to this cell."""


def _partitioned_bounds(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], counter: _Counter,
                        max_boxes: int = _PARTITION_BOXES, relative_improvement: float = 0.01,
                        progress: Progress | None = None, patient: bool = False
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.float64] | None], int]:
    """The final tightening of short records: spatial branch and bound on the box of a.

    The relaxations replace a_i δx_s by a set that grows with the width of the box of a_i (McCormick:
    :func:`_coupled_lp`; the interval relaxation: r_i Δx_s per product), so the box that one relaxation gives
    for the whole box of a is wider than the exact set's (outer/inner 1.4-2 at 8 bits without the cells).
    Here the box of a is cut into cells; each cell's interval relaxation is tightened over the cell alone (narrower a,
    smaller envelopes), cells whose relaxation is proven empty (certified phase 1) are dropped, and the hull of
    the cells' boxes is the bound. Every feasible point has its a in some cell and satisfies that cell's
    relaxation, so the hull is a guaranteed outer bound. The cells that attain a bound of the hull are halved
    along their relatively widest a_i and solved again, until ``max_boxes`` cells were solved or a refinement
    moves no bound by more than ``relative_improvement`` of its width (``patient``: only once the cells were
    halved twice along every a_i, see :func:`_closed_relaxation_gap`). Returns the box, the extreme points
    (``points[2k]`` attains the lower bound of θ_k) and the number of cells solved."""
    na, p = data.orders.na, data.orders.num_parameters
    # the interval relaxation: a third of McCormick's columns, and as tight once the cells are narrow
    relaxation = _interval_lp
    counter.stage = f"partition of the box of a ({data.u.size} samples)"

    def solve(a_low: NDArray[np.float64], a_high: NDArray[np.float64], depth: int) -> _SubBox | None:
        cell_low, cell_high = low.copy(), high.copy()
        cell_low[:na], cell_high[:na] = a_low, a_high
        box_low, box_high, _, points, empty = _tighten(data, cell_low, cell_high, counter, 3, 0.05, True, relaxation,
                                                       full_rounds=True)
        if empty:
            return None
        if not points:
            # HiGHS found the cell's relaxation infeasible, but the certificate cannot prove it: a sliver within
            # the solver's tolerance. Keeping the cell's box would give the hull the whole box of b (at
            # 96 cells at N = 1000, 8 bits left the bounds as before the partition); the relaxation widened by
            # the tolerance contains the cell's set, so its certified bounds hold (or prove the cell empty).
            widened = _widened(relaxation(data, box_low, box_high))
            wide_low, wide_high, _ = _bounds_over(widened, p, counter)
            if not np.all(np.isfinite(wide_low)):
                if _proven_infeasible(widened, counter):
                    return None
            else:
                box_low, box_high = np.maximum(box_low, wide_low), np.minimum(box_high, wide_high)
            points = [None] * (2 * p)
        return _SubBox(a_low, a_high, box_low, box_high, tuple(None if x is None else x[:p] for x in points), depth)

    def hull(cells: list[_SubBox]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return (np.min([c.low for c in cells], axis=0), np.max([c.high for c in cells], axis=0))

    def halves(cell: _SubBox) -> list[tuple[NDArray[np.float64], NDArray[np.float64], int]]:
        i = int(np.argmax((cell.a_high - cell.a_low) / np.maximum(high[:na] - low[:na], 1e-300)))
        middle = 0.5 * (cell.a_low[i] + cell.a_high[i])
        left_high, right_low = cell.a_high.copy(), cell.a_low.copy()
        left_high[i], right_low[i] = middle, middle
        return [(cell.a_low, left_high, cell.depth + 1), (right_low, cell.a_high, cell.depth + 1)]

    solved = 0
    cells: list[_SubBox] = []
    pending = halves(_SubBox(low[:na], high[:na], low, high, ()))
    current_low, current_high = low.copy(), high.copy()
    while True:
        for a_low, a_high, depth in pending:
            solved += 1
            cell = solve(a_low, a_high, depth)
            if cell is not None:
                cells.append(cell)
            if progress is not None:
                progress(_PARTITION_STAGE, solved, max_boxes)
        if not cells:  # every cell proven empty, the caller's relaxation not (tolerances): keep its box
            return low, high, [None] * (2 * p), solved
        cells_low, cells_high = hull(cells)
        new_low, new_high = np.maximum(cells_low, low), np.minimum(cells_high, high)
        moved = np.max(((current_high - current_low) - (new_high - new_low))
                       / np.maximum(current_high - current_low, 1e-300))
        current_low, current_high = new_low, new_high
        _LOG.debug("partition: %d cell(s) solved, the hull moved a bound by %.3g of its width, half-widths %s",
                   solved, moved, 0.5 * (current_high - current_low))
        deciding = sorted({int(np.argmin([c.low[k] for c in cells])) for k in range(p)}
                          | {int(np.argmax([c.high[k] for c in cells])) for k in range(p)})
        # A refinement that moves the hull by under a tenth of ``relative_improvement`` ends the partition (the
        # relaxation is about tight: 1e-4 of the width at 15 bits); one that moves it by less than
        # ``relative_improvement`` ends it only once the cells just solved were halved twice along every a_i:
        # one halving leaves a bound to the other axes, so the first refinements may move the hull by little
        # before the next ones move it by much (N = 100, 8 bits, run 9: b1 0.7 % and 0.3 %, then 3.6 %).
        # Waiting for the two halvings at every move below the tolerance made N = 1000, 15 bits 5 times slower.
        settled = min(depth for _, _, depth in pending) >= 2 * na
        tiny = moved < 0.1 * relative_improvement and solved > 2 * na and not patient
        if tiny or (moved < relative_improvement and settled) or solved + 2 * len(deciding) > max_boxes:
            break
        # a cell is replaced by its halves only once they are solved (in the next turn of the loop)
        pending = [half for index in deciding for half in halves(cells[index])]
        cells = [cell for index, cell in enumerate(cells) if index not in deciding]
    if progress is not None:
        progress(_PARTITION_STAGE, solved, solved)  # the stage ends, usually before the most cells it may take
    points: list[NDArray[np.float64] | None] = [None] * (2 * p)
    for k in range(p):
        if cells:
            lowest = min(cells, key=lambda c: c.low[k])
            highest = max(cells, key=lambda c: c.high[k])
            points[2 * k] = lowest.points[2 * k] if lowest.points else None
            points[2 * k + 1] = highest.points[2 * k + 1] if highest.points else None
    return current_low, current_high, points, solved


RELAXATION_GAP_TARGET = 1.1
"""Largest ratio of a parameter's outer interval to the span of its verified inner values that a partitioned
record is left with when a patient partition can do better (:func:`_closed_relaxation_gap`): the goal set
for N <= 1000 (above it a tenth of the reported width may be relaxation, not data). A lower target
costs time on most records at 8 bits: at 1.05 the median run of N = 100 was partitioned twice (2.4 times the
CPU) for 1.05 instead of 1.06."""


def _relaxation_gap(low: NDArray[np.float64], high: NDArray[np.float64], inner_low: NDArray[np.float64],
                    inner_high: NDArray[np.float64]) -> float:
    """The largest outer/inner ratio over the parameters with verified inner values on both sides."""
    inner = inner_high - inner_low
    known = np.isfinite(inner) & (inner > 0)
    return float(np.max((high - low)[known] / inner[known])) if np.any(known) else 1.0


def _closed_relaxation_gap(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64],
                           points: list[NDArray[np.float64] | None], inner: tuple[NDArray[np.float64], ...],
                           counter: _Counter, progress: Progress | None
                           ) -> tuple[NDArray[np.float64], NDArray[np.float64], tuple[NDArray[np.float64], ...], int]:
    """The partition made again, patient, where the verified inner values show that the first one stopped
    early: a gap above :data:`RELAXATION_GAP_TARGET`. A first partition ends on a refinement that moves the
    hull by under a tenth of its tolerance, which the first halvings along one a_i can do before the next
    move it by much (N = 100, 8 bits, run 8: b2 1.102 after 6 cells; with every cell halved twice along each
    a_i, 1.08 or less over 10 runs). Waiting for those halvings on every record made N = 1000, 15 bits 5 times
    slower where the first partition is already tight, so only a record whose gap shows it pays. It starts
    from the first partition's hull (a valid outer box, so its cells' relaxations are at least as tight); the
    inner values are searched again from its extreme points and kept where they are wider (every one is a
    verified point). Returns the box, the inner values and witness, and the cells solved (0: not needed)."""
    if _relaxation_gap(low, high, inner[0], inner[1]) <= RELAXATION_GAP_TARGET:
        return low, high, inner, 0
    new_low, new_high, cell_points, cells = _partitioned_bounds(data, low, high, counter, progress=progress,
                                                                patient=True)
    new_low, new_high = np.maximum(new_low, low), np.minimum(new_high, high)
    points = [new if new is not None else old for new, old in zip(cell_points, points)]
    inner_low, inner_high, witness = _inner_values(data, new_low, new_high, points, counter)
    inner_low, inner_high = np.fmin(inner_low, inner[0]), np.fmax(inner_high, inner[1])
    return new_low, new_high, (inner_low, inner_high, inner[2] if witness is None else witness), cells


_WIDENING = 1e-6
"""Relative widening of every row by :func:`_widened` (ten times HiGHS's primal feasibility tolerance)."""


def _widened(lp: _LP) -> _LP:
    """The LP with every row relaxed by ``_WIDENING`` (1 + |its bound|), equalities becoming ranged rows: its
    feasible set contains the LP's, so its certified bounds are bounds of the LP's set too."""
    def slack(bound: NDArray[np.float64]) -> NDArray[np.float64]:
        return _WIDENING * (1.0 + np.abs(bound))

    A_range, range_lower, range_upper = lp.ranged()
    return _LP(lp.A_ub, lp.b_ub + slack(lp.b_ub), sp.csr_matrix((0, lp.lower.size)), np.zeros(0), lp.lower, lp.upper,
               sp.vstack([A_range, lp.A_eq]).tocsr(),
               np.concatenate([range_lower - slack(range_lower), lp.b_eq - slack(lp.b_eq)]),
               np.concatenate([range_upper + slack(range_upper), lp.b_eq + slack(lp.b_eq)]))


_MOMENT_STAGE = "moment (SDP) relaxation"


def _lifted_moment_lp(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64]
                      ) -> tuple[sp.csr_matrix, NDArray[np.float64], sp.csr_matrix, NDArray[np.float64],
                                 NDArray[np.float64], NDArray[np.float64]]:
    """The McCormick LP (:func:`_coupled_lp`, with the shared backlash if any) lifted by the moment columns
    A_ij ~ a_i a_j (box from the products of the bounds of a, McCormick rows) and D_s ~ δx_s^2 (0 <= D_s <=
    Δx_s^2): (A_ub, b_ub, A_eq, b_eq, lower, upper). Without cuts it is the McCormick LP (A, D are free in
    their boxes); the cuts of :func:`identify.moment_relaxation.moment_cuts` are rows over these columns."""
    from identify import moment_relaxation as moments

    na, N = data.orders.na, data.u.size
    base = _coupled_lp(data, low, high)
    width = base.lower.size
    extra = moments.moment_columns(na, N)
    a_low, a_high = low[:na], high[:na]
    pair_low, pair_high = [], []
    for i, j in [(i, j) for i in range(na) for j in range(i, na)]:
        corners = [a_low[i] * a_low[j], a_low[i] * a_high[j], a_high[i] * a_low[j], a_high[i] * a_high[j]]
        # a_i^2 >= 0 even when the box of a_i holds 0
        least = 0.0 if i == j and a_low[i] <= 0.0 <= a_high[i] else min(corners)
        pair_low.append(least - 1e-12 * (1.0 + abs(least)))
        pair_high.append(max(corners) + 1e-12 * (1.0 + abs(max(corners))))
    lower = np.concatenate([base.lower, pair_low, np.zeros(N)])
    upper = np.concatenate([base.upper, pair_high, data.dx ** 2 * (1.0 + 1e-12)])

    def widen(matrix: sp.csr_matrix) -> sp.csr_matrix:
        return sp.hstack([matrix, sp.csr_matrix((matrix.shape[0], extra))]).tocsr()

    rlt, rlt_rhs = moments.moment_rows(na, a_low, a_high, width + extra, width)
    return (sp.vstack([widen(base.A_ub), rlt]).tocsr(), np.concatenate([base.b_ub, rlt_rhs]), widen(base.A_eq),
            base.b_eq, lower, upper)


def _moment_bounds(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], counter: _Counter,
                   notes: list[str]) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The final tightening by the first-order moment relaxation (:mod:`identify.moment_relaxation`): the SDP
    of every bound is solved with cvxpy, its PSD duals become cuts of the McCormick LP lifted by the moment
    columns (A, D), and that LP's certified bounds are intersected with the box. An SDP that fails, or a
    missing cvxpy, leaves the bound as it was and adds a note. Returns the box and the SDP time in seconds."""
    from identify import moment_relaxation as moments

    missing = moments.available()
    if missing is not None:
        notes.append(f"all parameters: the moment (SDP) relaxation was not run: {missing}; the bounds are the LP ones")
        return low, high, 0.0
    na, p, N = data.orders.na, data.orders.num_parameters, data.u.size
    A_ub, b_ub, A_eq, b_eq, lower, upper = _lifted_moment_lp(data, low, high)
    try:
        cuts = moments.moment_cuts(na=na, p=p, num_samples=N, equations=A_eq, equation_rhs=b_eq,
                                   inequalities=A_ub, inequality_rhs=b_ub, lower=lower, upper=upper,
                                   objectives=list(range(2 * p)), delta_bound_rad=data.dx)
    except Exception as error:  # noqa: BLE001 - any failure of the optional SDP path keeps the LP bounds
        notes.append(f"all parameters: the moment (SDP) relaxation failed ({type(error).__name__}: {error}); "
                     "the bounds are the LP ones (still guaranteed)")
        return low, high, 0.0
    names = data.orders.parameter_names
    for objective, status in cuts.failed:
        k, side = divmod(objective, 2)
        notes.append(f"{names[k]} {'upper' if side else 'lower'} bound: the moment SDP gave no dual ({status}); "
                     "that bound is the LP one (still guaranteed)")
    if not cuts.rhs.size:
        return low, high, cuts.sdp_s
    lp = _LP(sp.vstack([A_ub, cuts.rows]).tocsr(), np.concatenate([b_ub, cuts.rhs]), A_eq, b_eq, lower, upper)
    counter.stage = f"{_MOMENT_STAGE} of {N} samples"
    new_low, new_high, _ = _bounds_over(lp, p, counter)
    if not np.all(np.isfinite(new_low)):
        return low, high, cuts.sdp_s  # not proven empty here: keep the box (the LP path decides emptiness)
    return np.maximum(low, new_low), np.minimum(high, new_high), cuts.sdp_s


RETRY_SETTINGS = {"solver": "ipm", "run_crossover": "off", "presolve": "on"}
"""HiGHS settings for every solve of a task a dead worker left unfinished, solved once more
(:class:`_GuardedMap`): the interior-point method without crossover (its duals are all the certificate of
:meth:`_Solver.minimize` needs). The worker deaths met so far were HiGHS 1.16 overflowing its stack in the dual
simplex (``HEkkDualRHS::chooseNormal``), which the interior-point method does not run; the solver is
deterministic, so the same task by the dual simplex would die again (and did, with presolve off: N = 100 000,
8 bits, run 0 of the record-length benchmark). It costs about 3 times the simplex on a part."""


class _GuardedMap:
    """``map_windows(_window_task, tasks)`` that survives the loss of the processes running it.

    A worker process that dies (a segfault inside HiGHS, the out-of-memory killer) breaks a process pool
    (``BrokenProcessPool``, a ``BrokenExecutor``) and a Dask cluster reports ``KilledWorker``. The tasks that
    did not finish are solved once more, each in its own map call and by :data:`RETRY_SETTINGS` (a pool that
    starts anew after a lost worker, ``rig.batch``'s, or a Dask cluster, takes them; a broken pool refuses them
    at once). If that fails too, every window's and part's box still contains the feasible set, so the results
    that did arrive give a valid bound: the map stops there, the failure is recorded for the notes, and every
    later stage gets no results (it keeps the box it was given) instead of the user getting a traceback."""

    def __init__(self, map_windows: MapFunction, counter: _Counter) -> None:
        self._map = map_windows
        self._counter = counter
        self.failure: str | None = None

    def results(self, tasks: Iterable[Any], stage: str, one_per_call: bool = False) -> Iterable[Any]:
        """The tasks' results in order; ``one_per_call`` hands each task to its own ``map`` call (all submitted
        before the first result is awaited, as ``Executor.map`` does), so that a pool's chunks of several tasks
        cannot leave a core idle on a few long tasks."""
        if self.failure is not None:
            return
        tasks = list(tasks)
        finished = 0
        try:
            for result in self._outcomes(tasks, one_per_call):
                finished += 1
                yield result
            return
        except Exception as error:  # noqa: BLE001 - only the executor's own failures, re-raised otherwise
            first = self._lost_worker(error)
        _LOG.warning("%s: %s; solving its %d unfinished task(s) again by the interior-point method", stage, first,
                     len(tasks) - finished)
        try:
            yield from self._outcomes([(*task[:-1], True) for task in tasks[finished:]], True)
        except Exception as error:  # noqa: BLE001 - as above
            self._lost_worker(error)
            self.failure = first
            self._counter.lost_stages.append((stage, first))

    def _outcomes(self, tasks: list[Any], one_per_call: bool) -> Iterable[Any]:
        if one_per_call:
            pending = [self._map(_window_task, [task]) for task in tasks]
            outcomes: Iterable[Any] = (outcome for batch in pending for outcome in batch)
        else:
            outcomes = self._map(_window_task, tasks)
        for result, done in outcomes:
            self._counter.merge(done)
            yield result

    @staticmethod
    def _lost_worker(error: Exception) -> str:
        """The message of an executor's lost worker; any other error is raised again."""
        if not (isinstance(error, BrokenExecutor) or type(error).__name__ == "KilledWorker"):
            raise error
        return f"{type(error).__name__}: {error}".rstrip(": ")


def _coupled_bounds(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], counter: _Counter,
                    max_rounds: int, relative_improvement: float, map_windows: MapFunction = map,
                    progress: Progress | None = None, window: int = _WINDOW,
                    joint_samples: int = _JOINT_SAMPLES
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], int, list[NDArray[np.float64]], _WindowPlan]:
    """Coupled bounds; records longer than two windows go window by window.

    1. The McCormick rounds on the first window make the box of a narrow.
    2. Every window (``window`` samples, consecutive ones sharing ``_WINDOW_OVERLAP``) is bounded on the
       interval relaxation over the current box; the boxes are intersected (each contains the whole record's
       set) and fed back into every window's relaxation, until no interval shrinks by more than
       ``relative_improvement``. The windows are independent: ``map_windows`` may run them in parallel.
    3. The final rounds solve the interval relaxation jointly over all samples when there are at most
       ``joint_samples`` (the all-data relaxation, from a narrower box than the first window's, so never
       wider than it); otherwise jointly over each of the overlapping parts of ``joint_samples`` samples
       (in parallel through ``map_windows``), their boxes intersected, and again from the intersection (one
       round of each part per pass) until a pass shrinks no interval by ``relative_improvement``.
       Intersecting window boxes alone is 1.1-2 times wider than the joint relaxation (the information of
       bounded-error data is spread over the whole record), so the parts are large.

    Each step's bounds are certified bounds of a valid relaxation of a subset of the equations over a box that
    contains the feasible set, so their intersection is a guaranteed outer bound."""
    p, na, N = data.orders.num_parameters, data.orders.na, data.u.size
    if N <= 2 * window or not na:
        counter.stage = f"coupled relaxation of all {N} samples"
        low, high, used, points, empty = _tighten(data, low, high, counter, max_rounds, relative_improvement, True)
        plan = _WindowPlan(((0, N),), 1, 0, 1)
        return (np.full(p, math.nan), np.full(p, math.nan), used, [], plan) if empty else (low, high, used, points, plan)
    counter.stage = f"coupled relaxation of the first {window} samples"
    low, high, rounds, _, empty = _tighten(_subset(data, window), low, high, counter, max_rounds,
                                           relative_improvement, False)
    segments = _window_segments(N, window, _WINDOW_OVERLAP)
    if empty:
        return np.full(p, math.nan), np.full(p, math.nan), rounds, [], _WindowPlan(tuple(segments), 0, 0, 0)
    windows = [_restrict(data, [segment]) for segment in segments]
    guarded = _GuardedMap(map_windows, counter)
    own = _TaskBounds(len(windows), p)
    active, wanted = list(range(len(windows))), [None] * len(windows)
    passes = 0
    for passes in range(1, max(max_rounds, 1) + 1):
        label = f"window pass {passes}"
        new_low, new_high = low.copy(), high.copy()
        tasks = (("bounds", windows[k], low, high, None, mask, None, False) for k, mask in zip(active, wanted))
        for count, (k, mask, (lows, highs)) in enumerate(zip(active, wanted, guarded.results(tasks, label))):
            own.record(k, lows, highs, mask)
            new_low, new_high = np.maximum(new_low, lows), np.minimum(new_high, highs)
            if progress is not None:
                progress(label, count + 1, len(active))
        if np.any(new_low > new_high):
            # every window is a valid relaxation, so disjoint boxes prove the set empty only up to solver
            # tolerances: let the joint relaxation below decide
            break
        moving, advance = _pass_result(f"window pass {passes}", wanted, p, low, high, new_low, new_high,
                                       relative_improvement, na)
        low, high = new_low, new_high
        if not moving.any():
            break
        # The next pass re-bounds, per window, only the bounds still moving for which the window's own bound
        # came within one box width of the intersection and could reach it (:meth:`_TaskBounds.candidates`);
        # the windows and bounds left out are still valid (only the tightening is given up, never the guarantee).
        active, wanted = own.candidates(low, high, moving, np.repeat(high - low, 2), advance)
        if not active:
            break
    rounds += passes
    chunks = _window_segments(N, max(joint_samples, window), _WINDOW_OVERLAP) if N > joint_samples else [(0, N)]
    all_parts = len(chunks)
    if len(chunks) > 1:
        # Only the parts that hold a window whose own bound came within one box width of the intersection in
        # some direction: the others are valid too, but far from deciding (the same rule as the passes').
        width = np.repeat(high - low, 2)
        near = np.any(own.own > _as_lower_bounds(low, high) - width, axis=1)
        starts = np.array([segment[0] for segment in segments])[near]
        stops = np.array([segment[1] for segment in segments])[near]
        deciding = [chunk for chunk in chunks if np.any((starts >= chunk[0]) & (stops <= chunk[1]))]
        chunks = deciding or chunks
    points: list[NDArray[np.float64] | None] = [None] * (2 * p)
    chunk_passes = 0
    # All data jointly: all max_rounds rounds unless nothing moves. Each round maps a box monotonically (a
    # smaller box gives a smaller relaxation) and this box lies inside the one the all-data rounds started
    # over all the data at once, so after as many rounds it lies inside their result too; stopping at the
    # passes' tolerance could stop earlier, from a box that is already close. Parts: a fixed point over the parts,
    # one round of each part's relaxation per pass (_PART_ROUNDS), every pass from the intersection of the
    # previous one, each part solving only the bounds still moving that it may decide, until no bound moves or
    # _PART_PASSES passes were run. The box after any pass is a guaranteed outer bound, so the stopping rule
    # trades only tightness, never validity.
    settings = np.array([max_rounds, 1e-6]) if all_parts == 1 else np.array([_PART_ROUNDS, relative_improvement])
    part_bounds = _TaskBounds(len(chunks), p)
    # each part's next pass starts from its last basis (and settings) on the same LP, apart from the new box
    starts: list[_PartStart | None] = [None] * len(chunks)
    active_parts, part_wanted = list(range(len(chunks))), [None] * len(chunks)
    last_pass_parts = 0
    for chunk_passes in range(1, (_PART_PASSES if all_parts > 1 else 1) + 1):
        label = f"joint relaxation of {len(active_parts)} part(s) of up to {min(N, joint_samples)} samples"
        last_pass_parts = len(active_parts)
        new_low, new_high = low.copy(), high.copy()
        best_low, best_high = np.full(p, -math.inf), np.full(p, math.inf)
        tasks = (("joint", _restrict(data, [chunks[c]]), low, high, settings, mask, starts[c], False)
                 for c, mask in zip(active_parts, part_wanted))
        if progress is not None:
            progress(label, 0, len(active_parts))
        # one part per map call: parts are few and long, so chunks of several would leave a core idle
        for k, (c, mask, (lows, highs, used, chunk_points, empty, starts[c])) in enumerate(
                zip(active_parts, part_wanted, guarded.results(tasks, label, one_per_call=True))):
            part_bounds.record(c, lows, highs, mask)
            if empty:
                # a part of the equations has no solution, so neither has the whole record
                return np.full(p, math.nan), np.full(p, math.nan), rounds + used, [], _WindowPlan(
                    tuple(segments), len(chunks), passes, chunk_passes)
            rounds = max(rounds, passes + used)
            for j in range(p):
                if chunk_points and chunk_points[2 * j] is not None and lows[j] > best_low[j]:
                    best_low[j], points[2 * j] = lows[j], chunk_points[2 * j]
                if chunk_points and chunk_points[2 * j + 1] is not None and highs[j] < best_high[j]:
                    best_high[j], points[2 * j + 1] = highs[j], chunk_points[2 * j + 1]
            new_low, new_high = np.maximum(new_low, lows), np.minimum(new_high, highs)
            if progress is not None:
                progress(label, k + 1, len(active_parts))
        new_high = np.maximum(new_high, new_low)
        moving, advance = _pass_result(f"joint pass {chunk_passes}", part_wanted, p, low, high, new_low,
                                       new_high, relative_improvement, na)
        gain = (high - low) - (new_high - new_low)
        low, high = new_low, new_high
        if not moving.any():
            break
        # The next pass re-solves, per part, only the bounds still moving whose own bound lies within this
        # pass's gain in width of the intersection and could reach it: a part's relaxation tightens with the
        # box (its envelopes are about r_i Δx_s), so a part further off is not expected to decide.
        active_parts, part_wanted = part_bounds.candidates(low, high, moving, np.repeat(gain, 2), advance)
        if not active_parts:
            break
    return low, high, rounds, points, _WindowPlan(tuple(segments), len(chunks), passes, chunk_passes, all_parts,
                                                  last_pass_parts if chunk_passes > 1 else 0)


def _as_lower_bounds(low: NDArray[np.float64], high: NDArray[np.float64]) -> NDArray[np.float64]:
    """The box as 2p lower bounds, larger = tighter: [low_0, -high_0, low_1, -high_1, ...] (the order of the
    extreme points of :func:`_bounds_over`)."""
    return np.stack([low, -high], axis=-1).reshape(*np.shape(low)[:-1], -1)


def _pass_result(label: str, wanted: Sequence[NDArray[np.bool_] | None], p: int, low: NDArray[np.float64],
                 high: NDArray[np.float64], new_low: NDArray[np.float64], new_high: NDArray[np.float64],
                 relative_improvement: float, na: int) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """After a pass over windows or parts (``wanted``: each task's selected bounds, None for all 2p) from the
    box [low, high] to [new_low, new_high]: the bounds still moving (:func:`_moving`) and the advance of each
    of the 2p lower bounds (:func:`_as_lower_bounds`), logged with the pass's ``label``."""
    moving = _moving(low, high, new_low, new_high, relative_improvement, na)
    advance = _as_lower_bounds(new_low, new_high) - _as_lower_bounds(low, high)
    _LOG.debug("%s over %d task(s), %d LPs: moving bounds %s, half-widths %s", label, len(wanted),
               sum(p * 2 if mask is None else int(mask.sum()) for mask in wanted), moving.astype(int),
               0.5 * (new_high - new_low))
    return moving, advance


def _moving(low: NDArray[np.float64], high: NDArray[np.float64], new_low: NDArray[np.float64],
            new_high: NDArray[np.float64], relative_improvement: float, na: int) -> NDArray[np.bool_]:
    """Per bound (2p, the order of :func:`_as_lower_bounds`): whether the next pass should solve it again,
    that is whether this pass moved it, or any bound of a, by more than half of ``relative_improvement`` times
    the width of its interval before the pass (two sides moving by less shrink an interval by less than
    ``relative_improvement``). The box of a sets every relaxation's envelopes (r_i Δx_s), so while it shrinks
    every bound may move again: at N = 100 000, 12 bits, the upper bound of b2 moved 3.6 % in the pass after
    one that had not moved it."""
    width = np.repeat(np.maximum(high - low, 1e-300), 2)
    moved = (_as_lower_bounds(new_low, new_high) - _as_lower_bounds(low, high)) / width > 0.5 * relative_improvement
    return moved | bool(moved[: 2 * na].any())


class _TaskBounds:
    """The own bounds of every window or part (tasks x 2p, :func:`_as_lower_bounds`) from its last solve and
    from the solve before, and the advance of the intersection in the last two passes, to choose what the next
    pass re-solves."""

    def __init__(self, num_tasks: int, p: int) -> None:
        self.own = np.full((num_tasks, 2 * p), -math.inf)
        self.before = np.full((num_tasks, 2 * p), -math.inf)
        self.advance: NDArray[np.float64] | None = None

    def record(self, task: int, lows: NDArray[np.float64], highs: NDArray[np.float64],
               wanted: NDArray[np.bool_] | None) -> None:
        solved = np.ones(self.own.shape[1], dtype=bool) if wanted is None else wanted
        self.before[task, solved] = self.own[task, solved]
        self.own[task, solved] = _as_lower_bounds(lows, highs)[solved]

    def candidates(self, low: NDArray[np.float64], high: NDArray[np.float64], moving: NDArray[np.bool_],
                   margin: NDArray[np.float64], advance: NDArray[np.float64]
                   ) -> tuple[list[int], list[NDArray[np.bool_]]]:
        """The tasks to re-solve and, for each, the bounds (the ``wanted`` of :func:`_bounds_over`): a bound
        still ``moving`` whose own value lies within ``margin`` (2p) of the intersection and would reach it
        with its expected gain. The intersection of a fixed point advances about geometrically (the benchmark's
        N = 100 000, 12 bits: shrinks of 0.64, 0.18, 0.036 per pass over the parts), and so does each task, so
        the expected gain is the task's gain in its last solve times twice the ratio of the intersection's
        last two advances (``advance``: this pass's, per bound), at most that gain; a task solved once may
        gain any amount. Only tightening is at stake: every bound left out stays a valid bound."""
        best = _as_lower_bounds(low, high)
        ratio = np.ones_like(advance)
        if self.advance is not None:
            ratio = np.clip(2.0 * advance / np.maximum(self.advance, 1e-300), 0.0, 1.0)
        self.advance = np.maximum(advance, 0.0)
        solved_twice = np.isfinite(self.before)
        gained = np.where(np.isfinite(self.own), math.inf, 0.0)  # never solved (own -inf): never chosen
        last_gain = np.zeros(self.own.shape)
        last_gain[solved_twice] = self.own[solved_twice] - self.before[solved_twice]
        gained[solved_twice] = (last_gain * ratio)[solved_twice]
        chosen = moving & (self.own > best - margin) & (self.own + gained >= best)
        rows = np.flatnonzero(chosen.any(axis=1))
        return [int(row) for row in rows], [chosen[row] for row in rows]


def _subset(data: _Data, count: int) -> _Data:
    """The problem restricted to the first ``count`` samples."""
    keep_eq = data.times < count
    shared = data.shared
    if shared is not None:
        keep = shared.sample_indices < count
        shared = SharedBacklashConstraints(shared.sample_indices[keep], shared.rising[keep], shared.output_rad[keep],
                                           shared.zeta_bound_rad[keep], shared.rows, shared.rhs, shared.lower,
                                           shared.upper)
    return _Data(data.orders, data.u[:count], data.xc[:count], data.dx[:count], data.times[keep_eq],
                 data.regressors[keep_eq], shared)


class _ExactProblemAtFixedA:
    """The coupled problem with a fixed: z_{i,s} = a_i δx_s is substituted, so the equations
    -psi_t θ + δx_t + Σ_i a_i δx_{t-i} = -x_t^c are linear in (θ, δx) and the LP is the exact feasible set for
    that a (no product columns, no envelope rows: about a third of the relaxation's columns). The matrix is
    built once; each a only rewrites the lag coefficients and the bounds of a."""

    def __init__(self, data: _Data, theta_low: NDArray[np.float64], theta_high: NDArray[np.float64]) -> None:
        orders = data.orders
        na, p = orders.na, orders.num_parameters
        N, m = data.u.size, data.times.size
        width = p + N
        # one row per equation: the p columns of θ, then δx_{t-na} .. δx_{t-1} (value a_i, set per a), then δx_t
        per_row = p + na + 1
        cols = np.empty((m, per_row), dtype=np.int64)
        vals = np.ones((m, per_row))
        cols[:, :p] = np.arange(p)
        vals[:, :p] = -data.regressors
        lag_cols = [p + data.times - i for i in range(1, na + 1)]
        for i in range(1, na + 1):
            cols[:, p + na - i] = lag_cols[i - 1]
        cols[:, p + na] = p + data.times
        A_eq = sp.csr_matrix((vals.ravel(), cols.ravel(), np.arange(m + 1) * per_row), shape=(m, width))
        gain, gain_rhs = _gain_row(orders, width)
        lp = _LP(sp.csr_matrix((0, width)), np.zeros(0), sp.vstack([A_eq, gain]).tocsr(),
                 np.concatenate([-data.xc[data.times], gain_rhs]),
                 np.concatenate([theta_low, -data.dx]), np.concatenate([theta_high, data.dx]))
        if data.shared is not None:
            lp = _with_shared_backlash(lp, data, p)
        lp.A_eq.sort_indices()
        # where each lag coefficient sits in the final matrix's data (rows stay in order under the stacking)
        A = lp.A_eq
        keys = np.repeat(np.arange(A.shape[0], dtype=np.int64), np.diff(A.indptr)) * A.shape[1] + A.indices
        self._lag_positions = [np.searchsorted(keys, np.arange(m, dtype=np.int64) * A.shape[1] + lag_cols[i])
                               for i in range(na)]
        for i in range(na):
            if not np.array_equal(keys[self._lag_positions[i]], np.arange(m) * A.shape[1] + lag_cols[i]):
                raise AssertionError("lag coefficients not found in the exact fixed-a matrix")  # pragma: no cover
        self._a_positions = [np.searchsorted(keys, np.arange(m, dtype=np.int64) * A.shape[1] + i) for i in range(na)]
        for i in range(na):
            if not np.array_equal(keys[self._a_positions[i]], np.arange(m) * A.shape[1] + i):
                raise AssertionError("a coefficients not found in the exact fixed-a matrix")  # pragma: no cover
        self._lp = lp
        self._na = na
        self._times = data.times
        self._p = p
        self._num_samples = N

    def linearized(self, a0: NDArray[np.float64], point: NDArray[np.float64], a_low: NDArray[np.float64],
                   a_high: NDArray[np.float64]) -> _LP:
        """The equations linearised at an exact point (a0, δx0): a_i δx_s ≈ a0_i δx_s + a_i δx0_s - a0_i δx0_s,
        with a free in [a_low, a_high]. Not a relaxation and not exact: it only proposes the next a, which
        :meth:`at` then verifies."""
        lp = self._lp
        dx0 = point[self._p: self._p + self._num_samples]
        values = lp.A_eq.data.copy()
        rhs = lp.b_eq.copy()
        m = self._times.size
        for i in range(self._na):
            lagged = dx0[self._times - (i + 1)]
            values[self._lag_positions[i]] = a0[i]
            values[self._a_positions[i]] += lagged
            rhs[:m] += a0[i] * lagged
        lower, upper = lp.lower.copy(), lp.upper.copy()
        lower[: self._na], upper[: self._na] = a_low, a_high
        A_eq = sp.csr_matrix((values, lp.A_eq.indices, lp.A_eq.indptr), shape=lp.A_eq.shape)
        return _LP(lp.A_ub, lp.b_ub, A_eq, rhs, lower, upper)

    def at(self, fixed_a: NDArray[np.float64]) -> _LP:
        """The exact LP for this a (a's columns fixed by their bounds)."""
        lp = self._lp
        values = lp.A_eq.data.copy()
        for i in range(self._na):
            values[self._lag_positions[i]] = fixed_a[i]
        lower, upper = lp.lower.copy(), lp.upper.copy()
        lower[: self._na] = upper[: self._na] = fixed_a
        A_eq = sp.csr_matrix((values, lp.A_eq.indices, lp.A_eq.indptr), shape=lp.A_eq.shape)
        return _LP(lp.A_ub, lp.b_ub, A_eq, lp.b_eq, lower, upper)


_INNER_BISECTIONS = 5
"""Bisection steps between the last weight whose a admits no exact solution and the first that does."""
_INNER_LOCAL_STEPS = 4
"""Sequential-LP steps from each verified point along the exact set's boundary (:func:`_inner_values`)."""


def _inner_values(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], points: list[NDArray[np.float64]],
                  counter: _Counter, refine: bool = True
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]:
    """Verified values of every parameter, attained by points of the exact feasible set.

    For each bound: fix a at the relaxation's extreme point's a, or, if that a admits no exact solution, at the
    farthest point towards it from an anchor that does (the centre of the box, else the first extreme point's
    a that does; weights 0.95, 0.8, 0.5, 0, then bisection);
    then local steps of a sequential LP: the bilinear terms linearised at the verified point propose a new a
    within a trust region (:meth:`_ExactProblemAtFixedA.linearized`), which counts only once the exactly
    linear problem at that a (in b and δx) has a solution. Every reported value is that of such a solution,
    checked against the equations. Without ``refine`` (long records, where each exact LP spans the whole
    record) only the weights are tried, without bisection and local steps."""
    orders = data.orders
    na, p = orders.na, orders.num_parameters
    inner_low, inner_high = np.full(p, math.nan), np.full(p, math.nan)
    witness = None
    exact = _ExactProblemAtFixedA(data, low, high)
    scale = max(1.0, float(np.max(np.abs(data.xc))))

    def checked(lp: _LP, k: int, direction: float) -> NDArray[np.float64] | None:
        cost = np.zeros(lp.lower.size)
        cost[k] = direction
        try:
            # with a fixed the chained equations are solved best without presolve
            _, x = _Solver(lp, first_solve={"presolve": "off"}).minimize(cost, counter)
        except RuntimeError:
            return None  # a diagnostic only: the outer bounds do not depend on it
        return x

    def verified(fixed_a: NDArray[np.float64], k: int, direction: float) -> NDArray[np.float64] | None:
        lp = exact.at(fixed_a)
        x = checked(lp, k, direction)
        if x is None:
            return None
        # the solver's point satisfies the equations to its tolerance; report it only if it does
        residual = np.max(np.abs(lp.A_eq @ x - lp.b_eq)) if lp.A_eq.shape[0] else 0.0
        return x if residual <= 1e-7 * scale else None

    # the line searches start from an a that admits an exact solution: the centre of the box if it does, else
    # the first extreme point's a that does
    centre = 0.5 * (low[:na] + high[:na])
    candidates = [centre] + [np.clip(point[:na], low[:na], high[:na]) for point in points if point is not None]
    centre = next((candidate for candidate in candidates if verified(candidate, 0, 1.0) is not None), centre)
    for k in range(p):
        for direction, point in ((1.0, points[2 * k]), (-1.0, points[2 * k + 1])):
            if point is None:
                continue
            extreme = np.clip(point[:na], low[:na], high[:na])
            found, last_infeasible = None, None
            for weight in (1.0, 0.95, 0.8, 0.5, 0.0):
                x = verified(centre + weight * (extreme - centre), k, direction)
                if x is not None:
                    found = (weight, x)
                    break
                last_infeasible = weight
            if found is None:
                continue
            weight, best = found
            if refine and last_infeasible is not None:
                inside, outside = weight, last_infeasible
                for _ in range(_INNER_BISECTIONS):
                    middle = 0.5 * (inside + outside)
                    x = verified(centre + middle * (extreme - centre), k, direction)
                    if x is not None:
                        inside, best = middle, x
                    else:
                        outside = middle
            radius = 0.25 * (high[:na] - low[:na])
            for _ in range(_INNER_LOCAL_STEPS if refine else 0):
                a0 = best[:na]
                proposal = checked(exact.linearized(a0, best, np.maximum(low[:na], a0 - radius),
                                                    np.minimum(high[:na], a0 + radius)), k, direction)
                if proposal is None:
                    break
                x = None
                for step in (1.0, 0.5, 0.25):
                    x = verified(a0 + step * (proposal[:na] - a0), k, direction)
                    if x is not None and direction * x[k] < direction * best[k]:
                        break
                    x = None
                if x is None:
                    radius = 0.25 * radius
                    continue
                best = x
            value = float(best[k])
            if direction > 0:
                inner_low[k] = value if math.isnan(inner_low[k]) else min(inner_low[k], value)
            else:
                inner_high[k] = value if math.isnan(inner_high[k]) else max(inner_high[k], value)
            if witness is None:
                witness = best[:p].copy()
    return inner_low, inner_high, witness


def _explain(data: _Data, counter: _Counter) -> EmptyLinearSetExplanation:
    """Smallest extra equation error τ (added to every paper-method inequality) that makes some orthant feasible."""
    best_tau, best_rows = math.inf, np.zeros(0, dtype=int)
    m = data.times.size
    for signs in itertools.product((1, -1), repeat=data.orders.na):
        lp = _orthant_lp(data, signs)
        rows = lp.A_ub.shape[0]
        A = sp.hstack([lp.A_ub, -sp.csr_matrix(np.ones((rows, 1)))]).tocsr()
        cost = np.zeros(lp.lower.size + 1)
        cost[-1] = 1.0
        counter.solves += 1
        result = linprog(cost, A_ub=A, b_ub=lp.b_ub, A_eq=sp.hstack([lp.A_eq, sp.csr_matrix((1, 1))]), b_eq=lp.b_eq,
                         bounds=np.vstack([np.column_stack([lp.lower, lp.upper]), [[0.0, None]]]), method="highs")
        if result.status == 0 and result.fun < best_tau:
            best_tau = float(result.fun)
            marginals = np.abs(result.ineqlin.marginals)
            best_rows = np.flatnonzero(marginals[:m] + marginals[m:] > 1e-9)
    samples = tuple(int(data.times[r]) for r in best_rows)
    if best_tau <= 0.0:
        return EmptyLinearSetExplanation(samples, 0.0, (
            "the equations are consistent one by one (Cerone 1993 bounds) but no single inner-signal sequence "
            "satisfies them all with shared errors; the inner-signal bounds are probably too tight: check the noise "
            "bound, the orders and the delay nk, and that the backlash did not change between the experiments."))
    message = (
        f"no linear block with na={data.orders.na}, nk={data.orders.nk}, nb={data.orders.nb} and unit static gain "
        f"reproduces the inner-signal bounds; the equations at samples {list(samples)} conflict and would need an "
        f"extra error of {best_tau:.3g} rad. Check: the noise bound is too small, the orders or the delay nk are "
        "wrong, the backlash bounds do not hold for the dynamic experiment (different plant state, drift), or the "
        "data are not from the assumed structure."
    )
    return EmptyLinearSetExplanation(samples, best_tau, message)


def bound_linear_block(input_rad: ArrayLike, inner_lower_rad: ArrayLike, inner_upper_rad: ArrayLike, *,
                       na: int, nk: int, nb: int, method: str = "coupled", max_tightening_rounds: int = 6,
                       tightening_tolerance: float = 0.02,
                       shared_backlash: SharedBacklashConstraints | None = None,
                       verify_inner: bool = True, window_samples: int = _WINDOW,
                       joint_samples: int = _JOINT_SAMPLES, partition_samples: int = DEFAULT_PARTITION_SAMPLES,
                       moment_samples: int = DEFAULT_MOMENT_SAMPLES, map_windows: MapFunction | None = None,
                       progress: Progress | None = None) -> LinearBlockBounds:
    """Guaranteed bounds on θ = [a_1..a_na, b_nk..b_nb] with unit static gain (eq. (8)), Section 5.

    Parameters
    ----------
    input_rad
        u_t of the dynamic experiment.
    inner_lower_rad, inner_upper_rad
        x_t^min, x_t^max from :func:`identify.inner_signal_bounds.bound_inner_signal` (eq. (23)); NaN where
        x_t is not bounded (a sample whose output was not measured). An equation of eq. (7) is used only when
        its regressors are complete: the equation at t needs x_t, ..., x_{t-na}, so each missing sample sets
        aside up to na + 1 equations. The bounds hold as before (fewer equations give a set that contains the
        one of all of them), only possibly wider.
    na, nk, nb
        Orders: A = 1 + a_1 q^-1 + ... + a_na q^-na, B = b_nk q^-nk + ... + b_nb q^-nb.
    method
        ``"paper"`` (per-equation errors, Cerone 1993) or ``"coupled"`` (shared errors, McCormick
        relaxation with iterated tightening; never wider than ``"paper"``).
    max_tightening_rounds, tightening_tolerance
        Coupled method: stop after this many rounds or when no interval shrinks by more than this fraction.
    shared_backlash
        Coupled method: tie the inverted samples to one backlash in D_γ instead of letting each sample take
        its own worst case (from :func:`identify.inner_signal_bounds.shared_backlash_constraints`).
    verify_inner
        Coupled method: compute the verified inner values (2p or more extra LPs; about a quarter of the time
        for long records). The outer bounds do not depend on it.
    window_samples, joint_samples
        Coupled method on records longer than two windows: windows of this many samples are bounded one by
        one and their boxes intersected; the final relaxation is solved jointly over all samples if there are
        at most ``joint_samples``, else over the windows that decide the bounds, up to that many samples
        (see :func:`_coupled_bounds`; the time grows about linearly with the record).
    partition_samples
        Coupled method on records up to this length: the final tightening cuts the box of a into cells, each
        bounded by its own relaxation, and takes the hull (spatial branch and bound, :func:`_partitioned_bounds`;
        narrows the outer bounds towards the exact set at a few times the cost). 0 switches it off.
    moment_samples
        Coupled method on records up to this length: a last tightening by the first-order moment (SDP)
        relaxation, solved with cvxpy and certified through LP cuts (:func:`_moment_bounds`). 0 (the default)
        switches it off; it needs cvxpy (``pip install 'gearbox-rig[sdp]'``), else a note says it did not run.
    map_windows
        ``map(function, tasks)`` used for the windows, e.g. ``executor.map`` of a process pool or a Dask
        client's executor; the builtin ``map`` (one process) by default. The tasks and results are plain data.
        HiGHS 1.16 can crash the process solving a bounding LP of a long record (BENCHMARKS.md, "Record
        length"); run in worker processes, a crash costs only their tasks, which are solved again
        (:class:`_GuardedMap`). ``rig identify output-backlash`` does so even with ``--jobs 1``; from Python,
        pass ``executor.map`` of ``rig.batch.executor_for(1, isolated=True)`` for a record of many windows.
    progress
        ``progress(stage, done, total)``, called as windows finish (for long records).
    """
    _check_settings(method, window_samples=window_samples, joint_samples=joint_samples,
                    partition_samples=partition_samples, moment_samples=moment_samples)
    orders = LinearModelOrders(na, nk, nb)
    data = _prepare(input_rad, inner_lower_rad, inner_upper_rad, orders, shared_backlash)
    counter = _Counter()
    names = orders.parameter_names
    low, high, feasible = _paper_bounds(data, counter)
    if not feasible:
        return LinearBlockBounds(method=method, orders=orders, intervals={}, explanation=_explain(data, counter),
                                 num_linear_programs=counter.solves, max_certificate_gap=counter.max_gap)
    rounds = 0
    inner = (None, None, None)
    moment_notes: list[str] = []
    windowing = f"all {data.u.size} samples in one relaxation per orthant"
    if method == "coupled":
        low, high, rounds, points, windowing = _coupled_stages(
            data, low, high, counter, moment_notes, max_tightening_rounds=max_tightening_rounds,
            tightening_tolerance=tightening_tolerance, map_windows=map if map_windows is None else map_windows,
            progress=progress, window_samples=window_samples, joint_samples=joint_samples,
            partition_samples=partition_samples, moment_samples=moment_samples)
        if np.any(np.isnan(low)):
            return LinearBlockBounds(method=method, orders=orders, intervals={}, explanation=_explain(data, counter),
                                     num_linear_programs=counter.solves, num_tightening_rounds=rounds,
                                     feasible_orthants=tuple(feasible), max_certificate_gap=counter.max_gap,
                                     windowing=windowing)
        if verify_inner and any(point is not None for point in points):
            refine = data.u.size <= max(partition_samples, 2 * window_samples)
            verified = _inner_values(data, low, high, points, counter, refine)
            if orders.na and data.u.size <= partition_samples:
                low, high, verified, cells = _closed_relaxation_gap(data, low, high, points, verified, counter,
                                                                    progress)
                if cells:
                    windowing += f", partitioned again, patient, for the gap to the verified values ({cells} solved)"
            inner_low, inner_high, witness = verified
            inner = ({n: float(v) for n, v in zip(names, inner_low)}, {n: float(v) for n, v in zip(names, inner_high)},
                     None if witness is None else {n: float(v) for n, v in zip(names, witness)})
    notes = _fallback_notes(names, counter) + tuple(moment_notes)
    return LinearBlockBounds(method=method, orders=orders, intervals=_intervals_of_box(orders, low, high),
                             inner_lower=inner[0], inner_upper=inner[1], inner_point=inner[2],
                             num_linear_programs=counter.solves, num_tightening_rounds=rounds,
                             feasible_orthants=tuple(feasible), max_certificate_gap=counter.max_gap, notes=notes,
                             windowing=windowing)


def _check_settings(method: str, **sample_counts: int) -> None:
    """Refuse an unknown method or a window, joint, partition or moment length that is no integer above its
    least useful value (20 samples for windows and joint parts, 0 = off for the partition and the moments)."""
    if method not in LINEAR_BOUND_METHODS:
        raise InvalidInputError(f"method: expected one of {', '.join(LINEAR_BOUND_METHODS)}, got {method!r}")
    least = {"window_samples": 20, "joint_samples": 20, "partition_samples": 0, "moment_samples": 0}
    for name, value in sample_counts.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least[name]:
            raise InvalidInputError(f"{name}: expected an integer >= {least[name]}, got {value!r}")


def _coupled_stages(data: _Data, low: NDArray[np.float64], high: NDArray[np.float64], counter: _Counter,
                    moment_notes: list[str], *, max_tightening_rounds: int, tightening_tolerance: float,
                    map_windows: MapFunction, progress: Progress | None, window_samples: int, joint_samples: int,
                    partition_samples: int, moment_samples: int
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], int, list[Any], str]:
    """The coupled method's stages after the paper's bounds: the McCormick relaxation with iterated tightening
    over windows and joint parts (:func:`_coupled_bounds`), then on short records the partition of the box of
    a (:func:`_partitioned_bounds`) and the moment cuts (:func:`_moment_bounds`). Returns the box (NaN where
    the set is empty), the rounds, the feasible points found, and the windowing in words."""
    na = data.orders.na
    low, high, rounds, points, plan = _coupled_bounds(data, low, high, counter, max_tightening_rounds,
                                                      tightening_tolerance, map_windows, progress, window_samples,
                                                      joint_samples)
    windowing = _describe(plan, data.u.size, window_samples, joint_samples)
    if not np.any(np.isnan(low)) and na and data.u.size <= partition_samples:
        low, high, cell_points, cells = _partitioned_bounds(data, low, high, counter, progress=progress)
        points = [new if new is not None else old for new, old in zip(cell_points, points)] if points else cell_points
        windowing += f", then the box of a partitioned into cells ({cells} solved)"
    if not np.any(np.isnan(low)) and na and data.u.size <= moment_samples:
        low, high, sdp_s = _moment_bounds(data, low, high, counter, moment_notes)
        windowing += f", then cuts from the moment (SDP) relaxation ({sdp_s:.1f} s in cvxpy)"
    return low, high, rounds, points, windowing


def _intervals_of_box(orders: LinearModelOrders, low: NDArray[np.float64],
                      high: NDArray[np.float64]) -> dict[str, ParameterInterval]:
    """The box as named intervals; a bound of b at the artificial box ±_B_BOX is reported infinite (no
    information about that coefficient)."""
    intervals = {}
    for k, name in enumerate(orders.parameter_names):
        lo, hi = float(low[k]), float(high[k])
        if k >= orders.na:
            lo = -math.inf if lo <= -_B_BOX * (1 - 1e-9) else lo
            hi = math.inf if hi >= _B_BOX * (1 - 1e-9) else hi
        intervals[name] = ParameterInterval(lo, hi)
    return intervals


def _describe(plan: _WindowPlan, num_samples: int, window: int, joint_samples: int) -> str:
    if len(plan.segments) == 1:
        return f"all {num_samples} samples in one McCormick relaxation"
    joint = (f"then all {num_samples} samples jointly" if plan.all_parts <= 1 else
             f"then {plan.num_parts} of {plan.all_parts} overlapping parts of {joint_samples} samples jointly (those "
             f"holding a deciding window), intersected ({plan.part_passes} pass{'es' if plan.part_passes > 1 else ''}"
             f" of one round each" + (f", the last over the {plan.second_pass_parts} parts near the intersection"
                                      if plan.part_passes > 1 else "") + ")")
    return (f"{len(plan.segments)} windows of {window} samples (overlap {_WINDOW_OVERLAP}), {plan.passes} passes "
            f"of intersected window bounds, {joint}")


def _fallback_notes(names: tuple[str, ...], counter: _Counter) -> tuple[str, ...]:
    """One note per (parameter, side) whose bounding LP HiGHS could not solve at some stage."""
    seen: dict[tuple[int, str], list[str]] = {}
    for k, side, status, stage in counter.fallbacks:
        seen.setdefault((k, side), [])
        if f"{stage} ({status})" not in seen[(k, side)]:
            seen[(k, side)].append(f"{stage} ({status})")
    solver_notes = tuple(
        f"{names[k]} {side} bound: HiGHS could not solve its bounding LP in the {', '.join(where)} after "
        f"the retries ({_RECOVERY_NAMES}); the bound there is the previous valid one, so it may be looser "
        "than the method allows (still guaranteed)" for (k, side), where in sorted(seen.items()))
    lost_notes = tuple(
        f"all parameters: a process running the windows stopped in the {stage} ({reason}); the bounds are the "
        "intersection of the windows and parts solved before that (still guaranteed, possibly looser than the "
        "method allows); rerun with fewer jobs or another joint_samples for the rest"
        for stage, reason in counter.lost_stages)
    return solver_notes + lost_notes
