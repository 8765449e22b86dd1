"""``rig inspect LOG``: a log's metadata, sample count and lost-sample count, or what is wrong with it."""

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
            "files are accepted too."
        ),
    )
    parser.add_argument("log", metavar="LOG", help="a rig-log v1 file, a CSV with columns t,u,y, or .mf4/.mdf/.mat")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.set_defaults(handler=run)


def summary(path: str) -> dict[str, Any]:
    """The JSON summary of a log: samples, lost, sample_period_s, per-flag counts and the metadata."""
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


def run(args: argparse.Namespace) -> int:
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
