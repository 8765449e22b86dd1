"""Plant descriptions in TOML (``configs/plants/*.toml``) to and from the dataclasses of
:mod:`identify.plant_blocks`, :mod:`rig.protocols.encoder_counts` and :mod:`sim_backend.noise`.

Every key is validated by :mod:`rig.protocols.config_schema`: an error names the file, the dotted key and
what was expected, and unknown keys are rejected. The format::

    name = "cerone2009"                  # optional (default: the file name)
    description = "..."                  # optional
    sample_period_s = 1.0
    seed = 2009                          # optional: seed of the noise generator

    [encoder]                            # EncoderResolution
    bits = 12
    multi_turn_bits = 0                  # optional
    signed = true                        # optional (default false)
    direction = 1                        # optional, +1 or -1
    offset_counts = 0                    # optional

    [noise]
    kind = "uniform"                     # quantization | uniform | gaussian | coloured
    bound_rad = 7.67e-4                  # uniform
    # std_rad = ... or snr_db = ...      # gaussian, coloured
    # numerator = [1.0, 0.5]             # coloured: G_v(q) in q^-1
    # denominator = [1.0, -0.85]

    [[blocks]]                           # in signal order, the command enters the first
    type = "linear"                      # see BLOCK_TYPES for every type and its keys
    a = [0.5, 0.7]
    b = [0.0, 1.4, 0.8]
    # enabled = false                    # any block: keep it in the file but switch it off

A ``drive_train`` block (:class:`identify.drive_train.DriveTrain`, the physical train with position loop,
play, shaft, friction and gravity) takes the constructor's keyword arguments as keys, each with its unit in
its name (see ``DRIVE_TRAIN_KEYS``); the sample period is the file's. Only ``gear_ratio``,
``motor_inertia_kg_m2`` and ``load_inertia_kg_m2`` are required; a limit that is left out is no limit, and a
``shaft_stiffness_nm_per_rad`` left out is a rigid shaft (the form ``rig diagnose`` fits its drive-train
effects in: friction on the load, gravity, rate and torque limits).

An ``output_backlash`` table may add ``backlash_growth = { per_rad_travel = 2e-6, max_rad = 0.05 }``: its play then
grows with wear, each flank by k rad per rad of output travel it drives, up to max_rad
(:class:`identify.backlash_wear.WearingOutputBacklash`; ``max_rad`` optional, no limit). Without the key the
block is the backlash of the catalogue, exactly as before.

Input backlash and switch borders are inline tables: ``{ kind = "table", nodes_u = [...], values = [...] }``
or ``{ kind = "arctan", input_shift_rad = -1.0, output_shift_rad = 0.0, lower_input_rad = -2.0,
upper_input_rad = 2.0, lower_value_rad = -1.0, upper_value_rad = 1.0 }`` (the limits are optional).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from identify.backlash_wear import BacklashGrowth, WearingOutputBacklash
from identify.drive_train import POSITION_FEEDBACK, DriveTrain
from identify.effect_catalogue import EFFECTS, Effect, effect_for_block
from identify.plant_blocks import (
    ArctanBorder,
    Block,
    InputBacklash,
    InputSwitch,
    LinearBlock,
    OutputBacklash,
    PiecewiseLinearBorder,
    PlantModel,
)
from identify.validation import InvalidInputError
from rig.protocols.config_schema import ConfigTable, load_toml
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import ConfigError
from sim_backend.noise import BoundedUniformNoise, ColouredNoise, GaussianNoise, NoiseModel, NoNoise
from sim_backend.plant import SimulatedGearbox

__all__ = ["BLOCK_TYPES", "PlantConfig", "describe_noise", "load_plant_config", "load_simulated_plant",
           "plant_config_from_toml_text", "plant_config_to_toml"]


@dataclass(frozen=True)
class PlantConfig:
    """A plant description: the blocks (with their on/off switches), the encoder, the noise and the seed."""

    name: str
    sample_period_s: float
    encoder: EncoderResolution
    noise: NoiseModel
    blocks: tuple[Block, ...]
    enabled: tuple[bool, ...] = ()
    seed: int | None = None
    description: str = ""
    source: str = "<memory>"

    def __post_init__(self) -> None:
        if not self.enabled:
            object.__setattr__(self, "enabled", (True,) * len(self.blocks))
        if len(self.enabled) != len(self.blocks):
            raise InvalidInputError(f"enabled: expected one switch per block ({len(self.blocks)}), got {len(self.enabled)}")

    @property
    def plant(self) -> PlantModel:
        """The enabled blocks, in signal order."""
        return PlantModel(tuple(block for block, on in zip(self.blocks, self.enabled) if on))

    def gearbox(self, seed: int | None = None) -> SimulatedGearbox:
        """The :class:`SimulatedGearbox`; ``seed`` overrides the config's seed."""
        return SimulatedGearbox(
            plant=self.plant,
            encoder=self.encoder,
            noise=self.noise,
            sample_period_s=self.sample_period_s,
            seed=seed if seed is not None else self.seed,
            name=self.name,
        )


# ----------------------------------------------------------------------------------------------------------
# Reading
# ----------------------------------------------------------------------------------------------------------


def load_plant_config(path: str | Path) -> PlantConfig:
    """Read and validate a plant config; raises :class:`ConfigError` naming the file and key."""
    root = load_toml(path)
    return _parse(root, default_name=Path(path).stem)


def load_simulated_plant(path: str | Path, *, sample_period_s: float, encoder: EncoderResolution,
                         fmu_input: str | None = None, fmu_output: str | None = None,
                         fmu_parameters: Mapping[str, Any] | None = None) -> PlantConfig:
    """The plant behind a simulated rig (``[simulation] plant`` of a rig config): a plant TOML, or an FMU
    (:func:`sim_backend.fmu_plant.fmu_plant_config`: the FMU's block at the rig's sample period, read by the
    rig's encoder; ``fmu_input`` / ``fmu_output`` choose its variables when it has several, and
    ``fmu_parameters`` set its parameters)."""
    from sim_backend.fmu_plant import fmu_plant_config, is_fmu_path

    if is_fmu_path(path):
        return fmu_plant_config(path, sample_period_s, encoder, input_name=fmu_input, output_name=fmu_output,
                                options=("fmu_input", "fmu_output"), parameters=fmu_parameters)
    return load_plant_config(path)


def plant_config_from_toml_text(text: str, source: str = "<text>") -> PlantConfig:
    """Parse a plant config from a TOML string (used by round trips and tests)."""
    import tomllib

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(source, "<file>", f"not valid TOML: {err}") from err
    return _parse(ConfigTable(source, "", data), default_name="plant")


def _parse(root: ConfigTable, default_name: str) -> PlantConfig:
    name = root.string("name", default_name)
    description = root.string("description", "")
    period = root.number("sample_period_s", minimum=0.0, exclusive_minimum=True)
    seed = root.integer("seed", None, minimum=0)
    encoder = _parse_encoder(root.table("encoder"))
    noise = _parse_noise(root.table("noise", {}))
    blocks, enabled = [], []
    for table in root.tables("blocks"):
        block, on = _parse_block(table, period)
        blocks.append(block)
        enabled.append(on)
    if not blocks:
        raise root.error("blocks", "expected at least one [[blocks]] table")
    root.finish()
    config = PlantConfig(name=name, sample_period_s=period, encoder=encoder, noise=noise, blocks=tuple(blocks),
                         enabled=tuple(enabled), seed=seed, description=description, source=root.source)
    try:
        config.plant  # noqa: B018 - validates the chain as a whole
    except InvalidInputError as err:
        raise root.error("blocks", str(err)) from err
    return config


def _build(table: ConfigTable, factory: Callable[..., Any], **kwargs: Any) -> Any:
    try:
        return factory(**kwargs)
    except InvalidInputError as err:
        message = str(err)
        argument = message.split(":", 1)[0].split(",")[0].strip()
        key = argument if argument in kwargs else "<table>"
        raise table.error(key, message.split(":", 1)[1].strip() if key != "<table>" else message) from err


def _parse_encoder(table: ConfigTable) -> EncoderResolution:
    encoder = _build(
        table,
        EncoderResolution,
        bits=table.integer("bits", minimum=1, maximum=32),
        multi_turn_bits=table.integer("multi_turn_bits", 0, minimum=0, maximum=32),
        signed=table.boolean("signed", False),
        direction=table.integer("direction", 1, minimum=-1, maximum=1),
        offset_counts=table.integer("offset_counts", 0, minimum=0),
    )
    table.finish()
    return encoder


NOISE_KINDS = ("quantization", "uniform", "gaussian", "coloured")


def _parse_noise(table: ConfigTable) -> NoiseModel:
    kind = table.string("kind", "quantization", choices=NOISE_KINDS)
    if kind == "quantization":
        noise: NoiseModel = NoNoise()
    elif kind == "uniform":
        noise = _build(table, BoundedUniformNoise, bound_rad=table.number("bound_rad", minimum=0.0, exclusive_minimum=True))
    else:
        std = table.number("std_rad", None, minimum=0.0, exclusive_minimum=True)
        snr = table.number("snr_db", None)
        if (std is None) == (snr is None):
            raise table.error("std_rad", "give exactly one of std_rad and snr_db")
        if kind == "gaussian":
            noise = _build(table, GaussianNoise, std_rad=std, snr_db=snr)
        else:
            noise = _build(table, ColouredNoise, std_rad=std, snr_db=snr,
                           numerator=tuple(table.numbers("numerator", [1.0, 0.5], min_length=1)),
                           denominator=tuple(table.numbers("denominator", [1.0, -0.85], min_length=1)))
    table.finish()
    return noise


def _parse_border(table: ConfigTable, key: str) -> Any:
    border = table.table(key)
    kind = border.string("kind", choices=("table", "arctan"))
    if kind == "table":
        result = _build(border, PiecewiseLinearBorder, nodes_u=tuple(border.numbers("nodes_u", min_length=2)),
                        values=tuple(border.numbers("values", min_length=2)))
    else:
        result = _build(
            border, ArctanBorder,
            input_shift_rad=border.number("input_shift_rad"),
            output_shift_rad=border.number("output_shift_rad", 0.0),
            lower_input_rad=(border.number("lower_input_rad", -math.inf) if border.has("lower_input_rad")
                             else -math.inf),
            upper_input_rad=(border.number("upper_input_rad", math.inf) if border.has("upper_input_rad")
                             else math.inf),
            lower_value_rad=border.number("lower_value_rad", 0.0),
            upper_value_rad=border.number("upper_value_rad", 0.0),
        )
    border.finish()
    return result


def _parse_block(table: ConfigTable, period: float) -> tuple[Block, bool]:
    kind = table.string("type", choices=tuple(BLOCK_TYPES))
    enabled = table.boolean("enabled", True)
    block = BLOCK_TYPES[kind][1](table, period)
    table.finish()
    return block, enabled


def _read_linear(t: ConfigTable, period: float) -> LinearBlock:
    return _build(t, LinearBlock, a=tuple(t.numbers("a")), b=tuple(t.numbers("b", min_length=1)), sample_period_s=period)


def _read_state_space(t: ConfigTable, period: float) -> LinearBlock:
    A = t.matrix("A")
    B, C = t.numbers("B", min_length=1), t.numbers("C", min_length=1)
    D = t.number("D", 0.0)
    try:
        return LinearBlock.from_state_space(A, B, C, D, period)
    except (InvalidInputError, ValueError) as err:
        raise t.error(str(err).split(":", 1)[0], str(err)) from err


def _read_input_backlash(t: ConfigTable, period: float) -> InputBacklash:
    return _build(t, InputBacklash, ascending=_parse_border(t, "ascending"), descending=_parse_border(t, "descending"),
                  initial_output_rad=t.number("initial_output_rad", 0.0))


def _read_input_switch(t: ConfigTable, period: float) -> InputSwitch:
    return _build(t, InputSwitch, ascending=_parse_border(t, "ascending"), descending=_parse_border(t, "descending"),
                  initial_input_rad=t.number("initial_input_rad", 0.0),
                  initial_ascending=t.boolean("initial_ascending", True))


def _effect_reader(entry: Effect) -> Callable[[ConfigTable, float], Block]:
    """The reader of an effect's table, from its catalogue entry's keys (:mod:`identify.effect_catalogue`)."""

    def read(t: ConfigTable, period: float) -> Block:
        values: dict[str, Any] = {}
        for key in entry.toml_keys:
            getter = t.integer if key.kind == "integer" else t.number
            extra = {"minimum": 0} if key.kind == "integer" else {}
            values[key.key] = getter(key.key, **extra) if key.default is None else getter(key.key, key.default, **extra)
        kwargs = dict(values)
        if entry.takes_sample_period:
            kwargs["sample_period_s"] = period
        return _build(t, entry.block_class, **kwargs)

    return read


DRIVE_TRAIN_REQUIRED = ("gear_ratio", "motor_inertia_kg_m2", "load_inertia_kg_m2")
DRIVE_TRAIN_NUMBERS = ("shaft_damping_nm_s_per_rad", "play_rad", "shaft_friction_nm", "shaft_presliding_twist_rad",
                       "position_loop_bandwidth_hz",
                       "position_loop_damping_ratio", "velocity_feedforward", "position_integral_gain_per_s",
                       "motor_viscous_damping_nm_s_per_rad", "coulomb_friction_nm", "static_friction_nm",
                       "viscous_friction_nm_s_per_rad", "pendulum_mass_kg", "pendulum_length_m", "gravity_m_per_s2",
                       "hanging_angle_rad", "initial_angle_rad")
DRIVE_TRAIN_LIMITS = ("shaft_stiffness_nm_per_rad", "motor_speed_limit_rad_per_s", "motor_torque_limit_nm")
DRIVE_TRAIN_KEYS = (*DRIVE_TRAIN_REQUIRED, *DRIVE_TRAIN_NUMBERS, *DRIVE_TRAIN_LIMITS, "position_feedback",
                    "drive_enabled")
"""The keys of a ``drive_train`` block: required, optional numbers (default: the constructor's), limits
(left out: infinite, i.e. a rigid shaft, no speed limit, no torque limit; TOML has no way to write a missing
limit other than leaving it out), and the two switches."""


def _read_drive_train(t: ConfigTable, period: float) -> DriveTrain:
    defaults = DriveTrain.__dataclass_fields__
    kwargs: dict[str, Any] = {key: t.number(key) for key in DRIVE_TRAIN_REQUIRED}
    kwargs.update({key: t.number(key, defaults[key].default) for key in DRIVE_TRAIN_NUMBERS})
    kwargs.update({key: t.number(key) for key in DRIVE_TRAIN_LIMITS if t.has(key)})
    kwargs.setdefault("shaft_stiffness_nm_per_rad", math.inf)  # left out: a rigid shaft
    kwargs["position_feedback"] = t.string("position_feedback", defaults["position_feedback"].default,
                                           choices=POSITION_FEEDBACK)
    kwargs["drive_enabled"] = t.boolean("drive_enabled", defaults["drive_enabled"].default)
    return _build(t, DriveTrain, sample_period_s=period, **kwargs)


BACKLASH_GROWTH_KEY = "backlash_growth"
"""The optional key of an ``output_backlash`` table that makes its play grow with wear
(:mod:`identify.backlash_wear`): ``backlash_growth = { per_rad_travel = 2e-6, max_rad = 0.02 }``, k and g_max
of the law, ``max_rad`` optional (no limit)."""


def _wearing_reader(plain: Callable[[ConfigTable, float], Block]) -> Callable[[ConfigTable, float], Block]:
    """The ``output_backlash`` reader: the catalogue's (``plain``), or with :data:`BACKLASH_GROWTH_KEY` a
    :class:`WearingOutputBacklash` of the same keys."""

    def read(t: ConfigTable, period: float) -> Block:
        if not t.has(BACKLASH_GROWTH_KEY):
            return plain(t, period)
        growth_table = t.table(BACKLASH_GROWTH_KEY)
        growth = _build(growth_table, BacklashGrowth,
                        per_rad_travel=growth_table.number("per_rad_travel", minimum=0.0),
                        max_rad=growth_table.number("max_rad", minimum=0.0, exclusive_minimum=True)
                        if growth_table.has("max_rad") else math.inf)
        growth_table.finish()
        return _build(t, WearingOutputBacklash, m_l=t.number("m_l"), c_l_rad=t.number("c_l_rad"),
                      m_r=t.number("m_r"), c_r_rad=t.number("c_r_rad"),
                      initial_output_rad=t.number("initial_output_rad", 0.0), growth=growth)

    return read


BLOCK_TYPES: dict[str, tuple[type, Callable[[ConfigTable, float], Block]]] = {
    "linear": (LinearBlock, _read_linear),
    "state_space": (LinearBlock, _read_state_space),
    "input_backlash": (InputBacklash, _read_input_backlash),
    "input_switch": (InputSwitch, _read_input_switch),
    **{entry.toml_type: (entry.block_class, _effect_reader(entry)) for entry in EFFECTS.values()
       if entry.placement != "dynamics"},
    "drive_train": (DriveTrain, _read_drive_train),
}
"""``type`` in a ``[[blocks]]`` table -> (block class, reader): the linear and Hammerstein blocks, then every
effect of the catalogue (:data:`identify.effect_catalogue.EFFECTS`) under its ``toml_type``; the catalogue's
dynamics effects (friction on the load, gravity, rate and torque limits, shaft play) are keys of the one
``drive_train`` table. An ``output_backlash`` with :data:`BACKLASH_GROWTH_KEY` is a
:class:`~identify.backlash_wear.WearingOutputBacklash`."""
BLOCK_TYPES["output_backlash"] = (OutputBacklash, _wearing_reader(BLOCK_TYPES["output_backlash"][1]))


# ----------------------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------------------


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
        return f'"{escaped}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_value(item) for item in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{key} = {_value(item)}" for key, item in value.items()) + " }"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def _border_fields(border: Any, key: str) -> dict[str, Any]:
    if isinstance(border, PiecewiseLinearBorder):
        return {"kind": "table", "nodes_u": list(border.nodes_u), "values": list(border.values)}
    if isinstance(border, ArctanBorder):
        fields: dict[str, Any] = {"kind": "arctan", "input_shift_rad": border.input_shift_rad,
                                  "output_shift_rad": border.output_shift_rad}
        if math.isfinite(border.lower_input_rad):
            fields.update(lower_input_rad=border.lower_input_rad, lower_value_rad=border.lower_value_rad)
        if math.isfinite(border.upper_input_rad):
            fields.update(upper_input_rad=border.upper_input_rad, upper_value_rad=border.upper_value_rad)
        return fields
    raise InvalidInputError(
        f"{key}: a {type(border).__name__} border cannot be written to TOML; use PiecewiseLinearBorder or ArctanBorder"
    )


def _block_fields(block: Block) -> dict[str, Any]:
    if isinstance(block, LinearBlock):
        return {"type": "linear", "a": list(block.a), "b": list(block.b)}
    if isinstance(block, InputBacklash):
        return {"type": "input_backlash", "ascending": _border_fields(block.ascending, "ascending"),
                "descending": _border_fields(block.descending, "descending"),
                "initial_output_rad": block.initial_output_rad}
    if isinstance(block, InputSwitch):
        return {"type": "input_switch", "ascending": _border_fields(block.ascending, "ascending"),
                "descending": _border_fields(block.descending, "descending"),
                "initial_input_rad": block.initial_input_rad, "initial_ascending": block.initial_ascending}
    if isinstance(block, WearingOutputBacklash):
        growth = {"per_rad_travel": block.growth.per_rad_travel}
        if math.isfinite(block.growth.max_rad):
            growth["max_rad"] = block.growth.max_rad
        return {**_block_fields(block.unworn), BACKLASH_GROWTH_KEY: growth}
    entry = effect_for_block(block)
    if entry is not None:
        return entry.toml_fields(block)
    if isinstance(block, DriveTrain):
        fields = {"type": "drive_train"}
        fields.update({key: getattr(block, key) for key in (*DRIVE_TRAIN_REQUIRED, *DRIVE_TRAIN_NUMBERS)})
        fields.update({key: getattr(block, key) for key in DRIVE_TRAIN_LIMITS if math.isfinite(getattr(block, key))})
        fields.update(position_feedback=block.position_feedback, drive_enabled=block.drive_enabled)
        return fields
    raise InvalidInputError(f"blocks: a {type(block).__name__} block has no TOML form")


def _noise_fields(noise: NoiseModel) -> dict[str, Any]:
    if isinstance(noise, NoNoise):
        return {"kind": "quantization"}
    if isinstance(noise, BoundedUniformNoise):
        return {"kind": "uniform", "bound_rad": noise.bound_rad}
    if isinstance(noise, (GaussianNoise, ColouredNoise)):
        fields: dict[str, Any] = {"kind": noise.kind}
        if noise.std_rad is not None:
            fields["std_rad"] = noise.std_rad
        else:
            fields["snr_db"] = float(noise.snr_db)
        if isinstance(noise, ColouredNoise):
            fields.update(numerator=list(noise.numerator), denominator=list(noise.denominator))
        return fields
    raise InvalidInputError(f"noise: a {type(noise).__name__} has no TOML form")


def describe_noise(noise: NoiseModel) -> dict[str, Any]:
    """The ``[noise]`` table of ``noise`` as a plain dict (what a log records about the noise)."""
    return _noise_fields(noise)


def plant_config_to_toml(config: PlantConfig) -> str:
    """Write ``config`` as TOML that :func:`load_plant_config` reads back to an equal config."""
    lines = [f"name = {_value(config.name)}"]
    if config.description:
        lines.append(f"description = {_value(config.description)}")
    lines.append(f"sample_period_s = {_value(float(config.sample_period_s))}")
    if config.seed is not None:
        lines.append(f"seed = {_value(int(config.seed))}")
    encoder = config.encoder
    lines += ["", "[encoder]", f"bits = {encoder.bits}", f"multi_turn_bits = {encoder.multi_turn_bits}",
              f"signed = {_value(encoder.signed)}", f"direction = {encoder.direction}",
              f"offset_counts = {encoder.offset_counts}", "", "[noise]"]
    lines += [f"{key} = {_value(value)}" for key, value in _noise_fields(config.noise).items()]
    for block, on in zip(config.blocks, config.enabled):
        lines += ["", "[[blocks]]"]
        lines += [f"{key} = {_value(value)}" for key, value in _block_fields(block).items()]
        if not on:
            lines.append("enabled = false")
    return "\n".join(lines) + "\n"
