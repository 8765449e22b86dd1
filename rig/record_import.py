"""Import measurements written by other tools: per-sample JSON records, chosen columns,
units, a validity flag, one-sample read failures and irregular sampling.

Every command that reads a record through :func:`read_measurement` accepts:

* **JSON records**: an object with a list of per-sample objects (the K-Scale sysid logger's ``entries[]``,
  or any key given by ``records=KEY`` in ``--columns``), or a top-level list of such objects;
* ``--columns t=timestamp,u=goal_position,y=position``: which key or CSV column is the time (s), the
  command and the measured angle (default ``t``, ``u``, ``y``), and optionally ``tau=NAME`` the torque the
  drive reported (any unit, taken as it is: ``rig diagnose`` uses it to tell a weight from a sensor error);
* **MDF4 and MAT files**: channels (MDF) or variables (MAT) by the same names and options; an MDF channel's
  own unit is converted (:mod:`rig.channel_units`);
* ``--units``: ``rad`` (default), ``deg``, ``rev``, or ``counts:N`` (N counts per revolution), for u and y; it
  overrides an MDF channel's unit, with a warning where the two disagree;
* ``--valid COLUMN``: keep only the samples where COLUMN holds (true, or nonzero in a CSV); when it holds on
  several stretches the longest is kept and the others are counted in a note;
* **spikes** (one-sample read failures): sample t is a spike when it departs from both neighbours by more
  than :data:`SPIKE_JUMP_FACTOR` times the 99th percentile of |y_t - y_{t-1}| (and at least
  :data:`SPIKE_MIN_JUMP_RAD`) while the neighbours agree within that percentile's double; it is replaced by
  the mean of its neighbours, and counted;
* **irregular sampling**: when time steps leave +-:data:`IRREGULAR_TOLERANCE` of their median,
  the record is resampled on a uniform grid at the median period by linear interpolation, with a note
  giving the spread; a gap longer than :data:`MAX_GAP_PERIODS` periods is refused (samples are missing,
  not jittered).

Rig-log v1 files go through :func:`rig.log_file.read_experiment_data` unchanged. Error messages never echo
more than one line of a file, and at most :data:`ECHO_LIMIT` characters of it.
"""

from __future__ import annotations

import json
import math
from datetime import datetime, timedelta
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag, utc_timestamp
from rig.channel_units import parse_units
from rig.protocols.errors import LogFileError

__all__ = ["ImportOptions", "ImportReport", "RecordImportError", "parse_columns", "parse_units", "read_measurement",
           "remove_spikes", "uniform_sampling"]

SPIKE_JUMP_FACTOR = 10.0
"""A spike departs from both neighbours by at least this many times the record's 99th percentile of
|y_t - y_{t-1}|: far more than the fastest real motion of the record between two samples."""

SPIKE_MIN_JUMP_RAD = 0.05
"""... and by at least this (so that a record at rest, whose percentile is one encoder count, does not turn
every two-count step into a spike)."""

IRREGULAR_TOLERANCE = 0.02
"""Time steps within 2 % of their median are regular (a host clock's rounding); wider spreads are
resampled."""

MAX_GAP_PERIODS = 3.0
"""A time step longer than this many median periods is a gap (samples lost), refused rather than bridged."""

ECHO_LIMIT = 120
"""At most this many characters of a file appear in an error message."""

RECORD_LIST_KEYS = ("entries", "samples", "records", "data")
"""Keys under which a JSON object keeps its per-sample list, tried in this order."""


class RecordImportError(LogFileError):
    """A record that cannot be imported; the message names the file and what was expected."""


@dataclass(frozen=True)
class ImportOptions:
    """What :func:`read_measurement` does with a file (module docstring)."""

    columns: dict[str, str] = field(default_factory=lambda: {"t": "t", "u": "u", "y": "y"})
    units: str | None = None  # None: the file's own units (an MDF channel's), else radians
    valid: str | None = None
    remove_spikes: bool = True
    irregular: str = "resample"  # or "refuse"

    @property
    def is_default(self) -> bool:
        """No column, unit or validity option given (spike and sampling rules at their defaults)."""
        return (all(self.columns.get(role) == role for role in ("t", "u", "y")) and "records" not in self.columns
                and "tau" not in self.columns
                and self.units is None and self.valid is None and self.remove_spikes and self.irregular == "resample")

    def channel_map(self) -> dict[str, str]:
        """Role -> column, key or channel name: ``t``, ``u``, ``y``, with a torque ``tau`` and with ``valid``
        ``valid``. The one
        channel map of every format (CSV, JSON, MDF4, MAT)."""
        wanted = {role: self.columns.get(role, role) for role in ("t", "u", "y")}
        if "tau" in self.columns:
            wanted["tau"] = self.columns["tau"]
        if self.valid:
            wanted["valid"] = self.valid
        return wanted

    def __post_init__(self) -> None:
        if self.units is not None:
            parse_units(self.units)
        if self.irregular not in ("resample", "refuse"):
            raise ValueError(f"irregular: expected resample or refuse, got {self.irregular!r}")


@dataclass(frozen=True)
class ImportReport:
    """What was done to the record on the way in: notes in words, spikes replaced (sample indices in the
    record as imported), whether it was resampled, and the time steps' spread."""

    notes: tuple[str, ...] = ()
    spike_samples: tuple[int, ...] = ()
    resampled: bool = False
    period_min_s: float = math.nan
    period_median_s: float = math.nan
    period_max_s: float = math.nan
    kept_samples: tuple[int, int] | None = None

    @property
    def spikes(self) -> int:
        return len(self.spike_samples)

    def to_dict(self) -> dict[str, Any]:
        return {"notes": list(self.notes), "spikes": self.spikes, "spike_samples": list(self.spike_samples[:20]),
                "resampled": self.resampled,
                "period_s": {"min": self.period_min_s, "median": self.period_median_s, "max": self.period_max_s},
                "kept_samples": list(self.kept_samples) if self.kept_samples else None}


def _short(text: str) -> str:
    line = text.strip().splitlines()[0] if text.strip() else ""
    return line if len(line) <= ECHO_LIMIT else line[:ECHO_LIMIT] + " ..."


def parse_columns(text: str) -> dict[str, str]:
    """``t=timestamp,u=goal_position,y=position`` -> ``{"t": "timestamp", ...}``; missing roles keep their
    default name; ``tau=NAME`` names the drive's torque, ``records=KEY`` a JSON object's per-sample list."""
    columns = {"t": "t", "u": "u", "y": "y"}
    for part in filter(None, (p.strip() for p in text.split(","))):
        role, sep, name = part.partition("=")
        role, name = role.strip(), name.strip()
        if not sep or role not in ("t", "u", "y", "tau", "records") or not name:
            raise ValueError(f"--columns: expected t=NAME,u=NAME,y=NAME (and optionally tau=NAME, records=KEY), got "
                             f"{part!r}")
        columns[role] = name
    return columns


def remove_spikes(y: NDArray[np.float64]) -> tuple[NDArray[np.float64], tuple[int, ...]]:
    """Replace one-sample read failures by the mean of their neighbours (module docstring gives the rule);
    return the cleaned signal and the indices replaced."""
    y = np.asarray(y, dtype=float).copy()
    if y.size < 3:
        return y, ()
    steps = np.abs(np.diff(y))
    if not np.any(np.isfinite(steps)):
        return y, ()
    typical = float(np.nanquantile(steps, 0.99))  # a LOST sample (NaN) is no step, and never a spike
    jump = max(SPIKE_JUMP_FACTOR * typical, SPIKE_MIN_JUMP_RAD)
    middle = y[1:-1]
    before, after = y[:-2], y[2:]
    spikes = ((np.abs(middle - before) > jump) & (np.abs(middle - after) > jump)
              & (np.abs(after - before) <= max(2.0 * typical, 0.5 * jump)))
    index = np.flatnonzero(spikes) + 1
    y[index] = 0.5 * (y[index - 1] + y[index + 1])
    return y, tuple(int(i) for i in index)


def uniform_sampling(t: NDArray[np.float64], *signals: NDArray[np.float64], refuse: bool = False,
                     source: str = "") -> tuple[NDArray[np.float64], list[NDArray[np.float64]], str, tuple[float, float, float]]:
    """Check the time steps; resample ``signals`` linearly onto a uniform grid at the median period when
    they leave +-:data:`IRREGULAR_TOLERANCE` of their median (max - min above twice it; or raise when ``refuse``). Returns the time, the
    signals, a note (empty when regular) and (min, median, max) of the steps."""
    steps = np.diff(t)
    median = float(np.median(steps))
    spread = (float(np.min(steps)), median, float(np.max(steps)))
    if not median > 0:
        raise RecordImportError(f"{source}: the time column does not increase (median step {median:g} s)")
    if spread[2] > MAX_GAP_PERIODS * median:
        at = int(np.argmax(steps))
        raise RecordImportError(
            f"{source}: samples are missing: a time step of {spread[2]:.4g} s after sample {at} (median "
            f"{median:.4g} s); cut the record there or fill the gap")
    relative = (spread[2] - spread[0]) / median
    if relative <= 2.0 * IRREGULAR_TOLERANCE:
        return t, list(signals), "", spread
    words = (f"irregular sampling: time steps {spread[0] * 1e3:.3g} .. {spread[2] * 1e3:.3g} ms (median "
             f"{median * 1e3:.4g} ms, spread {100 * relative:.0f} % of it)")
    if refuse:
        raise RecordImportError(f"{source}: {words}; resample it or allow resampling")
    grid = t[0] + median * np.arange(int(math.floor((t[-1] - t[0]) / median)) + 1)
    return grid, [np.interp(grid, t, s) for s in signals], words + f": resampled to a uniform {median * 1e3:.4g} ms", spread


def _json_records(path: Path, text: str, options: ImportOptions) -> dict[str, NDArray[np.float64]]:
    try:
        document = json.loads(text)
    except json.JSONDecodeError as err:
        raise RecordImportError(f"{path}: not valid JSON at line {err.lineno}, column {err.colno}: {err.msg}") from None
    records_key = options.columns.get("records")
    if isinstance(document, list):
        records = document
    elif isinstance(document, dict):
        keys = [records_key] if records_key else [k for k in RECORD_LIST_KEYS if isinstance(document.get(k), list)]
        if not keys or not isinstance(document.get(keys[0]), list):
            raise RecordImportError(
                f"{path}: a JSON object without a per-sample list (tried {', '.join(keys or RECORD_LIST_KEYS)}); its "
                f"keys are {_short(', '.join(sorted(map(str, document))))}; name the list with --columns records=KEY")
        records = document[keys[0]]
    else:
        raise RecordImportError(f"{path}: expected a JSON object with a per-sample list or a list of records")
    if not records or not all(isinstance(r, dict) for r in records):
        raise RecordImportError(f"{path}: the per-sample list must hold at least one object per sample")
    wanted = options.channel_map()
    available = sorted(map(str, records[0]))
    missing = [name for name in wanted.values() if name not in records[0]]
    if missing:
        raise RecordImportError(
            f"{path}: the records have no key {', '.join(missing)}; they have {_short(', '.join(available))}; "
            "choose with --columns t=KEY,u=KEY,y=KEY")
    out: dict[str, NDArray[np.float64]] = {}
    for role, name in wanted.items():
        try:
            values = [record[name] for record in records]
            out[role] = np.array([float(bool(v)) if role == "valid" else
                                  (math.nan if v is None and role == "tau" else float(v)) for v in values], dtype=float)
        except (KeyError, TypeError, ValueError):
            bad = next(i for i, r in enumerate(records) if not isinstance(r.get(name), (int, float, bool)))
            raise RecordImportError(f"{path}: record {bad} has no number under {name!r}") from None
    return out


MESSAGE_LIMIT = 400
"""An error from another reader is cut to its first line and this many characters (it may quote a header
line, and a one-line file's header is the whole file)."""


def _bounded(err: LogFileError) -> RecordImportError:
    text = str(err)
    first = text.splitlines()[0] if text else ""
    if len(first) > MESSAGE_LIMIT or first != text:
        first = first[:MESSAGE_LIMIT] + " ..."
    return RecordImportError(first)


def _csv_columns(path: Path, options: ImportOptions) -> dict[str, NDArray[np.float64]]:
    from rig.signal_files import read_signal_table

    wanted = options.channel_map()
    try:
        table = read_signal_table(path, tuple(wanted.values()))
    except RecordImportError:
        raise
    except LogFileError as err:
        raise _bounded(err) from None
    return {role: table[name] for role, name in wanted.items()}


def _measurement_columns(table: Any, options: ImportOptions) -> dict[str, NDArray[np.float64]]:
    """The channel map of ``options`` read from an MDF4 or MAT file's
    :class:`~rig.measurement_files.MeasurementTable`, u and y in radians (the channel's own unit, or
    ``--units``), t in seconds."""
    from rig.measurement_files import read_channels

    try:
        return read_channels(table, options.channel_map(), raw_roles=("valid", "tau"), stated_units=options.units)
    except RecordImportError:
        raise
    except LogFileError as err:
        raise _bounded(err) from None


def _longest_run(flag: NDArray[np.bool_]) -> tuple[int, int, int]:
    """[start, stop) of the longest run of True and the number of runs."""
    padded = np.concatenate(([False], flag, [False])).astype(int)
    edges = np.flatnonzero(np.diff(padded))
    starts, stops = edges[0::2], edges[1::2]
    if starts.size == 0:
        return 0, 0, 0
    longest = int(np.argmax(stops - starts))
    return int(starts[longest]), int(stops[longest]), int(starts.size)


def _looks_like_json(path: Path) -> tuple[bool, str]:
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise RecordImportError(f"{path}: not a text file (byte {err.start} is not UTF-8)") from None
    return text.lstrip()[:1] in ("{", "["), text


def _measurement_table(path: Path) -> Any:
    """All channels of an MDF4 or MAT file (:func:`rig.measurement_files.read_measurement`)."""
    from rig.measurement_files import read_measurement as read_file

    try:
        return read_file(path)
    except LogFileError as err:
        raise _bounded(err) from None


def read_measurement(path: str | Path, options: ImportOptions | None = None) -> tuple[ExperimentRecord, ImportReport]:
    """Read one record for analysis with ``options`` (module docstring); return it and what was done."""
    from rig.log_file import is_rig_log, read_experiment_data
    from rig.measurement_files import measurement_format
    from rig.signal_files import check_input_file

    options = options or ImportOptions()
    path = check_input_file(path, "a rig log, a CSV, MDF4 or MAT file, or a JSON record")
    binary = measurement_format(path) is not None  # MDF4 / MAT: channels by name, read by their own reader
    table = _measurement_table(path) if binary else None
    exported = table is not None and options.is_default and table.metadata is not None
    is_json, text = (False, "") if binary or is_rig_log(path) else _looks_like_json(path)
    plain_options = all(options.columns.get(role) == role for role in ("t", "u", "y")) and options.valid is None \
        and "tau" not in options.columns \
        and options.units is None
    if exported or (not binary and not is_json and plain_options):
        try:
            record = read_experiment_data(path)
        except RecordImportError:
            raise
        except LogFileError as err:
            raise _bounded(err) from None
        t, u, y, valid = record.time_s, record.command_rad, record.angle_rad, None
        metadata, flags, counts, torque = record.metadata, record.flags, record.encoder_counts, record.drive_torque
    else:
        if not binary and not is_json and is_rig_log(path):
            raise RecordImportError(f"{path}: a rig log has fixed columns and units; --columns, --units and --valid "
                                    "are for records of other tools")
        if binary:
            columns = _measurement_columns(table, options)
            scale = 1.0
        else:
            columns = _json_records(path, text, options) if is_json else _csv_columns(path, options)
            scale = parse_units(options.units or "rad")
        t, u, y = columns["t"], columns["u"] * scale, columns["y"] * scale
        valid, torque = columns.get("valid"), columns.get("tau")
        metadata, flags, counts = None, None, None
    notes: list[str] = []
    kept = None
    if valid is not None:
        start, stop, runs = _longest_run(valid > 0.5)
        if stop - start < 2:
            raise RecordImportError(f"{path}: {options.valid} holds on fewer than two samples")
        if runs > 1 or stop - start < valid.size:
            notes.append(f"--valid {options.valid}: kept samples {start}..{stop - 1} ({stop - start} of {valid.size}, the "
                         f"longest of {runs} stretch{'es' if runs > 1 else ''} where it holds)")
        t, u, y, kept = t[start:stop], u[start:stop], y[start:stop], (start, stop)
        torque = None if torque is None else torque[start:stop]
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        bad = int(np.flatnonzero(~(np.diff(t) > 0))[0]) + 1 if np.any(np.diff(t) <= 0) else 0
        raise RecordImportError(f"{path}: the time column must increase; it does not at sample {bad}")
    spikes: tuple[int, ...] = ()
    if options.remove_spikes:
        y, spikes = remove_spikes(y)
        if spikes:
            offset = kept[0] if kept else 0
            shown = ", ".join(str(i + offset) for i in spikes[:8]) + (" ..." if len(spikes) > 8 else "")
            notes.append(f"{len(spikes)} one-sample read failure(s) (spikes) replaced by the mean of their neighbours: "
                         f"sample(s) {shown}")
    t, (u, y, *with_torque), note, spread = uniform_sampling(t, u, y, *(() if torque is None else (torque,)),
                                                             refuse=options.irregular == "refuse", source=str(path))
    torque = with_torque[0] if with_torque else None
    if note:
        notes.append(note)
        if flags is not None:  # the flags belong to the samples as taken; a resampled one is LOST where y is unknown
            lost_before = int(np.count_nonzero(flags & int(SampleFlag.LOST)))
            flags = np.where(np.isnan(y), int(SampleFlag.LOST), 0).astype(np.uint8)
            counts = None
            if lost_before or np.any(flags):
                notes.append(f"the sample flags are not resampled: each resampled sample next to one of the {lost_before} "
                             f"LOST samples is LOST ({int(np.count_nonzero(flags))} in all), the other flags are dropped")
    period = float(np.median(np.diff(t))) if note == "" else spread[1]
    if metadata is None or note:
        start = metadata.acquisition_start_utc if metadata is not None else None
        if metadata is None and table is not None and table.start_utc is not None:
            # an MDF file's start time is the instant of its master time 0; the record's sample 0 is at t[0]
            file_start = datetime.fromisoformat(table.start_utc.replace("Z", "+00:00"))
            start = utc_timestamp(file_start + timedelta(seconds=float(t[0])))
        metadata = ExperimentMetadata(sample_period_s=period, source=str(path),
                                      transport="json records" if is_json else (measurement_format(path) or "csv"),
                                      acquisition_start_utc=start)
    record = ExperimentRecord(time_s=np.asarray(t, dtype=float), command_rad=np.asarray(u, dtype=float),
                              angle_rad=np.asarray(y, dtype=float), encoder_counts=counts, flags=flags,
                              metadata=metadata, drive_torque=torque)
    return record, ImportReport(notes=tuple(notes), spike_samples=spikes, resampled=bool(note),
                                period_min_s=spread[0], period_median_s=spread[1], period_max_s=spread[2],
                                kept_samples=kept)


def add_import_arguments(parser: Any) -> None:
    """The import options of every command that reads records (``--columns``, ``--units``, ``--valid``,
    ``--keep-spikes``, ``--refuse-irregular``)."""
    parser.add_argument("--columns", default=None, metavar="t=NAME,u=NAME,y=NAME",
                        help="which CSV column or JSON record key is time (s), command and measured angle "
                             "(default t,u,y; tau=NAME names the drive's torque, in any unit; records=KEY names a "
                             "JSON object's per-sample list)")
    parser.add_argument("--units", default=None, metavar="UNIT",
                        help="units of u and y: rad (default; an MDF channel's own unit when not given), deg, rev, "
                             "or counts:N with N counts per revolution")
    parser.add_argument("--valid", default=None, metavar="COLUMN",
                        help="keep only the longest stretch of samples where COLUMN holds (e.g. torque_enable)")
    parser.add_argument("--keep-spikes", action="store_true",
                        help="do not replace one-sample read failures (spikes) by their neighbours' mean")
    parser.add_argument("--refuse-irregular", action="store_true",
                        help="refuse irregularly sampled records instead of resampling them at the median period")


def options_from_arguments(args: Any) -> ImportOptions:
    """The :class:`ImportOptions` of parsed :func:`add_import_arguments`."""
    columns = parse_columns(args.columns) if args.columns else {"t": "t", "u": "u", "y": "y"}
    return ImportOptions(columns=columns, units=args.units, valid=args.valid, remove_spikes=not args.keep_spikes,
                         irregular="refuse" if args.refuse_irregular else "resample")
