"""Measurement noise added to the load angle before the encoder quantises it.

Four models, each a frozen dataclass that states its bound (``noise_bound_rad``) so that a log can record it:

* :class:`NoNoise` -- quantisation only: the encoder's rounding is the only error (bound 0 here; the
  encoder adds half a count);
* :class:`BoundedUniformNoise` -- eta_t ~ U[-d, d], the bounded-error setting of Cerone et al. (2009),
  eqs. (4)-(5) and Section 6;
* :class:`GaussianNoise` -- white Gaussian noise (bound infinite), given by its standard deviation or by a
  signal-to-noise ratio;
* :class:`ColouredNoise` -- v_t = G_v(q) e_t, Gaussian e_t filtered, the setting of Pouliquen et al.
  (2013), Section IV, with G_v(q) = (1 + 0.5 q^-1) / (1 - 0.85 q^-1) by default; its standard deviation
  is that of v_t itself.

Randomness comes from a :class:`numpy.random.Generator`. ``model.sampler(rng)`` returns a sampler whose
``next()`` draws one sample and ``draw(n)`` draws n; any interleaving of the two gives the same sequence,
so a simulated device ticked sample by sample and an offline whole-array run agree exactly.

SNR is 10 log10(var(w) / var(v)) with w the noise-free output; :meth:`GaussianNoise.for_snr` turns it into a
standard deviation given w.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal as scipy_signal

from identify.plant_blocks import LinearBlock
from identify.validation import InvalidInputError, as_signal, positive

__all__ = [
    "BoundedUniformNoise",
    "ColouredNoise",
    "GaussianNoise",
    "NoNoise",
    "NoiseModel",
    "NoiseSampler",
    "std_for_snr",
]

_CHUNK = 4096


def std_for_snr(clean_output: ArrayLike, snr_db: float) -> float:
    """Noise standard deviation that gives ``snr_db`` = 10 log10(var(w) / sigma^2) on the noise-free output w."""
    w = as_signal("clean_output", clean_output, min_samples=2)
    snr = float(snr_db)
    if not math.isfinite(snr):
        raise InvalidInputError(f"snr_db: expected a finite number of dB, got {snr_db!r}")
    variance = float(np.var(w))
    if variance == 0.0:
        raise InvalidInputError("clean_output: the noise-free output is constant, so an SNR cannot set the noise level")
    return math.sqrt(variance / 10.0 ** (snr / 10.0))


@runtime_checkable
class NoiseSampler(Protocol):
    def next(self) -> float: ...

    def draw(self, num_samples: int) -> NDArray[np.float64]: ...


@runtime_checkable
class NoiseModel(Protocol):
    kind: str

    @property
    def noise_bound_rad(self) -> float: ...

    def sampler(self, rng: np.random.Generator) -> NoiseSampler: ...


class _ChunkedSampler:
    """Draws the white sequence in chunks (a Generator gives the same numbers whether asked for one at a
    time or for an array), optionally colours it with a :class:`LinearBlock` stepper."""

    def __init__(self, white: Callable[[int], NDArray[np.float64]], colour: LinearBlock | None) -> None:
        self._white = white
        self._buffer: list[float] = []
        self._position = 0
        self._colour = colour.stepper() if colour is not None else None

    def _white_samples(self, num_samples: int) -> NDArray[np.float64]:
        out = np.empty(num_samples)
        filled = 0
        while filled < num_samples:
            if self._position == len(self._buffer):
                self._buffer = self._white(_CHUNK).tolist()
                self._position = 0
            take = min(num_samples - filled, len(self._buffer) - self._position)
            out[filled:filled + take] = self._buffer[self._position:self._position + take]
            self._position += take
            filled += take
        return out

    def next(self) -> float:
        if self._position == len(self._buffer):
            self._buffer = self._white(_CHUNK).tolist()
            self._position = 0
        value = self._buffer[self._position]
        self._position += 1
        return self._colour.step(value) if self._colour is not None else value

    def draw(self, num_samples: int) -> NDArray[np.float64]:
        if num_samples < 0:
            raise InvalidInputError(f"num_samples: expected an integer >= 0, got {num_samples}")
        white = self._white_samples(num_samples)
        if self._colour is None:
            return white
        step = self._colour.step
        return np.array([step(value) for value in white.tolist()], dtype=float)


class _ZeroSampler:
    def next(self) -> float:
        return 0.0

    def draw(self, num_samples: int) -> NDArray[np.float64]:
        return np.zeros(num_samples)


@dataclass(frozen=True)
class NoNoise:
    """Quantisation only: no additive noise; the encoder's rounding (half a count) is the only error."""

    kind: str = "quantization"

    @property
    def noise_bound_rad(self) -> float:
        return 0.0

    def sampler(self, rng: np.random.Generator) -> _ZeroSampler:
        return _ZeroSampler()


@dataclass(frozen=True)
class BoundedUniformNoise:
    """eta_t ~ U[-bound_rad, bound_rad], i.i.d.: |eta_t| <= Delta eta, eq. (5) of Cerone et al. (2009)."""

    bound_rad: float
    kind: str = "uniform"

    def __post_init__(self) -> None:
        object.__setattr__(self, "bound_rad", positive("bound_rad", self.bound_rad))

    @property
    def noise_bound_rad(self) -> float:
        return self.bound_rad

    def sampler(self, rng: np.random.Generator) -> _ChunkedSampler:
        bound = self.bound_rad
        return _ChunkedSampler(lambda n: rng.uniform(-bound, bound, size=n), None)


@dataclass(frozen=True)
class GaussianNoise:
    """White Gaussian noise with standard deviation ``std_rad``; or, with ``snr_db`` instead, a level still
    to be fixed from the noise-free output by :meth:`resolved` (the bound is infinite either way)."""

    std_rad: float | None = None
    snr_db: float | None = None
    kind: str = "gaussian"

    def __post_init__(self) -> None:
        _check_level(self.std_rad, self.snr_db)

    @property
    def noise_bound_rad(self) -> float:
        return math.inf

    @classmethod
    def for_snr(cls, clean_output: ArrayLike, snr_db: float) -> GaussianNoise:
        return cls(std_rad=std_for_snr(clean_output, snr_db), snr_db=snr_db)

    @property
    def needs_reference(self) -> bool:
        """True while the level is given only as an SNR."""
        return self.std_rad is None

    def resolved(self, clean_output: ArrayLike) -> GaussianNoise:
        """This model with ``std_rad`` fixed from the SNR and the noise-free output (unchanged if set)."""
        if self.std_rad is not None:
            return self
        return replace(self, std_rad=std_for_snr(clean_output, self.snr_db))

    def sampler(self, rng: np.random.Generator) -> _ChunkedSampler:
        std = _require_std(self)
        return _ChunkedSampler(lambda n: rng.normal(0.0, std, size=n), None)


@dataclass(frozen=True)
class ColouredNoise:
    """v_t = G_v(q) e_t with e_t white Gaussian, scaled so that v_t has standard deviation ``std_rad``
    (stationary); Pouliquen et al. (2013), Section IV. ``numerator``/``denominator`` are the coefficients
    of G_v in q^-1, the denominator with its leading 1."""

    std_rad: float | None = None
    snr_db: float | None = None
    numerator: tuple[float, ...] = (1.0, 0.5)
    denominator: tuple[float, ...] = (1.0, -0.85)
    kind: str = "coloured"

    def __post_init__(self) -> None:
        _check_level(self.std_rad, self.snr_db)
        numerator = tuple(float(v) for v in self.numerator)
        denominator = tuple(float(v) for v in self.denominator)
        if not denominator or denominator[0] != 1.0:
            raise InvalidInputError(f"denominator: expected coefficients starting with 1, got {denominator!r}")
        if not numerator or not all(math.isfinite(v) for v in numerator + denominator):
            raise InvalidInputError("numerator, denominator: expected finite coefficients")
        if np.any(np.abs(np.roots(denominator)) >= 1.0):
            raise InvalidInputError(f"denominator: G_v must be stable (poles inside the unit circle), got {denominator!r}")
        object.__setattr__(self, "numerator", numerator)
        object.__setattr__(self, "denominator", denominator)

    @property
    def noise_bound_rad(self) -> float:
        return math.inf

    @property
    def filter_gain(self) -> float:
        """sqrt(sum h_k^2), the H2 norm of G_v: std(v) = filter_gain * std(e)."""
        _, impulse = scipy_signal.dimpulse((self.numerator, self.denominator, 1.0), n=4000)
        return float(np.sqrt(np.sum(np.square(impulse[0]))))

    @property
    def needs_reference(self) -> bool:
        return self.std_rad is None

    def resolved(self, clean_output: ArrayLike) -> ColouredNoise:
        if self.std_rad is not None:
            return self
        return replace(self, std_rad=std_for_snr(clean_output, self.snr_db))

    def sampler(self, rng: np.random.Generator) -> _ChunkedSampler:
        white_std = _require_std(self) / self.filter_gain
        colour = LinearBlock(a=self.denominator[1:], b=self.numerator, sample_period_s=1.0)
        return _ChunkedSampler(lambda n: rng.normal(0.0, white_std, size=n), colour)


def _check_level(std_rad: float | None, snr_db: float | None) -> None:
    if std_rad is None and snr_db is None:
        raise InvalidInputError("std_rad, snr_db: give the noise level as std_rad or as snr_db")
    if std_rad is not None:
        positive("std_rad", std_rad)
    if snr_db is not None and not math.isfinite(float(snr_db)):
        raise InvalidInputError(f"snr_db: expected a finite number of dB, got {snr_db!r}")


def _require_std(model: GaussianNoise | ColouredNoise) -> float:
    if model.std_rad is None:
        raise InvalidInputError(
            f"{model.kind} noise given as snr_db={model.snr_db:g} needs the noise-free output to set its level: "
            "call resolved(clean_output) first (SimulatedGearbox.simulate does this for you)"
        )
    return float(model.std_rad)
