"""Units of the channels a measurement file carries, converted once into seconds and radians.

A CSV or JSON record carries no units: its numbers are read in the unit ``--units`` states (``rad`` when it
states none). An MDF4 channel carries its own (asammdf's ``Signal.unit``, what INCA and CANape write); it is
converted here by :func:`angle_factor` and :func:`time_factor`:

=====================================  =============================================================
unit written in the file               read as
=====================================  =============================================================
``rad``, ``radian(s)``                 radians
``deg``, ``°``, ``degree(s)``          pi/180 rad
``rev``, ``revolution(s)``, ``turn``   2 pi rad
``counts``, ``cnt``, ``inc``, ...      2 pi/N rad, with N from ``--units counts:N`` (a file does not say N:
                                       refused without it)
none (``""``, ``-``)                   what ``--units`` states, else radians
anything else (``mm``, ``V``, ...)     refused, naming the channel and the unit, unless ``--units`` states one
=====================================  =============================================================

A stated ``--units`` that contradicts the file's unit wins, with a warning naming both (the user may know
better than a mislabelled channel; the warning says which numbers were used). Time channels are read in
``s``, ``ms``, ``us`` or ``ns``.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

from rig.protocols.angle_units import NO_UNIT as _NO_UNIT
from rig.protocols.angle_units import angle_unit_factor, unit_kind
from rig.protocols.errors import LogFileError

__all__ = ["UNITS_HELP", "UnitMismatchWarning", "angle_factor", "parse_units", "time_factor", "unit_kind"]

UNITS_HELP = "rad, deg, rev, or counts:N (N counts per revolution, e.g. counts:4096)"

_TIME_UNITS = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6, "ns": 1e-9}


class UnitMismatchWarning(UserWarning):
    """``--units`` contradicts the unit a channel of the file carries; the stated unit was used."""


def parse_units(text: str) -> float:
    """``rad`` -> 1, ``deg`` -> pi/180, ``rev`` -> 2 pi, ``counts:N`` -> 2 pi / N: the factor to radians."""
    text = text.strip()
    if text in ("rad", "deg", "rev"):
        return angle_unit_factor(text)
    if text.startswith("counts:"):
        try:
            resolution = float(text.split(":", 1)[1])
        except ValueError:
            resolution = math.nan
        if math.isfinite(resolution) and resolution > 0:
            return 2.0 * math.pi / resolution
    raise ValueError(f"--units: expected {UNITS_HELP}, got {text!r}")


def angle_factor(path: Path | str, channel: str, file_unit: str, stated: str | None) -> float:
    """The factor that turns channel ``channel`` of ``path`` (written in ``file_unit``) into radians, given
    the ``--units`` the user ``stated`` (None: nothing stated). Raises :class:`LogFileError` for a unit that
    cannot be converted without more information, saying what to pass; warns when ``stated`` contradicts it."""
    kind = unit_kind(file_unit)
    if stated is not None:
        factor = parse_units(stated)
        stated_kind = stated.strip().split(":", 1)[0]
        if kind not in ("", stated_kind):
            warnings.warn(f"{path}: channel {channel!r} is in {file_unit!r} in the file, but --units {stated} was "
                          f"given: read as {stated} (drop --units to use the file's unit)", UnitMismatchWarning,
                          stacklevel=3)
        return factor
    if kind == "":
        return 1.0
    if kind == "counts":
        raise LogFileError(f"{path}: channel {channel!r} is in {file_unit!r}, and the file does not say how many "
                           "counts make a revolution; pass --units counts:N (e.g. counts:4096 for a 12-bit encoder)")
    if kind == "unknown":
        raise LogFileError(f"{path}: channel {channel!r} is in {file_unit!r}, which is no angle unit read here "
                           f"({UNITS_HELP}); convert the channel, or pass --units to say how to read its numbers")
    return angle_unit_factor(kind)


def time_factor(path: Path | str, channel: str, file_unit: str) -> float:
    """The factor that turns time channel ``channel`` (written in ``file_unit``) into seconds."""
    key = file_unit.strip()
    if key.lower() in _NO_UNIT:
        return 1.0
    factor = _TIME_UNITS.get(key, _TIME_UNITS.get(key.lower()))
    if factor is not None:
        return factor
    raise LogFileError(f"{path}: time channel {channel!r} is in {file_unit!r}; expected s, ms, us or ns: convert "
                       "it, or choose another time channel with --columns t=NAME")
