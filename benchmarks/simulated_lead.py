"""The simulated serial rig's lead: held samples of a staircase for each ``lead_s`` of ``configs/sim_serial.toml``.

The simulated serial device of ``rig demo`` and ``rig run configs/sim_serial.toml`` runs in the driver's
process: a host starved by other programs starves the device's threads too, and when they fall behind, every
setpoint can arrive after its tick (HELD to the end of the run). The lead (``lead_s``, how far ahead of the
device's ticks the setpoints are queued) is what covers such a pause. Each run streams the demo's quick
staircase (:data:`rig.demo_outcome.QUICK_PLAN`: 5 amplitudes from 1 to 4 rad, 300 samples a half-wave, 3000
samples at 1 kHz, filtered with the demo's reference pole 0.95) from rest through
:class:`rig.demo.SimulatedRigSession`, as ``rig demo --transport serial`` streams it, once per run (no repeat
of a failed run), with the rig's config but ``lead_s`` set to each value; then the same staircase on the
simulated CANopen rig (``configs/sim_canopen.toml`` as shipped), for comparison.

Per row: the held samples of each run, the smallest lead of a setpoint over its tick (negative: the setpoints
arrived that long after their ticks), lost samples, and the load average (1 min) when the row ended. The
effect shows only on a loaded host: ``--hog N`` runs N CPU-bound processes beside the runs. Usage::

    python benchmarks/simulated_lead.py --runs 3 --hog 4
    python benchmarks/simulated_lead.py --runs 3 --leads 0.25 1.0
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from identify.excitation_design import filtered_staircase  # noqa: E402
from rig.demo import SimulatedRigSession  # noqa: E402
from rig.demo_outcome import QUICK_PLAN  # noqa: E402
from rig.protocols.errors import TransportError  # noqa: E402
from transport_timing import cpu_hogs  # noqa: E402


def staircase() -> np.ndarray:
    """The demo's quick staircase: 3000 samples (5 amplitudes x 2 half-waves x 300)."""
    return filtered_staircase(list(QUICK_PLAN.staircase_amplitudes_rad), QUICK_PLAN.reference_pole,
                              QUICK_PLAN.samples_per_half_wave)


def run_once(wire: str, command_rad: np.ndarray, lead_s: float | None) -> dict[str, object]:
    """One staircase from rest on the simulated ``wire`` rig (``lead_s`` None: the config's)."""
    session = SimulatedRigSession(wire, None)
    if lead_s is not None:
        session.config = replace(session.config, options={**session.config.options, "lead_s": lead_s})
    session.max_attempts = 1
    try:
        session.run("staircase", command_rad, keep_log=False, max_lost=command_rad.size, kind="filtered_staircase")
    except TransportError as err:
        return {"failed": str(err)}
    run = session.runs["staircase"]
    return {"held": run.held, "lost": run.lost, "lead_s": run.lead_s, "min_lead_s": run.min_lead_s}


def _cells(runs: list[dict[str, object]], key: str, form: str) -> str:
    return ", ".join("link failed" if "failed" in run else format(run[key], form) for run in runs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--leads", type=float, nargs="+", default=[0.25, 1.0],
                        help="lead_s values of the serial rig (default: 0.25, the transport's default, and 1.0, "
                             "configs/sim_serial.toml's)")
    parser.add_argument("--runs", type=int, default=3, help="staircases per row (default 3)")
    parser.add_argument("--hog", type=int, default=0, metavar="N",
                        help="CPU-bound processes (a busy loop each) beside the runs (default 0)")
    parser.add_argument("--no-canopen", action="store_true", help="leave out the CANopen row")
    args = parser.parse_args()
    command = staircase()
    rows = [("serial", lead) for lead in args.leads] + ([] if args.no_canopen else [("canopen", None)])
    blas = {name: os.environ.get(name) for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    print(f"# staircase of {command.size} samples at 1 kHz, {args.runs} runs a row, {args.hog} CPU hogs, "
          f"Python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.2f} at the start, BLAS threads {blas}")
    print("| wire | lead_s | held samples, per run | min lead s, per run | lost, per run | load avg at the end |")
    print("|---|---|---|---|---|---|")
    with cpu_hogs(args.hog):
        for wire, lead in rows:
            runs = [run_once(wire, command, lead) for _ in range(args.runs)]
            leads = {run["lead_s"] for run in runs if "lead_s" in run}
            lead_cell = ", ".join(f"{value:g}" for value in sorted(leads)) or "-"
            print(f"| {wire} | {lead_cell} | {_cells(runs, 'held', 'd')} | {_cells(runs, 'min_lead_s', '.2f')} "
                  f"| {_cells(runs, 'lost', 'd')} | {os.getloadavg()[0]:.2f} |", flush=True)
            for run in runs:
                if "failed" in run:
                    print(f"  {wire}: {run['failed']}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
