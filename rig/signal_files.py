"""Read signals for analysis from plain CSV files (and, once they exist, the project's experiment logs).

Every problem raises :class:`~rig.protocols.errors.LogFileError` naming the file, the line or column and
what was expected.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rig.protocols.errors import LogFileError


def read_signal_table(path: str | Path, required_columns: tuple[str, ...]) -> dict[str, NDArray[np.float64]]:
    """Read a CSV file with a header row into ``{column: float array}``.

    Lines starting with ``#`` are comments. Every column in ``required_columns`` must be present; other
    columns are kept. Every value must be a finite number.
    """
    path = Path(path)
    if not path.is_file():
        raise LogFileError(f"{path}: no such file")
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = [(number, row) for number, row in enumerate(csv.reader(handle), start=1)
                    if row and not row[0].lstrip().startswith("#")]
    except UnicodeDecodeError as err:
        raise LogFileError(f"{path}: not a text file (byte {err.start} is not UTF-8); expected a CSV") from None
    except csv.Error as err:
        raise LogFileError(f"{path}: not a readable CSV: {err}") from None
    if not rows:
        raise LogFileError(f"{path}: the file is empty; expected a header row with columns {', '.join(required_columns)}")
    header_line, header = rows[0]
    names = [name.strip() for name in header]
    missing = [name for name in required_columns if name not in names]
    if missing:
        raise LogFileError(
            f"{path}: line {header_line}: missing column(s) {', '.join(missing)}; the header has {', '.join(names)}"
        )
    if len(rows) == 1:
        raise LogFileError(f"{path}: the file has a header but no data rows")
    values = np.empty((len(rows) - 1, len(names)))
    for index, (line, row) in enumerate(rows[1:]):
        if len(row) != len(names):
            raise LogFileError(f"{path}: line {line}: expected {len(names)} values, got {len(row)}")
        for column, text in enumerate(row):
            try:
                values[index, column] = float(text)
            except ValueError:
                raise LogFileError(
                    f"{path}: line {line}, column {names[column]}: {text.strip()!r} is not a number"
                ) from None
            if not np.isfinite(values[index, column]):
                raise LogFileError(
                    f"{path}: line {line}, column {names[column]}: {text.strip()} is not a finite number"
                )
    return {name: values[:, column].copy() for column, name in enumerate(names)}
