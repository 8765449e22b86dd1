"""Simulated data of Section 6 of Cerone, Piga and Regruto (2009), shared by the set-membership tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel

GAMMA = {"m_l": 0.248, "c_l": 0.0698, "m_r": 0.252, "c_r": 0.0349}
THETA = {"a1": 0.5, "a2": 0.7, "b1": 1.4, "b2": 0.8}
LINEAR = LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0)
PLANT = PlantModel((LINEAR, OutputBacklash(GAMMA["m_l"], GAMMA["c_l"], GAMMA["m_r"], GAMMA["c_r"])))
AMPLITUDES = np.linspace(0.6, 3.0, 50)
HALF_WAVE = 100
_STAIRCASE = filtered_staircase(list(AMPLITUDES), 0.8125, HALF_WAVE)
_STEADY = staircase_steady_state_indices(AMPLITUDES.size, HALF_WAVE)
STEADY_INPUT = _STAIRCASE[_STEADY]
STEADY_OUTPUT_NOISE_FREE = PLANT.simulate(_STAIRCASE)[_STEADY]


def noise_bound(n_bit: int) -> float:
    """Δη = 2π/2^n_bit of an n-bit absolute encoder (Section 6)."""
    return 2.0 * np.pi / 2**n_bit


@dataclass(frozen=True)
class Experiment:
    noise_bound_rad: float
    steady_input_rad: np.ndarray
    steady_output_rad: np.ndarray
    input_rad: np.ndarray
    output_rad: np.ndarray
    inner_rad: np.ndarray  # the true x_t


def experiment(n_bit: int, seed: int, num_samples: int = 100) -> Experiment:
    """Both experiments with uniform noise in [-Δη, Δη] drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    delta = noise_bound(n_bit)
    steady_y = STEADY_OUTPUT_NOISE_FREE + rng.uniform(-delta, delta, STEADY_INPUT.size)
    u = prbs_sequence(num_samples, 1.0, rng=rng)
    y = PLANT.simulate(u) + rng.uniform(-delta, delta, num_samples)
    return Experiment(delta, STEADY_INPUT, steady_y, u, y, LINEAR.apply(u))
