"""Experiment log files: self-describing, readable without this package, and crash-safe.

Format ``rig-log v1`` (a CSV file with a commented header)::

    # rig-log v1
    # metadata {"sample_period_s": 0.001, "source": "cerone2009", ...}      <- one line of JSON
    # units time_s=s command_rad=rad angle_rad=rad encoder_counts=counts flags=bits(1 LOST,2 LATE,...)
    time_s,command_rad,angle_rad,encoder_counts,flags
    # start {"acquisition_start_utc": "2025-03-04T09:15:02.123456Z"}          <- with the first sample of a run
    0.0,0.0,0.0,0,0
    0.001,0.25,nan,,1                                                        <- a LOST sample
    # summary {"frame_errors": 0, "stop": "quick stop sent, ..."}              <- at the end, if the run ended

Format ``rig-log v2`` is v1 with one more column, ``drive_torque``: the torque the drive reported at each sample,
in the unit the units line names (a CiA 402 drive: its torque actual value 0x6077, in per mille of the motor's
rated torque 0x6076; empty where not measured). A log is written as v2 only when its run's link reports the drive's
torque (:attr:`rig.transports.base.Transport.drive_torque_unit`), so a log without it stays readable by v1 readers.

* pandas: ``pandas.read_csv(path, comment="#")``; numpy:
  ``numpy.genfromtxt(path, delimiter=",", names=True, skip_header=3)`` (the header is always 3 comment
  lines); MATLAB:
  ``readtable(path, "CommentStyle", "#")``. The metadata line is plain JSON after ``"# metadata "``.
* Samples are appended one line each and flushed to the OS every ``flush_every`` samples (1 by default) or
  after ``flush_interval_s``; a process killed at any instant leaves every flushed line readable, and a
  torn last line is dropped on reading with a warning. ``close()`` flushes and fsyncs.
* Floats are written with ``repr`` (shortest exact round trip).
* When the acquisition started (the host's UTC clock when the first sample of a run reached the log: after
  sample 0's instant by as much as the runner waits for its answer, up to the lead on a device-clocked wire,
  100 ms by default on CANopen; a trace's own time stamps give the instant itself, ``rig import``) is only
  known once it has; a writer with ``stamp_start``
  writes it with that sample as one comment line ``# start {"acquisition_start_utc": ...}`` (ISO 8601, UTC),
  and :func:`read_log` puts it in ``metadata.acquisition_start_utc``. A log written before this line existed
  reads with the start None (unknown); a record whose metadata already holds the start (``write_log`` of a
  record read back) keeps it in the metadata line.
* What is only known at the end of a run (the damaged frames the transport discarded, what the controlled
  stop did, who owned the sample clock and how the run kept it: ``sample_clock`` ``"device"`` with
  ``min_lead_s``, or ``"host"`` with ``send_lateness_p50_s``, ``_p99_s``, ``_max_s``; see
  :class:`rig.runner.RunSummary`) follows the last sample as one comment line ``# summary {JSON}``
  (:meth:`LogWriter.write_summary`); :func:`read_log` puts it in the metadata's ``extra["summary"]``. A
  log of a killed run has no summary line; comment-aware readers (pandas, numpy, MATLAB above) skip it.

:func:`read_experiment_data` also accepts plain CSV files with columns ``t,u,y`` (seconds, radians) made by
other tools, and ASAM MDF4 (``.mf4``/``.mdf``) and MATLAB (``.mat``) files, a rig log exported by ``rig export``
or channels ``t,u,y`` of another tool (:mod:`rig.measurement_files`, which dispatches on the suffix).
"""

from __future__ import annotations

import errno
import json
import math
import os
import re
import stat
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, TextIO

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag, now_utc
from identify.validation import InvalidInputError
from rig.protocols.errors import LogFileError
from rig.signal_files import check_input_file

__all__ = ["COLUMNS", "FORMAT_LINE", "TORQUE_COLUMN", "TORQUE_FORMAT_LINE", "LogWriteError", "LogWriter", "SetAside",
           "check_output_varies", "count_samples", "is_rig_log", "read_experiment_data", "read_log",
           "read_usable_input_output", "unusable_as_missing", "write_log"]

FORMAT_LINE = "# rig-log v1"
TORQUE_FORMAT_LINE = "# rig-log v2"
COLUMNS = ("time_s", "command_rad", "angle_rad", "encoder_counts", "flags")
TORQUE_COLUMN = "drive_torque"
_FORMATS = {FORMAT_LINE: COLUMNS, TORQUE_FORMAT_LINE: (*COLUMNS, TORQUE_COLUMN)}
"""The columns of each format, by its first line."""
_METADATA_PREFIX = "# metadata "
_SUMMARY_PREFIX = "# summary "
_START_PREFIX = "# start "
_UNITS_LINE = ("# units time_s=s command_rad=rad angle_rad=rad encoder_counts=counts flags=bits("
               + ",".join(f"{int(flag)} {flag.name}" for flag in SampleFlag if flag.value) + ")")


class LogWriteError(LogFileError):
    """The log could not be written (path not writable, directory missing, disk full, file size limit).

    The message names the path, the OS's reason and, during a run, how many samples were flushed and so
    are kept in the file."""


_ADVICE = {
    errno.ENOSPC: "the disk is full: free space or write the log to another disk",
    errno.EDQUOT: "the disk quota is used up: free space or write the log to another disk",
    errno.EFBIG: "the file size limit was reached (ulimit -f): raise it or write shorter logs",
    errno.EACCES: "no permission to write there: choose another path or change its permissions",
    errno.EPERM: "no permission to write there: choose another path or change its permissions",
    errno.EROFS: "the file system is read-only: choose another path",
    errno.ENOENT: "the directory does not exist: create it or choose another path",
    errno.EISDIR: "the path is a directory: give a file name",
    errno.ENOTDIR: "a part of the path is not a directory: choose another path",
}


def _os_reason(err: OSError) -> str:
    """'No space left on device (ENOSPC); the disk is full: ...' for an OSError from open/write/flush."""
    name = errno.errorcode.get(err.errno, "") if err.errno is not None else ""
    reason = err.strerror or str(err)
    advice = _ADVICE.get(err.errno) if err.errno is not None else None
    return f"{reason}{f' ({name})' if name else ''}" + (f"; {advice}" if advice else "")


def _metadata_dict(metadata: ExperimentMetadata | Mapping[str, Any]) -> dict[str, Any]:
    if isinstance(metadata, ExperimentMetadata):
        return metadata.to_dict()
    return ExperimentMetadata.from_dict(metadata).to_dict()


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (set, frozenset)):
        return sorted(value)
    return str(value)


class LogWriter:
    """Append samples to a ``rig-log v1`` file as they come.

    Parameters
    ----------
    path
        The file to create (an existing file is replaced).
    metadata
        :class:`~identify.experiment_record.ExperimentMetadata` (or a dict of its fields).
    flush_every
        Flush to the OS after this many samples (1: every sample).
    flush_interval_s
        Also flush when this much time has passed since the last flush (None: only by count).
    fsync
        Also fsync at every flush (survives power loss, costs a disk write per flush); ``close`` always
        fsyncs.
    claimed
        The :class:`rig.output_paths.ClaimedOutput` of ``path`` (claimed before a run starts, so that no other
        run writes it); None opens ``path`` itself, replacing a file there.
    stamp_start
        Record the host's UTC clock at the first sample as the acquisition start (a run; module docstring),
        unless the metadata holds one already.

    Examples
    --------
    >>> with LogWriter(path, metadata) as log:          # doctest: +SKIP
    ...     log.append(0.0, 0.1, 0.0, encoder_counts=0)
    """

    def __init__(self, path: str | Path, metadata: ExperimentMetadata | Mapping[str, Any], *,
                 flush_every: int = 1, flush_interval_s: float | None = None, fsync: bool = False,
                 claimed: Any = None, stamp_start: bool = False, drive_torque_unit: str | None = None) -> None:
        self.path = Path(path)
        if isinstance(flush_every, bool) or not isinstance(flush_every, int) or flush_every < 1:
            raise InvalidInputError(f"flush_every: expected an integer >= 1, got {flush_every!r}")
        if flush_interval_s is not None and not (math.isfinite(flush_interval_s) and flush_interval_s > 0):
            raise InvalidInputError(f"flush_interval_s: expected a number > 0 or None, got {flush_interval_s!r}")
        values = _metadata_dict(metadata)
        self._stamp_start = stamp_start and values.get("acquisition_start_utc") is None
        self.acquisition_start_utc: str | None = values.get("acquisition_start_utc")
        try:
            header = json.dumps(values, allow_nan=False, default=_json_default)
        except ValueError as err:
            raise InvalidInputError(
                f"metadata: {err} (write an infinite bound or a NaN as a string such as \"inf\")"
            ) from err
        self.flush_every = flush_every
        self.flush_interval_s = flush_interval_s
        self.fsync = fsync
        self.drive_torque_unit = drive_torque_unit
        first, units, columns = FORMAT_LINE, _UNITS_LINE, COLUMNS
        if drive_torque_unit is not None:
            token = "_".join(str(drive_torque_unit).split())
            if not token or "=" in token:
                raise InvalidInputError(f"drive_torque_unit: expected a unit such as 'N_m', got {drive_torque_unit!r}")
            first, units = TORQUE_FORMAT_LINE, f"{_UNITS_LINE} {TORQUE_COLUMN}={token}"
            columns = _FORMATS[TORQUE_FORMAT_LINE]
        self.samples = 0
        self.flushed_samples = 0
        self._pending = 0
        self._last_time: float | None = None
        self._failure: str | None = None
        self._summary_written = False
        try:
            self._file: TextIO | None = (self.path.open("w", encoding="utf-8", newline="\n") if claimed is None
                                         else claimed.open_text())
        except OSError as err:
            if isinstance(err, FileNotFoundError) and not self.path.parent.is_dir():
                raise LogWriteError(f"{self.path}: cannot open the log for writing: the directory {self.path.parent} "
                                    "does not exist; create it or choose another path") from None
            raise LogWriteError(f"{self.path}: cannot open the log for writing: {_os_reason(err)}") from None
        try:  # written and fsynced at once: a full disk or a device that refuses writes shows up here, before a run
            self._file.write(f"{first}\n{_METADATA_PREFIX}{header}\n{units}\n{','.join(columns)}\n")
            self._flush(sync=True)
        except OSError as err:
            self._abandon()
            raise LogWriteError(f"{self.path}: cannot write the log's header: {_os_reason(err)}") from None

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()

    def _flush(self, sync: bool) -> None:
        assert self._file is not None
        self._file.flush()
        if sync:
            try:
                os.fsync(self._file.fileno())
            except OSError as err:
                if err.errno != errno.EINVAL:  # a pipe or character device cannot be fsynced; nothing to lose
                    raise
        self._last_flush = time.monotonic()
        self.flushed_samples = self.samples

    def _abandon(self) -> None:
        """Close the file after a failed write without flushing again (the OS refused the bytes)."""
        assert self._file is not None
        try:
            self._file.close()
        except OSError:
            pass  # the same failure, reported already; the descriptor is closed anyway
        self._file = None

    def _fail(self, err: OSError, doing: str) -> LogWriteError:
        """Remember a write failure (every later call reports it) and close the file."""
        self._failure = (f"{self.path}: cannot write the log ({doing}): {_os_reason(err)}; the "
                         f"{self.flushed_samples} samples flushed before are kept and readable")
        self._abandon()
        return LogWriteError(self._failure)

    def append(self, time_s: float, command_rad: float, angle_rad: float, encoder_counts: int | None = None,
               flags: int | SampleFlag = SampleFlag.OK, drive_torque: float | None = None) -> None:
        """Write one sample. A LOST sample may pass ``angle_rad=nan``; times must increase. ``drive_torque``
        (None or NaN: not measured) needs a log made with a ``drive_torque_unit``."""
        if self._file is None:
            raise LogWriteError(self._failure) if self._failure else LogFileError(f"{self.path}: the log is closed")
        if self._summary_written:
            raise LogFileError(f"{self.path}: the summary is written; no sample may follow it")
        time_value, command, angle, flag = float(time_s), float(command_rad), float(angle_rad), int(flags)
        if not math.isfinite(time_value) or (self._last_time is not None and time_value <= self._last_time):
            raise InvalidInputError(
                f"time_s: sample {self.samples} at {time_s!r} s does not follow {self._last_time!r} s; times must increase"
            )
        if not math.isfinite(command):
            raise InvalidInputError(f"command_rad: sample {self.samples} is {command_rad!r}")
        if not 0 <= flag <= 255:
            raise InvalidInputError(f"flags: sample {self.samples} has {flags!r}; expected SampleFlag bits")
        lost = bool(flag & SampleFlag.LOST)
        if lost:
            angle = math.nan
        elif not math.isfinite(angle):
            raise InvalidInputError(f"angle_rad: sample {self.samples} is {angle_rad!r}; flag it LOST instead")
        counts = "" if encoder_counts is None or lost else str(int(encoder_counts))
        line = f"{time_value!r},{command!r},{angle!r},{counts},{flag}"
        if self.drive_torque_unit is not None:
            torque = math.nan if drive_torque is None else float(drive_torque)
            if math.isinf(torque):
                raise InvalidInputError(f"drive_torque: sample {self.samples} is {drive_torque!r}")
            line += "," if math.isnan(torque) else f",{torque!r}"
        elif drive_torque is not None:
            raise InvalidInputError(f"drive_torque: {self.path} has no {TORQUE_COLUMN} column; make the LogWriter "
                                    "with the torque's drive_torque_unit (the transport's)")
        line += "\n"
        if self._stamp_start:
            self.acquisition_start_utc = now_utc()
            line = f"{_START_PREFIX}{json.dumps({'acquisition_start_utc': self.acquisition_start_utc})}\n{line}"
            self._stamp_start = False
        try:
            self._file.write(line)
        except OSError as err:  # a write that filled the buffer went to the OS and was refused
            raise self._fail(err, f"sample {self.samples}") from None
        self._last_time = time_value
        self.samples += 1
        self._pending += 1
        if self._pending >= self.flush_every or (
                self.flush_interval_s is not None and time.monotonic() - self._last_flush >= self.flush_interval_s):
            try:
                self._flush(sync=self.fsync)
            except OSError as err:
                raise self._fail(err, f"flushing samples {self.flushed_samples} to {self.samples - 1}") from None
            self._pending = 0

    def append_many(self, time_s: ArrayLike, command_rad: ArrayLike, angle_rad: ArrayLike,
                    encoder_counts: ArrayLike | None = None, flags: ArrayLike | None = None,
                    drive_torque: ArrayLike | None = None) -> None:
        """Write whole arrays (an offline simulation), one line per sample."""
        times = np.asarray(time_s, dtype=float)
        commands = np.asarray(command_rad, dtype=float)
        angles = np.asarray(angle_rad, dtype=float)
        counts = [None] * times.size if encoder_counts is None else np.asarray(encoder_counts).tolist()
        flag_values = [0] * times.size if flags is None else np.asarray(flags).tolist()
        torques = [None] * times.size if drive_torque is None else np.asarray(drive_torque, dtype=float).tolist()
        for row in zip(times.tolist(), commands.tolist(), angles.tolist(), counts, flag_values, torques):
            self.append(*row)

    def write_summary(self, summary: Mapping[str, Any]) -> None:
        """Write the run's summary (JSON-able values, e.g. ``{"frame_errors": 3}``) after the last sample;
        no sample may follow. Read back into ``metadata.extra["summary"]`` by :func:`read_log`. After a
        write failure it does nothing (the failure was raised already)."""
        if self._file is None and self._failure:
            return
        if self._file is None:
            raise LogWriteError(self._failure) if self._failure else LogFileError(f"{self.path}: the log is closed")
        line = json.dumps(dict(summary), allow_nan=False, default=_json_default)
        try:
            self._file.write(f"{_SUMMARY_PREFIX}{line}\n")
        except OSError as err:
            raise self._fail(err, "writing the summary") from None
        self._summary_written = True

    def close(self) -> None:
        """Flush, fsync and close (idempotent). After a write failure it only releases the file: the failure
        was raised already, and raising it again from a ``finally`` would hide what happened first."""
        if self._file is None:
            return
        try:
            self._flush(sync=True)
        except OSError as err:
            raise self._fail(err, f"flushing samples {self.flushed_samples} to {self.samples - 1} on close") from None
        self._file.close()
        self._file = None


def write_log(path: str | Path, record: ExperimentRecord) -> None:
    """Write a whole :class:`ExperimentRecord` as a log file (``rig-log v2`` with the drive's torque, if it has
    it, in the unit ``metadata.extra["drive_torque_unit"]`` names: "as_recorded" where it names none)."""
    unit = None if record.drive_torque is None else str(record.metadata.extra.get("drive_torque_unit", "as_recorded"))
    with LogWriter(path, record.metadata, flush_every=max(1, len(record)), drive_torque_unit=unit) as log:
        log.append_many(record.time_s, record.command_rad, record.angle_rad, record.encoder_counts, record.flags,
                        record.drive_torque)


def is_rig_log(path: Path) -> bool:
    """Whether ``path`` is a regular file starting with the ``# rig-log`` format line (after a UTF-8 BOM, if
    any); False if it cannot be read. Reads 16 bytes at most (``/dev/zero`` has no first line)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return False
        with open(path, "rb") as handle:
            first = handle.read(16)
    except OSError:
        return False
    return first.removeprefix(b"\xef\xbb\xbf").startswith(b"# rig-log")


def count_samples(path: str | Path) -> int | None:
    """Number of complete sample lines in a ``rig-log v1`` file, without parsing them (fast, for a message
    after an interrupted run); None when the file is missing or is not a rig log."""
    path = Path(path)
    if not is_rig_log(path):
        return None
    lines = 0
    try:
        with path.open("rb") as handle:
            tail = head = b""
            while chunk := handle.read(1 << 20):
                lines += chunk.count(b"\n")
                tail = (tail + chunk)[-4096:]
                head = head or chunk
    except OSError:
        return None
    if tail.endswith(b"\n") and tail[:-1].rsplit(b"\n", 1)[-1].startswith(_SUMMARY_PREFIX.encode()):
        lines -= 1
    if b"\n" + _START_PREFIX.encode() in head:
        lines -= 1
    return max(0, lines - 4)  # format, metadata, units and column lines


def read_log(path: str | Path) -> ExperimentRecord:
    """Read a ``rig-log v1`` or ``v2`` file; raises :class:`LogFileError` naming the file, line and problem. A v2
    log's torque column is the record's ``drive_torque`` (None where no sample has one), its unit
    ``metadata.extra["drive_torque_unit"]``."""
    path = check_input_file(path, "a rig log")
    raw = path.read_bytes()
    nul = raw.find(b"\0")
    if nul >= 0:
        raise LogFileError(f"{path}: not a CSV file (NUL bytes at byte {nul}); a crash can leave zeros at the end "
                           f"of a file: keep the bytes before {nul} (e.g. head -c {nul} {path.name} > fixed.csv)")
    try:
        text = raw.decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError as err:
        raise LogFileError(f"{path}: not a text file (byte {err.start} is not UTF-8); expected a rig-log v1 CSV") from None
    del raw
    lines = text.split("\n")
    if not text:
        raise LogFileError(f"{path}: the file is empty; expected a '{FORMAT_LINE}' log")
    first = lines[0].rstrip("\r")
    if not first.startswith("# rig-log"):
        raise LogFileError(
            f"{path}: line 1: expected '{FORMAT_LINE}', got {first[:60]!r}; this is not a rig log "
            "(plain CSV files with columns t,u,y are read by read_experiment_data)"
        )
    expected_columns = _FORMATS.get(first)
    if expected_columns is None:
        raise LogFileError(f"{path}: line 1: unsupported log format {first[2:]!r}; this version reads "
                           f"{' and '.join(repr(line[2:]) for line in _FORMATS)}")
    torque_unit = None
    torn = not text.endswith("\n")
    if torn:
        warnings.warn(f"{path}: the last line is incomplete (the writer stopped mid-line); it was dropped",
                      stacklevel=2)
        lines = lines[:-1]
    elif lines[-1] == "":
        lines = lines[:-1]
    metadata_line, header_line = None, None
    for number, line in enumerate(lines[1:], start=2):
        if line.startswith(_METADATA_PREFIX):
            metadata_line = number
        elif line.startswith("# units "):
            _check_units(path, number, line)
            torque_unit = dict(re.findall(r"(\w+)=(\S+)", line)).get(TORQUE_COLUMN)
        elif not line.startswith("#"):
            header_line = number
            break
    if metadata_line is None:
        raise LogFileError(f"{path}: no '{_METADATA_PREFIX.strip()}' line in the header; the file is damaged")
    try:
        metadata = ExperimentMetadata.from_dict(json.loads(lines[metadata_line - 1][len(_METADATA_PREFIX):]))
    except json.JSONDecodeError as err:
        raise LogFileError(f"{path}: line {metadata_line}: the metadata is not valid JSON: {err.msg} at column {err.colno}") from None
    except (ValueError, TypeError) as err:  # InvalidInputError, or a field of the wrong type ("extra": "ab")
        raise LogFileError(f"{path}: line {metadata_line}: bad metadata: {err}") from None
    if header_line is None:
        raise LogFileError(f"{path}: the header has no column line '{','.join(expected_columns)}'; the file is damaged")
    columns = tuple(name.strip() for name in lines[header_line - 1].split(","))
    if columns != expected_columns:
        raise LogFileError(f"{path}: line {header_line}: expected columns {','.join(expected_columns)} "
                           f"({first[2:]}), got {','.join(columns)}")
    if torque_unit is not None and TORQUE_COLUMN in columns:
        metadata = ExperimentMetadata.from_dict({**metadata.to_dict(),
                                                 "extra": {**metadata.extra, "drive_torque_unit": torque_unit}})
    rows = lines[header_line:]
    if rows and rows[0].startswith(_START_PREFIX):
        number = header_line + 1
        try:
            start = json.loads(rows[0][len(_START_PREFIX):])["acquisition_start_utc"]
            metadata = ExperimentMetadata.from_dict({**metadata.to_dict(), "acquisition_start_utc": start})
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
            raise LogFileError(f"{path}: line {number}: the start line is damaged ({err}); expected "
                               f'{_START_PREFIX}{{"acquisition_start_utc": "2025-03-04T09:15:02.123456Z"}}') from None
        rows = rows[1:]
        header_line += 1
    if rows and rows[-1].startswith(_SUMMARY_PREFIX):
        number = header_line + len(rows)
        try:
            summary = json.loads(rows.pop()[len(_SUMMARY_PREFIX):])
        except json.JSONDecodeError as err:
            raise LogFileError(f"{path}: line {number}: the summary is not valid JSON: {err.msg} at column {err.colno}") from None
        if not isinstance(summary, dict):
            raise LogFileError(f"{path}: line {number}: the summary is not a JSON object")
        metadata = ExperimentMetadata.from_dict({**metadata.to_dict(), "extra": {**metadata.extra, "summary": summary}})
    n = len(rows)
    time_s, command, angle = np.empty(n), np.empty(n), np.empty(n)
    counts = np.zeros(n, dtype=np.int64)
    flags = np.zeros(n, dtype=np.uint8)
    torque = np.full(n, np.nan) if TORQUE_COLUMN in columns else None
    has_counts = False
    for index, row in enumerate(rows):
        number = header_line + 1 + index
        fields = row.rstrip("\r").split(",")
        if len(fields) != len(columns):
            raise LogFileError(f"{path}: line {number}: expected {len(columns)} values, got {len(fields)}")
        if torque is not None and fields[5].strip():
            try:
                torque[index] = float(fields[5])
            except ValueError:
                raise LogFileError(f"{path}: line {number}, column {TORQUE_COLUMN}: {fields[5][:40]!r} is not a "
                                   "number") from None
        try:
            time_s[index], command[index], angle[index] = float(fields[0]), float(fields[1]), float(fields[2])
        except ValueError:
            column = next(name for name, text in zip(COLUMNS, fields) if not _is_float(text))
            raise LogFileError(f"{path}: line {number}, column {column}: {fields[COLUMNS.index(column)]!r} is not a number") from None
        try:
            if fields[3].strip():
                counts[index] = int(fields[3])
                has_counts = True
            flag_value = int(fields[4])
        except (ValueError, OverflowError):
            column = "encoder_counts" if not _is_int(fields[3]) else "flags"
            raise LogFileError(f"{path}: line {number}, column {column}: {fields[COLUMNS.index(column)][:40]!r} is "
                               "not an integer") from None
        if not 0 <= flag_value <= 255:
            raise LogFileError(f"{path}: line {number}, column flags: {flag_value} is not a combination of the "
                               f"SampleFlag bits ({_FLAG_NAMES})")
        flags[index] = flag_value
    if n == 0:
        raise LogFileError(f"{path}: the log has a header but no samples")
    try:
        record = ExperimentRecord(time_s=time_s, command_rad=command, angle_rad=angle,
                                  encoder_counts=counts if has_counts else None, flags=flags, metadata=metadata,
                                  drive_torque=torque if torque is not None and np.isfinite(torque).any() else None)
    except InvalidInputError as err:
        raise LogFileError(f"{path}: {_with_line(str(err), header_line)}") from None
    if n > 2:
        step = float(np.median(np.diff(time_s)))
        if abs(step - metadata.sample_period_s) > 0.01 * metadata.sample_period_s:
            raise LogFileError(f"{path}: line {metadata_line}: the metadata says sample_period_s = "
                               f"{metadata.sample_period_s:g} s, but time_s steps by {step:g} s (median); one of "
                               "them is wrong, so the log cannot be trusted")
    if n > 1:  # the runner writes every sample, LOST ones too, at k * period: a hole means the file was edited
        steps = np.diff(time_s)
        off = np.flatnonzero(np.abs(steps - metadata.sample_period_s) > 0.5 * metadata.sample_period_s)
        if off.size:
            row = int(off[0])
            raise LogFileError(
                f"{path}: line {header_line + 2 + row}: time_s steps by {float(steps[row]):g} s after "
                f"{float(time_s[row])!r} s, but the metadata (line {metadata_line}) says the period is "
                f"{metadata.sample_period_s:g} s ({off.size} such steps; a rig log has a line for every sample, "
                "LOST ones too): the file was cut or pasted together; give each piece as its own file")
    return record


_FLAG_NAMES = ", ".join(f"{int(flag)} {flag.name}" for flag in SampleFlag if flag.value)


_EXPECTED_UNITS = {"time_s": "s", "command_rad": "rad", "angle_rad": "rad", "encoder_counts": "counts"}


def _check_units(path: Path, number: int, line: str) -> None:
    """The ``# units`` line must give the units this reader assumes; it converts nothing."""
    for name, unit in re.findall(r"(\w+)=([^\s(]+)", line):
        expected = _EXPECTED_UNITS.get(name)
        if expected is not None and unit != expected:
            raise LogFileError(f"{path}: line {number}: {name} is in {unit!r}, expected {expected!r}; convert the "
                               f"column to {expected} (logs are read as written, without unit conversion)")


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _is_int(text: str) -> bool:
    if not text.strip():
        return True
    try:
        int(text)
    except ValueError:
        return False
    return True


def _with_line(message: str, header_line: int) -> str:
    """Turn 'name: sample k is ...' into 'line L, column name: ...' for a reader looking at the file."""
    name, _, rest = message.partition(": sample ")
    if not rest:
        return message
    index_text, _, problem = rest.partition(" ")
    try:
        line = header_line + 1 + int(index_text)
    except ValueError:
        return message
    return f"line {line}, column {name}: sample {index_text} {problem}"


def read_experiment_data(path: str | Path) -> ExperimentRecord:
    """Read a ``rig-log v1`` file, or a plain CSV with columns ``t,u,y`` (seconds, radians) from another
    tool (``#`` comment lines allowed, other columns ignored). The sample period of a plain CSV is the
    median time step."""
    from rig.measurement_files import measurement_format, read_measurement_record, read_table

    path = check_input_file(path, "a rig-log v1 file or a CSV with columns t,u,y")
    kind = measurement_format(path)
    if kind is None and is_rig_log(path):
        return read_log(path)
    if kind is not None:
        record = read_measurement_record(path)
        if record is not None:
            return record
    table = read_table(path, ("t", "u", "y"))
    t, u, y = table["t"], table["u"], table["y"]
    if t.size < 2:
        raise LogFileError(f"{path}: expected at least two samples, got {t.size}")
    period = _check_time_column(path, t)
    metadata = ExperimentMetadata(sample_period_s=period, source=str(path), transport="csv")
    return ExperimentRecord(time_s=t, command_rad=u, angle_rad=y, encoder_counts=None, flags=None, metadata=metadata)


def read_input_output(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(u, y) for identification from a ``rig-log v1`` file or a CSV with columns ``u`` and ``y``. The
    methods need only the sample order, so a ``t`` column is optional; when present it must increase (rows
    out of order, e.g. two files pasted together, would be identified as one record)."""
    from rig.measurement_files import measurement_format, read_measurement_record, read_table

    path = check_input_file(path, "a rig-log v1 file or a CSV with columns u,y")
    kind = measurement_format(path)
    record = read_log(path) if kind is None and is_rig_log(path) else (
        read_measurement_record(path) if kind is not None else None)
    if record is not None:
        return record.command_rad, record.angle_rad
    table = read_table(path, ("u", "y"), optional_columns=("t",))
    if "t" in table and table["t"].size > 1:
        _check_time_column(path, table["t"])
    return table["u"], table["y"]


@dataclass(frozen=True)
class SetAside:
    """The samples of a record that an analysis leaves out: those whose flags make them unusable
    (:meth:`identify.experiment_record.SampleFlag.unusable`: LOST, DUPLICATE, FAULT, NOT_FOLLOWED, AMBIGUOUS),
    counted per flag (a sample with two of them counts under each)."""

    samples: int
    total: int
    by_flag: dict[str, int]

    def flags_text(self) -> str:
        """'LOST 3, DUPLICATE 1'."""
        return ", ".join(f"{name} {count}" for name, count in self.by_flag.items())

    def to_dict(self) -> dict[str, Any]:
        return {"samples": self.samples, "of": self.total, "by_flag": dict(self.by_flag)}


def unusable_as_missing(record: ExperimentRecord) -> tuple[NDArray[np.float64], SetAside]:
    """The record's angles with NaN at every unusable sample (the methods of ``identify`` take NaN for a
    sample not measured), and what was set aside."""
    unusable = ~record.valid_mask
    by_flag = {flag.name: int(np.count_nonzero(unusable & ((record.flags & int(flag)) != 0)))
               for flag in SampleFlag if flag & SampleFlag.unusable()}
    angle = np.where(unusable, np.nan, record.angle_rad)
    return angle, SetAside(int(np.count_nonzero(unusable)), len(record),
                           {name: count for name, count in by_flag.items() if count})


def read_usable_input_output(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64], SetAside]:
    """:func:`read_input_output` with the output NaN at the samples a rig log (CSV, MDF4 or MAT) flags
    unusable, and what was set aside (nothing for a plain table, which has no flags)."""
    from rig.measurement_files import measurement_format, read_measurement_record

    path = check_input_file(path, "a rig-log v1 file or a CSV with columns u,y")
    kind = measurement_format(path)
    record = read_log(path) if kind is None and is_rig_log(path) else (
        read_measurement_record(path) if kind is not None else None)
    if record is None:
        u, y = read_input_output(path)
        return u, y, SetAside(0, int(u.size), {})
    y, aside = unusable_as_missing(record)
    return record.command_rad, y, aside


JITTER_NOTE = 0.01
"""A plain CSV's ``t`` whose steps spread more than this fraction of the median step gets a warning."""
JITTER_LIMIT = 0.5
"""A step farther than this fraction from the median (a hole, or two samples at nearly one time) is refused."""
SLOWEST_PERIOD_S = 1.0
"""A median step of this many seconds or more is taken for ``t`` in milliseconds or a sample index."""


def _check_time_column(path: Path, t: NDArray[np.float64]) -> float:
    """Check a plain CSV's ``t`` (seconds, increasing, evenly spaced) and return its median step.

    Refused: ``t`` not increasing, a median step of a second or more (milliseconds or a sample index, not
    seconds), a step off the median by more than half of it (a hole of missing samples, or a burst); a
    spread beyond 1 % gives a warning with the spread (the methods assume the median period)."""
    _check_increasing_time(path, t)
    steps = np.diff(t)
    period = float(np.median(steps))
    if period >= SLOWEST_PERIOD_S:
        raise LogFileError(
            f"{path}: column t steps by {period:g} (median), a sample every {period:g} s: t must be in seconds; if it "
            f"is in milliseconds, divide it by 1000 (then {period / 1000:g} s); if it is a sample number, multiply it "
            "by the sample period")
    deviation = np.abs(steps - period)
    off = np.flatnonzero(deviation > JITTER_LIMIT * period)
    spread = (f"steps from {float(steps.min()):.6g} to {float(steps.max()):.6g} s, median {period:.6g} s, "
              f"spread {100 * float(deviation.max()) / period:.3g} %")
    if off.size:
        row = int(off[0]) + 1  # the data row after which the step is
        hole = steps[row - 1] > period
        what = (f"a hole: t jumps by {float(steps[row - 1]):.6g} s, about {round(float(steps[row - 1]) / period) - 1} "
                "samples missing" if hole else f"t steps by only {float(steps[row - 1]):.6g} s")
        raise LogFileError(
            f"{path}: column t, data row {row + 1}: {what} ({spread}; {off.size} steps off by more than "
            f"{100 * JITTER_LIMIT:g} %): the methods need a fixed sample period; cut the record at the hole "
            "(give each part as its own file) or resample it onto an even grid")
    if float(deviation.max()) > JITTER_NOTE * period:
        warnings.warn(f"{path}: column t is uneven ({spread}); the record is used as if sampled every {period:.6g} s",
                      stacklevel=3)
    return period


def _check_increasing_time(path: Path, t: NDArray[np.float64]) -> None:
    """Refuse a ``t`` column that does not increase strictly, naming the first data row that breaks it."""
    backwards = np.flatnonzero(np.diff(t) <= 0)
    if backwards.size:
        row = int(backwards[0]) + 1
        raise LogFileError(f"{path}: column t must increase strictly (seconds); data row {row + 1} has "
                           f"t = {float(t[row])!r} after {float(t[row - 1])!r}: are two records pasted together? "
                           "Give each as its own file")


def check_output_varies(path: str | Path, angle_rad: NDArray[np.float64]) -> None:
    """Refuse a record whose measured output never changes (an unplugged or unpowered encoder reads a
    constant): no method can identify anything from it, and some would report a perfect fit."""
    valid = angle_rad[np.isfinite(angle_rad)]
    if valid.size == 0:
        raise LogFileError(f"{path}: no valid output sample (every sample is LOST or not a number): is the "
                           "encoder connected? Check its cable, power and node id, then record again")
    if valid.size > 1 and float(np.ptp(valid)) == 0.0:
        raise LogFileError(f"{path}: the output is constant ({float(valid[0]):g} rad in all {valid.size} valid "
                           "samples): is the encoder connected? Check its cable, power and node id, then record again")
