"""``rig identify METHOD ...``: the identification methods, one module each."""

from __future__ import annotations

import argparse
import importlib

METHOD_MODULES: tuple[str, ...] = ("rig.commands.identify_hammerstein", "rig.commands.identify_output_backlash")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "identify",
        help="identify a model from captured data",
        description="Identify a model from captured data (experiment logs or plain CSV files).",
    )
    methods = parser.add_subparsers(title="methods", metavar="METHOD", required=True)
    for module_name in METHOD_MODULES:
        importlib.import_module(module_name).register(methods)
