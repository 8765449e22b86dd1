"""Cost of the drive train: CPU µs per sample of :meth:`DriveTrain.apply`, of stepping and of the pure-Python
recurrence the compiled kernel replaced (``tests/identify/drive_train_reference.py``), and the CPU seconds of
one model-discrepancy diagnosis of a K-Scale STS3215 record (the workflow fits the drive-train candidates, so
the train's recurrence is run many times).

CPU time of this process (``time.process_time``), so the figures depend less on what else the machine
runs than wall-clock figures; still, state the load (``uptime``) with them. The first call of a compiled
kernel (numba, cached on disk after the first run) is made before timing.

Run: ``.venv/bin/python benchmarks/drive_train_speed.py [--record FILE.json] [--no-diagnosis] [--profile]``
(``NUMBA_CACHE_DIR=$(mktemp -d)`` in front: the first call's figure is the compilation).
"""

from __future__ import annotations

import argparse
import cProfile
import math
import pstats
import sys
import time
from pathlib import Path

import numpy as np

from identify.drive_train import DriveTrain
from identify.plant_blocks import LinearBlock

ROOT = Path(__file__).resolve().parents[1]
KSCALE = ROOT / "benchmarks" / "discrepancy_realdata.py"
DEFAULT_RECORD = "sysid_sts3215_sin_sin_2025-03-17_190436.json"  # sin_sin, kp 16, first repetition

TRAINS = {
    # the rigid train the workflow fits (rigid_train_like of a 2 Hz loop at 100 Hz, with friction and gravity)
    "rigid, 100 Hz": DriveTrain(sample_period_s=0.01, gear_ratio=1.0, motor_inertia_kg_m2=0.5, load_inertia_kg_m2=0.5,
                                shaft_stiffness_nm_per_rad=math.inf, position_loop_bandwidth_hz=2.0,
                                position_loop_damping_ratio=0.7, coulomb_friction_nm=0.5, static_friction_nm=0.6,
                                pendulum_mass_kg=1.0, pendulum_length_m=0.5, motor_speed_limit_rad_per_s=5.0),
    # the test suite's compliant 1:10 train with play at 1 kHz (167 Hz shaft mode)
    "compliant with play, 1 kHz": DriveTrain(
        sample_period_s=1e-3, gear_ratio=10.0, motor_inertia_kg_m2=1e-5, load_inertia_kg_m2=1e-2,
        shaft_stiffness_nm_per_rad=200.0, shaft_damping_nm_s_per_rad=0.5, play_rad=0.01, position_loop_bandwidth_hz=5.0,
        position_loop_damping_ratio=1.0, coulomb_friction_nm=0.05, static_friction_nm=0.08, pendulum_mass_kg=0.5,
        pendulum_length_m=0.1),
    # a two-mass train with the clean-room generator's shaft (150 N m/rad, 0.004 kg m^2 load, 30.8 Hz mode)
    # behind a 60 Hz loop at 1 kHz, without and with dry friction inside the shaft (0.19 N m, presliding
    # twist 1.7 mrad: its peak stiffness is 2.5 k, under the velocity loop's rate, which sets the sub-steps)
    "two-mass, 1 kHz": DriveTrain(
        sample_period_s=1e-3, gear_ratio=1.0, motor_inertia_kg_m2=0.002, load_inertia_kg_m2=0.004,
        shaft_stiffness_nm_per_rad=150.0, shaft_damping_nm_s_per_rad=0.0775, position_loop_bandwidth_hz=60.0),
    "two-mass with shaft friction, 1 kHz": DriveTrain(
        sample_period_s=1e-3, gear_ratio=1.0, motor_inertia_kg_m2=0.002, load_inertia_kg_m2=0.004,
        shaft_stiffness_nm_per_rad=150.0, shaft_damping_nm_s_per_rad=0.0775, position_loop_bandwidth_hz=60.0,
        shaft_friction_nm=0.19, shaft_presliding_twist_rad=1.7e-3),
    # for comparison: the order-2 linear block a fitted start model has
    "linear block (order 2)": LinearBlock(a=(-1.6, 0.64), b=(0.0, 0.02, 0.02), sample_period_s=0.01),
}


def _cpu_us_per_sample(run, samples: int) -> float:
    run()  # the first call compiles (or loads the cache)
    repeats, elapsed = 0, 0.0
    while elapsed < 1.0:
        started = time.process_time()
        run()
        elapsed += time.process_time() - started
        repeats += 1
    return 1e6 * elapsed / (repeats * samples)


def first_call_cpu_s() -> float:
    """CPU seconds of the first ``apply`` in this process: numba compiles the kernel (an empty cache, e.g. a
    fresh ``NUMBA_CACHE_DIR``) or loads it from its cache."""
    train = TRAINS["compliant with play, 1 kHz"]
    started = time.process_time()
    train.apply(np.zeros(10))
    return time.process_time() - started


def stepper_table() -> None:
    sys.path.insert(0, str(ROOT / "tests" / "identify"))
    from drive_train_reference import reference_load_angle_rad  # the recurrence before it was compiled

    uptime = Path("/proc/loadavg").read_text().split()[:3]
    print(f"load average {' '.join(uptime)}")
    print(f"first call of the compiled kernel: {first_call_cpu_s():.2f} CPU s")
    print("| train | sub-steps per sample | apply [CPU µs/sample] | step [CPU µs/sample] "
          "| pure-Python recurrence [CPU µs/sample] |")
    print("|---|---|---|---|---|")
    for name, train in TRAINS.items():
        command = 0.5 * np.sin(np.linspace(0.0, 20.0, 2000)) + np.where(np.arange(2000) % 400 < 200, 0.3, -0.3)

        def stepped(train=train, command=command):
            step = train.stepper().step
            for r in command:
                step(r)

        substeps = train.substeps_per_sample if isinstance(train, DriveTrain) else "-"
        pure_python = "-"  # the reference predates the shaft's friction: it has no figure for such a train
        if isinstance(train, DriveTrain) and train.shaft_friction_nm == 0.0:
            pure_python = f"{_cpu_us_per_sample(lambda: reference_load_angle_rad(train, command), 2000):.3g}"
        print(f"| {name} | {substeps} | {_cpu_us_per_sample(lambda: train.apply(command), 2000):.3g} "
              f"| {_cpu_us_per_sample(stepped, 2000):.3g} | {pure_python} |")


def diagnosis(record: str, profile: bool) -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("discrepancy_realdata", KSCALE)
    realdata = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(realdata)
    path = realdata.KSCALE / record
    noise_bound_rad = 1.5 * realdata.COUNT_RAD
    profiler = cProfile.Profile() if profile else None
    started = time.process_time()
    if profiler:
        profiler.enable()
    run = realdata.diagnose_one(str(path), noise_bound_rad)
    if profiler:
        profiler.disable()
    cpu_s = time.process_time() - started
    named = "+".join(run["effects"]) or "-"
    print(f"\n{record}: verdict {run['verdict']} {named}, gap {1e3 * run['gap_initial']:.3g} -> "
          f"{1e3 * run['gap_final']:.3g} mrad; {cpu_s:.1f} CPU s")
    if profiler:
        pstats.Stats(profiler).sort_stats("tottime").print_stats(12)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", default=DEFAULT_RECORD, help="a file of ../shared/realdata/kscale_sts3215")
    parser.add_argument("--no-diagnosis", action="store_true", help="only the stepper table")
    parser.add_argument("--profile", action="store_true", help="cProfile the diagnosis (its top 12 by own time)")
    args = parser.parse_args()
    stepper_table()
    if not args.no_diagnosis:
        diagnosis(args.record, args.profile)


if __name__ == "__main__":
    main()
