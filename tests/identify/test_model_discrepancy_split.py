"""A given linear model's two-mass form does not fix how the inertia is split between the motor and the load
(:func:`identify.model_discrepancy.candidates.split_family`): every split has a train of the same linear
response, and a play inside the train behaves differently in each. The records come from the clean-room
generator (``benchmarks/independent_plants``, used as a data source only) behind its cascade servo, whose motor
the load pushes back (J_l / J = 0.67); the benchmark's case runner scores the diagnosis."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

from identify.model_discrepancy.candidates import drive_train_like, split_family
from identify.model_discrepancy.thresholds import SPLIT_FORM_NOISE_BOUNDS, SPLIT_LOAD_SHARES
from identify.plant_blocks import PlantModel

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))
import model_discrepancy_confusion as confusion  # noqa: E402


def _play_record(servo: str) -> dict:
    return confusion.generator_module().generate("backlash", 1017, excitation="chirp", duration_s=3.0, bits=12,
                                                 noise_rad=confusion.NOISE_STD_RAD, nominal={"servo": servo})


def test_every_split_follows_the_block_and_only_the_true_one_lets_the_play_reproduce_the_record():
    # behind the cascade servo the two-mass fit of the block takes a light load (0.12 of the inertia, the truth
    # 0.67); with the generator's own play there its free run misses the record as badly as without a play
    record = _play_record("cascade")
    block = confusion.nominal_linear_block(record["nominal"])
    delta = confusion.independent_noise_bound(record["nominal"])
    u = record["command_rad"] - record["command_rad"][0]
    y = record["angle_rad"] - record["command_rad"][0]
    n_est = int(0.6 * u.size)
    play = 2.0 * record["truth"]["parameters"]["half_width_rad"]

    def validated_gap(train) -> float:
        error = PlantModel((dataclasses.replace(train, play_rad=play),)).simulate(u)[n_est:] - y[n_est:]
        return float(np.sqrt(np.mean(error ** 2)))

    base = drive_train_like(block, u[:n_est])
    family = split_family(block)
    assert [member.load_inertia_kg_m2 for member in family] == pytest.approx(SPLIT_LOAD_SHARES)
    following = [m for m in family if np.max(np.abs(m.apply(u) - block.apply(u))) <= SPLIT_FORM_NOISE_BOUNDS * delta]
    assert len(following) >= 3
    without_play = float(np.sqrt(np.mean((block.apply(u)[n_est:] - y[n_est:]) ** 2)))
    assert validated_gap(base) > 0.9 * without_play  # the light load's play explains nothing
    best = min(validated_gap(member) for member in following)
    assert best < 0.3 * without_play and best < delta  # a heavier load's play reproduces the record
    assert {round(m.load_inertia_kg_m2, 2) for m in following if validated_gap(m) < delta} >= {0.7}


def test_behind_a_servo_the_load_does_not_push_back_no_other_split_follows_the_block():
    # the kinematic servo holds the motor whatever the load does: only a light load reproduces that, so the
    # dynamics candidates keep the one train they had
    record = _play_record("kinematic")
    block = confusion.nominal_linear_block(record["nominal"])
    delta = confusion.independent_noise_bound(record["nominal"])
    u = record["command_rad"] - record["command_rad"][0]
    assert all(np.max(np.abs(m.apply(u) - block.apply(u))) > SPLIT_FORM_NOISE_BOUNDS * delta
               for m in split_family(block))


@pytest.mark.slow
def test_a_play_behind_a_servo_the_load_pushes_back_is_named_with_its_width_inside_the_interval():
    # before the other splits were tried: `ambiguous` between a gain error and gravity, the play's fit stopped at
    # half its width (4.1 against 8.3 mrad) and lowered the validated gap by 12 %
    case = confusion.run_independent_case("backlash", 0, 1, 1017, "given", ("chirp",),
                                          confusion.INDEPENDENT_DURATION_S, 1, 12, confusion.NOISE_STD_RAD,
                                          servo="cascade")
    assert case["seed"] == 1017 and case["excitation"] == "chirp"
    assert case["outcome"] == "right" and case["named"] == ["shaft_play"], case.get("reason")
    assert case["covered"] == [1, 1], case["missed"]
