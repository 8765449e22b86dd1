"""``rig identify hammerstein DATA``: subspace identification of a Hammerstein model with input backlash or
switch (Pouliquen et al. 2013; :mod:`identify.hammerstein_subspace`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rig import exit_codes

DESCRIPTION = """\
Identify a state-space model of the linear part and the ascending/descending borders of an input backlash
or switch from one experiment with the cyclic excitation of Table I (Pouliquen et al. 2013).

DATA is a CSV file with columns u and y (one row per sample; other columns are ignored) or a rig log
file (command_rad is u, angle_rad is y), in CSV or as the .mf4/.mdf/.mat of `rig export`; an MDF4 or MAT file
of another tool with channels u and y is read too. The data start with a hold at u_min, whose mean output gives
mu0 = H[u_min], unless --mu0 is given; without --hold-samples the hold is the leading run of samples at
the first value. The borders are continuous piecewise-linear functions with nodes from --nodes or
--num-nodes equally spaced nodes on [--u-min, --u-max] (default: the range of u)."""


def _node_list(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(item) for item in text.split(",") if item.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if len(values) < 2:
        raise argparse.ArgumentTypeError(f"expected at least two nodes (u_min and u_max), got {text!r}")
    return values


def _order(text: str) -> int | str:
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer or 'auto', got {text!r}") from None


def register(methods: argparse._SubParsersAction) -> None:
    parser = methods.add_parser(
        "hammerstein",
        help="subspace identification with input backlash or switch (Pouliquen et al. 2013)",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("data", metavar="DATA.csv", nargs="+",
                        help="CSV with columns u, y, a rig log, or .mf4/.mdf/.mat with channels u, y; several files are identified independently")
    nodes = parser.add_mutually_exclusive_group()
    nodes.add_argument("--num-nodes", type=int, default=8, metavar="K",
                       help="equally spaced nodes on [u_min, u_max], both ends included (default 8: n_p = 7)")
    nodes.add_argument("--nodes", type=_node_list, metavar="V0,V1,...",
                       help="node positions of both paths, strictly increasing, first u_min, last u_max; write --nodes=-3,-1,0,3 when the first is negative")
    parser.add_argument("--descending-nodes", type=_node_list, metavar="V0,V1,...",
                        help="other nodes for the descending path (Remark 3; same ends as --nodes)")
    parser.add_argument("--u-min", type=float, default=None, help="start of the interval (default: min of u)")
    parser.add_argument("--u-max", type=float, default=None, help="end of the interval (default: max of u)")
    parser.add_argument("--order", type=_order, default="auto", metavar="N|auto",
                        help="state dimension, or auto: the largest singular-value gap (default auto)")
    mu0 = parser.add_mutually_exclusive_group()
    mu0.add_argument("--hold-samples", type=int, default=None, metavar="K",
                     help="length of the leading hold at u_min (default: the leading run at the first value)")
    mu0.add_argument("--mu0", type=float, default=None, metavar="VALUE", help="H[u_min], when known (no hold needed)")
    parser.add_argument("--past-horizon", type=int, default=None, metavar="P", help="past block rows p (default 15)")
    parser.add_argument("--future-horizon", type=int, default=None, metavar="F", help="future block rows f (default 15)")
    parser.add_argument("--split", choices=("separate", "rank1"), default="separate",
                        help="B and mu: separately with A, C fixed (Remark 5, default) or by the rank-1 SVD of eq. (14)")
    parser.add_argument("--no-feedthrough", action="store_true", help="fix D = 0 (strictly proper G)")
    parser.add_argument("--refine", action="store_true",
                        help="refine the subspace estimate by minimising the output error of the whole model")
    parser.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="identify several files in N processes (0: one per core; default 1)")
    parser.add_argument("--scheduler", metavar="ADDRESS", default=None,
                        help="run the files on the Dask cluster at ADDRESS instead (needs dask[distributed])")
    from rig.record_import import add_import_arguments

    add_import_arguments(parser)
    parser.add_argument("--json", action="store_true",
                        help='print the model as JSON (kind hammerstein_model); with several files '
                             '{"kind": "batch", "version": 1, "results": [{"file", "model" | "error"}]}')
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from functools import partial

    from rig.batch import batch_document, map_files

    options = {key: getattr(args, key) for key in (
        "nodes", "descending_nodes", "num_nodes", "u_min", "u_max", "order", "hold_samples", "mu0",
        "past_horizon", "future_horizon", "split", "no_feedthrough", "refine")}
    from rig.record_import import options_from_arguments

    options["import"] = options_from_arguments(args)
    if len(args.data) == 1 and args.scheduler is None:
        result = identify_file(args.data[0], options)  # errors go to rig.cli with their exit code
        if args.json:
            print(json.dumps(_model_document(result)))
        else:
            _print_table(result[0], Path(args.data[0]), result[1], result[2])
        sys.stdout.flush()
        return exit_codes.SUCCESS
    outcomes = map_files(partial(identify_file, options=options), args.data, jobs=args.jobs,
                         scheduler=args.scheduler)
    if args.json:
        print(json.dumps(batch_document([outcome.to_json("model", _model_document)
                                         for outcome in outcomes])))
    else:
        for outcome in outcomes:
            if outcome.error is None:
                _print_table(outcome.result[0], Path(outcome.path), outcome.result[1], outcome.result[2])
            else:
                print(f"data             {outcome.path}\nerror            {outcome.error}")
            print()
    sys.stdout.flush()
    return exit_codes.SUCCESS if all(outcome.error is None for outcome in outcomes) else exit_codes.BAD_INPUT


def identify_file(path_text: str, options: dict):
    """Identify one file with the command's options; return the model, the hold length used and what was set
    aside (:func:`_set_aside_document`): the samples its flags make unusable are NaN to
    :func:`identify.hammerstein_subspace.identify_hammerstein`, which leaves out the windows and rows that hold
    them."""
    import numpy as np

    from identify.border_lifting import PathNodes, uniform_nodes
    from identify.hammerstein_subspace import (
        DEFAULT_FUTURE_HORIZON,
        DEFAULT_PAST_HORIZON,
        identify_hammerstein,
    )
    from identify.validation import InvalidInputError
    from rig.log_file import check_output_varies, read_usable_input_output, unusable_as_missing

    path = Path(path_text)
    imported = options.get("import")
    if imported is None or imported.is_default:
        u, y, set_aside = read_usable_input_output(path)  # u, y columns; no time column needed
    else:
        from rig.record_import import read_measurement

        record, report = read_measurement(path, imported)
        u = record.command_rad
        y, set_aside = unusable_as_missing(record)
        for note in report.notes:
            print(f"import           {note}", file=sys.stderr)
    if u.size == 0:
        raise InvalidInputError(f"{path}: no samples")
    check_output_varies(path, y)
    if options["nodes"] is not None:
        if options["u_min"] is not None or options["u_max"] is not None:
            raise InvalidInputError("--nodes: give either --nodes or --u-min/--u-max with --num-nodes, not both")
        ascending = options["nodes"]
    else:
        u_min = float(np.min(u)) if options["u_min"] is None else options["u_min"]
        u_max = float(np.max(u)) if options["u_max"] is None else options["u_max"]
        ascending = tuple(uniform_nodes(u_min, u_max, options["num_nodes"]).tolist())
    descending = options["descending_nodes"] if options["descending_nodes"] is not None else ascending
    nodes = PathNodes(ascending, descending)

    hold = options["hold_samples"]
    if options["mu0"] is None and hold is None:
        leading = np.flatnonzero(u != u[0])
        hold = int(leading[0]) if leading.size else int(u.size)
        if abs(u[0] - nodes.u_min) > 1e-9 * (nodes.u_max - nodes.u_min):
            raise InvalidInputError(
                f"{path}: the data start at u = {float(u[0])}, not at u_min = {nodes.u_min}; the method needs the "
                "cyclic random excitation that starts with a hold at u_min (configs/experiments/hammerstein_cyclic.toml): "
                "start with the hold at u_min or give --mu0"
            )
    past = DEFAULT_PAST_HORIZON if options["past_horizon"] is None else options["past_horizon"]
    future = DEFAULT_FUTURE_HORIZON if options["future_horizon"] is None else options["future_horizon"]
    try:
        model = identify_hammerstein(
            u, y, nodes,
            hold_samples=hold, mu0_rad=options["mu0"], order=options["order"], past_horizon=past,
            future_horizon=future, feedthrough=not options["no_feedthrough"], split=options["split"],
            refine=options["refine"],
        )
    except InvalidInputError as err:
        raise InvalidInputError(f"{path}: {err}") from err
    return model, hold, _set_aside_document(set_aside, u.size - past - future + 1, model.num_columns)


def _set_aside_document(set_aside, all_windows: int, used_windows: int) -> dict:
    """What ``--json`` (key ``set_aside``) and the table say about the unusable samples: how many, by flag,
    and the Hankel windows (columns) left out because they hold one."""
    return {**set_aside.to_dict(), "hankel_columns_left_out": int(all_windows - used_windows),
            "hankel_columns": int(all_windows)}


def _model_document(result) -> dict:
    """The ``--json`` object of one file: the model (kind hammerstein_model) and ``set_aside``."""
    model, _, set_aside = result
    return {**model.to_dict(), "set_aside": set_aside}


def _print_table(model, path: Path, hold: int | None, set_aside: dict | None = None) -> None:
    numerator, denominator = model.transfer_function
    print(f"data             {path}")
    if set_aside and set_aside["samples"]:
        flags = ", ".join(f"{name} {count}" for name, count in set_aside["by_flag"].items())
        print(f"set aside        {set_aside['samples']} of {set_aside['of']} samples, unusable by their flags ({flags}): "
              f"{set_aside['hankel_columns_left_out']} of the {set_aside['hankel_columns']} Hankel columns (windows "
              "holding one) and their least-squares rows are left out")
    print(f"order            {model.order}   (p = {model.past_horizon}, f = {model.future_horizon}, "
          f"j = {model.num_columns} columns, B and mu: {model.split})")
    shown = model.singular_values[: min(8, model.singular_values.size)]
    print("singular values  " + "  ".join(f"{s:.4g}" + (" |" if k + 1 == model.order else "")
                                          for k, s in enumerate(shown)))
    for pole in model.poles:
        print(f"pole             {pole.real:+.6f} {pole.imag:+.6f}j   |p| = {abs(pole):.6f}")
    if not model.stable:
        print(f"WARNING          unstable: a pole has |p| = {max(abs(p) for p in model.poles):.4g} >= 1; the model "
              "grows without bound in a free run. Try a lower --order, longer or more cyclic data, or --refine")
    print("G(q^-1)          num " + " ".join(f"{c:+.6g}" for c in numerator))
    print("                 den " + " ".join(f"{c:+.6g}" for c in denominator))
    mu0_source = f"hold of {hold} samples, re-estimated" if model.mu0_hold_rad is not None else "given/estimated"
    print(f"mu0              {model.mu0:.6g}   ({mu0_source})")
    print(f"fit              {model.fit_percent:.2f} %   residual RMS {model.residual_rms_rad:.4g}")
    print(f"play             {model.play_at_nodes().describe()}")
    if model.refinement is not None:
        r = model.refinement
        outcome = "applied" if r.applied else "not applied: no improvement or unstable, subspace estimate kept"
        print(f"refinement       output-error RMS {r.rms_before_rad:.4g} -> {r.rms_after_rad:.4g} "
              f"({r.evaluations} evaluations, {outcome})")
    print()
    asc, desc = model.ascending_border, model.descending_border
    if asc.nodes_u == desc.nodes_u:
        print(f"{'u':>10}  {'ascending h':>12}  {'descending h':>12}")
        for u_node, h_a, h_d in zip(asc.nodes_u, asc.values, desc.values):
            print(f"{u_node:>10.4g}  {h_a:>12.6g}  {h_d:>12.6g}")
    else:
        for name, border in (("ascending", asc), ("descending", desc)):
            print(f"{name} border:  " + ", ".join(f"h({u:.4g}) = {h:.6g}" for u, h in zip(border.nodes_u, border.values)))
