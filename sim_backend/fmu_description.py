"""What an FMU file describes, and the user's choices checked against it.

:func:`describe_fmu` reads an FMU's model description (``modelDescription.xml``, the "FMI Description Schema"
chapter of the FMI 2.0 and 3.0 standards) without loading its binary: its FMI version, its interfaces
(co-simulation, model exchange), its real inputs and outputs (:class:`FmuVariable`), its parameters
(:class:`FmuParameter`) and the platforms it has binaries for, all in one :class:`FmuDescription` (what
``rig inspect model.fmu`` prints).

The user's choices are checked against that description before any binary is loaded: which real input takes
the commanded angle and which real output gives the load angle (:func:`choose_variable`), their units
(:func:`angle_scale`: rad, deg or rev), the parameter values (:func:`parse_parameter_assignments` for the
command line, :func:`check_fmu_parameters`) and a binary for this platform (:func:`check_platform`). A refusal
is a :class:`~rig.protocols.errors.ConfigError` naming the FMU file, the option or key, and what the FMU
accepts. :func:`sim_backend.fmu_plant.open_fmu_block` runs these checks and makes the block from what passes.
"""

from __future__ import annotations

import math
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rig.protocols.angle_units import angle_unit_factor, unit_kind
from rig.protocols.errors import ConfigError

__all__ = ["FMU_SUFFIX", "INTEGER_TYPES", "INTERFACES", "REAL_TYPES", "SETTABLE_VARIABILITIES", "FmuDescription",
           "FmuParameter", "FmuVariable", "angle_scale", "check_fmu_parameters", "check_platform", "choose_variable",
           "describe_fmu", "is_fmu_path", "parse_parameter_assignments"]

FMU_SUFFIX = ".fmu"

INTERFACES = ("co_simulation", "model_exchange")
"""The FMI interface types a block can run: the FMU's own solver, or ours (CVode) on its equations."""


def is_fmu_path(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` names an FMU (by its suffix ``.fmu``, as every FMI tool writes it)."""
    return Path(path).suffix.lower() == FMU_SUFFIX


@dataclass(frozen=True)
class FmuVariable:
    """A real-valued input or output of the FMU: name, value reference, unit and description."""

    name: str
    value_reference: int
    unit: str = ""
    description: str = ""

    def describe(self) -> str:
        unit = f" [{self.unit}]" if self.unit else ""
        return f"{self.name}{unit}"


SETTABLE_VARIABILITIES = ("fixed", "tunable")
"""A parameter (causality ``parameter``) of these variabilities may be set before the FMU is initialised (FMI
2.0 section 2.2.7, FMI 3.0 section 2.4.7.4): ``fixed`` ones there only, ``tunable`` ones there and later. Both
are set here once, before initialisation, so both are accepted; constants, calculated parameters and other
variables are not parameters one can set."""

REAL_TYPES = ("Real", "Float64", "Float32")
"""The FMI types of a real number (FMI 2.0 ``Real``, FMI 3.0 ``Float64`` and ``Float32``)."""

INTEGER_TYPES = ("Integer", "Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64")
"""The FMI types of an integer (FMI 2.0 ``Integer``, FMI 3.0 the sized ones)."""


@dataclass(frozen=True)
class FmuParameter:
    """A variable of the FMU with causality ``parameter`` (or ``calculatedParameter``, which cannot be set):
    what it is, what it accepts, and its start value."""

    name: str
    value_reference: int
    type: str
    variability: str
    causality: str = "parameter"
    start: str | None = None
    minimum: float | None = None
    maximum: float | None = None
    unit: str = ""
    description: str = ""

    @property
    def settable(self) -> bool:
        """Whether it can be set before initialisation (:data:`SETTABLE_VARIABILITIES`) and is a number or a
        boolean (the types set here)."""
        return self.causality == "parameter" and self.variability in SETTABLE_VARIABILITIES and (
            self.type in REAL_TYPES or self.type in INTEGER_TYPES or self.type == "Boolean")

    def accepts(self) -> str:
        """'a real number in [0.1, 2] (start 0.7, unit 1)': what a value must be."""
        kind = {"Boolean": "true or false"}.get(self.type, "an integer" if self.type in INTEGER_TYPES
                                               else "a real number")
        low = "-inf" if self.minimum is None else f"{self.minimum:g}"
        high = "inf" if self.maximum is None else f"{self.maximum:g}"
        bounds = f" in [{low}, {high}]" if self.minimum is not None or self.maximum is not None else ""
        extras = [f"start {self.start}" if self.start is not None else "", f"unit {self.unit}" if self.unit else ""]
        extra = ", ".join(item for item in extras if item)
        return f"{kind}{bounds}" + (f" ({extra})" if extra else "")

    def describe(self) -> str:
        """One line of ``rig inspect model.fmu``."""
        causality = "" if self.causality == "parameter" else f" {self.causality}"
        settable = "" if self.settable else "; cannot be set"
        text = f"{self.name}: {self.accepts()}, {self.variability}{causality}{settable}"
        return text + (f" - {self.description}" if self.description else "")


@dataclass(frozen=True)
class FmuDescription:
    """What ``modelDescription.xml`` says about an FMU, and which of its binaries this machine can load."""

    path: str
    fmi_version: str
    model_name: str
    interfaces: tuple[str, ...]
    inputs: tuple[FmuVariable, ...]
    outputs: tuple[FmuVariable, ...]
    other_inputs: tuple[str, ...]
    """Inputs that are not real numbers (integer, boolean, string): they keep their start values."""
    other_outputs: tuple[str, ...]
    platforms: tuple[str, ...]
    model_identifiers: dict[str, str] = field(default_factory=dict)
    parameters: tuple[FmuParameter, ...] = ()
    """Every variable with causality ``parameter`` or ``calculatedParameter`` (settable or not)."""
    variables: dict[str, tuple[str, str]] = field(default_factory=dict)
    """Every variable's (causality, variability), to say why a name given as a parameter is not one."""


def _platform() -> str:
    import fmpy

    return str(fmpy.platform)


def _fmpy(path: str) -> Any:
    try:
        import fmpy
    except ImportError as err:
        raise ConfigError(path, "fmpy", "reading an FMU needs the package fmpy: pip install 'gearbox-rig[fmu]'") \
            from err
    return fmpy


def describe_fmu(path: str | os.PathLike[str]) -> FmuDescription:
    """Read an FMU's model description without loading its binary.

    Raises :class:`~rig.protocols.errors.ConfigError` naming the file when it is missing, not an FMU (a zip
    archive holding ``modelDescription.xml``), of an FMI version other than 2.0 or 3.0, or without a
    co-simulation or model-exchange interface."""
    source = str(path)
    fmpy = _fmpy(source)
    if not Path(source).is_file():
        raise ConfigError(source, "file", "no such FMU file (give the path of the .fmu your tool exported)")
    try:
        from fmpy import read_model_description

        description = read_model_description(source, validate=False)
        platforms = tuple(fmpy.supported_platforms(source))
    except (zipfile.BadZipFile, KeyError, OSError) as err:
        raise ConfigError(source, "file", f"not an FMU (a zip archive holding modelDescription.xml): {err}") from err
    except Exception as err:  # fmpy raises bare Exceptions for malformed model descriptions
        raise ConfigError(source, "modelDescription.xml", f"cannot be read: {err}") from err
    version = str(description.fmiVersion)
    if not (version == "2.0" or version.startswith("3.")):
        raise ConfigError(source, "fmiVersion", f"FMI {version} is not supported; export the model as FMI 2.0 or 3.0")
    interfaces, identifiers = [], {}
    if description.coSimulation is not None:
        interfaces.append("co_simulation")
        identifiers["co_simulation"] = description.coSimulation.modelIdentifier
    if description.modelExchange is not None:
        interfaces.append("model_exchange")
        identifiers["model_exchange"] = description.modelExchange.modelIdentifier
    if not interfaces:
        raise ConfigError(source, "modelDescription.xml", "the FMU has neither a co-simulation nor a "
                                                          "model-exchange interface (scheduled execution is not supported)")
    inputs, outputs, other_inputs, other_outputs = [], [], [], []
    parameters, variables = [], {}
    for variable in description.modelVariables:
        variables[variable.name] = (str(variable.causality), str(variable.variability))
        if variable.causality in ("parameter", "calculatedParameter") and not getattr(variable, "dimensions", None):
            parameters.append(FmuParameter(
                variable.name, int(variable.valueReference), str(variable.type), str(variable.variability),
                str(variable.causality), None if variable.start is None else str(variable.start), _bound(variable, "min"),
                _bound(variable, "max"), _unit(variable), str(variable.description or "")))
        if variable.causality not in ("input", "output"):
            continue
        if variable.type in REAL_TYPES and not getattr(variable, "dimensions", None):
            item = FmuVariable(variable.name, int(variable.valueReference), _unit(variable),
                               str(variable.description or ""))
            (inputs if variable.causality == "input" else outputs).append(item)
        else:
            (other_inputs if variable.causality == "input" else other_outputs).append(variable.name)
    return FmuDescription(path=source, fmi_version=version, model_name=str(description.modelName),
                          interfaces=tuple(interfaces), inputs=tuple(inputs), outputs=tuple(outputs),
                          other_inputs=tuple(other_inputs), other_outputs=tuple(other_outputs),
                          platforms=platforms, model_identifiers=identifiers, parameters=tuple(parameters),
                          variables=variables)


def _unit(variable: Any) -> str:
    """A variable's unit: its own, or its declared type's."""
    unit = variable.unit or (getattr(variable.declaredType, "unit", None) if variable.declaredType else None)
    return str(unit or "")


def _bound(variable: Any, which: str) -> float | None:
    """A variable's ``min`` or ``max`` (its own, or its declared type's) as a number, or None."""
    value = getattr(variable, which, None)
    if value is None and variable.declaredType is not None:
        value = getattr(variable.declaredType, which, None)
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        return None


def parse_parameter_assignments(texts: list[str] | tuple[str, ...], option: str = "--fmu-parameter") -> dict[str, Any]:
    """``["damping_ratio=0.5", "enabled=true"]`` -> ``{"damping_ratio": 0.5, "enabled": True}`` (numbers as
    TOML writes them, ``true``/``false``); a malformed one raises :class:`ConfigError` naming it."""
    values: dict[str, Any] = {}
    for text in texts:
        name, sep, value = text.partition("=")
        name, value = name.strip(), value.strip()
        if not sep or not name or not value:
            raise ConfigError(option, text, "expected NAME=VALUE, e.g. --fmu-parameter damping_ratio=0.5")
        if value.lower() in ("true", "false"):
            values[name] = value.lower() == "true"
            continue
        try:
            values[name] = int(value)
        except ValueError:
            try:
                values[name] = float(value)
            except ValueError:
                raise ConfigError(option, text, f"{value!r} is not a number, true or false") from None
    return values


def check_fmu_parameters(description: FmuDescription, values: Any, key: str = "fmu_parameters") -> tuple[
        tuple[str, int, str, Any], ...]:
    """Check parameter values against the FMU's model description and return them as the block carries them,
    ``(name, value reference, type, value)``. An unknown name, a variable that is no parameter one can set, a
    value of the wrong type or outside the parameter's [min, max] raises :class:`ConfigError` naming the FMU
    file, ``key``, the parameter and what it accepts."""
    source = description.path
    if not hasattr(values, "items"):
        raise ConfigError(source, key, f"expected a table of parameter = value, got {values!r}")
    by_name = {parameter.name: parameter for parameter in description.parameters}
    settable = [parameter for parameter in description.parameters if parameter.settable]
    listed = ", ".join(p.name for p in settable[:30]) + (" ..." if len(settable) > 30 else "") if settable else "none"
    out = []
    for name, value in values.items():
        where = f"{key}.{name}"
        parameter = by_name.get(name)
        if parameter is None:
            if name in description.variables:
                causality, variability = description.variables[name]
                raise ConfigError(source, where, f"is not a parameter of the FMU (causality {causality}, variability "
                                                 f"{variability}); the parameters it lets be set: {listed}")
            raise ConfigError(source, where, f"the FMU has no variable {name!r}; the parameters it lets be set: {listed} "
                                             f"(rig inspect {Path(source).name} lists them)")
        if not parameter.settable:
            raise ConfigError(source, where, f"cannot be set (causality {parameter.causality}, variability "
                                             f"{parameter.variability}, type {parameter.type}; only parameters of "
                                             "variability fixed or tunable that are numbers or booleans can); the "
                                             f"parameters it lets be set: {listed}")
        if parameter.type == "Boolean":
            if not isinstance(value, bool):
                raise ConfigError(source, where, f"expected true or false, got {value!r}")
            out.append((name, parameter.value_reference, parameter.type, bool(value)))
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(source, where, f"expected {parameter.accepts()}, got {value!r}")
        if parameter.type in INTEGER_TYPES and value != int(value):
            raise ConfigError(source, where, f"expected {parameter.accepts()}, got {value!r}")
        if (parameter.minimum is not None and value < parameter.minimum) or (
                parameter.maximum is not None and value > parameter.maximum):
            raise ConfigError(source, where, f"{value!r} is outside the range the FMU accepts: {parameter.accepts()}")
        number = int(value) if parameter.type in INTEGER_TYPES else float(value)
        out.append((name, parameter.value_reference, parameter.type, number))
    return tuple(out)


def angle_scale(description: FmuDescription, variable: FmuVariable, kind: str, option: str) -> float:
    """The factor from the FMU's unit of ``variable`` to radians (rad or none: 1; deg, rev: converted); an
    input or output in another unit is refused, naming it."""
    found = unit_kind(variable.unit)
    if found in ("", "rad"):
        return 1.0
    if found in ("deg", "rev"):
        return angle_unit_factor(found)
    raise ConfigError(description.path, option, f"the FMU's {kind} {variable.name!r} is in {variable.unit!r}, which "
                                                f"is no angle unit converted here (rad, deg, rev): the rig's "
                                                f"{'command' if kind == 'input' else 'load angle'} is an angle; export "
                                                f"the model with this {kind} in rad or deg")


def choose_variable(description: FmuDescription, kind: str, wanted: str | None, option: str) -> FmuVariable:
    """The FMU's real ``kind`` ("input" or "output") named ``wanted``, or its only one."""
    variables = description.inputs if kind == "input" else description.outputs
    listed = ", ".join(v.describe() for v in variables) or "none"
    if wanted is not None:
        for variable in variables:
            if variable.name == wanted:
                return variable
        raise ConfigError(description.path, option, f"the FMU has no real {kind} {wanted!r}; its real {kind}s: {listed}")
    if len(variables) == 1:
        return variables[0]
    if not variables:
        others = description.other_inputs if kind == "input" else description.other_outputs
        extra = f" (its non-real {kind}s {', '.join(others)} cannot carry an angle)" if others else ""
        raise ConfigError(description.path, option, f"the FMU has no real {kind}{extra}: the model must take the "
                                                    "commanded angle (rad) as an input and give the load angle as an output")
    how = f"{option} NAME" if option.startswith("--") else f'{option} = "NAME" in [simulation]'
    raise ConfigError(description.path, option, f"the FMU has {len(variables)} real {kind}s ({listed}): say which "
                                                f"one is the {'commanded angle' if kind == 'input' else 'load angle'} "
                                                f"with {how}")


def check_platform(description: FmuDescription, interface: str) -> None:
    """Raise :class:`ConfigError` unless the FMU holds the binary of ``interface`` for this platform (under its
    FMI 2.0 name, e.g. ``binaries/linux64/``, or its FMI 3.0 platform tuple, e.g. ``binaries/x86_64-linux/``),
    saying which platforms it has binaries for."""
    import fmpy

    current = _platform()
    identifier = description.model_identifiers[interface]
    binary_names = (f"binaries/{current}/{identifier}", f"binaries/{fmpy.platform_tuple}/{identifier}")
    with zipfile.ZipFile(description.path) as archive:
        names = archive.namelist()
    if any(name.startswith(binary_names) for name in names):
        return
    present = ", ".join(p for p in description.platforms if p != "c-code") or "none"
    sources = " It holds C sources: compile them for this platform (fmpy.build.build_platform_binary)." \
        if "c-code" in description.platforms else ""
    raise ConfigError(description.path, "binaries",
                      f"the FMU has no binary for this platform ({current}: binaries/{current}/{identifier}"
                      f"{fmpy.sharedLibraryExtension} or binaries/{fmpy.platform_tuple}/); it has binaries for: "
                      f"{present}.{sources} Export it from your tool for this platform.")

