"""Records with samples not measured (NaN: LOST, or unusable by their flags): every method sets them aside as
the mathematics allows and still holds the truth, with 0.1 %, 1 % and a burst of samples missing."""

from __future__ import annotations

import numpy as np
import pytest

from identify.border_lifting import PathNodes
from identify.cyclic_excitation import cyclic_random_excitation
from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.hammerstein_subspace import complete_windows, identify_hammerstein
from identify.output_backlash_identification import bound_output_backlash_system
from identify.plant_blocks import InputBacklash, LinearBlock, OutputBacklash, PiecewiseLinearBorder, PlantModel
from identify.validation import InvalidInputError

PATTERNS = {"0.1 %": ("random", 0.001), "1 %": ("random", 0.01), "burst": ("burst", 50)}


def missing(y: np.ndarray, pattern: str, seed: int = 7) -> np.ndarray:
    """``y`` with the samples of ``pattern`` NaN: a random fraction, or a burst in the middle."""
    kind, size = PATTERNS[pattern]
    out = y.copy()
    if kind == "random":
        out[np.random.default_rng(seed).choice(y.size, max(1, int(size * y.size)), replace=False)] = np.nan
    else:
        out[y.size // 2: y.size // 2 + size] = np.nan
    return out


# --- set membership (Cerone et al. 2009) -------------------------------------------------------------------

LINEAR = {"a1": 0.5, "a2": 0.7, "b1": 1.4, "b2": 0.8}
CERONE = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))


@pytest.fixture(scope="module")
def cerone_data():
    rng = np.random.default_rng(0)
    noise = 2 * np.pi / 2**12
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    u = prbs_sequence(600, 1.0, rng=1)
    y = CERONE.simulate(u) + rng.uniform(-noise, noise, u.size)
    steady_y = CERONE.simulate(staircase)[steady] + rng.uniform(-noise, noise, steady.size)
    return staircase[steady], steady_y, u, y, noise


@pytest.mark.parametrize("pattern", list(PATTERNS))
@pytest.mark.parametrize("method", ["paper", "coupled"])
def test_set_membership_bounds_hold_the_truth_with_samples_missing(cerone_data, pattern, method):
    steady_u, steady_y, u, y, noise = cerone_data
    result = bound_output_backlash_system(steady_u, steady_y, u, missing(y, pattern), noise, na=2, nk=1, nb=2,
                                          method=method, partition_samples=0)
    for name, interval in result.linear_intervals.items():
        assert interval.lower <= LINEAR[name] <= interval.upper, (name, interval)
    lost = np.isnan(missing(y, pattern))
    assert np.all(np.isnan(result.inner_signal.lower_rad[lost])) and not np.any(result.inner_signal.invertible[lost])


def test_set_membership_refuses_too_few_complete_equations_saying_how_many(cerone_data):
    steady_u, steady_y, u, y, noise = cerone_data
    y = y.copy()
    y[::2] = np.nan  # every equation needs x_t, x_{t-1}, x_{t-2}: none is complete
    with pytest.raises(InvalidInputError, match=r"give 0 equations.*300 samples without an inner-signal bound.*set "
                                                r"aside 598 of the 598 equations; the orders are too high for the "
                                                r"data \(at least 8 equations are needed\)"):
        bound_output_backlash_system(steady_u, steady_y, u, y, noise, na=2, nk=1, nb=2, method="paper")


# --- Hammerstein subspace (Pouliquen et al. 2013) ----------------------------------------------------------

NODES = tuple(np.linspace(-3.0, 3.0, 8).tolist())
H_A = np.array((-1.0, -0.9, -0.7, -0.4, 0.0, 0.4, 0.8, 1.0))
H_D = np.array((-1.0, -0.6, -0.2, 0.2, 0.5, 0.75, 0.9, 1.0))
HOLD = 100


@pytest.fixture(scope="module")
def cyclic_data():
    u = cyclic_random_excitation(HOLD + 2500, -3.0, 3.0, HOLD, rng=3)
    plant = PlantModel((InputBacklash(PiecewiseLinearBorder(NODES, tuple(H_A)), PiecewiseLinearBorder(NODES, tuple(H_D)),
                                      initial_output_rad=-1.0),
                        LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=0.01)))
    y = plant.simulate(u) + 0.5 + np.random.default_rng(1).uniform(-1e-3, 1e-3, u.size)
    return u, y


def border_error(model) -> float:
    return max(float(np.max(np.abs(np.array(model.ascending_border.values) - H_A - 0.5))),
               float(np.max(np.abs(np.array(model.descending_border.values) - H_D - 0.5))))


@pytest.mark.parametrize("pattern", list(PATTERNS))
def test_hammerstein_borders_are_as_good_with_samples_missing(cyclic_data, pattern):
    u, y = cyclic_data
    complete = identify_hammerstein(u, y, PathNodes(NODES, NODES), hold_samples=HOLD, order=2)
    lossy_y = missing(y, pattern)
    lossy = identify_hammerstein(u, lossy_y, PathNodes(NODES, NODES), hold_samples=HOLD, order=2, refine=True)
    assert border_error(lossy) <= max(1.5 * border_error(complete), 1e-3)
    assert np.isfinite(lossy.fit_percent) and lossy.fit_percent > 99.0
    assert lossy.num_columns == int(np.count_nonzero(complete_windows(lossy_y, 30))) < complete.num_columns


def test_hammerstein_refuses_too_few_complete_windows_saying_how_many(cyclic_data):
    u, y = cyclic_data
    y = y.copy()
    y[HOLD::20] = np.nan  # most windows of 30 samples hold one (those in the hold do not)
    with pytest.raises(InvalidInputError, match=r"125 of the 2600 outputs are missing.*leaves 71 complete windows of p \+ f = 30 samples.*at least 435"):
        identify_hammerstein(u, y, PathNodes(NODES, NODES), hold_samples=HOLD, order=2)


def test_complete_windows_marks_the_windows_without_a_missing_sample():
    y = np.array([0.0, 1.0, np.nan, 3.0, 4.0, 5.0])
    assert complete_windows(y, 2).tolist() == [True, False, False, True, True]
