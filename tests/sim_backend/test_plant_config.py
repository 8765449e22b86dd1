"""Plant configs: the shipped files load, round-trip through TOML, and errors name file and key."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from identify.plant_blocks import (
    InputSwitch,
    LinearBlock,
    OutputBacklash,
    OutputGain,
    PiecewiseLinearBorder,
    PlantModel,
    pouliquen2013_switch,
)
from rig.protocols.errors import ConfigError
from sim_backend.noise import BoundedUniformNoise, ColouredNoise
from sim_backend.plant_config import load_plant_config, plant_config_from_toml_text, plant_config_to_toml

PLANTS = Path(__file__).resolve().parents[2] / "configs" / "plants"

MINIMAL = """
sample_period_s = 0.001
[encoder]
bits = 12
[[blocks]]
type = "linear"
a = [0.5, 0.7]
b = [0.0, 1.4, 0.8]
"""


def test_cerone_config_holds_the_paper_parameters():
    config = load_plant_config(PLANTS / "cerone2009.toml")
    linear, backlash = config.plant.blocks
    assert linear == LinearBlock(a=(0.5, 0.7), b=(0.0, 1.4, 0.8), sample_period_s=1e-3)
    assert linear.static_gain == pytest.approx(1.0)
    assert backlash == OutputBacklash(m_l=0.248, c_l_rad=0.0698, m_r=0.252, c_r_rad=0.0349)
    # the paper's error model: eta ~ U[-d, d], d = one count of a 12-bit encoder; a 32-bit encoder reads it
    assert isinstance(config.noise, BoundedUniformNoise) and config.noise.bound_rad == pytest.approx(2 * math.pi / 4096)
    assert config.encoder.bits == 32
    assert config.seed == 2009


def test_pouliquen_configs_hold_the_paper_borders_and_noise():
    switch = load_plant_config(PLANTS / "pouliquen2013_switch.toml")
    assert switch.plant.blocks[0] == pouliquen2013_switch()
    assert isinstance(switch.noise, ColouredNoise) and switch.noise.snr_db == 10.0
    assert switch.plant.blocks[1].static_gain == pytest.approx(1.0)


@pytest.mark.parametrize("name", ("cerone2009", "pouliquen2013_backlash", "pouliquen2013_switch", "precision_gearbox",
                                  "pendulum_servo"))
def test_shipped_configs_round_trip_through_toml(name):
    config = load_plant_config(PLANTS / f"{name}.toml")
    again = plant_config_from_toml_text(plant_config_to_toml(config))
    for field in ("name", "description", "sample_period_s", "encoder", "noise", "blocks", "enabled", "seed"):
        assert getattr(again, field) == getattr(config, field), field


def test_node_table_borders_and_disabled_blocks_round_trip():
    text = MINIMAL + """
[[blocks]]
type = "input_switch"
enabled = false
ascending = { kind = "table", nodes_u = [-1.0, 0.0, 1.0], values = [-1.0, -0.2, 1.0] }
descending = { kind = "table", nodes_u = [-1.0, 0.0, 1.0], values = [-1.0, 0.2, 1.0] }
"""
    config = plant_config_from_toml_text(text)
    assert config.enabled == (True, False)
    assert len(config.plant.blocks) == 1
    assert isinstance(config.blocks[1], InputSwitch)
    assert config.blocks[1].ascending == PiecewiseLinearBorder((-1.0, 0.0, 1.0), (-1.0, -0.2, 1.0))
    assert plant_config_from_toml_text(plant_config_to_toml(config)).blocks == config.blocks


def test_a_fitted_gain_error_block_round_trips_and_scales_the_output():
    config = plant_config_from_toml_text(MINIMAL + '[[blocks]]\ntype = "gain"\ngain = 1.08\n')
    assert config.blocks[1] == OutputGain(1.08)
    assert plant_config_from_toml_text(plant_config_to_toml(config)).blocks == config.blocks
    u = np.linspace(0.0, 1.0, 50)
    assert config.plant.simulate(u) == pytest.approx(1.08 * PlantModel(config.blocks[:1]).simulate(u))


@pytest.mark.parametrize(("extra", "replace", "key", "problem"), [
    ("colour = 1\n", None, "colour", "unknown key"),
    ("", ("bits = 12", "bits = 0"), "encoder.bits", ">= 1"),
    ("", ("sample_period_s = 0.001", ""), "sample_period_s", "required"),
    ("", ('type = "linear"', 'type = "lenear"'), "blocks[0].type", "expected one of"),
    ("", ("a = [0.5, 0.7]", 'a = "0.5"'), "blocks[0].a", "list of finite numbers"),
    ("[[blocks]]\ntype = \"output_backlash\"\nm_l = -0.2\nc_l_rad = 0.1\nm_r = 0.2\nc_r_rad = 0.1\n", None,
     "blocks[1].m_l", "> 0"),
    ("[[blocks]]\ntype = \"delay\"\nsamples = 2\nsample = 3\n", None, "blocks[1].sample", "unknown key"),
    ("[noise]\nkind = \"gaussian\"\n", None, "noise.std_rad", "exactly one of std_rad and snr_db"),
    ("[[blocks]]\ntype = \"input_backlash\"\nascending = { kind = \"table\", nodes_u = [1.0, 0.0], values = [0.0, 1.0] }\n"
     "descending = { kind = \"arctan\", input_shift_rad = 1.0 }\n", None, "blocks[1].ascending.nodes_u",
     "strictly increasing"),
    ("[[blocks]]\ntype = \"resonance\"\nfrequency_hz = 900.0\ndamping_ratio = 0.05\n", None, "blocks[1].frequency_hz", "Nyquist"),
])
def test_config_errors_name_file_and_key(tmp_path, extra, replace, key, problem):
    text = MINIMAL
    if replace:
        text = text.replace(*replace)
    # top-level keys must come before the first table
    text = extra + text if extra.startswith("colour") else text + extra
    path = tmp_path / "plant.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as caught:
        load_plant_config(path)
    assert caught.value.source == str(path)
    assert caught.value.key == key, str(caught.value)
    assert problem in caught.value.problem


def test_missing_file_is_named():
    with pytest.raises(ConfigError, match="no such file"):
        load_plant_config(PLANTS / "nope.toml")
