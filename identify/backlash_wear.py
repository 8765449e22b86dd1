"""An output backlash whose play grows with wear: the gearbox of an endurance run.

The block is the output backlash of eqs. (2)-(3) of Cerone, Piga and Regruto (2009) (:class:`identify.plant_blocks.
OutputBacklash`) whose dead-band half-widths grow by abrasive wear. Each tooth flank wears in proportion to the
output travel made while it carries the load (Archard's law: worn volume proportional to the sliding distance
under load), up to a limit:

.. math::

    c_{r,t} = c_{r,0} + \\min(k S^+_{t-1}, g_{max}), \\qquad c_{l,t} = c_{l,0} + \\min(k S^-_{t-1}, g_{max}),

    S^+_t = \\sum_{\\tau <= t} \\max(w_\\tau - w_{\\tau-1}, 0), \\qquad
    S^-_t = \\sum_{\\tau <= t} \\max(w_{\\tau-1} - w_\\tau, 0),

with w_t the output (load) angle, k the wear per unit travel (rad of half-width per rad of output travel,
``per_rad_travel``) and g_max the most a flank can wear (``max_rad``). The output moves up only on the right
line (eq. (2), the right flank in contact) and down only on the left line, so S^+ is the travel of the right
flank and S^- that of the left. Sample t's output uses the half-widths worn by the travel before it: the
wear of a move takes effect from the next sample. The total play is c_l + c_r. The law is deterministic
(nothing is drawn at random), so a seeded run repeats exactly.

The block keeps the true half-widths of every sample (:meth:`WearingOutputBacklash.apply_with_play`,
:func:`simulate_with_play`), which tests and the trend figure compare with the bounds of
:func:`identify.feasible_parameter_set.bound_backlash_parameters`. An :class:`~identify.plant_blocks.OutputBacklash`
without wear is a separate class, so a plant without wear runs exactly the code it ran before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.plant_blocks import OutputBacklash, PlantModel
from identify.validation import InvalidInputError, as_signal

__all__ = ["BacklashGrowth", "PlayTrace", "WearingOutputBacklash", "simulate_with_play", "wearing_backlash_of"]


@dataclass(frozen=True)
class BacklashGrowth:
    """The wear law of the module docstring.

    Parameters
    ----------
    per_rad_travel
        k >= 0: growth of a flank's dead-band half-width (rad of the backlash input x) per rad of output
        travel made on that flank.
    max_rad
        g_max > 0: the most each flank's half-width can grow (``inf``: no limit).
    """

    per_rad_travel: float
    max_rad: float = math.inf

    def __post_init__(self) -> None:
        rate = float(self.per_rad_travel)
        if not (math.isfinite(rate) and rate >= 0.0):
            raise InvalidInputError(f"per_rad_travel: expected a finite number >= 0, got {self.per_rad_travel!r}")
        limit = float(self.max_rad)
        if math.isnan(limit) or limit <= 0.0:
            raise InvalidInputError(f"max_rad: expected a number > 0 (inf: no limit), got {self.max_rad!r}")
        object.__setattr__(self, "per_rad_travel", rate)
        object.__setattr__(self, "max_rad", limit)

    def growth_rad(self, travel_rad: ArrayLike) -> NDArray[np.float64]:
        """min(k S, g_max): the growth of a flank after the travel S (rad) on it."""
        return np.minimum(self.per_rad_travel * np.asarray(travel_rad, dtype=float), self.max_rad)


@dataclass(frozen=True)
class PlayTrace:
    """The true half-widths of a wearing backlash at every sample (those that gave w_t)."""

    c_l_rad: NDArray[np.float64]
    c_r_rad: NDArray[np.float64]

    def __post_init__(self) -> None:
        if np.shape(self.c_l_rad) != np.shape(self.c_r_rad):
            raise InvalidInputError(f"c_r_rad: expected {np.size(self.c_l_rad)} values like c_l_rad, got "
                                    f"{np.size(self.c_r_rad)}")

    @property
    def play_rad(self) -> NDArray[np.float64]:
        """The total play c_l + c_r (rad of the backlash input)."""
        return self.c_l_rad + self.c_r_rad

    def __len__(self) -> int:
        return int(np.size(self.c_l_rad))


@dataclass(frozen=True)
class WearingOutputBacklash:
    """An output backlash (eqs. (2)-(3) of Cerone et al. 2009) whose half-widths grow by the law of
    :class:`BacklashGrowth`, starting from ``c_l_rad`` and ``c_r_rad``.

    Examples
    --------
    A unit-slope play driven back and forth by 1 rad: every pass wears the flank that drives.

    >>> block = WearingOutputBacklash(1.0, 0.05, 1.0, 0.05, BacklashGrowth(per_rad_travel=0.01))
    >>> x = np.concatenate([np.linspace(0, 1, 11), np.linspace(1, -1, 21), np.linspace(-1, 1, 21)])
    >>> w, play = block.apply_with_play(x)
    >>> round(float(play.c_r_rad[-1] - 0.05), 6) > 0 and round(float(play.c_l_rad[-1] - 0.05), 6) > 0
    True
    """

    m_l: float
    c_l_rad: float
    m_r: float
    c_r_rad: float
    growth: BacklashGrowth
    initial_output_rad: float = 0.0

    def __post_init__(self) -> None:
        # the same checks as the backlash without wear
        OutputBacklash(self.m_l, self.c_l_rad, self.m_r, self.c_r_rad, self.initial_output_rad)
        if not isinstance(self.growth, BacklashGrowth):
            raise InvalidInputError(f"growth: expected a BacklashGrowth, got {type(self.growth).__name__}")
        for name in ("m_l", "c_l_rad", "m_r", "c_r_rad", "initial_output_rad"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def unworn(self) -> OutputBacklash:
        """The backlash as it left the factory (no wear)."""
        return OutputBacklash(self.m_l, self.c_l_rad, self.m_r, self.c_r_rad, self.initial_output_rad)

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        return self.apply_with_play(signal)[0]

    def apply_with_play(self, backlash_input_rad: ArrayLike) -> tuple[NDArray[np.float64], PlayTrace]:
        """w_t for a whole input x_t (rad) from rest, and the half-widths in force at every sample."""
        x = as_signal("backlash_input_rad", backlash_input_rad)
        w = np.empty_like(x)
        c_l = np.empty_like(x)
        c_r = np.empty_like(x)
        _wearing_backlash_kernel(x, self.m_l, self.c_l_rad, self.m_r, self.c_r_rad, self.growth.per_rad_travel,
                                 self.growth.max_rad, self.initial_output_rad, w, c_l, c_r)
        return w, PlayTrace(c_l, c_r)

    def stepper(self) -> WearingBacklashStepper:
        return WearingBacklashStepper(self)


class WearingBacklashStepper:
    """One sample per :meth:`step`, bit for bit as :meth:`WearingOutputBacklash.apply`; ``c_l`` and ``c_r``
    are the half-widths the next sample will use (the device's truth as it runs)."""

    __slots__ = ("m_l", "c_l0", "m_r", "c_r0", "rate", "limit", "w", "up", "down", "c_l", "c_r")

    def __init__(self, block: WearingOutputBacklash) -> None:
        self.m_l, self.c_l0, self.m_r, self.c_r0 = block.m_l, block.c_l_rad, block.m_r, block.c_r_rad
        self.rate, self.limit = block.growth.per_rad_travel, block.growth.max_rad
        self.w = block.initial_output_rad
        self.up = self.down = 0.0
        self.c_l, self.c_r = self.c_l0, self.c_r0

    def step(self, x: float) -> float:
        x = float(x)
        w = self.w
        if x <= w / self.m_l - self.c_l:
            new = self.m_l * (x + self.c_l)
        elif x >= w / self.m_r + self.c_r:
            new = self.m_r * (x - self.c_r)
        else:
            new = w
        if new > w:
            self.up += new - w
            self.c_r = self.c_r0 + min(self.rate * self.up, self.limit)
        elif new < w:
            self.down += w - new
            self.c_l = self.c_l0 + min(self.rate * self.down, self.limit)
        self.w = new
        return new


@numba.njit(cache=True)
def _wearing_backlash_kernel(x, m_l, c_l0, m_r, c_r0, rate, limit, w0, w_out, c_l_out, c_r_out):
    """The loop of :meth:`WearingBacklashStepper.step` over a whole signal (the same operations in the same
    order, so the same numbers)."""
    w = w0
    up = 0.0
    down = 0.0
    c_l = c_l0
    c_r = c_r0
    for t in range(x.size):
        x_t = x[t]
        c_l_out[t] = c_l
        c_r_out[t] = c_r
        if x_t <= w / m_l - c_l:
            new = m_l * (x_t + c_l)
        elif x_t >= w / m_r + c_r:
            new = m_r * (x_t - c_r)
        else:
            new = w
        if new > w:
            up += new - w
            c_r = c_r0 + min(rate * up, limit)
        elif new < w:
            down += w - new
            c_l = c_l0 + min(rate * down, limit)
        w = new
        w_out[t] = w


def wearing_backlash_of(plant: PlantModel) -> WearingOutputBacklash | None:
    """The plant's wearing backlash, or None; a plant with two is refused (whose play would be the truth?)."""
    found = plant.find(WearingOutputBacklash)
    if len(found) > 1:
        raise InvalidInputError(f"blocks: {len(found)} output backlashes with wear; a plant may have one")
    return found[0] if found else None


def simulate_with_play(plant: PlantModel, command_rad: ArrayLike) -> tuple[NDArray[np.float64], PlayTrace | None]:
    """:meth:`PlantModel.simulate` (the same numbers), and the true half-widths of its wearing backlash at
    every sample (None for a plant without wear)."""
    wearing = wearing_backlash_of(plant)
    if wearing is None:
        return plant.simulate(command_rad), None
    y = as_signal("command_rad", command_rad)
    play = None
    for block in plant.blocks:
        if block is wearing:
            y, play = wearing.apply_with_play(y)
        else:
            y = block.apply(y)
    return np.asarray(y, dtype=float), play
