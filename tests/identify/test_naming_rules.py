"""The naming rules of docs/design.md ("One signal vocabulary"), checked on the public functions of identify.

A signal parameter is never a bare paper letter or an unnamed quantity (``u``, ``y``, ``z``, ``command``, ...):
it says what it is and its unit (``input_rad``, ``output_rad``, ``command_rad``). A number parameter (a public
function's, a method's or a result type's constructor's) ends with its unit (rule 3), unless it is dimensionless or
a paper symbol the glossary maps (rule 4). The exceptions below are the whole list, each with its reason; a new
public function that breaks a rule fails here."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import re

import identify

BARE_SIGNAL_NAMES = {"u", "y", "z", "w", "u_t", "command", "output", "input", "angle", "signal"}

EXCEPTIONS = {
    # the block interface (plant_blocks.Block, drive_train.DriveTrain): a block's signal may be an angle, a
    # torque or a lifted input, so apply() and step() keep generic names
    "apply": "block interface", "step": "block interface",
    # generic signal processing, in the unit of whatever signal it is given
    "lowpass_filter": "any unit",
}


UNIT_SUFFIX = re.compile(r"_(rad|s|hz|nm|samples|db|kg|m|kg_m2|per_s|rad_per_s|rad_per_s2|rad_per_sample|m_per_s2"
                         r"|nm_per_rad|nm_s_per_rad|nm_per_unit|percent)$")
"""Rule 3's units (and the SI compounds the drive train uses; N m per unit of a signal recorded in its own unit)."""

DIMENSIONLESS = {
    # ratios, fractions, gains and slopes (rad per rad): a dimensionless quantity carries no suffix (rule 3)
    "m_l", "m_r", "slope", "gain", "gain_change", "gear_ratio", "velocity_feedforward", "damping_ratio",
    "position_loop_damping_ratio", "filter_pole", "reference_pole", "pole_tolerance", "complexity_penalty",
    "min_reduction", "reduction", "consistent_fraction", "estimation_fraction", "falsified_fraction",
    "falsified_fraction_before", "falsified_fraction_after", "falsified_fraction_initial",
    "falsified_fraction_final", "required_noise_scale", "score", "explained_fraction",
    # the LP of linear_block_bounds works on θ = [a, b], dimensionless coefficients
    "max_certificate_gap", "tightening_tolerance",
    # the wear law of backlash_wear: rad of half-width per rad of output travel
    "per_rad_travel",
}

PAPER_SYMBOLS = {"D": "the feedthrough of (A, B, C, D)", "mu0": "μ0 of Pouliquen et al. (2013), glossary P13"}

ANY_UNIT = {
    # a number in the unit of whatever the caller gives: an interval of any parameter, a tolerance on any
    # signal, a coordinate of any polygon, the median half-width of intervals of any parameters
    "value", "lower", "upper", "threshold", "offset", "x", "u_t", "median_half_width",
}


def _public_objects():
    """(module name, name, object) of every name in an identify module's ``__all__`` defined there (for a
    package such as ``model_discrepancy``: defined in one of its modules)."""
    for info in pkgutil.iter_modules(identify.__path__):
        module = importlib.import_module(f"identify.{info.name}")
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            defined_in = getattr(obj, "__module__", None) or ""
            if defined_in == module.__name__ or (info.ispkg and defined_in.startswith(f"{module.__name__}.")):
                yield info.name, name, obj


def _public_callables():
    for module_name, name, obj in _public_objects():
        if inspect.isfunction(obj):
            yield f"{module_name}.{name}", name, obj
        elif inspect.isclass(obj):
            for attribute, value in vars(obj).items():
                function = getattr(value, "__func__", value)
                if inspect.isfunction(function) and not attribute.startswith("_"):
                    yield f"{module_name}.{name}.{attribute}", attribute, function


def _constructors():
    """The public result and block types built from fields: their constructor's parameters are public names."""
    for module_name, name, obj in _public_objects():
        if inspect.isclass(obj) and dataclasses.is_dataclass(obj):
            yield f"{module_name}.{name}", obj


def _number_parameters():
    """(label, parameter name) of every parameter annotated as one float (``float`` or ``float | None``)."""
    signatures = [(label, inspect.signature(inspect.unwrap(function))) for label, _, function in _public_callables()]
    signatures += [(label, inspect.signature(cls)) for label, cls in _constructors()]
    for label, signature in signatures:
        for parameter in signature.parameters.values():
            annotation = str(parameter.annotation).replace("'", "")
            if annotation in ("float", "float | None", "None | float"):
                yield label, parameter.name


def test_no_public_function_of_identify_takes_a_bare_signal_name():
    offenders = []
    for label, name, function in _public_callables():
        if name in EXCEPTIONS:
            continue
        parameters = set(inspect.signature(inspect.unwrap(function)).parameters)
        offenders += [f"{label}({bad})" for bad in sorted(parameters & BARE_SIGNAL_NAMES)]
    assert offenders == []


def test_the_rule_sees_the_functions_it_is_about():
    labels = {label for label, _, _ in _public_callables()}
    assert {"hammerstein_subspace.identify_hammerstein", "border_lifting.lifted_input",
            "plant_blocks.PlantModel.simulate", "model_discrepancy.diagnose_model"} <= labels


def _without_unit(parameters):
    allowed = DIMENSIONLESS | set(PAPER_SYMBOLS) | ANY_UNIT
    return [f"{label}({name})" for label, name in parameters if not UNIT_SUFFIX.search(name) and name not in allowed]


def test_every_number_parameter_of_identify_names_its_unit():
    assert _without_unit(_number_parameters()) == []


def test_the_unit_rule_sees_constructors_and_methods_and_catches_the_old_names():
    seen = set(_number_parameters())
    assert {("backlash_blocks.OutputBacklash", "c_l_rad"), ("backlash_blocks.InputSwitch", "initial_input_rad"),
            ("backlash_blocks.InputBacklash", "initial_output_rad"),
            ("feasible_parameter_set.BacklashFeasibleSet.contains", "c_r_rad"),
            ("hammerstein_model.HammersteinModel", "residual_rms_rad")} <= seen
    # the names replaced when units joined the names fail the rule
    old = [("OutputBacklash", "c_l"), ("OutputBacklash", "initial_output"), ("InputSwitch", "initial_input"),
           ("ArctanBorder", "input_shift"), ("HammersteinModel", "residual_rms")]
    assert len(_without_unit(old)) == len(old)
