"""Confusion matrix of the model-discrepancy workflow (issue 6) on hidden-effect records, and a run on the real
EMPS record.

For every effect (and for no effect) ``--cases`` records are simulated with random realistic parameters and a
12-bit encoder (:mod:`identify.discrepancy_cases`); the workflow sees the data, the noise bound and either the
nominal linear model (``--start given``) or nothing (``--start fitted``: it fits its own linear model). The
row is the true effect, the column the first effect named ("none" if nothing, "ambig" when the verdict is
ambiguous: candidates within their uncertainty of each other, none chosen); the gap reduction is
1 - gap_final / gap_initial. Also counted: cases where more effects than the true one were named, and how
many fitted parameters of a rightly named effect have an interval that contains the true value.

Run:  nice -n 10 .venv/bin/python benchmarks/model_discrepancy_confusion.py --cases 20 --start given
      nice -n 10 .venv/bin/python benchmarks/model_discrepancy_confusion.py --cases 5 --start fitted
      nice -n 10 .venv/bin/python benchmarks/model_discrepancy_confusion.py --emps-only
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from identify.discrepancy_cases import hidden_effect_record
from identify.effect_catalogue import EFFECT_NAMES, effect
from identify.model_discrepancy import diagnose_model

TRUE_EFFECTS = ("none", *EFFECT_NAMES)  # every effect of the catalogue
EMPS = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "emps" / "DATA_EMPS.mat"


def confusion(cases: int, start: str, effects: tuple[str, ...], first_seed: int) -> None:
    columns = (*TRUE_EFFECTS, "ambiguous", "other")
    counts = {row: {column: 0 for column in columns} for row in effects}
    reductions: dict[str, list[float]] = {row: [] for row in effects}
    extras = {row: 0 for row in effects}
    covered = {row: [0, 0] for row in effects}  # parameters whose interval holds the truth, parameters
    started = time.perf_counter()
    for row in effects:
        for case in range(cases):
            record = hidden_effect_record(() if row == "none" else (row,), first_seed + case)
            result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad,
                                    record.sample_period_s, record.nominal_model if start == "given" else None)
            named = result.missing_effects[0] if result.missing_effects else (
                "ambiguous" if result.verdict == "ambiguous" else "none")
            counts[row][named if named in counts[row] else "other"] += 1
            extras[row] += len(result.missing_effects) > (0 if row == "none" else 1)
            if row != "none":
                reductions[row].append(1.0 - result.final.gap_rad / result.initial.gap_rad)
            if row != "none" and named == row:
                entry = effect(row)
                truth = entry.report(next(b for b in record.true_model.blocks if isinstance(b, entry.block_class)))
                for key, (low, high) in result.parameter_intervals.get(row, {}).items():
                    covered[row][0] += low <= truth[key] <= high
                    covered[row][1] += 1
    elapsed = time.perf_counter() - started
    short = {name: name[:5] for name in columns} | {"dead_zone": "deadz", "coulomb_friction": "fric", "offset": "offs",
                                                    "gain_error": "gain"}
    print(f"\nstart model: {start}; {cases} cases per row (seeds {first_seed}..{first_seed + cases - 1}); "
          f"{elapsed:.0f} s in all")
    print("| true \\ named | " + " | ".join(short[c] for c in columns)
          + " | correct | more named | median gap reduction | truth in interval |")
    print("|---" * (len(columns) + 5) + "|")
    for row in effects:
        correct = counts[row][row] / cases
        median = f"{100 * np.median(reductions[row]):.1f} %" if reductions[row] else "-"
        print(f"| {row} | " + " | ".join(str(counts[row][c]) for c in columns)
              + f" | {100 * correct:.0f} % | {extras[row]} | {median} | "
              + (f"{covered[row][0]} of {covered[row][1]} |" if covered[row][1] else "- |"))


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
    parser.add_argument("--first-seed", type=int, default=1000)
    parser.add_argument("--emps-only", action="store_true")
    parser.add_argument("--no-emps", action="store_true")
    parser.add_argument("--emps-decimate", type=int, default=5)
    parser.add_argument("--emps-noise-bound", type=float, default=1e-6, metavar="M")
    args = parser.parse_args()
    if args.effects is not None:
        effects = tuple(args.effects.split(","))
    else:
        effects = tuple(e for e in TRUE_EFFECTS if args.start == "given" or e != "gain_error")
    if not args.emps_only:
        confusion(args.cases, args.start, effects, args.first_seed)
    if not args.no_emps:
        emps(args.emps_decimate, args.emps_noise_bound)


if __name__ == "__main__":
    main()
