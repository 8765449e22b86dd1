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
each new a counting only once the exact problem at it is solved: :func:`~.inner_values._inner_values`).

A record with few gaps (:func:`~.trajectory_lp.eliminates_inner_signal`) is bounded with the inner signal
eliminated (:mod:`~.trajectory_lp`; ``eliminate_inner_signal``, the default): with a fixed, the equations make x an
affine function of b and of the na values that start each chain of equations, x = M(a)[b; s], so the exact problem
at fixed a is an LP of p + 4 + na columns and one row per sample. Over a box of a, with a^c its centre, every point
of the set satisfies M(a^c)[b; s] + Σ_i (a_i - a^c_i) φ_i within its intervals widened by E_t = Σ_k |h_k| Σ_i r_i
Δx_{t-k-i} (h: the impulse response of 1/A(a^c); φ_i: the response to the lagged centres x^c): the trajectory
relaxation (:func:`~.trajectory_lp._trajectory_relaxation`), as tight as the interval relaxation with δx as
columns over all samples and solved by row generation in a time linear in N. Its rounds from the paper method's box
replace the windows and parts below; then the box of a is partitioned into cells at every record length, and
again while the verified inner values show a gap above ``RELAXATION_GAP_TARGET``. The inner values solve the same
exact LP at fixed a, and a value counts only once the exact O(N) check of its point (:mod:`~.point_check`: θ and
the backlash fixed, the set of the last na inner-signal values carried forward sample by sample, a witness corrected
exactly) accepts it.

Otherwise (``eliminate_inner_signal=False``, or many gaps), for records longer than two windows (400 samples) the
work goes window by window, so that it grows about
linearly with the record (:func:`~.windows._coupled_bounds`). The feasible set of any subset of the
equations contains the full one, so every window's bounds are valid. The box of a is first tightened on the
first 200 samples (McCormick); the box of a is then narrow, and the later LPs use a smaller relaxation that is
tight for a narrow box (:func:`~.problem._interval_lp`: a_i δx_s = a_i^c δx_s + e, |e| <= r_i Δx_s, without product
columns or envelope rows). Every 200-sample window (consecutive ones share 20 samples) is bounded, the boxes
are intersected and fed back into every window's relaxation until they stop shrinking; the windows are
independent tasks for ``map_windows`` (a process pool's or a Dask client's ``executor.map``). The final rounds
solve the relaxation jointly over all samples when there are at most ``joint_samples`` (3000): the all-data
relaxation, from a box inside the one it started from before, and never wider. Longer records are solved
jointly in overlapping parts of ``joint_samples`` samples, one round each, whose boxes are intersected and fed
back for further passes over the parts (a fixed point like the windows'): about linear in N, but
wider than one relaxation over everything would be (bounded-error information is spread over the record).
After the first pass, a pass over the windows or parts solves, per task, only the bounds still moving that the
task may still decide (:class:`~.windows._TaskBounds`); the paper method's orthant LPs of such records are solved by row
generation (:func:`~.problem._row_generated_bounds`), so that the windows start within about a second.
Within one LP, the bounds of the parameters are solved on one HiGHS model whose objective changes, each
solve starting from the previous optimal basis.

Without the trajectory relaxation, records up to ``partition_samples`` (1000) get a final tightening by spatial
branch and bound on the box of
a (:func:`~.final_tightening._partitioned_bounds`): the box is cut into cells, each bounded by its own interval
relaxation, and the hull of the cells is the bound; the cells that decide a bound are halved again. One relaxation over
the whole box left up to half of the reported width to the relaxation at 8 bits; the cells bring the
outer bounds to within about 5-10 % of the verified inner values.

Records up to ``moment_samples`` (0 by default: off) get a last tightening by the first-order moment (SDP)
relaxation of the bilinear terms (:func:`~.final_tightening._moment_bounds`, :mod:`identify.moment_relaxation`, with
cvxpy): the duals of its PSD constraints become cuts of the lifted McCormick LP, whose bound HiGHS certifies as every
other LP's. On the paper's example it narrows the bounds by under 1 % at about twice the cost (BENCHMARKS.md).

A window or part whose worker process dies (a segfault inside the solver, the out-of-memory killer; a process
pool's ``BrokenProcessPool``, Dask's ``KilledWorker``) is not a traceback either: the bounds are those of the
windows and parts that finished (:class:`~.windows._GuardedMap`), with a note.

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

from collections.abc import Callable, Iterable
from typing import Any

# The public defaults and callable types come first: the modules below import them from here.

DEFAULT_PARTITION_SAMPLES = 1000
"""Records up to this length get the final tightening by partition of the box of a
(:func:`~.final_tightening._partitioned_bounds`)."""
DEFAULT_MOMENT_SAMPLES = 0
"""Records up to this length get the moment (SDP) cuts as a last tightening (:func:`~.final_tightening._moment_bounds`);
off by default."""

MapFunction = Callable[..., Iterable[Any]]
"""``map(function, tasks)``: the builtin, or ``Executor.map`` to run the windows in other processes."""
Progress = Callable[[str, int, int], None]
"""``progress(stage, done, total)``, called as windows finish."""


from identify.linear_block_bounds.certified_lp import RETRY_SETTINGS  # noqa: E402
from identify.linear_block_bounds.final_tightening import RELAXATION_GAP_TARGET  # noqa: E402
from identify.linear_block_bounds.pipeline import LINEAR_BOUND_METHODS, bound_linear_block  # noqa: E402
from identify.linear_block_bounds.problem import LinearModelOrders, SharedBacklashConstraints  # noqa: E402
from identify.linear_block_bounds.result import EmptyLinearSetExplanation, LinearBlockBounds  # noqa: E402
from identify.linear_block_bounds.trajectory_lp import eliminates_inner_signal  # noqa: E402
from identify.linear_block_bounds.windows import DEFAULT_JOINT_SAMPLES, DEFAULT_WINDOW_SAMPLES  # noqa: E402

__all__ = ["DEFAULT_JOINT_SAMPLES", "DEFAULT_MOMENT_SAMPLES", "DEFAULT_PARTITION_SAMPLES", "DEFAULT_WINDOW_SAMPLES", "LINEAR_BOUND_METHODS", "EmptyLinearSetExplanation", "LinearBlockBounds", "LinearModelOrders", "MapFunction",
           "Progress", "SharedBacklashConstraints", "bound_linear_block", "eliminates_inner_signal"]
