"""A first-order moment (Shor) relaxation of the coupled linear-block problem, written with cvxpy, used to make
certified cutting planes for the bounding LP.

The coupled feasible set (:mod:`identify.linear_block_bounds`) is bilinear in a_i δx_s. McCormick replaces each
product z_{i,s} = a_i δx_s by its four envelope inequalities over the box of (a_i, δx_s), one product at a
time. The first-order moment relaxation (Shor; Lasserre's hierarchy at order 1, restricted to the cliques of
the products) keeps, for every sample s, the moment matrix of v_s = (1, a_1 .. a_na, δx_s),

    M_s = [[1, a^T, δx_s], [a, A, z_{:,s}], [δx_s, z_{:,s}^T, D_s]]  ⪰ 0,

with A (a stand-in for a a^T) shared by all samples, D_s for δx_s^2 (0 <= D_s <= Δx_s^2) and the McCormick
inequalities of A over the box of a (RLT). On the graph of the products M_s = v_s v_s^T, so the set contains
the exact one; with the McCormick rows of z kept, it is never looser than McCormick, and the shared A ties
the products of different samples to one a (for a near a corner of its box, A - a a^T is small for every s).

Certification. An SDP solver's optimum is only as good as its tolerances, so the SDP value is not used as a
bound. Instead, for any symmetric Z_s ⪰ 0 the inequality <Z_s, M_s> >= 0 holds at every exact point
(v^T Z_s v >= 0): the dual matrices of the PSD constraints at the SDP's optimum are turned into such linear
cuts, made valid for the dual as rounded (its smallest eigenvalue, minus an error bound for the eigenvalue
computation, times the largest |v_s|^2 over the box, is subtracted from the right-hand side), and appended
to the McCormick LP in the lifted variables (θ, δx, z, A, D). That LP is then solved by HiGHS and certified
by the same Neumaier-Shcherbina bound as every other LP (:mod:`identify.linear_block_bounds`). By weak duality
the LP with the cuts of an objective's optimal dual attains that SDP's bound (up to the solver's accuracy),
and whatever the SDP's accuracy, the certified LP bound is a guaranteed outer bound.

The solver is Clarabel (an interior-point conic solver that ``pip install cvxpy`` brings along), else SCS.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

__all__ = ["MomentCuts", "moment_cuts"]

_LOG = logging.getLogger(__name__)

_SOLVERS = ("CLARABEL", "SCS")
"""cvxpy solvers tried in order (both install with cvxpy from PyPI)."""
_EIGEN_ERROR = 64.0 * np.finfo(float).eps
"""Relative error bound (times ||Z||_F) on the smallest eigenvalue computed by LAPACK for a matrix of size <= 8
(backward stable: |λ_computed - λ| <= c n eps ||Z||_2, with a generous c)."""


@dataclass(frozen=True)
class MomentCuts:
    """Linear cuts ``rows @ w <= rhs`` in the lifted columns w = (θ, δx, z, [shared backlash], A, D) of
    :func:`identify.linear_block_bounds.problem._coupled_lp` extended by the moment columns (see
    :func:`moment_cuts`), valid at every point of the exact feasible set inside the box.

    Attributes
    ----------
    rows, rhs
        One row per sample and objective whose SDP was solved.
    solved, failed
        Objectives (index 2k: lower bound of θ_k, 2k + 1: upper bound) whose SDP gave a dual, and those that did
        not (solver status), for the notes.
    sdp_s
        Wall time of the cvxpy compile and the solves, seconds.
    """

    rows: sp.csr_matrix
    rhs: NDArray[np.float64]
    solved: tuple[int, ...]
    failed: tuple[tuple[int, str], ...]
    sdp_s: float


def moment_columns(na: int, num_samples: int) -> int:
    """Number of columns the moment relaxation adds: the na(na+1)/2 entries of A, then D_s per sample."""
    return na * (na + 1) // 2 + num_samples


def _pairs(na: int) -> list[tuple[int, int]]:
    return [(i, j) for i in range(na) for j in range(i, na)]


def moment_rows(na: int, a_low: NDArray[np.float64], a_high: NDArray[np.float64], width: int,
                first: int) -> tuple[sp.csr_matrix, NDArray[np.float64]]:
    """The McCormick (RLT) inequalities of A_ij = a_i a_j over the box of a, as rows over ``width`` columns
    (a_i is column i, A's entries start at column ``first`` in :func:`_pairs` order): rows @ w <= rhs."""
    rows, rhs = [], []
    for index, (i, j) in enumerate(_pairs(na)):
        li, ui, lj, uj = a_low[i], a_high[i], a_low[j], a_high[j]
        column = first + index
        # A >= lj a_i + li a_j - li lj ; A >= uj a_i + ui a_j - ui uj ; A <= uj a_i + li a_j - li uj ; A <= lj a_i + ui a_j - ui lj
        for ci, cj, sign, constant in ((lj, li, 1.0, li * lj), (uj, ui, 1.0, ui * uj), (uj, li, -1.0, li * uj),
                                       (lj, ui, -1.0, ui * lj)):
            row = np.zeros(width)
            row[i] += sign * ci
            row[j] += sign * cj
            row[column] -= sign
            rows.append(row)
            rhs.append(sign * constant)
    return sp.csr_matrix(np.array(rows).reshape(-1, width)), np.array(rhs)


def moment_cuts(*, na: int, p: int, num_samples: int, equations: sp.csr_matrix, equation_rhs: NDArray[np.float64],
                inequalities: sp.csr_matrix, inequality_rhs: NDArray[np.float64], lower: NDArray[np.float64],
                upper: NDArray[np.float64], objectives: list[int], delta_bound_rad: NDArray[np.float64]) -> MomentCuts:
    """Solve the moment SDP for each objective (index 2k: min θ_k, 2k + 1: max θ_k) and turn the duals of its
    PSD constraints into cuts.

    ``equations``/``inequalities`` (with right-hand sides) and the column box ``lower``/``upper`` are the lifted
    LP (McCormick rows, equations, shared backlash, RLT rows of A) over columns (θ (p), δx (N), z (na·N),
    other columns, A, D); δx_s is column p + s, z_{i,s} column p + N + i·N + s, A and D the last
    :func:`moment_columns` columns. Returns the cuts (rows over the same columns); an objective whose SDP
    fails gives no cuts and is listed in ``failed``."""
    import cvxpy as cp

    started = time.perf_counter()
    N = num_samples
    width = lower.size
    first_a2 = width - moment_columns(na, N)
    first_d = first_a2 + na * (na + 1) // 2
    w = cp.Variable(width)
    cost = cp.Parameter(width)
    constraints = [equations @ w == equation_rhs, inequalities @ w <= inequality_rhs, w >= lower, w <= upper]
    # the moment matrices, one per sample, stacked as an affine map of w: entry (r, c) of M_s
    size = na + 2
    blocks = []
    for s in range(N):
        index = np.full((size, size), -1, dtype=np.int64)
        for i in range(na):
            index[0, 1 + i] = index[1 + i, 0] = i
            index[1 + i, na + 1] = index[na + 1, 1 + i] = p + N + i * N + s
        for k, (i, j) in enumerate(_pairs(na)):
            index[1 + i, 1 + j] = index[1 + j, 1 + i] = first_a2 + k
        index[0, na + 1] = index[na + 1, 0] = p + s
        index[na + 1, na + 1] = first_d + s
        blocks.append(index)
    positions = np.array(blocks)  # (N, size, size); -1 at (0, 0), the constant 1
    flat = positions.reshape(N, -1)
    selector_rows, selector_cols = np.nonzero(flat >= 0)
    selector = sp.csr_matrix((np.ones(selector_rows.size), (selector_rows * size * size + selector_cols,
                                                             flat[selector_rows, selector_cols])),
                             shape=(N * size * size, width))
    constant = np.zeros(N * size * size)
    constant[np.arange(N) * size * size] = 1.0
    stacked = selector @ w + constant
    psd = [cp.reshape(stacked[s * size * size:(s + 1) * size * size], (size, size), order="C") >> 0 for s in range(N)]
    problem = cp.Problem(cp.Minimize(cost @ w), constraints + psd)
    cut_rows, cut_cols, cut_vals, rhs, solved, failed = [], [], [], [], [], []
    radius_sq = 1.0 + float(np.sum(np.maximum(lower[:na] ** 2, upper[:na] ** 2))) + delta_bound_rad ** 2
    for objective in objectives:
        k, side = divmod(objective, 2)
        vector = np.zeros(width)
        vector[k] = -1.0 if side else 1.0
        cost.value = vector
        status = "not run"
        for solver in _SOLVERS:
            if solver not in cp.installed_solvers():
                continue
            try:
                with warnings.catch_warnings():
                    # "Solution may be inaccurate": any dual gives valid cuts, and the LP certifies the bound
                    warnings.simplefilter("ignore", UserWarning)
                    problem.solve(solver=solver)
                status = str(problem.status)
            except cp.error.SolverError as error:
                status = f"{solver}: {error}"
                continue
            if problem.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) and psd[0].dual_value is not None:
                break
        else:
            failed.append((objective, status))
            continue
        for s, constraint in enumerate(psd):
            Z = np.asarray(constraint.dual_value, dtype=float)
            Z = 0.5 * (Z + Z.T)
            values, vectors = np.linalg.eigh(Z)
            Z = (vectors * np.maximum(values, 0.0)) @ vectors.T  # the nearest PSD matrix, up to rounding
            Z = 0.5 * (Z + Z.T)
            norm = float(np.linalg.norm(Z))
            if norm == 0.0:
                continue
            Z = Z / norm  # scale-free cut
            smallest = float(np.linalg.eigvalsh(Z)[0]) - _EIGEN_ERROR * size
            # <Z, M_s> >= min(0, λ_min(Z)) |v_s|^2 at every exact point (v^T Z v >= λ_min |v|^2); as a row:
            # -(Σ_{(r,c) != (0,0)} Z_rc M_rc) <= Z_00 - min(0, λ_min) |v_s|^2_max
            index = positions[s]
            keep = index >= 0
            margin = -min(0.0, smallest) * float(radius_sq[s])
            cut_cols.append(index[keep])
            cut_vals.append(-Z[keep])  # (r, c) and (c, r) add up to -2 Z_rc exactly in the sparse sum
            cut_rows.append(np.full(int(np.count_nonzero(keep)), len(rhs)))
            rhs.append((Z[0, 0] + margin) * (1.0 + 1e-14) + 1e-15)
        solved.append(objective)
    sdp_s = time.perf_counter() - started
    _LOG.debug("moment relaxation: %d SDPs in %.2f s (%d failed)", len(objectives), sdp_s, len(failed))
    matrix = (sp.csr_matrix((np.concatenate(cut_vals), (np.concatenate(cut_rows), np.concatenate(cut_cols))),
                            shape=(len(rhs), width)) if rhs else sp.csr_matrix((0, width)))
    return MomentCuts(matrix, np.array(rhs, dtype=float), tuple(solved), tuple(failed), sdp_s)


def available() -> str | None:
    """None if cvxpy and a solver it can use here are installed, else what to install."""
    try:
        import cvxpy as cp
    except ImportError:
        return "cvxpy is not installed (pip install 'gearbox-rig[sdp]' or pip install cvxpy)"
    if not any(solver in cp.installed_solvers() for solver in _SOLVERS):
        return f"cvxpy has none of the solvers {', '.join(_SOLVERS)} (pip install clarabel)"
    return None

