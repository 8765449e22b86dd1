"""Cost of one model-discrepancy diagnosis against the record length N: wall and CPU seconds of
``diagnose_model`` (the in-process API that ``rig diagnose LOG --model MODEL`` calls) on records of the
hidden-effect generator (:func:`identify.discrepancy_cases.hidden_effect_record`: the precision gearbox's
position loop at 1 kHz, random steps and ramps, a 12-bit encoder plus 0.2 mrad noise), for three cases:

* ``backlash, given``: an output backlash missing from the given nominal model;
* ``backlash, fitted``: the same record without a model (the workflow fits a linear start model);
* ``nothing, given``: nothing missing from the given nominal model.

Every case runs the whole default catalogue. The table gives the verdict, the effects named with their fitted
sizes and, for the backlash, the true half-widths c_l and c_r with the error of the named play's total width
(the backlash's c_l + c_r, or the drive train's play b, which is the total width). The BLAS is held to one
thread (``rig.blas_threads``, as ``rig`` does); set ``OMP_NUM_THREADS=1`` too. The compiled drive-train kernel
is loaded before timing. CPU seconds are this process's (``time.process_time``).

Run: ``OMP_NUM_THREADS=1 nice -n 5 .venv/bin/python benchmarks/diagnosis_speed.py [--sizes 10000 30000 100000]
[--cases given fitted nothing] [--seed 11] [--profile FILE]`` (``--profile``: cProfile every run into FILE.N.case,
read with ``python -m pstats``).
"""

from __future__ import annotations

import argparse
import cProfile
import datetime
import os
import time
from pathlib import Path

import numpy as np

from identify.discrepancy_cases import hidden_effect_record
from identify.drive_train import DriveTrain
from identify.model_discrepancy import diagnose_model
from identify.plant_blocks import OutputBacklash
from rig.blas_threads import limited_blas_threads

CASES = {
    # name: (hidden effects, start from the given nominal model)
    "given": (("backlash",), True),
    "fitted": (("backlash",), False),
    "nothing": ((), True),
}
CASE_LABELS = {"given": "backlash, given", "fitted": "backlash, fitted", "nothing": "nothing, given"}
PLAY_KEYS = {"backlash": ("c_l_rad", "c_r_rad"), "shaft_play": ("play_rad",)}
"""The reported keys whose sum is the total width of a named play."""


def load_average() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def blas_setting() -> str:
    from threadpoolctl import threadpool_info

    threads = sorted({f"{pool['internal_api']} {pool['num_threads']}" for pool in threadpool_info()
                      if pool["user_api"] == "blas"})
    return f"{', '.join(threads)} (threadpoolctl); OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}"


def named_sizes(result) -> str:
    """Every named effect with its fitted parameters (angles in mrad)."""
    parts = []
    for step in result.steps:
        values = ", ".join(f"{key.removesuffix('_rad')} {1e3 * value:.2f}" if key.endswith("_rad")
                           else f"{key} {value:.4g}" for key, value in step.parameters.items())
        parts.append(f"{step.effect} ({values})")
    return "; ".join(parts) or "-"


def play_error(result, truth: OutputBacklash | None) -> str:
    """The named play's total width minus the true c_l + c_r (mrad), or '-'."""
    if truth is None:
        return "-"
    for step in result.steps:
        for effect, keys in PLAY_KEYS.items():
            if effect in step.effect.split("+"):
                width = sum(step.parameters[key] for key in keys)
                return f"{1e3 * (width - truth.c_l_rad - truth.c_r_rad):+.2f}"
    return "no play named"


def run_case(size: int, case: str, seed: int, profile: str | None) -> str:
    effects, given = CASES[case]
    record = hidden_effect_record(effects, seed, num_samples=size)
    truths = record.true_model.find(OutputBacklash)
    truth = truths[0] if truths else None
    profiler = cProfile.Profile() if profile else None
    wall, cpu = time.perf_counter(), time.process_time()
    if profiler:
        profiler.enable()
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            record.nominal_model if given else None)
    if profiler:
        profiler.disable()
        profiler.dump_stats(f"{profile}.{size}.{case}")
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    true_text = "-" if truth is None else f"c_l {1e3 * truth.c_l_rad:.2f}, c_r {1e3 * truth.c_r_rad:.2f}"
    verdict = result.verdict + (f" ({' | '.join(result.ambiguous_between)})" if result.ambiguous_between else "")
    return (f"| {size} | {CASE_LABELS[case]} | {wall:.1f} | {cpu:.1f} | {verdict} | {named_sizes(result)} "
            f"| {true_text} | {play_error(result, truth)} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 30_000, 100_000])
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--seed", type=int, default=11, help="seed of the hidden-effect records")
    parser.add_argument("--profile", metavar="FILE", help="cProfile each run into FILE.N.case")
    args = parser.parse_args()
    with limited_blas_threads(1):
        DriveTrain(sample_period_s=1e-3, gear_ratio=1.0, motor_inertia_kg_m2=1.0, load_inertia_kg_m2=1.0,
                   shaft_stiffness_nm_per_rad=float("inf")).apply(np.zeros(2))  # load the compiled kernel
        print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, seed {args.seed}; "
              f"BLAS threads: {blas_setting()}")
        print(f"load average before: {load_average()}")
        print("| N | case | wall s | CPU s | verdict | named (fitted sizes, mrad) | true backlash (mrad) "
              "| named play width - true c_l + c_r (mrad) |")
        print("|---|---|---|---|---|---|---|---|")
        for size in args.sizes:
            for case in args.cases:
                print(run_case(size, case, args.seed, args.profile), flush=True)
        print(f"load average after: {load_average()}")


if __name__ == "__main__":
    main()
