"""The backlash and switch blocks of the two papers, and the borders of the latter (part of the block set of
:mod:`identify.plant_blocks`, which exports them too: a block here runs ``apply`` and ``stepper`` as every block
there does).

* Cerone, Piga, Regruto (2009), *Parameter bounds evaluation for linear system with output backlash*, eqs. (2)-(3):
  :class:`OutputBacklash`;
* Pouliquen et al. (2013), *Subspace identification of Hammerstein systems with nonparametric input backlash and
  switch nonlinearities*, Section II: :class:`InputBacklash` and :class:`InputSwitch` with arbitrary borders (the
  direction signal delta(t) and eq. (2)), and the example borders of Section IV.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.validation import InvalidInputError, as_signal, finite, finite_coefficients, positive

__all__ = ["ArctanBorder", "Border", "InputBacklash", "InputSwitch", "OutputBacklash", "PiecewiseLinearBorder",
           "pouliquen2013_backlash", "pouliquen2013_switch"]

Border = Callable[[float], float]
"""A border of an input backlash or switch: a function of the input angle (rad) returning the output."""


@dataclass(frozen=True)
class OutputBacklash:
    """Backlash at the output of the linear block, eqs. (2)-(3) of Cerone et al. (2009).

    .. math::

        w_t = m_l (x_t + c_l)  if x_t <= z_l;\\quad
        w_t = m_r (x_t - c_r)  if x_t >= z_r;\\quad
        w_t = w_{t-1}          if z_l < x_t < z_r,

    with z_l = w_{t-1}/m_l - c_l and z_r = w_{t-1}/m_r + c_r (eq. (3)). The cases are tested in this
    order. ``initial_output_rad`` is w_{-1}.

    Parameters
    ----------
    m_l, c_l_rad, m_r, c_r_rad
        Slopes (> 0, dimensionless: rad of w per rad of x) and dead-band half-widths (> 0, in rad of x) of
        the left and right lines; gamma = [m_l c_l m_r c_r] in eq. (6).
    initial_output_rad
        w_{-1}, the output the gearbox rests at before the first sample.
    """

    m_l: float
    c_l_rad: float
    m_r: float
    c_r_rad: float
    initial_output_rad: float = 0.0

    def __post_init__(self) -> None:
        for name in ("m_l", "c_l_rad", "m_r", "c_r_rad"):
            object.__setattr__(self, name, positive(name, getattr(self, name)))
        object.__setattr__(self, "initial_output_rad", finite("initial_output_rad", self.initial_output_rad))

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        # a fresh writable copy: one compiled signature (a read-only input would compile a second one)
        x = np.array(as_signal("signal", signal), dtype=np.float64)
        return _output_backlash_run(x, self.m_l, self.c_l_rad, self.m_r, self.c_r_rad, self.initial_output_rad)

    def stepper(self) -> _OutputBacklashStepper:
        return _OutputBacklashStepper(self)


@numba.njit(cache=True)
def _output_backlash_run(x, m_l, c_l, m_r, c_r, w):
    """The loop of :meth:`_OutputBacklashStepper.step` over a whole signal from w_{-1} = ``w`` (the same
    operations in the same order, so the same numbers; compiled, as every per-sample loop a diagnosis runs
    in its fits)."""
    out = np.empty(x.size)
    for t in range(x.size):
        x_t = x[t]
        if x_t <= w / m_l - c_l:
            w = m_l * (x_t + c_l)
        elif x_t >= w / m_r + c_r:
            w = m_r * (x_t - c_r)
        out[t] = w
    return out


class _OutputBacklashStepper:
    __slots__ = ("m_l", "c_l", "m_r", "c_r", "w")

    def __init__(self, block: OutputBacklash) -> None:
        self.m_l, self.c_l, self.m_r, self.c_r = block.m_l, block.c_l_rad, block.m_r, block.c_r_rad
        self.w = block.initial_output_rad

    def step(self, x: float) -> float:
        x = float(x)
        w = self.w
        if x <= w / self.m_l - self.c_l:
            w = self.m_l * (x + self.c_l)
        elif x >= w / self.m_r + self.c_r:
            w = self.m_r * (x - self.c_r)
        self.w = w
        return w


def _evaluate_border(border: Border, u: list[float], name: str) -> list[float]:
    """Border values sample by sample; a border may offer ``evaluate_list`` that gives the same numbers."""
    evaluate = getattr(border, "evaluate_list", None)
    values = evaluate(u) if evaluate is not None else [float(border(v)) for v in u]
    for index, value in enumerate(values):
        if not math.isfinite(value):
            raise InvalidInputError(f"{name}: the border returned {value} at input {u[index]!r} (sample {index})")
    return values


def _border_value(border: Border, x: float, name: str) -> float:
    """One border value; the same number as :func:`_evaluate_border` gives for this sample."""
    value = float(border(x))
    if not math.isfinite(value):
        raise InvalidInputError(f"{name}: the border returned {value} at input {x!r}")
    return value


@dataclass(frozen=True)
class PiecewiseLinearBorder:
    """A border given by a node table: linear between nodes, constant beyond the end nodes.

    This is the continuous piecewise-linear description of eq. (3) of Pouliquen et al. (2013) (after
    Van Pelt and Bernstein 2001), evaluated with :func:`numpy.interp`.

    Parameters
    ----------
    nodes_u
        Strictly increasing input angles (rad), at least two.
    values
        Border output at each node.
    """

    nodes_u: tuple[float, ...]
    values: tuple[float, ...]

    def __post_init__(self) -> None:
        nodes = finite_coefficients("nodes_u", self.nodes_u)
        values = finite_coefficients("values", self.values)
        if len(nodes) < 2:
            raise InvalidInputError(f"nodes_u: expected at least 2 nodes, got {len(nodes)}")
        if len(values) != len(nodes):
            raise InvalidInputError(f"values: expected one value per node ({len(nodes)}), got {len(values)}")
        steps = np.diff(nodes)
        if np.any(steps <= 0.0):
            bad = int(np.flatnonzero(steps <= 0.0)[0]) + 1
            raise InvalidInputError(f"nodes_u: expected strictly increasing nodes, node {bad} is {nodes[bad]!r}")
        object.__setattr__(self, "nodes_u", nodes)
        object.__setattr__(self, "values", values)

    def __call__(self, u: float) -> float:
        return float(np.interp(u, self.nodes_u, self.values))

    def evaluate_list(self, input_rad: list[float]) -> list[float]:
        """The border at each input value (a list in, a list out: the per-sample steppers use it)."""
        return np.interp(np.asarray(input_rad, dtype=float), self.nodes_u, self.values).tolist()


@dataclass(frozen=True)
class ArctanBorder:
    """h(u) = arctan(u + ``input_shift_rad``) + ``output_shift_rad`` for ``lower_input_rad`` < u <=
    ``upper_input_rad``, ``lower_value_rad`` for u <= ``lower_input_rad`` and ``upper_value_rad`` for
    u > ``upper_input_rad`` (u and h in rad, as the borders of :class:`InputBacklash`).

    The borders of the simulation study, Section IV of Pouliquen et al. (2013); see
    :func:`pouliquen2013_backlash` and :func:`pouliquen2013_switch`. With the default infinite limits
    the border is the plain shifted arctangent.
    """

    input_shift_rad: float
    output_shift_rad: float = 0.0
    lower_input_rad: float = -math.inf
    upper_input_rad: float = math.inf
    lower_value_rad: float = 0.0
    upper_value_rad: float = 0.0

    def __post_init__(self) -> None:
        for name in ("input_shift_rad", "output_shift_rad", "lower_value_rad", "upper_value_rad"):
            object.__setattr__(self, name, finite(name, getattr(self, name)))
        lower, upper = float(self.lower_input_rad), float(self.upper_input_rad)
        if math.isnan(lower) or math.isnan(upper) or not lower < upper:
            raise InvalidInputError(
                f"lower_input_rad, upper_input_rad: expected lower < upper, got {lower!r}, {upper!r}")
        object.__setattr__(self, "lower_input_rad", lower)
        object.__setattr__(self, "upper_input_rad", upper)

    def __call__(self, u: float) -> float:
        u = float(u)
        if u <= self.lower_input_rad:
            return self.lower_value_rad
        if u > self.upper_input_rad:
            return self.upper_value_rad
        return math.atan(u + self.input_shift_rad) + self.output_shift_rad

    def evaluate_list(self, input_rad: list[float]) -> list[float]:
        """The border at each input value (a list in, a list out: the per-sample steppers use it)."""
        return [self(v) for v in input_rad]


def pouliquen2013_backlash() -> InputBacklash:
    """The backlash of Section IV.B of Pouliquen et al. (2013): H_a(u) = arctan(u - 1) (ascending),
    H_d(u) = arctan(u + 1) (descending)."""
    return InputBacklash(ascending=ArctanBorder(input_shift_rad=-1.0),
                         descending=ArctanBorder(input_shift_rad=1.0))


def pouliquen2013_switch() -> InputSwitch:
    """The switch of Section IV.A of Pouliquen et al. (2013), with H_0 = (arctan 3 - arctan 1)/2:
    H_a(u) = arctan(u - 1) + H_0 and H_d(u) = arctan(u + 1) - H_0 on (-2, 2], -1 for u <= -2, 1 for u > 2
    (as printed; the two arctangent branches meet at +-2 with value +-1.017, so each border has a jump of
    0.017 there)."""
    h0 = 0.5 * (math.atan(3.0) - math.atan(1.0))
    limits = {"lower_input_rad": -2.0, "upper_input_rad": 2.0, "lower_value_rad": -1.0, "upper_value_rad": 1.0}
    return InputSwitch(
        ascending=ArctanBorder(input_shift_rad=-1.0, output_shift_rad=h0, **limits),
        descending=ArctanBorder(input_shift_rad=1.0, output_shift_rad=-h0, **limits),
    )


def _check_border(name: str, border: Any) -> None:
    if not callable(border):
        raise InvalidInputError(f"{name}: expected a callable border u -> value, got {type(border).__name__}")


@dataclass(frozen=True)
class InputBacklash:
    """Backlash with arbitrary borders at the plant input, Section II of Pouliquen et al. (2013).

    The output follows the ascending border H_a while the input rises and pushes it, the descending border
    H_d while the input falls and pushes it, and holds its last value in between:

    .. math:: v_t = \\min(H_d(u_t), \\max(H_a(u_t), v_{t-1})),

    which, for increasing borders with H_a <= H_d, is the direction form H[u] = delta P_a + (1-delta) P_d
    of eq. (2) with the paths P_a, P_d extended by the horizontal inner segments.

    Parameters
    ----------
    ascending, descending
        Borders H_a and H_d (callables rad -> rad; :class:`PiecewiseLinearBorder` for a node table). The
        output v is the linear block's input; with the linear block normalised to unit static gain (A.2 of
        Pouliquen et al. 2013) it is in rad of the plant output, so the borders' values are in rad.
    initial_output_rad
        v_{-1}, in the borders' unit (rad).
    """

    ascending: Border
    descending: Border
    initial_output_rad: float = 0.0

    def __post_init__(self) -> None:
        _check_border("ascending", self.ascending)
        _check_border("descending", self.descending)
        object.__setattr__(self, "initial_output_rad", finite("initial_output_rad", self.initial_output_rad))

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        u = as_signal("signal", signal).tolist()
        lows = _evaluate_border(self.ascending, u, "ascending")
        highs = _evaluate_border(self.descending, u, "descending")
        v = self.initial_output_rad
        out = []
        append = out.append
        for low, high in zip(lows, highs):
            if v < low:
                v = low
            if v > high:
                v = high
            append(v)
        return np.array(out, dtype=float)

    def stepper(self) -> _InputBacklashStepper:
        return _InputBacklashStepper(self)


class _InputBacklashStepper:
    __slots__ = ("ascending", "descending", "v")

    def __init__(self, block: InputBacklash) -> None:
        self.ascending = block.ascending
        self.descending = block.descending
        self.v = block.initial_output_rad

    def step(self, x: float) -> float:
        x = float(x)
        low = _border_value(self.ascending, x, "ascending")
        high = _border_value(self.descending, x, "descending")
        v = self.v
        if v < low:
            v = low
        if v > high:
            v = high
        self.v = v
        return v


@dataclass(frozen=True)
class InputSwitch:
    """Switch with arbitrary borders at the plant input, Section II of Pouliquen et al. (2013), eq. (2):

    .. math:: H[u_t] = \\delta_t H_a(u_t) + (1 - \\delta_t) H_d(u_t),

    with the direction signal delta_t = 1 if u_t > u_{t-1}, delta_{t-1} if u_t = u_{t-1}, 0 if
    u_t < u_{t-1}. The output jumps from one border to the other when the input reverses.

    Parameters
    ----------
    ascending, descending
        Borders H_a and H_d (callables rad -> rad, as for :class:`InputBacklash`).
    initial_input_rad
        u_{-1} (the rest position).
    initial_ascending
        delta_{-1}.
    """

    ascending: Border
    descending: Border
    initial_input_rad: float = 0.0
    initial_ascending: bool = True

    def __post_init__(self) -> None:
        _check_border("ascending", self.ascending)
        _check_border("descending", self.descending)
        object.__setattr__(self, "initial_input_rad", finite("initial_input_rad", self.initial_input_rad))
        object.__setattr__(self, "initial_ascending", bool(self.initial_ascending))

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        u = as_signal("signal", signal).tolist()
        ups = _evaluate_border(self.ascending, u, "ascending")
        downs = _evaluate_border(self.descending, u, "descending")
        previous = self.initial_input_rad
        ascending = self.initial_ascending
        out = []
        append = out.append
        for u_t, up, down in zip(u, ups, downs):
            if u_t > previous:
                ascending = True
            elif u_t < previous:
                ascending = False
            previous = u_t
            append(up if ascending else down)
        return np.array(out, dtype=float)

    def stepper(self) -> _InputSwitchStepper:
        return _InputSwitchStepper(self)


class _InputSwitchStepper:
    __slots__ = ("ascending", "descending", "previous", "rising")

    def __init__(self, block: InputSwitch) -> None:
        self.ascending = block.ascending
        self.descending = block.descending
        self.previous = block.initial_input_rad
        self.rising = block.initial_ascending

    def step(self, x: float) -> float:
        x = float(x)
        if x > self.previous:
            self.rising = True
        elif x < self.previous:
            self.rising = False
        self.previous = x
        if self.rising:
            return _border_value(self.ascending, x, "ascending")
        return _border_value(self.descending, x, "descending")
