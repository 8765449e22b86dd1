"""``rig run --live``, headless: the terminal view is chosen without a display, the log of a
run with the view holds the same samples as one without it, and a slow renderer costs frames and rows of the
view, never samples of the log."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest

from identify.experiment_record import SampleFlag
from rig import exit_codes, live_view
from rig.cli import main
from rig.live_view import LiveFeed, LiveFrame, TerminalRenderer, WindowRenderer, display_available
from rig.log_file import read_log
from rig.rig_config import load_rig_config
from sim_backend.plant_config import load_plant_config

from live_rig import CONFIGS, RATE_HZ, sim_rig_config


def _run(directory: Path, seconds: float, *options: str) -> Path:
    directory.mkdir()
    log = directory / "run.csv"
    assert main(["run", str(sim_rig_config(directory)), "--experiment", str(CONFIGS / "experiments" / "prbs.toml"),
                 "--out", str(log), "--duration", repr(seconds), "--json", *options]) == exit_codes.SUCCESS
    return log


def _flagged(record, flag) -> np.ndarray:
    return (record.flags & flag) != 0


def _assert_the_simulated_plant_answered(config_path: Path, record) -> None:
    """Every answered sample is what the plant gives offline for the commands logged (the plant steps once per
    SYNC: a run is deterministic in its samples)."""
    config = load_rig_config(config_path)
    expected = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    answered = ~_flagged(record, SampleFlag.LOST)
    measured = expected.simulate(record.command_rad).measured_angle_rad
    np.testing.assert_array_equal(record.angle_rad[answered], measured[answered])


@pytest.fixture
def headless(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("MPLBACKEND", "Agg")


def test_a_live_run_logs_the_same_samples_as_a_run_without_the_view(headless, tmp_path, capsys):
    live = read_log(_run(tmp_path / "live", 1.0, "--live"))
    shown = capsys.readouterr().err
    plain = read_log(_run(tmp_path / "plain", 1.0))
    assert live.num_samples == plain.num_samples == 200  # complete: one row per sample of the second
    np.testing.assert_array_equal(live.time_s, plain.time_s)
    # the same commands, except where a loaded host made one run (not the other) hold a sample: the log then has
    # the command the drive really applied, and the plant's answers follow it from there on
    held = _flagged(live, SampleFlag.HELD) | _flagged(plain, SampleFlag.HELD)
    assert (~held).sum() >= 100  # 100 held would take half a second of host stalls beyond the 100 ms lead
    np.testing.assert_array_equal(live.command_rad[~held], plain.command_rad[~held])
    # so each log holds exactly the answers of the plant to its own commands; with no sample held or lost in
    # either run the two logs are equal sample for sample
    _assert_the_simulated_plant_answered(tmp_path / "live" / "sim_canopen.toml", live)
    _assert_the_simulated_plant_answered(tmp_path / "plain" / "sim_canopen.toml", plain)
    if not (held | _flagged(live, SampleFlag.LOST) | _flagged(plain, SampleFlag.LOST)).any():
        np.testing.assert_array_equal(live.angle_rad, plain.angle_rad)
    # the terminal view (no display), its last frame after the run with the log's own counters
    lost, held = _flagged(live, SampleFlag.LOST).sum(), _flagged(live, SampleFlag.HELD).sum()
    assert " . command   * load angle" in shown
    assert f"samples 200/200  lost {lost}  held {held}" in shown
    assert "0 of 200 rows not shown (the log has every sample)" in shown  # the buffer holds 4096 rows


class SlowRenderer:
    """A renderer far slower than the frame interval (0.5 s a frame against 0.1 s)."""

    min_interval_s = 0.0

    def __init__(self) -> None:
        self.frames: list[LiveFrame] = []
        self.closed = False

    def draw(self, frame: LiveFrame) -> None:
        self.frames.append(frame)
        time.sleep(0.5)

    def close(self) -> None:
        self.closed = True


def test_a_slow_renderer_loses_frames_and_rows_of_the_view_never_samples(headless, tmp_path, capsys, monkeypatch):
    renderer = SlowRenderer()
    monkeypatch.setattr(live_view, "choose_renderer", lambda stream: renderer)
    # 8 rows between the run and the view: at 200 Hz a 0.5 s frame lets 100 rows arrive
    monkeypatch.setattr(live_view, "LIVE_BUFFER_ROWS", 8)
    log = _run(tmp_path / "slow", 2.0, "--live")
    record = read_log(log)
    assert record.num_samples == 400 and renderer.closed
    _assert_the_simulated_plant_answered(tmp_path / "slow" / "sim_canopen.toml", record)
    last = renderer.frames[-1]
    assert last.final and len(renderer.frames) >= 2
    assert (last.samples, last.total_samples) == (400, 400)
    assert last.lost == _flagged(record, SampleFlag.LOST).sum()  # exact, though the view missed rows
    assert last.held == _flagged(record, SampleFlag.HELD).sum()
    assert last.dropped_rows > 0 and last.time_s.size < 400
    np.testing.assert_array_equal(last.time_s, np.sort(last.time_s))  # the rows it did see, in order
    summary = capsys.readouterr().err.strip().splitlines()[-1]
    frames_skipped = int(summary.split(" frames drawn, ")[1].split(" skipped")[0])
    assert frames_skipped > 0
    assert f"{last.dropped_rows} of 400 rows not shown (the log has every sample)" in summary


def test_the_feed_keeps_the_newest_rows_and_counts_every_one():
    feed = LiveFeed(capacity=3)
    flags = [0, int(SampleFlag.LOST), int(SampleFlag.HELD), 0, int(SampleFlag.LOST | SampleFlag.LATE)]
    for k, flag in enumerate(flags):
        feed.offer(0.01 * k, float(k), float(-k), flag)
    assert [row[1] for row in feed.take()] == [2.0, 3.0, 4.0]
    assert (feed.offered, feed.dropped, feed.lost, feed.held) == (5, 2, 2, 1)
    assert feed.take() == [] and feed.dropped == 2


@pytest.mark.parametrize("environ, expected", [
    ({"DISPLAY": ":0"}, True), ({"WAYLAND_DISPLAY": "wayland-0"}, True), ({}, False),
    ({"DISPLAY": ":0", "MPLBACKEND": "Agg"}, False), ({"DISPLAY": ":0", "MPLBACKEND": "svg"}, False),
    ({"DISPLAY": ":0", "MPLBACKEND": "TkAgg"}, True)])
def test_a_window_only_with_a_display_and_an_interactive_backend(environ, expected, monkeypatch):
    monkeypatch.setattr(live_view.sys, "platform", "linux")
    assert display_available(environ) is expected


def _frame(n: int, final: bool = False) -> LiveFrame:
    t = np.arange(n) / RATE_HZ
    return LiveFrame(t, np.sign(np.sin(7 * t)), 0.5 * np.sign(np.sin(7 * t)), samples=n, total_samples=500, lost=1,
                     held=2, dropped_rows=0, final=final)


def test_the_terminal_plot_puts_both_curves_between_their_range():
    lines = TerminalRenderer(stream=None, width=40, height=9).render(_frame(300))
    assert lines[0].endswith("+1 rad") and lines[10].endswith("-1 rad")
    plot = lines[1:10]
    assert plot[0].count(".") > 0 and plot[-1].count(".") > 0  # the command at +-1 rad: top and bottom rows
    assert plot[2].count("*") > 0 and plot[6].count("*") > 0  # the angle at +-0.5 rad: rows 2 and 6 of 0..8
    assert lines[-1].endswith("samples 300/500  lost 1  held 2")


def test_the_status_line_gives_the_time_elapsed_and_left_of_a_long_run():
    frame = dataclasses.replace(_frame(300), samples=3_600_000, total_samples=28_800_000, sample_period_s=1e-3)
    assert frame.status_line().endswith("elapsed 1:00:00  ETA 7:00:00  samples 3600000/28800000  lost 1  held 2")


def test_the_window_draws_what_it_is_sent_off_screen(headless):
    window = WindowRenderer.start(require_window=False)  # Agg: the same figure code, drawn off screen
    assert window.backend.lower() == "agg"
    try:
        window.draw(_frame(100))
        window.draw(_frame(200, final=True))  # waits until the window has drawn the final frame
        assert 1 <= window.frames_sent <= 2 and window.frames_shown == window.frames_sent
    finally:
        window.close()
    assert not window._process.is_alive()


def test_a_display_that_does_not_answer_gives_the_terminal_view_and_says_why(monkeypatch):
    monkeypatch.setenv("DISPLAY", ":97")  # set, as after a closed X forwarding, but no server behind it
    monkeypatch.delenv("MPLBACKEND", raising=False)
    renderer = live_view.choose_renderer(stream=None)
    assert isinstance(renderer, TerminalRenderer)
    assert renderer.note.startswith("no window: matplotlib chose its non-interactive backend")
    assert "no display server answers at :97" in renderer.note
    assert renderer.render(_frame(10))[-1] == renderer.note  # shown under the status line
