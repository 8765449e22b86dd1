"""Measurement files of other tools: ASAM MDF4 (``.mf4``/``.mdf``) and MATLAB (``.mat``), read and written.

Every command that reads data goes through :func:`measurement_format` (the one place that dispatches on the
file's suffix) and then either reads a rig log (:func:`read_measurement_record`, a file written by
``rig export`` or laid out like one) or a table of columns (:func:`read_table`), with the same column names as
a CSV: ``t, u, y`` (seconds, radians) for data of other tools, ``command_rad`` for an excitation. Text files
(rig-log v1 and plain CSV) stay with :mod:`rig.log_file` and :mod:`rig.signal_files`.

Layout written by :func:`write_mdf` (ASAM MDF 4.10, with ``asammdf``, the optional extra ``[mdf]``):

* one channel group ("rig-log v1 samples") whose master is the sample time, with the channels ``time_s`` (s),
  ``command_rad`` (rad), ``angle_rad`` (rad, NaN where LOST), ``encoder_counts`` (counts, 0 where LOST; absent
  when the log has none), ``flags`` (the SampleFlag bits, named in the channel comment) and, from a log with the
  drive's torque (rig-log v2), ``drive_torque`` (in its unit, NaN where not measured), each with its unit and a
  comment that says what it is;
* the log's metadata in the header comment (``<HDcomment>``): the readable lines in ``<TX>``, and the exact
  metadata JSON as the common property ``rig_metadata`` (plus ``sample_period_s``, ``encoder_bits``, ... as
  their own properties, which CANape and the asammdf GUI show); a file-history entry names this tool and version.

Layout written by :func:`write_mat` (``scipy.io.savemat``, MATLAB 5 / v7 format, which ``load`` reads): the
columns as column vectors ``time_s``, ``command_rad``, ``angle_rad``, ``encoder_counts`` (int64), ``flags``
(uint8), ``drive_torque`` where the log has it, and a struct ``metadata`` with the metadata's scalar fields, ``config`` and ``extra`` as JSON text and
``rig_log_json`` (the exact metadata, read back by :func:`read_measurement_record`).

Reading a foreign file: an MDF file's channels by name (any group; the ``t`` of a ``u, y`` pair is the master
time of their group unless a channel ``t`` exists), a MAT file's numeric vectors by variable name (a struct's
fields are not searched). A missing channel raises :class:`~rig.protocols.errors.LogFileError` naming the file
and the channel and listing the channels present.
"""

from __future__ import annotations

import json
import math
import os
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape

import numpy as np
from numpy.typing import NDArray

from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag
from identify.validation import InvalidInputError
from rig.protocols.errors import LogFileError
from rig.signal_files import check_input_file, read_signal_table

__all__ = ["MDF_SUFFIXES", "MAT_SUFFIXES", "MDF_INSTALL_HINT", "MeasurementTable", "require_asammdf", "measurement_format",
           "read_channels", "read_measurement", "read_measurement_record", "read_table", "write_mat", "write_mdf"]

MDF_SUFFIXES = (".mf4", ".mdf")
MAT_SUFFIXES = (".mat",)
MDF_INSTALL_HINT = "pip install 'gearbox-rig[mdf]'"

_COLUMNS = ("time_s", "command_rad", "angle_rad", "encoder_counts", "flags")
_FLAG_TEXT = ", ".join(f"{int(flag)} {flag.name}" for flag in SampleFlag if flag.value)
_UNITS = {"time_s": "s", "command_rad": "rad", "angle_rad": "rad", "encoder_counts": "counts", "flags": ""}
_COMMENTS = {
    "time_s": "sample instant k * sample_period_s",
    "command_rad": "command sent to the drive (input side)",
    "angle_rad": "load-side angle read by the encoder; NaN where the sample is LOST",
    "encoder_counts": "raw encoder reading; 0 where the sample is LOST",
    "flags": f"SampleFlag bits ({_FLAG_TEXT})",
    "drive_torque": "the torque the drive reported (CiA 402 0x6077: per mille of the rated torque); NaN where not "
                    "measured",
}
_METADATA_PROPERTY = "rig_metadata"


def measurement_format(path: str | Path) -> str | None:
    """``"mdf"`` for ``.mf4``/``.mdf``, ``"mat"`` for ``.mat`` (any case), None for text files (a rig log or
    CSV). The one place where a reader is chosen by suffix."""
    suffix = Path(path).suffix.lower()
    if suffix in MDF_SUFFIXES:
        return "mdf"
    if suffix in MAT_SUFFIXES:
        return "mat"
    return None


@dataclass(frozen=True)
class MeasurementTable:
    """The numeric channels of a measurement file and, for a file written by ``rig export``, the log's metadata.

    ``columns`` maps a channel name to a 1-D float array (integer channels keep their integer type);
    ``time_bases`` maps a channel to the master time of its group (MDF only)."""

    path: Path
    kind: str
    columns: dict[str, NDArray[Any]]
    metadata: dict[str, Any] | None = None
    time_bases: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    repeated: dict[str, list[int]] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    start_utc: str | None = None

    def present(self) -> str:
        names = sorted(self.columns)
        shown = ", ".join(names[:40]) + (f", ... ({len(names)} in all)" if len(names) > 40 else "")
        return shown or "none"

    def column(self, name: str, what: str) -> NDArray[Any]:
        """The channel ``name``; a missing one raises an error naming the file and listing those present."""
        if name not in self.columns:
            raise LogFileError(f"{self.path}: no channel {name!r} ({what}); the file has: {self.present()}")
        return self.columns[name]


def require_asammdf(path: Path) -> Any:
    try:
        import asammdf
    except ImportError as err:
        raise LogFileError(f"{path}: reading and writing ASAM MDF files needs the package asammdf: "
                           f"{MDF_INSTALL_HINT}") from err
    return asammdf


def read_measurement(path: str | Path) -> MeasurementTable:
    """Read every numeric 1-D channel of an MDF or MAT file (see the module docstring)."""
    kind = measurement_format(path)
    if kind is None:
        raise LogFileError(f"{path}: not an MDF (.mf4, .mdf) or MATLAB (.mat) file")
    path = check_input_file(path, "an ASAM MDF file" if kind == "mdf" else "a MATLAB .mat file")
    return _read_mdf(path) if kind == "mdf" else _read_mat(path)


def _read_mdf(path: Path) -> MeasurementTable:
    asammdf = require_asammdf(path)
    try:
        mdf = asammdf.MDF(path)
    except Exception as err:  # asammdf raises MdfException, struct.error, ValueError ... on a damaged file
        raise LogFileError(f"{path}: not a readable ASAM MDF file: {err}") from None
    try:
        columns: dict[str, NDArray[Any]] = {}
        bases: dict[str, NDArray[np.float64]] = {}
        repeated: dict[str, list[int]] = {}
        units: dict[str, str] = {}
        for name, places in mdf.channels_db.items():
            if len(places) > 1:
                repeated[name] = [group for group, _ in places]
            group, index = places[0]
            try:
                signal = mdf.get(name, group=group, index=index, raw=False)
            except Exception as err:
                raise LogFileError(f"{path}: channel {name!r} cannot be read: {err}") from None
            samples = np.asarray(signal.samples)
            if samples.ndim != 1 or samples.dtype.kind not in "fiub":
                continue  # arrays, strings, bytes: not a signal of ours
            columns[name] = samples
            bases[name] = np.asarray(signal.timestamps, dtype=float)
            units[name] = str(signal.unit or "")
        metadata = _mdf_metadata(path, mdf.header.comment)
        start_utc = _mdf_start(mdf)
    finally:
        mdf.close()
    for name in repeated:
        columns.pop(name, None)  # which one is meant is unclear; named in the error if it is asked for
    return MeasurementTable(path, "mdf", columns, metadata, bases, repeated, units, start_utc)


def _mdf_start(mdf: Any) -> str | None:
    """The file's start time (the header's absolute time of its master time 0) in UTC, or None."""
    from identify.experiment_record import utc_timestamp

    try:
        start = mdf.header.start_time
        if start.tzinfo is None:  # a local time without its offset: not an instant
            return None
        return utc_timestamp(start)
    except (AttributeError, ValueError, OverflowError):
        return None


def _mdf_metadata(path: Path, comment: str) -> dict[str, Any] | None:
    """The exact metadata JSON from the header comment's ``rig_metadata`` property, if there is one."""
    if not comment or "<" not in comment:
        return None
    try:
        root = ElementTree.fromstring(comment)
    except ElementTree.ParseError:
        return None
    for element in root.iter("e"):
        if element.get("name") == _METADATA_PROPERTY:
            try:
                value = json.loads(element.text or "")
            except json.JSONDecodeError as err:
                raise LogFileError(f"{path}: the header's {_METADATA_PROPERTY} is not valid JSON: {err.msg}") from None
            if not isinstance(value, dict):
                raise LogFileError(f"{path}: the header's {_METADATA_PROPERTY} is not a JSON object")
            return value
    return None


def _read_mat(path: Path) -> MeasurementTable:
    from scipy.io import loadmat

    try:
        contents = loadmat(path, simplify_cells=True)
    except NotImplementedError:  # "Please use HDF reader for matlab v7.3 files"
        raise LogFileError(f"{path}: a MATLAB v7.3 (HDF5) file; save it as v7 (save(name, ..., '-v7')) so that "
                           "it can be read") from None
    except Exception as err:  # ValueError, TypeError, MatReadError on a damaged or foreign file
        raise LogFileError(f"{path}: not a readable MATLAB .mat file: {err}") from None
    columns: dict[str, NDArray[Any]] = {}
    for name, value in contents.items():
        if name.startswith("__"):
            continue
        array = np.asarray(value) if isinstance(value, (np.ndarray, int, float)) else None
        if array is None or array.dtype.kind not in "fiub" or array.ndim > 2:
            continue
        if array.ndim == 2:
            if 1 not in array.shape:
                continue  # a matrix, not one signal
            array = array.reshape(-1)
        columns[name] = array.reshape(-1)
    metadata = None
    struct = contents.get("metadata")
    if isinstance(struct, dict) and isinstance(struct.get("rig_log_json"), str):
        try:
            metadata = json.loads(struct["rig_log_json"])
        except json.JSONDecodeError as err:
            raise LogFileError(f"{path}: metadata.rig_log_json is not valid JSON: {err.msg}") from None
    return MeasurementTable(path, "mat", columns, metadata)


def _float_column(table: MeasurementTable, name: str, what: str) -> NDArray[np.float64]:
    repeated = table.repeated
    if name in repeated:
        raise LogFileError(f"{table.path}: channel {name!r} appears in {len(repeated[name])} channel groups "
                           f"({', '.join(map(str, repeated[name]))}); which one is meant is unclear: keep one "
                           "(asammdf: MDF.filter) or rename the others")
    return np.asarray(table.column(name, what), dtype=float)


def read_table(path: str | Path, required_columns: tuple[str, ...],
               optional_columns: tuple[str, ...] = ()) -> dict[str, NDArray[np.float64]]:
    """``{column: float array}`` from a CSV, MDF or MAT file, with the column rules of
    :func:`rig.signal_files.read_signal_table`: every required column (and every optional one present) must
    hold finite numbers, and all have one length. In an MDF file a missing ``t`` is the master time of the
    other columns' group (they must share one), and the channels' units are converted (``t``/``time_s`` to
    seconds, the others to radians: :mod:`rig.channel_units`)."""
    if measurement_format(path) is None:
        return read_signal_table(path, required_columns, optional_columns)
    table = read_measurement(path)
    wanted = {name: name for name in required_columns}
    wanted.update({name: name for name in optional_columns if name in table.columns})
    time_role = "time_s" if "time_s" in wanted else "t"
    return read_channels(table, wanted, time_role=time_role)


def read_channels(table: MeasurementTable, wanted: dict[str, str], *, time_role: str = "t",
                  raw_roles: tuple[str, ...] = (), stated_units: str | None = None) -> dict[str, NDArray[np.float64]]:
    """``{role: float array}`` for the channel map ``wanted`` (role -> channel name) of a measurement file.

    The role ``time_role`` is converted to seconds; ``raw_roles`` (a validity flag) are taken as they are;
    every other role is an angle, converted to radians from the channel's unit in the file or from
    ``stated_units`` (``--units``; :func:`rig.channel_units.angle_factor`). Where the time channel's name is
    ``t`` and an MDF file has no such channel, the master time of the other channels' group is the time (they
    must share one). Every channel must hold finite numbers, all of one length."""
    from rig.channel_units import angle_factor, time_factor

    path = table.path
    what = "expected channels " + ", ".join(wanted.values())
    if "u" in wanted or "y" in wanted:
        what += "; choose them with --columns t=NAME,u=NAME,y=NAME"
    derived_time = (table.kind == "mdf" and time_role in wanted and wanted[time_role] == "t"
                    and "t" not in table.columns)
    out: dict[str, NDArray[np.float64]] = {}
    for role, name in wanted.items():
        if derived_time and role == time_role:
            continue
        values = _float_column(table, name, what)
        unit = table.units.get(name, "")
        if role == time_role:
            values = values * time_factor(path, name, unit)
        elif role not in raw_roles:
            values = values * angle_factor(path, name, unit, stated_units)
        out[role] = values
    if derived_time:
        others = [role for role in wanted if role != time_role]
        if not others:
            raise LogFileError(f"{path}: no channel 't' ({what}); the file has: {table.present()}")
        first = wanted[others[0]]
        for role in others[1:]:
            other = wanted[role]
            if not np.array_equal(table.time_bases[other], table.time_bases[first]):
                raise LogFileError(f"{path}: channels {first!r} and {other!r} have different time bases (other "
                                   "groups or rates); resample them onto one (asammdf: MDF.resample) and export again")
        out[time_role] = table.time_bases[first]
    lengths = {wanted[role]: values.size for role, values in out.items() if not (derived_time and role == time_role)}
    if len(set(lengths.values())) > 1:
        raise LogFileError(f"{path}: channels of different lengths: "
                           + ", ".join(f"{name} {size}" for name, size in lengths.items()))
    for role, values in out.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise LogFileError(f"{path}: channel {wanted[role]!r}, sample {int(bad[0])}: {values[bad[0]]!r} is not a "
                               f"finite number ({bad.size} such samples)")
    if next(iter(out.values())).size == 0:
        raise LogFileError(f"{path}: the channels have no samples")
    return out


def read_measurement_record(path: str | Path) -> ExperimentRecord | None:
    """The rig log in an MDF or MAT file that carries the log's metadata (written by ``rig export``), checked
    as :func:`rig.log_file.read_log` checks a CSV log; None for a file without it (read it as ``t, u, y``)."""
    table = read_measurement(path)
    if table.metadata is None:
        return None
    path = table.path
    what = "a rig log exported by `rig export` has time_s, command_rad, angle_rad, flags"
    try:
        metadata = ExperimentMetadata.from_dict(table.metadata)
    except (ValueError, TypeError) as err:
        raise LogFileError(f"{path}: bad metadata: {err}") from None
    time_s = _float_column(table, "time_s", what)
    command = _float_column(table, "command_rad", what)
    angle = _float_column(table, "angle_rad", what)
    flags_raw = table.column("flags", what)
    counts_raw = table.columns.get("encoder_counts")
    sizes = {time_s.size, command.size, angle.size, flags_raw.size} | ({counts_raw.size} if counts_raw is not None else set())
    if len(sizes) > 1:
        raise LogFileError(f"{path}: the channels time_s, command_rad, angle_rad, encoder_counts, flags have "
                           "different lengths")
    if time_s.size == 0:
        raise LogFileError(f"{path}: the log has no samples")
    for name, values in (("flags", flags_raw), ("encoder_counts", counts_raw)):
        if values is not None and values.dtype.kind == "f" and not np.all(np.isfinite(values) & (values == np.round(values))):
            raise LogFileError(f"{path}: channel {name!r} holds values that are not integers")
    flags = np.asarray(flags_raw).astype(np.int64)
    if np.any((flags < 0) | (flags > 255)):
        row = int(np.flatnonzero((flags < 0) | (flags > 255))[0])
        raise LogFileError(f"{path}: channel 'flags', sample {row}: {int(flags[row])} is not a combination of the "
                           f"SampleFlag bits ({_FLAG_TEXT})")
    counts = None if counts_raw is None else np.asarray(counts_raw).astype(np.int64)
    torque = _float_column(table, "drive_torque", what) if "drive_torque" in table.columns else None
    try:
        record = ExperimentRecord(time_s=time_s, command_rad=command, angle_rad=angle, encoder_counts=counts,
                                  flags=flags.astype(np.uint8), metadata=metadata, drive_torque=torque)
    except InvalidInputError as err:
        raise LogFileError(f"{path}: {err}") from None
    if time_s.size > 1:
        steps = np.diff(time_s)
        off = np.flatnonzero(np.abs(steps - metadata.sample_period_s) > 0.5 * metadata.sample_period_s)
        if off.size:
            row = int(off[0])
            raise LogFileError(f"{path}: channel 'time_s' steps by {float(steps[row]):g} s after sample {row}, but "
                               f"the metadata says the period is {metadata.sample_period_s:g} s ({off.size} such "
                               "steps): the file was cut or pasted together")
    return record


def _metadata_json(record: ExperimentRecord) -> str:
    from rig.log_file import _json_default

    return json.dumps(record.metadata.to_dict(), allow_nan=False, default=_json_default)


def _columns(record: ExperimentRecord) -> dict[str, NDArray[Any]]:
    lost = (record.flags & int(SampleFlag.LOST)) != 0
    columns: dict[str, NDArray[Any]] = {
        "time_s": np.asarray(record.time_s, dtype=float),
        "command_rad": np.asarray(record.command_rad, dtype=float),
        "angle_rad": np.where(lost, math.nan, np.asarray(record.angle_rad, dtype=float)),
    }
    if record.encoder_counts is not None:
        columns["encoder_counts"] = np.where(lost, 0, np.asarray(record.encoder_counts)).astype(np.int64)
    columns["flags"] = np.asarray(record.flags).astype(np.uint8)
    if record.drive_torque is not None:
        columns["drive_torque"] = np.asarray(record.drive_torque, dtype=float)
    return columns


def write_mdf(path: str | Path, record: ExperimentRecord) -> None:
    """Write ``record`` as an ASAM MDF 4.10 file (layout in the module docstring) at exactly ``path``, which
    must end in ``.mf4`` or ``.mdf`` (asammdf saves an MDF 4 file as ``.mf4``; it is moved to the name asked)."""
    path = Path(path)
    asammdf = require_asammdf(path)
    from asammdf.blocks.v4_blocks import FileHistory

    from rig import __version__

    columns = _columns(record)
    timestamps = columns["time_s"]
    mdf = asammdf.MDF(version="4.10")
    try:
        units = {**_UNITS, "drive_torque": str(record.metadata.extra.get("drive_torque_unit", ""))}
        signals = [asammdf.Signal(samples=values, timestamps=timestamps, name=name, unit=units[name],
                                  comment=_COMMENTS[name]) for name, values in columns.items()]
        mdf.append(signals, comment="rig-log v1 samples")
        if record.metadata.acquisition_start is not None:  # else asammdf's default: the time of the export
            mdf.header.start_time = record.metadata.acquisition_start
        metadata_json = _metadata_json(record)
        meta = record.metadata
        lines = [f"rig log exported by gearbox-rig {__version__}", f"source: {meta.source}",
                 f"transport: {meta.transport}", f"sample_period_s: {meta.sample_period_s!r}"]
        properties = {"sample_period_s": repr(meta.sample_period_s), "source": meta.source,
                      "transport": meta.transport, "encoder_bits": meta.encoder_bits,
                      "noise_bound_rad": meta.noise_bound_rad, "excitation": meta.excitation,
                      "seed": meta.seed, "software_version": meta.software_version}
        elements = "".join(f'<e name="{escape(key)}">{escape(str(value))}</e>' for key, value in properties.items()
                           if value not in (None, ""))
        mdf.header.comment = (f"<HDcomment><TX>{escape(chr(10).join(lines))}</TX><common_properties>{elements}"
                              f'<e name="{_METADATA_PROPERTY}">{escape(metadata_json)}</e>'
                              "</common_properties></HDcomment>")
        history = FileHistory()
        history.comment = (f"<FHcomment><TX>rig export of a rig-log v1 record ({meta.source})</TX>"
                           f"<tool_id>rig</tool_id><tool_vendor>gearbox-rig</tool_vendor>"
                           f"<tool_version>{escape(__version__)}</tool_version></FHcomment>")
        mdf.file_history.insert(0, history)
        saved = Path(mdf.save(path, overwrite=True))
    finally:
        mdf.close()
    if saved.resolve() != path.resolve():  # asammdf names an MDF 4 file .mf4 whatever it was asked: give it the name asked
        os.replace(saved, path)


def write_mat(path: str | Path, record: ExperimentRecord) -> None:
    """Write ``record`` as a MATLAB v7 ``.mat`` file (layout in the module docstring)."""
    from scipy.io import savemat

    meta = record.metadata
    struct: dict[str, Any] = {}
    for key, value in meta.to_dict().items():
        if isinstance(value, (dict, list)):
            struct[key] = json.dumps(value, default=str)
        elif value is None:
            struct[key] = np.zeros((0, 0))  # MATLAB's []
        else:
            struct[key] = value
    struct["rig_log_json"] = _metadata_json(record)
    struct["flag_bits"] = _FLAG_TEXT
    savemat(str(path), {**_columns(record), "metadata": struct}, oned_as="column", appendmat=False,
            do_compression=True)
