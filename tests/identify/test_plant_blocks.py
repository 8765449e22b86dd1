"""Each plant block against its defining equation, and stepping against whole-array simulation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal as scipy_signal

from identify.plant_blocks import (
    ArctanBorder,
    CoulombFriction,
    DeadZone,
    Delay,
    InputBacklash,
    InputSwitch,
    LinearBlock,
    OutputBacklash,
    OutputOffset,
    PiecewiseLinearBorder,
    PlantModel,
    Resonance,
    Saturation,
    pouliquen2013_backlash,
    pouliquen2013_switch,
)
from identify.validation import InvalidInputError

CERONE_LINEAR = LinearBlock(a=(0.5, 0.7), b=(0.0, 1.4, 0.8), sample_period_s=1e-3)
CERONE_BACKLASH = OutputBacklash(m_l=0.248, c_l_rad=0.0698, m_r=0.252, c_r_rad=0.0349)


def run_stepper(block, signal):
    stepper = block.stepper()
    return np.array([stepper.step(value) for value in signal])


# --- linear block ----------------------------------------------------------------------------------------


def test_linear_block_follows_the_difference_equation_of_eq_1():
    u = np.random.default_rng(0).standard_normal(50)
    x = CERONE_LINEAR.apply(u)
    expected = np.zeros(50)
    for t in range(50):
        # x_t = -a1 x_{t-1} - a2 x_{t-2} + b1 u_{t-1} + b2 u_{t-2}
        past = lambda s, k: s[t - k] if t - k >= 0 else 0.0  # noqa: E731
        expected[t] = -0.5 * past(expected, 1) - 0.7 * past(expected, 2) + 1.4 * past(u, 1) + 0.8 * past(u, 2)
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-12)
    assert CERONE_LINEAR.static_gain == pytest.approx(1.0, abs=1e-15)
    assert np.all(np.abs(CERONE_LINEAR.poles) < 1.0)


def test_linear_block_from_state_space_matches_scipy_dlsim():
    A = [[1.8858, -0.9048], [1.0, 0.0]]
    B = [1.0, 0.0]
    C = [0.1994, -0.1804]
    block = LinearBlock.from_state_space(A, B, C, 0.0, sample_period_s=0.01)
    u = np.random.default_rng(1).standard_normal(200)
    _, y_expected, _ = scipy_signal.dlsim((np.array(A), np.array(B).reshape(2, 1), np.array(C).reshape(1, 2), [[0.0]], 0.01), u)
    np.testing.assert_allclose(block.apply(u), y_expected[:, 0], atol=1e-10)
    # the second seed's G(q) = q^-1 (0.1994 - 0.1804 q^-1) / (1 - 1.8858 q^-1 + 0.9048 q^-2)
    np.testing.assert_allclose(block.a, (-1.8858, 0.9048), atol=1e-12)
    np.testing.assert_allclose(block.b[:3], (0.0, 0.1994, -0.1804), atol=1e-12)


def test_linear_block_stepper_equals_apply_bit_for_bit():
    u = np.random.default_rng(2).standard_normal(3000)
    for block in (CERONE_LINEAR, LinearBlock((), (2.5,), 1.0), LinearBlock((-0.9,), (0.1,), 1.0),
                  LinearBlock((0.1, -0.2, 0.05), (0.0, 0.0, 0.3, 0.2, 0.1), 1.0)):
        assert np.array_equal(run_stepper(block, u), block.apply(u))


def test_linear_block_rejects_bad_coefficients_by_name():
    with pytest.raises(InvalidInputError, match=r"a\[1\]"):
        LinearBlock(a=(0.5, float("nan")), b=(1.0,), sample_period_s=1.0)
    with pytest.raises(InvalidInputError, match="sample_period_s"):
        LinearBlock(a=(), b=(1.0,), sample_period_s=0.0)
    with pytest.raises(InvalidInputError, match="C: expected 2 entries"):
        LinearBlock.from_state_space(np.eye(2), [1, 0], [1, 0, 0], 0.0, 1.0)


# --- output backlash, eqs. (2)-(3) of Cerone et al. 2009 -------------------------------------------------


def test_output_backlash_follows_right_line_holds_in_the_band_then_follows_left_line():
    x = np.array([0.5, 1.0, 0.95, 0.92, 0.9, 0.5, 0.55, 0.58])
    w = CERONE_BACKLASH.apply(x)
    m_l, c_l, m_r, c_r = 0.248, 0.0698, 0.252, 0.0349
    assert w[0] == pytest.approx(m_r * (0.5 - c_r))
    assert w[1] == pytest.approx(m_r * (1.0 - c_r))
    # z_l = w/m_l - c_l = 0.9109 < 0.95, 0.92 < z_r = 1.0: the third case holds w_{t-1}
    assert w[2] == w[1] and w[3] == w[1]
    assert w[4] == pytest.approx(m_l * (0.9 + c_l))
    assert w[5] == pytest.approx(m_l * (0.5 + c_l))
    # z_r = w/m_r + c_r = 0.5956: rising to 0.58 still holds
    assert w[6] == w[5] and w[7] == w[5]
    assert CERONE_BACKLASH.apply(np.append(x, 0.6))[-1] == pytest.approx(m_r * (0.6 - c_r))


def test_output_backlash_every_sample_satisfies_one_case_of_eq_2():
    x = np.cumsum(np.random.default_rng(3).normal(0, 0.05, 2000))
    w = CERONE_BACKLASH.apply(x)
    previous = np.concatenate(([0.0], w[:-1]))
    z_l = previous / 0.248 - 0.0698
    z_r = previous / 0.252 + 0.0349
    left = (x <= z_l) & np.isclose(w, 0.248 * (x + 0.0698), atol=1e-15)
    right = (x >= z_r) & (x > z_l) & np.isclose(w, 0.252 * (x - 0.0349), atol=1e-15)
    hold = (z_l < x) & (x < z_r) & (w == previous)
    assert np.all(left | right | hold)
    assert left.sum() > 100 and right.sum() > 100 and hold.sum() > 100


def test_output_backlash_starts_from_initial_output_and_rejects_non_positive_parameters():
    assert CERONE_BACKLASH.apply([0.0, 0.01])[0] == 0.0  # inside the band around w_{-1} = 0
    held = OutputBacklash(0.25, 0.05, 0.25, 0.05, initial_output_rad=0.1).apply([0.4, 0.42])
    assert held[0] == 0.1 and held[1] == 0.1  # z_l = 0.35 < 0.4, 0.42 < z_r = 0.45
    with pytest.raises(InvalidInputError, match="c_l_rad"):
        OutputBacklash(0.25, 0.0, 0.25, 0.05)


# --- input backlash and switch, Pouliquen et al. 2013 ----------------------------------------------------


def test_input_backlash_with_arctan_borders_follows_ascending_then_holds_then_descending():
    backlash = pouliquen2013_backlash()
    rising = np.linspace(-3.0, 3.0, 61)
    falling = np.linspace(3.0, -3.0, 61)
    v = backlash.apply(np.concatenate((rising, falling)))
    # from rest (v = 0) the input first drops to -3: the descending border pulls v to arctan(-2), which
    # holds while rising until the ascending border arctan(u - 1) reaches it at u = -1
    pushed = rising > -1.0
    np.testing.assert_allclose(v[:61][~pushed], math.atan(-2.0), atol=1e-15)
    np.testing.assert_allclose(v[:61][pushed], np.arctan(rising[pushed] - 1.0), atol=1e-15)
    descending = v[61:]
    held = falling >= 1.0  # arctan(u + 1) >= arctan(2) = the value reached at u = 3
    np.testing.assert_allclose(descending[held], math.atan(2.0), atol=1e-15)
    np.testing.assert_allclose(descending[~held], np.arctan(falling[~held] + 1.0), atol=1e-15)


def test_input_backlash_with_node_table_borders():
    # a straight-line backlash of play 0.2 rad as node tables
    nodes = (-10.0, 10.0)
    backlash = InputBacklash(PiecewiseLinearBorder(nodes, (-10.1, 9.9)), PiecewiseLinearBorder(nodes, (-9.9, 10.1)))
    v = backlash.apply([0.5, 0.45, 0.35, 0.2, 0.25])
    np.testing.assert_allclose(v, [0.4, 0.4, 0.4, 0.3, 0.3], atol=1e-12)


def test_input_switch_jumps_between_borders_when_the_input_reverses():
    switch = pouliquen2013_switch()
    h0 = 0.5 * (math.atan(3.0) - math.atan(1.0))
    u = np.array([-3.0, -1.0, 0.5, 1.5, 1.5, 0.5, 0.5, 1.0, 3.0])
    h = switch.apply(u)
    ascending = lambda v: math.atan(v - 1.0) + h0  # noqa: E731
    descending = lambda v: math.atan(v + 1.0) - h0  # noqa: E731
    assert h[0] == -1.0  # u <= -2, falling from rest u_{-1} = 0
    assert h[1] == pytest.approx(ascending(-1.0))
    assert h[3] == pytest.approx(ascending(1.5))
    assert h[4] == h[3]  # equal input keeps the direction delta_{t-1}
    assert h[5] == pytest.approx(descending(0.5))  # reversal: jump to the other border
    assert h[5] - ascending(0.5) == pytest.approx(descending(0.5) - ascending(0.5))
    assert h[5] - ascending(0.5) > 0.95  # the jump is large at u = 0.5
    assert h[6] == h[5]
    assert h[7] == pytest.approx(ascending(1.0))
    assert h[8] == 1.0


def test_switch_and_backlash_steppers_equal_apply_for_any_callable_border():
    u = np.random.default_rng(4).uniform(-3, 3, 500)
    blocks = (pouliquen2013_switch(), pouliquen2013_backlash(),
              InputBacklash(lambda v: math.tanh(v) - 0.1, lambda v: math.tanh(v) + 0.1),
              InputSwitch(PiecewiseLinearBorder((-3, 0, 3), (-1, -0.5, 1)), PiecewiseLinearBorder((-3, 0, 3), (-1, 0.5, 1))))
    for block in blocks:
        assert np.array_equal(run_stepper(block, u), block.apply(u))


def test_borders_are_validated():
    with pytest.raises(InvalidInputError, match="nodes_u: expected strictly increasing"):
        PiecewiseLinearBorder((0.0, 1.0, 1.0), (0.0, 1.0, 2.0))
    with pytest.raises(InvalidInputError, match="values: expected one value per node"):
        PiecewiseLinearBorder((0.0, 1.0), (0.0,))
    with pytest.raises(InvalidInputError, match="ascending: expected a callable"):
        InputBacklash(1.0, math.atan)
    with pytest.raises(InvalidInputError, match="descending: the border returned nan"):
        InputBacklash(math.atan, lambda v: float("nan")).apply([0.0])
    assert PiecewiseLinearBorder((0.0, 1.0), (0.0, 2.0))(5.0) == 2.0
    assert ArctanBorder(input_shift_rad=0.0)(1.0) == pytest.approx(math.pi / 4)


# --- static blocks, delay, offset, resonance -------------------------------------------------------------


def test_dead_zone_and_saturation():
    u = np.array([-1.0, -0.1, -0.05, 0.0, 0.02, 0.2, 1.0])
    np.testing.assert_allclose(DeadZone(-0.1, 0.05).apply(u), [-0.9, 0.0, 0.0, 0.0, 0.0, 0.15, 0.95], atol=1e-15)
    np.testing.assert_array_equal(Saturation(-0.5, 0.5).apply(u), [-0.5, -0.1, -0.05, 0.0, 0.02, 0.2, 0.5])
    with pytest.raises(InvalidInputError, match="lower_rad < upper_rad"):
        Saturation(1.0, 1.0)
    with pytest.raises(InvalidInputError, match="left_rad <= right_rad"):
        DeadZone(0.1, -0.1)


def test_delay_shifts_exactly():
    u = np.random.default_rng(5).standard_normal(100)
    y = Delay(7).apply(u)
    assert np.array_equal(y[7:], u[:-7]) and np.all(y[:7] == 0.0)
    assert np.array_equal(Delay(0).apply(u), u)
    assert np.all(Delay(200).apply(u) == 0.0)
    assert np.array_equal(run_stepper(Delay(7), u), y)
    with pytest.raises(InvalidInputError, match="samples"):
        Delay(-1)


def test_output_offset_adds_offset_and_linear_drift():
    y = OutputOffset(offset_rad=0.01, drift_rad_per_s=0.002, sample_period_s=0.5).apply(np.zeros(5))
    np.testing.assert_allclose(y, 0.01 + 0.002 * 0.5 * np.arange(5), atol=1e-15)


def test_resonance_has_unit_static_gain_and_its_peak_at_the_given_frequency():
    resonance = Resonance(frequency_hz=40.0, damping_ratio=0.05, sample_period_s=1e-3)
    assert resonance.apply(np.ones(20000))[-1] == pytest.approx(1.0, abs=1e-9)
    linear = resonance.to_linear_block()
    frequencies, response = scipy_signal.freqz(linear.b, (1.0, *linear.a), worN=20000, fs=1000.0)
    peak = np.argmax(np.abs(response))
    assert frequencies[peak] == pytest.approx(40.0 * math.sqrt(1 - 2 * 0.05**2), rel=0.01)
    assert np.abs(response[peak]) == pytest.approx(1 / (2 * 0.05 * math.sqrt(1 - 0.05**2)), rel=0.02)
    with pytest.raises(InvalidInputError, match="Nyquist"):
        Resonance(frequency_hz=600.0, damping_ratio=0.05, sample_period_s=1e-3)


# --- friction ---------------------------------------------------------------------------------------------


def test_friction_sticks_below_breakaway():
    friction = CoulombFriction(breakaway_torque_nm=2.0, coulomb_torque_nm=1.5, stiffness_nm_per_rad=100.0)
    assert friction.breakaway_deflection_rad == pytest.approx(0.02)
    x = 0.0199 * np.sin(np.linspace(0, 20, 500))
    assert np.all(friction.apply(x) == 0.0)


def test_friction_breaks_away_slips_then_slides_lagging_by_the_coulomb_twist():
    friction = CoulombFriction(breakaway_torque_nm=2.0, coulomb_torque_nm=1.5, stiffness_nm_per_rad=100.0)
    x = np.arange(0, 101) * 1e-3  # a slow ramp 0 .. 0.1 rad
    y = friction.apply(x)
    moving = np.flatnonzero(y != 0.0)
    first = moving[0]
    assert x[first] > 0.02 and x[first - 1] <= 0.02 + 1e-15  # breakaway when the twist exceeds T_s / k
    np.testing.assert_allclose(y[first:], x[first:] - 0.015, atol=1e-12)  # sliding: twist = T_c / k
    # reversal: stuck until the twist reaches -T_s / k the other way
    back = friction.apply(np.concatenate((x, x[-1] - np.arange(1, 40) * 1e-3)))
    reversal = back[101:]
    stuck = reversal == back[100]
    assert stuck[:33].all() and not stuck[36:].any()


def test_friction_validates_its_torques():
    with pytest.raises(InvalidInputError, match="coulomb_torque_nm"):
        CoulombFriction(breakaway_torque_nm=1.0, coulomb_torque_nm=2.0, stiffness_nm_per_rad=10.0)


# --- the chain ---------------------------------------------------------------------------------------------


def all_effects_plant() -> PlantModel:
    period = 1e-3
    return PlantModel((
        DeadZone(-0.002, 0.003),
        Saturation(-2.5, 2.5),
        pouliquen2013_backlash(),
        Delay(2),
        LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), period),
        Resonance(80.0, 0.05, period),
        OutputBacklash(0.248, 0.0698, 0.252, 0.0349),
        CoulombFriction(0.5, 0.4, 200.0),
        OutputOffset(0.01, 0.001, period),
    ))


def test_plant_stepper_reproduces_simulate_bit_for_bit():
    plant = all_effects_plant()
    u = np.cumsum(np.random.default_rng(6).normal(0, 0.05, 4000))
    y = plant.simulate(u)
    stepper = plant.stepper()
    stepped = np.array([stepper.step(value) for value in u])
    assert np.array_equal(stepped, y)
    assert np.std(y) > 0.01


def test_with_block_and_without_build_new_models():
    plant = PlantModel((CERONE_LINEAR, CERONE_BACKLASH))
    delayed = plant.with_block(Delay(3), 0)
    assert [type(b).__name__ for b in delayed.blocks] == ["Delay", "LinearBlock", "OutputBacklash"]
    assert len(plant.blocks) == 2  # unchanged
    u = np.random.default_rng(7).standard_normal(50)
    assert np.array_equal(delayed.simulate(u)[3:], plant.simulate(u)[:-3])
    assert delayed.without(Delay) == plant
    assert plant.with_block(Saturation(-1, 1)).blocks[-1] == Saturation(-1, 1)
    with pytest.raises(InvalidInputError, match="has no Resonance"):
        plant.without(Resonance)
    with pytest.raises(InvalidInputError, match="index"):
        plant.with_block(Delay(1), 5)


def test_plant_rejects_mismatched_periods_non_blocks_and_bad_samples():
    with pytest.raises(InvalidInputError, match="sample periods of the blocks differ"):
        PlantModel((CERONE_LINEAR, Resonance(10.0, 0.1, 1e-2)))
    with pytest.raises(InvalidInputError, match=r"blocks\[1\]"):
        PlantModel((CERONE_LINEAR, "backlash"))
    with pytest.raises(InvalidInputError, match="command_rad: sample 2 is nan"):
        PlantModel((CERONE_LINEAR,)).simulate([0.0, 1.0, float("nan")])
    with pytest.raises(InvalidInputError, match="u_t: sample 0"):
        PlantModel((CERONE_LINEAR,)).stepper().step(float("inf"))
    assert PlantModel((CERONE_LINEAR,)).sample_period_s == 1e-3


BLOCK_FACTORIES = (
    lambda r: DeadZone(-r.uniform(0, 0.1), r.uniform(0, 0.1)),
    lambda r: Saturation(-r.uniform(0.5, 2), r.uniform(0.5, 2)),
    lambda r: Delay(int(r.integers(0, 4))),
    lambda r: LinearBlock((r.uniform(-0.5, 0.5), r.uniform(-0.3, 0.3)), (0.0, r.uniform(0.1, 1), r.uniform(-0.5, 0.5)), 1e-3),
    lambda r: Resonance(r.uniform(5, 400), r.uniform(0.01, 0.9), 1e-3),
    lambda r: OutputBacklash(r.uniform(0.1, 1), r.uniform(0.01, 0.2), r.uniform(0.1, 1), r.uniform(0.01, 0.2)),
    lambda r: CoulombFriction(r.uniform(0.1, 1), r.uniform(0, 0.1), r.uniform(5, 50)),
    lambda r: OutputOffset(r.uniform(-0.1, 0.1), r.uniform(-0.1, 0.1), 1e-3),
    lambda r: pouliquen2013_backlash(),
    lambda r: pouliquen2013_switch(),
)


@settings(max_examples=40, deadline=None)
@given(choices=st.lists(st.integers(0, len(BLOCK_FACTORIES) - 1), min_size=1, max_size=6), seed=st.integers(0, 2**31))
def test_any_chain_steps_exactly_like_it_simulates(choices, seed):
    rng = np.random.default_rng(seed)
    plant = PlantModel(tuple(BLOCK_FACTORIES[index](rng) for index in choices))
    u = np.cumsum(rng.normal(0, 0.2, 300))
    stepper = plant.stepper()
    assert np.array_equal([stepper.step(value) for value in u], plant.simulate(u))


def test_sample_periods_equal_up_to_rounding_are_one_period():
    """A CSV's median time step (0.0010000000000000009 s) matches a model's 0.001 s; 1 ms and 2 ms do not."""
    from identify.plant_blocks import Delay, LinearBlock, OutputOffset, PlantModel

    PlantModel((LinearBlock((-0.5,), (0.5,), 0.001), OutputOffset(0.0, 1e-3, 0.0010000000000000009), Delay(1)))
    with pytest.raises(InvalidInputError, match="sample periods of the blocks differ"):
        PlantModel((LinearBlock((-0.5,), (0.5,), 0.001), OutputOffset(0.0, 1e-3, 0.002)))
