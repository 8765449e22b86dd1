"""Rig configs (``configs/sim_*.toml``, ``configs/rig_*.toml``): which transport, which devices, which
limits, and (for a simulated rig) which plant answers on the wire.

The format::

    name = "sim_serial"                  # optional (default: the file name)
    description = "..."                  # optional
    sample_rate_hz = 1000.0              # the rig's fixed sample rate

    [transport]
    url = "serial:///dev/ttyUSB0"        # canopen://IFACE/CHANNEL | can://IFACE/CHANNEL | serial://PATH
    # ...                                # the chosen transport's options (unknown ones are rejected)

    [drive]
    counts_per_revolution = 131072       # drive position units per motor revolution

    [encoder]                            # the load encoder (rig.protocols.encoder_counts.EncoderResolution)
    bits = 12
    multi_turn_bits = 0
    signed = true
    direction = 1
    offset_counts = 0

    [limits]                             # software limits, checked before anything is sent
    position_min_rad = -12.0
    position_max_rad = 12.0
    rate_max_rad_per_s = 5000.0

    [watchdog]
    feedback_timeout_s = 0.1             # no feedback for this long: controlled stop
    late_tolerance_s = 0.0005            # a cycle that starts later than this after its deadline is LATE

    [bring_up]                           # optional: the CiA 402 state machine's deadlines and pacing
    enable_timeout_s = 5.0               # the walk to OPERATION ENABLED
    fault_reset_timeout_s = 1.0          # how long FAULT may last after the reset's rising edge
    quick_stop_timeout_s = 0.5           # the stop waits this long for the motor to halt, then disables
    poll_interval_s = 0.002              # statusword polling pace while waiting for a transition

    [simulation]                         # only for a simulated rig: the plant behind the wire
    plant = "plants/precision_gearbox.toml"   # relative to this file; or an FMU: "my_gearbox.fmu"
    seed = 4                             # optional: seed of the simulated noise
    # fmu_input = "command"              # an FMU with several real inputs/outputs: which carry the
    # fmu_output = "angle"               # commanded angle and the load angle (rad)
    # fmu_parameters = { damping_ratio = 0.5 }   # set before the FMU starts (`rig inspect my_gearbox.fmu` lists them)

A simulated serial rig uses ``url = "serial://pty"``: the simulated device creates a pty and the command
line puts its path in the URL.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from identify.validation import InvalidInputError
from rig.protocols.cia402 import BringUpTiming, DriveScaling
from rig.protocols.config_schema import ConfigTable, load_toml
from rig.protocols.encoder_counts import EncoderResolution
from rig.protocols.errors import ConfigError
from rig.transports import parse_transport_url, transport_class
from rig.transports.base import CommandLimits

__all__ = ["RigConfig", "SimulationConfig", "load_rig_config"]

SIMULATED_SERIAL_URL = "serial://pty"


@dataclass(frozen=True)
class SimulationConfig:
    """The plant behind a simulated rig's wire."""

    plant_path: Path
    seed: int | None = None
    fmu_input: str | None = None
    fmu_output: str | None = None
    fmu_parameters: dict[str, Any] = field(default_factory=dict)
    fmu_seconds_per_sample: float | None = None
    """How long the FMU plant took a sample when the config was loaded (measured: a plant slower than the
    rig's clock makes the simulated devices miss their deadlines, and the run's error then says so)."""


@dataclass(frozen=True)
class RigConfig:
    """A validated rig config; :meth:`transport_options` are the keyword arguments of the transport."""

    name: str
    source: str
    sample_rate_hz: float
    url: str
    scheme: str
    options: dict[str, Any]
    drive: DriveScaling
    encoder: EncoderResolution
    limits: CommandLimits
    feedback_timeout_s: float
    late_tolerance_s: float
    simulation: SimulationConfig | None = None
    description: str = ""
    raw: dict[str, Any] = field(default_factory=dict)
    timing: BringUpTiming = field(default_factory=BringUpTiming)

    @property
    def sample_period_s(self) -> float:
        return 1.0 / self.sample_rate_hz

    def transport_options(self) -> dict[str, Any]:
        """Everything the transport's constructor takes besides the URL."""
        return {**self.options, "encoder": self.encoder, "sample_period_s": self.sample_period_s,
                "limits": self.limits, "drive": self.drive, "timing": self.timing}


def _encoder(table: ConfigTable) -> EncoderResolution:
    try:
        encoder = EncoderResolution(
            bits=table.integer("bits", minimum=1, maximum=32),
            multi_turn_bits=table.integer("multi_turn_bits", 0, minimum=0, maximum=32),
            signed=table.boolean("signed", False),
            direction=table.integer("direction", 1, minimum=-1, maximum=1),
            offset_counts=table.integer("offset_counts", 0, minimum=0),
        )
    except InvalidInputError as err:
        key = str(err).split(":", 1)[0]
        raise table.error(key if table.has(key) else "<table>", str(err)) from err
    if encoder.bits + encoder.multi_turn_bits > 32:
        raise table.error("multi_turn_bits", "bits + multi_turn_bits must be at most 32 (a 32-bit position value)")
    table.finish()
    return encoder


def _option_defaults(cls: type) -> dict[str, Any]:
    """Each keyword option of a transport class (and its bases) with its default (or None without one)."""
    import inspect

    defaults: dict[str, Any] = {}
    for klass in reversed(cls.__mro__):
        if "__init__" in vars(klass):
            for name, parameter in inspect.signature(klass.__init__).parameters.items():
                if parameter.kind is parameter.KEYWORD_ONLY or parameter.kind is parameter.POSITIONAL_OR_KEYWORD:
                    defaults[name] = None if parameter.default is parameter.empty else parameter.default
    return defaults


def _transport_options(table: ConfigTable, scheme: str) -> dict[str, Any]:
    """The ``[transport]`` options, each checked against the type of the transport's own default (a count in
    ``*_ms``, a rate and a timeout in ``*_s`` must be > 0)."""
    cls = transport_class(scheme)
    from rig.transports import _accepted_options

    accepted = _accepted_options(cls) - {"encoder", "sample_period_s", "limits", "drive", "timing", "name"}
    defaults = _option_defaults(cls)
    options: dict[str, Any] = {}
    for key, value in table.data.items():
        if key == "url":
            continue
        if key not in accepted:
            raise table.error(key, f"not an option of the {scheme} transport (accepted: {', '.join(sorted(accepted))})")
        default = defaults.get(key)
        positive = key.endswith(("_s", "_ms", "rate")) or key in ("bitrate", "baudrate")
        if isinstance(default, bool):
            options[key] = table.boolean(key)
        elif isinstance(default, int):
            options[key] = table.integer(key, minimum=1 if positive else None)
        elif isinstance(default, float):
            options[key] = table.number(key, minimum=0.0, exclusive_minimum=True) if positive else table.number(key)
        else:  # a string, or a path given as a string (default None)
            options[key] = table.string(key)
    return options


def _check_fmu_plant(table: ConfigTable, simulation: SimulationConfig, rate_hz: float) -> SimulationConfig:
    """An FMU plant is checked on load (the file, its input and output, its binary for this platform), so that
    a bad one is named before any device starts; ``fmu_input`` / ``fmu_output`` belong to an FMU only."""
    from sim_backend.fmu_plant import is_fmu_path, open_fmu_block, time_fmu_steps

    if not is_fmu_path(simulation.plant_path):
        for key in ("fmu_input", "fmu_output", "fmu_parameters"):
            if getattr(simulation, key):
                what = "sets parameters" if key == "fmu_parameters" else "chooses a variable"
                raise table.error(key, f"{what} of an FMU plant, but the plant is {simulation.plant_path.name}")
        return simulation
    try:
        block = open_fmu_block(simulation.plant_path, 1.0 / rate_hz, simulation.fmu_input, simulation.fmu_output,
                               options=("fmu_input", "fmu_output"), parameters=simulation.fmu_parameters)
        seconds = time_fmu_steps(block)
    except ConfigError as err:
        raise table.error("fmu_parameters" if err.key.startswith("fmu_parameters") else "plant", str(err)) from err
    return dataclasses.replace(simulation, fmu_seconds_per_sample=seconds)


def load_rig_config(path: str | Path) -> RigConfig:
    """Read and validate a rig config; raises :class:`ConfigError` naming the file and key."""
    path = Path(path)
    root = load_toml(path)
    name = root.string("name", path.stem)
    description = root.string("description", "")
    rate = root.number("sample_rate_hz", minimum=0.0, exclusive_minimum=True, maximum=100_000.0)

    transport = root.table("transport")
    url = transport.string("url")
    try:
        scheme, _ = parse_transport_url(url)
    except ConfigError as err:
        raise transport.error("url", err.problem) from err
    options = _transport_options(transport, scheme)
    for key in ("drive_eds", "encoder_eds"):  # like the plant: relative to this file
        if key in options and not Path(options[key]).is_absolute():
            options[key] = str(path.parent / options[key])

    drive_table = root.table("drive", None)
    drive = DriveScaling(drive_table.integer("counts_per_revolution", 1 << 17, minimum=1, maximum=1 << 30))
    drive_table.finish()

    encoder = _encoder(root.table("encoder"))

    limits_table = root.table("limits")
    low = limits_table.number("position_min_rad")
    high = limits_table.number("position_max_rad")
    if high <= low:
        raise limits_table.error("position_max_rad", f"expected a number > position_min_rad ({low:g}), got {high:g}")
    rate_limit = limits_table.number("rate_max_rad_per_s", minimum=0.0, exclusive_minimum=True)
    limits_table.finish()

    watchdog = root.table("watchdog", None)
    period = 1.0 / rate
    feedback_timeout = watchdog.number("feedback_timeout_s", max(0.05, 20 * period), minimum=2 * period)
    late_tolerance = watchdog.number("late_tolerance_s", 0.5 * period, minimum=0.0, maximum=period)
    watchdog.finish()

    bring_up = root.table("bring_up", None)
    defaults = BringUpTiming()
    timing = BringUpTiming(**{
        name: bring_up.number(name, getattr(defaults, name), minimum=0.0, maximum=600.0)
        for name in ("enable_timeout_s", "fault_reset_timeout_s", "quick_stop_timeout_s", "poll_interval_s")})
    bring_up.finish()

    simulation = None
    if root.has("simulation"):
        sim = root.table("simulation")
        plant = sim.string("plant")
        plant_path = (path.parent / plant) if not Path(plant).is_absolute() else Path(plant)
        if not plant_path.is_file():
            raise sim.error("plant", f"no such plant config {plant_path}")
        simulation = SimulationConfig(plant_path, sim.integer("seed", None, minimum=0),
                                      sim.string("fmu_input", None), sim.string("fmu_output", None),
                                      dict(sim.table("fmu_parameters", None).data))
        simulation = _check_fmu_plant(sim, simulation, rate)
        sim.finish()
    if url == SIMULATED_SERIAL_URL and simulation is None:
        raise transport.error("url", f"{SIMULATED_SERIAL_URL} is the simulated device's pty: add a [simulation] table")
    root.finish()
    config = RigConfig(name=name, source=str(path), sample_rate_hz=rate, url=url, scheme=scheme, options=options,
                     drive=drive, encoder=encoder, limits=CommandLimits(low, high, rate_limit),
                     feedback_timeout_s=feedback_timeout, late_tolerance_s=late_tolerance, simulation=simulation,
                     description=description, raw=dict(root.data), timing=timing)
    try:  # the transport checks its options (bus load at this rate, EDS files, node-IDs) without I/O
        transport_class(scheme)(**parse_transport_url(url)[1], **config.transport_options())
    except ConfigError as err:
        raise transport.error(err.key, err.problem) from err
    return config
