"""DriveTrain: physics against known truth, step == apply, TOML round trip, energy, parameter checks.

Each test states the analytic value it checks and the tolerance, and why the tolerance is what it is.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from drive_train_reference import reference_load_angle_rad

from identify.drive_train import DriveTrain
from identify.plant_blocks import Delay, OutputOffset, PlantModel
from identify.validation import InvalidInputError
from rig.protocols.errors import ConfigError
from sim_backend.plant_config import (
    DRIVE_TRAIN_KEYS,
    load_plant_config,
    plant_config_from_toml_text,
    plant_config_to_toml,
)

PLANTS = Path(__file__).resolve().parents[2] / "configs" / "plants"
PERIOD_S = 1e-3

# A 1:10 train at 1 kHz: motor 1e-5 kg m^2 (0.001 at the load side), load 0.01 kg m^2, shaft 1000 N m/rad
# (two-mass mode at 167 Hz, far above the 5 Hz position loop: rigid at the loop's frequencies).
STIFF = dict(sample_period_s=PERIOD_S, gear_ratio=10.0, motor_inertia_kg_m2=1e-5, load_inertia_kg_m2=1e-2,
             shaft_stiffness_nm_per_rad=1e3, shaft_damping_nm_s_per_rad=0.5, position_loop_bandwidth_hz=5.0,
             position_loop_damping_ratio=1.0)


def _second_order_step(time_s, natural_rad_per_s, damping_ratio):
    """1 - e^(-zeta w t) (cos w_d t + zeta / sqrt(1 - zeta^2) sin w_d t), 0 < zeta < 1."""
    damped = natural_rad_per_s * math.sqrt(1.0 - damping_ratio**2)
    decay = np.exp(-damping_ratio * natural_rad_per_s * time_s)
    return 1.0 - decay * (np.cos(damped * time_s) + damping_ratio / math.sqrt(1.0 - damping_ratio**2)
                          * np.sin(damped * time_s))


def test_rigid_train_follows_a_step_with_the_position_loops_second_order_response():
    zeta = 0.5
    train = DriveTrain(**{**STIFF, "position_loop_damping_ratio": zeta})
    y = train.apply(np.ones(1500))
    time_s = np.arange(y.size) * PERIOD_S
    truth = _second_order_step(time_s, train.natural_frequency_rad_per_s, zeta)
    # the shaft's compliance (static loop stiffness 10.9 N m/rad against 1000) and the ZOH of the command
    # shift the response by about 1 %; the whole curve within 0.01 rad of 1 rad
    assert np.max(np.abs(y - truth)) < 0.01
    overshoot = y.max() - 1.0
    assert overshoot == pytest.approx(math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2)), rel=0.03)  # 16.3 %
    peak_s = time_s[np.argmax(y)]
    assert peak_s == pytest.approx(math.pi / (train.natural_frequency_rad_per_s * math.sqrt(1 - zeta**2)), rel=0.02)
    settled = np.flatnonzero(np.abs(y - 1.0) > 0.02)[-1] * PERIOD_S
    assert settled == pytest.approx(np.flatnonzero(np.abs(truth - 1.0) > 0.02)[-1] * PERIOD_S, rel=0.03)
    assert y[-1] == pytest.approx(1.0, abs=1e-6)


def test_load_feedback_closes_the_loop_on_the_load_angle():
    # with gravity, the P loop's static error m g l sin(theta) / (K_v K_p) is on the angle it measures: the
    # load's with load feedback, the motor's (plus the shaft's twist on the load) with motor feedback
    gravity = dict(pendulum_mass_kg=0.5, pendulum_length_m=0.1, viscous_friction_nm_s_per_rad=0.05)
    on_load = DriveTrain(**STIFF, **gravity, position_feedback="load")
    on_motor = DriveTrain(**STIFF, **gravity)
    target = 0.5
    y_load = on_load.apply(np.full(3000, target))[-1]
    y_motor = on_motor.apply(np.full(3000, target))[-1]
    stiffness = on_load.servo_stiffness_nm_per_rad
    torque = on_load.gravity_torque_nm * math.sin(y_load)
    assert target - y_load == pytest.approx(torque / stiffness, rel=1e-4)
    torque = on_motor.gravity_torque_nm * math.sin(y_motor)
    assert target - y_motor == pytest.approx(torque / stiffness + torque / on_motor.shaft_stiffness_nm_per_rad, rel=1e-4)


def test_free_pendulum_swings_with_the_small_angle_period():
    # drive off: the arm swings the motor through the gear, J = J_l + N^2 J_m; amplitude 0.02 rad makes the
    # large-amplitude correction (1 + theta^2 / 16) 2.5e-5; zero crossings interpolated to well below 1e-3
    train = DriveTrain(**STIFF, pendulum_mass_kg=0.5, pendulum_length_m=0.1, drive_enabled=False,
                       initial_angle_rad=0.02)
    y = train.apply(np.zeros(5000))
    rising = np.flatnonzero((y[:-1] < 0.0) & (y[1:] >= 0.0))
    crossings_s = (rising + y[rising] / (y[rising] - y[rising + 1])) * PERIOD_S
    expected_s = 2 * math.pi * math.sqrt(train.total_inertia_kg_m2 / train.gravity_torque_nm)
    assert len(crossings_s) >= 4
    assert np.mean(np.diff(crossings_s)) == pytest.approx(expected_s, rel=1e-3)


def test_coulomb_friction_leaves_a_steady_lag_of_friction_over_stiffness_on_a_slow_ramp():
    # with velocity feedforward the P loop has no velocity lag; at constant speed the shaft carries T_c, so
    # the load lags by T_c / k (shaft twist) + T_c / (K_v K_p) (the servo's static stiffness). The command
    # is held over each sample: y_{k+1} - r_k is that lag minus half a sample of travel v T / 2.
    coulomb = 0.1
    train = DriveTrain(**{**STIFF, "shaft_stiffness_nm_per_rad": 50.0, "shaft_damping_nm_s_per_rad": 0.2},
                       velocity_feedforward=1.0, coulomb_friction_nm=coulomb, static_friction_nm=0.15)
    speed = 0.2
    r = speed * np.arange(3000) * PERIOD_S
    y = train.apply(r)
    lag = r[-501:-1] - y[-500:]
    expected = coulomb / train.shaft_stiffness_nm_per_rad + coulomb / train.servo_stiffness_nm_per_rad
    assert np.ptp(lag) < 1e-9  # steady
    assert lag.mean() == pytest.approx(expected - speed * PERIOD_S / 2, rel=1e-5)


def test_stiction_holds_the_load_until_the_breakaway_torque_is_exceeded():
    # the command creeps up; the shaft winds up while the load sticks at exactly its rest angle, and it
    # breaks away in the sample in which the shaft's torque exceeds T_s (the trajectory holds the states at
    # the sample instants: the first not stuck is the sample after the breakaway)
    breakaway = 0.15
    train = DriveTrain(**{**STIFF, "shaft_stiffness_nm_per_rad": 50.0, "shaft_damping_nm_s_per_rad": 0.2},
                       velocity_feedforward=1.0, coulomb_friction_nm=0.1, static_friction_nm=breakaway)
    trajectory = train.simulate(0.2 * np.arange(300) * PERIOD_S)
    moved = int(np.flatnonzero(~trajectory.stuck)[0])
    assert np.all(trajectory.load_angle_rad[:moved] == 0.0)
    assert np.all(trajectory.shaft_torque_nm[:moved - 1] <= breakaway)
    assert np.all(trajectory.friction_torque_nm[:moved - 1] == trajectory.shaft_torque_nm[:moved - 1])
    assert trajectory.shaft_torque_nm[moved] > breakaway - 0.01  # within one sample's rise (about 2e-3 N m)
    assert trajectory.load_angle_rad[moved + 5] > 0.0


def test_play_shows_as_lost_motion_equal_to_its_width_when_the_command_reverses():
    # up and down a slow ramp; at equal load angle the two branches are apart by the play b plus the friction's
    # twist on both sides, 2 T_c (1/k + 1/(K_v K_p)), less one sample of travel v T (zero-order hold); checked
    # to a tenth of a sub-step's travel v h
    play = 0.05
    coulomb = 0.02
    train = DriveTrain(**STIFF, velocity_feedforward=1.0, coulomb_friction_nm=coulomb, static_friction_nm=coulomb,
                       play_rad=play)
    up = np.linspace(0.0, 0.5, 2500)
    speed = 0.5 / (2499 * PERIOD_S)
    r = np.concatenate([up, up[::-1]])
    y = train.apply(r)
    rising_y, rising_r = y[1:2501], r[:2500]
    falling_y, falling_r = y[2501:][::-1], r[2500:-1][::-1]
    lost = np.interp(0.25, rising_y, rising_r) - np.interp(0.25, falling_y, falling_r)
    twist = 2 * coulomb * (1 / train.shaft_stiffness_nm_per_rad + 1 / train.servo_stiffness_nm_per_rad)
    substep_travel = speed * PERIOD_S / train.substeps_per_sample
    assert lost == pytest.approx(play + twist - speed * PERIOD_S, abs=0.1 * substep_travel)
    # without the play the same run shows only the friction's twist
    rigid = DriveTrain(**STIFF, velocity_feedforward=1.0, coulomb_friction_nm=coulomb, static_friction_nm=coulomb)
    y = rigid.apply(r)
    lost = np.interp(0.25, y[1:2501], rising_r) - np.interp(0.25, y[2501:][::-1], falling_r)
    assert lost == pytest.approx(twist - speed * PERIOD_S, abs=0.1 * substep_travel)


def test_rate_and_torque_limits_hold():
    speed_limit, torque_limit = 20.0, 0.05  # at the motor: 2 rad/s and 0.5 N m at the load
    train = DriveTrain(**STIFF, motor_speed_limit_rad_per_s=speed_limit, motor_torque_limit_nm=torque_limit)
    trajectory = train.simulate(np.ones(2000))
    assert np.max(np.abs(trajectory.motor_torque_nm)) <= torque_limit
    assert np.max(np.abs(trajectory.motor_torque_nm)) == torque_limit  # reached: the start is torque-limited
    assert np.max(np.abs(trajectory.motor_velocity_rad_per_s)) <= speed_limit * (1 + 1e-9)
    slope = np.diff(trajectory.load_angle_rad) / PERIOD_S
    assert slope.max() == pytest.approx(speed_limit / train.gear_ratio, rel=1e-6)  # reached and held
    assert trajectory.load_angle_rad[-1] == pytest.approx(1.0, abs=1e-6)
    # a torque limit below the gravity torque: the arm settles where m g l sin(theta) = N tau_max
    gravity = DriveTrain(**STIFF, pendulum_mass_kg=0.5, pendulum_length_m=0.1, motor_torque_limit_nm=0.03,
                         viscous_friction_nm_s_per_rad=0.05)
    y = gravity.apply(np.full(8000, 1.5))
    assert y[-1] == pytest.approx(math.asin(gravity.gear_ratio * 0.03 / gravity.gravity_torque_nm), abs=1e-4)


def _everything():
    return DriveTrain(**{**STIFF, "shaft_stiffness_nm_per_rad": 200.0}, play_rad=0.01, velocity_feedforward=0.5,
                      position_integral_gain_per_s=2.0, position_feedback="load", motor_speed_limit_rad_per_s=30.0,
                      motor_torque_limit_nm=0.08, motor_viscous_damping_nm_s_per_rad=1e-5, coulomb_friction_nm=0.05,
                      static_friction_nm=0.08, viscous_friction_nm_s_per_rad=0.01, pendulum_mass_kg=0.5,
                      pendulum_length_m=0.1, hanging_angle_rad=0.1, initial_angle_rad=0.2)


def test_stepping_gives_apply_and_simulate_bit_for_bit():
    train = _everything()
    rng = np.random.default_rng(15)
    command = np.cumsum(rng.normal(0.0, 0.01, 1500)) + np.where(np.arange(1500) % 500 < 250, 0.5, -0.5)
    stepper = train.stepper()
    stepped = np.array([stepper.step(r) for r in command])
    assert np.array_equal(stepped, train.apply(command))
    assert np.array_equal(stepped, train.simulate(command).load_angle_rad)
    chain = PlantModel((Delay(1), train, OutputOffset(0.01, 0.0, PERIOD_S)))
    plant_stepper = chain.stepper()
    assert np.array_equal(np.array([plant_stepper.step(r) for r in command]), chain.simulate(command))
    stepper.reset(train.initial_angle_rad)
    assert np.array_equal(np.array([stepper.step(r) for r in command]), stepped)


def test_energy_is_conserved_without_damping_friction_or_drive():
    # drive off, no dampers, no friction: a pendulum released at 1 rad hits both sides of the play and rings
    # the shaft; Stoermer-Verlet keeps the total energy within 1e-3 (relative), here over 5 s, 5000 samples
    train = DriveTrain(**{**STIFF, "shaft_damping_nm_s_per_rad": 0.0}, play_rad=0.02, pendulum_mass_kg=0.5,
                       pendulum_length_m=0.1, drive_enabled=False, initial_angle_rad=1.0)
    trajectory = train.simulate(np.zeros(5000))
    energy = train.energy_j(trajectory)
    assert np.max(np.abs(energy / energy[0] - 1.0)) < 1e-3
    twist = trajectory.motor_angle_rad / train.gear_ratio - trajectory.load_angle_rad
    assert twist.max() > 0.01 and twist.min() < -0.01  # the play was crossed both ways
    # the hard case: the shaft pre-twisted 0.04 rad into contact (most of the energy in the 167 Hz mode),
    # ringing through the play, energy read at every sample
    stepper = train.stepper()
    stepper.reset(0.0)
    stepper.phi = 0.05
    half = 0.5 * train.play_rad
    energies = []
    for _ in range(3000):
        twist = stepper.phi - stepper.theta
        dead = twist - half if twist > half else (twist + half if twist < -half else 0.0)
        energies.append(0.5 * train.reflected_motor_inertia_kg_m2 * stepper.omega_phi**2
                        + 0.5 * train.load_inertia_kg_m2 * stepper.omega**2
                        + 0.5 * train.shaft_stiffness_nm_per_rad * dead**2
                        + train.gravity_torque_nm * (1.0 - math.cos(stepper.theta)))
        stepper.step(0.0)
    energies = np.array(energies)
    assert np.max(np.abs(energies / energies[0] - 1.0)) < 1e-3


def test_pendulum_servo_config_round_trips_and_gives_identical_output():
    config = load_plant_config(PLANTS / "pendulum_servo.toml")
    (train,) = config.plant.blocks
    assert isinstance(train, DriveTrain) and train.position_feedback == "load"
    assert train.sample_period_s == config.sample_period_s == 0.01
    again = plant_config_from_toml_text(plant_config_to_toml(config))
    assert again.blocks == config.blocks
    third = plant_config_from_toml_text(plant_config_to_toml(again))
    command = np.concatenate([np.zeros(20), np.full(150, 1.2), np.linspace(1.2, -1.0, 230)])
    y = config.plant.simulate(command)
    assert np.array_equal(y, again.plant.simulate(command))
    assert np.array_equal(y, third.plant.simulate(command))
    # the P loop on the output encoder holds the arm short of the goal by gravity over the servo's stiffness
    assert 1.0 < y[160] < 1.2
    gearbox = config.gearbox()
    run = gearbox.simulate(command)
    assert np.array_equal(run.load_angle_rad, y)
    assert np.array_equal([gearbox.step(r).measured_angle_rad for r in command], run.measured_angle_rad)


def test_drive_train_keys_are_the_constructors_and_limits_left_out_are_none():
    fields = {field.name for field in dataclasses.fields(DriveTrain)} - {"sample_period_s"}
    assert set(DRIVE_TRAIN_KEYS) == fields
    text = ('sample_period_s = 0.001\n[encoder]\nbits = 12\n[[blocks]]\ntype = "drive_train"\n'
            "gear_ratio = 10.0\nmotor_inertia_kg_m2 = 1e-5\nload_inertia_kg_m2 = 0.01\n"
            "shaft_stiffness_nm_per_rad = 1000.0\n")
    (train,) = plant_config_from_toml_text(text).blocks
    assert train.motor_torque_limit_nm == math.inf and train.motor_speed_limit_rad_per_s == math.inf
    assert "motor_torque_limit_nm" not in plant_config_to_toml(plant_config_from_toml_text(text))


@pytest.mark.parametrize(("line", "key", "problem"), [
    ("shaft_stiffnes_nm_per_rad = 3.0", "blocks[0].shaft_stiffnes_nm_per_rad", "unknown key"),
    ("play_rad = -0.01", "blocks[0].play_rad", ">= 0"),
    ("static_friction_nm = 0.01\ncoulomb_friction_nm = 0.02", "blocks[0].static_friction_nm", "coulomb_friction_nm"),
    ('position_feedback = "encoder"', "blocks[0].position_feedback", "expected one of"),
    ("pendulum_mass_kg = 10.0\npendulum_length_m = 0.2", "blocks[0].load_inertia_kg_m2", "m l^2"),
])
def test_drive_train_config_errors_name_the_key(line, key, problem):
    text = ('sample_period_s = 0.001\n[encoder]\nbits = 12\n[[blocks]]\ntype = "drive_train"\n'
            "gear_ratio = 10.0\nmotor_inertia_kg_m2 = 1e-5\nload_inertia_kg_m2 = 0.01\n"
            f"shaft_stiffness_nm_per_rad = 1000.0\n{line}\n")
    with pytest.raises(ConfigError) as caught:
        plant_config_from_toml_text(text)
    assert caught.value.key == key, str(caught.value)
    assert problem in caught.value.problem


BAD_VALUES = {
    "sample_period_s": 0.0, "gear_ratio": -2.0, "motor_inertia_kg_m2": 0.0, "load_inertia_kg_m2": math.nan,
    "shaft_stiffness_nm_per_rad": -1.0, "shaft_damping_nm_s_per_rad": -0.1, "play_rad": -1e-3,
    "shaft_friction_nm": -0.1, "shaft_presliding_twist_rad": 0.0,
    "position_loop_bandwidth_hz": 0.0, "position_loop_damping_ratio": -0.7, "velocity_feedforward": 1.5,
    "position_integral_gain_per_s": -1.0, "position_feedback": "both", "motor_speed_limit_rad_per_s": 0.0,
    "motor_torque_limit_nm": -1.0, "motor_viscous_damping_nm_s_per_rad": math.inf, "coulomb_friction_nm": -0.1,
    "static_friction_nm": -0.1, "viscous_friction_nm_s_per_rad": -0.1, "pendulum_mass_kg": -1.0,
    "pendulum_length_m": -0.1, "gravity_m_per_s2": 0.0, "hanging_angle_rad": math.inf,
    "initial_angle_rad": math.nan, "drive_enabled": "yes",
}


def test_every_parameter_has_a_bad_value_case():
    assert set(BAD_VALUES) == {field.name for field in dataclasses.fields(DriveTrain)}


@pytest.mark.parametrize("name", sorted(BAD_VALUES))
def test_every_parameter_is_validated_with_an_error_naming_it(name):
    with pytest.raises(ValueError, match=f"^{name}:"):
        DriveTrain(**{**STIFF, name: BAD_VALUES[name]})


def _two_mass_ode_run(train, command):
    """The load angle of ``train`` (no play, no load friction, P-P loop on the motor) by an adaptive
    eighth-order Runge-Kutta solution of its continuous equations, the command held over each sample:
    J_m' phi'' = K_v (K_p (r - phi) - phi') - tau_s, J_l theta'' = tau_s - d_v theta',
    tau_s = k Delta + d Delta' + T_h w, w' = Delta' (1 - w sgn Delta') / d_h (Dahl 1976)."""
    from scipy.integrate import solve_ivp

    motor, load = train.reflected_motor_inertia_kg_m2, train.load_inertia_kg_m2
    k, d, viscous = train.shaft_stiffness_nm_per_rad, train.shaft_damping_nm_s_per_rad, train.viscous_friction_nm_s_per_rad
    friction, presliding = train.shaft_friction_nm, train.shaft_presliding_twist_rad
    kp, kv = train.position_gain_per_s, train.velocity_gain_nm_s_per_rad

    def rhs(_t, x, r):
        phi, omega_phi, theta, omega, w = x
        twist_rate = omega_phi - omega
        shaft = k * (phi - theta) + d * twist_rate + friction * w
        drive = kv * (kp * (r - phi) - omega_phi)
        return [omega_phi, (drive - shaft) / motor, omega, (shaft - viscous * omega) / load,
                twist_rate * (1.0 - w * np.sign(twist_rate)) / presliding]

    x = np.zeros(5)
    out = np.empty(command.size)
    for i, r in enumerate(command):
        out[i] = x[2]
        x = solve_ivp(rhs, (0.0, train.sample_period_s), x, args=(float(r),), method="DOP853", rtol=1e-10,
                      atol=1e-13).y[:, -1]
    return out


def test_friction_inside_the_shaft_follows_dahls_equations():
    # a 2 Hz sine of 0.5 rad accelerates the load at up to 79 rad/s^2 (0.79 N m through the shaft); the shaft's
    # friction of 0.3 N m moves the load by up to 1.6 mrad. The train's sub-steps solve the same equations as an
    # adaptive Runge-Kutta to within 1e-4 rad, as they do without the friction (5.3e-5 rad measured either way:
    # the Störmer-Verlet error of the train, not of the friction's exact update)
    train = DriveTrain(**{**STIFF, "shaft_stiffness_nm_per_rad": 200.0, "shaft_damping_nm_s_per_rad": 0.2},
                       shaft_friction_nm=0.3, shaft_presliding_twist_rad=1e-3)
    command = 0.5 * np.sin(2.0 * math.pi * 2.0 * np.arange(1000) * PERIOD_S)
    y = train.apply(command)
    frictionless = dataclasses.replace(train, shaft_friction_nm=0.0).apply(command)
    assert np.max(np.abs(y - frictionless)) > 1.5e-3
    assert np.max(np.abs(y - _two_mass_ode_run(train, command))) < 1e-4
    # rate independent and bounded: the friction torque never exceeds T_h, the train steps as it applies
    trajectory = train.simulate(command)
    twist = trajectory.motor_angle_rad / train.gear_ratio - trajectory.load_angle_rad
    twist_rate = trajectory.motor_velocity_rad_per_s / train.gear_ratio - trajectory.load_velocity_rad_per_s
    friction = trajectory.shaft_torque_nm - 200.0 * twist - 0.2 * twist_rate
    assert np.max(np.abs(friction)) <= 0.3 * (1.0 + 1e-12)
    assert np.max(np.abs(friction)) > 0.29
    stepper = train.stepper()
    np.testing.assert_array_equal([stepper.step(r) for r in command], y)


def test_a_rigid_shaft_with_friction_inside_is_refused():
    with pytest.raises(InvalidInputError, match="^shaft_friction_nm: a rigid shaft"):
        DriveTrain(**{**STIFF, "shaft_stiffness_nm_per_rad": math.inf}, shaft_friction_nm=0.1)


def test_a_train_too_stiff_for_its_sample_period_is_refused():
    with pytest.raises(InvalidInputError, match="^shaft_stiffness_nm_per_rad: .* sub-steps per sample"):
        DriveTrain(**{**STIFF, "shaft_stiffness_nm_per_rad": 1e9})


def test_angles_see_only_torques_per_inertia_and_load_side_quantities():
    # what identification from (command, angle) can name: scaling every inertia, stiffness, damping, friction,
    # gravity and torque limit by one factor, or the gear ratio with J_m / N^2 and the motor-side limits,
    # leaves the angle unchanged (so a fitted candidate states friction / J in rad/s^2, not N m)
    train = _everything()
    command = np.concatenate([np.zeros(20), np.full(400, 0.8), np.linspace(0.8, -0.6, 600)])
    y = train.apply(command)
    scale = 3.0
    torque_like = ("motor_inertia_kg_m2", "load_inertia_kg_m2", "shaft_stiffness_nm_per_rad", "shaft_damping_nm_s_per_rad",
                   "motor_torque_limit_nm", "motor_viscous_damping_nm_s_per_rad", "coulomb_friction_nm",
                   "static_friction_nm", "viscous_friction_nm_s_per_rad", "pendulum_mass_kg")
    heavier = dataclasses.replace(train, **{name: scale * getattr(train, name) for name in torque_like})
    np.testing.assert_allclose(heavier.apply(command), y, rtol=0, atol=1e-12)
    ratio = 4.0
    geared = dataclasses.replace(train, gear_ratio=ratio * train.gear_ratio,
                                 motor_inertia_kg_m2=train.motor_inertia_kg_m2 / ratio**2,
                                 motor_viscous_damping_nm_s_per_rad=train.motor_viscous_damping_nm_s_per_rad / ratio**2,
                                 motor_speed_limit_rad_per_s=ratio * train.motor_speed_limit_rad_per_s,
                                 motor_torque_limit_nm=train.motor_torque_limit_nm / ratio)
    np.testing.assert_allclose(geared.apply(command), y, rtol=0, atol=1e-12)


# the trains of the tests above (and their rigid form), against the pure-Python recurrence the compiled kernel
# replaced (tests/identify/drive_train_reference.py)
REFERENCE_CASES = {
    "stiff": dict(STIFF),
    "load feedback with gravity": dict(STIFF, pendulum_mass_kg=0.5, pendulum_length_m=0.1,
                                       viscous_friction_nm_s_per_rad=0.05, position_feedback="load"),
    "free pendulum": dict(STIFF, pendulum_mass_kg=0.5, pendulum_length_m=0.1, drive_enabled=False,
                          initial_angle_rad=0.02),
    "stiction": dict(STIFF, shaft_stiffness_nm_per_rad=50.0, shaft_damping_nm_s_per_rad=0.2, velocity_feedforward=1.0,
                     coulomb_friction_nm=0.1, static_friction_nm=0.15),
    "limits": dict(STIFF, motor_speed_limit_rad_per_s=20.0, motor_torque_limit_nm=0.05),
    "rigid with everything": dict(STIFF, shaft_stiffness_nm_per_rad=math.inf, velocity_feedforward=0.5,
                                  position_integral_gain_per_s=2.0, motor_speed_limit_rad_per_s=30.0,
                                  motor_torque_limit_nm=0.08, motor_viscous_damping_nm_s_per_rad=1e-5,
                                  coulomb_friction_nm=0.05, static_friction_nm=0.08, viscous_friction_nm_s_per_rad=0.01,
                                  pendulum_mass_kg=0.5, pendulum_length_m=0.1, hanging_angle_rad=0.1),
}


@pytest.mark.parametrize("case", [*REFERENCE_CASES, "everything"])
def test_the_compiled_recurrence_gives_the_pure_python_one_within_1e_12(case):
    train = _everything() if case == "everything" else DriveTrain(**REFERENCE_CASES[case])
    rng = np.random.default_rng(15)
    command = np.cumsum(rng.normal(0.0, 0.01, 1200)) + np.where(np.arange(1200) % 400 < 200, 0.5, -0.5)
    reference = reference_load_angle_rad(train, command)
    assert np.ptp(reference) > 0.03  # the case moves (the free pendulum swings by +-0.02 rad)
    np.testing.assert_allclose(train.apply(command), reference, rtol=1e-12, atol=1e-12 * np.max(np.abs(reference)))
