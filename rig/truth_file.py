"""The truth beside a simulated log: the true play of a wearing gearbox, in a sidecar CSV file.

``rig simulate`` of a plant whose backlash wears (:mod:`identify.backlash_wear`) writes, next to ``run.csv``,
``run.truth.csv``::

    # rig-truth v1
    # metadata {"log": "run.csv", "quantity": "play of the wearing output backlash", "resolution_rad": 1e-06, ...}
    time_s,c_l_rad,c_r_rad,play_rad
    0.0,0.0698,0.0349,0.1047
    ...

A row at the first and the last sample and wherever a half-width has moved by more than
:data:`TRUTH_RESOLUTION_RAD` since the row before; the truth holds from a row's time until the next row's,
so read step-wise it is within that resolution of the true half-widths at every sample (an hour at 1 kHz
is about 65 000 rows instead of 3.6 million). Readable without this package: ``pandas.read_csv(path,
comment="#")``. ``rig trend`` draws it and compares the bounds with it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from identify.backlash_wear import PlayTrace
from rig.protocols.errors import LogFileError
from rig.signal_files import check_input_file, read_signal_table

__all__ = ["FORMAT_LINE", "TRUTH_RESOLUTION_RAD", "PlayTruth", "read_play_truth", "truth_path_for", "write_play_truth"]

FORMAT_LINE = "# rig-truth v1"
TRUTH_RESOLUTION_RAD = 1e-6
"""A sidecar row is written when a half-width has moved by more than this: 1/1500 of a 12-bit count."""

COLUMNS = ("time_s", "c_l_rad", "c_r_rad", "play_rad")


def truth_path_for(log_path: str | Path) -> Path:
    """``run.csv`` -> ``run.truth.csv`` (the sidecar of a log, in its directory)."""
    path = Path(log_path)
    return path.with_name(f"{path.stem}.truth.csv")


@dataclass(frozen=True)
class PlayTruth:
    """The true half-widths from the time of each row on (step-wise)."""

    time_s: NDArray[np.float64]
    c_l_rad: NDArray[np.float64]
    c_r_rad: NDArray[np.float64]
    resolution_rad: float
    source: str

    @property
    def play_rad(self) -> NDArray[np.float64]:
        return self.c_l_rad + self.c_r_rad

    def play_range(self, start_s: float, end_s: float) -> tuple[float, float] | None:
        """Smallest and largest true play from ``start_s`` (inclusive) to ``end_s`` (exclusive); None when
        the truth does not reach back to ``start_s``."""
        first = int(np.searchsorted(self.time_s, start_s, side="right")) - 1  # the row in force at start_s
        if first < 0:
            return None
        last = max(first + 1, int(np.searchsorted(self.time_s, end_s, side="left")))
        values = self.play_rad[first:last]
        return float(np.min(values)), float(np.max(values))


def _kept_rows(c_l: NDArray[np.float64], c_r: NDArray[np.float64], resolution: float) -> NDArray[np.int64]:
    """Indices of the rows: the first sample, every sample where a half-width left the last row's value by more
    than ``resolution``, and the last sample (a loop over the samples, but only float compares)."""
    kept = [0]
    last_l, last_r = float(c_l[0]), float(c_r[0])
    # the half-widths never decrease, so a row is due where either passes last + resolution
    index = 0
    n = c_l.size
    while True:
        next_l = int(np.searchsorted(c_l, last_l + resolution, side="right"))
        next_r = int(np.searchsorted(c_r, last_r + resolution, side="right"))
        index = min(next_l, next_r)
        if index >= n:
            break
        kept.append(index)
        last_l, last_r = float(c_l[index]), float(c_r[index])
    if kept[-1] != n - 1:
        kept.append(n - 1)
    return np.asarray(kept, dtype=np.int64)


def write_play_truth(path: str | Path, time_s: NDArray[np.float64], play: PlayTrace, log_name: str,
                     sample_period_s: float) -> int:
    """Write the sidecar of ``play`` (the half-widths at each of ``time_s``); returns the number of rows."""
    c_l, c_r = np.asarray(play.c_l_rad, dtype=float), np.asarray(play.c_r_rad, dtype=float)
    rows = _kept_rows(c_l, c_r, TRUTH_RESOLUTION_RAD)
    metadata = {"log": log_name, "quantity": "play of the wearing output backlash (c_l_rad + c_r_rad, rad of the "
                "backlash input)", "resolution_rad": TRUTH_RESOLUTION_RAD, "sample_period_s": sample_period_s,
                "samples": int(c_l.size)}
    times, lefts, rights = (np.asarray(values, dtype=float)[rows].tolist() for values in (time_s, c_l, c_r))
    with Path(path).open("w", encoding="utf-8") as handle:
        handle.write(f"{FORMAT_LINE}\n# metadata {json.dumps(metadata)}\n{','.join(COLUMNS)}\n")
        handle.writelines(f"{t!r},{left!r},{right!r},{left + right!r}\n"
                          for t, left, right in zip(times, lefts, rights))
    return int(rows.size)


def read_play_truth(path: str | Path) -> PlayTruth:
    """Read a sidecar (or any CSV with columns time_s, c_l_rad, c_r_rad); an error names the file and what
    is wrong."""
    path = check_input_file(path, "a truth file with columns time_s, c_l_rad, c_r_rad")
    table = read_signal_table(path, ("time_s", "c_l_rad", "c_r_rad"))
    time_s = table["time_s"]
    if time_s.size > 1 and np.any(np.diff(time_s) <= 0):
        row = int(np.flatnonzero(np.diff(time_s) <= 0)[0]) + 1
        raise LogFileError(f"{path}: column time_s: row {row + 1} does not come after the row before; a truth file's "
                           "times increase")
    resolution = 0.0
    with path.open("r", encoding="utf-8", errors="replace") as handle:
        for line in (handle.readline(), handle.readline()):
            if line.startswith("# metadata "):
                try:
                    resolution = float(json.loads(line[len("# metadata "):]).get("resolution_rad", 0.0))
                except (ValueError, AttributeError, TypeError):
                    raise LogFileError(f"{path}: line 2: the metadata is not a JSON object with a number "
                                       "resolution_rad") from None
    return PlayTruth(time_s, table["c_l_rad"], table["c_r_rad"], resolution, str(path))
