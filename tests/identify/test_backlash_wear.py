"""The wearing output backlash: the play grows as the law says, and a plant without wear is unchanged."""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import pytest

from identify.backlash_wear import BacklashGrowth, WearingOutputBacklash, simulate_with_play
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
from identify.validation import InvalidInputError

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _back_and_forth(cycles: int = 5, amplitude: float = 1.0, samples: int = 200) -> np.ndarray:
    rng = np.random.default_rng(7)
    ramp = np.linspace(-amplitude, amplitude, samples)
    return np.concatenate([np.concatenate([ramp, ramp[::-1]]) * rng.uniform(0.5, 1.0) for _ in range(cycles)])


def test_each_flank_grows_by_k_times_its_own_travel():
    growth = BacklashGrowth(per_rad_travel=0.003)
    block = WearingOutputBacklash(0.8, 0.05, 1.2, 0.03, growth)
    x = _back_and_forth()
    w, play = block.apply_with_play(x)
    steps = np.diff(np.concatenate([[0.0], w]))
    up = np.cumsum(np.maximum(steps, 0.0))  # S+_t, the right flank's travel up to and with sample t
    down = np.cumsum(np.maximum(-steps, 0.0))
    # sample t uses the wear of the travel before it
    np.testing.assert_allclose(play.c_r_rad[1:], 0.03 + 0.003 * up[:-1], rtol=0, atol=1e-14)
    np.testing.assert_allclose(play.c_l_rad[1:], 0.05 + 0.003 * down[:-1], rtol=0, atol=1e-14)
    assert play.c_r_rad[0] == 0.03 and play.c_l_rad[0] == 0.05
    np.testing.assert_array_equal(play.play_rad, play.c_l_rad + play.c_r_rad)
    assert np.all(np.diff(play.play_rad) >= 0.0) and play.play_rad[-1] > play.play_rad[0] + 0.01


def test_the_output_follows_the_worn_lines():
    """Where the output moves it lies on the line of the flank in contact, with that sample's half-width."""
    block = WearingOutputBacklash(0.8, 0.05, 1.2, 0.03, BacklashGrowth(per_rad_travel=0.003))
    x = _back_and_forth()
    w, play = block.apply_with_play(x)
    moved = np.diff(np.concatenate([[0.0], w]))
    right, left = moved > 0, moved < 0
    np.testing.assert_allclose(w[right], 1.2 * (x[right] - play.c_r_rad[right]), atol=1e-14)
    np.testing.assert_allclose(w[left], 0.8 * (x[left] + play.c_l_rad[left]), atol=1e-14)


def test_growth_stops_at_its_limit():
    block = WearingOutputBacklash(1.0, 0.05, 1.0, 0.05, BacklashGrowth(per_rad_travel=0.01, max_rad=0.02))
    _, play = block.apply_with_play(_back_and_forth(cycles=20))
    assert play.c_l_rad[-1] == pytest.approx(0.07, abs=1e-15) and play.c_r_rad[-1] == pytest.approx(0.07, abs=1e-15)
    assert np.max(play.play_rad) <= 0.14 + 1e-15


def test_stepping_gives_apply_bit_for_bit():
    block = WearingOutputBacklash(0.248, 0.0698, 0.252, 0.0349, BacklashGrowth(per_rad_travel=1e-3, max_rad=0.01))
    x = _back_and_forth(cycles=8, amplitude=2.0)
    w, play = block.apply_with_play(x)
    stepper = block.stepper()
    stepped, c_l, c_r = [], [], []
    for value in x:
        c_l.append(stepper.c_l)
        c_r.append(stepper.c_r)
        stepped.append(stepper.step(value))
    np.testing.assert_array_equal(w, stepped)
    np.testing.assert_array_equal(play.c_l_rad, c_l)
    np.testing.assert_array_equal(play.c_r_rad, c_r)


def test_no_growth_is_the_backlash_without_wear_bit_for_bit():
    plain = OutputBacklash(0.248, 0.0698, 0.252, 0.0349)
    worn = WearingOutputBacklash(0.248, 0.0698, 0.252, 0.0349, BacklashGrowth(per_rad_travel=0.0))
    x = _back_and_forth(cycles=6, amplitude=3.0)
    np.testing.assert_array_equal(worn.apply(x), plain.apply(x))
    assert worn.unworn == plain


def test_simulate_with_play_equals_the_plant_simulation():
    linear = LinearBlock(a=(0.5, 0.7), b=(0.0, 1.4, 0.8), sample_period_s=1e-3)
    wearing = WearingOutputBacklash(0.248, 0.0698, 0.252, 0.0349, BacklashGrowth(per_rad_travel=1e-4))
    plant = PlantModel((linear, wearing))
    u = _back_and_forth(amplitude=3.0)
    y, play = simulate_with_play(plant, u)
    np.testing.assert_array_equal(y, plant.simulate(u))
    assert len(play) == u.size
    plain = PlantModel((linear, OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))
    y_plain, none = simulate_with_play(plain, u)
    assert none is None
    np.testing.assert_array_equal(y_plain, plain.simulate(u))


@pytest.mark.parametrize("kwargs, key", [({"per_rad_travel": -1e-3}, "per_rad_travel"),
                                         ({"per_rad_travel": math.nan}, "per_rad_travel"),
                                         ({"per_rad_travel": 1e-3, "max_rad": 0.0}, "max_rad")])
def test_bad_laws_are_refused_naming_the_parameter(kwargs, key):
    with pytest.raises(InvalidInputError, match=key):
        BacklashGrowth(**kwargs)


def test_the_simulated_gearbox_without_wear_is_unchanged():
    """The shipped plants without wear give the numbers they gave before the wear existed (digests taken
    with the code of that time), and their trajectories carry no play."""
    from rig.experiment_config import load_experiment_config
    from sim_backend.plant_config import load_plant_config

    expected = {"cerone2009": "f72be67550402d46b01c22fd1b741e9a67ca31606c3cde4411e626da585151f9",
                "precision_gearbox": "710f2e426da386fbe8a32e6870406e13530c9fac5424d85c02fbd044e533cfa2"}
    command = load_experiment_config(CONFIGS / "experiments" / "steady_staircase.toml").command_rad[:3000]
    for name, digest in expected.items():
        run = load_plant_config(CONFIGS / "plants" / f"{name}.toml").gearbox().simulate(command)
        assert run.play is None
        hashed = hashlib.sha256()
        for array in (run.load_angle_rad, run.measured_angle_rad, run.encoder_counts):
            hashed.update(np.ascontiguousarray(array).tobytes())
        assert hashed.hexdigest() == digest, name


def test_the_wearing_plant_config_loads_and_round_trips():
    from sim_backend.plant_config import load_plant_config, plant_config_from_toml_text, plant_config_to_toml

    config = load_plant_config(CONFIGS / "plants" / "wearing_gearbox.toml")
    wearing = config.plant.blocks[-1]
    assert isinstance(wearing, WearingOutputBacklash)
    assert wearing.growth == BacklashGrowth(per_rad_travel=2e-6, max_rad=0.05)
    assert plant_config_from_toml_text(plant_config_to_toml(config)).blocks == config.blocks
    run = config.gearbox().simulate(np.resize(np.repeat([1.5, -1.5, 2.5, -2.5], 100), 4000))
    assert run.play is not None and run.play.play_rad[-1] > run.play.play_rad[0]


@pytest.mark.parametrize("growth, key", [("{ per_rad_travel = -1.0 }", "backlash_growth.per_rad_travel"),
                                         ("{ per_rad_travel = 1e-6, max_rad = 0 }", "backlash_growth.max_rad"),
                                         ("{ per_rad_travel = 1e-6, rate = 2 }", "backlash_growth.rate"),
                                         ("{ max_rad = 0.1 }", "backlash_growth.per_rad_travel"),
                                         ("0.001", "backlash_growth")])
def test_bad_growth_tables_name_the_key(growth, key):
    from rig.protocols.errors import ConfigError
    from sim_backend.plant_config import plant_config_from_toml_text

    text = ("sample_period_s = 0.001\n[encoder]\nbits = 12\n[[blocks]]\ntype = \"output_backlash\"\n"
            f"m_l = 1.0\nc_l_rad = 0.01\nm_r = 1.0\nc_r_rad = 0.01\nbacklash_growth = {growth}\n")
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        plant_config_from_toml_text(text, "plant.toml")
