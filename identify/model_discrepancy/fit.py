"""Step 4 of the workflow, the fit: one candidate effect added to the model and fitted on the estimation
segment (:func:`_try_effect`: catalogue guesses ranked, the best polished, loop starts for a drive train,
contact-branch starts for a play, the breakaway scanned for stick-slip, delays walked), the fit of an inner
twin (:func:`_compound`), the baseline a further effect must beat (:func:`_baseline_refit`), and the
cross-validation refits that the judgement and the intervals use (:func:`_fold_refit`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from identify.drive_train import DriveTrain
from identify.effect_catalogue import EFFECTS, GuessContext, effect
from identify.effect_signatures import SignatureScore, signature_scores
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel

from identify.model_discrepancy.candidates import (
    _Candidate,
    _dynamics_chain,
    _insert_index,
    _loop_starts,
    _merged,
    _with_loop,
    split_family,
)
from identify.model_discrepancy.comparison import simulated
from identify.model_discrepancy.chain import (
    _Chain,
    _Component,
    _bridged,
    _build,
    _run_error,
    _linear_component,
    _measured_error,
    _polish,
    _rms,
    _train,
)
from identify.model_discrepancy.options import DiagnoseOptions
from identify.model_discrepancy.start_model import _output_error_fit
from identify.model_discrepancy.thresholds import (
    BASELINE_EFFORT,
    BREAKAWAY_SCAN,
    CONTACT_BRANCH_PLAYS,
    CONTACT_BRANCH_ROUNDS,
    DELAY_REFINE_REACH,
    DYNAMICS_EVALUATIONS,
    FAILED_RUN_ERROR_RAD,
    FIT_MAX_SAMPLES,
    FOLDS,
    FOLD_EVALUATIONS,
    LOOP_POLISHED_STARTS,
    LOOP_START_GUESSES,
    REFIT_FOLDS,
    SPLIT_FORM_NOISE_BOUNDS,
    SPLIT_POLISHED_STARTS,
    START_SCREEN_SAMPLES,
    STATIC_FRICTION_SCAN,
    STICK_SLIP_MIN_GAIN,
    STICK_SLIP_ROUNDS,
)


def _try_effect(kind: str, chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], n_est: int,
                delta: float, period: float, residual: NDArray[np.float64], scores: dict[str, SignatureScore],
                max_delay_samples: int, max_evaluations: int,
                forced_starts: Sequence[tuple[float, ...]] = (),
                modes: tuple[tuple[float, float], ...] = ()) -> _Candidate:
    """The candidate of effect ``kind`` added to ``chain``: its catalogue guesses (and, for a dynamics effect
    with a free loop, the loop starts) ranked by the estimation error, the best polished, and each of
    ``forced_starts`` (values of the effect, unranked) polished too; the fit with the lowest estimation error
    is kept, its delays walked (:func:`_walk_delays`); ``modes`` (``start_model.record_modes``) go to the
    guesses. The fit uses the first :func:`_fit_samples` samples of the estimation segment (all of it on a
    record of up to :data:`FIT_MAX_SAMPLES`); its starts are ranked and polished on the first
    :func:`_screen_samples` of them (:data:`START_SCREEN_SAMPLES`), and on a record longer than that the best
    start is polished again on all the fit uses; the candidate's estimation error and validated gap
    (:func:`_judged`) are over the whole segments.

    A hysteresis after the linear block (catalogue ``contact_start``) also polishes the best start of each of
    its contact-branch forms (:func:`_contact_branch_start`; friction has one per breakaway/sliding ratio),
    whether or not it ranks above the best guess: they lead to different minima. From a fitted start on a
    hidden asymmetric backlash (seed 1016, c_l 34.8, c_r 39.6 mrad) the contact-branch starts ranked first
    and polished to a one-sided play (c_r = 0, 20.9 mrad validated) while the best guess polishes to the
    truth (0.61 mrad); on hidden Coulomb friction (seed 1015, breakaway 30.6, sliding 14.5 mrad) the start
    at breakaway = sliding ranked first and stopped at 6.2 mrad, the one at 1.5 times the sliding reaches
    0.65 mrad (the polish cannot move the breakaway). A stick-slip fit ends in :func:`_stick_slip_fit`."""
    index = _insert_index(chain, kind)
    n_fit = _fit_samples(n_est)
    u_est, y_est = u[:n_fit], y[:n_fit]
    n_screen = _screen_samples(n_est)
    u_start, y_start = u[:n_screen], y[:n_screen]
    entry = effect(kind)
    train: DriveTrain | None = None
    splits: list[tuple[_Chain, DriveTrain]] = []
    if entry.placement == "dynamics":
        chain, train = _dynamics_chain(chain, index, u_est)
        splits = [(chain, train), *_other_splits(chain, index, train, u_est, delta)]

    def with_effect(values: tuple[float, ...], base: _Chain = chain) -> _Chain:
        components = list(base.components)
        if entry.placement == "dynamics":  # merged into the drive train
            return _merged(base, index, kind, values)
        else:
            components.insert(index, _Component(kind, tuple(float(v) for v in values), sample_period_s=period))
        return _Chain(components)

    if entry.searched:
        options = [with_effect((d,)) for d in range(1, max_delay_samples + 1)]
    else:
        simulated = np.where(np.isnan(y), _bridged(y), y - residual)  # for the guesses only
        options = [with_effect(g, base) for base, base_train in (splits or [(chain, train)])
                   for g in entry.guesses(GuessContext(u, residual, delta, period, scores, simulated, base_train,
                                                       modes))]
        if entry.placement == "dynamics" and chain.components[index].loop_free and options:
            # the guesses ranked at the start model's loop; the best LOOP_START_GUESSES from every loop start
            costs = [_rms(_run_error(option, u_start, y_start)) for option in options]
            ranked = [options[i] for i in np.argsort(costs)[:LOOP_START_GUESSES]]
            options = [_with_loop(option, index, loop) for option in ranked for loop in _loop_starts(train)]
    options = [_refit_last_linear(option, u_start, y_start) for option in options]
    costs = [_rms(_run_error(option, u_start, y_start)) for option in options]
    if entry.placement == "dynamics" and chain.components[index].loop_free:
        starts = _distinct_loop_starts(options, costs, index, LOOP_POLISHED_STARTS)
    elif len(splits) > 1:
        starts = _best_of_each_split(options, costs, index, SPLIT_POLISHED_STARTS)
    else:
        starts = [options[int(np.argmin(costs))]]
    if entry.contact_start is not None:
        plays = np.geomspace(delta, max(float(np.max(np.abs(residual))), 4.0 * delta), CONTACT_BRANCH_PLAYS)
        forms = [[with_effect(start, refit) for start in entry.contact_start(c_l, c_r)] for refit, c_l, c_r in
                 filter(None, (_contact_branch_start(chain, u_start, y_start, play) for play in plays))]
        for contacts in zip(*forms):  # the best start of each form, over the plays the refits began from
            starts.append(contacts[int(np.argmin([_rms(_run_error(c, u_start, y_start)) for c in contacts]))])
    starts += [with_effect(tuple(values)) for values in forced_starts]
    fits = [_polished_start(start, u_start, y_start, max_evaluations) for start in starts]
    if entry.stick_slip and train is None:
        fits = [_stick_slip_fit(fit, index, u_start, y_start, max_evaluations) for fit in fits]
    best = fits[int(np.argmin([_rms(_run_error(fit, u_start, y_start)) for fit in fits]))]
    if n_screen < n_fit:
        best = _polished_start(best, u_est, y_est, max_evaluations)
    if not entry.searched or not entry.vanished(_build(best.components[index], best.components[index].values),
                                                 delta):  # a delay the held fit found; see _walk_delays
        best = _walk_delays(best, u_est, y_est, _budget(best, max_evaluations), max_delay_samples)
    return _judged(kind, _stick_slip_scanned(best, u_est, y_est), index, u, y, n_est)


def _other_splits(chain: _Chain, index: int, train: DriveTrain, u: NDArray[np.float64],
                  delta: float) -> list[tuple[_Chain, DriveTrain]]:
    """``chain`` with its drive train at ``index`` replaced by each other split of the inertia of the same linear
    response (:func:`split_family`) whose free run on ``u`` stays within :data:`SPLIT_FORM_NOISE_BOUNDS` noise
    bounds of the train's, when the train is a given linear model's two-mass form (``stands_for``); else none.
    A given drive train of the user's keeps its split, and a fitted linear start has its own loop to trade."""
    holder = chain.components[index]
    if holder.stands_for is None or train.rigid:
        return []
    reference = train.apply(u)
    out = []
    for member in split_family(holder.stands_for):
        if np.max(np.abs(member.apply(u) - reference)) <= SPLIT_FORM_NOISE_BOUNDS * delta:
            components = list(chain.components)
            components[index] = replace(holder, block=member)
            out.append((_Chain(components), _train(member, holder.values, holder.effects, holder.loop_free)))
    return out


def _best_of_each_split(options: Sequence[_Chain], costs: Sequence[float], index: int, count: int) -> list[_Chain]:
    """The best-ranked option of each split of the drive train at ``index`` (its ``block``), the ``count``
    best of those."""
    best: dict[int, tuple[float, _Chain]] = {}
    for option, cost in zip(options, costs):
        key = id(option.components[index].block)
        if key not in best or cost < best[key][0]:
            best[key] = (cost, option)
    return [option for _cost, option in sorted(best.values(), key=lambda pair: pair[0])[:count]]


def _screen_samples(n_est: int) -> int:
    """How many of the ``n_est`` estimation samples a candidate's starts are ranked and polished on: the first
    :data:`START_SCREEN_SAMPLES` at most (and at most :func:`_fit_samples`)."""
    return min(_fit_samples(n_est), START_SCREEN_SAMPLES)


def _fit_samples(n_est: int) -> int:
    """How many of the ``n_est`` estimation samples a candidate's fit uses: the first :data:`FIT_MAX_SAMPLES` at
    most."""
    return min(n_est, FIT_MAX_SAMPLES)


def _baseline_refit(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], max_evaluations: int) -> _Chain:
    """``chain`` refitted on the estimation segment (u, y) at :data:`BASELINE_EFFORT` times the candidates'
    effort: its delays re-searched, then everything polished (the baseline a further effect must beat, and
    the model without an effect in :func:`_still_needed`)."""
    return _polish(_refine_delays(chain, u, y), u, y, _budget(chain, BASELINE_EFFORT * max_evaluations))


def _polished_start(start: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], max_evaluations: int) -> _Chain:
    """One start of a candidate fit: its delays re-searched, its linear block polished alone, then everything
    polished (:func:`_polish`) on the estimation segment (u, y)."""
    best = _refine_delays(start, u, y)
    if any(c.kind == "linear" for c in best.components):
        best = _polish(best, u, y, max_evaluations, frozenset({"linear"}))
    return _polish(best, u, y, _budget(best, max_evaluations))


def _distinct_loop_starts(options: Sequence[_Chain], costs: Sequence[float], index: int,
                          count: int) -> list[_Chain]:
    """The ``count`` lowest-cost options whose loops (bandwidth and damping of the drive train at ``index``,
    as built: starts beyond a cap are the same loop) differ from each other's."""
    chosen: list[_Chain] = []
    loops: set[tuple[float, float]] = set()
    for i in np.argsort(costs):
        train = _build(options[int(i)].components[index], options[int(i)].components[index].values)
        assert isinstance(train, DriveTrain)
        loop = (train.position_loop_bandwidth_hz, train.position_loop_damping_ratio)
        if loop not in loops:
            loops.add(loop)
            chosen.append(options[int(i)])
        if len(chosen) == count:
            break
    return chosen


def _budget(chain: _Chain, evaluations: int) -> int:
    """``evaluations``, or at most :data:`DYNAMICS_EVALUATIONS` when the chain holds a drive train."""
    if any(c.kind == "drive_train" for c in chain.components):
        return min(evaluations, DYNAMICS_EVALUATIONS)
    return evaluations


def _best_of(options: Sequence[_Chain], u: NDArray[np.float64], y: NDArray[np.float64],
             samples: NDArray[np.bool_] | None) -> _Chain:
    """The option with the lowest error on (u, y) (:func:`_run_error`; only on the ``samples`` marked True if
    given)."""
    errors = [_run_error(option, u, y) for option in options]
    return options[int(np.argmin([_rms(e if samples is None else e[samples]) for e in errors]))]


def _scan_breakaway(chain: _Chain, index: int, u: NDArray[np.float64], y: NDArray[np.float64],
                    samples: NDArray[np.bool_] | None = None) -> _Chain:
    """Where a stick-slip load sticks depends on the breakaway twist through the whole history, so the
    free-run error is discontinuous in it and a gradient polish leaves it where it started: scan the
    breakaway/sliding ratio 1..3 in steps of 0.05 at the fitted sliding twist and keep the best fit."""
    component = chain.components[index]
    slide = abs(component.values[1])

    def with_ratio(ratio: float) -> _Chain:
        components = list(chain.components)
        components[index] = _Component(component.kind, (ratio * slide, slide), sample_period_s=component.sample_period_s)
        return _Chain(components)

    return _best_of([chain, *(with_ratio(ratio) for ratio in np.linspace(*BREAKAWAY_SCAN))], u, y, samples)


def _stick_slip_fit(chain: _Chain, index: int, u: NDArray[np.float64], y: NDArray[np.float64],
                    max_evaluations: int) -> _Chain:
    """A polished stick-slip fit (friction after the linear block at ``index``) finished by alternating the
    breakaway scan (:func:`_scan_breakaway`) with a polish of everything else (:func:`_polished_start`) while
    the estimation error falls (:data:`STICK_SLIP_ROUNDS`, :data:`STICK_SLIP_MIN_GAIN`).

    The polish cannot move the breakaway (the free run is piecewise constant in it), and the scan holds the
    linear block and the sliding twist where the previous breakaway left them; after a new breakaway both
    move again. From a fitted start the linear block has absorbed part of the friction, and one polish and
    one scan stopped short: hidden Coulomb friction, seed 1004 (breakaway 17.2, sliding 7.1 mrad), ended at
    4.2 mrad validated and load friction was named; three rounds reach 0.51 mrad (the noise level) at
    17.2 and 7.2 mrad; seed 1000 went from 4.1 to 0.67 mrad."""
    best = _scan_breakaway(chain, index, u, y)
    cost = _rms(_run_error(best, u, y))
    for _ in range(STICK_SLIP_ROUNDS - 1):
        option = _scan_breakaway(_polished_start(best, u, y, max_evaluations), index, u, y)
        option_cost = _rms(_run_error(option, u, y))
        if option_cost > (1.0 - STICK_SLIP_MIN_GAIN) * cost:
            break
        best, cost = option, option_cost
    return best


def _scan_static_friction(chain: _Chain, index: int, kind: str, u: NDArray[np.float64],
                          y: NDArray[np.float64], samples: NDArray[np.bool_] | None = None) -> _Chain:
    """:func:`_scan_breakaway` for friction inside a drive train: the breakaway/Coulomb ratio T_s / T_c over
    1..2 in steps of 0.05 at the fitted Coulomb friction (its values are T_c / J, (T_s - T_c) / J, ...)."""
    holder = chain.components[index]
    offset = (2 if holder.loop_free else 0) + sum(EFFECTS[name].free_parameters
                                                 for name in holder.effects[:holder.effects.index(kind)])
    coulomb = abs(holder.values[offset])

    def with_ratio(ratio: float) -> _Chain:
        values = list(holder.values)
        values[offset + 1] = (ratio - 1.0) * coulomb
        components = list(chain.components)
        components[index] = replace(holder, values=tuple(values))
        return _Chain(components)

    return _best_of([chain, *(with_ratio(ratio) for ratio in np.linspace(*STATIC_FRICTION_SCAN))], u, y, samples)


def _stick_slip_scanned(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64],
                        samples: NDArray[np.bool_] | None = None) -> _Chain:
    """``chain`` with the breakaway of every stick-slip effect in it (catalogue ``stick_slip``) scanned
    (:func:`_scan_breakaway`, :func:`_scan_static_friction`), one after the other. Every fit that moves a
    stick-slip effect's neighbours needs it, not only the fit that adds the effect: a gradient polish never
    moves the breakaway, so a friction fitted before a play kept the breakaway it had without the play
    (hidden shaft_play + load_friction records, given the model: T_s / J at the fitted T_c / J in 7 of 20,
    truth 1.3-1.4 times it, and the intervals, refitted from there, missed it)."""
    for index, component in enumerate(chain.components):
        if component.kind == "drive_train":
            for kind in component.effects:
                if EFFECTS[kind].stick_slip:
                    chain = _scan_static_friction(chain, index, kind, u, y, samples)
        elif component.kind in EFFECTS and EFFECTS[component.kind].stick_slip:
            chain = _scan_breakaway(chain, index, u, y, samples)
    return chain


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
    if any(not (kind in EFFECTS and EFFECTS[kind].linear_dynamics) for kind in kinds[index + 1:]):
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
    return refit if _rms(_run_error(refit, u, y)) <= _rms(_run_error(chain, u, y)) else chain


def _contact_branch_start(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], play_rad: float,
                          rounds: int = CONTACT_BRANCH_ROUNDS) -> tuple[_Chain, float, float] | None:
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
        w = OutputBacklash(m_l=1.0, c_l_rad=max(c_l, 1e-9), m_r=1.0, c_r_rad=max(c_r, 1e-9)).apply(x)
        right = np.abs(w - (x - c_r)) < 1e-12
        left = np.abs(w - (x + c_l)) < 1e-12
        measured = ~np.isnan(y)
        right, left = right & measured, left & measured
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


def _refine_delays(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], reach: int = DELAY_REFINE_REACH,
                   samples: NDArray[np.bool_] | None = None) -> _Chain:
    """Re-search every integer delay already in the chain within +-``reach`` samples (a delay found before
    a second effect was added absorbs part of that effect's lag)."""
    for index, component in enumerate(chain.components):
        if not (component.kind in EFFECTS and EFFECTS[component.kind].searched):
            continue
        current = int(round(component.values[0]))
        options = []
        for d in range(max(0, current - reach), current + reach + 1):
            components = list(chain.components)
            components[index] = _Component(component.kind, (float(d),))
            options.append(_Chain(components))
        errors = [_run_error(option, u, y) for option in options]
        costs = [_rms(e if samples is None else e[samples]) for e in errors]
        chain = options[int(np.argmin(costs))]
    return chain


def _walk_delays(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], max_evaluations: int,
                 longest: int) -> _Chain:
    """The profile of the fit over each integer delay of ``chain``: the other free parameters polished
    (:func:`_polish`, ``max_evaluations``) at the delay one sample shorter, or else one longer, and on in
    the direction that lowers the polished estimation error while it does, within 0..``longest`` samples.

    :func:`_refine_delays` moves a delay with the other parameters held, which cannot leave a joint optimum
    of the wrong delay: a delay found before a lagging effect is in absorbs part of its lag, and the effect
    fitted at that delay takes the value that suits it (hidden delay + torque limit, seed 1004: delay 13
    and T/J 12 300 rad/s^2 leave 6.9 mrad on the estimation segment, and no other delay is better at that
    T/J; the true delay 10 with T/J polished to 5 480 rad/s^2 leaves 0.44 mrad, the noise level; on seed
    1003 the first delay is 17 samples, the truth 10).

    :func:`_try_effect` walks a delay already in the chain, and the delay candidate itself (fitted at every
    delay with the rest held) only when that fit found a delay, 1 sample or more. There the walk moves a
    delay the record shows: a torque limit named first, without the delay, is lowered until it lags like
    both, and the delay candidate with that limit held finds 1 sample (seed 1001, truth 4; walked: 4, the
    limit within 2 % and the truth's gap, where unwalked the resonance fitted that lag better and was named
    for it). At 0 samples the candidate is no delay (catalogue ``vanished``): with the rest held the record
    shows no missing lag, and a delay walked in from there only trades against the lag the fitted effects
    already model (a speed limit, the loop's bandwidth). Walking that candidate too split the repetitions of
    one experiment on the real K-Scale servo (sin_time_square kp 16 and 32, after rate_limit + gravity:
    the delay walked from 0 to 2-3 samples lowered the validated gap by 12-40 %, and rate_limit + gravity +
    delay was named on 3 of 8 records, the others ambiguous)."""
    if chain.vector().size == 0:
        return chain

    def at(option: _Chain, index: int, samples: int) -> _Chain:
        components = list(option.components)
        components[index] = replace(components[index], values=(float(samples),))
        return _polish(_Chain(components), u, y, max_evaluations)

    for index, component in enumerate(chain.components):
        if not (component.kind in EFFECTS and EFFECTS[component.kind].searched):
            continue
        start = int(round(component.values[0]))
        cost = _rms(_run_error(chain, u, y))
        for direction in (-1, 1):
            moved = False
            stop = longest + 1 if direction > 0 else -1
            for samples in range(start + direction, stop, direction):
                option = at(chain, index, samples)
                option_cost = _rms(_run_error(option, u, y))
                if option_cost >= cost:
                    break
                chain, cost, moved = option, option_cost, True
            if moved:
                break
    return chain


def _judged(kind: str, chain: _Chain, index: int, u: NDArray[np.float64], y: NDArray[np.float64],
            n_est: int) -> _Candidate:
    """A fitted chain as a :class:`_Candidate` of effect ``kind`` at ``index``: its validated gap and error
    and its estimation error."""
    error = (_measured_error(y, simulated(chain.model(), u, y))[n_est:] if chain.linear_stable()
             else np.full(y.size - n_est, FAILED_RUN_ERROR_RAD))
    error = np.where(np.isfinite(error), error, FAILED_RUN_ERROR_RAD)
    component = chain.components[index]
    return _Candidate(kind, chain, _rms(error), _build(component, component.values), index,
                      _rms(_run_error(chain, u[:n_est], y[:n_est])), error)


def _compound(kinds: Sequence[str], hysteresis: _Candidate, tried: Sequence[_Candidate], chain: _Chain,
              u: NDArray[np.float64], y: NDArray[np.float64], n_est: int, delta: float, period: float,
              options: DiagnoseOptions) -> list[_Candidate]:
    """Dynamics effects ``kinds`` merged into one drive train (the inner twin of the fitted ``hysteresis``,
    catalogue ``inner_twin``): the first as fitted in this round (refitted if it vanished), each further one
    fitted through the ones before (:func:`_try_effect` from the chain so far, its guesses from that chain's
    residual), the values of all of them free in its polish; and all of them started from the hysteresis'
    width (catalogue ``width_starts``). Returns the candidate after each effect; the last one is the compound,
    whichever of the two fits the estimation segment better."""
    by_kind = {c.kind: c for c in tried}

    def fitted(kind: str, base: _Chain, forced: Sequence[tuple[float, ...]] = ()) -> _Candidate:
        output = simulated(base.model(), u, y)
        return _try_effect(kind, base, u, y, n_est, delta, period, _measured_error(y, output),
                           signature_scores(u, y, output, delta, period), options.max_delay_samples,
                           options.max_evaluations, forced)

    parts: list[_Candidate] = []
    for kind in kinds:
        if not parts and kind in by_kind:
            parts.append(by_kind[kind])
        else:
            parts.append(fitted(kind, parts[-1].chain if parts else chain))
    half_widths = EFFECTS[hysteresis.kind].half_widths
    width = sum(half_widths(hysteresis.block)) if half_widths is not None else 0.0
    if width > 0 and all(EFFECTS[kind].width_starts is not None for kind in kinds):
        # the whole twin started from the hysteresis' width (catalogue width_starts), the last effect polished
        # with all of them free; kept if it fits the estimation segment better than the sequential fit
        index = _insert_index(chain, kinds[0])
        base, train = _dynamics_chain(chain, index, u[:_fit_samples(n_est)])
        for kind in kinds[:-1]:
            base = _merged(base, index, kind, EFFECTS[kind].width_starts(width, train)[0])
        joint = fitted(kinds[-1], base, EFFECTS[kinds[-1]].width_starts(width, train))
        if joint.estimation_rms_rad < parts[-1].estimation_rms_rad:
            parts[-1] = joint
    return parts


def _fold_refit(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64], part: NDArray[np.intp],
                max_evaluations: int) -> tuple[_Chain, NDArray[np.float64]]:
    """``chain`` refitted from its fitted values (delays re-searched, then at most :data:`FOLD_EVALUATIONS`
    evaluations) with the samples ``part`` left out of the cost (the free run still covers the whole record),
    and its free-run error on ``part``: one fold of a contiguous K-fold cross-validation."""
    keep = np.ones(u.size, dtype=bool)
    keep[part] = False
    refit = _polish(_refine_delays(chain, u, y, samples=keep), u, y, min(max_evaluations, FOLD_EVALUATIONS),
                    samples=keep)
    refit = _stick_slip_scanned(refit, u, y, keep)
    return refit, _run_error(refit, u, y)[part]


def _fold_parts(samples: int, folds: int = FOLDS) -> list[NDArray[np.intp]]:
    """The ``folds`` contiguous folds of a record (contiguous: a free-run error is correlated over
    neighbouring samples, so interleaved folds would leave out nothing the refit does not see)."""
    return np.array_split(np.arange(samples), folds)


def _held_out_errors(chain: _Chain, u: NDArray[np.float64], y: NDArray[np.float64],
                     max_evaluations: int) -> tuple[NDArray[np.float64], ...]:
    """The free-run error on each of the :data:`REFIT_FOLDS` folds of ``chain`` refitted without it
    (:func:`_fold_refit`)."""
    return tuple(_fold_refit(chain, u, y, part, max_evaluations)[1] for part in _fold_parts(u.size, REFIT_FOLDS))
