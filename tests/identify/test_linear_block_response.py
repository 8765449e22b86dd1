"""The numbers the set-membership figures show, computed and tested here: the guaranteed |G| envelope over
the parameter box, the membership test of a side of D_γ, and the one parser of a1/b2 names."""

from __future__ import annotations

import numpy as np
import pytest

from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.feasible_parameter_set import ParameterInterval
from identify.linear_block_response import MagnitudeEnvelope, box_magnitude_envelope, linear_parameter, polynomials
from identify.output_backlash_identification import bound_output_backlash_system
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
from identify.validation import InvalidInputError

LINEAR = LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 0.01)
BACKLASH = OutputBacklash(0.248, 0.0698, 0.252, 0.0349)
PLANT = PlantModel((LINEAR, BACKLASH))
NOISE = 1e-3
TRUTH = {"m_l": 0.248, "c_l": 0.0698, "m_r": 0.252, "c_r": 0.0349}


@pytest.fixture(scope="module")
def results():
    rng = np.random.default_rng(0)
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 6)), 0.8125, 100)
    steady = staircase_steady_state_indices(6, 100)
    steady_y = PLANT.simulate(staircase)[steady] + rng.uniform(-NOISE, NOISE, steady.size)
    u = prbs_sequence(60, 1.0, rng=1)
    y = PLANT.simulate(u) + rng.uniform(-NOISE, NOISE, u.size)
    return {method: bound_output_backlash_system(staircase[steady], steady_y, u, y, NOISE, na=2, nk=1, nb=2,
                                                 method=method) for method in ("paper", "coupled")}


def test_parameter_names_are_parsed_in_one_place():
    assert linear_parameter("a1") == ("a", 1) and linear_parameter("b12") == ("b", 12)
    assert linear_parameter("m_l") is None and linear_parameter("a") is None and linear_parameter("ab1") is None
    b, a = polynomials({"a1": 0.5, "a2": 0.7, "b1": 1.4, "b2": 0.8, "m_l": 9.0})
    np.testing.assert_array_equal(a, [1.0, 0.5, 0.7])
    np.testing.assert_array_equal(b, [0.0, 1.4, 0.8])
    with pytest.raises(InvalidInputError, match="expected b<k>"):
        polynomials({"a1": 0.5})


def test_the_envelope_of_the_identified_box_contains_the_true_model_and_the_coupled_one_is_narrower(results):
    omega = np.logspace(np.log10(np.pi / 1000.0), np.log10(np.pi), 200)
    true_magnitude = np.abs(np.polyval(np.r_[0.0, 1.4, 0.8][::-1], np.exp(-1j * omega))
                            / np.polyval(np.r_[1.0, 0.5, 0.7][::-1], np.exp(-1j * omega)))
    envelopes = {method: result.linear.magnitude_envelope(omega) for method, result in results.items()}
    for envelope in envelopes.values():
        assert envelope.fraction_containing(true_magnitude) == 1.0
        assert np.all(envelope.lower <= envelope.central) and np.all(envelope.central <= envelope.upper)
        assert envelope.bounded_fraction == 1.0 and envelope.unbounded_above_fraction == 0.0
    assert envelopes["coupled"].median_width_db < envelopes["paper"].median_width_db
    assert not envelopes["coupled"].contains(2.0 * true_magnitude).all()


def test_a_side_of_the_backlash_set_contains_the_true_backlash_and_not_a_wrong_one(results):
    backlash = results["coupled"].backlash
    m_l, c_l, m_r, c_r = TRUTH["m_l"], TRUTH["c_l"], TRUTH["m_r"], TRUTH["c_r"]
    assert backlash.contains(m_l, c_l, m_r, c_r) == {"left": True, "right": True}
    # twice the right dead band is outside D_γ^r, the left side is unchanged
    assert backlash.contains(m_l, c_l, m_r, c_r_rad=2 * c_r) == {"left": True, "right": False}
    # the band of lines over a side holds the true line at every input
    x = np.linspace(0.0, 3.0, 50)
    low, high = backlash.right.output_band(x)
    true_w = backlash.right.side_line(TRUTH["m_r"], TRUTH["m_r"] * TRUTH["c_r"], x)
    assert np.all(low <= true_w + 1e-12) and np.all(true_w <= high + 1e-12)


def test_box_envelope_is_exact_on_a_hand_case_and_contains_every_box_model():
    # G = b0 / (1 + a1 q^-1), a1 in [0.4, 0.6], b0 in [1, 2]: at ω = 0, |A| = 1 + a1; at ω = π, |A| = 1 - a1.
    lower, upper = box_magnitude_envelope({"a1": ParameterInterval(0.4, 0.6), "b0": ParameterInterval(1.0, 2.0)},
                                          [0.0, np.pi])
    np.testing.assert_allclose(lower, [1 / 1.6, 1 / 0.6], rtol=1e-12)
    np.testing.assert_allclose(upper, [2 / 1.4, 2 / 0.4], rtol=1e-12)
    # A box around a second-order model: every sampled model lies inside the envelope, and the upper envelope
    # is reached. |B| is largest at a corner of the b-box; |A| is smallest on the boundary of its zonotope,
    # where every a_i but one sits at a bound: searching those edges finds the supremum.
    rng = np.random.default_rng(3)
    box = {"a1": ParameterInterval(-1.25, -1.15), "a2": ParameterInterval(0.45, 0.5),
           "b1": ParameterInterval(0.1, 0.2), "b2": ParameterInterval(0.05, 0.1)}
    omega = np.linspace(0.01, np.pi, 200)
    z = np.exp(-1j * omega)
    envelope = MagnitudeEnvelope.of_box(box, omega)

    def magnitude(a1, a2, b1, b2):
        return np.abs((b1 * z + b2 * z**2) / (1 + a1 * z + a2 * z**2))

    samples = np.array([magnitude(*(rng.uniform(box[k].lower, box[k].upper) for k in ("a1", "a2", "b1", "b2")))
                        for _ in range(300)])
    assert all(envelope.contains(sample).all() for sample in samples)
    dense = np.linspace(0.0, 1.0, 201)
    a_edges = [(box["a1"].lower + t * 0.1, a2) for t in dense for a2 in (0.45, 0.5)]
    a_edges += [(a1, 0.45 + t * 0.05) for t in dense for a1 in (-1.25, -1.15)]
    largest = np.max([magnitude(a1, a2, b1, b2) for a1, a2 in a_edges for b1 in (0.1, 0.2) for b2 in (0.05, 0.1)],
                     axis=0)
    assert np.all(largest <= envelope.upper * (1 + 1e-12))
    assert np.min(largest / envelope.upper) > 0.999
    # A box of zero width is one model: the envelope collapses onto it, the central model.
    point = {k: ParameterInterval(v.center, v.center) for k, v in box.items()}
    collapsed = MagnitudeEnvelope.of_box(point, omega)
    exact = np.abs((0.15 * z + 0.075 * z**2) / (1 - 1.2 * z + 0.475 * z**2))
    for values in (collapsed.lower, collapsed.upper, collapsed.central):
        np.testing.assert_allclose(values, exact, rtol=1e-9)
    assert collapsed.median_width_db == pytest.approx(0.0, abs=1e-6)


def test_an_envelope_with_a_pole_on_the_unit_circle_says_where_it_is_unbounded():
    # a1 in [-1.1, -0.9]: the box holds A = 1 - q^-1, a pole at z = 1 (ω = 0)
    envelope = MagnitudeEnvelope.of_box({"a1": ParameterInterval(-1.1, -0.9), "b1": ParameterInterval(0.1, 0.2)},
                                        [0.0, np.pi])
    assert np.isinf(envelope.upper[0]) and np.isfinite(envelope.upper[1])
    assert envelope.unbounded_above_fraction == 0.5 and envelope.bounded_fraction == 0.5
