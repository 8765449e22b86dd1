"""The angle units a file or a model may carry, and their factor to radians: one table for the readers of
measurement files (:mod:`rig.channel_units`) and for an FMU's input and output (:mod:`sim_backend.fmu_plant`)."""

from __future__ import annotations

import math

__all__ = ["ANGLE_UNITS", "COUNT_UNITS", "NO_UNIT", "angle_unit_factor", "unit_kind"]

ANGLE_UNITS = {
    "rad": ("rad", 1.0), "radian": ("rad", 1.0), "radians": ("rad", 1.0),
    "deg": ("deg", math.pi / 180.0), "°": ("deg", math.pi / 180.0), "degree": ("deg", math.pi / 180.0),
    "degrees": ("deg", math.pi / 180.0),
    "rev": ("rev", 2.0 * math.pi), "revolution": ("rev", 2.0 * math.pi), "revolutions": ("rev", 2.0 * math.pi),
    "turn": ("rev", 2.0 * math.pi), "turns": ("rev", 2.0 * math.pi),
}
"""Unit text (lower case) -> (its canonical name, the factor to radians)."""

COUNT_UNITS = frozenset({"counts", "count", "cnt", "cnts", "inc", "incr", "increments", "ticks", "lsb"})
"""Encoder counts: the factor needs the counts per revolution, which a unit text does not carry."""

NO_UNIT = frozenset({"", "-", "1", "none"})


def unit_kind(unit: str) -> str:
    """``"rad"``, ``"deg"``, ``"rev"``, ``"counts"``, ``""`` (no unit) or ``"unknown"`` for a unit text."""
    key = unit.strip().lower()
    if key in NO_UNIT:
        return ""
    if key in ANGLE_UNITS:
        return ANGLE_UNITS[key][0]
    if key in COUNT_UNITS:
        return "counts"
    return "unknown"


def angle_unit_factor(kind: str) -> float:
    """The factor to radians of ``"rad"``, ``"deg"`` or ``"rev"`` (:func:`unit_kind`)."""
    return ANGLE_UNITS[kind][1]
