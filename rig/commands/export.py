"""``rig export LOG --format mdf|mat|csv --out FILE``: a log as ASAM MDF4, MATLAB or rig-log CSV
(:mod:`rig.measurement_files`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rig import exit_codes

FORMATS = {"mdf": (".mf4", ".mdf"), "mat": (".mat",), "csv": (".csv", ".log", ".txt")}

DESCRIPTION = """\
Write a log in the format of the user's toolchain, with its metadata (units, sample period, encoder bits,
config, seed, software version, the run's summary):

  mdf  ASAM MDF 4.10 (.mf4/.mdf; CANape, INCA, asammdf): channels time_s, command_rad, angle_rad,
       encoder_counts, flags with units and comments; the metadata in the header comment (property
       rig_metadata holds it as JSON) and a file-history entry. Needs asammdf: pip install 'gearbox-rig[mdf]'
  mat  MATLAB v7 (.mat; load('run.mat')): column vectors of the same names and a struct 'metadata'
  csv  the rig-log v1 CSV (pandas, numpy, MATLAB readtable)

LOG is anything the analysis commands read: a rig log, a CSV with columns t,u,y, or an .mf4/.mdf/.mat
file. Every command that reads data reads the .mf4/.mdf and .mat files written here (and MDF/MAT files of other
tools with channels t,u,y: the t of an MDF file is its master time)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "export",
        help="write a log as ASAM MDF4 (.mf4), MATLAB (.mat) or rig-log CSV",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("log", metavar="LOG", help="a rig log, a CSV with columns t,u,y, or .mf4/.mdf/.mat")
    parser.add_argument("--format", choices=sorted(FORMATS), default=None,
                        help="output format (default: from the suffix of --out: .mf4/.mdf, .mat, .csv)")
    parser.add_argument("--out", metavar="FILE", required=True,
                        help="file to write (.mf4 or .mdf for mdf, .mat for mat); an existing file is refused "
                             "unless --force. It is written under a temporary name and moved into place when complete")
    parser.add_argument("--force", action="store_true", help="replace an existing --out file")
    parser.add_argument("--json", action="store_true", help='print {"log", "out", "format", "samples", "acquisition_start_utc"} as JSON')
    parser.set_defaults(handler=run)


def output_format(out: str, given: str | None) -> str:
    """The format of ``--out``: ``given``, which must fit the suffix (the readers choose by suffix), or the
    one the suffix names."""
    suffix = Path(out).suffix.lower()
    if given is None:
        for name, suffixes in FORMATS.items():
            if suffix in suffixes:
                return name
        raise ValueError(f"--out {out}: cannot tell the format from the suffix {suffix or '(none)'!r}; give "
                         "--format mdf|mat|csv or name the file .mf4, .mat or .csv")
    if given in ("mdf", "mat") and suffix not in FORMATS[given]:
        raise ValueError(f"--out {out}: a {given} file must be named {' or '.join(FORMATS[given])} (the readers "
                         f"of every rig command choose the format by the suffix)")
    if given == "csv" and suffix in FORMATS["mdf"] + FORMATS["mat"]:
        raise ValueError(f"--out {out}: a CSV file named {suffix} would be read as {suffix[1:]}; name it .csv")
    return given


def run(args: argparse.Namespace) -> int:
    from rig.log_file import read_experiment_data, write_log
    from rig.measurement_files import require_asammdf, write_mat, write_mdf
    from rig.output_paths import atomic_output, check_output_file, is_regular_target

    kind = output_format(args.out, args.format)
    if kind == "mdf":
        require_asammdf(Path(args.out))  # before the work: a missing package is named at once
    out = check_output_file(args.out, "--out", inputs=[args.log], force=args.force)
    record = read_experiment_data(args.log)
    with atomic_output(out, "--out", force=args.force, suffix=".mf4" if kind == "mdf" else None) as written:
        if kind == "mdf":
            write_mdf(written, record)
        elif kind == "mat":
            write_mat(written, record)
        else:
            write_log(written, record)
    # the data may be going to stdout (--out /dev/stdout): then what is said goes to stderr
    status = sys.stdout if is_regular_target(out) else sys.stderr
    start = record.metadata.acquisition_start_utc
    if start is None and kind == "mdf":
        print(f"rig: note: {args.log} records no acquisition start (a log written before rig recorded it, or data "
              f"of another tool): the start time of {out} is the time of this export", file=sys.stderr)
    if args.json:
        print(json.dumps({"log": args.log, "out": str(out), "format": kind, "samples": len(record),
                          "acquisition_start_utc": start}), file=status)
    else:
        print(f"{args.log} -> {out} ({kind}, {len(record)} samples)", file=status)
    return exit_codes.SUCCESS
