"""The naming rules of docs/design.md ("One signal vocabulary"), checked on the public functions of identify.

A signal parameter is never a bare paper letter or an unnamed quantity (``u``, ``y``, ``z``, ``command``, ...):
it says what it is and its unit (``input_rad``, ``output_rad``, ``command_rad``). The exceptions below are the
whole list, each with its reason; a new public function that breaks the rule fails here."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import identify

BARE_SIGNAL_NAMES = {"u", "y", "z", "w", "u_t", "command", "output", "input", "angle", "signal"}

EXCEPTIONS = {
    # the block interface (plant_blocks.Block, drive_train.DriveTrain): a block's signal may be an angle, a
    # torque or a lifted input, so apply() and step() keep generic names
    "apply": "block interface", "step": "block interface",
    # generic signal processing, in the unit of whatever signal it is given
    "lowpass_filter": "any unit",
}


def _public_callables():
    for info in pkgutil.iter_modules(identify.__path__):
        module = importlib.import_module(f"identify.{info.name}")
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if getattr(obj, "__module__", None) != module.__name__:
                continue
            if inspect.isfunction(obj):
                yield f"{info.name}.{name}", name, obj
            elif inspect.isclass(obj):
                for attribute, value in vars(obj).items():
                    function = getattr(value, "__func__", value)
                    if inspect.isfunction(function) and not attribute.startswith("_"):
                        yield f"{info.name}.{name}.{attribute}", attribute, function


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
