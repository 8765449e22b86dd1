"""Loop timing of the rig driver against its simulated devices: CANopen and serial (and raw CAN) at
1 kHz and 2 kHz.

For each transport and rate, ``rig.runner.run_experiment`` streams a slow sine (well inside the limits)
into the simulated rig for ``--duration`` seconds and the table reports:

* lost samples (goal 0) and late cycles (goal at most 0.1 % at 1 kHz), next to the host's floor: the
  late cycles of the runner's wait loop alone, with no transport, which no driver on this host can beat;
* period jitter |t_k - t_{k-1} - T| of the setpoint sends, p50 / p99 / max, in microseconds;
* CPU use of the whole process (driver + simulated devices, which share it) as a fraction of one core;
* for CAN: the bus load of one cycle at the configured bit rate (worst-case bit stuffing), the load the
  simulated bus measured, and the highest rate the bus could carry with these frames.

The simulated devices run in the same Python process as the driver (python-can's virtual bus is
in-process), so they compete with it for the GIL and the two CPU cores: on real hardware the driver is
the only Python in the loop. Usage::

    python benchmarks/transport_timing.py                   # 5 s per case
    nice -n 10 python benchmarks/transport_timing.py --duration 60
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rig.commands.run import start_simulated_devices  # noqa: E402
from rig.rig_config import load_rig_config  # noqa: E402
from rig.runner import run_experiment, wait_until  # noqa: E402
from rig.transports import open_transport  # noqa: E402
from sim_backend.plant_config import load_plant_config  # noqa: E402


class _NullSink:
    def append(self, *row: object) -> None:
        pass

    def close(self) -> None:
        pass


def _config(kind: str, rate_hz: float, directory: Path):
    text = (ROOT / "configs" / f"sim_{kind}.toml").read_text()
    text = text.replace("sample_rate_hz = 1000.0", f"sample_rate_hz = {rate_hz!r}")
    text = text.replace('plant = "plants/', f'plant = "{ROOT / "configs" / "plants"}/')
    text = text.replace("late_tolerance_s = 0.0005", f"late_tolerance_s = {0.5 / rate_hz!r}")
    # a shared, loaded machine can stall the process for more than the template's 0.1 s: measure, don't stop
    text = text.replace("feedback_timeout_s = 0.1", "feedback_timeout_s = 2.0")
    path = directory / f"{kind}_{rate_hz:g}.toml"
    path.write_text(text)
    return load_rig_config(path)


def measure(kind: str, rate_hz: float, duration_s: float, directory: Path, pending_cycles: int) -> dict[str, object]:
    config = _config(kind, rate_hz, directory)
    # the plant's physics stay at its own 1 kHz; only the wall-clock rate of the loop changes here
    gearbox = load_plant_config(config.simulation.plant_path).gearbox(seed=config.simulation.seed)
    num_samples = int(round(duration_s * rate_hz))
    command = 0.5 * np.sin(2 * np.pi * 0.5 * np.arange(num_samples) / rate_hz)
    with contextlib.ExitStack() as stack:
        url, device = start_simulated_devices(config, gearbox, stack)
        transport = open_transport(url, **config.transport_options())
        summary = run_experiment(transport, command, _NullSink(), feedback_timeout_s=config.feedback_timeout_s,
                                 late_tolerance_s=config.late_tolerance_s, pending_cycles=pending_cycles)
        measured_load = device.bus_load() if hasattr(device, "bus_load") else None
        if measured_load is None and hasattr(device, "bits"):
            measured_load = device.bits / (summary.wall_s * device.bitrate)
    period = 1.0 / rate_hz
    send_times = np.arange(summary.samples) * period + summary.send_lateness_s
    jitter_us = np.abs(np.diff(send_times) - period) * 1e6
    row: dict[str, object] = {
        "transport": kind, "rate_hz": rate_hz, "samples": summary.samples, "lost": summary.lost,
        "duplicate": summary.duplicate, "load_average": os.getloadavg()[0],
        "late": summary.late, "late_pct": 100.0 * summary.late / summary.samples,
        "jitter_p50_us": float(np.percentile(jitter_us, 50)), "jitter_p99_us": float(np.percentile(jitter_us, 99)),
        "jitter_max_us": float(jitter_us.max()), "cpu": summary.cpu_s / summary.wall_s,
        "achieved_hz": summary.rate_hz,
    }
    load = getattr(transport, "load", None)
    if load is not None:
        row.update(bus_load_pct=100 * load.load, measured_load_pct=100 * measured_load, bus_limit_hz=load.max_rate_hz)
    return row


def host_floor(rate_hz: float, duration_s: float) -> dict[str, object]:
    """The same absolute-deadline wait as the runner with nothing else to do: the late cycles this host
    makes whatever the driver does (a virtual machine's scheduler or timer slack waking the loop late)."""
    period = 1.0 / rate_hz
    num_cycles = int(round(duration_s * rate_hz))
    lateness = np.empty(num_cycles)
    cpu_start = time.process_time()
    start = time.perf_counter() + period
    for k in range(num_cycles):
        wait_until(start + k * period)
        lateness[k] = time.perf_counter() - (start + k * period)
    wall = time.perf_counter() - start
    late = int(np.count_nonzero(lateness > 0.5 * period))
    jitter_us = np.abs(np.diff(lateness)) * 1e6
    return {"transport": "host floor (bare wait loop)", "rate_hz": rate_hz, "samples": num_cycles, "lost": 0,
            "duplicate": 0, "load_average": os.getloadavg()[0], "late": late, "late_pct": 100.0 * late / num_cycles,
            "jitter_p50_us": float(np.percentile(jitter_us, 50)), "jitter_p99_us": float(np.percentile(jitter_us, 99)),
            "jitter_max_us": float(jitter_us.max()), "cpu": (time.process_time() - cpu_start) / wall,
            "achieved_hz": (num_cycles - 1) / wall}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=5.0, help="seconds per case (default 5)")
    parser.add_argument("--rates", type=float, nargs="+", default=[1000.0, 2000.0])
    parser.add_argument("--transports", nargs="+", default=["canopen", "serial", "can"],
                        choices=["canopen", "serial", "can"])
    parser.add_argument("--pending-cycles", type=int, default=4,
                        help="feedback later than this many cycles is LOST (the runner's default: 4)")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = parser.parse_args()
    rows = [host_floor(rate, args.duration) for rate in args.rates]
    with tempfile.TemporaryDirectory() as directory:
        for kind in args.transports:
            for rate in args.rates:
                rows.append(measure(kind, rate, args.duration, Path(directory), args.pending_cycles))
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"# transport timing, {args.duration:g} s per case, Python {platform.python_version()}, "
          f"{platform.machine()}, simulated devices in-process, pending window {args.pending_cycles} cycles")
    print("| transport | rate | samples | lost | duplicate | late (%) | jitter p50 / p99 / max (us) | CPU (1 core) "
          "| load avg | CAN load (worst case / measured) | CAN limit |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        can_columns = "n/a | n/a"
        if "bus_load_pct" in row:
            can_columns = (f"{row['bus_load_pct']:.1f}% / {row['measured_load_pct']:.1f}% | "
                           f"{row['bus_limit_hz']:.0f} Hz")
        print(f"| {row['transport']} | {row['rate_hz']:.0f} Hz | {row['samples']} | {row['lost']} | "
              f"{row['duplicate']} | {row['late']} ({row['late_pct']:.2f}%) | {row['jitter_p50_us']:.0f} / "
              f"{row['jitter_p99_us']:.0f} / {row['jitter_max_us']:.0f} | {100 * row['cpu']:.0f}% | "
              f"{row['load_average']:.2f} | {can_columns} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
