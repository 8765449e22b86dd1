"""The guesses, builders and random draws of the catalogue's signal-chain effects (placements ``input``,
``output`` and ``end``: a play or friction after the drive, a dead zone, a saturation, a mode, an offset, a gain
error, a drifting gain, an encoder error), and the constants that bound their fits; :mod:`identify.drive_train_effects` holds
those of the effects inside the drive train. The table itself, one :class:`~identify.effect_catalogue.Effect`
per effect, is :data:`identify.effect_catalogue.EFFECTS`; its entries refer to these (they are its parts, not an
API: ``__all__`` holds the constants).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from identify.plant_blocks import (Block, CoulombFriction, EncoderError, OutputBacklash, OutputGainDrift, Resonance,
                                   Saturation)

if TYPE_CHECKING:
    from identify.effect_catalogue import GuessContext

__all__ = ["ENCODER_ERROR_MAX_RAD", "FRICTION_STIFFNESS_NM_PER_RAD", "GAIN_DRIFT_TIME_CONSTANTS", "MAX_RESONANCE_DAMPING",
           "NEGLIGIBLE_GAIN_ERROR"]

NEGLIGIBLE_GAIN_ERROR = 1.0e-3
"""A fitted gain within this of 1 is no gain error: a 0.1 % scale error is below what the workflow resolves
on records of a few thousand samples with a 12-bit encoder (it moves a 1 rad step by 1 mrad, about half a
count)."""

# Evidence: a judgement of the largest error of a working encoder: an on-axis magnetic sensor whose magnet is off
# centre shows about a degree, an optical encoder arc-minutes; the generators' eccentricities are 0.5-8 mrad. Set
# when the gain error got the encoder error as its look-alike: our 6-8 % gain errors over +-0.8 rad were
# matched within the noise bound by encoder errors of 0.1 rad (hidden gain_error seeds 91 and 92).
ENCODER_ERROR_MAX_RAD = 0.02
"""The largest once- plus twice-per-revolution error (rad) a working encoder has: a fitted encoder error
beyond it is no look-alike of a gain error (catalogue ``implausible``, ``bounded_look_alikes``)."""

MAX_RESONANCE_DAMPING = 0.3
"""A resonance is a narrow peak: a fitted damping ratio is kept below this (a heavily damped second-order
section would otherwise stand in for a delay)."""

FRICTION_STIFFNESS_NM_PER_RAD = 1.0
"""The workflow fits Coulomb friction as twists (torques over a unit stiffness): from position data only the
ratio torque/stiffness is identifiable."""


def backlash_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    levels = context.levels()
    return [(left, right) for left in levels for right in levels]


def friction_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    slides = np.geomspace(context.noise_bound_rad, 2.0 * context.residual_amplitude_rad, 14)
    return [(r * c, c) for c in slides for r in (1.0, 1.25, 1.5, 1.8, 2.2, 2.8)]


def dead_zone_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # each edge on its own: a record may barely reach one side's edge, and a symmetric guess misses it
    span = float(np.max(np.abs(context.command_rad)))
    edges = np.geomspace(max(context.noise_bound_rad, 1e-3 * span), 0.3 * span, 6)
    return [(left, right) for left in edges for right in edges]


def saturation_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # each limit from the commands on its side: travel limits need not be symmetric
    u = context.command_rad
    levels = (0.3, 0.5, 0.7, 0.85, 0.95)
    below = np.quantile(-u[u < 0], levels) if np.any(u < 0) else np.zeros(1)
    above = np.quantile(u[u > 0], levels) if np.any(u > 0) else np.zeros(1)
    return [(float(low), float(high)) for low in below for high in above]


def resonance_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    nyquist = 0.5 / context.sample_period_s
    score = context.scores.get("resonance")
    peak = score.details.get("peak_frequency_hz", 0.1 * nyquist) if score is not None else 0.1 * nyquist
    frequencies = [f for f in (peak, *np.geomspace(0.02 * nyquist, 0.8 * nyquist, 16)) if 0.0 < f < 0.98 * nyquist]
    return [*context.modes, *((f, z) for f in frequencies for z in (0.02, 0.05, 0.1))]


def gain_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    score = context.scores.get("gain_error")
    relative_error = score.details.get("relative_error", 0.0) if score is not None else 0.0
    return [(relative_error,), *((e,) for e in (-0.2, -0.05, 0.05, 0.2))]


GAIN_DRIFT_TIME_CONSTANTS = (0.1, 0.3, 1.0, 3.0)
"""The time constants, in record lengths, a gain drift's fit starts from (:func:`gain_drift_guesses`): from a
gain that has settled early in the record to one still drifting almost linearly at its end."""


def build_gain_drift(v: Sequence[float], period: float) -> Block:
    # free values (e0, dg, tau in s, dz in rad): the gain starts at 1 + e0 and moves by dg, the zero by dz, with
    # the time constant tau
    return OutputGainDrift(gain=1.0 + v[0], gain_change=v[1], time_constant_s=max(abs(v[2]), period),
                           sample_period_s=period, zero_change_rad=v[3])


def gain_drift_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # for each time constant, e0, dg and dz by least squares on r ~ e0 y^ + (dg y^ + dz) (1 - exp(-t T / tau))
    # (linear in them once tau is fixed)
    r, y_hat = context.residual_rad, context.simulated_rad
    duration = r.size * context.sample_period_s
    if y_hat is None:
        return [(0.0, 0.05, factor * duration, 0.0) for factor in GAIN_DRIFT_TIME_CONSTANTS]
    times = np.arange(r.size) * context.sample_period_s
    usable = np.isfinite(r) & np.isfinite(y_hat)
    out = []
    for factor in GAIN_DRIFT_TIME_CONSTANTS:
        tau = factor * duration
        settled = -np.expm1(-times / tau)
        phi = np.column_stack((y_hat, settled * y_hat, settled))[usable]
        start, change, zero = np.linalg.lstsq(phi, r[usable], rcond=None)[0] if np.any(phi) else (0.0, 0.0, 0.0)
        out.append((float(start), float(change), tau, float(zero)))
    return out


def random_gain_drift(rng: np.random.Generator, u: NDArray[np.float64], estimation_fraction: float,
                      period: float) -> Block:
    # a gain that starts within 2 % of one and moves by 3-15 % with a time constant of 0.3-3 record lengths
    duration = u.size * period
    return OutputGainDrift(gain=1.0 + rng.uniform(-0.02, 0.02),
                           gain_change=rng.choice((-1.0, 1.0)) * rng.uniform(0.03, 0.15),
                           time_constant_s=rng.uniform(0.3, 3.0) * duration, sample_period_s=period)


def build_encoder_error(v: Sequence[float], period: float) -> Block:
    # free values (a1 cos p1, a1 sin p1, a2 cos p2, a2 sin p2): any real vector is a valid error, and the
    # output is linear in them (a1 sin(x + p1) = a1 cos p1 sin x + a1 sin p1 cos x)
    return EncoderError(once_per_rev_rad=math.hypot(v[0], v[1]), once_per_rev_phase_rad=math.atan2(v[1], v[0]),
                        twice_per_rev_rad=math.hypot(v[2], v[3]), twice_per_rev_phase_rad=math.atan2(v[3], v[2]))


def encoder_error_implausible(block: EncoderError) -> str:
    size = block.once_per_rev_rad + block.twice_per_rev_rad
    if size <= ENCODER_ERROR_MAX_RAD:
        return ""
    return (f"an error of {size:.3g} rad once and twice per revolution, beyond the {ENCODER_ERROR_MAX_RAD:g} rad of a "
            "working encoder")


def encoder_error_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # the least-squares fit of the signature (the residual on sin y^, cos y^, sin 2y^, cos 2y^), and a small
    # error at the noise bound
    score = context.scores.get("encoder_error")
    small = (context.noise_bound_rad, 0.0, 0.0, 0.0)
    if score is None or not score.details:
        return [small]
    d = score.details
    return [(d["sin_rad"], d["cos_rad"], d["sin2_rad"], d["cos2_rad"]), small]


def build_backlash(v: Sequence[float], period: float) -> Block:
    return OutputBacklash(m_l=1.0, c_l_rad=max(abs(v[0]), 1e-12), m_r=1.0, c_r_rad=max(abs(v[1]), 1e-12))


def build_saturation(v: Sequence[float], period: float) -> Block:
    lower, upper = -abs(v[0]), abs(v[1])
    return Saturation(lower_rad=lower, upper_rad=max(upper, lower + 1e-9))


def build_friction(v: Sequence[float], period: float) -> Block:
    slide = abs(v[1])
    stick = max(abs(v[0]), slide, 1e-12)
    return CoulombFriction(breakaway_torque_nm=stick * FRICTION_STIFFNESS_NM_PER_RAD,
                           coulomb_torque_nm=slide * FRICTION_STIFFNESS_NM_PER_RAD,
                           stiffness_nm_per_rad=FRICTION_STIFFNESS_NM_PER_RAD)


def build_resonance(v: Sequence[float], period: float) -> Block:
    nyquist = 0.5 / period
    frequency = min(max(abs(v[0]), 1e-3 * nyquist), 0.98 * nyquist)
    damping = min(max(abs(v[1]), 1e-3), MAX_RESONANCE_DAMPING)
    return Resonance(frequency_hz=frequency, damping_ratio=damping, sample_period_s=period)


def random_saturation(rng: np.random.Generator, u: NDArray[np.float64], estimation_fraction: float,
                       period: float) -> Block:
    # each limit lies within what both segments of the workflow's split reach on its side: a limit one
    # segment never crosses cannot be fitted, or seen, by any method
    split = int(round(estimation_fraction * u.size))
    segments = (u[:split], u[split:])
    reach_down = min(float(-np.min(segment)) for segment in segments)
    reach_up = min(float(np.max(segment)) for segment in segments)
    return Saturation(lower_rad=-rng.uniform(0.5, 0.75) * reach_down, upper_rad=rng.uniform(0.5, 0.75) * reach_up)


def random_friction(rng: np.random.Generator, u: NDArray[np.float64], estimation_fraction: float,
                     period: float) -> Block:
    stick = rng.uniform(0.015, 0.04)
    return CoulombFriction(breakaway_torque_nm=stick * 2000.0, coulomb_torque_nm=stick * 2000.0 * rng.uniform(0.4, 0.75),
                           stiffness_nm_per_rad=2000.0)
