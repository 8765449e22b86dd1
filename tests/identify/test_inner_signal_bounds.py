"""Inner-signal bounds of Section 4 (Prop. 2-4) and the band bound for non-invertible samples."""

from __future__ import annotations

import numpy as np
import pytest

from identify.feasible_parameter_set import bound_backlash_parameters
from identify.inner_signal_bounds import bound_inner_signal
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
from identify.validation import InvalidInputError
from cerone2009_data import experiment


@pytest.mark.parametrize("n_bit", [15, 12, 10, 8])
@pytest.mark.parametrize("seed", [0, 1])
def test_every_sample_is_bounded_and_invertibility_follows_proposition_2(n_bit: int, seed: int) -> None:
    data = experiment(n_bit, seed, num_samples=300)
    fps = bound_backlash_parameters(data.steady_input_rad, data.steady_output_rad, data.noise_bound_rad)
    bounds = bound_inner_signal(data.output_rad, data.noise_bound_rad, fps)
    x = data.inner_rad
    assert np.all(bounds.lower_rad <= x) and np.all(x <= bounds.upper_rad)
    step = np.abs(np.diff(data.output_rad))
    assert np.array_equal(bounds.invertible[1:], step > 2 * data.noise_bound_rad) and not bounds.invertible[0]
    assert 0 < bounds.num_invertible < x.size  # the PRBS response has both kinds
    # Prop. 4 over the vertices is at least as tight as inverting with the orthotope's corner values
    m_r, c_r = fps.m_r, fps.c_r
    rising = (bounds.direction == 1) & (data.output_rad > data.noise_bound_rad)
    y = data.output_rad[rising]
    assert np.all(bounds.lower_rad[rising] >= (y - data.noise_bound_rad) / m_r.upper + c_r.lower - 1e-12)
    assert np.all(bounds.upper_rad[rising] <= (y + data.noise_bound_rad) / m_r.lower + c_r.upper + 1e-12)
    assert np.allclose(bounds.center_rad, 0.5 * (bounds.lower_rad + bounds.upper_rad))


def test_fifteen_bit_invertible_samples_are_within_a_few_noise_bounds() -> None:
    data = experiment(15, 3)
    fps = bound_backlash_parameters(data.steady_input_rad, data.steady_output_rad, data.noise_bound_rad)
    bounds = bound_inner_signal(data.output_rad, data.noise_bound_rad, fps)
    # x = (y - η)/m + c: Δη/m ~ 7.7e-4 plus the γ uncertainty times |x| <= 3
    assert np.max(bounds.half_width_rad[bounds.invertible]) < 3e-3
    assert np.median(bounds.half_width_rad[~bounds.invertible]) > 0.02


def test_band_bound_stays_valid_where_the_backlash_lines_cross() -> None:
    # m_r > m_l: the lines m_r(x - c_r) and m_l(x + c_l) cross at x = 0.25, inside the signal range, where
    # w/m_l - c_l <= x <= w/m_r + c_r fails; the hull of the two inversions still holds.
    gamma = dict(m_l=0.2, c_l=0.05, m_r=0.3, c_r=0.05)
    amplitudes = np.linspace(0.6, 3.0, 10)
    steady_u = np.concatenate([amplitudes, -amplitudes])
    steady_y = np.concatenate([0.3 * (amplitudes - 0.05), 0.2 * (-amplitudes + 0.05)])
    fps = bound_backlash_parameters(steady_u, steady_y, 1e-4)
    u = np.random.default_rng(0).choice([-1.0, 1.0], size=400)
    linear = LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0)
    x = linear.apply(u)
    backlash = OutputBacklash(gamma["m_l"], gamma["c_l"], gamma["m_r"], gamma["c_r"])
    y = PlantModel((linear, backlash)).simulate(u) + np.random.default_rng(1).uniform(-1e-4, 1e-4, 400)
    bounds = bound_inner_signal(y, 1e-4, fps)
    assert np.all(bounds.lower_rad <= x) and np.all(x <= bounds.upper_rad)
    w = y
    band_upper = w / 0.3 + 0.05
    assert np.any(x > band_upper + 1e-3)  # the naive band would have excluded the truth here


def test_validation() -> None:
    data = experiment(12, 0)
    fps = bound_backlash_parameters(data.steady_input_rad, data.steady_output_rad, data.noise_bound_rad)
    with pytest.raises(InvalidInputError, match="output_rad: sample 1 is inf"):
        bound_inner_signal([0.0, np.inf, 1.0], 1e-3, fps)
    with pytest.raises(InvalidInputError, match="noise_bound_rad"):
        bound_inner_signal([0.0, 1.0], -1.0, fps)
    with pytest.raises(InvalidInputError, match="backlash: expected a BacklashFeasibleSet"):
        bound_inner_signal([0.0, 1.0], 1e-3, None)  # type: ignore[arg-type]
