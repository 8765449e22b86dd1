"""Read signals for analysis from plain CSV files (and, once they exist, the project's experiment logs).

Every problem raises :class:`~rig.protocols.errors.LogFileError` naming the file, the line or column and
what was expected. Reads are bounded: a line longer than :data:`MAX_LINE_BYTES` or a NUL byte ends the read
at once ("not a CSV file"), so ``/dev/zero`` or a sparse file of zeros costs nothing; devices, pipes and
directories are refused before anything is read. A UTF-8 byte-order mark is accepted.
"""

from __future__ import annotations

import csv
import stat
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rig.protocols.errors import LogFileError

__all__ = ["MAX_LINE_BYTES", "check_input_file", "read_signal_table", "read_text_lines"]

MAX_LINE_BYTES = 1 << 20
"""Longest line a CSV or log may have (a row of numbers is well under a kilobyte)."""

_BOM = b"\xef\xbb\xbf"


def check_input_file(path: str | Path, expected: str = "a CSV file") -> Path:
    """Refuse, before reading, a path that is missing, a directory, or not a regular file (a device such as
    ``/dev/zero``, a pipe, a socket); return it as a ``Path``."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise LogFileError(f"{path}: no such file; expected {expected}") from None
    except OSError as err:
        raise LogFileError(f"{path}: cannot be read: {err.strerror}; expected {expected}") from None
    if stat.S_ISDIR(mode):
        raise LogFileError(f"{path}: is a directory; give {expected} in it")
    if not stat.S_ISREG(mode):
        kind = ("a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode)
                else "a pipe" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "not a file")
        raise LogFileError(f"{path}: is {kind}, not a regular file; expected {expected} (save the data to a file first)")
    return path


def read_text_lines(path: Path, expected: str = "a CSV file") -> list[tuple[int, str]]:
    """``(line number, text)`` of every line of a UTF-8 text file (a leading BOM dropped, line ends
    stripped), read in bounded pieces: a NUL byte, a line longer than :data:`MAX_LINE_BYTES` or bytes that
    are not UTF-8 stop the read with a message naming the byte offset."""
    lines: list[tuple[int, str]] = []
    offset = 0
    with path.open("rb") as handle:
        number = 0
        while True:
            raw = handle.readline(MAX_LINE_BYTES + 1)
            if not raw:
                break
            number += 1
            if number == 1 and raw.startswith((b"\xff\xfe", b"\xfe\xff")):
                raise LogFileError(f"{path}: the file is UTF-16 encoded (it starts with a UTF-16 byte-order mark); "
                                   f"save it as UTF-8 (in Excel: CSV UTF-8; pandas: to_csv(..., encoding='utf-8'))")
            nul = raw.find(b"\0")
            if nul >= 0:
                raise LogFileError(f"{path}: not a CSV file (NUL bytes at byte {offset + nul}); expected {expected}"
                                   " (a binary file, or a file padded with zeros by a crash: cut it at that byte)")
            if len(raw) > MAX_LINE_BYTES and not raw.endswith(b"\n"):
                raise LogFileError(f"{path}: line {number} is longer than {MAX_LINE_BYTES} bytes: not a CSV file; "
                                   f"expected {expected}")
            if number == 1 and raw.startswith(_BOM):
                raw, offset = raw[len(_BOM):], offset + len(_BOM)
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError as err:
                raise LogFileError(f"{path}: not a text file (byte {offset + err.start} is not UTF-8); expected "
                                   f"{expected} (save it as UTF-8)") from None
            offset += len(raw)
            lines.append((number, text.rstrip("\r\n")))
    return lines


def _separator_hint(header: str, data: str | None) -> str:
    """'looks like ';'-separated ...' when the header is one field holding another separator."""
    for separator, name in ((";", "';'-separated"), ("\t", "tab-separated"), ("|", "'|'-separated")):
        if separator in header:
            decimal = " with decimal commas" if data is not None and "," in data else ""
            how = f"sep={separator!r}" + (", decimal=','" if decimal else "")
            return (f"; it looks like {name}{decimal}: write it with ',' between values and '.' as the decimal "
                    f"point (pandas: pandas.read_csv(path, {how}).to_csv(new_path, index=False))")
    return ""


def read_signal_table(path: str | Path, required_columns: tuple[str, ...],
                      optional_columns: tuple[str, ...] = ()) -> dict[str, NDArray[np.float64]]:
    """Read a CSV file with a header row into ``{column: float array}``.

    Lines starting with ``#`` are comments. Every column in ``required_columns`` must be present and hold
    finite numbers; so must each of ``optional_columns`` that is present. Other columns are kept when they
    hold finite numbers only and ignored otherwise (a text column of notes, a time stamp as a date). A
    column name given twice is refused (which one is meant?).
    """
    path = check_input_file(path)
    numbered = read_text_lines(path)
    try:
        rows = [(number, row) for number, row in zip((n for n, _ in numbered), csv.reader(text for _, text in numbered))
                if row and not row[0].lstrip().startswith("#")]
    except csv.Error as err:
        raise LogFileError(f"{path}: not a readable CSV: {err}") from None
    if not rows:
        raise LogFileError(f"{path}: the file is empty; expected a header row with columns {', '.join(required_columns)}")
    header_line, header = rows[0]
    names = [name.strip() for name in header]
    missing = [name for name in required_columns if name not in names]
    if missing:
        raw_header = next(text for number, text in numbered if number == header_line)
        data_text = next((text for number, text in numbered if number > header_line and text.strip()), None)
        raise LogFileError(
            f"{path}: line {header_line}: missing column(s) {', '.join(missing)}; the header has "
            f"{', '.join(names)[:120]}{_separator_hint(raw_header, data_text)}"
        )
    repeated = sorted({name for name in names if names.count(name) > 1 and name})
    if repeated:
        name = repeated[0]
        places = [str(index + 1) for index, other in enumerate(names) if other == name]
        raise LogFileError(f"{path}: line {header_line}: column {name} appears {len(places)} times (columns "
                           f"{', '.join(places)}); which one is meant is unclear: rename or remove the others")
    if len(rows) == 1:
        raise LogFileError(f"{path}: the file has a header but no data rows")
    strict = {name for name in (*required_columns, *optional_columns) if name in names}
    values = np.empty((len(rows) - 1, len(names)))
    ignored: set[int] = set()
    for index, (line, row) in enumerate(rows[1:]):
        if len(row) != len(names):
            hint = ""
            if len(row) > len(names) and any("." not in field and field.strip().lstrip("-").isdigit() for field in row):
                hint = ("; if the numbers use decimal commas (0,5), write them with decimal points, or quote "
                        "them and convert")
            raise LogFileError(f"{path}: line {line}: expected {len(names)} values, got {len(row)}{hint}")
        for column, text in enumerate(row):
            if column in ignored:
                continue
            try:
                values[index, column] = float(text)
                finite = bool(np.isfinite(values[index, column]))
            except ValueError:
                finite = None
            if finite:
                continue
            if names[column] not in strict:
                ignored.add(column)  # not one of ours: a note, a date, an empty cell
                continue
            if finite is None:
                raise LogFileError(
                    f"{path}: line {line}, column {names[column]}: {text.strip()[:40]!r} is not a number"
                )
            raise LogFileError(f"{path}: line {line}, column {names[column]}: {text.strip()} is not a finite number")
    return {name: values[:, column].copy() for column, name in enumerate(names) if column not in ignored}
