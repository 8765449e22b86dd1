"""The model-discrepancy workflow from a fitted start: the workflow fits its own linear model,
which has absorbed part of the hidden effect, and the candidate fits must still reach the truth's gap; and the
acceptance of a candidate must not hang on a validation block where the data cannot tell the models apart.

The records are the hidden-effect cases of the benchmark (:mod:`identify.discrepancy_cases`, seeds of the
20-case rows of ``benchmarks/model_discrepancy_confusion.py --start fitted``) that failed before the fix.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from identify.discrepancy_cases import hidden_effect_record
from identify.effect_catalogue import SEARCHED_EFFECT_NAMES, effect
from identify.effect_signatures import signature_scores
from identify.model_discrepancy import ESTIMATION_FRACTION, VALIDATION_BLOCKS, diagnose_model, disagreement
from identify.model_discrepancy.chain import _rms
from identify.model_discrepancy.fit import _try_effect
from identify.model_discrepancy.judgement import _acceptance
from identify.model_discrepancy.start_model import _start, record_modes
from servo_and_shaft import servo_and_shaft_block


def _fitted_start_candidate(name: str, seed: int):
    """The round-1 candidate ``name`` on hidden-effect record (``name``, ``seed``) from the fitted linear start
    model, the truth's validated gap, and the true block."""
    record = hidden_effect_record((name,), seed)
    u, y, delta, period = record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s
    n_est = int(round(ESTIMATION_FRACTION * u.size))
    start_model, _, chain = _start(u, y, period, n_est, None, 40, lambda _message: None)
    initial = disagreement(start_model, u, y, delta, n_est)
    scores = signature_scores(u, y, initial.simulated_rad, delta, period)
    candidate = _try_effect(name, chain, u, y, n_est, delta, period, initial.residual_rad, scores, 40, 40)
    truth_gap = _rms((y - record.true_model.simulate(u))[n_est:])
    return candidate, truth_gap, record.true_model.blocks[-1]


@pytest.mark.parametrize("seed", [1004, 1015])
def test_a_stick_slip_fit_from_a_fitted_start_reaches_the_noise_level(seed):
    # seed 1004: breakaway 17.2, sliding 7.1 mrad; one polish and one breakaway scan stopped at 4.2 mrad
    # validated (the truth leaves 0.49 mrad) and load friction was named instead. Seed 1015: breakaway 30.6,
    # sliding 14.5 mrad; only the contact-branch start at breakaway = sliding was polished, 6.2 mrad (truth
    # 0.55 mrad), and nothing was named
    candidate, truth_gap, block = _fitted_start_candidate("coulomb_friction", seed)
    assert candidate.gap_rad < 1.2 * truth_gap
    fitted = effect("coulomb_friction").report(candidate.block)
    assert fitted["breakaway_deflection_rad"] == pytest.approx(block.breakaway_deflection_rad, rel=0.05)
    assert fitted["sliding_deflection_rad"] == pytest.approx(block.sliding_deflection_rad, rel=0.1)


def test_an_asymmetric_backlash_from_a_fitted_start_is_fitted_from_its_best_guess_too():
    # seed 1016: c_l 34.8, c_r 39.6 mrad; the contact-branch starts ranked first and polished to a one-sided
    # play (c_r = 0, 20.9 mrad validated); Coulomb friction plus an offset was named instead
    candidate, truth_gap, block = _fitted_start_candidate("backlash", 1016)
    assert candidate.gap_rad < 1.5 * truth_gap
    assert candidate.block.c_l_rad == pytest.approx(block.c_l_rad, rel=0.05)
    assert candidate.block.c_r_rad == pytest.approx(block.c_r_rad, rel=0.05)


def _block_errors(gaps_rad, samples=50):
    """An error of ``samples`` samples per validation block, each block +-its gap (RMS = |value| = gap)."""
    signs = np.sign(np.random.default_rng(0).standard_normal(samples * len(gaps_rad)))
    return np.repeat(np.asarray(gaps_rad, dtype=float), samples) * signs


def test_a_block_where_both_models_stay_within_the_noise_bound_does_not_widen_the_acceptance():
    # the model so far is falsified in seven blocks (errors of 1.0-1.3 against a bound of 0.8) and sits on the
    # measured level in the eighth (0.03), where the candidate stays at 0.4: both within the bound there
    assert VALIDATION_BLOCKS == 8
    current = _block_errors([1.1, 1.0, 1.3, 1.2, 1.0, 1.2, 1.1, 0.03])
    candidate = _block_errors([0.4] * 8)
    factor = 1.06
    args = (candidate, factor, current, factor * _rms(candidate), _rms(current), 0.15)
    reduction, interval, word = _acceptance(*args, 0.8)
    assert word == "clear" and interval[0] > 0.5
    assert interval[0] <= reduction <= interval[1]
    # with a bound the eighth block's errors exceed, it is evidence: its log ratio of ln(1.06 0.4 / 0.03) = +2.6
    # against about -1 in the others leaves the reduction undecided
    _, wide, word = _acceptance(*args, 0.01)
    assert word == "undecided" and wide[0] < 0.15 < wide[1]
    assert math.isclose(1.0 - reduction, factor * _rms(candidate) / _rms(current))


def test_a_resonance_that_rings_in_one_validation_block_is_named_from_a_fitted_start():
    # seed 1014: the resonance rings in one validation block of 8 (3.8 noise bounds off the start model there,
    # within the noise elsewhere): validated 63 %, blocks -10 to 87 %, refits 39 to 81 %. Judged on the union
    # of the two intervals it was undecided and nothing was named; the refits judge the size now
    record = hidden_effect_record(("resonance",), 1014)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            None)
    assert result.verdict == "named" and result.missing_effects == ("resonance",), result.verdict_reason
    entry = next(c for c in result.candidates if c.effect == "resonance" and c.acceptance == "clear")
    assert entry.validation_interval[0] < 0.15 <= entry.reduction and entry.refit_interval[0] >= 0.15
    entry_class = effect("resonance").block_class
    truth = effect("resonance").report(next(b for b in record.true_model.blocks if isinstance(b, entry_class)))
    low, high = result.parameter_intervals["resonance"]["frequency_hz"]
    assert low <= truth["frequency_hz"] <= high


@pytest.mark.parametrize("seed", [1006, 1017])
def test_a_fitted_resonance_gets_every_value_the_record_cannot_exclude_and_no_more_than_a_few_per_cent(seed):
    # from a fitted start the fit of a resonance is biased by what the fitted linear start absorbed, and the
    # fold refits, which share that bias, left intervals around it that missed the truth (seed 1006: 170.64 Hz
    # outside [170.70, 170.93]; seed 1017: 184.85 Hz outside [184.64, 184.82], damping 0.0366 outside
    # [0.0345, 0.0366]), while the true values keep the free run within the noise bound as often as the fit
    record = hidden_effect_record(("resonance",), seed)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            None)
    assert result.missing_effects == ("resonance",) and result.consistent
    entry = effect("resonance")
    truth = entry.report(next(b for b in record.true_model.blocks if isinstance(b, entry.block_class)))
    for key, value in truth.items():
        low, high = result.parameter_intervals["resonance"][key]
        assert low <= value <= high, f"{key}: truth {value:g} outside [{low:g}, {high:g}]"
        assert high - low < 0.3 * value, f"{key}: [{low:g}, {high:g}] says little about {value:g}"


def _servo_and_shaft_prbs_record(seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """A clean record of a plant of four poles (a stiff 60 Hz servo and a 30.8 Hz shaft mode,
    :func:`servo_and_shaft.servo_and_shaft_block`) under bare +-0.01 rad steps held 20-100 ms, read by a
    12-bit encoder with noise of std 1e-4 rad: command, angle, noise bound (half a count + 4.5 std)."""
    rng = np.random.default_rng(seed)
    u, t, level = np.zeros(3000), 0, 0.01
    while t < u.size:
        hold = int(rng.integers(20, 101))
        u[t:t + hold] = level
        level = -level if rng.random() < 0.5 else level
        t += hold
    count = 2.0 * math.pi / 4096
    y = np.round((servo_and_shaft_block().apply(u) + rng.normal(0.0, 1e-4, u.size)) / count) * count
    return u, y, 0.5 * count + 4.5e-4


def test_a_delay_that_poles_the_fitted_start_lacks_could_give_is_not_named():
    # the order-2 start holds one pole pair of the four; a delay of a few samples lowered the gap and was named
    # (6 of 6 seeds), though the plant has no delay: with a linear block of order 3-4 in the start's place the
    # delay is no longer needed, so the record cannot tell a delay from the poles, and the verdict says so
    # without naming it (the resonance, which names those poles, left out of the candidates)
    u, y, delta = _servo_and_shaft_prbs_record(0)
    result = diagnose_model(u, y, delta, 1e-3,
                            candidates=tuple(name for name in SEARCHED_EFFECT_NAMES if name != "resonance"))
    assert result.linear_fit is not None and result.linear_fit.order <= 2
    assert "delay" not in result.missing_effects
    assert result.verdict == "ambiguous" and result.ambiguous_between == ("delay",)
    assert "a linear block of order" in result.verdict_reason and "delay is not named" in result.verdict_reason


def test_the_records_modes_are_the_lightly_damped_poles_of_its_higher_order_linear_models():
    # the servo-and-shaft plant's poles: the servo's 60 Hz at damping 0.7 (not a light mode) and the shaft's
    # 30.82 Hz at damping 0.050, read from z-plane poles as s = ln(z) / T
    u, y, _ = _servo_and_shaft_prbs_record(0)
    modes = record_modes(u, y, 1e-3, int(round(ESTIMATION_FRACTION * u.size)), 0.3)
    assert modes and all(damping < 0.3 for _, damping in modes)
    frequency, damping = min(modes, key=lambda mode: abs(mode[0] - 30.82))
    assert frequency == pytest.approx(math.sqrt(150.0 / 0.004) / (2 * math.pi), rel=0.01)
    assert damping == pytest.approx(0.0775 / (2 * math.sqrt(150.0 * 0.004)), rel=0.1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_mode_a_fitted_start_lacks_is_named_a_resonance_with_the_shafts_frequency_and_damping(seed):
    # the shaft's 30.8 Hz mode (zeta 0.05) behind the order-2 start: the resonance's grid of guesses (16
    # frequencies, 1.28 apart) polished to 144 Hz at the damping cap, whose basin is a few damping ratios wide,
    # and a delay stood in; started from the poles of linear models of order 3-4 it is found
    u, y, delta = _servo_and_shaft_prbs_record(seed)
    result = diagnose_model(u, y, delta, 1e-3)
    assert result.verdict == "named" and result.missing_effects == ("resonance",) and result.consistent
    stiffness, damping, inertia = 150.0, 0.0775, 0.004
    truth = {"frequency_hz": math.sqrt(stiffness / inertia) / (2 * math.pi),
             "damping_ratio": damping / (2 * math.sqrt(stiffness * inertia))}
    for key, value in truth.items():
        low, high = result.parameter_intervals["resonance"][key]
        assert low <= value <= high, f"{key}: truth {value:g} outside [{low:g}, {high:g}]"
        assert high - low < 0.2 * value, f"{key}: [{low:g}, {high:g}] says little about {value:g}"


def test_a_delay_the_poles_cannot_give_is_still_named_from_a_fitted_start():
    # a hidden delay of 13 samples: with a linear block of order 3-4 in the start's place the delay is still
    # needed, and stays named
    record = hidden_effect_record(("delay",), 1000)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s)
    assert result.missing_effects == ("delay",) and result.verdict == "named"
    assert result.steps[0].parameters["samples"] == record.true_model.blocks[0].samples
