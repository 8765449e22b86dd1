"""Noise models: bounds, levels, SNR, and identical sequences whether drawn one by one or as arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest

from identify.validation import InvalidInputError
from sim_backend.noise import BoundedUniformNoise, ColouredNoise, GaussianNoise, NoNoise, std_for_snr


def test_uniform_noise_stays_within_its_bound_and_fills_it():
    noise = BoundedUniformNoise(bound_rad=1e-3)
    samples = noise.sampler(np.random.default_rng(0)).draw(20000)
    assert noise.noise_bound_rad == 1e-3
    assert np.max(np.abs(samples)) <= 1e-3
    assert np.max(samples) > 0.999e-3 and np.min(samples) < -0.999e-3
    assert np.std(samples) == pytest.approx(1e-3 / math.sqrt(3), rel=0.03)


def test_gaussian_and_coloured_noise_have_the_requested_standard_deviation():
    white = GaussianNoise(std_rad=0.02).sampler(np.random.default_rng(1)).draw(40000)
    assert np.std(white) == pytest.approx(0.02, rel=0.03)
    assert GaussianNoise(std_rad=0.02).noise_bound_rad == math.inf
    coloured = ColouredNoise(std_rad=0.02).sampler(np.random.default_rng(2)).draw(40000)
    assert np.std(coloured) == pytest.approx(0.02, rel=0.1)
    # G_v = (1 + 0.5 q^-1)/(1 - 0.85 q^-1) makes neighbours strongly correlated; white noise does not
    assert np.corrcoef(coloured[1:], coloured[:-1])[0, 1] > 0.8
    assert abs(np.corrcoef(white[1:], white[:-1])[0, 1]) < 0.03


def test_snr_sets_the_level_from_the_noise_free_output():
    clean = np.sin(np.linspace(0, 60, 30000))
    noise = GaussianNoise(snr_db=10.0)
    with pytest.raises(InvalidInputError, match="needs the noise-free output"):
        noise.sampler(np.random.default_rng(0))
    resolved = noise.resolved(clean)
    samples = resolved.sampler(np.random.default_rng(3)).draw(clean.size)
    measured_snr = 10 * math.log10(np.var(clean) / np.var(samples))
    assert measured_snr == pytest.approx(10.0, abs=0.2)
    assert resolved.std_rad == pytest.approx(std_for_snr(clean, 10.0))
    with pytest.raises(InvalidInputError, match="constant"):
        std_for_snr(np.ones(10), 10.0)


def test_one_by_one_and_array_draws_give_the_same_sequence():
    for model in (BoundedUniformNoise(0.1), GaussianNoise(std_rad=0.1), ColouredNoise(std_rad=0.1)):
        stepped = model.sampler(np.random.default_rng(4))
        mixed = [stepped.next() for _ in range(3)] + stepped.draw(5000).tolist() + [stepped.next() for _ in range(10)]
        whole = model.sampler(np.random.default_rng(4)).draw(5013)
        assert np.array_equal(np.array(mixed), whole), model.kind


def test_quantization_only_adds_nothing_and_levels_are_validated():
    assert np.all(NoNoise().sampler(np.random.default_rng(0)).draw(10) == 0.0)
    assert NoNoise().noise_bound_rad == 0.0
    with pytest.raises(InvalidInputError, match="bound_rad"):
        BoundedUniformNoise(bound_rad=-1.0)
    with pytest.raises(InvalidInputError, match="std_rad, snr_db"):
        GaussianNoise()
    with pytest.raises(InvalidInputError, match="stable"):
        ColouredNoise(std_rad=0.1, denominator=(1.0, -1.2))
