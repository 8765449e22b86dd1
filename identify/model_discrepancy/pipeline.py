"""The workflow from end to end (:func:`diagnose_model`): the record checked, moved to its operating point,
checked for excitation, then the start model, the search, the intervals and the verdict, each step one call
into its module (the package docstring lists them).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.drive_train import DriveTrain
from identify.effect_catalogue import EFFECTS, SEARCHED_EFFECT_NAMES
from identify.plant_blocks import LinearBlock, OutputOffset, PlantModel
from identify.validation import InvalidInputError, as_signal, positive, same_length, varying, with_options

from identify.model_discrepancy.candidates import _candidate_names, drive_train_like
from identify.model_discrepancy.comparison import restartable, restarted_every
from identify.model_discrepancy.disagreement import disagreement, gross_disagreements
from identify.model_discrepancy.drive_torque import SAG_LOOK_ALIKES, load_torque_check
from identify.model_discrepancy.intervals import _named_intervals, _with_final_parameters
from identify.model_discrepancy.open_world import open_world_checked
from identify.model_discrepancy.options import DiagnoseOptions
from identify.model_discrepancy.result import Disagreement, DiscrepancyResult
from identify.model_discrepancy.left_open import (
    _look_alikes_checked,
    _mechanisms_left_open,
    _order_left_open,
    _shape_left_open,
)
from identify.model_discrepancy.search import _family_rechecked, _search, _still_needed
from identify.model_discrepancy.search_state import _Search
from identify.model_discrepancy.start_model import _start
from identify.model_discrepancy.thresholds import (
    AT_REST_NOISE_BOUNDS,
    MIN_MEASURED_FRACTION,
    OPERATING_POINT_MIN_NOISE_BOUNDS,
    OPERATING_POINT_SAMPLES,
    RESTART_FORM_NOISE_BOUNDS,
    RESTART_WINDOW_S,
)
from identify.model_discrepancy.verdict import (
    _estimation_falsified,
    _excitation,
    _final_verdict,
    _left_unexplained,
    _not_excited,
    _with_findings,
)


GRAVITY_KEY = "gravity_per_inertia_rad_per_s2"
"""The gravity candidate's fitted m g l / J (the catalogue's parameter)."""


def diagnose_model(command_rad: ArrayLike, angle_rad: ArrayLike, noise_bound_rad: float,
                   sample_period_s: float, model: PlantModel | None = None, options: DiagnoseOptions | None = None,
                   *, drive_torque: ArrayLike | None = None, drive_torque_nm_per_unit: float | None = None,
                   progress: Callable[[str], None] | None = None, **option_values: Any) -> DiscrepancyResult:
    """Run the model-discrepancy workflow (the steps of the package docstring), one named step
    each: the checks (:func:`_checked_record`), the gross disagreements of the measurement over the whole
    record (:func:`gross_disagreements`: a sensor wrap is undone, glitches are left out, both reported in
    ``findings`` and the verdict's reason, :func:`_with_findings`), the move to the operating point (:func:`_operating_point`,
    :func:`_absolute`), the excitation check (:func:`_excitation`, :func:`_not_excited`), the start model
    (:func:`_start`), the greedy search (:func:`_search`), the intervals of what was named
    (:func:`_named_intervals`), the verdict (:func:`_final_verdict`) and the open-world check of what the final
    model leaves (:func:`open_world_checked`), all on free runs (:func:`_diagnosed`); then, when that names
    nothing and leaves only drive-train effects open, the same steps for those on windows that restart the load
    from the measured angle (:func:`_restarted_if_open`).

    Parameters
    ----------
    command_rad, angle_rad
        Measured input u_t and output y_t (rad), one record. NaN in ``angle_rad`` marks a sample not
        measured (LOST, or unusable by its flags): the free run still covers it (the model needs only the
        command), but it is left out of every residual, fit and count (its residual is 0, it is never
        falsified, and the gaps and falsified fractions are over the measured samples). Each segment must
        keep :data:`MIN_MEASURED_FRACTION` of its samples.
    noise_bound_rad
        delta: bound on the measurement error, |e_t| <= delta (include the encoder's half count).
    sample_period_s
        T.
    model
        The user's model; None fits the best low-order linear model (:func:`fit_linear_model`), whose
        coefficients are then refitted together with every effect.
    options
        The settings (:class:`DiagnoseOptions`); or give its fields as keywords (``candidates=...``,
        ``max_effects=2``, ...), which override those of ``options``.
    drive_torque
        The torque the drive reported at each sample (the CiA 402 torque actual value 0x6077, a motor current;
        any unit, NaN where not measured), or None. When the angle names a weight (gravity) or leaves it open,
        beside the sensor errors that read like its sag (an encoder error, an offset, a gain error) or with its
        shape undecided, the torque shows whether the drive carries a weight (:func:`_with_drive_torque`).
    drive_torque_nm_per_unit
        N m at the motor per unit of ``drive_torque`` (a rig log's summary gives it for the CiA 402 torque:
        0x6076 / 1e6), or None. With it and a ``model`` holding a :class:`~identify.drive_train.DriveTrain`, the
        torque can also exclude a weight (:mod:`.drive_torque`).
    progress
        Called with one line of text per stage and candidate.

    Raises
    ------
    InvalidInputError
        Signals too short, of different lengths or not varying, a noise bound or period that is not
        positive, a model of another sample period, or a setting out of range.
    TypeError
        A keyword that is no field of :class:`DiagnoseOptions` (the message lists them).
    """
    options = with_options("diagnose_model", options, DiagnoseOptions, option_values)
    if drive_torque is None:
        return _diagnosed_record(command_rad, angle_rad, noise_bound_rad, sample_period_s, model, options, progress)
    u, y, delta, period = _checked_record(command_rad, angle_rad, noise_bound_rad, sample_period_s, model)
    torque = as_signal("drive_torque", drive_torque, missing_allowed=True)
    same_length(command_rad=u, drive_torque=torque)
    scale = None if drive_torque_nm_per_unit is None else positive("drive_torque_nm_per_unit", drive_torque_nm_per_unit)
    result = _diagnosed_record(u, y, delta, period, model, options, progress)
    return _with_drive_torque(result, u, y, torque, scale, delta, period, model, options,
                              progress or (lambda _message: None))


def _diagnosed_record(command_rad: ArrayLike, angle_rad: ArrayLike, noise_bound_rad: float, sample_period_s: float,
                      model: PlantModel | None, options: DiagnoseOptions,
                      progress: Callable[[str], None] | None, sag_shape_shown: bool = False) -> DiscrepancyResult:
    """:func:`diagnose_model` from the angle alone; ``sag_shape_shown``: the drive's torque has shown the sine
    of a weight's sag, which the angle need not show again (:func:`_shape_left_open` is not asked)."""
    u, y, delta, period = _checked_record(command_rad, angle_rad, noise_bound_rad, sample_period_s, model)
    findings, cleaned = gross_disagreements(u, y, delta)
    if findings:  # measurement-side: the rest of the record is judged with them put aside, and says so
        if progress is not None:
            for finding in findings:
                progress(finding.text())
        return _with_findings(_diagnosed_record(u, cleaned, delta, period, model, options, progress, sag_shape_shown),
                              findings)
    operating_point = _operating_point(u, y, delta) if options.from_operating_point else 0.0
    if operating_point != 0.0:
        result = _diagnosed_record(u - operating_point, y - operating_point, delta, period, model,
                                   replace(options, from_operating_point=False), progress, sag_shape_shown)
        return _absolute(result, operating_point, period)
    n_est = int(round(options.estimation_fraction * u.size))
    _check_measured(y, n_est)
    say = progress or (lambda _message: None)
    excitation = _excitation(u, n_est)
    if excitation["reason"]:
        say(f"not excited: {excitation['reason']}")
        return _not_excited(u, y, delta, model, n_est, excitation, options.consistent_fraction)
    first = _diagnosed(u, y, delta, period, model, options, n_est, excitation, say, sag_shape_shown)
    first = _restarted_if_open(first, u, y, delta, period, n_est, excitation, options, say)
    return _judged_where_it_disagrees(first, u, y, delta, period, model, n_est, options, say)


def _diagnosed(u: NDArray[np.float64], y: NDArray[np.float64], delta: float, period: float, model: PlantModel | None,
               options: DiagnoseOptions, n_est: int, excitation: dict[str, Any],
               say: Callable[[str], None], sag_shape_shown: bool = False) -> DiscrepancyResult:
    """The start model, the search, the intervals, the verdict and the open-world check of one record, under
    the comparison in force (:mod:`.comparison`)."""
    start_model, linear_fit, chain = _start(u, y, period, n_est, model, options.max_evaluations, say)
    initial = disagreement(start_model, u, y, delta, n_est)
    candidates = list(_candidate_names(options.candidates, model))
    found = _search(_Search(chain, initial, [], [], (), initial.residual_rad[n_est:]), list(candidates), u, y, n_est,
                    delta, period, options, say, resolve_ties=True)
    found = _family_rechecked(found, candidates, u, y, n_est, delta, options, say)
    found = _still_needed(found, u, y, n_est, delta, options, say)
    found = _look_alikes_checked(found, u, y, n_est, delta, period, options, say)
    found = _order_left_open(found, u, y, n_est, delta, period, linear_fit is not None, options, say)
    chain, current, steps = found.chain, found.current, found.steps
    consistent = current.falsified_fraction <= options.consistent_fraction
    intervals, reduction = _named_intervals(chain, steps, start_model, u, y, delta, current, options, say)
    steps = _with_final_parameters(steps, chain)
    found = _mechanisms_left_open(replace(found, steps=steps), candidates, say)
    if not sag_shape_shown:
        found = _shape_left_open(found, y, delta, say)
    verdict, reason = _final_verdict(u, y, initial, current, found, consistent, delta, period, options)
    verdict, reason, structure = open_world_checked(verdict, reason, u, y, initial, current, steps, consistent, n_est)
    return DiscrepancyResult(
        steps=tuple(steps), start_model=start_model, final_model=chain.model() if steps else start_model,
        initial=initial, final=current, consistent=consistent,
        unexplained=_left_unexplained(current, consistent, delta, tuple(
            name for name in dict.fromkeys((*found.ambiguous_between, *(c.effect for c in found.undecided)))
            if name not in {step.effect for step in steps})),
        estimation_samples=n_est, noise_bound_rad=delta, linear_fit=linear_fit, verdict=verdict,
        verdict_reason=reason, candidates=tuple(found.tried), ambiguous_between=found.ambiguous_between,
        parameter_intervals=intervals, gap_reduction=reduction, excitation=excitation, undecided=found.undecided,
        residual_structure=structure,
    )


def _with_drive_torque(result: DiscrepancyResult, u: NDArray[np.float64], y: NDArray[np.float64],
                       torque: NDArray[np.float64], nm_per_unit: float | None, delta: float, period: float,
                       model: PlantModel | None, options: DiagnoseOptions,
                       say: Callable[[str], None]) -> DiscrepancyResult:
    """``result``, or, when it names gravity or leaves it open (beside the sensor errors that read like its sag,
    :data:`SAG_LOOK_ALIKES`, or its shape undecided over a short span of angles), the drive's torque checked for
    the weight (:func:`.drive_torque.load_torque_check`):

    - when the torque excludes the weight the sag would need (:func:`_weight_torque`), the record diagnosed
      again without gravity, the sensor errors that read like its sag searched with the rest (not only tried as
      look-alikes of what is named): a weight named from the angle alone is overruled too;
    - when the drive carries the weight gravity left open, the record diagnosed again without those sensor errors
      (the weight is shown, they are not needed for the sag) and without asking the angle for the sine's shape,
      which the torque showed (its harmonic is the part of a sine the lags, which hold the angle itself, cannot
      take: the bend a spring or a constant torque has not);
    - otherwise the result as it was, the check's figures added to its reason (what the torque bounds).

    The check is in ``load_torque_check`` either way."""
    left_open = set(result.ambiguous_between) | {candidate.effect for candidate in result.undecided}
    named = "gravity" in result.missing_effects
    if "gravity" not in left_open and not named:
        return result
    check = load_torque_check(u, y, torque, result.start_model, period, _weight_torque(result, model, nm_per_unit))
    say(f"drive torque: {check.text()}")
    if check.outcome == "no_load_torque":  # the sensor errors that read like the sag are searched, not only tried
        sensor = SAG_LOOK_ALIKES if set(SEARCHED_EFFECT_NAMES) <= set(options.candidates) else ()  # as look-alikes
        kept = tuple(dict.fromkeys((*(name for name in options.candidates if name != "gravity"), *sensor)))
        again = _diagnosed_record(u, y, delta, period, model, replace(options, candidates=kept), say)
        return replace(again, load_torque_check=check, verdict_reason=(
            f"{again.verdict_reason.rstrip('.')}. The drive's torque: {check.text()} (gravity not tried)."))
    if check.outcome == "undecided" or named:
        return replace(result, load_torque_check=check,
                       verdict_reason=f"{result.verdict_reason.rstrip('.')}. The drive's torque: {check.text()}.")
    kept = tuple(name for name in options.candidates if name not in SAG_LOOK_ALIKES)
    again = _diagnosed_record(u, y, delta, period, model, replace(options, candidates=kept), say, sag_shape_shown=True)
    return replace(again, load_torque_check=check, verdict_reason=(
        f"{again.verdict_reason.rstrip('.')}. The drive's torque: {check.text()} ({', '.join(SAG_LOOK_ALIKES)} not "
        "tried)."))


def _weight_torque(result: DiscrepancyResult, model: PlantModel | None, nm_per_unit: float | None) -> float:
    """W of :mod:`.drive_torque`: the once-per-revolution torque, in the torque record's unit, that the weight
    fitted to the sag (the best fit of the gravity candidate, m g l at the load) puts on the drive: over the
    start model's gear ratio and ``nm_per_unit``. NaN unless the user's ``model`` holds a
    :class:`~identify.drive_train.DriveTrain` (a train the workflow made from a linear model has no physical
    inertia) and the scale is known."""
    trains = [block for block in result.start_model.blocks if isinstance(block, DriveTrain)]
    fits = [candidate for candidate in result.candidates
            if candidate.effect == "gravity" and math.isfinite(candidate.parameters.get(GRAVITY_KEY, math.nan))]
    if nm_per_unit is None or model is None or not trains or not fits or not any(
            isinstance(block, DriveTrain) for block in model.blocks):
        return math.nan
    best = min(fits, key=lambda candidate: candidate.gap_rad)
    train = trains[0]
    return best.parameters[GRAVITY_KEY] * train.total_inertia_kg_m2 / train.gear_ratio / nm_per_unit


def _restarted_if_open(first: DiscrepancyResult, u: NDArray[np.float64], y: NDArray[np.float64], delta: float,
                       period: float, n_est: int, excitation: dict[str, Any], options: DiagnoseOptions,
                       say: Callable[[str], None]) -> DiscrepancyResult:
    """``first`` (the free-run judgement), or, when it named nothing and left only drive-train effects open
    (catalogue placement ``dynamics``), the judgement of those candidates on windows that restart the load from
    the measured angle (:mod:`.comparison`) if that one names them, against the drive-train form of the same
    start model (:func:`_restartable_start`).

    Only names the free run left open can come out, and a second judgement that names nothing, or leaves the
    record ambiguous, leaves ``first`` as it was: the restarted comparison resolves what the free run could not
    decide because the load's state drifted from the record's, and it cannot make a record `explained` (a
    restarted run hides a slowly growing error, a sensor's for example, that the free run shows). With a
    sensor's or the command's effect among those left open it is not tried: a restart moves the load by the
    sensor's error too, and on the clean-room generator's drifting sensor gain (seeds 1004, 1007, 1012, 1013,
    open between an offset and gravity or an encoder error) it then named both, where the free run had rightly
    left them open.

    A mode of the model left open beside them (catalogue ``linear_dynamics``: a resonance, which a play that
    switches the load on and off the motor resembles) is not judged on restarted windows, where each restart
    would ring it: the drive-train effects are, and when they are named there the mode stays open beside them
    (``ambiguous``, the named effects kept in the model)."""
    left_open = tuple(dict.fromkeys(effect for name in (*first.ambiguous_between, *(c.effect for c in first.undecided))
                                    for effect in name.split("+")))  # an inner twin is listed as "a+b"
    if first.steps or not left_open or first.verdict not in ("ambiguous", "unexplained"):
        return first
    modes = tuple(name for name in left_open if EFFECTS[name].linear_dynamics)
    left_open = tuple(name for name in left_open if name not in modes)
    if not left_open or not all(EFFECTS[name].placement == "dynamics" for name in left_open):
        return first  # a sensor's or the command's effect is judged by the free run, which a restart cannot overrule
    start = _restartable_start(first.start_model, u, delta)
    if start is None:
        return first
    window = max(2, int(round(RESTART_WINDOW_S / period)))
    say(f"the free run leaves {', '.join(left_open)} open; judged again on windows of {window} samples that "
        f"restart the load from the measured angle")
    with restarted_every(window):
        second = _diagnosed(u, y, delta, period, start, replace(options, candidates=left_open), n_est, excitation,
                            say)
    if not second.steps or second.verdict != "named" or second.ambiguous_between or second.undecided:
        say(f"the restarted comparison does not decide either ({second.verdict})")
        return first
    reason = (f"the free run left {', '.join(left_open)} open; compared on windows of {window} samples "
              f"({window * period:.3g} s) that restart the load from the measured angle, where a state that drifts "
              f"from the record's (a load rattling in a play) no longer decides: {second.verdict_reason}")
    verdict, ambiguous_between = second.verdict, second.ambiguous_between
    if modes:
        verdict, ambiguous_between = "ambiguous", modes
        reason = (f"{reason}; {', '.join(modes)}, left open beside {', '.join(left_open)} by the free run, is a mode "
                  f"of the model, not of the drive train, which a restart would ring, so it is not judged on these "
                  f"windows: whether it is there as well cannot be told from this record")
    rounds = 1 + max((c.round for c in first.candidates), default=-1)  # the restarted rounds follow the free run's
    return replace(second, start_model=first.start_model, linear_fit=first.linear_fit, verdict=verdict,
                   verdict_reason=reason, ambiguous_between=ambiguous_between,
                   candidates=(*first.candidates, *(replace(c, round=c.round + rounds) for c in second.candidates)),
                   restart_window_samples=window)


def _judged_where_it_disagrees(first: DiscrepancyResult, u: NDArray[np.float64], y: NDArray[np.float64],
                               delta: float, period: float, model: PlantModel | None, n_est: int,
                               options: DiagnoseOptions, say: Callable[[str], None]) -> DiscrepancyResult:
    """``first``, or, when the start model agrees with the validation segment but not with the estimation
    segment (``first`` is then ``unexplained``, :func:`.verdict._verdict`), the record judged where it disagrees:
    steps 2-9 on the estimation segment alone, split as a record is (its first ``estimation_fraction`` fits, the
    rest validates). The validation segment then has nothing to judge an effect on, and the estimation segment
    does (an effect the validation segment's commands hardly excite, a sensor error small at the angles it
    visits).

    What that names or leaves open is kept only when the model with it still agrees with the record's validation
    segment, as the start model does; the result then describes the judgement made: its estimation segment is
    the estimation segment's first part, its validated gaps are over the rest of the record. Otherwise, and when
    the estimation segment's own split is not excited or the disagreement lies in its first part only (nothing
    left to validate on), ``first``, with what the estimation segment alone said added to its reason."""
    if first.steps or first.verdict != "unexplained" or \
            first.initial.falsified_fraction > options.consistent_fraction or \
            _estimation_falsified(first.initial, y, n_est) <= options.consistent_fraction:
        return first
    n_part = int(round(options.estimation_fraction * n_est))
    part = f"the estimation segment alone (samples 0-{n_part - 1} fitting, {n_part}-{n_est - 1} validating)"
    u_part, y_part = u[:n_est], y[:n_est]
    excitation = _excitation(u_part, n_part)
    try:
        _check_measured(y_part, n_part)
    except InvalidInputError as too_few:
        excitation = {**excitation, "reason": str(too_few)}
    if excitation["reason"]:
        say(f"{part} is not judged: {excitation['reason']}")
        return replace(first, verdict_reason=f"{first.verdict_reason}. Judged on {part}: not excited "
                                             f"({excitation['reason']})")
    say(f"judged on {part}, where the record disagrees with the start model")
    found = _diagnosed(u_part, y_part, delta, period, model, options, n_part, excitation, say)
    found = _restarted_if_open(found, u_part, y_part, delta, period, n_part, excitation, options, say)
    if found.initial.falsified_fraction <= options.consistent_fraction:
        return replace(first, verdict_reason=(
            f"{first.verdict_reason}. Its last {n_est - n_part} samples agree with the start model too: the "
            "disagreement lies where an effect would be fitted, and no part of the record that shows it is left to "
            "validate one on"))
    if found.verdict not in ("named", "ambiguous"):
        return replace(first, verdict_reason=f"{first.verdict_reason}. Judged on {part}: {found.verdict} "
                                             f"({found.verdict_reason})")
    validation = disagreement(found.final_model, u, y, delta, n_est)
    named = ", ".join(found.missing_effects)
    judged_model = f"the model with {named}" if named else "the start model of that part"
    if validation.falsified_fraction > options.consistent_fraction:
        return replace(first, verdict_reason=(
            f"{first.verdict_reason}. Judged on {part}: {found.verdict} ({found.verdict_reason}); but {judged_model} "
            f"disagrees with the validation segment on {100 * validation.falsified_fraction:.1f} % of its samples, "
            "where the start model agrees: rejected"))
    initial = disagreement(found.start_model, u, y, delta, n_part)
    final = disagreement(found.final_model, u, y, delta, n_part)
    return replace(found, initial=initial, final=final,
                   consistent=final.falsified_fraction <= options.consistent_fraction,
                   verdict_reason=(f"{first.verdict_reason}. Judged on {part}: {found.verdict_reason}; "
                                   f"{judged_model} agrees with the validation segment (samples {n_est}-{u.size - 1}) "
                                   "within the noise bound too"))


def _restartable_start(start_model: PlantModel, u: NDArray[np.float64], delta: float) -> PlantModel | None:
    """The start model with a drive train whose load can be restarted: itself if it has one, else its linear
    block replaced by the drive train of the same response (:func:`drive_train_like`) when that train's free
    run stays within :data:`RESTART_FORM_NOISE_BOUNDS` noise bounds of the model's on every sample; None when
    there is no linear block or no such train."""
    if restartable(start_model):
        return start_model
    blocks = list(start_model.blocks)
    at = next((i for i, block in enumerate(blocks) if isinstance(block, LinearBlock)), None)
    if at is None:
        return None
    inner = PlantModel(tuple(blocks[:at])).simulate(u) if at else u
    linear = blocks[at]
    assert isinstance(linear, LinearBlock)
    blocks[at] = drive_train_like(linear, inner)
    train_form = PlantModel(tuple(blocks))
    apart = float(np.max(np.abs(train_form.simulate(u) - start_model.simulate(u))))
    return train_form if apart <= RESTART_FORM_NOISE_BOUNDS * delta else None


def _checked_record(command_rad: ArrayLike, angle_rad: ArrayLike, noise_bound_rad: float, sample_period_s: float,
                    model: PlantModel | None) -> tuple[NDArray[np.float64], NDArray[np.float64], float, float]:
    """u, y, delta and T of :func:`diagnose_model`, checked (T is the model's own when it has one, so that the
    blocks added carry exactly the model's period)."""
    u = as_signal("command_rad", command_rad, min_samples=50)
    y = as_signal("angle_rad", angle_rad, min_samples=50, missing_allowed=True)
    same_length(command_rad=u, angle_rad=y)
    delta = positive("noise_bound_rad", noise_bound_rad)
    period = positive("sample_period_s", sample_period_s)
    if model is not None and not isinstance(model, PlantModel):
        raise InvalidInputError(f"model: expected a PlantModel or None, got {type(model).__name__}")
    if model is not None and model.sample_period_s is not None:
        if abs(model.sample_period_s - period) > 1e-3 * period:
            raise InvalidInputError(
                f"sample_period_s: the data are sampled every {period:g} s, the model every {model.sample_period_s:g} s")
        period = model.sample_period_s
    varying("command_rad", u, "record a step or PRBS experiment (configs/experiments/prbs.toml) to compare a "
                              "model with")
    return u, y, delta, period


def _check_measured(y: NDArray[np.float64], n_est: int) -> None:
    """Refuse a record whose estimation or validation segment is too little measured (:data:`MIN_MEASURED_FRACTION`),
    saying how many samples are left and how many are needed."""
    missing = np.isnan(y)
    if not np.any(missing):
        return
    for name, part in (("estimation", slice(0, n_est)), ("validation", slice(n_est, y.size))):
        total = int(missing[part].size)
        measured = total - int(np.count_nonzero(missing[part]))
        needed = int(math.ceil(MIN_MEASURED_FRACTION * total))
        if measured < needed:
            raise InvalidInputError(
                f"angle_rad: {int(np.count_nonzero(missing))} of the {y.size} samples are missing (NaN: lost or "
                f"unusable), which leaves {measured} measured samples of the {total} of the {name} segment; at "
                f"least {needed} ({100 * MIN_MEASURED_FRACTION:.0f} %) are needed: record again with fewer lost samples")


def _operating_point(u: NDArray[np.float64], y: NDArray[np.float64], delta: float) -> float:
    """u_0, the record's first command, when the plant rested under it before the record began: the record
    starts at rest (its first angles within two noise bounds of each other), nearer u_0 than zero, with u_0 not
    within a tenth of a noise bound of zero; 0 otherwise. Every model then runs on u - u_0 from zero: from rest
    at u_0 (a play centred there). A record that starts in motion has a state no angle gives, and one whose
    angle rests nearer zero than its moving command (the command began with the record): both run from zero.
    An angle resting away from its command (friction, play, an offset) stays in the residual for the candidates
    to explain."""
    first = y[:OPERATING_POINT_SAMPLES]
    first = first[~np.isnan(first)]
    if first.size == 0:
        return 0.0
    y0, u0 = float(np.median(first)), float(u[0])
    at_rest = float(np.ptp(first)) <= AT_REST_NOISE_BOUNDS * delta
    rested_under_u0 = abs(y0 - u0) < abs(y0) and abs(u0) > OPERATING_POINT_MIN_NOISE_BOUNDS * delta
    return u0 if at_rest and rested_under_u0 else 0.0


def _absolute(result: DiscrepancyResult, operating_point: float, period: float) -> DiscrepancyResult:
    """``result`` of a run on u - u_0, y - u_0 in absolute angles: simulated outputs moved back by u_0, models
    wrapped as u_0 + M(u - u_0)."""

    def wrap(model: PlantModel) -> PlantModel:
        return PlantModel((OutputOffset(offset_rad=-operating_point, drift_rad_per_s=0.0, sample_period_s=period),
                           *model.blocks,
                           OutputOffset(offset_rad=operating_point, drift_rad_per_s=0.0, sample_period_s=period)))

    def moved(d: Disagreement) -> Disagreement:
        return replace(d, simulated_rad=d.simulated_rad + operating_point)

    steps = tuple(replace(step, model=wrap(step.model)) for step in result.steps)
    return replace(result, steps=steps, start_model=wrap(result.start_model), final_model=wrap(result.final_model),
                   initial=moved(result.initial), final=moved(result.final), operating_point_rad=operating_point)
