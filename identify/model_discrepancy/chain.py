"""The model every step of the workflow simulates and fits: a chain of components (fixed blocks, a linear block
with free coefficients, effects from the catalogue with free parameters, a drive train holding dynamics
effects) with one flat vector of free parameters, its error on a record (its free run, or its restarted run:
:mod:`.comparison`), and the least-squares polish of that vector (:func:`_polish`).

Shared by the steps: the start model (:mod:`.start_model`) is a chain, a candidate (:mod:`.candidates`,
:mod:`.fit`) is a chain with one effect more, and the intervals (:mod:`.intervals`) move its parameters.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from identify.drive_train import DriveTrain
from identify.effect_catalogue import EFFECTS, effect
from identify.plant_blocks import Block, LinearBlock, PlantModel
from identify.validation import InvalidInputError

from identify.model_discrepancy.comparison import simulated

from identify.model_discrepancy.thresholds import (
    EFFECT_DIFF_STEP,
    FAILED_RUN_ERROR_RAD,
    LINEAR_DIFF_STEP,
    LOOP_BANDWIDTH_NYQUIST_SHARE,
    LOOP_DAMPING_RANGE,
)


@dataclass(frozen=True)
class _Component:
    """One link of the chain: a fixed block, or a named effect with free parameters, or a drive train
    holding dynamics effects (kind ``"drive_train"``: ``block`` the train they go into, ``effects`` their
    names in the order of ``values``, led by the loop's bandwidth and damping when ``loop_free``; ``stands_for``:
    the given linear model a two-mass train was made from, which does not fix how the train's inertia is split
    between the motor and the load)."""

    kind: str  # "fixed", "linear", "drive_train", or an effect name
    values: tuple[float, ...] = ()
    block: Block | None = None
    sample_period_s: float = 1.0
    na: int = 0
    nk: int = 0  # leading zeros of B (pure delay of a linear component), not free
    effects: tuple[str, ...] = ()
    loop_free: bool = False
    stands_for: LinearBlock | None = None

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
    if kind == "drive_train":
        assert isinstance(component.block, DriveTrain)
        return _train(component.block, v, component.effects, component.loop_free)
    return effect(kind).build(v, component.sample_period_s)


def _train(base: DriveTrain, values: Sequence[float], effects: Sequence[str], loop_free: bool) -> DriveTrain:
    """``base`` with the loop (when ``loop_free``: bandwidth and damping, the first two values) and then each
    dynamics effect's fields set from ``values`` (catalogue ``train_fields``)."""
    train, k = base, 0
    if loop_free:
        nyquist = 0.5 / base.sample_period_s
        train = replace(train, position_loop_bandwidth_hz=min(max(abs(values[0]), 1e-3 * nyquist),
                                                               LOOP_BANDWIDTH_NYQUIST_SHARE * nyquist),
                        position_loop_damping_ratio=min(max(abs(values[1]), LOOP_DAMPING_RANGE[0]),
                                                        LOOP_DAMPING_RANGE[1]))
        k = 2
    for name in effects:
        entry = EFFECTS[name]
        train = entry.in_train(values[k:k + entry.free_parameters], train)
        k += entry.free_parameters
    return train


def _effect_block(chain: "_Chain", kind: str) -> Block | None:
    """The block that holds effect ``kind`` in ``chain`` (its own component, or the drive train it was merged
    into), or None."""
    for component in chain.components:
        if component.kind == kind or (component.kind == "drive_train" and kind in component.effects):
            return _build(component, component.values)
    return None


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

    def offset(self, index: int) -> int:
        """Where the values of component ``index`` start in :meth:`vector`."""
        return sum(len(c.values) for c in self.components[:index] if c.free)

    def with_vector(self, theta: Sequence[float]) -> _Chain:
        out, k = [], 0
        for c in self.components:
            if c.free:
                n = len(c.values)
                out.append(replace(c, values=tuple(float(x) for x in theta[k:k + n])))
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


def _measured_error(y: NDArray[np.float64], simulated: NDArray[np.float64]) -> NDArray[np.float64]:
    """y_t - y^_t where y_t was measured, 0 where it is missing (NaN: a LOST or unusable sample), so that a
    sample not measured counts neither against a model nor for it: it drops out of every least-squares cost,
    and every comparison of two models on the same samples (their ratio of RMS errors) is unchanged by it."""
    with np.errstate(invalid="ignore"):
        return np.where(np.isnan(y), 0.0, y - simulated)


def _bridged(y: NDArray[np.float64]) -> NDArray[np.float64]:
    """``y`` with its missing samples (NaN) interpolated linearly between the measured ones: for equation-error
    start values only (an ARX fit filters y, where one NaN would spread), never for a residual."""
    missing = np.isnan(y)
    if not np.any(missing):
        return y
    index = np.arange(y.size)
    return np.where(missing, np.interp(index, index[~missing], y[~missing]), y)


def _run_error(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """y - y^ of ``chain`` under the comparison in force (:func:`.comparison.simulated`: the free run, or the run
    restarted from the measured angle); a run that fails or diverges gives a huge error on every sample."""
    if not chain.linear_stable():
        return np.full(y.size, FAILED_RUN_ERROR_RAD / math.sqrt(y.size))
    try:
        output = simulated(chain.model(), u, y)
    except (InvalidInputError, ValueError, OverflowError, FloatingPointError):
        return np.full(y.size, FAILED_RUN_ERROR_RAD / math.sqrt(y.size))
    if not np.all(np.isfinite(output)):
        return np.full(y.size, FAILED_RUN_ERROR_RAD / math.sqrt(y.size))
    return _measured_error(y, output)


def _rms(values: NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(values * values)))


def _polish(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], max_evaluations: int,
            kinds: frozenset[str] | None = None, samples: NDArray[np.bool_] | None = None,
            held: Sequence[int] = ()) -> _Chain:
    """Least-squares fit of the free parameters of ``chain`` (only of components whose kind is in ``kinds``
    if given; never the entries ``held`` of :meth:`_Chain.vector`) to its error on (u, y) (:func:`_run_error`; only
    on the ``samples`` marked True if given: the run covers the whole record, the cost only those samples)."""
    theta_all = chain.vector()
    if theta_all.size == 0:
        return chain
    mask = np.concatenate([np.full(len(c.values), kinds is None or c.kind in kinds)
                           for c in chain.components if c.free])
    mask[list(held)] = False
    if not np.any(mask):
        return chain
    theta0 = theta_all[mask]
    scale = np.maximum(np.abs(theta0), 1e-6)
    steps = np.concatenate([np.full(len(c.values), LINEAR_DIFF_STEP if c.kind == "linear" else EFFECT_DIFF_STEP)
                            for c in chain.components if c.free])[mask]

    def expand(z: NDArray[np.float64]) -> _Chain:
        theta = theta_all.copy()
        theta[mask] = z * scale
        return chain.with_vector(theta)

    def error(option: _Chain) -> NDArray[np.float64]:
        full = _run_error(option, u, y)
        return full if samples is None else full[samples]

    with np.errstate(all="ignore"):
        fit = optimize.least_squares(lambda z: error(expand(z)), theta0 / scale,
                                     method="trf", diff_step=steps, max_nfev=max_evaluations)
    candidate = expand(fit.x)
    if _rms(error(candidate)) <= _rms(error(chain)):
        return candidate
    return chain


def _effect_parameters(chain: _Chain) -> dict[str, dict[str, float]]:
    """The public parameters of every effect of a fitted chain; an effect inside a drive train reports what
    it adds to the train without it (catalogue ``report_in_train``)."""
    out: dict[str, dict[str, float]] = {}
    for component in chain.components:
        if component.kind == "drive_train":
            train = _build(component, component.values)
            for kind in component.effects:
                base = _without(component, kind)
                parameters = effect(kind).report_in_train(train, _build(base, base.values))
                out[kind] = {key: float(value) for key, value in parameters.items()}
        elif component.kind in EFFECTS:
            out[component.kind] = _parameters(component.kind, _build(component, component.values))
    return out


def _without(component: _Component, kind: str) -> _Component:
    """Drive-train ``component`` with dynamics effect ``kind``'s values and name taken out (its train's field
    then keeps the start's value)."""
    k = 2 if component.loop_free else 0
    for name in component.effects:
        n = EFFECTS[name].free_parameters
        if name == kind:
            return replace(component, values=component.values[:k] + component.values[k + n:],
                           effects=tuple(e for e in component.effects if e != kind))
        k += n
    raise ValueError(f"{kind} is not in this drive train ({', '.join(component.effects)})")
