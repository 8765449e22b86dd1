"""The drive-train candidates of the effect catalogue: friction on the load, gravity, rate
and torque limits, fitted inside a drive train.

Each hidden-effect record is the nominal 30 Hz position loop as a rigid drive train holding one effect of
realistic size (:mod:`identify.discrepancy_cases`), read by a 12-bit encoder; the workflow gets the nominal
linear model. It must name exactly that effect, with parameter intervals containing the true values, and
name nothing on the clean record.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from identify.discrepancy_cases import hidden_effect_record, step_excitation
from identify.drive_train import DriveTrain
from identify.drive_train_effects import reference_train
from identify.effect_catalogue import DYNAMICS_EFFECTS, effect
from identify.effect_signatures import EFFECT_NAMES, signature_scores
from identify.model_discrepancy import (
    ESTIMATION_FRACTION,
    DiagnoseOptions,
    DiscrepancyStep,
    diagnose_model,
    disagreement,
    drive_train_like,
    rigid_train_like,
)
from identify.model_discrepancy.candidates import _dynamics_chain, _merged
from identify.model_discrepancy.chain import _build, _Chain, _Component
from identify.model_discrepancy.fit import _try_effect
from identify.model_discrepancy.search import _family_rechecked, _Search
from identify.plant_blocks import LinearBlock, PlantModel
from identify.validation import InvalidInputError
from servo_and_shaft import servo_and_shaft_block
from sim_backend.plant_config import plant_config_from_toml_text, plant_config_to_toml

SEED = 1000


@pytest.mark.parametrize("name", DYNAMICS_EFFECTS)
def test_a_hidden_drive_train_effect_is_named_with_intervals_holding_the_truth(name):
    record = hidden_effect_record((name,), SEED)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            record.nominal_model)
    assert result.verdict == "named"
    assert result.missing_effects == (name,)
    # a rigid model has no shaft to hold a friction inside it: that effect is not tried (it would have to
    # invent the shaft as well); a model with the shaft is given where the effect needs it
    if all(isinstance(block, LinearBlock) for block in record.nominal_model.blocks):
        assert all(not effect(c.effect).needs_shaft for c in result.candidates if c.effect in DYNAMICS_EFFECTS)
    entry = effect(name)
    (train,) = record.true_model.blocks
    truth = entry.report(train)
    intervals = result.parameter_intervals[name]
    assert set(intervals) == set(truth)
    for key, value in truth.items():
        low, high = intervals[key]
        assert low <= value <= high, f"{key}: truth {value:g} outside [{low:g}, {high:g}]"
    # the effect explains the record: the validated gap falls to the encoder's noise level
    assert result.final.gap_rad < record.noise_bound_rad


def test_a_clean_record_names_no_drive_train_effect():
    record = hidden_effect_record((), SEED)
    for model in (record.nominal_model, None):
        result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad,
                                record.sample_period_s, model)
        assert result.verdict == "explained"
        assert result.missing_effects == ()
        # explained says how small an effect could hide: one under the noise bound does not show
        assert f"noise bound ({record.noise_bound_rad:.3g} rad)" in result.verdict_reason
        assert "less than the noise bound would not show" in result.verdict_reason


def test_gravity_merges_into_the_users_drive_train_and_is_reported_per_inertia():
    # the user's model is a physical rigid train (J = 0.02 kg m^2, 1:50) without the arm; the record has an
    # arm of 0.4 kg at 0.08 m (m g l / J = 15.7 rad/s^2, sagging the 8 Hz loop by 6 mrad when horizontal)
    period = 1e-3
    model_train = DriveTrain(sample_period_s=period, gear_ratio=50.0, motor_inertia_kg_m2=2e-6,
                             load_inertia_kg_m2=0.015, shaft_stiffness_nm_per_rad=math.inf,
                             position_loop_bandwidth_hz=8.0, position_loop_damping_ratio=0.8)
    true_train = dataclasses.replace(model_train, pendulum_mass_kg=0.4, pendulum_length_m=0.08,
                                     hanging_angle_rad=0.2)
    rng = np.random.default_rng(7)
    u = step_excitation(3000, rng)
    count = 2.0 * math.pi / 4096
    y = np.round((true_train.apply(u) + rng.uniform(-2e-4, 2e-4, u.size)) / count) * count
    delta = 0.5 * count + 2e-4
    result = diagnose_model(u, y, delta, period, PlantModel((model_train,)))
    assert result.missing_effects == ("gravity",)
    truth = true_train.gravity_torque_nm / true_train.total_inertia_kg_m2
    low, high = result.parameter_intervals["gravity"]["gravity_per_inertia_rad_per_s2"]
    assert low <= truth <= high
    low, high = result.parameter_intervals["gravity"]["hanging_angle_rad"]
    assert low <= 0.2 <= high
    # the final model is the user's train (inertia, gear, loop) with the arm: its weight m g l is the truth
    (final,) = result.final_model.blocks
    assert isinstance(final, DriveTrain)
    assert final.gear_ratio == 50.0 and final.total_inertia_kg_m2 == pytest.approx(true_train.total_inertia_kg_m2)
    assert final.gravity_torque_nm == pytest.approx(true_train.gravity_torque_nm, rel=0.05)


def test_friction_inside_the_users_shaft_is_named_and_reported_as_the_twist_it_holds():
    # the user's two-mass train (1:10, load 0.004 kg m^2 on a 150 N m/rad shaft, a 15 Hz loop on the motor)
    # without friction in its shaft; the record's shaft holds 0.3 N m of dry friction (T_h / k = 2 mrad, Dahl's
    # model, presliding twist 0.5 mrad), which moves the load by up to 3.2 mrad on 0.5 rad steps
    period = 1e-3
    model_train = DriveTrain(sample_period_s=period, gear_ratio=10.0, motor_inertia_kg_m2=2e-5,
                             load_inertia_kg_m2=0.004, shaft_stiffness_nm_per_rad=150.0,
                             shaft_damping_nm_s_per_rad=0.05, position_loop_bandwidth_hz=15.0,
                             position_loop_damping_ratio=0.8)
    true_train = dataclasses.replace(model_train, shaft_friction_nm=0.3, shaft_presliding_twist_rad=0.5e-3)
    rng = np.random.default_rng(7)
    u = step_excitation(3000, rng, 0.5)
    count = 2.0 * math.pi / 4096
    y = np.round((true_train.apply(u) + rng.uniform(-2e-4, 2e-4, u.size)) / count) * count
    delta = 0.5 * count + 2e-4
    result = diagnose_model(u, y, delta, period, PlantModel((model_train,)))
    assert result.verdict == "named" and result.missing_effects == ("shaft_friction",)
    assert result.final.gap_rad < delta
    intervals = result.parameter_intervals["shaft_friction"]
    low, high = intervals["friction_twist_rad"]
    assert low <= 0.3 / 150.0 <= high
    low, high = intervals["presliding_twist_rad"]
    assert low <= 0.5e-3 <= high
    # the final model is the user's train with the friction in its shaft
    (final,) = result.final_model.blocks
    assert isinstance(final, DriveTrain) and final.shaft_stiffness_nm_per_rad == 150.0
    assert final.shaft_friction_nm == pytest.approx(0.3, rel=0.35)


def test_friction_on_the_load_reports_what_it_adds_to_the_users_viscous_friction():
    # the user's rigid train already has viscous friction (d_v / J = 20 1/s, a quarter of the loop's damping
    # 2 zeta omega_n); the record adds Coulomb friction T_c / J = 30 rad/s^2 (sagging the 8 Hz loop by 12 mrad)
    # and nothing viscous: the effect's viscous term is what it adds (zero), not the train's total
    period = 1e-3
    rigid = DriveTrain(sample_period_s=period, gear_ratio=50.0, motor_inertia_kg_m2=2e-6,
                       load_inertia_kg_m2=0.015, shaft_stiffness_nm_per_rad=math.inf,
                       position_loop_bandwidth_hz=8.0, position_loop_damping_ratio=0.8)
    inertia = rigid.total_inertia_kg_m2
    model_train = dataclasses.replace(rigid, viscous_friction_nm_s_per_rad=20.0 * inertia)
    true_train = dataclasses.replace(model_train, coulomb_friction_nm=30.0 * inertia,
                                     static_friction_nm=30.0 * inertia)
    rng = np.random.default_rng(8)
    u = step_excitation(3000, rng)
    count = 2.0 * math.pi / 4096
    y = np.round((true_train.apply(u) + rng.uniform(-2e-4, 2e-4, u.size)) / count) * count
    result = diagnose_model(u, y, 0.5 * count + 2e-4, period, PlantModel((model_train,)))
    assert result.missing_effects == ("load_friction",)
    (step,) = result.steps
    assert step.parameters["coulomb_per_inertia_rad_per_s2"] == pytest.approx(30.0, rel=0.15)
    assert abs(step.parameters["viscous_per_inertia_per_s"]) < 2.0
    low, high = result.parameter_intervals["load_friction"]["viscous_per_inertia_per_s"]
    assert low <= 0.0 <= high
    # the final model keeps the user's viscous friction
    (final,) = result.final_model.blocks
    assert final.viscous_friction_nm_s_per_rad / inertia == pytest.approx(20.0, abs=2.0)


def test_the_rigid_equivalent_of_a_linear_loop_reproduces_its_free_run():
    # the 30 Hz, zeta 0.7 loop discretised with a zero-order hold: the fitted rigid train follows it within a
    # hundredth of the noise bound of the hidden-effect records (1 mrad), with the loop's own bandwidth
    # (the integrator's explicit damping shifts it by 0.5 %)
    block = LinearBlock(a=(-1.73691838, 0.76805512), b=(0.0, 0.01625312, 0.01488362), sample_period_s=1e-3)
    u = step_excitation(2000, np.random.default_rng(2))
    train = rigid_train_like(block, u)
    assert train.rigid
    assert np.max(np.abs(train.apply(u) - block.apply(u))) < 1e-5
    assert train.position_loop_bandwidth_hz == pytest.approx(30.0, rel=0.01)
    assert train.position_loop_damping_ratio == pytest.approx(0.7, rel=0.01)


def test_a_linear_block_with_a_shaft_mode_becomes_a_two_mass_train():
    # bare steps of up to 1.2 rad through the stiff servo: the rigid train cannot hold the 30.8 Hz mode (its
    # free run misses the block by a third of a radian); the two-mass train follows it within a third of a
    # 12-bit count (its motor is not infinitely stiff against the shaft's torque), with the servo's loop
    block = servo_and_shaft_block()
    u = step_excitation(3000, np.random.default_rng(3))
    rigid = rigid_train_like(block, u)
    assert np.max(np.abs(rigid.apply(u) - block.apply(u))) > 0.3
    train = drive_train_like(block, u)
    assert not train.rigid
    assert np.max(np.abs(train.apply(u) - block.apply(u))) < 0.5e-3
    assert train.position_loop_bandwidth_hz == pytest.approx(60.0, rel=0.05)
    assert train.position_loop_damping_ratio == pytest.approx(0.7, rel=0.05)


def test_a_linear_loop_without_a_shaft_mode_stays_a_rigid_train():
    block = LinearBlock(a=(-1.73691838, 0.76805512), b=(0.0, 0.01625312, 0.01488362), sample_period_s=1e-3)
    u = step_excitation(2000, np.random.default_rng(2))
    assert drive_train_like(block, u) == rigid_train_like(block, u)


def test_a_rigid_train_follows_the_second_order_step_and_round_trips_through_toml():
    train = reference_train(1e-3, 5.0, 0.5)
    y = train.apply(np.ones(1000))
    t = np.arange(y.size) * 1e-3
    w, z = 2.0 * math.pi * 5.0, 0.5
    wd = w * math.sqrt(1 - z * z)
    truth = 1.0 - np.exp(-z * w * t) * (np.cos(wd * t) + z / math.sqrt(1 - z * z) * np.sin(wd * t))
    # the ZOH of the command and the explicit damping of the sub-steps: within 0.5 % of the 1 rad step
    assert np.max(np.abs(y - truth)) < 5e-3
    text = ("sample_period_s = 0.001\n[encoder]\nbits = 12\n[[blocks]]\ntype = \"drive_train\"\n"
            "gear_ratio = 1.0\nmotor_inertia_kg_m2 = 0.5\nload_inertia_kg_m2 = 0.5\n"
            "position_loop_bandwidth_hz = 5.0\nposition_loop_damping_ratio = 0.5\n")
    config = plant_config_from_toml_text(text)
    assert config.blocks == (train,)  # a stiffness left out is a rigid shaft
    assert plant_config_from_toml_text(plant_config_to_toml(config)).blocks == (train,)


def test_a_rigid_train_with_play_is_refused_with_what_to_do():
    with pytest.raises(InvalidInputError, match="rigid shaft.*give a finite stiffness"):
        dataclasses.replace(reference_train(1e-3), play_rad=0.01)


def test_play_between_the_inertias_is_told_apart_from_an_output_backlash():
    # output backlash holds the output still while the drive turns back; play inside the train lets the load
    # coast on through it (motor feedback, no friction on the load) and bounce at contact. On a backlash
    # record the shaft-play candidate leaves most of the gap (and backlash is named); on a shaft-play record
    # backlash does not explain it (the parametrised test above names shaft_play there)
    for hidden, rival in (("backlash", "shaft_play"), ("shaft_play", "backlash")):
        record = hidden_effect_record((hidden,), SEED)
        result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad,
                                record.sample_period_s, record.nominal_model)
        assert result.missing_effects == (hidden,)
        first_round = {c["effect"]: c for c in result.to_dict()["candidates"] if c["round"] == 0}
        assert first_round[rival]["gap"] > 10 * first_round[hidden]["gap"], (hidden, first_round[rival])


def test_friction_on_the_load_with_play_is_named_as_both_not_as_an_output_hysteresis():
    # friction stops the load inside the play when the drive turns back: an output backlash's map, which wins
    # the first round; its inner twin (catalogue inner_twin), started from the backlash's width, is tried with
    # it and explains the record to the noise (seed 1012: the friction alone fits 2.5 times the true friction
    # and a play fitted through it stays closed)
    record = hidden_effect_record(("shaft_play", "load_friction"), 1012)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            record.nominal_model)
    assert set(result.missing_effects) == {"load_friction", "shaft_play"}
    first_round = {c.effect: c for c in result.candidates if c.round == 0}
    assert min(first_round, key=lambda name: first_round[name].penalised_gap_rad) == "load_friction+shaft_play"
    assert min(("backlash", "coulomb_friction", "load_friction", "shaft_play"),
               key=lambda name: first_round[name].penalised_gap_rad) in ("backlash", "coulomb_friction")
    (train,) = record.true_model.blocks
    for name in ("load_friction", "shaft_play"):
        for key, value in effect(name).report(train).items():
            low, high = result.parameter_intervals[name][key]
            if key != "viscous_per_inertia_per_s":  # a small viscous part is not resolved beside the Coulomb part
                assert low <= value <= high, f"{key}: truth {value:g} outside [{low:g}, {high:g}]"
    assert result.final.gap_rad < record.noise_bound_rad


def test_the_breakaway_of_a_friction_is_refitted_when_a_play_is_fitted_through_it():
    # a gradient polish never moves the breakaway (the free run jumps where the load sticks), so it is scanned
    # after every fit holding a stick-slip effect; before, the breakaway kept the value fitted without the play
    # (seed 1013: T_s / J 719 rad/s^2 against the truth's 1010, the interval [582, 856] refitted from there)
    record = hidden_effect_record(("shaft_play", "load_friction"), 1013)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            record.nominal_model)
    assert set(result.missing_effects) == {"load_friction", "shaft_play"}
    (train,) = record.true_model.blocks
    truth = effect("load_friction").report(train)["static_per_inertia_rad_per_s2"]
    (step,) = (s for s in result.steps if s.effect == "load_friction")
    assert step.parameters["static_per_inertia_rad_per_s2"] == pytest.approx(truth, rel=0.1)
    low, high = result.parameter_intervals["load_friction"]["static_per_inertia_rad_per_s2"]
    assert low <= truth <= high


@pytest.mark.parametrize("seed", [1004, 1012])
def test_from_a_fitted_start_a_loads_viscous_friction_is_given_the_range_the_loops_damping_can_trade(seed):
    # with the loop fitted too, the record shows mainly K_v / J + d_v / J: the fit put it all in the loop
    # (seed 1004: d_v / J 0.002 against the truth's 41.5 1/s) and the fold refits, started there, gave [0, 0.04];
    # the traded point alone, without refitting the rest, left the uncertainty before the truth (seed 1012:
    # 12.9 1/s outside [0, 9.2])
    record = hidden_effect_record(("load_friction",), seed)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s)
    assert result.missing_effects == ("load_friction",)
    (train,) = record.true_model.blocks
    for key, value in effect("load_friction").report(train).items():
        low, high = result.parameter_intervals["load_friction"][key]
        assert low <= value <= high, f"{key}: truth {value:g} outside [{low:g}, {high:g}]"


def test_a_torque_limit_fitted_after_a_too_long_delay_moves_the_delay_to_the_truth():
    # round 1 names the delay alone at 13 samples (the truth 10: the missing torque limit lags too); fitted at
    # 13 samples the limit takes 12 300 rad/s^2 (2.2 times the truth) and leaves 9.1 mrad, and re-searching
    # the delay at that limit keeps 13. The fit must reach what the truth leaves, from the guesses as from
    # the truth
    record = hidden_effect_record(("delay", "torque_limit"), 1004)
    u, y, delta = record.command_rad, record.angle_rad, record.noise_bound_rad
    n_est = int(round(ESTIMATION_FRACTION * u.size))
    true_delay, true_train = record.true_model.blocks
    truth = effect("torque_limit").report(true_train)["torque_limit_per_inertia_rad_per_s2"]
    truth_gap = float(np.sqrt(np.mean((y - record.true_model.simulate(u))[n_est:] ** 2)))
    chain = _Chain([_Component("delay", (13.0,)), _Component("fixed", block=record.nominal_model.blocks[0])])
    start = disagreement(chain.model(), u, y, delta, n_est)
    scores = signature_scores(u, y, start.simulated_rad, delta, record.sample_period_s)
    for forced in ((), ((truth,),)):
        fit = _try_effect("torque_limit", chain, u, y, n_est, delta, record.sample_period_s, start.residual_rad,
                          scores, 40, 40, forced)
        assert fit.chain.components[0].values == (float(true_delay.samples),), forced
        fitted = effect("torque_limit").report(fit.block)["torque_limit_per_inertia_rad_per_s2"]
        assert abs(fitted / truth - 1.0) < 0.02, (forced, fitted, truth)
        assert fit.gap_rad < 1.05 * truth_gap, (forced, fit.gap_rad, truth_gap)


def test_each_named_effect_reports_the_parameters_of_the_final_model_it_hands_over():
    # seed 1004: round 1 names the delay at 13 samples, and fitting the torque limit moves it to the truth, 10;
    # the report said 13 while the final model (the one a user writes out as plant TOML) had 10
    record = hidden_effect_record(("delay", "torque_limit"), 1004)
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            record.nominal_model)
    assert result.missing_effects == ("delay", "torque_limit")
    final_delay, final_train = result.final_model.blocks
    true_delay, _ = record.true_model.blocks
    blocks = {"delay": final_delay, "torque_limit": final_train}
    for named in result.report().missing_effects:
        assert named.parameters == pytest.approx(effect(named.effect).report(blocks[named.effect])), named.effect
        for key, value in named.parameters.items():
            low, high = named.parameter_intervals[key]
            assert low <= value <= high, (named.effect, key)
    assert result.report().missing_effects[0].parameters["samples"] == true_delay.samples


def test_a_delay_fitted_after_a_torque_limit_that_took_its_lag_reaches_the_true_delay():
    # round 1 names the torque limit alone (seed 1001: the truth is 4 samples of delay before it); fitted
    # without the delay, the limit is lowered to lag like both. The delay candidate fitted at every delay
    # with that limit held finds 1 sample, and the limit polished there leaves 21 mrad on the estimation
    # segment; the resonance then fitted the lag better and was named for it. Walked from there, with the
    # limit polished at each delay, the delay must reach the truth, the limit within 2 % of it and the
    # validated gap what the truth leaves
    record = hidden_effect_record(("delay", "torque_limit"), 1001)
    u, y, delta, period = record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s
    n_est = int(round(ESTIMATION_FRACTION * u.size))
    true_delay, true_train = record.true_model.blocks
    truth = effect("torque_limit").report(true_train)["torque_limit_per_inertia_rad_per_s2"]
    truth_gap = float(np.sqrt(np.mean((y - record.true_model.simulate(u))[n_est:] ** 2)))
    chain = _Chain([_Component("fixed", block=record.nominal_model.blocks[0])])
    start = disagreement(chain.model(), u, y, delta, n_est)
    limit = _try_effect("torque_limit", chain, u, y, n_est, delta, period, start.residual_rad,
                        signature_scores(u, y, start.simulated_rad, delta, period), 40, 40)
    after = disagreement(limit.chain.model(), u, y, delta, n_est)
    fit = _try_effect("delay", limit.chain, u, y, n_est, delta, period, after.residual_rad,
                      signature_scores(u, y, after.simulated_rad, delta, period), 40, 40)
    assert fit.block == true_delay, (fit.block, true_delay)
    fitted = effect("torque_limit").report(_build(fit.chain.components[1], fit.chain.components[1].values))
    assert abs(fitted["torque_limit_per_inertia_rad_per_s2"] / truth - 1.0) < 0.02, (fitted, truth)
    assert fit.gap_rad < 1.05 * truth_gap, (fit.gap_rad, truth_gap)


def test_friction_without_stiction_beside_gravity_is_named_as_the_backlash_it_is():
    # hidden backlash + gravity, seed 1018 (c_l 22.1, c_r 19.8 mrad): the final model held Coulomb friction
    # without stiction (breakaway = sliding = 20.8 mrad) and gravity, 0.629 mrad validated; refitted as a
    # backlash with the rest of the model the polish trades the asymmetry against the hanging angle on the
    # estimation segment and validates at 0.721 mrad, and the friction was named. Friction without stiction is
    # the symmetric backlash's map, so the family recheck must name backlash, at no worse a gap
    record = hidden_effect_record(("backlash", "gravity"), 1018)
    u, y, delta = record.command_rad, record.angle_rad, record.noise_bound_rad
    n_est = int(round(ESTIMATION_FRACTION * u.size))
    chain, _ = _dynamics_chain(_Chain([_Component("fixed", block=record.nominal_model.blocks[0])]), 0, u[:n_est])
    chain = _merged(chain, 0, "gravity", (743.1, -0.0533))  # the friction + gravity fit's gravity (rad/s^2, rad)
    chain = _Chain([*chain.components, _Component("coulomb_friction", (0.02083, 0.02083))])
    current = disagreement(chain.model(), u, y, delta, n_est)
    steps = [DiscrepancyStep(name, {}, {}, 0.02, 0.02, 1.0, current.falsified_fraction, chain.model())
             for name in ("coulomb_friction", "gravity")]
    found = _Search(chain, current, steps, [], (), current.residual_rad[n_est:])
    rechecked = _family_rechecked(found, EFFECT_NAMES, u, y, n_est, delta, DiagnoseOptions(), lambda _m: None)
    assert [step.effect for step in rechecked.steps] == ["backlash", "gravity"]
    assert rechecked.current.gap_rad <= current.gap_rad * (1.0 + 1e-9)
    true_backlash = record.true_model.blocks[-1]
    half_width = 0.5 * (rechecked.steps[0].parameters["c_l_rad"] + rechecked.steps[0].parameters["c_r_rad"])
    assert half_width == pytest.approx(0.5 * (true_backlash.c_l_rad + true_backlash.c_r_rad), rel=0.05)
