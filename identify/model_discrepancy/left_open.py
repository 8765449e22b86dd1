"""What the record cannot tell apart (step 6, before the verdict): the effects a round leaves open listed with
the look-alikes that fit as well (:func:`_look_alikes_fitted`); each named effect checked against its
look-alikes (:func:`_look_alikes_checked`), against linear dynamics of a higher order from a fitted start
(:func:`_order_left_open`), against another mechanism with the same map (:func:`_mechanisms_left_open`), and
against a shape over the angle the record's motion is too small to show (:func:`_shape_left_open`). Each
returns the search's state with the effect dropped or kept and the verdict's reason."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from identify.effect_catalogue import (
    ANGLE_SHAPE_EXPERIMENT,
    EFFECTS,
    LINEAR_ORDER_EXPERIMENT,
    LOOK_ALIKE_EXPERIMENTS,
    SAME_MAP_READINGS,
    SEARCHED_EFFECT_NAMES,
    look_alike_experiments,
)
from identify.effect_signatures import SignatureScore, signature_scores
from identify.validation import InvalidInputError

from identify.model_discrepancy.candidates import _Candidate, _insert_index, _vanished, _without_effect
from identify.model_discrepancy.comparison import simulated
from identify.model_discrepancy.chain import _Chain, _effect_block, _linear_component, _polish
from identify.model_discrepancy.disagreement import disagreement
from identify.model_discrepancy.fit import _baseline_refit, _budget, _judged, _try_effect
from identify.model_discrepancy.judgement import _within_uncertainty
from identify.model_discrepancy.options import DiagnoseOptions
from identify.model_discrepancy.result import Disagreement, DiscrepancyStep
from identify.model_discrepancy.search_state import _Search
from identify.model_discrepancy.start_model import fit_linear_model
from identify.model_discrepancy.thresholds import (
    BASELINE_EFFORT,
    LOOK_ALIKE_APART_FRACTION,
    ORDER_LOOK_ALIKE_EXTRA,
    START_MAX_ORDER,
)


def _look_alikes_fitted(best: _Candidate, members: tuple[str, ...], chain: _Chain, u: NDArray[np.float64],
                        y: NDArray[np.float64], n_est: int, delta: float, period: float, current: Disagreement,
                        scores: dict[str, SignatureScore], options: DiagnoseOptions,
                        modes: tuple[tuple[float, float], ...]) -> list[_Candidate]:
    """The effects the search never tries on their own (catalogue ``look_alike_only``: the encoder error) that
    are look-alikes of ``members``, the candidates a round leaves open (``best`` the best of them), fitted into
    the round's ``chain`` as they were, and kept when the record cannot tell them from ``best`` by the rule of
    :func:`_look_alikes_checked`: the two outputs within the noise bound of each other on all but
    :data:`LOOK_ALIKE_APART_FRACTION` of the record, or the look-alike's validated gap within the uncertainty of
    ``best``'s or lower. Left out: a look-alike that vanishes, and one that counts as a look-alike only of members
    that bound it and is fitted at a size no working device has (catalogue ``bounded_look_alikes``). Over a small
    range of angles an offset and a load torque are one constant, and so is a sensor error once per revolution:
    a round left open between the first two lists the third when it fits as well.

    A look-alike fitted to the record that does not pass is made to follow ``best``'s output instead
    (:func:`_following`), as a named effect's look-alike is: over the small range of angles an estimation segment
    may cover, the encoder error's harmonics are nearly one polynomial, and its fit to the record chases the
    quantisation with errors of a tenth of a radian that cancel there and not over the validation segment's
    angles (the clean-room eccentricity on cascade steps seed 1035: 104 and 55 mrad fitted, 16.7 mrad validated,
    where 1.0 and 0.5 mrad fit the estimation segment within 0.05 mrad rms and validate at 0.68)."""
    if not set(SEARCHED_EFFECT_NAMES) <= set(options.candidates):
        return []  # a search the user restricted to some candidates stays within them
    measured = ~np.isnan(y)
    best_output = simulated(best.chain.model(), u, y)
    apart_allowed = max(options.consistent_fraction, LOOK_ALIKE_APART_FRACTION)
    out: list[_Candidate] = []
    for alike in dict.fromkeys(a for m in members for a in EFFECTS[m].look_alikes):
        entry = EFFECTS[alike]
        if alike in members or not entry.look_alike_only or _insert_index(chain, alike) < 0:
            continue
        for candidate in _look_alike_fits(alike, chain, best_output, u, y, n_est, delta, period, current, scores,
                                          options, modes):
            if _vanished(candidate, u, delta):
                continue
            if all(alike in EFFECTS[m].bounded_look_alikes and entry.implausible is not None
                   and entry.implausible(candidate.block) for m in members if alike in EFFECTS[m].look_alikes):
                continue
            apart = float(np.mean(np.abs(simulated(candidate.chain.model(), u, y) - best_output)[measured] > delta))
            if apart <= apart_allowed or candidate.gap_rad <= best.gap_rad or _within_uncertainty(
                    best.gap_rad, best.validation_error_rad, candidate.gap_rad, candidate.validation_error_rad):
                out.append(candidate)
                break
    return out


def _look_alike_fits(alike: str, chain: _Chain, best_output: NDArray[np.float64], u: NDArray[np.float64],
                     y: NDArray[np.float64], n_est: int, delta: float, period: float, current: Disagreement,
                     scores: dict[str, SignatureScore], options: DiagnoseOptions,
                     modes: tuple[tuple[float, float], ...]) -> Iterator[_Candidate]:
    """Look-alike ``alike`` in ``chain``: fitted to the record, then (only if asked for) made to follow
    ``best_output`` (:func:`_following`)."""
    fitted = _try_effect(alike, chain, u, y, n_est, delta, period, current.residual_rad, scores,
                         options.max_delay_samples, options.max_evaluations, modes=modes)
    yield fitted
    yield _following(fitted, best_output, u, y, n_est, options)


def _following(candidate: _Candidate, output: NDArray[np.float64], u: NDArray[np.float64], y: NDArray[np.float64],
               n_est: int, options: DiagnoseOptions) -> _Candidate:
    """``candidate`` polished to follow ``output`` (another model's free run) on the whole record's measured
    samples, then judged against the record: whether any such look-alike gives what that model gives, the
    question a look-alike answers. Fitted to the data on the estimation segment, a look-alike with more freedom
    than the effect (a sensor error's second harmonic) can extrapolate far off over angles only the validation
    segment reaches."""
    matched = _polish(candidate.chain, u, output, _budget(candidate.chain, options.max_evaluations),
                      samples=~np.isnan(y))
    return _judged(candidate.kind, matched, candidate.index, u, y, n_est)


def _look_alikes_checked(found: _Search, u: NDArray[np.float64], y: NDArray[np.float64], n_est: int,
                         delta: float, period: float, options: DiagnoseOptions,
                         say: Callable[[str], None]) -> _Search:
    """Each named effect with look-alikes (catalogue ``look_alikes``: gravity, the encoder error, the offset) checked
    against them: the look-alike is fitted in its place (the final model without the effect, plus the
    look-alike, :func:`_try_effect`), and when the two fitted models' free-run outputs are within the noise
    bound of each other on all but ``consistent_fraction`` of the record's measured samples
    (:data:`LOOK_ALIKE_APART_FRACTION` is that fraction), or when they differ but the look-alike fits the
    validation segment as well within the uncertainty (:func:`_within_uncertainty`) or better, the record
    cannot tell them apart: the effect is
    dropped (the rest refitted as a round's baseline, :func:`_baseline_refit`), the search is ambiguous
    between them, and the reason says what experiment would separate them (:data:`LOOK_ALIKE_EXPERIMENTS`).
    The look-alikes of a look-alike that also fits are tried in the effect's place as well: over a small
    range of angles a load torque, a sensor error and an offset are all one constant, and all three are
    reported.

    The whole record is compared, not the validation segment: the outputs, not their fit to the data, are
    what a further record would have to tell apart. A torque ~ sin of the load angle through a stiff servo
    deflects the load by torque / stiffness at every angle: in slow motion exactly the shape of a
    once-per-revolution sensor error; only fast moves (the servo lags the torque) or a softer servo show the
    difference."""
    named = [step.effect for step in found.steps]
    whole_catalogue = set(SEARCHED_EFFECT_NAMES) <= set(options.candidates)

    def allowed(alike: str) -> bool:
        # (a search the user restricted to some candidates stays within them)
        return alike not in named and (alike in options.candidates
                                       or (whole_catalogue and EFFECTS[alike].look_alike_only))

    apart_allowed = max(options.consistent_fraction, LOOK_ALIKE_APART_FRACTION)
    measured = ~np.isnan(y)
    named_output = found.current.simulated_rad

    def apart_from_named(chain: _Chain) -> float:
        theirs = simulated(chain.model(), u, y)
        return float(np.mean(np.abs(named_output - theirs)[measured] > delta))

    beyond: list[str] = []  # bounded look-alikes fitted at a size no working device has

    def fitted_in_place(alike: str, reduced: _Chain, before: Disagreement,
                        member: str) -> tuple[_Candidate, float] | None:
        """``alike`` fitted into ``reduced`` and the share of the record's measured samples where its output
        is further than the noise bound from the named model's; None when it vanishes, or when it is one of the
        ``member``'s bounded look-alikes and no working device has it (catalogue ``bounded_look_alikes``). When
        its output is apart, it is made to follow the named model's output instead (:func:`_following`)."""
        scores = signature_scores(u, y, before.simulated_rad, delta, period)
        other = _try_effect(alike, reduced, u, y, n_est, delta, period, before.residual_rad, scores,
                            options.max_delay_samples, options.max_evaluations)
        entry = EFFECTS[alike]
        if entry.vanished(other.block, delta):
            return None
        apart = apart_from_named(other.chain)
        if apart > apart_allowed:
            matched = _following(other, named_output, u, y, n_est, options)
            matched_apart = apart_from_named(matched.chain)
            if matched_apart < apart:
                other, apart = matched, matched_apart
        bounded = alike in EFFECTS[member].bounded_look_alikes and entry.implausible is not None
        why = entry.implausible(other.block) if bounded else ""
        if why:
            beyond.append(f"{alike} would give the output of {member} as well, but only as {why}, so it is not "
                          "taken for a look-alike (a damaged sensor would need a second encoder to show)")
            return None
        return other, apart

    for step in found.steps:
        reduced = _without_effect(found.chain, step.effect)
        if reduced is None:
            continue
        before = disagreement(reduced.model(), u, y, delta, n_est)
        group: list[tuple[str, str, _Candidate, float]] = []  # (look-alike, of which member, its fit, apart)
        members = [step.effect]
        while members:  # the look-alikes of the named effect, then theirs (an offset, gravity and a sensor error)
            member = members.pop(0)
            for alike in EFFECTS[member].look_alikes:
                if (not allowed(alike) or alike == step.effect or any(alike == g[0] for g in group)
                        or _insert_index(reduced, alike) < 0):
                    continue
                fit = fitted_in_place(alike, reduced, before, member)
                if fit is None:
                    continue
                if fit[1] > apart_allowed and fit[0].gap_rad > found.current.gap_rad and not _within_uncertainty(
                        found.current.gap_rad, found.current.residual_rad[n_est:], fit[0].gap_rad,
                        fit[0].validation_error_rad):
                    say(f"{step.effect} and its look-alike {alike} give outputs apart by more than the noise bound "
                        f"on {100 * fit[1]:.1f} % of the record, and the record prefers {step.effect} (validated gap "
                        f"{found.current.gap_rad:.3g} against {fit[0].gap_rad:.3g} rad): told apart")
                    continue
                group.append((alike, member, *fit))
                members.append(alike)
        if not group:
            continue
        between = (step.effect, *(alike for alike, *_ in group))
        reason = _look_alike_reason(between, group, found.current.gap_rad, before.gap_rad, delta, apart_allowed)
        say(f"ambiguous: {reason}")
        return _without_step(found, step, reduced, before, between, reason, u, y, n_est, delta, options)
    if beyond:
        say("; ".join(beyond))
        return replace(found, beyond_device_reason="; ".join(beyond))
    return found



def _without_step(found: _Search, step: DiscrepancyStep, reduced: _Chain, before: Disagreement,
                  between: tuple[str, ...], reason: str, u: NDArray[np.float64], y: NDArray[np.float64], n_est: int,
                  delta: float, options: DiagnoseOptions) -> _Search:
    """``found`` with the named ``step`` dropped for what the record cannot tell from it: the model without it
    (``reduced``, whose disagreement is ``before``) refitted, the verdict ambiguous ``between`` for ``reason``."""
    refit = _baseline_refit(reduced, u[:n_est], y[:n_est], options.max_evaluations)
    without = disagreement(refit.model(), u, y, delta, n_est)
    if without.gap_rad > before.gap_rad:
        refit, without = reduced, before
    at = found.steps.index(step)
    steps = [s for s in found.steps if s is not step]
    if at < len(steps):  # the next step now follows the model before the dropped one
        steps[at] = replace(steps[at], gap_before_rad=step.gap_before_rad,
                            falsified_fraction_before=step.falsified_fraction_before)
    if steps:
        steps[-1] = replace(steps[-1], gap_after_rad=without.gap_rad, model=refit.model(),
                            falsified_fraction_after=without.falsified_fraction)
    return _Search(refit, without, steps, found.tried, between, without.residual_rad[n_est:], (), reason)


def _order_left_open(found: _Search, u: NDArray[np.float64], y: NDArray[np.float64], n_est: int, delta: float,
                     period: float, fitted_start: bool, options: DiagnoseOptions,
                     say: Callable[[str], None]) -> _Search:
    """From a fitted start, a named effect that linear dynamics of a higher order can stand in for (catalogue
    ``order_look_alike``: a delay, whose lag poles the start model lacks also give) must still be needed once
    the start model has more poles: the best linear model of orders ``START_MAX_ORDER + 1`` ..
    ``START_MAX_ORDER + ORDER_LOOK_ALIKE_EXTRA`` (:func:`fit_linear_model` on the estimation segment) takes the
    start model's place in the fitted chain, which is polished with the effect and without it (the linear
    block's own input delay held, so it cannot take the effect's place). When the chain without it fits no
    worse, or within its uncertainty (:func:`_within_uncertainty`), the effect is not named: the verdict is
    ambiguous, and the reason gives the gaps and the experiment that separates them
    (:data:`LINEAR_ORDER_EXPERIMENT`)."""
    if not fitted_start or found.ambiguous_between or found.undecided:
        return found
    for step in found.steps:
        reduced = _without_effect(found.chain, step.effect)
        if not EFFECTS[step.effect].order_look_alike or reduced is None:
            continue
        orders = (START_MAX_ORDER + 1, START_MAX_ORDER + ORDER_LOOK_ALIKE_EXTRA)
        try:
            linear = fit_linear_model(u, y, period, n_est, min_order=orders[0], max_order=orders[1],
                                      max_evaluations=options.max_evaluations)
        except InvalidInputError:
            return found
        at = next((i for i, c in enumerate(found.chain.components) if c.kind == "linear"), None)
        if at is None:
            continue
        components = list(found.chain.components)
        components[at] = _linear_component(linear.block)
        richer = _Chain(components)
        richer_without = _without_effect(richer, step.effect)
        assert richer_without is not None
        budget = _budget(richer, BASELINE_EFFORT * options.max_evaluations)
        fitted = disagreement(_polish(richer, u[:n_est], y[:n_est], budget).model(), u, y, delta, n_est)
        higher = disagreement(_polish(richer_without, u[:n_est], y[:n_est], budget).model(), u, y, delta, n_est)
        if higher.gap_rad > fitted.gap_rad and not _within_uncertainty(
                fitted.gap_rad, fitted.residual_rad[n_est:], higher.gap_rad, higher.residual_rad[n_est:]):
            say(f"{step.effect} is still needed with a linear block of order {linear.order} (validated gap "
                f"{fitted.gap_rad:.3g} against {higher.gap_rad:.3g} rad without it): told apart")
            continue
        reason = (f"{step.effect} lowers the validated gap to {found.current.gap_rad:.3g} rad, and with a linear "
                  f"block of order {linear.order} in the start model's place the model fits to {higher.gap_rad:.3g} "
                  f"rad without it ({fitted.gap_rad:.3g} rad with it): the lag it adds is what poles the start "
                  f"model lacks would give, so whether it is {step.effect} or linear dynamics of a higher order "
                  f"cannot be told from this record, and {step.effect} is not named. To separate them: "
                  f"{LINEAR_ORDER_EXPERIMENT}")
        say(f"ambiguous: {reason}")
        before = disagreement(reduced.model(), u, y, delta, n_est)
        return _without_step(found, step, reduced, before, (step.effect,), reason, u, y, n_est, delta, options)
    return found


def _look_alike_reason(between: tuple[str, ...], group: Sequence[tuple[str, str, _Candidate, float]],
                       named_gap_rad: float, gap_without_rad: float, delta: float, apart_allowed: float) -> str:
    """The verdict's reason for a named effect (``between[0]``) and the look-alikes of ``group`` (look-alike,
    the member it is a look-alike of, its fit, the share of samples apart) the record cannot tell apart."""
    names = ", ".join(between[:-1]) + " and " + between[-1]
    gaps = ", ".join([f"{named_gap_rad:.3g} rad with {between[0]}"]
                     + [f"{fit.gap_rad:.3g} rad with {alike}" for alike, _, fit, _ in group])
    together = 100 * (1 - max(apart for *_, apart in group))
    closeness = (f"give outputs within the noise bound ({delta:.3g} rad) of each other on {together:.1f} % of the "
                 "record once each is fitted" if together >= 100 * (1 - apart_allowed) else
                 f"fit the record equally well within their uncertainty, their outputs within the noise bound "
                 f"({delta:.3g} rad) of each other on {together:.1f} % of it")
    experiments = look_alike_experiments(frozenset((member, alike)) for alike, member, _, _ in group)
    two = len(between) == 2
    told = f"{between[0]} from {between[1]}" if two else f"{names} apart"
    return (f"{names} {closeness} (validated gap {gaps}, {gap_without_rad:.3g} rad with "
            f"{'neither' if two else 'none of them'}): this record cannot tell {told}, so "
            f"{'neither' if two else 'none'} is named. To separate them: {experiments}")


def _mechanisms_left_open(found: _Search, candidates: Sequence[str], say: Callable[[str], None]) -> _Search:
    """A named effect whose fitted map is exactly another mechanism's (catalogue ``same_map_as``) keeps its place
    in the model, with its sizes and intervals (the map is identified), but the verdict is ambiguous between
    the mechanisms: the reason reads the fitted sizes both ways (:data:`SAME_MAP_READINGS`) and says what
    experiment separates them (:data:`LOOK_ALIKE_EXPERIMENTS`).

    An output backlash with unit slopes, w_t = x_t + c_l going down and x_t - c_r going up (eq. (3) of Cerone
    et al. 2009), is the map of Coulomb friction without stiction behind a stiff position loop: the load stops
    short of the command by T_c / K either way and stands until the drive has turned back through twice that,
    plus an offset of (c_l - c_r) / 2 (a constant load torque). From the command and the angle alone no record
    separates them; friction with stiction (breakaway above sliding) leaves stick-slip jumps and is named as
    friction by the family rule. A search the user restricted to candidates without the other mechanism stays
    within them, and a verdict already ambiguous keeps its own reason."""
    if found.ambiguous_between or found.undecided:
        return found
    named = [step.effect for step in found.steps]
    for step in found.steps:
        for other in EFFECTS[step.effect].same_map_as:
            if other in named or other not in candidates:
                continue
            reading = SAME_MAP_READINGS[(step.effect, other)](step.parameters)
            reason = (f"but the {step.effect} fitted is also the map of {other}: {reading}. From the command and "
                      f"the angle alone the two are one map, so which of them it is cannot be told from this record "
                      f"(the fitted map stays in the model). To separate them: "
                      f"{LOOK_ALIKE_EXPERIMENTS[frozenset((step.effect, other))]}")
            say(f"ambiguous: {reason}")
            return replace(found, ambiguous_between=(step.effect, other), mechanism_reason=reason)
    return found



def _shape_left_open(found: _Search, y: NDArray[np.float64], delta: float, say: Callable[[str], None]) -> _Search:
    """A named effect whose output is a sine of the angle (catalogue ``angle_sag``: a weight's sag of amplitude
    S) over a record whose angles span only R: such a sag departs from a straight line by at most S R^2 / 8
    there, and when that is below the noise bound the record has shown a load torque with a value and a slope
    at these angles, not its sine: cogging, a spring or any torque that varies smoothly with the angle fits as
    well. The fitted effect stays in the model (the local map is identified), the verdict is ambiguous, and
    the reason says what range of angles would show the shape (:data:`ANGLE_SHAPE_EXPERIMENT`)."""
    if found.ambiguous_between or found.undecided or found.mechanism_reason:
        return found
    measured = y[np.isfinite(y)]
    span = float(np.max(measured) - np.min(measured)) if measured.size else 0.0
    for step in found.steps:
        entry = EFFECTS[step.effect]
        block = _effect_block(found.chain, step.effect)
        if entry.angle_sag is None or block is None:
            continue
        sag = entry.angle_sag(block)
        bend = sag * span**2 / 8.0
        if bend >= delta:
            continue
        reason = (f"but the record's angles span {span:.3g} rad, over which a sine of the angle of amplitude {sag:.3g} "
                  f"rad departs from a straight line by at most {bend:.3g} rad, under the noise bound ({delta:.3g} "
                  f"rad): the record shows a load torque with a value and a slope at these angles, which {step.effect} "
                  f"fits, and so would any torque that varies smoothly with the angle (cogging, a spring), so which it "
                  f"is cannot be told from this record (the fitted {step.effect} stays in the model). To see its "
                  f"shape: {ANGLE_SHAPE_EXPERIMENT}")
        say(f"ambiguous: {reason}")
        return replace(found, ambiguous_between=(step.effect,), mechanism_reason=reason)
    return found
