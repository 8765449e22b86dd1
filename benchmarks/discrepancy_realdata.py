"""Repeatability of the model-discrepancy workflow on real records.

The K-Scale STS3215 servo records (``../shared/realdata/kscale_sts3215``: 5 trajectories x 3 position-loop
gains x 4 repetitions of the same experiment) are read as ``rig diagnose`` reads them
(``--columns t=timestamp,u=goal_position,y=position --valid torque_enable``: spikes replaced, jitter
resampled) and diagnosed from a fitted linear start model with one noise bound for all (default 1.5 counts
of the 4096-count encoder). Per configuration the table gives the four verdicts, the named effects, the
parameter intervals and whether the four agree: same verdict and same named effects, and for every named
parameter intervals that overlap (all four share a point). The agreement rate is the share of
configurations where they do (goal 100 %). With ``--drive-torque KEY`` the workflow also gets the servo's
reported torque under that key (``torque`` or ``current``: ``--columns ...,tau=KEY``), and each record whose
angle left a weight open beside a sensor error says what the torque showed. Then the EMPS record, as in
``model_discrepancy_confusion.py``.

Run: ``.venv/bin/python benchmarks/discrepancy_realdata.py [--jobs 2] [--trajectories sin_sin,sin_time_square]
[--drive-torque torque]``.
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

def _realdata() -> Path:
    """``shared/realdata`` next to the checkout (or next to any folder above it: a git worktree sits one
    level deeper); ``RIG_REALDATA_DIR`` overrides."""
    import os

    if os.environ.get("RIG_REALDATA_DIR"):
        return Path(os.environ["RIG_REALDATA_DIR"])
    for parent in Path(__file__).resolve().parents:
        if (parent / "shared" / "realdata").is_dir():
            return parent / "shared" / "realdata"
    return Path(__file__).resolve().parents[2] / "shared" / "realdata"


REALDATA = _realdata()
KSCALE = REALDATA / "kscale_sts3215"
COUNT_RAD = 2.0 * math.pi / 4096


def diagnose_one(path: str, noise_bound_rad: float, torque_key: str | None = None) -> dict:
    from identify.model_discrepancy import diagnose_model
    from rig.record_import import ImportOptions, read_measurement

    columns = {"t": "timestamp", "u": "goal_position", "y": "position"}
    if torque_key is not None:
        columns["tau"] = torque_key
    record, imported = read_measurement(path, ImportOptions(columns=columns, valid="torque_enable"))
    started = time.process_time()
    result = diagnose_model(record.command_rad, record.angle_rad, noise_bound_rad, record.metadata.sample_period_s,
                            drive_torque=record.drive_torque)
    document = result.to_dict()
    return {"file": Path(path).name, "verdict": result.verdict, "reason": result.verdict_reason,
            "effects": tuple(result.missing_effects), "ambiguous": tuple(result.ambiguous_between),
            "intervals": {effect: dict(values) for effect, values in result.parameter_intervals.items()},
            "gap_initial": document["gap_initial"], "gap_final": document["gap_final"],
            "falsified_final": document["falsified_fraction_final"], "spikes": imported.spikes,
            "undecided": tuple((c.effect, c.reduction, *c.reduction_interval) for c in result.undecided),
            "samples": int(record.command_rad.size), "cpu_s": time.process_time() - started,
            "torque_check": None if result.load_torque_check is None else result.load_torque_check.text()}


def _overlap(intervals: list[tuple[float, float]]) -> bool:
    return max(low for low, _ in intervals) <= min(high for _, high in intervals)


def answer(run: dict) -> str:
    """The named effects, then the ambiguous ones (``a|b``) if the verdict is ambiguous: ``rate_limit; ? gravity``."""
    named = "+".join(run["effects"])
    ambiguous = "|".join(run["ambiguous"])
    return (named + (f"; ? {ambiguous}" if ambiguous else "")).strip("; ") or "-"


def agree(runs: list[dict]) -> tuple[bool, str]:
    """Repeatability: the repetitions agree on the verdict and the named effects, and the intervals of every
    named parameter overlap.
    (Which candidates an ambiguous verdict lists is not a named effect: :func:`same_contenders` says whether
    those agree too.)"""
    verdicts = {run["verdict"] for run in runs}
    if len(verdicts) > 1:
        return False, "verdicts differ"
    if len({run["effects"] for run in runs}) > 1:
        return False, "named effects differ"
    for effect in runs[0]["effects"]:
        for key in runs[0]["intervals"].get(effect, {}):
            if not _overlap([tuple(run["intervals"][effect][key]) for run in runs]):
                return False, f"{effect} {key} intervals do not overlap"
    return True, ""


def same_contenders(runs: list[dict]) -> bool:
    """The stricter reading: the ambiguous candidates listed are the same set in every repetition too."""
    return len({frozenset(run["ambiguous"]) for run in runs}) == 1


def kscale(noise_bound_rad: float, jobs: int, trajectories: set[str] | None = None,
           torque_key: str | None = None) -> None:
    with (KSCALE / "index.csv").open() as handle:
        rows = [row for row in csv.DictReader(handle) if trajectories is None or row["trajectory"] in trajectories]
    started = time.perf_counter()
    runs = []
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for row, run in zip(rows, pool.map(diagnose_one, [str(KSCALE / row["file"]) for row in rows],
                                           [noise_bound_rad] * len(rows), [torque_key] * len(rows))):
            runs.append(run)  # one line per record as it is done (a long run can be read while it goes on)
            print(f"  {row['trajectory']} kp {row['kp']} {run['file']}: {run['verdict']} "
                  f"{answer(run)} ({run['cpu_s']:.1f} s CPU)"
                  + "".join(f"; {name} {100 * r:.0f} % [{100 * low:.0f}, {100 * high:.0f}]"
                            for name, r, low, high in run["undecided"])
                  + (f"; the drive's torque: {run['torque_check']}" if run["torque_check"] else ""), flush=True)
    elapsed = time.perf_counter() - started
    cpu = [run["cpu_s"] for run in runs]
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for row, run in zip(rows, runs):
        groups[(row["trajectory"], row["kp"])].append(run)
    print(f"\nK-Scale STS3215: {len(runs)} records, noise bound {noise_bound_rad:.4g} rad "
          f"({noise_bound_rad / COUNT_RAD:.2g} counts), fitted linear start model"
          + (f", with the servo's {torque_key!r} as the drive's torque" if torque_key else "") + f"; {elapsed:.0f} s with {jobs} "
          f"process(es); CPU per record {min(cpu):.1f}-{max(cpu):.1f} s, {sum(cpu):.0f} s in all")
    print("| trajectory | kp | verdicts (4 repetitions) | named; ? ambiguous | parameter intervals | "
          "gap initial -> final [mrad] | spikes | agree | same ambiguous set |")
    print("|---|---|---|---|---|---|---|---|---|")
    agreed = strict = 0
    reasons: dict[str, str] = {}
    for (trajectory, kp), group in groups.items():
        ok, why = agree(group)
        agreed += ok
        strict += ok and same_contenders(group)
        verdicts = " / ".join(run["verdict"] for run in group)
        named = " / ".join(answer(run) for run in group)
        intervals = "; ".join(
            f"{effect} {key} " + " ".join(f"[{low:.3g}, {high:.3g}]" for low, high in
                                          (run["intervals"][effect][key] for run in group))
            for effect in group[0]["effects"] for key in group[0]["intervals"].get(effect, {})
        ) if ok and group[0]["effects"] else "-"
        gaps = " / ".join(f"{1e3 * run['gap_initial']:.3g}->{1e3 * run['gap_final']:.3g}" for run in group)
        spikes = sum(run["spikes"] for run in group)
        print(f"| {trajectory} | {kp} | {verdicts} | {named} | {intervals} | {gaps} | {spikes} | "
              f"{'yes' if ok else 'no: ' + why} | {'yes' if same_contenders(group) else 'no'} |")
        reasons.setdefault(group[0]["verdict"], f"{trajectory} kp {kp}: {group[0]['reason']}")
    print(f"\nagreement: {agreed} of {len(groups)} configurations ({100 * agreed / len(groups):.0f} %); with the same "
          f"ambiguous candidates too: {strict} of {len(groups)}")
    print("one reason per verdict, in the workflow's words:")
    for verdict, reason in reasons.items():
        print(f"- {verdict}: {reason}")


def emps(decimate: int, noise_bound_m: float) -> None:
    from scipy.io import loadmat

    from identify.model_discrepancy import diagnose_model

    path = REALDATA / "emps" / "DATA_EMPS.mat"
    if not path.is_file():
        print(f"\nEMPS: {path} not found, skipped")
        return
    data = loadmat(path)
    t = np.ravel(data["t"])[::decimate]
    reference, measured = np.ravel(data["qg"])[::decimate], np.ravel(data["qm"])[::decimate]
    period = float(np.median(np.diff(t)))
    started = time.perf_counter()
    result = diagnose_model(reference, measured, noise_bound_m, period)
    print(f"\nEMPS DATA_EMPS.mat: qg -> qm, every {decimate}th sample ({reference.size} samples), noise bound "
          f"{noise_bound_m:g} m; {time.perf_counter() - started:.0f} s")
    print(f"verdict {result.verdict}: {result.verdict_reason}")
    for step in result.steps:
        intervals = result.parameter_intervals.get(step.effect, {})
        print(f"  {step.effect}: " + ", ".join(
            f"{k} = {v:.4g} [{intervals[k][0]:.4g}, {intervals[k][1]:.4g}]" if k in intervals else f"{k} = {v:.4g}"
            for k, v in step.parameters.items()))
    if result.gap_reduction:
        print(f"  gap {result.initial.gap_rad:.4g} -> {result.final.gap_rad:.4g} m "
              f"({100 * result.gap_reduction_fraction:.1f} % smaller; folds {100 * result.gap_reduction['low']:.1f} .. "
              f"{100 * result.gap_reduction['high']:.1f} %)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--noise-bound-counts", type=float, default=1.5,
                        help="noise bound in counts of the 4096-count encoder (default 1.5: the half count of "
                             "quantisation plus one count of reading noise)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--trajectories", default=None,
                        help="only these trajectories, comma-separated (default: all five)")
    parser.add_argument("--drive-torque", default=None, metavar="KEY",
                        help="also give the workflow the servo's torque under this record key (torque or current)")
    parser.add_argument("--no-emps", action="store_true")
    parser.add_argument("--emps-decimate", type=int, default=5)
    parser.add_argument("--emps-noise-bound", type=float, default=1e-6, metavar="M")
    args = parser.parse_args()
    if not KSCALE.is_dir():
        print(f"{KSCALE} not found")
    else:
        kscale(args.noise_bound_counts * COUNT_RAD, args.jobs,
               set(args.trajectories.split(",")) if args.trajectories else None, args.drive_torque)
    if not args.no_emps:
        emps(args.emps_decimate, args.emps_noise_bound)


if __name__ == "__main__":
    main()
