"""Excitation design of Cerone et al. (2009): PRBS, filtered staircase (Section 3.1, Remark 1), Appendix search."""

from __future__ import annotations

import numpy as np
import pytest

from identify.excitation_design import (
    design_filter_pole,
    filtered_staircase,
    filtered_step,
    lowpass_filter,
    prbs_sequence,
    staircase_steady_state_indices,
)
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
from identify.validation import InvalidInputError

PLANT = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))


@pytest.mark.parametrize("bits", [3, 5, 7, 9])
def test_prbs_is_maximal_length_with_balanced_levels(bits: int) -> None:
    period = 2**bits - 1
    u = prbs_sequence(2 * period, 0.5, rng=4, register_bits=bits)
    assert set(u.tolist()) == {-0.5, 0.5}
    assert np.array_equal(u[:period], u[period:])
    for shift in range(1, period):  # no shorter period
        assert not np.array_equal(u[:period], u[shift:shift + period])
    assert np.count_nonzero(u[:period] > 0) == 2 ** (bits - 1)  # one more +A than -A per period


def test_prbs_seeded_and_validated() -> None:
    assert np.array_equal(prbs_sequence(100, 1.0, rng=3), prbs_sequence(100, 1.0, rng=np.random.default_rng(3)))
    assert not np.array_equal(prbs_sequence(100, 1.0, rng=3), prbs_sequence(100, 1.0, rng=4))
    with pytest.raises(InvalidInputError, match="amplitude_rad"):
        prbs_sequence(10, -1.0)
    with pytest.raises(InvalidInputError, match="num_samples"):
        prbs_sequence(0, 1.0)
    with pytest.raises(InvalidInputError, match="register_bits"):
        prbs_sequence(10, 1.0, register_bits=40)


def test_first_order_filter_is_the_difference_equation_and_nth_order_is_its_power() -> None:
    r = np.random.default_rng(0).normal(size=50)
    u = lowpass_filter(r, 0.6)
    expected = np.zeros(50)
    for t in range(1, 50):
        expected[t] = 0.6 * expected[t - 1] + 0.4 * r[t - 1]  # F(z) = (1 - a)/(z - a)
    assert np.allclose(u, expected, atol=1e-14)
    assert np.allclose(lowpass_filter(r, 0.6, filter_order=3), lowpass_filter(lowpass_filter(u, 0.6), 0.6), atol=1e-14)


def test_staircase_reaches_every_amplitude_and_the_backlash_output_lies_on_its_lines() -> None:
    amplitudes = np.linspace(0.6, 3.0, 50)
    u = filtered_staircase(list(amplitudes), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    assert np.allclose(u[steady], np.repeat(amplitudes, 2) * np.tile([1.0, -1.0], 50), atol=1e-8)
    w = PLANT.simulate(u)[steady]
    # eq. (11) on positive half-waves, eq. (12) on negative ones: x_t did not overshoot with a = 0.8125
    assert np.allclose(w[0::2], 0.252 * (amplitudes - 0.0349), atol=1e-8)
    assert np.allclose(w[1::2], 0.248 * (-amplitudes + 0.0698), atol=1e-8)


def test_staircase_shuffle_uses_rng_and_keeps_the_amplitudes() -> None:
    u = filtered_staircase([1.0, 2.0, 3.0], 0.0, 5, shuffle=True, rng=1)
    levels = u[staircase_steady_state_indices(3, 5)]
    assert sorted(np.abs(levels).round(12).tolist()) == [1.0, 1.0, 2.0, 2.0, 3.0, 3.0]
    with pytest.raises(InvalidInputError, match="filter_pole"):
        filtered_staircase([1.0], 1.0, 5)
    with pytest.raises(InvalidInputError, match="amplitudes_rad"):
        filtered_staircase([1.0, -2.0], 0.5, 5)


def test_bisection_finds_the_fastest_pole_without_overshoot() -> None:
    design = design_filter_pole(PLANT.simulate, 1.0, reference_pole=0.99, num_samples=2500, tolerance_rad=1e-7,
                                pole_tolerance=1e-3)
    # The paper's search gave a = 0.8125 for this plant; the pole found must pass and a pole 0.02 faster must
    # not (the step response then overshoots and the backlash keeps a higher output).
    assert 0.78 < design.filter_pole < 0.85
    assert design.trials[0].filter_pole == 0.0 and not design.trials[0].passed
    last_passed = [t for t in design.trials if t.passed][-1]
    assert last_passed.filter_pole == design.filter_pole
    w_ref = PLANT.simulate(filtered_step(1.0, 0.99, 2500))[-1]
    assert abs(PLANT.simulate(filtered_step(1.0, design.filter_pole, 2500))[-1] - w_ref) <= 1e-7
    assert abs(PLANT.simulate(filtered_step(1.0, design.filter_pole - 0.02, 2500))[-1] - w_ref) > 1e-7


def test_noisy_search_uses_two_noise_bounds_plus_epsilon() -> None:
    noise = 1e-3
    rng = np.random.default_rng(5)
    design = design_filter_pole(lambda u: PLANT.simulate(u) + rng.uniform(-noise, noise, u.size), 1.0,
                                reference_pole=0.99, num_samples=2500, noise_bound_rad=noise, tolerance_rad=1e-6)
    assert design.threshold_rad == pytest.approx(2e-3 + 1e-6)
    # With noise the test tolerates small overshoot: the pole can only be faster (smaller) or equal.
    assert design.filter_pole < 0.85
    with pytest.raises(InvalidInputError, match="reference_pole"):
        design_filter_pole(PLANT.simulate, 1.0, reference_pole=1.0, num_samples=10)
    with pytest.raises(InvalidInputError, match="run_step_experiment"):
        design_filter_pole(None, 1.0, reference_pole=0.9, num_samples=10)  # type: ignore[arg-type]
