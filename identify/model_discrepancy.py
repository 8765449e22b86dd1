"""Model-discrepancy workflow: find where a simulation model and a measurement disagree, name the missing
physical effect, add it with fitted parameters, and show the validated gap shrink.

The workflow (issue 6) runs in five steps on one record (u_t, y_t), t = 0..N-1, with a known bound
delta on the measurement error (|e_t| <= delta, the noise bound of set-membership identification,
eq. (4) of Cerone et al. 2009):

1. **Start** from a given :class:`~identify.plant_blocks.PlantModel` or, without one, from the best
   low-order linear model (:func:`fit_linear_model`: output-error fit, order chosen by validation error).
2. **Disagree** (:func:`disagreement`): free-run simulation y^_t of the model on the measured input, residual
   r_t = y_t - y^_t; a sample is *falsified* when |r_t| > delta (it cannot be explained by the model plus
   admissible noise); falsified samples are grouped into windows.
3. **Explain** (:func:`signature_scores`): each candidate effect leaves a signature in r_t
   (see :mod:`identify.effect_signatures`).
4. **Add and fit**: every candidate is inserted into the model, its parameters (with the linear block's
   coefficients when the start model was fitted) are fitted on the estimation segment, and the gap
   g = sqrt(mean r_t^2) is measured on the validation segment. The effect whose penalised gap
   g_after (1 + penalty * n_parameters) is lowest and below g_before is kept; repeat until the falsified
   fraction on the validation segment is at most ``consistent_fraction`` or no candidate helps.
5. **Show**: one :class:`DiscrepancyStep` per kept effect and a :class:`DiscrepancyResult` overall.

The start model and all fits use only the estimation segment; every number quoted as a gap is measured on
the validation segment, which the fits never see.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize
from scipy.signal import lfilter

from identify.effect_catalogue import EFFECT_NAMES, EFFECTS, GuessContext, effect
from identify.effect_signatures import SignatureScore, signature_scores
from identify.plant_blocks import Block, CoulombFriction, LinearBlock, OutputBacklash, PlantModel, Resonance
from identify.validation import InvalidInputError, as_signal, positive, same_length, varying

ESTIMATION_FRACTION = 0.6
"""Default share of the record the effects are fitted on; the rest is the validation segment."""

__all__ = [
    "DisagreementWindow",
    "Disagreement",
    "DiscrepancyStep",
    "DiscrepancyResult",
    "LinearFit",
    "EFFECT_NAMES",
    "diagnose_model",
    "disagreement",
    "fit_linear_model",
]

_BIG = 1.0e6
_LINEAR_DIFF_STEP = 1e-6
"""Relative finite-difference step of the polish for polynomial coefficients: with poles near z = 1 a
0.1 % change of a_1 is a different system, and the fit stalls."""
_EFFECT_DIFF_STEP = 1e-3
"""... and for effect parameters, whose free-run response has kinks (a play taken up, a limit reached)."""
_BASELINE_EFFORT = 5
"""Before another effect is tried, the model so far is polished with this many times the evaluations of one
candidate fit."""


# ----------------------------------------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DisagreementWindow:
    """A run of samples where falsified samples cluster: [start, stop) sample indices."""

    start: int
    stop: int
    falsified_samples: int
    peak_residual_rad: float


@dataclass(frozen=True)
class Disagreement:
    """Free-run residual r_t = y_t - y^_t of a model against the measurement (step 2).

    Attributes
    ----------
    simulated_rad
        y^_t, the model's free-run output on the measured input.
    residual_rad
        r_t = y_t - y^_t.
    falsified
        |r_t| > noise bound delta: samples the model cannot explain with admissible noise.
    falsified_fraction
        Fraction of falsified samples on the validation segment.
    gap_rad
        sqrt(mean r_t^2) on the validation segment.
    windows
        Where falsified samples cluster (whole record).
    """

    simulated_rad: NDArray[np.float64]
    residual_rad: NDArray[np.float64]
    falsified: NDArray[np.bool_]
    falsified_fraction: float
    gap_rad: float
    windows: tuple[DisagreementWindow, ...]


@dataclass(frozen=True)
class LinearFit:
    """The start linear model (step 1) and how its order was chosen."""

    block: LinearBlock
    order: int
    validation_gap_by_order_rad: dict[int, float]


@dataclass(frozen=True)
class DiscrepancyStep:
    """One effect added to the model (step 4).

    Attributes
    ----------
    effect
        One of :data:`EFFECT_NAMES`.
    parameters
        The fitted parameters of the effect (units in the names).
    evidence
        The signature scores of the residual before the effect was added (0 = no sign of it, 1 = the
        residual is entirely this signature), and the validated gap every candidate reached.
    gap_before_rad, gap_after_rad
        Validated gap before and after adding the effect.
    falsified_fraction_before, falsified_fraction_after
        Fraction of validation samples with |r_t| > delta before and after.
    """

    effect: str
    parameters: dict[str, float]
    evidence: dict[str, Any]
    gap_before_rad: float
    gap_after_rad: float
    falsified_fraction_before: float
    falsified_fraction_after: float
    model: PlantModel = field(repr=False)


@dataclass(frozen=True)
class DiscrepancyResult:
    """The whole workflow (step 5).

    Attributes
    ----------
    steps
        The effects added, in order; empty when the start model already explains the data.
    start_model, final_model
        The model before and after.
    initial, final
        The disagreement of the start and final model.
    consistent
        True if the final model's falsified fraction on the validation segment is at most the tolerance.
    unexplained
        A plain-language statement of what is left.
    estimation_samples
        The first ``estimation_samples`` samples are the estimation segment, the rest the validation one.
    linear_fit
        How the start linear model was chosen (None when a model was given).
    """

    steps: tuple[DiscrepancyStep, ...]
    start_model: PlantModel
    final_model: PlantModel
    initial: Disagreement
    final: Disagreement
    consistent: bool
    unexplained: str
    estimation_samples: int
    noise_bound_rad: float
    linear_fit: LinearFit | None = None

    @property
    def missing_effects(self) -> tuple[str, ...]:
        return tuple(step.effect for step in self.steps)

    def to_json_dict(self) -> dict[str, Any]:
        """The ``rig diagnose --json`` document (keys fixed by issue 6)."""
        return {
            "missing_effects": [
                {
                    "effect": step.effect,
                    "parameters": {k: float(v) for k, v in step.parameters.items()},
                    "gap_before": float(step.gap_before_rad),
                    "gap_after": float(step.gap_after_rad),
                }
                for step in self.steps
            ],
            "gap_initial": float(self.initial.gap_rad),
            "gap_final": float(self.final.gap_rad),
            "falsified_fraction_initial": float(self.initial.falsified_fraction),
            "falsified_fraction_final": float(self.final.falsified_fraction),
        }


# ----------------------------------------------------------------------------------------------------------
# Step 2: disagreement
# ----------------------------------------------------------------------------------------------------------


def _windows(falsified: NDArray[np.bool_], residual: NDArray[np.float64], merge_gap: int,
             min_falsified: int) -> tuple[DisagreementWindow, ...]:
    index = np.flatnonzero(falsified)
    if index.size == 0:
        return ()
    breaks = np.flatnonzero(np.diff(index) > merge_gap)
    starts = np.concatenate(([index[0]], index[breaks + 1]))
    stops = np.concatenate((index[breaks], [index[-1]])) + 1
    windows = []
    for start, stop in zip(starts.tolist(), stops.tolist()):
        count = int(np.count_nonzero(falsified[start:stop]))
        if count >= min_falsified:
            windows.append(DisagreementWindow(start, stop, count, float(np.max(np.abs(residual[start:stop])))))
    return tuple(windows)


def disagreement(model: PlantModel, command_rad: ArrayLike, angle_rad: ArrayLike, noise_bound_rad: float,
                 estimation_samples: int | None = None, *, merge_gap_samples: int = 20,
                 min_window_samples: int = 3) -> Disagreement:
    """Free-run residual of ``model`` against the measurement and the samples it falsifies.

    A sample is falsified when |y_t - y^_t| > delta, the noise bound of eq. (4) of Cerone et al. (2009):
    no admissible noise sequence can explain it. Falsified samples less than ``merge_gap_samples`` apart
    form one window; windows with fewer than ``min_window_samples`` falsified samples are dropped.

    Parameters
    ----------
    model
        The model, simulated from rest on the whole command.
    command_rad, angle_rad
        u_t and the measured y_t.
    noise_bound_rad
        delta > 0.
    estimation_samples
        Samples before the validation segment; the fraction and gap are computed on the rest
        (default: 0, the whole record).
    """
    u = as_signal("command_rad", command_rad, min_samples=2)
    y = as_signal("angle_rad", angle_rad, min_samples=2)
    same_length(command_rad=u, angle_rad=y)
    delta = positive("noise_bound_rad", noise_bound_rad)
    start = 0 if estimation_samples is None else int(estimation_samples)
    if not 0 <= start < u.size:
        raise InvalidInputError(f"estimation_samples: expected 0 <= n < {u.size}, got {estimation_samples!r}")
    simulated = np.asarray(model.simulate(u), dtype=float)
    residual = y - simulated
    if not np.all(np.isfinite(residual)):
        residual = np.where(np.isfinite(residual), residual, _BIG)
    falsified = np.abs(residual) > delta
    tail = residual[start:]
    return Disagreement(
        simulated_rad=simulated,
        residual_rad=residual,
        falsified=falsified,
        falsified_fraction=float(np.mean(falsified[start:])),
        gap_rad=float(np.sqrt(np.mean(tail * tail))),
        windows=_windows(falsified, residual, merge_gap_samples, min_window_samples),
    )


# ----------------------------------------------------------------------------------------------------------
# Parametrised models: a chain of components, some with free parameters
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Component:
    """One link of the chain: a fixed block, or a named effect with free parameters."""

    kind: str  # "fixed", "linear", or an effect name
    values: tuple[float, ...] = ()
    block: Block | None = None
    sample_period_s: float = 1.0
    na: int = 0
    nk: int = 0  # leading zeros of B (pure delay of a linear component), not free

    @property
    def free(self) -> int:
        if self.kind == "fixed" or (self.kind in EFFECTS and EFFECTS[self.kind].searched):
            return 0
        return len(self.values)


def _linear_component(block: LinearBlock) -> _Component:
    b = list(block.b)
    nk = 0
    while nk < len(b) - 1 and b[nk] == 0.0:
        nk += 1
    return _Component("linear", tuple(block.a) + tuple(b[nk:]), sample_period_s=block.sample_period_s,
                      na=len(block.a), nk=nk)


def _build(component: _Component, values: Sequence[float]) -> Block:
    kind = component.kind
    if kind == "fixed":
        assert component.block is not None
        return component.block
    v = [float(x) for x in values]
    if kind == "linear":
        return LinearBlock(a=tuple(v[: component.na]), b=(0.0,) * component.nk + tuple(v[component.na:]),
                           sample_period_s=component.sample_period_s)
    return effect(kind).build(v, component.sample_period_s)


def _parameters(kind: str, block: Block) -> dict[str, float]:
    """The public parameters of a fitted effect block."""
    return {key: float(value) for key, value in effect(kind).report(block).items()}


class _Chain:
    """A list of components with a flat vector of the free parameters."""

    def __init__(self, components: Sequence[_Component]) -> None:
        self.components = tuple(components)

    def vector(self) -> NDArray[np.float64]:
        values = [c.values for c in self.components if c.free]
        return np.array([x for v in values for x in v], dtype=float)

    def with_vector(self, theta: Sequence[float]) -> _Chain:
        out, k = [], 0
        for c in self.components:
            if c.free:
                n = len(c.values)
                out.append(_Component(c.kind, tuple(float(x) for x in theta[k:k + n]), c.block, c.sample_period_s, c.na,
                                      c.nk))
                k += n
            else:
                out.append(c)
        return _Chain(out)

    def model(self) -> PlantModel:
        return PlantModel(tuple(_build(c, c.values) for c in self.components))

    def linear_stable(self) -> bool:
        for c in self.components:
            if c.kind == "linear" and c.na:
                if np.any(np.abs(np.roots((1.0, *c.values[: c.na]))) >= 0.9999):
                    return False
        return True


def _free_run_error(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    if not chain.linear_stable():
        return np.full(y.size, _BIG / math.sqrt(y.size))
    try:
        simulated = chain.model().simulate(u)
    except (InvalidInputError, ValueError, OverflowError, FloatingPointError):
        return np.full(y.size, _BIG / math.sqrt(y.size))
    error = y - simulated
    if not np.all(np.isfinite(error)):
        return np.full(y.size, _BIG / math.sqrt(y.size))
    return error


def _rms(values: NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(values * values)))


def _polish(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], max_evaluations: int,
            kinds: frozenset[str] | None = None) -> _Chain:
    """Least-squares fit of the free parameters of ``chain`` (only of components whose kind is in ``kinds``
    if given) to the free-run error on (u, y)."""
    theta_all = chain.vector()
    if theta_all.size == 0:
        return chain
    mask = np.concatenate([np.full(len(c.values), kinds is None or c.kind in kinds)
                           for c in chain.components if c.free])
    if not np.any(mask):
        return chain
    theta0 = theta_all[mask]
    scale = np.maximum(np.abs(theta0), 1e-6)
    steps = np.concatenate([np.full(len(c.values), _LINEAR_DIFF_STEP if c.kind == "linear" else _EFFECT_DIFF_STEP)
                            for c in chain.components if c.free])[mask]

    def expand(z: NDArray[np.float64]) -> _Chain:
        theta = theta_all.copy()
        theta[mask] = z * scale
        return chain.with_vector(theta)

    with np.errstate(all="ignore"):
        fit = optimize.least_squares(lambda z: _free_run_error(expand(z), u, y), theta0 / scale,
                                     method="trf", diff_step=steps, max_nfev=max_evaluations)
    candidate = expand(fit.x)
    if _rms(_free_run_error(candidate, u, y)) <= _rms(_free_run_error(chain, u, y)):
        return candidate
    return chain


# ----------------------------------------------------------------------------------------------------------
# Step 1: the start linear model
# ----------------------------------------------------------------------------------------------------------


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
                     estimation_samples: int, *, max_order: int = 2, input_delay_samples: int = 1,
                     max_evaluations: int = 40) -> LinearFit:
    """The best low-order linear model y_t = B(q^-1)/A(q^-1) u_t (eq. (1) of Cerone et al. 2009).

    For each order n = 1..``max_order`` an equation-error (ARX) fit gives the initial guess of an
    output-error fit that minimises the free-run error on the estimation segment; the order with the
    smallest free-run RMS error on the validation segment wins (a higher order only if it lowers that error
    by more than 2 %). B has ``input_delay_samples`` leading zeros (the one sample a sampled drive always
    takes); a longer delay and higher-order modes are left for the workflow to name (``delay``,
    ``resonance``).
    """
    u = as_signal("command_rad", command_rad, min_samples=10)
    y = as_signal("angle_rad", angle_rad, min_samples=10)
    same_length(command_rad=u, angle_rad=y)
    period = positive("sample_period_s", sample_period_s)
    n_est = int(estimation_samples)
    if not 10 <= n_est < u.size:
        raise InvalidInputError(f"estimation_samples: expected 10 <= n < {u.size}, got {estimation_samples!r}")
    if max_order < 1:
        raise InvalidInputError(f"max_order: expected >= 1, got {max_order!r}")
    gaps: dict[int, float] = {}
    best: tuple[float, int, LinearBlock] | None = None
    for order in range(1, max_order + 1):
        try:
            a, b = _steiglitz_mcbride(u[:n_est], y[:n_est], order, input_delay_samples)
        except InvalidInputError:
            continue
        chain = _Chain([_linear_component(LinearBlock(a=a, b=b, sample_period_s=period))])
        chain = _polish(chain, u[:n_est], y[:n_est], max_evaluations)
        block = chain.model().blocks[0]
        assert isinstance(block, LinearBlock)
        gap = _rms((y - block.apply(u))[n_est:])
        gaps[order] = gap
        if best is None or gap < 0.98 * best[0]:
            best = (gap, order, block)
    if best is None:
        raise InvalidInputError(f"angle_rad: no stable linear model of order 1..{max_order} fits the data")
    return LinearFit(block=best[2], order=best[1], validation_gap_by_order_rad=gaps)


# ----------------------------------------------------------------------------------------------------------
# Step 4: candidate effects
# ----------------------------------------------------------------------------------------------------------


def _insert_index(chain: _Chain, kind: str) -> int:
    """Where an effect goes (its catalogue placement): ``input`` before the first linear component,
    ``output`` after the last linear/resonance component, ``end`` at the very end."""
    linear = [i for i, c in enumerate(chain.components)
              if c.kind in ("linear", "resonance") or isinstance(c.block, (LinearBlock, Resonance))]
    placement = effect(kind).placement
    if placement == "input":
        return linear[0] if linear else 0
    if placement == "end":
        return len(chain.components)
    return linear[-1] + 1 if linear else len(chain.components)


@dataclass(frozen=True)
class _Candidate:
    kind: str
    chain: _Chain
    gap_rad: float
    block: Block
    index: int
    estimation_rms_rad: float = math.inf


def _try_effect(kind: str, chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], n_est: int,
                delta: float, period: float, residual: NDArray[np.float64], scores: dict[str, SignatureScore],
                max_delay_samples: int, max_evaluations: int) -> _Candidate:
    index = _insert_index(chain, kind)
    u_est, y_est = u[:n_est], y[:n_est]

    def with_effect(values: tuple[float, ...], base: _Chain = chain) -> _Chain:
        components = list(base.components)
        components.insert(index, _Component(kind, tuple(float(v) for v in values), sample_period_s=period))
        return _Chain(components)

    entry = effect(kind)
    if entry.searched:
        options = [with_effect((d,)) for d in range(1, max_delay_samples + 1)]
    else:
        options = [with_effect(g) for g in entry.guesses(GuessContext(u, residual, delta, period, scores))]
    options = [_refit_last_linear(option, u_est, y_est) for option in options]
    if kind in ("backlash", "coulomb_friction"):
        plays = np.geomspace(delta, max(float(np.max(np.abs(residual))), 4.0 * delta), 4)
        for contact in filter(None, (_contact_branch_start(chain, u_est, y_est, play) for play in plays)):
            refit, c_l, c_r = contact
            if kind == "backlash":
                options.append(with_effect((c_l, c_r), refit))
            else:
                slide = 0.5 * (c_l + c_r)
                options += [with_effect((ratio * slide, slide), refit) for ratio in (1.0, 1.5, 2.0)]
    costs = [_rms(_free_run_error(option, u_est, y_est)) for option in options]
    best = options[int(np.argmin(costs))]
    best = _refine_delays(best, u_est, y_est)
    if any(c.kind == "linear" for c in best.components):
        best = _polish(best, u_est, y_est, max_evaluations, frozenset({"linear"}))
    best = _polish(best, u_est, y_est, max_evaluations)
    if kind == "coulomb_friction":
        best = _scan_breakaway(best, index, u_est, y_est)
    gap = _rms((y - best.model().simulate(u))[n_est:]) if best.linear_stable() else _BIG
    block = _build(best.components[index], best.components[index].values)
    return _Candidate(kind, best, gap if math.isfinite(gap) else _BIG, block, index,
                      _rms(_free_run_error(best, u_est, y_est)))


def _scan_breakaway(chain: _Chain, index: int, u: NDArray[np.float64], y: NDArray[np.float64]) -> _Chain:
    """Where a stick-slip load sticks depends on the breakaway twist through the whole history, so the
    free-run error is discontinuous in it and a gradient polish leaves it where it started: scan the
    breakaway/sliding ratio 1..3 in steps of 0.05 at the fitted sliding twist and keep the best fit."""
    component = chain.components[index]
    slide = abs(component.values[1])

    def with_ratio(ratio: float) -> _Chain:
        components = list(chain.components)
        components[index] = _Component(component.kind, (ratio * slide, slide), sample_period_s=component.sample_period_s)
        return _Chain(components)

    options = [chain, *(with_ratio(ratio) for ratio in np.linspace(1.0, 3.0, 41))]
    costs = [_rms(_free_run_error(option, u, y)) for option in options]
    return options[int(np.argmin(costs))]


def _raised_order(block: LinearBlock, order: int) -> LinearBlock:
    """The same transfer function with extra poles and zeros at z = 0.3 that cancel, so that a joint fit
    has ``order`` poles to move (the start model's order was chosen with the effect still missing)."""
    a, b = np.array((1.0, *block.a)), np.array(block.b)
    while a.size - 1 < order:
        a, b = np.convolve(a, (1.0, -0.3)), np.convolve(b, (1.0, -0.3))
    return LinearBlock(a=tuple(a[1:]), b=tuple(b), sample_period_s=block.sample_period_s)


def _refit_last_linear(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64]) -> _Chain:
    """When the chain has a free linear component followed only by resonances (a fitted start model with
    input-side effects before it, or a resonance after it), refit that component by output error from the
    signal entering it to y (:func:`_output_error_fit`); linear blocks commute, so the resonances are applied
    to the input. The start model's coefficients were fitted with the effect missing and have absorbed part
    of it."""
    kinds = [c.kind for c in chain.components]
    if "linear" not in kinds:
        return chain
    index = kinds.index("linear")
    if any(kind != "resonance" for kind in kinds[index + 1:]):
        return chain
    linear = chain.components[index]
    others = chain.components[:index] + chain.components[index + 1:]
    inner = PlantModel(tuple(_build(c, c.values) for c in others)).simulate(u) if others else u
    try:
        a, b = _output_error_fit(inner, y, tuple(linear.values[: linear.na]), linear.nk,
                                 len(linear.values) - linear.na)
    except np.linalg.LinAlgError:
        return chain
    components = list(chain.components)
    components[index] = _linear_component(LinearBlock(a=a, b=b, sample_period_s=linear.sample_period_s))
    refit = _Chain(components)
    return refit if _rms(_free_run_error(refit, u, y)) <= _rms(_free_run_error(chain, u, y)) else chain


def _contact_branch_start(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], play_rad: float,
                          rounds: int = 5) -> tuple[_Chain, float, float] | None:
    """A start for a play after the chain's free linear block, which was fitted with the play missing and
    has absorbed part of it.

    On a contact branch of eq. (2) of Cerone et al. (2009) (unit slopes) the play's input is known from its
    output: x_t = y_t + c_r on the right branch, y_t - c_l on the left one; inside the play it is not.
    Alternate ``rounds`` times, from half-widths ``play_rad``: simulate the play on the linear block's
    output x^ to find which samples are on a branch; set c_r, c_l to the mean of x^ - y and y - x^ over
    those samples (in the first round only their sum, split evenly); refit the linear block by output
    error (:func:`_output_error_fit`) to x^ moved into [y_t - c_l, y_t + c_r], where the play's input must
    lie. Returns the chain with the refitted linear block and (c_l, c_r), or None when the chain does not
    end in its free linear block.
    """
    kinds = [c.kind for c in chain.components]
    if not kinds or kinds[-1] != "linear":
        return None
    linear = chain.components[-1]
    before = chain.components[:-1]
    inner = PlantModel(tuple(_build(c, c.values) for c in before)).simulate(u) if before else u
    block = _build(linear, linear.values)
    assert isinstance(block, LinearBlock)
    c_l = c_r = play_rad
    for round_index in range(rounds):
        x = block.apply(inner)
        w = OutputBacklash(m_l=1.0, c_l=max(c_l, 1e-9), m_r=1.0, c_r=max(c_r, 1e-9)).apply(x)
        right = np.abs(w - (x - c_r)) < 1e-12
        left = np.abs(w - (x + c_l)) < 1e-12
        if np.any(right):
            c_r = float(np.mean(x[right] - y[right]))
        if np.any(left):
            c_l = float(np.mean(y[left] - x[left]))
        if round_index == 0:
            # the start model's bias shifts both means by the same amount in opposite directions: only the
            # width c_l + c_r is known yet, so begin centred and let the refits find the asymmetry
            c_l = c_r = max(0.5 * (c_l + c_r), 0.0)
        c_l, c_r = max(c_l, 0.0), max(c_r, 0.0)
        recovered = np.clip(x, y - c_l, y + c_r)  # x within the play around the measured output
        try:
            a, b = _output_error_fit(inner, recovered, block.a, linear.nk, len(linear.values) - linear.na)
        except np.linalg.LinAlgError:
            return None
        block = LinearBlock(a=a, b=b, sample_period_s=linear.sample_period_s)
    return _Chain([*before, _linear_component(block)]), c_l, c_r


def _output_error_fit(u: NDArray[np.float64], y: NDArray[np.float64], a: tuple[float, ...], delay: int,
                      numerator_terms: int, max_evaluations: int = 60) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Output-error fit of y_t = B(q^-1)/A(q^-1) u_t (eq. (1) of Cerone et al. 2009) from the denominator
    ``a``, by variable projection: for a given A the error is linear in B (least squares on u filtered by
    q^-k / A, k = ``delay`` .. ``delay + numerator_terms - 1``), so only A is searched. Returns a and b (with
    ``delay`` leading zeros)."""

    def solve(a_values: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        denominator = (1.0, *a_values)
        phi = np.column_stack([lfilter([0.0] * (delay + j) + [1.0], denominator, u) for j in range(numerator_terms)])
        theta, *_ = np.linalg.lstsq(phi, y, rcond=None)
        return theta, y - phi @ theta

    def residual(a_values: NDArray[np.float64]) -> NDArray[np.float64]:
        if np.any(np.abs(np.roots((1.0, *a_values))) >= 0.9999):
            return np.full(y.size, _BIG / math.sqrt(y.size))
        return solve(a_values)[1]

    with np.errstate(all="ignore"):
        fit = optimize.least_squares(residual, np.array(a, dtype=float), method="trf", diff_step=_LINEAR_DIFF_STEP,
                                     max_nfev=max_evaluations)
    theta, _ = solve(fit.x)
    return tuple(float(v) for v in fit.x), (0.0,) * delay + tuple(float(v) for v in theta)


def _refine_delays(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], reach: int = 5) -> _Chain:
    """Re-search every integer delay already in the chain within +-``reach`` samples (a delay found before
    a second effect was added absorbs part of that effect's lag)."""
    for index, component in enumerate(chain.components):
        if component.kind != "delay":
            continue
        current = int(round(component.values[0]))
        options = []
        for d in range(max(0, current - reach), current + reach + 1):
            components = list(chain.components)
            components[index] = _Component("delay", (float(d),))
            options.append(_Chain(components))
        costs = [_rms(_free_run_error(option, u, y)) for option in options]
        chain = options[int(np.argmin(costs))]
    return chain


def _start_chain(model: PlantModel | None, linear: LinearBlock | None, order: int) -> _Chain:
    if model is None:
        assert linear is not None
        return _Chain([_linear_component(_raised_order(linear, order))])
    return _Chain([_Component("fixed", block=block) for block in model.blocks])


def diagnose_model(command_rad: ArrayLike, angle_rad: ArrayLike, noise_bound_rad: float,
                   sample_period_s: float, model: PlantModel | None = None, *,
                   estimation_fraction: float = ESTIMATION_FRACTION, candidates: Sequence[str] = EFFECT_NAMES,
                   max_effects: int = 3, complexity_penalty: float = 0.03, min_reduction: float = 0.15,
                   consistent_fraction: float = 0.01, max_delay_samples: int = 40,
                   max_evaluations: int = 40,
                   progress: Callable[[str], None] | None = None) -> DiscrepancyResult:
    """Run the model-discrepancy workflow of issue 6 (steps 1-5 of the module docstring).

    Parameters
    ----------
    command_rad, angle_rad
        Measured input u_t and output y_t (rad), one record.
    noise_bound_rad
        delta: bound on the measurement error, |e_t| <= delta (include the encoder's half count).
    sample_period_s
        T.
    model
        The user's model; None fits the best low-order linear model (:func:`fit_linear_model`), whose
        coefficients are then refitted together with every effect.
    estimation_fraction
        The first fraction of the record is the estimation segment, the rest the validation segment.
    candidates
        Effect names to try (default all of :data:`EFFECT_NAMES`).
    max_effects
        Stop after this many effects.
    complexity_penalty
        A candidate's penalised gap is g_after (1 + penalty * n_parameters).
    min_reduction
        A candidate is kept only if g_after (1 + penalty n) <= (1 - min_reduction) g_before.
    consistent_fraction
        The model is consistent with the noise bound when at most this fraction of validation samples is
        falsified.
    max_delay_samples
        Longest delay tried.
    max_evaluations
        Function evaluations per least-squares polish.
    """
    u = as_signal("command_rad", command_rad, min_samples=50)
    y = as_signal("angle_rad", angle_rad, min_samples=50)
    same_length(command_rad=u, angle_rad=y)
    delta = positive("noise_bound_rad", noise_bound_rad)
    period = positive("sample_period_s", sample_period_s)
    if not 0.2 <= estimation_fraction <= 0.9:
        raise InvalidInputError(f"estimation_fraction: expected 0.2 .. 0.9, got {estimation_fraction!r}")
    unknown = [name for name in candidates if name not in EFFECT_NAMES]
    if unknown:
        raise InvalidInputError(f"candidates: unknown effect {unknown[0]!r}; expected some of {', '.join(EFFECT_NAMES)}")
    if model is not None and not isinstance(model, PlantModel):
        raise InvalidInputError(f"model: expected a PlantModel or None, got {type(model).__name__}")
    if model is not None and model.sample_period_s is not None:
        if abs(model.sample_period_s - period) > 1e-3 * period:
            raise InvalidInputError(
                f"sample_period_s: the data are sampled every {period:g} s, the model every {model.sample_period_s:g} s")
        period = model.sample_period_s  # the blocks added must carry exactly the model's period
    varying("command_rad", u, "record a step or PRBS experiment (configs/experiments/prbs.toml) to compare a "
                              "model with")
    n_est = int(round(estimation_fraction * u.size))
    say = progress or (lambda _message: None)

    linear_fit = None
    if model is None:
        linear_fit = fit_linear_model(u, y, period, n_est, max_evaluations=max_evaluations)
        start_model = PlantModel((linear_fit.block,))
        say(f"start: linear model of order {linear_fit.order}")
    else:
        start_model = model
    chain = _start_chain(model, linear_fit.block if linear_fit else None, 2)
    initial = disagreement(start_model, u, y, delta, n_est)
    current = initial
    steps: list[DiscrepancyStep] = []
    remaining = [name for name in candidates]
    while len(steps) < max_effects and current.falsified_fraction > consistent_fraction and remaining:
        if steps and chain.vector().size:
            # the same structure refitted at least as long as the candidates will be: the baseline they must
            # beat (a further effect must earn its place by its physics, not by the extra polishing it brings)
            baseline = _polish(_refine_delays(chain, u[:n_est], y[:n_est]), u[:n_est], y[:n_est],
                               _BASELINE_EFFORT * max_evaluations)
            refitted = disagreement(baseline.model(), u, y, delta, n_est)
            if refitted.gap_rad < current.gap_rad:
                chain, current = baseline, refitted
                if current.falsified_fraction <= consistent_fraction:
                    break
        scores = signature_scores(u, y, current.simulated_rad, delta, period)
        tried = []
        for kind in remaining:
            candidate = _try_effect(kind, chain, u, y, n_est, delta, period, current.residual_rad, scores,
                                    max_delay_samples, max_evaluations)
            say(f"  {kind}: validated gap {candidate.gap_rad:.3g} rad")
            if not EFFECTS[kind].vanished(candidate.block, delta):
                tried.append(candidate)
        if not tried:
            break
        penalised = {c.kind: c.gap_rad * (1.0 + complexity_penalty * EFFECTS[c.kind].free_parameters) for c in tried}
        best = min(tried, key=lambda c: penalised[c.kind])
        best = _prefer_within_family(best, tried, penalised, current.gap_rad)
        if penalised[best.kind] > (1.0 - min_reduction) * current.gap_rad:
            break
        polished = _polish(_refine_delays(best.chain, u[:n_est], y[:n_est]), u[:n_est], y[:n_est], max_evaluations)
        if _rms((y - polished.model().simulate(u))[n_est:]) <= best.gap_rad:
            best = _Candidate(best.kind, polished, best.gap_rad, _build(polished.components[best.index],
                                                                       polished.components[best.index].values), best.index)
        after = disagreement(best.chain.model(), u, y, delta, n_est)
        evidence: dict[str, Any] = {
            "signature_scores": {name: score.score for name, score in scores.items()},
            "signature_details": {name: dict(score.details) for name, score in scores.items()},
            "candidate_gaps_rad": {c.kind: c.gap_rad for c in tried},
        }
        steps.append(DiscrepancyStep(
            effect=best.kind, parameters=_parameters(best.kind, best.block), evidence=evidence,
            gap_before_rad=current.gap_rad, gap_after_rad=after.gap_rad,
            falsified_fraction_before=current.falsified_fraction, falsified_fraction_after=after.falsified_fraction,
            model=best.chain.model(),
        ))
        say(f"added {best.kind}: gap {current.gap_rad:.3g} -> {after.gap_rad:.3g} rad")
        chain, current = best.chain, after
        remaining = [name for name in remaining if name != best.kind]
    final_model = chain.model() if steps else start_model
    consistent = current.falsified_fraction <= consistent_fraction
    if consistent:
        unexplained = "the model is consistent with the noise bound on the validation segment"
    else:
        unexplained = (
            f"{100 * current.falsified_fraction:.1f} % of validation samples still exceed the noise bound "
            f"(gap {current.gap_rad:.3g} rad against a bound of {delta:.3g} rad) and none of the candidate "
            "effects lowers the validated gap further: what is left is unexplained"
        )
    return DiscrepancyResult(
        steps=tuple(steps), start_model=start_model, final_model=final_model, initial=initial, final=current,
        consistent=consistent, unexplained=unexplained, estimation_samples=n_est, noise_bound_rad=delta,
        linear_fit=linear_fit,
    )


STICTION_RATIO = 1.15
"""Friction has real stiction when its breakaway twist exceeds the sliding one by this factor; without it
(breakaway = sliding) Coulomb friction is the same map as a symmetric backlash with unit slopes."""

FRICTION_CLEARLY_BETTER = 0.8
"""Friction with stiction must fit the estimation segment to this fraction of backlash's error to be named
over backlash (the two fits differ only through the stiction)."""

FRICTION_MIN_HALVING = 0.5
"""... and bring the validated gap to at most this fraction of the gap before."""

FAMILY_TIE = 1.05
"""Friction that wins the validated gap without real stiction gives way to backlash when backlash's penalised
gap is within this factor of friction's (the simpler, equivalent map)."""


def _prefer_within_family(best: _Candidate, tried: Sequence[_Candidate], penalised: dict[str, float],
                          gap_before_rad: float) -> _Candidate:
    """Backlash and Coulomb friction are one family (``"hysteresis"`` in the catalogue: hysteresis after the
    drive); decide between them.

    Friction without stiction is the same map as a symmetric backlash with unit slopes, so friction is named
    only if its stiction is real (:data:`STICTION_RATIO`) and it fits the estimation segment clearly better
    (:data:`FRICTION_CLEARLY_BETTER`). Conversely, a stick-slip model's free run is very sensitive to its
    thresholds (where the load sticks depends on the whole history), so on the validation segment backlash
    can look better although friction is the effect; when backlash wins the validated gap but friction with
    real stiction fits the estimation segment clearly better and still halves the gap
    (:data:`FRICTION_MIN_HALVING`), friction is named.
    """
    by_kind = {c.kind: c for c in tried}
    backlash, friction = by_kind.get("backlash"), by_kind.get("coulomb_friction")
    if best.kind not in ("backlash", "coulomb_friction") or backlash is None or friction is None:
        return best
    assert isinstance(friction.block, CoulombFriction)
    stiction = friction.block.breakaway_torque_nm > STICTION_RATIO * friction.block.coulomb_torque_nm
    clearly_better = friction.estimation_rms_rad < FRICTION_CLEARLY_BETTER * backlash.estimation_rms_rad
    if stiction and clearly_better and friction.gap_rad <= FRICTION_MIN_HALVING * gap_before_rad:
        return friction
    if best.kind == "coulomb_friction" and not (stiction and clearly_better) \
            and penalised["backlash"] <= FAMILY_TIE * penalised["coulomb_friction"]:
        return backlash
    return best
