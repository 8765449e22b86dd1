"""Subspace identification of a Hammerstein system with input backlash or switch (Pouliquen et al., CDC 2013).

One experiment with the cyclic excitation of Table I (:mod:`identify.cyclic_excitation`) and one subspace
step give both a state-space model (A, B, C, D) of the linear part G(q) and nonparametric (piecewise-linear)
ascending and descending borders of the nonlinearity:

1. lift the input: z(t) with H[u(t)] = μ0 + μ z(t) (eq. (4), :mod:`identify.border_lifting`); μ0 is the
   output mean over a leading hold at u_min (Section III) or given;
2. PI-MOESP on (z, y - μ0) (eqs. (8)-(13)): an LQ factorisation of the stacked block-Hankel matrices
   [Z_f; Z_p; Y_f] gives the projection O_f of eq. (11) as L32 Q2; its left singular vectors span Γ_f.
   The L factor is the Cholesky factor of the Gram matrix of the input rows, which the Hankel structure
   gives in O((p+f) m^2 N), so no j × j projection and no explicit inverse is formed
   (:func:`pi_moesp_observability`; the tests hold a Householder QR reference);
3. the order n from the largest gap between consecutive singular values (or given);
4. A and C from the shift invariance of Γ_f (step 1 of Section III);
5. bold B = B μ and bold D = D μ by linear least squares on the output with the initial state (step 2);
6. the rank-1 split of [bold D; bold B] (eq. (14)) and the unit static gain G(1) = 1 (assumption A.2).

Beyond the paper:

* ``split="separate"`` is the variant of Remark 5: with A and C fixed, B, D and μ are estimated
  separately by alternating least squares on the output error, which enforces the rank-1 structure that the
  over-parameterised fit of step 5 ignores;
* the output offset μ0 is re-estimated jointly with B and D (a constant regressor), so a short or noisy
  hold costs little; ``estimate_offset=False`` keeps the paper's hold mean;
* ``refine=True`` minimises the output error of the whole Hammerstein model (transfer-function parameters,
  node slopes, offset and initial state) with :func:`scipy.optimize.least_squares`, starting from the
  subspace estimate.

Limitations: assumption A.1 (both paths start at μ0 = H[u_min]) is required: with Table I the direction
signal δ(t) is 4-periodic, so a separate start offset of the ascending path would not be persistently
exciting. G must have a finite non-zero static gain (A.2); a pure integrator cannot be normalised.

Example
-------
>>> import numpy as np
>>> from identify.cyclic_excitation import cyclic_random_excitation
>>> from identify.border_lifting import PathNodes
>>> from identify.plant_blocks import LinearBlock, PlantModel, pouliquen2013_backlash
>>> u = cyclic_random_excitation(3000, -3.0, 3.0, hold_samples=50, rng=0)
>>> G = LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=1.0)
>>> y = PlantModel((pouliquen2013_backlash(), G)).simulate(u)
>>> model = identify_hammerstein(u, y, PathNodes.uniform(-3.0, 3.0, 8), hold_samples=50)
>>> model.order, np.round(np.sort_complex(model.poles), 4).tolist()
(2, [(0.9429-0.1255j), (0.9429+0.1255j)])
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.signal
from numpy.typing import ArrayLike, NDArray

from identify.border_lifting import PathNodes, check_cyclic_input, lifted_input
from identify.hammerstein_model import HammersteinModel, NodePlay, RefinementReport, _state_space_to_tf
from identify.validation import (InvalidInputError, as_signal, renamed_parameters, same_length, varying,
                                 with_options)

__all__ = [
    "HammersteinModel",
    "HammersteinOptions",
    "NodePlay",
    "RefinementReport",
    "complete_windows",
    "identify_hammerstein",
    "pi_moesp_observability",
    "select_order",
]

logger = logging.getLogger(__name__)

DEFAULT_FUTURE_HORIZON = 15
DEFAULT_PAST_HORIZON = 15


# ----------------------------------------------------------------------------------------------------------
# PI-MOESP, eqs. (8)-(13)
# ----------------------------------------------------------------------------------------------------------


_GRAM_CHUNK = 4096


def _hankel_gram(w: NDArray[np.float64], num_blocks: int, num_columns: int) -> NDArray[np.float64]:
    """H^T H for the transposed block-Hankel H whose row t is [w(t), ..., w(t + num_blocks - 1)], t < num_columns,
    in O(s M^2 j).

    Block (b1, b2) is Σ_{t<j} w(t + b1) w(t + b2)^T. Along a diagonal b2 - b1 = d it changes only by the
    samples that enter and leave the window, so one lag product per d plus a running sum of s rank-one
    corrections gives every block without forming the j × s M matrix product.
    """
    s, j = num_blocks, num_columns
    M = w.shape[1]
    base = np.zeros((s, M, M))                                           # (d, M, M): Σ_t w(t) w(t + d)^T
    for start in range(0, j, _GRAM_CHUNK):                               # chunks that stay in cache
        stop = min(start + _GRAM_CHUNK, j)
        head = w[start:stop].T
        for d in range(s):
            base[d] += head @ w[start + d : stop + d]
    # corrections[d, b] = Σ_{l<b} w(j + l) w(j + l + d)^T - w(l) w(l + d)^T, for b + d < s
    # (only l + d <= s - 2 is used; the zero padding fills the rest of the windows)
    early = np.vstack((w[: 2 * s - 1], np.zeros((2 * s, M))))[: 2 * s - 1]
    late = np.vstack((w[j:], np.zeros((2 * s, M))))[: 2 * s - 1]
    lead = np.lib.stride_tricks.sliding_window_view(early, s, axis=0)    # (l, M, d): w(l + d)
    tail = np.lib.stride_tricks.sliding_window_view(late, s, axis=0)     # w(j + l + d)
    steps = np.einsum("li,lkd->dlik", late[:s], tail) - np.einsum("li,lkd->dlik", early[:s], lead)
    before = np.tri(s, s, -1)                                            # [b, l] = 1 for l < b
    corrections = (before @ steps.reshape(s, s, M * M)).reshape(s, s, M, M)
    b1, d = np.nonzero(np.arange(s)[:, None] + np.arange(s)[None, :] < s)
    blocks = base[d] + corrections[d, b1]
    gram = np.empty((s, M, s, M))
    gram[b1, :, b1 + d, :] = blocks
    gram[b1 + d, :, b1, :] = blocks.transpose(0, 2, 1)
    return gram.reshape(s * M, s * M)


def pi_moesp_observability(
    inputs: ArrayLike, output_rad: ArrayLike, past_horizon: int, future_horizon: int, *, remove_offset: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Left singular vectors and singular values of the PI-MOESP projection O_f of eq. (11).

    With the LQ factorisation [Z_f; Z_p; Y_f] = L Q (no explicit inverse), O_f = Y_f Φ^T (Φ Φ^T)^-1 Φ
    Π_{Z_f}^⊥ = L32 Q2, so the SVD of the small block L32 (f × p m) gives the U_1 and S_1 of eq. (12).
    The L factor of the input rows is the Cholesky factor of their Gram matrix, which the Hankel structure
    gives in O((p+f) m^2 N) operations (:func:`_hankel_gram`), and the output rows follow by triangular
    solves (the tests compare it with a Householder QR of the stacked j × ((p+f) m + f) matrix).

    Parameters
    ----------
    inputs
        The inputs z, shape (N, m) (the lifted input of eq. (4)) or (N,).
    output_rad
        The output y, shape (N,); NaN marks a sample not measured. Column t of the block-Hankel matrices is
        the window of p + f samples from t, and each window satisfies eq. (8) with its own state, so the
        windows that hold a missing sample are left out (:func:`complete_windows`) and the others used as they
        are.
    past_horizon, future_horizon
        p and f.
    remove_offset
        Project out a constant as well as Z_f (equivalently, centre every Hankel row), so that a constant
        output offset, such as an error in μ0, does not appear as an extra state.

    Returns
    -------
    U, singular_values, input_diagonal
        U (f, f) left singular vectors, the singular values (largest first), and |diag| of the input part of
        L (a zero there means the input is not persistently exciting of order p + f).
    """
    inputs = np.asarray(inputs, dtype=float)
    if inputs.ndim == 1:
        inputs = inputs[:, None]
    outputs = np.asarray(output_rad, dtype=float).reshape(-1, 1)
    p, f = int(past_horizon), int(future_horizon)
    m = inputs.shape[1]
    j = inputs.shape[0] - p - f + 1
    a, b = f * m, (f + p) * m
    s, M = p + f, m + 1
    w = np.hstack((inputs, outputs))
    if np.any(np.isnan(outputs)):
        # the complete windows only, as rows of the explicit (transposed) block-Hankel matrix
        windows = np.flatnonzero(complete_windows(outputs[:, 0], s))
        hankel = np.lib.stride_tricks.sliding_window_view(w, s, axis=0)[windows].transpose(0, 2, 1).reshape(-1, s * M)
        gram = hankel.T @ hankel
        if remove_offset:
            sums = hankel.sum(axis=0)
            gram -= np.outer(sums, sums) / max(windows.size, 1)
    else:
        gram = _hankel_gram(w, s, j)
        if remove_offset:
            # row sums of the Hankel matrix: Σ_{t<j} w(t + b), from one cumulative sum
            cumulative = np.vstack((np.zeros((1, M)), np.cumsum(w, axis=0)))
            sums = (cumulative[j : j + s] - cumulative[:s]).ravel()
            gram -= np.outer(sums, sums) / j
    index = np.arange(s * M).reshape(s, M)
    order = np.concatenate((index[p:, :m].ravel(), index[:p, :m].ravel(), index[p:, m]))
    gram = gram[np.ix_(order, order)]
    try:
        R_in = scipy.linalg.cholesky(gram[:b, :b], lower=False, check_finite=False)
    except np.linalg.LinAlgError:
        return np.eye(f), np.zeros(min(f, p * m)), np.zeros(b)
    R_out = scipy.linalg.solve_triangular(R_in, gram[:b, b:], trans="T", check_finite=False)
    L32 = R_out[a:b].T
    input_diagonal = np.abs(np.diag(R_in))
    U, singular_values, _ = scipy.linalg.svd(L32, full_matrices=True, check_finite=False)
    return U, singular_values, input_diagonal


def complete_windows(output_rad: NDArray[np.float64], window_samples: int) -> NDArray[np.bool_]:
    """For each t = 0..N - ``window_samples``, whether the window of samples t .. t + window_samples - 1 holds
    no missing (NaN) output: the columns of the block-Hankel matrices of eq. (8) that can be used."""
    missing = np.concatenate(([0], np.cumsum(np.isnan(output_rad))))
    return (missing[window_samples:] - missing[: missing.size - window_samples]) == 0


def select_order(singular_values: ArrayLike, max_order: int) -> int:
    """The n in 1..max_order with the largest ratio s_n / s_{n+1} of consecutive singular values (eq. (12))."""
    s = np.asarray(singular_values, dtype=float)
    top = min(int(max_order), s.size - 1)
    if top < 1:
        raise InvalidInputError(f"max_order: need at least two singular values to choose an order, got {s.size}")
    floor = np.finfo(float).tiny
    ratios = s[:top] / np.maximum(s[1 : top + 1], floor)
    return int(np.argmax(ratios)) + 1


# ----------------------------------------------------------------------------------------------------------
# B, D and μ with A, C known
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Regressors:
    """The output as a linear function of θ = [vec bold B, bold D, x0, offset] (step 2 of Section III).

    y(t) = Σ_i Σ_k bold B[i,k] F_i[t,k] + Σ_k bold D[k] z_k(t) + (C A^t) x0 + offset, where F_i is the
    response of C (qI - A)^-1 e_i to each lifted input. The regressor matrix Ψ (N × K, K = n m + m + n + 1)
    is reduced once by a QR factorisation, Ψ = Q R; every later least-squares problem whose parameters map
    linearly into θ = T ϑ is then solved on the K-row system R T ϑ ≈ Q^T y.
    """

    R: NDArray[np.float64]          # (K, K)
    qty: NDArray[np.float64]        # (K,)
    residual_floor: float           # |y|^2 - |Q^T y|^2: the part of y outside the span of Ψ
    O: NDArray[np.float64]          # (N, n): C A^t, for the free response
    keep: NDArray[np.bool_]         # which entries of θ are estimated (D and the offset may be fixed at 0)
    n: int
    m: int
    feedthrough: bool
    offset: bool

    @property
    def num_nuisance(self) -> int:
        return self.n + int(self.offset)

    def solve(self, T: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
        """argmin_ϑ |y - Ψ T ϑ|^2 and the minimum."""
        design = self.R @ T
        theta = _lstsq(design, self.qty)
        cost = float(np.sum((self.qty - design @ theta) ** 2)) + self.residual_floor
        return theta, cost

    def _nuisance_map(self, T: NDArray[np.float64], first_column: int) -> None:
        n, m = self.n, self.m
        T[n * m + m : n * m + m + n, first_column : first_column + n] = np.eye(n)
        if self.offset:
            T[-1, first_column + n] = 1.0

    def map_for_fixed_mu(self, mu: NDArray[np.float64]) -> NDArray[np.float64]:
        """T with θ = T [B, D, x0, offset] for fixed μ: bold B = B μ, bold D = D μ."""
        n, m, k = self.n, self.m, self.num_nuisance
        T = np.zeros((n * m + m + n + 1, n + 1 + k))
        T[: n * m, :n] = np.kron(np.eye(n), mu[:, None])
        T[n * m : n * m + m, n] = mu if self.feedthrough else 0.0
        self._nuisance_map(T, n + 1)
        return T

    def map_for_fixed_gain(self, B: NDArray[np.float64], D: float) -> NDArray[np.float64]:
        """T with θ = T [μ, x0, offset] for fixed B, D."""
        n, m, k = self.n, self.m, self.num_nuisance
        T = np.zeros((n * m + m + n + 1, m + k))
        T[: n * m, :m] = np.kron(B[:, None], np.eye(m))
        T[n * m : n * m + m, :m] = D * np.eye(m)
        self._nuisance_map(T, m)
        return T


def _regressors(A: NDArray[np.float64], C: NDArray[np.float64], z: NDArray[np.float64], y: NDArray[np.float64],
                feedthrough: bool, offset: bool) -> _Regressors:
    n = A.shape[0]
    N, m = z.shape
    denominator = np.poly(A)
    columns = np.empty((N, n * m + m + n + 1))
    impulse = np.zeros(N + 1)
    impulse[0] = 1.0
    for i in range(n):
        numerator, _ = scipy.signal.ss2tf(A, np.eye(n)[:, i : i + 1], C.reshape(1, n), np.zeros((1, 1)))
        numerator = np.squeeze(numerator)
        columns[:, i * m : (i + 1) * m] = scipy.signal.lfilter(numerator, denominator, z, axis=0)
        columns[:, n * m + m + i] = scipy.signal.lfilter(numerator, denominator, impulse)[1:]  # C A^t e_i
    columns[:, n * m : n * m + m] = z if feedthrough else 0.0
    columns[:, -1] = 1.0 if offset else 0.0
    O = columns[:, n * m + m : n * m + m + n].copy()
    keep = np.ones(columns.shape[1], dtype=bool)
    if not feedthrough:
        keep[n * m : n * m + m] = False
    if not offset:
        keep[-1] = False
    # QR of [Ψ, y]: R gives Ψ's factor, its last column Q^T y, and its last diagonal entry |y - Ψ θ_LS|.
    # The regressors are filtered inputs, known at every sample: a row with a missing output is left out.
    measured = ~np.isnan(y)
    augmented = np.column_stack((columns[:, keep], y))[measured]
    k = augmented.shape[1] - 1
    R_aug = np.triu(scipy.linalg.lapack.dgeqrf(augmented, overwrite_a=True)[0][: k + 1])
    R, qty = R_aug[:k, :k], R_aug[:k, k]
    # expand R back to the full θ layout with zero columns for fixed-at-zero parameters
    R_full = np.zeros((k, columns.shape[1]))
    R_full[:, keep] = R
    floor = float(R_aug[k, k] ** 2)
    return _Regressors(R_full, qty, floor, O, keep, n, m, feedthrough, offset)


def _lstsq(matrix: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    return scipy.linalg.lstsq(matrix, target, check_finite=False, lapack_driver="gelsy")[0]


def _overparameterised_fit(reg: _Regressors) -> tuple[NDArray, NDArray, NDArray]:
    """Step 2 of Section III: bold B (n, m), bold D (m,) and the nuisance (x0, offset) by least squares."""
    n, m = reg.n, reg.m
    selection = np.eye(reg.keep.size)[:, reg.keep]
    theta = selection @ reg.solve(selection)[0]
    return theta[: n * m].reshape(n, m), theta[n * m : n * m + m], _nuisance(reg, theta[n * m + m :])


def _nuisance(reg: _Regressors, tail: NDArray[np.float64]) -> NDArray[np.float64]:
    """[x0, offset] (offset 0 when it is not estimated)."""
    return np.concatenate((tail[: reg.n], [tail[reg.n] if reg.offset else 0.0]))


def _rank_one_split(bold_B: NDArray, bold_D: NDArray, feedthrough: bool) -> tuple[NDArray, float, NDArray]:
    """Eq. (14): the dominant singular triple of [bold D; bold B] = [D; B] μ (bold B alone without D)."""
    stacked = np.vstack((bold_D[None, :], bold_B)) if feedthrough else bold_B
    U, s, Vt = np.linalg.svd(stacked, full_matrices=False)
    column = U[:, 0] * s[0]
    if feedthrough:
        return column[1:], float(column[0]), Vt[0].copy()
    return column, 0.0, Vt[0].copy()


def _separate_fit(reg: _Regressors, mu: NDArray[np.float64], max_iterations: int = 500,
                  tolerance: float = 1e-13) -> tuple[NDArray, float, NDArray, NDArray]:
    """Remark 5: B, D and μ estimated separately with A, C fixed, by alternating least squares.

    y(t) = Σ_i B_i (F_i(t) μ) + D (z(t) μ) + nuisance is linear in (B, D) for fixed μ and in μ for fixed
    (B, D); no half-step can increase the residual, and the result satisfies bold B = B μ exactly instead
    of truncating an unstructured estimate (eq. (14)). Each half-step is a small problem on the QR-reduced
    regressors (:class:`_Regressors`).
    """
    n, m = reg.n, reg.m
    previous = np.inf
    B, D = np.zeros(n), 0.0
    tail = np.zeros(reg.num_nuisance)
    for _ in range(max_iterations):
        theta, _ = reg.solve(reg.map_for_fixed_mu(mu))
        B, D = theta[:n], float(theta[n]) if reg.feedthrough else 0.0
        theta, cost = reg.solve(reg.map_for_fixed_gain(B, D))
        mu, tail = theta[:m], theta[m:]
        scale = np.linalg.norm(mu)  # keep the bilinear factors balanced
        mu, B, D = mu / scale, B * scale, D * scale
        if previous - cost <= tolerance * max(previous, np.finfo(float).tiny):
            break
        previous = cost
    return B, D, mu, _nuisance(reg, tail)


# ----------------------------------------------------------------------------------------------------------
# Output-error refinement (beyond the paper)
# ----------------------------------------------------------------------------------------------------------


def _refine(z: NDArray, y: NDArray, numerator: NDArray, denominator: NDArray, mu: NDArray, mu0: float,
            free_response: NDArray, feedthrough: bool
            ) -> tuple[NDArray, NDArray, NDArray, float, NDArray, RefinementReport]:
    """Minimise Σ (y - μ0 - G(q) μ z)^2 over G (unit static gain), μ, μ0 and the initial filter state.

    G = b(q^-1)/a(q^-1) with a = [1, a_1..a_n]; the last numerator coefficient is eliminated by
    G(1) = Σb / (1 + Σa) = 1 (A.2), which also removes the scale ambiguity between G and μ.
    """
    n = len(denominator) - 1
    b = np.zeros(n + 1)
    b[: len(numerator)] = numerator[-(n + 1):] if len(numerator) > n + 1 else numerator
    first_b = 0 if feedthrough else 1
    m = z.shape[1]
    # initial lfilter state (direct form II transposed) reproducing the subspace model's free response
    probe = np.zeros(2 * n)
    free = np.column_stack([scipy.signal.lfilter(b, denominator, probe, zi=np.eye(n)[k])[0] for k in range(n)])
    zi0 = _lstsq(free, free_response[: 2 * n])
    measured = ~np.isnan(y)

    def unpack(params: NDArray) -> tuple[NDArray, NDArray, NDArray, float, NDArray]:
        a = np.concatenate(([1.0], params[:n]))
        b_free = params[n : 2 * n - first_b]
        b_full = np.zeros(n + 1)
        b_full[first_b:n] = b_free
        b_full[n] = a.sum() - b_free.sum()
        offset = 2 * n - first_b
        return a, b_full, params[offset : offset + m], float(params[offset + m]), params[offset + m + 1 :]

    def residual(params: NDArray) -> NDArray:
        a, b_full, mu_k, mu0_k, zi = unpack(params)
        with np.errstate(all="ignore"):
            model = mu0_k + scipy.signal.lfilter(b_full, a, z @ mu_k, zi=zi)[0]
        r = np.where(measured, y - model, 0.0)  # a missing output costs nothing
        return np.where(np.isfinite(r), r, 1e6)

    start = np.concatenate((denominator[1:], b[first_b:n], mu, [mu0], zi0))
    before = residual(start)
    solution = scipy.optimize.least_squares(residual, start, method="trf", x_scale="jac")
    a, b_full, mu_new, mu0_new, zi = unpack(solution.x)
    rms_before_rad = float(np.sqrt(np.mean(before[measured] ** 2)))
    rms_after_rad = float(np.sqrt(np.mean(solution.fun[measured] ** 2)))
    applied = rms_after_rad < rms_before_rad and bool(np.all(np.abs(np.roots(a)) < 1.0))
    report = RefinementReport(
        rms_before_rad=rms_before_rad, rms_after_rad=rms_after_rad if applied else rms_before_rad,
        evaluations=int(solution.nfev),
        converged=bool(solution.success), message=str(solution.message), applied=applied,
    )
    if not applied:
        return numerator, denominator, mu, mu0, zi0, report  # keep the subspace estimate
    return b_full, a, mu_new, mu0_new, zi, report


# ----------------------------------------------------------------------------------------------------------
# The identification
# ----------------------------------------------------------------------------------------------------------


def _check_int(name: str, value: Any, lowest: int) -> int:
    try:
        valid = not isinstance(value, bool) and int(value) == value and value >= lowest
    except (TypeError, ValueError):
        valid = False
    if not valid:
        raise InvalidInputError(f"{name}: expected an integer >= {lowest}, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class HammersteinOptions:
    """The settings of :func:`identify_hammerstein`, checked when built (an :class:`InvalidInputError` names
    the field). ``identify_hammerstein(u, y, nodes, options)`` or the same fields as keywords.

    Attributes
    ----------
    hold_samples
        Length K of the leading hold at u_min: μ0 starts as the mean of y over it (Section III).
    mu0_rad
        μ0 = H[u_min] when it is known (then no hold is needed). With neither, μ0 starts at 0; with
        ``estimate_offset`` (the default) it is re-estimated from all data anyway.
    order
        n, or ``"auto"``: the largest gap among the first ``max_order`` singular values.
    max_order
        The largest n that ``order="auto"`` considers.
    past_horizon, future_horizon
        p and f of the block-Hankel matrices (f > n and p > n; j = N - p - f + 1 columns).
    feedthrough
        Estimate D (the paper's eq. (6)); ``False`` fixes D = 0 for a strictly proper G.
    split
        ``"separate"`` (default: Remark 5, B, D and μ by alternating least squares with A, C fixed; it
        was as accurate or better in ``benchmarks/pouliquen2013_hammerstein.py``) or ``"rank1"`` (eq. (14)).
    estimate_offset
        Re-estimate μ0 jointly with B and D (a constant regressor); ``False`` keeps the hold mean or ``mu0_rad``.
    refine
        Run the output-error refinement after the subspace step (:class:`RefinementReport`).
    initial_direction
        δ(-1) of the direction signal (0: the input came down to u(0)).
    min_visits
        Fewest samples each node segment must hold on each path.
    """

    hold_samples: int | None = None
    mu0_rad: float | None = None
    order: int | Literal["auto"] = "auto"
    max_order: int = 10
    past_horizon: int = DEFAULT_PAST_HORIZON
    future_horizon: int = DEFAULT_FUTURE_HORIZON
    feedthrough: bool = True
    split: Literal["rank1", "separate"] = "separate"
    estimate_offset: bool = True
    refine: bool = False
    initial_direction: int = 0
    min_visits: int = 1

    def __post_init__(self) -> None:
        for name, lowest in (("past_horizon", 1), ("future_horizon", 2), ("max_order", 1)):
            object.__setattr__(self, name, _check_int(name, getattr(self, name), lowest))
        if self.split not in ("rank1", "separate"):
            raise InvalidInputError(f"split: expected 'rank1' or 'separate', got {self.split!r}")
        if self.order != "auto":
            object.__setattr__(self, "order", _check_int("order", self.order, 1))
        if self.mu0_rad is not None:
            if self.hold_samples is not None:
                raise InvalidInputError("hold_samples, mu0_rad: give one of them, not both")
            if not np.isfinite(float(self.mu0_rad)):
                raise InvalidInputError(f"mu0_rad: expected a finite number, got {self.mu0_rad!r}")
        elif self.hold_samples is not None:
            object.__setattr__(self, "hold_samples", _check_int("hold_samples", self.hold_samples, 1))
        elif not self.estimate_offset:
            raise InvalidInputError("hold_samples, mu0_rad: give one of them, or set estimate_offset=True")


@renamed_parameters(u="input_rad", y="output_rad")
def identify_hammerstein(
    input_rad: ArrayLike,
    output_rad: ArrayLike,
    nodes: PathNodes | ArrayLike,
    options: HammersteinOptions | None = None,
    **option_values: Any,
) -> HammersteinModel:
    """Identify G(q) and the borders of an input backlash or switch from one Table I experiment.

    Implements Section III of Pouliquen et al. (2013), one named step each: μ0 from the hold
    (:func:`_start_offset`), the lifting of eq. (4) and PI-MOESP, eqs. (8)-(13) (:func:`_observability`),
    the order from the singular values (:func:`_choose_order`), A and C from Γ_f (:func:`_shift_invariance`),
    bold B and bold D by least squares with the rank-1 split of eq. (14) or Remark 5 (:func:`_input_gains`),
    the unit static gain of A.2 (:func:`_unit_static_gain`) and the optional refinement. See the module
    docstring for what goes beyond the paper.

    Parameters
    ----------
    input_rad, output_rad
        Input u and output y, one sample each per time step, starting at u_min (with the hold, if any); the
        old keyword names ``u=``, ``y=`` still work, with a DeprecationWarning. NaN in ``output_rad`` marks a
        sample not measured (LOST): the Hankel columns (windows of p + f samples) that hold one and the rows
        of the least squares at it are left out, μ0 is the mean of the hold's measured samples, and
        ``num_columns`` of the model counts the windows used.
    nodes
        Path nodes (eq. (3)); :meth:`PathNodes.uniform` for equally spaced ones, or one sequence of node
        positions shared by both paths.
    options
        The settings (:class:`HammersteinOptions`); or give its fields as keywords (``hold_samples=50``,
        ``split="rank1"``, ...), which override those of ``options``.

    Raises
    ------
    InvalidInputError
        Non-finite samples, lengths that differ, an input that does not follow the cyclic design (names the
        sample, path or segment), too little data for the horizons, an input that is not persistently
        exciting, an order the data do not support, a linear part with no finite non-zero static gain, or a
        setting out of range.
    TypeError
        A keyword that is no field of :class:`HammersteinOptions` (the message lists them).
    """
    options = with_options("identify_hammerstein", options, HammersteinOptions, option_values)
    u_signal = varying("input_rad", as_signal("input_rad", input_rad), "use the cyclic random excitation of "
                       "identify.cyclic_excitation (configs/experiments/hammerstein_cyclic.toml)")
    y_signal = as_signal("output_rad", output_rad, missing_allowed=True)
    N = same_length(input_rad=u_signal, output_rad=y_signal)
    nodes = _path_nodes(nodes)
    p, f = options.past_horizon, options.future_horizon

    mu0_start, mu0_hold_rad = _start_offset(u_signal, y_signal, nodes, options)
    m = nodes.num_lifted_inputs
    j = N - p - f + 1
    needed_columns = (p + f) * m + f
    if j < needed_columns:
        raise InvalidInputError(
            f"input_rad, output_rad: {N} samples are too few for past_horizon={p}, future_horizon={f} and {m} lifted inputs: "
            f"the Hankel matrices need at least {needed_columns} columns, i.e. {needed_columns + p + f - 1} samples"
        )
    missing = int(np.count_nonzero(np.isnan(y_signal)))
    if missing:
        j = int(np.count_nonzero(complete_windows(y_signal, p + f)))
        if j < needed_columns:
            raise InvalidInputError(
                f"output_rad: {missing} of the {N} outputs are missing (NaN, LOST), which leaves {j} complete windows "
                f"of p + f = {p + f} samples (Hankel columns); past_horizon={p}, future_horizon={f} and {m} lifted "
                f"inputs need at least {needed_columns}: record again with fewer lost samples, or use shorter "
                "horizons or fewer nodes")
    check_cyclic_input(u_signal, nodes, initial_direction=options.initial_direction,
                       tolerance_rad=_node_tolerance(nodes), min_visits=options.min_visits)

    z = lifted_input(u_signal, nodes, initial_direction=options.initial_direction)
    y_bar = y_signal - mu0_start
    U, singular_values = _observability(z, y_bar, p, f)
    n = _choose_order(singular_values, options)
    A, C = _shift_invariance(U, singular_values, n)
    B, D, mu, x0, offset, free_response = _input_gains(A, C, z, y_bar, options)
    mu0_final = mu0_start + offset
    B, D, mu = _unit_static_gain(A, B, C, D, mu)

    numerator, denominator = _state_space_to_tf(A, B, C, D)
    model_output = mu0_final + scipy.signal.lfilter(numerator, denominator, z @ mu) + free_response @ x0
    refinement = None
    if options.refine:
        A, B, C, D, mu, mu0_final, x0, model_output, refinement = _refined_model(
            z, y_signal, numerator, denominator, mu, mu0_final, free_response @ x0, options.feedthrough,
            (A, B, C, D, x0, model_output))
    measured = ~np.isnan(y_signal)  # the fit and its RMS are over the measured samples
    residual = (y_signal - model_output)[measured]
    spread = np.linalg.norm(y_signal[measured] - y_signal[measured].mean())
    fit = 100.0 * (1.0 - np.linalg.norm(residual) / spread) if spread > 0 else float("nan")
    num_a = len(nodes.ascending) - 1
    return HammersteinModel(
        A=A, B=B, C=C, D=D, mu0=mu0_final, nodes=nodes,
        mu_ascending=mu[:num_a], mu_descending=mu[num_a:],
        singular_values=singular_values, order=n, past_horizon=p, future_horizon=f, num_columns=j,
        split=options.split, initial_state=x0, fit_percent=float(fit),
        residual_rms_rad=float(np.sqrt(np.mean(residual**2))), mu0_hold_rad=mu0_hold_rad, refinement=refinement,
    )


def _path_nodes(nodes: PathNodes | ArrayLike) -> PathNodes:
    """``nodes`` as :class:`PathNodes`: one sequence of positions is shared by both paths."""
    if isinstance(nodes, PathNodes):
        return nodes
    try:
        shared = tuple(float(v) for v in nodes)  # type: ignore[union-attr]
    except (TypeError, ValueError) as err:
        raise InvalidInputError(
            f"nodes: expected a PathNodes or a sequence of node positions, got {type(nodes).__name__}"
        ) from err
    return PathNodes(shared, shared)


def _node_tolerance(nodes: PathNodes) -> float:
    """How far from a node value an input still counts as at it (u_min on the hold, the cyclic check)."""
    return 1e-9 * (nodes.u_max - nodes.u_min)


def _start_offset(u: NDArray[np.float64], y: NDArray[np.float64], nodes: PathNodes,
                  options: HammersteinOptions) -> tuple[float, float | None]:
    """(μ0 to start from, the paper's hold mean or None): ``mu0_rad`` if given, else the mean of y over the
    hold at u_min (Section III), else 0 (then the offset is estimated from all data)."""
    if options.mu0_rad is not None:
        return float(options.mu0_rad), None
    if options.hold_samples is None:
        return 0.0, None
    K = options.hold_samples
    if K > u.size:
        raise InvalidInputError(f"hold_samples: {K} is longer than the data ({u.size} samples)")
    off_hold = np.flatnonzero(np.abs(u[:K] - nodes.u_min) > _node_tolerance(nodes))
    if off_hold.size:
        k = int(off_hold[0])
        raise InvalidInputError(
            f"hold_samples: sample {k} of the hold is u = {float(u[k])}, expected u_min = {nodes.u_min}; "
            "shorten hold_samples or give mu0_rad"
        )
    if np.all(np.isnan(y[:K])):
        raise InvalidInputError(f"hold_samples: all {K} outputs of the hold are missing (LOST): no mu0 can be read "
                                "from it; give mu0_rad or record again")
    mu0_hold_rad = float(np.nanmean(y[:K]))  # the samples of the hold that were measured
    return mu0_hold_rad, mu0_hold_rad


def _observability(z: NDArray[np.float64], y_bar: NDArray[np.float64], p: int,
                   f: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """U and the singular values of the PI-MOESP projection (eqs. (8)-(12)), after checking that the lifted
    input is persistently exciting of order p + f.

    The subspace step projects out a constant (an error in μ0 would otherwise look like an extra state);
    the offset itself is estimated in the least-squares step."""
    U, singular_values, input_diagonal = pi_moesp_observability(z, y_bar, p, f)
    if input_diagonal.min() <= 1e-10 * input_diagonal.max():
        raise InvalidInputError(
            f"input_rad: the lifted input is not persistently exciting of order p + f = {p + f} "
            f"({z.shape[1]} lifted inputs): check the excitation or use fewer nodes or shorter horizons"
        )
    return U, singular_values


def _choose_order(singular_values: NDArray[np.float64], options: HammersteinOptions) -> int:
    """n: the largest gap of the singular values (eq. (12)) for ``order="auto"``, else the given order if
    the horizons and the singular values support it."""
    p, f = options.past_horizon, options.future_horizon
    if options.order == "auto":
        n = select_order(singular_values, min(options.max_order, f - 1, p))
        logger.info("order %d chosen from the singular values (gap s_%d / s_%d = %.3g)", n, n, n + 1,
                    singular_values[n - 1] / max(singular_values[n], np.finfo(float).tiny))
        return n
    n = int(options.order)
    if n >= f or n > p:
        raise InvalidInputError(f"order: {n} needs future_horizon > {n} and past_horizon >= {n}, got {f} and {p}")
    if n > singular_values.size or singular_values[n - 1] <= 1e-12 * singular_values[0]:
        raise InvalidInputError(
            f"order: the data support at most order {int(np.sum(singular_values > 1e-12 * singular_values[0]))} "
            f"(singular values {np.array2string(singular_values[: n + 1], precision=3)})"
        )
    return n


def _shift_invariance(U: NDArray[np.float64], singular_values: NDArray[np.float64],
                      n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Step 1 of Section III: C and A from the extended observability matrix Γ_f = U_1 S_1^(1/2)."""
    gamma = U[:, :n] * np.sqrt(singular_values[:n])
    C = gamma[0].copy()
    A = _lstsq(gamma[:-1], gamma[1:])
    return A, C


def _input_gains(A: NDArray[np.float64], C: NDArray[np.float64], z: NDArray[np.float64], y_bar: NDArray[np.float64],
                 options: HammersteinOptions) -> tuple[NDArray, float, NDArray, NDArray, float, NDArray]:
    """Steps 2 and 3 of Section III: bold B, bold D (and x0, the offset) by least squares, then eq. (14)'s
    rank-1 split or Remark 5's separate fit. Returns B, D, μ, x0, the offset added to μ0 (0 unless
    ``estimate_offset``) and the free response C A^t (N, n)."""
    n = A.shape[0]
    reg = _regressors(A, C, z, y_bar, options.feedthrough, options.estimate_offset)
    bold_B, bold_D, nuisance = _overparameterised_fit(reg)
    B, D, mu = _rank_one_split(bold_B, bold_D, options.feedthrough)
    if options.split == "separate":
        B, D, mu, nuisance = _separate_fit(reg, mu)
    offset = float(nuisance[n]) if options.estimate_offset else 0.0
    return B, D, mu, nuisance[:n], offset, reg.O


def _unit_static_gain(A: NDArray[np.float64], B: NDArray[np.float64], C: NDArray[np.float64], D: float,
                      mu: NDArray[np.float64]) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
    """A.2: scale B, D by 1/G(1) and μ by G(1), so that G(1) = D + C (I - A)^-1 B = 1."""
    n = A.shape[0]
    try:
        gain = float(D + C @ np.linalg.solve(np.eye(n) - A, B))
    except np.linalg.LinAlgError:
        gain = np.inf
    if not np.isfinite(gain) or abs(gain) < 1e-12 * (abs(D) + np.linalg.norm(C) * np.linalg.norm(B)):
        raise InvalidInputError(
            f"input_rad, output_rad: the identified linear part has static gain {gain}; the normalisation G(1) = 1 (assumption A.2) "
            f"needs a finite non-zero gain (poles {np.round(np.linalg.eigvals(A), 4).tolist()})"
        )
    return B / gain, D / gain, mu * gain


def _refined_model(z: NDArray, y: NDArray, numerator: NDArray, denominator: NDArray, mu: NDArray, mu0: float,
                   free_response: NDArray, feedthrough: bool, subspace: tuple) -> tuple:
    """The output-error refinement (:func:`_refine`) and, if it was applied, the refined model in
    controllable canonical form with x(0) in its coordinates; else the subspace model ``subspace`` =
    (A, B, C, D, x0, model output) unchanged. Returns A, B, C, D, μ, μ0, x0, the model output, the report."""
    A, B, C, D, x0, model_output = subspace
    numerator, denominator, mu, mu0, zi, refinement = _refine(
        z, y, numerator, denominator, mu, mu0, free_response, feedthrough)
    logger.info("output-error refinement %s: RMS %.6g -> %.6g rad after %d evaluations (%s)",
                "applied" if refinement.applied else "not applied", refinement.rms_before_rad, refinement.rms_after_rad,
                refinement.evaluations, refinement.message)
    if refinement.applied:
        n = A.shape[0]
        A_c, B_c, C_c, D_c = scipy.signal.tf2ss(numerator, denominator)
        A, B, C, D = A_c, B_c[:, 0], C_c[0], float(D_c[0, 0])
        # x(0) in the new coordinates: the free response of the refined filter state, matched on 2n samples
        free = scipy.signal.lfilter(numerator, denominator, np.zeros(y.size), zi=zi)[0]
        model_output = mu0 + scipy.signal.lfilter(numerator, denominator, z @ mu) + free
        observability = np.vstack([C @ np.linalg.matrix_power(A, k) for k in range(2 * n)])
        x0 = _lstsq(observability, free[: 2 * n])
    return A, B, C, D, mu, mu0, x0, model_output, refinement
