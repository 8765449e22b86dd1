"""A sink that passes what it is given on to another (:class:`rig.runner.SampleSink`), for the wrappers that look
at each row on its way to the log: the progress bar's flag counters, the live view's feed. Free of numpy so that
the command line imports it at once."""

from __future__ import annotations

from typing import Any

__all__ = ["ForwardingSink"]


class ForwardingSink:
    """A :class:`rig.runner.SampleSink` that passes every row, the summary and the close on to ``sink``; a
    subclass looks at each row in :meth:`append` after calling this one (the log first)."""

    def __init__(self, sink: Any) -> None:
        self._sink = sink

    def append(self, time_s: float, command_rad: float, angle_rad: float, encoder_counts: int | None = None,
               flags: int = 0, **columns: float) -> None:
        self._sink.append(time_s, command_rad, angle_rad, encoder_counts, flags, **columns)

    def write_summary(self, summary: Any) -> None:
        write_summary = getattr(self._sink, "write_summary", None)
        if write_summary is not None:
            write_summary(summary)

    def close(self) -> None:
        self._sink.close()
