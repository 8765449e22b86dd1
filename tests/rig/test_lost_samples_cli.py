"""Logs with LOST samples (and other unusable flags) are analysed: the reader keeps the flags, and
``rig diagnose``, ``rig identify hammerstein`` and ``rig identify output-backlash`` set the unusable samples
aside, say how many, and refuse only when too little is left, naming the file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from identify.cyclic_excitation import cyclic_random_excitation
from identify.discrepancy_cases import hidden_effect_record
from identify.experiment_record import ExperimentMetadata, SampleFlag
from identify.plant_blocks import InputBacklash, LinearBlock, PiecewiseLinearBorder, PlantModel
from rig import exit_codes
from rig.cli import main
from rig.log_file import LogWriter
from rig.record_import import read_measurement
from nominal_model import NOMINAL_TOML

PATTERNS = {"0.1 %": ("random", 0.001), "1 %": ("random", 0.01), "burst": ("burst", 50)}


def lost_samples(size: int, pattern: str, seed: int = 7) -> np.ndarray:
    kind, amount = PATTERNS[pattern]
    if kind == "random":
        return np.sort(np.random.default_rng(seed).choice(size, max(1, int(amount * size)), replace=False))
    return np.arange(size // 2 + 300, size // 2 + 300 + amount)


def write_log(path, period_s, u, y, lost, duplicate=()) -> None:
    """A rig log whose ``lost`` samples are LOST (angle NaN) and ``duplicate`` samples DUPLICATE."""
    flags = np.zeros(u.size, dtype=np.uint8)
    flags[np.asarray(lost, dtype=int)] = int(SampleFlag.LOST)
    flags[np.asarray(duplicate, dtype=int)] |= np.uint8(SampleFlag.DUPLICATE)
    angle = np.where(flags & SampleFlag.LOST, np.nan, y)
    with LogWriter(path, ExperimentMetadata(sample_period_s=period_s, source="test"), flush_every=4096) as writer:
        writer.append_many(np.arange(u.size) * period_s, u, angle, flags=flags)


@pytest.fixture(scope="module")
def backlash_record():
    return hidden_effect_record(("backlash",), 3)


def test_the_reader_keeps_the_flags_of_a_log_with_a_lost_sample(tmp_path, backlash_record):
    record = backlash_record
    log = tmp_path / "one_lost.csv"
    write_log(log, record.sample_period_s, record.command_rad, record.angle_rad, [11], duplicate=[40])
    read, report = read_measurement(log)
    assert read.flags[11] == SampleFlag.LOST and np.isnan(read.angle_rad[11])
    assert read.flags[40] == SampleFlag.DUPLICATE and read.lost_count == 1
    assert report.spikes == 0


@pytest.mark.parametrize("pattern", list(PATTERNS))
def test_diagnose_fits_the_hidden_backlash_with_samples_lost(tmp_path, capsys, backlash_record, pattern):
    record = backlash_record
    log = tmp_path / "lossy.csv"
    lost = lost_samples(record.command_rad.size, pattern)
    write_log(log, record.sample_period_s, record.command_rad, record.angle_rad, lost, duplicate=[5])
    model = tmp_path / "nominal.toml"
    model.write_text(NOMINAL_TOML)
    code = main(["diagnose", str(log), "--model", str(model), "--noise-bound", repr(record.noise_bound_rad), "--json"])
    assert code == exit_codes.SUCCESS
    document = json.loads(capsys.readouterr().out)
    # the play's map is fitted; its mechanism (a play, or friction without stiction) is left open
    assert document["verdict"] == "ambiguous" and document["ambiguous_between"] == ["backlash", "coulomb_friction"]
    assert [entry["effect"] for entry in document["missing_effects"]] == ["backlash"]
    truth = record.true_model.blocks[1]
    parameters = document["missing_effects"][0]["parameters"]
    assert parameters["c_l_rad"] == pytest.approx(truth.c_l_rad, abs=1e-3)
    assert parameters["c_r_rad"] == pytest.approx(truth.c_r_rad, abs=1e-3)
    assert document["set_aside"] == {"samples": lost.size + 1, "of": record.command_rad.size,
                                     "by_flag": {"LOST": lost.size, "DUPLICATE": 1}}


def test_diagnose_text_says_what_was_set_aside(tmp_path, capsys, backlash_record):
    record = backlash_record
    log = tmp_path / "lossy.csv"
    write_log(log, record.sample_period_s, record.command_rad, record.angle_rad, [11, 12, 13])
    model = tmp_path / "nominal.toml"
    model.write_text(NOMINAL_TOML)
    assert main(["diagnose", str(log), "--model", str(model), "--noise-bound", "0.001"]) == exit_codes.SUCCESS
    out = capsys.readouterr().out
    assert "set aside     3 of 3000 samples, unusable by their flags (LOST 3)" in out
    assert "step 1: backlash" in out


def test_diagnose_refuses_a_log_mostly_lost_naming_the_file_and_what_is_left(tmp_path, capsys, backlash_record):
    record = backlash_record
    log = tmp_path / "mostly_lost.csv"
    write_log(log, record.sample_period_s, record.command_rad, record.angle_rad, np.arange(2000, 2900))
    assert main(["diagnose", str(log), "--noise-bound", "0.001"]) == exit_codes.BAD_INPUT
    err = capsys.readouterr().err
    assert str(log) in err
    assert "leaves 300 measured samples of the 1200 of the validation segment; at least 600 (50 %) are needed" in err


NODES = tuple(np.linspace(-3.0, 3.0, 8).tolist())
H_A = np.array((-1.0, -0.9, -0.7, -0.4, 0.0, 0.4, 0.8, 1.0))
H_D = np.array((-1.0, -0.6, -0.2, 0.2, 0.5, 0.75, 0.9, 1.0))
HOLD = 100


@pytest.fixture(scope="module")
def cyclic_data():
    u = cyclic_random_excitation(HOLD + 2500, -3.0, 3.0, HOLD, rng=3)
    plant = PlantModel((InputBacklash(PiecewiseLinearBorder(NODES, tuple(H_A)), PiecewiseLinearBorder(NODES, tuple(H_D)),
                                      initial_output_rad=-1.0),
                        LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=0.01)))
    return u, plant.simulate(u) + 0.5 + np.random.default_rng(1).uniform(-1e-3, 1e-3, u.size)


@pytest.mark.parametrize("pattern", list(PATTERNS))
def test_identify_hammerstein_reads_a_log_with_samples_lost(tmp_path, capsys, cyclic_data, pattern):
    u, y = cyclic_data
    log = tmp_path / "cyclic.csv"
    lost = lost_samples(u.size, pattern)
    write_log(log, 0.01, u, y, lost)
    assert main(["identify", "hammerstein", str(log), "--order", "2", "--hold-samples", str(HOLD), "--json"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert np.max(np.abs(np.array(document["borders"]["ascending"]["h"]) - H_A - 0.5)) < 2e-3
    assert np.max(np.abs(np.array(document["borders"]["descending"]["h"]) - H_D - 0.5)) < 2e-3
    aside = document["set_aside"]
    assert aside["samples"] == lost.size and aside["by_flag"] == {"LOST": lost.size}
    assert 0 < aside["hankel_columns_left_out"] <= 30 * lost.size and aside["hankel_columns"] == u.size - 29
    assert document["num_columns"] == aside["hankel_columns"] - aside["hankel_columns_left_out"]


def test_identify_hammerstein_text_and_refusal_name_the_file(tmp_path, capsys, cyclic_data):
    u, y = cyclic_data
    log = tmp_path / "cyclic.csv"
    write_log(log, 0.01, u, y, [500])
    assert main(["identify", "hammerstein", str(log), "--order", "2", "--hold-samples", str(HOLD)]) == 0
    assert "set aside        1 of 2600 samples, unusable by their flags (LOST 1): 30 of the 2571 Hankel" in \
        capsys.readouterr().out
    write_log(log, 0.01, u, y, np.arange(HOLD, u.size, 20))
    assert main(["identify", "hammerstein", str(log), "--order", "2", "--hold-samples", str(HOLD)]) == 2
    err = capsys.readouterr().err
    assert str(log) in err and "leaves 71 complete windows" in err and "need at least 435" in err


def test_identify_output_backlash_bounds_hold_the_truth_with_samples_lost(tmp_path, capsys):
    from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
    from identify.plant_blocks import OutputBacklash

    plant = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))
    rng = np.random.default_rng(0)
    noise = 2 * np.pi / 2**12
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    steady_csv = tmp_path / "steady.csv"
    steady_csv.write_text("u,y\n" + "".join(f"{a!r},{b!r}\n" for a, b in zip(
        staircase[steady].tolist(), (plant.simulate(staircase)[steady] + rng.uniform(-noise, noise, 100)).tolist())))
    u = prbs_sequence(400, 1.0, rng=1)
    log = tmp_path / "prbs.csv"
    write_log(log, 1.0, u, plant.simulate(u) + rng.uniform(-noise, noise, u.size), [100, 101, 250])
    assert main(["identify", "output-backlash", "--steady", str(steady_csv), "--dynamic", str(log), "--noise-bound",
                 repr(noise), "--na", "2", "--nk", "1", "--nb", "2", "--partition-samples", "0", "--json"]) == 0
    document = json.loads(capsys.readouterr().out)
    for name, value in {"a1": 0.5, "a2": 0.7, "b1": 1.4, "b2": 0.8}.items():
        assert document["linear"][name]["lower"] <= value <= document["linear"][name]["upper"]
    # x_100, x_101 and x_250 are each needed by the equations at t .. t + 2: 4 + 3 of the 398
    assert document["set_aside"] == {"samples": 3, "of": 400, "by_flag": {"LOST": 3}, "equations_left_out": 7,
                                     "equations": 398}
