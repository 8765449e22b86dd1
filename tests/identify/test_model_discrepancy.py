"""The model-discrepancy workflow on hidden-effect data: a linear gearbox model plus one (or two) effects with
random realistic parameters, read by a 12-bit encoder; the workflow sees only the data, the noise bound and
(in part of the cases) the nominal model without the effect."""

from __future__ import annotations

import re

import json
from dataclasses import replace

import numpy as np
import pytest

from identify.discrepancy_cases import NOMINAL_LINEAR, hidden_effect_record
from identify.border_lifting import direction_signal
from identify.effect_catalogue import EFFECTS, SEARCHED_EFFECT_NAMES
from identify.effect_signatures import EFFECT_NAMES, signature_scores
from identify.model_discrepancy import (
    REFIT_FOLDS,
    CandidateResult,
    Disagreement,
    DiscrepancyReport,
    DiscrepancyStep,
    diagnose_model,
    disagreement,
    fit_linear_model,
)
from identify.model_discrepancy.chain import _Chain, _Component
from identify.model_discrepancy.judgement import _acceptance, _refit_reduction, _with_refits, _within_uncertainty
from identify.model_discrepancy.search import _clear_end, _Search, _still_needed
from identify.model_discrepancy import DiagnoseOptions
from identify.plant_blocks import DeadZone, Delay, LinearBlock, OutputBacklash, OutputGain, OutputOffset, PlantModel
from identify.validation import InvalidInputError

SIX = ("backlash", "dead_zone", "saturation", "delay", "coulomb_friction", "resonance")


SERIES = tuple(name for name in EFFECT_NAMES if EFFECTS[name].placement != "dynamics")
"""The effects that are blocks of the series chain. The fitted-start tests of these effects try only them:
each drive-train candidate costs a sub-stepped simulation per evaluation (from a fitted start 5-10 times
the whole series search), and that the drive-train candidates do not take these effects' place is what
``benchmarks/model_discrepancy_confusion.py`` checks with the whole catalogue (BENCHMARKS.md)."""


def run(record, given_model=True, candidates=SEARCHED_EFFECT_NAMES):
    return diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                          record.nominal_model if given_model else None, candidates=candidates)


@pytest.mark.parametrize("effect", SIX)
@pytest.mark.parametrize("seed", [11, 12])
def test_names_the_hidden_effect_and_halves_the_gap_given_the_nominal_model(effect, seed):
    record = hidden_effect_record((effect,), seed)
    result = run(record)
    assert result.missing_effects, f"{effect}: nothing named, gap {result.initial.gap_rad:.3g} rad"
    assert result.missing_effects[0] == effect, f"{effect} named {result.missing_effects}"
    assert result.final.gap_rad <= 0.5 * result.initial.gap_rad
    assert result.steps[0].gap_after_rad <= 0.5 * result.steps[0].gap_before_rad


@pytest.mark.parametrize("effect", SIX)
def test_names_the_hidden_effect_from_a_fitted_linear_start_model(effect):
    record = hidden_effect_record((effect,), 21)
    result = run(record, given_model=False, candidates=SERIES)
    assert result.linear_fit is not None
    if effect == "delay":
        # a delay of 5 samples: with a linear block of order 4 in the start's place (a pole pair near a quarter
        # of the sampling rate) the model fits as well without it, so from a fitted start the record cannot tell
        # the delay from poles
        assert result.verdict == "ambiguous" and result.ambiguous_between == ("delay",)
        assert "linear block of order 4" in result.verdict_reason
        return
    assert result.missing_effects[:1] == (effect,)
    assert result.final.gap_rad <= 0.5 * result.initial.gap_rad
    # the fitted linear block is refitted with the effect: what is left is the 12-bit encoder's noise
    assert result.final.gap_rad < 1.5 * record.noise_bound_rad


@pytest.mark.parametrize("seed", [31, 32])
@pytest.mark.parametrize("given_model", [True, False])
def test_names_nothing_when_no_effect_is_missing(seed, given_model):
    record = hidden_effect_record((), seed)
    result = run(record, given_model)
    assert result.missing_effects == ()
    assert result.consistent
    assert result.to_dict()["missing_effects"] == []
    # 12-bit quantisation plus 0.2 mrad noise: the RMS error of a right model is below the bound / sqrt(3)
    assert result.final.gap_rad < record.noise_bound_rad / np.sqrt(3.0) * 1.1


def test_finds_backlash_and_delay_together():
    record = hidden_effect_record(("backlash", "delay"), 41)
    true_delay = record.true_model.find(Delay)[0].samples
    result = run(record, candidates=SERIES)
    assert set(result.missing_effects[:2]) == {"backlash", "delay"}
    delay_step = next(step for step in result.steps if step.effect == "delay")
    # the play adds lag of its own, so the delay is found to within a few samples
    assert abs(delay_step.parameters["samples"] - true_delay) <= 3
    assert result.final.gap_rad <= 0.1 * result.initial.gap_rad


@pytest.mark.parametrize("seed", [91, 92])
def test_names_a_wrong_scale_gain_error_and_fits_it(seed):
    record = hidden_effect_record(("gain_error",), seed)
    true_gain = record.true_model.find(OutputGain)[0].gain
    result = run(record)
    assert result.missing_effects == ("gain_error",)
    assert result.steps[0].parameters["gain"] == pytest.approx(true_gain, abs=2e-3)
    assert result.final.gap_rad <= 0.5 * result.initial.gap_rad
    assert result.consistent


def test_fitted_parameters_are_close_to_the_truth():
    record = hidden_effect_record(("dead_zone",), 51)
    truth = record.true_model.blocks[0]
    step = run(record).steps[0]
    assert step.parameters["left_rad"] == pytest.approx(truth.left_rad, abs=3e-3)
    assert step.parameters["right_rad"] == pytest.approx(truth.right_rad, abs=3e-3)


JSON_KEYS = {"verdict", "verdict_reason", "noise_bound", "missing_effects", "ambiguous_between", "candidates",
             "gap_initial", "gap_final", "gap_reduction", "falsified_fraction_initial", "falsified_fraction_final",
             "excitation", "operating_point", "undecided", "findings", "residual_structure", "restart_window_samples",
             "load_torque_check", "kind", "version"}


def test_json_document_has_exactly_the_documented_keys():
    record = hidden_effect_record(("dead_zone",), 61)
    document = run(record).to_dict()
    assert set(document) == JSON_KEYS
    assert document["verdict"] == "named"
    assert document["noise_bound"] == pytest.approx(record.noise_bound_rad)
    (entry,) = document["missing_effects"]
    assert set(entry) == {"effect", "parameters", "parameter_intervals", "gap_before", "gap_after"}
    assert entry["effect"] == "dead_zone"
    assert entry["gap_before"] == pytest.approx(document["gap_initial"])
    assert entry["gap_after"] == pytest.approx(document["gap_final"])
    assert document["falsified_fraction_final"] < document["falsified_fraction_initial"]


def test_disagreement_windows_cover_the_falsified_samples():
    u = np.zeros(400)
    u[100:] = 1.0
    model = PlantModel((LinearBlock(a=(-0.9,), b=(0.0, 0.1), sample_period_s=1e-3),))
    y = model.simulate(u)
    y[200:230] += 0.05  # a burst the model cannot explain
    result = disagreement(model, u, y, noise_bound_rad=0.01)
    assert result.falsified_fraction == pytest.approx(30 / 400)
    (window,) = result.windows
    assert (window.start, window.stop, window.falsified_samples) == (200, 230, 30)
    assert window.peak_residual_rad == pytest.approx(0.05)


def test_linear_start_model_recovers_the_nominal_block_and_its_order():
    record = hidden_effect_record((), 71)
    fit = fit_linear_model(record.command_rad, record.angle_rad, record.sample_period_s, 1800)
    assert fit.order == 2
    assert fit.block.a == pytest.approx(NOMINAL_LINEAR.a, abs=2e-3)
    assert fit.block.static_gain == pytest.approx(1.0, abs=2e-3)


@pytest.mark.parametrize("seed", [81, 82, 83])
def test_signatures_point_at_the_effect(seed):
    record = hidden_effect_record(("delay",), seed)
    simulated = record.nominal_model.simulate(record.command_rad)
    scores = signature_scores(record.command_rad, record.angle_rad, simulated, record.noise_bound_rad,
                              record.sample_period_s)
    assert set(scores) == set(EFFECT_NAMES)
    true_delay = record.true_model.find(Delay)[0].samples
    assert max(scores, key=lambda name: scores[name].score) == "delay"
    assert scores["delay"].score > 0.9
    assert scores["delay"].details["delay_samples"] == true_delay
    assert abs(scores["delay"].details["lag_of_peak_correlation_samples"] - true_delay) <= true_delay


def test_direction_signal_holds_the_last_direction():
    values = np.array([0.0, 1.0, 2.0, 2.0, 2.0, 1.0, 1.0, 3.0])
    assert direction_signal(values, threshold=0.5).tolist() == [0.0, 1.0, 1.0, 1.0, 1.0, -1.0, -1.0, 1.0]


def test_misuse_is_reported_by_argument_name():
    u = np.zeros(100)
    with pytest.raises(InvalidInputError, match="noise_bound_rad"):
        diagnose_model(u, u, 0.0, 1e-3)
    with pytest.raises(InvalidInputError, match="candidates"):
        diagnose_model(u, u, 1e-3, 1e-3, candidates=("gremlins",))
    with pytest.raises(InvalidInputError, match="angle_rad"):
        diagnose_model(u, u[:50], 1e-3, 1e-3)
    with pytest.raises(InvalidInputError, match=r"command_rad: the input is constant \(0 in all 100 samples\)"):
        diagnose_model(u, u, 1e-3, 1e-3)


@pytest.mark.parametrize("seed", [0, 2, 4])
def test_the_residual_input_correlation_peaks_after_the_hidden_delay(seed):
    record = hidden_effect_record(("delay",), seed)
    (delay,) = [block for block in record.true_model.blocks if isinstance(block, Delay)]
    simulated = record.nominal_model.simulate(record.command_rad)
    details = signature_scores(record.command_rad, record.angle_rad, simulated, record.noise_bound_rad,
                               record.sample_period_s)["delay"].details
    # r_t = y^_{t-d} - y^_t answers an input step d samples after the model does, and the model's own
    # response peaks a few samples after the step
    assert delay.samples <= details["lag_of_peak_residual_input_correlation_samples"] <= delay.samples + 10


# ----------------------------------------------------------------------------------------------------------
# The verdict
# ----------------------------------------------------------------------------------------------------------


def test_a_record_with_no_hidden_effect_is_explained():
    record = hidden_effect_record((), 31)
    result = run(record)
    assert result.verdict == "explained"
    assert result.to_dict()["candidates"] == []


def test_a_named_effect_carries_parameter_intervals_containing_its_fit_and_a_gap_reduction_range():
    record = hidden_effect_record(("backlash",), 11)
    result = run(record)
    # the play's map is named; from positions alone it is also friction without stiction: mechanism left open
    assert result.verdict == "ambiguous" and result.ambiguous_between == ("backlash", "coulomb_friction")
    document = result.to_dict()
    assert document["kind"] == "model_discrepancy" and document["version"] == 7
    assert DiscrepancyReport.from_dict(json.loads(json.dumps(document))) == result.report()
    (entry,) = document["missing_effects"]
    truth = record.true_model.blocks[1]
    for key, true_value in (("c_l_rad", truth.c_l_rad), ("c_r_rad", truth.c_r_rad)):
        low, high = entry["parameter_intervals"][key]
        assert low <= entry["parameters"][key] <= high
        # the interval contains the truth and is no wider than the encoder's resolution (+-delta) plus a
        # tenth of the play
        assert low <= true_value <= high
        assert high - low < 2 * record.noise_bound_rad + 0.1 * true_value
    reduction = document["gap_reduction"]
    assert len(reduction["folds"]) == 4 and 0.9 < reduction["low"] <= reduction["high"] <= 1.0
    tried = {c["effect"] for c in document["candidates"] if c["round"] == 0}
    # every effect the rigid model can hold (not the friction inside a shaft it does not have), and the inner
    # twin of the hysteresis that won the round (tried as one compound candidate)
    assert tried == ({name for name in SEARCHED_EFFECT_NAMES if not EFFECTS[name].needs_shaft}
                     | {"+".join(EFFECTS["backlash"].inner_twin)})
    assert all(c["gap"] > 0 and c["gap_uncertainty"] >= 0 for c in document["candidates"])


def test_two_candidates_equally_good_are_ambiguous_and_none_is_chosen():
    # a dead band on a command that stays positive takes a constant off it: but for the first transient the
    # record is the same as an offset of the output, and within the noise (20 mrad) the two validated gaps
    # differ by less than 1 %
    rng = np.random.default_rng(1)
    u = 0.3 + 0.6 * rng.uniform(size=20).repeat(150)
    truth = PlantModel((DeadZone(left_rad=-0.1, right_rad=0.1), NOMINAL_LINEAR))
    y = truth.simulate(u) + rng.uniform(-2e-2, 2e-2, u.size)
    result = diagnose_model(u, y, 2.1e-2, 0.001, PlantModel((NOMINAL_LINEAR,)), candidates=("dead_zone", "offset"))
    assert result.verdict == "ambiguous", result.verdict_reason
    assert set(result.ambiguous_between) == {"offset", "dead_zone"}
    assert result.missing_effects == ()
    assert "none is chosen" in result.verdict_reason


def test_a_command_that_never_reverses_is_not_excited_and_not_scored():
    u = np.linspace(0.0, 1.0, 2000)
    y = PlantModel((NOMINAL_LINEAR, Delay(5))).simulate(u)
    result = diagnose_model(u, y, 1e-3, 0.001, PlantModel((NOMINAL_LINEAR,)))
    assert result.verdict == "not_excited"
    assert "never reverses" in result.verdict_reason
    assert result.candidates == () and result.missing_effects == ()


def test_a_validation_segment_with_too_few_reversals_is_said_to_be_too_short():
    u = np.concatenate((np.tile(np.repeat([0.5, -0.5], 100), 6), np.full(900, 0.5)))
    y = PlantModel((NOMINAL_LINEAR,)).simulate(u)
    result = diagnose_model(u, y, 1e-3, 0.001, PlantModel((NOMINAL_LINEAR, OutputGain(1.1))))
    assert result.verdict == "not_excited"
    assert "validation segment is too short" in result.verdict_reason


def test_an_output_moving_while_command_and_model_rest_is_an_unmeasured_input():
    rng = np.random.default_rng(3)
    record = hidden_effect_record((), 31)
    swing = np.zeros(record.command_rad.size)
    still = np.flatnonzero(np.abs(np.diff(record.command_rad, prepend=0.0)) == 0.0)
    swing[still] = 0.05 * np.sin(still / 7.0) + rng.uniform(-1e-3, 1e-3, still.size)
    result = diagnose_model(record.command_rad, record.angle_rad + swing, record.noise_bound_rad,
                            record.sample_period_s, record.nominal_model)
    # a 50 mrad swing at 23 Hz while the command holds: no candidate explains it, and it is not the command's;
    # it repeats, so it is said with its amplitude and period, and as what it can be: the plant's own limit
    # cycle (a loop hunting through friction or play) or a periodic input the record does not contain
    assert result.verdict == "not_excited", result.verdict_reason
    assert "input the record does not contain" in result.verdict_reason and "limit cycle" in result.verdict_reason
    assert result.missing_effects == ()
    period_s = float(re.search(r"a period of ([0-9.e-]+) s", result.verdict_reason).group(1))
    amplitude = float(re.search(r"oscillating by \+-([0-9.e-]+) rad", result.verdict_reason).group(1))
    assert period_s == pytest.approx(2 * np.pi * 7 * record.sample_period_s, rel=0.05)
    assert amplitude == pytest.approx(0.05, rel=0.1)


def test_an_output_drifting_while_command_and_model_rest_is_no_limit_cycle():
    rng = np.random.default_rng(3)
    record = hidden_effect_record((), 31)
    drift = np.zeros(record.command_rad.size)
    still = np.flatnonzero(np.abs(np.diff(record.command_rad, prepend=0.0)) == 0.0)
    drift[still] = np.cumsum(rng.normal(0.0, 0.004, still.size))  # a hand on the arm: no period
    # candidates that could take a slow wander for an effect (a constant, a load torque, a play, a lag); the
    # whole catalogue gives the same answer in 45 s instead of a few
    result = diagnose_model(record.command_rad, record.angle_rad + drift, record.noise_bound_rad,
                            record.sample_period_s, record.nominal_model,
                            candidates=("offset", "gravity", "backlash", "delay"))
    assert result.verdict == "not_excited", result.verdict_reason
    assert "input the record does not contain" in result.verdict_reason and "limit cycle" not in result.verdict_reason


def test_a_gain_error_is_not_a_candidate_against_a_fitted_start_model():
    record = hidden_effect_record(("gain_error",), 71)
    result = run(record, given_model=False)
    assert "gain_error" not in {c.effect for c in result.candidates}


def test_a_record_in_absolute_angles_runs_freely_from_its_operating_point_not_from_zero():
    record = hidden_effect_record(("backlash",), 11)
    shift = 3.1
    result = diagnose_model(record.command_rad + shift, record.angle_rad + shift, record.noise_bound_rad,
                            record.sample_period_s, record.nominal_model)
    assert result.operating_point_rad == pytest.approx(shift, abs=2e-3)
    assert result.missing_effects == ("backlash",)
    # the same answer as on the record at zero: no start-up transient from 0 to 3.1 rad
    at_zero = run(record)
    assert result.initial.gap_rad == pytest.approx(at_zero.initial.gap_rad, rel=1e-6)
    assert result.final.gap_rad == pytest.approx(at_zero.final.gap_rad, rel=0.05)
    # the models returned work in absolute angles: the final one reproduces the measurement within the noise
    simulated = result.final_model.simulate(record.command_rad + shift)
    assert np.sqrt(np.mean((simulated - record.angle_rad - shift)[result.estimation_samples:] ** 2)) < 2 * record.noise_bound_rad
    assert result.final.simulated_rad == pytest.approx(simulated)


def test_repetitions_of_one_experiment_give_one_answer_with_overlapping_intervals():
    """Repeatability on the simulator: the same plant and command, measured four times with fresh noise."""
    record = hidden_effect_record(("backlash",), 12)
    clean = record.true_model.simulate(record.command_rad)
    count = 2 * np.pi / 2 ** 12
    answers, intervals = set(), []
    for repetition in range(4):
        rng = np.random.default_rng(100 + repetition)
        y = np.round((clean + rng.uniform(-2e-4, 2e-4, clean.size)) / count) * count
        result = diagnose_model(record.command_rad, y, record.noise_bound_rad, record.sample_period_s,
                                record.nominal_model)
        answers.add((result.verdict, result.missing_effects, result.ambiguous_between))
        intervals.append(result.parameter_intervals["backlash"])
    assert answers == {("ambiguous", ("backlash",), ("backlash", "coulomb_friction"))}
    for key in ("c_l_rad", "c_r_rad"):
        assert max(i[key][0] for i in intervals) <= min(i[key][1] for i in intervals), \
            f"{key}: {[i[key] for i in intervals]}"


@pytest.mark.parametrize("offset_noise_ratio, verdict", [(0.2, "unexplained"), (0.43, "ambiguous"), (1.0, "named")])
def test_an_effect_whose_gap_reduction_straddles_the_acceptance_is_undecided_not_named(offset_noise_ratio, verdict):
    # a constant offset c under uniform noise +-a: fitting the offset takes the gap from sqrt(c^2 + a^2/3) to
    # a/sqrt(3), i.e. with the penalty of its 2 parameters (1.06) by 1 - 1.06 / sqrt(1 + 3 c^2 / a^2): about
    # -4 %, 15 % (the acceptance) and 47 % for c/a = 0.2, 0.43 and 1
    record = hidden_effect_record((), 31)
    rng = np.random.default_rng(5)
    noise = 0.02
    y = record.nominal_model.simulate(record.command_rad) + offset_noise_ratio * noise \
        + rng.uniform(-noise, noise, record.command_rad.size)
    result = diagnose_model(record.command_rad, y, 0.9 * noise, record.sample_period_s, record.nominal_model,
                            candidates=("offset",))
    assert result.verdict == verdict, result.verdict_reason
    (candidate,) = result.candidates
    low, high = candidate.reduction_interval
    assert low <= candidate.reduction <= high
    if verdict == "ambiguous":
        assert candidate.acceptance == "undecided" and low < 0.15 < high
        assert result.undecided == (candidate,) and result.ambiguous_between == ("offset",)
        assert result.missing_effects == () and "cannot be told" in result.verdict_reason
        document = json.loads(json.dumps(result.to_dict()))
        assert document["undecided"][0]["effect"] == "offset"
        assert DiscrepancyReport.from_dict(document) == result.report()
    else:
        assert candidate.acceptance == ("clear" if verdict == "named" else "rejected")
        assert result.undecided == ()


def test_a_clear_effect_is_named_with_its_reduction_clear_over_validation_blocks_and_refits():
    record = hidden_effect_record(("backlash",), 11)
    result = run(record, candidates=("backlash",))
    assert result.missing_effects == ("backlash",)
    (candidate,) = result.candidates
    assert candidate.acceptance == "clear" and len(candidate.fold_reductions) == REFIT_FOLDS
    low, high = candidate.reduction_interval
    assert low >= 0.15 and min(candidate.fold_reductions) >= 0.15
    assert candidate.reduction_interval == candidate.refit_interval  # the refits measure the size...
    assert candidate.reduction >= 0.15  # ... and the validation segment shows it too
    document = json.loads(json.dumps(result.to_dict()))
    assert document["version"] == 7 and len(document["candidates"][0]["fold_reductions"]) == REFIT_FOLDS
    assert DiscrepancyReport.from_dict(document) == result.report()


def _fold_errors(gaps_rad, samples=50, seed=0):
    rng = np.random.default_rng(seed)
    return [gap * np.sign(rng.standard_normal(samples)) for gap in gaps_rad]


def test_a_reduction_the_refits_put_on_both_sides_of_the_acceptance_is_undecided():
    # the validation blocks alone say 30-40 %: clear; the folds say 60, 50, 0 and 10 %: pooled 25 %, but
    # leaving out one fold moves it from 17 to 36 %, so the jackknife interval reaches below 15 %
    entry = CandidateResult(0, "offset", 0.65, 0.01, 0.65, {"offset_rad": 0.1}, False, True, 0.35, (0.30, 0.40),
                            "clear", (0.30, 0.40))
    baseline = _fold_errors([1.0, 1.0, 1.0, 1.0])
    folds, refit = _refit_reduction(_fold_errors([0.4, 0.5, 1.0, 0.9]), baseline, 1.0)
    assert folds == pytest.approx((0.6, 0.5, 0.0, 0.1))
    assert refit[0] < 0.15 < refit[1]
    judged = _with_refits(entry, folds, refit, 0.15)
    assert judged.acceptance == "undecided" and judged.reduction_interval == (refit[0], max(0.40, refit[1]))
    # the same refits all near 35 %: the union stays clear
    steady, interval = _refit_reduction(_fold_errors([0.64, 0.66, 0.65, 0.65]), baseline, 1.0)
    assert _with_refits(entry, steady, interval, 0.15).acceptance == "clear"
    # and refits all near 0 % against a validation interval straddling the acceptance: undecided, not rejected
    none, interval = _refit_reduction(_fold_errors([1.0, 1.01, 0.99, 1.0]), baseline, 1.0)
    straddling = replace(entry, validation_interval=(0.05, 0.25), acceptance="undecided")
    assert _with_refits(straddling, none, interval, 0.15).acceptance == "undecided"
    assert _with_refits(replace(entry, validation_interval=(0.02, 0.10)), none, interval, 0.15).acceptance \
        == "rejected"


def _block_errors(block_gaps_rad, samples=40, seed=0):
    return np.concatenate(_fold_errors(block_gaps_rad, samples, seed))


def test_an_effect_the_record_excites_in_one_validation_block_is_judged_by_its_refits():
    # a torque limit reached once in the validation segment: one block 50 noise bounds off, removed, the next
    # one just beyond the bound as the motion settles, and the six others within the noise (as the
    # hidden-effect record given the model, seed 1006)
    noise_bound = 1.0
    current = _block_errors([0.5, 50.0, 1.2, 0.5, 0.5, 0.5, 0.5, 0.5])
    candidate = _block_errors([0.5] * 8)
    factor = 1.03
    penalised, gap = factor * float(np.sqrt(np.mean(candidate ** 2))), float(np.sqrt(np.mean(current ** 2)))
    reduction, validation, word = _acceptance(candidate, factor, current, penalised, gap, 0.15, noise_bound)
    assert reduction > 0.95 and validation[0] < 0.15 < validation[1] and word == "undecided"
    entry = CandidateResult(0, "torque_limit", penalised / factor, 0.0, penalised, {}, False, True, reduction,
                            validation, word, validation)
    # the 8 refits over the whole record see the limit in every fold: clear, and their interval is judged
    baseline = _fold_errors([10.0, 12.0, 9.0, 11.0, 10.0, 13.0, 8.0, 10.0])
    folds, refit = _refit_reduction(_fold_errors([0.5, 0.6, 0.5, 0.7, 0.5, 0.6, 0.5, 0.5]), baseline, factor)
    judged = _with_refits(entry, folds, refit, 0.15)
    assert judged.acceptance == "clear" and judged.reduction_interval == refit and refit[0] > 0.9
    # refits that straddle the acceptance: the union, undecided
    straddling, interval = _refit_reduction(_fold_errors([2.0, 12.0, 1.0, 11.0, 2.0, 13.0, 1.0, 10.0]), baseline,
                                            factor)
    assert interval[0] < 0.15 < interval[1]
    assert _with_refits(entry, straddling, interval, 0.15).acceptance == "undecided"
    # clear refits with a validated reduction under the acceptance: the validation segment does not show it
    weak = replace(entry, reduction=0.10, validation_interval=(-0.5, 0.6), acceptance="undecided")
    judged = _with_refits(weak, folds, refit, 0.15)
    assert judged.acceptance == "undecided" and judged.reduction_interval == (-0.5, max(0.6, refit[1]))
    # but refits clearly below the acceptance do not reject alone: the union straddles, undecided (on real
    # servo records the other way moved repetitions of one experiment between ambiguous and unexplained)
    none, interval = _refit_reduction(_fold_errors([10.0, 12.5, 8.5, 11.0, 10.0, 12.0, 8.0, 10.5]), baseline, factor)
    assert interval[1] < 0.15
    assert _with_refits(weak, none, interval, 0.15).acceptance == "undecided"


def test_a_torque_limit_reached_once_in_the_validation_segment_is_named():
    record = hidden_effect_record(("torque_limit",), 1006)
    result = run(record)
    assert result.verdict == "named" and result.missing_effects == ("torque_limit",), result.verdict_reason
    entry = next(c for c in result.candidates if c.effect == "torque_limit" and c.acceptance == "clear")
    assert entry.validation_interval[0] < 0.15 <= entry.reduction  # the block spread alone would not decide
    assert entry.refit_interval[0] >= 0.15


def test_a_version_3_document_is_still_read():
    record = hidden_effect_record(("backlash",), 11)
    document = json.loads(json.dumps(run(record, candidates=("backlash",)).to_dict()))
    document["version"] = 3
    del document["findings"]
    report = DiscrepancyReport.from_dict(document)
    assert report.findings == () and report.missing_effects[0].effect == "backlash"


def test_a_version_2_document_is_still_read():
    record = hidden_effect_record(("backlash",), 11)
    document = json.loads(json.dumps(run(record, candidates=("backlash",)).to_dict()))
    document["version"] = 2
    for candidate in document["candidates"]:
        for key in ("validation_interval", "fold_reductions", "refit_interval"):
            del candidate[key]
    (candidate,) = DiscrepancyReport.from_dict(document).candidates
    assert candidate.refit_interval is None and candidate.fold_reductions == ()
    assert candidate.validation_interval == candidate.reduction_interval


def test_a_version_1_document_is_still_read():
    record = hidden_effect_record(("backlash",), 11)
    document = json.loads(json.dumps(run(record, candidates=("backlash",)).to_dict()))
    document["version"] = 1
    del document["undecided"]
    for candidate in document["candidates"]:
        for key in ("reduction", "reduction_interval", "acceptance"):
            del candidate[key]
    report = DiscrepancyReport.from_dict(document)
    assert report.undecided == () and report.missing_effects[0].effect == "backlash"
    assert all(c.acceptance == "" for c in report.candidates)


def test_a_keyword_that_is_no_option_is_refused_with_the_options_listed():
    command = np.sin(np.linspace(0.0, 20.0, 400))
    with pytest.raises(TypeError, match=r"diagnose_model\(\) got an unexpected keyword argument 'max_effect' "
                                        r"\(the options are estimation_fraction, candidates, max_effects, "):
        diagnose_model(command, command, 1e-3, 0.01, max_effect=2)


def test_an_end_the_validation_falsifies_is_no_tie_of_one_consistent_with_the_noise_bound():
    # hidden load_friction + gravity, seed 1010: the ends followed from an undecided round were load_friction
    # + gravity (0.489 mrad, 0.7 % of the validation samples outside the bound) and backlash + gain_error +
    # load_friction (0.728 mrad, 11.8 % outside); one block of the second, held on an encoder count, was at
    # 0.083 mrad, so the per-block log ratios spread from -1.4 to 0.9 and the two were "within their
    # uncertainty": ambiguous, nothing named. Here the same shape: the second end falsified in three blocks
    rng = np.random.default_rng(3)
    delta, blocks = 1.0e-3, np.array_split(np.arange(1200), 8)
    consistent = rng.uniform(-0.8 * delta, 0.8 * delta, 1200)
    falsified = consistent.copy()
    for k, scale in ((1, 2.4), (3, 0.15), (4, 2.4), (7, 2.0)):
        falsified[blocks[k]] *= scale

    def end(error, effects, bound=delta):
        current = Disagreement(np.zeros(error.size), error, np.abs(error) > bound,
                               float(np.mean(np.abs(error) > bound)), float(np.sqrt(np.mean(error ** 2))), ())
        steps = [DiscrepancyStep(name, {}, {}, 0.0, 0.0, 0.0, 0.0, PlantModel((NOMINAL_LINEAR,))) for name in effects]
        return _Search(_Chain([]), current, steps, [], (), error)

    good = end(consistent, ("load_friction", "gravity"))
    bad = end(falsified, ("backlash", "gain_error", "load_friction"))
    assert good.current.falsified_fraction == 0.0 and bad.current.falsified_fraction > 0.1
    cost = lambda e, parameters: e.current.gap_rad * (1.0 + 0.03 * parameters)  # noqa: E731
    assert _within_uncertainty(cost(good, 5), good.validation_error_rad, cost(bad, 6), bad.validation_error_rad)
    assert _clear_end([bad, good], 0.03, 0.01) is good
    # the same errors under a bound both are consistent with: a tie, ambiguous as before
    wide = 3.0 * delta
    assert _clear_end([end(falsified, ("backlash", "gain_error", "load_friction"), wide),
                       end(consistent, ("load_friction", "gravity"), wide)], 0.03, 0.01) is None


def _named_search(record, effects_and_values):
    """A finished search on ``record`` with the given model and ``effects_and_values`` (name, values) added in
    that order, each step's gaps those of the model up to it."""
    n_est = int(round(0.6 * record.command_rad.size))
    components = [_Component("fixed", block=block) for block in record.nominal_model.blocks]
    steps, before = [], disagreement(record.nominal_model, record.command_rad, record.angle_rad,
                                     record.noise_bound_rad, n_est)
    for name, values in effects_and_values:
        at = len(components) if EFFECTS[name].placement == "end" else 1
        components.insert(at, _Component(name, values, sample_period_s=record.sample_period_s))
        chain = _Chain(components)
        after = disagreement(chain.model(), record.command_rad, record.angle_rad, record.noise_bound_rad, n_est)
        steps.append(DiscrepancyStep(name, {}, {}, before.gap_rad, after.gap_rad, before.falsified_fraction,
                                     after.falsified_fraction, chain.model()))
        before = after
    return _Search(chain, before, steps, [], (), before.residual_rad[n_est:]), n_est


def test_an_effect_the_later_ones_make_redundant_is_dropped_and_one_still_needed_is_kept():
    # hidden saturation from a fitted start, seed 1004: the offset named in round 1 ended at 0.012 mrad once the
    # saturation was in. Here: an offset of a tenth of the noise bound named before the true backlash
    record = hidden_effect_record(("backlash",), 11)
    truth = next(b for b in record.true_model.blocks if isinstance(b, OutputBacklash))
    found, n_est = _named_search(record, [("offset", (0.1 * record.noise_bound_rad, 0.0)),
                                          ("backlash", (truth.c_l_rad, truth.c_r_rad))])
    kept = _still_needed(found, record.command_rad, record.angle_rad, n_est, record.noise_bound_rad,
                         DiagnoseOptions(), lambda _m: None)
    assert [step.effect for step in kept.steps] == ["backlash"]
    assert kept.current.gap_rad <= 1.05 * found.current.gap_rad
    assert not any(isinstance(b, OutputOffset) for b in kept.chain.model().blocks)
    step = kept.steps[0]  # it now follows the model before the offset, and carries the check
    assert step.gap_before_rad == found.steps[0].gap_before_rad and step.gap_after_rad == kept.current.gap_rad
    assert step.evidence["dropped_after_search"]["offset"]["penalised_reduction"] < DiagnoseOptions().min_reduction
    # a real drift of 20 noise bounds over the record on top of the same backlash: both earn their place (a
    # constant offset would not: an asymmetric play shifts the output by (c_r - c_l) / 2 and stands in for it)
    duration_s = record.command_rad.size * record.sample_period_s
    drift = 20.0 * record.noise_bound_rad / duration_s
    shifted = replace(record, angle_rad=record.angle_rad + drift * record.sample_period_s
                      * np.arange(record.angle_rad.size))
    found, n_est = _named_search(shifted, [("offset", (0.0, drift)), ("backlash", (truth.c_l_rad, truth.c_r_rad))])
    kept = _still_needed(found, shifted.command_rad, shifted.angle_rad, n_est, shifted.noise_bound_rad,
                         DiagnoseOptions(), lambda _m: None)
    assert [step.effect for step in kept.steps] == ["offset", "backlash"] and kept is found


@pytest.mark.parametrize("seed", [0])  # seeds 1-4 agree as closely (period within 1 %, amplitude within 5 %)
def test_a_hunting_axis_is_said_as_a_limit_cycle_with_its_amplitude_and_period(seed):
    """A position loop with integral action hunting through stiction while its command rests
    (``tests/peers/hunting_axis``, a generator written from the physics alone): nothing in the catalogue is
    that, and the reason says what the record shows, the oscillation's amplitude and period against the
    generator's truth (period within 3 %, amplitude within 15 %), as a limit cycle or a periodic input."""
    import sys
    from pathlib import Path

    from identify.plant_blocks import LinearBlock, PlantModel

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "peers" / "hunting_axis"))
    import hunting

    record = hunting.generate(seed)
    nominal = LinearBlock(a=tuple(record["nominal_a"][1:]), b=tuple(record["nominal_b"]),
                          sample_period_s=record["sample_period_s"])
    result = diagnose_model(record["command_rad"], record["angle_rad"], record["noise_bound_rad"],
                            record["sample_period_s"], PlantModel((nominal,)))
    assert result.missing_effects == () and "limit cycle" in result.verdict_reason, result.verdict_reason
    period_s = float(re.search(r"a period of ([0-9.e-]+) s", result.verdict_reason).group(1))
    amplitude = float(re.search(r"oscillating by \+-([0-9.e-]+) rad", result.verdict_reason).group(1))
    assert period_s == pytest.approx(record["truth"]["limit_cycle_period_s"], rel=0.03)
    assert amplitude == pytest.approx(record["truth"]["limit_cycle_amplitude_rad"], rel=0.15)


def test_what_is_left_names_the_candidates_the_verdict_left_open():
    # an offset over a small square wave is also a load that depends on the angle: neither is added, and the
    # text of what is left must not say that no candidate lowers the gap (both do, to a tenth of it)
    nominal = LinearBlock(a=(-1.73691838, 0.76805512), b=(0.0, 0.01625312, 0.01488362), sample_period_s=0.001)
    square = 0.01 * np.sign(np.sin(np.arange(3000) / 37.0))
    angle = nominal.apply(square) + 0.004 + np.random.default_rng(1).uniform(-2e-4, 2e-4, square.size)
    result = diagnose_model(square, angle, 0.001, 0.001, PlantModel((nominal,)))
    assert result.verdict == "ambiguous" and result.missing_effects == ()
    assert "none of the candidate effects lowers" not in result.unexplained
    for name in result.ambiguous_between:
        assert name in result.unexplained
    assert "cannot tell whether they are there" in result.unexplained
    # what a black box finds in the residual is what the candidates left open would take, not a missing effect
    assert "structure the catalogue does not hold" not in result.verdict_reason
