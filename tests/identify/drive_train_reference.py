"""The pure-Python drive-train stepper as it was before the recurrence was compiled with numba:
a reference for ``test_drive_train.py`` only, which checks the compiled kernel of
:mod:`identify.drive_train` against it within 1e-12 relative. Not used by the product."""

from __future__ import annotations

import math

import numpy as np

from identify.drive_train import DriveTrain


def reference_load_angle_rad(train: DriveTrain, command_rad: np.ndarray) -> np.ndarray:
    """Load angle at the start of each sample, by the Störmer-Verlet sub-steps of the module docstring."""
    ratio = train.gear_ratio
    motor_inertia = train.reflected_motor_inertia_kg_m2
    load_inertia = train.load_inertia_kg_m2
    stiffness, damping = train.shaft_stiffness_nm_per_rad, train.shaft_damping_nm_s_per_rad
    half_play = 0.5 * train.play_rad
    motor_damping = train.motor_viscous_damping_nm_s_per_rad * ratio * ratio
    coulomb, static = train.coulomb_friction_nm, train.static_friction_nm
    viscous, gravity, hanging = train.viscous_friction_nm_s_per_rad, train.gravity_torque_nm, train.hanging_angle_rad
    drive_on, load_feedback = train.drive_enabled, train.position_feedback == "load"
    kp, ki, kv = train.position_gain_per_s, train.position_integral_gain_per_s, train.velocity_gain_nm_s_per_rad
    feedforward, period = train.velocity_feedforward, train.sample_period_s
    speed_limit, torque_limit = train.motor_speed_limit_rad_per_s / ratio, train.motor_torque_limit_nm * ratio
    substeps = train.substeps_per_sample
    h = period / substeps
    kick = 0.5 * h
    rigid_inertia = train.total_inertia_kg_m2
    phi = theta = previous = train.initial_angle_rad
    omega_phi = omega = integral = 0.0
    stuck = True
    out = []

    def drive_torque(error, velocity, rate, integral):
        reference = kp * (error + ki * integral) + rate
        clamped = False
        if reference > speed_limit:
            reference, clamped = speed_limit, True
        elif reference < -speed_limit:
            reference, clamped = -speed_limit, True
        drive = kv * (reference - velocity)
        if drive > torque_limit:
            drive, clamped = torque_limit, True
        elif drive < -torque_limit:
            drive, clamped = -torque_limit, True
        return drive, clamped

    def half_kick(omega, external, stuck, inertia):
        momentum = inertia * omega + kick * external
        if stuck and -static <= external <= static:
            return omega, stuck
        if -kick * coulomb <= momentum <= kick * coulomb:
            return 0.0, True
        sliding = coulomb if momentum > 0.0 else -coulomb
        return (momentum - kick * sliding) / (inertia + kick * viscous), False

    for r in np.asarray(command_rad, dtype=float).tolist():
        out.append(theta)
        rate = feedforward * (r - previous) / period
        previous = r
        for _ in range(substeps):
            integrating = True
            for half in (0, 1):
                if train.rigid:
                    drive, clamped = drive_torque(r - theta, omega, rate, integral) if drive_on else (0.0, False)
                    external = drive - motor_damping * omega - gravity * math.sin(theta - hanging)
                    omega, stuck = half_kick(omega, external, stuck, rigid_inertia)
                    integrating = integrating and not clamped
                    if half == 0:
                        theta += h * omega
                    continue
                twist, twist_rate = phi - theta, omega_phi - omega
                if half_play == 0.0:
                    shaft = stiffness * twist + damping * twist_rate
                elif twist > half_play:
                    spring, damper = stiffness * (twist - half_play), damping * twist_rate
                    shaft = 0.0 if spring + damper <= 0.0 else spring + min(spring, damper)
                elif twist < -half_play:
                    spring, damper = stiffness * (twist + half_play), damping * twist_rate
                    shaft = 0.0 if spring + damper >= 0.0 else spring + max(spring, damper)
                else:
                    shaft = 0.0
                if drive_on:
                    drive, clamped = drive_torque(r - (theta if load_feedback else phi), omega_phi, rate, integral)
                else:
                    drive, clamped = 0.0, False
                integrating = integrating and not clamped
                omega_phi += kick * (drive - shaft - motor_damping * omega_phi) / motor_inertia
                omega, stuck = half_kick(omega, shaft - gravity * math.sin(theta - hanging), stuck, load_inertia)
                if half == 0:
                    phi += h * omega_phi
                    theta += h * omega
            if drive_on and integrating and ki != 0.0:
                integral += h * (r - (theta if load_feedback or train.rigid else phi))
        if train.rigid:
            phi, omega_phi = theta, omega
    return np.array(out)
