"""Look-alike effects on the clean-room generator: what the discrepancy workflow says about a sensor error that
looks like a load torque (encoder eccentricity against gravity), a sensor that wraps at +-pi, and the records
it should leave alone or name rightly (none, gravity, coulomb), seed by seed.

The records come from ``benchmarks/independent_plants/drive_train_generator.py`` (data source only: its physics
is not changed here). The workflow gets the record, the generator's nominal model as an exact zero-order-hold
linear block (:func:`nominal_linear_block`), a noise bound of half a count plus 4.5 standard deviations of the
generator's Gaussian noise, and the sample period: the protocol of ``model_discrepancy_confusion.py
--generator independent``. The excitation rotates with the seed through steps, chirp, multisine and prbs
(3-5 s at 1 kHz, 12-bit encoder, noise std 1e-4 rad); ``wrap`` records take steps (the others rarely cross
+-pi), and a seed whose effect the generator says is not excited is replaced by the next.

Run:  OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python benchmarks/discrepancy_lookalikes.py --seeds 10 --jobs 2
      [--effects eccentricity,wrap,gravity,none,coulomb] [--first-seed 2000]
Each case prints a line (effect, seed, excitation, verdict, named, ambiguous_between, findings); then a count
table per effect.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

from identify.model_discrepancy import diagnose_model
from identify.plant_blocks import PlantModel

# the protocol of the confusion benchmark's independent rows: one definition of the record, model and bound
from model_discrepancy_confusion import INDEPENDENT_DURATION_S as DURATION_S
from model_discrepancy_confusion import INDEPENDENT_EXCITATIONS as EXCITATIONS
from model_discrepancy_confusion import NOISE_STD_RAD, generator_module, nominal_linear_block
from model_discrepancy_confusion import independent_noise_bound as noise_bound

EFFECTS = ("eccentricity", "wrap", "gravity", "none", "coulomb")


def record_for(effect: str, seed: int, max_draws: int = 40, setting: dict | None = None) -> tuple[dict, int, str]:
    """The first excited record from ``seed`` on (the seed, the excitation); ``setting`` may fix the
    excitation, its amplitude, the duration and the encoder bits."""
    generator = generator_module()
    setting = setting or {}
    for draw in range(max_draws):
        s = seed + 1000 * draw
        excitation = setting.get("excitation") or ("steps" if effect == "wrap" else EXCITATIONS[s % len(EXCITATIONS)])
        record = generator.generate(effect, s, excitation=excitation,
                                    duration_s=setting.get("duration_s") or DURATION_S[excitation],
                                    bits=setting.get("bits") or 12, noise_rad=NOISE_STD_RAD,
                                    amplitude_rad=setting.get("amplitude_rad"))
        if effect == "none" or record["truth"]["excited"]:
            return record, s, excitation
    raise RuntimeError(f"{effect}: no excited record from seed {seed}")


def run_case(effect: str, seed: int, setting: dict | None = None) -> dict:
    record, s, excitation = record_for(effect, seed, setting=setting)
    nominal = record["nominal"]
    started = time.perf_counter()
    result = diagnose_model(record["command_rad"], record["angle_rad"], noise_bound(nominal),
                            float(nominal["sample_period_s"]), PlantModel((nominal_linear_block(nominal),)))
    return {"effect": effect, "seed": s, "excitation": excitation, "verdict": result.verdict,
            "named": list(result.missing_effects), "ambiguous_between": list(result.ambiguous_between),
            "findings": [f.text()[:120] for f in getattr(result, "findings", ())],
            "reason": result.verdict_reason[:300], "seconds": round(time.perf_counter() - started, 1)}


def label(case: dict) -> str:
    if case["verdict"] == "ambiguous":
        between = "|".join(case["ambiguous_between"]) or "-"
        return f"ambiguous({'+'.join(case['named']) + ' then ' if case['named'] else ''}{between})"
    if case["named"]:
        return f"{case['verdict']}({'+'.join(case['named'])})"
    return case["verdict"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=2000)
    parser.add_argument("--effects", default=",".join(EFFECTS))
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--excitation", default=None, help="one excitation for every record (default: rotate)")
    parser.add_argument("--amplitude", type=float, default=None, metavar="RAD")
    parser.add_argument("--duration", type=float, default=None, metavar="S")
    parser.add_argument("--bits", type=int, default=None)
    args = parser.parse_args()
    setting = {"excitation": args.excitation, "amplitude_rad": args.amplitude, "duration_s": args.duration,
               "bits": args.bits}
    effects = tuple(e for e in args.effects.split(",") if e)
    started = time.perf_counter()
    runs: dict[str, list[dict]] = {e: [] for e in effects}
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = [pool.submit(run_case, e, args.first_seed + i, setting) for e in effects for i in range(args.seeds)]
        for future in as_completed(futures):
            case = future.result()
            runs[case["effect"]].append(case)
            print(json.dumps(case), file=sys.stderr, flush=True)
    print(f"{args.seeds} seeds per effect from {args.first_seed}, setting {setting}; "
          f"{time.perf_counter() - started:.0f} s")
    for effect in effects:
        counts: dict[str, int] = {}
        for case in runs[effect]:
            counts[label(case)] = counts.get(label(case), 0) + 1
        print(f"| {effect} | " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1])) + " |")


if __name__ == "__main__":
    main()
