"""Step 6 of the workflow, the verdict: explained / named / ambiguous / unexplained / not excited
(:data:`VERDICTS`) with its reason in words (:func:`_verdict`), including the checks that make a record not
excited: a segment where the command never turns or too short a validation segment (:func:`_excitation`),
and an output that moves while the command and the model rest (:func:`_unmeasured_input`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.border_lifting import direction_signal
from identify.effect_catalogue import look_alike_experiments
from identify.plant_blocks import Delay, PlantModel

from identify.model_discrepancy.disagreement import disagreement
from identify.model_discrepancy.options import DiagnoseOptions
from identify.model_discrepancy.result import (
    CandidateResult,
    Disagreement,
    DiscrepancyResult,
    DiscrepancyStep,
    GrossDisagreement,
)
from identify.model_discrepancy.search_state import _Search
from identify.model_discrepancy.thresholds import (
    COMMAND_STILL_RANGE_FRACTION,
    MIN_REDUCTION,
    MIN_SEGMENT_REVERSALS,
    MIN_VALIDATION_SAMPLES,
    REST_OSCILLATION_CORRELATION,
    REST_OSCILLATION_CYCLES,
    UNMEASURED_INPUT_FRACTION,
    UNMEASURED_MODEL_STILL_NOISE_BOUNDS,
    UNMEASURED_OUTPUT_MOTION_NOISE_BOUNDS,
)


def _command_reversals(u: NDArray[np.float64]) -> NDArray[np.bool_]:
    """True at the samples where the command's direction of motion turns (a designed command moves smoothly
    or holds exactly: only steps below a millionth of its range, rounding, are no motion)."""
    threshold = COMMAND_STILL_RANGE_FRACTION * float(np.ptp(u)) if u.size else 0.0
    direction = direction_signal(u, threshold=threshold)
    turns = np.zeros(u.size, dtype=bool)
    turns[1:] = (np.diff(direction) != 0) & (direction[:-1] != 0)
    return turns


def _excitation(u: NDArray[np.float64], n_est: int) -> dict[str, Any]:
    """Whether the record can show the effects: reversals of the command in each segment and the validation
    segment's length (:data:`MIN_SEGMENT_REVERSALS`, :data:`MIN_VALIDATION_SAMPLES`); ``reason`` says why
    not, or is empty."""
    turns = _command_reversals(u)
    estimation, validation = int(np.count_nonzero(turns[:n_est])), int(np.count_nonzero(turns[n_est:]))
    samples = int(u.size - n_est)
    reason = ""
    if samples < MIN_VALIDATION_SAMPLES:
        reason = (f"the validation segment is too short to judge: {samples} samples, at least "
                  f"{MIN_VALIDATION_SAMPLES} needed")
    elif estimation + validation == 0:
        reason = "the command never reverses its direction: no effect can be told apart from a lag or a scale"
    elif validation < MIN_SEGMENT_REVERSALS:
        reason = (f"the validation segment is too short to judge: the command reverses {validation} times there "
                  f"(at least {MIN_SEGMENT_REVERSALS} needed); record longer or move more often")
    elif estimation < MIN_SEGMENT_REVERSALS:
        reason = (f"the estimation segment cannot fit an effect: the command reverses {estimation} times there "
                  f"(at least {MIN_SEGMENT_REVERSALS} needed)")
    return {"reversals_estimation": estimation, "reversals_validation": validation, "validation_samples": samples,
            "reason": reason}


def _at_rest(u: NDArray[np.float64], simulated: NDArray[np.float64], delta: float) -> NDArray[np.bool_]:
    """Per step between two samples: the command holds and the model's free run rests."""
    command_still = np.abs(np.diff(u)) <= 1e-12 + COMMAND_STILL_RANGE_FRACTION * float(np.ptp(u))
    return command_still & (np.abs(np.diff(simulated)) <= UNMEASURED_MODEL_STILL_NOISE_BOUNDS * delta)


def _unmeasured_input(u: NDArray[np.float64], y: NDArray[np.float64], simulated: NDArray[np.float64],
                      delta: float, period_s: float) -> str:
    """A reason when the output moves while the command and the model are at rest
    (:data:`UNMEASURED_INPUT_FRACTION`), else an empty string. Where it oscillates there
    (:func:`_rest_oscillation`), the reason gives the amplitude and period and names both readings."""
    still = _at_rest(u, simulated, delta)
    output_moves = np.abs(np.diff(y)) > UNMEASURED_OUTPUT_MOTION_NOISE_BOUNDS * delta
    share = float(np.mean(still & output_moves))
    if share < UNMEASURED_INPUT_FRACTION:
        return ""
    moves = f"the output moves while the command and the model are at rest in {100 * share:.0f} % of samples"
    oscillation = _oscillation_text(y, still, delta, period_s)
    if not oscillation:
        return f"{moves}: an input the record does not contain (torque off, an external load) drives it"
    return f"{moves}, {oscillation}"


def _oscillation_text(y: NDArray[np.float64], still: NDArray[np.bool_], delta: float, period_s: float) -> str:
    """The output's oscillation where the command and the model rest, in words (:func:`_rest_oscillation`,
    larger than the noise bound), or an empty string: a limit cycle of the plant's own loop, or a periodic
    input the record does not contain, which the record cannot tell apart."""
    oscillation = _rest_oscillation(y, still)
    if oscillation is None or oscillation[1] <= delta:
        return ""
    period_samples, amplitude_rad = oscillation
    return (f"oscillating by +-{amplitude_rad:.3g} rad with a period of {period_samples * period_s:.3g} s "
            f"({1 / (period_samples * period_s):.3g} Hz) while the command and the model rest: a limit cycle of the "
            "plant's own loop (a position loop hunting through friction or play) looks so, as does a periodic input "
            "the record does not contain; this record cannot tell them apart (record the drive's torque, or hold "
            "with the loop gain changed: a limit cycle's amplitude and period follow the gain, an external input's "
            "do not)")


def _rest_oscillation(y: NDArray[np.float64], still: NDArray[np.bool_]) -> tuple[float, float] | None:
    """(period in samples, half its peak-to-peak amplitude after the first period, 1st to 99th percentile) of the
    output over the longest stretch where the command and the model rest, when it repeats there: its autocorrelation has a first peak of at least
    :data:`REST_OSCILLATION_CORRELATION` and the stretch holds :data:`REST_OSCILLATION_CYCLES` periods; else None."""
    best_start, best_length, start = 0, 0, None
    for index, flag in enumerate(np.append(still, False)):
        if flag and start is None:
            start = index
        elif not flag and start is not None:
            if index - start > best_length:
                best_start, best_length = start, index - start
            start = None
    segment = y[best_start:best_start + best_length + 1]
    segment = segment[np.isfinite(segment)]
    if segment.size < 8:
        return None
    centred = segment - segment.mean()
    spectrum = np.fft.rfft(centred, 2 * centred.size)
    correlation = np.fft.irfft(np.abs(spectrum) ** 2)[:centred.size]
    if correlation[0] <= 0.0:
        return None
    correlation = correlation / correlation[0]
    falling = np.flatnonzero(correlation < 0.0)
    if falling.size == 0 or falling[0] + 1 >= centred.size // REST_OSCILLATION_CYCLES:
        return None  # it never turns back, or not within a third of the stretch
    lag = int(falling[0] + np.argmax(correlation[falling[0]:centred.size // REST_OSCILLATION_CYCLES]))
    if lag <= falling[0] or correlation[lag] < REST_OSCILLATION_CORRELATION:
        return None
    settled = centred[lag:]  # the first period can still hold the end of the move before the rest
    return float(lag), 0.5 * float(np.percentile(settled, 99) - np.percentile(settled, 1))


def _not_excited(u: NDArray[np.float64], y: NDArray[np.float64], delta: float, model: PlantModel | None,
                 n_est: int, excitation: dict[str, Any], consistent_fraction: float) -> DiscrepancyResult:
    """The result of a record whose segments cannot show the effects (:func:`_excitation`): not scored, a
    verdict on a segment that cannot show the effects would be a guess."""
    start_model = model if model is not None else PlantModel((Delay(1),))
    initial = disagreement(start_model, u, y, delta, n_est)
    return DiscrepancyResult(
        steps=(), start_model=start_model, final_model=start_model, initial=initial, final=initial,
        consistent=initial.falsified_fraction <= consistent_fraction,
        unexplained=f"not judged: {excitation['reason']}", estimation_samples=n_est, noise_bound_rad=delta,
        linear_fit=None, verdict="not_excited", verdict_reason=str(excitation["reason"]), excitation=excitation,
    )


def _verdict(initial: Disagreement, final: Disagreement, steps: Sequence[DiscrepancyStep],
             ambiguous_between: tuple[str, ...], consistent: bool, delta: float,
             consistent_fraction: float, undecided: Sequence[CandidateResult] = (),
             min_reduction: float = MIN_REDUCTION, estimation_falsified: float = 0.0,
             estimation_samples: int = 0) -> tuple[str, str]:
    """The verdict of the workflow and the reason in words (package docstring, step 6). ``explained`` needs
    agreement on the whole record: at most ``consistent_fraction`` of the samples falsified on the validation
    segment and on the estimation segment alike (``estimation_falsified``, :func:`_estimation_falsified`); a
    start model that agrees on the validation segment only is ``unexplained``, with where it disagrees."""
    if initial.falsified_fraction <= consistent_fraction:
        if estimation_falsified > consistent_fraction:
            where = ", ".join(f"{w.start}-{w.stop - 1}" for w in initial.windows if w.start < estimation_samples)
            return "unexplained", (
                f"the start model agrees with the validation segment within the noise bound ({delta:.3g} rad), but "
                f"{100 * estimation_falsified:.1f} % of the estimation segment's samples are outside it"
                f"{' (samples ' + where + ')' if where else ''}: the record disagrees with the model there, which a "
                "validation segment that does not show it cannot judge")
        return "explained", (f"the start model agrees with the data within the noise bound ({delta:.3g} rad) on "
                             f"{100 * (1 - initial.falsified_fraction):.1f} % of validation samples and "
                             f"{100 * (1 - estimation_falsified):.1f} % of estimation samples; an effect that moves "
                             "the angle by less than the noise bound would not show in this record")
    named = ", ".join(step.effect for step in steps)
    if undecided:
        before = f"{named} named (gap {initial.gap_rad:.3g} -> {final.gap_rad:.3g} rad); then " if steps else ""
        words = "; ".join(f"with {c.effect} the validated gap is {_percent_lower(c.reduction)}, reduction "
                          f"{c.interval_text()} within its uncertainty" for c in undecided)
        return "ambiguous", (f"{before}{words}, against {100 * min_reduction:.0f} % required: whether "
                             f"{'it is' if len(undecided) == 1 else 'they are'} there cannot be told from this "
                             "record, so none is named")
    if ambiguous_between:
        before = f" after {named}" if steps else ""
        pairs = [frozenset((a, b)) for i, a in enumerate(ambiguous_between) for b in ambiguous_between[i + 1:]]
        experiments = look_alike_experiments(pairs)
        names = " and ".join((", ".join(ambiguous_between[:-1]), ambiguous_between[-1]))
        return "ambiguous", (f"{names} fit the validation segment equally well within "
                             f"their uncertainty{before}: none is chosen"
                             + (f". To separate them: {experiments}" if experiments else ""))
    if steps:
        left = ("the model is then consistent with the noise bound" if consistent else
                f"{100 * final.falsified_fraction:.1f} % of validation samples stay outside the noise bound: part "
                "of the disagreement is unexplained")
        verb = "lowers" if len(steps) == 1 else "lower"
        return "named", f"{named} {verb} the validated gap from {initial.gap_rad:.3g} to {final.gap_rad:.3g} rad; {left}"
    return "unexplained", (f"{100 * initial.falsified_fraction:.1f} % of validation samples are outside the noise "
                           f"bound and no candidate lowers the validated gap ({initial.gap_rad:.3g} rad) enough")


def _estimation_falsified(initial: Disagreement, y: NDArray[np.float64], n_est: int) -> float:
    """The fraction of the estimation segment's measured samples that ``initial`` falsifies (its
    ``falsified_fraction`` is the validation segment's)."""
    measured = max(int(np.count_nonzero(~np.isnan(y[:n_est]))), 1)
    return float(np.count_nonzero(initial.falsified[:n_est]) / measured)


def _with_findings(result: DiscrepancyResult, findings: Sequence[GrossDisagreement]) -> DiscrepancyResult:
    """``result`` of the record with its gross disagreements put aside (:func:`gross_disagreements`), with
    them: carried in ``findings`` and said first in the verdict's reason. A record with findings is never
    ``explained``: when the rest agrees with the start model the verdict is ``unexplained`` (by the model:
    the disagreement is the measurement's)."""
    if not findings:
        return result
    said = "; ".join(finding.text() for finding in findings)
    put_aside = "undone" if all(f.kind == "sensor_wrap" for f in findings) else "put aside"
    if result.verdict == "explained":
        verdict = "unexplained"
        reason = (f"{said}. With {'it' if len(findings) == 1 else 'them'} {put_aside}, {result.verdict_reason}: "
                  "the record's disagreement is the measurement's, which no model effect explains")
    else:
        verdict = result.verdict
        reason = f"{said}. With {'it' if len(findings) == 1 else 'them'} {put_aside}: {result.verdict_reason}"
    return replace(result, verdict=verdict, verdict_reason=reason, findings=(*findings, *result.findings),
                   unexplained=f"{said}; {result.unexplained}")


def _percent_lower(reduction: float) -> str:
    """A gap reduction in words: "18 % lower", or "35 % higher" when it grew."""
    return f"{100 * abs(reduction):.0f} % {'lower' if reduction >= 0 else 'higher'}"


def _final_verdict(u: NDArray[np.float64], y: NDArray[np.float64], initial: Disagreement, final: Disagreement,
                   found: _Search, consistent: bool, delta: float, period_s: float,
                   options: DiagnoseOptions) -> tuple[str, str]:
    """:func:`_verdict` (ambiguous when the named map is also another mechanism's, ``found.mechanism_reason``),
    and a record where nothing is named (unexplained, or ambiguous before any effect) whose output moves on its own (:func:`_unmeasured_input`) is not excited by the command instead: a
    candidate undecided on such a record is as meaningless as none, the record cannot test the model."""
    n_est = int(round(options.estimation_fraction * u.size))
    ambiguous_between = () if found.mechanism_reason else found.ambiguous_between
    verdict, reason = _verdict(initial, final, found.steps, ambiguous_between, consistent, delta,
                               options.consistent_fraction, found.undecided, options.min_reduction,
                               _estimation_falsified(initial, y, n_est), n_est)
    if found.mechanism_reason and verdict == "named":  # the map is named, its mechanism left open
        verdict, reason = "ambiguous", f"{reason}; {found.mechanism_reason}"
    if found.beyond_device_reason:
        reason = f"{reason}; {found.beyond_device_reason}"
    if found.look_alike_reason and verdict == "ambiguous":
        named = ", ".join(step.effect for step in found.steps)
        reason = (f"{named} named (gap {initial.gap_rad:.3g} -> {final.gap_rad:.3g} rad); then " if named else "") \
            + found.look_alike_reason
    if verdict == "unexplained" or (verdict == "ambiguous" and not found.steps):
        unmeasured = _unmeasured_input(u, y, final.simulated_rad, delta, period_s)
        if unmeasured:
            return "not_excited", unmeasured
    if verdict in ("unexplained", "ambiguous", "named"):  # what the catalogue cannot name, said as what it is
        oscillation = _oscillation_text(y, _at_rest(u, final.simulated_rad, delta), delta, period_s)
        if oscillation:
            reason = f"{reason}; the output is {oscillation}"
    return verdict, reason


def _left_unexplained(current: Disagreement, consistent: bool, delta: float, left_open: Sequence[str] = ()) -> str:
    """What is left, in words (:attr:`DiscrepancyResult.unexplained`); ``left_open``: candidates not added
    that the verdict leaves open (ambiguous or undecided)."""
    if consistent:
        return "the model is consistent with the noise bound on the validation segment"
    left = (f"{100 * current.falsified_fraction:.1f} % of validation samples still exceed the noise bound "
            f"(gap {current.gap_rad:.3g} rad against a bound of {delta:.3g} rad)")
    if left_open:
        return (f"{left}; {', '.join(left_open)} would lower the validated gap, but this record cannot tell "
                f"whether {'it is' if len(left_open) == 1 else 'they are'} there (the verdict's reason): not added")
    return f"{left} and none of the candidate effects lowers the validated gap further: what is left is unexplained"
