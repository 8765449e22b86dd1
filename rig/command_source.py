"""Commands produced as they are sent: a run of hours holds a few thousand samples of its command at a time.

A :class:`CommandSource` yields the drive position targets of a run in chunks (:data:`CHUNK_SAMPLES` samples
each), from sample 0 every time :meth:`CommandSource.chunks` is called, the same values each time: a source
is a recipe (an array, one cycle of an excitation and how to repeat it), not a stream of state. The runner
(:func:`rig.runner.run_experiment`) checks each chunk against the software limits before any of its samples
is sent (:class:`rig.runner.CheckedCommand`); an array passed to it is wrapped as :class:`ArrayCommand`.

* :class:`ArrayCommand`: an array in memory, cut into chunks.
* :class:`CyclicCommand`: one cycle repeated sample by sample to ``num_samples`` (``numpy.resize``), or
  forever (``num_samples`` None).
* :class:`FilteredRepeatCommand`: a reference repeated and then low-pass filtered, the filter's state carried
  from chunk to chunk, so the command is the filter of the whole repeated reference
  (:meth:`rig.experiment_config.Excitation.repeated`, a filtered staircase).
* :class:`CsvCommandFile`: the ``command_rad`` column of a CSV file, read from disk as it is sent;
  :class:`RepeatedSource` repeats such a finite source (``rig run --duration``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.validation import InvalidInputError, as_signal

__all__ = ["CHUNK_SAMPLES", "CSV_CHUNK_ROWS", "ArrayCommand", "CommandSource", "CsvCommandFile", "CyclicCommand",
           "FilteredRepeatCommand", "RepeatedSource", "as_command_source"]

CHUNK_SAMPLES = 4096
"""Samples a source yields at a time: 4 s at 1 kHz, 32 KiB of floats; checking one against the limits takes a
few milliseconds of Python, spread by the runner over the samples of the chunk before it."""


class CommandSource(ABC):
    """Drive position targets (rad), one per sample, yielded in chunks as a run sends them.

    Attributes
    ----------
    num_samples
        The samples of the command, or None when it is open-ended (it ends where :meth:`chunks` ends).
    """

    num_samples: int | None

    @abstractmethod
    def chunks(self) -> Iterator[NDArray[np.float64]]:
        """The command from sample 0, as 1-D float arrays of at most :data:`CHUNK_SAMPLES` samples (none
        empty); every call yields the same values."""

    def head(self, count: int) -> NDArray[np.float64]:
        """The first ``count`` samples (fewer if the command is shorter)."""
        parts, have = [], 0
        if count > 0:
            for chunk in self.chunks():
                parts.append(chunk[:count - have])
                have += parts[-1].size
                if have >= count:
                    break
        return np.concatenate(parts) if parts else np.zeros(0)

    def to_array(self) -> NDArray[np.float64]:
        """The whole command in memory (a finite source only: for tests and short commands)."""
        if self.num_samples is None:
            raise InvalidInputError("the command is open-ended: it has no whole array")
        return self.head(self.num_samples)


class ArrayCommand(CommandSource):
    """A command held in memory (finite, 1-D), yielded in chunks."""

    def __init__(self, command_rad: ArrayLike, chunk_samples: int = CHUNK_SAMPLES) -> None:
        self.command_rad = as_signal("command_rad", command_rad)
        self.num_samples = int(self.command_rad.size)
        self.chunk_samples = _chunk_size(chunk_samples)

    def chunks(self) -> Iterator[NDArray[np.float64]]:
        for start in range(0, self.num_samples, self.chunk_samples):
            yield self.command_rad[start:start + self.chunk_samples]


class CyclicCommand(CommandSource):
    """``cycle_rad`` repeated sample by sample: ``numpy.resize(cycle_rad, num_samples)``, produced a chunk at a
    time; ``num_samples`` None repeats it until the run is stopped."""

    def __init__(self, cycle_rad: ArrayLike, num_samples: int | None, chunk_samples: int = CHUNK_SAMPLES) -> None:
        self.cycle_rad = as_signal("cycle_rad", cycle_rad)
        self.num_samples = None if num_samples is None else _count("num_samples", num_samples)
        self.chunk_samples = _chunk_size(chunk_samples)

    def chunks(self) -> Iterator[NDArray[np.float64]]:
        cycle, size = self.cycle_rad, self.cycle_rad.size
        start = 0
        while self.num_samples is None or start < self.num_samples:
            count = self.chunk_samples if self.num_samples is None else min(self.chunk_samples,
                                                                            self.num_samples - start)
            yield cycle[(start + np.arange(count)) % size]
            start += count


class FilteredRepeatCommand(CommandSource):
    """``reference_rad`` repeated sample by sample, filtered from rest by F(z)^n, F(z) = (1 - a)/(z - a)
    (:func:`identify.excitation_design.lowpass_filter`), a chunk at a time: each of the n first-order stages
    carries its state from one chunk to the next, so the samples are those of the filter run over the whole
    repeated reference at once (the same arithmetic, in the same order)."""

    def __init__(self, reference_rad: ArrayLike, filter_pole: float, filter_order: int, num_samples: int | None,
                 chunk_samples: int = CHUNK_SAMPLES) -> None:
        self.reference = CyclicCommand(reference_rad, num_samples, chunk_samples)
        self.filter_pole = float(filter_pole)
        if not 0.0 <= self.filter_pole < 1.0:
            raise InvalidInputError(f"filter_pole: expected 0 <= a < 1, got {filter_pole!r}")
        self.filter_order = _count("filter_order", filter_order)
        self.num_samples = self.reference.num_samples

    def chunks(self) -> Iterator[NDArray[np.float64]]:
        from scipy import signal as scipy_signal

        pole = self.filter_pole
        numerator, denominator = [0.0, 1.0 - pole], [1.0, -pole]
        states = [np.zeros(1) for _ in range(self.filter_order)]
        for chunk in self.reference.chunks():
            u = chunk
            for stage in range(self.filter_order):
                u, states[stage] = scipy_signal.lfilter(numerator, denominator, u, zi=states[stage])
            yield np.asarray(u, dtype=float)


def as_command_source(command: CommandSource | ArrayLike) -> CommandSource:
    """``command`` itself if it is a :class:`CommandSource`, else the array wrapped as an :class:`ArrayCommand`."""
    return command if isinstance(command, CommandSource) else ArrayCommand(command)


def _count(name: str, value: int) -> int:
    if isinstance(value, bool) or int(value) != value or value < 1:
        raise InvalidInputError(f"{name}: expected an integer >= 1, got {value!r}")
    return int(value)


def _chunk_size(value: int) -> int:
    return _count("chunk_samples", value)


CSV_CHUNK_ROWS = 64
"""Rows of a command file parsed at a time: parsing costs a few microseconds a row (7 us on a loaded 2-core
host), and a chunk is parsed in one go, so small chunks keep a host-paced loop's cycle from waiting for
4096 of them (30 ms)."""


class CsvCommandFile(CommandSource):
    """The ``command_rad`` column of a CSV file (a header row, ``#`` comment lines, optionally a ``time_s``
    column that must step by ``sample_period_s``), read from disk a chunk at a time as the run sends it.

    Opening it counts the data rows (a pass over the bytes, nothing kept) and checks the header; the values
    are parsed as they are read, with the rules of :func:`rig.signal_files.read_signal_table` (finite numbers,
    one value per column): a bad value is a :class:`~rig.protocols.errors.LogFileError` naming the line, raised
    when its chunk is read (before the run for the first chunk; during it, the run ends with the controlled
    stop before any sample of that chunk is sent).
    """

    def __init__(self, path: str | Path, sample_period_s: float, chunk_samples: int = CSV_CHUNK_ROWS) -> None:
        from rig.protocols.errors import LogFileError
        from rig.signal_files import check_input_file

        self.path = check_input_file(path)
        self.sample_period_s = float(sample_period_s)
        self.chunk_samples = _chunk_size(chunk_samples)
        rows = 0
        header: list[str] | None = None
        for _number, row in self._rows():
            if header is None:
                header = [name.strip() for name in row]
            else:
                rows += 1
        if header is None:
            raise LogFileError(f"{self.path}: the file is empty; expected a header row with columns command_rad")
        if "command_rad" not in header:
            raise LogFileError(f"{self.path}: missing column(s) command_rad; the header has {', '.join(header)[:120]}")
        for name in ("command_rad", "time_s"):
            if header.count(name) > 1:
                raise LogFileError(f"{self.path}: column {name} appears {header.count(name)} times; which one is "
                                   "meant is unclear: rename or remove the others")
        if rows == 0:
            raise LogFileError(f"{self.path}: the file has a header but no data rows")
        self.columns = header
        self.num_samples = rows

    def _rows(self) -> Iterator[tuple[int, list[str]]]:
        """``(line number, fields)`` of the header and data rows (comments and blank lines skipped)."""
        import csv

        from rig.protocols.errors import LogFileError
        from rig.signal_files import MAX_LINE_BYTES

        with self.path.open("r", encoding="utf-8-sig", newline="") as handle:
            lines = ((number, text) for number, text in enumerate(iter(lambda: handle.readline(MAX_LINE_BYTES + 1),
                                                                       ""), start=1))
            numbered = _bounded_lines(self.path, lines, MAX_LINE_BYTES)
            try:
                for number, row in numbered:
                    if row and not row[0].lstrip().startswith("#"):
                        yield number, row
            except csv.Error as err:
                raise LogFileError(f"{self.path}: not a readable CSV: {err}") from None

    def chunks(self) -> Iterator[NDArray[np.float64]]:
        from rig.protocols.errors import LogFileError

        names = self.columns
        command_column = names.index("command_rad")
        time_column = names.index("time_s") if "time_s" in names else None
        values: list[float] = []
        previous_time: float | None = None
        row_number = 0  # data rows before this one
        rows = self._rows()
        next(rows)  # the header (checked on opening)
        for line, row in rows:
            if len(row) != len(names):
                raise LogFileError(f"{self.path}: line {line}: expected {len(names)} values, got {len(row)}")
            value = _finite(self.path, line, "command_rad", row[command_column])
            if time_column is not None:
                time_s = _finite(self.path, line, "time_s", row[time_column])
                if previous_time is not None and not math.isclose(time_s - previous_time, self.sample_period_s,
                                                                  rel_tol=1e-6, abs_tol=1e-12):
                    raise LogFileError(f"{self.path}: line {line}: time_s steps by {time_s - previous_time:g} s "
                                       f"after row {row_number}, but the rig samples every "
                                       f"{self.sample_period_s:g} s")
                previous_time = time_s
            values.append(value)
            row_number += 1
            if len(values) == self.chunk_samples:
                yield np.array(values)
                values = []
        if values:
            yield np.array(values)


class RepeatedSource(CommandSource):
    """A finite ``source`` cut, or repeated from its start, to ``num_samples`` (None: until the run stops)."""

    def __init__(self, source: CommandSource, num_samples: int | None) -> None:
        if source.num_samples is None:
            raise InvalidInputError("source: an open-ended command cannot be repeated")
        self.source = source
        self.num_samples = None if num_samples is None else _count("num_samples", num_samples)

    def chunks(self) -> Iterator[NDArray[np.float64]]:
        left = self.num_samples
        while left is None or left > 0:
            for chunk in self.source.chunks():
                if left is not None:
                    chunk = chunk[:left]
                    left -= chunk.size
                if chunk.size:
                    yield chunk
                if left is not None and left <= 0:
                    return


def _bounded_lines(path: Path, lines: Iterator[tuple[int, str]], max_bytes: int) -> Iterator[tuple[int, list[str]]]:
    """csv rows of ``lines``, refusing a NUL byte or a line longer than ``max_bytes`` (not a CSV file)."""
    import csv

    from rig.protocols.errors import LogFileError

    def checked() -> Iterator[str]:
        for number, text in lines:
            if "\0" in text:
                raise LogFileError(f"{path}: line {number}: not a CSV file (NUL bytes)")
            if len(text) > max_bytes and not text.endswith("\n"):
                raise LogFileError(f"{path}: line {number} is longer than {max_bytes} bytes: not a CSV file")
            numbers.append(number)
            yield text

    numbers: list[int] = []
    for row in csv.reader(checked()):
        yield numbers[-1], row
        numbers.clear()


def _finite(path: Path, line: int, column: str, text: str) -> float:
    from rig.protocols.errors import LogFileError

    try:
        value = float(text)
    except ValueError:
        raise LogFileError(f"{path}: line {line}, column {column}: {text.strip()[:40]!r} is not a number") from None
    if not math.isfinite(value):
        raise LogFileError(f"{path}: line {line}, column {column}: {text.strip()} is not a finite number")
    return value
