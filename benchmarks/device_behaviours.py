"""The CANopen master against the legal variety of real devices (``sim_backend.canopen_behaviour``): for
each simulated behaviour, the outcome of a run (runs clean / stops safely), the drive's state and NMT
state after it, the samples kept of those sent, and the message when it stopped.

Usage::

    python benchmarks/device_behaviours.py [--samples 400] [--rate 200]
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from identify.experiment_record import SampleFlag  # noqa: E402
from rig.transports.simulated import start_simulated_devices  # noqa: E402
from rig.protocols.errors import RigError  # noqa: E402
from rig.rig_config import load_rig_config  # noqa: E402
from rig.runner import run_experiment  # noqa: E402
from rig.transports import open_transport  # noqa: E402
from sim_backend.canopen_behaviour import real_variety  # noqa: E402
from sim_backend.plant_config import load_plant_config  # noqa: E402

# what the master is told about a device, as a user would write it in [transport], and the faults a
# behaviour needs to show (an NMT reaction to a fault shows only with a fault)
MASTER_OPTIONS = {"encoder TPDO one SYNC late": {"encoder_tpdo_latency_cycles": 1}}
FAULT_AT = {"pre-operational on fault": 200, "stopped on fault": 200}
FAULTED_BEFORE = {"fault reset takes 20 ms"}


class _Rows:
    def __init__(self) -> None:
        self.flags: list[int] = []

    def append(self, time_s, command_rad, angle_rad, encoder_counts=None, flags=0) -> None:
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


def run_one(name: str, behaviours, num_samples: int, rate_hz: float, directory: Path) -> dict[str, object]:
    config = _config(rate_hz, directory)
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    injection = {"fault_at_seq": FAULT_AT[name], "fault_code": 0x2310} if name in FAULT_AT else {}
    command = 0.5 * np.sin(2 * np.pi * 0.5 * np.arange(num_samples) / rate_hz)
    rows, message = _Rows(), ""
    with contextlib.ExitStack() as stack:
        url, rig = start_simulated_devices(config, gearbox, stack, drive_behaviour=behaviours[0],
                                           encoder_behaviour=behaviours[1], **injection)
        drive_eds, encoder_eds = rig.write_eds(directory)
        transport = open_transport(url, **dict(config.transport_options(), drive_eds=str(drive_eds),
                                                encoder_eds=str(encoder_eds), **MASTER_OPTIONS.get(name, {})))
        stack.callback(transport.close)
        if name in FAULTED_BEFORE:
            rig.inject_fault(0x2310)
        try:
            run_experiment(transport, command, rows, feedback_timeout_s=config.feedback_timeout_s,
                           late_tolerance_s=config.late_tolerance_s)
            outcome = "runs clean"
        except RigError as err:
            outcome, message = "stops safely", str(err).replace(f"{url} ", "")
        state, nmt = rig.state.name.replace("_", " "), rig.drive.nmt.state
    flags = np.array(rows.flags, dtype=int)
    usable = int(np.count_nonzero((flags & int(SampleFlag.unusable())) == 0))
    if outcome == "runs clean" and usable < num_samples:
        outcome = "runs, with unusable samples"
    return {"behaviour": name, "outcome": outcome, "state": state, "nmt": nmt, "kept": usable, "sent": num_samples,
            "message": message}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=400)
    parser.add_argument("--rate", type=float, default=200.0, help="sample rate in Hz (default 200)")
    args = parser.parse_args()
    print(f"# CANopen master vs simulated device behaviours, {args.samples} samples at {args.rate:g} Hz")
    print("| device behaviour | outcome | drive after the run | NMT after | samples usable / sent | message |")
    print("|---|---|---|---|---|---|")
    for name, behaviours in real_variety().items():
        with tempfile.TemporaryDirectory() as directory:
            row = run_one(name, behaviours, args.samples, args.rate, Path(directory))
        print(f"| {row['behaviour']} | {row['outcome']} | {row['state']} | {row['nmt']} | {row['kept']} / "
              f"{row['sent']} | {row['message'][:150]} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
