"""A long record: the candidates' fits use the first FIT_MAX_SAMPLES samples of the estimation segment, so their
cost stops growing with the record, while each candidate is still judged over the whole segments and the effect
kept is polished on the whole estimation segment. The bound is lowered here so that a 3000-sample record is
"long" (the real bound, 20 000 samples, is above every record of the tests)."""

from __future__ import annotations

from collections import Counter

import pytest

import identify.model_discrepancy.fit as fit
from identify.discrepancy_cases import hidden_effect_record
from identify.drive_train import DriveTrain
from identify.effect_signatures import signature_scores
from identify.model_discrepancy import diagnose_model, disagreement
from identify.model_discrepancy.start_model import _start_chain
from identify.model_discrepancy.thresholds import ESTIMATION_FRACTION, MAX_DELAY_SAMPLES, MAX_EVALUATIONS
from identify.plant_blocks import OutputBacklash, PlantModel

WINDOW = 900


@pytest.fixture
def record():
    return hidden_effect_record(("backlash",), 11)


@pytest.fixture
def simulated_lengths(monkeypatch):
    """The number of samples of every free run (of a chain, or of a drive train alone), counted."""
    lengths: Counter[int] = Counter()
    simulate, apply = PlantModel.simulate, DriveTrain.apply
    in_chain = []

    def counted_simulate(self, command_rad):
        lengths[len(command_rad)] += 1
        in_chain.append(True)
        try:
            return simulate(self, command_rad)
        finally:
            in_chain.pop()

    def counted_apply(self, signal):
        if not in_chain:  # a train run alone (the rigid train a dynamics effect goes into is fitted so)
            lengths[len(signal)] += 1
        return apply(self, signal)

    monkeypatch.setattr(PlantModel, "simulate", counted_simulate)
    monkeypatch.setattr(DriveTrain, "apply", counted_apply)
    return lengths


@pytest.mark.parametrize("kind", ["backlash", "shaft_play"])
def test_a_candidate_is_fitted_on_the_bounded_window_and_judged_on_the_whole_segments(record, monkeypatch,
                                                                                       simulated_lengths, kind):
    monkeypatch.setattr(fit, "FIT_MAX_SAMPLES", WINDOW)
    u, y, delta, period = record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s
    n_est = int(round(ESTIMATION_FRACTION * u.size))
    assert n_est > WINDOW
    start = disagreement(record.nominal_model, u, y, delta, n_est)
    scores = signature_scores(u, y, start.simulated_rad, delta, period)
    simulated_lengths.clear()
    candidate = fit._try_effect(kind, _start_chain(record.nominal_model, None, 2), u, y, n_est, delta, period,
                                start.residual_rad, scores, MAX_DELAY_SAMPLES, MAX_EVALUATIONS)
    longer = {length: count for length, count in simulated_lengths.items() if length > WINDOW}
    # the fit's free runs all stay within the window; only the judgement runs the whole record (the validated
    # gap) and the whole estimation segment (the estimation error the compound fits are compared by)
    assert sum(simulated_lengths.values()) > 20
    assert longer == {u.size: 1, n_est: 1}
    assert candidate.validation_error_rad.size == u.size - n_est


def test_the_named_backlash_keeps_its_size_when_the_candidates_are_fitted_on_a_window(record, monkeypatch):
    truth = record.true_model.find(OutputBacklash)[0]
    options = dict(candidates=("backlash", "delay"))
    whole = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                           record.nominal_model, **options)
    monkeypatch.setattr(fit, "FIT_MAX_SAMPLES", WINDOW)
    windowed = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                              record.nominal_model, **options)
    assert windowed.missing_effects == whole.missing_effects == ("backlash",)
    for key, true_value in (("c_l_rad", truth.c_l_rad), ("c_r_rad", truth.c_r_rad)):
        fitted = windowed.steps[0].parameters[key]
        # polished on the whole estimation segment: the size of the fit on all of it, within the encoder's noise
        assert abs(fitted - whole.steps[0].parameters[key]) < 0.1 * record.noise_bound_rad
        assert abs(fitted - true_value) < record.noise_bound_rad
    assert windowed.final.gap_rad < 1.05 * whole.final.gap_rad


SCREEN = 300


@pytest.mark.parametrize("kind", ["backlash", "shaft_play"])
def test_a_candidate_screens_its_starts_on_the_first_samples_and_polishes_only_the_best_on_the_window(
        record, monkeypatch, simulated_lengths, kind):
    u, y, delta, period = record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s
    n_est = int(round(ESTIMATION_FRACTION * u.size))
    start = disagreement(record.nominal_model, u, y, delta, n_est)
    scores = signature_scores(u, y, start.simulated_rad, delta, period)
    monkeypatch.setattr(fit, "FIT_MAX_SAMPLES", WINDOW)

    def window_runs(screen: int) -> Counter[int]:
        monkeypatch.setattr(fit, "START_SCREEN_SAMPLES", screen)
        simulated_lengths.clear()
        fit._try_effect(kind, _start_chain(record.nominal_model, None, 2), u, y, n_est, delta, period,
                        start.residual_rad, scores, MAX_DELAY_SAMPLES, MAX_EVALUATIONS)
        return Counter(simulated_lengths)

    unscreened, screened = window_runs(WINDOW), window_runs(SCREEN)
    # every start ranked and polished on the screen; the window runs only the best start's polish, the delay
    # walk and the stick-slip scan; the whole segments once each for the judgement
    assert set(screened) == {SCREEN, WINDOW, n_est, u.size}
    assert screened[n_est] == screened[u.size] == 1
    assert screened[SCREEN] > screened[WINDOW]
    assert screened[WINDOW] < unscreened[WINDOW]


def test_the_named_backlash_keeps_its_size_when_the_starts_are_screened_on_the_first_samples(record, monkeypatch):
    truth = record.true_model.find(OutputBacklash)[0]
    options = dict(candidates=("backlash", "delay"))
    monkeypatch.setattr(fit, "FIT_MAX_SAMPLES", WINDOW)
    monkeypatch.setattr(fit, "START_SCREEN_SAMPLES", WINDOW)
    whole = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                           None, **options)
    monkeypatch.setattr(fit, "START_SCREEN_SAMPLES", SCREEN)
    screened = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad,
                              record.sample_period_s, None, **options)
    assert screened.missing_effects == whole.missing_effects == ("backlash",)
    for key, true_value in (("c_l_rad", truth.c_l_rad), ("c_r_rad", truth.c_r_rad)):
        fitted = screened.steps[0].parameters[key]
        assert abs(fitted - whole.steps[0].parameters[key]) < 0.1 * record.noise_bound_rad
        assert abs(fitted - true_value) < record.noise_bound_rad
    assert screened.final.gap_rad < 1.05 * whole.final.gap_rad
