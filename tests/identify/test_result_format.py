"""Every result type saves itself and reads itself back (``to_dict``/``from_dict`` with ``kind`` and
``version``): a result saved as JSON and reopened equals the original; another kind or version is named."""

from __future__ import annotations

import json

import numpy as np
import pytest

from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.feasible_parameter_set import BacklashFeasibleSet
from identify.inner_signal_bounds import InnerSignalBounds
from identify.linear_block_bounds import LinearBlockBounds
from identify.output_backlash_identification import OutputBacklashIdentification, bound_output_backlash_system
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
from identify.result_format import ResultFormatError

PLANT = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0), OutputBacklash(0.248, 0.0698, 0.252, 0.0349)))


def _identify(method: str = "coupled", steady_noise: float = 0.0) -> OutputBacklashIdentification:
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    u = prbs_sequence(100, 1.0, rng=1)
    y_steady = PLANT.simulate(staircase)[steady] + steady_noise * np.resize([1.0, -1.0, 0.0], steady.size)
    return bound_output_backlash_system(staircase[steady], y_steady, u, PLANT.simulate(u), 1e-5, na=2, nk=1, nb=2,
                                        method=method)


def _reopened(document: dict) -> dict:
    return json.loads(json.dumps(document))


@pytest.fixture(scope="module")
def result() -> OutputBacklashIdentification:
    return _identify()


def _same_arrays(first, second) -> None:
    for name in first.__dataclass_fields__:
        a, b = getattr(first, name), getattr(second, name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a, b), name
        else:
            assert a == b, name


def test_an_output_backlash_result_saved_and_reopened_equals_the_original(result) -> None:
    document = result.to_dict()
    assert document["kind"] == "output_backlash" and document["version"] == 1
    # the documented keys stay
    assert {"backlash", "linear", "method", "invertible_samples", "samples"} <= set(document)
    back = OutputBacklashIdentification.from_dict(_reopened(document))
    assert back.to_dict() == document
    assert back.linear_intervals == result.linear_intervals and back.backlash_intervals == result.backlash_intervals
    assert back.linear == result.linear
    _same_arrays(back.inner_signal, result.inner_signal)
    for side in ("left", "right"):
        _same_arrays(getattr(back.backlash, side), getattr(result.backlash, side))
    assert np.array_equal(back.backlash.alpha_rad, result.backlash.alpha_rad)


def test_each_part_saves_itself(result) -> None:
    assert LinearBlockBounds.from_dict(_reopened(result.linear.to_dict())) == result.linear
    _same_arrays(InnerSignalBounds.from_dict(_reopened(result.inner_signal.to_dict())), result.inner_signal)
    assert BacklashFeasibleSet.from_dict(_reopened(result.backlash.to_dict())).to_dict() == result.backlash.to_dict()


def test_an_empty_feasible_set_round_trips_with_its_explanation() -> None:
    empty = _identify(steady_noise=1e-3)  # 100 noise bounds off: no backlash explains the points
    assert empty.is_empty
    document = empty.to_dict()
    assert document["empty"] is True and document["explanation"] == empty.explanation
    back = OutputBacklashIdentification.from_dict(_reopened(document))
    assert back.is_empty and back.explanation == empty.explanation and back.to_dict() == document


@pytest.mark.parametrize("change, words", [
    ({"kind": "hammerstein_model"}, "got kind 'hammerstein_model' version 1"),
    ({"version": 7}, "kind 'output_backlash' version 7 cannot be read"),
    ({"kind": None}, "no 'kind' key"),
])
def test_another_kind_or_version_is_named(result, change, words) -> None:
    document = {**result.to_dict(), **change}
    if change.get("kind", "") is None:
        del document["kind"]
    with pytest.raises(ResultFormatError, match=words.replace("(", r"\(")):
        OutputBacklashIdentification.from_dict(document)


def test_a_malformed_document_names_the_key(result) -> None:
    document = result.to_dict()
    del document["linear_bounds"]["orders"]
    with pytest.raises(ResultFormatError, match="'orders' is missing"):
        OutputBacklashIdentification.from_dict(document)


def test_the_inner_signal_bounds_contain_the_true_inner_signal(result) -> None:
    inner = result.inner_signal
    true_x = PLANT.blocks[0].apply(prbs_sequence(100, 1.0, rng=1))
    assert inner.contains(true_x).all() and not inner.contains(true_x + 1.0).any()
    assert inner.median_half_width_rad(invertible=True) <= inner.median_half_width_rad(invertible=False)
