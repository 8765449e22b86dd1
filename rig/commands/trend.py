"""``rig trend LOG --window 60s``: guaranteed bounds on the play per time window of an endurance run
(:mod:`identify.backlash_trend`; Cerone, Piga, Regruto 2009, eqs. (11)-(20))."""

from __future__ import annotations

import argparse
import json
import logging
import math
import re
import sys
import time
from pathlib import Path
from typing import Any

from rig import exit_codes

DESCRIPTION = """\
Split the log of an endurance run into windows of time and bound the backlash's play (c_l + c_r) in each,
with the exact set-membership method behind `rig identify output-backlash` (the backlash feasible set D_gamma
of the steady-state points, eqs. (11)-(20) of Cerone, Piga, Regruto 2009). LOG is a rig log of the
steady_staircase experiment, repeated for as long as the run lasts (`rig run ... --duration S`, or offline
`rig simulate PLANT --excitation configs/experiments/steady_staircase.toml --duration 3600`), or its .mf4/.mat
export: its metadata say where each half-wave ends, and the last usable sample of each half-wave's settled tail
is a steady-state point of the window it ends in. Samples flagged LOST (or otherwise unusable) are set aside;
a half-wave whose whole tail was lost gives no point. A window that cannot bound the play (no steady-state
point, no reversal, fewer than two amplitudes on a side) says why instead of giving a number. The bounds
hold while the play is constant within a window: --wear-allowance a (the slope times the most a half-width
wears within one window) widens the noise bound so that every value the play took in a window is inside its
bounds. When LOG has a truth file beside it (LOG with .truth.csv for its
suffix, written by `rig simulate` of a wearing plant), the true play is compared and drawn."""

WINDOW_UNITS = {"s": 1.0, "sec": 1.0, "min": 60.0, "h": 3600.0}


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "trend",
        help="guaranteed bounds on the backlash per time window of an endurance run (set membership)",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("log", metavar="LOG", help="rig log of the (repeated) steady_staircase experiment")
    parser.add_argument("--window", default="60s", metavar="LENGTH",
                        help="window length with its unit: 60s, 5min, 1h (a bare number is seconds; default 60s)")
    parser.add_argument("--noise-bound", type=float, default=None, metavar="RAD",
                        help="bound on the output measurement error (rad), > 0; default: the log's noise_bound_rad")
    parser.add_argument("--wear-allowance", type=float, default=0.0, metavar="RAD",
                        help="the most the wear can move a steady output within one window (slope times the wear "
                             "of a half-width per window), added to the noise bound; default 0: a play constant "
                             "within each window")
    parser.add_argument("--filter-step", type=float, default=None, metavar="RAD",
                        help="amplitude of the step used to tune the filter pole, if known (alpha terms of eq. "
                             "(14)-(15))")
    parser.add_argument("--truth", metavar="TRUTH.csv", default=None,
                        help="the true play over time (columns time_s, c_l_rad, c_r_rad); default: LOG's truth "
                             "file if there is one")
    parser.add_argument("--jobs", type=int, default=0, metavar="N",
                        help="N processes for the windows (0, the default: one per core; 1: in this process)")
    parser.add_argument("--scheduler", metavar="ADDRESS", default=None,
                        help="bound the windows on the Dask cluster at ADDRESS instead (needs dask[distributed])")
    parser.add_argument("--json", action="store_true",
                        help="print the result as one JSON object (kind backlash_trend, version 1)")
    parser.add_argument("--save", metavar="TREND.json", default=None, help="also write the JSON object to a file")
    parser.add_argument("--csv", metavar="TREND.csv", default=None,
                        help="write the table: window start/end, play lower/upper bound, truth, status, reason")
    parser.add_argument("--figure", metavar="TREND.png", default=None,
                        help="draw the bounds over time as a band, with the true play when known")
    parser.add_argument("--force", action="store_true", help="replace existing --save, --csv and --figure files")
    parser.set_defaults(handler=run)


def parse_window(text: str) -> float:
    """Seconds of a ``--window`` text: ``60s``, ``2.5min``, ``1h`` or a bare number of seconds."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([a-zA-Z]*)\s*", text)
    unit = match.group(2).lower() if match else ""
    if match is None or (unit and unit not in WINDOW_UNITS):
        raise ValueError(f"--window: expected a length with a unit such as 60s, 5min or 1h, got {text!r}")
    seconds = float(match.group(1)) * WINDOW_UNITS.get(unit, 1.0)
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"--window: expected a length > 0, got {text!r}")
    return seconds


def _bound_task(task: dict[str, Any]):
    """One window (a module-level function of plain data, so that it runs in other processes and on Dask)."""
    from identify.backlash_trend import bound_window_play

    return bound_window_play(**task)


def _outputs(args: argparse.Namespace) -> list[tuple[str, str]]:
    return [(option, path) for option, path in (("--save", args.save), ("--csv", args.csv),
                                                  ("--figure", args.figure)) if path is not None]


def run(args: argparse.Namespace) -> int:
    from rig.batch import executor_for, map_callable, usable_cores
    from rig.output_paths import check_output_file

    window_s = parse_window(args.window)
    if args.jobs < 0:
        raise ValueError(f"--jobs: expected 0 (all cores) or a positive number of processes, got {args.jobs}")
    if args.noise_bound is not None and not (math.isfinite(args.noise_bound) and args.noise_bound > 0):
        raise ValueError(f"--noise-bound: expected a number of rad > 0, got {args.noise_bound}")
    if not (math.isfinite(args.wear_allowance) and args.wear_allowance >= 0):
        raise ValueError(f"--wear-allowance: expected a number of rad >= 0, got {args.wear_allowance}")
    outputs = _outputs(args)
    paths = [Path(path).resolve() for _, path in outputs]
    if len(set(paths)) != len(paths):
        raise ValueError("--save, --csv, --figure: give each output its own file")
    for option, path in outputs:  # before the work: an hour of log takes a while to read
        check_output_file(path, option, inputs=[args.log, *([args.truth] if args.truth else [])], force=args.force)
    started = time.perf_counter()
    tasks, truth, noise_bound = _windows_of(args, window_s)
    log = logging.getLogger("rig.trend")
    log.info("read %s in %.1f s: %d windows", args.log, time.perf_counter() - started, len(tasks))
    jobs = args.jobs
    if args.scheduler is None:
        jobs = min(usable_cores() if jobs == 0 else jobs, usable_cores(), max(1, len(tasks)))
    with executor_for(jobs, args.scheduler) as executor:
        windows = list(map_callable(executor)(_bound_task, tasks))
    from identify.backlash_trend import BacklashTrend

    if truth is not None:
        windows = [window.with_truth(*(truth.play_range(window.start_s, window.end_s) or (None, None)))
                   for window in windows]
    trend = BacklashTrend(source=str(args.log), window_s=window_s, noise_bound_rad=noise_bound,
                          filter_step_rad=args.filter_step, windows=tuple(windows),
                          truth_source=None if truth is None else truth.source, wear_allowance_rad=args.wear_allowance)
    document = trend.to_dict()
    _write_outputs(args, trend, document, truth)
    if args.json:
        print(json.dumps(document))
    else:
        _print_table(trend, args)
    sys.stdout.flush()
    return exit_codes.EMPTY_FEASIBLE_SET if any(w.status == "empty" for w in trend.windows) else exit_codes.SUCCESS


def _windows_of(args: argparse.Namespace, window_s: float):
    """The tasks of the windows (their steady-state points), the truth (or None) and the noise bound."""
    from collections.abc import Mapping

    import numpy as np

    from rig.staircase_points import staircase_steady_samples
    from rig.log_file import read_experiment_data
    from rig.truth_file import read_play_truth, truth_path_for

    path = Path(args.log)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file (the log to trend)")
    record = read_experiment_data(path)
    config = record.metadata.config if isinstance(record.metadata.config, Mapping) else {}
    excitation = config.get("excitation") if isinstance(config.get("excitation"), Mapping) else {}
    if excitation.get("kind") != "filtered_staircase":
        raise ValueError(
            f"{path}: rig trend bounds the play from the steady-state points of the steady_staircase experiment "
            f"(excitation kind filtered_staircase), but this record's excitation is "
            f"{excitation.get('kind') or 'not recorded'} (metadata config.excitation): record the endurance run "
            "with `rig run RIG.toml --experiment configs/experiments/steady_staircase.toml --duration S` (or "
            "offline with `rig simulate PLANT.toml --excitation configs/experiments/steady_staircase.toml "
            "--duration S`)")
    noise_bound = args.noise_bound
    if noise_bound is None:
        noise_bound = record.metadata.noise_bound_rad
        if noise_bound is None or not (math.isfinite(noise_bound) and noise_bound > 0):
            raise ValueError(f"{path}: the metadata give no finite noise bound (noise_bound_rad is {noise_bound}); "
                             "give --noise-bound RAD (2*pi/2**n for an n-bit encoder, plus the noise)")
    points = staircase_steady_samples(record, path, skip_unusable=True, skip_after_wrap=True)
    time_s = record.time_s
    period = record.metadata.sample_period_s
    start = float(time_s[0])
    guard = 1e-6 * period  # k T computed in floating point: a sample at 60 s belongs to the window from 60 s

    def window_of(times):
        return np.floor((np.asarray(times) - start + guard) / window_s).astype(np.int64)

    count = int(window_of(time_s[-1])) + 1
    unusable = np.bincount(window_of(time_s[~record.valid_mask]), minlength=count)
    lost_points = np.bincount(window_of(time_s[points.unusable_ends]), minlength=count)
    owner = window_of(time_s[points.ends])
    order = np.searchsorted(owner, np.arange(count + 1))  # owner is sorted: the points of window k are a slice
    end_of_record = float(time_s[-1]) + period
    tasks = []
    for k in range(count):
        chosen = slice(int(order[k]), int(order[k + 1]))
        tasks.append({"index": k, "start_s": start + k * window_s, "end_s": min(start + (k + 1) * window_s,
                                                                                  end_of_record),
                      "steady_input_rad": points.command_rad[chosen], "steady_output_rad": points.angle_rad[chosen],
                      "noise_bound_rad": float(noise_bound), "wear_allowance_rad": args.wear_allowance,
                      "filter_step_amplitude_rad": args.filter_step,
                      "samples_set_aside": int(unusable[k]), "points_set_aside": int(lost_points[k])})
    truth_path = Path(args.truth) if args.truth is not None else truth_path_for(path)
    truth = None
    if args.truth is not None or truth_path.is_file():
        truth = read_play_truth(truth_path)
    return tasks, truth, float(noise_bound)


CSV_COLUMNS = ("window", "start_s", "end_s", "status", "play_lower_rad", "play_upper_rad", "truth_min_rad",
               "truth_max_rad", "truth_inside", "c_l_lower_rad", "c_l_upper_rad", "c_r_lower_rad", "c_r_upper_rad",
               "right_points", "left_points", "samples_set_aside", "points_set_aside", "reason")


def trend_rows(trend) -> list[list[str]]:
    """The CSV table's rows (:data:`CSV_COLUMNS`): empty cells where a window has no number."""
    def text(value: float | None) -> str:
        return "" if value is None else repr(float(value))

    rows = []
    for window in trend.windows:
        play, c_l, c_r = window.play_rad, window.c_l_rad, window.c_r_rad
        inside = window.truth_inside
        rows.append([str(window.index), repr(window.start_s), repr(window.end_s), window.status,
                     text(play and play.lower), text(play and play.upper), text(window.truth_min_rad),
                     text(window.truth_max_rad), "" if inside is None else str(inside).lower(),
                     text(c_l and c_l.lower), text(c_l and c_l.upper), text(c_r and c_r.lower), text(c_r and c_r.upper),
                     str(window.right_points), str(window.left_points), str(window.samples_set_aside),
                     str(window.points_set_aside), window.reason])
    return rows


def _write_outputs(args: argparse.Namespace, trend, document: dict, truth) -> None:
    import csv
    import io

    from rig.output_paths import atomic_output

    if args.save is not None:
        with atomic_output(args.save, "--save", force=args.force) as written:
            written.write_text(json.dumps(document))
    if args.csv is not None:
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(CSV_COLUMNS)
        writer.writerows(trend_rows(trend))
        with atomic_output(args.csv, "--csv", force=args.force) as written:
            written.write_text(buffer.getvalue(), encoding="utf-8")
    if args.figure is not None:
        import matplotlib

        matplotlib.use("Agg")
        from matplotlib.figure import Figure

        from rig.plots.trend import trend_figure
        from rig.report import FIGURE_DPI

        drawing = trend_figure(trend, "trend", truth)
        figure = Figure(figsize=drawing.size_in, layout="constrained")
        drawing.draw(figure)
        with atomic_output(args.figure, "--figure", force=args.force, suffix=".png") as written:
            figure.savefig(written, dpi=FIGURE_DPI, format="png")


def _print_table(trend, args: argparse.Namespace) -> None:
    inside, judged = trend.truth_inside_count
    print(f"log          {trend.source}")
    print(f"windows      {len(trend.windows)} of {trend.window_s:g} s, {len(trend.bounded)} bounded")
    print(f"noise bound  {trend.noise_bound_rad:.6g} rad" + ("" if args.noise_bound is not None else " (the log's)")
          + (f" + wear allowance {trend.wear_allowance_rad:.6g} rad" if trend.wear_allowance_rad else ""))
    if judged:
        print(f"truth        {trend.truth_source}: inside the bounds in {inside} of {judged} windows")
    print()
    print(f"{'window':>6} {'start_s':>9} {'end_s':>9} {'R/L':>7} {'play lower':>12} {'play upper':>12} "
          f"{'truth':>21}  status")
    for window in trend.windows:
        truth = ("" if window.truth_min_rad is None else
                 f"{window.truth_min_rad:.6g}-{window.truth_max_rad:.6g}")
        points = f"{window.right_points}/{window.left_points}"
        if window.play_rad is not None:
            bounds = f"{window.play_rad.lower:>12.6g} {window.play_rad.upper:>12.6g}"
            status = "bounded" + ("" if window.truth_inside is None else
                                  "" if window.truth_inside else "  TRUTH OUTSIDE")
        else:
            bounds = f"{'-':>12} {'-':>12}"
            status = f"{window.status}: {window.reason}"
        print(f"{window.index:>6} {window.start_s:>9.6g} {window.end_s:>9.6g} {points:>7} {bounds} {truth:>21}  "
              f"{status}")
        if window.samples_set_aside:
            print(f"{'':>6} set aside: {window.samples_set_aside} samples unusable by their flags, "
                  f"{window.points_set_aside} steady-state points lost")
