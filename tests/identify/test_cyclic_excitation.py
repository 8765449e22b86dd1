"""Table I excitation of Pouliquen et al. (2013): structure, seeding, streaming, errors."""

from __future__ import annotations

import numpy as np
import pytest

from identify.cyclic_excitation import cyclic_random_excitation, iter_cyclic_random_excitation
from identify.validation import InvalidInputError


def test_leading_hold_then_every_cycle_reaches_both_ends_and_randoms_are_strictly_inside() -> None:
    hold = 25
    u = cyclic_random_excitation(hold + 1 + 4 * 500, -3.0, 3.0, hold, rng=7)
    assert np.all(u[: hold + 1] == -3.0)
    cycles = u[hold + 1 :].reshape(-1, 4)
    assert np.all(cycles[:, 1] == 3.0) and np.all(cycles[:, 3] == -3.0)
    randoms = cycles[:, [0, 2]]
    assert np.all((randoms > -3.0) & (randoms < 3.0))
    # Remark 2: uniform on the interval; 1000 draws put about 1/6 in each unit bin (binomial sd ~ 12).
    counts, _ = np.histogram(randoms, bins=6, range=(-3.0, 3.0))
    assert np.all(np.abs(counts - 1000 / 6) < 60)


def test_same_seed_same_sequence_and_different_seed_differs() -> None:
    first = cyclic_random_excitation(400, 0.0, 1.0, 10, rng=3)
    again = cyclic_random_excitation(400, 0.0, 1.0, 10, rng=np.random.default_rng(3))
    other = cyclic_random_excitation(400, 0.0, 1.0, 10, rng=4)
    assert np.array_equal(first, again)
    assert not np.array_equal(first, other)


@pytest.mark.parametrize("num_samples, hold, per_step", [(0, 0, 1), (1, 0, 1), (4003, 7, 1), (61, 3, 3)])
def test_stream_gives_the_array_numbers(num_samples: int, hold: int, per_step: int) -> None:
    array = cyclic_random_excitation(num_samples, -1.0, 2.0, hold, rng=11, samples_per_step=per_step)
    streamed = list(iter_cyclic_random_excitation(-1.0, 2.0, hold, rng=11, num_samples=num_samples,
                                                  samples_per_step=per_step))
    assert np.array_equal(array, np.array(streamed))


def test_unbounded_stream_keeps_cycling() -> None:
    stream = iter_cyclic_random_excitation(-1.0, 1.0, 0, rng=2)
    values = [next(stream) for _ in range(1 + 4 * 1000)]
    assert values[0] == -1.0 and values[-1] == -1.0 and values[-3] == 1.0


def test_samples_per_step_repeats_each_value() -> None:
    u = cyclic_random_excitation(2 + 3 * 9, 0.0, 5.0, 2, rng=0, samples_per_step=3)
    steps = u[2:].reshape(-1, 3)
    assert np.all(steps == steps[:, :1])
    assert steps[:, 0].tolist()[:5:2] == [0.0, 5.0, 0.0]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"input_min_rad": 1.0, "input_max_rad": 1.0}, "input_min_rad < input_max_rad"),
        ({"hold_samples": -1}, "hold_samples"),
        ({"num_samples": 2.5}, "num_samples"),
        ({"rng": "seed"}, "rng"),
        ({"samples_per_step": 0}, "samples_per_step"),
    ],
)
def test_bad_arguments_are_named(kwargs: dict, message: str) -> None:
    arguments = {"num_samples": 10, "input_min_rad": -1.0, "input_max_rad": 1.0, "hold_samples": 0, "rng": 0} | kwargs
    with pytest.raises(InvalidInputError, match=message):
        cyclic_random_excitation(**arguments)
