"""Intervals of effects named on a plant the model's structure cannot follow: a record of the clean-room
generator (``benchmarks/independent_plants``, used as a data source only: a two-mass drive train with a 30.8 Hz
shaft mode behind a stiff servo) with Coulomb friction on the load, which the workflow names as load friction
in a rigid train. The benchmark's own case runner scores it (``model_discrepancy_confusion.run_independent_case``:
the generator's truth in the terms of the effect named)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))
import model_discrepancy_confusion as confusion  # noqa: E402


@pytest.mark.slow
def test_the_intervals_of_a_friction_named_in_a_rigid_train_hold_the_generators_truth():
    # seed 1006, multisine: the rigid train cannot hold the shaft mode, 17 % of the validation samples stay
    # outside the noise bound. The fold refits alone gave a viscous damping of [3.3e-8, 5.3] 1/s on the load
    # where the generator has none (0): the structure error moved it, the refits shared the bias
    case = confusion.run_independent_case("coulomb", 0, 1, 1006, "given", ("multisine",),
                                          confusion.INDEPENDENT_DURATION_S, 1, 12, confusion.NOISE_STD_RAD)
    assert case["seed"] == 1006 and "load_friction" in case["named"], case
    assert case["covered"] == [3, 3], case["missed"]


@pytest.mark.slow
def test_a_friction_whose_static_error_is_under_half_the_bound_but_moves_the_record_is_named():
    # seed 1005, chirp: Coulomb friction on the load peaking at 0.89 counts (1.37 mrad, the bound 1.217 mrad).
    # The fitted load friction lowered the validated gap by 28-33 %, but its static error through the shaft was
    # 0.5 mrad, under half the bound, so the catalogue's size test called it nothing: `unexplained`. Taking it
    # out of the fitted model moves the free run by more than half the bound: it is there.
    case = confusion.run_independent_case("coulomb", 0, 1, 1005, "given", ("chirp",),
                                          confusion.INDEPENDENT_DURATION_S, 1, 12, confusion.NOISE_STD_RAD)
    assert case["seed"] == 1005 and case["effect_size_counts"] < 1.0
    assert case["outcome"] == "right" and case["named"] == ["load_friction"], case.get("reason")
    assert case["covered"][1] == 3 and case["covered"][0] == 3, case["missed"]
