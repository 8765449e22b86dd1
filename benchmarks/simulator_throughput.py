"""Simulator throughput: samples per second of the seed-000 plant (Cerone et al. 2009, Section 6) with every
effect switched on, for the whole-array path (``simulate``) and the per-sample path (``step``) that the
simulated devices tick once per SYNC or frame.

Run:  nice -n 10 .venv/bin/python benchmarks/simulator_throughput.py [--samples N] [--repeats R]

The target is "well above 100 kHz" for ``simulate`` so that the simulator is never the bottleneck of a
1-2 kHz loop; a simulated device needs only the loop rate from ``step``.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from identify.plant_blocks import (
    CoulombFriction,
    DeadZone,
    Delay,
    InputBacklash,
    LinearBlock,
    OutputBacklash,
    OutputOffset,
    PiecewiseLinearBorder,
    PlantModel,
    Resonance,
    Saturation,
)
from rig.protocols.encoder_counts import EncoderResolution
from sim_backend.noise import BoundedUniformNoise, ColouredNoise
from sim_backend.plant import SimulatedGearbox

PERIOD_S = 1e-3


def all_effects_plant() -> PlantModel:
    """Seed 000's linear block and output backlash with every other effect of the simulator in series."""
    play = PiecewiseLinearBorder((-10.0, 10.0), (-10.002, 9.998))
    return PlantModel((
        Saturation(-2.5, 2.5),
        DeadZone(-0.001, 0.001),
        InputBacklash(play, PiecewiseLinearBorder((-10.0, 10.0), (-9.998, 10.002))),
        Delay(2),
        LinearBlock(a=(0.5, 0.7), b=(0.0, 1.4, 0.8), sample_period_s=PERIOD_S),
        Resonance(frequency_hz=120.0, damping_ratio=0.03, sample_period_s=PERIOD_S),
        OutputBacklash(m_l=0.248, c_l_rad=0.0698, m_r=0.252, c_r_rad=0.0349),
        CoulombFriction(breakaway_torque_nm=0.3, coulomb_torque_nm=0.2, stiffness_nm_per_rad=2000.0),
        OutputOffset(offset_rad=0.002, drift_rad_per_s=1e-5, sample_period_s=PERIOD_S),
    ))


def best_rate(function, num_samples: int, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return num_samples / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    n, step_n = args.samples, min(args.samples, 50_000)
    u = np.random.default_rng(0).choice([-1.0, 1.0], size=n)  # PRBS-like +-1, as in Section 6
    plant = all_effects_plant()
    encoder = EncoderResolution(bits=12, signed=True)
    uniform = SimulatedGearbox(plant, encoder, BoundedUniformNoise(np.pi / 4096), seed=1)
    coloured = SimulatedGearbox(plant, encoder, ColouredNoise(std_rad=1e-3), seed=1)

    def step_plant() -> None:
        stepper = plant.stepper()
        for value in u[:step_n].tolist():
            stepper.step(value)

    def step_gearbox() -> None:
        uniform.reset()
        for value in u[:step_n].tolist():
            uniform.step(value)

    rows = [
        ("PlantModel.simulate (9 blocks)", n, best_rate(lambda: plant.simulate(u), n, args.repeats)),
        ("SimulatedGearbox.simulate, uniform noise + 12-bit encoder", n,
         best_rate(lambda: uniform.simulate(u), n, args.repeats)),
        ("SimulatedGearbox.simulate, coloured noise + 12-bit encoder", n,
         best_rate(lambda: coloured.simulate(u), n, args.repeats)),
        ("PlantModel.stepper().step, per sample", step_n, best_rate(step_plant, step_n, args.repeats)),
        ("SimulatedGearbox.step, per sample (noise + encoder)", step_n, best_rate(step_gearbox, step_n, args.repeats)),
    ]
    print(f"# simulator throughput, seed-000 plant with all effects on ({platform.python_implementation()} "
          f"{platform.python_version()}, numpy {np.__version__}, {platform.machine()})")
    print("| path | samples | samples/s |")
    print("|---|---:|---:|")
    for name, samples, rate in rows:
        print(f"| {name} | {samples} | {rate:,.0f} |")


if __name__ == "__main__":
    main()
