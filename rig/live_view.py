"""Watch a run as it goes (``rig run --live``): the command, the load angle and the lost/held counters.

The view never slows the capture. It sits on the sink (:class:`ObservedSink`, a
:class:`rig.runner.SampleSink`): each final row goes to the log first, then is offered to a bounded buffer
(:class:`LiveFeed`, a ``collections.deque`` with ``maxlen``: an append is O(1), takes no lock the sample
path could wait on, and pushes out the oldest row when the view has fallen behind). The LOST/HELD counters
are counted there, from every row, so they stay exact whatever the view misses. A thread of its own
(:class:`LiveView`) takes what the buffer holds a few times a second and hands a :class:`LiveFrame` to a
renderer; a frame that comes due while the renderer is still busy is skipped, not queued. So a slow
renderer costs frames and rows *of the view*, never samples of the log.

On the steady staircase the view also shows the latest trend window's guaranteed bounds on the play
(:class:`rig.live_trend.LiveTrend`: the points picked on the view's thread, each window bounded in a process of its
own).

Renderers: :class:`WindowRenderer`, a matplotlib figure drawn in a process of its own (a GUI needs its main
thread, and the runner owns this one), when a display is there; :class:`TerminalRenderer`, a text plot on
stderr, otherwise (no ``DISPLAY``/``WAYLAND_DISPLAY``, or ``MPLBACKEND`` a non-interactive backend such as
``Agg``). Nothing here prints on its own: the terminal renderer writes to the stream it is given.
"""

from __future__ import annotations

import collections
import contextlib
import math
import os
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TextIO

import numpy as np
from numpy.typing import NDArray

from identify.experiment_record import SampleFlag
from rig.live_trend import trend_text
from rig.sinks import ForwardingSink

if TYPE_CHECKING:
    from rig.live_trend import LiveTrend

__all__ = ["FRAME_INTERVAL_S", "LIVE_BUFFER_ROWS", "LiveFeed", "LiveFrame", "LiveView", "ObservedSink",
           "TerminalRenderer", "WindowRenderer", "WindowUnavailable", "choose_renderer", "display_available",
           "open_live_view"]

LIVE_BUFFER_ROWS = 4096
"""Rows held between the sample path and the view at most (4 s at 1 kHz); older ones are pushed out."""
FRAME_INTERVAL_S = 0.1
"""A frame at most this often (10 a second); a renderer may ask for fewer (:attr:`Renderer.min_interval_s`)."""
WINDOW_S = 5.0
"""The view shows the last this many seconds."""
NON_INTERACTIVE_BACKENDS = frozenset({"agg", "cairo", "pdf", "pgf", "ps", "svg", "template"})
"""matplotlib's built-in backends that draw no window (``BackendFilter.NON_INTERACTIVE`` of matplotlib 3.9)."""

_LOST, _HELD, _UNUSABLE = int(SampleFlag.LOST), int(SampleFlag.HELD), int(SampleFlag.unusable())


class LiveFeed:
    """The bounded buffer between the sample path (:meth:`offer`) and the view (:meth:`take`), with the
    counters of every row offered."""

    def __init__(self, capacity: int = LIVE_BUFFER_ROWS) -> None:
        if capacity < 1:
            raise ValueError(f"live view buffer: expected at least 1 row, got {capacity}")
        self._rows: collections.deque[tuple[float, float, float, int]] = collections.deque(maxlen=capacity)
        self.offered = 0
        self.taken = 0
        self.lost = 0
        self.held = 0

    def offer(self, time_s: float, command_rad: float, angle_rad: float, flags: int) -> None:
        """From the sample path: count the row and buffer it; never waits (a full buffer drops its oldest row)."""
        self.offered += 1
        if flags & _LOST:
            self.lost += 1
        if flags & _HELD:
            self.held += 1
        self._rows.append((time_s, command_rad, angle_rad, flags))

    def take(self) -> list[tuple[float, float, float, int]]:
        """From the view: every row buffered now, oldest first (time, command, angle, flags)."""
        rows = []
        with contextlib.suppress(IndexError):
            while True:
                rows.append(self._rows.popleft())
        self.taken += len(rows)
        return rows

    @property
    def dropped(self) -> int:
        """Rows the view never saw (pushed out of the full buffer); the log has them all."""
        pending = len(self._rows)  # first: a row is counted offered before it is buffered
        return self.offered - self.taken - pending


class ObservedSink(ForwardingSink):
    """A :class:`rig.runner.SampleSink` that writes each row to ``sink`` and then offers it to ``feed``."""

    def __init__(self, sink: Any, feed: LiveFeed) -> None:
        super().__init__(sink)
        self._feed = feed

    def append(self, time_s: float, command_rad: float, angle_rad: float, encoder_counts: int | None = None,
               flags: int = 0, **columns: float) -> None:
        super().append(time_s, command_rad, angle_rad, encoder_counts, flags, **columns)  # the log first
        self._feed.offer(time_s, command_rad, angle_rad, flags)


@dataclass(frozen=True)
class LiveFrame:
    """What one picture of the view shows.

    Attributes
    ----------
    time_s, command_rad, angle_rad
        The rows of the last :data:`WINDOW_S` seconds that reached the view (gaps where it dropped some).
    samples, total_samples
        Rows written to the log so far, and rows the run will write.
    lost, held
        Rows flagged LOST / HELD so far (counted from every row, exact).
    dropped_rows
        Rows the view did not see (all of them are in the log).
    final
        The last frame, drawn after the run.
    trend
        The latest trend window's bounds on the play in words (:func:`rig.live_trend.trend_text`); "" where the
        view has no trend.
    sample_period_s
        The rig's sample period: the status line gives the run's time so far and the time left (nan: not
        shown).
    """

    time_s: NDArray[np.float64]
    command_rad: NDArray[np.float64]
    angle_rad: NDArray[np.float64]
    samples: int
    total_samples: int
    lost: int
    held: int
    dropped_rows: int
    final: bool = False
    sample_period_s: float = math.nan
    trend: str = ""

    def status_line(self) -> str:
        """``t 1.234 s  command +0.1 rad  load angle +0.09 rad  elapsed 0:00:01  ETA 0:00:04  samples
        1234/5000  lost 0  held 0`` (elapsed and ETA in the rig's sample time, when the period is known)."""
        if self.time_s.size:
            now = (f"t {self.time_s[-1]:.3f} s  command {self.command_rad[-1]:+.4f} rad  "
                   f"load angle {self.angle_rad[-1]:+.4f} rad")
        else:
            now = "t -  (no sample yet)"
        shown = f"  (view: {self.dropped_rows} rows not shown)" if self.dropped_rows else ""
        timing = ""
        if math.isfinite(self.sample_period_s):
            left = max(self.total_samples - self.samples, 0) * self.sample_period_s
            timing = (f"  elapsed {_clock_time(self.samples * self.sample_period_s)}  "
                      f"ETA {_clock_time(left)}")
        return (f"{now}{timing}  samples {self.samples}/{self.total_samples}  lost {self.lost}  held {self.held}"
                f"{shown}")


def _clock_time(seconds: float) -> str:
    """``h:mm:ss``."""
    whole = int(round(seconds))
    return f"{whole // 3600}:{whole // 60 % 60:02d}:{whole % 60:02d}"


class Renderer(Protocol):
    """Draws frames; ``draw`` may take as long as it likes (the view skips the frames that come due meanwhile)."""

    min_interval_s: float

    def draw(self, frame: LiveFrame) -> None: ...

    def close(self) -> None: ...


class LiveView:
    """A thread that turns what :class:`LiveFeed` holds into frames for ``renderer``, at most every
    ``frame_interval_s`` (or the renderer's :attr:`~Renderer.min_interval_s`), until :meth:`stop`, which
    draws the final frame. Use :meth:`observe` to put it on a sink."""

    def __init__(self, renderer: Renderer, total_samples: int, sample_period_s: float, *,
                 capacity: int | None = None, frame_interval_s: float = FRAME_INTERVAL_S,
                 window_s: float = WINDOW_S, trend: LiveTrend | None = None) -> None:
        self.renderer = renderer
        self.feed = LiveFeed(LIVE_BUFFER_ROWS if capacity is None else capacity)
        self.total_samples = int(total_samples)
        self.sample_period_s = float(sample_period_s)
        self.frame_interval_s = max(frame_interval_s, getattr(renderer, "min_interval_s", 0.0))
        self._window_rows = max(2, int(math.ceil(window_s / sample_period_s)))
        self._window = np.zeros((0, 3))  # time, command, angle of the rows shown
        self.trend = trend
        self.frames_drawn = 0
        self.frames_skipped = 0
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="rig-live-view", daemon=True)
        self.error: BaseException | None = None

    def observe(self, sink: Any) -> ObservedSink:
        return ObservedSink(sink, self.feed)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 30.0) -> None:
        """Draw the final frame and end the thread (a renderer stuck longer than ``timeout_s`` is left)."""
        self._stopping.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def _loop(self) -> None:
        try:
            due = time.monotonic()
            while not self._stopping.wait(max(0.0, due - time.monotonic())):
                self._draw(final=False)
                now = time.monotonic()
                due += self.frame_interval_s
                if now > due:  # the renderer took longer than the interval: the frames due meanwhile are skipped
                    self.frames_skipped += int((now - due) // self.frame_interval_s) + 1
                    due = now + self.frame_interval_s
            self._draw(final=True)
        except Exception as err:  # the view failed: the capture goes on without it; the command says why
            self.error = err

    def _draw(self, final: bool) -> None:
        # only the new rows go through Python objects; the window is joined as arrays (a copy, no loop), so
        # the view holds the interpreter lock for microseconds at a time, not for a whole window
        new = np.array(self.feed.take(), dtype=float).reshape(-1, 4)
        self._window = rows = np.concatenate([self._window, new[:, :3]])[-self._window_rows:]
        trend = ""
        if self.trend is not None:
            self.trend.add(new[:, 0], new[:, 1], new[:, 2], (new[:, 3].astype(np.int64) & _UNUSABLE) == 0)
            # the final frame (the capture has ended) waits for the windows being bounded
            trend = trend_text(self.trend.finish() if final else self.trend.current())
        feed = self.feed
        self.renderer.draw(LiveFrame(rows[:, 0], rows[:, 1], rows[:, 2], samples=feed.offered,
                                     total_samples=self.total_samples, lost=feed.lost, held=feed.held,
                                     dropped_rows=feed.dropped, final=final, sample_period_s=self.sample_period_s,
                                     trend=trend))
        self.frames_drawn += 1

    def summary_line(self) -> str:
        """One line for the command to print after the run."""
        text = (f"live view: {self.frames_drawn} frames drawn, {self.frames_skipped} skipped while drawing, "
                f"{self.feed.dropped} of {self.feed.offered} rows not shown (the log has every sample)")
        if self.error is not None:
            text += f"; the view stopped: {self.error}"
        if self.trend is not None and self.trend.error is not None:
            text += f"; the trend stopped: {type(self.trend.error).__name__}: {self.trend.error}"
        return text


def display_available(environ: Any = None) -> bool:
    """A matplotlib window can be shown: ``MPLBACKEND`` is not a non-interactive backend, and on Linux and
    other X11/Wayland systems ``DISPLAY`` or ``WAYLAND_DISPLAY`` is set."""
    environ = os.environ if environ is None else environ
    backend = environ.get("MPLBACKEND", "").strip().lower()
    if backend in NON_INTERACTIVE_BACKENDS:
        return False
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"))


def choose_renderer(stream: TextIO) -> Renderer:
    """A :class:`WindowRenderer` when a display is there and matplotlib opens a window on it, else a
    :class:`TerminalRenderer` on ``stream`` (which says why there is no window when one was tried)."""
    if not display_available():
        return TerminalRenderer(stream)
    try:
        return WindowRenderer.start()
    except WindowUnavailable as err:
        return TerminalRenderer(stream, note=f"no window: {err}")


@contextlib.contextmanager
def open_live_view(total_samples: int, sample_period_s: float, stream: TextIO,
                   renderer: Renderer | None = None, trend: LiveTrend | None = None) -> Iterator[LiveView]:
    """A started :class:`LiveView` on ``renderer`` (default :func:`choose_renderer`), with ``trend`` if given;
    stopped, its renderer and trend closed on exit."""
    renderer = choose_renderer(stream) if renderer is None else renderer
    view = LiveView(renderer, total_samples, sample_period_s, trend=trend)
    try:
        view.start()
        yield view
    finally:
        try:
            view.stop()
        finally:
            renderer.close()
            if trend is not None:
                trend.close()


class TerminalRenderer:
    """A text plot of the last seconds on ``stream``: the command (``.``) and the load angle (``*``, ``#``
    where both fall), the range on the right, and the status line (:meth:`LiveFrame.status_line`). On a
    terminal each frame replaces the previous one in place (ANSI cursor moves); into a file or pipe a
    frame is written at most every 2 s."""

    def __init__(self, stream: TextIO, width: int = 72, height: int = 12, note: str = "") -> None:
        self.stream = stream
        self.note = note
        self.width, self.height = width, height
        self.tty = bool(getattr(stream, "isatty", lambda: False)())
        self.min_interval_s = FRAME_INTERVAL_S if self.tty else 2.0
        self._lines_shown = 0

    def render(self, frame: LiveFrame) -> list[str]:
        """The lines of one frame."""
        grid = [[" "] * self.width for _ in range(self.height)]
        values = np.concatenate([frame.command_rad, frame.angle_rad])
        values = values[np.isfinite(values)]
        low, high = (float(values.min()), float(values.max())) if values.size else (-1.0, 1.0)
        if high - low < 1e-9:
            low, high = low - 0.5, high + 0.5
        if frame.time_s.size:
            column = np.minimum((np.arange(frame.time_s.size) * self.width) // frame.time_s.size, self.width - 1)
            for signal, mark in ((frame.command_rad, "."), (frame.angle_rad, "*")):
                finite = np.isfinite(signal)
                rows = np.round((high - signal[finite]) / (high - low) * (self.height - 1)).astype(int)
                for cell in np.unique(rows * self.width + column[finite]).tolist():  # each cell once
                    y, x = divmod(cell, self.width)
                    grid[y][x] = "#" if grid[y][x] not in (" ", mark) else mark
        border = "+" + "-" * self.width + "+"
        lines = [f"{border}  {high:+.4g} rad"]
        lines += ["|" + "".join(row) + "|" for row in grid]
        lines.append(f"{border}  {low:+.4g} rad")
        span = f"{frame.time_s[0]:.2f} .. {frame.time_s[-1]:.2f} s" if frame.time_s.size else "no samples yet"
        lines.append(f" . command   * load angle   # both   {span}")
        lines.append(frame.status_line())
        if frame.trend:
            lines.append(frame.trend)
        if self.note:
            lines.append(self.note)
        return lines

    def draw(self, frame: LiveFrame) -> None:
        lines = self.render(frame)
        if self.tty and self._lines_shown:
            self.stream.write(f"\x1b[{self._lines_shown}F")  # back to the first line of the last frame
        self.stream.write("".join(f"{line}\x1b[K\n" if self.tty else f"{line}\n" for line in lines))
        self.stream.flush()
        self._lines_shown = len(lines)

    def close(self) -> None:
        pass


class WindowUnavailable(Exception):
    """No matplotlib window could be opened; the message says why."""


WINDOW_POINTS = 2000
"""Points per curve sent to the window at most (a frame of 5 s at 1 kHz is thinned to this)."""


class WindowRenderer:
    """A matplotlib figure in a process of its own; a frame is sent only when the window has drawn the last
    one (else it is skipped), so a slow or frozen window never blocks the view, let alone the capture."""

    min_interval_s = FRAME_INTERVAL_S

    def __init__(self, process: Any, connection: Any, backend: str) -> None:
        self._process = process
        self._connection = connection
        self.backend = backend
        self._ready = True  # the window has drawn what it was sent
        self._closed = False  # the user closed the window
        self.frames_sent = 0
        self.frames_shown = 0

    @classmethod
    def start(cls, *, require_window: bool = True, timeout_s: float = 30.0) -> WindowRenderer:
        """The window process, once it has opened a figure. Raises :class:`WindowUnavailable` when it could
        not open one, did not answer in ``timeout_s``, or, with ``require_window``, opened no window
        (matplotlib fell back to a non-interactive backend: no display server answering, or no GUI toolkit). Without ``require_window`` the figure may be drawn off screen (tests)."""
        import multiprocessing

        context = multiprocessing.get_context("spawn")  # a fresh interpreter: no forked threads or locks
        ours, theirs = context.Pipe()
        process = context.Process(target=_window_process, args=(theirs,), name="rig-live-window", daemon=True)
        process.start()
        theirs.close()
        try:
            if not ours.poll(timeout_s):
                raise WindowUnavailable(f"the window's process did not start within {timeout_s:g} s")
            try:
                kind, detail = ours.recv()
            except EOFError:
                raise WindowUnavailable(f"the window's process ended (exit code {process.exitcode})") from None
            if kind != "ready":
                raise WindowUnavailable(detail)
            if require_window and detail.lower() in NON_INTERACTIVE_BACKENDS:
                raise WindowUnavailable(
                    f"matplotlib chose its non-interactive backend {detail}: no display server answers at "
                    f"{os.environ.get('DISPLAY') or os.environ.get('WAYLAND_DISPLAY') or 'DISPLAY'}, or no GUI "
                    "toolkit (tkinter, PyQt) is installed")
        except WindowUnavailable:
            with contextlib.suppress(OSError):
                ours.send(None)
            process.join(5)
            if process.is_alive():
                process.terminate()
                process.join(5)
            ours.close()
            raise
        return cls(process, ours, detail)

    def draw(self, frame: LiveFrame) -> None:
        # the final frame waits (a little) for the window to be ready, and for it to be drawn
        self._collect(wait_s=5.0 if frame.final else 0.0)
        if not self._ready:
            return
        step = max(1, frame.time_s.size // WINDOW_POINTS)
        thinned = {name: getattr(frame, name)[::step] for name in ("time_s", "command_rad", "angle_rad")}
        status = frame.status_line() + (f"\n{frame.trend}" if frame.trend else "")
        self._connection.send({**thinned, "status": status, "final": frame.final})
        self._ready = False
        self.frames_sent += 1
        if frame.final:
            self._collect(wait_s=5.0)

    def _collect(self, wait_s: float) -> None:
        """Read the window's answers; with ``wait_s``, wait that long at most for it to be ready."""
        deadline = time.monotonic() + wait_s
        while not self._closed and self._connection.poll(max(0.0, deadline - time.monotonic()) if not self._ready
                                                          else 0.0):
            message = self._connection.recv()
            if message == "closed":  # the user closed the window: the run goes on without a view
                self._closed, self._ready = True, False
                return
            self.frames_shown = message
            self._ready = True

    def close(self) -> None:
        with contextlib.suppress(OSError, BrokenPipeError):
            self._connection.send(None)
        self._process.join(5)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(5)
        self._connection.close()


def _window_process(connection: Any) -> None:
    """In the window's process: a figure with the command and the load angle of the last seconds, the
    counters in its title; answers "ready" with its backend, then each frame with the number drawn."""
    import signal
    import warnings

    # a Ctrl-C at the terminal reaches this process too: the run reports it, and then closes the window
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    warnings.filterwarnings("ignore", message=".*non-interactive.*")  # drawn off screen: nothing to show
    try:
        import matplotlib.pyplot as plt

        figure, axes = plt.subplots(figsize=(9, 4.5), num="rig run --live")
        (command_line,) = axes.plot([], [], label="command", linewidth=1.0)
        (angle_line,) = axes.plot([], [], label="load angle", linewidth=1.0)
        axes.set_xlabel("time [s]")
        axes.set_ylabel("angle [rad]")
        axes.legend(loc="upper left")
        title = axes.set_title("waiting for the first sample", fontsize=9)
        figure.tight_layout()
        plt.show(block=False)
    except Exception as err:  # e.g. TclError: couldn't connect to display
        connection.send(("failed", f"{type(err).__name__}: {err}".splitlines()[0]))
        return
    connection.send(("ready", plt.get_backend()))
    shown = 0
    while True:
        if not plt.fignum_exists(figure.number):
            connection.send("closed")
            return
        if connection.poll(0.02):
            frame = connection.recv()
            if frame is None:
                plt.close(figure)
                return
            command_line.set_data(frame["time_s"], frame["command_rad"])
            angle_line.set_data(frame["time_s"], frame["angle_rad"])
            title.set_text(frame["status"])
            axes.relim()
            axes.autoscale_view()
            figure.canvas.draw_idle()
            shown += 1
            connection.send(shown)
        plt.pause(0.03)
