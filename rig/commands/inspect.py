"""``rig inspect LOG``: a log's metadata, sample count and lost-sample count, or what is wrong with it;
``rig inspect MODEL.fmu``: an FMU's interfaces, inputs, outputs and parameters (what ``fmu_parameters`` and
``--fmu-parameter`` accept)."""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from typing import Any

from rig import exit_codes


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "inspect",
        help="show a log's metadata, sample count and lost samples",
        description=(
            "Show a log's metadata, its sample count and its lost-sample count, or say exactly what is wrong "
            "with a damaged or foreign file. Plain CSV files with columns t,u,y and ASAM MDF4 (.mf4/.mdf) or MATLAB (.mat) "
            "files are accepted too. Given an FMU (.fmu), list its interfaces, real inputs and outputs and its "
            "parameters with type, range, start value and whether they can be set."
        ),
    )
    parser.add_argument("log", metavar="LOG",
                        help="a rig log, a CSV with columns t,u,y, .mf4/.mdf/.mat, or an FMU (.fmu)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.set_defaults(handler=run)


def summary(path: str) -> dict[str, Any]:
    """The JSON summary of a log: samples, lost, sample_period_s, per-flag counts and the metadata."""
    import numpy as np

    from identify.experiment_record import SampleFlag
    from rig.log_file import read_experiment_data

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        record = read_experiment_data(path)
    metadata = record.metadata.to_dict()
    duration = float(record.time_s[-1] - record.time_s[0])
    out: dict[str, Any] = {
        "log": str(path),
        "samples": len(record),
        "lost": record.lost_count,
        "sample_period_s": record.sample_period_s,
        "duration_s": duration,
        "has_encoder_counts": record.encoder_counts is not None,
        # the samples with the drive's torque (rig-log v2), in its unit: None for a log without the column
        "drive_torque_samples": None if record.drive_torque is None else int(np.isfinite(record.drive_torque).sum()),
        "flags": {flag.name.lower(): record.count_flag(flag) for flag in SampleFlag if flag.value},
        "warnings": [str(warning.message) for warning in caught],
    }
    out.update({key: value for key, value in metadata.items() if key not in out})
    return out


def _text(value: Any) -> str:
    if isinstance(value, float) and math.isfinite(value):
        return f"{value:g}"
    if isinstance(value, (dict, list)):
        return json.dumps(value) if value else "-"
    return "-" if value is None or value == "" else str(value)


def fmu_summary(path: str) -> dict[str, Any]:
    """The JSON summary of an FMU: version, interfaces, real inputs and outputs (with units) and every
    parameter (type, variability, start, min, max, unit, settable)."""
    from sim_backend.fmu_plant import describe_fmu

    description = describe_fmu(path)
    return {"fmu": str(path), "fmi_version": description.fmi_version, "model_name": description.model_name,
            "interfaces": list(description.interfaces), "platforms": list(description.platforms),
            "inputs": [{"name": v.name, "unit": v.unit} for v in description.inputs],
            "outputs": [{"name": v.name, "unit": v.unit} for v in description.outputs],
            "parameters": [{"name": p.name, "type": p.type, "variability": p.variability, "start": p.start,
                            "min": p.minimum, "max": p.maximum, "unit": p.unit, "settable": p.settable,
                            "description": p.description} for p in description.parameters]}


def _print_fmu(info: dict[str, Any], path: str) -> None:
    from sim_backend.fmu_plant import describe_fmu

    description = describe_fmu(path)
    print(f"fmu          {info['fmu']}")
    print(f"model        {info['model_name']} (FMI {info['fmi_version']}; {', '.join(info['interfaces'])})")
    print(f"platforms    {', '.join(info['platforms']) or '-'}")
    print(f"inputs       {', '.join(v.describe() for v in description.inputs) or '-'}")
    print(f"outputs      {', '.join(v.describe() for v in description.outputs) or '-'}")
    if not description.parameters:
        print("parameters   none")
    for number, parameter in enumerate(description.parameters):
        print(f"{'parameters' if number == 0 else '':<12} {parameter.describe()}")


def run(args: argparse.Namespace) -> int:
    from sim_backend.fmu_plant import is_fmu_path

    if is_fmu_path(args.log):
        info = fmu_summary(args.log)
        if args.json:
            print(json.dumps(info))
        else:
            _print_fmu(info, args.log)
        return exit_codes.SUCCESS
    info = summary(args.log)
    for message in info["warnings"]:
        print(f"rig: warning: {message}", file=sys.stderr)
    if args.json:
        print(json.dumps(info))
        return exit_codes.SUCCESS
    width = max(len(key) for key in info)
    for key, value in info.items():
        if key == "acquisition_start_utc" and value is None:
            value = "unknown (not recorded: a log written before rig recorded it, or data of another tool)"
        print(f"{key:<{width}}  {_text(value)}")
    return exit_codes.SUCCESS
