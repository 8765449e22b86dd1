"""The catalogue of physical effects the model-discrepancy workflow can name (issue 15, item 1).

Each effect is defined once, here: the block class of :mod:`identify.plant_blocks` that models it, its
``type`` in a plant TOML ``[[blocks]]`` table and the keys of that table, its name in ``rig diagnose``, the
parameters the workflow reports (with units), where it sits in the model, how its free parameters become a
block, the initial guesses of its fit, the signature it leaves in the free-run residual
(:mod:`identify.effect_signatures`), what "vanished" means for a fitted block, and how the hidden-effect
test records (:mod:`identify.discrepancy_cases`) draw a block of realistic size.

The workflow (:mod:`identify.model_discrepancy`), the plant TOML reader and writer
(:mod:`sim_backend.plant_config`), the hidden-effect cases and the report read this table; adding an effect
is one :class:`Effect` entry in :data:`EFFECTS` plus its block class.

Placement (``Effect.placement``):

* ``"input"``: before the first linear component (a map of the command: dead zone, saturation, delay);
* ``"output"``: after the last linear component or resonance (a play or friction after the drive, a mode);
* ``"end"``: at the very end (what the encoder reads: offset, scale).

Adding an effect: write its block (a frozen dataclass with ``apply`` and ``stepper``, as in
:mod:`identify.plant_blocks`), add one :class:`Effect` here, and, if its residual has a signature of its own,
score it under the same name in :func:`identify.effect_signatures.signature_scores`. The TOML reader and
writer, the workflow's candidates, the hidden-effect cases and the confusion benchmark pick it up. A block
that replaces the linear dynamics rather than adding to them (the drive-train block of issue 15, item 2)
needs one more placement value, handled in :func:`identify.model_discrepancy._insert_index` and in
:data:`PLACEMENTS`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from identify.plant_blocks import (
    Block,
    CoulombFriction,
    DeadZone,
    Delay,
    OutputBacklash,
    OutputGain,
    OutputOffset,
    Resonance,
    Saturation,
)
from identify.validation import InvalidInputError

if TYPE_CHECKING:
    from identify.effect_signatures import SignatureScore

__all__ = ["EFFECTS", "EFFECT_NAMES", "PLACEMENTS", "Effect", "GuessContext", "Parameter", "TomlKey", "effect",
           "effect_for_block", "effect_for_toml_type"]

NEGLIGIBLE_GAIN_ERROR = 1.0e-3
"""A fitted gain within this of 1 is no gain error: a 0.1 % scale error is below what the workflow resolves
on records of a few thousand samples with a 12-bit encoder (it moves a 1 rad step by 1 mrad, about half a
count)."""

MAX_RESONANCE_DAMPING = 0.3
"""A resonance is a narrow peak: a fitted damping ratio is kept below this (a heavily damped second-order
section would otherwise stand in for a delay)."""

FRICTION_STIFFNESS_NM_PER_RAD = 1.0
"""The workflow fits Coulomb friction as twists (torques over a unit stiffness): from position data only the
ratio torque/stiffness is identifiable."""


@dataclass(frozen=True)
class Parameter:
    """A parameter the workflow reports for a named effect: its public name (units in the name, as in the
    JSON), its unit and what it is."""

    name: str
    unit: str
    description: str
    lower: float = -math.inf
    upper: float = math.inf
    """The values the parameter can take (a half-width is never negative): intervals are clipped to them."""


@dataclass(frozen=True)
class TomlKey:
    """A key of the effect's plant TOML table: also the block's constructor argument and attribute."""

    key: str
    kind: str = "number"  # "number" or "integer"
    default: float | int | None = None  # None: the key is required


@dataclass(frozen=True)
class GuessContext:
    """What the initial guesses of a fit may look at: the command u_t, the start model's residual r_t, the
    noise bound delta, the sample period T and the residual's signature scores."""

    command_rad: NDArray[np.float64]
    residual_rad: NDArray[np.float64]
    noise_bound_rad: float
    sample_period_s: float
    scores: dict[str, SignatureScore]

    @property
    def residual_amplitude_rad(self) -> float:
        return max(float(np.max(np.abs(self.residual_rad))), 4.0 * self.noise_bound_rad)


@dataclass(frozen=True)
class Effect:
    """One catalogue entry (see the module docstring).

    Attributes
    ----------
    name
        The name ``rig diagnose`` gives it (``"backlash"``).
    block_class
        Its block in :mod:`identify.plant_blocks`.
    toml_type
        ``type`` in a plant TOML ``[[blocks]]`` table (``"output_backlash"``).
    toml_keys
        The other keys of that table; each is the block's constructor argument of the same name.
    takes_sample_period
        The block's constructor also takes the plant's ``sample_period_s``.
    parameters
        What the workflow reports for a fitted block (:attr:`report`'s keys, in order).
    placement
        ``"input"``, ``"output"`` or ``"end"``.
    free_parameters
        Number of values the fit moves (the complexity the penalty counts).
    build
        Free values (and T) -> block; maps any real vector to a valid block (the least-squares fit is
        unconstrained).
    report
        Block -> the reported parameters.
    guesses
        Initial values of the free parameters for the fit (each is one start).
    vanished
        Block, delta -> True when the fitted effect is no effect (a play of zero width ...).
    random_block
        rng, command, estimation fraction, T -> a block of realistic size for the hidden-effect records.
    signature
        In words: what the effect leaves in the free-run residual (scored by
        :func:`identify.effect_signatures.signature_scores` under the same name).
    family
        Effects that are the same map in a limit share a family; the workflow decides between them by a
        documented rule (``_prefer_within_family`` in :mod:`identify.model_discrepancy`).
    searched
        The free value is an integer found by exhaustive search (the delay), not by least squares.
    needs_reversals
        The effect shows only where the command reverses its direction (hysteresis).
    needs_given_model
        The effect is tried only against a given model (a fitted start model has absorbed it).
    contact_start
        For a hysteresis after the linear block: starts of the fit from the half-widths (c_l, c_r) of a
        contact-branch refit (``_contact_branch_start`` in :mod:`identify.model_discrepancy`).
    stick_slip
        The free run is discontinuous in the breakaway threshold: the fit ends with a scan of the
        breakaway/sliding ratio.
    linear_dynamics
        The block is linear dynamics (it commutes with the linear block: output-side effects go after it,
        and the linear block is refitted through it).
    """

    name: str
    block_class: type
    toml_type: str
    toml_keys: tuple[TomlKey, ...]
    takes_sample_period: bool
    parameters: tuple[Parameter, ...]
    placement: str
    free_parameters: int
    build: Callable[[Sequence[float], float], Block]
    report: Callable[[Any], dict[str, float]]
    guesses: Callable[[GuessContext], list[tuple[float, ...]]]
    vanished: Callable[[Any, float], bool]
    random_block: Callable[[np.random.Generator, NDArray[np.float64], float, float], Block]
    signature: str
    family: str | None = None
    searched: bool = False
    needs_reversals: bool = False
    needs_given_model: bool = False
    contact_start: Callable[[float, float], list[tuple[float, ...]]] | None = None
    stick_slip: bool = False
    linear_dynamics: bool = False

    def block_from_toml(self, values: dict[str, Any], sample_period_s: float) -> Block:
        """The block of a TOML table whose keys were read into ``values``."""
        kwargs = dict(values)
        if self.takes_sample_period:
            kwargs["sample_period_s"] = sample_period_s
        return self.block_class(**kwargs)

    def toml_fields(self, block: Block) -> dict[str, Any]:
        """The TOML table of ``block`` (``type`` first)."""
        fields: dict[str, Any] = {"type": self.toml_type}
        for key in self.toml_keys:
            value = getattr(block, key.key)
            fields[key.key] = int(value) if key.kind == "integer" else float(value)
        return fields


# ----------------------------------------------------------------------------------------------------------
# The entries
# ----------------------------------------------------------------------------------------------------------


def _levels(context: GuessContext, count: int = 7) -> NDArray[np.float64]:
    return np.geomspace(context.noise_bound_rad, context.residual_amplitude_rad, count)


def _backlash_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    levels = _levels(context)
    return [(left, right) for left in levels for right in levels]


def _friction_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    slides = np.geomspace(context.noise_bound_rad, 2.0 * context.residual_amplitude_rad, 14)
    return [(r * c, c) for c in slides for r in (1.0, 1.25, 1.5, 1.8, 2.2, 2.8)]


def _dead_zone_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # each edge on its own: a record may barely reach one side's edge, and a symmetric guess misses it
    span = float(np.max(np.abs(context.command_rad)))
    edges = np.geomspace(max(context.noise_bound_rad, 1e-3 * span), 0.3 * span, 6)
    return [(left, right) for left in edges for right in edges]


def _saturation_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    # each limit from the commands on its side: travel limits need not be symmetric
    u = context.command_rad
    levels = (0.3, 0.5, 0.7, 0.85, 0.95)
    below = np.quantile(-u[u < 0], levels) if np.any(u < 0) else np.zeros(1)
    above = np.quantile(u[u > 0], levels) if np.any(u > 0) else np.zeros(1)
    return [(float(low), float(high)) for low in below for high in above]


def _resonance_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    nyquist = 0.5 / context.sample_period_s
    score = context.scores.get("resonance")
    peak = score.details.get("peak_frequency_hz", 0.1 * nyquist) if score is not None else 0.1 * nyquist
    frequencies = [f for f in (peak, *np.geomspace(0.02 * nyquist, 0.8 * nyquist, 16)) if 0.0 < f < 0.98 * nyquist]
    return [(f, z) for f in frequencies for z in (0.02, 0.05, 0.1)]


def _gain_guesses(context: GuessContext) -> list[tuple[float, ...]]:
    score = context.scores.get("gain_error")
    relative_error = score.details.get("relative_error", 0.0) if score is not None else 0.0
    return [(relative_error,), *((e,) for e in (-0.2, -0.05, 0.05, 0.2))]


def _build_backlash(v: Sequence[float], period: float) -> Block:
    return OutputBacklash(m_l=1.0, c_l=max(abs(v[0]), 1e-12), m_r=1.0, c_r=max(abs(v[1]), 1e-12))


def _build_saturation(v: Sequence[float], period: float) -> Block:
    lower, upper = -abs(v[0]), abs(v[1])
    return Saturation(lower_rad=lower, upper_rad=max(upper, lower + 1e-9))


def _build_friction(v: Sequence[float], period: float) -> Block:
    slide = abs(v[1])
    stick = max(abs(v[0]), slide, 1e-12)
    return CoulombFriction(breakaway_torque_nm=stick * FRICTION_STIFFNESS_NM_PER_RAD,
                           coulomb_torque_nm=slide * FRICTION_STIFFNESS_NM_PER_RAD,
                           stiffness_nm_per_rad=FRICTION_STIFFNESS_NM_PER_RAD)


def _build_resonance(v: Sequence[float], period: float) -> Block:
    nyquist = 0.5 / period
    frequency = min(max(abs(v[0]), 1e-3 * nyquist), 0.98 * nyquist)
    damping = min(max(abs(v[1]), 1e-3), MAX_RESONANCE_DAMPING)
    return Resonance(frequency_hz=frequency, damping_ratio=damping, sample_period_s=period)


def _random_saturation(rng: np.random.Generator, u: NDArray[np.float64], estimation_fraction: float,
                       period: float) -> Block:
    # each limit lies within what both segments of the workflow's split reach on its side: a limit one
    # segment never crosses cannot be fitted, or seen, by any method
    split = int(round(estimation_fraction * u.size))
    segments = (u[:split], u[split:])
    reach_down = min(float(-np.min(segment)) for segment in segments)
    reach_up = min(float(np.max(segment)) for segment in segments)
    return Saturation(lower_rad=-rng.uniform(0.5, 0.75) * reach_down, upper_rad=rng.uniform(0.5, 0.75) * reach_up)


def _random_friction(rng: np.random.Generator, u: NDArray[np.float64], estimation_fraction: float,
                     period: float) -> Block:
    stick = rng.uniform(0.015, 0.04)
    return CoulombFriction(breakaway_torque_nm=stick * 2000.0, coulomb_torque_nm=stick * 2000.0 * rng.uniform(0.4, 0.75),
                           stiffness_nm_per_rad=2000.0)


EFFECTS: dict[str, Effect] = {effect.name: effect for effect in (
    Effect(
        name="backlash", block_class=OutputBacklash, toml_type="output_backlash",
        toml_keys=(TomlKey("m_l"), TomlKey("c_l"), TomlKey("m_r"), TomlKey("c_r"), TomlKey("initial_output", default=0.0)),
        takes_sample_period=False,
        parameters=(Parameter("c_l_rad", "rad", "left half-width of the play", lower=0.0),
                    Parameter("c_r_rad", "rad", "right half-width of the play", lower=0.0)),
        placement="output", free_parameters=2, build=_build_backlash,
        report=lambda b: {"c_l_rad": b.c_l, "c_r_rad": b.c_r},
        guesses=_backlash_guesses,
        vanished=lambda b, delta: b.c_l + b.c_r < delta,
        random_block=lambda rng, u, f, period: OutputBacklash(m_l=1.0, c_l=rng.uniform(0.01, 0.04), m_r=1.0,
                                                      c_r=rng.uniform(0.01, 0.04)),
        signature="a residual that changes sign where the model's motion reverses (r ~ c s_t, s_t the last "
                  "direction of y^)",
        family="hysteresis", needs_reversals=True,
        contact_start=lambda c_l, c_r: [(c_l, c_r)],
    ),
    Effect(
        name="dead_zone", block_class=DeadZone, toml_type="dead_zone",
        toml_keys=(TomlKey("left_rad"), TomlKey("right_rad")), takes_sample_period=False,
        parameters=(Parameter("left_rad", "rad", "left edge of the dead band", upper=0.0),
                    Parameter("right_rad", "rad", "right edge of the dead band", lower=0.0)),
        placement="input", free_parameters=2,
        build=lambda v, period: DeadZone(left_rad=-abs(v[0]), right_rad=abs(v[1])),
        report=lambda b: {"left_rad": b.left_rad, "right_rad": b.right_rad},
        guesses=_dead_zone_guesses,
        vanished=lambda b, delta: b.right_rad - b.left_rad < delta,
        random_block=lambda rng, u, f, period: DeadZone(left_rad=-rng.uniform(0.03, 0.10), right_rad=rng.uniform(0.03, 0.10)),
        signature="the output stuck near zero while the model moves (r ~ -clip(y^, -w, w))",
    ),
    Effect(
        name="saturation", block_class=Saturation, toml_type="saturation",
        toml_keys=(TomlKey("lower_rad"), TomlKey("upper_rad")), takes_sample_period=False,
        parameters=(Parameter("lower_rad", "rad", "lower limit of the command", upper=0.0),
                    Parameter("upper_rad", "rad", "upper limit of the command", lower=0.0)),
        placement="input", free_parameters=2, build=_build_saturation,
        report=lambda b: {"lower_rad": b.lower_rad, "upper_rad": b.upper_rad},
        guesses=_saturation_guesses,
        vanished=lambda b, delta: False,
        random_block=_random_saturation,
        signature="a residual growing with |u| at the extremes (r ~ -(y^ - clip(y^, -q, q)))",
    ),
    Effect(
        name="delay", block_class=Delay, toml_type="delay",
        toml_keys=(TomlKey("samples", kind="integer"),), takes_sample_period=False,
        parameters=(Parameter("samples", "samples", "input delay in whole samples", lower=0.0),),
        placement="input", free_parameters=1,
        build=lambda v, period: Delay(int(round(v[0]))),
        report=lambda b: {"samples": float(b.samples)},
        guesses=lambda context: [],
        vanished=lambda b, delta: b.samples == 0,
        random_block=lambda rng, u, f, period: Delay(int(rng.integers(3, 16))),
        signature="the residual of a model d samples early (r ~ y^_{t-d} - y^_t)",
        searched=True,
    ),
    Effect(
        name="coulomb_friction", block_class=CoulombFriction, toml_type="coulomb_friction",
        toml_keys=(TomlKey("breakaway_torque_nm"), TomlKey("coulomb_torque_nm"), TomlKey("stiffness_nm_per_rad"),
                   TomlKey("initial_output_rad", default=0.0)),
        takes_sample_period=False,
        parameters=(Parameter("breakaway_deflection_rad", "rad", "twist at which the load breaks away", lower=0.0),
                    Parameter("sliding_deflection_rad", "rad", "twist while it slides", lower=0.0)),
        placement="output", free_parameters=2, build=_build_friction,
        report=lambda b: {"breakaway_deflection_rad": b.breakaway_deflection_rad,
                          "sliding_deflection_rad": b.sliding_deflection_rad},
        guesses=_friction_guesses,
        vanished=lambda b, delta: b.breakaway_deflection_rad < delta / 2.0,
        random_block=_random_friction,
        signature="the backlash signature, and stick-slip: the output flat while the model moves, then a jump",
        family="hysteresis", needs_reversals=True,
        contact_start=lambda c_l, c_r: [(ratio * 0.5 * (c_l + c_r), 0.5 * (c_l + c_r)) for ratio in (1.0, 1.5, 2.0)],
        stick_slip=True,
    ),
    Effect(
        name="resonance", block_class=Resonance, toml_type="resonance",
        toml_keys=(TomlKey("frequency_hz"), TomlKey("damping_ratio")), takes_sample_period=True,
        parameters=(Parameter("frequency_hz", "Hz", "natural frequency of the mode", lower=0.0),
                    Parameter("damping_ratio", "1", "damping ratio of the mode", lower=0.0)),
        placement="output", free_parameters=2, build=_build_resonance,
        report=lambda b: {"frequency_hz": b.frequency_hz, "damping_ratio": b.damping_ratio},
        guesses=_resonance_guesses,
        vanished=lambda b, delta: False,
        random_block=lambda rng, u, f, period: Resonance(frequency_hz=rng.uniform(60.0, 200.0),
                                                 damping_ratio=rng.uniform(0.02, 0.08),
                                                 sample_period_s=period),
        signature="a narrow peak in the residual's spectrum (share of power within three bins of the peak)",
        linear_dynamics=True,
    ),
    Effect(
        name="offset", block_class=OutputOffset, toml_type="offset",
        toml_keys=(TomlKey("offset_rad", default=0.0), TomlKey("drift_rad_per_s", default=0.0)),
        takes_sample_period=True,
        parameters=(Parameter("offset_rad", "rad", "constant offset of the measured angle"),
                    Parameter("drift_rad_per_s", "rad/s", "drift of the measured angle")),
        placement="end", free_parameters=2,
        build=lambda v, period: OutputOffset(offset_rad=v[0], drift_rad_per_s=v[1], sample_period_s=period),
        report=lambda b: {"offset_rad": b.offset_rad, "drift_rad_per_s": b.drift_rad_per_s},
        guesses=lambda context: [(float(np.mean(context.residual_rad)), 0.0)],
        vanished=lambda b, delta: False,
        random_block=lambda rng, u, f, period: OutputOffset(offset_rad=rng.uniform(-0.05, 0.05),
                                                    drift_rad_per_s=rng.uniform(-0.01, 0.01),
                                                    sample_period_s=period),
        signature="r ~ o + drift t T",
    ),
    Effect(
        name="gain_error", block_class=OutputGain, toml_type="gain",
        toml_keys=(TomlKey("gain"),), takes_sample_period=False,
        parameters=(Parameter("gain", "1", "measured / modelled angle", lower=0.0),
                    Parameter("relative_error", "1", "gain - 1")),
        placement="end", free_parameters=1,
        build=lambda v, period: OutputGain(gain=1.0 + v[0]),
        report=lambda b: {"gain": b.gain, "relative_error": b.gain - 1.0},
        guesses=_gain_guesses,
        vanished=lambda b, delta: abs(b.gain - 1.0) < NEGLIGIBLE_GAIN_ERROR,
        random_block=lambda rng, u, f, period: OutputGain(gain=1.0 + rng.choice((-1.0, 1.0)) * rng.uniform(0.03, 0.15)),
        signature="r ~ e y^: the measured output is (1 + e) times the model's",
        needs_given_model=True,
    ),
)}
"""Every effect, by its diagnose name, in the order the workflow tries them."""

EFFECT_NAMES: tuple[str, ...] = tuple(EFFECTS)
"""Names of the effects the workflow can name."""

_BY_CLASS = {entry.block_class: entry for entry in EFFECTS.values()}
_BY_TOML = {entry.toml_type: entry for entry in EFFECTS.values()}


def effect(name: str) -> Effect:
    """The entry of ``name``; :class:`InvalidInputError` naming the choices otherwise."""
    try:
        return EFFECTS[name]
    except KeyError:
        raise InvalidInputError(f"effect: unknown effect {name!r}; expected one of {', '.join(EFFECT_NAMES)}") from None


def effect_for_block(block: Block) -> Effect | None:
    """The entry whose block class ``block`` is, or None (a linear block, an input backlash ...)."""
    return _BY_CLASS.get(type(block))


def effect_for_toml_type(toml_type: str) -> Effect | None:
    """The entry whose plant TOML ``type`` is ``toml_type``, or None."""
    return _BY_TOML.get(toml_type)


PLACEMENTS = ("input", "output", "end")
"""Where an effect can sit (module docstring)."""


def _check() -> None:
    for entry in EFFECTS.values():
        if entry.placement not in PLACEMENTS:
            raise AssertionError(f"{entry.name}: placement {entry.placement!r}")
        if not math.isfinite(entry.free_parameters) or entry.free_parameters < 1:
            raise AssertionError(f"{entry.name}: free_parameters")


_check()
