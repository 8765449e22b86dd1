"""Step 3 of the workflow, the candidates: which effects of the catalogue (:mod:`identify.effect_catalogue`)
are tried, and where each goes into the model (its placement: before or after the linear dynamics, at the
end, or inside a drive train that replaces the linear block, :func:`drive_train_like`). A
:class:`_Candidate` is one effect fitted into the model (:mod:`.fit` makes it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from identify.drive_train import DriveTrain
from identify.drive_train_effects import reference_train
from identify.effect_catalogue import EFFECTS, effect
from identify.plant_blocks import Block, LinearBlock, PlantModel, Resonance
from identify.validation import InvalidInputError

from identify.model_discrepancy.chain import _Chain, _Component, _build, _train, _without
from identify.model_discrepancy.thresholds import (
    FAILED_RUN_ERROR_RAD,
    LOOP_BANDWIDTH_NYQUIST_SHARE,
    LOOP_DAMPING_RANGE,
    LOOP_START_FACTORS,
    SHAFT_MODE_MAX_DAMPING,
    SHAFT_TRAIN_ERROR_SHARE,
    SHAFT_TRAIN_LOAD_INERTIA_STARTS,
    SPLIT_LOAD_SHARES,
    VANISHED_PEAK_NOISE_BOUNDS,
)


def _candidate_names(candidates: Sequence[str], model: PlantModel | None) -> tuple[str, ...]:
    """The candidates to try: a fitted linear start model has a free static gain, which absorbs any scale
    error, so an effect that needs a given model is not identifiable against it (docs/methods/model_discrepancy.md: a gain error can
    only be named against a given model); an effect inside the shaft needs a model with a compliant shaft
    (:func:`_has_shaft`)."""
    shaft = model is not None and _has_shaft(model)
    return tuple(name for name in candidates
                 if (model is not None or not EFFECTS[name].needs_given_model) and (shaft or not EFFECTS[name].needs_shaft))


def _has_shaft(model: PlantModel) -> bool:
    """The model holds a compliant shaft: a drive train of finite stiffness, or a linear block with a shaft
    mode (a lightly damped pole pair besides its loop, :func:`_shaft_mode`)."""
    return any((isinstance(block, DriveTrain) and not block.rigid)
               or (isinstance(block, LinearBlock) and _shaft_mode(block) is not None) for block in model.blocks)


def _insert_index(chain: _Chain, kind: str) -> int:
    """Where an effect goes (its catalogue placement): ``input`` before the first linear component,
    ``output`` after the last linear/resonance component, ``end`` at the very end; ``dynamics`` at the drive
    train (the chain's ``drive_train`` component, or the fixed drive train of a given model), else at the
    first linear component, which :func:`_dynamics_chain` replaces with a drive train; -1 when the chain
    has neither (a model without linear dynamics: no dynamics effect can go in)."""
    linear = [i for i, c in enumerate(chain.components)
              if c.kind in ("linear", "drive_train") or (c.kind in EFFECTS and EFFECTS[c.kind].linear_dynamics)
              or isinstance(c.block, (LinearBlock, Resonance, DriveTrain))]
    placement = effect(kind).placement
    if placement == "dynamics":
        trains = [i for i, c in enumerate(chain.components) if c.kind == "drive_train" or isinstance(c.block, DriveTrain)]
        plain = [i for i, c in enumerate(chain.components) if c.kind == "linear" or isinstance(c.block, LinearBlock)]
        return (trains or plain or [-1])[0]
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
    validation_error_rad: NDArray[np.float64] | None = None


def _dynamics_chain(chain: _Chain, index: int, u: NDArray[np.float64]) -> tuple[_Chain, DriveTrain]:
    """The chain with a ``drive_train`` component at ``index`` (catalogue placement ``dynamics``) and the
    train the effect goes into: that component if there is one; a given model's fixed drive train made a
    component (loop fixed); or the linear component replaced by the drive train of the same response
    (:func:`drive_train_like`; loop free again in the joint fit when the linear block was free, fixed
    when it was the given model's; a two-mass train keeps its fitted shaft either way)."""
    component = chain.components[index]
    if component.kind == "drive_train":
        train = _build(component, component.values)
        assert isinstance(train, DriveTrain)
        return chain, train
    if isinstance(component.block, DriveTrain):
        holder = _Component("drive_train", (), component.block, component.block.sample_period_s)
    else:
        linear = _build(component, component.values)
        assert isinstance(linear, LinearBlock)
        before = chain.components[:index]
        inner = PlantModel(tuple(_build(c, c.values) for c in before)).simulate(u) if before else u
        fitted = drive_train_like(linear, inner)
        if component.kind == "linear":
            holder = _Component("drive_train", (fitted.position_loop_bandwidth_hz, fitted.position_loop_damping_ratio),
                                fitted, linear.sample_period_s, loop_free=True)
        else:
            holder = _Component("drive_train", (), fitted, linear.sample_period_s,
                                stands_for=None if fitted.rigid else linear)
    components = list(chain.components)
    components[index] = holder
    train = _build(holder, holder.values)
    assert isinstance(train, DriveTrain)
    return _Chain(components), train


def _loop_starts(train: DriveTrain) -> list[tuple[float, float]]:
    low, high = LOOP_DAMPING_RANGE
    return [(f * train.position_loop_bandwidth_hz, min(max(z * train.position_loop_damping_ratio, low), high))
            for f, z in LOOP_START_FACTORS]


def _with_loop(chain: _Chain, index: int, loop: tuple[float, float]) -> _Chain:
    components = list(chain.components)
    holder = components[index]
    components[index] = replace(holder, values=tuple(loop) + holder.values[2:])
    return _Chain(components)


_TRAIN_CACHE: dict[tuple[Any, ...], DriveTrain] = {}


def drive_train_like(block: LinearBlock, input_rad: NDArray[np.float64]) -> DriveTrain:
    """The drive train the dynamics effects go into, of the same response as ``block`` on ``input_rad``:
    the rigid train (:func:`rigid_train_like`), or, when the block has a lightly damped pole pair besides
    its loop (a shaft mode), the two-mass train (:func:`two_mass_train_like`) if its free run is within
    :data:`SHAFT_TRAIN_ERROR_SHARE` of the rigid train's error of the block's. A friction or a play fitted
    into a rigid train of a block with a shaft mode has to stand in for the mode as well."""
    rigid = rigid_train_like(block, input_rad)
    split = _shaft_mode(block)
    if split is None:
        return rigid
    shaft = two_mass_train_like(block, input_rad, *split)
    target = block.apply(input_rad)
    rigid_error = float(np.sqrt(np.mean((rigid.apply(input_rad) - target) ** 2)))
    shaft_error = float(np.sqrt(np.mean((shaft.apply(input_rad) - target) ** 2)))
    return shaft if shaft_error <= SHAFT_TRAIN_ERROR_SHARE * rigid_error else rigid


def _continuous_poles(block: LinearBlock) -> NDArray[np.complex128]:
    """The block's poles as s = ln(z) / T (poles at the origin of z, pure delays, left out), slowest first."""
    poles = np.roots((1.0, *block.a)) if block.a else np.zeros(0)
    poles = poles[np.abs(poles) > 1e-9]
    continuous = np.log(poles.astype(complex)) / block.sample_period_s
    return continuous[np.argsort(np.abs(continuous))]


def _loop_start(continuous: NDArray[np.complex128], period: float) -> tuple[float, float]:
    """A position loop's bandwidth f_n and damping zeta from the slowest poles of ``continuous`` (complex
    pair: omega_n = |s|, zeta = -Re s / |s|; two real: omega_n = sqrt(s_1 s_2), zeta = (s_1 + s_2) /
    (2 omega_n); one real pole s: omega_n = 2|s|, zeta = 1, the critically damped pair of the same rise),
    within the fitted loop's range."""
    continuous = continuous[:2]
    if continuous.size == 2:
        natural = float(np.sqrt(np.abs(continuous[0] * continuous[1])))
        damping = float(-np.real(continuous.sum()) / (2.0 * natural)) if natural > 0 else 1.0
    elif continuous.size == 1:
        natural, damping = 2.0 * float(abs(continuous[0])), 1.0
    else:
        natural, damping = 2.0 * math.pi * 0.1 / period, 1.0
    nyquist = 0.5 / period
    return (min(max(natural / (2.0 * math.pi), 1e-3 * nyquist), LOOP_BANDWIDTH_NYQUIST_SHARE * nyquist),
            min(max(damping, LOOP_DAMPING_RANGE[0]), LOOP_DAMPING_RANGE[1]))


def _shaft_mode(block: LinearBlock) -> tuple[tuple[float, float], complex] | None:
    """The loop's start and the shaft mode's pole s (Im s > 0) when the block has a complex pair of damping
    ratio below :data:`SHAFT_MODE_MAX_DAMPING` and at least two poles besides it (the loop); else None."""
    continuous = _continuous_poles(block)
    pairs = [s for s in continuous if s.imag > 0 and -s.real / abs(s) < SHAFT_MODE_MAX_DAMPING]
    if not pairs or continuous.size < 4:
        return None
    mode = min(pairs, key=lambda s: -s.real / abs(s))
    rest = np.array([s for s in continuous if abs(s - mode) > 1e-9 * abs(mode) and abs(s - np.conj(mode)) > 1e-9 * abs(mode)])
    return _loop_start(rest, block.sample_period_s), complex(mode)


def rigid_train_like(block: LinearBlock, input_rad: NDArray[np.float64]) -> DriveTrain:
    """The rigid drive train (:func:`identify.drive_train_effects.reference_train`) whose position loop
    reproduces ``block``'s free run on ``input_rad`` best (least squares on bandwidth f_n and damping zeta),
    from the loop of the block's dominant poles (:func:`_loop_start`). The same block and input give the
    same train (cached: every dynamics candidate of a round starts from it)."""
    key = ("rigid", block.a, block.b, block.sample_period_s, input_rad.size, hash(input_rad.tobytes()))
    if key in _TRAIN_CACHE:
        return _TRAIN_CACHE[key]
    period = block.sample_period_s
    start = _loop_start(_continuous_poles(block), period)
    target = block.apply(input_rad)
    base = reference_train(period, *start)

    def error(v: NDArray[np.float64]) -> NDArray[np.float64]:
        try:
            return _train(base, v, (), True).apply(input_rad) - target
        except InvalidInputError:
            return np.full(input_rad.size, FAILED_RUN_ERROR_RAD / math.sqrt(input_rad.size))

    with np.errstate(all="ignore"):
        fit = optimize.least_squares(error, np.array(start), method="trf", diff_step=1e-4, max_nfev=20)
    return _cached(key, _train(base, fit.x, (), True))


def _two_mass_train(period: float, values: Sequence[float]) -> DriveTrain:
    """The normalised two-mass train (total inertia 1, gear 1, the loop on the motor's angle) of
    (f_n, zeta, ln J_l, ln k, ln d, ln d_v)."""
    bandwidth, damping, log_load, log_stiffness, log_damping, log_viscous = values
    load = math.exp(log_load)
    return replace(reference_train(period, abs(bandwidth), abs(damping)), motor_inertia_kg_m2=1.0 - load,
                   load_inertia_kg_m2=load, shaft_stiffness_nm_per_rad=math.exp(log_stiffness),
                   shaft_damping_nm_s_per_rad=math.exp(log_damping),
                   viscous_friction_nm_s_per_rad=math.exp(log_viscous))


def two_mass_train_like(block: LinearBlock, input_rad: NDArray[np.float64], loop: tuple[float, float],
                        mode: complex) -> DriveTrain:
    """The two-mass drive train (a motor J_m under the position loop, a shaft of stiffness k and damping d, a
    load J_l with viscous friction d_v to the frame; J_m + J_l = 1) whose free run reproduces ``block``'s on
    ``input_rad`` best (least squares on f_n, zeta, J_l, k, d and d_v). Starts: the loop's bandwidth and
    damping, and for each load share J_l of :data:`SHAFT_TRAIN_LOAD_INERTIA_STARTS` the shaft of the mode's
    pole s as the load's mode against a motor the loop holds (k = |s|^2 J_l, d = 2 zeta_s |s| J_l with
    zeta_s = -Re s / |s|, a tenth of it as d_v). The load's own friction matters where the block cannot
    show it: while a play is open it alone stops the load (a free load in a play of 5.6 mrad, without it,
    rattled 3 mrad off a record its nominal model plus the play reproduces within 0.8 mrad). Cached as
    :func:`rigid_train_like`."""
    key = ("two_mass", block.a, block.b, block.sample_period_s, input_rad.size, hash(input_rad.tobytes()))
    if key in _TRAIN_CACHE:
        return _TRAIN_CACHE[key]
    period = block.sample_period_s
    target = block.apply(input_rad)
    natural, damping = abs(mode), -mode.real / abs(mode)
    fits = []
    for load in SHAFT_TRAIN_LOAD_INERTIA_STARTS:
        shaft_damping = 2.0 * damping * natural * load
        fits.append(_two_mass_fit(period, input_rad, target, (loop[0], loop[1], math.log(load),
                                                              math.log(natural**2 * load), math.log(shaft_damping),
                                                              math.log(0.1 * shaft_damping)), 80))
    return _cached(key, min(fits, key=lambda fit: fit[0])[1])


def _two_mass_fit(period: float, input_rad: NDArray[np.float64], target: NDArray[np.float64],
                  start: Sequence[float], max_evaluations: int, load: float | None = None) -> tuple[float, DriveTrain]:
    """(cost, train): the least-squares fit of :func:`_two_mass_train`'s (f_n, zeta, ln J_l, ln k, ln d, ln d_v)
    to ``target`` on ``input_rad`` from ``start``, the loop within the fitted loop's range and J_l within 1e-4 to
    0.95; with ``load`` given, J_l is held there and ``start`` has the other five."""
    nyquist = 0.5 / period
    low = [1e-3 * nyquist, LOOP_DAMPING_RANGE[0], math.log(1e-4), -np.inf, -np.inf, -np.inf]
    high = [LOOP_BANDWIDTH_NYQUIST_SHARE * nyquist, LOOP_DAMPING_RANGE[1], math.log(0.95), np.inf, np.inf, np.inf]
    if load is not None:
        del low[2], high[2]

    def values(v: Sequence[float]) -> tuple[float, ...]:
        return tuple(v) if load is None else (v[0], v[1], math.log(load), *v[2:])

    def error(v: NDArray[np.float64]) -> NDArray[np.float64]:
        try:
            return _two_mass_train(period, values(v)).apply(input_rad) - target
        except (InvalidInputError, OverflowError):
            return np.full(input_rad.size, FAILED_RUN_ERROR_RAD / math.sqrt(input_rad.size))

    with np.errstate(all="ignore"):
        fit = optimize.least_squares(error, np.clip(start, low, high), bounds=(low, high), method="trf",
                                     diff_step=1e-4, max_nfev=max_evaluations)
    return float(fit.cost), _two_mass_train(period, values(fit.x))


def split_family(block: LinearBlock) -> tuple[DriveTrain, ...]:
    """Two-mass trains of ``block``'s linear response at the load shares of :data:`SPLIT_LOAD_SHARES`: the poles
    and the zero of a linear model fix five numbers of the six (f_n, zeta, J_l, k, d, d_v), so every split of
    the inertia between the motor and the load has a train of that response, and a play or friction inside the
    train behaves differently in each. Each is fitted (f_n, zeta, k, d, d_v at its J_l) to ``block``'s free run
    on broadband steps (:func:`_split_probe`), from the shaft that gives the block's mode (:func:`_shaft_mode`)
    as the two masses' mode (about 3 s for five shares at 1 kHz; the members need only follow the block within
    a fraction of the noise bound, which :func:`~identify.model_discrepancy.fit._other_splits` checks on the
    record). Empty for a block without a shaft mode. Cached per block."""
    key = ("split", block.a, block.b, block.sample_period_s)
    if key in _FAMILY_CACHE:
        return _FAMILY_CACHE[key]
    split = _shaft_mode(block)
    family: list[DriveTrain] = []
    if split is not None:
        (loop, mode), period = split, block.sample_period_s
        probe = _split_probe(abs(mode), period)
        target = block.apply(probe)
        natural, damping = abs(mode), -mode.real / abs(mode)
        for load in SPLIT_LOAD_SHARES:
            reduced = load * (1.0 - load)  # the two masses' mode: k = omega^2 J_m J_l / (J_m + J_l)
            start = (loop[0], loop[1], math.log(natural ** 2 * reduced), math.log(2.0 * damping * natural * reduced),
                     math.log(0.2 * damping * natural * reduced))
            family.append(_two_mass_fit(period, probe, target, start, 30, load=load)[1])
    if len(_FAMILY_CACHE) > 16:
        _FAMILY_CACHE.clear()
    _FAMILY_CACHE[key] = tuple(family)
    return tuple(family)


_FAMILY_CACHE: dict[tuple[Any, ...], tuple[DriveTrain, ...]] = {}


def _split_probe(natural_rad_per_s: float, period: float) -> NDArray[np.float64]:
    """Broadband steps for :func:`split_family`: 0.05 rad levels held from one sample to two periods of the
    shaft's mode at random (seeded: the same block gives the same family), 2 000 samples."""
    rng = np.random.default_rng(0)
    longest = max(2, int(round(2.0 * 2.0 * math.pi / (natural_rad_per_s * period))))
    return np.repeat(rng.uniform(-0.05, 0.05, 2000), rng.integers(1, longest + 1, 2000))[:2000]


def _cached(key: tuple[Any, ...], train: DriveTrain) -> DriveTrain:
    if len(_TRAIN_CACHE) > 64:
        _TRAIN_CACHE.clear()
    _TRAIN_CACHE[key] = train
    return train


def _merged(chain: _Chain, index: int, kind: str, values: Sequence[float]) -> _Chain:
    """``chain`` with dynamics effect ``kind`` of free ``values`` merged into its drive-train component at
    ``index`` (:func:`_dynamics_chain` made it one)."""
    components = list(chain.components)
    holder = components[index]
    components[index] = replace(holder, values=holder.values + tuple(float(v) for v in values),
                                effects=holder.effects + (kind,))
    return _Chain(components)


def _without_effect(chain: _Chain, kind: str) -> _Chain | None:
    """``chain`` with effect ``kind`` taken out: its own component removed, or, for a dynamics effect, its
    values and name removed from the drive train (the train's field then keeps the start's value, for a
    rigid train the neutral one); None when the chain does not hold it."""
    components = list(chain.components)
    for i, component in enumerate(components):
        if component.kind == kind:
            return _Chain(components[:i] + components[i + 1:])
        if component.kind == "drive_train" and kind in component.effects:
            components[i] = _without(component, kind)
            return _Chain(components)
    return None


def _vanished(candidate: _Candidate, u: NDArray[np.float64], delta: float) -> bool:
    """Whether the candidate's fitted effect is nothing on this record: the catalogue's size test says so
    (``vanished``) and, for an effect in the drive train's dynamics, the record agrees: taking it out of the
    fitted model moves its free run by less than :data:`VANISHED_PEAK_NOISE_BOUNDS` noise bounds on every
    sample. A dynamics effect's size test reads a static proxy (a friction's static error, a weight's sag); what
    it does to a moving record can be more (a friction's lag on a chirp, with a static error under the bound).
    The size tests of the other effects are their effect on the signal itself (an output backlash's width, a
    gain's scale)."""
    entry = EFFECTS[candidate.kind]
    if not entry.vanished(candidate.block, delta):
        return False
    if entry.placement != "dynamics":
        return True
    without = _without_effect(candidate.chain, candidate.kind)
    if without is None:
        return True
    try:
        moved = float(np.max(np.abs(candidate.chain.model().simulate(u) - without.model().simulate(u))))
    except InvalidInputError:
        return True
    return not moved >= VANISHED_PEAK_NOISE_BOUNDS * delta
