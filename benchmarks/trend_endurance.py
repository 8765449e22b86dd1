"""Endurance trend: an hour of a wearing gearbox at 1 kHz, bounded window by window by ``rig trend``.

The record is made on the simulated clock (``rig simulate --duration``: as fast as the computer runs the
plant, not in real time) from ``configs/plants/wearing_gearbox.toml`` (the plant of Cerone, Piga, Regruto
2009, Section 6, whose play grows with wear) driven by the repeated ``steady_staircase`` experiment; the
simulation also writes the truth file of the play. Then ``rig trend LOG --window 60s`` bounds the play in
each minute on the local cores (``--jobs``) and the script counts the windows whose bounds hold every value
the true play took in them.

The wear allowance: the law grows each half-width by k = 2e-6 rad per rad of output travel, and the staircase
drives each flank about 4.5 rad per second, so a half-width wears about 5.4e-4 rad per minute; times the
largest slope 0.252 that moves a steady output by 1.4e-4 rad. ``--wear-allowance 2e-4`` covers it with a
margin (identify/backlash_trend.py says why this keeps every value of the play inside its window's bounds).

Thread settings: ``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS`` and ``MKL_NUM_THREADS`` are set to 1 in the
environment of ``rig trend``, so each of its worker processes (which inherit it) runs one thread.

Run:  nice -n 10 .venv/bin/python benchmarks/trend_endurance.py [--duration 3600] [--jobs 2] [--keep DIR]

Goal: the trend of an hour in under 2 minutes of wall time on 2 cores.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLANT = ROOT / "configs" / "plants" / "wearing_gearbox.toml"
EXCITATION = ROOT / "configs" / "experiments" / "steady_staircase.toml"
WEAR_ALLOWANCE_RAD = 2e-4
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _rig(*arguments: str, env: dict[str, str]) -> tuple[float, float, str, str]:
    """Run ``rig -v ARGUMENTS`` in a process of its own; (wall seconds, CPU seconds of it and its worker
    processes, stdout, stderr). A failure stops the script."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "rig.cli", "-v", *arguments], env=env, capture_output=True,
                          text=True)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if done.returncode not in (0, 4):
        sys.exit(f"rig {' '.join(arguments)} failed with exit code {done.returncode}:\n{done.stderr}")
    return wall, cpu, done.stdout, done.stderr


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=3600.0, help="seconds of simulated record (default 3600)")
    parser.add_argument("--window", default="60s", help="rig trend --window (default 60s)")
    parser.add_argument("--jobs", type=int, default=2, help="rig trend --jobs (default 2)")
    parser.add_argument("--keep", metavar="DIR", default=None,
                        help="write the log, truth, table and figure into DIR and keep them (default: a temporary "
                             "directory, removed at the end)")
    args = parser.parse_args()

    folder = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="rig-trend-bench-"))
    folder.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
           **{name: "1" for name in THREAD_VARIABLES}}
    log = folder / "endurance.csv"
    try:
        load_before = os.getloadavg()
        simulate_s, simulate_cpu, _, _ = _rig("simulate", str(PLANT), "--excitation", str(EXCITATION), "--duration",
                             repr(args.duration), "--out", str(log), "--force", env=env)
        trend_s, trend_cpu, printed, said = _rig("trend", str(log), "--window", args.window, "--jobs", str(args.jobs),
                                "--wear-allowance", repr(WEAR_ALLOWANCE_RAD), "--json", "--csv",
                                str(folder / "trend.csv"), "--figure", str(folder / "trend.png"), "--force", env=env)
        load_after = os.getloadavg()
    finally:
        if not args.keep:
            shutil.rmtree(folder, ignore_errors=True)
    document = json.loads(printed)
    read = re.search(r"read .* in ([0-9.]+) s", said)
    summary = document["summary"]
    windows = document["windows"]
    bounded = [w for w in windows if w["status"] == "bounded"]
    first, last = bounded[0], bounded[-1]

    def center(window) -> float:
        return float(window["play_rad"]["center"])

    def width(window) -> float:
        return float(window["play_rad"]["upper"]) - float(window["play_rad"]["lower"])

    rows = [
        ("command", f"rig trend endurance.csv --window {args.window} --jobs {args.jobs} --wear-allowance "
                    f"{WEAR_ALLOWANCE_RAD:g}"),
        ("record", f"{args.duration:g} s at 1 kHz ({int(round(args.duration * 1000))} samples), wearing_gearbox, "
                   "steady_staircase repeated"),
        ("simulate (rig simulate --duration, simulated clock)", f"{simulate_s:.1f} s wall, {simulate_cpu:.1f} CPU-s"),
        ("trend wall time (read + windows + outputs)", f"{trend_s:.1f} s, {trend_cpu:.1f} CPU-s with its workers; "
                                                       f"reading the log {read.group(1) if read else '?'} s of it"),
        ("windows / bounded / cannot bound / empty",
         f"{summary['windows']} / {summary['bounded']} / {summary['cannot_bound']} / {summary['empty']}"),
        ("truth inside the bounds", f"{summary['truth_inside']} of {summary['truth_judged']} windows"),
        ("play bounds, first window", f"[{first['play_rad']['lower']:.5f}, {first['play_rad']['upper']:.5f}] rad, "
                                      f"truth {first['truth_min_rad']:.5f}-{first['truth_max_rad']:.5f}"),
        ("play bounds, last window", f"[{last['play_rad']['lower']:.5f}, {last['play_rad']['upper']:.5f}] rad, "
                                     f"truth {last['truth_min_rad']:.5f}-{last['truth_max_rad']:.5f}"),
        ("midpoint growth / median width", f"{center(last) - center(first):.5f} rad / "
                                           f"{sorted(width(w) for w in bounded)[len(bounded) // 2]:.5f} rad"),
        ("threads", ", ".join(f"{name}=1" for name in THREAD_VARIABLES) + f" in every worker ({args.jobs} processes)"),
        ("machine", f"{platform.node()}, {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
                    f"Python {platform.python_version()}"),
        ("date", datetime.datetime.now().isoformat(timespec="minutes")),
        ("load average before / after", f"{load_before[0]:.2f} / {load_after[0]:.2f} (1 min)"),
        ("goal: under 2 minutes", "met" if trend_s < 120 else f"NOT met ({trend_s:.0f} s)"),
    ]
    width_name = max(len(name) for name, _ in rows)
    for name, value in rows:
        print(f"{name:<{width_name}}  {value}")


if __name__ == "__main__":
    main()
