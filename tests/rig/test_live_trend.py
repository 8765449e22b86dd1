"""``rig run --live`` on the steady staircase: the latest trend window's guaranteed bounds on the play, from the
rows the view sees, are the bounds ``rig trend`` gives that window from the log; rows the view missed widen
them, never exclude the log's bounds; a live run shows them in its final frame."""

from __future__ import annotations

import concurrent.futures
import json
from pathlib import Path

import numpy as np
import pytest

from identify.backlash_trend import TrendWindow
from identify.experiment_record import SampleFlag
from rig import exit_codes
from rig.cli import main
from rig.live_trend import LiveTrend, trend_text
from rig.log_file import read_log
from rig.staircase_points import staircase_plan

from live_rig import sim_rig_config

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
STAIRCASE = CONFIGS / "experiments" / "steady_staircase.toml"


class InThisThread(concurrent.futures.Executor):
    """Runs each task at once, on the caller's thread: every window is bounded as soon as it is complete."""

    def submit(self, fn, /, *args, **kwargs):
        future = concurrent.futures.Future()
        future.set_result(fn(*args, **kwargs))
        return future


def _offline_trend(log: Path, window: str, capsys) -> list[TrendWindow]:
    main(["trend", str(log), "--window", window, "--jobs", "1", "--json"])
    return [TrendWindow.from_dict(window) for window in json.loads(capsys.readouterr().out)["windows"]]


def _live_windows(record, window_s: float, keep) -> dict[int, TrendWindow]:
    """Every window the live trend bounds from the rows ``keep`` (a mask) of ``record``, fed as the view takes
    them (batches of 100 rows)."""
    trend = LiveTrend(staircase_plan(record.metadata.config, "log"), record.metadata.sample_period_s, window_s,
                      record.metadata.noise_bound_rad, executor=InThisThread())
    usable = record.valid_mask
    windows = {}
    for start in range(0, len(record), 100):
        rows = slice(start, start + 100)
        chosen = keep[rows]
        trend.add(record.time_s[rows][chosen], record.command_rad[rows][chosen], record.angle_rad[rows][chosen],
                  usable[rows][chosen])
        latest = trend.current()
        if latest is not None:
            windows[latest.index] = latest
    assert trend.finish() is trend.current() and trend.error is None
    return windows


@pytest.fixture(scope="module")
def staircase_log(tmp_path_factory):
    """3.5 s of the steady staircase on the simulated wearing gearbox, with the truth of its play."""
    log = tmp_path_factory.mktemp("staircase") / "run.csv"
    assert main(["simulate", str(CONFIGS / "plants" / "wearing_gearbox.toml"), "--excitation", str(STAIRCASE),
                 "--duration", "3.5", "--out", str(log)]) == exit_codes.SUCCESS
    return log


def test_each_complete_window_has_the_bounds_rig_trend_gives_it(staircase_log, capsys):
    capsys.readouterr()
    offline = _offline_trend(staircase_log, "1s", capsys)
    record = read_log(staircase_log)
    live = _live_windows(record, 1.0, np.ones(len(record), dtype=bool))
    assert sorted(live) == [0, 1, 2]  # the window the run ended in (3-3.5 s) is not complete
    for index, window in live.items():
        expected = offline[index]
        assert window.status == expected.status == "bounded"
        assert (window.start_s, window.end_s) == (expected.start_s, expected.end_s)
        assert (window.right_points, window.left_points) == (expected.right_points, expected.left_points)
        np.testing.assert_allclose([window.play_rad.lower, window.play_rad.upper],
                                   [expected.play_rad.lower, expected.play_rad.upper], rtol=1e-12, atol=0)
        assert expected.truth_inside  # (the log's truth file: the bounds are right)
    assert trend_text(live[2]).startswith(f"trend: play [{live[2].play_rad.lower:.6g}, ")


def test_rows_the_view_missed_widen_the_bounds_and_keep_the_logs(staircase_log, capsys):
    record = read_log(staircase_log)
    every = _live_windows(record, 1.0, np.ones(len(record), dtype=bool))
    keep = np.ones(len(record), dtype=bool)
    keep[1050:1450] = False  # the view fell behind for 0.4 s of window 1: four of its half-wave ends unseen
    missed = _live_windows(record, 1.0, keep)
    assert missed[1].right_points + missed[1].left_points < every[1].right_points + every[1].left_points
    assert missed[1].play_rad.lower <= every[1].play_rad.lower <= every[1].play_rad.upper <= missed[1].play_rad.upper
    assert missed[0] == every[0] and missed[2] == every[2]


def test_a_live_run_of_the_staircase_shows_the_latest_windows_bounds(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    log = tmp_path / "run.csv"
    # 200 Hz (the view tests' rate): a half-wave of 100 samples is 0.5 s, so a window of 2 s has 2 points a side
    assert main(["run", str(sim_rig_config(tmp_path)), "--experiment", str(STAIRCASE), "--out", str(log),
                 "--duration", "4.5", "--json", "--live", "--trend-window", "2s"]) == exit_codes.SUCCESS
    shown = capsys.readouterr().err
    assert not (read_log(log).flags & int(SampleFlag.unusable())).any()  # (else the log's points differ)
    offline = _offline_trend(log, "2s", capsys)
    assert offline[1].status == "bounded"
    final = shown.rsplit(" . command   * load angle", 1)[1]
    assert trend_text(offline[1]) in final, final
