"""Guaranteed bounds on the play, window by window: how the backlash of an endurance run grows with wear.

Each window's steady-state points (ū_i, ȳ_i) of the staircase (Section 3.2 of Cerone, Piga, Regruto 2009)
give the exact feasible set D_γ of that window (eqs. (11)-(17)) and its orthotope B_γ (eqs. (18)-(20)),
computed by :func:`identify.feasible_parameter_set.bound_backlash_parameters`, the method behind ``rig
identify output-backlash``. D_γ is the product of the left polygon (eq. (15), c_l) and the right one
(eq. (14), c_r), so the total play c_l + c_r ranges over exactly [c_l^min + c_r^min, c_l^max + c_r^max]: the
sum of the two exact intervals is the exact bound on the play, not a looser box.

A play that wears during a window is not one backlash for all its points: a point taken when the half-width
was c_i lies m·(c* - c_i) away from the line of any other half-width c* the window went through. With a wear
allowance a >= m·(c_max - c_min) (the slope times the most a half-width wears within one window) added to
the noise bound of every point, eq. (5) holds for every c* in [c_min, c_max] of each side, so every value the
play took in the window lies inside its bounds (and the windows' bounds move with the wear). With a = 0 the
bounds are those of a constant play; points worn apart by more than the noise leaves room for give an empty
set, whose explanation says how much larger the bound would have to be. A window whose data cannot bound the play (no steady-state point, all points on one side: the
command never turned back, fewer than two distinct amplitudes on a side) says why instead of giving a
number; one whose points contradict the noise bound has an empty feasible set and says which.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from identify.feasible_parameter_set import ParameterInterval, bound_backlash_parameters
from identify.result_format import check_kind, malformed, number, tagged
from identify.validation import InvalidInputError, as_signal

__all__ = ["STATUSES", "BacklashTrend", "TrendWindow", "bound_window_play"]

STATUSES = ("bounded", "cannot_bound", "empty")
"""``bounded``: the play's interval is known; ``cannot_bound``: the window's data do not bound it (the reason
says why); ``empty``: no backlash fits the window's points within the noise bound."""


def _interval_or_none(data: Any) -> ParameterInterval | None:
    return None if data is None else ParameterInterval.from_dict(data)


def _optional(value: Any) -> float | None:
    return None if value is None else float(value)


@dataclass(frozen=True)
class TrendWindow:
    """One window of the trend.

    Attributes
    ----------
    index, start_s, end_s
        The window's number and its time span [start_s, end_s) in the record's time (s).
    status, reason
        One of :data:`STATUSES`, and in words why a window is not ``bounded`` ("" when it is).
    right_points, left_points
        Steady-state points of the positive (eq. (11)) and negative (eq. (12)) half-waves in the window.
    play_rad, c_l_rad, c_r_rad
        Guaranteed intervals of the total play c_l + c_r and of each half-width (rad of the backlash input);
        None unless ``bounded``.
    m_l, m_r
        Intervals of the slopes (None unless ``bounded``).
    truth_min_rad, truth_max_rad
        The true play's smallest and largest value in the window, when a simulation's truth is known.
    samples_set_aside, points_set_aside
        Samples in the window that their flags make unusable (LOST, ...), and steady-state points left out
        because every sample of their settled tail was.
    """

    index: int
    start_s: float
    end_s: float
    status: str
    reason: str
    right_points: int
    left_points: int
    play_rad: ParameterInterval | None = None
    c_l_rad: ParameterInterval | None = None
    c_r_rad: ParameterInterval | None = None
    m_l: ParameterInterval | None = None
    m_r: ParameterInterval | None = None
    truth_min_rad: float | None = None
    truth_max_rad: float | None = None
    samples_set_aside: int = 0
    points_set_aside: int = 0

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise InvalidInputError(f"status: expected one of {', '.join(STATUSES)}, got {self.status!r}")
        if (self.status == "bounded") != (self.play_rad is not None):
            raise InvalidInputError(f"play_rad: a window is bounded exactly when it has a play interval (status "
                                    f"{self.status}, play_rad {self.play_rad})")
        if not self.end_s >= self.start_s:
            raise InvalidInputError(f"end_s: expected >= start_s = {self.start_s}, got {self.end_s}")

    @property
    def truth_inside(self) -> bool | None:
        """Whether every value the true play took in the window lies inside the bounds (None: no truth, or
        not bounded)."""
        if self.play_rad is None or self.truth_min_rad is None or self.truth_max_rad is None:
            return None
        return self.play_rad.lower <= self.truth_min_rad and self.truth_max_rad <= self.play_rad.upper

    def with_truth(self, truth_min_rad: float | None, truth_max_rad: float | None) -> TrendWindow:
        from dataclasses import replace

        return replace(self, truth_min_rad=truth_min_rad, truth_max_rad=truth_max_rad)

    def to_dict(self) -> dict[str, Any]:
        intervals = {name: None if value is None else value.to_dict()
                     for name, value in (("play_rad", self.play_rad), ("c_l_rad", self.c_l_rad),
                                         ("c_r_rad", self.c_r_rad), ("m_l", self.m_l), ("m_r", self.m_r))}
        return {"index": self.index, "start_s": number(self.start_s), "end_s": number(self.end_s),
                "status": self.status, "reason": self.reason, "right_points": self.right_points,
                "left_points": self.left_points, **intervals,
                "truth_min_rad": None if self.truth_min_rad is None else number(self.truth_min_rad),
                "truth_max_rad": None if self.truth_max_rad is None else number(self.truth_max_rad),
                "truth_inside": self.truth_inside, "samples_set_aside": self.samples_set_aside,
                "points_set_aside": self.points_set_aside}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrendWindow:
        return cls(int(data["index"]), float(data["start_s"]), float(data["end_s"]), str(data["status"]),
                   str(data["reason"]), int(data["right_points"]), int(data["left_points"]),
                   *(_interval_or_none(data[name]) for name in ("play_rad", "c_l_rad", "c_r_rad", "m_l", "m_r")),
                   truth_min_rad=_optional(data["truth_min_rad"]), truth_max_rad=_optional(data["truth_max_rad"]),
                   samples_set_aside=int(data["samples_set_aside"]), points_set_aside=int(data["points_set_aside"]))


@dataclass(frozen=True)
class BacklashTrend:
    """The windows of one record, in time order, with what they were computed from.

    ``source`` names the record, ``window_s`` the window length, ``noise_bound_rad`` the Δη of the
    measurements (eq. (5)), ``wear_allowance_rad`` the a added to it for the wear within a window (module
    docstring), ``filter_step_rad`` r̄_F of eqs. (14)-(15) (None: α = 0); ``truth_source`` names where the
    truth came from (None: no truth known).
    """

    source: str
    window_s: float
    noise_bound_rad: float
    filter_step_rad: float | None
    windows: tuple[TrendWindow, ...]
    truth_source: str | None = None
    wear_allowance_rad: float = 0.0

    KIND = "backlash_trend"
    VERSION = 1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise InvalidInputError(f"window_s: expected a number of seconds > 0, got {self.window_s!r}")
        object.__setattr__(self, "windows", tuple(self.windows))

    @property
    def bounded(self) -> tuple[TrendWindow, ...]:
        return tuple(window for window in self.windows if window.status == "bounded")

    @property
    def truth_inside_count(self) -> tuple[int, int]:
        """(windows whose bounds meet the truth, bounded windows with a truth)."""
        judged = [window.truth_inside for window in self.windows if window.truth_inside is not None]
        return sum(judged), len(judged)

    def to_dict(self) -> dict[str, Any]:
        inside, judged = self.truth_inside_count
        return tagged(self.KIND, self.VERSION, {
            "source": self.source, "window_s": number(self.window_s), "noise_bound_rad": number(self.noise_bound_rad),
            "wear_allowance_rad": number(self.wear_allowance_rad),
            "filter_step_rad": None if self.filter_step_rad is None else number(self.filter_step_rad),
            "truth_source": self.truth_source,
            "summary": {"windows": len(self.windows), "bounded": len(self.bounded),
                        "cannot_bound": sum(w.status == "cannot_bound" for w in self.windows),
                        "empty": sum(w.status == "empty" for w in self.windows),
                        "truth_inside": inside, "truth_judged": judged},
            "windows": [window.to_dict() for window in self.windows]})

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BacklashTrend:
        """Inverse of :meth:`to_dict` (the summary is recomputed); another kind or version is a
        ResultFormatError."""
        check_kind(data, cls.KIND, (cls.VERSION,))
        with malformed(cls.KIND):
            step = data["filter_step_rad"]
            return cls(str(data["source"]), float(data["window_s"]), float(data["noise_bound_rad"]),
                       None if step is None else float(step),
                       tuple(TrendWindow.from_dict(window) for window in data["windows"]),
                       None if data["truth_source"] is None else str(data["truth_source"]),
                       float(data["wear_allowance_rad"]))


def bound_window_play(index: int, start_s: float, end_s: float, steady_input_rad: ArrayLike,
                      steady_output_rad: ArrayLike, noise_bound_rad: float, *,
                      wear_allowance_rad: float = 0.0, filter_step_amplitude_rad: float | None = None,
                      samples_set_aside: int = 0, points_set_aside: int = 0) -> TrendWindow:
    """The :class:`TrendWindow` of one window's steady-state points: D_γ and B_γ by
    :func:`~identify.feasible_parameter_set.bound_backlash_parameters` (eqs. (11)-(20) of Cerone et al.
    2009) with the noise bound Δη + a (``wear_allowance_rad``, module docstring), the play's interval as the
    sum of the exact intervals of c_l and c_r, or the reason the window cannot bound it.

    Examples
    --------
    >>> u = np.array([1.0, -1.0, 2.0, -2.0])
    >>> y = np.array([0.25 * (1 - 0.04), 0.25 * (-1 + 0.06), 0.25 * (2 - 0.04), 0.25 * (-2 + 0.06)])
    >>> window = bound_window_play(0, 0.0, 60.0, u, y, 1e-4)
    >>> window.status, window.play_rad.contains(0.1)
    ('bounded', True)
    >>> bound_window_play(1, 60.0, 120.0, u[u > 0], y[u > 0], 1e-4).status
    'cannot_bound'
    """
    common = {"index": int(index), "start_s": float(start_s), "end_s": float(end_s),
              "samples_set_aside": int(samples_set_aside), "points_set_aside": int(points_set_aside)}
    u = as_signal("steady_input_rad", steady_input_rad)
    y = as_signal("steady_output_rad", steady_output_rad)
    if u.shape != y.shape:
        raise InvalidInputError(f"steady_output_rad: expected {u.size} values like steady_input_rad, got {y.size}")
    right, left = int(np.count_nonzero(u > 0)), int(np.count_nonzero(u < 0))
    common.update(right_points=right, left_points=left)
    lost = f" ({points_set_aside} more were LOST or unusable)" if points_set_aside else ""
    if right == 0 and left == 0:
        return TrendWindow(status="cannot_bound", reason="no steady-state point in this window: no half-wave of the "
                           f"staircase ends in it{lost}", **common)
    if right == 0 or left == 0:
        side, other, flank = (("positive", "negative", "left flank (c_l, eq. (15))") if left == 0
                              else ("negative", "positive", "right flank (c_r, eq. (14))"))
        return TrendWindow(status="cannot_bound", reason=f"no reversal: all {right + left} steady-state points are on "
                           f"the {side} side (the command never turned {other}), so nothing bounds the "
                           f"{flank}{lost}", **common)
    allowance = float(wear_allowance_rad)
    if not (math.isfinite(allowance) and allowance >= 0.0):
        raise InvalidInputError(f"wear_allowance_rad: expected a finite number >= 0, got {wear_allowance_rad!r}")
    try:
        feasible = bound_backlash_parameters(u, y, float(noise_bound_rad) + allowance,
                                             filter_step_amplitude_rad=filter_step_amplitude_rad)
    except InvalidInputError as err:
        return TrendWindow(status="cannot_bound", reason=f"{err}{lost}", **common)
    if feasible.is_empty:
        assert feasible.explanation is not None
        return TrendWindow(status="empty", reason=f"empty feasible set: {feasible.explanation.message}", **common)
    intervals = feasible.intervals()
    c_l, c_r = intervals["c_l"], intervals["c_r"]
    play = ParameterInterval(c_l.lower + c_r.lower, c_l.upper + c_r.upper)
    return TrendWindow(status="bounded", reason="", play_rad=play, c_l_rad=c_l, c_r_rad=c_r, m_l=intervals["m_l"],
                       m_r=intervals["m_r"], **common)
