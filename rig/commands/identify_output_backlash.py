"""``rig identify output-backlash``: guaranteed parameter bounds of a linear system with output backlash
(Cerone, Piga and Regruto 2009; :mod:`identify.output_backlash_identification`)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from rig import exit_codes

DESCRIPTION = """\
Bound the parameters of a linear block followed by an output backlash from a steady-state experiment
and a dynamic (PRBS) experiment with bounded output noise (Cerone, Piga, Regruto 2009).

STEADY.csv has one row per steady-state point with columns u and y (radians): the input and output at
the end of every half-wave of the filtered square-wave staircase, positive and negative half-waves in
any order. STEADY may also be the rig log of the steady_staircase experiment as `rig run` or `rig simulate`
wrote it: its metadata say where each half-wave ends, and the last valid sample of each half-wave's
settled tail (its last 10 %) is taken, as `rig demo` does. DYNAMIC.csv has columns u and y per sample (a column t is ignored). Both may also be rig-log
v1 files (command_rad is u, angle_rad is y), also as the .mf4/.mdf/.mat of `rig export`, or MDF4/MAT files
with channels u and y. --noise-bound is the bound on the output error, e.g.
2*pi/2**n for an n-bit encoder. All bounds are guaranteed to contain every parameter consistent with the
data, the noise bound and the model structure; an empty feasible set exits with code 4 and says why."""


def register(methods: argparse._SubParsersAction) -> None:
    parser = methods.add_parser(
        "output-backlash",
        help="set-membership bounds of a linear system with output backlash (Cerone et al. 2009)",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--steady", required=True, action="append", metavar="STEADY.csv",
                        help="steady-state points, columns u, y (repeat --steady/--dynamic for several experiments)")
    parser.add_argument("--dynamic", required=True, action="append", metavar="DYNAMIC.csv",
                        help="dynamic experiment, columns u, y (the k-th --dynamic goes with the k-th --steady)")
    parser.add_argument("--noise-bound", required=True, type=float, metavar="RAD",
                        help="bound on the output measurement error (rad), > 0")
    parser.add_argument("--na", required=True, type=int, help="order of A(q^-1) = 1 + a1 q^-1 + ... + a_na q^-na")
    parser.add_argument("--nk", required=True, type=int, help="first coefficient b_nk of B(q^-1) (input delay)")
    parser.add_argument("--nb", required=True, type=int, help="last coefficient b_nb of B(q^-1)")
    parser.add_argument("--method", choices=("paper", "coupled"), default="coupled",
                        help="coupled (default, tightest): shared inner-signal errors, McCormick LP relaxation; "
                             "paper: errors-in-variables bounds per equation (Cerone 1993)")
    parser.add_argument("--filter-step", type=float, default=None, metavar="RAD",
                        help="amplitude of the step used to tune the filter pole, if known (alpha terms of eq. (14)-(15))")
    parser.add_argument("--json", action="store_true",
                        help="print the result as one JSON object (kind output_backlash, version 1: the bounds and "
                             "the whole result, which `rig report` draws)")
    parser.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="N processes (0: one per core; default 1): for one pair, the windows of a long record; "
                             "for several --steady/--dynamic pairs, the pairs")
    parser.add_argument("--scheduler", metavar="ADDRESS", default=None,
                        help="run the windows (one pair) or the pairs on the Dask cluster at ADDRESS instead "
                             "(needs dask[distributed])")
    parser.add_argument("--windows", action="store_true",
                        help="coupled method: bound by windows and joint parts with the inner signal's errors as LP "
                             "columns even where the record has few gaps (by default such a record is bounded with "
                             "the inner signal eliminated, in time linear in its length, at every length with the "
                             "partition below and the verified inner values)")
    parser.add_argument("--window-samples", type=int, default=200, metavar="N",
                        help="coupled method, windows: records longer than two windows are bounded window by window, "
                             "N samples each (default 200)")
    parser.add_argument("--joint-samples", type=int, default=3000, metavar="N",
                        help="coupled method, windows: the final relaxation is solved jointly over all samples up to "
                             "N, else over overlapping parts of N samples whose bounds are intersected (default 3000; "
                             "larger is tighter and slower); the verified inner values are computed only up to N "
                             "samples")
    parser.add_argument("--partition-samples", type=int, default=1000, metavar="N",
                        help="coupled method: 0 switches off the final tightening by partition of the box of a "
                             "(outer bounds close to the verified inner values at a few times the cost); with "
                             "--windows (or a record of many gaps) only records up to N samples get it (default "
                             "1000)")
    parser.add_argument("--moment-samples", type=int, default=0, metavar="N",
                        help="coupled method: records up to N samples (default 0: never) get a last tightening by cuts "
                             "from the first-order moment (SDP) relaxation, solved with cvxpy (pip install "
                             "'gearbox-rig[sdp]'; without it a note says so); well under 1 %% narrower on the paper's "
                             "example at about twice the time")
    parser.add_argument("--save", metavar="RESULT.json", default=None,
                        help="also write the --json object with the data it came from (steady points, dynamic "
                             "record, noise bound, orders) to RESULT.json (an existing file is refused unless --force)")
    parser.add_argument("--force", action="store_true", help="replace an existing --save file")
    parser.set_defaults(handler=run)


SAVED_FORMAT = "rig output-backlash result v1"
"""The ``format`` of a ``--save`` file: the ``--json`` object (kind ``output_backlash``) plus ``data`` (the
inputs it came from)."""


def _read(path_text: str, role: str):
    """(u, y, set aside) of the ``role`` experiment, naming the role when the file is missing. The dynamic
    experiment's output is NaN at the samples its flags make unusable (:func:`rig.log_file.unusable_as_missing`),
    which the bounds leave out; the steady-state points are each a usable sample (set aside: None)."""
    from rig.log_file import check_output_varies, is_rig_log, read_input_output, read_usable_input_output
    from rig.measurement_files import measurement_format, read_measurement_record
    from rig.signal_files import check_input_file

    if not Path(path_text).exists():
        raise FileNotFoundError(f"{path_text}: no such file ({role} data)")
    path = check_input_file(path_text, f"the {role} data (a CSV with columns u, y, or a rig log)")
    if role == "steady-state":
        if is_rig_log(path) or (measurement_format(path) is not None and read_measurement_record(path) is not None):
            return (*staircase_steady_points(path)[:2], None)
        if _has_time_column(path):
            raise ValueError(
                f"{path}: --steady takes one row per steady-state point (columns u, y: the last sample of each "
                "half-wave of the steady_staircase experiment), but this is a per-sample record (a CSV with a t "
                "column) that does not say where the half-waves end: give the staircase experiment's rig log (its "
                "metadata say it), or pass a record of every sample as --dynamic")
    if role == "steady-state":
        return (*read_input_output(path), None)
    u, y, set_aside = read_usable_input_output(path)
    check_output_varies(path, y)
    return u, y, set_aside


def _has_time_column(path: Path) -> bool:
    from rig.measurement_files import read_table

    return "t" in read_table(path, ("u", "y"), optional_columns=("t",))


def staircase_steady_points(path: Path):
    """(u, y, description) of the steady-state points of a steady_staircase rig log: at the last sample of
    every half-wave (from the excitation's ``samples_per_half_wave`` and amplitudes in the metadata; a log
    cut or repeated by ``rig run --duration`` has the ends it holds), u is the command there and y the last
    valid angle in the half-wave's settled tail. A half-wave whose whole tail is LOST or unusable is left out
    and said (a point left out can only widen the feasible set); fewer than two points left is refused."""
    import numpy as np

    from rig.log_file import read_experiment_data
    from rig.staircase_points import staircase_steady_samples

    points = staircase_steady_samples(read_experiment_data(path), path, skip_unusable=True)
    total = points.ends.size + len(points.unusable_ends)
    if points.ends.size < 2:
        raise ValueError(f"{path}: {points.ends.size} of the {total} half-waves {'has' if points.ends.size == 1 else 'have'} a usable settled tail (the last "
                         f"{points.tail} samples of each; the others are all LOST or unusable): at least two steady-"
                         "state points are needed; record the staircase again")
    moved = int(np.count_nonzero(points.taken != points.ends))
    left_out = len(points.unusable_ends)
    lines = ", ".join(str(int(index) + 5) for index in points.unusable_ends[:5]) + (", ..." if left_out > 5 else "")
    description = (f"{points.ends.size} points: the end of each half-wave of {points.samples_per_half_wave} samples "
                   "of the staircase log" + (f", {moved} of them taken up to {points.tail - 1} samples early (the "
                                             "end sample was lost)" if moved else "")
                   + (f"; {left_out} half-wave{'s' * (left_out != 1)} left out (line{'s' * (left_out != 1)} {lines}: "
                      f"{'their' if left_out != 1 else 'its'} whole settled tail LOST or unusable)" if left_out else ""))
    return points.command_rad, points.angle_rad, description


def run(args: argparse.Namespace) -> int:
    if len(args.steady) != len(args.dynamic):
        raise ValueError(f"--steady/--dynamic: give them in pairs (got {len(args.steady)} --steady and "
                         f"{len(args.dynamic)} --dynamic); the k-th --steady goes with the k-th --dynamic")
    if args.save is not None:  # before the work: a coupled bound can take a while
        from rig.output_paths import check_output_file

        check_output_file(args.save, "--save", inputs=[*args.steady, *args.dynamic], force=args.force)
    if args.jobs < 0:
        raise ValueError(f"--jobs: expected 0 (all cores) or a positive number of processes, got {args.jobs}")
    if len(args.steady) == 1:
        return _run_one(args, args.steady[0], args.dynamic[0])
    return _run_batch(args)


def _run_batch(args: argparse.Namespace) -> int:
    """Several experiments, bounded independently in parallel (rig/batch.py); one bad pair is reported
    with its error while the others come out."""
    from functools import partial

    from rig.batch import batch_document, map_files

    if len(set(args.dynamic)) != len(args.dynamic):
        raise ValueError("--dynamic: each dynamic file once when several pairs are given")
    if args.save is not None:
        raise ValueError("--save: one --steady/--dynamic pair at a time")
    options = {key: getattr(args, key) for key in _OPTIONS}
    outcomes = map_files(partial(bound_pair, steady_of=dict(zip(args.dynamic, args.steady)), options=options),
                         args.dynamic, jobs=args.jobs, scheduler=args.scheduler,
                         shared_files=sorted(set(args.steady)))
    entries = []
    for steady, outcome in zip(args.steady, outcomes):
        entry = {"steady": steady, "dynamic": outcome.path}
        entry.update({"error": outcome.error} if outcome.error is not None else {"bounds": outcome.result})
        entries.append(entry)
    if args.json:
        print(json.dumps(batch_document(entries)))
    else:
        for entry in entries:
            print(f"steady-state data  {entry['steady']}\ndynamic data       {entry['dynamic']}")
            bounds = entry.get("bounds")
            if bounds is None:
                print(f"error              {entry['error']}")
            elif bounds.get("empty"):
                print(f"empty feasible set: {bounds['explanation']}")
            else:
                for group in ("backlash", "linear"):
                    for name, interval in bounds[group].items():
                        print(f"{name:<10} {float(interval['lower']):>14.8g} {float(interval['upper']):>14.8g}")
            print()
    sys.stdout.flush()
    if any("error" in entry for entry in entries):
        return exit_codes.BAD_INPUT
    if any(entry["bounds"].get("empty") for entry in entries):
        return exit_codes.EMPTY_FEASIBLE_SET
    return exit_codes.SUCCESS


def bound_pair(dynamic: str, steady_of: dict[str, str], options: dict) -> dict:
    """The ``--json`` document of one experiment (``{"empty": true, ...}`` for an empty feasible set); a
    module-level function returning plain data, so that it runs in other processes."""
    from rig.batch import shipped_path, user_path

    result, _, _, _, y, set_aside = _bound(shipped_path(steady_of[user_path(dynamic)]), dynamic, options)  # a cluster worker's copies
    return _document(result, options["method"], _set_aside_document(set_aside, y, options))


_OPTIONS = ("noise_bound", "na", "nk", "nb", "method", "filter_step", "window_samples", "joint_samples",
            "partition_samples", "moment_samples", "windows")


def _bound(steady: str, dynamic: str, options: dict, map_windows=None, progress=None):
    from identify.output_backlash_identification import bound_output_backlash_system
    from identify.validation import InvalidInputError

    steady_u, steady_y, _ = _read(steady, "steady-state")
    u, y, set_aside = _read(dynamic, "dynamic")
    try:
        result = bound_output_backlash_system(steady_u, steady_y, u, y, options["noise_bound"], na=options["na"],
                                              nk=options["nk"], nb=options["nb"], method=options["method"],
                                              filter_step_amplitude_rad=options["filter_step"],
                                              window_samples=options["window_samples"],
                                              joint_samples=options["joint_samples"],
                                              partition_samples=options["partition_samples"],
                                              moment_samples=options["moment_samples"], map_windows=map_windows,
                                              progress=progress, eliminate_inner_signal=not options["windows"],
                                              verify_inner=_verifies_inner(u, y, options))
    except InvalidInputError as err:
        raise InvalidInputError(f"{err} (--steady {steady}, --dynamic {dynamic})") from err
    return result, steady_u, steady_y, u, y, set_aside


def _verifies_inner(u, y, options: dict) -> bool:
    """Whether the verified inner values are computed: on a record bounded with the inner signal eliminated (their
    LPs have a few columns), or up to --joint-samples samples (each of their LPs has a column per sample)."""
    from identify.linear_block_bounds import eliminates_inner_signal

    equations, left_out = _equation_counts(y, options)
    return len(u) <= options["joint_samples"] or (
        not options["windows"] and eliminates_inner_signal(len(u), equations - left_out, options["na"]))


def _equation_counts(y, options: dict) -> tuple[int, int]:
    """The equations of eq. (7) of the dynamic record and those left out because their regressors (x_t .. x_{t-na})
    need a sample not measured: as :func:`identify.linear_block_bounds.bound_linear_block` counts them."""
    import numpy as np

    from identify.linear_block_bounds import LinearModelOrders

    orders = LinearModelOrders(options["na"], options["nk"], options["nb"])
    times = np.arange(orders.first_equation, y.size)
    known = ~np.isnan(y)
    complete = np.all([known[times - i] for i in range(orders.na + 1)], axis=0) if times.size else known[:0]
    return int(times.size), int(times.size - np.count_nonzero(complete))


def _set_aside_document(set_aside, y, options: dict) -> dict:
    """The samples of the dynamic record set aside (unusable by their flags) and the equations of eq. (7)
    left out because their regressors need one (:func:`_equation_counts`)."""
    equations, left_out = _equation_counts(y, options)
    return {**set_aside.to_dict(), "equations_left_out": left_out, "equations": equations}


def _document(result, method: str, set_aside: dict | None = None) -> dict:
    """The ``--json`` object: :meth:`OutputBacklashIdentification.to_dict` (the documented keys, with
    ``kind`` and ``version``), ``notes`` when a bound fell back (a bounding LP HiGHS could not solve), and
    ``set_aside``: the dynamic record's unusable samples and the equations they took out."""
    assert result.method == method
    document = result.to_dict()
    if set_aside is not None:
        document["set_aside"] = set_aside
    if result.linear is not None and result.linear.notes:
        document["notes"] = list(result.linear.notes)
    return document


class _ProgressLine:
    """Progress of the windows on stderr: one line rewritten in place on a terminal, else a line per stage
    (and per quarter of a long stage), so that logs stay short and stdout stays the result (``--json``)."""

    def __init__(self, stream) -> None:
        self.stream = stream
        self.tty = hasattr(stream, "isatty") and stream.isatty()
        self.stage: str | None = None
        self.quarter = -1

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.tty:
            end = "\n" if done == total else ""
            self.stream.write(f"\r{stage}: {done}/{total}{end}")
        else:
            quarter = (4 * done) // max(total, 1)
            if stage == self.stage and quarter == self.quarter:
                return
            self.stage, self.quarter = stage, quarter
            if done == 0 or quarter > 0:
                self.stream.write(f"{stage}: {done}/{total}\n")
        self.stream.flush()


def _steady_description(steady: str, count: int) -> str:
    from rig.log_file import is_rig_log

    if is_rig_log(Path(steady)):
        return staircase_steady_points(Path(steady))[2]
    return f"{count} points"


def _run_one(args: argparse.Namespace, steady: str, dynamic: str) -> int:
    from rig.batch import executor_for, map_callable

    options = {key: getattr(args, key) for key in _OPTIONS}
    # the windows and parts of a long record run in worker processes even with --jobs 1: a crash inside
    # HiGHS then loses that worker's windows (valid, looser bounds with a note), not the command
    with executor_for(args.jobs, args.scheduler, isolated=True) as executor:
        result, steady_u, steady_y, u, y, set_aside = _bound(steady, dynamic, options, map_callable(executor),
                                                             _ProgressLine(sys.stderr))
    aside = _set_aside_document(set_aside, y, options)
    document = _document(result, args.method, aside)
    if result.is_empty:
        if args.json:
            print(json.dumps(document))
        print(f"empty feasible set: {result.explanation}", file=sys.stderr)
        return exit_codes.EMPTY_FEASIBLE_SET
    backlash = result.backlash_intervals
    linear = result.linear_intervals
    inner = result.inner_signal
    if args.save is not None:
        _save(args.save, document, args, steady, dynamic, steady_u, steady_y, u, y)
    if args.json:
        print(json.dumps(document))
    else:
        print(f"steady-state data  {steady}  ({_steady_description(steady, len(steady_u))})")
        print(f"dynamic data       {dynamic}  ({inner.lower_rad.size} samples, {inner.num_invertible} invertible)")
        if aside["samples"]:
            print(f"set aside          {aside['samples']} samples unusable by their flags ({set_aside.flags_text()}): "
                  f"the {aside['equations_left_out']} of the {aside['equations']} equations that need one are left out")
        print(f"noise bound        {args.noise_bound:.6g} rad     method {args.method}")
        if result.linear.windowing:
            print(f"windowing          {result.linear.windowing}")
        print()
        print(f"{'parameter':<10} {'lower':>14} {'upper':>14} {'center':>14} {'half-width':>11}")
        for name, interval in (*backlash.items(), *linear.items()):
            print(f"{name:<10} {interval.lower:>14.8g} {interval.upper:>14.8g} {interval.center:>14.8g} "
                  f"{interval.half_width:>11.3g}")
        ratios = result.linear.outer_inner_ratio
        if ratios is not None:
            print()
            print("verified inner values (points of the exact feasible set reach at least these; '-': no verified "
                  "point found, the outer bound still holds) and outer/inner, how many times wider than the span of "
                  "the verified values the guaranteed interval is (1: exact):")
            for name in linear:
                low, high = (f"{value:>14.8g}" if math.isfinite(value) else f"{'-':>14}"
                             for value in (result.linear.inner_lower[name], result.linear.inner_upper[name]))
                ratio = "-" if ratios.get(name) is None else f"{ratios[name]:.3g}"
                print(f"{name:<10} {low} {high}  outer/inner {ratio}")
        elif result.method == "coupled":
            print()
            print(f"outer/inner        not computed: the verified inner values are computed for records bounded "
                  f"with the inner signal eliminated (not --windows, few gaps) or of up to --joint-samples "
                  f"({args.joint_samples}) samples, this one has {inner.lower_rad.size}")
        for note in result.linear.notes:
            print(f"note: {note}")
    sys.stdout.flush()
    return exit_codes.SUCCESS


def _save(path_text: str, document: dict, args: argparse.Namespace, steady: str, dynamic: str, steady_u, steady_y,
          u, y) -> None:
    """Write the ``--save`` file (:data:`SAVED_FORMAT`); an unwritable path is an OSError naming it."""
    saved = {"format": SAVED_FORMAT, **document, "data": {
        "steady": {"u": steady_u.tolist(), "y": steady_y.tolist(), "file": str(steady)},
        "dynamic": {"u": u.tolist(), "y": [None if math.isnan(v) else v for v in y.tolist()], "file": str(dynamic)},
        "noise_bound_rad": args.noise_bound, "filter_step_rad": args.filter_step,
        "na": args.na, "nk": args.nk, "nb": args.nb}}
    from rig.output_paths import atomic_output

    with atomic_output(path_text, "--save", force=args.force) as written:
        written.write_text(json.dumps(saved))
