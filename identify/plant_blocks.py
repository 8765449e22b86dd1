"""The blocks a gearbox model is built from, shared by the simulator and the model-discrepancy workflow.

Every block is a frozen dataclass of parameters with two ways to run it that give bit-identical results:

* ``block.apply(signal)`` runs a whole 1-D array, starting from rest;
* ``block.stepper()`` returns a fresh object whose ``step(x: float) -> float`` advances one sample, so a
  protocol front-end can tick the plant once per SYNC or per received frame.

:class:`PlantModel` chains blocks in signal order (``blocks[0]`` sees the command). Sources:

* Cerone, Piga, Regruto (2009), *Parameter bounds evaluation for linear system with output backlash*:
  eq. (1) linear block :class:`LinearBlock`, eqs. (2)-(3) output backlash :class:`OutputBacklash`;
* Pouliquen et al. (2013), *Subspace identification of Hammerstein systems with nonparametric input
  backlash and switch nonlinearities*, Section II: :class:`InputBacklash` and :class:`InputSwitch` with
  arbitrary borders (the direction signal delta(t) and eq. (2)), and the example borders of Section IV.

The backlash and switch blocks and their borders are defined in :mod:`identify.backlash_blocks` and exported
here with the others.

The remaining blocks (:class:`DeadZone`, :class:`Saturation`, :class:`Delay`, :class:`Resonance`,
:class:`OutputOffset`, :class:`OutputGainDrift`, :class:`CoulombFriction`) are the usual effects a real gearbox adds; their
docstrings give the equation each implements. Angles are in radians throughout.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal as scipy_signal

from identify.backlash_blocks import (ArctanBorder, InputBacklash, InputSwitch, OutputBacklash,
                                      PiecewiseLinearBorder, pouliquen2013_backlash, pouliquen2013_switch)
from identify.validation import InvalidInputError, as_signal, finite, finite_coefficients, positive

__all__ = [
    "ArctanBorder",
    "Block",
    "BlockStepper",
    "CoulombFriction",
    "DeadZone",
    "Delay",
    "EncoderError",
    "InputBacklash",
    "InputSwitch",
    "LinearBlock",
    "OutputBacklash",
    "OutputGain",
    "OutputGainDrift",
    "OutputOffset",
    "PiecewiseLinearBorder",
    "PlantModel",
    "PlantStepper",
    "Resonance",
    "Saturation",
    "pouliquen2013_backlash",
    "pouliquen2013_switch",
]

@runtime_checkable
class BlockStepper(Protocol):
    """Advances one block by one sample."""

    def step(self, x: float) -> float: ...


@runtime_checkable
class Block(Protocol):
    """What :class:`PlantModel` needs from a block."""

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]: ...

    def stepper(self) -> BlockStepper: ...


# ----------------------------------------------------------------------------------------------------------
# Linear dynamics
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LinearBlock:
    """Discrete-time linear block x_t = B(q^-1)/A(q^-1) u_t, eq. (1) of Cerone et al. (2009).

    Parameters
    ----------
    a
        ``(a1, ..., a_na)`` of A(q^-1) = 1 + a1 q^-1 + ... + a_na q^-na (the leading 1 is implied).
    b
        ``(b0, b1, ..., b_nb)`` of B(q^-1) = b0 + b1 q^-1 + ...; leading zeros are a pure delay.
    sample_period_s
        The sample period T the coefficients belong to.

    Examples
    --------
    The linear block of Section 6 of Cerone et al. (2009), with unit static gain eq. (8):

    >>> block = LinearBlock(a=(0.5, 0.7), b=(0.0, 1.4, 0.8), sample_period_s=1.0)
    >>> round(block.static_gain, 12)
    1.0
    """

    a: tuple[float, ...]
    b: tuple[float, ...]
    sample_period_s: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "a", finite_coefficients("a", self.a))
        object.__setattr__(self, "b", finite_coefficients("b", self.b))
        object.__setattr__(self, "sample_period_s", positive("sample_period_s", self.sample_period_s))
        if not self.b:
            raise InvalidInputError("b: expected at least one coefficient b0 of B(q^-1)")

    @classmethod
    def from_state_space(cls, A: ArrayLike, B: ArrayLike, C: ArrayLike, D: ArrayLike,
                         sample_period_s: float) -> LinearBlock:
        """Build the block from a single-input single-output realisation x+ = A x + B u, y = C x + D u
        (the form of eq. (6)-(7) of Pouliquen et al. 2013)."""
        A_matrix = np.atleast_2d(np.asarray(A, dtype=float))
        n = A_matrix.shape[0]
        if A_matrix.shape != (n, n):
            raise InvalidInputError(f"A: expected a square matrix, got shape {A_matrix.shape}")
        B_column = np.asarray(B, dtype=float).reshape(n, 1) if np.size(B) == n else None
        C_row = np.asarray(C, dtype=float).reshape(1, n) if np.size(C) == n else None
        if B_column is None:
            raise InvalidInputError(f"B: expected {n} entries (one input), got shape {np.shape(B)}")
        if C_row is None:
            raise InvalidInputError(f"C: expected {n} entries (one output), got shape {np.shape(C)}")
        if np.size(D) != 1:
            raise InvalidInputError(f"D: expected a scalar (one input, one output), got shape {np.shape(D)}")
        D_value = np.asarray(D, dtype=float).reshape(1, 1)
        for name, matrix in (("A", A_matrix), ("B", B_column), ("C", C_row), ("D", D_value)):
            if not np.all(np.isfinite(matrix)):
                raise InvalidInputError(f"{name}: expected finite entries")
        numerator, denominator = scipy_signal.ss2tf(A_matrix, B_column, C_row, D_value)
        numerator = np.atleast_1d(np.squeeze(numerator))
        b = tuple(float(v) for v in numerator / denominator[0])
        a = tuple(float(v) for v in denominator[1:] / denominator[0])
        return cls(a=a, b=b, sample_period_s=sample_period_s)

    @property
    def static_gain(self) -> float:
        """G(1) = sum(b) / (1 + sum(a)), eq. (8) of Cerone et al. (2009)."""
        denominator = 1.0 + sum(self.a)
        if denominator == 0.0:
            return math.inf
        return sum(self.b) / denominator

    @property
    def poles(self) -> NDArray[np.complex128]:
        """Roots of z^na A(z^-1)."""
        return np.roots((1.0, *self.a)) if self.a else np.array([], dtype=complex)

    def _padded(self) -> tuple[list[float], list[float]]:
        order = max(len(self.a) + 1, len(self.b))
        a = [1.0, *self.a] + [0.0] * (order - len(self.a) - 1)
        b = list(self.b) + [0.0] * (order - len(self.b))
        return a, b

    def to_control(self) -> Any:
        """This block as python-control's discrete-time ``TransferFunction`` (sample time
        :attr:`sample_period_s`; needs ``pip install control``)."""
        from identify.control_systems import discrete_transfer_function

        a, b = self._padded()
        return discrete_transfer_function(b, a, self.sample_period_s, "LinearBlock.to_control()")

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        """Filter a whole signal from rest (direct form II transposed, as :func:`scipy.signal.lfilter`)."""
        u = as_signal("signal", signal)
        a, b = self._padded()
        return scipy_signal.lfilter(b, a, u)

    def stepper(self) -> _LinearStepper:
        a, b = self._padded()
        return _LinearStepper(a, b)


class _LinearStepper:
    """Direct form II transposed, written with the same operation order as scipy's lfilter so that
    stepping and :meth:`LinearBlock.apply` agree to the last bit."""

    __slots__ = ("a", "b", "z")

    def __init__(self, a: list[float], b: list[float]) -> None:
        self.a = a
        self.b = b
        self.z = [0.0] * (len(a) - 1)

    def step(self, x: float) -> float:
        a, b, z = self.a, self.b, self.z
        if not z:
            return x * b[0]
        y = z[0] + b[0] * x
        last = len(z) - 1
        for n in range(last):
            z[n] = z[n + 1] + x * b[n + 1] - y * a[n + 1]
        z[last] = x * b[last + 1] - y * a[last + 1]
        return y


@dataclass(frozen=True)
class Resonance:
    """A lightly damped second-order section with unit static gain, in series with the drive train.

    Continuous prototype H(s) = w_n^2 / (s^2 + 2 zeta w_n s + w_n^2), w_n = 2 pi ``frequency_hz``,
    discretised with the bilinear transform pre-warped at w_n, so the resonance sits exactly at
    ``frequency_hz`` and the static gain is exactly 1; it adds no pure delay (use :class:`Delay` for that).

    Parameters
    ----------
    frequency_hz
        Undamped natural frequency, below the Nyquist frequency 1 / (2 T).
    damping_ratio
        zeta in (0, 1); a lightly damped mode has zeta of a few hundredths.
    sample_period_s
        Sample period T.
    """

    frequency_hz: float
    damping_ratio: float
    sample_period_s: float

    def __post_init__(self) -> None:
        period = positive("sample_period_s", self.sample_period_s)
        frequency = positive("frequency_hz", self.frequency_hz)
        if frequency >= 0.5 / period:
            raise InvalidInputError(
                f"frequency_hz: expected a frequency below the Nyquist frequency {0.5 / period:g} Hz, "
                f"got {frequency:g}"
            )
        damping = finite("damping_ratio", self.damping_ratio)
        if not 0.0 < damping < 1.0:
            raise InvalidInputError(f"damping_ratio: expected 0 < zeta < 1, got {damping:g}")
        object.__setattr__(self, "frequency_hz", frequency)
        object.__setattr__(self, "damping_ratio", damping)
        object.__setattr__(self, "sample_period_s", period)

    def to_linear_block(self) -> LinearBlock:
        """The equivalent :class:`LinearBlock` (A and B of second order)."""
        omega = 2.0 * math.pi * self.frequency_hz
        k = omega / math.tan(omega * self.sample_period_s / 2.0)  # pre-warped bilinear constant
        zeta = self.damping_ratio
        a0 = k * k + 2.0 * zeta * omega * k + omega * omega
        a1 = (2.0 * omega * omega - 2.0 * k * k) / a0
        a2 = (k * k - 2.0 * zeta * omega * k + omega * omega) / a0
        gain = omega * omega / a0
        return LinearBlock(a=(a1, a2), b=(gain, 2.0 * gain, gain), sample_period_s=self.sample_period_s)

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        return self.to_linear_block().apply(signal)

    def stepper(self) -> _LinearStepper:
        return self.to_linear_block().stepper()


# ----------------------------------------------------------------------------------------------------------
# Static input nonlinearities, delay, offset
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DeadZone:
    """Static dead zone with unit slopes: y = u - left if u < left, u - right if u > right, else 0.

    Parameters
    ----------
    left_rad, right_rad
        Edges of the dead band, ``left_rad <= right_rad``.
    """

    left_rad: float
    right_rad: float

    def __post_init__(self) -> None:
        left = finite("left_rad", self.left_rad)
        right = finite("right_rad", self.right_rad)
        if left > right:
            raise InvalidInputError(f"left_rad, right_rad: expected left_rad <= right_rad, got {left:g} > {right:g}")
        object.__setattr__(self, "left_rad", left)
        object.__setattr__(self, "right_rad", right)

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        u = as_signal("signal", signal)
        return np.where(u < self.left_rad, u - self.left_rad, np.where(u > self.right_rad, u - self.right_rad, 0.0))

    def stepper(self) -> _StaticStepper:
        left, right = self.left_rad, self.right_rad

        def step(x: float) -> float:
            x = float(x)
            return x - left if x < left else (x - right if x > right else 0.0)

        return _StaticStepper(step)


@dataclass(frozen=True)
class Saturation:
    """Static saturation (travel limits): y = min(max(u, lower_rad), upper_rad)."""

    lower_rad: float
    upper_rad: float

    def __post_init__(self) -> None:
        lower = finite("lower_rad", self.lower_rad)
        upper = finite("upper_rad", self.upper_rad)
        if lower >= upper:
            raise InvalidInputError(f"lower_rad, upper_rad: expected lower_rad < upper_rad, got {lower:g} >= {upper:g}")
        object.__setattr__(self, "lower_rad", lower)
        object.__setattr__(self, "upper_rad", upper)

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        return np.clip(as_signal("signal", signal), self.lower_rad, self.upper_rad)

    def stepper(self) -> _StaticStepper:
        lower, upper = self.lower_rad, self.upper_rad

        def step(x: float) -> float:
            x = float(x)
            return lower if x < lower else (upper if x > upper else x)

        return _StaticStepper(step)


class _StaticStepper:
    __slots__ = ("step",)

    def __init__(self, step: Callable[[float], float]) -> None:
        self.step = step


@dataclass(frozen=True)
class Delay:
    """Pure delay y_t = u_{t - samples}, with y_t = 0 (rest) for t < samples."""

    samples: int

    def __post_init__(self) -> None:
        if isinstance(self.samples, bool) or not isinstance(self.samples, (int, np.integer)) or self.samples < 0:
            raise InvalidInputError(f"samples: expected an integer >= 0, got {self.samples!r}")
        object.__setattr__(self, "samples", int(self.samples))

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        u = as_signal("signal", signal)
        out = np.zeros_like(u)
        if self.samples < u.size:
            out[self.samples:] = u[: u.size - self.samples]
        return out

    def stepper(self) -> _DelayStepper:
        return _DelayStepper(self.samples)


class _DelayStepper:
    __slots__ = ("buffer",)

    def __init__(self, samples: int) -> None:
        self.buffer: deque[float] = deque([0.0] * samples)

    def step(self, x: float) -> float:
        if not self.buffer:
            return float(x)
        self.buffer.append(float(x))
        return self.buffer.popleft()


@dataclass(frozen=True)
class OutputOffset:
    """Offset and slow linear drift of the measured angle: y_t = x_t + (offset + drift * t T).

    Models a mounting offset of the load encoder and a thermal drift of the zero.
    """

    offset_rad: float
    drift_rad_per_s: float
    sample_period_s: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "offset_rad", finite("offset_rad", self.offset_rad))
        object.__setattr__(self, "drift_rad_per_s", finite("drift_rad_per_s", self.drift_rad_per_s))
        object.__setattr__(self, "sample_period_s", positive("sample_period_s", self.sample_period_s))

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        x = as_signal("signal", signal)
        times = np.arange(x.size, dtype=float) * self.sample_period_s
        return x + (self.offset_rad + self.drift_rad_per_s * times)

    def stepper(self) -> _OffsetStepper:
        return _OffsetStepper(self)


class _OffsetStepper:
    __slots__ = ("offset", "drift", "period", "k")

    def __init__(self, block: OutputOffset) -> None:
        self.offset, self.drift, self.period = block.offset_rad, block.drift_rad_per_s, block.sample_period_s
        self.k = 0

    def step(self, x: float) -> float:
        time = float(self.k) * self.period
        self.k += 1
        return float(x) + (self.offset + self.drift * time)


@dataclass(frozen=True)
class OutputGain:
    """Static gain on the measured angle: y_t = g x_t.

    Models a scale the model has wrong: a gear ratio, an encoder resolution, a stiffness ratio
    (g = 1: none)."""

    gain: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "gain", finite("gain", self.gain))

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        return self.gain * as_signal("signal", signal)

    def stepper(self) -> _StaticStepper:
        gain = self.gain
        return _StaticStepper(lambda x: gain * float(x))


@dataclass(frozen=True)
class OutputGainDrift:
    """A measured angle whose gain and zero settle from their first values towards others with one first-order
    time constant: y_t = (g0 + dg s_t) x_t + dz s_t, s_t = 1 - exp(-t T / tau), t the sample index from the
    record's start.

    Models a sensor whose scale and zero follow its temperature while the rig warms up (the sensitivity of a
    magnetic or inductive sensor, a resolver's excitation amplitude): a temperature that approaches a new
    steady value (Newton's law of cooling) moves the gain by dg and the zero by dz with the time constant tau;
    over a record much shorter than tau both drift linearly, dg t T / tau and dz t T / tau. (A gain drifting
    about an angle A other than the frame's zero is dz = -dg A.)"""

    gain: float
    gain_change: float
    time_constant_s: float
    sample_period_s: float
    zero_change_rad: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "gain", finite("gain", self.gain))
        object.__setattr__(self, "gain_change", finite("gain_change", self.gain_change))
        object.__setattr__(self, "time_constant_s", positive("time_constant_s", self.time_constant_s))
        object.__setattr__(self, "sample_period_s", positive("sample_period_s", self.sample_period_s))
        object.__setattr__(self, "zero_change_rad", finite("zero_change_rad", self.zero_change_rad))

    def settled(self, samples: int) -> NDArray[np.float64]:
        """s_t at samples 0 .. ``samples`` - 1: the share of the change done."""
        return -np.expm1(-np.arange(samples, dtype=float) * self.sample_period_s / self.time_constant_s)

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        x = as_signal("signal", signal)
        s = self.settled(x.size)
        return (self.gain + self.gain_change * s) * x + self.zero_change_rad * s

    def stepper(self) -> _GainDriftStepper:
        return _GainDriftStepper(self)


class _GainDriftStepper:
    __slots__ = ("block", "k")

    def __init__(self, block: OutputGainDrift) -> None:
        self.block, self.k = block, 0

    def step(self, x: float) -> float:
        b = self.block
        s = -math.expm1(-float(self.k) * b.sample_period_s / b.time_constant_s)
        self.k += 1
        return (b.gain + b.gain_change * s) * float(x) + b.zero_change_rad * s


@dataclass(frozen=True)
class EncoderError:
    """Once- and twice-per-revolution error of the angle sensor (an eccentric or tilted encoder disc):
    y_t = x_t + a1 sin(x_t + p1) + a2 sin(2 x_t + p2), x_t the true angle at the sensor (rad).

    A measurement-side effect: the error depends on the angle alone, the same at every speed, and the drive
    never feels it (a load torque of the same shape, gravity, deflects the servo more the softer it is and
    lags in fast moves)."""

    once_per_rev_rad: float
    once_per_rev_phase_rad: float
    twice_per_rev_rad: float = 0.0
    twice_per_rev_phase_rad: float = 0.0

    def __post_init__(self) -> None:
        for name in ("once_per_rev_rad", "once_per_rev_phase_rad", "twice_per_rev_rad", "twice_per_rev_phase_rad"):
            object.__setattr__(self, name, finite(name, getattr(self, name)))

    def _error(self, x: NDArray[np.float64] | float) -> NDArray[np.float64] | float:
        return (self.once_per_rev_rad * np.sin(x + self.once_per_rev_phase_rad)
                + self.twice_per_rev_rad * np.sin(2.0 * x + self.twice_per_rev_phase_rad))

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        x = as_signal("signal", signal)
        return x + self._error(x)

    def stepper(self) -> _StaticStepper:
        return _StaticStepper(lambda x: float(x) + float(self._error(float(x))))


# ----------------------------------------------------------------------------------------------------------
# Friction
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CoulombFriction:
    """Coulomb friction with stiction on a load driven through a compliant coupling (quasi-static).

    The block's input x_t is the angle the drive train imposes; the load angle y_t is connected to it by a
    torsional stiffness k, so the coupling torque is k (x_t - y_{t-1}) before the load moves. The load's
    inertia is neglected at the sample rate (quasi-static), and friction opposes the direction of motion:

    * sliding (the load moved in direction s = +-1 in the previous sample) continues while
      s k (x_t - y_{t-1}) > T_c, with y_t = x_t - s T_c / k (the coupling holds exactly the Coulomb torque);
    * otherwise the load breaks away when |k (x_t - y_{t-1})| > T_s, with s = sign(x_t - y_{t-1}) and
      y_t = x_t - s T_c / k (it slips forward by (T_s - T_c)/k: stick-slip);
    * otherwise it sticks: y_t = y_{t-1}.

    With T_c = T_s this is a play operator of half-width T_s/k (friction plus compliance look like
    backlash); with T_c < T_s it shows stick-slip at every start.

    Parameters
    ----------
    breakaway_torque_nm
        Static friction torque T_s > 0 that must be exceeded to start the load moving.
    coulomb_torque_nm
        Sliding friction torque T_c, 0 <= T_c <= T_s.
    stiffness_nm_per_rad
        Torsional stiffness k > 0 of the coupling between the drive train and the load.
    initial_output_rad
        y_{-1}, the load angle at rest before the first sample.
    """

    breakaway_torque_nm: float
    coulomb_torque_nm: float
    stiffness_nm_per_rad: float
    initial_output_rad: float = 0.0

    def __post_init__(self) -> None:
        breakaway = positive("breakaway_torque_nm", self.breakaway_torque_nm)
        coulomb = finite("coulomb_torque_nm", self.coulomb_torque_nm)
        if not 0.0 <= coulomb <= breakaway:
            raise InvalidInputError(
                f"coulomb_torque_nm: expected 0 <= coulomb_torque_nm <= breakaway_torque_nm ({breakaway:g}), got {coulomb:g}"
            )
        object.__setattr__(self, "breakaway_torque_nm", breakaway)
        object.__setattr__(self, "coulomb_torque_nm", coulomb)
        object.__setattr__(self, "stiffness_nm_per_rad", positive("stiffness_nm_per_rad", self.stiffness_nm_per_rad))
        object.__setattr__(self, "initial_output_rad", finite("initial_output_rad", self.initial_output_rad))

    @property
    def breakaway_deflection_rad(self) -> float:
        """T_s / k: the twist of the coupling at which the load breaks away."""
        return self.breakaway_torque_nm / self.stiffness_nm_per_rad

    @property
    def sliding_deflection_rad(self) -> float:
        """T_c / k: the twist the coupling keeps while the load slides."""
        return self.coulomb_torque_nm / self.stiffness_nm_per_rad

    def apply(self, signal: ArrayLike) -> NDArray[np.float64]:
        # a fresh writable copy: one compiled signature (a read-only input would compile a second one)
        x = np.array(as_signal("signal", signal), dtype=np.float64)
        return _friction_run(x, self.breakaway_deflection_rad, self.sliding_deflection_rad, self.initial_output_rad)

    def stepper(self) -> _FrictionStepper:
        return _FrictionStepper(self)


@numba.njit(cache=True)
def _friction_run(x, stick, slide, y):
    """The loop of :meth:`_FrictionStepper.step` over a whole signal from rest at y_{-1} = ``y`` (the same
    operations in the same order, so the same numbers)."""
    out = np.empty(x.size)
    moving = 0
    for t in range(x.size):
        x_t = x[t]
        twist = x_t - y
        if moving > 0 and twist > slide:
            y = x_t - slide
        elif moving < 0 and -twist > slide:
            y = x_t + slide
        elif twist > stick:
            moving = 1
            y = x_t - slide
        elif -twist > stick:
            moving = -1
            y = x_t + slide
        else:
            moving = 0
        out[t] = y
    return out


class _FrictionStepper:
    __slots__ = ("stick", "slide", "y", "moving")

    def __init__(self, block: CoulombFriction) -> None:
        self.stick = block.breakaway_deflection_rad
        self.slide = block.sliding_deflection_rad
        self.y = block.initial_output_rad
        self.moving = 0  # +1, -1 while sliding, 0 while stuck

    def step(self, x: float) -> float:
        x = float(x)
        twist = x - self.y
        if self.moving > 0 and twist > self.slide:
            self.y = x - self.slide
        elif self.moving < 0 and -twist > self.slide:
            self.y = x + self.slide
        elif twist > self.stick:
            self.moving = 1
            self.y = x - self.slide
        elif -twist > self.stick:
            self.moving = -1
            self.y = x + self.slide
        else:
            self.moving = 0
        return self.y


# ----------------------------------------------------------------------------------------------------------
# The chain
# ----------------------------------------------------------------------------------------------------------


def _check_block(index: int, block: Any) -> None:
    if not (callable(getattr(block, "apply", None)) and callable(getattr(block, "stepper", None))):
        raise InvalidInputError(
            f"blocks[{index}]: expected a plant block with apply() and stepper(), got {type(block).__name__}"
        )


@dataclass(frozen=True)
class PlantModel:
    """A chain of blocks in signal order: ``blocks[0]`` receives the command, the last gives the load angle.

    Examples
    --------
    The simulated example of Section 6 of Cerone et al. (2009): linear block, then output backlash.

    >>> plant = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0),
    ...                     OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))
    >>> step_filter = LinearBlock(a=(-0.8125,), b=(0.0, 0.1875), sample_period_s=1.0)  # F(z), Section 3.1
    >>> y = plant.simulate(step_filter.apply(np.ones(300)))
    >>> round(float(y[-1]), 4)  # m_r (1 - c_r), eq. (11), when x_t does not overshoot
    0.2432
    """

    blocks: tuple[Block, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        blocks = tuple(self.blocks)
        for index, block in enumerate(blocks):
            _check_block(index, block)
        object.__setattr__(self, "blocks", blocks)
        periods = {(type(b).__name__, b.sample_period_s) for b in blocks if hasattr(b, "sample_period_s")}
        values = [period for _, period in periods]
        if values and not all(math.isclose(period, values[0], rel_tol=1e-9) for period in values):
            described = ", ".join(f"{name} {period:g} s" for name, period in sorted(periods))
            raise InvalidInputError(f"blocks: the sample periods of the blocks differ ({described})")

    @property
    def sample_period_s(self) -> float | None:
        """The sample period shared by the blocks that have one, or None if no block has one."""
        for block in self.blocks:
            period = getattr(block, "sample_period_s", None)
            if period is not None:
                return float(period)
        return None

    def simulate(self, command_rad: ArrayLike) -> NDArray[np.float64]:
        """Run a whole command signal (rad) through the chain from rest and return the output (rad)."""
        y = as_signal("command_rad", command_rad)
        for block in self.blocks:
            y = block.apply(y)
        return np.asarray(y, dtype=float)

    def stepper(self) -> PlantStepper:
        """A fresh stepper at rest; ``stepper().step(u_t)`` repeated gives :meth:`simulate` bit for bit."""
        return PlantStepper(tuple(block.stepper() for block in self.blocks))

    def with_block(self, block: Block, index: int | None = None) -> PlantModel:
        """A new model with ``block`` inserted before position ``index`` (appended if None)."""
        blocks = list(self.blocks)
        if index is None:
            blocks.append(block)
        else:
            if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index <= len(blocks):
                raise InvalidInputError(f"index: expected an integer from 0 to {len(blocks)}, got {index!r}")
            blocks.insert(int(index), block)
        return PlantModel(tuple(blocks))

    def without(self, block_type: type) -> PlantModel:
        """A new model with every block of ``block_type`` removed; raises if there is none."""
        kept = tuple(block for block in self.blocks if not isinstance(block, block_type))
        if len(kept) == len(self.blocks):
            present = ", ".join(type(block).__name__ for block in self.blocks) or "no blocks"
            raise InvalidInputError(f"block_type: the model has no {block_type.__name__} (it has {present})")
        return PlantModel(kept)

    def find(self, block_type: type) -> tuple[Block, ...]:
        """The blocks of ``block_type``, in signal order."""
        return tuple(block for block in self.blocks if isinstance(block, block_type))


class PlantStepper:
    """Advances a :class:`PlantModel` one sample per :meth:`step`."""

    __slots__ = ("_steps", "_motor", "samples")

    def __init__(self, steppers: tuple[BlockStepper, ...]) -> None:
        self._steps = tuple(stepper.step for stepper in steppers)
        self._motor = next((stepper for stepper in steppers if hasattr(stepper, "motor_torque_nm")), None)
        self.samples = 0

    @property
    def motor_torque_nm(self) -> float | None:
        """The motor's torque at the start of the last sample, from the first block that models a motor (a
        :class:`~identify.drive_train.DriveTrain`), or None for a plant without one."""
        return None if self._motor is None else float(self._motor.motor_torque_nm)

    def step(self, u_t: float) -> float:
        """Feed one command sample (rad) and return the output sample (rad)."""
        y = float(u_t)
        if not math.isfinite(y):
            raise InvalidInputError(f"u_t: sample {self.samples} is {u_t!r}; expected a finite angle in rad")
        for step in self._steps:
            y = step(y)
        self.samples += 1
        return y
