"""The cyclic random excitation of Pouliquen et al. (CDC 2013), Table I, with a leading hold at ``u_min``.

The sequence starts with ``hold_samples`` samples at ``u_min`` (Section III: the mean output over the hold
estimates the offset μ0), then follows Table I forever::

    u(0) = u_min
    step 1: a random value in ]u_min; u_max[   (ascending path)
    step 2: u_max                              (end of the ascending path)
    step 3: a random value in ]u_min; u_max[   (descending path)
    step 4: u_min                              (end of the descending path), back to step 1

so every cycle traverses the whole ascending path and the whole descending path, and an input backlash or
switch is always driven along the same two paths. The random values are uniform on the interval
(Remark 2), which visits every node segment of the border parametrisation (eq. (3)) equally often.

Two forms give the same numbers for the same seed: :func:`cyclic_random_excitation` returns an array, and
:func:`iter_cyclic_random_excitation` yields one sample at a time for a runner that streams set-points.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from identify.validation import InvalidInputError

__all__ = ["cyclic_random_excitation", "iter_cyclic_random_excitation", "SAMPLES_PER_CYCLE"]

SAMPLES_PER_CYCLE = 4
"""Table I has four steps per cycle (random ascending, u_max, random descending, u_min)."""


def _check(input_min_rad: float, input_max_rad: float, hold_samples: int,
           samples_per_step: int) -> tuple[float, float]:
    low, high = float(input_min_rad), float(input_max_rad)
    if not (np.isfinite(low) and np.isfinite(high)):
        raise InvalidInputError(f"input_min_rad, input_max_rad: expected finite numbers, got {input_min_rad!r}, "
                                f"{input_max_rad!r}")
    if not low < high:
        raise InvalidInputError(f"input_min_rad, input_max_rad: expected input_min_rad < input_max_rad, got "
                                f"input_min_rad={low}, input_max_rad={high}")
    if int(hold_samples) != hold_samples or hold_samples < 0:
        raise InvalidInputError(f"hold_samples: expected an integer >= 0, got {hold_samples!r}")
    if int(samples_per_step) != samples_per_step or samples_per_step < 1:
        raise InvalidInputError(f"samples_per_step: expected an integer >= 1, got {samples_per_step!r}")
    return low, high


def _generator(rng: np.random.Generator | int | None) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, (int, np.integer)):
        return np.random.default_rng(rng)
    raise InvalidInputError(f"rng: expected a numpy.random.Generator or an integer seed, got {type(rng).__name__}")


def _strictly_inside(values: NDArray[np.float64], low: float, high: float) -> NDArray[np.float64]:
    # Generator.uniform draws from [low, high); Table I asks for the open interval ]u_min; u_max[.
    return np.clip(values, np.nextafter(low, high), np.nextafter(high, low))


def cyclic_random_excitation(
    num_samples: int,
    input_min_rad: float,
    input_max_rad: float,
    hold_samples: int,
    rng: np.random.Generator | int | None,
    *,
    samples_per_step: int = 1,
) -> NDArray[np.float64]:
    """Return the Table I excitation of Pouliquen et al. (2013) as an array of ``num_samples`` values.

    Parameters
    ----------
    num_samples
        Total length, hold included. The last cycle is cut wherever ``num_samples`` falls.
    input_min_rad, input_max_rad
        The working interval [u_min; u_max] on which the nonlinearity's borders are identified.
    hold_samples
        Samples at ``u_min`` before the cyclic sequence (Section III, estimation of μ0). Table I's own
        initial value u(0) = u_min follows the hold.
    rng
        A ``numpy.random.Generator`` or an integer seed (record it with the experiment).
    samples_per_step
        Each value of Table I is repeated this many times (1 in the paper). A larger value suits a drive
        that cannot follow a new set-point every sample; the direction signal δ(t) of Section II-B keeps
        its value while u(t) = u(t-1), so the lifting is unchanged.

    Returns
    -------
    ndarray
        ``[u_min] * hold_samples`` followed by u(0) = u_min, r1, u_max, r2, u_min, r3, u_max, ... where the r
        are independent and uniform on ]u_min; u_max[ (Remark 2).

    Examples
    --------
    >>> u = cyclic_random_excitation(9, -3.0, 3.0, hold_samples=2, rng=1)
    >>> u[[0, 1, 2, 4, 6, 8]].tolist()
    [-3.0, -3.0, -3.0, 3.0, -3.0, 3.0]
    """
    low, high = _check(input_min_rad, input_max_rad, hold_samples, samples_per_step)
    if int(num_samples) != num_samples or num_samples < 0:
        raise InvalidInputError(f"num_samples: expected an integer >= 0, got {num_samples!r}")
    generator = _generator(rng)
    num_steps = -(-max(int(num_samples) - int(hold_samples), 0) // samples_per_step)
    num_cycles = -(-max(num_steps - 1, 0) // SAMPLES_PER_CYCLE)
    draws = _strictly_inside(generator.uniform(low, high, size=(num_cycles, 2)), low, high)
    cycles = np.empty((num_cycles, SAMPLES_PER_CYCLE))
    cycles[:, 0] = draws[:, 0]
    cycles[:, 1] = high
    cycles[:, 2] = draws[:, 1]
    cycles[:, 3] = low
    steps = np.concatenate(([low], cycles.ravel()))[:num_steps]
    sequence = np.concatenate((np.full(int(hold_samples), low), np.repeat(steps, samples_per_step)))
    return sequence[: int(num_samples)]


def iter_cyclic_random_excitation(
    input_min_rad: float,
    input_max_rad: float,
    hold_samples: int,
    rng: np.random.Generator | int | None,
    *,
    num_samples: int | None = None,
    samples_per_step: int = 1,
) -> Iterator[float]:
    """Yield the Table I excitation sample by sample, forever or for ``num_samples`` samples.

    Same arguments and, for the same seed, the same numbers as :func:`cyclic_random_excitation`; random
    values are drawn one cycle at a time, so a runner can stream set-points for as long as it likes.

    Examples
    --------
    >>> stream = iter_cyclic_random_excitation(-3.0, 3.0, hold_samples=2, rng=1)
    >>> [next(stream) for _ in range(3)]
    [-3.0, -3.0, -3.0]
    """
    low, high = _check(input_min_rad, input_max_rad, hold_samples, samples_per_step)
    if num_samples is not None and (int(num_samples) != num_samples or num_samples < 0):
        raise InvalidInputError(f"num_samples: expected an integer >= 0 or None, got {num_samples!r}")
    generator = _generator(rng)
    return _stream(low, high, int(hold_samples), generator, num_samples, int(samples_per_step))


def _stream(
    low: float, high: float, hold_samples: int, generator: np.random.Generator,
    num_samples: int | None, samples_per_step: int,
) -> Iterator[float]:
    emitted = 0

    def steps() -> Iterator[float]:
        for _ in range(hold_samples):
            yield low
        for _ in range(samples_per_step):
            yield low
        while True:
            draws = _strictly_inside(generator.uniform(low, high, size=(1, 2)), low, high)[0]
            for value in (float(draws[0]), high, float(draws[1]), low):
                for _ in range(samples_per_step):
                    yield value

    for value in steps():
        if num_samples is not None and emitted >= num_samples:
            return
        emitted += 1
        yield value
