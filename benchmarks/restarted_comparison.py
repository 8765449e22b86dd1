"""Why a play whose load rattles is judged on restarted windows: the evidence for the restarted comparison's
window (``identify.model_discrepancy.thresholds.RESTART_WINDOW_S``).

For each play record of the clean-room generator (``benchmarks/independent_plants``: a two-mass train with a
30.8 Hz shaft mode behind a 60 Hz servo, a play between motor and load with the generator's own contact law,
1 kHz, 12-bit encoder), the nominal model's drive-train form (the one the workflow uses,
``identify.model_discrepancy.pipeline._restartable_start``) is given plays from 0 to 2 times the generator's and
run against the record: freely, and restarted from the measured angle every W samples
(``identify.model_discrepancy.comparison.restarted_run``). A row gives, per comparison, the play (as a multiple
of the true one) at which the RMS error is least, and that least error as a share of the error without a play.
A comparison that can find the play has its least near 1.00 and well under 100 %.

The drive-train form is not the generator's train (its load's viscous friction and contact law are the fitted
block's and ours), so even the true play does not bring the error to the noise level.

Run:  OMP_NUM_THREADS=1 nice -n 5 .venv/bin/python benchmarks/restarted_comparison.py
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import model_discrepancy_confusion as confusion  # noqa: E402
from identify.model_discrepancy.comparison import restarted_run  # noqa: E402
from identify.model_discrepancy.pipeline import _restartable_start  # noqa: E402
from identify.plant_blocks import PlantModel  # noqa: E402

RECORDS = (("steps", 1000), ("steps", 1004), ("steps", 1008), ("steps", 1012), ("steps", 1016),
           ("prbs", 1011), ("prbs", 1019), ("multisine", 1018), ("chirp", 1001), ("multisine", 1002))
"""The backlash rows' records (seed, excitation as the confusion benchmark draws them): the eight whose free run
left the play open or unnamed before the restarted comparison, then two the free run names."""

WINDOWS = (20, 50, 100, 200)
FACTORS = np.linspace(0.0, 2.0, 41)


def one_record(excitation: str, seed: int) -> dict:
    generator = confusion.generator_module()
    record = generator.generate("backlash", seed, excitation=excitation,
                                duration_s=confusion.INDEPENDENT_DURATION_S[excitation], bits=12,
                                noise_rad=confusion.NOISE_STD_RAD)
    nominal = record["nominal"]
    u = record["command_rad"] - record["command_rad"][0]  # from its operating point, as the workflow runs it
    y = record["angle_rad"] - record["command_rad"][0]
    start = _restartable_start(PlantModel((confusion.nominal_linear_block(nominal),)), u,
                               confusion.independent_noise_bound(nominal))
    train = start.blocks[0]
    play = 2.0 * record["truth"]["parameters"]["half_width_rad"]
    models = [PlantModel((dataclasses.replace(train, play_rad=f * play),)) for f in FACTORS]

    def row(outputs: list[np.ndarray]) -> tuple[float, float]:
        errors = np.array([np.sqrt(np.mean((o - y) ** 2)) for o in outputs])
        best = int(np.argmin(errors))
        return float(FACTORS[best]), float(errors[best] / errors[0])

    result = {"excitation": excitation, "seed": seed, "play_mrad": 1e3 * play,
              "free": row([m.simulate(u) for m in models])}
    for window in WINDOWS:
        result[window] = row([restarted_run(m, u, y, window) for m in models])
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    args = parser.parse_args()
    started = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(one_record, *zip(*RECORDS)))
    print(f"play at the least RMS error (x true play) and that error as a share of the error without a play; "
          f"{time.perf_counter() - started:.0f} s with {args.jobs} process(es)")
    columns = ("free", *WINDOWS)
    print("| record | true play [mrad] | " + " | ".join(
        "free run" if c == "free" else f"restarted every {c}" for c in columns) + " |")
    print("|---" * (2 + len(columns)) + "|")
    for r in results:
        print(f"| {r['excitation']} {r['seed']} | {r['play_mrad']:.2f} | "
              + " | ".join(f"x{r[c][0]:.2f}, {100 * r[c][1]:.0f} %" for c in columns) + " |")
    for c in columns:
        near = sum(abs(r[c][0] - 1.0) <= 0.2 for r in results)
        print(f"{'free run' if c == 'free' else f'restarted every {c}'}: least within 20 % of the true play on "
              f"{near} of {len(results)} records")


if __name__ == "__main__":
    main()
