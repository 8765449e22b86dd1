"""Fault -> outcome -> samples kept / samples sent, for every wire fault ``rig run --sim-faults`` injects.
Each case is one ``rig run`` of the PRBS experiment on a simulated rig at 1 kHz, as a user
would type it; the table is the evidence behind the README's "Faults and outcomes".

    .venv/bin/python benchmarks/fault_outcomes.py [--duration 2]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from identify.experiment_record import SampleFlag  # noqa: E402
from rig.cli import main as rig  # noqa: E402
from rig.log_file import read_log  # noqa: E402
from rig.protocols.errors import LogFileError  # noqa: E402

CASES = [  # (wire, --sim-faults SPEC)
    ("canopen", "drop=0.001"), ("canopen", "burst=50@500"), ("canopen", "fault=0x2310@1000"),
    ("canopen", "heartbeat@1000"), ("canopen", "disable@1000"), ("canopen", "sdo_abort=0x6060"),
    ("canopen", "delay=12@1000"), ("canopen", "bus_error@1000"), ("canopen", "bus_off@1000"),
    ("can", "drop=0.001"), ("can", "burst=50@500"), ("can", "fault=0x3210@1000"), ("can", "bus_off@1000"),
    ("serial", "drop=0.001"), ("serial", "burst=50@500"), ("serial", "fault=0x7121@1000"),
    ("serial", "garbage=0.01"), ("serial", "bitflip=0.01"), ("serial", "truncate=0.01"), ("serial", "lag=2@1000"),
    ("serial", "lag=60@1000"), ("serial", "unplug@1000"),
    ("canopen", "stall=30@1000"), ("canopen", "stall=300@1000"), ("can", "stall=300@1000"), ("serial", "stall=300@1000"),
]


def run_case(wire: str, spec: str, duration_s: float, directory: Path) -> dict[str, object]:
    out = directory / f"{wire}_{spec.replace('@', '_at_').replace('=', '_')}.csv"
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = rig(["run", str(ROOT / "configs" / f"sim_{wire}.toml"), "--experiment",
                    str(ROOT / "configs" / "experiments" / "prbs.toml"), "--out", str(out),
                    "--duration", str(duration_s), "--sim-faults", spec, "--json"])
    try:
        log = read_log(out)
        in_log, lost = log.num_samples, int(np.count_nonzero(log.flags & SampleFlag.LOST))
    except LogFileError:  # refused before anything streamed: a header and no samples
        in_log, lost = 0, 0
    sent = json.loads(stdout.getvalue())["samples"] if code == 0 else in_log
    message = stderr.getvalue().strip().splitlines()[-1] if code else ""
    return {"wire": wire, "fault": spec, "exit": code, "outcome": "ridden through" if code == 0 else "safe stop",
            "kept": in_log - lost, "lost": lost, "sent": sent, "planned": int(round(duration_s * 1000)),
            "message": message}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=2.0, help="seconds per case (default 2)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as directory:
        rows = [run_case(wire, spec, args.duration, Path(directory)) for wire, spec in CASES]
    print(f"# fault outcomes: rig run on the simulated rigs, PRBS at 1 kHz, {args.duration:g} s per case")
    print("| wire | --sim-faults | outcome (exit) | samples kept / sent (planned) | lost (flagged) | message |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        print(f"| {row['wire']} | `{row['fault']}` | {row['outcome']} ({row['exit']}) | {row['kept']} / {row['sent']} "
              f"({row['planned']}) | {row['lost']} | {row['message'].replace('|', '/')} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
