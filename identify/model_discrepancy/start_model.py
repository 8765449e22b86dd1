"""Step 1 of the workflow, the start model: the user's model, or the best low-order linear model
(:func:`fit_linear_model`: equation-error start, Steiglitz-McBride iterations, output-error polish, order
chosen by validation error), and the chain the search begins with. Also the output-error fit of a linear
block by variable projection (:func:`_output_error_fit`), which the candidate fits reuse to refit a start
model that absorbed part of an effect.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize
from scipy.signal import lfilter

from identify.plant_blocks import LinearBlock, PlantModel
from identify.validation import InvalidInputError, as_signal, positive, same_length

from identify.model_discrepancy.chain import (
    _Chain,
    _Component,
    _bridged,
    _linear_component,
    _measured_error,
    _polish,
    _rms,
)
from identify.model_discrepancy.result import LinearFit
from identify.model_discrepancy.thresholds import (
    FAILED_RUN_ERROR_RAD,
    JOINT_FIT_ORDER,
    LINEAR_DIFF_STEP,
    MAX_EVALUATIONS,
    ORDER_CHOICE_FACTOR,
    ORDER_LOOK_ALIKE_EXTRA,
    START_INPUT_DELAY_SAMPLES,
    START_MAX_ORDER,
)


def _arx(u: NDArray[np.float64], y: NDArray[np.float64], order: int, delay: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Equation-error least squares y_t + a1 y_{t-1} + ... = b_d u_{t-d} + ... + b_{d+n-1} u_{t-d-n+1}."""
    start = order + delay
    rows = [-y[start - i: y.size - i] for i in range(1, order + 1)]
    rows += [u[start - delay - j: u.size - delay - j] for j in range(order)]
    phi = np.column_stack(rows)
    theta, *_ = np.linalg.lstsq(phi, y[start:], rcond=None)
    return tuple(float(v) for v in theta[:order]), (0.0,) * delay + tuple(float(v) for v in theta[order:])


def _steiglitz_mcbride(u: NDArray[np.float64], y: NDArray[np.float64], order: int, delay: int,
                       iterations: int = 25) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Output-error fit by Steiglitz-McBride iterations: ARX on u and y prefiltered by 1/A of the previous
    iterate, which converges to the output-error minimiser for white measurement noise."""
    a, b = _arx(u, y, order, delay)
    for _ in range(iterations):
        poles = np.roots((1.0, *a))
        if np.any(np.abs(poles) >= 1.0):
            poles = np.where(np.abs(poles) >= 1.0, 0.99 * poles / np.abs(poles), poles)
            a = tuple(float(v) for v in np.real(np.poly(poles))[1:])
        denominator = (1.0, *a)
        new_a, new_b = _arx(lfilter([1.0], denominator, u), lfilter([1.0], denominator, y), order, delay)
        if max(abs(x - z) for x, z in zip(a + b, new_a + new_b)) < 1e-10:
            a, b = new_a, new_b
            break
        a, b = new_a, new_b
    poles = np.roots((1.0, *a))
    if np.any(np.abs(poles) >= 0.999):  # reflect into the unit disc; the output-error polish goes on from there
        poles = np.where(np.abs(poles) >= 0.999, 0.99 * poles / np.abs(poles), poles)
        a = tuple(float(v) for v in np.real(np.poly(poles))[1:])
        b = (0.0,) * delay + _arx_numerator(u, y, a, order, delay)
    return a, b


def _arx_numerator(u: NDArray[np.float64], y: NDArray[np.float64], a: tuple[float, ...], order: int,
                   delay: int) -> tuple[float, ...]:
    """Least-squares B for a fixed A: y filtered by A against the delayed inputs."""
    target = lfilter((1.0, *a), [1.0], y)
    start = order + delay
    phi = np.column_stack([u[start - delay - j: u.size - delay - j] for j in range(order)])
    theta, *_ = np.linalg.lstsq(phi, target[start:], rcond=None)
    return tuple(float(v) for v in theta)


def fit_linear_model(command_rad: ArrayLike, angle_rad: ArrayLike, sample_period_s: float,
                     estimation_samples: int, *, max_order: int = START_MAX_ORDER, min_order: int = 1,
                     input_delay_samples: int = START_INPUT_DELAY_SAMPLES,
                     max_evaluations: int = MAX_EVALUATIONS) -> LinearFit:
    """The best low-order linear model y_t = B(q^-1)/A(q^-1) u_t (eq. (1) of Cerone et al. 2009).

    For each order n = ``min_order``..``max_order`` an equation-error (ARX) fit gives the initial guess of an
    output-error fit that minimises the free-run error on the estimation segment; the order with the
    smallest free-run RMS error on the validation segment wins (a higher order only if it lowers that error
    by more than 2 %). B has ``input_delay_samples`` leading zeros (the one sample a sampled drive always
    takes); a longer delay and higher-order modes are left for the workflow to name (``delay``,
    ``resonance``).
    """
    u = as_signal("command_rad", command_rad, min_samples=10)
    y = as_signal("angle_rad", angle_rad, min_samples=10, missing_allowed=True)
    same_length(command_rad=u, angle_rad=y)
    period = positive("sample_period_s", sample_period_s)
    n_est = int(estimation_samples)
    if not 10 <= n_est < u.size:
        raise InvalidInputError(f"estimation_samples: expected 10 <= n < {u.size}, got {estimation_samples!r}")
    if not 1 <= min_order <= max_order:
        raise InvalidInputError(f"min_order, max_order: expected 1 <= min_order <= max_order, got {min_order!r}, "
                                f"{max_order!r}")
    gaps: dict[int, float] = {}
    best: tuple[float, int, LinearBlock] | None = None
    for order in range(min_order, max_order + 1):
        try:
            a, b = _steiglitz_mcbride(u[:n_est], _bridged(y[:n_est]), order, input_delay_samples)
        except InvalidInputError:
            continue
        chain = _Chain([_linear_component(LinearBlock(a=a, b=b, sample_period_s=period))])
        chain = _polish(chain, u[:n_est], y[:n_est], max_evaluations)
        block = chain.model().blocks[0]
        assert isinstance(block, LinearBlock)
        gap = _rms(_measured_error(y, block.apply(u))[n_est:])
        gaps[order] = gap
        if best is None or gap < ORDER_CHOICE_FACTOR * best[0]:
            best = (gap, order, block)
    if best is None:
        raise InvalidInputError(f"angle_rad: no stable linear model of order {min_order}..{max_order} fits the data")
    return LinearFit(block=best[2], order=best[1], validation_gap_by_order_rad=gaps)


def _output_error_fit(u: NDArray[np.float64], y: NDArray[np.float64], a: tuple[float, ...], delay: int,
                      numerator_terms: int, max_evaluations: int = 60) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Output-error fit of y_t = B(q^-1)/A(q^-1) u_t (eq. (1) of Cerone et al. 2009) from the denominator
    ``a``, by variable projection: for a given A the error is linear in B (least squares on u filtered by
    q^-k / A, k = ``delay`` .. ``delay + numerator_terms - 1``), so only A is searched. Returns a and b (with
    ``delay`` leading zeros)."""

    measured = ~np.isnan(y)  # a missing sample is no row of the least squares

    def solve(a_values: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        denominator = (1.0, *a_values)
        phi = np.column_stack([lfilter([0.0] * (delay + j) + [1.0], denominator, u) for j in range(numerator_terms)])
        theta, *_ = np.linalg.lstsq(phi[measured], y[measured], rcond=None)
        return theta, _measured_error(y, phi @ theta)

    def residual(a_values: NDArray[np.float64]) -> NDArray[np.float64]:
        if np.any(np.abs(np.roots((1.0, *a_values))) >= 0.9999):
            return np.full(y.size, FAILED_RUN_ERROR_RAD / math.sqrt(y.size))
        return solve(a_values)[1]

    with np.errstate(all="ignore"):
        fit = optimize.least_squares(residual, np.array(a, dtype=float), method="trf", diff_step=LINEAR_DIFF_STEP,
                                     max_nfev=max_evaluations)
    theta, _ = solve(fit.x)
    return tuple(float(v) for v in fit.x), (0.0,) * delay + tuple(float(v) for v in theta)


def record_modes(u: NDArray[np.float64], y: NDArray[np.float64], period: float, n_est: int,
                 max_damping: float) -> tuple[tuple[float, float], ...]:
    """Where the modes of the record sit: the pole pairs (natural frequency in Hz, damping ratio below
    ``max_damping``) of the best linear models of each order ``START_MAX_ORDER + 1`` .. ``START_MAX_ORDER +
    ORDER_LOOK_ALIKE_EXTRA`` (:func:`fit_linear_model` on the estimation segment), a z-plane pole p read as
    s = ln(p) / T. They start the fit of a mode a fitted start model lacks: a lightly damped mode's basin is a
    few damping ratios wide in frequency, narrower than any grid of guesses (the clean-room generator's shaft
    mode, 30.8 Hz at damping 0.053, behind an order-2 start: 0.46 mrad validated from 30.8 Hz, 2.2 mrad or more
    from 28 or 33 Hz, where the best grid guess polished to 144 Hz)."""
    modes: list[tuple[float, float]] = []
    for order in range(START_MAX_ORDER + 1, START_MAX_ORDER + ORDER_LOOK_ALIKE_EXTRA + 1):
        try:
            block = fit_linear_model(u, y, period, n_est, min_order=order, max_order=order).block
        except InvalidInputError:
            continue
        for pole in np.roots((1.0, *block.a)):
            if pole.imag <= 0.0 or abs(pole) >= 1.0:
                continue
            s = complex(np.log(complex(pole))) / period
            frequency, damping = abs(s) / (2.0 * math.pi), -s.real / abs(s)
            if 0.0 < damping < max_damping and frequency < 0.5 / period:
                modes.append((frequency, damping))
    return tuple(modes)


def _raised_order(block: LinearBlock, order: int) -> LinearBlock:
    """The same transfer function with extra poles and zeros at z = 0.3 that cancel, so that a joint fit
    has ``order`` poles to move (the start model's order was chosen with the effect still missing)."""
    a, b = np.array((1.0, *block.a)), np.array(block.b)
    while a.size - 1 < order:
        a, b = np.convolve(a, (1.0, -0.3)), np.convolve(b, (1.0, -0.3))
    return LinearBlock(a=tuple(a[1:]), b=tuple(b), sample_period_s=block.sample_period_s)


def _start_chain(model: PlantModel | None, linear: LinearBlock | None, order: int) -> _Chain:
    if model is None:
        assert linear is not None
        return _Chain([_linear_component(_raised_order(linear, order))])
    return _Chain([_Component("fixed", block=block) for block in model.blocks])


def _start(u: NDArray[np.float64], y: NDArray[np.float64], period: float, n_est: int, model: PlantModel | None,
           max_evaluations: int, say: Callable[[str], None]) -> tuple[PlantModel, LinearFit | None, _Chain]:
    """Step 1: the start model (the given one, or :func:`fit_linear_model` on the estimation segment), how
    its order was chosen, and the chain the search begins with (a fitted linear block raised to order 2 so
    that joint fits have two poles to move)."""
    if model is not None:
        return model, None, _start_chain(model, None, JOINT_FIT_ORDER)
    linear_fit = fit_linear_model(u, y, period, n_est, max_evaluations=max_evaluations)
    say(f"start: linear model of order {linear_fit.order}")
    return PlantModel((linear_fit.block,)), linear_fit, _start_chain(None, linear_fit.block, JOINT_FIT_ORDER)
