"""The catalogue of physical effects the model-discrepancy workflow can name.

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
* ``"end"``: at the very end (what the encoder reads: offset, scale);
* ``"dynamics"``: inside the drive's dynamics, as fields of a :class:`~identify.drive_train.DriveTrain`
  (friction on the load's motion, gravity, the drive's rate and torque limits, play between the motor and
  the load inertia). Such an effect is realised
  by merging its fields into the model's drive train, if the model has one (a given model with a
  ``drive_train`` block, or a chain where another dynamics effect was already added), or else by replacing
  the model's linear dynamics with the rigid drive train of the same response
  (:func:`identify.model_discrepancy.rigid_train_like`: a P-P cascade of bandwidth f_n and damping zeta fitted to
  the linear block's free run, free again in the joint fit when the start model was fitted). Its
  parameters are per unit inertia (the workflow sees positions only: a torque T and the inertia J it acts
  on are known only as T / J), and its TOML form is the ``drive_train`` table's keys it sets.

Adding an effect: write its block (a frozen dataclass with ``apply`` and ``stepper``, as in
:mod:`identify.plant_blocks`), its guesses and builder (:mod:`identify.series_effects` for a signal-chain
effect), add one :class:`Effect` here, and, if its residual has a signature of its own,
score it under the same name in :func:`identify.effect_signatures.signature_scores`. The TOML reader and
writer, the workflow's candidates, the hidden-effect cases and the confusion benchmark pick it up. A dynamics
effect is one entry too: its ``train_fields`` (in :mod:`identify.drive_train_effects`, with its guesses and
draws) map free values to the drive train's fields (placement
``"dynamics"``, handled in :func:`identify.model_discrepancy.candidates._insert_index` and ``_dynamics_chain``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from identify.drive_train import DriveTrain
from identify.drive_train_effects import (
    friction_fields,
    friction_report,
    friction_width_starts,
    gravity_fields,
    gravity_guesses,
    limit_resolution,
    load_friction_guesses,
    play_fields,
    random_gravity,
    random_load_friction,
    random_rate_limit,
    random_shaft_friction,
    random_shaft_play,
    random_torque_limit,
    rate_fields,
    rate_limit_guesses,
    shaft_friction_fields,
    shaft_friction_guesses,
    shaft_friction_report,
    shaft_play_guesses,
    static_error,
    torque_fields,
    torque_limit_guesses,
    torque_resolution,
    train_builder,
)
from identify.plant_blocks import (
    Block,
    CoulombFriction,
    DeadZone,
    Delay,
    EncoderError,
    OutputBacklash,
    OutputGain,
    OutputGainDrift,
    OutputOffset,
    Resonance,
    Saturation,
)
from identify.series_effects import (
    ENCODER_ERROR_MAX_RAD,
    MAX_RESONANCE_DAMPING,
    NEGLIGIBLE_GAIN_ERROR,
    backlash_guesses,
    build_backlash,
    build_encoder_error,
    build_friction,
    build_gain_drift,
    build_resonance,
    build_saturation,
    dead_zone_guesses,
    encoder_error_guesses,
    encoder_error_implausible,
    friction_guesses,
    gain_drift_guesses,
    gain_guesses,
    random_friction,
    random_gain_drift,
    random_saturation,
    resonance_guesses,
    saturation_guesses,
)
from identify.validation import InvalidInputError

if TYPE_CHECKING:
    from identify.effect_signatures import SignatureScore

__all__ = ["ANGLE_SHAPE_EXPERIMENT", "DYNAMICS_EFFECTS", "EFFECTS", "EFFECT_NAMES", "HYSTERESIS_INNER_TWIN",
           "LINEAR_ORDER_EXPERIMENT", "LOOK_ALIKE_EXPERIMENTS", "MAX_RESONANCE_DAMPING",
           "SAME_MAP_READINGS",
           "PLACEMENTS", "SEARCHED_EFFECT_NAMES", "ENCODER_ERROR_MAX_RAD", "Effect",
           "GuessContext", "Parameter", "TomlKey", "effect", "effect_for_block", "effect_for_toml_type",
           "look_alike_experiments"]

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
    simulated_rad: NDArray[np.float64] | None = None
    """y^_t, the start model's free run (the drive-train guesses read its speeds and accelerations)."""
    train: DriveTrain | None = None
    """For a dynamics effect: the drive train it goes into (its loop bandwidth scales the guesses)."""
    modes: tuple[tuple[float, float], ...] = ()
    """(natural frequency Hz, damping ratio) of the lightly damped modes of higher-order linear models of the
    record, where the start model is fitted (a mode's guesses start there)."""

    @property
    def residual_amplitude_rad(self) -> float:
        return max(float(np.max(np.abs(self.residual_rad))), 4.0 * self.noise_bound_rad)

    def levels(self, count: int = 7) -> NDArray[np.float64]:
        """``count`` sizes spaced geometrically from the noise bound to the residual's amplitude (where the
        guesses of an effect's size start)."""
        return np.geomspace(self.noise_bound_rad, self.residual_amplitude_rad, count)


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
        documented rule (``_prefer_within_family`` in :mod:`identify.model_discrepancy.judgement`).
    searched
        The free value is an integer found by exhaustive search (the delay), not by least squares.
    needs_reversals
        The effect shows only where the command reverses its direction (hysteresis).
    needs_given_model
        The effect is tried only against a given model (a fitted start model has absorbed it).
    contact_start
        For a hysteresis after the linear block: starts of the fit from the half-widths (c_l, c_r) of a
        contact-branch refit (``_contact_branch_start`` in :mod:`identify.model_discrepancy.fit`).
    stick_slip
        The free run is discontinuous in the breakaway threshold: the fit ends with a scan of the
        breakaway/sliding ratio (``_scan_breakaway``, or ``_scan_static_friction`` for a dynamics effect).
    linear_dynamics
        The block is linear dynamics (it commutes with the linear block: output-side effects go after it,
        and the linear block is refitted through it).
    train_fields
        Placement ``"dynamics"`` only: (free values, the drive train they go into) -> the
        :class:`~identify.drive_train.DriveTrain` fields the effect sets (``build`` then merges them into
        :func:`identify.drive_train_effects.reference_train`); any real vector gives valid fields.
    inner_twin
        For an effect after the drive: the dynamics effects that, merged into one drive train, leave the same
        signature from inside the drive (:data:`HYSTERESIS_INNER_TWIN`); whenever this effect wins a round of
        the search, the twin is tried too, as one compound explanation (``_compound`` in
        :mod:`identify.model_discrepancy.fit`).
    half_widths
        For a hysteresis: fitted block -> the half-widths (c_l, c_r) of the loop it draws between input and
        output (rad; backlash: its own, friction: the sliding twist either way). They start the other
        members of its family (:attr:`contact_start`) when the family is decided again with the whole model,
        and their sum w starts the play of its inner twin (:attr:`width_starts`).
    width_starts
        For a member of an inner twin: (the total width w of the output hysteresis fitted to the same record,
        the drive train) -> starts of its free values (the first is used when it is not the last member
        fitted). The hysteresis of the twin is the play b plus the friction's static error 2 T_c / (J
        omega_n^2) (the drive stops that short of the command either way), so half of w goes to each:
        b = w / 2, T_c / J = omega_n^2 w / 4. Started from the friction fit alone, the play stays closed: on a
        hidden shaft_play + load_friction record (seed 1012, play 44.3 mrad, T_c / J 603 rad/s^2) the friction
        alone fitted 1490 rad/s^2 and the play through it polished to 0 (gap 8.7 mrad), while from a play at
        the backlash's width (87.6 mrad) the polish reached 43.9 mrad and 611 rad/s^2 (gap 0.59 mrad).
    resolution
        Dynamics effects: (fitted train, its free run y^, the angle resolution e) -> half-widths by which
        the parameters' intervals are widened: what an angle known only within +-e leaves unresolved of a
        torque or a limit (the fold refits all see the same quantised levels and cannot show it).
    look_alikes
        Effects that give the same output on records of ordinary motion though their physics differ (a load
        torque ~ sin of the angle through the drive, gravity, and a once-per-revolution sensor error; an offset,
        a gain error and a sensor error over a small range of angles, a value and a slope there): when
        this effect is named, each look-alike is fitted in its place, and if the two fitted models' outputs
        are within the noise bound of each other on the record, the verdict is ambiguous between them, with
        the experiment that separates them (:data:`LOOK_ALIKE_EXPERIMENTS`; ``_look_alikes_checked`` in
        :mod:`identify.model_discrepancy.left_open`).
    same_map_as
        Other mechanisms whose map from command to angle is exactly this effect's fitted map (an output
        backlash with unit slopes is Coulomb friction without stiction behind the position loop, plus an offset
        of half its asymmetry): the data of one record can never tell them apart, so when this effect is
        named it stays in the model (the map is identified) and the verdict is ambiguous between the
        mechanisms, reading the fitted sizes both ways (:data:`SAME_MAP_READINGS`) and saying what experiment
        separates them (:data:`LOOK_ALIKE_EXPERIMENTS`; ``_mechanisms_left_open`` in
        :mod:`identify.model_discrepancy.left_open`).
    look_alike_only
        Not searched by default (not in :data:`SEARCHED_EFFECT_NAMES`): tried as the look-alike of a named
        effect or of the effects a round leaves open, or when named in the workflow's ``candidates``.
    generalises
        Effects that are this one in a limit (a gain error is a drifting gain that does not move): where an end of
        the search with this effect and one with the simpler effect in its place fit within their uncertainty of
        each other, the simpler is named, as an end with fewer effects is (``_clear_end`` in
        :mod:`identify.model_discrepancy.search`).
    angle_sag
        For an effect that is a sine of the angle once per revolution (a weight's torque): fitted block ->
        the amplitude S (rad) of the sag it leaves at rest. Over a range R of angles such a sag departs from a
        straight line by at most S R^2 / 8; when that is below the noise bound, the record has not shown the
        sine, and any load torque that varies smoothly with the angle (cogging, a spring) fits as well
        (``_shape_left_open`` in :mod:`identify.model_discrepancy.left_open`).
    loop_damping_value
        Dynamics effects: the index of the free value that is a viscous damping per inertia d / J (1/s) on
        the load's speed, which adds to the velocity loop's own K_v / J = 2 zeta omega_n: when the loop is
        fitted too, the record shows mainly their sum, and the parameter's interval is walked along that
        trade (``_loop_traded_intervals`` in :mod:`identify.model_discrepancy.intervals`).
    added_to_train
        Dynamics effects: the reported parameters that add to a field the train may already have (the load's
        viscous friction of a given or re-expressed train): they are reported as what the effect adds
        (:meth:`report_in_train`), since the train's own part is the model's.
    order_look_alike
        A linear effect that linear dynamics of a higher order can stand in for (a delay of d samples is the lag
        that poles the start model lacks also give): from a fitted start it must still be needed once a linear
        block of a higher order takes the start model's place; if the model fits as well without it, the
        verdict is ambiguous and the effect is not named (:data:`LINEAR_ORDER_EXPERIMENT`; ``_order_left_open``
        in :mod:`identify.model_discrepancy.left_open`).
    needs_shaft
        Dynamics effects inside the shaft (its friction): tried only when the model has a compliant shaft (a
        given drive train with a finite stiffness, or a given linear block with a shaft mode,
        :func:`identify.model_discrepancy.candidates.drive_train_like`); in a rigid train the effect would have
        to invent the shaft as well.
    implausible
        Fitted block -> why no working device of its kind has it (an encoder's once- and twice-per-revolution
        error beyond :data:`~identify.series_effects.ENCODER_ERROR_MAX_RAD`), or "" where one could; None: any fit is plausible.
    bounded_look_alikes
        Look-alikes that count as this effect's only at a size a working device has (their ``implausible``): they
        give this effect's output only with harmonics far larger than the effect, which cancel each other (over
        a small range of angles a sensor error of 0.1 rad, once and twice per revolution, is an 8 % gain error's
        line). One fitted beyond it is not reported as a look-alike, only said.
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
    train_fields: Callable[[Sequence[float], DriveTrain], dict[str, Any]] | None = None
    resolution: Callable[[DriveTrain, NDArray[np.float64], float], dict[str, float]] | None = None
    inner_twin: tuple[str, ...] = ()
    half_widths: Callable[[Any], tuple[float, float]] | None = None
    width_starts: Callable[[float, DriveTrain], list[tuple[float, ...]]] | None = None
    loop_damping_value: int | None = None
    angle_sag: Callable[[Any], float] | None = None
    look_alikes: tuple[str, ...] = ()
    same_map_as: tuple[str, ...] = ()
    look_alike_only: bool = False
    generalises: tuple[str, ...] = ()
    added_to_train: tuple[str, ...] = ()
    order_look_alike: bool = False
    needs_shaft: bool = False
    implausible: Callable[[Any], str] | None = None
    bounded_look_alikes: tuple[str, ...] = ()

    def in_train(self, values: Sequence[float], train: DriveTrain) -> DriveTrain:
        """``train`` with this dynamics effect's fields set from its free ``values``."""
        assert self.train_fields is not None, f"{self.name} is no dynamics effect"
        return replace(train, **self.train_fields(values, train))

    def report_in_train(self, train: DriveTrain, base: DriveTrain) -> dict[str, float]:
        """:attr:`report` of ``train``, which holds this dynamics effect put into ``base``: the parameters
        named in :attr:`added_to_train` are what the effect adds to ``base``'s own (a given train's viscous
        friction is the model's, not the missing effect's)."""
        values = self.report(train)
        if self.added_to_train:
            own = self.report(base)
            values = {key: value - own[key] if key in self.added_to_train else value for key, value in values.items()}
        return values

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


HYSTERESIS_INNER_TWIN = ("load_friction", "shaft_play")
"""The inner-dynamics twin of an output-side hysteresis (backlash, Coulomb friction after the drive): Coulomb
friction on the load's motion together with a play between the motor and the load inertia. When the drive
turns back, friction stops the load inside the play instead of letting it coast through, so the output
stands still until the far side of the play is taken up: the map of an output backlash. Neither of the two
alone does that (a load without friction coasts through the play; friction without a play drags the whole
train), so a greedy search that adds one effect per round meets the hysteresis first and never the pair
(hidden shaft_play + load_friction records, given the model: 7 of 20 named an output hysteresis first). Named
in order: friction first, then the play fitted through it."""


EFFECTS: dict[str, Effect] = {effect.name: effect for effect in (
    Effect(
        name="backlash", block_class=OutputBacklash, toml_type="output_backlash",
        toml_keys=(TomlKey("m_l"), TomlKey("c_l_rad"), TomlKey("m_r"), TomlKey("c_r_rad"),
                   TomlKey("initial_output_rad", default=0.0)),
        takes_sample_period=False,
        parameters=(Parameter("c_l_rad", "rad", "left half-width of the play", lower=0.0),
                    Parameter("c_r_rad", "rad", "right half-width of the play", lower=0.0)),
        placement="output", free_parameters=2, build=build_backlash,
        report=lambda b: {"c_l_rad": b.c_l_rad, "c_r_rad": b.c_r_rad},
        guesses=backlash_guesses,
        vanished=lambda b, delta: b.c_l_rad + b.c_r_rad < delta,
        random_block=lambda rng, u, f, period: OutputBacklash(m_l=1.0, c_l_rad=rng.uniform(0.01, 0.04), m_r=1.0,
                                                      c_r_rad=rng.uniform(0.01, 0.04)),
        signature="a residual that changes sign where the model's motion reverses (r ~ c s_t, s_t the last "
                  "direction of y^)",
        family="hysteresis", needs_reversals=True,
        contact_start=lambda c_l, c_r: [(c_l, c_r)], inner_twin=HYSTERESIS_INNER_TWIN,
        half_widths=lambda b: (b.c_l_rad, b.c_r_rad), same_map_as=("coulomb_friction",),
    ),
    Effect(
        name="dead_zone", block_class=DeadZone, toml_type="dead_zone",
        toml_keys=(TomlKey("left_rad"), TomlKey("right_rad")), takes_sample_period=False,
        parameters=(Parameter("left_rad", "rad", "left edge of the dead band", upper=0.0),
                    Parameter("right_rad", "rad", "right edge of the dead band", lower=0.0)),
        placement="input", free_parameters=2,
        build=lambda v, period: DeadZone(left_rad=-abs(v[0]), right_rad=abs(v[1])),
        report=lambda b: {"left_rad": b.left_rad, "right_rad": b.right_rad},
        guesses=dead_zone_guesses,
        vanished=lambda b, delta: b.right_rad - b.left_rad < delta,
        random_block=lambda rng, u, f, period: DeadZone(left_rad=-rng.uniform(0.03, 0.10), right_rad=rng.uniform(0.03, 0.10)),
        signature="the output stuck near zero while the model moves (r ~ -clip(y^, -w, w))",
    ),
    Effect(
        name="saturation", block_class=Saturation, toml_type="saturation",
        toml_keys=(TomlKey("lower_rad"), TomlKey("upper_rad")), takes_sample_period=False,
        parameters=(Parameter("lower_rad", "rad", "lower limit of the command", upper=0.0),
                    Parameter("upper_rad", "rad", "upper limit of the command", lower=0.0)),
        placement="input", free_parameters=2, build=build_saturation,
        report=lambda b: {"lower_rad": b.lower_rad, "upper_rad": b.upper_rad},
        guesses=saturation_guesses,
        vanished=lambda b, delta: False,
        random_block=random_saturation,
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
        order_look_alike=True,
    ),
    Effect(
        name="coulomb_friction", block_class=CoulombFriction, toml_type="coulomb_friction",
        toml_keys=(TomlKey("breakaway_torque_nm"), TomlKey("coulomb_torque_nm"), TomlKey("stiffness_nm_per_rad"),
                   TomlKey("initial_output_rad", default=0.0)),
        takes_sample_period=False,
        parameters=(Parameter("breakaway_deflection_rad", "rad", "twist at which the load breaks away", lower=0.0),
                    Parameter("sliding_deflection_rad", "rad", "twist while it slides", lower=0.0)),
        placement="output", free_parameters=2, build=build_friction,
        report=lambda b: {"breakaway_deflection_rad": b.breakaway_deflection_rad,
                          "sliding_deflection_rad": b.sliding_deflection_rad},
        guesses=friction_guesses,
        vanished=lambda b, delta: b.breakaway_deflection_rad < delta / 2.0,
        random_block=random_friction,
        signature="the backlash signature, and stick-slip: the output flat while the model moves, then a jump",
        family="hysteresis", needs_reversals=True,
        contact_start=lambda c_l, c_r: [(ratio * 0.5 * (c_l + c_r), 0.5 * (c_l + c_r)) for ratio in (1.0, 1.5, 2.0)],
        stick_slip=True, inner_twin=HYSTERESIS_INNER_TWIN,
        half_widths=lambda b: (b.sliding_deflection_rad, b.sliding_deflection_rad),  # the output lags by +-it
    ),
    Effect(
        name="resonance", block_class=Resonance, toml_type="resonance",
        toml_keys=(TomlKey("frequency_hz"), TomlKey("damping_ratio")), takes_sample_period=True,
        parameters=(Parameter("frequency_hz", "Hz", "natural frequency of the mode", lower=0.0),
                    Parameter("damping_ratio", "1", "damping ratio of the mode", lower=0.0)),
        placement="output", free_parameters=2, build=build_resonance,
        report=lambda b: {"frequency_hz": b.frequency_hz, "damping_ratio": b.damping_ratio},
        guesses=resonance_guesses,
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
        look_alikes=("encoder_error",),
    ),
    Effect(
        name="gain_error", block_class=OutputGain, toml_type="gain",
        toml_keys=(TomlKey("gain"),), takes_sample_period=False,
        parameters=(Parameter("gain", "1", "measured / modelled angle", lower=0.0),
                    Parameter("relative_error", "1", "gain - 1")),
        placement="end", free_parameters=1,
        build=lambda v, period: OutputGain(gain=1.0 + v[0]),
        report=lambda b: {"gain": b.gain, "relative_error": b.gain - 1.0},
        guesses=gain_guesses,
        vanished=lambda b, delta: abs(b.gain - 1.0) < NEGLIGIBLE_GAIN_ERROR,
        random_block=lambda rng, u, f, period: OutputGain(gain=1.0 + rng.choice((-1.0, 1.0)) * rng.uniform(0.03, 0.15)),
        signature="r ~ e y^: the measured output is (1 + e) times the model's",
        needs_given_model=True, look_alikes=("encoder_error",), bounded_look_alikes=("encoder_error",),
    ),
    Effect(
        name="gain_drift", block_class=OutputGainDrift, toml_type="gain_drift",
        toml_keys=(TomlKey("gain"), TomlKey("gain_change"), TomlKey("time_constant_s"),
                   TomlKey("zero_change_rad", default=0.0)),
        takes_sample_period=True,
        parameters=(Parameter("start_relative_error", "1", "gain - 1 at the record's first sample"),
                    Parameter("relative_error_change", "1", "dg: how far the gain moves, all of it after many tau"),
                    Parameter("time_constant_s", "s", "tau of the first-order approach", lower=0.0),
                    Parameter("zero_change_rad", "rad", "dz: how far the zero moves with it, in the frame the "
                              "workflow ran in (from the operating point where it moved there; a gain drifting "
                              "about an angle A moves the zero by -dg A)")),
        placement="end", free_parameters=4, build=build_gain_drift,
        report=lambda b: {"start_relative_error": b.gain - 1.0, "relative_error_change": b.gain_change,
                          "time_constant_s": b.time_constant_s, "zero_change_rad": b.zero_change_rad},
        guesses=gain_drift_guesses,
        # vanished: a gain that does not move is a gain error (the catalogue's own, which it generalises)
        vanished=lambda b, delta: abs(b.gain_change) < NEGLIGIBLE_GAIN_ERROR,
        random_block=random_gain_drift,
        signature="r ~ (e0 + dg s) y^ + dz s, s = 1 - exp(-t T / tau): the measured output a multiple of the "
                  "model's that changes over the record, its zero moving with it (a sensor following its "
                  "temperature)",
        needs_given_model=True, generalises=("gain_error",),
    ),
    Effect(
        name="encoder_error", block_class=EncoderError, toml_type="encoder_error",
        toml_keys=(TomlKey("once_per_rev_rad"), TomlKey("once_per_rev_phase_rad"),
                   TomlKey("twice_per_rev_rad", default=0.0), TomlKey("twice_per_rev_phase_rad", default=0.0)),
        takes_sample_period=False,
        parameters=(Parameter("once_per_rev_rad", "rad", "amplitude a1 of the sensor error once per revolution",
                              lower=0.0),
                    Parameter("once_per_rev_phase_rad", "rad", "its phase p1: a1 sin(angle + p1), the angle "
                              "from the operating point the workflow started at"),
                    Parameter("twice_per_rev_rad", "rad", "amplitude a2 of the sensor error twice per revolution",
                              lower=0.0),
                    Parameter("twice_per_rev_phase_rad", "rad", "its phase p2: a2 sin(2 angle + p2)")),
        placement="end", free_parameters=4, build=build_encoder_error,
        report=lambda b: {"once_per_rev_rad": b.once_per_rev_rad, "once_per_rev_phase_rad": b.once_per_rev_phase_rad,
                          "twice_per_rev_rad": b.twice_per_rev_rad,
                          "twice_per_rev_phase_rad": b.twice_per_rev_phase_rad},
        guesses=encoder_error_guesses,
        vanished=lambda b, delta: b.once_per_rev_rad + b.twice_per_rev_rad < delta / 2.0,
        random_block=lambda rng, u, f, period: EncoderError(
            once_per_rev_rad=rng.uniform(2e-3, 6e-3), once_per_rev_phase_rad=rng.uniform(-math.pi, math.pi),
            twice_per_rev_rad=rng.uniform(0.5e-3, 2e-3), twice_per_rev_phase_rad=rng.uniform(-math.pi, math.pi)),
        signature="r ~ a1 sin(y^ + p1) + a2 sin(2 y^ + p2): the same error at the same angle, at every speed",
        look_alikes=("gravity", "offset", "gain_error"), look_alike_only=True,
        implausible=encoder_error_implausible,
    ),
    Effect(
        name="load_friction", block_class=DriveTrain, toml_type="drive_train",
        toml_keys=(TomlKey("coulomb_friction_nm"), TomlKey("static_friction_nm"),
                   TomlKey("viscous_friction_nm_s_per_rad")),
        takes_sample_period=True,
        parameters=(Parameter("coulomb_per_inertia_rad_per_s2", "rad/s^2", "Coulomb friction T_c / J on the load's motion", lower=0.0),
                    Parameter("static_per_inertia_rad_per_s2", "rad/s^2", "breakaway friction T_s / J (>= T_c / J)", lower=0.0),
                    Parameter("viscous_per_inertia_per_s", "1/s", "viscous friction d_v / J", lower=0.0)),
        placement="dynamics", free_parameters=3, build=train_builder(friction_fields),
        report=friction_report, guesses=load_friction_guesses,
        # vanished: the breakaway friction holds the loop within half a noise bound (T_s / (J omega_n^2)
        # < delta / 2) and the viscous part adds less than 1 % to the loop's damping 2 zeta omega_n
        vanished=lambda b, delta: (static_error(b, b.static_friction_nm / b.total_inertia_kg_m2) < delta / 2.0
                                   and b.viscous_friction_nm_s_per_rad / b.total_inertia_kg_m2
                                   < 0.01 * 2.0 * b.position_loop_damping_ratio * b.natural_frequency_rad_per_s),
        random_block=random_load_friction,
        signature="a lag against the model's motion (r ~ -c sign(v^)), the load left short where it stops",
        train_fields=friction_fields,
        stick_slip=True,
        width_starts=friction_width_starts,
        resolution=lambda train, y_hat, e: torque_resolution(
            train, ("coulomb_per_inertia_rad_per_s2", "static_per_inertia_rad_per_s2"), e),
        loop_damping_value=2,  # d_v / J
        added_to_train=("viscous_per_inertia_per_s",),
    ),
    Effect(
        name="gravity", block_class=DriveTrain, toml_type="drive_train",
        toml_keys=(TomlKey("pendulum_mass_kg"), TomlKey("pendulum_length_m"), TomlKey("gravity_m_per_s2"),
                   TomlKey("hanging_angle_rad")),
        takes_sample_period=True,
        parameters=(Parameter("gravity_per_inertia_rad_per_s2", "rad/s^2", "m g l / J: the weight's largest torque over the inertia", lower=0.0),
                    Parameter("hanging_angle_rad", "rad", "angle at which the arm hangs straight down")),
        placement="dynamics", free_parameters=2, build=train_builder(gravity_fields),
        report=lambda b: {"gravity_per_inertia_rad_per_s2": b.gravity_torque_nm / b.total_inertia_kg_m2,
                          "hanging_angle_rad": b.hanging_angle_rad},
        guesses=gravity_guesses,
        # vanished: the arm's weight, horizontal, sags the loop by less than half a noise bound
        vanished=lambda b, delta: static_error(b, b.gravity_torque_nm / b.total_inertia_kg_m2) < delta / 2.0,
        random_block=random_gravity,
        signature="a position-dependent sag (r ~ -S sin(y^ - theta_0), S = m g l / (J omega_n^2))",
        train_fields=gravity_fields, look_alikes=("encoder_error",),
        angle_sag=lambda b: static_error(b, b.gravity_torque_nm / b.total_inertia_kg_m2),
        resolution=lambda train, y_hat, e: torque_resolution(train, ("gravity_per_inertia_rad_per_s2",), e),
    ),
    Effect(
        name="rate_limit", block_class=DriveTrain, toml_type="drive_train",
        toml_keys=(TomlKey("motor_speed_limit_rad_per_s"),), takes_sample_period=True,
        parameters=(Parameter("speed_limit_rad_per_s", "rad/s", "largest speed of the load (the drive's speed limit / N)", lower=0.0),),
        placement="dynamics", free_parameters=1, build=train_builder(rate_fields),
        report=lambda b: {"speed_limit_rad_per_s": b.motor_speed_limit_rad_per_s / b.gear_ratio},
        guesses=rate_limit_guesses,
        # vanished: never (as saturation): a limit the motion never reaches changes nothing, so it cannot
        # lower the penalised gap and is not kept
        vanished=lambda b, delta: False,
        random_block=random_rate_limit,
        signature="a lag that grows while the model moves faster than the limit (r ~ -T sum (v^ - clip(v^, q)))",
        train_fields=rate_fields,
        resolution=lambda train, y_hat, e: {"speed_limit_rad_per_s": limit_resolution(train, y_hat, e, 1)},
    ),
    Effect(
        name="torque_limit", block_class=DriveTrain, toml_type="drive_train",
        toml_keys=(TomlKey("motor_torque_limit_nm"),), takes_sample_period=True,
        parameters=(Parameter("torque_limit_per_inertia_rad_per_s2", "rad/s^2", "N tau_max / J: the largest acceleration the drive gives", lower=0.0),),
        placement="dynamics", free_parameters=1, build=train_builder(torque_fields),
        report=lambda b: {"torque_limit_per_inertia_rad_per_s2": b.motor_torque_limit_nm * b.gear_ratio
                          / b.total_inertia_kg_m2},
        guesses=torque_limit_guesses,
        vanished=lambda b, delta: False,  # as rate_limit
        random_block=random_torque_limit,
        signature="the lag of an acceleration limit (the double sum of the model's excess acceleration)",
        train_fields=torque_fields,
        resolution=lambda train, y_hat, e: {"torque_limit_per_inertia_rad_per_s2": limit_resolution(train, y_hat, e, 2)},
    ),
    Effect(
        name="shaft_play", block_class=DriveTrain, toml_type="drive_train",
        toml_keys=(TomlKey("play_rad"), TomlKey("shaft_stiffness_nm_per_rad"), TomlKey("shaft_damping_nm_s_per_rad")),
        takes_sample_period=True,
        parameters=(Parameter("play_rad", "rad", "total width of the play between the motor and the load inertia",
                              lower=0.0),),
        placement="dynamics", free_parameters=1, build=train_builder(play_fields),
        report=lambda b: {"play_rad": b.play_rad},
        guesses=shaft_play_guesses,
        vanished=lambda b, delta: b.play_rad < delta,  # as backlash: a play narrower than the noise bound
        random_block=random_shaft_play,
        signature="at a reversal the load coasts on through the play while the drive turns back, then is "
                  "caught with a bounce (output backlash instead holds the output still)",
        needs_reversals=True,
        train_fields=play_fields,
        width_starts=lambda width, train: [(0.5 * width,), (width,)],
    ),
    Effect(
        name="shaft_friction", block_class=DriveTrain, toml_type="drive_train",
        toml_keys=(TomlKey("shaft_friction_nm"), TomlKey("shaft_presliding_twist_rad"),
                   TomlKey("shaft_stiffness_nm_per_rad"), TomlKey("shaft_damping_nm_s_per_rad")),
        takes_sample_period=True,
        parameters=(Parameter("friction_twist_rad", "rad", "twist the shaft's dry friction holds against its spring "
                              "(T_h / k)", lower=0.0),
                    Parameter("presliding_twist_rad", "rad", "twist over which the friction goes from sticking to "
                              "sliding (Dahl's T_h / sigma_0)", lower=0.0)),
        placement="dynamics", free_parameters=2, build=train_builder(shaft_friction_fields),
        report=shaft_friction_report, guesses=shaft_friction_guesses,
        # vanished: the friction holds less than half a noise bound of twist
        vanished=lambda b, delta: shaft_friction_report(b)["friction_twist_rad"] < delta / 2.0,
        random_block=random_shaft_friction,
        signature="the shaft's mode rings less and stiffer after small reversals, and the load stops up to T_h / k "
                  "off where the shaft's spring alone would leave it, on the side it came from",
        train_fields=shaft_friction_fields, needs_shaft=True,
    ),
)}
"""Every effect, by its diagnose name, in the order the workflow tries them."""

EFFECT_NAMES: tuple[str, ...] = tuple(EFFECTS)
"""Names of the effects the workflow can name."""

SEARCHED_EFFECT_NAMES: tuple[str, ...] = tuple(name for name, entry in EFFECTS.items() if not entry.look_alike_only)
"""The effects the workflow searches by default (the others are tried as look-alikes of a named effect)."""

LOOK_ALIKE_EXPERIMENTS: dict[frozenset[str], str] = {
    frozenset({"gravity", "encoder_error"}): (
        "move slowly through a full revolution in both directions, or at two speeds or with a softer servo: a "
        "sensor error is the same at every speed and servo setting, while a load torque deflects the load more "
        "when the servo is softer and lags at higher acceleration; or read the angle with a second encoder"),
    frozenset({"offset", "encoder_error"}): (
        "move through a wider range of angles (a quarter turn or more, in both directions): an offset is the same "
        "at every angle, while an error that depends on the angle (a sensor error, a load torque, cogging) changes "
        "with it; over a small range of angles any of them is a constant"),
    frozenset({"gain_error", "encoder_error"}): (
        "move through a wider range of angles (a quarter turn or more, in both directions): a gain error grows in "
        "proportion to the angle, while a once-per-revolution error turns back within the revolution; over a small "
        "range of angles both are a slope"),
    frozenset({"gravity", "offset"}): (
        "move through a wider range of angles (a quarter turn or more, in both directions): an offset is the same "
        "at every angle, while a load's weight sags the load by an amount that changes with the angle"),
    frozenset({"backlash", "coulomb_friction"}): (
        "record again at another position-loop gain (friction's band, twice F / k, shrinks as the loop stiffness k "
        "grows; a play keeps its width), or log the drive's torque or current through the reversals (a play turns "
        "the motor through its width with "
        "almost no torque, friction needs its full breakaway torque at once), or read the motor side with a "
        "second encoder (across a play the motor moves while the load stands; under friction both stand), or "
        "lock the output and twist the input both ways at low torque"),
}
"""The experiment that tells look-alike effects apart (catalogue ``look_alikes`` and ``same_map_as``), for the
verdict's reason."""


def look_alike_experiments(pairs: Iterable[frozenset[str]]) -> str:
    """The experiments of :data:`LOOK_ALIKE_EXPERIMENTS` that separate ``pairs`` of effects, joined with "; and ",
    each said once: experiments that start with the same instruction (the text before the first ": ") give it
    once, followed by each of their reasons."""
    reasons: dict[str, list[str]] = {}
    for pair in dict.fromkeys(pairs):
        if pair in LOOK_ALIKE_EXPERIMENTS:
            instruction, _, why = LOOK_ALIKE_EXPERIMENTS[pair].partition(": ")
            reasons.setdefault(instruction, [])
            if why and why not in reasons[instruction]:
                reasons[instruction].append(why)
    return "; and ".join(": ".join((instruction, "; ".join(whys))) if whys else instruction
                         for instruction, whys in reasons.items())


ANGLE_SHAPE_EXPERIMENT = (
    "move through a wider range of angles (a quarter turn or more, in both directions): a weight's sag is a sine of "
    "the angle once per revolution, while cogging repeats many times a revolution and a spring grows with the angle")
"""The experiment that shows the shape of an effect over the angle (catalogue ``angle_sag``)."""

LINEAR_ORDER_EXPERIMENT = (
    "a step of the command, read at a finer time step if the drive allows: a delay leaves the angle still for its "
    "d samples and then moves it, while poles move it at once but slowly; or a model of the drive's loop")
"""The experiment that tells a delay from linear dynamics of a higher order (catalogue ``order_look_alike``)."""


def _play_or_friction(parameters: Mapping[str, float]) -> str:
    c_l, c_r = parameters["c_l_rad"], parameters["c_r_rad"]
    return (f"a play of width {c_l + c_r:.3g} rad (c_l {c_l:.3g}, c_r {c_r:.3g}), or Coulomb friction without "
            f"stiction that leaves the output {0.5 * (c_l + c_r):.3g} rad behind the command either way (divide by "
            f"the position loop's stiffness per unit torque to read it as a torque), with an offset of "
            f"{0.5 * (c_l - c_r):.3g} rad")


SAME_MAP_READINGS: dict[tuple[str, str], Callable[[Mapping[str, float]], str]] = {
    ("backlash", "coulomb_friction"): _play_or_friction,
}
"""(named effect, other mechanism) -> the named effect's fitted parameters read as either mechanism, in words
(catalogue ``same_map_as``)."""

_BY_CLASS = {entry.block_class: entry for entry in EFFECTS.values() if entry.placement != "dynamics"}
_BY_TOML = {entry.toml_type: entry for entry in EFFECTS.values() if entry.placement != "dynamics"}
"""Blocks and TOML types of one effect each; the dynamics effects share the ``drive_train`` block and table
(read and written as a whole by :mod:`sim_backend.plant_config`)."""

DYNAMICS_EFFECTS: tuple[str, ...] = tuple(name for name, entry in EFFECTS.items() if entry.placement == "dynamics")
"""The effects realised inside a drive train."""


def effect(name: str) -> Effect:
    """The entry of ``name``; :class:`InvalidInputError` naming the choices otherwise."""
    try:
        return EFFECTS[name]
    except KeyError:
        raise InvalidInputError(f"effect: unknown effect {name!r}; expected one of {', '.join(EFFECT_NAMES)}") from None


def effect_for_block(block: Block) -> Effect | None:
    """The entry whose block class ``block`` is, or None (a linear block, an input backlash, a drive train:
    the dynamics effects it holds are :data:`DYNAMICS_EFFECTS`)."""
    return _BY_CLASS.get(type(block))


def effect_for_toml_type(toml_type: str) -> Effect | None:
    """The entry whose plant TOML ``type`` is ``toml_type``, or None."""
    return _BY_TOML.get(toml_type)


PLACEMENTS = ("input", "output", "end", "dynamics")
"""Where an effect can sit (module docstring)."""


def _check() -> None:
    for entry in EFFECTS.values():
        if entry.placement not in PLACEMENTS:
            raise AssertionError(f"{entry.name}: placement {entry.placement!r}")
        if not math.isfinite(entry.free_parameters) or entry.free_parameters < 1:
            raise AssertionError(f"{entry.name}: free_parameters")
        if (entry.placement == "dynamics") != (entry.train_fields is not None):
            raise AssertionError(f"{entry.name}: a dynamics effect, and only one, has train_fields")
        if entry.needs_shaft and entry.placement != "dynamics":
            raise AssertionError(f"{entry.name}: only an effect inside the drive train can need its shaft")
        if entry.inner_twin and entry.half_widths is None:
            raise AssertionError(f"{entry.name}: an effect with an inner twin gives its hysteresis' half-widths")
        if any(EFFECTS[name].placement != "dynamics" for name in entry.inner_twin):
            raise AssertionError(f"{entry.name}: an inner twin is made of dynamics effects (one drive train)")
        for other in entry.look_alikes:
            if entry.name not in EFFECTS[other].look_alikes or frozenset({entry.name, other}) not in LOOK_ALIKE_EXPERIMENTS:
                raise AssertionError(f"{entry.name}: look-alikes are mutual and say what separates them")


_check()
