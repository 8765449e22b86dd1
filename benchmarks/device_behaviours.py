"""The CANopen master against the legal variety of real devices (``sim_backend.canopen_behaviour``): one
table, one row per simulated behaviour and master mode (``auto``: interpolated position where the drive's EDS
has the buffer, else CSP; ``csp``), with the mode the master chose, the outcome, the drive's state after the
run, the wrong rows and the largest step of the target the drive applied between two SYNCs against the
command's largest step. ``--peer`` adds the variants of the independent conformance peer
(``../shared/conformance/canopen/run.py``) as further rows of the same table.

Columns:

* mode used: ``ip_buffer`` (CiA 402 interpolated position, 0x6060 = 7, records 0x60C1 into the buffer 0x60C4)
  or ``csp`` (cyclic synchronous position, 0x6060 = 8), as the master chose it; for a peer variant, the mode
  the peer's drive showed in 0x6061;
* outcome: ``runs clean`` (no error, every row usable, none wrong), ``runs, N unusable`` / ``runs, WRONG
  ROWS``, ``stops safely`` (the master stopped with an error and the drive is not left OPERATION ENABLED or
  QUICK STOP ACTIVE), ``UNSAFE`` (the drive left enabled, or an applied step above 8x the command's largest:
  more than any HELD stretch under 8 samples gives), ``traceback`` (an error outside the rig's error tree);
  for a peer variant, the peer's own verdict;
* wrong rows: usable logged rows whose command differs from the target the simulated drive applied at that
  sample (``DeviceRecord.wrong_rows``: row k is sample k, or k plus the samples a late first target left HELD at
  the start); for a peer variant its ``cmd_wrong``;
* applied / command step: the largest change of the applied target between two consecutive SYNCs (from the
  position before sample 0 on), against the largest change between two consecutive commands, in drive counts
  (2**17 per revolution); for a peer variant its ``max_jump`` (actual position 0x6064) and ``cmd_max_step``;
* message: the master's error, or how many rows are HELD (a setpoint that missed its SYNC); for a peer variant
  whether it meets the peer's expectation, and the master's message.

Usage::

    python benchmarks/device_behaviours.py [--samples 400] [--rate 200] [--peer [--peer-samples 1500] [--peer-json FILE]]

The simulated devices answer from threads of this process, so runs take the demo's window for late answers
(``rig.demo.SIMULATED_RIG_PENDING_CYCLES``). The peer runs at its own rate (1 kHz) in its own processes.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from identify.experiment_record import SampleFlag  # noqa: E402
from rig.demo import SIMULATED_RIG_PENDING_CYCLES  # noqa: E402
from rig.protocols.errors import RigError  # noqa: E402
from rig.rig_config import load_rig_config  # noqa: E402
from rig.runner import run_experiment  # noqa: E402
from rig.transports import open_transport  # noqa: E402
from rig.transports.simulated import start_simulated_devices  # noqa: E402
from sim_backend.canopen_behaviour import real_variety  # noqa: E402
from sim_backend.plant_config import load_plant_config  # noqa: E402

# what the master is told about a device, as a user would write it in [transport], and the faults a
# behaviour needs to show (an NMT reaction to a fault shows only with a fault)
MASTER_OPTIONS = {"encoder TPDO one SYNC late": {"encoder_tpdo_latency_cycles": 1}}
FAULT_AT = {"pre-operational on fault": 200, "stopped on fault": 200}
FAULTED_BEFORE = {"fault reset takes 20 ms"}
ENABLED_STATES = ("OPERATION ENABLED", "QUICK STOP ACTIVE")
UNSAFE_STEP_FACTOR = 8  # an applied step above this many of the command's largest steps is unsafe
PEER_RUN = ROOT.parent / "shared" / "conformance" / "canopen" / "run.py"
PEER_MODES = {7: "ip_buffer", 8: "csp"}  # 0x6061 (modes of operation display) -> the master's name


class _Rows:
    """A sample sink that keeps what the table needs: time, command and flags of every row."""

    def __init__(self) -> None:
        self.time_s: list[float] = []
        self.command_rad: list[float] = []
        self.flags: list[int] = []

    def append(self, time_s, command_rad, angle_rad, encoder_counts=None, flags=0) -> None:
        self.time_s.append(float(time_s))
        self.command_rad.append(float(command_rad))
        self.flags.append(int(flags))

    def close(self) -> None:
        pass


def _config(rate_hz: float, directory: Path):
    text = (ROOT / "configs" / "sim_canopen.toml").read_text()
    plant = (ROOT / "configs" / "plants" / "precision_gearbox.toml").read_text()
    plant = plant.replace("sample_period_s = 0.001", f"sample_period_s = {1 / rate_hz!r}")
    plant = plant.replace("frequency_hz = 120.0", f"frequency_hz = {min(120.0, 0.2 * rate_hz)!r}")
    (directory / "plant.toml").write_text(plant)
    text = text.replace("sample_rate_hz = 1000.0", f"sample_rate_hz = {rate_hz!r}")
    text = text.replace('plant = "plants/precision_gearbox.toml"', f'plant = "{directory / "plant.toml"}"')
    text = text.replace("late_tolerance_s = 0.0005", f"late_tolerance_s = {0.5 / rate_hz!r}")
    text = text.replace("feedback_timeout_s = 0.1", "feedback_timeout_s = 1.0")
    path = directory / "rig.toml"
    path.write_text(text)
    return load_rig_config(path)


def _largest_step(counts) -> int:
    return int(np.max(np.abs(np.diff(np.asarray(counts, dtype=np.int64))))) if len(counts) > 1 else 0


def run_one(name: str, behaviours, mode: str, num_samples: int, rate_hz: float, directory: Path) -> dict[str, object]:
    """One run of the master in ``mode`` against the simulated devices with ``behaviours``: a row of the table."""
    config = _config(rate_hz, directory)
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    injection = {"fault_at_seq": FAULT_AT[name], "fault_code": 0x2310} if name in FAULT_AT else {}
    command = 0.5 * np.sin(2 * np.pi * 0.5 * np.arange(num_samples) / rate_hz)
    rows, message, outcome = _Rows(), "", ""
    with contextlib.ExitStack() as stack:
        url, rig = start_simulated_devices(config, gearbox, stack, drive_behaviour=behaviours[0],
                                           encoder_behaviour=behaviours[1], **injection)
        drive_eds, encoder_eds = rig.write_eds(directory)  # what the vendor ships for these devices
        options = dict(config.transport_options(), drive_eds=str(drive_eds), encoder_eds=str(encoder_eds),
                       mode=mode, **MASTER_OPTIONS.get(name, {}))
        transport = open_transport(url, **options)
        stack.callback(transport.close)
        if name in FAULTED_BEFORE:
            rig.inject_fault(0x2310)  # the drive is in FAULT when the master comes
        try:
            run_experiment(transport, command, rows, feedback_timeout_s=config.feedback_timeout_s,
                           late_tolerance_s=config.late_tolerance_s, pending_cycles=SIMULATED_RIG_PENDING_CYCLES)
        except RigError as err:
            outcome, message = "stops safely", " ".join([str(err), *getattr(err, "__notes__", ())])
        except Exception as err:  # noqa: BLE001  (the table reports it; the drive's state still counts)
            outcome, message = "traceback", f"{type(err).__name__}: {err}"
        message = message.replace(f"{url} ", "")
        state = rig.state.name.replace("_", " ")
        record = rig.record()
        applied = record.applied_targets.tolist()
        before = rig.position_before_samples
        mode_used = getattr(transport, "mode", "?")
    scaling = rig.drive_scaling
    flags = np.array(rows.flags, dtype=int)
    usable = (flags & int(SampleFlag.unusable())) == 0
    # row k is the drive's sample k, or k + the offset of a first target that came too late (HELD rows at the start)
    wrong = record.wrong_rows([scaling.counts_from_rad(value) for value in rows.command_rad], usable)
    applied_step = _largest_step(([before] if before is not None else []) + applied)
    command_step = _largest_step([scaling.counts_from_rad(value) for value in command])
    if state in ENABLED_STATES or applied_step > UNSAFE_STEP_FACTOR * max(command_step, 1):
        outcome = "UNSAFE"
    elif not outcome:
        unusable = int(np.count_nonzero(~usable)) + num_samples - len(rows.flags)
        outcome = "runs, WRONG ROWS" if wrong else f"runs, {unusable} unusable" if unusable else "runs clean"
    held = int(np.count_nonzero(flags & int(SampleFlag.HELD)))
    if held:  # a setpoint that missed its SYNC: the drive held the one before, then took a later one
        message = f"{held} rows HELD; {message}" if message else f"{held} rows HELD"
    return {"device": name, "mode": mode_used, "outcome": outcome, "state": state, "wrong": wrong,
            "usable": int(np.count_nonzero(usable)), "rows": len(rows.flags), "applied_step": applied_step,
            "command_step": command_step, "note": message}


def peer_rows(num_samples: int | None, keep_json: str | None = None) -> list[dict[str, object]]:
    """The conformance peer's variants (its ``run.py --json``), as rows of the table; ``keep_json``: copy its
    JSON lines (every measured value, the master's whole message) there."""
    with tempfile.TemporaryDirectory() as directory:
        out = Path(directory) / "peer.jsonl"
        command = [sys.executable, str(PEER_RUN), "--json", str(out)]
        if num_samples is not None:
            command += ["--n", str(num_samples)]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
        done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
        if not out.exists():
            raise SystemExit(f"{PEER_RUN} wrote no results (exit {done.returncode}):\n{done.stderr[-800:]}")
        results = [json.loads(line) for line in out.read_text().splitlines() if line.strip()]
        if keep_json:
            shutil.copyfile(out, keep_json)
    rows = []
    for result in results:
        expectation = ("PASS" if result.get("pass") else "FAIL") + f" against \"{result.get('expected', '?')}\""
        # the bus URL (one per variant) says nothing the row does not: drop it, keep the master's words
        message = re.sub(r"(rig: )?(device error: )?canopen://\S+ ", "", result.get("message") or "")
        rows.append({"device": f"peer: {result['variant']}", "mode": PEER_MODES.get(result.get("mode_shown"), "?"),
                     "outcome": result.get("verdict", "?"), "state": result.get("final_state", "?"),
                     "wrong": result.get("cmd_wrong"), "usable": result.get("usable"), "rows": result.get("rows"),
                     "applied_step": result.get("max_jump"), "command_step": result.get("cmd_max_step"),
                     "note": f"{expectation}; {message}" if message else expectation})
    return rows


def _cell(value: object) -> str:
    return "-" if value is None else str(value).replace("|", "/").replace("\n", " ")


def print_row(row: dict[str, object]) -> None:
    print(f"| {_cell(row['device'])} | {_cell(row['mode'])} | {_cell(row['outcome'])} | {_cell(row['state'])} | "
          f"{_cell(row['wrong'])} | {_cell(row['usable'])} / {_cell(row['rows'])} | {_cell(row['applied_step'])} / "
          f"{_cell(row['command_step'])} | {_cell(row['note'])[:120]} |", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=400, help="samples per run (default 400)")
    parser.add_argument("--rate", type=float, default=200.0, help="sample rate in Hz (default 200)")
    parser.add_argument("--peer", action="store_true", help="add the conformance peer's variants (~3-5 min)")
    parser.add_argument("--peer-samples", type=int, default=None,
                        help="samples per peer run (its --n; default: the peer's own, 1500)")
    parser.add_argument("--peer-json", default=None, metavar="FILE",
                        help="keep the peer's JSON lines (all its measured values, whole messages) in FILE")
    args = parser.parse_args()
    print(f"# CANopen master vs device behaviours: simulated drive {args.samples} samples at {args.rate:g} Hz, "
          f"modes auto and csp" + (", then the conformance peer's variants (1 kHz)" if args.peer else ""))
    print("| device / variant | mode used | outcome | drive after the run | wrong rows | usable / rows | "
          "largest step applied / command (counts) | message |")
    print("|---|---|---|---|---|---|---|---|")
    for name, behaviours in real_variety().items():
        for mode in ("auto", "csp"):
            with tempfile.TemporaryDirectory() as directory:
                row = run_one(name, behaviours, mode, args.samples, args.rate, Path(directory))
            row["device"] = f"{name} [{mode}]"
            print_row(row)
    if args.peer:
        for row in peer_rows(args.peer_samples, args.peer_json):
            print_row(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
