"""Confusion matrix of the model-discrepancy workflow (issue 6, extended in issue 15 item 6) on hidden-effect
records, and a run on the real EMPS record.

For every effect (and for no effect) ``--cases`` records are simulated with random realistic parameters and a
12-bit encoder (:mod:`identify.discrepancy_cases`); the workflow sees the data, the noise bound and either the
nominal linear model (``--start given``) or nothing (``--start fitted``: it fits its own linear model). The
row is the true effect, the column the first effect named ("none" if nothing, "ambig" when the verdict is
ambiguous: candidates within their uncertainty of each other, none chosen); the gap reduction is
1 - gap_final / gap_initial. Also counted: cases where more effects than the true one were named, and how
many fitted parameters of a rightly named effect have an interval that contains the true value, and the median
width of those intervals in per cent of the true value.

Rows of two effects at once (``--pairs``, ``a+b``): a case is correct when exactly the two are named (in either
order); the table gives the named sets.

Run:  nice -n 10 .venv/bin/python benchmarks/model_discrepancy_confusion.py --cases 20 --start given --jobs 2
      nice -n 10 .venv/bin/python benchmarks/model_discrepancy_confusion.py --cases 5 --start fitted --jobs 2
      nice -n 10 .venv/bin/python benchmarks/model_discrepancy_confusion.py --emps-only
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from identify.discrepancy_cases import hidden_effect_record
from identify.effect_catalogue import EFFECT_NAMES, effect
from identify.model_discrepancy import diagnose_model

TRUE_EFFECTS = ("none", *EFFECT_NAMES)  # every effect of the catalogue
PAIRS = ("gravity+rate_limit", "load_friction+gravity", "backlash+gravity", "delay+torque_limit",
         "shaft_play+load_friction")
"""Default rows of two effects at once: the servo with an arm (weight and speed limit, friction and weight),
an output play behind a drive with an arm, a lag before a torque-limited drive, a gear's play with friction
on the load it drives."""
EMPS = next((parent / "shared" / "realdata" for parent in Path(__file__).resolve().parents
             if (parent / "shared" / "realdata").is_dir()),
            Path(__file__).resolve().parents[2] / "shared" / "realdata") / "emps" / "DATA_EMPS.mat"
"""``shared/realdata`` next to the checkout or next to any folder above it (a git worktree sits deeper)."""


def run_case(effects: tuple[str, ...], seed: int, start: str) -> dict:
    """One hidden-effect record diagnosed: the named effects, the verdict, the gap reduction, and per named
    true effect how many of its parameter intervals hold the truth (``missed``: the others, with the truth
    and the interval, in the case's line on stderr)."""
    record = hidden_effect_record(effects, seed)
    started = time.perf_counter()
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad,
                            record.sample_period_s, record.nominal_model if start == "given" else None)
    covered, missed, widths = [0, 0], [], []
    for name in set(effects) & set(result.missing_effects):
        entry = effect(name)
        truth = entry.report(next(b for b in record.true_model.blocks if isinstance(b, entry.block_class)))
        for key, (low, high) in result.parameter_intervals.get(name, {}).items():
            inside = low <= truth[key] <= high
            if truth[key] != 0.0:
                widths.append((high - low) / abs(truth[key]))
            covered[0] += inside
            covered[1] += 1
            if not inside:
                missed.append(f"{name}.{key}: truth {truth[key]:.4g} outside [{low:.4g}, {high:.4g}]")
    return {"named": tuple(result.missing_effects), "verdict": result.verdict,
            "reduction": 1.0 - result.final.gap_rad / result.initial.gap_rad if result.initial.gap_rad > 0 else 0.0,
            "covered": covered, "missed": missed, "widths": widths, "seconds": time.perf_counter() - started}


def _run_rows(rows: tuple[tuple[str, ...], ...], cases: int, start: str, first_seed: int,
              jobs: int) -> dict[tuple[str, ...], list[dict]]:
    tasks = [(row, first_seed + case) for row in rows for case in range(cases)]
    out: dict[tuple[str, ...], list[dict]] = {row: [] for row in rows}
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        results = pool.map(run_case, [t[0] for t in tasks], [t[1] for t in tasks], [start] * len(tasks))
        for (row, seed), result in zip(tasks, results):  # one line per case as it is done, on stderr
            out[row].append(result)
            print(f"  {'+'.join(row) or 'none'} seed {seed}: {result['verdict']} {'+'.join(result['named']) or '-'} "
                  f"({result['seconds']:.0f} s) " + json.dumps({"row": list(row), "seed": seed, **result}),
                  file=sys.stderr, flush=True)
    return out


def confusion(cases: int, start: str, effects: tuple[str, ...], first_seed: int, jobs: int) -> None:
    started = time.perf_counter()
    runs = _run_rows(tuple(() if row == "none" else (row,) for row in effects), cases, start, first_seed, jobs)
    print(f"\nstart model: {start}; {cases} cases per row (seeds {first_seed}..{first_seed + cases - 1}); "
          f"{time.perf_counter() - started:.0f} s in all with {jobs} process(es)")
    confusion_table(runs, effects)


def confusion_table(runs: dict[tuple[str, ...], list[dict]], effects: tuple[str, ...]) -> None:
    """The confusion matrix of single-effect rows (``effects``: names, "none" for the clean records)."""
    columns = (*TRUE_EFFECTS, "ambiguous", "other")
    short = {name: name[:5] for name in columns} | {"dead_zone": "deadz", "coulomb_friction": "fric", "offset": "offs",
                                                    "gain_error": "gain", "load_friction": "lfric", "gravity": "grav",
                                                    "rate_limit": "rate", "torque_limit": "torq",
                                                    "shaft_play": "play"}
    print("| true \\ named | " + " | ".join(short[c] for c in columns)
          + " | correct | more named | median gap reduction | truth in interval | median width | median s |")
    print("|---" * (len(columns) + 7) + "|")
    diagonal = total = inside = intervals = 0
    for row in effects:
        results = runs[() if row == "none" else (row,)]
        counts = {column: 0 for column in columns}
        for result in results:
            named = result["named"][0] if result["named"] else ("ambiguous" if result["verdict"] == "ambiguous" else "none")
            counts[named if named in counts else "other"] += 1
        extras = sum(len(r["named"]) > (0 if row == "none" else 1) for r in results)
        covered = [sum(r["covered"][0] for r in results), sum(r["covered"][1] for r in results)]
        reductions = [r["reduction"] for r in results] if row != "none" else []
        median = f"{100 * np.median(reductions):.1f} %" if reductions else "-"
        diagonal, total = diagonal + counts[row], total + len(results)
        inside, intervals = inside + covered[0], intervals + covered[1]
        print(f"| {row} | " + " | ".join(str(counts[c]) for c in columns)
              + f" | {100 * counts[row] / len(results):.0f} % | {extras} | {median} | "
              + (f"{covered[0]} of {covered[1]}" if covered[1] else "-")
              + f" | {_median_width(results)} | {np.median([r['seconds'] for r in results]):.1f} |")
    print(f"\ndiagonal {diagonal} of {total} ({100 * diagonal / total:.1f} %); truth in interval {inside} of "
          f"{intervals} ({100 * inside / max(intervals, 1):.1f} %)")


def pairs(cases: int, start: str, rows: tuple[tuple[str, ...], ...], first_seed: int, jobs: int) -> None:
    """Two hidden effects at once: correct when exactly the two are named."""
    started = time.perf_counter()
    runs = _run_rows(rows, cases, start, first_seed, jobs)
    print(f"\ntwo effects at once, start model: {start}; {cases} cases per row (seeds {first_seed}.."
          f"{first_seed + cases - 1}); {time.perf_counter() - started:.0f} s in all with {jobs} process(es)")
    pairs_table(runs, rows)


def pairs_table(runs: dict[tuple[str, ...], list[dict]], rows: tuple[tuple[str, ...], ...]) -> None:
    """The rows of two effects at once."""
    print("| true effects | both named, nothing else | named sets (count) | ambiguous | median gap reduction | "
          "truth in interval | median width | median s |")
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        results = runs[row]
        right = sum(set(r["named"]) == set(row) for r in results)
        sets: dict[str, int] = {}
        for r in results:
            label = "+".join(r["named"]) if r["named"] else ("ambiguous" if r["verdict"] == "ambiguous" else "none")
            sets[label] = sets.get(label, 0) + 1
        covered = [sum(r["covered"][0] for r in results), sum(r["covered"][1] for r in results)]
        print(f"| {' + '.join(row)} | {right} of {len(results)} ({100 * right / len(results):.0f} %) | "
              + ", ".join(f"{k} ({v})" for k, v in sorted(sets.items(), key=lambda kv: -kv[1]))
              + f" | {sum(r['verdict'] == 'ambiguous' for r in results)} | "
              + f"{100 * np.median([r['reduction'] for r in results]):.1f} % | "
              + (f"{covered[0]} of {covered[1]}" if covered[1] else "-")
              + f" | {_median_width(results)} | {np.median([r['seconds'] for r in results]):.1f} |")


def _median_width(results: list[dict]) -> str:
    """The median width of the intervals of the rightly named parameters, in per cent of the true value
    (cases logged before the widths were, none)."""
    widths = [w for r in results for w in r.get("widths", [])]
    return f"{100 * np.median(widths):.1f} %" if widths else "-"


def tables_from_log(path: Path) -> None:
    """The tables of the cases a run logged on stderr (one JSON object per line after the case's summary),
    e.g. of a run stopped before its end: rows with the cases they have."""
    runs: dict[tuple[str, ...], list[dict]] = {}
    for line in path.read_text().splitlines():
        if "{" in line:
            case = json.loads(line[line.index("{"):])
            runs.setdefault(tuple(case["row"]), []).append(case)
    print(f"\nfrom {path.name}: {sum(len(v) for v in runs.values())} cases")
    singles = tuple("+".join(row) or "none" for row in runs if len(row) < 2)
    if singles:
        confusion_table(runs, singles)
    doubles = tuple(row for row in runs if len(row) == 2)
    if doubles:
        pairs_table(runs, doubles)


def emps(decimate: int, noise_bound_m: float) -> None:
    """Reference position qg -> measured motor position qm of the EMPS closed loop (metres, not radians:
    the workflow is unit-agnostic). qm moves in steps of 5e-8 m; the default bound is 20 such steps."""
    from scipy.io import loadmat

    if not EMPS.is_file():
        print(f"\nEMPS: {EMPS} not found, skipped")
        return
    data = loadmat(EMPS)
    t = np.ravel(data["t"])[::decimate]
    reference = np.ravel(data["qg"])[::decimate]
    measured = np.ravel(data["qm"])[::decimate]
    period = float(np.median(np.diff(t)))
    started = time.perf_counter()
    result = diagnose_model(reference, measured, noise_bound_m, period, None, progress=None)
    print(f"\nEMPS DATA_EMPS.mat: qg -> qm, every {decimate}th sample ({reference.size} samples, T = {period:g} s), "
          f"noise bound {noise_bound_m:g} m, fitted linear start model of order {result.linear_fit.order}; "
          f"{time.perf_counter() - started:.0f} s")
    print(f"initial gap {result.initial.gap_rad:.4g} m, {100 * result.initial.falsified_fraction:.1f} % falsified, "
          f"{len(result.initial.windows)} windows")
    for number, step in enumerate(result.steps, 1):
        parameters = ", ".join(f"{k} = {v:.4g}" for k, v in step.parameters.items())
        print(f"step {number}: {step.effect}: gap {step.gap_before_rad:.4g} -> {step.gap_after_rad:.4g} "
              f"({parameters}); signature scores "
              + ", ".join(f"{k} {v:.2f}" for k, v in step.evidence["signature_scores"].items()))
    print(f"final gap {result.final.gap_rad:.4g} m, {100 * result.final.falsified_fraction:.1f} % falsified; "
          f"{result.unexplained}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", type=int, default=20, help="random cases per true effect (default 20)")
    parser.add_argument("--start", choices=("given", "fitted"), default="given")
    parser.add_argument("--effects", default=None,
                        help="rows, comma-separated (default: all; with --start fitted all but gain_error, which a "
                             "fitted linear start model absorbs: no method can name it there)")
    parser.add_argument("--pairs", default=",".join(PAIRS),
                        help="rows of two effects, a+b comma-separated (default: %(default)s; '' for none)")
    parser.add_argument("--jobs", type=int, default=1, help="processes (default 1)")
    parser.add_argument("--first-seed", type=int, default=1000)
    parser.add_argument("--emps-only", action="store_true")
    parser.add_argument("--no-emps", action="store_true")
    parser.add_argument("--from-log", type=Path, metavar="FILE",
                        help="print the tables of the cases logged (stderr) by an earlier run, and nothing else")
    parser.add_argument("--emps-decimate", type=int, default=5)
    parser.add_argument("--emps-noise-bound", type=float, default=1e-6, metavar="M")
    args = parser.parse_args()
    if args.from_log is not None:
        tables_from_log(args.from_log)
        return
    if args.effects is not None:
        effects = tuple(e for e in args.effects.split(",") if e)
    else:
        effects = tuple(e for e in TRUE_EFFECTS if args.start == "given" or e != "gain_error")
    if not args.emps_only:
        if effects:
            confusion(args.cases, args.start, effects, args.first_seed, args.jobs)
        rows = tuple(tuple(row.split("+")) for row in args.pairs.split(",") if row)
        if rows:
            pairs(args.cases, args.start, rows, args.first_seed, args.jobs)
    if not args.no_emps:
        emps(args.emps_decimate, args.emps_noise_bound)


if __name__ == "__main__":
    main()
