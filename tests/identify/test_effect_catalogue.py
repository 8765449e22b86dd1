"""The effect catalogue: every effect is one entry, and the workflow, the plant TOML
reader and writer and the hidden-effect cases all read it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from identify.discrepancy_cases import SAMPLE_PERIOD_S, random_effect, step_excitation
from identify.drive_train import DriveTrain
from identify.drive_train_effects import reference_train
from identify.effect_catalogue import (
    DYNAMICS_EFFECTS,
    EFFECT_NAMES,
    EFFECTS,
    GuessContext,
    effect,
    effect_for_block,
)
from identify.effect_signatures import signature_scores
from identify.plant_blocks import LinearBlock, PlantModel
from identify.validation import InvalidInputError
from sim_backend.plant_config import (
    BLOCK_TYPES,
    DRIVE_TRAIN_KEYS,
    load_plant_config,
    plant_config_from_toml_text,
    plant_config_to_toml,
)


@pytest.mark.parametrize("name", DYNAMICS_EFFECTS)
def test_every_dynamics_effect_round_trips_through_the_drive_train_table(name):
    # its keys are drive_train keys, and a train holding it reads back equal, the effect's values included
    entry = effect(name)
    rng = np.random.default_rng(3)
    u = step_excitation(2000, rng)
    block, _ = random_effect(name, rng, u)
    assert isinstance(block, DriveTrain) and entry.toml_type == "drive_train"
    assert all(key.key in DRIVE_TRAIN_KEYS for key in entry.toml_keys)
    base = plant_config_from_toml_text("sample_period_s = 0.001\n[encoder]\nbits = 12\n[[blocks]]\n"
                                       'type = "delay"\nsamples = 1\n')
    text = plant_config_to_toml(dataclasses.replace(base, blocks=(block,)))
    (again,) = plant_config_from_toml_text(text).blocks
    assert again == block
    assert entry.report(again) == entry.report(block)


@pytest.mark.parametrize("name", [n for n in EFFECT_NAMES if n not in DYNAMICS_EFFECTS])
def test_every_effect_round_trips_through_plant_toml_under_its_catalogue_type(name, tmp_path):
    entry = effect(name)
    rng = np.random.default_rng(3)
    u = step_excitation(2000, rng)
    block, _ = random_effect(name, rng, u)
    assert isinstance(block, entry.block_class)
    assert BLOCK_TYPES[entry.toml_type][0] is entry.block_class
    linear = LinearBlock(a=(-0.5,), b=(0.0, 0.5), sample_period_s=SAMPLE_PERIOD_S)
    config = load_plant_config_text(linear, block)
    again = plant_config_from_toml_text(plant_config_to_toml(config))
    assert again.blocks == config.blocks
    assert effect_for_block(again.blocks[1]) is entry
    path = tmp_path / "plant.toml"
    path.write_text(plant_config_to_toml(config))
    assert load_plant_config(path).blocks == config.blocks


def load_plant_config_text(linear, block):
    fields = effect_for_block(block).toml_fields(block)
    lines = ["sample_period_s = 0.001", "[encoder]", "bits = 12", "[[blocks]]", 'type = "linear"',
             f"a = {list(linear.a)}", f"b = {list(linear.b)}", "[[blocks]]"]
    lines += [f"{key} = {value!r}" if not isinstance(value, str) else f'{key} = "{value}"' for key, value in fields.items()]
    return plant_config_from_toml_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("name", EFFECT_NAMES)
def test_every_effect_builds_a_block_reporting_its_catalogue_parameters(name):
    entry = EFFECTS[name]
    rng = np.random.default_rng(5)
    u = step_excitation(2000, rng)
    y_hat = PlantModel((LinearBlock(a=(-0.9,), b=(0.0, 0.1), sample_period_s=SAMPLE_PERIOD_S),)).simulate(u)
    residual = 0.01 * np.sin(np.arange(u.size) / 50.0)
    scores = signature_scores(u, y_hat + residual, y_hat, 1e-3, SAMPLE_PERIOD_S)
    guesses = entry.guesses(GuessContext(u, residual, 1e-3, SAMPLE_PERIOD_S, scores, y_hat,
                                         reference_train(SAMPLE_PERIOD_S)))
    values = guesses[0] if guesses else (5.0,)
    assert len(values) == entry.free_parameters
    block = entry.build(values, SAMPLE_PERIOD_S)
    assert isinstance(block, entry.block_class)
    reported = entry.report(block)
    assert tuple(reported) == tuple(p.name for p in entry.parameters)
    assert all(p.unit for p in entry.parameters)
    random_block, _ = random_effect(name, rng, u)
    assert not entry.vanished(random_block, 1e-3), "a realistic hidden effect must not count as vanished"


def test_unknown_effect_names_the_choices():
    with pytest.raises(InvalidInputError, match="backlash"):
        effect("wobble")
