"""FMU plants: time per sample of an FMU stepped as a plant block, for the interfaces and
FMI versions :mod:`sim_backend.fmu_plant` runs, and the time of ``rig diagnose --model x.fmu`` with an
effect hidden around the FMU.

Run:  nice -n 10 .venv/bin/python benchmarks/fmu_plant_throughput.py [--samples N] [--repeats R] [FMU ...]

Without FMU arguments it builds the test FMUs of ``tests/fmu_models`` (pythonfmu's Python servo, and the C
servo compiled with gcc as FMI 2.0 and 3.0, co-simulation and model exchange). A simulated rig steps its
plant once per SYNC in the device's thread: a plant whose step takes longer than the period cannot keep a
1 kHz rig (the step time must stay well under 1000 us).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PERIOD_S = 1e-3


def test_fmus(folder: Path) -> list[tuple[str, Path]]:
    sys.path.insert(0, str(ROOT / "tests"))
    from fmu_models.build import build_c_servo, build_python_fmu

    fmus = [("pythonfmu servo, FMI 2.0 CS", build_python_fmu("gearbox_servo", folder))]
    for version in ("2.0", "3.0"):
        for interface, short in (("CoSimulation", "CS"), ("ModelExchange", "ME")):
            fmus.append((f"C servo, FMI {version} {short}", build_c_servo(folder, version, (interface,))))
    return fmus


def step_times(path: Path, samples: int, repeats: int) -> tuple[float, float, float]:
    """Median and worst microseconds per sample of stepping, over ``repeats`` runs, and the seconds to open."""
    from sim_backend.fmu_plant import open_fmu_block

    started = time.perf_counter()
    block = open_fmu_block(path, PERIOD_S)
    opened = time.perf_counter() - started
    command = np.sin(np.linspace(0.0, 20.0, samples))
    per_sample = []
    for _ in range(repeats):
        stepper = block.stepper()
        started = time.perf_counter()
        for x in command.tolist():
            stepper.step(x)
        per_sample.append((time.perf_counter() - started) / samples * 1e6)
        stepper.close()
    return float(np.median(per_sample)), float(np.max(per_sample)), opened


def diagnose_time(path: Path) -> tuple[float, str]:
    """Seconds of ``diagnose_model`` on a dead zone hidden before the FMU (the test record of
    tests/rig/test_diagnose_fmu.py, 1 140 samples at 100 Hz) and what it named."""
    from identify.model_discrepancy import diagnose_model
    from identify.plant_blocks import DeadZone, PlantModel
    from rig.protocols.encoder_counts import EncoderResolution
    from sim_backend.fmu_plant import open_fmu_block

    period = 0.01
    levels = [0.3, -0.5, 0.9, -0.2, 0.6, -0.8, 0.15, -0.4, 0.7, -0.65, 0.25, -0.9, 0.5, -0.3, 0.8, -0.15]
    steps = np.concatenate([np.zeros(20), *(np.full(70, level) for level in levels)])
    command = np.convolve(steps, np.ones(8) / 8)[: steps.size]
    block = open_fmu_block(path, period)
    encoder = EncoderResolution(bits=12, signed=True)
    angle = encoder.rad_from_counts(encoder.counts_from_rad(PlantModel((DeadZone(-0.06, 0.08), block)).simulate(command)))
    started = time.perf_counter()
    result = diagnose_model(command, np.asarray(angle, dtype=float), encoder.quantization_bound_rad + 2e-5, period,
                            PlantModel((block,)))
    return time.perf_counter() - started, f"{result.verdict}: {', '.join(result.missing_effects) or '-'}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fmus", nargs="*", type=Path, help="FMUs to time (default: the test FMUs, built here)")
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"host: {platform.processor() or platform.machine()}, Python {platform.python_version()}, "
          f"load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as folder:
        fmus = [(path.name, path) for path in args.fmus] if args.fmus else test_fmus(Path(folder))
        print(f"\nstepping, {args.samples} samples x {args.repeats} runs (period {PERIOD_S * 1e3:g} ms)")
        print(f"{'FMU':<30} {'median us/sample':>17} {'worst':>8} {'open s':>8}")
        for name, path in fmus:
            median, worst, opened = step_times(path, args.samples, args.repeats)
            print(f"{name:<30} {median:>17.1f} {worst:>8.1f} {opened:>8.3f}")
        print("\nrig diagnose on a dead zone hidden before the FMU (1140 samples, every effect around it)")
        print(f"{'FMU':<30} {'seconds':>8}  result")
        for name, path in fmus:
            if "ME" in name.split()[-1:]:  # model exchange: CVode through Python callbacks, about 0.4 ms a sample
                continue
            seconds, named = diagnose_time(path)
            print(f"{name:<30} {seconds:>8.1f}  {named}")
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
