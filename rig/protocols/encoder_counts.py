"""The one place where encoder counts and radians convert (docs/design.md, "Counts and radians convert in
one place").

An n-bit absolute encoder divides one revolution into 2**n counts; a multi-turn encoder adds m bits that
count whole revolutions, so the position value wraps at 2**(n + m), as the CiA 406 position value does.
The simulated encoder (:mod:`sim_backend.plant`) turns the load angle into counts with
:meth:`EncoderResolution.counts_from_rad`; every transport codec turns the counts it receives back into
radians with :meth:`EncoderResolution.rad_from_counts`.

Quantisation rounds to the nearest count, so a reading is within half a count, ``pi / 2**n`` rad, of the
angle; the bounded-error methods take one full count ``2 pi / 2**n`` as the conservative bound of the
project's conventions (DESIGN.md section 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.validation import InvalidInputError

__all__ = ["EncoderResolution"]


@dataclass(frozen=True)
class EncoderResolution:
    """Resolution and counting convention of an absolute encoder.

    Parameters
    ----------
    bits
        Single-turn resolution n: 2**n counts per revolution (1..32).
    multi_turn_bits
        Bits m of the revolution counter (0 for a single-turn encoder); the position value wraps at
        2**(n + m), total at most 48 bits.
    signed
        Whether the device reports the position value as a two's-complement number, i.e. in
        [-2**(n+m-1), 2**(n+m-1)) instead of [0, 2**(n+m)). Decoded angles lie in [-R/2, R/2) resp.
        [0, R), with R = 2 pi 2**m the angle range.
    direction
        +1 if counts increase with the load angle, -1 if the device counts the other way (CiA 406 "code
        sequence").
    offset_counts
        Position value reported at zero load angle (the CiA 406 preset / zero offset), in [0, 2**(n+m)).

    Examples
    --------
    >>> encoder = EncoderResolution(bits=12)
    >>> encoder.counts_from_rad(math.pi / 2)
    1024
    >>> encoder.counts_from_rad(-0.001)  # wraps below zero
    4095
    >>> round(encoder.rad_from_counts(4095, near_rad=0.0), 6)
    -0.001534
    """

    bits: int
    multi_turn_bits: int = 0
    signed: bool = False
    direction: int = 1
    offset_counts: int = 0

    def __post_init__(self) -> None:
        for name, low, high in (("bits", 1, 32), ("multi_turn_bits", 0, 32)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
                raise InvalidInputError(f"{name}: expected an integer from {low} to {high}, got {value!r}")
            object.__setattr__(self, name, int(value))
        if self.bits + self.multi_turn_bits > 48:
            raise InvalidInputError(
                f"bits + multi_turn_bits: expected at most 48 bits in all, got {self.bits + self.multi_turn_bits}"
            )
        if not isinstance(self.signed, (bool, np.bool_)):
            raise InvalidInputError(f"signed: expected true or false, got {self.signed!r}")
        object.__setattr__(self, "signed", bool(self.signed))
        if self.direction not in (1, -1) or isinstance(self.direction, bool):
            raise InvalidInputError(f"direction: expected +1 or -1, got {self.direction!r}")
        object.__setattr__(self, "direction", int(self.direction))
        offset = self.offset_counts
        modulus = 1 << (self.bits + self.multi_turn_bits)
        if isinstance(offset, bool) or not isinstance(offset, (int, np.integer)) or not 0 <= offset < modulus:
            raise InvalidInputError(f"offset_counts: expected an integer from 0 to {modulus - 1}, got {offset!r}")
        object.__setattr__(self, "offset_counts", int(offset))
        # derived constants, cached because a simulated device converts one sample per SYNC
        object.__setattr__(self, "_modulus", 1 << (self.bits + self.multi_turn_bits))
        object.__setattr__(self, "_count_rad", 2.0 * math.pi / (1 << self.bits))

    @property
    def counts_per_revolution(self) -> int:
        """2**n."""
        return 1 << self.bits

    @property
    def modulus(self) -> int:
        """2**(n + m): the position value wraps here."""
        return self._modulus

    @property
    def count_rad(self) -> float:
        """One count in radians, 2 pi / 2**n."""
        return self._count_rad

    @property
    def quantization_bound_rad(self) -> float:
        """Largest distance between an angle and its decoded reading: half a count, pi / 2**n."""
        return 0.5 * self.count_rad

    @property
    def range_rad(self) -> float:
        """The angle range before the position value wraps, 2 pi 2**m."""
        return self.count_rad * self.modulus

    @overload
    def counts_from_rad(self, angle_rad: float) -> int: ...

    @overload
    def counts_from_rad(self, angle_rad: NDArray[np.float64]) -> NDArray[np.int64]: ...

    def counts_from_rad(self, angle_rad: float | ArrayLike) -> int | NDArray[np.int64]:
        """Position value the device reports for the load angle ``angle_rad``: rounded to the nearest count,
        counted in ``direction``, shifted by ``offset_counts`` and wrapped at 2**(n+m) (and two's-complement
        if ``signed``). Accepts a float (returns an int) or an array (returns an int64 array)."""
        if isinstance(angle_rad, (float, int)) and not isinstance(angle_rad, bool):
            return self._counts_from_float(float(angle_rad))
        angle = np.asarray(angle_rad, dtype=float)
        if not np.all(np.isfinite(angle)):
            raise InvalidInputError(f"angle_rad: expected finite angles, got {angle_rad!r}")
        raw = np.rint(self.direction * angle / self.count_rad)
        counts = (np.mod(raw, float(self.modulus)).astype(np.int64) + self.offset_counts) % self.modulus
        if self.signed:
            half = self.modulus >> 1
            counts = np.where(counts >= half, counts - self.modulus, counts)
        if counts.ndim == 0:
            return int(counts)
        return counts

    def _counts_from_float(self, angle: float) -> int:
        # The same operations as the array path, in Python numbers (round() rounds half to even like
        # numpy.rint), so one sample at a time gives the same counts, about 20 times faster.
        if not math.isfinite(angle):
            raise InvalidInputError(f"angle_rad: expected finite angles, got {angle!r}")
        modulus = self._modulus
        counts = (round(self.direction * angle / self._count_rad) % modulus + self.offset_counts) % modulus
        if self.signed and counts >= modulus >> 1:
            counts -= modulus
        return counts

    def _rad_from_int(self, counts: int, near_rad: float | None) -> float:
        low = -(self.modulus >> 1) if self.signed else 0
        if not low <= counts < low + self.modulus:
            raise InvalidInputError(
                f"counts: expected position values from {low} to {low + self.modulus - 1} "
                f"({self.bits}+{self.multi_turn_bits} bits, {'signed' if self.signed else 'unsigned'}), got {counts!r}"
            )
        relative = (counts - self.offset_counts) % self.modulus
        if self.direction < 0:
            relative = (-relative) % self.modulus
        if self.signed and relative >= self.modulus >> 1:
            relative -= self.modulus
        angle = float(relative) * self.count_rad
        if near_rad is not None:
            angle = angle + float(round((float(near_rad) - angle) / self.range_rad)) * self.range_rad
        return angle

    @overload
    def rad_from_counts(self, counts: int, near_rad: float | None = None) -> float: ...

    @overload
    def rad_from_counts(self, counts: ArrayLike, near_rad: float | ArrayLike | None = None) -> NDArray[np.float64]: ...

    def rad_from_counts(self, counts: int | ArrayLike,
                        near_rad: float | ArrayLike | None = None) -> float | NDArray[np.float64]:
        """Load angle of a position value: undoes the offset and the direction; the result lies in
        [0, R) (unsigned) or [-R/2, R/2) (signed), R = :attr:`range_rad`.

        ``near_rad`` picks, instead, the equivalent angle (modulo R) nearest to it, e.g. the previous
        reading, so that a load that turns past the wrap keeps a continuous angle.
        """
        if isinstance(counts, (int, np.integer)) and not isinstance(counts, bool) and (
                near_rad is None or isinstance(near_rad, (float, int))):
            return self._rad_from_int(int(counts), near_rad)
        values = np.asarray(counts)
        if values.dtype.kind not in "iu" and not (values.dtype.kind == "f" and np.all(values == np.round(values))):
            raise InvalidInputError(f"counts: expected integer position values, got {counts!r}")
        values = values.astype(np.int64)
        low = -(self.modulus >> 1) if self.signed else 0
        if np.any(values < low) or np.any(values >= low + self.modulus):
            raise InvalidInputError(
                f"counts: expected position values from {low} to {low + self.modulus - 1} "
                f"({self.bits}+{self.multi_turn_bits} bits, {'signed' if self.signed else 'unsigned'}), got {counts!r}"
            )
        relative = (values - self.offset_counts) % self.modulus
        if self.direction < 0:
            relative = (-relative) % self.modulus
        if self.signed:
            relative = np.where(relative >= (self.modulus >> 1), relative - self.modulus, relative)
        angle = relative.astype(float) * self.count_rad
        if near_rad is not None:
            near = np.asarray(near_rad, dtype=float)
            angle = angle + np.round((near - angle) / self.range_rad) * self.range_rad
        if angle.ndim == 0:
            return float(angle)
        return angle
