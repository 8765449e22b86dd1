"""The simulated gearbox: stepping equals whole-array simulation, the measurement error stays within the
stated bound, and the encoder counts are what the CiA 406 device would report."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
from identify.validation import InvalidInputError
from rig.protocols.encoder_counts import EncoderResolution
from sim_backend.noise import BoundedUniformNoise, GaussianNoise
from sim_backend.plant import GearboxSample, SimulatedGearbox
from sim_backend.plant_config import load_plant_config

PLANTS = Path(__file__).resolve().parents[2] / "configs" / "plants"
NAMES = ("cerone2009", "pouliquen2013_backlash", "pouliquen2013_switch", "precision_gearbox")


def command(num_samples: int, amplitude_rad: float) -> np.ndarray:
    rng = np.random.default_rng(11)
    return amplitude_rad * np.repeat(rng.uniform(-1, 1, num_samples // 20 + 1), 20)[:num_samples]


@pytest.mark.parametrize("name", NAMES)
def test_step_by_step_equals_simulate_for_every_shipped_plant(name):
    gearbox = load_plant_config(PLANTS / f"{name}.toml").gearbox(seed=5)
    u = command(1500, 3.0 if name.startswith("pouliquen") else 1.0)
    run = gearbox.simulate(u)
    stepped = gearbox.calibrated_for(u)
    samples = [stepped.step(value) for value in u]
    assert np.array_equal([s.load_angle_rad for s in samples], run.load_angle_rad)
    assert np.array_equal([s.measured_angle_rad for s in samples], run.measured_angle_rad)
    assert np.array_equal([s.encoder_counts for s in samples], run.encoder_counts)
    assert all(isinstance(s.encoder_counts, int) for s in samples[:5])
    np.testing.assert_allclose(run.time_s[:3], [0.0, 1e-3, 2e-3])


@pytest.mark.parametrize("name", ("cerone2009", "precision_gearbox"))
def test_measurement_error_is_within_noise_bound_plus_half_a_count(name):
    gearbox = load_plant_config(PLANTS / f"{name}.toml").gearbox()
    run = gearbox.simulate(command(5000, 1.0))
    error = np.abs(run.measured_angle_rad - run.load_angle_rad)
    bound = gearbox.noise_bound_rad + gearbox.encoder.quantization_bound_rad
    assert gearbox.measurement_error_bound_rad == pytest.approx(bound)
    assert np.max(error) <= bound * (1 + 1e-12)
    assert np.max(error) > 0.5 * bound  # the bound is not loose by much
    np.testing.assert_array_equal(run.encoder_counts, gearbox.encoder.counts_from_rad(run.measured_angle_rad))


def test_cerone_plant_reaches_the_right_line_of_the_backlash_at_steady_state():
    gearbox = load_plant_config(PLANTS / "cerone2009.toml").gearbox()
    filtered_step = LinearBlock(a=(-0.8125,), b=(0.0, 0.1875), sample_period_s=1e-3).apply(np.full(400, 2.0))
    run = gearbox.simulate(filtered_step)
    # eq. (11): y = m_r (u - c_r) + eta at steady state, |eta| <= one count
    assert run.measured_angle_rad[-1] == pytest.approx(0.252 * (2.0 - 0.0349), abs=2 * np.pi / 4096)


def test_cerone_noise_gives_the_snr_of_table_ii_for_12_bits():
    gearbox = load_plant_config(PLANTS / "cerone2009.toml").gearbox(seed=1)
    prbs = np.random.default_rng(2).choice([-1.0, 1.0], size=20000)  # the +-1 PRBS of Section 6
    run = gearbox.simulate(prbs)
    error = run.measured_angle_rad - run.load_angle_rad
    snr_db = 10 * np.log10(np.var(run.load_angle_rad) / np.var(error))
    assert snr_db == pytest.approx(56.2, abs=1.5)  # Table II, n_bit = 12 (N = 100 there)
    assert np.max(np.abs(error)) <= 2 * np.pi / 4096 + gearbox.encoder.quantization_bound_rad


def test_same_seed_same_run_other_seed_other_noise_and_reset_restarts():
    plant = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1e-3), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))
    make = lambda seed: SimulatedGearbox(plant, EncoderResolution(bits=16, signed=True),  # noqa: E731
                                         BoundedUniformNoise(1e-3), seed=seed)
    u = command(300, 1.0)
    first, again, other = make(1).simulate(u), make(1).simulate(u), make(2).simulate(u)
    assert np.array_equal(first.measured_angle_rad, again.measured_angle_rad)
    assert not np.array_equal(first.measured_angle_rad, other.measured_angle_rad)
    assert np.array_equal(first.load_angle_rad, other.load_angle_rad)
    gearbox = make(1)
    head = [gearbox.step(value) for value in u[:10]]
    gearbox.reset()
    assert [gearbox.step(value) for value in u[:10]] == head
    assert isinstance(head[0], GearboxSample)
    assert make(None).seed is not None  # a drawn seed is recorded


def test_snr_noise_must_be_calibrated_before_stepping_and_errors_name_the_argument():
    plant = PlantModel((LinearBlock((-0.5,), (0.0, 0.5), 1e-3),))
    gearbox = SimulatedGearbox(plant, EncoderResolution(bits=16, signed=True), GaussianNoise(snr_db=20.0), seed=3)
    with pytest.raises(InvalidInputError, match="calibrated_for"):
        gearbox.step(0.1)
    u = np.sin(np.arange(2000) * 0.05)
    run = gearbox.simulate(u)
    snr = 10 * np.log10(np.var(run.load_angle_rad) / np.var(run.measured_angle_rad - run.load_angle_rad))
    assert snr == pytest.approx(20.0, abs=0.5)
    with pytest.raises(InvalidInputError, match="sample_period_s"):
        SimulatedGearbox(plant, EncoderResolution(bits=12), sample_period_s=0.01)
    with pytest.raises(InvalidInputError, match="command_rad: sample 1"):
        gearbox.simulate([0.0, float("nan")])
