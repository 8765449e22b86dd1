"""The catalogue's effects inside the drive's dynamics (placement ``"dynamics"`` of
:mod:`identify.effect_catalogue`): how each is put into a :class:`~identify.drive_train.DriveTrain`.

For friction on the load, gravity, the drive's speed and torque limits, a play between the motor and the load
and friction inside the shaft: the train fields its free values set (``*_fields``, per unit inertia: positions
alone show a torque T only as T / J), the values it reports, the initial guesses of its fit, the hidden
blocks the test records draw (``random_*``) and how finely a record resolves its size. The catalogue's entries
refer to these (they are its parts, not an API: ``__all__`` holds the constants and :func:`reference_train`, the
normalised train the effects go into when the model has none).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from identify.drive_train import DriveTrain

if TYPE_CHECKING:
    from identify.effect_catalogue import GuessContext
    from identify.plant_blocks import Block

__all__ = ["PLAY_CONTACT_DAMPING_RATIO", "PLAY_CONTACT_FREQUENCY_RATIO", "REFERENCE_BANDWIDTH_HZ",
           "REFERENCE_DAMPING_RATIO", "SHAFT_FRICTION_MAX_STIFFENING", "reference_train"]


REFERENCE_BANDWIDTH_HZ = 30.0
REFERENCE_DAMPING_RATIO = 0.7
"""The position loop of :func:`reference_train` when no start model says otherwise (the drive loop of the
hidden-effect records, :mod:`identify.discrepancy_cases`)."""


def reference_train(sample_period_s: float, bandwidth_hz: float = REFERENCE_BANDWIDTH_HZ,
                    damping_ratio: float = REFERENCE_DAMPING_RATIO) -> DriveTrain:
    """The normalised rigid drive train the workflow fits: gear 1, total inertia J = 1 kg m^2 (0.5 at the
    motor, 0.5 at the load: with a rigid shaft only the sum matters), a P-P cascade of ``bandwidth_hz`` and
    ``damping_ratio`` and nothing else. With J = 1 a torque in N m is the acceleration T / J it causes in
    rad/s^2, which is what positions alone can show."""
    return DriveTrain(sample_period_s=sample_period_s, gear_ratio=1.0, motor_inertia_kg_m2=0.5,
                      load_inertia_kg_m2=0.5, shaft_stiffness_nm_per_rad=math.inf,
                      position_loop_bandwidth_hz=bandwidth_hz, position_loop_damping_ratio=damping_ratio)


def _loop_stiffness_per_inertia(train: DriveTrain) -> float:
    """The load's stiffness per inertia: a torque T / J on the load of a rigid train leaves a static position
    error T / (J omega_n^2) in its P loop, which holds the motor; a shaft of stiffness k between them twists
    by T / k more: 1 / (1 / omega_n^2 + J / k)."""
    compliance = 1.0 / train.natural_frequency_rad_per_s ** 2
    if not train.rigid:
        compliance += train.total_inertia_kg_m2 / train.shaft_stiffness_nm_per_rad
    return 1.0 / compliance


def friction_fields(v: Sequence[float], train: DriveTrain) -> dict[str, Any]:
    # the viscous friction adds to what the train has (a two-mass train fitted to a linear block keeps its
    # load's own); Coulomb and breakaway friction are the effect's alone
    inertia = train.total_inertia_kg_m2
    coulomb = abs(v[0])
    return {"coulomb_friction_nm": coulomb * inertia, "static_friction_nm": (coulomb + abs(v[1])) * inertia,
            "viscous_friction_nm_s_per_rad": train.viscous_friction_nm_s_per_rad + abs(v[2]) * inertia}


def gravity_fields(v: Sequence[float], train: DriveTrain) -> dict[str, Any]:
    # m g l / J = |v0|: keep the train's arm (m, l) if it has one, else an arm of the load's inertia at 1 m
    # (m l^2 = J_l, the largest point mass the load inertia allows), and set g
    if train.pendulum_mass_kg * train.pendulum_length_m > 0.0:
        mass, length = train.pendulum_mass_kg, train.pendulum_length_m
    else:
        mass, length = train.load_inertia_kg_m2, 1.0
    per_inertia = max(abs(v[0]), 1e-9)
    return {"pendulum_mass_kg": mass, "pendulum_length_m": length, "hanging_angle_rad": float(v[1]),
            "gravity_m_per_s2": per_inertia * train.total_inertia_kg_m2 / (mass * length)}


def rate_fields(v: Sequence[float], train: DriveTrain) -> dict[str, Any]:
    return {"motor_speed_limit_rad_per_s": max(abs(v[0]), 1e-6) * train.gear_ratio}


def torque_fields(v: Sequence[float], train: DriveTrain) -> dict[str, Any]:
    return {"motor_torque_limit_nm": max(abs(v[0]), 1e-6) * train.total_inertia_kg_m2 / train.gear_ratio}


def train_builder(fields: Callable[[Sequence[float], DriveTrain], dict[str, Any]]) -> Callable[[Sequence[float], float], Block]:
    return lambda v, period: replace(reference_train(period), **fields(v, reference_train(period)))


def friction_report(b: DriveTrain) -> dict[str, float]:
    inertia = b.total_inertia_kg_m2
    return {"coulomb_per_inertia_rad_per_s2": b.coulomb_friction_nm / inertia,
            "static_per_inertia_rad_per_s2": b.static_friction_nm / inertia,
            "viscous_per_inertia_per_s": b.viscous_friction_nm_s_per_rad / inertia}


def _band_levels(context: GuessContext, count: int) -> NDArray[np.float64]:
    """Static position errors from the noise bound to the residual's amplitude, as T / J = error omega_n^2."""
    assert context.train is not None
    return context.levels(count) * _loop_stiffness_per_inertia(context.train)


def load_friction_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # Coulomb friction T_c / J that holds the load within a band of the noise bound .. the residual's
    # amplitude; breakaway 1 or 1.5 times it; a little viscous friction (2 % of the loop's damping
    # 2 zeta omega_n: a start at exactly 0 would not move in the scaled polish)
    assert context.train is not None
    viscous = _viscous_guess(context.train)
    return [(c, excess * c, viscous) for c in _band_levels(context, 6) for excess in (0.01, 0.5)]


def _viscous_guess(train: DriveTrain) -> float:
    """d_v / J of 2 % of the damping that moves with the load (a start at exactly 0 would not move in the
    scaled polish): in a rigid train the loop's 2 zeta omega_n; behind a shaft the load's critical damping on
    it, 2 sqrt(k J_l) / J."""
    if train.rigid:
        return 0.02 * 2.0 * train.position_loop_damping_ratio * train.natural_frequency_rad_per_s
    return 0.02 * 2.0 * math.sqrt(train.shaft_stiffness_nm_per_rad * train.load_inertia_kg_m2) / train.total_inertia_kg_m2


def friction_width_starts(width_rad: float, train: DriveTrain) -> list[tuple[float, ...]]:
    # half the twin's hysteresis is the friction's static error 2 T_c / (J omega_n^2) (Effect.width_starts);
    # and a breakaway excess of 1 % as in the guesses
    coulomb = 0.25 * width_rad * _loop_stiffness_per_inertia(train)
    return [(coulomb, 0.01 * coulomb, _viscous_guess(train))]


def gravity_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # the sag the gravity signature fitted (m g l / J = sag omega_n^2, theta_0 from its phase), and levels
    score = context.scores.get("gravity")
    guesses = []
    assert context.train is not None
    if score is not None and score.details.get("sag_amplitude_rad", 0.0) > 0.0:
        guesses.append((score.details["sag_amplitude_rad"] * _loop_stiffness_per_inertia(context.train),
                        score.details["hanging_angle_rad"]))
    # theta_0 = +-0.1 rad (a start at exactly 0 would not move in the scaled polish)
    return guesses + [(g, side * 0.1) for g in _band_levels(context, 5) for side in (-1.0, 1.0)]


def _peaks(context: GuessContext, order: int) -> tuple[float, float]:
    """The peak speed (order 1) or acceleration (order 2) of the start model's free run and of the
    measurement (y = y^ + r; its acceleration, noisy at a count per T^2, is not used: 0)."""
    simulated = context.simulated_rad if context.simulated_rad is not None else np.zeros_like(context.residual_rad)
    model, measured = simulated, simulated + context.residual_rad
    for _ in range(order):
        model = np.gradient(model) / context.sample_period_s
        measured = np.gradient(measured) / context.sample_period_s
    return float(np.max(np.abs(model))), (float(np.max(np.abs(measured))) if order == 1 else 0.0)


def rate_limit_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # a limit below the model's peak speed (else it changes nothing), and the measured peak speed
    model, measured = _peaks(context, 1)
    return [(fraction * model,) for fraction in (0.3, 0.5, 0.7, 0.9)] + ([(measured,)] if 0 < measured < model else [])


def torque_limit_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    model, _ = _peaks(context, 2)
    return [(fraction * model,) for fraction in (0.1, 0.2, 0.35, 0.5, 0.7, 0.9)]


def _segment_peak(rng: np.random.Generator, u: NDArray[np.float64], estimation_fraction: float, period: float,
                  order: int) -> float:
    """The smaller of the two segments' peak speed (order 1) or acceleration (order 2) of the reference
    train's free run: a hidden limit below it is reached in both segments."""
    y = reference_train(period).apply(u)
    for _ in range(order):
        y = np.gradient(y) / period
    split = int(round(estimation_fraction * u.size))
    return min(float(np.max(np.abs(y[:split]))), float(np.max(np.abs(y[split:]))))


def random_load_friction(rng: np.random.Generator, u: NDArray[np.float64], f: float, period: float) -> Block:
    # Coulomb friction holding the load within 8-25 mrad of the reference loop (30 Hz: T_c / J of 280-890
    # rad/s^2), breakaway 1-1.5 times it, viscous up to a fifth of the loop's own damping 2 zeta omega_n
    stiffness = _loop_stiffness_per_inertia(reference_train(period))
    coulomb = rng.uniform(0.008, 0.025) * stiffness
    loop_damping = 2.0 * REFERENCE_DAMPING_RATIO * 2.0 * math.pi * REFERENCE_BANDWIDTH_HZ
    return train_builder(friction_fields)((coulomb, coulomb * rng.uniform(0.0, 0.5),
                                             rng.uniform(0.0, 0.2) * loop_damping), period)


def random_gravity(rng: np.random.Generator, u: NDArray[np.float64], f: float, period: float) -> Block:
    # an arm whose weight sags the 30 Hz loop by 10-40 mrad when horizontal, hanging within +-0.5 rad of 0
    stiffness = _loop_stiffness_per_inertia(reference_train(period))
    return train_builder(gravity_fields)((rng.uniform(0.010, 0.040) * stiffness, rng.uniform(-0.5, 0.5)), period)


def random_rate_limit(rng: np.random.Generator, u: NDArray[np.float64], f: float, period: float) -> Block:
    # 40-70 % of the peak speed both segments reach
    return train_builder(rate_fields)((rng.uniform(0.4, 0.7) * _segment_peak(rng, u, f, period, 1),), period)


def random_torque_limit(rng: np.random.Generator, u: NDArray[np.float64], f: float, period: float) -> Block:
    # 30-60 % of the peak acceleration both segments reach
    return train_builder(torque_fields)((rng.uniform(0.3, 0.6) * _segment_peak(rng, u, f, period, 2),), period)



PLAY_CONTACT_FREQUENCY_RATIO = 8.0
PLAY_CONTACT_DAMPING_RATIO = 0.5
"""The shaft that closes the play of ``shaft_play`` in a rigid train: its two-mass mode in contact is this
many times the position loop's omega_n, with this damping ratio. Positions sampled at a few times the loop's
bandwidth cannot resolve a contact mode that far above it (a stiffer contact only costs sub-steps: 8 omega_n
at 30 Hz and 1 kHz is 38 per sample), and zeta = 0.5 lets an impact rebound by exp(-pi zeta / sqrt(1 -
zeta^2)) = 16 % of its closing speed. A train with its own finite shaft keeps its stiffness and damping."""


def _shaft_of_mode(train: DriveTrain, frequency_ratio: float, damping_ratio: float) -> dict[str, Any]:
    """The shaft fields that give ``train``'s two inertias a two-mass mode at ``frequency_ratio`` times its
    loop's omega_n with ``damping_ratio``: k = w^2 / c, d = 2 zeta w / c with c = 1/J_m' + 1/J_l."""
    compliance = 1.0 / train.reflected_motor_inertia_kg_m2 + 1.0 / train.load_inertia_kg_m2
    mode = frequency_ratio * train.natural_frequency_rad_per_s
    return {"shaft_stiffness_nm_per_rad": mode**2 / compliance,
            "shaft_damping_nm_s_per_rad": 2.0 * damping_ratio * mode / compliance}


def _contact_shaft(train: DriveTrain) -> dict[str, Any]:
    """The shaft fields of ``train``: its own if it has a finite shaft, else the contact shaft of
    :data:`PLAY_CONTACT_FREQUENCY_RATIO` (what closes a play, or holds a friction, put into a rigid train)."""
    if not train.rigid:
        return {"shaft_stiffness_nm_per_rad": train.shaft_stiffness_nm_per_rad,
                "shaft_damping_nm_s_per_rad": train.shaft_damping_nm_s_per_rad}
    return _shaft_of_mode(train, PLAY_CONTACT_FREQUENCY_RATIO, PLAY_CONTACT_DAMPING_RATIO)


def play_fields(v: Sequence[float], train: DriveTrain) -> dict[str, Any]:
    # the dead-zone shaft of Nordin and Gutman (2002) between the two inertias, |v0| its total width
    return {"play_rad": abs(v[0]), **_contact_shaft(train)}


def shaft_play_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # total widths from the noise bound to twice the residual's amplitude (a play of width b leaves the load
    # up to b / 2 either side of the motor)
    return [(b,) for b in np.geomspace(context.noise_bound_rad, 2.0 * context.residual_amplitude_rad, 8)]


def random_shaft_play(rng: np.random.Generator, u: NDArray[np.float64], f: float, period: float) -> Block:
    # a total play of 20-60 mrad at the load (output backlash's hidden half-widths are 10-40 mrad a side)
    return train_builder(play_fields)((rng.uniform(0.02, 0.06),), period)


SHAFT_FRICTION_MAX_STIFFENING = 20.0
"""The shaft's friction is at most this many times as stiff as its spring when it starts to stick (T_h / d_h
<= 20 k: a presliding twist below a twentieth of the friction's twist T_h / k is held there), so the train
needs at most sqrt(1 + 2 * 20) = 6.4 times the sub-steps of its spring alone (the fit moves d_h freely, and an
unbounded stiffness would refuse the train for its sub-steps). A stiffer start changes the load's angle only
within that twentieth of the friction's twist after each reversal; the clean-room generator's couplings reach
10 k."""


def shaft_friction_fields(v: Sequence[float], train: DriveTrain) -> dict[str, Any]:
    # Dahl's friction inside the shaft: |v0| the twist T_h / k it holds against the spring, |v1| its
    # presliding twist d_h (at least a SHAFT_FRICTION_MAX_STIFFENING-th of |v0|)
    shaft = _contact_shaft(train)
    twist = abs(v[0])
    return {**shaft, "shaft_friction_nm": twist * shaft["shaft_stiffness_nm_per_rad"],
            "shaft_presliding_twist_rad": max(abs(v[1]), twist / SHAFT_FRICTION_MAX_STIFFENING, 1e-9)}


def shaft_friction_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # friction twists from the noise bound to the residual's amplitude (the load is left up to T_h / k off the
    # model where the shaft stops twisting), each sticking within a fifth of it or within all of it
    return [(twist, ratio * twist) for twist in context.levels(4) for ratio in (0.2, 1.0)]


def random_shaft_friction(rng: np.random.Generator, u: NDArray[np.float64], f: float, period: float) -> Block:
    # a compliant shaft (mode at twice the loop's bandwidth, damping ratio 0.05) whose friction holds 2-6 mrad
    # of twist, sticking within 20-100 % of that
    train = reference_train(period)
    shaft = replace(train, **_shaft_of_mode(train, 2.0, 0.05))
    twist = rng.uniform(2e-3, 6e-3)
    return replace(shaft, **shaft_friction_fields((twist, rng.uniform(0.2, 1.0) * twist), shaft))


def shaft_friction_report(b: DriveTrain) -> dict[str, float]:
    return {"friction_twist_rad": b.shaft_friction_nm / b.shaft_stiffness_nm_per_rad if not b.rigid else 0.0,
            "presliding_twist_rad": b.shaft_presliding_twist_rad}


def torque_resolution(train: DriveTrain, keys: Sequence[str], resolution_rad: float) -> dict[str, float]:
    """A torque per inertia shows as a static error T / (J omega_n^2) known within +-e: +-e omega_n^2."""
    return {key: resolution_rad * _loop_stiffness_per_inertia(train) for key in keys}


def _longest_run(mask: NDArray[np.bool_]) -> int:
    best = run = 0
    for flag in mask.tolist():
        run = run + 1 if flag else 0
        best = max(best, run)
    return best


def limit_resolution(train: DriveTrain, simulated: NDArray[np.float64], resolution_rad: float,
                      order: int) -> float:
    """A speed (order 1) or acceleration (order 2) limit is the slope or curvature of the free run over the
    longest stretch of n samples at the limit; with both ends known within +-e it is known within
    2 e / (n T) (speed) or 4 e / (n T)^2 (acceleration, from e = a (n T)^2 / 2 at each end)."""
    period = train.sample_period_s
    rate = np.asarray(simulated, dtype=float)
    for _ in range(order):
        rate = np.gradient(rate) / period
    limit = (train.motor_speed_limit_rad_per_s / train.gear_ratio if order == 1
             else train.motor_torque_limit_nm * train.gear_ratio / train.total_inertia_kg_m2)
    if not math.isfinite(limit):
        return 0.0
    samples = max(_longest_run(np.abs(rate) >= 0.98 * limit), 1)
    return (2.0 if order == 1 else 4.0) * resolution_rad / (samples * period) ** order


def static_error(train: DriveTrain, torque_per_inertia: float) -> float:
    return torque_per_inertia / _loop_stiffness_per_inertia(train)
