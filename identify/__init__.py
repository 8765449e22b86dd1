"""Pure numerics that turn rig logs into identification results.

Arrays and dataclasses in, frozen dataclasses out: no I/O, no plotting and no hardware libraries are
imported here (``tests/identify/test_import_purity.py`` checks it). Signals follow one convention
everywhere: 1-D float arrays of equal length, ordered ``(time_s, inputs, outputs)``, angles in radians,
named ``input_rad``/``output_rad`` by the methods and ``command_rad``/``angle_rad`` where they are a
record's columns, units in every public parameter name (the rules: ``docs/design.md``, "One signal
vocabulary"; ``tests/identify/test_naming_rules.py`` checks them).

The public functions and types are available at the top level (``from identify import identify_hammerstein,
diagnose_model, ExperimentRecord``), loaded on first use: ``import identify`` itself imports none of the method
modules (a diagnosis need not load the LP solver, nor a Hammerstein identification the effect catalogue).
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version
from typing import TYPE_CHECKING, Any

try:
    __version__ = version("gearbox-rig")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

_EXPORTS: dict[str, tuple[str, ...]] = {
    "experiment_record": ("ExperimentMetadata", "ExperimentRecord", "SampleFlag"),
    "excitation_design": ("FilterPoleDesign", "design_filter_pole", "filtered_staircase", "prbs_sequence",
                          "staircase_steady_state_indices"),
    "cyclic_excitation": ("cyclic_random_excitation",),
    "border_lifting": ("PathNodes",),
    "hammerstein_subspace": ("HammersteinModel", "HammersteinOptions", "identify_hammerstein"),
    "output_backlash_identification": ("OutputBacklashIdentification", "bound_output_backlash_system"),
    "feasible_parameter_set": ("BacklashFeasibleSet", "ParameterInterval", "bound_backlash_parameters"),
    "inner_signal_bounds": ("InnerSignalBounds", "bound_inner_signal"),
    "linear_block_bounds": ("LinearBlockBounds", "LinearModelOrders", "bound_linear_block"),
    "model_discrepancy": ("DiagnoseOptions", "DiscrepancyReport", "DiscrepancyResult", "MissingEffect",
                          "diagnose_model"),
    "plant_blocks": ("CoulombFriction", "DeadZone", "Delay", "InputBacklash", "InputSwitch", "LinearBlock",
                     "OutputBacklash", "OutputGain", "OutputGainDrift", "OutputOffset", "PlantModel", "Resonance",
                     "Saturation"),
    "drive_train": ("DriveTrain",),
    "effect_catalogue": ("EFFECT_NAMES",),
    "result_format": ("ResultFormatError",),
    "validation": ("InvalidInputError",),
}
"""Module (under ``identify``) -> the public names it gives the top level. ``model_discrepancy`` is named by
its import path only, so that it may be a module or a package with the same public names."""

_MODULE_OF = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = ["__version__", *sorted(_MODULE_OF)]


def __getattr__(name: str) -> Any:
    """Load a public name from its module on first use (PEP 562) and keep it here."""
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module 'identify' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"identify.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_MODULE_OF})


if TYPE_CHECKING:  # for type checkers and editors: the same names, imported eagerly only when checking types
    from identify.border_lifting import PathNodes
    from identify.cyclic_excitation import cyclic_random_excitation
    from identify.drive_train import DriveTrain
    from identify.effect_catalogue import EFFECT_NAMES
    from identify.excitation_design import (
        FilterPoleDesign,
        design_filter_pole,
        filtered_staircase,
        prbs_sequence,
        staircase_steady_state_indices,
    )
    from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag
    from identify.feasible_parameter_set import BacklashFeasibleSet, ParameterInterval, bound_backlash_parameters
    from identify.hammerstein_subspace import HammersteinModel, HammersteinOptions, identify_hammerstein
    from identify.inner_signal_bounds import InnerSignalBounds, bound_inner_signal
    from identify.linear_block_bounds import LinearBlockBounds, LinearModelOrders, bound_linear_block
    from identify.model_discrepancy import (
        DiagnoseOptions,
        DiscrepancyReport,
        DiscrepancyResult,
        MissingEffect,
        diagnose_model,
    )
    from identify.output_backlash_identification import OutputBacklashIdentification, bound_output_backlash_system
    from identify.plant_blocks import (
        CoulombFriction,
        DeadZone,
        Delay,
        InputBacklash,
        InputSwitch,
        LinearBlock,
        OutputBacklash,
        OutputGain,
        OutputGainDrift,
        OutputOffset,
        PlantModel,
        Resonance,
        Saturation,
    )
    from identify.result_format import ResultFormatError
    from identify.validation import InvalidInputError
