"""``rig trend``: guaranteed bounds on the play per window of an endurance log of a wearing gearbox, made on
the simulated clock by ``rig simulate --duration`` (an hour of samples would take seconds; these take 40 s
of simulated time)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from identify.backlash_trend import BacklashTrend, TrendWindow, bound_window_play
from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag
from identify.result_format import ResultFormatError
from rig import exit_codes
from rig.cli import main
from rig.experiment_config import REPEAT_FILTERED
from rig.commands.trend import parse_window
from rig.experiment_config import load_experiment_config
from rig.log_file import write_log
from rig.truth_file import read_play_truth, truth_path_for
from sim_backend.plant_config import load_plant_config

STAIRCASE = """\
name = "short_staircase"
seed = 5
[excitation]
kind = "filtered_staircase"
amplitude_min_rad = 0.6
amplitude_max_rad = 3.0
num_amplitudes = 10
filter_pole = 0.8125
samples_per_half_wave = 100
"""

PLANT = """\
name = "fast_wear"
sample_period_s = 0.001
seed = 11
[encoder]
bits = 32
signed = true
[noise]
kind = "uniform"
bound_rad = 0.0015339807878856412
[[blocks]]
type = "linear"
a = [0.5, 0.7]
b = [0.0, 1.4, 0.8]
[[blocks]]
type = "output_backlash"
m_l = 0.248
c_l_rad = 0.0698
m_r = 0.252
c_r_rad = 0.0349
backlash_growth = { per_rad_travel = 1.0e-4 }
"""

SLOPE_MAX = 0.252
WINDOW_S = 10.0


@pytest.fixture(scope="module")
def endurance(tmp_path_factory):
    """40 s of the short staircase on a gearbox whose play wears fast (about 0.009 rad per 10 s window),
    its truth file, and the wear allowance the truth justifies (the slope times the most a half-width wore
    within one window, with a margin)."""
    folder = tmp_path_factory.mktemp("endurance")
    (folder / "staircase.toml").write_text(STAIRCASE)
    (folder / "plant.toml").write_text(PLANT)
    log = folder / "run.csv"
    assert main(["simulate", str(folder / "plant.toml"), "--excitation", str(folder / "staircase.toml"),
                 "--duration", "40", "--out", str(log)]) == exit_codes.SUCCESS
    truth = read_play_truth(truth_path_for(log))
    worn = max(float(np.ptp(side[(truth.time_s >= k * WINDOW_S) & (truth.time_s < (k + 1) * WINDOW_S)]))
               for side in (truth.c_l_rad, truth.c_r_rad) for k in range(4))
    return log, truth, 1.2 * SLOPE_MAX * (worn + truth.resolution_rad)


def _trend(log: Path, *options: str, capsys) -> tuple[int, dict]:
    code = main(["trend", str(log), "--window", "10s", "--json", *options])
    return code, json.loads(capsys.readouterr().out)


def test_the_bounds_hold_the_true_play_in_every_window_and_grow_with_it(endurance, tmp_path, capsys):
    log, truth, allowance = endurance
    outputs = {"--save": tmp_path / "trend.json", "--csv": tmp_path / "trend.csv", "--figure": tmp_path / "trend.png"}
    code, document = _trend(log, "--wear-allowance", repr(allowance), "--jobs", "2",
                            *[item for option, path in outputs.items() for item in (option, str(path))], capsys=capsys)
    assert code == exit_codes.SUCCESS
    trend = BacklashTrend.from_dict(document)
    assert [w.status for w in trend.windows] == ["bounded"] * 4
    assert [(w.start_s, w.end_s) for w in trend.windows] == [(0.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 40.0)]
    # every value the true play took in a window lies inside that window's bounds
    assert trend.truth_inside_count == (4, 4)
    for window in trend.windows:
        low, high = truth.play_range(window.start_s, window.end_s)
        assert window.play_rad.lower <= low and high <= window.play_rad.upper
    centers = [w.play_rad.center for w in trend.windows]
    assert all(later > earlier for earlier, later in zip(centers, centers[1:]))
    grown = truth.play_rad[-1] - truth.play_rad[0]
    assert centers[-1] - centers[0] > 0.5 * grown > 0.01
    # the saved JSON reopens to the same result; the CSV has a row per window; the figure is a PNG
    assert BacklashTrend.from_dict(json.loads(outputs["--save"].read_text())) == trend
    rows = list(csv.DictReader(outputs["--csv"].open()))
    assert [row["status"] for row in rows] == ["bounded"] * 4
    assert float(rows[2]["play_lower_rad"]) == trend.windows[2].play_rad.lower
    assert float(rows[2]["truth_max_rad"]) == trend.windows[2].truth_max_rad and rows[2]["truth_inside"] == "true"
    assert outputs["--figure"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_one_process_gives_the_same_result_as_the_pool(endurance, capsys):
    log, _, allowance = endurance
    _, pooled = _trend(log, "--wear-allowance", repr(allowance), "--jobs", "2", capsys=capsys)
    _, alone = _trend(log, "--wear-allowance", repr(allowance), "--jobs", "1", capsys=capsys)
    assert pooled == alone


def test_without_the_wear_allowance_a_window_worn_apart_is_an_empty_set_that_says_so(endurance, capsys):
    log, _, _ = endurance
    code, document = _trend(log, "--window", "40s", capsys=capsys)  # one window over all the wear
    (window,) = document["windows"]
    assert code == exit_codes.EMPTY_FEASIBLE_SET
    assert window["status"] == "empty" and "times larger" in window["reason"] and window["play_rad"] is None


def _staircase_then_hold(folder: Path, lost_tails: int = 0) -> Path:
    """A log of 10 s of the staircase and then 10 s holding its last level (negative): the second window
    has no reversal. ``lost_tails``: that many half-waves of the first window lose their whole settled
    tail (LOST)."""
    (folder / "staircase.toml").write_text(STAIRCASE)
    excitation = load_experiment_config(folder / "staircase.toml")
    command = excitation.repeated(10_000)
    command = np.concatenate([command, np.full(10_000, command[-1])])
    gearbox = load_plant_config(Path(__file__).resolve().parents[2] / "configs" / "plants" / "cerone2009.toml").gearbox()
    run = gearbox.simulate(command)
    angle, flags = run.measured_angle_rad.copy(), np.zeros(command.size, dtype=np.uint8)
    for k in range(lost_tails):  # half-waves 3, 5, ...: the last 10 samples of each
        end = (3 + 2 * k) * 100 + 99
        angle[end - 9:end + 1], flags[end - 9:end + 1] = np.nan, int(SampleFlag.LOST)
    metadata = ExperimentMetadata(
        sample_period_s=0.001, source="test", transport="offline", noise_bound_rad=gearbox.measurement_error_bound_rad,
        config={"excitation": excitation.metadata(), "excitation_samples": int(excitation.command_rad.size),
                "num_samples": int(command.size), "excitation_repeat": REPEAT_FILTERED})
    path = folder / "hold.csv"
    write_log(path, ExperimentRecord(run.time_s, command, angle, None, flags, metadata))
    return path


def test_a_window_without_reversals_cannot_bound_the_play_and_says_why(tmp_path, capsys):
    log = _staircase_then_hold(tmp_path, lost_tails=3)
    code, document = _trend(log, capsys=capsys)
    assert code == exit_codes.SUCCESS
    first, second = (TrendWindow.from_dict(window) for window in document["windows"])
    assert first.status == "bounded" and first.play_rad.contains(0.0698 + 0.0349)
    # the LOST samples are set aside: three half-waves give no point, the bounds still hold
    assert first.samples_set_aside == 30 and first.points_set_aside == 3 and first.right_points + first.left_points == 97
    assert second.status == "cannot_bound" and second.play_rad is None and second.right_points == 0
    assert second.reason.startswith("no reversal: all 100 steady-state points are on the negative side")
    assert "right flank" in second.reason
    main(["trend", str(log), "--window", "10s"])
    text = capsys.readouterr().out
    assert "cannot_bound: no reversal" in text and "set aside: 30 samples" in text


def test_an_existing_output_is_not_overwritten_without_force(tmp_path, capsys):
    log = _staircase_then_hold(tmp_path)
    table, saved = tmp_path / "trend.csv", tmp_path / "trend.json"
    table.write_text("mine\n")
    assert main(["trend", str(log), "--window", "10s", "--csv", str(table), "--save", str(saved)]) == \
        exit_codes.WRITE_FAILED
    assert "the file exists (--csv)" in capsys.readouterr().err
    assert table.read_text() == "mine\n" and not saved.exists()  # refused before any work
    assert main(["trend", str(log), "--window", "10s", "--csv", str(table), "--force"]) == exit_codes.SUCCESS
    assert table.read_text().startswith("window,start_s,end_s,status")


def test_a_log_that_is_no_staircase_is_refused_naming_the_file_and_what_to_record(tmp_path, capsys):
    (tmp_path / "prbs.toml").write_text('[excitation]\nkind = "prbs"\nnum_samples = 2000\namplitude_rad = 1.0\n')
    log = tmp_path / "prbs.csv"
    main(["simulate", str(Path(__file__).resolve().parents[2] / "configs" / "plants" / "cerone2009.toml"),
          "--excitation", str(tmp_path / "prbs.toml"), "--out", str(log)])
    capsys.readouterr()
    assert main(["trend", str(log)]) == exit_codes.BAD_INPUT
    error = capsys.readouterr().err
    assert str(log) in error and "prbs" in error and "steady_staircase.toml --duration" in error


@pytest.mark.parametrize("text, seconds", [("60s", 60.0), ("2.5min", 150.0), ("1h", 3600.0), ("90", 90.0),
                                           ("1e1 s", 10.0)])
def test_window_lengths_take_their_unit(text, seconds):
    assert parse_window(text) == seconds


@pytest.mark.parametrize("text", ["60 parsecs", "-5s", "0min", "s", ""])
def test_bad_window_lengths_are_refused_naming_the_option(text):
    with pytest.raises(ValueError, match="--window"):
        parse_window(text)


def test_the_result_refuses_another_kind_and_keeps_a_window_that_cannot_bound():
    u = np.array([1.0, -1.0, 2.0, -2.0, 3.0, -3.0])
    y = np.where(u > 0, 0.25 * (u - 0.04), 0.25 * (u + 0.06))
    bounded = bound_window_play(0, 0.0, 60.0, u, y, 1e-3)
    one_side = bound_window_play(1, 60.0, 120.0, u[u > 0], y[u > 0], 1e-3)
    single = bound_window_play(2, 120.0, 180.0, np.array([1.0, -1.0, 1.0, -1.0]), np.array([0.24, -0.26, 0.24, -0.26]),
                               1e-3)
    assert bounded.play_rad.contains(0.1) and bounded.c_l_rad.contains(0.06) and bounded.c_r_rad.contains(0.04)
    assert one_side.status == "cannot_bound" and "left flank" in one_side.reason
    assert single.status == "cannot_bound" and "1 distinct amplitude" in single.reason
    trend = BacklashTrend("x.csv", 60.0, 1e-3, None, (bounded, one_side, single))
    assert BacklashTrend.from_dict(json.loads(json.dumps(trend.to_dict()))) == trend
    with pytest.raises(ResultFormatError, match="backlash_trend"):
        BacklashTrend.from_dict({**trend.to_dict(), "kind": "output_backlash"})
