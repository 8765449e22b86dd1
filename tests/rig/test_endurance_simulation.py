"""Endurance records on the simulated clock: ``rig simulate --duration`` repeats a staircase before its filter
and writes the truth file of a wearing gearbox; the trend leaves out the wrapped half-wave of a log repeated
sample by sample."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from identify.experiment_record import ExperimentMetadata, ExperimentRecord
from rig import exit_codes
from rig.cli import main
from rig.staircase_points import staircase_steady_samples
from rig.experiment_config import REPEAT_FILTERED
from rig.experiment_config import load_experiment_config
from rig.log_file import read_log
from rig.truth_file import read_play_truth, truth_path_for
from sim_backend.plant_config import load_plant_config

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
STAIRCASE = CONFIGS / "experiments" / "steady_staircase.toml"


@pytest.mark.parametrize("shuffle", [False, True])
def test_a_repeated_staircase_stays_filtered_across_the_wrap(tmp_path, shuffle):
    text = STAIRCASE.read_text().replace("filter_order = 1", f"filter_order = 1\nshuffle = {str(shuffle).lower()}")
    (tmp_path / "staircase.toml").write_text(text)
    excitation = load_experiment_config(tmp_path / "staircase.toml")
    size = excitation.command_rad.size
    command = excitation.repeated(3 * size + 500)
    np.testing.assert_array_equal(command[:size], excitation.command_rad)  # the first cycle as generated
    within = np.max(np.abs(np.diff(excitation.command_rad)))
    assert np.max(np.abs(np.diff(command))) <= within + 1e-12  # no unfiltered step at the wraps
    # after the filter settles, each cycle's half-wave ends are the first cycle's
    ends = np.arange(1, 101) * 100 - 1
    np.testing.assert_allclose(command[ends[1:] + 2 * size], excitation.command_rad[ends[1:]], atol=1e-8)
    np.testing.assert_array_equal(excitation.repeated(700), excitation.command_rad[:700])


def test_simulate_duration_writes_the_log_and_the_truth_of_the_wear(tmp_path, capsys):
    log = tmp_path / "run.csv"
    assert main(["simulate", str(CONFIGS / "plants" / "wearing_gearbox.toml"), "--excitation", str(STAIRCASE),
                 "--duration", "25", "--out", str(log), "--json"]) == exit_codes.SUCCESS
    printed = json.loads(capsys.readouterr().out)
    assert printed == {"log": str(log), "samples": 25_000, "truth": str(truth_path_for(log))}
    record = read_log(log)
    assert len(record) == 25_000 and record.metadata.config["excitation_repeat"] == REPEAT_FILTERED
    assert record.metadata.config["excitation_samples"] == 10_000
    truth = read_play_truth(truth_path_for(log))
    gearbox = load_plant_config(CONFIGS / "plants" / "wearing_gearbox.toml").gearbox()
    excitation = load_experiment_config(STAIRCASE)
    play = gearbox.simulate(excitation.repeated(25_000)).play.play_rad
    # step-wise, the truth file is within its resolution (per half-width) of the true play at every sample
    rows = np.searchsorted(truth.time_s, record.time_s, side="right") - 1
    assert np.max(np.abs(truth.play_rad[rows] - play)) <= 2 * truth.resolution_rad
    assert truth.time_s[0] == 0.0 and truth.time_s[-1] == record.time_s[-1]
    assert truth.time_s.size < 25_000 / 4


def test_simulate_refuses_an_existing_truth_file_before_the_work(tmp_path, capsys):
    log = tmp_path / "run.csv"
    truth_path_for(log).write_text("mine\n")
    assert main(["simulate", str(CONFIGS / "plants" / "wearing_gearbox.toml"), "--excitation", str(STAIRCASE),
                 "--out", str(log)]) == exit_codes.WRITE_FAILED
    assert "run.truth.csv: the file exists" in capsys.readouterr().err
    assert not log.exists() and truth_path_for(log).read_text() == "mine\n"


def test_a_plant_without_wear_writes_no_truth_file(tmp_path):
    log = tmp_path / "run.csv"
    assert main(["simulate", str(CONFIGS / "plants" / "cerone2009.toml"), "--excitation", str(STAIRCASE),
                 "--out", str(log), "--duration", "1"]) == exit_codes.SUCCESS
    assert not truth_path_for(log).exists()


def test_the_half_wave_after_a_wrap_sample_by_sample_is_left_out():
    """``rig run --duration`` repeats the filtered samples: the command steps unfiltered at each wrap, and
    the first half-wave after it overshoots (its end is off the backlash line by 0.011 rad here)."""
    excitation = load_experiment_config(STAIRCASE)
    command = np.resize(excitation.command_rad, 30_000)
    run = load_plant_config(CONFIGS / "plants" / "cerone2009.toml").gearbox().simulate(command)
    metadata = ExperimentMetadata(sample_period_s=0.001, config={"excitation": excitation.metadata(),
                                                                 "excitation_samples": 10_000})
    record = ExperimentRecord(run.time_s, command, run.load_angle_rad, None, None, metadata)
    kept = staircase_steady_samples(record, Path("run.csv"), skip_after_wrap=True)
    np.testing.assert_array_equal(kept.wrapped_ends, [10_099, 20_099])
    assert kept.ends.size == 300 - 2
    u, y = kept.command_rad, kept.angle_rad
    line = np.where(u > 0, 0.252 * (u - 0.0349), 0.248 * (u + 0.0698))
    assert np.max(np.abs(y - line)) < 1e-7
    every = staircase_steady_samples(record, Path("run.csv"))  # rig identify output-backlash keeps them all
    assert every.ends.size == 300 and every.wrapped_ends.size == 0


def test_run_duration_repeats_a_staircase_before_its_filter(tmp_path):
    """``rig run --duration`` longer than the staircase repeats it as ``rig simulate`` does: the device gets
    no unfiltered step back to 0 at each wrap, and the log says how it was repeated."""
    text = STAIRCASE.read_text().replace("num_amplitudes = 50", "num_amplitudes = 2").replace(
        "samples_per_half_wave = 100", "samples_per_half_wave = 25").replace(
        "amplitude_min_rad = 0.6", "amplitude_min_rad = 0.2").replace("amplitude_max_rad = 3.0", "amplitude_max_rad = 0.3")
    (tmp_path / "staircase.toml").write_text(text)
    excitation = load_experiment_config(tmp_path / "staircase.toml")
    log = tmp_path / "run.csv"
    assert main(["run", str(CONFIGS / "sim_serial.toml"), "--experiment", str(tmp_path / "staircase.toml"),
                 "--duration", "0.35", "--out", str(log)]) == exit_codes.SUCCESS
    record = read_log(log)
    assert len(record) > 3 * excitation.command_rad.size
    assert record.metadata.config["excitation_repeat"] == REPEAT_FILTERED
    within = np.max(np.abs(np.diff(excitation.command_rad)))
    assert np.max(np.abs(np.diff(record.command_rad))) <= within + 1e-4  # the drive's counts: 2 pi / 2^17 rad
